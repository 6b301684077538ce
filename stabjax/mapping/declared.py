"""Declared outcomes: rules, then templates, then escape (the mapper of a model's ``Outcomes``).

The declaration and its rule language are the model's (:mod:`stabjax.model.outcomes`); this module
assigns them. Codes are, in this order (first match wins):

1. the **rule** outcomes, in declaration order: the first rule that holds over the trajectory's
   late-window features;
2. the **template** outcomes: each template is an initial condition integrated with the plan's own
   settings and engine at every grid point (:func:`template_features_at`, before the first trajectory
   of the run); a trajectory no rule claimed takes the template whose feature vector is nearest, if
   that distance is at most ``max_distance`` (default: half the smallest distance between two
   templates' feature vectors at that point, so the assignment is never a close call between two);
3. the **escape** outcome (``escaped``, or as ``escape`` names it) when the plan has an escape radius
   and the trajectory left it;
4. ``unclassified``: no rule holds and no template is near; 5. ``failed``: the solver did not reach t1,
   or an observable that a rule or a template feature reads is not finite in the window.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..errors import ValidationError
from ..fold import status as S
from ..model.outcomes import (FAILED_NAME, UNCLASSIFIED, Outcomes, _names, feature_getter, feature_matrix,
                              finite_features, parse)
from .mapper import Mapper, OutcomeScheme, grid_layout, outcome_names

COINCIDE_RTOL = 1e-6  # feature vectors this close (relative to their size) are one attractor


class Declared(Mapper):
    """Rules + templates + escape (a per-trajectory mapper); its state is the templates' feature vectors
    at every grid point, (grid points, templates, features), or None without templates."""

    kind = "declared"

    def __init__(self, system, decl: Outcomes, escape: bool):
        names, colors = outcome_names(decl, tuple(decl.rules) + tuple(decl.templates), escape)
        self.scheme = OutcomeScheme(names, colors, decl)

    def prepare(self, plan) -> np.ndarray | None:
        if not self.decl.templates:
            return None
        ns = max(plan.n_sample, 1)
        return self.prepare_at(plan, plan.params_at(np.arange(plan.size // ns) * ns))

    def check(self, plan, tf) -> None:
        """Two templates that coincide somewhere are refused (naming them, the point and their distance):
        otherwise the default ``max_distance`` is zero there and every trajectory ends "unclassified"
        without a word, after the whole run (issue 22, item 6)."""
        hit = None if tf is None else coinciding_templates(self.decl, tf)
        if hit is None:
            return
        p, a, b, d = hit
        where = ""
        if plan.grid:
            idx = np.unravel_index(p, grid_layout(plan)[1])
            where = " at " + ", ".join(f"{ax.name} = {np.asarray(ax.values[i]).tolist()}" for ax, i in zip(plan.grid, idx))
        raise ValidationError("outcomes.templates", f"templates {a!r} and {b!r} coincide{where} (feature distance "
                              f"{d:.3g}): they reach the same attractor, so no trajectory there could be told between "
                              "them; drop one, or choose initial conditions in different basins")

    def assign(self, plan, results, index, tf) -> np.ndarray:
        ns = max(plan.n_sample, 1)
        return self.label(plan, results, plan.params_at(index), None if tf is None else tf[index // ns])

    def prepare_at(self, plan, base) -> np.ndarray | None:
        return template_features_at(plan, base) if self.decl.templates else None

    def label(self, plan, results, params, tf) -> np.ndarray:
        return assign(self.scheme, plan.system, results, params, tf)

    def variables(self, plan, tf) -> tuple[dict[str, Any], dict[str, Any]]:
        if tf is None:
            return {}, {}
        gdims, gshape = grid_layout(plan)
        data = {"template_features": ((*gdims, "template", "feature"), tf.reshape(*gshape, *tf.shape[1:]),
                                      {"long_name": "feature vectors of the templates at each grid point"})}
        coords = {"template": ("template", np.array(list(self.decl.templates), dtype=object)),
                  "feature": ("feature", np.array(list(self.decl.features), dtype=object))}
        return data, coords


def assign(sch: OutcomeScheme, system, results: Mapping[str, np.ndarray], params: Mapping[str, np.ndarray],
           template_features: np.ndarray | None = None) -> np.ndarray:
    """Outcome codes (int8, shape (N,)) of N trajectories under the declaration ``sch.decl``.

    ``results``: the engine's per-trajectory arrays (``solver_status``, ``feat_*``); ``params``: their
    parameters (N, ...); ``template_features``: (N, n_templates, n_features), the feature vectors of the
    templates integrated at each trajectory's grid point.
    """
    decl = sch.decl
    status = np.asarray(results["solver_status"])
    n = status.shape[0]
    code = np.full(n, -1, np.int16)
    names = sch.names
    feat = feature_getter(results, tuple(system.observables))

    def par(name):
        return np.asarray(params[name], float).reshape(n)

    obs, scalars = _names(system)
    for i, (name, text) in enumerate(decl.rules.items()):
        hit = np.broadcast_to(parse(text, obs, scalars, f"outcomes.rules.{name}")(feat, par), (n,))
        code = np.where((code < 0) & hit, i, code)
    if decl.templates and template_features is not None:
        x = feature_matrix(decl, system, feat, par)  # (N, F)
        d = np.linalg.norm(x[:, None, :] - template_features, axis=-1)  # (N, T)
        d = np.where(np.isfinite(d), d, np.inf)
        j = np.argmin(d, axis=1)
        dmin = d[np.arange(n), j]
        limit = decl.max_distance if decl.max_distance is not None else 0.5 * min_template_spacing(template_features)
        ok = dmin <= limit
        code = np.where((code < 0) & ok, len(decl.rules) + j, code)
    unclassified, failed = names.index(UNCLASSIFIED), names.index(FAILED_NAME)
    code = np.where(code < 0, unclassified, code)
    finite = finite_features(results, tuple(system.observables), decl.observables_read(system))
    code = S.outcomes(status, code, escape=names.index(decl.escape) if decl.escape in names else None, failed=failed,
                      finite=finite)
    return code.astype(np.int8)


def template_features_at(plan, base: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """Template feature vectors (P, n_templates, n_features) at P parameter points, or None without templates.

    ``base``: every parameter of one trajectory per point (its swept values); each template's overrides
    replace the initial conditions, and the templates run with the plan's settings and engine choice: the
    same code path as every sampled trajectory.
    """
    decl = plan.mapper.decl
    if decl is None or not decl.templates:
        return None
    from ..engines.simulate import solve_batch

    g = len(next(iter(base.values())))
    names = list(decl.templates)
    params = {k: np.concatenate([np.asarray(v)] * len(names)) for k, v in base.items()}
    for j, name in enumerate(names):
        over = plan.system.params.resolve(decl.templates[name])
        for k in decl.templates[name]:
            params[k][j * g:(j + 1) * g] = over[k]
    params = plan.system.check(params)
    varied = set().union(*[set(t) for t in decl.templates.values()])
    static = [k for k in plan.static_params() if k not in varied]
    res = solve_batch(plan.integrated, params, plan.icfg, plan.vcfg, static=static)
    feat = feature_getter(res, tuple(plan.system.observables))
    n = g * len(names)

    def par(name):
        return np.asarray(params[name], float).reshape(n)

    x = feature_matrix(decl, plan.system, feat, par)  # (T * P, F)
    ok = S.succeeded(np.asarray(res["solver_status"]))
    x = np.where(ok[:, None], x, np.nan)
    return x.reshape(len(names), g, -1).transpose(1, 0, 2)


def min_template_spacing(tf: np.ndarray) -> np.ndarray:
    """Per trajectory (grid point): the smallest distance between two templates' feature vectors."""
    t = tf.shape[-2]
    if t < 2:
        return np.full(tf.shape[:-2], np.inf)
    d = np.linalg.norm(tf[..., :, None, :] - tf[..., None, :, :], axis=-1)
    # a template that failed at a point (NaN features) is far from everything: it must not make the
    # spacing NaN, which would leave every trajectory there unclassified
    d = np.where(np.eye(t, dtype=bool) | ~np.isfinite(d), np.inf, d)
    return d.min(axis=(-1, -2))


def coinciding_templates(decl: Outcomes, tf: np.ndarray) -> tuple[int, str, str, float] | None:
    """The first (point, template a, template b, distance) where two templates' feature vectors
    coincide (distance <= COINCIDE_RTOL (1 + |feature vector|)), or None.

    Coinciding templates make the default ``max_distance`` (half the smallest spacing) zero, and
    every trajectory near them would end "unclassified" without a word; with a given ``max_distance``
    the choice between the two is arbitrary. Either way the plan is refused before it runs.
    """
    t = tf.shape[-2]
    if t < 2:
        return None
    names = list(decl.templates)
    d = np.linalg.norm(tf[:, :, None, :] - tf[:, None, :, :], axis=-1)  # (P, T, T)
    size = np.linalg.norm(tf, axis=-1)
    scale = 1.0 + np.maximum(size[:, :, None], size[:, None, :])
    with np.errstate(invalid="ignore"):
        close = (d <= COINCIDE_RTOL * scale) & ~np.eye(t, dtype=bool)
    if not close.any():
        return None
    p, a, b = (int(x[0]) for x in np.nonzero(close))
    return p, names[a], names[b], float(d[p, a, b])
