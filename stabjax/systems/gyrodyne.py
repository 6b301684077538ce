"""Rigid body with a tetrahedral cluster of single-gimbal control moment gyroscopes (gyrodynes).

Khoroshilov (1983), documented in ``docs/models/gyrodyne.md``: forced oscillations
under the gimbal law

    H_i nu_i' = k_i phi + K_i phi' + k_i' theta + K_i' theta' + k_i'' psi + K_i'' psi' + A_i sin Omega_i t

and the stability of the forced oscillation (2.2) near the resonance 2 omega_01 ~ Omega_2.

Models (numeric option ``model``):

* 0 -- normal coordinates (1.3) in a generic form: coefficients from the physical
  parameters by the paper mapping or the consistent projection (``mapping``), or given
  directly (``source = 1``; defaults = the regression case).
* 1 -- the two-channel quasi-linear model (theta, phi; psi = 0): (1.2)'s second and third
  lines with the only second-order term that survives psi = 0, -d theta' phi.
  It equals model 0 with the consistent mapping exactly (tested).
* 2 -- full three-axis nonlinear dynamics: the exact single-gimbal CMG equations of which
  (1.1) is the truncation (gimbal inertia and rotor transverse inertia neglected, as in the paper)

      I w' + w x (I w + h) + sum_i H_i nu_i' (g_i x s_i) = 0,   h = sum_i H_i s_i,
      s_i = cos nu_i u_i + sin nu_i w_i   (rotor axis; s_i' = nu_i' g_i x s_i),

  with (psi, theta, phi) body 1-2-3 Euler angles (psi about x, theta about y, phi about z),
  exact kinematics. (1.1) keeps only the cos nu_i parts of s_i and g_i x s_i; the signs
  follow the geometric reading (gyrodyne.md, misprint 3: the printed +r sin lambda_i of the
  y equation and the missing q sin lambda_i term of the z equation are misprints). The
  linearisation is (1.2) (tested). The 1-2-3 kinematics give r ~ phi' + psi' theta where the
  second-order terms of (1.2) use r ~ phi' - psi' theta; the difference only enters through psi, which the two-channel
  analysis sets to zero.

Geometry: gimbal axes point to the vertices of a regular tetrahedron (TET0, turned by
``tet_yaw`` about z); lambda_i, delta_i follow (see :mod:`.gyrodyne_theory`). Any three gyros
work, the fourth (``spare``, paper: gyro 4) is a cold spare: rotor at rest, gimbal idle.
Gains are allocated per active set from desired stiffness/damping matrices (``Kp``, ``Kd``):
k = W^-1 Kp, K = W^-1 Kd, W = [w_i] over the active gyros.

Failure model (``fail``, ``t_fail``): at t_fail gyro ``fail`` loses its rotor momentum and its
gimbal freezes (it drops out of h and of the control), the spare is switched in at the
failed gyro's slot with its rotor at nominal momentum H_spare and gimbal at its rest angle 0,
and the gains are re-allocated for the new set. The switch is instantaneous and the
angular momentum exchanged by despinning/spinning up the rotors is assumed dumped
externally (no attitude kick): only the cluster geometry (d, d', forcing directions, gains)
changes. The scanning harmonic of the failed slot passes to the spare. Its frequency is not
re-tuned: with ``tune = 1``, Omega_2 = 2 (omega_01 - eps) of the nominal set.

Stability of (2.2) is measured as in the documented regression case: two copies of the system are integrated,
a reference started on (2.2) (plus optional free amplitudes ``E0``) and a copy started
``delta`` off in both free modes; the observables are the free-mode amplitudes E1, E2 of their
difference (normal coordinates of the current set), and :meth:`Gyrodyne.classify` fits their
exponential growth rate over the late window.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..model.params import Param, ParamSet, check_positive, require
from ..config import VerdictConfig
from ..model.system import System
from ..model.outcomes import VERDICTS
from ..errors import ValidationError
from . import gyrodyne_theory as th
from ..fold import verdict as V

CONVERGED, FLIPPED, DIVERGED, UNDECIDED, FAILED = 0, 1, 2, 3, 4

# default: a small agile spacecraft with mini-CMGs, see stabjax/reproduce/gyrodyne.py for the reasoning
KP_DEFAULT = (8.0, 0.0, 0.0, 0.0, 6.0, 1.5, 0.0, 1.5, 4.0)
KD_DEFAULT = (0.5, 0.0, 0.0, 0.0, 0.03, 0.005, 0.0, 0.005, 0.03)

_NC_KEYS = ("w1sq", "w2sq", "xi1", "xi2", "b1", "b2", "q21", "q22", "q11", "q12", "c1", "c2", "Om", "fa", "fb")
_QL_KEYS = ("Iy", "Iz", "ap", "bp", "bpp", "app", "N2", "N1", "N0u", "N0", "d", "dp", "fy", "fz")


def _mat(arr):
    arr = np.asarray(arr, dtype=float)
    return arr.reshape(3, 3) if arr.size == 9 else (np.diag(arr.reshape(3)) if arr.size == 3 else arr)


class Gyrodyne(System):
    outcomes = VERDICTS  # the attitude verdicts are this system's outcomes (stabjax.fold.verdict)
    name = "gyrodyne"
    title = "Tetrahedral CMG cluster: forced oscillations and resonance 2 omega_01 ~ Omega_2"
    paper = "Khoroshilov (1983); eqs. (1.1)-(1.3), (2.1), (2.2), (3.1), (3.3)"
    params = ParamSet(
        (
            Param("model", 1.0, "model of the dynamics; 0: normal coordinates (1.3); 1: two-channel quasi-linear (1.2); "
                  "2: full nonlinear 3-axis",
                  choices=(0.0, 1.0, 2.0)),
            Param("mapping", 1.0, "model 0 and theory, physical source: 0: paper mapping; 1: consistent projection "
                  "(docs/models/gyrodyne.md, misprint 8)",
                  choices=(0.0, 1.0)),
            Param("source", 0.0, "model 0 and theory: 0 coefficients from physical parameters, 1 given directly (nc_*)",
                  choices=(0.0, 1.0)),
            Param("I", (60.0, 50.0, 40.0), "principal moments (I_x, I_y, I_z)", (3,), "kg m^2"),
            Param("H", (8.0, 8.0, 8.0, 8.0), "signed rotor momenta of gyros 1..4 along u_i", (4,), "N m s"),
            Param("tet_yaw", 0.3, "turn of the tetrahedron about body z (0: cube-inscribed, |d| = |d'|)", (), "rad"),
            Param("Kp", KP_DEFAULT, "desired stiffness matrix [axis, angle], angles (psi, theta, phi): 3 diagonal or 9 entries; "
                  "(1.2): a' = Kp[1,2], b' = Kp[1,1], b'' = Kp[2,1] (= a' required), a'' = Kp[2,2]", (3, 3), "N m/rad",
                  parse=_mat),
            Param("Kd", KD_DEFAULT, "desired rate-gain matrix (the K gains; N_2 = -Kd[1,1], N_1 = -Kd[1,2], N^0 = -Kd[2,1], "
                  "N_0 = -Kd[2,2])", (3, 3), "N m s/rad", parse=_mat),
            Param("gain", 1.0, "damping-gain multiplier on Kd (and nc_q): the 'damping gain' axis of the tongue maps"),
            Param("A", (0.0, 1.0, 0.0), "scanning amplitudes of slots 1, 2, 3; entry j - 1 is A_j of slot j "
                  "(slot 2 drives the resonance)", (3,), "N m"),
            Param("Omega", (1.0, 2.0, 0.7), "scanning frequencies Omega_1..3 (Omega_2 replaced when tune = 1)", (3,), "rad/s"),
            Param("tune", 1.0, "1: Omega_2 = 2 (omega_01 - eps) of the nominal set; 0: Omega_2 = Omega[1]", choices=(0.0, 1.0)),
            Param("eps", 0.0, "detuning from resonance; eps = omega_01 - Omega_2/2, used when tune = 1", (), "rad/s"),
            Param("spare", 4.0, "the cold spare gyro; the other three are active, in slots by index "
                  "(1: active set 2-3-4; 2: active set 1-3-4; 3: active set 1-2-4; 4: active set 1-2-3)",
                  choices=(1.0, 2.0, 3.0, 4.0)),
            Param("fail", 0.0, "failing gyro; it fails at t_fail (it must be active) and the spare takes its slot "
                  "(0: no failure; 1: gyro 1 fails; 2: gyro 2 fails; 3: gyro 3 fails; 4: gyro 4 fails)",
                  choices=(0.0, 1.0, 2.0, 3.0, 4.0)),
            Param("t_fail", 0.0, "failure time", (), "s"),
            Param("nc_w", (1.0, 1.6), "source = 1: (omega_1, omega_2) of (1.3)", (2,), "rad/s"),
            Param("nc_xi", (0.3, 0.25), "source = 1: (xi_1, xi_2)", (2,), "rad/s"),
            Param("nc_beta", (0.8, -1.3), "source = 1: (beta_1, beta_2)", (2,)),
            Param("nc_q", (-0.0002, -0.001, -0.0008, 0.0003), "source = 1: (q21, q22, q11, q12), scaled by gain", (4,), "1/s"),
            Param("nc_c", (0.05, 0.0), "source = 1: (c1, c2) of the quadratic term", (2,), "1/rad/s"),
            Param("nc_f2", (2.0, 1.2), "source = 1: (a_0, b_0') at Omega_2", (2,), "rad/s^2"),
            Param("nc_f3", (0.0, 0.0), "source = 1: (a^1, b_0'') at Omega_3", (2,), "rad/s^2"),
            Param("E0", (0.0, 0.0), "initial free amplitudes (E1, E2) of the reference copy (phases 0)", (2,), "rad",
                  kind="initial"),
            Param("delta", 1e-4, "offset of the perturbed copy in both free modes", (), "rad", kind="initial"),
        )
    )
    state = (("ang", (3,)), ("rate", (3,)), ("nu", (4,)), ("ang_p", (3,)), ("rate_p", (3,)), ("nu_p", (4,)))
    observables = ("E1", "size", "E2", "E1_ref", "theta", "phi")
    observable_doc = (
        "free mode-1 amplitude of (perturbed - reference) [rad]",
        "|(psi, theta, phi)| of the perturbed copy [rad]",
        "free mode-2 amplitude of (perturbed - reference) [rad]",
        "free mode-1 amplitude of the reference relative to (2.2) [rad]",
        "theta of the reference [rad]",
        "phi of the reference [rad]",
    )
    # growth_tol: |growth rate| [1/s] below which the verdict is undecided; diverge_size [rad]
    verdict = VerdictConfig(growth_tol=2e-5, late_fraction=0.6, diverge_size=1.0)
    default_t1 = 6000.0

    # -- host side ------------------------------------------------------------------------
    def check(self, p):
        p = dict(p)
        check_positive(p, "I", value_ndim=1)
        Ix, Iy, Iz = (np.asarray(p["I"])[..., k] for k in range(3))
        require((Ix <= Iy + Iz) & (Iy <= Ix + Iz) & (Iz <= Ix + Iy), "I", "must satisfy the triangle inequality", p["I"])
        require(np.asarray(p["Omega"]) > 0, "Omega", "must be positive", p["Omega"])
        require(np.asarray(p["gain"]) >= 0, "gain", "must be >= 0", p["gain"])
        require(np.asarray(p["t_fail"]) >= 0, "t_fail", "must be >= 0", p["t_fail"])
        require(np.asarray(p["delta"]) > 0, "delta", "must be positive", p["delta"])
        sp, f = np.asarray(p["spare"]), np.asarray(p["fail"])
        require(f != sp, "fail", "the failing gyro must be active, not the spare", f)
        direct = np.asarray(p["source"]) > 0.5
        phys = ~direct | (np.asarray(p["model"]) > 0.5)
        if phys.any():
            Kp = np.asarray(p["Kp"])
            scale = np.maximum(np.abs(Kp).max(axis=(-1, -2)), 1e-300)
            require(~phys | (np.abs(Kp[..., 2, 1] - Kp[..., 1, 2]) <= 1e-9 * scale), "Kp",
                    "needs Kp[2,1] = Kp[1,2] (b'' = a', symmetric theta-phi stiffness, docs/models/gyrodyne.md misprint 5) for the normal coordinates", Kp)
            require(~phys | (np.abs(Kp[..., 1, 2]) > 1e-12 * scale), "Kp",
                    "needs a' = Kp[1,2] != 0 (the beta equation divides by it, D.4)", Kp)
            H = np.asarray(p["H"])
            for stage in ("pre", "post"):
                idx = th.slots(p, stage)
                Ha = np.take_along_axis(np.broadcast_to(H, idx.shape[:-1] + (4,)), idx, axis=-1)
                require(~phys | np.all(Ha != 0, axis=-1), "H", f"active gyros ({stage} failover) need H_i != 0", H)
            try:
                pre, post, _ = th.normal_coefficients(p, np)
            except np.linalg.LinAlgError:
                raise ValidationError("tet_yaw", "the active gimbal torque axes do not span space") from None
        else:
            pre, post, _ = th.normal_coefficients(p, np)
        for nm, nc in (("pre", pre), ("post", post)):
            require((nc["w1sq"] > 0) & (nc["w2sq"] > 0), "Kp" if phys.any() else "nc_w",
                    f"d_k > 0 needed (real omega_1, omega_2; {nm} failover)", nc["w1sq"])
            require(np.abs(nc["xi1"] * nc["xi2"]) > 0, "H" if phys.any() else "nc_xi",
                    f"xi_1 xi_2 != 0 needed (d' != 0, beta_1 != beta_2; {nm} failover)", nc["xi1"])
            md = th.modes(nc)
            s = nc["w1sq"] + nc["w2sq"] + nc["xi1"] * nc["xi2"]
            require(0.25 * s * s - nc["w1sq"] * nc["w2sq"] > 0, "nc_xi", "natural frequencies must be real and distinct", s)
            gap = np.minimum(np.abs(nc["Om"] - md["w01"][..., None]), np.abs(nc["Om"] - md["w02"][..., None]))
            forced = (np.abs(nc["fa"]) + np.abs(nc["fb"])) > 0
            require(np.all(~forced | (gap > 1e-6 * md["w01"][..., None]), axis=-1), "Omega",
                    f"a forcing frequency equals a natural frequency ({nm}): (2.2) has infinite amplitude", nc["Om"])
        return p

    def theory(self, p):
        return th.evaluate(p)

    # -- traced ----------------------------------------------------------------------------
    def prepare(self, p):
        pre, post, Om2 = th.normal_coefficients(p, jnp)
        a = dict(p)
        a["Om2"] = Om2
        a["nc_pre"] = {k: pre[k] for k in _NC_KEYS}
        a["nc_post"] = {k: post[k] for k in _NC_KEYS}
        a["md_pre"] = th.modes(pre, jnp)
        a["md_post"] = th.modes(post, jnp)
        geo = th.geometry(p["tet_yaw"], jnp)
        a["g"], a["u"], a["w"] = geo["g"], geo["u"], geo["w"]
        Om = jnp.stack([p["Omega"][0], Om2, p["Omega"][2]])
        for stage in ("pre", "post"):
            ql = th.quasi_linear(p, stage, jnp)
            a["ql_" + stage] = {k: ql[k] for k in _QL_KEYS}
            al = th.allocation(p, stage, jnp)
            idx = al["idx"]
            z43 = jnp.zeros((4, 3))
            a["gyro_" + stage] = dict(
                Gk=z43.at[idx].set(al["Gk"]), GK=z43.at[idx].set(al["GK"]),
                H=jnp.zeros(4).at[idx].set(al["H"]), A=jnp.zeros(4).at[idx].set(p["A"]),
                Om=jnp.ones(4).at[idx].set(Om), on=jnp.zeros(4).at[idx].set(1.0),
            )
        a["Om_slots"] = Om
        return a

    @staticmethod
    def _stage(t, a, key):
        post = t >= a["t_fail"]
        return jax.tree_util.tree_map(lambda x, y: jnp.where(post, y, x), a[key + "_pre"], a[key + "_post"])

    def _accel_normal(self, t, x, v, a):
        nc = self._stage(t, a, "nc")
        y2, v2, y1, v1 = th.to_normal(x[1], x[2], v[1], v[2], nc)
        acc2, acc1 = th.normal_accel(t, y2, v2, y1, v1, nc, jnp)
        return acc1 + acc2, nc["b1"] * acc1 + nc["b2"] * acc2

    def _accel_quasi(self, t, x, v, a):
        ql = self._stage(t, a, "ql")
        th_, ph, thd, phd = x[1], x[2], v[1], v[2]
        sn = jnp.sin(a["Om_slots"] * t)
        thdd = (jnp.sum(ql["fy"] * sn) - ql["bp"] * th_ - ql["ap"] * ph + ql["dp"] * phd + ql["N2"] * thd
                + ql["N1"] * phd) / ql["Iy"]
        phdd = (jnp.sum(ql["fz"] * sn) - ql["bpp"] * th_ - ql["app"] * ph - ql["dp"] * thd + ql["N0u"] * thd
                + ql["N0"] * phd - ql["d"] * thd * ph) / ql["Iz"]
        return thdd, phdd

    @staticmethod
    def euler_rates(ang, w):
        """Body 1-2-3 angles (psi about x, theta about y, phi about z): (psi', theta', phi') from w."""
        _, thv, ph = ang[0], ang[1], ang[2]
        cph, sph = jnp.cos(ph), jnp.sin(ph)
        psid = (w[0] * cph - w[1] * sph) / jnp.cos(thv)
        return jnp.stack([psid, w[0] * sph + w[1] * cph, w[2] - psid * jnp.sin(thv)])

    @staticmethod
    def body_rates(ang, angd):
        """Inverse of :meth:`euler_rates`."""
        thv, ph = ang[1], ang[2]
        cth, sth, cph, sph = jnp.cos(thv), jnp.sin(thv), jnp.cos(ph), jnp.sin(ph)
        return jnp.stack([angd[0] * cth * cph + angd[1] * sph, -angd[0] * cth * sph + angd[1] * cph,
                          angd[0] * sth + angd[2]])

    def _full(self, t, x, v, nu, a):
        gy = self._stage(t, a, "gyro")
        angd = self.euler_rates(x, v)
        ctrl = gy["Gk"] @ x + gy["GK"] @ angd + gy["A"] * jnp.sin(gy["Om"] * t)  # H_i nu_i' (active gyros)
        ctrl = gy["on"] * ctrl
        cn, sn = jnp.cos(nu), jnp.sin(nu)
        s = cn[:, None] * a["u"] + sn[:, None] * a["w"]
        gxs = cn[:, None] * a["w"] - sn[:, None] * a["u"]
        h = jnp.sum(gy["H"][:, None] * s, axis=0)
        tau = jnp.sum(ctrl[:, None] * gxs, axis=0)
        I = a["I"]
        L = I * v + h
        wd = (-jnp.stack([v[1] * L[2] - v[2] * L[1], v[2] * L[0] - v[0] * L[2], v[0] * L[1] - v[1] * L[0]]) - tau) / I
        nud = jnp.where(gy["on"] > 0, ctrl / jnp.where(gy["H"] != 0, gy["H"], 1.0), 0.0)
        return angd, wd, nud

    def _rhs_one(self, t, s, a):
        x, v, nu = s[0:3], s[3:6], s[6:10]
        t0d, p0d = self._accel_normal(t, x, v, a)
        t1d, p1d = self._accel_quasi(t, x, v, a)
        angd2, wd2, nud2 = self._full(t, x, v, nu, a)
        m = a["model"]
        thdd = jnp.where(m < 0.5, t0d, t1d)
        phdd = jnp.where(m < 0.5, p0d, p1d)
        z = jnp.zeros(())
        lin = jnp.concatenate([jnp.stack([z, v[1], v[2], z, thdd, phdd]), jnp.zeros(4)])
        full = jnp.concatenate([angd2, wd2, nud2])
        return jnp.where(m > 1.5, full, lin)

    def rhs(self, t, y, a):
        return jnp.concatenate([self._rhs_one(t, y[:10], a), self._rhs_one(t, y[10:], a)])

    def _copy_state(self, y2, v2, y1, v1, a):
        nc = a["nc_pre"]
        thv, ph = y1 + y2, nc["b1"] * y1 + nc["b2"] * y2
        thd, phd = v1 + v2, nc["b1"] * v1 + nc["b2"] * v2
        ang = jnp.stack([jnp.zeros(()), thv, ph])
        angd = jnp.stack([jnp.zeros(()), thd, phd])
        rate = jnp.where(a["model"] > 1.5, self.body_rates(ang, angd), angd)
        return jnp.concatenate([ang, rate, jnp.zeros(4)])

    def initial_state(self, p):
        a = self.prepare(p)
        md = a["md_pre"]
        f = th.forced_solution(0.0, a["nc_pre"], jnp)
        e = th.free_solution(p["E0"][0], 0.0, p["E0"][1], 0.0, md, jnp)
        dl = th.free_solution(p["delta"], 0.0, p["delta"], 0.0, md, jnp)
        ref = [fi + ei for fi, ei in zip(f, e)]
        pert = [ri + di for ri, di in zip(ref, dl)]
        return jnp.concatenate([self._copy_state(*ref, a), self._copy_state(*pert, a)])

    def equilibrium(self, p):
        """The target motion (2.2) at t = 0 for both copies (it is periodic, not an equilibrium)."""
        a = self.prepare(p)
        s = self._copy_state(*th.forced_solution(0.0, a["nc_pre"], jnp), a)
        return jnp.concatenate([s, s])

    def _angles_rates(self, s, a):
        x, v = s[0:3], s[3:6]
        angd = jnp.where(a["model"] > 1.5, self.euler_rates(x, v), v)
        return x, angd

    def observe(self, t, y, a):
        xr, dr = self._angles_rates(y[:10], a)
        xp_, dp_ = self._angles_rates(y[10:], a)
        nc = self._stage(t, a, "nc")
        md = self._stage(t, a, "md")
        d = th.to_normal(xp_[1] - xr[1], xp_[2] - xr[2], dp_[1] - dr[1], dp_[2] - dr[2], nc)
        E1, _, E2, _ = th.mode_amplitudes(*d, md, jnp)
        f = th.forced_solution(t, nc, jnp)
        r = th.to_normal(xr[1], xr[2], dr[1], dr[2], nc)
        E1r, _, _, _ = th.mode_amplitudes(*[ri - fi for ri, fi in zip(r, f)], md, jnp)
        size = jnp.sqrt(jnp.sum(xp_ * xp_))
        return jnp.stack([E1, size, E2, E1r, xr[1], xr[2]])

    # -- verdict ------------------------------------------------------------------------------
    def classify(self, ts, obs, solver_ok, cfg, t0=0.0):
        """Verdict from the exponential growth rate of E1 (difference of the two copies).

        growth1, growth2: least-squares slopes of log E1, log E2 against t over the late window
        t >= t0 + (1 - late_fraction)(t1 - t0) [1/s]. CONVERGED: growth1 < -growth_tol;
        DIVERGED: growth1 > growth_tol or the perturbed copy's angles exceed diverge_size;
        UNDECIDED: |growth1| <= growth_tol (neutral within resolution); FAILED: solver/NaN (or
        too few late points for growth1). The failed/size precedence is the generic one
        (:func:`stabjax.fold.verdict.resolve`): angles above diverge_size at a finite checkpoint make
        the run DIVERGED even if the solver failed or the state went non-finite later (the full
        model's attitude runaways, whose spun-up gimbals exhaust max_steps); ``size_max`` is the
        largest finite size.
        """
        t1 = ts[-1]
        late = ts >= t0 + (1.0 - cfg.late_fraction) * (t1 - t0)
        finite = jnp.all(jnp.isfinite(obs))

        def slope(e):
            ok = late & (e > 1e-300) & jnp.isfinite(e)
            w = ok.astype(ts.dtype)
            ly = jnp.log(jnp.where(ok, e, 1.0))
            n, sx, sy = w.sum(), (w * ts).sum(), (w * ly).sum()
            sxx, sxy = (w * ts * ts).sum(), (w * ts * ly).sum()
            den = n * sxx - sx * sx
            return jnp.where((n >= 3) & (den > 0), (n * sxy - sx * sy) / jnp.where(den > 0, den, 1.0), jnp.nan)

        g1, g2 = slope(obs[:, 0]), slope(obs[:, 2])
        size_max = jnp.max(jnp.where(jnp.isfinite(obs[:, 1]), obs[:, 1], -jnp.inf))
        failed = ~solver_ok | ~finite | jnp.isnan(g1)
        rest = jnp.where(g1 > cfg.growth_tol, DIVERGED, jnp.where(g1 < -cfg.growth_tol, CONVERGED, UNDECIDED))
        verdict = V.resolve(rest, failed, size_max, cfg)
        return dict(
            verdict=verdict,
            growth1=g1, growth2=g2,
            E1_t1=obs[-1, 0], E2_t1=obs[-1, 2],
            E1_ref_max=jnp.max(obs[:, 3]),
            size_max=size_max,
            error_t1=obs[-1, 0],
        )
