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
  fired or the nearest template and its distance, the attractor a discovery put it on, escape,
  the classifier's summary numbers);
* the feature space of the samples coloured by outcome (with the templates), and the basin
  fractions along a swept parameter with their 95 % Wilson bands;
* for a minimal-fatal-shock result, ``|delta*|`` per grid point, where a click replays the witness start
  beside the unshocked start (:mod:`stabjax.present.viewshock`).

A running or interrupted sweep's chunk store (``RESULT.nc.zarr``) can be viewed too: finished chunks are
shown, the others are marked pending, and the page refreshes as chunks land; when the sweep finishes and
removes its store, the page switches to the netCDF file it wrote (and says so). What a click means, the
re-simulation and the explanation are the viewer's model, :mod:`stabjax.present.viewmodel`; this module is
the Bokeh page and its server.
"""
from __future__ import annotations

import socket
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ValidationError
from .labels import attractor_label, axis_label, heading, theory_words
from .viewmodel import (Result, agreement_html, components, esc, feature_columns, fraction_columns,  # noqa: F401
                        map_columns, status_text, theory_lines)
from . import kit

LOOPBACK = "127.0.0.1"


# ---- the page ------------------------------------------------------------------------------------


def build(doc, r: Result, refresh_s: float = 2.0) -> None:
    """Lay out the explorer for ``r`` in the Bokeh document ``doc`` and wire its callbacks."""
    from bokeh.layouts import column, row
    from bokeh.models import (BoxAnnotation, ColumnDataSource, Div, HoverTool, Legend, LegendItem, Select,
                              Spinner, TapTool)
    from bokeh.plotting import figure

    if r.kind == "shock":  # its own page: delta* per grid point, a click replays the witness
        from .viewshock import build_shock

        return build_shock(doc, r)
    names, colors = r.names_colors()
    state: dict[str, Any] = {"leading": 0, "idx": None}
    dims = r.grid_dims()
    data, how = map_columns(r)
    src = ColumnDataSource(data)
    title = heading(r.ds)
    kind_words = kit.kind_of(r.ds).words
    fmap = figure(title=f"{title} ({kind_words}) — click a cell or a dot to re-simulate it", width=640, height=480,
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
    where = kit.where_of(r.ds)
    items = [LegendItem(label=attractor_label(n, where), renderers=[glyph], index=shown.index(n))
             for n in names if n in shown]
    if "pending" in shown:
        items.append(LegendItem(label="pending (running sweep)", renderers=[glyph], index=shown.index("pending")))
    tl = ColumnDataSource(theory_lines(r))
    th = fmap.multi_line(xs="xs", ys="ys", source=tl, line_color="black", line_width=2.5)
    main = r.ds.attrs.get("theory_main") or ""
    if tl.data["xs"]:
        items.append(LegendItem(label=f"theory boundary: {theory_words(r.ds, main)}", renderers=[th]))
    if r.kind == "refine" and len(r.ds.attrs["axes"].split()) == 2:
        a0, a1 = r.ds.attrs["axes"].split()
        mid = fmap.scatter(r.ds[f"{a1}_mid"].values, r.ds[f"{a0}_mid"].values, size=3, color="black")
        items.append(LegendItem(label="bracketed boundary (midpoints)", renderers=[mid]))
    fmap.add_layout(Legend(items=items, click_policy="hide", label_text_font_size="9pt"), "below")

    status = Div(text=status_text(r), width=640, name="status")
    agree = Div(text=agreement_html(r), width=640, name="agreement")

    # trajectory panel
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
        comps = components(traj)
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
                    "<table style='font-size:12px'>" + "".join(f"<tr><td><b>{esc(a)}</b></td><td>{esc(b)}</td></tr>"
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
            state["templates"].append((name, components(t)))
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
                     x_axis_label=axis_label(r.ds, fr["dim"], math=False), y_axis_label="basin stability S",
                     y_range=(-0.02, 1.02),
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
        """Read the store again: redraw the map as chunks land; rebuild the page when what it shows changed
        (the sweep finished and the result file replaced its store, a discovery's outcomes arrived)."""
        before = (r.path, r.ds.attrs.get("store_chunks"), r.names_colors()[0])
        try:
            r.reload()
        except Exception as exc:  # noqa: BLE001 - said on the page; the server keeps running
            status.text = f"<b>could not read {esc(r.path)} again</b>: {esc(type(exc).__name__)}: {esc(exc)}"
            return
        if (r.path, r.names_colors()[0]) != (before[0], before[2]):
            for cb in list(doc.session_callbacks):
                doc.remove_periodic_callback(cb)
            doc.clear()
            build(doc, r, refresh_s)
            return
        if r.ds.attrs.get("store_chunks") != before[1]:
            src.data = map_columns(r, state["leading"])[0]
            agree.text = agreement_html(r)
        status.text = status_text(r)

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


# ---- the server ----------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def page(doc, result: Result, refresh_s: float = 2.0) -> None:
    """The page of one browser tab: over the shared result (a file), or over its own reading of a store
    (which may have finished and been removed since); a result that cannot be read any more is said on
    the page, not answered with an HTTP error."""
    try:
        r = result.session()
    except Exception as exc:  # noqa: BLE001 - the page says what happened
        from bokeh.models import Div

        doc.add_root(Div(text=f"<b>stabjax view: {esc(result.path)} cannot be read</b>: {esc(exc)}", name="status",
                         width=800))
        return
    build(doc, r, refresh_s)


def serve(path: str | Path, *, port: int = 0, show: bool = True, quit_after: float | None = None,
          refresh_s: float = 2.0, announce=print) -> None:
    """Serve the explorer of ``path`` on http://127.0.0.1:PORT/ until Ctrl-C (or ``quit_after`` seconds).

    The result is read once here, so a bad path fails before the server starts; each browser tab
    then gets its own page (:func:`page`) over the same loaded result, or its own reading of a store.
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
    app = Application(FunctionHandler(lambda doc: page(doc, result, refresh_s)))
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