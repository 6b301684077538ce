"""Every bad input answered (issue 18, item 6): a message naming the field, exit status 2, no traceback,
no hang, nothing on disk lost; usage errors print the usage; the exit status tells the truth."""
from __future__ import annotations

import contextlib
import json
import math
import signal
import time
from pathlib import Path

import pytest

import stabjax  # noqa: F401  (float64)
from clirun import TINY, captured  # noqa: E402
from stabjax.errors import ValidationError
from stabjax.validate import eval_number
from stabjax.plan.spec import make_plan



@contextlib.contextmanager
def time_limit(seconds: float):
    """Fail (instead of hanging the suite) when the body runs longer than ``seconds``."""

    def handler(signum, frame):
        raise TimeoutError(f"took longer than {seconds} s")

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def cli(capsys, *args) -> tuple[int, str, str]:
    """Run the CLI in-process; returns (exit status, stdout, stderr) with line wrapping undone."""
    with time_limit(120):
        return captured(capsys, *args)


def assert_clean(out: str, err: str):
    assert "Traceback" not in out + err and "File \"" not in out + err, err


# ---- usage errors -----------------------------------------------------------------------------


@pytest.mark.parametrize("args, says", [
    (["sweep", "--bogus"], "No such option: --bogus"),
    (["bogus"], "No such command 'bogus'"),
    (["theory", "monoaxial", "extra"], "unexpected extra argument"),
    (["sweep", "SPEC", "--batch-size", "x"], "--batch-size"),
    (["sweep", "SPEC", "--batch-size", "2.5"], "--batch-size"),
    (["simulate"], "Missing argument"),
    (["simulate", "monoaxial", "--t1", "soon"], "--t1"),
    (["horizon-check", "X.nc", "--n", "many"], "--n"),
])
def test_usage_errors_print_usage_and_exit_2(tmp_path, capsys, args, says):
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    args = [str(spec) if a == "SPEC" else a for a in args]
    code, out, err = cli(capsys, *args)
    assert code == 2
    assert "Usage:" in err and says in err, err
    assert_clean(out, err)
    assert spec.read_text() == TINY and sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


def test_no_import_of_click():
    """typer 0.29 vendors click as typer._click and no longer installs it: the CLI must not need it."""
    src = (Path(stabjax.__file__).parent / "app" / "cli.py").read_text()
    assert "import click" not in src


# ---- bounded expressions -----------------------------------------------------------------------


@pytest.mark.parametrize("text", [
    "9**9**9", "10**400", "2**-2000", "1e400", "-1e999", "nan", "inf", "exp(1000)", "1/0", "sqrt(-1)",
    "(-8)**(1/3)", "__import__('os').system('true')", "().__class__", "True", "x", "1,2", "lambda: 1",
    "[1]*10**9", "'a'*10**9", "(" * 300 + "1" + ")" * 300, "1+" * 150 + "1", "9" * 400, "",
    "sin(1, 2)", "sqrt(x=4)", "pi()", "1 if 1 else 2",
])
def test_bad_expressions_are_refused_quickly(text):
    t = time.perf_counter()
    with time_limit(5), pytest.raises(ValueError):
        eval_number(text, "x")
    assert time.perf_counter() - t < 1.0


@pytest.mark.parametrize("text, value", [
    ("7/9", 7 / 9), ("1/sqrt(3)", 1 / math.sqrt(3)), ("2*pi", 2 * math.pi), ("-3**2", -9.0), ("2**0.5", math.sqrt(2)),
    ("1e-3*cos(pi/7)", 1e-3 * math.cos(math.pi / 7)), ("+(1.5)", 1.5), ("exp(log(2))", 2.0), ("1e308", 1e308),
])
def test_good_expressions_still_work(text, value):
    assert eval_number(text, "x") == pytest.approx(value, rel=1e-15)


def test_set_expression_that_would_hang_exits_2(capsys):
    code, out, err = cli(capsys, "theory", "monoaxial", "--set", "mu=9**9**9")
    assert code == 2 and "error: mu:" in err and "exponent" in err
    assert_clean(out, err)


# ---- specs: one bad field at a time, each named -------------------------------------------------

M = {"system": "monoaxial"}
CAP = {"dist": "cap", "center": "r", "half_angle": 0.5}
BAD_SPECS = [
    # top level
    ({"system": 1}, "system"),
    ({**M, "bogus": 1}, "bogus"),
    ({**M, "name": "../evil"}, "name"),
    ({**M, "name": 3}, "name"),
    ({**M, "description": 5}, "description"),
    ({**M, "grid": [1, 2]}, "grid"),
    ({**M, "run": 3}, "run"),
    # [params]
    ({**M, "params": {"mu": True}}, "params.mu"),
    ({**M, "params": {"mu": math.nan}}, "params.mu"),
    ({**M, "params": {"mu": "9**9**9"}}, "params.mu"),
    ({**M, "params": {"mu": "__import__('os')"}}, "params.mu"),
    ({**M, "params": {"foo": 1}}, "params.foo"),
    ({**M, "params": {"J": [1, [2, 3]]}}, "params.J"),
    ({**M, "params": {"w0": [1, True, 0]}}, "params.w0"),
    ({**M, "params": {"mu": 10**400}}, "params.mu"),
    # [grid]
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 2.5}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": True}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 0}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 10**12}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": "4"}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": math.nan, "stop": 1, "num": 4}}}, "grid.alpha.start"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": "x", "num": 4}}}, "grid.alpha.stop"),
    ({**M, "grid": {"alpha": {"start": True, "stop": 1, "num": 4}}}, "grid.alpha.start"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": math.inf, "num": 4}}}, "grid.alpha.stop"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 4, "log": 1}}}, "grid.alpha.log"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1}}}, "grid.alpha.num"),
    ({**M, "grid": {"alpha": {"start": 0.3, "num": 4}}}, "grid.alpha.stop"),
    ({**M, "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 4, "step": 0.1}}}, "grid.alpha.step"),
    ({**M, "grid": {"alpha": []}}, "grid.alpha"),
    ({**M, "grid": {"alpha": 0.5}}, "grid.alpha"),
    ({**M, "grid": {"alpha": [0.5, True]}}, "grid.alpha[1]"),
    ({**M, "grid": {"alpha": [0.5, math.inf]}}, "grid.alpha[1]"),
    ({**M, "grid": {"w0": [[0, 0, 0], [1, 1]]}}, "grid.w0[1]"),
    ({**M, "grid": {"J": [[4, 5, 4]], "J[0]": [4.0, 5.0]}}, "grid.J[0]"),
    ({**M, "grid": {"J[0]": [4.0, 5.0], "J": [[4, 5, 4]]}}, "grid.J"),
    ({**M, "grid": {"D[1,1]": [1.0, 2.0], "D[1, 1]": [1.0, 2.0]}}, "grid.D[1, 1]"),
    ({**M, "grid": {"J[7]": [1.0, 2.0]}}, "grid.J[7]"),
    ({**M, "grid": {"nope": [1.0, 2.0]}}, "grid.nope"),
    ({**M, "grid": {"alpha": {"start": -1, "stop": 1, "num": 4, "log": True}}}, "grid.alpha"),
    ({**M, "grid": {a: {"start": 1, "stop": 2, "num": 10**7} for a in ("alpha", "sigma", "b")}}, "grid"),
    ({**M, "grid": {"omega0": {"start": 1, "stop": 2, "num": "x"}}}, "grid.omega0.num"),
    ({**M, "grid": {"normalize": {"start": 0, "stop": 1, "num": 3}}}, "grid.normalize"),  # 0.5: not a choice
    ({**M, "grid": {"normalize": [0, 0.5]}}, "grid.normalize[1]"),
    # [sample]
    ({**M, "sample": {"n": 2.5, "s0": {"dist": "sphere"}}}, "sample.n"),
    ({**M, "sample": {"n": True, "s0": {"dist": "sphere"}}}, "sample.n"),
    ({**M, "sample": {"s0": {"dist": "sphere"}}}, "sample.n"),
    ({**M, "sample": {"n": 10**12, "s0": {"dist": "sphere"}}}, "sample.n"),
    ({**M, "sample": {"n": 4, "seed": -1, "s0": {"dist": "sphere"}}}, "sample.seed"),
    ({**M, "sample": {"n": 4, "seed": 1.5, "s0": {"dist": "sphere"}}}, "sample.seed"),
    ({**M, "sample": {"n": 4, "seed": True, "s0": {"dist": "sphere"}}}, "sample.seed"),
    ({**M, "sample": {"n": 4}}, "sample"),
    ({**M, "sample": {"n": 4, "s0": "sphere"}}, "sample.s0"),
    ({**M, "sample": {"n": 4, "s0": {"center": "r"}}}, "sample.s0.dist"),
    ({**M, "sample": {"n": 4, "s0": {"dist": "banana"}}}, "sample.s0.dist"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "half_angle": math.nan}}}, "sample.s0.half_angle"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "half_angle": 9}}}, "sample.s0.half_angle"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "half_angle": True}}}, "sample.s0.half_angle"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "center": "alpha"}}}, "sample.s0.center"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "center": "w0"}, "w0": {"dist": "ball", "radius": 1}}},
     "sample.s0.center"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "center": [1, 0]}}}, "sample.s0.center"),
    ({**M, "sample": {"n": 4, "s0": {**CAP, "extra": 1}}}, "sample.s0.extra"),
    ({**M, "sample": {"n": 4, "s0": {"dist": "cap", "center": "r"}}}, "sample.s0.half_angle"),
    ({**M, "sample": {"n": 4, "s0": {"dist": "uniform", "low": 0, "high": math.inf}}}, "sample.s0.high"),
    ({**M, "sample": {"n": 4, "b": {"dist": "uniform", "low": 2, "high": 1}}}, "sample.b.high"),
    ({**M, "sample": {"n": 4, "w0": {"dist": "normal", "mean": 0, "std": -1}}}, "sample.w0.std"),
    ({**M, "sample": {"n": 4, "w0": {"dist": "normal", "mean": "x", "std": 1}}}, "sample.w0.mean"),
    ({**M, "sample": {"n": 4, "w0": {"dist": "ball", "radius": True}}}, "sample.w0.radius"),
    ({**M, "sample": {"n": 4, "w0": {"dist": "ball", "radius": 1, "center": [0, 0]}}}, "sample.w0.center"),
    ({**M, "sample": {"n": 4, "w0": {"dist": "ball", "radius": 1, "center": [0, math.nan, 0]}}}, "sample.w0.center[1]"),
    ({**M, "sample": {"n": 4, "alpha": {"dist": "sphere"}}}, "sample.alpha.dist"),
    ({**M, "sample": {"n": 4, "J": {"dist": "so3"}}}, "sample.J.dist"),
    ({**M, "sample": {"n": 4, "nope": {"dist": "sphere"}}}, "sample.nope"),
    # 10^12 trajectories: their results alone need 192 TB; refused from the sizes, before any draw
    ({**M, "grid": {"alpha": {"start": 0.1, "stop": 1, "num": 10**6}},
      "sample": {"n": 10**6, "s0": {"dist": "sphere"}}}, "grid"),
    ({**M, "sample": {"n": 10**8 + 1, "s0": {"dist": "sphere"}}}, "sample.n"),
    ({**M, "grid": {"alpha": [0.5]}, "sample": {"n": 4, "alpha": {"dist": "uniform", "low": 0, "high": 1}}},
     "sample.alpha"),
    # [integrate]
    ({**M, "integrate": 3}, "integrate"),
    ({**M, "integrate": {"t1": math.nan}}, "integrate.t1"),
    ({**M, "integrate": {"t1": -5}}, "integrate.t1"),
    ({**M, "integrate": {"t0": math.inf}}, "integrate.t0"),
    ({**M, "integrate": {"t0": True}}, "integrate.t0"),
    ({**M, "integrate": {"dt0": -1}}, "integrate.dt0"),
    ({**M, "integrate": {"dt0": math.nan}}, "integrate.dt0"),
    ({**M, "integrate": {"max_steps": 1.5}}, "integrate.max_steps"),
    ({**M, "integrate": {"max_steps": 1e12}}, "integrate.max_steps"),
    ({**M, "integrate": {"max_steps": True}}, "integrate.max_steps"),
    ({**M, "integrate": {"n_checkpoints": "100"}}, "integrate.n_checkpoints"),
    ({**M, "integrate": {"n_checkpoints": 4}}, "integrate.n_checkpoints"),
    ({**M, "integrate": {"rtol": True}}, "integrate.rtol"),
    ({**M, "integrate": {"atol": 0}}, "integrate.atol"),
    ({**M, "integrate": {"solver": 5}}, "integrate.solver"),
    ({**M, "integrate": {"solver": "euler9"}}, "integrate.solver"),
    ({**M, "integrate": {"engine": "gpu9"}}, "integrate.engine"),
    ({**M, "integrate": {"lanes": -1}}, "integrate.lanes"),
    ({**M, "integrate": {"lanes": 2.5}}, "integrate.lanes"),
    ({**M, "integrate": {"lanes": 10**12}}, "integrate.lanes"),
    ({**M, "integrate": {"foo": 1}}, "integrate.foo"),
    ({**M, "integrate": {"settings": {"threads": 1}}}, "integrate.settings"),
    # [engine]: the engines' declared settings (stabjax.engines.SETTINGS)
    ({**M, "engine": 3}, "engine"),
    ({**M, "engine": {"foo": 1}}, "engine.foo"),
    ({**M, "engine": {"threads": -1}}, "engine.threads"),
    ({**M, "engine": {"width": 2.5}}, "engine.width"),
    ({**M, "engine": {"lanes": 2**25}}, "engine.lanes"),
    ({**M, "integrate": {"threads": 2}, "engine": {"threads": 2}}, "engine.threads"),
    # [verdict]
    ({**M, "verdict": 3}, "verdict"),
    ({**M, "verdict": {"converged_tol": True}}, "verdict.converged_tol"),
    ({**M, "verdict": {"converged_tol": math.nan}}, "verdict.converged_tol"),
    ({**M, "verdict": {"late_fraction": 0}}, "verdict.late_fraction"),
    ({**M, "verdict": {"late_fraction": 1.5}}, "verdict.late_fraction"),
    ({**M, "verdict": {"settle_tol": -1}}, "verdict.settle_tol"),
    ({**M, "verdict": {"diverge_size": "big"}}, "verdict.diverge_size"),
    ({**M, "verdict": {"bogus": 1}}, "verdict.bogus"),
    # a system judged by named outcomes reads no [verdict] threshold: refused, not recorded as if it counted
    ({**M, "outcomes": {"discover": True}, "verdict": {"converged_tol": 1e-4}}, "verdict.converged_tol"),
]


@pytest.mark.parametrize("spec, field", BAD_SPECS, ids=[f"{i}-{f}" for i, (_, f) in enumerate(BAD_SPECS)])
def test_bad_spec_names_the_field(spec, field):
    """A fuzz over single-field mistakes: each a ValidationError naming the full field path, at once."""
    t = time.perf_counter()
    with time_limit(20), pytest.raises(ValidationError) as info:
        make_plan(spec)
    assert info.value.field == field, str(info.value)
    assert info.value.message
    assert time.perf_counter() - t < 10


def test_fuzz_has_enough_cases():
    assert len(BAD_SPECS) >= 40


def test_t1_override_is_checked():
    for bad in (math.nan, math.inf, -1.0, 0.0):
        with pytest.raises(ValidationError) as info:
            make_plan({**M}, t1=bad)
        assert info.value.field == "--t1"


def test_integrate_type_error_names_the_field():
    """Formerly 'integrate: bad value': the field itself is named."""
    from stabjax.config import IntegrateConfig

    with pytest.raises(ValidationError) as info:
        IntegrateConfig.from_dict({"max_steps": "lots"})
    assert info.value.field == "integrate.max_steps"


def test_good_spec_still_accepted():
    p = make_plan({**M, "name": "at2019_alpha_t1e+06", "grid": {"alpha": {"start": 0.3, "stop": 1, "num": 3.0},
                   "J[0]": [4, "9/2"]}, "sample": {"n": 2, "seed": 0, "s0": CAP},
                   "integrate": {"t1": "2e3", "max_steps": 1e6, "n_checkpoints": 64}})
    assert p.shape == (3, 2, 2) and p.icfg.max_steps == 10**6 and p.icfg.t1 == 2000.0


# ---- the same through the CLI: exit 2, the field in the message, no traceback, nothing written ------


@pytest.mark.parametrize("body, field", [
    ('system = "monoaxial"\n[grid]\nalpha = {start = 0.3, stop = 1, num = 2.5}\n', "grid.alpha.num"),
    ('system = "monoaxial"\n[integrate]\nt0 = nan\n', "integrate.t0"),
    ('system = "monoaxial"\n[integrate]\nmax_steps = true\n', "integrate.max_steps"),
    ('system = "monoaxial"\n[params]\nmu = "9**9**9"\n', "params.mu"),
    ('system = "monoaxial"\n[sample]\nn = 4\ns0 = {dist = "cap", center = "r", half_angle = inf}\n',
     "sample.s0.half_angle"),
    ('system = "monoaxial"\n[grid]\n"J[0]" = [4.0, 5.0]\nJ = [[4, 5, 4]]\n', "grid.J"),
    ('system = "monoaxial"\n[grid]\nalpha = {start = 0.3, stop = 1, num = 100000000000}\n', "grid.alpha.num"),
    ('system = "monoaxial"\n[verdict]\nconverged_tol = true\n', "verdict.converged_tol"),
    ('system = "monoaxial"\n[extra]\nx = 1\n', "extra"),
    ('system = "monoaxial"\nname = "../../x"\n', "name"),
    ('system = "monoaxial"\n[grid\n', "spec"),
])
def test_cli_bad_spec_exit_2(tmp_path, capsys, body, field):
    spec = tmp_path / "bad.toml"
    spec.write_text(body)
    code, out, err = cli(capsys, "sweep", spec, "--out", tmp_path / "bad.nc", "--no-progress")
    assert code == 2 and f"error: {field}:" in err, err
    assert_clean(out, err)
    assert spec.read_text() == body and sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_cli_bad_options_exit_2(tmp_path, capsys, monkeypatch):
    import stabjax.engines as E

    def compiled(*args, **kwargs):  # a refusal does not wait for an engine's kernel to compile
        raise AssertionError("the engine was resolved before the options were refused")

    monkeypatch.setattr(E, "resolve_plan", compiled)
    monkeypatch.setattr(E, "resolve", compiled)
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    for args, field in [
        (["sweep", spec, "--t1", "nan"], "--t1"),
        (["sweep", spec, "--batch-size", "0"], "--batch-size"),
        (["simulate", "monoaxial", "--t1", "inf"], "--t1"),
        (["simulate", "monoaxial", "--rtol", "0"], "--rtol"),
        (["simulate", "monoaxial", "--t1", "10", "--ts", "20"], "--ts"),
        (["simulate", "monoaxial", "--set", "alpha=1/0"], "alpha"),
        (["simulate", "monoaxial", "--set", "alpha"], "--set"),
        (["theory", "nosuch"], "system"),
        (["sweep", tmp_path / "missing.toml"], "spec"),
        (["sweep", tmp_path], "spec"),
        (["plot", spec], "file"),
        (["plot", tmp_path], "file"),
        (["horizon-check", spec], "file"),
        (["simulate", "monoaxial", "--ts", "1,nan"], "--ts"),
        (["simulate", "monoaxial", "--ts", ","], "--ts"),
        (["simulate", "monoaxial", "--ts", "1,9**9**9"], "--ts"),
        (["theory", "monoaxial", "--set", "=5"], "--set"),
        (["theory", "monoaxial", "--set", "mu=1.5", "--set", "mu=2"], "--set"),
        (["reproduce", "nosuch"], "name"),
        (["reproduce", "at2019", "--out-dir", spec, "--quick"], "--out-dir"),
        (["bench", "--sizes", "x"], "--sizes"),
        (["bench", "--sizes", "0", "--quick"], "--sizes"),
        (["bench", "--t1", "nan", "--quick"], "--t1"),
        (["bench", "--out", tmp_path, "--quick"], "--out"),
        (["bench", "--out", spec, "--quick"], "--out"),
        (["horizon-check", spec, "--factor", "nan"], "--factor"),
        (["horizon-check", spec, "--n", "0"], "--n"),
        (["horizon-check", spec, "--tighten", "nan"], "--tighten"),
    ]:
        code, out, err = cli(capsys, *args)
        assert code == 2 and f"error: {field}:" in err, (args, err)
        assert_clean(out, err)
    assert spec.read_text() == TINY and sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


# ---- output paths --------------------------------------------------------------------------------


def test_output_path_refusals_touch_nothing(tmp_path, capsys):
    spec = tmp_path / "spec.nc"  # a spec may have any name; writing over it is refused all the same
    spec.write_text(TINY)
    foreign = tmp_path / "foreign.nc"
    foreign.write_bytes(b"not mine")
    img = tmp_path / "mine.png"
    img.write_bytes(b"a picture")
    (tmp_path / "adir.nc").mkdir()
    cases = [
        ([spec, "--out", spec], "input"),
        ([spec, "--out", tmp_path / "adir.nc"], "directory"),
        ([spec, "--out", tmp_path], "directory"),
        ([spec, "--out", tmp_path / "r.txt"], "writes .nc"),
        ([spec, "--out", tmp_path / "r"], "writes .nc"),
        ([spec, "--out", foreign], "--force"),
    ]
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    for args, says in cases:
        code, out, err = cli(capsys, "sweep", *args, "--no-progress")
        assert code == 2 and "error: --out:" in err and says in err, (args, err)
        assert_clean(out, err)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir.nc", "foreign.nc", "mine.png", "spec.nc"]


def test_rerun_replaces_own_result_else_needs_force(tmp_path, capsys):
    """The README's `stabjax sweep SPEC` works when run twice (the previous result of the same spec is
    replaced, and it is said); a result of another spec, or a foreign image, needs --force."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    out = tmp_path / "r.nc"
    code, _, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot")
    assert code == 0 and out.exists() and "replaced" not in err
    code, _, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot")
    assert code == 0 and "r.nc exists: it will be replaced (a previous result of this spec)" in err, err
    # another spec (or another --t1) on the same output: refused, the file untouched
    first = out.read_bytes()
    for args in (["--t1", "60"], []):
        if not args:
            spec.write_text(TINY.replace("0.7]", "0.8]"))
        code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--no-plot", *args)
        assert code == 2 and "is not a result of this spec" in err and "--force" in err, err
        assert_clean(o, err)
        assert out.read_bytes() == first
    # an image that is not this result's map: refused unless --force, also where the result beside it is this
    # spec's own and would be replaced (the image was replaced with it, a user's file of that name lost)
    png = out.with_suffix(".png")
    code, _, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--force")  # the spec changed above
    assert code == 0 and png.exists()
    code, _, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 0 and "it will be replaced" in err  # its own map, stamped: replaced with the result
    first = out.read_bytes()
    png.write_bytes(b"someone's picture")
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 2 and f"{png.name} exists and is not the map of a previous result of this spec" in err, err
    assert "--force" in err and png.read_bytes() == b"someone's picture" and out.read_bytes() == first
    code, o, err = cli(capsys, "sweep", spec, "--out", out, "--no-progress", "--force")
    assert code == 0 and "it will be replaced" in err and png.read_bytes() != b"someone's picture"
    # plot: the map of the result is redrawn (said); another image, or the result itself, is refused
    code, o, err = cli(capsys, "plot", out)
    assert code == 0 and "replaced the previous file" in o
    other = tmp_path / "other.svg"
    other.write_bytes(b"<svg/>")
    for args, says in ([["--out", other], "--force"], [["--out", out], "writes .png or .pdf or .svg"],
                       [["--out", spec], "writes .png"], [["--out", tmp_path], "directory"]):
        code, o, err = cli(capsys, "plot", out, *args)
        assert code == 2 and says in err, err
    assert other.read_bytes() == b"<svg/>"
    code, o, err = cli(capsys, "plot", out, "--out", other, "--force")
    assert code == 0 and other.read_bytes() != b"<svg/>"


def test_simulate_output(tmp_path, capsys):
    out = tmp_path / "traj.nc"
    args = ["simulate", "monoaxial", "--t1", "10", "--ts", "1,10", "--out", out, "--json"]
    assert cli(capsys, *args)[0] == 0
    code, o, err = cli(capsys, *args)  # a trajectory of the same system: replaced
    assert code == 0
    other = tmp_path / "other.nc"
    other.write_bytes(b"data")
    code, o, err = cli(capsys, *args[:-3], "--out", other)
    assert code == 2 and "--force" in err and other.read_bytes() == b"data"
    code, o, err = cli(capsys, *args[:-3], "--out", tmp_path / "traj.csv")
    assert code == 2 and "writes .nc" in err


# ---- exit status tells the truth -----------------------------------------------------------------


def test_solver_failure_exits_1(capsys, monkeypatch):
    import functools

    from stabjax.engines import simulate as engine

    monkeypatch.setattr(engine, "simulate", functools.partial(engine.simulate, max_steps=3))
    code, out, err = cli(capsys, "simulate", "monoaxial", "--t1", "100")
    assert code == 1 and "did not reach t1 = 100: the step budget ran out" in err
    assert_clean(out, err)
    from stabjax.fold.status import describe

    assert describe(100) == "the state left the escape radius"
    assert describe(9) == "the solver failed (nonfinite, code 9)" and "unknown, code 77" in describe(77)


BLOWUP = """
import jax.numpy as jnp
from stabjax import Outcomes, Param, ParamSet, System


class Blow(System):
    params = ParamSet((Param("x0", 1.0, "initial x", kind="initial"),))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    default_t1 = 10.0
    outcomes = Outcomes(rules={"small": "max(x) < 1"}, window=0.5)

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, p):
        return y ** 2

    def observe(self, t, y, p):
        return y
"""


def test_failed_trajectory_shows_its_last_finite_state(tmp_path, capsys):
    """x' = x^2 from x0 = 1 leaves every float at t = 1: the table and the JSON show the last saved state that
    is one (x(0.9) = 1/(1 - 0.9) = 10), not the solver's inf fill under the title "final state at t = 10"."""
    model = tmp_path / "blow.py"
    model.write_text(BLOWUP)
    code, out, err = cli(capsys, "simulate", f"{model}:Blow", "--ts", "0.5,0.9", "--json")
    assert code == 1
    final = json.loads(out)
    assert final["t"] == 0.9 and final["solver_ok"] is False
    assert final["x"] == pytest.approx(10.0, rel=1e-8)  # rtol 1e-10 on a growth of 10x: well inside 1e-8
    assert "did not reach t1 = 10" in err and "finite is at t = 0.9" in err
    code, out, err = cli(capsys, "simulate", f"{model}:Blow", "--ts", "0.5")
    assert code == 1 and "last finite saved state (t1 = 10 not reached) at t = 0.5" in out and "inf" not in out


def test_interrupt_exits_130(tmp_path, capsys, monkeypatch):
    from stabjax.run import sweep

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    monkeypatch.setattr(sweep, "run_plan", interrupted)
    code, out, err = cli(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-progress")
    assert code == 130 and "interrupted" in err
    assert_clean(out, err)
    # a command without its own handler: still 130, no traceback
    from stabjax.model import registry

    monkeypatch.setattr(registry, "get_system", interrupted)
    code, out, err = cli(capsys, "theory", "monoaxial")
    assert code == 130
    assert_clean(out, err)


def test_console_usage_error_without_click():
    """The issue's example, as a user runs it: `python -m stabjax sweep --bogus` prints the usage, exits 2."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "stabjax", "sweep", "--bogus"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert "Usage:" in r.stderr and "No such option: --bogus" in r.stderr
    assert "Traceback" not in r.stderr + r.stdout


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(spec: dict) -> str:
    """Just enough TOML for the cases above (top-level values, then one [table] per dict)."""
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in spec.items() if not isinstance(v, dict)]
    for k, v in spec.items():
        if isinstance(v, dict):
            lines += [f"[{json.dumps(k)}]"] + [f"{json.dumps(kk)} = {_toml_value(x)}" for kk, x in v.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("spec, field", BAD_SPECS, ids=[f"{i}-{f}" for i, (_, f) in enumerate(BAD_SPECS)])
def test_bad_spec_through_the_cli(tmp_path, capsys, spec, field):
    """The same fuzz as a user meets it: a TOML file, `stabjax sweep`: exit 2, the field named, no
    traceback, the spec untouched and nothing written."""
    body = to_toml(spec)
    path = tmp_path / "bad.toml"
    path.write_text(body)
    code, out, err = cli(capsys, "sweep", path, "--out", tmp_path / "bad.nc", "--no-progress")
    assert code == 2 and f"error: {field}:" in err, (body, err)
    assert_clean(out, err)
    assert path.read_text() == body and sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_messages_name_the_mistake_made(tmp_path, capsys):
    """A boolean parameter is called a boolean (it was "ragged list"), a folder as starts file a folder (it was
    "unknown format"), and a model without theorems says so instead of printing an empty table."""
    with pytest.raises(ValidationError, match="got a boolean") as info:
        make_plan({**M, "params": {"alpha": True}})
    assert info.value.field == "params.alpha"
    with pytest.raises(ValidationError, match="ragged"):
        make_plan({**M, "params": {"J": [[4, 5], [4]]}})
    with pytest.raises(ValidationError, match="is a folder") as info:
        make_plan({**M, "sample": {"n": 4, "from": str(tmp_path)}})
    assert info.value.field == "sample.from"
    model = tmp_path / "blow.py"
    model.write_text(BLOWUP)
    code, out, err = cli(capsys, "theory", f"{model}:Blow")
    assert code == 0 and "Blow states no theorem" in out and "┃" not in out  # no empty table
