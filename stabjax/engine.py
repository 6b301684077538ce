"""Batch integration: one compiled solve per (system, integrate config, chunk size).

Two engines (``IntegrateConfig.engine``):

* ``"fused"`` (default): :mod:`stabjax.fast` -- the same Tsit5 method and step-size controller
  as diffrax, written as one loop over lanes of trajectories with per-lane step sizes, lanes
  refilled from a queue, the classifier updated at each checkpoint inside the loop, one loop per
  CPU core. Systems it cannot run (another solver, a system-specific ``classify``, a primitive
  without a lane-wise rule) silently use the diffrax path.
* ``"diffrax"``: the reference path, a vmapped ``diffrax.diffeqsolve``. Nothing is stored per
  solver step: each trajectory saves only its observables (error, size) at a fixed set of
  checkpoint times, which the classifier (:mod:`stabjax.verdict`) reduces to per-trajectory
  scalars inside the same compiled function. So a chunk of B trajectories costs
  O(B * n_checkpoints) memory whatever the number of steps.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import Any, Callable, Mapping

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from .errors import ValidationError
from .fast import Unsupported
from .registry import get_system
from .system import System, VerdictConfig
from . import verdict as V

ENGINES = ("auto", "native", "fused", "diffrax")

SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "heun": diffrax.Heun,
    "bosh3": diffrax.Bosh3,
    # implicit (L-stable ESDIRK 5(4)) for stiff systems; default root finder (VeryChord, tolerances from the controller)
    "kvaerno5": diffrax.Kvaerno5,
    "kvaerno3": diffrax.Kvaerno3,
}


@dataclass(frozen=True)
class IntegrateConfig:
    """The ``[integrate]`` table of a sweep spec."""

    t1: float = 1.0e4
    t0: float = 0.0
    solver: str = "tsit5"
    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = 2_000_000
    n_checkpoints: int = 2000
    dt0: float | None = None
    # "auto": native (C, stabjax.native) on CPU when a compiler works, else fused (XLA, stabjax.fast),
    # else diffrax; "native"/"fused" prefer that engine (same fallbacks); "diffrax": reference path
    engine: str = "auto"
    lanes: int = 0  # fused engine: trajectories stepped side by side per device (0: automatic)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None, *, section: str = "integrate", default_t1: float | None = None):
        """From a spec table: every field checked for its type (``section.field`` named), then :meth:`validate`."""
        from .validate import record_from_dict

        d = dict(d or {})
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
            if f.name in ("solver", "engine") or (v is None and f.default is None):
                continue
            if isinstance(f.default, int) and not isinstance(f.default, bool):
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
        if not isinstance(self.engine, str) or self.engine not in ENGINES:
            raise ValidationError(f"{section}.engine", f"unknown engine {self.engine!r}; choose from {', '.join(ENGINES)}")
        # 0: automatic; at most 2^24 lanes (a GPU keeps 2^18 busy): the lane state is allocated up front
        integer(self.lanes, f"{section}.lanes", lo=0, hi=2**24)

    def checkpoints(self) -> np.ndarray:
        """Half log-spaced (early power-law transients), half linear (late excursions); includes t1."""
        k = self.n_checkpoints
        span = self.t1 - self.t0
        lin = np.linspace(self.t0, self.t1, k - k // 2)
        log = self.t0 + np.logspace(np.log10(span * 1e-5), np.log10(span), k // 2)
        ts = np.unique(np.concatenate([lin, log]))
        ts[-1] = self.t1
        return ts


def verdict_config(system: System, overrides: Mapping[str, Any] | None = None, section: str = "verdict") -> VerdictConfig:
    """The system's thresholds with the spec's ``[verdict]`` overrides, each checked (``verdict.<name>``)."""
    from .validate import check_verdict, record_from_dict

    cfg = record_from_dict(VerdictConfig, overrides, section, base=system.verdict, what="threshold")
    check_verdict(cfg, section)
    return cfg


def _as_system(system: System | str) -> System:
    return get_system(system) if isinstance(system, str) else system


def _solve_one(system: System, icfg: IntegrateConfig, ts: jnp.ndarray, saveat_fn, p):
    args = system.prepare(p)
    y0 = system.initial_state(p)
    term = diffrax.ODETerm(system.rhs)
    saveat = diffrax.SaveAt(ts=ts) if saveat_fn is None else diffrax.SaveAt(ts=ts, fn=saveat_fn)
    solver = SOLVERS[icfg.solver]()
    # implicit solvers: a PI controller (diffrax docs' suggestion for mildly stiff problems); with the
    # default I controller Kvaerno5 rejected about half its steps on the gyrodyne model
    pi = dict(pcoeff=0.3, icoeff=0.4) if isinstance(solver, diffrax.AbstractImplicitSolver) else {}
    sol = diffrax.diffeqsolve(
        term,
        solver,
        icfg.t0,
        icfg.t1,
        icfg.dt0,
        y0,
        args=args,
        saveat=saveat,
        stepsize_controller=diffrax.PIDController(rtol=icfg.rtol, atol=icfg.atol, **pi),
        max_steps=icfg.max_steps,
        throw=False,
        adjoint=diffrax.ForwardMode(),  # plain while loop: no checkpointing machinery for a forward-only solve
    )
    return sol


@functools.lru_cache(maxsize=64)
def _batch_fn(system: System, icfg: IntegrateConfig, vcfg: VerdictConfig):
    """Compiled ``params(B, ...) -> summaries(B)``; cached so each spec compiles once, not per chunk."""
    ts = jnp.asarray(icfg.checkpoints())
    classify = getattr(system, "classify", None) or V.classify

    def one(p):
        sol = _solve_one(system, icfg, ts, lambda t, y, a: system.observe(t, y, a), p)
        ok = sol.result == diffrax.RESULTS.successful
        out = dict(classify(ts, sol.ys, ok, vcfg, icfg.t0))
        out["n_steps"] = sol.stats["num_accepted_steps"]
        out["n_rejected"] = sol.stats["num_rejected_steps"]
        out["solver_status"] = sol.result._value  # diffrax RESULTS code: 0 success, else failure reason
        return out

    return jax.jit(jax.vmap(one))


def solve_batch(system: System | str, params: Mapping[str, np.ndarray], icfg: IntegrateConfig,
                vcfg: VerdictConfig | None = None, *, static=None,
                progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Integrate and classify a batch. ``params``: every parameter, leading dim N (already checked).

    ``static`` (native and fused engines): names of parameters that are the same in every batch of
    the sweep; they are compiled in as constants (default: those equal across this batch).
    ``progress(done, n)``: called while the native engine runs. The engine that ran is
    :func:`last_engine`.
    """
    system = _as_system(system)
    vcfg = vcfg or system.verdict
    for name in engine_chain(system, icfg):
        try:
            if name == "native":
                from . import native

                out = native.solve(system, params, icfg, vcfg, static=static, progress=progress)
            elif name == "fused":
                from . import fast

                out = fast.solve(system, params, icfg, vcfg, lanes=icfg.lanes or None, static=static)
            else:
                out = _solve_diffrax(system, params, icfg, vcfg)
        except Unsupported:  # e.g. a primitive without a rule: the next engine handles it
            continue
        _LAST_ENGINE["name"] = name
        return out
    raise AssertionError("the diffrax path supports every system")


_LAST_ENGINE: dict[str, str] = {}


def last_engine() -> str:
    """Name of the engine that ran the last :func:`solve_batch` call of this process."""
    return _LAST_ENGINE.get("name", "")


def engine_chain(system: System, icfg: IntegrateConfig) -> list[str]:
    """Engines to try, in order, for this system and ``[integrate]`` table."""
    from . import fast, native

    if icfg.engine == "diffrax":
        return ["diffrax"]
    chain = []
    if icfg.engine in ("auto", "native") and native.would_run(system, icfg):
        chain.append("native")
    if fast.would_run(system, icfg):
        chain.append("fused")
    return chain + ["diffrax"]


DIFFRAX_CHUNK = 4096  # the diffrax path stores every checkpoint: bound its memory per call


def _solve_diffrax(system: System, params: Mapping[str, np.ndarray], icfg: IntegrateConfig,
                   vcfg: VerdictConfig) -> dict[str, np.ndarray]:
    fn = _batch_fn(system, icfg, vcfg)
    n = len(next(iter(params.values())))
    if n <= DIFFRAX_CHUNK:
        p = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
        return {k: np.asarray(v) for k, v in fn(p).items()}
    # e.g. a fused-engine-sized chunk that fell back: sub-chunks of one size (last one padded)
    parts = []
    for lo in range(0, n, DIFFRAX_CHUNK):
        hi = min(n, lo + DIFFRAX_CHUNK)
        p = {k: np.asarray(v[lo:hi], dtype=np.float64) for k, v in params.items()}
        if hi - lo < DIFFRAX_CHUNK:
            p = {k: np.concatenate([v, np.repeat(v[-1:], DIFFRAX_CHUNK - (hi - lo), axis=0)]) for k, v in p.items()}
        out = fn({k: jnp.asarray(v) for k, v in p.items()})
        parts.append({k: np.asarray(v)[: hi - lo] for k, v in out.items()})
    return {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}


def batch_params(system: System, overrides: Mapping[str, Any] | None, n: int = 1) -> dict[str, np.ndarray]:
    """Defaults + overrides, validated, broadcast to a batch of ``n``."""
    p = system.params.resolve(overrides)
    p = system.check(p)
    return {k: np.broadcast_to(v, (n, *np.shape(v))).copy() for k, v in p.items()}


def simulate(system: System | str, params: Mapping[str, Any] | None = None, *, t1: float | None = None,
             ts=None, t0: float = 0.0, solver: str = "tsit5", rtol: float = 1e-10, atol: float = 1e-12,
             max_steps: int | None = None) -> xr.Dataset:
    """One trajectory with the full state saved at ``ts`` (default: 1000 points on [t0, t1]; t1 always included).

    Returns a Dataset with a variable per state component (3-vectors on dim ``axis``) and per observable.
    """
    system = _as_system(system)
    t1 = float(system.default_t1 if t1 is None else t1)
    icfg = IntegrateConfig(t1=t1, t0=t0, solver=solver, rtol=rtol, atol=atol,
                           max_steps=int(max_steps or 10_000_000), n_checkpoints=1000)
    icfg.validate("simulate")
    if ts is None:
        ts = np.linspace(t0, t1, 1001)
    ts = np.asarray(ts, dtype=float).ravel()
    if not np.all(np.isfinite(ts)) or np.any(ts < t0) or np.any(ts > t1):
        raise ValidationError("ts", f"save times must lie in [t0, t1] = [{t0}, {t1}]")
    ts = np.unique(np.append(ts, t1))
    p = system.params.resolve(params)
    p = system.check(p)
    pj = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in p.items()}
    sol = _simulate_jit(system, icfg, jnp.asarray(ts), pj)
    ys = np.asarray(sol["ys"])
    obs = np.asarray(sol["obs"])
    ds = xr.Dataset(coords={"t": ("t", ts, {"long_name": "time"})})
    comps = system.unpack(ys)
    for name, shape in system.state:
        ds[name] = (("t", *_dims_for(name, shape)), comps[name])
    for i, name in enumerate(system.observables):
        ds[name] = ("t", obs[:, i], {"long_name": system.observable_doc[i]})
    if "axis" in ds.dims:
        ds = ds.assign_coords(axis=["x", "y", "z"])
    status = int(sol["status"])
    ds.attrs.update(
        system=system.name, solver=solver, rtol=rtol, atol=atol, t0=t0, t1=t1,
        solver_status=status, solver_ok=int(status == 0), n_steps=int(sol["n_steps"]),
        params=_params_json(p),
    )
    return ds


@functools.lru_cache(maxsize=32)
def _simulate_fn(system: System, icfg: IntegrateConfig):
    def run(ts, p):
        sol = _solve_one(system, icfg, ts, None, p)
        args = system.prepare(p)
        obs = jax.vmap(system.observe, in_axes=(0, 0, None))(ts, sol.ys, args)
        return dict(ys=sol.ys, obs=obs, status=sol.result._value, n_steps=sol.stats["num_accepted_steps"])

    return jax.jit(run)


def _simulate_jit(system, icfg, ts, p):
    return _simulate_fn(system, icfg)(ts, p)


def _dims_for(name: str, shape: tuple[int, ...]) -> tuple[str, ...]:
    if shape == (3,):
        return ("axis",)
    if shape == (3, 3):
        return ("row", "col")
    return tuple(f"{name}_dim{i}" for i in range(len(shape)))


def _params_json(p: Mapping[str, np.ndarray]) -> str:
    import json

    return json.dumps({k: np.asarray(v).tolist() for k, v in p.items()})


__all__ = ["IntegrateConfig", "simulate", "solve_batch", "batch_params", "verdict_config", "SOLVERS", "ENGINES",
           "engine_chain", "last_engine"]
