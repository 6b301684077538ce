"""Stop a trajectory once its outcome is decided: at a stable fixed point (autonomous systems only).

Escape (``max_i |y_i| > escape_radius``) already stops a trajectory in every engine. This module
adds the second decided fate: the trajectory has reached a **stable equilibrium**. Everything here
is plain JAX on one trajectory, so the three engines run the one definition: the fused engine
evaluates it lane-wise, the native engine translates it into C like the model's ``rhs``, the
diffrax engine calls it as an ``Event``.

The test, at an accepted state ``x`` (the engines ask at steps that reach a checkpoint):

1. ``J = df/dx`` at ``x`` by forward mode, one JVP per state component (no Jacobian routine, so
   the lane-wise and C translations see only the model's own primitives, products and sums).
2. Its characteristic polynomial ``det(lambda I - J) = lambda^n + a_1 lambda^(n-1) + ... + a_n``
   by **Faddeev-LeVerrier** (n matrix products and traces, no pivoting, no branches), which also
   gives the adjugate, hence ``J^-1 = -M_n / c_0`` at no extra cost.
3. **Routh-Hurwitz**: all eigenvalues in the open left half-plane iff every entry of the first
   column of the Routh table is > 0 (leading coefficient 1). A zero entry (an eigenvalue on the
   imaginary axis, or a degenerate table) counts as *not* stable, so the test can only err towards
   not stopping. Unrolled for the state size: divisions and products, no branches.
4. **Distance to the equilibrium**: Newton's step ``delta = J^-1 f(x)`` is the distance to the
   equilibrium to first order (``f(x*) = 0 = f(x) + J (x* - x) + O(|delta|^2)``). The trajectory
   stops when ``RMS_i(delta_i / (atol + rtol |x_i|)) <= DISTANCE_TOL`` (1000): within 1000 tolerance
   units of the equilibrium, in the norm the step-size controller uses. Why not 1: the full run
   itself gets no closer. Near a stable equilibrium the controller lengthens the steps until they sit
   on the method's stability boundary, where the error estimate is at the tolerance, and the numerical
   solution hovers at a fixed scaled distance for ever. Measured with Tsit5, rtol = atol = 1e-8: 5-20
   units on the pendulum example (t = 300 .. 700), 240-570 units at Lorenz-63's C+ (r = 24.4, t = 800 ..
   4000: the step is held by the fast eigenvalue -13.6 while the slow focus turns at 9.6 rad/s). 1000
   lies above both; a system whose plateau lies higher never stops (the safe failure: no gain). And it
   lies far below any outcome's tolerance: the features of a stopped run differ from the full run's by
   at most ~1000 (atol + rtol |x|) (1e-5 relative at rtol = 1e-8), while rule bounds and template
   neighbourhoods are ~1e-3 and up and discovery's grouping scale is never below 1e4 tolerances. This is
   the "|f| below a threshold from the tolerances": ``|f|`` measured through ``J^-1``, which makes it
   dimensionally right -- a slow equilibrium (small eigenvalues, near a bifurcation) needs a much
   smaller ``|f|`` than a fast one -- and a saddle with ``f = 0`` fails step 3. The late-window features
   of the stopped run are those of the frozen state (mean = x, std = 0, min = max = x, see
   :func:`fast_forward`); the full run's stay within the plateau above of the same equilibrium, so no
   outcome changes.

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
from .features import fold_observation  # the feature rows are the fold's: one definition

# stop within this many tolerance units (atol + rtol |x_i|, RMS) of the equilibrium (module docstring)
DISTANCE_TOL = 1000.0

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


# ---- the test ------------------------------------------------------------------------------------------------

def jacobian(rhs, t, y, args):
    """``f(t, y)`` and ``J = df/dy`` (n forward-mode JVPs, columns stacked)."""
    n = y.shape[0]
    eye = np.eye(n)  # constants: the lane-wise and C translations fold them
    f = None
    cols = []
    for i in range(n):
        fi, ji = jax.jvp(lambda z: rhs(t, z, args), (y,), (jnp.asarray(eye[i], y.dtype),))
        f = fi if f is None else f
        cols.append(ji)
    return f, jnp.stack(cols, axis=1)


def charpoly_adjugate(J):
    """Faddeev-LeVerrier: ``(a, M)`` with ``det(lambda I - J) = lambda^n + a[0] lambda^(n-1) + ... + a[n-1]``
    and ``M`` the last matrix of the recursion, so that ``J^-1 = -M / a[n-1]`` (when invertible).
    Matrix products and traces only (unrolled for the static size n)."""
    n = J.shape[0]
    eye = np.eye(n)
    M = jnp.zeros_like(J)
    c = jnp.ones((), J.dtype)
    a = []
    for k in range(1, n + 1):
        M = J @ M + c * eye
        P = J @ M
        c = -sum(P[i, i] for i in range(n)) / k
        a.append(c)
    return jnp.stack(a), M


def hurwitz(a):
    """All roots of ``lambda^n + a[0] lambda^(n-1) + ... + a[n-1]`` in the open left half-plane
    (Routh's table; a zero or negative first-column entry: False). Plain arithmetic, unrolled."""
    n = a.shape[0]
    coeffs = [jnp.ones((), a.dtype)] + [a[i] for i in range(n)]
    row0 = coeffs[0::2]
    row1 = coeffs[1::2]
    zero = jnp.zeros((), a.dtype)
    ok = jnp.ones((), bool)
    width = len(row0)
    row0 = row0 + [zero] * (width - len(row0))
    row1 = row1 + [zero] * (width - len(row1))
    for _ in range(n):  # rows 1 .. n of the table; each first entry must be > 0
        lead = row1[0]
        ok = ok & (lead > 0)
        safe = jnp.where(lead > 0, lead, 1.0)
        nxt = [(lead * row0[j + 1] - row0[0] * row1[j + 1]) / safe for j in range(width - 1)] + [zero]
        row0, row1 = row1, nxt
    return ok


def at_fixed_point(rhs, t, y, args, rtol: float, atol: float):
    """The stop predicate (traced, one trajectory): ``y`` lies within the solver tolerance of an
    equilibrium whose Jacobian is Hurwitz (see the module docstring). Returns a bool scalar."""
    f, J = jacobian(rhs, t, y, args)
    a, M = charpoly_adjugate(J)
    stable = hurwitz(a)
    det_like = a[-1]  # c_0 = det(-J): > 0 for a Hurwitz J (all its coefficients are)
    safe = jnp.where(det_like != 0, det_like, 1.0)
    delta = -(M @ f) / safe  # J^-1 f
    scale = atol + rtol * jnp.abs(y)
    dist = jnp.sqrt(jnp.mean((delta / scale) ** 2))
    finite = jnp.all(jnp.isfinite(f)) & jnp.isfinite(dist)
    return stable & finite & (dist <= DISTANCE_TOL)


# ---- the fold after a stop ----------------------------------------------------------------------------------

def window_index(ts: np.ndarray, vcfg) -> int:
    """Index of the first checkpoint inside the feature window (as :func:`stabjax.fold.verdict.update` tests it)."""
    t0 = float(vcfg.t0) if vcfg.t1 is not None else 0.0
    span = (float(vcfg.t1) - t0) if vcfg.t1 is not None else float(ts[-1])
    inw = (np.asarray(ts, float) - t0) >= span * (1.0 - vcfg.feature_window)
    return int(np.argmax(inw)) if inw.any() else len(ts)


def fast_forward(c, n_in, obs, xp=jnp):
    """The fold state ``c`` after ``n_in`` more checkpoints inside the feature window, all observing
    ``obs`` (the frozen state's observables), and ``obs`` as the final value: the late-window
    features of a run that stays at the stopped state (mean, min, max include it; its spread adds
    nothing). The attitude-verdict entries of the fold are left as they were at the stop (those
    verdicts are never computed from a stopped run, :func:`resolve`). One trajectory in JAX (the
    fused engine vmaps it), or with ``xp=numpy`` a batch at once (leading dims; ``n_in`` shaped
    (..., 1)): the native engine applies it on the host without a compile per batch size."""
    if "feat" not in c:
        return c
    out = dict(c)
    out["feat"] = fold_observation(c["feat"], obs, n_in, xp)
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
    trajectory; the radii never overlap, so at most one holds). Plain arithmetic and min reductions."""
    pts = known.points  # constants: the lane-wise and C translations fold them
    scale = np.asarray(known.scale)
    o = obs[: pts.shape[2]] / scale
    k_out = jnp.asarray(-1.0, jnp.float64)
    for k in range(pts.shape[0]):
        d2 = jnp.min(jnp.sum((o[None, :] - pts[k] / scale) ** 2, axis=1))
        k_out = jnp.where(d2 <= known.eps[k] ** 2, float(k), k_out)
    return k_out


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
           "active", "jacobian", "charpoly_adjugate", "hurwitz", "at_fixed_point", "window_index", "fast_forward",
           "stop_reasons", "KnownAttractors", "known_attractors", "known_for", "with_known", "near_attractor", "substitute", "attractor_stop_active",
           "STOP_ATTRACTOR", "HIT_NONE", "HIT_FIXED_POINT", "HIT_ATTRACTOR0", "CLOUD_POINTS", "TEST_EVERY",
           "fixed_point_every"]
