import pytest
"""Figures the documentation quotes from a quick command, recomputed: a change that moves a number must move the
page with it (the README, where these figures lived first, once said [0.4031, 0.4039] for a bracket the command
put at [0.375, 0.3758])."""
import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the refinement's brackets in tests/explore/test_refine.py
def test_refine_alpha_bracket_matches_the_refinement_page():
    """`stabjax sweep sweeps/refine_alpha.toml`: the run count, bracket (to the digits it prints) and distance
    below the theorem's alpha = 2/3 that docs/guide/refinement.md quotes are what the refinement gives. Fails on
    any drift of the engine, classifier or refinement that moves the bracket by a lattice step (1e-3 / 1.28), or
    on an edit of the page."""
    from stabjax.explore.refine import refine_spec

    text = (ROOT / "docs" / "guide" / "refinement.md").read_text()
    m = re.search(r"stabjax sweep sweeps/refine_alpha\.toml .*?\((\d+) runs\):\s*\n\s*#\s*\[([\d.]+), ([\d.]+)\] "
                  r"at t1 = ([\de.+]+), ([\d.]+) below the theorem's 2/3", text)
    assert m, "the refinement page's refine_alpha line was not found"
    runs, lo, hi, t1, below = int(m[1]), m[2], m[3], float(m[4]), m[5]
    ds = refine_spec(ROOT / "sweeps" / "refine_alpha.toml")
    spec_t1 = float(re.search(r"^t1 = (\S+)", (ROOT / "sweeps" / "refine_alpha.toml").read_text(), re.M)[1])
    assert t1 == spec_t1
    assert ds.attrs["n_points"] == runs and ds.attrs["n_segments"] == 1
    a, b = sorted([float(ds["alpha_lo"][0]), float(ds["alpha_hi"][0])])

    def shown(x, like):  # the value as the page prints it: as many decimals as the page's figure
        return f"{x:.{len(like.split('.')[1])}f}".rstrip("0")

    assert (shown(a, lo), shown(b, hi)) == (lo.rstrip("0"), hi.rstrip("0"))
    # distance from the bracket's midpoint up to the theorem's boundary alpha = 2/3 (monoaxial Theorem 1)
    np.testing.assert_allclose(float(ds["theory_distance_alpha"][0]), 2 / 3 - 0.5 * (a + b), atol=1e-9)
    assert shown(2 / 3 - 0.5 * (a + b), below) == below.rstrip("0")


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the docs' figures are checked by the other tests here
def test_gyrostat_gravity_counts_match_the_saakyan_page():
    """`saakyan_gyrostat_gravity_44` (random starts up to 1.5 rad): the converged counts at h = 0.8 and h = 1 and
    the first gain at which all 12 converge that docs/models/saakyan.md quotes are what the sweep gives. Fails on
    a drift of the model, engine or classifier that moves one start's verdict, or on an edit of the page."""
    from stabjax.run.sweep import run_spec

    text = " ".join((ROOT / "docs" / "models" / "saakyan.md").read_text().split())
    m = re.search(r"\(`sweeps/saakyan_gyrostat_gravity_44\.toml`\) (\d+) of (\d+) converge at h = 0\.8, (\d+) of \d+ at h = 1, "
                  r"all from h = ([\d.]+)\.", text)
    assert m, "the saakyan page's saakyan_gyrostat_gravity_44 sentence was not found"
    at08, n, at1, h_all = int(m[1]), int(m[2]), int(m[3]), float(m[4])
    ds = run_spec(ROOT / "sweeps" / "saakyan_gyrostat_gravity_44.toml")
    v = ds["verdict"].isel(horizon=-1) if "horizon" in ds["verdict"].dims else ds["verdict"]
    conv = (v == 0).sum("sample").values
    h = ds["h"].values
    assert ds.sizes["sample"] == n
    assert conv[np.isclose(h, 0.8)][0] == at08 and conv[np.isclose(h, 1.0)][0] == at1
    full = h[conv == n]
    assert np.isclose(full.min(), h_all) and (conv[h >= h_all - 1e-9] == n).all()
