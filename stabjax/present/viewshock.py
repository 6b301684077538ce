"""The page of a minimal-fatal-shock result in ``stabjax view`` (issue 31, item 6: the witness one click away).

``|delta*|`` per grid point -- one dot with its bracket, a curve over one grid axis with the theorems' guaranteed
radii, or a map over two -- red flags marked; a click on a grid point, or on the witness in the start plane (a shock
of two parameter entries), re-simulates the witness start and the unshocked start with the settings the result
recorded, draws their observables against time side by side with the outcome each reached, and prints the command
that replays the witness. What a click means and the columns drawn are :mod:`stabjax.present.shock`'s (the
result's model, tested without a browser); this module is the Bokeh page, built by
:func:`stabjax.present.view.build` for a result of kind ``shock``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from . import shock as SH
from .labels import heading
from .viewmodel import Result, components, esc, status_text


def build_shock(doc, r: Result) -> None:
    """The page of a minimal-fatal-shock result: ``|delta*|`` per grid point (its bracket, the theorems' radii,
    red flags); a click on a grid point, or on the witness in the start plane, re-simulates the witness start and
    the unshocked start with the recorded settings, draws their observables against time side by side with the
    outcome each reached, and prints the command that replays the witness (:mod:`stabjax.present.shock`)."""
    from bokeh.layouts import column, row
    from bokeh.models import BoxAnnotation, ColumnDataSource, Div, HoverTool, Select, Span, TapTool
    from bokeh.plotting import figure

    ds = r.ds
    dims = SH.grid_dims(ds)
    data, how = SH.view_columns(ds)
    src = ColumnDataSource(data)
    state: dict[str, Any] = {"leading": 0}
    fmap = figure(title=f"{heading(ds)} (minimal fatal shocks) — click a grid point to replay its witness",
                  width=640, height=440, tools="tap,pan,wheel_zoom,box_zoom,reset,save", x_axis_label=how["x_label"],
                  y_axis_label=how["y_label"], name="map")
    if how["glyph"] == "quad":  # the clickable glyph first: the page's tests and readers find it there
        glyph = fmap.quad(left="left", right="right", bottom="bottom", top="top", source=src, fill_color="color",
                          line_color="line", line_width=2, selection_line_color="black", selection_line_width=3,
                          nonselection_fill_alpha=1.0)
    else:
        glyph = fmap.scatter(x="x", y="y", source=src, fill_color="color", line_color="black", size=11,
                             selection_line_width=3, nonselection_fill_alpha=0.8, legend_label="|delta*| at a grid point (red: a theorem refuted)")
        fmap.segment(x0="x", y0="lo", x1="x", y1="hi", source=src, line_color=SH.FOUND, line_width=3,
                     legend_label="bracket [lo, |delta*|]")
        for i, (th, line) in enumerate(how["theory"].items()):
            colour, dash = SH.THEORY_STYLES[i % len(SH.THEORY_STYLES)][0], ["dashed", "dotted", "dashdot", "dotdash"][i % 4]
            if how["dim"] is None:
                if np.isfinite(line) and line > 0:
                    fmap.add_layout(Span(location=float(line), dimension="width", line_color=colour,
                                         line_dash=dash, line_width=2))
                    fmap.line([-0.5, 0.5], [line, line], line_color=colour, line_dash=dash,
                              legend_label=f"radius guaranteed by {th}: {line:.4g}")
            else:
                fmap.line(x=line[0], y=line[1], line_color=colour, line_dash=dash, line_width=2,
                          legend_label=f"radius guaranteed by {th}")
        fmap.legend.label_text_font_size = "9pt"
        fmap.legend.location = "top_left"
    fmap.add_tools(HoverTool(renderers=[glyph], tooltips=[("", "@name")]))
    fmap.select_one(TapTool).renderers = [glyph]
    status = Div(text=status_text(r), width=640, name="status")
    verdicts = SH.theories(ds)
    table = "".join(f"<tr><td>{esc(th)}</td>" + "".join(
        f"<td>{int((np.asarray(ds[f'theory_verdict_{th}'].values) == k).sum())}</td>" for k in range(len(SH.VERDICT_NAMES))) + "</tr>"
        for th in verdicts)
    agree = Div(width=640, name="agreement", text=(
        "<b>Theorems against the minimal fatal shock</b> (grid points)<table style='font-size:12px'><tr><th></th>"
        + "".join(f"<th>{v}</th>" for v in SH.VERDICT_NAMES) + f"</tr>{table}</table>" if verdicts else
        "<p><b>Theory</b>: no theorem's region was searched against.</p>")
        + f"<div style='font-size:11px'>{esc(ds.attrs.get('statement', ''))}</div>")

    # the two trajectories of a click
    fts = figure(title="click a grid point: the witness start and the unshocked start against time", width=620,
                 height=320, x_axis_label="time t", y_axis_label="observable value", name="timeseries",
                 tools="pan,wheel_zoom,box_zoom,reset,save")
    late = BoxAnnotation(fill_color="#e9c46a", fill_alpha=0.25, name="late_window")
    fts.add_layout(late)
    lines: dict[tuple[str, str], Any] = {}
    palette = ["#264653", "#e76f51", "#2a9d8f", "#8d0801", "#6c757d", "#9b5de5", "#00bbf9", "#f15bb5"]
    for k, o in enumerate(list(r.plan.system.observables)[:8]):
        for who, dash in (("witness", "solid"), ("unshocked", "dashed")):
            lines[who, o] = fts.line("t", "y", source=ColumnDataSource(dict(t=[], y=[])), line_dash=dash,
                                     line_color=palette[k % len(palette)], line_width=1.5, legend_label=f"{o} ({who})",
                                     name=f"{who}:{o}")
    fts.legend.label_text_font_size = "9pt"
    fph = figure(title="phase portrait", width=620, height=300, name="phase", tools="pan,wheel_zoom,box_zoom,reset,save")
    ph = {who: ColumnDataSource(dict(x=[], y=[])) for who in ("witness", "unshocked")}
    fph.line("x", "y", source=ph["witness"], line_color="#d62728", line_width=1.3, legend_label="witness")
    fph.line("x", "y", source=ph["unshocked"], line_color="#264653", line_width=1.3, line_dash="dashed",
             legend_label="unshocked start")
    phx, phy = Select(title="phase x", width=150), Select(title="phase y", width=150)
    why = Div(text="<i>click a grid point (or the witness in the start plane)</i>", width=620, name="why")

    plane = SH.plane_columns(ds, 0)
    psrc: dict[str, Any] = {}
    fpl = None
    if plane is not None:
        cx, cy = plane["components"]
        fpl = figure(title="start plane: the shock ball and its witness (click the witness to replay it)", width=640,
                     height=440, x_axis_label=cx, y_axis_label=cy, name="plane", match_aspect=True,
                     tools="tap,pan,wheel_zoom,box_zoom,reset,save")
        psrc = {k: ColumnDataSource(plane[k]) for k in ("witness", "lo", "hi", "ball", "base")}
        wit = fpl.scatter("x", "y", source=psrc["witness"], marker="star", size=20, fill_color="red",
                          line_color="black", legend_label="witness (click: replay)")
        fpl.scatter("x", "y", source=psrc["lo"], size=5, color=SH.NONE_FOUND, legend_label="largest not fatal")
        fpl.scatter("x", "y", source=psrc["hi"], size=5, color="#D55E00", legend_label="fatal, bracket's end")
        fpl.line("x", "y", source=psrc["ball"], line_color=SH.FOUND, line_width=2, legend_label="ball |delta*|")
        fpl.scatter("x", "y", source=psrc["base"], size=9, color="black", legend_label="unshocked start")
        psrc["theory"] = ColumnDataSource(dict(xs=[v[0] for v in plane["theory"].values()],
                                               ys=[v[1] for v in plane["theory"].values()]))
        fpl.multi_line("xs", "ys", source=psrc["theory"], line_color="black", line_dash="dashed",
                       legend_label="guaranteed region(s)")
        fpl.select_one(TapTool).renderers = [wit]
        fpl.legend.label_text_font_size = "8pt"

    def show(g: int):
        st = SH.starts(r, g)
        ic = r.plan.icfg
        try:
            trajs = {"unshocked": r.run(st["base"])}
            if st["witness"] is not None:
                trajs["witness"] = r.run(st["witness"])
        except Exception as exc:  # noqa: BLE001 - shown on the page, the server keeps running
            why.text = f"<b>could not re-simulate grid point {g}</b>: {esc(type(exc).__name__)}: {esc(exc)}"
            return
        for (who, o), ln in lines.items():
            t = trajs.get(who)
            ln.data_source.data = dict(t=t["t"].values, y=t[o].values) if t is not None else dict(t=[], y=[])
        lo, hi = r.late_window()
        late.left, late.right = float(lo), float(hi)
        where = ", ".join(f"{k} = {float(v):.4g}" for k, v in st["sel"].items())
        fts.title.text = (f"{where + ': ' if where else ''}witness (solid), unshocked start (dashed); shaded: the "
                          "window outcomes are judged on")
        comps = {who: components(t) for who, t in trajs.items()}
        state["comps"] = comps
        opts = list(comps["unshocked"])
        if list(phx.options) != opts:
            phx.options, phy.options = opts, opts
            phx.value, phy.value = opts[0], opts[min(1, len(opts) - 1)]
        draw_phase()
        if plane is not None:
            bvals = [float(np.ravel(st["base"][e.split("[")[0]])[_entry_index(r, e)]) for e in plane["components"]]
            pl = SH.plane_columns(ds, g, np.array(bvals))
            for k in ("witness", "lo", "hi", "ball", "base"):
                psrc[k].data = pl[k]
            psrc["theory"].data = dict(xs=[v[0] for v in pl["theory"].values()], ys=[v[1] for v in pl["theory"].values()])
        names = ds.attrs.get("outcome_names", "").split()
        p = ds.sel(st["sel"]) if st["sel"] else ds
        reached = f"the unshocked start reaches <b>{esc(SH.outcome_name(ds, p['base_outcome'].values))}</b>"
        if st["witness"] is not None:
            reached += f"; the witness reaches <b>{esc(SH.outcome_name(ds, p['shock_witness_outcome'].values))}</b>"
        status_w = ", ".join(f"{who} solver status {t.attrs['solver_status']}" for who, t in trajs.items())
        rows = SH.point_rows(ds, g)
        why.text = (f"<b>grid point {g}</b>{': ' + esc(where) if where else ''} &mdash; {reached} (as the search "
                    f"classified them; outcomes: {esc(', '.join(names))})<br><i>re-simulated on the diffrax engine "
                    f"with the result's solver ({ic.solver}, rtol {ic.rtol:g}, atol {ic.atol:g}) to t1 = {ic.t1:g}; "
                    f"{esc(status_w)}</i><table style='font-size:12px'>"
                    + "".join(f"<tr><td><b>{esc(a)}</b></td><td>{esc(b)}</td></tr>" for a, b in rows) + "</table>"
                    + (f"<b>replay the witness</b>: <pre style='white-space:pre-wrap;font-size:11px'>"
                       f"{esc(st['command'])}</pre>" if st["command"] else "<b>no witness to replay</b>"))

    def draw_phase():
        comps = state.get("comps") or {}
        for who, s in ph.items():
            c = comps.get(who, {})
            s.data = dict(x=c[phx.value], y=c[phy.value]) if phx.value in c and phy.value in c else dict(x=[], y=[])
        fph.xaxis.axis_label, fph.yaxis.axis_label = phx.value, phy.value

    def on_select(_attr, _old, new):
        if new:
            show(int(src.data["idx"][new[0]]))

    def on_witness(_attr, _old, new):
        if new:
            show(int(psrc["witness"].data["idx"][new[0]]))

    src.selected.on_change("indices", on_select)
    if plane is not None:
        psrc["witness"].selected.on_change("indices", on_witness)
    phx.on_change("value", lambda _attr, _old, _new: draw_phase())
    phy.on_change("value", lambda _attr, _old, _new: draw_phase())
    lead = None
    if len(dims) >= 3:
        lead = Select(title=f"{dims[0]} (first axis)", value="0", width=200,
                      options=[(str(i), f"{v:.4g}") for i, v in enumerate(np.asarray(ds[dims[0]].values, float))])

        def on_lead(_a, _o, new):
            state["leading"] = int(new)
            src.data = SH.view_columns(ds, state["leading"])[0]

        lead.on_change("value", on_lead)
    left = column(*([lead] if lead is not None else []), fmap, status, agree, *([fpl] if fpl is not None else []))
    doc.add_root(row(left, column(why, fts, row(phx, phy), fph)))
    doc.title = f"stabjax view: {heading(ds)}"


def _entry_index(r: Result, key: str) -> int:
    """The flat index inside its parameter of a shocked entry ``key`` (``x0`` -> 0, ``S0[1]`` -> 1)."""
    name, _, idx = key.partition("[")
    shape = r.plan.system.params[name].shape
    return int(np.ravel_multi_index(tuple(int(i) for i in idx.rstrip("]").split(",")), shape)) if idx else 0
