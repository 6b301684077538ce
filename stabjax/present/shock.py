"""What a person sees of a minimal-fatal-shock search (:mod:`stabjax.explore.shock`): a summary in words, the
figures, and the report's section.

Figures (:func:`plot_shock`): without a grid, the minimal fatal shock of the attractor with its bracket and the
theorems' guaranteed radii; along one grid axis, ``|delta*|(p)`` with its bracket as a band over the guaranteed
radii, red flags marked; on two axes, a map of ``|delta*|``. When the shock moves two entries (a start plane),
a second panel draws the plane: each scanned direction's exit bracket, the ball of radius ``|delta*|`` in the
search's norm, the theorems' balls, the witness -- over a basin picture when one is given (``basin``: a sweep of
the same two parameters, its ``outcome`` or ``verdict`` map).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import xarray as xr

VERDICT_NAMES = ("refuted", "consistent", "conservative", "not_applicable", "untested")  # shock_result.VERDICTS


def theories(ds: xr.Dataset) -> list[str]:
    return [str(v)[len("theory_radius_"):] for v in ds.data_vars if str(v).startswith("theory_radius_")]


def outcome_name(ds: xr.Dataset, code) -> str:
    names = str(ds.attrs.get("outcome_names", "")).split()
    code = int(code)
    return names[code] if 0 <= code < len(names) else "none"


def grid_dims(ds: xr.Dataset) -> list[str]:
    return list(ds["shock_norm"].dims)


def _points(ds: xr.Dataset):
    """(selection dict, point dataset) of every grid point."""
    dims = grid_dims(ds)
    if not dims:
        yield {}, ds
        return
    for idx in np.ndindex(*[ds.sizes[d] for d in dims]):
        sel = {d: ds[d].values[i] for d, i in zip(dims, idx)}
        yield sel, ds.sel(sel)


def format_summary(ds: xr.Dataset, limit: int = 12) -> str:
    """The search in words: attractor, norm, |delta*| and its bracket, witness, effort, the theorems' verdicts (a red
    flag with the command that replays its witness)."""
    from ..explore.shock_result import witness_replay

    cfg = json.loads(ds.attrs.get("shock_json", "{}"))
    lines = [f"minimal fatal shock of {ds.attrs.get('system', '?')} ({ds.attrs.get('sweep_name', '')}): shocked "
             f"{', '.join(cfg.get('components', []))}; norm {ds.attrs.get('norm', '?')}",
             f"effort: {ds.attrs.get('n_trajectories', 0):,} trajectories in {ds.attrs.get('rounds', 0)} rounds, "
             f"{ds.attrs.get('n_directions', 0)} directions scanned; {float(ds.attrs.get('wall_time_s', np.nan)):.1f} s"]
    shown = 0
    flags = []
    for sel, p in _points(ds):
        where = ", ".join(f"{k} = {float(v):g}" for k, v in sel.items())
        att = outcome_name(ds, p["base_outcome"].values)
        hi, lo = float(p["shock_norm"].values), float(p["shock_norm_lo"].values)
        if np.isnan(lo):
            row = f"  {where or 'start'}: the unshocked start reaches {att}: no search"
        elif np.isnan(hi):
            row = f"  {where or 'start'}: from {att}: no fatal shock up to {lo:.4g}"
        else:
            w = ", ".join(f"{c} = {v:.4g}" for c, v in zip(ds["component"].values, p["shock_witness"].values))
            row = (f"  {where or 'start'}: from {att}: |delta*| = {hi:.4g} (bracket [{lo:.4g}, {hi:.4g}]) "
                   f"-> {outcome_name(ds, p['shock_witness_outcome'].values)}; witness {w}")
        und = float(p["shock_undecided_norm"].values) if "shock_undecided_norm" in p else np.nan
        if np.isfinite(und) and not und >= hi:  # a smaller shock whose fate is unknown: the answer may be smaller
            row += f"; a start shocked by {und:.4g} was left undecided (counted as not fatal)"
        for th in theories(ds):
            v = int(p[f"theory_verdict_{th}"].values)
            r = float(p[f"theory_radius_{th}"].values)
            f_lo, f_hi = float(p[f"theory_factor_lo_{th}"].values), float(p[f"theory_factor_hi_{th}"].values)
            if v == 0:
                flags.append((th, where, r, hi, witness_replay(ds, **sel)["command"]))
                # refuted by the radius, or by the predicate holding at the witness (its region need not be a ball:
                # a radius below the shock does not make the comparison true)
                row += (f"; {th}: RED FLAG (radius {r:.4g} > a fatal shock {hi:.4g})" if r > hi else
                        f"; {th}: RED FLAG (its hypothesis holds at the fatal witness, norm {hi:.4g})")
            elif v == 2:
                row += f"; {th}: conservative by {f_lo:.3g}" + (f"..{f_hi:.3g}" if np.isfinite(f_hi) else "+") + \
                       f" (radius {r:.4g})"
            elif v == 1:
                row += f"; {th}: consistent (radius {r:.4g} within the resolution)"
            elif v == 4:
                row += f"; {th}: untested (radius {r:.4g} beyond the largest shock searched, {lo:.4g})"
            else:
                row += f"; {th}: not applicable"
        if shown < limit:
            lines.append(row)
        shown += 1
    if shown > limit:
        lines.append(f"  ... {shown - limit} more grid points (in the file)")
    lines.append("statement: " + str(ds.attrs.get("statement", "")))
    for th, where, r, hi, cmd in flags[:5]:
        inside = (f"inside the guaranteed radius {r:.4g}" if r > hi else
                  f"where its hypothesis holds (inside its region, whose largest ball has radius {r:.4g})")
        lines.append(f"RED FLAG {th}{' at ' + where if where else ''}: a start at norm {hi:.4g} {inside} does not "
                     f"reach the attractor. Replay: {cmd}")
    if len(flags) > 5:
        lines.append(f"... {len(flags) - 5} more red flags")
    return "\n".join(lines)


# ---- figures --------------------------------------------------------------------------------------------

# eight distinct (colour, dash) pairs (Okabe-Ito colours): a fifth theorem repeated the first's line
THEORY_STYLES = (("#000000", "--"), ("#D55E00", ":"), ("#009E73", "-."), ("#CC79A7", (0, (5, 2, 1, 2))),
                 ("#E69F00", "--"), ("#56B4E9", ":"), ("#000000", "-."), ("#D55E00", (0, (1, 1))))


def plot_shock(ds: xr.Dataset, out: str | Path | None = None, basin: xr.Dataset | None = None, title: str | None = None):
    """The figure of a shock result (see the module docstring); written to ``out`` if given. Returns the figure."""
    import matplotlib.pyplot as plt

    from .maps import legend_below, save

    plane = ds.sizes.get("component", 0) == 2 and "direction_scale" in ds
    fig, axs = plt.subplots(1, 2 if plane else 1, figsize=(12.5 if plane else 6.8, 5.4), constrained_layout=True,
                            squeeze=False)
    ax = axs[0, 0]
    dims = grid_dims(ds)
    if len(dims) == 1:
        _curve(ax, ds, dims[0])
    elif len(dims) == 2:
        _map(fig, ax, ds, dims)
    else:
        _single(ax, ds)
    h, lab = ax.get_legend_handles_labels()
    if h:
        legend_below(ax, h, ncol=1, width=70)
    if plane:
        _plane(axs[0, 1], ds, basin)
    import textwrap

    fig.suptitle(textwrap.fill(title or f"Minimal fatal shock: {ds.attrs.get('system', '')} "
                                        f"({ds.attrs.get('sweep_name', '')})", 80), fontsize=10)
    return save(fig, out, dpi=100)


def _size_label(ds) -> str:
    """The shock-size axis's label: the norm's words in full, wrapped (cut at 90 characters, it ended mid-word)."""
    import textwrap

    return "\n".join(textwrap.wrap(f"size of the shock, {ds.attrs.get('norm', '')}" + _unit(ds), 60))


def _unit(ds):
    u = str(ds["shock_norm"].attrs.get("units", "1"))
    return "" if u in ("", "1") else f" [{u}]"


def _theory_lines(ax, ds, x=None):
    for i, th in enumerate(theories(ds)):
        col, ls = THEORY_STYLES[i % len(THEORY_STYLES)]
        r = np.asarray(ds[f"theory_radius_{th}"].values, float)
        r = np.where(np.isinf(r), np.nan, r)
        what = str(ds[f"theory_radius_{th}"].attrs.get("theorem", "")).split(": ", 1)[-1].split(";")[0] or th
        label = f"radius guaranteed by {th}: {what}"
        if x is None:
            if np.isfinite(r).any() and float(r) > 0:
                ax.axhline(float(r), color=col, ls=ls, lw=1.8, label=f"{label}: {float(r):.4g}")
        else:
            ax.plot(x, np.where(r > 0, r, np.nan), color=col, ls=ls, lw=1.8, marker=".", label=label)


def _red_flags(ax, ds, x=None):
    for th in theories(ds):
        bad = np.asarray(ds[f"theory_verdict_{th}"].values) == 0
        if bad.any():
            y = np.asarray(ds["shock_norm"].values)
            ax.plot(np.asarray(x)[bad] if x is not None else [0], y[bad] if x is not None else [float(y)], "x",
                    color="red", ms=13, mew=2.5, zorder=1, label=f"red flag: a fatal shock inside the region of {th}")


def _single(ax, ds):
    hi, lo = float(ds["shock_norm"].values), float(ds["shock_norm_lo"].values)
    att = outcome_name(ds, ds["base_outcome"].values)
    if np.isfinite(hi):
        ax.errorbar([0], [hi], yerr=[[hi - lo], [0]], fmt="o", color="#0072B2", capsize=6, ms=8,
                    label=f"minimal fatal shock found: {hi:.4g} (bracket [{lo:.4g}, {hi:.4g}])")
    elif np.isnan(lo):  # nothing searched: the unshocked start reached no attractor to shock
        ax.plot([0], [0], "x", color="#6c757d", ms=9, label=f"no search: the unshocked start reaches {att}")
    else:
        ax.plot([0], [lo], "^", color="#009E73", ms=9, label=f"no fatal shock up to {lo:.4g}")
    _theory_lines(ax, ds)
    _red_flags(ax, ds)
    ax.set_xticks([0], [f"from {att}"])
    ax.set_xlim(-1, 1)
    tops = [v for v in [hi, lo] + [float(ds[f"theory_radius_{t}"]) for t in theories(ds)] if np.isfinite(v)]
    ax.set_ylim(0, 1.15 * max(tops) if tops else None)
    ax.set_ylabel(_size_label(ds))


def _curve(ax, ds, dim):
    from .labels import axis_label

    x = ds[dim].values
    hi, lo = ds["shock_norm"].values, ds["shock_norm_lo"].values
    ax.fill_between(x, lo, hi, color="#56B4E9", alpha=0.5, label="bracket of the minimal fatal shock")
    ax.plot(x, hi, "o-", color="#0072B2", zorder=3, label="minimal fatal shock found |delta*| (a fatal start exists)")
    none = np.isnan(hi) & np.isfinite(lo)
    if none.any():
        ax.plot(x[none], lo[none], "^", color="#009E73", label="no fatal shock found up to this size")
    _theory_lines(ax, ds, x)
    _red_flags(ax, ds, x)
    ax.set_xlabel(axis_label(ds, dim))
    ax.set_ylabel(_size_label(ds), fontsize=8)
    ax.set_ylim(0, None)
    ax.grid(alpha=0.3)


def _map(fig, ax, ds, dims):
    from .labels import axis_label

    v = ds["shock_norm"].transpose(dims[1], dims[0]).values
    m = ax.pcolormesh(ds[dims[0]].values, ds[dims[1]].values, v, shading="nearest", cmap="viridis")
    fig.colorbar(m, ax=ax, label="minimal fatal shock |delta*|" + _unit(ds))
    ax.set_xlabel(axis_label(ds, dims[0]))
    ax.set_ylabel(axis_label(ds, dims[1]))


def _plane(ax, ds, basin):
    """The start plane at the first grid point: exits along the scanned directions, the shock ball, the witness."""
    p = ds.isel({d: 0 for d in grid_dims(ds)})
    comps = [str(c) for c in ds["component"].values]
    base = np.asarray(p["shock_witness"].values - p["shock_delta"].values, float)
    if not np.all(np.isfinite(base)):
        base = np.zeros(2)
    if basin is not None:
        _basin(ax, basin, comps)
    U = ds["direction_vector"].values
    sc = np.asarray(p["direction_scale"].values, float)
    lo, hi = np.asarray(p["direction_exit_lo"].values), np.asarray(p["direction_exit_hi"].values)
    pts = lambda r: base + (U / sc[:, None]) * r[:, None]  # noqa: E731 - a radius in the norm along each direction
    ax.plot(*pts(lo).T, ".", color="#009E73", ms=5, label="largest not-fatal shock found along a direction")
    ok = np.isfinite(hi)
    ax.plot(*pts(hi)[ok].T, ".", color="#D55E00", ms=5, label="fatal shock at the bracket's end along a direction")
    th = np.linspace(0, 2 * np.pi, 721)
    circ = np.stack([np.cos(th), np.sin(th)], 1)
    scale = _norm_of(ds, p, circ)
    hi0 = float(p["shock_norm"].values)
    if np.isfinite(hi0):
        ax.plot(*(base + circ * (hi0 / scale)[:, None]).T, "-", color="#0072B2", lw=2,
                label=f"shock ball of radius |delta*| = {hi0:.4g} in the search's norm")
        w = np.asarray(p["shock_witness"].values, float)
        ax.plot(*w, "*", color="red", ms=15, mec="k", label=f"witness: reaches {outcome_name(ds, p['shock_witness_outcome'].values)}")
    for i, name in enumerate(theories(ds)):
        r = float(p[f"theory_radius_{name}"].values)
        if np.isfinite(r) and r > 0:
            col, ls = THEORY_STYLES[i % len(THEORY_STYLES)]
            # the ball of the search's norm the theorem guarantees, not its region's shape (an ellipse V < 1 is
            # drawn as the largest such ball inside it: "region of" called that circle the region)
            ax.plot(*(base + circ * (r / scale)[:, None]).T, color=col, ls=ls, lw=1.6,
                    label=f"ball guaranteed by {name} (radius {r:.4g}, the search's norm)")
    ax.plot(*base, "o", color="k", ms=6, label=f"the attractor's start ({outcome_name(ds, p['base_outcome'].values)})")
    ax.set_xlabel(comps[0])
    ax.set_ylabel(comps[1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("start plane: the shock ball and its witness", fontsize=9)


def _norm_of(ds, p, circ):
    """The norm of the unit vectors ``circ`` (M, 2), interpolated from the scanned directions' scale (the norm of a
    parameter shift is a norm: its unit ball is convex and even, so the interpolation in angle is close)."""
    U = ds["direction_vector"].values
    sc = np.asarray(p["direction_scale"].values, float)
    ang = np.arctan2(U[:, 1], U[:, 0])
    ang = np.concatenate([ang, ang + np.pi])
    sc = np.concatenate([sc, sc])
    order = np.argsort(ang)
    a, s = ang[order], sc[order]
    a = np.concatenate([a - 2 * np.pi, a, a + 2 * np.pi])
    s = np.concatenate([s, s, s])
    return np.interp(np.arctan2(circ[:, 1], circ[:, 0]), a, s)


def _basin(ax, basin: xr.Dataset, comps):
    """The outcome map of a sweep over the same two parameters, under the shock picture."""
    from matplotlib.colors import ListedColormap

    var = "outcome" if "outcome" in basin else "verdict"
    da = basin[var]
    if "horizon" in da.dims:
        da = da.isel(horizon=-1)
    names = comps if all(c in da.dims for c in comps) else [c.replace("[", "_").rstrip("]") for c in comps]
    if not all(n in da.dims for n in names):
        return
    colors = str(da.attrs.get("flag_colors", "")).split() or None
    k = len(str(da.attrs.get("flag_meanings", "")).split()) or int(np.nanmax(da.values)) + 1
    cmap = ListedColormap(colors) if colors else "tab10"
    ax.pcolormesh(basin[names[0]].values, basin[names[1]].values, da.transpose(names[1], names[0]).values,
                  shading="nearest", cmap=cmap, vmin=-0.5, vmax=k - 0.5, alpha=0.35)


# ---- the report's section -----------------------------------------------------------------------------------


def report_parts(ds: xr.Dataset) -> list[tuple[str, str]]:
    """(heading, HTML) of the shock section of ``stabjax report``."""
    import base64
    import html
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig = plot_shock(ds)
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    png = base64.b64encode(buf.getvalue()).decode()
    text = html.escape(format_summary(ds, limit=40))
    return [("Minimal fatal shock", f"<pre>{text}</pre>"),
            ("Figure", f"<figure><img alt='minimal fatal shock' src='data:image/png;base64,{png}'><figcaption>"
                       "The minimal fatal shock with its bracket and the theorems' guaranteed radii."
                       "</figcaption></figure>"),
            ("Witnesses", witness_table(ds))]


def witness_table(ds: xr.Dataset, limit: int = 40) -> str:
    """HTML table of the witness start of every grid point (the first ``limit``): the start, the outcome it reaches
    (and re-checked with tighter tolerances) and the ``stabjax simulate`` command that replays it."""
    import html

    from ..explore.shock_result import witness_replay

    e = html.escape
    comps = [str(c) for c in ds["component"].values]
    head = "".join(f"<th>{e(h)}</th>" for h in ("grid point", "|delta*|", "witness start", "reaches", "command"))
    rows, found = [], 0
    for sel, p in _points(ds):
        rep = witness_replay(ds, **sel)
        if not rep["found"]:
            continue
        found += 1
        if found > limit:
            continue
        reach = outcome_name(ds, p["shock_witness_outcome"].values)
        if "shock_witness_recheck" in ds:
            reach += f" (re-checked: {outcome_name(ds, p['shock_witness_recheck'].values)})"
        start = ", ".join(f"{c} = {v:.10g}" for c, v in zip(comps, p["shock_witness"].values))
        cells = [e(", ".join(f"{k} = {float(v):g}" for k, v in sel.items()) or "start"),
                 f"{float(p['shock_norm'].values):.6g}", e(start), e(reach), f"<code>{e(rep['command'])}</code>"]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    if not rows:
        return "<p>No fatal shock was found at any grid point: no witness to replay.</p>"
    more = f"<p>... and {found - limit} more witnesses (in the file)</p>" if found > limit else ""
    return (f"<p>Each witness is a fatal start: replay it with its command (or click its grid point in "
            f"<code>stabjax view</code>).</p><table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody>"
            f"</table>{more}")


# ---- the viewer's model (stabjax view): what a click on a grid point means -------------------------------------
# Pure functions of the loaded result (and, for the starts, of its rebuilt plan); the Bokeh page that draws them is
# stabjax.present.view. A grid point is addressed by its flat index ``g``, C order over the grid axes.

FOUND, NONE_FOUND, NOT_SEARCHED, RED_FLAG = "#0072B2", "#009E73", "#bdbdbd", "#d62728"


def point_of(ds: xr.Dataset, g: int) -> dict:
    """The selection (one value per grid axis) of flat grid index ``g``; ``{}`` without a grid."""
    dims = grid_dims(ds)
    if not dims:
        return {}
    idx = np.unravel_index(int(g), [ds.sizes[d] for d in dims])
    return {d: ds[d].values[i] for d, i in zip(dims, idx)}


def _refuted(ds: xr.Dataset) -> np.ndarray:
    """Flat mask of the grid points where some theorem is refuted (a red flag)."""
    n = int(np.prod([ds.sizes[d] for d in grid_dims(ds)]))
    bad = np.zeros(n, bool)
    for th in theories(ds):
        bad |= np.asarray(ds[f"theory_verdict_{th}"].values).ravel() == 0
    return bad


def point_words(ds: xr.Dataset) -> list[str]:
    """One line per grid point (flat order): |delta*| and its bracket, the outcome of the witness, a red flag."""
    hi = np.asarray(ds["shock_norm"].values, float).ravel()
    lo = np.asarray(ds["shock_norm_lo"].values, float).ravel()
    wo = np.asarray(ds["shock_witness_outcome"].values).ravel()
    base = np.asarray(ds["base_outcome"].values).ravel()
    bad = _refuted(ds)
    out = []
    for k in range(hi.size):
        if np.isnan(lo[k]):
            out.append(f"not searched: the unshocked start reaches {outcome_name(ds, base[k])}")
        elif np.isnan(hi[k]):
            out.append(f"no fatal shock up to {lo[k]:.4g} from {outcome_name(ds, base[k])}")
        else:
            out.append(f"|delta*| = {hi[k]:.4g} in [{lo[k]:.4g}, {hi[k]:.4g}]: {outcome_name(ds, base[k])} -> "
                       f"{outcome_name(ds, wo[k])}" + ("; RED FLAG" if bad[k] else ""))
    return out


def view_columns(ds: xr.Dataset, leading: int = 0) -> tuple[dict, dict]:
    """(columns, settings) of the viewer's figure of ``|delta*|``, one clickable glyph per grid point (``idx``: its
    flat grid index): without a grid one dot with its bracket; along one axis ``|delta*|(p)`` with the bracket
    (``lo``, ``hi``), where no fatal shock was found the bracket's lower end (no witness there); on two or more axes
    a map of ``|delta*|`` over the last two (at index ``leading`` of the first of three, 0 of any others), a red
    flag's cell outlined. Settings: ``glyph``, axis labels and ``theory`` ({name: (x, radius)} lines along an axis,
    {name: radius} without a grid)."""
    from .labels import axis_label

    dims = grid_dims(ds)
    hi = np.asarray(ds["shock_norm"].values, float)
    lo = np.asarray(ds["shock_norm_lo"].values, float)
    words = point_words(ds)
    bad = _refuted(ds)
    ylab = f"size of the shock, {ds.attrs.get('norm', '')}"[:80] + _unit(ds)
    found = np.isfinite(hi.ravel())
    color = np.where(bad, RED_FLAG, np.where(found, FOUND, np.where(np.isfinite(lo.ravel()), NONE_FOUND,
                                                                    NOT_SEARCHED))).tolist()
    radius = {th: np.asarray(ds[f"theory_radius_{th}"].values, float) for th in theories(ds)}
    if len(dims) <= 1:
        x = np.asarray(ds[dims[0]].values, float) if dims else np.zeros(1)
        y = np.where(found, hi.ravel(), lo.ravel())
        data = dict(x=x, y=y, lo=lo.ravel(), hi=hi.ravel(), idx=np.arange(y.size), color=color, name=words)
        theory = {th: ((x, np.where(r.ravel() > 0, r.ravel(), np.nan)) if dims else float(r)) for th, r in radius.items()}
        return data, dict(glyph="scatter", x_label=axis_label(ds, dims[0], math=False) if dims else "",
                          y_label=ylab, theory=theory, dim=dims[0] if dims else None)
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    from .maps import cell_edges

    shape = [ds.sizes[d] for d in dims]
    sel = (leading,) + (0,) * (len(dims) - 3) if len(dims) >= 3 else ()
    yd, xd = dims[-2:]
    flat = np.arange(hi.size).reshape(shape)[sel]
    log = {d: bool(ds[d].attrs.get("log_axis", 0)) for d in (xd, yd)}
    xe, ye = cell_edges(ds[xd].values, log[xd]), cell_edges(ds[yd].values, log[yd])
    iy, ix = (a.ravel() for a in np.meshgrid(np.arange(len(ye) - 1), np.arange(len(xe) - 1), indexing="ij"))
    idx = flat[iy, ix]
    h = hi.ravel()[idx]
    span = (np.nanmin(hi), np.nanmax(hi)) if np.isfinite(hi).any() else (0.0, 1.0)
    cmap = colormaps["viridis"]
    scaled = (h - span[0]) / (span[1] - span[0]) if span[1] > span[0] else np.full(h.size, 0.5)
    fill = [to_hex(cmap(s)) if np.isfinite(s) else color[k] for s, k in zip(scaled, idx)]
    data = dict(left=xe[ix], right=xe[ix + 1], bottom=ye[iy], top=ye[iy + 1], x=np.asarray(ds[xd].values, float)[ix],
                y=np.asarray(ds[yd].values, float)[iy], idx=idx, color=fill,
                line=[RED_FLAG if bad[k] else "white" for k in idx], name=[words[k] for k in idx])
    return data, dict(glyph="quad", x_label=axis_label(ds, xd, math=False), y_label=axis_label(ds, yd, math=False),
                      theory={}, span=span, dim=None)


def plane_columns(ds: xr.Dataset, g: int, base: np.ndarray | None = None) -> dict | None:
    """The start plane at grid point ``g`` when the shock moves two entries of the parameters (None otherwise):
    ``lo``/``hi`` the scanned directions' exit brackets, ``ball`` the ball of radius ``|delta*|`` in the search's
    norm, ``theory`` the theorems' balls ({name: (x, y)}), ``witness`` and ``base`` (the unshocked start's entries:
    ``base`` if given, else the witness less its shock), as in the figure of :func:`plot_shock`."""
    if not (ds.sizes.get("component", 0) == 2 and "direction_scale" in ds):
        return None
    p = ds.isel(dict(zip(grid_dims(ds), np.unravel_index(int(g), [ds.sizes[d] for d in grid_dims(ds)])))) if grid_dims(ds) else ds
    w = np.asarray(p["shock_witness"].values, float)
    if base is None:
        base = w - np.asarray(p["shock_delta"].values, float)
    base = np.asarray(base, float) if np.all(np.isfinite(base)) else np.zeros(2)
    U = ds["direction_vector"].values
    sc = np.asarray(p["direction_scale"].values, float)

    def along(r):
        pts = base + (U / sc[:, None]) * np.asarray(r, float)[:, None]
        ok = np.all(np.isfinite(pts), axis=1)
        return dict(x=pts[ok, 0], y=pts[ok, 1])

    th = np.linspace(0, 2 * np.pi, 361)
    circ = np.stack([np.cos(th), np.sin(th)], 1)
    scale = _norm_of(ds, p, circ)

    def ball(r):
        pts = base + circ * (r / scale)[:, None]
        return pts[:, 0], pts[:, 1]

    hi = float(p["shock_norm"].values)
    theory = {}
    for name in theories(ds):
        r = float(p[f"theory_radius_{name}"].values)
        if np.isfinite(r) and r > 0:
            theory[name] = ball(r)
    found = np.all(np.isfinite(w))
    bx, by = ball(hi) if np.isfinite(hi) else ([], [])
    return dict(lo=along(p["direction_exit_lo"].values), hi=along(p["direction_exit_hi"].values),
                ball=dict(x=bx, y=by), theory=theory, base=dict(x=[base[0]], y=[base[1]]),
                witness=dict(x=[w[0]] if found else [], y=[w[1]] if found else [], idx=[int(g)] if found else []),
                components=[str(c) for c in ds["component"].values])


def starts(r, g: int) -> dict:
    """The two starts a click on grid point ``g`` re-simulates (``r``: a :class:`stabjax.present.viewmodel.Result`):
    ``witness`` -- every parameter of the witness start, from :func:`stabjax.explore.shock_result.witness_replay`
    (None where no fatal shock was found), with the ``command`` that replays it -- and ``base``, the unshocked start
    the search shocked: the spec's start at that grid point, moved onto its attractor first with ``settle = true``
    (:func:`stabjax.explore.shock_config.settle`, as the search did)."""
    from ..explore.shock_result import witness_replay

    sel = point_of(r.ds, g)
    rep = witness_replay(r.ds, **sel)
    plan = r.plan
    base = plan.system.check(plan.params_at(np.array([int(g)])))  # as the search's base_points
    if settings(r.ds).get("settle"):
        from ..explore.shock_config import settle, shock_config

        base = settle(plan, shock_config(plan), base)
    witness = {k: np.asarray(v, float) for k, v in rep["params"].items()} if rep["found"] else None
    return dict(sel=sel, witness=witness, command=rep["command"], base={k: np.asarray(v)[0] for k, v in base.items()})


def settings(ds: xr.Dataset) -> dict:
    """The recorded ``[shock]`` table (``shock_json``)."""
    return json.loads(ds.attrs.get("shock_json", "{}"))


def point_rows(ds: xr.Dataset, g: int) -> list[tuple[str, str]]:
    """(what, value) rows of grid point ``g`` for the viewer: the attractor shocked, ``|delta*|`` and its bracket,
    the shock and the witness start with the outcome it reached (and re-checked), the effort, each theorem's
    verdict, the statistical statement."""
    sel = point_of(ds, g)
    p = ds.sel(sel) if sel else ds
    comps = [str(c) for c in ds["component"].values]
    hi, lo = float(p["shock_norm"].values), float(p["shock_norm_lo"].values)
    rows = [("grid point", ", ".join(f"{k} = {float(v):.6g}" for k, v in sel.items()) or "(no grid)"),
            ("attractor shocked", f"{outcome_name(ds, p['base_outcome'].values)} (the unshocked start's outcome)"),
            ("norm", str(ds.attrs.get("norm", "")))]
    if np.isnan(lo):
        return rows + [("search", "none: the unshocked start does not reach the attractor searched")]
    if np.isnan(hi):
        rows.append(("minimal fatal shock", f"none found up to {lo:.6g}: no witness"))
    else:
        rows.append(("minimal fatal shock", f"|delta*| = {hi:.6g}, bracket [{lo:.6g}, {hi:.6g}]"))
        rows.append(("shock delta*", ", ".join(f"{c} {v:+.6g}" for c, v in zip(comps, p["shock_delta"].values))))
        rows.append(("witness start", ", ".join(f"{c} = {v:.10g}" for c, v in zip(comps, p["shock_witness"].values))))
        rows.append(("witness reaches", outcome_name(ds, p["shock_witness_outcome"].values) + " (recorded by the search)"))
        if "shock_witness_recheck" in ds:
            rows.append(("re-checked", f"{outcome_name(ds, p['shock_witness_recheck'].values)} with rtol and atol / 100"))
    und = float(p["shock_undecided_norm"].values)
    if np.isfinite(und):
        rows.append(("undecided", f"a shocked start of norm {und:.4g} was left undecided (counted as not fatal)"))
    rows.append(("effort", f"{int(p['shock_trajectories'].values):,} trajectories at this grid point"))
    words = {0: "RED FLAG: a fatal start inside the guaranteed region", 1: "consistent (within the resolution)",
             2: "conservative", 3: "not applicable (its hypotheses fail here)",
             4: "untested (its radius lies beyond the largest shock searched, max_radius)"}
    for th in theories(ds):
        v = int(p[f"theory_verdict_{th}"].values)
        rg = float(p[f"theory_radius_{th}"].values)
        f_lo, f_hi = float(p[f"theory_factor_lo_{th}"].values), float(p[f"theory_factor_hi_{th}"].values)
        extra = f" by {f_lo:.3g}" + (f"..{f_hi:.3g}" if np.isfinite(f_hi) else "+") if v == 2 else ""
        rows.append((f"theorem {th}", f"{words.get(v, '?')}{extra}; guaranteed radius {rg:.6g}"))
    return rows
