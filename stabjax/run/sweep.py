"""Run a sweep plan in chunks of bounded memory, resumable, into a labelled xarray Dataset.

Chunks are blocks of the plan's grid (:class:`stabjax.run.store.Chunking`), padded to one size so the
vmapped solve compiles once per spec. With an output path, each finished chunk is written to a
zarr store (``<out>.zarr``, :mod:`stabjax.run.store`) as it finishes; a killed sweep restarted with the
same command continues from it, and a changed spec, model or command-line override is refused
rather than silently mixed (:mod:`stabjax.plan.identity`). Chunks run in this process or on Dask
workers (:mod:`stabjax.run.distributed`). The dataset's variables are defined in :mod:`stabjax.run.dataset`;
the netCDF file is a copy of the finished store.

The runner is one loop (``_run_chunks``) with two doors: :func:`run_plan` for a plan's whole grid, and
:func:`run_points` for explicit grid points (``Plan.points``), through which an explorer such as the
boundary refinement (:mod:`stabjax.explore.refine`) runs each round: the same engine, chunking, store, resume and
Dask path as a sweep. The progress bar (:mod:`stabjax.run.progress`) and the horizon check
(:mod:`stabjax.run.horizon`) are modules of their own.
"""
from __future__ import annotations

import dataclasses
import os
import platform
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import xarray as xr

from . import dataset as D
from . import derive
from ..fold import stops
from .. import engines
from . import signals
from ..config import setup_jax
from ..engines.base import N_SUMMARY_FIELDS
from ..errors import OutputError, ValidationError
from .outputs import clean_stale_temps, temp_beside, write_reason
from .progress import progress_bar
from ..plan.spec import Plan, check_plan, static_params
from .store import Chunking

DEFAULT_MEMORY_FRACTION = 0.25


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
    _positive_batch(batch_size)
    if batch_size > max_b:
        raise ValidationError(
            "batch_size",
            f"{batch_size} trajectories per chunk need about {batch_size * per / 2**30:.2f} GiB "
            f"(limit {limit / 2**30:.2f} GiB); use at most {max_b}",
        )
    return int(min(batch_size, plan.size))


def _refuse_before_compiling(plan: Plan, batch_size: int | None) -> None:
    """What can be refused without the engine: every trajectory's parameters (``check_plan``) and a batch size
    below one. Resolving the engine compiles its kernel (seconds to tens of seconds for a new model), which a
    spec with ``mu = 0.5`` in its grid should not wait for."""
    if batch_size is not None:
        _positive_batch(batch_size)
    check_plan(plan)


def _positive_batch(batch_size: int) -> None:
    if batch_size < 1:
        raise ValidationError("batch_size", f"must be >= 1, got {batch_size}")


class _Memory:
    """Chunk records kept in memory (a sweep without an output file); the store's interface."""

    def __init__(self, plan: Plan, batch: int, state: Any = None):
        self.plan = plan
        self.chunking = Chunking(plan.shape, batch)
        self.batch, self.n = batch, plan.size
        self.n_chunks = self.chunking.n_chunks
        self.results: dict[str, np.ndarray] = {}
        self.manifest: dict[str, Any] = {"chunks": {}}
        self.state = state  # the mapper's (stabjax.run.derive.prepare): before the first chunk, whose outcomes need it

    def pending(self) -> list[int]:
        return [i for i in range(self.n_chunks) if str(i) not in self.manifest["chunks"]]

    def bounds(self, i: int) -> tuple[int, int]:
        return self.chunking.bounds(i)

    def steps(self) -> int:
        return int(sum(c["steps"] for c in self.manifest["chunks"].values()))

    def chunk_results(self, i: int) -> dict[str, np.ndarray]:
        lo, hi = self.bounds(i)
        return {k: v[lo:hi] for k, v in self.results.items()}

    def write(self, i: int, res: Mapping[str, np.ndarray], engine: str, info: Mapping[str, Any] | None = None):
        lo, hi = self.bounds(i)
        said: list[dict[str, str]] = []
        with derive.keeping(said):
            rec = derive.chunk(self.plan, res, lo, hi, self.state)
        for k, v in rec.items():
            if k not in self.results:
                self.results[k] = np.empty((self.n, *v.shape[1:]), dtype=v.dtype)
            self.results[k][lo:hi] = v
        self.manifest["chunks"][str(i)] = {"engine": engine, "steps": int(np.asarray(res["n_steps"]).sum()),
                                           **(info or {}), **({"warnings": said} if said else {})}

    def dataset(self, said: list[dict[str, str]] | None = None) -> xr.Dataset:
        """The run's dataset; ``said``: what the outcome stage warned before the first chunk (:func:`run_plan`)."""
        return assemble(self.plan, self.results, state=self.state,
                        said=derive.merged(said, derive.said_by_chunks(self.manifest)))

    def close(self):
        pass


PILOT_MIN = 128  # trajectories: the smallest first chunk the recurrence stop learns attractors from
LAZY_ABOVE = 1 << 22  # trajectories: above this, the netCDF file is written from the store chunk by chunk


def chunk_params(plan: Plan, batch: int, i: int) -> dict[str, np.ndarray]:
    """Parameters of chunk ``i`` (:class:`stabjax.run.store.Chunking` of ``batch``), padded with copies of
    its last trajectory to the chunking's size, so that every chunk has the same shapes (one compile
    per spec)."""
    ch = Chunking(plan.shape, batch)
    lo, hi = ch.bounds(i)
    p = plan.params_for(lo, hi)
    if hi - lo < ch.size:
        p = {k: np.concatenate([v, np.repeat(v[-1:], ch.size - (hi - lo), axis=0)]) for k, v in p.items()}
    return p


def solve_chunk(plan: Plan, batch: int, i: int, *,
                progress: Callable[[int, int], None] | None = None) -> tuple[dict[str, np.ndarray], str]:
    """Integrate chunk ``i`` of ``plan``: (per-trajectory results trimmed to the chunk, engine name).

    The one function that computes a chunk, here and on Dask workers, so both give the same numbers.
    """
    delay = os.environ.get("_STABJAX_TEST_CHUNK_SLEEP")  # tests only: widen the window for kill -9
    if delay:
        time.sleep(float(delay))
    signals.wait_in_chunk(i)  # tests only: a signal sent while chunk i is in flight
    lo, hi = Chunking(plan.shape, batch).bounds(i)
    plan = engines.resolve_plan(plan, static=static_params(plan))  # a worker's own plan: resolved (cached) here
    res = engines.solve(plan.engine, plan.integrated, chunk_params(plan, batch, i), plan.icfg, plan.vcfg,
                        static=static_params(plan), progress=progress)
    return {k: np.asarray(v)[: hi - lo] for k, v in res.items()}, plan.engine


def default_store(out: str | Path) -> Path:
    return Path(str(out) + ".zarr")


def run_plan(plan: Plan, out: str | Path | None = None, *, batch_size: int | None = None, progress: bool = False,
             restart: bool = False, keep_partial: bool = False, memory_limit: int | None = None,
             on_chunk: Callable[[int, int], None] | None = None, store: str | Path | None = None,
             overrides: Mapping[str, Any] | None = None, executor=None,
             on_open: Callable[[], None] | None = None, force: bool = False) -> xr.Dataset:
    """Integrate every trajectory of ``plan``; write ``out`` (netCDF) if given and return the Dataset.

    With ``out`` (or ``store``), finished chunks go to a zarr store (:mod:`stabjax.run.store`; default
    ``<out>.zarr``) as they finish: the same call after a kill continues from it, ``restart`` starts
    over, a different computation on the same store is refused, and so is a second writer. After
    ``out`` is written the store is removed unless ``keep_partial``. ``overrides``: the command-line
    settings that are not in the spec (``t1``), recorded in the store's identity. ``executor``: a
    :class:`stabjax.run.distributed.DaskExecutor` to run the chunks on Dask workers (default: here).
    ``on_open``: called once the run goes ahead (the store accepted: every refusal is before it), for what
    the caller says only then, such as which file will be replaced. ``out`` is never the starts file, the model
    or a module loaded (even with ``force``), and an existing file there is replaced only when it is a result of
    this same spec (a re-run) or with ``force=True`` (:func:`stabjax.run.outputs.guard_result`, as ``stabjax
    sweep`` does).
    """
    from . import store as S
    from .outputs import guard_result

    setup_jax()
    if out is not None:
        guard_result(plan, out, force=force)
    _refuse_before_compiling(plan, batch_size)
    plan = engines.resolve_plan(plan, static=static_params(plan))  # once: it sizes the chunks and runs them all

    store_path = Path(store) if store is not None else (default_store(out) if out is not None else None)
    if batch_size is None and store_path is not None and not restart:
        batch_size = S.stored_batch(store_path)  # a resume keeps the chunking it started with
    if batch_size is None and plan.icfg.attractor_stop and plan.size >= 2 * PILOT_MIN:
        # the recurrence stop learns the attractors from the first chunk: an eighth of the run (_run_chunks)
        batch_size = min(choose_batch_size(plan, None, memory_limit), max(PILOT_MIN, -(-plan.size // 8)))
    batch = choose_batch_size(plan, batch_size, memory_limit)  # refuse impossible sizes before touching them
    early: list[dict[str, str]] = []  # what the outcome stage warns, kept in the result (derive.keeping)
    with derive.keeping(early):
        state = derive.prepare(plan)  # templates integrated and checked before the store exists: a refusal leaves nothing
    n = plan.size
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    sink = S.ChunkStore(store_path, plan, batch, overrides=overrides, restart=restart, template_features=state) \
        if store_path is not None else _Memory(plan, batch, state)
    try:
        if on_open is not None:
            on_open()
        run = _run_chunks(plan, sink, batch, progress=progress, on_chunk=on_chunk, executor=executor,
                          overrides=overrides)
        attrs = {**D.run_attrs(**run),
                 **D.engine_attrs(sink.manifest, executor.describe() if executor is not None else "local",
                                  plan.engine_note)}
        if isinstance(sink, _Memory):
            ds = sink.dataset(early)
            ds.attrs.update(attrs)
            return ds
        try:
            sink.finish(attrs, said=early)
        except ValidationError:
            # the whole-set mapper refused every record (too many attractors for the outcome codes): a store of
            # these settings cannot give a result, and a run with others is another computation: none is kept
            if not keep_partial:
                sink.discard()
                sink.close()
                sink.remove_dir()
            raise
        lazy = n > LAZY_ABOVE
        ds = S.open_store(store_path, dask=lazy)  # the netCDF file is a copy of the store (chunk by chunk: lazy)
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
        sink.remove_dir()  # only one it made, and only if empty: a user's file put in the store stays
    if lazy:  # not loaded into memory: read back lazily, chunk by chunk
        return xr.open_dataset(out, engine="netcdf4", chunks={})
    return ds


def once(f: Callable[[], None] | None) -> Callable[[], None]:
    """``f`` (if any) called the first time the result is, never again: an explorer opens a store per round, and
    what its caller says when the run goes ahead (``on_open``) is said at the first."""
    pending = [f] if f is not None else []

    def call() -> None:
        if pending:
            pending.pop()()
    return call


def run_points(plan: Plan, values: np.ndarray, *, store: str | Path | None = None, batch_size: int | None = None,
               progress: bool = False, restart: bool = False, keep_store: bool = False,
               memory_limit: int | None = None, overrides: Mapping[str, Any] | None = None,
               executor=None, on_open: Callable[[], None] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Integrate the plan's samples at explicit grid points ``values`` (P, n_axes) through the same runner as
    :func:`run_plan` (chunks, engine, Dask workers, chunk store, resume): the per-trajectory records, point-major
    (each point's samples contiguous), and the run's record (``engines``, ``steps``, ``wall``, ``batch``,
    ``n_resumed``, ``n_chunks``). An explorer (:mod:`stabjax.explore.refine`) hands each round's points here.

    With ``store`` the chunks go to a chunk store whose identity covers the points (a store of other points is
    refused, the same points resume); it is removed once read unless ``keep_store``. ``on_open``: as for
    :func:`run_plan`, called once the store accepted the run. Without a batch size the
    chunks are a power of two (>= 64) trajectories, so that a shape-compiled engine compiles a few shapes for
    all the rounds of an explorer rather than one per round.
    """
    from . import store as S

    setup_jax()
    values = np.ascontiguousarray(np.asarray(values, float).reshape(-1, len(plan.grid)))
    _refuse_before_compiling(dataclasses.replace(plan, points=values), batch_size)
    plan = dataclasses.replace(engines.resolve_plan(plan, static=static_params(plan)), points=values)
    if batch_size is None and store is not None and not restart:
        batch_size = S.stored_batch(Path(store))  # a resume keeps the chunking it started with
    if batch_size is None:
        b = choose_batch_size(plan, None, memory_limit)
        batch_size = min(max(64, 1 << (b - 1).bit_length()), default_batch(plan)) if _engine(plan).compiles_per_shape \
            else b
    batch = choose_batch_size(plan, batch_size, memory_limit)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}  # the points: in the plan's identity
    sink = S.ChunkStore(store, plan, batch, overrides=overrides, restart=restart) if store is not None \
        else _Memory(plan, batch)
    try:
        if on_open is not None:
            on_open()
        info = _run_chunks(plan, sink, batch, progress=progress, executor=executor, overrides=overrides)
        if isinstance(sink, _Memory):
            results = sink.results
        else:
            results = {k: np.asarray(v) for k, v in S.load_results(sink.path, sink.manifest, lazy=False).items()}
        info["engines"] = sorted({c.get("engine", "?") for c in sink.manifest["chunks"].values()})
        info["n_chunks"] = sink.n_chunks
        if store is not None and not keep_store:
            sink.discard()
    finally:
        sink.close()
    if store is not None and not keep_store:
        sink.remove_dir()
    return results, info


def _run_chunks(plan: Plan, sink, batch: int, *, progress: bool = False,
                on_chunk: Callable[[int, int], None] | None = None, executor=None,
                overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Compute every pending chunk of ``plan`` into ``sink``, here or on the executor's workers, the chunk in
    flight written before a SIGTERM/SIGHUP stops the run: the run's wall time, steps, chunk size and number of
    chunks resumed."""
    t_start = time.perf_counter()
    n = plan.size
    n_chunks = sink.n_chunks  # blocks of the grid of at most `batch` trajectories (store.Chunking)
    pending = sink.pending()
    n_resumed = n_chunks - len(pending)
    bar = progress_bar(progress, n, plan.name, n_chunks)
    try:
        if bar is not None and n_resumed:
            bar.update(sum(sink.bounds(i)[1] - sink.bounds(i)[0] for i in range(n_chunks) if i not in pending),
                       steps=0, chunks=n_resumed)
        steps_run = [0]
        signals.hold()  # SIGTERM/SIGHUP: the chunk in flight is written, then the run stops

        def go(plan: Plan, ids: list[int]):
            if executor is None:
                for i in ids:
                    lo, hi = sink.bounds(i)
                    shown = [0]

                    def within(done, _total, lo=lo, hi=hi, shown=shown):
                        k = min(done, hi - lo) - shown[0]
                        if bar is not None and k > 0:
                            bar.update(k, steps=steps_run[0])
                            shown[0] += k

                    t0 = time.perf_counter()
                    res, eng = solve_chunk(plan, batch, i, progress=within)
                    sink.write(i, res, eng, {"worker": f"{platform.node()}:{os.getpid()}",
                                             "seconds": round(time.perf_counter() - t0, 4)})
                    steps_run[0] += int(res["n_steps"].sum())
                    if bar is not None:
                        bar.update(hi - lo - shown[0], steps=steps_run[0], chunk_done=True)
                    if on_chunk is not None:
                        on_chunk(i, n_chunks)
                    signals.checkpoint()
            else:
                for i, res, eng, info in executor.map_chunks(plan, batch, ids, overrides):
                    lo, hi = sink.bounds(i)
                    sink.write(i, res, eng, info)
                    steps_run[0] += int(res["n_steps"].sum())
                    del res
                    if bar is not None:
                        bar.update(hi - lo, steps=steps_run[0], chunk_done=True)
                    if on_chunk is not None:
                        on_chunk(i, n_chunks)
                    signals.checkpoint()

        if plan.icfg.attractor_stop and plan.icfg.known_attractors is None and n_chunks > 1:
            # the recurrence stop (stabjax.fold.stops): the first chunk runs to t1 and its trajectories make the
            # known attractors of the rest (read back from the sink: a resumed run finds the same ones)
            go(plan, [i for i in pending if i == 0])
            plan = stops.with_known(plan, sink.chunk_results(0))
            pending = [i for i in pending if i != 0]
        go(plan, pending)
    finally:
        signals.release()
        if bar is not None:
            bar.close()
    return dict(wall=time.perf_counter() - t_start, steps=sink.steps(), batch=batch, n_resumed=n_resumed)


def run_spec(spec: Mapping[str, Any] | str | Path, out: str | Path | None = None, *, batch_size: int | None = None,
             progress: bool = False, restart: bool = False, t1: float | None = None, **kw) -> xr.Dataset:
    """Load (if a path), plan and run a sweep spec. See :mod:`stabjax.plan.spec` for the format; ``out`` and
    ``force``: :func:`run_plan` (``out`` is never the spec file read either)."""
    from .outputs import plan_result

    setup_jax()
    plan = plan_result(spec, out, t1=t1, force=bool(kw.get("force", False)), caller="run_spec", kw=kw,
                       runner=run_plan)
    return run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart,
                    overrides={"t1": None if t1 is None else float(t1)}, **kw)


def assemble(plan: Plan, results: Mapping[str, np.ndarray], *, state: Any = None, wall: float = float("nan"),
             steps: int = 0, batch: int = 0, n_resumed: int = 0,
             said: list[dict[str, str]] | None = None) -> xr.Dataset:
    """The Dataset of a plan from its per-trajectory records (every trajectory, flat (N, ...), as
    :func:`stabjax.run.derive.chunk` stores them, or the engines' raw results, whose records are derived
    here): the derive step over all of them, laid out by :func:`stabjax.run.dataset.build`. ``state``: the
    mapper's (:func:`stabjax.run.derive.prepare`; integrated now when not given). ``said``: what the outcome
    stage warned of these records before (the runner's: the mapper's preparation and each chunk's record), else
    None (raw results: what the preparation and the records' derivation warn here); the result's
    ``warnings_json`` holds it and what the mapper warns over every record (:func:`stabjax.run.derive.finish`)."""
    kept: list[dict[str, str]] = []
    with derive.keeping(kept):
        if state is None:
            state = plan.mapper.prepare(plan)
        if "outcome" not in results:  # the engines' results (a whole-set mapper's records are unchanged by it)
            results = derive.chunk(plan, results, 0, plan.size, state)
    derived = derive.finish(plan, results, state)
    # records the runner derived already are derived again here (a whole-set mapper's): said once, by their chunks
    derived.warnings = derive.merged(kept if said is None else said, derived.warnings)
    shape = plan.shape
    ds = D.build(plan, {k: np.asarray(v).reshape(shape + np.shape(v)[1:]) for k, v in results.items()}, derived)
    ds.attrs.update(D.run_attrs(wall=wall, steps=steps, batch=batch, n_resumed=n_resumed))
    return ds


def write(ds: xr.Dataset, out: str | Path) -> Path:
    """Write ``ds`` to ``out`` atomically (temp file of this process + ``os.replace``); dask-backed
    variables are computed and written one chunk at a time, in this thread (bounded memory)."""
    import dask

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(out)  # a run killed while it wrote this file left its temporary file behind
    tmp = temp_beside(out)
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
    """A result file (netCDF) read into memory; a missing file is a ValidationError naming it. The public
    :func:`stabjax.open_result` (:func:`stabjax.present.kit.open_result`) also opens a sweep's chunk store,
    running or finished, and refuses a file that is no stabjax result by name."""
    path = Path(path)
    if not path.exists():
        raise ValidationError("file", f"not found: {path}")
    return xr.load_dataset(path, engine="netcdf4")


def export_store(store: str | Path, out: str | Path) -> xr.Dataset:
    """Write the netCDF file of a finished store (``stabjax export STORE.zarr --out x.nc``): a copy of
    the store's dataset, chunk by chunk, after every chunk was checked against its checksum."""
    from .store import finished_store, open_store

    finished_store(store)
    ds = open_store(store)
    write(ds, out)
    return ds
