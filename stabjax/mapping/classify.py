"""A plan's outcome mapper, chosen once (:func:`mapper_for`), and the one entry point for classifying
results with it from outside the runner (:func:`classify`)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..model.outcomes import Outcomes
from .declared import Declared
from .discover import Discovery
from .mapper import Mapped, Mapper
from .verdicts import Verdicts


def mapper_for(system, decl: Outcomes | None, escape: bool) -> Mapper:
    """The mapper of a declaration: None (``VERDICTS``) the verdicts, ``discover`` the discovery, else
    rules + templates + escape (``escape``: the plan has an escape radius)."""
    if decl is None:
        return Verdicts()
    if decl.discover:
        return Discovery(decl, escape)
    return Declared(system, decl, escape)


def classify(plan, results: Mapping[str, np.ndarray], state: Any = None) -> Mapped:
    """Classify ``results`` (the engines' per-trajectory records of every trajectory of ``plan``, flat, in
    the plan's order; a plan with explicit ``points`` lays each point's samples out contiguously) with the
    plan's mapper. ``state``: the mapper's :meth:`Mapper.prepare` output when already at hand (else the
    templates are integrated now, at the plan's grid points)."""
    mapper = plan.mapper
    if state is None:
        state = mapper.prepare(plan)
    return mapper.map_set(plan, {k: np.asarray(v) for k, v in results.items()}, state)
