"""Fault tests for issue 22 ("Nothing lost, nothing silent"): files never destroyed, failures loud,
exit statuses that tell the truth (0 all classified, 1 some failed, 2 bad input, 128 + signal).

Each test names the item it keeps closed. A full disk is simulated by patching the writer (netCDF's
HDF error, matplotlib's ENOSPC); signals are sent to a real ``stabjax sweep`` process.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import stabjax
from clirun import TINY, captured, status  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "tests" / "models" / "oscillator.py"


def cli(capsys, *args) -> tuple[int, str, str]:
    return captured(capsys, *args)


def clean(out: str, err: str) -> None:
    assert "Traceback" not in out + err and 'File "' not in err, err


def files(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def spec_file(tmp_path: Path, body: str = TINY, name: str = "tiny.toml") -> Path:
    p = tmp_path / name
    p.write_text(body)
    return p


# ---- item 2: export and reproduce never replace what is not theirs -----------------------------------


def test_export_replaces_its_own_result_and_needs_force_otherwise(tmp_path, capsys):
    spec = spec_file(tmp_path)
    code, _, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress", "--no-plot", "--keep-store")
    assert code == 0, err
    store, out = tmp_path / "r.nc.zarr", tmp_path / "e.nc"
    code, o, err = cli(capsys, "export", store, "--out", out)
    assert code == 0 and "replaced" not in o
    first = xr.load_dataset(out)
    code, o, err = cli(capsys, "export", store, "--out", out)  # an export of the same store: replaced, said
    assert code == 0 and "replaced the previous file" in o, o
    foreign = tmp_path / "notes.nc"
    foreign.write_bytes(b"my notes")
    code, o, err = cli(capsys, "export", store, "--out", foreign)
    assert code == 2 and "error: --out:" in err and "--force" in err
    clean(o, err)
    assert foreign.read_bytes() == b"my notes"
    code, o, err = cli(capsys, "export", store, "--out", spec.with_suffix(".nc"), "--force")
    assert code == 0
    # never into the store itself
    code, o, err = cli(capsys, "export", store, "--out", store / "x.nc")
    assert code == 2 and "inside the store" in err
    again = xr.load_dataset(out)
    np.testing.assert_array_equal(first["verdict"].values, again["verdict"].values)


def _fake_reproducer(calls):
    def run(out_dir: Path, quick: bool = False):
        calls.append(Path(out_dir))
        out_dir.mkdir(parents=True, exist_ok=True)
        a, b = out_dir / "fig.png", out_dir / "table.md"
        a.write_bytes(b"new figure")
        b.write_text("new table")
        return [a, b]

    return run


def test_reproduce_refuses_foreign_files_and_replaces_its_own(tmp_path, capsys, monkeypatch):
    """The shipped figures (no record of ours) need --force, refused before anything is computed; our own
    unchanged files are replaced; a file changed since we wrote it is refused again; a file of a kind
    reproducers do not write (a README) is never in the way."""
    from stabjax.model import registry

    calls = []
    monkeypatch.setattr(registry, "get_reproducer", lambda name: _fake_reproducer(calls))
    out_dir = tmp_path / "results"
    out_dir.mkdir()
    (out_dir / "fig.png").write_bytes(b"shipped figure")
    (out_dir / "README").write_text("mine")
    code, o, err = cli(capsys, "reproduce", "fake", "--out-dir", out_dir)
    assert code == 2 and "error: --out-dir:" in err and "holds files this command did not write (fig.png)" in err
    assert "--force" in err and not calls
    clean(o, err)
    assert sorted(p.name for p in out_dir.iterdir()) == ["README", "fig.png"]
    code, o, err = cli(capsys, "reproduce", "fake", "--out-dir", out_dir, "--force")
    assert code == 0 and "(replaced)" in o
    assert (out_dir / "fig.png").read_bytes() == b"new figure" and (out_dir / "table.md").read_text() == "new table"
    assert not (out_dir / ".staging-fake").exists() and (out_dir / "README").read_text() == "mine"
    record = json.loads((out_dir / ".stabjax-reproduce.json").read_text())
    assert record["fake"]["fig.png"] == hashlib.sha256(b"new figure").hexdigest()
    code, o, err = cli(capsys, "reproduce", "fake", "--out-dir", out_dir)  # a re-run replaces its own files
    assert code == 0, err
    (out_dir / "table.md").write_text("edited by hand")
    n = len(calls)
    code, o, err = cli(capsys, "reproduce", "fake", "--out-dir", out_dir)
    assert code == 2 and "table.md exists" in err
    assert len(calls) == n  # refused before anything is computed
    assert (out_dir / "table.md").read_text() == "edited by hand"


def test_reproduce_keeps_refused_work_in_staging(tmp_path, capsys, monkeypatch):
    """A conflict only visible after the run (a file in a subfolder): nothing replaced, the new files kept."""
    from stabjax.model import registry

    def run(out_dir: Path, quick: bool = False):
        (out_dir / "sub").mkdir(parents=True, exist_ok=True)
        f = out_dir / "sub" / "fig.png"
        f.write_bytes(b"new")
        return [f]

    monkeypatch.setattr(registry, "get_reproducer", lambda name: run)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "fig.png").write_bytes(b"old")
    code, o, err = cli(capsys, "reproduce", "fake", "--out-dir", tmp_path)
    assert code == 2 and "fig.png exists and was not written by this command" in err and ".staging-fake" in err
    assert (tmp_path / "sub" / "fig.png").read_bytes() == b"old"
    assert (tmp_path / ".staging-fake" / "sub" / "fig.png").read_bytes() == b"new"


# ---- item 3: outputs never resolve to the spec, the model or a module ------------------------------------


def test_outputs_never_resolve_to_the_model_or_a_module(tmp_path, capsys):
    model = tmp_path / "model.py"
    model.write_bytes(MODEL.read_bytes())
    spec = spec_file(tmp_path, 'system = "model.py:Oscillator"\nname = "osc"\n[grid]\nk = [0.0, 0.1]\n'
                               '[integrate]\nt1 = 5.0\nn_checkpoints = 16\n', "osc.toml")
    link = tmp_path / "m.nc"
    link.symlink_to(model)
    (tmp_path / "r.png").symlink_to(model)
    before = files(tmp_path)
    for extra in ((), ("--force",)):
        code, o, err = cli(capsys, "sweep", spec, "--out", link, "--no-progress", *extra)
        assert code == 2 and "error: --out:" in err and "input" in err, err
        clean(o, err)
    # the map of the result (r.png, a link to the model) may not be the model either
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress", "--force")
    assert code == 2 and "input" in err
    # a store that holds the spec or the model
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "s.nc", "--store", tmp_path, "--no-progress")
    assert code == 2 and "error: --store:" in err and "input of this command" in err
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "s.nc", "--store", model, "--no-progress")
    assert code == 2 and "error: --store:" in err and "not a directory" in err
    assert files(tmp_path) == before and model.read_bytes() == MODEL.read_bytes()


# ---- item 6: templates -------------------------------------------------------------------------------------


def _osc_spec(tmp_path: Path, outcomes: str, params: str = "c = 2.0") -> Path:
    return spec_file(tmp_path, f'system = "{MODEL}:Oscillator"\nname = "osc"\n[params]\n{params}\n'
                               '[grid]\nk = [0.0, 0.1]\n[integrate]\nt1 = 40.0\nn_checkpoints = 32\n'
                               f'[outcomes]\n{outcomes}\n', "osc.toml")


def test_coinciding_templates_are_refused_before_the_run(tmp_path, capsys):
    """Two starts in the same basin (both decay to 0): their features coincide, max_distance would be 0 and
    every trajectory 'unclassified' without a word. Refused naming both, the point and the distance."""
    spec = _osc_spec(tmp_path, 'rules = {}\ntemplates = {a = {x0 = 1.0}, b = {x0 = 2.0}}\nfeatures = ["final(amplitude)"]')
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress")
    assert code == 2 and "error: outcomes.templates: templates 'a' and 'b' coincide at k = 0.0" in err, err
    assert "feature distance" in err
    clean(o, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["osc.toml"]  # no store, no result


def test_identical_templates_are_refused_statically(tmp_path, capsys):
    spec = _osc_spec(tmp_path, 'templates = {a = {x0 = 1.0}, b = {x0 = 1}}\nfeatures = ["final(amplitude)"]')
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress")
    assert code == 2 and "error: outcomes.templates.b: the same initial condition as outcomes.templates.a" in err


def test_single_template_says_the_distance_is_unbounded(tmp_path, capsys):
    spec = _osc_spec(tmp_path, 'rules = {}\ntemplates = {rest = {x0 = 1.0}}\nfeatures = ["final(amplitude)"]',
                     params="c = 0.5")
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress", "--no-plot")
    assert "note: outcomes: one template (rest) and no max_distance: the default distance is unbounded" in err, err
    assert code == 0
    ds = xr.load_dataset(tmp_path / "r.nc")
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert (ds["outcome"].values == names.index("rest")).all()  # absorbed, as the note says


def test_template_spacing_ignores_a_failed_template():
    from stabjax.mapping.declared import min_template_spacing

    tf = np.array([[[0.0], [1.0], [np.nan]], [[0.0], [3.0], [10.0]]])
    np.testing.assert_array_equal(min_template_spacing(tf), [1.0, 3.0])


# ---- item 12: rules, full disk, scheduler ----------------------------------------------------------------


@pytest.mark.parametrize("rule, says", [
    ("1/0 > 0", "evaluates to inf"),
    ("max(amplitude) > 10.0**400", "evaluates to inf"),
    ("max(amplitude) < 1" + "0" * 400, "non-finite constant"),
])
def test_rule_that_cannot_work_is_refused_before_the_run(tmp_path, capsys, rule, says):
    spec = _osc_spec(tmp_path, f'rules = {{bad = "{rule}"}}')
    t = time.perf_counter()
    code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress")
    assert code == 2 and "error: outcomes.rules.bad:" in err and says in err, err
    assert time.perf_counter() - t < 10  # statically: nothing integrated
    assert sorted(p.name for p in tmp_path.iterdir()) == ["osc.toml"]


def test_rule_evaluation_never_raises_on_features():
    """Division by a feature that is zero gives inf (numpy), not a ZeroDivisionError after the run."""
    from stabjax.model.outcomes import Rule

    r = Rule("1/min(x) > 1", ("x",), (), "outcomes.rules.r")
    got = r(lambda stat, obs: np.float64(0.0), lambda name: None)
    assert bool(got) is True


def test_full_disk_writing_the_result(tmp_path, capsys, monkeypatch):
    """netCDF reports a full disk as 'RuntimeError: NetCDF: HDF error': one line, exit 1, the chunks kept,
    no half file, and the export command that finishes the job works once there is space."""
    spec = spec_file(tmp_path)
    out = tmp_path / "r.nc"

    def full(self, path, *a, **k):
        Path(path).write_bytes(b"partial")  # what a full disk leaves behind
        raise RuntimeError("NetCDF: HDF error")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", full)
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 1 and f"could not write {out}" in err and "NetCDF: HDF error" in err, err
    assert f"stabjax export {out}.zarr --out {out}" in err
    clean(o, err)
    assert not out.exists() and not list(tmp_path.glob(".r.nc.*"))
    monkeypatch.undo()
    code, o, err = cli(capsys, "export", f"{out}.zarr", "--out", out)
    assert code == 0 and out.exists()


def test_full_disk_drawing_the_map(tmp_path, capsys, monkeypatch):
    import stabjax.present.maps as P

    spec = spec_file(tmp_path)
    out = tmp_path / "r.nc"

    def full(ds, path, *a, **k):
        Path(path).write_bytes(b"half a png")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(P, "plot_sweep", full)
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 1 and "r.png: could not write it (No space left on device)" in err, err
    assert f"stabjax plot {out} --out {out.with_suffix('.png')}" in err
    clean(o, err)
    assert out.exists() and not out.with_suffix(".png").exists() and not list(tmp_path.glob(".r.*.png"))


def _garbage_server():
    """A port that answers like something other than a Dask scheduler (the reliability run's case)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)

    def serve():
        while True:
            try:
                c, _ = srv.accept()
            except OSError:
                return
            try:
                c.sendall(b"\xff" * 64)
                time.sleep(0.2)
            except OSError:
                pass
            finally:
                c.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv


def test_unreachable_scheduler_is_one_line_within_the_timeout(tmp_path, capsys):
    spec = spec_file(tmp_path)
    free = socket.socket()
    free.bind(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()  # nothing listens there now
    srv = _garbage_server()
    try:
        for addr in (f"tcp://127.0.0.1:{port}", f"tcp://127.0.0.1:{srv.getsockname()[1]}"):
            t = time.perf_counter()
            code, o, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress",
                               "--scheduler", addr, "--connect-timeout", "2")
            assert code == 2 and "error: --scheduler: cannot reach" in err and f"scheduler at {addr}" in err, err
            clean(o, err)
            assert time.perf_counter() - t < 20
    finally:
        srv.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]
    code, o, err = cli(capsys, "sweep", spec, "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "0")
    assert code == 2 and "error: --connect-timeout:" in err


# ---- item 10: exit statuses ----------------------------------------------------------------------------


def test_all_failed_exits_1_with_the_result_written(tmp_path, capsys):
    spec = spec_file(tmp_path, TINY + "max_steps = 2\n")
    out = tmp_path / "r.nc"
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot")
    assert code == 1 and "2 of 2 trajectories failed: the solver did not reach t1" in err, err
    clean(o, err)
    ds = xr.load_dataset(out)
    assert (ds["solver_status"].values != 0).all()


def _ds(verdicts=None, outcomes=None, names=("a", "unclassified", "failed")):
    data = {}
    if verdicts is not None:
        data["verdict"] = ("i", np.asarray(verdicts, np.int8))
    attrs = {"n_trajectories": len(verdicts if verdicts is not None else outcomes)}
    if outcomes is not None:
        data["outcome"] = ("i", np.asarray(outcomes, np.int8), {"flag_meanings": " ".join(names)})
        attrs["outcomes_from_verdicts"] = 0
    return xr.Dataset(data, attrs=attrs)


def test_run_status_rules(capsys):
    from stabjax.fold import verdict as V
    from stabjax.app.sweep_cmds import run_status

    F = V.NAMES.index("failed")
    assert run_status(_ds(verdicts=[0, 1, 2, 3])) == 0  # undecided is a verdict, not a failure
    assert run_status(_ds(verdicts=[0, F, 0])) == 1
    assert "1 of 3 trajectories failed" in capsys.readouterr().err
    assert run_status(_ds(outcomes=[0, 1, 0])) == 0  # some unclassified: a result
    assert run_status(_ds(outcomes=[1, 1])) == 1
    assert "no trajectory was classified: all 2 are unclassified" in capsys.readouterr().err
    assert run_status(_ds(outcomes=[0, 2])) == 1


# ---- item 11: SIGTERM and SIGHUP ---------------------------------------------------------------------------


@pytest.mark.parametrize("sig, status, resume", [(signal.SIGTERM, 143, True), (signal.SIGHUP, 129, False)])
def test_signal_keeps_chunks_and_resumes_to_the_same_result(tmp_path, sig, status, resume):
    """Like Ctrl-C: the chunk in flight is written, the finished chunks kept, how to resume printed,
    exit 128 + signal; the resumed result equals an uninterrupted run (SIGTERM; SIGHUP takes the same path)."""
    from stabjax.run import store as S

    body = TINY.replace("alpha = [0.5, 0.7]", "alpha = [0.3, 0.5, 0.7, 0.8]")  # 4 chunks: one is left to resume
    spec = spec_file(tmp_path, body)
    out = tmp_path / "r.nc"
    store = Path(str(out) + ".zarr")
    # chunk 2 says it is in flight (a file) and waits for the signal: it lands inside a chunk on any machine
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu", STABJAX_THREADS="1",
               _STABJAX_TEST_SIGNAL_IN_CHUNK=f"2:{tmp_path}")
    cmd = [sys.executable, "-m", "stabjax", "sweep", str(spec), "--out", str(out), "--batch-size", "1",
           "--no-progress", "--no-plot"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while not (tmp_path / "chunk-2").exists() and proc.poll() is None and time.time() < deadline:
            time.sleep(0.02)
        assert (tmp_path / "chunk-2").exists(), "chunk 2 never started"
        assert len(S.read_manifest(store)["chunks"]) == 2  # chunks 0 and 1 are written, chunk 2 is in flight
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    name = signal.Signals(sig).name
    assert proc.returncode == status, err
    assert f"interrupted by {name}: finished chunks are kept in {store}; run the same command to resume" in \
        " ".join(err.split()), err
    assert "Traceback" not in err
    kept = len(S.read_manifest(store)["chunks"])
    assert kept == 3  # the chunk in flight was written, then the run stopped
    assert not out.exists()
    if not resume:
        return
    # the same command again, in this process (a fresh process's resume is test_ci_dask_client_killed_then_rerun's)
    from clirun import status as exit_status

    assert exit_status(*cmd[3:]) == 0
    resumed = xr.load_dataset(out)
    assert resumed.attrs["chunks_resumed"] == kept
    from stabjax.plan.spec import load_spec
    from stabjax.run.sweep import run_spec

    ref = run_spec(load_spec(spec), batch_size=1)
    for k in ("verdict", "solver_status", "n_steps", "error_t1"):
        np.testing.assert_array_equal(resumed[k].values, ref[k].values)


# ---- item 15: brackets survive ------------------------------------------------------------------------------


def test_help_keeps_bracketed_words(capsys):
    code, o, err = cli(capsys, "sweep", "--help")
    assert code == 0 and "A spec with a [refine] section" in o, o


def test_messages_keep_bracketed_text(tmp_path, capsys):
    spec = spec_file(tmp_path, 'system = "monoaxial"\n"[bold]x[/bold]" = 1\n')
    code, o, err = cli(capsys, "sweep", spec)
    assert code == 2 and "error: [bold]x[/bold]: unknown top-level key" in err, err
    code, o, err = cli(capsys, "theory", "nosuch[red]")
    assert code == 2 and "nosuch[red]" in err, err


def test_every_command_help_shows_its_brackets(capsys):
    """Every '[word]' written in a command's docstring or option help appears in its --help."""
    import re

    from stabjax.app.cli import app

    for cmd in app.registered_commands:
        name = cmd.name or cmd.callback.__name__.replace("_", "-")
        texts = [cmd.callback.__doc__ or ""]
        import inspect

        for p in inspect.signature(cmd.callback).parameters.values():
            texts.append(getattr(p.default, "help", None) or "")
        words = set(re.findall(r"\[[a-z_]+\]", " ".join(texts)))
        if not words:
            continue
        code, o, err = cli(capsys, name.removesuffix("-cmd"), "--help")
        for w in words:
            assert w in o, (name, w)


def test_sigterm_in_any_command_exits_143_and_handlers_are_restored(capsys, monkeypatch):
    from stabjax.model import registry

    before = signal.getsignal(signal.SIGTERM)

    def slow(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
        raise AssertionError("SIGTERM did not interrupt")

    monkeypatch.setattr(registry, "get_system", slow)
    code, o, err = cli(capsys, "theory", "monoaxial")
    assert code == 143 and "interrupted by SIGTERM" in err, err
    clean(o, err)
    assert signal.getsignal(signal.SIGTERM) is before  # an in-process caller keeps its own handler


# ---- items 7 and 9: what stays accepted ------------------------------------------------------------------


def test_one_entry_swept_with_the_vector_fixed_is_accepted():
    """Item 7 refuses a parameter both fixed and swept; one entry swept with the rest of the vector fixed
    is a different, meaningful spec and stays accepted."""
    from stabjax.plan.spec import make_plan

    p = make_plan({"system": "monoaxial", "params": {"J": [4.0, 5.0, 4.0]}, "grid": {"J[0]": [4.0, 5.0]}})
    assert p.shape == (2,)
    np.testing.assert_array_equal(p.params_for(0, 2)["J"], [[4.0, 5.0, 4.0], [5.0, 5.0, 4.0]])


def test_environment_variables_are_read_through_their_checks(monkeypatch):
    from stabjax.config import check_environment, setup_jax
    from stabjax.engines.native import default_threads
    from stabjax.errors import ValidationError

    monkeypatch.setenv("STABJAX_THREADS", "3")
    assert default_threads() == 3
    monkeypatch.setenv("STABJAX_THREADS", "abc")
    with pytest.raises(ValidationError) as info:
        default_threads()  # a Dask worker or an API caller reads it too: never silently ignored
    assert info.value.field == "STABJAX_THREADS"
    monkeypatch.delenv("STABJAX_THREADS")
    check_environment()
    with pytest.raises(ValidationError) as info:
        setup_jax(x64=False)
    assert info.value.field == "x64"
