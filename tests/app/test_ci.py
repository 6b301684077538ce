"""In CI (``$CI`` set) a test that skips because a tool is missing -- the C compiler, Chromium, a package of the
test extra -- fails the run (tests/ci_tools.py, taken in by tests/conftest.py); elsewhere it skips, saying why.
Run on probe tests in a folder of their own, in a fresh pytest process with those hooks alone."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]

PROBE = '''import pytest

@pytest.mark.skipif(True, reason="no working C compiler")
def test_native():
    pass

def test_browser():
    pytest.skip("no Chromium found (apt-get install chromium): browser test skipped")

@pytest.mark.skipif(True, reason="run with the rest of the file")
def test_not_a_tool():
    pass

def test_runs():
    pass
'''
IMPORT = '''import pytest

pytest.importorskip("stabjax_no_such_module")

def test_x():
    pass
'''


@pytest.mark.parametrize("ci", [False, True])
def test_a_missing_tool_fails_in_ci_and_skips_elsewhere(tmp_path, ci):
    (tmp_path / "test_probe.py").write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")])
    env["PYTEST_DISABLE_PLUGIN_AUTOLOAD"] = "1"  # the hooks alone: a second, not the installed plugins' startup
    run = [sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider", "-p", "ci_tools"]
    if ci:
        env["CI"] = "true"
    r = subprocess.run([*run, str(tmp_path / "test_probe.py")], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    last = r.stdout.strip().splitlines()[-1]
    if ci:
        assert r.returncode == 1 and "1 failed, 1 passed, 1 skipped, 1 error" in last, r.stdout
        assert "CI is set and a tool the tests need is missing" in r.stdout
    else:
        assert r.returncode == 0 and "1 passed, 3 skipped" in last, r.stdout
    (tmp_path / "test_probe.py").unlink()
    (tmp_path / "test_import.py").write_text(IMPORT)
    r = subprocess.run([*run, str(tmp_path / "test_import.py")], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    if ci:  # a collection error: the run stops, failed
        assert r.returncode not in (0, 5) and "CI is set and a tool the tests need is missing" in r.stdout, r.stdout
    else:  # the module skipped: nothing ran, nothing failed
        assert r.returncode in (0, 5) and "1 skipped" in r.stdout, r.stdout
