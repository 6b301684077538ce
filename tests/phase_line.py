"""x' = a x: the smallest model discovery warns about, or not, by one parameter (the result-warning tests).

    a = 1:  every start but 0 runs off, |x(t)| = |x0| e^t: no attractor; discovery counts the runaways as
            'escaped' and says so (``UnboundedWarning``)
    a = -1: every start rests at 0 long before t1 = 20: one fixed point, nothing said
"""
import jax.numpy as jnp

from stabjax import Param, ParamSet, System


class PhaseLine(System):
    name = "phase_line_test"
    title = "linear phase line x' = a x"
    params = ParamSet((Param("a", 1.0, "growth rate"), Param("x0", 1.0, "initial x", kind="initial")))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, p):
        return p["a"] * y

    def observe(self, t, y, p):
        return y


def spec(a: float, n: int = 20, **extra) -> dict:
    """A discovery sweep of ``n`` starts in [-2, 2] to t1 = 20 (seconds, one compile for both signs of ``a``)."""
    return {"system": f"{__file__}:PhaseLine", "name": "phase_line", "params": {"a": a},
            "sample": {"n": n, "seed": 0, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0}},
            "integrate": {"t1": 20.0, "n_checkpoints": 40}, **extra}
