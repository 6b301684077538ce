"""Sweeps on Dask workers: an existing scheduler (``--scheduler tcp://HOST:PORT``) or a local
cluster of worker processes (``--workers N``).

What is sent to a worker is ``solve chunk i of plan P`` as plain data (the spec dict, the
command-line t1, the effective integrate/verdict settings and the chunk size); the worker plans
the spec itself (once per process: :data:`_PLANS`, keyed by the plan's identity), checks that its
identity (:mod:`stabjax.plan.identity`: spec, settings, parameter values, model files) matches the
client's, and runs :func:`stabjax.run.sweep.solve_chunk`, the same function
and engine choice as a local run, so results are bitwise those of a local run on the same
hardware. Each worker compiles once per spec: its compiled kernels stay cached in the process,
the native engine's C builds are cached on disk (``$STABJAX_CACHE_DIR``), and XLA's compilations
go to JAX's persistent compilation cache (``<cache>/jax``).

Chunks are futures with ``retries=2``; a worker that dies (kill -9, OOM) has its chunk re-run
elsewhere by the scheduler (Dask's ``allowed-failures``). The client is the only writer of the
store: it collects results as chunks complete (:func:`distributed.as_completed`).

Local workers are started by spawning (``distributed.worker.multiprocessing-method: spawn``),
never by forking this process, which has loaded JAX. Threads: every worker runs one chunk at a
time (one Dask thread); the engine inside it uses ``threads`` OS threads, passed with every task and
set on the worker's plan by :func:`stabjax.engines.with_threads` (an engine setting that changes no result).
``workers * threads`` may not exceed this machine's cores unless ``oversubscribe``.
A plan over explicit points (``Plan.points``: a round of :mod:`stabjax.explore.refine`) travels with its points
and runs through :meth:`DaskExecutor.map_chunks` like any plan. On a host with
several GPUs a local cluster runs one worker per device, each seeing only its own
(``CUDA_VISIBLE_DEVICES``).
"""
from __future__ import annotations

import logging
import os
import socket
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from ..errors import StabjaxError, ValidationError
from ..plan import identity as I

_PLANS: dict[str, Any] = {}  # per worker process: plan key -> Plan (so each spec is planned and compiled once)


def cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def cache_dir() -> Path:
    return Path(os.environ.get("STABJAX_CACHE_DIR") or Path.home() / ".cache" / "stabjax")


def _setup_process():
    """Once per worker process: the JAX settings of every entry point (float64) and JAX's persistent
    compilation cache."""
    import jax

    from ..config import setup_jax

    setup_jax()

    if not jax.config.jax_compilation_cache_dir:
        d = cache_dir() / "jax"
        d.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(d))


def payload_for(plan, batch: int, overrides: Mapping[str, Any] | None = None, threads: int | None = None) -> dict:
    """Everything a worker needs to re-plan ``plan`` exactly (plain, picklable data), with the
    plan's identity (:mod:`stabjax.plan.identity`) for the worker to compare its own plan with."""
    from dataclasses import asdict

    from ..plan.spec import jsonable

    return {"spec": jsonable(plan.spec), "t1": (overrides or {}).get("t1"),
            "icfg": {**plan.icfg.__dict__, "settings": dict(plan.icfg.settings)},
            "vcfg": asdict(plan.vcfg), "batch": int(batch), "identity": I.identity(plan), "threads": threads,
            "points": None if plan.points is None else np.asarray(plan.points, float).tolist()}  # explicit points


def _plan_key(payload: Mapping[str, Any]) -> str:
    return I.digest([payload["identity"], payload["icfg"], payload["vcfg"], payload.get("threads"),
                     payload.get("points")])


def worker_plan(payload: Mapping[str, Any]):
    """The payload's plan, planned from its spec in this process (once) and checked against the
    client's identity: a different model file or imported module, stabjax version, or a plan not
    built from its spec is refused, naming what differs."""
    key = _plan_key(payload)
    plan = _PLANS.get(key)
    if plan is None:
        _setup_process()
        from dataclasses import replace

        from ..plan.spec import make_plan

        plan = make_plan(payload["spec"], t1=payload["t1"])
        from .. import engines

        # the engine's threads per worker: an engine setting that changes no result
        plan = replace(plan, icfg=engines.with_threads(replace(plan.icfg, **payload["icfg"]), payload.get("threads")),
                       vcfg=replace(plan.vcfg, **{k: (tuple(v) if isinstance(v, list) else v)  # JSON: lists
                                                  for k, v in payload["vcfg"].items()}))
        if payload.get("points") is not None:  # a plan over explicit grid points (a refinement round)
            plan = replace(plan, points=np.asarray(payload["points"], float))
        theirs, mine = payload["identity"], I.identity(plan)
        refusals, _ = I.compare(theirs, mine)
        host = socket.gethostname()
        if theirs.get("model") != mine.get("model"):
            raise StabjaxError(f"worker {host}: model source {mine['model'].get('file')} differs from the client's "
                               f"({'; '.join(c for c in refusals if c.startswith('model'))}); install the same model "
                               "files on every worker")
        if refusals:
            raise StabjaxError(f"worker {host}: the spec plans to a different run than the client's "
                               f"({'; '.join(refusals)}): different stabjax versions, or a plan not built from its spec")
        _PLANS[key] = plan
    return plan


def run_chunk(payload: Mapping[str, Any], i: int):
    """The task a worker runs: chunk ``i`` of the payload's plan -> (i, results, engine, info)."""
    from .sweep import solve_chunk

    t0 = time.perf_counter()
    plan = worker_plan(payload)
    res, engine = solve_chunk(plan, payload["batch"], i)
    info = {"worker": f"{socket.gethostname()}:{os.getpid()}", "seconds": round(time.perf_counter() - t0, 4)}
    return i, res, engine, info


def _gpu_devices() -> list[str]:
    """Physical ids of the GPUs this process may use (empty on CPU)."""
    import jax

    if jax.default_backend() != "gpu":
        return []
    n = jax.local_device_count()
    visible = [v.strip() for v in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if v.strip()]
    return visible[:n] if visible else [str(i) for i in range(n)]


class DaskExecutor:
    """Run sweep chunks on Dask. Use as a context manager (the cluster and client are closed on exit).

    ``scheduler``: address of an existing scheduler (``tcp://host:8786``) or a scheduler file;
    ``workers``: start a local cluster of that many worker processes instead. ``threads``: native
    engine threads per worker (default: this machine's cores // workers for a local cluster, the
    worker's own default for a remote one).
    """

    def __init__(self, *, scheduler: str | None = None, workers: int | None = None, threads: int | None = None,
                 oversubscribe: bool = False, retries: int = 2, timeout: float = 30.0):
        if (scheduler is None) == (workers is None):
            raise ValidationError("--scheduler", "give either --scheduler ADDRESS or --workers N (not both)")
        if workers is not None and workers < 1:
            raise ValidationError("--workers", f"must be >= 1, got {workers}")
        if threads is not None and threads < 1:
            raise ValidationError("--threads", f"must be >= 1, got {threads}")
        self.scheduler, self.workers, self.threads = scheduler, workers, threads
        self.oversubscribe, self.retries, self.timeout = oversubscribe, retries, timeout
        self.cluster = None
        self.client = None

    # -- lifecycle
    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def start(self):
        import dask
        from distributed import Client

        dask.config.set({"distributed.worker.multiprocessing-method": "spawn"})
        if self.workers is not None:
            self.cluster = self._local_cluster()
            self.client = Client(self.cluster, set_as_default=False, timeout=self.timeout)
        else:
            target = self.scheduler
            kw = {"scheduler_file": target} if not target.startswith(("tcp://", "tls://", "inproc://", "ucx://")) \
                and Path(target).is_file() else {"address": target}
            try:
                self.client = Client(**kw, set_as_default=False, timeout=self.timeout)
            except (OSError, TimeoutError) as exc:
                raise ValidationError("--scheduler", f"cannot reach the Dask scheduler at {target}: {exc}") from None
            self._check_remote_threads()

    def _local_cluster(self):
        from distributed import LocalCluster, Nanny, Scheduler, SpecCluster

        n = self.workers
        gpus = _gpu_devices()
        env = {"OMP_NUM_THREADS": "1"}
        if gpus:
            if n > len(gpus) and not self.oversubscribe:
                raise ValidationError("--workers", f"{n} workers for {len(gpus)} GPU(s): one worker per device "
                                      "(--oversubscribe to share devices)")
            specs = {i: {"cls": Nanny, "options": {"nthreads": 1, "env": {**env, "CUDA_VISIBLE_DEVICES": gpus[i % len(gpus)]}}}
                     for i in range(n)}
            return SpecCluster(workers=specs, scheduler={"cls": Scheduler, "options": {"host": "127.0.0.1",
                                                                                      "dashboard_address": None}},
                               silence_logs=logging.ERROR)
        c = cores()
        threads = self.threads or max(1, c // n)
        if n * threads > c and not self.oversubscribe:
            raise ValidationError("--threads", f"{n} workers x {threads} threads = {n * threads} exceeds the {c} cores "
                                  "of this machine; use fewer, or pass --oversubscribe")
        self.threads = threads  # sent with each task in the plan's [integrate] settings (payload_for)
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, silence_logs=logging.ERROR, env=env)

    def _check_remote_threads(self):
        if self.threads is None:
            return
        info = self.client.scheduler_info()["workers"]
        per_host: dict[str, int] = {}
        for w in info.values():
            per_host[w["host"]] = per_host.get(w["host"], 0) + int(w["nthreads"]) * self.threads
        host_cores = self.client.run(lambda: (socket.gethostname(), cores()))
        by_ip = {}
        for addr, (_, c) in host_cores.items():
            by_ip[info[addr]["host"]] = c
        for host, need in per_host.items():
            if need > by_ip.get(host, need) and not self.oversubscribe:
                raise ValidationError("--threads", f"{need} threads on {host} exceed its {by_ip[host]} cores "
                                      "(Dask threads x --threads); use fewer, or pass --oversubscribe")

    def close(self):
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def describe(self) -> str:
        n = len(self.client.scheduler_info()["workers"]) if self.client is not None else 0
        where = "local cluster" if self.cluster is not None else self.scheduler
        return f"dask ({where}, {n} workers, {self.threads or 'default'} engine threads each)"

    def n_workers(self) -> int:
        return len(self.client.scheduler_info()["workers"])

    def wait_for_workers(self, n: int = 1, timeout: float | None = None):
        self.client.wait_for_workers(n, timeout=timeout or self.timeout)

    # -- work
    def map_chunks(self, plan, batch: int, chunks: Iterable[int], overrides: Mapping[str, Any] | None = None
                   ) -> Iterator[tuple[int, dict[str, np.ndarray], str, dict]]:
        """Submit every chunk; yield (i, results, engine, info) as each completes (any order)."""
        from distributed import as_completed

        chunks = list(chunks)
        if not chunks:
            return
        payload = payload_for(plan, batch, overrides, self.threads)
        futs = [self.client.submit(run_chunk, payload, i, retries=self.retries, pure=False) for i in chunks]
        try:
            for fut in as_completed(futs, loop=self.client.loop):
                try:
                    out = fut.result()
                except StabjaxError:
                    raise
                except Exception as exc:
                    raise StabjaxError(f"a chunk failed on the Dask workers after {self.retries} retries: "
                                       f"{type(exc).__name__}: {exc}") from None
                fut.release()
                yield out
        finally:
            for f in futs:
                if not f.done():
                    f.cancel()
