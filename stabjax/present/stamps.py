"""Which result a figure or a report shows, written into the file itself, so that a command replaces its
own previous output and nothing else (issue 29: ``stabjax report R.nc`` replaced any ``R.html`` and
``stabjax plot R.nc`` any ``R.png``, a user's own notes among them, because "its own previous output" was
decided from the file name alone).

The stamp is one line of text, ``stabjax-source SOURCE SPEC``: a digest of the result file's resolved path
and the digest of the spec it was computed from (:func:`stabjax.plan.identity.spec_digest`, the digest the
sweep's maps have carried as the PNG text ``stabjax-spec`` since before this module; such a map is still
recognised). It is written where each format keeps text that no viewer shows:

* PNG: text chunks (``stabjax-source``; ``stabjax-spec`` as before);
* SVG: the Dublin Core ``description`` of the figure's metadata;
* PDF: the document's ``Keywords``;
* HTML: ``<meta name="stabjax-source" content="... sha=DIGEST">`` in the head, with the digest of the whole
  page (:func:`seal`): a page a user has edited since (notes added to a report) no longer matches, and is a
  user's file again.

:func:`shows` decides: an existing file may be replaced without ``--force`` when its stamp names the same
result file or the same spec (a result of the same computation); a file without a stamp is a user's.
"""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

KEY = "stabjax-source"
PNG_SPEC_KEY = "stabjax-spec"  # the sweep's maps before this module: the spec digest alone
_STAMP = re.compile(rb"stabjax-source ([0-9a-f]{16}|-) ([0-9a-f]{16}|-)")
_SEAL = re.compile(rb" sha=([0-9a-f]{16})")
_UNSEALED = b" sha=" + b"-" * 16
_READ_LIMIT = 64 << 20  # a figure or a page of ours is far smaller: a larger file is no output of ours


def spec_of(ds) -> str | None:
    """The digest of the spec a result was computed from, or None (a dataset that records none)."""
    from ..plan.identity import spec_digest

    try:
        return spec_digest(json.loads(ds.attrs["spec_json"]))
    except (KeyError, ValueError, TypeError, AttributeError):
        return None


def source_of(source) -> str | None:
    """The digest of a result file's resolved path, or None without one (a dataset computed in memory)."""
    if not source:
        return None
    return hashlib.sha256(str(Path(source).resolve()).encode()).hexdigest()[:16]


def text(ds, source=None) -> str:
    """The stamp of ``ds`` read from ``source``: ``stabjax-source SOURCE SPEC`` (``-`` for an unknown part)."""
    return f"{KEY} {source_of(source) or '-'} {spec_of(ds) or '-'}"


def metadata(path, ds, source=None) -> dict | None:
    """What matplotlib's ``savefig(metadata=...)`` writes into an image at ``path`` to stamp it (None for a
    format that carries no stamp)."""
    suffix = Path(path).suffix.lower()
    stamp = text(ds, source)
    if suffix == ".png":
        meta = {KEY: stamp}
        spec = spec_of(ds)
        if spec:
            meta[PNG_SPEC_KEY] = spec
        return meta
    if suffix == ".svg":
        return {"Description": stamp}
    if suffix == ".pdf":
        return {"Keywords": stamp}
    return None


def html_meta(ds, source=None) -> str:
    """The ``<meta>`` element that stamps a page; :func:`seal` fills in the page's digest once it is whole."""
    return f'<meta name="{KEY}" content="{text(ds, source)}{_UNSEALED.decode()}">'


def seal(page: str) -> str:
    """The page with the digest of its bytes (taken with the digest's place blank) written into its stamp."""
    data = page.encode("utf-8")
    return data.replace(_UNSEALED, b" sha=" + _digest(data).encode(), 1).decode("utf-8")


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def read(path) -> tuple[str | None, str | None] | None:
    """(source digest, spec digest) stamped into the file at ``path``, either None when unknown; None when
    the file carries no stamp of ours (or cannot be read)."""
    path = Path(path)
    try:
        if path.stat().st_size > _READ_LIMIT:
            return None
        if path.suffix.lower() == ".png":
            from PIL import Image

            with Image.open(path) as im:
                info = dict(im.info)
            m = _STAMP.search(str(info.get(KEY, "")).encode())
            if m:
                return _parts(m)
            spec = info.get(PNG_SPEC_KEY)
            return (None, str(spec)) if spec else None
        data = path.read_bytes()
        m = _STAMP.search(data)
        if m is None:
            return None
        if path.suffix.lower() in (".html", ".htm"):  # a page edited since it was written is the user's
            sealed = _SEAL.search(data, m.end(), m.end() + 32)
            if sealed is None or _digest(data[:sealed.start()] + _UNSEALED + data[sealed.end():]) != sealed[1].decode():
                return None
        return _parts(m)
    except Exception:  # noqa: BLE001 -- unreadable, or not an image PIL knows: no stamp of ours
        return None


def _parts(m) -> tuple[str | None, str | None]:
    src, spec = (g.decode() for g in m.groups())
    return (None if src == "-" else src), (None if spec == "-" else spec)


def shows(path, ds, source=None) -> bool:
    """Whether the file at ``path`` is a figure or page of ours showing this result: its stamp names the same
    result file (``source``) or the same spec as ``ds``."""
    found = read(path)
    if found is None:
        return False
    src, spec = found
    return (src is not None and src == source_of(source)) or (spec is not None and spec == spec_of(ds))
