"""`stabjax report RESULT` (issue 24, item 2): one self-contained HTML page per result kind, with
provenance read from the result, S ± SE and Wilson intervals, inlined figures, theory agreement
and warnings."""
import base64
import re
from html.parser import HTMLParser

import numpy as np
import pytest
import xarray as xr

from clirun import status  # noqa: E402
from stabjax.mapping.basin import basin_stats
from stabjax.present.kit import kind, open_result
from stabjax.present.report import warnings


def run_cli(*args):
    return status(*args)


class _Page(HTMLParser):
    """Collects what a browser would fetch: every src/href, and the text."""

    def __init__(self):
        super().__init__()
        self.links, self.text, self.imgs = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("src", "href"):
            if key in a:
                self.links.append(a[key])
        if tag == "img":
            self.imgs.append(a["src"])

    def handle_data(self, data):
        self.text.append(data)


def _page(path):
    p = _Page()
    p.feed(path.read_text())
    return p, " ".join(p.text)


@pytest.mark.parametrize("which", ["verdicts", "basin", "refine"])
def test_report_of_every_result_kind_is_one_self_contained_page(results, which, tmp_path, capsys):
    res = results[which]
    out = tmp_path / f"{which}.html"
    assert run_cli("report", str(res), "--out", str(out)) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    ds = open_result(res)
    assert kind(ds) == which
    page, text = _page(out)
    # nothing to fetch: every image is inlined PNG data, no other link
    assert page.imgs and all(src.startswith("data:image/png;base64,") for src in page.imgs)
    assert all(link.startswith("data:") for link in page.links)
    for src in page.imgs:
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    # what was run: from the result's attributes
    for key in ("model_sha256", "fingerprint", "git_commit", "created"):
        assert str(ds.attrs[key]) in text, key
    assert ds.attrs["system"] in text and "jax" in text and "What was run" in text
    assert "Theory agreement" in text and "Warnings" in text


def test_report_outcome_table_has_s_se_and_wilson_of_the_result(results, tmp_path):
    out = tmp_path / "b.html"
    assert run_cli("report", str(results["basin"]), "--out", str(out)) == 0
    ds = open_result(results["basin"])
    names = str(ds["outcome"].attrs["flag_meanings"]).split()
    st = basin_stats(np.asarray(ds["outcome"].values)[None, :], len(names))
    _, text = _page(out)
    for k, name in enumerate(names):
        row = (f"{name} {int(st['count'][0, k])} {st['fraction'][0, k]:.4f} ± {st['se'][0, k]:.4f} "
               f"[{st['ci_low'][0, k]:.4f}, {st['ci_high'][0, k]:.4f}]")
        assert row in re.sub(r"\s+", " ", text), row


def test_report_theory_agreement_counts_match_the_map(results, tmp_path):
    """The page's theory x simulation table, red flags and conservative count are those of the result's own
    variables, counted here with plain numpy: the verdict at t1 (the last horizon) against the main
    predicate's flag (theory_guaranteed), over every grid cell."""
    out = tmp_path / "v.html"
    assert run_cli("report", str(results["verdicts"]), "--out", str(out)) == 0
    ds = open_result(results["verdicts"])
    assert ds.attrs["theory_main"] == "guaranteed"
    v = np.asarray(ds["verdict"].values)[..., -1].ravel()  # verdict at t1
    ok = np.asarray(ds["theory_guaranteed"].values).ravel().astype(bool)
    names = ["converged", "flipped", "diverged", "undecided", "failed"]
    rows = {"theory: guaranteed": [int(((v == i) & ok).sum()) for i in range(5)],
            "theory: silent": [int(((v == i) & ~ok).sum()) for i in range(5)]}
    red = int((ok & ((v == names.index("flipped")) | (v == names.index("diverged")))).sum())
    conservative = int((~ok & (v == names.index("converged"))).sum())
    assert sum(map(sum, rows.values())) == v.size == 20
    _, text = _page(out)
    text = re.sub(r"\s+", " ", text)
    assert "theory \\ simulation " + " ".join(names) in text
    for row, vals in rows.items():
        assert f"{row} " + " ".join(str(x) for x in vals) in text, row
    assert f"Red flags (theory guarantees stability, simulation flipped or diverged): {red}" in text
    assert f"Theory conservative (silent, simulation converged): {conservative}" in text


def test_report_warnings_name_unclassified_failures_and_horizon_changes(results):
    ds = open_result(results["verdicts"])
    v = ds["verdict"].values
    changed = int((v[..., -1] != v[..., -2]).sum())
    ws = " ".join(warnings(ds))
    assert (f"{changed} of {v[..., -1].size} verdicts differ" in ws) == (changed > 0)
    # a solver failure and an unclassified majority are called out with their counts
    bad = ds.copy(deep=True)
    bad["solver_status"].values.flat[0] = 1
    bad["outcome"].values[...] = 3  # 'undecided' (outcomes are the verdicts here)
    ws = " ".join(warnings(bad))
    assert "1 of 20 trajectories ended with a solver failure" in ws
    assert "100.0% of the trajectories are 'undecided'" in ws


def test_report_warns_when_the_model_file_changed(results, tmp_path):
    ds = open_result(results["basin"])
    model = tmp_path / "model.py"
    model.write_text("# edited\n")
    ds.attrs["model_file"] = str(model)
    assert any("has changed since this result was computed" in w for w in warnings(ds))


def test_report_refuses_what_it_must_not_overwrite(results, tmp_path, capsys):
    res = results["verdicts"]
    assert run_cli("report", str(res), "--out", str(res)) == 2  # its input
    assert "error: --out:" in capsys.readouterr().err
    other = tmp_path / "notes.html"
    other.write_text("my notes")
    assert run_cli("report", str(res), "--out", str(other)) == 2
    assert other.read_text() == "my notes"
    assert run_cli("report", str(res), "--out", str(tmp_path / "x.pdf")) == 2
    foreign = tmp_path / "foreign.nc"
    foreign.write_bytes(b"not netcdf")
    capsys.readouterr()
    assert run_cli("report", str(foreign)) == 2
    assert capsys.readouterr().err.startswith("error: file:")
    # through the API: a dataset that is no result is refused by name (it was an AttributeError in render)
    from stabjax import write_report
    from stabjax.errors import ValidationError

    with pytest.raises(ValidationError, match="not a stabjax result") as info:
        write_report(xr.Dataset(), tmp_path / "e.html")
    assert info.value.field == "result" and not (tmp_path / "e.html").exists()


def _with_unclassified(ds, per_point: dict[float, int]):
    """The along-T basin result with every start 'fixed_point' except ``per_point[T]`` 'unclassified' ones."""
    names = str(ds["outcome"].attrs["flag_meanings"]).split()
    bad = ds.copy(deep=True)
    code = np.full(bad["outcome"].shape, names.index("fixed_point"), bad["outcome"].dtype)
    for T, n in per_point.items():
        code[list(np.isclose(bad["T"].values, T)).index(True), :n] = names.index("unclassified")
    bad["outcome"].values[...] = code
    return bad


def test_report_warns_per_grid_point_and_names_the_points(results):
    """Issue 29: 12 % unclassified at one grid point printed "Warnings: None" because the share pooled over the
    grid was small. Here 2 of 16 starts at T = 0.3 (12.5 %) and none elsewhere pool to 2 / 48 = 4.2 %, below
    the 5 % threshold: the warning names T = 0.3 with its share; with 1 of 16 more at T = 0.7 (6.2 %) both
    points are named, the larger share first; with 0 of 16 anywhere there is no warning."""
    ds = open_result(results["along"])
    assert ds.sizes["sample"] == 16 and list(ds["T"].values) == [0.3, 0.5, 0.7]
    ws = [w for w in warnings(_with_unclassified(ds, {0.3: 2})) if "unclassified" in w]
    assert len(ws) == 1 and "At 1 of 3 grid points more than 5% of the trajectories are 'unclassified': " \
                            "T = 0.3 (12.5%)." in ws[0]
    ws = [w for w in warnings(_with_unclassified(ds, {0.3: 2, 0.7: 1})) if "unclassified" in w]
    assert len(ws) == 1 and "At 2 of 3 grid points" in ws[0] and "T = 0.3 (12.5%); T = 0.7 (6.2%)." in ws[0]
    assert not [w for w in warnings(_with_unclassified(ds, {})) if "unclassified" in w]


def test_report_of_a_discovery_says_where_each_attractor_lies(discovery, tmp_path):
    """Two fixed points that only their location tells apart (the pendulum's rest point in two wells of the
    cylinder, theta* = asin(T/K) and theta* + 2 pi): the page's table names each with its representative's state."""
    from stabjax.present.report import write_report

    out = write_report(discovery, tmp_path / "d.html", source="d.nc")
    _, text = _page(out)
    text = re.sub(r"\s+", " ", text)
    n1, n2 = (int(c) for c in discovery["attractor_count"].values)
    assert "Attractors found" in text
    assert f"fixed_point_1 fixed point {n1} - at theta = 0.5236, omega = 0" in text  # pi/6
    assert f"fixed_point_2 fixed point {n2} - at theta = 6.807, omega = 0" in text  # pi/6 + 2 pi


def test_report_replaces_its_own_page_and_no_other_file(results, tmp_path, capsys):
    """Issue 29: `stabjax report R.nc` replaced any R.html (a user's notes among them) because "its own
    previous page" was decided from the file name. Now from the page's stamp: a user's R.html is refused
    (exit 2, unchanged), replaced with --force; a page the report wrote of this result is replaced, but not
    once notes were added to it (the stamp's digest of the page no longer matches); a page it wrote of
    another result is not replaced."""
    import shutil

    res = tmp_path / "R.nc"
    shutil.copy(results["verdicts"], res)
    notes = res.with_suffix(".html")
    notes.write_text("<html>my notes</html>")
    assert run_cli("report", str(res)) == 2
    assert "error: --out:" in capsys.readouterr().err and notes.read_text() == "<html>my notes</html>"
    assert run_cli("report", str(res), "--force") == 0
    assert "my notes" not in notes.read_text()
    capsys.readouterr()
    assert run_cli("report", str(res)) == 0  # its own page, stamped: replaced without --force
    assert "replaced the previous file" in capsys.readouterr().out
    notes.write_text(notes.read_text().replace("</body>", "<p>my notes on this run</p></body>"))
    assert run_cli("report", str(res)) == 2  # edited since: the user's page now
    assert "my notes on this run" in notes.read_text()
    assert run_cli("report", str(res), "--force") == 0
    other = tmp_path / "other.html"
    assert run_cli("report", str(results["basin"]), "--out", str(other)) == 0
    page = other.read_text()
    assert run_cli("report", str(res), "--out", str(other)) == 2  # a page of another result
    assert other.read_text() == page


def test_a_theorem_is_held_against_named_outcomes():
    """The shock example's Lyapunov disc (r0 < 1 guarantees the origin; exact: the basin is that disc) against the
    outcomes of 200 starts: the page counted nothing and said "this system states no theorem" beside the theory's
    own variables. Guaranteed and origin are the starts with r0 < 1, silent and cycle2 those with 1 < r0 < 3."""
    from pathlib import Path

    import stabjax
    from stabjax.present.report import render, theory_section

    model = Path(stabjax.__file__).parent / "examples" / "shock_circle" / "model.py"
    box = {"dist": "uniform", "low": -2.0, "high": 2.0}
    ds = stabjax.run_spec({"system": f"{model}:Circle", "sample": {"n": 200, "seed": 0, "x0": box, "y0": box},
                           "integrate": {"t1": 30.0, "n_checkpoints": 100}})
    r0 = np.hypot(ds["x0_sample"].values, ds["y0_sample"].values)
    header, rows, sentences = theory_section(ds)
    assert header == ["theory \\ outcome", "origin", "cycle2"]
    inside = int((r0 < 1).sum())
    assert rows == [["theory: guaranteed", f"{inside:,}", "0"], ["theory: silent", "0", f"{r0.size - inside:,}"]]
    assert "states no theorem" not in render(ds) and "lyapunov_disc" in sentences[0]
    # the disc guarantees the origin and is the basin itself: nothing refuted, nothing conservative
    assert sentences[1:] == ["It guarantees 'origin'. Theory conservative (silent, ended in 'origin'): 0.",
                             "RED FLAGS (guaranteed 'origin', ended in another outcome): 0."]


def test_what_the_sweep_warned_is_in_the_result_and_its_page(results, tmp_path, capsys):
    """A reliability pass: what attractor discovery warned was printed on the terminal only, and the page of the
    result listed the attractors it had called into doubt without a caveat. x' = x: 20 runaways counted as
    'escaped' and said (UnboundedWarning): the terminal says it once, as before; the netCDF file and the kept
    store hold it (``warnings_json``: class and text), and the page lists it under Warnings. A result of which
    nothing was said holds an empty list and its page says so; one made before the attribute claims nothing."""
    import html
    import json
    from pathlib import Path

    import phase_line
    from clirun import captured

    from stabjax.present.report import _checked, stored_warnings

    spec = tmp_path / "runaway.toml"
    spec.write_text(f'system = "{Path(phase_line.__file__).resolve()}:PhaseLine"\nname = "runaway"\n'
                    '[params]\na = 1.0\n[sample]\nn = 20\nseed = 0\nx0 = {dist = "uniform", low = -2.0, high = 2.0}\n'
                    '[integrate]\nt1 = 20.0\nn_checkpoints = 40\n')
    out = tmp_path / "r.nc"
    code, _, err = captured(capsys, "sweep", spec, "--out", out, "--keep-store", "--no-progress", "--no-plot")
    assert code == 0 and err.count("trajectories grow without bound") == 1, err
    said = json.loads(open_result(out).attrs["warnings_json"])
    assert [w["category"] for w in said] == ["UnboundedWarning"]
    assert said[0]["message"].startswith("20 of 20 trajectories grow without bound over the feature window: "
                                         "counted as 'escaped'")
    assert json.loads(open_result(tmp_path / "r.nc.zarr").attrs["warnings_json"]) == said
    assert run_cli("report", out) == 0
    section = html.unescape(out.with_suffix(".html").read_text().split("<h2>Warnings</h2>")[1])
    assert f"UnboundedWarning: {said[0]['message']}" in section and "None:" not in section
    for which in ("basin", "verdicts"):  # nothing said by their outcome stage
        ds = open_result(results[which])
        assert ds.attrs["warnings_json"] == "[]" and stored_warnings(ds) == []
        assert not [w for w in warnings(ds) if "Warning:" in w]
        assert "no warning while the outcomes were found" in _checked(ds)
        del ds.attrs["warnings_json"]
        assert stored_warnings(ds) == [] and "no warning while the outcomes" not in _checked(ds)
