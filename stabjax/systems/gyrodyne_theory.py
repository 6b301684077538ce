"""Khoroshilov's tetrahedral CMG cluster: normal coordinates, forced solution, averaging.

Khoroshilov (1983), documented in ``docs/models/gyrodyne.md``. Everything here is written once for
NumPy (batched theory maps) and JAX (traced, inside :class:`~stabjax.systems.gyrodyne.Gyrodyne`):
functions take the array module ``xp`` and use ``...`` indexing, so the same code serves both.

Chain of quantities (all with mu = 1, physical units, docs/models/gyrodyne.md, misprint 6):

* geometry ("Setup and state" there; misprint 3): gimbal axes g_i = tetrahedron vertex directions; with
  g = (cos l cos d, sin l cos d, -sin d) the mounting angles lambda_i = l, delta_i = d follow;
  rotor direction at nu = 0 is u_i = (-sin l, cos l, 0), output-torque axis w_i = g_i x u_i
  = (cos l sin d, sin l sin d, cos d). Signed H_i orients the spin.
* (1.2) coefficients a', b', a'', b'', d, d', N_0, N^0, N_1, N_2 and forcing a_i', a_i'' ("Equations of motion", model 1).
  Gains are *allocated*: the user gives the desired stiffness/damping matrices Kp, Kd and
  every active set gets per-gyro gains k = W^-1 Kp, K = W^-1 Kd (W = [w_i] of the active
  gyros), so (1.2)'s a..c'' equal Kp's entries for every set; a set change alters d, d'
  (the nominal momentum h = sum H_i u_i = (-d', d, 0)) and the forcing directions.
* generic (1.3) constants ("Equations of motion", model 0): omega_1^2, omega_2^2, xi_1, xi_2, beta_1, beta_2, q21, q22,
  q11, q12, c1, c2 and three harmonics (Omega_j, a_j into the y2 equation, b_j into y1), via
  the *paper* mapping or the *consistent-projection* mapping (misprint 8), or given
  directly ("direct" source, e.g. the "Regression case").
* normal modes, forced solution (2.2) with D_1..D_4, h_1..h_4 -- evaluated at the forcing
  frequencies Omega_2, Omega_3; the paper prints omega_01, omega_02 there, which makes the
  denominators vanish identically (misprint 7).
* averaged coefficients p0..p3, g1, g2 of (3.3). p2, p3 use the corrected chain
  D(Omega_2) -> U, W (the alpha -> beta correction, misprint 13); the printed alpha-version is kept
  as :func:`p23_printed` for comparison only. g1 uses the compact form (the sign printed in
  the paper's explicit g1 is wrong, misprint 15).
* predicates ("Theorems as implemented"): the paper's p1 + p3 < 0 and Delta_1 > 0, the exact Routh-Hurwitz p1 < 0 and
  Delta_1 > 0; mode 2: the paper's g1 < 0 and g1 g2 > 0 (g1 g2 > 0 is probably a misprint of
  g1^2 + g2^2 > 0), exact g1 < 0.
* :func:`numerical_average` averages the right-hand side of the standard form (3.1) over the
  fast phase numerically (variation of constants with a 4x4 solve, *not* the printed
  delta_ij), so the printed/corrected coefficients can be checked independently.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..model.system import Predicate, Theory

# ---- geometry --------------------------------------------------------------------------------

#: vertices of a regular tetrahedron inscribed in the cube (unit vectors); none lies on +-z,
#: so lambda_i is defined for every gyro, and equal momenta give d, d' != 0 for every 3-subset
TET0 = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]) / np.sqrt(3.0)


def geometry(tet_yaw, xp=np):
    """Gimbal axes g, rotor axes u, torque axes w (each (..., 4, 3)) and lambda, delta (..., 4).

    The tetrahedron TET0 is turned by ``tet_yaw`` about body z (a yaw other than a multiple of
    pi/2 makes |d| != |d'| and distinguishes the four active sets).
    """
    c, s = xp.cos(tet_yaw), xp.sin(tet_yaw)
    gx0, gy0, gz0 = TET0[:, 0], TET0[:, 1], TET0[:, 2]
    c, s = xp.asarray(c)[..., None], xp.asarray(s)[..., None]
    gx, gy = c * gx0 - s * gy0, s * gx0 + c * gy0
    gz = gz0 + 0.0 * gx
    lam = xp.arctan2(gy, gx)
    cd = xp.sqrt(gx * gx + gy * gy)
    sd = -gz
    delta = xp.arctan2(sd, cd)
    cl, sl = xp.cos(lam), xp.sin(lam)
    g = xp.stack([gx, gy, gz], axis=-1)
    u = xp.stack([-sl, cl, 0.0 * cl], axis=-1)
    w = xp.stack([cl * sd, sl * sd, cd], axis=-1)
    return dict(g=g, u=u, w=w, lam=lam, delta=delta)


def _slot_tables():
    """SLOT_PRE[spare-1] = active gyros (0-based) in slots 1..3; SLOT_POST[spare-1, fail] after failover.

    Before failure the three non-spare gyros take the slots in increasing index order (paper:
    gyro 4 is the spare). At failover the spare takes the failed gyro's slot (and with it
    that slot's scanning harmonic A_j sin Omega_j t); fail = 0 means no failure.
    """
    pre = np.zeros((4, 3), dtype=np.int64)
    post = np.zeros((4, 5, 3), dtype=np.int64)
    for sp in range(4):
        act = [i for i in range(4) if i != sp]
        pre[sp] = act
        for f in range(5):
            slots = list(act)
            if f >= 1 and (f - 1) in act:
                slots[act.index(f - 1)] = sp
            post[sp, f] = slots
    return pre, post


SLOT_PRE, SLOT_POST = _slot_tables()


def slots(p, stage: str, xp=np):
    """Physical gyro index (0-based) of each slot, (..., 3)."""
    sp = xp.asarray(p["spare"]).astype(np.int64) - 1
    if stage == "pre":
        return xp.asarray(SLOT_PRE)[sp]
    f = xp.asarray(p["fail"]).astype(np.int64)
    return xp.asarray(SLOT_POST)[sp, f]


def _take_rows(a, idx, xp):
    """a (..., 4, k), idx (..., 3) -> (..., 3, k) (batch dims broadcast)."""
    batch = np.broadcast_shapes(a.shape[:-2], idx.shape[:-1])
    a = xp.broadcast_to(a, batch + a.shape[-2:])
    idx = xp.broadcast_to(idx, batch + idx.shape[-1:])
    return xp.take_along_axis(a, idx[..., :, None], axis=-2)


def allocation(p, stage: str, xp=np):
    """Per-slot gyro data and allocated gains for one stage ('pre' or 'post' failover).

    Returns W (..., 3, 3) with columns w_i of the slot gyros, Gk, GK (..., 3, 3): rows = slots,
    columns = angles (psi, theta, phi) [gyro law H_i nu_i' = Gk_i . angles + GK_i . rates + A_i sin],
    H (..., 3), u, w, g (..., 3, 3) rows per slot, and ``idx`` the gyro indices.
    """
    geo = geometry(p["tet_yaw"], xp)
    idx = slots(p, stage, xp)
    w = _take_rows(geo["w"], idx, xp)
    u = _take_rows(geo["u"], idx, xp)
    g = _take_rows(geo["g"], idx, xp)
    H = _take_rows(xp.asarray(p["H"])[..., :, None], idx, xp)[..., 0]
    W = xp.swapaxes(w, -1, -2)
    Kp = xp.asarray(p["Kp"])
    Kd = xp.asarray(p["gain"])[..., None, None] * xp.asarray(p["Kd"])
    Gk = xp.linalg.solve(W, Kp)
    GK = xp.linalg.solve(W, Kd)
    return dict(W=W, Gk=Gk, GK=GK, H=H, u=u, w=w, g=g, idx=idx)


# ---- (1.2)/(1.3) coefficients ---------------------------------------------------------------------


def quasi_linear(p, stage: str, xp=np):
    """Coefficients of the two-channel model (model 1) for one stage; angles ordered (psi, theta, phi).

    a' = Kp[1,2], b' = Kp[1,1] (theta equation), b'' = Kp[2,1], a'' = Kp[2,2] (phi equation);
    N_2 = -Kd[1,1], N_1 = -Kd[1,2], N^0 = -Kd[2,1], N_0 = -Kd[2,2] (Kd scaled by ``gain``);
    d = sum H_i cos lambda_i, d' = sum H_i sin lambda_i over the active gyros;
    forcing of slot j: a_j' = -A_j w_jy, a_j'' = -A_j w_jz.
    """
    al = allocation(p, stage, xp)
    Kp = xp.asarray(p["Kp"])
    Kd = xp.asarray(p["gain"])[..., None, None] * xp.asarray(p["Kd"])
    u, w, H = al["u"], al["w"], al["H"]
    A = xp.asarray(p["A"])
    return dict(
        Iy=xp.asarray(p["I"])[..., 1], Iz=xp.asarray(p["I"])[..., 2],
        ap=Kp[..., 1, 2], bp=Kp[..., 1, 1], bpp=Kp[..., 2, 1], app=Kp[..., 2, 2],
        N2=-Kd[..., 1, 1], N1=-Kd[..., 1, 2], N0u=-Kd[..., 2, 1], N0=-Kd[..., 2, 2],
        d=xp.sum(H * u[..., 1], axis=-1), dp=-xp.sum(H * u[..., 0], axis=-1),
        fy=-A * w[..., 1], fz=-A * w[..., 2],
    )


def betas(Iy, Iz, ap, bp, app, xp=np):
    """Roots beta_1 (+) > beta_2 (-) of beta^2 + (Iz b' - Iy a'')/(Iz a') beta - Iy/Iz = 0 (D.4)."""
    B = (Iy * app - Iz * bp) / (Iz * ap)
    r = xp.sqrt(0.25 * B * B + Iy / Iz)
    return 0.5 * B + r, 0.5 * B - r


def normal_from_physical(p, stage: str, mapping, Omega2, xp=np):
    """Generic (1.3) constants from physical parameters. ``mapping``: 0 paper, 1 consistent [D]."""
    ql = quasi_linear(p, stage, xp)
    Iy, Iz = ql["Iy"], ql["Iz"]
    b1, b2 = betas(Iy, Iz, ql["ap"], ql["bp"], ql["app"], xp)
    e1, e2 = Iy + Iz * b1 * b1, Iy + Iz * b2 * b2
    dk1 = ql["bp"] + ql["app"] * b1 * b1 + 2 * ql["ap"] * b1
    dk2 = ql["bp"] + ql["app"] * b2 * b2 + 2 * ql["ap"] * b2
    f12 = -ql["dp"] * (b2 - b1)
    R = ql["N0u"] + b1 * ql["N0"]
    R1 = ql["N0u"] + b2 * ql["N0"]
    Rp = ql["N2"] + b1 * ql["N1"]
    Rpp = ql["N2"] + b2 * ql["N1"]
    cons = xp.asarray(xp.asarray(mapping) > 0.5)
    def sel(c_, pa):
        c_, pa = xp.asarray(c_), xp.asarray(pa)
        extra = max(c_.ndim, pa.ndim) - cons.ndim
        return xp.where(cons.reshape(cons.shape + (1,) * max(extra, 0)) if extra > 0 else cons, c_, pa)
    fy, fz = ql["fy"], ql["fz"]
    # (1.3) keeps only the Omega_2, Omega_3 harmonics: the paper mapping drops slot 1 (docs/models/gyrodyne.md, misprint 9)
    keep1 = xp.asarray([0.0, 1.0, 1.0])
    fa = sel((fy + b2[..., None] * fz) / e2[..., None], keep1 * fz / e2[..., None])
    fb = sel((fy + b1[..., None] * fz) / e1[..., None], keep1 * fy / e1[..., None])
    Om = xp.asarray(p["Omega"]) + 0.0 * fa
    Om = xp.concatenate([Om[..., :1], xp.asarray(Omega2)[..., None] + 0.0 * Om[..., :1], Om[..., 2:]], axis=-1)
    return dict(
        w1sq=dk2 / e2, w2sq=dk1 / e1, xi1=f12 / e2, xi2=f12 / e1, b1=b1, b2=b2,
        q21=sel((Rp + b2 * R) / e2, R / e2), q22=sel((Rpp + b2 * R1) / e2, R1 / e2),
        q11=sel((Rp + b1 * R) / e1, Rp / e1), q12=sel((Rpp + b1 * R1) / e1, Rpp / e1),
        c1=sel(-b2 * ql["d"] / e2, -ql["d"] / e2), c2=sel(-b1 * ql["d"] / e1, 0.0 * e1),
        Om=Om, fa=fa, fb=fb, e1=e1, e2=e2, d=ql["d"], dp=ql["dp"],
    )


def normal_direct(p, Omega2, xp=np):
    """Generic (1.3) constants given directly (``source = 1``); damping scaled by ``gain``."""
    w = xp.asarray(p["nc_w"])
    q = xp.asarray(p["gain"])[..., None] * xp.asarray(p["nc_q"])
    c = xp.asarray(p["nc_c"])
    f2, f3 = xp.asarray(p["nc_f2"]), xp.asarray(p["nc_f3"])
    z = 0.0 * f2[..., 0]
    Om = xp.asarray(p["Omega"]) + 0.0 * f2[..., :1]
    Om = xp.concatenate([Om[..., :1], xp.asarray(Omega2)[..., None] + 0.0 * Om[..., :1], Om[..., 2:]], axis=-1)
    return dict(
        w1sq=w[..., 0] ** 2, w2sq=w[..., 1] ** 2, xi1=xp.asarray(p["nc_xi"])[..., 0], xi2=xp.asarray(p["nc_xi"])[..., 1],
        b1=xp.asarray(p["nc_beta"])[..., 0], b2=xp.asarray(p["nc_beta"])[..., 1],
        q21=q[..., 0], q22=q[..., 1], q11=q[..., 2], q12=q[..., 3], c1=c[..., 0], c2=c[..., 1],
        Om=Om, fa=xp.stack([z, f2[..., 0], f3[..., 0]], axis=-1), fb=xp.stack([z, f2[..., 1], f3[..., 1]], axis=-1),
    )


def _where_dict(cond, a, b, xp):
    return {k: xp.where(cond[..., None] if xp.ndim(a[k]) > xp.ndim(cond) else cond, a[k], b[k]) for k in a}


def normal_coefficients(p, xp=np):
    """(pre, post) generic constants, the tuned Omega_2 and the detuning eps.

    With ``tune = 1`` the scanning frequency is Omega_2 = 2 (omega_01 - eps) computed for the
    nominal (pre-failure) set -- the scanning program knows nothing of a later failure;
    otherwise Omega_2 = Omega[1] and eps = omega_01 - Omega_2 / 2.
    """
    tune = xp.asarray(p["tune"]) > 0.5
    direct = xp.asarray(p["source"]) > 0.5
    om_given = xp.asarray(p["Omega"])[..., 1]
    # pass 1: frequencies do not depend on Omega_2
    nd = normal_direct(p, om_given, xp)
    keys = ("w1sq", "w2sq", "xi1", "xi2", "b1", "b2", "q21", "q22", "q11", "q12", "c1", "c2", "Om", "fa", "fb")
    out = []
    for stage in ("pre", "post"):
        npre = normal_from_physical(p, stage, p["mapping"], om_given, xp)
        out.append(_where_dict(direct, {k: nd[k] for k in keys}, {k: npre[k] for k in keys}, xp))
    w01 = modes(out[0], xp)["w01"]
    Om2 = xp.where(tune, 2.0 * (w01 - xp.asarray(p["eps"])), om_given)
    res = []
    for nc in out:
        Om = nc["Om"]
        nc = dict(nc)
        nc["Om"] = xp.concatenate([Om[..., :1], Om2[..., None], Om[..., 2:]], axis=-1)
        res.append(nc)
    return res[0], res[1], Om2


# ---- normal modes, forced solution -------------------------------------------------------------------


def modes(nc, xp=np):
    """omega_01 > omega_02, mode shapes alpha_1, alpha_2 and the delta_ij of (3.1)."""
    s = nc["w1sq"] + nc["w2sq"] + nc["xi1"] * nc["xi2"]
    disc = xp.sqrt(xp.maximum(0.25 * s * s - nc["w1sq"] * nc["w2sq"], 0.0))
    w01 = xp.sqrt(0.5 * s + disc)
    w02 = xp.sqrt(xp.maximum(0.5 * s - disc, 0.0))
    a1 = (w01 * w01 - nc["w1sq"]) / (nc["xi1"] * w01)
    a2 = (w02 * w02 - nc["w1sq"]) / (nc["xi1"] * w02)
    return dict(
        w01=w01, w02=w02, a1=a1, a2=a2,
        d11=(a1 * w02 - a2 * w01) / a2, d12=a2 * w02 - a1 * w01,
        d21=a1 * w01 - a2 * w02, d22=(a2 * w01 - a1 * w02) / a1,
    )


def forced_constants(Om, a, b, nc):
    """D_1, D_2, h_1, h_2 at forcing frequency Om with amplitudes (a into y2, b into y1) (docs/models/gyrodyne.md, misprint 7).

    Evaluated at the forcing frequency; the paper's printed omega_01/omega_02 in their place make
    the denominators vanish identically.
    """
    w1, w2, x1, x2 = nc["w1sq"], nc["w2sq"], nc["xi1"], nc["xi2"]
    O2 = Om * Om
    h1 = (w1 - O2) / (x1 * Om)
    h2 = x2 * Om / (O2 - w2)
    D1 = a * (O2 - w2) / (x1 * x2 * O2 - (O2 - w2) * (O2 - w1))
    D2 = b * x1 * Om / ((w1 - O2) * (w2 - O2) - x1 * x2 * O2)
    return D1, D2, h1, h2


def forced_solution(t, nc, xp=np):
    """(2.2), summed over the three harmonics: returns y2, v2, y1, v1 at time t."""
    Om, fa, fb = nc["Om"], nc["fa"], nc["fb"]
    ex = lambda v: xp.asarray(v)[..., None]  # noqa: E731
    D1, D2, h1, h2 = forced_constants(Om, fa, fb, {k: ex(nc[k]) for k in ("w1sq", "w2sq", "xi1", "xi2")})
    t = xp.asarray(t)[..., None]
    s, c = xp.sin(Om * t), xp.cos(Om * t)
    y2 = xp.sum(D1 * s + D2 * c, axis=-1)
    v2 = xp.sum(Om * (D1 * c - D2 * s), axis=-1)
    y1 = xp.sum(D1 * h2 * c + D2 * h1 * s, axis=-1)
    v1 = xp.sum(Om * (-D1 * h2 * s + D2 * h1 * c), axis=-1)
    return y2, v2, y1, v1


def free_solution(E1, th1, E2, th2, md, xp=np):
    """The free part of (2.1): y2, v2, y1, v1 for amplitudes E and phases theta."""
    y2 = E1 * xp.sin(th1) + E2 * xp.sin(th2)
    v2 = E1 * md["w01"] * xp.cos(th1) + E2 * md["w02"] * xp.cos(th2)
    y1 = E1 * md["a1"] * xp.cos(th1) + E2 * md["a2"] * xp.cos(th2)
    v1 = -E1 * md["a1"] * md["w01"] * xp.sin(th1) - E2 * md["a2"] * md["w02"] * xp.sin(th2)
    return y2, v2, y1, v1


def mode_amplitudes(dy2, dv2, dy1, dv1, md, xp=np):
    """Invert :func:`free_solution`: (E1, theta1, E2, theta2) of a deviation from (2.2)."""
    k1, k2 = md["a1"] * md["w01"], md["a2"] * md["w02"]
    # dy2 = S1 + S2, dv1 = -k1 S1 - k2 S2 ; dv2 = w01 C1 + w02 C2, dy1 = a1 C1 + a2 C2
    S1 = (-dv1 - k2 * dy2) / (k1 - k2)
    S2 = dy2 - S1
    det = md["w01"] * md["a2"] - md["w02"] * md["a1"]
    C1 = (md["a2"] * dv2 - md["w02"] * dy1) / det
    C2 = (md["w01"] * dy1 - md["a1"] * dv2) / det
    return xp.sqrt(S1 * S1 + C1 * C1), xp.arctan2(S1, C1), xp.sqrt(S2 * S2 + C2 * C2), xp.arctan2(S2, C2)


def to_normal(th, ph, thd, phd, nc):
    """theta = y1 + y2, phi = beta_1 y1 + beta_2 y2 -> (y2, v2, y1, v1)."""
    b1, b2 = nc["b1"], nc["b2"]
    y1 = (b2 * th - ph) / (b2 - b1)
    y2 = (ph - b1 * th) / (b2 - b1)
    v1 = (b2 * thd - phd) / (b2 - b1)
    v2 = (phd - b1 * thd) / (b2 - b1)
    return y2, v2, y1, v1


def normal_accel(t, y2, v2, y1, v1, nc, xp=np):
    """Right-hand side of (1.3) in the generic form of D.4 [S] (mu = 1): returns (v2', v1')."""
    phi = nc["b1"] * y1 + nc["b2"] * y2
    quad = (v1 + v2) * phi
    sn = xp.sin(nc["Om"] * xp.asarray(t)[..., None])
    acc2 = (-nc["w1sq"] * y2 + nc["xi1"] * v1 + nc["q21"] * v1 + nc["q22"] * v2 + nc["c1"] * quad
            + xp.sum(nc["fa"] * sn, axis=-1))
    acc1 = (-nc["w2sq"] * y1 - nc["xi2"] * v2 + nc["q11"] * v1 + nc["q12"] * v2 + nc["c2"] * quad
            + xp.sum(nc["fb"] * sn, axis=-1))
    return acc2, acc1


# ---- averaging -------------------------------------------------------------------------------


def averaged(nc, xp=np):
    """p0..p3, g1, g2 of (3.3) for the resonance 2 omega_01 ~ Omega_2 (corrected p2, p3)."""
    md = modes(nc, xp)
    w01, w02, a1, a2 = md["w01"], md["w02"], md["a1"], md["a2"]
    d11, d12, d21, d22 = md["d11"], md["d12"], md["d21"], md["d22"]
    q21, q22, q11, q12 = nc["q21"], nc["q22"], nc["q11"], nc["q12"]
    p0 = 0.5 * w01 * (q12 / d12 - q21 * a1 / d11)
    p1 = -0.5 * w01 * (q22 / d11 + a1 * q11 / d12)
    g1 = -0.5 * w02 * (q22 / d22 + a2 * q11 / d21)
    g2 = 0.5 * w02 * (q12 / d21 - q21 * a2 / d22)
    Om = nc["Om"][..., 1]
    D1, D2, h1, h2 = forced_constants(Om, nc["fa"][..., 1], nc["fb"][..., 1], nc)
    b1, b2 = nc["b1"], nc["b2"]
    U = D1 * (w01 - Om) * (h2 * a1 * b1 + b2) + D2 * (h1 * (b1 * w01 - b2 * Om) + a1 * (b2 * w01 - b1 * Om))
    W = D2 * (w01 - Om) * (h1 * a1 * b1 - b2) + D1 * (a1 * (b2 * w01 - b1 * Om) - h2 * (b1 * w01 - b2 * Om))
    p2 = nc["c1"] * U / (4 * d11) - nc["c2"] * W / (4 * d12)
    p3 = nc["c1"] * W / (4 * d11) + nc["c2"] * U / (4 * d12)
    return dict(p0=p0, p1=p1, p2=p2, p3=p3, g1=g1, g2=g2, **md, D1=D1, D2=D2, h1=h1, h2=h2)


def p23_printed(nc, xp=np):
    """The paper's literal p2, p3 (docs/models/gyrodyne.md, misprint 13): alpha in place of beta inside the braces.

    D_1, D_2, h_1, h_2 are still taken at Omega_2 (the printed omega_01 there is singular);
    c2 is ignored as in the paper mapping. For comparison only -- it over-predicts growth.
    """
    md = modes(nc, xp)
    w01, a1, a2, d11 = md["w01"], md["a1"], md["a2"], md["d11"]
    Om = nc["Om"][..., 1]
    D1, D2, h1, h2 = forced_constants(Om, nc["fa"][..., 1], nc["fb"][..., 1], nc)
    U = D1 * (w01 - Om) * (h2 * a1 * a1 + a2) + D2 * (h1 * (a1 * w01 - a2 * Om) + a1 * (a2 * w01 - a1 * Om))
    W = D2 * (w01 - Om) * (h1 * a1 * a1 - a2) + D1 * (a1 * (a2 * w01 - a1 * Om) - h2 * (a1 * w01 - a2 * Om))
    return nc["c1"] * U / (4 * d11), nc["c1"] * W / (4 * d11)


def growth_rate(p0, p1, p2, p3, eps, xp=np):
    """Largest real part of the averaged mode-1 system: p1 + Re sqrt(p2^2 + p3^2 - (p0 + eps)^2)."""
    disc = p2 * p2 + p3 * p3 - (p0 + eps) ** 2
    return p1 + xp.sqrt(xp.maximum(disc, 0.0))


def averaged_solution(t, x0, gam0, co, eps):
    """Closed-form solution of the Cartesian averaged system (3.3) for mode 1 (NumPy, scalar params).

    Y' = (p1+p3) Y + (p2-p0-eps) Z,  Z' = (p0+p2+eps) Y + (p1-p3) Z;  returns x1(t), gamma1(t).
    """
    from scipy.linalg import expm

    M = np.array([[co["p1"] + co["p3"], co["p2"] - co["p0"] - eps], [co["p0"] + co["p2"] + eps, co["p1"] - co["p3"]]])
    Y0 = np.array([x0 * np.cos(gam0), x0 * np.sin(gam0)])
    out = np.array([expm(M * tk) @ Y0 for tk in np.atleast_1d(t)])
    return np.hypot(out[:, 0], out[:, 1]), np.arctan2(out[:, 1], out[:, 0])


def standard_form_rates(t, E1, th1, E2, th2, nc, md=None):
    """(E1', theta1' - omega_01, E2', theta2' - omega_02) by variation of constants in (2.1) (NumPy).

    The free part of (2.1) is linear in S_k = E_k sin th_k, C_k = E_k cos th_k, so the perturbation
    (0, P2, 0, P1) of (1.3) (the mu-terms evaluated on (2.1)) gives (S, C)' = M^-1 P exactly;
    independent of the printed delta_ij of (3.1).
    """
    md = md or modes(nc)
    fy2, fv2, fy1, fv1 = forced_solution(t, nc)
    y2, v2, y1, v1 = free_solution(E1, th1, E2, th2, md)
    y2, v2, y1, v1 = y2 + fy2, v2 + fv2, y1 + fy1, v1 + fv1
    phi = nc["b1"] * y1 + nc["b2"] * y2
    P2 = nc["q21"] * v1 + nc["q22"] * v2 + nc["c1"] * (v1 + v2) * phi
    P1 = nc["q11"] * v1 + nc["q12"] * v2 + nc["c2"] * (v1 + v2) * phi
    w01, w02, a1, a2 = md["w01"], md["w02"], md["a1"], md["a2"]
    # Cartesian free coordinates S_k = E_k sin th_k, C_k = E_k cos th_k: (y2, v2, y1, v1) = M (S1, C1, S2, C2)
    M = np.array([[1.0, 0.0, 1.0, 0.0], [0.0, w01, 0.0, w02], [0.0, a1, 0.0, a2], [-a1 * w01, 0.0, -a2 * w02, 0.0]])
    P = np.stack(np.broadcast_arrays(0 * P2, P2, 0 * P1, P1), -1)
    dS1, dC1, dS2, dC2 = np.moveaxis(np.linalg.solve(M, P[..., None])[..., 0], -1, 0)
    S1, C1, S2, C2 = E1 * np.sin(th1), E1 * np.cos(th1), E2 * np.sin(th2), E2 * np.cos(th2)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = [(S1 * dS1 + C1 * dC1) / E1, (C1 * dS1 - S1 * dC1) / E1**2,
               (S2 * dS2 + C2 * dC2) / E2, (C2 * dS2 - S2 * dC2) / E2**2]
    return np.stack(np.broadcast_arrays(*out), -1)


def standard_form_printed(t, E1, th1, E2, th2, nc, md=None):
    """(3.1) as printed (with the OCR fixes of docs/models/gyrodyne.md, misprint 10), f_1 = -P2, f_2 = -P1 on (2.1)."""
    md = md or modes(nc)
    fy2, fv2, fy1, fv1 = forced_solution(t, nc)
    y2, v2, y1, v1 = free_solution(E1, th1, E2, th2, md)
    y2, v2, y1, v1 = y2 + fy2, v2 + fv2, y1 + fy1, v1 + fv1
    phi = nc["b1"] * y1 + nc["b2"] * y2
    f1 = -(nc["q21"] * v1 + nc["q22"] * v2 + nc["c1"] * (v1 + v2) * phi)
    f2 = -(nc["q11"] * v1 + nc["q12"] * v2 + nc["c2"] * (v1 + v2) * phi)
    d11, d12, d21, d22 = md["d11"], md["d12"], md["d21"], md["d22"]
    E1d = f1 * np.cos(th1) / d11 - f2 * np.sin(th1) / d12
    T1d = -(f1 * np.sin(th1) / d11 + f2 * np.cos(th1) / d12) / E1
    E2d = f1 * np.cos(th2) / d22 - f2 * np.sin(th2) / d21
    T2d = -(f2 * np.cos(th2) / d21 + f1 * np.sin(th2) / d22) / E2
    return np.stack([E1d, T1d, E2d, T2d], -1)


def numerical_average(nc, n_t: int = 256, n_g: int = 8):
    """p0..p3, g1, g2 by averaging the standard form over the fast phase (unbatched NumPy dicts).

    Mode 1 (resonant): theta1 = Omega_2 t / 2 + gamma, average over one period 4 pi / Omega_2 of
    (E1'/E1, theta1' - omega_01) at several gamma, then fit p1 + p2 sin 2g + p3 cos 2g and
    p0 + p2 cos 2g - p3 sin 2g. Mode 2: average over t and theta2 independently (non-resonant).
    The amplitude used is tiny: the averaged system is linear in the free amplitudes.
    """
    md = modes(nc)
    Om2 = float(nc["Om"][1])
    T = 4 * np.pi / Om2
    ts = (np.arange(n_t) + 0.5) / n_t * T
    gs = np.arange(n_g) / n_g * np.pi
    x = 1e-6
    r_amp, r_ph = [], []
    for g in gs:
        r = standard_form_rates(ts, x, 0.5 * Om2 * ts + g, 0.0, 0.0, nc, md)
        r_amp.append(r[:, 0].mean() / x)
        r_ph.append(r[:, 1].mean())
    r_amp, r_ph = np.array(r_amp), np.array(r_ph)
    A = np.stack([np.ones_like(gs), np.sin(2 * gs), np.cos(2 * gs)], -1)
    p1, p2, p3 = np.linalg.lstsq(A, r_amp, rcond=None)[0]
    B = np.stack([np.ones_like(gs), np.cos(2 * gs), -np.sin(2 * gs)], -1)
    p0, p2b, p3b = np.linalg.lstsq(B, r_ph, rcond=None)[0]
    # mode 2: non-resonant torus average (t over the Omega_2 period, theta2 over [0, 2 pi))
    th = (np.arange(64) + 0.5) / 64 * 2 * np.pi
    TT, HH = np.meshgrid(ts, th, indexing="ij")
    r2 = standard_form_rates(TT.ravel(), 0.0, 0.0, x, HH.ravel(), nc, md)
    g1 = r2[:, 2].mean() / x
    g2 = r2[:, 3].mean()
    return dict(p0=p0, p1=p1, p2=p2, p3=p3, p2_phase=p2b, p3_phase=p3b, g1=g1, g2=g2)


# ---- predicates ------------------------------------------------------------------------------


def predicates(co, eps, xp=np):
    """Margins of the averaged stability conditions: returns dict name -> (ok, margin)."""
    p0, p1, p2, p3, g1, g2 = co["p0"], co["p1"], co["p2"], co["p3"], co["g1"], co["g2"]
    delta1 = p1 * p1 - p3 * p3 - (p0 + p2 + eps) * (p2 - p0 - eps)
    out = {}
    out["mode1_exact"] = (p1 < 0) & (delta1 > 0), xp.minimum(-p1, delta1 / xp.maximum(xp.abs(p1), 1e-300))
    out["mode1_paper"] = (p1 + p3 < 0) & (delta1 > 0), xp.minimum(-(p1 + p3), delta1 / xp.maximum(xp.abs(p1), 1e-300))
    out["mode2_exact"] = g1 < 0, -g1
    out["mode2_paper"] = (g1 < 0) & (g1 * g2 > 0), xp.minimum(-g1, xp.sign(g1 * g2) * xp.abs(g1))
    return out, delta1


def evaluate(p: Mapping[str, np.ndarray]) -> Theory:
    """All predicates of D.7 for the post-failover configuration (= nominal one if fail = 0)."""
    pre, post, Om2 = normal_coefficients(p, np)
    co = averaged(post, np)
    eps = co["w01"] - 0.5 * Om2
    preds, delta1 = predicates(co, eps, np)
    growth = growth_rate(co["p0"], co["p1"], co["p2"], co["p3"], eps, np)
    P = {}
    docs = {
        "mode1_exact": "averaged equations (3.3) say mode 1 decays; p1 < 0 and Delta_1 = p1^2 + (p0+eps)^2 - p2^2 - p3^2 > 0 "
                       "(Routh-Hurwitz of (3.3))",
        "mode1_paper": "paper: p1 + p3 < 0 and p1^2 - p3^2 - (p0+p2+eps)(p2-p0-eps) > 0",
        "mode2_exact": "g1 < 0 (mode 2, exact; g1^2 + g2^2 > 0 always)",
        "mode2_paper": "paper: g1 < 0 and g1 g2 > 0 (g1 g2 > 0 probably a misprint)",
    }
    for k, (ok, m) in preds.items():
        P[k] = Predicate(ok=np.asarray(ok), margin=np.asarray(m, float), doc=docs[k])
    P["stable_exact"] = Predicate(
        ok=P["mode1_exact"].ok & P["mode2_exact"].ok,
        margin=np.minimum(P["mode1_exact"].margin, P["mode2_exact"].margin),
        doc="both modes, exact averaged conditions: forced oscillation (2.2) asymptotically stable",
    )
    P["stable_paper"] = Predicate(
        ok=P["mode1_paper"].ok & P["mode2_paper"].ok,
        margin=np.minimum(P["mode1_paper"].margin, P["mode2_paper"].margin),
        doc="both modes, the paper's conditions",
    )
    p2l, p3l = p23_printed(post, np)
    derived = dict(
        omega01=co["w01"], omega02=co["w02"], alpha1=co["a1"], alpha2=co["a2"], Omega2=Om2, eps=eps,
        p0=co["p0"], p1=co["p1"], p2=co["p2"], p3=co["p3"], g1=co["g1"], g2=co["g2"], Delta1=delta1,
        growth_pred=growth, growth_pred_printed=growth_rate(co["p0"], co["p1"], p2l, p3l, eps, np),
        D1=co["D1"], D2=co["D2"], A2_star_ratio=np.abs(co["p1"]) / np.maximum(np.hypot(co["p2"], co["p3"]), 1e-300),
        omega01_pre=modes(pre, np)["w01"],
    )
    derived_doc = dict(
        omega01="fast natural frequency, post-failover set", omega02="slow natural frequency",
        alpha1="mode-1 shape", alpha2="mode-2 shape", Omega2="scanning frequency of slot 2 (tuned if tune=1)",
        eps="detuning omega_01 - Omega_2/2", p0="(3.3)", p1="(3.3)", p2="(3.3), corrected", p3="(3.3), corrected",
        g1="(3.3) mode 2 damping", g2="(3.3) mode 2 frequency shift", Delta1="Delta_1 = p1^2 + (p0+eps)^2 - p2^2 - p3^2",
        growth_pred="averaged growth rate of a mode-1 disturbance [1/s]",
        growth_pred_printed="the same with the paper's literal (alpha-version) p2, p3",
        D1="forced amplitude D_1 at Omega_2", D2="forced amplitude D_2 at Omega_2",
        A2_star_ratio="|p1| / sqrt(p2^2+p3^2): tongue opens when this drops below 1 (scale A_2 by it)",
        omega01_pre="omega_01 of the nominal (pre-failure) set",
    )
    return Theory(predicates=P, derived=derived, derived_doc=derived_doc, main="mode1_exact")
