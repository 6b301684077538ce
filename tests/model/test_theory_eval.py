"""The theory evaluated once per distinct set of the parameters it reads (stabjax.model.theory_eval, issue 32).

The reference is the plain per-trajectory evaluation ``system.theory(p)``: every theory variable must be the
same bit for bit, on every shipped sweep (small samples) and on toy theories that read the starts, read
nothing per trajectory, or decide what to read from the values.
"""
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from stabjax import Param, ParamSet, System
from stabjax.model import theory_eval
from stabjax.model.system import Predicate, Theory
from stabjax.plan.spec import load_spec, make_plan

SWEEPS = Path(__file__).resolve().parents[2] / "stabjax" / "sweeps"


def _bits(x, n):
    a = np.ascontiguousarray(np.broadcast_to(np.asarray(x), (n,)))
    return a.view(np.uint8) if a.dtype != bool else a


def _same(a: Theory, b: Theory, n: int) -> None:
    assert a.main == b.main and set(a.predicates) == set(b.predicates) and set(a.derived) == set(b.derived)
    for k, pa in a.predicates.items():
        pb = b.predicates[k]
        assert pa.doc == pb.doc
        np.testing.assert_array_equal(_bits(pa.ok, n), _bits(pb.ok, n), err_msg=k)
        np.testing.assert_array_equal(_bits(np.asarray(pa.margin, float), n), _bits(np.asarray(pb.margin, float), n),
                                      err_msg=k)
    for k, va in a.derived.items():
        np.testing.assert_array_equal(_bits(np.asarray(va, float), n), _bits(np.asarray(b.derived[k], float), n),
                                      err_msg=k)


# the shipped sweeps whose theory is cheap enough per trajectory for CI (the twobody ones take seconds per
# hundred trajectories evaluated the plain way: one of each paper)
SPECS = ["default.toml", "bench_1e6.toml", "gyrodyne_eps_gain.toml", "saakyan_region_axis.toml",
         "saakyan_gravity_ratio.toml", "saakyan_gyrostat_h.toml", "twobody_near_unstable.toml"]


@pytest.mark.parametrize("name", SPECS)
def test_shipped_sweeps_bit_for_bit(name):
    spec = load_spec(SWEEPS / name)
    if "sample" in spec and "n" in spec["sample"]:
        spec["sample"]["n"] = min(spec["sample"]["n"], 12)
    plan = make_plan(spec)
    n = min(plan.size, 400)
    p = plan.system.check(plan.params_for(0, n))
    _same(plan.system.theory(p), theory_eval.evaluate(plan.system, p), n)


class Toy(System):
    """A theory that reads the model parameter ``k`` (an expensive function of it, counted per row) and,
    in ``region``, the start ``x0``."""
    name = "theory_eval_toy"
    params = ParamSet((Param("k", 1.0, "gain"), Param("x0", 0.0, "start", kind="initial")))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    rows_seen: list = []
    reads_start = False

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, p):
        return -p["k"] * y

    def observe(self, t, y, p):
        return y

    def theory(self, p):
        k = np.asarray(p["k"], float)
        type(self).rows_seen.append(k.size)
        bound = np.sqrt(k) + np.sin(k)  # stands for an expensive computation per model row
        preds = {"gain": Predicate(k > 0.5, k - 0.5, "k > 1/2")}
        if self.reads_start:
            x0 = np.asarray(p["x0"], float)
            preds["region"] = Predicate(np.abs(x0) < bound, bound - np.abs(x0), "|x0| < sqrt(k) + sin(k)")
        return Theory(preds, {"bound": bound}, {"bound": "sqrt(k) + sin(k)"}, main="gain")


def _toy_params(n=600, seed=0):
    rng = np.random.default_rng(seed)
    k = rng.choice([0.25, 1.0, 2.0, 3.5, -0.0, 0.0], size=n)
    return {"k": k, "x0": rng.normal(size=n)}


def test_a_theory_of_the_model_parameters_is_evaluated_once_per_distinct_row():
    Toy.rows_seen = []
    sysm = Toy()
    p = _toy_params()
    plain = sysm.theory(p)
    Toy.rows_seen = []
    shared = theory_eval.evaluate(sysm, p)
    _same(plain, shared, 600)
    # a probe of one row, then the six distinct values of k (-0.0 and 0.0 are told apart: bit for bit)
    assert Toy.rows_seen == [1, 6]


def test_a_theory_that_reads_the_start_is_evaluated_per_trajectory():
    sysm = Toy()
    sysm.reads_start = True
    p = _toy_params()
    Toy.rows_seen = []
    _same(sysm.theory(p), theory_eval.evaluate(sysm, p), 600)
    assert Toy.rows_seen[-1] == 600


class ValueDependent(Toy):
    """Reads the start only where some gain is large: the one-row probe (k = 0.25 there) does not see it."""
    name = "theory_eval_value_dependent"

    def theory(self, p):
        th = super().theory(p)
        k = np.asarray(p["k"], float)
        if (k > 3).any():
            x0 = np.asarray(p["x0"], float)
            th.derived["far"] = np.abs(x0) * k
        else:
            th.derived["far"] = np.zeros_like(k)
        return th


def test_lookups_that_depend_on_the_values_fall_back_to_every_trajectory():
    sysm = ValueDependent()
    p = _toy_params()
    p["k"][0] = 0.25  # the probe's row
    Toy.rows_seen = []
    _same(sysm.theory(p), theory_eval.evaluate(sysm, p), 600)
    assert Toy.rows_seen[-1] == 600


def test_saakyan_l_116_is_the_same_deduplicated():
    """Saakyan's l of (1.16)/(1.18): the deduplicated evaluation equals the per-row one (bit for bit)."""
    from stabjax.systems import saakyan_theory as ST

    rng = np.random.default_rng(5)
    I = np.repeat(np.array([[4.0, 3.0, 2.0], [5.0, 4.0, 1.5]]), 40, axis=0)
    H = ST._unit(np.repeat(rng.normal(size=(4, 3)), 20, axis=0))
    lam = np.repeat([1.0, 0.7], 40)
    K = np.tile(np.repeat([4.5, 3.0], 20), 2)
    per_row = ST._l_116_rows(I, H, lam, K, 4001, 1e-7)
    np.testing.assert_array_equal(_bits(ST.l_116(I, H, lam, K), 80), _bits(per_row, 80))
    assert np.isfinite(per_row).any()


@pytest.mark.parametrize("params,field", [
    ({"mu": float("nan"), "sigma": 4 / 3, "alpha": 7 / 9}, "mu"),
    ({"mu": 0.5, "sigma": 4 / 3, "alpha": 7 / 9}, "mu"),
    ({"mu": 1.5, "sigma": 4 / 3, "alpha": "x"}, "alpha"),
    ({"mu": 1.5, "sigma": 4 / 3, "alpha": 7 / 9, "bogus": 1.0}, "bogus"),
])
def test_the_python_theory_checks_its_parameters_as_the_command_does(params, field):
    """The reliability pass: ``get_system(name).theory(p)``, which the docs gave as the function behind
    ``stabjax theory``, evaluated mu = NaN (every predicate False, margins NaN) and mu = 0.5 (outside paper A's
    mu >= 1) without a word. ``stabjax.theory`` checks first, naming the field, as the command does."""
    import stabjax
    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError) as e:
        stabjax.theory("monoaxial", params)
    assert e.value.field == field, str(e.value)


def test_the_python_theory_at_checked_parameters_is_theorem_1():
    """Defaults for the parameters not given; Theorem 1's margin 2 sigma - (mu + 1 + beta (mu - 1)) (paper A's (7))
    with the perturbation cos(omega0 t^alpha)'s least admissible beta, 1 - alpha, at mu = 1.5, sigma = 4/3,
    alpha = 7/9: 8/3 - (5/2 + 1/9) = 1/18."""
    import stabjax

    th = stabjax.theory("monoaxial", {"mu": 1.5, "sigma": 4 / 3, "alpha": 7 / 9})
    want = 1 / 18
    np.testing.assert_allclose(np.asarray(th.predicates["theorem1"].margin), want, rtol=1e-12)
    assert bool(np.all(th.predicates["theorem1"].ok)) == (want >= 0)
