"""Dask execution: a local cluster of spawned workers gives the local run's dataset bitwise, a worker
killed mid-sweep loses nothing, the README's scheduler + workers recipe works on 127.0.0.1, and
workers x threads never oversubscribes the cores unless asked."""
import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from killing import kill_after_chunks

from stabjax.run import distributed as D
from stabjax.run import store as S
from stabjax.errors import StabjaxError, ValidationError
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import open_result, run_plan
from test_store import TINY  # the store tests' 4 x 4 map, resumed here across workers

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def plan():
    return make_plan(tomllib.loads(TINY))


@pytest.fixture(scope="module")
def reference(plan):
    return run_plan(plan, None, batch_size=4)


def assert_same(ds, ref):
    assert set(ds.data_vars) == set(ref.data_vars)
    for k in ref.data_vars:
        np.testing.assert_array_equal(ds[k].values, ref[k].values, err_msg=k)


def test_oversubscription_refused(monkeypatch):
    monkeypatch.setattr(D, "cores", lambda: 2)
    with pytest.raises(ValidationError, match="2 workers x 2 threads = 4 exceeds the 2 cores"):
        D.DaskExecutor(workers=2, threads=2)._local_cluster()
    with pytest.raises(ValidationError, match="--scheduler"):
        D.DaskExecutor(workers=2, scheduler="tcp://127.0.0.1:1")


def test_payload_replans_to_the_same_plan(plan):
    p = D.payload_for(plan, 4, {"t1": None})
    D._PLANS.clear()
    again = D.worker_plan(json.loads(json.dumps(p)))  # plain data survives any serialisation
    assert again.fingerprint() == plan.fingerprint() and again.icfg == plan.icfg and again.vcfg == plan.vcfg
    assert D.worker_plan(p) is again  # planned once per process
    # engine settings travel as plain data; the worker's threads are set on its plan (stabjax.engines.with_threads)
    from dataclasses import replace

    tuned = replace(plan, icfg=plan.icfg.replace(settings={"threads": 2, "lanes": 64}))
    D._PLANS.clear()
    back = D.worker_plan(json.loads(json.dumps(D.payload_for(tuned, 4, {"t1": None}, threads=1))))
    assert dict(back.icfg.settings) == {"threads": 1, "lanes": 64} and back.fingerprint() == plan.fingerprint()
    # a worker whose model file differs from the client's refuses the chunk
    D._PLANS.clear()
    with pytest.raises(StabjaxError, match="model source monoaxial.py differs"):
        D.worker_plan({**p, "identity": {**p["identity"], "model": {**p["identity"]["model"], "sha256": "0" * 64}}})
    # a plan changed in code (not from its spec) would be recomputed differently: refused
    orig = plan.grid[0].values
    plan.grid[0].values = orig + 0.01
    try:
        with pytest.raises(StabjaxError, match="not built from its spec"):
            D.worker_plan(D.payload_for(plan, 4, {"t1": None}))
    finally:
        plan.grid[0].values = orig


@pytest.mark.slow  # starts 2 spawned worker processes (~25 s on 2 busy cores)
def test_local_cluster_same_dataset_and_worker_killed(plan, reference, tmp_path, monkeypatch):
    # each chunk takes >= 1 s on the workers, so a worker can be killed while it holds one
    monkeypatch.setenv("_STABJAX_TEST_CHUNK_SLEEP", "1.0")
    out = tmp_path / "d.nc"
    killed = {}
    with D.DaskExecutor(workers=2, threads=1) as ex:
        ex.wait_for_workers(2)
        ds = run_plan(plan, None, batch_size=4, executor=ex)
        assert_same(ds, reference)  # bitwise: the same engine, the same chunks
        assert ds.attrs["engine"] == reference.attrs["engine"] and "dask" in ds.attrs["executor"]

        # explicit grid points (a refinement round) through the workers: the local engine's values
        from stabjax.run.sweep import run_points

        flat = np.array([15, 0, 7, 3, 9])
        a, b = np.unravel_index(flat, plan.shape)
        values = np.stack([plan.grid[0].values[a], plan.grid[1].values[b]], axis=1)
        got, info = run_points(plan, values, batch_size=2, executor=ex)
        want, _ = run_points(plan, values, batch_size=2)
        assert info["n_chunks"] == 3
        for k in want:
            np.testing.assert_array_equal(got[k], want[k], err_msg=k)
        verdicts = reference["verdict"].values.reshape(-1, got["verdict"].shape[-1])  # (trajectories, horizons)
        np.testing.assert_array_equal(got["verdict"], verdicts[flat])

        done_before = set()

        def kill_busy_worker(i, n):
            if killed:
                return
            done_before.add(i)
            pids = ex.client.run(os.getpid)
            for addr, keys in ex.client.processing().items():
                if keys:
                    os.kill(pids[addr], signal.SIGKILL)
                    killed[addr] = pids[addr]
                    return

        ds2 = run_plan(plan, out, batch_size=4, executor=ex, on_chunk=kill_busy_worker, keep_partial=True)
    assert killed, "no worker was busy after the first chunk"
    assert_same(ds2, reference)
    m = S.read_manifest(tmp_path / "d.nc.zarr")
    assert len(m["chunks"]) == 4
    pid = next(iter(killed.values()))
    after = [c["worker"] for i, c in m["chunks"].items() if int(i) not in done_before]
    assert after and not any(w.endswith(f":{pid}") for w in after)  # the chunk it held was re-run elsewhere
    assert_same(open_result(out), reference)


@pytest.mark.slow  # the README recipe: a scheduler, two workers and the client as separate processes (~40 s)
def test_scheduler_and_two_workers_recipe(tmp_path, reference):
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    sched_file = tmp_path / "scheduler.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu", STABJAX_THREADS="1")
    procs = []
    log = open(tmp_path / "dask.log", "w")
    try:
        procs.append(subprocess.Popen(["dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(sched_file)], env=env, stdout=log, stderr=log))
        deadline = time.time() + 60
        while not sched_file.exists() and time.time() < deadline:
            time.sleep(0.2)
        assert sched_file.exists(), "scheduler did not start"
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen(["dask", "worker", address, "--nworkers", "1", "--nthreads", "1",
                                           "--no-dashboard"], env=env, stdout=log, stderr=log))
        out = tmp_path / "r.nc"
        r = subprocess.run([sys.executable, "-m", "stabjax", "sweep", str(spec), "--scheduler", address, "--out",
                            str(out), "--batch-size", "4", "--threads", "1", "--no-progress", "--no-plot"],
                           env=env, capture_output=True, text=True, timeout=240, cwd=tmp_path)
        assert r.returncode == 0, r.stderr[-3000:]
        ds = open_result(out)
        assert_same(ds, reference)
        assert address in ds.attrs["executor"]
    finally:
        for p in procs[::-1]:
            p.kill()
        for p in procs:
            p.wait(30)
        log.close()


@pytest.mark.slow  # a CLI client with 2 local workers, killed, then run again (~60 s)
def test_dask_client_sigkill_then_rerun(tmp_path, reference):
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    out = tmp_path / "k.nc"
    store = tmp_path / "k.nc.zarr"
    cmd = [sys.executable, "-m", "stabjax", "sweep", str(spec), "--out", str(out), "--batch-size", "2",
           "--workers", "2", "--threads", "1", "--no-progress", "--no-plot"]
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    p = subprocess.Popen(cmd, env={**env, "_STABJAX_TEST_CHUNK_SLEEP": "1.0"}, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, cwd=tmp_path)
    kill_after_chunks(p, store, 2, 120)
    done = len(S.read_manifest(store)["chunks"])
    assert 2 <= done < 8 and not out.exists()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    ds = open_result(out)
    assert ds.attrs["chunks_resumed"] == done
    assert_same(ds, reference)


@pytest.mark.slow  # starts 2 worker processes (~15 s)
def test_one_worker_per_gpu_sees_only_its_device(monkeypatch):
    """The multi-GPU layout, checked on CPU: with two (pretend) devices each worker gets its own
    CUDA_VISIBLE_DEVICES; more workers than devices is refused. (No GPU runs here.)"""
    monkeypatch.setattr(D, "_gpu_devices", lambda: ["3", "5"])
    with pytest.raises(ValidationError, match="one worker per device"):
        D.DaskExecutor(workers=3)._local_cluster()
    with D.DaskExecutor(workers=2) as ex:
        ex.wait_for_workers(2)
        seen = ex.client.run(lambda: os.environ.get("CUDA_VISIBLE_DEVICES"))
    assert sorted(seen.values()) == ["3", "5"]


# ---- in CI (not slow): one spawned local worker shared by the tests below --------------------------------------

REFINE = {"system": "monoaxial", "name": "dask_refine", "params": {"mu": 1.5, "sigma": "4/3"},
          "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": 3}}, "integrate": {"t1": 300.0, "n_checkpoints": 64},
          "refine": {"tol": {"alpha": 0.05}, "pair": ["converged", "*"]}}


@pytest.fixture(scope="module")
def one_worker():
    """A local cluster of one spawned worker with one engine thread (started once for these tests)."""
    with D.DaskExecutor(workers=1, threads=1) as ex:
        ex.wait_for_workers(1)
        yield ex


def test_ci_local_cluster_sweep_is_the_local_sweep(plan, reference, one_worker):
    """A sweep through a Dask worker gives the in-process sweep's dataset bitwise (same engine, same chunks), and
    the worker runs its engine with the executor's thread count. Fails if the payload re-plans differently on the
    worker, chunks come back misplaced, or the threads reach the worker some other way."""
    ds = run_plan(plan, None, batch_size=4, executor=one_worker)
    assert_same(ds, reference)
    assert ds.attrs["engine"] == reference.attrs["engine"] and "dask (local cluster, 1 workers" in ds.attrs["executor"]
    # the worker's engine threads travel with the task, in its plan's [integrate] settings, not in its environment
    assert set(one_worker.client.run(lambda: os.environ.get("STABJAX_THREADS")).values()) == {None}
    threads = one_worker.client.run(lambda: sorted({p.icfg.settings.get("threads") for p in D._PLANS.values()}))
    assert list(threads.values()) == [[1]]


def test_ci_refinement_runs_its_rounds_on_the_workers(one_worker, tmp_path):
    """A refinement's rounds go through the same runner and Dask path as a sweep: the result equals the
    in-process refinement's, and every round's chunks were computed by the worker (the round stores say so)."""
    from stabjax.explore.refine import refine_spec

    local = refine_spec(REFINE)
    out = tmp_path / "r.nc"
    ds = refine_spec(REFINE, out, executor=one_worker, batch_size=4, keep_store=True)
    assert ds.attrs["rounds"] >= 3 and ds.attrs["n_points"] > 3  # the boundary needed refining
    for k in local.data_vars:
        np.testing.assert_array_equal(ds[k].values, local[k].values, err_msg=k)
    pids = set(one_worker.client.run(os.getpid).values())
    for r in range(ds.attrs["rounds"]):
        chunks = S.read_manifest(tmp_path / "r.nc.zarr" / f"round_{r:04d}")["chunks"].values()
        assert chunks and all(int(c["worker"].rsplit(":", 1)[1]) in pids for c in chunks)


def test_ci_dask_client_killed_then_rerun(tmp_path, reference):
    """`stabjax sweep --workers 1` SIGKILLed after 1 of 4 chunks, then the same command: it resumes the stored
    chunks (a dead client's lock is broken) and gives the uninterrupted dataset bitwise."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    out = tmp_path / "k.nc"
    store = tmp_path / "k.nc.zarr"
    cmd = [sys.executable, "-m", "stabjax", "sweep", str(spec), "--out", str(out), "--batch-size", "4",
           "--workers", "1", "--threads", "1", "--no-progress", "--no-plot"]
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    p = subprocess.Popen(cmd, env={**env, "_STABJAX_TEST_CHUNK_SLEEP": "0.5"}, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, cwd=tmp_path)
    kill_after_chunks(p, store, 1, 120)
    done = len(S.read_manifest(store)["chunks"])
    assert 1 <= done < 4 and not out.exists()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    ds = open_result(out)
    assert ds.attrs["chunks_resumed"] == done
    assert_same(ds, reference)
