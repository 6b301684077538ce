"""Theorem predicates of Saakyan's active stabilisation of rotation, vectorised over batches.

Saakyan (1974), documented in ``docs/models/saakyan.md``. Every function takes NumPy arrays
whose leading dimensions are batch dimensions (vectors carry a trailing axis of 3) and
returns arrays; predicates come back as :class:`stabjax.model.system.Predicate` with a signed
margin (> 0: the hypothesis holds).

Notation: ``I = (A, B, C)`` principal moments (in B-3/B-4 the reduced moments C_i - J_i),
``H`` the body axis H0 (unit), ``lam`` the spin rate lambda, ``K = alpha/lam`` the gain
(``h`` in B-3/B-4, where alpha = lam h), ``nu = 3 g0/R``.

Steady spins (the invariant set of the invariance argument)
-----------------------------------------------------------
On the set E where dV/dt = 0 (w1 = lam delta, (1.13)) the closed loops of B-1..B-4 reduce,
with delta = S - H constant, to one tangent vector field on the unit sphere [D]:

    F(S) = lam K H x delta - lam^2 S x (I delta) + nu S x (Ig delta) = 0,

(Ig = I in B-2, the gyrostat moments C_i in B-4, nu = 0 in B-1/B-3); for nu = 0 this is
lam times the F of (1.14) in its vector form. F is tangent to the sphere, so by Poincare-Hopf a
nondegenerate target zero at S = H always comes with at least one other zero: there is
always an off-target steady spin ``omega = omega0 + lam S0``, which is why the radius l of
(1.18) is finite and why the global ("in the large") claims of Theorems 3-4 cannot hold.
:func:`steady_spins` finds all zeros (Levenberg-Marquardt on the sphere from a Fibonacci
grid of starts, docs/models/saakyan.md, "The l of (1.18)"); :func:`l_spurious` takes the smallest
|delta| over the nonzero ones; :func:`l_116` solves the paper's scalar equation (1.16).

Regions of initial conditions: every theorem that guarantees one states it as ``derived["radius_<theorem>"]``, a radius
in the norm max(|w1(0)|/lam, |delta(0)|) (:func:`_radius`), for the minimal-fatal-shock search (``[shock] theory``).

Size (~640 lines): the theorems of one paper (predicates, steady spins, the radius l of (1.18)) over
shared notation; each predicate is tested against the paper's statements in tests/systems/test_saakyan_theory.py.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..model.system import Predicate, Theory

AXIS_TOL = 1e-9  # |H_k| > 1 - AXIS_TOL: H0 counts as lying along principal axis k
LAM2NU_TOL = 1e-9  # |lam^2/nu - 1| below this: Theorem 2's knife edge lam^2 = nu holds


# ---------------------------------------------------------------------------------------------
# small vector helpers (batched, trailing axis 3)


def _cross(a, b):
    return np.cross(a, b)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _f(x):
    return np.asarray(x, dtype=float)


def principal_axis(H, tol: float = AXIS_TOL) -> np.ndarray:
    """Index k of the principal axis H0 lies along (either sense), -1 if none."""
    H = _unit(H)
    k = np.argmax(np.abs(H), axis=-1)
    along = np.take_along_axis(np.abs(H), k[..., None], axis=-1)[..., 0] > 1 - tol
    return np.where(along, k, -1)


def axis_roles(I):
    """(m1, m_mid, m2) = max, middle, min of the moments."""
    s = np.sort(_f(I), axis=-1)
    return s[..., 2], s[..., 1], s[..., 0]


# ---------------------------------------------------------------------------------------------
# B-1 conditions


def c110(I, lam, K) -> Predicate:
    """(1.10): alpha > lam^2 m1, i.e. K > lam m1. Margin K/(lam m1) - 1."""
    m1 = axis_roles(I)[0]
    margin = _f(K) / (_f(lam) * m1) - 1.0
    return Predicate(margin > 0, margin, "(1.10) alpha > lam^2 m1 (K > lam max(A,B,C)): V positive definite")


def c121(I, H, lam, K) -> Predicate:
    """(1.21): H0 along a principal axis and K > lam (3 m1 - 2 m2). Margin K/(lam(3m1-2m2)) - 1."""
    m1, _, m2 = axis_roles(I)
    margin = _f(K) / (_f(lam) * (3 * m1 - 2 * m2)) - 1.0
    ok = (principal_axis(H) >= 0) & (margin > 0)
    return Predicate(ok, margin, "(1.21) H0 principal, (K - lam m1)/(lam (m1 - m2)) > 2: region (1.22) with l = 2")


def middle_axis_bound(I, lam):
    """The paper's middle-axis gain bound lam max{2 I_mid - I_min, 3 I_max - 2 I_mid} (A > B > C relabelled)."""
    m1, mm, m2 = axis_roles(I)
    return _f(lam) * np.maximum(2 * mm - m2, 3 * m1 - 2 * mm)


def middle_axis(I, H, lam, K) -> Predicate:
    """Middle-axis condition K > max{lam(2B - C), lam(3A - 2B)} (paper: A > B > C, H0 along y).

    ``ok`` only where H0 lies along the axis of the middle moment (distinct moments) and
    (1.10) holds; the margin K/bound - 1 is reported everywhere.
    """
    I = _f(I)
    k = principal_axis(H)
    order = np.argsort(I, axis=-1)
    mid = order[..., 1]
    distinct = (np.diff(np.sort(I, axis=-1), axis=-1) > 0).all(axis=-1)
    margin = _f(K) / middle_axis_bound(I, lam) - 1.0
    ok = (k == mid) & distinct & (margin > 0) & c110(I, lam, K).ok
    return Predicate(ok, margin, "middle axis: K > lam max{2 I_mid - I_min, 3 I_max - 2 I_mid} (paper, A > B > C, H0 || y)")


def exact_axis_bound(I, H, lam):
    """[D] For H0 = e_k: no spurious steady spin iff K >= lam max_{j: I_j < I_k} (2 I_k - I_j).

    Returns that bound combined with (1.10) (max with lam m1); NaN where H0 is not principal.
    """
    I = _f(I)
    k = principal_axis(H)
    kk = np.maximum(k, 0)
    Ik = np.take_along_axis(I, kk[..., None], axis=-1)[..., 0]
    cand = np.where(I < Ik[..., None], 2 * Ik[..., None] - I, -np.inf)
    bound = _f(lam) * np.maximum(cand.max(axis=-1), axis_roles(I)[0])
    return np.where(k >= 0, bound, np.nan)


def no_spurious_exact(I, H, lam, K) -> Predicate:
    """[D] principal-axis H0: (1.10) and no off-target steady spin other than the inverted one."""
    b = exact_axis_bound(I, H, lam)
    with np.errstate(invalid="ignore"):
        margin = _f(K) / b - 1.0
    ok = np.isfinite(margin) & (margin > 0)
    return Predicate(ok, np.where(np.isfinite(margin), margin, -1.0),
                     "[D] H0 = e_k: K > lam max(m1, max_{I_j < I_k}(2 I_k - I_j)) -- no spurious steady spins")


def principal_circles(I, H, lam, K):
    """[D] Spurious-spin circles for H0 = e_k: delta_k = (K - lam I_j)/(lam (I_j - I_k)) for j != k.

    Returns (N, 3) array of |delta| = sqrt(-2 delta_k) for each j (NaN where j = k, where
    the circle does not exist, i.e. delta_k not in (-2, 0), or where H0 is not principal).
    """
    I = _f(I)
    lam, K = _f(lam)[..., None], _f(K)[..., None]
    k = principal_axis(H)
    kk = np.maximum(k, 0)
    Ik = np.take_along_axis(I, kk[..., None], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        dk = (K - lam * I) / (lam * (I - Ik))
        ln = np.sqrt(-2 * dk)
    exists = (dk > -2) & (dk < 0) & (np.arange(3) != kk[..., None]) & (k[..., None] >= 0)
    return np.where(exists, ln, np.nan)


def bracket_phi0(I, H):
    """The bracket of phi(0) (instability without mu): b1^2 b2^2 (A-B)^2 + b1^2 b3^2 (A-C)^2 + b2^2 b3^2 (C-B)^2."""
    I, b = _f(I), _unit(H)
    A, B, C = I[..., 0], I[..., 1], I[..., 2]
    b1, b2, b3 = b[..., 0] ** 2, b[..., 1] ** 2, b[..., 2] ** 2
    return b1 * b2 * (A - B) ** 2 + b1 * b3 * (A - C) ** 2 + b2 * b3 * (C - B) ** 2


# ---------------------------------------------------------------------------------------------
# steady spins


def tangent_field(S, I, Ig, H, lam, K, nu):
    """F(S) = lam K H x d - lam^2 S x (I d) + nu S x (Ig d), d = S - H (see module doc)."""
    d = S - H
    return (lam * K)[..., None] * _cross(H, d) - (lam**2)[..., None] * _cross(S, I * d) + nu[..., None] * _cross(S, Ig * d)


def _hat(v):
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
         np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _jac(S, I, Ig, H, lam, K, nu):
    d = S - H
    eye = np.eye(3)
    dI, dIg = I[..., :, None] * eye, Ig[..., :, None] * eye
    return ((lam * K)[..., None, None] * _hat(H)
            - (lam**2)[..., None, None] * (_hat(S) @ dI - _hat(I * d))
            + nu[..., None, None] * (_hat(S) @ dIg - _hat(Ig * d)))


def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def _steady_spins_unique(I, Ig, H, lam, K, nu, n_start, iters):
    """Core of :func:`steady_spins` for (U,) rows: returns S (U, M, 3) and converged mask (U, M)."""
    U = I.shape[0]
    S = np.broadcast_to(fibonacci_sphere(n_start), (U, n_start, 3)).copy()
    ex = lambda a: np.broadcast_to(a[:, None], (U, n_start) + a.shape[1:])  # noqa: E731
    Ie, Ige, He, le, Ke, ne = ex(I), ex(Ig), ex(H), ex(lam), ex(K), ex(nu)
    scale = le * Ke + le**2 * Ie.max(-1) + np.abs(ne) * Ige.max(-1)
    for _ in range(iters):
        F = tangent_field(S, Ie, Ige, He, le, Ke, ne) / scale[..., None]
        J = _jac(S, Ie, Ige, He, le, Ke, ne) / scale[..., None, None]
        # tangent basis at S
        ax = np.argmin(np.abs(S), axis=-1)
        e = np.eye(3)[ax]
        t1 = _unit(_cross(S, e))
        t2 = _cross(S, t1)
        T = np.stack([t1, t2], -1)  # (U, M, 3, 2)
        Jr = J @ T
        A = np.swapaxes(Jr, -1, -2) @ Jr + 1e-12 * np.eye(2)
        g = np.swapaxes(Jr, -1, -2) @ F[..., None]
        c = -np.linalg.solve(A, g)[..., 0]
        step = (T @ c[..., None])[..., 0]
        sn = np.linalg.norm(step, axis=-1, keepdims=True)
        step = step * np.minimum(1.0, 0.5 / np.maximum(sn, 1e-300))
        S = _unit(S + step)
    res = np.linalg.norm(tangent_field(S, Ie, Ige, He, le, Ke, ne), axis=-1) / scale
    return S, res < 1e-9


def _unique_rows(*arrays):
    """Stack per-row model parameters, return (unique block, inverse index)."""
    cols = [np.asarray(a, float).reshape(a.shape[0], -1) for a in arrays]
    block = np.concatenate(cols, axis=1)
    uniq, inv = np.unique(block, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)


def steady_spins(I, H, lam, K, nu=0.0, Ig=None, n_start: int = 48, iters: int = 40):
    """All zeros of the tangent field F on the sphere (see module doc), batched.

    Returns ``(S, ok)``: candidate solutions S (..., n_start, 3) (duplicates kept) and a mask
    of converged ones. Model rows are de-duplicated first, so a sweep's samples cost nothing.
    """
    I = _f(I)
    H = _unit(H)
    bshape = np.broadcast_shapes(I.shape[:-1], H.shape[:-1], np.shape(lam), np.shape(K), np.shape(nu))
    Ig = I if Ig is None else _f(Ig)
    I, Ig, H = (np.broadcast_to(a, bshape + (3,)).reshape(-1, 3) for a in (I, Ig, H))
    lam, K, nu = (np.broadcast_to(_f(a), bshape).reshape(-1) for a in (lam, K, nu))
    uniq, inv = _unique_rows(I, Ig, H, lam[:, None], K[:, None], nu[:, None])
    S, ok = _steady_spins_unique(uniq[:, 0:3], uniq[:, 3:6], uniq[:, 6:9], uniq[:, 9], uniq[:, 10], uniq[:, 11],
                                 n_start, iters)
    return S[inv].reshape(bshape + (n_start, 3)), ok[inv].reshape(bshape + (n_start,))


def spurious_summary(I, H, lam, K, nu=0.0, Ig=None, **kw):
    """(l, delta_l, c*) from one call of :func:`steady_spins`.

    l: smallest |delta| = |S - H| over off-target steady spins (the l of (1.18)), inf if none;
    delta_l: that spin's delta (NaN if none); c*: min over off-target spins of the (w1, delta)
    part of V, 1/2 sum (lam K + nu Ig_i - lam^2 I_i) delta_i^2 (docs/models/saakyan.md, "Theorems as implemented").
    """
    H = _unit(H)
    I = _f(I)
    Igv = I if Ig is None else _f(Ig)
    S, ok = steady_spins(I, H, lam, K, nu, Igv, **kw)
    bshape = ok.shape[:-1]
    d = S - np.broadcast_to(H, bshape + (3,))[..., None, :]
    dn = np.linalg.norm(d, axis=-1)
    good = ok & (dn > 1e-6)
    dn_m = np.where(good, dn, np.inf)
    j = np.argmin(dn_m, axis=-1)
    l = np.take_along_axis(dn_m, j[..., None], axis=-1)[..., 0]
    dmin = np.take_along_axis(d, j[..., None, None], axis=-2)[..., 0, :]
    dmin = np.where(np.isfinite(l)[..., None], dmin, np.nan)
    q = (_f(lam) * _f(K))[..., None] + _f(nu)[..., None] * Igv - (_f(lam) ** 2)[..., None] * I
    q = np.broadcast_to(q, bshape + (3,))
    lev = 0.5 * np.sum(q[..., None, :] * d**2, axis=-1)
    cs = np.where(good, lev, np.inf).min(axis=-1)
    return l, dmin, cs


def l_spurious(I, H, lam, K, nu=0.0, Ig=None, **kw):
    """Smallest |delta| over off-target steady spins (l of (1.18)) and that spin's delta."""
    l, dmin, _ = spurious_summary(I, H, lam, K, nu, Ig, **kw)
    return l, dmin


def spin_level(I, lam, K, nu, Ig, delta):
    """V at a steady spin: 1/2 sum (lam K + nu Ig_i - lam^2 I_i) delta_i^2 (the (w1, delta) part of V)."""
    q = (_f(lam) * _f(K))[..., None] + _f(nu)[..., None] * _f(Ig) - (_f(lam) ** 2)[..., None] * _f(I)
    return 0.5 * np.sum(q * delta**2, axis=-1)


def c_star(I, H, lam, K, nu=0.0, Ig=None, **kw):
    """Rigorous sublevel bound: min V over off-target steady spins."""
    return spurious_summary(I, H, lam, K, nu, Ig, **kw)[2]


def f116(d3, I, H, lam, K):
    """The paper's (1.16) f(delta_3) (elementwise; d3 broadcast against the batch)."""
    I, b = _f(I), _unit(H)
    A, B, C = I[..., 0], I[..., 1], I[..., 2]
    b1, b2, b3 = b[..., 0], b[..., 1], b[..., 2]
    lam, K = _f(lam), _f(K)
    kc = K - lam * C
    with np.errstate(divide="ignore", invalid="ignore"):
        D1 = 1.0 / ((K - lam * A) * b3 - lam * (A - C) * d3)
        D2 = 1.0 / ((K - lam * B) * b3 - lam * (B - C) * d3)
        return (kc**2 * b1**2 * d3 * D1**2 + kc**2 * b2**2 * d3 * D2**2 + 2 * kc * b1**2 * D1 + 2 * kc * b2**2 * D2
                + d3 + 2 * b3)


def delta_from_116(d3, I, H, lam, K):
    """delta_1, delta_2 from delta_3 (formulas below (1.14))."""
    I, b = _f(I), _unit(H)
    A, B, C = I[..., 0], I[..., 1], I[..., 2]
    lam, K = _f(lam), _f(K)
    kc = K - lam * C
    with np.errstate(divide="ignore", invalid="ignore"):
        D1 = 1.0 / ((K - lam * A) * b[..., 2] - lam * (A - C) * d3)
        D2 = 1.0 / ((K - lam * B) * b[..., 2] - lam * (B - C) * d3)
        return np.stack([kc * b[..., 0] * d3 * D1, kc * b[..., 1] * d3 * D2, d3], -1)


def l_116(I, H, lam, K, n_grid: int = 4001, tol: float = 1e-7):
    """l of (1.18) from the paper's route: roots of (1.16) on [-1 - b3, 1 - b3].

    Sign changes of f on a grid are bisected; a root counts only if the delta it gives
    solves (1.14) and lies on the sphere (poles of f also change sign). Returns the
    smallest |delta| over accepted roots, NaN where none (e.g. b3 = 0, principal axes:
    (1.16) is degenerate there, docs/models/saakyan.md, misprint 6).
    """
    I, H = _f(I), _unit(H)
    lam, K = _f(lam), _f(K)
    bshape = np.broadcast_shapes(I.shape[:-1], H.shape[:-1], lam.shape, K.shape)
    I, H = (np.broadcast_to(a, bshape + (3,)).reshape(-1, 3) for a in (I, H))
    lam, K = (np.broadcast_to(a, bshape).reshape(-1) for a in (lam, K))
    if lam.size > 1:  # l depends on the model's parameters alone: once per distinct row, not per start (issue 32)
        from ..model.theory_eval import distinct_rows

        first, inv = distinct_rows(I, H, lam, K)
        if len(first) < lam.size:
            return _l_116_rows(I[first], H[first], lam[first], K[first], n_grid, tol)[inv].reshape(bshape)
    return _l_116_rows(I, H, lam, K, n_grid, tol).reshape(bshape)


def _l_116_rows(I, H, lam, K, n_grid: int, tol: float):
    """:func:`l_116` on rows: I, H (M, 3) (H a unit vector), lam, K (M,)."""
    b3 = H[:, 2]
    s = np.linspace(0.0, 1.0, n_grid)
    lo_, hi_ = -1 - b3, 1 - b3
    x = lo_[:, None] + (hi_ - lo_)[:, None] * s[None, :]
    ex = lambda a: a[:, None]  # noqa: E731
    fx = f116(x, I[:, None, :], H[:, None, :], ex(lam), ex(K))
    sc = np.isfinite(fx[:, :-1]) & np.isfinite(fx[:, 1:]) & (np.sign(fx[:, :-1]) * np.sign(fx[:, 1:]) < 0)
    a, b = x[:, :-1].copy(), x[:, 1:].copy()
    fa = fx[:, :-1].copy()
    for _ in range(60):
        m = 0.5 * (a + b)
        fm = f116(m, I[:, None, :], H[:, None, :], ex(lam), ex(K))
        left = np.sign(fm) == np.sign(fa)
        a = np.where(left, m, a)
        fa = np.where(left, fm, fa)
        b = np.where(left, b, m)
    r = 0.5 * (a + b)
    d = delta_from_116(r, I[:, None, :], H[:, None, :], ex(lam), ex(K))
    S = H[:, None, :] + d
    F = tangent_field(S, I[:, None, :], I[:, None, :], H[:, None, :], ex(lam), ex(K), np.zeros_like(r))
    scale = (lam * K + lam**2 * I.max(-1))[:, None]
    with np.errstate(invalid="ignore"):
        good = sc & (np.abs(np.linalg.norm(S, axis=-1) - 1) < tol) & (np.linalg.norm(F, axis=-1) / scale < tol) & (
            np.linalg.norm(d, axis=-1) > 1e-6)
    dn = np.where(good, np.linalg.norm(d, axis=-1), np.inf)
    out = dn.min(axis=-1)
    return np.where(np.isfinite(out), out, np.nan)


# ---------------------------------------------------------------------------------------------
# B-2..B-4 conditions


def lam2_nu(lam, nu, tol: float = LAM2NU_TOL) -> Predicate:
    """Theorem 2's lam^2 = nu (a knife edge): ok where |lam^2/nu - 1| < tol; margin tol - |lam^2/nu - 1|."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dev = np.abs(_f(lam) ** 2 / _f(nu) - 1.0)
    dev = np.where(np.isfinite(dev), dev, np.inf)
    return Predicate(dev < tol, tol - dev, f"Theorem 2: lam^2 = nu (|lam^2/nu - 1| < {tol:g})")


def c27(I, lam, nu, K) -> Predicate:
    """(2.7) generalised [docs/models/saakyan.md, misprint 9]: alpha > max_i (lam^2 - nu) I_i and alpha > 0 (V of (2.6) positive definite)."""
    lam, nu, K = _f(lam), _f(nu), _f(K)
    alpha = lam * K
    bound = np.maximum(np.max((lam**2 - nu)[..., None] * _f(I), axis=-1), 0.0)
    margin = np.minimum(alpha - bound, alpha) / np.maximum(lam**2 * axis_roles(I)[0], 1e-300)
    return Predicate(margin > 0, margin, "(2.7) alpha > max_i (lam^2 - nu) I_i, alpha > 0: V of (2.6) positive definite")


def c_h(I, lam, h) -> Predicate:
    """Theorem 3: h > lam m1 (alpha = lam h > lam^2 m1). Margin h/(lam m1) - 1."""
    margin = _f(h) / (_f(lam) * axis_roles(I)[0]) - 1.0
    return Predicate(margin > 0, margin, "Theorem 3: h > lam max(A,B,C)")


def bound_44(I, Jw, lam, nu, exact: bool):
    """(4.4) bound on h: max_i ((lam^2 - nu) I_i +- nu J_i)/lam (printed: +, exact [D]: -)."""
    lam, nu = _f(lam)[..., None], _f(nu)[..., None]
    sgn = -1.0 if exact else 1.0
    return np.max(((lam**2 - nu) * _f(I) + sgn * nu * _f(Jw)) / lam, axis=-1)


def c44(I, Jw, lam, nu, h, exact: bool) -> Predicate:
    """(4.4) printed (+nu J_i, conservative) or exact (-nu J_i) [D]; both also need h > 0."""
    b = bound_44(I, Jw, lam, nu, exact)
    h = _f(h)
    margin = np.minimum(h - b, h) / (_f(lam) * axis_roles(I)[0])
    doc = ("(4.4) exact [D]: h > max_i ((lam^2 - nu) I_i - nu J_i)/lam and h > 0" if exact else
           "(4.4) as printed: h > max_i ((lam^2 - nu) I_i + nu J_i)/lam and h > 0")
    return Predicate(margin > 0, margin, doc)


# ---------------------------------------------------------------------------------------------
# initial perturbation (host side; mirrors SaakyanBase.initial_state)


def initial_deviation(p: Mapping[str, np.ndarray]):
    """(w1(0), delta(0)) from the initial-condition parameters (see saakyan.py, ``init``)."""
    H = _unit(p["H"])
    lam = _f(p["lam"])
    init = _f(p.get("init", 0.0))
    S0 = _unit(p["S0"])
    dw0 = _f(p["dw0"])
    rho = _f(p.get("rho", 0.0))
    w_ratio = _f(p.get("w_ratio", 1.0))
    # shell mode: |delta0| = rho along the great circle from H towards S0; |w1| = w_ratio lam rho
    u = S0 - np.sum(S0 * H, -1, keepdims=True) * H
    un = np.linalg.norm(u, axis=-1, keepdims=True)
    fallback = _unit(np.cross(H, np.eye(3)[np.argmin(np.abs(H), axis=-1)]))
    u = np.where(un > 1e-12, u / np.maximum(un, 1e-300), fallback)
    th = 2 * np.arcsin(np.clip(rho / 2, 0, 1))
    S_shell = np.cos(th)[..., None] * H + np.sin(th)[..., None] * u
    dn = np.linalg.norm(dw0, axis=-1, keepdims=True)
    w_shell = (w_ratio * lam * rho)[..., None] * dw0 / np.maximum(dn, 1e-300)
    shell = (init == 1)[..., None]
    S = np.where(shell, S_shell, S0)
    w1 = np.where(shell, w_shell, dw0)
    return w1, S - H


def region(w1, d, lam, l) -> Predicate:
    """(1.18)/(1.22): |w1(0)| < lam l and |delta(0)| < l. Margin: min of the relative slacks."""
    wn = np.linalg.norm(w1, axis=-1)
    dn = np.linalg.norm(d, axis=-1)
    l, lam = _f(l), _f(lam)
    with np.errstate(invalid="ignore", divide="ignore"):
        margin = np.minimum(1 - wn / (lam * l), 1 - dn / l)
    margin = np.where(np.isfinite(margin), margin, np.where(np.isinf(l), 1.0, -1.0))
    return Predicate(margin > 0, margin, "initial perturbation in |w1| < lam l, |delta| < l")


def _lyap_wd(w1, d, I, lam, K, nu, Ig):
    """(w1, delta) part of V: 1/2 [sum I (w1 - lam d)^2 + sum (lam K + nu Ig - lam^2 I) d^2]."""
    lam_ = _f(lam)[..., None]
    return 0.5 * np.sum(_f(I) * (w1 - lam_ * d) ** 2, -1) + spin_level(I, lam, K, nu, Ig, d)


def _q_positive(I, lam, K, nu, Ig):
    q = (_f(lam) * _f(K))[..., None] + _f(nu)[..., None] * _f(Ig) - (_f(lam) ** 2)[..., None] * _f(I)
    return q.min(-1) > 0


# ---------------------------------------------------------------------------------------------
# per-system evaluation


def _b(p, name, default=None):
    return _f(p[name]) if name in p else _f(default)


def _batch(p, names_vec, names_scalar):
    shapes = [np.shape(p[n])[:-1] for n in names_vec if n in p] + [np.shape(p[n]) for n in names_scalar if n in p]
    return np.broadcast_shapes(*shapes) if shapes else ()


def _common(p, K, nu, Ig, gain_name):
    """Predicates shared by all five loops, for gain K (= h in B-3/B-4)."""
    bs = _batch(p, ["I", "H", "S0", "dw0", "Jw"], ["lam", gain_name, "nu", "init", "rho", "w_ratio", "use_mu"])
    I = np.broadcast_to(_f(p["I"]), bs + (3,))
    H = np.broadcast_to(_unit(p["H"]), bs + (3,))
    lam = np.broadcast_to(_f(p["lam"]), bs)
    K = np.broadcast_to(_f(K), bs)
    nu = np.broadcast_to(_f(nu), bs)
    Ig = np.broadcast_to(_f(Ig), bs + (3,))
    use_mu = np.broadcast_to(_b(p, "use_mu", 1.0), bs) > 0
    w1, d = initial_deviation({k: v for k, v in p.items()})
    w1, d = np.broadcast_to(w1, bs + (3,)), np.broadcast_to(d, bs + (3,))
    l, dl, cs = spurious_summary(I, H, lam, K, nu, Ig)
    V0 = _lyap_wd(w1, d, I, lam, K, nu, Ig)
    qpos = _q_positive(I, lam, K, nu, Ig)
    with np.errstate(invalid="ignore", divide="ignore"):
        sub_margin = np.where(np.isfinite(cs), 1 - V0 / cs, 1.0)
    sublevel = Predicate(use_mu & qpos & (sub_margin > 0), sub_margin,
                         "[D] V(0) < c* = min V over off-target steady spins (rigorous basin, V positive definite)")
    derived = {
        "l_spurious": l,
        "c_star": cs,
        "V0": V0,
        "w1_0": np.linalg.norm(w1, axis=-1),
        "delta_0": np.linalg.norm(d, axis=-1),
        "r_w": lam * l,
        "r_delta": l,
    }
    doc = {
        "l_spurious": "smallest |delta| over off-target steady spins (l of (1.18), robust algorithm)",
        "c_star": "min of V over off-target steady spins (sublevel-set basin)",
        "V0": "(w1, delta) part of V at t = 0",
        "w1_0": "|w1(0)| = |omega(0) - omega0(0) - lam H0|",
        "delta_0": "|delta(0)| = |S0(0) - H0|",
        "r_w": "guaranteed radius of (1.18) in w1: lam l",
        "r_delta": "guaranteed radius of (1.18) in delta: l",
    }
    return dict(I=I, H=H, lam=lam, K=K, nu=nu, Ig=Ig, use_mu=use_mu, w1=w1, d=d, l=l, dl=dl,
                sublevel=sublevel, derived=derived, doc=doc)


def _b1_predicates(c, p):
    I, H, lam, K = c["I"], c["H"], c["lam"], c["K"]
    p110 = c110(I, lam, K)
    p121 = c121(I, H, lam, K)
    reg118 = region(c["w1"], c["d"], lam, c["l"])
    reg122 = region(c["w1"], c["d"], lam, np.full_like(lam, 2.0))
    th1 = Predicate(p110.ok & c["use_mu"] & reg118.ok, np.minimum(p110.margin, reg118.margin),
                    "Theorem 1: (1.10), mu from (1.11), initial perturbation in (1.18)")
    cor1 = Predicate(p121.ok & c["use_mu"] & reg122.ok, np.minimum(p121.margin, reg122.margin),
                     "Corollary 1: H0 principal, (1.21), mu from (1.11), initial perturbation in (1.22)")
    guaranteed = Predicate(th1.ok | cor1.ok, np.maximum(th1.margin, cor1.margin),
                           "Theorem 1 or Corollary 1 guarantees convergence")
    mid = middle_axis(I, H, lam, K)
    exact = no_spurious_exact(I, H, lam, K)
    br = bracket_phi0(I, H)
    unstable = Predicate(~c["use_mu"] & (br > 1e-14) & (c["nu"] == 0), br,
                         "instability without mu: mu = 0 and the bracket of phi(0) > 0 (H0 not principal)")
    preds = {"c110": p110, "c121": p121, "middle_axis": mid, "no_spurious_exact": exact, "region118": reg118,
             "region122": reg122, "theorem1": th1, "corollary1": cor1, "sublevel": c["sublevel"],
             "unstable_no_mu": unstable, "guaranteed": guaranteed}
    derived = dict(c["derived"])
    doc = dict(c["doc"])
    derived["l_116"] = l_116(I, H, lam, K)
    doc["l_116"] = "l from the roots of the paper's (1.16) (NaN where (1.16) is degenerate)"
    derived["K_121"] = lam * (3 * axis_roles(I)[0] - 2 * axis_roles(I)[2])
    doc["K_121"] = "gain bound of (1.21): lam (3 m1 - 2 m2)"
    derived["K_110"] = lam * axis_roles(I)[0]
    doc["K_110"] = "gain bound of (1.10): lam m1"
    derived["bracket_phi0"] = br
    doc["bracket_phi0"] = "bracket of phi(0) = -lam^4 K [..]: > 0 means instability without mu"
    _radius(derived, doc, "theorem1", p110.ok & c["use_mu"], c["l"],
            "region (1.18) of Theorem 1 (Cor. 2 for omega0 = 0): l where (1.10) holds and mu is on")
    _radius(derived, doc, "corollary1", p121.ok & c["use_mu"], 2.0,
            "region (1.22) of Corollary 1: 2 where H0 is principal, (1.21) holds and mu is on")
    return preds, derived, doc


def _radius(derived, doc, name, holds, radius, what):
    """The region of initial conditions a theorem guarantees, as a radius in the norm max(|w1(0)|/lam, |delta(0)|)
    (the two balls |w1(0)| < lam r, |delta(0)| < r of (1.18)/(1.22) are the one ball of radius r in it): ``radius``
    where the theorem's other hypotheses ``holds``, else 0 (nothing guaranteed). Read by ``[shock] theory``
    (:mod:`stabjax.explore.shock_result`), which holds the minimal fatal shock in that norm against it."""
    derived[f"radius_{name}"] = np.where(holds, radius, 0.0) * np.ones(np.shape(holds))
    doc[f"radius_{name}"] = f"guaranteed radius in max(|w1(0)|/lam, |delta(0)|): {what}; else 0"


def evaluate_moving(p: Mapping[str, np.ndarray]) -> Theory:
    """B-1, Theorem 1 / Corollary 1 (the middle-axis and exact conditions are reported too)."""
    c = _common(p, p["K"], 0.0, p["I"], "K")
    preds, derived, doc = _b1_predicates(c, p)
    return Theory(preds, derived, doc, main="guaranteed")


evaluate_fixed = evaluate_moving  # Corollary 2 is Theorem 1 with omega0 = 0


def evaluate_gravity(p: Mapping[str, np.ndarray]) -> Theory:
    """B-2, Theorem 2: lam^2 = nu, region (1.22), mu from (1.11), (2.8)."""
    c = _common(p, p["K"], p["nu"], p["I"], "K")
    I, lam, K, nu = c["I"], c["lam"], c["K"], c["nu"]
    ln = lam2_nu(lam, nu)
    p27 = c27(I, lam, nu, K)
    reg122 = region(c["w1"], c["d"], lam, np.full_like(lam, 2.0))
    reg_l = region(c["w1"], c["d"], lam, c["l"])
    th2 = Predicate(ln.ok & (K > 0) & c["use_mu"] & reg122.ok, np.minimum(ln.margin, reg122.margin),
                    "Theorem 2: lam^2 = nu, alpha > 0, mu from (1.11),(2.8), initial perturbation in (1.22)")
    local = Predicate(p27.ok & c["use_mu"] & reg_l.ok, np.minimum(p27.margin, reg_l.margin),
                      "[D] off the knife edge: (2.7) and initial perturbation closer than the nearest steady spin")
    preds = {"lam2_nu": ln, "c27": p27, "region122": reg122, "region_l": reg_l, "theorem2": th2,
             "local_l": local, "sublevel": c["sublevel"]}
    derived = dict(c["derived"])
    doc = dict(c["doc"])
    derived["lam2_over_nu"] = lam**2 / nu
    doc["lam2_over_nu"] = "lam^2 / nu (Theorem 2 needs 1)"
    _radius(derived, doc, "theorem2", ln.ok & (K > 0) & c["use_mu"], 2.0,
            "region (1.22) of Theorem 2: 2 where lam^2 = nu, alpha > 0 and mu is on")
    return Theory(preds, derived, doc, main="theorem2")


def evaluate_gyrostat(p: Mapping[str, np.ndarray]) -> Theory:
    """B-3, Theorem 3 (as claimed: global), and its valid local version [D]."""
    c = _common(p, p["h"], 0.0, p["I"], "h")
    I, lam, h = c["I"], c["lam"], c["K"]
    ph = c_h(I, lam, h)
    torque_ok = np.broadcast_to(_b(p, "torque", 0.0), h.shape) != 1
    th3 = Predicate(ph.ok & c["use_mu"] & torque_ok, ph.margin,
                    "Theorem 3 as claimed (global): h > lam m1, M = mu + grad U/2 with mu of (3.21)")
    reg = region(c["w1"], c["d"], lam, c["l"])
    local = Predicate(th3.ok & reg.ok, np.minimum(ph.margin, reg.margin),
                      "[D] Theorem 3, valid local form: also initial perturbation in (1.18) with K = h")
    preds = {"c_h": ph, "theorem3": th3, "region118": reg, "theorem3_local": local, "sublevel": c["sublevel"]}
    derived = dict(c["derived"])
    doc = dict(c["doc"])
    derived["h_over_lam_m1"] = h / (lam * axis_roles(I)[0])
    doc["h_over_lam_m1"] = "h / (lam m1) (Theorem 3 needs > 1)"
    _radius(derived, doc, "theorem3", th3.ok, np.inf, "Theorem 3 as claimed: every start (inf) where h > lam m1")
    _radius(derived, doc, "theorem3_local", th3.ok, c["l"], "its valid local form [D]: l of (1.18) with K = h")
    return Theory(preds, derived, doc, main="theorem3")


def evaluate_gyrostat_gravity(p: Mapping[str, np.ndarray]) -> Theory:
    """B-4, Theorem 4 with (4.4) as printed (main) and exact [D]."""
    Ig = _f(p["I"]) + _f(p["Jw"])
    c = _common(p, p["h"], p["nu"], Ig, "h")
    I, lam, h, nu = c["I"], c["lam"], c["K"], c["nu"]
    Jw = np.broadcast_to(_f(p["Jw"]), I.shape)
    pp = c44(I, Jw, lam, nu, h, exact=False)
    pe = c44(I, Jw, lam, nu, h, exact=True)
    torque_ok = np.broadcast_to(_b(p, "torque", 0.0), h.shape) != 1
    th4 = Predicate(pp.ok & c["use_mu"] & torque_ok, pp.margin,
                    "Theorem 4 as claimed (global): (4.4) as printed, torque (4.1) with (3.21),(4.5)")
    reg = region(c["w1"], c["d"], lam, c["l"])
    local = Predicate(pe.ok & c["use_mu"] & torque_ok & reg.ok, np.minimum(pe.margin, reg.margin),
                      "[D] valid local form: exact (4.4) and initial perturbation closer than the nearest steady spin")
    preds = {"c44_printed": pp, "c44_exact": pe, "theorem4": th4, "region_l": reg, "theorem4_local": local,
             "sublevel": c["sublevel"]}
    derived = dict(c["derived"])
    doc = dict(c["doc"])
    derived["h44_printed"] = bound_44(I, Jw, lam, nu, exact=False)
    derived["h44_exact"] = bound_44(I, Jw, lam, nu, exact=True)
    doc["h44_printed"] = "bound of (4.4) as printed (+nu J_i)"
    doc["h44_exact"] = "exact bound of (4.4) (-nu J_i) [D]"
    _radius(derived, doc, "theorem4", th4.ok, np.inf, "Theorem 4 as claimed: every start (inf) where (4.4) holds")
    _radius(derived, doc, "theorem4_local", pe.ok & c["use_mu"] & torque_ok, c["l"],
            "its valid local form [D]: exact (4.4), closer than the nearest steady spin")
    return Theory(preds, derived, doc, main="theorem4")
