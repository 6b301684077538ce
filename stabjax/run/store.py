"""The chunk store of a sweep: a zarr group holding the sweep's dataset, filled chunk by chunk.

Layout of a store directory (default ``<out>.zarr`` next to the netCDF output)::

    zarr.json         the zarr group (format 3, consolidated metadata): the dataset's attributes
    <variable>/       one zarr array per variable and coordinate of the sweep's dataset, with the
                      dataset's dims (``xr.open_zarr(store)`` gives the netCDF file's variables)
    manifest.json     the committed chunk record: identity, chunking, the entries above that the
                      store wrote, per finished chunk its engine, worker, time, steps and the
                      sha256 of every array's block, and the sha256 of every other array: the
                      "static" ones written when the store is created (coordinates, samples, the
                      parameters' variables) and the "derived" ones written when it finishes
                      (basin statistics, a classification over the whole sweep), and the sha256 of
                      every zarr.json ("metadata": recorded once the writer has written them, when the
                      store is created and when it finishes) (replaced atomically)
    .lock             the writer holding the store: {"pid", "host", "started"} (O_CREAT|O_EXCL)

Chunks (:class:`Chunking`) are blocks of the dataset's grid -- ``(1, ..., 1, m, full trailing
dims)`` -- so chunk i of the sweep is a contiguous run of flat trajectory indices *and* exactly one
zarr chunk of every per-trajectory variable; no two sweep chunks share a zarr chunk, and a region
write never touches another chunk's data.

Writes happen in this order: the chunk's arrays, then the manifest listing the chunk with its
checksums (write-to-temp + ``os.replace``). The committed chunk record is that file rather than the
group's attributes: zarr rewrites ``zarr.json`` in place, and a kill midway would leave a group no
one can open (the group's metadata is written when the arrays are created, and its attributes are
replaced atomically when the sweep finishes; a store whose metadata cannot be read starts over). A process killed at any moment leaves a manifest that
lists only chunks whose data are complete; a chunk written but not yet listed is recomputed (to the
same values) by the next run. Durability is against process death (kill -9, OOM); nothing is
fsync'ed, so a power cut may lose recent chunks -- and a file of any array lost or damaged afterwards
(a deleted file, a truncated one, a flipped byte) is caught by its checksum: recomputed on resume (a
chunk integrated again, a static array written again from the plan, a derived one computed again
when the sweep finishes), named in an error by ``export``, never read as the fill value. The metadata
too: a chunk's checksum is of the values zarr decodes, blind to an outcome name or attribute changed in a
zarr.json, so each zarr.json has its own; one deleted or changed is named by ``export``, and a resume trusts
nothing read through it: the arrays are created again and every chunk computed again.

A store directory is only ever created, reused when it holds a store of the same computation, or
refused: a directory holding anything else is refused untouched, and ``--restart`` (or removing the
store after the netCDF file is written) deletes only the entries the manifest lists.

The manifest's identity (:mod:`stabjax.plan.identity`) is compared on every resume; any difference is
refused with a message naming what changed (library versions: recorded and reported only).

Size (~1000 lines, over the house's 550): the chunk grid, the zarr layout, the manifest and the
integrity checks are one file format and change together: :class:`ChunkStore` guards one invariant
(a chunk is listed in the manifest only once all its blocks are on disk, an array is read only
against its checksum), with the reads that must honour the same layout (:func:`verify`,
:func:`verify_arrays`, :func:`load_results`, :func:`open_store`); split, the layout would be known in
two places. The writer lock is :mod:`stabjax.run.lock`.
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import os
import socket
import time
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..plan import identity as I
from .lock import Lock, StoreError, StoreIOError, _pid_alive

FORMAT = "stabjax-store/4"  # /3: every array checksummed (the chunks' blocks, "static" and "derived" arrays);
# /4: every zarr.json too (the group's and each array's: attributes, outcome names, dtypes, codecs)
# earlier layouts: their entries besides the manifest (for --restart); None: the manifest lists them itself
OLD_FORMATS = {"stabjax-store/1": ["data"], "stabjax-store/2": None, "stabjax-store/3": None}
MANIFEST = "manifest.json"
LOCK = ".lock"
ROOT = "zarr.json"
REWRITING = "being rewritten"  # the group's zarr.json while finish() replaces it (its checksum is not known yet)
PLACEHOLDER_BYTES = 64 << 20  # per-trajectory arrays up to this size are laid out without Dask (ChunkStore._layout)


# ---- identity: stabjax.plan.identity (the one place a run's identity is computed) --------------------

identity = I.identity
describe_changes = I.describe_changes


# ---- the chunk grid ----------------------------------------------------------------------------


class Chunking:
    """The chunks of a plan of ``shape`` for a requested chunk size ``batch``.

    A chunk is a block ``(1, ..., 1, m, d_{j+1}, ..., d_k)`` of the grid: the innermost axes that
    fit in ``batch`` whole, and ``m`` points of the next one (balanced, so that the last block of a
    row is not a sliver). In C order its trajectories are contiguous, and it is one zarr chunk of
    each per-trajectory array: the store writes whole chunks and nothing else. Every chunk has at
    most ``size`` <= ``batch`` trajectories (the engines compile once, for ``size``); only the
    blocks at the end of axis j are smaller.
    """

    def __init__(self, shape, batch: int):
        self.shape = tuple(int(s) for s in shape)
        self.batch = int(batch)
        self.n = int(np.prod(self.shape)) if self.shape else 1
        if self.n <= self.batch:
            self.axis, self.inner, self.m = None, self.n, 0
            self.block, self.grid, self.size = self.shape, (1,), self.n
        else:
            j, inner = len(self.shape) - 1, 1
            while inner * self.shape[j] <= self.batch:
                inner *= self.shape[j]
                j -= 1
            per = self.batch // inner
            pieces = -(-self.shape[j] // per)
            m = -(-self.shape[j] // pieces)
            self.axis, self.inner, self.m = j, inner, m
            self.block = (1,) * j + (m,) + self.shape[j + 1:]
            self.grid = self.shape[:j] + (-(-self.shape[j] // m),)
            self.size = m * inner
        self.n_chunks = int(np.prod(self.grid))

    def _split(self, i: int) -> tuple[tuple[int, ...], int, int]:
        idx = np.unravel_index(int(i), self.grid)
        j = self.axis
        start = int(idx[-1]) * self.m
        return tuple(int(x) for x in idx[:-1]), start, min(self.shape[j], start + self.m)

    def region(self, i: int) -> tuple[slice, ...]:
        """Chunk ``i`` as slices of the grid."""
        if self.axis is None:
            return tuple(slice(0, s) for s in self.shape)
        outer, start, stop = self._split(i)
        return (tuple(slice(o, o + 1) for o in outer) + (slice(start, stop),)
                + tuple(slice(0, s) for s in self.shape[self.axis + 1:]))

    def block_shape(self, i: int) -> tuple[int, ...]:
        return tuple(r.stop - r.start for r in self.region(i))

    def bounds(self, i: int) -> tuple[int, int]:
        """Chunk ``i`` as the flat trajectory indices [lo, hi)."""
        if self.axis is None:
            return 0, self.n
        outer, start, stop = self._split(i)
        j = self.axis
        o = int(np.ravel_multi_index(outer, self.shape[:j])) if j else 0
        lo = (o * self.shape[j] + start) * self.inner
        return lo, lo + (stop - start) * self.inner

    def chunk_coords(self, i: int) -> tuple[int, ...]:
        """Chunk ``i``'s position in the zarr chunk grid of the plan's dims."""
        if self.axis is None:
            return (0,) * len(self.shape)
        outer, start, _ = self._split(i)
        return outer + (start // self.m,) + (0,) * (len(self.shape) - self.axis - 1)


# ---- the manifest ------------------------------------------------------------------------------


def read_manifest(path: Path, hint: str | None = None) -> dict | None:
    """The store's manifest, None without one; a :class:`StoreError` for one that cannot be used, ending
    with ``hint`` (what the command can do; default: the sweep's ``--restart``)."""
    mf = Path(path) / MANIFEST
    if not mf.exists():
        return None
    try:
        m = json.loads(mf.read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{mf} is unreadable ({exc}); {hint or 'pass --restart to start the sweep over'}") from None
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        old = isinstance(m, dict) and m.get("format") in OLD_FORMATS
        raise StoreError(f"{mf} is {'a store of an earlier stabjax version' if old else 'not a stabjax store manifest'}; "
                         f"{hint or 'pass --restart to start over, or use another --out'}")
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


def _ours_transient(p: Path) -> bool:
    """Files the store writes for an instant (a manifest being replaced) or holds while it runs (the
    lock: only one in the lock's own format, so that another tool's ``.lock`` counts as foreign)."""
    name = p.name
    if name in (LOCK, LOCK + ".break"):
        if name == LOCK + ".break":
            return p.is_file() and p.stat().st_size == 0
        try:
            held = json.loads(p.read_text() or "{}")
        except (OSError, ValueError):
            return False
        return isinstance(held, dict) and (not held or {"pid", "host", "started"} <= set(held))
    return (name.startswith(f".{MANIFEST}.") or name.startswith(f".{ROOT}.")) and name.endswith(".tmp")


def _safe_entry(name: str) -> bool:
    """A manifest entry the store may delete: a plain name inside the store directory."""
    return isinstance(name, str) and name not in ("", ".", "..") and "/" not in name and "\\" not in name \
        and "\0" not in name


def stored_batch(path: str | Path) -> int | None:
    """Batch size of an existing store (a resume without --batch-size keeps it)."""
    try:
        m = read_manifest(Path(path))
    except StoreError:
        return None
    return int(m["batch_size"]) if m else None


def checksum(block: np.ndarray) -> str:
    """sha256 of a block's dtype, shape and bytes (C order), 16 hex digits. Text (a coordinate of names:
    object, unicode or numpy's StringDType, as xarray writes and zarr reads it) by its values, so that the
    sum of what was written equals the sum of what is read back."""
    b = np.asarray(block)
    if b.dtype.kind in "OUT":
        h = hashlib.sha256(f"text{b.shape}".encode())
        h.update(json.dumps([str(x) for x in b.ravel().tolist()]).encode())
        return h.hexdigest()[:16]
    b = np.ascontiguousarray(b)
    h = hashlib.sha256(f"{b.dtype.str}{b.shape}".encode())
    h.update(b.tobytes())
    return h.hexdigest()[:16]


def remove_listed(path: Path, m: Mapping[str, Any], *, manifest: bool = True) -> None:
    """Delete what a store wrote (the manifest ``m``'s entries), the manifest last. First the manifest is
    rewritten to list no chunk and no arrays: a kill midway leaves a store that starts over and recreates
    its arrays, never one whose manifest lists data that are gone."""
    path = Path(path)
    entries = [e for e in m.get("entries", []) if _safe_entry(e)]
    if not m.get("damaged") and (path / MANIFEST).exists():
        _atomic_json(path / MANIFEST, {**m, "arrays": None, "chunks": {}, "finished": False})
    for e in entries:
        if e == MANIFEST:
            continue
        p = path / e
        if p.is_dir() and not p.is_symlink():
            _remove_array(p)
        elif p.exists() or p.is_symlink():
            p.unlink()
    if manifest:
        (path / MANIFEST).unlink(missing_ok=True)


def _zarr_file(rel: tuple[str, ...]) -> bool:
    """A file zarr writes inside an array's folder: its metadata, or a chunk (``c/0/1`` in zarr 3, ``0.1`` or
    ``0/1`` in zarr 2's keys; a 0-d array's one chunk is ``c`` in zarr 3, ``0`` in zarr 2): names of digits,
    nothing else."""
    if len(rel) == 1 and rel[0] in ("zarr.json", ".zarray", ".zattrs", ".zgroup", ".zmetadata", "c"):
        return True
    keys = rel[1:] if rel[0] == "c" else rel
    return bool(keys) and all(k.replace(".", "").isdigit() for k in keys)


def _remove_array(folder: Path) -> None:
    """An array's folder, file by file: what zarr wrote goes, a file a user put there stays (with the folders
    that hold it); a whole-tree delete took the user's file with it."""
    for root, dirs, files in os.walk(folder, topdown=False):
        here = Path(root)
        for f in files:
            if _zarr_file((here / f).relative_to(folder).parts):
                (here / f).unlink()
        for d in dirs:
            with contextlib.suppress(OSError):
                (here / d).rmdir()  # only when emptied (a link, the user's, is never a folder rmdir removes)
    with contextlib.suppress(OSError):
        folder.rmdir()


def rounds_note(folder: str | Path) -> str:
    """For a folder holding the per-round stores of a refinement or a shock search (``round_NNNN``, each with
    its manifest): where its result is, as a clause for a message; else empty."""
    folder = Path(folder)
    try:
        rounds = [d for d in folder.glob("round_[0-9]*") if (d / MANIFEST).is_file()]
    except OSError:
        return ""
    if not rounds:
        return ""
    done = folder.with_name(folder.name[: -len(".zarr")]) if folder.name.endswith(".zarr") else None
    where = f": the search's result is {done}" if done is not None else ""
    return f"; {folder} holds the kept rounds of a refinement or a shock search{where}"


def discard_rounds(base: Path, remove_base: bool) -> None:
    """After a refinement or a shock search has written its result: its per-round stores under ``base``
    (``round_NNNN``), each removed by its own manifest's list, and ``base`` itself if ``remove_base`` and
    empty. Never the whole tree: ``--store`` may name a folder of the user's, whose files stay."""
    base = Path(base)
    for d in sorted(base.glob("round_[0-9]*")):
        if not d.is_dir() or d.is_symlink() or not (d / MANIFEST).is_file():
            continue
        try:
            m = json.loads((d / MANIFEST).read_text())
        except (OSError, ValueError):
            continue  # not a manifest this code can read: the folder is left as it is
        remove_listed(d, m)
        with contextlib.suppress(OSError):
            d.rmdir()
    if remove_base:
        with contextlib.suppress(OSError):
            base.rmdir()


def meta_files(names) -> list[str]:
    """The metadata files of a group holding the arrays ``names``: they carry what the values mean (the
    dataset's attributes, outcome names, and -- in each array's and the group's consolidated copy -- dtypes,
    shapes, fill values and codecs), so a flipped bit in them is as wrong as one in a chunk."""
    return [ROOT, *(f"{k}/{ROOT}" for k in sorted(names))]


def file_sum(path: Path) -> str:
    """sha256 of a file's bytes, 16 hex digits (the metadata files: small, and written whole by one writer)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


@contextlib.contextmanager
def _quiet_zarr():
    """zarr warns that manifest.json and .lock are not zarr nodes, and that consolidated metadata is
    not in the v3 specification yet (xarray and zarr-python read it): neither is the user's concern."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*not recognized as a component of a Zarr hierarchy.*")
        warnings.filterwarnings("ignore", message=".*Consolidated metadata is currently not part.*")
        yield


# ---- the store ---------------------------------------------------------------------------------


class ChunkStore:
    """The writer's view of a store: lock held from open to :meth:`close`.

    ``batch``: the requested chunk size (the chunks are :class:`Chunking` blocks of at most that
    many trajectories); ``overrides``: command-line settings recorded in the identity; ``restart``:
    remove what a previous run of the store wrote (only that) and start over; ``template_features``:
    the plan's, when the caller has integrated them already (a new store records them).
    """

    def __init__(self, path: str | Path, plan, batch: int, *, overrides: Mapping[str, Any] | None = None,
                 restart: bool = False, template_features: np.ndarray | None = None):
        from ..config import versions

        self.path = Path(path)
        self.plan = plan
        self.batch = int(batch)
        self.chunking = Chunking(plan.shape, self.batch)
        self.n = int(plan.size)
        self.n_chunks = self.chunking.n_chunks
        self.version_changes: list[str] = []
        self.repaired: list[str] = []  # chunks found missing or corrupt on open (recomputed)
        self._group = None
        self._tf: Any = False  # template features: not yet known
        self._tf_given = template_features
        self._restarted = False
        ident = identity(plan, {"batch_size": self.batch, **(overrides or {})})
        existed = self.path.is_dir()
        if existed and not restart and not (self.path / MANIFEST).exists():
            self._refuse_foreign()  # before the lock: nothing is created in a directory that is not ours
        self._made_dir = not existed  # a folder the user made (an empty --store DIR) is theirs: never removed
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise StoreError(f"{self.path} exists and is not a directory; choose another --store") from None
        except OSError as exc:
            raise StoreIOError(f"cannot create the store {self.path}: {exc}") from None
        self.lock = Lock(self.path / LOCK)
        self.lock.acquire(self.path)
        try:
            old = self._previous(restart)
            if old is not None:
                since = "the store was written" if old.get("finished") else "the interrupted run"
                refusals, self.version_changes = I.compare(old.get("identity", {}), ident, since)
                if refusals:
                    raise StoreError(
                        f"{self.path} holds a run of a different computation ({'; '.join(refusals)}); "
                        "pass --restart to discard it, or use another --out")
                self.manifest = old
                self._made_dir = bool(old.get("made_dir"))
                self.manifest.setdefault("resumed_with_versions", [])
                v = versions()
                if v != old.get("versions") and v not in self.manifest["resumed_with_versions"]:
                    self.manifest["resumed_with_versions"].append(v)
                self._check_chunks()
            else:
                if not self._restarted:
                    self._refuse_foreign()
                self.manifest = {"format": FORMAT, "identity": ident, "batch_size": self.batch,
                                 "chunking": {"shape": list(self.chunking.shape), "block": list(self.chunking.block)},
                                 "n_chunks": self.n_chunks, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                                 "versions": versions(), "entries": [MANIFEST], "arrays": None, "finished": False,
                                 "made_dir": self._made_dir, "chunks": {}}
                self._save_manifest()
        except BaseException:
            self.lock.release()
            raise

    # -- what is in the directory
    def _refuse_foreign(self):
        foreign = sorted(p.name for p in self.path.iterdir() if not _ours_transient(p))
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
            raise StoreError(f"--store: {self.path} exists and is not a stabjax store (it holds {shown}); nothing in it was "
                             "changed. Use a new or empty directory for --store (or another --out)")

    def _previous(self, restart: bool) -> dict | None:
        """The manifest to resume, or None to start afresh (after --restart removed what the store wrote)."""
        if not restart:
            return read_manifest(self.path)
        try:
            old = read_manifest(self.path)
        except StoreError:
            old = self._damaged_manifest()
        if old is not None:
            self._made_dir = bool(old.get("made_dir"))  # unknown (an earlier version, a damaged manifest): kept
            self._remove_entries(old)
            self._restarted = True  # a store of ours: what else a user put in it stays, and is no reason to refuse
        return None

    def _damaged_manifest(self) -> dict:
        """What a store with an unreadable manifest wrote, for --restart: the manifest itself and the
        zarr group marked as a stabjax store. Anything else in the directory refuses the restart
        (it cannot be told from a user's files), before anything is removed."""
        mf = self.path / MANIFEST
        try:
            m = json.loads(mf.read_text())
        except (OSError, ValueError):
            m = None  # our writes are atomic: a damaged manifest was cut short by hand or by the disk
        if isinstance(m, dict) and m.get("format") in OLD_FORMATS:
            listed = OLD_FORMATS[m["format"]]
            if listed is None:  # a manifest listing what it wrote: the rest of the directory is told apart
                listed = [e for e in m.get("entries") or [] if isinstance(e, str) and e != MANIFEST]
                return {"entries": [MANIFEST, *listed], "damaged": True}
            entries = [MANIFEST, *listed]
        elif m is not None:
            raise StoreError(f"{mf} is not a stabjax store manifest: {self.path} is not a store, and nothing in it "
                             "was removed; use another --store")
        else:
            entries = [MANIFEST] + self._zarr_entries()
        foreign = sorted(p.name for p in self.path.iterdir() if p.name not in entries and not _ours_transient(p))
        if foreign:
            raise StoreError(f"{self.path}: the manifest is unreadable and the directory also holds "
                             f"{', '.join(foreign[:5])}; nothing was removed. Remove the store by hand, or use "
                             "another --store")
        return {"entries": entries, "damaged": True}

    def _zarr_entries(self) -> list[str]:
        try:
            root = json.loads((self.path / ROOT).read_text())
        except (OSError, ValueError):
            return []
        if not isinstance(root, dict) or root.get("attributes", {}).get("stabjax_store") not in (FORMAT, *OLD_FORMATS):
            return []
        children = (root.get("consolidated_metadata") or {}).get("metadata") or {}
        return [ROOT] + sorted({k.split("/")[0] for k in children})

    def _remove_entries(self, m: Mapping[str, Any], *, manifest: bool = True):
        """Delete what the store wrote (the manifest's entries), the manifest last. First the manifest
        is rewritten to list no chunk and no arrays: a kill midway leaves a store that starts over and
        recreates its arrays, never one whose manifest lists data that are gone."""
        self._group = None
        remove_listed(self.path, m, manifest=manifest)

    def discard(self):
        """Delete what the store wrote (the netCDF file is written); the lock stays until close, and
        anything else a user put in the directory stays."""
        self._remove_entries(self.manifest)

    def remove_dir(self):
        """After :meth:`discard` and :meth:`close`: the store's directory, if a store made it and it is empty
        (a folder the user made for ``--store``, or one they put files in, stays)."""
        if self._made_dir:
            with contextlib.suppress(OSError):
                self.path.rmdir()

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
        return self.chunking.bounds(i)

    def steps(self) -> int:
        return int(sum(c.get("steps", 0) for c in self.manifest["chunks"].values()))

    def chunk_results(self, i: int) -> dict[str, np.ndarray]:
        """The stored records of finished chunk ``i`` (flat over its trajectories)."""
        lo, hi = self.bounds(i)
        return {k: np.asarray(v[lo:hi]) for k, v in load_results(self.path, self.manifest, lazy=True).items()}

    # -- integrity
    def _check_chunks(self):
        """Every array the store holds against its checksums: a finished chunk whose block of some array
        is missing or differs is dropped from the manifest (computed again); a damaged static array
        (coordinates, samples, the parameters' variables) is written again from the plan; a damaged
        derived one (basin statistics, a classification over the whole sweep) is computed again when
        the sweep finishes. Each is said in a :class:`StoreWarning`; a store whose metadata (a zarr.json)
        is missing or changed starts over: its arrays are written again and every chunk computed again."""
        if self.manifest.get("arrays") is None:
            return
        damaged = verify_metadata(self.path, self.manifest)
        try:
            if not damaged:
                bad = verify(self.path, self.manifest)
                broken = verify_arrays(self.path, self.manifest)
        except StoreError as exc:  # metadata that zarr cannot open although its checksums hold
            damaged = {"": str(exc)}
        if damaged:
            self._start_over(metadata_problem(damaged))
            return
        if not bad and not broken:
            return
        for i, why in sorted(bad.items()):
            del self.manifest["chunks"][str(i)]
        static = sorted(k for k in broken if k in (self.manifest.get("static") or {}))
        derived = sorted(k for k in broken if k not in static)
        for k in derived:
            del self.manifest["derived"][k]
        self.manifest["finished"] = False
        self._save_manifest()
        if static:
            if "template_features" in static:  # not read back: integrated again (or the caller's)
                from . import dataset as D

                self._tf = self._tf_given if self._tf_given is not None else D.template_features(self.plan)
            try:
                self._rewrite_static(static)
            except OSError as exc:
                raise self._io_error(", ".join(static), exc) from None
            self._save_manifest()
        said = [f"chunk {i}: {why}" for i, why in sorted(bad.items())] + [broken[k] for k in static + derived]
        self.repaired.extend(said)
        parts = []
        if bad:
            parts.append(f"{len(bad)} finished chunk(s) are missing or damaged and are computed again")
        if static:
            parts.append(f"{', '.join(static)} {'was' if len(static) == 1 else 'were'} written again from the spec")
        if derived:
            parts.append(f"{', '.join(derived)} {'is' if len(derived) == 1 else 'are'} computed again at the end")
        warnings.warn(f"{self.path}: {'; '.join(parts)} ({'; '.join(said[:5])}{' ...' if len(said) > 5 else ''})",
                      StoreWarning, stacklevel=3)

    def _start_over(self, why: str):
        """The store's metadata cannot be trusted, so neither can anything read through it: the manifest
        lists no arrays and no chunk (the first chunk written creates the arrays again, removing what the
        store wrote before), said in one warning."""
        n = len(self.manifest["chunks"])
        self.manifest.update(arrays=None, chunks={}, static=None, derived=None, metadata=None, finished=False)
        self._save_manifest()
        self.repaired.append(why)
        again = f" and its {n} finished chunk(s) are computed again" if n else ""
        warnings.warn(f"{self.path}: {why}: the store's arrays are written again{again}", StoreWarning, stacklevel=4)

    # -- data
    def _data(self):
        import zarr

        if self._group is None:
            with _quiet_zarr():
                self._group = zarr.open_group(self.path, mode="r+", zarr_format=3)
        return self._group

    def template_features(self):
        """The plan's template features: read back from the store when it has them (a resume
        classifies with the very numbers the first chunks used), else integrated now."""
        if self._tf is False:
            if self.manifest.get("arrays") is not None and "template_features" in self.manifest.get("entries", []):
                tf = np.asarray(self._data()["template_features"][...])
                self._tf = tf.reshape(-1, *tf.shape[-2:])
            elif self._tf_given is not None:
                self._tf = self._tf_given
            else:
                self._tf = self.plan.mapper.prepare(self.plan)
        return self._tf

    def _layout(self, records: Mapping[str, tuple[np.dtype, tuple[int, ...]]]):
        """The store's dataset before any chunk: the per-trajectory records (name -> dtype, trailing
        shape) as placeholders, the basin statistics too; the coordinates and the variables of the
        parameters alone (the "static" arrays) with their values.

        The placeholders are numpy arrays of zarr's fill value (NaN, 0) when they fit in
        ``PLACEHOLDER_BYTES``: zarr writes no chunk equal to its fill value, so nothing of them reaches
        the disk, and nothing needs Dask (whose array module takes ~0.7 s of CPU to import). Above, they
        are lazy Dask arrays, never computed (no memory). The arrays' metadata is the same either way."""
        from . import dataset as D
        from . import derive

        shape, block = self.chunking.shape, self.chunking.block
        n = int(np.prod(shape)) if shape else 1
        size = sum(n * int(np.prod(t)) * np.dtype(dt).itemsize for dt, t in records.values())
        if size <= PLACEHOLDER_BYTES:
            def empty(full, dtype, chunks=None):
                return np.full(full, np.nan if np.dtype(dtype).kind in "fc" else 0, dtype=dtype)
        else:
            import dask.array as da

            def empty(full, dtype, chunks=None):
                return da.empty(full, chunks=chunks or full, dtype=dtype)
        holders = {k: empty(shape + tuple(t), np.dtype(dt), block + tuple(t)) for k, (dt, t) in records.items()}
        ds = D.build(self.plan, holders, derive.initial(self.plan, self.template_features(), empty=empty))
        ds.attrs.update(stabjax_store=FORMAT, stabjax_complete=0)
        for k in [k for k, v in ds.variables.items() if v.dtype.kind == "U"]:  # zarr 3: variable-length strings
            ds[k] = ds[k].astype(object)                                      # have a spec, fixed-length not yet
        return ds

    def _static_names(self, ds) -> list[str]:
        """The variables of the layout written with their values when the store is created."""
        lazy = set(self.manifest.get("arrays") or {}) | self._basin_names()
        return sorted(str(k) for k in ds.variables if k not in lazy)

    def _basin_names(self) -> set[str]:
        """The basin statistics the layout holds as placeholders (none for a whole-set mapper: added at the end)."""
        from . import dataset as D
        from .derive import BASIN_STATS

        if not self.plan.n_sample or self.plan.mapper.whole_set:
            return set()
        return set(D.basin_vars(self.plan, dict.fromkeys(BASIN_STATS)))

    def _create(self, rec: Mapping[str, np.ndarray]):
        """Create the dataset's arrays (from the first chunk's keys, dtypes and trailing shapes): the
        coordinates and the variables that depend on the parameters only are written now (and their
        checksums recorded: the manifest's ``static``), the per-trajectory ones are filled chunk by
        chunk, the basin statistics at the end."""
        shape, block = self.chunking.shape, self.chunking.block
        ds = self._layout({k: (v.dtype, v.shape[1:]) for k, v in rec.items()})
        names = [ROOT, *sorted(str(k) for k in ds.variables)]
        # write-ahead: the manifest lists every entry before it exists, so --restart can remove them
        leftovers = [e for e in self.manifest["entries"] if e != MANIFEST]  # of a creation killed midway
        if leftovers:
            self._remove_entries({"entries": leftovers, "damaged": True}, manifest=False)
        self.manifest["entries"] = [MANIFEST, *names]
        self._save_manifest()
        nd = len(shape)
        enc = {k: {"chunks": block + tuple(v.shape[nd:])} for k, v in ds.variables.items()
               if nd and v.dims[:nd] == self.plan.dims}
        if "outcome" in rec and self._basin_per_chunk():  # basin statistics: one zarr chunk per sweep chunk's grid points
            for k in self._basin_names():
                enc[k] = {"chunks": block[:-1] + tuple(ds[k].shape[nd - 1:])}
        # zarr skips a chunk equal to its fill value: the placeholders write nothing, and a chunk of a static array
        # holding only the fill value has no file (read back, it is that value: its checksum holds)
        with _quiet_zarr():
            # lazy placeholders are never computed (compute=False); with numpy ones there is nothing to defer, and
            # xarray then needs no dask.delayed
            lazy = any(not isinstance(v.data, np.ndarray) for v in ds.variables.values())
            ds.to_zarr(self.path, mode="a", compute=not lazy, zarr_format=3, consolidated=True, encoding=enc)
        self._group = None
        self.manifest["arrays"] = {k: {"dtype": v.dtype.str, "trailing": list(v.shape[1:]),
                                       "dims": list(ds[k].dims[nd:])} for k, v in rec.items()}
        self.manifest["variables"] = [str(k) for k in ds.data_vars]  # the dataset's order (zarr lists names sorted)
        self.manifest["static"] = self._sums(self._static_names(ds))
        self.manifest["derived"] = {}
        self.manifest["metadata"] = self._meta_sums(ds.variables)  # as xarray and zarr left them: complete now
        self._save_manifest()

    def _meta_sums(self, names) -> dict[str, str]:
        return {f: file_sum(self.path / f) for f in meta_files(str(k) for k in names)}

    def _sums(self, names) -> dict[str, str]:
        """The checksums of whole arrays of the group, as they read back."""
        g = self._data()
        return {k: checksum(g[k][...]) for k in names}

    def _rewrite_static(self, names: list[str]):
        """Write the static arrays ``names`` again from the plan (they hold the parameters' values alone:
        the same numbers as when the store was created) and record their checksums."""
        arrays = self.manifest["arrays"]
        ds = self._layout({k: (np.dtype(a["dtype"]), tuple(a["trailing"])) for k, a in arrays.items()})
        g = self._data()
        for k in names:
            g[k][...] = np.asarray(ds[k].values)
        self.manifest["static"].update(self._sums(names))

    def _basin_per_chunk(self) -> bool:
        """Whether each chunk holds every sample of its grid points (the sample axis is not split)."""
        ax = self.chunking.axis
        return bool(self.plan.n_sample) and (ax is None or ax < len(self.chunking.shape) - 1)

    def write(self, i: int, res: Mapping[str, np.ndarray], engine: str, info: Mapping[str, Any] | None = None):
        """Store chunk ``i`` (the engine's results, trimmed to the chunk's trajectories): its record
        (:func:`stabjax.run.derive.chunk`: verdicts, outcome) into the arrays, then the manifest
        entry with the checksum of every array's block."""
        import zarr

        from . import dataset as D
        from . import derive

        lo, hi = self.bounds(i)
        said: list[dict[str, str]] = []
        with derive.keeping(said):  # what the outcome stage warns: kept with the chunk, for the result's warnings_json
            rec = derive.chunk(self.plan, res, lo, hi, self.template_features())
        try:
            if self.manifest.get("arrays") is None:
                self._create(rec)
            arrays = self.manifest["arrays"]
            if set(rec) != set(arrays):
                raise StoreError(f"chunk {i} returned results {sorted(rec)} but the store holds {sorted(arrays)}")
            region, block = self.chunking.region(i), self.chunking.block_shape(i)
            g = self._data()
            sums = {}
            with zarr.config.set({"array.write_empty_chunks": True}):  # every chunk has its file: a missing one is lost
                for k, v in rec.items():
                    trailing = tuple(arrays[k]["trailing"])
                    if v.shape != (hi - lo, *trailing):
                        raise StoreError(f"chunk {i}: result {k} has shape {v.shape}, expected {(hi - lo, *trailing)}")
                    b = v.reshape(block + trailing).copy(order="C")  # ascontiguousarray makes a 0-d block 1-d
                    g[k][region + (slice(None),) * len(trailing)] = b
                    sums[k] = checksum(b)
                if "outcome" in rec and self._basin_per_chunk():
                    # a reader of the running store sees the statistics of every finished grid point (the
                    # chunk holds all its samples); finish() computes them all again from the stored outcomes
                    stats = derive.basin(self.plan, rec["outcome"].reshape(block))
                    for k, (_, values, _) in D.basin_vars(self.plan, stats).items():
                        g[k][region[:-1] + (slice(None),)] = values
            entry = {"engine": engine, "steps": int(np.asarray(res["n_steps"]).sum()) if "n_steps" in res else 0}
            entry.update(info or {})
            if said:
                entry["warnings"] = said
            entry["sha256"] = sums
            self.manifest["chunks"][str(i)] = entry
            self._save_manifest()
        except OSError as exc:
            raise self._io_error(f"chunk {i}", exc) from None

    def finish(self, attrs: Mapping[str, Any], said: list[dict[str, str]] | None = None):
        """After the last chunk: the variables that need every trajectory (the derive step over the stored
        outcomes, or a whole-set mapper over the stored records: basin statistics, entropy, ...) and the
        run's attributes (wall time, steps, engines); the store then reads as the finished dataset. Its
        ``warnings_json``: what the outcome stage warned before the first chunk (``said``: the mapper's
        preparation, done again by every run), with each chunk (kept in the manifest: a chunk of an interrupted
        run says it still) and now (a whole-set mapper: run again on every finish), each once."""
        from . import dataset as D
        from . import derive

        if not self.complete():
            raise StoreError(f"{self.path}: {len(self.manifest['chunks'])} of {self.n_chunks} chunks finished")
        try:
            if self.manifest.get("arrays") is None:  # a plan with no trajectory cannot happen; be explicit
                raise StoreError(f"{self.path} has no arrays")
            g = self._data()
            arrays = self.manifest["arrays"]
            # the group's zarr.json is rewritten below (attributes; new arrays in its consolidated metadata): a
            # kill before its new checksum is recorded leaves a store whose metadata is known to be unverified
            self.manifest["metadata"][ROOT] = REWRITING
            self.manifest["finished"] = False
            self._save_manifest()
            derived = None
            if "outcome" in arrays or "solver_status" in arrays:
                # stored outcomes (a per-trajectory mapper), or the whole-set mapper over every stored record
                records = {"outcome": np.asarray(g["outcome"][...]).reshape(-1)} if "outcome" in arrays \
                    else load_results(self.path, self.manifest)
                derived = derive.finish(self.plan, records, self.template_features(), with_theory=False)
                data, coords = D.outcome_vars(self.plan, derived, derived.mapped.codes.reshape(self.plan.shape))
                held = set(self.manifest.get("variables", [])) & set(g.array_keys())
                for k in held & set(data):  # placeholders since the store's creation; or written by an earlier
                    values = np.asarray(data[k][1])  # finish and damaged since (a resume computes them again)
                    g[k][...] = values.astype(object) if values.dtype.kind == "U" else values
                added = {k: v for k, v in data.items() if k not in held}
                if added:  # what needs every outcome (starts-file agreement, basin entropy; a whole-set mapper's all)
                    self._add_vars(added, coords)
            told = derive.merged(said, derive.said_by_chunks(self.manifest), derived.warnings if derived is not None else None)
            _set_root_attrs(self.path, {**attrs, **derive.warnings_attr(told), "stabjax_complete": 1})
            # everything else the store holds (basin statistics, a classification over the whole sweep):
            # checksummed as written, so that export and a resume read nothing else
            made = set(self.manifest.get("static") or {}) | set(self.manifest["arrays"])
            self.manifest["derived"] = self._sums(sorted(set(self._data().array_keys()) - made))
            self.manifest["metadata"] = self._meta_sums(made | set(self.manifest["derived"]))
            self.manifest["finished"] = True
            self._save_manifest()
        except OSError as exc:
            raise self._io_error("the dataset's statistics", exc) from None


    def _add_vars(self, data: Mapping[str, tuple], coords: Mapping[str, tuple]):
        """Variables known only when every chunk is in (:func:`stabjax.run.dataset.outcome_vars`: a
        whole-set mapper's outcomes; what needs every outcome code), written as new arrays of the group, listed in the
        manifest first and placed in the dataset's order as :func:`stabjax.run.dataset.build` places them."""
        import xarray as xr

        from . import dataset as D

        extra = xr.Dataset(dict(data), coords=dict(coords))
        D.cf_attributes(extra, self.plan)
        # xarray's append replaces the group's attributes with these: keep the dataset's
        extra.attrs = json.loads((self.path / ROOT).read_text()).get("attributes", {})
        for k in [k for k, v in extra.variables.items() if v.dtype.kind == "U"]:
            extra[k] = extra[k].astype(object)
        names = [k for k in extra.variables if k not in self.manifest["entries"]]
        self.manifest["entries"] = [*self.manifest["entries"], *names]
        order = [v for v in self.manifest.get("variables", []) if v not in extra.data_vars]
        at = next((j for j, v in enumerate(order) if v.startswith(("theory_", "margin_", "derived_"))), len(order))
        self.manifest["variables"] = order[:at] + [str(k) for k in extra.data_vars] + order[at:]  # as build() orders
        self._save_manifest()
        existing = set(self._data().array_keys())
        extra = extra.drop_vars([k for k in extra.variables if k in existing and k not in data])
        with _quiet_zarr():
            extra.to_zarr(self.path, mode="a", zarr_format=3, consolidated=True)
        self._group = None


class StoreWarning(UserWarning):
    """Something in the store was repaired (a chunk recomputed)."""


def _set_root_attrs(path: Path, attrs: Mapping[str, Any]) -> None:
    """Update the zarr group's attributes by replacing ``zarr.json`` atomically (zarr rewrites it in
    place; a kill midway would leave a group no one can open)."""
    root = Path(path) / ROOT
    meta = json.loads(root.read_text())
    meta.setdefault("attributes", {}).update(I.plain(dict(attrs)))
    _atomic_json(root, meta)


def verify_metadata(path: str | Path, manifest: Mapping[str, Any]) -> dict[str, str]:
    """Metadata file -> what is wrong, for every zarr.json of the store (the group's, each array's) that is
    missing, has no checksum in the manifest, or differs from the checksum recorded when the store's writer
    finished writing it. Checked before anything is read through them: a chunk's checksum is computed from
    the values zarr decodes, so it cannot see an outcome name or an attribute changed in the metadata."""
    if manifest.get("arrays") is None:
        return {}
    sums = manifest.get("metadata")
    sums = sums if isinstance(sums, dict) else {}
    held = set(manifest["arrays"]) | set(manifest.get("static") or {}) | set(manifest.get("derived") or {})
    bad: dict[str, str] = {}
    for f in sorted(set(meta_files(held)) | set(sums)):
        if f not in sums:
            bad[f] = f"{f} has no checksum in the manifest"
        elif sums[f] == REWRITING:
            bad[f] = f"{f} was being rewritten when the sweep stopped"
        elif not (Path(path) / f).is_file():
            bad[f] = f"{f} is missing"
        else:
            try:
                same = file_sum(Path(path) / f) == sums[f]
            except OSError as exc:
                bad[f] = f"{f} cannot be read ({exc.strerror or exc})"
                continue
            if not same:
                bad[f] = f"{f} differs from its checksum (changed after it was written)"
    return bad


def _unreadable(name: str) -> str:
    return f"{name} is unreadable, cut short or overwritten"


def _open_arrays(path: str | Path, manifest: Mapping[str, Any], names) -> dict[str, Any]:
    """The zarr arrays ``names``, through metadata checked against its checksums first; a
    :class:`StoreError` naming the damaged file(s) otherwise (nothing is read through them)."""
    import zarr

    bad = verify_metadata(path, manifest)
    if bad:
        raise StoreError(metadata_problem(bad))
    try:
        with _quiet_zarr():
            g = zarr.open_group(Path(path), mode="r", zarr_format=3)
            return {k: g[k] for k in names}
    except Exception as exc:  # noqa: BLE001 - metadata matching its checksums that zarr refuses: a bug of ours
        raise StoreError(f"the store's arrays cannot be opened ({type(exc).__name__}: {exc})") from None


def metadata_problem(bad: Mapping[str, str]) -> str:
    """One line for damaged metadata files: the first few named, the rest counted."""
    said = [bad[f] for f in sorted(bad)]
    return "; ".join(said[:3]) + (f" and {len(said) - 3} more metadata file(s)" if len(said) > 3 else "")


def _file_id(f: Path) -> tuple | None:
    """What identifies one version of a chunk file without reading it (None: no such file)."""
    try:
        st = f.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def verify(path: str | Path, manifest: Mapping[str, Any], known: dict | None = None) -> dict[int, str]:
    """Chunk index -> what is wrong, for every finished chunk whose block of some array is missing
    (no chunk file), unreadable, or differs from the checksum recorded when it was written. Raises
    :class:`StoreError` when the metadata the arrays are read through is damaged.

    ``known``: a cache the caller keeps between calls on the same store (``stabjax view`` refreshing a
    running sweep's store), of the chunk files that matched their checksums, each with its inode, size
    and modification time; a file unchanged since is not read again. Why: each refresh would otherwise
    read every finished chunk twice, once here and once to show it."""
    arrays = manifest.get("arrays") or {}
    if not manifest["chunks"]:
        return {}
    if not arrays:  # chunks listed before any array was created: a manifest edited by hand
        return {int(i): "the store has no arrays" for i in manifest["chunks"]}
    ch = Chunking(manifest["chunking"]["shape"], manifest["batch_size"])
    arr = _open_arrays(path, manifest, arrays)
    bad: dict[int, str] = {}
    for key, entry in manifest["chunks"].items():
        i = int(key)
        coords = ch.chunk_coords(i)
        for k, a in arr.items():
            trailing = len(arrays[k]["trailing"])
            ck = a.metadata.encode_chunk_key(coords + (0,) * trailing)
            want = (entry.get("sha256") or {}).get(k)
            fid = _file_id(Path(path) / k / ck) if known is not None else None
            if fid is not None and known.get((k, ck)) == (want, fid):
                continue
            try:
                b = a[ch.region(i) + (slice(None),) * trailing]
            except Exception:  # noqa: BLE001 - a truncated or overwritten chunk file
                bad[i] = _unreadable(f"{k}/{ck}")
                break
            got = checksum(b)
            if got == want and fid is not None:
                known[(k, ck)] = (want, fid)
            if got != want:
                # zarr writes no chunk equal to the fill value (an outcome code 0 throughout): a chunk without
                # its file is lost only when what it reads as differs from the checksum
                gone = not (Path(path) / k / ck).is_file()
                bad[i] = f"{k}/{ck} {'is missing' if gone else 'differs from its checksum'}"
                break
    return bad


def verify_arrays(path: str | Path, manifest: Mapping[str, Any]) -> dict[str, str]:
    """Array name -> what is wrong, for every whole-array checksum of the manifest (``static``: written
    when the store was created; ``derived``: when it finished) whose array has a chunk file missing, is
    unreadable, or differs from its checksum. Raises :class:`StoreError` when the arrays cannot be opened."""
    sums = {**(manifest.get("static") or {}), **(manifest.get("derived") or {})}
    if not sums:
        return {}
    arr = _open_arrays(path, manifest, sums)
    bad: dict[str, str] = {}
    for k, a in arr.items():
        try:
            values = a[...]
        except Exception:  # noqa: BLE001 - a truncated or overwritten chunk file: which one
            bad[k] = _unreadable(k)
            for idx in np.ndindex(*a.cdata_shape):
                try:
                    a.blocks[idx]
                except Exception:  # noqa: BLE001
                    bad[k] = _unreadable(f"{k}/{a.metadata.encode_chunk_key(idx)}")
                    break
            continue
        if checksum(values) != sums[k]:
            # zarr writes no chunk equal to the fill value: a chunk without its file is lost only when the sum differs
            gone = [ck for ck in (a.metadata.encode_chunk_key(i) for i in np.ndindex(*a.cdata_shape))
                    if not (Path(path) / k / ck).is_file()]
            bad[k] = f"{k}/{gone[0]} is missing" if gone else f"{k} differs from its checksum"
    return bad


def load_results(path: str | Path, manifest: Mapping[str, Any], *, lazy: bool = False) -> dict[str, Any]:
    """The per-trajectory records of a store, flat over the trajectories (N, *trailing) in the plan's
    C order: dask arrays reading the store (``lazy``) or numpy."""
    import zarr

    with _quiet_zarr():
        g = zarr.open_group(Path(path), mode="r", zarr_format=3)
    nd = len(manifest["chunking"]["shape"])
    out = {}
    for k, meta in (manifest.get("arrays") or {}).items():
        trailing = tuple(meta["trailing"])
        if lazy:
            import dask.array as da

            a = da.from_zarr(g[k])
        else:
            a = np.asarray(g[k][...])
        out[k] = a.reshape((-1, *trailing)) if nd else a.reshape((1, *trailing))
    return out


def pending_mask(manifest: Mapping[str, Any]) -> np.ndarray:
    """Boolean array over the plan's grid: True where a trajectory's chunk has not finished."""
    ch = Chunking(manifest["chunking"]["shape"], manifest["batch_size"])
    pending = np.ones(ch.shape, bool)
    for i in manifest.get("chunks", {}):
        pending[ch.region(int(i))] = False
    return pending


def open_store(path: str | Path, *, dask: bool = True):
    """The dataset a store holds, as xarray reads it (``xr.open_zarr``), lazily; with the zarr
    encodings dropped and text coordinates as Python strings, so that it writes to netCDF exactly
    as the dataset of a run without a store does. ``dask``: its variables are Dask arrays (read chunk
    by chunk when computed); else xarray's own lazy arrays, each read whole by ``load()`` -- the same
    values, without Dask's import and task graph, for a dataset that is loaded anyway."""
    import xarray as xr

    ds = xr.open_zarr(Path(path), consolidated=True, zarr_format=3, chunks={} if dask else None)
    with contextlib.suppress(StoreError, TypeError, KeyError):
        order = (read_manifest(Path(path)) or {}).get("variables") or []
        names = [v for v in order if v in ds.data_vars] + [v for v in ds.data_vars if v not in order]
        ds = xr.Dataset({v: ds[v] for v in names}, coords=ds.coords, attrs=ds.attrs)  # every coordinate kept
    for v in ds.variables.values():
        v.encoding = {}
    for k in list(ds.coords):
        if ds[k].dtype.kind == "T":  # numpy StringDType
            ds = ds.assign_coords({k: (ds[k].dims, ds[k].values.astype(object), ds[k].attrs)})
    for k in ("stabjax_store", "stabjax_complete"):
        ds.attrs.pop(k, None)
    return ds


def plan_from_manifest(manifest: Mapping[str, Any]):
    """Rebuild the plan a store was computed for (spec + overrides + effective integrate settings)."""
    from ..plan.spec import make_plan

    ident = manifest["identity"]
    plan = make_plan(ident["spec"], t1=ident["overrides"].get("t1"))
    icfg = dataclasses.replace(plan.icfg, **ident["integrate"])
    if icfg != plan.icfg:
        plan = dataclasses.replace(plan, icfg=icfg)
    return plan


def holder(path: Path) -> dict | None:
    """The lock's record of the sweep writing the store ({"pid", "host"}), or None when no live one holds it."""
    lock = Path(path) / LOCK
    try:
        h = json.loads(lock.read_text() or "{}")
    except (OSError, ValueError):
        return None
    if h.get("host") == socket.gethostname() and isinstance(h.get("pid"), int) and not _pid_alive(h["pid"]):
        return None
    return h


def damage(store: str | Path, manifest: Mapping[str, Any], known: dict | None = None) -> tuple[str, str] | None:
    """What is wrong with the finished part of a store, and how to go on, each in words; None when every
    metadata file, every finished chunk and every whole array matches the checksum recorded when it was
    written. What reads a store for a user (``export``, :func:`stabjax.open_result`, ``plot``, ``report``,
    ``view``) asks this first: nothing damaged is filled in or read as something else."""
    damaged = verify_metadata(store, manifest)
    if damaged:
        return metadata_problem(damaged), ("Run the sweep command again: it writes the store's arrays again and "
                                           "recomputes its chunks")
    bad = verify(store, manifest, known)  # ``known``: :func:`verify`'s cache of chunk files already checked
    broken = verify_arrays(store, manifest)
    if not (bad or broken):
        return None
    said = [f"chunk {i}: {why}" for i, why in sorted(bad.items())] + [broken[k] for k in sorted(broken)]
    what = ([f"{len(bad)} chunk(s) are missing or damaged"] if bad else []) + \
        ([f"{'array' if len(broken) == 1 else 'arrays'} {', '.join(sorted(broken))} "
          f"{'is' if len(broken) == 1 else 'are'} missing or damaged"] if broken else [])
    return (f"{' and '.join(what)} ({'; '.join(said[:5])}{' ...' if len(said) > 5 else ''})",
            "Run the sweep command again: it recomputes them")


def finished_store(store: str | Path):
    """(manifest, plan) of a finished store that no sweep is writing and whose every chunk matches its
    checksum, for ``stabjax export``; otherwise an error saying what is wrong and how to go on."""
    from ..errors import ValidationError

    store = Path(store)
    if not store.exists():
        raise ValidationError("store", f"not found: {store}")
    if not store.is_dir():
        raise ValidationError("store", f"{store} is a file, not a stabjax store (a directory written by "
                                       "'stabjax sweep ... --keep-store')")
    m = read_manifest(store, hint=f"nothing can be exported from it. Compute it again with the sweep that wrote "
                                  f"it: stabjax sweep SPEC --store {store} --restart")
    if m is None:
        raise ValidationError("store", f"{store} is not a stabjax store (no {MANIFEST}){rounds_note(store)}")
    h = holder(store)
    if h is not None:
        raise StoreError(f"{store} is being written by pid {h.get('pid')} on {h.get('host')}; export it when that sweep ends")
    done = len(m["chunks"])
    if done == m["n_chunks"] and not m.get("finished") and rounds_note(store.parent):
        raise ValidationError("store", f"{store} is one round of a refinement or a shock search (its points' "
                                       f"integrations, not a result){rounds_note(store.parent)}")
    if done != m["n_chunks"] or not m.get("finished"):
        raise StoreError(f"{store} is incomplete: {done} of {m['n_chunks']} chunks finished; run the sweep command "
                         "again to finish it")
    problem = damage(store, m)
    if problem is not None:
        raise StoreError(f"{store}: {problem[0]}; nothing was exported. {problem[1]}")
    return m, plan_from_manifest(m)


__all__ = ["ChunkStore", "Chunking", "StoreError", "StoreIOError", "StoreWarning", "Lock", "finished_store",
           "identity", "describe_changes", "read_manifest", "damage", "open_store", "pending_mask", "load_results",
           "plan_from_manifest", "stored_batch", "verify", "verify_arrays", "verify_metadata", "checksum"]
