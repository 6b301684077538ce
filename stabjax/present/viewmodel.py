"""The viewer's model of a result (``stabjax view``, :mod:`stabjax.present.view`): what a click on the map means,
the re-simulation of that trajectory with the settings the result recorded, why it got its outcome, and the
columns every figure of the page draws -- pure functions of the loaded result, tested without a browser.

Split from the Bokeh page (:mod:`stabjax.present.view`) at the seam the page's own docstring drew: this module
knows results, the page knows Bokeh. A result is read through the kit's opener
(:func:`stabjax.present.kit.open_result`), so a running or interrupted sweep's store is shown like a finished
file (its unfinished chunks marked pending; a discovery's trajectories without an outcome until it ends), and
a store that its sweep removed on finishing is followed to the netCDF file written from it.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ValidationError
from . import kit
from .labels import axis_label, trajectory_noun

if TYPE_CHECKING:
    import xarray as xr

PENDING_COLOR = "#f0f0f0"


# ---- the result ------------------------------------------------------------------------------------


class Result:
    """A loaded result and what the page needs from it: its map, its trajectories' parameters,
    their re-simulation and the explanation of their outcome.

    ``path``: a netCDF result or a sweep's store. A store is read again by :meth:`reload` as its chunks
    land; once its sweep has finished and removed it, the result file written from it
    (:func:`stabjax.present.kit.finished_file`) is shown instead and :attr:`note` says so; a store that is
    gone with no such file keeps what was last read, and :attr:`note` says what happened."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.store = self.path if self.path.is_dir() else None
        self.opened = time.time()
        self.note = ""
        self.ds = None
        self._plan = None
        self._verified: dict = {}  # the store's chunk files checked so far (kit.open_result)
        self.reload()

    def reload(self) -> None:
        """Read the result again (a store: the chunks finished so far, each checked against its checksum once
        while its file is unchanged)."""
        try:
            ds = kit.open_result(self.path, verified=self._verified if self.path == self.store else None)
        except Exception as exc:  # noqa: BLE001 - a store being removed fails in many ways midway
            if self.store is None or self.path != self.store:
                raise
            nc = self._written_from_store()
            if nc is None:
                if self.ds is None:
                    raise
                self.note = (f"the store {self.store} cannot be read now ({_reason(exc)}); still showing what was "
                             "read last" + (f" -- when its sweep finishes, open {kit.finished_file(self.store)}"
                                            if kit.finished_file(self.store) else ""))
                return
            self.path = nc
            ds = kit.open_result(nc)
            self.note = (f"the sweep finished and removed its store {self.store}: now showing the result it wrote, "
                         f"{nc}")
        self.ds = ds
        self.kind = kit.kind(ds)
        self.running = "pending" in ds and bool(ds["pending"].any())

    def _written_from_store(self) -> Path | None:
        """The netCDF file the sweep of this store wrote when it finished (it then removes the store), once
        the store is gone or emptied: written since this viewer opened the store, of the same spec."""
        from ..run.outputs import spec_digest_of as spec_of

        nc = kit.finished_file(self.store)
        if nc is None or not nc.is_file():
            return None
        try:
            if nc.stat().st_mtime < self.opened - 1.0:  # an older file of the same name: not this run's
                return None
            import xarray as xr

            with xr.open_dataset(nc, engine="netcdf4") as done:
                same = self.ds is None or spec_of(done) == spec_of(self.ds)
        except Exception:  # noqa: BLE001 - being written, or not a result: not (yet) the store's result
            return None
        return nc if same else None

    def session(self) -> "Result":
        """The result for one more browser tab: this one when it is a file (read once, shared), else a copy
        that reads the store again on its own (it may have been removed since)."""
        if self.store is None or self.path != self.store:
            return self
        import copy

        other = copy.copy(self)
        other._plan = None
        other._verified = dict(self._verified)
        other.reload()
        return other

    # -- identity and re-simulation ---------------------------------------------------------------
    @property
    def plan(self):
        """The sweep plan, rebuilt from the spec and settings recorded in the dataset."""
        if self._plan is None:
            from ..plan.spec import make_plan

            spec = kit.json_attr(self.ds, "spec_json")
            if spec is None:
                raise ValidationError("result", f"{self.path} records no spec: its trajectories cannot be re-run")
            integ = kit.json_attr(self.ds, "integrate_json", {}) or {}
            self._plan = make_plan(spec, t1=integ.get("t1"))
        return self._plan

    def names_colors(self) -> tuple[list[str], list[str]]:
        """Outcome (or refinement label) names and their colours, as recorded (``flag_colors``)."""
        return kit.names_colors(self.ds)

    def params_of(self, idx: int) -> dict[str, np.ndarray]:
        """Every parameter of trajectory ``idx`` (flat sweep index, or refinement point index)."""
        plan = self.plan
        if self.kind == "refine":
            import dataclasses

            axes = self.ds.attrs["axes"].split()
            values = np.array([[float(self.ds[f"point_{a}"].values[idx]) for a in axes]])
            p = dataclasses.replace(plan, points=values).params_for(0, 1)  # the point's first sample
            return {k: np.asarray(v)[0] for k, v in p.items()}
        p = plan.params_at(np.array([idx]))
        return {k: np.asarray(v)[0] for k, v in p.items()}

    def simulate(self, idx: int, n_times: int = 1500) -> xr.Dataset:
        """Trajectory ``idx`` again, with the result's system, solver, tolerances and horizon."""
        return self.run(self.params_of(idx), n_times)

    def run(self, params, n_times: int = 1500) -> xr.Dataset:
        """The trajectory from ``params`` with the result's system, solver, tolerances and horizon (a shock
        result's witness and unshocked starts, :func:`stabjax.present.shock.starts`)."""
        from ..engines.simulate import simulate

        ic = self.plan.icfg
        lin = np.linspace(ic.t0, ic.t1, n_times // 2)
        geo = ic.t0 + np.geomspace(max((ic.t1 - ic.t0) * 1e-5, 1e-12), ic.t1 - ic.t0, n_times // 2)
        ts = np.unique(np.clip(np.concatenate([lin, geo]), ic.t0, ic.t1))
        return simulate(self.plan.system, params, t1=ic.t1, t0=ic.t0, ts=ts, solver=ic.solver,
                        rtol=ic.rtol, atol=ic.atol, max_steps=ic.max_steps)

    def late_window(self) -> tuple[float, float]:
        """The window the classifier judges the end of a run on: the outcome features' last
        ``window`` fraction (named outcomes), else the verdict's last ``late_decades`` in log-time; a shock
        search for an excitability threshold judges the whole run."""
        ic, vc = self.plan.icfg, self.plan.vcfg
        decl = self.plan.scheme.decl
        if self.kind == "shock" and kit.json_attr(self.ds, "shock_json", {}).get("excitability"):
            return ic.t0, ic.t1
        if self.kind in ("basin", "discovery", "shock") and decl is not None:
            w = float(decl.window)
            return ic.t1 - w * (ic.t1 - ic.t0), ic.t1
        return ic.t0 + (ic.t1 - ic.t0) * 10.0 ** (-float(vc.late_decades)), ic.t1

    # -- the map ----------------------------------------------------------------------------------
    def grid_dims(self) -> list[str]:
        return kit.grid_dims(self.ds)

    def codes(self) -> np.ndarray:
        """Outcome code of every trajectory, in the plan's flat order (verdicts at t1 without outcomes)."""
        return kit.codes(self.ds)

    def explain(self, idx: int, traj: xr.Dataset | None = None) -> list[tuple[str, str]]:
        """(what, value) rows saying why trajectory ``idx`` got its verdict and outcome (``traj``: its
        re-simulation, for the escape time)."""
        from ..fold import status as S
        from ..fold import verdict as V

        ds = self.ds
        names, _ = self.names_colors()
        rows: list[tuple[str, str]] = []
        if self.kind == "refine":
            lab = int(ds["point_label"].values[idx])
            rows.append(("label", f"{names[lab]} (share of samples {float(ds['point_share'].values[idx]):.2f})"))
            rows.append(("found in round", str(int(ds["point_round"].values[idx]))))
            return rows
        flat = {k: np.asarray(v.values).reshape(-1, *v.shape[len(self.plan.dims):])
                for k, v in ds.data_vars.items() if v.dims[: len(self.plan.dims)] == tuple(self.plan.dims)}
        one = {k: v[idx] for k, v in flat.items()}
        code = int(self.codes()[idx])
        if "pending" in one and bool(one["pending"]):
            return [("status", "not computed yet (its chunk has not finished)")]
        if self.kind == "discovery" and "outcome" not in ds:
            rows.append(("outcome", "assigned when every trajectory has run: attractor discovery groups the whole "
                                    "sweep's trajectories by their late-window features"))
        else:
            where = kit.where_of(ds).get(names[code], "")
            rows.append(("outcome", names[code] + (f" ({where})" if where else "")))
        if "verdict" in one:
            v = np.atleast_1d(one["verdict"])
            hs = ds["horizon"].values if "horizon" in ds.dims else [self.plan.icfg.t1]
            rows.append(("verdict at each horizon", ", ".join(f"T={T:.3g}: {V.NAMES[int(x)]}" for T, x in zip(hs, v))))
        st = int(one.get("solver_status", 0))
        if st == S.ESCAPED:
            when = ""
            if traj is not None:  # the re-run stops there too: its last finite save time
                fin = np.all([np.isfinite(traj[v].values.reshape(traj.sizes["t"], -1)).all(1)
                              for v in traj.data_vars if "t" in traj[v].dims], axis=0)
                when = f" at t ≈ {float(traj['t'].values[fin][-1]):.4g}" if fin.any() and not fin.all() else ""
            rows.append(("escape", f"stopped{when} once max|y_i| > {self.plan.system.escape_radius or '?'} "
                                   "(status 100): ran away"))
            rows.append(("assigned by", "the escape (before any rule or template)"))
        elif st != 0:
            rows.append(("solver", f"failed with status {st} (did not reach t1): outcome 'failed'"))
        elif not self.plan.scheme.from_verdicts and names[code] == "failed":
            # the rules would read NaN here, and one of them (a catch-all) might even say it holds
            rows.append(("features", "an observable the outcome reads is NaN or infinite in the late window "
                                     "(the solver reached t1): outcome 'failed', no rule or template consulted"))
        else:
            rows += self._rule_rows(idx, code, one)
        for k in ("error_t1", "error_max_late", "t_settle", "n_flips", "t_first_flip", "decay_exponent", "peak_ratio"):
            if k in one:
                val = np.atleast_1d(one[k])[-1]
                rows.append((k, f"{float(val):.4g}  ({V.SUMMARY_DOC.get(k, '')})"))
        for k in [k for k in one if "lyap" in k.lower()]:
            rows.append((k, f"{float(np.ravel(one[k])[-1]):.4g}"))
        return rows

    def _rule_rows(self, idx: int, code: int, one: dict) -> list[tuple[str, str]]:
        """The rule that fired, or the nearest template and its distance (named outcomes), or the group a
        discovery put it in."""
        from ..model import outcomes as O

        sch = self.plan.scheme
        if sch.from_verdicts:
            return [("assigned by", "the verdict at t1 (this system names no outcomes of its own)")]
        if self.kind == "discovery":
            if "outcome" not in self.ds:
                return []
            found = {a["name"]: a for a in kit.attractors(self.ds)}
            name = self.names_colors()[0][code]
            if sch.decl is not None and name == sch.decl.escape:  # reached t1: discovery saw it run away
                return [("assigned by", "attractor discovery: it grows without bound over its late window (no "
                         "attractor; counted with the escapes, stabjax.mapping.discover.unbounded)")]
            a = found.get(name)
            return [("assigned by", "attractor discovery: grouped by its late-window features with "
                     + (f"{a['count']:,} {trajectory_noun(a['count'])} on one {a['type'].replace('_', ' ')}" if a else
                        "no group (too far from every attractor found)"))]
        decl = sch.decl
        system = self.plan.system
        res = {k: np.asarray(v)[None] for k, v in one.items() if k.startswith("feat_")}
        if not res:
            return []
        feat = O.feature_getter(res, tuple(system.observables))
        params = self.params_of(idx)

        def par(name):
            return np.asarray(params[name], float).reshape(1)

        obs, scalars = O._names(system)
        out = []
        for name, text in decl.rules.items():
            hit = bool(np.ravel(O.parse(text, obs, scalars, f"outcomes.rules.{name}")(feat, par))[0])
            out.append((f"rule {name}", f"{'holds' if hit else 'does not hold'}: {text}"))
            if hit:
                out.append(("assigned by", f"rule {name} (the first that holds)"))
                return out
        if decl.templates and "template_features" in self.ds:
            x = O.feature_matrix(decl, system, feat, par)[0]
            ns = max(self.plan.n_sample, 1)
            tf = np.asarray(self.ds["template_features"].values).reshape(-1, len(decl.templates), x.size)[idx // ns]
            d = np.linalg.norm(tf - x, axis=-1)
            j = int(np.nanargmin(d)) if np.isfinite(d).any() else 0
            out.append(("nearest template", f"{list(decl.templates)[j]} at distance {d[j]:.4g} "
                                            f"(features {', '.join(decl.features)})"))
        return out


# ---- the page's columns ---------------------------------------------------------------------------


def _edges(x: np.ndarray, log: bool) -> np.ndarray:
    from .maps import cell_edges

    return cell_edges(np.asarray(x, float), log)


def map_columns(r: Result, leading: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """(ColumnDataSource data, figure settings) of the result's map.

    One glyph per cell (grid results), per sampled start (samples only) or per evaluated point
    (refinement); ``idx`` is the trajectory a click re-simulates. ``leading``: the index along the
    first grid axis when there are three (the map shows the last two).
    """
    ds = r.ds
    names, colors = r.names_colors()
    label = lambda d: axis_label(ds, d, math=False)  # noqa: E731
    if r.kind == "refine":
        axes = ds.attrs["axes"].split()
        lab = np.asarray(ds["point_label"].values).astype(int)
        xd = axes[1] if len(axes) == 2 else axes[0]
        x = np.asarray(ds[f"point_{xd}"].values, float)
        y = np.asarray(ds[f"point_{axes[0]}"].values, float) if len(axes) == 2 else lab.astype(float)
        data = dict(x=x, y=y, idx=np.arange(len(x)), color=[colors[k] for k in lab], name=[names[k] for k in lab],
                    alpha=np.ones(len(x)))
        return data, dict(glyph="scatter", x_label=label(xd),
                          y_label=label(axes[0]) if len(axes) == 2 else "label", log_x=False, log_y=False)
    codes = r.codes()
    dims = r.grid_dims()
    ns = max(r.plan.n_sample, 1)
    pending = np.asarray(ds["pending"].values).ravel() if "pending" in ds else np.zeros(codes.size, bool)
    if not dims:  # samples only: one dot per sampled start, at its first two sampled scalars
        keys = [k[: -len("_sample")] for k in ds.data_vars if k.endswith("_sample") and ds[k].dims == ("sample",)]
        x = ds[f"{keys[0]}_sample"].values if keys else np.arange(codes.size, dtype=float)
        y = ds[f"{keys[1]}_sample"].values if len(keys) > 1 else codes.astype(float)
        col = [PENDING_COLOR if p else colors[c] for c, p in zip(codes, pending)]
        data = dict(x=np.asarray(x, float), y=np.asarray(y, float), idx=np.arange(codes.size), color=col,
                    name=["pending" if p else names[c] for c, p in zip(codes, pending)], alpha=np.ones(codes.size))
        return data, dict(glyph="scatter", x_label=label(keys[0]) if keys else "sample",
                          y_label=label(keys[1]) if len(keys) > 1 else "outcome code", log_x=False,
                          log_y=False)
    shape = tuple(ds.sizes[d] for d in dims)
    per_point = codes.reshape(*shape, ns)
    pend = pending.reshape(*shape, ns)
    if len(dims) >= 3:  # the last two axes, at index `leading` of the first (and 0 of any others)
        sel = (leading,) + (0,) * (len(dims) - 3)
        per_point, pend = per_point[sel], pend[sel]
        base = np.ravel_multi_index(sel + (0, 0), shape) * ns
        dims2 = dims[-2:]
    else:
        base, dims2 = 0, dims
    frac = np.stack([(per_point == k).mean(-1) for k in range(len(names))], -1)
    dom, share = frac.argmax(-1), frac.max(-1)
    anypend = pend.any(-1)
    log = {d: bool(ds[d].attrs.get("log_axis", 0)) for d in dims2}
    if len(dims2) == 2:
        yd, xd = dims2
        xe, ye = _edges(ds[xd].values, log[xd]), _edges(ds[yd].values, log[yd])
        iy, ix = np.meshgrid(np.arange(len(ye) - 1), np.arange(len(xe) - 1), indexing="ij")
        iy, ix = iy.ravel(), ix.ravel()
        d, s, pe = dom.ravel(), share.ravel(), anypend.ravel()
        data = dict(left=xe[ix], right=xe[ix + 1], bottom=ye[iy], top=ye[iy + 1],
                    x=np.asarray(ds[xd].values, float)[ix], y=np.asarray(ds[yd].values, float)[iy],
                    idx=base + (iy * (len(xe) - 1) + ix) * ns,
                    color=[PENDING_COLOR if p else colors[k] for k, p in zip(d, pe)],
                    name=["pending" if p else names[k] + (f" ({v:.2f})" if ns > 1 else "") for k, v, p in zip(d, s, pe)],
                    alpha=(0.35 + 0.65 * s) if ns > 1 else np.ones(len(d)))
        return data, dict(glyph="quad", x_label=label(xd), y_label=label(yd), log_x=log[xd], log_y=log[yd],
                          xd=xd, yd=yd)
    xd = dims2[0]
    xe = _edges(ds[xd].values, log[xd])
    n = len(xe) - 1
    data = dict(left=xe[:-1], right=xe[1:], bottom=np.zeros(n), top=np.ones(n), x=np.asarray(ds[xd].values, float),
                y=np.full(n, 0.5), idx=base + np.arange(n) * ns,
                color=[PENDING_COLOR if p else colors[k] for k, p in zip(dom, anypend)],
                name=["pending" if p else names[k] + (f" ({v:.2f})" if ns > 1 else "") for k, v, p in zip(dom, share, anypend)],
                alpha=(0.35 + 0.65 * share) if ns > 1 else np.ones(n))
    return data, dict(glyph="quad", x_label=label(xd), y_label="", log_x=log[xd], log_y=False, xd=xd)


def theory_lines(r: Result, leading: int = 0) -> dict[str, list]:
    """The theory's boundary on the map: the zero contour of the main predicate's margin (xs, ys lists)."""
    ds = r.ds
    main = ds.attrs.get("theory_main") or ""
    xs, ys = [], []
    if r.kind == "refine":
        if "theory_margin" not in ds:
            return dict(xs=[], ys=[])
        axes = ds.attrs["axes"].split()
        if len(axes) != 2:
            return dict(xs=[], ys=[])
        m = ds["theory_margin"].transpose(f"{axes[0]}_theory", f"{axes[1]}_theory").values
        x, y = ds[f"{axes[1]}_theory"].values, ds[f"{axes[0]}_theory"].values
    else:
        dims = r.grid_dims()
        if f"margin_{main}" not in ds or len(dims) < 2:
            return dict(xs=[], ys=[])
        from .labels import categories

        m = ds[f"margin_{main}"]
        if "sample" in m.dims:
            m = m.isel(sample=0)
        if len(dims) >= 3:
            m = m.isel({dims[0]: leading, **{d: 0 for d in dims[1:-2]}})
        yd, xd = dims[-2:]
        if categories(ds, xd) or categories(ds, yd):
            return dict(xs=[], ys=[])
        m = m.transpose(yd, xd).values
        x, y = ds[xd].values, ds[yd].values
    if len(x) < 2 or len(y) < 2 or not (np.nanmin(m) < 0 < np.nanmax(m)):
        return dict(xs=[], ys=[])
    import contourpy

    gen = contourpy.contour_generator(np.asarray(x, float), np.asarray(y, float), np.asarray(m, float))
    for line in gen.lines(0.0):
        xs.append(line[:, 0].tolist())
        ys.append(line[:, 1].tolist())
    return dict(xs=xs, ys=ys)


def agreement_html(r: Result) -> str:
    """The theory x simulation counts (confusion) as a small table, or why there are none."""
    import html

    from .report import theory_section

    th = theory_section(r.ds) if r.kind != "shock" else None  # a shock search's theorems: its own panel
    if th is None:
        return "<p><b>Theory</b>: this system states no theorem here; nothing to compare.</p>"
    header, rows, sentences = th
    e = html.escape
    head = "".join(f"<th>{e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return (f"<b>Theory agreement</b><table class='confusion' style='border-collapse:collapse;font-size:12px'>"
            f"<tr>{head}</tr>{body}</table>" + "".join(f"<div style='font-size:12px'>{e(s)}</div>" for s in sentences))


def feature_columns(r: Result) -> dict[str, np.ndarray]:
    """Per-trajectory feature columns for the feature-space view: the declared outcome features
    (what templates are compared in) and every late-window statistic of every observable."""
    ds = r.ds
    cols: dict[str, np.ndarray] = {}
    stats = [k for k in ds.data_vars if k.startswith("feat_")]
    if not stats or r.kind == "refine":
        return cols
    n = r.codes().size
    obs = [str(o) for o in ds["observable"].values] if "observable" in ds.coords else []
    flat = {k: np.asarray(ds[k].values).reshape(n, -1) for k in stats}
    sch = r.plan.scheme
    if not sch.from_verdicts and sch.decl.features:
        from ..model import outcomes as O

        feat = O.feature_getter({k: v for k, v in flat.items()}, tuple(r.plan.system.observables))
        allp = r.plan.params_at(np.arange(n))

        def par(name):
            return np.asarray(allp[name], float).reshape(n)

        x = O.feature_matrix(sch.decl, r.plan.system, feat, par)
        for j, f in enumerate(sch.decl.features):
            cols[f] = x[:, j]
    for k in stats:
        for j, o in enumerate(obs[: flat[k].shape[1]]):
            cols[f"{k[5:]}({o})"] = flat[k][:, j]
    return cols


def fraction_columns(r: Result, outcome: int, at: dict[str, int] | None = None) -> dict[str, Any] | None:
    """Basin fraction of one outcome along the last swept axis with its Wilson band, at the index
    ``at`` of every other grid axis (default 0; the page follows the clicked cell), or None when the
    result has no per-point fractions (no samples) or no swept axis."""
    ds = r.ds
    if "basin_fraction" not in ds or r.kind == "refine":
        return None
    dims = [d for d in ds["basin_fraction"].dims if d != "outcome_name"]
    if not dims:
        return None
    xd = dims[-1]
    sub = ds[["basin_fraction", "basin_ci_low", "basin_ci_high"]].isel(outcome_name=outcome)
    other = {d: int((at or {}).get(d, 0)) for d in dims[:-1]}
    sub = sub.isel(other) if other else sub
    where = ", ".join(f"{d} = {float(ds[d].values[i]):.4g}" for d, i in other.items())
    return dict(x=np.asarray(ds[xd].values, float), s=sub["basin_fraction"].values,
                lo=sub["basin_ci_low"].values, hi=sub["basin_ci_high"].values, dim=xd, where=where)


def components(traj: xr.Dataset) -> dict[str, np.ndarray]:
    """Scalar time series of a simulated trajectory: state components first (x, y of a phase
    portrait), then the observables."""
    out: dict[str, np.ndarray] = {}
    for k, v in traj.data_vars.items():
        if "t" not in v.dims:
            continue
        if v.ndim == 1:
            out[k] = v.values
        else:
            flat = v.values.reshape(v.shape[0], -1)
            labels = [str(a) for a in v["axis"].values] if "axis" in v.dims else [str(i) for i in range(flat.shape[1])]
            for j in range(flat.shape[1]):
                out[f"{k}_{labels[j] if j < len(labels) else j}"] = flat[:, j]
    return out


def status_text(r: Result) -> str:
    ds = r.ds
    n = int(ds.attrs.get("n_trajectories", 0))
    txt = (f"{r.path.name}: {n:,} trajectories; t1 = {r.plan.icfg.t1:g}; engine {ds.attrs.get('engine', '?')}; "
           f"created {ds.attrs.get('created', '?')}")
    if r.note:
        txt = f"<b>{esc(r.note)}</b><br>" + txt
    if "pending" in ds and not r.running:
        txt = (f"<b>chunk store, every chunk finished</b> ({ds.attrs.get('store_chunks', '?')}); the netCDF file is "
               f"written when the sweep ends (or: stabjax export {r.path} --out FILE.nc)<br>" + txt)
    elif "pending" in ds:
        from ..run.lock import held
        from ..run.store import LOCK

        done = int((~np.asarray(ds["pending"].values)).sum())
        if r.store is not None and not held(r.store / LOCK):  # no sweep writes it: it was stopped, not running
            txt = (f"<b>interrupted sweep</b>: {done:,} of {int(ds['pending'].size):,} trajectories finished "
                   f"({ds.attrs.get('store_chunks', '?')} chunks; pending cells grey); no sweep is writing this "
                   f"store: the same stabjax sweep command resumes it, and this page follows<br>" + txt)
        else:
            txt = (f"<b>running sweep</b>: {done:,} of {int(ds['pending'].size):,} trajectories finished "
                   f"({ds.attrs.get('store_chunks', '?')} chunks; pending cells grey; refreshes as chunks land)<br>"
                   + txt)
    if r.kind == "discovery" and "outcome" not in ds:
        txt += "<br>attractor discovery: the outcomes are assigned when every trajectory has run"
    return txt


def esc(x) -> str:
    import html

    return html.escape(str(x))


def _reason(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
