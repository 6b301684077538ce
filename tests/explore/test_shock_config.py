"""What a shock search's spec is told when it is wrong: the field, and advice that fits a shock search (not advice
meant for a sweep's tables). Every case is refused before anything is integrated."""
from __future__ import annotations

import jax.numpy as jnp
import pytest

import shock_models as M
from stabjax.model.outcomes import Outcomes
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import System
from stabjax.errors import ValidationError
from stabjax.explore.shock import shock_spec
from stabjax.model import registry


class Lopsided1D(System):
    """x' = -x (1 - x) (1 + 2x): the origin's basin is (-1/2, 1), so the minimal fatal shock, 1/2, lies on one side."""
    name = "test_shock_lopsided"
    params = ParamSet((Param("x0", 0.0, "initial x", kind="initial"),))
    state = (("x", ()),)
    observables = ("x",)
    observable_doc = ("x",)
    escape_radius = 10.0
    outcomes = Outcomes(rules={"origin": "abs(final(x)) < 0.25"}, window=0.1)

    def initial_state(self, p):
        return jnp.stack([p["x0"]])

    def rhs(self, t, y, a):
        return -y * (1 - y) * (1 + 2 * y)

    def observe(self, t, y, a):
        return y


@pytest.fixture(autouse=True)
def models(monkeypatch):
    monkeypatch.setitem(registry.SYSTEMS, Lopsided1D.name, f"{__name__}:Lopsided1D")
    monkeypatch.setitem(registry._cache, Lopsided1D.name, Lopsided1D())
    for name, cls in M.MODELS.items():
        monkeypatch.setitem(registry.SYSTEMS, name, f"shock_models:{cls.__name__}")
        monkeypatch.setitem(registry._cache, name, cls())


def refused(**extra) -> ValidationError:
    spec = {"system": "test_shock_t2", "name": "shock", "integrate": {"t1": 60.0},
            "shock": {"components": ["x0", "y0"], "max_radius": 2.0}}
    for key, value in extra.items():
        spec[key] = {**spec.get(key, {}), **value}
    with pytest.raises(ValidationError) as exc:
        shock_spec(spec)
    return exc.value


@pytest.mark.parametrize("sample", [{"n": 5}, {"n": 5, "x0": {"dist": "uniform", "low": 0, "high": 1}},
                                    {"from": "starts.csv"}])
def test_a_sample_table_beside_a_shock_is_refused_as_such(sample):
    # {"n": 5} alone used to be told to add a parameter to sample (the model has none of the one it named), and a
    # starts file would have been looked for first: the table is refused whole, whatever it holds
    exc = refused(sample=sample)
    assert exc.field == "sample" and "a shock search chooses its own starts" in exc.message
    assert "s0" not in exc.message and "starts.csv" not in exc.message


@pytest.mark.parametrize("value", ["nan", "NaN", "2 * nan"])
def test_a_nan_weight_is_refused_as_not_a_number(value):
    exc = refused(shock={"weights": {"x0": value}})
    assert exc.field == "shock.weights.x0"
    assert "NaN is not allowed" in exc.message and "max(" not in exc.message


def test_a_nan_in_a_rule_is_refused_as_not_a_number():
    from stabjax.model.outcomes import Rule

    with pytest.raises(ValidationError) as exc:
        Rule("max(x) < nan", ("x",), (), "outcomes.rules.rest")
    assert exc.value.field == "outcomes.rules.rest"
    assert "NaN is not allowed" in exc.value.message and "max(nan)" not in exc.value.message


@pytest.mark.parametrize("directions", [2, 64])
def test_one_component_is_searched_both_ways_whatever_the_seed(directions):
    """In one dimension the unit sphere is {+1, -1}: both are searched (two random draws from seed 1 are both +1,
    and found the far side's 1 instead of 1/2), no more than those two, and the statement makes no statistical
    claim."""
    from stabjax.explore.shock import shock_spec

    spec = {"system": "test_shock_lopsided", "name": "lop", "integrate": {"t1": 40.0, "n_checkpoints": 200,
                                                                         "rtol": 1e-8, "atol": 1e-10},
            "shock": {"components": ["x0"], "max_radius": 2.0, "directions": directions, "seed": 1}}
    ds = shock_spec(spec)
    lo, hi = float(ds.shock_norm_lo), float(ds.shock_norm)
    assert lo <= 0.5 <= hi and hi - lo <= 0.01 * hi * (1 + 1e-9)  # the default 1 % resolution
    assert float(ds.shock_witness.values[0]) < -0.5  # the witness lies on the near side
    assert ds.attrs["n_directions"] == 2 and sorted(ds.direction_vector.values.ravel()) == [-1.0, 1.0]
    assert "in either direction of x0" in ds.attrs["statement"] and "confidence" not in ds.attrs["statement"]
