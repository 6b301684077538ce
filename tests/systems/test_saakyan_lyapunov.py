"""Lyapunov identities along the vector field, and deviation form vs original form (docs/models/saakyan.md).

dV/dt is computed by forward-mode automatic differentiation of the Lyapunov function
(1.9)/(2.6)/(3.18)/(4.3) (as written in original variables) along the right-hand side,
dV/dt = dV/dt|_explicit + grad_y V . f(t, y), and compared with the paper's closed forms
(1.12), (3.20) at random states.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import stabjax  # noqa: F401
from stabjax.model.registry import get_system

NAMES = ["saakyan_moving", "saakyan_fixed", "saakyan_gravity", "saakyan_gyrostat", "saakyan_gyrostat_gravity"]


def _prep(name, over):
    s = get_system(name)
    p = s.check(s.params.resolve(over))
    pj = {k: jnp.asarray(v) for k, v in p.items()}
    return s, pj, s.prepare(pj)


def _random_states(s, n, rng):
    ys = []
    for _ in range(n):
        w = rng.normal(size=3)
        S = rng.normal(size=3)
        S /= np.linalg.norm(S)
        if s.gyrostat:
            ys.append(np.concatenate([w, 3 * rng.normal(size=3), S]))
        else:
            ys.append(np.concatenate([w, S]))
    return jnp.asarray(np.array(ys))


def _vdot_autodiff(s, a):
    def one(t, y):
        f = s.rhs(t, y, a)
        _, dv = jax.jvp(lambda tt, yy: s.lyapunov(tt, yy, a), (t, y), (jnp.ones_like(t), f))
        return dv

    return jax.jit(jax.vmap(one))


PARAMS = {
    "saakyan_moving": dict(I=(4.0, 3.0, 2.0), lam=0.5, K=7.2, w0c=(0.1, -0.2, 0.3), w0a=(0.2, 0.3, 0.15),
                           w0f=(0.3, 0.7, 0.2), w0phi=(0.1, 0.0, 1.5)),
    "saakyan_fixed": dict(I=(5.0, 6.0, 4.0), lam=0.9, K=2.0),  # identity does not need (1.10)
    "saakyan_gravity": dict(I=(4.0, 3.0, 2.0), lam=0.6, K=6.0, nu=0.5),  # nor lam^2 = nu
    "saakyan_gyrostat": dict(I=(4.0, 3.0, 2.0), Jw=(0.3, 0.2, 0.4), lam=0.5, h=6.0),
    "saakyan_gyrostat_gravity": dict(I=(4.0, 3.0, 2.0), Jw=(0.3, 0.2, 0.4), lam=0.5, h=1.0, nu=0.3, gz=0.0),
}


@pytest.mark.parametrize("name", NAMES)
def test_lyapunov_identity_by_autodiff(name):
    """(1.12) for B-1/B-2 (with (1.11), (2.8)), (3.20) for B-3, the same form for B-4 (4.3)."""
    rng = np.random.default_rng(1)
    s, pj, a = _prep(name, dict(PARAMS[name], H=(0.3, -0.5, 0.8)))
    ys = _random_states(s, 20, rng)
    ts = jnp.asarray(rng.uniform(0, 20, size=20))
    vd = np.asarray(_vdot_autodiff(s, a)(ts, ys))
    rate = np.asarray(jax.vmap(lambda t, y: s.lyapunov_rate(t, y, a))(ts, ys))
    scale = np.abs(rate).max()
    assert scale > 1e-2  # non-trivial states
    np.testing.assert_allclose(vd, rate, rtol=0, atol=1e-12 * scale * 100)
    assert (rate <= 0).all() or name == "saakyan_gyrostat_gravity"


def test_b4_physical_gravity_on_z_adds_z_dot_G():
    """[D] with z' = z x w + G (gz = 1) the (4.3) rate gains z.G, which has either sign."""
    rng = np.random.default_rng(2)
    s, pj, a = _prep("saakyan_gyrostat_gravity", dict(PARAMS["saakyan_gyrostat_gravity"], gz=1.0))
    ys = _random_states(s, 30, rng)
    ts = jnp.zeros(30)
    vd = np.asarray(_vdot_autodiff(s, a)(ts, ys))
    rate = np.asarray(jax.vmap(lambda t, y: s.lyapunov_rate(t, y, a))(ts, ys))
    np.testing.assert_allclose(vd, rate, atol=1e-10)
    _, _, a0 = _prep("saakyan_gyrostat_gravity", dict(PARAMS["saakyan_gyrostat_gravity"], gz=0.0))
    paper = np.asarray(jax.vmap(lambda t, y: s.lyapunov_rate(t, y, a0))(ts, ys))
    extra = vd - paper
    assert extra.max() > 1e-3 and extra.min() < -1e-3


def _solve(fun, x0, ts):
    f = jax.jit(fun)
    sol = solve_ivp(lambda t, x: np.asarray(f(t, jnp.asarray(x))), (0, ts[-1]), x0, method="DOP853",
                    rtol=1e-11, atol=1e-13, t_eval=ts)
    assert sol.success
    return sol.y.T


DEV = {
    "saakyan_moving": dict(PARAMS["saakyan_moving"]),
    "saakyan_fixed": dict(I=(5.0, 6.0, 4.0), lam=0.9, K=6.0, use_mu=0.0),
    "saakyan_gravity": dict(PARAMS["saakyan_gravity"]),
    "saakyan_gyrostat": dict(PARAMS["saakyan_gyrostat"], eta0=(0.3, -0.4, 0.5)),
    "saakyan_gyrostat_gravity": dict(PARAMS["saakyan_gyrostat_gravity"], eta0=(0.3, -0.4, 0.5)),
}


@pytest.mark.parametrize("name", NAMES)
def test_deviation_form_matches_original_form(name):
    """(1.7)-(1.8) / (2.4)-(2.5) / (3.17) / (4.2) (components as printed) give the same trajectories."""
    s, pj, a = _prep(name, DEV[name])
    y0 = s.initial_state(pj)
    x0 = s.to_deviation(0.0, y0, a)
    ts = np.array([0.0, 2.0, 5.0, 10.0])
    ys = _solve(lambda t, y: s.rhs(t, y, a), np.asarray(y0), ts)
    xs = _solve(lambda t, x: s.deviation_rhs(t, x, a), np.asarray(x0), ts)
    back = np.array([np.asarray(s.from_deviation(t, jnp.asarray(x), a)) for t, x in zip(ts, xs)])
    assert np.abs(ys[-1] - ys[0]).max() > 1e-2
    np.testing.assert_allclose(back, ys, atol=1e-7)
    # the deviation system keeps the constraint (1.15) |beta + delta| = 1
    beta = np.asarray(a["beta"])
    d = xs[:, 3:6]
    np.testing.assert_allclose(np.sum(d * d, 1) + 2 * d @ beta, 0, atol=1e-9)


@pytest.mark.parametrize("name", ["saakyan_fixed", "saakyan_gravity", "saakyan_gyrostat"])
def test_rhs_pointwise_equals_deviation_rhs(name):
    """At random states on the sphere the two vector fields agree to rounding (no integration)."""
    rng = np.random.default_rng(3)
    over = dict(DEV[name], use_mu=1.0)
    s, pj, a = _prep(name, over)
    for y in _random_states(s, 10, rng):
        f = np.asarray(s.rhs(0.3, y, a))
        x = s.to_deviation(0.3, y, a)
        g = np.asarray(s.deviation_rhs(0.3, x, a))
        fd = np.asarray(s.to_deviation(0.3, jnp.asarray(f), {**a, "lam": 0.0, "h": 0.0, "beta": 0 * a["beta"]}))
        np.testing.assert_allclose(g, fd, atol=1e-12)
