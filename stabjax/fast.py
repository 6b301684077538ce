"""Fused sweep engine: one compiled loop steps a whole batch of trajectories, each with its own step size.

Why not ``jit(vmap(diffrax.diffeqsolve))``: a vmapped ``while_loop`` runs every lane until the
slowest one has finished (lock-step waste), it saves the observables of every checkpoint before
the classifier sees them, and on CPU the vmapped model becomes (3, N) slices, stacks and
transposes that XLA fuses badly. Here (measurements in ``benchmarks/NOTES.md``):

* **Lanes and a queue.** ``lanes`` trajectories are integrated side by side in ONE
  ``lax.while_loop`` per device; each lane has its own time, step size, counters and
  classifier state. A lane whose trajectory reached ``t1`` (or failed) writes its summaries and
  is refilled at once from the queue of pending trajectories, so no lane idles while others
  finish (only the tail of the queue runs part-full).
* **The method is diffrax's.** Tsitouras 5(4) with the same tableau, the same error norm (RMS
  of ``err / (atol + rtol max(|y0|, |y1|))``), the same I-controller as ``diffrax.PIDController``
  defaults (safety 0.9, factor in [0.2, 10], accepted steps never shrink, rejected ones shrink
  by at least 0.9), the same initial step (Hairer's rule), the same clipping of the last step to
  ``t1``. Final states agree with diffrax and SciPy to the tolerance (``tests/test_fast.py``).
* **Checkpoints without storage.** A step handles at most ``CHECKPOINT_SLOTS`` checkpoints and
  ends on the next one if it would cross more (the controller's own proposal is kept for the
  step after); the state at a checkpoint comes from Tsit5's dense output (the interpolant
  diffrax uses for ``SaveAt(ts=...)``) and goes straight into the running classifier
  (:func:`stabjax.verdict.update`, the very rules of :func:`stabjax.verdict.classify`).
* **Lane-wise evaluation of the model.** The system's ``prepare/initial_state/rhs/observe``
  and the classifier are traced once per trajectory (jaxprs) and evaluated with every array
  element held separately as a (lanes,) vector or a constant (:class:`LaneFn`): slices,
  stacks, 3x3 products become bookkeeping, XLA sees only elementwise ops on contiguous
  vectors. Parameters equal across the sweep are folded in as constants. float64 log, sin,
  cos and pow use branch-free vectorisable code (XLA:CPU calls scalar libm for them).
  Systems with a primitive that has no rule (or with their own ``classify``, or another
  solver) raise :class:`Unsupported` and the engine uses the diffrax path.
* **Both CPU cores.** Trajectories are dealt round-robin to the local devices, each device runs
  its own loop (``shard_map``); :mod:`stabjax` asks JAX for one host device per core. On a GPU
  the same code runs on one device with wide lanes.

A trajectory that cannot progress (its right-hand side is not finite at an accepted state:
diffrax would shrink the step until ``max_steps``) is stopped at once with the status code
diffrax would end with (``max_steps_reached`` = 1). For FAILED trajectories only ``verdict``,
``solver_status`` and the step counts are meaningful.
"""
from __future__ import annotations

import functools
import os
from typing import Iterable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from . import verdict as V

# ---- Tsit5 tableau (Tsitouras 2011), the float64 values diffrax uses --------------------------
_C = (0.161, 0.327, 0.9, 0.9800255409045097, 1.0, 1.0)
_A = (
    (0.161,),
    (-0.008480655492356989, 0.335480655492357),
    (2.8971530571054935, -6.359448489975075, 4.3622954328695815),
    (5.325864828439257, -11.748883564062828, 7.4955393428898365, -0.09249506636175525),
    (5.86145544294642, -12.92096931784711, 8.159367898576159, -0.071584973281401, -0.028269050394068383),
    (0.09646076681806523, 0.01, 0.4798896504144996, 1.379008574103742, -3.290069515436081, 2.324710524099774),
)
_E = (0.0017800110522257773, 0.0008164344596567463, -0.007880878010261994, 0.1447110071732629,
      -0.5823571654525552, 0.45808210592918686, -0.015151515151515152)
_ORDER = 5  # diffrax's error order for Tsit5 on an ODE
SAFETY, FACTORMIN, FACTORMAX = 0.9, 0.2, 10.0
STATUS_OK, STATUS_MAX_STEPS = 0, 1  # diffrax RESULTS codes
# checkpoints handled per step; a step that would contain more ends on the next one (see NOTES.md)
CHECKPOINT_SLOTS = int(os.environ.get("STABJAX_CHECKPOINT_SLOTS", "1"))

SUPPORTED_SOLVERS = ("tsit5",)


def _interp_weights(th):
    """Tsit5 dense-output weights b_i(theta) (diffrax ``_Tsit5Interpolation``)."""
    th2 = th * th
    b1 = -1.0530884977290216 * th * (th - 1.3299890189751412) * (th2 - 1.4364028541716351 * th + 0.7139816917074209)
    b2 = 0.1017 * th2 * (th2 - 2.1966568338249754 * th + 1.2949852507374631)
    b3 = 2.490627285651252793 * th2 * (th2 - 2.38535645472061657 * th + 1.57803468208092486)
    b4 = -16.54810288924490272 * (th - 1.21712927295533244) * (th - 0.61620406037800089) * th2
    b5 = 47.37952196281928122 * (th - 1.203071208372362603) * (th - 0.658047292653547382) * th2
    b6 = -34.87065786149660974 * (th - 1.2) * (th - 0.666666666666666667) * th2
    b7 = 2.5 * (th - 1) * (th - 0.6) * th2
    return (b1, b2, b3, b4, b5, b6, b7)


def default_lanes(platform: str | None = None) -> int:
    """Lanes per device: small enough that a step's working set stays in cache on CPU, wide on GPU
    (2^18 measured fastest on an H100: 2^16 leaves it idle between kernels, 2^20 is bound by
    memory traffic; benchmarks/NOTES.md G2)."""
    env = os.environ.get("STABJAX_LANES")
    if env:
        return max(1, int(env))
    platform = platform or jax.default_backend()
    return 256 if platform == "cpu" else 262144


def _t1_clip_floor(t1: float) -> float:
    x = float(t1)
    for _ in range(100):  # diffrax rounds a step ending within 100 ulp of t1 to t1
        x = float(np.nextafter(x, -np.inf))
    return x


# ==== vectorisable float64 log / sin / cos ====================================================
# XLA:CPU calls scalar libm for log, sin, cos, pow and atan2 (measured 9-25 ns per element on
# the benchmark machine against ~2 ns for its vectorised exp); the lane-wise evaluator below
# routes float64 log, sin, cos and pow through these branch-free versions instead (log: 2 ulp,
# sin/cos: 0.5 ulp of 1 in absolute terms; see tests/test_fast.py).

_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_SQRT2 = 1.4142135623730951
_LOG_C = [1.0 / (2 * k + 1) for k in range(1, 12)]  # 1/3, 1/5, ..., 1/23

def fast_log(x):
    """Natural log for float64 vectors: exponent + atanh series on [sqrt(1/2), sqrt(2)) (~1 ulp)."""
    tiny = x < 2.2250738585072014e-308
    xs = jnp.where(tiny, x * 18014398509481984.0, x)  # 2**54: subnormals to normal range
    bits = lax.bitcast_convert_type(xs, jnp.int64)
    e = ((bits >> 52) & 0x7FF) - 1023 - jnp.where(tiny, 54, 0)
    m = lax.bitcast_convert_type((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000, jnp.float64)
    big = m > _SQRT2
    m = jnp.where(big, 0.5 * m, m)
    e = (e + big.astype(e.dtype)).astype(jnp.float64)
    f = (m - 1.0) / (m + 1.0)
    s = f * f
    p = _LOG_C[-1]
    for c in _LOG_C[-2::-1]:
        p = c + s * p
    r = e * _LN2_HI + ((2.0 * f + 2.0 * f * s * p) + e * _LN2_LO)
    r = jnp.where(x == 0, -jnp.inf, r)
    r = jnp.where(x < 0, jnp.nan, r)
    return jnp.where(x == jnp.inf, jnp.inf, jnp.where(jnp.isnan(x), x, r))

# pi/2 as a sum of 26-bit pieces (Cody & Waite): n * piece is exact for |n| < 2**26. Computed
# from a 100-digit pi by repeated rounding of the remainder to 26 significant bits.
_PIO2 = (1.5707963407039642, -1.3909067675399456e-08, 6.123233932053594e-17, 6.368317178484799e-25)

_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_Cc = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
       -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
_TWO_OVER_PI = 0.6366197723675814
SINCOS_LIMIT = 2.0 ** 26 * 1.5707963267948966  # |n| < 2**26: the products n * piece are exact

def _ksin(x):
    z = x * x; w = z * z
    r = _S[1] + z * (_S[2] + z * _S[3]) + z * w * (_S[4] + z * _S[5])
    return x + z * x * (_S[0] + z * r)

def _kcos(x):
    z = x * x; w = z * z
    r = z * (_Cc[0] + z * (_Cc[1] + z * _Cc[2])) + w * w * (_Cc[3] + z * (_Cc[4] + z * _Cc[5]))
    hz = 0.5 * z
    w = 1.0 - hz
    return w + (((1.0 - w) - hz) + z * r)

def _reduce(x):
    n = jnp.round(x * _TWO_OVER_PI)
    r = x - n * _PIO2[0]
    r = r - n * _PIO2[1]
    r = r - n * _PIO2[2]
    r = r - n * _PIO2[3]
    q = (n - 4.0 * jnp.floor(0.25 * n))  # n mod 4 in {0,1,2,3}
    return r, q

_ATANHI = (4.63647609000806093515e-01, 7.85398163397448278999e-01, 9.82793723247329054082e-01, 1.57079632679489655800e+00)
_ATANLO = (2.26987774529616870924e-17, 3.06161699786838301793e-17, 1.39033110312309984516e-17, 6.12323399573676603587e-17)
_AT = (3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01, -1.11111104054623557880e-01,
       9.09088713343650656196e-02, -7.69187620504482999495e-02, 6.66107313738753120669e-02, -5.83357013379057348645e-02,
       4.97687799461593236017e-02, -3.65315727442169155270e-02, 1.62858201153657823623e-02)
_PI = 3.141592653589793
_PIO2_HI, _PIO2_LO = 1.5707963267948966, 6.123233995736766e-17
_PI_LO = 1.2246467991473532e-16


def _atan01(t):
    """atan(t) for 0 <= t <= 1 (fdlibm s_atan.c, branch-free)."""
    i0, i1, i2 = t >= 0.4375, t >= 0.6875, t >= 1.1875  # t <= 1: the fourth interval never applies
    num = jnp.where(i1, t - 1.0, jnp.where(i0, 2.0 * t - 1.0, t))
    den = jnp.where(i1, t + 1.0, jnp.where(i0, 2.0 + t, 1.0))
    x = num / den
    del i2
    z = x * x
    w = z * z
    s1 = z * (_AT[0] + w * (_AT[2] + w * (_AT[4] + w * (_AT[6] + w * (_AT[8] + w * _AT[10])))))
    s2 = w * (_AT[1] + w * (_AT[3] + w * (_AT[5] + w * (_AT[7] + w * _AT[9]))))
    hi = jnp.where(i1, _ATANHI[1], _ATANHI[0])
    lo = jnp.where(i1, _ATANLO[1], _ATANLO[0])
    return jnp.where(i0, hi - ((x * (s1 + s2) - lo) - x), x - x * (s1 + s2))


def fast_atan2(y, x):
    """atan2 for float64 vectors without libm: reduce to atan(t), t = min/max in [0, 1] (< 1 ulp of pi)."""
    ax, ay = jnp.abs(x), jnp.abs(y)
    both_inf = jnp.isinf(ax) & jnp.isinf(ay)
    big, small = jnp.maximum(ax, ay), jnp.minimum(ax, ay)
    t = jnp.where(both_inf, 1.0, jnp.where(big == 0, 0.0, small / jnp.where(big == 0, 1.0, big)))
    a = _atan01(t)
    a = jnp.where(ay > ax, (_PIO2_HI - a) + _PIO2_LO, a)
    neg_x = jnp.signbit(x)
    a = jnp.where(neg_x, (_PI - a) + _PI_LO, a)
    a = jnp.where(jnp.isnan(x) | jnp.isnan(y), jnp.nan, a)
    return jnp.where(jnp.signbit(y), -a, a)


def _sincos(name, x):
    """sin/cos of a lane vector: the fast path unless some |x| is beyond the exact reduction."""
    fast = fast_sin_small if name == "sin" else fast_cos_small
    exact = jnp.sin if name == "sin" else jnp.cos
    return _materialize(lax.cond(jnp.any(jnp.abs(x) > SINCOS_LIMIT), exact, fast, x), 3)


def fast_cos_small(x):
    r, q = _reduce(x)
    s, c = _ksin(r), _kcos(r)
    return jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s)))

def fast_sin_small(x):
    r, q = _reduce(x)
    s, c = _ksin(r), _kcos(r)
    return jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c)))



# ==== lane-wise evaluation: run a per-trajectory function on rows of lanes =================
#
# ``jax.vmap`` of a per-trajectory model gives XLA arrays like (3, L) that it slices, stacks,
# transposes and concatenates; on CPU the fusions built from those shuffle data and recompute
# shared terms per output row (measured: ~190-300 ns per lane per right-hand-side evaluation
# of the monoaxial model, see benchmarks/NOTES.md). Here the model's jaxpr is evaluated with
# every array element held separately: an element is either a Python/NumPy constant or a
# (L,) vector over lanes. Slices, reshapes, stacks and small matrix products become
# bookkeeping on NumPy object arrays, and XLA only ever sees elementwise operations on
# contiguous (L,) vectors, which it fuses into SIMD loops. ``pow`` with a lane-varying
# exponent goes through exp/log (XLA's vectorised kernels) instead of scalar libm calls.
# Any primitive without a rule raises ``_Unsupported`` and the engine falls back to vmap.

def _materialize(x, level=2):
    """Store a lane vector once instead of letting XLA recompute it in every consumer.

    XLA:CPU fuses a cheap producer into *each* of its consumers; in a Runge-Kutta step, where
    every stage derivative feeds all later stages, the error estimate and the dense output,
    that duplicates the right-hand side many times over (measured: ~8x more arithmetic than
    the jaxpr holds). A division is "expensive" to XLA's fusion heuristics and is never
    duplicated, so ``x / one`` with a run-time ``one`` (exactly 1.0, an input of the compiled
    function so it cannot be constant-folded) makes ``x`` a materialised buffer. x / 1.0 == x
    exactly in IEEE arithmetic. ``optimization_barrier`` does not survive XLA:CPU's pipeline.
    """
    one = _ONE[-1] if _ONE else None
    if level > _MAT_LEVEL:
        return x
    if one is None or not _BARRIER or _is_const(x) or x.dtype != one.dtype:
        return x
    return x / one


_ONE: list = []  # the run-time 1.0 of the device loop being traced (a stack: traces may nest)
_BARRIER = os.environ.get("STABJAX_NO_BARRIER") is None
_FAST_ATAN2 = os.environ.get("STABJAX_FAST_ATAN2", "0") == "1"
_MAT_LEVEL = int(os.environ.get("STABJAX_MAT_LEVEL", "2"))


class _Unsupported(Exception):
    pass


_ELEMENTWISE = frozenset("""
add sub mul div rem pow max min atan2 nextafter and or xor not neg sign floor ceil round is_finite
exp exp2 log log1p expm1 tanh logistic sin cos tan asin acos atan sinh cosh asinh acosh atanh sqrt
rsqrt cbrt integer_pow square abs eq ne lt le gt ge convert_element_type select_n clamp erf erfc
erf_inv lgamma digamma copy copy_p reduce_precision real imag conj shift_left shift_right_logical
shift_right_arithmetic population_count
""".split())

_REDUCE = {"reduce_sum": "add", "reduce_max": "max", "reduce_min": "min", "reduce_prod": "mul",
           "reduce_and": "and", "reduce_or": "or"}


def _is_const(e) -> bool:
    return isinstance(e, (np.generic, np.ndarray))


def _obj(shape):
    return np.empty(shape, dtype=object)


def _rows_to_objs(shapes, rows):
    """Consecutive flat rows -> one object array per shape (the lane-wise evaluator's input)."""
    out, k = [], 0
    for shape in shapes:
        o = _obj(shape)
        for j, i in enumerate(np.ndindex(shape)):
            o[i] = rows[k + j]
        out.append(o)
        k += int(np.prod(shape))
    return out


def _const_array(x, dtype=None):
    x = np.asarray(x, dtype=dtype)
    out = _obj(x.shape)
    for i in np.ndindex(x.shape):
        out[i] = x[i]  # NumPy scalar
    return out


class _Lanes:
    """Evaluator of closed jaxprs on object arrays whose elements are constants or (L,) vectors."""

    # In a dot product, drop the terms whose constant factor is exactly zero (the native emitter
    # turns this on: a diagonal gain matrix K then costs 3 products instead of 9). IEEE gives NaN
    # for 0 * inf, so the result differs only when the other factor is not finite; that factor is
    # a component of the state or of a value computed from it, which makes the derivative
    # non-finite elsewhere, so the step is rejected either way. (And in the sign of an exact zero.)
    drop_zero_terms = False

    def __init__(self, L: int):
        self.L = L

    # -- elements ---------------------------------------------------------------------------
    def lift(self, e, dtype):
        if _is_const(e):
            return jnp.full((self.L,), np.asarray(e).astype(dtype))
        return e

    def bind_elem(self, prim, params, es, in_dtypes):
        if all(_is_const(e) for e in es):
            with jax.ensure_compile_time_eval():
                r = prim.bind(*[np.asarray(e, dtype=d) for e, d in zip(es, in_dtypes)], **params)
            return np.asarray(r)[()]
        f64 = all(d == np.float64 for d in in_dtypes)
        if prim.name == "pow" and f64:
            return self.pow(es[0], es[1], in_dtypes)
        if prim.name == "log" and f64 and not params.get("accuracy"):
            return _materialize(fast_log(es[0]), 3)
        if prim.name in ("sin", "cos") and f64 and not params.get("accuracy"):
            return _sincos(prim.name, es[0])
        if prim.name == "atan2" and f64 and _FAST_ATAN2:
            return _materialize(fast_atan2(es[0], es[1]), 2)
        if prim.name == "select_n" and _is_const(es[0]):
            return es[1 + int(es[0])]
        return prim.bind(*[self.lift(e, d) for e, d in zip(es, in_dtypes)], **params)

    def pow(self, x, y, dtypes):
        """x ** y for float x, y as exp(y log|x|) with XLA's vectorised exp and :func:`fast_log`.

        IEEE special cases as in libm. Relative error about (4 + 2 |y ln x|) ulp: exp amplifies
        the rounding of y ln x (at most ~1.6e-13 for finite results, typically 1e-15).
        """
        if _is_const(y):
            yv = float(y)
            if yv == 0.0:
                return np.asarray(1.0, dtype=dtypes[0])[()]
            if yv == 1.0:
                return x
            if yv == 0.5:
                return jnp.sqrt(x)
            if yv == int(yv) and abs(yv) <= 4:
                return lax.integer_pow(x, int(yv))
        x = self.lift(x, dtypes[0])
        y = self.lift(y, dtypes[1])
        r = jnp.exp(y * fast_log(jnp.abs(x)))
        yi = jnp.round(y)
        is_int = y == yi
        odd = is_int & (yi - 2.0 * jnp.floor(0.5 * yi) != 0)
        # IEEE 754 pow special cases (libm's): negative bases, zeros, infinities, NaNs
        r = jnp.where(x < 0, jnp.where(is_int | jnp.isinf(x), jnp.where(odd & ~jnp.isinf(y), -r, r), jnp.nan), r)
        r = jnp.where((x == -1) & jnp.isinf(y), 1.0, r)
        r = jnp.where(x == 0, jnp.where(y > 0, 0.0, jnp.where(y < 0, jnp.inf, jnp.where(y == 0, 1.0, jnp.nan))), r)
        return _materialize(jnp.where((y == 0) | (x == 1), 1.0, r), 3)

    def binop(self, name, a, b, dtype):
        prim = _PRIMS[name]
        return self.bind_elem(prim, {}, [a, b], [dtype, dtype])

    # -- primitives ---------------------------------------------------------------------------
    def eval_closed(self, closed, args):
        return self.eval_jaxpr(closed.jaxpr, closed.consts, args)

    def eval_jaxpr(self, jaxpr, consts, args):
        env = {}

        def read(v):
            if isinstance(v, _Literal):
                return _const_array(v.val, v.aval.dtype)
            return env[v]

        for v, c in zip(jaxpr.constvars, consts):
            if isinstance(c, jax.core.Tracer):
                raise _Unsupported("traced constant")
            env[v] = _const_array(np.asarray(c))
        for v, a in zip(jaxpr.invars, args):
            env[v] = a
        for eqn in jaxpr.eqns:
            ins = [read(v) for v in eqn.invars]
            outs = self.apply(eqn, ins)
            for v, o in zip(eqn.outvars, outs):
                if not isinstance(v, _DropVar):
                    env[v] = o
        return [read(v) for v in jaxpr.outvars]

    def apply(self, eqn, ins):
        name = eqn.primitive.name
        p = eqn.params
        out_avals = [v.aval for v in eqn.outvars]
        if name in _ELEMENTWISE:
            shape = out_avals[0].shape
            in_dtypes = [v.aval.dtype for v in eqn.invars]
            arrs = [np.broadcast_to(a, shape) for a in ins]
            out = _obj(shape)
            for i in np.ndindex(shape):
                out[i] = self.bind_elem(eqn.primitive, p, [a[i] for a in arrs], in_dtypes)
            return [out]
        if name in ("jit", "pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
                    "custom_vjp_call", "custom_vjp_call_jaxpr"):
            sub = p.get("jaxpr", p.get("call_jaxpr", p.get("fun_jaxpr")))
            if sub is None:
                raise _Unsupported(name)
            if hasattr(sub, "consts"):
                return self.eval_closed(sub, ins[: len(sub.jaxpr.invars)])
            return self.eval_jaxpr(sub, (), ins[: len(sub.invars)])
        a = ins[0] if ins else None
        if name == "slice":
            strides = p["strides"] or (1,) * a.ndim
            return [a[tuple(slice(s, l, st) for s, l, st in zip(p["start_indices"], p["limit_indices"], strides))]]
        if name == "squeeze":
            return [np.squeeze(a, axis=tuple(p["dimensions"]))]
        if name == "reshape":
            if p.get("dimensions") not in (None, ()):
                raise _Unsupported("reshape with dimensions")
            return [a.reshape(tuple(p["new_sizes"]))]
        if name == "expand_dims":
            return [np.expand_dims(a, tuple(p["dimensions"]))]
        if name == "broadcast_in_dim":
            shape = tuple(p["shape"])
            expanded = [1] * len(shape)
            for src, dst in enumerate(p["broadcast_dimensions"]):
                expanded[dst] = a.shape[src]
            return [np.broadcast_to(a.reshape(expanded), shape)]
        if name == "transpose":
            return [np.transpose(a, tuple(p["permutation"]))]
        if name == "rev":
            return [np.flip(a, tuple(p["dimensions"]))]
        if name == "concatenate":
            return [np.concatenate(ins, axis=p["dimension"])]
        if name == "stack":
            return [np.stack(ins, axis=p["axis"])]
        if name == "split":
            cuts = np.cumsum(p["sizes"])[:-1]
            return list(np.split(a, cuts, axis=p["axis"]))
        if name == "iota":
            aval = out_avals[0]
            ar = np.arange(aval.shape[p["dimension"]], dtype=aval.dtype)
            shp = [1] * len(aval.shape)
            shp[p["dimension"]] = -1
            return [_const_array(np.broadcast_to(ar.reshape(shp), aval.shape))]
        if name in _REDUCE:
            axes = tuple(p["axes"])
            keep = [d for d in range(a.ndim) if d not in axes]
            moved = np.transpose(a, keep + list(axes))
            out_shape = tuple(a.shape[d] for d in keep)
            flat = moved.reshape(out_shape + (-1,))
            dtype = eqn.invars[0].aval.dtype
            out = _obj(out_shape)
            for i in np.ndindex(out_shape):
                acc = flat[i][0]
                for e in flat[i][1:]:
                    acc = self.binop(_REDUCE[name], acc, e, dtype)
                out[i] = acc
            return [out]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], p, eqn)]
        if name == "dynamic_slice":
            idx = ins[1:]
            if not all(_is_const(i[()]) for i in idx):
                raise _Unsupported("dynamic_slice with lane-varying index")
            starts = [int(i[()]) for i in idx]
            starts = [min(max(s, 0), d - n) for s, d, n in zip(starts, a.shape, p["slice_sizes"])]
            return [a[tuple(slice(s, s + n) for s, n in zip(starts, p["slice_sizes"]))]]
        if name == "cond":
            branches = p["branches"]
            index = ins[0][()]
            ops = ins[1:]
            if _is_const(index):
                k = int(np.clip(int(index), 0, len(branches) - 1))
                return self.eval_closed(branches[k], ops)
            outs = [self.eval_closed(b, ops) for b in branches]
            idx = jnp.clip(index, 0, len(branches) - 1).astype(jnp.int32)
            res = []
            for j, aval in enumerate(out_avals):
                o = _obj(aval.shape)
                for i in np.ndindex(aval.shape):
                    o[i] = lax.select_n(idx, *[self.lift(b[j][i], aval.dtype) for b in outs])
                res.append(o)
            return res
        raise _Unsupported(name)

    def dot_general(self, x, y, p, eqn):
        (lc, rc), (lb, rb) = p["dimension_numbers"]
        lf = [d for d in range(x.ndim) if d not in lc and d not in lb]
        rf = [d for d in range(y.ndim) if d not in rc and d not in rb]
        xt = np.transpose(x, list(lb) + lf + list(lc))
        yt = np.transpose(y, list(rb) + rf + list(rc))
        bshape = tuple(x.shape[d] for d in lb)
        xs = tuple(x.shape[d] for d in lf)
        ys = tuple(y.shape[d] for d in rf)
        kn = int(np.prod([x.shape[d] for d in lc])) if lc else 1
        xt = xt.reshape(bshape + xs + (kn,))
        yt = yt.reshape(bshape + ys + (kn,))
        dtype = eqn.outvars[0].aval.dtype
        out = _obj(bshape + xs + ys)
        for b in np.ndindex(bshape):
            for i in np.ndindex(xs):
                for j in np.ndindex(ys):
                    acc = None
                    for k in range(kn):
                        xe, ye = xt[b + i + (k,)], yt[b + j + (k,)]
                        if self.drop_zero_terms and any(_is_const(e) and e == 0 for e in (xe, ye)):
                            continue
                        term = self.binop("mul", xe, ye, dtype)
                        acc = term if acc is None else self.binop("add", acc, term, dtype)
                    out[b + i + j] = acc if acc is not None else np.zeros((), dtype)[()]
        return out


_PRIMS = {"add": lax.add_p, "mul": lax.mul_p, "max": lax.max_p, "min": lax.min_p, "and": lax.and_p, "or": lax.or_p}
try:
    from jax.extend.core import Literal as _Literal, DropVar as _DropVar
except ImportError:  # older JAX
    from jax.core import Literal as _Literal, DropVar as _DropVar


def _rows(x, L):
    """Batch-last array (*shape, L) -> object array ``shape`` of (L,) rows."""
    x = jnp.asarray(x)
    out = _obj(x.shape[:-1])
    for i in np.ndindex(x.shape[:-1]):
        out[i] = x[i]
    return out


def _unrows(o, L, dtype):
    """Object array of rows/constants -> batch-last array (*shape, L)."""
    if o.shape == ():
        e = o[()]
        return jnp.full((L,), np.asarray(e).astype(dtype)) if _is_const(e) else e.astype(dtype)
    flat = [(jnp.full((L,), np.asarray(e).astype(dtype)) if _is_const(e) else e.astype(dtype)) for e in o.ravel()]
    return jnp.stack(flat).reshape(*o.shape, L)


class LaneFn:
    """A per-trajectory function evaluated lane-wise on batch-last pytrees (see above)."""

    def __init__(self, fn, *example):
        self.closed = jax.make_jaxpr(fn)(*example)
        self.out_tree = jax.tree.structure(jax.eval_shape(fn, *example))
        self.in_avals = [v.aval for v in self.closed.jaxpr.invars]

    def rows_in(self, L, *args):
        leaves = jax.tree.leaves(args)
        return [_rows(jnp.broadcast_to(x, (*aval.shape, L)) if jnp.ndim(x) == 0 else x, L)
                for x, aval in zip(leaves, self.in_avals)]

    def call_rows(self, L, rows):
        return _Lanes(L).eval_closed(self.closed, rows)

    def __call__(self, L, *args):
        outs = self.call_rows(L, self.rows_in(L, *args))
        avals = [v.aval for v in self.closed.jaxpr.outvars]
        return jax.tree.unflatten(self.out_tree, [_unrows(o, L, a.dtype) for o, a in zip(outs, avals)])


class _RowSpec:
    """How a pytree of per-trajectory arrays maps to a flat list of (L,) lane rows."""

    def __init__(self, tree_example):
        leaves, self.treedef = jax.tree.flatten(tree_example)
        self.shapes = [tuple(x.shape) for x in leaves]  # per-trajectory shapes
        self.dtypes = [x.dtype for x in leaves]
        self.sizes = [int(np.prod(s)) for s in self.shapes]

    def objs(self, rows):
        """Flat rows -> one object array per leaf (the lane-wise evaluator's input)."""
        return _rows_to_objs(self.shapes, rows)

    def tree(self, rows, L):
        """Flat rows -> pytree of batch-last arrays (L last)."""
        leaves, k = [], 0
        for shape, n, dt in zip(self.shapes, self.sizes, self.dtypes):
            part = [r.astype(dt) for r in rows[k:k + n]]
            leaves.append(part[0] if shape == () else jnp.stack(part).reshape(*shape, L))
            k += n
        return jax.tree.unflatten(self.treedef, leaves)


def _flat_rows(objs, L, dtypes=None):
    """Object arrays -> flat list of (L,) rows (constants broadcast)."""
    out = []
    for j, o in enumerate(objs):
        dt = None if dtypes is None else dtypes[j]
        for i in np.ndindex(o.shape):
            e = o[i]
            if _is_const(e):
                out.append(jnp.full((L,), np.asarray(e) if dt is None else np.asarray(e).astype(dt)))
            else:
                out.append(e if dt is None else e.astype(dt))
    return out


def _obj1(rows):
    o = _obj((len(rows),))
    for i, r in enumerate(rows):
        o[i] = r
    return o


def _obj0(x):
    o = _obj(())
    o[()] = x
    return o


class Unsupported(Exception):
    """The fused engine cannot run this system/config; use the diffrax path."""


class _Model:
    """A system's traced methods evaluated lane-wise, with the batch-constant parameters folded in.

    Parameters equal across the whole batch (``static``) are compile-time constants: the
    evaluator folds them (``pow(x, 0.5)`` becomes ``sqrt``, ``x * 1`` disappears); the others
    arrive as lane rows. ``prepare`` runs once per trajectory (at refill); its outputs that are
    constants are kept in a template and only its lane-varying entries are carried.
    """

    def __init__(self, system, static: Mapping[str, np.ndarray], dyn_shapes: Mapping[str, tuple], vcfg, t_late):
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
        ex_c = jax.eval_shape(lambda: V.init(f64))
        self.n_obs = int(np.prod(ex_obs.shape))
        self.args_spec = _RowSpec(ex_args)
        self.c_spec = _RowSpec(ex_c)
        t_late = float(t_late)
        self.template = None
        try:
            self.prep = LaneFn(lambda pd: system.prepare(full(pd)), ex_pd)
            self.init = LaneFn(lambda pd: system.initial_state(full(pd)), ex_pd)
            self.rhs = LaneFn(system.rhs, ex_t, ex_y, ex_args)
            self.obs = LaneFn(system.observe, ex_t, ex_y, ex_args)
            self.upd = LaneFn(lambda c, t, o: V.update(c, t, o, vcfg, t_late), ex_c, ex_t, ex_obs)
            # dry run of every function on abstract lanes: an unsupported primitive shows up now
            L = 8
            jax.eval_shape(self._dry, *[sds((L,), f64) for _ in range(sum(int(np.prod(s)) for s in self.dyn_shapes.values()))])
        except _Unsupported as exc:
            raise Unsupported(f"no lane-wise rule for primitive {exc}") from None

    def _dry(self, *rows):
        L = rows[0].shape[0] if rows else 8
        args, y0 = self.fresh_rows(L, list(rows))
        args_objs = self.args_objs(args)
        t = jnp.zeros((L,))
        f = self.f(L, t, y0, args_objs)
        o = self.observe(L, t, y0, args_objs)
        c = _flat_rows(self.c_spec.objs([jnp.zeros((L,), d) for d, n in zip(self.c_spec.dtypes, self.c_spec.sizes)
                                        for _ in range(n)]), L)
        return f, self.update(L, c, t, o)

    def dyn_objs(self, rows):
        return _rows_to_objs([self.dyn_shapes[key] for key in self.dyn_keys], rows)

    def fresh_rows(self, L, dyn_rows):
        """Lane-varying prepared args (flat rows; constants go to the template) and y0 rows."""
        ins = self.dyn_objs(dyn_rows)
        lanes = _Lanes(L)
        args = lanes.eval_closed(self.prep.closed, ins)
        if self.template is None:
            self.template = [np.vectorize(lambda e: e if _is_const(e) else None, otypes=[object])(a)
                             if a.size else a for a in args]
        rows = [a[i] for a in args for i in np.ndindex(a.shape) if not _is_const(a[i])]
        # a slot constant in one trace is constant in every trace (same jaxpr, same constants)
        y0 = _flat_rows(lanes.eval_closed(self.init.closed, ins), L, [np.float64])
        return rows, y0

    def args_objs(self, rows):
        out, k = [], 0
        for tpl in self.template:
            o = _obj(tpl.shape)
            for i in np.ndindex(tpl.shape):
                if tpl[i] is None:
                    o[i] = rows[k]
                    k += 1
                else:
                    o[i] = tpl[i]
            out.append(o)
        return out

    def f(self, L, t, y, args_objs):
        out = _Lanes(L).eval_closed(self.rhs.closed, [_obj0(t), _obj1(y)] + args_objs)
        return [_materialize(r, 1) for r in _flat_rows(out, L, [np.float64])]

    def observe(self, L, t, y, args_objs):
        out = _Lanes(L).eval_closed(self.obs.closed, [_obj0(t), _obj1(y)] + args_objs)
        return _flat_rows(out, L, [np.float64])

    def update(self, L, c_rows, t, obs_rows):
        ins = self.c_spec.objs(c_rows) + [_obj0(t), _obj1(obs_rows)]
        out = _Lanes(L).eval_closed(self.upd.closed, ins)
        return _flat_rows(out, L, self.c_spec.dtypes)


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
    ts_np = icfg.checkpoints()
    K = len(ts_np)
    t0, t1 = float(icfg.t0), float(icfg.t1)
    t1_floor = _t1_clip_floor(t1)
    rtol, atol = float(icfg.rtol), float(icfg.atol)
    max_steps = int(icfg.max_steps)
    t_late = V.late_start(vcfg, t0, float(ts_np[-1]))
    f64 = jnp.float64
    model = _Model(system, static, dyn_shapes, vcfg, t_late)
    n_state = model.n_state

    def run(p: Mapping[str, jnp.ndarray], one):
        _ONE.append(one.reshape(()))
        try:
            return _run(p)
        finally:
            _ONE.pop()

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
            h1 = jnp.where(max_d <= 1e-15, jnp.maximum(1e-6, h0 * 1e-3), jnp.exp(fast_log(0.01 / max_d) / _ORDER))
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
            c0 = V.init(f64)
            vc = [jnp.full((L,), x[i]) for x in jax.tree.leaves(c0) for i in np.ndindex(x.shape)]
            zi = jnp.zeros((L,), jnp.int32)
            return dict(args=args, y=y, f=f, t=tt, tn=tn, ck=zi, vc=vc, nacc=zi, nrej=zi)

        summ_shape = jax.eval_shape(lambda: v_finalize(
            jax.tree.map(lambda x: jnp.broadcast_to(x[..., None], (*x.shape, 1)), V.init(f64)), jnp.ones((1,), bool)))
        out = {k: jnp.zeros((M, *s.shape[1:]), s.dtype) for k, s in summ_shape.items()}  # trailing dims (INTERFACES 2)
        for k in ("n_steps", "n_rejected", "solver_status"):
            out[k] = jnp.zeros((M,), jnp.int32)
        if with_state:
            for i in range(n_state):
                out[f"__y{i}"] = jnp.zeros((M,), f64)

        def sel(mask, a, b):
            return jax.tree.map(lambda x, y: jnp.where(mask, x, y), a, b)

        def finish_and_refill(carry, done, status):
            lane, idx, nxt, out = carry
            summ = v_finalize(model.c_spec.tree(lane["vc"], L), status == STATUS_OK)
            summ["n_steps"] = lane["nacc"]
            summ["n_rejected"] = lane["nrej"]
            summ["solver_status"] = status
            if with_state:
                for i in range(n_state):
                    summ[f"__y{i}"] = lane["y"][i]
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
                yi = [_materialize(v) for v in _lincomb(y, h, _A[i], fs)]
                fs.append(model.f(L, t + _C[i] * h, yi, args))
            y_new = [_materialize(v) for v in _lincomb(y, h, _A[5], fs)]
            f7 = model.f(L, te, y_new, args)
            fs.append(f7)
            y_err = [h * e for e in _lincomb([0.0] * n_state, 1.0, _E, fs)]

            # -- diffrax PIDController (I-controller defaults) --
            y_err = [jnp.where(jnp.isnan(e), jnp.inf, e) for e in y_err]
            bad_new = functools.reduce(jnp.logical_or, [jnp.isnan(v) for v in y_new])
            ratios = []
            for y0i, y1i, ei in zip(y, y_new, y_err):
                ysc = jnp.maximum(jnp.abs(y0i), jnp.abs(jnp.where(bad_new, y0i, y1i)))
                ratios.append(ei / (atol + ysc * rtol))
            err = rms(ratios)
            keep = err < 1
            factor = jnp.clip(SAFETY * jnp.exp(-fast_log(err) / _ORDER), jnp.where(keep, 1.0, FACTORMIN),
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
                bs = [_materialize(b) for b in _interp_weights(th)]
                y_ck = [_materialize(v) for v in _lincomb(y, h, [1.0] * 7, [[b * fi for fi in f] for b, f in zip(bs, fs)])]
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
            lane = dict(args=lane["args"], y=y, f=f, t=t_prev, tn=t_next, ck=ck, vc=vc, nacc=nacc, nrej=nrej)

            reached = active & (t_prev >= t1) & (ck >= K)
            finite = functools.reduce(jnp.logical_and, [jnp.isfinite(v) for v in f])
            stuck = active & ~reached & (((nacc + nrej) >= max_steps) | ~finite)
            done = reached | stuck
            status = jnp.where(reached, STATUS_OK, STATUS_MAX_STEPS).astype(jnp.int32)
            carry = (lane, idx, nxt, out)
            return lax.cond(jnp.any(done), lambda c: finish_and_refill(c, done, status), lambda c: c, carry)

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


def would_run(system, icfg) -> bool:
    """Whether the fused engine takes this system/config (a primitive without a lane-wise rule
    is only found when compiling; :func:`solve` then raises :class:`Unsupported`)."""
    return (getattr(icfg, "engine", "auto") in ("auto", "native", "fused") and icfg.solver in SUPPORTED_SOLVERS
            and getattr(system, "classify", None) is None)


class _Static:
    """Hashable wrapper of the batch-constant parameters (part of the compile-cache key)."""

    def __init__(self, static: Mapping[str, np.ndarray]):
        self.values = {k: np.asarray(v, np.float64) for k, v in sorted(static.items())}
        self.key = tuple((k, v.shape, v.tobytes()) for k, v in self.values.items())

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, _Static) and self.key == other.key


@functools.lru_cache(maxsize=64)
def _compiled(system, icfg, vcfg, lanes: int, n_dev: int, static: _Static, dyn_shapes: tuple, with_state=False):
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


def split_static(params: Mapping[str, np.ndarray], static: Iterable[str] | None = None):
    """(static values, dynamic arrays). ``static=None``: every parameter equal across the batch."""
    p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
    if static is None:
        static = [k for k, v in p.items() if v.shape[0] > 0 and np.array_equal(v, np.broadcast_to(v[:1], v.shape))]
    # a name claimed static but varying in this batch stays dynamic: correctness over compile reuse
    static = {k for k in static if k in p and np.array_equal(p[k], np.broadcast_to(p[k][:1], p[k].shape))}
    return {k: p[k][0] for k in p if k in static}, {k: v for k, v in p.items() if k not in static}


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
    fn = _compiled(system, icfg, vcfg, lanes, n_dev, _Static(st), shapes, bool(with_state))
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
    across this batch. ``with_state``: also return ``state_t1`` (N, n_state), the state at t1.
    Raises :class:`Unsupported` when the system cannot run lane-wise.
    """
    if icfg.solver not in SUPPORTED_SOLVERS:
        raise Unsupported(f"solver {icfg.solver!r} (fused engine: {', '.join(SUPPORTED_SOLVERS)})")
    if getattr(system, "classify", None) is not None:
        raise Unsupported(f"{system.name} has its own classify()")
    fn, args, order, n = prepare_call(system, icfg, vcfg, params, lanes=lanes, n_devices=n_devices, static=static,
                                      with_state=with_state)
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
    return res


__all__ = ["solve", "would_run", "prepare_call", "default_lanes", "SUPPORTED_SOLVERS", "Unsupported", "fast_log", "LaneFn"]
