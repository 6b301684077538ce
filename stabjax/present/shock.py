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

VERDICT_NAMES = ("refuted", "consistent", "conservative", "not_applicable")


def theories(ds: xr.Dataset) -> list[str]:
    return [str(v)[len("theory_radius_"):] for v in ds.data_vars if str(v).startswith("theory_radius_")]


def _name(ds: xr.Dataset, code) -> str:
    names = str(ds.attrs.get("outcome_names", "")).split()
    code = int(code)
    return names[code] if 0 <= code < len(names) else "none"


def _grid(ds: xr.Dataset) -> list[str]:
    return list(ds["shock_norm"].dims)


def _points(ds: xr.Dataset):
    """(selection dict, point dataset) of every grid point."""
    dims = _grid(ds)
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
        att = _name(ds, p["base_outcome"].values)
        hi, lo = float(p["shock_norm"].values), float(p["shock_norm_lo"].values)
        if np.isnan(lo):
            row = f"  {where or 'start'}: the unshocked start reaches {att}: no search"
        elif np.isnan(hi):
            row = f"  {where or 'start'}: from {att}: no fatal shock up to {lo:.4g}"
        else:
            w = ", ".join(f"{c} = {v:.4g}" for c, v in zip(ds["component"].values, p["shock_witness"].values))
            row = (f"  {where or 'start'}: from {att}: |delta*| = {hi:.4g} (bracket [{lo:.4g}, {hi:.4g}]) "
                   f"-> {_name(ds, p['shock_witness_outcome'].values)}; witness {w}")
        for th in theories(ds):
            v = int(p[f"theory_verdict_{th}"].values)
            r = float(p[f"theory_radius_{th}"].values)
            f_lo, f_hi = float(p[f"theory_factor_lo_{th}"].values), float(p[f"theory_factor_hi_{th}"].values)
            if v == 0:
                flags.append((th, where, r, hi, witness_replay(ds, **sel)["command"]))
                row += f"; {th}: RED FLAG (radius {r:.4g} > a fatal shock {hi:.4g})"
            elif v == 2:
                row += f"; {th}: conservative by {f_lo:.3g}" + (f"..{f_hi:.3g}" if np.isfinite(f_hi) else "+") + \
                       f" (radius {r:.4g})"
            elif v == 1:
                row += f"; {th}: consistent (radius {r:.4g} within the resolution)"
            else:
                row += f"; {th}: not applicable"
        if shown < limit:
            lines.append(row)
        shown += 1
    if shown > limit:
        lines.append(f"  ... {shown - limit} more grid points (in the file)")
    lines.append("statement: " + str(ds.attrs.get("statement", "")))
    for th, where, r, hi, cmd in flags[:5]:
        lines.append(f"RED FLAG {th}{' at ' + where if where else ''}: a start at norm {hi:.4g} inside the guaranteed "
                     f"radius {r:.4g} does not reach the attractor. Replay: {cmd}")
    if len(flags) > 5:
        lines.append(f"... {len(flags) - 5} more red flags")
    return "\n".join(lines)


# ---- figures --------------------------------------------------------------------------------------------

_TH_STYLES = (("#000000", "--"), ("#D55E00", ":"), ("#009E73", "-."), ("#CC79A7", (0, (5, 2, 1, 2))))


def plot_shock(ds: xr.Dataset, out: str | Path | None = None, basin: xr.Dataset | None = None, title: str | None = None):
    """The figure of a shock result (see the module docstring); written to ``out`` if given. Returns the figure."""
    import matplotlib.pyplot as plt

    from .maps import legend_below, save

    plane = ds.sizes.get("component", 0) == 2 and "direction_scale" in ds
    fig, axs = plt.subplots(1, 2 if plane else 1, figsize=(12.5 if plane else 6.8, 5.4), constrained_layout=True,
                            squeeze=False)
    ax = axs[0, 0]
    dims = _grid(ds)
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


def _unit(ds):
    u = str(ds["shock_norm"].attrs.get("units", "1"))
    return "" if u in ("", "1") else f" [{u}]"


def _theory_lines(ax, ds, x=None):
    for i, th in enumerate(theories(ds)):
        col, ls = _TH_STYLES[i % len(_TH_STYLES)]
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
    att = _name(ds, ds["base_outcome"].values)
    if np.isfinite(hi):
        ax.errorbar([0], [hi], yerr=[[hi - lo], [0]], fmt="o", color="#0072B2", capsize=6, ms=8,
                    label=f"minimal fatal shock found: {hi:.4g} (bracket [{lo:.4g}, {hi:.4g}])")
    else:
        ax.plot([0], [lo], "^", color="#009E73", ms=9, label=f"no fatal shock up to {lo:.4g}")
    _theory_lines(ax, ds)
    _red_flags(ax, ds)
    ax.set_xticks([0], [f"from {att}"])
    ax.set_xlim(-1, 1)
    tops = [v for v in [hi, lo] + [float(ds[f"theory_radius_{t}"]) for t in theories(ds)] if np.isfinite(v)]
    ax.set_ylim(0, 1.15 * max(tops) if tops else None)
    ax.set_ylabel(f"size of the shock, {ds.attrs.get('norm', '')}"[:90] + _unit(ds))


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
    ax.set_ylabel(f"size of the shock, {ds.attrs.get('norm', '')}"[:90] + _unit(ds), fontsize=8)
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
    p = ds.isel({d: 0 for d in _grid(ds)})
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
        ax.plot(*w, "*", color="red", ms=15, mec="k", label=f"witness: reaches {_name(ds, p['shock_witness_outcome'].values)}")
    for i, name in enumerate(theories(ds)):
        r = float(p[f"theory_radius_{name}"].values)
        if np.isfinite(r) and r > 0:
            col, ls = _TH_STYLES[i % len(_TH_STYLES)]
            ax.plot(*(base + circ * (r / scale)[:, None]).T, color=col, ls=ls, lw=1.6, label=f"region of {name}")
    ax.plot(*base, "o", color="k", ms=6, label=f"the attractor's start ({_name(ds, p['base_outcome'].values)})")
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
                       "</figcaption></figure>")]
