"""Benchmark of a user model: the Duffing example on stabjax's engine against named baselines.

Two questions, each answered in one process:

1. Does a model from outside the package run at the speed of a built-in one? The built-in
   ``monoaxial`` system is run by its registered name and again as a user reference
   (``"stabjax.systems.monoaxial:Monoaxial"``: a separate instance through the user-model door,
   checked and compiled on its own): the same code on the same engine, so any difference is the
   cost of the door, not of the model. Interleaved rounds, median ratio.
2. How does a user model compare with the baselines a user would otherwise write? The Duffing
   example (``examples/duffing``, five coexisting attractors) by ``run_spec`` (default engine),
   against a plain ``jit(vmap(diffrax.diffeqsolve))`` of the model's own ``rhs`` (Tsit5, same
   tolerances, final state only) and a SciPy ``solve_ivp`` DOP853 loop over a subset with a
   NumPy right-hand side.

Run: ``python -m benchmarks.bench_models [--n 4096] [--t1 1000] [--rounds 3]``.
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

MODEL = Path("examples/duffing/model.py")  # from a clone's root; --model names another copy


def _spec(n: int, t1: float, model: Path = MODEL) -> dict:
    return {"system": f"{model}:Duffing", "name": "bench_duffing",
            "sample": {"n": n, "seed": 2, "x0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                       "v0": {"dist": "uniform", "low": -0.5, "high": 1.0}},
            "integrate": {"t1": t1, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": int(4 * t1)}}


def _timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def door_cost(n: int = 4096, t1: float = 1e3, rounds: int = 3) -> dict:
    """Built-in monoaxial by name vs the same class loaded from its file (interleaved rounds)."""
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_plan

    grid = {"alpha": {"start": 0.3, "stop": 1.0, "num": n}}
    plans = {"builtin": make_plan({"system": "monoaxial", "grid": grid, "integrate": {"t1": t1}}),
             "user ref": make_plan({"system": "stabjax.systems.monoaxial:Monoaxial", "grid": grid,
                                     "integrate": {"t1": t1}})}
    for p in plans.values():
        run_plan(p)  # compile outside the timing
    walls: dict[str, list[float]] = {k: [] for k in plans}
    steps = {}
    for _ in range(rounds):
        for k, p in plans.items():
            w, ds = _timed(lambda p=p: run_plan(p))
            walls[k].append(w)
            steps[k] = int(ds["n_steps"].sum())
    ratios = [u / b for u, b in zip(walls["user ref"], walls["builtin"])]
    return {"n": n, "t1": t1, "rounds": rounds, "wall_s": walls, "accepted_steps": steps,
            "median_ratio_user_over_builtin": statistics.median(ratios), "engine": "default"}


def duffing_rhs_numpy(t, y, delta, k3, a):
    return [y[1], -delta * y[1] - k3 * y[0] ** 3 + a * np.cos(t)]


def baselines(n: int = 4096, t1: float = 1e3, k_scipy: int = 8, model: Path = MODEL) -> dict:
    import diffrax
    import jax
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp

    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_plan

    plan = make_plan(_spec(n, t1, model))
    run_plan(make_plan(_spec(min(n, 256), t1, model)))  # compile (same kernel: the chunk size is not compiled in)
    w_stab, ds = _timed(lambda: run_plan(plan))
    steps = int(ds["n_steps"].sum())
    out = {"n": n, "t1": t1, "stabjax": {"engine": ds.attrs.get("engine", ""), "wall_s": w_stab,
                                          "accepted_steps": steps, "traj_steps_per_s": steps / w_stab,
                                          "basin_fraction": ds["basin_fraction"].values.tolist()}}
    sysm = plan.system
    x0, v0 = plan.sample["x0"], plan.sample["v0"]
    fixed = {k: jnp.asarray(v) for k, v in plan.fixed.items()}

    def one(x, v):
        p = {**fixed, "x0": x, "v0": v}
        sol = diffrax.diffeqsolve(diffrax.ODETerm(sysm.rhs), diffrax.Tsit5(), 0.0, t1, None, sysm.initial_state(p),
                                  args=sysm.prepare(p), saveat=diffrax.SaveAt(t1=True),
                                  stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-8), max_steps=2_000_000)
        return sol.ys[-1], sol.stats["num_accepted_steps"]

    fn = jax.jit(jax.vmap(one))
    X, Vv = jnp.asarray(x0), jnp.asarray(v0)
    w_c, exe = _timed(lambda: fn.lower(X, Vv).compile())
    w_d, (ys, acc) = _timed(lambda: jax.block_until_ready(exe(X, Vv)))
    d_steps = int(np.asarray(acc).sum())
    out["diffrax_vmap"] = {"wall_s": w_d, "compile_s": w_c, "accepted_steps": d_steps,
                           "traj_steps_per_s": d_steps / w_d}
    idx = np.linspace(0, n - 1, k_scipy).round().astype(int)
    walls, sp_steps = [], 0
    for i in idx:
        w, sol = _timed(lambda i=i: solve_ivp(duffing_rhs_numpy, (0.0, t1), [x0[i], v0[i]], method="DOP853",
                                              rtol=1e-8, atol=1e-8, args=(0.08, 1.0, 0.2)))
        walls.append(w)
        sp_steps += sol.t.size - 1
    out["scipy_dop853"] = {"n_measured": int(k_scipy), "wall_s_per_trajectory": float(np.mean(walls)),
                           "traj_steps_per_s": sp_steps / float(np.sum(walls))}
    per_traj = w_stab / n
    out["ratios"] = {"diffrax_vmap_over_stabjax_wall": w_d / w_stab,
                     "scipy_per_trajectory_over_stabjax": float(np.mean(walls)) / per_traj}
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4096)
    ap.add_argument("--t1", type=float, default=1e3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="JSON file for the figures")
    ap.add_argument("--model", type=Path, default=MODEL, help="the Duffing example's model file")
    a = ap.parse_args(argv)
    from stabjax.config import setup_jax

    setup_jax()
    res = {"door": door_cost(a.n, a.t1, a.rounds), "duffing": baselines(a.n, a.t1, model=a.model)}
    d, b = res["door"], res["duffing"]
    print(f"built-in monoaxial by name vs as a user reference module:Class (N = {d['n']}, t1 = {d['t1']:g}, {d['rounds']} rounds): "
          f"median wall ratio user/builtin = {d['median_ratio_user_over_builtin']:.3f}")
    print(f"Duffing example, N = {b['n']}, t1 = {b['t1']:g}:")
    print(f"  stabjax ({b['stabjax']['engine']}): {b['stabjax']['wall_s']:.2f} s, "
          f"{b['stabjax']['traj_steps_per_s']:.3g} traj-steps/s")
    print(f"  jit(vmap(diffeqsolve)): {b['diffrax_vmap']['wall_s']:.2f} s (+{b['diffrax_vmap']['compile_s']:.1f} s compile), "
          f"{b['diffrax_vmap']['traj_steps_per_s']:.3g} traj-steps/s; {b['ratios']['diffrax_vmap_over_stabjax_wall']:.1f}x "
          "stabjax's wall")
    print(f"  SciPy DOP853 loop: {b['scipy_dop853']['wall_s_per_trajectory'] * 1e3:.1f} ms per trajectory; "
          f"{b['ratios']['scipy_per_trajectory_over_stabjax']:.0f}x stabjax's per-trajectory time")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(res, indent=1, default=float))
    return res


if __name__ == "__main__":
    main()
