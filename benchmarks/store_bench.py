"""Where a sweep's chunk store spends its time: pyBasin's pendulum case through ``run_plan`` with an output file.

``python -m benchmarks.store_bench [--n 10000] [--t1 1000] [--repeat 3] [--json FILE]``. The case of
:mod:`benchmarks.peer_bench` with the example's rules and default stops (N = 10^4 uniform starts, t1 = 1000,
rtol 1e-8, atol 1e-6, 4000 checkpoints), written to a netCDF file through the chunk store, as
``stabjax sweep`` does. Each phase of the store is timed (wall and CPU seconds of this process):

* ``open``: the store directory, lock and manifest (``ChunkStore.__init__``);
* ``create``: the zarr layout at the first chunk (``ChunkStore._create``); ``write``: the chunks' blocks,
  checksums and manifest entries (``ChunkStore.write``, without ``create``);
* ``finish``: basin statistics and the checksums of the derived arrays; ``read back``: the store read for the
  netCDF copy (``open_store`` and ``load``); ``netcdf``: the file written; ``discard``: the store removed.

The libraries are imported before the clock starts (xarray imports dask.array at its first Dataset and
``distributed`` at its first ``to_netcdf``, with or without a store: import time is not the store's), and a
first run at N = 64 compiles the kernel. Printed: the median over ``--repeat`` runs of each phase, and the
integration (``solve``) beside them.
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

PHASES = ("open", "create", "write", "finish", "read back", "netcdf", "discard")


def _timers():
    """Wrap the store's phases with wall/CPU timers; returns the dict they add to."""
    import xarray as xr

    from stabjax.run import store as S
    from stabjax.run import sweep as W

    T: dict[str, list[float]] = {}

    def timed(name, fn):
        def wrap(*a, **k):
            w, c = time.perf_counter(), time.process_time()
            try:
                return fn(*a, **k)
            finally:
                d = T.setdefault(name, [0.0, 0.0])
                d[0] += time.perf_counter() - w
                d[1] += time.process_time() - c
        return wrap

    S.ChunkStore.__init__ = timed("open", S.ChunkStore.__init__)
    S.ChunkStore._create = timed("create", S.ChunkStore._create)
    S.ChunkStore.write = timed("write+create", S.ChunkStore.write)
    S.ChunkStore.finish = timed("finish", S.ChunkStore.finish)
    S.ChunkStore.discard = timed("discard", S.ChunkStore.discard)
    S.open_store = timed("read back", S.open_store)
    xr.Dataset.load = timed("read back", xr.Dataset.load)
    W.write = timed("netcdf", W.write)
    W.solve_chunk = timed("solve", W.solve_chunk)
    return T


def run(n: int, t1: float, repeat: int) -> dict:
    import dask.array  # noqa: F401 - imported first: see the module docstring
    import distributed  # noqa: F401
    import netCDF4  # noqa: F401
    import xarray  # noqa: F401
    import zarr  # noqa: F401

    from stabjax.plan.spec import make_plan
    from stabjax.run import sweep as W

    from . import peer_bench

    T = _timers()
    spec = peer_bench.spec(n, t1)
    spec["system"] = str(Path(__file__).resolve().parents[1] / "stabjax" / "examples" / "pendulum" / "model.py") \
        + ":Pendulum"
    spec["integrate"].pop("early_stop")  # the stops as a user gets them (peer_bench turns them off)
    runs = []
    with tempfile.TemporaryDirectory() as d:
        W.run_plan(make_plan({**spec, "sample": {**spec["sample"], "n": 64}}), Path(d) / "compile.nc")  # compiles
        for r in range(repeat):
            T.clear()
            w, c = time.perf_counter(), time.process_time()
            W.run_plan(make_plan(spec), Path(d) / f"r{r}.nc")
            total = [time.perf_counter() - w, time.process_time() - c]
            rec = {k: list(v) for k, v in T.items()}
            rec["write"] = [a - b for a, b in zip(rec.pop("write+create"), rec.get("create", [0.0, 0.0]))]
            rec["store"] = [sum(rec.get(k, [0.0, 0.0])[i] for k in PHASES) for i in (0, 1)]
            rec["run_plan"] = total
            runs.append(rec)
    keys = [*PHASES, "store", "solve", "run_plan"]
    return {"n": n, "t1": t1, "repeat": repeat,
            "median": {k: {"wall_s": round(statistics.median(r.get(k, [0, 0])[0] for r in runs), 3),
                           "cpu_s": round(statistics.median(r.get(k, [0, 0])[1] for r in runs), 3)} for k in keys},
            "runs": runs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.store_bench", description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--t1", type=float, default=1000.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from stabjax import setup_jax

    setup_jax()
    rec = run(a.n, a.t1, a.repeat)
    print(f"{'phase':<10} {'wall s':>8} {'CPU s':>8}   (median of {a.repeat}, N = {a.n}, t1 = {a.t1:g})")
    for k, v in rec["median"].items():
        print(f"{k:<10} {v['wall_s']:>8.3f} {v['cpu_s']:>8.3f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rec, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
