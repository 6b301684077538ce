"""Vectorisable float64 log, sin and cos for the fused engine's lane-wise evaluator.

XLA:CPU calls scalar libm for log, sin, cos and pow (measured 9-25 ns per element against ~2 ns
for its vectorised exp); the lane-wise evaluator (:mod:`stabjax.engines.lanes`) routes float64
log, sin, cos and pow through these branch-free versions instead (log: 2 ulp, sin/cos: 0.5 ulp of
1 in absolute terms; tests/engines/test_fused.py). fdlibm's polynomials, Cody & Waite's reduction.
"""
from __future__ import annotations

import jax.numpy as jnp
from jax import lax

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

def fast_cos_small(x):
    r, q = _reduce(x)
    s, c = _ksin(r), _kcos(r)
    return jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s)))

def fast_sin_small(x):
    r, q = _reduce(x)
    s, c = _ksin(r), _kcos(r)
    return jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c)))


__all__ = ["fast_log", "fast_sin_small", "fast_cos_small", "SINCOS_LIMIT"]
