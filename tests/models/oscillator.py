"""A damped linear oscillator with velocity feedback: the two-state model the tests load from a file.

    x' = v,   v' = -(c - k) v - x

Decays for k < c and grows for k > c (closed-form boundary k = c).
"""
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System


class Oscillator(System):
    title = "damped linear oscillator with feedback gain"
    params = ParamSet((
        Param("c", 0.5, "damping"),
        Param("k", 0.0, "feedback gain (destabilising)"),
        Param("x0", 1.0, "initial displacement", kind="initial"),
        Param("v0", 0.0, "initial velocity", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("amplitude", "x")
    observable_doc = ("sqrt(x^2 + v^2)", "displacement")
    default_t1 = 40.0
    outcomes = Outcomes(
        rules={"decays": "max(amplitude) < 1e-2", "grows": "final(amplitude) > 10"},
        window=0.25,
    )

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["v0"]])

    def rhs(self, t, y, p):
        return jnp.stack([y[1], -(p["c"] - p["k"]) * y[1] - y[0]])

    def observe(self, t, y, p):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2), y[0]])
