"""`stabjax report RESULT` (issue 24, item 2): one self-contained HTML page per result kind, with
provenance read from the result, S ± SE and Wilson intervals, inlined figures, theory agreement
and warnings."""
import base64
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from clirun import status  # noqa: E402
from stabjax.mapping.basin import basin_stats
from stabjax.present.report import kind, warnings
from stabjax.run.sweep import open_result

from see_results import build


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return build(tmp_path_factory.mktemp("report"))


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
    from stabjax.present.maps import confusion

    out = tmp_path / "v.html"
    assert run_cli("report", str(results["verdicts"]), "--out", str(out)) == 0
    c = confusion(open_result(results["verdicts"]))
    _, text = _page(out)
    text = re.sub(r"\s+", " ", text)
    for row, vals in c["rows"].items():
        assert f"{row} " + " ".join(str(v) for v in vals) in text, row
    assert f"Red flags (theory guarantees stability, simulation flipped or diverged): {c['red_flags']}" in text
    assert f"Theory conservative (silent, simulation converged): {c['conservative']}" in text


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
