"""Registry of systems: name -> "module:Class". Adding a model = one module + one line here.

Imports are lazy so that ``stabjax systems`` and the CLI start fast and a broken optional
model cannot break the others.
"""
from __future__ import annotations

import importlib

from .errors import ValidationError

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
    "two-body": "stabjax.reproduce.twobody:run",
    "gyrodyne": "stabjax.reproduce.gyrodyne:run",
}

_cache: dict[str, object] = {}


def list_systems(available_only: bool = False) -> list[str]:
    """Registered names; with ``available_only`` only those whose module imports."""
    if not available_only:
        return list(SYSTEMS)
    out = []
    for name in SYSTEMS:
        try:
            get_system(name)
        except ImportError:
            continue
        out.append(name)
    return out


def get_system(name: str):
    """Return the (singleton) system object registered as ``name``."""
    if name not in SYSTEMS:
        raise ValidationError("system", f"unknown system {name!r}; registered: {', '.join(SYSTEMS)}")
    if name not in _cache:
        module, cls = SYSTEMS[name].split(":")
        _cache[name] = getattr(importlib.import_module(module), cls)()
    return _cache[name]


def get_reproducer(name: str):
    if name not in REPRODUCE:
        raise ValidationError("name", f"unknown reproduction {name!r}; known: {', '.join(REPRODUCE)}")
    module, fn = REPRODUCE[name].split(":")
    return getattr(importlib.import_module(module), fn)
