"""The one derive step: every variable a run computes from its trajectories' records.

The engines return per-trajectory records (late-window features, verdicts, solver status); this module
computes everything else the dataset holds -- the outcomes (through the plan's mapper,
:mod:`stabjax.mapping.mapper`), the mapper's own variables (template features, discovered attractors),
basin statistics, basin entropy, the agreement with a starts file's labels, the theory and the
provenance -- and :mod:`stabjax.run.dataset` lays them out (names, dims, attributes, CF). In the order a
run calls it:

``prepare(plan)``                   before the first chunk, and before a store exists: the mapper's state
                                    (the templates integrated at every grid point) and the refusals it
                                    can make without integrating (a refusal leaves nothing behind)
``chunk(plan, res, lo, hi, state)`` the stored record of trajectories [lo, hi): the engine's results,
                                    escaped verdicts diverged, and a per-trajectory mapper's outcome
                                    codes (stored and checksummed with the chunk)
``basin(plan, codes)``              basin statistics of the grid points whose samples ``codes`` hold
``initial(plan, state)``            what is known before the first trajectory (:class:`Derived` with
                                    basin placeholders): the store's layout
``finish(plan, records, state)``    what needs every trajectory: a whole-set mapper's outcomes, basin
                                    statistics, entropy, the starts file's agreement (:class:`Derived`)

What the outcome stage says about the result while it runs -- the warnings of :meth:`prepare`, of each chunk's
:func:`chunk` and of :func:`finish` (discovery's ``TransientWarning``, ``MixedWarning``, ...) -- is kept by
:func:`keeping` and stored in the result's ``warnings_json`` attribute (:data:`WARNINGS_ATTR`), besides being
shown on the terminal as before.
"""
from __future__ import annotations

import contextlib
import json
import os
import platform
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..fold import verdict as V
from ..fold.status import verdicts as status_verdicts
from ..mapping.basin import STATS as BASIN_STATS
from ..mapping.basin import basin_stats
from ..mapping.mapper import Mapped

THEORY_CHUNK = 262_144  # trajectories per host-side pass over the parameters


@dataclass
class Derived:
    """The computed variables of a run, for :func:`stabjax.run.dataset.build` to lay out.

    ``mapped``: the outcome codes (flat; None in the store's layout, whose codes are its own arrays), their
    scheme and the mapper's variables, or None (records without a solver status have no outcome);
    ``basin``: :func:`stabjax.mapping.basin.basin_stats` over the grid (None without ``[sample]``);
    ``entropy``: :func:`stabjax.mapping.entropy.basin_entropy` of a 2-D grid of starts, or None;
    ``starts``: the starts file's label variables (:func:`stabjax.plan.starts.dataset_vars`);
    ``theory``: (values (N,) per name, attributes per name, name of the main predicate), or None;
    ``provenance``: the dataset's global attributes that say what was computed and where;
    ``warnings``: what the outcome stage warned about the result (:func:`keeping`), or None where it is not
    known yet (the store's layout: added when the run finishes)."""

    mapped: Mapped | None = None
    basin: dict[str, Any] | None = None
    entropy: dict[str, Any] | None = None
    starts: dict[str, Any] = field(default_factory=dict)
    theory: tuple[dict[str, np.ndarray], dict[str, dict], str] | None = None
    provenance: dict[str, Any] = field(default_factory=dict)
    warnings: list[dict[str, str]] | None = None


# ---- what the outcome stage says about the result ------------------------------------------------------

WARNINGS_ATTR = "warnings_json"  # the result's attribute: JSON list of {"category": class name, "message": text}


def _of_the_result(category: type) -> bool:
    """Whether a warning of ``category`` is said about the result: a class of stabjax's own (discovery's
    ``TransientWarning``, ``MixedWarning``, ``SplitWarning``, ``RepresentativeWarning``, ``UnboundedWarning``),
    not the runner's word on its store (:class:`stabjax.run.store.StoreWarning`), nor another library's
    (JAX's or NumPy's deprecations and runtime warnings are not the result's)."""
    module = getattr(category, "__module__", "") or ""
    return (module == "stabjax" or module.startswith("stabjax.")) and not module.startswith("stabjax.run.") \
        and not issubclass(category, DeprecationWarning)


def _module_of(filename: str):
    """The loaded module whose file is ``filename`` (to show a warning again as :func:`warnings.warn` showed it:
    with that module's name and its registry of warnings already shown), or None."""
    for mod in list(sys.modules.values()):
        if getattr(mod, "__file__", None) == filename:
            return mod
    return None


@contextlib.contextmanager
def keeping(into: list[dict[str, str]]):
    """Keep in ``into`` what the block warns about the result ({"category", "message"}, in order, each once;
    :func:`_of_the_result`), whatever the warning filters say (a result's caveats do not depend on what the
    terminal shows), and raise every warning of the block again as it was raised (its file, line and module):
    the filters then show, hide or raise it as they would have, once the block is done."""
    caught: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield into
    finally:
        for w in caught:
            if _of_the_result(w.category):
                said = {"category": w.category.__name__, "message": str(w.message)}
                if said not in into:
                    into.append(said)
        modules: dict[str, Any] = {}
        for w in caught:
            if w.filename not in modules:
                modules[w.filename] = _module_of(w.filename)
            mod = modules[w.filename]
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno,
                                   module=mod.__name__ if mod is not None else None,
                                   registry=mod.__dict__.setdefault("__warningregistry__", {}) if mod is not None
                                   else None, source=w.source)


def merged(*said: list[dict[str, str]] | None) -> list[dict[str, str]]:
    """The warnings of several stages of one result, in order, each once."""
    out: list[dict[str, str]] = []
    for part in said:
        out += [w for w in part or () if w not in out]
    return out


def said_by_chunks(manifest: Mapping[str, Any]) -> list[dict[str, str]]:
    """What the chunks' outcome stage warned (each chunk's record ``warnings``, :func:`keeping` around
    :func:`chunk`), in chunk order: kept with the chunks, so a resumed run says what its first run's chunks said."""
    chunks = manifest.get("chunks", {})
    return merged(*(chunks[k].get("warnings") for k in sorted(chunks, key=int)))


def warnings_attr(said: list[dict[str, str]] | None) -> dict[str, str]:
    """The result's attribute of ``said`` (:data:`WARNINGS_ATTR`)."""
    return {WARNINGS_ATTR: json.dumps(merged(said), ensure_ascii=False)}


def prepare(plan) -> Any:
    """The mapper's state, integrated and checked before the run."""
    state = plan.mapper.prepare(plan)
    plan.mapper.check(plan, state)
    return state


def chunk(plan, res: Mapping[str, np.ndarray], lo: int, hi: int, state: Any) -> dict[str, np.ndarray]:
    """The stored record of trajectories [lo, hi): the engine's results with escaped trajectories'
    verdicts set to diverged (they ran away; not a solver failure) and, when the engine reports a solver
    status and the mapper is per trajectory, the ``outcome`` code of each trajectory (``state``:
    :func:`prepare`)."""
    mapper = plan.mapper
    out = {k: np.asarray(v) for k, v in res.items()}
    if not mapper.uses_verdicts:
        # the attitude classifier's summaries (verdict, decay exponents, flips) read observable 0 as an
        # error and 1 as a size: they mean nothing for a model with its own outcomes, and are left out
        out = {k: v for k, v in out.items() if k.startswith("feat_") or k not in V.SUMMARY_DOC}
    if "verdict" in out and "solver_status" in out:
        out["verdict"] = status_verdicts(out["solver_status"], out["verdict"])  # escaped: diverged (stabjax.fold.status)
    if "solver_status" in out and not mapper.whole_set:
        out["outcome"] = mapper.assign_chunked(plan, out, lo, hi, state)
    return out


def basin(plan, codes) -> dict[str, Any] | None:
    """Per-grid-point basin statistics over the samples of ``codes`` (shaped (..., n_sample)); None
    without ``[sample]``."""
    if not plan.n_sample:
        return None
    return basin_stats(np.asarray(codes), len(plan.scheme.names))


def initial(plan, state: Any, empty=None) -> Derived:
    """The variables known before the first trajectory, with placeholders for the basin statistics
    (the chunk store's layout; the statistics are written chunk by chunk and when the run finishes):
    ``empty(shape, dtype)`` (default: lazy Dask zeros, never computed). A whole-set mapper's outcome
    variables are not known yet: added when the run finishes."""
    mapper = plan.mapper
    out = Derived(theory=theory(plan), provenance=provenance(plan))
    if mapper.whole_set:
        return out
    out.mapped = Mapped(None, mapper.scheme, *mapper.variables(plan, state))
    if plan.n_sample:
        if empty is None:
            import dask.array as da

            def empty(shape, dtype):
                return da.zeros(shape, dtype=dtype, chunks=shape)
        shape = tuple(plan.shape[:-1]) + (len(mapper.scheme.names),)
        out.basin = {k: empty(shape, np.dtype(np.int64 if k == "count" else float)) for k in BASIN_STATS}
    return out


def finish(plan, records: Mapping[str, Any], state: Any, *, with_theory: bool = True) -> Derived:
    """Every computed variable from the records of every trajectory (flat, (N, ...) in the plan's order):
    the outcome codes (a per-trajectory mapper's ``outcome`` record, else the whole-set mapper run now),
    basin statistics, entropy and the starts file's agreement, and what the mapper warned meanwhile (``warnings``,
    :func:`keeping`); the theory and provenance unless ``with_theory`` is False (a store holds them from its
    creation)."""
    from ..mapping import entropy
    from ..plan import starts

    mapper = plan.mapper
    out = Derived(theory=theory(plan) if with_theory else None, provenance=provenance(plan) if with_theory else {},
                  warnings=[])
    with keeping(out.warnings):  # what the mapper says of the result: in its warnings_json too
        if "outcome" in records:
            out.mapped = Mapped(np.asarray(records["outcome"]).reshape(-1), mapper.scheme,
                                *mapper.variables(plan, state))
        elif "solver_status" in records:
            out.mapped = mapper.map_set(plan, {k: np.asarray(v) for k, v in records.items()}, state)
    if out.mapped is None:
        return out
    codes = out.mapped.codes.reshape(plan.shape)
    names = list(out.mapped.scheme.names)
    if plan.n_sample:
        out.basin = basin_stats(codes, len(names))
    out.starts = starts.dataset_vars(plan, codes, names)
    if entropy.applies(plan):  # one start per cell of a 2-D grid of initial conditions: Daza et al. (2016)
        out.entropy = entropy.basin_entropy(codes)
    return out


def theory(plan) -> tuple[dict[str, np.ndarray], dict[str, dict], str]:
    """The model's theorem predicates, their margins and derived quantities at every trajectory's
    parameters (flat, (N,)), their attributes, and the name of the main predicate (evaluated once per
    distinct set of the parameters each reads, :mod:`stabjax.model.theory_eval`)."""
    from ..model import theory_eval

    # filled in place chunk by chunk (not concatenated): at 10^7 trajectories the theory variables
    # alone are ~0.65 GB, and a concatenation would hold them twice
    full: dict[str, np.ndarray] = {}
    meta: dict[str, dict] = {}
    main = ""

    def put(key, lo, hi, val, dtype):
        if key not in full:
            full[key] = np.empty(plan.size, dtype=dtype)
        full[key][lo:hi] = np.broadcast_to(val, (hi - lo,))

    for lo in range(0, plan.size, THEORY_CHUNK):
        hi = min(plan.size, lo + THEORY_CHUNK)
        p = plan.system.check(plan.params_for(lo, hi))
        th = theory_eval.evaluate(plan.system, p)  # once per distinct set of the parameters it reads
        main = th.main
        for name, pred in th.predicates.items():
            put(f"theory_{name}", lo, hi, pred.ok, np.int8)
            put(f"margin_{name}", lo, hi, pred.margin, float)
            meta[f"theory_{name}"] = {"long_name": pred.doc, "flag_values": np.array([0, 1], np.int8),
                                      "flag_meanings": "not_guaranteed guaranteed",
                                      **({"guarantees": pred.outcome} if pred.outcome else {})}
            meta[f"margin_{name}"] = {"long_name": f"signed margin of: {pred.doc} (> 0 inside)"}
        for name, val in th.derived.items():
            put(f"derived_{name}", lo, hi, val, float)
            meta[f"derived_{name}"] = {"long_name": th.derived_doc.get(name, name)}
    return full, meta, main


def _git_commit() -> str:
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance(plan) -> dict[str, Any]:
    """What was computed (system, spec, settings, the model's identity) and where (versions, commit,
    device, machine, time): the dataset's global attributes."""
    import jax

    from ..config import versions
    from ..plan.identity import provenance as identity_attrs
    from ..plan.spec import jsonable

    return {
        "system": plan.system.name,
        "sweep_name": plan.name,
        "paper": plan.system.paper,
        "spec_json": json.dumps(jsonable(plan.spec)),
        # the parameters the run held fixed: one swept or sampled as a whole is none of them (one entry swept,
        # "J[0]", leaves the vector's other entries fixed: it stays, the axis overriding that entry)
        "fixed_params_json": json.dumps({k: np.asarray(v).tolist() for k, v in plan.fixed.items()
                                         if k not in plan.sample
                                         and not any(ax.param.name == k and ax.index is None for ax in plan.grid)}),
        # the known attractors are the runner's state (found by the run itself, a refinement's earlier rounds):
        # their count here, their identity in the fingerprint
        "integrate_json": json.dumps({**{k: v for k, v in plan.icfg.__dict__.items() if k != "known_attractors"},
                                      "settings": dict(plan.icfg.settings),
                                      **({"known_attractors": len(plan.icfg.known_attractors.labels)}
                                         if plan.icfg.known_attractors is not None else {})}),
        "verdict_json": json.dumps(plan.vcfg.__dict__),
        "system_ref": str(plan.spec.get("system", plan.system.name)),
        **identity_attrs(plan),  # fingerprint, model file and every local module it imports, with hashes
        "outcomes_from_verdicts": int(plan.mapper.uses_verdicts),
        "versions_json": json.dumps(versions()),
        "git_commit": _git_commit(),
        "device": str(jax.devices()[0].device_kind) + f" x{jax.device_count()}",
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus".strip(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
