"""Outcome mappers: the fold's features in, every trajectory's outcome out.

One protocol serves the three ways stabjax names what a trajectory reached (the shape of Attractors.jl's
``BasinMap``, formerly ``AttractorMapper``, and of pyBasin's predictors):

==================  =========================================  =============================================
mapper              outcomes                                   shape
==================  =========================================  =============================================
 ``Verdicts``       the attitude verdicts (``VERDICTS``)       per trajectory (:mod:`stabjax.mapping.verdicts`)
``Declared``        rules, then templates, then escape         per trajectory (:mod:`stabjax.mapping.declared`)
``Discovery``       the attractors found in the features       whole set (:mod:`stabjax.mapping.discover`)
==================  =========================================  =============================================

A plan holds its mapper (``Plan.mapper``), chosen once when the plan is made
(:func:`stabjax.mapping.classify.mapper_for`), so
nothing downstream asks which kind of outcome a run has: it asks the mapper. What a mapper answers:

``scheme``                  the outcomes' names (code = index) and colours known before the run (a
                            whole-set mapper's final names come with its :class:`Mapped`)
``uses_verdicts``           whether the engines must fold the attitude classifier (verdicts), or the
                            late-window features alone
``prepare(plan)``           work before the first trajectory, returning the mapper's state (the
                            templates' features, integrated at every grid point); a run stores it, so
                            that a resume classifies with the very numbers the first chunks used
``check(plan, state)``      refusals that need no integration (coinciding templates; a discovery that
                            cannot group the sweep's trajectories), made before anything is written
``assign(plan, results, index, state)``  codes (int8) of the trajectories at flat plan indices ``index``
                            (per-trajectory mappers: the runner stores them with each chunk)
``map_set(plan, results, state)``        every trajectory at once: a :class:`Mapped`
``prepare_at(plan, base)``  the state at explicit parameter points (one row per point: the templates
                            integrated there), for trajectories that are not the plan's own
``label(plan, results, params, state)``  codes of trajectories with explicit parameters (N, ...), ``state``
                            being each one's row of :meth:`prepare_at` (per-trajectory mappers; a search
                            such as the regions of attraction labels shocked starts with it)
``variables(plan, state)``  the mapper's own dataset variables known before the run

The trait ``whole_set`` picks the runner's path, as Attractors.jl's ``allows_mapper_u0``: a
per-trajectory mapper's codes are computed and stored with each chunk; a whole-set mapper runs once
every chunk is in. For code outside the runner (a refinement's rounds, the regions of attraction)
:func:`stabjax.mapping.classify.classify` is the one entry: "classify these results with this plan's mapper". Attractors that
a mapper found per grid point go through :mod:`stabjax.mapping.continuation` to be followed along a
parameter.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from ..model.outcomes import FAILED_NAME, UNCLASSIFIED, Outcomes

CHUNK = 262_144  # trajectories per host-side pass of a per-trajectory mapper (parameters and features in memory)


@dataclass(frozen=True)
class OutcomeScheme:
    """The outcomes of a plan: names (code = index), colours, and the declaration behind them (None: the
    attitude verdicts are the outcomes)."""

    names: tuple[str, ...]
    colors: tuple[str, ...]
    decl: Outcomes | None

    @property
    def from_verdicts(self) -> bool:
        return self.decl is None


@dataclass
class Mapped:
    """A mapper's answer for a set of trajectories: ``codes`` (N,) int8 into ``scheme.names``, and the
    mapper's own dataset variables (``data``, ``coords``: xarray ``(dims, values, attrs)`` tuples)."""

    codes: np.ndarray
    scheme: OutcomeScheme
    data: dict[str, Any] = field(default_factory=dict)
    coords: dict[str, Any] = field(default_factory=dict)


class Mapper:
    """The protocol (see the module docstring); subclasses set ``scheme`` and implement ``assign``
    (per trajectory) or ``map_set`` (whole set)."""

    kind: ClassVar[str] = ""
    whole_set: ClassVar[bool] = False
    uses_verdicts: ClassVar[bool] = False
    scheme: OutcomeScheme

    @property
    def decl(self) -> Outcomes | None:
        return self.scheme.decl

    def prepare(self, plan) -> Any:
        return None

    def check(self, plan, state: Any) -> None:
        return None

    def assign(self, plan, results: Mapping[str, np.ndarray], index: np.ndarray, state: Any) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} maps the whole set of trajectories (map_set)")

    def prepare_at(self, plan, base: Mapping[str, np.ndarray]) -> Any:
        return None

    def label(self, plan, results: Mapping[str, np.ndarray], params: Mapping[str, np.ndarray], state: Any) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} maps the whole set of trajectories (map_set)")

    def assign_chunked(self, plan, results: Mapping[str, np.ndarray], lo: int, hi: int, state: Any) -> np.ndarray:
        """Codes of the plan's trajectories [lo, hi) (``results``: theirs, flat), :data:`CHUNK` at a time."""
        out = np.empty(hi - lo, np.int8)
        for a in range(lo, hi, CHUNK):
            b = min(hi, a + CHUNK)
            sl = {k: np.asarray(v)[a - lo:b - lo] for k, v in results.items()}
            out[a - lo:b - lo] = self.assign(plan, sl, np.arange(a, b), state)
        return out

    def map_set(self, plan, results: Mapping[str, np.ndarray], state: Any) -> Mapped:
        n = len(np.asarray(results["solver_status"]))
        data, coords = self.variables(plan, state)
        return Mapped(self.assign_chunked(plan, results, 0, n, state), self.scheme, data, coords)

    def variables(self, plan, state: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        return {}, {}


def grid_layout(plan) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """(dims, shape) of the plan's grid points: its dims without ``sample``."""
    if plan.n_sample:
        return tuple(plan.dims[:-1]), tuple(plan.shape[:-1])
    return tuple(plan.dims), tuple(plan.shape)


def outcome_names(decl: Outcomes, found: tuple[str, ...], escape: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(names, colours) of named outcomes: ``found`` (rules, templates or discovered attractors) in the
    palette's order, then the escape outcome when the plan has one, then ``unclassified`` and ``failed``."""
    from ..model.outcomes import COLOR_ESCAPED, GREY_FAILED, GREY_UNCLASSIFIED, PALETTE

    names = tuple(found) + ((decl.escape,) if escape else ()) + (UNCLASSIFIED, FAILED_NAME)
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(found))]
    colors += ([COLOR_ESCAPED] if escape else []) + [GREY_UNCLASSIFIED, GREY_FAILED]
    return names, tuple(colors)
