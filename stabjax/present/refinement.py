"""The plot of a refinement's dataset (:mod:`stabjax.explore.refine`): evaluated points coloured by label, each
horizon's bracketed boundary, and the theorem's boundary. Apart from the explorer so that the refinement module
stays one subject (and under the house's 550 lines); it reads nothing but the dataset, so a written file is
plotted as well as a fresh one.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import kit
from .labels import axis_label, fixed_note, theory_words

if TYPE_CHECKING:
    import xarray as xr

# the bracketed (empirical) boundary: the colour of the converged region's edge on the sweep maps, apart
# from the theorem's black line
EDGE = "#CC79A7"


def refine_title(ds: xr.Dataset, head: str | None = None) -> str:
    """What was refined, in words, and how much of the lattice it cost; the fixed parameters that matter."""
    pair = ds.attrs.get("pair", "").split()
    between = (f"{pair[0]} and not {pair[0]}" if pair[1:] == ["*"] else " and ".join(pair)) if pair else \
        f"{ds.attrs.get('label', 'label')}s"
    t1 = kit.t1_of(ds)
    hs = np.atleast_1d(ds.attrs.get("horizons", [ds.attrs.get("horizon")]))
    when = f"horizons T = {', '.join(f'{h:g}' for h in hs)}" if len(hs) > 1 else f"horizon T = {hs[0]:g}"
    first = head or (f"Refined boundary between {between}: {ds.attrs['n_points']:,} of "
                     f"{ds.attrs['full_grid_points']:,} lattice points run")
    # the spec's fixed parameters (the refinement's own variables name no theorem's parameters)
    fixed = fixed_note(ds[[]], exclude=ds.attrs["axes"].split())
    second = "; ".join(x for x in (fixed, f"{when}, t1 = {t1:g}") if x)
    return f"{first}\n{second}"


def plot_refine(ds: xr.Dataset, out: str | Path | None = None, ax=None, title: str | None = None):
    """Evaluated points (coloured by label), bracketed boundary midpoints, and the theorem's boundary; written
    to ``out`` when given. ``title``: the first line of the title, in words
    (default: what was refined and what it cost). Returns the figure."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from ..fold import verdict as V

    names = ds.attrs["axes"].split()
    lnames = ds.attrs["label_names"].split()
    colors = list(V.COLORS) if ds.attrs.get("label") == "verdict" else \
        [plt.get_cmap("tab10")(i % 10) for i in range(len(lnames))]
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 5.2), constrained_layout=True)
    else:
        fig = ax.figure
    lab = ds["point_label"].values
    handles = []
    said = theory_words(ds)
    if len(names) == 2:
        xd, yd = names[1], names[0]  # same orientation as plot_sweep: second axis horizontal
        for c in np.unique(lab):
            sel = lab == c
            ax.scatter(ds[f"point_{xd}"].values[sel], ds[f"point_{yd}"].values[sel], s=4, color=colors[c], lw=0)
            handles.append(Line2D([], [], color=colors[c], marker="o", ls="", label=lnames[c]))
        for h, col, what in _horizon_styles(ds):
            sel = ds["segment_horizon"].values == h if "segment_horizon" in ds else slice(None)
            ax.plot(ds[f"{xd}_mid"].values[sel], ds[f"{yd}_mid"].values[sel], ".", color=col, ms=2.5)
            handles.append(Line2D([], [], color=col, marker=".", ls="", ms=8,
                                  label=f"bracketed boundary{what} (midpoints)"))
        if "theory_margin" in ds:
            m = ds["theory_margin"].transpose(f"{yd}_theory", f"{xd}_theory").values
            if np.nanmin(m) < 0 < np.nanmax(m):
                ax.contour(ds[f"{xd}_theory"].values, ds[f"{yd}_theory"].values, m, levels=[0.0], colors="k",
                           linewidths=2.0)
                handles.append(Line2D([], [], color="k", lw=2, label=f"theory boundary: {said}"))
        ax.set_xlabel(axis_label(ds, xd))
        ax.set_ylabel(axis_label(ds, yd))
    else:
        xd = names[0]
        x = ds[f"point_{xd}"].values
        for c in np.unique(lab):
            sel = lab == c
            ax.scatter(x[sel], np.full(sel.sum(), c), s=14, color=colors[c], label=lnames[c], zorder=3)
        for h, col, what in _horizon_styles(ds):
            sel = ds["segment_horizon"].values == h if "segment_horizon" in ds else slice(None)
            for i, (lo, hi) in enumerate(zip(ds[f"{xd}_lo"].values[sel], ds[f"{xd}_hi"].values[sel])):
                ax.axvspan(min(lo, hi), max(lo, hi), color=col, alpha=0.5,
                           label=f"bracketed boundary{what}" if i == 0 else None)
        if "theory_margin" in ds:
            from .maps import zero_crossings

            for i, xc in enumerate(zero_crossings(ds[f"{xd}_theory"].values, ds["theory_margin"].values)):
                ax.axvline(xc, color="k", lw=2, label=f"theory boundary: {said}" if i == 0 else None)
        ax.set_yticks(range(len(lnames)), lnames)
        ax.set_xlabel(axis_label(ds, xd))
        handles = ax.get_legend_handles_labels()[0]
    from .maps import legend_below, save

    if handles:
        legend_below(ax, handles, ncol=3 if len(names) == 2 else 2, width=60)
    ax.set_title(refine_title(ds, title), fontsize=9)

    return save(fig, out, own)


def _horizon_styles(ds: xr.Dataset):
    """(horizon, colour, legend suffix) per bracketed horizon: grey/black alone, a colour per horizon otherwise."""
    import matplotlib.pyplot as plt

    hs = np.atleast_1d(ds.attrs.get("horizons", [ds.attrs.get("horizon")]))
    if len(hs) == 1:
        return [(hs[0], EDGE, "")]
    cmap = plt.get_cmap("viridis")
    return [(h, cmap(i / (len(hs) - 1)), f" at T = {h:g}") for i, h in enumerate(hs)]


def format_summary(ds: xr.Dataset) -> str:
    """The refinement in a few lines: segments, points and steps against the full lattice, each horizon's
    bracket, and the distance to the theorem's boundary."""
    lines = [f"{ds.attrs['n_segments']} boundary segments ({ds.attrs['n_unbracketed']} wider than the tolerance) "
             f"from {ds.attrs['n_points']} points ({ds.attrs['n_trajectories']} trajectories, "
             f"{ds.attrs['total_steps']:,} steps, {ds.attrs['rounds']} rounds); the full lattice of the same resolution "
             f"({' x '.join(map(str, np.atleast_1d(ds.attrs['lattice_shape'])))}) holds {ds.attrs['full_grid_points']:,}"]
    hs = np.atleast_1d(ds.attrs.get("horizons", [ds.attrs.get("horizon")]))
    if len(hs) > 1 and "segment_horizon" in ds:  # each horizon's bracket
        names = ds.attrs["axes"].split()
        sh = ds["segment_horizon"].values
        for h in hs:
            sel = sh == h
            line = f"horizon T = {h:g}: {int(sel.sum())} segment(s)"
            if len(names) == 1 and 0 < sel.sum() <= 4:
                n = names[0]
                lo, hi = ds[f"{n}_lo"].values[sel], ds[f"{n}_hi"].values[sel]
                line += ", " + ", ".join(f"{n} in [{a:.6g}, {b:.6g}]" for a, b in zip(lo, hi))
            lines.append(line)
    summ = json.loads(ds.attrs.get("theory_distance_json", "{}"))
    for n, s in summ.items():
        lines.append(f"distance to the {ds.attrs['theory_main']} boundary along {n} (> 0: theorem conservative): "
                     f"median {s['median']:+.4g}, range [{s['min']:+.4g}, {s['max']:+.4g}]")
    return "\n".join(lines)
