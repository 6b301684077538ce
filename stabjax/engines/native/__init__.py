"""Native CPU engine: the model's jaxprs translated to C, one SIMD Tsit5 loop per core.

Why (docs/performance.md): the fused XLA engine (:mod:`stabjax.engines.fused`) reached ~5% of
the CPU's float64 peak because XLA:CPU splits one Runge-Kutta step into ~400 fusions that pass
every intermediate through memory, and calls scalar libm for sin, cos, log, pow and atan2. Here
the same per-trajectory functions are compiled by a C compiler into one loop that keeps a whole
step in registers. Three parts:

* :mod:`.emit`: the system's rhs, observables and the classifier update as C functions;
* :mod:`.kernel`: the C template of the integration loop (SIMD over trajectories, Tsit5 with
  diffrax's method and controller, checkpoints from the dense output, a queue of trajectories);
* :mod:`.build`: the C compiler, its flags and the on-disk cache of compiled libraries.

This module runs the compiled loop: one call per core from Python threads (ctypes releases the
GIL); the calls share the queue, a progress counter and a stop flag (Ctrl-C stops every thread
after its current step). Without a working C compiler, or for a system whose right-hand side
uses a primitive without a C rule, :func:`solve` raises :class:`Unsupported` and the sweep runs
on the next engine (:func:`stabjax.engines.resolve`).
"""
from __future__ import annotations

import ctypes
import functools
import os
import threading
import time
from typing import Callable, Iterable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ...fold import stops
from ...fold import verdict as V
from ...config import escape_radius
from ...fold.status import MAX_STEPS as STATUS_MAX_STEPS, OK as STATUS_OK
from ..base import THREADS, Engine, Unsupported, lane_engine_declines, queued_bytes_per_trajectory
from ..static import StaticParams, split_static
from ..tsit5 import SOLVER, t1_clip_floor
from .build import available, compile_library, compiler
from .emit import NativeModel
from .kernel import Job, eval_only as _eval_only_source, kernel_source

DEFAULT_WIDTH = 16  # trajectories per SIMD block (two AVX-512 vectors of doubles; docs/performance.md)
# ... for a classifier state above this many doubles per trajectory: 8. The state is read and written at
# every checkpoint for the whole block; with the attitude classifier's ~160 doubles, 16 lanes put the state
# and its update (2 x 20 KB) beyond a 32 KB L1 cache, and 8 lanes ran paper A's benchmark faster
# (docs/performance.md); a small state (named outcomes: the features alone) keeps 16
WIDE_STATE = 64
NARROW_WIDTH = 8


@functools.lru_cache(maxsize=64)
def default_width(vcfg) -> int:
    """Lanes per block for a classifier state sized to ``vcfg`` (see :data:`WIDE_STATE`)."""
    size = sum(int(np.prod(x.shape)) for x in jax.tree.leaves(jax.eval_shape(lambda: V.init(jnp.float64, vcfg))))
    return DEFAULT_WIDTH if size <= WIDE_STATE else NARROW_WIDTH


def _build(source: str) -> ctypes.CDLL:
    lib = compile_library(source)
    lib.stabjax_run.argtypes = [ctypes.POINTER(Job)]
    lib.stabjax_run.restype = ctypes.c_int64
    dp = ctypes.POINTER(ctypes.c_double)
    if hasattr(lib, "stabjax_eval"):
        lib.stabjax_eval.argtypes = [ctypes.c_double, dp, dp, dp, dp]
        lib.stabjax_update.argtypes = [dp, ctypes.c_double, dp, dp]
        lib.stabjax_eval_split.argtypes = [ctypes.c_double, dp, dp, dp]
    return lib



# a features-only fold observes of the checkpoints before its window only the last of each step (kernel_source);
# False: every one (the tests compare both, bit for bit)
SKIP_BEFORE_WINDOW = True


class _Kernel:
    def __init__(self, system, icfg, vcfg, static, dyn_shapes, width, eval_only=False):
        ts = V.checkpoint_times(icfg.checkpoints(), vcfg)  # every horizon exactly
        self.ts = np.ascontiguousarray(ts, np.float64)
        t_late = V.late_start(vcfg, float(icfg.t0), float(ts[-1]))
        self.fixed = stops.active(system, icfg)
        self.model = NativeModel(system, static, dyn_shapes, vcfg, t_late,
                                 (float(icfg.rtol), float(icfg.atol), stops.window_start(self.ts, vcfg))
                                 if self.fixed else None,
                                 icfg.known_attractors if stops.attractor_stop_active(system, icfg) else None)
        self.width = width
        # a fold of the late-window features alone (named outcomes) reads no checkpoint before the window
        # but the last one (kernel_source)
        window_from = 0 if vcfg.verdicts or not SKIP_BEFORE_WINDOW else stops.window_index(self.ts, vcfg)
        self.source = kernel_source(self.model, width, escape_radius(system, icfg),
                                    fp_every=stops.fixed_point_every(len(self.ts)), window_from=window_from,
                                    eval_entries=eval_only)
        if eval_only:
            self.source = _eval_only_source(self.source)
        self.lib = _build(self.source)
        self.vcfg = vcfg
        self.icfg = icfg
        self._finalize = jax.jit(jax.vmap(lambda c, ok: V.finalize(c, ok, vcfg)))


@functools.lru_cache(maxsize=32)
def _kernel(system, icfg, vcfg, static: StaticParams, dyn_shapes: tuple, width: int, eval_only=False) -> _Kernel:
    return _Kernel(system, icfg, vcfg, static.values, dict(dyn_shapes), width, eval_only)


def clear_cache() -> None:
    """Forget the kernels loaded in this process (the next solve builds, or loads from disk, anew)."""
    _kernel.cache_clear()


def evaluate(kern: _Kernel, t: float, y: np.ndarray, a: np.ndarray, *,
             split: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The compiled rhs and observables of one trajectory (prepared args ``a`` as from host_inputs).

    ``split=True`` computes the rhs as the loop's sixth and seventh stages do: its t-only part
    first (:func:`split_t`), then the rest.
    """
    m = kern.model
    y = np.ascontiguousarray(y, np.float64)
    a = np.ascontiguousarray(a if m.n_args else np.zeros(1), np.float64)
    dy, obs = np.empty(m.n_state), np.empty(max(m.n_obs, 1))
    dp = ctypes.POINTER(ctypes.c_double)
    kern.lib.stabjax_eval(float(t), y.ctypes.data_as(dp), a.ctypes.data_as(dp), dy.ctypes.data_as(dp),
                          obs.ctypes.data_as(dp))
    if split:
        kern.lib.stabjax_eval_split(float(t), y.ctypes.data_as(dp), a.ctypes.data_as(dp), dy.ctypes.data_as(dp))
    return dy, obs[: m.n_obs]


def update(kern: _Kernel, c: np.ndarray, t: float, obs: np.ndarray) -> np.ndarray:
    """The compiled classifier update of one trajectory (``c`` flat, as ``model.c0``)."""
    c = np.ascontiguousarray(c, np.float64)
    o = np.ascontiguousarray(obs, np.float64)
    out = np.empty(kern.model.n_c)
    dp = ctypes.POINTER(ctypes.c_double)
    kern.lib.stabjax_update(c.ctypes.data_as(dp), float(t), o.ctypes.data_as(dp), out.ctypes.data_as(dp))
    return out




def bucket(n: int) -> int:
    """The batch size the host-side JAX functions are compiled for: ``n`` rounded up to a power of two, at
    least :data:`MIN_BUCKET`. They are jitted per shape; a refinement's rounds of 258, 530, 1093, ...
    trajectories each compiled them anew (measured: ~1.8 s of every ~2 s round of the pendulum's start-plane
    refinement, against ~0.2 s in the kernel); below MIN_BUCKET one compile serves every size, and the padded
    rows cost microseconds. Rows are independent, so padding changes no row."""
    return max(MIN_BUCKET, 1 << (int(n) - 1).bit_length())


MIN_BUCKET = 4096


def _padded(tree, n: int, m: int):
    """Every leaf's rows padded from ``n`` to ``m`` with copies of the last row."""
    if m == n:
        return tree
    return jax.tree.map(lambda v: np.concatenate([np.asarray(v), np.repeat(np.asarray(v)[-1:], m - n, axis=0)]),
                        tree)


def host_inputs(model, dyn, n: int):
    """``model.host_inputs`` for ``n`` trajectories, compiled for :func:`bucket` (``n``) of them."""
    m = bucket(n)
    ain, y0 = model.host_inputs(_padded(dyn, n, m), m)
    return np.ascontiguousarray(ain[:n]), np.ascontiguousarray(y0[:n])


def finalize(kern, c, ok: np.ndarray) -> dict[str, np.ndarray]:
    """The summaries of ``n`` trajectories' fold states. A features-only fold's (means, spreads: plain
    arithmetic per row) is compiled for :func:`bucket` (``n``) rows; the attitude classifier's is compiled for
    exactly ``n``: XLA's code for its decay fits differs with the batch size in the last bits (measured:
    decay_exponent of sweeps/default.toml moved by up to 8e-11 relative on 4096 rows against 1075)."""
    n = int(np.shape(ok)[0])
    m = n if "peak" in c else bucket(n)
    out = kern._finalize(_padded(c, n, m), jnp.asarray(_padded(np.asarray(ok), n, m)))
    return {k: np.asarray(v)[:n] for k, v in out.items()}


def warm(system, icfg, vcfg, params, *, static=None) -> float:
    """Build everything a :func:`solve` of these shapes needs (C kernel, host-side JAX functions);
    returns the seconds taken (the benchmark's compile time)."""
    t = time.perf_counter()
    n = int(next(iter(params.values())).shape[0])
    kern, dyn = kernel_for(system, icfg, vcfg, params, static=static)
    host_inputs(kern.model, dyn, n)
    finalize(kern, kern.model.c_tree_from(np.zeros((n, kern.model.n_c))), np.zeros((n,), bool))
    return time.perf_counter() - t


def default_threads() -> int:
    """``$STABJAX_THREADS`` if set (a user's limit for a run in this process), else one
    thread per core available to this process. The engine setting ``threads`` overrides both."""
    from ...config import env_int

    env = env_int("STABJAX_THREADS")  # "abc" or 0: refused naming the variable, never ignored
    if env:
        return env
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def kernel_for(system, icfg, vcfg, params, *, static=None, width: int | None = None, check: bool = True,
               eval_only: bool = False):
    """The compiled kernel for this batch's shapes and constants, and the dynamic parameters.

    ``check=False`` builds it even for a system with its own ``classify``, ``eval_only=True``
    without the integration loop (both for tests of the translation: :func:`evaluate`, :func:`update`).
    """
    if icfg.solver != SOLVER:
        raise Unsupported(f"solver {icfg.solver!r} (the native engine runs {SOLVER} only)")
    if check and system.classify is not None:
        raise Unsupported(f"{system.name} has its own classify()")
    st, dyn = split_static(params, static)
    shapes = tuple(sorted((k, v.shape[1:]) for k, v in dyn.items()))
    # the kernel does not depend on how many threads run it: one cache entry for any ``threads``; nor on the
    # recurrence stop's clouds (data of the run: run_raw), only on their shape
    key_cfg = icfg.replace(settings={}) if icfg.settings else icfg
    if isinstance(icfg.known_attractors, stops.KnownAttractors):
        key_cfg = key_cfg.replace(known_attractors=stops.layout(icfg.known_attractors))
    width = int(width or ENGINE.setting(icfg, "width") or default_width(vcfg))
    return _kernel(system, key_cfg, vcfg, StaticParams(st), shapes, width, eval_only), dyn


def solve(system, params: Mapping[str, np.ndarray], icfg, vcfg, *, static: Iterable[str] | None = None,
          with_state: bool = False, threads: int | None = None, width: int | None = None,
          progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Integrate and classify ``params`` (every parameter, leading dim N) natively. Returns summaries (N,).

    Same contract as :func:`stabjax.engines.fused.solve`. ``progress(done, n)`` is called from the
    calling thread about twice a second while the threads run. ``threads`` and ``width`` default
    to the engine settings ``threads`` and ``width`` of ``icfg.settings`` (0: one thread per core,
    16 lanes per block).
    Raises :class:`Unsupported` when the system cannot be translated or no C compiler works.
    """
    n = int(next(iter(params.values())).shape[0])
    kern, dyn = kernel_for(system, icfg, vcfg, params, static=static, width=width)
    model = kern.model
    ain, y0 = host_inputs(model, dyn, n)
    known = stops.attractor_data(icfg.known_attractors) if kern.model.known is not None else None
    raw = run_raw(kern, ain, y0, threads=threads or ENGINE.setting(icfg, THREADS) or None, progress=progress,
                  known=known)
    c = model.c_tree_from(raw["c"])
    summ = finalize(kern, c, raw["status"] == STATUS_OK)
    fp = raw["fp"] == stops.HIT_FIXED_POINT  # attractor stops (codes 2 + k): features replaced later
    if fp.any():  # finished at the equilibrium: its features (stabjax.fold.stops.at_equilibrium)
        summ = stops.at_equilibrium(summ, fp, raw["obs"][:, : max(model.n_obs, 1)])
    summ["n_steps"] = raw["nacc"]
    summ["n_rejected"] = raw["nrej"]
    summ["solver_status"] = raw["status"]
    summ["stopped_at"] = raw["t"]
    summ["fixed_point"] = raw["fp"].astype(np.int32)
    if with_state:
        summ["state_t1"] = raw["y"]
        summ["t_stop"] = raw["t"]
    return summ


def run_raw(kern: _Kernel, ain: np.ndarray, y0: np.ndarray, *, threads: int | None = None,
            progress: Callable[[int, int], None] | None = None, known: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Run the compiled loop on prepared inputs; returns the raw per-trajectory outputs. ``known``: the
    recurrence stop's clouds (:func:`stabjax.fold.stops.attractor_data`), for a kernel built with them."""
    if (kern.model.known is not None) != (known is not None):
        raise ValueError("the recurrence stop's clouds go with a kernel built for them, and only then")
    model, icfg = kern.model, kern.icfg
    n = int(y0.shape[0])
    NA = max(model.n_args, 1)
    if ain.shape[1] != NA:
        ain = np.ascontiguousarray(np.zeros((n, NA)) if model.n_args == 0 else ain)
    cout = np.empty((n, model.n_c), np.float64)
    yout = np.empty((n, model.n_state), np.float64)
    tout = np.empty(n, np.float64)
    nacc = np.zeros(n, np.int32)
    nrej = np.zeros(n, np.int32)
    status = np.full(n, STATUS_MAX_STEPS, np.int32)
    fp = np.zeros(n, np.int32)
    oout = np.zeros((n, max(model.n_obs, 1)), np.float64)
    nxt = np.zeros(1, np.int64)
    ndone = np.zeros(1, np.int64)
    stop = np.zeros(1, np.int32)
    drains = np.zeros(2, np.int64)
    c0 = np.ascontiguousarray(model.c0, np.float64)

    def ptr(a):
        return a.ctypes.data_as(ctypes.c_void_p)

    job = Job(n=n, K=len(kern.ts), max_steps=int(icfg.max_steps), t0=float(icfg.t0), t1=float(icfg.t1),
              t1_floor=t1_clip_floor(float(icfg.t1)), rtol=float(icfg.rtol), atol=float(icfg.atol),
              dt0=float(icfg.dt0) if icfg.dt0 is not None else -1.0,
              ain=ptr(ain), y0in=ptr(y0), c0=ptr(c0), ts=ptr(kern.ts), cout=ptr(cout), yout=ptr(yout),
              nacc_out=ptr(nacc), nrej_out=ptr(nrej), status_out=ptr(status), next=ptr(nxt), ndone=ptr(ndone),
              stop=ptr(stop), tout=ptr(tout), fp_out=ptr(fp), oout=ptr(oout), drains=ptr(drains),
              known=ptr(known) if known is not None else None)
    n_threads = max(1, min(int(threads or default_threads()), -(-n // kern.width)))
    workers = [threading.Thread(target=kern.lib.stabjax_run, args=(ctypes.byref(job),), daemon=True)
               for _ in range(n_threads)]
    for w in workers:
        w.start()
    try:
        while any(w.is_alive() for w in workers):
            workers[0].join(0.5)
            if progress is not None:
                progress(int(ndone[0]), n)
    except BaseException:
        stop[0] = 1  # every thread stops after its current step; nothing of this call is kept
        for w in workers:
            w.join()
        raise
    for w in workers:
        w.join()
    if int(ndone[0]) != n:
        raise RuntimeError(f"native engine finished {int(ndone[0])} of {n} trajectories")
    # drains: FIFO items classified on overflow and when their lane finished (an observable of the
    # queue for tests; the per-lane order of classifier updates, hence every result, is the same)
    return {"c": cout, "y": yout, "t": tout, "nacc": nacc, "nrej": nrej, "status": status, "fp": fp, "obs": oout,
            "drains": {"overflow": int(drains[0]), "late": int(drains[1])}}


class NativeEngine(Engine):
    """The native C engine (CPU with a working C compiler)."""

    name = "native"
    compiles_per_shape = False  # the C loop takes any number of trajectories

    def supports(self, system, icfg) -> str | None:
        reason = lane_engine_declines(self.name, SOLVER, system, icfg)
        if reason is not None:
            return reason
        if jax.default_backend() != "cpu":
            return f"the JAX backend is {jax.default_backend()}, not cpu"
        if not available():
            return "no working C compiler (set CC)" if compiler() else "no C compiler on PATH (set CC)"
        return None

    def prepare(self, system, params, icfg, vcfg, static=None) -> None:
        super().prepare(system, params, icfg, vcfg, static)
        kernel_for(system, icfg, vcfg, params, static=static)

    def default_chunk(self, plan) -> int:
        """Lanes are refilled from a queue: longer chunks waste less at the tail; progress is
        still reported within a chunk."""
        return 65536

    def bytes_per_trajectory(self, plan) -> int:
        return queued_bytes_per_trajectory(plan)

    def solve(self, system, params, icfg, vcfg, static=None, progress=None):
        return solve(system, params, icfg, vcfg, static=static, progress=progress)


ENGINE = NativeEngine()

__all__ = ["ENGINE", "NativeEngine", "solve", "available", "Unsupported", "compiler", "kernel_for", "run_raw", "evaluate",
           "update", "warm", "clear_cache", "default_threads", "DEFAULT_WIDTH", "default_width"]
