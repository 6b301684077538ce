"""Bezglasnyi-Mysina sweep specs end to end on small batches (the shipped specs, shrunk)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_spec
from stabjax.fold.verdict import CONVERGED

SPECS = sorted((Path(__file__).resolve().parents[2] / "sweeps").glob("twobody_*.toml"))
SMALL = {"t1": 300.0, "rtol": 1e-8, "atol": 1e-10, "n_checkpoints": 400}


def test_specs_exist():
    assert len(SPECS) >= 6


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_shipped_specs_plan(path):
    plan = make_plan(load_spec(path))
    assert plan.size <= 1000  # a few minutes on 2 cores
    assert plan.system.name.startswith("twobody_")


def _shrink(path, n, grid_num=None):
    spec = load_spec(path)
    spec["sample"]["n"] = n
    if grid_num:
        for v in spec.get("grid", {}).values():
            v["num"] = grid_num
    spec["integrate"] = dict(SMALL)
    return spec


def test_near_unstable_and_b_rate_end_to_end():
    sdir = SPECS[0].parent
    ds = run_spec(_shrink(sdir / "twobody_near_unstable.toml", 4))
    assert (ds["verdict"].isel(horizon=-1).values == CONVERGED).all()  # every start near s0 = -r0 left it
    assert ds["theory_guaranteed"].values.all()
    # (Omega_r, b) map, 2 x 2 x 1 = the same batch shape (one compile)
    ds = run_spec(_shrink(sdir / "twobody_b_rate.toml", 1, grid_num=2))
    assert set(ds["verdict"].dims) == {"Omega_r", "b", "sample", "horizon"}
    for k in ("margin_physical", "margin_paper", "margin_printed", "margin_guaranteed", "derived_b_star_physical"):
        assert k in ds
    m = ds["margin_physical"].values
    want = ds["b"].values[None, :, None] - ds["derived_b_star_physical"].values
    np.testing.assert_allclose(m, want, atol=1e-9)
    # b* = 6 rho at |Omega_r| = 6 with rho = 2.3458 / 3 (docs/models/twobody.md), both signs (rho differs by sign)
    assert abs(ds["derived_b_star_physical"].values[-1, 0, 0] - 6 * 2.3458 / 3) < 1e-3


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the loops against SciPy in test_twobody_reference.py, the sweeps above
@pytest.mark.parametrize("name", ["twobody_uniaxial", "twobody_triaxial_rotating"])
def test_generic_classifier_on_the_fused_engine(name):
    """No system-specific classify(): the fused engine takes these loops (no primitive without a
    lane-wise rule) and the default start converges there."""
    from stabjax.engines import fused as fast
    from stabjax.config import IntegrateConfig
    from stabjax.engines.simulate import batch_params
    from stabjax.model.registry import get_system

    s = get_system(name)
    assert getattr(s, "classify", None) is None
    icfg = IntegrateConfig(engine="fused", **SMALL)
    out = fast.solve(s, batch_params(s, None, 1), icfg, s.verdict)  # fast.Unsupported if it cannot run
    assert out["verdict"][0, -1] == CONVERGED


def test_noise_floor_is_converged_by_the_generic_rule():
    """What the removed classify() added (late window settled below 1e-3 converged_tol = 1e-6 rad:
    converged, whatever the sign of the noisy log-log slope) is the generic floor_tol rule."""
    import jax.numpy as jnp

    from stabjax.fold import verdict as V
    from stabjax.model.registry import get_system

    s = get_system("twobody_uniaxial")
    assert s.verdict.floor_tol == 1e-6 and s.verdict.converged_tol == 1e-3  # the former 1e-3 * converged_tol
    # (the late window is the last decade in log-time: settling at t = 50 is a decade before t1)
    ts = np.linspace(0.0, 3000.0, 4000)
    err = np.where(ts < 50.0, 1.0 - ts / 60.0, 1e-9 * (1.0 + 0.5 * ts / 3000.0))  # settles, then a rising floor
    obs = jnp.asarray(np.stack([err, np.ones_like(ts)], axis=1))
    out = V.classify(jnp.asarray(ts), obs, jnp.asarray(True), s.verdict, 0.0)
    # no checkpoint between the floor and settle_tol: no decay law (reason 2), and converged
    assert np.isnan(out["decay_exponent"][-1]) and int(out["decay_reason"][-1]) == 2
    assert int(out["verdict"][-1]) == CONVERGED
    out = V.classify(jnp.asarray(ts), obs, jnp.asarray(True), s.verdict.replace(floor_tol=0.0), 0.0)
    assert int(out["verdict"][-1]) == V.UNDECIDED  # the plain slope rule alone: undecided
