"""Integration engines behind one protocol (:class:`~stabjax.engines.base.Engine`).

* ``native`` (:mod:`stabjax.engines.native`): the model's jaxprs as C, one SIMD Tsit5 loop per
  core (CPU with a C compiler);
* ``fused`` (:mod:`stabjax.engines.fused`): one XLA loop over lanes of trajectories (GPU, and CPU
  without a C compiler);
* ``diffrax`` (:mod:`stabjax.engines.diffrax_engine`): vmapped ``diffrax.diffeqsolve``, every
  solver and every system.

Shared pieces: :mod:`.tsit5` (tableau, dense output, controller constants), :mod:`.lanes` (the
lane-wise jaxpr evaluator, with the list of JAX constructs the fast engines run), :mod:`.unrolled`
(small dense linear algebra as scalar operations, for the lane evaluator), :mod:`.vmath` (vectorisable log, sin, cos), :mod:`.static`
(batch-constant parameters). No engine imports another.

The engine of a sweep is resolved once per plan (:func:`resolve_plan`): ``[integrate] engine =
"auto"`` tries native, then fused, then diffrax; a named engine is tried first, then the others in
that order. An engine that declines (:meth:`Engine.supports`, or :class:`Unsupported` while
translating the system) hands over to the next, and the reason is kept on the plan, written to the
dataset attribute ``engine_note`` and logged as one line.

Settings: each engine declares the tuning settings it reads (:data:`SETTINGS`, plain data here, so
that validating a spec imports no engine and never diffrax). A spec gives them in its ``[engine]``
table (or, as before, in ``[integrate]``); :func:`integrate_config` checks each against the
declarations of the engines the choice may run, and they travel to the engine as
``IntegrateConfig.settings``, a mapping the layers above pass on without reading. The identity of
a run keeps only the settings declared to change results (:func:`result_settings`).
"""
from __future__ import annotations

import dataclasses
import importlib
import logging
from typing import Any, Iterable, Mapping, NamedTuple

import numpy as np

from .base import THREADS, Engine, Progress, Result, Setting, Unsupported

ORDER = ("native", "fused", "diffrax")
CHOICES = ("auto",) + ORDER  # the values of ``[integrate] engine``
# what each engine reads from ``icfg.settings`` (Engine.settings); 0: the engine chooses
SETTINGS: dict[str, tuple[Setting, ...]] = {
    "native": (
        Setting(THREADS, 0, 4096, "native engine: OS threads (0: $STABJAX_THREADS, else one per core)"),
        # measured: a dense-checkpoint run (t1 = 50, 4000 checkpoints) gives last-bit different
        # summaries at width 4 or 1 than at 16 (vector libm calls of another width): kept in the identity
        Setting("width", 0, 1024, "native engine: trajectories per SIMD block (0: 16, or 8 for a classifier state above 64 doubles)", changes_results=True),
    ),
    # lanes are independent and each lane runs the same vector code: any lane count gives the same bits
    "fused": (Setting("lanes", 0, 2**24, "fused engine: trajectories stepped side by side per device "
                                         "(0: 256 on CPU, 2^18 on a GPU)"),),
    "diffrax": (),
}
_MODULES = {"native": "stabjax.engines.native", "fused": "stabjax.engines.fused",
            "diffrax": "stabjax.engines.diffrax_engine"}
log = logging.getLogger("stabjax.engines")


def get(name: str) -> Engine:
    """The engine called ``name`` (its module is imported on first use: diffrax only when needed)."""
    try:
        return importlib.import_module(_MODULES[name]).ENGINE
    except KeyError:
        raise ValueError(f"unknown engine {name!r}; choose from {', '.join(ORDER)}") from None


def chain(choice: str) -> tuple[str, ...]:
    """Engines to try, in order, for ``[integrate] engine = choice``."""
    if choice == "auto":
        return ORDER
    return (choice,) + tuple(e for e in ORDER if e != choice)


def check_choice(choice: Any, field: str = "integrate.engine") -> str:
    if not isinstance(choice, str) or choice not in CHOICES:
        from ..errors import ValidationError

        raise ValidationError(field, f"unknown engine {choice!r}; choose from {', '.join(CHOICES)}")
    return choice


def declared(choice: str = "auto") -> dict[str, list[Setting]]:
    """Setting name -> its declarations by the engines that ``choice`` may run (its chain: the
    named engine first, then those it falls back to)."""
    out: dict[str, list[Setting]] = {}
    for name in chain(choice):
        for s in SETTINGS[name]:
            out.setdefault(s.name, []).append(s)
    return out


def check_settings(choice: str, settings: Mapping[str, Any] | None, section: str = "engine") -> dict[str, int]:
    """``settings`` checked against the declarations of the engines ``choice`` may run: an unknown
    name, a wrong type or a value out of range raises a ValidationError naming ``section.name``."""
    from ..errors import ValidationError

    decl = declared(check_choice(choice))
    out = {}
    for k, v in dict(settings or {}).items():
        if k not in decl:
            raise ValidationError(f"{section}.{k}", f"unknown engine setting; the engines of engine = {choice!r} "
                                                    f"declare: {', '.join(sorted(decl)) or 'none'}")
        for s in decl[k]:
            v = s.check(v, f"{section}.{k}")
        out[k] = v
    return out


def execution_only(name: str) -> bool:
    """True when ``name`` is a setting that no engine declares as changing results."""
    ds = declared().get(name)
    return bool(ds) and not any(s.changes_results for s in ds)


def result_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """``settings`` (or a spec table) without the entries that change no result (the identity's view)."""
    return {k: v for k, v in dict(settings).items() if not execution_only(k)}


def integrate_config(table: Mapping[str, Any] | None, engine_table: Mapping[str, Any] | None = None, *,
                     default_t1: float | None = None):
    """An :class:`~stabjax.config.IntegrateConfig` from a spec's ``[integrate]`` table and its ``[engine]``
    table of engine settings. An engine setting may stand in either table (``[integrate]`` for the
    specs written before ``[engine]``), not in both; each is checked by :func:`check_settings`."""
    from dataclasses import fields

    from ..config import IntegrateConfig
    from ..errors import ValidationError
    from ..validate import table as as_table

    core_names = {f.name for f in fields(IntegrateConfig)} - {"settings"}
    integ = dict(as_table(table if table is not None else {}, "integrate"))
    eng = dict(as_table(engine_table if engine_table is not None else {}, "engine"))
    choice = check_choice(integ.get("engine", "auto"))
    known = declared(choice)
    moved = {k: integ.pop(k) for k in list(integ) if k not in core_names and k in known}
    for k in integ:
        if k not in core_names:
            raise ValidationError(f"integrate.{k}", f"unknown field; known: {', '.join(sorted(core_names))}; "
                                                    f"engine settings: {', '.join(sorted(known)) or 'none'}")
    for k in moved:
        if k in eng:
            raise ValidationError(f"engine.{k}", f"also given as integrate.{k}: give it once (in [engine])")
    settings = {**check_settings(choice, moved, "integrate"), **check_settings(choice, eng, "engine")}
    icfg = IntegrateConfig.from_dict(integ, default_t1=default_t1)
    return icfg.replace(settings=settings) if settings else icfg


def with_threads(icfg, n: int | None):
    """``icfg`` with :data:`~stabjax.engines.base.THREADS` set to ``n`` (None or 0: unchanged): how a
    Dask worker tells its engine how many threads it may use."""
    return icfg if not n else icfg.replace(settings={**icfg.settings, THREADS: int(n)})


class Choice(NamedTuple):
    engine: str
    note: str  # "" when the first engine of the chain runs; else which declined and why


def resolve(system, icfg, vcfg=None, params: Mapping[str, np.ndarray] | None = None,
            static: Iterable[str] | None = None) -> Choice:
    """The engine that runs ``system`` with ``icfg``. With ``params`` (a batch of the sweep's
    parameters) the candidate also translates the system for them (:meth:`Engine.prepare`, cached),
    so a primitive without a rule is found here, once, and not in every chunk."""
    check_settings(icfg.engine, icfg.settings, "integrate.settings")  # plain data: imports no engine
    notes = []
    for name in chain(icfg.engine):
        eng = get(name)
        try:
            if params is None:
                reason = eng.supports(system, icfg)
                if reason is not None:
                    raise Unsupported(reason)
            else:
                eng.prepare(system, params, icfg, vcfg or system.verdict, static)
        except Unsupported as exc:
            notes.append(f"{name}: {exc}")
            continue
        return Choice(name, "" if not notes else f"engine {name} runs {system.name} ({'; '.join(notes)})")
    raise AssertionError("the diffrax engine runs every system")


def resolve_plan(plan, static: Iterable[str] | None = None):
    """``plan`` with its engine resolved (a new plan; unchanged if already resolved). The reason for
    a fallback is logged once (logger ``stabjax.engines``) and kept as ``plan.engine_note``."""
    if plan.engine:
        return plan
    probe = plan.params_for(0, min(plan.size, 2))
    choice = resolve(plan.integrated, plan.icfg, plan.vcfg, probe, static)
    if choice.note:
        log.warning(choice.note)
    return dataclasses.replace(plan, engine=choice.engine, engine_note=choice.note)


def trajectory_fn(system, icfg):
    """``f(ts, params) -> {"ys", "obs", "status", "n_steps"}``: one trajectory with its full state at
    ``ts`` (:func:`stabjax.engines.simulate.simulate`). The diffrax engine, which saves states, runs it (imported here,
    on first use)."""
    from .diffrax_engine import simulate_fn

    return simulate_fn(system, icfg)


def solve(name: str, system, params: Mapping[str, np.ndarray], icfg, vcfg, *, static: Iterable[str] | None = None,
          progress: Progress | None = None) -> Result:
    """Run engine ``name`` on one chunk. A :class:`stabjax.model.tangent.TangentSystem` (the model with its
    tangent dynamics) comes back in the model's own layout plus the exponent (``lyapunov``)."""
    from ..model.tangent import TangentSystem, split

    from ..fold.stops import stop_reasons, substitute

    res = get(name).solve(system, params, icfg, vcfg, static=static, progress=progress)
    if "fixed_point" in res:  # why each integration ended (stabjax.fold.stops.REASONS)
        if icfg.known_attractors is not None:  # stopped near attractor k: its representative's features
            res = substitute(res, icfg.known_attractors)
        res = dict(res)
        res["stop_reason"] = stop_reasons(res["solver_status"], res.pop("fixed_point"))
    if isinstance(system, TangentSystem):
        res = split(res, len(system.base.observables))
    return res


__all__ = ["Engine", "Unsupported", "Result", "Setting", "Choice", "ORDER", "CHOICES", "SETTINGS", "THREADS", "get",
           "chain", "check_choice", "check_settings", "declared", "execution_only", "result_settings",
           "integrate_config", "with_threads", "trajectory_fn", "resolve", "resolve_plan", "solve"]
