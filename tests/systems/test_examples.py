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
    tw = ts[ts >= t_from]
    # t_eval: the dense output of the steps that hold a window time only (the same values as dense_output=True)
    sol = solve_ivp(rhs, (ts[0], ts[-1]), y0, method="DOP853", rtol=1e-11, atol=1e-11, t_eval=tw,
                    args=(p,), events=events)
    if sol.status == 1:
        return "escaped"
    assert sol.status == 0, sol.message
    ys = sol.y  # (n_state, K)
    o = np.stack([obs_fn(ys[:, j], p) for j in range(len(tw))])  # (K, n_obs)
    return {"max": o.max(0), "min": o.min(0), "mean": o.mean(0), "std": o.std(0), "final": o[-1]}


def scipy_features_stacked(rhs, obs_fn, y0s, p, ts, t_from):
    """``scipy_features`` of many starts (same parameters, no escape radius) in one DOP853 integration of the
    stacked system: one Python call per step for all starts instead of one per start.

    SciPy's DOP853 accepts a step when the RMS over the components of its scaled error estimate is <= 1. Over M
    stacked starts, with rtol and atol both divided by sqrt(M), that RMS adds the starts' squared errors instead of
    averaging them, so the steps follow the hardest start. (DOP853 blends a 5th- and a 3rd-order
    estimate, so this is not an exact per-start bound; what the comparison needs is a reference far tighter than
    the engines' tolerances, and it stays at 1e-11 / sqrt(M) or finer.)"""
    y0s = np.asarray(y0s, dtype=float)  # (M, n_state)
    m, d = y0s.shape
    shrink = 1.0 / np.sqrt(m)

    def f(t, y):
        dy = rhs(t, y.reshape(d, m), p)
        return np.concatenate([np.broadcast_to(c, (m,)) for c in dy])

    tw = ts[ts >= t_from]
    sol = solve_ivp(f, (ts[0], ts[-1]), y0s.T.ravel(), method="DOP853", rtol=1e-11 * shrink, atol=1e-11 * shrink,
                    t_eval=tw)
    assert sol.status == 0, sol.message
    ys = sol.y.reshape(d, m, len(tw))
    out = []
    for i in range(m):
        o = np.stack([obs_fn(ys[:, i, j], p) for j in range(len(tw))])  # (K, n_obs)
        out.append({"max": o.max(0), "min": o.min(0), "mean": o.mean(0), "std": o.std(0), "final": o[-1]})
    return out


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

    feats = {}  # SciPy's features by start (initial state)

    def feats_of(start):
        y0 = tuple(float(start[k]) for k in ic_keys)
        if y0 not in feats:
            feats[y0] = scipy_features(rhs, obs_fn, list(y0), start, ts, t_from, escape)
        return feats[y0]

    def nudge(start):
        return {**start, ic_keys[0]: start[ic_keys[0]] * (1 + 1e-7) + 1e-7}

    starts = []
    for i in range(n):
        start = dict(fixed)
        for k in plan.sample:
            start[k] = float(ds[f"{k}_sample"].values[i])
        starts.append(start)
    if escape is None:  # one stacked integration of every start SciPy will need (an escape stops one start only)
        assert set(plan.sample) <= set(ic_keys)  # the starts differ in their initial state only
        need = starts + [nudge(s) for s in starts]
        need += [{**starts[0], **{k: float(v) for k, v in over.items()}} for over in plan.scheme.decl.templates.values()]
        assert all(set(over) <= set(ic_keys) for over in plan.scheme.decl.templates.values())
        y0s = list(dict.fromkeys(tuple(float(s[k]) for k in ic_keys) for s in need))
        feats.update(zip(y0s, scipy_features_stacked(rhs, obs_fn, y0s, fixed, ts, t_from)))

    robust = agree = 0
    cache = {}
    for i, start in enumerate(starts):
        got = names[int(ds["outcome"].values[i])]
        assert got != FAILED_NAME
        ref = scipy_label(plan, feats_of, start, cache)
        nudged = scipy_label(plan, feats_of, nudge(start), cache)
        if ref != nudged:
            continue
        robust += 1
        assert got == ref, f"start {i} {start}: stabjax {got}, SciPy {ref}"
        agree += 1
    assert robust >= 0.75 * n, f"only {robust} of {n} starts have a label robust to a 1e-7 nudge"
    # the standard errors in the dataset are the binomial ones
    s = ds["basin_fraction"].values
    np.testing.assert_allclose(ds["basin_se"].values, np.sqrt(s * (1 - s) / n), rtol=1e-12)
