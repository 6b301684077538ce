"""Registry of systems: name -> "module:Class". Adding a model = one module + one line here.

Imports are lazy so that ``stabjax systems`` and the CLI start fast and a broken optional
model cannot break the others.
"""
from __future__ import annotations

import importlib

from ..errors import ValidationError

SYSTEMS: dict[str, str] = {
    # A. Aleksandrov & Tikhonov (2019)
    "monoaxial": "stabjax.systems.monoaxial:Monoaxial",
    # B. Saakyan (1974)
    "saakyan_moving": "stabjax.systems.saakyan:SaakyanMoving",
    "saakyan_fixed": "stabjax.systems.saakyan:SaakyanFixed",
    "saakyan_gravity": "stabjax.systems.saakyan:SaakyanGravity",
    "saakyan_gyrostat": "stabjax.systems.saakyan:SaakyanGyrostat",
    "saakyan_gyrostat_gravity": "stabjax.systems.saakyan:SaakyanGyrostatGravity",
    # C. Bezglasnyi & Mysina (2011)
    "twobody_uniaxial": "stabjax.systems.twobody:TwoBodyUniaxial",
    "twobody_triaxial": "stabjax.systems.twobody:TwoBodyTriaxial",
    "twobody_uniaxial_rotating": "stabjax.systems.twobody:TwoBodyUniaxialRotating",
    "twobody_triaxial_rotating": "stabjax.systems.twobody:TwoBodyTriaxialRotating",
    # D. Khoroshilov (1983)
    "gyrodyne": "stabjax.systems.gyrodyne:Gyrodyne",
}

# `stabjax reproduce NAME`: "module:function(out_dir: pathlib.Path, quick: bool) -> list[Path]"
REPRODUCE: dict[str, str] = {
    "at2019": "stabjax.reproduce.at2019:run",
    "saakyan": "stabjax.reproduce.saakyan:run",
    "twobody": "stabjax.reproduce.twobody:run",
    "gyrodyne": "stabjax.reproduce.gyrodyne:run",
}

_cache: dict[str, object] = {}
_registered: dict[str, type] = {}  # stabjax.register(name, cls), for the running process

ENTRY_POINT_GROUP = "stabjax.systems"


def _entry_points() -> dict[str, object]:
    """Installed packages' systems: ``[project.entry-points."stabjax.systems"] name = "module:Class"``."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def cached(name: str, obj=None):
    """The system object kept for ``name`` (None if none); with ``obj``, keep it."""
    if obj is not None:
        _cache[name] = obj
    return _cache.get(name)


def is_registered(name: str) -> bool:
    return name in _registered


def add_registered(name: str, cls, obj) -> None:
    """Record a class checked by :func:`stabjax.model.loading.register` under ``name``."""
    _registered[name] = cls
    _cache[name] = obj


def lookup(name: str):
    """Where ``name`` comes from: 'builtin', 'registered', 'entry point', or None when unknown."""
    if name in SYSTEMS:
        return "builtin"
    if name in _registered:
        return "registered"
    if name in _entry_points():
        return "entry point"
    return None


def all_names() -> list[str]:
    return list(SYSTEMS) + [n for n in _registered if n not in SYSTEMS] + \
        [n for n in _entry_points() if n not in SYSTEMS and n not in _registered]


def list_systems(available_only: bool = False) -> list[str]:
    """Known names (built in, registered, installed); with ``available_only`` only those that load."""
    if not available_only:
        return all_names()
    out = []
    for name in all_names():
        try:
            get_system(name)
        except (ImportError, ValidationError):
            continue
        out.append(name)
    return out


def load_entry_point(name: str):
    """The class an installed package registers as ``name`` (entry-point group ``stabjax.systems``)."""
    eps = _entry_points()
    try:
        return eps[name].load()
    except Exception as exc:  # noqa: BLE001 - a broken installed package must not take the others down
        raise ValidationError("system", f"entry point {name!r} ({eps[name].value}) failed to load: "
                                        f"{type(exc).__name__}: {exc}") from None


def get_system(name: str):
    """Return the (singleton) system object known as ``name`` (built in or registered; an installed
    package's system: :func:`stabjax.model.loading.resolve`)."""
    if name in _cache:
        return _cache[name]
    if name in SYSTEMS:
        module, cls = SYSTEMS[name].split(":")
        _cache[name] = getattr(importlib.import_module(module), cls)()
        return _cache[name]
    if name in _entry_points():
        raise ValidationError("system", f"{name!r} is an installed package's system: load it with "
                                        "stabjax.model.loading.resolve (stabjax.get_system), which checks it first")
    raise ValidationError("system", f"unknown system {name!r}; known: {', '.join(all_names())} "
                                    "(or give 'path/to/model.py:ClassName' / 'module:ClassName')")


def get_reproducer(name: str):
    if name not in REPRODUCE:
        raise ValidationError("name", f"unknown reproduction {name!r}; known: {', '.join(REPRODUCE)}")
    module, fn = REPRODUCE[name].split(":")
    return getattr(importlib.import_module(module), fn)
