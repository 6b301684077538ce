"""Basin entropy (stabjax.mapping.entropy) against the definitions of Daza et al. (2016), computed directly."""
import math

import numpy as np
import pytest

from stabjax.mapping.entropy import basin_entropy


def _direct(lab, eps):
    """Box by box, as eq. (2)-(5) of the paper read (loops, no vectorisation)."""
    s = []
    for i in range(0, lab.shape[0] // eps * eps, eps):
        for j in range(0, lab.shape[1] // eps * eps, eps):
            box = lab[i:i + eps, j:j + eps].ravel()
            _, c = np.unique(box, return_counts=True)
            p = c / box.size
            s.append(float(-(p * np.log(p)).sum()))
    s = np.array(s)
    return s.mean(), (s[s > 0].mean() if (s > 0).any() else 0.0)


def test_single_basin_has_zero_entropy():
    r = basin_entropy(np.zeros((20, 30), int))
    assert r["S_b"] == 0 and r["S_bb"] == 0 and r["n_boundary_boxes"] == 0


def test_straight_boundary_through_box_middles():
    """A vertical boundary at column 12 with 5-cell boxes: the boxes of columns 10-14 hold 2/5 and 3/5."""
    lab = np.zeros((20, 30), int)
    lab[:, 12:] = 1
    r = basin_entropy(lab, 5)
    s_box = -(0.4 * math.log(0.4) + 0.6 * math.log(0.6))
    assert r["n_boundary_boxes"] == 4 and r["n_boxes"] == 24
    assert r["S_bb"] == pytest.approx(s_box, rel=1e-12)
    assert r["S_b"] == pytest.approx(4 * s_box / 24, rel=1e-12)
    assert not r["fractal_by_ln2"]  # a smooth boundary stays below ln 2


def test_well_mixed_basins_reach_ln_n():
    """Three outcomes in equal shares in every box (a 3-periodic pattern): S_i = ln 3 in every box."""
    i, j = np.indices((30, 30))
    r = basin_entropy((i + j) % 3, 3)
    assert r["S_b"] == pytest.approx(math.log(3), rel=1e-12) and r["fractal_by_ln2"]


def test_matches_direct_computation_on_random_labels_and_partial_boxes():
    rng = np.random.default_rng(0)
    lab = rng.integers(0, 4, (47, 33))
    lab[:20, :] = 2
    for eps in (1, 3, 5, 7):
        r = basin_entropy(lab, eps)
        sb, sbb = _direct(lab, eps)
        assert r["S_b"] == pytest.approx(sb, rel=1e-12) and r["S_bb"] == pytest.approx(sbb, rel=1e-12)
        assert r["cells_used"] == (47 // eps * eps) * (33 // eps * eps)


def test_sweep_of_a_start_grid_reports_it():
    """A 2-D [grid] over initial conditions without [sample]: the dataset holds S_b and S_bb."""
    from stabjax.run.sweep import run_spec

    spec = {"system": "examples/pendulum/model.py:Pendulum",
            "grid": {"theta0": {"start": -2.6, "stop": 3.6, "num": 20}, "omega0": {"start": -4.0, "stop": 4.0, "num": 20}},
            "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 300}}
    ds = run_spec(spec)
    sb, sbb = _direct(ds["outcome"].values, 5)
    assert float(ds["basin_entropy"]) == pytest.approx(sb, rel=1e-12)
    assert float(ds["boundary_basin_entropy"]) == pytest.approx(sbb, rel=1e-12)
    from stabjax.present.basins import format_summary

    assert "basin entropy S_b" in format_summary(ds)
