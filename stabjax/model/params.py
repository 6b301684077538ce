"""Parameter declarations, parsing and vectorised validation helpers.

A system declares its parameters as :class:`Param` records. Values travel through the
engine as NumPy arrays whose trailing dimensions are the parameter's ``shape`` and
whose leading dimensions (if any) are batch dimensions, so every check here works on a
single value and on a whole sweep at once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from ..errors import ValidationError
from ..validate import eval_number


@dataclass(frozen=True)
class Param:
    """One named parameter of a system.

    ``kind`` is ``"model"`` for physical/controller constants and ``"initial"`` for
    initial conditions; both may be fixed, swept or sampled.
    ``parse`` turns a user value (number, list, comma string) into an array of ``shape``;
    the default accepts exactly ``prod(shape)`` numbers.
    """

    name: str
    default: Any
    doc: str
    shape: tuple[int, ...] = ()
    unit: str = ""
    kind: str = "model"
    parse: Callable[[np.ndarray], np.ndarray] | None = None
    choices: tuple[Any, ...] | None = None  # for discrete (integer-coded) parameters

    KINDS = ("model", "initial")

    def __post_init__(self):
        # a misspelt kind ran as a model constant, silently: what attractor_stop and the starts accept changed
        if self.kind not in self.KINDS:
            raise ValidationError(f"{self.name}.kind", f"{self.kind!r} is not a kind of parameter; choose one of "
                                                       f"{', '.join(map(repr, self.KINDS))}")

    @property
    def size(self) -> int:
        return int(np.prod(self.shape)) if self.shape else 1


def _to_array(value: Any, name: str) -> np.ndarray:
    if isinstance(value, np.ndarray) and value.dtype.kind in "fiu":
        return np.asarray(value, dtype=float)
    if isinstance(value, str):
        parts = [p for p in value.replace(";", ",").split(",") if p.strip()]
        try:
            arr = np.array([eval_number(p, name) for p in parts], dtype=float)
        except ValueError as exc:
            raise ValidationError(name, f"cannot parse {value!r} as numbers ({exc})") from None
        if arr.size == 0:
            raise ValidationError(name, f"cannot parse {value!r} as numbers (empty)")
        return arr[0] if arr.size == 1 else arr

    def conv(v, depth=0):
        # booleans are ints in Python (True == 1): a switch where a number belongs is refused, not read as 1
        if isinstance(v, (bool, np.bool_)):
            raise ValidationError(name, f"expected numbers, got a boolean ({value!r})")
        if isinstance(v, (int, float, np.integer, np.floating)):
            try:
                return float(v)
            except OverflowError:
                raise ValidationError(name, f"{v!r} is too large") from None
        if isinstance(v, str):
            try:
                return eval_number(v, name)
            except ValueError as exc:
                raise ValidationError(name, f"cannot parse {v!r} as a number ({exc})") from None
        if isinstance(v, (list, tuple, np.ndarray)) and depth < 3:
            return [conv(x, depth + 1) for x in v]
        raise ValidationError(name, f"cannot parse {value!r} as numbers")

    try:
        return np.asarray(conv(value), dtype=float)
    except ValidationError:  # conv's own message (a ValueError too), not "ragged"
        raise
    except ValueError:  # ragged nesting
        raise ValidationError(name, f"cannot parse {value!r} as numbers (ragged list)") from None


def parse_value(param: Param, value: Any) -> np.ndarray:
    """Parse one (unbatched) value of ``param`` into an array of ``param.shape``."""
    arr = _to_array(value, param.name)
    if param.parse is not None:
        arr = param.parse(arr)
    if arr.shape != param.shape:
        if arr.size == param.size:
            arr = arr.reshape(param.shape)
        else:
            want = "a number" if not param.shape else f"{param.size} numbers (shape {param.shape})"
            raise ValidationError(param.name, f"expected {want}, got {arr.size} value(s): {value!r}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(param.name, f"non-finite value {value!r}")
    if param.choices is not None and not np.isin(arr, param.choices).all():
        raise ValidationError(param.name, f"must be one of {param.choices}, got {value!r}")
    return arr


def diag_or_matrix(arr: np.ndarray) -> np.ndarray:
    """Parser for 3x3 matrices given as 3 diagonal entries or 9 entries (row-major)."""
    arr = np.asarray(arr, dtype=float)
    if arr.shape == (3, 3):
        return arr
    if arr.size == 3:
        return np.diag(arr.reshape(3))
    if arr.size == 9:
        return arr.reshape(3, 3)
    return arr  # shape error reported by parse_value


@dataclass
class ParamSet:
    """Declared parameters of a system, in order."""

    params: tuple[Param, ...]
    by_name: dict[str, Param] = field(init=False)

    def __post_init__(self):
        self.by_name = {p.name: p for p in self.params}

    def __getitem__(self, name: str) -> Param:
        try:
            return self.by_name[name]
        except KeyError:
            raise ValidationError(name, f"unknown parameter; known: {', '.join(self.by_name)}") from None

    def __iter__(self):
        return iter(self.params)

    def defaults(self) -> dict[str, np.ndarray]:
        return {p.name: parse_value(p, p.default) for p in self.params}

    def resolve(self, overrides: Mapping[str, Any] | None = None) -> dict[str, np.ndarray]:
        """Defaults with ``overrides`` applied (unbatched), each parsed and shape-checked."""
        values = self.defaults()
        for name, value in (overrides or {}).items():
            values[name] = parse_value(self[name], value)
        return values


# ---- vectorised checks used by systems' ``check`` methods -------------------------------------


def require(cond: np.ndarray | bool, field_name: str, message: str, values: np.ndarray | None = None):
    """Raise ``ValidationError(field_name, ...)`` where ``cond`` is False anywhere in the batch.

    ``cond`` has the batch shape (or is a scalar); ``values`` (batch shape + value shape) is
    used to quote the first offending value in the message.
    """
    cond = np.asarray(cond, dtype=bool)
    if cond.all():
        return
    detail = ""
    if values is not None:
        vals = np.asarray(values)
        if cond.ndim and vals.shape[: cond.ndim] == cond.shape:
            first = vals[~cond][0]
        else:
            first = vals
        detail = f" (got {np.array2string(np.asarray(first), precision=6, separator=',')})"
    raise ValidationError(field_name, message + detail)


def check_positive(p: Mapping[str, np.ndarray], name: str, strict: bool = True, value_ndim: int = 0):
    """Every entry positive (or non-negative); ``value_ndim`` trailing dims belong to the value."""
    v = np.asarray(p[name])
    cond = (v > 0) if strict else (v >= 0)
    if value_ndim:
        cond = cond.all(axis=tuple(range(-value_ndim, 0)))
    require(cond, name, "must be " + ("positive" if strict else "non-negative"), v)


def check_unit(p: Mapping[str, np.ndarray], name: str, tol: float = 1e-6) -> np.ndarray:
    """Unit vectors: within ``tol`` of norm 1 they are renormalised silently; otherwise rejected.

    Rejecting (rather than normalising with a warning) keeps a sweep from running the wrong
    geometry because of a typo; the message gives the normalised value to paste back.
    """
    v = np.asarray(p[name], dtype=float)
    n = np.linalg.norm(v, axis=-1)
    bad = np.abs(n - 1.0) > tol
    if bad.any():
        w = v[bad][0] if v.ndim > 1 else v
        nw = np.linalg.norm(w)
        hint = f"; normalised it would be {np.array2string(w / nw, precision=9, separator=',')}" if nw > 0 else ""
        raise ValidationError(name, f"must be a unit vector, has norm {nw:.9g}{hint}")
    return v / n[..., None]


def check_spd(p: Mapping[str, np.ndarray], name: str, sym_tol: float = 1e-12) -> None:
    """Symmetric positive definite 3x3 (batched)."""
    m = np.asarray(p[name], dtype=float)
    asym = np.abs(m - np.swapaxes(m, -1, -2)).max(axis=(-1, -2))
    scale = np.maximum(np.abs(m).max(axis=(-1, -2)), 1.0)
    require(asym <= sym_tol * scale, name, "must be symmetric", m)
    eig = np.linalg.eigvalsh(m)
    require(eig[..., 0] > 0, name, f"must be positive definite (smallest eigenvalue {eig[..., 0].min():.6g})", m)
