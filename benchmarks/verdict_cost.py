"""Per-checkpoint cost of the multi-horizon classifier on the native engine (README, Verdicts).

    PYTHONPATH=. JAX_PLATFORMS=cpu python benchmarks/verdict_cost.py

128 monoaxial trajectories at the default sweep's settings (t1 = 2e4, rtol 1e-8), 4000 and 500
checkpoints, one thread, timed after a warm-up (compile) call. "fixed" is the state the engines
build today (``verdict.init(dtype)``: 8 horizon slots, features capacity); "sized" is the state
sized to the config (``verdict.init(dtype, vcfg, n_obs)``), which the engines get by passing the
config (substituted here by wrapping ``verdict.init``).
"""
import time

import numpy as np

from stabjax import native
from stabjax import verdict as V
from stabjax.engine import IntegrateConfig, batch_params
from stabjax.registry import get_system


def measure(n=128, t1=2e4):
    S = get_system("monoaxial")
    p = batch_params(S, None, n)
    p["alpha"] = np.linspace(0.3, 1.0, n)
    orig = V.init
    rows = []
    for state in ("fixed", "sized"):
        for K in (4000, 500):
            icfg = IntegrateConfig(t1=t1, n_checkpoints=K, rtol=1e-8, atol=1e-10)
            vcfg = V.bind(S.verdict, icfg.t0, icfg.t1, n_obs=len(S.observables))
            native._kernel.cache_clear()  # the kernel cache does not know which state init builds
            if state == "sized":
                V.init = lambda dtype=None, cfg=None, n_obs=None, _v=vcfg: orig(dtype, _v, len(S.observables))
            try:
                native.solve(S, p, icfg, vcfg, threads=1)
                t = time.perf_counter()
                out = native.solve(S, p, icfg, vcfg, threads=1)
                dt = time.perf_counter() - t
            finally:
                V.init = orig
            rows.append((state, K, int(out["n_steps"].sum()), dt))
            print(f"{state:6s} state, {K:5d} checkpoints: {rows[-1][2]} steps, {dt:.3f} s", flush=True)
    return rows


if __name__ == "__main__":
    measure()
