"""How much of the benchmark's stabjax row is the native kernel, and how much the host side around it
(parameters, host inputs, dataset assembly): ``bench.run_stabjax`` (the engine as a user calls it)
twice, ``native.run_raw`` on the same sweep between them, and the second run under cProfile, whose
``run_raw`` entry is the time the kernel's threads took (NOTES.md, session 7):

    python benchmarks/host_share.py --n 65536
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time

from stabjax import bench, native


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=65536)
    a = ap.parse_args()
    r = bench.run_stabjax(a.n, 1e4)
    print(f"run_stabjax: {r['wall_s']:.2f} s, {r['traj_steps_per_s']:.3g} traj-steps/s", flush=True)
    kern, ain, y0 = bench.native_kernel(a.n)
    t = time.perf_counter()
    rr = native.run_raw(kern, ain, y0, threads=native.default_threads())
    w = time.perf_counter() - t
    print(f"run_raw:     {w:.2f} s, {rr['nacc'].sum() / w:.3g} traj-steps/s", flush=True)
    pr = cProfile.Profile()
    pr.enable()
    r = bench.run_stabjax(a.n, 1e4)
    pr.disable()
    raw = [v[3] for k, v in pstats.Stats(pr).stats.items() if k[2] == "run_raw"]
    print(f"run_stabjax: {r['wall_s']:.2f} s, {r['traj_steps_per_s']:.3g} traj-steps/s; of it run_raw (the "
          f"kernel's threads) {sum(raw):.2f} s, the host side {r['wall_s'] - sum(raw):.2f} s")


if __name__ == "__main__":
    main()
