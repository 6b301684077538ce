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

Labels. A point's label is its ``verdict`` (:mod:`stabjax.fold.verdict`) or, for systems that declare
named outcomes, its ``outcome``; with ``[sample] n > 1`` it is the dominant (most frequent) label
of the point's samples (ties: the lower code). The runner returns a verdict per horizon (results of shape
``(N, n_horizons)``); ``horizon = t`` brackets one of them (default ``t1``), ``horizons = "all"`` or a list
of times brackets each of them in the same run: a cell is split where the labels of *any* horizon differ on
its boundary, so each horizon's boundary is bracketed to the tolerance from one set of points (they are
integrated once, whatever the number of horizons). The dataset's segments carry their ``segment_horizon``;
``point_label`` is the longest horizon's label, ``point_label_by_horizon`` every horizon's.
``pair = ["converged", "flipped"]`` restricts boundaries to adjacent points labelled one of each;
``pair = ["converged", "*"]`` separates one outcome from all the others.

What it can miss: like any grid method, the coarse grid must resolve the regions: an island, or a
boundary that enters and leaves a coarse cell between the same corners, is invisible if no
evaluated point lands in it. The benchmark (``benchmarks/refine_bench.py``, in a source checkout) compares
the refinement against the full lattice and counts any boundary edge of the full grid it did not find.

Theory. For each bracketed segment the signed distance from its midpoint to the zero contour of
the system's main theorem margin (``theory(p).predicates[main].margin``) is measured along each
axis, in that axis's units: positive where the midpoint lies outside the region the theorem
guarantees (margin < 0; the theorem is conservative there, the empirical stable region reaches
beyond it), negative where the theorem claims stability at an empirical boundary.

Running: the refiner is an *explorer* (:class:`Refiner`: ``propose`` the next round's points, ``observe``
their results); it integrates nothing itself. :func:`refine_plan` hands each round's points to the sweep's
runner (:func:`stabjax.run.sweep.run_points`), so a refinement gets what a sweep gets: the plan's engine, chunks
of ``--batch-size``, Dask workers, progress, and a chunk store per round (``<out>.zarr/round_NNNN``,
``--store``/``--keep-store``) from which a killed run resumes without recomputing a finished chunk.

Layout: the [refine] table, its lattice and the point labels are :mod:`stabjax.explore.refine_config`; the plot is
:mod:`stabjax.present.refinement`; here are the explorer, the theory distance and the output dataset.
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from ..fold import stops
from ..errors import StabjaxError, ValidationError
from ..plan.spec import Plan

from .refine_config import RefineConfig, _labels, classes, fine_values, refine_config


# ---- the refiner: an explorer ---------------------------------------------------------------------


class Refiner:
    """Quadtree (2-D) / bisection (1-D) refinement over the integer lattice of a plan's grid, as an explorer:
    :meth:`propose` gives the next round's lattice points (None: done), :meth:`observe` takes their results.
    It integrates nothing itself; :func:`refine_plan` hands each round to the sweep's runner.

    Lattice coordinates: axis ``a`` runs over ``0 .. (n_a - 1) * 2**L_a``; coarse grid points are the
    multiples of ``2**L_a``. ``labs[h]`` holds the label at horizon ``cfg.horizons[h]`` of every evaluated
    site (-1: not evaluated); ``lab`` is the longest horizon's. A cell is ``(lo, ext)``: its lower corner and
    its extent (powers of two) per axis. With several horizons a cell is split where *any* horizon's labels
    differ on its boundary, so every horizon's boundary ends bracketed to the tolerance (a cell none of them
    straddles is never split), from the same runs: the runner returns every horizon's verdict at once.
    """

    def __init__(self, plan: Plan, cfg: RefineConfig):
        self.plan, self.cfg = plan, cfg
        self.D = len(plan.grid)
        self.step = tuple(2**L for L in cfg.levels)
        self.fine = [fine_values(ax.values, ax.log, L) for ax, L in zip(plan.grid, cfg.levels)]
        self.shape = tuple(len(f) for f in self.fine)
        self.H = len(cfg.horizons)
        self.labs = np.full((self.H, *self.shape), -1, np.int16)
        self.cls = np.append(classes(cfg), -1)  # index -1 (unknown) -> class -1
        self.coords: list[np.ndarray] = []  # per round: (P, D) lattice coordinates
        self.results: list[dict[str, np.ndarray]] = []
        self.point_labels: list[np.ndarray] = []
        self.point_share: list[np.ndarray] = []
        self.leaves: list | None = None  # None: the coarse grid is not evaluated yet
        self._final: list = []  # leaves one lattice step wide on every axis: never split, never asked again
        self._wide: list = []  # the other leaves: asked again each round
        self.done = False

    @property
    def lab(self) -> np.ndarray:
        """Labels at the longest horizon bracketed (-1: not evaluated)."""
        return self.labs[-1]

    def values(self, coords: np.ndarray) -> np.ndarray:
        """Grid-axis values (P, D) of lattice points."""
        return np.stack([self.fine[a][coords[:, a]] for a in range(self.D)], axis=1)

    def propose(self) -> np.ndarray | None:
        """Lattice coordinates (P, D) of the next round's points; None when every boundary is bracketed."""
        if self.leaves is None:
            grids = np.meshgrid(*[np.arange(0, n, s) for n, s in zip(self.shape, self.step)], indexing="ij")
            return np.stack([g.ravel() for g in grids], axis=1).astype(np.int64)
        # A cell is split as soon as the labels known on its boundary differ. Known labels only accumulate, so
        # the final tree is the least fixed point of that rule whatever the order of the splits; children that
        # already straddle by known labels (points a finer neighbour put on their edges) are split in the same
        # pass, which saves rounds (latency) and no points.
        need: set[tuple[int, ...]] = set()
        new_leaves = []
        work = self._wide
        while work:  # level by level: every cell of a level asked at once (_straddle_many)
            wide = [c for c in work if max(c[1]) > 1]
            self._final += [c for c in work if max(c[1]) <= 1]
            work = []
            for (lo, ext), split in zip(wide, self._straddle_many(wide)):
                if not split:
                    new_leaves.append((lo, ext))
                    continue
                kids = self._children(lo, ext)
                for clo, cext in kids:
                    need.update(c for c in self._corners(clo, cext) if self.lab[c] < 0)
                work.extend(kids)
        self._wide = new_leaves
        self.leaves = sorted(new_leaves + self._final)
        if not need:
            self.done = True
            return None
        return np.array(sorted(need), dtype=np.int64).reshape(-1, self.D)

    def observe(self, coords: np.ndarray, res: Mapping[str, np.ndarray]):
        """The results of the proposed points (point-major: each point's samples contiguous)."""
        lab, share = _labels(self.plan, self.cfg, res, len(coords))
        self.labs[(slice(None), *coords.T)] = lab.T
        self.coords.append(coords)
        self.results.append(dict(res))
        self.point_labels.append(lab)
        self.point_share.append(share)
        if self.leaves is None:  # the coarse grid's cells
            if self.D == 1:
                self.leaves = [((i,), (self.step[0],)) for i in range(0, self.shape[0] - 1, self.step[0])]
            else:
                self.leaves = [((i, j), self.step) for i in range(0, self.shape[0] - 1, self.step[0])
                               for j in range(0, self.shape[1] - 1, self.step[1])]
            self._wide = [c for c in self.leaves if max(c[1]) > 1]
            self._final = [c for c in self.leaves if max(c[1]) <= 1]

    def run(self, evaluate: Callable[[int, np.ndarray], Mapping[str, np.ndarray]]) -> "Refiner":
        """Explore until every boundary is bracketed: ``evaluate(round, values)`` gives the results of the
        points ``values`` (P, D), point-major. Refuses a round that would pass ``max_points``."""
        while (coords := self.propose()) is not None:
            r, n = len(self.coords), self.n_points
            if n + len(coords) > self.cfg.max_points:
                raise StabjaxError(f"refinement needs more than refine.max_points = {self.cfg.max_points} points "
                                   f"(round {r}: {n} done, {len(coords)} more); raise it (finished rounds are kept "
                                   "and re-used) or coarsen the tolerance")
            self.observe(coords, evaluate(r, self.values(coords)))
        return self

    # -- cell geometry --------------------------------------------------------------------------
    def cell_edges(self, lo, ext, h: int = -1):
        """Label arrays (at horizon index ``h``) along each edge of a cell (1-D: the interval itself), with
        their axis and origin."""
        lab = self.labs[h]
        if self.D == 1:
            return [(0, (lo[0],), lab[lo[0]: lo[0] + ext[0] + 1])]
        (i, j), (di, dj) = lo, ext
        return [(0, (i, j), lab[i: i + di + 1, j]), (0, (i, j + dj), lab[i: i + di + 1, j + dj]),
                (1, (i, j), lab[i, j: j + dj + 1]), (1, (i + di, j), lab[i + di, j: j + dj + 1])]

    def _straddles(self, lo, ext) -> bool:
        """Whether the known labels on the cell's boundary fall in more than one class (at any horizon). Asked
        for every leaf wider than one step in every round (74,000 times on the pendulum's start plane): the
        smallest and largest known class, not a set of them (a set per edge: 18 of 30 s of that refinement)."""
        for h in range(self.H):  # a boundary at any horizon
            c = self.cls[np.concatenate([e for _, _, e in self.cell_edges(lo, ext, h)])]
            c = c[c >= 0]
            if c.size and c.min() != c.max():
                return True
        return False

    def _edges(self, cells):
        """Every point on the cells' edges (as :meth:`cell_edges` lists them, cell by cell, edge by edge): flat
        lattice indices, each point's edge, each edge's axis, and where each cell's points begin."""
        lo = np.array([c[0] for c in cells], np.int64)
        ext = np.array([c[1] for c in cells], np.int64)
        if self.D == 1:  # the interval itself
            starts, strides, lens = lo[:, 0], np.ones(len(cells), np.int64), ext[:, 0] + 1
            axes = np.zeros(len(cells), np.int64)
        else:  # the four edges (flat index into the (n0, n1) lattice)
            n1 = self.shape[1]
            i, j, di, dj = lo[:, 0], lo[:, 1], ext[:, 0], ext[:, 1]
            starts = np.stack([i * n1 + j, i * n1 + j + dj, i * n1 + j, (i + di) * n1 + j], 1).ravel()
            strides = np.tile(np.array([n1, n1, 1, 1], np.int64), len(cells))
            lens = np.stack([di + 1, di + 1, dj + 1, dj + 1], 1).ravel()
            axes = np.tile(np.array([0, 0, 1, 1], np.int64), len(cells))
        seg = np.repeat(np.arange(len(starts)), lens)
        first = np.concatenate([[0], np.cumsum(lens)[:-1]])
        idx = starts[seg] + (np.arange(int(lens.sum())) - first[seg]) * strides[seg]
        return idx, seg, axes, first[:: len(starts) // len(cells)]

    def _straddle_many(self, cells) -> np.ndarray:
        """:meth:`_straddles` of many cells at once (bool, one per cell): the classes on every cell's boundary
        gathered in one index array, the smallest and largest known class per cell by ``reduceat``. In pure
        Python per cell it was 18 of the 30 s of the pendulum's start-plane refinement (74,000 calls)."""
        if not cells:
            return np.zeros(0, bool)
        idx, _, _, bounds = self._edges(cells)
        out = np.zeros(len(cells), bool)
        big = np.iinfo(np.int64).max
        for h in range(self.H):  # a boundary at any horizon
            c = self.cls[self.labs[h].ravel()[idx]].astype(np.int64)
            lo_c = np.minimum.reduceat(np.where(c >= 0, c, big), bounds)
            hi_c = np.maximum.reduceat(c, bounds)
            out |= (hi_c >= 0) & (lo_c < hi_c)
        return out

    def _children(self, lo, ext):
        halves = [[(lo[a], ext[a] // 2), (lo[a] + ext[a] // 2, ext[a] // 2)] if ext[a] > 1 else [(lo[a], ext[a])]
                  for a in range(self.D)]
        if self.D == 1:
            return [((x[0],), (x[1],)) for x in halves[0]]
        return [((x[0], y[0]), (x[1], y[1])) for x in halves[0] for y in halves[1]]

    def _corners(self, lo, ext):
        if self.D == 1:
            return [(lo[0],), (lo[0] + ext[0],)]
        return [(lo[0] + a * ext[0], lo[1] + b * ext[1]) for a in (0, 1) for b in (0, 1)]

    # -- results ----------------------------------------------------------------------------------
    def segments(self, h: int = -1) -> list[tuple[int, tuple[int, ...], tuple[int, ...]]]:
        """Boundary segments at horizon index ``h`` (default: the longest): (axis, lattice point p, lattice
        point q) with q after p on that axis, consecutive evaluated points on a leaf's edge whose labels fall in
        different classes (every leaf's edges at once, :meth:`_edges`)."""
        if not self.leaves:
            return []
        idx, seg, axes, _ = self._edges(self.leaves)
        lab = self.labs[h].ravel()[idx]
        k = np.nonzero(lab >= 0)[0]  # evaluated points, in edge order
        u, w = k[:-1], k[1:]
        cu, cw = self.cls[lab[u]], self.cls[lab[w]]
        pair = (seg[u] == seg[w]) & (cu >= 0) & (cw >= 0) & (cu != cw)
        p = np.stack(np.unravel_index(idx[u[pair]], self.shape), axis=1)
        q = np.stack(np.unravel_index(idx[w[pair]], self.shape), axis=1)
        return sorted({(int(a), tuple(map(int, pp)), tuple(map(int, qq)))
                       for a, pp, qq in zip(axes[seg[u[pair]]], p, q)})

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
    p = dataclasses.replace(plan, points=values, n_sample=0, sample={}).params_for(0, len(values))
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


def assemble(ref: Refiner, *, wall: float = float("nan"), engines: set[str] = frozenset(),
             rounds_resumed: int = 0) -> xr.Dataset:
    plan, cfg = ref.plan, ref.cfg
    from ..run.dataset import cf_attributes
    from ..run.derive import provenance

    names = [ax.name for ax in plan.grid]
    # every horizon's boundary, ascending in horizon (one horizon: the segments as they always were)
    per_h = [ref.segments(h) for h in range(ref.H)]
    segs = [s for hs in per_h for s in hs]
    seg_h = np.concatenate([np.full(len(hs), h, np.int64) for h, hs in enumerate(per_h)])
    S = len(segs)
    seg_axis = np.array([s[0] for s in segs], np.int8)
    P = np.array([s[1] for s in segs], np.int64).reshape(S, ref.D)
    Q = np.array([s[2] for s in segs], np.int64).reshape(S, ref.D)
    val = lambda C: np.stack([ref.fine[a][C[:, a]] for a in range(ref.D)], axis=1) if len(C) else np.zeros((0, ref.D))
    vp, vq = val(P), val(Q)
    mid = np.empty_like(vp)
    for a, ax in enumerate(plan.grid):  # midpoint in the axis's own metric (log axes: geometric)
        mid[:, a] = np.sqrt(vp[:, a] * vq[:, a]) if ax.log else 0.5 * (vp[:, a] + vq[:, a])
    lab_p = ref.labs[(seg_h, *P.T)] if S else np.zeros(0, np.int16)
    lab_q = ref.labs[(seg_h, *Q.T)] if S else np.zeros(0, np.int16)
    horizons = np.asarray(cfg.horizons, float)
    flag = {"flag_values": np.arange(len(cfg.names), dtype=np.int16), "flag_meanings": " ".join(cfg.names)}
    # the axis a segment runs along is a category (flags) with two axes; with one it is always 0, and a
    # one-element flag list comes back from netCDF as a scalar that CF tools (cf_xarray) cannot decode
    axis_flags = {"flag_values": np.arange(ref.D, dtype=np.int8), "flag_meanings": " ".join(names)} if ref.D > 1 else {}
    data: dict[str, Any] = {"segment_axis": ("segment", seg_axis, {
        "long_name": "grid axis the segment runs along (index into the axes attribute)", "axes": " ".join(names),
        **axis_flags}),
        "segment_horizon": ("segment", horizons[seg_h], {
            "long_name": f"verdict horizon T whose {cfg.label}s the segment brackets"})}
    units_of = [{"units": ax.param.unit} if ax.param.unit else {} for ax in plan.grid]  # else "1" (cf_attributes)
    for a, (n, ax) in enumerate(zip(names, plan.grid)):
        units = units_of[a]
        data[f"{n}_lo"] = ("segment", vp[:, a], {"long_name": f"{n} at the segment's first corner", **units})
        data[f"{n}_hi"] = ("segment", vq[:, a], {"long_name": f"{n} at the segment's second corner", **units})
        data[f"{n}_mid"] = ("segment", mid[:, a], {"long_name": f"{n} at the segment's midpoint", **units})
        data[f"width_{n}"] = ("segment", np.abs(vq[:, a] - vp[:, a]),
                              {"long_name": f"bracket width along {n}", "tolerance": cfg.tol[a], **units})
    data["label_lo"] = ("segment", lab_p, {"long_name": f"{cfg.label} at the first corner", **flag})
    data["label_hi"] = ("segment", lab_q, {"long_name": f"{cfg.label} at the second corner", **flag})
    width_ok = np.all([np.abs(vq[:, a] - vp[:, a]) <= cfg.tol[a] * (1 + 1e-9) for a in range(ref.D)], axis=0) \
        if S else np.zeros(0, bool)
    data["bracketed"] = ("segment", width_ok.astype(np.int8), {
        "long_name": "whether the bracket is within the tolerance on every axis",
        "flag_values": np.array([0, 1], np.int8), "flag_meanings": "wider_than_tolerance within_tolerance"})
    # the theorem's margin on a regular grid, so that the plot needs nothing but this file
    nt = 201 if ref.D == 2 else 1001
    tgrid = [np.linspace(float(ax.values.min()), float(ax.values.max()), nt) for ax in plan.grid]
    mesh = np.meshgrid(*tgrid, indexing="ij")
    mt, main = _margin(plan, np.stack([g.ravel() for g in mesh], axis=1))
    # theory: only segments between the stable outcome and another one say how conservative the theorem is
    # (a model that states no theorem gets no theory variables: NaN distances to a contour that is not there)
    if cfg.stable is not None and S and main:
        st = cfg.names.index(cfg.stable)
        use = (lab_p == st) ^ (lab_q == st)
        for a, n in enumerate(names):
            d = np.full(S, np.nan)
            if use.any():
                d[use] = theory_distance(plan, mid[use], a)
            data[f"theory_distance_{n}"] = ("segment", d, {
                "long_name": f"signed distance along {n} from the segment midpoint to the theorem's zero contour "
                             f"(> 0: outside the guaranteed region, the theorem is conservative; NaN: no zero on the "
                             f"line, or not a {cfg.stable} boundary)", **units_of[a]})
    # every evaluated point
    C = np.concatenate(ref.coords) if ref.coords else np.zeros((0, ref.D), np.int64)
    pv = val(C)
    rounds = np.concatenate([np.full(len(c), r, np.int16) for r, c in enumerate(ref.coords)])
    ns = max(plan.n_sample, 1)
    steps = np.concatenate([np.asarray(r["n_steps"]).reshape(len(c), ns).sum(axis=1)
                            for r, c in zip(ref.results, ref.coords)])
    for a, n in enumerate(names):
        data[f"point_{n}"] = ("point", pv[:, a], {"long_name": f"{n} of an evaluated point", **units_of[a]})
    plab, pshare = np.concatenate(ref.point_labels), np.concatenate(ref.point_share)  # (points, horizons)
    data["point_label"] = ("point", plab[:, -1], {"long_name": f"dominant {cfg.label} at the longest horizon "
                                                               f"bracketed (T = {cfg.horizon:g})", **flag})
    data["point_share"] = ("point", pshare[:, -1],
                           {"long_name": "fraction of the point's samples carrying its label (longest horizon)"})
    data["point_label_by_horizon"] = (("point", "horizon"), plab,
                                      {"long_name": f"dominant {cfg.label} at each horizon bracketed", **flag})
    data["point_share_by_horizon"] = (("point", "horizon"), pshare, {
        "long_name": "fraction of the point's samples carrying its label at each horizon bracketed"})
    data["point_round"] = ("point", rounds, {"long_name": "round in which the point was evaluated"})
    data["point_steps"] = ("point", steps, {"long_name": "accepted solver steps over the point's samples"})
    coords = {f"{n}_theory": (f"{n}_theory", g, {"long_name": f"{n} (theory grid)", **u})
              for n, g, u in zip(names, tgrid, units_of)} if main else {}
    coords["horizon"] = ("horizon", horizons, {"long_name": "verdict horizon T bracketed: labels of the prefix "
                                                            "t <= T of each run"})
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
        pair=" ".join(cfg.pair) if cfg.pair else "", horizon=cfg.horizon, horizons=list(cfg.horizons),
        n_segments_by_horizon=[len(hs) for hs in per_h], rounds=len(ref.coords),
        n_points=ref.n_points, n_trajectories=ref.n_points * ns, total_steps=ref.total_steps,
        lattice_shape=list(ref.shape), full_grid_points=full, full_grid_trajectories=full * ns,
        n_segments=S, n_unbracketed=int(S - width_ok.sum()), rounds_resumed=int(rounds_resumed),
        wall_time_s=float(wall), engine=",".join(sorted(engines)) or "resumed",
        theory_distance_json=json.dumps(dist_summary),
    )
    # CF-1.10 as a sweep's dataset (Conventions, title, history, source; units and long_name everywhere; the
    # categorical variables above carry their flags), so that the same tools read both
    cf_attributes(ds, plan, activity="refinement", trajectories=ref.n_points * ns)
    return ds


# ---- entry points -------------------------------------------------------------------------------


def refine_plan(plan: Plan, out: str | Path | None = None, *, store: str | Path | None = None,
                batch_size: int | None = None, progress: bool = False, restart: bool = False,
                keep_store: bool = False, executor=None, overrides: Mapping[str, Any] | None = None,
                on_open: Callable[[], None] | None = None, force: bool = False) -> xr.Dataset:
    """Run the refinement described by ``plan.spec["refine"]``; write ``out`` (netCDF) if given (never over an
    input, an existing file only when a result of this spec or with ``force``: :func:`stabjax.run.outputs.guard_result`).

    Each round's points go through the sweep's runner (:func:`stabjax.run.sweep.run_points`): the plan's engine,
    chunks of ``batch_size``, the executor's Dask workers, and a chunk store per round,
    ``<store>/round_NNNN`` (default store ``<out>.zarr``), so a killed refinement re-run with the same command
    recomputes no finished chunk; ``restart`` discards them; the store is removed after ``out`` is written
    unless ``keep_store``. ``on_open``: called once, when the first round's store accepted the run (as for
    :func:`stabjax.run.sweep.run_plan`). The store's identity is the plan's with the round's points (``[refine]
    max_points`` left out: raising it resumes the same run).
    """
    from ..mapping.classify import classify
    from ..run.store import discard_rounds
    from ..run.outputs import guard_result
    from ..run.sweep import default_store, once, run_points, write

    cfg = refine_config(plan)
    if out is not None:
        guard_result(plan, out, force=force)
    base = Path(store) if store is not None else (default_store(out) if out is not None else None)
    # the default <out>.zarr is the sweep's own (also when named, as the command line names it: resumed, the
    # folder exists and stayed behind, empty); a --store folder elsewhere only if this run makes it
    own_base = base is not None and (store is None or not base.exists()
                                     or (out is not None and base == default_store(out)))
    spec = dict(plan.spec)
    spec["refine"] = {k: v for k, v in spec.get("refine", {}).items() if k != "max_points"}
    rplan = dataclasses.replace(plan, spec=spec)
    engines: set[str] = set()
    resumed = [0]

    opened = once(on_open)  # the caller's word (which file will be replaced), at the first round's store

    plans = [rplan]  # with the recurrence stop: rounds after the first stop at the first round's attractors

    def evaluate(r: int, values: np.ndarray) -> dict[str, np.ndarray]:
        res, info = run_points(plans[-1], values, store=None if base is None else base / f"round_{r:04d}",
                               batch_size=batch_size, progress=progress, restart=restart, keep_store=True,
                               executor=executor, overrides=overrides, on_open=opened)
        if cfg.label == "outcome" and "outcome" not in res:
            # the templates integrated at this round's points (the mapper's state of the points' plan)
            res["outcome"] = classify(dataclasses.replace(plan, points=values), res).codes
        engines.update(info["engines"])
        resumed[0] += info["n_resumed"] == info["n_chunks"]
        if r == 0 and rplan.icfg.attractor_stop and "outcome" in res:
            plans.append(stops.with_known(rplan, res))
        return res

    t0 = time.perf_counter()
    ref = Refiner(plan, cfg).run(evaluate)
    ds = assemble(ref, wall=time.perf_counter() - t0, engines=engines, rounds_resumed=resumed[0])
    if out is not None:
        write(ds, out)
        if not keep_store and base is not None:
            discard_rounds(base, own_base)
    return ds


def refine_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, t1: float | None = None,
                **kw) -> xr.Dataset:
    """Load (if a path), plan and refine a spec with a ``[refine]`` section (``out`` never the spec file read)."""
    from ..run.outputs import plan_result

    plan = plan_result(spec, out, t1=t1, force=bool(kw.get("force", False)), section="refine", caller="refine_spec",
                       kw=kw, runner=refine_plan)
    return refine_plan(plan, out, **kw)
