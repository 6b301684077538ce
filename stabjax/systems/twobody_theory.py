"""Theorem predicates of Bezglasnyi & Mysina (2011), vectorised over parameter grids (docs/models/twobody.md, "Theorems as implemented").

Every theorem (1-4) rests on one hypothesis, (10) / (15) and their rotating-frame analogues:
the symmetric matrix

    P(t) = B + C(t) + 1/2 (delta^' I2 delta^-1 + delta^ I2 (delta^-1)')   ( = B + C + 1/2 J' )

is uniformly positive definite, P(t) >= b0 I with b0 > 0 for all t >= 0. Then V' <= -b0 |w|^2
(or |x|^2) and the motions tend to the equilibria; the aligned one is asymptotically stable,
the others unstable. The *margin* returned is ``min_t lambda_min(P(t))`` over the window:

* one period of delta when the rotor rate is constant (``delta_prog = 0, dA = 0``) in a König
  frame: P then depends on t only through delta (``N_PERIOD`` points over one period);
* otherwise the grid ``t in [0, T_theory]`` (at least ``N_WINDOW`` points and ``PER_TURN`` per
  turn of delta and of each omega0 component, at most ``N_WINDOW_MAX``), also always in the
  rotating frame, where omega0(t) enters.

Each grid minimum is then refined by two zooms around its minimiser, so the margin is the
window minimum to ~1e-7, independent of the grid (a plain grid would miss it by O(spacing^2)
and scatter b* along a sweep). The window is finite: a condition that fails only after
``T_theory`` is not seen.

Three versions of C are evaluated, because the paper's printed C differs from the exact one
(docs/models/twobody.md, misprints 1, 2, 5):

``physical``  C = sym([w02]x I2~) (+ sym([w0]x J) in the rotating frame); then P = B + J' (+ sym([w0]x J)).
              This is the exact V' of the physically correct closed loop (variant 0). [D]
``paper``     C = sym([w0 + w02]x I2 delta^T) + sym([w0]x I1): the exact V' of the *printed*
              equations of motion (variant 1, gyroscopic matrix G = I2 delta^T). [D]
``printed``   formula (9) / (21) literally: the c11 misprint in the w02^3 term, and in (21) the
              missing sym([w0]x I1) and the lone w02^3 in the last terms of 2 c13, 2 c23
              (the OCR slip "(w02 + w02^2)" in c11 is read as w0^2 + w02^2). Informational only.

With B = b I, lambda_min(b I + Q) = b + lambda_min(Q), so the smallest admissible b is
``b_star = -min_t lambda_min(P(t) - B)`` (strict: b > b_star). For the physical König case with a
constant rate, J' = delta' delta^ M0 delta^T with the constant M0 = [e_z]x I2 - I2 [e_z]x, whence
the explicit ``b_star = -delta' lambda_min(M0)`` (delta' > 0) or ``-delta' lambda_max(M0)`` (delta' < 0).

Equilibria and the theorems' claims (docs/models/twobody.md, "Equilibria"): uniaxial ``s0 = r0`` asymptotically stable,
``s0 = -r0`` unstable; triaxial ``s~0i = r0i`` asymptotically stable, the three rotations by pi
about r01, r02, r03 unstable (isolated only when the alpha_i are distinct; equal gains give a
continuum of pi rotations). See :func:`equilibria_uniaxial`, :func:`equilibria_triaxial`.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..model.system import Predicate, Theory
from .twobody_programs import delta_is_periodic, delta_program, omega0_program

N_PERIOD = 240  # delta samples over one period (constant rate, König frame)
N_WINDOW = 2001  # least number of time samples on [0, T_theory] otherwise ...
PER_TURN = 32  # ... raised so that delta and every omega0 component get >= PER_TURN samples per turn
N_WINDOW_MAX = 40001
_CHUNK = 256  # time samples per vectorised block (bounds memory: batch x chunk x 9 doubles)

KINDS = ("physical", "paper", "printed")


# ---- small batched linear algebra ------------------------------------------------------------

def hat(v):
    """[v]x for v of shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, float)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
         np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def sym(x):
    return 0.5 * (x + np.swapaxes(x, -1, -2))


def rotz(d):
    """delta^: rotor axes -> carrier axes, shape (..., 3, 3)."""
    d = np.asarray(d, float)
    c, s, z, o = np.cos(d), np.sin(d), np.zeros_like(d), np.ones_like(d)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def m0_matrix(I2):
    """M0 = [e_z]x I2 - I2 [e_z]x (docs/models/twobody.md, "Theorems as implemented"): J' = delta' delta^ M0 delta^T."""
    ez = hat(np.array([0.0, 0.0, 1.0]))
    I2 = np.asarray(I2, float)
    return ez @ I2 - I2 @ ez


def c_printed(w, w3_last, delta, I2):
    """Formula (9) (König, ``w = w02``) or (21) (``w = w0 + w02``) exactly as printed.

    ``w3_last`` is the third component used in the last terms of 2 c13 and 2 c23 (the paper keeps
    w02^3 there in (21)). The c11 w^3 term is the printed one, w^3 (I2yx sin d + I2zy cos d).
    """
    I2 = np.asarray(I2, float)
    Ixx, Iyy, Izz = I2[..., 0, 0], I2[..., 1, 1], I2[..., 2, 2]
    Ixy, Ixz, Iyz = I2[..., 0, 1], I2[..., 0, 2], I2[..., 1, 2]
    c, s = np.cos(delta), np.sin(delta)
    w1, w2, w3 = w[..., 0], w[..., 1], w[..., 2]
    c11 = w2 * (Ixz * c - Iyz * s) + w3 * (Ixy * s + Iyz * c)
    c22 = w3 * (Ixx * s + Ixy * c) - w1 * (Ixz * s + Iyz * c)
    c33 = w1 * Iyz - w2 * Ixz
    c12 = 0.5 * (-w1 * (Ixz * c - Iyz * s) + w2 * (Ixz * s + Iyz * c) + w3 * ((Ixx - Iyy) * c - 2 * Ixy * s))
    c13 = 0.5 * (w1 * (Ixy * c - Iyy * s) + w2 * (Izz - Ixx * c + Ixy * s) - w3_last * Iyz)
    c23 = 0.5 * (w1 * (Ixy * s + Iyy * c - Izz) - w2 * (Ixx * s + Ixy * c) + w3_last * Ixz)
    return np.stack([np.stack([c11, c12, c13], -1), np.stack([c12, c22, c23], -1),
                     np.stack([c13, c23, c33], -1)], -2)


def c_matrices(I1, I2, delta, ddelta, om0=None):
    """The three C + 1/2 J' matrices (B excluded) at the given rotor states; shapes (..., 3, 3).

    ``om0`` (..., 3) is the reference frame's rate in carrier components (None: König frame).
    """
    I1, I2 = np.asarray(I1, float), np.asarray(I2, float)
    D = rotz(delta)
    Dt = np.swapaxes(D, -1, -2)
    It = D @ I2[..., None, :, :] @ Dt if D.ndim > I2.ndim else D @ I2 @ Dt
    I2b = I2[..., None, :, :] if D.ndim > I2.ndim else I2
    I1b = np.asarray(I1)[..., None, :, :] if D.ndim > I1.ndim else I1
    Jdot = ddelta[..., None, None] * (D @ m0_matrix(I2b) @ Dt)
    w02 = np.zeros(np.shape(delta) + (3,))
    w02[..., 2] = ddelta
    if om0 is None:
        om0 = np.zeros_like(w02)
    u = om0 + w02
    phys = Jdot + sym(hat(om0) @ (I1b + It))
    paper = 0.5 * Jdot + sym(hat(om0) @ I1b) + sym(hat(u) @ (I2b @ Dt))
    printed = 0.5 * Jdot + c_printed(u, w02[..., 2], delta, I2b)
    return {"physical": phys, "paper": paper, "printed": printed}


def _batch_shape(p, rotating):
    shapes = [np.shape(p["I1"])[:-2], np.shape(p["I2"])[:-2], np.shape(p["B"])[:-2]]
    for k in ("b", "delta_prog", "delta0", "Omega_r", "dA", "dnu", "tau", "T_theory", "variant"):
        shapes.append(np.shape(p[k]))
    if rotating:
        for k in ("om0_c", "om0_a", "om0_f", "om0_p"):
            shapes.append(np.shape(p[k])[:-1])
    return np.broadcast_shapes(*shapes)


def window_margins(p: Mapping[str, np.ndarray], rotating: bool):
    """min over the window of lambda_min(P) for each kind, with and without B.

    Returns ``{kind: (margin, b_star)}`` with arrays of the batch shape.
    """
    shape = _batch_shape(p, rotating)
    bc = lambda k, tail=0: np.broadcast_to(np.asarray(p[k], float), shape + np.shape(p[k])[len(np.shape(p[k])) - tail:])  # noqa: E731
    I1, I2, Bm = bc("I1", 2), bc("I2", 2), bc("B", 2)
    Btot = Bm + np.asarray(bc("b"))[..., None, None] * np.eye(3)
    prog, d0, Om, dA, dnu, tau, T = (bc(k) for k in ("delta_prog", "delta0", "Omega_r", "dA", "dnu", "tau", "T_theory"))
    periodic = delta_is_periodic(prog, dA) & (not rotating)
    with np.errstate(divide="ignore"):
        period = np.where(Om != 0, 2 * np.pi / np.abs(np.where(Om != 0, Om, 1.0)), 0.0)
    fastest = np.abs(Om) + np.abs(dA)
    if rotating:
        fastest = np.maximum(fastest, np.abs(bc("om0_f", 1)).max(-1))
    turns = T * fastest / (2 * np.pi)
    n_win = np.clip(np.ceil(PER_TURN * turns) + 1, N_WINDOW, N_WINDOW_MAX).astype(int)
    n = np.where(periodic, N_PERIOD, n_win)
    nmax = int(n.max()) if n.size else N_PERIOD
    span = np.where(periodic, period, T)
    if rotating:
        oc, oa, of, oph = (bc(k, 1) for k in ("om0_c", "om0_a", "om0_f", "om0_p"))
    e = lambda a: a[..., None]  # noqa: E731

    def lam_at(t):
        """{(kind, with_B): lambda_min(P(t))} for times t of shape batch + (m,)."""
        delta, ddelta, _ = delta_program(np, t, e(prog), e(d0), e(Om), e(dA), e(dnu), e(tau))
        om0 = omega0_program(np, t, oc[..., None, :], oa[..., None, :], of[..., None, :], oph[..., None, :])[0] \
            if rotating else None
        mats = c_matrices(I1, I2, delta, ddelta, om0)
        out = {}
        for kind in KINDS:
            out[kind, False] = np.linalg.eigvalsh(mats[kind])[..., 0]
            out[kind, True] = np.linalg.eigvalsh(mats[kind] + Btot[..., None, :, :])[..., 0]
        return out

    keys = [(kind, wb) for kind in KINDS for wb in (False, True)]
    best = {key: np.full(shape, np.inf) for key in keys}
    t_best = {key: np.zeros(shape) for key in keys}

    def update(t, lam):
        for key in keys:
            i = np.argmin(lam[key], axis=-1)[..., None]
            v = np.take_along_axis(lam[key], i, -1)[..., 0]
            tv = np.take_along_axis(t, i, -1)[..., 0]
            better = v < best[key]
            best[key] = np.where(better, v, best[key])
            t_best[key] = np.where(better, tv, t_best[key])

    for k0 in range(0, nmax, _CHUNK):
        k = np.arange(k0, min(k0 + _CHUNK, nmax), dtype=float)
        # periodic: k/n of a period (endpoint excluded); window: linspace(0, T, n); past n: repeat t = 0
        frac = np.where(periodic[..., None], k / n[..., None], k / np.maximum(n[..., None] - 1, 1))
        t = np.where(k < n[..., None], frac * span[..., None], 0.0)
        update(t, lam_at(t))
    # refine around each grid minimiser (two zooms of 33 points): the grid alone misses the
    # minimum by O(spacing^2) and non-nested grids would give scattered b* along a sweep
    h = np.where(periodic, span / np.maximum(n, 1), span / np.maximum(n - 1, 1))
    for zoom in (1.0, 1.0 / 16):
        for key in keys:
            t = t_best[key][..., None] + (zoom * h)[..., None] * np.linspace(-1.0, 1.0, 33)
            if not np.all(periodic):
                t = np.where(periodic[..., None], t, np.clip(t, 0.0, T[..., None]))
            lam = lam_at(t)
            i = np.argmin(lam[key], axis=-1)[..., None]
            v = np.take_along_axis(lam[key], i, -1)[..., 0]
            better = v < best[key]
            best[key] = np.where(better, v, best[key])
            t_best[key] = np.where(better, np.take_along_axis(t, i, -1)[..., 0], t_best[key])
    return {kind: (best[kind, True], -best[kind, False]) for kind in KINDS}


def b_star_explicit(I2, Omega_r):
    """Physical König, constant rate, B = b I: b* = -delta' lambda_min(M0) (delta' > 0) or -delta' lambda_max(M0)."""
    ev = np.linalg.eigvalsh(m0_matrix(I2))
    Om = np.asarray(Omega_r, float)
    return np.where(Om >= 0, -Om * ev[..., 0], -Om * ev[..., -1])


# ---- equilibria and the theorems' claims -------------------------------------------------------

def equilibria_uniaxial(r0):
    """[(label, s0, claim)] with claim 'asymptotically stable' / 'unstable' (Theorems 1, 3)."""
    r0 = np.asarray(r0, float)
    return [("s0 = r0", r0, "asymptotically stable"), ("s0 = -r0", -r0, "unstable")]


def equilibria_triaxial(R):
    """[(label, S, claim)]: S = matrix of the s~0i (columns) at each equilibrium (Theorems 2, 4).

    ``R`` = [r01 r02 r03] (columns). The sign combinations consistent with s03 = s01 x s02 are
    (+,+,+) and the rotations by pi about r01 (+,-,-), r02 (-,+,-), r03 (-,-,+).
    """
    R = np.asarray(R, float)
    out = [("s0i = r0i (+,+,+)", R, "asymptotically stable")]
    for i, signs in enumerate(((1, -1, -1), (-1, 1, -1), (-1, -1, 1))):
        out.append((f"pi about r0{i + 1} {tuple('+' if x > 0 else '-' for x in signs)}", R * np.array(signs, float),
                    "unstable"))
    return out


def evaluate(p: Mapping[str, np.ndarray], rotating: bool = False, triaxial: bool = False) -> Theory:
    """All predicates for one of the four systems on batched parameters ``p``."""
    res = window_margins(p, rotating)
    th = "Theorem " + ("3" if rotating else "1") if not triaxial else "Theorem " + ("4" if rotating else "2")
    cond = "(10)" if not triaxial else "(15)"
    if rotating:
        cond += " in the rotating frame, C from (21)"
    variant = np.asarray(p["variant"])
    preds = {
        "physical": Predicate(
            ok=res["physical"][0] > 0, margin=res["physical"][0],
            doc=f"{th}, {cond}, exact for the physically correct loop: min_t lambda_min(B + J'"
                + (" + sym([w0]x J)" if rotating else "") + ") > 0"),
        "paper": Predicate(
            ok=res["paper"][0] > 0, margin=res["paper"][0],
            doc=f"{th}, {cond}, exact for the printed equations (G = I2 delta^T): min_t lambda_min(B + 1/2 J' + "
                "sym([w0 + w02]x I2 delta^T) + sym([w0]x I1)) > 0"),
        "printed": Predicate(
            ok=res["printed"][0] > 0, margin=res["printed"][0],
            doc=f"{th}, {cond} with C exactly as printed in " + ("(21)" if rotating else "(9)")
                + " (misprints kept; informational)"),
    }
    main_margin = np.where(variant == 1, res["paper"][0], res["physical"][0])
    preds["guaranteed"] = Predicate(
        ok=main_margin > 0, margin=main_margin,
        doc=f"{th}: the condition for the simulated variant (0 physical, 1 paper) holds on the window, so the "
            "aligned equilibrium is asymptotically stable and (almost) every motion converges to it")
    derived = {f"b_star_{k}": res[k][1] for k in KINDS}
    derived_doc = {f"b_star_{k}": f"smallest b for B = b I (plus the given B) making the {k} condition hold (b > b_star)"
                   for k in KINDS}
    if triaxial:
        a = np.asarray(p["alphas"], float)
        distinct = (a[..., 0] != a[..., 1]) & (a[..., 1] != a[..., 2]) & (a[..., 0] != a[..., 2])
        derived["alphas_distinct"] = distinct
        derived_doc["alphas_distinct"] = ("the alpha_i are distinct: exactly four equilibria (identity stable, three "
                                          "pi rotations unstable); otherwise a continuum of pi rotations")
        derived["n_unstable_equilibria"] = np.where(distinct, 3.0, np.inf)
    else:
        derived["n_unstable_equilibria"] = np.ones(np.shape(main_margin))
    derived_doc["n_unstable_equilibria"] = "number of equilibria the theorem calls unstable (inf: a continuum)"
    return Theory(predicates=preds, derived=derived, derived_doc=derived_doc, main="guaranteed")
