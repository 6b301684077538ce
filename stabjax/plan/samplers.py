"""The ``[sample]`` distributions of a sweep spec: each entry checked field by field (:func:`sample_args`,
nothing drawn yet), then ``n`` values drawn (:func:`draw`) from the spec's seeded generator.

Distributions (per parameter, ``n`` draws, ``seed``):
``{dist="uniform", low, high}``, ``{dist="normal", mean, std}``, ``{dist="sphere"}``,
``{dist="cap", center=[..] | "<param name>", half_angle}`` (uniform on a spherical cap),
``{dist="ball", radius, center=[..]}`` (uniform in a ball), ``{dist="so3"}`` (uniform rotation matrices).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .. import validate as V
from ..errors import ValidationError
from ..model.params import Param


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


_DISTS = {
    "uniform": {"low", "high"}, "normal": {"mean", "std"}, "sphere": set(), "cap": {"center", "half_angle"},
    "ball": {"radius", "center"}, "so3": set(),
}
_REQUIRED = {"uniform": {"low", "high"}, "normal": {"mean", "std"}, "cap": {"center", "half_angle"}, "ball": {"radius"}}


def sample_args(key: str, raw: Any, prm: Param, fixed: Mapping[str, np.ndarray], varied: set[str]) -> dict:
    """Check one ``[sample]`` entry field by field (nothing drawn yet); returns its parsed arguments."""
    field_name = f"sample.{key}"
    V.table(raw, field_name)
    if "dist" not in raw:
        raise ValidationError(f"{field_name}.dist", f"required: one of {', '.join(_DISTS)}")
    dist = V.string(raw["dist"], f"{field_name}.dist", tuple(_DISTS))
    extra = set(raw) - _DISTS[dist] - {"dist"}
    if extra:
        raise ValidationError(f"{field_name}.{sorted(extra)[0]}", f"unknown key for dist={dist!r}; "
                                                                 f"known: {', '.join(sorted(_DISTS[dist])) or 'none'}")
    for k in sorted(_REQUIRED.get(dist, ())):
        if k not in raw:
            raise ValidationError(f"{field_name}.{k}", f"required for dist={dist!r}")
    shape = prm.shape
    if dist == "so3" and shape != (3, 3):
        raise ValidationError(f"{field_name}.dist", f"dist='so3' needs a 3x3 parameter; {prm.name} has shape {shape}")
    if dist in ("sphere", "ball", "cap") and shape != (3,):
        raise ValidationError(f"{field_name}.dist", f"dist={dist!r} needs a 3-vector parameter; {prm.name} has shape {shape}")
    a: dict[str, Any] = {"dist": dist}
    if dist == "uniform":
        a["low"] = V.number(raw["low"], f"{field_name}.low")
        a["high"] = V.number(raw["high"], f"{field_name}.high")
        if not a["high"] >= a["low"]:
            raise ValidationError(f"{field_name}.high", f"must be >= low ({a['low']}), got {a['high']}")
        # the draws are finite only if the width is: high - low overflows for |bounds| near 1.8e308
        if not np.isfinite(a["high"] - a["low"]):
            raise ValidationError(f"{field_name}.high", "high - low overflows")
    elif dist == "normal":
        a["mean"] = V.number(raw["mean"], f"{field_name}.mean")
        a["std"] = V.number(raw["std"], f"{field_name}.std", lo=0.0, hi=1e300)
    elif dist == "ball":
        a["radius"] = V.number(raw["radius"], f"{field_name}.radius", lo=0.0, hi=1e300)
        a["center"] = np.array(V.numbers(raw.get("center", [0.0, 0.0, 0.0]), f"{field_name}.center", length=3))
    elif dist == "cap":
        a["half_angle"] = V.number(raw["half_angle"], f"{field_name}.half_angle", lo=0.0, hi=float(np.pi))
        c = raw["center"]
        if isinstance(c, str):
            if c not in fixed:
                raise ValidationError(f"{field_name}.center", f"{c!r} is not a parameter; give a unit 3-vector or "
                                                              "the name of a fixed 3-vector parameter")
            if c in varied:
                raise ValidationError(f"{field_name}.center", f"{c!r} is swept or sampled; the cap needs one fixed center")
            c = fixed[c]
        else:
            c = np.array(V.numbers(c, f"{field_name}.center", length=3))
        c = np.asarray(c, dtype=float)
        if c.shape != (3,) or not np.isclose(np.linalg.norm(c), 1, atol=1e-6):
            raise ValidationError(f"{field_name}.center", "must be a unit 3-vector or the name of one")
        a["center"] = _unit(c)
    return a


def draw(a: Mapping[str, Any], prm: Param, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``n`` values of ``prm`` from the checked distribution ``a`` (see :func:`sample_args`)."""
    dist, shape = a["dist"], prm.shape
    if dist == "uniform":
        return rng.uniform(a["low"], a["high"], size=(n, *shape))
    if dist == "normal":
        return a["mean"] + a["std"] * rng.standard_normal((n, *shape))
    if dist == "so3":
        from scipy.spatial.transform import Rotation

        return Rotation.random(n, random_state=rng).as_matrix()
    if dist == "sphere":
        return _unit(rng.standard_normal((n, 3)))
    if dist == "ball":
        d = _unit(rng.standard_normal((n, 3)))
        rad = a["radius"] * rng.uniform(0, 1, size=(n, 1)) ** (1 / 3)
        return a["center"] + rad * d
    # cap: uniform on {x : angle(x, c) <= h}; cos(angle) uniform on [cos h, 1] (Archimedes)
    h, c = a["half_angle"], a["center"]
    z = rng.uniform(np.cos(h), 1.0, size=n)
    phi = rng.uniform(0, 2 * np.pi, size=n)
    e = np.array([1.0, 0, 0]) if abs(c[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = _unit(np.cross(c, e))
    e2 = np.cross(c, e1)
    rho = np.sqrt(np.maximum(1 - z * z, 0))
    return z[:, None] * c + rho[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
