"""Saakyan sweeps end to end on small batches, and `stabjax reproduce saakyan` in quick mode."""
from __future__ import annotations

from pathlib import Path

import numpy as np

import stabjax  # noqa: F401
from stabjax.spec import load_spec, make_plan
from stabjax.sweep import run_spec
from stabjax.verdict import CONVERGED

SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"


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
    v = ds["verdict"].sel(torque=[0.0, 2.0]).values
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
    from stabjax.verdict import DIVERGED

    spec = load_spec(SWEEPS / "saakyan_no_mu.toml")
    spec["sample"]["n"] = 2
    ds = run_spec(spec)
    assert (ds["verdict"].sel(use_mu=0.0).values == DIVERGED).all()
    assert (ds["verdict"].sel(use_mu=1.0).values == CONVERGED).all()
    assert ds["theory_unstable_no_mu"].sel(use_mu=0.0).values.min() == 1
