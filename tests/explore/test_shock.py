"""Minimal fatal shocks (stabjax.explore.shock) against closed forms: the research note's T1, T2, T3 and a transient-
growth excitability threshold (models and their exact values in shock_models.py).

What a search promises, and what is asserted: the witness is a fatal start, so the true minimal fatal shock is at
most |delta*| (up to the integration; the witness of a red flag is re-integrated by SciPy's DOP853 here); the
bracket [r_lo, |delta*|] is narrower than the resolution; r_lo is statistical (no fatal shock among the directions
searched below it), so that the bracket holds the exact value is the search's quality, asserted on these cases.
Bisection radii never land on the edge states here (r = 1 exactly) except by a measure-zero accident.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import shock_models as M
from stabjax.errors import ValidationError
from stabjax.explore.shock import minimal_fatal_shock, shock_spec
from stabjax.explore.shock_result import CONSERVATIVE, CONSISTENT, REFUTED, witness_replay
from stabjax.model import registry

REL = 0.01  # the default resolution: the bracket is narrower than 1 % of |delta*|
T1_INTEGRATE = {"t1": 20.0, "n_checkpoints": 200, "rtol": 1e-8, "atol": 1e-10}  # one compiled kernel for T1


@pytest.fixture(autouse=True)
def models(monkeypatch):
    for name, cls in M.MODELS.items():
        monkeypatch.setitem(registry.SYSTEMS, name, f"shock_models:{cls.__name__}")
        monkeypatch.setitem(registry._cache, name, cls())


def search(system, shock, t1=20.0, n_checkpoints=200, **extra):
    spec = {"system": system, "name": "shock", "integrate": {"t1": t1, "n_checkpoints": n_checkpoints,
                                                               "rtol": 1e-8, "atol": 1e-10}, "shock": shock, **extra}
    return shock_spec(spec)


def bracket(ds, **sel):
    p = ds.sel(**sel) if sel else ds
    return float(p["shock_norm_lo"]), float(p["shock_norm"])


def assert_brackets(ds, exact, **sel):
    lo, hi = bracket(ds, **sel)
    assert hi - lo <= REL * hi * (1 + 1e-9)  # the resolution
    assert lo <= exact <= hi, (lo, exact, hi)


def test_t1_bistable_both_ways():
    """x' = -x + x^3 from the origin: delta* = 1; the witness blows up (escaped), and does in SciPy's DOP853."""
    from scipy.integrate import solve_ivp

    ds = search("test_shock_t1", {"components": ["x0"], "max_radius": 2.0, "directions": 4})
    assert_brackets(ds, 1.0)
    names = ds.attrs["outcome_names"].split()
    assert names[int(ds.base_outcome)] == "origin" and names[int(ds.shock_witness_outcome)] == "escaped"
    x0 = float(ds.shock_witness.values[0])
    assert 1.0 < abs(x0) <= 1.0 + REL
    blow = lambda t, y: abs(y[0]) - 10.0  # noqa: E731
    blow.terminal = True
    sol = solve_ivp(lambda t, y: -y + y**3, (0, 20), [x0], method="DOP853", rtol=1e-12, atol=1e-14, events=blow)
    assert sol.status == 1 and sol.t[-1] < 0.5 * math.log(x0**2 / (x0**2 - 1)) + 1e-6  # before the blow-up time


def test_t2_circle_every_direction_and_excitability():
    """T2: the exit radius is 1 along every scanned direction; into the r = 4 cycle's basin it is 3."""
    ds = search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 12,
                                  "refine": "none"}, t1=60.0, n_checkpoints=300)
    assert_brackets(ds, 1.0)
    hi = ds.direction_exit_hi.values
    lo = ds.direction_exit_lo.values
    searched = np.isfinite(hi) & (hi - lo <= REL * hi * (1 + 1e-9))  # the directions bisected to the resolution
    assert searched.sum() >= 1 and np.all((lo[searched] <= 1.0) & (1.0 <= hi[searched]))
    ds4 = search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 5.0, "directions": 12,
                                   "target": ["cycle4"], "refine": "none"}, t1=60.0, n_checkpoints=300)
    assert_brackets(ds4, 3.0)
    assert ds4.attrs["outcome_names"].split()[int(ds4.shock_witness_outcome)] == "cycle4"


def search_t3(shock, phi, **extra):
    """A T3 search at the rotation ``phi``, given as a one-point grid axis rather than a fixed parameter (the
    result is that point's): a fixed parameter is compiled into the native loop as a constant, so each angle
    was a loop of its own (and its witness re-check's another); as an axis every angle runs the same one, and a
    single grid point has no other to share a best direction with (CI time)."""
    return search("test_shock_t3", shock, grid={"phi": [phi]}, **extra).sel(phi=phi)


def test_t3_anisotropic_length_and_direction():
    """T3 (a = 1, b = 4, phi = 30 deg): delta* = 1 along 30 or 210 deg. Any shock of norm <= (1 + REL) that is
    fatal lies within acos(1 / (1 + REL)) of those directions (the exit radius is 1 / cos(theta - phi) there)."""
    ds = search_t3({"components": ["x0", "y0"], "max_radius": 2.5, "directions": 16}, math.radians(30.0))
    assert_brackets(ds, 1.0)
    d = ds.shock_delta.values
    theta = math.atan2(d[1], d[0])
    assert M.t3_exit_radius(theta) <= float(ds.shock_norm) * (1 + 1e-9)  # the witness is outside the basin
    off = min(abs(math.remainder(theta - math.radians(a), 2 * math.pi)) for a in (30.0, 210.0))
    assert off <= math.acos(1 / (1 + REL))


def test_weighted_norm_flips_the_direction():
    """phi = 0: unweighted, delta* = 1 along z1 (x); in sqrt(dx^2 + (dy/4)^2) it is 0.5 along z2 (y)."""
    plain = search_t3({"components": ["x0", "y0"], "max_radius": 2.5, "directions": 16}, 0.0)
    assert_brackets(plain, 1.0)
    d = plain.shock_delta.values
    assert abs(d[0]) > abs(d[1])
    weighted = search_t3({"components": ["x0", "y0"], "max_radius": 1.0, "directions": 16, "weights": {"y0": 0.25}},
                         0.0)
    assert_brackets(weighted, 0.5)
    d = weighted.shock_delta.values
    assert abs(d[1]) > 1.9 and abs(d[0]) < abs(d[1]) * math.tan(math.acos(1 / (1 + REL))) * 4


def test_a_refined_witness_reaches_the_grid_points_whose_fatal_cone_is_narrow():
    """T3 along a at max_radius 1.5 (b = 16: z2 never leaves the basin within it; phi = 97 deg, 36 deg from the
    nearest of the 8 scanned directions of seed 0, taken mod 180): delta*(a) = sqrt(a) along phi. At sqrt(a) = 0.5
    the fatal cone within 1.5 is +-70 deg wide and the scan finds it; at 1.45 and 1.49 it is +-15 and +-6.6 deg,
    missed by every scanned direction and by the scanned best direction shared before the refinement. Only the
    refined witness of sqrt(a) = 0.5 (near phi), shared after the refinement, reaches them: without that share
    they said "no fatal shock up to 1.5" (shock_norm NaN, shock_norm_lo 1.5)."""
    w = (0.5, 1.45, 1.49)
    ds = search("test_shock_t3", {"components": ["x0", "y0"], "max_radius": 1.5, "directions": 8},
                params={"b": 16.0, "phi": math.radians(97.0)}, grid={"a": [x * x for x in w]})
    for a, x in zip(ds.a.values, w):
        assert_brackets(ds, x, a=a)
    assert (ds.shock_cma_generations > 0).all()  # each point refined from the witness it was given


@pytest.mark.slow  # the grid's packing into rounds is also exercised by the red-flag test (three claims)
def test_along_an_axis_follows_the_closed_form():
    """T3 along a: delta*(a) = sqrt(a) (b = 4 > a), every grid point in the same rounds."""
    ds = search("test_shock_t3", {"components": ["x0", "y0"], "max_radius": 2.5, "directions": 16},
                grid={"a": [0.5, 1.0, 2.0]})
    for a in (0.5, 1.0, 2.0):
        assert_brackets(ds, math.sqrt(a), a=a)
    assert ds.shock_norm.dims == ("a",)


def test_settle_moves_the_start_onto_its_attractor():
    """T2 from (0.3, 0): the start itself is 0.7 from the basin's edge; settled (integrated to t1 first) it is the
    origin, 1 from the edge; settled from (2.5, 0) it is a point of the r = 2 cycle, 1 from the edges r = 1, 3."""
    kw = dict(t1=60.0, n_checkpoints=300)
    shock = {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 12, "refine": "none"}
    raw = search("test_shock_t2", shock, params={"x0": 0.3}, **kw)
    assert_brackets(raw, 0.7)
    settled = search("test_shock_t2", {**shock, "settle": True}, params={"x0": 0.3}, **kw)
    assert_brackets(settled, 1.0)
    w, dlt = settled.shock_witness.values, settled.shock_delta.values
    assert np.abs(w - dlt).max() < 1e-9  # the base is the origin
    cycle = search("test_shock_t2", {**shock, "settle": True, "attractor": "cycle2", "refine": "cma"},
                   params={"x0": 2.5}, **kw)  # the exit depends on the direction here: refined
    assert_brackets(cycle, 1.0)
    assert abs(np.hypot(*(cycle.shock_witness.values - cycle.shock_delta.values)) - 2.0) < 1e-6


def test_settle_of_a_start_that_escapes_leaves_it_as_given():
    """x' = -x + x^3 from x0 = 1.5 (outside the origin's basin |x| < 1): there is no attractor to settle on. The
    settle run's non-finite final state was written back as the start, so the unshocked run 'failed' (exit 1);
    the start stays as given and its run escapes, an answer (the same as without settle)."""
    shock = {"components": ["x0"], "max_radius": 2.0, "directions": 2, "refine": "none"}
    settled = search("test_shock_t1", {**shock, "settle": True}, params={"x0": 1.5})
    plain = search("test_shock_t1", shock, params={"x0": 1.5})
    names = settled.attrs["outcome_names"].split()
    assert names[int(settled.base_outcome)] == "escaped" == names[int(plain.base_outcome)]
    assert int(settled.base_solver_status) == int(plain.base_solver_status)


def test_discovered_attractors_decide_fatal():
    """T2 with its attractors discovered (no rules): the origin's group and the r = 2 cycle's; delta* = 1."""
    ds = search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 8, "refine": "none"},
                t1=60.0, n_checkpoints=300, outcomes={"discover": True, "discovery": {"lyapunov": False}})
    assert_brackets(ds, 1.0)
    names = ds.attrs["outcome_names"].split()
    assert names[int(ds.base_outcome)] != names[int(ds.shock_witness_outcome)]
    assert "unclassified" in names and "escaped" not in names


def test_excitability_threshold_of_a_neighbourhood():
    """x' = -x + 10 y, y' = -y: leaving |x| <= 0.1 (and coming back) takes a shock of 0.02705 in direction 84 deg."""
    exact, th = M.t4_threshold()
    ds = search("test_shock_t4", {"components": ["x0", "y0"], "max_radius": 0.2, "directions": 16,
                                  "excitability": "max(ax) > 0.1"}, n_checkpoints=2000)
    assert_brackets(ds, exact)
    names = ds.attrs["outcome_names"].split()
    assert names[int(ds.base_outcome)] == "stayed" and names[int(ds.shock_witness_outcome)] == "left"


def test_wrong_theorem_is_a_red_flag_with_a_witness_scipy_confirms():
    """A theorem claiming the disc r < 1.3 (the basin is r < 1): refuted, in both forms (a predicate's margin and a
    derived radius), with a witness inside the claim that SciPy's DOP853 takes to the r = 2 cycle; the true claim is
    consistent and a claim of 0.5 conservative by a factor 2."""
    from scipy.integrate import solve_ivp

    ds = search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 12,
                                  "theory": ["disc", "disc_radius"]}, t1=60.0, n_checkpoints=300,
                grid={"claim": [0.5, 1.0, 1.3]})
    for name in ("disc", "disc_radius"):
        v = ds[f"theory_verdict_{name}"]
        assert int(v.sel(claim=1.3)) == REFUTED and int(v.sel(claim=1.0)) == CONSISTENT
        assert int(v.sel(claim=0.5)) == CONSERVATIVE
        f_lo, f_hi = float(ds[f"theory_factor_lo_{name}"].sel(claim=0.5)), float(
            ds[f"theory_factor_hi_{name}"].sel(claim=0.5))
        assert f_lo <= 2.0 <= f_hi
    np.testing.assert_allclose(ds["theory_radius_disc"].values, [0.5, 1.0, 1.3], rtol=1e-6)
    rep = witness_replay(ds, claim=1.3)
    x0, y0 = rep["params"]["x0"], rep["params"]["y0"]
    assert 1.0 < math.hypot(x0, y0) < 1.3 and f"-s x0={x0!r}" in rep["command"]
    sol = solve_ivp(M.t2_rhs, (0, 60), [x0, y0], method="DOP853", rtol=1e-11, atol=1e-13, dense_output=True)
    r_late = np.hypot(*sol.sol(np.linspace(50, 60, 101)))
    assert sol.success and np.all(np.abs(r_late - 2.0) < 1e-3)  # the r = 2 cycle, not the origin
    names = ds.attrs["outcome_names"].split()
    assert names[int(ds.shock_witness_recheck.sel(claim=1.3))] == "cycle2"


def test_deterministic_and_resumed_from_the_store(tmp_path):
    """The same seed gives the same search; a second run over a kept store resumes every round, bitwise, and one
    that does not keep it removes the store it made."""
    shock = {"components": ["x0"], "max_radius": 2.0, "directions": 4}
    spec = {"system": "test_shock_t1", "name": "shock", "integrate": T1_INTEGRATE, "shock": shock}
    a = shock_spec(spec, tmp_path / "a.nc", keep_store=True)
    assert (tmp_path / "a.nc.zarr" / "round_0000").is_dir()
    b = shock_spec(spec, tmp_path / "a.nc", keep_store=True)
    assert b.attrs["rounds_resumed"] == b.attrs["rounds"] == a.attrs["rounds"]
    for v in ("shock_norm", "shock_norm_lo", "shock_delta", "direction_exit_hi"):
        np.testing.assert_array_equal(a[v].values, b[v].values)
    c = shock_spec(spec)
    np.testing.assert_array_equal(a.shock_delta.values, c.shock_delta.values)
    # resumed without keep_store, its default store named as the command line names it: the rounds and their
    # folder go (the folder stayed behind, empty)
    d = shock_spec(spec, tmp_path / "a.nc", store=tmp_path / "a.nc.zarr")
    assert d.attrs["rounds_resumed"] == a.attrs["rounds"] and not (tmp_path / "a.nc.zarr").exists()


def test_a_store_folder_of_the_users_keeps_its_files(tmp_path):
    """``--store DIR`` naming a folder that holds a user's file: only the rounds' stores are removed (the
    whole tree was); what will be replaced is said once the first round's store accepted the run."""
    from user_store import check_said_once_the_store_accepts, check_user_store_folder_kept

    # a coarse resolution: a few rounds (the checks need more than one), not the default 1 %'s bisection
    shock = {"components": ["x0"], "max_radius": 2.0, "directions": 2, "rel_resolution": 0.1}  # 3 rounds, not 6
    spec = {"system": "test_shock_t1", "name": "shock", "integrate": T1_INTEGRATE, "shock": shock}
    check_user_store_folder_kept(lambda out, **kw: shock_spec(spec, out, **kw), tmp_path)
    check_said_once_the_store_accepts(lambda out, **kw: shock_spec(spec, out, **kw), tmp_path)


def test_python_entry_point_and_cf_attributes():
    import stabjax

    assert stabjax.minimal_fatal_shock is minimal_fatal_shock
    ds = minimal_fatal_shock("test_shock_t1", ["x0"], 2.0, directions=2, integrate=T1_INTEGRATE)
    assert_brackets(ds, 1.0)
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name"), name
        if var.dtype.kind in "iuf" and "flag_values" not in var.attrs:
            assert "units" in var.attrs, name
    assert ds.attrs["Conventions"].startswith("CF") and ds.attrs["kind"] == "shock"
    assert "no fatal shock in either direction of x0" in ds.attrs["statement"]  # one component: no statistics
    assert "confidence" not in ds.attrs["statement"] and ds.attrs["n_directions"] == 2
    # one name is one component, not its letters (list("x0") was the components x and 0)
    one = minimal_fatal_shock("test_shock_t1", "x0", 2.0, directions=2, integrate=T1_INTEGRATE)
    assert list(one["component"].values) == ["x0"]
    np.testing.assert_array_equal(one["shock_norm"].values, ds["shock_norm"].values)


@pytest.mark.parametrize("shock, field", [
    ({"components": ["omega"]}, "shock.components[0]"),  # a model parameter, not an initial condition
    ({"components": ["x0", "z0"]}, "shock.components[1]"),  # not a parameter at all
    ({"components": ["x0", "y0"], "norm": "max", "blocks": [["x0"], ["zz"]]}, "shock.blocks[1]"),
    ({"components": ["x0", "y0"], "space": "state", "norm": "max", "blocks": [["x"], ["x0"]]}, "shock.blocks[1]"),
    ({"components": ["x0", "y0"], "weights": {"q": 2.0}}, "shock.weights.q"),
    ({"components": ["x0"], "resolution": 0.0}, "shock.resolution"),
    ({"components": ["x0"], "resolution": -0.01}, "shock.resolution"),
    ({"components": ["x0"], "rel_resolution": 0}, "shock.rel_resolution"),
    ({"components": ["x0"], "attractor": "cycle9"}, "shock.attractor"),
    ({"components": ["x0"], "target": ["nowhere"]}, "shock.target"),
    ({"components": ["x0"], "theory": ["no_such_theorem"]}, "shock.theory[0]"),
    ({"components": ["x0"], "directions": 0}, "shock.directions"),
    ({"components": ["x0"], "sideways": 1}, "shock.sideways"),
    ({"components": ["x0"], "settle": True}, "shock.settle"),  # y0 is a state entry no shocked entry sets
])
def test_bad_input_names_the_field(shock, field):
    with pytest.raises(ValidationError) as exc:
        search("test_shock_t2", {"max_radius": 2.0, **shock}, t1=60.0)
    assert exc.value.field == field


def test_bad_input_through_the_command_line_exits_2_and_writes_nothing(tmp_path, capsys):
    from clirun import captured

    spec = tmp_path / "bad.toml"
    body = ('system = "test_shock_t2"\nname = "bad"\n[params]\nomega = 1.0\n[shock]\ncomponents = ["omega"]\n'
            'max_radius = 2.0\n')
    spec.write_text(body)
    code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "bad.nc", "--no-progress")
    assert code == 2 and "shock.components[0]" in err + out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"] and spec.read_text() == body
    spec.write_text(body.replace('["omega"]', '["x0"]') + "resolution = 0\n")
    code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "bad.nc", "--no-progress")
    assert code == 2 and "shock.resolution" in err + out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_a_grid_sweep_of_the_shocked_parameter_is_refused():
    with pytest.raises(ValidationError) as exc:
        search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0}, grid={"x0": [0.0, 0.1]})
    assert exc.value.field == "shock.components[0]"
    with pytest.raises(ValidationError) as exc:
        search("test_shock_t2", {"components": ["x0"], "max_radius": 2.0},
               sample={"n": 2, "y0": {"dist": "uniform", "low": 0, "high": 0.1}})
    assert exc.value.field == "sample"


@pytest.mark.slow
def test_rounds_run_on_dask_workers_with_the_local_result():
    """Every round through a spawned Dask worker (the example model, loadable there) gives the in-process search."""
    from pathlib import Path

    from stabjax.plan.spec import load_spec
    from stabjax.run.distributed import DaskExecutor

    spec = load_spec(Path(__file__).resolve().parents[2] / "examples" / "shock_circle" / "spec.toml")
    spec["shock"].update(directions=8, refine="none")
    local = shock_spec(spec)
    with DaskExecutor(workers=1, threads=1) as ex:
        ex.wait_for_workers(1)
        ds = shock_spec(spec, executor=ex)
    for v in ("shock_norm", "shock_norm_lo", "shock_delta", "direction_exit_lo", "direction_exit_hi"):
        np.testing.assert_array_equal(ds[v].values, local[v].values, err_msg=v)
    assert_brackets(ds, 1.0)


@pytest.fixture
def never_searched(monkeypatch):
    """A search that starts fails the test at once: before the size check a round too large was built whole and
    allocated memory until the machine killed it."""
    from stabjax.explore.shock import Search

    def started(self, evaluate):
        raise AssertionError("the search started: its largest round was not refused")

    monkeypatch.setattr(Search, "run", started)


@pytest.mark.parametrize("shock, grid, field", [
    ({"directions": 16777216, "radii": 64}, None, "shock.directions"),  # round 0: 1e9 trajectories
    ({"directions": 100000}, {"claim": {"start": 0.5, "stop": 1.5, "num": 100000}}, "shock.directions"),  # x the grid
    ({"directions": 4}, {"claim": {"start": 0.5, "stop": 1.5, "num": 5000}}, "grid"),  # sharing: G (G - 1) radii
    ({"directions": 4, "popsize": 16777216}, None, "shock.popsize"),  # a CMA-ES generation
])
def test_a_round_too_large_is_refused_before_the_search(never_searched, shock, grid, field):
    """The largest round a search can reach -- the scan (grid points x (directions x radii + 1)), the round
    sharing every grid point's best direction with every other, a bisection, a CMA-ES generation -- is held to
    a sweep's bound on the points of a sample, and refused naming the field that makes it large, before anything
    runs."""
    extra = {"grid": grid} if grid else {}
    with pytest.raises(ValidationError) as exc:
        search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0, **shock}, t1=60.0, **extra)
    assert exc.value.field == field and "over the 100,000,000 trajectories a round may hold" in exc.value.message


def test_a_round_over_the_memory_allowed_is_refused(never_searched, monkeypatch):
    """Below the bound on points, a round whose trajectories' results and arrays exceed the memory a sweep may
    take (stabjax.validate.check_allocation, a quarter of the free memory, here of 1 GiB) is refused too."""
    from stabjax import validate

    monkeypatch.setattr(validate, "available_memory", lambda: 1 << 30)
    with pytest.raises(ValidationError) as exc:
        search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 2.0, "directions": 1_000_000}, t1=60.0)
    assert exc.value.field == "shock.directions" and "would need" in exc.value.message


def test_a_round_too_large_exits_2_and_leaves_nothing(never_searched, tmp_path, capsys):
    """From the command line: exit status 2 naming shock.directions, and no result, figure or store on disk."""
    from clirun import captured

    spec = tmp_path / "big.toml"
    spec.write_text('system = "test_shock_t2"\nname = "big"\n[shock]\ncomponents = ["x0", "y0"]\nmax_radius = 1.0\n'
                    'directions = 16777216\nradii = 64\n')
    code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "big.nc", "--no-progress")
    assert code == 2 and "shock.directions" in err + out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.toml"]


def test_no_statement_where_the_start_reaches_another_outcome():
    """A start that reaches an outcome other than the attractor asked for holds no search: the result says so,
    and makes no statistical statement about directions that were never bisected; it is no failure (exit 0)."""
    ds = search("test_shock_t2", {"components": ["x0", "y0"], "max_radius": 1.0, "directions": 2, "refine": "none",
                                  "attractor": "origin"}, t1=60.0, n_checkpoints=300, params={"x0": 2.0})
    assert ds.attrs["outcome_names"].split()[int(ds.base_outcome)] == "cycle2"
    assert np.isnan(float(ds.shock_norm)) and np.isnan(float(ds.shock_norm_lo))
    assert ds.attrs["statement"].startswith("no search ran") and "no fatal shock among" not in ds.attrs["statement"]
    from stabjax.app.sweep_cmds import shock_status

    assert shock_status(ds) == 0
