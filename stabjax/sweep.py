"""Run a sweep plan in chunks of bounded memory, resumable, into a labelled xarray Dataset.

Chunks all have the same size (the last is padded) so the vmapped solve compiles once per
spec. With an output path, each finished chunk is written to ``<out>.partial/`` with a
manifest holding the plan fingerprint; a killed sweep restarted with the same spec skips
finished chunks, and a changed spec is refused rather than silently mixed.
"""
from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from . import verdict as V
from .engine import last_engine, solve_batch
from .errors import StabjaxError, ValidationError
from .spec import Plan, check_plan, load_spec, make_plan

DEFAULT_MEMORY_FRACTION = 0.25
N_SUMMARY_FIELDS = 24  # generous upper bound on per-trajectory float outputs (summaries + theory)


def _available_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def static_params(plan: Plan) -> list[str]:
    """Parameters equal in every chunk of the plan (fixed, not swept, not sampled)."""
    varied = {ax.param.name for ax in plan.grid} | set(plan.sample)
    return [k for k in plan.fixed if k not in varied]


def bytes_per_trajectory(plan: Plan) -> int:
    """Working memory of one trajectory inside a compiled chunk.

    diffrax path: the observables at every checkpoint dominate. Native/fused engines: no per-checkpoint
    storage, only the parameters and the summaries of each queued trajectory (lane state lives in
    cache on CPU, on the device on a GPU).
    """
    if _queued(plan):
        n_par = sum(int(np.prod(np.shape(v))) or 1 for v in plan.fixed.values())
        return 8 * (2 * n_par + 2 * N_SUMMARY_FIELDS + 64)
    k = len(plan.icfg.checkpoints())
    n_obs = len(plan.system.observables)
    return 8 * (6 * k * n_obs + 64 * plan.system.state_size + 256)


def default_batch(plan: Plan) -> int:
    """Chunk size when none is given: the native/fused engines refill lanes from a queue, so longer
    queues (bigger chunks) waste less at the tail; progress is still reported per chunk. On a GPU
    the fused engine keeps 2^18 lanes busy, so a chunk holds 2^20 trajectories (NOTES.md G2)."""
    if not _queued(plan):
        return 4096
    import jax

    return 65536 if jax.default_backend() == "cpu" else 1 << 20


def _queued(plan: Plan) -> bool:
    """Whether a queued engine (native or fused: no per-checkpoint storage) takes this plan."""
    from .engine import engine_chain

    return engine_chain(plan.system, plan.icfg)[0] != "diffrax"


def choose_batch_size(plan: Plan, batch_size: int | None, memory_limit: int | None = None) -> int:
    limit = memory_limit or int(DEFAULT_MEMORY_FRACTION * _available_memory())
    per = bytes_per_trajectory(plan)
    result_bytes = plan.size * 8 * N_SUMMARY_FIELDS
    if result_bytes > limit:
        raise ValidationError(
            "grid",
            f"{plan.size:,} trajectories need {result_bytes / 2**30:.2f} GiB for their results alone, over the "
            f"{limit / 2**30:.2f} GiB allowed; split the sweep into several specs",
        )
    max_b = max(1, limit // per)
    if batch_size is None:
        return int(min(plan.size, default_batch(plan), max_b))
    if batch_size < 1:
        raise ValidationError("batch_size", f"must be >= 1, got {batch_size}")
    if batch_size > max_b:
        raise ValidationError(
            "batch_size",
            f"{batch_size} trajectories per chunk need about {batch_size * per / 2**30:.2f} GiB "
            f"(limit {limit / 2**30:.2f} GiB); use at most {max_b}",
        )
    return int(min(batch_size, plan.size))


class _Store:
    """Finished chunks on disk next to the output file."""

    def __init__(self, out: Path, plan: Plan, batch: int, restart: bool):
        self.dir = Path(str(out) + ".partial")
        self.manifest = {"fingerprint": plan.fingerprint(), "size": plan.size, "batch_size": batch}
        mf = self.dir / "manifest.json"
        if self.dir.exists() and mf.exists() and not restart:
            old = json.loads(mf.read_text())
            if old != self.manifest:
                raise StabjaxError(
                    f"{self.dir} holds a partial run of a different sweep (fingerprint {old.get('fingerprint')} vs "
                    f"{self.manifest['fingerprint']}, batch size {old.get('batch_size')} vs {batch}); "
                    "pass --restart to discard it, or use another --out"
                )
        elif self.dir.exists() and restart:
            shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        mf.write_text(json.dumps(self.manifest))

    def path(self, i: int) -> Path:
        return self.dir / f"chunk_{i:06d}.npz"

    def done(self, i: int) -> bool:
        return self.path(i).exists()

    def load(self, i: int) -> dict[str, np.ndarray]:
        with np.load(self.path(i)) as z:
            return {k: z[k] for k in z.files}

    def save(self, i: int, res: Mapping[str, np.ndarray]):
        tmp = self.dir / f".tmp_{i:06d}.npz"
        np.savez(tmp, **res)
        os.replace(tmp, self.path(i))  # atomic: a kill never leaves a half-written chunk

    def remove(self):
        shutil.rmtree(self.dir, ignore_errors=True)


def run_plan(plan: Plan, out: str | Path | None = None, *, batch_size: int | None = None, progress: bool = False,
             restart: bool = False, keep_partial: bool = False, memory_limit: int | None = None,
             on_chunk: Callable[[int, int], None] | None = None) -> xr.Dataset:
    """Integrate every trajectory of ``plan``; write ``out`` (netCDF) if given and return the Dataset."""
    batch = choose_batch_size(plan, batch_size, memory_limit)  # first: refuse impossible sizes before touching them
    check_plan(plan)
    n = plan.size
    n_chunks = -(-n // batch)
    store = _Store(Path(out), plan, batch, restart) if out is not None else None
    results: dict[str, np.ndarray] = {}
    t_start = time.perf_counter()
    steps_total = 0
    n_resumed = 0
    engines: set[str] = set()

    def put(i, res):
        nonlocal steps_total
        lo, hi = i * batch, min(n, (i + 1) * batch)
        for k, v in res.items():
            if k not in results:
                results[k] = np.empty((n, *v.shape[1:]), dtype=v.dtype)
            results[k][lo:hi] = v[: hi - lo]
        steps_total += int(res["n_steps"][: hi - lo].sum())

    bar = _progress(progress, n, plan.name)
    try:
        for i in range(n_chunks):
            lo, hi = i * batch, min(n, (i + 1) * batch)
            shown = [0]
            if store is not None and store.done(i):
                put(i, store.load(i))
                n_resumed += 1
            else:
                p = plan.params_for(lo, hi)
                if hi - lo < batch:  # pad with copies of the last trajectory: same shapes, no recompile
                    p = {k: np.concatenate([v, np.repeat(v[-1:], batch - (hi - lo), axis=0)]) for k, v in p.items()}
                shown = [0]

                def within(done, _total, lo=lo, hi=hi, shown=shown):
                    k = min(done, hi - lo) - shown[0]
                    if bar is not None and k > 0:
                        bar.update(k, steps=steps_total)
                        shown[0] += k

                res = solve_batch(plan.system, p, plan.icfg, plan.vcfg, static=static_params(plan), progress=within)
                engines.add(last_engine())
                res = {k: v[: hi - lo] for k, v in res.items()}
                if store is not None:
                    store.save(i, res)
                put(i, res)
            if bar is not None:
                bar.update(hi - lo - shown[0], steps=steps_total)
            if on_chunk is not None:
                on_chunk(i, n_chunks)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t_start
    ds = assemble(plan, results, wall=wall, steps=steps_total, batch=batch, n_resumed=n_resumed)
    ds.attrs["engine"] = ",".join(sorted(engines)) or "resumed"
    if out is not None:
        write(ds, out)
        if not keep_partial:
            store.remove()
    return ds


def run_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, batch_size: int | None = None,
             progress: bool = False, restart: bool = False, t1: float | None = None, **kw) -> xr.Dataset:
    """Load (if a path), plan and run a sweep spec. See :mod:`stabjax.spec` for the format."""
    if isinstance(spec, (str, Path)):
        spec = load_spec(spec)
    plan = make_plan(spec, t1=t1)
    return run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart, **kw)


# ---- dataset assembly ------------------------------------------------------------------------


def _theory_vars(plan: Plan, chunk: int = 262_144) -> dict[str, tuple[np.ndarray, dict]]:
    parts: dict[str, list[np.ndarray]] = {}
    meta: dict[str, dict] = {}
    main = ""
    for lo in range(0, plan.size, chunk):
        p = plan.system.check(plan.params_for(lo, min(plan.size, lo + chunk)))
        th = plan.system.theory(p)
        main = th.main
        for name, pred in th.predicates.items():
            n_here = min(plan.size, lo + chunk) - lo
            parts.setdefault(f"theory_{name}", []).append(np.broadcast_to(pred.ok, (n_here,)).astype(np.int8))
            parts.setdefault(f"margin_{name}", []).append(np.broadcast_to(pred.margin, (n_here,)).astype(float))
            meta[f"theory_{name}"] = {"long_name": pred.doc, "flag_values": np.array([0, 1], np.int8),
                                      "flag_meanings": "not_guaranteed guaranteed"}
            meta[f"margin_{name}"] = {"long_name": f"signed margin of: {pred.doc} (> 0 inside)"}
        for name, val in th.derived.items():
            n_here = min(plan.size, lo + chunk) - lo
            parts.setdefault(f"derived_{name}", []).append(np.broadcast_to(val, (n_here,)).astype(float))
            meta[f"derived_{name}"] = {"long_name": th.derived_doc.get(name, name)}
    out = {k: (np.concatenate(v), meta[k]) for k, v in parts.items()}
    out["_main"] = (np.array(main), {})
    return out


def assemble(plan: Plan, results: Mapping[str, np.ndarray], *, wall: float = float("nan"), steps: int = 0,
             batch: int = 0, n_resumed: int = 0) -> xr.Dataset:
    shape, dims = plan.shape, plan.dims
    coords: dict[str, Any] = {}
    data: dict[str, Any] = {}
    for ax in plan.grid:
        attrs = {"long_name": ax.param.doc, "units": ax.param.unit, "spec_key": ax.key, "log_axis": int(ax.log)}
        if ax.values.ndim == 1:
            coords[ax.name] = (ax.name, ax.values, attrs)
        else:  # vector-valued axis: index coordinate + the vectors as a variable
            coords[ax.name] = (ax.name, np.arange(ax.size), attrs)
            data[f"{ax.name}_value"] = ((ax.name, *[f"{ax.name}_c{i}" for i in range(ax.values.ndim - 1)]), ax.values)
    if plan.n_sample:
        coords["sample"] = ("sample", np.arange(plan.n_sample), {"long_name": "random draw index"})
        for k, v in plan.sample.items():
            prm = plan.system.params[k]
            extra = ("axis",) if v.shape[1:] == (3,) else tuple(f"{k}_c{i}" for i in range(v.ndim - 1))
            data[f"{k}_sample"] = (("sample", *extra), v, {"long_name": f"sampled {prm.doc}"})
    for k, v in results.items():
        # trailing dims (INTERFACES 2): e.g. verdicts at each horizon, features per observable
        extra = V.TRAILING_DIMS.get(k, ())[: max(v.ndim - 1, 0)]
        extra += tuple(f"{k}_dim{i}" for i in range(len(extra), v.ndim - 1))
        data[k] = ((*dims, *extra), v.reshape(shape + v.shape[1:]), {"long_name": V.SUMMARY_DOC.get(k, k)})
        if "horizon" in extra and "horizon" not in coords:
            coords["horizon"] = ("horizon", V.horizon_times(plan.vcfg, plan.icfg.t0, plan.icfg.t1),
                                 {"long_name": "horizon T: verdicts of the prefix t <= T of each run"})
        if "observable" in extra and "observable" not in coords:
            coords["observable"] = ("observable", list(plan.system.observables)[: v.shape[-1]])
    if "verdict" in data:
        data["verdict"][2].update(flag_values=np.arange(len(V.NAMES), dtype=np.int8), flag_meanings=" ".join(V.NAMES))
    th = _theory_vars(plan)
    main = str(th.pop("_main")[0])
    for k, (v, attrs) in th.items():
        data[k] = (dims, v.reshape(shape), attrs)
    ds = xr.Dataset({k: v for k, v in data.items()}, coords=coords)
    ds.attrs.update(provenance(plan))
    ds.attrs.update(theory_main=main, wall_time_s=float(wall), total_steps=int(steps), batch_size=int(batch),
                    chunks_resumed=int(n_resumed), n_trajectories=int(plan.size))
    return ds


def _git_commit() -> str:
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def versions() -> dict[str, str]:
    import diffrax
    import jax

    from . import __version__

    return {"stabjax": __version__, "jax": jax.__version__, "diffrax": diffrax.__version__,
            "numpy": np.__version__, "xarray": xr.__version__, "python": platform.python_version()}


def provenance(plan: Plan) -> dict[str, Any]:
    import jax

    return {
        "system": plan.system.name,
        "sweep_name": plan.name,
        "paper": plan.system.paper,
        "spec_json": json.dumps(_jsonable(plan.spec)),
        "fixed_params_json": json.dumps({k: np.asarray(v).tolist() for k, v in plan.fixed.items()}),
        "integrate_json": json.dumps(plan.icfg.__dict__),
        "verdict_json": json.dumps(plan.vcfg.__dict__),
        "fingerprint": plan.fingerprint(),
        "versions_json": json.dumps(versions()),
        "git_commit": _git_commit(),
        "device": str(jax.devices()[0].device_kind) + f" x{jax.device_count()}",
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus".strip(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _jsonable(x):
    from .spec import _jsonable as j

    return j(x)


def write(ds: xr.Dataset, out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    ds.to_netcdf(tmp, engine="netcdf4")
    os.replace(tmp, out)
    return out


def open_result(path: str | Path) -> xr.Dataset:
    path = Path(path)
    if not path.exists():
        raise ValidationError("file", f"not found: {path}")
    return xr.load_dataset(path, engine="netcdf4")


# ---- horizon check -----------------------------------------------------------------------------


def horizon_check(ds: xr.Dataset, *, factor: float = 4.0, n: int = 64, seed: int = 0,
                  batch_size: int | None = None) -> xr.Dataset:
    """Re-run a random subset of a finished sweep with ``t1 * factor``; return old/new verdicts.

    A thin use of the multi-horizon classifier: the sweep's own dataset already holds verdicts at
    t1 and the decades below it (dim ``horizon``); this extends the run *beyond* t1 for a subset,
    with the old horizons kept (``verdict_horizons``: the re-run's verdicts at every horizon up to
    t1 * factor). The result has dim ``traj`` with the flat indices, ``verdict_short`` (the
    dataset's, at t1) / ``verdict_long`` (at t1 * factor), and attrs ``n_changed`` and a
    confusion table.
    """
    spec = json.loads(ds.attrs["spec_json"])
    plan = make_plan(spec)
    icfg = plan.icfg
    if factor <= 1:
        raise ValidationError("factor", f"must be > 1, got {factor}")
    rng = np.random.default_rng(seed)
    n = min(n, plan.size)
    idx = np.sort(rng.choice(plan.size, size=n, replace=False))
    from .engine import IntegrateConfig

    long_cfg = IntegrateConfig(**{**icfg.__dict__, "t1": icfg.t1 * factor})
    hs = V.horizon_times(plan.vcfg, icfg.t0, icfg.t1)
    long_v = V.bind(plan.vcfg, long_cfg.t0, long_cfg.t1, horizons=list(hs[-(V.MAX_HORIZONS - 1):]))
    plan_long = Plan(**{**plan.__dict__, "icfg": long_cfg, "vcfg": long_v})
    p = plan_long.system.check(plan_long.params_at(idx))
    res = solve_batch(plan.system, p, long_cfg, long_v)
    old = np.asarray(V.at_t1(ds["verdict"]).values).ravel()[idx]
    new_all = np.asarray(res["verdict"])
    new = new_all[:, -1] if new_all.ndim == 2 else new_all
    table = np.zeros((len(V.NAMES), len(V.NAMES)), dtype=int)
    np.add.at(table, (old.astype(int), new.astype(int)), 1)
    out = xr.Dataset(
        {"verdict_short": ("traj", old), "verdict_long": ("traj", new),
         "transition": (("short", "long"), table),
         **({"verdict_horizons": (("traj", "horizon"), new_all)} if new_all.ndim == 2 else {})},
        coords={"traj": idx, "short": list(V.NAMES), "long": list(V.NAMES),
                **({"horizon": ("horizon", np.asarray(long_v.horizons))} if new_all.ndim == 2 else {})},
    )
    out.attrs.update(t1_short=icfg.t1, t1_long=long_cfg.t1, n_changed=int((old != new).sum()), n_checked=int(n))
    return out


# ---- progress ---------------------------------------------------------------------------------


class _Bar:
    def __init__(self, total: int, name: str):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("traj"),
            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn(), transient=False,
        )
        self.t0 = time.perf_counter()
        self.progress.start()
        self.task = self.progress.add_task(name, total=total, rate="")

    def update(self, k: int, steps: int = 0):
        dt = max(time.perf_counter() - self.t0, 1e-9)
        self.progress.update(self.task, advance=k, rate=f"{steps / dt:,.0f} traj-steps/s")

    def close(self):
        self.progress.stop()


def _progress(enabled: bool, total: int, name: str):
    return _Bar(total, name) if enabled else None
