"""Attractors found from the trajectories themselves: featurise, scale, group, type and name (the
whole-set outcome mapper :class:`Discovery`, :mod:`stabjax.mapping.mapper`).

A model that declares no outcomes rules (or a spec with ``[outcomes] discover = true``) gets its
outcomes here, after every trajectory of the sweep has run (the grouping pools all grid points,
so an attractor keeps one name across the grid, as Attractors.jl's ``FeaturizeGroupAcrossParameter``).

1. **Features** (what the fold already computes, no extra cost): per observable, the mean, standard
   deviation, minimum and maximum over the late window ``[t0 + (1 - window)(t1 - t0), t1]``.
2. **Scaling**: every feature of observable k is divided by the range that observable covers over
   the whole sweep (max of its window maxima minus min of its window minima). Per *observable*, not
   per feature: a z-score per feature (pyBasin) would blow the solver noise in the window std of
   fixed points (1e-12) up to unit size; per observable no observable dominates by its units and
   the noise stays noise. A range is never taken below 10^4 solver tolerances
   (:func:`observable_ranges`): an observable every trajectory brings to the same value carries
   only noise.
3. **Grouping**: scikit-learn's DBSCAN (Ester et al. 1996) with radius ``eps`` (fraction of each
   observable's range) and ``min_samples``, on a random subsample of ``subsample`` trajectories;
   every trajectory then takes the label of its nearest core sample if that lies within ``eps``
   (DBSCAN's own border rule, so the result is the one DBSCAN would give on the subsample plus
   border points). Trajectories farther than ``eps`` from every core sample are grouped again among
   themselves (a small basin missed by the subsample is found there), until none is left or no
   group forms; a trajectory left over within ``eps`` of a grouped one joins its group (the
   subsample is sparser than the whole set, whose DBSCAN would have made it a border point); the
   rest is ``unclassified`` (e.g. trajectories still in a transient). Linear in N
   after the subsample: 10^5 trajectories take about a second (``docs/performance.md``).
   Why DBSCAN and not HDBSCAN (pyBasin's default) or recurrences (Attractors.jl): a chaotic
   attractor's features scatter between finite windows but form one connected cloud, which
   density-connectivity keeps whole at any radius above the sampling gaps, while two attractors
   whose feature clouds are more than ``eps`` apart are never joined; HDBSCAN's cluster selection
   may split a cloud of uneven density and turns basins smaller than its ``min_cluster_size``
   into noise; the recurrence finite-state machine needs a state-space grid and runs trajectories
   one after the other (a vmapped batch engine runs them all at once).
4. **Types** per group (pyBasin's ``DynamicalSystemClusterer`` idea, thresholds stated):
   ``fixed_point`` when the median window std of every observable is below ``fixed_point_tol``
   times its range; else ``chaotic`` when the median largest Lyapunov exponent
   (:mod:`stabjax.model.tangent`) is above ``chaos_threshold``; else ``limit_cycle`` (a periodic or
   quasi-periodic motion: its exponent is 0 for autonomous flows, negative for forced ones).
   Without the exponent (``lyapunov = false``) a non-stationary group is ``attractor``.
   Names: the type and a number, ``fixed_point_1``, ``limit_cycle_1``, ``chaotic_1``, ... numbered
   by decreasing basin size within each type.
5. **Along a parameter** (one ``[grid]`` axis with ``[sample]``): each grid point is grouped on its
   own and the attractors of neighbouring points are matched by the distance between their
   representatives (:mod:`stabjax.mapping.continuation`, Attractors.jl's global continuation), so
   ``basin_fraction`` along the axis follows one attractor and births and deaths are reported
   (``attractor_events``). ``continuation = false`` groups all points together instead.
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
from ..model.outcomes import FAILED_NAME, UNCLASSIFIED, DiscoveryConfig  # [outcomes.discovery]: the declaration's
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


def feature_table(results: Mapping[str, np.ndarray], observables: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """(N, 4 n_obs) late-window features and their names (``mean(x)``, ...)."""
    cols, names = [], []
    for k, o in enumerate(observables):
        for s in STATS:
            cols.append(np.asarray(results[f"feat_{s}"], float)[:, k])
            names.append(f"{s}({o})")
    return np.stack(cols, axis=1), names


NOISE_FACTOR = 1e4  # differences below this many solver tolerances are numerical, not dynamical


def observable_ranges(results, valid: np.ndarray, n_obs: int, atol: float = 0.0, rtol: float = 0.0) -> np.ndarray:
    """Range of each observable over the valid trajectories' windows, at least ``NOISE_FACTOR``
    tolerances (atol + rtol max|value|): an observable that every trajectory brings to the same
    value (a velocity at rest) must not blow its solver noise up to the size of a real difference.
    Measured: Tsit5 at rtol = atol = 1e-8 stays 4e-5 (4000 tolerances) from a weakly stable focus
    (Lorenz r = 24.4), the controller holding the step where the oscillation is barely damped."""
    lo = np.asarray(results["feat_min"], float)[valid, :n_obs]
    hi = np.asarray(results["feat_max"], float)[valid, :n_obs]
    if lo.shape[0] == 0:
        return np.ones(n_obs)
    r = np.nanmax(hi, axis=0) - np.nanmin(lo, axis=0)
    big = np.maximum(np.nanmax(np.abs(hi), axis=0), np.nanmax(np.abs(lo), axis=0))
    floor = NOISE_FACTOR * (atol + rtol * np.where(np.isfinite(big), big, 0.0))
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


def discover(results: Mapping[str, np.ndarray], observables: tuple[str, ...], cfg: DiscoveryConfig,
             valid: np.ndarray, atol: float = 0.0, rtol: float = 0.0) -> Attractors:
    """Group the ``valid`` trajectories (reached t1, finite features) of ``results`` into attractors;
    ``atol``, ``rtol``: the solver's tolerances (the noise floor of the feature scales)."""
    n_obs = len(observables)
    feats, fnames = feature_table(results, observables)
    valid = np.asarray(valid, bool) & np.all(np.isfinite(feats), axis=1)
    scale = observable_ranges(results, valid, n_obs, atol, rtol)
    x = feats / np.repeat(scale, len(STATS))[None, :]
    idx = np.flatnonzero(valid)
    lab_v, stats = group(x[idx], cfg)
    lam_all = np.asarray(results["lyapunov"], float) if "lyapunov" in results else None
    groups = [idx[lab_v == g] for g in range(int(lab_v.max()) + 1 if lab_v.size else 0)]
    groups = [g for g in groups if g.size]
    return _named(groups, feats, fnames, x, scale, lam_all, cfg, stats)


def _describe(g: np.ndarray, feats, x, scale, lam_all, cfg: DiscoveryConfig):
    """(type, median features, median exponent, representative index) of one group of trajectories."""
    n_obs = len(scale)
    std_cols = [k * len(STATS) + 1 for k in range(n_obs)]
    med = np.median(feats[g], axis=0)
    rel_std = med[std_cols] / scale
    lam = float(np.nanmedian(lam_all[g])) if lam_all is not None and np.isfinite(lam_all[g]).any() else math.nan
    if np.all(rel_std < cfg.fixed_point_tol):
        kind = "fixed_point"
    elif lam_all is None:
        kind = "attractor"
    elif lam > cfg.chaos_threshold:
        kind = "chaotic"
    else:
        kind = "limit_cycle"
    xm = np.median(x[g], axis=0)
    rep = int(g[np.argmin(np.linalg.norm(x[g] - xm, axis=1))])
    return kind, med, lam, rep


def _named(groups, feats, fnames, x, scale, lam_all, cfg, stats, kinds=None) -> Attractors:
    """Name and order the groups (type, then decreasing size); ``kinds``: given types (continuation)."""
    typed = []
    for i, g in enumerate(groups):
        kind, med, lam, rep = _describe(g, feats, x, scale, lam_all, cfg)
        kind = kinds[i] if kinds is not None else kind
        typed.append((TYPES.index(kind), -g.size, kind, g, med, lam, rep))
    typed.sort(key=lambda r: (r[0], r[1], r[6]))
    labels = np.full(len(feats), -1, np.int64)
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
    stats.update(n_grouped=int((labels >= 0).sum()))
    return Attractors(labels=labels, names=names, types=types, counts=np.asarray(counts, np.int64),
                     features=np.asarray(fmed).reshape(len(names), len(fnames)), feature_names=fnames,
                     lyapunov=np.asarray(lams, float), representative=np.asarray(reps, np.int64), scale=scale,
                     stats=stats)


def _continued(results, observables, cfg: DiscoveryConfig, valid: np.ndarray, n_points: int,
               atol: float = 0.0, rtol: float = 0.0) -> tuple[Attractors, list[dict[str, Any]]]:
    """Attractors followed along one grid axis: each point grouped on its own (:func:`group`, features
    scaled by the whole sweep's ranges so distances compare between points), then matched from point to
    point by :func:`stabjax.mapping.continuation.match_sequentially`. Trajectories are laid out point-major
    (``n_points`` grid points, the same number of samples each). Returns the discovery (labels over all
    trajectories) and the births and deaths (:func:`stabjax.mapping.continuation.events`)."""
    from . import continuation as C

    n_obs = len(observables)
    feats, fnames = feature_table(results, observables)
    valid = np.asarray(valid, bool) & np.all(np.isfinite(feats), axis=1)
    scale = observable_ranges(results, valid, n_obs, atol, rtol)
    x = feats / np.repeat(scale, len(STATS))[None, :]
    lam_all = np.asarray(results["lyapunov"], float) if "lyapunov" in results else None
    per = len(feats) // n_points
    found: list[list[C.Found]] = []
    for k in range(n_points):
        idx = np.arange(k * per, (k + 1) * per)
        idx = idx[valid[idx]]
        local = []
        if idx.size:
            lab, _ = group(x[idx], cfg)
            for g in range(int(lab.max()) + 1 if lab.size else 0):
                gi = idx[lab == g]
                if gi.size:
                    kind, _, _, rep = _describe(gi, feats, x, scale, lam_all, cfg)
                    local.append(C.Found(gi, kind, x[rep]))
        found.append(local)
    ids, spans = C.match_sequentially(found, cfg.match_threshold)
    groups, kinds = C.merged(found, ids, len(spans))
    majority = [max(TYPES, key=lambda t: (ks.count(t), -TYPES.index(t))) for ks in kinds]
    disc = _named(groups, feats, fnames, x, scale, lam_all, cfg, {"points": n_points}, kinds=majority)
    names = [disc.names[int(disc.labels[g[0]])] for g in groups]
    return disc, C.events(spans, names, n_points)


# ---- the mapper -------------------------------------------------------------------------------------


class Discovery(Mapper):
    """The outcomes are the attractors found in the whole sweep's features (a whole-set mapper; see the
    module docstring). Before the run its scheme holds the fates alone (escape, unclassified, failed)."""

    kind = "discovery"
    whole_set = True

    def __init__(self, decl, escape: bool):
        self.escape = bool(escape)
        self.cfg = DiscoveryConfig.from_dict(decl.discovery or {})
        self.scheme = OutcomeScheme(*outcome_names(decl, (), self.escape), decl)

    def map_set(self, plan, results: Mapping[str, np.ndarray], state: Any = None) -> Mapped:
        """The attractors of every trajectory's results: codes, the scheme with the attractors' names, and
        the attractors' variables."""
        from ..fold import status as S

        decl, cfg = self.decl, self.cfg
        status = np.asarray(results["solver_status"])
        events = None
        if cfg.continuation and len(plan.grid) == 1 and plan.n_sample:
            disc, events = _continued(results, tuple(plan.system.observables), cfg, status == 0, plan.grid[0].size,
                                      plan.icfg.atol, plan.icfg.rtol)
        else:
            disc = discover(results, tuple(plan.system.observables), cfg, status == 0, plan.icfg.atol, plan.icfg.rtol)
        names, colors = outcome_names(decl, tuple(disc.names), self.escape)
        if len(names) > 127:
            raise ValidationError("outcomes.discovery", f"{len(disc.names)} attractors found: more than the outcome "
                                  "codes hold; raise eps or min_samples")
        code = np.where(disc.labels >= 0, disc.labels, names.index(UNCLASSIFIED))
        ok = status == 0
        if self.escape:
            code = np.where(status == S.ESCAPED, names.index(decl.escape), code)
            ok = ok | (status == S.ESCAPED)
        code = np.where(ok, code, names.index(FAILED_NAME)).astype(np.int8)
        data, coords = _attractor_vars(plan, disc, results, cfg)
        if events is not None:
            ax = plan.grid[0]
            ev = [{**e, ax.name: float(ax.values[e["index"]])} for e in events]
            data["attractor_events"] = ((), json.dumps(ev), {
                "long_name": f"births and deaths of attractors along {ax.name} (JSON: attractor, event, first grid "
                             f"index where it is present (birth) or absent again (death), the {ax.name} value there)"})
        return Mapped(code, OutcomeScheme(names, colors, decl), data, coords)


def _attractor_vars(plan, disc: Attractors, results, cfg: DiscoveryConfig):
    a = len(disc.names)
    comps = [f"{name}" if not shape else f"{name}_{'_'.join(map(str, i))}"
             for name, shape in plan.system.state for i in (np.ndindex(shape) if shape else [()])]
    states = np.full((a, len(comps)), np.nan)
    for k, rep in enumerate(disc.representative):
        states[k] = representative_state(plan, int(rep))
    starts = plan.params_at(disc.representative) if a else {}
    varied = [ax.param.name for ax in plan.grid] + list(plan.sample) if a else []
    n_obs = len(plan.system.observables)
    final = np.asarray(results["feat_final"], float)[disc.representative, :n_obs] if a else np.zeros((0, n_obs))
    data = {
        "attractor_type": ("attractor", np.array(disc.types, dtype=object),
                           {"long_name": "fixed_point (window std ~ 0), chaotic (lyapunov > threshold), "
                                         "limit_cycle (else), attractor (no exponent)"}),
        "attractor_count": ("attractor", disc.counts, {"long_name": "trajectories grouped into the attractor "
                                                                    "(all grid points)"}),
        "attractor_features": (("attractor", "attractor_feature"), disc.features,
                               {"long_name": "median late-window features of the attractor's trajectories"}),
        "attractor_lyapunov": ("attractor", disc.lyapunov,
                               {"long_name": "median largest Lyapunov exponent of its trajectories"}),
        "attractor_representative": ("attractor", disc.representative,
                                     {"long_name": "flat index of the trajectory nearest the median features"}),
        "attractor_state": (("attractor", "state_component"), states,
                            {"long_name": "state at t1 of the representative trajectory (re-integrated)"}),
        "attractor_observables": (("attractor", "observable"), final,
                                  {"long_name": "observables of the representative trajectory at t1"}),
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


def representative_state(plan, index: int) -> np.ndarray:
    """The state at t1 of trajectory ``index`` of ``plan``, integrated on its own (diffrax, the plan's
    solver and tolerances)."""
    from ..engines.simulate import simulate

    p = {k: np.asarray(v)[0] for k, v in plan.params_at(np.array([index])).items()}
    icfg = plan.icfg
    ds = simulate(plan.system, p, t1=icfg.t1, t0=icfg.t0, ts=[icfg.t1], solver=icfg.solver, rtol=icfg.rtol,
                  atol=icfg.atol, max_steps=icfg.max_steps)
    return np.concatenate([np.ravel(ds[name].values[-1]) for name, _ in plan.system.state])
