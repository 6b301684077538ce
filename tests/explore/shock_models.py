"""Models whose minimal fatal shock is known in closed form (the research note's T1, T2, T3), for the shock tests.

T1  x' = -x + x^3: the origin's basin is |x| < 1, delta* = 1 both ways; |x0| > 1 blows up in finite time
    (t* = 1/2 ln(x0^2 / (x0^2 - 1))), stopped at the escape radius.
T2  x' = -s(r) x - y, y' = -s(r) y + x, s(r) = sin(pi r)/(pi r): r' = -sin(pi r)/pi, so the origin's basin is the
    disc r < 1 (delta* = 1 in every direction), the cycles r = 2 and r = 4 are stable, r = 1 and r = 3 unstable:
    the smallest shock into the r = 4 cycle's basin (excitability into it) is 3.
T3  z' = (-a z1 + z1^3, -b z2 + z2^3), x = R(phi) z: the basin is the rotated rectangle |z1| < sqrt(a),
    |z2| < sqrt(b); the exit radius along angle theta is min(sqrt(a)/|cos(theta - phi)|, sqrt(b)/|sin(theta - phi)|),
    the minimal fatal shock sqrt(a) along phi (and phi + pi).
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from stabjax.model.outcomes import Outcomes
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import Predicate, System, Theory


class Bistable1D(System):
    name = "test_shock_t1"
    title = "x' = -x + x^3"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"),
                       Param("claim", 1.0, "radius a test theorem claims around the origin")))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    default_t1 = 20.0
    escape_radius = 10.0
    outcomes = Outcomes(rules={"origin": "abs(final(x)) < 0.5"}, window=0.1)

    def theory(self, p):
        m = np.asarray(p["claim"] - np.abs(p["x0"]), float)
        return Theory({"claimed_region": Predicate(m > 0, m, "|x0| < claim")}, {"claimed_radius": np.asarray(
            p["claim"], float) + 0 * np.asarray(p["x0"], float)}, main="claimed_region")

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, a):
        return -y + y ** 3

    def observe(self, t, y, a):
        return y


def _s(r):
    small = r < 1e-8
    pr = jnp.pi * jnp.where(small, 1.0, r)
    return jnp.where(small, 1.0, jnp.sin(pr) / pr)


class Circle2D(System):
    name = "test_shock_t2"
    title = "circular basin boundary r = 1"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"), Param("y0", 0.0, "initial y", kind="initial"),
                       Param("omega", 1.0, "rotation rate"),
                       Param("claim", 1.0, "radius a test theorem claims around the origin (1: the truth)")))
    state = (("x", ()), ("y", ()))
    observables = ("r",)
    observable_doc = ("distance from the origin",)
    default_t1 = 60.0
    outcomes = Outcomes(rules={"origin": "max(r) < 0.5", "cycle2": "abs(mean(r) - 2) < 0.5",
                               "cycle4": "abs(mean(r) - 4) < 0.5"}, window=0.2)

    def theory(self, p):
        """A test theorem: convergence to the origin from every start with r < claim (true for claim <= 1)."""
        claim = np.asarray(p["claim"], float)
        m = claim - np.hypot(np.asarray(p["x0"], float), np.asarray(p["y0"], float))
        return Theory({"disc": Predicate(m > 0, m, "sqrt(x0^2 + y0^2) < claim")}, {"disc_radius": claim + 0 * m},
                      main="disc")

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"]])

    def rhs(self, t, y, a):
        r = jnp.sqrt(y[0] ** 2 + y[1] ** 2)
        s = _s(r)
        return jnp.stack([-s * y[0] - a["omega"] * y[1], -s * y[1] + a["omega"] * y[0]])

    def observe(self, t, y, a):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2)])


class Rectangle2D(System):
    name = "test_shock_t3"
    title = "rotated rectangle basin"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"), Param("y0", 0.0, "initial y", kind="initial"),
                       Param("a", 1.0, "rate along z1"), Param("b", 4.0, "rate along z2"),
                       Param("phi", math.radians(30.0), "rotation of the rectangle", unit="rad")))
    state = (("x", ()), ("y", ()))
    observables = ("rr",)
    observable_doc = ("distance from the origin",)
    default_t1 = 20.0
    escape_radius = 10.0
    outcomes = Outcomes(rules={"origin": "final(rr) < 0.5"}, window=0.1)

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"]])

    def rhs(self, t, y, a):
        c, s = jnp.cos(a["phi"]), jnp.sin(a["phi"])
        z1, z2 = c * y[0] + s * y[1], -s * y[0] + c * y[1]
        d1, d2 = -a["a"] * z1 + z1 ** 3, -a["b"] * z2 + z2 ** 3
        return jnp.stack([c * d1 - s * d2, s * d1 + c * d2])

    def observe(self, t, y, a):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2)])


def t2_rhs(t, y, omega=1.0):
    """T2 in NumPy, for SciPy's DOP853 (np.sinc(r) = sin(pi r)/(pi r))."""
    s = np.sinc(np.hypot(y[0], y[1]))
    return [-s * y[0] - omega * y[1], -s * y[1] + omega * y[0]]


def t3_exit_radius(theta, a=1.0, b=4.0, phi=math.radians(30.0)):
    c, s = np.abs(np.cos(theta - phi)), np.abs(np.sin(theta - phi))
    with np.errstate(divide="ignore"):
        return np.minimum(np.sqrt(a) / c, np.sqrt(b) / s)


class NonNormal2D(System):
    """x' = -x + k y, y' = -y: the origin attracts everything, but a shock in y makes x grow first,
    x(t) = (x0 + k y0 t) e^-t, before it comes back: the excitability threshold of the neighbourhood |x| <= eps."""

    name = "test_shock_t4"
    title = "transient growth"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"), Param("y0", 0.0, "initial y", kind="initial"),
                       Param("k", 10.0, "coupling")))
    state = (("x", ()), ("y", ()))
    observables = ("ax", "rr")
    observable_doc = ("|x|", "distance from the origin")
    default_t1 = 20.0
    outcomes = Outcomes(rules={"origin": "final(rr) < 1e-3"}, window=0.1)

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"]])

    def rhs(self, t, y, a):
        return jnp.stack([-y[0] + a["k"] * y[1], -y[1]])

    def observe(self, t, y, a):
        return jnp.stack([jnp.abs(y[0]), jnp.sqrt(y[0] ** 2 + y[1] ** 2)])


def t4_threshold(eps=0.1, k=10.0, n=20001):
    """Smallest |(x0, y0)| from which max_t |x(t)| reaches eps: eps / max over directions of max_t |x(t)| on the
    unit circle, x(t) = (cos th + k sin th t) e^-t (maximised in t in closed form, over th on a fine grid)."""
    th = np.linspace(0, np.pi, n)
    c, s = np.cos(th), np.sin(th)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = np.where(k * s != 0, 1 - c / (k * s), 0.0)
    peak = np.where(ts > 0, np.abs(k * s) * np.exp(-np.maximum(ts, 0)), 0.0)
    g = np.maximum(np.abs(c), peak)
    i = np.argmax(g)
    return eps / g[i], th[i]


MODELS = {"test_shock_t1": Bistable1D, "test_shock_t2": Circle2D, "test_shock_t3": Rectangle2D,
          "test_shock_t4": NonNormal2D}
