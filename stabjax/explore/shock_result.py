"""A shock search's result: the theorem's guaranteed region against it, the dataset, and the witness's replay.

**Against the theory.** A theorem states a region of initial conditions it guarantees, through the system's
:class:`stabjax.model.system.Theory` (``[shock] theory = [...]``), in one of two forms:

* a **derived radius** (``Theory.derived[name]``): the radius ``r_g`` of a ball in the shock's norm (Saakyan's
  ``region118_radius`` = l of (1.18) in max(|w1|/lam, |delta|), where Theorem 1's hypotheses hold, else 0);
* a **predicate** (``Theory.predicates[name]``): a margin over the initial-condition parameters, > 0 inside the
  region. Its radius in the shock's norm is the smallest zero of the margin along the directions searched
  (a scan of ``THEORY_SCAN`` radii, then bisection; followed beyond ``max_radius`` where the region reaches it, so
  the radius stored is the theorem's, not capped by the search): exact for a ball, an upper estimate otherwise.

Verdicts (per grid point): **refuted** where the witness -- a fatal start -- lies inside the guaranteed region
(its norm below ``r_g``, or the predicate's margin positive at the witness): a red flag, certain up to the
classification of that one trajectory, which is therefore re-integrated with tolerances a hundred times tighter
(``shock_witness_recheck``); **consistent** where ``r_g`` lies within the resolution below the bracket or in it
(the theorem is tight); **conservative** where ``r_g <= r_lo``, by a factor in [r_lo / r_g, |delta*| / r_g];
**not applicable** where ``r_g = 0`` (the hypotheses fail there), no attractor was searched, or the predicate
names the outcome it guarantees and the shocked attractor is another; **untested** where
no fatal shock was found up to ``max_radius`` and ``r_g`` lies beyond it (the range between was never searched:
the search neither confirms nor refutes the theorem there).
"""
from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any, Mapping

import numpy as np
import xarray as xr

from .shock_config import Norm, ShockConfig, describe_norm, fraction_bound

THEORY_SCAN = 32  # radii per direction at which a predicate's margin is evaluated before bisecting its first zero
THEORY_DIRECTIONS = 32  # scan directions used for a predicate's radius (plus the witness's)
THEORY_CHUNK = 512  # parameter rows per call of the system's theory
THEORY_REACH = 2.0 ** 20  # a predicate's region is followed up to this many times max_radius (then: inf)
VERDICTS = ("refuted", "consistent", "conservative", "not_applicable", "untested")
REFUTED, CONSISTENT, CONSERVATIVE, NOT_APPLICABLE, UNTESTED = range(5)
RECHECK_TIGHTER = 100.0  # the witness of a red flag is re-integrated with rtol and atol divided by this


def theory_values(plan, params: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """A predicate's margin or a derived quantity of the system's theory at parameter rows (chunked: some theories
    hold a grid per row)."""
    n = len(next(iter(params.values())))
    out = np.empty(n)
    for lo in range(0, n, THEORY_CHUNK):
        hi = min(n, lo + THEORY_CHUNK)
        th = plan.system.theory(plan.system.check({k: np.asarray(v)[lo:hi] for k, v in params.items()}))
        v = th.predicates[name].margin if name in th.predicates else th.derived[name]
        out[lo:hi] = np.broadcast_to(np.asarray(v, float), (hi - lo,))
    return out


def predicate_radius(plan, norm: Norm, name: str, g: np.ndarray, U: np.ndarray, r_max: float) -> np.ndarray:
    """Radius in the shock's norm of a predicate's region at grid points ``g`` (P,), over directions ``U``
    (P, D, d): the smallest first zero of the margin along them (0 where the margin is <= 0 unshocked).

    A direction along which the margin stays positive up to ``r_max`` (the largest shock searched) is followed
    further -- the theory only, nothing is integrated -- in windows (top, 2 top] of ``THEORY_SCAN`` radii each, up
    to ``THEORY_REACH`` r_max: the radius is the theorem's, not the search's range. Where the margin stays positive
    as far as every direction reaches (or goes), the region holds no edge along them: ``inf`` (a global claim)."""
    P, D, d = U.shape
    gg = np.repeat(g, D)
    uu = U.reshape(P * D, d)
    m0 = theory_values(plan, norm.params(g, np.zeros((P, d))), name)

    def scan(rows, R):
        """Margins (len(rows), len(R)) along rows ``rows`` at radii ``R`` (inf where the ray cannot reach one)."""
        K = len(R)
        g3, u3 = np.repeat(gg[rows], K), np.repeat(uu[rows], K, axis=0)
        r3 = np.tile(R, len(rows))
        dl = norm.shift(g3, u3, r3)
        reach = np.all(np.isfinite(dl), axis=1)
        m = np.full(len(r3), np.inf)
        if reach.any():
            m[reach] = theory_values(plan, norm.params(g3[reach], dl[reach]), name)
        return m.reshape(len(rows), K), reach.reshape(len(rows), K)

    R = r_max * np.arange(1, THEORY_SCAN + 1) / THEORY_SCAN
    m, reach = scan(np.arange(P * D), R)
    neg = m <= 0
    first = np.where(neg.any(axis=1), neg.argmax(axis=1), -1)
    lo = np.where(first > 0, R[np.maximum(first - 1, 0)], 0.0)
    hi = np.where(first >= 0, R[np.maximum(first, 0)], np.inf)
    # beyond the search's range: the directions still inside at r_max, and reaching it (a ray whose norm saturates
    # is inside as far as it goes)
    go = np.flatnonzero((first < 0) & reach.all(axis=1))
    top = r_max
    while len(go) and top < THEORY_REACH * r_max:
        R = top * (1 + np.arange(1, THEORY_SCAN + 1) / THEORY_SCAN)
        m, reach = scan(go, R)
        neg = m <= 0
        f = np.where(neg.any(axis=1), neg.argmax(axis=1), -1)
        hit = f >= 0
        lo[go[hit]] = np.where(f[hit] > 0, R[np.maximum(f[hit] - 1, 0)], top)
        hi[go[hit]] = R[f[hit]]
        go = go[~hit & reach.all(axis=1)]
        top = 2 * top
    cut = np.flatnonzero(np.isfinite(hi))
    for _ in range(30):
        if not len(cut):
            break
        mid = 0.5 * (lo[cut] + hi[cut])
        dm = norm.shift(gg[cut], uu[cut], mid)
        ok = np.all(np.isfinite(dm), axis=1)
        mm = np.full(len(cut), -np.inf)
        if ok.any():
            mm[ok] = theory_values(plan, norm.params(gg[cut][ok], dm[ok]), name)
        inside = mm > 0
        lo[cut] = np.where(inside, mid, lo[cut])
        hi[cut] = np.where(inside, hi[cut], mid)
    r = np.where(np.isfinite(hi), 0.5 * (lo + hi), np.inf).reshape(P, D).min(axis=1)
    return np.where(m0 > 0, r, 0.0)


def compare(plan, cfg: ShockConfig, norm: Norm, name: str, search, witness: np.ndarray, found: np.ndarray,
            lo: np.ndarray, hi: np.ndarray, names: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Radius, verdict and factor bracket of theorem ``name`` at every grid point (see the module docstring).
    A predicate that names the outcome it guarantees (``Predicate(..., outcome=...)``) is held only where the
    shocked attractor is that outcome: its region says nothing of another attractor's basin."""
    G = search.G
    g = np.arange(G)
    base = norm.params(g, np.zeros((G, cfg.dim)))
    th = plan.system.theory(plan.system.check({k: np.asarray(v)[:1] for k, v in base.items()}))
    doc = th.derived_doc.get(name, name) if name in th.derived else th.predicates[name].doc
    if name in th.derived:
        rg = theory_values(plan, base, name)
        inside = found & (hi < rg)
    else:
        rays_g = np.array(search.rays.g)
        U = np.array(search.rays.u)
        D = min(THEORY_DIRECTIONS, cfg.directions)
        dirs = []
        for k in range(G):
            ks = np.flatnonzero(rays_g == k)[:D]
            extra = [witness[k] / np.linalg.norm(witness[k])] if found[k] and np.linalg.norm(witness[k]) > 0 \
                else [U[ks[0]]]
            dirs.append(np.concatenate([U[ks], np.array(extra)]))
        rg = predicate_radius(plan, norm, name, g, np.stack(dirs), cfg.max_radius)
        inside = np.zeros(G, bool)
        if found.any():
            wm = theory_values(plan, norm.params(g[found], witness[found]), name)
            inside[found] = wm > 0
    valid = search.attractor >= 0
    said = th.predicates[name].outcome if name in th.predicates else ""
    if said and said in names:
        valid &= search.attractor == names.index(said)
    verdict = np.full(G, NOT_APPLICABLE, np.int8)
    ok = valid & (rg > 0)  # NaN: no radius there; inf: a global claim
    tol = cfg.tol(np.where(found, hi, np.inf))
    verdict[ok] = np.where(rg[ok] < lo[ok] - tol[ok], CONSERVATIVE, CONSISTENT)  # beyond the resolution, or within it
    # no fatal shock up to max_radius (= lo), and the theorem's region reaches beyond it: the range between was never
    # searched, so the search neither confirms nor refutes it there
    beyond = ok & ~found & (rg > lo * (1 + 1e-9))
    verdict[beyond] = UNTESTED
    verdict[ok & inside] = REFUTED
    with np.errstate(divide="ignore", invalid="ignore"):
        f_lo = np.where(ok & ~beyond, lo / rg, np.nan)
        f_hi = np.where(ok & found, hi / rg, np.nan)
    return {"radius": rg, "verdict": verdict, "factor_lo": f_lo, "factor_hi": f_hi, "doc": doc}


def recheck(rplan, label, g: np.ndarray, params: Mapping[str, np.ndarray]) -> np.ndarray:
    """Outcome codes of starts re-integrated with rtol and atol divided by ``RECHECK_TIGHTER`` (same horizon)."""
    from ..engines.simulate import solve_batch
    from ..plan.spec import static_params

    if not len(g):
        return np.zeros(0, np.int16)
    icfg = rplan.icfg.replace(rtol=rplan.icfg.rtol / RECHECK_TIGHTER, atol=rplan.icfg.atol / RECHECK_TIGHTER)
    p = rplan.system.check({k: np.asarray(v) for k, v in params.items()})
    res = solve_batch(rplan.integrated, p, icfg, rplan.vcfg, static=[k for k in static_params(rplan)])
    return label(g, p, {k: np.asarray(v) for k, v in res.items()})


# ---- the dataset ---------------------------------------------------------------------------------------


def _units(plan, cfg: ShockConfig) -> str:
    """The norm's unit: the shocked components' common unit when the norm is unweighted, else ``1``."""
    if cfg.weights:
        return "1"
    if cfg.space == "params":
        units = {plan.system.params[e.param].unit for e in cfg.entries}
        return units.pop() or "1" if len(units) == 1 else "1"
    return "1"


def assemble(plan, rplan, cfg: ShockConfig, norm: Norm, search, names: tuple[str, ...], base, *,
             wall: float = float("nan"), engines=frozenset(), rounds_resumed: int = 0, label=None,
             base_status: np.ndarray | None = None, total_steps: int | None = None) -> xr.Dataset:
    """The result's dataset (see the module docstring and docs/guide/shock.md for its variables).
    ``base_status``: the unshocked starts' solver status (diffrax's codes), which says why a base start that
    failed did (the solver stopped, or it reached t1 with observables not finite). ``total_steps``: the rounds'
    accepted solver steps, stored as ``attrs["total_steps"]`` (None: unknown, no such attribute)."""
    from ..run.dataset import cf_attributes, status_flags
    from ..run.derive import provenance

    G, d = search.G, cfg.dim
    gshape = tuple(ax.size for ax in plan.grid)
    gdims = tuple(ax.name for ax in plan.grid)
    shp = lambda x: np.asarray(x).reshape(gshape + np.shape(x)[1:])  # noqa: E731
    r = search.rays
    rg, hi_all, lo_all = np.array(r.g), np.array(r.hi), np.array(r.lo)
    best = search.best()
    found = np.isfinite(best)
    hi = np.where(found, best, np.nan)
    lo = np.full(G, np.nan)
    witness = np.full((G, d), np.nan)
    wcode = np.full(G, -1, np.int16)
    for g in range(G):
        ks = np.flatnonzero(rg == g)
        if not search.valid[g] or not len(ks):
            continue
        lo[g] = min(float(np.min(lo_all[ks])), best[g]) if found[g] else float(np.min(lo_all[ks]))
        if found[g]:
            k = ks[np.argmin(hi_all[ks])]
            witness[g], wcode[g] = r.delta[k], r.code[k]
    lo = np.where(np.isinf(lo), cfg.max_radius, lo)
    gidx = np.arange(G)
    wparams = norm.params(gidx, np.nan_to_num(witness))
    wvals = np.stack([wparams[e.param] if e.index is None else wparams[e.param][(slice(None), *e.index)]
                      for e in cfg.entries], axis=1)
    wvals[~found] = np.nan
    units = _units(plan, cfg)
    flags = {"flag_values": np.arange(len(names), dtype=np.int16), "flag_meanings": " ".join(names)}
    nu = {"units": units}
    comp_units = " ".join(plan.system.params[e.param].unit or "1" for e in cfg.entries)
    data: dict[str, Any] = {
        "base_outcome": (gdims, shp(np.where(search.valid, search.attractor, getattr(search, "base_codes", -1))
                                    .astype(np.int16)),
                         {"long_name": "outcome of the unshocked start (the attractor shocked)", **flags}),
        **({} if base_status is None else {"base_solver_status": (gdims, shp(np.asarray(base_status, np.int32)), {
            "long_name": "solver status of the unshocked start (diffrax RESULTS codes; 100: escaped the escape "
                         "radius)", "flag_values": status_flags()[0], "flag_meanings": status_flags()[1]})}),
        "shock_norm": (gdims, shp(hi), {"long_name": "size of the minimal fatal shock found: norm of the smallest "
                                                     "fatal shock (NaN: none up to max_radius)", **nu}),
        "shock_norm_lo": (gdims, shp(lo), {"long_name": "lower end of the bracket: no fatal shock below it among the "
                                                        "directions searched (statistical)", **nu}),
        "shock_delta": ((*gdims, "component"), shp(witness), {
            "long_name": "the minimal fatal shock found: shift of each shocked entry", "component_units": comp_units}),
        "shock_witness": ((*gdims, "component"), shp(wvals), {
            "long_name": "witness start: the shocked entries' values of the smallest fatal shock",
            "component_units": comp_units}),
        "shock_witness_outcome": (gdims, shp(wcode), {"long_name": "outcome the witness start reaches (-1: no "
                                                                    "witness, no fatal shock found)", **flags}),
        "shock_undecided_norm": (gdims, shp(np.where(np.isfinite(search.undecided_min), search.undecided_min,
                                                     np.nan)),
                                 {"long_name": "smallest norm of a shocked start the classifier left undecided or "
                                               "unclassified (counted as not fatal; NaN: none)", **nu}),
        "shock_trajectories": (gdims, shp(search.trajectories), {"long_name": "trajectories integrated for the "
                                                                              "grid point's search"}),
        "shock_cma_generations": (gdims, shp(search.cma_generations),
                                  {"long_name": "CMA-ES generations of the local refinement"}),
    }
    if cfg.space == "state":
        comps = [f"{n}" if not s else f"{n}_{'_'.join(map(str, i))}"
                 for n, s in plan.system.state for i in (np.ndindex(s) if s else [()])]
        dev = np.full((G, len(comps)), np.nan)
        if found.any():
            dev[found] = norm.deviation(gidx[found], witness[found])
        data["shock_state_delta"] = ((*gdims, "state_component"), shp(dev), {
            "long_name": "shift of the start state by the minimal fatal shock found (what the norm measures)"})
    # the scan directions' exit brackets (the same directions at every grid point)
    N = cfg.directions
    scan = np.array(r.kind) == 0
    dlo = np.full((G, N), np.nan)
    dhi = np.full((G, N), np.nan)
    for g in range(G):
        ks = np.flatnonzero(scan & (rg == g))
        if search.valid[g]:
            dlo[g] = np.where(np.isinf(lo_all[ks]), np.nan, lo_all[ks])
            dhi[g] = np.where(np.isinf(hi_all[ks]), np.nan, hi_all[ks])
    U = np.array(r.u)[scan][:N]
    if cfg.space == "params":  # the norm of each unit direction (the plot draws the norm's ball from it)
        scale = norm(np.repeat(gidx, N), np.tile(U, (G, 1))).reshape(G, N)
        data["direction_scale"] = ((*gdims, "direction"), shp(scale), {
            "long_name": "norm of the unit direction (a shock r u has the size r times this)"})
    data["direction_vector"] = (("direction", "component"), U, {"long_name": "unit direction of each scanned shock "
                                                                             "in the shocked entries"})
    data["direction_exit_lo"] = ((*gdims, "direction"), shp(dlo), {
        "long_name": "largest radius found not fatal below the first fatal one along the direction (NaN: not "
                     "searched, or no fatal shock as far as it reaches)", **nu})
    data["direction_exit_hi"] = ((*gdims, "direction"), shp(dhi), {
        "long_name": "smallest fatal radius found along the direction, if bracketed to the resolution (NaN: no "
                     "fatal shock up to max_radius)", **nu})
    theory_json = {}
    for name in cfg.theory:
        c = compare(plan, cfg, norm, name, search, witness, found, np.where(np.isnan(lo), 0, lo), hi, names)
        data[f"theory_radius_{name}"] = (gdims, shp(c["radius"]), {
            "long_name": f"radius of the region guaranteed by {name} in the shock's norm (0: its hypotheses fail; "
                         "inf: no edge along the directions searched)",
            "theorem": str(c["doc"]), **nu})
        data[f"theory_verdict_{name}"] = (gdims, shp(c["verdict"]), {
            "long_name": f"{name} against the minimal fatal shock",
            "flag_values": np.arange(len(VERDICTS), dtype=np.int8),
            "flag_meanings": " ".join(VERDICTS)})
        data[f"theory_factor_lo_{name}"] = (gdims, shp(c["factor_lo"]), {
            "long_name": f"lower end of |delta*| / radius of {name} (> 1: the theorem is conservative by this factor)"})
        data[f"theory_factor_hi_{name}"] = (gdims, shp(c["factor_hi"]), {
            "long_name": f"upper end of |delta*| / radius of {name}"})
        theory_json[name] = {v: int((c["verdict"] == i).sum()) for i, v in enumerate(VERDICTS)}
    if label is not None and found.any():
        rc = np.full(G, -1, np.int16)
        gf = gidx[found]
        rc[found] = recheck(rplan, label, gf, {k: np.asarray(v)[found] for k, v in wparams.items()})
        data["shock_witness_recheck"] = (gdims, shp(rc), {
            "long_name": f"outcome of the witness start re-integrated with rtol and atol / {RECHECK_TIGHTER:g}",
            **flags})
    coords: dict[str, Any] = {ax.name: (ax.name, ax.values, {"long_name": ax.param.doc or ax.name,
                                                              **({"units": ax.param.unit} if ax.param.unit else {})})
                              for ax in plan.grid}
    coords["component"] = ("component", np.array([e.key for e in cfg.entries], dtype=object),
                           {"long_name": "shocked entry of an initial-condition parameter"})
    coords["direction"] = ("direction", np.arange(N), {"long_name": "index of a scanned direction"})
    if cfg.space == "state":
        coords["state_component"] = ("state_component", np.array(comps, dtype=object))
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(provenance(plan))
    n_traj = int(search.trajectories.sum())
    ds.attrs.update(
        kind="shock", shock_json=json.dumps({**asdict(cfg), "entries": [e.key for e in cfg.entries]}),
        norm=describe_norm(cfg), outcome_names=" ".join(names), rounds=search.rounds,
        round_sizes=list(search.round_sizes), n_directions=N, n_trajectories=n_traj,
        wall_time_s=float(wall), engine=",".join(sorted(engines)) or "resumed", rounds_resumed=int(rounds_resumed),
        statement=_statement(cfg, search.valid, found),
        theory_json=json.dumps(theory_json), grid_keys_json=json.dumps({ax.name: ax.key for ax in plan.grid}),
    )
    if total_steps is not None:  # the rounds' records carry no steps: none stored rather than a false 0
        ds.attrs["total_steps"] = int(total_steps)
    cf_attributes(ds, plan, activity="shock search", trajectories=n_traj)
    return ds


def _statement(cfg: ShockConfig, valid: np.ndarray, found: np.ndarray | None = None) -> str:
    """What the result promises, where a search ran: a grid point whose unshocked start failed or reached no
    attractor to shock (``valid`` false) holds no bracket, so the statistical statement is not made of it; where no
    fatal shock was found (``found`` false) there is no witness, so none is promised."""
    N = cfg.directions
    why = "the unshocked start failed or did not reach the attractor to shock; base_outcome says which"
    if not valid.any():
        return (f"no search ran{' at any grid point' if valid.size > 1 else ''} ({why}): shock_norm and "
                "shock_norm_lo are NaN.")
    found = valid if found is None else np.asarray(found, bool) & valid
    skipped = int((~valid).sum())
    where = f"at the {int(valid.sum())} of {valid.size} grid points searched: " if skipped else ""
    elsewhere = f" At the other {skipped} no search ran ({why})." if skipped else ""
    scan = (f"each scanned at {cfg.radii} radii up to {cfg.max_radius:g}, then bisected; a direction is assumed to "
            f"leave the basin once between two scan radii")
    upper = "shock_norm is a fatal shock found (its witness start is stored): an upper bound."
    n_found, n_valid = int(found.sum()), int(valid.sum())
    if n_found == 0:
        upper = (f"No fatal shock was found up to max_radius = {cfg.max_radius:g}: shock_norm is NaN, no witness, and "
                 "shock_norm_lo is max_radius.")
    elif n_found < n_valid:
        upper = (f"Where one was found ({n_found} of the {n_valid} grid points searched), {upper[0].lower() + upper[1:]} "
                 f"At the other {n_valid - n_found} no fatal shock was found up to max_radius = {cfg.max_radius:g} "
                 "(shock_norm NaN, no witness).")
    if cfg.dim == 1 and N == 2:  # both directions of the one component: nothing is left to chance
        return (f"{where}no fatal shock in either direction of {cfg.components[0]} below shock_norm_lo ({scan}). "
                f"{upper}{elsewhere}")
    return (f"{where}no fatal shock among the {N} directions searched below shock_norm_lo ({scan}): the share of "
            f"directions that could hold a smaller one is below {fraction_bound(N):.2g} at 95 % confidence; a "
            f"narrower cone can escape. {upper}{elsewhere}")


# ---- replay ----------------------------------------------------------------------------------------------


def witness_replay(ds: xr.Dataset, **sel) -> dict[str, Any]:
    """Parameters and the one command (``stabjax simulate ...``) that replay the witness start at a grid point
    (``sel``: one value per grid axis; none without a grid), for a person, a test, or the explorer's click."""
    from ..errors import ValidationError

    if not hasattr(ds, "data_vars") or "shock_norm" not in ds or "shock_witness" not in ds:
        raise ValidationError("ds", "not a minimal-fatal-shock result (no shock_norm, shock_witness): "
                                    "witness_replay replays what stabjax.minimal_fatal_shock found")
    axes = ds["shock_norm"].dims
    for k, v in sel.items():
        if k not in axes:
            raise ValidationError(k, f"is not a grid axis of this result ({', '.join(axes) or 'it has no grid'})")
        if np.ndim(v) or not np.isin(v, ds[k].values):
            grid = ", ".join(f"{x:g}" for x in ds[k].values)
            raise ValidationError(k, f"{v!r} is not one of its grid values ({grid})")
    if set(sel) != set(axes):
        raise ValidationError("sel", f"select one grid point: give a value of each of {', '.join(axes)}")
    fixed = json.loads(ds.attrs["fixed_params_json"])
    point = ds.sel(**sel) if sel else ds
    p = {k: np.asarray(v, float) for k, v in fixed.items()}
    keys = json.loads(ds.attrs.get("grid_keys_json", "{}"))
    vals = np.asarray(point["shock_witness"].values, float)
    if not np.all(np.isfinite(vals)):
        return {"params": None, "command": "", "found": False}
    import re

    items = [(keys.get(ax, ax), float(point[ax].values)) for ax in ds["shock_norm"].dims]
    items += list(zip([str(c) for c in ds["component"].values], vals))
    for key, v in items:
        m = re.match(r"^(\w+)(?:\[(.*)\])?$", key)
        name, idx = m.group(1), m.group(2)
        if idx is None:
            p[name] = np.asarray(v)
        else:
            arr = np.array(p[name], float)
            arr[tuple(int(i) for i in idx.split(","))] = v
            p[name] = arr
    integ = json.loads(ds.attrs.get("integrate_json", "{}"))
    sets = " ".join(f"-s {k}={','.join(repr(float(x)) for x in np.ravel(v))}" for k, v in p.items())
    cmd = (f"stabjax simulate {ds.attrs.get('system_ref', ds.attrs.get('system'))} {sets} --t1 {integ.get('t1', '')} "
           f"--rtol {integ.get('rtol', 1e-10):g} --atol {integ.get('atol', 1e-12):g}")
    return {"params": {k: np.asarray(v).tolist() for k, v in p.items()}, "command": cmd, "found": True}
