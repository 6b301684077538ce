"""Error bounds for integrated quantities, derived from the solver's tolerances (not one machine's rounding).

diffrax's ``PIDController`` accepts a step when the RMS over the n state components of
``err_i / (atol + rtol * max(|y_i(t_n)|, |y_i(t_n+1)|))`` is <= 1, where ``err`` is the embedded
error estimate. So every accepted step's local error has Euclidean norm
``<= sqrt(n) * (atol + rtol * y_max)`` (y_max: the largest |y_i| along the run), whatever the
rounding of the machine that ran it. Local errors made at different steps are carried to the end
by the linearised flow, whose growth over the horizon is ``kappa = max ||Phi(t, s)||_2``; so the
global error after ``n_steps`` accepted steps is at most ``kappa * (n_steps + 1) * sqrt(n) * tol``
(one more "step" for the dense-output interpolation at save times that fall inside a step, whose
error is of the same order as the step's). A scalar observable with Lipschitz constant L in the state
then has error <= L times that. Machine rounding only changes *which* admissible errors occur (the
size of the first rounding seed, hence the number of steps), never this bound, because n_steps
is the run's own count.
"""
from __future__ import annotations

import math

import numpy as np


def local_tolerance(n_state: int, rtol: float, atol: float, y_max: float) -> float:
    """Largest Euclidean norm of one accepted step's local error under diffrax's RMS error norm."""
    return math.sqrt(n_state) * (atol + rtol * y_max)


def global_error_bound(n_steps: int, n_state: int, rtol: float, atol: float, y_max: float,
                       kappa: float = 1.0) -> float:
    """Bound on the state error after ``n_steps`` accepted steps (see the module docstring)."""
    return kappa * (n_steps + 1) * local_tolerance(n_state, rtol, atol, y_max)


def flow_growth(jac: np.ndarray, t1: float, n: int = 400) -> float:
    """kappa = max over 0 <= t <= t1 of ||exp(A t)||_2 for a constant Jacobian A (an equilibrium).

    For an autonomous linearisation Phi(t, s) = exp(A (t - s)), so this is the worst growth of a
    local error made at any step; sampled on ``n`` points (the norm is smooth in t).
    """
    from scipy.linalg import expm

    return max(np.linalg.norm(expm(jac * t), 2) for t in np.linspace(0.0, t1, n))
