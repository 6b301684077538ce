"""The words on every figure, page and table of a result (the kit's other half, :mod:`stabjax.present.kit`):
axes in words with their symbol and unit (:func:`axis_label`), what the theory says (:func:`theory_words`),
headings and titles (:func:`heading`), discrete-choice axes as labelled categories, the fixed parameters
that matter, and what one cell of a map is. Every plot, the report and the viewer take their words from
here, so a result reads the same wherever it is shown."""
from __future__ import annotations

import json
import re
from typing import TYPE_CHECKING

import numpy as np

from . import kit

if TYPE_CHECKING:
    import xarray as xr

GREEK = {"alpha", "beta", "gamma", "delta", "epsilon", "mu", "nu", "sigma", "lambda", "omega", "theta", "phi", "psi",
         "xi", "eta", "kappa", "rho", "tau", "zeta", "chi"}
GREEK_CAPITAL = {"gamma", "delta", "theta", "lambda", "xi", "pi", "sigma", "phi", "psi", "omega"}  # in math text


def trajectory_noun(n: int) -> str:
    """The noun after a count of ``n`` trajectories: "1 trajectory", "2 trajectories"."""
    return "trajectory" if n == 1 else "trajectories"


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


def axis_label(ds: xr.Dataset, name: str, math: bool = True) -> str:
    """An axis in words a reader knows, with its symbol and unit -- "perturbation order sigma ($\\sigma$)",
    "initial angle ($\\theta_0$) [rad]" -- for any axis a result is drawn over: a grid axis (its coordinate's
    description; an entry of a vector parameter by the spec's name for it, ``A[1]``, not the coordinate's
    ``A_1``), a sampled parameter (``<name>_sample``'s description), a refined axis or any other parameter
    (the system's Param). The symbol alone when nothing describes it. ``math = False``: the name as it is
    written instead of the symbol in math text (a browser page, where ``$...$`` is not typeset)."""
    def sym(n):
        return symbol(n) if math else n

    if name in ds.coords:
        a = ds[name].attrs
        key = str(a.get("spec_key", name))
        return words(str(a.get("long_name", "")), sym(key if "[" in key else name), str(a.get("units", "")))
    if f"{name}_sample" in ds:
        a = ds[f"{name}_sample"].attrs
        return words(str(a.get("long_name", "")).removeprefix("sampled "), sym(name), str(a.get("units", "")))
    unit = str(ds[f"{name}_mid"].attrs.get("units", "")) if f"{name}_mid" in ds else ""
    prm = kit.param_of(ds, name)
    if prm is None:
        return words("", sym(name), unit)
    return words(prm.doc, sym(name), unit or prm.unit)


def theory_words(ds: xr.Dataset, main: str | None = None) -> str:
    """What the theory's predicate ``main`` (default: the result's main one) says, in words: its description
    as the result recorded it (``theory_<main>``), else as the system states it at its defaults (a refinement
    records the predicate's name only); the name when neither is known."""
    main = main if main is not None else str(ds.attrs.get("theory_main") or "")
    doc = str(ds[f"theory_{main}"].attrs.get("long_name", "")) if f"theory_{main}" in ds else ""
    if not doc:
        system = kit.system_of(ds)
        try:
            doc = system.theory(system.check(system.params.resolve({}))).predicates[main].doc
        except Exception:  # noqa: BLE001 -- a system without this predicate: its name is all there is
            doc = ""
    return words(doc, "", limit=60) or main


def main_predicate(ds: xr.Dataset) -> str | None:
    """The predicate the system names as "theory guarantees stability", when the result holds its margin."""
    main = ds.attrs.get("theory_main") or ""
    return main if f"margin_{main}" in ds else None


def described(ds: xr.Dataset) -> str:
    """The spec's ``description`` (the user's own words for the run), capitalised, or ""."""
    d = str((kit.json_attr(ds, "spec_json", {}) or {}).get("description", "") or "").strip()
    return d[:1].upper() + d[1:] if d else ""


def heading(ds: xr.Dataset) -> str:
    """What the result is, in one line: the spec's description, else the system and the run's name (which
    name a user's own run)."""
    return described(ds) or f"{ds.attrs.get('system', '')}: {ds.attrs.get('sweep_name', '') or 'result'}"


def error_words(ds: xr.Dataset, metric: str) -> str:
    """The y axis of a 1-D map in words: which error (the system's error observable, with its unit) and
    when -- "largest late angle between s and r [rad]" for ``error_max_late``, not the variable name."""
    system = kit.system_of(ds)
    obs = str(system.observable_doc[0]) if system is not None and system.observable_doc else "error"
    m = re.search(r"\s*\[([^\]]+)\]\s*$", obs)
    unit = f" [{m[1]}]" if m else ""
    obs = (obs[: m.start()] if m else obs).split(",")[0].strip() or "error"
    if metric == "error_max_late":
        return f"largest late {obs}{unit}"
    return f"{obs} at t1{unit}"


def attractor_label(name: str, where: dict[str, str]) -> str:
    """An outcome's name for a legend, with where the attractor lies when it was discovered
    ("fixed_point_1 at x = 8.5, y = 8.5, z = 23.4")."""
    return f"{name} {where[name]}" if where.get(name, "").startswith("at ") else \
        f"{name} ({where[name]})" if where.get(name) else name


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
    prm = kit.param_of(ds, dim)
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
        prm = kit.param_of(ds, k)
        label = _choice_labels(prm.doc, [value]) if prm is not None and prm.choices is not None else None
        out.append(label[0] if label else f"{symbol(k)} = {value:.4g}")
    return ", ".join(out[:limit])


def cell_note(ds: xr.Dataset) -> str:
    """What one cell of the map is: one trajectory, or the fraction of n random starts."""
    if "sample" in ds.dims:
        return f"one cell: fraction of n = {ds.sizes['sample']} random starts"
    return "one cell: one trajectory"
