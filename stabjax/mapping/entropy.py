"""Basin entropy S_b and boundary basin entropy S_bb (Daza, Wagemakers, Georgeot, Guéry-Odelin and
Sanjuán, Sci. Rep. 6, 31416 (2016)) of a 2-D grid of starts.

The outcome of every start on a regular grid is known (``[grid]`` over two initial conditions, no
``[sample]``). Tile the grid into N boxes of eps x eps cells; in box i let p_ij be the share of its
cells with outcome j. Then (natural logarithms, nats; eq. (2)-(5) of the paper)

    S_i  = -sum_j p_ij ln p_ij
    S_b  = (1/N)   sum_i S_i                 (<= ln N_A for N_A outcomes)
    S_bb = (1/N_b) sum_{i: S_i > 0} S_i      (N_b boxes that hold more than one outcome)

S_bb > ln 2 is a sufficient (not necessary) sign of a fractal boundary (the paper's "ln 2 criterion"):
a smooth boundary splits the boxes it crosses in two parts of varying share, whose mean entropy
stays below ln 2. Every outcome counts as one colour, ``unclassified``, ``failed`` and escapes
included (they are fates of the start as much as the attractors). Rows and columns that do not fill
a whole box at the high end of an axis are left out (as Attractors.jl's ``basin_entropy``, which
requires whole boxes, would refuse them); the number of cells used is reported.

Box: eps = 5 cells per side (the dataset's attributes name it; :func:`basin_entropy` takes any
other). S_b depends on eps (Daza et al. relate it to the uncertainty exponent of the boundary):
compare values at the same box size.
"""
from __future__ import annotations

import math

import numpy as np

DEFAULT_BOX = 5
LN2 = math.log(2.0)


def basin_entropy(labels: np.ndarray, eps: int = DEFAULT_BOX) -> dict[str, float]:
    """S_b, S_bb and the counts behind them for a 2-D integer label array (rows x columns)."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ValueError(f"basin entropy needs a 2-D grid of outcomes, got shape {lab.shape}")
    eps = int(eps)
    if eps < 1:
        raise ValueError(f"box size must be >= 1 cell, got {eps}")
    n0, n1 = (lab.shape[0] // eps) * eps, (lab.shape[1] // eps) * eps
    if n0 == 0 or n1 == 0:
        raise ValueError(f"the grid {lab.shape} holds no whole {eps} x {eps} box")
    boxes = lab[:n0, :n1].reshape(n0 // eps, eps, n1 // eps, eps).transpose(0, 2, 1, 3).reshape(-1, eps * eps)
    values = np.unique(boxes)
    p = np.stack([(boxes == v).mean(axis=1) for v in values], axis=1)  # (N, N_A)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_i = -np.sum(np.where(p > 0, p * np.log(p), 0.0), axis=1)
    boundary = s_i > 0
    n_b = int(boundary.sum())
    s_bb = float(s_i[boundary].mean()) if n_b else 0.0
    return {"S_b": float(s_i.mean()), "S_bb": s_bb, "n_boxes": int(len(s_i)), "n_boundary_boxes": n_b,
            "box": eps, "cells_used": int(n0 * n1), "n_outcomes": int(len(values)),
            "fractal_by_ln2": bool(s_bb > LN2)}


def applies(plan, eps: int = DEFAULT_BOX) -> bool:
    """A grid of two axes over initial conditions and no sampling (one start per cell) that holds at
    least one whole box."""
    return (len(plan.grid) == 2 and not plan.n_sample
            and all(ax.param.kind == "initial" and ax.values.ndim == 1 and ax.size >= eps for ax in plan.grid))
