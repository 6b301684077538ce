"""End-to-end CLI: sweep -> dataset + PNG, plot, theory, simulate, systems; bad input exits non-zero."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from clirun import status  # noqa: E402
from stabjax.run.sweep import open_result

SMALL = """
system = "monoaxial"
name = "tiny"
[params]
mu = 1.5
[grid]
alpha = {start = 0.3, stop = 1.0, num = 4}
sigma = [1.2, 1.3, 1.4, 1.5]
[integrate]
t1 = 400.0
n_checkpoints = 128
"""


def run_cli(*args, capsys=None):
    return status(*args)


# the full suite's (a diffrax compile of the monoaxial model, ~10 s); in CI's 10 minutes the native engine's
# verdicts equal the diffrax engine's at every horizon on this model: tests/engines/test_verdict_engines.py::
# test_native_equals_diffrax_at_every_horizon and tests/engines/test_native.py::test_verdicts_summaries_and_steps_match_diffrax_engine
@pytest.mark.slow
def test_the_cli_sweeps_verdicts_are_the_diffrax_engines(tmp_path):
    """The verdicts of the end-to-end sweep are those of the same spec on the diffrax engine (diffrax's own Tsit5
    and controller, not the CLI's native engine): a classification that the engine's integration does not decide."""
    import tomllib

    from stabjax.run.sweep import run_spec

    spec = tmp_path / "tiny.toml"
    spec.write_text(SMALL)
    out = tmp_path / "tiny.nc"
    assert run_cli("sweep", str(spec), "--out", str(out), "--no-progress", "--no-plot") == 0
    ds = open_result(out)
    spec_d = tomllib.loads(SMALL)
    spec_d["integrate"]["engine"] = "diffrax"
    ref = run_spec(spec_d)
    assert ref.attrs["engine"] == "diffrax" and ds.attrs["engine"] != "diffrax"
    np.testing.assert_array_equal(ds["verdict"].values, ref["verdict"].values)


def test_sweep_4x4_end_to_end(tmp_path, capsys):
    spec = tmp_path / "tiny.toml"
    spec.write_text(SMALL)
    out = tmp_path / "tiny.nc"
    assert run_cli("sweep", str(spec), "--out", str(out), "--no-progress") == 0
    assert out.exists() and out.with_suffix(".png").stat().st_size > 10_000
    assert not Path(str(out) + ".zarr").exists()
    ds = open_result(out)
    assert ds["verdict"].dims == ("alpha", "sigma", "horizon") and ds["verdict"].shape == (4, 4, 4)
    assert ds["horizon"].values[-1] == json.loads(ds.attrs["integrate_json"])["t1"]
    for var in ("verdict", "error_t1", "error_max_settled", "t_first_flip", "decay_exponent", "n_steps",
                "solver_status", "theory_guaranteed", "margin_guaranteed", "theory_theorem1", "derived_alpha_crit"):
        assert var in ds, var
    assert (ds["solver_status"] == 0).all()
    assert len(np.unique(ds["verdict"].isel(horizon=-1).values)) >= 2  # the grid is not one verdict throughout
    # the theory on the grid equals the closed form sigma > 1.5 - alpha/4
    a, s = np.meshgrid(ds.alpha.values, ds.sigma.values, indexing="ij")
    np.testing.assert_array_equal(ds["theory_theorem1"].values.astype(bool), s > 1.5 - a / 4)
    for key in ("spec_json", "versions_json", "git_commit", "fixed_params_json"):
        assert key in ds.attrs
    assert json.loads(ds.attrs["spec_json"])["grid"]["sigma"] == [1.2, 1.3, 1.4, 1.5]
    text = capsys.readouterr().out
    assert "theory: guaranteed" in text and "RED FLAGS" in text
    png = tmp_path / "again.png"
    assert run_cli("plot", str(out), "--out", str(png)) == 0 and png.exists()
    # horizon-check's success path: the command reports what stabjax.run.horizon.horizon_check computes
    from stabjax.run.horizon import horizon_check

    capsys.readouterr()
    assert run_cli("horizon-check", str(out), "--factor", "2", "--n", "3", "--seed", "1", "--json") == 0
    rep = json.loads(capsys.readouterr().out)
    hc = horizon_check(open_result(out), factor=2, n=3, seed=1)
    assert rep["n_checked"] == 3 and rep["t1_short"] == 400.0 and rep["t1_long"] == 800.0
    assert rep["transition"] == hc["transition"].values.tolist() and rep["n_changed"] == hc.attrs["n_changed"]


def test_resume_after_interrupt(tmp_path):
    from stabjax.plan.spec import make_plan
    from stabjax.plan.spec import load_spec
    from stabjax.run.sweep import run_plan

    spec = tmp_path / "tiny.toml"
    spec.write_text(SMALL)
    plan = make_plan(load_spec(spec))
    out = tmp_path / "r.nc"

    def boom(i, n):
        if i == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_plan(plan, out, batch_size=4, on_chunk=boom)
    from stabjax.run.store import read_manifest

    partial = Path(str(out) + ".zarr")
    assert len(read_manifest(partial)["chunks"]) == 2 and not out.exists()
    ds = run_plan(plan, out, batch_size=4)
    assert ds.attrs["chunks_resumed"] == 2
    ref = run_plan(plan, None, batch_size=4)
    np.testing.assert_array_equal(ds["verdict"].values, ref["verdict"].values)
    np.testing.assert_allclose(ds["error_t1"].values, ref["error_t1"].values, rtol=1e-12)
    # a different spec on the same output is refused, not mixed
    from stabjax.errors import StabjaxError

    with pytest.raises(KeyboardInterrupt):
        run_plan(plan, out, batch_size=4, on_chunk=boom)
    other = make_plan({**load_spec(spec), "name": "other"})
    with pytest.raises(StabjaxError, match="not a result of this spec"):  # the finished result is not replaced
        run_plan(other, out, batch_size=4)
    with pytest.raises(StabjaxError, match="different computation"):  # allowed to, it still meets the other store
        run_plan(other, out, batch_size=4, force=True)


@pytest.mark.parametrize(
    "body, field",
    [
        ('system = "monoaxial"\n[grid]\nfoo = [1, 2]\n', "grid.foo"),
        ('system = "monoaxial"\n[grid]\nmu = [0.5, 1.5]\n', "grid.mu"),
        ('system = "monoaxial"\n[params]\nmu = 0.5\n', "params.mu"),
        ('system = "monoaxial"\n[params]\nr = [1, 1, 1]\n', "params.r"),
        ('system = "monoaxial"\n[params]\nD = [1, 2, 0, 0, 1, 0, 0, 0, 1]\n', "params.D"),
        ('system = "monoaxial"\n[params]\nD = [1, -1, 1]\n', "params.D"),
        ('system = "monoaxial"\n[params]\nJ = [1, 0, 1]\n', "params.J"),
        ('system = "monoaxial"\n[integrate]\nt1 = -5\n', "integrate.t1"),
        ('system = "monoaxial"\n[integrate]\nsolver = "euler9"\n', "integrate.solver"),
        ('system = "monoaxial"\n[integrate]\nfoo = 1\n', "integrate.foo"),
        ('system = "monoaxial"\n[verdict]\nflip = 1\n', "verdict.flip"),
        ('system = "monoaxial"\n[sample]\nn = 4\ns0 = {dist = "banana"}\n', "sample.s0.dist"),
        ('system = "monoaxial"\n[sample]\nn = 4\ns0 = {dist = "cap", center = "r", half_angle = 9}\n', "sample.s0.half_angle"),
        ('system = "nosuch"\n', "system"),
        ('system = "monoaxial"\nbogus = 1\n', "bogus"),
        ('system = "monoaxial"\n[grid]\n"J[5]" = [1, 2]\n', "grid.J[5]"),
        ('system = "monoaxial"\n[grid]\nalpha = {start = 0.1, stop = 1}\n', "grid.alpha.num"),
        ('system = "monoaxial"\n[grid]\nalpha = [0.5, -1]\n', "grid.alpha"),
    ],
)
def test_bad_specs_name_the_field(tmp_path, capsys, monkeypatch, body, field):
    """Each refused naming its field, before the engine is resolved: resolving it compiles a kernel (seconds for
    a new model), which a refusal must not wait for."""
    import stabjax.engines as E

    def compiled(*args, **kwargs):
        raise AssertionError("the engine was resolved before the spec was refused")

    monkeypatch.setattr(E, "resolve_plan", compiled)
    monkeypatch.setattr(E, "resolve", compiled)
    spec = tmp_path / "bad.toml"
    spec.write_text(body)
    out = tmp_path / "bad.nc"
    code = run_cli("sweep", str(spec), "--out", str(out), "--no-progress")
    err = capsys.readouterr().err
    assert code == 2
    assert f"error: {field}:" in " ".join(err.split()), err
    assert not out.exists()


def test_sweep_too_large_for_memory_is_refused(tmp_path, capsys):
    spec = tmp_path / "huge.toml"
    spec.write_text('system = "monoaxial"\n[grid]\nalpha = {start = 0.3, stop = 1, num = 100000}\n'
                    'sigma = {start = 1, stop = 2, num = 100000}\n')
    assert run_cli("sweep", str(spec), "--out", str(tmp_path / "h.nc"), "--no-progress") == 2
    assert "error: grid:" in capsys.readouterr().err
    spec.write_text(SMALL)
    assert run_cli("sweep", str(spec), "--out", str(tmp_path / "h.nc"), "--batch-size", "100000000") == 2
    assert "error: --batch-size:" in capsys.readouterr().err


def test_simulate_writes_trajectory(tmp_path, capsys):
    out = tmp_path / "traj.nc"
    code = run_cli("simulate", "monoaxial", "--set", "alpha=0.7777777777777778", "--t1", "1000",
                   "--ts", "1,5,10,50,100,1000", "--out", str(out), "--json")
    assert code == 0
    final = json.loads(capsys.readouterr().out)
    ds = xr.load_dataset(out)
    np.testing.assert_array_equal(ds.t.values, [1, 5, 10, 50, 100, 1000])
    assert ds.w.dims == ("t", "axis") and ds.s.dims == ("t", "axis") and ds.angle.dims == ("t",)
    # the SciPy DOP853 reference at rtol 1e-12 (tests/references.py); the run is at the default rtol 1e-8 on an
    # O(1) state that contracts after t ~ 50: within ten times rtol (tests/systems/test_monoaxial.py measures 1e-8)
    from references import monoaxial_paper

    _, ref_angle, _ = monoaxial_paper(7 / 9, [1.0, 5.0, 10.0, 50.0, 100.0, 1000.0])
    np.testing.assert_allclose(ds.angle.values, ref_angle, rtol=0, atol=1e-7)
    np.testing.assert_allclose(final["s"], ds.s.values[-1])
    assert run_cli("simulate", "monoaxial", "--set", "mu=0.9") == 2
    assert run_cli("simulate", "monoaxial", "--set", "w0=1,2") == 2
    err = capsys.readouterr().err
    assert "error: mu:" in err and "error: w0:" in err


def test_theory_json(capsys):
    assert run_cli("theory", "monoaxial", "--set", "mu=1.5", "--set", "sigma=1.3333333333333333",
                   "--set", "alpha=0.7777777777777778", "--json") == 0
    res = json.loads(capsys.readouterr().out)
    assert res["predicates"]["theorem1"]["ok"] is True
    np.testing.assert_allclose(res["predicates"]["theorem1"]["margin"], 1 / 18)
    np.testing.assert_allclose(res["derived"]["alpha_crit"]["value"], 2 / 3)


def test_systems_lists_parameters(capsys):
    assert run_cli("systems", "--json") == 0
    info = json.loads(capsys.readouterr().out)
    names = {p["name"] for p in info["monoaxial"]["params"]}
    assert {"J", "D", "a", "mu", "b", "sigma", "alpha", "omega0", "r", "s0", "w0"} <= names


def test_console_script_exit_code(tmp_path):
    r = subprocess.run([sys.executable, "-m", "stabjax", "theory", "monoaxial", "--set", "mu=0"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "mu" in r.stderr


def test_a_map_of_the_same_spec_is_replaced_without_its_result(tmp_path):
    """A fresh clone holds the README's map (results/default.png) but not its result: the map is stamped
    with its spec, so the main job may redraw it; an image of another spec, or an unstamped one, is kept."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(SMALL)
    out = tmp_path / "tiny.nc"
    assert run_cli("sweep", str(spec), "--out", str(out), "--no-progress") == 0
    out.unlink()  # as in a clone: the map is there, the result is not
    assert run_cli("sweep", str(spec), "--out", str(out), "--no-progress") == 0 and out.exists()
    out.unlink()
    spec.write_text(SMALL.replace("n_checkpoints = 128", "n_checkpoints = 64"))  # another spec: its map is kept
    png = out.with_suffix(".png")
    before = png.read_bytes()
    assert run_cli("sweep", str(spec), "--out", str(out), "--no-progress") == 2
    assert png.read_bytes() == before and not out.exists()


def test_a_sweep_with_many_unclassified_starts_says_so_and_exits_0(tmp_path, capsys):
    """The circle's starts near r0 = 1 leave the unstable cycle slowly (r' ~ r - 1): at t1 = 2 a share of them has
    reached neither rule's window, so is 'unclassified'. That is an outcome (exit 0), but the other fractions are
    lower bounds: the sweep said nothing of it on the terminal (the report alone warned)."""
    from clirun import captured

    import stabjax

    model = Path(stabjax.__file__).parent / "examples" / "shock_circle" / "model.py"
    spec = tmp_path / "s.toml"
    spec.write_text(f'system = "{model}:Circle"\nname = "short"\n[integrate]\nt1 = 2.0\nn_checkpoints = 40\n'
                    '[sample]\nn = 200\nseed = 0\nx0 = {dist = "uniform", low = -2.0, high = 2.0}\n'
                    'y0 = {dist = "uniform", low = -2.0, high = 2.0}\n')
    code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress", "--no-plot")
    assert code == 0, err
    ds = open_result(tmp_path / "r.nc")
    names = ds["outcome"].attrs["flag_meanings"].split()
    share = float((ds["outcome"].values == names.index("unclassified")).mean())
    assert share > 0.05
    assert f"warning: {100 * share:.1f}% of the trajectories are 'unclassified'" in err
