"""The one protocol every engine implements, and the exception an engine raises to decline."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

import numpy as np

# per-trajectory results: ``verdict``, the classifier summaries, ``n_steps``, ``n_rejected``,
# ``solver_status`` (codes: :mod:`stabjax.fold.status`), each with leading dim N
Result = dict[str, np.ndarray]
Progress = Callable[[int, int], None]


# the setting every engine that runs OS threads reads, and that whoever spreads the work over
# processes (a Dask worker) sets: the one setting name the layers above may write (never read)
THREADS = "threads"


@dataclass(frozen=True)
class Setting:
    """One tuning setting an engine declares (``[engine]`` table of a spec, or ``[integrate]``).

    An integer in [lo, hi]; ``default`` (0) means "the engine chooses". ``changes_results``: False
    when no value changes any result in any bit (the identity of a run, :mod:`stabjax.plan.identity`,
    then ignores it: a resume with another value continues the same run); True when it may.
    Declarations are plain data kept in :mod:`stabjax.engines` (importing them imports no engine).
    """

    name: str
    lo: int
    hi: int
    doc: str
    default: int = 0
    changes_results: bool = False

    def check(self, value: Any, field: str) -> int:
        from ..validate import integer

        return integer(value, field, lo=self.lo, hi=self.hi)


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
    ``settings``              the :class:`Setting` s it reads from ``icfg.settings`` (declared in
                              :data:`stabjax.engines.SETTINGS`); :meth:`setting` reads one
    """

    name: str = ""
    compiles_per_shape: bool = True

    @property
    def settings(self) -> tuple[Setting, ...]:
        from . import SETTINGS

        return SETTINGS.get(self.name, ())

    def setting(self, icfg, name: str) -> int:
        """The value of this engine's setting ``name`` in ``icfg`` (its declared default when unset)."""
        decl = {s.name: s for s in self.settings}[name]
        return int(icfg.settings.get(name, decl.default))

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
