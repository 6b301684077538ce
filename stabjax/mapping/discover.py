"""Attractors found from the trajectories themselves: featurise, scale, group, type and name (the
whole-set outcome mapper :class:`Discovery`, :mod:`stabjax.mapping.mapper`).

A model that declares no outcomes rules (or a spec with ``[outcomes] discover = true``) gets its
outcomes here, after every trajectory of the sweep has run (the grouping pools all grid points,
so an attractor keeps one name across the grid, as Attractors.jl's ``FeaturizeGroupAcrossParameter``).

1. **Features** (what the fold already computes, no extra cost): per observable, the mean, standard
   deviation, minimum and maximum over the late window ``[t0 + (1 - window)(t1 - t0), t1]``.
   **Runaways** first (:func:`unbounded`): a trajectory whose window grows (its final values at least
   ``GROWTH`` times the window's RMS, its exponent not negative) and ends far outside the box the other
   windows stayed in has reached no attractor; it takes the escape outcome, as if an escape radius had
   stopped it, and is left out of everything below (its 1e43 would otherwise set the scale).
2. **Scaling**: every feature of observable k is divided by the range that observable covers over
   the whole sweep (max of its window maxima minus min of its window minima). Per *observable*, not
   per feature: a z-score per feature (pyBasin) would blow the solver noise in the window std of
   fixed points (1e-12) up to unit size; per observable no observable dominates by its units and
   the noise stays noise. A range is never taken below :func:`floor_factor` solver tolerances
   (atol + rtol max|value|, :func:`observable_ranges`): an observable every trajectory brings to the
   same value carries only noise, and two trajectories each within the fixed-point stop's distance
   (1000 tolerances, :mod:`stabjax.fold.stops`) of one equilibrium must lie within ``eps`` of each other.
3. **Grouping**: scikit-learn's DBSCAN (Ester et al. 1996) with radius ``eps`` (fraction of each
   observable's range) and ``min_samples``, on a random subsample of ``subsample`` trajectories;
   every trajectory then takes the label of its nearest core sample if that lies within ``eps``
   (DBSCAN's own border rule, so the result is the one DBSCAN would give on the subsample plus
   border points). Trajectories farther than ``eps`` from every core sample are grouped again among
   themselves (a small basin missed by the subsample is found there), until none is left or no
   group forms; a trajectory left over within ``eps`` of a grouped one joins its group (the
   subsample is sparser than the whole set, whose DBSCAN would have made it a border point); the
   rest is ``unclassified`` (e.g. trajectories still in a transient); a trajectory with a NaN or
   infinite feature is ``failed``, as a solver failure is, never grouped nor unclassified. Linear in N
   after the subsample: 10^5 trajectories take about a second (``docs/performance.md``).
   Trajectories **at rest** -- stopped at a stable equilibrium by the fixed-point stop, or with every
   observable's window std within :func:`rest_threshold` (the stop's 1000 solver tolerances, or
   ``fixed_point_tol`` of the range) -- are grouped by where they rest (their last observables), the
   others by their window features: a fixed point is a point, whatever transient its window still
   holds. Fixed points found twice (by both groupings, or split by a transient) whose positions lie
   within ``eps`` are one; a trajectory left ungrouped that ends within the rest threshold of a fixed
   point in every observable is at it, and one that approaches a stable equilibrium (at rest, its
   exponent below ``-chaos_threshold`` in an autonomous model, or, without the exponent, ending its
   window at an extreme of every observable) joins the fixed point it ends at within ``eps``. Without
   the exponent, groups still in such a monotone approach join the fixed point they end at, or, where
   none rests, each other when they end within ``eps`` of one another: one equilibrium, one name. A
   trajectory left ungrouped with a positive exponent joins the nearest chaotic group when it lies within
   ``eps`` of that group's extent in window features (DBSCAN leaves a chaotic cloud's sparse edge out).
   Why DBSCAN and not HDBSCAN (pyBasin's default) or recurrences (Attractors.jl): a chaotic
   attractor's features scatter between finite windows but form one connected cloud, which
   density-connectivity keeps whole at any radius above the sampling gaps, while two attractors
   whose feature clouds are more than ``eps`` apart are never joined; HDBSCAN's cluster selection
   may split a cloud of uneven density and turns basins smaller than its ``min_cluster_size``
   into noise; the recurrence finite-state machine needs a state-space grid and runs trajectories
   one after the other (a vmapped batch engine runs them all at once).
4. **Types** per group (pyBasin's ``DynamicalSystemClusterer`` idea, thresholds stated):
   ``fixed_point`` when most members are at rest (``attractor`` where the exponent says the state may still move
   where the observables do not look, :func:`_hidden_motion`) (above: the thresholds follow from the solver's
   tolerances, so the stop and the typing agree); else ``chaotic`` when the median largest Lyapunov
   exponent (:mod:`stabjax.model.tangent`) is above ``chaos_threshold`` and the window lasted long enough for a
   runaway at that rate to have been seen (exponent x window length >= ``CHAOS_SPAN``; else untyped and said,
   :func:`_short_for_chaos`); else ``fixed_point`` again
   when that exponent is below ``-chaos_threshold`` and the model is autonomous (a bounded motion of an
   autonomous flow other than an equilibrium has a zero exponent) or most members end their window at
   an extreme of every observable (a monotone approach, no oscillation): a group still approaching a
   stable equilibrium is never called a cycle (one so typed while its members still oscillate over the
   window, and contracted less than ``CYCLE_BIAS`` by its start, is said, a :class:`TransientWarning`: a
   relaxation cycle watched for a short window has such a finite-time exponent too, Van der Pol at mu = 1 over
   two periods -0.06); else ``attractor`` (untyped) when its negative exponent
   has not contracted a separation of the observables' range below ``eps`` by the window's start
   (exp(lambda * (window start - t0)) > eps: the window holds a forced transient, no cycle yet) or most members
   end their window at an extreme of every observable (a monotone approach or drift is no cycle); else
   ``fixed_point`` in an autonomous model where the representative's oscillation dies out at the exponent's rate
   (:func:`_decaying`: a weak focus, its exponent within ``chaos_threshold`` of a cycle's 0); else
   ``attractor`` in an autonomous model where its members trace closed orbits farther than ``eps`` apart
   (:func:`_continuum`: a centre's family of neutral orbits, said); else ``limit_cycle`` (a periodic or
   quasi-periodic motion: its exponent is 0 for autonomous flows, negative for forced ones). The finite-time
   exponent of a cycle is off zero by up to ln(max|f| / min|f| along it) / (window length): keep the
   window long where a cycle is strongly relaxational. Without the exponent (``lyapunov = false``) a
   group not at rest is ``attractor``; where it, or an unclassified trajectory, ends its window in a
   monotone approach, a :class:`TransientWarning` says that t1 did not outlast the transient -- unless the
   approach heads for a hyperbolic stable equilibrium, which it then is (:func:`_places`, with or without
   the exponent).
   Names: the type and a number, ``fixed_point_1``, ``limit_cycle_1``, ``chaotic_1``, ... numbered
   by decreasing basin size within each type. A fixed point that rests at, or lingers by, an unstable
   equilibrium (a start on a saddle's stable manifold, a heteroclinic cycle watched too briefly) is no
   attractor: its trajectories are unclassified, and said (:func:`_unstable`).
5. **Along a parameter** (one ``[grid]`` axis with ``[sample]``): each grid point's attractors are
   found on their own and matched to those of the previous point of the same type by the distance
   between their representatives (:mod:`stabjax.mapping.continuation`, Attractors.jl's global
   continuation; ``match_threshold``, default from the data), so ``basin_fraction`` along the axis
   follows one attractor, two groups of different type never share a name, and births and deaths
   are reported (``attractor_events``). ``continuation = false`` groups all points together instead.
6. **Representative** of each group: the member whose features lie nearest the group's median;
   its parameters (start), its state at t1 (re-integrated on its own) and the group's median
   features are stored in the dataset.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..errors import ValidationError
from ..fold.stops import DISTANCE_TOL, STOP_FIXED_POINT, is_autonomous
# DiscoveryConfig: [outcomes.discovery], the declaration's
from ..model.outcomes import FAILED_NAME, UNCLASSIFIED, DiscoveryConfig, finite_features
from .mapper import Mapped, Mapper, OutcomeScheme, outcome_names

STATS = ("mean", "std", "min", "max")
TYPES = ("fixed_point", "limit_cycle", "chaotic", "attractor")


@dataclass
class Attractors:
    """The attractors found: ``labels`` (N,) index into ``names`` or -1 (unclassified / not valid)."""

    labels: np.ndarray
    names: list[str]
    types: list[str]
    counts: np.ndarray
    features: np.ndarray  # (A, n_obs * 4): median feature vector of each group, physical units
    feature_names: list[str]
    lyapunov: np.ndarray  # (A,) median exponent (NaN without it)
    representative: np.ndarray  # (A,) trajectory index
    scale: np.ndarray  # (n_obs,) the observables' ranges used for scaling
    stats: dict[str, Any] = field(default_factory=dict)
    unbounded: np.ndarray | None = None  # (N,) ran away (:func:`unbounded`): no attractor, label -1


def feature_table(results: Mapping[str, np.ndarray], observables: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """(N, 4 n_obs) late-window features and their names (``mean(x)``, ...)."""
    cols, names = [], []
    for k, o in enumerate(observables):
        for s in STATS:
            cols.append(np.asarray(results[f"feat_{s}"], float)[:, k])
            names.append(f"{s}({o})")
    return np.stack(cols, axis=1), names


NOISE_FACTOR = 1e4  # differences below this many solver tolerances are numerical, not dynamical
STOP_DISTANCE = DISTANCE_TOL  # the fixed-point stop's (and the solver's plateau's) bound, in tolerance units


def tolerances(results, valid: np.ndarray, n_obs: int, atol: float = 0.0, rtol: float = 0.0) -> np.ndarray:
    """The solver's tolerance on each observable, atol + rtol max|value| over the valid windows (the
    step-size controller's norm, applied to the observables)."""
    lo = np.asarray(results["feat_min"], float)[valid, :n_obs]
    hi = np.asarray(results["feat_max"], float)[valid, :n_obs]
    if lo.shape[0] == 0:
        return np.full(n_obs, float(atol))
    big = np.maximum(np.nanmax(np.abs(hi), axis=0), np.nanmax(np.abs(lo), axis=0))
    return atol + rtol * np.where(np.isfinite(big), big, 0.0)


def floor_factor(n_obs: int, eps: float | None = None) -> float:
    """The smallest range, in solver tolerances, an observable's features are scaled by: at least
    ``NOISE_FACTOR``, and so large that two trajectories each within the fixed-point stop's distance
    (``STOP_DISTANCE`` tolerance units) of one equilibrium -- each of their 4 features of each observable
    then differs by at most twice that -- lie within ``eps`` of each other after scaling: the stop and the
    grouping agree (a start the stop froze near the equilibrium joins the others at it)."""
    if not eps:
        return NOISE_FACTOR
    return max(NOISE_FACTOR, 2.0 * STOP_DISTANCE * math.sqrt(len(STATS) * n_obs) / eps)


def observable_ranges(results, valid: np.ndarray, n_obs: int, atol: float = 0.0, rtol: float = 0.0,
                      eps: float | None = None) -> np.ndarray:
    """Range of each observable over the valid trajectories' windows, at least :func:`floor_factor`
    tolerances (:func:`tolerances`): an observable that every trajectory brings to the same value (a
    velocity at rest) must not blow its solver noise up to the size of a real difference. Measured:
    Tsit5 at rtol = atol = 1e-8 stays 4e-5 (4000 tolerances) from a weakly stable focus (Lorenz
    r = 24.4), the controller holding the step where the oscillation is barely damped."""
    lo = np.asarray(results["feat_min"], float)[valid, :n_obs]
    hi = np.asarray(results["feat_max"], float)[valid, :n_obs]
    if lo.shape[0] == 0:
        return np.ones(n_obs)
    r = np.nanmax(hi, axis=0) - np.nanmin(lo, axis=0)
    floor = floor_factor(n_obs, eps) * tolerances(results, valid, n_obs, atol, rtol)
    r = np.where(np.isfinite(r), np.maximum(r, floor), 0.0)
    return np.where(r > 0, r, 1.0)


def _dbscan(x: np.ndarray, cfg: DiscoveryConfig, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DBSCAN on a subsample of ``x``: (core points, their labels, labels of the subsample indices)."""
    from sklearn.cluster import DBSCAN

    n = len(x)
    take = np.sort(rng.choice(n, size=cfg.subsample, replace=False)) if n > cfg.subsample else np.arange(n)
    db = DBSCAN(eps=cfg.eps, min_samples=min(cfg.min_samples, len(take))).fit(x[take])
    core = db.core_sample_indices_
    return x[take][core], db.labels_[core], take


def group(x: np.ndarray, cfg: DiscoveryConfig) -> tuple[np.ndarray, dict[str, Any]]:
    """Labels (N,) of scaled feature vectors ``x`` (finite), -1 for ungrouped; see the module docstring."""
    from sklearn.neighbors import NearestNeighbors

    n = len(x)
    labels = np.full(n, -1, np.int64)
    rng = np.random.default_rng(cfg.seed)
    todo = np.arange(n)
    next_label, rounds = 0, 0
    while todo.size >= cfg.min_samples:
        rounds += 1
        core_x, core_lab, _ = _dbscan(x[todo], cfg, rng)
        if core_x.shape[0] == 0:
            break
        nn = NearestNeighbors(n_neighbors=1).fit(core_x)
        d, j = nn.kneighbors(x[todo])
        near = d[:, 0] <= cfg.eps
        labels[todo[near]] = core_lab[j[near, 0]] + next_label
        next_label += int(core_lab.max()) + 1
        if near.all():
            break
        todo = todo[~near]
    # the subsample is sparser than the whole set: a trajectory within eps of a grouped one (not of
    # a core sample) would have been a border point of full-set DBSCAN; it joins that group
    left = np.flatnonzero(labels < 0)
    done = np.flatnonzero(labels >= 0)
    if left.size and done.size:
        d, j = NearestNeighbors(n_neighbors=1).fit(x[done]).kneighbors(x[left])
        near = d[:, 0] <= cfg.eps
        labels[left[near]] = labels[done[j[near, 0]]]
    return labels, {"rounds": rounds}


@dataclass
class _Features:
    """What grouping and typing read of every trajectory (see :func:`features`)."""

    feats: np.ndarray  # (N, 4 n_obs) physical units
    names: list[str]
    x: np.ndarray  # scaled window features
    xf: np.ndarray  # (N, n_obs) scaled observables at the last checkpoint
    scale: np.ndarray  # (n_obs,)
    tol: np.ndarray  # (n_obs,) the solver's tolerance on each observable
    valid: np.ndarray  # reached t1 with finite features
    final: np.ndarray  # (N, n_obs) the last checkpoint's observables
    lam: np.ndarray | None  # (N,) largest Lyapunov exponent, None when not integrated
    at_rest: np.ndarray  # (N,) stopped by the fixed-point stop, or every window std at the rest threshold
    autonomous: bool
    unbounded: np.ndarray  # (N,) runs away over its window (:func:`unbounded`); never in ``valid``
    settle: float | None = None  # time from t0 to the window's start (None: not known)
    span: float | None = None  # the window's length in time (None: not known)
    # trajectory index -> (times, observables (M, n_obs)) densely over the window, integrated again on its own
    # (None: not available); asked only of a representative whose type the features leave open (_decaying)
    trace: Any = None
    # trajectory index -> whether it spirals about a stable equilibrium inside its window (None: not asked;
    # :meth:`Again.focus`), asked only of a weak focus's representative (:func:`_describe`)
    focus: Any = None
    envelope: dict = field(default_factory=dict)  # representative -> its envelope's decay (cache of _decaying)
    chaos: float = 0.01  # DiscoveryConfig.chaos_threshold
    stopped: np.ndarray | None = None  # (N,) frozen at an equilibrium by the fixed-point stop (Newton: f = 0)
    eps: float = 0.05  # DiscoveryConfig.eps
    orbits: dict = field(default_factory=dict)  # (member, member) -> their orbits' distance (cache of _continuum)
    continua: set = field(default_factory=set)  # representatives of the groups _continuum untyped
    no_focus: set = field(default_factory=set)  # representatives of dying oscillations about no stable equilibrium


def features(results: Mapping[str, np.ndarray], observables: tuple[str, ...], cfg: DiscoveryConfig,
             valid: np.ndarray, atol: float = 0.0, rtol: float = 0.0, autonomous: bool = False,
             settle: float | None = None, span: float | None = None, trace=None, focus=None) -> _Features:
    n_obs = len(observables)
    feats, fnames = feature_table(results, observables)
    final = np.asarray(results["feat_final"], float)[:, :n_obs]
    valid = np.asarray(valid, bool) & np.all(np.isfinite(feats), axis=1) & np.all(np.isfinite(final), axis=1)
    lam = np.asarray(results["lyapunov"], float) if "lyapunov" in results else None
    away = unbounded(feats, final, valid, lam, cfg)
    # taken out before the ranges are measured: one runaway's 1e43 would make every bounded attractor a
    # point of the scaled space, and all of them one group
    valid = valid & ~away
    scale = observable_ranges(results, valid, n_obs, atol, rtol, cfg.eps)
    tol = tolerances(results, valid, n_obs, atol, rtol)
    std = feats[:, [k * len(STATS) + 1 for k in range(n_obs)]]
    at_rest = np.all(std <= rest_threshold(scale, tol, cfg), axis=1)
    stopped = np.asarray(results["stop_reason"]) == STOP_FIXED_POINT if "stop_reason" in results else None
    if stopped is not None:
        at_rest |= stopped
    return _Features(feats, fnames, feats / np.repeat(scale, len(STATS))[None, :], final / scale, scale, tol, valid,
                     final, lam, at_rest, bool(autonomous), away, settle, span, trace,
                     focus=focus, chaos=cfg.chaos_threshold, stopped=stopped, eps=cfg.eps)


GROWTH = 2.0  # |final| / window RMS (per observable, RMS over the observables) at which a window is growing


def unbounded(feats: np.ndarray, final: np.ndarray, valid: np.ndarray, lam: np.ndarray | None,
              cfg: DiscoveryConfig) -> np.ndarray:
    """Per trajectory: its observables run away over the feature window, so it has reached no attractor
    and must not be grouped, typed or named as one (x' = x reached 1e43 and was called chaotic: its
    exponent is 1). Attractors.jl's recurrence mapper labels such a start -1, "diverged to infinity", when
    it stays ``consecutive_lost_steps`` outside the grid or its norm passes ``horizon_limit``; here there
    is no grid and no absolute limit to borrow, so the test reads the window itself and the other
    trajectories' windows. All three must hold:

    1. **The window grows**: the RMS over the observables of |final| / (the window's RMS), each
       observable against its own window RMS sqrt(mean^2 + std^2), is at least ``GROWTH``. A magnitude
       growing as e^(r t) over a window of length T gives sqrt(2 r T / (1 - e^(-2 r T))), for a monotone
       observable and for an oscillation whose amplitude grows alike (then per observable the phase at t1
       matters, over the observables it cancels for a focus); ``GROWTH`` = 2 is a growth by e^2 ~ 7 over
       the window. A bounded stationary motion gets there only at a peak of crest factor (max / RMS)
       above 2: never a sinusoid (sqrt 2), now and then a spiky one -- hence 2. and 3. A drift (a running
       pendulum's unwrapped angle, linear in t) stays near 1.3 and is not called unbounded.
    2. **It is not contracting**: its exponent is not below ``-chaos_threshold`` (unknown passes). A
       forced cycle whose response peaks at t1 in every start (all in phase with the forcing) has a
       negative exponent; a runaway's tangent grows with it, or at least does not shrink.
    3. **It ends far outside the box the other trajectories' windows stayed in**: some observable's
       |final| exceeds ``GROWTH`` times the largest |value| reached by the windows that do not grow (1.,
       2.; no such window: no box). A spiky bounded attractor's trajectory that ends at a peak ends
       inside the range its fellows' windows covered (measured: Van der Pol at mu = 5 ends 7 % of its
       starts with the ratio of 1. above 2, Lorenz-63 one in 300), the factor covering a peak their
       checkpoints sampled below its top; a runaway leaves it (Attractors.jl's "lost outside the grid").
    """
    mean, std, lo, hi = (feats[:, s::len(STATS)] for s in range(len(STATS)))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.where(final == 0, 0.0, np.abs(final) / np.hypot(mean, std))
        grows = valid & (np.sqrt(np.mean(ratio * ratio, axis=1)) >= GROWTH)
        if lam is not None:
            grows &= ~(lam < -cfg.chaos_threshold)
    rest = valid & ~grows
    box = np.max(np.maximum(np.abs(lo), np.abs(hi))[rest], axis=0) if rest.any() else np.zeros(final.shape[1])
    return grows & np.any(np.abs(final) > GROWTH * box, axis=1)


def rest_threshold(scale: np.ndarray, tol: np.ndarray, cfg: DiscoveryConfig) -> np.ndarray:
    """The window std (per observable) at or below which a trajectory is at rest: the fixed-point stop's
    distance from an equilibrium (``STOP_DISTANCE`` solver tolerances, where the solver's own solution
    hovers near a stable equilibrium), or ``fixed_point_tol`` of the observable's range."""
    return np.maximum(cfg.fixed_point_tol * scale, STOP_DISTANCE * tol)


def discover(results: Mapping[str, np.ndarray], observables: tuple[str, ...], cfg: DiscoveryConfig,
             valid: np.ndarray, atol: float = 0.0, rtol: float = 0.0, autonomous: bool = False,
             settle: float | None = None, span: float | None = None, trace=None, focus=None) -> Attractors:
    """Group the ``valid`` trajectories (reached t1, finite features) of ``results`` into attractors;
    ``atol``, ``rtol``: the solver's tolerances (the noise floor of the feature scales and the fixed
    points' threshold); ``autonomous``: the model does not read t (see the typing in the module docstring);
    ``settle``: the time from t0 to the window's start (a contraction that has not settled is no cycle); ``span``:
    the window's length (a growth too short to tell chaos from a runaway is not called chaotic); ``trace``: a
    trajectory's observables over the window, integrated again (:func:`_decaying`)."""
    f = features(results, observables, cfg, valid, atol, rtol, autonomous, settle, span, trace, focus)
    found, stats = _found(f, cfg, np.flatnonzero(f.valid))
    return _named(found, f, stats)


def _found(f: _Features, cfg: DiscoveryConfig, idx: np.ndarray) -> tuple[list[tuple], dict[str, Any]]:
    """The attractors among trajectories ``idx``: (members, type, median features, median exponent,
    representative) each. Trajectories at rest are grouped by where they rest (their last observables:
    a fixed point is a point, whatever transient its window still holds), the others by their window
    features; fixed points found twice are one, and a trajectory left ungrouped that approaches a stable
    equilibrium (:func:`_approaching`) joins the fixed point it ends at."""
    rest, moving = idx[f.at_rest[idx]], idx[~f.at_rest[idx]]
    groups, stats = [], {"rounds": 0}
    fine = REST_GAP * float(np.linalg.norm(rest_threshold(f.scale, f.tol, cfg) / f.scale))
    for members, x in ((rest, f.xf), (moving, f.x)):
        if members.size:
            lab, st = group(x[members], cfg)
            stats["rounds"] += st["rounds"]
            found_here = [members[lab == g] for g in range(int(lab.max()) + 1 if lab.size else 0)]
            if x is f.xf:  # points at rest: where they rest is known to the rest threshold, not to eps
                found_here = [h for g in found_here for h in _split_rest(g, f.xf, fine, cfg.min_samples)]
            groups += found_here
    found = [(g, *_describe(g, f, cfg)) for g in groups if g.size]
    # a fixed point's members still spiralling in, cut where they end farther apart than they still move: heading
    # to different equilibria, however close on the observables' scale (:func:`_split_by_end`; a group at rest was
    # split by where it rests, above)
    found = [q for r in found for q in ([r] if r[1] != "fixed_point" or np.mean(f.at_rest[r[0]]) > 0.5 else
                                        [(h, *_describe(h, f, cfg, kind="fixed_point"))
                                         for h in _split_by_end(r[0], f, cfg.min_samples)])]
    points = [r for r in found if r[1] == "fixed_point"]
    others = [r for r in found if r[1] != "fixed_point"]
    xm = f.x[:, ::len(STATS)]  # the scaled window means
    # one fixed point found by both groupings, or split by its transient: one attractor, placed by where its
    # members end or by their window means (a decaying oscillation, x'' + 0.04 x' + x = 0 at t1 = 150, still
    # ends up to 0.1 of its range from the focus, while its window mean is within 0.01); never two groups that
    # rest or spiral in apart (:func:`_apart`)
    merged, placed = _merge_near([g for g, *_ in points], (f.xf, xm), cfg.eps,
                                 apart=lambda g, h: bool(_apart(_ends(g, f), _ends(h, f), fine)))
    centres, means = [c for c, _ in placed], [m for _, m in placed]
    ends: list[np.ndarray] = []  # where each group still in a monotone approach ends (scaled observables)
    approach: list[np.ndarray] = []
    if f.lam is None:
        # without the exponent a group still in a monotone approach is untyped (``attractor``); one that ends
        # where a fixed point rests is that fixed point's transient, and such groups ending at one place are
        # one approach (at t1 = 20 the trajectories of x' = 1 - x from farther away made two groups beside
        # fixed_point_1, three names for one equilibrium; at t1 = 8, four 'attractors')
        kept = []
        for r in others:
            g = r[0]
            if r[1] != "attractor" or np.mean(_ends_at_extreme(g, f)) <= 0.5:
                kept.append(r)
                continue
            d = [np.linalg.norm(np.median(f.xf[g], axis=0) - c) for c in centres]
            if d and min(d) <= cfg.eps:
                j = int(np.argmin(d))
                merged[j] = np.concatenate([merged[j], g])
            else:
                approach.append(g)
        others = kept
        approach, placed = _merge_near(approach, (f.xf,), cfg.eps)
        ends = [c for c, in placed]
    left = np.setdiff1d(idx, np.concatenate([g for g, *_ in found]) if found else idx[:0])
    if left.size and centres:
        # ending within the rest threshold of a fixed point in every observable is being there, whatever the
        # window still held (a y decaying from 6e-7 to 1e-11 over the window has a std just above the 1000
        # tolerances of atol 1e-10: unclassified before, though it ends 1e-11 from the equilibrium)
        near = np.abs(f.xf[left][:, None, :] - np.asarray(centres)[None]) <= (rest_threshold(f.scale, f.tol, cfg)
                                                                               / f.scale)[None, None, :]
        there = np.all(near, axis=2)
        for i in np.flatnonzero(there.any(axis=1)):
            j = int(np.argmax(there[i]))
            merged[j] = np.append(merged[j], left[i])
        left = left[~there.any(axis=1)]
    others = _merge_chaotic(others, f, cfg)
    left, others = _join_chaotic(left, others, f, cfg)
    left = left[_approaching(left, f, cfg)]
    for targets, tmeans, into in ((centres, means, merged), (ends, None, approach)):  # a fixed point first
        if left.size and targets:
            d = np.linalg.norm(f.xf[left][:, None, :] - np.asarray(targets)[None], axis=-1)
            if tmeans is not None:  # a fixed point: by its window mean too, never one it ends apart from (_apart)
                d = np.minimum(d, np.linalg.norm(xm[left][:, None, :] - np.asarray(tmeans)[None], axis=-1))
                mine = tuple(np.asarray(v)[:, None] for v in _ends(left, f, pooled=False))
                theirs = tuple(np.stack([np.asarray(v) for v in col])[None] for col in zip(*(_ends(g, f) for g in into)))
                d = np.where(_apart(mine, theirs, fine), np.inf, d)
            j = np.argmin(d, axis=1)
            joins = np.flatnonzero(d[np.arange(left.size), j] <= cfg.eps)
            for i in joins:
                into[j[i]] = np.append(into[j[i]], left[i])
            left = np.delete(left, joins)
    # approaching trajectories that joined nothing (their transients' window features too far apart for
    # DBSCAN: x' = -x from 20 starts at t1 = 10), gathered about where they end or their window means
    mine = _ends(left, f, pooled=False)  # kept row for row with left as it shrinks
    while left.size >= cfg.min_samples:
        d = np.minimum(np.linalg.norm(f.xf[left] - f.xf[left[0]], axis=1), np.linalg.norm(xm[left] - xm[left[0]], axis=1))
        near = (d <= cfg.eps) & ~_apart(tuple(v[:1] for v in mine), mine, fine)
        if near.sum() >= cfg.min_samples:
            g = np.sort(left[near])
            kind = _describe(g, f, cfg)[0]
            (merged if kind == "fixed_point" else approach).append(g)
            left, mine = left[~near], tuple(v[~near] for v in mine)
        else:
            left, mine = left[1:], tuple(v[1:] for v in mine)
    # an approach that some members finish, at rest there (too few to be a group of their own), is to a point
    merged += [g for g in approach if f.at_rest[g].any()]
    others += [(np.sort(g), *_describe(np.sort(g), f, cfg)) for g in approach if not f.at_rest[g].any()]
    # every member rests at the point or approaches it (at rest, a negative exponent, a monotone approach)
    points = [(np.sort(g), *_describe(np.sort(g), f, cfg, kind="fixed_point")) for g in merged]
    return points + others, stats


def _join_chaotic(left: np.ndarray, others: list[tuple], f: _Features, cfg: DiscoveryConfig
                  ) -> tuple[np.ndarray, list[tuple]]:
    """Ungrouped trajectories on a chaotic attractor join it. A chaotic attractor's window features scatter
    (finite windows of an ergodic motion), and DBSCAN leaves the sparse edge of the cloud out as noise: Lorenz-63
    at rho = 28, 300 starts, 8 % unclassified, every one with the exponent of ``chaotic_1`` (0.88-0.94). A
    trajectory whose exponent is above ``chaos_threshold`` joins the chaotic group nearest in window features
    when it lies within ``eps`` (DBSCAN's own radius) of that group's extent (the largest distance of a member
    from the group's median), or when its window stays inside the box the group's windows cover (within ``eps``)
    with an exponent within the range of the group's; anything else stays where it was. Two chaotic attractors closer than that would
    have been one group to DBSCAN already."""
    chaotic = [i for i, r in enumerate(others) if r[1] == "chaotic"]
    if not left.size or not chaotic or f.lam is None:
        return left, others
    with np.errstate(invalid="ignore"):
        cand = left[f.lam[left] > cfg.chaos_threshold]
    if not cand.size:
        return left, others
    meds, reach = (np.array(v) for v in zip(*(_extent(others[i][0], f) for i in chaotic)))
    d = np.linalg.norm(f.x[cand][:, None, :] - meds[None], axis=-1)
    j = np.argmin(d, axis=1)
    joins = d[np.arange(cand.size), j] <= reach[j] + cfg.eps
    # or its window stays inside the box the group's windows cover (within eps), with an exponent among theirs:
    # the heavy tail of a window maximum put two Roessler trajectories (c = 5.7, z up to 18 and 19 against the
    # group's 22) beyond the extent, unclassified with the attractor's exponent
    k = len(STATS)
    for c in np.flatnonzero(~joins):
        g = others[chaotic[j[c]]][0]
        lo, hi = f.x[g][:, 2::k].min(axis=0) - cfg.eps, f.x[g][:, 3::k].max(axis=0) + cfg.eps
        lams = f.lam[g][np.isfinite(f.lam[g])]
        joins[c] = bool(lams.size and np.all(f.x[cand[c], 2::k] >= lo) and np.all(f.x[cand[c], 3::k] <= hi)
                        and lams.min() <= f.lam[cand[c]] <= lams.max())
    if not joins.any():
        return left, others
    others = list(others)
    for k in np.unique(j[joins]):
        g = np.sort(np.concatenate([others[chaotic[k]][0], cand[joins & (j == k)]]))
        others[chaotic[k]] = (g, *_describe(g, f, cfg, kind="chaotic"))
    return np.setdiff1d(left, cand[joins]), others


def _extent(g: np.ndarray, f: _Features) -> tuple[np.ndarray, float]:
    """(median, extent) of a group in scaled window features: the extent is the largest distance of a member from
    the median."""
    med = np.median(f.x[g], axis=0)
    return med, float(np.linalg.norm(f.x[g] - med, axis=1).max())


def _merge_chaotic(others: list[tuple], f: _Features, cfg: DiscoveryConfig) -> list[tuple]:
    """Chaotic groups whose feature clouds overlap are one attractor: a group merges with another when its median
    lies within the other's extent (the largest distance of a member from its median), as a single trajectory with a
    positive exponent joins it (:func:`_join_chaotic`). DBSCAN cut one cloud
    where its sampling left a gap: Lorenz-63 at r = 24.4 with 300 starts and 1000 checkpoints over t1 = 2000 gave
    chaotic_1..3, every one with exponent 0.79 and the same ranges. Two attractors' clouds do not hold each other's
    medians (the groups' own extents, not eps: DBSCAN already keeps clouds more than eps apart)."""
    idx = [i for i, r in enumerate(others) if r[1] == "chaotic"]
    if len(idx) < 2:
        return others
    groups = [others[i][0] for i in idx]
    i = 0
    while i < len(groups):  # each group absorbs every later one that overlaps it, then the next is taken
        (ma, ra), j = _extent(groups[i], f), i + 1
        while j < len(groups):
            mb, rb = _extent(groups[j], f)
            if np.linalg.norm(ma - mb) <= max(ra, rb):
                groups[i] = np.sort(np.concatenate([groups[i], groups.pop(j)]))
                (ma, ra), j = _extent(groups[i], f), i + 1
            else:
                j += 1
        i += 1
    out = [r for k, r in enumerate(others) if k not in idx]
    return out + [(g, *_describe(g, f, cfg, kind="chaotic")) for g in groups]


REST_GAP = 10.0  # rest thresholds between two equilibria's resting points that make them two


def _split_rest(g: np.ndarray, xf: np.ndarray, fine: float, min_samples: int) -> list[np.ndarray]:
    """A group of trajectories at rest, split where their resting points (scaled) fall apart by more than ``fine``
    (``REST_GAP`` rest thresholds) into parts of at least ``min_samples``: two equilibria closer than eps are still
    two (x' = -x (x - 0.1)(x - 0.2)(x - 5)(x - 10) / 10 rests at 0, 0.2 and 10: the first two, 0.018 of the range
    apart, were one fixed point). A smaller part rests at an equilibrium of its own too: left out (unclassified, as
    DBSCAN leaves out what is too sparse), never given a neighbour's name (theta observed unwrapped: one start resting
    2 pi from fixed_point_4 was counted in it). ``[g]`` when nothing splits."""
    from scipy.cluster.hierarchy import fcluster, linkage

    if g.size < 2 or fine <= 0:
        return [g]
    lab = fcluster(linkage(xf[g], method="single"), t=fine, criterion="distance")
    if lab.max() == 1:
        return [g]
    parts = [g[lab == k] for k in np.unique(lab)]
    return [p for p in parts if p.size >= min_samples]


def _split_by_end(g: np.ndarray, f: _Features, min_samples: int) -> list[np.ndarray]:
    """A fixed point's group cut where its members' last observables fall apart, in some observable, by more than
    ``REST_GAP`` times what the two neighbours there (in that observable's last value) still move over their windows
    (:func:`_motion`); never between two members in a monotone approach (its equilibrium lies beyond its window, by
    as far as its approach is slow). Members spiralling into one equilibrium end within their window ranges of it;
    ends far apart for how little they still move are different equilibria, however close on the observables' scale
    (theta'' = -0.1 theta' + 0.5 - sin theta with theta unwrapped: its running motion's drift makes theta's range
    ~1100, its rest points 2 pi apart 0.006 of it, and seven of them were one fixed_point_1). Parts smaller than
    ``min_samples`` are left out. ``[g]`` when nothing is cut."""
    parts = [g]
    for j in range(f.final.shape[1]):
        cut = []
        for p in parts:
            order = p[np.argsort(f.final[p, j], kind="stable")]
            moves = _motion(order, f)[:, j]
            mono = _ends_at_extreme(order, f)
            gap = np.diff(f.final[order, j]) > REST_GAP * np.maximum(moves[:-1], moves[1:])
            edges = np.flatnonzero(gap & ~(mono[:-1] & mono[1:])) + 1
            bounds = np.r_[0, edges, p.size]
            cut += [np.sort(order[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
        parts = cut
    if len(parts) == 1:
        return [g]
    # a part too small to be a group is left out, as DBSCAN leaves out what is too sparse (unclassified, unless
    # found approaching an equilibrium it does not end apart from): never given a neighbouring equilibrium's name
    return [p for p in parts if p.size >= min_samples]


def _motion(g: np.ndarray, f: _Features) -> np.ndarray:
    """(members, observables): each member's window range of each observable, at least the fixed-point stop's
    distance (``STOP_DISTANCE`` solver tolerances: where a trajectory at rest still hovers)."""
    k = len(STATS)
    return np.maximum(f.feats[g][:, 3::k] - f.feats[g][:, 2::k], STOP_DISTANCE * f.tol)


def _ends(g: np.ndarray, f: _Features, pooled: bool = True) -> tuple[np.ndarray, ...]:
    """Where trajectories ``g`` end, for :func:`_apart`: (at rest, in a monotone approach, scaled last observables,
    last observables, window ranges (:func:`_motion`)); ``pooled``: of the group as one (most members; medians),
    else of each member (rows)."""
    rest, mono, xf, end, move = f.at_rest[g], _ends_at_extreme(g, f), f.xf[g], f.final[g], _motion(g, f)
    if not pooled:
        return rest, mono, xf, end, move
    return (np.mean(rest) > 0.5, np.mean(mono) > 0.5, *(np.median(v, axis=0) for v in (xf, end, move)))


def _apart(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...], fine: float) -> np.ndarray:
    """Whether two groups of a fixed point's trajectories, or trajectories (:func:`_ends`, broadcast row by row),
    end at different equilibria though within ``eps``: both at rest, and their resting points (scaled) farther apart
    than ``fine`` (:func:`_split_rest`); or, neither in a monotone approach (whose equilibrium lies beyond its window),
    their last observables farther apart in some observable than ``REST_GAP`` times the larger of their window
    ranges (:func:`_split_by_end`)."""
    far_rest = np.linalg.norm(a[2] - b[2], axis=-1) > fine
    far_end = np.any(np.abs(a[3] - b[3]) > REST_GAP * np.maximum(a[4], b[4]), axis=-1)
    return np.where(a[0] & b[0], far_rest, ~(a[1] | b[1]) & far_end)


def _merge_near(groups: list[np.ndarray], by: tuple[np.ndarray, ...], eps: float, apart=None
                ) -> tuple[list[np.ndarray], list[tuple[np.ndarray, ...]]]:
    """Groups merged in order: one joins the first earlier group whose median in any of the positions ``by``
    (scaled, one row per trajectory) lies within ``eps`` of its own, unless ``apart(group, earlier)`` (two
    equilibria known apart more finely than eps: :func:`_apart`). The merged groups and their medians."""
    merged: list[np.ndarray] = []
    placed: list[tuple[np.ndarray, ...]] = []
    for g in groups:
        here = tuple(np.median(p[g], axis=0) for p in by)
        near = [i for i, there in enumerate(placed)
                if min(np.linalg.norm(a - b) for a, b in zip(here, there)) <= eps
                and not (apart is not None and apart(g, merged[i]))]
        if near:
            merged[near[0]] = np.concatenate([merged[near[0]], g])
            placed[near[0]] = tuple(np.median(p[merged[near[0]]], axis=0) for p in by)
        else:
            merged.append(g)
            placed.append(here)
    return merged, placed


def _approaching(members: np.ndarray, f: _Features, cfg: DiscoveryConfig) -> np.ndarray:
    """Per trajectory: approaching a stable equilibrium -- at rest, or its exponent below
    -chaos_threshold in an autonomous model (a bounded motion other than an equilibrium has a zero one),
    or, without the exponent, ending its window at an extreme of every observable (a monotone approach)."""
    out = f.at_rest[members].copy()
    if f.lam is not None and f.autonomous:
        with np.errstate(invalid="ignore"):
            out |= f.lam[members] < -cfg.chaos_threshold
    elif f.lam is None:
        out |= _ends_at_extreme(members, f)
    return out


def _describe(g: np.ndarray, f: _Features, cfg: DiscoveryConfig, kind: str | None = None):
    """(type, median features, median exponent, representative index) of one group of trajectories;
    ``kind``: its type when already known (a fixed point and the trajectories found approaching it)."""
    med = np.median(f.feats[g], axis=0)
    lam = float(np.nanmedian(f.lam[g])) if f.lam is not None and np.isfinite(f.lam[g]).any() else math.nan
    xm = np.median(f.x[g], axis=0)
    rep = int(g[np.argmin(np.linalg.norm(f.x[g] - xm, axis=1))])
    if kind is not None:
        pass
    elif np.mean(f.at_rest[g]) > 0.5:  # most at rest (the stop froze them, or their spread is numerical)
        kind = "attractor" if _hidden_motion(g, lam, f) else "fixed_point"
    elif f.lam is None:
        kind = "attractor"
    elif lam > cfg.chaos_threshold:
        kind = "attractor" if _short_for_chaos(lam, f) else "chaotic"
    elif lam < -cfg.chaos_threshold and (f.autonomous or np.mean(_ends_at_extreme(g, f)) > 0.5):
        # still approaching a stable equilibrium: a bounded motion of an autonomous flow other than an
        # equilibrium has a zero exponent, and a monotone approach is no cycle in any flow
        kind = "fixed_point"
    elif _unsettled(lam, f, cfg) or np.mean(_ends_at_extreme(g, f)) > 0.5:
        # a monotone approach or drift (every observable ends its window at an extreme) is no cycle whatever its
        # exponent: x' = -x^3 from t = 1000 to 2000 contracts at -0.001, and a 1-D flow has no cycle at all
        kind = "attractor"
    elif f.autonomous and lam < 0 and _decaying(rep, lam, f):
        # an oscillation dying out at its exponent's rate: a weak focus, no cycle -- if a stable equilibrium lies
        # inside its window; a cycle approached from outside falls toward its amplitude at the same rate
        # (r' = 0.02 r (1 - r^2), theta' = 1 at t1 = 150 was fixed_point_1, its origin an unstable focus): untyped
        if f.focus is None or f.focus(rep):
            kind = "fixed_point"
        else:
            kind = "attractor"
            f.no_focus.add(rep)
    elif f.autonomous and _continuum(g, f):
        kind = "attractor"  # closed orbits of many sizes, none attracting the others: a centre, no one cycle
        f.continua.add(rep)
    else:
        kind = "limit_cycle"
    return kind, med, lam, rep


def _unsettled(lam: float, f: _Features, cfg: DiscoveryConfig) -> bool:
    """Whether a group contracting at its exponent ``lam`` < 0 has not settled by the window's start: a
    separation of the order of the observables' range shrinks to exp(lam * settle) of it there, and while
    that exceeds ``eps`` the window holds the transient, not an attractor (x'' + 0.04 x' + x = exp(-t):
    exponent -0.02, exp(-0.02 * 75) = 0.22 at t1 = 150, and its decaying oscillations were five 'limit
    cycles'). A forced model's periodic attractor, contracting faster or watched longer, passes."""
    return f.settle is not None and lam < -cfg.chaos_threshold and math.exp(lam * f.settle) > cfg.eps


ENVELOPE_POINTS = 4001  # samples of a representative's window for its envelope (a period needs ~20 of them)
# the envelope's last peak below this share of its first: decaying, far beyond the dense sampling's error (~1e-5 of
# a peak); 0.9 missed the weak focus a = 0.005 watched to t1 = 50 (9 % over its window, its rate the exponent's
# to 1 %): three 'families of neutral orbits'
ENVELOPE_DECAY = 0.99


def _decaying(rep: int, lam: float, f: _Features) -> bool:
    """Whether a group with a small negative exponent (within ``chaos_threshold`` of 0, where a cycle's
    finite-time exponent may lie too) is an oscillation dying out -- a weak focus -- rather than a cycle: its
    representative, integrated again densely over the window (``f.trace``), oscillates with peaks (about the
    window's mean, in the observable of largest spread) that fall at every peak, at least 3 of them, to below
    ``ENVELOPE_DECAY`` of the first, at a rate (log-linear fit) within a factor 2 of the exponent. A cycle's peaks
    are equal; one approached from outside falls toward its amplitude at its Floquet rate while its exponent is
    that of the phase, ~0. (x'' + 0.01 x' + x = 0 watched to t1 = 100: exponent -0.005, peaks falling 22 % over the
    window, was limit_cycle_1.)"""
    if f.trace is None or not np.isfinite(lam):
        return False
    rate, drop = _envelope(rep, f)
    return bool(drop < ENVELOPE_DECAY and 0.5 * lam >= rate >= 2.0 * lam)


def _envelope(rep: int, f: _Features) -> tuple[float, float]:
    """:func:`_envelope_rate` of trajectory ``rep``'s dense window (integrated again once, then remembered)."""
    if rep not in f.envelope:
        f.envelope[rep] = _envelope_rate(*f.trace(rep))
    return f.envelope[rep]


def _dying(rep: int, f: _Features) -> bool:
    """Whether a group's representative oscillates with peaks falling at every peak to below ``ENVELOPE_DECAY`` of
    the first over the window: an oscillation dying out, a transient (without the exponent, a stable focus at
    x' = -0.2 (x - 1) - y, y' = (x - 1) - 0.2 y watched to t1 = 50 was three untyped groups, unsaid)."""
    return f.trace is not None and bool(_envelope(rep, f)[1] < ENVELOPE_DECAY)


def _continuum(g: np.ndarray, f: _Features) -> bool:
    """Whether a group that would be a limit cycle is a family of closed orbits instead -- a centre, or a
    conservative system's periodic orbits (x' = -y, y' = x: circles of every radius, one limit_cycle_1 with S = 1).
    Its members' window ranges (max - min of each observable, scaled: independent of the phase over whole periods)
    differ by more than ``eps`` between the smallest and the largest member, and those two, integrated again
    densely over the window (``f.trace``), each close on themselves there (an orbit, not an arc of a longer
    period) and lie farther than ``eps`` apart (the larger of the two directed distances between the point sets).
    One cycle gives every member the same orbit whatever its phase (the pendulum's running cycle, whose drifting
    final values spread its window features); a window shorter than a period decides nothing (the orbits do not
    close) and leaves the cycle typed."""
    if f.trace is None or g.size < 2:
        return False
    k = len(STATS)
    ranges = f.x[g][:, 3::k] - f.x[g][:, 2::k]
    ia, ib = int(np.argmin(ranges.sum(axis=1))), int(np.argmax(ranges.sum(axis=1)))
    if not np.linalg.norm(ranges[ib] - ranges[ia]) > f.eps:
        return False
    a, b = int(g[ia]), int(g[ib])
    if (a, b) not in f.orbits:
        orbits = [f.trace(i)[1] / f.scale for i in (a, b)]
        f.orbits[(a, b)] = _orbit_distance(*orbits) if all(_closes(o, f.eps) for o in orbits) \
            else math.nan
    return bool(f.orbits[(a, b)] > f.eps)


def _closes(orbit: np.ndarray, eps: float) -> bool:
    """Whether a densely sampled (scaled) orbit closes on itself: it never leaves ``eps`` of its first point (an
    orbit smaller than the grouping radius), or, after going halfway to its farthest point, comes back to within
    a quarter of that distance (and of eps / 2); an arc of a longer period does not."""
    if len(orbit) < 3 or not np.all(np.isfinite(orbit)):
        return False
    d = np.linalg.norm(orbit - orbit[0], axis=1)
    far = float(d.max())
    if far <= eps:
        return True
    away = int(np.flatnonzero(d > far / 2)[0])
    return bool(np.any(d[away:] < min(eps / 2, far / 4)))


def _orbit_distance(p: np.ndarray, q: np.ndarray) -> float:
    """The Hausdorff distance of two point sets (the larger directed distance), in blocks of rows."""
    def directed(u, v):
        return max(float(np.sqrt(((u[i:i + 256, None, :] - v[None]) ** 2).sum(-1)).min(axis=1).max())
                   for i in range(0, len(u), 256))
    return max(directed(p, q), directed(q, p))


def _envelope_rate(t: np.ndarray, obs: np.ndarray) -> tuple[float, float]:
    """(decay rate of the peaks, last peak / first peak) of the observable of largest spread about its mean; the
    peaks must fall at every one (else (nan, 1))."""
    if not (np.all(np.isfinite(obs)) and len(t) > 3):
        return math.nan, 1.0
    y = obs[:, int(np.argmax(np.std(obs, axis=0)))]
    c = y - np.mean(y)
    i = np.flatnonzero((c[1:-1] > c[:-2]) & (c[1:-1] >= c[2:]) & (c[1:-1] > 0)) + 1
    if len(i) < 3 or np.any(np.diff(c[i]) >= 0):
        return math.nan, 1.0
    return float(np.polyfit(t[i], np.log(c[i]), 1)[0]), float(c[i][-1] / c[i][0])


class Again:
    """Each representative integrated again on its own (diffrax, the plan's solver and tolerances:
    :func:`stabjax.engines.simulate.simulate`), saved at ``ENVELOPE_POINTS`` times over the feature window and
    remembered: the envelope and orbit tests (``trace``), the fixed-point placement and the state at t1 read the
    same integration. One set of save times compiles one program per model (a second set, [t1] alone, cost a
    trace and a compilation of diffrax's loop, ~1 s, in every discovery sweep)."""

    def __init__(self, plan, settle: float):
        icfg = plan.icfg
        self.plan = plan
        self.ts = np.linspace(icfg.t0 + settle, icfg.t1, ENVELOPE_POINTS)
        self._done: dict[int, Any] = {}
        self.inside: dict[int, tuple] = {}  # representative -> :func:`_equilibrium_inside`
        self.root: dict[int, Any] = {}  # representative -> :func:`_newton`

    def focus(self, index: int) -> bool:
        """Whether trajectory ``index`` spirals about a stable equilibrium inside its window, or cannot be asked (at
        rest, or its integration failed): :func:`_equilibrium_inside`, for :func:`_describe`'s weak focus."""
        return _equilibrium_inside(self.plan, int(index), self)[0] != "none"

    def __call__(self, index: int):
        index = int(index)
        if index not in self._done:
            self._done[index] = _again(self.plan, index, self.ts)
        return self._done[index]

    def trace(self, index: int):
        """Trajectory ``index``'s window: (times, observables), empty if the solver failed (for :func:`features`)."""
        ds = self(index)
        if int(ds.attrs["solver_status"]) != 0:
            return self.ts[:0], np.zeros((0, len(self.plan.system.observables)))
        t = ds["t"].values
        keep = t >= self.ts[0]
        return t[keep], np.stack([ds[o].values[keep] for o in self.plan.system.observables], axis=1)

    def states(self, index: int) -> np.ndarray:
        """The full state at each save time (rows) over the window."""
        ds = self(index)
        t = ds["t"].values
        Y = np.concatenate([ds[n].values.reshape(len(t), -1) for n, _ in self.plan.system.state], axis=1)
        return Y[t >= self.ts[0]]


CHAOS_SPAN = 2.0  # exponent x window length below which a runaway at that rate passes unbounded()'s GROWTH test


def _short_for_chaos(lam: float, f: _Features) -> bool:
    """Whether a positive exponent ``lam`` has had too short a window to tell a chaotic attractor from a slow
    runaway: a magnitude growing as e^(lam t) passes :func:`unbounded`'s ``GROWTH`` test (2 r T / (1 - e^(-2 r T))
    >= GROWTH^2) only once lam T > 1.97, so below ``CHAOS_SPAN`` the window cannot have shown the motion bounded
    (the unstable focus x' = 0.1 x - y, y' = x + 0.1 y watched for 7.5 time units: five 'chaotic' attractors).
    Such a group is left untyped, and said (:func:`_warn_short_window`). Lorenz-63 (0.9) needs a window of 2.2."""
    return f.span is not None and lam * f.span < CHAOS_SPAN


CYCLE_BIAS = 1e-3  # the least contraction by the window's start that a cycle's finite-time exponent can fake


def _cycle_like(lam: float, f: _Features) -> bool:
    """Whether a negative exponent could be a cycle's finite-time bias, off zero by up to ln(max|f| / min|f|) / T
    over a time T: a contraction by the window's start of exp(lam * settle) > ``CYCLE_BIAS`` (a thousandfold; Van
    der Pol at mu = 1 with t1 = 50: exp(-0.06 * 37.5) = 0.1). A focus at exponent -0.5 watched from t = 25 on
    (e^-12.5) is no cycle: its typing is not said."""
    return f.settle is None or not np.isfinite(lam) or math.exp(lam * f.settle) > CYCLE_BIAS


def _left_to_go(g: np.ndarray, lam: float, f: _Features) -> float:
    """How far a group in a monotone approach may still be from its equilibrium at t1 (scaled, the median member):
    an approach at the exponent ``lam`` < 0 that travelled a distance D over the window (its range) has D e^(lam T)
    / (1 - e^(lam T)) left to go. A lower estimate where the approach slows faster than exponentially (x' = -x^3:
    algebraic, exponent -0.02 at t1 = 100, 0.56 D left by this, 0.07 in fact). NaN where unknown."""
    if f.span is None or not np.isfinite(lam) or lam >= 0:
        return math.nan
    k = len(STATS)
    travel = np.linalg.norm(f.x[g][:, 3::k] - f.x[g][:, 2::k], axis=1)  # the scaled window ranges
    q = math.exp(lam * f.span)
    return float(np.median(travel) * q / (1.0 - q)) if q < 1 else math.inf


def _nearest_fixed(g: np.ndarray, name: str, names, types, typed, f: _Features) -> tuple[str, float]:
    """The other fixed point nearest to a group's members at t1 (scaled final states of the observables, median
    member to median member), and how far: ("", nan) where there is none. A group still on its way may be that
    one's equilibrium approached from elsewhere (the unforced Duffing oscillator at t1 = 60: a third small
    fixed point beside the first), and the user is told which to compare."""
    here = np.median(f.xf[g], axis=0)
    best, dist = "", math.nan
    for n, t, r in zip(names, types, typed):
        if t != "fixed_point" or n == name:
            continue
        d = float(np.linalg.norm(np.median(f.xf[r[3]], axis=0) - here))
        if not dist <= d:
            best, dist = n, d
    return best, dist


def _hidden_motion(g: np.ndarray, lam: float, f: _Features) -> bool:
    """Whether a group whose observables are at rest may still move where they do not look: an autonomous model,
    most members not frozen by the fixed-point stop (which checked f = 0), and an exponent that has not contracted a
    thousandfold by the window's start (exp(lam * settle) > ``CYCLE_BIAS``) -- an equilibrium reached from a start at
    the observables' scale has; a cycle on which every observable is constant (a rotation watched through its radius
    r: the cycles r = 2, 4, 6 of the shock example were fixed_point_2..4, exponent -2e-9) has not. Left untyped,
    and said (:func:`_warn_hidden_motion`)."""
    if not f.autonomous or not np.isfinite(lam) or lam > f.chaos:
        return False
    if f.stopped is not None and np.mean(f.stopped[g]) > 0.5:
        return False
    return f.settle is not None and _cycle_like(lam, f)


def _ends_at_extreme(g: np.ndarray, f: _Features) -> np.ndarray:
    """Per member: whether it ends its window at an extreme of every observable that moves (a monotone approach,
    no oscillation: an oscillation ends at its window minimum or maximum only by the phase's chance). An observable
    whose window spans no more than the fixed-point stop's distance (``STOP_DISTANCE`` solver tolerances) has come
    to rest, and its solver noise says nothing of the others (x' = -x^3, y' = -y: y's +-1e-10 at t1 = 100 made a
    monotone approach of x a 'limit cycle')."""
    min_cols = [k * len(STATS) + 2 for k in range(len(f.scale))]
    lo = f.feats[g][:, min_cols]
    hi = f.feats[g][:, [c + 1 for c in min_cols]]
    end = f.final[g]
    resting = (hi - lo) <= STOP_DISTANCE * f.tol
    return np.all((end == lo) | (end == hi) | resting, axis=1)


def _named(found, f: _Features, stats, kinds=None) -> Attractors:
    """Name and order the attractors ``found`` (:func:`_found`; type, then decreasing size); ``kinds``: given
    types (continuation)."""
    typed = []
    for i, (g, kind, med, lam, rep) in enumerate(found):
        kind = kinds[i] if kinds is not None else kind
        typed.append((TYPES.index(kind), -g.size, kind, g, med, lam, rep))
    typed.sort(key=lambda r: (r[0], r[1], r[6]))
    labels = np.full(len(f.feats), -1, np.int64)
    names, types, counts, fmed, lams, reps = [], [], [], [], [], []
    seen: dict[str, int] = {}
    for a, (_, _, kind, g, med, lam, rep) in enumerate(typed):
        seen[kind] = seen.get(kind, 0) + 1
        names.append(f"{kind}_{seen[kind]}")
        types.append(kind)
        counts.append(g.size)
        fmed.append(med)
        lams.append(lam)
        reps.append(rep)
        labels[g] = a
    stats.update(n_grouped=int((labels >= 0).sum()), n_unbounded=int(f.unbounded.sum()),
                 # untyped groups still in a transient that t1 did not outlast (:func:`_warn_transient`): most
                 # members end their window in a monotone approach, or (with the exponent, where an untyped
                 # group is one still contracting, :func:`_unsettled`) any
                 transient=[n for n, t, g, lam, rep in zip(names, types, (r[3] for r in typed), lams, reps)
                            if t == "attractor" and not lam > f.chaos and not np.mean(f.at_rest[g]) > 0.5
                            and rep not in f.continua and rep not in f.no_focus
                            and (np.mean(_ends_at_extreme(g, f)) > 0.5 or np.isfinite(lam) or _dying(rep, f))],
                 # untyped groups of closed orbits of many sizes (:func:`_continuum`, :func:`_warn_continuum`)
                 continuum=[(n, int(g.size), float(lam)) for n, t, g, lam, rep in
                            zip(names, types, (r[3] for r in typed), lams, reps)
                            if t == "attractor" and rep in f.continua],
                 # untyped oscillations dying out at their exponent's rate about no stable equilibrium (_describe)
                 no_focus=[(n, int(g.size), float(lam)) for n, t, g, lam, rep in
                           zip(names, types, (r[3] for r in typed), lams, reps) if t == "attractor" and rep in f.no_focus],
                 # untyped groups whose observables rest while the exponent says the state may move
                 hidden=[(n, int(g.size), float(lam)) for n, t, g, lam in zip(names, types, (r[3] for r in typed), lams)
                         if t == "attractor" and np.mean(f.at_rest[g]) > 0.5],
                 # untyped groups growing at a positive exponent over a window too short to tell chaos from a
                 # runaway (:func:`_short_for_chaos`, :func:`_warn_short_window`)
                 short_window=[(n, int(g.size), float(lam)) for n, t, g, lam in
                               zip(names, types, (r[3] for r in typed), lams) if t == "attractor" and lam > f.chaos],
                 transient_unclassified=int(_ends_at_extreme(np.flatnonzero(f.valid & (labels < 0)), f).sum()),
                 # limit cycles whose representative's peaks fall at every peak over the window: a cycle approached
                 # from outside, or an oscillation dying out with a finite-time exponent near 0 (:func:`_warn_fading`)
                 fading=[(n, int(g.size), float(f.envelope[rep][1])) for n, t, g, rep in
                         zip(names, types, (r[3] for r in typed), reps) if t == "limit_cycle" and _dying(rep, f)],
                 # fixed points typed by their negative exponent alone, their members still oscillating over the
                 # window (neither at rest nor in a monotone approach), where the exponent could be a cycle's
                 # finite-time bias: :func:`_warn_by_exponent`
                 by_exponent=[(n, int(g.size), float(lam)) for n, t, g, lam, rep in
                              zip(names, types, (r[3] for r in typed), lams, reps)
                              if t == "fixed_point" and np.mean(f.at_rest[g]) <= 0.5
                              and np.mean(_ends_at_extreme(g, f)) <= 0.5 and _cycle_like(lam, f)
                              and not _decaying(rep, lam, f)],
                 # fixed points still approached monotonically, and how far they may have to go (:func:`_left_to_go`;
                 # said where that is more than eps, :func:`_warn_still_far`)
                 still_far=[(n, int(g.size), float(lam), d, *_nearest_fixed(g, n, names, types, typed, f))
                            for n, t, g, lam in zip(names, types, (r[3] for r in typed), lams)
                            if t == "fixed_point" and np.mean(f.at_rest[g]) <= 0.5
                            and np.mean(_ends_at_extreme(g, f)) > 0.5
                            and np.isfinite(d := _left_to_go(g, lam, f))])
    return Attractors(labels=labels, names=names, types=types, counts=np.asarray(counts, np.int64),
                      features=np.asarray(fmed).reshape(len(names), len(f.names)), feature_names=f.names,
                      lyapunov=np.asarray(lams, float), representative=np.asarray(reps, np.int64), scale=f.scale,
                      stats=stats, unbounded=f.unbounded)


def _continued(results, observables, cfg: DiscoveryConfig, valid: np.ndarray, n_points: int,
               atol: float = 0.0, rtol: float = 0.0, autonomous: bool = False, settle: float | None = None,
               span: float | None = None, trace=None, focus=None) -> tuple[Attractors, list[dict[str, Any]], float]:
    """Attractors followed along one grid axis: each point's attractors found on their own (:func:`_found`,
    features scaled by the whole sweep's ranges so distances compare between points), then matched from
    point to point by :func:`stabjax.mapping.continuation.match_sequentially` (a group matches only an
    attractor of its own type). Trajectories are laid out point-major (``n_points`` grid points, the same
    number of samples each). Returns the discovery (labels over all trajectories), the births and deaths
    (:func:`stabjax.mapping.continuation.events`) and the match threshold used."""
    from . import continuation as C

    f = features(results, observables, cfg, valid, atol, rtol, autonomous, settle, span, trace, focus)
    per = len(f.feats) // n_points
    found: list[list[C.Found]] = []
    for k in range(n_points):
        idx = np.arange(k * per, (k + 1) * per)
        idx = idx[f.valid[idx]]
        found.append([C.Found(g, kind, f.x[rep]) for g, kind, _, _, rep in _found(f, cfg, idx)[0]])
    threshold = C.default_threshold(found) if cfg.match_threshold is None else cfg.match_threshold
    ids, spans = C.match_sequentially(found, threshold)
    groups, kinds = C.merged(found, ids, len(spans))
    disc = _named([(g, *_describe(g, f, cfg)) for g in groups], f, {"points": n_points}, kinds=[k[0] for k in kinds])
    names = [disc.names[int(disc.labels[g[0]])] for g in groups]
    return disc, C.events(spans, names, n_points), threshold


# ---- the mapper -------------------------------------------------------------------------------------

MAX_CODES = 127  # outcome codes are int8


def continues(plan, cfg: DiscoveryConfig) -> bool:
    """Whether the attractors are followed along the grid (one ``[grid]`` axis with ``[sample]`` and
    ``continuation``) rather than grouped over the whole sweep at once."""
    return bool(cfg.continuation and len(plan.grid) == 1 and plan.n_sample)



class Discovery(Mapper):
    """The outcomes are the attractors found in the whole sweep's features (a whole-set mapper; see the
    module docstring). Before the run its scheme holds the fates alone (escape, unclassified, failed)."""

    kind = "discovery"
    whole_set = True

    def __init__(self, decl, escape: bool):
        self.escape = bool(escape)
        self.cfg = DiscoveryConfig.from_dict(decl.discovery or {})
        self.scheme = OutcomeScheme(*outcome_names(decl, (), self.escape), decl)

    def check(self, plan, state: Any = None) -> None:
        """Before integrating: a grouping of fewer than ``min_samples`` trajectories (the whole sweep, or each
        grid point's samples under continuation) forms no group, and every trajectory would end
        unclassified after the whole run."""
        cfg = self.cfg
        n, where = (plan.n_sample, "per grid point (continuation groups each point on its own)") \
            if continues(plan, cfg) else (plan.size, "in the sweep")
        if n < cfg.min_samples:
            raise ValidationError("outcomes.discovery.min_samples", f"discovery calls a group of trajectories an "
                                  f"attractor when at least min_samples = {cfg.min_samples} of them lie within eps of "
                                  f"one another; there are {n} trajectories {where}, so every one would end "
                                  f"unclassified: sample at least {cfg.min_samples} starts, or lower min_samples")

    def map_set(self, plan, results: Mapping[str, np.ndarray], state: Any = None) -> Mapped:
        """The attractors of every trajectory's results: codes, the scheme with the attractors' names, and
        the attractors' variables."""
        from ..fold import status as S

        decl, cfg = self.decl, self.cfg
        status = np.asarray(results["solver_status"])
        events = None
        obs, auto = tuple(plan.system.observables), is_autonomous(plan.system)
        settle = (1.0 - float(decl.window)) * (plan.icfg.t1 - plan.icfg.t0)
        span = float(decl.window) * (plan.icfg.t1 - plan.icfg.t0)
        again = Again(plan, settle)
        if continues(plan, cfg):
            disc, events, threshold = _continued(results, obs, cfg, status == 0, plan.grid[0].size, plan.icfg.atol,
                                                 plan.icfg.rtol, auto, settle, span, again.trace,
                                                 again.focus)
        else:
            disc = discover(results, obs, cfg, status == 0, plan.icfg.atol, plan.icfg.rtol, auto, settle, span,
                            again.trace, again.focus)
        away = disc.unbounded if disc.unbounded is not None else np.zeros(status.shape, bool)
        # a runaway is what an escape radius would have stopped: the escape outcome, whether or not a radius
        # is set, so one sweep never holds a runaway under two names (and exits 0, as an escape does)
        escape = self.escape or bool(away.any())
        names, colors = outcome_names(decl, tuple(disc.names), escape)
        if len(names) > MAX_CODES:
            small = int(np.sum(disc.counts < 2 * cfg.min_samples))
            raise ValidationError("outcomes.discovery.eps", f"{len(disc.names)} attractors found with eps = {cfg.eps:g} "
                                  f"and min_samples = {cfg.min_samples} ({small} of them groups of fewer than "
                                  f"{2 * cfg.min_samples} trajectories): more than the {MAX_CODES} outcome codes hold; "
                                  "raise eps or min_samples")
        # where each attractor is, before anything is said of it by name: fixed points found at one equilibrium are
        # one attractor (merged; under continuation, whose names are matched point by point, said)
        places = _places(plan, disc, results, again, cfg.chaos_threshold, retype=events is None)
        if places.retyped:  # untyped approaches heading for a stable equilibrium: fixed points placed there
            disc, places = _retyped(disc, places)
            names, colors = outcome_names(decl, tuple(disc.names), escape)
        unstable = _unstable(plan, disc, places, again, results, cfg)
        if unstable:  # at a saddle, or by one: no attractor (unclassified, said)
            said = _by_place(disc, unstable, places.comps, plan.icfg)
            gone = {disc.names[k] for k, *_ in unstable}
            disc, places = _dropped(disc, places, {k for k, *_ in unstable}, renumber=events is None)
            if events is not None:
                events = [e for e in events if e.get("attractor") not in gone]
            names, colors = outcome_names(decl, tuple(disc.names), escape)
            _warn_unstable(said)
        same = _one_place(disc, places, plan.icfg)
        if same and events is None:
            disc, places = _merged(disc, places, same)
            names, colors = outcome_names(decl, tuple(disc.names), escape)
        elif same:
            _warn_one_place(disc, same)
        _say_places(disc, places)
        mixed = _ends_elsewhere(plan, disc, again, places, cfg.eps)
        if mixed:
            _warn_ends_elsewhere(mixed, obs)
        code = np.where(disc.labels >= 0, disc.labels, names.index(UNCLASSIFIED))
        if away.any():
            code = np.where(away, names.index(decl.escape), code)
            _warn_unbounded(int(away.sum()), status.size, decl.escape, self.escape)
        if disc.stats.get("transient") or disc.stats.get("transient_unclassified"):
            _warn_transient(disc.stats["transient"], dict(zip(disc.names, disc.counts.tolist())),
                            disc.stats["transient_unclassified"], "lyapunov" in results)
        if disc.stats.get("by_exponent"):
            _warn_by_exponent(disc.stats["by_exponent"])
        if disc.stats.get("hidden"):
            _warn_hidden_motion(disc.stats["hidden"])
        if disc.stats.get("continuum"):
            _warn_continuum(disc.stats["continuum"], cfg.eps)
        if disc.stats.get("no_focus"):
            _warn_no_focus(disc.stats["no_focus"])
        if disc.stats.get("short_window"):
            _warn_short_window(disc.stats["short_window"], span)
        if disc.stats.get("fading"):
            _warn_fading(disc.stats["fading"])
        if not continues(plan, cfg):
            split = _split_along_grid(plan, disc, results, obs)
            if split:
                _warn_split_along_grid(split, cfg.eps)
        far = [r for r in disc.stats.get("still_far", ()) if r[3] > cfg.eps]
        if far:
            _warn_still_far(far, cfg.eps)
        circling = _circling(disc, results, obs, cfg, status == 0, plan.icfg.atol, plan.icfg.rtol)
        if circling:
            _warn_circling(circling, cfg.eps)
        # then the solver's word: an escape by the radius, a failure, or non-finite features (failed)
        code = S.outcomes(status, code, escape=names.index(decl.escape) if self.escape else None,
                          failed=names.index(FAILED_NAME), finite=finite_features(results, obs)).astype(np.int8)
        data, coords = _attractor_vars(plan, disc, cfg, places)
        if events is not None:
            ax = plan.grid[0]
            ev = [{**e, ax.name: float(ax.values[e["index"]])} for e in events]
            data["attractor_events"] = ((), json.dumps(ev), {
                "long_name": f"births and deaths of attractors along {ax.name} (JSON: attractor, event, first grid "
                             f"index where it is present (birth) or absent again (death), the {ax.name} value there)",
                "match_threshold": threshold})
        return Mapped(code, OutcomeScheme(names, colors, decl), data, coords)


def _split_along_grid(plan, disc: Attractors, results, obs) -> list[str]:
    """Pairs of attractors that pooled grouping (``continuation = false``) likely made of one: of one type, never
    found at one grid point, and across some pair of neighbouring grid points each the nearest (median scaled
    features) of what appears where the other disappears. An attractor that moves with the parameter by more than
    ``eps`` between grid points falls apart into one group per stretch of the grid (the double well
    x'' = -0.3 x' + x - x^3 + F on F = -0.5 ... 0.5: the left well as fixed_point_1, _3 and _5)."""
    if plan.points is not None or not plan.grid or not plan.n_sample or not len(disc.names):
        return []
    shape = tuple(ax.size for ax in plan.grid)
    G = int(np.prod(shape))
    lab = np.asarray(disc.labels).reshape(G, -1)
    A = len(disc.names)
    present = np.stack([(lab == k).any(axis=1) for k in range(A)])  # (A, G)
    x, _ = feature_table(results, obs)
    x = (x / np.repeat(disc.scale, len(STATS))).reshape(G, lab.shape[1], -1)

    def at(k: int, g: int) -> np.ndarray:
        return np.median(x[g][lab[g] == k], axis=0)

    pairs: dict[tuple[int, int], str] = {}
    for g in range(G):
        idx = np.unravel_index(g, shape)
        for i, ax in enumerate(plan.grid):
            if idx[i] + 1 >= shape[i]:
                continue
            h = int(np.ravel_multi_index(idx[:i] + (idx[i] + 1,) + idx[i + 1:], shape))
            for here, there in ((g, h), (h, g)):
                gone = np.flatnonzero(present[:, here] & ~present[:, there])
                new = np.flatnonzero(present[:, there] & ~present[:, here])
                if not (gone.size and new.size):
                    continue
                for a in gone:
                    d = [float(np.linalg.norm(at(a, here) - at(b, there))) for b in new]
                    b = int(new[int(np.argmin(d))])
                    near = [float(np.linalg.norm(at(c, here) - at(b, there))) for c in gone]
                    if int(gone[int(np.argmin(near))]) != a or disc.types[a] != disc.types[b] \
                            or np.any(present[a] & present[b]):
                        continue
                    key = (min(a, b), max(a, b))
                    if key not in pairs:
                        v0, v1 = (float(ax.values[idx[i]]), float(ax.values[idx[i] + 1]))
                        pairs[key] = f"{disc.names[key[0]]} and {disc.names[key[1]]} (across {ax.name} = " \
                                     f"{v0:.6g} -> {v1:.6g})"
    return list(pairs.values())


def _warn_split_along_grid(pairs: list[str], eps: float) -> None:
    """Said, not only stored: pooled grouping may have given one moving attractor several names
    (:func:`_split_along_grid`)."""
    import warnings

    warnings.warn(f"{'; '.join(pairs)}: of one type, never found at one grid point, each the nearest of what "
                  f"appears where the other disappears: likely one attractor that moved farther than eps = {eps:g} "
                  f"between grid points, under two names (continuation = false groups every grid point's "
                  f"trajectories together by distance); set [outcomes.discovery] continuation = true (one grid axis) "
                  f"to follow it, or refine the grid", SplitWarning, stacklevel=3)


class SplitWarning(UserWarning):
    """Pooled discovery over a grid likely gave one attractor that moves with the parameter several names."""


class TransientWarning(UserWarning):
    """Discovery found trajectories still approaching something at t1 (monotonically, or contracting at a
    negative exponent that has not settled by the window's start): untyped groups or unclassified ones."""


def _warn_transient(names: list[str], counts: dict[str, int], unclassified: int, lyapunov: bool) -> None:
    """Said, not only stored: such a group is where trajectories were still heading at t1, typed by nothing
    (and such trajectories in no group are unclassified); a longer horizon lets them rest (typed
    ``fixed_point``), and the exponent types an approach at once."""
    import warnings

    parts = [f"{counts[k]} in {k}" for k in names] + ([f"{unclassified} unclassified"] if unclassified else [])
    n = sum(counts[k] for k in names) + unclassified
    how = "raise [integrate] t1" + ("" if lyapunov else ", or set [outcomes.discovery] lyapunov = true to type the "
                                                         "approach")
    way = ("contracting at a negative exponent, or monotonically" if lyapunov
           else "monotonically, or in oscillations dying out")
    warnings.warn(f"{n} trajectories ({', '.join(parts)}) end their feature window still approaching something "
                  f"({way}): a transient that t1 did not outlast, left untyped; {how}", TransientWarning,
                  stacklevel=3)


def _listed(groups: list[tuple[str, int, float]]) -> str:
    """``name (n trajectories, exponent lam), ...`` of the groups a warning is about."""
    return ", ".join(f"{name} ({n} trajectories, exponent {lam:.3g})" for name, n, lam in groups)


def _warn_by_exponent(groups: list[tuple[str, int, float]]) -> None:
    """Said, not only stored: a fixed point typed by its negative exponent while its members still oscillate over
    the feature window is either a slowly decaying oscillation (an equilibrium approached, as typed) or a strongly
    relaxational cycle whose finite-time exponent is off zero over a short window (Van der Pol at mu = 1 watched
    for four periods: -0.06); only a longer window tells them apart."""
    import warnings

    warnings.warn(f"{_listed(groups)}: typed a fixed point by the negative exponent alone, the trajectories still "
                  f"oscillating over the feature window (not at rest): an equilibrium approached slowly, or a cycle whose "
                  f"finite-time exponent is off zero over a short window; raise [integrate] t1 to tell them apart",
                  TransientWarning, stacklevel=3)


def _warn_hidden_motion(groups: list[tuple[str, int, float]]) -> None:
    """Said, not only stored: see :func:`_hidden_motion`."""
    import warnings

    warnings.warn(f"{_listed(groups)}: every observable at rest over the feature window, yet the exponent shows no "
                  f"contraction toward an equilibrium: a motion the observables do not see (a cycle on which they are constant) or "
                  f"a non-hyperbolic equilibrium; left untyped. Add an observable that moves along the state (or "
                  f"raise [integrate] t1)", TransientWarning, stacklevel=3)


def _warn_short_window(groups: list[tuple[str, int, float]], span: float) -> None:
    """Said, not only stored: a group growing at a positive exponent over a window too short for the growth to
    show (:func:`_short_for_chaos`) may be a chaotic attractor or trajectories running away slowly."""
    import warnings

    lams = [lam for _, _, lam in groups]
    parts = (f"{', '.join(name for name, _, _ in groups)} ({sum(n for _, n, _ in groups)} trajectories, exponent "
             f"{min(lams):.3g}{'' if f'{max(lams):.3g}' == f'{min(lams):.3g}' else f' to {max(lams):.3g}'}: a separation "
             f"grows "
             f"e^{max(lams) * span:.2g} over the window)")
    need = CHAOS_SPAN / min(lams)
    warnings.warn(f"{parts}: a positive exponent over a feature window of {span:.4g}, too short to tell a chaotic "
                  f"attractor from a slow runaway; left untyped. Raise [integrate] t1 so that the feature window "
                  f"lasts at least {need:.3g}", TransientWarning, stacklevel=3)


def _warn_still_far(groups: list[tuple[str, int, float, float, str, float]], eps: float) -> None:
    """Said, not only stored: a fixed point approached so slowly that its members may end farther than ``eps``
    from the equilibrium is placed where t1 left them, and one equilibrium approached from two sides (x' = -x^3
    from both signs) may then be two fixed points."""
    import warnings

    parts = ", ".join(f"{name} ({n} trajectories, exponent {lam:.3g}, at least {d:.2g} of the range to go"
                      + (f"; nearest fixed point {near}, {dn:.2g} of the range away" if near else "") + ")"
                      for name, n, lam, d, near, dn in groups)
    warnings.warn(f"{parts}: typed a fixed point by the negative exponent while still approaching it monotonically "
                  f"at t1, farther from it than eps = {eps:g} may allow: its position is where t1 left its "
                  f"trajectories, and fixed points so found on two sides may be one equilibrium; raise [integrate] "
                  f"t1", TransientWarning, stacklevel=3)


def _warn_continuum(groups: list[tuple[str, int, float]], eps: float) -> None:
    """Said, not only stored: a family of closed orbits is no attractor, and its basin stability means nothing."""
    import warnings

    warnings.warn(f"{_listed(groups)}: closed orbits of many sizes, their members' orbits farther than eps = {eps:g} apart "
                  f"and none contracting onto another (exponent ~0): a family of neutral orbits (a centre, or a "
                  f"conservative system), not one limit cycle; left untyped, and its basin fraction is that of the "
                  f"family, not of an attractor", TransientWarning, stacklevel=3)


def _warn_no_focus(groups: list[tuple[str, int, float]]) -> None:
    """Said, not only stored: an oscillation whose peaks fall as a weak focus's do, about no stable equilibrium."""
    import warnings

    warnings.warn(f"{_listed(groups)}: oscillations whose peaks fall at every peak, at the rate of their exponent, as a "
                  f"weak focus's do, but no stable equilibrium lies inside their window (Newton's method from the "
                  f"representative's state at t1): a limit cycle still approached from outside, or a focus too "
                  f"degenerate to place; left untyped; raise [integrate] t1 to tell them apart", TransientWarning,
                  stacklevel=3)


class RepresentativeWarning(UserWarning):
    """An attractor's representative could not be integrated again on its own for its state at t1."""


def _warn_representative(name: str) -> None:
    import warnings

    warnings.warn(f"{name}: its representative trajectory, integrated again on its own (diffrax) for its state at "
                  f"t1, did not reach t1; attractor_state is NaN and its place is given by its observables "
                  f"(attractor_observables)", RepresentativeWarning, stacklevel=3)


class UnboundedWarning(UserWarning):
    """Discovery found trajectories that run away (:func:`unbounded`) and counted them as escaped."""


def _warn_unbounded(n: int, total: int, name: str, radius: bool) -> None:
    """Said, not only counted: without a radius such a run integrates the runaways to t1 (up to 1e300 and
    a failure), and with one these grew within it, so the radius is what to set or lower."""
    import warnings

    what = "lower [integrate] escape_radius" if radius else "set [integrate] escape_radius"
    warnings.warn(f"{n} of {total} trajectories grow without bound over the feature window: counted as '{name}', "
                  f"not as an attractor; {what} (a bound above every attractor) to stop them early",
                  UnboundedWarning, stacklevel=3)


@dataclass
class _Places:
    """Where each attractor is (:func:`_places`): ``states`` (A, state size) and ``final`` (A, n_obs) of its
    representative at t1, or of the equilibrium Newton's method placed it at (``placed``); ``moving``: attractor
    index -> the spread of a fixed point's representative over the window where no equilibrium was found inside it
    (:func:`_warn_still_moving`); ``lost``: attractors whose representative failed when integrated again."""

    comps: list[str]
    states: np.ndarray
    final: np.ndarray
    placed: np.ndarray
    moving: dict[int, float]
    lost: list[int]
    retyped: tuple[int, ...] = ()  # untyped approaches placed ahead (:func:`_places`): fixed points


def _places(plan, disc: Attractors, results, again: Again, chaos: float, retype: bool = False) -> _Places:
    """Each attractor's place; nothing is said here (:func:`_say_places`, after the names are final). ``retype``:
    an untyped group said to be still in a transient whose representative heads for a hyperbolic stable equilibrium
    (:func:`_ahead`) is placed there and listed in ``retyped``, to be typed a fixed point (:func:`_retyped`): slow
    nodes x' = -k sin(pi x), y' = -20 (y - 0.1 x^2) at k = 0.006 left 10 starts bound for (0, 0) an untyped
    ``attractor_1`` beside ``fixed_point_1`` there (their exponent -0.0073, too near 0 to type them)."""
    a = len(disc.names)
    comps = [f"{name}" if not shape else f"{name}_{'_'.join(map(str, i))}"
             for name, shape in plan.system.state for i in (np.ndindex(shape) if shape else [()])]
    states = np.full((a, len(comps)), np.nan)
    lost = []
    for k, rep in enumerate(disc.representative):
        states[k] = representative_state(again, int(rep))
        if not np.all(np.isfinite(states[k])):  # never an attractor "at x = inf": unknown, and said
            states[k] = np.nan
            lost.append(k)
    n_obs = len(plan.system.observables)
    final = np.asarray(results["feat_final"], float)[disc.representative, :n_obs] if a else np.zeros((0, n_obs))
    placed = np.zeros(a, np.int8)
    moving: dict[int, float] = {}
    if a and is_autonomous(plan.system):
        # a representative the fixed-point stop finished is at its equilibrium already (stabjax.fold.equilibrium)
        stopped = np.asarray(results["stop_reason"]) == STOP_FIXED_POINT if "stop_reason" in results else None
        for k, (t, rep) in enumerate(zip(disc.types, disc.representative)):
            if t == "fixed_point" and np.all(np.isfinite(states[k])) and not (stopped is not None and stopped[rep]):
                placed[k], spread = _place_fixed_point(plan, int(rep), again, states, final, k, chaos)
                if spread is not None:
                    moving[k] = spread
    retyped = []
    if a and retype and is_autonomous(plan.system):
        transient = set(disc.stats.get("transient", ()))
        for k, (t, rep) in enumerate(zip(disc.types, disc.representative)):
            rep = int(rep)
            if t != "attractor" or disc.names[k] not in transient or not np.all(np.isfinite(states[k])):
                continue
            found, _, _, spread = _equilibrium_inside(plan, rep, again)
            if found == "none" and spread is None and _ahead(plan, rep, again, chaos):  # a monotone approach
                root = _newton(plan, rep, again)
                states[k], final[k], placed[k] = root.x, root.obs[: final.shape[1]], 2
                retyped.append(k)
    return _Places(comps, states, final, placed, moving, lost, tuple(retyped))


def _retyped(disc: Attractors, places: _Places) -> tuple[Attractors, _Places]:
    """The attractors ``places.retyped`` typed fixed points, every name numbered again within its type in order,
    the names in ``stats`` changed with them, and the retyped ones no longer said to be untyped transients."""
    import dataclasses

    types = ["fixed_point" if k in places.retyped else t for k, t in enumerate(disc.types)]
    names = _numbered(types)
    rename = dict(zip(disc.names, names))
    gone = {disc.names[k] for k in places.retyped}
    stats = dict(disc.stats)
    for key, v in disc.stats.items():
        if isinstance(v, list):
            stats[key] = [_renamed(x, rename) for x in v if not (key == "transient" and x in gone)]
    disc = dataclasses.replace(disc, names=names, types=types, stats=stats)
    return disc, dataclasses.replace(places, retyped=())


def _say_places(disc: Attractors, places: _Places) -> None:
    said = {r[0] for r in disc.stats.get("by_exponent", ())}  # already warned of (_warn_by_exponent)
    for k in places.lost:
        _warn_representative(disc.names[k])
    for k, spread in places.moving.items():
        if disc.names[k] not in said:
            _warn_still_moving(disc.names[k], spread)


def _attractor_vars(plan, disc: Attractors, cfg: DiscoveryConfig, places: _Places):
    a = len(disc.names)
    comps, states, final, placed = places.comps, places.states, places.final, places.placed
    starts = plan.params_at(disc.representative) if a else {}
    varied = [ax.param.name for ax in plan.grid] + list(plan.sample) if a else []
    data = {
        "attractor_type": ("attractor", np.array(disc.types, dtype=object),
                           {"long_name": "fixed_point (window std ~ 0), chaotic (lyapunov > threshold), "
                                         "limit_cycle (else), attractor (untyped: no exponent, or a transient "
                                         "still contracting at the window)"}),
        "attractor_count": ("attractor", disc.counts, {"long_name": "trajectories grouped into the attractor "
                                                                    "(all grid points)"}),
        "attractor_features": (("attractor", "attractor_feature"), disc.features,
                               {"long_name": "median late-window features of the attractor's trajectories"}),
        "attractor_lyapunov": ("attractor", disc.lyapunov,
                               {"long_name": "median largest Lyapunov exponent of its trajectories"}),
        "attractor_representative": ("attractor", disc.representative,
                                     {"long_name": "flat index of the trajectory nearest the median features"}),
        "attractor_state": (("attractor", "state_component"), states,
                            {"long_name": "state at t1 of the representative trajectory (re-integrated); of a fixed "
                                          "point still approached at t1, the stable equilibrium inside its last "
                                          "window or ahead of its approach (attractor_placed)"}),
        "attractor_observables": (("attractor", "observable"), final,
                                  {"long_name": "observables of the representative trajectory at t1 (of a placed "
                                                "fixed point, at the equilibrium)"}),
        "attractor_placed": ("attractor", placed, {
            "long_name": "how the attractor's state was found",
            "flag_values": np.array([0, 1, 2], np.int8),
            "flag_meanings": "representative_at_t1 equilibrium_by_newton_inside_the_last_window "
                             "equilibrium_by_newton_ahead_of_a_monotone_approach"}),
        "observable_range": ("observable", disc.scale,
                             {"long_name": "range of each observable over the sweep (feature scale)"}),
    }
    for k in varied:
        v = np.asarray(starts[k])
        extra = tuple(f"{k}_c{i}" for i in range(v.ndim - 1))
        data[f"attractor_start_{k}"] = (("attractor", *extra), v,
                                        {"long_name": f"{k} of the representative trajectory"})
    coords = {"attractor": ("attractor", np.array(disc.names, dtype=object)),
              "attractor_feature": ("attractor_feature", np.array(disc.feature_names, dtype=object)),
              "state_component": ("state_component", np.array(comps, dtype=object)),
              "observable": ("observable", list(plan.system.observables))}
    return data, coords


PLACE_MOVING = 1000.0  # window range, in tolerance units, above which a fixed point's representative still moves
NEWTON_STEPS = 50


def _place_fixed_point(plan, rep: int, again: Again, states, final, k: int, chaos: float
                       ) -> tuple[int, float | None]:
    """Place a fixed point whose representative still moves over the feature window (an oscillation dying out
    slowly: x' = -a(x - 1) - y, y' = (x - 1) - a y at a = 0.005 and t1 = 100 was placed "at x = -0.67, y = -0.74",
    1.9 from its equilibrium (1, 0), without a word) at the stable equilibrium inside its window
    (:func:`_equilibrium_inside`): ``states[k]``, ``final[k]`` updated, returns 1. Otherwise the position stays
    where t1 left the representative (returns 0 and, to be said by :func:`_warn_still_moving`, the representative's
    spread over the window; a monotone approach, whose equilibrium lies beyond the box, is said by
    :func:`_warn_still_far` instead). A representative at rest is left as is (0, None)."""
    found, x, obs, spread = _equilibrium_inside(plan, rep, again)
    placed = 1
    if found == "none" and spread is None and _ahead(plan, rep, again, chaos):
        root = _newton(plan, rep, again)
        found, x, obs, placed = "found", root.x, root.obs, 2
    if found != "found":
        return 0, spread
    states[k] = x
    final[k] = obs[: final.shape[1]]
    return placed, None


def _ahead(plan, rep: int, again: Again, chaos: float) -> bool:
    """Whether trajectory ``rep``, in a monotone approach at t1, heads for the stable equilibrium Newton's method
    finds from its state at t1 (:func:`_newton`), a hyperbolic one (its slowest mode decays faster than ``chaos``,
    the rate the exponent's typing tells from 0): the right-hand side there points toward it, and over the window
    the distance to it fell at least at half the rate of that mode (exp(growth window / 2)). A slow node
    (x' = -0.02 x, y' = -20 (y - x^2) watched to t1 = 100) left its trajectories on four sides of the equilibrium,
    four 'fixed points' at points that are none; placed at the one equilibrium they are one attractor
    (:func:`_one_place`). An approach slower than that (a non-hyperbolic equilibrium, or one far from the
    linear regime: x' = -x^3), or toward another point, is not placed (and said: :func:`_warn_still_far`)."""
    import jax.numpy as jnp

    root = _newton(plan, rep, again)
    if not (root.ok and root.growth < -chaos):
        return False
    icfg = plan.icfg
    Y = again.states(rep)
    ts = again.ts
    d0, d1 = np.linalg.norm(Y[0] - root.x), np.linalg.norm(Y[-1] - root.x)
    p = plan.system.check({key: np.asarray(v)[0] for key, v in plan.params_at(np.array([rep])).items()})
    args = plan.system.prepare({key: jnp.asarray(v) for key, v in p.items()})
    fy = np.asarray(plan.system.rhs(icfg.t1, jnp.asarray(Y[-1]), args))
    toward = float(np.dot(fy, root.x - Y[-1])) > 0
    return bool(toward and d0 > 0 and d1 <= d0 * math.exp(0.5 * root.growth * (ts[-1] - ts[0])))


def _equilibrium_inside(plan, rep: int, again: Again) -> tuple[str, Any, Any, float | None]:
    """The stable equilibrium inside trajectory ``rep``'s window, by Newton's method on the right-hand side from
    its state at t1 (:func:`_newton`): taken when Newton converges to within one tolerance unit, the Jacobian there
    is stable and the point lies inside the box the states span over the window (a spiral about it does; an
    equilibrium elsewhere does not). Returns (``"found"``, state, observables, None); (``"rest"`` or ``"failed"``,
    None, None, None) for a trajectory whose window spans at most ``PLACE_MOVING`` tolerance units or whose
    integration failed; else (``"none"``, None, None, spread), the spread its states span over the window, or None
    for a monotone approach (its equilibrium lies beyond the box)."""
    if rep in again.inside:
        return again.inside[rep]
    icfg = plan.icfg
    if int(again(rep).attrs["solver_status"]) != 0:
        return again.inside.setdefault(rep, ("failed", None, None, None))
    Y = again.states(rep)
    lo, hi = Y.min(axis=0), Y.max(axis=0)
    tol = icfg.atol + icfg.rtol * np.abs(Y[-1])
    if np.max((hi - lo) / tol) <= PLACE_MOVING:
        return again.inside.setdefault(rep, ("rest", None, None, None))
    root = _newton(plan, rep, again)
    slack = 10.0 * tol
    inside = root.ok and bool(np.all(root.x >= lo - slack) and np.all(root.x <= hi + slack))
    if inside and root.growth < 0:
        out = ("found", root.x, root.obs, None)
    elif not np.all((np.abs(Y[-1] - lo) <= slack) | (np.abs(Y[-1] - hi) <= slack)):
        out = ("none", None, None, float(np.max(hi - lo)))
    else:
        out = ("none", None, None, None)
    return again.inside.setdefault(rep, out)


@dataclass(frozen=True)
class _Root:
    """Newton's method from a trajectory's state at t1 (:func:`_newton`): ``ok`` when it converged (its last step
    below one tolerance unit, RMS), the equilibrium ``x`` and its observables ``obs``, and ``growth``, the largest
    real part of the Jacobian's eigenvalues there (NaN where Newton did not converge)."""

    ok: bool
    x: Any = None
    obs: Any = None
    growth: float = math.nan


def _newton(plan, rep: int, again: Again) -> _Root:
    """:class:`_Root` of trajectory ``rep`` (integrated again, :class:`Again`; remembered there): Newton's method on
    the right-hand side at t1 from its state at t1, at most ``NEWTON_STEPS`` steps, the Jacobian by forward-mode
    differentiation (exact, not differenced: the sign of its eigenvalues is the model's)."""
    import jax
    import jax.numpy as jnp

    if rep in again.root:
        return again.root[rep]
    icfg = plan.icfg
    if int(again(rep).attrs["solver_status"]) != 0:
        return again.root.setdefault(rep, _Root(False))
    Y = again.states(rep)
    p = plan.system.check({key: np.asarray(v)[0] for key, v in plan.params_at(np.array([rep])).items()})
    args = plan.system.prepare({key: jnp.asarray(v) for key, v in p.items()})

    def f(y):
        return plan.system.rhs(icfg.t1, y, args)

    jac = jax.jacfwd(f)
    y, ok = jnp.asarray(Y[-1]), False
    for _ in range(NEWTON_STEPS):
        J, fy = np.asarray(jac(y)), np.asarray(f(y))
        try:
            step = np.linalg.solve(J, fy)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        y = y - step
        if np.sqrt(np.mean((step / (icfg.atol + icfg.rtol * np.abs(np.asarray(y)))) ** 2)) < 1.0:
            ok = True
            break
    if not ok:
        return again.root.setdefault(rep, _Root(False))
    growth = float(np.max(np.real(np.linalg.eigvals(np.asarray(jac(y))))))
    return again.root.setdefault(rep, _Root(True, np.asarray(y), np.asarray(plan.system.observe(icfg.t1, y, args),
                                                                              float), growth))


def _warn_fading(groups: list[tuple[str, int, float]]) -> None:
    """Said, not only stored: a group typed a limit cycle (its exponent near 0) whose representative's peaks fall
    at every peak over the window. Either a cycle approached from outside, or an oscillation still dying out whose
    finite-time exponent is near 0 (x'' = x - x^3 - 0.02 x' watched to t1 = 150: orbits above the saddle's energy,
    slowly losing it, were two 'limit cycles' of a model that has none); only a longer window tells them apart."""
    import warnings

    parts = ", ".join(f"{name} ({n} trajectories, last peak {100 * drop:.3g}% of the first)" for name, n, drop in groups)
    warnings.warn(f"{parts}: typed a limit cycle while its representative's peaks fall at every peak over the feature "
                  f"window: a cycle still approached, or an oscillation dying out slowly; raise [integrate] t1 to tell "
                  f"them apart", TransientWarning, stacklevel=3)


def _one_place(disc: Attractors, places: _Places, icfg) -> list[tuple[int, int]]:
    """Pairs of fixed points, one of them placed by Newton (:func:`_place_fixed_point`), at the same equilibrium
    (within 100 tolerance units): DBSCAN kept apart groups still spiralling into one point (x'' = x - x^3 - 0.05 x'
    watched to t1 = 100: fixed_point_2 and fixed_point_3 both at (-1, 0))."""
    states, placed = places.states, places.placed
    fp = [k for k, t in enumerate(disc.types) if t == "fixed_point" and np.all(np.isfinite(states[k]))]
    pairs = []
    for i, a in enumerate(fp):
        for b in fp[i + 1:]:
            tol = icfg.atol + icfg.rtol * np.maximum(np.abs(states[a]), np.abs(states[b]))
            if (placed[a] or placed[b]) and np.all(np.abs(states[a] - states[b]) <= 100.0 * tol):
                pairs.append((a, b))
    return pairs


def _warn_one_place(disc: Attractors, pairs: list[tuple[int, int]]) -> None:
    """Said, not only stored (under continuation, whose names are matched point by point and are not merged): two
    fixed points at one equilibrium, one attractor under two names whose basin fractions add up."""
    import warnings

    if pairs:
        warnings.warn(f"{'; '.join(f'{disc.names[a]} and {disc.names[b]}' for a, b in pairs)} lie at the same "
                      f"equilibrium (placed by Newton's method inside their last windows): one attractor whose "
                      f"trajectories were still spiralling in at t1, grouped apart; add their basin fractions, or raise "
                      f"[integrate] t1", TransientWarning, stacklevel=3)


def _numbered(types: list[str]) -> list[str]:
    """Names ``<type>_<n>``, numbered in order within each type."""
    seen: dict[str, int] = {}
    names = []
    for t in types:
        seen[t] = seen.get(t, 0) + 1
        names.append(f"{t}_{seen[t]}")
    return names


def _renamed(v, rename: dict[str, str]):
    """A ``stats`` entry with its names changed: a name, or a tuple (name, ...) with another group's name further on
    (still_far's nearest)."""
    if isinstance(v, str):
        return rename.get(v, v)
    if isinstance(v, tuple):
        return tuple(rename.get(x, x) if isinstance(x, str) else x for x in v)
    return v


def _merged(disc: Attractors, places: _Places, pairs: list[tuple[int, int]]) -> tuple[Attractors, _Places]:
    """One attractor of fixed points found at one equilibrium (:func:`_one_place`): each pair's groups joined
    under the name of the larger (the first: groups are ordered by type, then size), their counts added, the place
    Newton found kept; the names of each type numbered again in order, and the names in ``stats`` (what is said of
    each group) changed with them."""
    import dataclasses

    root = list(range(len(disc.names)))

    def find(i):
        while root[i] != i:
            i = root[i]
        return i

    for a, b in pairs:
        ra, rb = find(a), find(b)
        if ra != rb:
            root[max(ra, rb)] = min(ra, rb)
    into = [find(i) for i in range(len(disc.names))]
    keep = [i for i in range(len(disc.names)) if into[i] == i]
    new = {old: n for n, old in enumerate(keep)}
    to = np.array([new[into[i]] for i in range(len(disc.names))], np.int64)
    labels = np.where(disc.labels >= 0, to[np.maximum(disc.labels, 0)], disc.labels)
    counts = np.bincount(to, weights=disc.counts, minlength=len(keep)).astype(np.int64)
    types = [disc.types[i] for i in keep]
    names = _numbered(types)
    rename = {disc.names[i]: names[to[i]] for i in range(len(disc.names))}
    states, final, placed = places.states.copy(), places.final.copy(), places.placed.copy()
    for i in range(len(disc.names)):  # the merged attractor's place: the equilibrium Newton found, if any did
        r = into[i]
        if placed[i] and not placed[r]:
            states[r], final[r], placed[r] = states[i], final[i], 1

    stats = dict(disc.stats)
    for key, v in disc.stats.items():
        if isinstance(v, list):
            out, first = [], set()
            for item in (_renamed(x, rename) for x in v):
                name = item if isinstance(item, str) else (item[0] if isinstance(item, tuple) and item else None)
                if name is not None and name in first:
                    continue
                if isinstance(item, tuple) and name in item[1:]:  # said of a group relative to itself, now
                    continue
                first.add(name)
                out.append(item)
            stats[key] = out
    disc = dataclasses.replace(disc, labels=labels, names=names, types=types, counts=counts,
                               features=disc.features[keep], lyapunov=disc.lyapunov[keep],
                               representative=disc.representative[keep], stats=stats)
    moving = {new[i]: v for i, v in places.moving.items() if i in new and not placed[i]}
    lost = [new[i] for i in places.lost if i in new]
    return disc, _Places(places.comps, states[keep], final[keep], placed[keep], moving, lost)


def _unstable(plan, disc: Attractors, places: _Places, again: Again, results, cfg: DiscoveryConfig
              ) -> list[tuple[int, bool, np.ndarray, float]]:
    """Fixed points that are no attractors: their representative rests at, or ends within ``eps`` (of each
    observable's range) of, an **unstable** equilibrium -- Newton's method from its state at t1 (:func:`_newton`)
    converges to a point whose Jacobian has an eigenvalue with real part above ``chaos_threshold`` (the rate the
    exponent's typing calls growth). A start on a saddle's stable manifold (the boundary between two basins: a
    column of a symmetric grid, x' = x - x^3, y' = -y from x0 = 0) comes to rest there and was
    ``fixed_point_3``, S = 0.048, with exponent +1; trajectories lingering by a saddle of a heteroclinic cycle
    (May-Leonard) at t1 were four 'fixed points'. Autonomous models only (a Jacobian at t1 says nothing of a forced
    one); a representative the fixed-point stop finished (certainly at a stable equilibrium), or placed inside
    its window at a stable one, is not asked. Returns (attractor index, at rest, equilibrium state, growth)."""
    if not is_autonomous(plan.system):
        return []
    stopped = np.asarray(results["stop_reason"]) == STOP_FIXED_POINT if "stop_reason" in results else None
    out = []
    for k, (t, rep) in enumerate(zip(disc.types, disc.representative)):
        rep = int(rep)
        if t != "fixed_point" or places.placed[k] or (stopped is not None and stopped[rep]):
            continue
        root = _newton(plan, rep, again)
        if not (root.ok and root.growth > cfg.chaos_threshold):
            continue
        near = np.abs(root.obs[: places.final.shape[1]] - places.final[k]) / disc.scale
        if np.all(near <= cfg.eps):
            out.append((k, _equilibrium_inside(plan, rep, again)[0] == "rest", root.x, root.growth))
    return out


def _dropped(disc: Attractors, places: _Places, drop: set[int], renumber: bool) -> tuple[Attractors, _Places]:
    """``disc`` without the attractors ``drop`` (:func:`_unstable`): their trajectories unclassified, what is said
    of them in ``stats`` left out, the others' names numbered again within each type (``renumber``; under
    continuation the names stay, being those of the births and deaths)."""
    import dataclasses

    keep = [i for i in range(len(disc.names)) if i not in drop]
    to = np.full(len(disc.names), -1, np.int64)
    to[keep] = np.arange(len(keep))
    labels = np.where(disc.labels >= 0, to[np.maximum(disc.labels, 0)], disc.labels)
    names = _numbered([disc.types[i] for i in keep]) if renumber else [disc.names[i] for i in keep]
    rename = {disc.names[i]: names[to[i]] for i in keep}
    gone = {disc.names[i] for i in drop}

    def about(v):  # the name a stats entry is about
        return v if isinstance(v, str) else (v[0] if isinstance(v, tuple) and v else None)

    stats = dict(disc.stats)
    for key, v in disc.stats.items():
        if isinstance(v, list):
            stats[key] = [_renamed(x, rename) for x in v if about(x) not in gone]
    disc = dataclasses.replace(disc, labels=labels, names=names, types=[disc.types[i] for i in keep],
                               counts=disc.counts[keep], features=disc.features[keep], lyapunov=disc.lyapunov[keep],
                               representative=disc.representative[keep], stats=stats)
    moving = {int(to[i]): v for i, v in places.moving.items() if i not in drop}
    lost = [int(to[i]) for i in places.lost if i not in drop]
    return disc, _Places(places.comps, places.states[keep], places.final[keep], places.placed[keep], moving, lost)


def _by_place(disc: Attractors, unstable, comps: list[str], icfg) -> list[tuple[int, bool, str, float]]:
    """What :func:`_warn_unstable` says: the groups of :func:`_unstable` at one equilibrium (within 100 tolerance
    units, as :func:`_one_place` joins fixed points) counted together, once per place (May-Leonard: 108 and 10
    trajectories by the one saddle (0, 1, 0) were said as two places); at rest where any of them rests."""
    out: list[list] = []
    for k, rest, x, g in unstable:
        for o in out:
            tol = icfg.atol + icfg.rtol * np.maximum(np.abs(o[4]), np.abs(x))
            if np.all(np.abs(o[4] - x) <= 100.0 * tol):
                o[0] += int(disc.counts[k])
                o[1] = o[1] or rest
                break
        else:
            out.append([int(disc.counts[k]), rest, _where(comps, x), g, np.asarray(x)])
    return [tuple(o[:4]) for o in out]


def _circling(disc: Attractors, results, observables, cfg: DiscoveryConfig, ok: np.ndarray, atol: float = 0.0,
              rtol: float = 0.0) -> list[tuple[str, int, float, float]]:
    """Unclassified trajectories that look like a fixed point's own, still spiralling in: their exponent within the
    range of the fixed point's members' and their window mean within ``eps`` (scaled) of the members' median. Left
    unclassified (a leftover joins a fixed point only with an exponent below ``-chaos_threshold``, and never one it
    ends apart from, :func:`_apart`, which needs the features: theta observed unwrapped, rest points 2 pi apart lie
    within eps of each other on its range; a cycle's
    trajectory circling a weak focus would have one near 0 too), and said: the linear weak focus x' = -0.001 x - y,
    y' = x - 0.001 y left its 4 innermost starts of 100 unclassified, their windows small circles DBSCAN kept apart,
    with nothing said (4 %, below the share the summary warns at). A leftover at rest is not spiralling in: it rests
    elsewhere (a part too small for a group, :func:`_split_rest`). (name, count, exponent range low, high)."""
    if "lyapunov" not in results or not disc.names:
        return []
    lam = np.asarray(results["lyapunov"], float).reshape(-1)
    x, names = feature_table(results, observables)
    mean = x[:, [names.index(f"mean({o})") for o in observables]] / disc.scale
    left = (disc.labels < 0) & ok & np.isfinite(lam) & np.all(np.isfinite(x), axis=1)
    tol = tolerances(results, left | (disc.labels >= 0), len(observables), atol, rtol)
    std = x[:, [names.index(f"std({o})") for o in observables]]
    left &= ~np.all(std <= rest_threshold(disc.scale, tol, cfg), axis=1)
    if disc.unbounded is not None:
        left &= ~disc.unbounded
    out = []
    for k, (name, t) in enumerate(zip(disc.names, disc.types)):
        mine = (disc.labels == k) & np.isfinite(lam)
        if t != "fixed_point" or not left.any() or not mine.any():
            continue
        lo, hi = float(lam[mine].min()), float(lam[mine].max())
        centre = np.median(mean[mine], axis=0)
        near = left & (lam >= lo) & (lam <= hi) & (np.linalg.norm(mean - centre, axis=1) <= cfg.eps)
        if near.any():
            out.append((name, int(near.sum()), lo, hi))
            left &= ~near
    return out


def _warn_circling(groups: list[tuple[str, int, float, float]], eps: float) -> None:
    """Said, not only stored: :func:`_circling`."""
    import warnings

    parts = "; ".join(f"{n} unclassified trajectories with exponents within {name}'s ({lo:.3g} to {hi:.3g}) and window "
                      f"means within eps = {eps:g} of it" for name, n, lo, hi in groups)
    warnings.warn(f"{parts}: probably trajectories still spiralling in, to it or to an equilibrium near it, left "
                  f"unclassified (their windows too far apart to group, or ending apart from it); raise [integrate] t1",
                  TransientWarning, stacklevel=3)


def _where(comps: list[str], x: np.ndarray) -> str:
    """``x = 0, y = -1.29e-12``: a state by its components."""
    return ", ".join(f"{c} = {float(v):.4g}" for c, v in zip(comps, x))


def _warn_unstable(groups: list[tuple[str, int, bool, str, float]]) -> None:
    """Said, not only stored: trajectories at (or lingering by) an unstable equilibrium, counted unclassified."""
    import warnings

    parts = "; ".join(f"{n} trajectories {'rest at' if rest else 'end by'} an unstable equilibrium at {where} (an "
                      f"eigenvalue with real part {g:.3g})" for n, rest, where, g in groups)
    warnings.warn(f"{parts}: no attractor -- a start on the stable manifold of a saddle (a basin boundary), or a "
                  f"trajectory still passing it at t1 (a heteroclinic cycle, a slow transient); counted unclassified. "
                  f"Raise [integrate] t1 to see where those still passing go", UnstableWarning, stacklevel=3)


class UnstableWarning(UserWarning):
    """Trajectories that came to rest at, or still linger by, an unstable equilibrium: counted unclassified."""


CHECK_MEMBERS = 12  # a fixed point's trajectories integrated again to see that they end at one place


def _ends_elsewhere(plan, disc: Attractors, again: Again, places: _Places, eps: float
                    ) -> list[tuple[str, int, list[str]]]:
    """Fixed points and limit cycles whose trajectories end at different places of the state space, though their
    observables' window features group them as one (x'' = x - x^3 - 0.3 x' observed through its energy alone: both
    wells were one fixed_point_1, "at x = -1"; two oscillators locked in phase or in antiphase, every component with
    the same mean, spread and range: one limit_cycle_1; each without a word). Of each, up to ``CHECK_MEMBERS``
    trajectories at one setting of the parameters that are not initial conditions (the setting most of them share;
    the representative first) are integrated again (:class:`Again`). Two fixed point's trajectories end apart when
    some state component's last values differ by more than ``REST_GAP`` times the larger of their window ranges
    there (at least the fixed-point stop's distance), as :func:`_apart` reads the observables; never two in a
    monotone approach, whose equilibrium lies beyond its window, nor two whose components differ by whole turns
    (2 pi): an angle seen through observables periodic in it (the pendulum observed through omega and sin theta
    rests at theta* + 2 pi k, one place to its observables). Two cycle's trajectories end apart when their orbits
    over the window, each closing on itself (:func:`_closes`), lie farther than ``eps`` apart (:func:`_orbit_distance`,
    each state component scaled by its largest window range among them, a component drifting over the window left
    out), as :func:`_continuum` compares orbits; an orbit that does not close (a window shorter than a period) is not
    compared. Returns (name,
    trajectories compared, the places where they end), for each found at more than one."""
    kinds = {q.name: q.kind for q in plan.system.params}
    labels = np.asarray(disc.labels).ravel()
    out = []
    for k, (t, rep) in enumerate(zip(disc.types, disc.representative)):
        members = np.flatnonzero(labels == k)
        if t not in ("fixed_point", "limit_cycle") or members.size < 2:
            continue
        p = plan.params_at(members)
        setting = [np.ascontiguousarray(v.reshape(members.size, -1)) for key, v in sorted(p.items())
                   if kinds.get(key) != "initial"]
        keys = [b"".join(v[i].tobytes() for v in setting) for i in range(members.size)]
        mine = keys[int(np.flatnonzero(members == rep)[0])] if rep in members else max(set(keys), key=keys.count)
        at = members[[key == mine for key in keys]]
        pick = np.random.default_rng(k).permutation(np.setdiff1d(at, [rep]))[:CHECK_MEMBERS - 1]
        chosen = [int(i) for i in ([rep] if rep in at else []) + list(pick)
                  if int(again(int(i)).attrs["solver_status"]) == 0]
        if len(chosen) < 2:
            continue
        windows = [again.states(i) for i in chosen]
        place, idx = (_fixed_places(windows, plan.icfg) if t == "fixed_point" else _cycle_places(windows, plan.icfg, eps))
        firsts = sorted(set(place[j] for j in idx), key=list(place).index)
        if len(firsts) < 2:
            continue
        if t == "fixed_point":
            said = [", ".join(f"{c} = {v:.4g}" for c, v in zip(places.comps, windows[q][-1])) + f" ({place.count(q)})"
                    for q in firsts]
        else:
            start = plan.params_at(np.array([chosen[q] for q in firsts]))
            init = [key for key in start if kinds.get(key) == "initial"]
            said = [f"{place.count(q)} on one orbit, one of them started at "
                    + ", ".join(f"{key} = {np.array2string(np.asarray(start[key])[n], precision=4)}" for key in init)
                    for n, q in enumerate(firsts)]
        out.append((disc.names[k], len(idx), said))
    return out


def _fixed_places(windows: list[np.ndarray], icfg) -> tuple[list[int], list[int]]:
    """Where trajectories of a fixed point end (:func:`_ends_elsewhere`): a place per trajectory (the index of the
    first one at it; chained), and the trajectories compared (all)."""
    ends, moves, mono = [], [], []
    for Y in windows:
        lo, hi = Y.min(axis=0), Y.max(axis=0)
        tol = icfg.atol + icfg.rtol * np.abs(Y[-1])
        still = (hi - lo) <= STOP_DISTANCE * tol
        ends.append(Y[-1])
        moves.append(np.maximum(hi - lo, STOP_DISTANCE * tol))
        mono.append(bool(np.all((Y[-1] == lo) | (Y[-1] == hi) | still)) and not np.all(still))
    ends, moves, mono = np.array(ends), np.array(moves), np.array(mono)
    gap = ends[:, None] - ends[None]
    turns = gap - 2.0 * np.pi * np.round(gap / (2.0 * np.pi))  # whole turns of an angle are no gap
    apart = np.any(np.minimum(np.abs(gap), np.abs(turns)) > REST_GAP * np.maximum(moves[:, None], moves[None]), axis=2)
    apart &= ~(mono[:, None] | mono[None])
    place = list(range(len(ends)))  # one place per group of trajectories not apart, chained
    for i in range(len(ends)):
        for j in range(i):
            if not apart[i, j]:
                a, b = place[i], place[j]
                place = [b if x == a else x for x in place]
    return place, list(range(len(ends)))


ORBIT_POINTS = 800  # points of each orbit compared (:func:`_cycle_places`)


def _cycle_places(windows: list[np.ndarray], icfg, eps: float) -> tuple[list[int], list[int]]:
    """Which orbit each trajectory of a limit cycle is on (:func:`_ends_elsewhere`): a place per trajectory (the
    index of the first one on its orbit, each compared with those firsts), and the trajectories compared (those whose
    orbit closes over the window)."""
    step = max(1, len(windows[0]) // ORBIT_POINTS)
    tol = icfg.atol + icfg.rtol * np.max([np.abs(Y).max(axis=0) for Y in windows], axis=0)
    scale = np.maximum(np.max([Y.max(axis=0) - Y.min(axis=0) for Y in windows], axis=0), 1000.0 * tol)
    # a component that drifts over the window (a running pendulum's angle: its two halves' means a quarter of its
    # range apart, where a periodic one's agree) is left out: its orbit never closes, and a small drift per period
    # fooled the closing test (the running cycle's members were five orbits)
    half = len(windows[0]) // 2
    keep = ~np.any([np.abs(Y[:half].mean(axis=0) - Y[half:].mean(axis=0)) > 0.25 * scale for Y in windows], axis=0)
    if not keep.any():
        return list(range(len(windows))), []
    orbits = [Y[::step, keep] / scale[keep] for Y in windows]
    idx = [i for i, o in enumerate(orbits) if _closes(o, eps)]
    place = list(range(len(orbits)))
    firsts: list[int] = []
    for i in idx:
        for q in firsts:
            if _orbit_distance(orbits[i], orbits[q]) <= eps:
                place[i] = q
                break
        else:
            firsts.append(i)
    return place, idx


def _warn_ends_elsewhere(groups: list[tuple[str, int, list[str]]], observables) -> None:
    """Said, not only stored: one name for trajectories that end at different places (:func:`_ends_elsewhere`)."""
    import warnings

    parts = "; ".join(f"{name}: {n} of its trajectories at one parameter setting, integrated again, end at "
                      f"{len(where)} places ({'; '.join(where)})" for name, n, where in groups)
    warnings.warn(f"{parts}: one name for trajectories that end apart in the state space, which the window "
                  f"features (mean, spread, range) of the observables ({', '.join(observables)}) do not tell apart; "
                  f"its basin fraction adds up several attractors. Observe what separates them (a state component, "
                  f"or a difference or product of components, that differs between them)", MixedWarning,
                  stacklevel=3)


class MixedWarning(UserWarning):
    """A discovered fixed point's or limit cycle's trajectories end at different places (equilibria, orbits) that
    its observables' window features do not separate."""


def _warn_still_moving(name: str, spread: float) -> None:
    import warnings

    warnings.warn(f"{name}: typed a fixed point while its representative still moves over the feature window (its "
                  f"state spans {spread:.3g} there), and no stable equilibrium was found inside that window: its "
                  f"position is where t1 left the representative; raise [integrate] t1", TransientWarning,
                  stacklevel=3)


def _again(plan, index: int, ts):
    """Trajectory ``index`` of ``plan`` integrated again on its own, saved at ``ts`` (diffrax, the plan's solver
    and tolerances: :func:`stabjax.engines.simulate.simulate`)."""
    from ..engines.simulate import simulate

    p = {k: np.asarray(v)[0] for k, v in plan.params_at(np.array([index])).items()}
    icfg = plan.icfg
    return simulate(plan.system, p, t1=icfg.t1, t0=icfg.t0, ts=ts, solver=icfg.solver, rtol=icfg.rtol,
                    atol=icfg.atol, max_steps=icfg.max_steps)


def representative_state(again: Again, index: int) -> np.ndarray:
    """The state at t1 of trajectory ``index``, integrated again on its own (:class:`Again`; t1 is its last save
    time); non-finite where that integration failed."""
    ds = again(index)
    if int(ds.attrs["solver_status"]) != 0:
        return np.full(again.plan.system.state_size, np.nan)
    return again.states(index)[-1]
