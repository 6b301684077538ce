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
"""
from __future__ import annotations

import dataclasses
import importlib
import logging
from typing import Iterable, Mapping, NamedTuple

import numpy as np

from .base import Engine, Progress, Result, Unsupported

ORDER = ("native", "fused", "diffrax")
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


class Choice(NamedTuple):
    engine: str
    note: str  # "" when the first engine of the chain runs; else which declined and why


def resolve(system, icfg, vcfg=None, params: Mapping[str, np.ndarray] | None = None,
            static: Iterable[str] | None = None) -> Choice:
    """The engine that runs ``system`` with ``icfg``. With ``params`` (a batch of the sweep's
    parameters) the candidate also translates the system for them (:meth:`Engine.prepare`, cached),
    so a primitive without a rule is found here, once, and not in every chunk."""
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


def solve(name: str, system, params: Mapping[str, np.ndarray], icfg, vcfg, *, static: Iterable[str] | None = None,
          progress: Progress | None = None) -> Result:
    """Run engine ``name`` on one chunk. A :class:`stabjax.lyapunov.TangentSystem` (the model with its
    tangent dynamics) comes back in the model's own layout plus the exponent (``lyapunov``)."""
    from ..lyapunov import TangentSystem, split

    from ..early import stop_reasons

    res = get(name).solve(system, params, icfg, vcfg, static=static, progress=progress)
    if "fixed_point" in res:  # why each integration ended (stabjax.early.REASONS)
        res = dict(res)
        res["stop_reason"] = stop_reasons(res["solver_status"], res.pop("fixed_point"))
    if isinstance(system, TangentSystem):
        res = split(res, len(system.base.observables))
    return res


__all__ = ["Engine", "Unsupported", "Result", "Choice", "ORDER", "get", "chain", "resolve", "resolve_plan", "solve"]
