"""The spec's ``[outcomes]`` table (rules, window, templates, features, max_distance) and ``[integrate] t0``:
what a sweep computes from them against an independent SciPy run, and every validation error naming its field."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from references import R_PAPER, S0_PAPER, monoaxial_rhs
from stabjax.fold import verdict as V
from stabjax.errors import ValidationError
from stabjax.plan.spec import make_plan

RULES = {"near": "max(angle) < 0.05", "far": "max(angle) >= 0.05"}


def test_rules_and_window_on_a_run_from_t0_match_scipy():
    """A run from t0 = 100 to t1 = 500 (the torque cos(omega0 t^alpha) depends on t, so starting at t0 is not a
    shift of a run from 0) with ``[outcomes] window = 0.25``: each trajectory's feature max and mean of the angle
    are those of the checkpoints in the last quarter of [t0, t1], here recomputed from a SciPy DOP853 run from t0
    (rtol 1e-12) at the same times, and the outcome is the first rule that holds. The sweep runs at rtol 1e-10 on
    an O(1) angle: 1e-8 absolute is 100 x rtol for the amplification over 400 time units (measured 2e-12). Fails
    if t0 is ignored (for alpha = 1/3 a run shifted to start at 0 has window mean 2.04 rad instead of 0.154), the
    window is taken from 0 or from the wrong end, or the rules are applied to other features."""
    t0, t1, w = 100.0, 500.0, 0.25
    alphas = [1 / 3, 7 / 9]
    spec = {"system": "monoaxial", "name": "o", "grid": {"alpha": alphas},
            "integrate": {"t0": t0, "t1": t1, "n_checkpoints": 64, "rtol": 1e-10, "atol": 1e-12},
            "outcomes": {"rules": RULES, "window": w}}
    from stabjax.run.sweep import run_spec

    ds = run_spec(spec)
    plan = make_plan(spec)
    ts = V.checkpoint_times(plan.icfg.checkpoints(), plan.vcfg)
    late = ts[ts - t0 >= (t1 - t0) * (1 - w)]
    assert late[0] >= 400.0 and late[-1] == t1 and len(late) >= 8
    obs = list(ds["observable"].values)
    names = ds["outcome"].attrs["flag_meanings"].split()
    for i, alpha in enumerate(alphas):
        args = (np.array([5.0, 6, 4]), 2 * np.eye(3), 1.0, 1.5, 2.0, 4 / 3, alpha, 1.0, R_PAPER)
        sol = solve_ivp(monoaxial_rhs, (t0, t1), np.concatenate([np.ones(3), S0_PAPER]), method="DOP853",
                        rtol=1e-12, atol=1e-14, t_eval=late, args=args)
        assert sol.success
        s = sol.y[3:].T
        angle = np.arctan2(np.linalg.norm(np.cross(s, R_PAPER), axis=1), s @ R_PAPER)
        np.testing.assert_allclose(float(ds["feat_max"][i, obs.index("angle")]), angle.max(), rtol=0, atol=1e-8)
        np.testing.assert_allclose(float(ds["feat_mean"][i, obs.index("angle")]), angle.mean(), rtol=0, atol=1e-8)
        want = "near" if angle.max() < 0.05 else "far"
        assert names[int(ds["outcome"][i])] == want
    assert [names[int(c)] for c in ds["outcome"].values] == ["far", "near"]  # both rules are exercised


R = {"near": "max(angle) < 0.05"}


@pytest.mark.parametrize("table, field", [
    ({"bogus": 1}, "outcomes.bogus"),
    ("x", "outcomes"),
    ({}, "outcomes"),  # declares no outcome
    ({"rules": "x"}, "outcomes.rules"),
    ({"rules": {"a": "max(angle) <"}}, "outcomes.rules.a"),
    ({"rules": {"a": "max(nope) < 1"}}, "outcomes.rules.a"),
    ({"rules": {"failed": "max(angle) < 1"}}, "outcomes"),  # a reserved name
    ({"rules": {"a b": "max(angle) < 1"}}, "outcomes"),  # not an identifier
    ({"rules": R, "window": 0}, "outcomes.window"),
    ({"rules": R, "window": 1.5}, "outcomes.window"),
    ({"rules": R, "window": math.nan}, "outcomes.window"),
    ({"rules": R, "window": True}, "outcomes.window"),
    ({"rules": R, "max_distance": -1}, "outcomes.max_distance"),
    ({"rules": R, "features": "max(angle)"}, "outcomes.features"),
    ({"templates": {"t": {"alpha": 0.5}}}, "outcomes.features"),  # templates need features
    ({"templates": {"t": {"nope": 1}}, "features": ["max(angle)"]}, "outcomes.templates.t.nope"),
    ({"templates": {"t": {}}, "features": ["max(angle)"]}, "outcomes.templates.t"),
    ({"templates": {"t": {"alpha": 0.5}}, "features": ["max(angle"]}, "outcomes.features[0]"),
    ({"discovery": {"eps": 0.1}}, "outcomes.discovery"),  # configures discovery, never switches it on
])
def test_outcomes_table_errors_name_their_field(table, field):
    """Each malformed ``[outcomes]`` entry is refused while planning, naming the field at fault."""
    with pytest.raises(ValidationError) as exc:
        make_plan({"system": "monoaxial", "grid": {"alpha": [0.5]}, "outcomes": table})
    assert exc.value.field == field, exc.value.message
