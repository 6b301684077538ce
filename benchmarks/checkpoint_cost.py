"""Where the native engine's time goes per checkpoint (issue #25's profile), on the engine benchmark's case.

``python -m benchmarks.checkpoint_cost [--n 4096] [--t1 1e4] [--reps 3]``: the native kernel alone
(:func:`stabjax.engines.native.solve`, compiled beforehand, best of ``--reps``) on paper A's monoaxial
example (``benchmarks.bench``: alpha axis, rtol 1e-8, atol 1e-10), varying one thing at a time:

* the number of checkpoints (2000 = the default, down to 20): the accepted steps do not change (the
  controller is not clipped by checkpoints), so the difference is what observing and classifying
  checkpoints costs, per checkpoint and trajectory;
* the verdict horizons (the default four against t1 alone): the multi-horizon classifier's share;
* the SIMD width (8 and 16 trajectories per block): the classifier state (about 160 doubles per
  trajectory) is read and written at every checkpoint for the whole block;
* a model with named outcomes (the pendulum example, pyBasin's case): the features-only fold against
  the attitude classifier's state (``VerdictConfig.verdicts``), 4000 checkpoints; and the same with the
  fixed-point stop's test on (asked every ``stabjax.fold.stops.fixed_point_every(K)`` checkpoints) and on but
  asked every ``TEST_EVERY`` = 8, as it was before.

Printed: wall seconds and accepted traj-steps/s per variant. Figures: docs/performance.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import time


def _best(fn, reps: int) -> float:
    fn()
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv: list[str] | None = None) -> int:
    from stabjax.config import setup_jax

    ap = argparse.ArgumentParser(prog="python -m benchmarks.checkpoint_cost", description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=4096)
    ap.add_argument("--t1", type=float, default=1e4)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args(argv)
    setup_jax()
    from stabjax.fold import stops
    from stabjax.engines import native
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import static_params

    from .bench import spec
    from .peer_bench import _plan as pendulum_plan

    def run(plan, width=None, label=""):
        p = plan.params_for(0, a.n)
        st = static_params(plan)
        out = {}

        def go():
            out["r"] = native.solve(plan.system, p, plan.icfg, plan.vcfg, static=st, width=width)

        w = _best(go, a.reps)
        steps = int(out["r"]["n_steps"].sum())
        print(f"{label:<58} {w:7.3f} s  {steps / w:9.3g} traj-steps/s  ({steps:,} accepted)", flush=True)
        return w, steps

    def mono(nck=2000, horizons=None):
        s = spec(a.n, a.t1)
        s["integrate"].update(n_checkpoints=nck, engine="native")
        if horizons is not None:
            s["verdict"] = {"horizons": horizons}
        return make_plan(s)

    base, _ = run(mono(), label="monoaxial, 2000 checkpoints, 4 horizons (default)")
    floor = None
    for nck in (500, 100, 20):
        floor, _ = run(mono(nck), label=f"monoaxial, {nck} checkpoints")
    run(mono(horizons=[a.t1]), label="monoaxial, 2000 checkpoints, one horizon (t1)")
    for w in (8, 16):
        run(mono(), width=w, label=f"monoaxial, width {w}")
    per = (base - floor) / (a.n * (2000 - 20))
    print(f"checkpoints' share of the default run: {(base - floor) / base:.0%}; {per * 1e9:.0f} ns wall per "
          "checkpoint and trajectory (all cores)")
    pend = pendulum_plan(a.n, 1000.0)
    run(pend, label="pendulum (named outcomes: features-only fold), width 16", width=16)
    run(pend, label="pendulum, width 8", width=8)
    old = dataclasses.replace(pend, vcfg=pend.vcfg.replace(verdicts=True))  # the fold before: attitude state too
    for w in (16, 8):
        run(old, width=w, label=f"pendulum with the attitude classifier's state, width {w}")
    # the fixed-point test's cost is a few per cent at most: off and on are timed interleaved, best of 2 x reps
    fp = dataclasses.replace(pend, icfg=pend.icfg.replace(early_stop=True))
    p = pend.params_for(0, a.n)
    st = static_params(pend)

    def pair(label):
        best = {}
        for q in (pend, fp):
            native.solve(q.system, p, q.icfg, q.vcfg, static=st)  # compile
        for _ in range(2 * a.reps):
            for name, q in (("off", pend), ("on", fp)):
                t = time.perf_counter()
                native.solve(q.system, p, q.icfg, q.vcfg, static=st)
                best[name] = min(best.get(name, float("inf")), time.perf_counter() - t)
        print(f"pendulum, fixed-point test {label}: off {best['off']:.3f} s, on {best['on']:.3f} s "
              f"({best['on'] / best['off'] - 1:+.0%})", flush=True)

    pair(f"every {stops.fixed_point_every(4000)} checkpoints")
    every = stops.fixed_point_every
    try:  # the test's interval as before: every TEST_EVERY checkpoints (a kernel of its own)
        stops.fixed_point_every = lambda k: stops.TEST_EVERY
        native.clear_cache()
        pair(f"every {stops.TEST_EVERY} checkpoints (before)")
    finally:
        stops.fixed_point_every = every
        native.clear_cache()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
