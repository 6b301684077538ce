"""Run a sweep plan in chunks of bounded memory, resumable, into a labelled xarray Dataset.

Chunks all have the same size (the last is padded) so the vmapped solve compiles once per
spec. With an output path, each finished chunk is written to a zarr store (``<out>.zarr``,
:mod:`stabjax.store`) as it finishes; a killed sweep restarted with the same command continues
from it, and a changed spec, model or command-line override is refused rather than silently
mixed. Chunks run in this process or on Dask workers (:mod:`stabjax.distributed`).

Size (~550 lines): the run loop, the in-memory and store sinks, dataset assembly and provenance are
the one path from a plan to a dataset; the store itself and the Dask executor are modules of their own.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from . import engines, signals
from . import verdict as V
from .config import setup_jax, versions
from .engine import solve_batch
from .engines.base import N_SUMMARY_FIELDS
from .errors import OutputError, ValidationError
from .outputs import write_reason
from .outcomes import STATUS_ESCAPED
from .spec import Plan, check_plan, jsonable, load_spec, make_plan, static_params

DEFAULT_MEMORY_FRACTION = 0.25
# per-trajectory results that are not classifier summaries
_DOC = {"stopped_at": "time at which the integration of this trajectory ended (t1 unless it stopped early: "
                      "escape, stable fixed point, failure; see stop_reason)",
        "stop_reason": "why the integration ended (stabjax.early): none = ran to t1, escaped, fixed_point = "
                       "reached a stable equilibrium within the solver tolerance (autonomous models), failed",
        "lyapunov": "largest Lyapunov exponent over the feature window (finite-time estimate from the tangent "
                    "dynamics, stabjax.lyapunov); NaN where the solver did not reach t1"}


def _available_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def bytes_per_trajectory(plan: Plan) -> int:
    """Working memory of one trajectory inside a compiled chunk, on the plan's engine."""
    return _engine(plan).bytes_per_trajectory(plan)


def default_batch(plan: Plan) -> int:
    """Chunk size when none is given: the plan's engine's (:meth:`stabjax.engines.Engine.default_chunk`)."""
    return _engine(plan).default_chunk(plan)


def _engine(plan: Plan):
    """The plan's engine; for a plan not yet resolved, the first that accepts it (no translation)."""
    return engines.get(plan.engine or engines.resolve(plan.integrated, plan.icfg).engine)


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


class _Memory:
    """Chunk results kept in memory (a sweep without an output file); the store's interface."""

    def __init__(self, plan: Plan, batch: int):
        self.batch, self.n = batch, plan.size
        self.n_chunks = -(-self.n // batch)
        self.results: dict[str, np.ndarray] = {}
        self.manifest: dict[str, Any] = {"chunks": {}}

    def pending(self) -> list[int]:
        return [i for i in range(self.n_chunks) if str(i) not in self.manifest["chunks"]]

    def bounds(self, i: int) -> tuple[int, int]:
        return i * self.batch, min(self.n, (i + 1) * self.batch)

    def steps(self) -> int:
        return int(sum(c["steps"] for c in self.manifest["chunks"].values()))

    def write(self, i: int, res: Mapping[str, np.ndarray], engine: str, info: Mapping[str, Any] | None = None):
        lo, hi = self.bounds(i)
        for k, v in res.items():
            if k not in self.results:
                self.results[k] = np.empty((self.n, *v.shape[1:]), dtype=v.dtype)
            self.results[k][lo:hi] = v
        self.manifest["chunks"][str(i)] = {"engine": engine, "steps": int(np.asarray(res["n_steps"]).sum()),
                                           **(info or {})}

    def close(self):
        pass


LAZY_ABOVE = 1 << 22  # trajectories: above this, the netCDF file is written from the store chunk by chunk


def chunk_params(plan: Plan, batch: int, i: int) -> dict[str, np.ndarray]:
    """Parameters of chunk ``i``; the last chunk is padded with copies of its last trajectory so every
    chunk has the same shapes (one compile per spec)."""
    lo, hi = i * batch, min(plan.size, (i + 1) * batch)
    p = plan.params_for(lo, hi)
    if hi - lo < batch:
        p = {k: np.concatenate([v, np.repeat(v[-1:], batch - (hi - lo), axis=0)]) for k, v in p.items()}
    return p


def solve_chunk(plan: Plan, batch: int, i: int, *,
                progress: Callable[[int, int], None] | None = None) -> tuple[dict[str, np.ndarray], str]:
    """Integrate chunk ``i`` of ``plan``: (per-trajectory results trimmed to the chunk, engine name).

    The one function that computes a chunk, here and on Dask workers, so both give the same numbers.
    """
    delay = os.environ.get("_STABJAX_TEST_CHUNK_SLEEP")  # tests only: widen the window for kill -9
    if delay:
        time.sleep(float(delay))
    lo, hi = i * batch, min(plan.size, (i + 1) * batch)
    plan = engines.resolve_plan(plan, static=static_params(plan))  # a worker's own plan: resolved (cached) here
    res = engines.solve(plan.engine, plan.integrated, chunk_params(plan, batch, i), plan.icfg, plan.vcfg,
                        static=static_params(plan), progress=progress)
    return {k: np.asarray(v)[: hi - lo] for k, v in res.items()}, plan.engine


def default_store(out: str | Path) -> Path:
    return Path(str(out) + ".zarr")


def run_plan(plan: Plan, out: str | Path | None = None, *, batch_size: int | None = None, progress: bool = False,
             restart: bool = False, keep_partial: bool = False, memory_limit: int | None = None,
             on_chunk: Callable[[int, int], None] | None = None, store: str | Path | None = None,
             overrides: Mapping[str, Any] | None = None, executor=None) -> xr.Dataset:
    """Integrate every trajectory of ``plan``; write ``out`` (netCDF) if given and return the Dataset.

    With ``out`` (or ``store``), finished chunks go to a zarr store (:mod:`stabjax.store`; default
    ``<out>.zarr``) as they finish: the same call after a kill continues from it, ``restart`` starts
    over, a different computation on the same store is refused, and so is a second writer. After
    ``out`` is written the store is removed unless ``keep_partial``. ``overrides``: the command-line
    settings that are not in the spec (``t1``), recorded in the store's identity. ``executor``: a
    :class:`stabjax.distributed.DaskExecutor` to run the chunks on Dask workers (default: here).
    """
    from . import store as S

    setup_jax()
    plan = engines.resolve_plan(plan, static=static_params(plan))  # once: it sizes the chunks and runs them all

    store_path = Path(store) if store is not None else (default_store(out) if out is not None else None)
    if batch_size is None and store_path is not None and not restart:
        batch_size = S.stored_batch(store_path)  # a resume keeps the chunking it started with
    batch = choose_batch_size(plan, batch_size, memory_limit)  # first: refuse impossible sizes before touching them
    check_plan(plan)
    tf = templates_first(plan)  # before the store exists: a refusal leaves nothing behind
    n = plan.size
    n_chunks = -(-n // batch)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    sink = S.ChunkStore(store_path, plan, batch, overrides=overrides, restart=restart) if store_path is not None \
        else _Memory(plan, batch)
    t_start = time.perf_counter()
    try:
        pending = sink.pending()
        n_resumed = n_chunks - len(pending)
        bar = _progress(progress, n, plan.name, n_chunks)
        try:
            if bar is not None and n_resumed:
                bar.update(sum(sink.bounds(i)[1] - sink.bounds(i)[0] for i in range(n_chunks) if i not in pending),
                           steps=0, chunks=n_resumed)
            steps_run = 0
            signals.hold()  # SIGTERM/SIGHUP: the chunk in flight is written, then the run stops
            if executor is None:
                for i in pending:
                    lo, hi = sink.bounds(i)
                    shown = [0]

                    def within(done, _total, lo=lo, hi=hi, shown=shown):
                        k = min(done, hi - lo) - shown[0]
                        if bar is not None and k > 0:
                            bar.update(k, steps=steps_run)
                            shown[0] += k

                    t0 = time.perf_counter()
                    res, eng = solve_chunk(plan, batch, i, progress=within)
                    sink.write(i, res, eng, {"worker": f"{platform.node()}:{os.getpid()}",
                                             "seconds": round(time.perf_counter() - t0, 4)})
                    steps_run += int(res["n_steps"].sum())
                    if bar is not None:
                        bar.update(hi - lo - shown[0], steps=steps_run, chunk_done=True)
                    if on_chunk is not None:
                        on_chunk(i, n_chunks)
                    signals.checkpoint()
            else:
                for i, res, eng, info in executor.map_chunks(plan, batch, pending, overrides):
                    lo, hi = sink.bounds(i)
                    sink.write(i, res, eng, info)
                    steps_run += int(res["n_steps"].sum())
                    del res
                    if bar is not None:
                        bar.update(hi - lo, steps=steps_run, chunk_done=True)
                    if on_chunk is not None:
                        on_chunk(i, n_chunks)
                    signals.checkpoint()
        finally:
            signals.release()
            if bar is not None:
                bar.close()
        wall = time.perf_counter() - t_start
        run_attrs = dict(wall=wall, steps=sink.steps(), batch=batch, n_resumed=n_resumed)
        executor_name = executor.describe() if executor is not None else "local"
        if isinstance(sink, _Memory):
            ds = assemble(plan, sink.results, template_features=tf, **run_attrs)
            _engine_attrs(ds, sink.manifest, executor_name, plan.engine_note)
            return ds
        lazy = n > LAZY_ABOVE
        ds = assemble_store(plan, store_path, sink.manifest, lazy=lazy, executor=executor_name, template_features=tf,
                            **run_attrs)
        ds.attrs["engine_note"] = plan.engine_note
        if not lazy:
            ds = ds.load()
        if out is None:
            return ds
        try:
            write(ds, out)
        except OSError as exc:
            exc = exc.reason if isinstance(exc, OutputError) else exc
            raise S.StoreIOError(f"could not write {out}: {exc}. Every chunk is finished and kept in {store_path}; "
                                 f"write the file with: stabjax export {store_path} --out {out}") from None
        if not keep_partial:
            sink.discard()  # under the lock: a writer waiting for it finds no store, not half of one
    finally:
        sink.close()
    if not keep_partial:
        with contextlib.suppress(OSError):
            store_path.rmdir()
    if lazy:  # not loaded into memory: read back lazily, chunk by chunk
        return xr.open_dataset(out, engine="netcdf4", chunks={})
    return ds


def _engine_attrs(ds: xr.Dataset, manifest: Mapping[str, Any], executor: str, note: str = "") -> None:
    from .store import engines_of

    ds.attrs["engine_note"] = note  # why the plan's engine is not the first choice ("" when it is)
    by = engines_of(manifest)
    ds.attrs["engine"] = ",".join(sorted(by))  # the engines that computed the chunks, resumed ones included
    ds.attrs["engine_chunks_json"] = json.dumps(by)  # engine -> [first, last] chunk runs
    ds.attrs["executor"] = executor


def assemble_store(plan: Plan, store_path: str | Path, manifest: Mapping[str, Any], *, lazy: bool,
                   executor: str = "", wall: float | None = None, steps: int | None = None, batch: int | None = None,
                   n_resumed: int | None = None, template_features: np.ndarray | None = None) -> xr.Dataset:
    """The sweep's Dataset from a complete store (arrays as dask arrays reading the store if ``lazy``)."""
    from .store import load_results

    results = load_results(store_path, manifest, lazy=lazy)
    chunks = manifest["chunks"].values()
    ds = assemble(plan, results,
                  wall=float(sum(c.get("seconds", 0.0) for c in chunks)) if wall is None else wall,
                  steps=int(sum(c.get("steps", 0) for c in chunks)) if steps is None else steps,
                  batch=int(manifest["batch_size"]) if batch is None else batch,
                  n_resumed=0 if n_resumed is None else n_resumed, template_features=template_features)
    _engine_attrs(ds, manifest, executor or "store")
    ds.attrs["store_created"] = manifest.get("created", "")
    return ds


def templates_first(plan: Plan) -> np.ndarray | None:
    """The template feature vectors at every grid point, integrated before any chunk of the sweep, or
    None without templates. Two templates that coincide somewhere are refused here (naming them, the
    point and their distance): otherwise the default ``max_distance`` is zero there and every
    trajectory ends "unclassified" without a word, after the whole run (issue 22, item 6)."""
    from .basin import template_features
    from .outcomes import coinciding_templates

    tf = template_features(plan)
    if tf is None:
        return None
    hit = coinciding_templates(plan.outcomes.decl, tf)
    if hit is not None:
        p, a, b, d = hit
        where = ""
        if plan.grid:
            idx = np.unravel_index(p, tuple(ax.size for ax in plan.grid))
            where = " at " + ", ".join(f"{ax.name} = {np.asarray(ax.values[i]).tolist()}" for ax, i in zip(plan.grid, idx))
        raise ValidationError("outcomes.templates", f"templates {a!r} and {b!r} coincide{where} (feature distance "
                              f"{d:.3g}): they reach the same attractor, so no trajectory there could be told between "
                              "them; drop one, or choose initial conditions in different basins")
    return tf


def run_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, batch_size: int | None = None,
             progress: bool = False, restart: bool = False, t1: float | None = None, **kw) -> xr.Dataset:
    """Load (if a path), plan and run a sweep spec. See :mod:`stabjax.spec` for the format."""
    setup_jax()
    if isinstance(spec, (str, Path)):
        spec = load_spec(spec)
    plan = make_plan(spec, t1=t1)
    return run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart,
                    overrides={"t1": None if t1 is None else float(t1)}, **kw)


# ---- dataset assembly ------------------------------------------------------------------------


def _theory_vars(plan: Plan, chunk: int = 262_144) -> dict[str, tuple[np.ndarray, dict]]:
    # filled in place chunk by chunk (not concatenated): at 10^7 trajectories the theory variables
    # alone are ~0.65 GB, and a concatenation would hold them twice
    full: dict[str, np.ndarray] = {}
    meta: dict[str, dict] = {}
    main = ""

    def put(key, lo, hi, val, dtype):
        if key not in full:
            full[key] = np.empty(plan.size, dtype=dtype)
        full[key][lo:hi] = np.broadcast_to(val, (hi - lo,))

    for lo in range(0, plan.size, chunk):
        hi = min(plan.size, lo + chunk)
        p = plan.system.check(plan.params_for(lo, hi))
        th = plan.system.theory(p)
        main = th.main
        for name, pred in th.predicates.items():
            put(f"theory_{name}", lo, hi, pred.ok, np.int8)
            put(f"margin_{name}", lo, hi, pred.margin, float)
            meta[f"theory_{name}"] = {"long_name": pred.doc, "flag_values": np.array([0, 1], np.int8),
                                      "flag_meanings": "not_guaranteed guaranteed"}
            meta[f"margin_{name}"] = {"long_name": f"signed margin of: {pred.doc} (> 0 inside)"}
        for name, val in th.derived.items():
            put(f"derived_{name}", lo, hi, val, float)
            meta[f"derived_{name}"] = {"long_name": th.derived_doc.get(name, name)}
    out = {k: (v, meta[k]) for k, v in full.items()}
    out["_main"] = (np.array(main), {})
    return out


def assemble(plan: Plan, results: Mapping[str, np.ndarray], *, wall: float = float("nan"), steps: int = 0,
             batch: int = 0, n_resumed: int = 0, template_features: np.ndarray | None = None) -> xr.Dataset:
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
    results = dict(results)
    if not plan.scheme.from_verdicts:
        # the attitude classifier's summaries (verdict, decay exponents, flips) read observable 0 as an
        # error and 1 as a size: they mean nothing for a model with its own outcomes, and are left out
        results = {k: v for k, v in results.items() if k.startswith("feat_") or k not in V.SUMMARY_DOC}
    if "verdict" in results and "solver_status" in results:
        # a trajectory stopped at escape_radius ran away: diverged, not a solver failure
        # (array operations only: in a big sweep these are dask arrays read lazily from the store)
        esc = results["solver_status"] == STATUS_ESCAPED
        v = results["verdict"]
        results["verdict"] = np.where(esc.reshape(esc.shape + (1,) * (v.ndim - 1)), V.DIVERGED, v).astype(v.dtype)
    for k, v in results.items():
        # trailing dims (INTERFACES 2): e.g. verdicts at each horizon, features per observable
        extra = V.TRAILING_DIMS.get(k, ())[: max(v.ndim - 1, 0)]
        extra += tuple(f"{k}_dim{i}" for i in range(len(extra), v.ndim - 1))
        data[k] = ((*dims, *extra), v.reshape(shape + v.shape[1:]), {"long_name": V.SUMMARY_DOC.get(k, _DOC.get(k, k))})
        if "horizon" in extra and "horizon" not in coords:
            coords["horizon"] = ("horizon", V.horizon_times(plan.vcfg, plan.icfg.t0, plan.icfg.t1),
                                 {"long_name": "horizon T: verdicts of the prefix t <= T of each run"})
        if "observable" in extra and "observable" not in coords:
            coords["observable"] = ("observable", list(plan.system.observables)[: v.shape[-1]])
    if "stop_reason" in data:
        from .early import REASONS

        data["stop_reason"][2].update(flag_values=np.arange(len(REASONS), dtype=np.int8), flag_meanings=" ".join(REASONS))
    if "verdict" in data:
        data["verdict"][2].update(flag_values=np.arange(len(V.NAMES), dtype=np.int8), flag_meanings=" ".join(V.NAMES))
    if "solver_status" in results:
        from .basin import dataset_vars

        bdata, bcoords = dataset_vars(plan, results, template_features)
        data.update(bdata)
        coords.update(bcoords)
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


def provenance(plan: Plan) -> dict[str, Any]:
    import jax

    return {
        "system": plan.system.name,
        "sweep_name": plan.name,
        "paper": plan.system.paper,
        "spec_json": json.dumps(jsonable(plan.spec)),
        "fixed_params_json": json.dumps({k: np.asarray(v).tolist() for k, v in plan.fixed.items()}),
        "integrate_json": json.dumps(plan.icfg.__dict__),
        "verdict_json": json.dumps(plan.vcfg.__dict__),
        "fingerprint": plan.fingerprint(),
        "system_ref": str(plan.spec.get("system", plan.system.name)),
        "model_file": str(_model_file(plan)),
        "model_sha256": plan.model_sha256,
        "outcomes_from_verdicts": int(plan.scheme.from_verdicts),
        "versions_json": json.dumps(versions()),
        "git_commit": _git_commit(),
        "device": str(jax.devices()[0].device_kind) + f" x{jax.device_count()}",
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus".strip(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _model_file(plan) -> str:
    from .models import source_file

    f = source_file(plan.system)
    return str(f) if f is not None else ""


def write(ds: xr.Dataset, out: str | Path) -> Path:
    """Write ``ds`` to ``out`` atomically (temp file of this process + ``os.replace``); dask-backed
    variables are computed and written one chunk at a time, in this thread (bounded memory)."""
    import dask

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        with dask.config.set(scheduler="synchronous"):
            ds.to_netcdf(tmp, engine="netcdf4")
        os.replace(tmp, out)
    except (OSError, RuntimeError) as exc:
        # a full disk reaches us from netCDF/HDF5 as ``RuntimeError: NetCDF: HDF error``: say which file
        # failed and the likely reason, not a traceback (exit 1); ``out`` itself is untouched
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OutputError):
            raise
        raise OutputError(out, write_reason(exc, out)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
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
    long_cfg = icfg.replace(t1=icfg.t1 * factor)
    hs = V.horizon_times(plan.vcfg, icfg.t0, icfg.t1)
    long_v = V.bind(plan.vcfg, long_cfg.t0, long_cfg.t1, horizons=list(hs[-(V.MAX_HORIZONS - 1):]))
    plan_long = dataclasses.replace(plan, icfg=long_cfg, vcfg=long_v, engine="")
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
    """A live progress bar on a terminal (rich): trajectories done/total, chunks, rates, elapsed, ETA."""

    def __init__(self, total: int, name: str, chunks: int = 0):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("traj"),
            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn(), transient=False,
        )
        self.t0 = time.perf_counter()
        self.progress.start()
        self.name, self.chunks, self.chunks_done, self.run = name, chunks, 0, 0
        self.task = self.progress.add_task(self._desc(), total=total, rate="")

    def _desc(self) -> str:
        from rich.markup import escape  # the description is read as markup: a name "[x]" must survive

        name = escape(self.name)
        return f"{name} ({self.chunks_done}/{self.chunks} chunks)" if self.chunks else name

    def update(self, k: int, steps: int = 0, chunks: int = 0, chunk_done: bool = False):
        """Advance by ``k`` trajectories; ``chunks``: resumed chunks (not counted in the rates)."""
        dt = max(time.perf_counter() - self.t0, 1e-9)
        self.chunks_done += chunks + int(chunk_done)
        if not chunks:
            self.run += k
        self.progress.update(self.task, advance=k, description=self._desc(),
                             rate=f"{self.run / dt:,.0f} traj/s {steps / dt:,.0f} traj-steps/s")

    def close(self):
        self.progress.stop()


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class _Lines:
    """Progress as plain lines, for output that is not a terminal (a log file, CI).

    A live bar redraws one line with control codes; in a file it is cut off or repeated as
    garbage. This writes one complete line every ``interval`` seconds (and a last one when the
    sweep ends): done/total trajectories, percent, chunks, the rate of this run (resumed chunks
    excluded) and the ETA from that rate, so ``tail -f log`` and a CI log both read well.
    """

    def __init__(self, total: int, name: str, chunks: int = 0, *, interval: float | None = None, stream=None):
        import sys

        self.total, self.name, self.chunks = max(int(total), 1), name, chunks
        self.interval = float(os.environ.get("STABJAX_PROGRESS_INTERVAL", "5")) if interval is None else interval
        self.stream = stream if stream is not None else sys.stderr
        self.done = self.run = self.chunks_done = 0
        self.t0 = self.last = time.perf_counter()

    def line(self) -> str:
        dt = max(time.perf_counter() - self.t0, 1e-9)
        rate = self.run / dt
        left = self.total - self.done
        eta = _clock(left / rate) if rate > 0 else "?"
        chunks = f", {self.chunks_done}/{self.chunks} chunks" if self.chunks else ""
        return (f"{self.name}: {self.done:,}/{self.total:,} traj ({100 * self.done / self.total:.0f}%{chunks}), "
                f"{rate:,.0f} traj/s, elapsed {_clock(dt)}, ETA {eta}")

    def _emit(self):
        print(self.line(), file=self.stream, flush=True)
        self.last = time.perf_counter()

    def update(self, k: int, steps: int = 0, chunks: int = 0, chunk_done: bool = False):
        self.done = min(self.total, self.done + k)
        self.chunks_done += chunks + int(chunk_done)
        if not chunks:
            self.run += k
        if time.perf_counter() - self.last >= self.interval:
            self._emit()

    def close(self):
        self._emit()


def _progress(enabled: bool, total: int, name: str, chunks: int = 0):
    """A live bar on a terminal, plain periodic lines otherwise (see :class:`_Lines`); None if disabled."""
    if not enabled:
        return None
    from rich.console import Console

    return _Bar(total, name, chunks) if Console().is_terminal else _Lines(total, name, chunks)


def export_store(store: str | Path, out: str | Path, *, lazy_above: int = 1 << 22) -> xr.Dataset:
    """Write the netCDF file of a complete store (``stabjax export STORE.zarr --out x.nc``)."""
    from .store import finished_store

    m, plan = finished_store(store)
    ds = assemble_store(plan, store, m, lazy=plan.size > lazy_above)
    write(ds, out)
    return ds
