"""The chunked zarr store: resume, refusal of a changed computation (naming what changed), one writer
at a time, kill -9 of the client, full disk / unwritable store, export, per-chunk engines."""
import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from killing import kill_after_chunks
import xarray as xr

from stabjax.run.sweep import export_store
from stabjax.run import store as S
from clirun import status  # noqa: E402
from stabjax.plan.spec import load_spec, make_plan
from stabjax.run.sweep import open_result, run_plan, run_spec

ROOT = Path(__file__).resolve().parents[2]

TINY = """
system = "monoaxial"
name = "tiny"
[params]
mu = 1.5
[grid]
alpha = {start = 0.3, stop = 1.0, num = 4}
sigma = [1.2, 1.3, 1.4, 1.5]
[integrate]
t1 = 100.0
n_checkpoints = 32
"""


def cli(*args) -> int:
    return status(*args)


@pytest.fixture(scope="module")
def reference():
    """The uninterrupted in-memory run the store's results must equal, bitwise."""
    plan = make_plan(__import__("tomllib").loads(TINY) | {"name": "tiny"})
    return run_plan(plan, None, batch_size=4)


@pytest.fixture
def spec(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    return p


def assert_same(ds, ref):
    assert set(ds.data_vars) == set(ref.data_vars)
    for k in ref.data_vars:
        np.testing.assert_array_equal(ds[k].values, ref[k].values, err_msg=k)


def interrupt_after(k):
    def boom(i, n):
        if i == k - 1:
            raise KeyboardInterrupt
    return boom


def test_resume_is_bitwise_and_records_real_engine(spec, tmp_path, reference):
    out = tmp_path / "r.nc"
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=4, on_chunk=interrupt_after(2))
    store = tmp_path / "r.nc.zarr"
    m = S.read_manifest(store)
    assert sorted(m["chunks"]) == ["0", "1"] and not out.exists()
    assert all(c["engine"] == reference.attrs["engine"] for c in m["chunks"].values())
    # the same call continues from the store (the chunk size is kept without --batch-size)
    ds = run_spec(spec, out, keep_partial=True)
    assert ds.attrs["chunks_resumed"] == 2 and ds.attrs["batch_size"] == 4
    assert_same(ds, reference)
    assert_same(open_result(out), reference)
    assert S.read_manifest(store)["n_chunks"] == 4
    # a fully resumed run records the engines that computed the chunks, not "resumed"
    again = run_spec(spec, out)
    assert again.attrs["chunks_resumed"] == 4 and again.attrs["engine"] == reference.attrs["engine"]
    assert json.loads(again.attrs["engine_chunks_json"]) == {reference.attrs["engine"]: [[0, 3]]}
    assert not store.exists()  # removed once the netCDF file is written (default; --keep-store keeps it)


def test_a_batch_that_follows_the_size_is_not_blamed_on_an_option():
    """A chunk is never larger than the run: a spec change that shrinks the run (shock.directions 32 -> 12) shrinks
    the batch with it, which the refusal must not call a --batch-size the user gave (they gave none)."""
    from stabjax.plan.identity import describe_changes

    old = {"spec": {"shock": {"directions": 32}}, "overrides": {"batch_size": 257}, "size": 257}
    new = {"spec": {"shock": {"directions": 12}}, "overrides": {"batch_size": 97}, "size": 97}
    changes = describe_changes(old, new)
    assert changes == ["spec shock.directions: 32 -> 12", "size: 257 -> 97"]
    # the same run size with another chunk: that is the option
    same = describe_changes({**old, "spec": new["spec"], "size": 97}, new)
    assert same == ["command-line --batch-size: 257 -> 97"]


def test_changed_t1_batch_spec_model_refused(spec, tmp_path, capsys):
    out = tmp_path / "r.nc"
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=4, on_chunk=interrupt_after(1))
    store = tmp_path / "r.nc.zarr"
    before = (store / "manifest.json").read_text()
    # a --t1 given on the command line is part of the identity
    assert cli("sweep", spec, "--out", out, "--t1", 50, "--no-progress", "--no-plot") == 2
    assert "command-line --t1: not given -> 50.0" in " ".join(capsys.readouterr().err.split())
    with pytest.raises(S.StoreError, match="--batch-size: 4 -> 8"):
        run_spec(spec, out, batch_size=8)
    changed = tmp_path / "changed.toml"
    changed.write_text(TINY.replace("t1 = 100.0", "t1 = 100.0\nrtol = 1e-9"))
    assert cli("sweep", changed, "--out", out, "--no-progress", "--no-plot") == 2
    assert "spec integrate.rtol: <unset> -> 1e-09" in " ".join(capsys.readouterr().err.split())
    # the model source: a different hash of the system's file is refused, naming the file
    m = json.loads(before)
    m["identity"]["model"]["sha256"] = "0" * 16
    (store / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(S.StoreError, match=r"model source monoaxial\.py"):
        run_spec(spec, out)
    (store / "manifest.json").write_text(before)
    assert (store / "manifest.json").read_text() == before  # nothing refused touched the store
    # --restart starts over
    ds = run_spec(spec, out, t1=50.0, restart=True)
    assert ds.attrs["chunks_resumed"] == 0 and json.loads(ds.attrs["integrate_json"])["t1"] == 50.0


def test_an_edited_starts_file_is_named_not_hashes(tmp_path, capsys):
    """Before the fix: "(spec sample.__sha256__: 60a5b674... -> 26504872...; parameters: c90d... -> 8a3b...)"."""
    (tmp_path / "starts.csv").write_text("theta0,omega0\n0.1,0.0\n1.0,0.5\n2.0,-1.0\n-1.0,2.0\n")
    spec = tmp_path / "s.toml"
    spec.write_text(f'system = "{ROOT / "examples" / "pendulum" / "model.py"}:Pendulum"\nname = "st"\n'
                    '[sample]\nfrom = "starts.csv"\n[integrate]\nt1 = 20.0\nn_checkpoints = 40\n')
    out = tmp_path / "r.nc"
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=2, on_chunk=interrupt_after(1))
    (tmp_path / "starts.csv").write_text("theta0,omega0\n0.1,0.0\n1.0,0.5\n2.0,-1.5\n-1.0,2.0\n")
    assert cli("sweep", spec, "--out", out, "--no-progress", "--no-plot") == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "(the starts file starts.csv changed since the interrupted run); pass --restart" in err, err
    assert "sha256" not in err and "parameters" not in err


def test_corrupt_manifest_is_a_clear_error(spec, tmp_path):
    out = tmp_path / "r.nc"
    store = tmp_path / "r.nc.zarr"
    store.mkdir()
    (store / "manifest.json").write_text("")
    with pytest.raises(S.StoreError, match="unreadable.*--restart"):
        run_spec(spec, out)
    run_spec(spec, out, restart=True, batch_size=8)
    assert out.exists()


def test_second_writer_refused_and_stale_lock_taken_over(spec, tmp_path):
    plan = make_plan(load_spec(spec))
    path = tmp_path / "s.zarr"
    with S.ChunkStore(path, plan, 4):
        with pytest.raises(S.StoreError, match=f"in use by pid {os.getpid()}"):
            S.ChunkStore(path, plan, 4)
        with pytest.raises(S.StoreError, match="being written"):
            export_store(path, tmp_path / "x.nc")
    assert not (path / S.LOCK).exists()
    # a lock left by a process that died (kill -9) on this host is stale: the next writer takes over
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (path / S.LOCK).write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename, "started": "x"}))
    with S.ChunkStore(path, plan, 4) as st:
        assert json.loads((path / S.LOCK).read_text())["pid"] == os.getpid()
        assert st.pending() == [0, 1, 2, 3]
    # an empty lock (its creator killed between creating and writing it) is stale once old
    (path / S.LOCK).write_text("")
    with pytest.raises(S.StoreError, match="in use by another process"):
        S.ChunkStore(path, plan, 4)
    os.utime(path / S.LOCK, (time.time() - 60, time.time() - 60))
    S.ChunkStore(path, plan, 4).close()
    # a lock held on another host cannot be checked: refused
    (path / S.LOCK).write_text(json.dumps({"pid": 1, "host": "elsewhere", "started": "x"}))
    with pytest.raises(S.StoreError, match="pid 1 on elsewhere"):
        S.ChunkStore(path, plan, 4)


def test_full_disk_keeps_finished_chunks(spec, tmp_path, monkeypatch, capsys, reference):
    """The zarr writer raising ENOSPC at chunk 2 (a full disk): exit 1, a clear message, chunks 0-1 kept."""
    import zarr

    out = tmp_path / "r.nc"
    real = zarr.Array.__setitem__

    def full_from_chunk_2(self, key, value):
        # chunks are rows of the 4 x 4 grid (alpha, sigma): chunk i is the region (i:i+1, 0:4)
        if isinstance(key, tuple) and key and isinstance(key[0], slice) and (key[0].start or 0) >= 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, key, value)

    monkeypatch.setattr(zarr.Array, "__setitem__", full_from_chunk_2)
    assert cli("sweep", spec, "--out", out, "--batch-size", 4, "--no-progress", "--no-plot") == 1
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert "the disk is full" in err and "2 finished chunk(s) of 4 are kept" in err and "Traceback" not in err
    store = tmp_path / "r.nc.zarr"
    assert sorted(S.read_manifest(store)["chunks"]) == ["0", "1"] and not out.exists()
    assert not (store / S.LOCK).exists()
    monkeypatch.setattr(zarr.Array, "__setitem__", real)
    assert cli("sweep", spec, "--out", out, "--no-progress", "--no-plot") == 0
    ds = open_result(out)
    assert ds.attrs["chunks_resumed"] == 2
    assert_same(ds, reference)


def test_unwritable_store_is_a_clear_error(spec, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert cli("sweep", spec, "--out", tmp_path / "r.nc", "--store", blocker / "s.zarr", "--no-progress",
               "--no-plot") == 1
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert "cannot create the store" in err and "Traceback" not in err


def test_export_and_keep_store(spec, tmp_path, reference):
    out = tmp_path / "r.nc"
    assert cli("sweep", spec, "--out", out, "--batch-size", 4, "--keep-store", "--no-progress", "--no-plot") == 0
    store = tmp_path / "r.nc.zarr"
    assert store.is_dir()
    assert cli("export", store, "--out", tmp_path / "x.nc") == 0
    x = open_result(tmp_path / "x.nc")
    assert_same(x, reference)
    assert x.attrs["engine"] == reference.attrs["engine"] and x.attrs["n_trajectories"] == 16
    # the store is the dataset: xr.open_zarr gives the netCDF file's variables and values
    z = xr.open_zarr(store)
    assert set(z.data_vars) == set(x.data_vars) and set(z.coords) == set(x.coords)
    for k in x.variables:
        np.testing.assert_array_equal(z[k].values, x[k].values, err_msg=k)
    assert z.attrs["fingerprint"] == x.attrs["fingerprint"] and z.attrs["total_steps"] == x.attrs["total_steps"]
    # an incomplete store is not exported
    m = S.read_manifest(store)
    del m["chunks"]["3"]
    m["finished"] = False
    (store / "manifest.json").write_text(json.dumps(m))
    assert cli("export", store, "--out", tmp_path / "y.nc") == 2 and not (tmp_path / "y.nc").exists()


def _env(**extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu", STABJAX_THREADS="1")
    env.update(extra)
    return env


def _sweep_cmd(spec, out):
    return [sys.executable, "-m", "stabjax", "sweep", str(spec), "--out", str(out), "--batch-size", "4",
            "--no-progress", "--no-plot"]


@pytest.mark.slow  # two CLI processes (~20 s on 2 busy cores)
def test_client_sigkill_then_rerun(spec, tmp_path, reference):
    out = tmp_path / "k.nc"
    store = tmp_path / "k.nc.zarr"
    p = subprocess.Popen(_sweep_cmd(spec, out), env=_env(_STABJAX_TEST_CHUNK_SLEEP="0.7"), cwd=tmp_path,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    kill_after_chunks(p, store, 1, 90)
    done = len(S.read_manifest(store)["chunks"])
    assert 1 <= done < 4 and not out.exists()
    assert json.loads((store / S.LOCK).read_text())["pid"] == p.pid  # left behind by the killed client
    r = subprocess.run(_sweep_cmd(spec, out), env=_env(), cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    ds = open_result(out)
    assert ds.attrs["chunks_resumed"] == done
    assert_same(ds, reference)


@pytest.mark.slow  # two CLI processes at once (~20 s on 2 busy cores)
def test_two_sweeps_on_one_output_at_once(spec, tmp_path, reference):
    out = tmp_path / "two.nc"
    env = _env(_STABJAX_TEST_CHUNK_SLEEP="1.0")
    procs = [subprocess.Popen(_sweep_cmd(spec, out), env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    try:
        results = [p.communicate(timeout=120) for p in procs]
    finally:
        for p in procs:
            p.kill()
            p.wait(30)
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], results
    refused = " ".join(results[[p.returncode for p in procs].index(2)][1].split())
    assert "is in use by pid" in refused and "Traceback" not in refused
    assert_same(open_result(out), reference)


def test_what_discovery_warns_is_kept_alike_resumed_or_not(tmp_path):
    """A discovery's warnings are the result's (``warnings_json``, stabjax.run.derive.keeping): an interrupted run
    resumed from its store, the netCDF file and `stabjax export` of the store hold what an uninterrupted run's
    dataset holds, and the terminal still hears it."""
    import phase_line
    from stabjax.mapping.discover import UnboundedWarning

    spec = phase_line.spec(1.0)  # x' = x: 20 runaways, counted as 'escaped', said (UnboundedWarning)
    with pytest.warns(UnboundedWarning, match="20 of 20 trajectories grow without bound"):
        said = json.loads(run_spec(spec).attrs["warnings_json"])
    assert len(said) == 1 and said[0]["category"] == "UnboundedWarning"
    assert said[0]["message"].startswith("20 of 20 trajectories grow without bound over the feature window")
    out = tmp_path / "r.nc"
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=10, on_chunk=interrupt_after(1))
    with pytest.warns(UnboundedWarning, match="20 of 20"):
        ds = run_spec(spec, out, keep_partial=True)
    assert ds.attrs["chunks_resumed"] == 1
    assert json.loads(ds.attrs["warnings_json"]) == said
    assert json.loads(open_result(out).attrs["warnings_json"]) == said
    export_store(tmp_path / "r.nc.zarr", tmp_path / "x.nc")
    assert json.loads(open_result(tmp_path / "x.nc").attrs["warnings_json"]) == said


def test_what_a_chunk_warns_is_kept_with_it_for_the_resumed_run(spec, tmp_path, monkeypatch):
    """A per-trajectory mapper's warning is raised with each chunk's outcomes (none of the shipped ones warns):
    it is kept in the chunk's manifest entry, so the resumed run's warnings_json says the first run's chunks'
    too, as the uninterrupted run's does; another library's warning is shown, never kept."""
    import warnings

    from stabjax.mapping.discover import MixedWarning
    from stabjax.mapping.verdicts import Verdicts

    assign = Verdicts.assign

    def warned(self, plan, results, index, state):
        warnings.warn(f"trajectories {index[0]} to {index[-1]}", MixedWarning)
        warnings.warn("a library's word", DeprecationWarning)
        return assign(self, plan, results, index, state)

    monkeypatch.setattr(Verdicts, "assign", warned)
    plan = make_plan(load_spec(spec))
    with pytest.warns(MixedWarning), pytest.warns(DeprecationWarning, match="a library's word"):
        whole = json.loads(run_plan(plan, None, batch_size=4).attrs["warnings_json"])
    assert whole == [{"category": "MixedWarning", "message": f"trajectories {4 * i} to {4 * i + 3}"} for i in range(4)]
    out = tmp_path / "r.nc"
    with pytest.raises(KeyboardInterrupt), pytest.warns(MixedWarning):
        run_spec(spec, out, batch_size=4, on_chunk=interrupt_after(2))
    assert S.read_manifest(tmp_path / "r.nc.zarr")["chunks"]["1"]["warnings"] == whole[1:2]
    with pytest.warns(MixedWarning) as shown:  # the terminal hears what this run computes, as before
        ds = run_spec(spec, out)
    assert [str(w.message) for w in shown if w.category is MixedWarning] == ["trajectories 8 to 11",
                                                                             "trajectories 12 to 15"]
    assert ds.attrs["chunks_resumed"] == 2 and json.loads(ds.attrs["warnings_json"]) == whole
    assert json.loads(open_result(out).attrs["warnings_json"]) == whole


def test_lazy_assembly_for_big_sweeps(spec, tmp_path, monkeypatch, reference):
    """Above LAZY_ABOVE trajectories the netCDF file is written from the store chunk by chunk (dask);
    the file is the same."""
    import stabjax.run.sweep as SW

    monkeypatch.setattr(SW, "LAZY_ABOVE", 0)
    out = tmp_path / "lazy.nc"
    ds = run_spec(spec, out, batch_size=3, keep_partial=True)  # chunks that do not align with the grid's rows
    # a requested size of 3 on rows of 4: blocks of 2 (two per row, balanced), 8 chunks
    m = S.read_manifest(tmp_path / "lazy.nc.zarr")
    assert m["n_chunks"] == 8 and len(m["chunks"]) == 8 and ds.attrs["chunks_resumed"] == 0
    assert ds["verdict"].chunks is not None  # returned lazily, read from the file
    assert_same(ds, reference)
    assert_same(open_result(out), reference)


def test_trailing_dims_are_chunked_with_the_sweep(spec, tmp_path, monkeypatch):
    """Results with trailing dims (e.g. a verdict per horizon) are stored with the dataset's dims then
    theirs, each zarr chunk one sweep chunk (a row of the 4 x 4 grid for a requested size of 5) times
    the whole trailing dims, whatever order the chunks finish in."""
    import zarr

    from stabjax.fold import verdict as V

    monkeypatch.setattr(V, "TRAILING_DIMS", {"verdict": ("horizon",)}, raising=False)
    plan = make_plan(load_spec(spec))
    rng = np.random.default_rng(0)
    h = len(V.horizon_times(plan.vcfg, plan.icfg.t0, plan.icfg.t1))
    full = {"verdict": rng.integers(0, 5, (16, h)).astype(np.int8), "n_steps": rng.integers(0, 99, 16),
            "feat": rng.standard_normal((16, 2))}
    path = tmp_path / "t.zarr"
    with S.ChunkStore(path, plan, 5) as st:
        assert st.n_chunks == 4 and [st.bounds(i) for i in range(4)] == [(0, 4), (4, 8), (8, 12), (12, 16)]
        for i in (3, 0, 2, 1):  # any completion order
            lo, hi = st.bounds(i)
            st.write(i, {k: v[lo:hi] for k, v in full.items()}, "native")
        assert st.complete()
        st.finish({})
    g = zarr.open_group(path, mode="r")
    assert g["verdict"].chunks == (1, 4, h) and g["feat"].chunks == (1, 4, 2)
    assert tuple(g["verdict"].metadata.dimension_names) == ("alpha", "sigma", "horizon")
    ds = S.open_store(path)
    for k, v in full.items():
        np.testing.assert_array_equal(ds[k].values, v.reshape(4, 4, *v.shape[1:]))
    for lazy in (False, True):  # the flat per-trajectory records, for a runner that reads them back
        got = S.load_results(path, S.read_manifest(path), lazy=lazy)
        for k, v in full.items():
            np.testing.assert_array_equal(np.asarray(got[k]), v)


@pytest.mark.parametrize("shape", [(4, 4), (7, 13), (3, 1000), (5, 3, 7), (1, 1), (10,), (2, 9, 1, 5)])
@pytest.mark.parametrize("batch", [1, 3, 4, 16, 40, 100, 10**6])
def test_chunks_are_grid_blocks_that_tile_the_plan(shape, batch):
    """Every chunk is a block of the grid whose flat C-order indices are exactly [lo, hi), of at most
    ``batch`` (and ``size``) trajectories, and the chunks tile the plan once; checked against the
    flat indices of an arange laid out on the grid."""
    ch = S.Chunking(shape, batch)
    flat = np.arange(int(np.prod(shape))).reshape(shape)
    seen = np.zeros(flat.size, int)
    for i in range(ch.n_chunks):
        lo, hi = ch.bounds(i)
        block = flat[ch.region(i)]
        np.testing.assert_array_equal(block.ravel(), np.arange(lo, hi))
        assert block.shape == ch.block_shape(i) and 0 < hi - lo <= min(ch.size, batch)
        assert tuple(r.start // c for r, c in zip(ch.region(i), ch.block)) == ch.chunk_coords(i)
        seen[lo:hi] += 1
    assert (seen == 1).all()
    if flat.size > batch:  # balanced: no more blocks along the split axis than blocks of the largest fitting size
        per = batch // ch.inner
        assert -(-shape[ch.axis] // ch.m) == -(-shape[ch.axis] // per)
