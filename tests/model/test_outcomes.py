"""Named outcomes as a model declares them: the rule language (assignment: tests/mapping/test_declared.py)."""
import numpy as np
import pytest

from stabjax.errors import ValidationError
from stabjax.model.outcomes import Rule

OBS = ("x", "v")


def feat_from(table):
    return lambda stat, obs: np.asarray(table[(stat, obs)], float)


def test_rule_evaluates_vectorised():
    r = Rule("std(x) < 1e-3 and abs(mean(v)) <= 2 * k or not final(x) > -1", OBS, ("k",), "f")
    feats = {("std", "x"): [0, 0, 1, 1], ("mean", "v"): [1, 3, 0, 0], ("final", "x"): [0, 0, 0, -2]}
    got = r(feat_from(feats), lambda name: np.array([1.0, 1.0, 1.0, 1.0]))
    np.testing.assert_array_equal(got, [True, False, False, True])
    chained = Rule("0 < max(x) <= 2", OBS, (), "f")
    np.testing.assert_array_equal(chained(feat_from({("max", "x"): [-1, 1, 2, 3]}), None), [False, True, True, False])


@pytest.mark.parametrize("text, needle", [
    ("max(y) < 1", "takes an observable name"),
    ("foo(x) < 1", "unknown function"),
    ("max(x)", "is not a condition"),
    ("x < 1", "unknown name 'x'"),
    ("__import__('os').system('true')", "calls take one argument"),
    ("max(x) < 'a'", "only numbers"),
    ("max(x) < 1 if True else 2", "unsupported syntax"),
    ("max(x) <", "cannot parse"),
    ("(max(x) < 1) + 1 > 0", "arithmetic on a condition"),
    ("max(x) < 1" + " " * 600, "longer than"),
    ("", "non-empty"),
])
def test_bad_rules_name_the_field(text, needle):
    with pytest.raises(ValidationError) as exc:
        Rule(text, OBS, ("k",), "outcomes.rules.settled")
    assert exc.value.field == "outcomes.rules.settled"
    assert needle in exc.value.message


def test_a_discovery_table_configures_discovery_and_never_switches_it_on():
    """``[outcomes.discovery]`` beside declared outcomes (a model's rules, the verdicts) is refused naming
    the table; with ``discover = true``, or for a model that declares nothing (already discovering), it
    configures discovery."""
    from stabjax.model.outcomes import Outcomes

    rules = Outcomes(rules={"rest": "std(x) < 1e-3"})
    for base in (rules, None):
        with pytest.raises(ValidationError) as exc:
            Outcomes.from_spec({"discovery": {"eps": 0.1}}, base=base)
        assert exc.value.field == "outcomes.discovery" and "discover = true" in exc.value.message
    on = Outcomes.from_spec({"discover": True, "discovery": {"eps": 0.1}}, base=rules)
    assert on.discover and not on.rules and on.discovery == {"eps": 0.1}
    found = Outcomes.from_spec({"discovery": {"eps": 0.1}}, base=Outcomes(discover=True))
    assert found.discover and found.discovery == {"eps": 0.1}
    with pytest.raises(ValidationError, match="outcomes.discovery"):
        Outcomes.from_spec({"discover": False, "discovery": {"eps": 0.1}}, base=Outcomes(discover=True))
