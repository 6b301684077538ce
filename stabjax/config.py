"""Settings as immutable values: the ``[integrate]`` and ``[verdict]`` tables, JAX setup (solver status codes: :mod:`stabjax.fold.status`).

Nothing here imports an engine (or diffrax): the spec loader (:mod:`stabjax.plan.spec`) validates a
spec with this module alone. The solver names are plain strings; the diffrax engine
(:mod:`stabjax.engines.diffrax_engine`) maps them to diffrax classes.

JAX's global settings (float64, one CPU device per core, equinox's error mode) are changed by
:func:`setup_jax`, which the command line and the documented entry points (``run_spec``,
``run_plan``, ``simulate``, ``solve_batch``) call; importing :mod:`stabjax` changes nothing.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from .errors import ValidationError

# explicit Runge-Kutta pairs and (kvaerno*) L-stable ESDIRK methods for stiff systems; only tsit5
# runs on the native and fused engines, the others on the diffrax engine
SOLVERS = ("tsit5", "dopri5", "dopri8", "heun", "bosh3", "kvaerno5", "kvaerno3")

# per-trajectory ``solver_status`` codes and what they mean: stabjax.fold.status (one definition)
# the verdicts' names, code = index (stabjax.fold.verdict holds the rules)
VERDICT_NAMES = ("converged", "flipped", "diverged", "undecided", "failed")


@dataclass(frozen=True)
class VerdictConfig:
    """Thresholds and windows of the excursion classifier (:mod:`stabjax.fold.verdict`). Angles in radians.

    settle_tol      error below which the trajectory counts as settled near the target
    excursion_tol   after settling, a run of checkpoints with error above this is an excursion
                    (default acos(0.9): the paper-A analysis counts s.r < 0.9)
    flip_tol        an excursion whose peak passes this has flipped (pi/2: closer to -r than to r)
    converged_tol   the error throughout the late window must be below this to converge
    late_fraction   (unused by the generic classifier since the log-time windows; kept for
                    system-specific classifiers, e.g. the gyrodyne's linear late window)
    diverge_size    observable 1 (size) above this -> diverged
    growth_tol      late log-log slope of the error above this (error growing) -> diverged
    floor_tol       errors below this are at the solver's noise floor (~rtol): their log-log trend
                    is noise; not used against convergence, nor in the decay fit
    late_decades    the late window of a horizon T is the last ``late_decades`` decades of it in
                    log-time: t - t0 >= (T - t0) 10^-late_decades (horizon-independent shape)
    converge_decades  the error must stay below converged_tol (and not grow) over the last this many
                    decades of the horizon in log-time (after settling); half a decade: a decay crosses
                    converged_tol once, recurrent bumps are the excursion rules' business (a decade)
    shrink_ratio    two successive excursion peaks with peak_last >= shrink_ratio * peak_prev
                    "do not shrink" (recurrent instability: never converged)
    fit_decades     the decay exponent is fitted over this many decades (log-time, multiple of
                    1/2) ending at the last checkpoint above floor_tol
    fit_min_points  fewer points above the noise floor in that tail -> decay exponent NaN
    horizons        times at which verdicts are also given (prefixes of the same run); () = t1 and
                    the ``n_horizon_decades`` decades below it. :func:`stabjax.fold.verdict.bind` fixes
                    them (with t0, t1) when a plan is made; the last horizon is always t1
    n_horizon_decades  default horizons: t0 + (t1 - t0) 10^-k, k = n_horizon_decades .. 0
    features        also return feat_max/min/mean/std/final of each observable (stabjax.fold.verdict)
    feature_window  features over t >= t0 + (1 - feature_window)(t1 - t0)
    verdicts        fold the attitude classifier's state (verdicts at every horizon, decay fits); False
                    where the outcomes are named (rules, templates, discovery): only the features are
                    folded, so a checkpoint costs a few operations per observable instead of ~160 entries
                    of state read and written (set by the plan, not by a spec)
    t0, t1, n_obs   bound by :func:`stabjax.fold.verdict.bind` (None/0: unbound; the fold assumes t0 = 0)
    """

    settle_tol: float = 0.1
    excursion_tol: float = float(np.arccos(0.9))
    flip_tol: float = float(np.pi / 2)
    converged_tol: float = 1e-3
    late_fraction: float = 0.5
    diverge_size: float = 1e6
    growth_tol: float = 0.5
    floor_tol: float = 1e-6
    late_decades: float = 1.0
    converge_decades: float = 0.5
    shrink_ratio: float = 1.0
    fit_decades: float = 1.0
    fit_min_points: float = 8
    horizons: tuple = ()
    n_horizon_decades: float = 3
    features: bool = False
    feature_window: float = 0.5
    verdicts: bool = True
    t0: float | None = None
    t1: float | None = None
    n_obs: int = 0

    def replace(self, **kw) -> "VerdictConfig":
        return replace(self, **kw)


class Settings(Mapping):
    """Engine settings as an immutable, hashable mapping (``IntegrateConfig.settings``). This module
    knows none of their names: the engines declare them and check them
    (:data:`stabjax.engines.SETTINGS`); the layers between pass them on."""

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | None = None, **kw):
        self._items = tuple(sorted({**dict(items or {}), **kw}.items()))

    def __getitem__(self, k):
        for name, v in self._items:
            if name == k:
                return v
        raise KeyError(k)

    def __iter__(self):
        return (k for k, _ in self._items)

    def __len__(self):
        return len(self._items)

    def __hash__(self):
        return hash(self._items)

    def __eq__(self, other):
        return isinstance(other, Mapping) and dict(self) == dict(other)

    def __repr__(self):
        return f"Settings({dict(self._items)!r})"

    def __reduce__(self):
        return Settings, (dict(self._items),)

    def __deepcopy__(self, memo):  # immutable (dataclasses.asdict deep-copies field values)
        return self


@dataclass(frozen=True)
class IntegrateConfig:
    """The ``[integrate]`` table of a sweep spec.

    ``engine``: "auto" or the name of an engine (:data:`stabjax.engines.CHOICES`; the engines
    package checks it and says what a name falls back to). ``settings``: the engines' own tuning
    settings (a :class:`Settings`; a dict is converted), declared and checked by the engines
    (:data:`stabjax.engines.SETTINGS`), read by none of the layers between.

    ``escape_radius``: stop a trajectory as soon as an accepted state has max_i |y_i| above it
    (status :data:`stabjax.fold.status.ESCAPED`); None: the system's :attr:`stabjax.model.system.System.escape_radius`.

    ``early_stop``: stop a trajectory once it sits at a stable equilibrium (:mod:`stabjax.fold.stops`;
    autonomous models only). None: decided per plan -- on where it cannot change an outcome (named
    outcomes or discovery on an autonomous model), off elsewhere and for a config used without a
    plan; true where the attitude verdicts are the outcomes is refused (their decay laws need the run
    up to t1).

    ``attractor_stop``: also stop a trajectory once it has stayed near an attractor this run has already
    found, for a feature window's length (:mod:`stabjax.fold.stops`, the recurrence stop; off by default: a
    heuristic, refused where it cannot apply). ``known_attractors``: the set the engines test (set by the
    runner from the run's own first trajectories, never by a spec).
    """

    t1: float = 1.0e4
    t0: float = 0.0
    solver: str = "tsit5"
    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = 2_000_000
    n_checkpoints: int = 2000
    dt0: float | None = None
    engine: str = "auto"
    escape_radius: float | None = None
    early_stop: bool | None = None
    attractor_stop: bool = False
    settings: Settings = Settings()
    known_attractors: Any = None

    def __post_init__(self):
        if not isinstance(self.settings, Settings):
            object.__setattr__(self, "settings", Settings(self.settings))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None, *, section: str = "integrate", default_t1: float | None = None):
        """From a spec table: every field checked for its type (``section.field`` named), then :meth:`validate`."""
        from .validate import record_from_dict

        d = dict(d or {})
        if "settings" in d:  # engine settings come through stabjax.engines.integrate_config, checked there
            raise ValidationError(f"{section}.settings", "engine settings are keys of [engine] (or [integrate]), "
                                                         "not a table named settings")
        if "known_attractors" in d:  # the runner's, found from the run itself
            raise ValidationError(f"{section}.known_attractors", "unknown field (set by the runner, not by a spec); "
                                                                 "ask for the stop with attractor_stop = true")
        if "t1" not in d and default_t1 is not None:
            d["t1"] = default_t1
        cfg = record_from_dict(cls, d, section)
        cfg.validate(section)
        return cfg

    def validate(self, section: str = "integrate"):
        from .validate import integer, number

        # types first (the dataclass itself is also built from Python code, not only from specs)
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("solver", "engine", "settings", "early_stop", "known_attractors") or (v is None and f.default is None):
                continue
            if isinstance(f.default, bool):
                if not isinstance(v, (bool, np.bool_)):
                    raise ValidationError(f"{section}.{f.name}", f"must be true or false, got {v!r}")
            elif isinstance(f.default, int):
                integer(v, f"{section}.{f.name}")
            elif isinstance(f.default, float) or f.default is None:
                number(v, f"{section}.{f.name}")
        number(self.t0, f"{section}.t0")
        if not np.isfinite(self.t1) or not self.t1 > self.t0:
            raise ValidationError(f"{section}.t1", f"must be finite and > t0 = {self.t0}, got {self.t1}")
        if not isinstance(self.solver, str) or self.solver not in SOLVERS:
            raise ValidationError(f"{section}.solver", f"unknown solver {self.solver!r}; choose from {', '.join(SOLVERS)}")
        for name in ("rtol", "atol"):
            v = getattr(self, name)
            if not (v > 0 and v < 1):
                raise ValidationError(f"{section}.{name}", f"must be in (0, 1), got {v}")
        # 2^31 - 1: more than any trajectory can take in a run that finishes, and within every engine's counters
        integer(self.max_steps, f"{section}.max_steps", lo=1, hi=2**31 - 1)
        integer(self.n_checkpoints, f"{section}.n_checkpoints", lo=8, hi=200_000)
        if self.dt0 is not None and not (self.dt0 > 0 and self.dt0 <= self.t1 - self.t0):
            raise ValidationError(f"{section}.dt0", f"must be in (0, t1 - t0], got {self.dt0}")
        if not isinstance(self.engine, str):  # which names exist: stabjax.engines.check_choice
            raise ValidationError(f"{section}.engine", f"must be an engine's name, got {self.engine!r}")
        if self.early_stop is not None and not isinstance(self.early_stop, (bool, np.bool_)):
            raise ValidationError(f"{section}.early_stop", f"must be true or false, got {self.early_stop!r}")
        if self.escape_radius is not None and not (np.isfinite(self.escape_radius) and self.escape_radius > 0):
            raise ValidationError(f"{section}.escape_radius", f"must be a finite number > 0, got {self.escape_radius}")

    def replace(self, **kw) -> "IntegrateConfig":
        return replace(self, **kw)

    def checkpoints(self) -> np.ndarray:
        """Half log-spaced (early power-law transients), half linear (late excursions); includes t1."""
        k = self.n_checkpoints
        span = self.t1 - self.t0
        lin = np.linspace(self.t0, self.t1, k - k // 2)
        log = self.t0 + np.logspace(np.log10(span * 1e-5), np.log10(span), k // 2)
        ts = np.unique(np.concatenate([lin, log]))
        ts[-1] = self.t1
        return ts


def escape_radius(system, icfg: IntegrateConfig) -> float | None:
    """The radius in force: the ``[integrate]`` table's, else the system's (None: no escape stop)."""
    r = icfg.escape_radius if icfg.escape_radius is not None else system.escape_radius
    return None if r is None else float(r)


def verdict_config(system, overrides: Mapping[str, Any] | None = None, section: str = "verdict") -> VerdictConfig:
    """The system's thresholds with the spec's ``[verdict]`` overrides, each checked (``verdict.<name>``)."""
    from .validate import check_verdict, record_from_dict

    if overrides and "verdicts" in overrides:  # the plan's decision (named outcomes or the attitude verdicts)
        raise ValidationError(f"{section}.verdicts", "unknown threshold (the plan decides whether the attitude "
                                                     "classifier runs: it does for systems judged by verdicts)")
    cfg = record_from_dict(VerdictConfig, overrides, section, base=system.verdict, what="threshold")
    check_verdict(cfg, section)
    return cfg


def versions() -> dict[str, str]:
    """Library versions recorded with every result (read from the installed packages' metadata:
    importing diffrax, for its version alone, took a second of every run that never used it)."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    import jax
    import xarray as xr

    from .version import __version__

    try:
        dfx = version("diffrax")
    except PackageNotFoundError:  # pragma: no cover - a source tree without metadata
        import diffrax

        dfx = diffrax.__version__
    return {"stabjax": __version__, "jax": jax.__version__, "diffrax": dfx,
            "numpy": np.__version__, "xarray": xr.__version__, "python": platform.python_version()}


_SETUP: dict[str, bool] = {}

_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def env_int(name: str, lo: int = 1, hi: int = 4096) -> int | None:
    """An integer environment variable (None when unset or empty), refused naming it otherwise:
    ``STABJAX_THREADS=abc`` used to be ignored without a word."""
    raw = os.environ.get(name, "").strip()
    if not raw:
        return None
    try:
        n = int(raw)
    except ValueError:
        raise ValidationError(name, f"must be an integer from {lo} to {hi}, got {raw!r}") from None
    if not lo <= n <= hi:
        raise ValidationError(name, f"must be an integer from {lo} to {hi}, got {n}")
    return n


def env_seconds(name: str, default: float) -> float:
    """A time in seconds from an environment variable (``default`` when unset or empty): a finite number >= 0,
    refused naming it otherwise (``STABJAX_PROGRESS_INTERVAL=abc`` was a traceback after the store was made)."""
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        v = float(raw)
    except ValueError:
        raise ValidationError(name, f"must be a number of seconds >= 0, got {raw!r}") from None
    if not (v >= 0 and v < float("inf")):
        raise ValidationError(name, f"must be a finite number of seconds >= 0, got {raw!r}")
    return v


def check_environment() -> None:
    """Validate every environment variable stabjax reads, each error naming the variable.

    ``STABJAX_X64`` (float64 only: 1/true/yes/on or unset; float32 is refused, see :func:`x64_wanted`),
    ``STABJAX_THREADS`` and ``STABJAX_CPU_DEVICES`` (positive integers; empty: unset),
    ``STABJAX_PROGRESS_INTERVAL`` (seconds between progress lines, a finite number >= 0; empty: 5),
    ``STABJAX_CACHE_DIR`` (not an existing file; empty: the default), ``CC`` (a program on PATH),
    ``EQX_ON_ERROR`` (``nan``: a solver error must become a status code, not an exception). Variables read by JAX, XLA and CUDA
    themselves (``XLA_FLAGS``, ``CUDA_VISIBLE_DEVICES``, ``JAX_*``) are theirs to check.
    """
    import shutil

    x64_wanted()
    env_int("STABJAX_THREADS")
    env_int("STABJAX_CPU_DEVICES", hi=64)
    env_seconds("STABJAX_PROGRESS_INTERVAL", 5.0)
    cache = os.environ.get("STABJAX_CACHE_DIR", "").strip()
    if cache:  # empty: the default, as the native engine and the Dask cache read it
        from pathlib import Path

        p = Path(cache).expanduser()
        if p.exists() and not p.is_dir():
            raise ValidationError("STABJAX_CACHE_DIR", f"{cache} exists and is not a directory")
    cc = os.environ.get("CC")
    if cc is not None and cc.strip() and shutil.which(cc.strip()) is None:
        raise ValidationError("CC", f"{cc!r} is not a program on PATH (the native engine's C compiler); "
                                    "unset CC to use cc/gcc")
    eqx = os.environ.get("EQX_ON_ERROR")
    if eqx is not None and eqx.strip() != "nan":
        raise ValidationError("EQX_ON_ERROR", f"stabjax needs 'nan' (a solver error becomes a status code of the "
                                              f"trajectory, not an exception that ends the sweep); got {eqx!r}")
    delay = os.environ.get("_STABJAX_TEST_CHUNK_SLEEP", "").strip()  # tests only
    if delay:
        try:
            ok = float(delay) >= 0
        except ValueError:
            ok = False
        if not ok:
            raise ValidationError("_STABJAX_TEST_CHUNK_SLEEP", f"must be seconds >= 0, got {delay!r}")


def setup_jax(x64: bool | None = None) -> None:
    """Set JAX's global options for stabjax, once per process (later calls do nothing).

    The environment is validated first (:func:`check_environment`; a bad variable raises a
    :class:`~stabjax.errors.ValidationError` naming it, on every call until it is fixed).

    * float64 (``jax_enable_x64``), always: the monoaxial instability of paper A is algebraic and
      invisible in float32, and the engines assume float64 (``x64=False`` and ``STABJAX_X64=0`` once
      promised float32 and crashed every sweep with an OverflowError; they are refused instead);
    * ``EQX_ON_ERROR=nan`` unless set: a solver error becomes NaN and a status code, not an exception;
    * one JAX CPU device per core (the fused engine runs one loop per device), only if the user has
      not chosen (``jax_num_cpu_devices``, an ``XLA_FLAGS`` host device count, or
      ``STABJAX_CPU_DEVICES``, where 1 switches it off) and JAX has not started its backends.
    """
    if x64 is not None and not x64:
        raise ValidationError("x64", "float32 is not supported: stabjax computes in float64")
    check_environment()
    if _SETUP.get("done"):
        return
    _SETUP["done"] = True
    os.environ.setdefault("EQX_ON_ERROR", "nan")
    import jax

    jax.config.update("jax_enable_x64", True)
    _host_devices(jax)


def x64_wanted() -> bool:
    """True when ``STABJAX_X64`` is unset or 1/true/yes/on; 0/false/no/off (float32) and anything else
    are refused naming the variable. Kept so that a user who set the once-documented opt-out learns
    why it is gone instead of meeting an OverflowError deep in an engine."""
    raw = os.environ.get("STABJAX_X64")
    if raw is None or raw.strip().lower() in _TRUE:
        return True
    if raw.strip().lower() in _FALSE:
        raise ValidationError("STABJAX_X64", f"float32 is not supported ({raw!r}): stabjax computes in float64 "
                                             "(paper A's instability is invisible in float32); unset it")
    raise ValidationError("STABJAX_X64", f"must be 1 (float64, the default) or unset, got {raw!r}")


def _host_devices(jax) -> None:
    want = os.environ.get("STABJAX_CPU_DEVICES")
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return
    try:
        if jax.config.jax_num_cpu_devices not in (-1, None) and want is None:
            return
        want = env_int("STABJAX_CPU_DEVICES", hi=64)
        n = want if want else len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        n = max(1, min(n, 64))
        if n > 1 or want:
            jax.config.update("jax_num_cpu_devices", n)
    except ValidationError:
        raise
    except Exception:  # backends already initialised, or an older JAX without the option
        pass


__all__ = ["IntegrateConfig", "Settings", "VerdictConfig", "verdict_config", "escape_radius", "setup_jax", "SOLVERS"]
