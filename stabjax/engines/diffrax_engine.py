"""The diffrax engine: a vmapped ``diffrax.diffeqsolve`` per chunk (the reference path).

Every solver of :data:`stabjax.config.SOLVERS` runs here (implicit ones included), and systems
with their own ``classify``. Nothing is stored per solver step: each trajectory saves only its
observables at the checkpoint times, which the classifier (:mod:`stabjax.fold.verdict`) reduces to
per-trajectory scalars inside the same compiled function, so a chunk of B trajectories costs
O(B * n_checkpoints) memory whatever the number of steps.

Early stops, as on the other engines: a trajectory that cannot progress -- its state or
derivative turned non-finite, or a finite-time blow-up -- has its step size collapse, and a step
below ~10 ulp of the horizon (``PIDController(dtmin=...)``) stops it with status 1 after a few
rejected steps (each shrinks the step by 5; ~20 from a NaN at t0), where diffrax would otherwise
reject steps until ``max_steps``. With an escape radius, a ``diffrax.Event`` stops a state outside
the ball at once with :data:`stabjax.fold.status.ESCAPED`. (An event testing the derivative for
NaN would stop a NaN trajectory after one step instead of ~20, but costs an evaluation of the
right-hand side per step and misses the blow-up: measured +55% time on the monoaxial model, against
+40% for ``dtmin``, which catches both.)

No stop at a stable fixed point (:mod:`stabjax.fold.stops`) here, although the model allows it: a vmapped
``while_loop`` steps every lane until the last one of the batch ends, so a stopped lane saves no time, and
the certain test (:mod:`stabjax.fold.equilibrium`, a Lyapunov equation and a bisection) would be evaluated at
every step of every lane (measured: 3.5-4x the CPU time of the pendulum example's 256 starts; the previous,
cheaper test cost 1.4x). Outcomes are those of the lane engines; the features of a start at rest are the
full run's (within its numerical plateau of the equilibrium) instead of the equilibrium's own.
"""
from __future__ import annotations

import functools
from typing import Mapping

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from ..fold import verdict as V
from ..config import IntegrateConfig, escape_radius
from ..fold.status import ESCAPED as STATUS_ESCAPED, MAX_STEPS as STATUS_MAX_STEPS
from .base import Engine
from .tsit5 import MIN_STEP_REL

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

CHUNK = 4096  # the diffrax engine stores every checkpoint: bound its memory per call


def solve_one(system, icfg: IntegrateConfig, ts: jnp.ndarray, saveat_fn, p, final: bool = False):
    """One trajectory: ``(diffrax solution, solver_status)``; the status is diffrax's code, or
    :data:`STATUS_MAX_STEPS` for a collapsed step size, :data:`STATUS_ESCAPED` for an escape.
    ``final``: also save the state where the solve ended (``sol.ys = (saved, y_end)``,
    ``sol.ts = (ts, t_end)``)."""
    args = system.prepare(p)
    y0 = system.initial_state(p)
    term = diffrax.ODETerm(system.rhs)
    saveat = diffrax.SaveAt(ts=ts) if saveat_fn is None else diffrax.SaveAt(ts=ts, fn=saveat_fn)
    if final:
        saveat = diffrax.SaveAt(subs=[saveat.subs, diffrax.SubSaveAt(t1=True)])
    solver = SOLVERS[icfg.solver]()
    # implicit solvers: a PI controller (diffrax docs' suggestion for mildly stiff problems); with the
    # default I controller Kvaerno5 rejected about half its steps on the gyrodyne model
    pi = dict(pcoeff=0.3, icoeff=0.4) if isinstance(solver, diffrax.AbstractImplicitSolver) else {}
    radius = escape_radius(system, icfg)
    # step-size collapse (as in the other engines, but absolute: diffrax's dtmin is a constant):
    # a step below ~10 ulp of the horizon's largest time stops the solve (dt_min_reached)
    dtmin = MIN_STEP_REL * max(abs(float(icfg.t0)), abs(float(icfg.t1)))

    def stop(t, y, a, **kw):  # the escape, as on the lane engines
        return jnp.max(jnp.abs(y)) > radius

    sol = diffrax.diffeqsolve(
        term, solver, icfg.t0, icfg.t1, icfg.dt0, y0, args=args, saveat=saveat,
        stepsize_controller=diffrax.PIDController(rtol=icfg.rtol, atol=icfg.atol, dtmin=dtmin, force_dtmin=False,
                                                  norm=_error_norm, **pi),
        max_steps=icfg.max_steps, throw=False,
        adjoint=diffrax.ForwardMode(),  # plain while loop: no checkpointing machinery for a forward-only solve
        event=None if radius is None else diffrax.Event(stop),
    )
    status = sol.result._value
    collapsed = sol.result == diffrax.RESULTS.dt_min_reached
    status = jnp.where(collapsed, STATUS_MAX_STEPS, status)
    if radius is not None:
        status = jnp.where(sol.result == diffrax.RESULTS.event_occurred, STATUS_ESCAPED, status)
    return sol, status.astype(jnp.int32)


_RMS = diffrax.PIDController(rtol=1e-3, atol=1e-6).norm  # diffrax's own default error norm


def _error_norm(err):
    """diffrax's RMS error norm, with NaN read as infinite. Why: a step whose error estimate is NaN (a stage
    that overflowed: x' = -1e4 x^3 from x = 1 with the step diffrax picks at t0) was rejected without
    shrinking, the same step retried until max_steps (diffrax 0.7.2), so the sweep's re-integration of a
    trajectory the lane engines solved in 117 steps failed at t0; an infinite error is rejected with the
    controller's smallest factor, as a failed step is. A finite error is the same number: results are
    unchanged bit for bit wherever the solve did not meet a NaN."""
    e = _RMS(err)
    return jnp.where(jnp.isnan(e), jnp.inf, e)


@functools.lru_cache(maxsize=64)
def _batch_fn(system, icfg: IntegrateConfig, vcfg):
    """Compiled ``params(B, ...) -> summaries(B)``; cached so each spec compiles once, not per chunk."""
    ts = jnp.asarray(V.checkpoint_times(icfg.checkpoints(), vcfg))  # every horizon exactly
    classify = system.classify or V.classify

    def one(p):
        sol, status = solve_one(system, icfg, ts, lambda t, y, a: system.observe(t, y, a), p, final=True)
        obs, t_end = sol.ys[0], sol.ts[1][-1]
        out = dict(classify(ts, obs, status == 0, vcfg, icfg.t0))
        out["n_steps"] = sol.stats["num_accepted_steps"]
        out["n_rejected"] = sol.stats["num_rejected_steps"]
        out["solver_status"] = status  # 0 success, else the failure reason (stabjax.fold.status)
        out["stopped_at"] = t_end
        out["fixed_point"] = jnp.zeros((), jnp.int32)  # no stop code here (module docstring)
        return out

    return jax.jit(jax.vmap(one))


def solve(system, params: Mapping[str, np.ndarray], icfg: IntegrateConfig, vcfg) -> dict[str, np.ndarray]:
    """Integrate and classify ``params`` (every parameter, leading dim N) in sub-chunks of :data:`CHUNK`."""
    fn = _batch_fn(system, icfg, vcfg)
    n = len(next(iter(params.values())))
    if n <= CHUNK:
        p = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
        return {k: np.asarray(v) for k, v in fn(p).items()}
    parts = []
    for lo in range(0, n, CHUNK):  # sub-chunks of one size (last one padded): one compilation
        hi = min(n, lo + CHUNK)
        p = {k: np.asarray(v[lo:hi], dtype=np.float64) for k, v in params.items()}
        if hi - lo < CHUNK:
            p = {k: np.concatenate([v, np.repeat(v[-1:], CHUNK - (hi - lo), axis=0)]) for k, v in p.items()}
        out = fn({k: jnp.asarray(v) for k, v in p.items()})
        parts.append({k: np.asarray(v)[: hi - lo] for k, v in out.items()})
    return {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}


@functools.lru_cache(maxsize=32)
def simulate_fn(system, icfg: IntegrateConfig):
    """Compiled ``(ts, params) -> {ys, obs, status, n_steps}`` of one trajectory (full state at ``ts``)."""
    def run(ts, p):
        sol, status = solve_one(system, icfg, ts, None, p)
        args = system.prepare(p)
        obs = jax.vmap(system.observe, in_axes=(0, 0, None))(ts, sol.ys, args)
        return dict(ys=sol.ys, obs=obs, status=status, n_steps=sol.stats["num_accepted_steps"])

    return jax.jit(run)


class DiffraxEngine(Engine):
    """``jit(vmap(diffeqsolve))`` over a chunk: runs every system and solver."""

    name = "diffrax"

    def supports(self, system, icfg) -> str | None:
        return None

    def default_chunk(self, plan) -> int:
        return CHUNK

    def bytes_per_trajectory(self, plan) -> int:
        """The observables at every checkpoint dominate."""
        k = len(plan.icfg.checkpoints())
        n_obs = len(plan.integrated.observables)
        return 8 * (6 * k * n_obs + 64 * plan.integrated.state_size + 256)

    def solve(self, system, params, icfg, vcfg, static=None, progress=None):
        return solve(system, params, icfg, vcfg)


ENGINE = DiffraxEngine()

__all__ = ["ENGINE", "DiffraxEngine", "SOLVERS", "CHUNK", "solve", "solve_one", "simulate_fn"]
