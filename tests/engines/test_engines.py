"""The engine protocol: one interface for native, fused and diffrax; the engine resolved once per
plan and recorded; settings without engines (the spec loader imports no diffrax, importing stabjax
changes no JAX setting); early stops on escape and on a non-finite state on every engine, against
closed forms."""
import dataclasses
import logging
import math
import os
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from stabjax import engines
from stabjax.fold import verdict as V
from stabjax.config import IntegrateConfig, VerdictConfig
from stabjax.fold.status import ESCAPED as STATUS_ESCAPED, MAX_STEPS as STATUS_MAX_STEPS
from stabjax.engines import diffrax_engine, fused, native
from stabjax.model.params import Param, ParamSet
from stabjax.plan.spec import make_plan
from stabjax.model.outcomes import VERDICTS
from stabjax.model.system import System

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RTOL, ATOL = 1e-8, 1e-10


class Growth(System):
    """dy/dt = k y, y(0) = y0: y = y0 e^{k t}."""

    name = "test_growth"
    outcomes = VERDICTS  # tests the attitude verdicts on a toy model
    # verdicts at t1 alone (no earlier horizons): the tests below read the verdict at t1, and a classifier
    # state with one horizon instead of four compiles ~30% faster on the fused engine (C: smaller kernels)
    verdict = VerdictConfig(n_horizon_decades=0)
    params = ParamSet((Param("k", 1.0, "rate"), Param("y0", 1.0, "initial value")))
    state = (("y", ()),)
    default_t1 = 20.0

    def initial_state(self, p):
        return jnp.reshape(p["y0"], (1,))

    def rhs(self, t, y, a):
        return a["k"] * y

    def observe(self, t, y, a):
        return jnp.stack([jnp.abs(y[0]), jnp.abs(y[0])])


class Escaping(Growth):
    name = "test_escaping"
    escape_radius = 1e3


class BlowUp(Growth):
    """dy/dt = y^2, y(0) = 1: y = 1 / (1 - t), infinite at t = 1."""

    name = "test_blowup"

    def rhs(self, t, y, a):
        return y * y


GROWTH, ESCAPING, BLOWUP = Growth(), Escaping(), BlowUp()  # one instance each: compiled once per engine


def _params(system, n=2):
    return {"k": np.ones(n), "y0": np.ones(n)}


def _engines():
    names = ["fused", "diffrax"]
    if native.available():
        names.insert(0, "native")
    return names


# ---- protocol -------------------------------------------------------------------------------


def test_every_engine_has_the_one_interface():
    plan = make_plan({"system": "monoaxial", "grid": {"alpha": [0.5, 0.7]}, "integrate": {"t1": 10.0}})
    for name in engines.ORDER:
        eng = engines.get(name)
        assert isinstance(eng, engines.Engine) and eng.name == name
        assert eng.default_chunk(plan) >= 1 and eng.bytes_per_trajectory(plan) > 0
        assert eng.supports(plan.system, plan.icfg) is None or name == "native"
    # the diffrax engine stores every checkpoint; the queued engines do not
    assert engines.get("diffrax").bytes_per_trajectory(plan) > engines.get("fused").bytes_per_trajectory(plan)
    assert engines.chain("auto") == ("native", "fused", "diffrax")
    assert engines.chain("diffrax") == ("diffrax", "native", "fused")
    with pytest.raises(ValueError, match="unknown engine"):
        engines.get("warp")


def test_system_hooks_are_declared():
    assert System.classify is None and System.escape_radius is None
    from stabjax.model.registry import get_system

    assert get_system("gyrodyne").classify is not None and get_system("monoaxial").classify is None
    why = engines.get("fused").supports(get_system("gyrodyne"), IntegrateConfig())
    assert "classify" in why


def test_plan_is_frozen_and_the_engine_is_resolved_once(monkeypatch, tmp_path, caplog):
    """A plan is a value; run_plan resolves its engine once, sizes chunks with it, records it; an
    engine that cannot translate the system hands over with one logged line naming the reason."""
    from stabjax.run import sweep

    plan = make_plan({"system": "monoaxial", "grid": {"alpha": [0.5, 0.9, 0.7]},
                      "integrate": {"t1": 5.0, "n_checkpoints": 16, "engine": "fused"}})
    assert plan.engine == ""
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.engine = "diffrax"
    calls = []

    def refuse(self, system, params, icfg, vcfg, static=None):
        calls.append(self.name)
        raise engines.Unsupported("no lane-wise rule for primitive test_prim")

    monkeypatch.setattr(fused.FusedEngine, "prepare", refuse)
    monkeypatch.setattr(native.NativeEngine, "prepare", refuse)
    with caplog.at_level(logging.WARNING, logger="stabjax.engines"):
        ds = sweep.run_plan(plan, tmp_path / "x.nc", batch_size=2)  # two chunks
    assert calls == ["fused", "native"]  # once per plan, not per chunk
    assert ds.attrs["engine"] == "diffrax"
    assert ds.attrs["engine_note"] == ("engine diffrax runs monoaxial (fused: no lane-wise rule for primitive test_prim; "
                                       "native: no lane-wise rule for primitive test_prim)")
    assert [r.getMessage() for r in caplog.records] == [ds.attrs["engine_note"]]
    assert ds["verdict"].sizes["alpha"] == 3 and plan.engine == ""  # the caller's plan is unchanged
    resolved = engines.resolve_plan(plan, static=sweep.static_params(plan))
    assert resolved.engine == "diffrax" and sweep.default_batch(resolved) == engines.get("diffrax").default_chunk(plan)


def test_loading_a_spec_imports_no_engine_and_import_changes_no_jax_setting():
    """Validating a spec, its engine settings included, and computing its identity import no engine
    module and never diffrax: the declarations are plain data in stabjax.engines (an earlier attempt that
    asked each engine at resolution imported diffrax on every run and was reverted)."""
    code = ("import sys, stabjax.plan.spec, stabjax.config, jax\n"
            "from stabjax.plan.spec import load_spec, make_plan\n"
            "make_plan(load_spec('sweeps/default.toml'))\n"
            "spec = {'system': 'monoaxial', 'integrate': {'t1': 5.0, 'threads': 2}, 'engine': {'lanes': 64, 'width': 8}}\n"
            "plan = make_plan(spec)\n"
            "assert dict(plan.icfg.settings) == {'threads': 2, 'lanes': 64, 'width': 8}, plan.icfg.settings\n"
            "plan.fingerprint()\n"
            "assert 'diffrax' not in sys.modules, 'diffrax imported'\n"
            "engine_modules = {'stabjax.engines.native', 'stabjax.engines.fused', 'stabjax.engines.diffrax_engine'}\n"
            "assert not engine_modules & set(sys.modules), 'an engine imported'\n"
            "assert not jax.config.jax_enable_x64, 'import switched x64 on'\n"
            "stabjax.config.setup_jax(); stabjax.config.setup_jax()\n"
            "assert jax.config.jax_enable_x64\n")
    env = {k: v for k, v in os.environ.items() if k not in ("STABJAX_X64", "JAX_ENABLE_X64")}
    env["PYTHONPATH"] = ROOT
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_engines_declare_their_settings_and_read_only_those():
    """Each engine's settings are its declaration in stabjax.engines.SETTINGS; an engine reads a setting
    through Engine.setting, which knows only declared names (fails if an engine reads an undeclared one,
    or a declaration lacks a range or a description)."""
    for name in engines.ORDER:
        eng = engines.get(name)
        assert eng.settings == engines.SETTINGS[name]
        for s in eng.settings:
            assert s.lo <= s.default <= s.hi and s.doc
            assert eng.setting(IntegrateConfig(), s.name) == s.default
            assert eng.setting(IntegrateConfig(settings={s.name: s.hi}), s.name) == s.hi
        with pytest.raises(KeyError):
            eng.setting(IntegrateConfig(), "no_such_setting")
    assert engines.THREADS in {s.name for s in engines.SETTINGS["native"]}
    assert engines.with_threads(IntegrateConfig(), 3).settings == {"threads": 3}
    assert engines.with_threads(IntegrateConfig(), None) == IntegrateConfig()


_SETTINGS_BASE = {"system": "monoaxial", "grid": {"alpha": [0.4, 0.55, 0.7], "sigma": [1.2, 1.4, 1.6]},
                  "integrate": {"t1": 20.0, "n_checkpoints": 32}}


def _settings_plan(integ=None, engine=None, choice=None):
    base = _SETTINGS_BASE
    spec = {**base, "integrate": {**base["integrate"], **(integ or {}), **({"engine": choice} if choice else {})}}
    if engine:
        spec["engine"] = engine
    return make_plan(spec)


def test_settings_that_change_no_result_leave_the_identity_alone():
    """threads (native) and lanes (fused) leave the fingerprint alone, whether given in [engine] or
    [integrate]; width is declared as changing results (a dense-checkpoint run gives last-bit different
    summaries at another SIMD width) and so changes the fingerprint. Fails if the identity counts an
    execution-only setting (a resume with another thread count would be refused) or ignores one that changes
    results (chunks of different bits would be mixed). That they change no bit: the test below and
    tests/engines/test_native.py's threads/width test."""
    plan = _settings_plan
    ref = plan(choice="native")
    same = [plan({"threads": 1}, choice="native"), plan(None, {"threads": 2}, "native"),
            plan(None, {"lanes": 8}, "native"), plan(None, {"threads": 2, "lanes": 64}, "native"),
            plan(None, {"lanes": 4}, "fused")]
    for p in same[:-1]:
        assert p.fingerprint() == ref.fingerprint(), p.icfg.settings
    assert same[-1].fingerprint() == plan(None, {"lanes": 64}, "fused").fingerprint()
    assert plan(None, {"width": 8}, "native").fingerprint() != ref.fingerprint()


@pytest.mark.slow  # the full suite's (CI's 10 minutes): two fused compiles; native threads: test_native.py
def test_settings_that_change_no_result_leave_the_results_alone(tmp_path):
    """threads (native) and lanes (fused) change not a bit of the result."""
    from stabjax.run import sweep

    plan = _settings_plan
    ref = plan(choice="native")
    if engines.get("native").supports(ref.system, ref.icfg) is None:
        r1 = sweep.run_plan(plan(None, {"threads": 1}, "native"), tmp_path / "t1.nc")
        r2 = sweep.run_plan(plan(None, {"threads": 2}, "native"), tmp_path / "t2.nc")
        assert r1.attrs["engine"] == r2.attrs["engine"] == "native"
        for k in r1.data_vars:
            np.testing.assert_array_equal(r1[k].values, r2[k].values, err_msg=k)
        assert r1.attrs["fingerprint"] == r2.attrs["fingerprint"]
    f1 = sweep.run_plan(plan(None, {"lanes": 4}, "fused"), tmp_path / "l4.nc")
    f2 = sweep.run_plan(plan(None, {"lanes": 64}, "fused"), tmp_path / "l64.nc")
    assert f1.attrs["engine"] == f2.attrs["engine"] == "fused" and f1.attrs["fingerprint"] == f2.attrs["fingerprint"]
    for k in f1.data_vars:
        np.testing.assert_array_equal(f1[k].values, f2[k].values, err_msg=k)


def test_no_module_above_the_engines_tests_an_engine_name():
    """Nothing outside stabjax/engines/ compares a value with an engine's name (==, !=, in): which
    engine runs is the engines' business (fails on e.g. ``if plan.engine == "native"`` in refine.py)."""
    import ast
    from pathlib import Path

    names = set(engines.ORDER)
    found = []
    pkg = Path(ROOT) / "stabjax"
    for f in pkg.rglob("*.py"):
        if (pkg / "engines") in f.parents:
            continue
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Compare):
                for c in [node.left, *node.comparators]:
                    consts = c.elts if isinstance(c, (ast.Tuple, ast.List, ast.Set)) else [c]
                    if any(isinstance(x, ast.Constant) and x.value in names for x in consts):
                        found.append(f"{f.relative_to(ROOT)}:{node.lineno}")
    assert not found, found


def test_x64_opt_out_is_refused(monkeypatch):
    """float32 crashed every sweep (issue 22, item 9): STABJAX_X64=0 is refused naming the variable."""
    from stabjax.config import x64_wanted
    from stabjax.errors import ValidationError

    for value in ("0", "off", "abc"):
        monkeypatch.setenv("STABJAX_X64", value)
        with pytest.raises(ValidationError) as info:
            x64_wanted()
        assert info.value.field == "STABJAX_X64"
    monkeypatch.setenv("STABJAX_X64", "1")
    assert x64_wanted()
    monkeypatch.delenv("STABJAX_X64")
    assert x64_wanted()


# ---- early stops ---------------------------------------------------------------------------


def _run(name, system, icfg, params=None):
    """One engine on two trajectories (default: identical); native and fused also return where they stopped."""
    params = _params(system) if params is None else params
    if name == "diffrax":
        return diffrax_engine.solve(system, params, icfg, system.verdict)
    module = native if name == "native" else fused
    return module.solve(system, params, icfg, system.verdict, with_state=True, static=[])


ESCAPE_CFG = IntegrateConfig(t1=20.0, rtol=RTOL, atol=ATOL, n_checkpoints=16, escape_radius=1e3)


# the fused engine (the GPU engine) in the full suite: its stops are the native engine's rules (CI's 10 minutes)
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "fused" else n for n in _engines()])
def test_escape_stops_at_the_first_accepted_state_outside_the_radius(name):
    """dy/dt = y, y0 = 1, radius 1e3: y leaves the ball at t* = ln 1000. The engines stop at the end
    of the first accepted step beyond it: the stop time lies after t* by less than one step, and
    there y(t_stop) = e^t_stop to the solver's tolerance."""
    res = _run(name, GROWTH, ESCAPE_CFG)
    assert np.all(res["solver_status"] == STATUS_ESCAPED)
    # at t1 (the last horizon, here the only one): solver_ok is False, and the outcome code maps the
    # status to the escape outcome
    assert np.all(res["verdict"][:, -1] == V.FAILED)
    steps = res["n_steps"]
    # ln(1000) = 6.9 at steps of ~0.1-0.3 (rtol 1e-8): tens of steps, not the 20 time units' worth
    assert np.all(steps > 5) and np.all(steps < 200) and np.all(res["n_rejected"] <= 3)
    if name == "diffrax":
        return
    t_stop, y_stop = res["t_stop"], res["state_t1"][:, 0]
    t_star = math.log(1e3)
    mean_step = t_stop / steps
    assert np.all(y_stop > 1e3)
    assert np.all(t_stop > t_star) and np.all(t_stop - t_star < 3 * mean_step)
    # for y' = y a relative local error adds up unchanged: at most rtol per accepted step (atol is
    # negligible at |y| >= 1), so the relative global error is below n_steps * rtol
    np.testing.assert_allclose(y_stop, np.exp(t_stop), rtol=RTOL * steps.max())


@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n == _engines()[0] else pytest.mark.slow)
                                  for n in _engines()])  # one engine in CI: the radius is read in one place
def test_system_escape_radius_and_its_override(name):
    """``System.escape_radius`` applies; ``[integrate] escape_radius`` overrides it."""
    icfg = IntegrateConfig(t1=20.0, rtol=RTOL, atol=ATOL, n_checkpoints=16)
    near = _run(name, ESCAPING, icfg)
    far = _run(name, ESCAPING, icfg.replace(escape_radius=1e6))
    assert np.all(near["solver_status"] == STATUS_ESCAPED) and np.all(far["solver_status"] == STATUS_ESCAPED)
    # ln(1e6) is twice ln(1e3): about twice the steps at a step size set by rtol alone
    assert np.all(far["n_steps"] > 1.5 * near["n_steps"]) and np.all(far["n_steps"] < 2.5 * near["n_steps"] + 5)


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "fused" else n for n in _engines()])  # fused: the full suite's
def test_blow_up_stops_at_once_on_every_engine(name):
    """dy/dt = y^2, y0 = 1 is infinite at t = 1. Every engine stops there (status 1: the step size
    collapses to ~10 ulp of t, or the derivative overflows) after a number of steps of the order of
    the steps to t = 1, not after max_steps rejected ones."""
    icfg = IntegrateConfig(t1=2.0, rtol=RTOL, atol=ATOL, n_checkpoints=16, max_steps=200_000)
    res = _run(name, BLOWUP, icfg)
    assert np.all(res["solver_status"] == STATUS_MAX_STEPS)
    assert np.all(np.isin(res["verdict"][:, -1], [V.FAILED, V.DIVERGED]))  # at t1
    total = res["n_steps"] + res["n_rejected"]
    assert np.all(total < 5000), total  # ~550 measured; max_steps would be 200000
    if name != "diffrax":  # where: at the blow-up time 1, to the accumulated tolerance (n_steps rtol)
        assert np.all(np.abs(res["t_stop"] - 1.0) < RTOL * res["n_steps"]) and np.all(res["state_t1"] > 1e6)


def test_the_diffrax_engine_shortens_a_step_whose_error_is_nan():
    """x' = -1e4 x^3, y' = -y from (1, 0): the step diffrax picks at t0 overflows a stage, and its error
    estimate is NaN. diffrax 0.7.2 retried that step unshortened until max_steps (status 1 at t0, the state
    inf), so a discovered attractor's representative re-integrated on its own was placed at x = inf; the lane
    engines solve it. Read as an infinite error the step is shortened: the solve reaches t1 = 50 with the
    closed form x = 1 / sqrt(1 + 2e4 t) to its tolerance, in a number of steps like the lane engines'."""
    from stabjax.engines.simulate import simulate

    class Cube(System):
        name = "cube_test"
        params = ParamSet((Param("x0", 1.0, "x start", kind="initial"),))
        state = (("x", ()), ("y", ()))
        observables = ("x",)
        observable_doc = ("x",)

        def initial_state(self, p):
            return jnp.stack([p["x0"], 0.0 * p["x0"]])

        def rhs(self, t, s, p):
            return jnp.stack([-1e4 * s[0] ** 3, -s[1]])

        def observe(self, t, s, p):
            return s[:1]

    ds = simulate(Cube(), {}, t1=50.0, ts=[10.0, 50.0], rtol=1e-8, atol=1e-10)
    assert ds.attrs["solver_status"] == 0 and 0 < ds.attrs["n_steps"] < 1000, ds.attrs
    exact = 1 / np.sqrt(1 + 2e4 * ds["t"].values)
    # a contracting flow: the global error stays of the order of the local tolerance on x ~ 1e-3
    np.testing.assert_allclose(ds["x"].values, exact, rtol=1e-5)


@pytest.mark.parametrize("name", _engines())
def test_non_finite_derivative_stops_at_once(name):
    """A derivative that is NaN from t0 (k = NaN): status 1 at once on the native and fused engines;
    on the diffrax engine (which used to reject steps until max_steps) once the rejected steps, each
    5 times shorter, are below ~10 ulp of t1. The other trajectory of the same batch is untouched."""
    from stabjax.engines.tsit5 import MIN_STEP_REL

    p = _params(GROWTH)
    p["k"][1] = np.nan
    res = _run(name, GROWTH, ESCAPE_CFG, p)
    assert res["solver_status"][1] == STATUS_MAX_STEPS and res["verdict"][1, -1] == V.FAILED
    t1 = ESCAPE_CFG.t1
    bound = 2 if name != "diffrax" else math.ceil(math.log(t1 / (MIN_STEP_REL * t1)) / math.log(5)) + 2  # 22
    assert res["n_steps"][1] + res["n_rejected"][1] <= bound
    ref = _run(name, GROWTH, ESCAPE_CFG)
    for k in ("solver_status", "n_steps", "n_rejected", "verdict"):
        assert np.array_equal(res[k][0], ref[k][0]), k
