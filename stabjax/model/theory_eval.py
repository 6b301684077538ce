"""A system's theory evaluated once per distinct set of the parameters it reads (issue 32).

A sweep's theory variables (``theory_*``, ``margin_*``, ``derived_*``) come from ``system.theory(p)`` on every
trajectory's parameters. Most theorems read only the model's parameters, which a sweep that samples starts
repeats for every start: Saakyan's ``l`` of (1.18) bisected a 4,001-point grid per trajectory, 32 of 36 s of a
sweep with 100 starts per grid point. :func:`evaluate` gives the same numbers at the cost of one evaluation per
distinct row of the parameters the theory reads:

1. **Which parameters it reads**, found by running it on one trajectory's parameters behind a mapping that
   records every value looked up (``p[k]``, ``p.get(k)``, ``items()``, ``values()``, ``dict(p)``, ``**p``: a
   copy of all of them reads all of them). A parameter whose value is never looked up cannot change a result.
   Conservative by construction: a theory that copies the whole mapping reads every parameter, starts
   included, and is evaluated per trajectory (the region test of Saakyan's (1.18) reads the start).
2. **Distinct rows** of those parameters, compared bit for bit (their bytes: -0.0 and 0.0 differ, NaN equals
   NaN), each represented by its first trajectory.
3. **One evaluation** on the representatives, again behind the recording mapping: if it read a parameter
   outside the set of step 1 (a theory whose lookups depend on values), the whole batch is evaluated as
   before instead. Otherwise every result is spread back to the trajectories of its row.

NumPy computes an element the same whatever else is in the batch, so the theory variables are those of the
per-trajectory evaluation, bit for bit (``tests/model/test_theory_eval.py``).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .system import Theory


class _Recording(Mapping):
    """A read-only view of a parameter mapping that records the keys whose values were looked up."""

    def __init__(self, p: Mapping[str, Any]):
        self._p = p
        self.read: set[str] = set()

    def __getitem__(self, key):
        value = self._p[key]
        self.read.add(key)
        return value

    def __iter__(self):
        return iter(self._p)

    def __len__(self):
        return len(self._p)

    def __contains__(self, key):
        return key in self._p


def _n(p: Mapping[str, Any]) -> int:
    return max((int(np.shape(v)[0]) for v in p.values() if np.ndim(v) >= 1), default=1)


def distinct_rows(*arrays) -> tuple[np.ndarray, np.ndarray]:
    """``(first, inverse)`` over the rows of ``arrays`` (each with leading dimension n, compared bit for bit):
    the index of each distinct row's first occurrence, and each row's distinct row (``first[inverse]`` has
    the values of every row)."""
    n = int(np.shape(arrays[0])[0])
    cols = [np.ascontiguousarray(np.asarray(a).reshape(n, -1)).view(np.uint8).reshape(n, -1) for a in arrays]
    block = np.ascontiguousarray(np.concatenate(cols, axis=1))
    keys = block.view(np.dtype((np.void, block.shape[1]))).ravel()
    _, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    return first, inv.reshape(-1)


def _rows(p: Mapping[str, Any], names, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`distinct_rows` of the per-trajectory parameters among ``names`` (others are one value for all)."""
    cols = [np.asarray(p[k]) for k in sorted(names) if np.ndim(p[k]) >= 1 and np.shape(p[k])[0] == n]
    if not cols:
        return np.zeros(1, np.int64), np.zeros(n, np.int64)
    return distinct_rows(*cols)


def _take(p: Mapping[str, Any], idx: np.ndarray, n: int) -> dict[str, Any]:
    return {k: (np.asarray(v)[idx] if np.ndim(v) >= 1 and np.shape(v)[0] == n else v) for k, v in p.items()}


def _spread(value, inv: np.ndarray, u: int):
    a = np.asarray(value)
    return a[inv] if a.ndim >= 1 and a.shape[0] == u else value


def evaluate(system, p: Mapping[str, Any]) -> Theory:
    """``system.theory(p)`` (``p``: checked, batched parameters, leading dimension N), evaluated once per
    distinct row of the parameters the theory reads (the module docstring); the same values."""
    n = _n(p)
    if n <= 1:
        return system.theory(p)
    try:
        probe = _Recording(_take(p, np.zeros(1, np.int64), n))
        system.theory(probe)
    except Exception:  # noqa: BLE001 - a theory that needs more than one row, or a real dict: as before
        return system.theory(p)
    names = probe.read
    first, inv = _rows(p, names, n)
    u = len(first)
    if u == n:  # every trajectory distinct in what the theory reads (it reads the starts): nothing to share
        return system.theory(p)
    rep = _Recording(_take(p, first, n))
    try:
        th = system.theory(rep)
    except Exception:  # noqa: BLE001
        return system.theory(p)
    if not rep.read <= names:  # lookups that depend on the values: the safe answer is the whole batch
        return system.theory(p)
    preds = {k: v._replace(ok=_spread(v.ok, inv, u), margin=_spread(v.margin, inv, u)) for k, v in th.predicates.items()}
    derived = {k: _spread(v, inv, u) for k, v in th.derived.items()}
    return Theory(preds, derived, dict(th.derived_doc), th.main)


def theory(system, params: Mapping[str, Any] | None = None) -> Theory:
    """Every theorem and corollary of ``system`` (a name, ``'file.py:Class'``, a System class or instance) at
    ``params`` (names to values; the system's defaults for the others): what ``stabjax theory SYSTEM --set ...``
    prints. The parameters are checked first as the command checks them -- an unknown name, a value that is not a
    number, NaN, or one outside the model's bounds (mu < 1 in paper A) is a :class:`stabjax.ValidationError`
    naming the field -- so a theorem is never evaluated on values it does not speak of (``system.theory(p)``
    itself, the model's hook, takes parameters already checked, as a sweep gives them)."""
    from ..config import setup_jax
    from .loading import resolve

    setup_jax()
    system = resolve(system)
    p = system.check(system.params.resolve(params))
    return system.theory(p)


__all__ = ["evaluate", "distinct_rows", "theory"]
