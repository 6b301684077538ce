"""A damped double pendulum written as users write mechanics: a mass matrix, ``M(q) q'' = f(q, q')``.

Point masses m1, m2 on massless rods l1, l2, angles q = (th1, th2) from the downward vertical,
viscous damping c at both joints:

    M(q) = [[(m1 + m2) l1^2,          m2 l1 l2 cos(th1 - th2)],
            [m2 l1 l2 cos(th1 - th2),  m2 l2^2               ]]
    f    = [-m2 l1 l2 sin(th1 - th2) w2^2 - (m1 + m2) g l1 sin th1 - c w1,
             m2 l1 l2 sin(th1 - th2) w1^2 - m2 g l2 sin th2 - c w2]

``rhs`` solves for q'' with ``jnp.linalg.solve`` (the construct the lane engines used to refuse;
tests/engines/test_constructs.py). The energy E = T + V decreases at the rate -c (w1^2 + w2^2).
"""
import jax.numpy as jnp

from stabjax import Param, ParamSet, System


def mass_matrix(q, p):
    c12 = jnp.cos(q[0] - q[1])
    m12 = p["m2"] * p["l1"] * p["l2"] * c12
    return jnp.array([[(p["m1"] + p["m2"]) * p["l1"] ** 2, m12], [m12, p["m2"] * p["l2"] ** 2]])


def forces(q, w, p):
    s12 = jnp.sin(q[0] - q[1])
    k = p["m2"] * p["l1"] * p["l2"] * s12
    return jnp.stack([-k * w[1] ** 2 - (p["m1"] + p["m2"]) * p["g"] * p["l1"] * jnp.sin(q[0]) - p["c"] * w[0],
                      k * w[0] ** 2 - p["m2"] * p["g"] * p["l2"] * jnp.sin(q[1]) - p["c"] * w[1]])


class DoublePendulum(System):
    name = "double_pendulum"
    title = "damped double pendulum (mass-matrix form)"
    params = ParamSet((
        Param("m1", 1.0, "mass 1"), Param("m2", 1.0, "mass 2"),
        Param("l1", 1.0, "rod 1"), Param("l2", 1.0, "rod 2"),
        Param("g", 9.81, "gravity"), Param("c", 0.3, "joint damping"),
        Param("th1", 1.0, "initial angle 1", kind="initial"), Param("th2", -0.5, "initial angle 2", kind="initial"),
    ))
    state = (("q", (2,)), ("w", (2,)))
    observables = ("speed", "angle")
    default_t1 = 10.0

    def initial_state(self, p):
        z = jnp.zeros_like(p["th1"])
        return jnp.stack([p["th1"], p["th2"], z, z])

    def rhs(self, t, y, p):
        q, w = y[:2], y[2:]
        return jnp.concatenate([w, jnp.linalg.solve(mass_matrix(q, p), forces(q, w, p))])

    def observe(self, t, y, p):
        return jnp.stack([jnp.sqrt(y[2] ** 2 + y[3] ** 2), jnp.abs(y[0])])
