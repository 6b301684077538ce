"""The examples outside attitude control, against an independent SciPy DOP853 integration.

For a subset of each example's sampled starts, SciPy integrates the same equations (written
again here in plain Python, tight tolerances), takes the late-window features at the same
checkpoint times and applies the same outcome rule or nearest-template assignment; every label
must agree. A start near a basin boundary can be labelled either way by two correct solvers, so a
start counts only if its SciPy label is unchanged by a 1e-7 perturbation of the start (and most
starts must pass that filter, so the comparison is not vacuous).
"""
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax.fold import verdict as V
from stabjax.mapping.declared import min_template_spacing
from stabjax.model.outcomes import FAILED_NAME, UNCLASSIFIED, Rule
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_plan

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def pendulum(t, y, p):
    return [y[1], -p["alpha"] * y[1] + p["T"] - p["K"] * np.sin(y[0])]


def pendulum_obs(y, p):
    return np.array([y[1], np.sin(y[0])])


def duffing(t, y, p):
    return [y[1], -p["delta"] * y[1] - p["k3"] * y[0] ** 3 + p["A"] * np.cos(t)]


def lorenz(t, u, p):
    x, y, z = u
    return [p["sigma"] * (y - x), p["r"] * x - x * z - y, x * y - p["b"] * z]


# name: (rhs, observables, initial-condition parameters, starts checked, horizon, checkpoints).
# The horizons are shorter than the shipped specs' (CI time) with the same 100-unit feature
# window: long enough for the slowest transient (pendulum: e^{-0.05 t}) to die out.
CASES = {
    "pendulum": (pendulum, pendulum_obs, ("theta0", "omega0"), 8, 300.0, 1200),
    "duffing": (duffing, lambda y, p: np.asarray(y), ("x0", "v0"), 8, 400.0, 1600),
    "lorenz": (lorenz, lambda y, p: np.asarray(y), ("x0", "y0", "z0"), 6, 400.0, 1600),
}


def scipy_features(rhs, obs_fn, y0, p, ts, t_from, escape):
    """Late-window features (max, min, mean, std, final per observable) from DOP853, or 'escaped'."""
    events = None
    if escape is not None:
        def ev(t, y, p):
            return escape - np.max(np.abs(y))
        ev.terminal, ev.direction = True, -1
        events = ev
    sol = solve_ivp(rhs, (ts[0], ts[-1]), y0, method="DOP853", rtol=1e-11, atol=1e-11, dense_output=True,
                    args=(p,), events=events)
    if sol.status == 1:
        return "escaped"
    assert sol.status == 0, sol.message
    tw = ts[ts >= t_from]
    ys = sol.sol(tw)  # (n_state, K)
    o = np.stack([obs_fn(ys[:, j], p) for j in range(len(tw))])  # (K, n_obs)
    return {"max": o.max(0), "min": o.min(0), "mean": o.mean(0), "std": o.std(0), "final": o[-1]}


def scipy_label(plan, feats_of, start, cache):
    sch = plan.scheme
    decl = sch.decl
    sysm = plan.system
    obs = tuple(sysm.observables)
    scalars = tuple(q.name for q in sysm.params if not q.shape)
    f = feats_of(start)
    if isinstance(f, str):
        return decl.escape
    getter = lambda stat, name: np.array([f[stat][obs.index(name)]])  # noqa: E731
    par = lambda name: np.array([float(start[name])])  # noqa: E731
    for name, text in decl.rules.items():
        if bool(Rule(text, obs, scalars, name)(getter, par)[0]):
            return name
    if decl.templates:
        def vec(ff):
            g = lambda stat, name: np.array([ff[stat][obs.index(name)]])  # noqa: E731
            return np.array([Rule(t, obs, scalars, "f", boolean=False)(g, par)[0] for t in decl.features])

        if "templates" not in cache:  # the fixed parameters are the same for every start
            cache["templates"] = np.stack([vec(feats_of({**start, **{k: float(v) for k, v in over.items()}}))
                                           for over in decl.templates.values()])
        tvec = cache["templates"]
        x = vec(f)
        d = np.linalg.norm(tvec - x, axis=1)
        limit = decl.max_distance or 0.5 * float(min_template_spacing(tvec[None])[0])
        if d.min() <= limit:
            return list(decl.templates)[int(np.argmin(d))]
    return UNCLASSIFIED


@pytest.mark.parametrize("name", sorted(CASES))
def test_example_labels_match_scipy(name):
    rhs, obs_fn, ic_keys, n, t1, n_ck = CASES[name]
    spec = load_spec(EXAMPLES / name / "spec.toml")
    spec["sample"] = {**spec["sample"], "n": n}
    spec["integrate"] = {**spec["integrate"], "t1": t1, "n_checkpoints": n_ck}
    spec["outcomes"] = {"window": 100.0 / t1}
    plan = make_plan(spec)
    ds = run_plan(plan)
    names = ds["outcome"].attrs["flag_meanings"].split()
    ts = V.checkpoint_times(plan.icfg.checkpoints(), plan.vcfg)  # the engines' checkpoints
    t_from = plan.icfg.t0 + (1 - plan.vcfg.feature_window) * (plan.icfg.t1 - plan.icfg.t0)
    fixed = {k: float(v) for k, v in plan.fixed.items() if np.ndim(v) == 0}
    escape = plan.escape_radius

    def feats_of(start):
        y0 = [float(start[k]) for k in ic_keys]
        return scipy_features(rhs, obs_fn, y0, start, ts, t_from, escape)

    robust = agree = 0
    cache = {}
    for i in range(n):
        start = dict(fixed)
        for k in plan.sample:
            start[k] = float(ds[f"{k}_sample"].values[i])
        got = names[int(ds["outcome"].values[i])]
        assert got != FAILED_NAME
        ref = scipy_label(plan, feats_of, start, cache)
        nudged = scipy_label(plan, feats_of, {**start, ic_keys[0]: start[ic_keys[0]] * (1 + 1e-7) + 1e-7}, cache)
        if ref != nudged:
            continue
        robust += 1
        assert got == ref, f"start {i} {start}: stabjax {got}, SciPy {ref}"
        agree += 1
    assert robust >= 0.75 * n, f"only {robust} of {n} starts have a label robust to a 1e-7 nudge"
    # the standard errors in the dataset are the binomial ones
    s = ds["basin_fraction"].values
    np.testing.assert_allclose(ds["basin_se"].values, np.sqrt(s * (1 - s) / n), rtol=1e-12)
