"""Tiny models for the engine tests whose claim is about dispatch, not about a model: they translate,
compile and run in a fraction of a paper model's time (the fused engine's XLA compile of monoaxial with the
attitude classifier is ~20 s on 2 cores; of DECAY, with the features-only fold a discovery sweep uses, ~3 s)."""
import jax.numpy as jnp

from stabjax.config import VerdictConfig
from stabjax.fold import verdict as V
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import System


class Decay(System):
    """dy/dt = -k y, y(0) = y0: y = y0 e^{-k t}. Its fold is the features-only one (no attitude verdicts)."""

    name = "test_decay"
    params = ParamSet((Param("k", 1.0, "rate"), Param("y0", 1.0, "initial value")))
    state = (("y", ()),)
    default_t1 = 10.0
    verdict = VerdictConfig(verdicts=False, features=True)

    def initial_state(self, p):
        return jnp.reshape(p["y0"], (1,))

    def rhs(self, t, y, a):
        return -a["k"] * y

    def observe(self, t, y, a):
        return jnp.stack([jnp.abs(y[0]), jnp.abs(y[0])])


class DecayWithClassify(Decay):
    """Decay with a system-specific ``classify`` hook (here the generic classifier): only the diffrax engine
    runs such a system, as it runs the gyrodyne."""

    name = "test_decay_classify"
    verdict = VerdictConfig()
    classify = staticmethod(V.classify)


DECAY, DECAY_CLASSIFY = Decay(), DecayWithClassify()  # one instance each: compiled once per engine
