"""Gyrodyne through the lead's engine: classify on a tiny batch, a sweep end to end, quick reproduce."""
from __future__ import annotations

import pytest

import numpy as np

import stabjax  # noqa: F401
from stabjax.config import IntegrateConfig
from stabjax.engines.simulate import batch_params, solve_batch
from stabjax.model.registry import get_system
from stabjax.systems.gyrodyne import CONVERGED, DIVERGED

S = get_system("gyrodyne")


def test_classify_inside_and_outside_tongue_d9():
    """D.9 case: eps = +0.0005 inside the tongue (growth +1.8e-3), eps = +0.004 outside (-4.2e-4)."""
    p = batch_params(S, dict(source=1.0, model=0.0), 2)
    p["eps"] = np.array([0.0005, 0.004])
    p = S.check(p)
    res = solve_batch(S, p, IntegrateConfig(t1=2500.0, rtol=1e-9, atol=1e-12, n_checkpoints=300))
    th = S.theory(p)
    assert list(res["verdict"]) == [DIVERGED, CONVERGED]
    assert list(th.predicates["mode1_exact"].ok) == [False, True]
    # inside: one real growing eigenvalue, matched closely; outside: a complex pair, so E1 beats and the
    # late-window fit is rougher (D.9 reports -3.8e-4 simulated vs -4.24e-4 predicted there)
    assert abs(res["growth1"][0] - th.derived["growth_pred"][0]) < 0.05 * th.derived["growth_pred"][0]
    assert abs(res["growth1"][1] - th.derived["growth_pred"][1]) < 1.5e-4


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the tongue classification below; reproduce --quick in the other papers' tests
def test_sweep_end_to_end_and_reproduce_quick(tmp_path):
    from stabjax.run.sweep import run_spec

    spec = {"system": "gyrodyne", "name": "tiny", "params": {"model": 1},
            "grid": {"eps": [-0.002, 0.0], "A[1]": [0.2, 1.5]},
            "integrate": {"t1": 3000.0, "rtol": 1e-8, "atol": 1e-11, "n_checkpoints": 200}}
    ds = run_spec(spec)
    v = ds["verdict"].values
    ok = ds["theory_mode1_exact"].values
    # theory: stable except at resonance with the large amplitude; simulation agrees
    assert ok.tolist() == [[True, True], [True, False]]
    assert v.tolist() == [[CONVERGED, CONVERGED], [CONVERGED, DIVERGED]]

    from stabjax.reproduce.gyrodyne import run

    paths = run(tmp_path, quick=True)
    assert all(p.exists() and p.stat().st_size > 0 for p in paths)
    assert any(p.suffix == ".png" for p in paths)
