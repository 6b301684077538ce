"""docs/models/ documents every registered system: each predicate that `stabjax theory` reports and
each parameter appear on the system's page, and no page, docstring or help text points outside the
repository (the English specification the models were first written from is not shipped)."""
import re
from pathlib import Path

import pytest

from stabjax.model.registry import SYSTEMS, get_system

ROOT = Path(__file__).resolve().parents[2]
PAGES = {"monoaxial": "monoaxial", "saakyan": "saakyan", "twobody": "twobody", "gyrodyne": "gyrodyne"}


def _page(system: str) -> str:
    stem = next(v for k, v in PAGES.items() if system.startswith(k))
    return (ROOT / "docs" / "models" / f"{stem}.md").read_text()


@pytest.mark.parametrize("name", list(SYSTEMS))
def test_page_names_every_predicate_and_parameter(name):
    system = get_system(name)
    text = _page(name)
    assert f"`{name}`" in text
    missing = [p.name for p in system.params.params if f"`{p.name}`" not in text]
    assert not missing, f"parameters not documented: {missing}"
    theory = system.theory(system.params.resolve())
    missing = [k for k in theory.predicates if f"`{k}`" not in text]
    assert not missing, f"predicates not documented: {missing}"


def test_nothing_points_outside_the_repository():
    bad = re.compile(r"MODELS\.md|\.\./shared|shared/seeds")
    files = [*(ROOT / "docs").rglob("*.md"), ROOT / "README.md", *(ROOT / "stabjax").rglob("*.toml"),
             *(ROOT / "stabjax").rglob("*.py")]
    offenders = [f"{f.relative_to(ROOT)}:{i}" for f in files for i, line in enumerate(f.read_text().splitlines(), 1)
                 if bad.search(line)]
    assert not offenders, offenders


def test_every_page_is_linked_from_the_readme_and_the_index():
    readme = (ROOT / "README.md").read_text()
    index = (ROOT / "docs" / "models" / "README.md").read_text()
    for stem in PAGES.values():
        assert f"docs/models/{stem}.md" in readme and f"({stem}.md)" in index
