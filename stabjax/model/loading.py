"""Systems from outside the package: load a user's model, check it, fingerprint it.

A sweep spec's ``system`` (or the first argument of :func:`stabjax.run.sweep.run_spec`,
:func:`stabjax.engines.simulate.simulate`, the plan functions) may be

* a registered name (built in, added with :func:`stabjax.register`, or installed by a package
  through the entry-point group ``stabjax.systems``);
* ``"path/to/model.py:ClassName"`` -- a file, relative to the spec file's folder (or the
  working directory when there is no spec file);
* ``"package.module:ClassName"`` -- an importable module;
* a :class:`~stabjax.model.system.System` subclass or instance (Python API).

Every model is checked before anything is integrated (:func:`validate_system`): the class is a
``System``, its parameters have finite defaults and names that clash with nothing, its state
layout is non-empty, and ``initial_state``, ``rhs`` and ``observe`` run at the defaults and
return float arrays of the declared shapes. Failures are :class:`~stabjax.errors.ValidationError`
naming the model file and the member at fault, so the CLI exits with status 2 before writing.
"""
from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib
import importlib.util
import inspect
import math
import os
import re
import signal
import site
import sys
import sysconfig
import threading
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ValidationError

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


MODEL_TIMEOUT_ENV = "STABJAX_MODEL_TIMEOUT"
DEFAULT_MODEL_TIMEOUT = 120.0  # seconds: importing a model, or constructing, running and tracing its members


class _ModelTimeout(BaseException):
    """Raised inside the model's code by the time limit (a BaseException, so that a model's own
    ``except Exception`` does not swallow it)."""


def model_timeout() -> float | None:
    """The time limit of model loading from ``$STABJAX_MODEL_TIMEOUT`` (seconds; 0: none)."""
    raw = os.environ.get(MODEL_TIMEOUT_ENV, "").strip()
    if not raw:
        return DEFAULT_MODEL_TIMEOUT
    try:
        v = float(raw)
    except ValueError:
        v = float("nan")
    if not math.isfinite(v) or v < 0:
        raise ValidationError(MODEL_TIMEOUT_ENV, f"must be a number of seconds >= 0 (0: no limit), got {raw!r}")
    return v or None


class _ModelExit(Exception):
    """The model's code called ``os._exit``."""


@contextlib.contextmanager
def no_exit():
    """While the block runs, ``os._exit`` in this process raises :class:`_ModelExit` instead of ending it.

    Why: ``os._exit`` ends the process at once, past every ``except``, ``finally`` and exit handler,
    with the status the model chose; a model calling ``os._exit(0)`` would make the command exit 0
    with nothing written, which reads as success. ``sys.exit`` needs no guard (it raises SystemExit,
    reported by :func:`_last_line`). A process forked inside the block (another pid) exits as usual,
    since its ``os._exit`` is how multiprocessing ends a child."""
    real = os._exit
    if getattr(real, "_stabjax_no_exit", False):  # nested: the outer guard stays
        yield
        return
    pid = os.getpid()

    def guarded(status):
        if os.getpid() != pid:
            real(status)
        raise _ModelExit(f"it called os._exit({status!r}); a model must not end the program")

    guarded._stabjax_no_exit = True
    os._exit = guarded
    try:
        yield
    finally:
        os._exit = real


@contextlib.contextmanager
def time_limit(what: str, where: str):
    """Run the block under :func:`model_timeout`; past it, a ValidationError naming ``where``.

    Why SIGALRM and not a thread: Python cannot stop a thread, so a model stuck in a loop would go
    on running (and holding the import lock of its module) after the error was reported, and a
    Ctrl-C would then hang at exit. The alarm raises inside the stuck code itself, which unwinds
    it. Limits of the choice: it needs the main thread of a POSIX process (elsewhere, e.g. on a Dask
    worker thread, the block runs unlimited; the client has loaded the same model under the limit
    already), and a loop inside a C extension that never returns to Python is not interrupted.
    """
    limit = model_timeout()
    if limit is None or not hasattr(signal, "setitimer") or threading.current_thread() is not threading.main_thread():
        with no_exit():
            yield
        return
    active = [True]

    def on_alarm(signum, frame):
        if active[0]:
            raise _ModelTimeout()

    previous = signal.signal(signal.SIGALRM, on_alarm)
    outer, _ = signal.setitimer(signal.ITIMER_REAL, limit)  # a limit around this one (nested loads) resumes after
    t0 = time.monotonic()
    try:
        with no_exit():
            yield
        active[0] = False
    except _ModelTimeout:
        raise ValidationError("system", f"{where}: {what} did not finish within {limit:g} s (a loop that never "
                                        f"ends, or waiting for input?); set {MODEL_TIMEOUT_ENV} to allow longer"
                              ) from None
    finally:
        active[0] = False
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if outer > 0:
            signal.setitimer(signal.ITIMER_REAL, max(outer - (time.monotonic() - t0), 1e-3))


def _is_model_error(exc: BaseException) -> bool:
    """Anything the model's code raises is reported as a model error (``sys.exit()`` included: loading
    a model must not end the program), except a Ctrl-C and our own time limit."""
    return not isinstance(exc, (KeyboardInterrupt, _ModelTimeout, ValidationError))


@functools.lru_cache(maxsize=1)
def _installed_roots() -> tuple[Path, ...]:
    """Folders whose modules are not the user's: the standard library, the installed packages and
    stabjax itself (its version is part of the identity)."""
    paths = sysconfig.get_paths()
    roots = {paths.get(k) for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    with contextlib.suppress(AttributeError):
        roots |= set(site.getsitepackages())
    with contextlib.suppress(AttributeError):
        roots.add(site.getusersitepackages())
    roots.add(str(Path(sys.modules[__package__.partition(".")[0]].__file__).parent))  # the stabjax package
    return tuple(Path(os.path.realpath(r)) for r in roots if r)


def _local_file(module) -> str | None:
    """The source file of a module that is the user's own (outside :func:`_installed_roots`), else None."""
    f = getattr(module, "__file__", None)
    if not f or not f.endswith(".py") or not os.path.isfile(f):
        return None
    real = Path(os.path.realpath(f))
    if any(real.is_relative_to(r) for r in _installed_roots()):
        return None
    return str(real)


@functools.lru_cache(maxsize=64)
def _imported_names(source: bytes) -> frozenset[str]:
    """Absolute module names a source file imports (``import a.b`` -> a, a.b; ``from a import b`` -> a, a.b).
    Remembered by content: every sweep's provenance asks again of the same files (a class defined in a long
    module, a test file, parsed once per plan)."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return frozenset()
    out: set[str] = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for n in names:
            parts = n.split(".")
            out.update(".".join(parts[: i + 1]) for i in range(len(parts)))
    return frozenset(out)


def _local_imports(new_modules: set[str], model_source: bytes) -> dict[str, str]:
    """module name -> file of every local module the model imported: those that appeared in
    ``sys.modules`` while it loaded, and those it (or one of them) imports by name that were
    already loaded before it."""
    found: dict[str, str] = {}
    for name in new_modules:
        f = _local_file(sys.modules.get(name))
        if f:
            found[name] = f
    todo = [model_source] + [Path(f).read_bytes() for f in found.values()]
    while todo:
        for name in _imported_names(todo.pop()):
            if name in found or name not in sys.modules:
                continue
            f = _local_file(sys.modules[name])
            if f:
                found[name] = f
                todo.append(Path(f).read_bytes())
    return found


_model_imports: dict[str, set[str]] = {}  # model file -> local module names it imported when last loaded


def _load_file(path: Path, cls_name: str, ref: str):
    """Import a model file as a module of its own, with its folder on the import path (a model may
    import a module beside it), under :func:`time_limit`; record the sha256 of the executed source
    and of every local module it imported on the class (``_stabjax_sources``: the identity)."""
    if not path.exists():
        raise ValidationError("system", f"model file not found: {path} (from {ref!r})")
    if path.is_dir():
        raise ValidationError("system", f"{path} is a folder: a model is given as 'file.py:Class' (from {ref!r})")
    if path.suffix != ".py":
        raise ValidationError("system", f"{path}: a model file must be a Python file (.py)")
    path = path.resolve()
    try:
        source = path.read_bytes()
    except OSError as exc:
        raise ValidationError("system", f"{path}: cannot read the model file ({exc})") from None
    if b"\0" in source:
        raise ValidationError("system", f"{path}: not a Python source file (it holds NUL bytes)")
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:12]
    mod_name = f"stabjax_user_{re.sub(r'[^0-9A-Za-z_]', '_', path.stem)}_{digest}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise ValidationError("system", f"{path}: cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    # local modules are imported afresh for each load: those an earlier model load imported (an
    # edited helper must not be served from this process's module cache) and any module named like a
    # file beside this model (another model's ``helpers`` must not stand in for this one's)
    beside = {p.stem for p in path.parent.glob("*.py")} | {p.parent.name for p in path.parent.glob("*/__init__.py")}
    stale = set().union(*_model_imports.values()) if _model_imports else set()
    for name in list(sys.modules):
        if name in stale or name.split(".")[0] in beside and _local_file(sys.modules[name]):
            sys.modules.pop(name, None)
    before = set(sys.modules)
    sys.modules[mod_name] = module  # dataclasses and pickling look classes up by module
    folder = str(path.parent)
    sys.path.insert(0, folder)
    try:
        with time_limit("importing the model", str(path)):
            exec(compile(source, str(path), "exec"), module.__dict__)  # the bytes hashed are the bytes run
    except BaseException as exc:  # noqa: BLE001 - the user's code: any failure is reported, not raised
        sys.modules.pop(mod_name, None)
        if isinstance(exc, ValidationError) and not str(exc.message).startswith(str(path)):
            # a declaration stabjax refused while the file ran (a Param's kind misspelt): the file and line named
            tb = [f for f in traceback.extract_tb(exc.__traceback__) if f.filename == str(path)]
            at = f" (line {tb[-1].lineno})" if tb else ""
            raise ValidationError(exc.field, f"{path}{at}: {exc.message}") from None
        if not _is_model_error(exc):
            raise
        hint = ""
        if isinstance(exc, ImportError) and "relative import" in str(exc):
            hint = "; a model file is loaded on its own: use absolute imports, or 'package.module:Class'"
        raise ValidationError("system", f"{path}: importing the model failed: {_last_line(exc)}{hint}") from None
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(folder)
    imports = _local_imports(set(sys.modules) - before - {mod_name}, source)
    _model_imports[str(path)] = set(imports)
    cls = getattr(module, cls_name, None)
    if cls is None:
        found = sorted(k for k, v in vars(module).items() if inspect.isclass(v) and v.__module__ == mod_name)
        raise ValidationError("system", f"{path}: no class {cls_name!r} (classes defined there: "
                                        f"{', '.join(found) or 'none'})")
    _require_class(cls, f"{path}: {cls_name}")
    if inspect.isclass(cls):
        cls._stabjax_source = str(path)
        sources = {str(path): hashlib.sha256(source).hexdigest()}
        for f in sorted(set(imports.values())):
            with contextlib.suppress(OSError):
                sources[f] = hashlib.sha256(Path(f).read_bytes()).hexdigest()
        cls._stabjax_sources = sources
    return cls


def _sources_unchanged(system) -> bool:
    """Whether every source file recorded for a loaded model still has its recorded hash."""
    for f, sha in getattr(type(system), "_stabjax_sources", {}).items():
        try:
            if hashlib.sha256(Path(f).read_bytes()).hexdigest() != sha:
                return False
        except OSError:
            return False
    return True


def local_sources(cls, new_modules: set[str] = frozenset()) -> dict[str, str]:
    """``{path: sha256}`` of a class's defining file and the local modules it imports, when that file
    is the user's own (outside the installed packages; ``{}`` otherwise: an installed package is
    identified by its version). For classes not loaded from a model file (``module:Class``, a class
    given in Python); ``new_modules``: modules that appeared while its module was imported."""
    module = sys.modules.get(getattr(cls, "__module__", ""), None)
    f = _local_file(module)
    if f is None:
        return {}
    try:
        source = Path(f).read_bytes()
    except OSError:
        return {}
    imports = _local_imports(set(new_modules) - {module.__name__}, source)
    out = {f: hashlib.sha256(source).hexdigest()}
    for g in sorted(set(imports.values()) - {f}):
        with contextlib.suppress(OSError):
            out[g] = hashlib.sha256(Path(g).read_bytes()).hexdigest()
    return out


def _load_module(mod: str, cls_name: str, ref: str):
    before = set(sys.modules)
    try:
        with time_limit("importing the model", mod):
            module = importlib.import_module(mod)
    except ImportError as exc:
        raise ValidationError("system", f"cannot import module {mod!r} (from {ref!r}): {exc}") from None
    except BaseException as exc:  # noqa: BLE001
        if not _is_model_error(exc):
            raise
        raise ValidationError("system", f"importing {mod!r} failed: {_last_line(exc)}") from None
    cls = getattr(module, cls_name, None)
    if cls is None:
        raise ValidationError("system", f"module {mod!r} has no attribute {cls_name!r}")
    _require_class(cls, f"{mod}:{cls_name}")
    if inspect.isclass(cls) and "_stabjax_sources" not in vars(cls):
        src = local_sources(cls, set(sys.modules) - before)
        if src:
            cls._stabjax_sources = src
    return cls


def _require_class(obj, where: str) -> None:
    """A model reference names a class; ``X = 5`` in the file is refused with the name the user wrote."""
    if not inspect.isclass(obj):
        shown = repr(obj)
        kind = type(obj).__name__
        raise ValidationError("system", f"{where} is {'an' if kind[0] in 'aeiou' else 'a'} {kind} "
                                        f"({shown if len(shown) <= 40 else shown[:37] + '...'}), "
                                        "not a class: a model is a stabjax.System subclass")


def _last_line(exc: BaseException) -> str:
    """``Type: message (line N of file)``, pointing at the innermost frame outside stabjax and importlib."""
    if isinstance(exc, SystemExit):
        return f"it called sys.exit({exc.code!r}); loading a model must not end the program"
    if isinstance(exc, _ModelExit):
        tb = [f for f in traceback.extract_tb(exc.__traceback__) if f"{Path(__file__).parent}" not in f.filename]
        return f"{exc}" + (f" (line {tb[-1].lineno} of {Path(tb[-1].filename).name})" if tb else "")
    if isinstance(exc, SyntaxError):
        if exc.lineno is None:
            return f"SyntaxError: {exc.msg}"
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
    path = Path(mod)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    # an existing file ('notes.txt:X') or a relative path ('.:X') is a file reference, refused by _load_file as not a
    # .py file, rather than a module name that importlib misreads ('No module named notes', a relative import)
    if mod.endswith(".py") or "/" in mod or "\\" in mod or mod.startswith(".") or path.is_file():
        # one object per unchanged model (its file and the local modules it imports): the engines'
        # compiled kernels are cached per system object
        key = (str(path.resolve()), cls_name)
        if key not in _loaded or not _sources_unchanged(_loaded[key]):
            _loaded.pop(key, None)
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
    """Make ``cls`` (a :class:`~stabjax.model.system.System` subclass) available as ``name`` in this process.

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


_loaded: dict[tuple[str, str], object] = {}
_instances: dict[type, object] = {}


def instantiate(cls):
    from .system import System

    if not inspect.isclass(cls) or not issubclass(cls, System):
        what = f"class {cls.__name__}" if inspect.isclass(cls) else f"a {type(cls).__name__}"
        raise ValidationError("system", f"{_where(cls) if inspect.isclass(cls) else cls!r}: {what} is not a "
                                        "stabjax.System subclass")
    try:
        with time_limit("constructing the system", _where(cls)):
            obj = cls()
    except BaseException as exc:  # noqa: BLE001
        if not _is_model_error(exc):
            raise
        raise ValidationError("system", f"{_where(cls)}: constructing the system failed: {_last_line(exc)}") from None
    if not getattr(obj, "name", ""):
        obj.name = cls.__name__
    return obj


_checked: dict[int, object] = {}


def validate_system(system):
    """Check a system once per object: parameters, layout, shapes and dtypes of its traced methods."""
    if id(system) in _checked and _checked[id(system)] is system:
        return system
    with time_limit("checking the model (running and tracing its members)", _where(system)):
        _validate(system)
    _checked[id(system)] = system
    return system


def _same_name_same_value(system, where: str, obs_names, y0: np.ndarray, ob: np.ndarray, observe) -> None:
    """An observable may share a state component's name only by observing that component (the pendulum's
    omega): a trajectory's dataset (``stabjax simulate``, the viewer's replay) holds one variable per name, and
    the observable silently replaced the state (x observed as 2x read back as the state x). Checked at the
    default initial state and at a second state, so that an observable equal to its component at one point
    only (x**2 at x = 1) is caught too."""
    parts = system.unpack(y0)
    clash = [o for o in obs_names if o in parts]
    if not clash:
        return
    y1 = y0 * 1.37 + 0.29
    ob1, parts1 = observe(y1), system.unpack(y1)
    for o in clash:
        j = obs_names.index(o)
        scalar = np.shape(parts[o]) == ()  # a vector component is never one observable
        if not scalar or ob[j] != parts[o] or ob1[j] != parts1[o]:
            state = f"{float(parts[o]):g}" if scalar else "a vector"
            raise ValidationError(f"{where}.observables", f"observable {o!r} has the name of a state component but "
                                                          f"observes something else ({o} = {state} in the state, "
                                                          f"{ob[j]:g} observed at the defaults): rename it")


def _validate(system):
    import jax
    import jax.numpy as jnp

    from ..config import setup_jax
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
    from .system import System

    if type(system).observable_doc is System.observable_doc and obs_names != tuple(System.observables):
        # its own observables under the base class's descriptions ("error metric", "size") labelled x and y so in
        # `stabjax systems`, simulate and the figures: described by their names instead
        system.observable_doc = obs_names
    if len(system.observable_doc) != len(obs_names):
        raise ValidationError(f"{where}.observable_doc", f"needs one line per observable ({len(obs_names)})")
    n = system.state_size
    try:
        p = system.check({k: v.copy() for k, v in defaults.items()})
    except ValidationError as exc:
        raise ValidationError(f"{where}.check", f"the defaults fail the model's own check: {exc}") from None
    except BaseException as exc:  # noqa: BLE001
        if not _is_model_error(exc):
            raise
        raise ValidationError(f"{where}.check", f"raised {_last_line(exc)}") from None
    pj = {k: jnp.asarray(v, jnp.float64) for k, v in p.items()}

    def call(member, fn, *a):
        return _member_call(where, member, fn, *a)

    def expect(member, val, shape):
        arr = jnp.asarray(val) if not hasattr(val, "shape") else val
        if tuple(arr.shape) != shape:
            raise ValidationError(f"{where}.{member}", f"returned shape {tuple(arr.shape)}, expected {shape}")
        if not jnp.issubdtype(arr.dtype, jnp.floating):
            raise ValidationError(f"{where}.{member}", f"returned dtype {arr.dtype}, expected a float array")
        if arr.dtype != jnp.float64:  # the engines' arithmetic mixes it with float64 state: a traceback there
            raise ValidationError(f"{where}.{member}", f"returned dtype {arr.dtype}; stabjax integrates in float64: "
                                                       "compute in float64 (no astype(float32), no float32 arrays)")

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
    _same_name_same_value(system, where, obs_names, np.asarray(y0), np.asarray(ob),
                          lambda y: np.asarray(call("observe", system.observe, t0, jnp.asarray(y), args)))
    # the engines trace these functions: a Python branch on a traced value fails only under jit
    try:
        jax.eval_shape(lambda q: system.rhs(t0, system.initial_state(q), system.prepare(q)), pj)
        jax.eval_shape(lambda q: system.observe(t0, system.initial_state(q), system.prepare(q)), pj)
    except BaseException as exc:  # noqa: BLE001
        if not _is_model_error(exc):
            raise
        raise ValidationError(f"{where}.rhs", f"cannot be traced by JAX (use jnp.where instead of Python "
                                              f"if on values): {_last_line(exc)}") from None
    outcomes = getattr(system, "outcomes", None)
    from .outcomes import VERDICTS, Outcomes

    if outcomes is not None and outcomes is not VERDICTS:
        if not isinstance(outcomes, Outcomes):
            raise ValidationError(f"{where}.outcomes", "must be a stabjax.Outcomes(...)")
        outcomes.check(system, where=f"{where}.outcomes")
    _check_theory(system, where, p)


def _member_call(where: str, member: str, fn, *a, said: str = ""):
    """A model member called by the check: an exception of the model's own code is an error naming the member."""
    try:
        return fn(*a)
    except ValidationError:
        raise
    except BaseException as exc:  # noqa: BLE001
        if not _is_model_error(exc):
            raise
        raise ValidationError(f"{where}.{member}", f"raised {_last_line(exc)}{said}") from None


def _check_theory(system, where: str, p: dict[str, np.ndarray]) -> None:
    """The theorems on a batch of two trajectories at the defaults: a stabjax.Theory whose predicates and derived
    quantities give one value per trajectory (or one for all), and whose ``main`` is one of its predicates. A wrong
    theory() was a traceback after the first chunk had been integrated (a store left behind), or a result naming a
    main theorem it does not have."""
    from .system import Predicate, Theory

    batch = {k: np.broadcast_to(np.asarray(v), (2, *np.shape(v))).copy() for k, v in p.items()}
    th = _member_call(where, "theory", system.theory, batch, said=" at the default parameters")
    if not isinstance(th, Theory):
        raise ValidationError(f"{where}.theory", f"returned a {type(th).__name__}; expected a stabjax.Theory("
                                                 "predicates={name: Predicate(ok, margin, doc)}, ...)")
    values = [(f"predicates.{k}.{part}", getattr(v, part, None)) for k, v in th.predicates.items()
              for part in ("ok", "margin")]
    for k, v in th.predicates.items():
        if not isinstance(v, Predicate):
            raise ValidationError(f"{where}.theory", f"predicate {k!r} is a {type(v).__name__}; expected a "
                                                     "stabjax.Predicate(ok, margin, doc)")
    for name, v in values + [(f"derived.{k}", v) for k, v in th.derived.items()]:
        try:
            np.broadcast_to(np.asarray(v, dtype=float), (2,))
        except (TypeError, ValueError):
            raise ValidationError(f"{where}.theory", f"{name} has shape {np.shape(v)} for a batch of 2 "
                                                     "trajectories: give one value per trajectory (shape (2,)) or "
                                                     "one for all") from None
    if th.main and th.main not in th.predicates:
        raise ValidationError(f"{where}.theory", f"main = {th.main!r} is not one of its predicates "
                                                 f"({', '.join(th.predicates) or 'none'})")
    _check_guaranteed_outcomes(system, where, th)


def _check_guaranteed_outcomes(system, where: str, th) -> None:
    """A predicate's ``outcome`` names one of the model's declared outcomes (its rules or templates): a
    misspelt one would count no red flag ever. A model that declares none (its attractors discovered) may still
    name one, which a spec's ``[outcomes]`` table declares; a result without that outcome says so and counts
    nothing (:func:`stabjax.mapping.basin.theory_agreement`)."""
    from .outcomes import Outcomes

    said = {k: v.outcome for k, v in th.predicates.items() if getattr(v, "outcome", "")}
    outcomes = getattr(system, "outcomes", None)
    if not said or not isinstance(outcomes, Outcomes):
        return
    names = (*outcomes.rules, *outcomes.templates)
    for k, o in said.items():
        if not isinstance(o, str) or o not in names:
            raise ValidationError(f"{where}.theory", f"predicate {k!r} guarantees outcome {o!r}, which is not one "
                                                     f"of the model's outcomes ({', '.join(names)})")
