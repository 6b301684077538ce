"""Benchmark on a peer's published case: pyBasin's damped driven pendulum, per core.

``python -m benchmarks.peer_bench [--n 10000] [--t1 1000] [--diffrax-n 500] [--json FILE]`` (or ``stabjax bench
--suite peers``); ``--stops [--reps 3]``: the stops on against every stop off (:func:`run_stops`). pyBasin's case study: theta' = omega, omega' = -alpha omega + T - K sin(theta), alpha = 0.1,
T = 0.5, K = 1; N = 10^4 uniform starts in theta in [-pi + asin(T/K), pi + asin(T/K)], omega in [-10, 10];
t in [0, 1000]; rtol 1e-8, atol 1e-6 (the same system and region as ``stabjax/examples/pendulum``). Every
trajectory runs to t1 (no early stop of any kind: the figure is integration throughput, as the peers report
it), with the example's 4000 checkpoints (``--checkpoints``: the classifier's share of the time). Contenders, in this process, on the same starts:

1. ``stabjax``: :func:`stabjax.run.sweep.run_plan` as a user calls it (engine "auto": native on a CPU with a C
   compiler), one thread per core; the run after a first one that compiles;
2. ``diffrax_vmap``: ``jax.jit(jax.vmap(diffeqsolve))`` with Tsit5 and the same controller on the first
   ``--diffrax-n`` starts (a subset: it is ~10x slower), reported per trajectory-step.

Printed: wall, accepted steps, trajectory-steps per second, per core (with the core count this process may
use), and the ratio to the diffrax baseline; the peers' published figures are quoted in docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

ALPHA, T, K = 0.1, 0.5, 1.0
RTOL, ATOL = 1e-8, 1e-6


def region():
    lo = -math.pi + math.asin(T / K)
    return (lo, lo + 2 * math.pi), (-10.0, 10.0)


def spec(n: int, t1: float, checkpoints: int = 4000, stops: bool = False) -> dict:
    (a, b), (c, d) = region()
    return {
        "system": "",  # set in _plan: the example model file
        "name": "peer_pendulum",
        "sample": {"n": int(n), "seed": 5, "theta0": {"dist": "uniform", "low": a, "high": b},
                   "omega0": {"dist": "uniform", "low": c, "high": d}},
        "integrate": {"t1": float(t1), "rtol": RTOL, "atol": ATOL, "n_checkpoints": checkpoints, "early_stop": stops,
                      **({"attractor_stop": True} if stops else {})},
    }


def _plan(n: int, t1: float, checkpoints: int = 4000, stops: bool = False):
    from pathlib import Path

    from stabjax.plan.spec import make_plan

    s = spec(n, t1, checkpoints, stops)
    s["system"] = str(Path(__file__).resolve().parents[1] / "stabjax" / "examples" / "pendulum" / "model.py") + ":Pendulum"
    return make_plan(s)


def cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def run_stabjax(n: int, t1: float, checkpoints: int = 4000) -> dict:
    from stabjax.run.sweep import run_plan

    plan = _plan(n, t1, checkpoints)
    run_plan(_plan(64, t1, checkpoints))  # compile
    t = time.perf_counter()
    ds = run_plan(plan)
    wall = time.perf_counter() - t
    steps = int(ds["n_steps"].sum())
    return {"engine": ds.attrs.get("engine"), "n": n, "wall_s": round(wall, 3), "steps": steps,
            "steps_per_trajectory": round(steps / n, 1), "traj_steps_per_s": steps / wall,
            "traj_steps_per_s_per_core": steps / wall / cores(),
            "outcomes": {str(k): int(v) for k, v in zip(*np.unique(ds["outcome"].values, return_counts=True))}}


def run_stops(n: int, t1: float, reps: int = 3) -> dict:
    """The same case with the stops on (at a stable fixed point, and near an attractor learnt from the first
    chunk) against every stop off, as a user runs it (:func:`stabjax.run.sweep.run_plan`): each once to
    compile, then ``reps`` times each, interleaved (off, on, off, on, ...); the best wall time of each, the
    process CPU time, the trajectory-steps, and the number of starts whose outcome differs (must be 0)."""
    from stabjax.run.sweep import run_plan

    plans = {"off": _plan(n, t1), "on": _plan(n, t1, stops=True)}
    names = {}
    for key, plan in plans.items():
        ds = run_plan(plan)  # compile (the C kernels are cached on disk for later processes)
        names[key] = np.asarray(str(ds["outcome"].attrs["flag_meanings"]).split())[ds["outcome"].values.ravel()]
    rec = {k: {"wall_s": [], "cpu_s": []} for k in plans}
    for _ in range(reps):
        for key, plan in plans.items():
            t, c = time.perf_counter(), time.process_time()
            ds = run_plan(plan)
            rec[key]["wall_s"].append(round(time.perf_counter() - t, 3))
            rec[key]["cpu_s"].append(round(time.process_time() - c, 3))
            rec[key]["steps"] = int(ds["n_steps"].sum())
            if key == "on":
                reasons = ds["stop_reason"].values.ravel()
                rec[key]["stopped"] = {r: int((reasons == i).sum()) for i, r in enumerate(("none", "escaped",
                                                                                          "fixed_point", "failed",
                                                                                          "attractor"))}
            got = np.asarray(str(ds["outcome"].attrs["flag_meanings"]).split())[ds["outcome"].values.ravel()]
            assert (got == names[key]).all(), "a rerun changed an outcome"
    for r in rec.values():
        r["best_wall_s"], r["best_cpu_s"] = min(r["wall_s"]), min(r["cpu_s"])
    return {"n": n, "reps": reps, **rec, "outcome_changes": int((names["on"] != names["off"]).sum()),
            "outcomes": {str(k): int(v) for k, v in zip(*np.unique(names["off"], return_counts=True))},
            "steps_ratio": rec["off"]["steps"] / rec["on"]["steps"],
            "wall_ratio": rec["off"]["best_wall_s"] / rec["on"]["best_wall_s"],
            "cpu_ratio": rec["off"]["best_cpu_s"] / rec["on"]["best_cpu_s"]}


def run_diffrax(n: int, t1: float) -> dict:
    import diffrax
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    plan = _plan(n, t1)
    p = plan.params_for(0, n)
    y0 = jnp.stack([jnp.asarray(p["theta0"]), jnp.asarray(p["omega0"])], axis=1)

    def rhs(t, y, _):
        return jnp.stack([y[1], -ALPHA * y[1] + T - K * jnp.sin(y[0])])

    def one(y):
        sol = diffrax.diffeqsolve(diffrax.ODETerm(rhs), diffrax.Tsit5(), 0.0, t1, None, y,
                                  stepsize_controller=diffrax.PIDController(rtol=RTOL, atol=ATOL),
                                  saveat=diffrax.SaveAt(t1=True), max_steps=2_000_000)
        return sol.ys[-1], sol.stats["num_accepted_steps"]

    f = jax.jit(jax.vmap(one))
    jax.block_until_ready(f(y0))  # compile
    t = time.perf_counter()
    ys, acc = jax.block_until_ready(f(y0))
    wall = time.perf_counter() - t
    steps = int(np.asarray(acc).sum())
    return {"n": n, "wall_s": round(wall, 3), "steps": steps, "traj_steps_per_s": steps / wall,
            "traj_steps_per_s_per_core": steps / wall / cores()}


def main(argv: list[str] | None = None) -> int:
    from stabjax.config import setup_jax

    ap = argparse.ArgumentParser(prog="python -m benchmarks.peer_bench", description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--t1", type=float, default=1000.0)
    ap.add_argument("--checkpoints", type=int, default=4000)
    ap.add_argument("--diffrax-n", type=int, default=500, help="starts for the diffrax baseline (0: skip)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--stops", action="store_true", help="the stops on against every stop off (issue 32, target 1)")
    ap.add_argument("--reps", type=int, default=3, help="with --stops: timed runs of each, interleaved")
    a = ap.parse_args(argv)
    setup_jax()
    from benchmarks.bench import machine

    if a.stops:
        load = os.getloadavg()
        r = run_stops(a.n, a.t1, a.reps)
        r.update(case="pyBasin damped pendulum, stops on vs off", machine=machine(), cores=cores(),
                 load_before=load, load_after=os.getloadavg())
        print(f"pyBasin pendulum, N = {a.n}: every stop off {r['off']['best_wall_s']} s wall "
              f"({r['off']['steps']:,} steps), stops on {r['on']['best_wall_s']} s ({r['on']['steps']:,} steps; "
              f"stopped {r['on']['stopped']}): {r['wall_ratio']:.2f}x wall, {r['cpu_ratio']:.2f}x CPU, "
              f"{r['steps_ratio']:.2f}x steps; outcomes changed: {r['outcome_changes']}; "
              f"load {load[0]:.1f} -> {r['load_after'][0]:.1f}")
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(r, fh, indent=1)
        return 0

    rec = {"case": "pyBasin damped pendulum", "machine": machine(), "cores": cores(), "t1": a.t1,
           "rtol": RTOL, "atol": ATOL, "checkpoints": a.checkpoints, "stabjax": run_stabjax(a.n, a.t1, a.checkpoints)}
    if a.diffrax_n:
        rec["diffrax_vmap"] = run_diffrax(a.diffrax_n, a.t1)
        rec["ratio_vs_diffrax"] = rec["stabjax"]["traj_steps_per_s"] / rec["diffrax_vmap"]["traj_steps_per_s"]
    s = rec["stabjax"]
    print(f"pyBasin pendulum: N = {s['n']}, t1 = {a.t1:g}, rtol {RTOL:g}, atol {ATOL:g}, {rec['cores']} cores "
          f"({rec['machine'].get('model_name', '?')})")
    print(f"  stabjax ({s['engine']}): {s['wall_s']} s, {s['steps_per_trajectory']} steps/trajectory, "
          f"{s['traj_steps_per_s']:.3g} traj-steps/s = {s['traj_steps_per_s_per_core']:.3g} per core")
    if a.diffrax_n:
        d = rec["diffrax_vmap"]
        print(f"  jit(vmap(diffrax)) on {d['n']} starts: {d['traj_steps_per_s']:.3g} traj-steps/s "
              f"-> stabjax / diffrax = {rec['ratio_vs_diffrax']:.1f}x")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rec, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
