"""The ``[refine]`` table of a spec, the lattice it defines over the grid, and the label of an evaluated point.

A refinement (:mod:`stabjax.explore.refine`) cuts each coarse interval of axis ``a`` into ``2**L_a`` parts, ``L_a``
the fewest halvings that bring every interval to the tolerance ``tol_a`` (log axes in log space). A point's
label is its verdict (escape counted as diverged, :mod:`stabjax.fold.status`) or its named outcome, dominant over
its samples, at each verdict horizon the refinement brackets (``horizon = t``: one; ``horizons = "all"`` or a
list: several, from the same runs). Kept apart from the refiner so that the table can be checked, and the
lattice rebuilt (the refinement benchmark), without the explorer or the runner.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..fold import verdict as V
from ..errors import StabjaxError, ValidationError
from ..plan.spec import Plan
from ..fold.status import verdicts as status_verdicts
from ..validate import integer as _integer, number as _number

REFINE_KEYS = ("tol", "rel_tol", "pair", "stable", "label", "horizon", "horizons", "max_points")
DEFAULT_REL_TOL = 1 / 64
MAX_LATTICE = 1 << 28  # lattice sites held as labels in memory (int16): 0.5 GiB at most
ANY = "*"

# ---- configuration ------------------------------------------------------------------------------


@dataclass(frozen=True)
class RefineConfig:
    """The validated ``[refine]`` table, resolved against the plan's grid."""

    tol: tuple[float, ...]  # per grid axis, parameter units
    levels: tuple[int, ...]  # halvings of each coarse interval
    label: str  # results key giving the label: "verdict" or "outcome"
    names: tuple[str, ...]  # label code -> name
    pair: tuple[str, str] | None
    stable: str | None  # the label whose region is compared with the theorem's
    horizons: tuple[float, ...]  # the verdict horizons bracketed, ascending (one per run of the runner: the
    # runner returns every horizon's verdict, so bracketing several costs only the points where they differ)
    max_points: int

    @property
    def horizon(self) -> float:
        """The longest horizon bracketed: the one ``point_label`` reports."""
        return self.horizons[-1]


def label_names(plan: Plan, label: str) -> tuple[str, ...]:
    """Names of the label codes: verdict names, or the system's declared outcomes."""
    if label == "verdict":
        return tuple(V.NAMES)
    if plan.mapper.uses_verdicts:
        raise ValidationError("refine.label", f"{plan.system.name} declares no named outcomes; use label = \"verdict\"")
    return tuple(plan.scheme.names)


def horizon_times(plan: Plan) -> np.ndarray:
    """The verdict horizons of the plan (absolute times, ascending, last = t1)."""
    return np.asarray(V.horizon_times(plan.vcfg, plan.icfg.t0, plan.icfg.t1), dtype=float)


def refine_config(plan: Plan, raw: Mapping[str, Any] | None = None) -> RefineConfig:
    """Validate ``[refine]`` (default: ``plan.spec["refine"]``) against the plan's grid."""
    raw = plan.spec.get("refine", {}) if raw is None else raw
    if not isinstance(raw, Mapping):
        raise ValidationError("refine", "must be a table")
    unknown = sorted(set(raw) - set(REFINE_KEYS))
    if unknown:
        raise ValidationError(f"refine.{unknown[0]}", f"unknown field; known: {', '.join(REFINE_KEYS)}")
    if not 1 <= len(plan.grid) <= 2:
        raise ValidationError("grid", f"refinement needs one or two grid axes (the coarse grid), got {len(plan.grid)}")
    for ax in plan.grid:
        if ax.values.ndim != 1:
            raise ValidationError(f"grid.{ax.key}", "refinement needs scalar axes (sweep one entry like \"J[0]\")")
        if ax.size < 2:
            raise ValidationError(f"grid.{ax.key}", "refinement needs at least 2 values per axis")
        d = np.diff(ax.values)
        if not (np.all(d > 0) or np.all(d < 0)):
            raise ValidationError(f"grid.{ax.key}", "refinement needs strictly monotone axis values")

    rel = None
    if "rel_tol" in raw:
        rel = _number(raw["rel_tol"], "refine.rel_tol")
        if not 0 < rel <= 1:
            raise ValidationError("refine.rel_tol", f"must be in (0, 1] (a fraction of each axis range), got {rel}")
    tol_raw = raw.get("tol")
    per_axis: dict[str, float] = {}
    if tol_raw is not None:
        if isinstance(tol_raw, Mapping):
            names = {ax.key: ax for ax in plan.grid} | {ax.name: ax for ax in plan.grid}
            for k, v in tol_raw.items():
                if k not in names:
                    raise ValidationError(f"refine.tol.{k}", f"not a grid axis; axes: {', '.join(a.key for a in plan.grid)}")
                per_axis[names[k].name] = _number(v, f"refine.tol.{k}")
        else:
            v = _number(tol_raw, "refine.tol")
            per_axis = {ax.name: v for ax in plan.grid}
        for k, v in per_axis.items():
            if not v > 0:
                raise ValidationError(f"refine.tol.{k}" if isinstance(tol_raw, Mapping) else "refine.tol",
                                      f"must be > 0, got {v}")
    if rel is None and tol_raw is None:
        rel = DEFAULT_REL_TOL
    tols, levels = [], []
    for ax in plan.grid:
        if ax.name in per_axis:
            t = per_axis[ax.name]
        elif rel is not None:
            t = rel * abs(float(ax.values[-1] - ax.values[0]))
        else:
            raise ValidationError("refine.tol", f"no tolerance for axis {ax.key!r}: give it here or set rel_tol")
        tols.append(float(t))
        # the field the user set is the one named: rel_tol, or the axis's tol
        field = (("refine.tol." + ax.name) if isinstance(tol_raw, Mapping) else "refine.tol") \
            if ax.name in per_axis else "refine.rel_tol"
        levels.append(_levels(ax.values, ax.log, t, field))

    label = raw.get("label")
    if label is None:
        label = "verdict" if plan.mapper.uses_verdicts else "outcome"
    if label not in ("verdict", "outcome"):
        raise ValidationError("refine.label", f"must be \"verdict\" or \"outcome\", got {label!r}")
    if label == "verdict" and not plan.mapper.uses_verdicts:
        raise ValidationError("refine.label", f"{plan.system.name}'s outcomes are named (rules, templates, discovery): "
                                              "it has no attitude verdicts; use label = \"outcome\"")
    if label == "outcome" and plan.mapper.whole_set:  # refused before any round is integrated
        raise ValidationError("outcomes.discover", "discovery groups a whole sweep's trajectories; refinement "
                              "needs declared outcomes (rules or templates)")
    names = label_names(plan, label)

    pair = raw.get("pair")
    if pair is not None:
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
            raise ValidationError("refine.pair", f"must be two outcome names, e.g. [\"converged\", \"flipped\"], got {pair!r}")
        if pair[0] not in names:
            raise ValidationError("refine.pair", f"unknown outcome {pair[0]!r}; known: {', '.join(names)}")
        if pair[1] != ANY and pair[1] not in names:
            raise ValidationError("refine.pair", f"unknown outcome {pair[1]!r}; known: {', '.join(names)} (or \"*\")")
        if pair[0] == pair[1]:
            raise ValidationError("refine.pair", "needs two different outcomes")
        pair = (pair[0], pair[1])
    stable = raw.get("stable")
    if stable is not None:
        if not isinstance(stable, str) or stable not in names:
            raise ValidationError("refine.stable", f"must name an outcome ({', '.join(names)}), got {stable!r}")
    else:  # the outcome the main theorem says it guarantees, else the pair's first, else converged
        stable = _guaranteed(plan) if label == "outcome" else None
        stable = stable or (pair[0] if pair else ("converged" if "converged" in names else None))

    horizons = _horizons(plan, raw, label)
    max_points = _integer(raw.get("max_points", 1_000_000), "refine.max_points", lo=1, hi=None)
    size = int(np.prod([(ax.size - 1) * 2**L + 1 for ax, L in zip(plan.grid, levels)]))
    if size * len(horizons) > MAX_LATTICE:  # one label per site and horizon
        raise ValidationError("refine.tol", f"the finest lattice would hold {size:,} points x {len(horizons)} "
                              f"horizon(s) (limit {MAX_LATTICE:,} labels); use a coarser tolerance")
    return RefineConfig(tol=tuple(tols), levels=tuple(levels), label=label, names=names, pair=pair, stable=stable,
                        horizons=horizons, max_points=int(max_points))


def _horizon(plan: Plan, value, field: str) -> float:
    """One horizon time, checked: in (t0, t1] and one of the plan's verdict horizons (t1 always is)."""
    t0, t1 = plan.icfg.t0, plan.icfg.t1
    h = _number(value, field)
    if not t0 < h <= t1:
        raise ValidationError(field, f"must be in (t0, t1] = ({t0:g}, {t1:g}], got {h:g}")
    hs = horizon_times(plan)
    if h != t1:
        match = np.nonzero(np.isclose(hs, h, rtol=1e-12, atol=0))[0]
        if not len(match):
            raise ValidationError(field, f"{h:g} is not one of the verdict horizons ({', '.join(f'{x:g}' for x in hs)})")
        h = float(hs[match[0]])
    return float(h)


def _horizons(plan: Plan, raw: Mapping[str, Any], label: str) -> tuple[float, ...]:
    """The horizons a refinement brackets: ``horizon = t`` (one), ``horizons = "all"`` (every verdict horizon
    of the plan) or ``horizons = [t, ...]``; default t1. Named outcomes have one horizon (t1)."""
    if "horizon" in raw and "horizons" in raw:
        raise ValidationError("refine.horizons", "give horizon (one) or horizons (several), not both")
    if "horizons" in raw:
        v = raw["horizons"]
        if label != "verdict":
            raise ValidationError("refine.horizons", "several horizons need label = \"verdict\" (named outcomes are "
                                  "decided once, at t1)")
        if v == "all":
            return tuple(float(h) for h in horizon_times(plan))
        if not isinstance(v, list) or not v:
            raise ValidationError("refine.horizons", f"must be \"all\" or a non-empty list of horizon times, got {v!r}")
        hs = sorted({_horizon(plan, x, f"refine.horizons[{i}]") for i, x in enumerate(v)})
        return tuple(hs)
    if "horizon" in raw:
        return (_horizon(plan, raw["horizon"], "refine.horizon"),)
    return (float(plan.icfg.t1),)


def fine_values(coarse: np.ndarray, log: bool, level: int) -> np.ndarray:
    """The lattice of one axis: each coarse interval cut into 2**level equal parts (in log for log axes)."""
    c = np.log(coarse) if log else np.asarray(coarse, float)
    k = 2**level
    frac = np.arange(k) / k
    v = (c[:-1, None] + frac[None, :] * np.diff(c)[:, None]).ravel()
    v = np.append(v, c[-1])
    v = np.exp(v) if log else v
    v[::k] = coarse  # the coarse grid's own values, bit for bit (round 0 = the plain sweep's grid)
    return v


def _max_width(coarse: np.ndarray, log: bool, level: int) -> float:
    """Widest lattice interval at ``level`` (log axes: the part next to each coarse interval's larger end)."""
    c = np.asarray(coarse, float)
    if not log:
        return float(np.max(np.abs(np.diff(c))) / 2**level)
    a, b = np.minimum(c[:-1], c[1:]), np.maximum(c[:-1], c[1:])
    return float(np.max(b - b * (a / b) ** (1.0 / 2**level)))


def _levels(coarse: np.ndarray, log: bool, tol: float, field: str = "refine.tol") -> int:
    for level in range(0, 31):
        if _max_width(coarse, log, level) <= tol * (1 + 1e-9):
            return level
    what = f"a tolerance of {tol:g} on this axis" if field == "refine.rel_tol" else f"{tol:g}"
    raise ValidationError(field, f"{what} needs more than 30 halvings of the coarse grid")


# ---- labels -------------------------------------------------------------------------------------


def _labels(plan: Plan, cfg: RefineConfig, res: Mapping[str, np.ndarray], n_points: int):
    """Per-point label (dominant over samples) and the fraction of samples carrying it, at each horizon of
    ``cfg.horizons``: two (n_points, n_horizons) arrays."""
    if cfg.label not in res:
        raise StabjaxError(f"the engine returned no {cfg.label!r} (refine.label)")
    lab = np.asarray(res[cfg.label])
    if cfg.label == "verdict":  # an escaped point is diverged, as in a sweep (one rule: stabjax.fold.status)
        lab = status_verdicts(np.asarray(res["solver_status"]), lab)
    if lab.ndim == 1:  # one label per trajectory (named outcomes, or a single-horizon engine): at t1
        if any(h != plan.icfg.t1 for h in cfg.horizons):
            raise StabjaxError(f"the results hold one {cfg.label} per trajectory (at t1) but the refinement asks "
                               f"for horizons {list(cfg.horizons)}")
        lab = np.repeat(lab[:, None], len(cfg.horizons), axis=1)
    else:  # (N, n_horizons): horizons ascending, last = t1
        hs = horizon_times(plan)
        if len(hs) == lab.shape[1]:
            cols = [int(np.argmin(np.abs(hs - h))) for h in cfg.horizons]
        elif all(h == plan.icfg.t1 for h in cfg.horizons):
            cols = [lab.shape[1] - 1] * len(cfg.horizons)
        else:
            raise StabjaxError(f"results hold {lab.shape[1]} horizons but the plan does not say which times")
        lab = lab[:, cols]
    lab = lab.astype(np.int64).reshape(n_points, -1, len(cfg.horizons))  # (points, samples, horizons)
    k = len(cfg.names)
    counts = np.stack([(lab == c).sum(axis=1) for c in range(k)], axis=-1)  # (points, horizons, codes)
    dom = counts.argmax(axis=-1)  # ties: the lower code
    return dom.astype(np.int16), counts.max(axis=-1) / lab.shape[1]


def classes(cfg: RefineConfig) -> np.ndarray:
    """Label code -> class for boundary tests (-1: not part of any boundary)."""
    k = len(cfg.names)
    if cfg.pair is None:
        return np.arange(k)
    cls = np.full(k, -1)
    a = cfg.names.index(cfg.pair[0])
    if cfg.pair[1] == ANY:
        cls[:] = 1
    else:
        cls[cfg.names.index(cfg.pair[1])] = 1
    cls[a] = 0
    return cls


def _guaranteed(plan) -> str | None:
    """The named outcome the system's main theorem guarantees (``Predicate(..., outcome=...)``), or None."""
    th = plan.system.theory(plan.system.check(plan.params_for(0, 1)))
    pred = th.predicates.get(th.main) if th.main else None
    return (pred.outcome or None) if pred is not None else None
