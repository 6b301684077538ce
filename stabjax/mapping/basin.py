"""Outcomes and basin stability of a finished plan, as dataset variables.

The engines return per-trajectory records (verdicts, late-window features, solver status);
this module turns them into the ``outcome`` variable (:func:`stabjax.model.outcomes.assign`) and, when
the plan samples (``[sample] n``), into per-grid-point basin stability: ``basin_count``,
``basin_fraction``, ``basin_se`` and the Wilson interval ``basin_ci_low`` / ``basin_ci_high``,
each over (grid axes..., ``outcome_name``). The per-grid-point statistics are reductions over the
sample axis, so their memory does not grow with N.

Templates (nearest-template outcomes) are integrated here, once per grid point, with the
plan's own settings and engine: the same code path as every sampled trajectory.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..model import outcomes as O
from ..fold import status as S

CHUNK = 262_144  # trajectories per host-side pass (parameters and features of a chunk in memory)


def _grid_points(plan) -> int:
    return int(np.prod([a.size for a in plan.grid])) if plan.grid else 1


def template_features(plan) -> np.ndarray | None:
    """(grid points, n_templates, n_features) feature vectors of the plan's templates, or None."""
    sch = plan.outcomes
    if sch is None or sch.decl is None or not sch.decl.templates:
        return None
    ns = max(plan.n_sample, 1)
    return template_features_at(plan, plan.params_at(np.arange(_grid_points(plan)) * ns))


def template_features_at(plan, base: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """Template feature vectors (P, n_templates, n_features) at P parameter points.

    ``base``: every parameter of one trajectory per point (its swept values); each template's
    overrides replace the initial conditions, and the templates run with the plan's settings.
    """
    sch = plan.outcomes
    if sch is None or sch.decl is None or not sch.decl.templates:
        return None
    from ..engines.simulate import solve_batch
    from ..plan.spec import static_params

    decl = sch.decl
    g = len(next(iter(base.values())))
    names = list(decl.templates)
    params = {k: np.concatenate([np.asarray(v)] * len(names)) for k, v in base.items()}
    for j, name in enumerate(names):
        over = plan.system.params.resolve(decl.templates[name])
        for k in decl.templates[name]:
            params[k][j * g:(j + 1) * g] = over[k]
    params = plan.system.check(params)
    varied = set().union(*[set(t) for t in decl.templates.values()])
    static = [k for k in static_params(plan) if k not in varied]
    res = solve_batch(plan.integrated, params, plan.icfg, plan.vcfg, static=static)
    feat = O.feature_getter(res, tuple(plan.system.observables))
    n = g * len(names)

    def par(name):
        return np.asarray(params[name], float).reshape(n)

    x = O.feature_matrix(decl, plan.system, feat, par)  # (T * P, F)
    ok = S.succeeded(np.asarray(res["solver_status"]))
    x = np.where(ok[:, None], x, np.nan)
    return x.reshape(len(names), g, -1).transpose(1, 0, 2)


def point_outcomes(plan, params: Mapping[str, np.ndarray], results: Mapping[str, np.ndarray],
                   n_points: int) -> np.ndarray:
    """Outcome codes of trajectories laid out point-major (each point's samples contiguous), as the
    boundary refinement evaluates them; templates are integrated at each point's parameters."""
    sch = plan.scheme
    if sch.from_verdicts:
        return O.assign(sch, plan.system, results, {})
    if sch.decl.discover:
        from ..errors import ValidationError

        raise ValidationError("outcomes.discover", "discovery groups a whole sweep's trajectories; refinement "
                              "needs declared outcomes (rules or templates)")
    n = len(np.asarray(results["solver_status"]))
    ns = n // n_points
    tf = template_features_at(plan, {k: np.asarray(v)[::ns] for k, v in params.items()})
    return O.assign(sch, plan.system, results, params, None if tf is None else np.repeat(tf, ns, axis=0))


def outcome_codes(plan, results: Mapping[str, np.ndarray], tf: np.ndarray | None = None) -> np.ndarray:
    """Outcome code of every trajectory of the plan (flat, C order), computed in chunks."""
    sch = plan.scheme
    n = plan.size
    if sch.from_verdicts:
        return O.assign(sch, plan.system, results, {})
    if tf is None:
        tf = template_features(plan)
    out = np.empty(n, np.int8)
    ns = max(plan.n_sample, 1)
    for lo in range(0, n, CHUNK):
        hi = min(n, lo + CHUNK)
        sl = {k: np.asarray(v)[lo:hi] for k, v in results.items()}
        p = plan.params_at(np.arange(lo, hi))
        tfi = None if tf is None else tf[np.arange(lo, hi) // ns]
        out[lo:hi] = O.assign(sch, plan.system, sl, p, tfi)
    return out


def dataset_vars(plan, results: Mapping[str, np.ndarray], tf: np.ndarray | None = None
                 ) -> tuple[dict[str, Any], dict[str, Any]]:
    """(data variables, coordinates) for the outcome and the basin statistics; ``tf``: the template
    features when already integrated (the sweep does it before the run, to check them first)."""
    sch = plan.scheme
    shape, dims = plan.shape, plan.dims
    tf = template_features(plan) if tf is None else tf
    extra: tuple[dict, dict] = ({}, {})
    if sch.decl is not None and sch.decl.discover:  # the outcomes are the attractors found (stabjax.mapping.discover)
        from . import discover

        codes, sch, *extra = discover.outcomes(plan, {k: np.asarray(v) for k, v in results.items()})
    else:
        codes = outcome_codes(plan, results, tf)
    flags = dict(flag_values=np.arange(len(sch.names), dtype=np.int8), flag_meanings=" ".join(sch.names),
                 flag_colors=" ".join(sch.colors))
    data: dict[str, Any] = {
        "outcome": (dims, codes.reshape(shape), {"long_name": "outcome of the trajectory", **flags}),
    }
    coords: dict[str, Any] = {"outcome_name": ("outcome_name", np.array(sch.names, dtype=object),
                                          {"long_name": "outcome name (code = index)"})}
    data.update(extra[0])
    coords.update(extra[1])
    from . import entropy
    from ..plan import starts

    data.update(starts.dataset_vars(plan, codes, list(sch.names)))

    if entropy.applies(plan):  # one start per cell of a 2-D grid of initial conditions: Daza et al. (2016)
        r = entropy.basin_entropy(codes.reshape(shape))
        meta = {"box": r["box"], "boxes": r["n_boxes"], "boundary_boxes": r["n_boundary_boxes"],
                "cells_used": r["cells_used"], "units": "nats"}
        data["basin_entropy"] = ((), r["S_b"], {"long_name": "basin entropy S_b (Daza et al. 2016)", **meta})
        data["boundary_basin_entropy"] = ((), r["S_bb"], {
            "long_name": "boundary basin entropy S_bb (> ln 2: fractal boundary, sufficient condition)", **meta})
    if tf is not None:
        gdims = tuple(a.name for a in plan.grid)
        gshape = tuple(a.size for a in plan.grid)
        data["template_features"] = ((*gdims, "template", "feature"), tf.reshape(*gshape, *tf.shape[1:]),
                                     {"long_name": "feature vectors of the templates at each grid point"})
        coords["template"] = ("template", np.array(list(sch.decl.templates), dtype=object))
        coords["feature"] = ("feature", np.array(list(sch.decl.features), dtype=object))
    if plan.n_sample:
        st = O.basin_stats(codes.reshape(shape), len(sch.names))
        gdims = tuple(a.name for a in plan.grid) + ("outcome_name",)
        n = plan.n_sample
        data["basin_count"] = (gdims, st["count"], {"long_name": f"trajectories per outcome (of N = {n})"})
        data["basin_fraction"] = (gdims, st["fraction"], {"long_name": f"basin stability S: fraction of N = {n} "
                                                                        "sampled trajectories"})
        data["basin_se"] = (gdims, st["se"], {"long_name": "standard error sqrt(S (1 - S) / N)"})
        data["basin_ci_low"] = (gdims, st["ci_low"], {"long_name": "95% Wilson score interval, lower end"})
        data["basin_ci_high"] = (gdims, st["ci_high"], {"long_name": "95% Wilson score interval, upper end"})
    return data, coords


def summary_rows(ds) -> list[tuple[str, int, float, float, float, float]]:
    """(outcome, count, S, SE, CI low, CI high) over the whole dataset (every grid point pooled)."""
    names = [str(x) for x in ds["outcome"].attrs["flag_meanings"].split()]
    codes = np.asarray(ds["outcome"].values).ravel()
    st = O.basin_stats(codes[None, :], len(names))
    return [(name, int(st["count"][0, k]), float(st["fraction"][0, k]), float(st["se"][0, k]),
             float(st["ci_low"][0, k]), float(st["ci_high"][0, k])) for k, name in enumerate(names)]
