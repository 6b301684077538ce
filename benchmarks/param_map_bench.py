"""Refinement of a parameter map with a slowly decaying stable side (issue 32, target 2), against the full lattice.

``python -m benchmarks.param_map_bench [--rel-tol 1/256] [--full-rows 16] [--json FILE]``: the (c, k) map of
:mod:`benchmarks.damped_map` (boundary of ``decays`` in closed form: k = c - gamma*), refined from a 17 x 17
coarse grid to ``--rel-tol`` of each axis, against the plain fixed-horizon sweep of the whole final lattice
(every stop off; ``--full-rows``: that many rows of it, scaled), with :func:`benchmarks.refine_bench.benchmark`.
Also checks every bracketed segment of the boundary against the closed form: the line must cross it (each
bracket's two ends on either side of k = c - gamma*, within the O(gamma*) wobble of the amplitude).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

MODEL = Path(__file__).resolve().parent / "damped_map.py"


def spec(rel_tol: str = "1/256") -> dict:
    from benchmarks.damped_map import T1

    return {"system": f"{MODEL}:DampedMap", "name": "damped_map",
            "description": "damped oscillator: decays vs not, damping c - k crossing zero",
            "grid": {"c": {"start": 0.0, "stop": 0.2, "num": 17}, "k": {"start": 0.0, "stop": 0.2, "num": 17}},
            "integrate": {"t1": T1, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 2000},
            "refine": {"rel_tol": rel_tol, "pair": ["decays", "*"]}}


def closed_form_check(ds) -> dict:
    """Segments of the ``decays`` boundary whose bracket does not straddle k = c - gamma* (allowing the 1 %
    wobble of gamma*): 0 expected."""
    from benchmarks.damped_map import gamma_star

    g = gamma_star()
    names = str(ds.attrs["label_names"]).split()
    dec = names.index("decays")
    use = (ds["label_lo"].values == dec) ^ (ds["label_hi"].values == dec)
    s_lo = ds["c_lo"].values - ds["k_lo"].values - g  # > 0: on the decaying side of the line
    s_hi = ds["c_hi"].values - ds["k_hi"].values - g
    slack = 0.02 * g
    ok = (np.minimum(s_lo, s_hi) <= slack) & (np.maximum(s_lo, s_hi) >= -slack)
    return {"gamma_star": g, "segments_checked": int(use.sum()), "segments_off_the_line": int((use & ~ok).sum())}


def main(argv: list[str] | None = None) -> int:
    from stabjax.config import setup_jax

    from benchmarks.refine_bench import benchmark, format_benchmark

    ap = argparse.ArgumentParser(prog="python -m benchmarks.param_map_bench", description=__doc__.split("\n")[0])
    ap.add_argument("--rel-tol", default="1/256")
    ap.add_argument("--full-rows", type=int, default=16)
    ap.add_argument("--no-full", action="store_true")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    setup_jax()
    s = spec(a.rel_tol)
    kept: list = []
    r = benchmark(s, full=not a.no_full, full_rows=a.full_rows, keep=kept)
    r.update(closed_form_check(kept[0]))
    print(format_benchmark(r))
    print(f"closed form k = c - {r['gamma_star']:.6f}: {r['segments_off_the_line']} of {r['segments_checked']} "
          "bracketed segments of the decays boundary off the line")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(r, fh, indent=1, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
