"""A shock search from the command line: `stabjax sweep` on a [shock] spec writes the result and its figure and prints
the summary with the red flag's replay command; `stabjax plot` and `stabjax report` read the result back."""
from __future__ import annotations

import numpy as np
import pytest

import shock_models as M
from stabjax.model import registry

SPEC = """system = "test_shock_t2"
name = "circle"
[params]
claim = 1.3
[integrate]
t1 = 60.0
n_checkpoints = 300
rtol = 1e-8
atol = 1e-10
[shock]
components = ["x0", "y0"]
max_radius = 2.0
directions = 12
refine = "none"
theory = ["disc"]
"""


@pytest.fixture(autouse=True)
def models(monkeypatch):
    for name, cls in M.MODELS.items():
        monkeypatch.setitem(registry.SYSTEMS, name, f"shock_models:{cls.__name__}")
        monkeypatch.setitem(registry._cache, name, cls())


def test_sweep_plot_report(tmp_path, capsys):
    from clirun import captured

    from stabjax.explore.shock_result import witness_replay
    from stabjax.run.sweep import open_result

    spec = tmp_path / "circle.toml"
    spec.write_text(SPEC)
    out = tmp_path / "circle.nc"
    code, text, err = captured(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 0, err
    assert out.exists() and out.with_suffix(".png").stat().st_size > 0 and not (tmp_path / "circle.nc.zarr").exists()
    assert "RED FLAG disc" in text and "stabjax simulate test_shock_t2" in text
    ds = open_result(out)
    rep = witness_replay(ds)
    assert rep["command"] in text.replace("\n", " ") or rep["command"].split(" -s ")[0] in text
    assert 1.0 < np.hypot(rep["params"]["x0"], rep["params"]["y0"]) < 1.3
    code, text, _ = captured(capsys, "plot", out, "--out", tmp_path / "fig.png")
    assert code == 0 and (tmp_path / "fig.png").stat().st_size > 0 and "|delta*|" in text
    code, _, err = captured(capsys, "report", out)
    page = out.with_suffix(".html").read_text()
    assert code == 0 and "Minimal fatal shock" in page and "RED FLAG" in page and "data:image/png;base64" in page


def test_plane_over_a_basin_picture(tmp_path):
    """The start plane drawn over a sweep of the same two parameters."""
    from stabjax.explore.shock import shock_spec
    from stabjax.present.shock import plot_shock
    from stabjax.run.sweep import run_spec

    integ = {"t1": 60.0, "n_checkpoints": 300, "rtol": 1e-8, "atol": 1e-10}
    ds = shock_spec({"system": "test_shock_t2", "name": "c", "integrate": integ,
                     "shock": {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 12, "refine": "none"}})
    basin = run_spec({"system": "test_shock_t2", "name": "b", "integrate": integ,
                      "grid": {"x0": {"start": -2, "stop": 2, "num": 9}, "y0": {"start": -2, "stop": 2, "num": 9}}})
    fig = plot_shock(ds, tmp_path / "plane.png", basin=basin)
    assert (tmp_path / "plane.png").stat().st_size > 0
    assert len(fig.axes) >= 2
