"""`stabjax view RESULT` (issue 24, item 1): the Bokeh document of every result kind, a click that
re-simulates the trajectory, a running sweep's store, and the page in a real browser (Chromium via
Playwright): it loads, draws the map, a click shows the trajectory, no console errors."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bokeh", reason="stabjax view needs Bokeh (pip install 'stabjax[view]')")

from bokeh.document import Document  # noqa: E402

from stabjax.present.kit import open_result  # noqa: E402
from stabjax.present.view import LOOPBACK, build  # noqa: E402
from stabjax.present.viewmodel import Result  # noqa: E402
from stabjax.run.sweep import run_spec  # noqa: E402

from see_results import VERDICT_MAP  # noqa: E402

CHROMIUM = os.environ.get("STABJAX_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
BROWSER_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run"]


def page(path):
    doc = Document()
    r = Result(path)
    build(doc, r)
    return doc, r


def click(doc, i):
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    src.selected.indices = [i]
    return src


def test_verdict_map_has_one_cell_per_grid_point_with_the_theory_boundary(results):
    doc, r = page(results["verdicts"])
    ds = open_result(results["verdicts"])
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert len(src.data["idx"]) == ds.sizes["alpha"] * ds.sizes["sigma"]
    # cell -> trajectory: the cell at (alpha_i, sigma_j) re-runs flat index i * n_sigma + j
    k = 7
    ia, js = int(np.argmin(abs(ds.alpha.values - src.data["y"][k]))), int(np.argmin(abs(ds.sigma.values - src.data["x"][k])))
    assert src.data["idx"][k] == ia * ds.sizes["sigma"] + js
    names = ["converged", "flipped", "diverged", "undecided", "failed"]
    v = ds["verdict"].values[..., -1]
    assert src.data["name"][k] == names[int(v[ia, js])]
    # the theory boundary sigma = mu - alpha (mu - 1)/2 is drawn: its points satisfy it
    lines = [m for m in doc.select_one({"name": "map"}).renderers if hasattr(m.data_source, "data")
             and "xs" in m.data_source.data]
    xs, ys = np.concatenate(lines[0].data_source.data["xs"]), np.concatenate(lines[0].data_source.data["ys"])
    assert len(xs) >= 2
    np.testing.assert_allclose(xs, 1.5 - ys * 0.25, atol=1e-9)  # guaranteed: Theorem 1 at mu = 1.5
    text = doc.select_one({"name": "agreement"}).text
    assert "theory: guaranteed" in text and "Red flags" in text


def test_a_click_re_simulates_the_trajectory_with_the_recorded_settings(results):
    """A click on a verdict cell draws that trajectory over [t0, t1] with the late window the verdict judges and
    explains its verdicts; a click on a sampled start of the pendulum redraws that start, and what it draws at
    t1 is the stored run's final observables (feat_final) within the two runs' error bounds: each run is within
    (n_steps + 1) sqrt(n) (atol + rtol y_max) of the exact solution, carried to t1 by the flow's growth near the
    stable rest point where the run ends (tests/tolerances.py; both observables, omega and sin(theta), are
    1-Lipschitz in the state). Fails if the click ran other parameters, another horizon or other tolerances."""
    from tolerances import flow_growth, global_error_bound

    doc, r = page(results["verdicts"])
    src = click(doc, 7)
    idx = int(src.data["idx"][7])
    ts = doc.select_one({"name": "timeseries"})
    lines = [g for g in ts.renderers if g.visible and len(g.data_source.data.get("t", [])) > 0]
    assert len(lines) == len(r.plan.system.observables)
    t = np.asarray(lines[0].data_source.data["t"])
    assert t[0] == 0.0 and t[-1] == 400.0  # the result's t1
    late = [a for a in ts.center if a.name == "late_window"][0]
    assert late.left == pytest.approx(40.0) and late.right == 400.0  # the last decade in log-time
    why = doc.select_one({"name": "why"}).text
    p = r.params_of(idx)
    assert f"trajectory {idx}" in why and f"alpha = {np.array2string(np.asarray(p['alpha']), precision=5)}" in why
    assert "verdict at each horizon" in why and "solver status 0" in why
    phase = doc.select_one({"name": "phase"}).renderers[0].data_source
    assert len(phase.data["x"]) == len(t)

    doc, r = page(results["basin"])
    ds = open_result(results["basin"])
    names = str(ds["outcome"].attrs["flag_meanings"]).split()
    k = int(np.flatnonzero(ds["outcome"].values == names.index("fixed_point"))[0])
    assert float(ds["stopped_at"].values[k]) == 150.0  # ran to t1: feat_final is the state at t1
    click(doc, k)
    ts = doc.select_one({"name": "timeseries"})
    lines = [g for g in ts.renderers if g.visible and len(g.data_source.data.get("t", [])) > 0]
    traj = r.simulate(k)  # what the click drew: the same re-simulation, deterministic
    obs = list(r.plan.system.observables)
    for j, o in enumerate(obs):
        np.testing.assert_array_equal(lines[j].data_source.data["y"], traj[o].values)
    assert traj["t"].values[-1] == 150.0 and r.plan.icfg.rtol == r.plan.icfg.atol == 1e-8
    prm = r.params_of(k)
    theta_star = np.arcsin(float(prm["T"]) / float(prm["K"]))  # the stable rest point, sin(theta*) = T/K
    jac = np.array([[0.0, 1.0], [-float(prm["K"]) * np.cos(theta_star), -float(prm["alpha"])]])
    kappa = flow_growth(jac, 150.0)
    y_max = float(max(np.abs(traj["theta"].values).max(), np.abs(traj["omega"].values).max()))
    ic = r.plan.icfg
    bound = (global_error_bound(int(ds["n_steps"].values[k]), 2, ic.rtol, ic.atol, y_max, kappa)
             + global_error_bound(int(traj.attrs["n_steps"]), 2, ic.rtol, ic.atol, y_max, kappa))
    at_t1 = np.array([traj[o].values[-1] for o in obs])
    stored = ds["feat_final"].sel(observable=obs).values[k]
    assert np.all(np.abs(at_t1 - stored) <= bound), (at_t1, stored, bound)
    assert np.abs(stored[1] - np.sin(theta_star)) < 0.05  # and it is the rest point the outcome names


def test_basin_result_explains_the_rule_that_fired_and_shows_feature_space(results):
    doc, r = page(results["basin"])
    ds = open_result(results["basin"])
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert len(src.data["idx"]) == ds.sizes["sample"]  # one dot per sampled start
    np.testing.assert_array_equal(src.data["x"], ds["theta0_sample"].values)
    names = str(ds["outcome"].attrs["flag_meanings"]).split()
    k = int(np.flatnonzero(ds["outcome"].values == names.index("limit_cycle"))[0])
    click(doc, k)
    why = doc.select_one({"name": "why"}).text
    assert "rule limit_cycle" in why and "holds" in why and "assigned by" in why and "rule limit_cycle (the first" in why
    feats = doc.select_one({"name": "features"}).renderers[0].data_source
    assert len(feats.data["x"]) == ds.sizes["sample"]
    np.testing.assert_allclose(feats.data["x"], ds["feat_final"].values[:, 0])
    # outcome colours are the dataset's flag_colors, on the map and in feature space
    colors = str(ds["outcome"].attrs["flag_colors"]).split()
    assert feats.data["color"][k] == colors[names.index("limit_cycle")] == src.data["color"][k]


def test_templates_are_named_with_their_distance_and_drawn_beside_the_trajectory(tmp_path):
    """A click on a start the Duffing example names by its nearest template says which template and at what
    distance; both are recomputed here from the stored features (max(x), std(x): the example's own) and the
    stored template features with plain numpy. The templates' own trajectories are drawn in the phase portrait."""
    import tomllib

    from see_results import ROOT

    spec = tomllib.loads((ROOT / "stabjax" / "examples" / "duffing" / "spec.toml").read_text())
    spec["system"] = f"{ROOT / 'stabjax' / 'examples' / 'duffing' / 'model.py'}:Duffing"
    spec["sample"]["n"] = 12
    spec["integrate"].update(t1=300.0, n_checkpoints=600)
    out = tmp_path / "duffing.nc"
    run_spec(spec, out)
    ds = open_result(out)
    names = str(ds["outcome"].attrs["flag_meanings"]).split()
    templates = [str(t) for t in ds["template"].values]
    code = ds["outcome"].values
    named = np.flatnonzero([names[c] in templates for c in code])
    assert named.size  # the templates name most starts of this example
    k = int(named[0])
    doc, r = page(out)
    click(doc, k)
    why = doc.select_one({"name": "why"}).text
    m = re.search(r"nearest template</b></td><td>(\w+) at distance ([\d.e+-]+)", why)
    assert m, why
    x = np.array([float(ds["feat_max"].sel(observable="x").values[k]), float(ds["feat_std"].sel(observable="x").values[k])])
    assert [str(f) for f in ds["feature"].values] == ["max(x)", "std(x)"]
    tf = np.asarray(ds["template_features"].values).reshape(-1, len(templates), 2)[0]  # no grid: one point
    d = np.linalg.norm(tf - x, axis=1)
    assert m.group(1) == templates[int(np.argmin(d))] == names[code[k]]
    assert float(m.group(2)) == pytest.approx(float(d.min()), rel=5e-4)  # printed to 4 significant digits
    # the templates' own trajectories at the clicked point, in the phase portrait
    phase = doc.select_one({"name": "phase"})
    tm = [g for g in phase.renderers if "xs" in g.data_source.data][0].data_source.data
    assert len(tm["xs"]) == ds.sizes["template"] and sorted(tm["name"]) == sorted(templates)


def test_an_escaped_trajectory_says_when_it_left_and_that_the_escape_decided(tmp_path):
    import tomllib

    from see_results import ROOT

    spec = tomllib.loads((ROOT / "stabjax" / "examples" / "lorenz" / "spec.toml").read_text())
    spec["system"] = f"{ROOT / 'stabjax' / 'examples' / 'lorenz' / 'model.py'}:{spec['system'].split(':')[1]}"
    spec["sample"]["n"] = 12
    spec["integrate"].update(t1=100.0, n_checkpoints=400)
    out = tmp_path / "lorenz.nc"
    run_spec(spec, out)
    ds = open_result(out)
    esc = np.flatnonzero(ds["solver_status"].values == 100)
    assert esc.size  # most starts of this case run away
    doc, _ = page(out)
    click(doc, int(esc[0]))
    why = doc.select_one({"name": "why"}).text
    t = float(re.search(r"stopped at t ≈ ([\d.e+-]+) once max\|y_i\| &gt; 200", why).group(1))
    assert 0 < t < 100
    assert "the escape (before any rule or template)" in why and "<b>rule " not in why


def test_fractions_along_a_swept_parameter_with_wilson_bands(results):
    doc, _ = page(results["along"])
    ds = open_result(results["along"])
    fr = doc.select_one({"name": "fractions"})
    bands = [g for g in fr.renderers if type(g.glyph).__name__ == "VArea"]
    assert bands
    d = bands[0].data_source.data
    np.testing.assert_array_equal(d["x"], ds["T"].values)
    k = [i for i in range(ds.sizes["outcome_name"]) if ds["basin_fraction"].isel(outcome_name=i).values.any()][0]
    np.testing.assert_allclose(d["lo"], ds["basin_ci_low"].isel(outcome_name=k).values)
    np.testing.assert_allclose(d["hi"], ds["basin_ci_high"].isel(outcome_name=k).values)
    assert np.all(d["lo"] <= d["s"]) and np.all(d["s"] <= d["hi"])


def test_refinement_points_are_clickable_and_re_run_at_their_parameters(results):
    doc, r = page(results["refine"])
    ds = open_result(results["refine"])
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert len(src.data["idx"]) == ds.sizes["point"]
    click(doc, 5)
    p = r.params_of(5)
    assert float(p["alpha"]) == float(ds["point_alpha"].values[5]) and float(p["sigma"]) == float(ds["point_sigma"].values[5])
    assert "label" in doc.select_one({"name": "why"}).text


def test_a_running_sweeps_store_shows_finished_chunks_and_marks_the_rest(tmp_path):
    out = tmp_path / "r.nc"

    def stop_after_first(i, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(VERDICT_MAP, out, batch_size=5, on_chunk=stop_after_first)
    store = Path(str(out) + ".zarr")
    ds = open_result(store)
    pending = ds["pending"].values.ravel()
    # chunks are blocks of the 5 x 4 grid (store.Chunking): a size of 5 gives rows of 4; chunk 0 done, 1-4 not
    assert pending.sum() == 16 and not pending[:4].any()
    doc, r = page(store)
    assert r.running
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert sum(n == "pending" for n in src.data["name"]) == 16
    # no sweep writes the store (the lock went with the interrupted one): said so, not "running" (a store stopped
    # by SIGTERM was labelled a running sweep that "refreshes as chunks land")
    status = doc.select_one({"name": "status"}).text
    assert "interrupted sweep" in status and "resumes it" in status and "running sweep" not in status
    from stabjax.run.lock import Lock
    from stabjax.run.store import LOCK

    writer = Lock(store / LOCK)  # a sweep writing it (this process, alive)
    writer.acquire(store)
    try:
        other, _ = page(store)
        assert "running sweep" in other.select_one({"name": "status"}).text
    finally:
        writer.release()
    # the rest of the sweep lands: the page's periodic refresh redraws the map from the store
    run_spec(VERDICT_MAP, out, batch_size=5, keep_partial=True)
    (refresh,) = [cb for cb in doc.session_callbacks if type(cb).__name__ == "PeriodicCallback"]
    refresh.callback()
    assert not r.running
    assert not any(n == "pending" for n in src.data["name"])
    assert "running sweep" not in doc.select_one({"name": "status"}).text


WELL = Path(__file__).with_name("double_well.py")
WELL_DISCOVERY = {  # no outcomes declared: discovery assigns them when every trajectory has run
    "system": f"{WELL}:DoubleWell", "name": "well",
    "sample": {"n": 12, "seed": 0, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
               "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
    "integrate": {"t1": 40.0, "n_checkpoints": 80},
}


def test_a_running_discovery_store_is_shown_and_followed_to_its_result(tmp_path):
    """Issue 29: `stabjax view` on an interrupted discovery store answered HTTP 500 (KeyError: 'verdict'), and a
    page left open on a running store failed once the sweep finished and removed the store. Now: the finished
    trajectories are shown (no outcome yet: discovery groups the whole sweep when it ends), the rest pending,
    a click explains that; when the sweep finishes, the open page and a new tab show the netCDF file it wrote
    and say so."""
    from stabjax.present.view import page as new_tab

    out = tmp_path / "well.nc"

    def stop_after_first(i, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(WELL_DISCOVERY, out, batch_size=4, on_chunk=stop_after_first)
    store = Path(str(out) + ".zarr")
    served = Result(store)  # what `stabjax view STORE` reads when it starts; each tab gets its own reading
    doc, r = page(store)
    assert r.running and r.kind == "discovery"
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    shown = list(src.data["name"])
    assert shown.count("pending") == 8 and shown.count(r.names_colors()[0][0]) == 4  # 1 of 3 chunks of 4 done
    done = shown.index(r.names_colors()[0][0])
    click(doc, done)
    why = doc.select_one({"name": "why"}).text
    assert "assigned when every trajectory has run" in why and "solver status 0" in why
    assert "interrupted sweep" in doc.select_one({"name": "status"}).text
    # the sweep finishes: the store is removed, the netCDF file written
    run_spec(WELL_DISCOVERY, out, batch_size=4)
    assert not store.exists() and out.is_file()
    (refresh,) = [cb for cb in doc.session_callbacks if type(cb).__name__ == "PeriodicCallback"]
    refresh.callback()
    assert r.path == out and not r.running and "outcome" in r.ds
    status = doc.select_one({"name": "status"}).text
    assert "the sweep finished and removed its store" in status and str(out) in status
    assert not doc.session_callbacks  # a file: nothing to refresh any more
    names = [str(n) for n in open_result(out)["outcome"].attrs["flag_meanings"].split()]
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    assert set(src.data["name"]) <= set(names)  # the outcomes now, no pending, no "computed" left
    # a tab opened after the store is gone gets the result file too, not an HTTP error
    other = Document()
    new_tab(other, served)
    assert other.select_one({"name": "map"}) is not None
    assert str(out) in other.select_one({"name": "status"}).text


def test_a_store_removed_without_a_result_keeps_the_page_and_says_why(tmp_path):
    """A store at a place of its own (not OUT.nc.zarr) that disappears: the page keeps what it read last and
    says the store cannot be read; nothing raises."""
    import shutil

    out = tmp_path / "r.nc"

    def stop_after_first(i, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(VERDICT_MAP, out, batch_size=5, on_chunk=stop_after_first, store=tmp_path / "mine")
    doc, r = page(tmp_path / "mine")
    before = dict(doc.select_one({"name": "map"}).renderers[0].data_source.data)
    shutil.rmtree(tmp_path / "mine")
    (refresh,) = [cb for cb in doc.session_callbacks if type(cb).__name__ == "PeriodicCallback"]
    refresh.callback()
    assert "cannot be read now" in doc.select_one({"name": "status"}).text
    assert list(doc.select_one({"name": "map"}).renderers[0].data_source.data["name"]) == list(before["name"])


def _listening(port: int) -> list[str]:
    """Local addresses listening on ``port`` (from /proc/net/tcp and tcp6)."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            f = row.split()
            addr, p = f[1].split(":")
            if int(p, 16) == port and f[3] == "0A":
                found.append(addr)
    return found


def _browser_or_skip():
    """Playwright's sync API with the system's Chromium; skipped where either is missing, except in CI (``CI``
    set), where a missing browser is a failure: the page's only end-to-end check must not vanish silently
    (the reasons carry the words tests/ci_tools.py turns into failures in CI, where that hook is installed)."""
    try:
        from playwright import sync_api
    except ImportError:
        sync_api = None
    missing = ("could not import playwright (pip install playwright)" if sync_api is None else
               "no Chromium found (apt-get install chromium, or STABJAX_CHROMIUM=PATH)" if CHROMIUM is None else None)
    if missing is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI is set and the browser test cannot run: {missing}")
        pytest.skip(f"{missing}: browser test skipped")
    return sync_api


def test_the_page_in_a_real_browser(results, tmp_path):
    sync_api = _browser_or_skip()
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.Popen([sys.executable, "-m", "stabjax", "view", str(results["verdicts"]), "--no-browser",
                             "--quit-after", "90"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    errors = []
    try:
        line = proc.stdout.readline()
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        assert m, line
        port = int(m.group(1))
        assert _listening(port) == ["0100007F"]  # 127.0.0.1 only, no other address (IPv4 or IPv6)
        with sync_api.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=BROWSER_ARGS)
            pg = browser.new_page(viewport={"width": 1320, "height": 1200})
            pg.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
            pg.on("pageerror", lambda exc: errors.append(str(exc)))
            pg.goto(m.group(0))
            pg.get_by_text("click a cell or a dot on the map").wait_for(timeout=30_000)
            canvas = pg.locator("canvas").first
            canvas.wait_for(timeout=30_000)
            assert pg.get_by_text("theory: guaranteed").count() == 1  # the confusion counts
            box = canvas.bounding_box()
            assert box["width"] > 300 and box["height"] > 300  # the map is drawn
            pg.mouse.click(box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.4)
            pg.get_by_text("re-simulated on the diffrax engine").wait_for(timeout=60_000)
            # the time series reached the browser's plot (BokehJS models of the page)
            n_points = pg.evaluate("""() => {
                const f = Bokeh.documents[0].get_model_by_name('timeseries');
                return f.renderers.filter(r => r.visible).map(r => {
                    const d = r.data_source.data, t = d instanceof Map ? d.get('t') : d['t'];
                    return t ? t.length : 0; });
            }""")
            assert len(n_points) >= 2 and min(n_points) > 100, n_points
            assert pg.get_by_text("verdict at each horizon").count() == 1
            pg.screenshot(path=str(tmp_path / "view.png"))
            browser.close()
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert not errors, errors


def test_view_refuses_bad_input(tmp_path, capsys):
    from stabjax.app.cli import main

    def run(*args):
        try:
            main(list(args))
        except SystemExit as exc:
            return exc.code or 0
        return 0

    assert run("view", str(tmp_path / "missing.nc"), "--no-browser") == 2
    assert capsys.readouterr().err.startswith("error: result:")
    assert run("view", str(tmp_path), "--no-browser", "--quit-after", "1") == 2
    assert "not a sweep's chunk store" in capsys.readouterr().err
    junk = tmp_path / "junk.nc"
    junk.write_text("not netcdf")
    assert run("view", str(junk), "--no-browser", "--quit-after", "1") == 2
    assert capsys.readouterr().err.startswith("error: result:")
    assert run("view", str(tmp_path), "--port", "70000") == 2
    assert capsys.readouterr().err.startswith("error: --port:")
    assert LOOPBACK == "127.0.0.1"


def test_fractions_follow_the_clicked_row_of_a_2d_sampled_map(tmp_path):
    from see_results import BASIN_ALONG

    # the small pendulum of the sampled results (see_results.py), on a 2-D grid: the view's code is what is tested
    spec = {**BASIN_ALONG, "name": "sampled2d", "grid": {"alpha": [0.35, 0.9], "T": [0.3, 0.5, 0.7]},
            "sample": {**BASIN_ALONG["sample"], "n": 4}}
    out = tmp_path / "s.nc"
    run_spec(spec, out)
    ds = open_result(out)
    doc, _ = page(out)
    fr = doc.select_one({"name": "fractions"})
    src = doc.select_one({"name": "map"}).renderers[0].data_source
    cell = int(np.flatnonzero(np.isclose(src.data["y"], 0.9))[0])  # a cell of the alpha = 0.9 row
    click(doc, cell)
    assert "at alpha = 0.9" in fr.title.text
    band = [g for g in fr.renderers if type(g.glyph).__name__ == "VArea"][0].data_source.data
    k = [i for i in range(ds.sizes["outcome_name"]) if ds["basin_fraction"].isel(outcome_name=i).values.any()][0]
    np.testing.assert_allclose(band["s"], ds["basin_fraction"].isel(outcome_name=k, alpha=1).values)
