"""One plot for every result (issue 30, item 4; issue 29): ``stabjax.plot`` and ``stabjax plot`` draw every kind
of result that ``report`` and ``view`` accept, the verdict-only functions refuse other results by name, a
discovered attractor is named with where it lies, and a figure replaces only a figure of the same result."""
import re
import shutil

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import stabjax  # noqa: E402
from clirun import captured, status  # noqa: E402
from stabjax.errors import ValidationError  # noqa: E402
from stabjax.present import kit  # noqa: E402
from stabjax.run.outputs import is_own_output, output_stamp, spec_digest_of  # noqa: E402


def test_the_public_api_offers_one_plot_and_one_opener():
    from stabjax.present import show

    assert "plot" in stabjax.__all__ and stabjax.plot is show.plot
    assert stabjax.open_result is kit.open_result
    assert stabjax.open_result.__doc__ and "chunk store" in stabjax.open_result.__doc__


@pytest.mark.parametrize("which, kind, layout", [("verdicts", "verdicts", "cells"), ("basin", "basin", "samples"),
                                                 ("along", "basin", "along"), ("refine", "refine", "points")])
def test_plot_draws_every_kind_of_result_and_stamps_it(results, which, kind, layout, tmp_path):
    """Each kind is drawn from its file (the figure is returned and written, folders made); the image carries
    the stamp naming the result it shows (its path's digest and its spec's), read back from the file."""
    ds = stabjax.open_result(results[which])
    assert (kit.kind(ds), kit.layout(ds)) == (kind, layout)
    out = tmp_path / "new" / f"{which}.png"
    fig = stabjax.plot(results[which], out)
    assert fig.axes and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    stamp = output_stamp(out)
    assert stamp["source"] == str(results[which].resolve()) and stamp["spec"] == spec_digest_of(ds) is not None
    assert is_own_output(out, results[which]) and is_own_output(out, spec=spec_digest_of(ds))
    labels = [t for ax in fig.axes for t in (ax.get_xlabel(), ax.get_ylabel()) if t]
    assert labels and not any(re.fullmatch(r"\w+", t) for t in labels)  # axes in words, not bare names
    plt.close("all")


def test_plot_of_a_dataset_in_memory_returns_the_figure_without_writing(results, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    fig = stabjax.plot(stabjax.open_result(results["refine"]), title="where converged meets the rest")
    assert fig.axes[0].get_title().startswith("where converged meets the rest")
    assert not list(tmp_path.iterdir())
    plt.close("all")


def test_verdict_only_functions_refuse_other_results_by_name(results):
    """Issue 29: plot_sweep(ds) and confusion(ds), the README's imports, raised KeyError('verdict') on a user
    model's result; now a ValidationError that points to the entry point drawing every kind."""
    from stabjax.present.maps import confusion, plot_sweep

    ds = stabjax.open_result(results["basin"])
    for fn in (plot_sweep, confusion):
        with pytest.raises(ValidationError, match=r"named outcomes: draw it with stabjax\.plot\(result\)"):
            fn(ds)


def test_a_discovered_attractor_is_named_with_where_it_lies(discovery, tmp_path):
    """Two fixed points told apart only by their location (pi/6 and pi/6 + 2 pi on the pendulum's cylinder):
    the plot's legend, the printed summary and the kit say where each representative ended."""
    from stabjax.present.show import summary

    assert kit.kind(discovery) == "discovery"
    assert kit.where_of(discovery) == {"fixed_point_1": "at theta = 0.5236, omega = 0",
                                       "fixed_point_2": "at theta = 6.807, omega = 0"}
    fig = stabjax.plot(discovery)
    legend = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert "fixed_point_1 at theta = 0.5236, omega = 0" in legend
    assert "fixed_point_2 at theta = 6.807, omega = 0" in legend
    plt.close("all")
    text = summary(discovery)
    n1, n2 = (int(c) for c in discovery["attractor_count"].values)
    assert re.search(rf"fixed_point_1\s+{n1} trajectories; at theta = 0.5236, omega = 0", text)
    assert re.search(rf"fixed_point_2\s+{n2} trajectories; at theta = 6.807, omega = 0", text)


def test_stabjax_plot_draws_a_refinement_it_used_to_refuse(results, tmp_path, capsys):
    res = tmp_path / "ref.nc"
    shutil.copy(results["refine"], res)
    code, out, _ = captured(capsys, "plot", str(res))
    assert code == 0 and "boundary segments" in out and f"wrote {res.with_suffix('.png')}" in out
    assert is_own_output(res.with_suffix(".png"), res)


@pytest.mark.parametrize("fmt", ["png", "svg", "pdf"])
def test_plot_replaces_its_own_figure_and_no_other_file(results, fmt, tmp_path, capsys):
    """Issue 29: `stabjax plot R.nc` replaced any R.png because "its own previous map" was decided from the
    name. Now from the stamp in the file, in every format: a user's file is refused (exit 2, unchanged) and
    replaced with --force; a figure of this result is replaced; a figure of another result is refused."""
    res = tmp_path / "R.nc"
    shutil.copy(results["verdicts"], res)
    fig = res.with_suffix(f".{fmt}")
    fig.write_bytes(b"a user's own figure")
    args = ["plot", str(res), "--format", fmt]
    code, _, err = captured(capsys, *args)
    assert code == 2 and "error: --out:" in err and fig.read_bytes() == b"a user's own figure"
    assert status(*args, "--force") == 0 and fig.read_bytes() != b"a user's own figure"
    code, out, _ = captured(capsys, *args)
    assert code == 0 and "replaced the previous file" in out  # its own figure
    other = tmp_path / f"other.{fmt}"
    assert status("plot", str(results["basin"]), "--out", str(other)) == 0
    before = other.read_bytes()
    assert status("plot", str(res), "--out", str(other)) == 2  # a figure of another result
    assert other.read_bytes() == before


def test_a_running_store_is_opened_for_the_viewer_and_refused_by_plot(tmp_path):
    from see_results import VERDICT_MAP

    from stabjax.run.sweep import run_spec

    out = tmp_path / "r.nc"

    def stop_after_first(i, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(VERDICT_MAP, out, batch_size=5, on_chunk=stop_after_first)
    store = tmp_path / "r.nc.zarr"
    ds = stabjax.open_result(store)
    assert int(ds["pending"].sum()) == 16 and ds.attrs["store_chunks"] == "1/5"
    with pytest.raises(ValidationError, match="running or interrupted sweep"):
        stabjax.plot(ds)
    with pytest.raises(ValidationError, match=r"1 of 5 chunks finished: watch it with stabjax view"):
        stabjax.plot(store)
    assert status("plot", str(store)) == 2 and not (tmp_path / "r.png").exists()
    with pytest.raises(ValidationError, match=r"^result: not found: .*gone\.nc"):
        stabjax.open_result(tmp_path / "gone.nc")
    np.testing.assert_array_equal(kit.codes(ds)[:4], ds["outcome"].values.ravel()[:4])


def test_a_store_that_is_gone_points_to_the_result_its_sweep_wrote(tmp_path):
    """`stabjax view R.nc.zarr` after the sweep finished (and removed its store) says where the result is."""
    (tmp_path / "r.nc").write_bytes(b"the result")
    assert kit.finished_file(tmp_path / "r.nc.zarr") == tmp_path / "r.nc"
    assert kit.finished_file(tmp_path / "mine") is None
    with pytest.raises(ValidationError, match=r"its sweep has finished: the result is .*r\.nc\)"):
        stabjax.open_result(tmp_path / "r.nc.zarr")
    assert status("view", str(tmp_path / "r.nc.zarr"), "--no-browser") == 2
