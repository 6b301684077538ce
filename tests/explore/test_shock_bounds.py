"""What a shock search may claim, at the edges of its settings: a coarse resolution never gives a negative norm, a
theorem whose region reaches past max_radius is not called consistent (and its radius is its own, not the search's
range), a table whose norm or fatality cannot be held against a theorem is refused, and the effort's steps are
counted (closed forms: the circle of shock_models.py, whose origin's basin is the disc r < 1)."""
from __future__ import annotations

import numpy as np
import pytest

import shock_models as M
from stabjax.errors import ValidationError
from stabjax.explore.shock import ladder_width, shock_spec
from stabjax.explore.shock_result import CONSERVATIVE, REFUTED, UNTESTED, VERDICTS
from stabjax.model import registry

INTEGRATE = {"t1": 20.0, "n_checkpoints": 100, "rtol": 1e-8, "atol": 1e-10}


@pytest.fixture(autouse=True)
def models(monkeypatch):
    for name, cls in M.MODELS.items():
        monkeypatch.setitem(registry.SYSTEMS, name, f"shock_models:{cls.__name__}")
        monkeypatch.setitem(registry._cache, name, cls())


def circle(shock, **extra):
    return shock_spec({"system": "test_shock_t2", "name": "shock", "integrate": INTEGRATE,
                       "shock": {"components": ["x0", "y0"], "directions": 4, **shock}, **extra})


@pytest.mark.parametrize("m", range(1, 17))
def test_every_rung_of_the_ladder_is_a_positive_radius(m):
    """The CMA-ES ladder's rungs centre (1 + w frac): a width that a coarse resolution asks for (0.5 m tol / centre,
    up to 0.5 m) is cut so that the lowest rung stays above 0; a width that kept them positive is left alone."""
    frac = (2 * np.arange(m) + 1) / m - 1
    for w in (0.1, 0.5, 1.0, 1.05, 2.0, 3.6, 0.5 * m * 0.9, 1e6):
        cut = ladder_width(w, m)
        assert np.all(1 + cut * frac > 0), (w, m, cut)
        if np.all(1 + w * frac > 0):
            assert cut == w


def test_a_coarse_resolution_gives_positive_norms_and_no_false_red_flag():
    """rel_resolution = 0.9 widened the ladder past its centre: rungs at negative radii, recorded as |delta*| = -1.08
    (its witness of norm +1.08) and a red flag of a true theorem. Every norm stored is a norm of a start tried."""
    ds = circle({"max_radius": 2.0, "rel_resolution": 0.9, "theory": ["disc", "disc_radius"]})
    hi, lo = float(ds.shock_norm), float(ds.shock_norm_lo)
    assert 0 < lo <= hi
    assert hi == pytest.approx(float(np.linalg.norm(ds.shock_delta.values)), rel=1e-9)
    assert hi >= 1.0 - 1e-6  # a fatal shock is at least the basin's radius
    und = float(ds.shock_undecided_norm)
    assert np.isnan(und) or und > 0
    for name in ("disc", "disc_radius"):  # the claim 1 is true: never refuted
        assert int(ds[f"theory_verdict_{name}"]) != REFUTED
    assert ds.attrs["total_steps"] > ds.attrs["n_trajectories"]  # the rounds' solver steps, not a hard-coded 0
    # a shocked start smaller than |delta*| whose fate is unknown is said beside the answer (it may be smaller)
    from stabjax.present import shock as SH

    assert ("left undecided" in SH.format_summary(ds)) == (und < hi)
    ds2 = ds.copy(deep=True)
    ds2["shock_undecided_norm"][...] = 0.5 * hi
    assert f"a start shocked by {0.5 * hi:.4g} was left undecided" in SH.format_summary(ds2)


def test_a_theorem_beyond_the_searched_range_is_untested():
    """max_radius 0.5 searches the disc r < 0.5 only: the theorem's radius 1 lies beyond it, so it is untested (not
    consistent), in both forms, and the predicate's radius is its own 1, not capped at 0.5. No fatal shock was found,
    so none is promised; a claim below 0.5 is still conservative."""
    ds = circle({"max_radius": 0.5, "theory": ["disc", "disc_radius"]}, grid={"claim": [0.25, 1.0]})
    assert np.all(np.isnan(ds.shock_norm.values)) and np.all(ds.shock_norm_lo.values == 0.5)
    np.testing.assert_allclose(ds.theory_radius_disc.values, [0.25, 1.0], rtol=1e-6)
    np.testing.assert_allclose(ds.theory_radius_disc_radius.values, [0.25, 1.0])
    for name in ("disc", "disc_radius"):
        v = ds[f"theory_verdict_{name}"]
        assert int(v.sel(claim=1.0)) == UNTESTED and int(v.sel(claim=0.25)) == CONSERVATIVE
        assert np.isnan(float(ds[f"theory_factor_lo_{name}"].sel(claim=1.0)))
        assert v.attrs["flag_meanings"].split() == list(VERDICTS) and VERDICTS[UNTESTED] == "untested"
    st = ds.attrs["statement"]
    assert "shock_norm is a fatal shock found" not in st and "No fatal shock was found up to max_radius" in st
    # said as such where a user reads it: the printed summary and a point's rows (report, viewer)
    from stabjax.present import shock as SH

    assert "disc: untested (radius 1 beyond the largest shock searched, 0.5)" in SH.format_summary(ds)
    rows = dict(SH.point_rows(ds, 1))
    assert rows["theorem disc"].startswith("untested (its radius lies beyond the largest shock searched")
    assert SH.VERDICT_NAMES == VERDICTS
    # the shock-size axis names the norm in full, wrapped (cut at 90 characters, it ended mid-word)
    fig = SH.plot_shock(ds)
    label = fig.axes[0].get_ylabel()
    assert label.replace("\n", " ") == f"size of the shock, {ds.attrs['norm']}" and max(map(len, label.split("\n"))) <= 60


def test_a_region_without_edge_has_an_infinite_radius():
    """A claim larger than the predicate scan follows (2^20 max_radius) has no edge along the directions: inf."""
    ds = circle({"max_radius": 0.5, "theory": ["disc"], "refine": "none"}, params={"claim": 1e9})
    assert np.isinf(float(ds.theory_radius_disc)) and int(ds.theory_verdict_disc) == UNTESTED


@pytest.mark.parametrize("shock, field, words", [
    ({"target": ["cycle4"], "theory": ["disc"]}, "shock.theory", ("shock.target", "cycle4")),
    ({"norm": "max", "blocks": [["x0"]]}, "shock.blocks", ("'y0'", "no block")),
    ({"norm": "max", "blocks": [["x0"]], "weights": {"x0": 2.0}}, "shock.blocks", ("'y0'",)),
    ({"space": "state", "norm": "max", "blocks": [["x"]]}, "shock.blocks", ("'y'", "no block")),
])
def test_a_table_that_cannot_mean_what_it_says_is_refused(shock, field, words):
    with pytest.raises(ValidationError) as exc:
        circle({"max_radius": 5.0, **shock})
    assert exc.value.field == field and all(w in exc.value.message for w in words), exc.value.message


def test_a_state_block_may_leave_out_what_the_shock_does_not_move():
    """Shocking x0 alone moves the state's x only: a max norm measuring x alone is the whole shift, not refused."""
    from stabjax.explore.shock import base_points
    from stabjax.explore.shock_config import Norm, shock_config
    from stabjax.plan.spec import make_plan

    plan = make_plan({"system": "test_shock_t2", "name": "s", "integrate": INTEGRATE,
                      "shock": {"components": ["x0"], "space": "state", "norm": "max", "blocks": [["x"]],
                                "max_radius": 1.0}})
    cfg = shock_config(plan)
    base, _ = base_points(plan)
    norm = Norm(plan, cfg, base)
    assert float(norm(np.array([0]), np.array([[0.25]]))[0]) == pytest.approx(0.25)


def test_refused_through_the_command_line_with_status_2(tmp_path, capsys):
    from clirun import captured

    spec = tmp_path / "bad.toml"
    head = ('system = "test_shock_t2"\nname = "bad"\n[shock]\ncomponents = ["x0", "y0"]\nmax_radius = 5.0\n')
    for extra, field in (('target = ["cycle4"]\ntheory = ["disc"]\n', "shock.theory"),
                         ('norm = "max"\nblocks = [["x0"]]\n', "shock.blocks")):
        spec.write_text(head + extra)
        code, out, err = captured(capsys, "sweep", spec, "--out", tmp_path / "bad.nc", "--no-progress")
        assert code == 2 and f"error: {field}:" in err + out
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]
