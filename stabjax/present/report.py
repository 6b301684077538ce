"""``stabjax report RESULT``: one self-contained HTML page per result, for a lab notebook.

A result is read and understood long after it was computed, by someone who did not run it. The
page therefore carries everything needed to judge it without the file: what was run (the spec,
the model file's hash, library versions, machine, time -- all read from the dataset's attributes,
never from the current environment), the outcome table with S ± SE and Wilson intervals, the
figures (PNG inlined as base64: one file, nothing to lose when it is mailed or attached), the
agreement with the theory, and the warnings that change how far the numbers can be trusted
(unclassified share, solver failures, verdicts that still change with the horizon, a model file
edited since, and what the outcome stage warned while the result was made: discovery's caveats, kept in the
result's ``warnings_json``, :func:`stored_warnings`).

Every kind of result the kit knows (:func:`stabjax.present.kit.kind`) is understood: verdict maps
(paper sweeps: every trajectory has a verdict, outcomes are the verdicts), named outcomes from a user
model (with per-point basin fractions), discovered attractors (with where each lies) and refinement
results (boundary segments from ``[refine]``); its figures are those of :func:`stabjax.present.show.plot`.
Warnings are per grid point: a share of unclassified trajectories that is large at a few points is named
there, not averaged away over the grid. The page carries a stamp naming the result it shows
(:func:`stabjax.run.outputs.stamp_output`), so ``stabjax report`` replaces its own page and no other file.
"""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .kit import json_attr as _json_attr
from .kit import kind

if TYPE_CHECKING:
    import xarray as xr

# a share of undecided/unclassified trajectories above this is called out: the classifier could
# not decide for that many, so the outcome fractions are lower bounds
UNCLASSIFIED_WARN = 0.05
POINTS_NAMED = 8  # grid points named in one warning (the rest counted)
WARNINGS_ATTR = "warnings_json"  # stabjax.run.derive.WARNINGS_ATTR (not imported: it would import JAX)


# ---- what the page says -------------------------------------------------------------------------


def provenance_rows(ds: xr.Dataset) -> list[tuple[str, str]]:
    """(what, value) of the run, from the dataset's attributes."""
    a = ds.attrs
    integ = _json_attr(ds, "integrate_json", {}) or {}
    rows = [
        ("system", f"{a.get('system', '?')}" + (f" ({a['system_ref']})" if a.get("system_ref") not in
                                                 (None, "", a.get("system")) else "")),
        ("paper", str(a.get("paper", "")) or "-"),
        ("description", str((_json_attr(ds, "spec_json", {}) or {}).get("description", "")) or "-"),
        ("model file", str(a.get("model_file", "")) or "built in"),
        ("model source sha256", str(a.get("model_sha256", "")) or "-"),
        ("spec fingerprint", str(a.get("fingerprint", "")) or "-"),
        ("trajectories", f"{int(a.get('n_trajectories', 0)):,}"),
        ("integration", ", ".join(f"{k} = {integ[k]}" for k in ("t0", "t1", "solver", "rtol", "atol", "max_steps")
                                  if k in integ) or "-"),
        ("engine", f"{a.get('engine', '?')}" + (f" ({a['engine_note']})" if a.get("engine_note") else "")
         + (f", executor {a['executor']}" if a.get("executor") else "")),
        ("steps, wall time", (f"{int(a['total_steps']):,} steps" if "total_steps" in a else "steps not recorded")
         + f", {float(a.get('wall_time_s', float('nan'))):.1f} s"),
        ("device, machine", f"{a.get('device', '?')}; {a.get('machine', '?')}"),
        ("versions", ", ".join(f"{k} {v}" for k, v in (_json_attr(ds, "versions_json", {}) or {}).items()) or "-"),
        ("git commit", str(a.get("git_commit", "")) or "-"),
        ("created", str(a.get("created", "")) or "-"),
    ]
    return rows


def outcome_table(ds: xr.Dataset) -> tuple[list[str], list[list[str]], str]:
    """(header, rows, note) of the outcomes pooled over the result, with S ± SE and 95 % Wilson intervals.

    For a refinement result the points are placed by the algorithm, not drawn at random, so no
    fraction is an estimate of anything: the table counts points per label and says so.
    """
    from ..mapping.basin import basin_stats
    from .kit import codes as all_codes
    from .kit import grid_dims, names_colors

    k = kind(ds)
    if k == "refine":
        names = ds.attrs["label_names"].split()
        lab = np.asarray(ds["point_label"].values)
        rows = [[n, f"{int((lab == i).sum()):,}"] for i, n in enumerate(names)]
        return (["label", "points"], rows,
                "points are chosen by the refinement (near the boundary), not at random: counts, not fractions")
    names, codes = names_colors(ds)[0], all_codes(ds)
    what = "outcome" if "outcome" in ds else "verdict at t1"
    st = basin_stats(codes[None, :], len(names))
    rows = [[n, f"{int(st['count'][0, i]):,}", f"{st['fraction'][0, i]:.4f} ± {st['se'][0, i]:.4f}",
             f"[{st['ci_low'][0, i]:.4f}, {st['ci_high'][0, i]:.4f}]"] for i, n in enumerate(names)]
    grid = grid_dims(ds)
    from .basins import LATTICE_NOTE

    note = (f"all {codes.size:,} trajectories pooled" + (f" over the grid ({' x '.join(grid)}); per-point fractions "
                                                         "are in the figures" if grid else "")
            + (LATTICE_NOTE if "sample" not in ds["outcome" if "outcome" in ds else "verdict"].dims else ""))
    return [what, "count", "S ± SE", "95% Wilson interval"], rows, note


def theory_section(ds: xr.Dataset) -> tuple[list[str], list[list[str]], list[str]] | None:
    """(header, rows, sentences) of the theory x simulation agreement, or None without a theory."""
    from .maps import confusion

    if kind(ds) == "refine":
        summ = _json_attr(ds, "theory_distance_json", {}) or {}
        if not summ:
            return None
        rows = [[ax, f"{s['median']:+.4g}", f"[{s['min']:+.4g}, {s['max']:+.4g}]"] for ax, s in summ.items()]
        return (["axis", "median distance", "range"], rows,
                [f"Distance of each bracketed boundary segment to the boundary of the theorem "
                 f"'{ds.attrs.get('theory_main', '')}' along the axis (> 0: the theorem is conservative there)."])
    main = ds.attrs.get("theory_main")
    if "verdict" not in ds and main and "outcome" in ds and f"theory_{main}" in ds:
        return _outcome_agreement(ds, main)
    if "verdict" not in ds or not main:
        return None
    c = confusion(ds)
    if "predicate" not in c:
        return None
    header = ["theory \\ simulation", *c["columns"]]
    rows = [[r, *[f"{v:,}" for v in vals]] for r, vals in c["rows"].items()]
    sentences = [f"Predicate '{c['predicate']}': 'guaranteed' rows are the trajectories whose parameters satisfy it.",
                 f"Theory conservative (silent, simulation converged): {c['conservative']:,}.",
                 f"Red flags (theory guarantees stability, simulation flipped or diverged): {c['red_flags']:,}."]
    return header, rows, sentences


def _outcome_agreement(ds: xr.Dataset, main: str):
    """The main theorem against named outcomes: trajectories guaranteed / not, per outcome, and where the
    predicate says which outcome it guarantees, its red flags and where it is conservative."""
    from ..mapping.basin import theory_agreement
    from .basins import agreement_sentences

    a = theory_agreement(ds)
    rows = [[label, *[f"{v:,}" for v in vals]] for label, vals in a["rows"].items()]
    return ["theory \\ outcome", *a["columns"]], rows, agreement_sentences(a)


def warnings(ds: xr.Dataset) -> list[str]:
    """What limits trust in this result, one sentence each (empty when nothing does)."""
    out = []
    k = kind(ds)
    if k == "refine":
        nu = int(ds.attrs.get("n_unbracketed", 0))
        if nu:
            out.append(f"{nu} of {ds.attrs.get('n_segments')} boundary segments are wider than the tolerance "
                       "(the point budget ran out, or the boundary is fractal there).")
        names = ds.attrs["label_names"].split()
        lab = np.asarray(ds["point_label"].values)
        for bad in ("undecided", "unclassified", "failed"):
            if bad in names and (lab == names.index(bad)).any():
                out.append(f"{int((lab == names.index(bad)).sum())} refinement points are '{bad}'.")
    else:
        out += undecided_warnings(ds)
        if "solver_status" in ds:
            st = np.asarray(ds["solver_status"].values).ravel()
            from ..fold.status import ESCAPED as STATUS_ESCAPED

            failed = int(((st != 0) & (st != STATUS_ESCAPED)).sum())
            if failed:
                out.append(f"{failed:,} of {st.size:,} trajectories ended with a solver failure (status != 0): "
                           "raise max_steps or loosen the tolerances, or read them as 'failed'.")
        if "verdict" in ds and "horizon" in ds.dims and ds.sizes["horizon"] >= 2:
            v = np.asarray(ds["verdict"].values)
            last, prev = v[..., -1].ravel(), v[..., -2].ravel()
            changed = int((last != prev).sum())
            if changed:
                T = ds["horizon"].values
                out.append(f"Horizon sensitivity: {changed:,} of {last.size:,} verdicts differ between T = {T[-2]:.4g} "
                           f"and t1 = {T[-1]:.4g}; a longer horizon may change more of them "
                           "(stabjax horizon-check RESULT re-runs a subset longer).")
    out += [f"{w['category']}: {w['message']}" if w["category"] else w["message"] for w in stored_warnings(ds)]
    from ..plan.identity import changed_sources  # the model file and every local module it imports

    for what in changed_sources(ds.attrs):
        out.append(f"The model file {what} has changed since this result was computed.")
    return out


def stored_warnings(ds: xr.Dataset) -> list[dict[str, str]]:
    """What the outcome stage warned while the result was made (``warnings_json``, written by the run:
    :func:`stabjax.run.derive.keeping`), each {"category": class name, "message": text}; empty for a result that
    records none (or was made before the attribute was)."""
    said = _json_attr(ds, WARNINGS_ATTR, []) or []
    if not isinstance(said, list):
        return []
    return [{"category": str(w.get("category", "")), "message": str(w.get("message", ""))} if isinstance(w, dict)
            else {"category": "", "message": str(w)} for w in said]


def _checked(ds: xr.Dataset) -> str:
    """What :func:`warnings` looked for and did not find, for this kind of result (a named-outcome page said
    "verdicts stable at the last horizon", a refinement's "no solver failures": checks it never made)."""
    if kind(ds) == "refine":
        return "every boundary segment bracketed within the tolerance, no refinement point undecided, " \
               "unclassified or failed"
    said = ["no unclassified excess at any grid point"]
    if WARNINGS_ATTR in ds.attrs:
        said.append("no warning while the outcomes were found")
    if "solver_status" in ds:
        said.append("no solver failures")
    if "verdict" in ds and "horizon" in ds.dims and ds.sizes["horizon"] >= 2:
        said.append("verdicts stable at the last horizon")
    return ", ".join(said)


def undecided_warnings(ds: xr.Dataset) -> list[str]:
    """The shares of 'unclassified' and 'undecided' trajectories above :data:`UNCLASSIFIED_WARN`, per grid
    point when the result samples starts at each point (the points named, with their share), else over the
    whole result (each grid cell is one trajectory: the map shows where they are)."""
    from .kit import codes as all_codes
    from .kit import grid_dims, names_colors, outcome_codes

    da = outcome_codes(ds)
    if da is None:
        return []
    names = names_colors(ds)[0]
    grid = grid_dims(ds)
    out = []
    for bad in ("unclassified", "undecided"):
        if bad not in names:
            continue
        code = names.index(bad)
        if "sample" in da.dims and grid:
            share = (da == code).mean("sample").transpose(*grid)
            flat = np.asarray(share.values).ravel()
            over = np.flatnonzero(flat > UNCLASSIFIED_WARN)
            if not over.size:
                continue
            order = over[np.argsort(-flat[over], kind="stable")]
            idx = np.unravel_index(order[:POINTS_NAMED], share.shape)
            points = []
            for j, p in enumerate(order[:POINTS_NAMED]):
                where = ", ".join(f"{d} = {float(ds[d].values[i[j]]):.4g}" if d in ds.coords else f"{d} #{i[j]}"
                                  for d, i in zip(grid, idx))
                points.append(f"{where} ({100 * flat[p]:.1f}%)")
            more = f", and {over.size - POINTS_NAMED} more" if over.size > POINTS_NAMED else ""
            out.append(f"At {over.size:,} of {flat.size:,} grid points more than {100 * UNCLASSIFIED_WARN:g}% of the "
                       f"trajectories are '{bad}': {'; '.join(points)}{more}. The other fractions there are lower "
                       "bounds; a longer t1 or other thresholds may decide them.")
        else:
            c = all_codes(ds)
            share = float((c == code).sum()) / max(c.size, 1)
            if share > UNCLASSIFIED_WARN:
                out.append(f"{100 * share:.1f}% of the trajectories are '{bad}' (over {100 * UNCLASSIFIED_WARN:g}%): "
                           "the other fractions are lower bounds; a longer t1 or other thresholds may decide them.")
    return out


def attractor_section(ds: xr.Dataset) -> tuple[list[str], list[list[str]]] | None:
    """(header, rows) of the attractors a discovery found, with where each lies; None for other results."""
    from .kit import attractors

    found = attractors(ds)
    if not found:
        return None
    rows = [[a["name"], a["type"].replace("_", " "), f"{a['count']:,}",
             f"{a['lyapunov']:.3g}" if np.isfinite(a["lyapunov"]) else "-", a["where"] or "-"] for a in found]
    lam = "largest Lyapunov exponent" + (" (median over its trajectories at every grid point)"
                                         if "attractor_events" in ds else "")
    return ["attractor", "type", "trajectories", lam, "where (representative)"], rows


# ---- figures -------------------------------------------------------------------------------------


def figures(ds: xr.Dataset) -> list[tuple[str, bytes]]:
    """(caption, PNG bytes) of the result's figures: the same pictures `stabjax plot` draws."""
    import tempfile

    import matplotlib.pyplot as plt

    from .show import plot

    captions = {"refine": "Evaluated points coloured by label and the bracketed boundary"
                          + (" with the theorem's boundary." if "theory_margin" in ds else "."),
                "basin": "Outcomes and basin stability S with 95% Wilson intervals.",
                "discovery": "Discovered attractors (named with where they lie) and basin stability S with 95% "
                             "Wilson intervals.",
                "verdicts": "Verdicts at t1 with the theory's boundary (the map of `stabjax plot`)."}
    out = []
    k = kind(ds)
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "figure.png"
        plot(ds, p, force=True)  # a file of this page's own temporary folder
        out.append((captions.get(k, "The result (the figure of `stabjax plot`)."), p.read_bytes()))
        if k == "verdicts" and "basin_fraction" in ds:
            from .basins import plot_basin

            q = Path(tmp) / "basin.png"
            plot_basin(ds, q)
            out.append(("Basin stability S per outcome with 95% Wilson intervals.", q.read_bytes()))
    plt.close("all")
    return out


# ---- the page ------------------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
color:#222;line-height:1.45}
h1{font-size:1.5em;margin-bottom:.2em} h2{font-size:1.15em;border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.5em 0;font-size:.92em} td,th{border:1px solid #ddd;padding:.25em .6em;text-align:left}
th{background:#f4f4f4} td.num{text-align:right;font-variant-numeric:tabular-nums}
.warn{background:#fff4e5;border-left:4px solid #e76f51;padding:.4em .8em;margin:.4em 0}
.ok{background:#eef7f1;border-left:4px solid #2a9d8f;padding:.4em .8em}
pre{background:#f7f7f7;padding:.6em;white-space:pre-wrap;font-size:.85em} figure{margin:1em 0} img{max-width:100%}
figcaption{font-size:.9em;color:#555} .muted{color:#666;font-size:.9em}
"""


def _table(header: list[str] | None, rows: list[list[str]], numeric: bool = True) -> str:
    """An HTML table; ``numeric``: columns after the first are numbers (right-aligned)."""
    e = html.escape
    head = "<thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr></thead>" if header else ""
    cls = " class=num" if numeric else ""
    body = "".join("<tr>" + "".join(f"<td{cls if i else ''}>{e(str(c))}</td>" for i, c in enumerate(r))
                   + "</tr>" for r in rows)
    return f"<table>{head}<tbody>{body}</tbody></table>"


def render(ds: xr.Dataset, source: str = "") -> str:
    """The HTML page of ``ds`` (``source``: the file it was read from, shown in the heading)."""
    from .kit import kind_of
    from .labels import heading

    e = html.escape
    title = heading(ds)
    parts = [f"<!doctype html><html lang=en><head><meta charset=utf-8>"
             f"<title>{e(title)} - stabjax report</title><style>{_CSS}</style></head><body>",
             f"<h1>{e(title)}</h1><p class=muted>{e(kind_of(ds).words)} ({e(kind(ds))} result)"
             + (f" read from <code>{e(source)}</code>" if source else "") + "; page written by <code>stabjax report</code>"
             "</p>"]
    parts.append("<h2>What was run</h2>" + _table(None, [list(r) for r in provenance_rows(ds)], numeric=False))
    spec = _json_attr(ds, "spec_json")
    if spec is not None:
        parts.append("<details><summary>spec (as recorded in the result)</summary><pre>"
                     f"{e(json.dumps(spec, indent=2))}</pre></details>")
    vcfg = _json_attr(ds, "verdict_json")
    if vcfg and "verdict" in ds:  # the attitude classifier's settings: of a result it classified, not of outcomes
        parts.append("<details><summary>classifier settings</summary><pre>"
                     f"{e(json.dumps(vcfg, indent=2))}</pre></details>")
    if ds.attrs.get("kind") == "shock":  # a minimal-fatal-shock search: its own section (stabjax.present.shock)
        from .shock import report_parts

        parts += [f"<h2>{e(h)}</h2>{body}" for h, body in report_parts(ds)] + ["</body></html>"]
        return "\n".join(parts)
    header, rows, note = outcome_table(ds)
    stats = "" if kind(ds) == "refine" else "; S = fraction, SE = sqrt(S (1 - S) / N), Wilson = 95% score interval"
    parts.append("<h2>Outcomes</h2>" + _table(header, rows) + f"<p class=muted>{e(note)}{stats}.</p>")
    if kind(ds) == "refine":
        from .refinement import format_summary

        parts.append(f"<pre>{e(format_summary(ds))}</pre>")
    att = attractor_section(ds)
    if att is not None:
        parts.append("<h2>Attractors found</h2>" + _table(att[0], att[1], numeric=False)
                     + "<p class=muted>where: the state at t1 of the trajectory nearest the group's median features "
                       "(a fixed point), or the range of each observable over the late window (an attractor that "
                       "moves).</p>")
    if "attractor_events" in ds:  # a continuation along the grid axis: where each attractor is born and dies
        ev = json.loads(str(ds["attractor_events"].values))
        axis = next((k for e_ in ev for k in e_ if k not in ("attractor", "event", "index")), None)
        rows = [[x["attractor"], x["event"], f"{x[axis]:g}" if axis else str(x["index"])] for x in ev]
        parts.append("<h2>Births and deaths along the axis</h2>"
                     + (_table(["attractor", "event", axis or "grid index"], rows, numeric=False) if rows
                        else "<p>None: every attractor is present at every grid point.</p>"))
    th = theory_section(ds)
    parts.append("<h2>Theory agreement</h2>")
    if th is None:
        parts.append("<p>This system states no theorem for these parameters: nothing to compare.</p>")
    else:
        header, rows, sentences = th
        parts.append(_table(header, rows) + "".join(f"<p>{e(s)}</p>" for s in sentences))
    parts.append("<h2>Figures</h2>")
    for caption, png in figures(ds):
        b64 = base64.b64encode(png).decode()
        parts.append(f"<figure><img alt='{e(caption)}' src='data:image/png;base64,{b64}'>"
                     f"<figcaption>{e(caption)}</figcaption></figure>")
    parts.append("<h2>Warnings</h2>")
    ws = warnings(ds)
    parts.append("".join(f"<div class=warn>{e(w)}</div>" for w in ws) if ws else
                 f"<div class=ok>None: {e(_checked(ds))}.</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(ds: xr.Dataset | str | Path, out: str | Path, source: str = "", *, force: bool = False) -> Path:
    """Write the page of the result ``ds`` (a dataset, or the path of a result file or a finished sweep's store)
    atomically (a half-written page is never left behind), stamped with the result it shows and the digest of
    its bytes (:func:`stabjax.run.outputs.stamp_output`: edited later, it is no longer a page of ours to
    replace). ``out`` (``.html``) is never the result's file or a module loaded, and an existing file there is
    replaced only when it is a page stabjax wrote of this result or of one of its spec, or with ``force=True``
    (what ``stabjax report`` checks of its ``--out``)."""
    import os

    from ..run.outputs import (check_output, clean_stale_temps, input_files, is_own_output, spec_digest_of,
                               stamp_output, temp_beside)
    from .show import _dataset

    ds, path = _dataset(ds)
    kind(ds)  # anything but a stabjax result is refused by name here, not by an AttributeError deep in render
    source = source or (str(path) if path is not None else "")
    out = Path(out)
    digest = spec_digest_of(ds)
    check_output(out, "out", (".html",), inputs=input_files(source or None), force=force,
                 same=lambda p: is_own_output(p, source or None, spec=digest),
                 what="a page stabjax wrote of this result (or of a result of its spec)")
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(out, keep_suffix=True)  # a process killed while it wrote this page left its file behind
    tmp = temp_beside(out, keep_suffix=True)  # the suffix tells stamp_output the format
    try:
        tmp.write_text(render(ds, source), encoding="utf-8")
        stamp_output(tmp, source or None, spec=spec_digest_of(ds))
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out

