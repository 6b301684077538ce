"""Every per-trajectory ``solver_status`` an engine returns, and what it means for a verdict and an outcome.

The one place these codes and their consequences are defined: the engines write the codes, and the sweep,
the refinement and the outcome assignment read them only through the functions below, so that a trajectory
gets the same label whichever path reports it (before, an escaped point was "failed" in a refinement and
"diverged" in a sweep, because the escape-to-diverged rule lived in the sweep's dataset assembly).

Codes: diffrax's ``RESULTS`` numbering below 100 (0 success, 1 max_steps_reached, any other code another
solver failure), the project's own from 100 on:

=========  ====  ========================================================================================
OK            0  reached t1
MAX_STEPS     1  step budget exhausted, step size collapsed, or the state or its derivative turned
                 non-finite (stopped at once)
ESCAPED     100  an accepted state left the ball ``max_i |y_i| <= escape_radius`` (stopped at once): the
                 trajectory ran away, which is an answer (diverged / the escape outcome), not a failure
=========  ====  ========================================================================================

Only array operations are used (``np.where``, comparisons), so the functions also work on the lazy dask
arrays of a big sweep read back from its store.
"""
from __future__ import annotations

import numpy as np

from ..config import VERDICT_NAMES

OK = 0
MAX_STEPS = 1
ESCAPED = 100
NAMES = {OK: "ok", MAX_STEPS: "max_steps", ESCAPED: "escaped"}  # other codes: "solver failure (diffrax code)"

# diffrax's RESULTS names in code order (diffrax 0.7; tests/run/test_cf.py compares them with the installed
# diffrax): written here so that labelling a dataset's solver_status does not import diffrax, and its
# dependencies, in every run on an engine that never uses it
DIFFRAX_RESULTS = ("successful", "max_steps_reached", "singular", "breakdown", "stagnation", "conlim",
                   "nonfinite_input", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite",
                   "dt_min_reached", "event_occurred", "max_steps_rejected", "internal_error")

_DIVERGED = VERDICT_NAMES.index("diverged")


def succeeded(status):
    """True where the solver reached t1."""
    return status == OK


def escaped(status):
    """True where the trajectory left the escape ball."""
    return status == ESCAPED


def verdicts(status, verdict):
    """The verdicts as results report them: an escaped trajectory is *diverged* at every horizon (the
    classifier itself, which sees only a stopped solver, says failed). ``verdict``: (N,) or (N, n_horizons)."""
    esc = escaped(status)
    esc = esc.reshape(esc.shape + (1,) * (verdict.ndim - esc.ndim))
    return np.where(esc, _DIVERGED, verdict).astype(verdict.dtype)


def outcomes(status, code, *, escape: int | None, failed: int, finite=None):
    """Outcome codes: ``code`` where the solver succeeded, ``escape`` (the declared escape outcome; None:
    none declared, so failed) where it escaped, ``failed`` for every other status.

    ``finite``: (N,) False where a feature the outcome reads is NaN or infinite although the solver reached
    t1 (:func:`stabjax.model.outcomes.finite_features`); failed too, as the verdicts treat a non-finite
    checkpoint: a rule or a grouping of NaN features is no classification. An escaped trajectory keeps
    its escape outcome (it stopped before its window)."""
    ok = succeeded(status) if finite is None else succeeded(status) & finite
    out = np.where(ok, code, failed)
    return np.where(escaped(status), failed if escape is None else escape, out)


def describe(code: int) -> str:
    """Why a trajectory stopped short of t1, in a user's words (``stabjax simulate``'s message)."""
    code = int(code)
    if code == MAX_STEPS:
        return ("the step budget ran out, the step size collapsed, or the state or its derivative became "
                "non-finite (NaN/inf); a larger [integrate] max_steps helps only in the first case")
    if code == ESCAPED:
        return "the state left the escape radius"
    name = DIFFRAX_RESULTS[code] if 0 <= code < len(DIFFRAX_RESULTS) else "unknown"
    return f"the solver failed ({name.replace('_', ' ')}, code {code})"
