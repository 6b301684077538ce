"""The command line a person expects (issue 24, item 4): --version, a one-line-per-system list,
progress that reads well in a log file, and a wheel that carries its licence and the examples."""
import io
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path


import stabjax
from clirun import status  # noqa: E402
from stabjax.model.registry import all_names

ROOT = Path(__file__).resolve().parents[2]


def run_cli(*args):
    return status(*args)


def test_version_prints_the_package_version(capsys):
    assert run_cli("--version") == 0
    assert capsys.readouterr().out.strip() == f"stabjax {stabjax.__version__}"


def test_systems_is_one_line_per_system_with_name_title_and_source(capsys):
    assert run_cli("systems") == 0
    lines = capsys.readouterr().out.strip().splitlines()
    names = all_names()
    assert len(lines) == len(names) + 1  # one per system, then how to get details
    for name, line in zip(names, lines):
        assert re.fullmatch(rf"{re.escape(name)}  -  .+  \((builtin|registered|entry point)\)", line), line
    assert "monoaxial  -  Monoaxial stabilisation" in lines[0]
    assert "stabjax systems NAME" in lines[-1]


def test_systems_name_shows_the_details(capsys):
    assert run_cli("systems", "monoaxial") == 0
    out = capsys.readouterr().out
    for word in ("alpha", "sigma", "observables", "outcomes", "state"):
        assert word in out, word


def test_examples_are_copied_out_and_never_overwritten_silently(tmp_path, capsys):
    dest = tmp_path / "ex"
    assert run_cli("examples", str(dest)) == 0
    for name in ("duffing", "lorenz", "pendulum"):
        assert (dest / name / "spec.toml").read_bytes() == (ROOT / "stabjax" / "examples" / name / "spec.toml").read_bytes()
        assert (dest / name / "model.py").stat().st_size > 0
    (dest / "duffing" / "spec.toml").write_text("# my edits")
    capsys.readouterr()
    assert run_cli("examples", str(dest)) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: dest:") and "--force" in err and len(err.strip().splitlines()) == 1
    assert (dest / "duffing" / "spec.toml").read_text() == "# my edits"
    assert run_cli("examples", str(dest), "--force") == 0
    assert "system" in (dest / "duffing" / "spec.toml").read_text()
    afile = tmp_path / "file"
    afile.write_text("x")
    assert run_cli("examples", str(afile)) == 2
    assert "error: dest:" in capsys.readouterr().err


def test_top_level_examples_is_the_package_directory():
    top = ROOT / "examples"
    assert top.is_symlink() and top.resolve() == (ROOT / "stabjax" / "examples").resolve()


def test_progress_without_a_terminal_is_plain_lines_with_rate_and_eta():
    from stabjax.run.progress import Lines as _Lines

    buf = io.StringIO()
    bar = _Lines(1000, "demo", chunks=4, interval=0.0, stream=buf)
    bar.update(250, chunks=1)  # a resumed chunk: counted as done, not in the rate
    bar.update(250, chunk_done=True)
    bar.update(500, chunk_done=True)
    bar.close()
    lines = buf.getvalue().splitlines()
    assert "\r" not in buf.getvalue() and "\x1b" not in buf.getvalue()  # no control codes in a log file
    assert lines[0].startswith("demo: 250/1,000 traj (25%, 1/4 chunks)")
    assert re.search(r"500/1,000 traj \(50%, 2/4 chunks\), [\d,]+ traj/s, elapsed 0:00:\d\d, ETA \d+:\d\d:\d\d",
                     lines[1]), lines[1]
    assert lines[-1].startswith("demo: 1,000/1,000 traj (100%, 3/4 chunks)") and "ETA 0:00:00" in lines[-1]


def test_progress_lines_are_spaced_by_the_interval():
    from stabjax.run.progress import Lines as _Lines

    buf = io.StringIO()
    bar = _Lines(100, "demo", interval=3600.0, stream=buf)
    for _ in range(100):
        bar.update(1)
    assert buf.getvalue() == ""  # nothing before the interval has passed ...
    bar.close()
    assert buf.getvalue().count("\n") == 1 and "100/100" in buf.getvalue()  # ... and one last line


def test_progress_picks_plain_lines_when_output_is_not_a_terminal():
    from stabjax.run.progress import Lines as _Lines, progress_bar as _progress

    assert _progress(False, 10, "x") is None
    bar = _progress(True, 10, "x")  # pytest captures the output: not a terminal
    assert isinstance(bar, _Lines)


def test_wheel_carries_the_licence_and_the_examples(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    cmd = [sys.executable, "-m", "pip", "wheel", str(ROOT), "-w", str(tmp_path), "--no-deps", "-q"]
    # the installed setuptools first (no index needed); an isolated build where it cannot make wheels alone
    built = subprocess.run(cmd + ["--no-build-isolation"], cwd=tmp_path, env=env, capture_output=True)
    if built.returncode != 0:
        subprocess.run(cmd, check=True, cwd=tmp_path, env=env, capture_output=True)
    (wheel,) = tmp_path.glob("stabjax-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    lic = [n for n in names if n.endswith("/LICENSE") and ".dist-info/" in n]
    assert lic and "MIT License" in zipfile.ZipFile(wheel).read(lic[0]).decode()
    for name in ("duffing", "lorenz", "pendulum"):
        for f in ("spec.toml", "model.py"):
            assert f"stabjax/examples/{name}/{f}" in names
