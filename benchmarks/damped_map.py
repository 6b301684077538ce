"""The benchmark map of issue 32 (target 2): a damped oscillator whose damping crosses zero.

    x' = v,   v' = -(c - k) v - x        (damping gamma = c - k)

On a (c, k) map the trajectories from (1, 0) decay for k < c, slowly near the line k = c (rate gamma / 2),
and grow for k > c until they leave the escape radius. With the outcome ``decays`` = "max(amplitude) < 1e-2"
over the last 5 % of t1 = 1000 (the window starts at t_w = 950), the amplitude sqrt(x^2 + v^2) of the
weakly damped oscillator is e^{-gamma t / 2} (1 + O(gamma)), so the region ``decays`` is bounded by the
line in closed form

    k = c - gamma*,   gamma* = 2 ln(100) / t_w = 0.009694...

(to O(gamma*) = 1 % of gamma* from the oscillation of the amplitude around its envelope). Between that line
and k = c the trajectories still decay but not enough by t1 (``unclassified``); above k = c they escape.
``python -m benchmarks.param_map_bench`` refines it and compares with the full lattice.
"""
import jax.numpy as jnp

from stabjax import Outcomes, Param, ParamSet, System

T1 = 1000.0
WINDOW = 0.05
THRESHOLD = 1e-2


def gamma_star(t1: float = T1, window: float = WINDOW, threshold: float = THRESHOLD) -> float:
    """The damping at which the amplitude reaches ``threshold`` at the window's start (closed form)."""
    import math

    return 2.0 * math.log(1.0 / threshold) / (t1 * (1.0 - window))


class DampedMap(System):
    title = "damped oscillator whose damping c - k crosses zero"
    params = ParamSet((
        Param("c", 0.1, "damping"),
        Param("k", 0.0, "negative damping (feedback gain)"),
        Param("x0", 1.0, "initial displacement", kind="initial"),
        Param("v0", 0.0, "initial velocity", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("amplitude",)
    observable_doc = ("sqrt(x^2 + v^2)",)
    default_t1 = T1
    escape_radius = 10.0
    outcomes = Outcomes(rules={"decays": f"max(amplitude) < {THRESHOLD}"}, window=WINDOW)

    def initial_state(self, p):
        return jnp.stack([p["x0"], p["v0"]])

    def rhs(self, t, y, p):
        return jnp.stack([y[1], -(p["c"] - p["k"]) * y[1] - y[0]])

    def observe(self, t, y, p):
        return jnp.stack([jnp.sqrt(y[0] ** 2 + y[1] ** 2)])
