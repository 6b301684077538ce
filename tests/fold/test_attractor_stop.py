"""The recurrence stop (stabjax.fold.stops, ``[integrate] attractor_stop``): a trajectory that stays near an
attractor the run has already found, for a feature window's length, is stopped and given that attractor's
features.

References independent of the code under test: the geometry of the clouds is checked with brute-force
NumPy distances; every outcome is compared, per start, with the same run without any stop (what the stop
must never change); the refinement's points and labels with the refinement without the stop. A stop that
fired on the wrong attractor, or a radius that reached another attractor, would change an outcome there.
"""
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from stabjax.fold import stops
from stabjax.errors import ValidationError
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_plan

EXAMPLES = Path(__file__).resolve().parents[2] / "stabjax" / "examples"
SWEEPS = Path(__file__).resolve().parents[2] / "stabjax" / "sweeps"


# ---- the clouds -------------------------------------------------------------------------------------------------

def _two_attractors(seed=0):
    """A circle of radius 1 around (5, 0) (a limit cycle, at random phases) and a point at (0, 0)."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 200)
    cyc = np.stack([5 + np.cos(ph), np.sin(ph)], axis=1)
    fp = np.zeros((60, 2)) + rng.normal(scale=1e-9, size=(60, 2))
    fin = np.concatenate([cyc, fp])
    labels = np.r_[np.zeros(200, int), np.ones(60, int)]
    res = {"feat_final": fin, "solver_status": np.zeros(260, int),
           **{k: np.stack([fin[:, 0] + i, fin[:, 1] + i], 1) for i, k in enumerate(stops._FEAT_KEYS[:-1])}}
    return labels, res


def test_clouds_cover_each_attractor_and_never_overlap():
    labels, res = _two_attractors()
    known = stops.known_attractors(labels, res, [0, 1, 2], dwell=10.0)
    assert known.labels == (0, 1)  # code 2 has no trajectory: not an attractor
    pts, scale, eps = known.points, np.asarray(known.scale), np.asarray(known.eps)
    assert pts.shape == (2, stops.CLOUD_POINTS, 2)
    # every member of an attractor lies within its radius of its cloud (brute force)
    for k, code in enumerate(known.labels):
        x = res["feat_final"][labels == code] / scale
        d = np.sqrt(((x[:, None] - pts[k][None] / scale) ** 2).sum(-1)).min(1)
        assert d.max() <= eps[k]
    # no state is within reach of both: the radii add up to at most half the clouds' distance
    gap = np.sqrt(((pts[0][:, None] / scale - pts[1][None] / scale) ** 2).sum(-1)).min()
    assert eps[0] + eps[1] <= gap / 2
    # and the traced test finds them: on the circle at new phases, at the point, and nowhere between
    ph = np.linspace(0, 2 * np.pi, 97)
    for o in np.stack([5 + np.cos(ph), np.sin(ph)], 1):
        assert float(stops.near_attractor(jnp.asarray(o), known)) == 0.0
    assert float(stops.near_attractor(jnp.asarray([0.0, 0.0]), known)) == 1.0
    assert float(stops.near_attractor(jnp.asarray([2.5, 0.0]), known)) == -1.0
    # the representative is a member of its attractor: its final value lies on the circle
    rep = known.reps[0]
    assert abs(np.hypot(rep[4, 0] - 5, rep[4, 1]) - 1) < 1e-12


def test_too_few_members_make_no_attractor():
    labels, res = _two_attractors()
    keep = np.r_[np.arange(200), np.arange(200, 200 + stops.MIN_CLOUD - 1)]
    known = stops.known_attractors(labels[keep], {k: v[keep] for k, v in res.items()}, [0, 1], dwell=1.0)
    assert known.labels == (0,)
    none = stops.known_attractors(labels[:5], {k: v[:5] for k, v in res.items()}, [0, 1], dwell=1.0)
    assert none is None


# ---- the pendulum: per start, on the lane engines --------------------------------------------------------------

def _pendulum(engine, stop, n):
    spec = load_spec(EXAMPLES / "pendulum" / "spec.toml")
    spec["sample"]["n"] = n
    spec["integrate"] = {**spec["integrate"], "engine": engine, "attractor_stop": stop}
    return make_plan(spec)


# the native runs: 512 starts in chunks of 128 (the pilot is the first quarter), the same run as the resumed and
# the Dask sweeps below compare with (one run for all three: CI time)
NATIVE_N, NATIVE_BATCH = 512, 128


@pytest.fixture(scope="module")
def pendulum_runs():
    out = {}
    for engine, n, batch in (("native", NATIVE_N, NATIVE_BATCH), ("fused", 256, 64)):
        for stop in (False, True):
            plan = _pendulum(engine, stop, n)
            out[engine, stop] = (plan, run_plan(plan, batch_size=batch))
    return out


@pytest.mark.parametrize("engine", ["native", "fused"])
def test_the_stop_never_changes_an_outcome(pendulum_runs, engine):
    plan, off = pendulum_runs[engine, False]
    _, on = pendulum_runs[engine, True]
    assert on.attrs["engine"] == engine
    np.testing.assert_array_equal(on.outcome.values, off.outcome.values)
    names = str(on.outcome.attrs["flag_meanings"]).split()
    assert str(on.stop_reason.attrs["flag_meanings"]).split()[stops.STOP_ATTRACTOR] == "attractor"
    stopped = on.stop_reason.values == stops.STOP_ATTRACTOR
    cycle = on.outcome.values == names.index("limit_cycle")
    # most starts reach the running solution; beyond the first chunk (the pilot) most of them stop there
    assert cycle.sum() > 0.5 * cycle.size
    assert stopped.sum() > 0.5 * cycle.sum()
    assert (on.stopped_at.values[stopped] < plan.icfg.t1).all()
    # a stop ends the run after at least one feature window near the attractor, never before
    window = plan.vcfg.feature_window * plan.icfg.t1
    assert (on.stopped_at.values[stopped] >= window).all()
    assert on.n_steps.values.sum() < 0.5 * off.n_steps.values.sum()


def test_a_stopped_trajectory_carries_its_attractors_features(pendulum_runs):
    _, on = pendulum_runs["native", True]
    _, off = pendulum_runs["native", False]
    stopped = on.stop_reason.values == stops.STOP_ATTRACTOR
    # the representative's features: those of a full run on the same cycle, so mean(omega) agrees with
    # every full run on the cycle to the spread of the full runs' own window means
    m_on = on.feat_mean.values[stopped, 0]
    m_off = off.feat_mean.values[stopped, 0]
    assert np.ptp(m_on) == 0.0  # one representative
    assert abs(m_on[0] - m_off.mean()) <= 2 * m_off.std() + 1e-9


def test_a_killed_sweep_resumes_with_the_same_attractors(tmp_path, pendulum_runs):
    plan, whole = pendulum_runs["native", True]  # the whole run, in one go

    def interrupt_after(k):
        def cb(i, n):
            if i >= k:
                raise KeyboardInterrupt
        return cb

    out = tmp_path / "p.nc"
    with pytest.raises(KeyboardInterrupt):
        run_plan(plan, out, batch_size=NATIVE_BATCH, on_chunk=interrupt_after(1))
    resumed = run_plan(plan, out, batch_size=NATIVE_BATCH)
    for v in ("outcome", "stop_reason", "n_steps", "stopped_at", "feat_mean"):
        np.testing.assert_array_equal(resumed[v].values, whole[v].values, err_msg=v)
    assert (whole.stop_reason.values == stops.STOP_ATTRACTOR).any()


def test_the_diffrax_engine_runs_to_t1_with_the_same_outcomes():
    """Neither stop is taken on the diffrax engine (a vmapped loop gains nothing from one), though both are on
    here (the pendulum is autonomous: early_stop defaults to true) and the lane engines take both on the same
    starts: every start runs to t1. This also covers tests/fold/test_early_stop.py's diffrax cases (slow)."""
    plan_on = _pendulum("diffrax", True, 48)
    assert plan_on.icfg.early_stop is True and stops.active(plan_on.integrated, plan_on.icfg)
    on = run_plan(plan_on, batch_size=16)
    plan_off = _pendulum("native", False, 48)
    off = run_plan(plan_off)
    np.testing.assert_array_equal(on.outcome.values, off.outcome.values)
    assert not (on.stop_reason.values == stops.STOP_ATTRACTOR).any()
    assert (on.stop_reason.values == stops.STOP_NONE).all()
    np.testing.assert_array_equal(on.stopped_at.values, plan_on.icfg.t1)


# ---- refinement: the same boundary for fewer steps -------------------------------------------------------------

def test_refinement_brackets_the_same_boundary_with_fewer_steps():
    from stabjax.explore.refine import refine_spec

    spec = load_spec(SWEEPS / "refine_pendulum.toml")
    spec["refine"] = {**spec["refine"], "rel_tol": "1/32"}
    ds = {}
    for stop in (False, True):
        spec["integrate"] = {**spec["integrate"], "attractor_stop": stop}
        ds[stop] = refine_spec(spec)
    for v in ("point_theta0", "point_omega0", "point_label", "theta0_lo", "omega0_hi", "label_lo"):
        np.testing.assert_array_equal(ds[True][v].values, ds[False][v].values, err_msg=v)
    # the first round (the coarse grid) runs to t1 and finds the attractors; the later rounds stop there
    first = ds[True].point_round.values == 0
    np.testing.assert_array_equal(ds[True].point_steps.values[first], ds[False].point_steps.values[first])
    assert ds[True].point_steps.values[~first].sum() < 0.5 * ds[False].point_steps.values[~first].sum()


# ---- where it cannot apply: refused, naming the field ----------------------------------------------------------

def test_refused_where_it_cannot_apply():
    spec = load_spec(EXAMPLES / "pendulum" / "spec.toml")
    bad = dict(spec, grid={"alpha": {"start": 0.05, "stop": 0.2, "num": 3}},
               integrate={**spec["integrate"], "attractor_stop": True})
    with pytest.raises(ValidationError) as e:  # the attractors move with a model parameter
        make_plan(bad)
    assert e.value.field == "integrate.attractor_stop" and "alpha" in e.value.message
    with pytest.raises(ValidationError) as e:
        make_plan(dict(spec, integrate={**spec["integrate"], "attractor_stop": "yes"}))
    assert e.value.field == "integrate.attractor_stop"
    with pytest.raises(ValidationError) as e:  # the runner's own field, never a spec's
        make_plan(dict(spec, integrate={**spec["integrate"], "known_attractors": [1, 2]}))
    assert e.value.field == "integrate.known_attractors"
    with pytest.raises(ValidationError) as e:  # discovery labels the whole run at the end
        make_plan(dict(spec, outcomes={"discover": True}, integrate={**spec["integrate"], "attractor_stop": True}))
    assert e.value.field == "integrate.attractor_stop"
    mono = {"system": "monoaxial", "integrate": {"t1": 100.0, "attractor_stop": True}}
    with pytest.raises(ValidationError) as e:  # the attitude verdicts read the run up to t1
        make_plan(mono)
    assert e.value.field == "integrate.attractor_stop"


def test_dask_workers_stop_at_the_same_attractors(pendulum_runs):
    """The first chunk runs on a worker like any other; the attractors found from it travel with the plan,
    so a Dask run gives, per start, what the run in this process gives."""
    from stabjax.run import distributed as D

    plan, here = pendulum_runs["native", True]
    with D.DaskExecutor(workers=1, threads=1) as ex:
        there = run_plan(plan, batch_size=NATIVE_BATCH, executor=ex)
    for v in ("outcome", "stop_reason", "n_steps", "feat_mean"):
        np.testing.assert_array_equal(there[v].values, here[v].values, err_msg=v)
    assert (there.stop_reason.values == stops.STOP_ATTRACTOR).sum() > 128


def test_the_sweep_says_how_many_stopped_early(tmp_path, capsys):
    """`stabjax sweep` prints how many trajectories ended before t1 and why, counted from the dataset. (The
    command's main in this process: the kernels of the runs above serve it.)"""
    import shutil

    import xarray as xr

    from stabjax.app.cli import main

    for f in ("model.py", "spec.toml"):
        shutil.copy(EXAMPLES / "pendulum" / f, tmp_path / f)
    spec = (tmp_path / "spec.toml").read_text().replace("n = 2000", "n = 384")
    (tmp_path / "spec.toml").write_text(spec.replace("n_checkpoints = 4000", "n_checkpoints = 4000\nattractor_stop = true"))
    out = tmp_path / "p.nc"
    try:
        main(["sweep", str(tmp_path / "spec.toml"), "--out", str(out), "--no-plot"])
    except SystemExit as exc:
        assert not exc.code, capsys.readouterr()
    stdout = " ".join(capsys.readouterr().out.split())  # as printed, whatever the console's line width
    with xr.open_dataset(out) as ds:
        codes = ds.stop_reason.values
    n_fp, n_at = int((codes == stops.STOP_FIXED_POINT).sum()), int((codes == stops.STOP_ATTRACTOR).sum())
    assert n_at > 0
    assert f"stopped early, fate decided: {n_fp:,} at a stable fixed point, {n_at:,} near an attractor" in stdout
