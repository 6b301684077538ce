"""``stabjax view RESULT``: an interactive explorer of a result in the browser (a Bokeh server).

Why Bokeh (``bokeh.server``): the explorer's interactions need Python -- a click on a cell must
re-simulate that trajectory with :func:`stabjax.engines.simulate.simulate` and the settings recorded in the
dataset -- and a Bokeh server runs Python callbacks on browser events with no JavaScript to build
or ship. It is one well-kept library (NumFOCUS, stable 3.x API) on Tornado; Panel and HoloViews
would add two layers on top of the same Bokeh models, and Dash would add Flask, React and Plotly.
The server binds the loopback address only (``127.0.0.1``): a result's file paths and the power
to run simulations are not offered to the network.

What it shows (one page, :func:`build`):

* the map of the result -- verdicts or outcomes per grid cell (sampled cells: the dominant
  outcome, paler where it is less sure), sampled starts coloured by outcome, or the points and
  bracketed boundary of a refinement -- with the theory's boundary and the confusion counts;
* a click on a cell or a sample re-simulates that trajectory: observables against time with the
  late window shaded, a phase portrait, and why it got its verdict and outcome (the rule that
  fired or the nearest template and its distance, escape, the classifier's summary numbers);
* the feature space of the samples coloured by outcome (with the templates), and the basin
  fractions along a swept parameter with their 95 % Wilson bands.

A running sweep's chunk store (``RESULT.nc.zarr``) can be viewed too: finished chunks are shown,
the others are marked pending, and the page refreshes as chunks land. Every read of a result goes
through :func:`read_result`, the only function here that knows the store's layout.

Size (~820 lines): one Bokeh page (:func:`build`, ~270 lines of linked figures and callbacks that
share its local state) and the pure functions that compute its columns (tested without a browser).
"""
from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from ..fold import status as S
from ..model import outcomes as O
from ..fold import verdict as V
from ..errors import ValidationError

LOOPBACK = "127.0.0.1"
PENDING_COLOR = "#f0f0f0"


# ---- reading a result ---------------------------------------------------------------------------


def read_result(path: str | Path) -> xr.Dataset:
    """The result at ``path``: a netCDF file, or a sweep's chunk store (possibly still being written).

    For a store, the finished chunks are assembled with the sweep's own code and a boolean
    ``pending`` variable (grid dims) marks the trajectories not computed yet. This is the only
    function of the viewer that reads the store (its format is the sweep's business).
    """
    from ..run.sweep import open_result

    path = Path(path)
    if not path.is_dir():
        try:
            ds = open_result(path)
        except ValidationError:
            raise
        except Exception as exc:  # noqa: BLE001 - netCDF/HDF5 raise several types for a foreign file
            raise ValidationError("result", f"{path} is not a netCDF result ({type(exc).__name__})") from None
        if not any(k in ds for k in ("verdict", "outcome", "point_label")):
            raise ValidationError("result", f"{path} is not a stabjax result (no verdict, outcome or refinement points)")
        return ds
    from ..run import dataset as D
    from ..run.store import open_store, pending_mask, plan_from_manifest, read_manifest

    m = read_manifest(path)
    if m is None:
        raise ValidationError("result", f"{path} is a directory but not a sweep's chunk store (no manifest)")
    plan = plan_from_manifest(m)
    pending = pending_mask(m)
    if not m.get("arrays") or pending.all():
        raise ValidationError("result", f"{path}: no chunk has finished yet; try again in a moment")
    ds = open_store(path).load()  # the store is the sweep's dataset (unfinished chunks: fill values)
    if not m.get("finished"):  # a running sweep: the engines so far (a finished store has its run's attributes)
        ds.attrs.update(D.engine_attrs(m, "store"))
    ds["pending"] = (plan.dims, pending, {"long_name": "not computed yet (running sweep)"})
    ds.attrs["store_chunks"] = f"{len(m.get('chunks', {}))}/{m.get('n_chunks', '?')}"
    return ds


def _json(ds, key, default=None):
    try:
        return json.loads(ds.attrs[key])
    except (KeyError, ValueError, TypeError):
        return default


class Result:
    """A loaded result and what the page needs from it: its map, its trajectories' parameters,
    their re-simulation and the explanation of their outcome."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._plan = None
        self.reload()

    def reload(self):
        from .report import kind

        self.ds = read_result(self.path)
        self.kind = kind(self.ds)
        self.running = "pending" in self.ds and bool(self.ds["pending"].any())

    # -- identity and re-simulation ---------------------------------------------------------------
    @property
    def plan(self):
        """The sweep plan, rebuilt from the spec and settings recorded in the dataset."""
        if self._plan is None:
            from ..plan.spec import make_plan

            spec = _json(self.ds, "spec_json")
            if spec is None:
                raise ValidationError("result", f"{self.path} records no spec: its trajectories cannot be re-run")
            integ = _json(self.ds, "integrate_json", {}) or {}
            self._plan = make_plan(spec, t1=integ.get("t1"))
        return self._plan

    def names_colors(self) -> tuple[list[str], list[str]]:
        """Outcome (or refinement label) names and their colours, as recorded (``flag_colors``)."""
        if self.kind == "refine":
            names = self.ds.attrs["label_names"].split()
            cols = list(V.COLORS) if self.ds.attrs.get("label") == "verdict" else list(O.PALETTE)
            return names, [cols[i % len(cols)] for i in range(len(names))]
        if "outcome" in self.ds:
            from .basins import outcome_colors, outcome_names

            return outcome_names(self.ds), outcome_colors(self.ds)
        return list(V.NAMES), list(V.COLORS)

    def params_of(self, idx: int) -> dict[str, np.ndarray]:
        """Every parameter of trajectory ``idx`` (flat sweep index, or refinement point index)."""
        plan = self.plan
        if self.kind == "refine":
            import dataclasses

            axes = self.ds.attrs["axes"].split()
            values = np.array([[float(self.ds[f"point_{a}"].values[idx]) for a in axes]])
            p = dataclasses.replace(plan, points=values).params_for(0, 1)  # the point's first sample
            return {k: np.asarray(v)[0] for k, v in p.items()}
        p = plan.params_at(np.array([idx]))
        return {k: np.asarray(v)[0] for k, v in p.items()}

    def simulate(self, idx: int, n_times: int = 1500) -> xr.Dataset:
        """Trajectory ``idx`` again, with the result's system, solver, tolerances and horizon."""
        from ..engines.simulate import simulate

        ic = self.plan.icfg
        lin = np.linspace(ic.t0, ic.t1, n_times // 2)
        geo = ic.t0 + np.geomspace(max((ic.t1 - ic.t0) * 1e-5, 1e-12), ic.t1 - ic.t0, n_times // 2)
        ts = np.unique(np.clip(np.concatenate([lin, geo]), ic.t0, ic.t1))
        return simulate(self.plan.system, self.params_of(idx), t1=ic.t1, t0=ic.t0, ts=ts, solver=ic.solver,
                        rtol=ic.rtol, atol=ic.atol, max_steps=ic.max_steps)

    def late_window(self) -> tuple[float, float]:
        """The window the classifier judges the end of a run on: the outcome features' last
        ``window`` fraction (named outcomes), else the verdict's last ``late_decades`` in log-time."""
        ic, vc = self.plan.icfg, self.plan.vcfg
        if self.kind == "basin" and self.plan.scheme.decl is not None:
            w = float(self.plan.scheme.decl.window)
            return ic.t1 - w * (ic.t1 - ic.t0), ic.t1
        return ic.t0 + (ic.t1 - ic.t0) * 10.0 ** (-float(vc.late_decades)), ic.t1

    # -- the map ----------------------------------------------------------------------------------
    def grid_dims(self) -> list[str]:
        var = "outcome" if "outcome" in self.ds else "verdict"
        return [d for d in self.ds[var].dims if d not in ("sample", "horizon")] if var in self.ds else []

    def codes(self) -> np.ndarray:
        """Outcome code of every trajectory, in the plan's flat order (verdicts at t1 without outcomes)."""
        if "outcome" in self.ds:
            return np.asarray(self.ds["outcome"].values).ravel()
        return np.asarray(V.at_t1(self.ds["verdict"]).values).ravel()

    def explain(self, idx: int, traj: xr.Dataset | None = None) -> list[tuple[str, str]]:
        """(what, value) rows saying why trajectory ``idx`` got its verdict and outcome (``traj``: its
        re-simulation, for the escape time)."""
        ds = self.ds
        names, _ = self.names_colors()
        rows: list[tuple[str, str]] = []
        if self.kind == "refine":
            lab = int(ds["point_label"].values[idx])
            rows.append(("label", f"{names[lab]} (share of samples {float(ds['point_share'].values[idx]):.2f})"))
            rows.append(("found in round", str(int(ds["point_round"].values[idx]))))
            return rows
        flat = {k: np.asarray(v.values).reshape(-1, *v.shape[len(self.plan.dims):])
                for k, v in ds.data_vars.items() if v.dims[: len(self.plan.dims)] == tuple(self.plan.dims)}
        one = {k: v[idx] for k, v in flat.items()}
        code = int(self.codes()[idx])
        rows.append(("outcome", names[code]))
        if "pending" in one and bool(one["pending"]):
            return [("status", "not computed yet (its chunk has not finished)")]
        if "verdict" in one:
            v = np.atleast_1d(one["verdict"])
            hs = ds["horizon"].values if "horizon" in ds.dims else [self.plan.icfg.t1]
            rows.append(("verdict at each horizon", ", ".join(f"T={T:.3g}: {V.NAMES[int(x)]}" for T, x in zip(hs, v))))
        st = int(one.get("solver_status", 0))
        if st == S.ESCAPED:
            when = ""
            if traj is not None:  # the re-run stops there too: its last finite save time
                fin = np.all([np.isfinite(traj[v].values.reshape(traj.sizes["t"], -1)).all(1)
                              for v in traj.data_vars if "t" in traj[v].dims], axis=0)
                when = f" at t ≈ {float(traj['t'].values[fin][-1]):.4g}" if fin.any() and not fin.all() else ""
            rows.append(("escape", f"stopped{when} once max|y_i| > {self.plan.system.escape_radius or '?'} "
                                   "(status 100): ran away"))
            rows.append(("assigned by", "the escape (before any rule or template)"))
        elif st != 0:
            rows.append(("solver", f"failed with status {st} (did not reach t1): outcome 'failed'"))
        else:
            rows += self._rule_rows(idx, code, one)
        for k in ("error_t1", "error_max_late", "t_settle", "n_flips", "t_first_flip", "decay_exponent", "peak_ratio"):
            if k in one:
                val = np.atleast_1d(one[k])[-1]
                rows.append((k, f"{float(val):.4g}  ({V.SUMMARY_DOC.get(k, '')})"))
        for k in [k for k in one if "lyap" in k.lower()]:
            rows.append((k, f"{float(np.ravel(one[k])[-1]):.4g}"))
        return rows

    def _rule_rows(self, idx: int, code: int, one: dict) -> list[tuple[str, str]]:
        """The rule that fired, or the nearest template and its distance (named outcomes only)."""
        sch = self.plan.scheme
        if sch.from_verdicts:
            return [("assigned by", "the verdict at t1 (this system names no outcomes of its own)")]
        decl = sch.decl
        system = self.plan.system
        res = {k: np.asarray(v)[None] for k, v in one.items() if k.startswith("feat_")}
        if not res:
            return []
        feat = O.feature_getter(res, tuple(system.observables))
        params = self.params_of(idx)

        def par(name):
            return np.asarray(params[name], float).reshape(1)

        obs, scalars = O._names(system)
        out = []
        for name, text in decl.rules.items():
            hit = bool(np.ravel(O.parse(text, obs, scalars, f"outcomes.rules.{name}")(feat, par))[0])
            out.append((f"rule {name}", f"{'holds' if hit else 'does not hold'}: {text}"))
            if hit:
                out.append(("assigned by", f"rule {name} (the first that holds)"))
                return out
        if decl.templates and "template_features" in self.ds:
            x = O.feature_matrix(decl, system, feat, par)[0]
            ns = max(self.plan.n_sample, 1)
            tf = np.asarray(self.ds["template_features"].values).reshape(-1, len(decl.templates), x.size)[idx // ns]
            d = np.linalg.norm(tf - x, axis=-1)
            j = int(np.nanargmin(d)) if np.isfinite(d).any() else 0
            out.append(("nearest template", f"{list(decl.templates)[j]} at distance {d[j]:.4g} "
                                            f"(features {', '.join(decl.features)})"))
        return out


# ---- the page ------------------------------------------------------------------------------------


def _edges(x: np.ndarray, log: bool) -> np.ndarray:
    from .maps import cell_edges

    return cell_edges(np.asarray(x, float), log)


def map_columns(r: Result, leading: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """(ColumnDataSource data, figure settings) of the result's map.

    One glyph per cell (grid results), per sampled start (samples only) or per evaluated point
    (refinement); ``idx`` is the trajectory a click re-simulates. ``leading``: the index along the
    first grid axis when there are three (the map shows the last two).
    """
    ds = r.ds
    names, colors = r.names_colors()
    label = lambda d: _axis_label(ds, d)  # noqa: E731
    if r.kind == "refine":
        axes = ds.attrs["axes"].split()
        lab = np.asarray(ds["point_label"].values).astype(int)
        xd = axes[1] if len(axes) == 2 else axes[0]
        x = np.asarray(ds[f"point_{xd}"].values, float)
        y = np.asarray(ds[f"point_{axes[0]}"].values, float) if len(axes) == 2 else lab.astype(float)
        data = dict(x=x, y=y, idx=np.arange(len(x)), color=[colors[k] for k in lab], name=[names[k] for k in lab],
                    alpha=np.ones(len(x)))
        return data, dict(glyph="scatter", x_label=_refine_label(ds, xd),
                          y_label=_refine_label(ds, axes[0]) if len(axes) == 2 else "label", log_x=False, log_y=False)
    codes = r.codes()
    dims = r.grid_dims()
    ns = max(r.plan.n_sample, 1)
    pending = np.asarray(ds["pending"].values).ravel() if "pending" in ds else np.zeros(codes.size, bool)
    if not dims:  # samples only: one dot per sampled start, at its first two sampled scalars
        keys = [k[: -len("_sample")] for k in ds.data_vars if k.endswith("_sample") and ds[k].dims == ("sample",)]
        x = ds[f"{keys[0]}_sample"].values if keys else np.arange(codes.size, dtype=float)
        y = ds[f"{keys[1]}_sample"].values if len(keys) > 1 else codes.astype(float)
        col = [PENDING_COLOR if p else colors[c] for c, p in zip(codes, pending)]
        data = dict(x=np.asarray(x, float), y=np.asarray(y, float), idx=np.arange(codes.size), color=col,
                    name=["pending" if p else names[c] for c, p in zip(codes, pending)], alpha=np.ones(codes.size))
        return data, dict(glyph="scatter", x_label=_param_label(r, keys[0]) if keys else "sample",
                          y_label=_param_label(r, keys[1]) if len(keys) > 1 else "outcome code", log_x=False,
                          log_y=False)
    shape = tuple(ds.sizes[d] for d in dims)
    per_point = codes.reshape(*shape, ns)
    pend = pending.reshape(*shape, ns)
    if len(dims) >= 3:  # the last two axes, at index `leading` of the first (and 0 of any others)
        sel = (leading,) + (0,) * (len(dims) - 3)
        per_point, pend = per_point[sel], pend[sel]
        base = np.ravel_multi_index(sel + (0, 0), shape) * ns
        dims2 = dims[-2:]
    else:
        base, dims2 = 0, dims
    frac = np.stack([(per_point == k).mean(-1) for k in range(len(names))], -1)
    dom, share = frac.argmax(-1), frac.max(-1)
    anypend = pend.any(-1)
    log = {d: bool(ds[d].attrs.get("log_axis", 0)) for d in dims2}
    if len(dims2) == 2:
        yd, xd = dims2
        xe, ye = _edges(ds[xd].values, log[xd]), _edges(ds[yd].values, log[yd])
        iy, ix = np.meshgrid(np.arange(len(ye) - 1), np.arange(len(xe) - 1), indexing="ij")
        iy, ix = iy.ravel(), ix.ravel()
        d, s, pe = dom.ravel(), share.ravel(), anypend.ravel()
        data = dict(left=xe[ix], right=xe[ix + 1], bottom=ye[iy], top=ye[iy + 1],
                    x=np.asarray(ds[xd].values, float)[ix], y=np.asarray(ds[yd].values, float)[iy],
                    idx=base + (iy * (len(xe) - 1) + ix) * ns,
                    color=[PENDING_COLOR if p else colors[k] for k, p in zip(d, pe)],
                    name=["pending" if p else names[k] + (f" ({v:.2f})" if ns > 1 else "") for k, v, p in zip(d, s, pe)],
                    alpha=(0.35 + 0.65 * s) if ns > 1 else np.ones(len(d)))
        return data, dict(glyph="quad", x_label=label(xd), y_label=label(yd), log_x=log[xd], log_y=log[yd],
                          xd=xd, yd=yd)
    xd = dims2[0]
    xe = _edges(ds[xd].values, log[xd])
    n = len(xe) - 1
    data = dict(left=xe[:-1], right=xe[1:], bottom=np.zeros(n), top=np.ones(n), x=np.asarray(ds[xd].values, float),
                y=np.full(n, 0.5), idx=base + np.arange(n) * ns,
                color=[PENDING_COLOR if p else colors[k] for k, p in zip(dom, anypend)],
                name=["pending" if p else names[k] + (f" ({v:.2f})" if ns > 1 else "") for k, v, p in zip(dom, share, anypend)],
                alpha=(0.35 + 0.65 * share) if ns > 1 else np.ones(n))
    return data, dict(glyph="quad", x_label=label(xd), y_label="", log_x=log[xd], log_y=False, xd=xd)


def _axis_label(ds, dim: str) -> str:
    """An axis in words with its unit: the parameter's description (its first clause), name and unit."""
    from .labels import words

    a = ds[dim].attrs if dim in ds.coords else {}
    return words(str(a.get("long_name", "")), dim, str(a.get("units", "")))


def _refine_label(ds, axis: str) -> str:
    a = ds[f"{axis}_mid"].attrs
    unit = a.get("units", "")
    return axis + (f" [{unit}]" if unit else "")


def _param_label(r: Result, name: str) -> str:
    from .labels import words

    try:
        p = r.plan.system.params[name]
        return words(p.doc, name, p.unit)
    except Exception:  # noqa: BLE001 - an unknown parameter is shown by its name
        return name


def theory_lines(r: Result, leading: int = 0) -> dict[str, list]:
    """The theory's boundary on the map: the zero contour of the main predicate's margin (xs, ys lists)."""
    ds = r.ds
    main = ds.attrs.get("theory_main") or ""
    xs, ys = [], []
    if r.kind == "refine":
        if "theory_margin" not in ds:
            return dict(xs=[], ys=[])
        axes = ds.attrs["axes"].split()
        if len(axes) != 2:
            return dict(xs=[], ys=[])
        m = ds["theory_margin"].transpose(f"{axes[0]}_theory", f"{axes[1]}_theory").values
        x, y = ds[f"{axes[1]}_theory"].values, ds[f"{axes[0]}_theory"].values
    else:
        dims = r.grid_dims()
        if f"margin_{main}" not in ds or len(dims) < 2:
            return dict(xs=[], ys=[])
        from .labels import categories

        m = ds[f"margin_{main}"]
        if "sample" in m.dims:
            m = m.isel(sample=0)
        if len(dims) >= 3:
            m = m.isel({dims[0]: leading, **{d: 0 for d in dims[1:-2]}})
        yd, xd = dims[-2:]
        if categories(ds, xd) or categories(ds, yd):
            return dict(xs=[], ys=[])
        m = m.transpose(yd, xd).values
        x, y = ds[xd].values, ds[yd].values
    if len(x) < 2 or len(y) < 2 or not (np.nanmin(m) < 0 < np.nanmax(m)):
        return dict(xs=[], ys=[])
    import contourpy

    gen = contourpy.contour_generator(np.asarray(x, float), np.asarray(y, float), np.asarray(m, float))
    for line in gen.lines(0.0):
        xs.append(line[:, 0].tolist())
        ys.append(line[:, 1].tolist())
    return dict(xs=xs, ys=ys)


def agreement_html(r: Result) -> str:
    """The theory x simulation counts (confusion) as a small table, or why there are none."""
    import html

    from .report import theory_section

    th = theory_section(r.ds) if r.kind != "basin" or "verdict" in r.ds else None
    if th is None:
        return "<p><b>Theory</b>: this system states no theorem here; nothing to compare.</p>"
    header, rows, sentences = th
    e = html.escape
    head = "".join(f"<th>{e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return (f"<b>Theory agreement</b><table class='confusion' style='border-collapse:collapse;font-size:12px'>"
            f"<tr>{head}</tr>{body}</table>" + "".join(f"<div style='font-size:12px'>{e(s)}</div>" for s in sentences))


def feature_columns(r: Result) -> dict[str, np.ndarray]:
    """Per-trajectory feature columns for the feature-space view: the declared outcome features
    (what templates are compared in) and every late-window statistic of every observable."""
    ds = r.ds
    cols: dict[str, np.ndarray] = {}
    stats = [k for k in ds.data_vars if k.startswith("feat_")]
    if not stats or r.kind == "refine":
        return cols
    n = r.codes().size
    obs = [str(o) for o in ds["observable"].values] if "observable" in ds.coords else []
    flat = {k: np.asarray(ds[k].values).reshape(n, -1) for k in stats}
    sch = r.plan.scheme
    if not sch.from_verdicts and sch.decl.features:
        feat = O.feature_getter({k: v for k, v in flat.items()}, tuple(r.plan.system.observables))
        allp = r.plan.params_at(np.arange(n))

        def par(name):
            return np.asarray(allp[name], float).reshape(n)

        x = O.feature_matrix(sch.decl, r.plan.system, feat, par)
        for j, f in enumerate(sch.decl.features):
            cols[f] = x[:, j]
    for k in stats:
        for j, o in enumerate(obs[: flat[k].shape[1]]):
            cols[f"{k[5:]}({o})"] = flat[k][:, j]
    return cols


def fraction_columns(r: Result, outcome: int, at: dict[str, int] | None = None) -> dict[str, Any] | None:
    """Basin fraction of one outcome along the last swept axis with its Wilson band, at the index
    ``at`` of every other grid axis (default 0; the page follows the clicked cell), or None when the
    result has no per-point fractions (no samples) or no swept axis."""
    ds = r.ds
    if "basin_fraction" not in ds or r.kind == "refine":
        return None
    dims = [d for d in ds["basin_fraction"].dims if d != "outcome_name"]
    if not dims:
        return None
    xd = dims[-1]
    sub = ds[["basin_fraction", "basin_ci_low", "basin_ci_high"]].isel(outcome_name=outcome)
    other = {d: int((at or {}).get(d, 0)) for d in dims[:-1]}
    sub = sub.isel(other) if other else sub
    where = ", ".join(f"{d} = {float(ds[d].values[i]):.4g}" for d, i in other.items())
    return dict(x=np.asarray(ds[xd].values, float), s=sub["basin_fraction"].values,
                lo=sub["basin_ci_low"].values, hi=sub["basin_ci_high"].values, dim=xd, where=where)


def build(doc, r: Result, refresh_s: float = 2.0) -> None:
    """Lay out the explorer for ``r`` in the Bokeh document ``doc`` and wire its callbacks."""
    from bokeh.layouts import column, row
    from bokeh.models import (BoxAnnotation, ColumnDataSource, Div, HoverTool, Legend, LegendItem, Select,
                              Spinner, TapTool)
    from bokeh.plotting import figure

    names, colors = r.names_colors()
    state: dict[str, Any] = {"leading": 0, "idx": None}
    dims = r.grid_dims()
    data, how = map_columns(r)
    src = ColumnDataSource(data)
    title = f"{r.ds.attrs.get('system', '')}: {r.ds.attrs.get('sweep_name', '')}"
    fmap = figure(title=f"{title} ({r.kind}) — click a cell or a dot to re-simulate it", width=640, height=480,
                  x_axis_type="log" if how["log_x"] else "linear", y_axis_type="log" if how["log_y"] else "linear",
                  tools="tap,pan,wheel_zoom,box_zoom,reset,save", x_axis_label=how["x_label"],
                  y_axis_label=how["y_label"], name="map")
    if how["glyph"] == "quad":
        glyph = fmap.quad(left="left", right="right", bottom="bottom", top="top", source=src, fill_color="color",
                          fill_alpha="alpha", line_color="white", line_width=0.5,
                          selection_line_color="black", selection_line_width=2.5, nonselection_fill_alpha="alpha")
    else:
        glyph = fmap.scatter(x="x", y="y", source=src, fill_color="color", line_color=None, size=7,
                             selection_line_color="black", selection_line_width=2, nonselection_fill_alpha=0.6)
    fmap.add_tools(HoverTool(renderers=[glyph], tooltips=[("", "@name"), ("x", "@x{0.0000}"), ("y", "@y{0.0000}")]))
    fmap.select_one(TapTool).renderers = [glyph]
    shown = [str(s).split(" (")[0] for s in data["name"]]
    items = [LegendItem(label=n, renderers=[glyph], index=shown.index(n)) for n in names if n in shown]
    if "pending" in shown:
        items.append(LegendItem(label="pending (running sweep)", renderers=[glyph], index=shown.index("pending")))
    tl = ColumnDataSource(theory_lines(r))
    th = fmap.multi_line(xs="xs", ys="ys", source=tl, line_color="black", line_width=2.5)
    main = r.ds.attrs.get("theory_main") or ""
    if tl.data["xs"]:
        items.append(LegendItem(label=f"theory boundary: {_theory_words(r, main)}", renderers=[th]))
    if r.kind == "refine" and len(r.ds.attrs["axes"].split()) == 2:
        a0, a1 = r.ds.attrs["axes"].split()
        mid = fmap.scatter(r.ds[f"{a1}_mid"].values, r.ds[f"{a0}_mid"].values, size=3, color="black")
        items.append(LegendItem(label="bracketed boundary (midpoints)", renderers=[mid]))
    fmap.add_layout(Legend(items=items, click_policy="hide", label_text_font_size="9pt"), "below")

    status = Div(text=_status_text(r), width=640, name="status")
    agree = Div(text=agreement_html(r), width=640, name="agreement")

    # trajectory panel
    ts_src = ColumnDataSource(dict(t=[], y=[], name=[]))
    fts = figure(title="click the map: observables of that trajectory against time", width=620, height=300,
                 x_axis_label="time t", y_axis_label="observable value", name="timeseries",
                 tools="pan,wheel_zoom,box_zoom,reset,save")
    ts_lines: list = []
    late = BoxAnnotation(fill_color="#e9c46a", fill_alpha=0.25, name="late_window")
    fts.add_layout(late)
    phase_src = ColumnDataSource(dict(x=[], y=[]))
    fph = figure(title="phase portrait", width=620, height=300, name="phase", tools="pan,wheel_zoom,box_zoom,reset,save")
    fph.line("x", "y", source=phase_src, line_color="#264653", line_width=1.2)
    start = ColumnDataSource(dict(x=[], y=[]))
    fph.scatter("x", "y", source=start, size=8, color="#e76f51", legend_label="start")
    why = Div(text="<i>click a cell or a dot on the map</i>", width=620, name="why")
    sample_pick = Spinner(title="sample within the cell", low=0, high=max(r.plan.n_sample - 1, 0), step=1, value=0,
                          width=160, visible=r.plan.n_sample > 1 and bool(dims))
    ph_opts: list[str] = []
    phx, phy = Select(title="phase x", width=150), Select(title="phase y", width=150)
    lead = None
    if len(dims) >= 3:
        lead = Select(title=f"{dims[0]} (first axis)", value="0", width=200,
                      options=[(str(i), f"{v:.4g}") for i, v in enumerate(np.asarray(r.ds[dims[0]].values, float))])

    def show(idx: int):
        state["idx"] = idx
        try:
            traj = r.simulate(idx)
        except Exception as exc:  # noqa: BLE001 - shown on the page, the server keeps running
            why.text = f"<b>could not re-simulate trajectory {idx}</b>: {type(exc).__name__}: {exc}"
            return
        obs = list(r.plan.system.observables)
        palette = ["#264653", "#e76f51", "#2a9d8f", "#8d0801", "#6c757d", "#9b5de5", "#00bbf9", "#f15bb5"]
        t = traj["t"].values
        for ln in ts_lines:
            ln.visible = False
        for k, o in enumerate(obs[:8]):
            if k >= len(ts_lines):
                s = ColumnDataSource(dict(t=[], y=[]))
                ts_lines.append(fts.line("t", "y", source=s, line_color=palette[k % len(palette)], line_width=1.4,
                                         legend_label=o))
            ts_lines[k].data_source.data = dict(t=t, y=traj[o].values)
            ts_lines[k].visible = True
        lo, hi = r.late_window()
        late.left, late.right = float(lo), float(hi)
        fts.title.text = (f"trajectory {idx}: observables against time (shaded: the late window the classifier "
                          f"judges, t ≥ {lo:.4g})")
        comps = _components(traj)
        nonlocal ph_opts
        if list(comps) != ph_opts:
            ph_opts = list(comps)
            phx.options, phy.options = ph_opts, ph_opts
            phx.value, phy.value = ph_opts[0], ph_opts[min(1, len(ph_opts) - 1)]
        state["comps"] = comps
        draw_phase()
        p = r.params_of(idx)
        swept = [a.param.name for a in r.plan.grid] + list(r.plan.sample)
        ptxt = ", ".join(f"{k} = {np.array2string(np.asarray(p[k]), precision=5)}" for k in dict.fromkeys(swept) if k in p)
        rows = r.explain(idx, traj)
        draw_templates(idx)
        if "follow" in state:
            state["follow"](idx)
        why.text = (f"<b>trajectory {idx}</b>: {ptxt}<br><i>re-simulated on the diffrax engine with the result's "
                    f"solver ({r.plan.icfg.solver}, rtol {r.plan.icfg.rtol:g}, atol {r.plan.icfg.atol:g}) to t1 = "
                    f"{r.plan.icfg.t1:g}; solver status {traj.attrs['solver_status']}</i>"
                    "<table style='font-size:12px'>" + "".join(f"<tr><td><b>{_esc(a)}</b></td><td>{_esc(b)}</td></tr>"
                                                             for a, b in rows) + "</table>")

    tmpl_src = ColumnDataSource(dict(xs=[], ys=[], name=[]))
    decl = None if r.kind == "refine" or r.plan.scheme.from_verdicts else r.plan.scheme.decl
    if decl is not None and decl.templates:
        fph.multi_line("xs", "ys", source=tmpl_src, line_color="#999999", line_dash="dashed", line_width=1,
                       legend_label="templates (same parameters)")

    def draw_templates(idx: int):
        """The templates' own trajectories at the clicked point: the attractors the outcome is named by."""
        if decl is None or not decl.templates:
            return
        base = r.params_of(idx)
        state["templates"] = []
        for name, over in decl.templates.items():
            full = r.plan.system.params.resolve(over)
            p = {**base, **{k: full[k] for k in over}}
            ic = r.plan.icfg
            try:
                from ..engines.simulate import simulate

                t = simulate(r.plan.system, p, t1=ic.t1, t0=ic.t0, solver=ic.solver, rtol=ic.rtol, atol=ic.atol,
                             max_steps=ic.max_steps)
            except Exception:  # noqa: BLE001 - a template that cannot run is left out of the picture
                continue
            state["templates"].append((name, _components(t)))
        draw_phase()

    def draw_phase():
        comps = state.get("comps") or {}
        if phx.value in comps and phy.value in comps:
            x, y = comps[phx.value], comps[phy.value]
            phase_src.data = dict(x=x, y=y)
            start.data = dict(x=x[:1], y=y[:1])
            fph.xaxis.axis_label, fph.yaxis.axis_label = phx.value, phy.value
            fph.title.text = f"phase portrait: {phy.value} against {phx.value}"
            tm = [(n, c) for n, c in state.get("templates", []) if phx.value in c and phy.value in c]
            tmpl_src.data = dict(xs=[c[phx.value] for _, c in tm], ys=[c[phy.value] for _, c in tm],
                                 name=[n for n, _ in tm])

    def on_select(_attr, _old, new):
        if new:
            show(int(src.data["idx"][new[0]]) + int(sample_pick.value or 0))

    def on_sample(_attr, _old, _new):
        sel = src.selected.indices
        if sel:
            show(int(src.data["idx"][sel[0]]) + int(sample_pick.value or 0))

    src.selected.on_change("indices", on_select)
    sample_pick.on_change("value", on_sample)
    phx.on_change("value", lambda _attr, _old, _new: draw_phase())
    phy.on_change("value", lambda _attr, _old, _new: draw_phase())

    # feature space and fractions
    extra = []
    fcols = feature_columns(r)
    if fcols:
        keys = list(fcols)
        codes = r.codes()
        fsrc = ColumnDataSource(dict(x=fcols[keys[0]], y=fcols[keys[min(1, len(keys) - 1)]],
                                     color=[colors[c] for c in codes], name=[names[c] for c in codes],
                                     idx=np.arange(codes.size)))
        ffs = figure(title="feature space: every trajectory, coloured by outcome (well separated classes = "
                           "trustworthy outcomes)", width=620, height=360, name="features",
                     tools="tap,pan,wheel_zoom,box_zoom,reset,save")
        # trajectories on one attractor share its features: coincident dots, a template's star on top
        fg = ffs.scatter("x", "y", source=fsrc, fill_color="color", line_color=None, size=9, alpha=0.6)
        ffs.add_tools(HoverTool(renderers=[fg], tooltips=[("", "@name"), ("trajectory", "@idx")]))
        fx, fy = Select(title="feature x", options=keys, value=keys[0], width=200), \
            Select(title="feature y", options=keys, value=keys[min(1, len(keys) - 1)], width=200)
        tsrc = ColumnDataSource(dict(x=[], y=[], name=[]))
        if "template_features" in r.ds:
            ffs.scatter("x", "y", source=tsrc, marker="star", size=18, fill_color=None, line_color="black",
                        line_width=1.5, legend_label="templates")
            ffs.legend.location = "top_left"

        def upd_features(_attr, _old, _new):
            fsrc.data = dict(fsrc.data, x=fcols[fx.value], y=fcols[fy.value])
            ffs.xaxis.axis_label, ffs.yaxis.axis_label = fx.value, fy.value
            if "template_features" in r.ds:
                feats = [str(f) for f in r.ds["feature"].values]
                tf = np.asarray(r.ds["template_features"].values).reshape(-1, r.ds.sizes["template"], len(feats))[0]
                if fx.value in feats and fy.value in feats:
                    tsrc.data = dict(x=tf[:, feats.index(fx.value)], y=tf[:, feats.index(fy.value)],
                                     name=[str(t) for t in r.ds["template"].values])
                else:
                    tsrc.data = dict(x=[], y=[], name=[])

        def on_feature_select(_a, _o, new):
            if new:
                show(int(fsrc.data["idx"][new[0]]))

        fsrc.selected.on_change("indices", on_feature_select)
        fx.on_change("value", upd_features)
        fy.on_change("value", upd_features)
        upd_features("value", None, None)
        extra.append(column(row(fx, fy), ffs))
    fr = fraction_columns(r, 0)
    fr_sources: dict[int, Any] = {}
    if fr is not None:
        ffr = figure(title=f"basin stability S along {fr['dim']}" + (f" at {fr['where']}" if fr["where"] else "")
                     + " (bands: 95% Wilson intervals)", width=620, height=320,
                     x_axis_label=_axis_label(r.ds, fr["dim"]), y_axis_label="basin stability S", y_range=(-0.02, 1.02),
                     name="fractions", tools="pan,wheel_zoom,box_zoom,reset,save")
        for k, (n, c) in enumerate(zip(names, colors)):
            if not np.any(r.ds["basin_fraction"].isel(outcome_name=k).values > 0):
                continue
            f = fraction_columns(r, k)
            fr_sources[k] = ColumnDataSource({key: v for key, v in f.items() if key not in ("dim", "where")})
            ffr.varea(x="x", y1="lo", y2="hi", source=fr_sources[k], fill_color=c, fill_alpha=0.25)
            ffr.line("x", "s", source=fr_sources[k], line_color=c, line_width=2, legend_label=n)
            ffr.scatter("x", "s", source=fr_sources[k], color=c, size=5)
        ffr.legend.label_text_font_size = "9pt"
        extra.append(ffr)

        def follow(idx: int):
            """The fractions along the last axis through the clicked cell (its other grid indices)."""
            gdims = r.grid_dims()
            if len(gdims) < 2:
                return
            point = np.unravel_index(idx // max(r.plan.n_sample, 1), [r.ds.sizes[d] for d in gdims])
            at = dict(zip(gdims[:-1], (int(i) for i in point[:-1])))
            for k, src_k in fr_sources.items():
                f = fraction_columns(r, k, at)
                src_k.data = {key: v for key, v in f.items() if key not in ("dim", "where")}
            ffr.title.text = f"basin stability S along {f['dim']} at {f['where']} (bands: 95% Wilson intervals)"

        state["follow"] = follow

    def refresh():
        before = r.ds.attrs.get("store_chunks")
        try:
            r.reload()
        except ValidationError:
            return
        if r.ds.attrs.get("store_chunks") != before:
            src.data = map_columns(r, state["leading"])[0]
            status.text = _status_text(r)
            agree.text = agreement_html(r)

    if lead is not None:
        def on_lead(_a, _o, new):
            state["leading"] = int(new)
            src.data = map_columns(r, state["leading"])[0]
            tl.data = theory_lines(r, state["leading"])

        lead.on_change("value", on_lead)
    if r.path.is_dir():
        doc.add_periodic_callback(refresh, int(refresh_s * 1000))
    left = column(*([lead] if lead is not None else []), fmap, status, agree, *extra)
    right = column(why, sample_pick, fts, row(phx, phy), fph)
    doc.add_root(row(left, right))
    doc.title = f"stabjax view: {title}"


def _theory_words(r: Result, main: str) -> str:
    """What the main predicate says: from the dataset (sweeps), else from the system's theory (a
    refinement records only the predicate's name)."""
    from .labels import words
    from .maps import theory_words

    if f"theory_{main}" in r.ds:
        return theory_words(r.ds, main)
    try:
        pred = r.plan.system.theory(r.plan.system.params.resolve()).predicates[main]
        return words(pred.doc, "", limit=60) or main
    except Exception:  # noqa: BLE001 - a theory that cannot be evaluated alone: its name
        return main


def _components(traj: xr.Dataset) -> dict[str, np.ndarray]:
    """Scalar time series of a simulated trajectory: state components first (x, y of a phase
    portrait), then the observables."""
    out: dict[str, np.ndarray] = {}
    for k, v in traj.data_vars.items():
        if "t" not in v.dims:
            continue
        if v.ndim == 1:
            out[k] = v.values
        else:
            flat = v.values.reshape(v.shape[0], -1)
            labels = [str(a) for a in v["axis"].values] if "axis" in v.dims else [str(i) for i in range(flat.shape[1])]
            for j in range(flat.shape[1]):
                out[f"{k}_{labels[j] if j < len(labels) else j}"] = flat[:, j]
    return out


def _esc(x) -> str:
    import html

    return html.escape(str(x))


def _status_text(r: Result) -> str:
    ds = r.ds
    n = int(ds.attrs.get("n_trajectories", 0))
    txt = (f"{r.path.name}: {n:,} trajectories; t1 = {r.plan.icfg.t1:g}; engine {ds.attrs.get('engine', '?')}; "
           f"created {ds.attrs.get('created', '?')}")
    if "pending" in ds and not r.running:
        txt = (f"<b>chunk store, every chunk finished</b> ({ds.attrs.get('store_chunks', '?')}); the netCDF file is "
               f"written when the sweep ends (or: stabjax export {r.path} --out FILE.nc)<br>" + txt)
    elif "pending" in ds:
        done = int((~np.asarray(ds["pending"].values)).sum())
        txt = (f"<b>running sweep</b>: {done:,} of {int(ds['pending'].size):,} trajectories finished "
               f"({ds.attrs.get('store_chunks', '?')} chunks; pending cells grey; refreshes as chunks land)<br>" + txt)
    return txt


# ---- the server ----------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def serve(path: str | Path, *, port: int = 0, show: bool = True, quit_after: float | None = None,
          refresh_s: float = 2.0, announce=print) -> None:
    """Serve the explorer of ``path`` on http://127.0.0.1:PORT/ until Ctrl-C (or ``quit_after`` seconds).

    The result is read once here, so a bad path fails before the server starts; each browser tab
    then gets its own page over the same loaded result.
    """
    try:
        from bokeh.application import Application
        from bokeh.application.handlers.function import FunctionHandler
        from bokeh.server.server import Server
    except ImportError:
        raise ValidationError("view", "needs Bokeh: pip install 'stabjax[view]'") from None
    result = Result(path)
    result.plan  # noqa: B018 - the spec must rebuild (a model file moved away is reported before serving)
    port = port or free_port()
    app = Application(FunctionHandler(lambda doc: build(doc, Result(path) if result.running else result, refresh_s)))
    server = Server({"/": app}, address=LOOPBACK, port=port, num_procs=1,
                    allow_websocket_origin=[f"{LOOPBACK}:{port}", f"localhost:{port}"])
    server.start()
    url = f"http://{LOOPBACK}:{port}/"
    announce(f"stabjax view: serving {path} at {url} (loopback only; Ctrl-C stops)")
    if quit_after is not None:  # scripts and tests: the server stops by itself
        server.io_loop.call_later(quit_after, server.io_loop.stop)
    if show:
        server.io_loop.add_callback(server.show, "/")
    try:
        server.io_loop.start()
    finally:
        server.stop()
