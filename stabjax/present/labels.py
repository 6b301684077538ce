"""Text on the figures: discrete-choice axes as labelled categories, the fixed parameters that matter,
and what one cell of a map is. Kept apart from :mod:`stabjax.present.maps` so each can change alone."""
from __future__ import annotations

import json
import re

import numpy as np
import xarray as xr

GREEK = {"alpha", "beta", "gamma", "delta", "epsilon", "mu", "nu", "sigma", "lambda", "omega", "theta", "phi", "psi",
         "xi", "eta", "kappa", "rho", "tau", "zeta", "chi"}
GREEK_CAPITAL = {"gamma", "delta", "theta", "lambda", "xi", "pi", "sigma", "phi", "psi", "omega"}  # in math text


def symbol(name: str) -> str:
    """Axis label in math text: alpha -> $\\alpha$, omega0 -> $\\omega_0$, J_1 -> $J_1$, lam -> $\\lambda$,
    Omega_r -> $\\Omega_r$ (capital Greek), A[1] -> $A[1]$; a name of several letters that is no Greek letter
    is set upright (gain -> $\\mathrm{gain}$), not as a product of italic variables."""
    m = re.fullmatch(r"(\w+)(\[[\d, ]+\])", name)  # an entry of a vector or matrix parameter, as the spec names it
    if m:
        return symbol(m[1])[:-1] + m[2].replace(" ", "") + "$"
    base, _, sub = name.partition("_")
    digits = ""
    while base and base[-1].isdigit():
        digits = base[-1] + digits
        base = base[:-1]
    base = {"lam": "lambda", "eps": "epsilon"}.get(base, base)
    if base in GREEK or (base[:1].isupper() and base.lower() in GREEK_CAPITAL):
        b = "\\" + base
    else:
        b = base if len(base) <= 1 else f"\\mathrm{{{base}}}"
    sub = ",".join(f"\\mathrm{{{x}}}" if len(x) > 1 and x.isalpha() and x not in GREEK else
                   ("\\" + x if x in GREEK else x) for x in sub.split("_") if x)
    subs = ",".join(x for x in (digits, sub) if x)
    return f"${b}_{{{subs}}}$" if subs else f"${b}$"


def words(doc: str, name: str, unit: str = "", limit: int = 44) -> str:
    """An axis label a reader knows: the parameter's description in words (its first clause, at
    most ``limit`` characters), its symbol's name and its unit -- "perturbation order (sigma)",
    "initial angle (theta0) [rad]". A bare name when there is no description."""
    doc = str(doc or "").strip()
    # a help text that starts with the setting it applies to ("init = 1: ...") is described by what
    # follows the condition
    doc = re.sub(r"^\w+ = [\d.]+: (?=\D)", "", doc)
    doc = re.split(r";|: | - ", doc, maxsplit=1)[0].strip()
    doc = re.sub(r"\s*\([^()]*\)?$", "", doc).strip().rstrip(",.")  # a trailing remark in parentheses
    doc = re.sub(r"\s+(in|of|for|at)$", "", doc)
    if re.fullmatch(r"[\d\s.,]*", doc):  # a choice list ("0: ..., 1: ...") is no description
        doc = ""
    if len(doc) > limit:
        doc = doc[:limit].rsplit(" ", 1)[0] + "…"
    if not name:
        return doc
    text = f"{doc} ({name})" if doc and doc.lower() != name.lower() else name
    return text + (f" [{unit}]" if unit and unit not in ("-", "1", "dimensionless") else "")


def _param(ds: xr.Dataset, dim: str):
    """The system's Param behind grid axis ``dim`` (None when unknown, e.g. a dataset of another version)."""
    from ..model.loading import resolve as get_system

    key = ds[dim].attrs.get("spec_key", dim) if dim in ds.coords else dim
    try:
        return get_system(ds.attrs.get("system", "")).params[str(key).split("[")[0]]
    except Exception:  # noqa: BLE001 -- any lookup failure just means "plot as numbers"
        return None


def _choice_labels(doc: str, values) -> list[str] | None:
    """Short labels from a help string of the form "0: text; 1: text" (text cut at "(", ",", " = ")."""
    found = {}
    for num, text in re.findall(r"(?<![\w.])(\d+): ([^;()]+)", doc):
        for cut in (",", " = ", " ("):
            text = text.split(cut)[0]
        text = text.strip()
        if len(text) > 28:
            text = text[:28].rsplit(" ", 1)[0] + "…"
        found.setdefault(float(num), text)
    labels = [found.get(float(v)) for v in values]
    if any(lab is None or not lab for lab in labels) or len(set(labels)) < len(labels):
        return None
    return labels


def categories(ds: xr.Dataset, dim: str) -> list[str] | None:
    """Tick labels when grid axis ``dim`` is a discrete choice (model variant, active set, failed gyro),
    else None. Labels come from the parameter's help text ("k: meaning"), else "name = k"."""
    prm = _param(ds, dim)
    if prm is None or prm.choices is None:
        return None
    vals = ds[dim].values
    return _choice_labels(prm.doc, vals) or [f"{dim} = {float(v):g}" for v in vals]


def category_axis(ax, which: str, labels: list[str], name: str):
    set_ticks = ax.set_xticks if which == "x" else ax.set_yticks
    set_ticks(np.arange(len(labels)), labels, fontsize=8, rotation=15 if which == "x" and len(labels) > 3 else 0)
    (ax.set_xlabel if which == "x" else ax.set_ylabel)(name)


def fixed_note(ds: xr.Dataset, limit: int = 5, exclude=()) -> str:
    """The fixed scalar parameters that matter: those the theorems mention (e.g. mu on the default map),
    then those the spec sets in [params]; discrete choices by their label ("paper mapping"). ``exclude``:
    names not to list (the axes of a result whose dimensions are not named after them)."""

    try:
        fixed = json.loads(ds.attrs.get("fixed_params_json", "{}"))
        chosen = list(json.loads(ds.attrs.get("spec_json", "{}")).get("params", {}))
    except (ValueError, AttributeError):
        return ""
    words = set()
    for k, v in ds.data_vars.items():
        if k.startswith("theory_"):
            words |= set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", str(v.attrs.get("long_name", ""))))
    names = [k for k in fixed if k in words] + [k for k in chosen if k in fixed and k not in words]
    out = []
    for k in names:
        if np.size(fixed[k]) != 1 or k in ds.dims or k in exclude:
            continue
        value = float(np.ravel(fixed[k])[0])
        prm = _param(ds, k)
        label = _choice_labels(prm.doc, [value]) if prm is not None and prm.choices is not None else None
        out.append(label[0] if label else f"{symbol(k)} = {value:.4g}")
    return ", ".join(out[:limit])


def cell_note(ds: xr.Dataset) -> str:
    """What one cell of the map is: one trajectory, or the fraction of n random starts."""
    if "sample" in ds["verdict"].dims:
        return f"one cell: fraction of n = {ds.sizes['sample']} random starts"
    return "one cell: one trajectory"
