"""Bezglasnyi-Mysina sweep specs end to end on small batches (the shipped specs, shrunk)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax.spec import load_spec, make_plan
from stabjax.sweep import run_spec
from stabjax.verdict import CONVERGED

SPECS = sorted((Path(__file__).resolve().parent.parent / "sweeps").glob("twobody_*.toml"))
SMALL = {"t1": 300.0, "rtol": 1e-8, "atol": 1e-10, "n_checkpoints": 400}


def test_specs_exist():
    assert len(SPECS) >= 6


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_shipped_specs_plan(path):
    plan = make_plan(load_spec(path))
    assert plan.size <= 1000  # a few minutes on 2 cores
    assert plan.system.name.startswith("twobody_")


def _shrink(path, n, grid_num=None):
    spec = load_spec(path)
    spec["sample"]["n"] = n
    if grid_num:
        for v in spec.get("grid", {}).values():
            v["num"] = grid_num
    spec["integrate"] = dict(SMALL)
    return spec


def test_near_unstable_and_b_rate_end_to_end():
    sdir = SPECS[0].parent
    ds = run_spec(_shrink(sdir / "twobody_near_unstable.toml", 4))
    assert (ds["verdict"].values == CONVERGED).all()  # every start near s0 = -r0 left it
    assert ds["theory_guaranteed"].values.all()
    # (Omega_r, b) map, 2 x 2 x 1 = the same batch shape (one compile)
    ds = run_spec(_shrink(sdir / "twobody_b_rate.toml", 1, grid_num=2))
    assert set(ds["verdict"].dims) == {"Omega_r", "b", "sample"}
    for k in ("margin_physical", "margin_paper", "margin_printed", "margin_guaranteed", "derived_b_star_physical"):
        assert k in ds
    m = ds["margin_physical"].values
    want = ds["b"].values[None, :, None] - ds["derived_b_star_physical"].values
    np.testing.assert_allclose(m, want, atol=1e-9)
    # b* = 6 rho at |Omega_r| = 6 with rho = 2.3458 / 3 (MODELS.md C.5), both signs (rho differs by sign)
    assert abs(ds["derived_b_star_physical"].values[-1, 0, 0] - 6 * 2.3458 / 3) < 1e-3
