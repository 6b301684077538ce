"""Prescribed time functions of the Bezglasnyi-Mysina carrier-rotor models (docs/models/twobody.md, "Setup and state").

Written once for both array libraries (``xp`` is ``numpy`` or ``jax.numpy``), so the traced
right-hand sides and the host-side theory predicates evaluate *the same* programs. Every
function broadcasts elementwise: the caller gives arrays of a common batch/time shape.

Rotor angle program ``delta(t)`` (parameter ``delta_prog``), always with its first two
derivatives, analytic (docs/models/twobody.md, "Numerical notes"):

* ``0`` constant rate plus a sinusoidal modulation:
  ``delta' = Omega_r + dA sin(dnu t)``,
  ``delta  = delta0 + Omega_r t + dA (1 - cos(dnu t)) / dnu``,
  ``delta'' = dA dnu cos(dnu t)``.  ``dA = 0`` is the paper's typical ``delta = Omega_r t``.
* ``1`` spin-up from rest: ``delta' = Omega_r tanh(t / tau)``,
  ``delta = delta0 + Omega_r tau log cosh(t / tau)``, ``delta'' = Omega_r / tau (1 - tanh^2)``.

Angular velocity of the rotating reference frame, given directly as carrier-frame
components (docs/models/twobody.md, "Setup and state"; paper-consistent):
``omega0_i(t) = om0_c_i + om0_a_i sin(om0_f_i t + om0_p_i)``, ``omega0_i' = om0_a_i om0_f_i cos(...)``.
"""
from __future__ import annotations


def _logcosh(xp, x):
    ax = xp.abs(x)
    return ax + xp.log1p(xp.exp(-2.0 * ax)) - xp.log(2.0)


def delta_program(xp, t, prog, delta0, Omega_r, dA, dnu, tau):
    """(delta, delta', delta'') at time(s) ``t`` for the coded program ``prog`` (see module doc)."""
    # program 0; dnu = 0 means no modulation (sin(0 t) = 0), guard the 1/dnu
    nu_safe = xp.where(dnu == 0, 1.0, dnu)
    mod = xp.where(dnu == 0, 0.0, dA * (1.0 - xp.cos(dnu * t)) / nu_safe)
    d0 = delta0 + Omega_r * t + mod
    dd0 = Omega_r + dA * xp.sin(dnu * t)
    ddd0 = dA * dnu * xp.cos(dnu * t)
    # program 1
    tau_safe = xp.where(tau > 0, tau, 1.0)
    th = xp.tanh(t / tau_safe)
    d1 = delta0 + Omega_r * tau_safe * _logcosh(xp, t / tau_safe)
    dd1 = Omega_r * th
    ddd1 = Omega_r / tau_safe * (1.0 - th * th)
    one = prog == 1
    return xp.where(one, d1, d0), xp.where(one, dd1, dd0), xp.where(one, ddd1, ddd0)


def omega0_program(xp, t, c, a, f, ph):
    """(omega0, omega0') in carrier components; ``t`` has shape S, the vectors S + (3,)."""
    arg = f * xp.asarray(t)[..., None] + ph
    return c + a * xp.sin(arg), a * f * xp.cos(arg)


def delta_is_periodic(prog, dA):
    """True where delta'(t) is constant, so every t-uniform König condition needs only delta in [0, 2 pi)."""
    return (prog == 0) & (dA == 0)
