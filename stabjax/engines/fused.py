"""Fused sweep engine: one compiled loop steps a whole batch of trajectories, each with its own step size.

Why not ``jit(vmap(diffrax.diffeqsolve))``: a vmapped ``while_loop`` runs every lane until the
slowest one has finished (lock-step waste), it saves the observables of every checkpoint before
the classifier sees them, and on CPU the vmapped model becomes (3, N) slices, stacks and
transposes that XLA fuses badly. Here (measurements in ``docs/performance.md``):

* **Lanes and a queue.** ``lanes`` trajectories are integrated side by side in ONE
  ``lax.while_loop`` per device; each lane has its own time, step size, counters and
  classifier state. A lane whose trajectory reached ``t1`` (or failed) writes its summaries and
  is refilled at once from the queue of pending trajectories, so no lane idles while others
  finish (only the tail of the queue runs part-full).
* **The method is diffrax's.** Tsitouras 5(4) with the same tableau, the same error norm (RMS
  of ``err / (atol + rtol max(|y0|, |y1|))``), the same I-controller as ``diffrax.PIDController``
  defaults (safety 0.9, factor in [0.2, 10], accepted steps never shrink, rejected ones shrink
  by at least 0.9), the same initial step (Hairer's rule), the same clipping of the last step to
  ``t1``. Final states agree with diffrax and SciPy to the tolerance (``tests/engines/test_fused.py``).
* **Checkpoints without storage.** A step handles at most ``CHECKPOINT_SLOTS`` checkpoints and
  ends on the next one if it would cross more (the controller's own proposal is kept for the
  step after); the state at a checkpoint comes from Tsit5's dense output (the interpolant
  diffrax uses for ``SaveAt(ts=...)``) and goes straight into the running classifier
  (:func:`stabjax.fold.verdict.update`, the very rules of :func:`stabjax.fold.verdict.classify`).
* **Lane-wise evaluation of the model.** The system's ``prepare/initial_state/rhs/observe``
  and the classifier are traced once per trajectory (jaxprs) and evaluated with every array
  element held separately as a (lanes,) vector or a constant (:mod:`stabjax.engines.lanes`): slices,
  stacks, 3x3 products become bookkeeping, XLA sees only elementwise ops on contiguous
  vectors. Parameters equal across the sweep are folded in as constants. float64 log, sin,
  cos and pow use branch-free vectorisable code (:mod:`stabjax.engines.vmath`; XLA:CPU calls
  scalar libm for them). Loops with a trip count known when tracing are unrolled and small
  dense linear algebra (solve, inv, det, eigh, Cholesky) is written out as scalar operations
  (:mod:`stabjax.engines.unrolled`): the list of what a model may use is in
  :mod:`stabjax.engines.lanes`. Systems with a primitive that has no rule (or with their own
  ``classify``, or another solver) raise :class:`Unsupported`: the sweep runs on the diffrax engine.
* **Both CPU cores.** Trajectories are dealt round-robin to the local devices, each device runs
  its own loop (``shard_map``); :func:`stabjax.config.setup_jax` asks JAX for one host device per core. On a GPU
  the same code runs on one device with wide lanes.

A trajectory that cannot progress (its right-hand side is not finite at an accepted state, or
its step size collapsed below ~10 ulp of t: diffrax would reject steps until ``max_steps``) is stopped at once with the status code
diffrax would end with (``max_steps_reached`` = 1); with an escape radius, one whose accepted
state leaves the ball is stopped at once with :data:`stabjax.fold.status.ESCAPED`. For FAILED
trajectories only ``verdict``, ``solver_status`` and the step counts are meaningful.

Length: about 570 lines, over the project's ~550-line guide, because the device loop (``_device_loop``) is
one closure whose step, checkpoint, stop and refill parts share the lane state; split, each part would take
that state as a dozen arguments.
"""
from __future__ import annotations

import functools
from typing import Iterable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ..fold import stops
from ..fold import verdict as V
from ..config import escape_radius
from ..fold.status import ESCAPED as STATUS_ESCAPED, MAX_STEPS as STATUS_MAX_STEPS, OK as STATUS_OK
from .base import Engine, Unsupported, lane_engine_declines, queued_bytes_per_trajectory
from .lanes import (LaneFn, Lanes, NoRule, RowSpec, flat_rows, is_const, materialize, materializing, obj, obj0,
                    obj1, rows_to_objs)
from .static import StaticParams, split_static
from .tsit5 import (A, C, E, FACTORMAX, FACTORMIN, MIN_STEP_REL, ORDER, SAFETY, SOLVER, interp_weights,
                    t1_clip_floor)
from .vmath import fast_log

# Checkpoints handled per step: a step that would contain more ends on the next one (measured
# fastest at 1 on CPU and GPU, docs/performance.md; the native engine has no such limit).
CHECKPOINT_SLOTS = 1


def default_lanes(platform: str | None = None) -> int:
    """Lanes per device: small enough that a step's working set stays in cache on CPU, wide on GPU
    (2^18 measured fastest on an H100: 2^16 leaves it idle between kernels, 2^20 is bound by
    memory traffic; docs/performance.md)."""
    platform = platform or jax.default_backend()
    return 256 if platform == "cpu" else 262144


class _Model:
    """A system's traced methods evaluated lane-wise, with the batch-constant parameters folded in.

    Parameters equal across the whole batch (``static``) are compile-time constants: the
    evaluator folds them (``pow(x, 0.5)`` becomes ``sqrt``, ``x * 1`` disappears); the others
    arrive as lane rows. ``prepare`` runs once per trajectory (at refill); its outputs that are
    constants are kept in a template and only its lane-varying entries are carried.
    """

    def __init__(self, system, static: Mapping[str, np.ndarray], dyn_shapes: Mapping[str, tuple], vcfg, t_late,
                 fixed_point: tuple[float, float, float] | None = None, known=None):
        sds = jax.ShapeDtypeStruct
        f64 = jnp.float64
        self.static = {k: np.asarray(v, np.float64) for k, v in static.items()}
        self.dyn_keys = sorted(dyn_shapes)
        self.dyn_shapes = {k: tuple(dyn_shapes[k]) for k in self.dyn_keys}
        ex_pd = {k: sds(self.dyn_shapes[k], f64) for k in self.dyn_keys}
        st = self.static

        def full(pd):
            return {**st, **pd}

        self.n_state = system.state_size
        ex_args = jax.eval_shape(lambda pd: system.prepare(full(pd)), ex_pd)
        ex_t, ex_y = sds((), f64), sds((self.n_state,), f64)
        ex_obs = jax.eval_shape(system.observe, ex_t, ex_y, ex_args)
        ex_c = jax.eval_shape(lambda: V.init(f64, vcfg))
        self.n_obs = int(np.prod(ex_obs.shape))
        self.args_spec = RowSpec(ex_args)
        self.c_spec = RowSpec(ex_c)
        t_late = float(t_late)
        self.template = None
        try:
            self.prep = LaneFn(lambda pd: system.prepare(full(pd)), ex_pd)
            self.init = LaneFn(lambda pd: system.initial_state(full(pd)), ex_pd)
            self.rhs = LaneFn(system.rhs, ex_t, ex_y, ex_args)
            self.obs = LaneFn(system.observe, ex_t, ex_y, ex_args)
            self.upd = LaneFn(lambda c, t, o: V.update(c, t, o, vcfg, t_late), ex_c, ex_t, ex_obs)
            # the stop test at a stable fixed point (stabjax.fold.equilibrium), fixed_point = (rtol, atol, t_window):
            # whether to stop, and the equilibrium
            self.fp = None if fixed_point is None else LaneFn(
                lambda t, y, a: stops.fixed_point_stop(system.rhs, t, y, a, *fixed_point), ex_t, ex_y, ex_args)
            self.fp_pre = None if fixed_point is None else LaneFn(
                lambda t, y, a: stops.near_stable(system.rhs, t, y, a, *fixed_point[:2]), ex_t, ex_y, ex_args)
            # the recurrence stop's test: the known attractor near the observation (stabjax.fold.stops)
            self.at = None if known is None else LaneFn(
                lambda t, y, a: stops.near_attractor(jnp.ravel(system.observe(t, y, a)), known), ex_t, ex_y, ex_args)
            # dry run of every function on abstract lanes: an unsupported primitive shows up now
            L = 8
            jax.eval_shape(self._dry, *[sds((L,), f64) for _ in range(sum(int(np.prod(s)) for s in self.dyn_shapes.values()))])
        except NoRule as exc:
            raise Unsupported(f"fused engine: no lane-wise rule for primitive {exc}") from None

    def _dry(self, *rows):
        L = rows[0].shape[0] if rows else 8
        args, y0 = self.fresh_rows(L, list(rows))
        args_objs = self.args_objs(args)
        t = jnp.zeros((L,))
        f = self.f(L, t, y0, args_objs)
        o = self.observe(L, t, y0, args_objs)
        if self.fp is not None:
            self.at_fixed_point(L, t, y0, args_objs)
            self.near_stable(L, t, y0, args_objs)
        if self.at is not None:
            self.near_attractor(L, t, y0, args_objs)
        c = flat_rows(self.c_spec.objs([jnp.zeros((L,), d) for d, n in zip(self.c_spec.dtypes, self.c_spec.sizes)
                                        for _ in range(n)]), L)
        return f, self.update(L, c, t, o)

    def dyn_objs(self, rows):
        return rows_to_objs([self.dyn_shapes[key] for key in self.dyn_keys], rows)

    def fresh_rows(self, L, dyn_rows):
        """Lane-varying prepared args (flat rows; constants go to the template) and y0 rows."""
        ins = self.dyn_objs(dyn_rows)
        lanes = Lanes(L)
        args = lanes.eval_closed(self.prep.closed, ins)
        if self.template is None:
            self.template = [np.vectorize(lambda e: e if is_const(e) else None, otypes=[object])(a)
                             if a.size else a for a in args]
        rows = [a[i] for a in args for i in np.ndindex(a.shape) if not is_const(a[i])]
        # a slot constant in one trace is constant in every trace (same jaxpr, same constants)
        y0 = flat_rows(lanes.eval_closed(self.init.closed, ins), L, [np.float64])
        return rows, y0

    def args_objs(self, rows):
        out, k = [], 0
        for tpl in self.template:
            o = obj(tpl.shape)
            for i in np.ndindex(tpl.shape):
                if tpl[i] is None:
                    o[i] = rows[k]
                    k += 1
                else:
                    o[i] = tpl[i]
            out.append(o)
        return out

    def f(self, L, t, y, args_objs):
        out = Lanes(L).eval_closed(self.rhs.closed, [obj0(t), obj1(y)] + args_objs)
        return [materialize(r) for r in flat_rows(out, L, [np.float64])]

    def observe(self, L, t, y, args_objs):
        out = Lanes(L).eval_closed(self.obs.closed, [obj0(t), obj1(y)] + args_objs)
        return flat_rows(out, L, [np.float64])

    def near_stable(self, L, t, y, args_objs):
        out = Lanes(L).eval_closed(self.fp_pre.closed, [obj0(t), obj1(y)] + args_objs)
        return flat_rows(out, L, [np.bool_])[0]

    def at_fixed_point(self, L, t, y, args_objs):
        """(stop (L,) bool, the equilibrium's rows)."""
        out = Lanes(L).eval_closed(self.fp.closed, [obj0(t), obj1(y)] + args_objs)
        rows = flat_rows(out, L, [np.bool_, np.float64])
        return rows[0], rows[1:]

    def near_attractor(self, L, t, y, args_objs):
        out = Lanes(L).eval_closed(self.at.closed, [obj0(t), obj1(y)] + args_objs)
        return materialize(flat_rows(out, L, [np.float64])[0])

    def update(self, L, c_rows, t, obs_rows):
        ins = self.c_spec.objs(c_rows) + [obj0(t), obj1(obs_rows)]
        out = Lanes(L).eval_closed(self.upd.closed, ins)
        return flat_rows(out, L, self.c_spec.dtypes)


def _lincomb(base, h, coeffs, fs):
    """Row-wise base + h * sum_j coeffs[j] * fs[j] (zero coefficients skipped)."""
    out = []
    for i in range(len(base)):
        acc = None
        for c, f in zip(coeffs, fs):
            if isinstance(c, float) and c == 0.0:
                continue
            term = c * f[i]
            acc = term if acc is None else acc + term
        out.append(base[i] if acc is None else base[i] + h * acc)
    return out


def _device_loop(system, icfg, vcfg, lanes: int, static: Mapping[str, np.ndarray], dyn_shapes, with_state=False):
    """``(params (M, ...), one) -> summaries (M,)`` for one device (traced)."""
    slots = CHECKPOINT_SLOTS
    ts_np = V.checkpoint_times(icfg.checkpoints(), vcfg)  # every horizon exactly
    K = len(ts_np)
    t0, t1 = float(icfg.t0), float(icfg.t1)
    t1_floor = t1_clip_floor(t1)
    rtol, atol = float(icfg.rtol), float(icfg.atol)
    max_steps = int(icfg.max_steps)
    t_late = V.late_start(vcfg, t0, float(ts_np[-1]))
    f64 = jnp.float64
    fixed = stops.active(system, icfg)
    known = icfg.known_attractors if stops.attractor_stop_active(system, icfg) else None
    model = _Model(system, static, dyn_shapes, vcfg, t_late,
                   (rtol, atol, stops.window_start(ts_np, vcfg)) if fixed else None, known)
    n_state = model.n_state
    radius = escape_radius(system, icfg)

    def run(p: Mapping[str, jnp.ndarray], one):
        with materializing(one.reshape(())):
            return _run(p)

    def _run(p):
        ts_ext = jnp.asarray(np.concatenate([ts_np, np.full(slots + 1, np.inf)]))
        M = p["__index__"].shape[0]
        L = min(lanes, M)
        v_finalize = jax.vmap(lambda c, ok: V.finalize(c, ok, vcfg), in_axes=(-1, 0), out_axes=0)

        def rms(rows):
            return jnp.sqrt(sum(r * r for r in rows) / len(rows))

        def initial_step(y0, f0, args):
            """diffrax ``_select_initial_step`` (Hairer, Norsett & Wanner II.4), per lane."""
            if icfg.dt0 is not None:
                return jnp.full((L,), float(icfg.dt0))
            scale = [atol + jnp.abs(y) * rtol for y in y0]
            d0 = rms([y / s for y, s in zip(y0, scale)])
            d1 = rms([f / s for f, s in zip(f0, scale)])
            small = (d0 < 1e-5) | (d1 < 1e-5)
            h0 = jnp.where(small, 1e-6, 0.01 * (d0 / jnp.where(small, 1.0, d1)))
            f1 = model.f(L, t0 + h0, [y + h0 * f for y, f in zip(y0, f0)], args)
            d2 = rms([(b - a) / s for a, b, s in zip(f0, f1, scale)]) / h0
            max_d = jnp.maximum(d1, d2)
            h1 = jnp.where(max_d <= 1e-15, jnp.maximum(1e-6, h0 * 1e-3), jnp.exp(fast_log(0.01 / max_d) / ORDER))
            return jnp.minimum(100 * h0, h1)

        def fresh(idx):
            """Lane state of trajectories ``idx`` at t0: prepared args, y0, f0, first step."""
            j = jnp.minimum(idx, M - 1)
            dyn_rows = []
            for k in model.dyn_keys:
                v = p[k][j]  # (L, *shape)
                for i in np.ndindex(model.dyn_shapes[k]):
                    dyn_rows.append(v[(slice(None),) + i])
            args, y = model.fresh_rows(L, dyn_rows)
            tt = jnp.full((L,), t0, f64)
            f = model.f(L, tt, y, model.args_objs(args))
            h = initial_step(y, f, model.args_objs(args))
            tn = jnp.minimum(t0 + h, t1)
            tn = jnp.where(tn > t1_floor, t1, tn)
            c0 = V.init(f64, vcfg)
            vc = [jnp.full((L,), x[i]) for x in jax.tree.leaves(c0) for i in np.ndindex(x.shape)]
            zi = jnp.zeros((L,), jnp.int32)
            return dict(args=args, y=y, f=f, t=tt, tn=tn, ck=zi, vc=vc, nacc=zi, nrej=zi, nt=zi, na=zi,
                        ak=jnp.full((L,), -1.0, f64), as_=jnp.zeros((L,), f64))

        summ_shape = jax.eval_shape(lambda: v_finalize(
            jax.tree.map(lambda x: jnp.broadcast_to(x[..., None], (*x.shape, 1)), V.init(f64, vcfg)), jnp.ones((1,), bool)))
        out = {k: jnp.zeros((M, *s.shape[1:]), s.dtype) for k, s in summ_shape.items()}  # trailing dims: horizons, observables
        for k in ("n_steps", "n_rejected", "solver_status", "fixed_point"):
            out[k] = jnp.zeros((M,), jnp.int32)
        out["stopped_at"] = jnp.zeros((M,), f64)
        if with_state:
            for i in range(n_state):
                out[f"__y{i}"] = jnp.zeros((M,), f64)
            out["__t"] = jnp.zeros((M,), f64)

        def sel(mask, a, b):
            return jax.tree.map(lambda x, y: jnp.where(mask, x, y), a, b)

        def finish_and_refill(carry, done, status, at_fp, x_star):
            lane, idx, nxt, out = carry
            ctree = model.c_spec.tree(lane["vc"], L)
            summ = v_finalize(ctree, status == STATUS_OK)
            if fixed:  # finished at the equilibrium: its features (stabjax.fold.stops.at_equilibrium)
                obs = jnp.stack(model.observe(L, lane["t"], x_star, model.args_objs(lane["args"])), axis=-1)
                summ = stops.at_equilibrium(summ, at_fp == stops.HIT_FIXED_POINT, obs, xp=jnp)
            summ["fixed_point"] = at_fp.astype(jnp.int32)
            summ["stopped_at"] = lane["t"]
            summ["n_steps"] = lane["nacc"]
            summ["n_rejected"] = lane["nrej"]
            summ["solver_status"] = status
            if with_state:
                for i in range(n_state):
                    summ[f"__y{i}"] = lane["y"][i]
                summ["__t"] = lane["t"]
            widx = jnp.where(done, idx, M)  # out of range: dropped
            out = {k: out[k].at[widx].set(summ[k].astype(out[k].dtype), mode="drop") for k in out}
            rank = jnp.cumsum(done.astype(jnp.int32)) - 1
            new_idx = jnp.where(done, nxt + rank, idx)
            new_idx = jnp.where(done & (new_idx >= M), M, new_idx).astype(jnp.int32)
            nxt = jnp.minimum(nxt + jnp.sum(done.astype(jnp.int32)), M).astype(jnp.int32)
            lane = sel(done, fresh(new_idx), lane)
            return lane, new_idx, nxt, out

        def body(carry):
            lane, idx, nxt, out = carry
            active = idx < M
            y, f1, t, tn, ck = lane["y"], lane["f"], lane["t"], lane["tn"], lane["ck"]
            args = model.args_objs(lane["args"])
            c_next = ts_ext[ck + slots]
            clipped = c_next < tn  # a step never crosses more pending checkpoints than it has slots
            te = jnp.where(clipped, c_next, tn)
            h = te - t

            # -- one Tsit5 step (FSAL: f1 is f at (t, y)) --
            fs = [f1]
            for i in range(5):
                yi = [materialize(v) for v in _lincomb(y, h, A[i], fs)]
                fs.append(model.f(L, t + C[i] * h, yi, args))
            y_new = [materialize(v) for v in _lincomb(y, h, A[5], fs)]
            f7 = model.f(L, te, y_new, args)
            fs.append(f7)
            y_err = [h * e for e in _lincomb([0.0] * n_state, 1.0, E, fs)]

            # -- diffrax PIDController (I-controller defaults) --
            y_err = [jnp.where(jnp.isnan(e), jnp.inf, e) for e in y_err]
            bad_new = functools.reduce(jnp.logical_or, [jnp.isnan(v) for v in y_new])
            ratios = []
            for y0i, y1i, ei in zip(y, y_new, y_err):
                ysc = jnp.maximum(jnp.abs(y0i), jnp.abs(jnp.where(bad_new, y0i, y1i)))
                ratios.append(ei / (atol + ysc * rtol))
            err = rms(ratios)
            keep = err < 1
            factor = jnp.clip(SAFETY * jnp.exp(-fast_log(err) / ORDER), jnp.where(keep, 1.0, FACTORMIN),
                              jnp.where(keep, FACTORMAX, SAFETY))
            dt = h * factor
            dt = jnp.where(keep & clipped, jnp.maximum(dt, tn - t), dt)  # a checkpoint clip is not a reason to slow down
            t_prev = jnp.minimum(jnp.where(keep, te, t), t1)
            t_next = t_prev + dt
            t_next = jnp.where(t_next > t1_floor, jnp.where(keep, t1, t_prev + 0.5 * (t1 - t_prev)), t_next)

            # -- the pending checkpoints inside this step, from its dense output (in time order) --
            vc = lane["vc"]
            inv_h = 1.0 / jnp.where(h > 0, h, 1.0)
            for j in range(slots):
                cj = ts_ext[ck + j]
                has_ck = keep & (cj <= te) & (ck + j < K)
                th = jnp.where(h > 0, (cj - t) * inv_h, 0.0)
                bs = [materialize(b) for b in interp_weights(th)]
                y_ck = [materialize(v) for v in _lincomb(y, h, [1.0] * 7, [[b * fi for fi in f] for b, f in zip(bs, fs)])]
                obs = model.observe(L, cj, y_ck, args)
                vc_new = model.update(L, vc, cj, obs)
                vc = [jnp.where(has_ck, a, b) for a, b in zip(vc_new, vc)]
                n_ck = has_ck.astype(jnp.int32) if j == 0 else n_ck + has_ck.astype(jnp.int32)
            ck = ck + n_ck

            stepped = active & (h > 0)
            nacc = lane["nacc"] + (stepped & keep).astype(jnp.int32)
            nrej = lane["nrej"] + (stepped & ~keep).astype(jnp.int32)
            y = [jnp.where(keep, a, b) for a, b in zip(y_new, y)]
            f = [jnp.where(keep, a, b) for a, b in zip(f7, f1)]
            nt = lane["nt"]
            lane = dict(args=lane["args"], y=y, f=f, t=t_prev, tn=t_next, ck=ck, vc=vc, nacc=nacc, nrej=nrej, nt=nt,
                        na=lane["na"], ak=lane["ak"], as_=lane["as_"])

            reached = active & (t_prev >= t1) & (ck >= K)
            finite = functools.reduce(jnp.logical_and, [jnp.isfinite(v) for v in f])
            # no progress possible (at t1 a step of length 0 may still observe the last checkpoint)
            collapsed = ~((t_next - t_prev) > MIN_STEP_REL * jnp.abs(t_prev)) & (t_prev < t1)  # a NaN step too
            stuck = active & ~reached & (((nacc + nrej) >= max_steps) | ~finite | collapsed)
            done = reached | stuck
            status = jnp.where(reached, STATUS_OK, STATUS_MAX_STEPS)
            if radius is not None:  # an accepted state outside the ball: stop at once
                size = functools.reduce(jnp.maximum, [jnp.abs(v) for v in y_new])
                escaped = active & stepped & keep & (size > radius)
                done = done | escaped
                status = jnp.where(escaped, STATUS_ESCAPED, status)
            at_fp = jnp.zeros(done.shape, jnp.int32)  # stop code: stabjax.fold.stops.HIT_*
            x_star = y  # the equilibrium a fixed-point stop reached (only read where one did)
            if fixed or known is not None:  # at an accepted step that reached a checkpoint
                can = active & stepped & keep & (n_ck > 0) & ~done
                if fixed:  # certainly at a stable equilibrium (stabjax.fold.equilibrium); asked every
                    # fixed_point_every(K) checkpoints
                    test = can & (ck >= nt)

                    def whole(near):
                        hit, xs = model.at_fixed_point(L, t_prev, y, args)
                        return near & hit, xs

                    def ask():  # the cheap question first, the whole test only where a lane says yes
                        near = test & model.near_stable(L, t_prev, y, args)
                        return lax.cond(jnp.any(near), whole, lambda nr: (nr, list(y)), near)

                    hit, x_star = lax.cond(jnp.any(test), ask, lambda: (jnp.zeros_like(done), list(y)))
                    at_fp = hit.astype(jnp.int32) * stops.HIT_FIXED_POINT
                    lane["nt"] = jnp.where(test, ck + stops.fixed_point_every(K), nt).astype(jnp.int32)
                if known is not None:  # the same known attractor at every test over a span of dwell
                    test = can & (ck >= lane["na"])
                    k = lax.cond(jnp.any(test), lambda: model.near_attractor(L, t_prev, y, args),
                                 lambda: jnp.full((L,), -1.0, f64))
                    same = (k >= 0) & (k == lane["ak"])
                    held = test & same & (t_prev - lane["as_"] >= known.dwell)
                    lane["as_"] = jnp.where(test & ~same, t_prev, lane["as_"])
                    lane["ak"] = jnp.where(test, k, lane["ak"])
                    lane["na"] = jnp.where(test, ck + stops.TEST_EVERY, lane["na"]).astype(jnp.int32)
                    code = stops.HIT_ATTRACTOR0 + jnp.maximum(k, 0.0).astype(jnp.int32)
                    at_fp = jnp.where((at_fp == 0) & held, code, at_fp)
                done = done | (at_fp != 0)
                status = jnp.where(at_fp != 0, STATUS_OK, status)
            status = status.astype(jnp.int32)
            carry = (lane, idx, nxt, out)
            return lax.cond(jnp.any(done), lambda c: finish_and_refill(c, done, status, at_fp, x_star), lambda c: c,
                            carry)

        def cond(carry):
            return jnp.any(carry[1] < M)

        idx0 = jnp.arange(L, dtype=jnp.int32)
        carry = (fresh(idx0), idx0, jnp.asarray(L, jnp.int32), out)
        _, _, _, out = lax.while_loop(cond, body, carry)
        return out

    return run


def _devices(n_dev: int | None):
    devs = jax.local_devices()
    if n_dev is not None:
        devs = devs[: max(1, n_dev)]
    return devs


@functools.lru_cache(maxsize=64)
def _compiled(system, icfg, vcfg, lanes: int, n_dev: int, static: StaticParams, dyn_shapes: tuple, with_state=False):
    run = _device_loop(system, icfg, vcfg, lanes, static.values, dict(dyn_shapes), with_state)
    if n_dev == 1:
        return jax.jit(run)
    from jax.sharding import Mesh, PartitionSpec as P

    mesh = Mesh(np.array(_devices(n_dev)), ("d",))
    shard_map = getattr(jax, "shard_map", None)
    if shard_map is None:  # older JAX
        from jax.experimental.shard_map import shard_map
    kw = {"check_vma": False} if "check_vma" in shard_map.__code__.co_varnames else {"check_rep": False}
    return jax.jit(shard_map(run, mesh=mesh, in_specs=P("d"), out_specs=P("d"), **kw))


def prepare_call(system, icfg, vcfg, params, *, lanes=None, n_devices=None, static=None, with_state=False):
    """Compiled function and its host-side inputs (used by :func:`solve` and the benchmark)."""
    st, dyn = split_static(params, static)
    n = next(iter(params.values())).shape[0]
    n_dev = max(1, min(len(_devices(n_devices)), n))
    lanes = int(lanes or default_lanes())
    per = -(-n // n_dev)
    total = per * n_dev
    dyn["__index__"] = np.arange(n, dtype=np.float64)
    if total > n:  # pad with copies of the last trajectory (shapes equal on every device)
        dyn = {k: np.concatenate([v, np.repeat(v[-1:], total - n, axis=0)]) for k, v in dyn.items()}
    # deal round-robin so both devices get the same mix of easy and hard trajectories
    order = np.arange(total).reshape(per, n_dev).T.ravel()
    dyn = {k: v[order] for k, v in dyn.items()}
    shapes = tuple(sorted((k, v.shape[1:]) for k, v in dyn.items() if k != "__index__"))
    key_cfg = icfg.replace(settings={}) if icfg.settings else icfg  # lanes is an argument: one entry per value
    fn = _compiled(system, key_cfg, vcfg, lanes, n_dev, StaticParams(st), shapes, bool(with_state))
    args = ({k: jnp.asarray(v) for k, v in dyn.items()}, jnp.ones((n_dev,), jnp.float64))
    return _executable(fn, args), args, order, n


_EXECUTABLES: dict = {}


def _executable(jitted, args):
    """Ahead-of-time compiled ``jitted`` for these argument shapes (cached; compile time is measurable)."""
    key = (id(jitted), str(jax.tree.map(lambda a: (a.shape, a.dtype), args)))
    hit = _EXECUTABLES.get(key)
    if hit is not None and hit[0] is jitted:
        return hit[1]
    compiled = jitted.lower(*args).compile()
    if len(_EXECUTABLES) > 64:
        _EXECUTABLES.clear()
    _EXECUTABLES[key] = (jitted, compiled)
    return compiled


def solve(system, params: Mapping[str, np.ndarray], icfg, vcfg, *, lanes: int | None = None,
          n_devices: int | None = None, static: Iterable[str] | None = None,
          with_state: bool = False) -> dict[str, np.ndarray]:
    """Integrate and classify ``params`` (every parameter, leading dim N). Returns summaries (N,).

    ``static``: names of parameters that are the same for every trajectory of this batch *and of
    every other batch of the same sweep* (they are compiled in as constants); default: those equal
    across this batch. ``with_state``: also return ``state_t1`` (N, n_state) and ``t_stop`` (N,), the
    state and time where each trajectory stopped (t1 unless it failed or escaped).
    ``lanes``: default the engine setting ``lanes`` of ``icfg.settings``, else :func:`default_lanes`.
    Raises :class:`Unsupported` when the system cannot run lane-wise.
    """
    reason = FusedEngine().supports(system, icfg)
    if reason is not None:
        raise Unsupported(reason)
    fn, args, order, n = prepare_call(system, icfg, vcfg, params, lanes=lanes or ENGINE.setting(icfg, "lanes") or None,
                                      n_devices=n_devices, static=static, with_state=with_state)
    return unpack(fn(*args), order, n)


def unpack(out, order, n) -> dict[str, np.ndarray]:
    """Device outputs -> summaries in the caller's trajectory order."""
    res = {}
    for k, v in out.items():
        v = np.asarray(v)
        back = np.empty_like(v)
        back[order] = v
        res[k] = back[:n]
    ys = sorted((k for k in res if k.startswith("__y")), key=lambda k: int(k[3:]))
    if ys:
        res["state_t1"] = np.stack([res.pop(k) for k in ys], axis=1)
    if "__t" in res:
        res["t_stop"] = res.pop("__t")
    return res


class FusedEngine(Engine):
    """The fused XLA engine (GPU, and CPU without a C compiler)."""

    name = "fused"

    def supports(self, system, icfg) -> str | None:
        return lane_engine_declines(self.name, SOLVER, system, icfg)

    def prepare(self, system, params, icfg, vcfg, static=None) -> None:
        super().prepare(system, params, icfg, vcfg, static)
        st, dyn = split_static(params, static)
        shapes = tuple(sorted((k, np.shape(v)[1:]) for k, v in dyn.items()))
        _Model(system, st, dict(shapes), vcfg, V.late_start(vcfg, float(icfg.t0), float(icfg.t1)),
               (float(icfg.rtol), float(icfg.atol),
                stops.window_start(V.checkpoint_times(icfg.checkpoints(), vcfg), vcfg))
               if stops.active(system, icfg) else None,
               icfg.known_attractors if stops.attractor_stop_active(system, icfg) else None)

    def default_chunk(self, plan) -> int:
        """Lanes are refilled from a queue: longer chunks waste less at the tail. On a GPU 2^18
        lanes stay busy with chunks of 2^20 trajectories (docs/performance.md)."""
        return 65536 if jax.default_backend() == "cpu" else 1 << 20

    def bytes_per_trajectory(self, plan) -> int:
        return queued_bytes_per_trajectory(plan)

    def solve(self, system, params, icfg, vcfg, static=None, progress=None):
        return solve(system, params, icfg, vcfg, static=static)


ENGINE = FusedEngine()

__all__ = ["ENGINE", "FusedEngine", "solve", "prepare_call", "unpack", "default_lanes", "CHECKPOINT_SLOTS"]
