"""Verdict maps with the theoretical boundary drawn over them, and the theory x simulation table.

The boundary is the zero contour of ``margin_<main>`` (the predicate the system names as
"theory guarantees stability"); cells where the theory guarantees stability but the
simulation flipped or diverged are the red flags and are marked with a cross. The map and
the table are the verdicts at t1; a dataset with verdicts at several horizons (dim ``horizon``)
also gets the empirical boundary of the converged region at each horizon drawn over it.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from .labels import (axis_label, categories, category_axis, cell_note, error_words, fixed_note, heading,
                     main_predicate, symbol, theory_words)

if TYPE_CHECKING:
    import xarray as xr


def _verdicts(ds: xr.Dataset, what: str) -> None:
    """Refuse a result without attitude verdicts (a user model's named outcomes, a discovery, a
    refinement) by name, pointing to the entry point that draws every kind."""
    if "verdict" not in ds:
        from .kit import kind_of

        k = kind_of(ds)
        raise ValidationError("result", f"{what} needs attitude verdicts; this result holds "
                                        f"{k.words if k else 'no verdicts'}: draw it with stabjax.plot(result) "
                                        "(or stabjax plot FILE), which draws every kind of result")


def wrap(label: str, width: int = 48) -> str:
    """A legend entry on lines of at most ``width`` characters (a long one would run off a small figure)."""
    import textwrap

    return "\n".join(textwrap.wrap(label, width)) if len(label) > width else label


def legend_below(ax, handles, ncol: int = 2, fontsize: float = 8, width: int = 48, title: str | None = None):
    """The legend under the axes, out of the data, as wide as the axes at most: the most columns (up to
    ``ncol``) that fit with the entries whole, else with entries wrapped at ``width`` characters, else one
    column wrapped to the axes' width."""
    engine = ax.figure.get_layout_engine()
    if engine is not None:  # the axes' width once laid out (constrained layout widens it)
        engine.execute(ax.figure)
    avail = ax.figure.get_figwidth() * 72 * ax.get_position().width * 1.15  # points; may reach a little past
    em = 0.55 * fontsize  # a character's mean width in points
    labels = [h.get_label().replace("\n", " ") for h in handles]

    def span(texts, k):  # width of the legend in points with k columns (filled column by column)
        rows = -(-len(texts) // k)
        cols = [texts[j * rows:(j + 1) * rows] for j in range(k)]
        return sum(max((len(line) for t in c for line in t.split("\n")), default=0) + 5 for c in cols if c) * em

    tries = [(k, None) for k in range(ncol, 0, -1)] + [(k, width) for k in range(ncol, 0, -1)]
    for k, w in tries + [(1, max(20, int(avail / em) - 5))]:
        texts = [wrap(t, w) if w else t for t in labels]
        if span(texts, k) <= avail or (k, w) == (1, max(20, int(avail / em) - 5)):
            break
    for h, t in zip(handles, texts):
        h.set_label(t)
    from matplotlib.transforms import ScaledTranslation

    # a fixed distance under the axes (tick labels and the axis label), whatever the axes' height
    below = ax.transAxes + ScaledTranslation(0, -40 / 72, ax.figure.dpi_scale_trans)
    return ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0), bbox_transform=below, ncol=k,
                     fontsize=fontsize, frameon=False, title=title, title_fontsize=fontsize)


def grid_dims(ds: xr.Dataset) -> list[str]:
    """The verdict map's grid axes (without ``sample`` and ``horizon``)."""
    _verdicts(ds, "a verdict map")
    return [d for d in ds["verdict"].dims if d not in ("sample", "horizon")]


def at_t1(ds: xr.Dataset) -> xr.Dataset:
    """The dataset at its last horizon (t1): variables with a ``horizon`` dim lose it."""
    return ds.isel(horizon=-1) if "horizon" in ds.dims else ds


def _converged_indicator(ds: xr.Dataset):
    from ..fold import verdict as V

    conv = (ds["verdict"] == V.CONVERGED).astype(float)
    return conv.mean("sample") if "sample" in conv.dims else conv


def horizon_boundaries(ds: xr.Dataset, dim: str | None = None) -> dict[float, list[tuple[float, float]]]:
    """Brackets of the empirical boundary of the converged region along a 1-D grid, at each horizon.

    Returns ``{T: [(lo, hi), ...]}``: adjacent grid values between which the verdict changes from
    converged to not converged or back (with samples: the converged fraction crosses 1/2).
    """
    from .kit import t1_of

    dims = grid_dims(ds)
    dim = dim or dims[0]
    hs = ds["horizon"].values if "horizon" in ds.dims else [None]
    out = {}
    for j, T in enumerate(hs):
        sub = ds.isel(horizon=j) if T is not None else ds
        c = _converged_indicator(sub)
        other = [d for d in c.dims if d != dim]
        if other:
            c = c.mean(other)
        x, v = sub[dim].values, c.values >= 0.5
        key = float(T) if T is not None else t1_of(ds)
        out[key] = [(float(x[i]), float(x[i + 1])) for i in range(len(x) - 1) if v[i] != v[i + 1]]
    return out


# Okabe & Ito's colour-blind-safe qualitative palette (blue, vermillion, reddish purple, sky blue, ...)
_HCOLORS = ("#0072B2", "#D55E00", "#CC79A7", "#56B4E9", "#E69F00", "#009E73", "#000000")


def _long_paths(cs, min_len: float, cell: tuple[float, float]) -> None:
    """Remove the contour pieces shorter than ``min_len`` cells (``cell``: one cell's width and
    height in data units): at a coarse horizon the converged indicator is speckled, and islands of
    one or two cells are noise, not a boundary."""
    from matplotlib.path import Path as MPath

    for path in cs.get_paths():
        if not len(path.vertices):
            continue
        segs = path.to_polygons(closed_only=False)
        good = [sg for sg in segs if len(sg) > 1 and
                np.sum(np.hypot(np.diff(sg[:, 0]) / cell[0], np.diff(sg[:, 1]) / cell[1])) >= min_len]
        if len(good) == len(segs):
            continue
        if good:
            path.vertices = np.concatenate(good)
            path.codes = np.concatenate([[MPath.MOVETO] + [MPath.LINETO] * (len(g) - 1) for g in good])
        else:
            path.vertices, path.codes = np.zeros((0, 2)), None


def _draw_horizons(ax, full: xr.Dataset, dims: list[str], log: dict):
    """The edge of the converged region had the runs stopped at the last horizon before t1 (dashed):
    where it differs from the t1 map, the verdicts there still depend on the horizon. Earlier
    horizons are left out of the map (their counts are in the printed table): at T = t1/100 most
    runs are still undecided and their edge is noise."""
    if "horizon" not in full.dims or full.sizes["horizon"] < 2:
        return []
    from matplotlib.lines import Line2D

    handles = []
    hs = full["horizon"].values
    for j, T in list(enumerate(hs))[-2:-1] if len(dims) == 2 else enumerate(hs):
        col = _HCOLORS[j % len(_HCOLORS)]
        c = _converged_indicator(full.isel(horizon=j))
        lab = f"converged region's edge at T = {T:,.4g}" if len(dims) != 2 else \
            f"converged region's edge, runs stopped at T = {T:,.4g}"
        if len(dims) == 2:
            xd, yd = dims[1], dims[0]
            m = c.transpose(yd, xd).values
            if np.nanmin(m) < 0.5 < np.nanmax(m) and full.sizes[xd] > 1 and full.sizes[yd] > 1:
                x, y = np.asarray(full[xd].values, float), np.asarray(full[yd].values, float)
                cs = ax.contour(x, y, m, levels=[0.5], colors=[col], linewidths=1.6, linestyles="--")
                if not (log.get(xd) or log.get(yd)):
                    _long_paths(cs, 4.0, (np.ptp(x) / (len(x) - 1), np.ptp(y) / (len(y) - 1)))
                if any(len(p.vertices) for p in cs.get_paths()):  # no legend entry for an edge left undrawn
                    handles.append(Line2D([], [], color=col, lw=1.6, ls="--", label=lab))
        elif len(dims) == 1:
            br = horizon_boundaries(full.isel(horizon=[j]), dims[0])[float(T)]
            for i, (a, b) in enumerate(br):
                mid = np.sqrt(a * b) if log.get(dims[0]) else 0.5 * (a + b)
                ax.axvline(mid, color=col, lw=1.3, ls="--", ymax=0.92 - 0.06 * j, label=lab if i == 0 else None)
                ax.axvspan(a, b, ymin=0.92 - 0.06 * j - 0.03, ymax=0.92 - 0.06 * j, color=col, alpha=0.5, lw=0)
            if br:
                handles.append(Line2D([], [], color=col, lw=1.3, ls="--", label=lab + " (bracket)"))
    return handles




def confusion(ds: xr.Dataset) -> dict:
    """Counts of (theory guarantees stability?) x (empirical verdict at t1)."""
    from ..fold import verdict as V

    _verdicts(ds, "the theory x simulation table")
    ds = at_t1(ds)
    main = main_predicate(ds)
    v = ds["verdict"].values.ravel()
    out = {"columns": list(V.NAMES), "rows": {}}
    if main is None:
        out["rows"]["(no theory)"] = [int((v == i).sum()) for i in range(len(V.NAMES))]
        return out
    ok = ds[f"theory_{main}"].values.ravel().astype(bool)
    out["rows"]["theory: guaranteed"] = [int(((v == i) & ok).sum()) for i in range(len(V.NAMES))]
    out["rows"]["theory: silent"] = [int(((v == i) & ~ok).sum()) for i in range(len(V.NAMES))]
    out["red_flags"] = int((ok & ((v == V.FLIPPED) | (v == V.DIVERGED))).sum())
    out["conservative"] = int((~ok & (v == V.CONVERGED)).sum())
    out["predicate"] = main
    return out


def converged_fraction(ds: xr.Dataset):
    """Fraction converged (at t1) over the ``sample`` dim and its standard error sqrt(p(1-p)/n)."""
    from ..fold import verdict as V

    ds = at_t1(ds)
    conv = (ds["verdict"] == V.CONVERGED).astype(float)
    n = ds.sizes["sample"]
    p = conv.mean("sample")
    se = np.sqrt(p * (1 - p) / n)
    return p, se


def verdict_cmap():
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from ..fold import verdict as V

    return ListedColormap(V.COLORS), BoundaryNorm(np.arange(-0.5, len(V.NAMES) + 0.5), len(V.NAMES))


def cell_edges(x: np.ndarray, log: bool) -> np.ndarray:
    x = np.asarray(x, float)
    if len(x) == 1:
        return np.array([x[0] - 0.5, x[0] + 0.5]) if not log else np.array([x[0] / 1.5, x[0] * 1.5])
    if log:
        lx = np.log(x)
        mid = (lx[1:] + lx[:-1]) / 2
        return np.exp(np.concatenate([[2 * lx[0] - mid[0]], mid, [2 * lx[-1] - mid[-1]]]))
    mid = (x[1:] + x[:-1]) / 2
    return np.concatenate([[2 * x[0] - mid[0]], mid, [2 * x[-1] - mid[-1]]])


def _cell_boundary(ax, xe, ye, ok):
    """The edge of the guaranteed cells, along the cell borders (a map with a category axis has no contour
    to interpolate): a segment wherever a guaranteed cell meets one that is not."""
    from matplotlib.collections import LineCollection

    segs = [[(xe[j + 1], ye[i]), (xe[j + 1], ye[i + 1])] for i, j in zip(*np.nonzero(ok[:, :-1] != ok[:, 1:]))]
    segs += [[(xe[j], ye[i + 1]), (xe[j + 1], ye[i + 1])] for i, j in zip(*np.nonzero(ok[:-1, :] != ok[1:, :]))]
    ax.add_collection(LineCollection(segs, colors="k", linewidths=2.2))


def _label_region(ax, x, y, ok, logx: bool, logy: bool):
    """Write "theory guarantees stability" inside the guaranteed region, at its cell farthest
    from the region's edge (so the words sit clearly on the right side of the boundary line)."""
    if not ok.any() or ok.all():
        return
    from scipy.ndimage import distance_transform_edt

    d = distance_transform_edt(np.pad(ok, 1, constant_values=False))[1:-1, 1:-1]
    iy, ix = np.unravel_index(np.argmax(d), d.shape)
    ax.text(x[ix], y[iy], "theory guarantees\nstability here", ha="center", va="center", fontsize=9,
            bbox=dict(boxstyle="round,pad=0.3", facecolor="white", edgecolor="0.3", alpha=0.85))


def _thin(ok: np.ndarray) -> bool:
    """The guaranteed cells form no region, only a line one cell wide (a condition holding on an equality)."""
    if not ok.any() or ok.all():
        return False
    return not (ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]).any()  # no 2 x 2 block of guaranteed cells


def _guaranteed_spans(x, ok, crossings) -> list[tuple[float, float]]:
    """The intervals of a 1-D axis where the theory holds: from the guaranteed grid points out to the
    interpolated zero crossings of its margin (or to the last grid point where there is no crossing)."""
    x = np.asarray(x, float)
    cuts = sorted(set([float(x.min()), float(x.max())] + [float(c) for c in crossings]))
    spans = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        inside = (x >= a) & (x <= b)
        if inside.any() and ok[inside].sum() * 2 > inside.sum():
            if spans and spans[-1][1] == a:
                spans[-1] = (spans[-1][0], b)
            else:
                spans.append((a, b))
    return spans


def _title(ds: xr.Dataset, title: str | None = None) -> str:
    """Two lines: what the map is (``title``, in words; by default the result's heading: the spec's
    ``description``, else the system and the sweep's name) with its horizon, then the fixed parameters that
    matter and what one cell is."""
    from .kit import t1_of

    fixed = fixed_note(ds)
    second = "; ".join(x for x in (fixed, cell_note(ds)) if x)
    return f"{title or heading(ds)}  (t1 = {t1_of(ds):g})\n{second}"


def zero_crossings(x, m):
    x, m = np.asarray(x, float), np.asarray(m, float)
    out = []
    for i in range(len(x) - 1):
        if np.isfinite(m[i]) and np.isfinite(m[i + 1]) and m[i] * m[i + 1] < 0:
            out.append(x[i] - m[i] * (x[i + 1] - x[i]) / (m[i + 1] - m[i]))
        elif m[i] == 0:
            out.append(x[i])
    return out


def plot_sweep(ds: xr.Dataset, out: str | Path | None = None, ax=None, title: str | None = None):
    """Draw the sweep's verdict map (1-D or 2-D grid; random samples as converged fractions) at t1,
    with the empirical boundary at each horizon (dataset dim ``horizon``) over the theory's.
    ``title``: what the map shows, in words (default: the spec's description, else the system and the
    sweep's name).
    A result without verdicts is refused with a pointer to :func:`stabjax.plot`, which draws every kind."""
    import matplotlib.pyplot as plt
    from matplotlib import patheffects
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from ..fold import verdict as V

    dims = grid_dims(ds)
    if len(dims) == 3 and ax is None:  # small multiples: one 2-D map per value of the first axis
        return _facets(ds, dims, out, title)
    full, ds = ds, at_t1(ds)
    main = main_predicate(ds)
    sampled = "sample" in ds["verdict"].dims
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 5.2), constrained_layout=True)
    else:
        fig = ax.figure
    margin = ds[f"margin_{main}"] if main else None
    if sampled and margin is not None:
        margin = margin.isel(sample=0)
    log = {d: bool(ds[d].attrs.get("log_axis", 0)) for d in dims if d in ds.coords}

    cats = {d: categories(ds, d) for d in dims}
    if len(dims) == 2:
        xd, yd = dims[1], dims[0]
        x, y = ds[xd].values, ds[yd].values
        # a categorical axis is drawn at positions 0..n-1, one equal-width cell per category
        x, y = (np.arange(len(x), dtype=float) if cats[xd] else x), (np.arange(len(y), dtype=float) if cats[yd] else y)
        if sampled:
            p, se = converged_fraction(ds)
            mesh = ax.pcolormesh(cell_edges(x, log[xd]), cell_edges(y, log[yd]), p.transpose(yd, xd).values, cmap="viridis",
                                 vmin=0, vmax=1)
            fig.colorbar(mesh, ax=ax, label=f"fraction converged (n = {ds.sizes['sample']}, SE <= {float(se.max()):.2f})")
            handles = []
        else:
            cmap, norm = verdict_cmap()
            vv = ds["verdict"].transpose(yd, xd).values
            ax.pcolormesh(cell_edges(x, log[xd]), cell_edges(y, log[yd]), vv, cmap=cmap, norm=norm)
            present = sorted(set(np.unique(vv).tolist()))
            handles = [Patch(color=V.COLORS[i], label=V.NAMES[i]) for i in present]
            if main:
                ok = ds[f"theory_{main}"].transpose(yd, xd).values.astype(bool)
                bad = ok & ((vv == V.FLIPPED) | (vv == V.DIVERGED))
                if bad.any():
                    yy, xx = np.nonzero(bad)
                    halo = [patheffects.withStroke(linewidth=3.5, foreground="white")]  # legible on dark cells
                    ax.plot(x[xx], y[yy], "kx", ms=7, mew=1.5, path_effects=halo)
                    handles.append(Line2D([], [], color="k", marker="x", ls="", mew=1.5, path_effects=halo,
                                          label="theory says stable, simulation not"))
        if margin is not None and len(x) > 1 and len(y) > 1:
            m = margin.transpose(yd, xd).values
            ok = ds[f"theory_{main}"]
            ok = (ok.isel(sample=0) if sampled else ok).transpose(yd, xd).values.astype(bool)
            said = theory_words(ds, main)
            if np.nanmin(m) < 0 < np.nanmax(m) and not (cats[xd] or cats[yd]):  # no contour across categories
                # the boundary line says where; a label in the region says which side (no hatching over it)
                ax.contour(x, y, m, levels=[0.0], colors="k", linewidths=2.2)
                if _thin(ok):  # a knife edge (e.g. lam^2 = nu): the region is the line itself
                    handles.append(Line2D([], [], color="k", lw=2.2,
                                          label=f"theory guarantees stability only on this line: {said}"))
                else:
                    handles.append(Line2D([], [], color="k", lw=2.2, label=f"theory boundary: {said}"))
                    _label_region(ax, x, y, ok, log[xd], log[yd])
            elif ok.any() and not ok.all():  # categories: the guaranteed cells' edge, along the cell borders
                _cell_boundary(ax, cell_edges(x, log[xd]), cell_edges(y, log[yd]), ok)
                handles.append(Line2D([], [], color="k", lw=2.2, label=f"theory boundary: {said}"))
                _label_region(ax, x, y, ok, log[xd], log[yd])
            elif ok.all():
                handles.append(Patch(facecolor="none", edgecolor="none", label=f"theory guarantees stability "
                                                                                f"everywhere here ({said})"))
        handles += _draw_horizons(ax, full, dims, log)
        ax.set_xlabel(axis_label(ds, xd))
        ax.set_ylabel(axis_label(ds, yd))
        if cats[xd]:
            category_axis(ax, "x", cats[xd], axis_label(ds, xd))
        elif log[xd]:
            ax.set_xscale("log")
        if cats[yd]:
            category_axis(ax, "y", cats[yd], axis_label(ds, yd))
        elif log[yd]:
            ax.set_yscale("log")
        if handles:
            legend_below(ax, handles)
    elif len(dims) == 1:
        xd = dims[0]
        x = np.arange(ds.sizes[xd], dtype=float) if cats[xd] else ds[xd].values
        if sampled:
            p, se = converged_fraction(ds)
            ax.errorbar(x, p.values, yerr=se.values, fmt="o" if cats[xd] else "o-", color=V.COLORS[0], capsize=3,
                        label=f"fraction converged ± SE (n = {ds.sizes['sample']})")
            ax.set_ylabel("fraction converged")
            ax.set_ylim(-0.05, 1.05)
        else:
            # the late window shows what the horizon ends on; the early transient peak is in error_max_settled
            metric = "error_max_late" if "error_max_late" in ds else "error_t1"
            yv = ds[metric].values.copy()
            yv = np.where(np.isfinite(yv), yv, ds["error_t1"].values) if "error_t1" in ds else yv
            vv = ds["verdict"].values
            for i, name in enumerate(V.NAMES):
                sel = vv == i
                if sel.any():
                    ax.scatter(x[sel], np.maximum(yv[sel], 1e-16), color=V.COLORS[i], label=name, s=36, zorder=3)
            ax.set_yscale("log")
            ax.set_ylabel(error_words(ds, metric))
        if margin is not None:
            mv = margin.values.reshape(len(x), -1)[:, 0] if sampled else margin.values
            crossings = [] if cats[xd] else zero_crossings(x, mv)
            for i, xc in enumerate(crossings):
                ax.axvline(xc, color="k", lw=2, label=f"theory boundary: {theory_words(ds, main)}" if i == 0 else None)
            okx = ds[f"theory_{main}"].values.astype(bool)
            if sampled:
                okx = okx.reshape(len(x), -1)[:, 0]
            if okx.any() and cats[xd]:  # shade each guaranteed category, not the span between them
                for i, xi in enumerate(x[okx]):
                    ax.axvspan(xi - 0.5, xi + 0.5, color="0.85", zorder=0, label="theory guarantees stability" if i == 0 else None)
            elif okx.any():  # shade out to the boundary line, not just to the last guaranteed grid point
                for i, (a, b) in enumerate(_guaranteed_spans(x, okx, crossings)):
                    ax.axvspan(a, b, color="0.85", zorder=0, label="theory guarantees stability" if i == 0 else None)
        if not cats[xd]:  # between categories there is no edge to bracket
            _draw_horizons(ax, full, dims, log)
        ax.set_xlabel(axis_label(ds, xd))
        if cats[xd]:
            category_axis(ax, "x", cats[xd], axis_label(ds, xd))
        elif log.get(xd):
            ax.set_xscale("log")
        legend_below(ax, ax.get_legend_handles_labels()[0])
    else:
        counts = V.counts(ds["verdict"].values)
        n = max(sum(counts.values()), 1)
        fr = np.array([counts[k] / n for k in V.NAMES])
        se = np.sqrt(fr * (1 - fr) / n)
        ax.bar(V.NAMES, fr, yerr=se, color=V.COLORS, capsize=4)
        ax.set_ylabel(f"fraction of {n} trajectories (± SE)")
    ax.set_title(_title(ds, title), fontsize=10)
    return save(fig, out, own)


def save(fig, out, own: bool = True, dpi: int = 110, **kw):
    """Write ``fig`` to ``out`` (folders made) if given; close it if this module made it."""
    if out is not None:
        import matplotlib.pyplot as plt

        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi, **kw)
        if own:
            plt.close(fig)
    return fig


def _facets(ds: xr.Dataset, dims: list[str], out, title: str | None = None):
    import matplotlib.pyplot as plt

    d0 = dims[0]
    n = ds.sizes[d0]
    ncol = 2 if n == 4 else min(n, 3)
    nrow = -(-n // ncol)
    fig, axs = plt.subplots(nrow, ncol, figsize=(6.0 * ncol, 5.2 * nrow), constrained_layout=True, squeeze=False)
    for i in range(nrow * ncol):
        ax = axs.flat[i]
        if i >= n:
            ax.set_visible(False)
            continue
        sub = ds.isel({d0: i})
        plot_sweep(sub, ax=ax)
        labels = categories(ds, d0)
        value = labels[i] if labels else f"{symbol(d0)} = {sub[d0].values.item():g}"
        ax.set_title(value, fontsize=10)  # the figure's title says the rest once
        leg = ax.get_legend()
        if leg is not None:  # one legend per panel crowds the grid: keep them short
            handles = leg.legend_handles
            leg.remove()
            legend_below(ax, handles, fontsize=7.5)
    fig.suptitle(_title(ds, title), fontsize=11)
    return save(fig, out, dpi=100)


def format_confusion(ds: xr.Dataset) -> str:
    """Plain-text table (also used by the CLI through rich)."""
    from ..fold import verdict as V

    full, ds = ds, at_t1(ds)
    c = confusion(ds)
    cols = c["columns"]
    w = max(len(r) for r in c["rows"]) + 2
    lines = [" " * w + "".join(f"{k:>11}" for k in cols)]
    for r, vals in c["rows"].items():
        lines.append(f"{r:<{w}}" + "".join(f"{v:>11d}" for v in vals))
    if "red_flags" in c:
        lines.append(f"theory conservative (silent, simulation converged): {c['conservative']}")
        lines.append(f"RED FLAGS (theory guarantees, simulation flipped/diverged): {c['red_flags']}")
    if "sample" in ds["verdict"].dims:
        p, se = converged_fraction(ds)
        n = ds.sizes["sample"]
        if p.ndim == 0:
            lines.append(f"fraction converged: {float(p):.3f} ± {float(se):.3f} (n = {n})")
        elif p.size <= 40:
            lines.append(f"fraction converged ± standard error (n = {n} per point):")
            flat_p, flat_se = p.stack(point=p.dims), se.stack(point=p.dims)
            for idx in range(flat_p.sizes["point"]):
                where = ", ".join(f"{d}={flat_p[d].values[idx]:.4g}" for d in p.dims)
                lines.append(f"  {where}: {float(flat_p[idx]):.3f} ± {float(flat_se[idx]):.3f}")
    if "horizon" in full.dims:
        lines.append("verdicts at each horizon T (prefixes of the same runs):")
        for j, T in enumerate(full["horizon"].values):
            cnt = V.counts(full["verdict"].isel(horizon=j).values)
            lines.append(f"  T = {T:<10.4g}" + "".join(f"{cnt[k]:>11d}" for k in cols))
        if len(grid_dims(full)) == 1:
            for T, br in horizon_boundaries(full).items():
                s = ", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in br) or "none"
                lines.append(f"  converged boundary brackets at T = {T:.4g}: {s}")
    return "\n".join(lines)
