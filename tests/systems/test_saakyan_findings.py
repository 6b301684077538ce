"""Where Saakyan's paper is wrong or conservative (docs/models/saakyan.md), each shown by simulation.

1. (3.9) combined with (3.21) counts -lam z x H0 twice: no convergence, dV/dt of (3.18) changes sign.
2. The global ("in the large") claims of Theorems 3-4 fail: with h > lam m1 the inverted spin is
   an invariant motion, and for h in (lam m1, lam(2 I_max - I_mid)) it is even asymptotically
   stable, so an open set of initial states never reaches the target.
3. (4.4) as printed (+nu J_i) is conservative: with h between the exact and the printed bound the
   target is still reached.
4. Spurious steady spins when (1.21) fails: an exact off-target steady spin lies inside (1.22).
5. Without mu the target of Corollary 2 is unstable (positive real root of phi, docs/models/saakyan.md).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax.engines.simulate import simulate
from stabjax.model.registry import get_system
from stabjax.systems import saakyan_theory as T

I432 = (4.0, 3.0, 2.0)
J_ = (0.3, 0.2, 0.4)
H_ = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
S_ = np.array([0.2, 0.9, -0.3]) / np.linalg.norm([0.2, 0.9, -0.3])


def _prep(name, over):
    s = get_system(name)
    p = s.check(s.params.resolve(over))
    pj = {k: jnp.asarray(v) for k, v in p.items()}
    return s, p, s.prepare(pj)


# 1 -------------------------------------------------------------------------------------------


def test_double_counted_term_prevents_convergence():
    """docs/models/saakyan.md case B-3: Theorem-3 torque converges, (3.9)+(3.21) does not (0.33 at t = 80)."""
    base = dict(I=I432, Jw=J_, lam=0.5, h=6.0, H=tuple(H_), S0=tuple(S_), eta0=tuple(np.array([0.8, -0.6, 2.0]) - 6 * H_))
    out = {}
    for tv in (0.0, 1.0, 2.0):
        ds = simulate("saakyan_gyrostat", dict(base, torque=tv), t1=80.0, ts=[0.0, 80.0])
        S = ds["S"].values[-1]
        out[tv] = np.linalg.norm(S - H_)
        # |z| is a first integral whatever the torque (3.7)
        assert ds["z_norm"].values[-1] == pytest.approx(np.sqrt(0.8**2 + 0.6**2 + 2.0**2), abs=1e-8)
    assert out[0.0] < 1e-8 and out[2.0] < 1e-8  # (3.9) with mu' = mu + lam eta x H0 is the same torque
    assert out[1.0] == pytest.approx(0.33, abs=0.01)
    th = get_system("saakyan_gyrostat").theory(get_system("saakyan_gyrostat").check(
        get_system("saakyan_gyrostat").params.resolve(dict(base, torque=1.0))))
    assert not th.predicates["theorem3"].ok  # the predicate does not credit the printed combination


def test_double_counted_term_makes_dV_sign_indefinite():
    s, _, a = _prep("saakyan_gyrostat", dict(I=I432, Jw=J_, lam=0.5, h=6.0, torque=1.0))
    rng = np.random.default_rng(5)

    def vdot(y):
        return jax.jvp(lambda yy: s.lyapunov(0.0, yy, a), (y,), (s.rhs(0.0, y, a),))[1]

    vals = []
    for _ in range(200):
        S = rng.normal(size=3)
        S /= np.linalg.norm(S)
        y = jnp.asarray(np.concatenate([rng.normal(size=3), 3 * rng.normal(size=3), S]))
        vals.append(float(jax.jit(vdot)(y)) - float(s.lyapunov_rate(0.0, y, a)))
    vals = np.array(vals)
    assert vals.max() > 1e-2  # dV/dt exceeds (3.20) somewhere ...
    # ... and there are states with dV/dt > 0 outright
    pos = []
    for _ in range(200):
        S = rng.normal(size=3)
        S /= np.linalg.norm(S)
        y = jnp.asarray(np.concatenate([0.1 * rng.normal(size=3), 3 * rng.normal(size=3), S]))
        pos.append(float(jax.jit(vdot)(y)))
    assert max(pos) > 1e-3


# 2 -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, extra", [
    ("saakyan_gyrostat", dict()),
    ("saakyan_gyrostat_gravity", dict(nu=0.02, gz=1.0)),
])
def test_global_claim_fails_inverted_spin_attracts(name, extra):
    """h = 4.5 > lam m1 = 4 (Theorem 3; (4.4) holds too), H0 = e_x: start 0.1 rad from the inverted
    spin (S0 = -H0, omega = -lam H0) and stay there -- an open set never reaches the target."""
    s = get_system(name)
    over = dict(I=I432, Jw=J_, lam=1.0, h=4.5, H=(1.0, 0.0, 0.0), init=1.0, rho=2 * np.cos(0.05),
                S0=(0.0, 0.6, 0.8), w_ratio=1.0, dw0=(-1.0, 0.05, -0.05), eta0=(0.2, -0.3, 0.1), **extra)
    p = s.check(s.params.resolve(over))
    th = s.theory(p)
    main = th.predicates[th.main]
    assert main.ok  # the paper claims convergence from everywhere
    # t1 and save times of test_printed_44_is_conservative (its gravity case reuses that compiled loop)
    ds = simulate(s, over, t1=400.0, ts=np.linspace(0, 400, 9))
    ang = ds["angle"].values
    assert ang[0] == pytest.approx(np.pi - 0.1, abs=1e-9)
    assert ang[-1] > np.pi - 1e-6  # converged onto the inverted spin
    assert ds["dist_E"].values[-1] < 1e-6


def test_inverted_spin_is_exactly_invariant_and_linearly_stable_in_b3():
    s, _, a = _prep("saakyan_gyrostat", dict(I=I432, Jw=J_, lam=1.0, h=4.5, H=(1.0, 0.0, 0.0)))
    H = np.array([1.0, 0.0, 0.0])
    y = jnp.asarray(np.concatenate([-H, 4.5 * H, -H]))
    assert np.abs(np.asarray(s.rhs(0.0, y, a))).max() == 0.0
    # (w1, delta) block of the Jacobian (eta never feeds back): all 5 tangent eigenvalues < 0
    Jf = np.asarray(jax.jacfwd(lambda yy: s.rhs(0.0, yy, a))(y))
    idx = [0, 1, 2, 6, 7, 8]
    ev = np.linalg.eigvals(Jf[np.ix_(idx, idx)])
    ev = np.delete(ev, np.argmin(np.abs(ev)))  # the radial direction of S0 (torques use S0/|S0|)
    assert ev.real.max() < -0.1


def test_theorem3_flawed_step_the_integral_is_not_n():
    """On E the eta equations (3.22) keep eta.(beta + l) - h l.(beta + l) constant [D]: the paper's
    (3.23) constant n is not the quantity it later equates, so l = 0 does not follow. Check along a
    trajectory started on E at the counter-example spin (l != 0)."""
    s, _, a = _prep("saakyan_gyrostat", dict(I=I432, Jw=J_, lam=1.0, h=5.0, H=(1.0, 0.0, 0.0)))
    l, d = T.l_spurious(np.array(I432), np.array([1.0, 0, 0]), 1.0, 5.0)
    S = np.array([1.0, 0, 0]) + d
    eta0 = np.array([0.3, -0.2, 0.4])
    y0 = np.concatenate([1.0 * S, 5.0 * np.array([1.0, 0, 0]) + eta0, S])
    f = jax.jit(lambda t, y: s.rhs(t, y, a))
    # the spin is steady: w1 = lam delta, delta constant
    g = np.asarray(f(0.0, jnp.asarray(y0)))
    assert np.abs(g[:3]).max() < 1e-12 and np.abs(g[6:]).max() < 1e-12
    from scipy.integrate import solve_ivp

    sol = solve_ivp(lambda t, y: np.asarray(f(t, jnp.asarray(y))), (0, 20), y0, method="DOP853", rtol=1e-11,
                    atol=1e-13, t_eval=np.linspace(0, 20, 9))
    eta = sol.y[3:6].T - 5.0 * np.array([1.0, 0, 0])
    inv = eta @ S
    assert np.ptp(inv) < 1e-8
    assert np.ptp(eta[:, 1]) > 0.1  # eta itself moves: the first integral is non-trivial
    # inserting (3.24) into (3.23) gives eta.(beta + l) = n + h l.(beta + l), and
    # l.(beta + l) = |l|^2/2 != 0 for l != 0: the two constants differ, no contradiction arises
    assert d @ S == pytest.approx(np.dot(d, d) / 2, abs=1e-12) and d @ S > 0.1


# 3 -------------------------------------------------------------------------------------------


def test_printed_44_is_conservative():
    """lam^2 = nu = 1, J = (1, 1, 1): printed (4.4) needs h > 1, exact only h > 0. h = 0.8 converges."""
    over = dict(I=I432, Jw=(1.0, 1.0, 1.0), lam=1.0, nu=1.0, h=0.8, H=tuple(H_), init=1.0, rho=0.6,
                S0=tuple(S_), dw0=(0.3, -0.2, 0.1))
    s = get_system("saakyan_gyrostat_gravity")
    th = s.theory(s.check(s.params.resolve(over)))
    assert not th.predicates["c44_printed"].ok and th.predicates["c44_exact"].ok
    assert th.derived["h44_printed"] == pytest.approx(1.0) and th.derived["h44_exact"] == pytest.approx(-1.0)
    ds = simulate(s, over, t1=400.0, ts=np.linspace(0, 400, 9))
    e = ds["error"].values
    assert e[0] > 1.0 and e[-1] < 1e-6
    assert (np.diff(np.log(e[4:])) < -1.0).all()  # steady exponential decay, not a stall


# 4 -------------------------------------------------------------------------------------------


def test_spurious_steady_spin_inside_region_122_when_121_fails():
    """docs/models/saakyan.md example (spurious spin): (4,3,2), H0 = e_x, lam = 1, K = 5 -- (1.10) yes, (1.21) no;
    S0 = (-0.5, 0, 0.866), omega = lam S0 is an exact steady spin with |delta| = 1.732 < 2."""
    S = np.array([-0.5, 0.0, np.sqrt(3) / 2])
    H = np.array([1.0, 0.0, 0.0])
    over = dict(I=I432, H=tuple(H), lam=1.0, K=5.0, S0=tuple(S), dw0=tuple(1.0 * (S - H)))
    s = get_system("saakyan_fixed")
    th = s.theory(s.check(s.params.resolve(over)))
    assert th.predicates["c110"].ok and not th.predicates["c121"].ok
    assert th.predicates["region122"].ok  # inside (1.22) ...
    assert not th.predicates["theorem1"].ok  # ... but outside (1.18): l = sqrt(3)
    assert th.derived["l_spurious"] == pytest.approx(np.sqrt(3), abs=1e-8)
    ds = simulate(s, over, t1=50.0, ts=np.linspace(0, 50, 6))
    assert np.abs(ds["S"].values - S).max() < 1e-6
    assert np.abs(ds["w"].values - S).max() < 1e-6
    # with (1.21) (K = 8.5) the same initial state converges
    ds2 = simulate(s, dict(over, K=8.5), t1=50.0, ts=np.linspace(0, 50, 6))
    assert ds2["error"].values[-1] < 1e-4


# 5 -------------------------------------------------------------------------------------------


def test_no_mu_linearisation_has_positive_real_root_and_phi0():
    lam, K = 1.0, 5.0
    s, _, a = _prep("saakyan_fixed", dict(I=I432, H=tuple(H_), lam=lam, K=K, use_mu=0.0))
    Jl = np.asarray(jax.jacfwd(lambda x: s.deviation_rhs(0.0, x, a))(jnp.zeros(6)))
    coeffs = np.poly(Jl) * np.prod(I432)  # ABC det(zeta I - J)
    assert abs(coeffs[-1]) < 1e-10  # Delta = zeta phi(zeta)
    phi0 = -(lam**4) * K * T.bracket_phi0(np.array(I432), H_)
    assert coeffs[-2] == pytest.approx(phi0, rel=1e-10)
    ev = np.linalg.eigvals(Jl)
    real_pos = ev[(np.abs(ev.imag) < 1e-12) & (ev.real > 1e-6)]
    assert real_pos.size >= 1
    th = s.theory(s.check(s.params.resolve(dict(I=I432, H=tuple(H_), lam=lam, K=K, use_mu=0.0))))
    assert th.predicates["unstable_no_mu"].ok and not th.predicates["guaranteed"].ok


def test_no_mu_simulation_leaves_the_target_with_mu_it_returns():
    over = dict(I=I432, H=tuple(H_), lam=1.0, K=5.0, init=1.0, rho=1e-6, use_mu=0.0)
    # t1 and save times of the spurious-spin test above (the same compiled loop): the error is ~1 by t = 20
    # without mu and ~1e-10 by t = 30 with it
    ds = simulate("saakyan_fixed", over, t1=50.0, ts=np.linspace(0, 50, 6))
    assert ds["error"].values[0] < 1e-5 and ds["error"].values[-1] > 1.0
    ds = simulate("saakyan_fixed", dict(over, use_mu=1.0), t1=50.0, ts=np.linspace(0, 50, 6))
    assert ds["error"].values[-1] < 1e-8
