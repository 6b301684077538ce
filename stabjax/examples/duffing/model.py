"""Forced Duffing oscillator with five coexisting periodic attractors.

    x' = v
    v' = -delta v - k3 x^3 + A cos(t)

At delta = 0.08, k3 = 1, A = 0.2 (Thomson & Stewart, Nonlinear Dynamics and Chaos, Fig. 1.9)
two period-1 and three period-3 oscillations (subharmonics) are stable at once. Rules cannot
name them without knowing them, so each is given by a *template*: a start known to reach it.
Every sampled trajectory is assigned the template whose late-window features (max and standard
deviation of x over the last 100 time units) are nearest.
"""
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System


class Duffing(System):
    title = "Forced Duffing oscillator (five periodic attractors)"
    params = ParamSet((
        Param("delta", 0.08, "linear damping"),
        Param("k3", 1.0, "cubic stiffness"),
        Param("A", 0.2, "forcing amplitude (forcing frequency 1)"),
        Param("x0", 0.0, "initial displacement", kind="initial"),
        Param("v0", 0.0, "initial velocity", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("x", "v")
    observable_doc = ("displacement", "velocity")
    default_t1 = 1000.0
    outcomes = Outcomes(
        templates={
            "y1": {"x0": -0.21, "v0": 0.02},
            "y2": {"x0": 1.05, "v0": 0.77},
            "y3": {"x0": -0.67, "v0": 0.02},
            "y4": {"x0": -0.46, "v0": 0.30},
            "y5": {"x0": -0.43, "v0": 0.12},
        },
        features=("max(x)", "std(x)"),
        window=0.1,
    )

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["v0"]])

    def rhs(self, t, y, p):
        x, v = y[0], y[1]
        return jnp.stack([v, -p["delta"] * v - p["k3"] * x ** 3 + p["A"] * jnp.cos(t)])

    def observe(self, t, y, p):
        return y
