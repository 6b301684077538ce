"""A model split into files, and models that misbehave while they load (issue 22, items 4, 13, 14).

The model is the oscillator of tests/models/oscillator.py, x' = v, v' = -(c - k) v - x, with its
right-hand side moved into a module beside it (``helpers.py``). Its closed form (amplitude decays as
exp(-(c - k) t / 2)) gives the outcomes the tests expect: k = 0 < c decays, k = 1 > c grows; a helper
edited to ignore k makes both decay.
"""
import hashlib
import json
import time

import numpy as np
import pytest
import xarray as xr

from stabjax.run import store as S
from stabjax.app.cli import main
from stabjax.run.sweep import run_spec

MODEL = '''
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System
from helpers import damped_rhs


class Oscillator(System):
    params = ParamSet((
        Param("c", 0.5, "damping"),
        Param("k", 0.0, "feedback gain (destabilising)"),
        Param("x0", 1.0, "initial displacement", kind="initial"),
        Param("v0", 0.0, "initial velocity", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("amplitude", "x")
    observable_doc = ("sqrt(x^2 + v^2)", "displacement")
    default_t1 = 40.0
    outcomes = Outcomes(rules={"decays": "max(amplitude) < 1e-2", "grows": "final(amplitude) > 10"}, window=0.25)

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["v0"]])

    def rhs(self, t, y, p):
        return damped_rhs(y, p)

    def observe(self, t, y, p):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2), y[0]])
'''
HELPER = '''
import jax.numpy as jnp


def damped_rhs(y, p):
    return jnp.stack([y[1], -(p["c"] - p["k"]) * y[1] - y[0]])
'''
HELPER_NO_FEEDBACK = HELPER.replace('-(p["c"] - p["k"])', '-p["c"]')
SPEC = """
system = "model.py:Oscillator"
name = "split"
[grid]
k = [0.0, 1.0]
[sample]
n = 8
seed = 0
x0 = {dist = "uniform", low = -1.0, high = 1.0}
v0 = {dist = "uniform", low = -1.0, high = 1.0}
[integrate]
t1 = 40.0
n_checkpoints = 200
"""


def _run(argv, capsys):
    code = 0
    try:
        main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code if exc.code is not None else 0
    cap = capsys.readouterr()
    return code, " ".join((cap.out + cap.err).split())


@pytest.fixture()
def project(tmp_path):
    (tmp_path / "model.py").write_text(MODEL)
    (tmp_path / "helpers.py").write_text(HELPER)
    (tmp_path / "spec.toml").write_text(SPEC)
    return tmp_path


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_model_imports_a_module_beside_it_and_the_result_records_both(project, capsys):
    """Fails if the model's folder is not on the import path while it loads (ModuleNotFoundError),
    or if the dataset does not record the helper with the sha256 of its bytes."""
    out = project / "res.nc"
    code, text = _run(["sweep", project / "spec.toml", "--out", out, "--no-progress", "--no-plot"], capsys)
    assert code == 0, text
    ds = xr.load_dataset(out)
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert (ds["outcome"].sel(k=0.0).values == names.index("decays")).all()
    assert (ds["outcome"].sel(k=1.0).values == names.index("grows")).all()
    sources = json.loads(ds.attrs["model_sources_json"])
    assert sources == {str((project / "model.py").resolve()): _sha(project / "model.py"),
                       str((project / "helpers.py").resolve()): _sha(project / "helpers.py")}
    assert ds.attrs["model_sha256"] == _sha(project / "model.py")
    import sys

    assert str(project) not in sys.path  # only while the model loads


def test_helper_edited_between_kill_and_resume_is_refused_then_recomputed(project):
    """Two chunks of four are stored; the helper then changes the dynamics (no feedback: every
    trajectory decays). Resuming must refuse naming the helper; --restart recomputes everything
    with the new helper. Fails if the identity hashes only the model file (the resume would mix
    two models: k = 1 'grows' from the old chunks, 'decays' from the new) or if this process kept
    serving the old helper from its module cache."""
    out = project / "res.nc"

    def stop_after_two(i, n):
        if i == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(project / "spec.toml", out, batch_size=4, on_chunk=stop_after_two)
    store = project / "res.nc.zarr"
    assert len(S.read_manifest(store)["chunks"]) == 2
    (project / "helpers.py").write_text(HELPER_NO_FEEDBACK)
    with pytest.raises(S.StoreError, match=r"model module helpers\.py \(imported by model\.py\)"):
        run_spec(project / "spec.toml", out, batch_size=4)
    ds = run_spec(project / "spec.toml", out, batch_size=4, restart=True)
    assert ds.attrs["chunks_resumed"] == 0
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert (ds["outcome"].values == names.index("decays")).all()  # without feedback k does not matter
    assert json.loads(ds.attrs["model_sources_json"])[str((project / "helpers.py").resolve())] == \
        _sha(project / "helpers.py")


def test_editing_a_helper_changes_the_fingerprint(project):
    from stabjax.plan.spec import load_spec, make_plan

    fp1 = make_plan(load_spec(project / "spec.toml")).fingerprint()
    (project / "helpers.py").write_text(HELPER + "\n# edited\n")
    fp2 = make_plan(load_spec(project / "spec.toml")).fingerprint()
    (project / "helpers.py").write_text(HELPER)
    assert fp1 != fp2 and make_plan(load_spec(project / "spec.toml")).fingerprint() == fp1


def _exiting_model(project, call: str, where: str) -> str:
    """Write a model that calls ``call`` (``sys.exit(0)``, ``os._exit(0)``) at import or in rhs; what the
    error must name besides the call."""
    module = call.split(".")[0]
    if where == "import":
        (project / "model.py").write_text(f"import {module}\n{call}\n" + MODEL)
        return "model.py"
    (project / "model.py").write_text(MODEL.replace("return damped_rhs(y, p)", f"import {module}; {call}"))
    return "Oscillator.rhs: raised"


@pytest.mark.parametrize("where", ["import", "rhs"])
def test_sys_exit_in_a_model_is_a_model_error(project, capsys, where):
    """A model calling sys.exit(0) must not end the program with status 0 and no output."""
    needle = _exiting_model(project, "sys.exit(0)", where)
    out = project / "res.nc"
    code, text = _run(["sweep", project / "spec.toml", "--out", out, "--no-progress", "--no-plot"], capsys)
    assert code == 2, text
    assert needle in text and "sys.exit(0)" in text and "model.py" in text and "Traceback" not in text
    assert not out.exists()


@pytest.mark.parametrize("where", ["import", "rhs"])
def test_os_exit_in_a_model_is_a_model_error(project, where):
    """``os._exit(0)`` ends a process past every handler: unguarded, the sweep would exit 0 with nothing
    written. Run in a child process, so that a regression ends the child (status 0, no message: this
    test fails) and not the test run."""
    import os
    import subprocess
    import sys

    needle = _exiting_model(project, "os._exit(0)", where)
    if where == "import":
        needle = "line 2 of model.py"
    out = project / "res.nc"
    r = subprocess.run([sys.executable, "-m", "stabjax", "sweep", str(project / "spec.toml"), "--out", str(out),
                        "--no-progress", "--no-plot"], capture_output=True, text=True, timeout=300,
                       env={**os.environ, "JAX_PLATFORMS": "cpu"})
    text = r.stdout + r.stderr
    assert r.returncode == 2, text
    assert "os._exit(0)" in text and needle in text and "Traceback" not in text
    assert not out.exists()


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # the child only calls os._exit: no lock to meet
def test_the_exit_guard_lets_a_forked_child_exit():
    """Inside the guard a forked child still ends with its own ``os._exit`` (multiprocessing's way),
    and the guard is gone after the block."""
    import os

    from stabjax.model.loading import no_exit

    real = os._exit
    with no_exit():
        assert os._exit is not real
        pid = os.fork()
        if pid == 0:
            os._exit(7)
        _, status = os.waitpid(pid, 0)
        with pytest.raises(Exception, match="os._exit"):
            os._exit(0)
    assert os.waitstatus_to_exitcode(status) == 7 and os._exit is real


@pytest.mark.parametrize("where", ["import", "rhs"])
def test_a_model_that_never_returns_is_stopped_by_the_time_limit(project, capsys, monkeypatch, where):
    """A loop that never ends at import or in rhs: exit 2 within the limit (1 s here), naming the model."""
    monkeypatch.setenv("STABJAX_MODEL_TIMEOUT", "1")
    if where == "import":
        (project / "model.py").write_text("while True:\n    pass\n" + MODEL)
        needle = "importing the model did not finish within 1 s"
    else:
        (project / "model.py").write_text(MODEL.replace("return damped_rhs(y, p)",
                                                        "while True:\n            pass"))
        needle = "checking the model (running and tracing its members) did not finish within 1 s"
    t0 = time.monotonic()
    code, text = _run(["sweep", project / "spec.toml", "--out", project / "res.nc", "--no-progress", "--no-plot"],
                      capsys)
    assert code == 2, text
    assert time.monotonic() - t0 < 30
    assert needle in text and "model.py" in text and "STABJAX_MODEL_TIMEOUT" in text


def test_bad_model_timeout_setting_is_named(project, capsys, monkeypatch):
    monkeypatch.setenv("STABJAX_MODEL_TIMEOUT", "soon")
    code, text = _run(["sweep", project / "spec.toml", "--out", project / "res.nc", "--no-progress", "--no-plot"],
                      capsys)
    assert code == 2 and "STABJAX_MODEL_TIMEOUT" in text and "'soon'" in text, text
    np.testing.assert_equal(sorted(p.name for p in project.iterdir()), ["helpers.py", "model.py", "spec.toml"])


def test_a_module_class_model_records_its_local_imports(tmp_path, monkeypatch):
    """``package.module:Class`` from the user's own package (on sys.path, not installed): the identity
    covers the module, its package and the module it imports. Fails if only the defining file is
    hashed (an edited helper would then go unnoticed)."""
    import sys

    from stabjax.plan.identity import changed_sources, model_sources, provenance
    from stabjax.model.loading import resolve
    from stabjax.plan.spec import make_plan

    pkg = tmp_path / "stabjax_test_userpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "helpers.py").write_text(HELPER)
    (pkg / "osc.py").write_text(MODEL.replace("from helpers import", "from stabjax_test_userpkg.helpers import"))
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in sys.modules if m.startswith("stabjax_test_userpkg")]:
        monkeypatch.delitem(sys.modules, name)
    try:
        system = resolve("stabjax_test_userpkg.osc:Oscillator")
        src = model_sources(system)
        assert src == {str((pkg / f).resolve()): _sha(pkg / f) for f in ("osc.py", "__init__.py", "helpers.py")}
        assert list(src)[0] == str((pkg / "osc.py").resolve())  # the defining file first
        # this process keeps running the helper it imported, and its identity says so; a result of it
        # warns once the file on disk differs (a new process would refuse to resume: other hashes)
        attrs = provenance(make_plan({"system": "stabjax_test_userpkg.osc:Oscillator", "grid": {"k": [0.0]}}))
        assert changed_sources(attrs) == []
        (pkg / "helpers.py").write_text(HELPER + "\n# edited\n")
        changed = changed_sources(attrs)
        assert len(changed) == 1 and changed[0].startswith(str((pkg / "helpers.py").resolve()))
    finally:
        for name in [m for m in sys.modules if m.startswith("stabjax_test_userpkg")]:
            sys.modules.pop(name, None)


@pytest.mark.slow  # three CLI processes (~30 s on 2 busy cores)
def test_helper_edited_between_kill_9_and_resume_in_new_processes(project):
    """The user's sequence: a sweep killed with SIGKILL, the helper edited, the same command again
    (a fresh process, which imports the edited helper): refused with status 2 naming the helper and
    the store untouched; with --restart every chunk is computed with the new helper (all decay)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from killing import kill_after_chunks

    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root), JAX_PLATFORMS="cpu", STABJAX_THREADS="1")
    cmd = [sys.executable, "-m", "stabjax", "sweep", str(project / "spec.toml"), "--out", str(project / "res.nc"),
           "--batch-size", "4", "--no-progress", "--no-plot"]
    store = project / "res.nc.zarr"
    p = subprocess.Popen(cmd, env={**env, "_STABJAX_TEST_CHUNK_SLEEP": "0.7"}, cwd=project,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kill_after_chunks(p, store, 1, 120)
    done = len(S.read_manifest(store)["chunks"])
    assert 1 <= done < 4
    (project / "helpers.py").write_text(HELPER_NO_FEEDBACK)
    manifest = (store / "manifest.json").read_bytes()
    r = subprocess.run(cmd, env=env, cwd=project, capture_output=True, text=True, timeout=180)
    err = " ".join(r.stderr.split())
    assert r.returncode == 2 and "model module helpers.py (imported by model.py)" in err, err
    assert (store / "manifest.json").read_bytes() == manifest
    r = subprocess.run(cmd + ["--restart"], env=env, cwd=project, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    ds = xr.load_dataset(project / "res.nc")
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert ds.attrs["chunks_resumed"] == 0 and (ds["outcome"].values == names.index("decays")).all()
