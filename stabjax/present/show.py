"""One entry point per way a result is shown, whatever its kind: :func:`plot` draws it, :func:`summary` writes
the text the command line prints after a sweep or ``stabjax plot``. Both dispatch on the result's kind
(:data:`stabjax.present.kit.KINDS`), so ``stabjax plot``, ``stabjax report``, ``stabjax view`` and
``stabjax.plot`` accept the same results: verdict maps, named outcomes and basin fractions (along an axis
too), discovered attractors, boundary refinements -- and the regions-of-attraction results once their
module (``present/shock.py``) is there.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ValidationError
from . import kit

if TYPE_CHECKING:
    import xarray as xr


def _dataset(result) -> tuple[Any, Path | None]:
    """(dataset, the file it was read from) of a result given as a dataset or a path."""
    if isinstance(result, (str, Path)):
        return kit.open_result(result, partial=False), Path(result)
    if not hasattr(result, "data_vars"):
        raise ValidationError("result", f"expected a result (an xarray Dataset, or the path of a netCDF file or "
                                        f"a sweep's store), got {type(result).__name__}")
    return result, None


def plot(result: xr.Dataset | str | Path, out: str | Path | None = None, *, title: str | None = None,
         source: str | Path | None = None, stamp: bool = True, force: bool = False):
    """Draw any stabjax result -- the figure ``stabjax plot`` writes -- and return the matplotlib figure.

    ``result``: a dataset (:func:`stabjax.run_spec`, :func:`stabjax.open_result`) or the path of a result
    file or of a finished sweep's store. What is drawn follows the result's kind: a verdict map with the
    theory's boundary (:func:`stabjax.present.maps.plot_sweep`); named outcomes or discovered attractors
    with their basin fractions, along an axis or per cell (:func:`stabjax.present.basins.plot_basin`, the
    attractors named with where they lie); a refinement's points and bracketed boundary
    (:func:`stabjax.present.refinement.plot_refine`). ``out``: also write it there (PNG, SVG or PDF; folders
    made) and close it, stamped with the result it shows (:func:`stabjax.run.outputs.stamp_output`;
    ``source``: the result's file, when ``result`` is a dataset read from one; ``stamp=False``: the caller
    stamps). ``title``: what the figure shows, in words
    (default: the spec's description). ``out`` is never the result's file or a module loaded, and an existing
    file there is replaced only when it is a figure stabjax drew of this result or of one of its spec (its stamp
    says so), or with ``force=True`` (what ``stabjax plot`` checks of its ``--out``).
    """
    ds, path = _dataset(result)
    if out is not None:
        from ..run.outputs import IMAGE_SUFFIXES, check_output, input_files, is_own_output, spec_digest_of

        digest, src = spec_digest_of(ds), source or path
        check_output(Path(out), "out", IMAGE_SUFFIXES, inputs=input_files(src), force=force,
                     same=lambda p: is_own_output(p, src, spec=digest),
                     what="a figure stabjax drew of this result (or of a result of its spec)")
    k = kit.kind_of(ds)
    if k is None:
        raise ValidationError("result", "not a stabjax result (no verdict, outcome, attractor or refinement points)")
    if "pending" in ds and bool(np.asarray(ds["pending"].values).any()):
        raise ValidationError("result", "this is part of a running or interrupted sweep (some chunks have not "
                                        "finished): watch it with stabjax view, or draw it when the sweep has finished")
    if k.name == "discovery" and "outcome" not in ds:
        raise ValidationError("result", "this discovery has no outcomes yet (they are assigned when every "
                                        "trajectory has run): draw it when the sweep has finished")
    draw = kit.function(k.draw)
    fig = draw(ds, out, **({"title": title} if title is not None else {}))
    if out is not None and stamp:
        from ..run.outputs import spec_digest_of, stamp_output

        stamp_output(out, source or path, spec=spec_digest_of(ds))
    return fig


def summary(ds: xr.Dataset) -> str:
    """The result in a few lines of plain text (what the command line prints): the theory x simulation table
    of a verdict map, the outcome table with S, SE and Wilson intervals of named outcomes (and where each
    discovered attractor lies), a refinement's segments and brackets."""
    k = kit.kind_of(ds)
    if k is None:
        raise ValidationError("result", "not a stabjax result (no verdict, outcome, attractor or refinement points)")
    if k.name == "discovery" and "outcome" not in ds:
        return "the outcomes are assigned when every trajectory has run (attractor discovery groups them all)"
    text = kit.function(k.text)(ds)
    if k.name == "verdicts" and "basin_fraction" in ds:  # a paper system with samples: its basin fractions too
        from .basins import format_summary

        text += "\n" + format_summary(ds)
    return text
