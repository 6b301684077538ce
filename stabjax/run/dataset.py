"""The layout of a sweep's dataset, defined once for the chunk store and the netCDF file.

A sweep's results reach the user two ways: the zarr chunk store (:mod:`stabjax.run.store`), which a
user may open with ``xr.open_zarr`` while the sweep runs, and the netCDF file. Both are laid out by
:func:`build` from the same inputs, so they hold the same variables: the per-trajectory records
(:func:`stabjax.run.derive.chunk`) and what the derive step computed from them
(:class:`stabjax.run.derive.Derived`: outcomes, the mapper's variables, basin statistics, entropy,
the starts file's agreement, theory, provenance). The store is created from :func:`build` over
placeholders (its layout) and filled chunk by chunk; the variables known only when every trajectory is in
(:func:`outcome_vars`) are added when the sweep finishes; the netCDF file is a copy of the finished
store (or, for a sweep without an output file, :func:`build` over the records kept in memory).

This module computes nothing: names, dims, attributes and the CF conventions.
"""
from __future__ import annotations

import json
import time
from typing import Any, Mapping

import numpy as np
import xarray as xr

from ..fold import verdict as V
from ..fold.status import ESCAPED as STATUS_ESCAPED
from ..mapping.mapper import grid_layout

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


def basin_vars(plan, stats: Mapping[str, Any] | None) -> dict[str, tuple]:
    """The basin statistics (:func:`stabjax.mapping.basin.basin_stats` over the grid points, or the store's
    placeholders) as variables over (grid axes..., ``outcome_name``); none without ``[sample]``."""
    if stats is None:
        return {}
    gdims = grid_layout(plan)[0] + ("outcome_name",)
    n = plan.n_sample
    return {
        "basin_count": (gdims, stats["count"], {"long_name": f"trajectories per outcome (of N = {n})", "units": "1"}),
        "basin_fraction": (gdims, stats["fraction"], {"long_name": f"basin stability S: fraction of N = {n} sampled "
                                                                   "trajectories", "units": "1"}),
        "basin_se": (gdims, stats["se"], {"long_name": "standard error sqrt(S (1 - S) / N)", "units": "1"}),
        "basin_ci_low": (gdims, stats["ci_low"], {"long_name": "95% Wilson score interval, lower end", "units": "1"}),
        "basin_ci_high": (gdims, stats["ci_high"], {"long_name": "95% Wilson score interval, upper end", "units": "1"}),
    }


def outcome_vars(plan, derived, codes) -> tuple[dict[str, Any], dict[str, Any]]:
    """(data variables, coordinates) of the outcomes, in the dataset's order: ``outcome`` (``codes``, shaped
    like the plan) with its CF flags, the mapper's own variables, the basin statistics, the starts file's
    labels and the basin entropy of ``derived`` (:class:`stabjax.run.derive.Derived`)."""
    mapped = derived.mapped
    sch = mapped.scheme
    flags = dict(flag_values=np.arange(len(sch.names), dtype=np.int8), flag_meanings=" ".join(sch.names),
                 flag_colors=" ".join(sch.colors))
    data: dict[str, Any] = {"outcome": (plan.dims, codes, {"long_name": "outcome of the trajectory", **flags})}
    coords: dict[str, Any] = {"outcome_name": ("outcome_name", np.array(sch.names, dtype=object),
                                               {"long_name": "outcome name (code = index)"})}
    data.update(mapped.data)
    coords.update(mapped.coords)
    data.update(basin_vars(plan, derived.basin))
    data.update(derived.starts)
    r = derived.entropy
    if r is not None:
        meta = {"box": r["box"], "boxes": r["n_boxes"], "boundary_boxes": r["n_boundary_boxes"],
                "cells_used": r["cells_used"], "units": "nats"}
        data["basin_entropy"] = ((), r["S_b"], {"long_name": "basin entropy S_b (Daza et al. 2016)", **meta})
        data["boundary_basin_entropy"] = ((), r["S_bb"], {
            "long_name": "boundary basin entropy S_bb (> ln 2: fractal boundary, sufficient condition)", **meta})
    return data, coords


def build(plan, records: Mapping[str, Any], derived) -> xr.Dataset:
    """The sweep's Dataset: the per-trajectory ``records`` (:func:`stabjax.run.derive.chunk` output), each
    shaped ``(*plan.shape, *trailing)`` (numpy, or dask placeholders for the store's layout), and the
    computed variables of ``derived`` (:class:`stabjax.run.derive.Derived`). The outcome codes are the
    records' ``outcome`` (a per-trajectory mapper) or the derived ones (a whole-set mapper); without
    either (the store's layout of a whole-set mapper) the outcome variables are left out."""
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
            data[f"{k}_sample"] = (("sample", *extra), v, {"long_name": f"sampled {prm.doc}",
                                                            **({"units": prm.unit} if prm.unit else {})})
    for k, v in records.items():
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
    if derived.mapped is not None:
        codes = records["outcome"] if "outcome" in records else derived.mapped.codes
        if codes is not None:
            odata, ocoords = outcome_vars(plan, derived, np.reshape(codes, shape) if isinstance(codes, np.ndarray)
                                          else codes)
            data.update(odata)
            coords.update(ocoords)
    values, meta, main = derived.theory
    for k, v in values.items():
        data[k] = (dims, v.reshape(shape), meta[k])
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(derived.provenance)
    if derived.warnings is not None:  # what the outcome stage warned (the store's layout: added when it finishes)
        from .derive import warnings_attr

        ds.attrs.update(warnings_attr(derived.warnings))
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
