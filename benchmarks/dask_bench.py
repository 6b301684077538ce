"""Dask benchmarks: the same sweep in this process and on 1, 2, ... local workers, the per-chunk
round trip, and a 10^7-trajectory sweep to a netCDF file with the client's peak memory.

    python -m benchmarks.dask_bench workers      (or: stabjax bench --suite dask, from a checkout)
    python -m benchmarks.dask_bench big --n 10000000 [--workers 2]

Research code beside the tests, not in the installed package (issue 25).
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from stabjax.run.distributed import DaskExecutor, cores


BENCH_SPEC = {
    "system": "monoaxial", "name": "bench_dask",
    "params": {"mu": 1.5, "sigma": 1.3333333333333333},
    "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": 64}},
    "sample": {"n": 256, "seed": 0, "s0": {"dist": "cap", "center": "r", "half_angle": 0.5}},
    "integrate": {"t1": 1000.0, "n_checkpoints": 64},
}


def benchmark(workers: Iterable[int] = (1, 2), *, spec: Mapping[str, Any] | None = None, batch_size: int = 2048,
              repeats: int = 2, tiny_chunks: int = 20) -> dict[str, Any]:
    """Wall time (best of ``repeats``, warm) of the same sweep in this process and on 1, 2, ... local
    Dask workers (each cluster runs the sweep once first: worker imports and compilation), whether
    the datasets are identical, and the per-chunk overhead: the round trip of a one-trajectory chunk
    through the scheduler and back against the same chunk solved in this process (medians)."""
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_plan, solve_chunk

    spec = dict(spec or BENCH_SPEC)
    plan = make_plan(spec)
    out: dict[str, Any] = {"n_trajectories": plan.size, "batch_size": batch_size, "cores": cores(), "wall_s": {},
                           "load_avg_before": os.getloadavg()[0]}

    def best(run):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            ds = run()
            times.append(time.perf_counter() - t0)
        return min(times), ds

    run_plan(plan, batch_size=batch_size)  # compile here first
    out["wall_s"]["local"], ref = best(lambda: run_plan(plan, batch_size=batch_size))
    tiny = make_plan({**spec, "grid": {"alpha": [0.5]}, "sample": {}})
    for n in workers:
        with DaskExecutor(workers=n) as ex:
            ex.wait_for_workers(n)
            out.setdefault("threads_per_worker", {})[n] = ex.threads
            run_plan(plan, batch_size=batch_size, executor=ex)  # warm-up: worker imports + compile
            out["wall_s"][f"dask_{n}"], ds = best(lambda: run_plan(plan, batch_size=batch_size, executor=ex))
            out[f"identical_dask_{n}"] = all(np.array_equal(ds[k].values, ref[k].values, equal_nan=True)
                                             for k in ref.data_vars)
            if n == min(workers):
                list(ex.map_chunks(tiny, 1, [0]))
                rt = []
                for _ in range(tiny_chunks):
                    t0 = time.perf_counter()
                    list(ex.map_chunks(tiny, 1, [0]))
                    rt.append(time.perf_counter() - t0)
                solve_chunk(tiny, 1, 0)
                loc = []
                for _ in range(tiny_chunks):
                    t0 = time.perf_counter()
                    solve_chunk(tiny, 1, 0)
                    loc.append(time.perf_counter() - t0)
                out["tiny_chunk_roundtrip_s"] = float(np.median(rt))
                out["tiny_chunk_local_s"] = float(np.median(loc))
    out["load_avg_after"] = os.getloadavg()[0]
    return out


def benchmark_big(n_traj: int = 10_000_000, *, out: str | Path = "/tmp/stabjax_big.nc", workers: int | None = None,
                  batch_size: int | None = None, t1: float = 10.0) -> dict[str, Any]:
    """A sweep of ``n_traj`` trajectories (monoaxial, short horizon, 8 checkpoints) run to the
    netCDF file, with the client's peak resident memory (``ru_maxrss``)."""
    import resource

    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_plan

    n_alpha = 1000
    spec = {"system": "monoaxial", "name": "big", "params": {"mu": 1.5, "sigma": 1.3333333333333333},
            "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": n_alpha}},
            "sample": {"n": n_traj // n_alpha, "seed": 0, "s0": {"dist": "cap", "center": "r", "half_angle": 0.5}},
            "integrate": {"t1": t1, "n_checkpoints": 8}}
    plan = make_plan(spec)
    t0 = time.perf_counter()
    if workers:
        with DaskExecutor(workers=workers) as ex:
            ds = run_plan(plan, out, batch_size=batch_size, executor=ex, restart=True)
    else:
        ds = run_plan(plan, out, batch_size=batch_size, restart=True)
    wall = time.perf_counter() - t0
    return {"n_trajectories": plan.size, "wall_s": wall, "total_steps": int(ds.attrs["total_steps"]),
            "engine": ds.attrs["engine"], "batch_size": int(ds.attrs["batch_size"]),
            "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
            "file_gib": Path(out).stat().st_size / 2**30}


def main(argv: list[str] | None = None):
    import argparse
    import json

    ap = argparse.ArgumentParser(description="stabjax Dask benchmarks")
    ap.add_argument("what", choices=["workers", "big"])
    ap.add_argument("--n", type=int, default=10_000_000)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--batch-size", type=int, default=None)
    ap.add_argument("--out", default="/tmp/stabjax_big.nc")
    a = ap.parse_args(argv)
    if a.what == "workers":
        r = benchmark()
    else:
        r = benchmark_big(a.n, out=a.out, workers=a.workers, batch_size=a.batch_size)
    print(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
