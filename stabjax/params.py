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

from .errors import ValidationError


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
    except ValueError:  # ragged nesting
        raise ValidationError(name, f"cannot parse {value!r} as numbers (ragged list)") from None


MAX_EXPRESSION_LENGTH = 200  # characters of one arithmetic expression
MAX_EXPONENT = 1024.0  # |b| in a ** b: beyond it a double over/underflows whatever a is
_CONSTANTS = {"pi": math.pi, "e": math.e, "tau": math.tau}
_FUNCTIONS = {
    "sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": math.asin, "acos": math.acos,
    "atan": math.atan, "exp": math.exp, "log": math.log, "log10": math.log10, "abs": abs,
    "radians": math.radians, "degrees": math.degrees,
}


def eval_number(text: str, name: str) -> float:
    """Numbers, or small arithmetic such as ``7/9``, ``1/sqrt(3)``, ``2*pi``, ``1e-3*cos(pi/7)``.

    Evaluated by walking the syntax tree (no ``eval``): number literals (as doubles, so no unbounded
    integer arithmetic), ``+ - * / **``, unary signs, parentheses, the constants pi, e, tau and the
    one-argument functions in ``_FUNCTIONS``. Bounded in size (``MAX_EXPRESSION_LENGTH`` characters)
    and in every intermediate (finite doubles, exponents ``|b| <= MAX_EXPONENT``), hence in time:
    ``9**9**9`` is refused at once instead of computed.
    """
    import ast

    text = text.strip()
    shown = text if len(text) <= 40 else text[:37] + "..."
    if len(text) > MAX_EXPRESSION_LENGTH:
        raise ValueError(f"expression longer than {MAX_EXPRESSION_LENGTH} characters")
    try:
        x = float(text)
    except ValueError:
        pass
    else:
        if not math.isfinite(x):
            raise ValueError(f"{shown!r} is not finite")
        return x
    if not text:
        raise ValueError("empty value")
    try:
        tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        raise ValueError(f"{shown!r} is not a number or an arithmetic expression") from None

    def finite(x: float) -> float:
        if not math.isfinite(x):
            raise ValueError(f"{shown!r} overflows")
        return x

    def walk(node) -> float:
        if isinstance(node, ast.Expression):
            return walk(node.body)
        if isinstance(node, ast.Constant) and type(node.value) in (int, float):
            try:
                return finite(float(node.value))
            except OverflowError:
                raise ValueError(f"{shown!r}: literal too large") from None
        if isinstance(node, ast.Name) and node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.UAdd, ast.USub)):
            v = walk(node.operand)
            return v if isinstance(node.op, ast.UAdd) else -v
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow)):
            a, b = walk(node.left), walk(node.right)
            if isinstance(node.op, ast.Add):
                return finite(a + b)
            if isinstance(node.op, ast.Sub):
                return finite(a - b)
            if isinstance(node.op, ast.Mult):
                return finite(a * b)
            if isinstance(node.op, ast.Div):
                if b == 0:
                    raise ValueError(f"{shown!r}: division by zero")
                return finite(a / b)
            if abs(b) > MAX_EXPONENT:
                raise ValueError(f"{shown!r}: exponent {b:g} too large (|exponent| <= {MAX_EXPONENT:g})")
            try:
                r = a**b
            except (OverflowError, ZeroDivisionError):
                raise ValueError(f"{shown!r} overflows") from None
            if isinstance(r, complex):
                raise ValueError(f"{shown!r} is not real")
            return finite(r)
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUNCTIONS
                and len(node.args) == 1 and not node.keywords):
            try:
                return finite(float(_FUNCTIONS[node.func.id](walk(node.args[0]))))
            except (OverflowError, ValueError) as exc:
                raise ValueError(f"{shown!r}: {node.func.id}: {exc}") from None
        raise ValueError(f"{shown!r}: only numbers, + - * / **, parentheses, {', '.join(_CONSTANTS)} and "
                         f"{', '.join(_FUNCTIONS)}(x) are allowed")

    try:
        return walk(tree)
    except RecursionError:
        raise ValueError(f"{shown!r} is nested too deeply") from None


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
