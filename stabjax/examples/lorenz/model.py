"""The "broken butterfly" Lorenz system: two chaotic attractors and escape to infinity.

    x' = sigma (y - x)
    y' = r x - x z - y
    z' = x y - b z

At sigma = 0.12, r = 0, b = -0.6 (Li & Sprott, Int. J. Bifurcation and Chaos 24, 2014) the
butterfly of the classic attractor splits into two mirror-image chaotic attractors, one in
x > 0 and one in x < 0, and part of the phase space runs off to infinity. A trajectory is
stopped as soon as max(|x|, |y|, |z|) passes ``escape_radius`` and counted as ``unbounded``;
the two chaotic attractors are told apart by the sign of x over the late window.
"""
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System


class BrokenButterfly(System):
    title = "Lorenz system, broken-butterfly parameters"
    params = ParamSet((
        Param("sigma", 0.12, "Prandtl-number parameter"),
        Param("r", 0.0, "Rayleigh-number parameter"),
        Param("b", -0.6, "geometric parameter"),
        Param("x0", 0.8, "initial x", kind="initial"),
        Param("y0", -3.0, "initial y", kind="initial"),
        Param("z0", 0.0, "initial z", kind="initial"),
    ))
    state = (("x", ()), ("y", ()), ("z", ()))
    observables = ("x", "y", "z")
    observable_doc = ("x", "y", "z")
    default_t1 = 1000.0
    escape_radius = 200.0
    outcomes = Outcomes(
        rules={
            "chaos_right": "min(x) > 0 and std(x) > 1e-3",
            "chaos_left": "max(x) < 0 and std(x) > 1e-3",
        },
        window=0.1,
        escape="unbounded",
    )

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"], p["z0"]])

    def rhs(self, t, u, p):
        x, y, z = u[0], u[1], u[2]
        return jnp.stack([p["sigma"] * (y - x), p["r"] * x - x * z - y, x * y - p["b"] * z])

    def observe(self, t, u, p):
        return u
