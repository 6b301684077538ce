"""Outcome plots: one figure for each dataset shape, legends in the system's outcome names."""
from pathlib import Path

import re

import matplotlib.image as mpimg
import numpy as np
import pytest
from matplotlib.colors import to_rgb

from stabjax.present.basins import format_summary, plot_basin
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import run_plan

MODEL = Path(__file__).parents[1] / "models" / "oscillator.py"
SAMPLE = {"n": 12, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
          "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}}


@pytest.mark.parametrize("layout, grid, sample", [
    ("samples only", {}, SAMPLE),
    ("fractions along k", {"k": [0.0, 0.55, 1.0]}, SAMPLE),
    ("dominant outcome", {"k": [0.0, 1.0], "c": [0.3, 0.5]}, SAMPLE),
    ("basin picture", {"x0": [-1.0, 0.0, 1.0], "v0": [-0.5, 0.5]}, None),
])
def test_each_layout_draws(layout, grid, sample, tmp_path):
    """Each dataset shape gets its figure, drawn in the outcomes' colours: every outcome that occurs (on the
    dominant-outcome map: that dominates a cell) shows its colour in the image. The printed table holds, per outcome, the count of trajectories with that code, S =
    count / N, SE = sqrt(S (1 - S) / N) and the 95 % Wilson interval as SciPy's binomtest computes it. Fails if a
    layout draws nothing of an outcome, or the table's numbers are not those of the outcome codes."""
    from scipy.stats import binomtest

    from stabjax.present.kit import names_colors

    spec = {"system": f"{MODEL}:Oscillator", "grid": grid, "integrate": {"t1": 40.0, "n_checkpoints": 64}}
    if sample:
        spec["sample"] = sample
    ds = run_plan(make_plan(spec))
    png = tmp_path / "p.png"
    plot_basin(ds, png)
    img = mpimg.imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 300
    names, colors = names_colors(ds)
    code = np.asarray(ds["outcome"].values).ravel()
    pixels = img[..., :3].reshape(-1, 3)
    # the dominant-outcome map shows each cell's most frequent outcome only; the other layouts every outcome
    drawn = np.unique(ds["basin_fraction"].values.argmax(axis=-1)) if layout == "dominant outcome" else np.unique(code)
    for k in drawn:
        rgb = np.array(to_rgb(colors[k]))
        assert (np.abs(pixels - rgb).max(axis=1) < 2 / 255).any(), f"{names[k]} ({colors[k]}) is not drawn"
    text = format_summary(ds)
    rows = {ln.split()[0]: ln for ln in text.splitlines()[1:len(names) + 1]}
    assert list(rows) == list(names)
    n = code.size
    for k, name in enumerate(names):
        count, S, se, lo, hi = (float(x) for x in re.findall(r"[-+]?\d*\.?\d+(?:e[-+]?\d+)?", rows[name][len(name):]))
        ci = binomtest(int((code == k).sum()), n).proportion_ci(confidence_level=0.95, method="wilson")
        assert count == (code == k).sum()
        np.testing.assert_allclose([S, se, lo, hi], [count / n, np.sqrt(count / n * (1 - count / n) / n),
                                                     ci.low, ci.high], atol=5e-5)  # printed to 4 decimals
