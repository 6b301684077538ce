"""The sweep specs ship inside the package and are found without the repository: importlib.resources
in the package, a `sweeps` link at the top of a clone, and (slow) a built wheel installed in a fresh
virtual environment running `stabjax reproduce at2019 --quick` from another directory."""
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from stabjax.reproduce import load_shipped, shipped_specs, sweeps_dir
from stabjax.plan.spec import make_plan

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "stabjax"


def test_every_shipped_spec_is_found_and_resolves_to_a_plan():
    names = shipped_specs()
    on_disk = sorted(p.stem for p in (PACKAGE / "sweeps").glob("*.toml"))
    assert names == on_disk and len(names) >= 25
    for prefix in ("at2019_", "saakyan_", "twobody_", "gyrodyne_"):
        assert any(n.startswith(prefix) for n in names), prefix
    for name in names:
        spec = load_shipped(name)
        assert spec["name"] == tomllib.loads((PACKAGE / "sweeps" / f"{name}.toml").read_text()).get("name", name)
        plan = make_plan(spec)
        assert plan.size >= 1


def test_a_missing_shipped_spec_is_a_validation_error():
    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError) as exc:
        load_shipped("no_such_spec")
    assert exc.value.field == "spec"


def test_top_level_sweeps_is_the_package_directory():
    # README commands (`stabjax sweep sweeps/default.toml`) run in a clone through this link
    top = ROOT / "sweeps"
    assert top.is_symlink() and top.resolve() == (PACKAGE / "sweeps").resolve()
    assert Path(str(sweeps_dir())).resolve() == (PACKAGE / "sweeps").resolve()


def test_pyproject_ships_the_specs_as_package_data():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "sweeps/*.toml" in cfg["tool"]["setuptools"]["package-data"]["stabjax"]


def test_no_module_loads_files_by_repository_relative_path():
    # a path climbing out of the package breaks in an installed wheel
    bad = re.compile(r"parents\[[1-9]\]|parent\.parent|\.\./")
    offenders = [f"{p.relative_to(ROOT)}:{i}" for p in PACKAGE.rglob("*.py")
                 for i, line in enumerate(p.read_text().splitlines(), 1) if bad.search(line)]
    assert not offenders, offenders


@pytest.mark.slow  # builds a wheel and a venv: ~30-60 s on 2 cores
def test_installed_wheel_reproduces_from_another_directory(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["JAX_PLATFORMS"] = "cpu"
    whl = tmp_path / "whl"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "-w", str(whl), "--no-deps", "-q"],
                   check=True, cwd=tmp_path, env=env)
    (wheel,) = whl.glob("stabjax-*.whl")
    venv = tmp_path / "venv"
    # jax etc. from the interpreter running the tests (a .pth line: its packages, not its .pth hooks, so an
    # editable stabjax there is not importable; --system-site-packages would reach the base interpreter, which
    # has no jax when the tests run in a virtual environment); --ignore-installed: only the wheel counts
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, env=env)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    import sysconfig

    here = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(site) / "tests-parent.pth").write_text("\n".join(sorted(here)) + "\n")
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--ignore-installed", str(wheel)],
                   check=True, cwd=tmp_path, env=env)
    run_dir = tmp_path / "elsewhere"
    run_dir.mkdir()
    where = subprocess.run([str(py), "-c", "import stabjax, stabjax.reproduce as r; print(stabjax.__file__);"
                            "print(len(r.shipped_specs()), r.load_shipped('default')['system'])"],
                           cwd=run_dir, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert where[0].startswith(str(venv)) and int(where[1]) >= 25 and where[2] == "monoaxial"
    out = subprocess.run([str(venv / "bin" / "stabjax"), "reproduce", "at2019", "--quick", "--out-dir", "figs"],
                         cwd=run_dir, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (run_dir / "figs" / "alpha_sweep.png").stat().st_size > 0


def test_installed_package_holds_no_benchmark_code(tmp_path):
    """setuptools' own build step (what a wheel ships, from pyproject's package config) copies the modules
    of the package and none of the benchmark code (benchmarks/, beside the tests). Fails if a benchmark module
    moves back into stabjax/, if the package finder starts picking up benchmarks/, or if a shipped module
    imports the benchmarks (it would break in an installed wheel)."""
    import shutil

    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("stabjax", "benchmarks", "tests"):  # tests and benchmarks present, as in a clone
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    built = tmp_path / "lib"
    subprocess.run([sys.executable, "-c", "import setuptools; setuptools.setup()", "-q", "build_py",
                    "--build-lib", str(built)], cwd=src, check=True, capture_output=True)
    shipped = sorted(p.relative_to(built).as_posix() for p in built.rglob("*.py"))
    assert "stabjax/run/sweep.py" in shipped and "stabjax/app/cli.py" in shipped and len(shipped) >= 40
    assert [p for p in shipped if not p.startswith("stabjax/")] == []
    names = {Path(p).stem for p in shipped}
    assert not names & {"bench", "bench_models", "refine_bench", "numba_baseline", "dask_bench"}, names
    imports = re.compile(r"^\s*(from|import)\s+(benchmarks|numba)\b", re.M)
    assert [p for p in shipped if imports.search((built / p).read_text())] == []


def test_every_cited_markdown_file_exists():
    """Docs and docstrings cite only Markdown files that exist (an interfaces and a models note were
    cited long after they were gone): looked up from the top, beside the citing file, under docs/ and
    docs/models/, or among the shipped results; a file cited as ``git show COMMIT:path`` lives in history."""
    cite = re.compile(r"(?<![\w/.:-])((?:[\w.-]+/)*[\w.-]+\.md)\b")
    results = {p.name for p in (ROOT / "results").rglob("*.md")}
    # (tests are not read: they name the files they make, e.g. a notes.md in a temporary folder)
    files = [ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *PACKAGE.rglob("*.py"), *(ROOT / "benchmarks").glob("*.py")]
    missing = []
    for f in files:
        for m in cite.finditer(f.read_text()):
            ref = m[1]
            where = [ROOT / ref, f.parent / ref, ROOT / "docs" / ref, ROOT / "docs" / "models" / ref]
            if not any(p.exists() for p in where) and Path(ref).name not in results:
                missing.append(f"{f.relative_to(ROOT)}: {ref}")
    assert not missing, missing
