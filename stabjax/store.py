"""A chunked, resumable, single-writer result store (zarr) for sweeps.

Layout of a store directory (default ``<out>.zarr`` next to the netCDF output)::

    manifest.json     what is being computed and how far it got (replaced atomically)
    .lock             the writer holding the store: {"pid", "host", "started"} (O_CREAT|O_EXCL)
    data/             zarr group: one array per per-trajectory result (verdict, n_steps, ...), flat
                      over the plan's trajectories (leading dim ``traj`` = N, then the result's
                      trailing dims); zarr chunk = sweep chunk, so chunk i of the sweep is exactly
                      zarr chunk i and no two chunks ever share a zarr chunk

Writes happen in this order: the chunk's arrays (region writes aligned to zarr chunks), then the
manifest, via write-to-temp + ``os.replace``. A process killed at any moment therefore leaves a
manifest that lists only chunks whose data are complete; a chunk whose data were written but not
yet listed is recomputed (to the same values) by the next run. Durability is against process
death (kill -9, OOM); nothing is fsync'ed, so a power cut may lose recent chunks.

The manifest's identity (spec, model source, command-line overrides, effective integrate and
verdict settings, stabjax version) is compared on every resume; any difference is refused with a
message naming what changed. The manifest also records, per finished chunk, the engine that
computed it, where, how long it took and its accepted step count.

Size (~520 lines): the zarr layout, the manifest, the writer lock and the identity checks are one
file format; they change together.
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import shutil
import socket
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from . import identity as I
from .errors import StabjaxError

FORMAT = "stabjax-store/1"
MANIFEST = "manifest.json"
LOCK = ".lock"
DATA = "data"


class StoreError(StabjaxError):
    """The store cannot be used for this run (another writer, a different computation): exit 2."""


class StoreIOError(StabjaxError):
    """Writing the store failed (full disk, no permission): exit 1. Finished chunks are kept."""

    exit_code = 1


# ---- identity: stabjax.identity (the one place a run's identity is computed) --------------------

identity = I.identity
describe_changes = I.describe_changes


# ---- lock --------------------------------------------------------------------------------------


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class Lock:
    """Exclusive writer lock: a file created with O_CREAT|O_EXCL holding pid and host.

    A lock left by a dead process on this host (kill -9) is stale and taken over; one held by a
    live process, or by any process on another host (we cannot tell), refuses the second writer.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.held = False

    def _read(self) -> dict | None:
        try:
            return json.loads(self.path.read_text() or "{}")
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}

    def acquire(self, store: Path):
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        for _ in range(50):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._read()
                if holder is None:
                    continue  # released meanwhile
                if not holder:  # being written this instant by its creator
                    time.sleep(0.05)
                    holder = self._read()
                    if holder is None:
                        continue
                if holder and holder.get("host") == me["host"] and isinstance(holder.get("pid"), int) \
                        and not _pid_alive(holder["pid"]):
                    self._break(holder)
                    continue
                if not holder and self._age() > 10:  # its creator died between creating and writing it
                    self._break(holder)
                    continue
                who = f"pid {holder.get('pid')} on {holder.get('host')}" if holder else "another process"
                raise StoreError(
                    f"{store} is in use by {who} (lock {self.path}, since {holder.get('started', '?') if holder else '?'}); "
                    "wait for it to finish, or use another --out. If that process is gone (another host), "
                    "delete the lock file by hand") from None
            except OSError as exc:
                raise StoreIOError(f"cannot create the lock {self.path}: {exc}") from None
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(me))
            self.held = True
            return
        raise StoreError(f"could not take the lock {self.path} (contended)")

    def _age(self) -> float:
        try:
            return time.time() - self.path.stat().st_mtime
        except OSError:
            return 0.0

    def _break(self, stale: dict):
        # only one process may break a stale lock: otherwise a second breaker could delete the
        # fresh lock the first one has just created
        guard = self.path.with_name(self.path.name + ".break")
        try:
            fd = os.open(guard, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            with contextlib.suppress(OSError):
                if time.time() - guard.stat().st_mtime > 30:  # a breaker died mid-way
                    guard.unlink()
            time.sleep(0.05)
            return
        try:
            os.close(fd)
            if self._read() == stale:
                self.path.unlink(missing_ok=True)
        finally:
            guard.unlink(missing_ok=True)

    def release(self):
        if self.held:
            holder = self._read()
            if holder and holder.get("pid") == os.getpid():
                self.path.unlink(missing_ok=True)
            self.held = False


# ---- the store ---------------------------------------------------------------------------------


def read_manifest(path: Path) -> dict | None:
    mf = Path(path) / MANIFEST
    if not mf.exists():
        return None
    try:
        m = json.loads(mf.read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{mf} is unreadable ({exc}); pass --restart to start the sweep over") from None
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise StoreError(f"{mf} is not a stabjax store manifest; pass --restart to start over, or use another --out")
    return m


def _atomic_json(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps(obj, indent=1))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def stored_batch(path: str | Path) -> int | None:
    """Batch size of an existing store (a resume without --batch-size keeps it)."""
    try:
        m = read_manifest(Path(path))
    except StoreError:
        return None
    return int(m["batch_size"]) if m else None


class ChunkStore:
    """The writer's view of a store: lock held from open to :meth:`close`."""

    def __init__(self, path: str | Path, plan, batch: int, *, overrides: Mapping[str, Any] | None = None,
                 restart: bool = False):
        from .config import versions

        self.path = Path(path)
        self.plan = plan
        self.batch = int(batch)
        self.n = int(plan.size)
        self.n_chunks = -(-self.n // self.batch)
        ident = identity(plan, {"batch_size": self.batch, **(overrides or {})})
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreIOError(f"cannot create the store {self.path}: {exc}") from None
        self.lock = Lock(self.path / LOCK)
        self.lock.acquire(self.path)
        try:
            old = None if restart else read_manifest(self.path)
            refusals, self.version_changes = I.compare(old.get("identity", {}), ident) if old is not None else ([], [])
            if refusals:
                raise StoreError(
                    f"{self.path} holds a run of a different computation ({'; '.join(refusals)}); "
                    "pass --restart to discard it, or use another --out")
            if old is None:
                self._clear()
                self.manifest = {"format": FORMAT, "identity": ident, "batch_size": self.batch,
                                 "n_chunks": self.n_chunks, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                                 "versions": versions(), "arrays": None, "chunks": {}}
                self._save_manifest()
            else:
                self.manifest = old
                self.manifest.setdefault("resumed_with_versions", [])
                v = versions()
                if v != old.get("versions") and v not in self.manifest["resumed_with_versions"]:
                    self.manifest["resumed_with_versions"].append(v)
        except BaseException:
            self.lock.release()
            raise
        self._group = None

    # -- housekeeping
    def _clear(self):
        for p in self.path.iterdir():
            if p.name in (LOCK, LOCK + ".break"):
                continue
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink()

    def discard(self):
        """Delete the data and the manifest (the netCDF file is written); the lock stays until close.
        The manifest goes first: a kill midway leaves a store that starts over, never one whose
        manifest lists chunks whose data are gone."""
        self._group = None
        (self.path / MANIFEST).unlink(missing_ok=True)
        self._clear()

    def _save_manifest(self):
        try:
            _atomic_json(self.path / MANIFEST, self.manifest)
        except OSError as exc:
            raise self._io_error("the manifest", exc) from None

    def _io_error(self, what: str, exc: OSError) -> StoreIOError:
        done = len(self.manifest.get("chunks", {}))
        why = "the disk is full" if exc.errno == errno.ENOSPC else str(exc)
        return StoreIOError(
            f"could not write {what} to {self.path}: {why}. The {done} finished chunk(s) of {self.n_chunks} are kept "
            f"in {self.path}; fix the cause and run the same command to continue")

    def close(self):
        self.lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- state
    def done(self, i: int) -> bool:
        return str(i) in self.manifest["chunks"]

    def pending(self) -> list[int]:
        return [i for i in range(self.n_chunks) if not self.done(i)]

    def complete(self) -> bool:
        return len(self.manifest["chunks"]) == self.n_chunks

    def bounds(self, i: int) -> tuple[int, int]:
        return i * self.batch, min(self.n, (i + 1) * self.batch)

    def steps(self) -> int:
        return int(sum(c.get("steps", 0) for c in self.manifest["chunks"].values()))

    # -- data
    def _data(self):
        import zarr

        if self._group is None:
            self._group = zarr.open_group(self.path / DATA, mode="a")
        return self._group

    def _template(self, res: Mapping[str, np.ndarray]):
        """Create every array from the first finished chunk's keys, dtypes and trailing shapes."""
        from . import verdict as V

        trailing = getattr(V, "TRAILING_DIMS", {})
        g = self._data()
        arrays = {}
        for k, v in res.items():
            v = np.asarray(v)
            names = tuple(trailing.get(k, ())) if len(trailing.get(k, ())) == v.ndim - 1 else \
                tuple(f"{k}_dim{j}" for j in range(v.ndim - 1))
            g.create_array(k, shape=(self.n, *v.shape[1:]), chunks=(self.batch, *v.shape[1:]), dtype=v.dtype,
                           fill_value=0, dimension_names=("traj", *names), overwrite=True)
            arrays[k] = {"dtype": v.dtype.str, "trailing": list(v.shape[1:]), "dims": list(names)}
        self.manifest["arrays"] = arrays
        self._save_manifest()

    def write(self, i: int, res: Mapping[str, np.ndarray], engine: str, info: Mapping[str, Any] | None = None):
        """Store chunk ``i`` (results already trimmed to the chunk's real trajectories)."""
        lo, hi = self.bounds(i)
        try:
            if self.manifest.get("arrays") is None:
                self._template(res)
            arrays = self.manifest["arrays"]
            if set(res) != set(arrays):
                raise StoreError(f"chunk {i} returned results {sorted(res)} but the store holds {sorted(arrays)}")
            g = self._data()
            for k, v in res.items():
                v = np.asarray(v)
                if v.shape != (hi - lo, *arrays[k]["trailing"]):
                    raise StoreError(f"chunk {i}: result {k} has shape {v.shape}, expected {(hi - lo, *arrays[k]['trailing'])}")
                g[k][lo:hi] = v
            entry = {"engine": engine, "steps": int(np.asarray(res["n_steps"]).sum()) if "n_steps" in res else 0}
            entry.update(info or {})
            self.manifest["chunks"][str(i)] = entry
            self._save_manifest()
        except OSError as exc:
            raise self._io_error(f"chunk {i}", exc) from None


def engines_of(manifest: Mapping[str, Any]) -> dict[str, list[list[int]]]:
    """Engine -> runs [first, last] of chunk indices it computed (compact per-chunk record)."""
    by = {}
    for i in sorted(int(k) for k in manifest["chunks"]):
        e = manifest["chunks"][str(i)].get("engine", "?")
        runs = by.setdefault(e, [])
        if runs and runs[-1][1] == i - 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return by


def load_results(path: str | Path, manifest: Mapping[str, Any], *, lazy: bool) -> dict[str, Any]:
    """The per-trajectory arrays of a complete store: dask arrays (``lazy``) or numpy."""
    import zarr

    g = zarr.open_group(Path(path) / DATA, mode="r")
    out = {}
    for k in manifest["arrays"]:
        native = np.dtype(g[k].dtype.char)  # zarr 3 reports '<f8'; netCDF4 warns about explicit byte orders
        if lazy:
            import dask.array as da

            out[k] = da.from_zarr(g[k]).map_blocks(_native, native, dtype=native)
        else:
            out[k] = _native(g[k][...], native)
    return out


def _native(b: np.ndarray, t: np.dtype) -> np.ndarray:
    return b.view(t) if b.dtype.isnative else b.astype(t)


def plan_from_manifest(manifest: Mapping[str, Any]):
    """Rebuild the plan a store was computed for (spec + overrides + effective integrate settings)."""
    from .spec import make_plan

    ident = manifest["identity"]
    plan = make_plan(ident["spec"], t1=ident["overrides"].get("t1"))
    icfg = dataclasses.replace(plan.icfg, **ident["integrate"])
    if icfg != plan.icfg:
        plan = dataclasses.replace(plan, icfg=icfg)
    return plan


def _holder(path: Path) -> dict | None:
    lock = Path(path) / LOCK
    try:
        h = json.loads(lock.read_text() or "{}")
    except (OSError, ValueError):
        return None
    if h.get("host") == socket.gethostname() and isinstance(h.get("pid"), int) and not _pid_alive(h["pid"]):
        return None
    return h


def finished_store(store: str | Path):
    """(manifest, plan) of a complete store that no sweep is writing, for ``stabjax export``."""
    from .errors import ValidationError

    store = Path(store)
    if not store.is_dir():
        raise ValidationError("store", f"not found: {store}")
    m = read_manifest(store)
    if m is None:
        raise ValidationError("store", f"{store} is not a stabjax store (no {MANIFEST})")
    h = _holder(store)
    if h is not None:
        raise StoreError(f"{store} is being written by pid {h.get('pid')} on {h.get('host')}; export it when that sweep ends")
    done = len(m["chunks"])
    if done != m["n_chunks"]:
        raise StoreError(f"{store} is incomplete: {done} of {m['n_chunks']} chunks finished; run the sweep command "
                         "again to finish it")
    return m, plan_from_manifest(m)


__all__ = ["ChunkStore", "StoreError", "StoreIOError", "Lock", "finished_store", "identity", "describe_changes",
           "read_manifest", "load_results", "engines_of", "plan_from_manifest", "stored_batch"]
