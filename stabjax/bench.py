"""Benchmark: the stabjax sweep engine against named baselines, in one process.

    stabjax bench [--sizes 256,4096,65536] [--t1 1e4] [--out results/bench.json] [--quick]
    python -m stabjax.bench ...

Model: the monoaxial paper example (MODELS.md A.5) with an alpha axis (alpha evenly spaced in
[0.3, 1.0]; every other parameter the paper's), rtol 1e-8, atol 1e-10, float64, horizon t1.
Contenders (all on the same trajectories):

1. ``stabjax``: the engine as a user calls it -- :func:`stabjax.sweep.run_spec` on a spec
   (default engine "auto": the native C engine on CPU), including theory evaluation and dataset
   assembly; ``stabjax_fused``: the same with the fused XLA engine (the previous default);
2. ``diffrax_vmap``: the plain baseline a user would write -- ``jax.jit(jax.vmap(diffeqsolve))``
   over an (N, 6) state with ``jnp.cross``, Tsit5, PIDController, ``SaveAt(t1=True)``;
3. ``scipy_dop853``: ``solve_ivp(method="DOP853")`` with a NumPy right-hand side, looping over
   a subset of trajectories (reported per trajectory);
4. ``numba_dopri5`` (if numba is installed): a compiled per-trajectory Dormand-Prince 5(4)
   loop with the same error norm and controller, over the same subset as SciPy.

Reported per contender and size: wall time of the run (compile excluded), compile time,
accepted steps (summed over trajectories; the vmapped baseline also gets its lock-step count),
trajectory-steps per second, peak resident memory during the run, and agreement checks:
verdicts of the fused engine against the diffrax engine path, final states of the fused engine
against the diffrax baseline and against SciPy. Also the machine, the load average, library
versions, XLA's flop count of one fused step and the fraction of the CPU's float64 peak: the
nominal peak (cores x clock x FMA units x lanes) and the peak measured before and after the run
(:func:`measured_peak`; the machine's speed drifts, and two virtual CPUs need not be two cores).
"""
from __future__ import annotations

import json
import math
import os
import platform
import resource
import time
from pathlib import Path

import numpy as np

SYSTEM = "monoaxial"
RTOL, ATOL = 1e-8, 1e-10
ALPHA_RANGE = (0.3, 1.0)


# ---- measurement helpers ---------------------------------------------------------------------


def _reset_peak_rss() -> bool:
    """Reset the kernel's high-water mark of resident memory (Linux), so peaks are per contender."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_rss_mb() -> float:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Timer:
    def __enter__(self):
        self.t = time.perf_counter()
        self.c = time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.t
        self.cpu = time.process_time() - self.c


def machine() -> dict:
    info = {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}
    try:
        txt = Path("/proc/cpuinfo").read_text()
        for key in ("model name", "cpu MHz", "flags"):
            for line in txt.splitlines():
                if line.startswith(key):
                    val = line.split(":", 1)[1].strip()
                    info[key.replace(" ", "_")] = (" ".join(f for f in val.split() if f.startswith("avx") or f == "fma")
                                                   if key == "flags" else val)
                    break
        for line in txt.splitlines():
            if line.startswith("model\t") or line.startswith("model "):
                info["cpu_model_number"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        info["loadavg_at_start"] = Path("/proc/loadavg").read_text().split()[:3]
    except OSError:
        pass
    return info


def versions() -> dict:
    import diffrax
    import equinox
    import jax
    import jaxlib
    import scipy

    from . import __version__

    v = {"stabjax": __version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__, "diffrax": diffrax.__version__,
         "equinox": equinox.__version__, "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import numba

        v["numba"] = numba.__version__
    except ImportError:
        pass
    return v


def peak_flops(info: dict) -> dict:
    """float64 peak: cores x clock x 2 FMA units x 8 lanes (AVX-512) x 2 flops (an assumption)."""
    ghz = float(info.get("cpu_MHz", 2000.0)) / 1000.0
    lanes = 8 if "avx512f" in info.get("flags", "") else 4
    per_cycle = 2 * lanes * 2
    cores = int(info.get("cpus") or 1)
    return {"ghz": ghz, "flops_per_cycle_per_core": per_cycle, "cores": cores,
            "peak_gflops_f64": cores * ghz * per_cycle,
            "assumption": "2 FMA units per core, vector width from /proc/cpuinfo flags, nominal clock"}


_PEAK_SRC = r"""
#include <stdint.h>
#ifdef __AVX512F__
#define VB 64
#else
#define VB 32
#endif
typedef double vd __attribute__((vector_size(VB)));
#define NACC 10  /* independent chains (a0..a9): two FMA units x 4-cycle latency need 8 */

/* multiply-adds on NACC independent vector chains: the float64 throughput one thread reaches */
double stabjax_peak_fma(int64_t iters) {
    const vd z = {0.0}, m = z + 0.999999, c = z + 1e-7;
    vd a0 = z + 1.0, a1 = z + 1.001, a2 = z + 1.002, a3 = z + 1.003, a4 = z + 1.004;
    vd a5 = z + 1.005, a6 = z + 1.006, a7 = z + 1.007, a8 = z + 1.008, a9 = z + 1.009;
    for (int64_t it = 0; it < iters; it++) {
        a0 = a0 * m + c; a1 = a1 * m + c; a2 = a2 * m + c; a3 = a3 * m + c; a4 = a4 * m + c;
        a5 = a5 * m + c; a6 = a6 * m + c; a7 = a7 * m + c; a8 = a8 * m + c; a9 = a9 * m + c;
        /* opaque to the optimiser: the chains stay in registers, one multiply-add each per iteration */
        __asm__ volatile("" : "+x"(a0), "+x"(a1), "+x"(a2), "+x"(a3), "+x"(a4), "+x"(a5), "+x"(a6), "+x"(a7),
                         "+x"(a8), "+x"(a9));
    }
    const vd s = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7 + a8 + a9;
    double out = 0.0;
    for (int j = 0; j < (int)(VB / 8); j++) out += s[j];
    return out;
}

int stabjax_peak_lanes(void) { return VB / 8; }
int stabjax_peak_chains(void) { return NACC; }

/* one dependent chain of scalar multiply-adds: bound by latency, not by execution units, so two
   threads on two real cores each keep their one-thread speed */
double stabjax_peak_chain(int64_t iters) {
    double x = 1.0;
    for (int64_t it = 0; it < iters; it++) {
        x = x * 0.999999 + 1e-7;
        __asm__ volatile("" : "+x"(x));
    }
    return x;
}
"""


def peak_library():
    """The compiled microbenchmark of :func:`measured_peak` (ctypes signatures set)."""
    import ctypes

    from . import native

    lib = native.compile_library(_PEAK_SRC)
    for f in (lib.stabjax_peak_fma, lib.stabjax_peak_chain):
        f.argtypes, f.restype = [ctypes.c_int64], ctypes.c_double
    return lib


def measured_peak(threads: int | None = None, seconds: float = 0.3) -> dict:
    """float64 throughput this machine delivers, measured: multiply-adds on independent vector
    chains in one thread and in ``threads`` concurrent threads (the roofline's measured ceiling),
    and one latency-bound scalar chain (two threads on two real cores both keep one thread's speed;
    shared cores or a CPU quota show as a slowdown). x86-64 only; ``{"error": ...}`` elsewhere."""
    from concurrent.futures import ThreadPoolExecutor

    if platform.machine() not in ("x86_64", "AMD64"):
        return {"error": "measured peak: x86-64 only"}
    try:
        lib = peak_library()
    except Exception as exc:
        return {"error": repr(exc)}
    lanes, chains = lib.stabjax_peak_lanes(), lib.stabjax_peak_chains()
    threads = int(threads or os.cpu_count() or 1)

    def timed(fn, iters, k):
        def one(_):
            t = time.perf_counter()
            fn(iters)  # ctypes releases the GIL for the call
            return time.perf_counter() - t
        t0 = time.perf_counter()
        with ThreadPoolExecutor(k) as ex:
            list(ex.map(one, range(k)))
        return time.perf_counter() - t0

    def calibrated(fn, flops_per_iter):
        iters = 1_000_000
        while timed(fn, iters, 1) < 0.05:
            iters *= 4
        iters = int(iters * seconds / max(timed(fn, iters, 1), 1e-9))
        one = min(timed(fn, iters, 1) for _ in range(3))
        many = min(timed(fn, iters, threads) for _ in range(3))
        return iters * flops_per_iter / one / 1e9, threads * iters * flops_per_iter / many / 1e9

    fma1, fman = calibrated(lib.stabjax_peak_fma, 2 * lanes * chains)
    ch1, chn = calibrated(lib.stabjax_peak_chain, 1)
    return {"gflops_f64_one_thread": fma1, "gflops_f64_all_threads": fman, "threads": threads,
            "scaling_fma": fman / fma1, "scaling_latency_chain": chn / ch1,
            "clock_ghz_from_chain": ch1 * 4,  # a float64 multiply-add's latency: 4 cycles (Skylake and later)
            "method": f"{chains} independent {lanes}-lane multiply-add chains per thread; "
                      "latency chain: one dependent scalar multiply-add"}


# float64 peak of GPUs by device-kind substring, TF/s without tensor cores (NVIDIA datasheets:
# H100 SXM5 / H200 34, H100 PCIe 26, A100 9.7); only used to put the fused engine's rate in scale
GPU_F64_PEAK_TFLOPS = (("H200", 34.0), ("H100 80GB HBM3", 34.0), ("H100 SXM", 34.0), ("H100", 25.6), ("A100", 9.7))


def accelerator() -> dict | None:
    """The JAX default device when it is not the CPU: kind, and its float64 peak where known."""
    import jax

    if jax.default_backend() == "cpu":
        return None
    kind = str(jax.devices()[0].device_kind)
    peak = next((v for k, v in GPU_F64_PEAK_TFLOPS if k in kind), None)
    return {"backend": jax.default_backend(), "device_kind": kind, "peak_tflops_f64": peak,
            "peak_source": "NVIDIA datasheet, FP64 without tensor cores" if peak else None}


# ---- the model --------------------------------------------------------------------------------


def alphas(n: int) -> np.ndarray:
    return np.linspace(*ALPHA_RANGE, n)


def spec(n: int, t1: float) -> dict:
    return {"system": SYSTEM, "name": f"bench_{n}",
            "grid": {"alpha": {"start": ALPHA_RANGE[0], "stop": ALPHA_RANGE[1], "num": int(n)}},
            "integrate": {"t1": float(t1), "rtol": RTOL, "atol": ATOL, "max_steps": 2_000_000}}


def paper_constants() -> dict:
    from .registry import get_system

    s = get_system(SYSTEM)
    p = s.check(s.params.resolve(None))
    return {k: np.asarray(v, float) for k, v in p.items()}


def params(n: int) -> dict:
    """The benchmark's parameters for ``n`` trajectories: the paper's constants, alpha swept."""
    p = {k: np.broadcast_to(v, (n, *np.shape(v))).copy() for k, v in paper_constants().items()}
    p["alpha"] = alphas(n)
    return p


def native_kernel(n: int, t1: float = 1e4, mod=None):
    """The native engine's compiled kernel for the benchmark sweep (alpha per lane, everything else
    folded in as constants) and its prepared inputs ``(kernel, ain, y0)``. ``mod``: a module with
    ``native``'s interface (benchmarks/ab_kernels.py passes an older revision's)."""
    from .engine import IntegrateConfig
    from .registry import get_system

    if mod is None:
        from . import native as mod
    s = get_system(SYSTEM)
    p = params(n)
    kern, dyn = mod.kernel_for(s, IntegrateConfig(t1=t1, rtol=RTOL, atol=ATOL), s.verdict, p,
                               static=[k for k in p if k != "alpha"])
    return (kern, *kern.model.host_inputs(dyn, n))


def numpy_rhs(t, y, alpha, c):
    """Independent NumPy right-hand side (MODELS.md A, (2), (4), (14); torques on s/|s|)."""
    J, D, r = c["J"], c["D"], c["r"]
    w, s = y[:3], y[3:]
    sh = s / math.sqrt(s @ s)
    sxr = np.cross(sh, r)
    d = sh - r
    m_r = -c["a"] * math.sqrt(d @ d) ** (c["mu"] - 1.0) * sxr
    m_p = c["b"] * math.cos(c["omega0"] * t**alpha) * math.sqrt(sxr @ sxr) ** (c["sigma"] - 1.0) * sxr
    dw = (-np.cross(w, J * w) - D @ w + m_r + m_p) / J
    return np.concatenate([dw, -np.cross(w, s)])


# ---- contenders -----------------------------------------------------------------------------------


def run_stabjax(n: int, t1: float, engine: str = "auto") -> dict:
    """The engine as a user calls it (run_spec); compile measured separately on the same shapes.

    ``engine="auto"`` is the default a user gets (the native C engine on CPU); ``"fused"`` is the
    XLA engine, kept as a named contender.
    """
    import tempfile

    from . import fast, native
    from .engine import engine_chain
    from .spec import make_plan
    from .sweep import choose_batch_size, run_spec, static_params

    sp = spec(n, t1)
    sp["integrate"]["engine"] = engine
    plan = make_plan(sp)
    batch = choose_batch_size(plan, None)
    used = engine_chain(plan.system, plan.icfg)[0]
    old_cache = os.environ.get("STABJAX_CACHE_DIR")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["STABJAX_CACHE_DIR"] = cache  # an empty cache: the C compiler really runs
        native._kernel.cache_clear()
        try:
            with _Timer() as tc:  # ahead-of-time build of exactly what run_spec will use
                if used == "native":
                    native.warm(plan.system, plan.icfg, plan.vcfg, plan.params_for(0, batch), static=static_params(plan))
                else:
                    fast.prepare_call(plan.system, plan.icfg, plan.vcfg, plan.params_for(0, batch),
                                      static=static_params(plan))
            _reset_peak_rss()
            with _Timer() as tr:
                ds = run_spec(sp)
        finally:
            if old_cache is None:
                os.environ.pop("STABJAX_CACHE_DIR", None)
            else:
                os.environ["STABJAX_CACHE_DIR"] = old_cache
    steps = int(ds["n_steps"].sum())
    return {"engine": ds.attrs.get("engine", used), "wall_s": tr.wall, "cpu_s": tr.cpu, "compile_s": tc.wall,
            "accepted_steps": steps, "rejected_steps": int(ds["n_rejected"].sum()), "traj_steps_per_s": steps / tr.wall,
            "peak_rss_mb": _peak_rss_mb(), "batch_size": batch,
            "threads_or_lanes": (native.default_threads() if used == "native" else min(fast.default_lanes(), batch)),
            "verdicts": {k: int((_at_t1(ds["verdict"]).values == i).sum()) for i, k in enumerate(
                ("converged", "flipped", "diverged", "undecided", "failed"))},
            "_verdict": _at_t1(ds["verdict"]).values.ravel()}


def _at_t1(v):
    """Verdicts at t1 (the last horizon) of a DataArray or (N, n_horizons) array."""
    if hasattr(v, "dims"):
        return v.isel(horizon=-1) if "horizon" in v.dims else v
    v = np.asarray(v)
    return v[:, -1] if v.ndim == 2 else v


def _diffrax_baseline_fn(t1: float, solver: str = "Tsit5"):
    """The plain baseline: ``jit(vmap(diffeqsolve))`` of the paper example over alpha (``solver``:
    a diffrax solver class name; the numba baseline's test uses Dopri5)."""
    import diffrax
    import jax
    import jax.numpy as jnp

    c = paper_constants()
    J, D, r = (jnp.asarray(c[k]) for k in ("J", "D", "r"))
    a, mu, b, sigma, om = (float(c[k]) for k in ("a", "mu", "b", "sigma", "omega0"))

    def rhs(t, y, alpha):
        w, s = y[:3], y[3:]
        sh = s / jnp.linalg.norm(s)
        sxr = jnp.cross(sh, r)
        m_r = -a * jnp.linalg.norm(sh - r) ** (mu - 1.0) * sxr
        m_p = b * jnp.cos(om * t**alpha) * jnp.linalg.norm(sxr) ** (sigma - 1.0) * sxr
        dw = (-jnp.cross(w, J * w) - D @ w + m_r + m_p) / J
        return jnp.concatenate([dw, -jnp.cross(w, s)])

    def one(y0, alpha):
        sol = diffrax.diffeqsolve(diffrax.ODETerm(rhs), getattr(diffrax, solver)(), 0.0, t1, None, y0, args=alpha,
                                  saveat=diffrax.SaveAt(t1=True),
                                  stepsize_controller=diffrax.PIDController(rtol=RTOL, atol=ATOL),
                                  max_steps=2_000_000)
        return sol.ys[-1], sol.stats["num_accepted_steps"], sol.stats["num_steps"], sol.result._value

    y0 = np.concatenate([c["w0"], c["s0"]])
    return jax.jit(jax.vmap(one)), y0


def run_diffrax(n: int, t1: float) -> dict:
    import jax.numpy as jnp

    fn, y0 = _diffrax_baseline_fn(t1)
    Y0 = jnp.asarray(np.tile(y0, (n, 1)))
    A = jnp.asarray(alphas(n))
    with _Timer() as tc:
        exe = fn.lower(Y0, A).compile()
    _reset_peak_rss()
    with _Timer() as tr:
        ys, acc, tot, res = exe(Y0, A)
        ys = np.asarray(ys)
    acc, tot = np.asarray(acc), np.asarray(tot)
    steps = int(acc.sum())
    return {"wall_s": tr.wall, "cpu_s": tr.cpu, "compile_s": tc.wall, "accepted_steps": steps,
            "rejected_steps": int(tot.sum() - steps), "traj_steps_per_s": steps / tr.wall,
            "lockstep_steps": int(tot.max()) * n, "lockstep_traj_steps_per_s": int(tot.max()) * n / tr.wall,
            "peak_rss_mb": _peak_rss_mb(), "failed": int((np.asarray(res) != 0).sum()), "_state": ys}


def _scipy_subset(n: int, k: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(int))


def run_scipy(n: int, t1: float, k: int) -> dict:
    from scipy.integrate import solve_ivp

    c = paper_constants()
    y0 = np.concatenate([c["w0"], c["s0"]])
    idx = _scipy_subset(n, k)
    states, steps, walls = [], [], []
    _reset_peak_rss()
    for i in idx:
        with _Timer() as tr:
            sol = solve_ivp(numpy_rhs, (0.0, t1), y0, method="DOP853", rtol=RTOL, atol=ATOL, args=(alphas(n)[i], c))
        walls.append(tr.wall)
        states.append(sol.y[:, -1])
        steps.append(sol.t.size - 1)  # accepted steps (dense=False: t holds every accepted step)
    per = float(np.mean(walls))
    return {"n_measured": int(len(idx)), "indices": idx.tolist(), "wall_s_measured": float(np.sum(walls)),
            "wall_s_per_trajectory": per, "wall_s_extrapolated": per * n, "accepted_steps_measured": int(np.sum(steps)),
            "traj_steps_per_s": float(np.sum(steps) / np.sum(walls)), "peak_rss_mb": _peak_rss_mb(),
            "_state": np.array(states)}


NUMBA_SRC = None  # built lazily in benchmarks/numba_dopri5.py


def run_numba(n: int, t1: float, k: int) -> dict | None:
    try:
        import importlib.util

        path = Path(__file__).resolve().parent.parent / "benchmarks" / "numba_dopri5.py"
        if not path.exists():
            return None
        spec_ = importlib.util.spec_from_file_location("numba_dopri5", path)
        mod = importlib.util.module_from_spec(spec_)
        spec_.loader.exec_module(mod)
    except ImportError:
        return None
    c = paper_constants()
    idx = _scipy_subset(n, k)
    y0 = np.concatenate([c["w0"], c["s0"]])
    with _Timer() as tc:
        mod.solve_many(np.tile(y0, (1, 1)), alphas(n)[:1], c, 1.0, RTOL, ATOL)  # compile
    _reset_peak_rss()
    with _Timer() as tr:
        ys, acc = mod.solve_many(np.tile(y0, (len(idx), 1)), alphas(n)[idx], c, t1, RTOL, ATOL)
    return {"n_measured": int(len(idx)), "compile_s": tc.wall, "wall_s_measured": tr.wall,
            "wall_s_per_trajectory": tr.wall / len(idx), "wall_s_extrapolated": tr.wall / len(idx) * n,
            "accepted_steps_measured": int(acc.sum()), "traj_steps_per_s": float(acc.sum() / tr.wall),
            "peak_rss_mb": _peak_rss_mb(), "_state": ys}


# ---- agreement and roofline -------------------------------------------------------------------------


def agreement(n: int, t1: float, stab: dict, dfx: dict | None, sp: dict | None, k_verdict: int) -> dict:
    """Final states of the native engine vs the diffrax baseline and SciPy; its verdicts (and those of
    run_spec and of the fused engine) vs the diffrax engine path."""
    from . import fast, native
    from .engine import IntegrateConfig, solve_batch
    from .registry import get_system

    s = get_system(SYSTEM)
    out = {}
    icfg = IntegrateConfig(t1=t1, rtol=RTOL, atol=ATOL)
    p = params(n)
    sub = _scipy_subset(n, k_verdict)
    psub = {k: v[sub] for k, v in p.items()}
    nat = native.solve(s, psub, icfg, s.verdict, with_state=True)
    fused = fast.solve(s, psub, icfg, s.verdict, with_state=True)
    ref = solve_batch(s, psub, IntegrateConfig(**{**icfg.__dict__, "engine": "diffrax"}))
    out["verdict_check_n"] = int(len(sub))
    out["verdicts_equal_native_vs_diffrax_engine"] = int((_at_t1(nat["verdict"]) == _at_t1(ref["verdict"])).sum())
    out["verdicts_equal_fused_vs_diffrax_engine"] = int((_at_t1(fused["verdict"]) == _at_t1(ref["verdict"])).sum())
    out["verdicts_equal_run_spec_vs_diffrax_engine"] = int((stab["_verdict"][sub] == _at_t1(ref["verdict"])).sum())
    if dfx is not None:
        for name, res in (("native", nat), ("fused", fused)):
            d = np.abs(res["state_t1"] - dfx["_state"][sub]).max(axis=1)
            out[f"max_abs_state_diff_{name}_vs_diffrax"] = float(d.max())
            out[f"median_abs_state_diff_{name}_vs_diffrax"] = float(np.median(d))
            out[f"frac_state_within_1e-6_{name}_vs_diffrax"] = float((d <= 1e-6).mean())
    if sp is not None:
        pos = {int(i): j for j, i in enumerate(sub)}
        rows = [pos[i] for i in sp["indices"] if i in pos]
        if rows:
            sps = sp["_state"][[j for j, i in enumerate(sp["indices"]) if i in pos]]
            out["max_abs_state_diff_native_vs_scipy"] = float(np.abs(nat["state_t1"][rows] - sps).max())
            if dfx is not None:
                out["max_abs_state_diff_diffrax_vs_scipy"] = float(
                    np.abs(dfx["_state"][[sub[j] for j in rows]] - sps).max())
    return out


def native_flops(t1: float) -> dict:
    """Operations per step of the native engine, counted in its generated C (see native.flops_per_step)."""
    from . import native
    from .engine import IntegrateConfig
    from .registry import get_system

    s = get_system(SYSTEM)
    n = 64
    p = params(n)
    icfg = IntegrateConfig(t1=t1, rtol=RTOL, atol=ATOL)
    kern = native_kernel(n, t1)[0]
    res = native.solve(s, p, icfg, s.verdict, static=[k for k in p if k != "alpha"])
    ck_per_step = len(icfg.checkpoints()) / float(np.mean(res["n_steps"]))
    out = native.flops_per_step(kern, ck_per_step)
    out["checkpoints_per_step"] = ck_per_step
    out["rejected_per_accepted"] = float(res["n_rejected"].sum() / res["n_steps"].sum())
    # a rejected attempt costs a step without checkpoints
    out["per_accepted_step"] = out["total"] + out["rejected_per_accepted"] * out["step"]
    return out


def step_flops() -> dict:
    """XLA's flop count of one fused step per lane (cost analysis of a 1-iteration loop body)."""
    import jax

    from . import fast
    from .engine import IntegrateConfig
    from .registry import get_system

    s = get_system(SYSTEM)
    n, L = 64, 64
    p = params(n)
    icfg = IntegrateConfig(t1=1e4, rtol=RTOL, atol=ATOL)
    exe, args, _, _ = fast.prepare_call(s, icfg, s.verdict, p, lanes=L, n_devices=1)
    ca = exe.cost_analysis()
    ca = ca[0] if isinstance(ca, (list, tuple)) else ca
    flops = float(ca.get("flops", float("nan")))
    trans = float(ca.get("transcendentals", 0.0))
    del jax
    # the module holds: initial fill (2 rhs + prepare), one loop body, the refill branch (2 rhs)
    # counted once each; subtract the fill/refill share estimated from the rhs count (6 rhs/step)
    return {"module_flops_per_lane": flops / L, "module_transcendentals_per_lane": trans / L,
            "note": "XLA HloCostAnalysis of the compiled loop, counted once (not per trip): one loop body "
                    "(6 rhs evaluations, dense output, classifier) plus the initial fill and the refill branch "
                    "(2 rhs evaluations each); per-step flops ~= module_flops_per_lane * 6 / 10"}


# ---- main -------------------------------------------------------------------------------------------


def _strip(d: dict) -> dict:
    return {k: v for k, v in d.items() if not k.startswith("_")}


def main(sizes=(256, 4096, 65536), t1: float = 1e4, out: str | Path = "results/bench.json", quick: bool = False,
         scipy_k: int | None = None, skip_diffrax_above: int | None = None, with_fused: bool = True) -> dict:
    import jax

    from . import fast

    if quick:  # smoke test: one tiny size, short horizon
        sizes, t1 = [16], min(t1, 20.0)
    sizes = [int(s) for s in sizes]
    scipy_k = scipy_k or (2 if quick else 8)
    out = Path(out)
    info = machine()
    result = {"model": f"{SYSTEM} paper example (MODELS.md A.5), alpha in linspace{ALPHA_RANGE}, rtol {RTOL}, "
                       f"atol {ATOL}, float64", "t1": t1, "quick": quick, "machine": info, "versions": versions(),
              "jax_devices": [str(d) for d in jax.devices()], "default_lanes": fast.default_lanes(),
              "env": {k: os.environ.get(k) for k in ("EQX_ON_ERROR", "XLA_FLAGS", "STABJAX_LANES")},
              "peak": peak_flops(info), "measured_peak": measured_peak(seconds=0.02 if quick else 0.3), "accelerator": accelerator(), "sizes": {}}
    try:
        result["flops"] = step_flops()
    except Exception as exc:  # cost analysis is best effort
        result["flops"] = {"error": repr(exc)}
    try:
        result["native_flops"] = native_flops(t1)
    except Exception as exc:
        result["native_flops"] = {"error": repr(exc)}
    for n in sizes:
        print(f"[bench] N={n} t1={t1}: stabjax ...", flush=True)
        row = {"stabjax": run_stabjax(n, t1)}
        if with_fused:
            print(f"[bench] N={n}: stabjax fused (XLA) engine ...", flush=True)
            row["stabjax_fused"] = run_stabjax(n, t1, engine="fused")
        if skip_diffrax_above is None or n <= skip_diffrax_above:
            print(f"[bench] N={n}: diffrax vmap ...", flush=True)
            row["diffrax_vmap"] = run_diffrax(n, t1)
        print(f"[bench] N={n}: scipy DOP853 subset ...", flush=True)
        row["scipy_dop853"] = run_scipy(n, t1, scipy_k)
        nb = run_numba(n, t1, scipy_k)
        if nb is not None:
            row["numba_dopri5"] = nb
        print(f"[bench] N={n}: agreement checks ...", flush=True)
        row["agreement"] = agreement(n, t1, row["stabjax"], row.get("diffrax_vmap"), row["scipy_dop853"],
                                     k_verdict=min(n, 64 if quick else 256))
        st = row["stabjax"]
        ratios = {}
        if "diffrax_vmap" in row:
            d = row["diffrax_vmap"]
            ratios["speedup_wall_vs_diffrax"] = d["wall_s"] / st["wall_s"]
            ratios["speedup_traj_steps_vs_diffrax"] = st["traj_steps_per_s"] / d["traj_steps_per_s"]
        ratios["speedup_per_trajectory_vs_scipy"] = row["scipy_dop853"]["wall_s_per_trajectory"] / (st["wall_s"] / n)
        if "numba_dopri5" in row:
            ratios["speedup_per_trajectory_vs_numba"] = row["numba_dopri5"]["wall_s_per_trajectory"] / (st["wall_s"] / n)
        if "stabjax_fused" in row:
            f = row["stabjax_fused"]
            ratios["speedup_wall_vs_fused"] = f["wall_s"] / st["wall_s"]
            ratios["fused_traj_steps_per_s"] = f["traj_steps_per_s"]
            if "diffrax_vmap" in row:
                ratios["fused_speedup_wall_vs_diffrax"] = row["diffrax_vmap"]["wall_s"] / f["wall_s"]
        nf = result["native_flops"].get("per_accepted_step")
        acc = result["accelerator"]
        ff = result["flops"].get("module_flops_per_lane")
        if acc and acc.get("peak_tflops_f64") and ff and st.get("engine") == "fused":
            ratios["est_flops_per_step"] = ff * 6 / 10  # see step_flops' note
            ratios["fraction_of_gpu_f64_peak"] = (ratios["est_flops_per_step"] * st["traj_steps_per_s"]
                                                  / (acc["peak_tflops_f64"] * 1e12))
        elif nf and st.get("engine") == "native":
            ratios["est_flops_per_step"] = nf
            ratios["fraction_of_f64_peak"] = nf * st["traj_steps_per_s"] / (result["peak"]["peak_gflops_f64"] * 1e9)
            mp = result["measured_peak"].get("gflops_f64_all_threads")
            if mp:
                ratios["fraction_of_measured_f64_peak"] = nf * st["traj_steps_per_s"] / (mp * 1e9)
        row["ratios"] = ratios
        result["sizes"][str(n)] = {k: (_strip(v) if isinstance(v, dict) else v) for k, v in row.items()}
        print(f"[bench] N={n}: " + json.dumps(ratios), flush=True)
    # the machine's speed drifts (benchmarks/NOTES.md): the same measurement again brackets the run
    result["measured_peak_end"] = measured_peak(seconds=0.02 if quick else 0.3)
    try:
        result["loadavg_at_end"] = Path("/proc/loadavg").read_text().split()[:3]
    except OSError:
        pass
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    md = markdown(result)
    out.with_suffix(".md").write_text(md)
    print(md)
    return result


def _accelerator_lines(r: dict) -> list[str]:
    acc = r.get("accelerator")
    if not acc:
        return []
    peak = f", float64 peak {acc['peak_tflops_f64']:g} TF/s ({acc['peak_source']})" if acc.get("peak_tflops_f64") else ""
    return [f"Accelerator: {acc['device_kind']} (JAX backend {acc['backend']}{peak}). The stabjax and diffrax rows ran "
            "on it; SciPy and numba ran on the host CPU above, whose peak the roofline line below refers to."]


def markdown(r: dict) -> str:
    m = r["machine"]
    lines = [f"# stabjax benchmark ({'quick smoke test' if r['quick'] else 'full'})", "",
             f"Model: {r['model']}, t1 = {r['t1']:g}.",
             f"Machine: {m.get('model_name', '?')} (family 6 model {m.get('cpu_model_number', '?')}), {m.get('cpus')} cores, "
             f"{m.get('cpu_MHz', '?')} MHz nominal, {m.get('flags', '')}; load average at start {m.get('loadavg_at_start')}, "
             f"at end {r.get('loadavg_at_end')}.",
             "Versions: " + ", ".join(f"{k} {v}" for k, v in r["versions"].items()) + ".",
             f"JAX devices: {len(r['jax_devices'])} ({r['jax_devices'][0] if r['jax_devices'] else '?'}); "
             f"lanes per device {r['default_lanes']}."] + _accelerator_lines(r) + ["",
             "| N | contender | wall s | compile s | accepted steps | traj-steps/s | peak RSS MB | notes |",
             "|---|---|---|---|---|---|---|---|"]
    for n, row in r["sizes"].items():
        st = row["stabjax"]
        for key, label in (("stabjax", f"stabjax (run_spec, {st.get('engine', '?')} engine)"),
                           ("stabjax_fused", "stabjax (run_spec, fused XLA engine)")):
            if key not in row:
                continue
            e = row[key]
            lines.append(f"| {n} | {label} | {e['wall_s']:.2f} | {e['compile_s']:.1f} | "
                         f"{e['accepted_steps']:,} | {e['traj_steps_per_s']:.3g} | {e['peak_rss_mb']:.0f} | "
                         f"verdicts {e['verdicts']} |")
        if "diffrax_vmap" in row:
            d = row["diffrax_vmap"]
            lines.append(f"| {n} | jit(vmap(diffrax)) | {d['wall_s']:.2f} | {d['compile_s']:.1f} | {d['accepted_steps']:,} | "
                         f"{d['traj_steps_per_s']:.3g} | {d['peak_rss_mb']:.0f} | lock-step {d['lockstep_traj_steps_per_s']:.3g} "
                         f"traj-steps/s |")
        sp = row["scipy_dop853"]
        lines.append(f"| {n} | SciPy DOP853 loop | {sp['wall_s_extrapolated']:.1f} (extrap.) | - | "
                     f"{sp['accepted_steps_measured']:,} ({sp['n_measured']} traj) | {sp['traj_steps_per_s']:.3g} | "
                     f"{sp['peak_rss_mb']:.0f} | {sp['wall_s_per_trajectory'] * 1e3:.0f} ms/trajectory |")
        if "numba_dopri5" in row:
            nb = row["numba_dopri5"]
            lines.append(f"| {n} | numba Dopri5 loop | {nb['wall_s_extrapolated']:.1f} (extrap.) | {nb['compile_s']:.1f} | "
                         f"{nb['accepted_steps_measured']:,} ({nb['n_measured']} traj) | {nb['traj_steps_per_s']:.3g} | "
                         f"{nb['peak_rss_mb']:.0f} | {nb['wall_s_per_trajectory'] * 1e3:.1f} ms/trajectory |")
    lines += ["", "Ratios and agreement:", ""]
    for n, row in r["sizes"].items():
        lines.append(f"- N = {n}: " + ", ".join(f"{k} {v:.3g}" for k, v in row["ratios"].items()) + "; "
                     + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row["agreement"].items()))
    fl = r.get("flops", {})
    nf = r.get("native_flops", {})
    pk = r["peak"]
    lines += ["", f"Roofline: peak {pk['peak_gflops_f64']:.0f} GF/s float64 ({pk['assumption']}). Native engine: "
                  f"{nf.get('per_accepted_step', float('nan')):.0f} flops per accepted step counted in its generated C "
                  f"(step {nf.get('step', float('nan')):.0f}, checkpoints {nf.get('checkpoints', float('nan')):.0f} at "
                  f"{nf.get('checkpoints_per_step', float('nan')):.2f} per step, rejected attempts "
                  f"{nf.get('rejected_per_accepted', float('nan')):.2f} per accepted step; a libm call counted as "
                  f"{nf.get('libm_flops', '?')} flops). "
                  f"XLA flops of the compiled fused loop per lane {fl.get('module_flops_per_lane', float('nan')):.0f} "
                  f"({fl.get('note', fl.get('error', ''))})."]
    for key, when in (("measured_peak", "before the run"), ("measured_peak_end", "after it")):
        mp = r.get(key) or {}
        if "gflops_f64_all_threads" in mp:
            lines.append(f"Measured peak {when}: {mp['gflops_f64_one_thread']:.0f} GF/s float64 in one thread, "
                         f"{mp['gflops_f64_all_threads']:.0f} GF/s in {mp['threads']} concurrent threads (scaling "
                         f"{mp['scaling_fma']:.2f}; a latency-bound scalar chain scales {mp['scaling_latency_chain']:.2f}, "
                         f"clock {mp['clock_ghz_from_chain']:.2f} GHz; {mp['method']}).")
        elif mp:
            lines.append(f"Measured peak {when}: {mp.get('error')}")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,4096,65536")
    ap.add_argument("--t1", type=float, default=1e4)
    ap.add_argument("--out", default="results/bench.json")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scipy-k", type=int, default=None)
    ap.add_argument("--no-fused", action="store_true", help="skip the fused (XLA) engine contender")
    a = ap.parse_args()
    main(sizes=[int(s) for s in a.sizes.split(",")], t1=a.t1, out=a.out, quick=a.quick, scipy_k=a.scipy_k,
         with_fused=not a.no_fused)
