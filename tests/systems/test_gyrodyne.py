"""Gyrodyne (Khoroshilov, docs/models/gyrodyne.md): geometry, models vs SciPy references, theory, averaging."""
from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import stabjax  # noqa: F401  (float64)
from stabjax.errors import ValidationError
from stabjax.model.registry import get_system
from stabjax.systems import gyrodyne_theory as T

S = get_system("gyrodyne")
D9 = dict(source=1.0, model=0.0)  # the regression case of D.9 (nc_* defaults)


def resolved(**over):
    return S.check(S.params.resolve(over))


def jrhs(p):
    a = S.prepare({k: jnp.asarray(v) for k, v in p.items()})
    f = jax.jit(lambda t, y: S.rhs(t, y, a))
    return a, f


def integrate_jax(p, ts, rtol=1e-11, atol=1e-13):
    import diffrax

    a = S.prepare({k: jnp.asarray(v) for k, v in p.items()})
    y0 = S.initial_state({k: jnp.asarray(v) for k, v in p.items()})
    sol = diffrax.diffeqsolve(diffrax.ODETerm(S.rhs), diffrax.Dopri8(), 0.0, float(ts[-1]), None, y0, args=a,
                              saveat=diffrax.SaveAt(ts=jnp.asarray(ts)),
                              stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol), max_steps=10**6)
    return np.asarray(sol.ys), a, np.asarray(y0)


# ---- geometry ------------------------------------------------------------------------------


@pytest.mark.parametrize("yaw", [0.0, 0.3, 1.1])
def test_tetrahedral_geometry(yaw):
    geo = T.geometry(yaw)
    g, u, w = geo["g"], geo["u"], geo["w"]
    np.testing.assert_allclose(np.linalg.norm(g, axis=-1), 1.0, atol=1e-14)
    G = g @ g.T
    off = G[~np.eye(4, dtype=bool)]
    np.testing.assert_allclose(off, -1.0 / 3.0, atol=1e-14)
    np.testing.assert_allclose(g.sum(axis=0), 0.0, atol=1e-14)  # vertices of a centred tetrahedron
    for sub in itertools.combinations(range(4), 3):
        assert abs(np.linalg.det(g[list(sub)])) > 0.5  # every 3-subset spans space
        assert abs(np.linalg.det(w[list(sub)])) > 0.1  # so do the torque axes used for allocation
    # mounting angles reproduce the axes: g = (cos l cos d, sin l cos d, -sin d); w = g x u; u horizontal
    lam, dl = geo["lam"], geo["delta"]
    np.testing.assert_allclose(g, np.stack([np.cos(lam) * np.cos(dl), np.sin(lam) * np.cos(dl), -np.sin(dl)], -1), atol=1e-14)
    np.testing.assert_allclose(w, np.cross(g, u), atol=1e-14)
    np.testing.assert_allclose(np.einsum("ij,ij->i", g, u), 0.0, atol=1e-14)
    np.testing.assert_allclose(u[:, 2], 0.0)


def test_slot_tables_and_allocation():
    p = resolved(spare=2.0, fail=3.0)
    np.testing.assert_array_equal(T.slots(p, "pre"), [0, 2, 3])
    np.testing.assert_array_equal(T.slots(p, "post"), [0, 1, 3])  # spare 2 takes failed gyro 3's slot
    for stage in ("pre", "post"):
        al = T.allocation(p, stage)
        np.testing.assert_allclose(al["W"] @ al["Gk"], p["Kp"], atol=1e-12)  # gains recomputed per set
        np.testing.assert_allclose(al["W"] @ al["GK"], p["gain"] * p["Kd"], atol=1e-12)


def test_validation_errors():
    with pytest.raises(ValidationError) as e:
        resolved(spare=2.0, fail=2.0)
    assert e.value.field == "fail"
    with pytest.raises(ValidationError) as e:
        resolved(Kp=[8, 0, 0, 0, 6, 1.5, 0, 1.0, 4])
    assert e.value.field == "Kp"
    with pytest.raises(ValidationError) as e:
        resolved(Omega=[1.0, -2.0, 1.0], tune=0.0)
    assert e.value.field == "Omega"
    with pytest.raises(ValidationError) as e:
        resolved(H=[8, 0, 8, 8])
    assert e.value.field == "H"
    with pytest.raises(ValidationError):
        resolved(model=3.0)
    with pytest.raises(ValidationError) as e:
        resolved(I=[1.0, 1.0, 5.0])
    assert e.value.field == "I"


# ---- theory: D.9 regression, averaging, predicates ---------------------------------------------


def d9_nc(eps=0.0, scale=1.0):
    p = resolved(**D9, eps=eps)
    pre, _, _ = T.normal_coefficients(p)
    nc = {k: np.asarray(v) for k, v in pre.items()}
    for k in ("q21", "q22", "q11", "q12", "c1", "c2"):
        nc[k] = nc[k] * scale
    return nc


def test_d9_regression_values():
    """The regression case of docs/models/gyrodyne.md. Independent of the code: the natural frequencies and mode
    shapes from the generating solution's closed form, written out here (omega_0^2 = S/2 +- sqrt(S^2/4 -
    omega_1^2 omega_2^2), S = omega_1^2 + omega_2^2 + xi_1 xi_2; alpha_h = (omega_0h^2 - omega_1^2) / (xi_1 omega_0h))
    to 1e-12, and the averaged coefficients p0..p3, g1, g2 against the numerical average of the standard form
    over the period (quadrature, not the closed-form averaging) to 1e-7 of their scale. The remaining figures
    (D1, D2, h1, h2, the interaction terms) are the documented values, which nothing else computes: kept as a
    regression guard at the digits the docs print."""
    w1, w2, x1, x2 = 1.0, 1.6, 0.3, 0.25  # the case's omega_1, omega_2, xi_1, xi_2
    S_ = w1**2 + w2**2 + x1 * x2
    w0 = np.sqrt(S_ / 2 + np.array([1, -1]) * np.sqrt(S_**2 / 4 - w1**2 * w2**2))
    alpha = (w0**2 - w1**2) / (x1 * w0)
    co = T.averaged(d9_nc())
    np.testing.assert_allclose([co["w01"], co["w02"]], w0, rtol=1e-12)
    np.testing.assert_allclose([co["a1"], co["a2"]], alpha, rtol=1e-12)
    na = T.numerical_average(d9_nc())
    scale = max(abs(co[k]) for k in ("p1", "p2", "p3"))
    for k in ("p0", "p1", "p2", "p3", "g1", "g2"):
        assert abs(co[k] - na[k]) < 1e-7 * scale, (k, co[k], na[k])
    ref = dict(w01=1.636964, w02=0.977419, a1=3.420258, a2=-0.152279, d11=-23.590262, d12=-5.747681, d21=5.747681,
               d22=-1.050301, p0=-6.645e-5, p1=-4.243e-4, g1=-4.757e-4, g2=3.968e-5, D1=-0.20790, D2=0.01502,
               h1=-9.89495, h2=0.10032, p2=7.523e-4, p3=-2.186e-3)
    for k, v in ref.items():
        assert co[k] == pytest.approx(v, rel=2e-3, abs=2e-6), k


def test_printed_standard_form_equals_variation_of_constants():
    nc = d9_nc()
    rng = np.random.default_rng(1)
    t, E1, t1, E2, t2 = (rng.uniform(0.1, 5.0, 7) for _ in range(5))
    np.testing.assert_allclose(T.standard_form_printed(t, E1, t1, E2, t2, nc),
                               T.standard_form_rates(t, E1, t1, E2, t2, nc), atol=1e-13)


@pytest.mark.parametrize("mapping", [0.0, 1.0])
def test_numerical_average_matches_corrected_coefficients(mapping):
    for p in (resolved(**D9, eps=0.001), resolved(mapping=mapping, eps=0.002), resolved(mapping=mapping, spare=2.0)):
        _, nc, _ = T.normal_coefficients(p)
        co, na = T.averaged(nc), T.numerical_average(nc)
        scale = max(abs(co[k]) for k in ("p1", "p2", "p3"))
        for k in ("p0", "p1", "p2", "p3", "g1", "g2"):
            assert abs(co[k] - na[k]) < 1e-7 * scale, (k, co[k], na[k])
        # the phase equation gives the same p2, p3 as the amplitude equation
        assert abs(na["p2_phase"] - na["p2"]) < 1e-7 * scale and abs(na["p3_phase"] - na["p3"]) < 1e-7 * scale
        # the literal alpha-version of p2, p3 is not what averaging gives
        p2l, p3l = T.p23_printed(nc)
        assert np.hypot(p2l - na["p2"], p3l - na["p3"]) > 0.05 * np.hypot(na["p2"], na["p3"])


def test_predicates_hand_checked():
    co = T.averaged(d9_nc())
    # inside the tongue (D.9): Delta_1 < 0 while p1 < 0 and p1 + p3 < 0
    preds, d1 = T.predicates(co, 0.0005)
    assert d1 < 0 and not preds["mode1_exact"][0] and not preds["mode1_paper"][0]
    hand = co["p1"] ** 2 + (co["p0"] + 0.0005) ** 2 - co["p2"] ** 2 - co["p3"] ** 2
    assert d1 == pytest.approx(hand, rel=1e-12)
    preds, d1 = T.predicates(co, 0.004)
    assert d1 > 0 and preds["mode1_exact"][0] and preds["mode1_paper"][0]
    # a point where the paper's p1 + p3 < 0 and the exact p1 < 0 disagree: p1 = -1, p3 = 2
    c2 = dict(p0=0.0, p1=-1.0, p2=0.0, p3=2.0, g1=-1.0, g2=0.0)
    preds, d1 = T.predicates(c2, 3.0)  # Delta_1 = 1 + 9 - 4 = 6 > 0
    assert d1 == pytest.approx(6.0)
    assert preds["mode1_exact"][0] and not preds["mode1_paper"][0]
    # mode 2: g1 < 0 with g2 = 0 -> exact stable, paper's g1 g2 > 0 fails
    assert preds["mode2_exact"][0] and not preds["mode2_paper"][0]
    # growth rate in the tongue centre: p1 + sqrt(p2^2 + p3^2 - p0^2) (D.9 table: +1.89e-3 at eps = 0)
    assert T.growth_rate(co["p0"], co["p1"], co["p2"], co["p3"], 0.0) == pytest.approx(1.89e-3, rel=5e-3)


def test_theory_evaluate_batched():
    p = resolved()
    n = 5
    pb = {k: np.broadcast_to(v, (n,) + np.shape(v)).copy() for k, v in p.items()}
    pb["eps"] = np.linspace(-0.003, 0.003, n)
    pb["spare"] = np.array([4.0, 3.0, 2.0, 1.0, 4.0])
    th = S.theory(pb)
    assert th.predicates["mode1_exact"].ok.shape == (n,)
    for i in range(n):
        pi = {k: v[i] for k, v in pb.items()}
        one = S.theory(pi)
        assert one.derived["growth_pred"] == pytest.approx(th.derived["growth_pred"][i], rel=1e-12)


# ---- models: closed form, SciPy references, linearisation ------------------------------------------


def test_mu0_reproduces_closed_form():
    """mu = 0 (no damping, c = 0): (1.3) reproduces (2.1) + (2.2) (amplitudes and phases)."""
    p = resolved(**D9, gain=0.0, nc_c=[0.0, 0.0], eps=0.01, E0=[0.05, 0.03], nc_f3=[0.4, -0.3],
                 Omega=[1.0, 2.0, 0.6])
    ts = np.linspace(0.0, 80.0, 9)
    ys, a, _ = integrate_jax(p, ts)
    nc = {k: np.asarray(v) for k, v in a["nc_pre"].items()}
    md = {k: np.asarray(v) for k, v in a["md_pre"].items()}
    f = T.forced_solution(ts, nc)
    e = T.free_solution(0.05, md["w01"] * ts, 0.03, md["w02"] * ts, md)
    y2, v2, y1, v1 = (fi + ei for fi, ei in zip(f, e))
    np.testing.assert_allclose(ys[:, 1], y1 + y2, atol=1e-8)
    np.testing.assert_allclose(ys[:, 2], nc["b1"] * y1 + nc["b2"] * y2, atol=1e-8)
    np.testing.assert_allclose(ys[:, 4], v1 + v2, atol=1e-8)
    # the forced solution satisfies (1.3) with mu = 0 (residual of the ODE)
    tt = np.linspace(0, 10, 50)
    fy2, fv2, fy1, fv1 = T.forced_solution(tt, nc)
    h = 1e-5
    acc = [(np.array(T.forced_solution(tt + h, nc)[i]) - np.array(T.forced_solution(tt - h, nc)[i])) / (2 * h) for i in (1, 3)]
    a2, a1 = T.normal_accel(tt, fy2, fv2, fy1, fv1, nc)
    np.testing.assert_allclose(acc[0], a2, atol=1e-7)
    np.testing.assert_allclose(acc[1], a1, atol=1e-7)
    # mode amplitudes recovered from the deviation
    E1, th1, E2, th2 = T.mode_amplitudes(*(ei for ei in e), md)
    np.testing.assert_allclose(E1, 0.05, atol=1e-12)
    np.testing.assert_allclose(E2, 0.03, atol=1e-12)


def np_two_channel(p, stage_switch=True):
    """Independent NumPy two-channel rhs of D.4 (theta, phi) for the first copy, from raw parameters."""
    geo = T.geometry(float(p["tet_yaw"]))
    I, H, Kp, Kd = p["I"], p["H"], p["Kp"], p["gain"] * p["Kd"]
    pre_slots = [i for i in range(4) if i != int(p["spare"]) - 1]
    post_slots = list(pre_slots)
    if int(p["fail"]) > 0:
        post_slots[pre_slots.index(int(p["fail"]) - 1)] = int(p["spare"]) - 1
    Om = np.array(p["Omega"], float)
    Om[1] = float(S.theory(p).derived["Omega2"])

    def coeffs(sl):
        u, w = geo["u"][sl], geo["w"][sl]
        return H[sl] @ u[:, 1], -(H[sl] @ u[:, 0]), -p["A"] * w[:, 1], -p["A"] * w[:, 2]

    cpre, cpost = coeffs(pre_slots), coeffs(post_slots)

    def f(t, y):
        d, dp, fy, fz = cpost if (stage_switch and t >= p["t_fail"]) else cpre
        thv, ph, thd, phd = y
        sn = np.sin(Om * t)
        thdd = (fy @ sn - Kp[1, 1] * thv - Kp[1, 2] * ph + dp * phd - Kd[1, 1] * thd - Kd[1, 2] * phd) / I[1]
        phdd = (fz @ sn - Kp[2, 1] * thv - Kp[2, 2] * ph - dp * thd - Kd[2, 1] * thd - Kd[2, 2] * phd - d * thd * ph) / I[2]
        return [thd, phd, thdd, phdd]

    return f


@pytest.mark.parametrize("over", [dict(), dict(spare=1.0, fail=3.0, t_fail=30.0, A=[0.3, 1.0, 0.5], tune=0.0)])
def test_two_channel_vs_scipy_and_normal_coordinates(over):
    p = resolved(model=1.0, **over)
    ts = np.array([0.0, 10.0, 25.0, 40.0, 60.0])
    ys, _, y0 = integrate_jax(p, ts)
    ref = solve_ivp(np_two_channel(p), (0, 60.0), y0[[1, 2, 4, 5]], method="DOP853", rtol=1e-11, atol=1e-13, t_eval=ts)
    np.testing.assert_allclose(ys[:, [1, 2, 4, 5]], ref.y.T, atol=1e-7)
    # model 0 with the consistent projection is the same system written in normal coordinates
    # (slot 1's harmonic is kept by the consistent mapping)
    ys0, _, _ = integrate_jax(dict(p, model=np.asarray(0.0), mapping=np.asarray(1.0)), ts)
    np.testing.assert_allclose(ys0, ys, atol=1e-8)


def np_full(p):
    """Independent NumPy full SGCMG rhs (one copy): angles (psi, theta, phi) 1-2-3, body rates, 4 gimbals."""
    geo = T.geometry(float(p["tet_yaw"]))
    g, u, w = geo["g"], geo["u"], geo["w"]
    I = p["I"]
    pre = [i for i in range(4) if i != int(p["spare"]) - 1]
    post = list(pre)
    if int(p["fail"]) > 0:
        post[pre.index(int(p["fail"]) - 1)] = int(p["spare"]) - 1
    Om = np.array(p["Omega"], float)
    Om[1] = float(S.theory(p).derived["Omega2"])
    Kp, Kd = p["Kp"], p["gain"] * p["Kd"]

    def gains(sl):
        Wm = w[sl].T
        return np.linalg.solve(Wm, Kp), np.linalg.solve(Wm, Kd)

    gpre, gpost = gains(pre), gains(post)

    def f(t, y):
        ang, om, nu = y[:3], y[3:6], y[6:10]
        sl, (Gk, GK) = (post, gpost) if t >= p["t_fail"] else (pre, gpre)
        ps, th_, ph = ang
        # Euler rates of the body 1-2-3 sequence, from R = Rx(psi) Ry(theta) Rz(phi)
        E = np.array([[np.cos(th_) * np.cos(ph), np.sin(ph), 0.0], [-np.cos(th_) * np.sin(ph), np.cos(ph), 0.0],
                      [np.sin(th_), 0.0, 1.0]])
        angd = np.linalg.solve(E, om)
        h = np.zeros(3)
        tau = np.zeros(3)
        nud = np.zeros(4)
        for j, i in enumerate(sl):
            ctrl = Gk[j] @ ang + GK[j] @ angd + p["A"][j] * np.sin(Om[j] * t)
            s = np.cos(nu[i]) * u[i] + np.sin(nu[i]) * w[i]
            h += p["H"][i] * s
            tau += ctrl * np.cross(g[i], s)
            nud[i] = ctrl / p["H"][i]
        omd = (-np.cross(om, I * om + h) - tau) / I
        return np.concatenate([angd, omd, nud])

    return f


@pytest.mark.parametrize("over", [dict(), dict(spare=2.0, fail=4.0, t_fail=20.0, A=[0.5, 2.0, 0.8], eps=0.01)])
def test_full_model_vs_scipy(over):
    p = resolved(model=2.0, E0=[0.05, 0.05], **over)
    ts = np.array([0.0, 7.0, 19.0, 33.0, 50.0])
    ys, _, y0 = integrate_jax(p, ts)
    ref = solve_ivp(np_full(p), (0, 50.0), y0[:10], method="DOP853", rtol=1e-11, atol=1e-13, t_eval=ts)
    np.testing.assert_allclose(ys[:, :10], ref.y.T, atol=1e-7)
    assert np.abs(ys[-1, 6:10]).max() > 1e-3  # gimbals actually moved


def test_full_model_linearisation_is_quasi_linear_12():
    """Jacobian of the full model at rest (A = 0) equals the three-axis linear part of (1.2)."""
    p = resolved(model=2.0, A=[0.0, 0.0, 0.0])
    a, _ = jrhs(p)
    J = np.asarray(jax.jacfwd(lambda y: S._rhs_one(0.0, y, a))(jnp.zeros(10)))
    geo = T.geometry(float(p["tet_yaw"]))
    sl = [0, 1, 2]
    h = p["H"][sl] @ geo["u"][sl]  # (-d', d, 0)
    I, Kp, Kd = p["I"], p["Kp"], p["gain"] * p["Kd"]
    # I x'' + Kp x + Kd x' + [x']_x h = 0 with x = (psi, theta, phi), omega ~ x' at rest
    hx = np.array([[0, -0.0, 0], [0, 0, 0], [0, 0, 0]], float)
    hx = np.array([[0.0, h[2], -h[1]], [-h[2], 0.0, h[0]], [h[1], -h[0], 0.0]])  # omega x h = -[h]x omega
    np.testing.assert_allclose(J[0:3, 3:6], np.eye(3), atol=1e-14)
    np.testing.assert_allclose(J[3:6, 0:3], -Kp / I[:, None], atol=1e-12)
    np.testing.assert_allclose(J[3:6, 3:6], (-Kd - hx) / I[:, None], atol=1e-12)
    # the (1.2) gyroscopic terms: -d phi' in x, -d' phi' in y, +d psi' + d' theta' in z
    d, dp = h[1], -h[0]
    np.testing.assert_allclose(hx, [[0, 0, -d], [0, 0, -dp], [d, dp, 0]], atol=1e-14)
    # gimbal rates: H nu' = Gk x (allocation), zero for the spare
    Gk = np.linalg.solve(geo["w"][sl].T, Kp)
    np.testing.assert_allclose(J[6:9, 0:3], Gk / p["H"][sl][:, None], atol=1e-12)
    np.testing.assert_allclose(J[9], 0.0)


def test_observables_and_invariants():
    p = resolved(model=1.0, delta=1e-4)
    a, f = jrhs(p)
    y0 = S.initial_state({k: jnp.asarray(v) for k, v in p.items()})
    obs = np.asarray(S.observe(0.0, y0, a))
    assert obs[0] == pytest.approx(1e-4, rel=1e-9) and obs[2] == pytest.approx(1e-4, rel=1e-9)
    assert obs[3] == pytest.approx(0.0, abs=1e-14)  # reference starts on (2.2)
    # without perturbation the two copies coincide for all time
    eq = S.equilibrium({k: jnp.asarray(v) for k, v in p.items()})
    np.testing.assert_allclose(eq[:10], eq[10:])
    np.testing.assert_allclose(np.asarray(y0[:10]), np.asarray(eq[:10]), atol=1e-15)
