"""Minimal fatal shocks: how far can the start be pushed off an attractor before it ends elsewhere?

The minimal fatal shock (Halekotte & Feudel, Sci. Rep. 10, 2020; Attractors.jl's ``minimal_fatal_shock``) of an
attractor is the smallest perturbation ``delta*`` of its state after which the trajectory reaches another
outcome; its size is the distance from the attractor to the edge of its basin, its direction the weak spot.
Here the state is the spec's start (its initial-condition parameters, put on the attractor; or, with ``settle =
true``, the state that start reaches at t1, for a model whose shocked parameters are its state) and a shock perturbs
chosen components in a chosen norm (:mod:`stabjax.explore.shock_config`), at every point of the spec's ``[grid]``.

The search is batched: every round is one batch of trajectories through the sweep's runner
(:func:`stabjax.run.sweep.run_points`: the plan's engine, chunks, Dask workers, a chunk store per round from which a
killed search resumes), with the points of every grid point packed together:

1. **Scan** (round 0, with the unshocked start that names the attractor): ``directions`` unit directions drawn
   i.i.d. (Gaussian in the shocked entries; one set for every grid point, common random numbers), each at
   ``radii`` radii evenly spaced up to ``max_radius``. Along each direction the first fatal radius and the one
   before it bracket the exit radius (a bisection on [0, max_radius] alone would find *a* crossing, not the first).
2. **Bisection** of the brackets, all at once, one radius per direction and round, only of the directions whose
   bracket could still hold the smallest fatal shock (its safe end below the best fatal shock found); until every
   such bracket is narrower than the resolution.
3. **Local refinement** (``refine = "cma"``): CMA-ES (Hansen's pycma, ask/tell) in the space of shocks, started at
   the best witness, one generation a round. The population is ranked fatal before not fatal, fatal by increasing
   norm, the others by decreasing norm (Deb's feasibility rule: the search stays on the basin's edge and slides
   along it to its nearest point), so it needs one trajectory per candidate, not a bisection. CMA-ES uses ranks
   only. Random directions alone find the minimising direction slowly once the shock has more than two entries
   (the cap of directions within 1 % of the minimum shrinks like a power of the dimension).
   Before it, along a grid, every grid point's best direction is also scanned and bisected at the other points
   (the witness of a neighbouring gain is the likeliest direction where the random ones found nothing).
4. **Polish**: the best refined shock's direction is scanned and bisected like the others.
5. **Sharing the refined witnesses** (with CMA-ES, along a grid): each refined direction not yet shared is scanned
   and bisected at the other grid points where it was not searched, and the points it improved (a smaller fatal
   shock, or one where none was found) are refined and polished again from it, while any improves, at most
   :data:`~stabjax.explore.shock_config.SHARE_ROUNDS` times: the scan's directions, and the best scanned one
   shared before the refinement, can all miss a narrow fatal cone that a neighbour's refined witness hits.

Result per grid point: ``|delta*|``, the smallest fatal shock found (an upper bound: a fatal start of that size
exists, the **witness**), the bracket's lower end ``r_lo`` -- *statistical*: no fatal shock among the N directions
searched below it (each direction scanned then bisected, assuming it leaves the basin once between two scan
radii), so the share of directions holding a smaller one is below 1 - 0.05^(1/N) (about 3/N) with 95 %
confidence, a narrow cone between them can escape -- and the effort (directions, trajectories, rounds).

Fatal: the outcome of the shocked start differs from the attractor's (the unshocked start's, or ``attractor``),
decided by the sweep's own machinery (:func:`outcome_codes`: rules, templates, discovery, attitude verdicts);
``undecided``/``unclassified`` (the classifier could not decide) are never fatal and never safe: they count as
not fatal in the bisection and their smallest norm is reported; a solver failure (a blow-up) is fatal. With
``target = [...]`` only those outcomes are fatal (the excitability threshold into chosen basins, Attractors.jl's
``target_id``); with ``excitability = "<condition>"`` a shock is fatal when the condition holds over the whole
run (``max(error) > 0.3``: the trajectory left that neighbourhood, even if it came back).

Layout: the table, the start shocked and the norm are :mod:`stabjax.explore.shock_config`; the theorems' regions, the dataset and the
replay are :mod:`stabjax.explore.shock_result`; the figures :mod:`stabjax.present.shock`.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from ..errors import StabjaxError, ValidationError
from ..plan.spec import Plan, make_plan
from .shock_config import (INCONCLUSIVE, LEFT, SHARE_ROUNDS, STAYED, Norm, ShockConfig, base_points, settle,
                           shock_config)

FATAL, SAFE, UNDECIDED = 1, 0, 2
PATIENCE = 8  # CMA-ES generations without a better fatal shock (by a quarter of the resolution) before it stops
CMA_SIGMA0 = 0.25  # initial step of CMA-ES on unit directions (about the angular spacing of the scan's directions)
LADDER_WIDTH = 0.1  # the rungs span +-10 % around the best fatal shock at first, then narrow towards the resolution
LADDER_SHRINK = 0.8


def ladder_width(width: float, m: int) -> float:
    """The CMA-ES ladder's half-width, a fraction of its centre: its ``m`` rungs lie at centre (1 + width frac),
    frac in [-(m - 1)/m, (m - 1)/m], so a width of m/(m - 1) or more would put the lowest rung at or below 0 (a
    coarse resolution asks for that: 0.5 m tol / centre grows with it), a negative "radius" whose shock is the
    opposite one, recorded with a negative norm. Such a width is cut to 1: the lowest rung at centre / m, every rung
    a positive radius. A width that keeps every rung positive is left as it is."""
    return 1.0 if width * (m - 1) >= m else width


# ---- the outcome of a shocked start: the one call into the outcome machinery ---------------------------


class Labeller:
    """Outcome codes of a round's trajectories, with the sweep's machinery: the plan's outcome mapper
    (:mod:`stabjax.mapping.mapper`). A per-trajectory mapper (attitude verdicts; rules, templates and escape)
    labels each shocked start with its parameters and its grid point's state (the templates integrated there
    once, :meth:`~stabjax.mapping.mapper.Mapper.prepare_at`); discovery, a whole-set mapper, groups the first
    round and places later trajectories by their nearest grouped one. The only place that asks the outcome
    machinery."""

    def __init__(self, plan: Plan, base: Mapping[str, np.ndarray]):
        self.plan = plan
        self.mapper = plan.mapper
        self.discover = self.mapper.whole_set
        self.names: tuple[str, ...] = tuple(plan.scheme.names)
        self.state = None if self.discover else self.mapper.prepare_at(plan, base)  # per grid point, or None
        self.ref = None  # discovery: the first round's grouped features

    def __call__(self, g: np.ndarray, params: Mapping[str, np.ndarray], results: Mapping[str, np.ndarray]):
        if self.discover:
            return self._discovered(results)
        state = None if self.state is None else self.state[g]
        return self.mapper.label(self.plan, results, params, state).astype(np.int16)

    def _discovered(self, results):
        """Discovery on the first round (the unshocked starts and the scan), pooled over the grid points; later
        trajectories join the group of their nearest grouped one within ``eps`` (discovery's own border rule),
        or are unclassified; non-finite features are failed, as in a sweep (:func:`stabjax.fold.status.outcomes`)."""
        from sklearn.neighbors import NearestNeighbors

        from ..fold import status as S
        from ..mapping import discover as D
        from ..model import outcomes as O

        plan = self.plan
        obs = tuple(plan.system.observables)
        cfg = self.mapper.cfg
        status = np.asarray(results["solver_status"])
        feats, _ = D.feature_table(results, obs)
        if self.ref is None:
            disc = D.discover(results, obs, cfg, status == 0, plan.icfg.atol, plan.icfg.rtol,
                              D.is_autonomous(plan.system))
            escape = (plan.escape_radius is not None) * (plan.scheme.decl.escape,)
            self.names = tuple(disc.names) + escape + (O.UNCLASSIFIED, O.FAILED_NAME)
            keep = disc.labels >= 0
            self.ref = (feats[keep] / np.repeat(disc.scale, len(D.STATS)), disc.labels[keep], disc.scale)
            lab = disc.labels
        else:
            x, lab_ref, scale = self.ref
            y = feats / np.repeat(scale, len(D.STATS))
            lab = np.full(len(y), -1)
            ok = np.all(np.isfinite(y), axis=1)
            if len(x) and ok.any():
                d, j = NearestNeighbors(n_neighbors=1).fit(x).kneighbors(y[ok])
                lab[ok] = np.where(d[:, 0] <= cfg.eps, lab_ref[j[:, 0]], -1)
        code = np.where(lab >= 0, lab, self.names.index(O.UNCLASSIFIED))
        escape = self.names.index(plan.scheme.decl.escape) if plan.escape_radius is not None else None
        code = S.outcomes(status, code, escape=escape, failed=self.names.index(O.FAILED_NAME),
                          finite=O.finite_features(results, obs))
        return code.astype(np.int16)


def classify(cfg: ShockConfig, names: tuple[str, ...], codes: np.ndarray, attractor: np.ndarray) -> np.ndarray:
    """FATAL, SAFE or UNDECIDED of each shocked start from its outcome code and its grid point's attractor code."""
    names = list(names)
    undecided = np.isin(codes, [names.index(n) for n in INCONCLUSIVE if n in names])
    if cfg.excitability is not None:
        fatal = codes != names.index(STAYED)
    elif cfg.target is not None:
        fatal = np.isin(codes, [names.index(t) for t in cfg.target if t in names])
    else:
        fatal = codes != attractor
    return np.where(undecided, UNDECIDED, np.where(fatal, FATAL, SAFE)).astype(np.int8)


# ---- the plan of a round ---------------------------------------------------------------------------


def round_plan(plan: Plan, cfg: ShockConfig) -> Plan:
    """The plan the rounds run: the spec's grid plus one axis per shocked entry (the rounds' points fill them in),
    and for an excitability search the outcomes ``left``/``stayed`` of the whole run."""
    from ..plan.spec import jsonable

    spec = json.loads(json.dumps(jsonable(plan.spec)))
    params = dict(spec.get("params") or {})
    base = plan.params_for(0, 1)
    grid = dict(spec.get("grid") or {})
    for e in cfg.entries:
        if e.index is None:
            params.pop(e.param, None)  # the whole parameter is swept: its [params] value is the base, carried by points
        v = np.asarray(base[e.param][0], float)
        grid[e.key] = [float(v if e.index is None else v[e.index])]
    spec["params"], spec["grid"] = params, grid
    if cfg.excitability is not None:
        spec["outcomes"] = {"rules": {LEFT: cfg.excitability, STAYED: f"not ({cfg.excitability})"}, "templates": {},
                            "discover": False, "window": 1.0}
    return make_plan(spec)


# ---- the search --------------------------------------------------------------------------------------


@dataclasses.dataclass
class Rays:
    """Directions searched, each at one grid point: its exit bracket [lo, hi] in the norm and the fatal shock at hi."""

    g: list = dataclasses.field(default_factory=list)
    u: list = dataclasses.field(default_factory=list)
    lo: list = dataclasses.field(default_factory=list)
    hi: list = dataclasses.field(default_factory=list)
    delta: list = dataclasses.field(default_factory=list)  # the fatal shock at hi (NaN while none)
    code: list = dataclasses.field(default_factory=list)  # its outcome code
    kind: list = dataclasses.field(default_factory=list)  # 0: scanned, 1: polished, 2: shared from another grid point

    def add(self, g, u, kind):
        k = len(self.g)
        self.g.append(int(g))
        self.u.append(np.asarray(u, float))
        self.lo.append(0.0)
        self.hi.append(np.inf)
        self.delta.append(np.full(len(u), np.nan))
        self.code.append(-1)
        self.kind.append(kind)
        return k


class Search:
    """The explorer: :meth:`run` proposes each round's shocks and hands them to ``evaluate(r, g, deltas) ->
    outcome codes``; it integrates nothing itself."""

    def __init__(self, cfg: ShockConfig, norm: Norm, G: int, names_fn: Callable[[], tuple[str, ...]]):
        self.cfg, self.norm, self.G = cfg, norm, G
        self.names_fn = names_fn
        self.rays = Rays()
        self.attractor = np.full(G, -1)  # outcome code of the unshocked start (-1: no search there)
        self.valid = np.zeros(G, bool)
        self.trajectories = np.zeros(G, np.int64)
        self.undecided_min = np.full(G, np.inf)  # smallest norm of a start the classifier left undecided
        self.cma_best = [None] * G  # (norm, delta, code) of the best fatal CMA-ES candidate
        self.cma_generations = np.zeros(G, np.int64)
        self.rounds = 0
        self.round_sizes: list[int] = []
        self._shared_from: dict[int, np.ndarray] = {}  # the direction each grid point's witness was last shared along

    # -- rounds -----------------------------------------------------------------------------------------
    def _evaluate(self, evaluate, g, deltas):
        codes = np.asarray(evaluate(self.rounds, np.asarray(g, np.int64), np.asarray(deltas, float)))
        self.rounds += 1
        self.round_sizes.append(len(g))
        np.add.at(self.trajectories, np.asarray(g, np.int64), 1)
        return codes

    def _classify(self, g, codes, norms):
        c = classify(self.cfg, self.names_fn(), codes, self.attractor[g])
        und = c == UNDECIDED
        if und.any():
            np.minimum.at(self.undecided_min, g[und], norms[und])
        return c

    def best(self) -> np.ndarray:
        """Smallest fatal norm found at each grid point (inf: none)."""
        out = np.full(self.G, np.inf)
        if self.rays.g:
            np.minimum.at(out, np.array(self.rays.g), np.array(self.rays.hi))
        return out

    def run(self, evaluate):
        cfg, G = self.cfg, self.G
        rng = np.random.default_rng(cfg.seed)
        if cfg.dim == 1:  # the whole unit sphere of one component, in turn (shock_config: at most 2)
            U = np.array([[1.0], [-1.0]])[: cfg.directions]
        else:
            U = rng.standard_normal((cfg.directions, cfg.dim))
            U /= np.linalg.norm(U, axis=1, keepdims=True)
        for g in range(G):
            for u in U:
                self.rays.add(g, u, 0)
        # round 0: the unshocked starts (which attractor) and the scan
        ks = np.arange(len(self.rays.g))
        self._scan(evaluate, ks, np.full(len(ks), cfg.max_radius), with_base=True)
        self._bisect(evaluate)
        self._share(evaluate)
        if cfg.refine == "cma" and cfg.dim >= 2 and cfg.generations > 0:
            todo = [int(g) for g in np.flatnonzero(np.isfinite(self.best()) & (self.attractor >= 0))]
            for p in range(1 + SHARE_ROUNDS):
                self._refine(evaluate, todo, p)
                if p == SHARE_ROUNDS:
                    break
                todo = self._share(evaluate, refined=True)  # the grid points it improved: refined again
                if not todo:
                    break
        return self

    def _refine(self, evaluate, gs, p=0):
        """CMA-ES at the grid points ``gs`` (pass ``p``), then the polish: each better refined shock's direction
        scanned and bisected like the others."""
        if not gs:
            return
        self._cma(evaluate, gs, p)
        polish = []
        best = self.best()
        for g in gs:
            c = self.cma_best[g]
            if c is not None and c[0] < best[g] and np.linalg.norm(c[1]) > 0:
                k = self.rays.add(g, c[1] / np.linalg.norm(c[1]), 1)
                self.rays.hi[k], self.rays.delta[k], self.rays.code[k] = c[0], c[1], c[2]
                polish.append(k)
        if polish:
            ks = np.array(polish)
            self._scan(evaluate, ks, np.array([self.rays.hi[k] for k in ks]), known_top=True)
            self._bisect(evaluate)

    def _best_ray(self, g):
        r = self.rays
        return min((k for k in range(len(r.g)) if r.g[k] == g), key=lambda k: r.hi[k])

    def _share(self, evaluate, refined=False):
        """Along a grid, each point's best direction is scanned and bisected at every other point too (a fatal
        direction of a neighbour is the likeliest one where the scan found none, or a worse one).

        Before the refinement every point's best direction is shared; after it (``refined``) only the directions
        that changed since they were last shared (a refined or polished witness, or one a share brought), and at
        each point only a direction not searched there yet, so that a refined witness reaches the points where the
        scan's directions missed a narrow fatal cone. Returns the grid points whose smallest fatal shock it made
        smaller (by more than a quarter of the resolution), or found where there was none: they are refined again.
        """
        r, best = self.rays, self.best()
        owners = [g for g in range(self.G) if np.isfinite(best[g])]
        if self.G < 2 or not owners:
            return []
        U = np.array(r.u)
        G_r = np.array(r.g)
        shared = []
        for h in owners:
            k = self._best_ray(h)
            u = np.asarray(r.u[k], float)
            if refined and h in self._shared_from and np.allclose(self._shared_from[h], u, rtol=0, atol=1e-12):
                continue
            self._shared_from[h] = u
            for g in range(self.G):
                if g == h or self.attractor[g] < 0:
                    continue
                if refined and np.any((G_r == g) & np.all(np.abs(U - u) <= 1e-12, axis=1)):
                    continue  # this direction was searched there already
                shared.append(r.add(g, u, 2))
        if not shared:  # one grid point searched, the others with no attractor to shock; or nothing new
            return []
        ks = np.array(shared)
        self._scan(evaluate, ks, np.full(len(ks), self.cfg.max_radius))
        self._bisect(evaluate)
        after = self.best()
        gain = np.isfinite(after) & (after < best - 0.25 * self.cfg.tol(after))  # best inf: any fatal shock found
        return [int(g) for g in np.flatnonzero(gain)]

    def _scan(self, evaluate, ks, top, with_base=False, known_top=False):
        """Each ray ``ks`` at ``radii`` radii up to ``top`` (the last one skipped when ``known_top``: it is a
        known fatal shock); the first fatal radius and the one before bracket the exit."""
        K, d = self.cfg.radii, self.cfg.dim
        js = np.arange(1, K + (0 if known_top else 1))
        if not len(js):  # one radius, and it is the known fatal shock: nothing below it was tried
            return
        kk = np.repeat(ks, len(js))
        R = (np.repeat(top, len(js)) * np.tile(js, len(ks)) / K)
        g = np.array(self.rays.g)[kk]
        u = np.array(self.rays.u)[kk]
        deltas = self.norm.shift(g, u, R)
        reach = np.all(np.isfinite(deltas), axis=1)
        run = np.flatnonzero(reach)
        gg, dd = g[run], deltas[run]
        if with_base:
            gg = np.concatenate([np.arange(self.G), gg])
            dd = np.concatenate([np.zeros((self.G, d)), dd])
        codes = self._evaluate(evaluate, gg, dd)
        if with_base:
            self.attractor, codes = self._attractors(codes[: self.G]), codes[self.G:]
        cls = np.full(len(kk), SAFE, np.int8)
        code_all = np.full(len(kk), -1)
        ok = self.attractor[g[run]] >= 0
        cls[run] = np.where(ok, self._classify(g[run], codes, R[run]), SAFE)
        code_all[run] = codes
        cls = cls.reshape(len(ks), len(js))
        for i, k in enumerate(ks):
            if self.attractor[self.rays.g[k]] < 0:
                continue
            f = np.flatnonzero(cls[i] == FATAL)
            if len(f):
                j = f[0]
                m = i * len(js) + j
                self.rays.lo[k] = float(R[m - 1]) if j > 0 else 0.0
                self.rays.hi[k], self.rays.delta[k], self.rays.code[k] = float(R[m]), deltas[m], int(code_all[m])
            elif known_top:
                self.rays.lo[k] = float(R[i * len(js) + len(js) - 1]) if len(js) else 0.0
            else:
                # safe up to the scan's top (a ray that cannot reach a radius is safe as far as it goes)
                self.rays.lo[k] = np.inf if not reach[i * len(js):(i + 1) * len(js)].all() else float(top[i])

    def _attractors(self, codes):
        names = self.names_fn()
        att = np.asarray(codes, np.int64).copy()
        bad = np.isin(att, [names.index(n) for n in (*INCONCLUSIVE, "failed") if n in names])
        if self.cfg.attractor is not None:
            if self.cfg.attractor not in names:
                raise ValidationError("shock.attractor", f"no outcome {self.cfg.attractor!r}; outcomes found: "
                                                         f"{', '.join(names)}")
            bad |= att != names.index(self.cfg.attractor)
        if self.cfg.excitability is not None:  # the unshocked start must stay in its own neighbourhood
            bad |= att != names.index(STAYED)
        self.base_codes = np.asarray(codes, np.int64)
        att[bad] = -1
        self.valid = att >= 0
        return att

    def _bisect(self, evaluate):
        r = self.rays
        while True:
            best = self.best()
            tol = self.cfg.tol(best)
            g, lo, hi = np.array(r.g), np.array(r.lo), np.array(r.hi)
            active = np.isfinite(hi) & (hi - lo > tol[g]) & (lo < best[g]) & (self.attractor[g] >= 0)
            ks = np.flatnonzero(active)
            if not len(ks):
                return
            R = 0.5 * (lo[ks] + hi[ks])
            deltas = self.norm.shift(g[ks], np.array(r.u)[ks], R)
            lost = ~np.all(np.isfinite(deltas), axis=1)  # a state norm that does not grow along the ray here
            for k in ks[lost]:
                r.lo[k] = r.hi[k]
            ks, R, deltas = ks[~lost], R[~lost], deltas[~lost]
            if not len(ks):
                continue
            codes = self._evaluate(evaluate, g[ks], deltas)
            cls = self._classify(g[ks], codes, R)
            for i, k in enumerate(ks):
                if cls[i] == FATAL:
                    r.hi[k], r.delta[k], r.code[k] = float(R[i]), deltas[i], int(codes[i])
                else:
                    r.lo[k] = float(R[i])

    def _cma(self, evaluate, gs, p=0):
        """CMA-ES over directions (candidates x, direction x/|x|), each ranked by its exit radius read off a ladder
        of ``radii`` radii around the best fatal shock so far, all candidates of the grid points ``gs`` in one round;
        started at each one's best witness, ``generations`` at most per pass ``p`` (seeded by the seed, the grid
        point and the pass)."""
        import cma

        cfg, m = self.cfg, self.cfg.radii
        best = self.best()
        es: dict[int, Any] = {}
        stale, width, gens = {}, {}, {}
        for g in gs:
            g = int(g)
            if not (np.isfinite(best[g]) and self.attractor[g] >= 0):
                continue
            k = self._best_ray(g)
            rng = np.random.default_rng([cfg.seed, g] if p == 0 else [cfg.seed, g, p])
            opts = {"randn": lambda *shape, rng=rng: rng.standard_normal(shape), "seed": np.nan, "verbose": -9,
                    "verb_disp": 0, "verb_log": 0, "maxiter": cfg.generations}
            if cfg.popsize:
                opts["popsize"] = cfg.popsize
            es[g] = cma.CMAEvolutionStrategy(np.asarray(self.rays.u[k], float), CMA_SIGMA0, opts)
            self.cma_best[g] = (float(best[g]), np.asarray(self.rays.delta[k], float), int(self.rays.code[k]))
            stale[g], width[g], gens[g] = 0, LADDER_WIDTH, 0
        frac = (2 * np.arange(m) + 1) / m - 1  # rungs at centre (1 + w frac), frac in (-1, 1)
        while es:
            gs, X, R = [], [], []
            for g, e in es.items():
                xs = np.array(e.ask())
                centre = self.cma_best[g][0]
                gs += [g] * len(xs)
                X.append(xs)
                R.append(np.tile(centre * (1 + width[g] * frac), (len(xs), 1)))
            g_c, X, R = np.array(gs), np.concatenate(X), np.concatenate(R)  # candidates; (C, m) radii
            U = X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-300)
            g_r = np.repeat(g_c, m)
            deltas = self.norm.shift(g_r, np.repeat(U, m, axis=0), R.ravel())
            reach = np.all(np.isfinite(deltas), axis=1)
            cls = np.full(len(g_r), SAFE, np.int8)
            codes = np.full(len(g_r), -1)
            run = np.flatnonzero(reach)
            codes[run] = self._evaluate(evaluate, g_r[run], deltas[run])
            cls[run] = self._classify(g_r[run], codes[run], R.ravel()[run])
            fatal = (cls == FATAL).reshape(len(g_c), m)
            first = np.where(fatal.any(axis=1), fatal.argmax(axis=1), m)
            est = np.where(first < m, np.take_along_axis(R, np.minimum(first, m - 1)[:, None], axis=1)[:, 0], np.inf)
            done = []
            for g, e in es.items():
                c = np.flatnonzero(g_c == g)
                key = np.where(np.isfinite(est[c]), est[c], 2 * R[c].max())  # no fatal rung: all tied, last
                e.tell(list(X[c]), list(np.argsort(np.argsort(key, kind="stable"), kind="stable").astype(float)))
                self.cma_generations[g] += 1
                gens[g] += 1
                old = self.cma_best[g][0]
                i = c[np.argmin(est[c])]
                if est[i] < old:
                    j = i * m + first[i]
                    self.cma_best[g] = (float(est[i]), deltas[j].copy(), int(codes[j]))
                tol = float(cfg.tol(np.array([self.cma_best[g][0]]))[0])
                improved = old - self.cma_best[g][0] > 0.25 * tol
                stale[g] = 0 if improved else stale[g] + 1
                # a best candidate fatal on the lowest rung may lie further down: keep the window; else narrow it
                if first[i] > 0:
                    width[g] = ladder_width(max(LADDER_SHRINK * width[g], 0.5 * m * tol / max(self.cma_best[g][0],
                                                                                              1e-300)), m)
                if stale[g] >= PATIENCE or e.stop() or gens[g] >= cfg.generations:
                    done.append(g)
            for g in done:
                del es[g]


# ---- entry points ------------------------------------------------------------------------------------


def shock_plan(plan: Plan, out: str | Path | None = None, *, store: str | Path | None = None,
               batch_size: int | None = None, progress: bool = False, restart: bool = False,
               keep_store: bool = False, executor=None, overrides: Mapping[str, Any] | None = None,
               on_open: Callable[[], None] | None = None, force: bool = False) -> xr.Dataset:
    """Search the minimal fatal shock described by ``plan.spec["shock"]`` at every grid point; write ``out``
    (netCDF) if given (never over an input, an existing file only when a result of this spec or with ``force``:
    :func:`stabjax.run.outputs.guard_result`).

    Each round's trajectories go through the sweep's runner (:func:`stabjax.run.sweep.run_points`) with a chunk
    store per round, ``<store>/round_NNNN`` (default store ``<out>.zarr``): a killed search re-run with the same
    command proposes the same rounds (everything is seeded) and recomputes no finished chunk; ``restart``
    discards them; the store is removed after ``out`` is written unless ``keep_store``. ``on_open``: called
    once, when the first round's store accepted the run (as for :func:`stabjax.run.sweep.run_plan`).
    """
    from ..run.outputs import guard_result
    from ..run.store import discard_rounds
    from ..run.sweep import default_store, once, run_points, write
    from .shock_result import assemble

    cfg = shock_config(plan)
    if out is not None:
        guard_result(plan, out, force=force)
    base_dir = Path(store) if store is not None else (default_store(out) if out is not None else None)
    # the default <out>.zarr is the search's own; a --store folder only if this run makes it
    # the default <out>.zarr is the search's own, also when named as the command line names it (resumed, it
    # exists: it stayed behind, empty); a --store folder elsewhere only if this run makes it
    own_base = base_dir is not None and (store is None or not base_dir.exists()
                                         or (out is not None and base_dir == default_store(out)))
    rplan = round_plan(plan, cfg)
    base, gv = base_points(plan)
    if cfg.settle:
        base = settle(plan, cfg, base)
    norm = Norm(plan, cfg, base)
    label = Labeller(rplan, base)
    engines: set[str] = set()
    resumed = [0]
    steps: list[int | None] = [0]  # the rounds' accepted solver steps (None: a round's records carry none)
    base_status = np.zeros(plan.size, np.int32)  # round 0 opens with the unshocked starts: why one of them failed

    opened = once(on_open)  # the caller's word (which file will be replaced), at the first round's store

    def evaluate(r: int, g: np.ndarray, deltas: np.ndarray) -> np.ndarray:
        p = norm.params(g, deltas)
        values = np.concatenate([gv[g], np.stack([p[e.param] if e.index is None else p[e.param][(slice(None), *e.index)]
                                                  for e in cfg.entries], axis=1)], axis=1)
        res, info = run_points(rplan, values, store=None if base_dir is None else base_dir / f"round_{r:04d}",
                               batch_size=batch_size, progress=progress, restart=restart, keep_store=True,
                               executor=executor, overrides=overrides, on_open=opened)
        engines.update(info["engines"])
        if steps[0] is not None:
            steps[0] = steps[0] + int(np.asarray(res["n_steps"]).sum()) if "n_steps" in res else None
        resumed[0] += info["n_resumed"] == info["n_chunks"]
        if r == 0:
            base_status[:] = np.asarray(res["solver_status"])[: plan.size]
        params = dataclasses.replace(rplan, points=values).params_for(0, len(values))
        return label(g, params, res)

    t0 = time.perf_counter()
    fresh = base_dir is not None and not base_dir.exists()
    try:
        search = Search(cfg, norm, plan.size, lambda: label.names).run(evaluate)
    except ValidationError:  # an attractor that discovery did not find: refused after round 0, nothing left behind
        if fresh:
            discard_rounds(base_dir, own_base)
        raise
    ds = assemble(plan, rplan, cfg, norm, search, label.names, base, wall=time.perf_counter() - t0,
                  engines=engines, rounds_resumed=resumed[0], label=label, base_status=base_status,
                  total_steps=steps[0])
    if out is not None:
        write(ds, out)
        if not keep_store and base_dir is not None:
            discard_rounds(base_dir, own_base)
    return ds


def shock_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, t1: float | None = None,
               **kw) -> xr.Dataset:
    """Load (if a path), plan and search a spec with a ``[shock]`` section (see :func:`shock_plan`; ``out`` never
    the spec file read)."""
    from ..run.outputs import plan_result

    plan = plan_result(spec, out, t1=t1, force=bool(kw.get("force", False)), section="shock", caller="shock_spec",
                       kw=kw, runner=shock_plan)
    return shock_plan(plan, out, overrides={"t1": t1}, **kw)


def minimal_fatal_shock(system, components, max_radius: float, *, params: Mapping[str, Any] | None = None,
                        grid: Mapping[str, Any] | None = None, integrate: Mapping[str, Any] | None = None,
                        outcomes: Mapping[str, Any] | None = None, out: str | Path | None = None,
                        **shock: Any) -> xr.Dataset:
    """The minimal fatal shock from Python in one call: ``system`` (a name, ``"model.py:Class"``, a class),
    the shocked initial-condition parameters ``components`` (a list of names, or one name), ``max_radius`` and any
    other ``[shock]`` field as a keyword (``norm="max"``, ``weights={...}``, ``theory=[...]``); ``params``/``grid``/``integrate``/``outcomes``:
    those tables of a spec. The same search as ``stabjax sweep`` on a spec with that ``[shock]`` table."""
    # one name is one component (list("theta0") was six one-letter ones); anything else goes to the spec's check
    comps = [components] if isinstance(components, str) else \
        list(components) if isinstance(components, (list, tuple)) else components
    spec: dict[str, Any] = {"system": system, "name": "shock",
                            "shock": {"components": comps, "max_radius": max_radius, **shock}}
    for k, v in (("params", params), ("grid", grid), ("integrate", integrate), ("outcomes", outcomes)):
        if v is not None:
            spec[k] = dict(v)
    return shock_spec(spec, out)


__all__ = ["shock_plan", "shock_spec", "minimal_fatal_shock", "Search", "Labeller", "classify", "round_plan",
           "base_points", "FATAL", "SAFE", "UNDECIDED", "StabjaxError"]
