"""Benchmark of the adaptive boundary refinement against the full lattice of the same resolution.

``python -m benchmarks.refine_bench`` (or ``stabjax bench --suite refine``): trajectories and
trajectory-steps of :mod:`stabjax.explore.refine` on a spec with a ``[refine]`` section (default: paper A's
(alpha, sigma) map, ``sweeps/refine_default.toml``) against the plain sweep over the refinement's
whole final lattice; with the full lattice run whole, also the boundary edges the refinement missed.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import xarray as xr

from stabjax.errors import ValidationError
from stabjax.explore.refine import refine_plan
from stabjax.explore.refine_config import RefineConfig, classes, fine_values, horizon_times, refine_config
from stabjax.plan.spec import Plan, load_spec, make_plan


# ---- benchmark ----------------------------------------------------------------------------------

BENCH_SPEC = Path(__file__).resolve().parents[1] / "stabjax" / "sweeps" / "refine_default.toml"  # package data


def full_lattice_spec(spec: Mapping[str, Any], plan: Plan | None = None) -> dict:
    """The plain sweep over the refinement's whole final lattice (the full grid of the same resolution): every
    trajectory to t1, no early stop of any kind (the fixed-horizon baseline), where the model allows stops."""
    plan = plan or make_plan(spec)
    cfg = refine_config(plan)
    grid = {ax.key: fine_values(ax.values, ax.log, L).tolist() for ax, L in zip(plan.grid, cfg.levels)}
    s = {k: v for k, v in spec.items() if k != "refine"}
    s["grid"] = grid
    integ = {k: v for k, v in s.get("integrate", {}).items() if k not in ("early_stop", "attractor_stop")}
    if not plan.mapper.uses_verdicts:
        integ["early_stop"] = False  # (the attitude verdicts never stop early: nothing to switch off)
    s["integrate"] = integ
    s["name"] = f"{spec.get('name', 'sweep')}_full"
    return s


def benchmark(spec: Mapping[str, Any] | str | Path = BENCH_SPEC, *, t1: float | None = None, full: bool = True,
              full_rows: int | None = None, out: str | Path | None = None,
              full_from: str | Path | None = None, keep: list | None = None, warm: bool = True) -> dict[str, Any]:
    """Trajectories and trajectory-steps of the refinement against the full lattice of the same resolution.

    ``full_rows``: integrate only that many evenly spaced rows (first axis) of the full lattice and scale
    its trajectory-steps by rows / rows run (stated in the result as ``full_rows_run``). With the full
    lattice run whole, also counts its boundary edges (adjacent lattice points of different classes) that
    the refinement did not find, and checks that the labels at the shared points agree. ``out``: keep the
    full lattice's dataset there; ``full_from``: compare with such a dataset instead of integrating the full
    lattice again (same lattice and fingerprint required; its recorded steps and wall time are reported).
    ``keep``: a list the refinement's dataset is appended to. ``warm``: run the refinement, and one row of the
    full lattice, once untimed before timing them (the C kernels and the host-side JAX are then compiled for
    both, as in a user's second run; otherwise the compile of the full lattice's few rows would be scaled
    up with them).
    """
    from stabjax.run.sweep import run_plan

    if isinstance(spec, (str, Path)):
        spec = load_spec(spec)
    spec = dict(spec)
    if t1 is not None:
        spec["integrate"] = {**spec.get("integrate", {}), "t1": float(t1)}
    plan = make_plan(spec)
    cfg = refine_config(plan)
    if warm:
        refine_plan(plan)
    t = time.perf_counter()
    ds = refine_plan(plan)
    wall_ref = time.perf_counter() - t
    if keep is not None:
        keep.append(ds)
    res: dict[str, Any] = {
        "system": plan.system.name, "axes": [ax.name for ax in plan.grid],
        "coarse": [ax.size for ax in plan.grid], "levels": list(cfg.levels), "tol": list(cfg.tol),
        "lattice": [int(x) for x in np.atleast_1d(ds.attrs["lattice_shape"])], "t1": plan.icfg.t1,
        "pair": list(cfg.pair) if cfg.pair else None,
        "refine_points": int(ds.attrs["n_points"]), "refine_trajectories": int(ds.attrs["n_trajectories"]),
        "refine_steps": int(ds.attrs["total_steps"]), "refine_wall_s": wall_ref, "refine_rounds": int(ds.attrs["rounds"]),
        "segments": int(ds.attrs["n_segments"]), "unbracketed": int(ds.attrs["n_unbracketed"]),
        "full_trajectories": int(ds.attrs["full_grid_trajectories"]),
        "theory_distance": json.loads(ds.attrs["theory_distance_json"]),
    }
    if full:
        fspec = full_lattice_spec(spec, plan=plan)
        rows = len(fspec["grid"][plan.grid[0].key])
        if full_rows is not None and full_rows < rows:
            pick = np.unique(np.linspace(0, rows - 1, full_rows).round().astype(int))
            fspec["grid"][plan.grid[0].key] = [fspec["grid"][plan.grid[0].key][i] for i in pick]
        else:
            pick = np.arange(rows)
        fplan = make_plan(fspec)
        if full_from is not None:
            from stabjax.run.sweep import open_result

            fds = open_result(full_from)
            # the same computation up to the last bits of the lattice (coarse grids of 9 and 17 values halved
            # 5 and 4 times give the same lattice up to rounding)
            strip = lambda d: {k: v for k, v in d.items() if k not in ("grid", "name", "description")}
            same = strip(json.loads(fds.attrs.get("spec_json", "{}"))) == strip(json.loads(json.dumps(fplan.spec)))
            for ax in fplan.grid:
                c = fds[ax.name].values if ax.name in fds.coords else np.zeros(0)
                same &= c.shape == ax.values.shape and np.allclose(c, ax.values, rtol=1e-12, atol=0)
            if not same:
                raise ValidationError("full_from", f"{full_from} is not the full lattice of this spec")
            wall_full = float(fds.attrs["wall_time_s"])
        else:
            if warm:  # one row, untimed: the compiles
                wspec = json.loads(json.dumps(fspec))
                wspec["grid"][plan.grid[0].key] = wspec["grid"][plan.grid[0].key][:1]
                run_plan(make_plan(wspec))
            t = time.perf_counter()
            fds = run_plan(fplan, out)
            wall_full = time.perf_counter() - t
        steps_run = int(fds.attrs["total_steps"])
        res.update(full_rows_run=int(len(pick)), full_rows=int(rows), full_steps_run=steps_run,
                   full_steps=int(round(steps_run * rows / len(pick))), full_wall_s=wall_full,
                   full_wall_s_scaled=wall_full * rows / len(pick))
        if len(pick) == rows:
            res.update(_compare_full(plan, cfg, ds, fds))
    res["ratio_trajectories"] = res["full_trajectories"] / max(res["refine_trajectories"], 1)
    if "full_steps" in res:
        res["ratio_steps"] = res["full_steps"] / max(res["refine_steps"], 1)
    return res


def _compare_full(plan: Plan, cfg: RefineConfig, ds: xr.Dataset, fds: xr.Dataset) -> dict[str, Any]:
    """Labels at the points both evaluated, and the full lattice's boundary edges the refinement missed."""
    names = [ax.name for ax in plan.grid]
    v = np.asarray(fds[cfg.label].values)
    if v.ndim > len(names) + (1 if plan.n_sample else 0):  # a horizon dimension: take the refined one
        hs = horizon_times(plan)
        v = v[..., int(np.argmin(np.abs(hs - cfg.horizon)))] if hs is not None else v[..., -1]
    if plan.n_sample:
        k = len(cfg.names)
        v = np.stack([(v == c).sum(-1) for c in range(k)], -1).argmax(-1)
    full_lab = v.astype(np.int64)
    fine = [fds[n].values for n in names]
    near = lambda a, x: np.abs(np.asarray(x)[:, None] - fine[a][None, :]).argmin(axis=1)  # lattice index
    idx = tuple(near(a, ds[f"point_{n}"].values) for a, n in enumerate(names))
    agree = int((full_lab[idx] == ds["point_label"].values).sum())
    lo = np.stack([near(a, ds[f"{n}_lo"].values) for a, n in enumerate(names)], axis=1)
    hi = np.stack([near(a, ds[f"{n}_hi"].values) for a, n in enumerate(names)], axis=1)
    found = {(int(a), *np.minimum(p, q).tolist()) for a, p, q in zip(ds["segment_axis"].values, lo, hi)}
    c = classes(cfg)[full_lab]
    edges = missed = 0
    for a in range(len(names)):
        sl0 = [slice(None)] * len(names)
        sl1 = [slice(None)] * len(names)
        sl0[a], sl1[a] = slice(None, -1), slice(1, None)
        c0, c1 = c[tuple(sl0)], c[tuple(sl1)]
        diff = (c0 >= 0) & (c1 >= 0) & (c0 != c1)
        for pos in zip(*np.nonzero(diff)):
            edges += 1
            missed += (a, *map(int, pos)) not in found
    return {"labels_agree": agree, "labels_compared": int(len(idx[0])), "full_boundary_edges": edges,
            "missed_edges": missed}


def format_benchmark(r: Mapping[str, Any]) -> str:
    lat = " x ".join(map(str, r["lattice"]))
    rows = [("", "trajectories", "trajectory-steps", "wall [s]"),
            (f"refinement (coarse {' x '.join(map(str, r['coarse']))}, {r['refine_rounds']} rounds)",
             f"{r['refine_trajectories']:,}", f"{r['refine_steps']:,}", f"{r['refine_wall_s']:.1f}")]
    if "full_steps" in r:
        note = "" if r["full_rows_run"] == r["full_rows"] else f" ({r['full_rows_run']} of {r['full_rows']} rows run, scaled)"
        rows.append((f"full lattice {lat}{note}", f"{r['full_trajectories']:,}", f"{r['full_steps']:,}",
                     f"{r['full_wall_s_scaled']:.1f}"))
        rows.append(("full / refinement", f"{r['ratio_trajectories']:.1f}x", f"{r['ratio_steps']:.1f}x",
                     f"{r['full_wall_s_scaled'] / max(r['refine_wall_s'], 1e-9):.1f}x"))
    else:
        rows.append((f"full lattice {lat}", f"{r['full_trajectories']:,}", "(not run)", ""))
    w = [max(len(x[i]) for x in rows) for i in range(4)]
    lines = [f"{r['system']} {', '.join(r['axes'])}, t1 = {r['t1']:g}, bracket tolerance "
             f"{', '.join(f'{a} {t:.4g}' for a, t in zip(r['axes'], r['tol']))}"
             + (f", pair {r['pair']}" if r["pair"] else "")]
    lines += ["  ".join(x[i].ljust(w[i]) if i == 0 else x[i].rjust(w[i]) for i in range(4)) for x in rows]
    lines.append(f"{r['segments']} boundary segments, {r['unbracketed']} wider than the tolerance")
    if "full_boundary_edges" in r:
        lines.append(f"full lattice: {r['full_boundary_edges']} boundary edges, {r['missed_edges']} not found by the "
                     f"refinement; labels agree at {r['labels_agree']} of {r['labels_compared']} shared points")
    for a, s in r["theory_distance"].items():
        lines.append(f"distance to the theorem's boundary along {a}: median {s['median']:+.4g} "
                     f"(range {s['min']:+.4g} .. {s['max']:+.4g}; > 0: theorem conservative)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import argparse

    from stabjax.config import setup_jax

    setup_jax()
    ap = argparse.ArgumentParser(prog="python -m benchmarks.refine_bench", description=__doc__.split("\n")[0])
    ap.add_argument("--bench", action="store_true", help=argparse.SUPPRESS)  # accepted: the older spelling
    ap.add_argument("--spec", default=str(BENCH_SPEC), help="spec with a [refine] section (default: %(default)s)")
    ap.add_argument("--t1", type=float, default=None)
    ap.add_argument("--no-full", action="store_true", help="skip the full lattice")
    ap.add_argument("--full-rows", type=int, default=None, help="run only this many rows of the full lattice, scaled")
    ap.add_argument("--full-out", default=None, help="keep the full lattice's dataset (netCDF) here")
    ap.add_argument("--full-from", default=None, help="compare with a full lattice dataset written by --full-out")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--cold", action="store_true", help="time the first runs (compiles included)")
    a = ap.parse_args(argv)
    r = benchmark(a.spec, t1=a.t1, full=not a.no_full, full_rows=a.full_rows, out=a.full_out, full_from=a.full_from,
                  warm=not a.cold)
    print(format_benchmark(r))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
