"""`stabjax reproduce NAME`: one module per paper, each with ``run(out_dir, quick=False)``.

The sweep specs they run ship inside the package (``stabjax/sweeps/*.toml``, package data) and are
read through :mod:`importlib.resources`, so ``stabjax reproduce`` works the same from a clone, an
editable install and an installed wheel. In a clone, ``sweeps/`` at the top is a link to the same
directory, for the README's commands.
"""
from __future__ import annotations

from importlib.resources import as_file, files
from importlib.resources.abc import Traversable

SPEC_SUFFIX = ".toml"


def sweeps_dir() -> Traversable:
    """The shipped sweep specs (a directory inside the installed package)."""
    return files("stabjax") / "sweeps"


def shipped_specs(prefix: str = "") -> list[str]:
    """Names (file stems) of the shipped specs starting with ``prefix``, sorted."""
    return sorted(p.name[: -len(SPEC_SUFFIX)] for p in sweeps_dir().iterdir()
                  if p.name.endswith(SPEC_SUFFIX) and p.name.startswith(prefix))


def load_shipped(name: str) -> dict:
    """The shipped spec ``name`` (stem, e.g. ``"saakyan_no_mu"``) as a dict, via :func:`stabjax.spec.load_spec`
    (so ``name`` defaults to the stem and a missing spec is a ``ValidationError`` naming it)."""
    from ..spec import load_spec

    with as_file(sweeps_dir() / f"{name}{SPEC_SUFFIX}") as path:
        return load_spec(path)
