"""The fixed-point stop's test: has the state entered, for certain, the neighbourhood of a stable equilibrium?

A trajectory may stop early at a stable equilibrium ``x*`` only if the run without the stop would have
given it the same outcome, at any solver tolerance (issue 29: at atol = 1e-6 a stop "within 1000
tolerance units" froze the pendulum at |omega| ~ 1e-3, the example's rule bound, and 126 of 10^4 starts
became ``unclassified``). So the stop does not freeze the state where it is: it **finishes at the
equilibrium**. The stopped run's late-window features are those of ``x*`` itself (mean = min = max = final
= the observables at ``x*``, spread 0), which is the trajectory's limit, and the stop is taken only when the
trajectory is *certain* to lie within one tolerance unit of ``x*`` per state component through the whole
feature window -- closer than the run without the stop can resolve. Every rule, template or discovery
step therefore sees the same features, up to the full run's own numerical error around ``x*``.

The test at an accepted state ``y`` at time ``t`` (plain JAX on one trajectory: the fused engine evaluates
it lane-wise, the native engine translates it to C; the diffrax engine runs every start to t1):

1. ``J = df/dy`` (one JVP per state component); its characteristic polynomial and adjugate by
   **Faddeev-LeVerrier**; **Routh-Hurwitz**: every eigenvalue in the open left half-plane (a zero or
   negative first-column entry counts as not stable, so the test errs towards not stopping).
2. **Distance**: Newton's step ``delta = J^-1 f(y)``, RMS in tolerance units ``atol + rtol |y_i|`` (the
   step-size controller's norm), at most :data:`DISTANCE_TOL` -- a cheap first filter.
3. **The equilibrium**: :data:`CHORD_STEPS` more chord-Newton steps with the same ``J^-1`` (one
   right-hand side each); the last correction must be below :data:`CONVERGED` tolerance units.
4. **Its Lyapunov function.** In scaled coordinates ``z = D^-1 (x - x*)``, ``D = diag(atol + rtol |x*_i|)``,
   the linearisation is ``J_z = D^-1 J D`` (J's eigenvalues). ``mu`` = :data:`SHIFT_SHARE` times the decay
   rate of the slowest mode (:func:`abscissa`: bisection with Routh-Hurwitz on the shifted characteristic
   polynomial), and ``P`` solves ``(J_z + mu I)^T P + P (J_z + mu I) = -I`` (:func:`lyapunov`), so along the
   linear flow ``V = z^T P z`` falls at least at the rate ``2 mu + 1 / lambda_max(P)`` (``lambda_max``
   bounded above by Gershgorin's and the trace's bounds). Over the sublevel set ``V <= c`` the largest
   ``|z_i|`` is ``sqrt(c (P^-1)_ii)``.
5. **The nonlinear remainder** ``r = D^-1 (f(y) - J (y - x*))`` at ``y``, per unit of distance ``e = |r| /
   max(|z|, 1)`` (a rate; below one unit its size is rounding), changes ``V`` at a relative rate of at most
   ``2 e sqrt(kappa(P))`` (Cauchy-Schwarz in the ``P`` norm), doubled because ``J`` is taken at ``y``, not
   at ``x*``: ``m = 4 e sqrt(kappa)``, which may take at most :data:`MARGIN_MAX` of ``2 mu``; the Lyapunov
   equation's residual ``rho`` (Frobenius) is at most :data:`RESIDUAL_MAX`. The rate used is ``2 mu + (1 -
   rho) / lambda_max - m``. The remainder is measured at the state, not bounded over the sublevel set (it
   scales with the distance, which ``V``'s decay shrinks and a non-normal flow may transiently stretch):
   an estimate, with the factor 2 above as room, not a proof for every model. The tests check the promise
   against SciPy on linear systems (exact) and on the pendulum.
6. **Certain arrival**: the state is ahead of the feature window (``t < t_window``, no window checkpoint
   folded yet) and ``V(z(y)) max_i (P^-1)_ii exp(-rate (t_window - t)) <= 1``: from the window's start on,
   every component stays within one tolerance unit of ``x*``.

Why one tolerance unit: the run without the stop gets no closer. Near a stable equilibrium the controller
lengthens the steps to the method's stability boundary and the numerical solution hovers at a plateau of
5-20 units (pendulum, Tsit5) to 240-570 units (Lorenz-63's C+); the stopped run's features are the exact
limit, the full run's are within its plateau of it. A rule bound that close to ``x*`` would make the full
run's own outcome a matter of rounding.

What it costs: ``n`` JVPs, ``CHORD_STEPS`` right-hand sides, :data:`BISECTIONS` Routh tables, a Lyapunov
equation (:data:`SMITH_DOUBLINGS` products of n x n matrices) and two inverses, asked at most ~48 times per trajectory
(:func:`stabjax.fold.stops.fixed_point_every`). What it gives up: a slowly decaying equilibrium (near a
bifurcation) stops late or not at all -- the safe failure, no gain, never a changed outcome.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# first filter: within this many tolerance units (RMS of Newton's step) of the equilibrium
DISTANCE_TOL = 1000.0
# chord-Newton steps from the state to the equilibrium, and the largest last correction (tolerance units)
CHORD_STEPS = 3
CONVERGED = 1e-3
# Smith's doubling after a Cayley transform: the sum covers 2^30 powers of the discrete map, enough for a
# ratio of ~10^8 between the fastest and the slowest decay rate (a stiffer equilibrium: residual too large,
# no stop)
SMITH_DOUBLINGS = 30
RESIDUAL_MAX = 0.1  # |J_z^T P + P J_z + I|_F
MARGIN_MAX = 0.5    # share of the shifted decay rate 2 mu the nonlinear remainder may take
# the Lyapunov function of J + mu I, mu = SHIFT_SHARE times the decay rate of J's slowest mode: V falls at
# least at 2 mu (Q = I alone gives 1 / lambda_max(P), which a badly scaled or lightly damped J makes tiny:
# 3.5e-4 against 0.05 on the pendulum at theta = -24.6); closer to 1 the transient factor of P grows
SHIFT_SHARE = 0.9
BISECTIONS = 16
# the Lyapunov equation solved directly up to this many states (10 unknowns: the lane engines unroll a
# solve of at most 12), by Smith's doubling above
DIRECT_MAX = 4


def jacobian(rhs, t, y, args):
    """``f(t, y)`` and ``J = df/dy`` (n forward-mode JVPs, columns stacked)."""
    n = y.shape[0]
    eye = np.eye(n)  # constants: the lane-wise and C translations fold them
    f = None
    cols = []
    for i in range(n):
        fi, ji = jax.jvp(lambda z: rhs(t, z, args), (y,), (eye[i].astype(y.dtype),))
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
    c = np.ones((), J.dtype)  # constants in NumPy: a jnp constant is an eager dispatch at every trace
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
    coeffs = [np.ones((), a.dtype)] + [a[i] for i in range(n)]
    row0 = coeffs[0::2]
    row1 = coeffs[1::2]
    zero = np.zeros((), a.dtype)
    ok = np.ones((), bool)
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


def shifted(a, mu):
    """Coefficients (leading 1 left out) of ``p(lambda - mu)``: the characteristic polynomial of ``J + mu I``
    from that of ``J`` (Taylor shift by repeated synthetic division, O(n^2), unrolled)."""
    n = a.shape[0]
    c = [np.ones((), a.dtype)] + [a[i] for i in range(n)]
    for i in range(n):
        for j in range(1, n + 1 - i):
            c[j] = c[j] - mu * c[j - 1]
    return jnp.stack(c[1:])


def abscissa(a):
    """A lower bound, within a relative 6e-4, of ``-max Re(lambda)`` over the roots of ``lambda^n + a[0]
    lambda^(n-1) + ... + a[n-1]`` (for a Hurwitz polynomial; else ~0): geometric bisection of the largest
    ``mu`` for which ``p(lambda - mu)`` is still Hurwitz, between ``R = -trace(J) / n = a[0] / n`` (the mean
    real part: ``J + R I`` has trace 0, not Hurwitz) and ``1e-16 R``, in :data:`BISECTIONS` steps."""
    R = a[0] / a.shape[0]  # -trace / n: J + R I has trace 0, so it is not Hurwitz
    lo, hi = R * 1e-16, R
    for _ in range(BISECTIONS):
        mid = jnp.sqrt(lo * hi)
        ok = hurwitz(shifted(a, mid))
        lo = jnp.where(ok, mid, lo)
        hi = jnp.where(ok, hi, mid)
    return lo


def lyapunov(J, s):
    """``(P, residual)``: ``P`` with ``J^T P + P J = -I`` for a Hurwitz ``J``, and ``|J^T P + P J + I|_F``: the
    ``n (n + 1) / 2`` equations for the entries of the symmetric ``P`` solved directly (one small solve: one
    library call in XLA, an unrolled elimination in the lane engines) up to :data:`DIRECT_MAX` states, beyond by
    :func:`smith` (whose products the lane engines unroll at any size)."""
    n = J.shape[0]
    if n > DIRECT_MAX:
        return smith(J, s)
    idx = [(i, j) for i in range(n) for j in range(i, n)]
    pos = {ij: k for k, ij in enumerate(idx)}
    pos.update({(j, i): k for (i, j), k in list(pos.items())})
    m = len(idx)
    # (J^T P + P J)_ij = sum_k J_ki P_kj + P_ik J_kj
    rows = []
    for (i, j) in idx:
        row = [np.zeros((), J.dtype)] * m
        for k in range(n):
            row[pos[(k, j)]] = row[pos[(k, j)]] + J[k, i]
            row[pos[(i, k)]] = row[pos[(i, k)]] + J[k, j]
        rows.append(jnp.stack(row))
    rhs = np.asarray([-1.0 if i == j else 0.0 for (i, j) in idx], J.dtype)
    v = jnp.linalg.solve(jnp.stack(rows), rhs)
    P = jnp.stack([jnp.stack([v[pos[(i, j)]] for j in range(n)]) for i in range(n)])
    R = J.T @ P + P @ J + np.eye(n)
    return P, jnp.sqrt(jnp.sum(R * R))


def smith(J, s):
    """``(P, residual)``: ``P`` with ``J^T P + P J = -I`` for a Hurwitz ``J``, and ``|J^T P + P J + I|_F``.

    The Cayley transform ``A = (s I + J)(s I - J)^-1`` (``s > 0``) maps the continuous equation to the
    Stein equation ``P - A^T P A = 2 s B^T B``, ``B = (s I - J)^-1``, whose solution ``sum_k (A^k)^T 2 s B^T B
    A^k`` Smith's doubling sums in :data:`SMITH_DOUBLINGS` steps (``X += A^T X A; A = A A``): matrix products
    and one n x n inverse, no eigenvalues. ``s`` near the eigenvalues' magnitude (the caller takes
    ``|det J|^(1/n)``) keeps the discrete map's slowest mode fastest. A truncated sum shows up in the
    residual."""
    n = J.shape[0]
    eye = np.eye(n)
    B = jnp.linalg.inv(s * eye - J)
    A = (s * eye + J) @ B
    X = 2.0 * s * (B.T @ B)
    for _ in range(SMITH_DOUBLINGS):
        X = X + A.T @ X @ A
        A = A @ A
    P = 0.5 * (X + X.T)
    R = J.T @ P + P @ J + eye
    return P, jnp.sqrt(jnp.sum(R * R))


def _lambda_max(S):
    """An upper bound of the largest eigenvalue of a symmetric positive definite ``S``: the smaller of its
    trace and Gershgorin's bound (the largest absolute row sum)."""
    n = S.shape[0]
    return jnp.minimum(sum(S[i, i] for i in range(n)), jnp.max(jnp.sum(jnp.abs(S), axis=1)))


def fixed_point_stop(rhs, t, y, args, rtol: float, atol: float, t_window: float):
    """``(stop, x_star)`` at the state ``y`` at time ``t`` (traced, one trajectory): whether the trajectory
    is certain to stay within one tolerance unit of the stable equilibrium ``x_star`` through the feature
    window that starts at ``t_window`` (the module docstring), and that equilibrium."""
    q = assess(rhs, t, y, args, rtol, atol, t_window)
    return q["stop"], q["x_star"]


def assess(rhs, t, y, args, rtol: float, atol: float, t_window: float) -> dict:
    """Every quantity of :func:`fixed_point_stop`'s decision, by name (``stop``, ``x_star``, ``dist``, ``conv``,
    ``mu``, ``res``, ``box``, ``m``, ``rate``, ...): the stop and the benchmarks read them."""
    n = y.shape[0]
    f, J = jacobian(rhs, t, y, args)
    a, M = charpoly_adjugate(J)
    stable = hurwitz(a)
    c0 = a[-1]  # det(-J): > 0 for a Hurwitz J (all its coefficients are)
    safe = jnp.where(c0 != 0, c0, 1.0)
    Jinv = -M / safe
    delta = Jinv @ f
    dist = jnp.sqrt(jnp.mean((delta / (atol + rtol * jnp.abs(y))) ** 2))
    x = y - delta
    last = delta
    for _ in range(CHORD_STEPS):
        last = Jinv @ rhs(t, x, args)
        x = x - last
    scale = atol + rtol * jnp.abs(x)
    conv = jnp.sqrt(jnp.mean((last / scale) ** 2))
    Jz = J * scale[None, :] / scale[:, None]
    # V = z^T P z with (J_z + mu I)^T P + P (J_z + mu I) = -I falls at the rate 2 mu + 1 / lambda_max(P)
    mu = SHIFT_SHARE * abscissa(a)  # J_z has J's eigenvalues
    a_mu = shifted(a, mu)
    s = jnp.exp(jnp.log(jnp.abs(jnp.where(a_mu[-1] != 0, a_mu[-1], 1.0))) / n)  # |det(J + mu I)|^(1/n)
    P, res = lyapunov(Jz + mu * np.eye(n), s)
    Pinv = jnp.linalg.inv(P)
    z = (y - x) / scale
    zz = jnp.sum(z * z)
    V = z @ P @ z
    box = V * jnp.max(jnp.stack([Pinv[i, i] for i in range(n)]))  # max_i z_i^2 over {V' <= V}
    lam = _lambda_max(P)
    kappa = lam * _lambda_max(Pinv)  # condition number of P, bounded above
    # the nonlinear remainder at the state, per unit of distance (a rate); below one tolerance unit of
    # distance its size is rounding, not curvature
    r = (f - J @ (y - x)) / scale
    e = jnp.sqrt(jnp.sum(r * r) / jnp.maximum(zz, 1.0))
    m = 4.0 * e * jnp.sqrt(kappa)
    rate = 2.0 * mu + (1.0 - res) / lam - m
    arrived = jnp.log(jnp.maximum(box, 1e-300)) <= rate * (t_window - t)
    finite = jnp.all(jnp.isfinite(f)) & jnp.all(jnp.isfinite(x)) & jnp.isfinite(box) & jnp.isfinite(rate)
    ok = (stable & hurwitz(a_mu) & finite & (dist <= DISTANCE_TOL) & (conv <= CONVERGED) & (res <= RESIDUAL_MAX)
          & (m <= MARGIN_MAX * 2.0 * mu) & (t < t_window) & arrived)
    return dict(stop=ok, x_star=x, stable=stable, dist=dist, conv=conv, mu=mu, res=res, box=box, lam=lam, e=e,
                kappa=kappa, m=m, rate=rate, arrived=arrived)


def near_stable(rhs, t, y, args, rtol: float, atol: float):
    """Steps 1-2 alone: a Hurwitz Jacobian and Newton's step within :data:`DISTANCE_TOL` tolerance units (a
    bool scalar). The engines ask this cheap question first, and the whole test (~20 times its cost: the
    bisection and the Lyapunov equation) only where some lane says yes."""
    f, J = jacobian(rhs, t, y, args)
    a, M = charpoly_adjugate(J)
    c0 = a[-1]
    delta = -(M @ f) / jnp.where(c0 != 0, c0, 1.0)
    dist = jnp.sqrt(jnp.mean((delta / (atol + rtol * jnp.abs(y))) ** 2))
    return hurwitz(a) & jnp.all(jnp.isfinite(f)) & (dist <= DISTANCE_TOL)


def at_fixed_point(rhs, t, y, args, rtol: float, atol: float, t_window: float):
    """The stop predicate alone (a bool scalar; :func:`fixed_point_stop`)."""
    return fixed_point_stop(rhs, t, y, args, rtol, atol, t_window)[0]


__all__ = ["DISTANCE_TOL", "CHORD_STEPS", "CONVERGED", "SMITH_DOUBLINGS", "RESIDUAL_MAX", "MARGIN_MAX", "SHIFT_SHARE",
           "BISECTIONS", "jacobian", "charpoly_adjugate", "hurwitz", "shifted", "abscissa", "lyapunov", "smith", "near_stable",
           "fixed_point_stop", "at_fixed_point"]
