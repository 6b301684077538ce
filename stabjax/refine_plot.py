"""The plot of a refinement's dataset (:mod:`stabjax.refine`): evaluated points coloured by label, each
horizon's bracketed boundary, and the theorem's boundary. Apart from the explorer so that the refinement module
stays one subject (and under the house's 550 lines); it reads nothing but the dataset, so a written file is
plotted as well as a fresh one.
"""
from __future__ import annotations

import json

from pathlib import Path

import numpy as np
import xarray as xr

from . import verdict as V


def plot_refine(ds: xr.Dataset, out: str | Path | None = None, ax=None):
    """Evaluated points (coloured by label), bracketed boundary midpoints, and the theorem's boundary."""
    from .plotting import plt, symbol
    from matplotlib.lines import Line2D

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
    main = ds.attrs.get("theory_main", "")
    unit = lambda n: f" [{ds[n + '_mid'].attrs['units']}]" if "units" in ds[n + "_mid"].attrs else ""
    if len(names) == 2:
        xd, yd = names[1], names[0]  # same orientation as plot_sweep: second axis horizontal
        for c in np.unique(lab):
            sel = lab == c
            ax.scatter(ds[f"point_{xd}"].values[sel], ds[f"point_{yd}"].values[sel], s=4, color=colors[c], lw=0)
            handles.append(Line2D([], [], color=colors[c], marker="o", ls="", label=lnames[c]))
        for h, col, what in _horizon_styles(ds):
            sel = ds["segment_horizon"].values == h if "segment_horizon" in ds else slice(None)
            ax.plot(ds[f"{xd}_mid"].values[sel], ds[f"{yd}_mid"].values[sel], ".", color=col, ms=2.5)
            handles.append(Line2D([], [], color=col, marker=".", ls="", label=f"bracketed boundary{what} (midpoints)"))
        if "theory_margin" in ds:
            m = ds["theory_margin"].transpose(f"{yd}_theory", f"{xd}_theory").values
            if np.nanmin(m) < 0 < np.nanmax(m):
                ax.contour(ds[f"{xd}_theory"].values, ds[f"{yd}_theory"].values, m, levels=[0.0], colors="k",
                           linewidths=2.0)
                handles.append(Line2D([], [], color="k", lw=2, label=f"theory boundary ({main})"))
        ax.set_xlabel(symbol(xd) + unit(xd))
        ax.set_ylabel(symbol(yd) + unit(yd))
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
            from .plotting import zero_crossings

            for i, xc in enumerate(zero_crossings(ds[f"{xd}_theory"].values, ds["theory_margin"].values)):
                ax.axvline(xc, color="k", lw=2, label=f"theory boundary ({main})" if i == 0 else None)
        ax.set_yticks(range(len(lnames)), lnames)
        ax.set_xlabel(symbol(xd) + unit(xd))
        ax.legend(fontsize=8)
    if handles:
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, fontsize=8, frameon=False)
    t1 = json.loads(ds.attrs.get("integrate_json", "{}")).get("t1", float("nan"))
    hs = np.atleast_1d(ds.attrs.get("horizons", [ds.attrs["horizon"]]))
    ax.set_title(f"{ds.attrs.get('system', '')}: {ds.attrs.get('sweep_name', '')} refined (horizon"
                 f"{'s ' + ', '.join(f'{h:g}' for h in hs) if len(hs) > 1 else ' ' + format(hs[0], 'g')}"
                 f", t1 = {t1:g}; {ds.attrs['n_points']} of {ds.attrs['full_grid_points']} lattice points)", fontsize=9)
    from .plotting import save

    return save(fig, out, own)


def _horizon_styles(ds: xr.Dataset):
    """(horizon, colour, legend suffix) per bracketed horizon: grey/black alone, a colour per horizon otherwise."""
    from .plotting import plt

    hs = np.atleast_1d(ds.attrs.get("horizons", [ds.attrs.get("horizon")]))
    if len(hs) == 1:
        return [(hs[0], "k" if len(ds.attrs["axes"].split()) == 2 else "0.6", "")]
    cmap = plt.get_cmap("viridis")
    return [(h, cmap(i / (len(hs) - 1)), f" at T = {h:g}") for i, h in enumerate(hs)]
