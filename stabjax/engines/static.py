"""Parameters equal across a sweep, compiled into the native and fused engines as constants."""
from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np


class StaticParams:
    """Hashable batch-constant parameter values (part of the engines' compile-cache keys)."""

    def __init__(self, static: Mapping[str, np.ndarray]):
        self.values = {k: np.asarray(v, np.float64) for k, v in sorted(static.items())}
        self.key = tuple((k, v.shape, v.tobytes()) for k, v in self.values.items())

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, StaticParams) and self.key == other.key


def split_static(params: Mapping[str, np.ndarray], static: Iterable[str] | None = None):
    """(static values, dynamic arrays). ``static=None``: every parameter equal across the batch."""
    p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
    if static is None:
        static = [k for k, v in p.items() if v.shape[0] > 0 and np.array_equal(v, np.broadcast_to(v[:1], v.shape))]
    # a name claimed static but varying in this batch stays dynamic: correctness over compile reuse
    static = {k for k in static if k in p and np.array_equal(p[k], np.broadcast_to(p[k][:1], p[k].shape))}
    return {k: p[k][0] for k in p if k in static}, {k: v for k, v in p.items() if k not in static}
