"""The one protocol every engine implements, and the exception an engine raises to decline."""
from __future__ import annotations

from typing import Callable, Iterable, Mapping

import numpy as np

# per-trajectory results: ``verdict``, the classifier summaries, ``n_steps``, ``n_rejected``,
# ``solver_status`` (codes: :mod:`stabjax.status`), each with leading dim N
Result = dict[str, np.ndarray]
Progress = Callable[[int, int], None]


class Unsupported(Exception):
    """This engine cannot run this system and configuration; the message says why.

    Raised by :meth:`Engine.prepare` and :meth:`Engine.solve` (a primitive without a lane-wise or
    C rule, no C compiler, another solver, a system-specific classifier).
    """


class Engine:
    """An integration engine: integrates a batch of trajectories and classifies each.

    ``name``                  as in ``[integrate] engine``
    ``compiles_per_shape``    True if each new batch shape costs a compilation (XLA engines): a caller
                              running batches of varying size (an explorer's rounds) pads them to a
                              few sizes; False if any batch runs on the same compiled code (native)
    ``supports(system, icfg)``  cheap check: None if it may run, else the reason it cannot
    ``prepare(...)``          translate and compile for this batch's shapes and constants (cached);
                              raises :class:`Unsupported` with the reason when it cannot
    ``default_chunk(plan)``   trajectories per chunk of a sweep when the user gives none
    ``bytes_per_trajectory(plan)``  working memory of one trajectory of a chunk
    ``solve(...)``            integrate and classify: :data:`Result`
    """

    name: str = ""
    compiles_per_shape: bool = True

    def supports(self, system, icfg) -> str | None:
        raise NotImplementedError

    def prepare(self, system, params: Mapping[str, np.ndarray], icfg, vcfg, static: Iterable[str] | None = None) -> None:
        reason = self.supports(system, icfg)
        if reason is not None:
            raise Unsupported(reason)

    def default_chunk(self, plan) -> int:
        raise NotImplementedError

    def bytes_per_trajectory(self, plan) -> int:
        raise NotImplementedError

    def solve(self, system, params: Mapping[str, np.ndarray], icfg, vcfg, static: Iterable[str] | None = None,
              progress: Progress | None = None) -> Result:
        raise NotImplementedError

    def __repr__(self):
        return f"<{self.name} engine>"


# results each trajectory of a queued engine keeps until its chunk is written: a generous upper
# bound on per-trajectory float outputs (summaries + theory)
N_SUMMARY_FIELDS = 24


def lane_engine_declines(engine: str, solver: str, system, icfg) -> str | None:
    """Why a lane engine (native, fused: one explicit method, the generic classifier) cannot run
    ``system`` with ``icfg``, or None."""
    if icfg.solver != solver:
        return f"solver {icfg.solver!r} (the {engine} engine runs {solver} only)"
    if system.classify is not None:
        return f"{system.name} has its own classify()"
    return None


def queued_bytes_per_trajectory(plan) -> int:
    """Native and fused engines: no per-checkpoint storage, only the parameters and the summaries
    of each queued trajectory (lane state lives in cache on CPU, on the device on a GPU)."""
    n_par = sum(int(np.prod(np.shape(v))) or 1 for v in plan.fixed.values())
    return 8 * (2 * n_par + 2 * N_SUMMARY_FIELDS + 64)
