"""Adaptive boundary refinement (stabjax.explore.refine) on a model whose boundary is known in closed form.

The damped linear oscillator x'' + (c - k) x' + x = 0 from (x, x') = (1, 0): with d = c - k,
d/dt (x^2 + x'^2) = -2 d x'^2, so the error e = |(x, x')| (distance to the equilibrium 0) decreases
monotonically for k < c and grows for k > c. The thresholds (refine_models.py) make the verdict change exactly
there, up to a band set by the horizon: converged needs e < 0.999 over the late window [t1/2, t1],
i.e. roughly exp(-d t1 / 4) < 0.999, d > 4 ln(1/0.999) / t1 = 8e-5; diverged needs the size e to pass
1.001 by t1, d < -2 ln(1.001) / t1 = -4e-5 (e^2 grows like exp(|d| t) on average). So the empirical
boundary lies in k in [c - DELTA, c + DELTA] with DELTA = 1e-3, ten times those bands, and far below
the tolerances tested (1/64 of the axis range and more).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from refine_models import T1, DampedOscillator, EscapingOscillator, NamedOutcomes
from stabjax.model import registry
from stabjax.fold import verdict as V
from stabjax.errors import ValidationError
from stabjax.model.system import VerdictConfig

DELTA = 1e-3


@pytest.fixture
def oscillator(monkeypatch):
    monkeypatch.setitem(registry.SYSTEMS, "test_oscillator", "refine_models:DampedOscillator")
    monkeypatch.setitem(registry._cache, "test_oscillator", DampedOscillator())
    return registry._cache["test_oscillator"]


def spec(grid, refine, **extra):
    return {"system": "test_oscillator", "name": "osc", "grid": grid, "refine": refine,
            "integrate": {"t1": T1, "n_checkpoints": 200, "rtol": 1e-8, "atol": 1e-10}, **extra}


C1 = 0.5 + 1 / 7  # c in the 1-D tests: no lattice point lands on the boundary


def closed_form(k, c):
    return np.where(k < c - DELTA, V.CONVERGED, np.where(k > c + DELTA, V.DIVERGED, -1))


def test_closed_form_labels(oscillator):
    """The verdicts on both sides agree with the closed form (the premise of the tests below)."""
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_points

    plan = make_plan(spec({"k": [0.0, 1.0]}, {}, params={"c": C1}))
    k = np.array([0.0, C1 - 0.01, C1 - 2 * DELTA, C1 + 2 * DELTA, C1 + 0.01, 1.0])
    res, info = run_points(plan, k[:, None])
    assert info["n_chunks"] == 1 and info["n_resumed"] == 0
    np.testing.assert_array_equal(np.asarray(res["verdict"])[:, -1], closed_form(k, C1))  # at t1


def test_bisection_1d_brackets_boundary(oscillator):
    from stabjax.explore.refine import refine_spec

    tol = 0.004
    ds = refine_spec(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": {"k": tol}}, params={"c": C1}))
    assert ds.attrs["n_segments"] == 1 and ds.attrs["n_unbracketed"] == 0
    lo, hi = float(ds["k_lo"][0]), float(ds["k_hi"][0])
    assert 0 < hi - lo <= tol
    assert lo - DELTA <= C1 <= hi + DELTA  # the exact boundary k = c is inside the bracket (up to the horizon band)
    assert {int(ds["label_lo"][0]), int(ds["label_hi"][0])} <= {V.CONVERGED, V.UNDECIDED, V.DIVERGED}
    np.testing.assert_array_equal(ds["point_label"].values, closed_form(ds["point_k"].values, C1))
    # 4 coarse intervals of 0.25 halved 6 times (0.25/64 <= 0.004 < 0.25/32): bisection costs 5 + 6 points, not 257
    assert list(np.atleast_1d(ds.attrs["lattice_shape"])) == [257] and ds.attrs["n_points"] == 5 + 6
    # theory: k < c - 0.1 -> the empirical boundary lies 0.1 beyond the theorem's, on its unsafe side
    np.testing.assert_allclose(float(ds["theory_distance_k"][0]), 0.1 + float(ds["k_mid"][0]) - C1, atol=1e-9)


def test_quadtree_2d_brackets_boundary_and_resumes(oscillator, tmp_path):
    from stabjax.explore.refine import refine_spec
    from stabjax.present.refinement import plot_refine
    from stabjax.run.sweep import open_result

    grid = {"k": {"start": 0.0, "stop": 1.0, "num": 5}, "c": {"start": 0.2, "stop": 0.8, "num": 4}}
    s = spec(grid, {"rel_tol": "1/64"})
    out = tmp_path / "osc.nc"
    ds = refine_spec(s, out, keep_store=True)
    tk, tc = 1 / 64, 0.6 / 64
    assert ds.attrs["n_segments"] > 0 and ds.attrs["n_unbracketed"] == 0
    wk, wc = ds["width_k"].values, ds["width_c"].values
    along_k = ds["segment_axis"].values == 0
    assert np.all(wk[along_k] <= tk * (1 + 1e-12)) and np.all(wc[~along_k] <= tc * (1 + 1e-12))
    assert np.all(wc[along_k] == 0) and np.all(wk[~along_k] == 0)
    # every bracket contains the line k = c (up to the horizon band): along k, k_lo <= c <= k_hi; along c, likewise
    klo, khi = np.minimum(ds["k_lo"], ds["k_hi"]).values, np.maximum(ds["k_lo"], ds["k_hi"]).values
    clo, chi = np.minimum(ds["c_lo"], ds["c_hi"]).values, np.maximum(ds["c_lo"], ds["c_hi"]).values
    assert np.all((klo - DELTA <= chi) & (clo <= khi + DELTA))
    assert np.all(np.abs(ds["k_mid"].values - ds["c_mid"].values) <= np.maximum(tk, tc) / 2 + DELTA)
    # the boundary crosses the whole square: every coarse row in c is represented
    assert np.ptp(ds["c_mid"].values) > 0.5
    expect = closed_form(ds["point_k"].values, ds["point_c"].values)
    band = expect == -1  # lattice points with k = c exactly (e.g. k = c = 0.5): undecided, any verdict allowed
    assert band.sum() < 0.1 * len(expect)
    np.testing.assert_array_equal(ds["point_label"].values[~band], expect[~band])
    # far fewer points than the lattice of the same resolution: k 4 intervals / 2^4, c 3 intervals / 2^5 (0.2/16 > tc)
    assert ds.attrs["full_grid_points"] == 65 * 97 and ds.attrs["n_points"] < ds.attrs["full_grid_points"] / 8
    # signed distance along k to k = c - 0.1: +0.1 (conservative) up to the bracket
    # (only for boundaries of the converged region; undecided | diverged segments in the band have none)
    st = (ds["label_lo"].values == V.CONVERGED) ^ (ds["label_hi"].values == V.CONVERGED)
    assert st.sum() > 0.5 * len(st)
    dk = ds["theory_distance_k"].values
    assert np.all(np.isnan(dk[~st]))
    np.testing.assert_allclose(dk[st], (0.1 + ds["k_mid"].values - ds["c_mid"].values)[st], atol=1e-9)
    # along c the contour c = k + 0.1 has slope 1 too, where it lies inside the c range [0.2, 0.8]
    dc = ds["theory_distance_c"].values
    inside = st & (ds["k_mid"].values + 0.1 <= 0.8)
    np.testing.assert_allclose(dc[inside], dk[inside], atol=1e-9)
    assert np.all(np.isnan(dc[~inside]))
    assert np.all(np.abs(dk[st] - 0.1) <= tk / 2 + DELTA)

    # resume: a re-run with every round's chunks stored integrates nothing and gives the identical dataset
    from stabjax.run import sweep

    def refuse(*_a, **_k):
        raise AssertionError("a resumed run must not integrate")

    assert sorted(p.name for p in (tmp_path / "osc.nc.zarr").iterdir()) == \
        [f"round_{r:04d}" for r in range(ds.attrs["rounds"])]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep, "solve_chunk", refuse)
        again = refine_spec(s, out)
    assert again.attrs["rounds_resumed"] == again.attrs["rounds"] == ds.attrs["rounds"]
    for k in ds.data_vars:
        np.testing.assert_array_equal(again[k].values, ds[k].values, err_msg=k)
    written = open_result(out)
    np.testing.assert_array_equal(written["k_mid"].values, ds["k_mid"].values)
    assert not (tmp_path / "osc.nc.zarr").exists()  # removed once the result is written
    png = tmp_path / "osc.png"
    plot_refine(written, png)
    assert png.stat().st_size > 0


def test_partial_resume_after_kill(oscillator, tmp_path):
    """A run killed after some rounds resumes them from the chunk store (the sweep's) and ends with the
    uninterrupted result, removing the store it made; a store of another spec is refused rather than mixed in."""
    from stabjax.run import store as S
    from stabjax.run import sweep
    from stabjax.errors import StabjaxError
    from stabjax.explore.refine import refine_spec

    # 1/16: 2 coarse intervals of 0.5 halved 3 times, 4 rounds: the kill lands in the third
    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 3}}, {"rel_tol": 1 / 16}, params={"c": C1})
    full = refine_spec(s)
    assert full.attrs["rounds"] >= 4
    solve = sweep.solve_chunk
    calls = []

    def dies_after_two(*a, **k):  # every round here is one chunk: the third round's chunk is interrupted
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(1)
        return solve(*a, **k)

    out = tmp_path / "osc1.nc"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep, "solve_chunk", dies_after_two)
        with pytest.raises(KeyboardInterrupt):
            refine_spec(s, out)
    rounds = sorted((tmp_path / "osc1.nc.zarr").iterdir())
    assert [r.name for r in rounds] == ["round_0000", "round_0001", "round_0002"]
    assert [len(S.read_manifest(r)["chunks"]) for r in rounds] == [1, 1, 0]
    # a changed spec is refused rather than mixed in (these very stores, left as they were: resumed below)
    with pytest.raises(StabjaxError, match="different computation"):
        refine_spec({**s, "params": {"c": 0.6}}, out)
    resumed = refine_spec(s, out, store=tmp_path / "osc1.nc.zarr")  # the default place, named as the CLI does
    assert resumed.attrs["rounds_resumed"] == 2
    assert not (tmp_path / "osc1.nc.zarr").exists()  # the sweep's own folder goes with its rounds (it stayed, empty)
    for k in ("k_lo", "k_hi", "label_lo", "label_hi", "point_k", "point_label", "point_steps"):
        np.testing.assert_array_equal(resumed[k].values, full[k].values)


def test_kept_rounds_point_to_the_result(oscillator, tmp_path, capsys):
    """A refinement kept with its rounds (``keep_store``): ``export`` of one round said "incomplete: 1 of 1
    chunks finished; run the sweep command again" (a round is never a finished sweep), and of the folder
    "not a stabjax store". Both are refused (exit 2) naming what the folder is and where the result is."""
    from clirun import captured

    from stabjax.explore.refine import refine_spec

    out = tmp_path / "kept.nc"
    refine_spec(spec({"k": {"start": 0.0, "stop": 1.0, "num": 3}}, {"rel_tol": 1 / 16}, params={"c": C1}), out,
                keep_store=True)
    folder = tmp_path / "kept.nc.zarr"
    for target, said in ((folder / "round_0000", "is one round of a refinement or a shock search"),
                         (folder, "not a stabjax store")):
        code, _, err = captured(capsys, "export", target, "--out", tmp_path / "x.nc")
        assert code == 2 and said in err and f"the search's result is {out}" in err, err
        assert "run the sweep command again" not in err and not (tmp_path / "x.nc").exists()


def test_samples_dominant_label_and_pair(oscillator):
    """With samples a point's label is its dominant outcome; pair restricts which boundaries count."""
    from stabjax.explore.refine import refine_spec

    # x0 in [1, 1.0005]: below diverge_size and above settle_tol at t = 0, so the closed form still holds
    # (the horizon bands grow to 1.2e-4 at most, within DELTA)
    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01, "pair": ["converged", "*"]},
             params={"c": C1}, sample={"n": 3, "seed": 1, "x0": {"dist": "uniform", "low": 1.0, "high": 1.0005}})
    ds = refine_spec(s)
    assert ds.attrs["n_trajectories"] == 3 * ds.attrs["n_points"]
    assert np.all(ds["point_share"].values == 1.0)
    assert ds.attrs["n_segments"] == 1
    assert int(ds["label_lo"][0]) == V.CONVERGED and int(ds["label_hi"][0]) != V.CONVERGED
    assert float(ds["k_lo"][0]) - DELTA <= C1 <= float(ds["k_hi"][0]) + DELTA
    # a pair that never meets (converged next to failed): nothing to bracket
    ds2 = refine_spec(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01, "pair": ["converged", "failed"]},
                           params={"c": C1}))
    assert ds2.attrs["n_segments"] == 0 and ds2.attrs["n_points"] == 5


def test_dominant_label_and_horizon_column():
    """Unit test of the label reduction: mode over samples (ties -> lower code); (N, H) verdicts -> one column."""
    from types import SimpleNamespace

    from stabjax.explore.refine_config import RefineConfig, _labels

    def ok(v):  # every trajectory reached t1 (solver_status 0)
        return {"verdict": v, "solver_status": np.zeros(len(v), np.int32)}

    cfg = RefineConfig(tol=(0.1,), levels=(1,), label="verdict", names=V.NAMES, pair=None, stable="converged",
                       horizons=(100.0,), max_points=10)
    plan = SimpleNamespace(vcfg=V.bind(VerdictConfig(), 0.0, 100.0, horizons=[10.0, 1.0]),
                           icfg=SimpleNamespace(t1=100.0, t0=0.0))
    lab, share = _labels(plan, cfg, ok(np.array([1, 1, 0, 3, 0, 3])), 2)  # 2 points x 3 samples
    np.testing.assert_array_equal(lab, [[1], [3]])  # (points, horizons)
    np.testing.assert_allclose(share, [[2 / 3], [2 / 3]])
    lab, share = _labels(plan, cfg, ok(np.array([3, 0, 2, 2])), 2)  # a tie goes to the lower code
    np.testing.assert_array_equal(lab, [[0], [2]])
    np.testing.assert_allclose(share, [[1 / 2], [1]])
    hv = np.array([[1, 2, 0], [1, 2, 3]])  # horizons 1, 10, 100 (t1)
    np.testing.assert_array_equal(_labels(plan, cfg, ok(hv), 2)[0], [[0], [3]])
    cfg10 = RefineConfig(**{**cfg.__dict__, "horizons": (10.0,)})
    np.testing.assert_array_equal(_labels(plan, cfg10, ok(hv), 2)[0], [[2], [2]])
    both = RefineConfig(**{**cfg.__dict__, "horizons": (1.0, 100.0)})  # several horizons: their columns, in order
    np.testing.assert_array_equal(_labels(plan, both, ok(hv), 2)[0], [[1, 0], [1, 3]])
    # samples x horizons: the mode is taken per horizon (point 0: horizon 1 -> 1, horizon 100 -> 0 by a tie)
    hs = np.array([[1, 0], [1, 2], [2, 2], [3, 3]])  # 2 points x 2 samples, columns = horizons 1 and 100 of (1, 10, 100)
    lab, share = _labels(plan, both, ok(np.stack([hs[:, 0], hs[:, 0], hs[:, 1]], axis=1)), 2)
    np.testing.assert_array_equal(lab, [[1, 0], [2, 2]])
    np.testing.assert_allclose(share, [[1, 1 / 2], [1 / 2, 1 / 2]])


@pytest.mark.parametrize("refine, field", [
    ({"tol": {"k": float("nan")}}, "refine.tol.k"),
    ({"tol": {"k": -1.0}}, "refine.tol.k"),
    ({"tol": {"q": 0.1}}, "refine.tol.q"),
    ({"tol": "abc"}, "refine.tol"),
    ({"rel_tol": float("inf")}, "refine.rel_tol"),
    ({"rel_tol": 2}, "refine.rel_tol"),
    ({"rel_tol": True}, "refine.rel_tol"),
    ({"bogus": 1}, "refine.bogus"),
    ({"pair": ["converged"]}, "refine.pair"),
    ({"pair": ["converged", "nope"]}, "refine.pair"),
    ({"horizon": 1e9}, "refine.horizon"),
    ({"horizon": 10.0}, "refine.horizon"),  # no multi-horizon verdicts in this plan
    ({"label": "colour"}, "refine.label"),
    ({"label": "outcome"}, "refine.label"),  # the oscillator declares no named outcomes
    ({"stable": "stable"}, "refine.stable"),
    ({"max_points": 0}, "refine.max_points"),
    ({"max_points": 2.5}, "refine.max_points"),
    ({"max_points": "1000"}, "refine.max_points"),
    ({"tol": 1e-12}, "refine.tol"),  # lattice too large
    ({"tol": {"k": 1e-12}}, "refine.tol.k"),
    ({"rel_tol": 1e-12}, "refine.rel_tol"),  # the field set is named (was refine.tol, which was not set)
    ("x", "refine"),
])
def test_bad_refine_fields(oscillator, refine, field):
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    plan = make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, refine))
    with pytest.raises(ValidationError) as exc:
        refine_config(plan)
    assert exc.value.field == field


def test_max_points_is_a_count_like_every_other(oscillator):
    """An integral float (1e3) is the count every other integer field takes, not an error."""
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    cfg = refine_config(make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"max_points": 1e3})))
    assert cfg.max_points == 1000 and isinstance(cfg.max_points, int)


def test_bad_grids(oscillator):
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    for grid, field in [({"k": [0.5]}, "grid.k"), ({"k": [0.0, 0.5, 0.2]}, "grid.k"), ({}, "grid"),
                        ({"k": [0.0, 1.0], "c": [0.0, 1.0], "x0": [1.0, 2.0]}, "grid")]:
        with pytest.raises(ValidationError) as exc:
            refine_config(make_plan(spec(grid, {})))
        assert exc.value.field == field


def test_a_store_folder_of_the_users_keeps_its_files(oscillator, tmp_path):
    """``--store DIR`` naming a folder that holds a user's file: only the rounds' stores are removed (the
    whole tree was); what will be replaced is said once the first round's store accepted the run."""
    from stabjax.explore.refine import refine_spec
    from user_store import check_said_once_the_store_accepts, check_user_store_folder_kept

    # 1/4: 2 coarse intervals of 0.5 halved once, 2 rounds (the checks need more than one)
    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 3}}, {"rel_tol": "1/4"}, params={"c": C1})
    check_user_store_folder_kept(lambda out, **kw: refine_spec(s, out, **kw), tmp_path)
    check_said_once_the_store_accepts(lambda out, **kw: refine_spec(s, out, **kw), tmp_path)


def test_cli_sweep_with_refine_and_bad_field(oscillator, tmp_path, capsys):
    """`stabjax sweep` runs the refinement for a spec with [refine]; a bad field exits 2 naming it, writing nothing."""
    from stabjax.app.cli import main
    from stabjax.run.sweep import open_result

    body = f"""system = "test_oscillator"
name = "osc"
[params]
c = {C1!r}
[grid]
k = {{start = 0.0, stop = 1.0, num = 5}}
[integrate]
t1 = {T1}
n_checkpoints = 200
"""
    good = tmp_path / "good.toml"
    good.write_text(body + "[refine]\nrel_tol = \"1/16\"\n")  # 0.25 halved twice: 3 rounds
    out = tmp_path / "good.nc"
    main(["sweep", str(good), "--out", str(out), "--no-progress"])
    ds = open_result(out)
    assert ds.attrs["kind"] == "refine" and ds.attrs["n_segments"] == 1
    assert float(ds["k_lo"][0]) - DELTA <= C1 <= float(ds["k_hi"][0]) + DELTA
    assert out.with_suffix(".png").exists()
    assert "boundary segments" in capsys.readouterr().out
    assert not (tmp_path / "good.nc.zarr").exists()  # the round stores are removed once the result is written

    # the sweep runner's options apply to a refinement too: chunks of --batch-size in --store, kept with --keep-store
    out2, store = tmp_path / "good2.nc", tmp_path / "rounds.zarr"
    main(["sweep", str(good), "--out", str(out2), "--no-plot", "--progress", "--batch-size", "2", "--store", str(store),
          "--keep-store"])
    ds2 = open_result(out2)
    for k in ("k_lo", "k_hi", "point_k", "point_label", "point_steps"):
        np.testing.assert_array_equal(ds2[k].values, ds[k].values, err_msg=k)
    rounds = sorted(store.iterdir())
    assert [r.name for r in rounds] == [f"round_{i:04d}" for i in range(ds.attrs["rounds"])]
    from stabjax.run import store as S

    for r, pts in zip(rounds, np.bincount(ds2["point_round"].values)):
        m = S.read_manifest(r)
        assert m["batch_size"] == min(2, pts) and len(m["chunks"]) == -(-int(pts) // 2)

    bad = tmp_path / "bad.toml"
    bad.write_text(body + "[refine]\ntol = {k = nan}\n")
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(bad), "--out", str(tmp_path / "bad.nc")])
    assert exc.value.code == 2
    assert "refine.tol.k" in capsys.readouterr().err
    assert not (tmp_path / "bad.nc").exists() and not (tmp_path / "bad.nc.zarr").exists()


def _by_values(plan, solve_points):
    """A refiner's ``evaluate(round, values)`` from a closed form of the points' parameters (no integration)."""
    import dataclasses

    def evaluate(_r, values):
        pp = dataclasses.replace(plan, points=values)
        return solve_points(pp.params_for(0, pp.size))
    return evaluate


def _synthetic(inside):
    """A solve_points that labels points by a closed-form region (no integration): converged inside."""
    def solve_points(p):
        v = np.where(inside(p), V.CONVERGED, V.FLIPPED).astype(np.int8)
        return {"verdict": v, "solver_status": np.zeros(len(v), np.int32), "n_steps": np.ones(len(v), np.int64)}
    return solve_points


def test_quadtree_finds_every_edge_of_a_curved_boundary(oscillator):
    """Disk boundary (k - 0.5)^2 + (c - 0.5)^2 = 0.3^2 on a log c axis: the refinement finds exactly the
    boundary edges of the full lattice of the same resolution, and never evaluates a point twice."""
    from stabjax.explore.refine import Refiner
    from stabjax.explore.refine_config import fine_values, refine_config
    from stabjax.plan.spec import make_plan

    inside = lambda p: (p["k"] - 0.5) ** 2 + (p["c"] - 0.5) ** 2 < 0.09
    plan = make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 9}, "c": {"start": 0.1, "stop": 1.0, "num": 7, "log": True}},
                          {"tol": {"k": 0.01, "c": 0.005}}))
    cfg = refine_config(plan)
    ref = Refiner(plan, cfg).run(_by_values(plan, _synthetic(inside)))
    kf, cf = ref.fine
    np.testing.assert_array_equal(cf[:: 2 ** cfg.levels[1]], plan.grid[1].values)
    assert np.max(np.diff(cf)) <= 0.005 and np.max(np.diff(kf)) <= 0.01
    assert np.max(np.diff(cf)) > 0.005 / 2  # the fewest halvings
    np.testing.assert_allclose(np.diff(np.log(cf))[:4], np.diff(np.log(cf))[0])  # geometric within a coarse interval
    K, C = np.meshgrid(kf, cf, indexing="ij")
    full = inside({"k": K, "c": C})
    edges = {(0, (i, j), (i + 1, j)) for i, j in zip(*np.nonzero(full[1:] != full[:-1]))}
    edges |= {(1, (i, j), (i, j + 1)) for i, j in zip(*np.nonzero(full[:, 1:] != full[:, :-1]))}
    assert set(ref.segments()) == edges
    coords = np.concatenate(ref.coords)
    assert len({tuple(c) for c in coords}) == len(coords) < full.size / 4
    np.testing.assert_array_equal(ref.lab[tuple(coords.T)], np.where(full[tuple(coords.T)], 0, 1))


def test_benchmark_against_full_lattice(oscillator, tmp_path):
    """The benchmark's bookkeeping on the oscillator: the full lattice (1-D, 65 points) holds exactly one
    boundary edge, found by the refinement, with the same labels at the shared points; --full-from re-uses it."""
    from benchmarks.refine_bench import benchmark, format_benchmark

    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 3}}, {"rel_tol": 1 / 64, "pair": ["converged", "*"]},
             params={"c": C1})
    full_nc = tmp_path / "full.nc"
    r = benchmark(s, out=full_nc)
    assert r["lattice"] == [65] and r["full_trajectories"] == 65 and r["refine_trajectories"] == 3 + 5
    assert r["full_boundary_edges"] == 1 and r["missed_edges"] == 0
    assert r["labels_agree"] == r["labels_compared"] == 8
    assert r["full_steps"] > r["refine_steps"] > 0 and r["ratio_steps"] == r["full_steps"] / r["refine_steps"]
    again = benchmark(s, full_from=full_nc)
    assert again["full_steps"] == r["full_steps"] and again["refine_steps"] == r["refine_steps"]
    assert "full / refinement" in format_benchmark(again)
    with pytest.raises(ValidationError, match="full_from"):
        benchmark({**s, "params": {"c": 0.6}}, full_from=full_nc)


def test_named_outcomes_label_and_pair(monkeypatch):
    from stabjax.explore.refine import Refiner, assemble
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    monkeypatch.setitem(registry.SYSTEMS, "test_named", "refine_models:NamedOutcomes")
    monkeypatch.setitem(registry._cache, "test_named", NamedOutcomes())

    def solve_points(p):  # outcome by closed form: decays below k = 0.3, rings up to 0.6, grows above
        o = np.where(p["k"] < 0.3, 0, np.where(p["k"] < 0.6, 1, 2)).astype(np.int8)
        return {"outcome": o, "verdict": np.zeros_like(o), "n_steps": np.ones(len(o), np.int64)}

    s = {**spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01, "pair": ["decays", "rings"]}),
         "system": "test_named"}
    plan = make_plan(s)
    cfg = refine_config(plan)
    assert cfg.label == "outcome" and cfg.stable == "decays"
    assert cfg.names == ("decays", "rings", "grows", "unclassified", "failed")
    ds = assemble(Refiner(plan, cfg).run(_by_values(plan, solve_points)))
    assert ds.attrs["n_segments"] == 1  # rings | grows is not part of the pair
    assert float(ds["k_lo"][0]) < 0.3 <= float(ds["k_hi"][0]) and float(ds["width_k"][0]) <= 0.01
    assert ds["label_lo"].attrs["flag_meanings"] == "decays rings grows unclassified failed"
    with pytest.raises(ValidationError, match="refine.pair"):
        refine_config(make_plan({**s, "refine": {"pair": ["decays", "converged"]}}))


def test_resume_refuses_another_horizon(oscillator, tmp_path):
    """Stored rounds belong to one t1: a --t1 override (not part of the spec) is a different computation."""
    from stabjax.run import store as S
    from stabjax.errors import StabjaxError
    from stabjax.explore.refine import refine_spec

    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 3}}, {"rel_tol": 1 / 8}, params={"c": C1})
    with pytest.raises(StabjaxError, match="max_points"):  # stops after the coarse round: 3 points stored
        refine_spec({**s, "refine": {**s["refine"], "max_points": 3}}, tmp_path / "o.nc")
    with pytest.raises(StabjaxError, match="different computation"):
        refine_spec(s, tmp_path / "o.nc", t1=2 * T1)
    # max_points only stops a run: raising it resumes the same run
    s2 = {**s, "refine": {**s["refine"], "max_points": 4}}
    with pytest.raises(StabjaxError, match="max_points"):
        refine_spec(s2, tmp_path / "p.nc")
    rounds = sorted((tmp_path / "p.nc.zarr").iterdir())  # 3 coarse points + 1 bisection
    assert [len(S.read_manifest(r)["chunks"]) for r in rounds] == [1, 1]
    done = refine_spec({**s2, "refine": {**s["refine"], "max_points": 100}}, tmp_path / "p.nc")
    assert done.attrs["rounds_resumed"] == 2 and done.attrs["n_points"] == 3 + 2  # 0.5 halved twice <= 1/8


def test_multi_horizon_verdicts_refine_t1_by_default(oscillator):
    """Results shaped (N, n_horizons) (horizons ascending, last = t1): without [refine] horizon, t1's column."""
    from stabjax.explore.refine import Refiner, assemble
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    def solve_points(p):
        at_t1 = np.where(p["k"] < 0.37, V.CONVERGED, V.FLIPPED)
        early = np.where(p["k"] < 0.81, V.CONVERGED, V.UNDECIDED)  # a different boundary at an earlier horizon
        v = np.stack([early, early, at_t1], axis=1).astype(np.int8)
        return {"verdict": v, "solver_status": np.zeros(len(v), np.int32), "n_steps": np.ones(len(v), np.int64)}

    plan = make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01}))
    ds = assemble(Refiner(plan, refine_config(plan)).run(_by_values(plan, solve_points)))
    assert ds.attrs["n_segments"] == 1 and float(ds["k_lo"][0]) < 0.37 <= float(ds["k_hi"][0])


def test_refine_named_outcome_of_a_user_model_file(tmp_path):
    """Refinement labels by a user model's named outcome (rules over features), the boundary from a closed form.

    tests/models/oscillator.py: x'' + (c - k) x' + x = 0 from (1, 0); "grows" when the amplitude
    sqrt(x^2 + v^2) at t1 = 40 exceeds 10. With g = (k - c)/2, w = sqrt(1 - g^2):
    x = e^{gt}(cos wt - (g/w) sin wt), v = -e^{gt} sin(wt) / w.
    """
    from pathlib import Path

    from scipy.optimize import brentq

    from stabjax.explore.refine import refine_spec

    def amp(k, c=0.5, t=40.0):
        g = (k - c) / 2
        w = np.sqrt(1 - g * g)
        x = np.exp(g * t) * (np.cos(w * t) - g / w * np.sin(w * t))
        v = -np.exp(g * t) * np.sin(w * t) / w
        return np.hypot(x, v)

    k_star = brentq(lambda k: amp(k) - 10.0, 0.55, 0.8)
    model = Path(__file__).parents[1] / "models" / "oscillator.py"
    s = {"system": f"{model}:Oscillator", "grid": {"k": {"start": 0.5, "stop": 0.9, "num": 5}},
         "integrate": {"t1": 40.0, "n_checkpoints": 64, "rtol": 1e-10, "atol": 1e-12},
         "refine": {"tol": {"k": 1e-3}, "pair": ["grows", "*"]}}
    ds = refine_spec(s, tmp_path / "r.nc")
    assert ds.attrs["n_segments"] == 1
    assert float(ds["k_lo"][0]) <= k_star <= float(ds["k_hi"][0])
    assert float(ds["width_k"][0]) <= 1e-3
    # the model states no theorem: no theory variables (they were NaN distances to a contour that is not there),
    # and the page says neither "the theorem's boundary" nor checks the result never made (verdicts, solver)
    from stabjax.present.report import _checked, render

    assert not [k for k in ds.variables if "theory" in str(k)]
    page = render(ds)
    assert "the theorem's boundary" not in page and "verdicts stable" not in page
    assert _checked(ds).startswith("every boundary segment bracketed within the tolerance")


def test_refine_and_sweep_label_an_escaped_point_alike(monkeypatch):
    """One rule for an escape (stabjax.fold.status): a point whose trajectory escapes is *diverged* in the
    refinement's labels exactly as in a sweep's verdicts at the same parameters. Fails if refine reads the
    classifier's raw verdict (failed) while the sweep maps the escape to diverged, or vice versa."""
    from stabjax.fold import status
    from stabjax.explore.refine import refine_spec
    from stabjax.run.sweep import run_spec

    monkeypatch.setitem(registry.SYSTEMS, "test_escaping_oscillator", "refine_models:EscapingOscillator")
    monkeypatch.setitem(registry._cache, "test_escaping_oscillator", EscapingOscillator())
    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": {"k": 0.02}}, params={"c": C1},
             system="test_escaping_oscillator")
    ref = refine_spec(s)
    k = ref["point_k"].values
    sw = run_spec({**{key: v for key, v in s.items() if key != "refine"}, "grid": {"k": k.tolist()}})
    esc = sw["solver_status"].values == status.ESCAPED
    # the premise: the far side escapes (e^2 ~ exp((k - c) t) passes 4 by t1 = 50 for k - c > ln 4 / 50)
    assert np.all(esc[k > C1 + 0.05]) and not np.any(esc[k < C1]) and esc.sum() >= 2
    np.testing.assert_array_equal(ref["point_label"].values, sw["verdict"].values[:, -1])
    assert np.all(ref["point_label"].values[esc] == V.DIVERGED)
    assert np.all(ref["point_label"].values[k < C1 - DELTA] == V.CONVERGED)


def test_identity_covers_the_points_of_a_round(oscillator, tmp_path):
    """The run's identity (stabjax.plan.identity) covers ``Plan.points``: a round's chunk store holding other points
    of the same count is refused (and recomputed with restart), the same points resume without integrating.
    Fails if the identity hashes only the grid axes (two rounds of equal size would share a fingerprint and
    the second would silently read the first one's verdicts), or if run_points still needs a digest of its
    own in the overrides."""
    import dataclasses

    from stabjax.plan import identity as I
    from stabjax.run import sweep
    from stabjax.plan.spec import make_plan
    from stabjax.run.store import StoreError, read_manifest
    from stabjax.run.sweep import run_points

    plan = make_plan(spec({"k": [0.0, 1.0]}, {}, params={"c": C1}))
    a = np.array([[0.1], [C1 - 0.01], [0.9]])
    b = np.array([[0.1], [C1 + 0.01], [0.9]])  # same count, one point on the other side of the boundary
    pa, pb = dataclasses.replace(plan, points=a), dataclasses.replace(plan, points=b)
    assert I.parameter_digest(pa) != I.parameter_digest(pb) != I.parameter_digest(plan)
    assert I.fingerprint(pa) != I.fingerprint(pb)
    assert I.fingerprint(pa) == I.fingerprint(dataclasses.replace(plan, points=a.copy()))
    assert I.fingerprint(dataclasses.replace(plan, points=a[::-1].copy())) != I.fingerprint(pa)  # order counts

    store = tmp_path / "round.zarr"
    res_a, info = run_points(plan, a, store=store, keep_store=True)
    assert info["n_resumed"] == 0
    assert "points" not in read_manifest(store)["identity"]["overrides"]  # no workaround digest
    np.testing.assert_array_equal(np.asarray(res_a["verdict"])[:, -1], closed_form(a[:, 0], C1))

    def refuse(*_a, **_k):
        raise AssertionError("the same points must resume, not integrate")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep, "solve_chunk", refuse)
        again, info = run_points(plan, a, store=store, keep_store=True)
    assert info["n_resumed"] == info["n_chunks"]
    np.testing.assert_array_equal(again["verdict"], res_a["verdict"])
    with pytest.raises(StoreError, match="different computation.*parameters"):
        run_points(plan, b, store=store, keep_store=True)
    res_b, info = run_points(plan, b, store=store, restart=True, keep_store=True)
    assert info["n_resumed"] == 0  # recomputed
    np.testing.assert_array_equal(np.asarray(res_b["verdict"])[:, -1], closed_form(b[:, 0], C1))
    assert closed_form(b[1:2, 0], C1)[0] != closed_form(a[1:2, 0], C1)[0]


def test_two_axis_refinement_dataset_is_cf(oscillator, tmp_path):
    """A 2-D refinement's dataset over two horizons (disk boundaries by closed form, no integration) passes the CF check of
    tests/run/test_cf.py in memory and read back from netCDF: segment_axis decodes to the axis names, every label
    variable to the verdict names. Fails if a variable lacks units/long_name or a code lacks a meaning."""
    import xarray as xr
    from cfcheck import REFINE_CATEGORICAL, check_cf

    from stabjax.explore.refine import Refiner, assemble
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import write

    disks = [lambda p, r=r: (p["k"] - 0.5) ** 2 + (p["c"] - 0.5) ** 2 < r * r for r in (0.35, 0.3)]
    plan = make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}, "c": {"start": 0.1, "stop": 1.0, "num": 4}},
                          {"tol": 0.05, "horizons": "all"}, verdict={"horizons": [5.0]}))
    ds = assemble(Refiner(plan, refine_config(plan)).run(_by_values(plan, _by_horizon(disks))))
    along = ds["segment_axis"].values
    assert set(along) == {0, 1} and list(ds["horizon"].values) == [5.0, T1]
    np.testing.assert_array_equal((ds["segment_axis"].cf == "k").values, along == 0)
    categorical = (*REFINE_CATEGORICAL, "segment_axis", "point_label_by_horizon")
    check_cf(ds, categorical, theory_flags=False, system="test_oscillator")
    write(ds, tmp_path / "r2.nc")
    with xr.open_dataset(tmp_path / "r2.nc") as back:
        check_cf(back.load(), categorical, theory_flags=False, system="test_oscillator")


def _by_horizon(boundaries):
    """A solve_points whose verdict at horizon h (columns: the plan's horizons, ascending) is converged where
    ``boundaries[h](p)`` holds, flipped elsewhere (closed forms, no integration)."""
    def solve_points(p):
        v = np.stack([np.where(inside(p), V.CONVERGED, V.FLIPPED) for inside in boundaries], axis=1).astype(np.int8)
        return {"verdict": v, "solver_status": np.zeros(len(v), np.int32), "n_steps": np.ones(len(v), np.int64)}
    return solve_points


def test_multi_horizon_1d_brackets_each_horizon(oscillator):
    """``horizons = "all"``: one run brackets the boundary of every horizon (closed forms k = 0.81 at T = 5,
    0.6 at T = 20, 0.37 at t1 = 50). Each bracket holds its own boundary and is within the tolerance; the
    points are the coarse grid plus each boundary's bisection (the three single-horizon runs' points, the
    shared coarse grid counted once); every point's label at each horizon is that horizon's closed form.
    Fails if a horizon's boundary is not refined, or labels are read from the wrong horizon column."""
    from stabjax.explore.refine import Refiner, assemble
    from stabjax.explore.refine_config import refine_config
    from stabjax.present.refinement import format_summary
    from stabjax.plan.spec import make_plan

    bounds = {5.0: 0.81, 20.0: 0.6, 50.0: 0.37}
    solve = _by_horizon([lambda p, b=b: p["k"] < b for b in bounds.values()])
    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01, "horizons": "all"},
             verdict={"horizons": [5.0, 20.0]})
    plan = make_plan(s)
    cfg = refine_config(plan)
    assert cfg.horizons == (5.0, 20.0, 50.0) and cfg.horizon == 50.0
    ds = assemble(Refiner(plan, cfg).run(_by_values(plan, solve)))
    assert ds.attrs["n_segments"] == 3 and ds.attrs["n_unbracketed"] == 0
    np.testing.assert_array_equal(ds["segment_horizon"].values, [5.0, 20.0, 50.0])
    for h, b in bounds.items():
        sel = ds["segment_horizon"].values == h
        lo, hi = float(ds["k_lo"].values[sel][0]), float(ds["k_hi"].values[sel][0])
        assert lo < b <= hi and hi - lo <= 0.01, (h, lo, hi)
    singles = []
    for h in bounds:
        p1 = make_plan({**s, "refine": {"tol": 0.01, "horizon": h}})
        singles.append(Refiner(p1, refine_config(p1)).run(_by_values(p1, solve)).n_points)
    assert ds.attrs["n_points"] == sum(singles) - 2 * 5  # the coarse grid (5 points) is shared
    k = ds["point_k"].values
    expect = np.stack([np.where(k < b, V.CONVERGED, V.FLIPPED) for b in bounds.values()], axis=1)
    np.testing.assert_array_equal(ds["point_label_by_horizon"].values, expect)
    np.testing.assert_array_equal(ds["point_label"].values, expect[:, -1])  # the longest horizon
    np.testing.assert_array_equal(ds["horizon"].values, [5.0, 20.0, 50.0])
    text = format_summary(ds)
    for h in bounds:
        assert f"horizon T = {h:g}: 1 segment(s), k in [" in text
    # a list picks some horizons; a time that is not a verdict horizon, or both keys, is refused
    assert refine_config(make_plan({**s, "refine": {"horizons": [50.0, 5.0]}})).horizons == (5.0, 50.0)
    for bad in ({"horizons": [7.0]}, {"horizons": []}, {"horizons": "some"}, {"horizon": 5.0, "horizons": "all"}):
        with pytest.raises(ValidationError, match="refine.horizons"):
            refine_config(make_plan({**s, "refine": bad}))


def test_multi_horizon_2d_finds_every_edge_at_every_horizon(oscillator, tmp_path):
    """Disks shrinking with the horizon (radius 0.35, 0.3, 0.25 at T = 5, 20, 50): for each horizon the
    refinement's segments are exactly the boundary edges of the full lattice at that horizon, although cells
    are split by the union of the three boundaries. The plot draws each horizon's bracket."""
    from stabjax.explore.refine import Refiner, assemble
    from stabjax.explore.refine_config import refine_config
    from stabjax.present.refinement import plot_refine
    from stabjax.plan.spec import make_plan

    radii = (0.35, 0.3, 0.25)
    disks = [lambda p, r=r: (p["k"] - 0.5) ** 2 + (p["c"] - 0.5) ** 2 < r * r for r in radii]
    plan = make_plan(spec({"k": {"start": 0.0, "stop": 1.0, "num": 9}, "c": {"start": 0.0, "stop": 1.0, "num": 9}},
                          {"tol": 0.02, "horizons": "all"}, verdict={"horizons": [5.0, 20.0]}))
    cfg = refine_config(plan)
    ref = Refiner(plan, cfg).run(_by_values(plan, _by_horizon(disks)))
    kf, cf = ref.fine
    K, C = np.meshgrid(kf, cf, indexing="ij")
    for h, inside in enumerate(disks):
        full = inside({"k": K, "c": C})
        edges = {(0, (i, j), (i + 1, j)) for i, j in zip(*np.nonzero(full[1:] != full[:-1]))}
        edges |= {(1, (i, j), (i, j + 1)) for i, j in zip(*np.nonzero(full[:, 1:] != full[:, :-1]))}
        assert set(ref.segments(h)) == edges and edges, radii[h]
    coords = np.concatenate(ref.coords)
    assert len({tuple(c) for c in coords}) == len(coords) < K.size / 2
    ds = assemble(ref)
    assert list(ds.attrs["n_segments_by_horizon"]) == [len(ref.segments(h)) for h in range(3)]
    for h, r in zip(cfg.horizons, radii):  # each segment's corners lie on both sides of its own horizon's circle
        sel = ds["segment_horizon"].values == h
        d = lambda e: np.hypot(ds[f"k_{e}"].values[sel] - 0.5, ds[f"c_{e}"].values[sel] - 0.5)
        assert np.all((d("lo") < r) != (d("hi") < r))
    png = tmp_path / "mh.png"
    plot_refine(ds, png)
    assert png.stat().st_size > 0


def test_multi_horizon_refinement_through_the_runner(oscillator):
    """Integrated: the oscillator's boundary is k = c at every horizon (up to the bands of the module
    docstring, < DELTA for T >= 25); a refinement over horizons 25 and 50 brackets it at both, and its labels
    at each horizon are the sweep runner's verdict columns at the same points (an independent path: run_points
    on the evaluated points, escape mapped by stabjax.fold.status)."""
    from stabjax.fold import status
    from stabjax.explore.refine import refine_spec
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_points

    s = spec({"k": {"start": 0.0, "stop": 1.0, "num": 5}}, {"tol": 0.01, "horizons": [25.0, 50.0]},
             params={"c": C1}, verdict={"horizons": [25.0]})
    ds = refine_spec(s)
    assert list(ds["segment_horizon"].values) == [25.0, 50.0] and ds.attrs["n_unbracketed"] == 0
    for lo, hi in zip(ds["k_lo"].values, ds["k_hi"].values):
        assert lo - DELTA <= C1 <= hi + DELTA and hi - lo <= 0.01
    k = ds["point_k"].values
    res, _ = run_points(make_plan({key: v for key, v in s.items() if key != "refine"}), k[:, None])
    v = status.verdicts(np.asarray(res["solver_status"]), np.asarray(res["verdict"]))
    np.testing.assert_array_equal(ds["point_label_by_horizon"].values, v)
    for h in range(2):
        np.testing.assert_array_equal(v[:, h][np.abs(k - C1) > DELTA], closed_form(k, C1)[np.abs(k - C1) > DELTA])


# ---- the refiner's bookkeeping, vectorised (issue 32: it was most of a refinement's wall time) ---------------------

def _reference_segments(ref, h=-1):
    """The per-leaf loop the vectorised Refiner.segments replaced."""
    out = set()
    for lo, ext in ref.leaves:
        for a, origin, e in ref.cell_edges(lo, ext, h):
            known = np.nonzero(e >= 0)[0]
            for u, w in zip(known[:-1], known[1:]):
                cu, cw = ref.cls[e[u]], ref.cls[e[w]]
                if cu >= 0 and cw >= 0 and cu != cw:
                    p, q = list(origin), list(origin)
                    p[a] += int(u)
                    q[a] += int(w)
                    out.add((a, tuple(p), tuple(q)))
    return sorted(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vectorised_straddle_and_segments_equal_the_per_cell_loops(seed):
    from pathlib import Path

    from stabjax.explore.refine import Refiner
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import load_spec, make_plan

    spec = load_spec(Path(__file__).resolve().parents[2] / "stabjax" / "sweeps" / "refine_pendulum.toml")
    plan = make_plan(spec)
    ref = Refiner(plan, refine_config(plan))
    rng = np.random.default_rng(seed)
    n0, n1 = ref.shape
    # labels: mostly unknown, a few classes, on a random set of lattice points
    ref.labs[:] = np.where(rng.random(ref.labs.shape) < 0.3, rng.integers(0, len(ref.cls) - 1, ref.labs.shape), -1)
    # a random quadtree of leaves over the lattice
    leaves, work = [], [((i, j), ref.step) for i in range(0, n0 - 1, ref.step[0]) for j in range(0, n1 - 1, ref.step[1])]
    while work:
        lo, ext = work.pop()
        if max(ext) > 1 and rng.random() < 0.6:
            work += ref._children(lo, ext)
        else:
            leaves.append((lo, ext))
    ref.leaves = sorted(leaves)
    wide = [c for c in leaves if max(c[1]) > 1]
    assert len(wide) > 50
    np.testing.assert_array_equal(ref._straddle_many(wide), [ref._straddles(*c) for c in wide])
    assert ref._straddle_many(wide).any() and not ref._straddle_many(wide).all()
    assert ref.segments() == _reference_segments(ref) and len(ref.segments()) > 10


def test_the_shipped_pendulum_refinement_runs_through_the_store_with_the_recurrence_stop(tmp_path, capsys):
    """``stabjax sweep sweeps/refine_pendulum.toml`` (coarser here): the rounds after the first carry the known
    attractors in their plan, and each round's chunk store records its provenance (a traceback once:
    ``KnownAttractors is not JSON serializable``)."""
    from pathlib import Path

    import xarray as xr
    from clirun import captured

    root = Path(__file__).resolve().parents[2]
    text = (root / "sweeps" / "refine_pendulum.toml").read_text()
    model = (root / "stabjax" / "examples" / "pendulum" / "model.py").as_posix()
    text = text.replace('"../examples/pendulum/model.py:Pendulum"', f'"{model}:Pendulum"')
    text = text.replace('rel_tol = "1/256"', 'rel_tol = "1/8"').replace("num = 17", "num = 5")  # 2 rounds
    # the shipped horizon and checkpoints: the compiled loops (with and without the clouds) are those of the
    # example's runs in tests/fold (the same settings); the few points here cost little to integrate (CI time)
    spec = tmp_path / "refine_pendulum.toml"
    spec.write_text(text)
    code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "r.nc", "--no-plot", "--no-progress")
    assert code == 0, err
    with xr.open_dataset(tmp_path / "r.nc") as ds:
        assert int(ds.attrs["rounds"]) >= 2 and int(ds.attrs["n_unbracketed"]) == 0
        assert json.loads(ds.attrs["integrate_json"])["attractor_stop"] is True
    assert not (tmp_path / "r.nc.zarr").exists()  # every round's store finished and removed
