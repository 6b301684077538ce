"""Adaptive boundary refinement: bracket the boundary between outcomes without the full grid.

A ``[refine]`` section in a sweep spec turns the spec's ``[grid]`` (one or two scalar axes) into
the *coarse* grid of a refinement. Every coarse interval is split in halves, ``L_a`` times along
axis ``a``, so the points the refinement may visit form a lattice of
``(n_a - 1) * 2**L_a + 1`` values per axis, ``L_a`` being the fewest halvings that bring every
interval of axis ``a`` to the tolerance ``tol_a`` (log axes are halved in log space). Starting
from the coarse grid, each round

* 1-D: bisects every interval whose two end points carry different labels;
* 2-D: subdivides every cell (quadtree style) whose boundary carries different labels -- its
  corners and any point a finer neighbour already put on its edges -- along each axis on which
  the cell is still wider than the tolerance;

and evaluates all the new lattice points of the round in one batch (already computed points are
re-used, never re-run). It stops when no cell that straddles the boundary can be split any more:
every boundary segment is then one lattice step long, i.e. bracketed to ``tol_a``.

Labels. A point's label is its ``verdict`` (:mod:`stabjax.verdict`) or, for systems that declare
named outcomes, its ``outcome``; with ``[sample] n > 1`` it is the dominant (most frequent) label
of the point's samples (ties: the lower code). With several verdict horizons (results of shape
``(N, n_horizons)``) one horizon is refined: ``horizon = t`` picks it, default ``t1``.
``pair = ["converged", "flipped"]`` restricts boundaries to adjacent points labelled one of each;
``pair = ["converged", "*"]`` separates one outcome from all the others.

What it can miss: like any grid method, the coarse grid must resolve the regions: an island, or a
boundary that enters and leaves a coarse cell between the same corners, is invisible if no
evaluated point lands in it. The benchmark (`benchmarks/refine_bench.py` in a source checkout) compares the refinement against the
full lattice and counts any boundary edge of the full grid the refinement did not find.

Theory. For each bracketed segment the signed distance from its midpoint to the zero contour of
the system's main theorem margin (``theory(p).predicates[main].margin``) is measured along each
axis, in that axis's units: positive where the midpoint lies outside the region the theorem
guarantees (margin < 0; the theorem is conservative there, the empirical stable region reaches
beyond it), negative where the theorem claims stability at an empirical boundary.

Resume: each finished round is saved to ``<out>.partial/round_NNNN.npz`` (atomic replace) with the
plan's fingerprint (which covers the ``[refine]`` section); a re-run recomputes nothing that was
saved and gives the same result. Points are evaluated through a ``solve_points(params) -> results``
callable (default: the plan's engine), so another executor (Dask workers) can run a round.

Size: this module is one algorithm (~850 lines) whose parts -- the [refine] table, the lattice and its
rounds, the round store, the theory distance, the output dataset and plot -- share the refiner's
lattice state and private helpers; split across files they would only trade length for names passed
between modules. The benchmark against the full lattice is its own module.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from . import verdict as V
from .errors import StabjaxError, ValidationError
from .status import verdicts as status_verdicts
from .validate import number as _number
from .spec import Plan, load_spec, make_plan

REFINE_KEYS = ("tol", "rel_tol", "pair", "stable", "label", "horizon", "max_points")
DEFAULT_REL_TOL = 1 / 64
MAX_LATTICE = 1 << 28  # lattice sites held as labels in memory (int16): 0.5 GiB at most
ANY = "*"

SolvePoints = Callable[[Mapping[str, np.ndarray]], Mapping[str, np.ndarray]]


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
    horizon: float  # the verdict horizon refined
    max_points: int


def label_names(plan: Plan, label: str) -> tuple[str, ...]:
    """Names of the label codes: verdict names, or the system's declared outcomes."""
    if label == "verdict":
        return tuple(V.NAMES)
    if plan.outcomes is None:
        raise ValidationError("refine.label", f"{plan.system.name} declares no named outcomes; use label = \"verdict\"")
    return tuple(plan.outcomes.names)


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
        levels.append(_levels(ax.values, ax.log, t))

    label = raw.get("label")
    if label is None:
        label = "outcome" if plan.outcomes is not None else "verdict"
    if label not in ("verdict", "outcome"):
        raise ValidationError("refine.label", f"must be \"verdict\" or \"outcome\", got {label!r}")
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
    else:
        stable = pair[0] if pair else ("converged" if "converged" in names else None)

    t1 = plan.icfg.t1
    horizon = t1
    if "horizon" in raw:
        horizon = _number(raw["horizon"], "refine.horizon")
        if not plan.icfg.t0 < horizon <= t1:
            raise ValidationError("refine.horizon", f"must be in (t0, t1] = ({plan.icfg.t0:g}, {t1:g}], got {horizon:g}")
        hs = horizon_times(plan)
        if horizon != t1 and (hs is None or not np.any(np.isclose(hs, horizon, rtol=1e-12, atol=0))):
            raise ValidationError("refine.horizon", f"{horizon:g} is not one of the verdict horizons "
                                  f"({', '.join(f'{h:g}' for h in (hs if hs is not None else [t1]))})")
    max_points = raw.get("max_points", 1_000_000)
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 1:
        raise ValidationError("refine.max_points", f"must be an integer >= 1, got {max_points!r}")
    size = int(np.prod([(ax.size - 1) * 2**L + 1 for ax, L in zip(plan.grid, levels)]))
    if size > MAX_LATTICE:
        raise ValidationError("refine.tol", f"the finest lattice would hold {size:,} points (limit {MAX_LATTICE:,}); "
                              "use a coarser tolerance")
    return RefineConfig(tol=tuple(tols), levels=tuple(levels), label=label, names=names, pair=pair, stable=stable,
                        horizon=float(horizon), max_points=int(max_points))


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


def _levels(coarse: np.ndarray, log: bool, tol: float) -> int:
    for level in range(0, 31):
        if _max_width(coarse, log, level) <= tol * (1 + 1e-9):
            return level
    raise ValidationError("refine.tol", f"{tol:g} needs more than 30 halvings of the coarse grid")


# ---- round store ------------------------------------------------------------------------------


class RoundStore:
    """Finished rounds next to the output file: ``<out>.partial/round_NNNN.npz`` + manifest."""

    def __init__(self, out: Path, fingerprint: str, restart: bool = False):
        self.dir = Path(str(out) + ".partial")
        self.manifest = {"fingerprint": fingerprint, "kind": "refine"}
        mf = self.dir / "manifest.json"
        if self.dir.exists() and restart:
            shutil.rmtree(self.dir)
        elif mf.exists():
            old = json.loads(mf.read_text())
            if old != self.manifest:
                raise StabjaxError(f"{self.dir} holds a partial run of a different spec (fingerprint "
                                   f"{old.get('fingerprint')} vs {fingerprint}); pass --restart to discard it, "
                                   "or use another --out")
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = self.dir / ".manifest.tmp"
        tmp.write_text(json.dumps(self.manifest))
        os.replace(tmp, mf)

    def path(self, r: int) -> Path:
        return self.dir / f"round_{r:04d}.npz"

    def load(self, r: int) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        if not self.path(r).exists():
            return None
        with np.load(self.path(r)) as z:
            return z["coords"], {k[2:]: z[k] for k in z.files if k.startswith("r_")}

    def save(self, r: int, coords: np.ndarray, res: Mapping[str, np.ndarray]):
        tmp = self.dir / f".tmp_{r:04d}.npz"
        np.savez(tmp, coords=coords, **{f"r_{k}": v for k, v in res.items()})
        os.replace(tmp, self.path(r))  # atomic: a kill never leaves a half-written round

    def remove(self):
        shutil.rmtree(self.dir, ignore_errors=True)


# ---- evaluation ---------------------------------------------------------------------------------


def point_params(plan: Plan, values: np.ndarray) -> dict[str, np.ndarray]:
    """Every parameter for grid-axis ``values`` (P, n_axes), like :meth:`Plan.params_at`:
    point-major, with the plan's samples (common random numbers) inside each point."""
    values = np.asarray(values, float).reshape(-1, len(plan.grid))
    ns = max(plan.n_sample, 1)
    n = len(values) * ns
    out = {k: np.broadcast_to(v, (n, *v.shape)).copy() for k, v in plan.fixed.items()}
    for a, ax in enumerate(plan.grid):
        vals = np.repeat(values[:, a], ns)
        if ax.index is None:
            out[ax.param.name] = vals
        else:
            out[ax.param.name][(slice(None), *ax.index)] = vals
    if plan.n_sample:
        for k, v in plan.sample.items():
            out[k] = np.tile(v, (len(values),) + (1,) * (v.ndim - 1))
    return out


def _check(plan: Plan, p: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``system.check`` with errors pointing at the grid axis or sample at fault (as check_plan)."""
    try:
        return plan.system.check(p)
    except ValidationError as exc:
        where = [f"grid.{a.key}" for a in plan.grid if a.param.name == exc.field]
        where += [f"sample.{k}" for k in plan.sample if k == exc.field]
        if where:
            raise ValidationError(where[0], exc.message) from None
        raise


def default_solver(plan: Plan) -> SolvePoints:
    """``solve_points`` on the plan's engine (resolved once), one call per round."""
    from . import engines
    from .sweep import static_params

    static = static_params(plan)
    plan = engines.resolve_plan(plan, static=static)
    pad = plan.engine != "native"  # shape-compiled engines: few distinct shapes

    def solve_points(params):
        n = len(next(iter(params.values())))
        m = max(64, 1 << (n - 1).bit_length()) if pad else n
        if m > n:
            params = {k: np.concatenate([v, np.repeat(v[-1:], m - n, axis=0)]) for k, v in params.items()}
        res = engines.solve(plan.engine, plan.system, params, plan.icfg, plan.vcfg, static=static)
        return {k: np.asarray(v)[:n] for k, v in res.items()}

    solve_points.engine = plan.engine
    return solve_points


def _labels(plan: Plan, cfg: RefineConfig, res: Mapping[str, np.ndarray], n_points: int):
    """Per-point label (dominant over samples) and the fraction of samples carrying it."""
    if cfg.label not in res:
        raise StabjaxError(f"the engine returned no {cfg.label!r} (refine.label)")
    lab = np.asarray(res[cfg.label])
    if cfg.label == "verdict":  # an escaped point is diverged, as in a sweep (one rule: stabjax.status)
        lab = status_verdicts(np.asarray(res["solver_status"]), lab)
    if lab.ndim == 2:  # (N, n_horizons): horizons ascending, last = t1
        hs = horizon_times(plan)
        if hs is not None and len(hs) == lab.shape[1]:
            col = int(np.argmin(np.abs(hs - cfg.horizon)))
        elif cfg.horizon == plan.icfg.t1:
            col = lab.shape[1] - 1
        else:
            raise StabjaxError(f"results hold {lab.shape[1]} horizons but the plan does not say which times")
        lab = lab[:, col]
    lab = lab.astype(np.int64).reshape(n_points, -1)
    k = len(cfg.names)
    counts = np.stack([(lab == c).sum(axis=1) for c in range(k)], axis=1)
    dom = counts.argmax(axis=1)  # ties: the lower code
    return dom.astype(np.int16), counts.max(axis=1) / lab.shape[1]


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


# ---- the refiner --------------------------------------------------------------------------------


class Refiner:
    """Quadtree (2-D) / bisection (1-D) refinement over the integer lattice of a plan's grid.

    Lattice coordinates: axis ``a`` runs over ``0 .. (n_a - 1) * 2**L_a``; coarse grid points are the
    multiples of ``2**L_a``. ``lab`` holds the label of every evaluated site (-1: not evaluated).
    A cell is ``(lo, ext)``: its lower corner and its extent (powers of two) per axis.
    """

    def __init__(self, plan: Plan, cfg: RefineConfig, solve_points: SolvePoints | None = None,
                 store: RoundStore | None = None):
        self.plan, self.cfg = plan, cfg
        self.solve_points = solve_points or default_solver(plan)
        self.store = store
        self.D = len(plan.grid)
        self.step = tuple(2**L for L in cfg.levels)
        self.fine = [fine_values(ax.values, ax.log, L) for ax, L in zip(plan.grid, cfg.levels)]
        self.shape = tuple(len(f) for f in self.fine)
        self.lab = np.full(self.shape, -1, np.int16)
        self.cls = np.append(classes(cfg), -1)  # index -1 (unknown) -> class -1
        self.coords: list[np.ndarray] = []  # per round: (P, D) lattice coordinates
        self.results: list[dict[str, np.ndarray]] = []
        self.point_labels: list[np.ndarray] = []
        self.point_share: list[np.ndarray] = []
        self.n_resumed = 0
        self.engines: set[str] = set()
        self.wall = 0.0

    # -- evaluation of one round ----------------------------------------------------------------
    def _evaluate(self, coords: np.ndarray):
        r = len(self.coords)
        n_done = sum(len(c) for c in self.coords)
        if n_done + len(coords) > self.cfg.max_points:
            raise StabjaxError(f"refinement needs more than refine.max_points = {self.cfg.max_points} points "
                               f"(round {r}: {n_done} done, {len(coords)} more); raise it (finished rounds are kept and "
                               "re-used) or coarsen the tolerance")
        saved = self.store.load(r) if self.store is not None else None
        if saved is not None:
            old, res = saved
            if old.shape != coords.shape or not np.array_equal(old, coords):
                raise StabjaxError(f"{self.store.path(r)} does not hold the points this run asks for; "
                                   "pass --restart to discard the partial run")
            self.n_resumed += 1
        else:
            values = np.stack([self.fine[a][coords[:, a]] for a in range(self.D)], axis=1)
            p = _check(self.plan, point_params(self.plan, values))
            res = {k: np.asarray(v) for k, v in self.solve_points(p).items()}
            if self.cfg.label == "outcome" and "outcome" not in res:
                from .basin import point_outcomes

                res["outcome"] = point_outcomes(self.plan, p, res, len(coords))
            engine = getattr(self.solve_points, "engine", "")
            if engine:
                self.engines.add(engine)
            if self.store is not None:
                self.store.save(r, coords, res)
        lab, share = _labels(self.plan, self.cfg, res, len(coords))
        self.lab[tuple(coords.T)] = lab
        self.coords.append(coords)
        self.results.append(res)
        self.point_labels.append(lab)
        self.point_share.append(share)

    # -- cell geometry --------------------------------------------------------------------------
    def cell_edges(self, lo, ext):
        """Label arrays along each edge of a cell (1-D: the interval itself), with their axis and origin."""
        if self.D == 1:
            return [(0, (lo[0],), self.lab[lo[0]: lo[0] + ext[0] + 1])]
        (i, j), (di, dj) = lo, ext
        return [(0, (i, j), self.lab[i: i + di + 1, j]), (0, (i, j + dj), self.lab[i: i + di + 1, j + dj]),
                (1, (i, j), self.lab[i, j: j + dj + 1]), (1, (i + di, j), self.lab[i + di, j: j + dj + 1])]

    def _straddles(self, lo, ext) -> bool:
        seen = set()
        for _, _, e in self.cell_edges(lo, ext):
            c = self.cls[e]
            seen.update(np.unique(c[c >= 0]).tolist())
            if len(seen) > 1:
                return True
        return False

    def _children(self, lo, ext):
        split = [e > 1 for e in ext]
        halves = []
        for a in range(self.D):
            if split[a]:
                h = ext[a] // 2
                halves.append([(lo[a], h), (lo[a] + h, h)])
            else:
                halves.append([(lo[a], ext[a])])
        if self.D == 1:
            return [((x[0],), (x[1],)) for x in halves[0]]
        return [((x[0], y[0]), (x[1], y[1])) for x in halves[0] for y in halves[1]]

    def _corners(self, lo, ext):
        if self.D == 1:
            return [(lo[0],), (lo[0] + ext[0],)]
        return [(lo[0] + a * ext[0], lo[1] + b * ext[1]) for a in (0, 1) for b in (0, 1)]

    # -- the loop ---------------------------------------------------------------------------------
    def run(self) -> "Refiner":
        t0 = time.perf_counter()
        grids = np.meshgrid(*[np.arange(0, n, s) for n, s in zip(self.shape, self.step)], indexing="ij")
        self._evaluate(np.stack([g.ravel() for g in grids], axis=1).astype(np.int64))
        if self.D == 1:
            leaves = [((i,), (self.step[0],)) for i in range(0, self.shape[0] - 1, self.step[0])]
        else:
            leaves = [((i, j), self.step) for i in range(0, self.shape[0] - 1, self.step[0])
                      for j in range(0, self.shape[1] - 1, self.step[1])]
        # A cell is split as soon as the labels known on its boundary differ. Known labels only accumulate, so
        # the final tree is the least fixed point of that rule whatever the order of the splits; children that
        # already straddle by known labels (points a finer neighbour put on their edges) are split in the same
        # pass, which saves rounds (latency) and no points.
        while True:
            need: set[tuple[int, ...]] = set()
            new_leaves = []
            work = list(reversed(leaves))
            while work:
                lo, ext = work.pop()
                if max(ext) > 1 and self._straddles(lo, ext):
                    kids = self._children(lo, ext)
                    for clo, cext in kids:
                        need.update(c for c in self._corners(clo, cext) if self.lab[c] < 0)
                    work.extend(reversed(kids))
                else:
                    new_leaves.append((lo, ext))
            leaves = sorted(new_leaves)
            if not need:
                break
            self._evaluate(np.array(sorted(need), dtype=np.int64).reshape(-1, self.D))
        self.leaves = leaves
        self.wall = time.perf_counter() - t0
        return self

    # -- results ----------------------------------------------------------------------------------
    def segments(self) -> list[tuple[int, tuple[int, ...], tuple[int, ...]]]:
        """Boundary segments: (axis, lattice point p, lattice point q) with q after p on that axis,
        consecutive evaluated points on a leaf's edge whose labels fall in different classes."""
        out = set()
        for lo, ext in self.leaves:
            for a, origin, e in self.cell_edges(lo, ext):
                known = np.nonzero(e >= 0)[0]
                for u, w in zip(known[:-1], known[1:]):
                    cu, cw = self.cls[e[u]], self.cls[e[w]]
                    if cu >= 0 and cw >= 0 and cu != cw:
                        p = list(origin)
                        q = list(origin)
                        p[a] += int(u)
                        q[a] += int(w)
                        out.add((a, tuple(p), tuple(q)))
        return sorted(out)

    @property
    def n_points(self) -> int:
        return sum(len(c) for c in self.coords)

    @property
    def total_steps(self) -> int:
        return int(sum(int(np.asarray(r["n_steps"]).sum()) for r in self.results))


# ---- theory -------------------------------------------------------------------------------------


def _margin(plan: Plan, values: np.ndarray) -> tuple[np.ndarray, str]:
    """The main theorem's margin at grid-axis ``values`` (M, D) (first sample), and its name."""
    values = np.asarray(values, float).reshape(-1, len(plan.grid))
    p = point_params(Plan(**{**plan.__dict__, "n_sample": 0, "sample": {}}), values)
    if plan.n_sample:  # the theorems are about parameters; use the first draw for any sampled one
        for k, v in plan.sample.items():
            p[k] = np.broadcast_to(v[0], (len(values), *v.shape[1:])).copy()
    th = plan.system.theory(plan.system.check(p))
    if not th.main or th.main not in th.predicates:
        return np.full(len(values), np.nan), ""
    m = np.broadcast_to(np.asarray(th.predicates[th.main].margin, float), (len(values),))
    return np.array(m), th.main


def theory_distance(plan: Plan, mids: np.ndarray, axis: int, n_scan: int = 513, n_bisect: int = 60) -> np.ndarray:
    """Signed distance along ``axis`` from each point of ``mids`` (S, D) to the nearest zero of the
    main margin on the same line within the axis range; > 0 where the margin is negative at the
    point (outside the guaranteed region). NaN where the line holds no zero."""
    S = len(mids)
    if S == 0:
        return np.zeros(0)
    ax = plan.grid[axis]
    lo, hi = float(np.min(ax.values)), float(np.max(ax.values))
    xs = np.linspace(lo, hi, n_scan)
    pts = np.repeat(mids[:, None, :], n_scan, axis=1)
    pts[:, :, axis] = xs[None, :]
    m, main = _margin(plan, pts.reshape(-1, mids.shape[1]))
    if not main:
        return np.full(S, np.nan)
    m = m.reshape(S, n_scan)
    m_mid, _ = _margin(plan, mids)
    x_mid = mids[:, axis]
    sgn = np.sign(m)
    cross = (sgn[:, :-1] * sgn[:, 1:] <= 0) & (sgn[:, :-1] != sgn[:, 1:]) & np.isfinite(m[:, :-1]) & np.isfinite(m[:, 1:])
    out = np.full(S, np.nan)
    a_lo = np.full(S, np.nan)
    a_hi = np.full(S, np.nan)
    for s in range(S):
        k = np.nonzero(cross[s])[0]
        if len(k) == 0:
            continue
        c = 0.5 * (xs[k] + xs[k + 1])
        j = k[np.argmin(np.abs(c - x_mid[s]))]
        a_lo[s], a_hi[s] = xs[j], xs[j + 1]
    ok = np.isfinite(a_lo)
    if not ok.any():
        return out
    # bisection on every bracketing scan interval at once (the margin need not be linear)
    base = mids[ok].copy()
    lo_x, hi_x = a_lo[ok], a_hi[ok]
    p = base.copy()
    p[:, axis] = lo_x
    m_lo, _ = _margin(plan, p)
    for _ in range(n_bisect):
        mid = 0.5 * (lo_x + hi_x)
        p[:, axis] = mid
        mm, _ = _margin(plan, p)
        left = np.sign(mm) == np.sign(m_lo)
        lo_x = np.where(left, mid, lo_x)
        m_lo = np.where(left, mm, m_lo)
        hi_x = np.where(left, hi_x, mid)
    root = 0.5 * (lo_x + hi_x)
    dist = np.abs(root - x_mid[ok])
    out[ok] = np.where(m_mid[ok] > 0, -dist, dist)
    return out


# ---- dataset --------------------------------------------------------------------------------------


def assemble(ref: Refiner) -> xr.Dataset:
    plan, cfg = ref.plan, ref.cfg
    from .sweep import provenance

    names = [ax.name for ax in plan.grid]
    segs = ref.segments()
    S = len(segs)
    seg_axis = np.array([s[0] for s in segs], np.int8)
    P = np.array([s[1] for s in segs], np.int64).reshape(S, ref.D)
    Q = np.array([s[2] for s in segs], np.int64).reshape(S, ref.D)
    val = lambda C: np.stack([ref.fine[a][C[:, a]] for a in range(ref.D)], axis=1) if len(C) else np.zeros((0, ref.D))
    vp, vq = val(P), val(Q)
    mid = np.empty_like(vp)
    for a, ax in enumerate(plan.grid):  # midpoint in the axis's own metric (log axes: geometric)
        mid[:, a] = np.sqrt(vp[:, a] * vq[:, a]) if ax.log else 0.5 * (vp[:, a] + vq[:, a])
    lab_p = ref.lab[tuple(P.T)] if S else np.zeros(0, np.int16)
    lab_q = ref.lab[tuple(Q.T)] if S else np.zeros(0, np.int16)
    flag = {"flag_values": np.arange(len(cfg.names), dtype=np.int16), "flag_meanings": " ".join(cfg.names)}
    data: dict[str, Any] = {"segment_axis": ("segment", seg_axis, {"long_name": "index of the grid axis the segment "
                                                                 "runs along", "axes": " ".join(names)})}
    for a, (n, ax) in enumerate(zip(names, plan.grid)):
        units = {"units": ax.param.unit} if ax.param.unit else {}
        data[f"{n}_lo"] = ("segment", vp[:, a], {"long_name": f"{n} at the segment's first corner", **units})
        data[f"{n}_hi"] = ("segment", vq[:, a], {"long_name": f"{n} at the segment's second corner", **units})
        data[f"{n}_mid"] = ("segment", mid[:, a], {"long_name": f"{n} at the segment's midpoint", **units})
        data[f"width_{n}"] = ("segment", np.abs(vq[:, a] - vp[:, a]),
                              {"long_name": f"bracket width along {n}", "tolerance": cfg.tol[a], **units})
    data["label_lo"] = ("segment", lab_p, {"long_name": f"{cfg.label} at the first corner", **flag})
    data["label_hi"] = ("segment", lab_q, {"long_name": f"{cfg.label} at the second corner", **flag})
    width_ok = np.all([np.abs(vq[:, a] - vp[:, a]) <= cfg.tol[a] * (1 + 1e-9) for a in range(ref.D)], axis=0) \
        if S else np.zeros(0, bool)
    data["bracketed"] = ("segment", width_ok.astype(np.int8), {"long_name": "1: bracket within the tolerance on every axis"})
    # theory: only segments between the stable outcome and another one say how conservative the theorem is
    main = ""
    if cfg.stable is not None and S:
        st = cfg.names.index(cfg.stable)
        use = (lab_p == st) ^ (lab_q == st)
        for a, n in enumerate(names):
            d = np.full(S, np.nan)
            if use.any():
                d[use] = theory_distance(plan, mid[use], a)
            data[f"theory_distance_{n}"] = ("segment", d, {
                "long_name": f"signed distance along {n} from the segment midpoint to the theorem's zero contour "
                             f"(> 0: outside the guaranteed region, the theorem is conservative; NaN: no zero on the "
                             f"line, or not a {cfg.stable} boundary)"})
    # every evaluated point
    C = np.concatenate(ref.coords) if ref.coords else np.zeros((0, ref.D), np.int64)
    pv = val(C)
    rounds = np.concatenate([np.full(len(c), r, np.int16) for r, c in enumerate(ref.coords)])
    ns = max(plan.n_sample, 1)
    steps = np.concatenate([np.asarray(r["n_steps"]).reshape(len(c), ns).sum(axis=1)
                            for r, c in zip(ref.results, ref.coords)])
    for a, n in enumerate(names):
        data[f"point_{n}"] = ("point", pv[:, a], {"long_name": f"{n} of an evaluated point"})
    data["point_label"] = ("point", np.concatenate(ref.point_labels), {"long_name": f"dominant {cfg.label}", **flag})
    data["point_share"] = ("point", np.concatenate(ref.point_share),
                           {"long_name": "fraction of the point's samples carrying its label"})
    data["point_round"] = ("point", rounds, {"long_name": "round in which the point was evaluated"})
    data["point_steps"] = ("point", steps, {"long_name": "accepted solver steps over the point's samples"})
    # the theorem's margin on a regular grid, so that the plot needs nothing but this file
    nt = 201 if ref.D == 2 else 1001
    tgrid = [np.linspace(float(ax.values.min()), float(ax.values.max()), nt) for ax in plan.grid]
    mesh = np.meshgrid(*tgrid, indexing="ij")
    mt, main = _margin(plan, np.stack([g.ravel() for g in mesh], axis=1))
    coords = {f"{n}_theory": (f"{n}_theory", g, {"long_name": f"{n} (theory grid)"}) for n, g in zip(names, tgrid)}
    if main:
        data["theory_margin"] = (tuple(f"{n}_theory" for n in names), mt.reshape(mesh[0].shape),
                                 {"long_name": f"margin of {main} (> 0: the theorem guarantees stability)"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(provenance(plan))
    full = int(np.prod(ref.shape))
    dist_summary = {}
    for n in names:
        k = f"theory_distance_{n}"
        if k in ds and np.isfinite(ds[k].values).any():
            v = ds[k].values[np.isfinite(ds[k].values)]
            dist_summary[n] = {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}
    ds.attrs.update(
        kind="refine", theory_main=main, refine_json=json.dumps({**asdict(cfg), "tol": list(cfg.tol)}),
        axes=" ".join(names), label=cfg.label, label_names=" ".join(cfg.names), stable=cfg.stable or "",
        pair=" ".join(cfg.pair) if cfg.pair else "", horizon=cfg.horizon, rounds=len(ref.coords),
        n_points=ref.n_points, n_trajectories=ref.n_points * ns, total_steps=ref.total_steps,
        lattice_shape=list(ref.shape), full_grid_points=full, full_grid_trajectories=full * ns,
        n_segments=S, n_unbracketed=int(S - width_ok.sum()), rounds_resumed=ref.n_resumed,
        wall_time_s=float(ref.wall), engine=",".join(sorted(ref.engines)) or "resumed",
        theory_distance_json=json.dumps(dist_summary),
    )
    return ds


# ---- entry points -------------------------------------------------------------------------------


def _fingerprint(plan: Plan) -> str:
    """The plan's fingerprint plus the resolved solver and classifier settings (a --t1 override is not in the spec)."""
    import hashlib

    spec = dict(plan.spec)
    if isinstance(spec.get("refine"), Mapping):  # max_points only stops a run: raising it resumes the same one
        spec["refine"] = {k: v for k, v in spec["refine"].items() if k != "max_points"}
    same = Plan(**{**plan.__dict__, "spec": spec})
    blob = json.dumps({"plan": same.fingerprint(), "integrate": plan.icfg.__dict__,
                       "verdict": {k: repr(v) for k, v in plan.vcfg.__dict__.items()}}, sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def refine_plan(plan: Plan, out: str | Path | None = None, *, solve_points: SolvePoints | None = None,
                restart: bool = False, keep_partial: bool = False, plot: bool = False) -> xr.Dataset:
    """Run the refinement described by ``plan.spec["refine"]``; write ``out`` (netCDF) if given."""
    cfg = refine_config(plan)
    store = RoundStore(Path(out), _fingerprint(plan), restart) if out is not None else None
    ref = Refiner(plan, cfg, solve_points, store).run()
    ds = assemble(ref)
    if out is not None:
        from .sweep import write

        write(ds, out)
        if plot:
            plot_refine(ds, Path(out).with_suffix(".png"))
        if not keep_partial:
            store.remove()
    return ds


def refine_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, t1: float | None = None,
                **kw) -> xr.Dataset:
    """Load (if a path), plan and refine a spec with a ``[refine]`` section."""
    if isinstance(spec, (str, Path)):
        spec = load_spec(spec)
    if "refine" not in spec:
        raise ValidationError("refine", "the spec has no [refine] section")
    return refine_plan(make_plan(spec, t1=t1), out, **kw)


def format_summary(ds: xr.Dataset) -> str:
    lines = [f"{ds.attrs['n_segments']} boundary segments ({ds.attrs['n_unbracketed']} wider than the tolerance) "
             f"from {ds.attrs['n_points']} points ({ds.attrs['n_trajectories']} trajectories, "
             f"{ds.attrs['total_steps']:,} steps, {ds.attrs['rounds']} rounds); the full lattice of the same resolution "
             f"({' x '.join(map(str, np.atleast_1d(ds.attrs['lattice_shape'])))}) holds {ds.attrs['full_grid_points']:,}"]
    summ = json.loads(ds.attrs.get("theory_distance_json", "{}"))
    for n, s in summ.items():
        lines.append(f"distance to the {ds.attrs['theory_main']} boundary along {n} (> 0: theorem conservative): "
                     f"median {s['median']:+.4g}, range [{s['min']:+.4g}, {s['max']:+.4g}]")
    return "\n".join(lines)


# ---- plot ---------------------------------------------------------------------------------------


def plot_refine(ds: xr.Dataset, out: str | Path | None = None, ax=None):
    """Evaluated points (coloured by label), bracketed boundary midpoints, and the theorem's boundary."""
    from .plotting import plt, symbol
    from matplotlib.lines import Line2D

    names = ds.attrs["axes"].split()
    lnames = ds.attrs["label_names"].split()
    colors = list(V.COLORS) if ds.attrs.get("label") == "verdict" else \
        [plt.get_cmap("tab10")(i % 10) for i in range(len(lnames))]
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 5.2), constrained_layout=True)
    else:
        fig = ax.figure
    lab = ds["point_label"].values
    handles = []
    main = ds.attrs.get("theory_main", "")
    unit = lambda n: f" [{ds[n + '_mid'].attrs['units']}]" if "units" in ds[n + "_mid"].attrs else ""
    if len(names) == 2:
        xd, yd = names[1], names[0]  # same orientation as plot_sweep: second axis horizontal
        for c in np.unique(lab):
            sel = lab == c
            ax.scatter(ds[f"point_{xd}"].values[sel], ds[f"point_{yd}"].values[sel], s=4, color=colors[c], lw=0)
            handles.append(Line2D([], [], color=colors[c], marker="o", ls="", label=lnames[c]))
        ax.plot(ds[f"{xd}_mid"].values, ds[f"{yd}_mid"].values, "k.", ms=2.5)
        handles.append(Line2D([], [], color="k", marker=".", ls="", label="bracketed boundary (midpoints)"))
        if "theory_margin" in ds:
            m = ds["theory_margin"].transpose(f"{yd}_theory", f"{xd}_theory").values
            if np.nanmin(m) < 0 < np.nanmax(m):
                ax.contour(ds[f"{xd}_theory"].values, ds[f"{yd}_theory"].values, m, levels=[0.0], colors="k",
                           linewidths=2.0)
                handles.append(Line2D([], [], color="k", lw=2, label=f"theory boundary ({main})"))
        ax.set_xlabel(symbol(xd) + unit(xd))
        ax.set_ylabel(symbol(yd) + unit(yd))
    else:
        xd = names[0]
        x = ds[f"point_{xd}"].values
        for c in np.unique(lab):
            sel = lab == c
            ax.scatter(x[sel], np.full(sel.sum(), c), s=14, color=colors[c], label=lnames[c], zorder=3)
        for i, (lo, hi) in enumerate(zip(ds[f"{xd}_lo"].values, ds[f"{xd}_hi"].values)):
            ax.axvspan(min(lo, hi), max(lo, hi), color="0.6", alpha=0.5, label="bracketed boundary" if i == 0 else None)
        if "theory_margin" in ds:
            from .plotting import zero_crossings

            for i, xc in enumerate(zero_crossings(ds[f"{xd}_theory"].values, ds["theory_margin"].values)):
                ax.axvline(xc, color="k", lw=2, label=f"theory boundary ({main})" if i == 0 else None)
        ax.set_yticks(range(len(lnames)), lnames)
        ax.set_xlabel(symbol(xd) + unit(xd))
        ax.legend(fontsize=8)
    if handles:
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, fontsize=8, frameon=False)
    t1 = json.loads(ds.attrs.get("integrate_json", "{}")).get("t1", float("nan"))
    ax.set_title(f"{ds.attrs.get('system', '')}: {ds.attrs.get('sweep_name', '')} refined (horizon {ds.attrs['horizon']:g}"
                 f", t1 = {t1:g}; {ds.attrs['n_points']} of {ds.attrs['full_grid_points']} lattice points)", fontsize=9)
    from .plotting import save

    return save(fig, out, own)


def run_cli(spec: Mapping[str, Any], out: Path, *, t1: float | None = None, plot: bool = True, restart: bool = False,
            console=None, err_console=None, executor=None) -> xr.Dataset:
    """`stabjax sweep SPEC` for a spec with a [refine] section: refine, write ``out`` (+ .png), print a summary.

    ``executor`` (a started :class:`stabjax.distributed.DaskExecutor`): each round's points run on its workers.
    """
    plan = make_plan(spec, t1=t1)
    refine_config(plan)  # every field checked before anything is integrated or written
    solve_points = executor.points_solver(plan) if executor is not None else None
    try:
        ds = refine_plan(plan, out, restart=restart, plot=plot, solve_points=solve_points)
    except KeyboardInterrupt:
        if err_console is not None:
            err_console.print(f"[yellow]interrupted: finished rounds are kept in {out}.partial; "
                              "run the same command to resume[/yellow]")
        import typer

        raise typer.Exit(130)
    pr = console.print if console is not None else print
    pr(f"wrote {out}  ({ds.attrs['wall_time_s']:.1f} s)")
    pr(format_summary(ds), highlight=False) if console is not None else pr(format_summary(ds))
    if plot:
        pr(f"wrote {Path(out).with_suffix('.png')}")
    return ds
