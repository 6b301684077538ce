"""Declared outcomes (stabjax.mapping.declared) and the verdict mapper: assignment order, templates, escape."""
import numpy as np

from stabjax.fold.status import ESCAPED as STATUS_ESCAPED
from stabjax.mapping.declared import assign
from stabjax.mapping.classify import mapper_for
from stabjax.model.outcomes import FAILED_NAME, UNCLASSIFIED, Outcomes

OBS = ("x", "v")


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
    sch = mapper_for(_Sys, decl, escape=True).scheme
    assert sch.names == ("small", "smaller", "a", "b", "gone", UNCLASSIFIED, FAILED_NAME)
    res = _results(7, status=[0, 0, 0, 0, STATUS_ESCAPED, 1, 0],
                   max_x=[0.2, 5, 5, 5, 5, 0.2, 5], mean_x=[0, 10.1, 19.0, 14.9, 0, 0, 25.1])
    tf = np.broadcast_to(np.array([[[10.0], [20.0]]]), (7, 2, 1))  # templates' mean(x): 10 and 20; spacing 10
    codes = assign(sch, _Sys, res, {}, tf)
    # 0: rule "small" (first match, although "smaller" holds too); 1, 2: nearest template within 5;
    # 3: 4.9 from a: a; 4: escaped; 5: solver failure wins over any rule; 6: 5.1 from the nearest: unclassified
    assert [sch.names[c] for c in codes] == ["small", "a", "b", "a", "gone", FAILED_NAME, UNCLASSIFIED]


def test_verdicts_are_the_outcomes_of_systems_without_a_declaration():
    m = mapper_for(_Sys, None, escape=False)
    assert m.scheme.names == ("converged", "flipped", "diverged", "undecided", "failed")
    res = _results(3)
    res["verdict"] = np.array([[0, 3], [1, 1], [4, 2]], np.int8)  # several horizons: the last is t1
    np.testing.assert_array_equal(m.assign(None, res, np.arange(3), None), [3, 1, 2])


def test_a_non_finite_feature_an_outcome_reads_is_failed_not_a_rule_match():
    # x's final is NaN where the solver reported success (an observable such as sqrt of a negative state):
    # the catch-all rule must not take it, nor may "unclassified"; a NaN in an observable no rule or
    # feature reads changes nothing. Row 2: a fixed-point stop writes std = 0 at the equilibrium, so a rule
    # reading std(x) alone still sees a NaN observable through x's other features.
    decl = Outcomes(rules={"high": "final(x) > 0.5", "low": "not (final(x) > 0.5)", "rest": "std(x) < 1"})
    sch = mapper_for(_Sys, decl, escape=False).scheme
    res = _results(5, final_x=[1.0, np.nan, 1.0, -np.inf, 0.0], final_v=[np.nan, 0, 0, 0, 0])
    res["feat_mean"][2, 0] = np.nan
    codes = assign(sch, _Sys, res, {})
    assert [sch.names[c] for c in codes] == ["high", FAILED_NAME, FAILED_NAME, FAILED_NAME, "low"]
    only_std = Outcomes(rules={"rest": "std(x) < 1"})
    s2 = mapper_for(_Sys, only_std, escape=False).scheme
    res = _results(2, final_x=[np.nan, 0.0], mean_x=[np.nan, 0.0])
    assert [s2.names[c] for c in assign(s2, _Sys, res, {})] == [FAILED_NAME, "rest"]


def test_a_non_finite_template_feature_is_failed_not_unclassified():
    decl = Outcomes(templates={"a": {"x0": 0.0}, "b": {"x0": 1.0}}, features=("mean(x)",))
    sch = mapper_for(_Sys, decl, escape=False).scheme
    res = _results(3, mean_x=[10.0, np.nan, 40.0])
    tf = np.broadcast_to(np.array([[[10.0], [20.0]]]), (3, 2, 1))
    assert [sch.names[c] for c in assign(sch, _Sys, res, {}, tf)] == ["a", FAILED_NAME, UNCLASSIFIED]
