"""The ``[shock]`` table of a spec: what is shocked, in which norm, from which attractor, and how hard to search.

A minimal fatal shock (:mod:`stabjax.explore.shock`) perturbs *initial-condition parameters* (``kind =
"initial"``: ``x0``, ``dw0``, one entry ``"dw0[1]"``) of the spec's start, which is put on the attractor (e.g.
Saakyan's target motion: ``S0 = H``, ``dw0 = 0``). A shock is a vector ``delta`` over the scalar entries of those
components; it is measured by

* ``space = "params"`` (default): ``delta`` itself, grouped by component; or
* ``space = "state"``: the shift of the start *state*, ``initial_state(base + delta) - initial_state(base)``,
  grouped by the system's state components (``System.state``). For a model whose state is its initial-condition
  parameters the two agree; where the model maps parameters onto a manifold (Saakyan's ``S0`` is normalised onto
  the unit sphere) only the state shift is the quantity a theorem's region is stated in. ``unit = ["s0"]`` puts a
  shocked vector back on the unit sphere (normalised) before the system sees it, for a model that refuses a
  direction that is not a unit vector; the shift is then best measured in the state.

Norm: ``norm = "euclidean"`` (default) is ``sqrt(sum_i (w_i d_i)^2)`` over every measured entry; ``norm = "max"``
is the largest of the blocks' weighted Euclidean norms (``blocks = [["w"], ["S"]]``; default: one block per
component), so that a region made of two balls, ``|w1| < lam l`` and ``|delta| < l`` ((1.18) of Saakyan), is the
one ball ``max(|w1|/lam, |delta|) < l``. A weight is a number or an expression of the scalar parameters
(``"1/lam"``), evaluated at each grid point.

Fields, one row per key of :data:`SHOCK_KEYS` (``stabjax.explore.shock`` says what the search does with them; the
documentation's settings table is generated from these rows):

===================  ===================================================================================
``components``       initial-condition parameters shocked (required): ``["x0", "v0"]``, ``["dw0", "S0"]``, ``"J0[1]"``
``unit``             shocked vector parameters put back on the unit sphere (e.g. ``["s0"]``)
``settle``           shock the state the spec's start reaches at t1 (a template's start, say), not the start itself
                     (default false)
``space``            ``"params"`` (default) or ``"state"``: what the norm measures
``norm``             ``"euclidean"`` (default) or ``"max"`` over ``blocks``
``weights``          name -> number or expression of the scalar parameters (``{w = "1/lam"}``)
``blocks``           with ``norm = "max"``: lists of component (or state component) names (default: one per component;
                     every shocked component in one)
``attractor``        the outcome the unshocked start must reach (default: whatever it reaches)
``target``           only these outcomes are fatal (the excitability threshold into their basins)
``excitability``     a condition over the whole run (``"max(error) > 0.3"``): fatal when it holds
``directions``       directions scanned (64; with one component both of its two directions, +1 and -1)
``radii``            radii per direction in the scan, and rungs of CMA-ES's ladder (8)
``max_radius``       the largest shock searched, in the norm's units (required)
``resolution``       bracket width to reach, absolute (default: ``rel_resolution``)
``rel_resolution``   bracket width to reach, a fraction of delta* (0.01)
``refine``           ``"cma"`` (default) or ``"none"``: the local refinement of the best shock by CMA-ES
``popsize``          CMA-ES's population per generation (pycma's default 4 + 3 ln d)
``generations``      CMA-ES's generations at most (40)
``seed``             of the directions and of CMA-ES (0)
``theory``           the system's theorems to hold against the result: predicates or derived radii (not with
                     ``target``)
===================  ===================================================================================

Here too: the start to shock at each grid point (:func:`base_points`, :func:`settle`). Kept apart from the search so
that the table can be checked (``stabjax sweep`` refuses a bad table before anything
is integrated or written) and the norm evaluated without the runner.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from .. import validate as V
from ..errors import ValidationError

SHOCK_KEYS = ("components", "unit", "settle", "space", "norm", "weights", "blocks", "attractor", "target", "excitability",
              "directions", "radii", "max_radius", "resolution", "rel_resolution", "refine", "popsize",
              "generations", "seed", "theory")
SPACES = ("params", "state")
NORMS = ("euclidean", "max")
REFINERS = ("cma", "none")
INCONCLUSIVE = ("undecided", "unclassified")  # the classifier could not decide: never fatal, never safe
LEFT, STAYED = "left", "stayed"  # the two outcomes of an excitability search
_ENTRY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+(?:\s*,\s*\d+)*)\])?$")


@dataclass(frozen=True)
class Entry:
    """One scalar entry of a shocked initial-condition parameter."""

    param: str
    index: tuple[int, ...] | None  # None: a scalar parameter
    component: str  # the component (as written in ``components``) it belongs to

    @property
    def key(self) -> str:
        """The grid key that sweeps it (``"x0"``, ``"dw0[1]"``)."""
        return self.param if self.index is None else f"{self.param}[{','.join(map(str, self.index))}]"


@dataclass(frozen=True)
class ShockConfig:
    """The validated ``[shock]`` table."""

    components: tuple[str, ...]
    entries: tuple[Entry, ...]
    unit: tuple[str, ...]  # vector components put back on the unit sphere after the shock
    settle: bool  # the base start is first integrated to t1: its final state is the attractor's state shocked
    space: str
    norm: str
    blocks: tuple[tuple[str, ...], ...]  # names in the measured space (components, or state components)
    weights: Mapping[str, Any]  # name -> number or expression text
    attractor: str | None
    target: tuple[str, ...] | None
    excitability: str | None
    directions: int
    radii: int
    max_radius: float
    resolution: float | None
    rel_resolution: float
    refine: str
    popsize: int | None
    generations: int
    seed: int
    theory: tuple[str, ...] = field(default=())

    @property
    def dim(self) -> int:
        return len(self.entries)

    def tol(self, best: np.ndarray) -> np.ndarray:
        """The bracket width to reach at each grid point (``best``: the smallest fatal norm found so far)."""
        if self.resolution is not None:
            return np.full(np.shape(best), self.resolution)
        return self.rel_resolution * np.where(np.isfinite(best), best, self.max_radius)


def _names(raw, fld: str) -> list[str]:
    if isinstance(raw, str):
        raw = [raw]
    if not isinstance(raw, list) or not raw or not all(isinstance(x, str) for x in raw):
        raise ValidationError(fld, f"must be a non-empty list of names, got {raw!r}")
    return list(raw)


def _entries(plan, comps: list[str]) -> list[Entry]:
    """The scalar entries of the shocked components, each checked against the system's parameters."""
    prm = plan.system.params.by_name
    swept = {ax.param.name: ax.key for ax in plan.grid}
    out: list[Entry] = []
    for i, c in enumerate(comps):
        fld = f"shock.components[{i}]"
        m = _ENTRY.match(c.strip())
        if not m or m.group(1) not in prm:
            raise ValidationError(fld, f"{c!r} is not a parameter of {plan.system.name}; initial conditions: "
                                       f"{', '.join(p.name for p in plan.system.params if p.kind == 'initial') or 'none'}")
        p = prm[m.group(1)]
        if p.kind != "initial":
            raise ValidationError(fld, f"{p.name} is a model parameter, not an initial condition (kind = \"initial\"): "
                                       "a shock perturbs the start, not the model")
        if p.choices is not None:
            raise ValidationError(fld, f"{p.name} takes only the values {p.choices} (a switch): it cannot be shocked")
        if p.name in swept:
            raise ValidationError(fld, f"{p.name} is swept by grid.{swept[p.name]}: the shock moves it from the "
                                       "spec's start; fix it in [params]")
        if m.group(2) is not None:
            idx = tuple(int(x) for x in m.group(2).split(","))
            if len(idx) != len(p.shape) or any(a >= s for a, s in zip(idx, p.shape)):
                raise ValidationError(fld, f"index {idx} out of range for {p.name} of shape {p.shape}")
            new = [Entry(p.name, idx, c)]
        elif p.shape:
            new = [Entry(p.name, tuple(int(x) for x in ix), c) for ix in np.ndindex(p.shape)]
        else:
            new = [Entry(p.name, None, c)]
        for e in new:
            if any(o.param == e.param and (o.index is None or e.index is None or o.index == e.index) for o in out):
                raise ValidationError(fld, f"{e.key} is shocked twice")
        out += new
    return out


def _positive(raw, key: str, default, integer: bool = False):
    if key not in raw:
        return default
    if integer:
        return V.integer(raw[key], f"shock.{key}", lo=1, hi=1 << 24)
    v = V.number(raw[key], f"shock.{key}")
    if not v > 0:
        raise ValidationError(f"shock.{key}", f"must be > 0, got {v:g}")
    return v


def shock_config(plan, raw: Mapping[str, Any] | None = None) -> ShockConfig:
    """Validate ``[shock]`` (default: ``plan.spec["shock"]``) against the plan, field by field."""
    raw = plan.spec.get("shock") if raw is None else raw
    if raw is None:
        raise ValidationError("shock", "the spec has no [shock] section")
    V.table(raw, "shock")
    unknown = sorted(set(raw) - set(SHOCK_KEYS))
    if unknown:
        raise ValidationError(f"shock.{unknown[0]}", f"unknown field; known: {', '.join(SHOCK_KEYS)}")
    if "refine" in plan.spec:
        raise ValidationError("refine", "a spec runs either a [refine] or a [shock] search, not both")
    if plan.n_sample:  # a [shock] table given beside a plan whose spec had none (the spec refuses the pair itself)
        from ..plan.spec import SHOCK_TAKES_NO_SAMPLE

        raise ValidationError("sample", SHOCK_TAKES_NO_SAMPLE)
    for ax in plan.grid:
        if ax.values.ndim != 1:
            raise ValidationError(f"grid.{ax.key}", "a shock search needs scalar axes (sweep one entry like \"J[0]\")")
    if "components" not in raw:
        raise ValidationError("shock.components", "required: the initial-condition parameters the shock perturbs, "
                                                  "e.g. [\"x0\", \"v0\"]")
    comps = _names(raw["components"], "shock.components")
    entries = _entries(plan, comps)
    unit = tuple(_names(raw["unit"], "shock.unit")) if "unit" in raw else ()
    for i, u in enumerate(unit):
        prm = plan.system.params.by_name.get(u)
        if u not in comps or prm is None or len(prm.shape) != 1:
            raise ValidationError(f"shock.unit[{i}]", f"{u!r} is not a shocked vector parameter (a whole one of "
                                                      f"{', '.join(comps)}): only those are put back on the sphere")
    space = V.string(raw.get("space", "params"), "shock.space", SPACES)
    norm = V.string(raw.get("norm", "euclidean"), "shock.norm", NORMS)
    measured = list(comps) if space == "params" else [n for n, _ in plan.system.state]
    where = "shocked components" if space == "params" else f"state components of {plan.system.name}"
    blocks: list[tuple[str, ...]]
    if "blocks" in raw:
        if norm != "max":
            raise ValidationError("shock.blocks", "blocks belong to norm = \"max\" (the Euclidean norm is one block)")
        bl = raw["blocks"]
        if not isinstance(bl, list) or not bl:
            raise ValidationError("shock.blocks", f"must be a list of lists of names, got {bl!r}")
        blocks = [tuple(_names(b, f"shock.blocks[{i}]")) for i, b in enumerate(bl)]
    else:
        used = measured if space == "state" else comps
        blocks = [tuple(used)] if norm == "euclidean" else [(n,) for n in used]
    seen: set[str] = set()
    for i, b in enumerate(blocks):
        for n in b:
            if n not in measured:
                raise ValidationError(f"shock.blocks[{i}]", f"{n!r} is not one of the {where}: {', '.join(measured)}")
            if n in seen:
                raise ValidationError(f"shock.blocks[{i}]", f"{n!r} is in two blocks")
            seen.add(n)
    if norm == "max" and space == "params":
        # a shocked component in no block would be moved for free: the norm would not see it
        free = [c for c in comps if c not in seen]
        if free:
            raise ValidationError("shock.blocks", f"{', '.join(repr(c) for c in free)} "
                                                  f"{'is' if len(free) == 1 else 'are'} shocked but in no block: the "
                                                  "max norm would not measure "
                                                  f"{'it' if len(free) == 1 else 'them'} (a shock of any size there "
                                                  "would cost nothing); put every shocked component in a block")
    weights = V.table(raw.get("weights", {}), "shock.weights")
    scalars = tuple(p.name for p in plan.system.params if not p.shape)
    for k, w in weights.items():
        if k not in seen:
            raise ValidationError(f"shock.weights.{k}", f"not a component of the norm ({', '.join(sorted(seen))})")
        if isinstance(w, str):
            from ..model.outcomes import parse

            parse(w, (), scalars, f"shock.weights.{k}", boolean=False)
        else:
            v = V.number(w, f"shock.weights.{k}")
            if not v > 0:
                raise ValidationError(f"shock.weights.{k}", f"must be > 0, got {v:g}")

    names = _outcome_names(plan)
    attractor = raw.get("attractor")
    if attractor is not None:
        attractor = V.string(attractor, "shock.attractor")
        if names is not None and attractor not in names:
            raise ValidationError("shock.attractor", f"no outcome {attractor!r}; outcomes: {', '.join(names)}")
    target = None
    if "target" in raw:
        target = tuple(_names(raw["target"], "shock.target"))
        for t in target:
            if names is not None and t not in names:
                raise ValidationError("shock.target", f"no outcome {t!r}; outcomes: {', '.join(names)}")
            if t == attractor:
                raise ValidationError("shock.target", f"{t!r} is the attractor itself")
    excit = raw.get("excitability")
    if excit is not None:
        from ..model.outcomes import _names as rule_names, parse

        if attractor is not None or target is not None:
            raise ValidationError("shock.excitability", "leaving a neighbourhood replaces the outcomes: give no "
                                                        "attractor or target with it")
        obs, sc = rule_names(plan.system)
        parse(V.string(excit, "shock.excitability"), obs, sc, "shock.excitability")
    directions = _positive(raw, "directions", 64, integer=True)
    if len(entries) == 1:
        # the unit sphere of one component is {+1, -1}: both are searched (stabjax.explore.shock), none drawn
        # at random (two draws could both be +1 and leave the other side unsearched), and more would repeat them
        directions = min(directions, 2)
    radii = _positive(raw, "radii", 8, integer=True)
    if "max_radius" not in raw:
        raise ValidationError("shock.max_radius", "required: the largest shock searched, in the norm's units")
    max_radius = _positive(raw, "max_radius", None)
    if "resolution" in raw and "rel_resolution" in raw:
        raise ValidationError("shock.resolution", "give resolution (absolute) or rel_resolution, not both")
    resolution = _positive(raw, "resolution", None)
    rel = _positive(raw, "rel_resolution", 0.01)
    if rel >= 1:
        raise ValidationError("shock.rel_resolution", f"must be below 1 (a fraction of the shock), got {rel:g}")
    refine = V.string(raw.get("refine", "cma"), "shock.refine", REFINERS)
    popsize = _positive(raw, "popsize", None, integer=True)
    if popsize is not None and popsize < 2:
        raise ValidationError("shock.popsize", f"must be >= 2, got {popsize}")
    generations = V.integer(raw.get("generations", 40), "shock.generations", lo=0, hi=10_000)
    seed = V.integer(raw.get("seed", 0), "shock.seed", lo=0, hi=2**63 - 1)
    theory = tuple(_names(raw["theory"], "shock.theory")) if "theory" in raw else ()
    if theory:
        if target is not None:
            raise ValidationError("shock.theory", "a theorem's region is held against the minimal fatal shock out of "
                                                  "the attractor's basin, but with shock.target only shocks into "
                                                  f"{', '.join(target)} count as fatal (a threshold into those "
                                                  "basins, not the basin's edge): give either theory or target")
        _check_theory(plan, theory)
    settle_ = V.boolean(raw.get("settle", False), "shock.settle")
    cfg = ShockConfig(components=tuple(comps), entries=tuple(entries), unit=unit, settle=settle_, space=space,
                      norm=norm, blocks=tuple(blocks), weights=dict(weights), attractor=attractor, target=target,
                      excitability=excit, directions=directions, radii=radii, max_radius=max_radius,
                      resolution=resolution, rel_resolution=rel, refine=refine, popsize=popsize,
                      generations=generations, seed=seed, theory=theory)
    check_rounds(plan, cfg)
    return cfg


def cma_popsize(cfg: ShockConfig) -> int:
    """Candidates CMA-ES asks for per grid point and generation: ``popsize``, or pycma's default 4 + 3 ln d."""
    return cfg.popsize or int(4 + 3 * math.log(cfg.dim))


# after the first refinement (CMA-ES, then the polish), the refined witnesses are shared along the grid and the grid
# points they improve refined again, while any improves, at most this many times (stabjax.explore.shock.Search.run);
# each such share round holds at most grid points x (grid points - 1) x radii trajectories, as the first
SHARE_ROUNDS = 3


def round_sizes(G: int, cfg: ShockConfig) -> list[tuple[int, str, str]]:
    """The most trajectories each kind of round can hold at ``G`` grid points, as ``(n, field, what)`` (``field``:
    the spec field that makes it large). A bound, not a forecast: sharing and bisection reach it when every grid
    point finds a fatal shock, the usual case."""
    D, K = cfg.directions, cfg.radii
    shared = G * (G - 1)  # every grid point's best direction at every other one
    at = "" if G == 1 else f"{G:,} grid points x "
    out = [(G * (D * K + 1), "shock.directions",
            f"round 0 (the scan: {at}({D:,} directions x {K:,} radii + the unshocked start) = {G * (D * K + 1):,} "
            "trajectories)")]
    if G > 1:
        out.append((shared * K, "grid", f"the round sharing each grid point's best direction with the others "
                                        f"({G:,} x {G - 1:,} grid points x {K:,} radii = {shared * K:,} trajectories)"))
    # a bisection round: one trajectory per ray still open, at most every ray (scanned, shared, polished); with
    # CMA-ES, up to SHARE_ROUNDS more shares of the refined witnesses and refinements (each a polished ray)
    cma = cfg.refine == "cma" and cfg.dim >= 2 and cfg.generations > 0
    passes = 1 + SHARE_ROUNDS if cma else 1
    rays = G * D + passes * (shared + G)
    more = (f"{shared:,} shared + " if shared else "") + f"{G:,} polished"
    more = f"{passes} x ({more})" if passes > 1 else more
    out.append((rays, "grid" if passes * shared > G * D else "shock.directions",
                f"a bisection round (one trajectory per direction searched: {at}{D:,} directions + {more} = "
                f"{rays:,} trajectories)"))
    if cma:
        P = cma_popsize(cfg)
        out.append((G * P * K, "shock.popsize" if cfg.popsize else "shock.radii",
                    f"a CMA-ES round ({at}{P:,} candidates x {K:,} radii = {G * P * K:,} "
                    "trajectories)"))
    return out


_FEWER = {"shock.directions": "use fewer directions or radii, or fewer grid points",
          "grid": "use fewer grid points, or split the grid into several specs",
          "shock.popsize": "use a smaller popsize or fewer radii", "shock.radii": "use fewer radii"}


def check_rounds(plan, cfg: ShockConfig) -> None:
    """Refuse, before anything runs, a search whose largest round could not be held: each round's trajectories
    against the limits a sweep's are held to (a sample's number of points, and the memory of the results,
    :func:`stabjax.validate.check_allocation`), with what the round itself holds per trajectory besides its
    results. A round is built whole (its shocks, then its parameters, then the runner's results): one too large
    allocates until the machine kills it."""
    from ..plan.spec import MAX_AXIS_POINTS, RESULT_BYTES_PER_TRAJECTORY

    # per trajectory: every parameter twice (the shocked starts, the runner's rows), the grid point's values and
    # shocked entries, the shock and its direction, radius, indices and codes
    n_params = sum(math.prod(p.shape) for p in plan.system.params)
    per = RESULT_BYTES_PER_TRAJECTORY + 8 * (2 * n_params + len(plan.grid) + 4 * cfg.dim + 8)
    for n, fld, what in round_sizes(plan.size, cfg):
        if n > MAX_AXIS_POINTS:
            raise ValidationError(fld, f"{what}: over the {MAX_AXIS_POINTS:,} trajectories a round may hold (a "
                                       f"sample's bound); {_FEWER[fld]}")
        V.check_allocation(fld, n * per, what)


def _outcome_names(plan) -> tuple[str, ...] | None:
    """The outcome names a shock can end in, or None where discovery names them after the run."""
    sch = plan.scheme
    if sch.decl is not None and sch.decl.discover:
        return None
    return tuple(sch.names)


def _check_theory(plan, names: tuple[str, ...]) -> None:
    """Each name is a predicate (a margin over the initial conditions) or a derived radius of the system's theory."""
    p = plan.system.check(plan.params_for(0, 1))
    th = plan.system.theory(p)
    known = sorted(th.predicates) + sorted(th.derived)
    for i, n in enumerate(names):
        if n not in th.predicates and n not in th.derived:
            raise ValidationError(f"shock.theory[{i}]", f"{plan.system.name} states no predicate or derived radius "
                                                        f"{n!r}; known: {', '.join(known) or 'none'}")


# ---- the start shocked -----------------------------------------------------------------------------


def base_points(plan) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every parameter of the unshocked start at each grid point (checked), and the grid axes' values (G, n_axes)."""
    G = plan.size
    base = plan.system.check(plan.params_for(0, G))
    if plan.grid:
        idx = np.unravel_index(np.arange(G), tuple(ax.size for ax in plan.grid))
        gv = np.stack([ax.values[i] for ax, i in zip(plan.grid, idx)], axis=1).astype(float)
    else:
        gv = np.zeros((G, 0))
    return {k: np.asarray(v) for k, v in base.items()}, gv


def settle(plan, cfg: ShockConfig, base: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``[shock] settle = true``: the start moved onto its attractor -- integrated to t1 (the plan's solver and
    tolerances) and its final state written back into the shocked entries. Needs entries that *are* state entries
    (``initial_state`` copies each into one state entry, and every state entry comes from one): checked on the
    Jacobian of ``initial_state``. For a forced system the final state is on the attractor at t1's phase; the shock
    is applied at t0, so choose t1 a whole number of forcing periods. A start that reaches no attractor (it escapes,
    or the solver fails) is left as given."""
    import jax

    from ..engines.simulate import simulate

    sysm = plan.system
    d = cfg.dim

    def y0(v, p):
        q = dict(p)
        for j, e in enumerate(cfg.entries):
            q[e.param] = v[j] if e.index is None else q[e.param].at[e.index].set(v[j])
        return jax.numpy.ravel(sysm.initial_state(q))

    p0 = {k: jax.numpy.asarray(np.asarray(v)[0]) for k, v in base.items()}
    vals = np.array([float(np.asarray(base[e.param][0]) if e.index is None else np.asarray(base[e.param][0])[e.index])
                     for e in cfg.entries])
    J = np.asarray(jax.jacfwd(y0)(jax.numpy.asarray(vals), p0))  # (n_state, d)
    if not (J.shape[0] == d and np.allclose(np.abs(J), np.eye(d)[np.argmax(np.abs(J), axis=0)].T)
            and np.allclose(np.abs(J).sum(axis=0), 1) and np.allclose(np.abs(J).sum(axis=1), 1)):
        raise ValidationError("shock.settle", "needs shocked components that set the whole state one entry each "
                                              f"(the state of {sysm.name} has {J.shape[0]} entries); put the start "
                                              "on the attractor in [params] instead")
    row = np.argmax(np.abs(J), axis=0)  # the state entry of each shocked entry
    out = {k: np.array(v, copy=True) for k, v in base.items()}
    G = len(next(iter(base.values())))
    for g in range(G):
        p = {k: np.asarray(v)[g] for k, v in base.items()}
        ic = plan.icfg
        ds = simulate(sysm, p, t1=ic.t1, t0=ic.t0, ts=[ic.t1], solver=ic.solver, rtol=ic.rtol, atol=ic.atol,
                      max_steps=ic.max_steps)
        yf = np.concatenate([np.ravel(ds[name].values[-1]) for name, _ in sysm.state])
        if int(ds.attrs["solver_status"]) != 0 or not np.all(np.isfinite(yf)):
            # no attractor to settle on (the start escapes, or the solver fails): the start stays as given, and
            # the unshocked run says what it reaches ("escaped" is an answer; the non-finite state written back
            # here made it "failed", exit 1)
            continue
        for j, e in enumerate(cfg.entries):
            v = yf[row[j]] * np.sign(J[row[j], j])
            if e.index is None:
                out[e.param][g] = v
            else:
                out[e.param][(g, *e.index)] = v
    return sysm.check(out)


# ---- the norm --------------------------------------------------------------------------------------


class Norm:
    """``N(delta)`` at each grid point: see the module docstring. ``measure(g, deltas)``: norms (M,) of shocks
    ``deltas`` (M, d) applied at grid points ``g`` (M,) (indices into the base parameters)."""

    def __init__(self, plan, cfg: ShockConfig, base: Mapping[str, np.ndarray]):
        self.plan, self.cfg, self.base = plan, cfg, base
        n = len(next(iter(base.values())))
        from ..model.outcomes import parse

        scalars = tuple(p.name for p in plan.system.params if not p.shape)
        self.w = {}  # name -> (G,) weights
        for k, w in cfg.weights.items():
            if isinstance(w, str):
                val = parse(w, (), scalars, f"shock.weights.{k}", boolean=False)(
                    None, lambda name: np.asarray(base[name], float).reshape(n))
                val = np.broadcast_to(np.asarray(val, float), (n,))
                if not (np.all(np.isfinite(val)) and np.all(val > 0)):
                    raise ValidationError(f"shock.weights.{k}", f"{w!r} is not a positive number at every grid point")
                self.w[k] = val
            else:
                self.w[k] = np.full(n, float(w))
        if cfg.space == "params":
            cols = {c: [i for i, e in enumerate(cfg.entries) if e.component == c] for c in cfg.components}
        else:
            cols, i = {}, 0
            for name, shape in plan.system.state:
                k = int(np.prod(shape)) if shape else 1
                cols[name] = list(range(i, i + k))
                i += k
            self._y0 = _state_fn(plan.system)
            self.y_base = self._states(np.arange(n), np.zeros((n, cfg.dim)))
        self.cols = cols
        if cfg.space == "state" and cfg.norm == "max":
            self._refuse_unmeasured(n)

    def _refuse_unmeasured(self, n: int) -> None:
        """A state component that the shocked entries move but no block measures would move for free (a shock of
        any size there costs nothing): refused, as the parameter space's check refuses an unmeasured component.
        Which state components move is seen from a finite shift of each entry at every grid point (the start
        state is a function of the parameters only: an exact zero where it does not depend on them)."""
        covered = {name for b in self.cfg.blocks for name in b}
        free = [name for name, _ in self.plan.system.state if name not in covered]
        if not free:
            return
        d = self.cfg.dim
        g = np.repeat(np.arange(n), d)
        deltas = np.tile(1e-3 * np.eye(d), (n, 1))
        dev = np.abs(self._states(g, deltas) - self.y_base[g])
        scale = 1.0 + np.abs(self.y_base[g])
        moved = [name for name in free if np.any(dev[:, self.cols[name]] > 1e-9 * scale[:, self.cols[name]])]
        if moved:
            raise ValidationError("shock.blocks", f"state component{'s' if len(moved) > 1 else ''} "
                                                  f"{', '.join(repr(c) for c in moved)} moved by the shocked "
                                                  f"entries but in no block: the max norm would not measure the "
                                                  "shift there (a shock of any size would cost nothing); put every "
                                                  "state component the shock moves in a block")

    def params(self, g: np.ndarray, deltas: np.ndarray) -> dict[str, np.ndarray]:
        """Every parameter of the shocked starts (checked: normalised as the system does)."""
        p = {k: np.asarray(v)[g].copy() for k, v in self.base.items()}
        for j, e in enumerate(self.cfg.entries):
            if e.index is None:
                p[e.param] = p[e.param] + deltas[:, j]
            else:
                p[e.param][(slice(None), *e.index)] += deltas[:, j]
        for name in self.cfg.unit:  # a direction: the shocked vector is put back on the sphere (a retraction)
            p[name] = p[name] / np.linalg.norm(p[name], axis=-1, keepdims=True)
        return p

    def _states(self, g, deltas):
        p = self.plan.system.check(self.params(g, deltas))
        return self._y0(p)

    def deviation(self, g: np.ndarray, deltas: np.ndarray) -> np.ndarray:
        """What the norm measures: ``deltas`` (params) or the start state's shift (state), (M, n)."""
        g = np.asarray(g, np.int64)
        deltas = np.asarray(deltas, float).reshape(len(g), self.cfg.dim)
        if self.cfg.space == "params":
            return deltas
        return self._states(g, deltas) - self.y_base[g]

    def __call__(self, g: np.ndarray, deltas: np.ndarray) -> np.ndarray:
        g = np.asarray(g, np.int64)
        dev = self.deviation(g, deltas)
        parts = []
        for b in self.cfg.blocks:
            s = np.zeros(len(g))
            for name in b:
                w = self.w[name][g] if name in self.w else 1.0
                s = s + (w * w) * np.sum(dev[:, self.cols[name]] ** 2, axis=1)
            parts.append(np.sqrt(s))
        return np.max(np.stack(parts), axis=0) if len(parts) > 1 else parts[0]

    def shift(self, g: np.ndarray, u: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """Shocks along directions ``u`` (M, d) of norm ``radius`` (M,): ``r u`` with ``N(r u) = radius``.

        A norm of the parameters is homogeneous (r = radius / N(u)); a norm of the state shift is found by
        bisection on r (it grows along a ray for the models here: monotonicity is assumed, not checked). A
        radius the ray never reaches (a state norm saturating, as an angle on a sphere does) gives NaN."""
        g = np.asarray(g, np.int64)
        u = np.asarray(u, float)
        radius = np.asarray(radius, float)
        if self.cfg.space == "params":
            return u * (radius / self(g, u))[:, None]
        lo = np.zeros(len(g))
        hi = np.maximum(radius, 1e-12) / np.maximum(np.linalg.norm(u, axis=1), 1e-300)
        for _ in range(64):  # grow hi until the ray's norm passes the radius (or it never will)
            short = self(g, u * hi[:, None]) < radius
            if not short.any() or hi.max() > 1e12:
                break
            hi = np.where(short, 2 * hi, hi)
        reach = self(g, u * hi[:, None]) >= radius
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = self(g, u * mid[:, None]) < radius
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return np.where(reach[:, None], u * hi[:, None], np.nan)


def _state_fn(system):
    """Start states of a batch of (checked) parameter dicts: ``initial_state`` vmapped, compiled once per padded size."""
    import jax

    from ..config import setup_jax

    setup_jax()
    f = jax.jit(jax.vmap(lambda p: jax.numpy.ravel(system.initial_state(p))))

    def y0(p):
        n = len(next(iter(p.values())))
        m = max(8, 1 << (n - 1).bit_length())  # a few shapes, not one per call
        padded = {k: np.concatenate([np.asarray(v, float), np.repeat(np.asarray(v, float)[-1:], m - n, axis=0)])
                  for k, v in p.items()}
        return np.asarray(f(padded))[:n]

    return y0


def describe_norm(cfg: ShockConfig) -> str:
    """The norm in words, e.g. ``max(|w| * 1/lam, |S|)`` (recorded with every result)."""
    def term(names):
        parts = [f"{n} * {cfg.weights[n]}" if n in cfg.weights else n for n in names]
        return "|" + ", ".join(parts) + "|"

    body = ", ".join(term(b) for b in cfg.blocks)
    what = "parameters" if cfg.space == "params" else "start state"
    return (f"max({body})" if len(cfg.blocks) > 1 else body) + f" of the shift of the {what}"


def fraction_bound(n: int, confidence: float = 0.95) -> float:
    """Largest share of directions that could hold a smaller fatal shock although none of ``n`` i.i.d. uniform
    ones did, at ``confidence``: 1 - (1 - confidence)^(1/n) (about 3/n at 95 %)."""
    return 1.0 - (1.0 - confidence) ** (1.0 / max(n, 1)) if n else math.nan
