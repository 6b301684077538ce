"""Trajectory verdicts from the whole checkpointed history of the error metric, at several horizons.

Why not the final state: in paper A an unstable body makes excursions towards s = -r in the slow
windows where cos(omega0 t^alpha) > 0 and then returns to within 1e-12 of r, so the final angle
says nothing. Why not a linear late window either: those windows are spaced geometrically in t
(t_k = (2 pi k / omega0)^(1/alpha)), so "the last half of the horizon" cuts the sequence of flips
wherever the horizon happens to fall; a run to t1 = 1e5 whose last flip came at 2.5e4 was called
converged. Every window below is therefore a window in **log-time**, relative to the horizon T
(measured from t0), and the rules use the recurrence of the excursions themselves.

The classifier is a streaming fold over the checkpoints (``init`` -> ``update`` per checkpoint ->
``finalize``; no per-step or per-checkpoint storage). The same fold classifies every *prefix*
t <= T_h of the trajectory for the horizons T_h of :attr:`VerdictConfig.horizons` (default: t1 and
the three decades below it): each per-horizon entry of the running state is updated while
t <= T_h and frozen afterwards, so one integration gives the verdicts at all horizons.

Running statistics (per horizon, over t <= T):

* settle time: first checkpoint with ``e < settle_tol``; the approach from a large initial error
  before it is the initial transient and never counts as an excursion;
* excursions after settling: maximal runs of checkpoints with ``e > excursion_tol``; for each its
  start time and peak; the peaks of the last two (their ratio is the **trend**), the start times of
  the last two (their ratio q in log-time is the observed **recurrence ratio**), the last time above
  ``excursion_tol``; flips (excursions past ``flip_tol`` = pi/2): count, first and last time;
* late window ``t - t0 >= (T - t0) 10^-late_decades`` (default: the last decade): the least-squares
  log-log slope of the error there (growth test); flips and excursions are judged against it;
* convergence window ``t - t0 >= (T - t0) 10^-converge_decades`` (default: the last half decade):
  largest error after settling there (the approach before the first settling is the initial
  transient). Half a decade because a decay crosses converged_tol once; recurrent bumps are what
  the excursion rules (a decade, and the recurrence ratio) are for;
* decay law: sums for a least-squares fit of log e against log(t - t0) in half-decade bins, using
  only settled checkpoints whose error is above the noise floor ``floor_tol`` (and below
  ``settle_tol``). The fit for horizon T uses the last ``fit_decades`` (default 1) decade of bins
  below T that end at the last bin holding such points: the tail in log-time where the decay is a
  power law, before the solver's noise floor. Reported with its standard error and the number of
  points; NaN with ``decay_reason`` 1 (never settled), 2 (fewer than ``fit_min_points`` points above
  the noise floor in that tail: e.g. a fast decay reaching the floor, or a horizon too short) or
  3 (non-finite history).

Verdict rules at horizon T (first match wins), thresholds in :class:`stabjax.model.system.VerdictConfig`:

1. FAILED     the solver did not reach T (max_steps, step-size collapse, escape) or a checkpoint up
              to T is NaN/Inf -- unless a *finite* checkpoint had already shown the size observable
              above ``diverge_size``: that run is DIVERGED (the failure came after the runaway).
2. DIVERGED   size observable above ``diverge_size`` at a finite checkpoint, or never settled and
              the late error grows (slope > ``growth_tol``) while below flip_tol.
3. FLIPPED    "never converged": resting past flip_tol at T; or a flip after settling **within the
              last decade** of the horizon (t - t0 > (T - t0)/10), whatever T is; or the last two
              excursion peaks **do not shrink** (peak_last >= shrink_ratio * peak_prev) and one of
              them passed flip_tol -- a recurrent instability, wherever the flips happened.
4. CONVERGED  settled for at least converge_decades in log-time (T - t0 >= 10^converge_decades
              (t_settle - t0)); excursion peaks shrinking (or fewer than two); **quiet since the last
              excursion** for at least max(10^late_decades, q^2) times its time in log-time:
              T - t0 >= max(10, q^2) (t_last_excursion_end - t0), q = ratio of the start times of
              the last two excursions (a geometric recurrence with ratio q would have shown its next
              excursion by q (t_last - t0); the square leaves room for the gaps to keep growing);
              the error below converged_tol throughout the convergence window and not growing over the
              late window (slope <= 0) unless the convergence window is all below floor_tol (the
              noise floor, where the slope is noise).
5. UNDECIDED  everything else: shrinking excursions still present late (trend in ``peak_ratio``,
              time in ``t_last_excursion``), non-shrinking excursions below pi/2, a single flip
              followed by less than a decade of quiet, or a slow decay above converged_tol at T.

Paper A's example (monoaxial, mu = 3/2, sigma = 4/3, the paper's initial condition): for alpha
~0.45 the body flips once at t ~ 70 after settling and then converges; that run is FLIPPED at
horizons T < ~700 (the flip is in the last decade), UNDECIDED while the error is still above
converged_tol, and CONVERGED beyond. For alpha = 1/3 flips recur at t ~ 3e2, 2e3, 8e3, 2e4, 3.4e4
with shrinking peaks (the one at 3.4e4 peaks on pi/2 itself): FLIPPED at every horizon up to
~2e5-3.4e5, then UNDECIDED while the (shrinking,
sub-pi/2) excursions go on.

Engine contract: ``update`` is traced by JAX and evaluated lane-wise by the native (C) and fused
(XLA) engines, so it uses elementwise operations, comparisons, selects and static slices only;
the horizons and bin edges are compile-time constants of a bound :class:`VerdictConfig`
(:func:`bind`, called when a plan is made). ``init(dtype)`` gives a state of fixed capacities
(``MAX_HORIZONS`` horizons, ``N_BINS`` decay bins, ``MAX_FEATURE_OBS`` observables with features)
that fits every config (slots beyond the configured horizons are carried unchanged);
``init(dtype, cfg)`` a state sized to ``cfg``, which costs the engines less per checkpoint.
An unbound config (``t1 is None``) assumes t0 = 0 and takes t1 from ``t_late`` (which
:func:`late_start` sets to t1).
"""
from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ValidationError
from ..config import VERDICT_NAMES, VerdictConfig
from . import features as FT

CONVERGED, FLIPPED, DIVERGED, UNDECIDED, FAILED = 0, 1, 2, 3, 4
NAMES = VERDICT_NAMES
COLORS = ("#2a9d8f", "#e76f51", "#8d0801", "#e9c46a", "#6c757d")

MAX_HORIZONS = 8
BINS_PER_DECADE = 2
N_BINS = 10  # half-decade bins of t - t0 over the 5 decades below t1, where the engines' checkpoints start
MAX_FEATURE_OBS = 8
_TOL = 1e-9  # relative slack on horizon and bin edges (checkpoint times computed elsewhere)

DECAY_REASONS = {0: "ok", 1: "never settled", 2: "too few points above the noise floor in the tail",
                 3: "non-finite history"}

# per-trajectory summary fields written to datasets, with their meaning ("at T": at each horizon)
SUMMARY_DOC = {
    "verdict": "at each horizon T: 0 converged, 1 flipped, 2 diverged, 3 undecided, 4 failed",
    "error_t1": "error metric at the horizon (last checkpoint <= T)",
    "error_max_settled": "largest error after settling, up to T (NaN if never settled)",
    "error_max_late": "largest error after settling over the last converge_decades (1/2) of T in log-time",
    "t_settle": "first checkpoint time with error < settle_tol (NaN if never up to T)",
    "t_first_flip": "first time after settling the error passed flip_tol (NaN if never up to T)",
    "t_last_flip": "last time after settling the error was above flip_tol (NaN if never up to T)",
    "t_last_excursion": "start time of the last excursion after settling, up to T (NaN if none)",
    "n_excursions": "number of excursions (error > excursion_tol) after settling, up to T",
    "n_flips": "number of excursions after settling whose peak passed flip_tol, up to T",
    "peak_last": "peak error of the last excursion up to T (NaN if none)",
    "peak_prev": "peak error of the excursion before the last (NaN if fewer than two)",
    "peak_ratio": "trend: peak_last / peak_prev (< 1 shrinking; NaN if fewer than two excursions)",
    "recurrence_ratio": "(start of last excursion - t0) / (start of the one before - t0) (NaN if < 2)",
    "decay_exponent": "-(slope of log error vs log(t - t0)) over the last decade above the noise floor "
                      "(NaN: see decay_reason)",
    "decay_exponent_se": "standard error of decay_exponent (least squares)",
    "decay_n": "number of checkpoints in the decay fit",
    "decay_t_end": "end of the decay fit's window (last half-decade bin with points above the floor)",
    "decay_reason": "0 ok, 1 never settled, 2 too few points above the noise floor in the tail, "
                    "3 non-finite history",
    "size_max": "largest finite value of the size observable up to T (-inf if none; non-finite checkpoints "
                "fail the trajectory unless this already exceeded diverge_size)",
    "feat_max": "largest value of each observable over the feature window",
    "feat_min": "smallest value of each observable over the feature window",
    "feat_mean": "mean of each observable over the feature window (checkpoints)",
    "feat_std": "standard deviation of each observable over the feature window (checkpoints)",
    "feat_final": "each observable at the last checkpoint",
}

_FEATURES = ("feat_max", "feat_min", "feat_mean", "feat_std", "feat_final")
# trailing dims of the per-trajectory results; keys not listed are (N,)
TRAILING_DIMS: dict[str, tuple[str, ...]] = {
    **{k: ("horizon",) for k in SUMMARY_DOC if not k.startswith("feat_")},
    **{k: ("observable",) for k in _FEATURES},
}


# ---- configuration --------------------------------------------------------------------------------


def default_horizons(cfg: VerdictConfig, t0: float, t1: float) -> np.ndarray:
    """t1 and the ``n_horizon_decades`` decades below it: t0 + (t1 - t0) 10^-k, ascending."""
    k = np.arange(int(cfg.n_horizon_decades), -1, -1, dtype=float)
    h = t0 + (t1 - t0) * 10.0 ** (-k)
    h[-1] = t1
    return h


def bind(cfg: VerdictConfig, t0: float, t1: float, *, horizons=None, n_obs: int | None = None,
         field: str = "verdict.horizons") -> VerdictConfig:
    """Fix the classifier's frame for one plan: t0, t1, the horizons (absolute times, ascending,
    last = t1; ``None``: those of ``cfg`` if any lie in (t0, t1], else :func:`default_horizons`)
    and the number of observables. The result is hashable and makes every window a constant."""
    t0, t1 = float(t0), float(t1)
    if not t1 > t0:
        raise ValidationError("integrate.t1", f"must be > t0 = {t0}, got {t1}")
    if horizons is None:
        horizons = cfg.horizons if cfg.horizons else None
    if horizons is None or len(horizons) == 0:
        hs = default_horizons(cfg, t0, t1)
    else:
        try:
            hs = np.asarray([float(h) for h in np.ravel(np.asarray(horizons, dtype=object))], dtype=float)
        except (TypeError, ValueError):
            raise ValidationError(field, f"must be a list of times, got {horizons!r}") from None
        bad = hs[~np.isfinite(hs) | (hs <= t0) | (hs > t1 * (1 + 1e-12))]
        if bad.size:
            raise ValidationError(field, f"horizons must lie in (t0, t1] = ({t0:g}, {t1:g}]; got {bad[0]:g}")
        hs = np.unique(np.append(hs[hs < t1], t1))
    if len(hs) > MAX_HORIZONS:
        raise ValidationError(field, f"at most {MAX_HORIZONS} horizons (t1 included), got {len(hs)}")
    if not 0 < cfg.late_decades <= 3:
        raise ValidationError("verdict.late_decades", f"must be in (0, 3], got {cfg.late_decades}")
    if not (cfg.fit_decades * BINS_PER_DECADE == round(cfg.fit_decades * BINS_PER_DECADE) and cfg.fit_decades > 0):
        raise ValidationError("verdict.fit_decades", f"must be a positive multiple of 1/{BINS_PER_DECADE}, "
                              f"got {cfg.fit_decades}")
    if not 0 < cfg.feature_window <= 1:
        raise ValidationError("verdict.feature_window", f"must be in (0, 1], got {cfg.feature_window}")
    n = int(cfg.n_obs if n_obs is None else n_obs)
    if cfg.features and n > MAX_FEATURE_OBS:
        raise ValidationError("verdict.features", f"features of at most {MAX_FEATURE_OBS} observables, "
                              f"the system has {n}")
    return cfg.replace(t0=t0, t1=t1, horizons=tuple(float(h) for h in hs), n_obs=n,
                       features=bool(cfg.features))


def horizon_times(cfg: VerdictConfig, t0: float | None = None, t1: float | None = None) -> np.ndarray:
    """The horizons of a (bound, or bound now with t0/t1) config: absolute times, last = t1."""
    if cfg.t1 is None:
        cfg = bind(cfg, 0.0 if t0 is None else t0, t1)
    return np.asarray(cfg.horizons, dtype=float)


def checkpoint_times(ts: np.ndarray, cfg: VerdictConfig) -> np.ndarray:
    """The checkpoint grid with every horizon of a bound ``cfg`` merged in exactly (so that each
    horizon's verdict sees the state *at* that horizon). Engines: ``ts = V.checkpoint_times(
    icfg.checkpoints(), vcfg)``. Without it a horizon's verdict uses the checkpoints <= it."""
    ts = np.asarray(ts, dtype=float)
    if cfg.t1 is None:
        return ts
    return np.unique(np.concatenate([ts, np.asarray(cfg.horizons, dtype=float)]))


def late_start(cfg: VerdictConfig, t0, t1):
    """What the engines pass to :func:`update` as ``t_late``: t1 (the windows are in log-time
    relative to each horizon now; an unbound config takes t1 from here)."""
    return t1


def _n_horizons(cfg: VerdictConfig) -> int:
    return len(cfg.horizons) if cfg.t1 is not None else int(cfg.n_horizon_decades) + 1


def _frame(cfg: VerdictConfig, span=None, cap: int = MAX_HORIZONS):
    """(t0, span, U (cap,) horizon offsets from t0, n_h, bin lower/upper edges (N_BINS,)).
    Constants (NumPy) for a bound config; for an unbound one, from ``span`` (t1 - t0, t0 = 0)."""
    if cfg.t1 is not None:
        t0 = float(cfg.t0)
        span = float(cfg.t1) - t0
        u = np.asarray(cfg.horizons, dtype=float) - t0
        xp = np
    else:
        t0 = 0.0
        k = np.arange(int(cfg.n_horizon_decades), -1, -1, dtype=float)
        xp = np if isinstance(span, (float, int, np.floating)) else jnp
        u = span * xp.asarray(10.0 ** (-k))
    n_h = int(u.shape[0])
    if n_h > cap:
        raise ValueError(f"the classifier state holds {cap} horizons, the config has {n_h}")
    u = xp.concatenate([u, xp.full((cap - n_h,), 1.0) * span]) if n_h < cap else u
    j = np.arange(N_BINS, dtype=float)
    lo = span * (10.0 ** ((j - N_BINS) / BINS_PER_DECADE))
    hi = span * (10.0 ** ((j + 1 - N_BINS) / BINS_PER_DECADE))
    return t0, span, u, n_h, lo, hi


# ---- the fold ---------------------------------------------------------------------------------------

# per-horizon entries that follow the running history while t <= T and are frozen afterwards
_RUN = ("settled", "t_settle", "in_exc", "peak", "peak_prev", "peak_last", "n_exc", "exc_flipped", "n_flips",
        "t_first_flip", "t_last_flip", "t_start_last", "t_start_prev", "t_exc_end", "max_settled", "finite",
        "e_last", "size_max")


def init(dtype=jnp.float64, cfg: VerdictConfig | None = None, n_obs: int | None = None):
    """Running state of the classifier before the first checkpoint (one trajectory).

    The classifier is a fold over the checkpoints: ``init`` -> ``update`` per checkpoint ->
    ``finalize``. :func:`classify` runs the fold with ``lax.scan`` over saved observables; the
    native and fused engines run the same ``update`` inside their step loops, so every engine
    applies exactly the same rules.

    ``init(dtype)``: fixed capacities (``MAX_HORIZONS`` horizons, ``MAX_FEATURE_OBS`` observables
    with features), right for every config. ``init(dtype, cfg)``: a state sized to ``cfg`` (its
    horizons; features only if enabled), which ``update``/``finalize`` recognise from its shapes;
    the engines' per-checkpoint cost grows with the size of this state (it is read and written
    at every checkpoint), so engines should pass ``cfg``.
    """
    H = MAX_HORIZONS if cfg is None else _n_horizons(cfg)
    F = MAX_FEATURE_OBS
    if cfg is not None:
        F = min(int(n_obs or cfg.n_obs or MAX_FEATURE_OBS), MAX_FEATURE_OBS) if cfg.features else 0
    # no zero-size leaves (the fused engine's row layout has no room for them): no features, no entry
    feat = {} if F == 0 else {"feat": jnp.stack([jnp.full((F,), v, dtype) for v in FT.INIT])}
    if cfg is not None and not cfg.verdicts:  # named outcomes: the features alone (no attitude state)
        return dict(span=jnp.asarray(jnp.nan, dtype), **feat)

    def f(v):
        return jnp.full((H,), v, dtype)

    false, zero = jnp.zeros((H,), bool), jnp.zeros((H,), jnp.int32)
    return dict(
        settled=false, t_settle=f(jnp.nan), in_exc=false, peak=f(0.0), peak_prev=f(jnp.nan), peak_last=f(jnp.nan),
        n_exc=zero, exc_flipped=false, n_flips=zero, t_first_flip=f(jnp.nan), t_last_flip=f(jnp.nan),
        t_start_last=f(jnp.nan), t_start_prev=f(jnp.nan), t_exc_end=f(jnp.nan), max_settled=f(-jnp.inf),
        finite=jnp.ones((H,), bool), e_last=f(jnp.inf), size_max=f(-jnp.inf),
        passed=false, max_late=f(-jnp.inf), growth=jnp.zeros((H, 5), dtype),
        dfit=jnp.zeros((N_BINS, 6), dtype), span=jnp.asarray(jnp.nan, dtype), **feat,
    )


def _advance(r, t, ek, size_k, fin_now, cfg: VerdictConfig):
    """One checkpoint of the running (scalar) history."""
    size_max = jnp.maximum(r["size_max"], jnp.where(jnp.isfinite(size_k), size_k, -jnp.inf))
    settled = r["settled"] | (ek < cfg.settle_tol)
    t_settle = jnp.where(~r["settled"] & settled, t, r["t_settle"])
    above = settled & (ek > cfg.excursion_tol)
    start = above & ~r["in_exc"]
    peak = jnp.where(start, ek, jnp.where(above, jnp.maximum(r["peak"], ek), r["peak"]))
    more = start & (r["n_exc"] > 0)  # an excursion that starts pushes the last one to prev
    peak_prev = jnp.where(more, r["peak_last"], r["peak_prev"])
    peak_last = jnp.where(above, peak, r["peak_last"])
    t_start_prev = jnp.where(more, r["t_start_last"], r["t_start_prev"])
    t_start_last = jnp.where(start, t, r["t_start_last"])
    t_exc_end = jnp.where(above, t, r["t_exc_end"])
    n_exc = r["n_exc"] + start.astype(jnp.int32)
    over = above & (ek > cfg.flip_tol)
    flipped_now = over & ~(r["exc_flipped"] & ~start)
    exc_flipped = jnp.where(start, over, r["exc_flipped"] | over)
    n_flips = r["n_flips"] + flipped_now.astype(jnp.int32)
    t_first_flip = jnp.where(jnp.isnan(r["t_first_flip"]) & flipped_now, t, r["t_first_flip"])
    t_last_flip = jnp.where(over, t, r["t_last_flip"])
    max_settled = jnp.where(settled, jnp.maximum(r["max_settled"], ek), r["max_settled"])
    return dict(
        settled=settled, t_settle=t_settle, in_exc=above, peak=peak, peak_prev=peak_prev, peak_last=peak_last,
        n_exc=n_exc, exc_flipped=exc_flipped, n_flips=n_flips, t_first_flip=t_first_flip, t_last_flip=t_last_flip,
        t_start_last=t_start_last, t_start_prev=t_start_prev, t_exc_end=t_exc_end, max_settled=max_settled,
        finite=r["finite"] & fin_now, e_last=ek, size_max=size_max,
    )


def _put(x, n, head):
    """``x`` with its first ``n`` entries (axis 0) replaced by ``head`` (static slices only)."""
    return head if n == x.shape[0] else jnp.concatenate([head, x[n:]], axis=0)


def update(c, t, obs_k, cfg: VerdictConfig, t_late):
    """Fold one checkpoint ``(t, obs_k)`` (obs_k: (n_obs,); 0 error, 1 size) into the state ``c``."""
    if "peak" not in c:  # the features alone (init with cfg.verdicts False)
        t0, span = _frame(cfg, t_late)[:2]
        out = {"span": jnp.asarray(span, c["span"].dtype) + jnp.zeros_like(c["span"])}
        if "feat" in c:
            out["feat"] = _fold_features(c["feat"], t - t0, obs_k, span, cfg)
        return out
    t0, span, U, n_h, lo, hi = _frame(cfg, t_late, c["peak"].shape[0])
    dtype = c["peak"].dtype
    u = t - t0
    ek = obs_k[0]
    size_k = obs_k[1] if obs_k.shape[0] > 1 else jnp.zeros_like(ek)
    fin_now = jnp.all(jnp.isfinite(obs_k))
    ek = jnp.where(jnp.isfinite(ek), ek, jnp.inf)
    Uh = U[:n_h]
    active = u <= Uh * (1 + _TOL)
    r = {k: c[k][n_h - 1] for k in _RUN}  # the last horizon is t1: it follows the whole history
    new = _advance(r, t, ek, size_k, fin_now, cfg)
    out = {k: _put(c[k], n_h, jnp.where(active, new[k], c[k][:n_h])) for k in _RUN}

    out["passed"] = _put(c["passed"], n_h, c["passed"][:n_h] | ((u >= Uh * (1 - _TOL)) & fin_now))
    late = active & (u >= Uh * 10.0 ** (-cfg.late_decades))
    # converged_tol test: the last converge_decades of T, after settling (the approach before the first
    # settling is the initial transient; the growth fit below keeps it: never-settled runs are judged by it)
    late_settled = active & (u >= Uh * 10.0 ** (-cfg.converge_decades)) & new["settled"]
    out["max_late"] = _put(c["max_late"], n_h, jnp.where(late_settled, jnp.maximum(c["max_late"][:n_h], ek),
                                                          c["max_late"][:n_h]))
    # logs relative to the span keep the least-squares sums well conditioned
    lx = jnp.log(jnp.maximum(u / span, 1e-300))
    ly = jnp.log(jnp.maximum(ek, 1e-300))
    use = late & (ek > 1e-13) & (u > 0) & jnp.isfinite(ek)
    w = use.astype(dtype)
    g = c["growth"][:n_h] + w[:, None] * jnp.stack([jnp.ones_like(lx), lx, ly, lx * lx, lx * ly])[None, :]
    out["growth"] = _put(c["growth"], n_h, g)

    # decay-law bins: settled, between the noise floor and settle_tol (excursions excluded)
    in_bin = (u >= lo) & jnp.where(np.arange(N_BINS) == N_BINS - 1, True, u < hi)
    fit_ok = new["settled"] & (ek > cfg.floor_tol) & (ek < cfg.settle_tol) & fin_now & (u > 0)
    wb = (in_bin & fit_ok).astype(dtype)
    out["dfit"] = c["dfit"] + wb[:, None] * jnp.stack([jnp.ones_like(lx), lx, ly, lx * lx, lx * ly, ly * ly])[None, :]

    F = c["feat"].shape[1] if "feat" in c else 0
    if cfg.features and F > 0:
        out["feat"] = _fold_features(c["feat"], u, obs_k, span, cfg)
    elif F > 0:
        out["feat"] = c["feat"]
    out["span"] = jnp.asarray(span, dtype) + jnp.zeros_like(c["span"])
    return out


def _fold_features(fe, u, obs_k, span, cfg: VerdictConfig):
    """The late-window feature rows after one checkpoint (:func:`stabjax.fold.features.fold_observation`)."""
    inw = (u >= span * (1.0 - cfg.feature_window)).astype(fe.dtype)
    return FT.fold_observation(fe, obs_k, inw)


def resolve(verdict, failed, size_max, cfg: VerdictConfig):
    """The rules every classifier shares, on top of its own ``verdict`` (rules 1 and 2, size part).

    ``size_max``: largest size observable over the *finite* checkpoints; ``failed``: the solver
    did not reach the horizon or a checkpoint was not finite. A finite checkpoint with size above
    ``diverge_size`` is evidence of divergence and wins (also over a later failure); otherwise a
    failure is FAILED; otherwise ``verdict``. Returns int8.
    """
    size_div = size_max > cfg.diverge_size
    return jnp.where(size_div, DIVERGED, jnp.where(failed, FAILED, verdict)).astype(jnp.int8)


def _lsq(n, sx, sy, sxx, sxy):
    den = n * sxx - sx * sx
    return jnp.where((n >= 3) & (den > 0), (n * sxy - sx * sy) / jnp.where(den > 0, den, 1.0), jnp.nan)


def finalize(c, solver_ok, cfg: VerdictConfig):
    """Verdicts and summaries at every horizon (trailing dim ``horizon``) from the running state."""
    if "peak" not in c:  # the features alone (init with cfg.verdicts False)
        return FT.summaries(c, cfg)
    dtype = c["peak"].dtype
    nan = jnp.asarray(jnp.nan, dtype)
    span_c = c["span"]
    t0, span, U, n_h, lo, hi = _frame(cfg, None if cfg.t1 is not None else span_c, c["peak"].shape[0])
    Uh = jnp.asarray(U[:n_h], dtype)
    g = {k: c[k][:n_h] for k in (*_RUN, "passed", "max_late")}
    settled, e1, n_exc = g["settled"], g["e_last"], g["n_exc"]
    # a solver failure after T leaves the verdict at T standing (it passed T with finite values);
    # at t1 itself a failure is a failure (e.g. an escape stopped just there)
    last = jnp.arange(n_h) == n_h - 1
    failed = ~g["finite"] | (~solver_ok & (~g["passed"] | last))
    gr = c["growth"][:n_h]
    slope = _lsq(gr[:, 0], gr[:, 1], gr[:, 2], gr[:, 3], gr[:, 4])

    late_u = Uh * 10.0 ** (-cfg.late_decades)
    late_flip = (g["n_flips"] > 0) & (g["t_last_flip"] - t0 >= late_u * (1 - _TOL))
    two = n_exc >= 2
    ratio = jnp.where(two, g["peak_last"] / jnp.where(two, g["peak_prev"], 1.0), nan)
    not_shrinking = two & (ratio >= cfg.shrink_ratio)
    recurrent_flip = not_shrinking & (jnp.maximum(g["peak_last"], g["peak_prev"]) > cfg.flip_tol)
    u_prev = jnp.maximum(g["t_start_prev"] - t0, 1e-300)
    q = jnp.where(two, (g["t_start_last"] - t0) / u_prev, nan)
    need = jnp.maximum(10.0 ** cfg.late_decades, jnp.where(two, q * q, 1.0)) * (g["t_exc_end"] - t0)
    quiet = (n_exc == 0) | (Uh >= need * (1 - _TOL))
    # settled for at least half a decade in log-time (the late window excludes the approach before it)
    long_settled = Uh >= 10.0 ** cfg.converge_decades * (g["t_settle"] - t0) * (1 - _TOL)
    max_late = g["max_late"]

    diverged = ~settled & (slope > cfg.growth_tol) & (e1 < cfg.flip_tol)
    flipped = (e1 > cfg.flip_tol) | late_flip | recurrent_flip
    # Below floor_tol the error sits at the solver's noise floor (~rtol) and its log-log slope is
    # noise of either sign, so the trend is only asked of errors above it. There is no shortcut on
    # the final error alone: in paper A the body returns to ~1e-12 between excursions, so the
    # whole late window must stay below converged_tol.
    not_growing = jnp.isnan(slope) | (slope <= 0.0) | (max_late < cfg.floor_tol)
    converged = (settled & long_settled & quiet & ~not_shrinking & (max_late > -jnp.inf)
                 & (max_late < cfg.converged_tol) & not_growing)
    rest = jnp.where(diverged, DIVERGED, jnp.where(flipped, FLIPPED, jnp.where(converged, CONVERGED, UNDECIDED)))
    verdict = resolve(rest, failed, g["size_max"], cfg)

    # decay law over the last fit_decades of half-decade bins below T that hold points above the floor
    d = c["dfit"]
    hi_c = jnp.asarray(hi, dtype)
    eligible = hi_c[None, :] <= Uh[:, None] * (1 + _TOL)
    has = eligible & (d[None, :, 0] > 0)
    idx = jnp.arange(N_BINS)
    j_end = jnp.max(jnp.where(has, idx[None, :], -1), axis=1)
    nb = int(round(cfg.fit_decades * BINS_PER_DECADE))
    win = eligible & (idx[None, :] > j_end[:, None] - nb) & (idx[None, :] <= j_end[:, None])
    S = jnp.sum(jnp.where(win[:, :, None], d[None, :, :], 0.0), axis=1)
    n, sx, sy, sxx, sxy, syy = (S[:, i] for i in range(6))
    nn = jnp.maximum(n, 1.0)
    sxx_c = sxx - sx * sx / nn
    sxy_c = sxy - sx * sy / nn
    syy_c = syy - sy * sy / nn
    ok = (n >= cfg.fit_min_points) & (sxx_c > 0)
    sl = sxy_c / jnp.where(sxx_c > 0, sxx_c, 1.0)
    ssr = jnp.maximum(syy_c - sl * sxy_c, 0.0)
    se = jnp.sqrt(ssr / jnp.maximum(n - 2.0, 1.0) / jnp.where(sxx_c > 0, sxx_c, 1.0))
    reason = jnp.where(~g["finite"], 3, jnp.where(~settled, 1, jnp.where(ok, 0, 2))).astype(jnp.int8)
    good = reason == 0
    t_end = jnp.where(j_end >= 0, t0 + hi_c[jnp.maximum(j_end, 0)], nan)

    out = dict(
        verdict=verdict,
        error_t1=e1,
        error_max_settled=jnp.where(settled, g["max_settled"], nan),
        error_max_late=max_late,
        t_settle=g["t_settle"],
        t_first_flip=g["t_first_flip"],
        t_last_flip=g["t_last_flip"],
        t_last_excursion=g["t_start_last"],
        n_excursions=n_exc,
        n_flips=g["n_flips"],
        peak_last=g["peak_last"],
        peak_prev=g["peak_prev"],
        peak_ratio=ratio,
        recurrence_ratio=q,
        decay_exponent=jnp.where(good, -sl, nan),
        decay_exponent_se=jnp.where(good, se, nan),
        decay_n=n.astype(jnp.int32),
        decay_t_end=t_end,
        decay_reason=reason,
        size_max=g["size_max"],
    )
    out.update(FT.summaries(c, cfg))
    return out


def classify(ts: jnp.ndarray, obs: jnp.ndarray, solver_ok: jnp.ndarray, cfg: VerdictConfig, t0: float = 0.0):
    """Classify one trajectory (traced; vmap it). ``obs`` is (K, n_obs): column 0 error, 1 size.

    An unbound ``cfg`` is bound here to (t0, ts[-1]) when those are concrete."""
    if cfg.t1 is None:
        try:
            cfg = bind(cfg, float(t0), float(ts[-1]), n_obs=int(obs.shape[-1]))
        except (TypeError, jax.errors.ConcretizationTypeError):
            pass
    t_late = late_start(cfg, t0, ts[-1])

    def step(c, x):
        t, ok = x
        return update(c, t, ok, cfg, t_late), None

    c, _ = jax.lax.scan(step, init(obs.dtype, cfg, int(obs.shape[-1])), (ts, obs))
    return finalize(c, solver_ok, cfg)


def at_t1(x):
    """The values at the last horizon (t1) of a result array or DataArray with a horizon dim."""
    if hasattr(x, "dims"):
        return x.isel(horizon=-1) if "horizon" in x.dims else x
    return x


def counts(verdicts) -> dict[str, int]:
    """Trajectory counts per verdict (at t1 when given a DataArray with a horizon dim)."""
    v = np.asarray(at_t1(verdicts)).ravel()
    return {name: int((v == i).sum()) for i, name in enumerate(NAMES)}
