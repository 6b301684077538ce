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
