"""Systems from outside the package: spec path, Python API, stabjax.register, entry points; bad models.

The oscillator x'' + (c - k) x' + x = 0 has the closed-form solution used to check the outcomes:
the amplitude sqrt(x^2 + v^2) decays as exp(-(c - k) t / 2) (up to a bounded oscillating factor).
"""
import json
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import stabjax
from stabjax.app.cli import main
from stabjax.errors import ValidationError

HERE = Path(__file__).parents[1]  # tests/
MODEL = HERE / "models" / "oscillator.py"

SPEC = """
system = "model.py:Oscillator"
name = "osc"
[grid]
k = [0.0, 1.0]
[sample]
n = 16
seed = 0
x0 = {dist = "uniform", low = -1.0, high = 1.0}
v0 = {dist = "uniform", low = -1.0, high = 1.0}
[integrate]
t1 = 40.0
n_checkpoints = 200
"""


def _run(argv, capsys):
    """(exit status, printed text) of the CLI run in-process; a normal return is status 0."""
    code = 0
    try:
        main(argv)
    except SystemExit as exc:
        code = exc.code if exc.code is not None else 0
    cap = capsys.readouterr()
    return code, " ".join((cap.out + cap.err).split())  # rich may wrap long lines


@pytest.fixture()
def project(tmp_path):
    shutil.copy(MODEL, tmp_path / "model.py")
    (tmp_path / "spec.toml").write_text(SPEC)
    return tmp_path


def _expect_outcomes(ds):
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert names == ["decays", "grows", "unclassified", "failed"]
    assert list(ds["outcome"].attrs["flag_values"]) == [0, 1, 2, 3]
    # k = 0 < c = 0.5: amplitude ~ exp(-t/4): at t in [30, 40] below 1e-2 for |start| <= sqrt(2)
    # k = 1 > c: grows as exp(t/4) from |start| >= the smallest sampled one: final amplitude > 10
    assert (ds["outcome"].sel(k=0.0).values == 0).all()
    assert (ds["outcome"].sel(k=1.0).values == 1).all()
    np.testing.assert_array_equal(ds["basin_fraction"].sel(k=0.0).values, [1, 0, 0, 0])
    np.testing.assert_array_equal(ds["basin_se"].values, 0.0)


def test_spec_path_relative_to_the_spec(project, capsys, monkeypatch, tmp_path_factory):
    elsewhere = tmp_path_factory.mktemp("cwd")
    monkeypatch.chdir(elsewhere)  # the model path is relative to the spec file, not the working directory
    out = project / "res.nc"
    code, text = _run(["sweep", str(project / "spec.toml"), "--out", str(out), "--no-progress"], capsys)
    assert code == 0, text
    ds = xr.load_dataset(out)
    _expect_outcomes(ds)
    assert "decays" in text and "grows" in text  # the CLI summary uses the system's names
    assert ds.attrs["model_sha256"] == __import__("hashlib").sha256((project / "model.py").read_bytes()).hexdigest()
    assert (project / "res.png").exists()


def test_changed_model_file_changes_the_fingerprint(project):
    from stabjax.plan.spec import load_spec, make_plan

    fp1 = make_plan(load_spec(project / "spec.toml")).fingerprint()
    (project / "model.py").write_text((project / "model.py").read_text() + "\n# edited\n")
    fp2 = make_plan(load_spec(project / "spec.toml")).fingerprint()
    assert fp1 != fp2


def test_python_api_accepts_a_class_and_an_instance(project):
    from stabjax.engines.simulate import simulate
    from stabjax.model.loading import resolve
    from stabjax.run.sweep import run_spec

    cls = type(resolve(f"{project / 'model.py'}:Oscillator"))
    spec = {"system": cls, "grid": {"k": [0.0, 1.0]},
            "sample": {"n": 16, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                       "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
            "integrate": {"t1": 40.0, "n_checkpoints": 200}}
    _expect_outcomes(run_spec(spec))
    spec["system"] = cls()
    _expect_outcomes(run_spec(spec))
    traj = simulate(cls, {"k": 0.0, "x0": 1.0, "v0": 0.0}, t1=10.0, ts=np.linspace(0, 10, 11))
    # x'' + 0.5 x' + x = 0, x(0) = 1, v(0) = 0: x = e^{-t/4} (cos wt + sin(wt) / (4 w)), w = sqrt(15)/4
    t = traj.t.values
    w = np.sqrt(15) / 4
    # the error bound follows from the solver's: each accepted step errs by at most
    # sqrt(n) (atol + rtol max|y|) (RMS error norm), carried to the end by the linear flow, whose
    # gain is kappa = max ||exp(A t)||_2 over the horizon; so n_steps * kappa * that
    from scipy.linalg import expm

    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    kappa = max(np.linalg.norm(expm(A * s_), 2) for s_ in np.linspace(0, 10, 201))
    bound = traj.attrs["n_steps"] * kappa * np.sqrt(2) * (1e-12 + 1e-10 * 1.0)
    np.testing.assert_allclose(traj["x"].values, np.exp(-t / 4) * (np.cos(w * t) + np.sin(w * t) / (4 * w)),
                               rtol=0, atol=bound)
    assert bound < 1e-6  # still a sharp check of the model
    # every variable labelled; the observable x is the state component x, one variable that says so
    assert traj["v"].attrs["long_name"] == "state component v"
    assert traj["x"].attrs["long_name"] == "state component x: displacement (also an observable)"
    assert traj["amplitude"].attrs["long_name"] == "sqrt(x^2 + v^2)"


def test_register_for_the_running_process(project, capsys, monkeypatch):
    from stabjax.model import registry
    from stabjax.model.loading import resolve

    cls = type(resolve(f"{project / 'model.py'}:Oscillator"))
    monkeypatch.setattr(registry, "_registered", {})
    monkeypatch.setattr(registry, "_cache", dict(registry._cache))
    stabjax.register("my_osc", cls)
    assert "my_osc" in stabjax.list_systems()
    with pytest.raises(ValidationError, match="already registered"):
        stabjax.register("my_osc", cls)
    with pytest.raises(ValidationError, match="built-in"):
        stabjax.register("monoaxial", cls)
    (project / "spec2.toml").write_text(SPEC.replace('"model.py:Oscillator"', '"my_osc"'))
    from stabjax.run.sweep import run_spec

    _expect_outcomes(run_spec(project / "spec2.toml"))


def test_entry_point_of_an_installed_distribution(tmp_path, capsys, monkeypatch):
    """A distribution on sys.path with ``[stabjax.systems] damped = "osc_pkg.model:Oscillator"``."""
    pkg = tmp_path / "osc_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    shutil.copy(MODEL, pkg / "model.py")
    dist = tmp_path / "osc_pkg-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: osc-pkg\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[stabjax.systems]\ndamped = osc_pkg.model:Oscillator\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    from stabjax.model import registry

    monkeypatch.setattr(registry, "_cache", dict(registry._cache))
    assert registry.lookup("damped") == "entry point"
    code, text = _run(["systems", "--json"], capsys)
    assert code == 0
    listed = json.loads(text)
    assert listed["damped"]["source"] == "entry point" and "monoaxial" in listed
    code, text = _run(["systems", "damped"], capsys)
    assert code == 0 and "decays" in text and "feedback gain" in text
    (tmp_path / "spec.toml").write_text(SPEC.replace('"model.py:Oscillator"', '"damped"'))
    from stabjax.run.sweep import run_spec

    _expect_outcomes(run_spec(tmp_path / "spec.toml"))


def test_systems_name_describes_a_builtin(capsys):
    code, text = _run(["systems", "monoaxial"], capsys)
    assert code == 0
    assert "alpha" in text and "converged" in text and "Traceback" not in text
    code, text = _run(["systems", "no_such_system"], capsys)
    assert code == 2 and "unknown system" in text and "Traceback" not in text


# ---- bad model files: each a clear error naming the file and the member, exit 2, nothing written ----

GOOD = MODEL.read_text()


def _with_theory(returned: str) -> str:
    """The oscillator with a theory() returning ``returned`` (``c``: the damping of the batch)."""
    return GOOD.replace("from stabjax import Outcomes, Param, ParamSet, System",
                        "import numpy as np\nfrom stabjax import Outcomes, Param, ParamSet, Predicate, System, Theory") \
        .replace("    def initial_state(self, p):", "    def theory(self, p):\n        c = np.asarray(p['c'], float)\n"
                 f"        return {returned}\n\n    def initial_state(self, p):", 1)
BAD = {
    "missing_file": (None, "model file not found"),
    "no_class": (GOOD.replace("class Oscillator(System)", "class Other(System)"), "no class 'Oscillator'"),
    "not_a_system": (GOOD.replace("class Oscillator(System)", "class Oscillator"), "not a stabjax.System"),
    "syntax": (GOOD + "\ndef broken(:\n", "importing the model failed"),
    "rhs_shape": (GOOD.replace("return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])",
                               "return jnp.stack([y[1], y[0], y[0]])"), "Oscillator.rhs: returned shape (3,)"),
    "rhs_dtype": (GOOD.replace("return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])",
                               "return jnp.array([1, 2])"), "Oscillator.rhs: returned dtype int"),
    "rhs_float32": (GOOD.replace("return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])",
                                 "return jnp.stack([y[1], -y[0]]).astype(jnp.float32)"),
                    "Oscillator.rhs: returned dtype float32; stabjax integrates in float64"),
    "rhs_raises": (GOOD.replace("return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])",
                                "raise RuntimeError('boom')"), "Oscillator.rhs: raised RuntimeError: boom"),
    "observe_shape": (GOOD.replace("return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2), y[0]])",
                                   "return y[0]"), "Oscillator.observe: returned shape ()"),
    "nan_default": (GOOD.replace('Param("c", 0.5, "damping")', 'Param("c", float("nan"), "damping")'),
                    "Oscillator.params.c"),
    "kind_misspelt": (GOOD.replace('kind="initial"', 'kind="initail"'), "'initail' is not a kind of parameter; choose one of 'model', 'initial'"),
    "no_rhs": (GOOD.replace("    def rhs(self, t, y, p):\n        return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])\n", ""),
               "Oscillator defines no rhs(self, t, y, args): every model must"),
    "duplicate_param": (GOOD.replace('Param("k", 0.0,', 'Param("c", 0.0,'), "declared twice: c"),
    "reserved_param": (GOOD.replace('Param("k", 0.0,', 'Param("sample", 0.0,').replace('p["k"]', 'p["sample"]'),
                       "clash with dataset names"),
    "bad_rule": (GOOD.replace('"max(amplitude) < 1e-2"', '"max(nope) < 1e-2"'), "outcomes.rules.decays"),
    "python_if": (GOOD.replace("return jnp.stack([y[1], -(p[\"c\"] - p[\"k\"]) * y[1] - y[0]])",
                               "return jnp.stack([y[1], -y[0]]) if y[0] > 0 else jnp.stack([y[1], y[0]])"),
                  "cannot be traced by JAX"),
    # the observable x replaced the state x in a trajectory's dataset (one variable per name)
    "observable_named_as_state": (GOOD.replace("return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2), y[0]])",
                                               "return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2), y[0] ** 2])"),
                                  "observable 'x' has the name of a state component but observes something else"),
    # a wrong theory() was a traceback after the first chunk had run, leaving a store behind
    **{f"theory_{case}": (_with_theory(body), needle) for case, (body, needle) in {
        "shape": ('Theory(predicates={"t": Predicate(np.ones(3, bool), np.ones(3), "t")}, main="t")',
                  "predicates.t.ok has shape (3,) for a batch of 2"),
        "keepdims": ('Theory(predicates={"t": Predicate(c[..., None] > 0, c[..., None], "t")}, main="t")',
                     "predicates.t.ok has shape (2, 1)"),
        "derived": ('Theory(predicates={}, derived={"r": np.ones(7)})', "derived.r has shape (7,)"),
        "dict": ('{"t": c > 0}', "returned a dict; expected a stabjax.Theory"),
        "main": ('Theory(predicates={"t": Predicate(c > 0, c, "t")}, main="nosuch")',
                 "main = 'nosuch' is not one of its predicates (t)"),
        "raises": ('{}["oops"]', "Oscillator.theory: raised KeyError: 'oops'"),
        # a misspelt guaranteed outcome would count every guaranteed trajectory a red flag
        "outcome": ('Theory(predicates={"t": Predicate(c > 0, c, "t", outcome="decay")}, main="t")',
                    "predicate 't' guarantees outcome 'decay', which is not one of the model's outcomes (decays, "),
    }.items()},
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_model_file(case, tmp_path, capsys):
    text, needle = BAD[case]
    if text is not None:
        (tmp_path / "model.py").write_text(text)
    (tmp_path / "spec.toml").write_text(SPEC)
    out = tmp_path / "res.nc"
    out.write_bytes(b"an earlier result")  # must survive the failed run
    code, msg = _run(["sweep", str(tmp_path / "spec.toml"), "--out", str(out), "--no-progress"], capsys)
    assert code == 2, msg
    assert needle in msg, msg
    assert "model.py" in msg, msg
    assert "Traceback" not in msg
    assert out.read_bytes() == b"an earlier result"
    assert not (tmp_path / "res.nc.zarr").exists() and not (tmp_path / "res.png").exists()


def test_observables_without_descriptions_are_described_by_their_names(tmp_path):
    """A model that declares its observables but not observable_doc inherited the base class's ("error metric",
    "size"), which labelled amplitude and x so in `stabjax systems`, simulate and the figures."""
    from stabjax.model.loading import resolve

    text = GOOD.replace('    observable_doc = ("sqrt(x^2 + v^2)", "displacement")\n', "")
    assert text != GOOD
    (tmp_path / "model.py").write_text(text)
    system = resolve(f"{tmp_path / 'model.py'}:Oscillator")
    assert tuple(system.observable_doc) == ("amplitude", "x")


def test_model_reference_forms():
    from stabjax.model.loading import resolve

    with pytest.raises(ValidationError, match="cannot import module"):
        resolve("no_such_module_xyz:Model")
    with pytest.raises(ValidationError, match="has no attribute"):
        resolve("stabjax.systems.monoaxial:Nope")
    with pytest.raises(ValidationError, match="must be a system name"):
        resolve(42)
    assert resolve("stabjax.systems.monoaxial:Monoaxial").state_size == 6
    with pytest.raises(ValidationError, match=r"monoaxial:__name__ is a str \('stabjax.systems.monoaxial'\), not a class"):
        resolve("stabjax.systems.monoaxial:__name__")


def test_model_references_that_are_not_model_files_say_what_they_are(tmp_path):
    """A text file, a folder, a binary file and a name bound to a number: each refused saying what it is, not
    with importlib's reading of it ('No module named notes', a relative import, 'line None')."""
    from stabjax.model.loading import resolve

    (tmp_path / "notes.txt").write_text("x = 1\n")
    (tmp_path / "five.py").write_text("X = 5\n")
    (tmp_path / "blob.py").write_bytes(b"a\0b")
    for ref, needle in [("notes.txt:X", "notes.txt: a model file must be a Python file (.py)"),
                        (".:X", "is a folder: a model is given as 'file.py:Class'"),
                        ("five.py:X", "five.py: X is an int (5), not a class"),
                        ("blob.py:X", "blob.py: not a Python source file (it holds NUL bytes)")]:
        with pytest.raises(ValidationError) as exc:
            resolve(ref, base_dir=tmp_path)
        assert exc.value.field == "system" and needle in exc.value.message, (ref, exc.value.message)
