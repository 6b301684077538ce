"""The variables of a sweep's dataset, defined once for the chunk store and the netCDF file.

A sweep's results reach the user two ways: the zarr chunk store (:mod:`stabjax.run.store`), which a
user may open with ``xr.open_zarr`` while the sweep runs, and the netCDF file. Both are built by
:func:`build` from the same per-trajectory arrays, so they hold the same variables: the store is
created from :func:`build` over placeholders (its layout), then filled chunk by chunk with what
:func:`derive_chunk` computes; the netCDF file is a copy of the finished store (or, for a sweep
without an output file, :func:`build` over the arrays kept in memory).

What is computed per chunk (so that it is stored with the chunk and checksummed with it): the
engines' records, the verdict with escaped trajectories marked diverged, and the outcome. What is
computed once: the coordinates, the theory variables (from the parameters alone) and the template
features (before the first chunk: the outcome of a chunk needs them), and, when the plan samples,
the basin statistics per grid point, which need every sample of a grid point (:func:`basin_vars`,
written when the sweep finishes).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import xarray as xr

from ..fold import verdict as V
from ..config import versions
from ..plan.identity import provenance as identity_attrs
from ..fold.status import ESCAPED as STATUS_ESCAPED
from ..fold.status import verdicts as status_verdicts

THEORY_CHUNK = 262_144  # trajectories per host-side pass over the parameters
# per-trajectory results that are not classifier summaries
_DOC = {"stopped_at": "time at which the integration of this trajectory ended (t1 unless it stopped early: "
                      "escape, stable fixed point, failure; see stop_reason)",
        "stop_reason": "why the integration ended (stabjax.fold.stops): none = ran to t1, escaped, fixed_point = "
                       "reached a stable equilibrium within the solver tolerance (autonomous models), failed",
        "lyapunov": "largest Lyapunov exponent over the feature window (finite-time estimate from the tangent "
                    "dynamics, stabjax.model.tangent); NaN where the solver did not reach t1"}


def trailing_dims(key: str, ndim_trailing: int) -> tuple[str, ...]:
    """Names of a result's dims after the plan's (e.g. ``horizon``; ``<key>_dim<i>`` when unnamed)."""
    extra = tuple(V.TRAILING_DIMS.get(key, ()))[:ndim_trailing]
    return extra + tuple(f"{key}_dim{i}" for i in range(len(extra), ndim_trailing))


def grid_layout(plan) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """(dims, shape) of the plan's grid points: its dims without ``sample``."""
    if plan.n_sample:
        return tuple(plan.dims[:-1]), tuple(plan.shape[:-1])
    return tuple(plan.dims), tuple(plan.shape)


def template_features(plan) -> np.ndarray | None:
    """(grid points, templates, features) of the plan's templates, or None (no templates): each
    template integrated at the parameters of each grid point (its first trajectory)."""
    from ..mapping.basin import template_features_at

    sch = plan.outcomes
    if sch is None or sch.decl is None or not sch.decl.templates:
        return None
    ns = max(plan.n_sample, 1)
    g = plan.size // ns
    return template_features_at(plan, plan.params_at(np.arange(g) * ns))


def per_trajectory_outcomes(plan) -> bool:
    """Whether a trajectory's outcome depends on it alone (rules, templates, verdicts), so that it is
    computed and stored with its chunk. False for a scheme that groups the whole sweep (attractor
    discovery, ``[outcomes] discover``): its outcome and basin variables come from
    :func:`stabjax.mapping.basin.dataset_vars` over every trajectory, when the sweep finishes."""
    decl = getattr(plan.scheme, "decl", None)
    return not getattr(decl, "discover", False)


def derive_chunk(plan, res: Mapping[str, np.ndarray], lo: int, hi: int, tf: np.ndarray | None) -> dict[str, np.ndarray]:
    """The stored record of trajectories [lo, hi): the engine's results with escaped trajectories'
    verdicts set to diverged (they ran away; not a solver failure) and, when the engine reports a
    solver status and the outcomes are per trajectory (:func:`per_trajectory_outcomes`), the
    ``outcome`` code of each trajectory (``tf``: :func:`template_features`)."""
    out = {k: np.asarray(v) for k, v in res.items()}
    if not plan.scheme.from_verdicts:
        # the attitude classifier's summaries (verdict, decay exponents, flips) read observable 0 as an
        # error and 1 as a size: they mean nothing for a model with its own outcomes, and are left out
        out = {k: v for k, v in out.items() if k.startswith("feat_") or k not in V.SUMMARY_DOC}
    if "verdict" in out and "solver_status" in out:
        out["verdict"] = status_verdicts(out["solver_status"], out["verdict"])  # escaped: diverged (stabjax.fold.status)
    if "solver_status" in out and per_trajectory_outcomes(plan):
        from ..model import outcomes as O
        from ..mapping.basin import CHUNK

        sch = plan.scheme
        if sch.from_verdicts:
            out["outcome"] = np.asarray(O.assign(sch, plan.system, out, {}), np.int8)
        else:
            codes = np.empty(hi - lo, np.int8)
            ns = max(plan.n_sample, 1)
            for a in range(lo, hi, CHUNK):
                b = min(hi, a + CHUNK)
                sl = {k: v[a - lo:b - lo] for k, v in out.items()}
                tfi = None if tf is None else tf[np.arange(a, b) // ns]
                codes[a - lo:b - lo] = O.assign(sch, plan.system, sl, plan.params_at(np.arange(a, b)), tfi)
            out["outcome"] = codes
    return out


def basin_vars(plan, codes) -> dict[str, tuple]:
    """Per-grid-point basin statistics over the samples, from the outcome codes (shape = plan.shape)."""
    from ..model import outcomes as O

    if not plan.n_sample:
        return {}
    sch = plan.scheme
    st = O.basin_stats(np.asarray(codes), len(sch.names))
    return _basin_layout(plan, st)


def outcome_extras(plan, codes, names: list[str]) -> dict[str, tuple]:
    """Variables that need every trajectory's outcome code (shape = plan.shape): the agreement with the
    labels of a starts file (:mod:`stabjax.plan.starts`) and the basin entropy of a 2-D grid of starts
    (:mod:`stabjax.mapping.entropy`). The store adds them when the sweep finishes."""
    from ..mapping import entropy
    from ..plan import starts

    codes = np.asarray(codes)
    data = dict(starts.dataset_vars(plan, codes, list(names)))
    if entropy.applies(plan):  # one start per cell of a 2-D grid of initial conditions: Daza et al. (2016)
        r = entropy.basin_entropy(codes.reshape(plan.shape))
        meta = {"box": r["box"], "boxes": r["n_boxes"], "boundary_boxes": r["n_boundary_boxes"],
                "cells_used": r["cells_used"], "units": "nats"}
        data["basin_entropy"] = ((), r["S_b"], {"long_name": "basin entropy S_b (Daza et al. 2016)", **meta})
        data["boundary_basin_entropy"] = ((), r["S_bb"], {
            "long_name": "boundary basin entropy S_bb (> ln 2: fractal boundary, sufficient condition)", **meta})
    return data


def _basin_layout(plan, st: Mapping[str, Any]) -> dict[str, tuple]:
    gdims = grid_layout(plan)[0] + ("outcome_name",)
    n = plan.n_sample
    return {
        "basin_count": (gdims, st["count"], {"long_name": f"trajectories per outcome (of N = {n})", "units": "1"}),
        "basin_fraction": (gdims, st["fraction"], {"long_name": f"basin stability S: fraction of N = {n} sampled "
                                                                "trajectories", "units": "1"}),
        "basin_se": (gdims, st["se"], {"long_name": "standard error sqrt(S (1 - S) / N)", "units": "1"}),
        "basin_ci_low": (gdims, st["ci_low"], {"long_name": "95% Wilson score interval, lower end", "units": "1"}),
        "basin_ci_high": (gdims, st["ci_high"], {"long_name": "95% Wilson score interval, upper end", "units": "1"}),
    }


def basin_placeholders(plan, chunks: bool = True) -> dict[str, tuple]:
    """The basin variables' layout with lazy placeholders (the store creates them; filled at the end)."""
    import dask.array as da

    if not plan.n_sample:
        return {}
    shape = grid_layout(plan)[1] + (len(plan.scheme.names),)
    st = {k: da.zeros(shape, dtype=np.int64 if k == "count" else float, chunks=shape)
          for k in ("count", "fraction", "se", "ci_low", "ci_high")}
    return _basin_layout(plan, st)


def _theory_vars(plan) -> tuple[dict[str, tuple[np.ndarray, dict]], str]:
    from ..model import theory_eval

    # filled in place chunk by chunk (not concatenated): at 10^7 trajectories the theory variables
    # alone are ~0.65 GB, and a concatenation would hold them twice
    full: dict[str, np.ndarray] = {}
    meta: dict[str, dict] = {}
    main = ""

    def put(key, lo, hi, val, dtype):
        if key not in full:
            full[key] = np.empty(plan.size, dtype=dtype)
        full[key][lo:hi] = np.broadcast_to(val, (hi - lo,))

    for lo in range(0, plan.size, THEORY_CHUNK):
        hi = min(plan.size, lo + THEORY_CHUNK)
        p = plan.system.check(plan.params_for(lo, hi))
        th = theory_eval.evaluate(plan.system, p)  # once per distinct set of the parameters it reads
        main = th.main
        for name, pred in th.predicates.items():
            put(f"theory_{name}", lo, hi, pred.ok, np.int8)
            put(f"margin_{name}", lo, hi, pred.margin, float)
            meta[f"theory_{name}"] = {"long_name": pred.doc, "flag_values": np.array([0, 1], np.int8),
                                      "flag_meanings": "not_guaranteed guaranteed"}
            meta[f"margin_{name}"] = {"long_name": f"signed margin of: {pred.doc} (> 0 inside)"}
        for name, val in th.derived.items():
            put(f"derived_{name}", lo, hi, val, float)
            meta[f"derived_{name}"] = {"long_name": th.derived_doc.get(name, name)}
    return {k: (v, meta[k]) for k, v in full.items()}, main


def build(plan, results: Mapping[str, Any], tf: np.ndarray | None = None,
          basin: Mapping[str, tuple] | None = None, whole: bool = True) -> xr.Dataset:
    """The sweep's Dataset from its per-trajectory records (:func:`derive_chunk` output), each shaped
    ``(*plan.shape, *trailing)`` (numpy, or dask placeholders for the store's layout). ``basin``:
    the basin variables (default: computed from ``results["outcome"]``). Without a stored outcome
    (a scheme over the whole sweep), ``whole`` adds :func:`whole_sweep_vars` (the store leaves them
    out of its layout and adds them when the sweep finishes)."""
    shape, dims = plan.shape, plan.dims
    coords: dict[str, Any] = {}
    data: dict[str, Any] = {}
    points = getattr(plan, "points", None)  # explicit grid points (P, n_axes) instead of the axes' product
    if points is not None:
        coords["point"] = ("point", np.arange(len(points)), {"long_name": "grid point index", "units": "1"})
    for a, ax in enumerate(plan.grid):
        attrs = {"long_name": ax.param.doc, "units": ax.param.unit, "spec_key": ax.key, "log_axis": int(ax.log)}
        if points is not None:
            coords[ax.name] = ("point", np.asarray(points)[:, a], attrs)
        elif ax.values.ndim == 1:
            coords[ax.name] = (ax.name, ax.values, attrs)
        else:  # vector-valued axis: index coordinate + the vectors as a variable
            coords[ax.name] = (ax.name, np.arange(ax.size), attrs)
            data[f"{ax.name}_value"] = ((ax.name, *[f"{ax.name}_c{i}" for i in range(ax.values.ndim - 1)]), ax.values)
    if plan.n_sample:
        coords["sample"] = ("sample", np.arange(plan.n_sample), {"long_name": "random draw index"})
        for k, v in plan.sample.items():
            prm = plan.system.params[k]
            extra = ("axis",) if v.shape[1:] == (3,) else tuple(f"{k}_c{i}" for i in range(v.ndim - 1))
            data[f"{k}_sample"] = (("sample", *extra), v, {"long_name": f"sampled {prm.doc}"})
    for k, v in results.items():
        if k == "outcome":
            continue
        extra = trailing_dims(k, v.ndim - len(shape))
        data[k] = ((*dims, *extra), v, {"long_name": V.SUMMARY_DOC.get(k, _DOC.get(k, k))})
        if "horizon" in extra and "horizon" not in coords:
            coords["horizon"] = ("horizon", V.horizon_times(plan.vcfg, plan.icfg.t0, plan.icfg.t1),
                                 {"long_name": "horizon T: verdicts of the prefix t <= T of each run"})
        if "observable" in extra and "observable" not in coords:
            coords["observable"] = ("observable", list(plan.system.observables)[: v.shape[-1]])
    if "stop_reason" in data:
        from ..fold.stops import REASONS

        data["stop_reason"][2].update(flag_values=np.arange(len(REASONS), dtype=np.int8), flag_meanings=" ".join(REASONS))
    if "verdict" in data:
        data["verdict"][2].update(flag_values=np.arange(len(V.NAMES), dtype=np.int8), flag_meanings=" ".join(V.NAMES))
    if "outcome" in results:
        sch = plan.scheme
        flags = dict(flag_values=np.arange(len(sch.names), dtype=np.int8), flag_meanings=" ".join(sch.names),
                     flag_colors=" ".join(sch.colors))
        data["outcome"] = (dims, results["outcome"], {"long_name": "outcome of the trajectory", **flags})
        coords["outcome_name"] = ("outcome_name", np.array(sch.names, dtype=object),
                                  {"long_name": "outcome name (code = index)"})
        if tf is not None:
            gdims, gshape = grid_layout(plan)
            data["template_features"] = ((*gdims, "template", "feature"), tf.reshape(*gshape, *tf.shape[1:]),
                                         {"long_name": "feature vectors of the templates at each grid point"})
            coords["template"] = ("template", np.array(list(sch.decl.templates), dtype=object))
            coords["feature"] = ("feature", np.array(list(sch.decl.features), dtype=object))
        data.update(basin if basin is not None else basin_vars(plan, results["outcome"]))
        if whole:
            data.update(outcome_extras(plan, np.asarray(results["outcome"]), list(sch.names)))
    elif whole and "solver_status" in results:
        flat = {k: np.asarray(v).reshape(plan.size, *np.shape(v)[len(shape):]) for k, v in results.items()}
        wdata, wcoords = whole_sweep_vars(plan, flat, tf)
        data.update(wdata)
        coords.update(wcoords)
    th, main = _theory_vars(plan)
    for k, (v, attrs) in th.items():
        data[k] = (dims, v.reshape(shape), attrs)
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(provenance(plan))
    ds.attrs.update(theory_main=main, n_trajectories=int(plan.size))
    cf_attributes(ds, plan)
    return ds


# ---- CF conventions ---------------------------------------------------------------------------------

CONVENTIONS = "CF-1.10"


def status_flags() -> tuple[np.ndarray, str]:
    """``solver_status``: diffrax's RESULTS codes (0 successful, 1 max_steps_reached, ...), in their
    order, and stabjax's own escaped (:data:`stabjax.fold.status.ESCAPED`)."""
    from ..fold.status import DIFFRAX_RESULTS

    names = list(DIFFRAX_RESULTS)
    return np.array([*range(len(names)), STATUS_ESCAPED], np.int32), " ".join([*names, "escaped"])


def _words(names) -> str:
    return " ".join(str(n).strip().replace(" ", "_") for n in names)


def cf_attributes(ds: xr.Dataset, plan, *, activity: str = "sweep", trajectories: int | None = None) -> xr.Dataset:
    """CF-1.10 metadata, in place: global ``Conventions``, ``title``, ``history``, ``source`` and
    ``references`` (the model's paper, where known); ``long_name`` and ``units`` on every numeric
    coordinate and variable (the models are written in nondimensional time and state, so a quantity
    without a declared unit is ``"1"``; text coordinates carry a ``long_name`` only); and
    ``flag_values``/``flag_meanings`` on every categorical variable (verdict, outcome, solver_status,
    decay_reason, theory predicates), so that CF tools (cf_xarray: ``ds.verdict.cf == "converged"``)
    decode the codes. ``activity``/``trajectories``: what produced the dataset, for ``title`` and
    ``history`` (a refinement runs fewer trajectories than its plan's grid holds)."""
    from ..version import __version__

    if "solver_status" in ds:
        values, meanings = status_flags()
        ds["solver_status"].attrs.update(long_name="solver status of the trajectory (diffrax RESULTS codes; "
                                                   "100: escaped the escape radius)",
                                         flag_values=values.astype(ds["solver_status"].dtype), flag_meanings=meanings)
    if "stop_reason" in ds:
        from ..fold.stops import REASONS

        ds["stop_reason"].attrs.update(flag_values=np.arange(len(REASONS), dtype=ds["stop_reason"].dtype),
                                       flag_meanings=" ".join(REASONS))
    if "decay_reason" in ds:
        codes = sorted(V.DECAY_REASONS)
        ds["decay_reason"].attrs.update(flag_values=np.array(codes, ds["decay_reason"].dtype),
                                        flag_meanings=_words(V.DECAY_REASONS[c] for c in codes))
    for name, var in ds.variables.items():
        if not var.attrs.get("long_name"):
            var.attrs["long_name"] = str(name).replace("_", " ")
        if var.dtype.kind in "biuf" and not var.attrs.get("units"):
            var.attrs["units"] = "1"
    sysname = plan.system.name
    title = getattr(plan.system, "title", "") or sysname
    created = ds.attrs.get("created") or time.strftime("%Y-%m-%dT%H:%M:%S%z")
    ds.attrs.update(
        Conventions=CONVENTIONS,
        title=f"stabjax {activity} {plan.name}: {title}",
        source=f"stabjax {__version__}: {sysname} integrated with {plan.icfg.solver} (rtol {plan.icfg.rtol:g}, "
               f"atol {plan.icfg.atol:g}) to t1 = {plan.icfg.t1:g}",
        history=f"{created}: stabjax {__version__} {activity} {plan.name} "
                f"({plan.size if trajectories is None else trajectories} trajectories)",
    )
    if getattr(plan.system, "paper", ""):
        ds.attrs["references"] = str(plan.system.paper)
    return ds


def whole_sweep_vars(plan, results: Mapping[str, Any], tf: np.ndarray | None = None) -> tuple[dict, dict]:
    """(data variables, coordinates) of a classification over the whole sweep: the outcome and basin
    variables from :func:`stabjax.mapping.basin.dataset_vars` over every trajectory (flat records, (N, ...))."""
    from ..mapping.basin import dataset_vars

    return dataset_vars(plan, {k: np.asarray(v) for k, v in results.items()}, tf)


def run_attrs(*, wall: float, steps: int, batch: int, n_resumed: int) -> dict[str, Any]:
    return dict(wall_time_s=float(wall), total_steps=int(steps), batch_size=int(batch), chunks_resumed=int(n_resumed))


def engines_of(manifest: Mapping[str, Any]) -> dict[str, list[list[int]]]:
    """Engine -> runs [first, last] of chunk indices it computed (compact per-chunk record)."""
    by = {}
    for i in sorted(int(k) for k in manifest["chunks"]):
        e = manifest["chunks"][str(i)].get("engine", "?")
        runs = by.setdefault(e, [])
        if runs and runs[-1][1] == i - 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return by


def engine_attrs(manifest: Mapping[str, Any], executor: str, note: str = "") -> dict[str, Any]:
    """Which engines computed the chunks (resumed ones included), where, and why not the first choice."""
    by = engines_of(manifest)
    return {"engine_note": note, "engine": ",".join(sorted(by)), "engine_chunks_json": json.dumps(by),
            "executor": executor}


def _git_commit() -> str:
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance(plan) -> dict[str, Any]:
    import jax

    from ..plan.spec import jsonable

    return {
        "system": plan.system.name,
        "sweep_name": plan.name,
        "paper": plan.system.paper,
        "spec_json": json.dumps(jsonable(plan.spec)),
        "fixed_params_json": json.dumps({k: np.asarray(v).tolist() for k, v in plan.fixed.items()}),
        "integrate_json": json.dumps({**plan.icfg.__dict__, "settings": dict(plan.icfg.settings)}),
        "verdict_json": json.dumps(plan.vcfg.__dict__),
        "system_ref": str(plan.spec.get("system", plan.system.name)),
        **identity_attrs(plan),  # fingerprint, model file and every local module it imports, with hashes
        "outcomes_from_verdicts": int(plan.scheme.from_verdicts),
        "versions_json": json.dumps(versions()),
        "git_commit": _git_commit(),
        "device": str(jax.devices()[0].device_kind) + f" x{jax.device_count()}",
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus".strip(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
