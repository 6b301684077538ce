"""Stop a trajectory once its outcome is decided: at a stable fixed point (autonomous systems only).

Escape (``max_i |y_i| > escape_radius``) already stops a trajectory in every engine. This module
adds the second decided fate: the trajectory has reached a **stable equilibrium**. Everything here
is plain JAX on one trajectory, so the lane engines run the one definition: the fused engine
evaluates it lane-wise, the native engine translates it into C like the model's ``rhs``. The diffrax
engine runs every trajectory to t1 (a vmapped loop steps the whole batch until its last lane ends, so a
stop saves it nothing: :mod:`stabjax.engines.diffrax_engine`).

The test (:mod:`stabjax.fold.equilibrium`, issue 29): the linearisation at the state is Hurwitz, Newton's
chord steps converge to the equilibrium ``x*``, and a quadratic Lyapunov function of the linearisation
proves the trajectory within one tolerance unit of ``x*`` per component from the start of the feature window
on. The stopped run then **finishes at the equilibrium**: its late-window features are those of ``x*``
(mean = min = max = final = the observables at ``x*``, spread 0: :func:`at_equilibrium`), the trajectory's
limit, which the run without the stop approaches to within its own numerical plateau. The stop depends on no
rule bound and holds at any tolerance: at pyBasin's atol = 1e-6 the previous criterion (the state frozen
within 1000 tolerance units, |omega| ~ 1e-3 on the pendulum) turned 126 of 10^4 rest-point starts
``unclassified``.

Why autonomous systems only: for ``f(t, x)`` an equilibrium of the frozen field at one time is not
one at later times (a forced oscillator's "rest" is a moment of its forcing). The model's rhs and
observables are traced and the stop is off when either reads ``t`` (:func:`is_autonomous`), which
also switches it off for the tangent dynamics of the Lyapunov exponent (their window switch reads
``t``). Why never for the attitude-verdict systems: their verdicts read decay laws and excursions
over log-time windows up to t1, which a stopped run no longer has.

**Near a known attractor (the recurrence idea; opt-in, ``[integrate] attractor_stop = true``).** The
third decided fate, after Attractors.jl's recurrence mapper: a trajectory that has stayed within a known
attractor's neighbourhood for as long as the feature window has the late-window features of that attractor
and is stopped. "Known" means found by this run itself, from trajectories integrated to t1 first: a
refinement's coarse round, a sweep's first chunk (:func:`known_attractors`). Each attractor is a cloud of
at most :data:`CLOUD_POINTS` points of observable space (the observables at t1 of the trajectories that
reached it, thinned by farthest-point sampling: the final states of many starts lie at all phases of a
limit cycle and spread over a chaotic attractor by its natural measure), with a radius ``eps`` (twice the
cloud's largest nearest-neighbour gap, so a trajectory on the attractor is always within reach of a cloud
point, and at most a quarter of the distance to any other attractor's cloud, so no state is near two).
Observables are scaled by their spread over all clouds, as discovery scales its features.

The engines test at a step that reached a checkpoint, every :data:`TEST_EVERY` checkpoints: the nearest attractor of the current observation (or none); a lane
stops once the same attractor was found at every test over a span of ``dwell`` (the feature window's
length). The stopped trajectory's late-window features are replaced by those of the attractor's
representative (a trajectory of the cloud; :func:`substitute`), so every rule, template or discovery step
gives it the attractor's outcome. What it cannot see: a trajectory that shadows an attractor for a whole
window and then leaves (a neighbourhood that reaches a basin boundary). It is therefore off unless asked
for, refused where the attractors move between trajectories (a varying parameter that is not an initial
condition) and on models that read ``t``, and the tests and the benchmark compare every outcome with and
without it (``python -m benchmarks.early_bench``).

``stop_reason`` codes (per trajectory, CF ``flag_values`` / ``flag_meanings``): :data:`REASONS`.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from dataclasses import dataclass

from ..errors import ValidationError
from .equilibrium import (DISTANCE_TOL, at_fixed_point, charpoly_adjugate, fixed_point_stop, hurwitz, jacobian,
                          near_stable)

# the lane engines ask for a known attractor at most once per TEST_EVERY checkpoints of a lane (the test is
# a few hundred flops against constant clouds), and for a fixed point at most once per fixed_point_every(K):
# that test costs about n + 1 right-hand sides plus the characteristic polynomial, and once the classifier's
# per-checkpoint cost fell (named outcomes fold the features alone) asking every 8 checkpoints cost +38 %
# wall on the pendulum (4096 starts, 4000 checkpoints, native engine; every 83: no measurable cost;
# `python -m benchmarks.checkpoint_cost`), so it is asked about FIXED_POINT_TESTS times over a run, a stop
# coming at most that late
TEST_EVERY = 8
FIXED_POINT_TESTS = 48


def fixed_point_every(n_checkpoints: int) -> int:
    """Checkpoints between two fixed-point tests of a lane (at least :data:`TEST_EVERY`)."""
    return max(TEST_EVERY, int(n_checkpoints) // FIXED_POINT_TESTS)

STOP_NONE, STOP_ESCAPED, STOP_FIXED_POINT, STOP_FAILED, STOP_ATTRACTOR = 0, 1, 2, 3, 4
REASONS = ("none", "escaped", "fixed_point", "failed", "attractor")
REASON_DOC = ("stop_reason: why the integration ended before t1: none (ran to t1), escaped (left the escape "
              "radius), fixed_point (reached a stable equilibrium within the solver tolerance; stabjax.fold.stops), "
              "failed (solver failure), attractor (stayed near a known attractor for a feature window)")

# the engines' per-trajectory stop code (result key "fixed_point"): 0 none, 1 fixed point, 2 + k attractor k
HIT_NONE, HIT_FIXED_POINT, HIT_ATTRACTOR0 = 0, 1, 2

# cloud points per known attractor: the test costs about CLOUD_POINTS * (3 n_obs + 1) flops per test
CLOUD_POINTS = 48
# fewest trajectories of one outcome that make a cloud (fewer: that attractor is not known, never stopped at)
MIN_CLOUD = 8
STOPPED_AT_DOC = "time at which the integration of this trajectory ended (t1 unless it stopped early)"


# ---- autonomy -------------------------------------------------------------------------------------------

def _uses_var(jaxpr, var) -> bool:
    """Whether ``var`` (an input of ``jaxpr``) reaches any equation or output; nested calls are followed
    (a call that receives it counts only if its own body uses the corresponding input)."""
    live = {var}
    for eqn in jaxpr.eqns:
        hit = [i for i, v in enumerate(eqn.invars) if not _is_literal(v) and v in live]
        if not hit:
            continue
        sub = eqn.params.get("jaxpr", eqn.params.get("call_jaxpr"))
        if sub is not None and len(eqn.params) and not isinstance(sub, (list, tuple)):
            inner = getattr(sub, "jaxpr", sub)
            if len(inner.invars) == len(eqn.invars):
                if not any(_uses_var(inner, inner.invars[i]) for i in hit):
                    continue
        live.update(v for v in eqn.outvars)
    return any((not _is_literal(v)) and v in live for v in jaxpr.outvars)


def _is_literal(v) -> bool:
    try:
        from jax.extend.core import Literal
    except ImportError:  # older JAX
        from jax.core import Literal
    return isinstance(v, Literal)


def is_autonomous(system, params=None) -> bool:
    """True when neither ``system.rhs`` nor ``system.observe`` reads ``t`` (traced with abstract
    arguments; ``params``: one trajectory's parameters, else the defaults)."""
    return _autonomous(system)


@functools.lru_cache(maxsize=64)
def _autonomous(system) -> bool:
    sds = jax.ShapeDtypeStruct
    p = system.params.resolve(None)
    p = {k: sds(np.shape(v), jnp.float64) for k, v in p.items()}
    try:
        args = jax.eval_shape(system.prepare, p)
        t, y = sds((), jnp.float64), sds((system.state_size,), jnp.float64)
        for fn in (system.rhs, system.observe):
            closed = jax.make_jaxpr(fn)(t, y, args)
            if _uses_var(closed.jaxpr, closed.jaxpr.invars[0]):
                return False
    except Exception:  # a model that cannot be traced abstractly: do not stop (the safe answer)
        return False
    return True


# ---- configuration -----------------------------------------------------------------------------------------

def resolve(icfg, system, has_outcomes: bool, field: str = "integrate.early_stop"):
    """``icfg`` with ``early_stop`` decided for a plan: ``None`` (the default) becomes True exactly
    where a stop cannot change an outcome -- named outcomes or discovery, an autonomous model, the
    generic fold -- and False elsewhere. ``true`` where the attitude verdicts are the outcomes, or for a
    system with its own classifier, is refused (their verdicts read the run up to t1). ``true`` on a
    non-autonomous model is kept but never fires (:func:`active`)."""
    want = icfg.early_stop
    if want is True and (not has_outcomes or system.classify is not None):
        raise ValidationError(field, f"{system.name}'s verdicts read decay laws and excursions up to t1; "
                                     "stopping a trajectory early would change them (set early_stop = false)")
    if want is None:
        want = bool(has_outcomes and system.classify is None and is_autonomous(system))
    return icfg.replace(early_stop=bool(want))


def active(system, icfg) -> bool:
    """Whether the engines test for a fixed point: asked for (``early_stop = true``, as a plan resolves
    it), an autonomous model, the generic fold. ``None`` (a raw config, no plan) means off."""
    return icfg.early_stop is True and system.classify is None and is_autonomous(system)


# ---- the fold after a stop ----------------------------------------------------------------------------------

def window_index(ts: np.ndarray, vcfg) -> int:
    """Index of the first checkpoint inside the feature window (as :func:`stabjax.fold.verdict.update` tests it)."""
    t0 = float(vcfg.t0) if vcfg.t1 is not None else 0.0
    span = (float(vcfg.t1) - t0) if vcfg.t1 is not None else float(ts[-1])
    inw = (np.asarray(ts, float) - t0) >= span * (1.0 - vcfg.feature_window)
    return int(np.argmax(inw)) if inw.any() else len(ts)


def window_start(ts: np.ndarray, vcfg) -> float:
    """Time of the first checkpoint inside the feature window: a fixed-point stop comes before it."""
    ts = np.asarray(ts, float)
    k = window_index(ts, vcfg)
    return float(ts[k]) if k < len(ts) else float(ts[-1])


def at_equilibrium(res: dict, stopped, obs, xp=np) -> dict:
    """Engine summaries with the late-window features of every trajectory in ``stopped`` (bool, (N,)) set to
    those of the equilibrium it stopped at: ``obs`` (N, n_obs), the observables at ``x*`` (max = min = mean =
    final = obs, std = 0). The stop comes before the window (:mod:`stabjax.fold.equilibrium`), so the window
    holds the equilibrium alone; written on the summaries, not the fold's running sums, whatever their
    layout. NumPy (the native and diffrax engines' results) or ``xp=jnp`` inside a compiled loop."""
    if "feat_mean" not in res:
        return res
    out = dict(res)
    for key in _FEAT_KEYS:
        v = res[key]
        m = min(int(v.shape[-1]), int(obs.shape[-1]))
        o = obs[..., :m].astype(v.dtype)
        val = xp.zeros_like(o) if key == "feat_std" else o
        head = xp.where(stopped[:, None], val, v[..., :m])
        out[key] = head if m == v.shape[-1] else xp.concatenate([head, v[..., m:]], axis=-1)
    return out


def stop_reasons(status, fixed):
    """``stop_reason`` codes from the solver status and the engines' stop code (NumPy)."""
    from .status import ESCAPED as STATUS_ESCAPED, OK as STATUS_OK

    status = np.asarray(status)
    fixed = np.asarray(fixed)
    out = np.where(status == STATUS_OK, STOP_NONE, np.where(status == STATUS_ESCAPED, STOP_ESCAPED, STOP_FAILED))
    ok = status == STATUS_OK
    out = np.where((fixed == HIT_FIXED_POINT) & ok, STOP_FIXED_POINT, out)
    return np.where((fixed >= HIT_ATTRACTOR0) & ok, STOP_ATTRACTOR, out).astype(np.int8)


# ---- near a known attractor (the recurrence stop) -------------------------------------------------------------

_FEAT_KEYS = ("feat_max", "feat_min", "feat_mean", "feat_std", "feat_final")


@dataclass(frozen=True)
class KnownAttractors:
    """The attractors a run has found so far, as the engines test them (plain tuples: hashable, so the
    compiled kernels are cached per set, and JSON-able, so a run's identity records it).

    ``labels``: the outcome code of each attractor; ``cloud``: (K, P, n_obs) points of observable space
    (flattened); ``scale``: (n_obs,) per-observable scale; ``eps``: (K,) radius in scaled units; ``dwell``:
    the time a trajectory must stay near one attractor; ``features``: (K, 5, F) the representative's
    ``feat_max``, ``feat_min``, ``feat_mean``, ``feat_std``, ``feat_final`` (flattened)."""

    labels: tuple
    cloud: tuple
    shape: tuple
    scale: tuple
    eps: tuple
    dwell: float
    features: tuple
    fshape: tuple

    @property
    def points(self) -> np.ndarray:
        return np.asarray(self.cloud, np.float64).reshape(self.shape)

    @property
    def reps(self) -> np.ndarray:
        return np.asarray(self.features, np.float64).reshape(self.fshape)


def _farthest(x: np.ndarray, m: int) -> tuple[np.ndarray, float]:
    """Indices of ``m`` points of ``x`` (n, d) by farthest-point sampling from the point nearest the
    mean (deterministic), and the covering radius: the largest distance of a point of ``x`` to them."""
    start = int(np.argmin(((x - x.mean(0)) ** 2).sum(1)))
    sel = [start]
    d = np.sqrt(((x - x[start]) ** 2).sum(1))
    while len(sel) < min(m, len(x)):
        i = int(np.argmax(d))
        if d[i] == 0:
            break
        sel.append(i)
        d = np.minimum(d, np.sqrt(((x - x[i]) ** 2).sum(1)))
    return np.asarray(sel), float(d.max())


def known_attractors(labels, results: dict, eligible, dwell: float) -> KnownAttractors | None:
    """The attractors found among trajectories that ran to t1 (``results``: engine summaries, ``labels``:
    their outcome codes, ``eligible``: the codes that name an attractor -- not escape, unclassified or
    failed). None when no attractor has :data:`MIN_CLOUD` trajectories or no two can be told apart."""
    labels = np.asarray(labels)
    fin = np.asarray(results["feat_final"], np.float64)
    if fin.ndim != 2:
        return None
    ran = np.asarray(results["solver_status"]) == 0
    if "stop_reason" in results:  # only full runs: a stopped one's final observables are a representative's
        ran &= np.asarray(results["stop_reason"]) == STOP_NONE
    ok = ran & np.all(np.isfinite(fin), axis=1)
    codes = [int(c) for c in eligible if np.count_nonzero(ok & (labels == c)) >= MIN_CLOUD]
    if not codes:
        return None
    every = fin[ok & np.isin(labels, codes)]
    scale = every.std(0)
    scale = np.where(scale > 0, scale, np.maximum(np.abs(every).max(0), 1.0))
    clouds, gaps, reps = [], [], []
    for c in codes:
        idx = np.flatnonzero(ok & (labels == c))
        x = fin[idx] / scale
        sel, cover = _farthest(x, CLOUD_POINTS)
        pts = x[sel]
        if len(pts) > 1:
            dd = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1)) + np.diag(np.full(len(pts), np.inf))
            gap = float(dd.min(1).max())
        else:
            gap = 0.0
        gaps.append(max(2.0 * gap, 2.0 * cover))
        pts = np.concatenate([pts, np.repeat(pts[-1:], CLOUD_POINTS - len(pts), 0)])  # fixed P: pad
        clouds.append(pts)
        # representative: the cloud's member nearest the mean of the outcome's features
        F = np.stack([np.asarray(results[k], np.float64)[idx] for k in _FEAT_KEYS], axis=1)  # (n, 5, F)
        flat = F.reshape(len(idx), -1)
        reps.append(F[int(np.argmin(((flat - flat.mean(0)) ** 2).sum(1)))])
    clouds = np.stack(clouds)
    K = len(codes)
    eps = np.asarray(gaps)
    floor = 1e-6  # a fixed point's cloud is one point (no gap): a radius above the solver's rtol-scale spread
    for i in range(K):
        near = min((float(np.sqrt(((clouds[i][:, None] - clouds[j][None]) ** 2).sum(-1)).min())
                    for j in range(K) if j != i), default=np.inf)
        eps[i] = min(max(eps[i], floor), near / 4)
    keep = eps > 0
    if not keep.any():
        return None
    codes = [c for c, k in zip(codes, keep) if k]
    clouds, eps, reps = clouds[keep], eps[keep], np.stack(reps)[keep]
    return KnownAttractors(tuple(int(c) for c in codes), tuple((clouds * scale).ravel().tolist()), clouds.shape,
                           tuple(scale.tolist()), tuple(eps.tolist()), float(dwell),
                           tuple(reps.ravel().tolist()), reps.shape)


def known_for(plan, results: dict) -> KnownAttractors | None:
    """The attractors of ``plan`` found among ``results`` (a sweep's or refinement's records of trajectories
    run without the recurrence stop, with their ``outcome`` codes): every declared rule or template outcome,
    a dwell of the feature window's length."""
    decl = plan.scheme.decl
    n_attr = len(decl.rules) + len(decl.templates)
    dwell = float(plan.vcfg.feature_window) * (float(plan.icfg.t1) - float(plan.icfg.t0))
    return known_attractors(results["outcome"], results, range(n_attr), dwell)


def with_known(plan, results: dict):
    """``plan`` with the attractors found in ``results`` for its engines to stop at (unchanged if none)."""
    import dataclasses

    known = known_for(plan, results)
    if known is None:
        return plan
    return dataclasses.replace(plan, icfg=plan.icfg.replace(known_attractors=known))


def near_attractor(obs, known: KnownAttractors):
    """Index (float) of the known attractor within whose radius ``obs`` lies, -1.0 if none (traced, one
    trajectory; the radii never overlap, so at most one holds). Plain arithmetic and min reductions; the
    clouds are constants here (the fused engine folds them), data in :func:`near_attractor_data`."""
    sp, scale, eps2 = attractor_arrays(known)
    return near_attractor_data(obs, sp, scale, eps2)


def attractor_arrays(known: KnownAttractors) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(points / scale (K, P, n_obs), scale (n_obs,), eps^2 (K,))``: what the test reads."""
    scale = np.asarray(known.scale, np.float64)
    return known.points / scale, scale, np.asarray(known.eps, np.float64) ** 2


def near_attractor_data(obs, sp, scale, eps2):
    """:func:`near_attractor` with the clouds as arrays (constants or data: the native engine reads them from
    memory, so that its compiled kernel serves every set of the same shape, :class:`AttractorLayout`)."""
    K, _, n = sp.shape
    o = obs[:n] / scale
    k_out = np.float64(-1.0)
    for k in range(K):
        d2 = jnp.min(jnp.sum((o[None, :] - sp[k]) ** 2, axis=1))
        k_out = jnp.where(d2 <= eps2[k], float(k), k_out)
    return k_out


@dataclass(frozen=True)
class AttractorLayout:
    """The shape of a :class:`KnownAttractors` and its dwell, without its clouds: what a compiled kernel
    depends on (the clouds are its data, :func:`attractor_data`)."""

    shape: tuple
    dwell: float


def layout(known: KnownAttractors) -> AttractorLayout:
    return AttractorLayout(tuple(known.shape), float(known.dwell))


def attractor_data(known: KnownAttractors) -> np.ndarray:
    """The clouds as one float64 vector, in the order :func:`near_attractor_data` reads them."""
    sp, scale, eps2 = attractor_arrays(known)
    return np.ascontiguousarray(np.concatenate([sp.ravel(), scale, eps2]), np.float64)


def substitute(res: dict, known: KnownAttractors) -> dict:
    """Engine results with the features of every trajectory stopped near attractor k replaced by the
    representative's (stop code ``HIT_ATTRACTOR0 + k``)."""
    hit = np.asarray(res["fixed_point"])
    k = hit - HIT_ATTRACTOR0
    at = k >= 0
    if not at.any():
        return res
    res = dict(res)
    reps = known.reps
    for j, key in enumerate(_FEAT_KEYS):
        v = np.array(res[key], np.float64, copy=True)
        m = min(v.shape[1], reps.shape[2])
        v[at, :m] = reps[k[at], j, :m]
        res[key] = v
    return res


def attractor_stop_active(system, icfg) -> bool:
    """Whether the engines test for a known attractor: a set is known, an autonomous model, the generic fold."""
    return icfg.known_attractors is not None and system.classify is None and is_autonomous(system)


__all__ = ["REASONS", "STOP_NONE", "STOP_ESCAPED", "STOP_FIXED_POINT", "STOP_FAILED", "is_autonomous", "resolve",
           "active", "jacobian", "charpoly_adjugate", "hurwitz", "at_fixed_point", "fixed_point_stop", "near_stable",
           "window_index", "window_start", "at_equilibrium", "DISTANCE_TOL",
           "stop_reasons", "KnownAttractors", "known_attractors", "known_for", "with_known", "near_attractor", "substitute", "attractor_stop_active",
           "STOP_ATTRACTOR", "near_attractor_data", "attractor_arrays", "AttractorLayout", "layout",
           "attractor_data", "HIT_NONE", "HIT_FIXED_POINT", "HIT_ATTRACTOR0", "CLOUD_POINTS", "TEST_EVERY",
           "fixed_point_every"]
