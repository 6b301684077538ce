"""Public integration API: :func:`solve_batch` (a batch of trajectories, classified) and
:func:`simulate` (one trajectory with its full state), on the engines of :mod:`stabjax.engines`.

Settings live in :mod:`stabjax.config`.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping

import numpy as np

from .. import engines
from ..config import SOLVERS, IntegrateConfig, Settings, VerdictConfig, setup_jax, verdict_config
from ..errors import ValidationError
from ..model.system import System

def _as_system(system) -> System:
    """A name, 'file.py:Class', 'module:Class', a System class or instance -> a checked System."""
    from ..model.loading import resolve

    return resolve(system)


def solve_batch(system: System | str, params: Mapping[str, np.ndarray], icfg: IntegrateConfig,
                vcfg: VerdictConfig | None = None, *, static=None,
                progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Integrate and classify a batch. ``params``: every parameter, leading dim N (already checked).

    The engine is chosen as for a sweep (:func:`stabjax.engines.resolve`; a fallback is logged at
    level INFO on the logger ``stabjax.engines``).
    ``static`` (native and fused engines): names of parameters that are the same in every batch
    of the sweep; they are compiled in as constants (default: those equal across this batch).
    ``progress(done, n)``: called while the native engine runs.
    """
    setup_jax()
    system = _as_system(system)
    _check_batch(system, params)
    vcfg = vcfg or system.verdict
    choice = engines.resolve(system, icfg, vcfg, params, static)
    if choice.note:  # a sweep warns once per plan; a batch call may be one of many: not shown by default
        engines.log.info(choice.note)
    return engines.solve(choice.engine, system, params, icfg, vcfg, static=static, progress=progress)


def _check_batch(system: System, params) -> None:
    """What a batch needs before any engine sees it (a KeyError or JAX's 'vmap got inconsistent sizes' else):
    every parameter of the system, each with the same leading dimension N."""
    if not isinstance(params, Mapping):
        raise ValidationError("params", f"a mapping of parameter names to arrays, got a {type(params).__name__}")
    missing = [p.name for p in system.params if p.name not in params]
    if missing:
        raise ValidationError("params", f"no {', '.join(map(repr, missing))}: every parameter of {system.name}, "
                                        "leading dim N (stabjax.engines.simulate.batch_params(system, overrides, n) "
                                        "fills in the defaults)")
    sizes = {k: (np.shape(v)[0] if np.ndim(v) else None) for k, v in params.items()}
    if len(set(sizes.values())) > 1 or None in sizes.values():
        raise ValidationError("params", "every parameter needs the same leading dimension N; got "
                                        + ", ".join(f"{k}: {'a scalar' if n is None else n}" for k, n in sizes.items()))


def batch_params(system: System, overrides: Mapping[str, Any] | None, n: int = 1) -> dict[str, np.ndarray]:
    """Defaults + overrides, validated, broadcast to a batch of ``n``."""
    p = system.params.resolve(overrides)
    p = system.check(p)
    return {k: np.broadcast_to(v, (n, *np.shape(v))).copy() for k, v in p.items()}


def simulate(system: System | str, params: Mapping[str, Any] | None = None, *, t1: float | None = None,
             ts=None, t0: float = 0.0, solver: str = "tsit5", rtol: float = 1e-10, atol: float = 1e-12,
             max_steps: int | None = None):
    """One trajectory with the full state saved at ``ts`` (default: 1001 points on [t0, t1], 1000 steps apart;
    t1 always included).

    Runs on the engine that saves full states (:func:`stabjax.engines.trajectory_fn`; stops at once on a non-finite state, and at the system's escape
    radius if it has one). ``params``: a mapping of parameter names (a start's components among them) to values,
    the system's defaults for the others. ``ts`` is saved sorted, without repeats, with ``t1`` added.
    Returns a Dataset with a variable per state component (3-vectors on dim ``axis``) and per observable.
    """
    setup_jax()
    import jax.numpy as jnp
    import xarray as xr

    if params is not None and not isinstance(params, Mapping):
        raise ValidationError("params", f"a mapping of parameter names to values (such as {{'x0': 0.3}}), "
                                        f"got a {type(params).__name__}")
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
    sol = engines.trajectory_fn(system, icfg)(jnp.asarray(ts), pj)
    ys = np.asarray(sol["ys"])
    obs = np.asarray(sol["obs"])
    ds = xr.Dataset(coords={"t": ("t", ts, {"long_name": "time"})})
    comps = system.unpack(ys)
    for name, shape in system.state:
        ds[name] = (("t", *_dims_for(name, shape)), comps[name], {"long_name": f"state component {name}"})
    for i, name in enumerate(system.observables):
        if name in ds:  # the model check holds such an observable equal to its state component: one variable
            ds[name].attrs["long_name"] = f"state component {name}: {system.observable_doc[i]} (also an observable)"
            continue
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


def _dims_for(name: str, shape: tuple[int, ...]) -> tuple[str, ...]:
    if shape == (3,):
        return ("axis",)
    if shape == (3, 3):
        return ("row", "col")
    return tuple(f"{name}_dim{i}" for i in range(len(shape)))


def _params_json(p: Mapping[str, np.ndarray]) -> str:
    import json

    return json.dumps({k: np.asarray(v).tolist() for k, v in p.items()})


__all__ = ["simulate", "solve_batch", "batch_params"]
