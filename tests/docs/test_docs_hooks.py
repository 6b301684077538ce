"""docs/hooks.py, without a site build: the settings tables hold every setting the code declares, a declared
setting without a stated meaning (or a stated meaning of a setting that is gone) stops the build, and the links
to repository files outside docs/ are found where GitHub would find them."""
from __future__ import annotations

import dataclasses
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def hooks():
    spec = importlib.util.spec_from_file_location("stabjax_docs_hooks", ROOT / "docs" / "hooks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _names(markdown: str) -> list[str]:
    return re.findall(r"^\| `([^`]+)` \|", markdown, re.M)


def test_tables_hold_every_declared_setting(hooks):
    from stabjax.config import IntegrateConfig, VerdictConfig
    from stabjax.engines import SETTINGS
    from stabjax.explore.refine_config import REFINE_KEYS
    from stabjax.explore.shock_config import SHOCK_KEYS
    from stabjax.model.outcomes import DiscoveryConfig, Outcomes
    from stabjax.plan.spec import TOP_KEYS

    def spec_fields(cls, section):
        return [f.name for f in dataclasses.fields(cls) if f.name not in hooks.NOT_IN_SPECS.get(section, ())]

    assert _names(hooks.table("integrate")) == spec_fields(IntegrateConfig, "integrate")
    assert _names(hooks.table("verdict")) == spec_fields(VerdictConfig, "verdict")
    assert _names(hooks.table("outcomes")) == list(Outcomes.KEYS)
    assert _names(hooks.table("discovery")) == spec_fields(DiscoveryConfig, "discovery")
    assert _names(hooks.table("refine")) == list(REFINE_KEYS)
    assert sorted(_names(hooks.table("top"))) == sorted(TOP_KEYS)
    assert _names(hooks.table("engine")) == [s.name for ss in SETTINGS.values() for s in ss]
    assert _names(hooks.table("shock")) == list(SHOCK_KEYS)
    # every meaning is a sentence of its own, none empty
    for name in ("integrate", "verdict", "outcomes", "discovery", "refine", "top", "engine", "dists", "status",
                 "shock"):
        rows = [r for r in hooks.table(name).splitlines()[2:]]
        assert rows and all(r.rstrip(" |").rsplit("|", 1)[-1].strip() for r in rows), name


def test_a_setting_without_a_meaning_stops_the_build(hooks, monkeypatch):
    from mkdocs.exceptions import PluginError

    monkeypatch.setitem(hooks.MEANINGS, "integrate", {k: v for k, v in hooks.MEANINGS["integrate"].items()
                                                      if k != "max_steps"})
    with pytest.raises(PluginError, match="max_steps"):
        hooks.table("integrate")
    monkeypatch.setitem(hooks.MEANINGS, "refine", {**hooks.MEANINGS["refine"], "gone": "a removed key"})
    with pytest.raises(PluginError, match="gone"):
        hooks.table("refine")
    with pytest.raises(PluginError, match="unknown table"):
        hooks.table("nonesuch")


def test_shock_keys_take_their_meanings_from_the_field_table(hooks, monkeypatch):
    """The [shock] table is the field table of shock_config.py's docstring, in SHOCK_KEYS' order, a continuation
    line joined to its row; a key without a row, or a row naming no key, stops the build."""
    from mkdocs.exceptions import PluginError

    from stabjax.explore import shock_config

    table = hooks.table("shock")
    settle = next(r for r in table.splitlines() if r.startswith("| `settle` |"))
    assert settle.endswith("not the start itself (default false) |")  # the row's second line, joined
    assert "| `components` | initial-condition parameters shocked (required): `[\"x0\", \"v0\"]`" in table
    doc = shock_config.__doc__
    monkeypatch.setattr(shock_config, "__doc__", re.sub(r"^``popsize``.*\n", "", doc, flags=re.M))
    with pytest.raises(PluginError, match="popsize"):
        hooks.table("shock")
    monkeypatch.setattr(shock_config, "__doc__", re.sub(r"^(``seed``.*\n)", r"\1``gone``  a removed key\n", doc,
                                                         flags=re.M))
    with pytest.raises(PluginError, match="names \\['gone'\\]"):
        hooks.table("shock")


def test_docstring_field_lists_are_read_whole(hooks):
    """The ``name   meaning`` lines of a record's docstring, with their continuation lines, and a line naming
    several fields at once (VerdictConfig's ``t0, t1, n_obs``)."""
    from stabjax.config import VerdictConfig

    docs = hooks.field_docs(VerdictConfig)
    assert set(docs) == {f.name for f in dataclasses.fields(VerdictConfig)}
    assert docs["excursion_tol"].endswith("(default acos(0.9): the paper-A analysis counts s.r < 0.9)")
    assert docs["t0"] == docs["n_obs"]


def test_cells_escape_pipes_outside_code_only(hooks):
    assert hooks._cell("max |y| and ``a |b|`` and `c|d`") == "max \\|y\\| and ``a |b|`` and `c|d`"


def test_links_to_repository_files_outside_docs(hooks):
    page = ROOT / "docs" / "guide" / "examples.md"
    text = "![a](../../examples/pendulum/pendulum.png) [b](specs.md) [c](https://x.org/a.png) ![d](../../nope.png)"
    found = [rel.as_posix() for _, rel in hooks._outside_links(page, text)]
    assert found == ["examples/pendulum/pendulum.png"]  # the link's path, not the package folder it points into
