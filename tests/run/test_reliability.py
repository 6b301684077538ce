"""A fresh reliability pass (issue 22's closing line): what a careful but unlucky user tried that still
lost work or a file, or ended with a misleading status. Each test asserts the exit status, a one-line
message naming the field or file, and that every file present before the command is byte-identical."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import xarray as xr

from test_safety import MODEL, TINY, clean, cli, files, spec_file


def test_store_equal_to_out_or_its_map_is_refused_before_the_run(tmp_path, capsys, monkeypatch):
    # --store r.nc --out r.nc: the store was made and filled, then the result could not be written
    # over it, and the message suggested `stabjax export r.nc --out r.nc`
    monkeypatch.chdir(tmp_path)
    spec = spec_file(tmp_path)
    before = files(tmp_path)
    for store in ("r.nc", "r.png", "./sub/../r.nc"):
        code, out, err = cli(capsys, "sweep", spec, "--out", "r.nc", "--store", store)
        clean(out, err)
        assert code == 2, (store, err)
        assert "--store" in err and ("r.nc" in err or "r.png" in err), err
        assert files(tmp_path) == before
        assert not (tmp_path / "r.nc").exists() and not (tmp_path / "r.png").exists()


@pytest.mark.parametrize("engine", ["native", pytest.param("fused", marks=pytest.mark.slow)])  # fused: the full suite's
def test_a_step_that_underflows_at_t0_fails_the_trajectory_instead_of_hanging(tmp_path, engine):
    # a derivative of 1e308 at t = 0: every step is rejected until h underflows to 0; the step counter
    # only counted steps with h > 0 and the collapse test (h < 10 ulp of |t|) is never true at t = 0,
    # so the sweep (one trajectory) ran for ever, and SIGTERM waits for the chunk in flight; on the fused
    # engine the step became NaN, which no "<" or "<=" test catches: both engines now require h > floor
    spec = spec_file(tmp_path, f'system = "{MODEL}:Oscillator"\nname = "huge"\n[params]\nc = 1e308\nv0 = 1.0\n'
                               f'[grid]\nk = [0.0, 0.1]\n[integrate]\nt1 = 1.0\nn_checkpoints = 8\nengine = "{engine}"\n',
                     "huge.toml")
    before = files(tmp_path)
    p = subprocess.run([sys.executable, "-m", "stabjax", "sweep", str(spec), "--out", str(tmp_path / "r.nc"),
                        "--no-plot", "--no-progress"], capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    assert "2 of 2 trajectories failed: the solver did not reach t1" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr
    assert all(files(tmp_path)[k] == v for k, v in before.items())
    ds = xr.load_dataset(tmp_path / "r.nc")
    assert (ds["solver_status"].values != 0).all()


def test_a_spec_of_one_trajectory_runs(tmp_path, capsys):
    # no [grid], no [sample]: one trajectory, a 0-d chunk block, which np.ascontiguousarray made 1-d:
    # the store write ended in a zarr traceback after the integration
    spec = spec_file(tmp_path, f'system = "{MODEL}:Oscillator"\nname = "one"\n[integrate]\nt1 = 5.0\n'
                               'n_checkpoints = 8\n', "one.toml")
    before = files(tmp_path)
    out = tmp_path / "one.nc"
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot")
    clean(o, err)
    assert code in (0, 1) and "wrote" in o, err  # 1 only if no rule classifies it: said, not a crash
    assert all(files(tmp_path)[k] == v for k, v in before.items())
    assert int(xr.load_dataset(out).attrs["n_trajectories"]) == 1


def test_store_refusals_name_the_option_and_say_what_the_file_is(tmp_path, capsys, monkeypatch):
    # the refusal of a user's folder as --store did not name the option; `export spec.toml` said
    # "not found" of a file that exists
    monkeypatch.chdir(tmp_path)
    spec = spec_file(tmp_path)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "n.txt").write_text("mine")
    before = files(tmp_path)
    code, out, err = cli(capsys, "sweep", spec, "--out", "r.nc", "--store", "notes")
    clean(out, err)
    assert code == 2 and "--store: " in err and "n.txt" in err, err
    code, out, err = cli(capsys, "export", spec, "--out", "x.nc")
    clean(out, err)
    assert code == 2 and "is a file, not a stabjax store" in err and "not found" not in err, err
    assert files(tmp_path) == before
