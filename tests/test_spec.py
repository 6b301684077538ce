"""Spec resolution: axes, entry axes, sampling distributions, plan indexing, horizon check."""
from pathlib import Path

import numpy as np

from stabjax.spec import make_plan


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


def test_horizon_check_counts_changes():
    """alpha = 1/3 is 'flipped' at t1 = 3000 (the 2nd excursion is in the late window); alpha = 7/9 converged.
    At 8x the horizon (t1 = 24000, late window [12000, 24000]) alpha = 1/3 is flipped again: its 4th excursion,
    17547-18098 with s.r down to -0.338 (docs/models/monoaxial.md), lies in that window; and the re-run equals
    a sweep run directly at t1 = 24000. Fails if the check re-runs the wrong trajectories, at the wrong horizon,
    or counts a change that is not one."""
    from stabjax.horizon import horizon_check
    from stabjax.sweep import run_spec

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
    from stabjax.spec import load_spec, make_plan

    plan = make_plan(load_spec(Path(__file__).resolve().parents[1] / "sweeps" / "default.toml"))
    assert plan.name == "default" and [a.name for a in plan.grid] == ["alpha", "sigma"]
