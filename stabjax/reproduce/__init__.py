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
    """The shipped spec ``name`` (stem, e.g. ``"saakyan_no_mu"``) as a dict, via :func:`stabjax.plan.spec.load_spec`
    (so ``name`` defaults to the stem and a missing spec is a ``ValidationError`` naming it)."""
    from ..plan.spec import load_spec

    with as_file(sweeps_dir() / f"{name}{SPEC_SUFFIX}") as path:
        return load_spec(path)


EXAMPLE_FILES = (".toml", ".py", ".png")  # what an example folder holds: spec, model, its figure


def examples_dir() -> Traversable:
    """The shipped examples (package data; ``examples/`` at the top of a clone links here)."""
    return files("stabjax") / "examples"


def example_names() -> list[str]:
    return sorted(p.name for p in examples_dir().iterdir() if p.is_dir() and (p / "spec.toml").is_file())


def copy_examples(dest, *, force: bool = False) -> list:
    """Copy every shipped example folder into ``dest`` (``dest/<name>/spec.toml, model.py, <name>.png``).

    Read through importlib.resources so it works from a wheel. Every target is checked before
    anything is written: an existing file is a ``ValidationError`` naming it unless ``force``,
    so a user's edited copy is never overwritten by accident.
    """
    from pathlib import Path

    from ..errors import ValidationError

    dest = Path(dest)
    plan = []
    for name in example_names():
        for f in sorted(examples_dir().joinpath(name).iterdir(), key=lambda t: t.name):
            if f.is_file() and f.name.endswith(EXAMPLE_FILES):
                plan.append((f, dest / name / f.name))
    if not plan:
        raise ValidationError("examples", "no examples found in the installed package")
    existing = [str(t) for _, t in plan if t.exists()]
    if existing and not force:
        raise ValidationError("dest", f"{existing[0]} exists ({len(existing)} example files already there); "
                                      "pass --force to replace them, or choose another folder")
    for src, target in plan:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(src.read_bytes())
    return [t for _, t in plan]
