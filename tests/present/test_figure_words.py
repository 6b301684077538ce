"""The paper figures speak words (issue "See it", item 3): the titles, axis labels and legends that
`stabjax reproduce NAME` and the refinement plot write carry no internal names (sweep stems such as
saakyan_region_axis, predicate or variable names such as mode1_exact or error_max_late, "system: sweep"
titles), and no legend entry is a bare equation number or symbol ("(1.21)", "(1.22): 2"). Each figure is
read as it is saved (quick runs, small grids)."""
from __future__ import annotations

import json
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from stabjax.model.registry import SYSTEMS  # noqa: E402

SNAKE = re.compile(r"(?<![\w\\{])[A-Za-z][A-Za-z0-9]*_[A-Za-z0-9_]+")  # mode1_exact, saakyan_region_axis
WORD = re.compile(r"[A-Za-z]{4,}")  # a word a reader reads (outside math text)


def _plain(text: str) -> str:
    """The text outside $...$ math (where subscripts like w_1 are notation, not names)."""
    return re.sub(r"\$[^$]*\$", " ", text)


def _texts(fig) -> dict[str, list[str]]:
    out = {"title": [], "label": [], "legend": []}
    if fig._suptitle is not None:
        out["title"].append(fig._suptitle.get_text())
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        out["title"] += [t for t in (ax.get_title(), ax.get_title("left"), ax.get_title("right")) if t]
        out["label"] += [t for t in (ax.get_xlabel(), ax.get_ylabel()) if t]
        leg = ax.get_legend()
        if leg is not None:
            title = leg.get_title().get_text()
            entries = [t.get_text() for t in leg.get_texts()]
            # entries that are values ("K = 2 N m s") are read with the legend's title ("potential gain ...")
            out["legend"] += [f"{title}: {e}" if title else e for e in entries]
    return out


def problems(fig) -> list[str]:
    texts = _texts(fig)
    bad = []
    systems = [s for s in SYSTEMS]
    for kind, items in texts.items():
        for t in items:
            plain = _plain(t)
            if SNAKE.search(plain):
                bad.append(f"{kind} names an internal variable: {t!r}")
            if any(re.search(rf"\b{re.escape(s)}:", plain) for s in systems):
                bad.append(f"{kind} is 'system: sweep': {t!r}")
            if kind in ("legend", "label") and not WORD.search(plain):
                bad.append(f"{kind} has no words: {t!r}")
    return bad


@pytest.fixture
def saved(monkeypatch):
    """Every figure saved while the test runs: {file name: problems found}."""
    seen: dict[str, list[str]] = {}
    real = Figure.savefig

    def spy(self, fname, *a, **k):
        seen[str(getattr(fname, "name", fname)).rsplit("/", 1)[-1]] = problems(self)
        return real(self, fname, *a, **k)

    monkeypatch.setattr(Figure, "savefig", spy)
    return seen


def _assert_clean(seen, expect):
    assert set(expect) <= set(seen), f"figures not drawn: {set(expect) - set(seen)}"
    bad = {k: v for k, v in seen.items() if v}
    assert not bad, bad


def test_the_checks_catch_what_the_old_figures_said():
    fig, ax = plt.subplots()
    ax.plot([0, 1], label="(1.21)")
    ax.plot([0, 1], label="l of (1.18) = 1.581")
    ax.plot([0, 1], label="theory boundary (mode1_exact)")
    ax.legend()
    ax.set_title("saakyan_region_axis")
    ax.set_ylabel("error_max_late at t1")
    found = problems(fig)
    assert len(found) == 5, found
    fig2, ax2 = plt.subplots()
    ax2.set_title("gyrodyne: gyrodyne_eps_gain  (t1 = 6000)")
    ax2.plot([0, 1], label=r"bound of Cor. 2, eq. (1.18): $\rho$ = 1.581")
    ax2.legend()
    assert [p.split(":")[0] for p in problems(fig2)] == ["title names an internal variable", "title is 'system"]
    plt.close("all")


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the same figure code as test_saakyan_figures
def test_at2019_figures(saved, tmp_path):
    from stabjax.reproduce import at2019

    at2019.alpha_horizons(tmp_path, quick=True)
    at2019.decay_laws(tmp_path, quick=True)
    _assert_clean(saved, ["alpha_sweep.png", "decay_laws.png"])


def test_saakyan_figures(saved, tmp_path, monkeypatch):
    """The quick run's figures. The example panels' words do not depend on the trajectories drawn: those are
    stand-ins here (the quick run with its real trajectories is tests/systems/test_saakyan_sweeps.py::
    test_reproduce_quick's, which checks what they show); the region sweep is run as the quick run runs it."""
    from stabjax.reproduce import load_shipped, saakyan, shipped_specs

    assert set(saakyan.TITLES) == set(shipped_specs("saakyan_"))  # every shipped map is titled in words
    drawn = []

    def stand_in(name, over, *, t1, ts, **_kw):
        drawn.append(name)
        e = np.exp(-np.asarray(ts) / 10.0)
        return xr.Dataset({"error": ("t", e), "angle": ("t", 0.5 * e)}, coords={"t": np.asarray(ts)})

    monkeypatch.setattr(saakyan, "simulate", stand_in)
    saakyan.run(tmp_path, quick=True)
    assert len(drawn) == len(saakyan.QUICK_EXAMPLES)  # every example panel was drawn
    _assert_clean(saved, ["saakyan_examples.png", "saakyan_region_generic.png", "saakyan_region_generic_fraction.png"])
    assert load_shipped("saakyan_region_generic")  # the quick run drew the shipped spec's figures


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the same figure code as test_saakyan_figures
def test_twobody_figures(saved, tmp_path):
    from stabjax.reproduce import twobody

    twobody.run(tmp_path, quick=True)
    _assert_clean(saved, ["b_rate_map.png", "random_starts.png"])


def test_gyrodyne_maps(saved, tmp_path):
    """The map of each shipped gyrodyne sweep, on a synthetic result of the same axes (no integration)."""
    from stabjax.reproduce import gyrodyne, load_shipped, shipped_specs
    from stabjax.plan.spec import make_plan

    assert set(gyrodyne.TITLES) == set(shipped_specs("gyrodyne_"))
    rng = np.random.default_rng(0)
    for stem in shipped_specs("gyrodyne_"):
        plan = make_plan(load_shipped(stem))
        dims = [ax.name for ax in plan.grid]
        coords = {ax.name: (ax.name, np.asarray(ax.values, float), {"spec_key": ax.key, "long_name": ax.param.doc,
                                                                    "units": ax.param.unit, "log_axis": 0})
                  for ax in plan.grid}
        shape = tuple(len(ax.values) for ax in plan.grid)
        margin = rng.normal(size=shape)
        doc = gyrodyne.get_system("gyrodyne").theory(gyrodyne.get_system("gyrodyne").params.resolve()) \
            .predicates["mode1_exact"].doc
        ds = xr.Dataset({"verdict": (dims, rng.integers(0, 4, size=shape).astype(np.int8)),
                         "error_t1": (dims, np.abs(margin)),
                         "theory_mode1_exact": (dims, (margin > 0).astype(np.int8), {"long_name": doc}),
                         "margin_mode1_exact": (dims, margin)}, coords=coords)
        ds.attrs.update(system="gyrodyne", sweep_name=stem, theory_main="mode1_exact",
                        fixed_params_json=json.dumps({}), integrate_json=json.dumps({"t1": 6000.0}),
                        spec_json=json.dumps(load_shipped(stem)))
        gyrodyne.plot_map(ds, stem, tmp_path)
    _assert_clean(saved, [f"{s}.png" for s in shipped_specs("gyrodyne_")])


def test_refine_figure(saved, results, tmp_path):
    """The figure of a 2-D refinement of a paper system: the one the report, view and plot tests read (see_results.py,
    monoaxial on a 3 x 3 grid of alpha and sigma), built once for them all."""
    from stabjax.present.kit import open_result
    from stabjax.present.refinement import plot_refine

    ds = open_result(results["refine"])
    assert ds.attrs["kind"] == "refine" and ds.attrs["n_segments"] > 0
    plot_refine(ds, tmp_path / "tiny_refine.png")
    _assert_clean(saved, ["tiny_refine.png"])
