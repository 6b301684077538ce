"""Trajectory verdicts from the whole checkpointed history of the error metric.

Why not the final state: in paper A an unstable body makes excursions towards s = -r in
the slow windows where cos(omega0 t^alpha) > 0 and then returns to within 1e-12 of r, so
the final angle says nothing. The classifier scans the error ``e(t_k)`` at the checkpoint
times and keeps running statistics only (no per-step storage):

* settle time: first checkpoint with ``e < settle_tol``;
* excursions after settling: maximal runs of checkpoints with ``e > excursion_tol``; for
  each its peak; the count, the peaks of the last two, how many excursions passed
  ``flip_tol`` (pi/2), the first flip time, and the largest error after settling;
* the late window ``t >= t0 + (1 - late_fraction)(t1 - t0)``: max error there and the
  least-squares slope of log e against log t (decay exponent = -slope; power-law decay
  in paper A gives a positive exponent close to 1/(mu - 1) asymptotically).

Verdict rules (first match wins), thresholds in :class:`stabjax.system.VerdictConfig`:

1. FAILED     solver did not reach t1 (max_steps, step-size collapse) or any NaN/Inf --
              unless a *finite* checkpoint had already shown the size observable above
              ``diverge_size``: that run is DIVERGED (the failure came after the runaway, e.g.
              an explicit solver chasing spun-up fast variables until max_steps).
2. DIVERGED   size observable above ``diverge_size`` at a finite checkpoint, or never settled
              and the late error grows (slope > ``growth_tol``) while below flip_tol.
3. FLIPPED    final error > flip_tol (resting near the inverted position), or an excursion
              passed flip_tol inside the late window (flips persist up to the horizon).
              A flip early on followed by flip-free windows and convergence is *not* a
              flip verdict (Theorem-type results are local; large initial errors may
              flip once); it is still reported in ``n_flips`` / ``t_first_flip``.
4. CONVERGED  settled, no excursion in the late window, error below converged_tol throughout
              the late window, and the late error not growing (slope <= 0) unless the whole
              late window is below floor_tol (the solver's noise floor, where the slope is noise).
5. UNDECIDED  everything else: e.g. excursions still present but shrinking below pi/2, or
              a slow decay that has not reached converged_tol by t1. A longer horizon
              (``stabjax horizon-check``) is the remedy.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .system import VerdictConfig

CONVERGED, FLIPPED, DIVERGED, UNDECIDED, FAILED = 0, 1, 2, 3, 4
NAMES = ("converged", "flipped", "diverged", "undecided", "failed")
COLORS = ("#2a9d8f", "#e76f51", "#8d0801", "#e9c46a", "#6c757d")

# per-trajectory summary fields written to datasets, with their meaning
SUMMARY_DOC = {
    "verdict": "0 converged, 1 flipped, 2 diverged, 3 undecided, 4 failed",
    "error_t1": "error metric at t1",
    "error_max_settled": "largest error after settling (NaN if never settled)",
    "error_max_late": "largest error in the late window",
    "t_settle": "first checkpoint time with error < settle_tol (NaN if never)",
    "t_first_flip": "first time after settling the error passed flip_tol (NaN if never)",
    "n_excursions": "number of excursions (error > excursion_tol) after settling",
    "n_flips": "number of excursions after settling whose peak passed flip_tol",
    "peak_last": "peak error of the last excursion (NaN if none)",
    "peak_prev": "peak error of the excursion before the last (NaN if fewer than two)",
    "decay_exponent": "-(slope of log error vs log t) over the late window (NaN if error underflows)",
    "size_max": "largest finite value of the size observable (-inf if none; non-finite checkpoints fail the "
                "trajectory unless this already exceeded diverge_size)",
}


def late_start(cfg: VerdictConfig, t0, t1):
    """Start of the late window."""
    return t0 + (1.0 - cfg.late_fraction) * (t1 - t0)


def init_features(n_obs: int, dtype=jnp.float64):
    """Running late-window statistics of every observable (named outcomes, :mod:`stabjax.outcomes`).

    Mean and spread by Welford's update: a limit cycle's angular velocity has mean ~5 and a
    fixed point's spread ~1e-9, so sum-of-squares would lose the spread to cancellation.
    """
    z = jnp.zeros(n_obs, dtype)
    return dict(f_max=z - jnp.inf, f_min=z + jnp.inf, f_mean=z, f_m2=z, f_n=jnp.asarray(0.0, dtype), f_last=z + jnp.nan)


def update_features(c, t, obs_k, cfg: VerdictConfig):
    use = (t >= cfg.feature_from) & jnp.all(jnp.isfinite(obs_k))
    n = c["f_n"] + jnp.where(use, 1.0, 0.0)
    delta = obs_k - c["f_mean"]
    mean = jnp.where(use, c["f_mean"] + delta / jnp.maximum(n, 1.0), c["f_mean"])
    m2 = jnp.where(use, c["f_m2"] + delta * (obs_k - mean), c["f_m2"])
    return dict(f_max=jnp.where(use, jnp.maximum(c["f_max"], obs_k), c["f_max"]),
                f_min=jnp.where(use, jnp.minimum(c["f_min"], obs_k), c["f_min"]),
                f_mean=mean, f_m2=m2, f_n=n, f_last=jnp.where(use, obs_k, c["f_last"]))


def finalize_features(c):
    n = c["f_n"]
    nan = jnp.nan
    return dict(feat_max=jnp.where(n > 0, c["f_max"], nan), feat_min=jnp.where(n > 0, c["f_min"], nan),
                feat_mean=jnp.where(n > 0, c["f_mean"], nan),
                feat_std=jnp.where(n > 0, jnp.sqrt(jnp.maximum(c["f_m2"], 0.0) / jnp.maximum(n, 1.0)), nan),
                feat_final=c["f_last"])


def init(dtype=jnp.float64):
    """Running state of the classifier before the first checkpoint (one trajectory).

    The classifier is a fold over the checkpoints: ``init`` -> ``update`` per checkpoint ->
    ``finalize``. :func:`classify` runs the fold with ``lax.scan`` over saved observables;
    the fused engine (:mod:`stabjax.fast`) runs the same ``update`` inside its step loop,
    so both engines apply exactly the same rules.
    """
    nan = jnp.asarray(jnp.nan, dtype)
    return dict(
        settled=jnp.asarray(False), t_settle=nan, in_exc=jnp.asarray(False), peak=jnp.asarray(0.0, dtype),
        peak_prev=nan, peak_last=nan, n_exc=jnp.asarray(0, jnp.int32), exc_flipped=jnp.asarray(False),
        n_flips=jnp.asarray(0, jnp.int32), t_first_flip=nan, late_exc=jnp.asarray(False),
        late_flip=jnp.asarray(False), max_settled=jnp.asarray(-jnp.inf, dtype), max_late=jnp.asarray(-jnp.inf, dtype),
        fit=jnp.zeros(5, dtype), finite=jnp.asarray(True), e_last=jnp.asarray(jnp.inf, dtype),
        size_max=jnp.asarray(-jnp.inf, dtype),
    )


def init_for(cfg: VerdictConfig, n_obs: int, dtype=jnp.float64):
    """``init`` plus the feature statistics when ``cfg.features``."""
    c = init(dtype)
    if cfg.features:
        c.update(init_features(n_obs, dtype))
    return c


def update(c, t, obs_k, cfg: VerdictConfig, t_late):
    """Fold one checkpoint ``(t, obs_k)`` (obs_k: (n_obs,)) into the running state ``c``."""
    ek = obs_k[0]
    size_k = obs_k[1] if obs_k.shape[0] > 1 else jnp.zeros_like(ek)
    finite = c["finite"] & jnp.all(jnp.isfinite(obs_k))
    ek = jnp.where(jnp.isfinite(ek), ek, jnp.inf)
    # over finite checkpoints only (non-finite ones are recorded in ``finite``), so that a run that
    # grew past diverge_size and then blew up can be told from a NaN run; never NaN (native max)
    size_max = jnp.maximum(c["size_max"], jnp.where(jnp.isfinite(size_k), size_k, -jnp.inf))
    settled = c["settled"] | (ek < cfg.settle_tol)
    t_settle = jnp.where(~c["settled"] & settled, t, c["t_settle"])
    above = settled & (ek > cfg.excursion_tol)
    start = above & ~c["in_exc"]
    peak = jnp.where(start, ek, jnp.where(above, jnp.maximum(c["peak"], ek), c["peak"]))
    # an excursion that starts pushes the last one to prev
    peak_prev = jnp.where(start & (c["n_exc"] > 0), c["peak_last"], c["peak_prev"])
    peak_last = jnp.where(above, peak, c["peak_last"])
    n_exc = c["n_exc"] + start.astype(jnp.int32)
    flipped_now = above & (ek > cfg.flip_tol) & ~c["exc_flipped"]
    exc_flipped = jnp.where(start, ek > cfg.flip_tol, c["exc_flipped"] | (above & (ek > cfg.flip_tol)))
    n_flips = c["n_flips"] + flipped_now.astype(jnp.int32)
    t_first_flip = jnp.where(jnp.isnan(c["t_first_flip"]) & flipped_now, t, c["t_first_flip"])
    late = t >= t_late
    late_exc = c["late_exc"] | (late & above)
    late_flip = c["late_flip"] | (late & above & (ek > cfg.flip_tol))
    max_settled = jnp.where(settled, jnp.maximum(c["max_settled"], ek), c["max_settled"])
    max_late = jnp.where(late, jnp.maximum(c["max_late"], ek), c["max_late"])
    use = late & (ek > 1e-13) & (t > 0) & jnp.isfinite(ek)
    lx, ly = jnp.log(jnp.maximum(t, 1e-300)), jnp.log(jnp.maximum(ek, 1e-300))
    w = use.astype(c["fit"].dtype)
    fit = c["fit"] + w * jnp.stack([jnp.ones_like(lx), lx, ly, lx * lx, lx * ly])
    out = dict(
        settled=settled, t_settle=t_settle, in_exc=above, peak=peak, peak_prev=peak_prev, peak_last=peak_last,
        n_exc=n_exc, exc_flipped=exc_flipped, n_flips=n_flips, t_first_flip=t_first_flip, late_exc=late_exc,
        late_flip=late_flip, max_settled=max_settled, max_late=max_late, fit=fit, finite=finite, e_last=ek,
        size_max=size_max,
    )
    if cfg.features:
        out.update(update_features(c, t, obs_k, cfg))
    return out


def resolve(verdict, failed, size_max, cfg: VerdictConfig):
    """The rules every classifier shares, on top of its own ``verdict`` (rules 1 and 2, size part).

    ``size_max``: largest size observable over the *finite* checkpoints; ``failed``: the solver
    did not reach t1 or a checkpoint was not finite. A finite checkpoint with size above
    ``diverge_size`` is evidence of divergence and wins (also over a later failure); otherwise a
    failure is FAILED; otherwise ``verdict``. Returns int8.
    """
    size_div = size_max > cfg.diverge_size
    return jnp.where(size_div, DIVERGED, jnp.where(failed, FAILED, verdict)).astype(jnp.int8)


def finalize(c, solver_ok, cfg: VerdictConfig):
    """Verdict and summaries from the running state after the last checkpoint."""
    dtype = c["fit"].dtype
    nan = jnp.asarray(jnp.nan, dtype)
    n, sx, sy, sxx, sxy = c["fit"]
    den = n * sxx - sx * sx
    slope = jnp.where((n >= 3) & (den > 0), (n * sxy - sx * sy) / jnp.where(den > 0, den, 1.0), nan)
    e1 = c["e_last"]
    size_max = c["size_max"]

    failed = ~solver_ok | ~c["finite"]
    diverged = ~c["settled"] & (slope > cfg.growth_tol) & (e1 < cfg.flip_tol)
    flipped = (e1 > cfg.flip_tol) | c["late_flip"]
    # Below floor_tol the error sits at the solver's noise floor (~rtol) and its log-log slope is
    # noise of either sign, so the trend is only asked of errors above it. There is no shortcut on
    # the final error alone: in paper A the body returns to ~1e-12 between excursions, so the
    # whole late window must stay below converged_tol.
    not_growing = jnp.isnan(slope) | (slope <= 0.0) | (c["max_late"] < cfg.floor_tol)
    converged = c["settled"] & ~c["late_exc"] & (c["max_late"] < cfg.converged_tol) & not_growing
    rest = jnp.where(diverged, DIVERGED, jnp.where(flipped, FLIPPED, jnp.where(converged, CONVERGED, UNDECIDED)))
    verdict = resolve(rest, failed, size_max, cfg)
    feats = finalize_features(c) if cfg.features else {}
    return dict(**feats,
        verdict=verdict,
        error_t1=e1,
        error_max_settled=jnp.where(c["settled"], c["max_settled"], nan),
        error_max_late=c["max_late"],
        t_settle=c["t_settle"],
        t_first_flip=c["t_first_flip"],
        n_excursions=c["n_exc"],
        n_flips=c["n_flips"],
        peak_last=c["peak_last"],
        peak_prev=c["peak_prev"],
        decay_exponent=-slope,
        size_max=size_max,
    )


def classify(ts: jnp.ndarray, obs: jnp.ndarray, solver_ok: jnp.ndarray, cfg: VerdictConfig, t0: float = 0.0):
    """Classify one trajectory (traced; vmap it). ``obs`` is (K, n_obs): column 0 error, 1 size."""
    t_late = late_start(cfg, t0, ts[-1])

    def step(c, x):
        t, ok = x
        return update(c, t, ok, cfg, t_late), None

    c, _ = jax.lax.scan(step, init_for(cfg, obs.shape[-1], obs.dtype), (ts, obs))
    return finalize(c, solver_ok, cfg)


def counts(verdicts: np.ndarray) -> dict[str, int]:
    v = np.asarray(verdicts).ravel()
    return {name: int((v == i).sum()) for i, name in enumerate(NAMES)}
