"""Plots of named outcomes and basin stability, with the system's own outcome names.

* samples only (no grid): the sampled starts coloured by outcome (the first two sampled scalar
  parameters as axes: the basins) beside the fractions with their 95 % Wilson intervals;
* one grid axis + samples: each outcome's fraction along the axis, with error bars;
* two grid axes + samples: the dominant outcome of each cell, shaded by its fraction;
* a grid without samples: one trajectory per cell, coloured by outcome (a basin picture when
  the axes are initial conditions).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.colors import BoundaryNorm, ListedColormap, to_rgb
from matplotlib.patches import Patch

from ..model.outcomes import PALETTE
from .maps import cell_edges


def outcome_names(ds: xr.Dataset) -> list[str]:
    return str(ds["outcome"].attrs["flag_meanings"]).split()


def outcome_colors(ds: xr.Dataset) -> list[str]:
    """The colours stored with the outcome (``flag_colors``), else the verdict colours."""
    cols = str(ds["outcome"].attrs.get("flag_colors", "")).split()
    if len(cols) == len(outcome_names(ds)):
        return cols
    from ..fold import verdict as V

    return (list(V.COLORS) + list(PALETTE))[: len(outcome_names(ds))]


def _legend(ax, names, colors, codes=None):
    """Legend of the outcomes that occur in ``codes`` (all of them without)."""
    present = [codes is None or bool((np.asarray(codes) == k).any()) for k in range(len(names))]
    handles = [Patch(color=c, label=n) for n, c, p in zip(names, colors, present) if p]
    ax.legend(handles=handles, fontsize=8, loc="upper right", framealpha=0.8)


def _label(ds: xr.Dataset, name: str) -> str:
    """An axis in words with its symbol and unit: a grid axis (its coordinate's description) or a
    sampled parameter (``<name>_sample``'s); the bare name only when the result has no description."""
    from .labels import symbol, words
    from .maps import axis_label

    if name in ds.coords:
        return axis_label(ds, name)
    doc = str(ds[f"{name}_sample"].attrs.get("long_name", "")) if f"{name}_sample" in ds else ""
    return words(doc.removeprefix("sampled "), symbol(name))


def _title(ds, what: str) -> str:
    name = ds.attrs.get("sweep_name", "")
    n = int(ds.sizes.get("sample", 0))
    return f"{ds.attrs.get('system', '')}: {what}" + (f"  [{name}]" if name else "") + (f"\nN = {n} samples per point"
                                                                                      if n else "")


def plot_basin(ds: xr.Dataset, out: str | Path) -> Path:
    """Draw the outcome picture that fits the dataset's shape (see the module docstring)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    names, colors = outcome_names(ds), outcome_colors(ds)
    grid = [d for d in ds["outcome"].dims if d != "sample"]
    has_sample = "sample" in ds["outcome"].dims
    if has_sample and not grid:
        fig = _samples_only(ds, names, colors)
    elif has_sample and len(grid) == 1:
        fig = _fractions_along(ds, grid[0], names, colors)
    elif has_sample and len(grid) == 2:  # the second grid axis horizontal, as on the verdict map (plotting)
        fig = _dominant_map(ds, grid[::-1], names, colors)
    elif not has_sample and len(grid) in (1, 2):
        fig = _outcome_map(ds, grid[::-1], names, colors)
    else:
        fig = _bars_only(ds, names, colors)
    fig.savefig(out, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return out


def _bar(ax, ds, names, colors, sel=None):
    f = ds["basin_fraction"] if sel is None else ds["basin_fraction"].sel(sel)
    lo = ds["basin_ci_low"] if sel is None else ds["basin_ci_low"].sel(sel)
    hi = ds["basin_ci_high"] if sel is None else ds["basin_ci_high"].sel(sel)
    f, lo, hi = (np.asarray(x.values).reshape(-1) for x in (f, lo, hi))
    x = np.arange(len(names))
    ax.bar(x, f, color=colors, yerr=np.vstack([f - lo, hi - f]), capsize=3, edgecolor="k", linewidth=0.4)
    for xi, fi in zip(x, f):
        ax.text(xi, fi + 0.02, f"{fi:.3f}", ha="center", fontsize=7)
    ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("basin stability S (95% Wilson interval)")


def _sampled_axes(ds):
    keys = [k[: -len("_sample")] for k in ds.data_vars if k.endswith("_sample") and ds[k].dims == ("sample",)]
    return keys[:2]


def _samples_only(ds, names, colors):
    keys = _sampled_axes(ds)
    if len(keys) < 2:
        return _bars_only(ds, names, colors)
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw=dict(width_ratios=[1.2, 1]))
    code = np.asarray(ds["outcome"].values)
    cmap = ListedColormap(colors)
    a0.scatter(ds[f"{keys[0]}_sample"].values, ds[f"{keys[1]}_sample"].values, c=code, cmap=cmap,
               norm=BoundaryNorm(np.arange(len(names) + 1) - 0.5, len(names)), s=4, linewidths=0)
    a0.set_xlabel(_label(ds, keys[0]))
    a0.set_ylabel(_label(ds, keys[1]))
    a0.set_title("sampled starts, coloured by outcome (one dot = one trajectory)", fontsize=9)
    _legend(a0, names, colors, code)
    _bar(a1, ds, names, colors)
    fig.suptitle(_title(ds, "basin stability"), fontsize=10, y=1.03)
    return fig


def _bars_only(ds, names, colors):
    fig, ax = plt.subplots(figsize=(6, 4))
    if "basin_fraction" in ds and ds["basin_fraction"].ndim == 1:
        _bar(ax, ds, names, colors)
    else:
        code = np.asarray(ds["outcome"].values).ravel()
        ax.bar(np.arange(len(names)), [(code == k).mean() for k in range(len(names))], color=colors)
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
    fig.suptitle(_title(ds, "outcome fractions"), fontsize=10)
    return fig


def _fractions_along(ds, dim, names, colors):
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    x = np.asarray(ds[dim].values, float)
    for k, (n, c) in enumerate(zip(names, colors)):
        f = ds["basin_fraction"].isel(outcome_name=k).values
        if not np.any(f > 0):
            continue
        lo, hi = ds["basin_ci_low"].isel(outcome_name=k).values, ds["basin_ci_high"].isel(outcome_name=k).values
        ax.errorbar(x, f, yerr=np.vstack([f - lo, hi - f]), color=c, marker="o", ms=3, capsize=2, label=n)
    ax.set_xlabel(_label(ds, dim))
    ax.set_ylabel("basin stability S (95% Wilson interval)")
    ax.set_ylim(-0.02, 1.02)
    if int(ds[dim].attrs.get("log_axis", 0)):
        ax.set_xscale("log")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(_title(ds, "basin stability along " + dim), fontsize=10)
    return fig


def _dominant_map(ds, dims, names, colors):
    fr = ds["basin_fraction"].transpose(dims[1], dims[0], "outcome_name").values  # (ny, nx, K)
    dom = fr.argmax(axis=-1)
    share = fr.max(axis=-1)
    rgb = np.array([to_rgb(c) for c in colors])[dom]
    rgb = 1 - (1 - rgb) * (0.35 + 0.65 * share[..., None])  # paler where the dominant outcome is less sure
    x, y = ds[dims[0]].values, ds[dims[1]].values
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    ax.imshow(rgb, origin="lower", aspect="auto", extent=_extent(x, y), interpolation="nearest")
    if fr.shape[0] * fr.shape[1] <= 400:
        for i in range(fr.shape[0]):
            for j in range(fr.shape[1]):
                ax.text(float(x[j]), float(y[i]), f"{share[i, j]:.2f}", ha="center", va="center", fontsize=6)
    ax.set_xlabel(_label(ds, dims[0]))
    ax.set_ylabel(_label(ds, dims[1]))
    _legend(ax, names, colors, dom)
    fig.suptitle(_title(ds, "dominant outcome per cell (shade and number: its fraction S)"), fontsize=10)
    return fig


def _outcome_map(ds, dims, names, colors):
    code = ds["outcome"].transpose(*dims[::-1]).values
    fig, ax = plt.subplots(figsize=(7.5, 5.5 if len(dims) == 2 else 2.5))
    cmap = ListedColormap(colors)
    norm = BoundaryNorm(np.arange(len(names) + 1) - 0.5, len(names))
    if len(dims) == 1:
        x = ds[dims[0]].values
        ax.imshow(code[None, :], aspect="auto", cmap=cmap, norm=norm, extent=(*_extent(x, np.array([0.0, 1.0]))[:2],
                                                                             0, 1), interpolation="nearest")
        ax.set_yticks([])
    else:
        x, y = ds[dims[0]].values, ds[dims[1]].values
        ax.imshow(code, origin="lower", aspect="auto", cmap=cmap, norm=norm, extent=_extent(x, y),
                  interpolation="nearest")
        ax.set_ylabel(_label(ds, dims[1]))
    ax.set_xlabel(_label(ds, dims[0]))
    _legend(ax, names, colors, code)
    fig.suptitle(_title(ds, "outcome (one cell = one trajectory)"), fontsize=10)
    return fig


def _extent(x, y):
    xe, ye = cell_edges(x, False), cell_edges(y, False)
    return (xe[0], xe[-1], ye[0], ye[-1])


def format_summary(ds: xr.Dataset, max_points: int = 12) -> str:
    """The outcome table the CLI prints: pooled counts and fractions, and per grid point if few."""
    from ..mapping.basin import summary_rows

    rows = summary_rows(ds)
    n = sum(r[1] for r in rows)
    lines = [f"{'outcome':<16}{'count':>9}{'S':>9}{'± SE':>9}   95% Wilson",
             *[f"{name:<16}{c:>9d}{s:>9.4f}{se:>9.4f}   [{lo:.4f}, {hi:.4f}]" for name, c, s, se, lo, hi in rows],
             f"(all {n} trajectories pooled)"]
    grid = [d for d in ds["outcome"].dims if d != "sample"]
    if "basin_fraction" in ds and grid:
        npts = int(np.prod([ds.sizes[d] for d in grid]))
        if npts <= max_points:
            names = outcome_names(ds)
            keep = [k for k in range(len(names)) if float(ds["basin_count"].isel(outcome_name=k).sum()) > 0]
            lines.append("per grid point: S ± SE")
            lines.append(" ".join(f"{d:>10}" for d in grid) + "".join(f"{names[k]:>22}" for k in keep))
            stacked = ds[["basin_fraction", "basin_se"]].stack(pt=grid)
            for j in range(stacked.sizes["pt"]):
                pt = stacked.isel(pt=j)
                head = " ".join(f"{float(pt[d]):>10.4g}" for d in grid)
                cells = "".join(f"{float(pt['basin_fraction'][k]):>13.4f} ± {float(pt['basin_se'][k]):.4f}"
                                for k in keep)
                lines.append(head + cells)
    if "start_label_mcc" in ds:
        lines.append(f"against the starts file's labels: agreement {float(ds['start_label_agreement']):.4f}, "
                     f"Matthews correlation {float(ds['start_label_mcc']):.4f} "
                     f"({ds['start_label_mcc'].attrs.get('mapping', '')})")
    if "attractor_events" in ds:
        import json

        for e in json.loads(str(ds["attractor_events"].values)):
            where = {k: v for k, v in e.items() if k not in ("attractor", "event", "index")}
            lines.append(f"{e['attractor']}: {'born' if e['event'] == 'birth' else 'lost'} at "
                         + ", ".join(f"{k} = {v:.6g}" for k, v in where.items()))
    if "basin_entropy" in ds:
        a = ds["basin_entropy"].attrs
        sbb = float(ds["boundary_basin_entropy"])
        lines.append(f"basin entropy S_b = {float(ds['basin_entropy']):.4f}, boundary basin entropy S_bb = {sbb:.4f} "
                     f"nats ({a.get('box')} x {a.get('box')} cells per box, {a.get('boundary_boxes')} of "
                     f"{a.get('boxes')} boxes on a boundary; S_bb {'>' if sbb > np.log(2) else '<='} ln 2"
                     f"{': fractal boundary' if sbb > np.log(2) else ''})")
    return "\n".join(lines)
