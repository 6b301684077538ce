"""Field validators for spec tables and config records: each names the full field path on failure.

TOML (and JSON, and Python) let a value of the wrong kind through silently in many places:
``True`` is an ``int`` in Python, ``float("nan")`` is a float, ``15.5`` passes ``int()`` by truncation.
These helpers accept exactly what a field means and raise :class:`stabjax.errors.ValidationError`
naming the field (``integrate.t0``, ``grid.alpha.num``, ...) otherwise. They import nothing heavy, so
the spec loader and the config module can both use them.
"""
from __future__ import annotations

import math
import os
import typing
from dataclasses import fields
from typing import Any, Mapping

import numpy as np

from .errors import ValidationError

MAX_INT = 2**62  # counts beyond this cannot index an array (int64) and cannot be meant


def kind_of(value: Any) -> str:
    """A short user-facing name for the type of a value (as TOML users know them)."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a number"
    return type(value).__name__


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


def number(value: Any, field: str, *, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, hi_open: bool = False, finite: bool = True) -> float:
    """A real number (int or float, or an arithmetic string such as ``"7/9"``); never a boolean."""
    if isinstance(value, (bool, np.bool_)):
        raise ValidationError(field, f"must be a number, got a boolean ({value!r})")
    if isinstance(value, str):
        try:
            x = eval_number(value, field)
        except ValueError as exc:
            raise ValidationError(field, str(exc)) from None
    elif isinstance(value, (int, float, np.integer, np.floating)):
        try:
            x = float(value)
        except OverflowError:
            raise ValidationError(field, f"{value!r} is too large") from None
    else:
        raise ValidationError(field, f"must be a number, got {kind_of(value)} ({value!r})")
    if finite and not math.isfinite(x):
        raise ValidationError(field, f"must be finite, got {x}")
    _range(x, field, lo, hi, lo_open, hi_open)
    return x


def integer(value: Any, field: str, *, lo: int | None = None, hi: int | None = MAX_INT) -> int:
    """An integer count; an integral float (``1e6``) is accepted, ``2.5``, booleans and strings are not."""
    if isinstance(value, (bool, np.bool_)):
        raise ValidationError(field, f"must be an integer, got a boolean ({value!r})")
    if isinstance(value, (int, np.integer)):
        n = int(value)
    elif isinstance(value, (float, np.floating)):
        if not math.isfinite(value) or not float(value).is_integer():
            raise ValidationError(field, f"must be an integer, got {value!r}")
        n = int(value)
    else:
        raise ValidationError(field, f"must be an integer, got {kind_of(value)} ({value!r})")
    _range(n, field, lo, hi, False, False)
    return n


def boolean(value: Any, field: str) -> bool:
    """``true``/``false`` only (not 0/1: a number where a switch belongs is likely a misplaced value)."""
    if not isinstance(value, bool):
        raise ValidationError(field, f"must be true or false, got {kind_of(value)} ({value!r})")
    return value


def string(value: Any, field: str, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str):
        raise ValidationError(field, f"must be a string, got {kind_of(value)} ({value!r})")
    if choices is not None and value not in choices:
        raise ValidationError(field, f"unknown value {value!r}; choose from {', '.join(choices)}")
    return value


def table(value: Any, field: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise ValidationError(field, f"must be a table, got {kind_of(value)} ({value!r})")
    return value


def numbers(value: Any, field: str, *, length: int | None = None) -> list[float]:
    """A list of finite numbers (optionally of a given length)."""
    if not isinstance(value, (list, tuple)):
        raise ValidationError(field, f"must be a list of numbers, got {kind_of(value)} ({value!r})")
    if length is not None and len(value) != length:
        raise ValidationError(field, f"must be {length} numbers, got {len(value)}")
    return [number(v, f"{field}[{i}]") for i, v in enumerate(value)]


def _range(x, field, lo, hi, lo_open, hi_open):
    if lo is not None and (x < lo or (lo_open and x == lo)):
        raise ValidationError(field, f"must be {'>' if lo_open else '>='} {lo}, got {x}")
    if hi is not None and (x > hi or (hi_open and x == hi)):
        raise ValidationError(field, f"must be {'<' if hi_open else '<='} {hi}, got {x}")


# ---- dataclass records from spec tables ------------------------------------------------------------


def _annotation(cls, name: str) -> str:
    try:
        hints = typing.get_type_hints(cls)
        ann = hints[name]
        return getattr(ann, "__name__", None) if isinstance(ann, type) else str(ann).replace("typing.", "")
    except Exception:  # noqa: BLE001 - string annotations that do not resolve: use the raw text
        return str(cls.__dataclass_fields__[name].type)


def coerce_field(cls, name: str, value: Any, field: str) -> Any:
    """Check ``value`` against the declared type of dataclass field ``name`` (bool, int, float, str,
    optional float, tuple of floats); other annotations pass through for the record's own checks."""
    ann = _annotation(cls, name).replace(" ", "")
    if ann in ("bool", "bool|None"):
        return boolean(value, field)
    if ann == "int":
        return integer(value, field)
    if ann in ("float", "float|None", "Optional[float]", "None|float"):
        return number(value, field)
    if ann in ("str", "str|None", "Optional[str]"):
        return string(value, field)
    if ann.startswith("tuple[float") or ann.startswith("tuple[int"):
        return tuple(numbers(value, field))
    return value


def record_from_dict(cls, d: Mapping[str, Any] | None, section: str, *, base=None, what: str = "field"):
    """A frozen dataclass ``cls`` from a spec table: unknown names and wrong types name ``section.key``.

    ``base``: an instance whose values are the defaults (``dataclasses.replace``); else ``cls()``.
    """
    from dataclasses import replace

    d = dict(table(d if d is not None else {}, section))
    known = {f.name for f in fields(cls)}
    out = {}
    for k, v in d.items():
        if k not in known:
            raise ValidationError(f"{section}.{k}", f"unknown {what}; known: {', '.join(sorted(known))}")
        out[k] = coerce_field(cls, k, v, f"{section}.{k}")
    try:
        return replace(base, **out) if base is not None else cls(**out)
    except (TypeError, ValueError) as exc:  # a record's own __post_init__ check
        if isinstance(exc, ValidationError):
            raise
        raise ValidationError(section, str(exc)) from None


# ---- memory ---------------------------------------------------------------------------------------

MEMORY_FRACTION = 0.25  # share of the available memory a plan's arrays may take


def available_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def check_allocation(field: str, nbytes: int, what: str) -> None:
    """Refuse, before allocating, an array that would take more than MEMORY_FRACTION of free memory."""
    limit = int(MEMORY_FRACTION * available_memory())
    if nbytes > limit:
        raise ValidationError(field, f"{what} would need {nbytes / 2**30:.3g} GiB, over the {limit / 2**30:.3g} GiB "
                                     "allowed; use fewer points or split the sweep")


def check_verdict(cfg, section: str = "verdict") -> None:
    """Ranges of the classifier thresholds (:class:`stabjax.model.system.VerdictConfig`), named ``section.<name>``.

    Every float threshold is finite; tolerances and sizes are positive (a zero or negative one makes a
    verdict impossible or certain); fractions of the horizon lie in (0, 1]. Fields added later are
    checked by their declared type in :func:`record_from_dict`.
    """
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        path = f"{section}.{f.name}"
        if isinstance(f.default, bool):
            boolean(v, path)
        elif isinstance(f.default, int):
            integer(v, path)
        elif isinstance(f.default, float):
            number(v, path)
        if f.name.endswith("_fraction") or f.name.endswith("_window"):
            number(v, path, lo=0.0, hi=1.0, lo_open=True)
        elif f.name == "growth_tol":  # a log-log slope: any finite value
            continue
        elif f.name == "floor_tol":
            number(v, path, lo=0.0)
        elif f.name.endswith("_tol") or f.name.endswith("_size"):
            number(v, path, lo=0.0, lo_open=True)
