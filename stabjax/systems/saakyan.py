"""Saakyan: active stabilisation of the rotational motion of a rigid body (five closed loops).

Saakyan (1974), documented in ``docs/models/saakyan.md``. A body axis H0 (unit, constant body
components beta) is brought onto a target direction S0 (body components alpha_i) while the
body spins about it at rate lam:

* ``saakyan_moving``   B-1, S rotates with a programmed omega0(t) (body components), torque
                        (1.3) with mu of (1.11); target (1.5) omega = omega0 + lam H0, H0 = S0.
* ``saakyan_fixed``    B-1, Corollary 2 (omega0 = 0), torque (1.23); ``use_mu = 0`` drops mu
                        (the paper: then unstable).
* ``saakyan_gravity``  B-2, central Newtonian field, nu = 3 g0/R, torque (2.2) with (2.8).
* ``saakyan_gyrostat`` B-3, gyrostat with three flywheels, (3.5), (3.6), (3.8), mu of (3.21).
* ``saakyan_gyrostat_gravity``  B-4, (4.1), (4.5).

All loops are integrated in the **original variables** (omega, [z,] S0); the deviation form
of the paper ((1.7)-(1.8), (2.4), (3.17), (4.2)) is available as :meth:`deviation_rhs`
with the maps :meth:`to_deviation` / :meth:`from_deviation`, and the Lyapunov functions
(1.9), (2.6), (3.18), (4.3) with the paper's derivatives (1.12), (3.20) as
:meth:`lyapunov` / :meth:`lyapunov_rate`.

Symbols (ASCII): ``I = (A, B, C)`` moments (B-3/B-4: the reduced moments A = C1 - J1, ...,
docs/models/saakyan.md, misprint 16), ``H`` = H0 = beta (normalised on input: only its direction
matters), ``lam`` = lambda, ``K = alpha/lam`` (B-1/B-2) or ``h`` (B-3/B-4, alpha = lam h)
-- the potential gain alpha is never a parameter of its own, to keep it apart from the
direction cosines alpha_i (misprint 2). ``N0`` of the paper is H0 (misprint 1).

Initial conditions: ``init = 0`` takes ``S0`` (normalised) and the angular-velocity
deviation ``dw0 = w1(0) = omega(0) - omega0(0) - lam H0`` as given. ``init = 1`` ("shell")
puts the perturbation at prescribed size, for region-of-attraction sweeps: |delta(0)| =
|S0(0) - H0| = ``rho`` along the great circle from H0 towards ``S0`` (a direction), and
w1(0) = ``w_ratio`` lam rho dw0/|dw0|, so ``rho`` is directly comparable with the l of
(1.18) and the 2 of (1.22).

Error metric: angle(S0, H0) + |w1|/lam (rad), zero exactly on the target motion. Size
observable: |w1|/lam. Every steady spin (the target, the inverted one, off-target ones on the
set E of (1.13)) has |w1|/lam = |delta| <= 2, so a body spinning more than ``SPIN_DIVERGE``
(10) lam away from the target spin is running away (e.g. without mu), not "flipped": the
verdict threshold ``diverge_size`` is 10 (not the generic 1e6 on |omega|); consequently a
start with |w1(0)| > 10 lam is diverged from the first checkpoint on. The generic classifier
(:mod:`stabjax.fold.verdict`, noise floor ``floor_tol`` = 1e-6) does the rest, so these systems
run on the fused engine.
Numerical note: torques use S0/|S0| (cf. docs/models/monoaxial.md, "Numerical notes"), so solver drift of |S0| cannot
add a spurious restoring term.

Size (~590 lines): five closed loops of one paper sharing their symbols, parameter sets and deviation
maps; split per loop, each file would import the shared half back.
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..model import linalg as la
from ..model.params import Param, ParamSet, check_positive, require
from ..config import VerdictConfig
from ..model.system import System
from ..model.outcomes import VERDICTS
from . import saakyan_theory as theory

I_DEFAULT = (5.0, 6.0, 4.0)
_h = np.array([0.3, -0.5, 0.8])
H_DEFAULT = tuple((_h / np.linalg.norm(_h)).round(12))
_s = np.array([0.2, 0.9, -0.3])
S0_DEFAULT = tuple((_s / np.linalg.norm(_s)).round(12))
DW0_DEFAULT = (0.3, -0.2, 0.1)


def _unit_or_error(p, name):
    v = np.asarray(p[name], float)
    n = np.linalg.norm(v, axis=-1)
    require(n > 1e-12, name, "must be a nonzero vector (only its direction is used)", v)
    return v / n[..., None]


# ----------------------------------------------------------------------------------------------
# parameters


def _common_params(gain: str):
    if gain == "K":
        g = Param("K", 6.0, "potential gain K = alpha/lam; U = alpha |S0 - H0|^2 ((1.10): K > lam max(I))",
                  (), "N m s")
    else:
        g = Param("h", 6.0, "gyrostat gain h: alpha = lam h and the target z = h H0 ((3.14)); Theorem 3: h > lam max(I)",
                  (), "N m s")
    return (
        Param("I", I_DEFAULT, "principal moments (A, B, C)" + (" of the body" if gain == "K" else
              ": reduced moments A = C1 - J1, B = C2 - J2, C = C3 - J3 (docs/models/saakyan.md, misprint 16)"), (3,), "kg m^2"),
        Param("H", H_DEFAULT, "body axis H0 (beta); normalised on input", (3,)),
        Param("lam", 0.5, "commanded spin rate lambda about H0 (> 0)", (), "rad/s"),
        g,
        Param("use_mu", 1.0, "stabilising torque mu; 1: stabilising torque mu ((1.11)/(2.8)/(3.21)/(4.5)) on; "
              "0: mu dropped", choices=(0.0, 1.0)),
    )


_INITIAL = (
    Param("S0", S0_DEFAULT, "initial body components of the target unit vector S0 (normalised on input); "
          "with init = 1 only its direction away from H0 is used", (3,), kind="initial"),
    Param("dw0", DW0_DEFAULT, "initial w1(0) = omega(0) - omega0(0) - lam H0 (init = 0), or its direction (init = 1)",
          (3,), "rad/s", kind="initial"),
    Param("init", 0.0, "0: as given, S0 and dw0; 1: initial states on a shell "
          "(|delta0| = rho, |w1(0)| = w_ratio lam rho)",
          choices=(0.0, 1.0), kind="initial"),
    Param("rho", 0.5, "init = 1: initial distance of S0 from H0; |delta(0)| = |S0(0) - H0| in [0, 2]", kind="initial"),
    Param("w_ratio", 1.0, "init = 1: |w1(0)| = w_ratio lam rho (1 matches the proportions of (1.18))", kind="initial"),
)

_PROGRAM = (
    Param("w0c", (0.0, 0.1, 0.0), "omega0 program, constant part c: omega0(t) = c + a sin(f t + phi) (body axes)",
          (3,), "rad/s"),
    Param("w0a", (0.2, 0.0, 0.15), "omega0 program amplitudes a (0 for a constant rotation)", (3,), "rad/s"),
    Param("w0f", (0.3, 0.0, 0.2), "omega0 program frequencies f", (3,), "rad/s"),
    Param("w0phi", (0.0, 0.0, math.pi / 2), "omega0 program phases phi; precession about body z at rate f with cone "
          "rate a: a = (a, a, 0), f = (f, f, 0), phi = (pi/2, 0, 0)", (3,), "rad"),
)


# ----------------------------------------------------------------------------------------------
# the B-1 family


class SaakyanBase(System):
    """Common machinery: parameters, checks, initial state, observables, verdict thresholds."""
    outcomes = VERDICTS  # the attitude verdicts are this system's outcomes (stabjax.fold.verdict)

    paper = "L. S. Saakyan, Active stabilisation of the rotational motion of a rigid body, 1974"
    state = (("w", (3,)), ("S", (3,)))
    observables = ("error", "spin_dev", "omega_norm", "angle", "w1_norm", "dist_E")
    observable_doc = (
        "angle(S0, H0) + |w1|/lam [rad]: zero exactly on the target motion",
        "|w1|/lam: spin deviation from the target in units of lam (<= 2 on every steady spin; "
        "above SPIN_DIVERGE = 10: diverged)",
        "|omega| [rad/s]",
        "angle between S0 and H0 [rad]",
        "|w1| = |omega - omega0 - lam H0| [rad/s]",
        "|w1 - lam delta| [rad/s]: distance from the set E of (1.13) where dV/dt = 0",
    )
    SPIN_DIVERGE = 10.0  # |w1|/lam (the size observable) above this: running away, diverged
    # The generic classifier with: size = |w1|/lam and diverge_size = SPIN_DIVERGE (see the module
    # docstring); floor_tol = 1e-6: these loops converge exponentially down to the solver's noise
    # floor (~rtol |omega|/lam), where the late log-log slope is noise of either sign.
    verdict = VerdictConfig(diverge_size=SPIN_DIVERGE, floor_tol=1e-6)
    default_t1 = 200.0
    gain = "K"
    has_program = False
    has_gravity = False
    gyrostat = False

    # -- host side ------------------------------------------------------------------------------
    def check(self, p):
        p = dict(p)
        check_positive(p, "I", value_ndim=1)
        p["H"] = _unit_or_error(p, "H")
        check_positive(p, "lam")
        check_positive(p, self.gain)
        if "nu" in p:
            check_positive(p, "nu", strict=False)
        if "Jw" in p:
            check_positive(p, "Jw", value_ndim=1)
        p["S0"] = _unit_or_error(p, "S0")
        init = np.asarray(p.get("init", 0.0))
        rho = np.asarray(p.get("rho", 0.0))
        require((rho >= 0) & (rho <= 2), "rho", "must lie in [0, 2] (|S0 - H0| <= 2)", rho)
        check_positive(p, "w_ratio", strict=False)
        dwn = np.linalg.norm(np.asarray(p["dw0"], float), axis=-1)
        require((init == 0) | (dwn > 0) | (np.asarray(p["w_ratio"]) == 0), "dw0",
                "must be nonzero with init = 1 (it gives the direction of w1(0))", p["dw0"])
        return p

    # -- traced ---------------------------------------------------------------------------------
    def prepare(self, p):
        a = dict(p)
        H = p["H"]
        a["beta"] = H / la.norm(H)
        a["Pdiag"] = jnp.sum(p["I"]) - p["I"]  # P = (tr Theta) I - Theta
        a["alpha"] = p["lam"] * p[self.gain]
        return a

    def program(self, t, a):
        """omega0(t), d omega0/dt in body axes (zero unless the class has a program)."""
        z = jnp.zeros(3)
        return z, z

    def initial_w1_S(self, a):
        beta, lam = a["beta"], a["lam"]
        S0 = a["S0"] / la.norm(a["S0"])
        u = S0 - la.dot(S0, beta) * beta
        un = la.norm(u)
        # basis vector along the smallest |beta_i| (first one on ties, as argmin), written with
        # comparisons so that the fused engine evaluates it lane-wise (no argmin, no gather)
        ab = jnp.abs(beta)
        i0 = (ab[0] <= ab[1]) & (ab[0] <= ab[2])
        i1 = ~i0 & (ab[1] <= ab[2])
        e = jnp.stack([i0, i1, ~i0 & ~i1]).astype(beta.dtype)
        fb = la.cross(beta, e)
        fb = fb / la.norm(fb)
        u = jnp.where(un > 1e-12, u / jnp.where(un > 1e-12, un, 1.0), fb)
        th = 2 * jnp.arcsin(jnp.clip(a["rho"] / 2, 0.0, 1.0))
        S_shell = jnp.cos(th) * beta + jnp.sin(th) * u
        dn = la.norm(a["dw0"])
        w_shell = a["w_ratio"] * lam * a["rho"] * a["dw0"] / jnp.where(dn > 0, dn, 1.0)
        shell = a["init"] == 1
        return jnp.where(shell, w_shell, a["dw0"]), jnp.where(shell, S_shell, S0)

    def initial_state(self, p):
        a = self.prepare(p)
        w1, S = self.initial_w1_S(a)
        w0, _ = self.program(0.0, a)
        return jnp.concatenate([w1 + w0 + a["lam"] * a["beta"], S])

    def equilibrium(self, p):
        a = self.prepare(p)
        w0, _ = self.program(0.0, a)
        return jnp.concatenate([w0 + a["lam"] * a["beta"], a["beta"]])

    def _split(self, y):
        return y[:3], y[3:6]

    def observe(self, t, y, a):
        w, S = y[:3], y[-3:]
        w0, _ = self.program(t, a)
        beta, lam = a["beta"], a["lam"]
        w1 = w - w0 - lam * beta
        d = S / la.norm(S) - beta
        ang = la.angle_between(S, beta)
        w1n = la.norm(w1)
        return jnp.stack([ang + w1n / lam, w1n / lam, la.norm(w), ang, w1n, la.norm(w1 - lam * d)])

    # -- the closed loop --------------------------------------------------------------------------
    def mu(self, t, w, S, a):
        """(1.11) in vector form [D]: -K w1 + (K - lam P)(H0 x w1) + w1 x Theta omega0."""
        w0, _ = self.program(t, a)
        beta, lam, K, I = a["beta"], a["lam"], a[self.gain], a["I"]
        w1 = w - w0 - lam * beta
        return -K * w1 + (K - lam * a["Pdiag"]) * la.cross(beta, w1) + la.cross(w1, I * w0)

    def torque(self, t, w, S, a):
        """(1.3) (B-1) / (1.23) (omega0 = 0): mu + Theta w0' + w0 x Theta w + lam H0 x Theta w + alpha delta."""
        w0, w0d = self.program(t, a)
        I, beta, lam = a["I"], a["beta"], a["lam"]
        Sh = S / la.norm(S)
        Iw = I * w
        return (a["use_mu"] * self.mu(t, w, Sh, a) + I * w0d + la.cross(w0, Iw) + lam * la.cross(beta, Iw)
                + a["alpha"] * (Sh - beta))

    def rhs(self, t, y, a):
        w, S = y[:3], y[3:]
        w0, _ = self.program(t, a)
        I = a["I"]
        dw = (self.torque(t, w, S, a) - la.cross(w, I * w)) / I
        return jnp.concatenate([dw, la.cross(S, w - w0)])

    # -- deviation form -----------------------------------------------------------------------------
    def to_deviation(self, t, y, a):
        w, S = y[:3], y[3:]
        w0, _ = self.program(t, a)
        return jnp.concatenate([w - w0 - a["lam"] * a["beta"], S - a["beta"]])

    def from_deviation(self, t, x, a):
        w0, _ = self.program(t, a)
        return jnp.concatenate([x[:3] + w0 + a["lam"] * a["beta"], x[3:] + a["beta"]])

    def deviation_rhs(self, t, x, a):
        """(1.7) with mu of (1.11), and (1.8), component by component as printed."""
        p1, q1, r1, d1, d2, d3 = (x[i] for i in range(6))
        A, B, C = a["I"][0], a["I"][1], a["I"][2]
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        lam, K, al = a["lam"], a["K"], a["alpha"]
        (p0, q0, r0), _ = self.program(t, a)
        m = a["use_mu"]
        mu1 = -K * p1 - (K - lam * (B + C)) * (b3 * q1 - b2 * r1) - (B * q0 * r1 - C * r0 * q1)
        mu2 = -K * q1 - (K - lam * (A + C)) * (b1 * r1 - b3 * p1) - (C * r0 * p1 - A * p0 * r1)
        mu3 = -K * r1 - (K - lam * (A + B)) * (b2 * p1 - b1 * q1) - (A * p0 * q1 - B * q0 * p1)
        dp = (lam * (B * b2 * r1 - C * b3 * q1) + B * q0 * r1 - C * r0 * q1 + (B - C) * q1 * r1 + al * d1 + m * mu1) / A
        dq = (lam * (C * b3 * p1 - A * b1 * r1) + C * r0 * p1 - A * p0 * r1 + (C - A) * r1 * p1 + al * d2 + m * mu2) / B
        dr = (lam * (A * b1 * q1 - B * b2 * p1) + A * p0 * q1 - B * q0 * p1 + (A - B) * p1 * q1 + al * d3 + m * mu3) / C
        return jnp.stack([dp, dq, dr, *self._ddelta(x, a)])

    @staticmethod
    def _ddelta(x, a):
        """(1.8) (also (2.5) and the delta part of (3.17))."""
        p1, q1, r1, d1, d2, d3 = (x[i] for i in range(6))
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        lam = a["lam"]
        return (
            b2 * r1 - b3 * q1 + lam * (b3 * d2 - b2 * d3) + d2 * r1 - d3 * q1,
            b3 * p1 - b1 * r1 + lam * (b1 * d3 - b3 * d1) + d3 * p1 - d1 * r1,
            b1 * q1 - b2 * p1 + lam * (b2 * d1 - b1 * d2) + d1 * q1 - d2 * p1,
        )

    # -- Lyapunov ---------------------------------------------------------------------------------------
    def _grav_coeff(self, a):
        """Coefficient added to alpha in front of delta_i^2 in V (nu I_i in (2.6), nu C_i in (4.3))."""
        return jnp.zeros(3)

    def lyapunov(self, t, y, a):
        """(1.9) (and (2.6), (3.18), (4.3) in the subclasses), in original variables."""
        w, S = y[:3], y[-3:]
        w0, _ = self.program(t, a)
        I, beta, lam = a["I"], a["beta"], a["lam"]
        w1 = w - w0 - lam * beta
        d = S - beta
        V2 = la.dot(I * w1, w1) - 2 * lam * la.dot(I * w1, d) + la.dot(a["alpha"] + self._grav_coeff(a), d * d)
        return 0.5 * V2 + self._lyap_extra(y, a)

    def _lyap_extra(self, y, a):
        return 0.0

    def lyapunov_rate(self, t, y, a):
        """The paper's dV/dt along the closed loop: (1.12) -K sum (w1 - lam delta)^2 ((3.20) with K = h)."""
        w, S = y[:3], y[-3:]
        w0, _ = self.program(t, a)
        w1 = w - w0 - a["lam"] * a["beta"]
        e = w1 - a["lam"] * (S - a["beta"])
        return -a[self.gain] * la.dot(e, e)


class SaakyanMoving(SaakyanBase):
    name = "saakyan_moving"
    title = "Saakyan B-1: body axis H0 tracks a vector S moving with programmed omega0(t) (Theorem 1)"
    params = ParamSet(_common_params("K") + _PROGRAM + _INITIAL)
    has_program = True

    def program(self, t, a):
        ph = a["w0f"] * t + a["w0phi"]
        return a["w0c"] + a["w0a"] * jnp.sin(ph), a["w0a"] * a["w0f"] * jnp.cos(ph)

    def theory(self, p):
        return theory.evaluate_moving(p)


class SaakyanFixed(SaakyanBase):
    name = "saakyan_fixed"
    title = "Saakyan B-1, Corollary 2: permanent rotation omega = lam H0 about a fixed direction S"
    params = ParamSet(_common_params("K") + _INITIAL)

    def theory(self, p):
        return theory.evaluate_fixed(p)


# ----------------------------------------------------------------------------------------------
# B-2


class SaakyanGravity(SaakyanBase):
    name = "saakyan_gravity"
    title = "Saakyan B-2: fixed local vertical in a central Newtonian field (Theorem 2, lam^2 = nu)"
    params = ParamSet(_common_params("K") + (
        Param("nu", 0.25, "gravity parameter nu = 3 g0/R; Theorem 2 needs lam^2 = nu", (), "1/s^2"),) + _INITIAL)
    has_gravity = True

    def theory(self, p):
        return theory.evaluate_gravity(p)

    def mu(self, t, w, S, a):
        """(2.8): mu of (1.11) with omega0 = 0 plus nu P (H0 x delta)."""
        d = S - a["beta"]
        return super().mu(t, w, S, a) + a["nu"] * a["Pdiag"] * la.cross(a["beta"], d)

    def torque(self, t, w, S, a):
        """(2.2): mu0 + lam H0 x Theta w - nu H0 x Theta S0 + alpha delta."""
        Sh = S / la.norm(S)
        I, beta = a["I"], a["beta"]
        return (a["use_mu"] * self.mu(t, w, Sh, a) + a["lam"] * la.cross(beta, I * w)
                - a["nu"] * la.cross(beta, I * Sh) + a["alpha"] * (Sh - beta))

    def rhs(self, t, y, a):
        """(2.1): Theta w' + w x Theta w - nu S0 x Theta S0 = M, S0' = S0 x w."""
        w, S = y[:3], y[3:]
        I = a["I"]
        Sh = S / la.norm(S)
        dw = (self.torque(t, w, S, a) - la.cross(w, I * w) + a["nu"] * la.cross(Sh, I * Sh)) / I
        return jnp.concatenate([dw, la.cross(S, w)])

    def deviation_rhs(self, t, x, a):
        """(2.4) with mu0 of (2.8) (components as printed), and (2.5) = (1.8)."""
        p1, q1, r1, d1, d2, d3 = (x[i] for i in range(6))
        A, B, C = a["I"][0], a["I"][1], a["I"][2]
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        lam, K, al, nu, m = a["lam"], a["K"], a["alpha"], a["nu"], a["use_mu"]
        mu1 = -K * p1 - (K - lam * (B + C)) * (b3 * q1 - b2 * r1) - nu * (B + C) * (b3 * d2 - b2 * d3)
        mu2 = -K * q1 - (K - lam * (A + C)) * (b1 * r1 - b3 * p1) - nu * (A + C) * (b1 * d3 - b3 * d1)
        mu3 = -K * r1 - (K - lam * (A + B)) * (b2 * p1 - b1 * q1) - nu * (A + B) * (b2 * d1 - b1 * d2)
        dp = (lam * (B * b2 * r1 - C * b3 * q1) + (B - C) * q1 * r1 + nu * (C - B) * d2 * d3
              + nu * (C * b3 * d2 - B * b2 * d3) + al * d1 + m * mu1) / A
        dq = (lam * (C * b3 * p1 - A * b1 * r1) + (C - A) * r1 * p1 + nu * (A - C) * d3 * d1
              + nu * (A * b1 * d3 - C * b3 * d1) + al * d2 + m * mu2) / B
        dr = (lam * (A * b1 * q1 - B * b2 * p1) + (A - B) * p1 * q1 + nu * (B - A) * d1 * d2
              + nu * (B * b2 * d1 - A * b1 * d2) + al * d3 + m * mu3) / C
        return jnp.stack([dp, dq, dr, *self._ddelta(x, a)])

    def _grav_coeff(self, a):
        return a["nu"] * a["I"]  # (2.6)


# ----------------------------------------------------------------------------------------------
# B-3, B-4: gyrostats


_GYRO = (
    Param("Jw", (0.3, 0.2, 0.4), "axial moments J_i of the three flywheels (gyrostat moments C_i = I_i + J_i)",
          (3,), "kg m^2"),
    Param("torque", 0.0, "control torque; 0: Theorem-3/4 torque, M = mu(3.21) + grad U/2 [R]; "
          "1: as printed, (3.9) combined with (3.21) "
          "(-lam z x H0 counted twice); 2: equivalent form, (3.9) with mu' = mu + lam eta x H0 (same as 0)",
          choices=(0.0, 1.0, 2.0)),
)
_GYRO_INITIAL = (
    Param("eta0", (0.0, 0.0, 0.0), "initial eta = z(0) - h H0 (z: total angular momentum, body axes); 0 = (3.12),(3.14)",
          (3,), "N m s", kind="initial"),
)


class SaakyanGyrostat(SaakyanBase):
    name = "saakyan_gyrostat"
    title = "Saakyan B-3: gyrostat with three flywheels, fixed target direction (Theorem 3)"
    params = ParamSet(_common_params("h") + _GYRO + _INITIAL + _GYRO_INITIAL)
    state = (("w", (3,)), ("z", (3,)), ("S", (3,)))
    observables = SaakyanBase.observables + ("z_norm",)
    observable_doc = SaakyanBase.observable_doc + ("|z|: total angular momentum (first integral (3.7) in B-3)",)
    gain = "h"
    gyrostat = True

    def theory(self, p):
        return theory.evaluate_gyrostat(p)

    def check(self, p):
        p = super().check(p)
        return p

    def prepare(self, p):
        a = super().prepare(p)
        a["Ig"] = p["I"] + p["Jw"]
        a["Pg"] = jnp.sum(a["Ig"]) - a["Ig"]
        return a

    def initial_state(self, p):
        a = self.prepare(p)
        w1, S = self.initial_w1_S(a)
        beta = a["beta"]
        return jnp.concatenate([w1 + a["lam"] * beta, a["h"] * beta + a["eta0"], S])

    def equilibrium(self, p):
        a = self.prepare(p)
        beta = a["beta"]
        return jnp.concatenate([a["lam"] * beta, a["h"] * beta, beta])

    def observe(self, t, y, a):
        return jnp.concatenate([super().observe(t, y, a), la.norm(y[3:6])[None]])

    def mu(self, t, w, z, S, a):
        """(3.21) in vector form [D]: -h w1 + (Theta_A w1 - eta) x omega."""
        beta, h = a["beta"], a["h"]
        w1 = w - a["lam"] * beta
        eta = z - h * beta
        return -h * w1 + la.cross(a["I"] * w1 - eta, w)

    def gravity(self, S, a):
        return jnp.zeros(3)

    def torque(self, t, w, z, S, a):
        """M by variant ``torque`` (see the parameter), plus the B-4 terms in the subclass."""
        beta, lam = a["beta"], a["lam"]
        Sh = S / la.norm(S)
        mu = self.mu(t, w, z, Sh, a)
        zxH = la.cross(z, beta)
        eta = z - a["h"] * beta
        tv = a["torque"]
        extra = jnp.where(tv == 1, -lam * zxH, jnp.where(tv == 2, -lam * zxH + lam * la.cross(eta, beta), 0.0))
        return a["use_mu"] * mu + extra + a["alpha"] * (Sh - beta)

    def rhs(self, t, y, a):
        """(3.5), (3.6), (3.8): Theta_A w' = z x w + M, z' = z x w, S0' = S0 x w."""
        w, z, S = y[:3], y[3:6], y[6:]
        zxw = la.cross(z, w)
        G = self.gravity(S, a)
        dw = (zxw + G + self.torque(t, w, z, S, a)) / a["I"]
        return jnp.concatenate([dw, zxw + self._g_on_z(a) * G, la.cross(S, w)])

    def _g_on_z(self, a):
        return 0.0

    def to_deviation(self, t, y, a):
        beta = a["beta"]
        return jnp.concatenate([y[:3] - a["lam"] * beta, y[6:] - beta, y[3:6] - a["h"] * beta])

    def from_deviation(self, t, x, a):
        beta = a["beta"]
        return jnp.concatenate([x[:3] + a["lam"] * beta, x[6:] + a["h"] * beta, x[3:6] + beta])

    def _mu321(self, x, a):
        p1, q1, r1 = x[0], x[1], x[2]
        e1, e2, e3 = x[6], x[7], x[8]
        A, B, C = a["I"][0], a["I"][1], a["I"][2]
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        lam, h = a["lam"], a["h"]
        return (
            -h * p1 + lam * (B * b3 * q1 - C * b2 * r1) + (B - C) * q1 * r1 - lam * (b3 * e2 - b2 * e3) - (e2 * r1 - e3 * q1),
            -h * q1 + lam * (C * b1 * r1 - A * b3 * p1) + (C - A) * p1 * r1 - lam * (b1 * e3 - b3 * e1) - (e3 * p1 - e1 * r1),
            -h * r1 + lam * (A * b2 * p1 - B * b1 * q1) + (A - B) * p1 * q1 - lam * (b2 * e1 - b1 * e2) - (e1 * q1 - e2 * p1),
        )

    def _eta_dot(self, x, a):
        """The eta equations of (3.17)."""
        p1, q1, r1 = x[0], x[1], x[2]
        e1, e2, e3 = x[6], x[7], x[8]
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        lam, h = a["lam"], a["h"]
        return (
            h * (b2 * r1 - b3 * q1) + lam * (b3 * e2 - b2 * e3) + e2 * r1 - e3 * q1,
            h * (b3 * p1 - b1 * r1) + lam * (b1 * e3 - b3 * e1) + e3 * p1 - e1 * r1,
            h * (b1 * q1 - b2 * p1) + lam * (b2 * e1 - b1 * e2) + e1 * q1 - e2 * p1,
        )

    def _grav_dev(self, x, a):
        return (0.0, 0.0, 0.0)

    def deviation_rhs(self, t, x, a):
        """(3.17) (Theorem-3 torque, ``torque`` = 0) with mu of (3.21); state (w1, delta, eta).

        B-4 adds the nu terms of (4.2) and the (4.5) part of mu0 via :meth:`_grav_dev`.
        """
        A, B, C = a["I"][0], a["I"][1], a["I"][2]
        al, m = a["alpha"], a["use_mu"]
        d = x[3:6]
        edot = self._eta_dot(x, a)
        mu = self._mu321(x, a)
        g = self._grav_dev(x, a)
        dp = (edot[0] + al * d[0] + m * mu[0] + g[0]) / A
        dq = (edot[1] + al * d[1] + m * mu[1] + g[1]) / B
        dr = (edot[2] + al * d[2] + m * mu[2] + g[2]) / C
        return jnp.stack([dp, dq, dr, *self._ddelta(x, a), *edot])

    def _lyap_extra(self, y, a):
        """(3.18)'s 1/2 sum (h delta_i - eta_i)^2 = 1/2 |h S0 - z|^2 (a constant of motion in B-3)."""
        e = a["h"] * y[6:] - y[3:6]
        return 0.5 * la.dot(e, e)


class SaakyanGyrostatGravity(SaakyanGyrostat):
    name = "saakyan_gyrostat_gravity"
    title = "Saakyan B-4: gyrostat in a central Newtonian field (Theorem 4, condition (4.4))"
    params = ParamSet(_common_params("h") + _GYRO + (
        Param("nu", 0.3, "nu = 3 g0/R", (), "1/s^2"),
        Param("gz", 1.0, "1: physical, z' = z x w + G (gravity torque on the total momentum); 0: as printed, (4.2) "
              "omits G in the eta equations (docs/models/saakyan.md, misprint 14)", choices=(0.0, 1.0)),
    ) + _INITIAL + _GYRO_INITIAL)
    has_gravity = True

    def theory(self, p):
        return theory.evaluate_gyrostat_gravity(p)

    def gravity(self, S, a):
        """G = nu S0 x Theta_g S0 (gyrostat moments C_i)."""
        Sh = S / la.norm(S)
        return a["nu"] * la.cross(Sh, a["Ig"] * Sh)

    def _g_on_z(self, a):
        return a["gz"]

    def torque(self, t, w, z, S, a):
        """(4.1): mu0 - nu H0 x Theta_g S0 + alpha delta with mu0 = mu(3.21) + nu P_g (H0 x delta) (4.5)."""
        Sh = S / la.norm(S)
        beta = a["beta"]
        d = Sh - beta
        grav = a["use_mu"] * a["nu"] * a["Pg"] * la.cross(beta, d) - a["nu"] * la.cross(beta, a["Ig"] * Sh)
        return super().torque(t, w, z, S, a) + grav

    def _grav_dev(self, x, a):
        """(4.2)'s nu terms plus the (4.5) part of mu0, as printed."""
        d1, d2, d3 = x[3], x[4], x[5]
        C1, C2, C3 = a["Ig"][0], a["Ig"][1], a["Ig"][2]
        b1, b2, b3 = a["beta"][0], a["beta"][1], a["beta"][2]
        nu, m = a["nu"], a["use_mu"]
        return (
            nu * (C3 - C2) * d2 * d3 + nu * (C3 * b3 * d2 - C2 * b2 * d3) - m * nu * (C2 + C3) * (b3 * d2 - b2 * d3),
            nu * (C1 - C3) * d3 * d1 + nu * (C1 * b1 * d3 - C3 * b3 * d1) - m * nu * (C1 + C3) * (b1 * d3 - b3 * d1),
            nu * (C2 - C1) * d1 * d2 + nu * (C2 * b2 * d1 - C1 * b1 * d2) - m * nu * (C1 + C2) * (b2 * d1 - b1 * d2),
        )

    def _grav_coeff(self, a):
        return a["nu"] * a["Ig"]  # (4.3)

    def lyapunov_rate(self, t, y, a):
        """(4.3)'s dV/dt = -h sum (w1 - lam delta)^2, plus gz z.G [D]: with gravity acting on z the
        constant-norm argument for |h S0 - z| fails (d/dt 1/2 |h S0 - z|^2 = z.G)."""
        G = self.gravity(y[6:], a)
        return super().lyapunov_rate(t, y, a) + a["gz"] * la.dot(y[3:6], G)


SYSTEMS = (SaakyanMoving, SaakyanFixed, SaakyanGravity, SaakyanGyrostat, SaakyanGyrostatGravity)
