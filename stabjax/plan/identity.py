"""The identity of a run: one place that says which computation a result or a store holds.

Everything that resumes, refuses or warns asks this module: the chunk store (resume or refuse),
the Dask workers (re-planned plan = the client's plan), the refinement's partial store, the
dataset's provenance attributes and the map stamp of the CLI. Before, five modules each hashed a
different subset (one hashed the model file, another its first 16 hex digits, a third the spec
without the settings), so a change one of them ignored could be resumed by it and mixed.

An identity is a plain JSON-able dict built from

* the resolved plan: its spec (a ``--t1`` override is recorded in it), the system's name, the
  effective ``[integrate]`` and ``[verdict]`` settings, a digest of every parameter value the plan
  resolves to (a plan changed in code rather than through its spec differs here; a plan over
  explicit grid points, ``Plan.points``, includes the points), and its size;
* the model's source files: the file defining the system's class and every *local* module it
  imported (:func:`model_sources`; "local" = outside the standard library and the installed
  packages, e.g. a ``helpers.py`` beside the model), each with its sha256;
* the command-line overrides that are not in the spec (``batch_size``, ``t1``);
* the library versions (:func:`stabjax.config.versions`).

Library versions are the one part that does not refuse a resume: an upgraded jax between a kill
and a resume is recorded (the store's ``resumed_with_versions``) and reported, because refusing
would throw away hours of chunks for a patch release; :func:`compare` returns them separately as
warnings. Everything else refuses, with :func:`describe_changes` naming what changed.

:func:`fingerprint` is the short hash of the refusing part, for attributes and file stamps.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

# engine settings that choose how the work is spread, never what it computes, are left out: the
# engines declare which (stabjax.engines.SETTINGS, Setting.changes_results); this module names none


# ---- the model's source files --------------------------------------------------------------------


def sha256_file(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def model_sources(system) -> dict[str, str]:
    """``{path: sha256}`` of the model's source files: the file defining the system's class first,
    then every local module it imported (recorded by ``stabjax.model.loading._load_file`` when the
    model was loaded, with the hashes of the bytes that were executed). For a system not loaded
    from a file (built in, ``module:Class``, a class given in Python) the defining file is hashed
    now, with the local modules it imports by name (:func:`stabjax.model.loading.local_sources`); ``{}``
    when the class has no file."""
    cls = type(system)
    recorded = vars(cls).get("_stabjax_sources")  # set on this class, not inherited from a model's base
    if recorded:
        return dict(recorded)
    from ..model.loading import local_sources, source_file

    local = local_sources(cls)  # a user's class given in Python or as module:Class: its local imports too
    if local:
        return local

    f = source_file(system)
    if f is None or not f.exists():
        return {}
    return {str(f): sha256_file(f)}


def _model_entry(system) -> dict[str, Any]:
    """The identity's ``model`` section: the defining file's name and hash, and the imported local
    modules' (names relative to the model's folder when inside it)."""
    src = model_sources(system)
    if not src:
        return {"file": "?", "sha256": "unknown", "imports": {}}
    files = list(src)
    main = Path(files[0])
    imports = {}
    for f in files[1:]:
        p = Path(f)
        try:
            name = str(p.relative_to(main.parent))
        except ValueError:
            name = str(p)
        imports[name] = src[f]
    return {"file": main.name, "sha256": src[files[0]], "imports": imports}


# ---- the identity ---------------------------------------------------------------------------------


def plain(x):
    """JSON-able copy of ``x`` (dataclasses, arrays, numpy scalars, non-finite floats as text)."""
    if is_dataclass(x) and not isinstance(x, type):
        return plain(asdict(x))
    if isinstance(x, Mapping):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        return plain(x.item())
    if isinstance(x, float) and not np.isfinite(x):
        return repr(x)
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    return repr(x)


def parameter_digest(plan) -> str:
    """Hash of every parameter value a plan resolves to (grid axes, samples, fixed values: each
    small, the cartesian product is not formed) and, for a plan over explicit grid points
    (``Plan.points``, an explorer's round), those points in their order: two rounds of the same
    size at other points are other computations, and a store or a worker must tell them apart
    from the identity alone (no caller-side digest in the overrides)."""
    h = hashlib.sha256()
    items = ([(f"grid:{a.key}", a.values) for a in plan.grid] + sorted((f"sample:{k}", v) for k, v in plan.sample.items())
             + sorted((f"fixed:{k}", v) for k, v in plan.fixed.items()))
    points = getattr(plan, "points", None)
    if points is not None:
        items.append(("points", points))
    for name, arr in items:
        a = np.ascontiguousarray(np.asarray(arr, dtype=float))
        h.update(name.encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()[:16]


def identity(plan, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Everything that decides the numbers of ``plan`` run with ``overrides`` (see the module
    docstring); ``versions`` is informative (a change warns, see :func:`compare`)."""
    from ..version import __version__
    from .. import engines
    from ..config import versions

    icfg = plain(plan.icfg)
    icfg["settings"] = engines.result_settings(icfg.get("settings") or {})
    if not icfg["settings"]:  # as identities were before engine settings moved (stores resume)
        del icfg["settings"]
    for k in ("attractor_stop", "known_attractors"):  # unset: as identities were before the recurrence stop
        if not icfg.get(k):
            icfg.pop(k, None)
    spec = plain(plan.spec)
    for table in ("integrate", "engine"):  # the same settings as written in the spec
        if isinstance(spec.get(table), Mapping):
            spec[table] = engines.result_settings(spec[table])
    if spec.get("engine") == {}:
        del spec["engine"]
    return {
        "spec": spec,
        "system": plan.system.name,
        "model": _model_entry(plan.system),
        "overrides": plain({k: v for k, v in (overrides or {}).items() if v is not None}),
        "integrate": icfg,
        "verdict": plain(plan.vcfg),
        "parameters": parameter_digest(plan),
        "stabjax": __version__,
        "size": int(plan.size),
        "versions": versions(),
    }


def _refusing(ident: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in ident.items() if k != "versions"}


def digest(obj) -> str:
    return hashlib.sha256(json.dumps(plain(obj), sort_keys=True).encode()).hexdigest()[:16]


def fingerprint(plan, overrides: Mapping[str, Any] | None = None) -> str:
    """Short hash of the part of the identity that refuses a resume (library versions excluded)."""
    return digest(_refusing(identity(plan, overrides)))


def spec_digest(spec: Mapping[str, Any]) -> str:
    """Digest of a spec as results store it (``spec_json``): stamps a map with the spec it shows.
    (Kept byte-for-byte as the stamps already shipped in ``results/`` were computed.)"""
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def compare(old: Mapping[str, Any], new: Mapping[str, Any], since: str = "") -> tuple[list[str], list[str]]:
    """(refusals, warnings) between a recorded identity and the current one: refusals name every
    change of the computation, warnings the library versions that differ (``since``: :func:`describe_changes`)."""
    refusals = describe_changes(old, new, since) if _refusing(old) != _refusing(new) else []
    warnings = []
    ov, nv = old.get("versions") or {}, new.get("versions") or {}
    for k in sorted(set(ov) | set(nv)):
        if ov.get(k) != nv.get(k):
            warnings.append(f"{k} {ov.get(k, 'unset')} -> {nv.get(k, 'unset')}")
    return refusals, warnings


def _flat(d, prefix=""):
    out = {}
    if isinstance(d, Mapping) and d:
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = d
    return out


def _short(v, none="none"):
    if v is None:
        return none
    s = json.dumps(v) if not isinstance(v, str) else v
    return s if len(s) <= 60 else s[:57] + "..."


STARTS_SUM = "sample.__sha256__"  # the starts file's content, recorded in the spec by make_plan


def describe_changes(old: Mapping[str, Any], new: Mapping[str, Any], since: str = "") -> list[str]:
    """Human-readable list of what differs between two identities (most specific first); ``since``: the
    run the old identity is of ("the interrupted run"), for the changes a user made in a file."""
    changes = []
    later = f" since {since}" if since else ""

    def diff(section, label):
        a, b = _flat(old.get(section, {})), _flat(new.get(section, {}))
        for k in sorted(set(a) | set(b)):
            if a.get(k, "<unset>") != b.get(k, "<unset>"):
                changes.append(f"{label}{k}: {_short(a.get(k, '<unset>'))} -> {_short(b.get(k, '<unset>'))}")

    spec_old, spec_new = _flat(old.get("spec", {})), _flat(new.get("spec", {}))
    starts = spec_old.get(STARTS_SUM) != spec_new.get(STARTS_SUM) and \
        spec_old.get("sample.from") == spec_new.get("sample.from") is not None
    if starts:  # the file's sha256 and the parameters drawn from it are what a user did: edit the file
        changes.append(f"the starts file {spec_new['sample.from']} changed{later}")
        old, new = ({**d, "spec": {**d["spec"], "sample": {k: v for k, v in d["spec"]["sample"].items()
                                                            if k != "__sha256__"}}, "parameters": None}
                    for d in (old, new))
    diff("spec", "spec ")
    for k in sorted(set(old.get("overrides", {})) | set(new.get("overrides", {}))):
        a, b = old.get("overrides", {}).get(k), new.get("overrides", {}).get(k)
        if k == "batch_size" and old.get("size") != new.get("size"):
            continue  # a chunk no larger than the run follows the size (listed below), not an option the user gave
        if a != b:
            flag = "--" + k.replace("_", "-")
            changes.append(f"command-line {flag}: {_short(a, 'not given')} -> {_short(b, 'not given')}")
    o, n = old.get("model") or {}, new.get("model") or {}
    if o.get("file") != n.get("file") or o.get("sha256") != n.get("sha256"):
        changes.append(f"model source {n.get('file')}: sha256 {str(o.get('sha256'))[:16]} -> {str(n.get('sha256'))[:16]}")
    oi, ni = o.get("imports") or {}, n.get("imports") or {}
    for k in sorted(set(oi) | set(ni)):
        if oi.get(k) != ni.get(k):
            a, b = (oi.get(k) or "not imported")[:16], (ni.get(k) or "not imported")[:16]
            changes.append(f"model module {k} (imported by {n.get('file') or o.get('file')}): sha256 {a} -> {b}")
    if not changes:  # e.g. a programmatic Plan with another IntegrateConfig
        diff("integrate", "integrate.")
        diff("verdict", "verdict.")
    for k in ("system", "stabjax", "size", "parameters"):
        if old.get(k) != new.get(k):
            changes.append(f"{k}: {_short(old.get(k))} -> {_short(new.get(k))}")
    if not changes and _refusing(old) != _refusing(new):
        changes.append("the run's fingerprint")
    return changes


# ---- what a result records --------------------------------------------------------------------------


def provenance(plan) -> dict[str, str]:
    """Dataset attributes that identify the run: ``fingerprint``, the model file and its hash,
    and every local module it imported with its hash (``model_sources_json``)."""
    src = model_sources(plan.system)
    files = list(src)
    return {
        "fingerprint": fingerprint(plan),
        "model_file": files[0] if files else "",
        "model_sha256": src[files[0]] if files else "unknown",
        "model_sources_json": json.dumps(src),
    }


def changed_sources(attrs: Mapping[str, Any]) -> list[str]:
    """The model files recorded in a result's attributes that differ on disk now (for a warning)."""
    try:
        src = json.loads(attrs.get("model_sources_json") or "{}")
    except ValueError:
        src = {}
    if attrs.get("model_file") and attrs.get("model_sha256"):  # results written before model_sources_json too
        src.setdefault(attrs["model_file"], attrs["model_sha256"])
    out = []
    for f, sha in src.items():
        if sha and sha != "unknown" and os.path.exists(f):
            now = sha256_file(f)
            if now != sha:
                out.append(f"{f} (sha256 {sha[:12]} then, {now[:12]} now)")
    return out

