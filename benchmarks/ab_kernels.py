"""Native kernel of a git revision against the working tree's, in one process, interleaved pairs.

The machine's speed drifts by tens of percent within minutes (benchmarks/NOTES.md), so two kernels
are only compared run against run: old, new, new, old, ... on the same trajectories (the benchmark's
monoaxial alpha sweep, T = 1e4), integration only (``native.run_raw``). Example (NOTES.md N21):

    python benchmarks/ab_kernels.py --rev 61d16a3 --n 65536 --pairs 4
"""
from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stabjax import bench, native


def native_at(rev: str):
    """``stabjax/native.py`` as of ``rev``, imported as a sibling module of the installed package."""
    root = Path(__file__).resolve().parent.parent
    src = subprocess.run(["git", "show", f"{rev}:stabjax/native.py"], cwd=root, capture_output=True, text=True,
                         check=True).stdout
    path = Path(tempfile.mkdtemp()) / "native_rev.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("stabjax._native_rev", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", required=True, help="git revision of the old kernel")
    ap.add_argument("--n", type=int, default=65536)
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    runs = {name: (mod, *bench.native_kernel(a.n, mod=mod))
            for name, mod in (("old", native_at(a.rev)), ("new", native))}
    walls: dict[str, list[float]] = {"old": [], "new": []}
    for rep in range(a.pairs):
        for name in ("old", "new") if rep % 2 == 0 else ("new", "old"):
            mod, kern, ain, y0 = runs[name]
            t = time.perf_counter()
            r = mod.run_raw(kern, ain, y0, threads=a.threads)
            w = time.perf_counter() - t
            walls[name].append(w)
            acc = int(r["nacc"].sum())
            print(f"{name} pair {rep}: wall {w:.2f} s, {acc} accepted steps, {acc / w:.3g} traj-steps/s", flush=True)
    ratios = [b / o for o, b in zip(walls["old"], walls["new"])]
    print("new/old wall per pair:", ", ".join(f"{x:.3f}" for x in ratios), f"; median {np.median(ratios):.3f}")


if __name__ == "__main__":
    main()
