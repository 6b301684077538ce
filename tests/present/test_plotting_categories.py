"""Figures a reader understands at a glance: discrete-choice axes (model variant, active set, failed
gyroscope) drawn as labelled categories, titles naming the fixed parameters the theorems use, and a
note of what one cell is. Synthetic datasets with the attributes a sweep writes (no integration)."""
import json

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from stabjax.present import labels as L  # noqa: E402
from stabjax.present import maps as P  # noqa: E402


def _dataset(system, axes, fixed, main, doc, sample=None, spec_params=None):
    dims = [d for d, _, _ in axes] + (["sample"] if sample else [])
    shape = [len(v) for _, v, _ in axes] + ([sample] if sample else [])
    coords = {d: (d, np.asarray(v, float), {"spec_key": key, "units": "", "log_axis": 0}) for d, v, key in axes}
    if sample:
        coords["sample"] = ("sample", np.arange(sample))
    rng = np.random.default_rng(0)
    verdict = rng.integers(0, 3, size=shape).astype(np.int8)
    margin = rng.normal(size=shape)
    ds = xr.Dataset({"verdict": (dims, verdict), "error_t1": (dims, np.abs(margin)),
                     f"theory_{main}": (dims, (margin > 0).astype(np.int8), {"long_name": doc}),
                     f"margin_{main}": (dims, margin)}, coords=coords)
    ds.attrs.update(system=system, sweep_name="test", theory_main=main, fixed_params_json=json.dumps(fixed),
                    integrate_json=json.dumps({"t1": 100.0}),
                    spec_json=json.dumps({"system": system, "params": spec_params or {}}))
    return ds


def test_choice_labels_from_help_text():
    assert L._choice_labels("0: normal coordinates (1.3); 1: two-channel quasi-linear (1.2); 2: full nonlinear",
                            [0, 1, 2]) == ["normal coordinates", "two-channel quasi-linear", "full nonlinear"]
    # a value the help does not name, or labels that collide, fall back (None)
    assert L._choice_labels("0: a; 1: b", [0, 2]) is None
    assert L._choice_labels("0: same, x; 1: same, y", [0, 1]) is None


def test_active_set_and_model_axes_are_categories():
    ds = _dataset("gyrodyne", [("spare", [1, 2, 3, 4], "spare"), ("eps", np.linspace(-1e-3, 1e-3, 5), "eps")],
                  {"model": 1.0, "mapping": 0.0, "gain": 1.0}, "mode1_exact", "p1 < 0 and Delta_1 > 0 (eps)",
                  spec_params={"model": 1, "mapping": 0})
    assert L.categories(ds, "spare") == ["active set 2-3-4", "active set 1-3-4", "active set 1-2-4", "active set 1-2-3"]
    assert L.categories(ds, "eps") is None
    fig = P.plot_sweep(ds)
    ax = fig.axes[0]
    ticks = [t.get_text() for t in ax.get_yticklabels()]
    assert ticks == L.categories(ds, "spare")
    np.testing.assert_array_equal(ax.get_yticks(), np.arange(4))
    assert not ax.collections or all(type(c).__name__ != "QuadContourSet" for c in ax.collections)
    assert "one cell: one trajectory" in ax.get_title()
    # the spec's fixed choices are named by their meaning, not their code; untouched defaults are not listed
    assert "two-channel quasi-linear, paper mapping" in ax.get_title() and "gain" not in ax.get_title()

    one = _dataset("gyrodyne", [("model", [0, 1, 2], "model")], {}, "mode1_exact", "p1 < 0")
    ax = P.plot_sweep(one).axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["normal coordinates", "two-channel quasi-linear",
                                                           "full nonlinear 3-axis"]
    fail = _dataset("gyrodyne", [("fail", [0, 1, 2, 3], "fail"), ("t_fail", [0.0, 500.0], "t_fail")], {},
                    "mode1_exact", "p1 < 0")
    assert L.categories(fail, "fail")[0] == "no failure"


def test_default_map_title_names_mu_and_the_cell():
    doc = "Theorem 1, (7): mu > 1, Assumption 1 with some beta in (1-alpha, 1], 2 sigma >= mu + 1 + beta (mu - 1)"
    ds = _dataset("monoaxial", [("sigma", [1.2, 1.3, 1.4], "sigma"), ("alpha", [0.3, 0.6, 0.9], "alpha")],
                  {"mu": 1.5, "a": 1.0, "J": [5.0, 6.0, 4.0]}, "theorem1", doc)
    title = P.plot_sweep(ds).axes[0].get_title()
    assert r"$\mu$ = 1.5" in title and "a =" not in title and "J" not in title  # only what the theorem uses
    assert L.categories(ds, "alpha") is None
    sampled = _dataset("monoaxial", [("alpha", [0.3, 0.6, 0.9], "alpha")], {"mu": 1.5}, "theorem1", doc, sample=8)
    assert "one cell: fraction of n = 8 random starts" in P.plot_sweep(sampled).axes[0].get_title()


def test_facets_label_each_panel_by_category():
    ds = _dataset("gyrodyne", [("spare", [1, 2, 3, 4], "spare"), ("eps", [-1e-3, 0.0, 1e-3], "eps"),
                               ("A_1", [0.5, 1.0], "A[1]")], {}, "mode1_exact", "p1 < 0")
    fig = P.plot_sweep(ds)
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert any(t.endswith("active set 1-2-3") for t in titles)
