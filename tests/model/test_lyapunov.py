"""Largest Lyapunov exponent from the tangent dynamics (stabjax.model.tangent) against known values.

References are independent of the code under test: the literature value for chaotic Lorenz-63,
and NumPy eigen-decompositions / SciPy DOP853 integrations for the bounds of the finite-time
estimate on an equilibrium and a limit cycle. Each tolerance is derived in its test.
"""
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax import Param, ParamSet, System
from stabjax.model.tangent import initial_tangent
from stabjax.run.sweep import run_spec

LORENZ = "examples/lorenz63/model.py:Lorenz63"


class Linear(System):
    """y' = A y with A's slow block non-normal: eigenvalues -0.3 +- 2i and -1."""
    name = "linear_test"
    params = ParamSet((Param("y0", 1.0, "initial y_0", kind="initial"),))
    state = (("y", (3,)),)
    observables = ("y0", "y1")
    observable_doc = ("y_0", "y_1")
    A = np.array([[-0.3, 4.0, 0.0], [-1.0, -0.3, 0.0], [0.0, 0.0, -1.0]])

    def initial_state(self, p):
        return jnp.stack([p["y0"], 0.5, 1.0])

    def rhs(self, t, y, p):
        return jnp.asarray(self.A) @ y

    def observe(self, t, y, p):
        return y[:2]


class VanDerPol(System):
    """x'' - mu (1 - x^2) x' + x = 0, mu = 1: one stable limit cycle."""
    name = "vdp_test"
    params = ParamSet((Param("mu", 1.0, "nonlinearity"), Param("x0", 2.0, "initial x", kind="initial")))
    state = (("x", ()), ("v", ()))
    observables = ("x", "v")
    observable_doc = ("x", "v")

    def initial_state(self, p):
        return jnp.stack([p["x0"], 0.0])

    def rhs(self, t, y, p):
        return jnp.stack([y[1], p["mu"] * (1 - y[0] ** 2) * y[1] - y[0]])

    def observe(self, t, y, p):
        return y


def _spec(system, t1, window, n=4, engine="auto", params=None, sample=None):
    return {"system": system, "params": params or {},
            "sample": {"n": n, "seed": 0, **(sample or {})},
            "integrate": {"t1": t1, "rtol": 1e-10, "atol": 1e-10, "n_checkpoints": 200, "engine": engine},
            "outcomes": {"rules": {"any": "lyapunov > -1e9"}, "window": window}}


def test_tangent_is_integrated_only_on_request():
    from stabjax.plan.spec import make_plan

    base = _spec(Linear, 10.0, 0.5, sample={"y0": {"dist": "uniform", "low": 0.5, "high": 1.0}})
    assert make_plan(base).lyapunov
    base["outcomes"] = {"rules": {"small": "abs(final(y0)) < 1"}}
    plan = make_plan(base)
    assert not plan.lyapunov and plan.integrated is plan.system
    base["outcomes"]["lyapunov"] = True
    assert make_plan(base).lyapunov
    # a template feature naming the exponent asks for it too
    base["outcomes"] = {"rules": {}, "templates": {"a": {"y0": 0.6}, "b": {"y0": 0.9}},
                        "features": ["max(y0)", "lyapunov"]}
    assert make_plan(base).lyapunov


@pytest.mark.parametrize("engine", ["native", pytest.param("fused", marks=pytest.mark.slow), "diffrax"])  # fused: the full suite's
def test_linear_equilibrium_exponent_every_engine(engine):
    """lambda_1 = max Re eig A = -0.3. In the slow block log|v| oscillates within ln kappa(V) of the
    exponential (V: A's eigenvectors), the fast direction dies as exp(-0.7 t_w): so over a window of
    length T_w the estimate is within ln kappa / T_w (+ solver error ~ 1e-9) of -0.3."""
    ds = run_spec(_spec(Linear, 100.0, 0.9, engine=engine,
                        sample={"y0": {"dist": "uniform", "low": 0.5, "high": 1.0}}))
    assert ds.attrs["engine"] == engine
    ev, vec = np.linalg.eig(Linear.A)
    lam1 = ev.real.max()
    bound = np.log(np.linalg.cond(vec)) / 90.0 + np.exp(-0.7 * 10.0)
    lam = ds["lyapunov"].values
    assert np.all(np.abs(lam - lam1) <= bound), (lam, lam1, bound)


def test_linear_exponent_matches_scipy_benettin():
    """The same window with Benettin's renormalised variational equation in SciPy DOP853: the two
    finite-time estimates of the same trajectory agree to the solver tolerance."""
    A = Linear.A
    v, total = initial_tangent(3), 0.0
    for k in range(100):  # renormalise every time unit; sum log-growth over [10, 100]
        v = solve_ivp(lambda t, w: A @ w, (k, k + 1.0), v, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        g = np.linalg.norm(v)
        v /= g
        total += np.log(g) if k >= 10 else 0.0
    ref = total / 90.0
    ds = run_spec(_spec(Linear, 100.0, 0.9, n=2, sample={"y0": {"dist": "uniform", "low": 0.5, "high": 1.0}}))
    np.testing.assert_allclose(ds["lyapunov"].values, ref, atol=1e-7)


def test_stable_fixed_point_lorenz_rho20():
    """Lorenz rho = 20 near C+: lambda_1 = max Re eig J(C+) = -0.155 (eigenvalues of the analytic
    Jacobian by NumPy); bound ln kappa(V) / T_w as for the linear system (the start is 0.1 from C+,
    the linearisation error decays with the state)."""
    s, r, b = 10.0, 20.0, 8.0 / 3.0
    q = np.sqrt(b * (r - 1))
    J = np.array([[-s, s, 0], [1, -1, -q], [q, q, -b]])
    ev, vec = np.linalg.eig(J)
    lam1 = ev.real.max()
    assert abs(lam1 - (-0.155)) < 1e-3
    ds = run_spec(_spec(LORENZ, 200.0, 0.5, n=3, params={"r": r, "y0": q, "z0": r - 1},
                        sample={"x0": {"dist": "uniform", "low": q - 0.1, "high": q + 0.1}}))
    bound = np.log(np.linalg.cond(vec)) / 100.0
    lam = ds["lyapunov"].values
    assert np.all(np.abs(lam - lam1) <= bound), (lam, lam1, bound)


def test_limit_cycle_exponent_is_zero():
    """On an autonomous limit cycle the tangent aligns with the flow f, so the estimate is
    ln(|f(x(t1))| / |f(x(t_w))|) / T_w: within ln(max|f| / min|f|) / T_w of 0 (the cycle's |f| range
    from a SciPy DOP853 integration), plus the transverse part, dead as exp(-1.06 t_w) (Floquet)."""
    mu = 1.0
    f = lambda t, y: [y[1], mu * (1 - y[0] ** 2) * y[1] - y[0]]
    sol = solve_ivp(f, (0, 200.0), [2.0, 0.0], method="DOP853", rtol=1e-10, atol=1e-12, t_eval=np.linspace(150, 200, 20001))
    speed = np.linalg.norm(np.array([f(0, y) for y in sol.y.T]), axis=1)
    T_w = 150.0
    bound = np.log(speed.max() / speed.min()) / T_w
    ds = run_spec(_spec(VanDerPol, 200.0, 0.75, n=6, sample={"x0": {"dist": "uniform", "low": 0.5, "high": 3.0}}))
    lam = ds["lyapunov"].values
    assert np.all(np.abs(lam) <= bound), (lam, bound)
    assert bound < 0.03  # the check is meaningful: far below a chaotic exponent


def test_lorenz63_chaotic_exponent():
    """sigma 10, rho 28, beta 8/3: lambda_1 = 0.9056 (Sprott; a QR run gives 0.9050). Over a window of
    T_w = 270 the finite-time estimates of different starts scatter (measured 0.009 at T_w = 540);
    the mean of n estimates must lie within 4 of their own standard errors (s / sqrt(n)) plus the
    literature values' spread (0.0006) of the asymptotic value."""
    ds = run_spec(_spec(LORENZ, 300.0, 0.9, n=8, params={"r": 28.0},
                        sample={"x0": {"dist": "uniform", "low": -10.0, "high": 10.0}}))
    lam = ds["lyapunov"].values
    se = lam.std(ddof=1) / np.sqrt(lam.size)
    assert abs(lam.mean() - 0.9056) <= 4 * se + 0.0006, (lam.mean(), se)
    assert lam.min() > 0.5  # every start on the attractor is chaotic


def test_rule_on_the_exponent_separates_chaos_from_rest():
    """Lorenz-63 at r = 24.4 with rules only (no coordinates): the exponent alone tells the chaotic
    attractor (lambda ~ 0.8 over T_w = 500) from the stable foci C+- (lambda = -0.0102, their leading
    eigenvalue; test_stable_fixed_point_lorenz_rho20 shows the estimate's bound). Independent check:
    the window spread of x, which is O(10) on the attractor and ~0 at C+-."""
    ds = run_spec({"system": LORENZ, "sample": {"n": 60, "seed": 4,
                                                "x0": {"dist": "uniform", "low": -20.0, "high": 20.0},
                                                "y0": {"dist": "uniform", "low": -25.0, "high": 25.0},
                                                "z0": {"dist": "uniform", "low": 0.0, "high": 45.0}},
                   "integrate": {"t1": 2000.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 2000},
                   "outcomes": {"rules": {"chaos": "lyapunov > 0.1", "rest": "lyapunov < 0"}, "window": 0.25}})
    code = ds["outcome"].values
    std_x = ds["feat_std"].sel(observable="x").values
    assert set(code) <= {0, 1} and (code == 0).any() and (code == 1).any()
    assert np.all(std_x[code == 0] > 1.0) and np.all(std_x[code == 1] < 1e-3)
