"""Basin stability (stabjax.mapping.basin): the Wilson interval and the standard error; runs in chunks: the
same fractions whatever the chunk size; N = 10^6 at one point."""
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binomtest

from stabjax.mapping.basin import basin_stats

from stabjax.plan.spec import make_plan
from stabjax.run.sweep import run_plan

MODEL = Path(__file__).parents[1] / "models" / "oscillator.py"


def _spec(n, k=(0.4, 0.6)):
    # c = 0.5: the amplitude goes as exp((k - c) t / 2), slowly at k = 0.4 and 0.6, so by t1 = 40 some
    # starts have grown past 10 ("grows") and the others are neither below 1e-2 nor above 10
    # ("unclassified"): every kind of record occurs
    return {"system": f"{MODEL}:Oscillator", "grid": {"k": list(k)},
            "sample": {"n": n, "seed": 5, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                       "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
            "integrate": {"t1": 40.0, "n_checkpoints": 64}}


def test_chunk_size_does_not_change_outcomes(tmp_path):
    plan = make_plan(_spec(1500))
    whole = run_plan(plan, batch_size=3000)
    chunked = run_plan(plan, tmp_path / "c.nc", batch_size=256)
    np.testing.assert_array_equal(whole["outcome"].values, chunked["outcome"].values)
    for v in ("basin_count", "basin_fraction", "basin_se", "basin_ci_low", "basin_ci_high"):
        np.testing.assert_array_equal(whole[v].values, chunked[v].values)
    assert whole["basin_fraction"].dims == ("k", "outcome_name")
    assert int(whole["basin_count"].sum()) == 3000
    names = whole["outcome"].attrs["flag_meanings"].split()
    fr = whole["basin_fraction"].sel(k=0.6).values
    # e^{0.05 t} growth at k = 0.6 from |start| in (0, sqrt 2]: final amplitude ~7.4 |start|, so the
    # starts with |start| > 10 / 7.4 are "grows" and the rest are neither (unclassified)
    assert fr[names.index("grows")] > 0 and fr[names.index("unclassified")] > 0
    # every trajectory's outcome is the model's rules applied to the closed-form solution
    # x = e^{gt} (x0 cos wt + B sin wt), g = (k - c)/2, w = sqrt(1 - g^2), B = (v0 - g x0)/w, at the checkpoints of
    # the rules' window (the last quarter of [0, 40]): a run at rtol 1e-8 is far closer to it than any trajectory
    # is to a threshold (checked below), so a single misassigned trajectory fails the test
    from stabjax.fold import verdict as V

    np.testing.assert_array_equal(whole["outcome"].values, _closed_form_outcomes(plan, names, V))


def _closed_form_outcomes(plan, names, V):
    ts = V.checkpoint_times(plan.icfg.checkpoints(), plan.vcfg)
    ts = ts[ts >= 0.75 * plan.icfg.t1]
    k = np.array([ax.values for ax in plan.grid if ax.name == "k"][0])[:, None, None]
    x0, v0 = plan.sample["x0"][None, :, None], plan.sample["v0"][None, :, None]
    g = (k - 0.5) / 2
    w = np.sqrt(1 - g * g)
    B = (v0 - g * x0) / w
    c, s_ = np.cos(w * ts), np.sin(w * ts)
    e = np.exp(g * ts)
    x = e * (x0 * c + B * s_)
    v = e * (g * (x0 * c + B * s_) + w * (B * c - x0 * s_))
    amp = np.hypot(x, v)
    mx, final = amp.max(axis=-1), amp[..., -1]
    assert np.all(np.abs(mx / 1e-2 - 1) > 1e-6) and np.all(np.abs(final / 10 - 1) > 1e-6)  # none on a threshold
    code = np.where(mx < 1e-2, names.index("decays"), np.where(final > 10, names.index("grows"),
                                                                names.index("unclassified")))
    return code


@pytest.mark.slow
def test_a_million_samples_at_one_point(tmp_path):
    plan = make_plan({**_spec(1_000_000, k=(0.4,)), "integrate": {"t1": 40.0, "n_checkpoints": 16}})
    ds = run_plan(plan, tmp_path / "m.nc", batch_size=65536)
    assert int(ds["basin_count"].sum()) == 1_000_000
    assert ds["basin_se"].shape == (1, 4)


@pytest.mark.parametrize("k, n", [(0, 10), (3, 20), (10, 10), (57, 200), (1, 1000)])
def test_basin_stats_against_scipy_wilson(k, n):
    codes = np.array([0] * k + [1] * (n - k))
    st = basin_stats(codes[None, :], 3)
    s = k / n
    assert st["count"][0].tolist() == [k, n - k, 0]
    np.testing.assert_allclose(st["fraction"][0], [s, 1 - s, 0])
    np.testing.assert_allclose(st["se"][0, 0], np.sqrt(s * (1 - s) / n), rtol=1e-15)
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    np.testing.assert_allclose([st["ci_low"][0, 0], st["ci_high"][0, 0]], [ci.low, ci.high], rtol=1e-12, atol=1e-15)
    assert st["ci_low"][0, 2] == 0 and st["ci_high"][0, 2] > 0  # an outcome never seen still has an upper bound


def test_standard_error_matches_the_spread_over_independent_samples():
    """S's SE is the binomial one: over 400 independent batches of N = 200 the spread of S agrees."""
    rng = np.random.default_rng(0)
    p, n = 0.3, 200
    batches = (rng.random((400, n)) < p).astype(int)
    st = basin_stats(batches, 2)
    spread = st["fraction"][:, 1].std(ddof=1)
    # the sample std of 400 estimates is within ~3.5 % of sigma = sqrt(p(1-p)/n) (chi distribution, 3 sigma ~ 11 %)
    assert abs(spread / np.sqrt(p * (1 - p) / n) - 1) < 0.11
    assert abs(st["se"][:, 1].mean() / np.sqrt(p * (1 - p) / n) - 1) < 0.02
