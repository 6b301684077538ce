"""Tsitouras 5(4) as diffrax runs it: tableau, dense output, step-size controller constants.

The native and fused engines take the same method, error norm and controller as
``diffrax.Tsit5`` with ``diffrax.PIDController`` defaults (an I-controller: safety 0.9, factor
in [0.2, 10], accepted steps never shrink, rejected ones shrink by at least 0.9), Hairer's
initial step, and diffrax's clipping of the last step to ``t1``; the float64 values below are
diffrax's.
"""
from __future__ import annotations

import numpy as np

SOLVER = "tsit5"

C = (0.161, 0.327, 0.9, 0.9800255409045097, 1.0, 1.0)  # nodes of stages 2..7
A = (
    (0.161,),
    (-0.008480655492356989, 0.335480655492357),
    (2.8971530571054935, -6.359448489975075, 4.3622954328695815),
    (5.325864828439257, -11.748883564062828, 7.4955393428898365, -0.09249506636175525),
    (5.86145544294642, -12.92096931784711, 8.159367898576159, -0.071584973281401, -0.028269050394068383),
    (0.09646076681806523, 0.01, 0.4798896504144996, 1.379008574103742, -3.290069515436081, 2.324710524099774),
)
E = (0.0017800110522257773, 0.0008164344596567463, -0.007880878010261994, 0.1447110071732629,
     -0.5823571654525552, 0.45808210592918686, -0.015151515151515152)  # error weights (5th - 4th order)
ORDER = 5  # diffrax's error order for Tsit5 on an ODE
SAFETY, FACTORMIN, FACTORMAX = 0.9, 0.2, 10.0
# Step-size collapse: a proposed step below MIN_STEP_REL * |t| (5 to 10 ulp of t) cannot make
# progress (t + h rounds to within a few ulp of t), so the trajectory stops as failed (status 1)
# instead of rejecting steps until max_steps (SciPy's solve_ivp uses 10 ulp). Happens at a
# finite-time blow-up; diffrax itself has no such test (see the diffrax engine's dtmin). The test is
# ``<=``: at t = 0 a step that underflowed to 0 (a derivative so large that every step is rejected,
# e.g. a parameter of 1e308) would otherwise loop for ever, uncounted by max_steps.
MIN_STEP_REL = 10 * 2.0 ** -52


def interp_weights(th):
    """Tsit5 dense-output weights b_i(theta) (diffrax ``_Tsit5Interpolation``); works on floats and arrays."""
    th2 = th * th
    b1 = -1.0530884977290216 * th * (th - 1.3299890189751412) * (th2 - 1.4364028541716351 * th + 0.7139816917074209)
    b2 = 0.1017 * th2 * (th2 - 2.1966568338249754 * th + 1.2949852507374631)
    b3 = 2.490627285651252793 * th2 * (th2 - 2.38535645472061657 * th + 1.57803468208092486)
    b4 = -16.54810288924490272 * (th - 1.21712927295533244) * (th - 0.61620406037800089) * th2
    b5 = 47.37952196281928122 * (th - 1.203071208372362603) * (th - 0.658047292653547382) * th2
    b6 = -34.87065786149660974 * (th - 1.2) * (th - 0.666666666666666667) * th2
    b7 = 2.5 * (th - 1) * (th - 0.6) * th2
    return (b1, b2, b3, b4, b5, b6, b7)


def t1_clip_floor(t1: float) -> float:
    """diffrax rounds a step ending within 100 ulp of t1 to t1: the largest time not so rounded."""
    x = float(t1)
    for _ in range(100):
        x = float(np.nextafter(x, -np.inf))
    return x
