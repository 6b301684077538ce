"""A trajectory whose observables turn NaN in the classification window, while the solver reaches t1, is
*failed* on every engine, with rules and with discovery (never a catch-all rule's, never unclassified).

The model is x' = x - x^3 observed through r = sqrt(x): a start x0 < 0 goes to x = -1, where r is NaN;
x0 > 0 goes to x = 1, r = 1. So the failed set is known in closed form: exactly the starts with x0 < 0.

Both tests' models are one class, x' = s (x - x^3) + (1 - s) (1 - x) (s = 1: the above; s = 0: x' = 1 - x, exactly:
the other term is multiplied by 0), with s on a grid of one point: a parameter of the run, not a constant of the
compiled program, so both share one program per engine and outcome mode, at the same t1 and checkpoints (CI time).
"""
import jax.numpy as jnp
import numpy as np
import pytest

from stabjax import Outcomes, Param, ParamSet, System
from stabjax.app.sweep_cmds import run_status
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import run_plan

ENGINES = ("diffrax", "fused", "native")


class NanObs(System):
    title = "x' = s (x - x^3) + (1 - s) (1 - x), observed through sqrt(x) (NaN for x < 0)"
    name = "nanobs_test"
    params = ParamSet((Param("x0", 0.5, "start", kind="initial"),
                       Param("s", 1.0, "1: x' = x - x^3 (NanObs), 0: x' = 1 - x (NanEarly)")))
    state = (("x", ()),)
    observables = ("r",)
    observable_doc = ("sqrt(x)",)
    default_t1 = 20.0
    outcomes = Outcomes(rules={"high": "final(r) > 0.5", "low": "not (final(r) > 0.5)"})

    def initial_state(self, p):
        return p["x0"][None]

    def rhs(self, t, y, p):
        return p["s"] * (y - y**3) + (1.0 - p["s"]) * (1.0 - y)

    def observe(self, t, y, p):
        return jnp.sqrt(y)


NANOBS = NanObs()  # one object for every run: the engines cache their compiled programs per model object
BISTABLE, NANEARLY = 1.0, 0.0  # s: x' = x - x^3, x' = 1 - x


def _run(engine, discover, s=BISTABLE, low=-2.0, high=2.0, t1=40.0):
    # t1 = 40 for both models (one program): x' = x - x^3 is at x = +-1 long before the window [20, 40] as before
    # at [10, 20] (the closed form's failed set is the same)
    spec = {"system": NANOBS, "name": "nanobs", "grid": {"s": [s]}, "sample": {"n": 50, "seed": 0,
            "x0": {"dist": "uniform", "low": low, "high": high}},
            "integrate": {"t1": t1, "n_checkpoints": 50, "engine": engine}}
    if discover:
        # continuation off: grouped over the whole sweep at once, as without the grid of s
        spec["outcomes"] = {"discover": True, "discovery": {"lyapunov": False, "continuation": False}}
    ds = run_plan(make_plan(spec))
    names = ds["outcome"].attrs["flag_meanings"].split()
    return np.asarray(ds["x0_sample"]).ravel(), [names[c] for c in np.asarray(ds["outcome"]).ravel()], ds


@pytest.mark.parametrize("discover", [False, True], ids=["rules", "discovery"])
@pytest.mark.parametrize("engine", ENGINES)
def test_nan_observables_are_failed_on_every_engine(engine, discover):
    x0, got, ds = _run(engine, discover)
    assert (np.asarray(ds["solver_status"]).ravel() == 0).all()  # the solver itself never failed
    neg = x0 < 0
    assert 10 < neg.sum() < 40
    assert [g for g, n in zip(got, neg) if n] == ["failed"] * int(neg.sum())
    rest = {g for g, n in zip(got, neg) if not n}
    assert rest == ({"fixed_point_1"} if discover else {"high"}), rest
    assert run_status(ds) == 1  # the sweep's exit status for failed trajectories


def test_the_view_says_why_a_nan_observable_is_failed(tmp_path):
    """Before, the explanation walked the rules: "rule low holds ... assigned by rule low" beside the
    outcome "failed"."""
    import inspect

    from stabjax.present.viewmodel import Result

    src = "import jax.numpy as jnp\nfrom stabjax import Outcomes, Param, ParamSet, System\n\n" + inspect.getsource(NanObs)
    (tmp_path / "nanobs.py").write_text(src)
    out = tmp_path / "r.nc"
    run_plan(make_plan({"system": f"{tmp_path / 'nanobs.py'}:NanObs", "name": "nanobs",
                        "grid": {"x0": [-0.5, 0.5]}, "integrate": {"t1": 20.0, "n_checkpoints": 50}}), out)
    r = Result(out)
    failed = dict(r.explain(0))
    assert failed["outcome"] == "failed" and "NaN or infinite" in failed["features"] and "assigned by" not in failed
    assert dict(r.explain(1))["assigned by"].startswith("rule high")


@pytest.mark.parametrize(("engine", "discover"), [(e, False) for e in ENGINES] + [("native", True)])
def test_nan_observables_before_the_window_do_not_reach_it(engine, discover):
    """NanEarly: x' = 1 - x (s = 0), observed through sqrt(x): NaN only until x crosses 0.
    x(t) = 1 + (x0 - 1) e^-t: a start x0 < 0 has r = sqrt(x) NaN until t = ln(1 - x0) <= ln 3, long
    before the late window (t >= 20 of [0, 40]), where r is within 1e-8 of 1 (t1 = 40 so that discovery,
    which types a fixed point to the solver's tolerances, sees one at rest). Only the window counts:
    every start is ``high`` (the fixed point), none failed. Fails if a checkpoint before the window
    reaches the window's sums as 0 * NaN."""
    x0, got, ds = _run(engine, discover, NANEARLY, -2.0, 0.5, t1=40.0)
    assert 10 < (x0 < 0).sum() < 45
    assert set(got) == ({"fixed_point_1"} if discover else {"high"}), sorted(set(got))
    assert run_status(ds) == 0
    if not discover:
        np.testing.assert_allclose(np.asarray(ds["feat_mean"]).ravel(), 1.0, atol=1e-5)
