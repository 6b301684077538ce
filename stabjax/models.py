"""Systems from outside the package: load a user's model, check it, fingerprint it.

A sweep spec's ``system`` (or the first argument of :func:`stabjax.sweep.run_spec`,
:func:`stabjax.engine.simulate`, the plan functions) may be

* a registered name (built in, added with :func:`stabjax.register`, or installed by a package
  through the entry-point group ``stabjax.systems``);
* ``"path/to/model.py:ClassName"`` -- a file, relative to the spec file's folder (or the
  working directory when there is no spec file);
* ``"package.module:ClassName"`` -- an importable module;
* a :class:`~stabjax.system.System` subclass or instance (Python API).

Every model is checked before anything is integrated (:func:`validate_system`): the class is a
``System``, its parameters have finite defaults and names that clash with nothing, its state
layout is non-empty, and ``initial_state``, ``rhs`` and ``observe`` run at the defaults and
return float arrays of the declared shapes. Failures are :class:`~stabjax.errors.ValidationError`
naming the model file and the member at fault, so the CLI exits with status 2 before writing.
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import re
import sys
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ValidationError

# dataset names a parameter may not take (they would collide in the result Dataset)
RESERVED = {"sample", "outcome", "horizon", "observable", "verdict", "t", "axis", "row", "col"}
_REF = re.compile(r"^(?P<mod>[^:]+):(?P<cls>[A-Za-z_][A-Za-z0-9_]*)$")


def _where(system_or_cls) -> str:
    """``file.py:Class`` (or ``module:Class``) of a system, for error messages."""
    cls = system_or_cls if inspect.isclass(system_or_cls) else type(system_or_cls)
    src = getattr(cls, "_stabjax_source", None)
    if src is None:
        try:
            src = inspect.getsourcefile(cls) or cls.__module__
        except TypeError:
            src = cls.__module__
    return f"{src}:{cls.__name__}"


def source_file(system) -> Path | None:
    """The file that defines the system's class (None for classes without a file)."""
    cls = type(system)
    src = getattr(cls, "_stabjax_source", None)
    if src:
        return Path(src)
    try:
        f = inspect.getsourcefile(cls)
    except TypeError:
        return None
    return Path(f) if f else None


def model_fingerprint(system) -> str:
    """sha256 of the file defining the system's class: provenance and resume identity.

    A resumed sweep or a re-plot compares it with the file on disk to detect a changed model.
    """
    f = source_file(system)
    if f is None or not f.exists():
        return "unknown"
    return hashlib.sha256(f.read_bytes()).hexdigest()


def _load_file(path: Path, cls_name: str, ref: str):
    if not path.exists():
        raise ValidationError("system", f"model file not found: {path} (from {ref!r})")
    if path.suffix != ".py":
        raise ValidationError("system", f"{path}: a model file must be a Python file (.py)")
    digest = hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
    mod_name = f"stabjax_user_{re.sub(r'[^0-9A-Za-z_]', '_', path.stem)}_{digest}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise ValidationError("system", f"{path}: cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module  # dataclasses and pickling look classes up by module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's code: any failure is reported, not raised
        sys.modules.pop(mod_name, None)
        hint = ""
        if isinstance(exc, ImportError) and "relative import" in str(exc):
            hint = "; a model file is loaded on its own: use absolute imports, or 'package.module:Class'"
        raise ValidationError("system", f"{path}: importing the model failed: {_last_line(exc)}{hint}") from None
    cls = getattr(module, cls_name, None)
    if cls is None:
        found = sorted(k for k, v in vars(module).items() if inspect.isclass(v) and v.__module__ == mod_name)
        raise ValidationError("system", f"{path}: no class {cls_name!r} (classes defined there: "
                                        f"{', '.join(found) or 'none'})")
    if inspect.isclass(cls):
        cls._stabjax_source = str(path.resolve())
    return cls


def _load_module(mod: str, cls_name: str, ref: str):
    try:
        module = importlib.import_module(mod)
    except ImportError as exc:
        raise ValidationError("system", f"cannot import module {mod!r} (from {ref!r}): {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise ValidationError("system", f"importing {mod!r} failed: {_last_line(exc)}") from None
    cls = getattr(module, cls_name, None)
    if cls is None:
        raise ValidationError("system", f"module {mod!r} has no attribute {cls_name!r}")
    return cls


def _last_line(exc: BaseException) -> str:
    """``Type: message (line N of file)``, pointing at the innermost frame outside stabjax and importlib."""
    if isinstance(exc, SyntaxError):
        return f"SyntaxError: {exc.msg} (line {exc.lineno} of {Path(exc.filename or '?').name})"
    tb = [f for f in traceback.extract_tb(exc.__traceback__)
          if "importlib" not in f.filename and f"{Path(__file__).parent}" not in f.filename]
    where = f" (line {tb[-1].lineno} of {Path(tb[-1].filename).name})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}"


def resolve(ref: Any, base_dir: str | Path | None = None):
    """A System instance from any of the accepted references (see the module docstring), checked."""
    from .registry import get_system, lookup
    from .system import System

    if isinstance(ref, System):
        return validate_system(ref)
    if inspect.isclass(ref):
        return validate_system(instantiate(ref))
    if not isinstance(ref, str) or not ref.strip():
        raise ValidationError("system", f"must be a system name, 'file.py:Class' or 'module:Class', got {ref!r}")
    ref = ref.strip()
    where = lookup(ref)
    if where == "entry point":
        return _entry_point_system(ref)
    if where is not None:
        return get_system(ref)
    m = _REF.match(ref)
    if m is None:
        return get_system(ref)  # unknown name: the registry's error lists the known ones
    mod, cls_name = m.group("mod"), m.group("cls")
    if mod.endswith(".py") or "/" in mod or "\\" in mod:
        path = Path(mod)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        # one object per unchanged file: the engines' compiled kernels are cached per system object
        key = (str(path.resolve()), cls_name, hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "")
        if key not in _loaded:
            _loaded[key] = validate_system(instantiate(_load_file(path, cls_name, ref)))
        return _loaded[key]
    cls = _load_module(mod, cls_name, ref)
    if cls not in _instances:
        _instances[cls] = validate_system(instantiate(cls))
    return _instances[cls]


def _entry_point_system(name: str):
    """An installed package's system, checked once and named as its entry point."""
    from .registry import cached, load_entry_point

    obj = cached(name)
    if obj is None:
        obj = validate_system(instantiate(load_entry_point(name)))
        obj.name = name
        cached(name, obj)
    return obj


def register(name: str, cls, *, replace: bool = False) -> None:
    """Make ``cls`` (a :class:`~stabjax.system.System` subclass) available as ``name`` in this process.

    The class is checked at once (:func:`validate_system`); a built-in name is refused, and so is an
    already registered one unless ``replace``.
    """
    from .registry import SYSTEMS, add_registered, is_registered

    if not isinstance(name, str) or not name.isidentifier():
        raise ValidationError("name", f"a system name must be an identifier, got {name!r}")
    if name in SYSTEMS:
        raise ValidationError("name", f"{name!r} is a built-in system")
    if is_registered(name) and not replace:
        raise ValidationError("name", f"{name!r} is already registered (pass replace=True)")
    obj = validate_system(instantiate(cls))
    obj.name = name
    add_registered(name, cls, obj)


_loaded: dict[tuple[str, str, str], object] = {}
_instances: dict[type, object] = {}


def instantiate(cls):
    from .system import System

    if not inspect.isclass(cls) or not issubclass(cls, System):
        what = f"class {cls.__name__}" if inspect.isclass(cls) else f"a {type(cls).__name__}"
        raise ValidationError("system", f"{_where(cls) if inspect.isclass(cls) else cls!r}: {what} is not a "
                                        "stabjax.System subclass")
    try:
        obj = cls()
    except Exception as exc:  # noqa: BLE001
        raise ValidationError("system", f"{_where(cls)}: constructing the system failed: {_last_line(exc)}") from None
    if not getattr(obj, "name", ""):
        obj.name = cls.__name__
    return obj


_checked: dict[int, object] = {}


def validate_system(system):
    """Check a system once per object: parameters, layout, shapes and dtypes of its traced methods."""
    if id(system) in _checked and _checked[id(system)] is system:
        return system
    import jax
    import jax.numpy as jnp

    from .config import setup_jax
    from .params import ParamSet
    from .system import System

    setup_jax()  # the check runs the model's JAX code: with the settings every entry point uses (float64)

    where = _where(system)
    if not isinstance(system, System):
        raise ValidationError("system", f"{where}: not a stabjax.System")
    if not isinstance(system.params, ParamSet):
        raise ValidationError(f"{where}.params", "must be a ParamSet((Param(...), ...))")
    names = [p.name for p in system.params]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValidationError(f"{where}.params", f"parameter name(s) declared twice: {', '.join(dup)}")
    clash = sorted(set(names) & RESERVED)
    if clash:
        raise ValidationError(f"{where}.params", f"parameter name(s) {', '.join(clash)} clash with dataset names "
                                                 f"({', '.join(sorted(RESERVED))}); rename them")
    for n in names:
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", n):
            raise ValidationError(f"{where}.params", f"parameter name {n!r} is not an identifier")
    try:
        defaults = system.params.defaults()
    except ValidationError as exc:
        raise ValidationError(f"{where}.params.{exc.field}", f"bad default: {exc.message}") from None
    if not system.state:
        raise ValidationError(f"{where}.state", "empty state layout; declare e.g. state = ((\"x\", ()), (\"v\", ()))")
    obs_names = tuple(system.observables)
    if not obs_names or len(set(obs_names)) != len(obs_names):
        raise ValidationError(f"{where}.observables", "must be a non-empty tuple of distinct names")
    if len(system.observable_doc) != len(obs_names):
        raise ValidationError(f"{where}.observable_doc", f"needs one line per observable ({len(obs_names)})")
    n = system.state_size
    try:
        p = system.check({k: v.copy() for k, v in defaults.items()})
    except ValidationError as exc:
        raise ValidationError(f"{where}.check", f"the defaults fail the model's own check: {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise ValidationError(f"{where}.check", f"raised {_last_line(exc)}") from None
    pj = {k: jnp.asarray(v, jnp.float64) for k, v in p.items()}

    def call(member, fn, *a):
        try:
            return fn(*a)
        except ValidationError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise ValidationError(f"{where}.{member}", f"raised {_last_line(exc)}") from None

    def expect(member, val, shape):
        arr = jnp.asarray(val) if not hasattr(val, "shape") else val
        if tuple(arr.shape) != shape:
            raise ValidationError(f"{where}.{member}", f"returned shape {tuple(arr.shape)}, expected {shape}")
        if not jnp.issubdtype(arr.dtype, jnp.floating):
            raise ValidationError(f"{where}.{member}", f"returned dtype {arr.dtype}, expected a float array")

    args = call("prepare", system.prepare, pj)
    y0 = call("initial_state", system.initial_state, pj)
    expect("initial_state", y0, (n,))
    t0 = jnp.asarray(0.0, jnp.float64)
    dy = call("rhs", system.rhs, t0, y0, args)
    expect("rhs", dy, (n,))
    ob = call("observe", system.observe, t0, y0, args)
    expect("observe", ob, (len(obs_names),))
    for member, val in (("initial_state", y0), ("rhs", dy), ("observe", ob)):
        if not np.all(np.isfinite(np.asarray(val))):
            raise ValidationError(f"{where}.{member}", f"not finite at the default parameters: {np.asarray(val)}")
    # the engines trace these functions: a Python branch on a traced value fails only under jit
    try:
        jax.eval_shape(lambda q: system.rhs(t0, system.initial_state(q), system.prepare(q)), pj)
        jax.eval_shape(lambda q: system.observe(t0, system.initial_state(q), system.prepare(q)), pj)
    except Exception as exc:  # noqa: BLE001
        raise ValidationError(f"{where}.rhs", f"cannot be traced by JAX (use jnp.where instead of Python "
                                              f"if on values): {_last_line(exc)}") from None
    outcomes = getattr(system, "outcomes", None)
    from .outcomes import VERDICTS, Outcomes

    if outcomes is not None and outcomes is not VERDICTS:
        if not isinstance(outcomes, Outcomes):
            raise ValidationError(f"{where}.outcomes", "must be a stabjax.Outcomes(...)")
        outcomes.check(system, where=f"{where}.outcomes")
    _checked[id(system)] = system
    return system
