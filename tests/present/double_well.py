"""A damped particle in a double well, the model the presentation tests discover attractors of.

    x' = v,   v' = -gamma v + x - x^3

Two stable equilibria, (x, v) = (-1, 0) and (1, 0) (the minima of the potential x^4/4 - x^2/2), with the
saddle at the origin between their basins: discovery finds two fixed points, and only their locations tell
``fixed_point_1`` from ``fixed_point_2``. No outcomes are declared (discovery names them).
"""
import jax.numpy as jnp

from stabjax import Param, ParamSet, System


class DoubleWell(System):
    title = "damped particle in a double well"
    params = ParamSet((
        Param("gamma", 0.5, "damping"),
        Param("x0", 0.5, "initial position", kind="initial"),
        Param("v0", 0.0, "initial velocity", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("x", "v")
    observable_doc = ("position", "velocity")
    default_t1 = 60.0

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["v0"]])

    def rhs(self, t, y, p):
        return jnp.stack([y[1], -p["gamma"] * y[1] + y[0] - y[0] ** 3])

    def observe(self, t, y, p):
        return y
