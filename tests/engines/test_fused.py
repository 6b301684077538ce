"""The fused engine (stabjax.engines.fused) against diffrax, an independent SciPy reference and the
diffrax engine path: final states, verdicts and summaries, refill, devices, constant folding,
failures, the lane-wise evaluator on every registered system, and the vectorised math."""
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax.fold import verdict as V
from stabjax.fold.status import MAX_STEPS as STATUS_MAX_STEPS
from stabjax import engines
from stabjax.engines import diffrax_engine, lanes, vmath
from stabjax.engines import fused as fast
from stabjax.engines.base import Unsupported
from stabjax.config import IntegrateConfig
from stabjax.engines.simulate import batch_params, solve_batch
from stabjax.model.registry import get_system, list_systems

from references import monoaxial_rhs
from tiny_systems import DECAY_CLASSIFY

SYS = get_system("monoaxial")
R = np.ones(3) / math.sqrt(3)
ALPHAS = np.linspace(0.3, 1.0, 8)
# rtol 1e-10 so that three different integrators agree to well below 1e-6 at t1
ICFG = IntegrateConfig(t1=800.0, rtol=1e-10, atol=1e-12, n_checkpoints=200)


def batch():
    p = batch_params(SYS, None, len(ALPHAS))
    p["alpha"] = ALPHAS.copy()
    p["w0"][1] = [0.5, -1.0, 2.0]  # a couple of other initial conditions, so w0 is lane-varying
    p["w0"][6] = [-2.0, 0.3, 0.1]
    return p


@pytest.fixture(scope="module")
def fused():
    # 8 trajectories over 2 lanes (per device): most lanes are refilled from the queue
    return fast.solve(SYS, batch(), ICFG, SYS.verdict, lanes=2, with_state=True)


@pytest.fixture(scope="module")
def diffrax_final():
    p = {k: jnp.asarray(v) for k, v in batch().items()}

    def one(q):
        args = SYS.prepare(q)
        sol = diffrax.diffeqsolve(diffrax.ODETerm(SYS.rhs), diffrax.Tsit5(), 0.0, ICFG.t1, None, SYS.initial_state(q),
                                  args=args, saveat=diffrax.SaveAt(t1=True),
                                  stepsize_controller=diffrax.PIDController(rtol=ICFG.rtol, atol=ICFG.atol),
                                  max_steps=1_000_000)
        return sol.ys[-1]

    return np.asarray(jax.jit(jax.vmap(one))(p))


def test_final_states_match_diffrax(fused, diffrax_final):
    assert np.all(fused["solver_status"] == 0)
    np.testing.assert_allclose(fused["state_t1"], diffrax_final, atol=1e-6, rtol=0)


@pytest.mark.parametrize("i", [0, 2, 5])
def test_final_states_match_scipy_dop853(fused, i):
    p = batch()
    y0 = np.concatenate([p["w0"][i], p["s0"][i]])
    args = (p["J"][i], p["D"][i], p["a"][i], p["mu"][i], p["b"][i], p["sigma"][i], p["alpha"][i], p["omega0"][i], p["r"][i])
    sol = solve_ivp(monoaxial_rhs, (0.0, ICFG.t1), y0, method="DOP853", rtol=1e-11, atol=1e-13, args=args)
    assert sol.success
    np.testing.assert_allclose(fused["state_t1"][i], sol.y[:, -1], atol=1e-6, rtol=0)


def test_verdicts_and_summaries_match_diffrax_engine(fused):
    ref = solve_batch(SYS, batch(), IntegrateConfig(**{**ICFG.__dict__, "engine": "diffrax"}))
    np.testing.assert_array_equal(fused["verdict"], ref["verdict"])
    for k in ("n_excursions", "n_flips"):
        np.testing.assert_array_equal(fused[k], ref[k], err_msg=k)
    for k in ("t_settle", "t_first_flip"):  # checkpoint times: equal or both NaN
        np.testing.assert_array_equal(fused[k], ref[k], err_msg=k)
    for k in ("error_t1", "error_max_late", "error_max_settled", "size_max", "peak_last"):
        np.testing.assert_allclose(fused[k], ref[k], atol=1e-6, rtol=1e-6, err_msg=k)
    # same method and controller; the fused engine only adds steps that end on checkpoints
    assert np.all(fused["n_steps"] >= ref["n_steps"])
    assert np.all(fused["n_steps"] <= 1.6 * ref["n_steps"] + 50)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: folding on the native engine (test_native.py's threads/width/static-folding test) and the folded fused engine against diffrax (test_final_states_match_diffrax)
def test_constant_folding_single_device_and_no_refill_change_nothing(fused):
    # every parameter lane-varying, one device, one lane per trajectory
    other = fast.solve(SYS, batch(), ICFG, SYS.verdict, lanes=8, n_devices=1, static=[], with_state=True)
    np.testing.assert_array_equal(other["verdict"], fused["verdict"])
    np.testing.assert_allclose(other["state_t1"], fused["state_t1"], atol=1e-8, rtol=0)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the fused engine's failures in test_reliability.py, the same test on the native engine
def test_failures_are_reported_not_raised():
    p = batch_params(SYS, None, 3)
    p["b"][1] = np.nan  # right-hand side NaN from t = 0: the solver can never accept a step
    p["w0"][2] = [300.0, -200.0, 100.0]  # needs far more than max_steps
    icfg = IntegrateConfig(t1=20.0, rtol=1e-8, atol=1e-10, n_checkpoints=16, max_steps=400)
    out = fast.solve(SYS, p, icfg, SYS.verdict, lanes=2, n_devices=1)
    assert out["verdict"][0, -1] != V.FAILED and out["solver_status"][0] == 0
    assert out["verdict"][1, -1] == V.FAILED and out["solver_status"][1] == STATUS_MAX_STEPS
    assert out["verdict"][2, -1] == V.FAILED and out["solver_status"][2] == STATUS_MAX_STEPS
    assert out["n_steps"][2] + out["n_rejected"][2] == 400


def test_engine_dispatch_and_fallback(monkeypatch):
    calls = []
    monkeypatch.setattr(diffrax_engine, "solve", lambda s, p, i, v: calls.append(s.name) or {"verdict": np.zeros(1)})
    # a system with its own classify() (as the gyrodyne): a tiny one, whose model check (run at every
    # solve_batch) costs milliseconds instead of the gyrodyne's seconds of eager JAX
    custom = DECAY_CLASSIFY
    assert custom.classify is not None
    with pytest.raises(Unsupported):
        fast.solve(custom, batch_params(custom, None, 1), ICFG, custom.verdict)
    solve_batch(custom, batch_params(custom, None, 1), ICFG.replace(engine="fused"))  # falls back to diffrax
    solve_batch(SYS, batch_params(SYS, None, 1), IntegrateConfig(engine="diffrax", t1=10.0))
    assert calls == [custom.name, SYS.name]
    with pytest.raises(Unsupported):
        fast.solve(SYS, batch_params(SYS, None, 1), IntegrateConfig(solver="dopri5"), SYS.verdict)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: a memory guard of the diffrax engine, ~30 s of compiles
def test_diffrax_path_subchunks_large_batches(monkeypatch):
    """A fused-sized chunk on the diffrax engine is split (its checkpoints would not fit in memory)."""
    p = batch_params(SYS, None, 7)
    p["alpha"] = np.linspace(0.4, 1.0, 7)
    icfg = IntegrateConfig(t1=5.0, n_checkpoints=16, engine="diffrax")
    whole = diffrax_engine.solve(SYS, p, icfg, SYS.verdict)
    monkeypatch.setattr(diffrax_engine, "CHUNK", 3)
    split = diffrax_engine.solve(SYS, p, icfg, SYS.verdict)
    # XLA:CPU gives bit-identical results for any batch size; on a GPU another batch shape may
    # change the rounding of a reduction (seen on an H100: 1.2e-14 relative), nothing more
    exact = jax.default_backend() == "cpu"
    for k in whole:
        if exact or not np.issubdtype(whole[k].dtype, np.floating):
            np.testing.assert_array_equal(split[k], whole[k], err_msg=k)
        else:
            np.testing.assert_allclose(split[k], whole[k], rtol=1e-12, atol=0, err_msg=k)


def test_engine_config_validation():
    """Engine choice and settings are checked by the engines' declarations (stabjax.engines.SETTINGS):
    fails if a bad name or value passes, or a setting of an engine the choice may fall back to is refused."""
    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError, match="engine"):
        engines.integrate_config({"engine": "warp"})
    with pytest.raises(ValidationError, match="lanes"):
        engines.integrate_config({"lanes": -1})
    assert engines.integrate_config({"engine": "diffrax", "lanes": 64}).settings == {"lanes": 64}
    assert engines.integrate_config({}, {"lanes": 64}).settings["lanes"] == 64
    assert engines.get("fused").setting(engines.integrate_config({}, {"lanes": 64}), "lanes") == 64
    assert engines.get("fused").setting(IntegrateConfig(), "lanes") == 0  # the declared default
    with pytest.raises(ValidationError, match="lanes"):  # a config built in Python is checked when resolved
        engines.resolve(SYS, IntegrateConfig(settings={"lanes": -1}))


# the gyrodyne (its own classify(): run by the diffrax engine) in the full suite (CI's 10 minutes)
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "gyrodyne" else n
                                  for n in list_systems(available_only=True)])
def test_lanewise_evaluation_equals_vmap(name):
    """The lane-wise evaluator (slices/dots/pow as per-element ops) computes what vmap computes."""
    S = get_system(name)
    L = 5
    rng = np.random.default_rng(0)
    p = {k: jnp.asarray(v) for k, v in batch_params(S, None, L).items()}
    args = jax.vmap(S.prepare, out_axes=-1)(p)
    y = jax.vmap(S.initial_state, out_axes=-1)(p)
    y = y + 0.1 * jnp.asarray(rng.normal(size=y.shape))
    t = jnp.linspace(0.3, 50.0, L)
    ex = (jax.ShapeDtypeStruct((), jnp.float64), jax.ShapeDtypeStruct(y.shape[:-1], jnp.float64),
          jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape[:-1], a.dtype), args))
    for fn in (S.rhs, S.observe):
        ref = jax.vmap(fn, in_axes=(0, -1, -1), out_axes=-1)(t, y, args)
        got = lanes.LaneFn(fn, *ex)(L, t, y, args)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-13 * float(jnp.max(jnp.abs(ref))))


def test_fast_log_matches_libm():
    rng = np.random.default_rng(1)
    x = np.concatenate([10 ** rng.uniform(-300, 300, 20000), rng.uniform(0.5, 2.0, 20000),
                        [1.0, 2.0, 0.5, np.finfo(float).max, 2.2250738585072014e-308]])
    fast_log = jax.jit(vmath.fast_log)  # jitted, as the engine runs it
    got = np.asarray(fast_log(jnp.asarray(x)))
    ref = np.log(x)
    assert np.max(np.abs(got - ref) / np.spacing(np.abs(ref) + 1e-300)) <= 2.0  # ulps
    special = np.asarray(fast_log(jnp.asarray([0.0, -1.0, np.inf, np.nan])))
    assert special[0] == -np.inf and np.isnan(special[1]) and special[2] == np.inf and np.isnan(special[3])


def test_fast_sin_cos_match_libm_including_huge_arguments():
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-10, 10, 20000), rng.uniform(-1e5, 1e5, 20000), rng.uniform(-1e8, 1e8, 5000),
                        np.arange(-40, 41) * np.pi / 2])
    for name, ref in (("sin", np.sin), ("cos", np.cos)):
        got = np.asarray(jax.jit(lambda v: lanes.sincos(name, v))(jnp.asarray(x)))
        np.testing.assert_allclose(got, ref(x), atol=2.3e-16, rtol=0, err_msg=name)
        huge = np.array([3e9, -1e15, 1e300, 0.5])  # beyond the fast reduction: exact path for the batch
        got = np.asarray(jax.jit(lambda v: lanes.sincos(name, v))(jnp.asarray(huge)))
        np.testing.assert_allclose(got, ref(huge), atol=1e-15, rtol=0, err_msg=name)
    assert np.isnan(np.asarray(lanes.sincos("cos", jnp.asarray([np.inf, np.nan])))).all()


def test_lanewise_pow_special_cases():
    vals = [0.0, -0.0, 1.0, -1.0, 2.0, -2.0, 0.5, -0.5, 3.0, -3.0, np.inf, -np.inf, np.nan, 1e-300, 1e300]
    xs, ys = np.meshgrid(vals, vals)
    xs, ys = xs.ravel(), ys.ravel()
    # every (x, y) pair in its own lane of one jitted evaluation (the rule is elementwise: a lane sees only its
    # own x and y), one XLA compile instead of eager operations for each of the 225 pairs
    pow_lanes = jax.jit(lambda x, y: lanes.Lanes(x.shape[0]).pow(x, y, [np.float64, np.float64]))
    got = np.asarray(pow_lanes(jnp.asarray(xs), jnp.asarray(ys)))
    ref = np.asarray(jnp.power(jnp.asarray(xs), jnp.asarray(ys)))  # XLA's pow: what the vmap path computes
    finite = np.isfinite(ref)
    # documented accuracy of exp(y ln|x|): (4 + 2 |y ln x|) ulp
    with np.errstate(all="ignore"):
        bound = np.nan_to_num((4 + 2 * np.abs(ys * np.log(np.abs(xs)))) * np.finfo(float).eps * np.abs(ref), nan=0.0)
    assert np.all(np.abs(got[finite] - ref[finite]) <= bound[finite])
    # infinities and NaNs where XLA has them (the sign of inf for odd negative powers of -0.0 aside)
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    assert np.array_equal(np.isinf(got), np.isinf(ref))
