"""The horizon check (``stabjax horizon-check``): re-run a random subset of a finished sweep beyond its t1, or
at a tighter tolerance, or both, and count the verdicts that change. Not a sweep: a sample of single
trajectories of the sweep's plan, solved in one batch on the plan's engine.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import xarray as xr

from ..fold import verdict as V
from ..engines.simulate import solve_batch
from ..errors import ValidationError
from ..plan.spec import make_plan


def horizon_check(ds: xr.Dataset, *, factor: float = 4.0, n: int = 64, seed: int = 0, tighten: float = 1.0,
                  batch_size: int | None = None) -> xr.Dataset:
    """Re-run a random subset of a finished sweep with ``t1 * factor`` and ``rtol``, ``atol`` divided by
    ``tighten``; return old/new verdicts.

    ``tighten`` checks the tolerance rather than the horizon (``factor = 1``): a verdict that changes with a
    tighter tolerance was decided by the solver's error, not by the dynamics (the main job at rtol 1e-8 had 11
    such cells, late flips grown from the error that each destabilising window amplifies).

    A thin use of the multi-horizon classifier: the sweep's own dataset already holds verdicts at
    t1 and the decades below it (dim ``horizon``); this extends the run *beyond* t1 for a subset,
    with the old horizons kept (``verdict_horizons``: the re-run's verdicts at every horizon up to
    t1 * factor). The result has dim ``traj`` with the flat indices, ``verdict_short`` (the
    dataset's, at t1) / ``verdict_long`` (at t1 * factor), and attrs ``n_changed`` and a
    confusion table. ``ds``: a sweep's result with attitude verdicts (a dataset, or the path of its file); any
    other result is refused naming ``ds``.
    """
    if isinstance(ds, (str, Path)):
        from ..present.kit import open_result

        ds = open_result(ds, field="ds", partial=False)
    if not hasattr(ds, "data_vars") or "verdict" not in ds or "spec_json" not in ds.attrs:
        what = ("named outcomes or discovered attractors" if hasattr(ds, "data_vars") and "outcome" in ds
                else f"a {type(ds).__name__}" if not hasattr(ds, "data_vars") else "no sweep's verdicts")
        raise ValidationError("ds", f"horizon_check compares a sweep's attitude verdicts; this holds {what} "
                                    "(run the sweep again with a longer t1 to compare outcomes)")
    spec = json.loads(ds.attrs["spec_json"])
    plan = make_plan(spec)
    icfg = plan.icfg
    if not factor >= 1:
        raise ValidationError("factor", f"must be >= 1, got {factor}")
    if not tighten >= 1:
        raise ValidationError("tighten", f"must be >= 1, got {tighten}")
    if factor == 1 and tighten == 1:
        raise ValidationError("factor", "a longer horizon (factor > 1), a tighter tolerance (tighten > 1) or both: "
                                        "with neither the re-run is the sweep's own")
    rng = np.random.default_rng(seed)
    n = min(n, plan.size)
    idx = np.sort(rng.choice(plan.size, size=n, replace=False))
    long_cfg = icfg.replace(t1=icfg.t1 * factor, rtol=icfg.rtol / tighten, atol=icfg.atol / tighten)
    hs = V.horizon_times(plan.vcfg, icfg.t0, icfg.t1)
    long_v = V.bind(plan.vcfg, long_cfg.t0, long_cfg.t1, horizons=list(hs[-(V.MAX_HORIZONS - 1):]))
    plan_long = dataclasses.replace(plan, icfg=long_cfg, vcfg=long_v, engine="")
    p = plan_long.system.check(plan_long.params_at(idx))
    res = solve_batch(plan.system, p, long_cfg, long_v)
    old = np.asarray(V.at_t1(ds["verdict"]).values).ravel()[idx]
    new_all = np.asarray(res["verdict"])
    new = new_all[:, -1] if new_all.ndim == 2 else new_all
    table = np.zeros((len(V.NAMES), len(V.NAMES)), dtype=int)
    np.add.at(table, (old.astype(int), new.astype(int)), 1)
    out = xr.Dataset(
        {"verdict_short": ("traj", old), "verdict_long": ("traj", new),
         "transition": (("short", "long"), table),
         **({"verdict_horizons": (("traj", "horizon"), new_all)} if new_all.ndim == 2 else {})},
        coords={"traj": idx, "short": list(V.NAMES), "long": list(V.NAMES),
                **({"horizon": ("horizon", np.asarray(long_v.horizons))} if new_all.ndim == 2 else {})},
    )
    out.attrs.update(t1_short=icfg.t1, t1_long=long_cfg.t1, rtol_short=icfg.rtol, rtol_long=long_cfg.rtol,
                     atol_short=icfg.atol, atol_long=long_cfg.atol, n_changed=int((old != new).sum()),
                     n_checked=int(n))
    return out
