"""Continuation (stabjax.mapping.continuation): matching along a parameter never joins two types, its default
threshold follows from the data, it runs again on saved output; and the issue's Van der Pol case end to end,
every checked start against an independent SciPy DOP853 integration."""
import functools
import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax.mapping import continuation as C


def _f(kind, rep, k=0):
    return C.Found(np.array([k]), kind, np.asarray(rep, float))


def test_a_match_that_would_change_the_type_is_a_death_and_a_birth():
    """A fixed point at points 0, 1 and a cycle at 2, 3 whose representatives lie close (unbounded
    threshold): two identities, the fixed point dying and the cycle born at point 2."""
    pts = [[_f("fixed_point", [0.0, 0.0])], [_f("fixed_point", [0.0, 0.01])],
           [_f("limit_cycle", [0.0, 0.02])], [_f("limit_cycle", [0.0, 0.03])]]
    ids, spans = C.match_sequentially(pts, math.inf)
    assert [i[0] for i in ids] == [0, 0, 1, 1] and spans == [[0, 1], [2, 3]]
    ev = C.events(spans, ["fixed_point_1", "limit_cycle_1"], 4)
    assert ev == [{"attractor": "limit_cycle_1", "event": "birth", "index": 2},
                  {"attractor": "fixed_point_1", "event": "death", "index": 2}]


def test_default_threshold_is_the_least_distance_between_coexisting_attractors():
    """Two fixed points 1.0 apart at point 0: the default threshold is 1.0; at point 1 one of them moved by
    0.4 (continued), the other jumped by 1.5 (a death and a birth, although no other candidate is nearer)."""
    pts = [[_f("fixed_point", [0.0]), _f("fixed_point", [1.0])],
           [_f("fixed_point", [0.4]), _f("fixed_point", [2.5])]]
    assert C.default_threshold(pts) == 1.0
    ids, spans = C.match_sequentially(pts)  # None: the default
    assert ids == [[0, 1], [0, 2]] and spans == [[0, 1], [0, 0], [1, 1]]
    assert C.default_threshold([[_f("fixed_point", [0.0])], [_f("fixed_point", [5.0])]]) == math.inf


def test_found_from_labels_rematches_saved_labels():
    """Any labelling goes through the step: labels of two points (0, 1 at point 0; 1 only at point 1),
    scaled features, and the labels' types: the identities follow the nearest same-type group."""
    x = np.array([[0.0], [0.1], [1.0], [1.1], [1.05], [1.02]])
    labels = np.array([0, 0, 1, 1, 1, 1])
    pts = C.found_from_labels(np.r_[labels[:3], labels[3:]], x, 2, kinds=["fixed_point", "fixed_point"])
    assert [[f.members.tolist() for f in p] for p in pts] == [[[0, 1], [2]], [[3, 4, 5]]]
    ids, spans = C.match_sequentially(pts, math.inf)
    assert ids == [[0, 1], [1]] and spans[0] == [0, 0] and spans[1] == [0, 1]


# ---- the Van der Pol case (issue 29) ----------------------------------------------------------

M = [-1.0, -0.5, -0.2, 0.2, 0.5, 1.0]
N, T1 = 200, 200.0


@functools.cache  # one model object for both runs: the engines cache their compiled kernels per object (CI time)
def _vdp():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class VanDerPol(System):
        """x'' - m (1 - x^2) x' + x = 0: the origin is stable for m < 0 (eigenvalues m/2 +- i sqrt(1 - m^2/4)),
        unstable for m > 0, where every start but the origin reaches the limit cycle of amplitude ~2."""

        name = "vdp_test"
        params = ParamSet((Param("m", 1.0, "damping"), Param("x0", 0.5, "initial x", kind="initial"),
                           Param("v0", 0.0, "initial v", kind="initial")))
        state = (("x", ()), ("v", ()))
        observables = ("x", "v")
        observable_doc = ("x", "v")
        escape_radius = 50.0  # m < 0: a start outside the unstable cycle runs away (none in [-1, 1]^2)

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["v0"]])

        def rhs(self, t, y, p):
            return jnp.stack([y[1], p["m"] * (1 - y[0] ** 2) * y[1] - y[0]])

        def observe(self, t, y, p):
            return y

    return VanDerPol()


def _scipy_types(m, x0, v0):
    """The attractor each start reaches by DOP853: the starts' equations stacked into one system (the RMS
    error norm over 2 n components: tolerance 1e-10 / sqrt(2 n) bounds each one's). The rest point when
    the state at t1 is within 1e-6 of the origin, the limit cycle when the last 50 time units swing x to
    2 +- 0.05 (the cycle's amplitude: 2.00 at m = 0.2, 2.01 at m = 1), else "none". ``m``: one value, or
    one per start (every parameter value's starts in one integration: the same bound on each component,
    one SciPy call instead of one per value)."""
    n = len(x0)
    m = np.broadcast_to(np.asarray(m, float), (n,))

    def f(t, y):
        x, v = y[:n], y[n:]
        return np.concatenate([v, m * (1 - x ** 2) * v - x])

    tol = 1e-10 / np.sqrt(2 * n)
    sol = solve_ivp(f, (0, T1), np.concatenate([x0, v0]), method="DOP853", rtol=tol, atol=tol, dense_output=True)
    assert sol.success
    end = np.abs(sol.y[:, -1]).reshape(2, n).max(axis=0)
    amp = np.abs(sol.sol(np.linspace(T1 - 50.0, T1, 2001))[:n]).max(axis=1)
    return np.where(end < 1e-6, "fixed_point", np.where(np.abs(amp - 2.0) < 0.05, "limit_cycle", "none"))


def test_van_der_pol_continuation_names_the_cycle_a_cycle():
    """Nothing declared, m in {-1, -0.5, -0.2, 0.2, 0.5, 1}, 200 starts per value: the rest point at m < 0
    and the amplitude-2 limit cycle at m > 0 are two attractors of their own type (before: one
    'fixed_point_1' with fraction 1.0 at every m and no event), the rest point dying and the cycle born at
    m = 0.2; the attractor type of every fifth start (240 in all) is the one SciPy's integration reaches."""
    import warnings

    from stabjax.run.sweep import run_spec

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ds = run_spec({"system": _vdp(), "grid": {"m": M},
                       "sample": {"n": N, "seed": 3, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                                  "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
                       "integrate": {"t1": T1}})
    # the rest point is typed by rest, the cycle by its exponent near 0: no type stands on the exponent alone
    assert not [w for w in said if "negative exponent alone" in str(w.message)]
    names, types = list(ds["attractor"].values), list(ds["attractor_type"].values)
    assert sorted(types) == ["fixed_point", "limit_cycle"]
    fp, lc = names[types.index("fixed_point")], names[types.index("limit_cycle")]
    frac = ds["basin_fraction"]
    np.testing.assert_array_equal(frac.sel(outcome_name=fp).values, [1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(frac.sel(outcome_name=lc).values, [0, 0, 0, 1, 1, 1])
    ev = json.loads(str(ds["attractor_events"].values))
    assert {(e["attractor"], e["event"], e["m"]) for e in ev} == {(fp, "death", 0.2), (lc, "birth", 0.2)}
    assert ds["attractor_events"].attrs["match_threshold"] == math.inf  # one attractor per point: no data scale
    flag = ds["outcome"].attrs["flag_meanings"].split()
    kind = {n: t for n, t in zip(names, types)}
    x0, v0 = ds["x0_sample"].values[::5], ds["v0_sample"].values[::5]
    k = len(x0)  # every m's checked starts in one SciPy integration (see _scipy_types)
    ref = _scipy_types(np.repeat(M, k), np.tile(x0, len(M)), np.tile(v0, len(M))).reshape(len(M), k)
    for i, m in enumerate(M):
        got = [kind.get(flag[int(c)], "none") for c in ds["outcome"].values[i, ::5]]
        np.testing.assert_array_equal(got, ref[i], err_msg=f"m = {m}")
    # the report says the births and deaths too (only the command line printed them), and no attitude
    # classifier's settings (a discovery has none)
    from stabjax.present.report import render

    page = render(ds)
    rows = page.split("Births and deaths along the axis", 1)[1].split("</table>", 1)[0]
    assert f"<td>{lc}</td><td>birth</td><td>0.2</td>" in rows and f"<td>{fp}</td><td>death</td><td>0.2</td>" in rows
    assert "classifier settings" not in page
    assert "not random draws" not in page  # sampled starts: S ± SE and Wilson are what they say
    # where each attractor is: one grid point's place (its representative's), said as such, and its exponent the
    # median over its trajectories at every grid point it lives at (the printed table and the report)
    from stabjax.present import kit
    from stabjax.present.basins import format_summary

    rep_m = {n: float(ds["attractor_start_m"].values[k]) for k, n in enumerate(names)}
    for a in kit.attractors(ds):
        assert a["where"].endswith(f"(at m = {rep_m[a['name']]:.4g}, its representative's grid point; followed "
                                   "along m)"), a["where"]
        assert (rep_m[a["name"]] > 0) == (a["type"] == "limit_cycle")
    text = format_summary(ds)
    said = "(median over its trajectories at every grid point)"
    assert text.count(said) == 2 and "its representative's grid point" in text
    assert f"largest Lyapunov exponent {said}" in page
    # and it is that median (the wording said "over its grid points", a median of per-point medians)
    lam, code = ds["lyapunov"].values.ravel(), ds["outcome"].values.ravel()
    for k, a in enumerate(kit.attractors(ds)):
        assert a["lyapunov"] == pytest.approx(np.nanmedian(lam[code == names.index(a["name"])]), rel=1e-12)


def test_a_fixed_point_typed_by_its_exponent_alone_is_said():
    """Van der Pol at m = 1 watched for four periods (t1 = 50, the window its last quarter): the cycle's
    finite-time exponent is about -0.06 (a relaxation cycle's exponent over a short window is off zero by up to
    ln(max|f| / min|f|) / window), below -chaos_threshold, so the group is typed a fixed point although every
    member still swings over the window (x from -2 to 2). The typing stands as documented, but is said: a
    TransientWarning names the group, its exponent and the remedy (a longer t1)."""
    from stabjax.mapping.discover import TransientWarning
    from stabjax.run.sweep import run_spec

    with pytest.warns(TransientWarning, match=r"fixed_point_1 \(100 trajectories, exponent -0\.0\d+\): typed a fixed "
                                              r"point by the negative exponent alone.*raise \[integrate\] t1"):
        ds = run_spec({"system": _vdp(), "params": {"m": 1.0, "v0": 0.0},
                       "sample": {"n": 100, "seed": 3, "x0": {"dist": "uniform", "low": 0.1, "high": 0.6}},
                       "integrate": {"t1": 50.0, "n_checkpoints": 200}})
    # the premise: one group, typed by the exponent, its members not at rest (the window's spread of x is the
    # cycle's: about 1.4, nowhere near a rest point's)
    assert list(ds["attractor_type"].values) == ["fixed_point"]
    assert float(ds["feat_std"].values[:, 0].min()) > 1.0


def test_van_der_pol_saved_output_rematches_to_the_same_events(tmp_path):
    """The sweep grouped over all points at once (continuation = false) and written to a file; its saved
    outcomes, late-window features and attractor types go through the continuation step afterwards (as
    Attractors.jl re-runs match_sequentially! on saved output): the rest point dies and the cycle is born
    at m = 0.2 (index 3), as the continuation in the run itself finds them."""
    from stabjax.mapping.discover import STATS
    from stabjax.run.sweep import open_result, run_spec

    out = tmp_path / "vdp.nc"
    run_spec({"system": _vdp(), "grid": {"m": M},
              "sample": {"n": 60, "seed": 3, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                         "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
              "integrate": {"t1": T1}, "outcomes": {"discover": True, "discovery": {"continuation": False}}}, out)
    ds = open_result(out)
    assert "attractor_events" not in ds
    codes = ds["outcome"].values.ravel()
    labels = np.where(codes < ds.sizes["attractor"], codes, -1)
    feats = np.stack([ds[f"feat_{s}"].values.reshape(codes.size, -1) for s in STATS], axis=2)  # (N, obs, stat)
    x = (feats / ds["observable_range"].values[None, :, None]).reshape(codes.size, -1)
    pts = C.found_from_labels(labels, x, len(M), kinds=[str(t) for t in ds["attractor_type"].values])
    ids, spans = C.match_sequentially(pts)
    kinds = [next(f.kind for f, a in zip(pts[s[0]], ids[s[0]]) if a == i) for i, s in enumerate(spans)]
    ev = C.events(spans, kinds, len(M))
    assert {(e["attractor"], e["event"], e["index"]) for e in ev} == {("fixed_point", "death", 3),
                                                                    ("limit_cycle", "birth", 3)}
