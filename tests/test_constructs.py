"""Which engine runs a model written with each common JAX construct: one-line models, the engine the plan
resolves to, and for the constructs the lane engines translate, the same solution as the diffrax engine.

The lane engines (native C, fused XLA) translate a model's jaxpr primitive by primitive; a primitive without a
rule sends the model to the diffrax engine (about 100x slower on a small batch, with a note). The table below is
the contract: a construct that moves from "diffrax" to "lanes" is progress and updates the table; one that moves
the other way is a regression this test catches.
"""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stabjax import engines
from stabjax.config import IntegrateConfig
from stabjax.outcomes import VERDICTS
from stabjax.params import Param, ParamSet
from stabjax.system import System

M = jnp.array([[2.0, 0.5, 0.1], [0.5, 3.0, 0.2], [0.1, 0.2, 1.5]])  # symmetric positive definite


def _relax(y, a):
    """A contraction written as a static loop: three steps z <- (z + y) / 2 from z = 0 give 7 y / 8."""
    return jax.lax.fori_loop(0, 3, lambda i, z: 0.5 * (z + y), jnp.zeros_like(y))


CONSTRUCTS = {
    # name: (right-hand side f(y, params) of y' = f, the engine family that runs it)
    "arithmetic": (lambda y, a: -a["k"] * y, "lanes"),
    "sin, exp, pow, abs": (lambda y, a: -jnp.sin(y) * jnp.exp(-y * y) - jnp.abs(y) ** 1.5 * jnp.sign(y), "lanes"),
    "where": (lambda y, a: jnp.where(y > 0, -y, -2.0 * y), "lanes"),
    "cross, norm": (lambda y, a: jnp.cross(y, jnp.array([0.0, 0.0, 1.0])) - jnp.linalg.norm(y) * y, "lanes"),
    "matmul": (lambda y, a: -(M @ y), "lanes"),
    "stop_gradient": (lambda y, a: -jax.lax.stop_gradient(M) @ y, "lanes"),
    "fori_loop, static bounds": (lambda y, a: -_relax(y, a), "lanes"),
    "scan": (lambda y, a: -jax.lax.scan(lambda c, m: (c + m @ y, None), jnp.zeros(3), jnp.stack([M, M.T]))[0],
             "lanes"),
    "linalg.solve": (lambda y, a: -jnp.linalg.solve(M, y), "diffrax"),  # LU with pivoting: no lane rule yet
    "linalg.inv": (lambda y, a: -jnp.linalg.inv(M) @ y, "diffrax"),
    "linalg.eigh": (lambda y, a: -jnp.linalg.eigh(M)[0][0] * y, "diffrax"),
    "while_loop": (lambda y, a: -jax.lax.while_loop(lambda z: z[0] < 1.0, lambda z: z + 1.0, jnp.zeros(3)) * y,
                   "diffrax"),
}


def _system(name, f):
    class Model(System):
        outcomes = VERDICTS
        params = ParamSet((Param("k", 1.0, "rate"), Param("y0", (1.0, 0.5, -0.25), "initial state", (3,))))
        state = (("y", (3,)),)
        default_t1 = 2.0

        def initial_state(self, p):
            return p["y0"]

        def rhs(self, t, y, a):
            return f(y, a)

        def observe(self, t, y, a):
            n = jnp.linalg.norm(y)
            return jnp.stack([n, n])

    Model.name = "construct_" + name.replace(" ", "_").replace(",", "")
    return Model()


ICFG = IntegrateConfig(t1=2.0, rtol=1e-10, atol=1e-12, n_checkpoints=16, engine="fused")


PARAMS = {"k": np.array([1.0, 2.0]), "y0": np.array([[1.0, 0.5, -0.25], [-0.3, 0.2, 0.9]])}
NEW_RULES = ("stop_gradient", "fori_loop, static bounds", "scan")  # the rules added with this test


@pytest.mark.parametrize("name", list(CONSTRUCTS))
def test_which_engine_runs_each_construct(name):
    """The plan resolves to a lane engine (fused tried first here: translation only, no compile) or to the
    diffrax engine, with a note saying why, as the table says. Fails if a construct loses its rule (or gains
    one without the table being updated)."""
    f, family = CONSTRUCTS[name]
    system = _system(name, f)
    choice = engines.resolve(system, ICFG, system.verdict, PARAMS, static=[])
    assert (choice.engine == "diffrax") == (family == "diffrax"), (name, choice)
    assert bool(choice.note) == (family == "diffrax")


@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n in NEW_RULES else pytest.mark.slow)
                                  for n, (_, fam) in CONSTRUCTS.items() if fam == "lanes"])
def test_lane_rules_compute_the_primitive(name):
    """Where a lane engine runs the model, its final state (fused; native too where a C compiler works) equals
    diffrax's Dopri8 at rtol 1e-12 within 1e-8
    (the engine runs Tsit5 at rtol 1e-10 over t = 2 on a contracting system). Fails if a rule computes
    something else than the primitive: a scan unrolled in the wrong order, a loop run the wrong number of
    times, stop_gradient not the identity. (~15 s each, mostly the fused engine's compile: the older
    constructs are also covered by the engines' own tests, and run here only without -m "not slow".)"""
    from stabjax.engines import fused, native

    f, _ = CONSTRUCTS[name]
    system = _system(name, f)
    ref = _final_states(system, PARAMS)
    got = fused.solve(system, PARAMS, ICFG, system.verdict, with_state=True, static=[])
    np.testing.assert_allclose(got["state_t1"], ref, rtol=0, atol=1e-8)
    if native.available():  # the C emitter shares the lane evaluator's rules
        nat = native.solve(system, PARAMS, ICFG.replace(engine="native"), system.verdict, with_state=True, static=[])
        np.testing.assert_allclose(nat["state_t1"], ref, rtol=0, atol=1e-8)


def _final_states(system, params):
    """y(t1) of each trajectory by diffrax's own Dopri8 at rtol 1e-12 (not the engines' Tsit5), vmapped."""
    import diffrax

    def one(p):
        a = system.prepare(p)
        sol = diffrax.diffeqsolve(diffrax.ODETerm(lambda t, y, a: system.rhs(t, y, a)), diffrax.Dopri8(), 0.0,
                                  ICFG.t1, 1e-3, system.initial_state(p), args=a,
                                  stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-14),
                                  max_steps=100_000)
        return sol.ys[-1]

    return np.asarray(jax.jit(jax.vmap(one))({k: jnp.asarray(v) for k, v in params.items()}))
