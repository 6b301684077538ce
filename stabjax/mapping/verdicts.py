"""The attitude verdicts as outcomes: the mapper of the declaration ``outcomes = VERDICTS`` (the built-in
attitude systems; :mod:`stabjax.fold.verdict` computes the verdicts inside the engines)."""
from __future__ import annotations

import numpy as np

from ..fold import status as S
from .mapper import Mapper, OutcomeScheme


class Verdicts(Mapper):
    """The attitude verdicts are the outcomes (``outcomes = VERDICTS``): the verdict at t1, an escaped
    trajectory diverged (:func:`stabjax.fold.status.verdicts`)."""

    kind = "verdicts"
    uses_verdicts = True

    def __init__(self):
        from ..fold import verdict as V

        self.scheme = OutcomeScheme(tuple(V.NAMES), tuple(V.COLORS), None)

    def assign(self, plan, results, index, state) -> np.ndarray:
        v = S.verdicts(np.asarray(results["solver_status"]), np.asarray(results["verdict"]))
        return (v[..., -1] if v.ndim > 1 else v).astype(np.int8)

    def label(self, plan, results, params, state) -> np.ndarray:
        return self.assign(plan, results, None, state)
