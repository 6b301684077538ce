"""Benchmark of the minimal-fatal-shock search against brute-force sampling of balls of growing radius.

``python -m benchmarks.shock_bench [--out results/shock_bench.json]``, from the checkout root: trajectories and wall
time for the search (:mod:`stabjax.explore.shock`, the defaults: 64 directions x 8 radii, bisection, CMA-ES on a
ladder of 8 radii, polish) to bracket ``delta*`` within 1 %, on two models whose ``delta*`` is known exactly,
against brute force in the same run: ``M`` starts uniform in the ball of radius ``r_k = r_0 1.01^k`` (``r_0`` the
search's first scan radius, ``max_radius / 8``), until a ball holds a fatal start; its estimate is the smallest fatal
start's norm (the same resolution: balls 1 % apart), its trajectories ``M k``. Brute force's ``M`` must grow with
the dimension: the fatal share of the ball of radius 1.01 delta* is ~1e-3 in 2-D and ~3e-7 in 6-D here (the caps
beyond the nearest face of the basin), so in 6-D it is run to a trajectory budget and reported as not reaching 1 %.

The models: ``x' = Q f(Q^T x)``, ``f_i(z) = -a_i z_i + z_i^3``: the basin of the origin is the box ``|z_i| <
sqrt(a_i)`` (rotated by Q), so ``delta* = min_i sqrt(a_i)`` along Q's column of the smallest ``a_i``. 2-D: the research
note's T3 (a = 1, 4; Q a rotation by 30 deg); 6-D: a = (1, 1.2, 1.4, 1.6, 1.8, 2)^2, Q a random rotation (seed 0).
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stabjax.model.outcomes import Outcomes
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import System

GROWTH = 1.01


def _rotation(d: int) -> np.ndarray:
    if d == 2:
        c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
        return np.array([[c, -s], [s, c]])
    q, r = np.linalg.qr(np.random.default_rng(0).standard_normal((d, d)))
    return q * np.sign(np.diag(r))


def _box(d: int, a: tuple[float, ...]):
    Q = _rotation(d)
    A = np.asarray(a, float)

    class Box(System):
        name = f"bench_box{d}"
        title = f"rotated box basin in {d}-D"
        params = ParamSet((Param("y0", (0.0,) * d, "initial state", (d,), kind="initial"),))
        state = (("y", (d,)),)
        observables = ("rr",)
        observable_doc = ("distance from the origin",)
        default_t1 = 20.0
        escape_radius = 10.0
        outcomes = Outcomes(rules={"origin": "final(rr) < 0.5"}, window=0.1)

        def initial_state(self, p):
            return p["y0"]

        def rhs(self, t, y, p):
            z = jnp.asarray(Q.T) @ y
            return jnp.asarray(Q) @ (-jnp.asarray(A) * z + z ** 3)

        def observe(self, t, y, p):
            return jnp.sqrt(jnp.sum(y * y))[None]

    Box.__qualname__ = Box.__name__ = f"Box{d}"
    return Box, float(np.sqrt(A.min()))


Box2, EXACT2 = _box(2, (1.0, 4.0))
Box6, EXACT6 = _box(6, tuple(x * x for x in (1.0, 1.2, 1.4, 1.6, 1.8, 2.0)))
# name: (system, exact delta*, max_radius, brute force's starts per ball, its trajectory budget)
CASES = {"2-D": ("benchmarks.shock_bench:Box2", EXACT2, 2.5, 2_000, None),
         "6-D": ("benchmarks.shock_bench:Box6", EXACT6, 2.5, 1_600, 210_000)}
INTEGRATE = {"t1": 20.0, "n_checkpoints": 200, "rtol": 1e-8, "atol": 1e-10}


def spec_for(system: str, max_radius: float, **shock) -> dict:
    return {"system": system, "name": "shock_bench", "integrate": dict(INTEGRATE),
            "shock": {"components": ["y0"], "max_radius": max_radius, **shock}}


def brute_force(spec: dict, exact: float, per_ball: int, budget: int | None, seed: int = 1) -> dict:
    """Balls of radius r_0 1.01^k, ``per_ball`` uniform starts each, through the search's runner and outcome
    assignment, until one holds a fatal start (or ``budget`` trajectories are spent)."""
    from stabjax.explore.shock import FATAL, Labeller, classify, round_plan
    from stabjax.explore.shock_config import Norm, base_points, shock_config
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import run_points

    plan = make_plan(spec)
    cfg = shock_config(plan)
    rplan = round_plan(plan, cfg)
    base, _ = base_points(plan)
    label = Labeller(rplan, base)
    norm = Norm(plan, cfg, base)
    g0 = np.zeros(1, np.int64)
    attractor = label(g0, {k: np.asarray(v) for k, v in base.items()},
                      run_points(rplan, np.zeros((1, cfg.dim)))[0])[0]
    rng = np.random.default_rng(seed)
    r, used, balls, t0 = cfg.max_radius / cfg.radii, 1, 0, time.perf_counter()
    while budget is None or used + per_ball <= budget:
        u = rng.standard_normal((per_ball, cfg.dim))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        x = u * (r * rng.uniform(size=(per_ball, 1)) ** (1 / cfg.dim))
        g = np.zeros(per_ball, np.int64)
        res, _ = run_points(rplan, x)
        codes = label(g, norm.params(g, x), res)
        fatal = classify(cfg, label.names, codes, np.full(per_ball, attractor)) == FATAL
        used += per_ball
        balls += 1
        if fatal.any():
            est = float(np.linalg.norm(x[fatal], axis=1).min())
            return {"trajectories": used, "wall_s": time.perf_counter() - t0, "balls": balls, "radius": r,
                    "estimate": est, "rel_error": est / exact - 1, "within_1pct": est <= exact * 1.01}
        r *= GROWTH
    return {"trajectories": used, "wall_s": time.perf_counter() - t0, "balls": balls, "radius": r / GROWTH,
            "estimate": None, "rel_error": None, "within_1pct": False,
            "note": f"no fatal start in any ball up to radius {r / GROWTH:.4g} within the budget of {budget:,}"}


def search(spec: dict, exact: float) -> dict:
    from stabjax.explore.shock import shock_spec

    t0 = time.perf_counter()
    ds = shock_spec(spec)
    wall = time.perf_counter() - t0
    lo, hi = float(ds.shock_norm_lo), float(ds.shock_norm)
    return {"trajectories": int(ds.attrs["n_trajectories"]), "rounds": int(ds.attrs["rounds"]), "wall_s": wall,
            "delta_star": hi, "bracket": [lo, hi], "rel_error": hi / exact - 1, "within_1pct": hi <= exact * 1.01,
            "bracket_holds_exact": lo <= exact <= hi}


def benchmark(cases=tuple(CASES)) -> dict:
    from stabjax.explore.shock import shock_spec

    out = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "growth": GROWTH, "cases": {}}
    for name in cases:
        system, exact, r_max, per_ball, budget = CASES[name]
        spec = spec_for(system, r_max)
        shock_spec(spec_for(system, r_max, directions=2, generations=1))  # compile once, outside both timings
        row = {"exact": exact, "search": search(spec, exact),
               "brute_force": {"per_ball": per_ball, "budget": budget, **brute_force(spec, exact, per_ball, budget)}}
        row["trajectory_ratio"] = row["brute_force"]["trajectories"] / row["search"]["trajectories"]
        out["cases"][name] = row
        print(name, json.dumps(row, indent=1), flush=True)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--case", action="append", choices=list(CASES), help="one case (default: both)")
    args = ap.parse_args(argv)
    res = benchmark(tuple(args.case or CASES))
    if args.out is not None:
        args.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
