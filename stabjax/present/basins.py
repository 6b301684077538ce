"""Plots of named outcomes and basin stability, with the system's own outcome names.

* samples only (no grid): the sampled starts coloured by outcome (the first two sampled scalar
  parameters as axes: the basins; one sampled parameter: each start at its outcome's row along it) beside the
  fractions with their 95 % Wilson intervals;
* one grid axis + samples: each outcome's fraction along the axis, with error bars;
* two grid axes + samples: the dominant outcome of each cell, shaded by its fraction;
* a grid without samples: one trajectory per cell, coloured by outcome (a basin picture when
  the axes are initial conditions).

Discovered attractors are named in the legends with where they lie (:func:`stabjax.present.kit.attractors`),
and so are they in the printed summary (:func:`format_summary`), so that ``fixed_point_1`` is told from
``fixed_point_2``.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from . import kit
from .labels import attractor_label, axis_label, heading, trajectory_noun
from .maps import cell_edges

if TYPE_CHECKING:
    import xarray as xr


def _legend(ax, names, colors, codes=None, where=None, extra=()):
    """Legend of the outcomes that occur in ``codes`` (all of them without), then ``extra`` handles (the
    theorem's); a discovered attractor is named with where it lies (``where``: :func:`stabjax.present.kit.where_of`)."""
    from matplotlib.patches import Patch

    present = [codes is None or bool((np.asarray(codes) == k).any()) for k in range(len(names))]
    handles = [Patch(color=c, label=attractor_label(n, where or {})) for n, c, p in zip(names, colors, present) if p]
    handles += list(extra)
    if where or extra:  # entries with locations are long: under the axes, off the data
        ax.legend(handles=handles, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), frameon=False)
    else:
        ax.legend(handles=handles, fontsize=8, loc="upper right", framealpha=0.8)


def _title(ds, what: str, head: str | None = None) -> str:
    """``head`` (default: the result's heading, its description, else the system and the run's name), then
    what is drawn."""
    n = int(ds.sizes.get("sample", 0))
    return f"{head or heading(ds)}\n{what}" + (f"; N = {n} samples per point" if n else "")


def plot_basin(ds: xr.Dataset, out: str | Path | None = None, title: str | None = None):
    """Draw the outcome picture that fits the dataset's shape (see the module docstring); write it to ``out``
    when given. ``title``: what it shows, in words (default: the spec's
    description). Returns the figure."""
    import matplotlib.pyplot as plt

    if "outcome" not in ds:
        raise ValidationError("result", "this result holds no outcomes yet (a discovery assigns them when "
                                            "the sweep has finished): show it when the sweep has finished")
    names, colors = kit.names_colors(ds)
    grid = [d for d in ds["outcome"].dims if d != "sample"]
    has_sample = "sample" in ds["outcome"].dims
    if has_sample and not grid:
        fig = _samples_only(ds, names, colors, title)
    elif has_sample and len(grid) == 1:
        fig = _fractions_along(ds, grid[0], names, colors, title)
    elif has_sample and len(grid) == 2:  # the second grid axis horizontal, as on the verdict map (plotting)
        fig = _dominant_map(ds, grid[::-1], names, colors, title)
    elif not has_sample and len(grid) in (1, 2):
        fig = _outcome_map(ds, grid[::-1], names, colors, title)
    else:
        fig = _bars_only(ds, names, colors, title)
    if out is not None:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=130, bbox_inches="tight")
        plt.close(fig)
    return fig


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


def _samples_only(ds, names, colors, head=None):
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap

    keys = _sampled_axes(ds)
    if not keys:
        return _bars_only(ds, names, colors, head)
    if len(keys) == 1:  # one sampled start: its outcome along that axis, the theorem's boundary across it
        fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw=dict(width_ratios=[1.2, 1]))
        code = np.asarray(ds["outcome"].values)
        x = ds[f"{keys[0]}_sample"].values
        a0.scatter(x, code, c=[colors[int(c)] for c in code], s=6, linewidths=0)
        a0.set_yticks(np.arange(len(names)), names, fontsize=8)
        a0.set_ylim(-0.6, len(names) - 0.4)
        a0.set_xlabel(axis_label(ds, keys[0]))
        a0.set_title("sampled starts by outcome (one dot = one trajectory)", fontsize=9)
        _legend(a0, names, colors, code, kit.where_of(ds), _theorem(a0, ds, [x, code], ("sample",), along=True))
        _bar(a1, ds, names, colors)
        fig.suptitle(_title(ds, "basin stability", head), fontsize=10, y=1.04)
        return fig
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw=dict(width_ratios=[1.2, 1]))
    code = np.asarray(ds["outcome"].values)
    cmap = ListedColormap(colors)
    a0.scatter(ds[f"{keys[0]}_sample"].values, ds[f"{keys[1]}_sample"].values, c=code, cmap=cmap,
               norm=BoundaryNorm(np.arange(len(names) + 1) - 0.5, len(names)), s=4, linewidths=0)
    a0.set_xlabel(axis_label(ds, keys[0]))
    a0.set_ylabel(axis_label(ds, keys[1]))
    a0.set_title("sampled starts, coloured by outcome (one dot = one trajectory)", fontsize=9)
    _legend(a0, names, colors, code, kit.where_of(ds),
            _theorem(a0, ds, [ds[f"{k}_sample"].values for k in keys], ("sample",)))
    _bar(a1, ds, names, colors)
    fig.suptitle(_title(ds, "basin stability", head), fontsize=10, y=1.03)
    return fig


def _bars_only(ds, names, colors, head=None):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    if "basin_fraction" in ds and ds["basin_fraction"].ndim == 1:
        _bar(ax, ds, names, colors)
    else:
        code = np.asarray(ds["outcome"].values).ravel()
        ax.bar(np.arange(len(names)), [(code == k).mean() for k in range(len(names))], color=colors)
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
    fig.suptitle(_title(ds, "outcome fractions", head), fontsize=10)
    return fig


def _fractions_along(ds, dim, names, colors, head=None):
    import matplotlib.pyplot as plt

    where = kit.where_of(ds)
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    x = np.asarray(ds[dim].values, float)
    for k, (n, c) in enumerate(zip(names, colors)):
        f = ds["basin_fraction"].isel(outcome_name=k).values
        if not np.any(f > 0):
            continue
        lo, hi = ds["basin_ci_low"].isel(outcome_name=k).values, ds["basin_ci_high"].isel(outcome_name=k).values
        ax.errorbar(x, f, yerr=np.vstack([f - lo, hi - f]), color=c, marker="o", ms=3, capsize=2,
                    label=attractor_label(n, where))
    ax.set_xlabel(axis_label(ds, dim))
    ax.set_ylabel("basin stability S (95% Wilson interval)")
    ax.set_ylim(-0.02, 1.02)
    if int(ds[dim].attrs.get("log_axis", 0)):
        ax.set_xscale("log")
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(handles=handles + _theorem(ax, ds, [x, np.array(1.0)], (dim,)), fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(_title(ds, "basin stability along " + axis_label(ds, dim), head), fontsize=10)
    return fig


def _dominant_map(ds, dims, names, colors, head=None):
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb

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
    ax.set_xlabel(axis_label(ds, dims[0]))
    ax.set_ylabel(axis_label(ds, dims[1]))
    _legend(ax, names, colors, dom, kit.where_of(ds), _theorem(ax, ds, [x, y], dims))
    fig.suptitle(_title(ds, "dominant outcome per cell (shade and number: its fraction S)", head), fontsize=10)
    return fig


def _outcome_map(ds, dims, names, colors, head=None):
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap

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
        ax.set_ylabel(axis_label(ds, dims[1]))
    ax.set_xlabel(axis_label(ds, dims[0]))
    at = [ds[d].values for d in dims] if len(dims) == 2 else [ds[dims[0]].values, np.array(0.5)]
    _legend(ax, names, colors, code, kit.where_of(ds), _theorem(ax, ds, at, dims))
    fig.suptitle(_title(ds, "outcome (one cell = one trajectory)", head), fontsize=10, y=1.0 if len(dims) == 2 else 1.1)
    return fig


def _theorem(ax, ds, at, dims, along: bool = False) -> list:
    """Draw the main theorem over an outcome picture; return its legend handles (none without a theorem).

    ``dims``: the picture's axes (grid axes, or ``("sample",)`` for sampled starts), ``at``: the positions of
    their points (the second one a constant height on a picture with one axis, or each point's height with
    ``along``: starts sampled along one axis, drawn at their outcome's row). The boundary is the zero of the
    predicate's margin (a contour on two grid axes, a triangulated one through sampled starts, vertical lines on
    one axis), drawn only where the margin depends on those axes alone; a cross marks each red flag (a cell or
    start the theorem guarantees that ends in another outcome, :func:`stabjax.mapping.basin.theory_agreement`).
    """
    from matplotlib import patheffects
    from matplotlib.lines import Line2D

    from ..mapping.basin import theory_agreement
    from .labels import theory_words
    from .maps import zero_crossings

    a = theory_agreement(ds)
    if a is None or f"margin_{a['predicate']}" not in ds:
        return []
    main, handles = a["predicate"], []
    said = theory_words(ds, main)
    m = ds[f"margin_{main}"]
    extra = [d for d in m.dims if d not in dims]
    if extra and all(np.all(np.ptp(m.values, axis=m.get_axis_num(d)) == 0) for d in extra):
        m = m.isel({d: 0 for d in extra})  # the same over the samples: one boundary over the grid
    if not [d for d in m.dims if d not in dims] and np.nanmin(m.values) < 0 < np.nanmax(m.values):
        mv = m.transpose(*[d for d in dims if d in m.dims]).values if m.dims else m.values
        if dims == ("sample",) and along:  # starts sampled along one axis: the margin's zeros along it
            order = np.argsort(np.asarray(at[0], float), kind="stable")
            for xc in zero_crossings(np.asarray(at[0], float)[order], mv[order]):
                ax.axvline(xc, color="k", lw=2.0)
            handles.append(Line2D([], [], color="k", lw=2.0, label=f"theory boundary: {said}"))
        elif dims == ("sample",):
            if len(at) == 2 and mv.size >= 3:
                ax.tricontour(np.asarray(at[0], float), np.asarray(at[1], float), mv, levels=[0.0], colors="k",
                              linewidths=2.0)
                handles.append(Line2D([], [], color="k", lw=2.0, label=f"theory boundary: {said}"))
        elif len(dims) == 2 and m.ndim == 2:
            ax.contour(at[0], at[1], mv.T, levels=[0.0], colors="k", linewidths=2.0)  # rows: the second axis
            handles.append(Line2D([], [], color="k", lw=2.0, label=f"theory boundary: {said}"))
        elif len(dims) == 1 and m.ndim == 1:
            for xc in zero_crossings(at[0], mv):
                ax.axvline(xc, color="k", lw=2.0)
            handles.append(Line2D([], [], color="k", lw=2.0, label=f"theory boundary: {said}"))
    if a.get("red_flags"):
        bad = ds["outcome"].copy(data=a["red_flag_mask"])
        bad = bad.any([d for d in bad.dims if d not in dims]) if set(bad.dims) - set(dims) else bad
        bad = bad.transpose(*dims).values
        halo = [patheffects.withStroke(linewidth=3.5, foreground="white")]
        if len(dims) == 2:
            ii, jj = np.nonzero(bad)
            ax.plot(np.asarray(at[0])[ii], np.asarray(at[1])[jj], "kx", ms=7, mew=1.5, path_effects=halo)
        else:
            idx = np.nonzero(bad)[0]
            y = np.asarray(at[1], float)
            ax.plot(np.asarray(at[0])[idx], y[idx] if y.ndim else np.full(idx.size, y), "kx", ms=7, mew=1.5,
                    path_effects=halo)
        handles.append(Line2D([], [], color="k", marker="x", ls="", mew=1.5, path_effects=halo,
                              label=f"red flag: guaranteed {a['guarantees']!r}, ended elsewhere ({a['red_flags']:,})"))
    return handles


def _extent(x, y):
    xe, ye = cell_edges(x, False), cell_edges(y, False)
    return (xe[0], xe[-1], ye[0], ye[-1])


# one trajectory per grid point (no [sample]): S is the share of a lattice, not an estimate from random draws
LATTICE_NOTE = ("; one trajectory per grid point, not random draws: S is the lattice's share, and SE and the "
                "Wilson interval (computed as for random draws) bound no error")


def format_summary(ds: xr.Dataset, max_points: int = 12) -> str:
    """The outcome table the CLI prints: pooled counts and fractions, and per grid point if few."""
    from ..mapping.basin import summary_rows, theory_agreement

    rows = summary_rows(ds)
    n = sum(r[1] for r in rows)
    lines = [f"{'outcome':<16}{'count':>9}{'S':>9}{'± SE':>9}   95% Wilson",
             *[f"{name:<16}{c:>9d}{s:>9.4f}{se:>9.4f}   [{lo:.4f}, {hi:.4f}]" for name, c, s, se, lo, hi in rows],
             f"(all {n} trajectories pooled)" + LATTICE_NOTE * ("sample" not in ds["outcome"].dims)]
    grid = [d for d in ds["outcome"].dims if d != "sample"]
    if "basin_fraction" in ds and grid:
        npts = int(np.prod([ds.sizes[d] for d in grid]))
        if npts <= max_points:
            names = kit.names_colors(ds)[0]
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
    found = kit.attractors(ds)
    if found:
        lines.append("attractors found (where: the representative trajectory's state at t1; for one that moves, "
                     "the late-window range of each observable, the median over its trajectories):")
        w = max(len(a["name"]) for a in found) + 2
        for a in found:
            lam = f", largest Lyapunov exponent {a['lyapunov']:.3g}" if np.isfinite(a["lyapunov"]) else ""
            if lam and "attractor_events" in ds:
                lam += " (median over its trajectories at every grid point)"
            lines.append(f"  {a['name']:<{w}}{a['count']:>9d} {trajectory_noun(a['count'])}{lam}; "
                         f"{a['where'] or 'where: not recorded'}")
    agree = theory_agreement(ds)
    if agree is not None:
        lines.append(f"theorem '{agree['predicate']}' against the outcomes (trajectories):")
        w = max(len(r) for r in agree["rows"]) + 2
        lines.append(" " * w + "".join(f"{c:>14}" for c in agree["columns"]))
        lines += [f"{r:<{w}}" + "".join(f"{v:>14d}" for v in vals) for r, vals in agree["rows"].items()]
        lines += [f"  {t}" for t in agreement_sentences(agree)]
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


def agreement_sentences(a: dict) -> list[str]:
    """What the theorem-against-outcome table (:func:`stabjax.mapping.basin.theory_agreement`) says, in words:
    its red flags and where it is conservative when the predicate names the outcome it guarantees."""
    head = (f"Predicate '{a['predicate']}'" + (f" ({a['doc']})" if a["doc"] else "")
            + ": 'guaranteed' rows are the trajectories whose parameters (and start, where it reads the start) "
              "satisfy it.")
    if a.get("absent"):
        return [head, f"It guarantees '{a['guarantees']}', which is not an outcome of this result (the spec's "
                      "[outcomes] replaced the model's, or the attractors were discovered): no red flag or "
                      "conservative count; the table counts, the reader judges."]
    if not a["guarantees"]:
        return [head, "It names no outcome it guarantees (Predicate(..., outcome=NAME) in the model's theory()): "
                      "a guaranteed trajectory ending in another outcome would refute it there, a silent one ending "
                      "in it is where it is conservative; the table counts, the reader judges."]
    g = a["guarantees"]
    by = ", ".join(f"{n} {c:,}" for n, c in a["red_flags_by_outcome"].items())
    out = [head, f"It guarantees '{g}'. Theory conservative (silent, ended in '{g}'): {a['conservative']:,}.",
           f"RED FLAGS (guaranteed '{g}', ended in another outcome): {a['red_flags']:,}" + (f" ({by})." if by else ".")]
    if a["undecided"]:
        out.append(f"{a['undecided']:,} guaranteed trajectories ended unclassified or failed: neither refuted nor "
                   "confirmed.")
    return out
