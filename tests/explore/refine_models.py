"""The models of the refinement's tests (tests/explore/test_refine.py, whose docstring derives their boundaries).

In a module of their own, beside the tests: a run's identity hashes the file that defines the model and the local
modules it imports (stabjax.plan.identity.model_sources), parsed again for every round's store; this small file is
parsed in a few milliseconds, the test module with its helpers in about 70 ms, a couple of hundred times (CI time).
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from stabjax.model.outcomes import VERDICTS, Outcomes
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import Predicate, System, Theory, VerdictConfig

T1 = 50.0


class DampedOscillator(System):
    """x'' + (c - k) x' + x = 0; the theorem below claims stability for k < c - 0.1 (conservative by 0.1)."""

    name = "test_oscillator"
    outcomes = VERDICTS  # tests the attitude verdicts on a toy model
    title = "damped linear oscillator with a gain threshold"
    params = ParamSet((
        Param("k", 0.0, "gain (negative damping)"),
        Param("c", 0.5, "damping"),
        Param("x0", 1.0, "initial position", kind="initial"),
    ))
    state = (("x", ()), ("v", ()))
    observables = ("error", "size")
    observable_doc = ("|(x, x')|", "|(x, x')|")
    verdict = VerdictConfig(settle_tol=0.999, excursion_tol=1.2, flip_tol=1.5, converged_tol=0.999,
                            diverge_size=1.001, growth_tol=0.5)
    default_t1 = T1

    def theory(self, p):
        margin = np.asarray(p["c"] - 0.1 - p["k"], float)
        return Theory(predicates={"bound": Predicate(margin > 0, margin, "k < c - 0.1")}, main="bound")

    def initial_state(self, p):
        return jnp.stack([p["x0"], jnp.zeros_like(p["x0"])])

    def equilibrium(self, p):
        return jnp.zeros(2)

    def rhs(self, t, y, a):
        return jnp.stack([y[1], -(a["c"] - a["k"]) * y[1] - y[0]])

    def observe(self, t, y, a):
        e = jnp.sqrt(y[0] ** 2 + y[1] ** 2)
        return jnp.stack([e, e])


class NamedOutcomes(DampedOscillator):
    """The oscillator with named outcomes (the 'bring your own model' shape): refinement labels by ``outcome``."""

    name = "test_named"
    outcomes = Outcomes(rules={"decays": "max(error) < 1e-3", "rings": "max(error) < 1", "grows": "max(error) >= 1"})


class EscapingOscillator(DampedOscillator):
    """The oscillator stopped at max(|x|, |x'|) > 2, with the size threshold of *diverged* raised to 10: for
    k > c + 0.03 the oscillation grows (e^2 ~ exp((k - c) t)) out of the ball before t1 = 50 (solver_status
    ESCAPED) and no checkpoint reaches the size 10, so the classifier alone says failed."""

    name = "test_escaping_oscillator"
    escape_radius = 2.0
    verdict = VerdictConfig(settle_tol=0.999, excursion_tol=1.2, flip_tol=1.5, converged_tol=0.999,
                            diverge_size=10.0, growth_tol=0.5)
