"""The papers' regions of initial conditions against the minimal fatal shock (docs/models/README.md, "Which claims
are regions of initial conditions"): Saakyan's (1.18) and (1.22) on the shipped principal-axis spec, paper C's
global claim. Heavy (hundreds of 300-s trajectories each): marked slow."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax.explore.shock import shock_spec
from stabjax.explore.shock_result import CONSISTENT, REFUTED, UNTESTED, witness_replay
from stabjax.reproduce import load_shipped


@pytest.mark.slow
def test_saakyan_region_118_refuted_and_122_consistent_on_the_largest_axis():
    """I = (4,3,2), H0 = e_x, lam = 1. K = 4.5: (1.10) holds, l = sqrt(2.5) (the spurious circle), yet a shock of
    norm < l flips the body: its witness, re-integrated by SciPy's DOP853 from the paper's component formulas, ends
    resting away from the target. K = 8.5: (1.21) holds, radius 2, and no fatal shock is found below it."""
    from references import ref_b1

    spec = load_shipped("saakyan_shock_max_axis")
    spec["grid"] = {"K": [4.5, 8.5]}
    spec["shock"]["directions"] = 32
    ds = shock_spec(spec)
    l = math.sqrt(2.5)
    p = ds.sel(K=4.5)
    assert float(p.theory_radius_radius_theorem1) == pytest.approx(l, rel=1e-6)
    assert int(p.theory_verdict_radius_theorem1) == REFUTED and float(p.shock_norm) < l
    names = ds.attrs["outcome_names"].split()
    assert names[int(p.shock_witness_outcome)] == "flipped" and names[int(p.shock_witness_recheck)] == "flipped"
    rep = witness_replay(ds, K=4.5)
    P = {k: (np.asarray(v, float) if np.ndim(v) else float(v)) for k, v in rep["params"].items()}
    S0 = P["S0"] / np.linalg.norm(P["S0"])
    H = np.array([1.0, 0.0, 0.0])
    assert max(np.linalg.norm(P["dw0"]) / P["lam"], np.linalg.norm(S0 - H)) == pytest.approx(float(p.shock_norm),
                                                                                            rel=1e-9)
    P.update(w0c=np.zeros(3), w0a=np.zeros(3), w0f=np.zeros(3), w0phi=np.zeros(3))
    f, x0 = ref_b1(P)
    sol = solve_ivp(f, (0.0, 300.0), x0, method="DOP853", rtol=1e-10, atol=1e-12)
    S = sol.y[3:, -1] / np.linalg.norm(sol.y[3:, -1])
    assert sol.success and math.acos(np.clip(S @ H, -1, 1)) > math.pi / 2  # past pi/2 from the target at t = 300
    q = ds.sel(K=8.5)
    assert np.isnan(float(q.shock_norm)) and float(q.shock_norm_lo) == 2.0
    assert int(q.theory_verdict_radius_corollary1) == CONSISTENT


@pytest.mark.slow
def test_twobody_global_claim_finds_no_fatal_shock():
    """Paper C, Theorem 1: every motion tends to the relative rest (but a measure-zero set): no fatal shock of the
    direction s0 (kept a unit vector) and the rate w0 among the directions searched, up to the whole sphere."""
    ds = shock_spec({"system": "twobody_uniaxial", "name": "tb", "params": {"s0": [0.0, 0.0, 1.0], "w0": [0.0] * 3},
                     "shock": {"components": ["w0", "s0"], "unit": ["s0"], "space": "state", "norm": "max",
                               "blocks": [["w"], ["s"]], "max_radius": 2.0, "directions": 16,
                               "theory": ["guaranteed"], "attractor": "converged"}})
    assert np.isnan(float(ds.shock_norm)) and float(ds.shock_norm_lo) == 2.0
    # the claim is global (its region reaches past max_radius: the rate w0 is unbounded), the search stops at 2:
    # beyond it the claim is untested, not "consistent", and its radius is not capped at the search's 2
    assert int(ds.theory_verdict_guaranteed) == UNTESTED and float(ds.theory_radius_guaranteed) > 2.0
