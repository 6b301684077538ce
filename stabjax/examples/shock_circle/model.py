"""A basin whose edge is a circle: the minimal fatal shock in closed form.

    x' = -s(r) x - omega y,   y' = -s(r) y + omega x,   s(r) = sin(pi r)/(pi r),   r = sqrt(x^2 + y^2)

In polar coordinates r' = -sin(pi r)/pi and theta' = omega: the origin is a stable focus whose basin is the disc
r < 1 (the circle r = 1 is an unstable cycle, the edge state), the cycles r = 2 and r = 4 are stable, r = 3 is
unstable. So the minimal fatal shock from the origin is 1 in every direction (into the r = 2 cycle), and the
smallest shock into the r = 4 cycle's basin (the excitability threshold into it) is 3.

The theorem: V = x^2 + y^2 has dV/dt = -2 r sin(pi r)/pi < 0 for 0 < r < 1, and the largest sublevel set of V on
which dV/dt < 0 is the disc r < 1 (Khalil's estimate with P = I): a guaranteed region of radius 1, tight here.
"""
import jax.numpy as jnp
import numpy as np

from stabjax import Outcomes, Param, ParamSet, Predicate, System, Theory


class Circle(System):
    title = "Circular basin edge (minimal fatal shock 1)"
    params = ParamSet((
        Param("omega", 1.0, "rotation rate", unit="1/s"),
        Param("x0", 0.0, "initial x", kind="initial"),
        Param("y0", 0.0, "initial y", kind="initial"),
    ))
    state = (("x", ()), ("y", ()))
    observables = ("r",)
    observable_doc = ("distance from the origin",)
    default_t1 = 60.0
    outcomes = Outcomes(
        rules={"origin": "max(r) < 0.5", "cycle2": "abs(mean(r) - 2) < 0.5", "cycle4": "abs(mean(r) - 4) < 0.5"},
        window=0.2,
    )

    def theory(self, p):
        r0 = np.hypot(np.asarray(p["x0"], float), np.asarray(p["y0"], float))
        margin = 1.0 - r0
        return Theory(
            predicates={"lyapunov_disc": Predicate(margin > 0, margin, "V = x^2 + y^2 < 1: dV/dt < 0 on the disc",
                                                   outcome="origin")},
            derived={"lyapunov_radius": np.ones_like(r0)},
            derived_doc={"lyapunov_radius": "radius of the disc V < 1 the Lyapunov function guarantees"},
            main="lyapunov_disc",
        )

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["y0"]])

    def rhs(self, t, y, p):
        r = jnp.sqrt(y[0] ** 2 + y[1] ** 2)
        small = r < 1e-8
        pr = jnp.pi * jnp.where(small, 1.0, r)
        s = jnp.where(small, 1.0, jnp.sin(pr) / pr)
        return jnp.stack([-s * y[0] - p["omega"] * y[1], -s * y[1] + p["omega"] * y[0]])

    def observe(self, t, y, p):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2)])
