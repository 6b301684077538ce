"""The interface every model implements, and the types theorem predicates return.

A *system* is a closed loop (plant + controller + exogenous signals) written as a
first-order ODE ``dy/dt = rhs(t, y, args)`` on a flat float64 state vector. The engine
(:mod:`stabjax.engine`) only ever calls the methods below, vmapped over a batch of
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

from .params import ParamSet


class Predicate(NamedTuple):
    """A theorem/corollary hypothesis evaluated over a batch of parameters."""

    ok: np.ndarray  # bool: hypothesis holds -> the theorem guarantees its conclusion
    margin: np.ndarray  # float: signed distance to the bound (> 0 inside)
    doc: str  # the inequality, with the paper's equation number


@dataclass
class Theory:
    """Result of evaluating a system's theorems: predicates plus derived quantities."""

    predicates: dict[str, Predicate]
    derived: dict[str, np.ndarray] = field(default_factory=dict)
    derived_doc: dict[str, str] = field(default_factory=dict)
    main: str = ""  # the predicate whose truth is "theory guarantees stability" (confusion table, boundary)


@dataclass(frozen=True)
class VerdictConfig:
    """Thresholds and windows of the excursion classifier (:mod:`stabjax.verdict`). Angles in radians.

    settle_tol      error below which the trajectory counts as settled near the target
    excursion_tol   after settling, a run of checkpoints with error above this is an excursion
                    (default acos(0.9): the paper-A analysis counts s.r < 0.9)
    flip_tol        an excursion whose peak passes this has flipped (pi/2: closer to -r than to r)
    converged_tol   the error throughout the late window must be below this to converge
    late_fraction   (unused by the generic classifier since the log-time windows; kept for
                    system-specific classifiers, e.g. the gyrodyne's linear late window)
    diverge_size    observable 1 (size) above this -> diverged
    growth_tol      late log-log slope of the error above this (error growing) -> diverged
    floor_tol       errors below this are at the solver's noise floor (~rtol): their log-log trend
                    is noise; not used against convergence, nor in the decay fit
    late_decades    the late window of a horizon T is the last ``late_decades`` decades of it in
                    log-time: t - t0 >= (T - t0) 10^-late_decades (horizon-independent shape)
    converge_decades  the error must stay below converged_tol (and not grow) over the last this many
                    decades of the horizon in log-time (after settling); half a decade: a decay crosses
                    converged_tol once, recurrent bumps are the excursion rules' business (a decade)
    shrink_ratio    two successive excursion peaks with peak_last >= shrink_ratio * peak_prev
                    "do not shrink" (recurrent instability: never converged)
    fit_decades     the decay exponent is fitted over this many decades (log-time, multiple of
                    1/2) ending at the last checkpoint above floor_tol
    fit_min_points  fewer points above the noise floor in that tail -> decay exponent NaN
    horizons        times at which verdicts are also given (prefixes of the same run); () = t1 and
                    the ``n_horizon_decades`` decades below it. :func:`stabjax.verdict.bind` fixes
                    them (with t0, t1) when a plan is made; the last horizon is always t1
    n_horizon_decades  default horizons: t0 + (t1 - t0) 10^-k, k = n_horizon_decades .. 0
    features        also return feat_max/min/mean/std/final of each observable (INTERFACES 4)
    feature_window  features over t >= t0 + (1 - feature_window)(t1 - t0)
    t0, t1, n_obs   bound by :func:`stabjax.verdict.bind` (None/0: unbound; the fold assumes t0 = 0)
    """

    settle_tol: float = 0.1
    excursion_tol: float = float(np.arccos(0.9))
    flip_tol: float = float(np.pi / 2)
    converged_tol: float = 1e-3
    late_fraction: float = 0.5
    diverge_size: float = 1e6
    growth_tol: float = 0.5
    floor_tol: float = 1e-6
    late_decades: float = 1.0
    converge_decades: float = 0.5
    shrink_ratio: float = 1.0
    fit_decades: float = 1.0
    fit_min_points: float = 8
    horizons: tuple = ()
    n_horizon_decades: float = 3
    features: float = False
    feature_window: float = 0.5
    t0: float | None = None
    t1: float | None = None
    n_obs: int = 0

    def replace(self, **kw) -> "VerdictConfig":
        from dataclasses import replace

        return replace(self, **kw)


class System:
    """Base class. Subclasses set the class attributes and implement the abstract methods."""

    name: str = ""
    title: str = ""
    paper: str = ""
    params: ParamSet = ParamSet(())
    state: tuple[tuple[str, tuple[int, ...]], ...] = ()  # layout of the flat state vector
    observables: tuple[str, ...] = ("error", "size")
    observable_doc: tuple[str, ...] = ("error metric", "size")
    verdict: VerdictConfig = VerdictConfig()
    default_t1: float = 100.0

    # -- host side ------------------------------------------------------------------------
    def check(self, p: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Validate a (possibly batched) parameter dict; return it, possibly normalised.

        Raise :class:`stabjax.errors.ValidationError` naming the field on bad input.
        """
        return p

    def theory(self, p: Mapping[str, np.ndarray]) -> Theory:
        """Evaluate every theorem/corollary on (batched) parameters."""
        return Theory(predicates={})

    # -- traced (one trajectory, inside jit/vmap) -------------------------------------------
    def prepare(self, p: Mapping[str, jnp.ndarray]) -> Any:
        """Derived constants computed once per trajectory (inverses, gains); passed as ``args``."""
        return dict(p)

    def initial_state(self, p: Mapping[str, jnp.ndarray]) -> jnp.ndarray:
        raise NotImplementedError

    def rhs(self, t, y, args) -> jnp.ndarray:
        raise NotImplementedError

    def observe(self, t, y, args) -> jnp.ndarray:
        raise NotImplementedError

    def equilibrium(self, p: Mapping[str, jnp.ndarray]) -> jnp.ndarray:
        """The target motion's state at t = 0 (for equilibria: the equilibrium)."""
        raise NotImplementedError

    # -- helpers -----------------------------------------------------------------------------
    @property
    def state_size(self) -> int:
        return sum(int(np.prod(s)) if s else 1 for _, s in self.state)

    def unpack(self, y):
        """Split a state array (..., n) into named components (..., *shape)."""
        out, i = {}, 0
        for name, shape in self.state:
            k = int(np.prod(shape)) if shape else 1
            out[name] = y[..., i : i + k].reshape(*y.shape[:-1], *shape)
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
