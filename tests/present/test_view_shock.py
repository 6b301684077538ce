"""`stabjax view` and `stabjax report` on a minimal-fatal-shock result (issue 31, item 6: the witness one click away).

The result: T2 of tests/explore/shock_models.py (x' = -s(r) x - omega y, y' = -s(r) y + omega x, s(r) = sin(pi r)/
(pi r); the origin's basin is the disc r < 1, the cycle r = 2 attracts what leaves it), searched on a 2 x 2 grid of
the rotation rate omega and a test theorem's claimed radius (1: the truth; 1.3: wrong, a red flag). A click on a grid
point must re-simulate the witness start and the unshocked start with the settings the result recorded; what it
draws is held against SciPy's DOP853 and against what the search recorded for the witness (its start, the outcome
it reached), within the two integrations' error bounds (tests/tolerances.py).
"""
import json
import math
import shlex

import numpy as np
import pytest

pytest.importorskip("bokeh", reason="stabjax view needs Bokeh (pip install 'stabjax[view]')")

from bokeh.document import Document  # noqa: E402

from see_results import ROOT  # noqa: E402
from stabjax.explore.shock_result import witness_replay  # noqa: E402
from stabjax.present import shock as SH  # noqa: E402
from stabjax.present.kit import open_result  # noqa: E402
from stabjax.present.view import build  # noqa: E402
from stabjax.present.viewmodel import Result  # noqa: E402

SPEC = {
    "system": f"{ROOT / 'tests' / 'explore' / 'shock_models.py'}:Circle2D", "name": "circle_view",
    "grid": {"omega": [1.0, 2.0], "claim": [1.0, 1.3]},
    "integrate": {"t1": 60.0, "n_checkpoints": 300, "rtol": 1e-8, "atol": 1e-10},
    # a coarse resolution (10 %, not 1 %): fewer bisection rounds; the witness of the wrong claim still lies
    # between the basin's edge (1) and the claim (1.3), and what is asserted is the view's, not the search's
    "shock": {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 8, "refine": "none", "theory": ["disc"],
              "rel_resolution": 0.1},
}


@pytest.fixture(scope="module")
def shock_nc(tmp_path_factory):
    from stabjax.explore.shock import shock_spec

    out = tmp_path_factory.mktemp("shock") / "circle.nc"
    shock_spec(SPEC, out)
    return out


def page(path):
    doc = Document()
    r = Result(path)
    build(doc, r)
    return doc, r


def click(doc, i):
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    src.selected.indices = [i]
    return src


def drawn(doc, who: str, obs: str = "r"):
    (line,) = [g for g in doc.select_one({"name": "timeseries"}).renderers if g.name == f"{who}:{obs}"]
    return np.asarray(line.data_source.data["t"]), np.asarray(line.data_source.data["y"])


def t2_rhs(t, y, omega):
    s = np.sinc(math.hypot(y[0], y[1]))  # sin(pi r)/(pi r)
    return [-s * y[0] - omega * y[1], -s * y[1] + omega * y[0]]


def test_the_map_has_one_cell_per_grid_point_and_marks_the_red_flag(shock_nc):
    """Two grid axes: a cell per grid point coloured by |delta*|, the cell of the wrong claim outlined in red; one
    axis (a slice of the same result): a dot per point at |delta*| with its bracket; the click index is the flat
    grid index (C order), which names the grid point's own |delta*|."""
    doc, r = page(shock_nc)
    ds = open_result(shock_nc)
    assert r.kind == "shock"
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert sorted(src.data["idx"]) == [0, 1, 2, 3]
    hi = ds["shock_norm"].values.ravel()
    for k, g in enumerate(src.data["idx"]):
        sel = SH.point_of(ds, g)
        assert float(src.data["x"][k]) == float(sel["claim"]) and float(src.data["y"][k]) == float(sel["omega"])
        assert f"|delta*| = {hi[g]:.4g}" in src.data["name"][k]
        refuted = int(ds["theory_verdict_disc"].sel(sel)) == 0
        assert (src.data["line"][k] == SH.RED_FLAG) == refuted == (float(sel["claim"]) == 1.3)
    one, how = SH.view_columns(ds.isel(omega=0))
    np.testing.assert_array_equal(one["x"], ds["claim"].values)
    np.testing.assert_array_equal(one["y"], ds["shock_norm"].isel(omega=0).values)
    np.testing.assert_array_equal(one["lo"], ds["shock_norm_lo"].isel(omega=0).values)
    np.testing.assert_array_equal(how["theory"]["disc"][1], ds["theory_radius_disc"].isel(omega=0).values)
    np.testing.assert_allclose(how["theory"]["disc"][1], [1.0, 1.3], rtol=1e-9)  # the claims, bisected
    assert "refuted" in doc.select_one({"name": "agreement"}).text


def test_a_click_replays_the_witness_beside_the_unshocked_start(shock_nc, capsys):
    """A click on the red flag's grid point (omega = 2, claim = 1.3) draws the witness's and the unshocked start's
    observable over [0, t1]; the witness starts at the recorded witness start, and at t1 it is on the cycle r = 2
    that the search recorded it reaching, in agreement with SciPy's DOP853 within the two runs' error bounds: each
    is within kappa (n_steps + 1) sqrt(2) (atol + rtol y_max) of the exact state, kappa = max_s ||Phi(t1, s)||. In
    polar coordinates r' = f(r) = -sin(pi r)/pi, theta' = omega, so Phi(t1, s) scales a radial error by
    f(r(t1))/f(r(s)) and a tangential one by r(t1)/r(s). The unshocked start (the origin) stays there. The
    command printed replays the same trajectory (run here through the command line)."""
    from scipy.integrate import solve_ivp
    from tolerances import global_error_bound

    from clirun import captured

    doc, r = page(shock_nc)
    ds = open_result(shock_nc)
    names = ds.attrs["outcome_names"].split()
    sel = {"omega": 2.0, "claim": 1.3}
    g = int(np.ravel_multi_index((1, 1), (2, 2)))
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    click(doc, list(src.data["idx"]).index(g))
    t, rw = drawn(doc, "witness")
    tb, rb = drawn(doc, "unshocked")
    ic = r.plan.icfg
    assert t[0] == tb[0] == 0.0 and t[-1] == tb[-1] == 60.0 and ic.rtol == 1e-8 and ic.atol == 1e-10
    w = ds["shock_witness"].sel(sel).values
    assert rw[0] == pytest.approx(math.hypot(*w), rel=1e-15) and 1.0 < rw[0] < 1.3
    assert np.all(rb == 0.0) and names[int(ds["base_outcome"].sel(sel))] == "origin"
    assert names[int(ds["shock_witness_outcome"].sel(sel))] == "cycle2"

    st = SH.starts(r, g)
    traj = r.run(st["witness"])  # what the click drew: the same re-simulation, deterministic
    np.testing.assert_array_equal(traj["r"].values, rw)
    assert float(st["witness"]["x0"]) == w[0] and float(st["witness"]["y0"]) == w[1]
    assert float(st["witness"]["omega"]) == 2.0 and float(st["witness"]["claim"]) == 1.3
    y1 = np.array([float(traj["x"].values[-1]), float(traj["y"].values[-1])])

    sol = solve_ivp(t2_rhs, (0, 60.0), w, method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True, args=(2.0,))
    assert sol.success
    rs = np.hypot(*sol.sol(np.linspace(0, 60.0, 6001)))
    f = lambda x: -np.sin(np.pi * x) / np.pi  # noqa: E731
    kappa = float(np.max(np.maximum(np.abs(f(rs[-1]) / f(rs)), rs[-1] / rs)))
    y_max = float(max(np.abs(traj["x"].values).max(), np.abs(traj["y"].values).max()))
    bound = (global_error_bound(int(traj.attrs["n_steps"]), 2, ic.rtol, ic.atol, y_max, kappa)
             + global_error_bound(sol.nfev, 2, 1e-12, 1e-14, y_max, kappa))  # nfev: more than DOP853's steps
    ref = sol.y[:, -1]
    assert np.linalg.norm(y1 - ref) <= bound, (y1, ref, bound)
    assert abs(rw[-1] - 2.0) < 1e-3  # the r = 2 cycle, as recorded ("cycle2": |mean(r) - 2| < 0.5)

    why = doc.select_one({"name": "why"}).text
    cmd = witness_replay(ds, **sel)["command"]
    assert cmd and cmd in why and "the witness reaches <b>cycle2</b>" in why and "reaches <b>origin</b>" in why
    assert "RED FLAG" in why and "re-simulated on the diffrax engine" in why

    args = shlex.split(cmd)
    assert args[:2] == ["stabjax", "simulate"]
    code, text, err = captured(capsys, *args[1:], "--json")
    assert code == 0, err
    final = json.loads(text)
    replayed = np.array([final["x"], final["y"]])
    assert final["t"] == 60.0
    # the same solver, tolerances and start: the same trajectory, within the two diffrax runs' bounds
    assert np.linalg.norm(replayed - y1) <= 2 * global_error_bound(
        max(int(traj.attrs["n_steps"]), final["n_steps"]), 2, ic.rtol, ic.atol, y_max, kappa)


def test_the_witness_in_the_start_plane_is_one_click_away(shock_nc):
    """The start plane (two shocked entries) shows the grid point's witness and its shock ball; a click on the
    witness replays it like a click on its grid point."""
    doc, r = page(shock_nc)
    ds = open_result(shock_nc)
    plane = doc.select_one({"name": "plane"})
    wit = [g for g in plane.renderers if getattr(g.glyph, "marker", None) == "star"][0].data_source
    np.testing.assert_array_equal([wit.data["x"][0], wit.data["y"][0]], ds["shock_witness"].values[0, 0])
    ball = [g for g in plane.renderers if type(g.glyph).__name__ == "Line"][0].data_source.data
    np.testing.assert_allclose(np.hypot(ball["x"], ball["y"]), float(ds["shock_norm"][0, 0]), rtol=1e-12)
    click(doc, 3)  # another grid point: the plane follows it
    g = int(doc.select_one({"name": "map"}).renderers[0].data_source.data["idx"][3])
    sel = SH.point_of(ds, g)
    np.testing.assert_array_equal([wit.data["x"][0], wit.data["y"][0]], ds["shock_witness"].sel(sel).values)
    wit.selected.indices = [0]
    assert f"<b>grid point {g}</b>" in doc.select_one({"name": "why"}).text
    _, rw = drawn(doc, "witness")
    assert rw[0] == pytest.approx(float(ds["shock_norm"].sel(sel)), rel=1e-15)


def test_the_report_names_every_witness_and_its_replay_command(shock_nc):
    from stabjax.present.report import render

    ds = open_result(shock_nc)
    page_html = render(ds, str(shock_nc))
    assert "<h2>Witnesses</h2>" in page_html and "RED FLAG disc" in page_html
    for sel, p in SH._points(ds):
        rep = witness_replay(ds, **sel)
        assert rep["found"] and rep["command"] in page_html
        assert f"{float(p['shock_witness'].values[0]):.10g}" in page_html


def test_witness_replay_refuses_a_wrong_selection_by_name(shock_nc, tmp_path):
    """A grid value that is not one, an axis that is not one, a point not fully selected, a result that is no
    shock search: each a ValidationError naming what is wrong (they were xarray KeyErrors)."""
    from stabjax.errors import ValidationError

    ds = open_result(shock_nc)
    sel, _ = next(iter(SH._points(ds)))
    ax = next(iter(sel))
    cases = [({**sel, "bogus": 1.0}, "bogus"), ({**sel, ax: 1e9}, ax)]
    if len(sel) > 1:
        cases.append(({ax: sel[ax]}, "sel"))
    for bad, field in cases:
        with pytest.raises(ValidationError) as info:
            witness_replay(ds, **bad)
        assert info.value.field == field, info.value
    with pytest.raises(ValidationError, match="not a minimal-fatal-shock result") as info:
        witness_replay(ds.drop_vars("shock_norm"), **sel)
    assert info.value.field == "ds"
    assert witness_replay(ds, **sel)["found"]


@pytest.mark.slow  # the page's model is proved in-process above; this is the page in a real browser
def test_the_shock_page_in_a_real_browser(shock_nc, tmp_path):
    import os
    import re
    import subprocess
    import sys

    from test_view import BROWSER_ARGS, CHROMIUM, _browser_or_skip

    sync_api = _browser_or_skip()
    proc = subprocess.Popen([sys.executable, "-m", "stabjax", "view", str(shock_nc), "--no-browser", "--quit-after",
                             "90"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, JAX_PLATFORMS="cpu"))
    errors = []
    try:
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", proc.stdout.readline())
        assert m
        with sync_api.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=BROWSER_ARGS)
            pg = browser.new_page(viewport={"width": 1320, "height": 1400})
            pg.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
            pg.on("pageerror", lambda exc: errors.append(str(exc)))
            pg.goto(m.group(0))
            pg.get_by_text("click a grid point (or the witness").wait_for(timeout=30_000)
            canvas = pg.locator("canvas").first
            canvas.wait_for(timeout=30_000)
            box = canvas.bounding_box()
            pg.mouse.click(box["x"] + box["width"] * 0.75, box["y"] + box["height"] * 0.3)
            pg.get_by_text("replay the witness").wait_for(timeout=60_000)
            n_points = pg.evaluate("""() => {
                const f = Bokeh.documents[0].get_model_by_name('timeseries');
                return f.renderers.map(r => {
                    const d = r.data_source.data, t = d instanceof Map ? d.get('t') : d['t'];
                    return t ? t.length : 0; });
            }""")
            assert min(n_points) > 100, n_points
            browser.close()
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert not errors, errors
