"""The presentation kit: what every plot, the report and the viewer need to know about a result before
they draw it -- the opener, the kind, the system behind it, its outcomes' names, colours and codes, and
where its discovered attractors lie. The words on the figures (axis labels, titles, the theory's words)
are the kit's other half, :mod:`stabjax.present.labels`.

* :func:`open_result` -- the one way a result is read: a netCDF file, or a sweep's chunk store
  (running, interrupted or finished), the unfinished chunks marked by a ``pending`` variable;
* :func:`kind` -- what the result holds (:data:`KINDS`): attitude verdicts (``verdicts``), named
  outcomes of rules and templates (``basin``), discovered attractors (``discovery``), a boundary
  refinement (``refine``) and, for the regions-of-attraction search, minimal fatal shocks (``shock``);
  :func:`layout` -- how its trajectories are laid out (one grid axis with samples at each value is the
  ``along`` layout: fractions along an axis);
* :func:`system_of` -- the :class:`~stabjax.model.system.System` a result was computed with, or None;
* :func:`names_colors`, :func:`codes` -- outcome (or refinement label) names, colours and the code of
  every trajectory, whatever the kind;
* :func:`attractors` -- each discovered attractor's type, size and location (its representative), so
  that a reader tells ``fixed_point_1`` from ``fixed_point_2``.

Every kind is drawn by :func:`stabjax.present.show.plot` and summarised by
:func:`stabjax.present.show.summary` through the module and function its :class:`Kind` names; a new
kind of result is one entry in :data:`KINDS` and a module of its own beside this one. Nothing heavy is
imported at module level (xarray, matplotlib and JAX are imported where they are used).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..errors import ValidationError

if TYPE_CHECKING:
    import xarray as xr

# a running discovery has no outcomes yet (they come from grouping every trajectory when the sweep ends)
COMPUTED = "computed: outcome assigned when the sweep ends"
COMPUTED_COLOR = "#8ecae6"


# ---- kinds ---------------------------------------------------------------------------------------


def _outcomes_of_their_own(ds) -> bool:
    """Named outcomes of the model (rules, templates, discovery), not the attitude verdicts."""
    return not int(ds.attrs.get("outcomes_from_verdicts", 1))


@dataclass(frozen=True)
class Kind:
    """One kind of result: how to recognise it, what it is in words, and the functions (``module:function``
    in :mod:`stabjax.present`) that draw it (``draw(ds, out=None, title=None) -> Figure``) and write its
    summary text (``text(ds) -> str``)."""

    name: str
    words: str
    detect: Callable[[Any], bool]
    draw: str
    text: str


# detection order matters: the first kind whose test holds is the result's
KINDS: tuple[Kind, ...] = (
    Kind("refine", "boundary refinement", lambda ds: ds.attrs.get("kind") == "refine" or "segment" in ds.dims,
         "refinement:plot_refine", "refinement:format_summary"),
    # regions of attraction (issue 31): minimal fatal shocks and their witnesses, drawn by present/shock.py
    Kind("shock", "minimal fatal shocks", lambda ds: ds.attrs.get("kind") == "shock" or "shock_norm" in ds,
         "shock:plot_shock", "shock:format_summary"),
    # a finished discovery has its attractors; a running one has trajectories without outcomes yet
    Kind("discovery", "discovered attractors",
         lambda ds: "attractor" in ds.dims or ("outcome" not in ds and "verdict" not in ds
                                               and _outcomes_of_their_own(ds) and "solver_status" in ds),
         "basins:plot_basin", "basins:format_summary"),
    Kind("basin", "named outcomes", lambda ds: "outcome" in ds and _outcomes_of_their_own(ds),
         "basins:plot_basin", "basins:format_summary"),
    Kind("verdicts", "verdict map", lambda ds: "verdict" in ds, "maps:plot_sweep", "maps:format_confusion"),
)


def kind_of(ds: xr.Dataset) -> Kind | None:
    """The :class:`Kind` of ``ds``, or None for a dataset that is no stabjax result."""
    return next((k for k in KINDS if k.detect(ds)), None)


def kind(ds: xr.Dataset) -> str:
    """``"verdicts"``, ``"basin"``, ``"discovery"``, ``"refine"`` or ``"shock"`` (see :data:`KINDS`)."""
    k = kind_of(ds)
    if k is None:
        raise ValidationError("result", "not a stabjax result (no verdict, outcome, attractor or refinement points)")
    return k.name


def function(ref: str):
    """The function ``module:function`` of :mod:`stabjax.present` (imported now: plots import matplotlib)."""
    import importlib

    mod, _, fn = ref.partition(":")
    try:
        module = importlib.import_module(f"{__package__}.{mod}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.{mod}":
            raise
        raise ValidationError("result", f"this version of stabjax cannot show this kind of result "
                                        f"(no stabjax.present.{mod})") from None
    return getattr(module, fn)


def outcome_var(ds) -> str | None:
    """The variable holding each trajectory's outcome: ``outcome``, else ``verdict`` (None: a refinement or
    a running discovery, whose trajectories have no outcome yet)."""
    return "outcome" if "outcome" in ds else "verdict" if "verdict" in ds else None


def grid_dims(ds) -> list[str]:
    """The result's grid axes (its per-trajectory dims without ``sample`` and ``horizon``)."""
    var = outcome_var(ds) or ("pending" if "pending" in ds else "solver_status" if "solver_status" in ds else None)
    return [d for d in ds[var].dims if d not in ("sample", "horizon")] if var else []


def layout(ds) -> str:
    """How the trajectories are laid out: ``samples`` (random starts, no grid), ``along`` (one grid axis with
    samples at each value: fractions along the axis), ``map`` (two or more grid axes with samples: fractions
    per cell), ``cells`` (a grid, one trajectory per cell), ``points`` (a refinement's evaluated points)."""
    if kind_of(ds) is not None and kind(ds) == "refine":
        return "points"
    grid = grid_dims(ds)
    sampled = "sample" in ds.dims
    if sampled:
        return "samples" if not grid else "along" if len(grid) == 1 else "map"
    return "cells"


def along(ds) -> str | None:
    """The grid axis of an along-axis result (one axis, samples at each value), else None."""
    return grid_dims(ds)[0] if layout(ds) == "along" else None


# ---- the system behind a result --------------------------------------------------------------------


def system_of(ds):
    """The System a result was computed with (its file and class, ``system_ref``, else its registered name),
    or None when it cannot be loaded here (a model file moved away, a result of another version): a figure
    is then labelled from the dataset alone."""
    from ..model.loading import resolve

    for ref in (ds.attrs.get("system_ref"), ds.attrs.get("system")):
        if not ref:
            continue
        try:
            return resolve(str(ref))
        except Exception:  # noqa: BLE001 -- any failure to load means "no system here"
            continue
    return None


def param_of(ds, name: str):
    """The system's Param ``name`` (an entry ``A[1]`` or a grid axis' spec key resolved), or None."""
    key = ds[name].attrs.get("spec_key", name) if name in ds.coords else name
    system = system_of(ds)
    try:
        return system.params[str(key).split("[")[0]]
    except Exception:  # noqa: BLE001 -- unknown system or parameter: plotted as a number
        return None


def json_attr(ds, key: str, default: Any = None) -> Any:
    """A JSON attribute of the result, parsed (``default`` when absent or unreadable)."""
    try:
        return json.loads(ds.attrs[key])
    except (KeyError, ValueError, TypeError):
        return default


def t1_of(ds) -> float:
    """The result's horizon t1 (NaN when it does not record one)."""
    return float((json_attr(ds, "integrate_json", {}) or {}).get("t1", float("nan")))


# ---- outcomes: names, colours, codes ---------------------------------------------------------------


def names_colors(ds) -> tuple[list[str], list[str]]:
    """Names and colours of the outcomes (verdicts, named outcomes, a refinement's labels), as recorded
    (``flag_meanings``, ``flag_colors``); a running discovery's trajectories are all :data:`COMPUTED`."""
    from ..fold import verdict as V
    from ..model.outcomes import PALETTE

    if kind(ds) == "refine":
        names = ds.attrs["label_names"].split()
        cols = list(V.COLORS) if ds.attrs.get("label") == "verdict" else list(PALETTE)
        return names, [cols[i % len(cols)] for i in range(len(names))]
    if "outcome" in ds:
        names = str(ds["outcome"].attrs["flag_meanings"]).split()
        cols = str(ds["outcome"].attrs.get("flag_colors", "")).split()
        if len(cols) != len(names):
            cols = (list(V.COLORS) + list(PALETTE))[: len(names)]
        return names, cols
    if "verdict" in ds:
        return list(V.NAMES), list(V.COLORS)
    return [COMPUTED], [COMPUTED_COLOR]


def codes(ds) -> np.ndarray:
    """The outcome code of every trajectory, flat in the plan's order (C order over the grid, then the
    samples): the outcome, else the verdict at t1, else 0 (:data:`COMPUTED`: a running discovery)."""
    var = outcome_var(ds)
    if var is None:
        ref = "pending" if "pending" in ds else "solver_status"
        return np.zeros(int(np.prod(ds[ref].shape)), np.int64)
    da = ds[var]
    if "horizon" in da.dims:
        da = da.isel(horizon=-1)
    return np.asarray(da.values).ravel()


def outcome_codes(ds):
    """The outcome of every trajectory as a DataArray over the grid (and ``sample``): ``outcome``, else the
    verdict at t1; None for a result without per-trajectory outcomes."""
    var = outcome_var(ds)
    if var is None:
        return None
    return ds[var].isel(horizon=-1) if "horizon" in ds[var].dims else ds[var]


# ---- discovered attractors: where they are -----------------------------------------------------------


def attractors(ds) -> list[dict[str, Any]]:
    """Each discovered attractor of the result (empty for other kinds): ``name``, ``type``, ``count``,
    ``lyapunov`` (the median over its trajectories, at every grid point it lives at) and ``where`` -- the
    representative trajectory's state at t1 for a fixed point, the late-window range of each observable for an
    attractor that moves (a point of a cycle says little); over a grid with the grid point it is taken at."""
    if "attractor" not in ds.dims or "attractor_type" not in ds:
        return []
    out = []
    # under continuation an attractor spans the grid axis: its place is said at its representative's grid point
    # (grouped over the whole grid at once, too: one name may hold a different place at every grid point)
    on_grid = [str(d) for d in ds.dims if f"attractor_start_{d}" in ds]
    followed = "attractor_events" in ds
    feats = [str(f) for f in ds["attractor_feature"].values] if "attractor_feature" in ds.coords else []
    comps = [str(c) for c in ds["state_component"].values] if "state_component" in ds.coords else []
    for k, name in enumerate(ds["attractor"].values):
        typ = str(ds["attractor_type"].values[k])
        state = np.asarray(ds["attractor_state"].values[k], float) if "attractor_state" in ds and comps else None
        obs = [str(o) for o in ds["observable"].values] if "observable" in ds.coords else []
        if typ == "fixed_point" and state is not None and np.all(np.isfinite(state)):
            where = "at " + ", ".join(f"{c} = {_num(v)}" for c, v in zip(comps, state))
            how = int(ds["attractor_placed"].values[k]) if "attractor_placed" in ds else 0
            if how == 1:
                where += " (the stable equilibrium inside its last window: its trajectories still approach it at t1)"
            elif how == 2:
                where += " (the stable equilibrium its trajectories head for: still approaching it at t1)"
        elif typ == "fixed_point" and "attractor_observables" in ds and obs:  # its state could not be recomputed
            where = "at " + ", ".join(f"{o} = {_num(v)}" for o, v in zip(obs, ds["attractor_observables"].values[k]))
        elif "attractor_features" in ds and feats:
            f = np.asarray(ds["attractor_features"].values[k], float)
            obs = [n[4:-1] for n in feats if n.startswith("min(")]
            where = ", ".join(f"{o} in [{_num(f[feats.index(f'min({o})')])}, {_num(f[feats.index(f'max({o})')])}]"
                              for o in obs if f"max({o})" in feats)
            cover = _cover(ds, str(name), f, feats)
            if cover:
                where += f"; its trajectories' windows cover {cover}"
        else:
            where = ""
        if where and on_grid:  # one grid point's place, not the attractor's everywhere
            at = ", ".join(f"{d} = {_num(ds[f'attractor_start_{d}'].values[k])}" for d in on_grid)
            how = f"followed along {', '.join(on_grid)}" if followed else "grouped over the grid"
            where += f" (at {at}, its representative's grid point; {how})"
        out.append({"name": str(name), "type": typ,
                    "count": int(ds["attractor_count"].values[k]) if "attractor_count" in ds else -1,
                    "lyapunov": float(ds["attractor_lyapunov"].values[k]) if "attractor_lyapunov" in ds else np.nan,
                    "where": where})
    return out


COVER_SHARE = 0.05  # of an observable's range: members' windows spreading beyond the typical one's by more are said


def _cover(ds, name: str, f: np.ndarray, feats: list[str]) -> str:
    """What the windows of attractor ``name``'s trajectories cover together, per observable (``x in [lo, hi]``),
    where that reaches beyond the median window (``f``, the attractor's median features) by more than
    ``COVER_SHARE`` of the observable's range; else "". A group of trajectories resting at a continuum of points
    (x' = 0, y' = -y: a line of equilibria) was printed "x in [0.1647, 0.1647]", a typical member's window, while
    its members rest all over [-1.97, 1.99]; a cycle's or a chaotic attractor's members cover about its median
    window, and nothing is added."""
    need = ("outcome", "feat_min", "feat_max", "observable_range")
    if any(v not in ds for v in need) or "flag_meanings" not in ds["outcome"].attrs:
        return ""
    names = ds["outcome"].attrs["flag_meanings"].split()
    if name not in names:
        return ""
    obs = [str(o) for o in ds["observable"].values]
    lo_all = ds["feat_min"].transpose(..., "observable").values.reshape(-1, len(obs))
    hi_all = ds["feat_max"].transpose(..., "observable").values.reshape(-1, len(obs))
    mine = (ds["outcome"].values.reshape(-1) == names.index(name)) if lo_all.shape[0] == ds["outcome"].size else None
    if mine is None or not mine.any():
        return ""
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(lo_all[mine], axis=0), np.nanmax(hi_all[mine], axis=0)
    scale = np.asarray(ds["observable_range"].values, float)
    parts, wider = [], False
    for i, o in enumerate(obs):
        if f"min({o})" not in feats or f"max({o})" not in feats:
            continue
        m_lo, m_hi = f[feats.index(f"min({o})")], f[feats.index(f"max({o})")]
        wider |= bool((m_lo - lo[i]) + (hi[i] - m_hi) > COVER_SHARE * scale[i])
        parts.append(f"{o} in [{_num(lo[i])}, {_num(hi[i])}]")
    return ", ".join(parts) if wider else ""


def where_of(ds) -> dict[str, str]:
    """{attractor name: where it is} for a discovery result (empty otherwise): for legends and tables."""
    return {a["name"]: a["where"] for a in attractors(ds) if a["where"]}


def _num(x: float) -> str:
    x = float(x)
    return "0" if abs(x) < 5e-13 else f"{x:.4g}"


# ---- the opener ------------------------------------------------------------------------------------


def open_result(path: str | Path, *, field: str = "result", partial: bool = True,
                verified: dict | None = None) -> xr.Dataset:
    """The result at ``path``, loaded: a netCDF file a sweep, a refinement or ``stabjax export`` wrote, or a
    sweep's chunk store (``RESULT.nc.zarr``), finished, running or interrupted.

    A store is assembled with the sweep's own reader (:func:`stabjax.run.store.open_store`); a boolean
    ``pending`` variable over the grid marks the trajectories whose chunk has not finished (their values
    are fill values), and ``attrs["store_chunks"]`` says how many of how many chunks have. ``partial =
    False`` refuses an unfinished store instead (a figure or a report of part of a sweep would read as the
    whole). Anything that is not a stabjax result is refused with a :class:`~stabjax.errors.ValidationError`
    naming ``field``, never a traceback of the netCDF library.

    ``verified``: an empty dict, kept by a caller that reads the same store again and again (the viewer of a
    running sweep): the chunk files that matched their checksums are remembered there, and one unchanged
    since (same inode, size and modification time) is not read a second time to check it.
    """
    path = Path(path)
    if not path.exists():
        done = finished_file(path)
        hint = f" (its sweep has finished: the result is {done})" if done is not None and done.is_file() else ""
        raise ValidationError(field, f"not found: {path}{hint}")
    if path.is_dir():
        return _open_store(path, field, partial, verified)
    if not path.is_file():  # a FIFO would block the open forever
        raise ValidationError(field, f"{path} is not a regular file (a pipe, device or socket)")
    import xarray as xr

    try:
        ds = xr.load_dataset(path, engine="netcdf4")
    except Exception as exc:  # noqa: BLE001 - netCDF/HDF5 raise several types for a foreign file
        raise ValidationError(field, f"{path} is not a netCDF result ({type(exc).__name__})") from None
    if kind_of(ds) is None:
        raise ValidationError(field, f"{path} is not a stabjax result (no verdict, outcome, attractor or "
                                     "refinement points)")
    return ds


def finished_file(store: str | Path) -> Path | None:
    """The netCDF file a sweep writes from the store ``store`` when it finishes (``--store`` at its default
    place, ``OUT.nc.zarr`` for ``OUT.nc``); None for a store at a place of its own."""
    store = Path(store)
    return store.with_name(store.name[: -len(".zarr")]) if store.name.endswith(".nc.zarr") else None


def _open_store(path: Path, field: str, partial: bool, verified: dict | None = None):
    from ..run import dataset as D
    from ..run.store import (REWRITING, ROOT, StoreError, damage, holder, open_store, pending_mask, plan_from_manifest,
                             read_manifest, rounds_note)

    try:
        m = read_manifest(path)
    except StoreError as exc:
        raise ValidationError(field, f"{path}: {exc}") from None
    if m is None:
        raise ValidationError(field, f"{path} is a directory but not a sweep's chunk store (no manifest)"
                                     f"{rounds_note(path)}")
    pending = pending_mask(m)
    if not m.get("arrays") or pending.all():
        raise ValidationError(field, f"{path}: no chunk has finished yet; try again in a moment")
    if not partial and (pending.any() or not m.get("finished")):
        done = len(m.get("chunks", {}))
        raise ValidationError(field, f"{path} is a sweep's store with {done} of {m.get('n_chunks', '?')} chunks "
                                     "finished: watch it with stabjax view, or show it when the sweep has finished")
    if (m.get("metadata") or {}).get(ROOT) == REWRITING and not m.get("finished") and holder(path) is not None:
        raise ValidationError(field, f"{path}: its sweep is writing the statistics of its finished run; try again "
                                     "in a moment")
    try:
        problem = damage(path, m, verified)  # checked as export checks it: a damaged chunk is never shown as a value
    except StoreError as exc:
        problem = (str(exc), "Run the sweep command again: it recomputes them")
    if problem is not None:
        raise ValidationError(field, f"{path}: {problem[0]}; nothing is shown from it. {problem[1]}")
    plan = plan_from_manifest(m)
    ds = open_store(path).load()  # the store is the sweep's dataset (unfinished chunks: fill values)
    if not m.get("finished"):  # a running sweep: the engines so far (a finished store has its run's attributes)
        ds.attrs.update(D.engine_attrs(m, "store"))
    ds["pending"] = (plan.dims, pending, {"long_name": "not computed yet (running sweep)"})
    ds.attrs["store_chunks"] = f"{len(m.get('chunks', {}))}/{m.get('n_chunks', '?')}"
    return ds
