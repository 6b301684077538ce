"""Lorenz-63 at r = 24.4: a chaotic attractor coexists with the two stable equilibria C+ and C-.

    x' = sigma (y - x)
    y' = r x - y - x z
    z' = x y - b z

With sigma = 10, b = 8/3 the equilibria C+- = (+-q, +-q, r - 1), q = sqrt(b (r - 1)), lose their
stability in a subcritical Hopf bifurcation at r_H = sigma (sigma + b + 3) / (sigma - b - 1)
= 24.74, and the chaotic attractor appears at r_A ~ 24.06 (Kaplan & Yorke 1979; Sparrow, The
Lorenz Equations, 1982). For r_A < r < r_H, here r = 24.4, a start goes to one of three attractors:
C+, C- or the chaotic (strange) attractor. This example declares no outcomes: discovery finds
the three and types them (fixed points by zero late-window spread, the chaotic one by its
positive largest Lyapunov exponent).
"""
import jax.numpy as jnp

from stabjax import Param, ParamSet, System


class Lorenz63(System):
    title = "Lorenz-63 (chaotic attractor beside two stable equilibria at r = 24.4)"
    params = ParamSet((
        Param("sigma", 10.0, "Prandtl number"),
        Param("r", 24.4, "reduced Rayleigh number"),
        Param("b", 8.0 / 3.0, "geometric factor"),
        Param("x0", 1.0, "initial x", kind="initial"),
        Param("y0", 1.0, "initial y", kind="initial"),
        Param("z0", 1.0, "initial z", kind="initial"),
    ))
    state = (("x", ()), ("y", ()), ("z", ()))
    observables = ("x", "y", "z")
    observable_doc = ("x", "y", "z")
    default_t1 = 1000.0

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"], p["z0"]])

    def rhs(self, t, u, p):
        x, y, z = u[0], u[1], u[2]
        return jnp.stack([p["sigma"] * (y - x), p["r"] * x - y - x * z, x * y - p["b"] * z])

    def observe(self, t, u, p):
        return u
