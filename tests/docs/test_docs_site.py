"""The documentation site builds with warnings as errors, its API reference holds every public name, and the
README stays a front page: short, its two set-up commands those of CI, its Python on the public API."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def test_site_builds_strict(tmp_path):
    """`mkdocs build --strict` (CI's only build of the site): a broken link or anchor, a docstring mkdocstrings cannot
    render, a settings table whose code declaration gained a setting without a stated meaning, or a public name
    that does not resolve fails the build. The API pages then hold an entry for every name of stabjax._API."""
    import stabjax

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "NO_MKDOCS_2_WARNING": "1", "JAX_PLATFORMS": "cpu"}
    site = tmp_path / "site"
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    api = (site / "api" / "index.html").read_text() + (site / "api" / "model" / "index.html").read_text()
    missing = [n for n in stabjax._API if f'id="stabjax.{n}"' not in api]
    assert not missing, f"public names without an entry in the API reference: {missing}"
    # the generated tables are there, with a setting of each source
    specs = (site / "guide" / "specs" / "index.html").read_text()
    for name in ("n_checkpoints", "converged_tol", "max_distance", "min_samples", "rel_tol", "lanes", "half_angle"):
        assert f"<code>{name}</code>" in specs, name
    # the images the pages show from outside docs/ are copied into the site
    assert (site / "repo" / "results" / "default.png").is_file()


def _set_up_commands() -> list[str]:
    text = README.read_text()
    section = text.split("\n## Set up\n", 1)[1].split("\n## ", 1)[0]
    return [b.strip() for b in re.findall(r"^```bash\n(.*?)^```", section, re.M | re.S)]


def test_readme_is_a_front_page():
    """At most ~250 lines; no performance history (sessions, commits) on it; its Python uses the public API."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    assert not re.search(r"\bsession \d+|\bat [0-9a-f]{7}\b", text), "performance history belongs on the site"
    python = "\n".join(re.findall(r"^```python[^\n]*\n(.*?)^```", text, re.M | re.S))
    assert python, "the README shows stabjax used from Python"
    assert not re.search(r"^\s*(from|import) stabjax\.", python, re.M), "the README's Python imports submodules"


def test_readme_set_up_is_two_commands_and_the_second_is_ci():
    """Exactly two set-up commands: install and run the main job; install and run the tests with the pytest
    command of .ci/run (so the README's promise and CI cannot part)."""
    first, second = _set_up_commands()
    assert first == "pip install -e . && python -m stabjax sweep sweeps/default.toml"
    install, _, test = second.partition(" && ")
    assert install == 'pip install -e ".[test]"'
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r'pip install (-q )?-e "\.\[test\]"', ci), "CI installs the test extra"
    ci_line = next(shlex.split(ln) for ln in ci.splitlines() if "-m pytest " in ln and not ln.lstrip().startswith("#"))
    readme_line = shlex.split(test)
    assert readme_line[:3] == ["python", "-m", "pytest"]
    assert readme_line[3:] == ci_line[ci_line.index("pytest") + 1:], (readme_line, ci_line)


def test_parameter_tables_are_the_registrys():
    """The parameter tables of the papers' pages are what docs/models/params_tables.py generates from the
    registry now (a parameter renamed, added or re-documented in the code without regenerating them fails)."""
    import runpy

    gen = runpy.run_path(str(ROOT / "docs" / "models" / "params_tables.py"))
    for group, names in gen["groups"].items():
        text = (ROOT / "docs" / "models" / f"{group}.md").read_text()
        assert f"<!-- params:{group} -->\n{gen['table'](names)}\n" in text, \
            f"docs/models/{group}.md: run `python docs/models/params_tables.py` from the top of the repository"
