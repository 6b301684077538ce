"""The late-window features of every observable, folded checkpoint by checkpoint inside every engine.

Per observable the fold keeps :data:`ROWS`: the window's max, min, sum, the sum of squared deviations
from ``ref`` (the window's first value), the count of checkpoints, the last value and ``ref``;
:func:`summaries` turns them into ``feat_max``, ``feat_min``, ``feat_mean``, ``feat_std`` and
``feat_final``, what outcome rules, templates and discovery read (:mod:`stabjax.model.outcomes`,
:mod:`stabjax.mapping`). The window is the last ``feature_window`` of [t0, t1]
(:func:`stabjax.fold.verdict.update` decides which checkpoints lie in it).

Like the verdict fold these are traced into the fused and diffrax engines and translated to C for the
native engine (elementwise arithmetic and selects only), so every engine computes the same numbers the same
way; a run the fixed-point stop finished takes the features of its equilibrium instead
(:func:`stabjax.fold.stops.at_equilibrium`).
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..config import VerdictConfig

ROWS = ("max", "min", "sum", "sum of squared deviations from ref", "count", "last", "ref")
INIT = (-np.inf, np.inf, 0.0, 0.0, 0.0, np.nan, 0.0)  # before the window


def fold_observation(fe, obs, w, xp=jnp):
    """The feature rows :data:`ROWS` after ``w`` more checkpoints in the window that all observe
    ``obs`` (``w`` = 0 or 1 per checkpoint in :func:`stabjax.fold.verdict.update`), ``obs`` being the last
    value. Lane-wise arithmetic and selects only; with ``xp=numpy`` on a batch (leading dims, ``w`` shaped
    (..., 1)).

    The spread is summed about the window's first value (``ref``), not as a sum of squares: the
    textbook E[x^2] - E[x]^2 keeps the rounding of the squares, ~sqrt(eps) |x| (1.5e-8 for an x at rest
    near 1, far above its spread), which called a trajectory at rest at x = 1 a limit cycle; shifted by ``ref`` the squares are those of the
    deviations themselves (Chan, Golub and LeVeque, Am. Stat. 37, 242 (1983), the shifted-data
    algorithm), and the mean's offset from ``ref`` is taken from the plain sum, to the sum's rounding."""
    F = fe.shape[-1]
    m = min(int(obs.shape[-1]), F)
    o = obs[..., :m].astype(fe.dtype)
    w = xp.asarray(w, fe.dtype)
    has = w > 0
    ref = xp.where(has & (fe[..., 4, :m] == 0), o, fe[..., 6, :m])  # the window's first value
    d = o - ref
    # selected, not weighted by w = 0: an observable that is NaN before the window (a sqrt of a
    # coordinate that starts negative) must not reach the window's sums through 0 * NaN = NaN
    rows = [xp.where(has, xp.maximum(fe[..., 0, :m], o), fe[..., 0, :m]),
            xp.where(has, xp.minimum(fe[..., 1, :m], o), fe[..., 1, :m]),
            xp.where(has, fe[..., 2, :m] + w * o, fe[..., 2, :m]),
            xp.where(has, fe[..., 3, :m] + w * d * d, fe[..., 3, :m]),
            fe[..., 4, :m] + w * xp.ones_like(o), o, ref]
    head = xp.stack(rows, axis=-2)
    return head if m == F else xp.concatenate([head, fe[..., m:]], axis=-1)


def summaries(c, cfg: VerdictConfig) -> dict:
    """feat_max/min/mean/std/final of each observable over the feature window (NaN where it saw none)."""
    F = c["feat"].shape[1] if "feat" in c else 0
    if not (cfg.features and F > 0):
        return {}
    nan = jnp.asarray(jnp.nan, c["feat"].dtype)
    m = min(int(cfg.n_obs) if cfg.n_obs else F, F)
    fe = c["feat"][:, :m]
    cnt = fe[4]
    safe = jnp.where(cnt > 0, cnt, 1.0)
    mean = fe[2] / safe
    shift = (fe[2] - cnt * fe[6]) / safe  # mean - ref, to the plain sum's rounding (:func:`fold_observation`)
    var = jnp.maximum(fe[3] / safe - shift * shift, 0.0)
    none = cnt == 0
    return dict(feat_max=jnp.where(none, nan, fe[0]), feat_min=jnp.where(none, nan, fe[1]),
                feat_mean=jnp.where(none, nan, mean), feat_std=jnp.where(none, nan, jnp.sqrt(var)),
                feat_final=fe[5])
