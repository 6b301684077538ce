"""Starts from a file (``[sample] from = "starts.csv"``) and the per-start comparison with its labels.

A user who has the starts of another tool (pyBasin's ``CsvSampler``, bSTAB, Attractors.jl) runs exactly
those: one row per start, one column per parameter, named as the model's (scalar) parameters; the
same rows at every grid point, as sampled starts are. Formats: ``.csv`` (a header row of names),
``.npy`` (a 1-D structured array: field names), ``.nc`` (a netCDF file: 1-D variables along one dimension).
Anything else is refused with the column named (a header naming a column twice, a variable along
another dimension): a column read wrongly would run other starts than the file's without a word.
Parameter columns hold finite real numbers: complex and bool columns are refused (float() would keep a
complex number's real part, a bool as 0/1). A CSV is read as utf-8-sig, so Excel's byte-order mark is not
part of the first column's name. A column ``label`` (or the one ``[sample] label = "NAME"`` names) holds the
other tool's outcome of each start; it is not a parameter, and a blank label is refused with its row. The
file's sha256 enters the sweep's identity (a resumed sweep whose file changed is refused like a changed spec).

Comparison (:func:`compare`): outcome codes and file labels are different alphabets, so each of our
outcomes is mapped to the file label most of its starts carry (pyBasin's majority mapping,
``case_studies/run_case_studies_with_defaults.py``); the agreement is the fraction of starts whose
mapped outcome equals their label, and the Matthews correlation coefficient (multi-class, Gorodkin
2004; ``sklearn.metrics.matthews_corrcoef``) is computed on the mapped outcomes. A majority map is
many-to-one, so one true basin split in two goes unpunished: ``one_to_one`` says whether the map was.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import ValidationError

FORMATS = (".csv", ".npy", ".nc")


def read(path: str | Path, field: str = "sample.from") -> dict[str, np.ndarray]:
    """Columns of a starts file: name -> 1-D array (integers and reals as float64; complex, bool and
    compound columns as stored, so that :func:`load` can refuse them as parameters instead of float()
    cutting a complex number to its real part or taking a bool as 0/1; anything else as str)."""
    return _read(path, field)[0]


def _read(path: str | Path, field: str = "sample.from") -> tuple[dict[str, np.ndarray], list[str]]:
    """:func:`read`, and where each start sits in the file, for messages: "line N" of a CSV (blank lines
    and quoted line breaks counted, as an editor shows them), "start I" (from 0) of the others."""
    path = Path(path)
    if path.is_dir():  # "." has no suffix: "unknown format" would send the user after the wrong mistake
        raise ValidationError(field, f"{path} is a folder; give a starts file ({', '.join(FORMATS)})")
    if path.suffix not in FORMATS:
        raise ValidationError(field, f"{path.name}: unknown format; use one of {', '.join(FORMATS)}")
    if not path.is_file():
        raise ValidationError(field, f"file not found: {path}")
    try:
        if path.suffix == ".csv":
            import csv

            # utf-8-sig: a BOM (Excel's "CSV UTF-8") is dropped, not read into the first column's name
            with open(path, newline="", encoding="utf-8-sig") as f:
                reader = csv.reader(f)
                rows, lines = [], []
                for r in reader:
                    rows.append(r)
                    lines.append(reader.line_num)
            if len(rows) < 2:
                raise ValidationError(field, f"{path.name}: needs a header row and at least one start")
            head = [h.strip() for h in rows[0]]
            twice = sorted({h for h in head if head.count(h) > 1})
            if twice:  # a dict of columns would keep the last one and drop the other without a word
                raise ValidationError(field, f"{path.name}: column {twice[0]!r} appears {head.count(twice[0])} times "
                                             "in the header; each column once")
            keep = [i for i in range(1, len(rows)) if any(c.strip() for c in rows[i])]
            body = [rows[i] for i in keep]
            where = [f"line {lines[i]}" for i in keep]
            if any(len(r) != len(head) for r in body):
                raise ValidationError(field, f"{path.name}: every row needs {len(head)} values")
            cols = {h: [r[i].strip() for r in body] for i, h in enumerate(head)}
        elif path.suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.dtype.names is None:
                raise ValidationError(field, f"{path.name}: needs a structured array (its field names name the "
                                             "parameters)")
            if arr.ndim != 1:
                raise ValidationError(field, f"{path.name}: needs a 1-D structured array (one row per start), "
                                             f"got shape {arr.shape}")
            for n in arr.dtype.names:
                if arr[n].ndim != 1:
                    raise ValidationError(field, f"{path.name}: field {n!r} has shape {arr.dtype[n].shape} per "
                                                 "start; each field holds one number per start")
            cols = {n: arr[n] for n in arr.dtype.names}
        else:
            import xarray as xr

            with xr.open_dataset(path) as ds:
                ones = [v.dims[0] for v in ds.data_vars.values() if v.ndim == 1]
                start = max(ones, key=ones.count) if ones else None  # the dimension most variables run along
                for k, v in ds.data_vars.items():  # a variable left out would leave its parameter at its default
                    if v.dims != (start,):
                        along = f" ({start!r})" if start else ""
                        raise ValidationError(field, f"{path.name}: variable {str(k)!r} has dimensions {v.dims}; "
                                                     f"every variable of a starts file is 1-D along the starts{along}")
                cols = {str(k): np.asarray(v.values) for k, v in ds.data_vars.items()}
    except ValidationError:
        raise
    except Exception as exc:  # noqa: BLE001  (a broken file: say which and why)
        raise ValidationError(field, f"{path.name}: cannot read ({exc})") from None
    out = {}
    for name, values in cols.items():
        kind = np.asarray(values).dtype.kind
        if kind in "bcV":  # bool, complex, compound (a netCDF complex variable read without auto_complex)
            out[name] = np.asarray(values)
            continue
        try:
            out[name] = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            out[name] = np.asarray(values, dtype=str)
    if len({len(v) for v in out.values()}) > 1:
        raise ValidationError(field, f"{path.name}: columns of different lengths")
    if path.suffix != ".csv":
        where = [f"start {i}" for i in range(len(next(iter(out.values()), ())))]
    return out, where


def sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load(sample_spec: Mapping[str, Any], system, base_dir: str | Path | None, grid_names: set[str]):
    """(parameter columns name -> (n,) float, labels (n,) str or None, the file's path) of ``[sample]``
    with ``from``; every column is a scalar parameter of ``system`` or the label column."""
    allowed = {"from", "label", "n", "seed", "__sha256__"}  # __sha256__: recorded by make_plan
    extra = sorted(set(sample_spec) - allowed)
    if extra:
        raise ValidationError(f"sample.{extra[0]}", "starts come from the file (sample.from): no distributions "
                                                   "beside it")
    ref = sample_spec["from"]
    if not isinstance(ref, str) or not ref.strip():
        raise ValidationError("sample.from", f"must be a file name, got {ref!r}")
    path = Path(ref)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    label_col = sample_spec.get("label", "label")
    if not isinstance(label_col, str):
        raise ValidationError("sample.label", f"must be a column name, got {label_col!r}")
    cols, where = _read(path)
    labels = cols.pop(label_col, None)
    if "label" in sample_spec and labels is None:
        raise ValidationError("sample.label", f"no column {label_col!r} in {path.name}")
    if labels is not None:
        labels = _labels(labels, label_col, where, path)
    if not cols:
        raise ValidationError("sample.from", f"{path.name}: no parameter column")
    for name, v in cols.items():
        if name not in system.params.by_name:
            raise ValidationError("sample.from", f"{path.name}: column {name!r} is not a parameter of "
                                                 f"{system.name}; known: {', '.join(p.name for p in system.params)}")
        if system.params[name].shape:
            raise ValidationError("sample.from", f"{path.name}: column {name!r}: only scalar parameters")
        if name in grid_names:
            raise ValidationError("sample.from", f"{path.name}: column {name!r} is also a grid axis")
        if v.dtype.kind in "bcV":
            raise ValidationError("sample.from", f"{path.name}: column {name!r} must hold real numbers")
        if v.dtype.kind != "f" or not np.all(np.isfinite(v)):
            bad = _first_bad(v)
            raise ValidationError("sample.from", f"{path.name}: column {name!r} must hold finite numbers; "
                                                 f"{where[bad]} holds {_shown(v[bad])}")
    n = len(next(iter(cols.values())))
    if "n" in sample_spec and sample_spec["n"] != n:
        raise ValidationError("sample.n", f"{path.name} holds {n} starts, not {sample_spec['n']}")
    return cols, labels, path


def _first_bad(v: np.ndarray) -> int:
    """The index of the first entry of a column that is not a finite number (text, blank, NaN or infinite)."""
    if v.dtype.kind == "f":
        return int(np.flatnonzero(~np.isfinite(v))[0])
    for i, x in enumerate(v):
        try:
            if not np.isfinite(float(x)):
                return i
        except (TypeError, ValueError):
            return i
    return 0


def _shown(x) -> str:
    text = str(x)
    return "a blank" if not text.strip() else repr(text) if not isinstance(x, (float, np.floating)) else text


def _labels(values: np.ndarray, column: str, where: list[str], path: Path) -> np.ndarray:
    """The label column as str, refusing a blank (or NaN) label: a label is another tool's outcome of its
    start, and a blank read as one more class would be mapped to an outcome and counted in the
    agreement as if that tool had answered."""
    values = np.asarray(values)
    text = np.array([str(x) for x in values.tolist()]) if values.dtype.kind == "V" else values.astype(str)
    blank = np.char.strip(text) == ""
    if values.dtype.kind == "f":
        blank |= np.isnan(values)
    if blank.any():
        i = int(np.flatnonzero(blank)[0])
        more = f" (and {int(blank.sum()) - 1} more)" if blank.sum() > 1 else ""
        raise ValidationError("sample.from", f"{path.name}: column {column!r} is blank at {where[i]}{more}: every "
                                             "start needs its label (the other tool's outcome); fill it in, or drop "
                                             "those starts")
    return text


def compare(outcome_names: list[str], codes: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    """Agreement and Matthews correlation of outcome ``codes`` (per start, flat) with file ``labels``
    (same order); see the module docstring."""
    from sklearn.metrics import matthews_corrcoef

    codes = np.asarray(codes).ravel()
    labels = np.asarray(labels).astype(str).ravel()
    mapping = {}
    for c in np.unique(codes):
        vals, cnt = np.unique(labels[codes == c], return_counts=True)
        mapping[outcome_names[int(c)]] = str(vals[np.argmax(cnt)])
    mapped = np.array([mapping[outcome_names[int(c)]] for c in codes])
    agree = float(np.mean(mapped == labels))
    mcc = float(matthews_corrcoef(labels, mapped))
    return {"agreement": agree, "mcc": mcc, "mapping": mapping,
            "one_to_one": len(set(mapping.values())) == len(mapping), "n": int(codes.size)}


def dataset_vars(plan, codes: np.ndarray, names: list[str]) -> dict[str, Any]:
    """``start_label`` (per start) and the comparison (pooled over the grid) for the dataset."""
    labels = plan.start_labels
    if labels is None:
        return {}
    lab = np.asarray(labels)
    per = np.broadcast_to(lab, np.asarray(codes).reshape(plan.shape).shape)
    r = compare(list(names), np.asarray(codes).ravel(), per.ravel())
    doc = ("majority mapping of each outcome to the file label most of its starts carry: "
           + json.dumps(r["mapping"]) + ("" if r["one_to_one"] else " (not one-to-one)"))
    return {
        "start_label": ("sample", lab.astype(object), {"long_name": "outcome of the start given in the starts file"}),
        "start_label_agreement": ((), r["agreement"], {"long_name": "fraction of starts whose outcome, mapped to "
                                                                    "the file's labels, equals their label",
                                                       "mapping": doc}),
        "start_label_mcc": ((), r["mcc"], {"long_name": "Matthews correlation coefficient of the mapped outcomes "
                                                        "against the file's labels", "mapping": doc}),
    }
