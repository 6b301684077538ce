"""Benchmark: the stabjax sweep engines against named baselines, in one process.

    stabjax bench [--sizes 256,4096,65536] [--t1 1e4] [--out results/bench.json] [--quick]
    python -m benchmarks.bench ...

Model: the monoaxial paper example (docs/models) with an alpha axis (alpha evenly spaced in
[0.3, 1.0]; every other parameter the paper's), rtol 1e-8, atol 1e-10, float64, horizon t1.
Contenders (all on the same trajectories):

1. ``stabjax``: the engine as a user calls it -- :func:`stabjax.run.sweep.run_spec` on a spec
   (default engine "auto": the native C engine on CPU), including theory evaluation and dataset
   assembly; ``stabjax_fused``: the same with the fused XLA engine;
2. ``diffrax_vmap``: the plain baseline a user would write -- ``jax.jit(jax.vmap(diffeqsolve))``
   over an (N, 6) state with ``jnp.cross``, Tsit5, PIDController, ``SaveAt(t1=True)``;
3. ``scipy_dop853``: ``solve_ivp(method="DOP853")`` with a NumPy right-hand side, looping over
   a subset of trajectories (reported per trajectory).

Reported per contender and size: wall time of the run (compile excluded), compile time,
accepted steps (summed over trajectories; the vmapped baseline also gets its lock-step count),
trajectory-steps per second, peak resident memory during the run, and agreement checks:
verdicts of the native and fused engines and of run_spec against the diffrax engine, final
states against the diffrax baseline and against SciPy. Also the machine, the load average and
library versions. How the figures in docs/performance.md were measured is described there.

Size (~500 lines): each named baseline (diffrax, SciPy, numba) is written here next to the engine it is
compared with, so the benchmark reads as one experiment; the other suites are modules of their own.
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

    from stabjax import __version__

    v = {"stabjax": __version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__, "diffrax": diffrax.__version__,
         "equinox": equinox.__version__, "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import numba

        v["numba"] = numba.__version__
    except ImportError:
        pass
    return v


def accelerator() -> dict | None:
    """The JAX default device when it is not the CPU."""
    import jax

    if jax.default_backend() == "cpu":
        return None
    return {"backend": jax.default_backend(), "device_kind": str(jax.devices()[0].device_kind)}


# ---- the model --------------------------------------------------------------------------------


def alphas(n: int) -> np.ndarray:
    return np.linspace(*ALPHA_RANGE, n)


def spec(n: int, t1: float) -> dict:
    return {"system": SYSTEM, "name": f"bench_{n}",
            "grid": {"alpha": {"start": ALPHA_RANGE[0], "stop": ALPHA_RANGE[1], "num": int(n)}},
            "integrate": {"t1": float(t1), "rtol": RTOL, "atol": ATOL, "max_steps": 2_000_000}}


def paper_constants() -> dict:
    from stabjax.model.registry import get_system

    s = get_system(SYSTEM)
    p = s.check(s.params.resolve(None))
    return {k: np.asarray(v, float) for k, v in p.items()}


def params(n: int) -> dict:
    """The benchmark's parameters for ``n`` trajectories: the paper's constants, alpha swept."""
    p = {k: np.broadcast_to(v, (n, *np.shape(v))).copy() for k, v in paper_constants().items()}
    p["alpha"] = alphas(n)
    return p


def numpy_rhs(t, y, alpha, c):
    """Independent NumPy right-hand side (paper A, (2), (4), (14); torques on s/|s|)."""
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

    from stabjax import engines
    from stabjax.engines import fused, native
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import choose_batch_size, run_plan, static_params

    sp = spec(n, t1)
    sp["integrate"]["engine"] = engine
    plan = make_plan(sp)
    old_cache = os.environ.get("STABJAX_CACHE_DIR")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["STABJAX_CACHE_DIR"] = cache  # an empty cache: the C compiler really runs
        native.clear_cache()
        try:
            with _Timer() as tc:  # the engine's choice and an ahead-of-time build of what run_plan will use
                plan = engines.resolve_plan(plan, static=static_params(plan))
                batch = choose_batch_size(plan, None)
                if plan.engine == "native":
                    native.warm(plan.system, plan.icfg, plan.vcfg, plan.params_for(0, batch), static=static_params(plan))
                elif plan.engine == "fused":
                    fused.prepare_call(plan.system, plan.icfg, plan.vcfg, plan.params_for(0, batch),
                                       static=static_params(plan))
                # libraries a process imports once, on its first sweep: xarray imports dask (and dask scipy,
                # jinja2, psutil) when it builds its first Variable, ~0.3 s that no later sweep pays
                import xarray as xr

                xr.Dataset({"x": ("a", np.zeros(2))})
            _reset_peak_rss()
            with _Timer() as tr:
                ds = run_plan(plan)
        finally:
            if old_cache is None:
                os.environ.pop("STABJAX_CACHE_DIR", None)
            else:
                os.environ["STABJAX_CACHE_DIR"] = old_cache
    steps = int(ds["n_steps"].sum())
    return {"engine": plan.engine, "engine_note": plan.engine_note, "wall_s": tr.wall, "cpu_s": tr.cpu,
            "compile_s": tc.wall, "accepted_steps": steps, "rejected_steps": int(ds["n_rejected"].sum()),
            "traj_steps_per_s": steps / tr.wall, "peak_rss_mb": _peak_rss_mb(), "batch_size": batch,
            "threads_or_lanes": (native.default_threads() if plan.engine == "native"
                                 else min(fused.default_lanes(), batch)),
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


# ---- agreement -------------------------------------------------------------------------------------


def run_numba(n: int, t1: float, k: int) -> dict | None:
    """The compiled one-trajectory-at-a-time baseline (:mod:`benchmarks.numba_baseline`); None without numba."""
    try:
        from benchmarks import numba_baseline as mod
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


def agreement(n: int, t1: float, stab: dict, dfx: dict | None, sp: dict | None, k_verdict: int) -> dict:
    """Final states of the native engine vs the diffrax baseline and SciPy; its verdicts (and those of
    run_spec and of the fused engine) vs the diffrax engine path."""
    from stabjax.config import IntegrateConfig
    from stabjax.engines import diffrax_engine, fused as fused_engine, native
    from stabjax.model.registry import get_system

    s = get_system(SYSTEM)
    out = {}
    icfg = IntegrateConfig(t1=t1, rtol=RTOL, atol=ATOL)
    p = params(n)
    sub = _scipy_subset(n, k_verdict)
    psub = {k: v[sub] for k, v in p.items()}
    fused = fused_engine.solve(s, psub, icfg, s.verdict, with_state=True)
    # without a C compiler the native rows compare the fused engine
    nat = native.solve(s, psub, icfg, s.verdict, with_state=True) if native.available() else fused
    ref = diffrax_engine.solve(s, psub, icfg, s.verdict)
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


# ---- main -------------------------------------------------------------------------------------------


def _strip(d: dict) -> dict:
    return {k: v for k, v in d.items() if not k.startswith("_")}


def main(sizes=(256, 4096, 65536), t1: float = 1e4, out: str | Path = "results/bench.json", quick: bool = False,
         scipy_k: int | None = None, skip_diffrax_above: int | None = None, with_fused: bool = True) -> dict:
    from stabjax.config import setup_jax

    setup_jax()
    import jax

    from stabjax.engines import fused

    if quick:  # smoke test: one tiny size, short horizon
        sizes, t1 = [16], min(t1, 20.0)
    sizes = [int(s) for s in sizes]
    scipy_k = scipy_k or (2 if quick else 8)
    out = Path(out)
    result = {"model": f"{SYSTEM} paper example (paper A, Section 5), alpha in linspace{ALPHA_RANGE}, rtol {RTOL}, "
                       f"atol {ATOL}, float64", "t1": t1, "quick": quick, "machine": machine(), "versions": versions(),
              "jax_devices": [str(d) for d in jax.devices()], "default_lanes": fused.default_lanes(),
              "env": {k: os.environ.get(k) for k in ("EQX_ON_ERROR", "XLA_FLAGS", "STABJAX_CPU_DEVICES")},
              "accelerator": accelerator(), "sizes": {}}
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
            print(f"[bench] N={n}: numba Dopri5 subset ...", flush=True)
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
        row["ratios"] = ratios
        result["sizes"][str(n)] = {k: (_strip(v) if isinstance(v, dict) else v) for k, v in row.items()}
        print(f"[bench] N={n}: " + json.dumps(ratios), flush=True)
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
    return [f"Accelerator: {acc['device_kind']} (JAX backend {acc['backend']}). The stabjax and diffrax rows ran "
            "on it; SciPy ran on the host CPU above."]


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
