"""Outcome plots: one figure for each dataset shape, legends in the system's outcome names."""
from pathlib import Path

import matplotlib.image as mpimg
import pytest

from stabjax.basin_plot import format_summary, plot_basin
from stabjax.spec import make_plan
from stabjax.sweep import run_plan

MODEL = Path(__file__).parent / "models" / "oscillator.py"
SAMPLE = {"n": 12, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
          "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}}


@pytest.mark.parametrize("layout, grid, sample", [
    ("samples only", {}, SAMPLE),
    ("fractions along k", {"k": [0.0, 0.55, 1.0]}, SAMPLE),
    ("dominant outcome", {"k": [0.0, 1.0], "c": [0.3, 0.5]}, SAMPLE),
    ("basin picture", {"x0": [-1.0, 0.0, 1.0], "v0": [-0.5, 0.5]}, None),
])
def test_each_layout_draws(layout, grid, sample, tmp_path):
    spec = {"system": f"{MODEL}:Oscillator", "grid": grid, "integrate": {"t1": 40.0, "n_checkpoints": 64}}
    if sample:
        spec["sample"] = sample
    ds = run_plan(make_plan(spec))
    png = plot_basin(ds, tmp_path / "p.png")
    img = mpimg.imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 300
    text = format_summary(ds)
    assert "decays" in text and "unclassified" in text and "failed" in text
