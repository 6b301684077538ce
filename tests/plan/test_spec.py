"""Spec resolution: axes, entry axes, sampling distributions, plan indexing, horizon check."""
from pathlib import Path

import numpy as np
import pytest

from stabjax.plan.spec import make_plan


def plan(**tables):
    return make_plan({"system": "monoaxial", **tables})


def test_grid_axes_and_flat_indexing():
    p = plan(grid={"alpha": [0.4, 0.8], "J[1]": {"start": 5, "stop": 7, "num": 3}, "b": {"start": 1, "stop": 100, "num": 3, "log": True}})
    assert p.shape == (2, 3, 3) and p.dims == ("alpha", "J_1", "b")
    np.testing.assert_allclose(p.grid[2].values, [1, 10, 100])
    q = p.params_for(0, p.size)
    a, j, b = np.meshgrid([0.4, 0.8], [5, 6, 7], [1, 10, 100], indexing="ij")
    np.testing.assert_allclose(q["alpha"], a.ravel())
    np.testing.assert_allclose(q["J"][:, 1], j.ravel())
    np.testing.assert_allclose(q["J"][:, [0, 2]], np.tile([5.0, 4.0], (18, 1)))
    np.testing.assert_allclose(q["b"], b.ravel())


def test_vector_axis_as_list():
    p = plan(grid={"w0": [[0, 0, 0], [1, 1, 1]]})
    q = p.params_for(0, 2)
    np.testing.assert_allclose(q["w0"], [[0, 0, 0], [1, 1, 1]])


def test_sampling_distributions():
    p = plan(sample={"n": 4000, "seed": 3, "s0": {"dist": "cap", "center": "r", "half_angle": 0.5},
                     "w0": {"dist": "ball", "radius": 2.0}, "b": {"dist": "uniform", "low": 1, "high": 2}})
    s0, w0, b = p.sample["s0"], p.sample["w0"], p.sample["b"]
    r = np.ones(3) / np.sqrt(3)
    ang = np.arccos(np.clip(s0 @ r, -1, 1))
    np.testing.assert_allclose(np.linalg.norm(s0, axis=1), 1, atol=1e-12)
    assert ang.max() <= 0.5 + 1e-12 and ang.max() > 0.49
    # uniform on the cap: P(angle < h/2) = (1 - cos(h/2)) / (1 - cos h)
    frac = (ang < 0.25).mean()
    expect = (1 - np.cos(0.25)) / (1 - np.cos(0.5))
    assert abs(frac - expect) < 4 * np.sqrt(expect * (1 - expect) / 4000)
    rad = np.linalg.norm(w0, axis=1)
    assert rad.max() <= 2 and abs((rad < 1).mean() - 1 / 8) < 0.03  # uniform in the ball
    assert 1 <= b.min() and b.max() <= 2
    # common random numbers: the same draws for every grid point, reproducible from the seed
    p2 = plan(grid={"alpha": [0.4, 0.8]}, sample={"n": 5, "seed": 3, "s0": {"dist": "sphere"}})
    q = p2.params_for(0, 10)
    np.testing.assert_allclose(q["s0"][:5], q["s0"][5:])
    np.testing.assert_allclose(p2.sample["s0"], plan(sample={"n": 5, "seed": 3, "s0": {"dist": "sphere"}}).sample["s0"])


def test_fingerprint_changes_with_spec():
    assert plan(grid={"alpha": [0.4]}).fingerprint() != plan(grid={"alpha": [0.5]}).fingerprint()


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: a 24,000-time-unit run; the horizon's warnings in tests/present/test_report.py
def test_horizon_check_counts_changes():
    """alpha = 1/3 is 'flipped' at t1 = 3000 (the 2nd excursion is in the late window); alpha = 7/9 converged.
    At 8x the horizon (t1 = 24000, late window [12000, 24000]) alpha = 1/3 is flipped again: its 4th excursion,
    17547-18098 with s.r down to -0.338 (docs/models/monoaxial.md), lies in that window; and the re-run equals
    a sweep run directly at t1 = 24000. Fails if the check re-runs the wrong trajectories, at the wrong horizon,
    or counts a change that is not one."""
    from stabjax.run.horizon import horizon_check
    from stabjax.run.sweep import run_spec

    spec = {"system": "monoaxial", "grid": {"alpha": [1 / 3, 7 / 9]}, "integrate": {"t1": 3000.0, "n_checkpoints": 3000}}
    ds = run_spec(spec)
    assert ds["verdict"].isel(horizon=-1).values.tolist() == [1, 0]
    hc = horizon_check(ds, factor=8, n=2)
    assert hc.attrs["n_checked"] == 2 and hc.attrs["t1_long"] == 24000
    np.testing.assert_array_equal(hc["traj"].values, [0, 1])
    np.testing.assert_array_equal(hc["verdict_short"].values, [1, 0])
    np.testing.assert_array_equal(hc["verdict_long"].values, [1, 0])  # flipped stays flipped, converged stays
    direct = run_spec({**spec, "integrate": {"t1": 24000.0, "n_checkpoints": 3000}})
    np.testing.assert_array_equal(hc["verdict_long"].values, direct["verdict"].isel(horizon=-1).values)
    table = hc["transition"].values
    assert table[1, 1] == 1 and table[0, 0] == 1 and table.sum() == 2 and hc.attrs["n_changed"] == 0


def test_the_plan_is_named_by_the_spec_not_by_an_axis():
    """The output file is results/<name>.nc: the name must survive the grid axes' parsing."""
    from stabjax.plan.spec import load_spec, make_plan

    plan = make_plan(load_spec(Path(__file__).resolve().parents[2] / "sweeps" / "default.toml"))
    assert plan.name == "default" and [a.name for a in plan.grid] == ["alpha", "sigma"]


def test_normal_sampling_is_the_normal_distribution():
    """``{dist = "normal", mean, std}``: 4000 draws of b pass a Kolmogorov-Smirnov test against N(2, 0.5^2)
    (fixed seed: a deterministic p-value, here far above 1e-3), their mean and std lie within 4 standard errors,
    and the same seed gives the same draws. Fails if mean and std are swapped, std is used as a variance, or
    the draws are not normal (e.g. uniform with that mean)."""
    from scipy import stats

    spec = {"n": 4000, "seed": 7, "b": {"dist": "normal", "mean": 2.0, "std": 0.5}}
    b = plan(sample=spec).sample["b"]
    assert b.shape == (4000,)
    assert stats.kstest(b, stats.norm(loc=2.0, scale=0.5).cdf).pvalue > 1e-3
    assert abs(b.mean() - 2.0) < 4 * 0.5 / np.sqrt(4000)
    assert abs(b.std() - 0.5) < 4 * 0.5 / np.sqrt(2 * 4000)
    np.testing.assert_array_equal(plan(sample=spec).sample["b"], b)


def test_so3_sampling_is_uniform_over_rotations():
    """``{dist = "so3"}`` on the triaxial two-body model's attitude matrix: every draw is a rotation
    (R^T R = I, det R = +1 to rounding), and the rotation angle theta of uniform (Haar) rotations has the CDF
    (theta - sin theta) / pi, which 4000 draws pass (Kolmogorov-Smirnov, fixed seed); each entry has mean 0 and
    variance 1/3. Fails for reflections, non-orthogonal matrices, or rotations biased towards the identity
    (e.g. exponentials of uniform axis-angle vectors)."""
    from scipy import stats

    p = make_plan({"system": "twobody_triaxial", "sample": {"n": 4000, "seed": 11, "S0": {"dist": "so3"}}})
    R = p.sample["S0"]
    assert R.shape == (4000, 3, 3)
    np.testing.assert_allclose(np.einsum("nki,nkj->nij", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    theta = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert stats.kstest(theta, lambda x: (x - np.sin(x)) / np.pi).pvalue > 1e-3
    se = np.sqrt(1 / 3 / 4000)
    assert np.all(np.abs(R.mean(axis=0)) < 4 * se)
    assert np.all(np.abs(R.var(axis=0) - 1 / 3) < 0.05)
