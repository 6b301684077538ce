"""stabjax: a batch stability explorer -- many trajectories at once, an outcome for each from its whole
history, and the empirical region held against a theorem's bound.

Everything a user runs or writes is here, under one flat namespace; the subpackages are the implementation
and may change between versions:

* **run**: :func:`run_spec`, :func:`run_plan`, :func:`make_plan`, :func:`load_spec`, :func:`open_result`,
  :func:`simulate`, :func:`solve_batch`, :func:`refine_spec`, :func:`refine_plan`, :func:`horizon_check`,
  :func:`shock_spec`, :func:`shock_plan`, :func:`minimal_fatal_shock`, :func:`witness_replay` (minimal fatal shocks);
  :func:`classify` (a plan's outcome mapper over given results); :func:`theory` (a model's theorems at given
  parameters, checked);
* **see**: :func:`plot`, :func:`write_report`, :func:`serve` (the browser explorer);
* **write a model**: :class:`System`, :class:`Param`, :class:`ParamSet`, :class:`Outcomes`,
  :data:`VERDICTS`, :class:`Predicate`, :class:`Theory`, :func:`register`, :func:`get_system`,
  :func:`list_systems`;
* **settings and errors**: :class:`IntegrateConfig`, :class:`VerdictConfig`, :func:`setup_jax`,
  :class:`StabjaxError`, :class:`ValidationError`.

Names are loaded on first use (PEP 562), so ``import stabjax`` -- and the command line's ``--help`` --
imports neither JAX nor xarray. Importing stabjax changes no global setting of JAX: the entry points
above call :func:`setup_jax` first, which switches float64 on (the monoaxial instability of paper A is
algebraic and invisible in float32; float64 is the only precision, and ``STABJAX_X64=0`` is refused).
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .version import __version__

# public name -> the module that defines it
_API = {
    # run
    "run_spec": "run.sweep", "run_plan": "run.sweep", "open_result": "present.kit",
    "make_plan": "plan.spec", "load_spec": "plan.spec",
    "simulate": "engines.simulate", "solve_batch": "engines.simulate",
    "refine_spec": "explore.refine", "refine_plan": "explore.refine",
    "shock_spec": "explore.shock", "shock_plan": "explore.shock", "minimal_fatal_shock": "explore.shock",
    "witness_replay": "explore.shock_result",
    "classify": "mapping.classify",
    "horizon_check": "run.horizon", "theory": "model.theory_eval",
    # see
    "plot": "present.show", "write_report": "present.report", "serve": "present.view",
    # write a model
    "System": "model.system", "Predicate": "model.system", "Theory": "model.system",
    "Param": "model.params", "ParamSet": "model.params",
    "Outcomes": "model.outcomes", "VERDICTS": "model.outcomes",
    "register": "model.loading", "get_system": "model.loading", "list_systems": "model.registry",
    # settings and errors
    "IntegrateConfig": "config", "VerdictConfig": "config", "setup_jax": "config",
    "StabjaxError": "errors", "ValidationError": "errors",
}
_RENAMED = {"get_system": "resolve"}  # the public name of a function whose module calls it otherwise

__all__ = sorted([*_API, "__version__"])


def __getattr__(name: str):
    mod = _API.get(name)
    if mod is None:
        raise AttributeError(f"module 'stabjax' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), _RENAMED.get(name, name))
    globals()[name] = value  # once loaded, a plain attribute
    return value


def __dir__():
    return __all__


if TYPE_CHECKING:  # for type checkers and editors: the same names, imported eagerly
    from .config import IntegrateConfig, VerdictConfig, setup_jax
    from .engines.simulate import simulate, solve_batch
    from .errors import StabjaxError, ValidationError
    from .explore.refine import refine_plan, refine_spec
    from .explore.shock import minimal_fatal_shock, shock_plan, shock_spec
    from .explore.shock_result import witness_replay
    from .mapping.classify import classify
    from .model.loading import register
    from .model.loading import resolve as get_system
    from .model.outcomes import VERDICTS, Outcomes
    from .model.params import Param, ParamSet
    from .model.registry import list_systems
    from .model.system import Predicate, System, Theory
    from .model.theory_eval import theory
    from .plan.spec import load_spec, make_plan
    from .present.kit import open_result
    from .present.report import write_report
    from .present.show import plot
    from .present.view import serve
    from .run.horizon import horizon_check
    from .run.sweep import run_plan, run_spec
