"""Figures a paper would print (issue 24, item 3): axes in words with units, the theory's side
labelled instead of hatched over, horizon edges without one-cell islands, colour-blind-safe
horizon colours, vector output with --format."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from clirun import status  # noqa: E402
from stabjax.present.labels import words  # noqa: E402
from stabjax.present.maps import _HCOLORS, _long_paths, plot_sweep  # noqa: E402
from stabjax.run.sweep import open_result, run_spec  # noqa: E402

from see_results import VERDICT_MAP  # noqa: E402


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig") / "tiny_map.nc"
    run_spec(VERDICT_MAP, out)
    return out


def run_cli(*args):
    return status(*args)


def test_words_give_a_description_a_reader_knows():
    assert words("perturbation order sigma: Q(u) = |u x r|^(sigma-1) u x r (sigma >= 1)", "$\\sigma$") == \
        "perturbation order sigma ($\\sigma$)"
    assert words("exponent alpha in cos(omega0 t^alpha) (0 < alpha; the paper's family has alpha <= 1)", "a") == \
        "exponent alpha in cos(omega0 t^alpha) (a)"
    assert words("initial angular velocity", "w0", "rad/s") == "initial angular velocity (w0) [rad/s]"
    assert words("0: normal coordinates (1.3); 1: two-channel", "model") == "model"  # a choice list is no description
    assert words("", "x") == "x"
    assert len(words("a " * 60, "x")) < 60


def test_map_axes_and_legend_are_in_words_and_the_theory_side_is_labelled(result):
    ds = open_result(result)
    fig = plot_sweep(ds)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "perturbation order sigma ($\\sigma$)"
    assert ax.get_ylabel().startswith("exponent alpha in cos(omega0 t^alpha)")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "theory boundary: some result of the paper guarantees asymptotic stability" in labels
    assert not any(lab.endswith("(guaranteed)") for lab in labels)  # no variable names in the legend
    # no hatching over the region: the boundary line and a label on its guaranteed side say it
    assert not any(getattr(c, "get_hatch", lambda: None)() for c in ax.collections)
    (text,) = [t for t in ax.texts if "theory guarantees" in t.get_text()]
    x, y = text.get_position()
    i, j = int(np.argmin(abs(ds.alpha.values - y))), int(np.argmin(abs(ds.sigma.values - x)))
    assert ds["theory_guaranteed"].values[i, j] == 1
    plt.close(fig)


def test_horizon_edge_drops_one_cell_islands_but_keeps_the_boundary():
    y, x = np.mgrid[0:20, 0:30].astype(float)
    m = (x > 12).astype(float)  # a long straight edge ...
    m[5, 3] = 1.0  # ... and a one-cell island
    fig, ax = plt.subplots()
    cs = ax.contour(x[0], y[:, 0], m, levels=[0.5])
    before = sum(len(p.to_polygons(closed_only=False)) for p in cs.get_paths())
    _long_paths(cs, 4.0, (1.0, 1.0))
    after = [sg for p in cs.get_paths() if len(p.vertices) for sg in p.to_polygons(closed_only=False)]
    assert before == 2 and len(after) == 1
    np.testing.assert_allclose(after[0][:, 0], 12.5)  # the edge that remains is the real one
    plt.close(fig)


def test_horizon_colours_are_okabe_ito():
    assert _HCOLORS[:6] == ("#0072B2", "#D55E00", "#CC79A7", "#56B4E9", "#E69F00", "#009E73")


@pytest.mark.parametrize("fmt, magic", [("svg", b"<?xml"), ("pdf", b"%PDF")])
def test_plot_format_writes_vector_output_beside_the_png(result, fmt, magic):
    assert run_cli("plot", str(result), "--format", fmt) == 0
    out = result.with_suffix(f".{fmt}")
    assert out.read_bytes()[:5].startswith(magic)


def test_plot_format_refuses_what_does_not_fit(result, tmp_path, capsys):
    assert run_cli("plot", str(result), "--format", "jpg") == 2
    assert capsys.readouterr().err.startswith("error: --format:")
    assert run_cli("plot", str(result), "--format", "svg", "--out", str(tmp_path / "m.pdf")) == 2
    assert "does not end in .svg" in capsys.readouterr().err


def test_both_maps_of_a_sampled_2d_result_put_the_same_axis_horizontal(tmp_path):
    import stabjax.present.basins as B

    spec = {"system": "monoaxial", "name": "sampled2d", "params": {"mu": 1.5},
            "grid": {"alpha": [0.4, 0.8], "sigma": [1.3, 1.4, 1.5]},
            "sample": {"n": 4, "seed": 0, "w0": {"dist": "ball", "radius": 0.1}},
            "integrate": {"t1": 50.0, "n_checkpoints": 64}}
    ds = run_spec(spec)
    fig = plot_sweep(ds)
    x_sweep = fig.axes[0].get_xlabel()
    plt.close(fig)
    fig = B.plot_basin(ds)  # the dominant-outcome map of the same cells
    assert fig.axes[0].get_xlabel() == x_sweep == "perturbation order sigma ($\\sigma$)"
    plt.close(fig)
