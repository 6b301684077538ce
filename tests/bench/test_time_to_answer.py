"""Smoke tests of the time-to-answer benchmarks (issue 32): they run, and what they assert holds on small cases.
Not timing tests: the figures are in docs/performance.md with their commands."""
import tomllib
from pathlib import Path

import numpy as np
import pytest

SWEEPS = Path(__file__).resolve().parents[2] / "stabjax" / "sweeps"


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: outcomes unchanged by the stops: tests/fold/test_early_stop.py and test_attractor_stop.py
def test_stops_on_against_off_change_no_outcome():
    from benchmarks.peer_bench import run_stops

    r = run_stops(300, 300.0, reps=1)
    assert r["outcome_changes"] == 0
    assert r["on"]["steps"] < r["off"]["steps"]
    assert r["on"]["stopped"]["fixed_point"] + r["on"]["stopped"]["attractor"] > 0


def test_param_map_boundary_is_bracketed_on_its_closed_form():
    from benchmarks.param_map_bench import closed_form_check, spec
    from stabjax.explore.refine import refine_plan
    from stabjax.plan.spec import make_plan

    s = spec("1/16")
    s["grid"] = {"c": {"start": 0.0, "stop": 0.2, "num": 9}, "k": {"start": 0.0, "stop": 0.2, "num": 9}}
    ds = refine_plan(make_plan(s))
    r = closed_form_check(ds)
    assert r["segments_checked"] >= 10 and r["segments_off_the_line"] == 0
    assert np.isclose(r["gamma_star"], 2 * np.log(100) / 950)


def test_e2e_bench_writes_every_shipped_spec_back_as_the_same_toml():
    from benchmarks.e2e_bench import to_toml
    from stabjax.plan.spec import load_spec

    for f in sorted(SWEEPS.glob("*.toml")):
        spec = load_spec(f)
        assert tomllib.loads(to_toml(spec)) == spec, f.name
