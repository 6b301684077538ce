"""GPU sizing study for the fused engine: wall time and traj-steps/s against batch size N and lanes.

    python benchmarks/gpu_lanes.py [--t1 1e4] [--runs N:L,N:L,...] [--diffrax N,N,...]

Same model and tolerances as ``stabjax.bench`` (the monoaxial paper example over alpha); each
(N, lanes) pair is compiled ahead of time (compile reported apart) and run once; the plain
``jit(vmap(diffrax))`` baseline runs on the sizes given with ``--diffrax`` in the same process.
Written for the lent GPU machine (see benchmarks/NOTES.md, G-entries); it runs on CPU too.
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from stabjax import bench, fast
from stabjax.engine import IntegrateConfig
from stabjax.registry import get_system


def fused(n: int, lanes: int, t1: float) -> dict:
    s = get_system(bench.SYSTEM)
    p = {k: np.broadcast_to(v, (n, *np.shape(v))).copy() for k, v in bench.paper_constants().items()}
    p["alpha"] = bench.alphas(n)
    icfg = IntegrateConfig(t1=t1, rtol=bench.RTOL, atol=bench.ATOL)
    t = time.perf_counter()
    exe, args, order, n_ = fast.prepare_call(s, icfg, s.verdict, p, lanes=lanes)
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    out = fast.unpack(exe(*args), order, n_)
    wall = time.perf_counter() - t
    steps = int(out["n_steps"].sum())
    txt = exe.as_text() if hasattr(exe, "as_text") else ""
    return {"engine": "fused", "n": n, "lanes": lanes, "compile_s": compile_s, "wall_s": wall, "accepted_steps": steps,
            "max_steps_one_traj": int((out["n_steps"] + out["n_rejected"]).max()),
            "traj_steps_per_s": steps / wall, "hlo_fusions": txt.count(" fusion("),
            "verdicts": np.bincount(out["verdict"].astype(int), minlength=5).tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=1e4)
    ap.add_argument("--runs", default="65536:65536,262144:262144,1048576:1048576,1048576:262144")
    ap.add_argument("--diffrax", default="262144,1048576")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    print("devices", jax.devices(), flush=True)
    rows = []
    for item in a.runs.split(","):
        n, lanes = (int(x) for x in item.split(":"))
        rows.append(fused(n, lanes, a.t1))
        print(json.dumps(rows[-1]), flush=True)
    for n in (int(x) for x in a.diffrax.split(",") if x):
        d = bench.run_diffrax(n, a.t1)
        rows.append({"engine": "diffrax_vmap", "n": n, **{k: v for k, v in d.items() if not k.startswith("_")}})
        print(json.dumps(rows[-1]), flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"devices": [str(d) for d in jax.devices()], "t1": a.t1, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
