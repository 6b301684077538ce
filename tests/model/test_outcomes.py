"""Named outcomes: the rule language, assignment order, templates, basin statistics, chunking."""
import numpy as np
import pytest
from scipy.stats import binomtest

from stabjax.errors import ValidationError
from stabjax.fold.status import ESCAPED as STATUS_ESCAPED
from stabjax.model.outcomes import (FAILED_NAME, UNCLASSIFIED, Outcomes, Rule, assign, basin_stats,
                              scheme)

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


class _Sys:
    """What assign() reads of a system: the observables and the (here: no) parameters."""

    observables = OBS
    params = ()


def _results(n, status=None, **feats):
    out = {"solver_status": np.zeros(n, np.int32) if status is None else np.asarray(status, np.int32),
           "verdict": np.zeros(n, np.int8)}
    for stat in ("max", "min", "mean", "std", "final"):
        out[f"feat_{stat}"] = np.zeros((n, 2))
    for key, val in feats.items():
        stat, obs = key.split("_")
        out[f"feat_{stat}"][:, OBS.index(obs)] = val
    return out


def test_first_rule_wins_then_templates_then_unclassified_escape_failed():
    decl = Outcomes(rules={"small": "max(x) < 1", "smaller": "max(x) < 0.5"},
                    templates={"a": {"x0": 0.0}, "b": {"x0": 1.0}}, features=("mean(x)",), escape="gone")
    sch = scheme(_Sys, decl, escape=True)
    assert sch.names == ("small", "smaller", "a", "b", "gone", UNCLASSIFIED, FAILED_NAME)
    res = _results(7, status=[0, 0, 0, 0, STATUS_ESCAPED, 1, 0],
                   max_x=[0.2, 5, 5, 5, 5, 0.2, 5], mean_x=[0, 10.1, 19.0, 14.9, 0, 0, 25.1])
    tf = np.broadcast_to(np.array([[[10.0], [20.0]]]), (7, 2, 1))  # templates' mean(x): 10 and 20; spacing 10
    codes = assign(sch, _Sys, res, {}, tf)
    # 0: rule "small" (first match, although "smaller" holds too); 1, 2: nearest template within 5;
    # 3: 4.9 from a: a; 4: escaped; 5: solver failure wins over any rule; 6: 5.1 from the nearest: unclassified
    assert [sch.names[c] for c in codes] == ["small", "a", "b", "a", "gone", FAILED_NAME, UNCLASSIFIED]


def test_verdicts_are_the_outcomes_of_systems_without_a_declaration():
    sch = scheme(_Sys, None, escape=False)
    assert sch.names == ("converged", "flipped", "diverged", "undecided", "failed")
    res = _results(3)
    res["verdict"] = np.array([[0, 3], [1, 1], [4, 2]], np.int8)  # several horizons: the last is t1
    np.testing.assert_array_equal(assign(sch, _Sys, res, {}), [3, 1, 2])


@pytest.mark.parametrize("k, n", [(0, 10), (3, 20), (10, 10), (57, 200), (1, 1000)])
def test_basin_stats_against_scipy_wilson(k, n):
    codes = np.array([0] * k + [1] * (n - k))
    st = basin_stats(codes[None, :], 3)
    s = k / n
    assert st["count"][0].tolist() == [k, n - k, 0]
    np.testing.assert_allclose(st["fraction"][0], [s, 1 - s, 0])
    np.testing.assert_allclose(st["se"][0, 0], np.sqrt(s * (1 - s) / n), rtol=1e-15)
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    np.testing.assert_allclose([st["ci_low"][0, 0], st["ci_high"][0, 0]], [ci.low, ci.high], rtol=1e-12, atol=1e-15)
    assert st["ci_low"][0, 2] == 0 and st["ci_high"][0, 2] > 0  # an outcome never seen still has an upper bound


def test_standard_error_matches_the_spread_over_independent_samples():
    """S's SE is the binomial one: over 400 independent batches of N = 200 the spread of S agrees."""
    rng = np.random.default_rng(0)
    p, n = 0.3, 200
    batches = (rng.random((400, n)) < p).astype(int)
    st = basin_stats(batches, 2)
    spread = st["fraction"][:, 1].std(ddof=1)
    # the sample std of 400 estimates is within ~3.5 % of sigma = sqrt(p(1-p)/n) (chi distribution, 3 sigma ~ 11 %)
    assert abs(spread / np.sqrt(p * (1 - p) / n) - 1) < 0.11
    assert abs(st["se"][:, 1].mean() / np.sqrt(p * (1 - p) / n) - 1) < 0.02
