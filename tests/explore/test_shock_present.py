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
rel_resolution = 0.1  # coarse (fewer bisection rounds): the witness still lies between 1 (the edge) and the claim 1.3
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
                     "shock": {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 12, "refine": "none",
                               "rel_resolution": 0.1}})  # the figure's test: a coarse bracket draws the same
    basin = run_spec({"system": "test_shock_t2", "name": "b", "integrate": integ,
                      "grid": {"x0": {"start": -2, "stop": 2, "num": 9}, "y0": {"start": -2, "stop": 2, "num": 9}}})
    fig = plot_shock(ds, tmp_path / "plane.png", basin=basin)
    assert (tmp_path / "plane.png").stat().st_size > 0
    assert len(fig.axes) >= 2


BLOW = '''
import jax.numpy as jnp
from stabjax import Outcomes, Param, ParamSet, System

class Blow(System):
    title = "x' = x^2 - c: from 0, to -sqrt(c) for c > 0; blows up in finite time for c < 0"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"), Param("c", 1.0, "offset")))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    default_t1 = 20.0
    outcomes = Outcomes(rules={"rest": "abs(final(x) + 1) < 0.1"}, window=0.1)

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, p):
        return y ** 2 - p["c"]

    def observe(self, t, y, p):
        return y
'''


def test_a_failed_unshocked_start_exits_1(tmp_path, capsys):
    """Where the unshocked start fails (c = -1: it blows up before t1) no search runs there: the sweep writes the
    result, says in one line why the start failed, exits 1, and makes the statistical statement only of the grid
    point searched (c = 1, whose bracket holds the closed form's delta* = 1: x0 > 1 blows up). With one grid point
    searched there is no other to share its best direction with: that round is skipped (it raised IndexError)."""
    from clirun import captured

    from stabjax.run.sweep import open_result

    (tmp_path / "blow.py").write_text(BLOW)
    spec = tmp_path / "blow.toml"
    spec.write_text('system = "blow.py:Blow"\nname = "blow"\n[grid]\nc = [1.0, -1.0]\n[integrate]\nt1 = 20.0\n'
                    'n_checkpoints = 100\n[shock]\ncomponents = ["x0"]\nmax_radius = 2.5\ndirections = 2\n'
                    'refine = "none"\n')
    out = tmp_path / "blow.nc"
    code, text, err = captured(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot")
    assert code == 1, text + err
    assert "the unshocked start failed at 1 of 2 grid points: the solver did not reach t1" in err
    assert "c = -1: the unshocked start reaches failed: no search" in text
    assert "at the 1 of 2 grid points searched: no fatal shock in either direction of x0" in text
    assert "At the other 1 no search ran" in text
    ds = open_result(out)
    assert ds.base_solver_status.sel(c=-1.0) != 0 and ds.base_solver_status.sel(c=1.0) == 0
    assert float(ds.shock_norm_lo.sel(c=1.0)) <= 1.0 <= float(ds.shock_norm.sel(c=1.0))


def test_each_theorem_keeps_its_own_line():
    """Five theorems drew the fifth with the first's line (four styles): eight distinct (colour, dash) pairs."""
    from stabjax.present.shock import THEORY_STYLES

    assert len({repr(s) for s in THEORY_STYLES}) == len(THEORY_STYLES) >= 8
