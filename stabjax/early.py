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

``stop_reason`` codes (per trajectory, CF ``flag_values`` / ``flag_meanings``): :data:`REASONS`.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .errors import ValidationError

# stop within this many tolerance units (atol + rtol |x_i|, RMS) of the equilibrium (module docstring)
DISTANCE_TOL = 1000.0

# the lane engines ask at most once per TEST_EVERY checkpoints of a lane: the test costs about n
# right-hand sides (n JVPs) and was measured at +9 % wall on the pendulum when asked at every step that
# reached a checkpoint (native engine, 4000 checkpoints); a stop comes at most 8 checkpoint intervals later
TEST_EVERY = 8

STOP_NONE, STOP_ESCAPED, STOP_FIXED_POINT, STOP_FAILED = 0, 1, 2, 3
REASONS = ("none", "escaped", "fixed_point", "failed")
REASON_DOC = ("stop_reason: why the integration ended before t1: none (ran to t1), escaped (left the escape "
              "radius), fixed_point (reached a stable equilibrium within the solver tolerance; stabjax.early), "
              "failed (solver failure)")
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
    """Index of the first checkpoint inside the feature window (as :func:`stabjax.verdict.update` tests it)."""
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
    fe = c["feat"]
    F = fe.shape[-1]
    m = min(int(obs.shape[-1]), F)
    o = obs[..., :m].astype(fe.dtype)
    w = xp.asarray(n_in, fe.dtype)
    has = w > 0
    rows = [xp.where(has, xp.maximum(fe[..., 0, :m], o), fe[..., 0, :m]),
            xp.where(has, xp.minimum(fe[..., 1, :m], o), fe[..., 1, :m]),
            fe[..., 2, :m] + w * o, fe[..., 3, :m] + w * o * o, fe[..., 4, :m] + w * xp.ones_like(o), o]
    head = xp.stack(rows, axis=-2)
    out = dict(c)
    out["feat"] = head if m == F else xp.concatenate([head, fe[..., m:]], axis=-1)
    return out


def stop_reasons(status, fixed):
    """``stop_reason`` codes from the solver status and the fixed-point flag (NumPy)."""
    from .status import ESCAPED as STATUS_ESCAPED, OK as STATUS_OK

    status = np.asarray(status)
    out = np.where(status == STATUS_OK, STOP_NONE, np.where(status == STATUS_ESCAPED, STOP_ESCAPED, STOP_FAILED))
    return np.where(np.asarray(fixed, bool) & (status == STATUS_OK), STOP_FIXED_POINT, out).astype(np.int8)


__all__ = ["REASONS", "STOP_NONE", "STOP_ESCAPED", "STOP_FIXED_POINT", "STOP_FAILED", "is_autonomous", "resolve",
           "active", "jacobian", "charpoly_adjugate", "hurwitz", "at_fixed_point", "window_index", "fast_forward",
           "stop_reasons"]
