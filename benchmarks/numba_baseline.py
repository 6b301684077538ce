"""Compiled per-trajectory CPU baseline of ``stabjax bench``: numba-jitted Dormand-Prince 5(4)
for the monoaxial model.

Part of the benchmark users run (``docs/performance.md``), not of the sweep engines; it needs the
optional ``numba`` (``pip install "stabjax[bench]"``): importing this module without it raises
``ImportError`` and the benchmark skips the contender. One trajectory at a time, one thread
(no ``prange``), so it is comparable with the SciPy loop of the benchmark:

    ys, acc = solve_many(y0s (k, 6), alphas (k,), c, t1, rtol, atol)

``c`` is :func:`benchmarks.bench.paper_constants` (J, D (3 or 3x3), a, mu, b, sigma, omega0, r,
normalize, ...). Returns the final states (k, 6) and the accepted step counts (k,).

Model (``stabjax/systems/monoaxial.py``): with s_hat = s/|s| if normalize else s,

    J w' = -w x Jw - D w - a |s_hat - r|^(mu-1) (s_hat x r) + b cos(omega0 t^alpha) |s_hat x r|^(sigma-1) (s_hat x r)
    s'   = -w x s

Method, the same as diffrax's ``Dopri5`` + ``PIDController`` defaults (and ``stabjax.engines.fused``):
Dormand-Prince tableau with FSAL and diffrax's error weights; error norm RMS of
err / (atol + rtol max(|y0|, |y1|)); I-controller, safety 0.9, factor in [0.2, 10], error
order 5 (exponent -1/5), accepted steps never shrink (factor >= 1), rejected ones shrink by at
least the safety factor; Hairer's initial step (diffrax ``_select_initial_step``); a step
ending within 100 ulp of t1 is clipped to t1. Accepted step counts equal diffrax's Dopri5 on
the same problem (``tests/bench/test_numba_baseline.py``).
Compiled with ``fastmath=False`` (IEEE semantics, no reassociation).
"""
from __future__ import annotations

import math

import numba
import numpy as np

# ---- Dormand-Prince 5(4) tableau (diffrax ``Dopri5``) -----------------------------------------
_C2, _C3, _C4, _C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63, _A64, _A65 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
# error weights b - b_hat with diffrax's embedded 4th-order weights (b_hat: 1951/21600, 0, 22642/50085,
# 451/720, -12231/42400, 649/6300, 1/60; Hairer's DOPRI5 code uses another b_hat, 5179/57600, ...)
_E1 = 35.0 / 384.0 - 1951.0 / 21600.0
_E3 = 500.0 / 1113.0 - 22642.0 / 50085.0
_E4 = 125.0 / 192.0 - 451.0 / 720.0
_E5 = -2187.0 / 6784.0 - -12231.0 / 42400.0
_E6 = 11.0 / 84.0 - 649.0 / 6300.0
_E7 = -1.0 / 60.0

ORDER = 5.0  # diffrax's error order of Dopri5 on an ODE
SAFETY, FACTORMIN, FACTORMAX = 0.9, 0.2, 10.0
MAX_STEPS = 10_000_000  # attempted steps per trajectory

_jit = numba.njit(cache=False, fastmath=False, error_model="numpy")


@_jit
def _rhs(t, y, alpha, P, Dm, out):
    """P = (J0, J1, J2, a, mu, b, sigma, omega0, r0, r1, r2, normalize); Dm the 3x3 damping matrix."""
    w0, w1, w2 = y[0], y[1], y[2]
    s0, s1, s2 = y[3], y[4], y[5]
    J0, J1, J2 = P[0], P[1], P[2]
    r0, r1, r2 = P[8], P[9], P[10]
    if P[11] > 0.0:
        ns = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        h0, h1, h2 = s0 / ns, s1 / ns, s2 / ns
    else:
        h0, h1, h2 = s0, s1, s2
    # s_hat x r
    x0 = h1 * r2 - h2 * r1
    x1 = h2 * r0 - h0 * r2
    x2 = h0 * r1 - h1 * r0
    d0, d1, d2 = h0 - r0, h1 - r1, h2 - r2
    kr = -P[3] * math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) ** (P[4] - 1.0)
    kp = P[5] * math.cos(P[7] * t**alpha) * math.sqrt(x0 * x0 + x1 * x1 + x2 * x2) ** (P[6] - 1.0)
    k = kr + kp
    # J w
    jw0, jw1, jw2 = J0 * w0, J1 * w1, J2 * w2
    m0 = -(w1 * jw2 - w2 * jw1) - (Dm[0, 0] * w0 + Dm[0, 1] * w1 + Dm[0, 2] * w2) + k * x0
    m1 = -(w2 * jw0 - w0 * jw2) - (Dm[1, 0] * w0 + Dm[1, 1] * w1 + Dm[1, 2] * w2) + k * x1
    m2 = -(w0 * jw1 - w1 * jw0) - (Dm[2, 0] * w0 + Dm[2, 1] * w1 + Dm[2, 2] * w2) + k * x2
    out[0] = m0 / J0
    out[1] = m1 / J1
    out[2] = m2 / J2
    out[3] = -(w1 * s2 - w2 * s1)
    out[4] = -(w2 * s0 - w0 * s2)
    out[5] = -(w0 * s1 - w1 * s0)


@_jit
def _initial_step(t0, y0, f0, alpha, P, Dm, rtol, atol, ytmp, f1):
    """diffrax ``_select_initial_step`` (Hairer, Norsett & Wanner II.4)."""
    n = y0.shape[0]
    d0 = 0.0
    d1 = 0.0
    for i in range(n):
        sc = atol + abs(y0[i]) * rtol
        d0 += (y0[i] / sc) ** 2
        d1 += (f0[i] / sc) ** 2
    d0 = math.sqrt(d0 / n)
    d1 = math.sqrt(d1 / n)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * (d0 / d1)
    for i in range(n):
        ytmp[i] = y0[i] + h0 * f0[i]
    _rhs(t0 + h0, ytmp, alpha, P, Dm, f1)
    d2 = 0.0
    for i in range(n):
        sc = atol + abs(y0[i]) * rtol
        d2 += ((f1[i] - f0[i]) / sc) ** 2
    d2 = math.sqrt(d2 / n) / h0
    max_d = max(d1, d2)
    if max_d <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max_d) ** (1.0 / ORDER)
    return min(100.0 * h0, h1)


@_jit
def solve_one(y0, alpha, P, Dm, t0, t1, t1_floor, rtol, atol, max_steps):
    """Integrate one trajectory from t0 to t1. Returns (y(t1), accepted, rejected, status)."""
    n = y0.shape[0]
    y = y0.copy()
    y_new = np.empty(n)
    ytmp = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    k5 = np.empty(n)
    k6 = np.empty(n)
    k7 = np.empty(n)
    _rhs(t0, y, alpha, P, Dm, k1)
    h = _initial_step(t0, y, k1, alpha, P, Dm, rtol, atol, ytmp, k2)
    t = t0
    tn = min(t0 + h, t1)
    if tn > t1_floor:
        tn = t1
    nacc = 0
    nrej = 0
    status = 0
    while t < t1:
        if nacc + nrej >= max_steps:
            status = 1  # diffrax's max_steps_reached
            break
        h = tn - t
        for i in range(n):
            ytmp[i] = y[i] + h * (_A21 * k1[i])
        _rhs(t + _C2 * h, ytmp, alpha, P, Dm, k2)
        for i in range(n):
            ytmp[i] = y[i] + h * (_A31 * k1[i] + _A32 * k2[i])
        _rhs(t + _C3 * h, ytmp, alpha, P, Dm, k3)
        for i in range(n):
            ytmp[i] = y[i] + h * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
        _rhs(t + _C4 * h, ytmp, alpha, P, Dm, k4)
        for i in range(n):
            ytmp[i] = y[i] + h * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
        _rhs(t + _C5 * h, ytmp, alpha, P, Dm, k5)
        for i in range(n):
            ytmp[i] = y[i] + h * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i])
        _rhs(t + h, ytmp, alpha, P, Dm, k6)
        for i in range(n):
            y_new[i] = y[i] + h * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i])
        _rhs(tn, y_new, alpha, P, Dm, k7)  # FSAL: k7 is f at the new point

        # -- error norm (diffrax): RMS of err / (atol + rtol max(|y0|, |y1|)) --
        bad_new = False
        for i in range(n):
            if math.isnan(y_new[i]):
                bad_new = True
        acc = 0.0
        for i in range(n):
            e = h * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
            if math.isnan(e):
                e = math.inf
            y1 = y[i] if bad_new else y_new[i]
            ysc = max(abs(y[i]), abs(y1))
            r = e / (atol + ysc * rtol)
            acc += r * r
        err = math.sqrt(acc / n)
        keep = err < 1.0

        # -- diffrax PIDController defaults as an I-controller --
        if err == 0.0:
            factor = FACTORMAX
        else:
            factor = SAFETY * err ** (-1.0 / ORDER)  # inf/nan error -> 0 -> clipped below
            if math.isnan(factor):
                factor = 0.0
        if keep:
            factor = min(max(factor, 1.0), FACTORMAX)
        else:
            factor = min(max(factor, FACTORMIN), SAFETY)
        dt = h * factor

        if keep:
            t = tn
            for i in range(n):
                y[i] = y_new[i]
                k1[i] = k7[i]
            nacc += 1
        else:
            nrej += 1
        t_prev = min(t, t1)
        t_next = t_prev + dt
        if t_next > t1_floor:  # diffrax rounds a step ending within 100 ulp of t1 to t1
            t_next = t1 if keep else t_prev + 0.5 * (t1 - t_prev)
        tn = t_next
    return y, nacc, nrej, status


def _t1_floor(t1: float) -> float:
    x = float(t1)
    for _ in range(100):
        x = float(np.nextafter(x, -np.inf))
    return x


def pack_constants(c: dict) -> tuple[np.ndarray, np.ndarray]:
    """(P, Dm) for the compiled right-hand side from :func:`benchmarks.bench.paper_constants`."""
    J = np.asarray(c["J"], float).reshape(3)
    r = np.asarray(c["r"], float).reshape(3)
    D = np.asarray(c["D"], float)
    Dm = np.diag(D.reshape(3)) if D.size == 3 else D.reshape(3, 3)
    norm = float(np.asarray(c.get("normalize", 1.0)))
    P = np.array([J[0], J[1], J[2], float(c["a"]), float(c["mu"]), float(c["b"]), float(c["sigma"]),
                  float(c["omega0"]), r[0], r[1], r[2], norm], dtype=np.float64)
    return P, np.ascontiguousarray(Dm, dtype=np.float64)


def solve_many(y0s, alphas, c: dict, t1: float, rtol: float, atol: float, max_steps: int = MAX_STEPS,
               return_stats: bool = False):
    """Integrate each (y0, alpha) in turn (a plain loop, one thread). Returns (ys (k, 6), accepted (k,));
    with ``return_stats`` also (rejected (k,), status (k,): 0 ok, 1 max_steps reached)."""
    y0s = np.ascontiguousarray(np.atleast_2d(np.asarray(y0s, dtype=np.float64)))
    alphas = np.asarray(alphas, dtype=np.float64).reshape(-1)
    if y0s.shape[0] != alphas.shape[0] or y0s.shape[1] != 6:
        raise ValueError(f"y0s must be (k, 6) and alphas (k,); got {y0s.shape} and {alphas.shape}")
    P, Dm = pack_constants(c)
    t1 = float(t1)
    floor = _t1_floor(t1)
    k = y0s.shape[0]
    ys = np.empty((k, 6))
    acc = np.zeros(k, dtype=np.int64)
    rej = np.zeros(k, dtype=np.int64)
    st = np.zeros(k, dtype=np.int64)
    for j in range(k):
        ys[j], acc[j], rej[j], st[j] = solve_one(y0s[j], float(alphas[j]), P, Dm, 0.0, t1, floor,
                                                 float(rtol), float(atol), int(max_steps))
    if return_stats:
        return ys, acc, rej, st
    return ys, acc
