"""Early stop at a stable fixed point (stabjax.fold.stops), on every engine.

References are independent of the code under test: NumPy's eigenvalues and inverse for the
Faddeev-LeVerrier / Routh-Hurwitz test; the pendulum's equilibrium in closed form
(theta* = asin(T/K), omega* = 0); and, per start, the same sweep with ``early_stop = false``.
Tolerances come from the stop criterion itself: the stopped state is within Newton's step
delta = J^-1 f of the equilibrium, and delta is stopped at RMS_i(delta_i / (atol + rtol |x_i|)) <= DISTANCE_TOL,
so each component is within sqrt(n) DISTANCE_TOL (atol + rtol |x_i|) (first order; at this distance
the second order is ~1e-12).
"""
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stabjax import Param, ParamSet, System
from stabjax.fold import stops
from stabjax.errors import ValidationError
from stabjax.model.outcomes import Outcomes
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_plan

EXAMPLES = Path(__file__).resolve().parents[2] / "stabjax" / "examples"
ENGINES = ("diffrax", "fused", "native")


# ---- the linear algebra against NumPy ---------------------------------------------------------------------

def test_routh_hurwitz_and_faddeev_leverrier_against_numpy():
    rng = np.random.default_rng(7)
    checked = 0
    for n in range(1, 7):
        for _ in range(150):
            A = rng.normal(size=(n, n)) * rng.choice([0.2, 1.0, 5.0]) - rng.uniform(0, 2) * np.eye(n)
            ev = np.linalg.eigvals(A)
            if abs(ev.real).min() < 1e-6 * max(1.0, abs(ev).max()):
                continue  # an eigenvalue on the axis to rounding: either answer is right
            a, M = stops.charpoly_adjugate(jnp.asarray(A))
            np.testing.assert_allclose(np.asarray(a), np.poly(A)[1:], rtol=1e-9, atol=1e-9 * np.abs(np.poly(A)).max())
            assert bool(stops.hurwitz(a)) == bool(ev.real.max() < 0), (A, ev)
            if abs(np.linalg.det(A)) > 1e-2:
                inv = -np.asarray(M) / float(a[-1])
                np.testing.assert_allclose(inv, np.linalg.inv(A), atol=1e-9 * np.abs(np.linalg.inv(A)).max())
            checked += 1
    assert checked > 800


def test_hurwitz_refuses_the_imaginary_axis():
    # lambda^2 + 1 (a centre), lambda^2 (double zero), lambda (lambda + 1): never "stable"
    for a in ([0.0, 1.0], [0.0, 0.0], [1.0, 0.0]):
        assert not bool(stops.hurwitz(jnp.asarray(a)))
    assert bool(stops.hurwitz(jnp.asarray([3.0, 3.0, 1.0])))  # (lambda + 1)^3


# ---- small models ---------------------------------------------------------------------------------------------

class Saddle(System):
    """x' = x, y' = -y from (0, y0): the trajectory runs INTO the saddle at the origin along its
    stable manifold (|f| -> 0), which must never count as a stable fixed point."""
    name = "saddle_test"
    params = ParamSet((Param("y0", 1.0, "start", kind="initial"),))
    state = (("x", ()), ("y", ()))
    observables = ("x", "y")
    observable_doc = ("x", "y")
    outcomes = Outcomes(rules={"origin": "abs(mean(y)) < 1e-3"})

    def initial_state(self, p):
        return jnp.stack([0.0 * p["y0"], p["y0"]])

    def rhs(self, t, y, p):
        return jnp.stack([y[0], -y[1]])

    def observe(self, t, y, p):
        return y


class Forced(System):
    """x' = -x + eps cos(t): with eps = 0 the same decay as an autonomous model, but the rhs reads t."""
    name = "forced_test"
    params = ParamSet((Param("x0", 1.0, "start", kind="initial"), Param("eps", 0.0, "forcing")))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    outcomes = Outcomes(rules={"rest": "abs(mean(x)) < 1e-3"})

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, p):
        return jnp.stack([-y[0] + p["eps"] * jnp.cos(t)])

    def observe(self, t, y, p):
        return y


def _spec(system, **integ):
    return {"system": system, "name": "es", "grid": {"y0" if system is Saddle else "x0": [0.5, 1.0, 2.0]},
            "integrate": {"t1": 60.0, "n_checkpoints": 200, **integ}}


def test_autonomy_is_read_from_the_jaxpr():
    assert stops.is_autonomous(Saddle())
    assert not stops.is_autonomous(Forced())
    pend = make_plan(load_spec(EXAMPLES / "pendulum" / "spec.toml"))
    assert stops.is_autonomous(pend.system) and pend.icfg.early_stop is True
    duff = make_plan(load_spec(EXAMPLES / "duffing" / "spec.toml"))
    assert not stops.is_autonomous(duff.system) and duff.icfg.early_stop is False


@pytest.mark.parametrize("engine", ENGINES)
def test_a_saddle_never_stops(engine):
    plan = make_plan(_spec(Saddle, engine=engine, early_stop=True))
    assert stops.active(plan.integrated, plan.icfg)
    ds = run_plan(plan)
    assert (ds.stop_reason.values == stops.STOP_NONE).all()
    np.testing.assert_array_equal(ds.stopped_at.values, 60.0)


@pytest.mark.parametrize("engine", ENGINES)
def test_a_non_autonomous_model_never_stops(engine):
    plan = make_plan(_spec(Forced, engine=engine, early_stop=True))
    assert not stops.active(plan.integrated, plan.icfg)
    ds = run_plan(plan)
    assert (ds.stop_reason.values == stops.STOP_NONE).all()
    assert (ds.outcome.values == 0).all()  # it does come to rest: only the stop is off


def test_the_predicate_at_equilibria_of_the_pendulum():
    plan = make_plan(load_spec(EXAMPLES / "pendulum" / "spec.toml"))
    s = plan.system
    a = s.prepare({k: jnp.asarray(v) for k, v in s.params.resolve(None).items()})
    th = np.arcsin(0.5)
    yes = stops.at_fixed_point(s.rhs, 0.0, jnp.asarray([th + 1e-7, 1e-7]), a, 1e-8, 1e-8)
    far = stops.at_fixed_point(s.rhs, 0.0, jnp.asarray([th + 1e-4, 0.0]), a, 1e-8, 1e-8)
    saddle = stops.at_fixed_point(s.rhs, 0.0, jnp.asarray([np.pi - th, 0.0]), a, 1e-8, 1e-8)
    assert bool(yes) and not bool(far) and not bool(saddle)


# ---- the examples: outcomes unchanged, per start, on every engine ------------------------------------------------

@pytest.fixture(scope="module")
def pendulum_runs():
    spec = load_spec(EXAMPLES / "pendulum" / "spec.toml")
    # fewer starts and checkpoints than the shipped spec (CI time); a horizon long enough for the
    # slowest rest-point approach (e^{-0.05 t}) to reach the solver tolerance
    spec["sample"]["n"] = 24
    spec["integrate"] = {**spec["integrate"], "t1": 700.0, "n_checkpoints": 1400}
    out = {}
    for engine in ENGINES:
        for es in (False, True):
            s = dict(spec, integrate={**spec["integrate"], "engine": engine, "early_stop": es})
            plan = make_plan(s)
            out[engine, es] = (plan, run_plan(plan))
    return out


@pytest.mark.parametrize("engine", ENGINES)
def test_early_stop_never_changes_an_outcome(pendulum_runs, engine):
    plan, off = pendulum_runs[engine, False]
    _, on = pendulum_runs[engine, True]
    assert on.attrs["engine"] == engine
    np.testing.assert_array_equal(on.outcome.values, off.outcome.values)
    assert (off.stop_reason.values == stops.STOP_NONE).all()
    names = str(on.outcome.attrs["flag_meanings"]).split()
    rest = on.outcome.values == names.index("fixed_point")
    stopped = on.stop_reason.values == stops.STOP_FIXED_POINT
    assert stopped.sum() >= 3  # starts that settle stop before t1 ...
    assert (on.stopped_at.values[stopped] < plan.icfg.t1).all()
    assert not (stopped & ~rest).any()  # ... and only those
    assert on.n_steps.values[stopped].sum() < off.n_steps.values[stopped].sum()


@pytest.mark.parametrize("engine", ENGINES)
def test_features_after_a_stop_are_those_of_the_equilibrium(pendulum_runs, engine):
    """Against SciPy (DOP853, rtol 1e-11) run to t1 from the same start: its rest angle is
    theta* + 2 pi k (k: turns before capture), which sets the scale atol + rtol |theta| of the bound."""
    from scipy.integrate import solve_ivp

    plan, on = pendulum_runs[engine, True]
    stopped = np.where(on.stop_reason.values == stops.STOP_FIXED_POINT)[0]
    icfg = plan.icfg
    p = plan.system.params.resolve(None)
    for i in stopped:
        y0 = [float(on.theta0_sample[i]), float(on.omega0_sample[i])]
        sol = solve_ivp(lambda t, y: [y[1], -p["alpha"] * y[1] + p["T"] - p["K"] * np.sin(y[0])],
                        (icfg.t0, icfg.t1), y0, method="DOP853", rtol=1e-11, atol=1e-11)
        th, om = sol.y[:, -1]
        assert abs(np.sin(th) - 0.5) < 1e-8 and abs(om) < 1e-8  # SciPy is at the equilibrium
        ref = np.array([om, np.sin(th)])
        # omega; sin(theta) (Lipschitz 1 in theta); the SciPy end state's own error ~1e-8 added
        tol = np.sqrt(2) * stops.DISTANCE_TOL * (icfg.atol + icfg.rtol * np.abs([0.0, th])) + 1e-8
        mean = on.feat_mean.values[i]
        assert (np.abs(mean - ref) <= tol).all(), (np.abs(mean - ref), tol)
        for k in ("feat_min", "feat_max", "feat_final"):
            np.testing.assert_allclose(on[k].values[i], mean, rtol=0, atol=1e-15)
    before = on.stopped_at.values[stopped] < icfg.t1 - 0.05 * (icfg.t1 - icfg.t0)  # stopped before the window
    assert before.any()
    # the fold's variance is sum(x^2)/n - mean^2: its rounding leaves a std of ~sqrt(eps) |mean|, no more
    std, mean = on.feat_std.values[stopped][before], on.feat_mean.values[stopped][before]
    assert (std <= 4 * np.sqrt(np.finfo(float).eps) * np.abs(mean) + 1e-15).all(), std


# ---- the spec ---------------------------------------------------------------------------------------------------

def test_spec_validation():
    with pytest.raises(ValidationError, match="integrate.early_stop"):
        make_plan(_spec(Saddle, early_stop="yes"))
    with pytest.raises(ValidationError, match="integrate.early_stop"):
        make_plan(_spec(Saddle, early_stop=1))
    # the attitude systems: their verdicts read decay laws up to t1
    assert make_plan({"system": "monoaxial", "integrate": {"t1": 100.0}}).icfg.early_stop is False
    with pytest.raises(ValidationError, match="integrate.early_stop"):
        make_plan({"system": "monoaxial", "integrate": {"t1": 100.0, "early_stop": True}})
    assert make_plan(_spec(Saddle, early_stop=False)).icfg.early_stop is False
    assert make_plan(_spec(Saddle)).icfg.early_stop is True


def test_lorenz63_at_rest_stops_without_moving_its_features():
    """Lorenz-63 at r = 24.4 (example): starts next to C+ come to rest slowly (Re lambda = -0.0102)
    and the numerical solution hovers 240-570 tolerance units away; with the stop the features sit
    within DISTANCE_TOL units, so both runs' means agree within twice that (per component, RMS bound
    times sqrt(n)). Native engine (the examples' default), rule outcomes instead of discovery (two starts)."""
    spec = load_spec(EXAMPLES / "lorenz63" / "spec.toml")
    c = np.sqrt(8.0 / 3.0 * 23.4)
    spec.pop("sample")
    spec["grid"] = {"x0": [c + 1.0, c + 0.5]}
    spec["params"] = {"y0": c, "z0": 23.4}
    spec["outcomes"] = {"rules": {"rest_plus": "std(x) < 1e-3 and mean(x) > 0",
                                  "rest_minus": "std(x) < 1e-3 and mean(x) < 0"}}
    runs = {}
    for es in (False, True):
        plan = make_plan(dict(spec, integrate={**spec["integrate"], "early_stop": es}))
        runs[es] = (plan, run_plan(plan))
    plan, on = runs[True]
    off = runs[False][1]
    np.testing.assert_array_equal(on.outcome.values, off.outcome.values)
    names = str(on.outcome.attrs["flag_meanings"]).split()
    assert [names[i] for i in on.outcome.values] == ["rest_plus", "rest_plus"]
    assert (on.stop_reason.values == stops.STOP_FIXED_POINT).all()
    assert (on.stopped_at.values < plan.icfg.t1).all()
    eq = np.abs(off.feat_mean.values)  # |x|, |y|, |z| at rest (observables: the state)
    tol = 2 * np.sqrt(3) * stops.DISTANCE_TOL * (plan.icfg.atol + plan.icfg.rtol * eq)
    assert (np.abs(on.feat_mean.values - off.feat_mean.values) <= tol).all()
