"""A theorem held against named outcomes: ``Predicate(..., outcome=NAME)`` says which outcome it guarantees, and
the sweep counts its red flags (guaranteed, ended elsewhere) and where it is conservative (silent, ended in it).

The model is the shock example's circle, r' = -sin(pi r)/pi: the basin of the origin is exactly the disc r0 < 1,
and every start with 1 < r0 < 3 goes to the cycle r = 2. Its theorems are deliberately wrong by known amounts:
``too_big`` claims the disc r0 < 1.5 (red flags: the starts with 1 < r0 < 1.5), ``too_small`` the disc r0 < 0.5
(conservative: the starts with 0.5 <= r0 < 1). Every expected count comes from r0 alone, not from stabjax.
"""
from __future__ import annotations

import numpy as np
import pytest

import stabjax
from stabjax.mapping.basin import theory_agreement

OVER = '''
import numpy as np
from stabjax import Predicate, Theory
from stabjax.examples.shock_circle.model import Circle


class Over(Circle):
    def theory(self, p):
        r0 = np.hypot(np.asarray(p["x0"], float), np.asarray(p["y0"], float))
        big, small, wide = 1.5 - r0, 0.5 - r0, 2.5 - r0
        return Theory(predicates={"too_big": Predicate(big > 0, big, "r0 < 1.5", outcome="origin"),
                                  "too_small": Predicate(small > 0, small, "r0 < 0.5", outcome="origin"),
                                  "wide": Predicate(wide > 0, wide, "r0 < 2.5", outcome="origin"),
                                  "wide_unsaid": Predicate(wide > 0, wide, "r0 < 2.5")},
                      main="too_big")
'''
SETTINGS = {"t1": 30.0, "n_checkpoints": 100}


@pytest.fixture(scope="module")
def over(tmp_path_factory):
    d = tmp_path_factory.mktemp("over")
    (d / "over.py").write_text(OVER)
    return f"{d / 'over.py'}:Over"


def _lines(ax, marker):
    return [ln for ln in ax.get_lines() if ln.get_marker() == marker]


def test_sampled_starts_count_red_flags_and_conservative_starts(over, tmp_path):
    import matplotlib.pyplot as plt

    from stabjax.present.basins import format_summary, plot_basin
    from stabjax.present.report import theory_section

    box = {"dist": "uniform", "low": -2.0, "high": 2.0}
    ds = stabjax.run_spec({"system": over, "sample": {"n": 300, "seed": 0, "x0": box, "y0": box},
                           "integrate": SETTINGS})
    x, y = ds["x0_sample"].values, ds["y0_sample"].values
    r0 = np.hypot(x, y)
    red = (r0 > 1) & (r0 < 1.5)
    assert red.sum() > 20  # the test means something
    a = theory_agreement(ds)
    assert a["guarantees"] == "origin" and a["predicate"] == "too_big"
    assert a["rows"] == {"theory: guaranteed": [int((r0 < 1).sum()), int(red.sum())],
                         "theory: silent": [0, int((r0 >= 1.5).sum())]}
    assert (a["red_flags"], a["red_flags_by_outcome"], a["conservative"], a["undecided"]) == \
           (int(red.sum()), {"cycle2": int(red.sum())}, 0, 0)
    np.testing.assert_array_equal(a["red_flag_mask"], red)

    text = format_summary(ds)
    assert f"RED FLAGS (guaranteed 'origin', ended in another outcome): {int(red.sum())} (cycle2 {int(red.sum())})" \
        in text
    header, rows, sentences = theory_section(ds)
    assert header == ["theory \\ outcome", "origin", "cycle2"] and any("RED FLAGS" in s for s in sentences)

    fig = plot_basin(ds)
    ax = fig.axes[0]
    (crosses,) = _lines(ax, "x")  # one cross per red flag, at its start
    got = sorted(zip(*crosses.get_data()))
    assert got == sorted(zip(x[red], y[red]))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "theory boundary: r0 < 1.5" in labels and any(t.startswith("red flag") for t in labels)
    plt.close(fig)

    from stabjax.present.viewmodel import Result, agreement_html

    path = tmp_path / "over.nc"
    ds.to_netcdf(path)
    page = agreement_html(Result(path))  # the viewer said "this system states no theorem here"
    assert "states no theorem" not in page and "RED FLAGS (guaranteed &#x27;origin&#x27;" in page

    ds.attrs["theory_main"] = "too_small"  # the other theorem: silent where the origin is still reached
    b = theory_agreement(ds)
    assert (b["red_flags"], b["conservative"]) == (0, int(((r0 >= 0.5) & (r0 < 1)).sum()))
    assert b["conservative"] > 20

    del ds["theory_too_small"].attrs["guarantees"]  # a theorem that names no outcome: the table alone
    c = theory_agreement(ds)
    assert "red_flags" not in c and c["rows"]["theory: silent"] == [int(((r0 >= 0.5) & (r0 < 1)).sum()),
                                                                     int((r0 >= 1).sum())]
    assert "names no outcome it guarantees" in theory_section(ds)[2][1] and "RED FLAGS" not in format_summary(ds)


def test_a_lattice_of_starts_marks_each_red_cell_and_draws_the_boundary(over):
    """One trajectory per cell: a cross on each cell the theorem guarantees that ends on the cycle, the
    boundary r0 = 1.5 as a contour (the grid avoids r0 = 1 and 1.5 exactly: 4/14 x sqrt(n) is neither)."""
    import matplotlib.pyplot as plt

    from stabjax.present.basins import plot_basin

    g = {"start": -2.0, "stop": 2.0, "num": 15}
    ds = stabjax.run_spec({"system": over, "grid": {"x0": g, "y0": g}, "integrate": SETTINGS})
    X, Y = np.meshgrid(ds["x0"].values, ds["y0"].values, indexing="ij")
    r0 = np.hypot(X, Y)
    red = (r0 > 1) & (r0 < 1.5)
    a = theory_agreement(ds)
    assert a["red_flags"] == int(red.sum()) > 0 and a["conservative"] == 0
    fig = plot_basin(ds)
    ax = fig.axes[0]
    (crosses,) = _lines(ax, "x")
    # the map draws the grid's second axis horizontally (as the verdict map does)
    assert sorted(zip(*crosses.get_data())) == sorted(zip(Y[red], X[red]))
    assert ax.collections and any("theory boundary" in t.get_text() for t in ax.get_legend().get_texts())
    plt.close(fig)


def test_starts_sampled_along_one_axis_show_the_boundary_and_each_red_flag(over):
    """Starts sampled along x0 alone (y0 = 0, so r0 = |x0|): the picture was a bar chart only, with no theorem on
    it (the summary counted the red flags). Now each start sits at its outcome's row along x0, the boundary of
    r0 < 1.5 is the two vertical lines x0 = -1.5 and 1.5 (zeros of the margin between neighbouring starts), and a
    cross marks each red flag: the starts with 1 < |x0| < 1.5, at the cycle's row."""
    import matplotlib.pyplot as plt

    from stabjax.present.basins import plot_basin

    ds = stabjax.run_spec({"system": over, "params": {"y0": 0.0},
                           "sample": {"n": 200, "seed": 1, "x0": {"dist": "uniform", "low": -2.0, "high": 2.0}},
                           "integrate": SETTINGS})
    x = ds["x0_sample"].values
    red = (np.abs(x) > 1) & (np.abs(x) < 1.5)
    assert theory_agreement(ds)["red_flags"] == int(red.sum()) > 5
    fig = plot_basin(ds)
    ax = fig.axes[0]
    (crosses,) = _lines(ax, "x")
    names = ds["outcome"].attrs["flag_meanings"].split()
    assert sorted(zip(*crosses.get_data())) == sorted((float(v), names.index("cycle2")) for v in x[red])
    vertical = sorted(ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_marker() != "x")
    spacing = np.max(np.diff(np.sort(x)))  # the crossing lies between two neighbouring starts
    assert len(vertical) == 2 and abs(vertical[0] + 1.5) < spacing and abs(vertical[1] - 1.5) < spacing, vertical
    assert any("theory boundary: r0 < 1.5" == t.get_text() for t in ax.get_legend().get_texts())
    plt.close(fig)


def test_refinement_compares_the_theorem_with_the_outcome_it_guarantees(over):
    """A refinement's theorem distance is taken along the boundary of the outcome the main theorem guarantees
    (no [refine] stable needed); an explicit one still wins."""
    from stabjax.explore.refine_config import refine_config
    from stabjax.plan.spec import make_plan

    base = {"system": over, "grid": {"x0": {"start": 0.05, "stop": 2.95, "num": 9}}, "integrate": SETTINGS}
    assert refine_config(make_plan({**base, "refine": {"tol": {"x0": 0.01}}})).stable == "origin"
    assert refine_config(make_plan({**base, "refine": {"tol": {"x0": 0.01}, "stable": "cycle2"}})).stable == "cycle2"


def test_a_shock_search_holds_a_theorem_only_against_the_attractor_it_guarantees(over):
    """Shocked off the cycle r = 2 (start (2, 0)), the minimal fatal shock is 1 (to r = 1 or r = 3). A disc
    r0 < 2.5 that guarantees the origin says nothing of the cycle's basin: not applicable; the same disc naming
    no outcome is read as a claim about the attractor shocked, and the fatal witness inside it refutes it."""
    from stabjax.explore.shock_result import VERDICTS

    ds = stabjax.shock_spec({"system": over, "params": {"x0": 2.0, "y0": 0.0}, "integrate": SETTINGS,
                           "shock": {"components": ["x0", "y0"], "max_radius": 1.5, "directions": 8,
                                     "theory": ["wide", "wide_unsaid"]}})
    assert abs(float(ds["shock_norm"]) - 1.0) < 0.05
    assert VERDICTS[int(ds["theory_verdict_wide"])] == "not_applicable"
    assert VERDICTS[int(ds["theory_verdict_wide_unsaid"])] == "refuted"


def test_a_guaranteed_outcome_the_result_does_not_have_is_said_and_counts_nothing(over, tmp_path, capsys):
    """The spec's [outcomes] replace the model's, so 'origin' is no outcome of the result: the sweep wrote its file
    and then died on a KeyError (exit 1), and report, plot and view crashed on that file. Now the table is shown
    and the theorem's guarantee said to be absent, nothing counted."""
    from clirun import captured

    from stabjax.present.basins import format_summary

    spec = tmp_path / "s.toml"
    spec.write_text(f'system = "{over.replace(chr(92), "/")}"\nname = "renamed"\n[integrate]\nt1 = 30.0\n'
                    'n_checkpoints = 100\n[sample]\nn = 60\nseed = 0\n'
                    'x0 = {dist = "uniform", low = -2.0, high = 2.0}\ny0 = {dist = "uniform", low = -2.0, high = 2.0}\n'
                    '[outcomes]\nrules = {inner = "max(r) < 0.5", outer = "abs(mean(r) - 2) < 0.5"}\nwindow = 0.2\n')
    out = tmp_path / "r.nc"
    code, text, err = captured(capsys, "sweep", spec, "--out", out, "--no-progress")
    assert code == 0, err
    assert "'origin', which is not an outcome of this result" in text and "RED FLAGS" not in text
    ds = stabjax.open_result(out)
    a = theory_agreement(ds)
    assert a["absent"] and "red_flags" not in a and "not an outcome of this result" in format_summary(ds)
    for cmd in (("report", out), ("plot", out, "--out", tmp_path / "again.png")):
        code, _, err = captured(capsys, *cmd)
        assert code == 0, err
