"""Bezglasnyi-Mysina closed loops against an independent NumPy/SciPy reference (docs/models/twobody.md).

The reference integrates *plant and controller separately*, written from the paper's
equations in a different form than the package's closed loop:

* physical plant: angular momentum K = I1 w + I2~ (w + w02), dK/dt + w x K = M_y, with
  d(I2~)/dt from the derivative of the rotation matrix (no M0 / [w02]x shortcut);
* printed plant (variant 1): equation (5) term by term, with I2 delta^-1 in the cross products;
* controls (6) / (12) / (16)+(19) / (16)+(24) including the rotor-acceleration feed-forward
  and, in the rotating frame, the nominal torque M0 (16) built from w0' -- terms that cancel in
  the package's closed-loop form, so a sign slip in either would show.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import stabjax  # noqa: F401  (float64)
from stabjax import get_system
from stabjax.engines.simulate import simulate


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def cross(a, b):
    """a x b of two 3-vectors: np.cross's products and differences, without its axis handling (which took
    most of the reference's time: the right-hand side below takes up to 15 cross products)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def delta_fn(t, p):
    """(delta, delta', delta'') of the two programs, written out independently."""
    d0, Om, dA, nu, tau = (float(p[k]) for k in ("delta0", "Omega_r", "dA", "dnu", "tau"))
    if float(p["delta_prog"]) == 1:
        return d0 + Om * tau * np.log(np.cosh(t / tau)), Om * np.tanh(t / tau), Om / tau / np.cosh(t / tau) ** 2
    mod = dA * (1 - np.cos(nu * t)) / nu if nu != 0 else 0.0
    return d0 + Om * t + mod, Om + dA * np.sin(nu * t), dA * nu * np.cos(nu * t)


def omega0_fn(t, p):
    c, a, f, ph = (np.asarray(p[k], float) for k in ("om0_c", "om0_a", "om0_f", "om0_p"))
    return c + a * np.sin(f * t + ph), a * f * np.cos(f * t + ph)


def reference_rhs(p, rotating, triaxial):
    I1, I2 = np.asarray(p["I1"], float), np.asarray(p["I2"], float)
    B = np.asarray(p["B"], float) + float(p["b"]) * np.eye(3)
    variant = float(p["variant"])
    kin = float(p.get("kinematics", 0.0))
    if triaxial:
        R = np.column_stack([p["r01"], p["r02"], cross(p["r01"], p["r02"])])

    def rot(t):
        d, dd, ddd = delta_fn(t, p)
        c, s = np.cos(d), np.sin(d)
        D = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        Dd = dd * np.array([[-s, -c, 0], [c, -s, 0], [0, 0, 0.0]])
        return D, Dd, np.array([0, 0, dd]), np.array([0, 0, ddd])

    def plant(t, w, wdot):
        """Left-hand side of the equations of motion (physical or printed (5))."""
        D, Dd, w02, w02d = rot(t)
        It = D @ I2 @ D.T
        if variant == 0:
            K = I1 @ w + It @ (w + w02)
            Itd = Dd @ I2 @ D.T + D @ I2 @ Dd.T
            return I1 @ wdot + Itd @ (w + w02) + It @ (wdot + w02d) + cross(w, K)
        G = I2 @ D.T
        return ((I1 + It) @ wdot + D @ I2 @ Dd.T @ w + It @ w02d + D @ I2 @ Dd.T @ w02 + cross(w, I1 @ w)
                + cross(w + w02, G @ w) + cross(w + w02, G @ w02))

    def potential(att):
        if triaxial:
            return sum(p["alphas"][i] * cross(R[:, i], att[:, i]) for i in range(3))
        return float(p["alpha"]) * cross(p["r0"], att)

    def f(t, y):
        x = y[:3]
        att = y[3:].reshape(3, 3) if triaxial else y[3:]
        D, Dd, w02, w02d = rot(t)
        It = D @ I2 @ D.T
        G = It if variant == 0 else I2 @ D.T
        if rotating:
            w0, w0d = omega0_fn(t, p)
            M0 = plant(t, w0, w0d)  # (16): the left side at w = w0
            M = -B @ x - Dd @ I2 @ D.T @ x + potential(att)  # (19) / (24)
            My = M0 + M
        else:
            w0, w0d = np.zeros(3), np.zeros(3)
            # (6) / corrected (12): the feed-forward terms use the same G as the plant
            My = (-(B + Dd @ I2 @ D.T) @ x + potential(att) + It @ w02d + D @ I2 @ Dd.T @ w02
                  + cross(w02, G @ w02))
        w = w0 + x
        # the plant is affine in wdot: solve plant(w, wdot) = My
        base = plant(t, w, np.zeros(3))
        Jm = np.column_stack([plant(t, w, e) - base for e in np.eye(3)])
        wdot = np.linalg.solve(Jm, My - base)
        v = x + (w0 if (rotating and kin == 1) else 0.0)
        datt = (-hat(v) @ att).ravel() if triaxial else -cross(v, att)
        return np.concatenate([wdot - w0d, datt])

    return f


CASES = [
    ("twobody_uniaxial", {}),
    ("twobody_uniaxial", {"variant": 1, "dA": 1.0, "dnu": 0.7, "b": 1.0, "delta0": 0.3}),
    ("twobody_uniaxial", {"delta_prog": 1, "tau": 2.0, "Omega_r": -4.0, "b": 0, "B": "2,3,4",
                          "r0": "0.6,0,0.8", "w0": "1,0.5,-0.7"}),
    ("twobody_triaxial", {"dA": 0.8, "dnu": 1.3, "B": "1,0.2,0,0.2,1,0.1,0,0.1,1", "b": 1.5}),
    ("twobody_triaxial", {"variant": 1, "alphas": "1,3,2"}),
    ("twobody_uniaxial_rotating", {}),
    ("twobody_uniaxial_rotating", {"variant": 1, "kinematics": 1, "dA": 0.5, "dnu": 2.0}),
    ("twobody_triaxial_rotating", {"delta_prog": 1, "tau": 3.0}),
    ("twobody_triaxial_rotating", {"variant": 1, "kinematics": 1, "om0_c": "0.1,0.2,-0.3"}),
]


@pytest.mark.parametrize("name,over", CASES)
def test_closed_loop_matches_scipy_reference(name, over):
    sys_ = get_system(name)
    p = sys_.check(sys_.params.resolve(over))
    ts = np.array([0.5, 2.0, 5.0, 10.0, 15.0])
    ds = simulate(sys_, over, t1=15.0, ts=ts, rtol=1e-11, atol=1e-13)
    assert ds.attrs["solver_ok"] == 1
    comps = [ds[n].values.reshape(len(ds.t), -1) for n, _ in sys_.state]
    y_jax = np.concatenate(comps, axis=1)
    sel = np.isin(ds.t.values, ts)
    y0 = np.asarray(sys_.initial_state(p))
    ref = solve_ivp(reference_rhs(p, sys_.rotating, sys_.triaxial), (0, 15.0), y0, method="DOP853",
                    t_eval=ts, rtol=1e-11, atol=1e-13)
    assert ref.success
    err = np.abs(y_jax[sel] - ref.y.T).max()
    assert err <= 1e-6, err
    # the trajectory actually moved (the comparison is not between two resting states)
    assert np.abs(ref.y[:, -1] - y0).max() > 1e-2
