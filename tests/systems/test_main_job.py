"""The README's main job (sweeps/default.toml): its verdicts are those of the dynamics, not of the solver's error.

Each window where cos(t^alpha) > 0 amplifies the error left between excursions (docs/models/monoaxial.md, "The
horizon needs the tolerance"). At the spec's former rtol = 1e-8 that error grew into late flips (t = 1.7e4 to 2e4)
in 11 cells of the low-alpha, low-sigma corner; the map drawn on another machine differed in one of them. The spec's
tolerance is right when a tenfold tighter one gives the same verdict in every cell at every horizon.
"""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import run_plan

SPEC = Path(__file__).resolve().parents[2] / "sweeps" / "default.toml"


def verdicts(rtol: float, atol: float) -> np.ndarray:
    plan = make_plan(load_spec(SPEC))
    plan = dataclasses.replace(plan, icfg=dataclasses.replace(plan.icfg, rtol=rtol, atol=atol))
    ds = run_plan(plan)
    assert (ds["solver_status"].values == 0).all()
    return ds["verdict"].values


def test_the_verdicts_do_not_change_with_a_tenfold_tighter_tolerance():
    """Every cell's verdict at every horizon (20, 200, 2e3, 2e4) is the same at the spec's tolerance and at a
    tenfold tighter one. (That the comparison has teeth, the former rtol 1e-8 changing 4 cells of the corner
    against 1e-10, is the next test's.)"""
    icfg = make_plan(load_spec(SPEC)).icfg
    assert (icfg.rtol, icfg.atol) == (1e-10, 1e-12)
    at_spec = verdicts(icfg.rtol, icfg.atol)
    tighter = verdicts(icfg.rtol / 10, icfg.atol / 10)
    differ = np.argwhere(at_spec != tighter)
    assert len(differ) == 0, f"{len(differ)} verdicts change with the tolerance, e.g. at index {differ[:5].tolist()}"


@pytest.mark.slow
def test_the_corner_cell_converges_as_an_independent_dop853_run_does():
    """The cell (alpha, sigma) = (0.433, 1.217), flipped or undecided at rtol 1e-8 depending on the machine:
    SciPy DOP853 at rtol 1e-12 flips once early (t ~ 80) and then stays within 1e-4 rad of the target from
    t = 10^3 to 2e4; the spec's verdict at 2e4 is converged."""
    from scipy.integrate import solve_ivp

    from references import R_PAPER, S0_PAPER, monoaxial_rhs

    plan = make_plan(load_spec(SPEC))
    i, j = nearest(plan.grid[0].values, 0.4333), nearest(plan.grid[1].values, 1.2167)
    alpha, sigma = float(plan.grid[0].values[i]), float(plan.grid[1].values[j])
    p = dict(J=np.array([5.0, 6, 4]), D=2 * np.eye(3), a=1.0, mu=1.5, b=2.0, sigma=sigma, alpha=alpha, omega0=1.0,
             r=R_PAPER)
    ts = np.linspace(0.0, 2e4, 200_001)
    sol = solve_ivp(monoaxial_rhs, (0.0, 2e4), np.concatenate([np.ones(3), S0_PAPER]), method="DOP853", rtol=1e-12,
                    atol=1e-14, t_eval=ts, args=tuple(p.values()))
    assert sol.success
    s = sol.y[3:].T / np.linalg.norm(sol.y[3:].T, axis=1)[:, None]
    angle = np.arccos(np.clip(s @ R_PAPER, -1.0, 1.0))
    over = angle > math.pi / 2
    flips = ts[1:][over[1:] & ~over[:-1]]
    assert len(flips) == 1 and flips[0] < 200.0
    assert angle[ts >= 1e3].max() < 1e-4
    ds = run_plan(plan)
    names = str(ds["verdict"].attrs["flag_meanings"]).split()
    assert names[int(ds["verdict"].values[i, j, -1])] == "converged"


def nearest(values, target: float) -> int:
    """The index of the grid value nearest ``target``."""
    return int(np.argmin(np.abs(np.asarray(values) - target)))


def test_the_tolerance_check_finds_the_cells_the_solver_decided(tmp_path, capsys):
    """``horizon_check(..., factor=1, tighten=100)`` re-runs at the same horizon with rtol and atol / 100 and
    counts the verdicts that change. On 4 cells of the main job's corner at the former rtol 1e-8 (here all 4 flip
    late; which of them do is the machine's rounding, so the count is checked against the datasets, not fixed)
    the re-run equals a sweep run directly at 1e-10 and it counts exactly the cells whose verdict differs from
    that sweep's, at least one; at the spec's rtol 1e-10 it finds none. ``stabjax horizon-check R.nc --factor 1 --tighten 100`` says the same, its table's
    runs named by their tolerance; --factor 1 alone (nothing to compare) and --tighten below 1 are refused."""
    from stabjax.run.horizon import horizon_check
    from stabjax.run.sweep import run_spec

    from clirun import captured

    corner = {**load_spec(SPEC), "grid": {"alpha": [0.38333333333333336, 0.4], "sigma": [1.2, 1.2166666666666666]}}
    old = {**corner, "integrate": {**corner["integrate"], "rtol": 1e-8, "atol": 1e-10}}
    ds = run_spec(old, tmp_path / "r.nc")
    hc = horizon_check(ds, factor=1, tighten=100, n=4)
    assert (hc.attrs["rtol_long"], hc.attrs["atol_long"], hc.attrs["t1_long"]) == (1e-10, 1e-12, 2e4)
    direct = run_spec(corner)["verdict"].isel(horizon=-1).values.ravel()
    np.testing.assert_array_equal(hc["verdict_long"].values, direct)
    solvers = int((ds["verdict"].isel(horizon=-1).values.ravel() != direct).sum())
    assert hc.attrs["n_checked"] == 4 and hc.attrs["n_changed"] == solvers >= 1
    assert horizon_check(run_spec(corner), factor=1, tighten=10, n=4).attrs["n_changed"] == 0

    code, out, err = captured(capsys, "horizon-check", tmp_path / "r.nc", "--factor", "1", "--tighten", "100")
    assert code == 0, err
    assert "rtol = 1e-08 (rows) vs t1 = 20000, rtol = 1e-10 (columns)" in out, out
    assert f"{solvers} of 4 verdicts changed" in out, out
    code, _, err = captured(capsys, "horizon-check", tmp_path / "r.nc", "--factor", "1")
    assert code == 2 and "--factor" in err and "tighter tolerance" in err, err
    code, _, err = captured(capsys, "horizon-check", tmp_path / "r.nc", "--tighten", "0.5")
    assert code == 2 and "--tighten" in err, err
