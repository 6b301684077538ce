"""Continuation: the attractors found at each grid point, matched from point to point along a parameter.

The step after a mapper (Datseris, Rossi and Wagemakers, Chaos 33, 073151 (2023): Attractors.jl's
global continuation, ``AttractorSeedContinueMatch`` with ``MatchBySSSetDistance`` and centroid
distances). It works on plain data, so any mapper's attractors go through it, and it can be run again
on saved output with other settings (as Attractors.jl's ``match_sequentially!``):

* :class:`Found`: one attractor at one grid point -- its members (trajectory indices), its type and
  its representative's scaled feature vector; :func:`found_from_labels` builds them from any labelling
  (a mapper's codes, a saved dataset's ``outcome``) and feature matrix;
* :func:`match_sequentially`: the groups of point k are matched to the attractors alive at point k - 1
  of the **same type** by the distance between representatives, pairs accepted greedily in increasing
  distance while both are free and the distance is below the threshold; an unmatched group is a new
  attractor (a birth), an attractor of point k - 1 left unmatched ends there (a death). So two groups of
  different type never share an identity (a name): a fixed point that turns into a limit cycle is the
  death of the one and the birth of the other (a Hopf bifurcation read from the data), never one
  attractor whose type is a vote over the points. Greedy, not an optimal assignment (as Attractors.jl);
  an attractor that vanishes and reappears gets a new identity;
* :func:`default_threshold`: the threshold when none is given, from the data: the smallest distance
  between the representatives of two attractors found at one grid point. Two distinct attractors were
  seen that close together, so a jump at least that long between neighbouring points is as long as the
  step from one attractor to another: a death and a birth, not a continuation (the scale Attractors.jl's
  proximity mapper takes its radius from, the least distance between attractors). Where no point holds
  two attractors the data give no such scale and the threshold is unbounded (``inf``, Attractors.jl's
  default ``MatchBySSSetDistance(threshold = Inf)``): the types alone then split;
* :func:`merged` gathers each identity's members over the points, :func:`events` lists the births and deaths.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np


@dataclass
class Found:
    """One attractor at one grid point: ``members`` (trajectory indices), ``kind`` (its type, e.g.
    ``fixed_point``) and ``rep`` (its representative's scaled feature vector)."""

    members: np.ndarray
    kind: str
    rep: np.ndarray


def found_from_labels(labels: np.ndarray, x: np.ndarray, n_points: int, kinds: Sequence[str] | None = None
                      ) -> list[list[Found]]:
    """Per grid point, the groups of a labelling: ``labels`` (N,) (-1: none), ``x`` (N, F) scaled
    features, trajectories laid out point-major (``n_points`` points, the same number of samples each);
    ``kinds[label]`` the type of each label (default: the label's own number). The representative is the
    member nearest the group's median features."""
    labels = np.asarray(labels)
    per = len(labels) // n_points
    out = []
    for k in range(n_points):
        idx = np.arange(k * per, (k + 1) * per)
        local = []
        for lab in np.unique(labels[idx]):
            if lab < 0:
                continue
            g = idx[labels[idx] == lab]
            xm = np.median(x[g], axis=0)
            rep = x[g[np.argmin(np.linalg.norm(x[g] - xm, axis=1))]]
            local.append(Found(g, str(lab) if kinds is None else kinds[int(lab)], rep))
        out.append(local)
    return out


def default_threshold(points: Sequence[Sequence[Found]]) -> float:
    """The smallest distance between the representatives of two attractors found at one point (``inf``
    where no point holds two); see the module docstring."""
    d = [float(np.linalg.norm(a.rep - b.rep)) for local in points
         for i, a in enumerate(local) for b in local[i + 1:]]
    return min(d) if d else math.inf


def match_sequentially(points: Sequence[Sequence[Found]], threshold: float | None = None
                       ) -> tuple[list[list[int]], list[list[int]]]:
    """Identities along the points: ``ids[k][j]``, the identity of group j of point k, and ``spans[a]``
    = [first point, last point] of identity a (numbered in order of birth). A group matches only an
    attractor of its own type, less than ``threshold`` away (None: :func:`default_threshold`)."""
    if threshold is None:
        threshold = default_threshold(points)
    ids: list[list[int]] = []
    spans: list[list[int]] = []
    alive: dict[int, Found] = {}  # identity -> its group at the last point
    for k, local in enumerate(points):
        pairs = sorted((float(np.linalg.norm(f.rep - alive[a].rep)), j, a) for j, f in enumerate(local)
                       for a in alive if alive[a].kind == f.kind)
        taken_new, taken_old, match = set(), set(), {}
        for d, j, a in pairs:
            if d < threshold and j not in taken_new and a not in taken_old:
                match[j] = a
                taken_new.add(j)
                taken_old.add(a)
        here, new_alive = [], {}
        for j, f in enumerate(local):
            a = match.get(j)
            if a is None:
                a = len(spans)
                spans.append([k, k])
            spans[a][1] = k
            here.append(a)
            new_alive[a] = f
        ids.append(here)
        alive = new_alive
    return ids, spans


def merged(points: Sequence[Sequence[Found]], ids: Sequence[Sequence[int]], n_ids: int
           ) -> tuple[list[np.ndarray], list[list[str]]]:
    """Per identity: its members over every point (concatenated in point order) and its type at each
    (one type: :func:`match_sequentially` matches within a type)."""
    members: list[list[np.ndarray]] = [[] for _ in range(n_ids)]
    kinds: list[list[str]] = [[] for _ in range(n_ids)]
    for local, here in zip(points, ids):
        for f, a in zip(local, here):
            members[a].append(f.members)
            kinds[a].append(f.kind)
    return [np.concatenate(m) for m in members], kinds


def events(spans: Sequence[Sequence[int]], names: Sequence[str], n_points: int) -> list[dict[str, Any]]:
    """Births and deaths, ``{"attractor", "event": "birth" | "death", "index"}``: a birth at the first grid
    index where an identity is present (after the first point), a death at the first index where it is
    absent again (before the end)."""
    out = []
    for (first, last), name in zip(spans, names):
        if first > 0:
            out.append({"attractor": name, "event": "birth", "index": first})
        if last < n_points - 1:
            out.append({"attractor": name, "event": "death", "index": last + 1})
    out.sort(key=lambda e: (e["index"], e["event"], e["attractor"]))
    return out
