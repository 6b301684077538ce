"""Every code block of the documentation (docs/**/*.md) and of README.md runs, so no snippet goes stale.

The convention (stated for writers in docs/guide/architecture.md, "Documentation"):

* ```` ```python ```` blocks run, top to bottom, in one namespace per page, in a fresh working folder holding
  copies of the repository's ``examples/`` and ``sweeps/`` (what a reader has at the top of a clone). A block
  with ``title="PATH"`` must also be the repository's file PATH, verbatim.
* ```` ```console ```` blocks: each line ``$ stabjax ...`` runs, in process, in the same folder and in page
  order with the python blocks. The lines under a command, up to the next ``$``, are output that must
  appear in what it prints (spaces normalised). The exit status must be 0, or N where the line ends in
  ``# exit N``.
* ```` ```toml ```` blocks: with ``title="PATH"``, the file PATH verbatim; with a ``system`` key, a whole spec
  that :func:`stabjax.make_plan` accepts (nothing is integrated); otherwise a fragment whose tables are
  sections a spec knows.
* ```` ```bash ````, ```` ```text ```` and the rest are shown, not run: installation, long runs, clusters, output.

A page whose blocks take more than ~10 s carries ``<!-- docs-test: slow -->`` and runs under the slow marker.
"""
from __future__ import annotations

import re
import shlex
import shutil
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
_FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```[ \t]*$", re.M | re.S)


@dataclass
class Block:
    page: Path
    line: int
    lang: str
    title: str | None
    code: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    text = page.read_text(encoding="utf-8")
    out = []
    for m in _FENCE.finditer(text):
        title = re.search(r'title="([^"]+)"', m[2])
        out.append(Block(page, text.count("\n", 0, m.start()) + 1, m[1], title[1] if title else None, m[3]))
    return out


def _id(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


def _runs(page: Path) -> bool:
    return any(b.lang in ("python", "console") for b in blocks(page))


def _slow(page: Path) -> bool:
    return re.search(r"^<!-- docs-test: slow -->$", page.read_text(encoding="utf-8"), re.M) is not None


RUN_PAGES = [pytest.param(p, id=_id(p), marks=[pytest.mark.slow] if _slow(p) else []) for p in PAGES if _runs(p)]


def _workdir(tmp: Path) -> Path:
    """A reader's clone as far as the pages need it: examples/ and sweeps/ copied (never the repository's own
    folders, which a page's commands could write into)."""
    skip = shutil.ignore_patterns("*.nc", "*.zarr", "*.html", "__pycache__")
    for name in ("examples", "sweeps"):
        shutil.copytree(ROOT / name, tmp / name, ignore=skip)
    return tmp


def commands(code: str) -> list[tuple[list[str], int, list[str]]]:
    """(argv after ``stabjax``, expected exit status, expected output lines) of a console block."""
    out = []
    for line in code.splitlines():
        if line.startswith("$ "):
            cmd, _, comment = line[2:].partition(" # ")
            m = re.match(r"exit (\d+)$", comment.strip())
            argv = shlex.split(cmd)
            assert argv[0] == "stabjax", f"a console block runs stabjax commands only, got {line!r}"
            out.append((argv[1:], int(m[1]) if m else 0, []))
        elif line.strip():
            assert out, f"output before any command: {line!r}"
            out[-1][2].append(line)
    return out


@pytest.mark.parametrize("page", RUN_PAGES)
def test_page_runs(page, tmp_path, monkeypatch, capsys):
    """The page's python and console blocks, in order, succeed (and print the output the page shows)."""
    from clirun import captured

    monkeypatch.chdir(_workdir(tmp_path))
    monkeypatch.setenv("COLUMNS", "200")  # rich tables and messages on one line each
    namespace: dict = {"__name__": "__docs__"}
    for b in blocks(page):
        start = time.perf_counter()
        if b.lang == "python":
            try:
                exec(compile(b.code, b.where, "exec"), namespace)
            except Exception as exc:
                raise AssertionError(f"{b.where}: the block fails: {exc!r}") from exc
        elif b.lang == "console":
            for argv, want, expected in commands(b.code):
                code, out, err = captured(capsys, *argv)
                assert code == want, f"{b.where}: stabjax {shlex.join(argv)} exited {code}, not {want}: {err[-800:]}"
                for line in expected:
                    assert " ".join(line.split()) in out + " " + err, \
                        f"{b.where}: stabjax {shlex.join(argv)} did not print {line!r}; it printed {(out + err)[-800:]}"
        else:
            continue
        print(f"{b.where}: {time.perf_counter() - start:.1f} s")


def _titled():
    return [pytest.param(b, id=f"{_id(b.page)}:{b.line}") for p in PAGES for b in blocks(p) if b.title]


@pytest.mark.parametrize("block", _titled())
def test_titled_block_is_the_file(block):
    """A block titled with a path shows that file of the repository, verbatim."""
    path = ROOT / block.title
    assert path.is_file(), f"{block.where}: {block.title} is not a file of the repository"
    assert block.code == path.read_text(encoding="utf-8"), f"{block.where}: differs from {block.title}"


def _toml():
    return [pytest.param(b, id=f"{_id(b.page)}:{b.line}") for p in PAGES for b in blocks(p)
            if b.lang == "toml" and not b.title]


@pytest.mark.parametrize("block", _toml())
def test_toml_block_is_a_valid_spec(block, tmp_path, monkeypatch):
    """A spec shown on a page is one that stabjax accepts: a whole spec is planned (every field checked, nothing
    integrated); a fragment names only sections a spec knows."""
    import stabjax
    from stabjax.plan.spec import TOP_KEYS

    doc = tomllib.loads(block.code)
    unknown = set(doc) - TOP_KEYS
    assert not unknown, f"{block.where}: not sections of a spec: {sorted(unknown)}"
    if "system" in doc:
        monkeypatch.chdir(_workdir(tmp_path))
        stabjax.make_plan(doc, base_dir=tmp_path)


def test_every_page_has_its_blocks_closed():
    """An unclosed fence would hide every block after it from these tests."""
    for page in PAGES:
        fences = [ln for ln in page.read_text(encoding="utf-8").splitlines() if ln.startswith("```")]
        assert len(fences) % 2 == 0, f"{_id(page)}: an odd number of ``` fences"
        assert sum(1 for f in fences if f.strip() != "```") == len(blocks(page)), f"{_id(page)}: a fence without a language"


def test_the_runners_run_what_they_see():
    """The extraction on a page written for the purpose: a python block, a console block with its expected
    output and exit status, a titled block, a toml fragment (so a regex change cannot make the tests above
    silently see nothing)."""
    page = ROOT / "docs" / "tutorial.md"
    got = blocks(page)
    assert [b.lang for b in got].count("python") >= 5 and any(b.lang == "console" for b in got)
    assert any(b.title == "examples/pendulum/model.py" for b in got)
    assert commands("$ stabjax theory monoaxial --set mu=0.5  # exit 2\nerror: mu: must be >= 1\n") == \
        [(["theory", "monoaxial", "--set", "mu=0.5"], 2, ["error: mu: must be >= 1"])]
