"""What a second thread gives: the measured float64 peak and the native kernel, one thread against two.

The machine's two virtual CPUs are not always two full cores (benchmarks/NOTES.md N24), so each round
measures the peak (``bench.measured_peak``) and then runs the benchmark's native kernel (monoaxial
alpha sweep, T = 1e4, integration only) on one thread and on two, order reversed every other round:

    python benchmarks/scaling.py --n 8192 --rounds 3
"""
from __future__ import annotations

import argparse
import time

from stabjax import bench, native


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=8192)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=0.2, help="length of each peak measurement")
    a = ap.parse_args()
    kern, ain, y0 = bench.native_kernel(a.n)
    for rnd in range(a.rounds):
        mp = bench.measured_peak(threads=2, seconds=a.seconds)
        wall = {}
        for threads in (1, 2) if rnd % 2 == 0 else (2, 1):
            t = time.perf_counter()
            native.run_raw(kern, ain, y0, threads=threads)
            wall[threads] = time.perf_counter() - t
        print(f"round {rnd} ({time.strftime('%H:%M:%S')}): peak {mp['gflops_f64_one_thread']:.0f} / "
              f"{mp['gflops_f64_all_threads']:.0f} GF/s (x{mp['scaling_fma']:.2f}), latency chain "
              f"x{mp['scaling_latency_chain']:.2f}; kernel one thread {wall[1]:.2f} s, two {wall[2]:.2f} s "
              f"(x{wall[1] / wall[2]:.2f})", flush=True)


if __name__ == "__main__":
    main()
