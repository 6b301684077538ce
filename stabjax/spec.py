"""Sweep specifications (TOML) -> validated, fully resolved plans.

A spec has ``system``, optional ``name``, and the tables ``[params]`` (fixed overrides),
``[grid]`` (cartesian axes), ``[sample]`` (random axes shared by every grid point, so
grid points are compared on common random numbers), ``[integrate]`` and ``[verdict]``.

Grid axis values: a list (scalars, or vectors for vector parameters), or
``{start, stop, num[, log]}``. A single entry of a vector/matrix parameter is addressed as
``"J[0]"`` / ``"D[1,1]"`` (quoted in TOML) and named ``J_0`` / ``D_1_1`` in datasets.

Sample distributions (per parameter, ``n`` draws, ``seed``):
``{dist="uniform", low, high}``, ``{dist="normal", mean, std}``, ``{dist="sphere"}``,
``{dist="cap", center=[..] | "<param name>", half_angle}`` (uniform on a spherical cap),
``{dist="ball", radius, center=[..]}`` (uniform in a ball), ``{dist="so3"}`` (uniform rotation matrices).
"""
from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from . import verdict as V
from .engine import IntegrateConfig, verdict_config
from .errors import ValidationError
from .params import Param, parse_value
from .registry import get_system
from .system import System, VerdictConfig

TOP_KEYS = {"system", "name", "description", "params", "grid", "sample", "integrate", "verdict", "run"}
_ENTRY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\[(\d+(?:\s*,\s*\d+)*)\]$")


@dataclass
class Axis:
    """One swept quantity: ``param`` (whole parameter) or one entry ``index`` of it."""

    key: str  # as written in the spec
    name: str  # dataset coordinate name
    param: Param
    index: tuple[int, ...] | None
    values: np.ndarray  # (n, *value_shape)
    log: bool = False

    @property
    def size(self) -> int:
        return len(self.values)

    @property
    def value_shape(self) -> tuple[int, ...]:
        return () if self.index is not None else self.param.shape


@dataclass
class Plan:
    system: System
    name: str
    spec: dict
    fixed: dict[str, np.ndarray]
    grid: list[Axis]
    sample: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (n, *shape)
    n_sample: int = 0
    icfg: IntegrateConfig = field(default_factory=IntegrateConfig)
    vcfg: VerdictConfig = field(default_factory=VerdictConfig)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(a.size for a in self.grid) + ((self.n_sample,) if self.n_sample else ())

    @property
    def dims(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.grid) + (("sample",) if self.n_sample else ())

    @property
    def size(self) -> int:
        return int(np.prod(self.shape)) if self.shape else 1

    def fingerprint(self) -> str:
        """Identity of the computation (spec + system + version): resume refuses on mismatch."""
        from . import __version__

        blob = json.dumps({"spec": _jsonable(self.spec), "system": self.system.name, "version": __version__},
                          sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def params_for(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Every parameter for the flat trajectory indices [start, stop) (C order over ``shape``)."""
        return self.params_at(np.arange(start, stop))

    def params_at(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        """Every parameter for the given flat trajectory indices."""
        n = len(flat)
        idx = np.unravel_index(flat, self.shape) if self.shape else ()
        out = {k: np.broadcast_to(v, (n, *v.shape)).copy() for k, v in self.fixed.items()}
        for ax, ii in zip(self.grid, idx):
            vals = ax.values[ii]
            if ax.index is None:
                out[ax.param.name] = vals
            else:
                out[ax.param.name][(slice(None), *ax.index)] = vals
        if self.n_sample:
            ii = idx[-1]
            for k, v in self.sample.items():
                out[k] = v[ii]
        return out


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def load_spec(path: str | Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ValidationError("spec", f"file not found: {path}")
    try:
        with open(path, "rb") as f:
            spec = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValidationError("spec", f"{path}: invalid TOML ({exc})") from None
    spec.setdefault("name", path.stem)
    return spec


def _axis_values(key: str, raw: Any, prm: Param, index) -> tuple[np.ndarray, bool]:
    field_name = f"grid.{key}"
    value_param = Param(prm.name, 0.0, prm.doc, () if index is not None else prm.shape, parse=None if index is not None else prm.parse,
                        choices=prm.choices)
    if isinstance(raw, Mapping):
        unknown = set(raw) - {"start", "stop", "num", "log"}
        if unknown:
            raise ValidationError(field_name, f"unknown key(s) {sorted(unknown)}; use start, stop, num, log")
        if value_param.shape:
            raise ValidationError(field_name, "a range needs a scalar axis; give a list of vectors, or sweep one entry like \"J[0]\"")
        try:
            start, stop, num = float(raw["start"]), float(raw["stop"]), int(raw["num"])
        except KeyError as exc:
            raise ValidationError(field_name, f"range needs {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ValidationError(field_name, f"bad range ({exc})") from None
        if num < 1:
            raise ValidationError(f"{field_name}.num", f"must be >= 1, got {num}")
        log = bool(raw.get("log", False))
        if log:
            if start <= 0 or stop <= 0:
                raise ValidationError(field_name, "log axis needs start > 0 and stop > 0")
            vals = np.geomspace(start, stop, num)
        else:
            vals = np.linspace(start, stop, num)
        return vals, log
    if not isinstance(raw, list) or not raw:
        raise ValidationError(field_name, "must be a non-empty list or a {start, stop, num} table")
    vals = np.stack([parse_value(value_param, v) for v in raw])
    return vals, False


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _sample(key: str, raw: Any, prm: Param, n: int, rng: np.random.Generator, fixed: Mapping[str, np.ndarray]) -> np.ndarray:
    field_name = f"sample.{key}"
    if not isinstance(raw, Mapping) or "dist" not in raw:
        raise ValidationError(field_name, "must be a table with a 'dist' key")
    dist = raw["dist"]
    shape = prm.shape
    allowed = {
        "uniform": {"low", "high"}, "normal": {"mean", "std"}, "sphere": set(), "cap": {"center", "half_angle"},
        "ball": {"radius", "center"}, "so3": set(),
    }
    if dist not in allowed:
        raise ValidationError(f"{field_name}.dist", f"unknown distribution {dist!r}; choose from {', '.join(allowed)}")
    extra = set(raw) - allowed[dist] - {"dist"}
    if extra:
        raise ValidationError(field_name, f"unknown key(s) {sorted(extra)} for dist={dist!r}")

    def num(k, default=None):
        if k not in raw:
            if default is None:
                raise ValidationError(f"{field_name}.{k}", "required")
            return default
        try:
            return float(raw[k])
        except (TypeError, ValueError):
            raise ValidationError(f"{field_name}.{k}", f"must be a number, got {raw[k]!r}") from None

    if dist == "uniform":
        lo, hi = num("low"), num("high")
        if not hi >= lo:
            raise ValidationError(field_name, f"high ({hi}) must be >= low ({lo})")
        return rng.uniform(lo, hi, size=(n, *shape))
    if dist == "normal":
        std = num("std")
        if std < 0:
            raise ValidationError(f"{field_name}.std", "must be >= 0")
        return num("mean") + std * rng.standard_normal((n, *shape))
    if dist == "so3":
        if shape != (3, 3):
            raise ValidationError(field_name, f"dist='so3' needs a 3x3 parameter; {prm.name} has shape {shape}")
        from scipy.spatial.transform import Rotation

        return Rotation.random(n, random_state=rng).as_matrix()
    if shape != (3,):
        raise ValidationError(field_name, f"dist={dist!r} needs a 3-vector parameter; {prm.name} has shape {shape}")
    if dist == "sphere":
        return _unit(rng.standard_normal((n, 3)))
    if dist == "ball":
        radius = num("radius")
        center = np.asarray(raw.get("center", [0, 0, 0]), dtype=float)
        if center.shape != (3,):
            raise ValidationError(f"{field_name}.center", "must be 3 numbers")
        d = _unit(rng.standard_normal((n, 3)))
        rad = radius * rng.uniform(0, 1, size=(n, 1)) ** (1 / 3)
        return center + rad * d
    # cap: uniform on {x : angle(x, c) <= h}; cos(angle) uniform on [cos h, 1] (Archimedes)
    h = num("half_angle")
    if not 0 <= h <= np.pi:
        raise ValidationError(f"{field_name}.half_angle", f"must be in [0, pi], got {h}")
    c = raw.get("center")
    if isinstance(c, str):
        if c not in fixed:
            raise ValidationError(f"{field_name}.center", f"{c!r} must name a fixed (not swept) 3-vector parameter")
        c = fixed[c]
    c = np.asarray(c, dtype=float)
    if c.shape != (3,) or not np.isclose(np.linalg.norm(c), 1, atol=1e-6):
        raise ValidationError(f"{field_name}.center", "must be a unit 3-vector or the name of one")
    c = _unit(c)
    z = rng.uniform(np.cos(h), 1.0, size=n)
    phi = rng.uniform(0, 2 * np.pi, size=n)
    a = np.array([1.0, 0, 0]) if abs(c[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = _unit(np.cross(c, a))
    e2 = np.cross(c, e1)
    rho = np.sqrt(np.maximum(1 - z * z, 0))
    return z[:, None] * c + rho[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def make_plan(spec: Mapping[str, Any], *, t1: float | None = None) -> Plan:
    """Validate a spec dict and resolve it into a :class:`Plan` (nothing is integrated)."""
    spec = dict(spec)
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise ValidationError(sorted(unknown)[0], f"unknown top-level key; known: {', '.join(sorted(TOP_KEYS))}")
    if "system" not in spec:
        raise ValidationError("system", "missing (e.g. system = \"monoaxial\")")
    system = get_system(spec["system"])
    for table in ("params", "grid", "sample", "integrate", "verdict"):
        if table in spec and not isinstance(spec[table], Mapping):
            raise ValidationError(table, "must be a table")
    fixed = system.params.resolve(spec.get("params", {}))
    # validate fixed values alone first: errors point at [params] rather than at a grid point
    fixed = {k: np.asarray(v) for k, v in system.check({k: v.copy() for k, v in fixed.items()}).items()}

    grid: list[Axis] = []
    seen = set()
    for key, raw in (spec.get("grid") or {}).items():
        m = _ENTRY.match(key)
        pname, index = (m.group(1), tuple(int(i) for i in m.group(2).split(","))) if m else (key, None)
        try:
            prm = system.params[pname]
        except ValidationError:
            raise ValidationError(f"grid.{key}", f"unknown parameter {pname!r} of {system.name}; known: "
                                  f"{', '.join(p.name for p in system.params)}") from None
        if index is not None:
            if len(index) != len(prm.shape) or any(i >= s for i, s in zip(index, prm.shape)):
                raise ValidationError(f"grid.{key}", f"index {index} out of range for shape {prm.shape}")
        if (pname, index) in seen or (pname, None) in seen:
            raise ValidationError(f"grid.{key}", "parameter swept twice")
        seen.add((pname, index))
        vals, log = _axis_values(key, raw, prm, index)
        name = pname if index is None else pname + "_" + "_".join(map(str, index))
        grid.append(Axis(key, name, prm, index, vals, log))

    sample_spec = dict(spec.get("sample") or {})
    n_sample, sample = 0, {}
    if sample_spec:
        try:
            n_sample = int(sample_spec.pop("n"))
        except KeyError:
            raise ValidationError("sample.n", "required: number of random draws") from None
        if n_sample < 1:
            raise ValidationError("sample.n", f"must be >= 1, got {n_sample}")
        seed = int(sample_spec.pop("seed", 0))
        rng = np.random.default_rng(seed)
        for key, raw in sample_spec.items():
            try:
                prm = system.params[key]
            except ValidationError:
                raise ValidationError(f"sample.{key}", f"unknown parameter of {system.name}") from None
            if any(a.param.name == key for a in grid):
                raise ValidationError(f"sample.{key}", "is also a grid axis")
            sample[key] = _sample(key, raw, prm, n_sample, rng, fixed)
        if not sample:
            raise ValidationError("sample", "no parameter to sample (add e.g. s0 = {dist = \"sphere\"})")

    icfg = IntegrateConfig.from_dict(spec.get("integrate"), default_t1=system.default_t1)
    if t1 is not None:
        icfg = IntegrateConfig(**{**icfg.__dict__, "t1": float(t1)})
        icfg.validate()
    vtab = dict(spec.get("verdict") or {})
    for k in ("t0", "t1", "n_obs"):
        if k in vtab:
            raise ValidationError(f"verdict.{k}", "is set from [integrate] and the system, not in [verdict]")
    horizons = vtab.pop("horizons", None)
    if horizons is not None and not isinstance(horizons, (list, tuple)):
        raise ValidationError("verdict.horizons", f"must be a list of times, got {horizons!r}")
    vcfg = verdict_config(system, vtab)
    # windows and horizons become constants of the plan (verdict.bind); the last horizon is t1
    vcfg = V.bind(vcfg, icfg.t0, icfg.t1, horizons=horizons, n_obs=len(system.observables))
    plan = Plan(system=system, name=str(spec.get("name", "sweep")), spec=spec, fixed=fixed, grid=grid,
                sample=sample, n_sample=n_sample, icfg=icfg, vcfg=vcfg)
    return plan


def check_plan(plan: Plan, chunk: int = 65536) -> None:
    """Validate every trajectory's parameters (vectorised, no integration), naming the axis at fault."""
    for start in range(0, plan.size, chunk):
        p = plan.params_for(start, min(plan.size, start + chunk))
        try:
            plan.system.check(p)
        except ValidationError as exc:
            where = [a.key for a in plan.grid if a.param.name == exc.field]
            where += [f"sample.{k}" for k in plan.sample if k == exc.field]
            if where:
                raise ValidationError(f"grid.{where[0]}" if not where[0].startswith("sample.") else where[0],
                                      exc.message) from None
            raise
