"""The excursion classifier on synthetic error histories with known answers."""
import jax
import jax.numpy as jnp
import numpy as np

from stabjax.fold import verdict as V
from stabjax.model.system import VerdictConfig

CFG = VerdictConfig()
TS = np.linspace(0, 1e4, 4001)
# log + linear checkpoints (the engines' layout) for histories over several decades
TL = np.unique(np.concatenate([np.linspace(0, 1e5, 4000), np.geomspace(1.0, 1e5, 4000)]))
_classify = jax.jit(V.classify, static_argnums=(3,))


def run_all(e, size=None, ok=True, cfg=CFG, ts=TS):
    """Summaries at every horizon (trailing dim)."""
    size = np.zeros_like(e) if size is None else size
    obs = jnp.stack([jnp.asarray(e), jnp.asarray(size)], axis=1)
    cfg = V.bind(cfg, float(ts[0]), float(ts[-1])) if cfg.t1 is None else cfg
    return jax.tree.map(np.asarray, _classify(jnp.asarray(ts), obs, jnp.asarray(ok), cfg, float(ts[0])))


def run(e, size=None, ok=True, cfg=CFG, ts=TS):
    """Summaries at t1 (the last horizon)."""
    return {k: v[..., -1] if V.TRAILING_DIMS.get(k) == ("horizon",) else v
            for k, v in run_all(e, size, ok, cfg, ts).items()}


def bump(t, t0, width, peak):
    return peak * np.exp(-(((t - t0) / width) ** 2))


def test_power_law_convergence():
    e = 1.0 / (1 + TS) ** 1.5
    r = run(e)
    assert r["verdict"] == V.CONVERGED
    np.testing.assert_allclose(r["decay_exponent"], 1.5, rtol=0.01)


def test_persisting_flips_are_flipped():
    e = 1e-6 + bump(TS, 300, 50, 3.0) + bump(TS, 2300, 80, 2.6) + bump(TS, 7600, 120, 2.2)
    r = run(e)
    assert r["verdict"] == V.FLIPPED
    assert r["n_flips"] == 3 and r["n_excursions"] == 3
    np.testing.assert_allclose(r["peak_last"], 2.2, rtol=1e-3)
    np.testing.assert_allclose(r["peak_prev"], 2.6, rtol=1e-3)


def test_early_flip_then_convergence_is_converged():
    e = 1e-7 / (1 + TS) + bump(TS, 600, 50, 2.5)
    r = run(e)
    assert r["verdict"] == V.CONVERGED and r["n_flips"] == 1
    assert 400 < r["t_first_flip"] < 600


def test_shrinking_excursions_below_flip_are_undecided():
    e = 1e-6 + bump(TS, 3000, 100, 1.4) + bump(TS, 8000, 150, 1.0)
    r = run(e)
    assert r["verdict"] == V.UNDECIDED
    np.testing.assert_allclose(r["peak_ratio"], 1.0 / 1.4, rtol=1e-3)


def test_flip_in_last_decade_is_flipped():
    """A flip at 0.3 t1 (inside the last decade in log-time) is a flip whatever the linear cut."""
    e = 1e-6 + bump(TS, 3000, 100, 2.0) + bump(TS, 8000, 150, 1.0)
    assert run(e)["verdict"] == V.FLIPPED


def test_resting_inverted_is_flipped():
    assert run(np.full_like(TS, 3.1))["verdict"] == V.FLIPPED


def test_failures_and_blowup():
    e = 1.0 / (1 + TS)
    bad = e.copy()
    bad[-10:] = np.nan
    assert run(bad)["verdict"] == V.FAILED
    assert run(e, ok=False)["verdict"] == V.FAILED
    assert run(e, size=np.geomspace(1, 1e8, len(TS)))["verdict"] == V.DIVERGED


def test_slow_decay_not_reaching_tolerance_is_undecided():
    e = 0.05 * (1 + TS) ** -0.1  # ~0.02 at t1: settled but above converged_tol
    assert run(e)["verdict"] == V.UNDECIDED


def test_thresholds_are_configurable():
    e = 0.05 * (1 + TS) ** -0.1
    assert run(e, cfg=CFG.replace(converged_tol=0.05))["verdict"] == V.CONVERGED


def test_noise_floor_does_not_block_convergence():
    """At the solver's noise floor (~rtol) the late slope is noise; that must not make it undecided."""
    rng = np.random.default_rng(0)
    e = np.where(TS < 100, 1.0 / (1 + TS), 3e-8 * (1 + rng.uniform(0, 1, len(TS))) * (TS / 1e4) ** 2)
    r = run(e)
    assert r["verdict"] == V.CONVERGED
    # the decay law is fitted above the floor only (the 1/t part), not on the floor's noise
    assert r["decay_reason"] == 0 and r["decay_t_end"] <= 100 * 10 ** 0.5 + 1e-9
    assert abs(r["decay_exponent"] - 1.0) < 0.1


def test_small_bumps_in_late_window_are_not_converged():
    """Paper A: returning to 1e-12 between bumps of 0.1 rad is not convergence (no final-error shortcut)."""
    e = 1e-12 + bump(TS, 2000, 50, 2.5) + bump(TS, 8000, 80, 0.1)
    assert run(e)["verdict"] == V.FLIPPED  # the flip at 2000 is in the last decade
    e = 1e-12 + bump(TS, 500, 30, 1.0) + bump(TS, 8000, 80, 0.1)
    assert run(e)["verdict"] == V.UNDECIDED


def test_growth_past_diverge_size_then_solver_failure_is_diverged():
    """A runaway whose spun-up state then exhausts max_steps: the finite checkpoints already show it."""
    cfg = CFG.replace(diverge_size=1.0)  # attitude in rad, as for the gyrodyne
    e = 1.0 / (1 + TS)
    size = np.geomspace(1e-3, 1e3, len(TS))  # passes diverge_size at t = 5000
    cut = 3 * len(TS) // 4
    size[cut:] = np.inf  # unreached checkpoints after the solver stopped (diffrax fills inf)
    e[cut:] = np.inf
    assert size[cut - 1] > cfg.diverge_size
    r = run(e, size=size, ok=False, cfg=cfg)
    assert r["verdict"] == V.DIVERGED
    np.testing.assert_allclose(r["size_max"], size[cut - 1])  # largest finite size, not inf
    # NaN instead of inf, and solver "ok" but state non-finite: the same evidence, the same verdict
    size[cut:] = np.nan
    assert run(e, size=size, ok=False, cfg=cfg)["verdict"] == V.DIVERGED
    assert run(e, size=size, ok=True, cfg=cfg)["verdict"] == V.DIVERGED
    # the same history cut before the size reached diverge_size: no evidence, failed
    size[len(TS) // 2 - 10:] = np.nan
    assert run(e, size=size, ok=False, cfg=cfg)["verdict"] == V.FAILED


def test_nan_without_prior_growth_is_failed():
    e = 1.0 / (1 + TS)
    size = np.full_like(TS, 0.1)
    e[-10:] = np.nan
    size[-10:] = np.nan
    r = run(e, size=size)
    assert r["verdict"] == V.FAILED
    np.testing.assert_allclose(r["size_max"], 0.1)
    size[-10:] = np.inf  # an infinite size is not evidence either: only finite checkpoints count
    assert run(e, size=size)["verdict"] == V.FAILED


def test_solver_failure_without_growth_is_failed():
    e = 1.0 / (1 + TS)
    size = np.full_like(TS, CFG.diverge_size * 0.99)
    assert run(e, size=size, ok=False)["verdict"] == V.FAILED
    # growth of the error alone (never settled, late slope > growth_tol) does not override a failure
    assert run(np.geomspace(0.5, 1.0, len(TS)), ok=False)["verdict"] == V.FAILED


# ---- recurrence-aware rules, multi-horizon verdicts, decay laws (issue 16) -------------------------


def lbump(t, tc, peak, width=0.04):
    """A bump of height ``peak`` at ``tc``, Gaussian in log-time (excursions in paper A widen with t)."""
    return peak * np.exp(-((np.log(np.maximum(t, 1e-12) / tc) / width) ** 2))


def test_default_horizons_are_decades_below_t1():
    cfg = V.bind(CFG, 0.0, 1e5)
    np.testing.assert_allclose(cfg.horizons, [1e2, 1e3, 1e4, 1e5], rtol=1e-15)
    assert V.bind(CFG, 0.0, 1e5, horizons=[5e3, 1e3]).horizons == (1e3, 5e3, 1e5)
    ts = V.checkpoint_times(np.linspace(0, 1e5, 7), cfg)
    assert all(h in ts for h in cfg.horizons)


def test_geometric_recurrence_with_steady_peaks_is_flipped():
    """Flips at t_k = 30 * 2.5^k, peak 3.0 each: recurrent, not shrinking."""
    tk = 30 * 2.5 ** np.arange(9)
    e = 1e-8 + sum(lbump(TL, t, 3.0) for t in tk[tk < 1e5])
    r = run_all(e, ts=TL)
    assert np.all(r["verdict"] == V.FLIPPED)
    np.testing.assert_allclose(r["recurrence_ratio"][-1], 2.5, rtol=0.02)
    np.testing.assert_allclose(r["peak_ratio"][-1], 1.0, rtol=0.02)


def test_non_shrinking_peaks_are_never_converged():
    """Two flips of equal height, then a long quiet stretch: the peaks did not shrink -> flipped at
    every horizon; the same below pi/2 -> not converged either."""
    e = 1e-9 / (1 + TL) + lbump(TL, 100, 2.4) + lbump(TL, 300, 2.5)
    assert np.all(run_all(e, ts=TL)["verdict"][1:] == V.FLIPPED)
    e = 1e-9 / (1 + TL) + lbump(TL, 100, 0.8) + lbump(TL, 300, 0.9)
    v = run_all(e, ts=TL)["verdict"]
    assert np.all(v[1:] == V.UNDECIDED)


def test_shrinking_recurrence_is_undecided_with_trend():
    """Peaks 3 * 0.85^k at t_k = 100 * 2^k: flips end at t = 800, sub-flip excursions go on to t1."""
    k = np.arange(10)
    tk, pk = 100 * 2.0 ** k, 3.0 * 0.85 ** k
    e = 1e-8 + sum(lbump(TL, t, p) for t, p in zip(tk, pk) if t < 1e5)
    r = run_all(e, ts=TL)
    h = V.bind(CFG, 0.0, 1e5).horizons
    assert h[1] == 1e3 and r["verdict"][1] == V.FLIPPED  # flips at 100..800 inside (1e2, 1e3]
    assert r["verdict"][-1] == V.UNDECIDED  # last flip at 800 < 1e4; shrinking excursions go on
    np.testing.assert_allclose(r["peak_ratio"][-1], 0.85, rtol=0.02)
    np.testing.assert_allclose(r["t_last_excursion"][-1], tk[tk < 1e5][-1], rtol=0.1)
    assert r["n_flips"][-1] == 4 and r["n_excursions"][-1] == 10


def test_early_single_flip_from_large_initial_condition():
    """Start inverted (3 rad), settle by t ~ 5, flip once at t ~ 70, then a power-law decay. The
    approach from the initial condition is not an excursion; the flip is a transient once a decade
    of quiet follows it: flipped at 1e2, converged from 1e3 on."""
    e = 3.0 * np.exp(-TL) + 0.05 / (1 + TL) ** 2 + lbump(TL, 70, 2.5, 0.08)
    r = run_all(e, ts=TL)
    assert list(r["verdict"]) == [V.FLIPPED, V.CONVERGED, V.CONVERGED, V.CONVERGED]
    assert r["n_excursions"][-1] == 1 and r["n_flips"][-1] == 1
    assert 0 < r["t_settle"][-1] < 10


def test_flip_after_settling_in_last_decade_whatever_t1():
    """One flip at 3000: converged at 1e3 (before), flipped at 1e4 (inside its last decade),
    converged at 1e5 (a decade of quiet after it)."""
    e = 0.05 / (1 + TL) ** 2 + lbump(TL, 3000, 2.5)
    r = run_all(e, ts=TL)
    assert list(r["verdict"][1:]) == [V.CONVERGED, V.FLIPPED, V.CONVERGED]


def test_issue_example_last_flip_at_quarter_horizon():
    """Flips at 1.5e3, 6e3, 2.5e4 in a run to 1e5: the old linear late window (t >= 5e4) called it
    converged; the last flip lies in the last decade -> flipped."""
    e = 1e-9 + sum(lbump(TL, t, p) for t, p in ((1.5e3, 2.9), (6e3, 2.7), (2.5e4, 2.5)))
    r = run(e, ts=TL)
    assert r["verdict"] == V.FLIPPED
    np.testing.assert_allclose(r["t_last_flip"], 2.5e4, rtol=0.05)


def test_prefix_verdicts_equal_truncated_runs():
    """The verdict at horizon T from one run equals the verdict of the run cut at T."""
    tk = 100 * 2.0 ** np.arange(10)
    e = 0.05 / (1 + TL) + sum(lbump(TL, t, 3.0 * 0.85 ** i) for i, t in enumerate(tk) if t < 1e5)
    full = run_all(e, ts=TL)
    for j, T in enumerate(V.bind(CFG, 0.0, 1e5).horizons):
        keep = TL <= T
        cut = run(e[keep], ts=TL[keep])
        for k in ("verdict", "n_excursions", "n_flips", "error_t1", "t_last_excursion"):
            np.testing.assert_array_equal(full[k][j], cut[k], err_msg=f"{k} at {T:g}")
        np.testing.assert_allclose(full["decay_exponent"][j], cut["decay_exponent"], rtol=1e-9)


def test_decay_fit_above_noise_floor_with_standard_error():
    """e = t^-1.5 above a noise floor of 1e-9: the fit uses the last decade above floor_tol."""
    rng = np.random.default_rng(1)
    e = 0.05 * (1 + TL) ** -1.5 + 1e-9 * rng.uniform(0, 1, len(TL))
    r = run_all(e, ts=TL)
    assert np.all(r["decay_reason"][1:] == 0)
    np.testing.assert_allclose(r["decay_exponent"][1:], 1.5, atol=0.02)
    assert np.all(r["decay_exponent_se"][1:] < 0.02)
    # 0.05 t^-1.5 = floor_tol (1e-6) at t ~ 1360: the window ends at the half-decade bin holding it
    assert np.all(r["decay_t_end"][2:] == r["decay_t_end"][2]) and 1360 <= r["decay_t_end"][2] < 3200
    # a fast decay seen on a coarse grid: 4 checkpoints above the floor -> NaN, reason 2
    r = run(0.05 * np.exp(-TS) + 1e-9)
    assert np.isnan(r["decay_exponent"]) and r["decay_reason"] == 2
    # never settled -> reason 1
    assert run(np.full_like(TL, 0.3), ts=TL)["decay_reason"] == 1


def test_solver_failure_after_a_horizon_keeps_that_verdict():
    e = 0.05 / (1 + TL) ** 2
    e[TL > 2e4] = np.inf  # the solver stopped at 2e4 (diffrax fills unreached checkpoints with inf)
    v = run_all(e, ok=False, ts=TL)["verdict"]
    assert list(v) == [V.CONVERGED, V.CONVERGED, V.CONVERGED, V.FAILED]


def test_features_over_the_feature_window():
    cfg = V.bind(CFG.replace(features=True), 0.0, 1e4, n_obs=2)
    size = TS / 1e4
    r = run(1.0 / (1 + TS), size=size, cfg=cfg)
    w = TS >= 5e3
    np.testing.assert_allclose(r["feat_max"], [1 / (1 + 5e3), 1.0], rtol=1e-12)
    np.testing.assert_allclose(r["feat_min"], [1 / (1 + 1e4), 0.5], rtol=1e-12)
    np.testing.assert_allclose(r["feat_mean"][1], size[w].mean(), rtol=1e-12)
    np.testing.assert_allclose(r["feat_std"][1], size[w].std(), rtol=1e-6)
    np.testing.assert_allclose(r["feat_final"], [1 / (1 + 1e4), 1.0], rtol=1e-12)
    assert "feat_max" not in run(1.0 / (1 + TS))


def test_bad_horizons_are_refused():
    import pytest

    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError, match="verdict.horizons"):
        V.bind(CFG, 0.0, 1e4, horizons=[2e4])
    with pytest.raises(ValidationError, match="verdict.horizons"):
        V.bind(CFG, 0.0, 1e4, horizons=list(range(1, 10)))


def test_slow_approach_from_inverted_start_is_the_transient():
    """Leaving the inverted position takes until t ~ 40 of T = 300 (exponential convergence after):
    the approach is not part of the late window, converged; settling at 0.5 T is too little
    evidence (less than half a decade settled): undecided."""
    ts = np.linspace(0.0, 300.0, 400)
    for t_s, want in ((40.0, V.CONVERGED), (150.0, V.UNDECIDED)):
        e = np.where(ts < t_s, 3.1 * (1 - ts / (t_s + 1.0)) + 0.09, 0.09 * np.exp(-(ts - t_s) / 5.0))
        r = run(e, ts=ts)
        assert r["verdict"] == want and r["n_excursions"] == 0, t_s


def test_window_std_of_a_large_offset_is_the_spread_not_the_cancellation():
    """x = c + a sin(t) with c = 1e3, a = 1e-6: the window std is a's spread (two-pass NumPy on the same
    checkpoints), to the plain sum's rounding (~n eps c = 4e-10 for n = 2000 in-window checkpoints);
    E[x^2] - E[x]^2 would cancel to ~sqrt(eps) c = 1.5e-5, 20x the spread itself. A constant is 0."""
    cfg = V.bind(CFG.replace(features=True), 0.0, 1e4, n_obs=2)
    c, a = 1e3, 1e-6
    x = c + a * np.sin(TS)
    r = run(np.ones_like(TS) * 0.5, size=x, cfg=cfg)
    w = TS >= 5e3
    n = int(w.sum())
    assert abs(r["feat_std"][1] - x[w].std()) <= n * np.finfo(float).eps * c, (r["feat_std"][1], x[w].std())
    assert run(np.ones_like(TS) * 0.5, size=np.full_like(TS, np.pi * 1e3), cfg=cfg)["feat_std"][1] == 0.0


def test_window_std_is_stable_in_every_engine():
    """The same fold in the native (C), fused and diffrax engines: observable c + y of the oscillator
    y'' = -y (y(0) = 0, y'(0) = a) with c = 1e3 and a = 1e-6 (u' = 0 holds c as state). The std over the
    window is a / sqrt(2) up to the window's sampling (two-pass NumPy of the closed form at the engines'
    checkpoints) and the fold's rounding (n eps c); the solver's error on y (rtol 1e-10 of a) is below both."""
    import jax.numpy as jnp

    from stabjax import Outcomes, Param, ParamSet, System
    from stabjax.run.sweep import run_spec

    class Offset(System):
        name = "offset_oscillator_test"
        params = ParamSet((Param("c", 1e3, "offset"), Param("a", 1e-6, "amplitude", kind="initial")))
        state = (("u", ()), ("y", ()), ("v", ()))
        observables = ("x",)
        observable_doc = ("c + y",)
        outcomes = Outcomes(rules={"any": "std(x) >= 0"}, window=0.5)

        def initial_state(self, p):
            return jnp.stack([p["c"], 0.0 * p["a"], p["a"]])

        def rhs(self, t, y, p):
            return jnp.stack([0.0 * y[0], y[2], -y[1]])

        def observe(self, t, y, p):
            return jnp.stack([y[0] + y[1]])

    for engine in ("native", "fused", "diffrax"):
        spec = {"system": Offset, "grid": {"a": [1e-6]},
                "integrate": {"t1": 200.0, "n_checkpoints": 4000, "rtol": 1e-10, "atol": 1e-20, "engine": engine}}
        from stabjax.plan.spec import make_plan

        plan = make_plan(spec)
        ds = run_spec(spec)
        assert ds.attrs["engine"] == engine
        ts = V.checkpoint_times(plan.icfg.checkpoints(), plan.vcfg)
        w = ts >= 100.0
        ref = (1e3 + 1e-6 * np.sin(ts[w])).std()
        got = float(ds["feat_std"].values.ravel()[0])
        assert abs(got - ref) <= w.sum() * np.finfo(float).eps * 1e3 + 1e-10 * 1e-6, (engine, got, ref)
