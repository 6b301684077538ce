"""The largest Lyapunov exponent from the tangent dynamics, integrated beside the state.

Benettin et al. (Meccanica 15, 1980) integrate the variational equation ``v' = J(x) v`` beside
``x' = f(x)`` and renormalise ``v`` at checkpoints, summing ``log |v|``. Here the renormalisation
is continuous instead: with the *normalised* tangent ``u = v / |v|`` and the growth rate
``mu = u.J u``,

    x' = f(t, x)
    u' = J u - mu u                   (|u| = 1 is invariant: d|u|^2/dt = 2 mu - 2 mu |u|^2)
    s' = g(t) mu / (t1 - t_w),        g(t) = 1 for t >= t_w, else 0

so ``d/dt log |v| = mu`` and ``s(t1) = (log|v(t1)| - log|v(t_w)|) / (t1 - t_w)`` is the finite-time
estimate of the largest exponent over the late window [t_w, t1] (the same window as the outcome
features). Why this form and not checkpoint renormalisation: it is an ordinary ODE with more state,
so every engine (native C from the jaxpr, fused XLA, diffrax) runs it unchanged and the adaptive
controller bounds its error like any other component; ``u`` stays of length 1, so nothing
overflows however long the run. ``mu`` is divided by ``u.u`` so that a numerical drift of |u| does
not bias the rate. ``J u`` comes from ``jax.jvp`` of the model's ``rhs`` (no Jacobian is formed).
The interval [t0, t_w] aligns ``u`` with the most unstable direction (Benettin's transient).

The step function g makes the controller reject a few steps at t_w (error ~ h * jump); the
integral's error stays at the tolerance. ``s`` is bounded by the largest |Re eig J| seen, so the
escape test (max |y_i| > radius) is not triggered by the tangent state in practice; ``u`` is a
unit vector.

Expected values (tests/model/test_lyapunov.py): chaotic Lorenz-63 (sigma 10, rho 28, beta 8/3):
0.9056 (Sprott, sprott.physics.wisc.edu/chaos/lorenzle.htm); an autonomous limit cycle: 0 (the
along-flow direction), the finite-time estimate within ln(max|f| / min|f|) / (t1 - t_w) of it; a
stable equilibrium: the largest real part of the Jacobian's eigenvalues. A forced (non-autonomous)
system has no zero exponent along the flow: its periodic attractors have lambda < 0.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .system import System

NAME = "lyapunov"  # the observable (and the bare name in rules) holding the exponent
DOC = "largest Lyapunov exponent over the feature window (finite-time estimate, tangent dynamics)"


def initial_tangent(n: int) -> np.ndarray:
    """A fixed unit vector with incommensurate entries (not in a coordinate subspace, which a
    symmetric model may leave invariant)."""
    v = 1.0 + np.mod(np.arange(n) * 0.6180339887498949, 1.0)
    return v / np.linalg.norm(v)


class TangentSystem(System):
    """``base`` with the normalised tangent vector and the log-growth integral as extra state.

    Observables: the base system's, then :data:`NAME` (= s, whose value at t1 is the exponent).
    Everything else (parameters, checks, theory, outcomes, escape radius) is the base system's.
    """

    def __init__(self, base: System, t_w: float, t1: float):
        if not t1 > t_w:
            raise ValueError(f"window start {t_w} must lie before t1 = {t1}")
        self.base, self.t_w, self.t1 = base, float(t_w), float(t1)
        n = base.state_size
        self.n = n
        self.name, self.title, self.paper = base.name, base.title, base.paper
        self.params, self.verdict, self.default_t1 = base.params, base.verdict, base.default_t1
        self.outcomes, self.escape_radius, self.classify = base.outcomes, base.escape_radius, base.classify
        self.state = tuple(base.state) + (("lyapunov_tangent", (n,)), ("lyapunov_integral", ()))
        self.observables = tuple(base.observables) + (NAME,)
        self.observable_doc = tuple(base.observable_doc) + (DOC,)
        self._u0 = initial_tangent(n)

    def check(self, p):
        return self.base.check(p)

    def theory(self, p):
        return self.base.theory(p)

    def prepare(self, p):
        return self.base.prepare(p)

    def equilibrium(self, p):
        return self.base.equilibrium(p)

    def initial_state(self, p):
        x0 = jnp.ravel(self.base.initial_state(p))
        return jnp.concatenate([x0, jnp.asarray(self._u0, x0.dtype), jnp.zeros((1,), x0.dtype)])

    def rhs(self, t, y, args):
        n = self.n
        x, u = y[:n], y[n:2 * n]
        fx, ju = jax.jvp(lambda z: self.base.rhs(t, z, args), (x,), (u,))
        uu = jnp.sum(u * u)
        mu = jnp.sum(u * ju) / uu
        ds = jnp.where(t >= self.t_w, mu, 0.0) / (self.t1 - self.t_w)
        return jnp.concatenate([fx, ju - mu * u, ds[None]])

    def observe(self, t, y, args):
        o = jnp.ravel(self.base.observe(t, y[: self.n], args))
        return jnp.concatenate([o, y[-1:]])

    def describe_outcomes(self):
        return self.base.describe_outcomes()

    def __repr__(self):
        return f"TangentSystem({self.base.name}, t_w={self.t_w:g}, t1={self.t1:g})"


@functools.lru_cache(maxsize=64)
def tangent(base: System, t_w: float, t1: float) -> TangentSystem:
    """The (cached: the engines compile once per system object) tangent wrapper of ``base``."""
    return TangentSystem(base, t_w, t1)


def window_start(t0: float, t1: float, window: float) -> float:
    """Start of the late window, as the fold's features use it: t0 + (1 - window)(t1 - t0)."""
    return float(t0) + (1.0 - float(window)) * (float(t1) - float(t0))


def split(results: dict, n_base_obs: int) -> dict:
    """Engine results of a :class:`TangentSystem` -> the base system's layout plus ``lyapunov`` (N,).

    The exponent is the last observable's value at the last checkpoint (``feat_final``); the
    other statistics of the integral over the window mean nothing and are dropped, so ``feat_*``
    keep one column per observable of the model.
    """
    out = dict(results)
    if "feat_final" not in out:
        raise ValueError("the Lyapunov exponent needs the late-window features (verdict features on)")
    lam = np.asarray(out["feat_final"])[:, n_base_obs]
    status = np.asarray(out.get("solver_status", np.zeros(len(lam), int)))
    out[NAME] = np.where(status == 0, lam, np.nan)
    for k in ("feat_max", "feat_min", "feat_mean", "feat_std", "feat_final"):
        if k in out:
            out[k] = np.asarray(out[k])[:, :n_base_obs]
    return out
