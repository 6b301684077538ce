"""Monoaxial stabilisation under zero-mean nonstationary perturbations.

Aleksandrov & Tikhonov, Vestnik SPbU Math. Mech. Astron. 6(64):2 (2019) 270-280
(documented in ``docs/models/monoaxial.md``).

Closed loop (2), (4) with the example perturbation (14) generalised to order sigma:

    J w' + w x J w = -D w - a |s - r|^(mu-1) (s x r) + b cos(omega0 t^alpha) Q_sigma(s - r)
    s' = -w x s,            Q_sigma(u) = |u x r|^(sigma-1) (u x r)

State ``y = (w, s)``: body angular velocity and the body components of the inertial unit
vector s. Target: the equilibrium (3) ``(w, s) = (0, r)``; the inverted position
``(0, -r)`` is also an equilibrium of (14) (docs/models/monoaxial.md, "Equilibria").

Numerical note (docs/models/monoaxial.md, "Numerical notes"): every torque is evaluated with ``s/|s|``. Without it a
1e-7 drift of |s| adds a linear restoring torque that hides the instability; the parameter
``normalize = 0`` switches the fix off so the artefact can be shown.
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..model import linalg as la
from ..model.params import Param, ParamSet, check_positive, check_spd, check_unit, diag_or_matrix, require
from ..config import VerdictConfig
from ..model.system import System
from ..model.outcomes import VERDICTS
from . import monoaxial_theory

_PHI, _THETA = 0.5, 0.8  # paper's roll and pitch at t = 0 (A.5); yaw does not enter
S0_DEFAULT = (math.sin(_THETA), math.sin(_PHI) * math.cos(_THETA), math.cos(_PHI) * math.cos(_THETA))
R_DEFAULT = tuple([1 / math.sqrt(3)] * 3)


class Monoaxial(System):
    outcomes = VERDICTS  # the attitude verdicts are this system's outcomes (stabjax.fold.verdict)
    name = "monoaxial"
    title = "Monoaxial stabilisation under zero-mean time-varying perturbations"
    paper = "Aleksandrov & Tikhonov (2019), Vestnik SPbU 6(64):2, 270-280; eqs. (2), (4), (7), (14)"
    params = ParamSet(
        (
            Param("J", (5.0, 6.0, 4.0), "principal moments of inertia (A, B, C)", (3,), "kg m^2"),
            Param("D", (2.0, 2.0, 2.0), "damping matrix of M_d = -D w: 3 diagonal entries or 9 (symmetric, positive definite)",
                  (3, 3), "N m s", parse=diag_or_matrix),
            Param("a", 1.0, "restoring gain a in M_r = -a |s-r|^(mu-1) s x r", (), "N m"),
            Param("mu", 1.5, "homogeneity order mu of the restoring torque (mu >= 1; Theorem 1 needs mu > 1)"),
            Param("b", 2.0, "perturbation amplitude b in (14)", (), "N m"),
            Param("sigma", 4.0 / 3.0, "perturbation order sigma: Q(u) = |u x r|^(sigma-1) u x r (sigma >= 1)"),
            Param("alpha", 7.0 / 9.0, "exponent alpha in cos(omega0 t^alpha) (0 < alpha; the paper's family has alpha <= 1)"),
            Param("omega0", 1.0, "frequency omega0 in cos(omega0 t^alpha)", (), "rad/s^alpha"),
            Param("r", R_DEFAULT, "body-fixed target axis r (unit)", (3,)),
            Param("normalize", 1.0, "1: evaluate torques with s/|s| (docs/models/monoaxial.md, numerical notes); 0: raw s, shows the drift artefact",
                  choices=(0.0, 1.0)),
            Param("s0", S0_DEFAULT, "initial body components of s (unit); default = paper's (0.717356, 0.334019, 0.611418)",
                  (3,), kind="initial"),
            Param("w0", (1.0, 1.0, 1.0), "initial angular velocity", (3,), "rad/s", kind="initial"),
        )
    )
    state = (("w", (3,)), ("s", (3,)))
    observables = ("angle", "wnorm")
    observable_doc = ("angle between s and r, atan2(|s x r|, s.r) [rad]", "|w| [rad/s]")
    verdict = VerdictConfig()
    default_t1 = 1.0e4

    # -- host side -------------------------------------------------------------------------
    def check(self, p):
        p = dict(p)
        check_positive(p, "J", value_ndim=1)
        check_spd(p, "D")
        check_positive(p, "a")
        require(p["mu"] >= 1, "mu", "must be >= 1 (restoring order; docs/models/monoaxial.md)", p["mu"])
        require(p["sigma"] >= 1, "sigma", "must be >= 1 (Q must be C^1; docs/models/monoaxial.md)", p["sigma"])
        require(p["alpha"] > 0, "alpha", "must be > 0", p["alpha"])
        p["r"] = check_unit(p, "r")
        p["s0"] = check_unit(p, "s0")
        return p

    def theory(self, p):
        return monoaxial_theory.evaluate(p)

    # -- traced ----------------------------------------------------------------------------
    def prepare(self, p):
        args = dict(p)
        args["Jinv"] = 1.0 / p["J"]
        return args

    def initial_state(self, p):
        return jnp.concatenate([p["w0"], p["s0"]])

    def equilibrium(self, p):
        return jnp.concatenate([jnp.zeros(3), p["r"]])

    def torque(self, t, w, s, a):
        """Control (M_d + M_r) plus perturbation (14), with s normalised if requested."""
        ns = la.norm(s)
        sh = jnp.where(a["normalize"] > 0, s / ns, s)
        r = a["r"]
        sxr = la.cross(sh, r)  # = (s - r) x r
        restoring = -a["a"] * la.norm(sh - r) ** (a["mu"] - 1.0) * sxr
        q = la.norm(sxr) ** (a["sigma"] - 1.0) * sxr
        phi = a["b"] * jnp.cos(a["omega0"] * t ** a["alpha"])
        return -a["D"] @ w + restoring + phi * q

    def rhs(self, t, y, a):
        w, s = y[:3], y[3:]
        Jw = a["J"] * w
        dw = a["Jinv"] * (-la.cross(w, Jw) + self.torque(t, w, s, a))
        ds = -la.cross(w, s)
        return jnp.concatenate([dw, ds])

    def observe(self, t, y, a):
        return jnp.stack([la.angle_between(y[3:], a["r"]), la.norm(y[:3])])

    # -- diagnostics -------------------------------------------------------------------------
    def energy(self, y, a):
        """E = 1/2 w'Jw + a/(mu+1) |s-r|^(mu+1); dE/dt = -w'Dw + w' Phi Q (docs/models/monoaxial.md, "Equations of motion")."""
        w, s = y[:3], y[3:]
        sh = s / la.norm(s)
        return 0.5 * la.dot(w, a["J"] * w) + a["a"] / (a["mu"] + 1.0) * la.norm(sh - a["r"]) ** (a["mu"] + 1.0)

    def window_starts(self, p, t1: float) -> np.ndarray:
        """Starts t_k = ((2k - 1/2) pi / omega0)^(1/alpha) of the windows where cos(omega0 t^alpha) > 0 (docs/models/monoaxial.md, "Findings")."""
        alpha, w0 = float(p["alpha"]), float(p["omega0"])
        k = np.arange(1, 10_000)
        tk = ((2 * k - 0.5) * np.pi / abs(w0)) ** (1 / alpha)
        return tk[tk <= t1]
