"""Damped pendulum driven by a constant torque: a fixed point and a rotating limit cycle coexist.

    theta' = omega
    omega' = -alpha omega + T - K sin(theta)

For T < K the pendulum has a stable rest point at theta* = asin(T/K); for small damping
(alpha < ~ 1.19 T ... here alpha = 0.1, T = 0.5, K = 1) it also has a stable running
solution, a limit cycle on the cylinder with mean angular velocity close to T/alpha. Which one a
start reaches is the basin-stability question (Menck et al., Nature Physics 9, 2013).
"""
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System


class Pendulum(System):
    title = "Damped pendulum with constant torque"
    params = ParamSet((
        Param("alpha", 0.1, "damping coefficient", unit="1/s"),
        Param("T", 0.5, "constant driving torque (per unit inertia)", unit="1/s^2"),
        Param("K", 1.0, "gravity stiffness g/l", unit="1/s^2"),
        Param("theta0", 0.5, "initial angle", unit="rad", kind="initial"),
        Param("omega0", 0.0, "initial angular velocity", unit="rad/s", kind="initial"),
    ))
    state = (("theta", ()), ("omega", ()))
    observables = ("omega", "sin_theta")
    observable_doc = ("angular velocity [rad/s]", "sin(theta)")
    default_t1 = 1000.0
    outcomes = Outcomes(
        rules={
            "fixed_point": "std(omega) < 1e-3 and abs(mean(omega)) < 1e-3",
            "limit_cycle": "mean(omega) > 0.5 * T / alpha",
        },
        window=0.05,  # the last 50 time units: many periods of the running solution
    )

    def initial_state(self, p):
        return jnp.stack([p["theta0"], p["omega0"]])

    def rhs(self, t, y, p):
        return jnp.stack([y[1], -p["alpha"] * y[1] + p["T"] - p["K"] * jnp.sin(y[0])])

    def observe(self, t, y, p):
        return jnp.stack([y[1], jnp.sin(y[0])])
