"""What a command may write, and where: outputs never destroy a user's file (issue 22, items 2 and 3).

* :func:`input_files` / :func:`same_file_as_any`: an output never resolves (through a symlink or a
  hard link either) to the command's input, the model file, or any Python module loaded in the process
  (a model's helper modules among them);
* :func:`check_store_path`: a chunk store is never an input file nor a folder holding one;
* :func:`write_image` / :func:`write_reason`: maps are written to a temporary file and renamed, and a
  failed write (a full disk) is one line naming the file (:class:`stabjax.errors.OutputError`, exit 1);
* :func:`reproduce_into`: ``stabjax reproduce`` computes in a staging folder and replaces only the
  files it wrote there before, unchanged since (``.stabjax-reproduce.json``), unless ``--force``;
* :func:`stamp_output` / :func:`output_stamp` / :func:`is_own_output`: an HTML page, PNG, SVG or PDF
  drawn from a result carries a stamp naming that result and the digest of the rest of its bytes, so
  that "this file is our own previous output of that result, unchanged since" is decided from the
  file's content, never from its name (issue 29: ``stabjax report R.nc`` must not replace a user's
  ``R.html``).

The checks that compare an output with a previous result of the same command stay with the commands
(:func:`stabjax.app.common.check_output`). Nothing heavy is imported at module level.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Callable, Iterator, Optional

from ..errors import OutputError, ValidationError

RECORD = ".stabjax-reproduce.json"


def same_file_as_any(path: Path, inputs) -> bool:
    """Whether ``path`` is one of ``inputs`` (the same file on disk: through a symlink or a hard link too)."""
    try:
        st = path.stat()
    except OSError:
        return False
    for inp in inputs:
        try:
            si = os.stat(inp)
        except (OSError, TypeError, ValueError):
            continue
        if (si.st_dev, si.st_ino) == (st.st_dev, st.st_ino):
            return True
    return False


def input_files(*paths, system=None) -> tuple[Path | str, ...]:
    """What a command must never write over: the files it reads (``paths``), the model file of
    ``system`` and every Python module loaded in this process (a model's helper modules among them:
    an output path resolving to any of them would destroy user code)."""
    files = [Path(p) for p in paths if p is not None]
    if system is not None:
        from ..model.loading import source_file

        src = source_file(system)
        if src is not None:
            files.append(Path(src))
    # kept as strings: a Path for each of the ~3000 modules a sweep has loaded cost 0.1 s per call
    files.extend(f for f in (getattr(mod, "__file__", None) for mod in list(sys.modules.values()))
                 if isinstance(f, str))
    return tuple(files)


def check_store_path(store: Path, inputs, outputs=()) -> None:
    """A chunk store is a directory of the sweep's own files: never an input file, never a folder
    holding the spec or the model (a ``--restart`` there would be one step from deleting them), never
    one of the files the same command writes (``--store`` equal to ``--out`` or its map: the store
    would be made, filled for minutes, and the result could not be written over it)."""
    from ..errors import ValidationError

    for o in outputs:
        if o is not None and Path(store).resolve() == Path(o).resolve():
            raise ValidationError("--store", f"{store} is also where this command writes {o}; "
                                             "give --store a directory of its own (default: <out>.zarr)")
    if store.exists() and not store.is_dir():
        raise ValidationError("--store", f"{store} exists and is not a directory" +
                              (" (it is this command's input)" if same_file_as_any(store, inputs) else ""))
    if store.is_dir():
        # each input resolved through its folder's real path (remembered: the inputs include every module loaded,
        # ~3000 files in a few hundred folders; resolving each file was 0.3 s a call); a file that is itself a
        # link is resolved whole. Nothing inside the store is listed (a store named by mistake may be a large tree)
        root = os.path.realpath(store)
        real_dirs: dict[str, str] = {}
        for f in inputs:
            try:
                path = os.fspath(f)
                if os.path.islink(path):
                    real = os.path.realpath(path)
                else:
                    folder, base = os.path.split(os.path.abspath(path))
                    if folder not in real_dirs:
                        real_dirs[folder] = os.path.realpath(folder)
                    real = os.path.join(real_dirs[folder], base)
            except (OSError, TypeError, ValueError):
                continue
            if (real == root or real.startswith(root.rstrip(os.sep) + os.sep)) and os.path.exists(real):
                raise ValidationError("--store", f"{store} holds {f}, an input of this command; a store directory "
                                                 "holds only what the sweep writes: choose another --store")


def _temp_form(out: Path, keep_suffix: bool) -> tuple[str, str]:
    """(prefix, ending) of the temporary files of ``out``: ``.NAME.`` and ``.tmp``, or with ``keep_suffix``
    (an image or a page, whose writer reads the format from the suffix) ``.STEM.`` and ``.tmp.SUFFIX``."""
    return (f".{out.stem}.", f".tmp{out.suffix}") if keep_suffix else (f".{out.name}.", ".tmp")


def temp_beside(out: Path, keep_suffix: bool = False) -> Path:
    """The temporary file a result is written to before it is renamed over ``out``:
    ``.NAME.HOST-PID.tmp`` beside it (``.STEM.HOST-PID.tmp.SUFFIX`` with ``keep_suffix``: figures and pages),
    naming the process that writes it (:func:`clean_stale_temps`)."""
    import socket

    prefix, end = _temp_form(out, keep_suffix)
    return out.with_name(f"{prefix}{socket.gethostname()}-{os.getpid()}{end}")


def clean_stale_temps(out: Path, keep_suffix: bool = False) -> list[Path]:
    """Remove the temporary files of ``out`` (:func:`temp_beside`) left by processes of this host that
    are dead (a kill -9 while the file was written); the files removed. Any other file -- one of a live
    process, of another host, or not of that exact form -- is left alone."""
    import socket

    from .lock import _pid_alive

    host, gone = socket.gethostname(), []
    prefix, end = _temp_form(out, keep_suffix)
    try:
        found = list(out.parent.glob(f"{glob.escape(prefix)}*{glob.escape(end)}"))
    except OSError:
        return gone
    for f in found:
        who = f.name[len(prefix):-len(end)]
        h, _, pid = who.rpartition("-")
        if h != host or not pid.isdigit() or not pid.isascii() or int(pid) == os.getpid() or _pid_alive(int(pid)):
            continue
        if f.is_file() and not f.is_symlink():
            try:
                f.unlink()
                gone.append(f)
            except OSError:
                pass
    return gone


def write_reason(exc: BaseException, out: Path) -> str:
    """Why a write failed, in words: the OS error, else the library's message with the free space
    (netCDF reports a full disk as ``RuntimeError: NetCDF: HDF error``)."""
    import shutil

    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    try:
        free = shutil.disk_usage(Path(out).parent).free
        space = f"; {free / 2**20:.1f} MiB free on its disk" + (" (the disk is full?)" if free < 2**26 else "")
    except OSError:
        space = ""
    return f"{type(exc).__name__}: {exc}{space}"


def write_image(path: Path, draw, result: Optional[Path] = None, *, spec: str | None = None) -> None:
    """``draw(tmp)`` into a temporary file beside ``path``, then rename it over ``path`` (atomic).
    ``result``: the result file the image is drawn from, ``spec``: the digest of its spec
    (:func:`spec_digest_of`); the image is then stamped with them (:func:`stamp_output`), so that drawing it
    again may replace it and nothing else."""
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(path, keep_suffix=True)  # a process killed while it drew this image left its file behind
    tmp = temp_beside(path, keep_suffix=True)
    try:
        draw(tmp)
        if result is not None or spec is not None:
            stamp_output(tmp, result, spec=spec)
        os.replace(tmp, path)
    except (OSError, RuntimeError) as exc:
        tmp.unlink(missing_ok=True)
        plt.close("all")
        hint = f"{result} is written; draw the map again with: stabjax plot {result} --out {path}" if result else ""
        raise OutputError(path, write_reason(exc, path), hint) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def reproduce_into(out_dir: Path, name: str, fn: Callable, *, quick: bool = False, force: bool = False
                   ) -> Iterator[tuple[Path, bool]]:
    """Run the reproduction ``fn`` into ``out_dir/.staging-NAME`` and move its files into ``out_dir``;
    yields (file written, whether it replaced one). See ``stabjax reproduce --help`` for the rules."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ValidationError("--out-dir", f"{out_dir} exists and is not a directory")
    record = reproduce_record(out_dir)
    mine = record.get(name, {})
    # before minutes of computing: the names an earlier run recorded, and any file of the kinds a
    # reproduction writes that this command did not write there (the figures tracked in the repository)
    if not force:
        refuse_foreign(out_dir, [out_dir / rel for rel in mine], mine)
        present = [p for p in out_dir.glob("*") if p.is_file()] if out_dir.is_dir() else []
        foreign = sorted(p.name for p in present if not p.name.startswith(".")
                         and p.suffix.lower() in REPRODUCE_SUFFIXES and not is_mine(p, out_dir, mine))
        if foreign:
            shown = ", ".join(foreign[:3]) + (f", ... ({len(foreign)} in all)" if len(foreign) > 3 else "")
            raise ValidationError("--out-dir", f"{out_dir} holds files this command did not write ({shown}); "
                                               "reproducing may replace them: pass --force to allow it, or choose "
                                               "another --out-dir")
    staging = out_dir / f".staging-{name}"
    staging.mkdir(parents=True, exist_ok=True)
    made = [Path(f) for f in fn(staging, quick=quick)]
    for f in made:  # a reproducer that writes elsewhere: said, not moved
        if not f.resolve().is_relative_to(staging.resolve()):
            yield f, False
    files = [f for f in made if f.resolve().is_relative_to(staging.resolve())]
    rels = [f.resolve().relative_to(staging.resolve()) for f in files]
    if not force:
        refuse_foreign(out_dir, [out_dir / r for r in rels], mine, staging=staging)
    for f, r in zip(files, rels):
        dest = out_dir / r
        dest.parent.mkdir(parents=True, exist_ok=True)
        replaced = dest.exists()
        os.replace(f, dest)
        mine[str(r)] = hashlib.sha256(dest.read_bytes()).hexdigest()
        yield dest, replaced
    record[name] = mine
    tmp = out_dir / f"{RECORD}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True))
    os.replace(tmp, out_dir / RECORD)
    for d in sorted((p for p in staging.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)) + [staging]:
        try:
            d.rmdir()  # only empty folders: anything left in staging is kept, never deleted
        except OSError:
            pass


def reproduce_record(out_dir: Path) -> dict:
    """``--out-dir/.stabjax-reproduce.json``: per reproduction, the files it wrote and their sha256."""
    try:
        rec = json.loads((out_dir / RECORD).read_text())
    except (OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


REPRODUCE_SUFFIXES = (".png", ".pdf", ".svg", ".nc", ".md", ".txt", ".json", ".csv")  # what reproducers write


def is_mine(path: Path, out_dir: Path, mine: dict) -> bool:
    """Whether ``path`` is a file an earlier run of this reproduction wrote there, unchanged since."""
    try:
        return mine.get(str(path.relative_to(out_dir))) == hashlib.sha256(path.read_bytes()).hexdigest()
    except (OSError, ValueError):
        return False


def refuse_foreign(out_dir: Path, dests: list[Path], mine: dict, staging: Path | None = None) -> None:
    """Refuse when a destination exists and is not, unchanged, a file an earlier run of this command wrote."""
    for dest in dests:
        if not dest.exists():
            continue
        if dest.is_dir():
            raise ValidationError("--out-dir", f"{dest} is a directory where a file would be written")
        if is_mine(dest, out_dir, mine):
            continue  # our own previous result, unchanged: replaced like a re-run of any command
        kept = f"; the new files are kept in {staging}" if staging is not None else ""
        raise ValidationError("--out-dir", f"{dest} exists and was not written by this command (or was changed "
                                           f"since); pass --force to replace it, or choose another --out-dir{kept}")


RESULT_SUFFIXES = (".nc",)


IMAGE_SUFFIXES = (".png", ".pdf", ".svg")


def check_output(out: Path, field: str, suffixes: tuple[str, ...], *, inputs: tuple[Path, ...] = (),
                  force: bool = False, same=None, what: str = "a previous result of this command") -> bool:
    """Refuse an output path that would lose something; True when an existing file will be replaced.

    Never the command's input (a spec, a result being plotted), never a directory, only the
    extensions the command writes. The command line's checks (``field`` an option, ``--out``) and the
    Python API's (:func:`guard_result`; ``field`` a keyword, ``out``, and the way to allow it ``force=True``). An existing file is replaced when ``same(out)`` says it is a
    previous result of the same computation (re-running a command is normal) or with ``--force``;
    anything else is refused with the way to allow it.
    """
    out = Path(out)
    hint = "--force" if field.startswith("--") else "force=True"
    if out.is_dir():
        raise ValidationError(field, f"{out} is a directory; give a file name ending in {suffixes[0]}")
    if out.suffix.lower() not in suffixes:
        raise ValidationError(field, f"{out}: this {'command' if field.startswith('--') else 'function'} writes "
                                     f"{' or '.join(suffixes)} files; "
                                     f"got {out.suffix or 'no extension'!r}")
    if out.parent.exists() and not out.parent.is_dir():
        raise ValidationError(field, f"{out.parent} is not a directory")
    if out.exists() and same_file_as_any(out, inputs):
        raise ValidationError(field, f"{out} is this command's input (the spec, the model or a module it imports, "
                                     "or the file read); it is never overwritten")
    if not out.exists():
        return False
    if force or (same is not None and same(out)):
        return True
    raise ValidationError(field, f"{out} exists and is not {what}; pass {hint} to replace it, "
                                 f"or choose another {field}")


def result_spec(path: Path):
    """The spec (parsed ``spec_json``) stored in a stabjax sweep result, or None for any other file."""
    try:
        import xarray as xr

        with xr.open_dataset(path, engine="netcdf4") as ds:
            return json.loads(ds.attrs["spec_json"]) if "spec_json" in ds.attrs else None
    except Exception:  # noqa: BLE001 - not a readable netCDF file: not a result
        return None


def guard_result(plan, out, *, force: bool = False, spec_file=None) -> bool:
    """The Python API's check of a result path (``run_plan``, ``refine_plan``, ``shock_plan``): what
    ``stabjax sweep`` checks of its ``--out``. Never the spec file read (``spec_file``), the starts file, the model
    or a module loaded, even with ``force``; an existing file only when it is a result of this same spec (a
    re-run) or with ``force=True``. True when an existing file will be replaced."""
    from ..plan.spec import spec_json

    this_spec = json.loads(spec_json(plan.spec))
    return check_output(Path(out), "out", RESULT_SUFFIXES, force=force,
                        inputs=input_files(spec_file, getattr(plan, "starts_file", None), system=plan.system),
                        same=lambda p: result_spec(p) == this_spec, what="a result of this spec")


def plan_result(spec, out, *, t1: float | None = None, force: bool = False, section: str | None = None,
                caller: str = "", kw=None, runner=None):
    """The plan of ``spec`` (a mapping, or a TOML file loaded here) for the ``*_spec`` functions, with ``out``
    checked by :func:`guard_result` before anything runs (never the spec file itself). ``section``: the table
    the spec must have (``"refine"``, ``"shock"``), refused by name when missing. ``kw``: the keywords
    ``caller`` passes on to ``runner``, refused in ``caller``'s name when ``runner`` takes none such (a
    TypeError naming an internal function otherwise, and only after the plan was made)."""
    import inspect

    from ..plan.spec import load_spec, make_plan

    if kw and runner is not None:
        takes = [k for k, v in inspect.signature(runner).parameters.items() if v.kind == v.KEYWORD_ONLY
                 and k != "overrides"]
        bad = [k for k in kw if k not in takes]
        if bad:
            raise TypeError(f"{caller}() got an unexpected keyword argument {bad[0]!r} (it takes t1, "
                            f"{', '.join(takes)})")
    spec_file = spec if isinstance(spec, (str, Path)) else None
    if spec_file is not None:
        spec = load_spec(spec_file)
    if section is not None and section not in spec:
        raise ValidationError(section, f"the spec has no [{section}] section")
    # run_spec of a spec with a [shock] table ran a plain sweep and returned its outcomes, as if searched
    for table, runs in (("refine", "refine_spec"), ("shock", "shock_spec")):
        if table != section and isinstance(spec, Mapping) and table in spec:
            raise ValidationError(table, f"the spec has a [{table}] table, which {caller or 'this function'}() does "
                                         f"not run: use stabjax.{runs}(spec) (as `stabjax sweep` does)")
    try:
        plan = make_plan(spec, t1=t1)
    except ValidationError as exc:
        if exc.field != "--t1":
            raise
        raise ValidationError("t1", exc.message) from None  # the argument's name here, not the command line's
    if out is not None:
        guard_result(plan, out, force=force, spec_file=spec_file)
    return plan


# ---- stamps: "our own previous output of this result, unchanged since", from the file's content -------------

STAMP = "stabjax-output"  # the stamp's keyword: a PNG text chunk's key, the word opening an HTML/SVG/PDF comment
STAMPED = {".png": "png", ".svg": "xml", ".html": "xml", ".htm": "xml", ".pdf": "pdf"}


def stamp_output(path: str | Path, source: str | Path | None = None, *, spec: str | None = None) -> None:
    """Stamp the file at ``path``, just written by stabjax (before it is renamed into place), as drawn from
    the result ``source`` (a file; None for a dataset held in memory) computed from the spec whose digest is
    ``spec`` (:func:`spec_digest_of`): the stamp names both and holds the sha256 of the file's other bytes, so a
    later edit (a user's notes added to a report) makes it a foreign file again.

    Where the stamp goes, leaving the file valid for every reader: a PNG ``tEXt`` chunk right after
    ``IHDR``; an HTML or SVG comment right after the ``<?xml ...?>`` or ``<!DOCTYPE ...>`` that opens it; a PDF comment
    line after ``%%EOF``. Other extensions are left unstamped (:func:`is_own_output` is then False).

    Use, for a command writing ``out`` from ``result`` (``write_image`` does the stamping itself)::

        check_output(out, "--out", (".html",), inputs=(result,), force=force,
                     same=lambda p: is_own_output(p, result, spec=spec_digest_of(ds)), what=f"the report of {result}")
        write(tmp); stamp_output(tmp, result, spec=spec_digest_of(ds)); os.replace(tmp, out)
    """
    path = Path(path)
    kind = STAMPED.get(path.suffix.lower())
    if kind is None:
        return
    data = path.read_bytes()
    found = _find_stamp(kind, data)
    if found is not None:  # stamped before (a file drawn by a stamping helper): one stamp, the new one
        data = data[:found[0]] + data[found[1]:]
    payload = json.dumps({"source": _relative_source(source, path), "spec": spec,
                          "sha256": hashlib.sha256(data).hexdigest()},
                         ensure_ascii=True, sort_keys=True).replace("-", "\\u002d")  # "--" ends an XML comment
    at = _stamp_offset(kind, data)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.stamp")
    try:
        tmp.write_bytes(data[:at] + _stamp_bytes(kind, payload.encode("ascii")) + data[at:])
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _relative_source(source: str | Path | None, path: Path) -> str | None:
    """The result's path as the stamp records it: relative to the stamped file's folder, so that the same
    figure drawn in another checkout (the README's map in a user's clone) has the same bytes; absolute only
    where no relative path leads there (another drive)."""
    if source is None:
        return None
    src = Path(source).resolve()
    try:
        return os.path.relpath(src, Path(path).resolve().parent)
    except ValueError:
        return str(src)


def output_stamp(path: str | Path) -> dict | None:
    """The stamp of a file written by :func:`stamp_output` -- ``{"source": resolved path of the result it
    was drawn from (recorded relative to the file's folder), "sha256": ...}`` -- or None: no stamp, not a
    file, unreadable, or changed since it was stamped (the digest of its other bytes differs)."""
    path = Path(path)
    kind = STAMPED.get(path.suffix.lower())
    if kind is None or not path.is_file():
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    found = _find_stamp(kind, data)
    if found is None:
        return None
    start, end, payload = found
    try:
        stamp = json.loads(payload)
    except ValueError:
        return None
    if not isinstance(stamp, dict) or stamp.get("sha256") != hashlib.sha256(data[:start] + data[end:]).hexdigest():
        return None
    src = stamp.get("source")
    if isinstance(src, str) and not os.path.isabs(src):
        stamp["source"] = str((path.resolve().parent / src).resolve())
    return stamp


def is_own_output(path: str | Path, source: str | Path | None = None, *, spec: str | None = None) -> bool:
    """Whether ``path`` is an output stabjax drew from the result ``source`` (the same file, by resolved path)
    or from a result of the same spec (digest ``spec``, :func:`spec_digest_of`: a re-run of the same
    computation), unchanged since: the test a command passes to :func:`stabjax.app.common.check_output` as
    ``same`` before replacing ``path`` without ``--force``. A map drawn before these stamps carries the spec's
    digest alone (the PNG text ``stabjax-spec``), and is recognised by it."""
    stamp = output_stamp(path)
    if stamp is None:
        return spec is not None and _legacy_png_spec(Path(path)) == spec
    return ((source is not None and stamp.get("source") == str(Path(source).resolve()))
            or (spec is not None and stamp.get("spec") == spec))


def spec_digest_of(ds) -> str | None:
    """The digest of the spec a result was computed from (its ``spec_json``), or None: what a stamp records so
    that a re-run of the same spec replaces the figures and pages of the previous run."""
    try:
        spec = json.loads(ds.attrs["spec_json"])
    except (KeyError, ValueError, TypeError, AttributeError):
        return None
    from ..plan.identity import spec_digest

    return spec_digest(spec)


LEGACY_PNG_KEY = "stabjax-spec"  # the sweep's maps before the stamps above: a PNG text chunk, the spec's digest


def _legacy_png_spec(path: Path) -> str | None:
    if path.suffix.lower() != ".png" or not path.is_file():
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    at = data.find(b"tEXt" + LEGACY_PNG_KEY.encode() + b"\0")
    if at < 4:
        return None
    n = int.from_bytes(data[at - 4:at], "big")
    return data[at + 4 + len(LEGACY_PNG_KEY) + 1:at + 4 + n].decode("latin-1")


def _stamp_bytes(kind: str, payload: bytes) -> bytes:
    if kind == "png":
        import zlib

        body = b"tEXt" + STAMP.encode() + b"\0" + payload
        return len(body[4:]).to_bytes(4, "big") + body + zlib.crc32(body).to_bytes(4, "big")
    if kind == "xml":
        return b"<!-- " + STAMP.encode() + b" " + payload + b" -->"
    return b"\n%" + STAMP.encode() + b" " + payload + b"\n"  # pdf: a comment line


def _stamp_offset(kind: str, data: bytes) -> int:
    if kind == "png":  # after the signature (8) and IHDR (4 + 4 + 13 + 4): a text chunk may come anywhere before IEND
        return 33 if data[12:16] == b"IHDR" else len(data)
    if kind == "xml":  # after the declaration or the doctype that must open the document, else first
        lead = len(data) - len(data.lstrip())
        head = data[lead:lead + 9].lower()
        close = b"?>" if head.startswith(b"<?xml") else b">" if head.startswith(b"<!doctype") else None
        at = data.find(close, lead) if close else -1
        return at + len(close) if at >= 0 else 0
    return len(data)  # pdf: after %%EOF (readers look for it within the last 1024 bytes)


def _find_stamp(kind: str, data: bytes) -> tuple[int, int, bytes] | None:
    """(start, end, payload) of the stamp in ``data``, or None."""
    if kind == "png":
        at = data.find(b"tEXt" + STAMP.encode() + b"\0")
        if at < 4:
            return None
        n = int.from_bytes(data[at - 4:at], "big")
        return at - 4, at + 4 + n + 4, data[at + 4 + len(STAMP) + 1:at + 4 + n]
    if kind == "xml":
        opening = b"<!-- " + STAMP.encode() + b" "
        at = data.find(opening)
        end = data.find(b" -->", at)
        if at < 0 or end < 0:
            return None
        return at, end + 4, data[at + len(opening):end]
    opening = b"\n%" + STAMP.encode() + b" "
    at = data.rfind(opening)
    end = data.find(b"\n", at + len(opening))
    if at < 0 or end < 0:
        return None
    return at, end + 1, data[at + len(opening):end]
