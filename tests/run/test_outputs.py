"""Stamps: an output drawn from a result says so in its own bytes (issue 29, "outputs that overwrite
foreign files"), so a report or a plot replaces its own previous file of the same result and nothing else.

The independent checks: every stamped file is still read by a reader that knows nothing of the stamp
(PIL for PNG, the XML parser for SVG, Python's HTML parser, the PDF trailer layout), and the stamp is
rejected after any change to the file's other bytes.
"""
import html.parser
import xml.etree.ElementTree as ET
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from stabjax.run.outputs import is_own_output, output_stamp, stamp_output, write_image  # noqa: E402

PAGE = "<!DOCTYPE html>\n<html><head><title>r</title></head><body><p>S = 0.15</p></body></html>\n"


def draw(path: Path) -> None:
    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [1, 0], label="a--b")
    fig.savefig(path)
    plt.close(fig)


@pytest.fixture
def result(tmp_path):
    r = tmp_path / "R.nc"
    r.write_bytes(b"stand-in for a result")  # only its path is stamped
    return r


def test_the_same_figure_in_another_checkout_has_the_same_bytes(tmp_path):
    """The stamp records the result relative to the figure's folder: the README's map, drawn again in a user's
    clone from its own results/default.nc, is byte for byte the committed one (before, the stamp held the
    absolute path, so a fresh clone's first command left results/default.png modified). Moved together, the
    figure still names its result; a figure whose result is elsewhere still names it."""
    outs = []
    for where in ("a", "b"):
        d = tmp_path / where / "results"
        d.mkdir(parents=True)
        (d / "R.nc").write_bytes(b"stand-in for a result")
        write_image(d / "R.png", draw, d / "R.nc", spec="0123")
        outs.append(d / "R.png")
    assert outs[0].read_bytes() == outs[1].read_bytes()
    moved = tmp_path / "c"
    (tmp_path / "a").rename(moved)
    assert is_own_output(moved / "results" / "R.png", moved / "results" / "R.nc")
    assert output_stamp(moved / "results" / "R.png")["source"] == str((moved / "results" / "R.nc").resolve())
    far = tmp_path / "elsewhere" / "S.nc"
    far.parent.mkdir()
    far.write_bytes(b"another result")
    write_image(tmp_path / "S.png", draw, far)
    assert is_own_output(tmp_path / "S.png", far) and not is_own_output(tmp_path / "S.png", moved / "results" / "R.nc")


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf", ".html"])
def test_a_stamped_output_names_its_result_and_stays_a_valid_file(tmp_path, result, suffix):
    out = tmp_path / f"R{suffix}"
    if suffix == ".html":
        out.write_text(PAGE)
    else:
        draw(out)
    before = out.read_bytes()
    stamp_output(out, result)
    data = out.read_bytes()
    assert len(data) > len(before)
    assert is_own_output(out, result)
    assert output_stamp(out)["source"] == str(result.resolve())
    # the same result reached through another spelling of its path
    assert is_own_output(out, tmp_path / "." / "R.nc")
    other = tmp_path / "other.nc"
    assert not is_own_output(out, other)
    # readers that do not know the stamp still read the file
    if suffix == ".png":
        from PIL import Image

        with Image.open(out) as im:
            im.verify()  # checks every chunk's CRC
        with Image.open(out) as im, Image.open(__import__("io").BytesIO(before)) as ref:
            assert im.tobytes() == ref.tobytes()
    elif suffix == ".svg":
        root = ET.fromstring(data)
        assert root.tag.endswith("svg")
    elif suffix == ".pdf":
        assert data.startswith(b"%PDF-") and b"%%EOF" in data[-1024:]
        assert data[:len(before)] == before  # appended after %%EOF: every object offset is unchanged
    else:
        tags = []

        class P(html.parser.HTMLParser):
            def handle_starttag(self, tag, attrs):
                tags.append(tag)

        P().feed(data.decode())
        assert tags == ["html", "head", "title", "body", "p"]
        assert data.decode().lstrip().lower().startswith("<!doctype html>")


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf", ".html"])
def test_an_edited_or_unstamped_file_is_not_ours(tmp_path, result, suffix):
    out = tmp_path / f"R{suffix}"
    if suffix == ".html":
        out.write_text(PAGE)
    else:
        draw(out)
    assert not is_own_output(out, result) and output_stamp(out) is None  # a file of the same name: foreign
    stamp_output(out, result)
    data = out.read_bytes()
    if suffix == ".html":  # a user's notes added to the report
        out.write_bytes(data.replace(b"<p>S = 0.15</p>", b"<p>S = 0.15</p><p>my notes</p>"))
    else:  # one byte changed far from the stamp
        i = len(data) // 2 if suffix != ".pdf" else len(data) // 3
        out.write_bytes(data[:i] + bytes([data[i] ^ 1]) + data[i + 1:])
    assert not is_own_output(out, result) and output_stamp(out) is None
    out.write_bytes(data)
    assert is_own_output(out, result)


def test_stamping_again_keeps_one_stamp_naming_the_new_result(tmp_path, result):
    out = tmp_path / "R.png"
    draw(out)
    stamp_output(out, tmp_path / "old.nc")
    stamp_output(out, result)
    assert out.read_bytes().count(b"stabjax-output") == 1
    assert is_own_output(out, result) and not is_own_output(out, tmp_path / "old.nc")


def test_other_files_are_never_ours(tmp_path, result):
    assert not is_own_output(tmp_path / "missing.png", result)
    (tmp_path / "d.png").mkdir()
    assert not is_own_output(tmp_path / "d.png", result)
    txt = tmp_path / "R.txt"
    txt.write_text("notes")
    stamp_output(txt, result)  # an extension without a stamp: left as it is
    assert txt.read_text() == "notes" and not is_own_output(txt, result)
    fake = tmp_path / "R.svg"  # a stamp-like comment with a wrong digest
    fake.write_text('<svg xmlns="http://www.w3.org/2000/svg"><!-- stabjax-output {"source": "%s", "sha256": "0"} '
                    '--></svg>' % result.resolve())
    assert not is_own_output(fake, result)


def test_write_image_stamps_the_map_with_its_result(tmp_path, result):
    out = tmp_path / "R.svg"
    write_image(out, draw, result)
    assert is_own_output(out, result)
    assert not list(tmp_path.glob(".*tmp*")) and not list(tmp_path.glob(".*stamp"))


@pytest.fixture
def pids():
    """(a pid of a process of this host that has ended, a pid of one still running): temporary files named by them."""
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        yield dead.pid, live.pid
    finally:
        live.kill()
        live.wait()


def test_the_next_write_removes_temporary_files_of_dead_writers_only(tmp_path, pids):
    """A kill -9 while the netCDF file is written leaves ``.NAME.HOST-PID.tmp``; the next write of that file
    removes it when PID is dead on this host, and leaves every other file alone."""
    import os
    import socket

    import numpy as np
    import xarray as xr

    from stabjax.run.outputs import temp_beside
    from stabjax.run.sweep import write

    dead, live = pids
    host = socket.gethostname()
    out = tmp_path / "r.nc"
    stale = tmp_path / f".r.nc.{host}-{dead}.tmp"
    kept = [tmp_path / f".r.nc.{host}-{live}.tmp",   # a writer still running
            tmp_path / f".r.nc.elsewhere-{dead}.tmp",  # another host's: its pids are not ours to judge
            tmp_path / f".r.nc.{dead}.tmp",            # not of that form
            tmp_path / ".r.nc.notes.tmp",
            tmp_path / f".other.nc.{host}-{dead}.tmp"]  # another output's
    for f in [stale, *kept]:
        f.write_bytes(b"partial")
    assert temp_beside(out).name == f".r.nc.{host}-{os.getpid()}.tmp"
    write(xr.Dataset({"x": ("i", np.arange(3.0))}), out)
    assert not stale.exists()
    assert all(f.read_bytes() == b"partial" for f in kept)
    assert xr.load_dataset(out)["x"].values.tolist() == [0.0, 1.0, 2.0]
    assert not temp_beside(out).exists()


def test_a_figure_of_a_result_of_the_same_spec_is_ours_and_so_is_a_map_stamped_before_the_stamps(tmp_path):
    """A re-run of the same spec writes another result file: its figures are recognised by the spec's digest. The
    sweep's maps shipped before these stamps carry that digest alone (the PNG text "stabjax-spec"): still ours for
    that spec, and for no other. Written here by PIL, a writer that knows nothing of stabjax."""
    from PIL import Image, PngImagePlugin

    out = tmp_path / "map.png"
    draw(out)
    stamp_output(out, None, spec="0123456789abcdef")
    assert output_stamp(out)["source"] is None
    assert is_own_output(out, spec="0123456789abcdef") and not is_own_output(out, spec="fedcba9876543210")
    assert not is_own_output(out, tmp_path / "R.nc")  # no result file named: only the spec decides
    legacy = tmp_path / "legacy.png"
    info = PngImagePlugin.PngInfo()
    info.add_text("stabjax-spec", "0123456789abcdef")
    Image.new("RGB", (4, 4)).save(legacy, pnginfo=info)
    assert output_stamp(legacy) is None
    assert is_own_output(legacy, spec="0123456789abcdef") and not is_own_output(legacy, spec="fedcba9876543210")
    assert not is_own_output(legacy, tmp_path / "R.nc")


def test_a_killed_drawing_leaves_no_temporary_image_or_page_for_good(tmp_path, pids):
    """Figures and pages are written through ``.STEM.HOST-PID.tmp.SUFFIX``: one a kill -9 left behind stayed for
    good (the netCDF file's were cleaned); now the next drawing of that file removes the dead process's."""
    import os
    import socket

    from stabjax.run.outputs import temp_beside, write_image

    dead, live = pids
    host = socket.gethostname()
    out = tmp_path / "s.png"
    stale = tmp_path / f".s.{host}-{dead}.tmp.png"
    kept = [tmp_path / f".s.{host}-{live}.tmp.png", tmp_path / f".s.elsewhere-{dead}.tmp.png",
            tmp_path / f".s.{host}-{dead}.tmp.svg", tmp_path / f".t.{host}-{dead}.tmp.png"]
    for f in [stale, *kept]:
        f.write_bytes(b"partial")
    assert temp_beside(out, keep_suffix=True).name == f".s.{host}-{os.getpid()}.tmp.png"
    write_image(out, draw)
    assert not stale.exists() and out.read_bytes()[:4] == b"\x89PNG"
    assert all(f.read_bytes() == b"partial" for f in kept)
