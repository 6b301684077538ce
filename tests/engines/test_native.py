"""The native engine (stabjax.engines.native: jaxprs translated to C, SIMD Tsit5 loop) against SciPy
DOP853, diffrax and the diffrax engine path; its C translation of every registered model against
JAX; failures, interruption, fallbacks and the sweep runner's use of it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax import engines
from stabjax.fold import verdict as V
from stabjax.config import IntegrateConfig
from stabjax.engines.simulate import batch_params, solve_batch
from stabjax.engines import native
from stabjax.engines.lanes import NoRule
from stabjax.engines.native import emit
from stabjax.model.registry import get_system, list_systems

from references import monoaxial_rhs
from tiny_systems import DECAY

pytestmark = pytest.mark.skipif(not native.available(), reason="no working C compiler")

SYS = get_system("monoaxial")
ALPHAS = np.linspace(0.3, 1.0, 40)
ICFG = IntegrateConfig(t1=800.0, rtol=1e-10, atol=1e-12, n_checkpoints=200)


def batch(n=len(ALPHAS)):
    p = batch_params(SYS, None, n)
    p["alpha"] = np.linspace(0.3, 1.0, n)
    p["w0"][1] = [0.5, -1.0, 2.0]  # other initial conditions, so w0 is a dynamic (lane-varying) input
    p["w0"][min(6, n - 1)] = [-2.0, 0.3, 0.1]
    return p


@pytest.fixture(scope="module")
def nat():
    # 40 trajectories through blocks of 16 lanes on 2 threads: lanes are refilled from the shared queue
    return native.solve(SYS, batch(), ICFG, SYS.verdict, with_state=True, threads=2)


@pytest.mark.parametrize("i", [0, 1, 6, 13, 39])
def test_final_states_match_scipy_dop853(nat, i):
    p = batch()
    y0 = np.concatenate([p["w0"][i], p["s0"][i]])
    args = (p["J"][i], p["D"][i], p["a"][i], p["mu"][i], p["b"][i], p["sigma"][i], p["alpha"][i], p["omega0"][i], p["r"][i])
    sol = solve_ivp(monoaxial_rhs, (0.0, ICFG.t1), y0, method="DOP853", rtol=1e-11, atol=1e-13, args=args)
    assert sol.success and nat["solver_status"][i] == 0
    np.testing.assert_allclose(nat["state_t1"][i], sol.y[:, -1], atol=1e-6, rtol=0)


def test_verdicts_summaries_and_steps_match_diffrax_engine(nat):
    """Also the multi-horizon classifier of tests/engines/test_verdict_engines.py (the same fold in the C
    engine and in the diffrax path's scan): identical verdicts at every horizon, on a batch whose outcomes
    differ between trajectories and between horizons (measured: 4 outcomes, 37 of 40 trajectories change)."""
    ref = solve_batch(SYS, batch(), IntegrateConfig(**{**ICFG.__dict__, "engine": "diffrax"}))
    v = ref["verdict"]
    assert v.shape == (len(ALPHAS), len(V.bind(SYS.verdict, ICFG.t0, ICFG.t1).horizons)) == nat["verdict"].shape
    assert v.shape[1] > 1 and len(np.unique(v)) >= 2 and np.any(v[:, 0] != v[:, -1])  # several outcomes and horizons
    np.testing.assert_array_equal(nat["verdict"], ref["verdict"])
    for k in ("n_excursions", "n_flips", "t_settle", "t_first_flip", "decay_reason", "decay_n", "t_last_excursion"):
        np.testing.assert_array_equal(nat[k], ref[k], err_msg=k)
    for k in ("error_t1", "error_max_late", "error_max_settled", "size_max", "peak_last", "decay_exponent"):
        np.testing.assert_allclose(nat[k], ref[k], atol=1e-6, rtol=1e-6, err_msg=k)
    # the rest of test_verdict_engines.py's keys, at its tolerances (the keys above are held to 1e-6 already)
    for k in ("peak_ratio", "decay_exponent_se"):
        np.testing.assert_allclose(nat[k], ref[k], rtol=1e-5, atol=1e-8, err_msg=k)
    # same method, controller and step sequence (checkpoints come from the dense output, as in
    # diffrax's SaveAt(ts)): accepted steps agree up to rounding-level differences of the controller
    np.testing.assert_allclose(nat["n_steps"], ref["n_steps"], rtol=0.02, atol=3)


def test_results_do_not_depend_on_threads_width_or_static_folding(nat):
    p = batch()
    other = native.solve(SYS, p, ICFG, SYS.verdict, with_state=True, threads=1, width=8, static=[])
    np.testing.assert_array_equal(other["verdict"], nat["verdict"])
    np.testing.assert_allclose(other["state_t1"], nat["state_t1"], atol=1e-9, rtol=0)
    again = native.solve(SYS, p, ICFG, SYS.verdict, with_state=True, threads=2)
    np.testing.assert_array_equal(again["state_t1"], nat["state_t1"])  # deterministic, whatever the scheduling


def test_every_summary_is_bit_identical_across_threads_and_runs(nat):
    """Which trajectories share a SIMD block depends on thread scheduling; every observation and
    classifier update goes through the same vector code (item batches padded, FIFO drains
    vectorised), so no summary may move even in its last bit (docs/performance.md)."""
    p = batch()
    runs = [native.solve(SYS, p, ICFG, SYS.verdict, with_state=True, threads=t) for t in (1, 2, 2)]
    for other in runs:
        for k in nat:
            np.testing.assert_array_equal(other[k], nat[k], err_msg=k)


def test_model_functions_behind_a_call_change_no_bit(nat, monkeypatch):
    """A large rhs and classifier update are compiled once and called from each site (kernel.CALL_LINES);
    every summary and final state equals the kernel that inlines them at every site, bit for bit: paper A's
    (t-only values shared by the last two stages, a verdict classifier) and Lorenz-63's features-only fold
    (an autonomous rhs, every stage behind the call)."""
    from stabjax.engines.native import kernel as K
    from stabjax.run.sweep import static_params

    default = K.CALL_LINES

    def run(call_lines, *args, **kw):
        monkeypatch.setattr(K, "CALL_LINES", call_lines)
        native.clear_cache()
        system, params, icfg, vcfg = args
        kern, _ = native.kernel_for(system, icfg, vcfg, params, static=kw.get("static"))
        return kern.source, native.solve(*args, **kw)

    try:
        src, inlined = run(10**9, SYS, batch(), ICFG, SYS.verdict, with_state=True, threads=2)
        assert "rhs_lanes(" not in src and "upd_lanes(" not in src
        assert K._lines(src, "f_rhs") >= default and K._lines(src, "f_upd") >= default  # so nat called both
        for k in nat:
            np.testing.assert_array_equal(inlined[k], nat[k], err_msg=k)
        plan = _example_plan("lorenz", early_stop=False)
        args = (plan.integrated, plan.params_for(0, plan.size), plan.icfg, plan.vcfg)
        kw = {"static": static_params(plan), "threads": 2}
        src0, called = run(0, *args, **kw)
        src1, inlined = run(10**9, *args, **kw)
        assert "rhs_lanes(TS, YT" in src0 and "upd_lanes(C" in src0 and "rhs_lanes(" not in src1
        for k in inlined:
            np.testing.assert_array_equal(called[k], inlined[k], err_msg=k)
    finally:
        native.clear_cache()


def test_classifier_queue_overflow_and_late_drains_change_nothing():
    """Checkpoints so dense that lane FIFOs fill (QCAP) and hold items until the lane finishes: the
    kernel's drain counters (``run_raw(...)["drains"]``) show both overflow drains and end-of-lane drains
    happen, and the summaries equal those of the diffrax engine, which classifies checkpoint by
    checkpoint (no queue, hence no overflow). Fails if the overflow no longer happens (the test would
    prove nothing: then raise n_checkpoints) or if a drain changes a summary."""
    # ``nat``'s trajectories and tolerances, 20 times denser checkpoints: the same C source as ``nat``'s kernel
    # (the checkpoint times are data of the run), so no second C compile
    icfg = ICFG.replace(n_checkpoints=4000)
    p = batch()
    kern, dyn = native.kernel_for(SYS, icfg, SYS.verdict, p)
    ain, y0 = kern.model.host_inputs(dyn, len(ALPHAS))
    drains = native.run_raw(kern, ain, y0, threads=1)["drains"]
    assert drains["overflow"] > 0 and drains["late"] > 0, drains  # measured: 8,965 and 7,017
    nat = native.solve(SYS, p, icfg, SYS.verdict, threads=1)
    ref = solve_batch(SYS, p, IntegrateConfig(**{**icfg.__dict__, "engine": "diffrax"}))
    np.testing.assert_array_equal(nat["verdict"], ref["verdict"])
    for k in ("n_excursions", "n_flips", "t_settle", "t_first_flip"):
        np.testing.assert_array_equal(nat[k], ref[k], err_msg=k)
    for k in ("error_t1", "error_max_late", "error_max_settled", "peak_last", "decay_exponent"):
        np.testing.assert_allclose(nat[k], ref[k], atol=1e-6, rtol=1e-6, err_msg=k)
    # a sparse run of the same trajectories (``nat``'s) does not overflow: the counter is not stuck above 0
    kern, dyn = native.kernel_for(SYS, ICFG, SYS.verdict, p)
    ain, y0 = kern.model.host_inputs(dyn, len(ALPHAS))
    assert native.run_raw(kern, ain, y0, threads=1)["drains"]["overflow"] == 0


def test_failures_are_reported_not_raised():
    p = batch_params(SYS, None, 3)
    p["b"][1] = np.nan  # right-hand side NaN from t = 0
    p["w0"][2] = [300.0, -200.0, 100.0]  # needs far more than max_steps
    icfg = IntegrateConfig(t1=20.0, rtol=1e-8, atol=1e-10, n_checkpoints=16, max_steps=400)
    out = native.solve(SYS, p, icfg, SYS.verdict)
    assert out["verdict"][0, -1] != V.FAILED and out["solver_status"][0] == 0
    assert out["verdict"][1, -1] == V.FAILED and out["solver_status"][1] == 1
    assert out["verdict"][2, -1] == V.FAILED and out["solver_status"][2] == 1
    assert out["n_steps"][2] + out["n_rejected"][2] == 400


def test_progress_and_interruption(nat):
    # the batch and settings of ``nat`` (its compiled kernel); one thread: the last report comes after the end
    seen = []
    out = native.solve(SYS, batch(), ICFG, SYS.verdict, progress=lambda done, n: seen.append((done, n)), threads=1)
    assert seen and all(n == len(ALPHAS) for _, n in seen) and seen[-1][0] == len(ALPHAS)
    np.testing.assert_array_equal(out["verdict"], nat["verdict"])

    def interrupt(done, n):
        raise KeyboardInterrupt

    long = IntegrateConfig(t1=1e6, n_checkpoints=100)
    with pytest.raises(KeyboardInterrupt):  # the threads stop at their next step; nothing is returned
        native.solve(SYS, batch(32), long, SYS.verdict, progress=interrupt)


def test_dispatch_prefers_native_and_falls_back(monkeypatch):
    assert engines.resolve(SYS, IntegrateConfig()) == ("native", "")
    assert engines.chain("fused") == ("fused", "native", "diffrax")
    choice = engines.resolve(SYS, IntegrateConfig(solver="dopri5"))
    assert choice.engine == "diffrax" and "solver 'dopri5'" in choice.note
    # with a batch (translated and compiled): the settings and constants of ``nat``, whose kernel is reused
    assert engines.resolve(SYS, ICFG, SYS.verdict, batch(2)) == ("native", "")

    # a primitive without a C rule: the fused engine takes over (once, with the reason), same answer. The
    # fallback does not depend on the model (every C rule refused): a tiny one (dy/dt = -k y, the features-only
    # fold) compiles on the fused engine in a few seconds where monoaxial with the attitude classifier takes ~20
    def refuse(self, prim, params, es, in_dtypes):
        raise NoRule(prim.name)

    native._kernel.cache_clear()
    monkeypatch.setattr(emit.CEmit, "bind_elem", refuse)
    p = {"k": np.array([0.5, 1.0]), "y0": np.array([1.0, -2.0])}
    short = IntegrateConfig(t1=5.0, n_checkpoints=32)
    choice = engines.resolve(DECAY, short, DECAY.verdict, p)
    assert choice.engine == "fused" and choice.note.startswith("engine fused runs test_decay (native: no C rule for")
    out = solve_batch(DECAY, p, short)
    assert out["feat_final"].shape[0] == 2 and np.all(out["solver_status"] == 0)
    # the answer: |y(t1)| = |y0| e^{-k t1}; for this contracting flow the local errors add up at most unchanged:
    # each step's is below rtol |y| + atol, so the relative global error is below n_steps (rtol + atol / |y(t1)|)
    exact = np.abs(p["y0"]) * np.exp(-p["k"] * short.t1)
    bound = out["n_steps"] * (short.rtol + short.atol / exact)
    assert np.all(np.abs(out["feat_final"][:, 0] - exact) <= bound * exact), (out["feat_final"][:, 0], exact, bound)
    native._kernel.cache_clear()


def test_no_compiler_means_no_native(monkeypatch):
    monkeypatch.setattr(native.build, "compiler", lambda: None)
    monkeypatch.setattr(native, "compiler", lambda: None)
    native.available.cache_clear()
    try:
        assert not native.available()
        choice = engines.resolve(SYS, IntegrateConfig())
        assert choice.engine == "fused" and "native: no C compiler on PATH" in choice.note
    finally:
        native.available.cache_clear()


def test_generated_c_is_exact_where_it_should_be():
    em = emit.CEmit()
    assert emit.flit(0.1) == "(0x1.999999999999ap-4)" and float.fromhex("0x1.999999999999ap-4") == 0.1
    x = emit.Sym("x", np.float64)
    assert em.pow_(x, np.float64(0.5), ["x", "0.5"], [np.float64, np.float64]).name in em.lines[-1]
    assert "sqrt(x)" in em.lines[-1]
    assert em.pow_(x, np.float64(1.0), ["x", "1.0"], [np.float64, np.float64]) is x


# the gyrodyne (its own classify(): run by the diffrax engine) in the full suite (CI's 10 minutes)
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "gyrodyne" else n
                                  for n in list_systems(available_only=True)])
def test_translation_of_every_model_equals_jax(name):
    """rhs and observables compiled from the jaxprs equal JAX's, with constants folded and without."""
    S = get_system(name)
    rng = np.random.default_rng(1)
    n = 3
    p = {k: np.asarray(v) for k, v in batch_params(S, None, n).items()}
    p = S.check(p) if hasattr(S, "check") else p
    icfg = IntegrateConfig(t1=10.0, n_checkpoints=16)
    for static in (None, []):
        kern, dyn = native.kernel_for(S, icfg, S.verdict, p, static=static, check=False, eval_only=True)
        a, y0 = kern.model.host_inputs(dyn, n)
        for i in range(n):
            q = {k: jnp.asarray(v[i]) for k, v in p.items()}
            args = S.prepare(q)
            y = np.asarray(S.initial_state(q)) + 0.1 * rng.normal(size=y0.shape[1])
            t = 0.3 + 7.0 * i
            ref_dy = np.asarray(S.rhs(t, jnp.asarray(y), args))
            ref_obs = np.ravel(np.asarray(S.observe(t, jnp.asarray(y), args)))
            np.testing.assert_allclose(y0[i], np.asarray(S.initial_state(q)), rtol=1e-14, atol=1e-15)
            dy, obs = native.evaluate(kern, t, y, a[i])
            # the sixth/seventh stages' form (t-only part computed apart) is the same arithmetic
            np.testing.assert_array_equal(native.evaluate(kern, t, y, a[i], split=True)[0], dy)
            scale = max(1.0, float(np.max(np.abs(ref_dy))))
            np.testing.assert_allclose(dy, ref_dy, rtol=1e-11, atol=1e-12 * scale, err_msg=f"{name} rhs static={static}")
            np.testing.assert_allclose(obs, ref_obs, rtol=1e-11, atol=1e-12, err_msg=f"{name} observe static={static}")


def test_rhs_split_and_zero_terms():
    """The t-only part of paper A's rhs is cos(omega0 t**alpha) (shared by the stages at t + h); the
    diagonal damping matrix costs no products with zero."""
    kern, _ = native.kernel_for(SYS, ICFG, SYS.verdict, batch(8), eval_only=True)
    m = kern.model
    t_part = m.functions.split("void f_rhs_t(", 1)[1].split("\n}\n", 1)[0]
    assert m.n_tv == 1 and "cos(" in t_part and "jpow(t" in t_part and "y[" not in t_part
    y_part = m.functions.split("void f_rhs_y(", 1)[1].split("\n}\n", 1)[0]
    assert "cos(" not in y_part and "jpow(" not in y_part
    rhs = m.functions.split("void f_rhs(", 1)[1].split("\n}\n", 1)[0]
    assert "(0x0.0p+0) *" not in rhs and "(-0x0.0p+0) *" not in rhs
    lines = ["const double v0 = y[0*S];", "const double v1 = a[0*S];", "const double v2 = v1 * v0;",
             "out[0*S] = v2;"]
    assert emit.split_t(lines) is None  # autonomous: nothing to share
    # a term t * y stays with the state; the product c * t that a sum consumes is not stored
    lines = ["const double v0 = y[0*S];", "const double v1 = t * v0;", "const double v2 = (0x1p+1) * t;",
             "const double v3 = cos(v2);", "const double v4 = v1 + v2;", "const double v5 = v4 * v3;",
             "out[0*S] = v5;"]
    t_lines, frontier, y_lines = emit.split_t(lines)
    assert frontier == ["v3"] and "const double v3 = cos(v2);" in t_lines
    assert "const double v1 = t * v0;" in y_lines and "const double v2 = (0x1p+1) * t;" in y_lines
    assert not any("cos(" in ln for ln in y_lines)


def test_classifier_update_equals_jax():
    kern, _ = native.kernel_for(SYS, ICFG, SYS.verdict, batch(8), eval_only=True)
    m = kern.model
    t_late = V.late_start(SYS.verdict, float(ICFG.t0), float(ICFG.t1))
    upd = jax.jit(lambda c, t, o: V.update(c, t, o, SYS.verdict, t_late))
    rng = np.random.default_rng(2)
    c_tree, c_flat = V.init(jnp.float64, SYS.verdict), m.c0.copy()  # the engines' state: sized to the config
    ts = np.sort(rng.uniform(0, ICFG.t1, 200))
    for t in ts:  # a noisy error signal with excursions, flips and NaN-free values
        e = abs(rng.normal(0, 0.6)) if rng.random() < 0.3 else 10 ** rng.uniform(-9, -1)
        o = np.array([e, rng.uniform(0, 3)])
        c_tree = upd(c_tree, t, jnp.asarray(o))
        c_flat = native.update(kern, c_flat, t, o)
        ref = np.concatenate([np.asarray(x, np.float64).ravel() for x in jax.tree.leaves(c_tree)])
        np.testing.assert_allclose(c_flat, ref, rtol=1e-13, atol=0, equal_nan=True)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the engine recorded: tests/app/test_cli.py; progress: test_progress_and_interruption
def test_sweep_runs_native_with_progress_and_records_engine(tmp_path):
    from stabjax.run.sweep import run_spec

    spec = {"system": "monoaxial", "name": "tiny",
            "grid": {"alpha": {"start": 0.4, "stop": 1.0, "num": 6}},
            "integrate": {"t1": 200.0, "n_checkpoints": 64}}
    ds = run_spec(spec, tmp_path / "tiny.nc", progress=True)
    assert ds.attrs["engine"] == "native"
    ref = run_spec({**spec, "integrate": {**spec["integrate"], "engine": "diffrax"}})
    np.testing.assert_array_equal(ds["verdict"].values, ref["verdict"].values)


def test_huge_trig_arguments():
    """cos(omega0 t**alpha) at t = 1e12 and 1e15 (libm's range reduction, as in JAX).

    alpha = 1 is folded as a constant (t**1 = t exactly): with a lane-varying alpha, t**alpha is
    exp(alpha log t), whose ~27 ulp at t = 1e12 move the cosine's argument by ~1e-3, the same
    for any pow of finite accuracy at such arguments."""
    p = batch_params(SYS, None, 2)
    p["alpha"] = np.array([1.0, 1.0])
    kern, dyn = native.kernel_for(SYS, ICFG, SYS.verdict, p, eval_only=True)
    a, _ = kern.model.host_inputs(dyn, 2)
    q = {k: jnp.asarray(v[0]) for k, v in p.items()}
    y = np.array([0.1, -0.2, 0.3, 0.6, 0.48, 0.64])
    for t in (3.0, 1e12, 1e15):
        ref = np.asarray(SYS.rhs(t, jnp.asarray(y), SYS.prepare(q)))
        dy, _ = native.evaluate(kern, t, y, a[0])
        np.testing.assert_allclose(dy, ref, rtol=1e-12, atol=1e-14, err_msg=f"t={t}")


# ---- time to answer (issue 32) ------------------------------------------------------------------------------------

def _example_plan(name, **integ):
    from pathlib import Path

    from stabjax.plan.spec import load_spec, make_plan

    spec = load_spec(Path(__file__).resolve().parents[2] / "stabjax" / "examples" / name / "spec.toml")
    spec["sample"]["n"] = 48
    spec["integrate"] = {**spec["integrate"], **integ}
    return make_plan(spec)


@pytest.mark.parametrize("name", ["pendulum", "lorenz"])
def test_features_only_fold_skips_early_checkpoints_bit_for_bit(name, monkeypatch):
    """A fold of the late-window features alone observes, of the checkpoints before its window, only the last
    of each step: every summary equals the run that observes every checkpoint, bit for bit, also the last
    value of trajectories that escape before the window (the broken-butterfly Lorenz example)."""
    from stabjax.run.sweep import static_params

    plan = _example_plan(name, early_stop=False)
    assert not plan.vcfg.verdicts
    p = plan.params_for(0, plan.size)
    runs = {}
    for skip in (True, False):
        monkeypatch.setattr(native, "SKIP_BEFORE_WINDOW", skip)
        native.clear_cache()
        runs[skip] = native.solve(plan.integrated, p, plan.icfg, plan.vcfg, static=static_params(plan))
    native.clear_cache()
    if name == "lorenz":
        assert (runs[True]["solver_status"] != 0).any()  # escapes before the window: their last values kept
    for k in runs[False]:
        np.testing.assert_array_equal(runs[True][k], runs[False][k], err_msg=k)


def test_recurrence_clouds_are_data_of_one_kernel():
    """Two sets of known attractors of one shape run on one compiled kernel (the clouds are its data, no C
    compile per run); a kernel built for them refuses to run without them, and the other way round."""
    import dataclasses

    from stabjax.fold import stops
    from stabjax.run.sweep import static_params

    plan = _example_plan("pendulum", early_stop=False, attractor_stop=True)
    p = plan.params_for(0, plan.size)
    known = stops.KnownAttractors(labels=(0, 1), cloud=tuple(np.linspace(-1.0, 1.0, 2 * 48 * 2)), shape=(2, 48, 2),
                                  scale=(1.0, 1.0), eps=(0.1, 0.1), dwell=50.0, features=tuple(np.zeros(2 * 5 * 2)),
                                  fshape=(2, 5, 2))
    other = dataclasses.replace(known, cloud=tuple(np.linspace(-2.0, 3.0, 2 * 48 * 2)), eps=(0.2, 0.05))
    k1, dyn = native.kernel_for(plan.integrated, plan.icfg.replace(known_attractors=known), plan.vcfg, p,
                                static=static_params(plan))
    k2, _ = native.kernel_for(plan.integrated, plan.icfg.replace(known_attractors=other), plan.vcfg, p,
                              static=static_params(plan))
    assert k1 is k2 and k1.model.known == stops.layout(known)
    ain, y0 = native.host_inputs(k1.model, dyn, plan.size)
    with pytest.raises(ValueError, match="clouds"):
        native.run_raw(k1, ain, y0)
    plain, _ = native.kernel_for(plan.integrated, plan.icfg, plan.vcfg, p, static=static_params(plan))
    with pytest.raises(ValueError, match="clouds"):
        native.run_raw(plain, ain, y0, known=stops.attractor_data(known))


def test_host_functions_compile_per_bucket_and_padding_changes_no_row():
    from stabjax.run.sweep import static_params

    assert native.bucket(1) == native.bucket(native.MIN_BUCKET) == native.MIN_BUCKET
    assert native.bucket(native.MIN_BUCKET + 1) == 2 * native.MIN_BUCKET
    # without the early stop (which the host functions do not see: same model, fold and finalize): the kernel of
    # test_features_only_fold_skips_early_checkpoints_bit_for_bit[pendulum], loaded instead of compiled again
    plan = _example_plan("pendulum", early_stop=False)
    p = plan.params_for(0, 37)
    kern, dyn = native.kernel_for(plan.integrated, plan.icfg, plan.vcfg, p, static=static_params(plan))
    a1, y1 = native.host_inputs(kern.model, dyn, 37)
    a2, y2 = kern.model.host_inputs(dyn, 37)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(y1, y2)
    c = kern.model.c_tree_from(np.random.default_rng(0).normal(size=(37, kern.model.n_c)))
    ok = np.arange(37) % 3 != 0
    padded = native.finalize(kern, c, ok)
    direct = {k: np.asarray(v) for k, v in kern._finalize(c, jnp.asarray(ok)).items()}
    for k in direct:
        np.testing.assert_array_equal(padded[k], direct[k], err_msg=k)
