"""Saakyan sweeps end to end on small batches, and `stabjax reproduce saakyan` in quick mode."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_spec
from stabjax.fold.verdict import CONVERGED

SWEEPS = Path(__file__).resolve().parents[2] / "sweeps"


def test_all_shipped_saakyan_specs_plan():
    specs = sorted(SWEEPS.glob("saakyan_*.toml"))
    assert len(specs) >= 9
    for path in specs:
        plan = make_plan(load_spec(path))
        assert plan.size <= 600, path.name  # small enough for 2 CPU cores


def test_double_count_sweep_small_batch():
    """Shipped finding: torque 1 ((3.9)+(3.21)) never converges, torques 0 and 2 always do."""
    spec = load_spec(SWEEPS / "saakyan_double_count.toml")
    spec["sample"]["n"] = 3
    spec["integrate"]["t1"] = 150.0
    ds = run_spec(spec)
    v = ds["verdict"].sel(torque=[0.0, 2.0]).isel(horizon=-1).values
    assert (v == CONVERGED).all()
    assert (ds["verdict"].sel(torque=1.0).values != CONVERGED).all()
    assert ds["theory_theorem3"].sel(torque=1.0).values.max() == 0
    assert ds["theory_theorem3"].sel(torque=0.0).values.min() == 1


def test_reproduce_quick(tmp_path):
    from stabjax.reproduce.saakyan import run

    files = run(tmp_path, quick=True)
    assert files and all(Path(f).exists() and Path(f).stat().st_size > 0 for f in files)
    import json

    ex = json.loads((tmp_path / "saakyan_examples.json").read_text())
    by = {e["label"]: e for e in ex}
    assert by["Cor. 2 without mu: unstable"]["error_t1"] > 100 * by["Cor. 2 without mu: unstable"]["error_t0"]
    assert by["B-3 (3.9)+(3.21): term counted twice"]["angle_t1"] > 0.1
    assert np.isfinite([e["error_t1"] for e in ex]).all()


def test_no_mu_sweep_small_batch_is_classified_diverged():
    """Shipped finding: without mu tiny perturbations run away (DIVERGED by the |w1|/lam rule), with mu converge."""
    from stabjax.fold.verdict import DIVERGED

    spec = load_spec(SWEEPS / "saakyan_no_mu.toml")
    spec["sample"]["n"] = 2
    ds = run_spec(spec)
    assert (ds["verdict"].sel(use_mu=0.0).isel(horizon=-1).values == DIVERGED).all()
    assert (ds["verdict"].sel(use_mu=1.0).isel(horizon=-1).values == CONVERGED).all()
    assert ds["theory_unstable_no_mu"].sel(use_mu=0.0).values.min() == 1


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the Saakyan loops run on the fused engine in test_reproduce_quick
def test_generic_classifier_on_the_fused_engine():
    """No system-specific classify(): the fused engine takes all five loops, and the generic rules
    (size = |w1|/lam, diverge_size = SPIN_DIVERGE; noise floor floor_tol) give the shipped no-mu
    finding: runaway without mu is DIVERGED, not flipped; with mu the run converges."""
    from stabjax.engines import fused as fast
    from stabjax.config import IntegrateConfig
    from stabjax.engines.simulate import batch_params
    from stabjax.model.registry import get_system
    from stabjax.fold.verdict import DIVERGED

    names = ("saakyan_moving", "saakyan_fixed", "saakyan_gravity", "saakyan_gyrostat", "saakyan_gyrostat_gravity")
    assert all(getattr(get_system(n), "classify", None) is None for n in names)
    s = get_system("saakyan_fixed")
    assert s.verdict.diverge_size == s.SPIN_DIVERGE == 10.0 and s.observables[1] == "spin_dev"
    assert s.verdict.floor_tol == 1e-6  # the former NOISE_FLOOR
    p = batch_params(s, dict(I=(4.0, 3.0, 2.0), H=(0.3, -0.5, 0.8), lam=1.0, K=5.0, init=1, rho=1e-3), 2)
    p["use_mu"] = np.array([0.0, 1.0])
    icfg = IntegrateConfig(t1=100.0, rtol=1e-8, atol=1e-10, n_checkpoints=400, engine="fused")
    out = fast.solve(s, p, icfg, s.verdict)  # raises fast.Unsupported if it cannot run lane-wise
    assert list(out["verdict"][:, -1]) == [DIVERGED, CONVERGED]
    assert out["size_max"][0, -1] > s.SPIN_DIVERGE and out["size_max"][1, -1] < 2.0
