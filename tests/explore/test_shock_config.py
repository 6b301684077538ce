"""What a shock search's spec is told when it is wrong: the field, and advice that fits a shock search (not advice
meant for a sweep's tables). Every case is refused before anything is integrated."""
from __future__ import annotations

import pytest

import shock_models as M
from stabjax.errors import ValidationError
from stabjax.explore.shock import shock_spec
from stabjax.model import registry


@pytest.fixture(autouse=True)
def models(monkeypatch):
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
