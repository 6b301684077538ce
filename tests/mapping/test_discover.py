"""Attractor discovery (stabjax.mapping.discover): grouping properties on synthetic feature clouds, and the
partition of the examples' starts against their declared rules/templates (independent of the
discovery code: the rules are the examples' own, checked against SciPy in test_examples.py)."""
import functools
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax.mapping.discover import DiscoveryConfig, group
from stabjax.run.sweep import run_spec


# one tolerance unit (atol + rtol |x|) at |x| = 1 under the default tolerances (rtol 1e-8, atol 1e-10): a fixed point
# placed by Newton's method is taken only when its last step is below it (stabjax.mapping.discover._place_fixed_point)
ONE_UNIT = 1e-10 + 1e-8 * 1.0


@functools.cache
def _one(model):
    """One object per test model class for the whole module: the engines cache their compiled kernels and the
    representatives' re-integration per model object, so runs at the same settings share them (CI time)."""
    return model()


def _cloud(rng, n, centre, spread, d=8):
    x = np.tile(np.asarray(centre, float), (n, 1))
    return x + rng.normal(0.0, spread, (n, d))


def test_one_chaotic_cloud_is_never_split():
    """A ring-shaped cloud (a chaotic attractor's features scatter along its own shape) of 20 000
    points, sampled at 4000: one group, every point in it."""
    rng = np.random.default_rng(1)
    th = rng.uniform(0, 2 * np.pi, 20000)
    x = np.zeros((20000, 8))
    x[:, 0], x[:, 1] = 0.3 * np.cos(th), 0.3 * np.sin(th)
    x += rng.normal(0, 0.01, x.shape)
    lab, _ = group(x, DiscoveryConfig())
    assert set(np.unique(lab)) == {0}


def test_two_clouds_apart_are_never_merged_and_a_rare_basin_is_found():
    """Two chaotic-like clouds whose edges are 3 eps apart, a fixed point and a basin of 12 starts
    (0.04 %: absent from the subsample) stay four groups."""
    rng = np.random.default_rng(2)
    cfg = DiscoveryConfig()
    a = _cloud(rng, 15000, np.zeros(8), 0.01)
    b = _cloud(rng, 10000, np.r_[0.2, np.zeros(7)], 0.01)  # centres 0.2 apart, edges (4 sigma) ~0.12 = 2.4 eps
    fp = np.tile(np.r_[-0.6, 0.5, np.zeros(6)], (5000, 1))
    rare = np.tile(np.r_[0.7, -0.4, np.zeros(6)], (12, 1))
    lab, _ = group(np.concatenate([a, b, fp, rare]), cfg)
    parts = [lab[:15000], lab[15000:25000], lab[25000:30000], lab[30000:]]
    firsts = [np.unique(p) for p in parts]
    assert all(len(f) == 1 and f[0] >= 0 for f in firsts)
    assert len({int(f[0]) for f in firsts}) == 4


def test_discovery_config_is_checked():
    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError, match="outcomes.discovery.eps"):
        DiscoveryConfig.from_dict({"eps": -1})
    with pytest.raises(ValidationError, match="unknown key"):
        DiscoveryConfig.from_dict({"radius": 0.1})
    # a negative chaos threshold named an equilibrium (exponent -0.05) and a cycle chaotic_1 and chaotic_2; a
    # subsample of 6 split the pendulum's one running cycle into three names; seed 0 is the default
    for key, value, said in (("chaos_threshold", -0.1, "must be >= 0"), ("subsample", 6, "at least 1000"),
                             ("subsample", 999, "at least 1000"), ("seed", -1, "non-negative"),
                             ("eps", 1e-300, "at least 1e-12")):  # a radius below rounding made two wells one
        with pytest.raises(ValidationError, match=said) as exc:
            DiscoveryConfig.from_dict({key: value})
        assert exc.value.field == f"outcomes.discovery.{key}"
    assert DiscoveryConfig.from_dict({"chaos_threshold": 0.0, "subsample": 1000, "seed": 0}).subsample == 1000


def _example(name, n, **over):
    spec = tomllib.load(open(f"examples/{name}/spec.toml", "rb"))
    spec["system"] = f"examples/{name}/" + spec["system"]
    spec["sample"]["n"] = n
    for k, v in over.items():
        spec.setdefault(k, {}).update(v)
    return spec


def _matched(declared, found):
    """Fraction of starts in the matched class: each found outcome mapped to the declared outcome
    most of its starts carry; the map must be one-to-one (no declared outcome split or merged)."""
    dn, fn = declared["outcome"].attrs["flag_meanings"].split(), found["outcome"].attrs["flag_meanings"].split()
    a, b = declared["outcome"].values.ravel(), found["outcome"].values.ravel()
    tab = np.zeros((len(dn), len(fn)), int)
    np.add.at(tab, (a, b), 1)
    used = [j for j in range(len(fn)) if tab[:, j].sum()]
    to = {j: int(np.argmax(tab[:, j])) for j in used}
    assert len(set(to.values())) == len(used), (dn, fn, tab)
    return sum(tab[to[j], j] for j in used) / a.size, {fn[j]: dn[to[j]] for j in used}


@pytest.mark.parametrize("name,n,expect", [
    # pendulum: the full suite's; in CI's run test_pendulum_discovery_start_by_start_against_scipy finds the
    # example's two attractors, typed so, and each start's against SciPy DOP853 (an independent reference)
    pytest.param("pendulum", 300, {"fixed_point": 1, "limit_cycle": 1}, marks=pytest.mark.slow),
    ("duffing", 300, {"limit_cycle": 5}),
    ("lorenz", 300, {"chaotic": 2}),
])
def test_examples_partition_recovered(name, n, expect):
    declared = run_spec(_example(name, n))
    found = run_spec(_example(name, n, outcomes={"discover": True}))
    frac, mapping = _matched(declared, found)
    assert frac >= 0.98, (frac, mapping)
    types = list(found["attractor_type"].values)
    assert {t: types.count(t) for t in set(types)} == expect
    if name == "lorenz":  # the escape outcome is kept as declared
        assert mapping.get("unbounded") == "unbounded"


def test_lorenz63_attractors_found_and_typed():
    """r = 24.4: C+- = (+-q, +-q, r - 1), q = sqrt(b (r - 1)), typed fixed points with the exponent of
    the Jacobian's leading eigenvalue there (-0.0102), and one chaotic attractor (lambda ~ 0.9)."""
    ds = run_spec(_example("lorenz63", 300))  # C- holds ~5 %: 15 starts, above min_samples
    types = list(ds["attractor_type"].values)
    assert sorted(types) == ["chaotic", "fixed_point", "fixed_point"]
    b, r = 8 / 3, 24.4
    q = np.sqrt(b * (r - 1))
    ifp = [i for i, t in enumerate(types) if t == "fixed_point"]
    fp = ds["attractor_state"].values[ifp]
    # distance to C+- a posteriori: f(x) = J (x - C) + O(|x - C|^2), so |x - C| <= |J^-1| |f(x)| (1 + 1 %).
    # (At rtol = atol = 1e-8 Tsit5 stays ~4e-5 from this weakly stable focus: the controller lets the
    # step grow to where the oscillatory mode is barely damped; 3e-7 at 1e-10, 3e-9 at 1e-12.)
    s = 10.0
    for x in fp:
        c = np.array([np.sign(x[0]) * q, np.sign(x[0]) * q, r - 1])
        J = np.array([[-s, s, 0], [r - c[2], -1, -c[0]], [c[1], c[0], -b]])
        f = np.array([s * (x[1] - x[0]), r * x[0] - x[1] - x[0] * x[2], x[0] * x[1] - b * x[2]])
        bound = 1.01 * np.linalg.norm(np.linalg.inv(J), 2) * np.linalg.norm(f)
        assert np.linalg.norm(x - c) <= bound + 1e-12 and bound < 1e-3, (x, c, bound)
    ev, vec = np.linalg.eig(np.array([[-s, s, 0], [1, -1, -q], [q, q, -b]]))
    lam1 = ev.real.max()
    lam = ds["attractor_lyapunov"].values
    # the window [1500, 2000] is long past the approach: the estimate is the linear one, within
    # ln kappa(V) / T_w (see test_lyapunov) of the eigenvalue: 0.272 / 500 = 5.4e-4
    t_w = 2000.0 * 0.25
    bound = np.log(np.linalg.cond(vec)) / t_w
    assert np.all(np.abs(lam[ifp] - lam1) <= bound), (lam[ifp], lam1, bound)
    assert lam[types.index("chaotic")] > 0.5
    assert ds["basin_fraction"].sel(outcome_name="unclassified").item() <= 0.02


def test_the_edge_of_a_chaotic_cloud_is_the_chaotic_attractor():
    """r = 28: one attractor, the chaotic one, reached from every start of the box. Finite windows of a chaotic
    motion scatter their features, and DBSCAN left the cloud's sparse edge out as noise: 79 of these 300 starts
    were unclassified (23 of 300 at the default tolerances), each with a positive exponent like chaotic_1's, so
    the reported interval excluded S = 1. They join the chaotic group: every start is chaotic_1."""
    ds = run_spec(_example("lorenz63", 300, params={"r": 28.0}, integrate={"t1": 300.0, "n_checkpoints": 1200}))
    assert list(ds["attractor_type"].values) == ["chaotic"]
    assert ds["attractor_lyapunov"].values[0] > 0.5
    assert ds["basin_count"].sel(outcome_name="chaotic_1").item() == 300


class TriWell:
    """x'' + c x' + V'(x) = 0, V'(x) = x (x^2 - 1)(x^2 - 4): stable rest points x = 0, +-2 (V'' = 4, 24),
    unstable at +-1 (the issue's "three stable rest points" model)."""


def _triwell():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class TriWellModel(System):
        name = "triwell_test"
        params = ParamSet((Param("c", 0.5, "damping"), Param("x0", 0.0, "initial x", kind="initial"),
                           Param("v0", 0.0, "initial v", kind="initial")))
        state = (("x", ()), ("v", ()))
        observables = ("x", "v")
        observable_doc = ("position", "velocity")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["v0"]])

        def rhs(self, t, y, p):
            x, v = y[0], y[1]
            return jnp.stack([v, -p["c"] * v - x * (x * x - 1) * (x * x - 4)])

        def observe(self, t, y, p):
            return y

    return TriWellModel


def test_model_without_outcomes_gets_its_attractors_not_verdicts():
    """Issue #23 item 1: no converged/flipped words and no attitude-verdict variables; the three rest
    points are found, typed and placed (100 starts' rest points checked with SciPy DOP853)."""

    model = _triwell()
    ds = run_spec({"system": model, "sample": {"n": 200, "seed": 5, "x0": {"dist": "uniform", "low": -2.5, "high": 2.5},
                                                 "v0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
                   "integrate": {"t1": 200.0, "rtol": 1e-8, "atol": 1e-10, "n_checkpoints": 400}})
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert names == ["fixed_point_1", "fixed_point_2", "fixed_point_3", "unclassified", "failed"]
    for var in ("verdict", "decay_exponent", "n_flips", "t_settle", "size_max", "error_t1"):
        assert var not in ds
    assert not any(w in " ".join(names) for w in ("converged", "flipped", "undecided"))
    rest = np.sort(ds["attractor_state"].values[:, 0])
    np.testing.assert_allclose(rest, [-2.0, 0.0, 2.0], atol=1e-6)
    # per start, every second (100): the rest point SciPy reaches is the representative state of the start's
    # group (a start whose SciPy rest point changes under a 1e-7 nudge lies on a basin boundary and is not
    # counted; most must count)
    x0, v0 = ds["x0_sample"].values[::2], ds["v0_sample"].values[::2]
    code = ds["outcome"].values[::2]

    def ends(x, v):  # every start stacked into one DOP853 system; the RMS error norm over 2 n components
        n = len(x)
        f = lambda t, y: np.concatenate([y[n:], -0.5 * y[n:] - y[:n] * (y[:n] ** 2 - 1) * (y[:n] ** 2 - 4)])  # noqa
        tol = 1e-11 / np.sqrt(2 * n)
        return solve_ivp(f, (0, 200.0), np.concatenate([x, v]), method="DOP853", rtol=tol, atol=tol).y[:n, -1]

    # the starts and their nudged copies in one integration (2 n starts: each component's bound is the same)
    e, nudged = np.split(ends(np.r_[x0, x0 * (1 + 1e-7) + 1e-7], np.r_[v0, v0]), 2)
    ok = np.abs(e - nudged) <= 1e-6
    robust = int(ok.sum())
    np.testing.assert_allclose(e[ok], ds["attractor_state"].values[code[ok], 0], atol=1e-6)
    assert robust >= 95, robust


def test_continuation_through_births_and_deaths():
    """Pendulum along the torque T (alpha = 0.3, K = 1): the running limit cycle exists above the
    homoclinic torque T_c ~ 4 alpha sqrt(K) / pi = 0.38 (Melnikov, first order in alpha), the rest
    point theta* = asin(T/K) only below the saddle-node at T = K. Along T = 0.1 ... 1.3 the limit
    cycle is born once (between 0.1 and 0.5), the fixed point is lost once (between 0.7 and 1.1),
    and each keeps one identity although both move (the fixed point's sin(theta) equals T / K, checked
    at every T where it exists; the cycle's mean angular velocity grows with T)."""
    import json

    T = [0.1, 0.5, 0.7, 1.1, 1.3]
    spec = {"system": "examples/pendulum/model.py:Pendulum", "grid": {"T": T}, "params": {"alpha": 0.3},
            "sample": {"n": 80, "seed": 1, "theta0": {"dist": "uniform", "low": -3.1, "high": 3.1},
                       "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
            "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 600},
            "outcomes": {"discover": True, "window": 0.2}}
    ds = run_spec(spec)
    types = list(ds["attractor_type"].values)
    assert sorted(types) == ["fixed_point", "limit_cycle"]
    names = list(ds["attractor"].values)
    fp, lc = names[types.index("fixed_point")], names[types.index("limit_cycle")]
    f_fp = ds["basin_fraction"].sel(outcome_name=fp).values
    f_lc = ds["basin_fraction"].sel(outcome_name=lc).values
    assert np.all(f_fp[:3] > 0) and np.all(f_fp[3:] == 0)
    assert f_lc[0] == 0 and np.all(f_lc[1:] > 0)
    ev = json.loads(str(ds["attractor_events"].values))
    assert {(e["attractor"], e["event"], e["T"]) for e in ev} == {(lc, "birth", 0.5), (fp, "death", 1.1)}
    code = ds["outcome"].values
    sin_final = ds["feat_final"].sel(observable="sin_theta").values
    omega_mean = ds["feat_mean"].sel(observable="omega").values
    for i, t in enumerate(T):
        if i < 3:
            np.testing.assert_allclose(sin_final[i][code[i] == names.index(fp)], t, atol=1e-6)
    w = [np.median(omega_mean[i][code[i] == names.index(lc)]) for i in range(1, 5)]
    assert np.all(np.diff(w) > 0)


def test_all_escaping_sweep_discovers_nothing_and_says_so():
    """Every start runs away (dx/dt = x, escape radius 10): no attractor, all counted as escaped."""
    grow, _, _ = _runaways()

    class Runaway(grow):
        name = "runaway_test"
        escape_radius = 10.0

    ds = run_spec({"system": Runaway, "sample": {"n": 20, "seed": 0, "x0": {"dist": "uniform", "low": 1.0, "high": 2.0}},
                   "integrate": {"t1": 50.0}})
    assert ds["outcome"].attrs["flag_meanings"].split() == ["escaped", "unclassified", "failed"]
    assert ds.sizes["attractor"] == 0
    assert float(ds["basin_fraction"].sel(outcome_name="escaped")) == 1.0


def test_cli_sweep_and_replot_of_a_discovery(tmp_path, capsys):
    """The command line end to end on a model without declarations: the summary names the attractors,
    and the result (no verdict variable) can be drawn again."""
    from stabjax.app.cli import main

    spec = tmp_path / "tri.toml"
    spec.write_text(f'''system = "{Path(__file__).resolve().parents[2] / "examples/pendulum/model.py"}:Pendulum"
name = "tri"
[sample]
n = 40
seed = 2
theta0 = {{dist = "uniform", low = -2.6, high = 3.6}}
omega0 = {{dist = "uniform", low = -6.0, high = 6.0}}
[integrate]
t1 = 300.0
n_checkpoints = 1200
[outcomes]
discover = true
window = 0.2
''')  # the settings of test_pendulum_discovery_start_by_start_against_scipy: its compiled kernels serve both
    out = tmp_path / "tri.nc"
    for args in (["sweep", str(spec), "--out", str(out), "--no-progress"], ["plot", str(out), "--out",
                                                                             str(tmp_path / "again.png")]):
        try:
            main(args)
        except SystemExit as exc:
            assert not exc.code, capsys.readouterr()
    text = capsys.readouterr().out
    assert "fixed_point_1" in text and "limit_cycle_1" in text and (tmp_path / "again.png").exists()


# ---- fixed points typed on the solver's tolerances; the stop and the typing agree (issue 29) ---------------


@functools.cache  # the same classes on every call: see _one
def _relax():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class Relax(System):
        """x' = -(x - c), y' = -y: one stable node at (c, 0), eigenvalues -1, -1."""

        name = "relax_test"
        params = ParamSet((Param("c", 1.0, "centre"), Param("x0", 0.0, "initial x", kind="initial"),
                           Param("y0", 0.0, "initial y", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")
        observable_doc = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, y, p):
            return jnp.stack([-(y[0] - p["c"]), -y[1]])

        def observe(self, t, y, p):
            return y

    class Focus(System):
        """x' = -a (x - 1) - y, y' = (x - 1) - a y: a stable focus at (1, 0), eigenvalues -a +- i."""

        name = "focus_test"
        params = ParamSet((Param("a", 0.5, "damping"), Param("x0", 0.0, "initial x", kind="initial"),
                           Param("y0", 0.0, "initial y", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")
        observable_doc = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, y, p):
            u = y[0] - 1.0
            return jnp.stack([-p["a"] * u - y[1], u - p["a"] * y[1]])

        def observe(self, t, y, p):
            return y

    return Relax, Focus


@pytest.mark.parametrize("lyapunov", [True, False])
def test_a_stable_equilibrium_is_one_fixed_point_with_or_without_the_exponent(lyapunov):
    """The issue's cases, 100 starts each, default tolerances: x' = -(x - c), y' = -y for c = 0, 1, 3
    (t1 = 100), and a stable focus at (1, 0) (a = 0.5; t1 = 50, its window [25, 50] still holds the decay
    from e^-12.5 of the start). Every start is fixed_point_1, placed at the equilibrium. Before, the window
    variance E[x^2] - E[x]^2 kept ~sqrt(eps) |x| and every start was limit_cycle_1 (lambda = -1 beside it);
    the focus gave four 'limit cycles' and 72 % unclassified. Without the exponent the fixed-point stop is on:
    every start stops there (stop_reason), and the stop and the typing agree: none is unclassified. The stop
    fires only where it proves the run within one solver tolerance of the equilibrium from the window's start
    on (:mod:`stabjax.fold.equilibrium`); the focus at t1 = 50 is not (its window starts ~1e-5 away, and the
    run without the stop holds that transient too), so without the exponent it is checked at t1 = 100, where
    its window starts within e^-25; at t1 = 50 it must then not be called anything it is not (below)."""
    from stabjax.fold.stops import STOP_FIXED_POINT

    Relax, Focus = _relax()
    box = {"n": 100, "seed": 0, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    # each case's parameter on a grid of one point: a parameter of the run, not a constant of its compiled kernel, so
    # the three centres share one kernel (CI time); each is a sweep of its own, discovered on its own
    cases = [(Relax, {"c": [c]}, 100.0, c) for c in (0.0, 1.0, 3.0)] + [(Focus, {"a": [0.5]}, 50.0 if lyapunov else 100.0, 1.0)]
    for model, grid, t1, centre in cases:
        ds = run_spec({"system": _one(model), "grid": grid, "sample": box, "integrate": {"t1": t1},
                       "outcomes": {"discover": True, "discovery": {"lyapunov": lyapunov}}})
        assert ds["outcome"].attrs["flag_meanings"].split() == ["fixed_point_1", "unclassified", "failed"], \
            (model.name, grid, ds["outcome"].attrs["flag_meanings"])
        assert (ds["outcome"].values == 0).all(), (model.name, grid)
        # the representative rests at the equilibrium: within the stop's 1000 tolerances (rtol 1e-8, atol 1e-10)
        np.testing.assert_allclose(ds["attractor_state"].values[0], [centre, 0.0], atol=1000 * (1e-10 + 1e-8 * 3))
        if lyapunov:
            assert ds["attractor_lyapunov"].values[0] < 0
        else:
            assert (ds["stop_reason"].values == STOP_FIXED_POINT).all()
    if not lyapunov:  # a transient of ~1e-5 still in the window, no exponent to type it: untyped, never a cycle
        ds = run_spec({"system": _one(Focus), "grid": {"a": [0.5]}, "sample": box, "integrate": {"t1": 50.0},
                       "outcomes": {"discover": True, "discovery": {"lyapunov": False}}})
        names = ds["outcome"].attrs["flag_meanings"].split()
        assert not any(n.startswith(("limit_cycle", "chaotic")) for n in names), names


@functools.cache
def _line():
    from stabjax import Param, ParamSet

    Relax, _ = _relax()

    class Line(Relax):
        """x' = (1 - s - q) (1 - x) + s (x - x^3) - q x^3 (y0 and c are not read). s = q = 0 (the default): x' =
        1 - x, one stable node at x = 1; s = 1 (Bistable): x' = x - x^3, stable nodes at x = +-1; q = 1: x' = -x^3, a
        non-hyperbolic stable equilibrium at 0 approached algebraically, x(t) = x0 / sqrt(1 + 2 x0^2 t); the other
        terms are multiplied by an exact 0. One class, so that with s on a grid of one point (a parameter of the run,
        not a constant of the compiled kernel) they share one kernel at the same settings (CI time)."""

        name = "line_test"
        params = ParamSet((*Relax.params.params, Param("s", 0.0, "0: x' = 1 - x, 1: x' = x - x^3"),
                           Param("q", 0.0, "1: x' = -x^3")))
        state = (("x", ()),)
        observables = ("x",)
        observable_doc = ("x",)

        def initial_state(self, p):
            return p["x0"][None]

        def rhs(self, t, y, p):
            return (1.0 - p["s"] - p["q"]) * (1.0 - y) + p["s"] * (y - y**3) - p["q"] * y**3

        def observe(self, t, y, p):
            return y

    return Line


LINE, BISTABLE = {"s": [0.0]}, {"s": [1.0]}  # the grids of one point that make _line()'s model each


def _discovered(model, sample, t1, discovery, warning, params=None, grid=None):
    """The discovery run of ``model``: dataset, outcome names, and the messages of the ``warning``s it gave."""
    import warnings

    spec = {"system": _one(model), "params": params or {}, "integrate": {"t1": t1},
            "outcomes": {"discover": True, "discovery": discovery}}
    if sample:
        spec["sample"] = sample
    if grid:
        spec["grid"] = grid
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ds = run_spec(spec)
    names = ds["outcome"].attrs["flag_meanings"].split()
    return ds, names, [str(w.message) for w in said if issubclass(w.category, warning)]


def test_approaching_trajectories_keep_one_name_with_the_exponent():
    """With the exponent (the default). A slowly decaying focus x' = -a (x - 1) - y, y' = (x - 1) - a y,
    a = 0.02 (eigenvalues -0.02 +- i), 60 starts, t1 = 150: its window [75, 150] still holds oscillations of
    0.1 of its range, so its members end far apart, but every exponent is -0.02: one fixed point (before, three
    fixed points at three points that are no equilibria, and 5 unclassified). Its window means lie within 0.01
    of the focus. And x' = 1 - x from 20 starts, t1 = 10: each transient's window features lie too far apart
    for DBSCAN, but every exponent is -1 and every one ends within 1e-4 of x = 1: one fixed point (before, all
    unclassified, exit 1, with a warning to turn on the exponent that was on)."""
    from stabjax.mapping.discover import TransientWarning

    Relax, Focus = _relax()
    Line = _line()
    box = {"n": 60, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 3.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    ds, names, said = _discovered(Focus, box, 150.0, {}, TransientWarning, params={"a": 0.02})
    assert names == ["fixed_point_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), \
        (names, np.bincount(ds["outcome"].values.ravel()))
    np.testing.assert_allclose(ds["attractor_lyapunov"].values, -0.02, rtol=0.05)
    assert np.abs(ds["feat_final"].values.reshape(-1, 2) - [1.0, 0.0]).max() > 0.1  # far apart at t1
    # typed by the exponent while its members still oscillate over the window, but its representative's peaks
    # fall at the exponent's rate (e^(-0.02 * 75) = 0.22 over the window): a focus, not the relaxation cycle whose
    # short-window exponent looks the same (said there: test_continuation); nothing is said
    assert not said, said
    ds, names, said = _discovered(Line, {**box, "n": 20}, 10.0, {}, TransientWarning)
    assert names == ["fixed_point_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), names
    assert not said


def test_an_attractor_whose_representative_fails_again_is_placed_by_its_observables(monkeypatch):
    """The state at t1 of each attractor's representative is integrated again on its own (diffrax); where that
    run fails (it did on x' = -1e4 x^3, where the sweep's own engine did not), the attractor was stored and
    printed "at x = inf". Now its state is NaN, a warning names it, and its place is that of its observables at
    t1 in the sweep itself (x' = 1 - x: at x = 1)."""
    from stabjax.mapping import discover as D
    from stabjax.present.kit import attractors

    Line = _line()
    monkeypatch.setattr(D, "representative_state", lambda plan, index: np.array([np.inf]))
    box = {"n": 20, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 3.0}}
    ds, names, said = _discovered(Line, box, 40.0, {}, D.RepresentativeWarning)
    assert names[0] == "fixed_point_1" and len(said) == 1 and said[0].startswith("fixed_point_1:"), (names, said)
    assert np.isnan(ds["attractor_state"].values).all()
    assert attractors(ds)[0]["where"] == "at x = 1"


def test_a_forced_transient_that_has_not_settled_is_no_limit_cycle():
    """The slow focus (a = 0.02) forced by exp(-t), which dies out: the model reads t, so a negative exponent
    does not type a fixed point, and its decaying oscillations, still 0.22 of their start at the window's start
    (exp(-0.02 * 75)), were five 'limit cycles'. Now no group is a cycle: they are untyped, and a warning says
    that t1 did not outlast the transient. The same focus with a = 0.5 forced by 0.5 cos(0.7 t) has a true
    periodic attractor (contracted by exp(-0.5 * 75) at the window's start): one limit cycle."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet
    from stabjax.mapping.discover import TransientWarning

    _, Focus = _relax()

    class Forcing(Focus):
        """The focus forced by (1 - w) exp(-t) + w 0.5 cos(0.7 t): w = 0 the kick, w = 1 the periodic forcing (the
        other term multiplied by an exact 0). One class, with a and w on a grid of one point each (parameters of the
        run, not constants of the compiled kernel): both runs share one kernel (CI time). Two grid axes: grouped
        over the whole sweep at once, as without a grid."""

        name = "forcing_test"
        params = ParamSet((*Focus.params.params, Param("w", 0.0, "0: forced by exp(-t), 1: by 0.5 cos(0.7 t)")))

        def rhs(self, t, y, p):
            force = (1.0 - p["w"]) * jnp.exp(-t) + p["w"] * (0.5 * jnp.cos(0.7 * t))
            return super().rhs(t, y, p) + jnp.stack([force, 0.0 * t])

    kick, forced = {"a": [0.02], "w": [0.0]}, {"a": [0.5], "w": [1.0]}
    box = {"n": 60, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 3.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    ds, names, said = _discovered(Forcing, box, 150.0, {}, TransientWarning, grid=kick)
    assert not any(n.startswith(("limit_cycle", "chaotic")) for n in names), names
    assert set(ds["attractor_type"].values) == {"attractor"} and len(said) == 1 and "raise [integrate] t1" in said[0]
    assert "lyapunov = true" not in said[0]  # it is on
    ds, names, said = _discovered(Forcing, box, 150.0, {}, TransientWarning, grid=forced)
    assert names == ["limit_cycle_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), names
    assert not said


def test_a_monotone_approach_is_one_group_without_the_exponent():
    """Without the exponent a trajectory still approaching x' = -(x - 1), y' = -y at t1 is untyped, but one
    equilibrium keeps one name. 100 starts in [-2, 2]^2, window [t1/2, t1], the rest threshold 1000 solver
    tolerances (1e-7 for y at atol 1e-10). At t1 = 26 ten starts rest, the others still approach, monotonically
    (each ends its window at an extreme of x and y) where the ten rest: one fixed point. At t1 = 30, 92 rest and
    8 end within 3e-11 of (1, 0) with a y window std just above 1e-7: they are at the fixed point too (before:
    unclassified). At t1 = 8 none rests: x alone (x' = 1 - x) made four untyped groups before, now one, ending
    where they all head; with y too the window features lie too far apart for DBSCAN (before: all unclassified),
    and the monotone approaches are gathered by where they end; either way the group heads for the one equilibrium
    at its linear rate, and is that fixed point, placed there. The bistable x' = x - x^3 at t1 = 8 keeps its two
    equilibria apart: every start with x0 > 0 at one, x0 < 0 at the other (but one near the unstable x = 0,
    still on its way)."""
    from stabjax.mapping.discover import TransientWarning

    Relax, _ = _relax()
    Line = _line()
    box = {"n": 100, "seed": 0, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}

    def run(model, t1, grid=None):  # x' = 1 - x and x' = x - x^3: one kernel, s on a grid of one point (_line),
        # continuation off: grouped over the whole sweep at once, as without the grid
        return _discovered(model, box, t1, {"lyapunov": False, "continuation": False}, TransientWarning, grid=grid)

    for t1 in (26.0, 30.0):
        ds, names, said = run(Relax, t1)
        assert names == ["fixed_point_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), \
            (t1, names, np.bincount(ds["outcome"].values.ravel()))
        np.testing.assert_allclose(ds["attractor_observables"].values[0], [1.0, 0.0], atol=1e-6)
        assert not said
    # the one approach, untyped without the exponent, heads for the hyperbolic stable equilibrium Newton's method
    # finds ahead of it, at the linear rate: the fixed point there (before: attractor_1, said to be a transient)
    for model, grid in ((Line, LINE), (Relax, None)):  # Relax: the transients' window features too far apart to
        ds, names, said = run(model, 8.0, grid)         # group, gathered by where they end
        assert names == ["fixed_point_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), names
        assert int(ds["attractor_placed"].values[0]) == 2 and not said, said
        np.testing.assert_allclose(ds["attractor_observables"].values[0], [1.0, 0.0][:ds.sizes["observable"]],
                                   atol=1e-8)
    ds, names, said = run(Line, 8.0, BISTABLE)
    x0, code = ds["x0_sample"].values.ravel(), ds["outcome"].values.ravel()
    slow = np.abs(x0) < 1e-3  # leaves x = 0 as x0 e^t: still on its way at t1 = 8 (x0 = -4e-4 is at x = -0.78)
    assert (code[slow] == names.index("unclassified")).all() and slow.sum() <= 1
    assert [names[c] for c in np.unique(code[~slow & (x0 > 0)])] == ["fixed_point_1"]
    assert [names[c] for c in np.unique(code[~slow & (x0 < 0)])] == ["fixed_point_2"]
    np.testing.assert_allclose(np.sort(ds["attractor_observables"].values.ravel()), [-1.0, 1.0], atol=1e-6)


def test_discovery_with_fewer_starts_than_min_samples_is_refused_before_integrating(tmp_path):
    """n = 3 below min_samples = 5 (whole sweep), and 4 per grid point under continuation: refused naming
    the field, with a message about discovery (not rules or templates), before anything is written."""
    from stabjax.errors import ValidationError

    # the settings of test_pendulum_discovery_start_by_start_against_scipy here, then of
    # test_continuation_through_births_and_deaths with the grid: their compiled kernels serve these runs (CI time)
    spec = {"system": "examples/pendulum/model.py:Pendulum", "outcomes": {"discover": True, "window": 0.2},
            "sample": {"n": 3, "seed": 1, "theta0": {"dist": "uniform", "low": -3.0, "high": 3.0},
                       "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
            "integrate": {"t1": 300.0, "n_checkpoints": 1200}}
    out = tmp_path / "few.nc"
    with pytest.raises(ValidationError) as exc:
        run_spec(spec, out)
    assert exc.value.field == "outcomes.discovery.min_samples"
    assert "3 trajectories in the sweep" in exc.value.message and "rule" not in exc.value.message
    assert not out.exists() and not (tmp_path / "few.nc.zarr").exists()
    spec["sample"]["n"], spec["grid"], spec["params"] = 4, {"T": [0.2, 0.4, 0.6]}, {"alpha": 0.3}
    spec["integrate"] = {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 600}
    with pytest.raises(ValidationError, match="4 trajectories per grid point"):
        run_spec(spec, out)
    spec["outcomes"]["discovery"] = {"continuation": False}  # 12 grouped together: runs
    assert run_spec(spec)["outcome"].shape == (3, 4)


def test_too_many_attractors_are_refused_and_leave_no_store(tmp_path):
    """min_samples = 1 and eps = 1e-9: every running trajectory is a group of its own, more than the 124
    attractor codes. That can only be known after grouping: refused naming eps, and the store of the run
    (whose identity holds these settings, so no other run could resume it) is removed."""
    from stabjax.errors import ValidationError

    spec = {"system": "examples/pendulum/model.py:Pendulum",
            "outcomes": {"discover": True, "discovery": {"eps": 1e-9, "min_samples": 1, "lyapunov": False}},
            "sample": {"n": 400, "seed": 1, "theta0": {"dist": "uniform", "low": -3.0, "high": 3.0},
                       "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
            "integrate": {"t1": 100.0, "n_checkpoints": 200}}
    out = tmp_path / "many.nc"
    with pytest.raises(ValidationError) as exc:
        run_spec(spec, out, batch_size=200)
    assert exc.value.field == "outcomes.discovery.eps" and "raise eps or min_samples" in exc.value.message
    assert not out.exists() and not (tmp_path / "many.nc.zarr").exists()


def _pendulum_types(T, alpha, theta0, omega0, t1, window):
    """The attractor each pendulum start reaches by DOP853: every start's equations stacked into one system
    (one integration; the error norm is an RMS over the 2 n components, so the tolerance 1e-11 is divided
    by sqrt(2 n) to bound each one's). At rest when the angular velocity stays within 1e-3 of 0 over the
    window (still decaying as e^(-alpha t / 2)), running when its window mean exceeds T / (2 alpha) (the
    running cycle's is close to T / alpha = 5), else None."""
    n = len(theta0)

    def f(t, y):
        th, om = y[:n], y[n:]
        return np.concatenate([om, -alpha * om + T - np.sin(th)])

    tol = 1e-11 / np.sqrt(2 * n)
    sol = solve_ivp(f, (0, t1), np.concatenate([theta0, omega0]), method="DOP853", rtol=tol, atol=tol,
                    dense_output=True)
    assert sol.success
    w = sol.sol(np.linspace(t1 * (1 - window), t1, 2001))[n:]  # (n, K)
    rest, run = np.abs(w).max(axis=1) < 1e-3, w.mean(axis=1) > T / (2 * alpha)
    return np.where(rest, "fixed_point", np.where(run, "limit_cycle", "none"))


def test_pendulum_discovery_start_by_start_against_scipy():
    """The pendulum example with nothing declared (discovery), 120 starts: each start's discovered
    attractor type is the one SciPy's DOP853 integration of the same equations reaches (rest point or
    running cycle), for every start whose SciPy answer a 1e-7 nudge does not change; most must count."""
    t1, window = 300.0, 0.2
    spec = {"system": "examples/pendulum/model.py:Pendulum", "outcomes": {"discover": True, "window": window},
            "sample": {"n": 120, "seed": 7, "theta0": {"dist": "uniform", "low": -3.1, "high": 3.1},
                       "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
            "integrate": {"t1": t1, "n_checkpoints": 1200}}
    import warnings

    from stabjax.mapping.discover import MixedWarning

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ds = run_spec(spec)
    # its rest points theta* + 2 pi k are one place to the observables (omega, sin theta): nothing to say of them
    assert not [w for w in said if issubclass(w.category, MixedWarning)], [str(w.message) for w in said]
    types = [str(t) for t in ds["attractor_type"].values]
    assert sorted(types) == ["fixed_point", "limit_cycle"]
    flag = ds["outcome"].attrs["flag_meanings"].split()
    kind = dict(zip([str(n) for n in ds["attractor"].values], types))
    th, om = ds["theta0_sample"].values, ds["omega0_sample"].values
    # the starts and their nudged copies in one integration (2 n starts: each component's bound is the same)
    ref, nudged = np.split(_pendulum_types(0.5, 0.1, np.r_[th, th * (1 + 1e-7) + 1e-7], np.r_[om, om], t1,
                                           window), 2)
    robust = ref == nudged
    got = np.array([kind.get(flag[int(c)], "none") for c in ds["outcome"].values])
    assert robust.sum() >= 100 and {"fixed_point", "limit_cycle"} <= set(ref[robust]), (robust.sum(), ref)
    bad = np.flatnonzero(robust & (got != ref))
    assert bad.size == 0, [(i, th[i], om[i], got[i], ref[i]) for i in bad]


def test_a_discovery_that_groups_nothing_says_so_in_its_own_words(capsys):
    """Twelve pendulum starts with min_samples = 12 and eps = 1e-9: no group forms, all unclassified; the
    exit status is 1 and the message speaks of attractors, eps and min_samples, not of rules or templates
    the spec does not have."""
    from stabjax.app.sweep_cmds import run_status

    ds = run_spec({"system": "examples/pendulum/model.py:Pendulum",
                   "outcomes": {"discover": True, "discovery": {"eps": 1e-9, "min_samples": 12}},
                   "sample": {"n": 12, "seed": 1, "theta0": {"dist": "uniform", "low": -3.0, "high": 3.0},
                              "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
                   "integrate": {"t1": 50.0, "n_checkpoints": 100}})
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert (ds["outcome"].values == names.index("unclassified")).all()
    assert run_status(ds) == 1
    err = capsys.readouterr().err
    assert "no attractor was found: no min_samples trajectories lie within eps" in err and "rule" not in err, err


# ---- runaways are no attractor: the escape outcome, whether or not a radius is set ---------------------


def _phase_line(model_name: str, doc: str, f):
    """A 1-D model x' = f(x), observed through x, started at x0."""
    from stabjax import Param, ParamSet, System

    class PhaseLine(System):
        __doc__ = doc
        name = model_name
        params = ParamSet((Param("x0", 0.5, "initial x", kind="initial"),))
        state = (("x", ()),)
        observables = ("x",)
        observable_doc = ("x",)

        def initial_state(self, p):
            return p["x0"][None]

        def rhs(self, t, y, p):
            return f(y)

        def observe(self, t, y, p):
            return y

    return PhaseLine


def _runaways():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    Grow = _phase_line("grow_test", "x' = x: every start but 0 runs off to +-infinity, |x(t)| = |x0| e^t.",
                       lambda y: y)

    class Spiral(System):
        """x' = -a x - y, y' = x - a y with a < 0: an unstable focus, |(x, y)|(t) = |(x0, y0)| e^(-a t)."""

        name = "spiral_test"
        params = ParamSet((Param("a", -0.1, "damping"), Param("x0", 1.0, "initial x", kind="initial"),
                           Param("y0", 0.0, "initial y", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")
        observable_doc = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, y, p):
            return jnp.stack([-p["a"] * y[0] - y[1], y[0] - p["a"] * y[1]])

        def observe(self, t, y, p):
            return y

    class Split(System):
        """x' = x - x^3, y' = x y: x settles at sign(x0), so y runs away for x0 > 0 and rests at 0 for
        x0 < 0; y(t) = y0 exp(asinh(x0 e^t / c) - asinh(x0 / c)), c = sqrt(1 - x0^2), for |x0| < 1."""

        name = "split_test"
        params = ParamSet((Param("x0", 0.5, "initial x", kind="initial"), Param("y0", 1.0, "initial y", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")
        observable_doc = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, y, p):
            return jnp.stack([y[0] - y[0] ** 3, y[0] * y[1]])

        def observe(self, t, y, p):
            return y

    return Grow, Spiral, Split


def _all_escaped(ds):
    from stabjax.app.sweep_cmds import run_status

    names = ds["outcome"].attrs["flag_meanings"].split()
    assert names == ["escaped", "unclassified", "failed"], names
    assert ds.sizes["attractor"] == 0
    assert (ds["outcome"].values == 0).all()
    assert (ds["solver_status"].values == 0).all()  # reached t1: no radius stopped them, discovery named them
    assert run_status(ds) == 0  # an escape is an answer, not a failure (docs/guide/stops.md)


def test_x_dot_x_runs_away_and_is_no_attractor():
    """The reliability pass's repro, small: x' = x from [-2, 2] was one 'chaotic' attractor (exponent 1,
    x up to 1e43, +inf and -inf together). Every start is escaped, none an attractor, and the final values
    are the runaway's own, |x0| e^t1."""
    from stabjax.mapping.discover import UnboundedWarning

    grow, _, _ = _runaways()
    with pytest.warns(UnboundedWarning, match="20 of 20 trajectories grow without bound.*escape_radius"):
        ds = run_spec({"system": grow, "sample": {"n": 20, "seed": 0, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0}},
                       "integrate": {"t1": 20.0, "n_checkpoints": 40}})
    _all_escaped(ds)
    x0 = ds["x0_sample"].values.ravel()
    np.testing.assert_allclose(ds["feat_final"].values.reshape(-1), x0 * np.exp(20.0), rtol=1e-5)


def test_unstable_focus_runs_away_and_is_no_attractor():
    """x' = -a x - y, y' = x - a y at a = -0.1 from [-2, 2]^2 to t1 = 100 was five 'chaotic' attractors; the
    radius grows only e^5 ~ 150 over the window, yet every start is escaped."""
    from stabjax.mapping.discover import UnboundedWarning

    _, spiral, _ = _runaways()
    box = {"dist": "uniform", "low": -2.0, "high": 2.0}
    with pytest.warns(UnboundedWarning, match="30 of 30"):
        ds = run_spec({"system": spiral, "sample": {"n": 30, "seed": 1, "x0": box, "y0": box},
                       "integrate": {"t1": 100.0, "n_checkpoints": 200}})
    _all_escaped(ds)
    r0 = np.hypot(ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel())
    fin = ds["feat_final"].values.reshape(-1, 2)
    np.testing.assert_allclose(np.hypot(fin[:, 0], fin[:, 1]), r0 * np.exp(0.1 * 100.0), rtol=1e-5)


def test_runaways_beside_an_attractor_leave_it_whole():
    """Starts with x0 > 0 run away in y, those with x0 < 0 rest at (-1, 0): the runaways are escaped (their
    y(t1) the closed form's) and the rest point is still found and placed, its scale not swamped by the
    runaways' 1e8."""
    from stabjax.mapping.discover import UnboundedWarning

    _, _, split = _runaways()
    with pytest.warns(UnboundedWarning, match="of 40 trajectories grow without bound"):
        ds = run_spec({"system": split, "sample": {"n": 40, "seed": 2, "x0": {"dist": "uniform", "low": -0.9,
                                                                               "high": 0.9},
                                                     "y0": {"dist": "uniform", "low": 0.5, "high": 1.0}},
                       "integrate": {"t1": 20.0, "n_checkpoints": 80}})
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert names == ["fixed_point_1", "escaped", "unclassified", "failed"], names
    x0, y0 = ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel()
    code = ds["outcome"].values.ravel()
    np.testing.assert_array_equal(code, np.where(x0 > 0, 1, 0))
    np.testing.assert_allclose(ds["attractor_state"].values[0], [-1.0, 0.0], atol=1e-6)
    c = np.sqrt(1 - x0 ** 2)
    y_t1 = y0 * np.exp(np.arcsinh(x0 * np.exp(20.0) / c) - np.arcsinh(x0 / c))
    up = x0 > 0
    np.testing.assert_allclose(ds["feat_final"].sel(observable="y").values.ravel()[up], y_t1[up], rtol=1e-5)


def test_a_weak_focus_is_no_limit_cycle():
    """The focus x' = -a (x - 1) - y, y' = (x - 1) - a y at a = 0.005 (eigenvalues -0.005 +- i) watched to t1 = 100: its exponent -0.005 lies within chaos_threshold of a cycle's 0, and every group was limit_cycle_1.
    Its oscillation dies out at the exponent's rate (peaks falling by e^(-0.005 * 50) = 0.78 over the window, the
    closed form's |z(t)| = |z0| e^(-0.005 t)): one fixed point, placed at the focus by its window means."""
    _, Focus = _relax()
    box = {"n": 60, "seed": 0, "x0": {"dist": "uniform", "low": -1.0, "high": 3.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    ds = run_spec({"system": Focus, "params": {"a": 0.005}, "sample": box, "integrate": {"t1": 100.0,
                                                                                         "n_checkpoints": 400}})
    assert "limit_cycle" not in set(ds["attractor_type"].values)
    assert list(ds["attractor_type"].values) == ["fixed_point"], list(ds["attractor_type"].values)
    np.testing.assert_allclose(ds["attractor_lyapunov"].values, -0.005, rtol=0.05)
    z0 = np.hypot(ds["x0_sample"].values.ravel() - 1.0, ds["y0_sample"].values.ravel())
    fin = ds["feat_final"].values.reshape(-1, 2)
    np.testing.assert_allclose(np.hypot(fin[:, 0] - 1.0, fin[:, 1]), z0 * np.exp(-0.005 * 100.0), rtol=1e-5)
    # every start is the focus's or (the sparse, small-amplitude ones DBSCAN leaves out) unclassified: none named
    # anything else
    names = ds["outcome"].attrs["flag_meanings"].split()
    lab = ds["outcome"].values.ravel()
    assert set(lab) <= {names.index("fixed_point_1"), names.index("unclassified")} and (lab == 0).mean() >= 0.8
    # where it is: the focus (1, 0) itself, not where t1 left the representative on its spiral (it was reported
    # 1.9 away from a start box of [-4, 4]^2, without a word); Newton's last step is below one tolerance unit
    rep = int(ds["attractor_representative"].values[0])
    assert np.hypot(fin[rep, 0] - 1.0, fin[rep, 1]) > 1e-3  # the representative is still on its way
    np.testing.assert_allclose(ds["attractor_state"].values[0], [1.0, 0.0], rtol=0, atol=ONE_UNIT)
    assert int(ds["attractor_placed"].values[0]) == 1
    from stabjax.present.kit import attractors

    assert "still approach it at t1" in attractors(ds)[0]["where"]
    # watched to t1 = 50 the peaks fall by 9 % over the window (e^(-0.005 * 18.8) over its three periods): the three
    # groups DBSCAN makes of the spirals' sizes were "families of neutral orbits (a centre)"; one fixed point
    ds = run_spec({"system": Focus, "params": {"a": 0.005}, "sample": box, "integrate": {"t1": 50.0,
                                                                                        "n_checkpoints": 200}})
    assert list(ds["attractor_type"].values) == ["fixed_point"], list(ds["attractor_type"].values)
    np.testing.assert_allclose(ds["attractor_state"].values[0], [1.0, 0.0], rtol=0, atol=ONE_UNIT)


def test_without_the_exponent_a_dying_oscillation_is_said_to_be_a_transient():
    """The focus at a = 0.2 (eigenvalues -0.2 +- i) watched to t1 = 50 without the exponent: over the window [25, 50]
    every oscillation falls by e^(-0.2 * 25) = 0.7 %, still 1e-2 of the range at its start, so DBSCAN's groups are
    pieces of one transient (three untyped groups and 75 unclassified of 100), and nothing said so. Each group is
    still untyped (without the exponent nothing types it), but the warning names every one: its representative's
    peaks fall at every peak."""
    from stabjax.mapping.discover import TransientWarning

    _, Focus = _relax()
    box = {"n": 100, "seed": 5, "x0": {"dist": "uniform", "low": -4.0, "high": 4.0},
           "y0": {"dist": "uniform", "low": -4.0, "high": 4.0}}
    ds, names, said = _discovered(Focus, box, 50.0, {"lyapunov": False}, TransientWarning, params={"a": 0.2})
    groups = [n for n in names if n not in ("unclassified", "failed")]
    assert groups and set(ds["attractor_type"].values) == {"attractor"}, names
    assert len(said) == 1 and "oscillations dying out" in said[0], said
    assert all(f" in {n}" in said[0] for n in groups), said[0]


@functools.cache
def _wells():
    """x'' = x - x^3 - c x' + F: two wells (stable equilibria at the outer roots of x - x^3 + F) for |F| < 0.385."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class Wells(System):
        params = ParamSet((Param("c", 0.05, "damping"), Param("F", 0.0, "constant force"),
                           Param("x0", 0.5, "x0", kind="initial"), Param("y0", 0.0, "y0", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, z, p):
            return jnp.stack([z[1], z[0] - z[0] ** 3 - p["c"] * z[1] + p["F"]])

        def observe(self, t, z, p):
            return jnp.stack([z[0], z[1]])

    return Wells


def test_a_double_well_that_has_no_cycle_says_so_of_every_cycle_it_names():
    """x'' = x - x^3 - 0.05 x' from 100 starts in [-1, 3] x [-2, 2], t1 = 100: energy only decreases, so there is no
    cycle; orbits still above the saddle's energy at t1 lose it so slowly that their exponent is ~0, and a group of
    them is typed limit_cycle. Every such name now comes with a warning that its peaks fall at every peak (a cycle
    still approached, or an oscillation dying out); each well's focus is placed at (+-1, 0). Groups still spiralling
    into one well (seed 4: fixed_point_2 and fixed_point_3 both at (-1, 0), one attractor under two names, said)
    are one attractor: one name per well, holding every start SciPy's DOP853 brings to rest in it."""
    import warnings

    from stabjax.mapping.discover import TransientWarning

    TwoWells = _wells()

    for seed in (0, 4):  # seed 4: one well's spirals in two groups (here)
        box = {"n": 100, "seed": seed, "x0": {"dist": "uniform", "low": -1.0, "high": 3.0},
               "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ds = run_spec({"system": TwoWells, "sample": box, "integrate": {"t1": 100.0},
                           "outcomes": {"discover": True}})
        said = " ".join(str(w.message) for w in caught if issubclass(w.category, TransientWarning))
        types, names = list(ds["attractor_type"].values), [str(n) for n in ds["attractor"].values]
        for n, t in zip(names, types):
            if t == "limit_cycle":
                assert f"{n} (" in said and "peaks fall at every peak" in said, said
        placed = ds["attractor_placed"].values.astype(bool)
        at = ds["attractor_state"].values[placed]
        assert len(at) and np.all(np.min(np.abs(at[:, :1] - np.array([[-1.0, 1.0]])), axis=1) < ONE_UNIT)
        np.testing.assert_allclose(at[:, 1], 0.0, atol=ONE_UNIT)
        fixed = [k for k, t in enumerate(types) if t == "fixed_point"]
        wells = np.round(ds["attractor_state"].values[fixed, 0])
        assert sorted(wells.tolist()) == [-1.0, 1.0], (names, wells)  # one name per well
        # each start the sweep puts in a well's name comes to rest in that well by DOP853 (run on to t = 400: the
        # spirals decay as e^(-0.025 t), to below 1e-4 of their size)
        out = ds["outcome"].values
        x0, y0 = ds["x0_sample"].values, ds["y0_sample"].values
        for k, w in zip(fixed, wells):
            code = list(ds["outcome"].attrs["flag_meanings"].split()).index(names[k])
            for i in np.flatnonzero(out == code)[:8]:
                end = solve_ivp(lambda t, z: [z[1], z[0] - z[0] ** 3 - 0.05 * z[1]], (0.0, 400.0),
                                [x0[i], y0[i]], method="DOP853", rtol=1e-9, atol=1e-11).y[:, -1]
                assert abs(end[0] - w) < 1e-3 and abs(end[1]) < 1e-3, (i, end, w)


def test_a_slow_runaway_over_a_short_window_is_not_called_chaotic():
    """The unstable focus x' = 0.1 x - y, y' = x + 0.1 y watched to t1 = 15 (window 7.5: a separation grows e^0.75,
    too little for unbounded() to see the runaway) was five 'chaotic' attractors. Its exponent is the closed form's
    0.1 and its radius grows as e^(0.1 t); no group is typed chaotic, and the warning says why and how long a window
    would tell."""
    from stabjax.mapping.discover import TransientWarning

    _, spiral, _ = _runaways()
    box = {"dist": "uniform", "low": -2.0, "high": 2.0}
    with pytest.warns(TransientWarning, match=r"exponent 0\.1.*too short to tell a chaotic attractor from a slow "
                                              r"runaway.*at least 20"):
        ds = run_spec({"system": spiral, "sample": {"n": 60, "seed": 1, "x0": box, "y0": box},
                       "integrate": {"t1": 15.0, "n_checkpoints": 60}})
    assert "chaotic" not in set(ds["attractor_type"].values)
    assert ds.sizes["attractor"] >= 1 and set(ds["attractor_type"].values) == {"attractor"}
    np.testing.assert_allclose(ds["attractor_lyapunov"].values, 0.1, atol=1e-3)
    r0 = np.hypot(ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel())
    fin = ds["feat_final"].values.reshape(-1, 2)
    np.testing.assert_allclose(np.hypot(fin[:, 0], fin[:, 1]), r0 * np.exp(0.1 * 15.0), rtol=1e-5)


@pytest.mark.parametrize("t1", [100.0, 2000.0])
def test_a_non_hyperbolic_equilibrium_is_never_a_cycle_and_its_slow_approach_is_said(t1):
    """x' = -x^3 from [-2, 2]: at t1 = 2000 (exponent -0.001, within chaos_threshold of 0) both sides were typed
    limit_cycle; a monotone approach is no cycle, so they are untyped transients, said. At t1 = 100 (exponent -0.02)
    they are fixed points by the exponent, placed at +-0.07 where t1 left them: the warning says that they are still
    approaching and may be one equilibrium, each naming the other. The trajectories themselves are the closed
    form's."""
    from stabjax.mapping.discover import TransientWarning

    x0 = np.linspace(-2.0, 2.0, 41)
    x0 = x0[x0 != 0]
    # each of the two names the other as the fixed point to compare it with
    said = ("fixed_point_1 .*nearest fixed point fixed_point_2.*fixed_point_2 .*nearest fixed point fixed_point_1"
            ".*still approaching it monotonically.*may be one equilibrium") if t1 == 100.0 else \
        "still approaching something.*raise \\[integrate\\] t1"
    with pytest.warns(TransientWarning, match=said):
        ds = run_spec({"system": _line(), "grid": {"x0": x0.tolist(), "q": [1.0]},  # x' = -x^3
                       "integrate": {"t1": t1, "n_checkpoints": 100}})
    types = set(ds["attractor_type"].values)
    assert "limit_cycle" not in types and "chaotic" not in types
    assert types == ({"fixed_point"} if t1 == 100.0 else {"attractor"}), types
    np.testing.assert_allclose(ds["feat_final"].values.ravel(), x0 / np.sqrt(1 + 2 * x0 ** 2 * t1), rtol=1e-5)
    # each group lies on one side of the equilibrium: two approaches, not one attractor split by chance
    lab = ds["outcome"].values.ravel()
    for a in range(ds.sizes["attractor"]):
        assert len(set(np.sign(x0[lab == a]))) == 1


def test_a_component_at_rest_does_not_make_a_monotone_approach_a_cycle():
    """The reliability pass: x' = -x^3 beside y' = -y, 200 starts, t1 = 100. The starts nearest x = 0 approach it
    monotonically at an exponent within chaos_threshold of 0, as the 1-D model's do; y has come to rest, only the
    solver's +-1e-10 left, and that noise ended no window at an extreme, so the approach failed the monotone test
    and five starts were 'limit_cycle_1', unsaid. Every group is now what the 1-D model gives (fixed points by the
    exponent, an untyped transient) and the approach is said; every start's x at t1 is the closed form's."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System
    from stabjax.mapping.discover import TransientWarning

    class CubicAndLinear(System):
        params = ParamSet((Param("x0", 0.3, "x0", kind="initial"), Param("y0", 0.0, "y0", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, z, p):
            return jnp.stack([-z[0] ** 3, -z[1]])

        def observe(self, t, z, p):
            return jnp.stack([z[0], z[1]])

    box = {"n": 200, "seed": 3, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -1.0, "high": 1.0}}
    ds, names, said = _discovered(CubicAndLinear, box, 100.0, {}, TransientWarning)
    types = list(ds["attractor_type"].values)
    assert "limit_cycle" not in types and "chaotic" not in types, (names, types)
    assert any("still approaching" in m for m in said), said
    x0 = ds["x0_sample"].values
    np.testing.assert_allclose(ds["feat_final"].values[:, 0], x0 / np.sqrt(1 + 2 * x0 ** 2 * 100.0), rtol=1e-5)


def test_a_centre_is_no_limit_cycle():
    """x' = -y, y' = x (the spiral model at a = 0): every orbit a circle of its own radius, none attracting. Its 300
    starts were one limit_cycle_1 with S = 1 +- 0. The smallest and the largest member's orbits, integrated again,
    close on themselves and lie |r_max - r_min| apart (scaled: far more than eps), so the group is a family of
    neutral orbits, left untyped and said. The orbits are the closed form's circles."""
    from stabjax.mapping.discover import TransientWarning

    _, spiral, _ = _runaways()
    box = {"dist": "uniform", "low": -2.0, "high": 2.0}
    with pytest.warns(TransientWarning, match="family of neutral orbits"):
        ds = run_spec({"system": spiral, "params": {"a": 0.0}, "sample": {"n": 300, "seed": 1, "x0": box, "y0": box},
                       "integrate": {"t1": 50.0, "n_checkpoints": 200}})
    assert "limit_cycle" not in set(ds["attractor_type"].values)
    r0 = np.hypot(ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel())
    fin = ds["feat_final"].values.reshape(-1, 2)
    np.testing.assert_allclose(np.hypot(fin[:, 0], fin[:, 1]), r0, rtol=1e-5)
    # a circle each: the window's sampled max of x lies within r (1 - cos(dt / 2)) of r, checkpoints dt = 0.25 apart
    mx = ds["feat_max"].values.reshape(-1, 2)[:, 0]
    assert np.all(mx <= r0 * (1 + 1e-6)) and np.all(mx >= r0 * np.cos(0.125) * (1 - 1e-6))


def test_orbits_of_one_cycle_at_other_phases_are_one_orbit():
    """The centre test's pieces: one circle sampled from two phases is one orbit (distance below the sampling's
    chord), two circles of radii 1 and 1.2 are 0.2 apart; an arc shorter than a period does not close, a circle
    smaller than eps does."""
    from stabjax.mapping.discover import _closes, _orbit_distance

    t = np.linspace(0.0, 20.0, 4001)
    circle = lambda r, phase: r * np.stack([np.cos(t + phase), np.sin(t + phase)], axis=1)  # noqa: E731
    chord = 2 * np.sin((t[1] - t[0]) / 2)
    assert _orbit_distance(circle(1.0, 0.0), circle(1.0, 2.0)) <= chord
    assert _orbit_distance(circle(1.0, 0.0), circle(1.2, 1.0)) == pytest.approx(0.2, abs=1.2 * chord)
    assert _closes(circle(1.0, 0.0), 0.05) and not _closes(circle(1.0, 0.0)[t < 5.0], 0.05)
    assert _closes(circle(0.01, 0.0)[t < 1.0], 0.05)  # an orbit within eps of a point is closed as far as eps sees


def _synthetic(x):
    """A _Features holding scaled window features ``x`` (N, 4) only, for the grouping helpers."""
    from stabjax.mapping.discover import _Features

    n = len(x)
    return _Features(feats=x, names=["mean(x)", "std(x)", "min(x)", "max(x)"], x=x, xf=x[:, :1], scale=np.ones(1),
                     tol=np.zeros(1), valid=np.ones(n, bool), final=x[:, :1], lam=np.full(n, 0.8),
                     at_rest=np.zeros(n, bool), autonomous=True, unbounded=np.zeros(n, bool))


def test_pieces_of_one_chaotic_cloud_are_one_attractor_and_two_clouds_stay_two():
    """DBSCAN cut Lorenz-63's one chaotic cloud (r = 24.4, 300 starts, 1000 checkpoints over t1 = 2000) into
    chaotic_1..3 of 203, 33 and 21 starts, medians 0.06-0.09 apart inside a cloud of extent 0.12 (the reliability
    pass). Pieces whose median lies within another's extent are one attractor; a cloud whose median lies outside
    every other's stays its own."""
    from stabjax.mapping.discover import DiscoveryConfig, _merge_chaotic

    rng = np.random.default_rng(0)
    big = rng.normal(0.0, 0.04, (200, 4))
    pieces = [big, rng.normal(0.06, 0.02, (30, 4)), rng.normal(-0.05, 0.02, (20, 4)),
              rng.normal(0.6, 0.04, (50, 4))]  # the last: another attractor, 0.6 x 2 away
    x = np.concatenate(pieces)
    bounds = np.cumsum([0] + [len(p) for p in pieces])
    groups = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    f = _synthetic(x)
    others = [(g, "chaotic", np.median(x[g], axis=0), 0.8, int(g[0])) for g in groups]
    cfg = DiscoveryConfig()
    out = sorted(sorted(r[0].tolist()) for r in _merge_chaotic(others, f, cfg))
    assert out == [list(range(250)), list(range(250, 300))]
    assert all(r[1] == "chaotic" for r in _merge_chaotic(others, f, cfg))


def test_a_cycle_its_observables_cannot_see_is_no_fixed_point():
    """The shock example's rotating field watched through r alone: its cycles r = 2, 4, 6 keep r constant, so every
    observable rests, and they were fixed_point_2..4 (exponent -2e-9; the reliability pass). An equilibrium reached
    from a start at the observables' scale has contracted by the window's start; these have not: untyped and said.
    The origin (exponent -1) stays a fixed point. Each start's radius class is the closed form's (r0 < 1: origin,
    1-3: r = 2, 3-5: r = 4, beyond: r = 6)."""
    from stabjax.mapping.discover import TransientWarning

    box = {"dist": "uniform", "low": -4.5, "high": 4.5}
    with pytest.warns(TransientWarning, match="a motion the observables do not see"):
        ds = run_spec({"system": "examples/shock_circle/model.py:Circle", "sample": {"n": 200, "seed": 2, "x0": box,
                                                                                     "y0": box},
                       "integrate": {"t1": 60.0, "rtol": 1e-8, "atol": 1e-10}, "outcomes": {"discover": True}})
    types = dict(zip(ds["attractor"].values, ds["attractor_type"].values))
    assert sorted(types.values()) == ["attractor", "attractor", "attractor", "fixed_point"], types
    r0 = np.hypot(ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel())
    rf = ds["feat_final"].values.ravel()
    expect = np.select([r0 < 1, r0 < 3, r0 < 5], [0.0, 2.0, 4.0], 6.0)
    np.testing.assert_allclose(rf, expect, atol=1e-4)
    names = ds["outcome"].attrs["flag_meanings"].split()
    lab = np.array([names[c] for c in ds["outcome"].values.ravel()])
    for r in (0.0, 2.0, 4.0, 6.0):
        assert len(set(lab[expect == r])) == 1  # one name per attractor
        if r:
            assert types[lab[expect == r][0]] == "attractor"


def test_two_equilibria_closer_than_eps_are_two():
    """x' = -x (x - 0.1)(x - 0.2)(x - 5)(x - 10) / 10 rests at 0, 0.2 and 10 (stable), with 0.1 and 5 unstable
    between: the rest points 0 and 0.2 lie 0.018 of the range apart, within eps, and were one fixed point (the
    reliability pass). Where a trajectory rests is known to its rest threshold: three fixed points, each start at the
    one its interval of x0 flows to (the closed form's phase line), placed there."""
    Three = _phase_line("three_test", "x' = -x (x - 0.1)(x - 0.2)(x - 5)(x - 10) / 10",
                        lambda y: -y * (y - 0.1) * (y - 0.2) * (y - 5.0) * (y - 10.0) / 10.0)
    x0 = np.concatenate([np.linspace(-1.0, 0.05, 12), np.linspace(0.15, 4.8, 20), np.linspace(5.3, 12.0, 20)])
    ds = run_spec({"system": _one(Three), "grid": {"x0": x0.tolist()},
                   "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-10, "n_checkpoints": 100}})
    assert list(ds["attractor_type"].values) == ["fixed_point"] * 3
    rest = np.select([x0 < 0.1, x0 < 5.0], [0.0, 0.2], 10.0)
    names = ds["outcome"].attrs["flag_meanings"].split()
    lab = np.array([names[c] for c in ds["outcome"].values.ravel()])
    at = dict(zip(ds["attractor"].values, ds["attractor_state"].values[:, 0]))
    for r in (0.0, 0.2, 10.0):
        assert len(set(lab[rest == r])) == 1, (r, set(lab[rest == r]))
        assert at[lab[rest == r][0]] == pytest.approx(r, abs=1e-6)


def test_pooled_grouping_over_a_grid_says_which_names_are_one_moving_attractor():
    """The reliability pass's case, smaller: x'' = -0.3 x' + x - x^3 + F over F = -0.5 ... 0.5 with
    continuation = false. Each well's equilibrium (a root of x - x^3 + F) moves ~0.1-0.2 between grid points, farther
    than eps, so the pooled grouping gives each well one name per stretch of the grid (exit 0, unsaid; the table
    said "at x = 1.125" with no grid point). Every pair of names that hold one well at neighbouring grid points is now
    said, no pair of different wells is, and each place names its representative's grid point."""
    from stabjax.mapping.discover import SplitWarning
    from stabjax.present.kit import attractors

    F = [-0.5, -0.3, -0.15, 0.0, 0.15, 0.3, 0.5]
    box = {"n": 100, "seed": 3, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    ds, names, said = _discovered(_wells(), box, 100.0, {"continuation": False}, SplitWarning, params={"c": 0.3},
                                  grid={"F": F})
    state = ds["attractor_state"].values
    rep_F = ds["attractor_start_F"].values
    placed = ds["attractor_placed"].values
    for k in range(len(state)):  # each name rests at a stable root of x - x^3 + F at its representative's F
        roots = np.roots([-1.0, 0.0, 1.0, rep_F[k]])
        stable = [r.real for r in roots if abs(r.imag) < 1e-12 and 1 - 3 * r.real ** 2 < 0]
        # placed by Newton: within one tolerance unit; else the re-integrated state, within the fixed-point stop's
        # 1000 units (the solver's plateau about a stable equilibrium)
        units = 1.0 if placed[k] else 1000.0
        x = min(stable, key=lambda r: abs(state[k, 0] - r))
        assert abs(state[k, 0] - x) < units * (1e-10 + 1e-8 * abs(x)) and abs(state[k, 1]) < units * 1e-10, k
    o = ds["outcome"].values
    present = {n: [j for j in range(len(F)) if (o[j] == i).any()] for i, n in enumerate(names) if n.startswith("fixed")}
    well = {n: np.sign(state[names.index(n), 0]) for n in present}
    expected = set()
    for side in (-1.0, 1.0):
        chain = sorted((n for n in present if well[n] == side), key=lambda n: present[n][0])
        expected |= {frozenset(p) for p in zip(chain, chain[1:])}
    assert len(expected) >= 2 and len(said) == 1, (present, said)  # the case splits; one warning says it
    text = said[0]
    reported = {frozenset(p) for p in re.findall(r"(fixed_point_\d+) and (fixed_point_\d+) \(across", text)}
    assert reported == expected, (reported, expected, present)
    assert "continuation = true" in text
    for a in attractors(ds):
        assert "(at F = " in a["where"] and "grouped over the grid" in a["where"], a


def _torque():
    """theta'' = -0.1 theta' + 0.5 - sin theta, observed through theta itself (unwrapped) and omega: rest points
    at theta* + 2 pi k (theta* = asin 0.5), and a running cycle whose drift makes theta's range ~1000."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class Torque(System):
        name = "torque_unwrapped_test"
        params = ParamSet((Param("theta0", 0.0, "theta0", kind="initial"),
                           Param("omega0", 0.0, "omega0", kind="initial")))
        state = (("theta", ()), ("omega", ()))
        observables = ("theta", "omega")
        observable_doc = ("theta, unwrapped", "omega")

        def initial_state(self, p):
            return jnp.stack([p["theta0"], p["omega0"]])

        def rhs(self, t, z, p):
            return jnp.stack([z[1], -0.1 * z[1] + 0.5 - jnp.sin(z[0])])

        def observe(self, t, z, p):
            return z

    return Torque


def test_rest_points_whole_turns_apart_on_an_unwrapped_angle_are_different_fixed_points():
    """The reliability pass's case: with theta observed unwrapped, the running cycle's drift makes theta's range
    ~1100 and the rest points theta* + 2 pi k lie 0.006 of it apart, within eps: seven of them were one fixed_point_1,
    placed at one, though the trajectories still spiralling in end far apart for how little they move. Each fixed
    point now holds one rest point: against SciPy's DOP853 (the starts stacked in one integration, as for the
    pendulum above), every start that rests at one theta* + 2 pi k (and whose answer a 1e-7 nudge does not change)
    has the name of that k or none (a rest point too few starts reach is no group), no two names share a k, and
    each name is placed at its own."""
    t1, n = 200.0, 300
    spec = {"system": _one(_torque()), "integrate": {"t1": t1, "rtol": 1e-8, "atol": 1e-8},
            "outcomes": {"discover": True},
            "sample": {"n": n, "seed": 1, "theta0": {"dist": "uniform", "low": -5 * np.pi / 6, "high": 7 * np.pi / 6},
                       "omega0": {"dist": "uniform", "low": -10.0, "high": 10.0}}}
    ds = run_spec(spec)
    th, om = ds["theta0_sample"].values, ds["omega0_sample"].values
    m = 2 * n

    def f(t, y):
        return np.concatenate([y[m:], -0.1 * y[m:] + 0.5 - np.sin(y[:m])])

    tol = 1e-11 / np.sqrt(2 * m)
    sol = solve_ivp(f, (0, t1), np.r_[th, th * (1 + 1e-7) + 1e-7, om, om], method="DOP853", rtol=tol, atol=tol)
    assert sol.success
    end_th, end_om = sol.y[:m, -1], sol.y[m:, -1]
    rest = np.abs(end_om) < 1e-2
    k = np.where(rest, np.round((end_th - np.arcsin(0.5)) / (2 * np.pi)), np.nan)
    k, nudged = np.split(k, 2)
    robust = (k == nudged) & np.isfinite(k)
    names = ds["outcome"].attrs["flag_meanings"].split()
    got = np.array([names[int(c)] for c in ds["outcome"].values])
    types = dict(zip(ds["attractor"].values, ds["attractor_type"].values))
    fixed = sorted(n for n, t in types.items() if t == "fixed_point")
    assert len(fixed) >= 3, (fixed, np.unique(k[robust], return_counts=True))
    at = dict(zip(ds["attractor"].values, ds["attractor_state"].values[:, 0]))
    for name in fixed:
        ks = set(k[robust & (got == name)])
        assert len(ks) == 1, (name, ks)
        # placed by Newton, or the re-integrated state frozen within the fixed-point stop's 1000 tolerance units
        assert abs(at[name] - (np.arcsin(0.5) + 2 * np.pi * ks.pop())) < 1000 * (1e-8 + 1e-8 * abs(at[name])), name
    for kk in np.unique(k[robust]):
        assert set(got[robust & (k == kk)]) <= set(fixed) | {"unclassified"}
        assert len(set(got[robust & (k == kk)]) - {"unclassified"}) <= 1, kk
        assert not (set(got[robust & (k == kk)]) & {n for n, t in types.items() if t != "fixed_point"}), kk


def test_a_fixed_point_whose_observables_cannot_tell_two_wells_apart_is_said():
    """x'' = x - x^3 - 0.3 x' observed through its energy alone: both wells rest at energy -1/4, and the
    observables group them as one fixed point "at x = -1" (the reliability pass: said nowhere). Its trajectories,
    integrated again, end at x = -1 and x = 1: said (MixedWarning), naming the fixed point and both places."""
    from stabjax.mapping.discover import MixedWarning

    class Energy(_wells()):
        name = "wells_energy_test"
        observables = ("E",)
        observable_doc = ("energy y^2/2 - x^2/2 + x^4/4",)

        def observe(self, t, z, p):
            return (0.5 * z[1] ** 2 - 0.5 * z[0] ** 2 + 0.25 * z[0] ** 4)[None]

    box = {"n": 100, "seed": 2, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    ds, names, said = _discovered(Energy, box, 100.0, {}, MixedWarning, params={"c": 0.3})
    assert list(ds["attractor_type"].values) == ["fixed_point"], ds["attractor_type"].values
    assert len(said) == 1, said
    assert "fixed_point_1" in said[0] and "x = -1," in said[0] and "x = 1," in said[0] and "(E)" in said[0], said


def _locked():
    """Two Stuart-Landau oscillators with second-harmonic coupling, z_j' = (1 + i - |z_j|^2) z_j + 0.2 z_k^2
    conj(z_j) (k the other one), written in real components: locking in phase (z2 = z1) and in antiphase (z2 = -z1)
    are both stable, on orbits of radius sqrt(1.25) whose components have the same window mean, spread and range."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System

    class Locked(System):
        name = "locked_test"
        params = ParamSet(tuple(Param(n, v, n, kind="initial")
                                for n, v in (("x10", 1.0), ("y10", 0.0), ("x20", 0.5), ("y20", 0.5))))
        state = (("x1", ()), ("y1", ()), ("x2", ()), ("y2", ()))
        observables = ("x1", "y1", "x2", "y2")
        observable_doc = ("x1", "y1", "x2", "y2")

        def initial_state(self, p):
            return jnp.stack([p["x10"], p["y10"], p["x20"], p["y20"]])

        def rhs(self, t, u, p):
            x1, y1, x2, y2 = u[0], u[1], u[2], u[3]
            g1, g2 = 1.0 - x1 * x1 - y1 * y1, 1.0 - x2 * x2 - y2 * y2
            # K z_k^2 conj(z_j) in components: z_k^2 = (a^2 - b^2) + 2ab i, times (x_j - i y_j)
            re1, im1 = x2 * x2 - y2 * y2, 2.0 * x2 * y2
            re2, im2 = x1 * x1 - y1 * y1, 2.0 * x1 * y1
            return jnp.stack([g1 * x1 - y1 + 0.2 * (re1 * x1 + im1 * y1), g1 * y1 + x1 + 0.2 * (im1 * x1 - re1 * y1),
                              g2 * x2 - y2 + 0.2 * (re2 * x2 + im2 * y2), g2 * y2 + x2 + 0.2 * (im2 * x2 - re2 * y2)])

        def observe(self, t, u, p):
            return u

    return Locked


def test_two_orbits_whose_window_features_are_equal_are_said():
    """The reliability pass's case: oscillators locked in phase or in antiphase have equal window features in
    every observable, so discovery groups them as one limit_cycle_1 (S = 1), and nothing said so. The cycle's
    trajectories integrated again lie on two orbits: said (MixedWarning), with a start on each. The reference:
    SciPy's DOP853 from the sample's first starts (to t = 200) ends both in phase and in antiphase."""
    from stabjax.mapping.discover import MixedWarning

    box = {"n": 60, "seed": 1, **{k: {"dist": "uniform", "low": -1.0, "high": 1.0} for k in ("x10", "y10", "x20", "y20")}}
    ds, names, said = _discovered(_locked(), box, 100.0, {}, MixedWarning)
    z = np.stack([ds[f"{k}_sample"].values for k in ("x10", "y10", "x20", "y20")], axis=1)

    def f(t, u):  # the equations in complex form, independently of the model's components
        z1, z2 = u[0] + 1j * u[1], u[2] + 1j * u[3]
        d1 = (1 + 1j - abs(z1) ** 2) * z1 + 0.2 * z2 ** 2 * np.conj(z1)
        d2 = (1 + 1j - abs(z2) ** 2) * z2 + 0.2 * z1 ** 2 * np.conj(z2)
        return [d1.real, d1.imag, d2.real, d2.imag]

    phase = []
    for u0 in z[:8]:
        s = solve_ivp(f, (0.0, 200.0), u0, method="DOP853", rtol=1e-9, atol=1e-11)
        x1, y1, x2, y2 = s.y[:, -1]
        phase.append(abs(np.angle((x2 + 1j * y2) / (x1 + 1j * y1))))
    assert min(phase) < 1e-3 and max(phase) > np.pi - 1e-3, phase  # both lockings among the starts
    assert list(ds["attractor_type"].values) == ["limit_cycle"], ds["attractor_type"].values
    assert len(said) == 1 and "limit_cycle_1" in said[0] and "end at 2 places" in said[0], said


def test_a_cycle_approached_slowly_from_outside_is_never_a_fixed_point():
    """r' = 0.02 r (1 - r^2), theta' = 1 (in x, y) at t1 = 150: the unit circle attracts so weakly that its
    trajectories' peaks fall at the rate of their finite-time exponent, as a weak focus's do; it was fixed_point_1
    (S = 0.995), though its only equilibrium, the origin, is an unstable focus (eigenvalues 0.02 +- i). A weak focus
    needs a stable equilibrium inside its window: none is there, so the group is left untyped and said."""
    import jax.numpy as jnp

    from stabjax import Param, ParamSet, System
    from stabjax.mapping.discover import TransientWarning

    class Slow(System):
        name = "slow_cycle_test"
        params = ParamSet((Param("x0", 1.0, "x0", kind="initial"), Param("y0", 0.0, "y0", kind="initial")))
        state = (("x", ()), ("y", ()))
        observables = ("x", "y")
        observable_doc = ("x", "y")

        def initial_state(self, p):
            return jnp.stack([p["x0"], p["y0"]])

        def rhs(self, t, u, p):
            g = 0.02 * (1.0 - u[0] * u[0] - u[1] * u[1])
            return jnp.stack([g * u[0] - u[1], g * u[1] + u[0]])

        def observe(self, t, u, p):
            return u

    assert np.all(np.linalg.eigvals([[0.02, -1.0], [1.0, 0.02]]).real > 0)  # the origin repels
    box = {"n": 60, "seed": 3, "x0": {"dist": "uniform", "low": -2.5, "high": 2.5},
           "y0": {"dist": "uniform", "low": -2.5, "high": 2.5}}
    ds, names, said = _discovered(Slow, box, 150.0, {}, TransientWarning)
    assert "fixed_point" not in set(ds["attractor_type"].values), ds["attractor_type"].values
    assert any("no stable equilibrium lies inside their window" in w for w in said), said


def test_a_resting_part_too_small_for_a_group_is_left_out_not_named_after_its_neighbour():
    """Trajectories at rest split by where they rest (:func:`_split_rest`): a part of fewer than min_samples, resting
    at an equilibrium of its own, is left out (unclassified), never counted in the nearest part (theta observed
    unwrapped: one start resting 2 pi from fixed_point_4 was counted in it)."""
    from stabjax.mapping.discover import _split_rest

    xf = np.r_[np.zeros(10), np.full(8, 0.5), [0.9]][:, None]
    g = np.arange(len(xf))
    parts = _split_rest(g, xf, fine=0.01, min_samples=5)
    assert sorted(map(list, parts)) == [list(range(10)), list(range(10, 18))]
    one = _split_rest(np.arange(10), np.zeros((10, 1)), fine=0.01, min_samples=5)
    assert [list(p) for p in one] == [list(range(10))]


def _saddle_or_slow():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet

    Relax, _ = _relax()

    class SaddleOrSlow(Relax):
        """x' = s (x - x^3) - (1 - s) a x, y' = -20 (y - (1 - s) x^2). s = 1: stable nodes at (+-1, 0) and a saddle
        at (0, 0) (eigenvalues +1, -20) whose stable manifold x = 0 bounds their basins; s = 0: one slow stable node
        at (0, 0) (eigenvalues -a, -20), approached along the parabola y = x^2. One class (s on a grid of one point)
        so that both share a kernel (CI time)."""

        name = "saddle_or_slow_test"
        params = ParamSet((*Relax.params.params, Param("s", 1.0, "1: a saddle between two nodes, 0: a slow node"),
                           Param("a", 0.02, "the slow node's rate")))

        def rhs(self, t, y, p):
            s = p["s"]
            return jnp.stack([s * (y[0] - y[0] ** 3) - (1.0 - s) * p["a"] * y[0], -20.0 * (y[1] - (1.0 - s) * y[0] ** 2)])

    return SaddleOrSlow


def _saddle_or_slow_rhs(s, a=0.02):
    return lambda t, y: [s * (y[0] - y[0] ** 3) - (1 - s) * a * y[0], -20.0 * (y[1] - (1 - s) * y[0] ** 2)]


def test_starts_on_a_saddles_stable_manifold_are_no_attractor():
    """x' = x - x^3, y' = -20 y on a symmetric grid: the column x0 = 0 lies on the saddle's stable manifold and comes
    to rest at (0, 0), where the Jacobian has the eigenvalue +1. Those starts were fixed_point_3 (S = 0.11, exponent
    +1, unsaid); they are unclassified now, said, and every other start is named by the node SciPy's DOP853 takes it
    to (placed there)."""
    from stabjax.mapping.discover import UnstableWarning

    x0, y0 = np.linspace(-1.0, 1.0, 9), np.linspace(-1.0, 1.0, 7)
    ds, names, said = _discovered(_saddle_or_slow(), None, 30.0, {}, UnstableWarning,
                                  grid={"x0": x0.tolist(), "y0": y0.tolist(), "s": [1.0]})
    assert names == ["fixed_point_1", "fixed_point_2", "unclassified", "failed"], names
    assert len(said) == 1 and re.search(r"7 trajectories rest at an unstable equilibrium at x = 0, y = 0 .*real part 1\b",
                                        said[0]), said
    out = ds["outcome"].squeeze().transpose("x0", "y0").values
    rhs = _saddle_or_slow_rhs(1.0)
    for i, a in enumerate(x0):
        for j, b in enumerate(y0):
            end = solve_ivp(rhs, (0.0, 60.0), [a, b], method="DOP853", rtol=1e-11, atol=1e-12).y[:, -1]
            if a == 0.0:  # on the stable manifold: the saddle itself, no attractor
                assert abs(end[0]) < 1e-9 and names[out[i, j]] == "unclassified"
            else:
                k = names[out[i, j]]
                place = ds["attractor_state"].sel(attractor=k).values
                np.testing.assert_allclose(place, end, atol=1e-6)
                assert abs(end[0]) == pytest.approx(1.0, abs=1e-8)
    assert set(ds["attractor_type"].values) == {"fixed_point"}


def test_a_slow_node_approached_from_all_sides_is_one_fixed_point_at_its_equilibrium():
    """A slow stable node (x' = -0.02 x, y' = -20 (y - x^2); eigenvalues -0.02 and -20), 120 starts in [-2, 2]^2,
    t1 = 100: every trajectory still approaches along the parabola, and DBSCAN grouped them on four sides of the node
    (four 'fixed points' at points that are none). Newton's method from each representative finds the one
    equilibrium ahead, a hyperbolic stable one approached at its slow rate: one fixed point, S = 1, placed at (0, 0)
    (attractor_placed 2), as SciPy's DOP853 says of every start."""
    rng = np.random.default_rng(4)
    box = {"n": 120, "seed": 5, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0},
           "y0": {"dist": "uniform", "low": -2.0, "high": 2.0}}
    # (continuation off: s on a grid of one point, the sweep's kernel shared with the saddle's)
    ds, names, _ = _discovered(_saddle_or_slow(), box, 100.0, {"continuation": False}, UserWarning, grid={"s": [0.0]})
    assert names == ["fixed_point_1", "unclassified", "failed"] and (ds["outcome"].values == 0).all(), \
        (names, np.bincount(ds["outcome"].values.ravel()))
    assert int(ds["attractor_placed"].values[0]) == 2
    np.testing.assert_allclose(ds["attractor_state"].values[0], [0.0, 0.0], atol=1e-8)
    rhs = _saddle_or_slow_rhs(0.0)
    starts = np.stack([ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel()], axis=1)
    assert np.abs(ds["feat_final"].values.reshape(-1, 2)[:, 0]).max() > 0.2  # still far from it at t1 ...
    for a, b in starts[rng.choice(len(starts), 12, replace=False)]:
        end = solve_ivp(rhs, (0.0, 2000.0), [a, b], method="DOP853", rtol=1e-11, atol=1e-14).y[:, -1]
        assert np.hypot(*end) < 1e-12  # ... yet its limit, from every start


def test_a_window_inside_a_chaotic_attractors_box_with_its_exponent_joins_it():
    """Roessler at c = 5.7 (100 starts, t1 = 600): two trajectories on the one chaotic attractor, with its exponent,
    were left unclassified, the heavy tail of a window maximum (z up to 18 and 19 against the group's 22) putting
    them beyond the group's extent. A leftover whose window lies inside the box the group's windows cover, with an
    exponent among theirs, joins it; one outside the box, or with another exponent, does not."""
    from stabjax.mapping.discover import DiscoveryConfig, _join_chaotic

    rng = np.random.default_rng(3)
    n = 100
    group = np.stack([rng.normal(0.5, 0.01, n), rng.normal(0.3, 0.01, n), rng.uniform(0.0, 0.05, n),
                      rng.uniform(0.9, 1.0, n)], axis=1)
    tail = [0.5, 0.3, 0.02, 0.7]  # a low window maximum: far from the median, inside the box
    left = np.array([tail, tail, [0.5, 0.3, 0.02, 1.3], [0.5, 0.3, -0.4, 0.95]])
    f = _synthetic(np.concatenate([group, left]))
    f.lam[:n] = rng.uniform(0.06, 0.1, n)
    f.lam[n:] = [0.08, 0.5, 0.08, 0.08]  # the second: the exponent of another motion
    g = np.arange(n)
    others = [(g, "chaotic", np.median(f.x[g], axis=0), 0.08, 0)]
    cfg = DiscoveryConfig()
    assert np.linalg.norm(f.x[n] - np.median(group, axis=0)) > np.linalg.norm(group - np.median(group, axis=0),
                                                                              axis=1).max() + cfg.eps
    rest, out = _join_chaotic(np.arange(n, n + 4), others, f, cfg)
    assert rest.tolist() == [n + 1, n + 2, n + 3]
    assert out[0][0].tolist() == list(range(n + 1)) and out[0][1] == "chaotic"


def test_groups_by_one_unstable_equilibrium_are_said_as_one_place():
    """May-Leonard: 108 and 10 trajectories lingering by the one saddle (0, 1, 0), grouped apart, were said as two
    places (x = -9.2e-41 and x = 0); one place, 118 trajectories, and the other saddles each once."""
    from types import SimpleNamespace

    from stabjax.mapping.discover import _by_place

    disc = SimpleNamespace(counts=np.array([108, 10, 6]))
    icfg = SimpleNamespace(atol=1e-14, rtol=1e-10)
    unstable = [(0, False, np.array([-9.184e-41, 1.0, 0.0]), 0.2), (1, True, np.array([0.0, 1.0, 0.0]), 0.2),
                (2, False, np.array([1.0, 0.0, 0.0]), 0.2)]
    said = _by_place(disc, unstable, ["x", "y", "z"], icfg)
    assert [(n, rest) for n, rest, _, _ in said] == [(118, True), (6, False)]
    assert said[1][2] == "x = 1, y = 0, z = 0"


def test_unclassified_trajectories_that_look_like_a_fixed_points_own_are_said():
    """The linear weak focus x' = -0.001 x - y, y' = x - 0.001 y (100 starts, t1 = 500): its 4 innermost starts,
    small circles DBSCAN kept apart, were unclassified with nothing said (4 %). A leftover with an exponent within the
    fixed point's members' and a window mean within eps of theirs is said (not joined: a cycle's trajectory circling
    a weak focus has an exponent near 0 too); one with another exponent, or elsewhere, or at rest (resting at another
    equilibrium, a part too small for a group), is not."""
    import warnings

    from stabjax.mapping.discover import Attractors, TransientWarning, _circling, _warn_circling

    n = 13
    mean = np.r_[np.full(8, 0.01), 0.0, 0.02, 0.0, 1.5, 0.01][:, None]
    std = np.r_[np.full(12, 0.05), 0.0][:, None]  # the last at rest
    lam = np.r_[np.full(8, -0.001), -0.001, -0.001, 0.05, -0.001, -0.001]
    labels = np.r_[np.zeros(8, int), -1, -1, -1, -1, -1]
    results = {"lyapunov": lam, "feat_mean": mean, "feat_std": std, "feat_min": mean - std, "feat_max": mean + std}
    disc = Attractors(labels=labels, names=["fixed_point_1"], types=["fixed_point"], counts=np.array([8]),
                      features=np.zeros((1, 4)), feature_names=["mean(x)", "std(x)", "min(x)", "max(x)"],
                      lyapunov=np.array([-0.001]), representative=np.array([0]), scale=np.array([4.0]))
    from stabjax.mapping.discover import DiscoveryConfig

    said = _circling(disc, results, ("x",), DiscoveryConfig(), np.ones(n, bool))
    assert said == [("fixed_point_1", 2, -0.001, -0.001)]
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        _warn_circling(said, 0.05)
    assert len(w) == 1 and issubclass(w[0].category, TransientWarning) and "2 unclassified" in str(w[0].message)
    assert _circling(disc, {**results, "lyapunov": np.r_[lam[:8], 0.01, 0.01, 0.05, 0.01, 0.01]}, ("x",),
                     DiscoveryConfig(), np.ones(n, bool)) == []


def _sine_nodes():
    import jax.numpy as jnp

    from stabjax import Param, ParamSet

    Relax, _ = _relax()

    class SineNodes(Relax):
        """x' = -k sin(pi x), y' = -20 (y - 0.1 x^2): stable nodes at even x, saddles at odd x; slow (k = 0.006).
        Newton's method on sin(pi x) from x ~ 0.45 jumps to x = -2, past the saddle at -1."""

        name = "sine_nodes_test"
        params = ParamSet((*Relax.params.params, Param("k", 0.006, "rate")))

        def rhs(self, t, y, p):
            return jnp.stack([-p["k"] * jnp.sin(jnp.pi * y[0]), -20.0 * (y[1] - 0.1 * y[0] ** 2)])

    return SineNodes


def test_an_untyped_approach_heading_for_a_fixed_point_is_that_fixed_point():
    """Slow nodes x' = -0.006 sin(pi x), 200 starts with |x0| < 0.95, t1 = 100: every start goes to (0, 0) (SciPy), but
    10 of them, their exponent (-0.007) too near 0 to type, were an untyped attractor_1 beside fixed_point_1 at (0, 0)
    (the seventh reliability pass). An untyped group still approaching, whose representative heads for a hyperbolic
    stable equilibrium, is a fixed point placed there, and one with the fixed point already there. Newton's jumps
    to x = +-2 are refused (no start is placed there)."""
    rng = np.random.default_rng(1)
    box = {"n": 200, "seed": 8, "x0": {"dist": "uniform", "low": -0.95, "high": 0.95},
           "y0": {"dist": "uniform", "low": -1.0, "high": 1.0}}
    ds, names, _ = _discovered(_sine_nodes(), box, 100.0, {}, UserWarning)
    assert names[0] == "fixed_point_1" and "attractor_1" not in names and not any(n.startswith("fixed_point_2")
                                                                                for n in names), names
    np.testing.assert_allclose(ds["attractor_state"].values[0], [0.0, 0.0], atol=1e-8)
    assert set(ds["attractor_type"].values) == {"fixed_point"}
    k = 0.006
    starts = np.stack([ds["x0_sample"].values.ravel(), ds["y0_sample"].values.ravel()], axis=1)
    for a, b in starts[rng.choice(len(starts), 8, replace=False)]:
        end = solve_ivp(lambda t, y: [-k * np.sin(np.pi * y[0]), -20.0 * (y[1] - 0.1 * y[0] ** 2)], (0.0, 3000.0),
                        [a, b], method="DOP853", rtol=1e-11, atol=1e-14).y[:, -1]
        assert np.hypot(*end) < 1e-9
