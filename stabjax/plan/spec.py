"""Sweep specifications (TOML) -> validated, fully resolved plans.

A spec has ``system``, optional ``name``, and the tables ``[params]`` (fixed overrides),
``[grid]`` (cartesian axes), ``[sample]`` (random axes shared by every grid point, so
grid points are compared on common random numbers), ``[integrate]``, ``[engine]`` (the engines'
tuning settings, declared and checked by :mod:`stabjax.engines`) and ``[verdict]``.

Grid axis values: a list (scalars, or vectors for vector parameters), or
``{start, stop, num[, log]}``. A single entry of a vector/matrix parameter is addressed as
``"J[0]"`` / ``"D[1,1]"`` (quoted in TOML) and named ``J_0`` / ``D_1_1`` in datasets.

Sample distributions (per parameter, ``n`` draws, ``seed``): :mod:`stabjax.plan.samplers` (uniform,
normal, sphere, cap, ball, so3). Starts from a file (``[sample] from``): :mod:`stabjax.plan.starts`.
"""
from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..config import IntegrateConfig, VerdictConfig, verdict_config
from .. import engines
from .. import validate as V
from ..fold import verdict as VD
from ..errors import ValidationError
from ..model.params import Param, parse_value
from ..model.loading import resolve as resolve_system
from ..mapping.classify import mapper_for
from ..mapping.mapper import Mapper, OutcomeScheme
from ..mapping.verdicts import Verdicts
from ..model.outcomes import VERDICTS, Outcomes
from .samplers import draw, sample_args
from ..model.system import System

# every top-level key is read by something: a section nothing reads (formerly ``[run]``, accepted with
# any content) is refused like any unknown key, so a setting the user believes in is never ignored
TOP_KEYS = {"system", "name", "description", "params", "grid", "sample", "integrate", "engine", "verdict", "outcomes",
            "refine", "shock"}  # [refine], [shock]: explorers' tables, checked by stabjax.explore (refine_config, shock_config)
_NAME = re.compile(r"^(?![.\-\s])[^/\\\x00-\x1f]{1,128}$")  # a file stem: no path, no hidden file
_ENTRY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\[(\d+(?:\s*,\s*\d+)*)\]$")

SHOCK_TAKES_NO_SAMPLE = ("a shock search chooses its own starts: remove [sample] (the start to shock is the "
                         "spec's, set in [params])")


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


@dataclass(frozen=True)
class Plan:
    """A validated, fully resolved sweep (an immutable value: derive changed ones with
    ``dataclasses.replace``). ``engine``: the engine that runs it, resolved once by
    :func:`stabjax.engines.resolve_plan` ("" until then), and ``engine_note`` why it is not the
    first choice ("" when it is)."""

    system: System
    name: str
    spec: dict
    fixed: dict[str, np.ndarray]
    grid: list[Axis]
    sample: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (n, *shape)
    n_sample: int = 0
    icfg: IntegrateConfig = field(default_factory=IntegrateConfig)
    vcfg: VerdictConfig = field(default_factory=VerdictConfig)
    # the outcome mapper, chosen once (stabjax.mapping.mapper): verdicts, rules + templates + escape, discovery
    mapper: Mapper = field(default_factory=Verdicts)
    lyapunov: bool = False  # integrate the tangent dynamics: per-trajectory largest Lyapunov exponent
    start_labels: Any = None  # labels of the starts of a [sample] from = FILE (stabjax.plan.starts), or None
    starts_file: Path | None = None  # that FILE: an input of the sweep, never one of its outputs
    # explicit grid points (P, n_axes): the plan runs these values of its grid axes, in this order, instead of
    # the axes' cartesian product (a refinement round: an explorer's points through the sweep's runner)
    points: np.ndarray | None = None

    engine: str = ""
    engine_note: str = ""

    @property
    def escape_radius(self) -> float | None:
        r = self.icfg.escape_radius
        return r if r is not None else self.system.escape_radius

    @property
    def integrated(self) -> System:
        """The system the engines integrate: the model, or with ``lyapunov`` the model with its tangent
        dynamics (:class:`stabjax.model.tangent.TangentSystem`, window = the outcome features' window)."""
        if not self.lyapunov:
            return self.system
        from ..model.tangent import tangent, window_start

        return tangent(self.system, window_start(self.icfg.t0, self.icfg.t1, self.vcfg.feature_window),
                       float(self.icfg.t1))

    @property
    def scheme(self) -> OutcomeScheme:
        """The outcomes' names and colours as the mapper knows them before the run."""
        return self.mapper.scheme

    @property
    def shape(self) -> tuple[int, ...]:
        grid = tuple(a.size for a in self.grid) if self.points is None else (len(self.points),)
        return grid + ((self.n_sample,) if self.n_sample else ())

    @property
    def dims(self) -> tuple[str, ...]:
        grid = tuple(a.name for a in self.grid) if self.points is None else ("point",)
        return grid + (("sample",) if self.n_sample else ())

    @property
    def size(self) -> int:
        return int(np.prod(self.shape)) if self.shape else 1

    def static_params(self) -> list[str]:
        """Parameters equal in every chunk of the plan (fixed, not swept, not sampled): compiled in as constants."""
        varied = {ax.param.name for ax in self.grid} | set(self.sample)
        return [k for k in self.fixed if k not in varied]

    def fingerprint(self) -> str:
        """Identity of the computation: :func:`stabjax.plan.identity.fingerprint` (the one place it is computed)."""
        from .identity import fingerprint

        return fingerprint(self)

    def params_for(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Every parameter for the flat trajectory indices [start, stop) (C order over ``shape``)."""
        return self.params_at(np.arange(start, stop))

    def params_at(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        """Every parameter for the given flat trajectory indices."""
        n = len(flat)
        idx = np.unravel_index(flat, self.shape) if self.shape else ()
        out = {k: np.broadcast_to(v, (n, *v.shape)).copy() for k, v in self.fixed.items()}
        for a, ax in enumerate(self.grid):
            vals = ax.values[idx[a]] if self.points is None else self.points[idx[0], a]
            if ax.index is None:
                out[ax.param.name] = vals
            else:
                out[ax.param.name][(slice(None), *ax.index)] = vals
        if self.n_sample:
            ii = idx[-1]
            for k, v in self.sample.items():
                out[k] = v[ii]
        return out


def jsonable(x):
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def system_ref(ref: Any) -> str:
    """A spec's ``system`` as a string (a class or instance given through the Python API -> module:Class)."""
    import inspect

    if isinstance(ref, str):
        return ref
    cls = ref if inspect.isclass(ref) else type(ref)
    return f"{cls.__module__}:{cls.__qualname__}"


def spec_json(spec: Mapping[str, Any]) -> str:
    """The spec as results store it (attribute ``spec_json``): used to tell a result of the same spec."""
    return json.dumps(jsonable(spec))


def load_spec(path: str | Path) -> dict:
    """A spec file; ``sweeps/NAME.toml`` not found here is the shipped spec NAME (an installed wheel
    has no sweeps/ folder beside the working directory, so the README's commands still run)."""
    path = Path(path)
    if not path.exists() and path.parent.name == "sweeps" and path.suffix == ".toml":
        from importlib.resources import as_file, files

        shipped = files("stabjax") / "sweeps" / path.name
        if shipped.is_file():
            with as_file(shipped) as p:
                return load_spec(p)
    if not path.exists():
        raise ValidationError("spec", f"file not found: {path}")
    if path.is_dir():
        raise ValidationError("spec", f"{path} is a directory, not a TOML file")
    if not path.is_file():  # a FIFO would block the read forever, a device never end
        raise ValidationError("spec", f"{path} is not a regular file (a pipe, device or socket); give a TOML file")
    try:
        with open(path, "rb") as f:
            spec = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValidationError("spec", f"{path}: invalid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValidationError("spec", f"{path}: cannot read ({exc})") from None
    spec.setdefault("name", path.stem)
    # a model file named in the spec is found relative to the spec's folder
    spec["__base_dir__"] = str(path.resolve().parent)
    return spec


MAX_AXIS_POINTS = 10**8  # one grid axis or sample: beyond this the values alone take gigabytes
MAX_TRAJECTORIES = 2**53  # a plan's flat index must be exact in a double and in int64
RESULT_BYTES_PER_TRAJECTORY = 8 * 24  # = 8 * sweep.N_SUMMARY_FIELDS: summaries + theory per trajectory


def _axis_size(key: str, raw: Any) -> int:
    """Number of points of a grid axis, checked before any array is built."""
    field_name = f"grid.{key}"
    if isinstance(raw, Mapping):
        if "num" not in raw:
            raise ValidationError(f"{field_name}.num", "required: number of points of the range")
        return V.integer(raw["num"], f"{field_name}.num", lo=1, hi=MAX_AXIS_POINTS)
    if not isinstance(raw, list) or not raw:
        raise ValidationError(field_name, f"must be a non-empty list or a {{start, stop, num}} table, got {V.kind_of(raw)}")
    return len(raw)


def _axis_values(key: str, raw: Any, prm: Param, index) -> tuple[np.ndarray, bool]:
    field_name = f"grid.{key}"
    value_param = Param(prm.name, 0.0, prm.doc, () if index is not None else prm.shape, parse=None if index is not None else prm.parse,
                        choices=prm.choices)
    if isinstance(raw, Mapping):
        unknown = set(raw) - {"start", "stop", "num", "log"}
        if unknown:
            raise ValidationError(f"{field_name}.{sorted(unknown)[0]}", "unknown key; use start, stop, num, log")
        if value_param.shape:
            raise ValidationError(field_name, "a range needs a scalar axis; give a list of vectors, or sweep one entry like \"J[0]\"")
        for k in ("start", "stop"):
            if k not in raw:
                raise ValidationError(f"{field_name}.{k}", "required")
        start = V.number(raw["start"], f"{field_name}.start")
        stop = V.number(raw["stop"], f"{field_name}.stop")
        num = V.integer(raw["num"], f"{field_name}.num", lo=1, hi=MAX_AXIS_POINTS)
        log = V.boolean(raw.get("log", False), f"{field_name}.log")
        if log:
            if start <= 0 or stop <= 0:
                raise ValidationError(field_name, "log axis needs start > 0 and stop > 0")
            vals = np.geomspace(start, stop, num)
        else:
            vals = np.linspace(start, stop, num)
        if prm.choices is not None and not np.isin(vals, prm.choices).all():
            raise ValidationError(field_name, f"{prm.name} takes only the values {prm.choices}; give them as a list")
        return vals, log
    vals = []
    for i, v in enumerate(raw):
        try:
            vals.append(parse_value(value_param, v))
        except ValidationError as exc:
            raise ValidationError(f"{field_name}[{i}]", exc.message) from None
    return np.stack(vals), False


def _check_distinct(key: str, raw: Any, vals: np.ndarray) -> None:
    """Refuse an axis with a value twice: the same trajectories would be run twice and the result
    would have a coordinate that does not identify its points (``sel`` picks one of them)."""
    flat = vals.reshape(len(vals), -1)
    _, first, inverse = np.unique(flat, axis=0, return_index=True, return_inverse=True)
    inverse = np.ravel(inverse)
    for i in range(len(flat)):
        j = int(first[inverse[i]])
        if j != i:
            if isinstance(raw, Mapping):
                raise ValidationError(f"grid.{key}", f"the range gives the value {flat[i].tolist()[0]!r} twice "
                                                     f"(points {j} and {i}): start and stop must differ by more "
                                                     "than rounding, or use num = 1")
            raise ValidationError(f"grid.{key}[{i}]", f"{np.asarray(vals[i]).tolist()!r} repeats grid.{key}[{j}]; "
                                                      "each value of an axis once")


def make_plan(spec: Mapping[str, Any], *, t1: float | None = None, base_dir: str | Path | None = None) -> Plan:
    """Validate a spec dict field by field and resolve it into a :class:`Plan` (nothing is integrated).

    ``spec["system"]`` may be a name, ``"file.py:Class"`` (relative to ``base_dir``: the spec
    file's folder when loaded by :func:`load_spec`, else the working directory), ``"module:Class"``,
    or a System class/instance (:mod:`stabjax.model.loading`).

    Every check that can fail runs before any array of the plan's size is built: the sizes of the
    grid axes and of the sample are checked (points per axis, trajectories in all, memory of the
    values) first.
    """
    V.table(spec, "spec")
    spec = dict(spec)
    base_dir = spec.pop("__base_dir__", None) if base_dir is None else base_dir
    spec.pop("__base_dir__", None)
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise ValidationError(sorted(unknown)[0], f"unknown top-level key; known: {', '.join(sorted(TOP_KEYS))}")
    if "system" not in spec:
        raise ValidationError("system", "missing (e.g. system = \"monoaxial\")")
    ref = spec["system"] if not isinstance(spec["system"], str) else V.string(spec["system"], "system")
    system = resolve_system(ref, base_dir)
    spec["system"] = system_ref(ref)
    src = getattr(type(system), "_stabjax_source", None)
    if src is not None:  # a model file: record where it was found, so the plan can be rebuilt anywhere
        spec["system"] = f"{src}:{type(system).__name__}"
    sweep_name = V.string(spec.get("name", "sweep"), "name")
    if not _NAME.match(sweep_name):
        raise ValidationError("name", f"{sweep_name!r}: must be a file stem (it names the output results/<name>.nc): "
                                      "no '/' or '\\', not starting with '.', '-' or a space, at most 128 characters")
    if "description" in spec:
        V.string(spec["description"], "description")
    for table in ("params", "grid", "sample", "integrate", "engine", "verdict"):
        if table in spec:
            V.table(spec[table], table)
    given = dict(spec.get("params") or {})
    try:
        fixed = system.params.resolve(given)
        # validate fixed values alone first: errors point at [params] rather than at a grid point
        fixed = {k: np.asarray(v) for k, v in system.check({k: v.copy() for k, v in fixed.items()}).items()}
    except ValidationError as exc:
        if exc.field in given or exc.field not in system.params.by_name:
            raise ValidationError(f"params.{exc.field}", exc.message) from None
        raise

    # sizes first, from the spec alone: nothing of the plan's size is allocated before they pass
    grid_spec = dict(spec.get("grid") or {})
    sample_spec = dict(spec.get("sample") or {})
    if sample_spec and "shock" in spec:
        # said here, before the sample table is read: its own complaints (a parameter to sample, a starts file)
        # would send the user to fix a table that a shock search refuses whole
        raise ValidationError("sample", SHOCK_TAKES_NO_SAMPLE)
    # a parameter both fixed and swept (or sampled): the fixed value is never used, yet it would be
    # recorded as a fixed parameter of the result (fixed_params_json). One entry swept ("J[0]") with
    # the whole vector fixed is fine: the other entries come from [params].
    for pname in given:
        for where, keys in (("grid", grid_spec), ("sample", sample_spec)):
            if pname in keys:
                raise ValidationError(f"params.{pname}", f"is also {'swept by' if where == 'grid' else 'sampled by'} "
                                                         f"{where}.{pname}; a parameter is either fixed or varied: "
                                                         f"remove one of them")
    sizes = [_axis_size(key, raw) for key, raw in grid_spec.items()]
    n_sample = 0
    from_file = None
    if "from" in sample_spec:  # the starts of a file (stabjax.plan.starts): their number is the file's
        from . import starts as ST

        from_file = ST.load(sample_spec, system, base_dir,
                            {re.sub(r"\[.*", "", k) for k in grid_spec})
        for pname in given:  # as with [sample] NAME: the file's column would win, the fixed value be recorded
            if pname in from_file[0]:
                raise ValidationError(f"params.{pname}", f"is also a column of the starts file {from_file[2].name} "
                                                         "(sample.from); a parameter is either fixed or read from the "
                                                         "file: remove one of them")
        sample_spec = {"n": len(next(iter(from_file[0].values())))}
        # the file's content is part of what runs: a changed file is a different sweep (fingerprint)
        spec["sample"] = {**dict(spec["sample"]), "__sha256__": ST.sha256(from_file[2])}
    if sample_spec:
        if "n" not in sample_spec:
            raise ValidationError("sample.n", "required: number of random draws")
        n_sample = V.integer(sample_spec.pop("n"), "sample.n", lo=1, hi=MAX_AXIS_POINTS)
        sizes.append(n_sample)
    total = math.prod(sizes)
    where = "grid" if grid_spec else "sample.n"
    if total > MAX_TRAJECTORIES:
        raise ValidationError(where, f"{' x '.join(map(str, sizes))} = {total:.3g} trajectories: too many to index "
                                     f"(at most 2^53 = {MAX_TRAJECTORIES:.3g}); split the sweep")
    # the results of every trajectory are held at the end (sweep.choose_batch_size repeats this check
    # against its own memory limit); refused here too, so that no sample of that size is drawn first
    V.check_allocation(where, total * RESULT_BYTES_PER_TRAJECTORY, f"the results of {total:,} trajectories")

    grid: list[Axis] = []
    seen: dict[str, list] = {}  # parameter name -> [(entry index or None, key)] of the axes sweeping it
    for (key, raw), size in zip(grid_spec.items(), sizes):
        m = _ENTRY.match(key)
        pname, index = (m.group(1), tuple(int(i) for i in m.group(2).split(","))) if m else (key, None)
        if pname not in system.params.by_name:
            raise ValidationError(f"grid.{key}", f"unknown parameter {pname!r} of {system.name}; known: "
                                  f"{', '.join(p.name for p in system.params)}")
        prm = system.params[pname]
        if index is not None:
            if len(index) != len(prm.shape) or any(i >= s for i, s in zip(index, prm.shape)):
                raise ValidationError(f"grid.{key}", f"index {index} out of range for shape {prm.shape}")
        prev = seen.setdefault(pname, [])
        for pidx, pkey in prev:  # whole parameter and one entry (either order), or one entry twice
            if index is None or pidx is None or pidx == index:
                raise ValidationError(f"grid.{key}", f"parameter {pname!r} is already swept by grid.{pkey}")
        prev.append((index, key))
        V.check_allocation(f"grid.{key}", size * 8 * (1 if index is not None else prm.size), "the axis values")
        vals, log = _axis_values(key, raw, prm, index)
        _check_distinct(key, raw, vals)
        name = pname if index is None else pname + "_" + "_".join(map(str, index))
        grid.append(Axis(key, name, prm, index, vals, log))

    sample = {}
    if from_file is not None:
        sample = {k: np.asarray(v, float) for k, v in from_file[0].items()}
    elif n_sample:
        seed = V.integer(sample_spec.pop("seed", 0), "sample.seed", lo=0, hi=2**128 - 1)
        if not sample_spec:
            raise ValidationError("sample", "no parameter to sample (add e.g. s0 = {dist = \"sphere\"})")
        varied = {a.param.name for a in grid} | set(sample_spec)
        checked = {}
        for key, raw in sample_spec.items():
            if key not in system.params.by_name:
                raise ValidationError(f"sample.{key}", f"unknown parameter of {system.name}; known: "
                                                       f"{', '.join(p.name for p in system.params)}")
            prm = system.params[key]
            if any(a.param.name == key for a in grid):
                raise ValidationError(f"sample.{key}", "is also a grid axis")
            checked[key] = sample_args(key, raw, prm, fixed, varied - {key})
            V.check_allocation(f"sample.{key}", n_sample * 8 * prm.size, "the sampled values")
        rng = np.random.default_rng(seed)
        for key, a in checked.items():
            sample[key] = draw(a, system.params[key], n_sample, rng)

    icfg = engines.integrate_config(spec.get("integrate"), spec.get("engine"), default_t1=system.default_t1)
    if t1 is not None:
        t1 = V.number(t1, "--t1")
        icfg = icfg.replace(t1=t1)
        # the override is part of what runs: recorded in the spec, hence in the fingerprint (a resume
        # or a replaced result at another horizon is then a different sweep, not mixed in)
        spec["integrate"] = {**dict(spec.get("integrate") or {}), "t1": t1}
        try:
            icfg.validate()
        except ValidationError as exc:
            raise ValidationError("--t1", exc.message) from None
    vtab = dict(spec.get("verdict") or {})
    for k in ("t0", "t1", "n_obs"):
        if k in vtab:
            raise ValidationError(f"verdict.{k}", "is set from [integrate] and the system, not in [verdict]")
    horizons = vtab.pop("horizons", None)
    if horizons is not None and not isinstance(horizons, (list, tuple)):
        raise ValidationError("verdict.horizons", f"must be a list of times, got {horizons!r}")
    vcfg = verdict_config(system, vtab)
    # VERDICTS (the attitude systems): the verdicts are the outcomes; no declaration: discovery
    decl = None if system.outcomes is VERDICTS else (system.outcomes or Outcomes(discover=True))
    if "outcomes" in spec:
        decl = Outcomes.from_spec(spec["outcomes"], base=decl)
    escape = (icfg.escape_radius if icfg.escape_radius is not None else system.escape_radius) is not None
    if decl is not None:
        decl.check(system, where="outcomes", escape=escape)
    mapper = mapper_for(system, decl, escape)  # chosen once: nothing downstream asks which kind of outcome
    if not mapper.uses_verdicts and spec.get("verdict"):
        # a threshold nothing reads would be recorded in the result as if it had shaped it
        key = next(iter(spec["verdict"]))
        raise ValidationError(f"verdict.{key}", f"{system.name}'s outcomes are named ([outcomes]); the [verdict] "
                                                "thresholds judge the attitude verdicts and nothing here reads "
                                                "them (the window is outcomes.window)")
    if decl is not None:
        # the fold also keeps late-window statistics of every observable, for the outcome rules
        # (named outcomes need nothing else: the attitude classifier's state is left out of the fold)
        vcfg = vcfg.replace(features=True, feature_window=float(decl.window), verdicts=mapper.uses_verdicts)
    # the tangent dynamics only when a rule, a feature, discovery or the user asks for the exponent
    lyap = decl is not None and decl.uses_lyapunov(system)
    n_obs = len(system.observables) + int(lyap)
    # windows and horizons become constants of the plan (verdict.bind); the last horizon is t1
    if lyap and n_obs > VD.MAX_FEATURE_OBS:
        raise ValidationError("outcomes.lyapunov", f"the exponent is kept as an extra observable: at most "
                              f"{VD.MAX_FEATURE_OBS - 1} observables beside it, {system.name} has {n_obs - 1}")
    vcfg = VD.bind(vcfg, icfg.t0, icfg.t1, horizons=horizons, n_obs=n_obs)
    # early stop at a stable fixed point: on by default where it cannot change an outcome (stabjax.fold.stops);
    # the tangent dynamics read t (their window), so the integrated system decides
    from ..fold.stops import resolve as _early
    from ..model.tangent import tangent, window_start

    integrated = tangent(system, window_start(icfg.t0, icfg.t1, vcfg.feature_window), float(icfg.t1)) if lyap \
        else system
    icfg = _early(icfg, integrated, not mapper.uses_verdicts)
    if icfg.attractor_stop:
        _check_attractor_stop(integrated, mapper, grid, sample)
    plan = Plan(system=system, name=sweep_name, spec=spec, fixed=fixed, grid=grid,
                sample=sample, n_sample=n_sample, icfg=icfg, vcfg=vcfg, mapper=mapper, lyapunov=lyap,
                start_labels=None if from_file is None else from_file[1],
                starts_file=None if from_file is None else from_file[2])
    return plan


def _check_attractor_stop(integrated, mapper: Mapper, grid, sample) -> None:
    """Where the recurrence stop (stabjax.fold.stops) cannot apply, refuse it naming why."""
    from ..fold.stops import is_autonomous

    field = "integrate.attractor_stop"
    if mapper.uses_verdicts or integrated.classify is not None:
        raise ValidationError(field, f"{integrated.name}'s verdicts read the run up to t1; the stop needs named "
                                     "outcomes (rules or templates)")
    if mapper.whole_set:
        raise ValidationError(field, "discovery groups the whole run's trajectories at the end; the stop needs "
                                     "declared outcomes (rules or templates)")
    if not is_autonomous(integrated):
        raise ValidationError(field, "the model (or the Lyapunov exponent's tangent dynamics) reads t: an attractor "
                                     "of a non-autonomous system is not a set of observable values")
    kinds = {p.name: p.kind for p in integrated.params.params}
    varied = [ax.param.name for ax in grid] + list(sample)
    moving = [k for k in varied if kinds.get(k, "model") != "initial"]
    if moving:
        raise ValidationError(field, f"{', '.join(moving)} vary and are not initial conditions: the attractors "
                                     "move with them, so one run's attractors are not known at another point")


def static_params(plan: Plan) -> list[str]:
    """Parameters equal in every chunk of the plan: :meth:`Plan.static_params`."""
    return plan.static_params()


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
