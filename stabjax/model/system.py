"""The interface every model implements, and the types theorem predicates return.

A *system* is a closed loop (plant + controller + exogenous signals) written as a
first-order ODE ``dy/dt = rhs(t, y, args)`` on a flat float64 state vector. The engine
(:mod:`stabjax.engines`) only ever calls the methods below, vmapped over a batch of
parameter dicts, so adding a model means writing one subclass and one registry entry.

Conventions
-----------
* ``p`` is a dict ``name -> array`` holding *one* trajectory's parameters (inside ``jit``/``vmap``)
  or a batch of them (host-side NumPy, in :meth:`System.check` and the theory functions).
* :meth:`System.observe` returns a short vector of observables at checkpoint times. Entry 0
  is the **error metric** ``e >= 0`` (zero at the target motion), entry 1 a **size** used
  to detect blow-up (e.g. ``|omega|``). Verdicts are computed from these alone, so nothing
  is stored per solver step.
* Theorem predicates live in a separate module per paper and return :class:`Predicate`
  records with a signed margin (``> 0``: the theorem's hypothesis holds), so boundaries are
  the zero contours of margins.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..config import VerdictConfig
from .params import ParamSet


class Predicate(NamedTuple):
    """A theorem/corollary hypothesis evaluated over a batch of parameters.

    ``outcome``: for a model with named outcomes (rules or templates), the outcome the theorem guarantees where
    its hypothesis holds (``"origin"``). With it a sweep counts the trajectories the theorem guarantees that end
    elsewhere (red flags) and the silent ones that end in it (where the theorem is conservative), and marks them
    on the basin figure; without it the table of theorem against outcome is shown and the reader judges.
    """

    ok: np.ndarray  # bool: hypothesis holds -> the theorem guarantees its conclusion
    margin: np.ndarray  # float: signed distance to the bound (> 0 inside)
    doc: str  # the inequality, with the paper's equation number
    outcome: str = ""  # the named outcome it guarantees (models with rules or templates); "" for the verdicts


@dataclass
class Theory:
    """Result of evaluating a system's theorems: predicates plus derived quantities."""

    predicates: dict[str, Predicate]
    derived: dict[str, np.ndarray] = field(default_factory=dict)
    derived_doc: dict[str, str] = field(default_factory=dict)
    main: str = ""  # the predicate whose truth is "theory guarantees stability" (confusion table, boundary)


class System:
    """The interface every model implements: a first-order ODE ``dy/dt = rhs(t, y, p)`` on a flat float64 state.

    Subclass it, set the class attributes below and write :meth:`initial_state`, :meth:`rhs` and
    :meth:`observe`. Those three are traced by JAX for one trajectory (``jnp`` functions; ``jnp.where``
    instead of a Python ``if`` on values); the engines call them vmapped over a batch of parameter dicts.
    The host-side members (:meth:`check`, :meth:`theory`) see NumPy batches. A model is checked before use
    (:mod:`stabjax.model.loading`): a member of the wrong shape or dtype is an error naming it.

    Attributes:
        name: the name it is known by (set by the registry or the loader: a file's model is ``file.py:Class``).
        title: one line describing the model (``stabjax systems``).
        paper: the source, for the papers' systems.
        params: the parameters, a :class:`ParamSet` of :class:`Param` (``kind="initial"`` marks initial
            conditions); each can be fixed, swept on a grid or sampled.
        state: the layout of the flat state vector, ``((name, shape), ...)``.
        observables: the names of what :meth:`observe` returns at the checkpoints; outcomes are decided from
            them alone. For the attitude systems entry 0 is the error metric, entry 1 a size that detects blow-up.
        observable_doc: one line per observable: its meaning and unit.
        verdict: the attitude classifier's thresholds (:class:`~stabjax.config.VerdictConfig`), which a spec's
            ``[verdict]`` overrides.
        default_t1: the horizon when a spec gives no ``[integrate] t1``.
        outcomes: an :class:`~stabjax.model.outcomes.Outcomes` declaration (rules, templates, escape);
            ``VERDICTS`` where the attitude verdicts are the outcomes; None: the attractors are discovered.
        classify: optional, a system-specific classifier ``classify(ts, obs, solver_ok, vcfg, t0) -> summaries``
            replacing the generic one (such a system runs on the diffrax engine only).
        escape_radius: optional: stop a trajectory once an accepted state has max_i |y_i| above it (the escape
            outcome; ``[integrate] escape_radius`` overrides it).
    """

    name: str = ""
    title: str = ""
    paper: str = ""
    params: ParamSet = ParamSet(())
    state: tuple[tuple[str, tuple[int, ...]], ...] = ()  # layout of the flat state vector
    observables: tuple[str, ...] = ("error", "size")
    observable_doc: tuple[str, ...] = ("error metric", "size")
    verdict: VerdictConfig = VerdictConfig()
    default_t1: float = 100.0
    # named outcomes (:class:`stabjax.model.outcomes.Outcomes`); ``stabjax.model.outcomes.VERDICTS``: the attitude
    # verdicts are the outcomes (the built-in attitude systems); None: the attractors are discovered
    outcomes: Any = None

    # -- optional hooks (None: not provided; the engines test these, never probe with getattr) --
    # A system-specific classifier ``classify(ts, obs, solver_ok, vcfg, t0) -> summaries`` (the
    # signature of :func:`stabjax.fold.verdict.classify`) replaces the generic one; it needs every
    # checkpoint's observables at once, so such a system runs on the diffrax engine only.
    classify: Callable[..., Mapping[str, Any]] | None = None
    # Stop a trajectory as soon as an accepted state has max_i |y_i| above this (its status is then
    # :data:`stabjax.fold.status.ESCAPED`); ``[integrate] escape_radius`` overrides it per spec.
    escape_radius: float | None = None

    # -- host side ------------------------------------------------------------------------
    def check(self, p: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Validate a (possibly batched) parameter dict; return it, possibly normalised.

        Raise :class:`stabjax.errors.ValidationError` naming the field on bad input.
        """
        return p

    def theory(self, p: Mapping[str, np.ndarray]) -> Theory:
        """Evaluate every theorem/corollary on (batched) parameters, already checked (:meth:`check`); from Python,
        :func:`stabjax.theory` checks them first."""
        return Theory(predicates={})

    # -- traced (one trajectory, inside jit/vmap) -------------------------------------------
    def prepare(self, p: Mapping[str, jnp.ndarray]) -> Any:
        """Derived constants computed once per trajectory (inverses, gains); passed as ``args``."""
        return dict(p)

    def initial_state(self, p: Mapping[str, jnp.ndarray]) -> jnp.ndarray:
        """The state at t0 from one trajectory's parameters (flat, ``state_size`` entries). Traced."""
        raise NotImplementedError(f"{type(self).__name__} defines no initial_state(self, p): every model must")

    def rhs(self, t, y, args) -> jnp.ndarray:
        """dy/dt at time ``t`` and state ``y``; ``args`` is :meth:`prepare`'s result. Traced."""
        raise NotImplementedError(f"{type(self).__name__} defines no rhs(self, t, y, args): every model must")

    def observe(self, t, y, args) -> jnp.ndarray:
        """The observables at a checkpoint, one entry per name of ``observables``. Traced."""
        raise NotImplementedError(f"{type(self).__name__} defines no observe(self, t, y, args): every model must")

    def equilibrium(self, p: Mapping[str, jnp.ndarray]) -> jnp.ndarray:
        """The target motion's state at t = 0 (for equilibria: the equilibrium). Optional."""
        raise NotImplementedError

    def describe_outcomes(self) -> list[tuple[str, str]]:
        """(name, how it is assigned) for ``stabjax systems NAME``."""
        from .outcomes import VERDICTS

        if self.outcomes is VERDICTS:
            from ..config import VERDICT_NAMES

            return [(n, "verdict (see the user guide: Outcomes and verdicts)") for n in VERDICT_NAMES]
        if self.outcomes is None:
            rows = [("fixed_point_k, limit_cycle_k, chaotic_k", "discovered: grouped late-window features, "
                                                               "typed by spread and Lyapunov exponent")]
            if self.escape_radius is not None:
                rows.append(("escaped", f"stopped once max|y_i| > {self.escape_radius:g}"))
            return rows + [("unclassified", "in no group"), ("failed", "solver did not reach t1 / NaN")]
        o = self.outcomes
        rows = [(k, f"rule: {v}") for k, v in o.rules.items()]
        rows += [(k, f"nearest template {dict(v)} in features {list(o.features)}") for k, v in o.templates.items()]
        if self.escape_radius is not None:
            rows.append((o.escape, f"stopped once max|y_i| > {self.escape_radius:g}"))
        rows += [("unclassified", "no rule holds, no template near"), ("failed", "solver did not reach t1 / NaN")]
        return rows

    # -- helpers -----------------------------------------------------------------------------
    @property
    def state_size(self) -> int:
        return sum(int(np.prod(s)) if s else 1 for _, s in self.state)

    def unpack(self, y):
        """Split a state array (..., n) into named components (..., *shape)."""
        out, i = {}, 0
        for name, shape in self.state:
            k = int(np.prod(shape)) if shape else 1
            out[name] = y[..., i : i + k].reshape(tuple(y.shape[:-1]) + tuple(shape))  # () of one state too
            i += k
        return out

    def describe(self) -> list[dict[str, Any]]:
        rows = []
        for prm in self.params:
            rows.append(
                dict(name=prm.name, kind=prm.kind, shape=prm.shape, default=prm.default, unit=prm.unit, doc=prm.doc)
            )
        return rows


SystemFactory = Callable[[], System]
