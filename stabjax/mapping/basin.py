"""Basin stability: per grid point and outcome, the fraction S of the N sampled trajectories, its
standard error and the 95 % Wilson score interval (Menck, Heitzig, Marwan and Kurths, Nature Physics 9,
89 (2013); Wilson, J. Am. Stat. Assoc. 22, 209 (1927)).

The statistics are reductions over the sample axis, so their memory does not grow with N; the run's
derive step (:mod:`stabjax.run.derive`) computes them from the outcome codes, the dataset
(:mod:`stabjax.run.dataset`) lays them out as ``basin_count``, ``basin_fraction``, ``basin_se``,
``basin_ci_low`` and ``basin_ci_high`` over (grid axes..., ``outcome_name``).
"""
from __future__ import annotations

import numpy as np

Z95 = 1.959963984540054  # two-sided 95 % normal quantile
STATS = ("count", "fraction", "se", "ci_low", "ci_high")


def basin_stats(codes: np.ndarray, n_outcomes: int, z: float = Z95) -> dict[str, np.ndarray]:
    """Per outcome over the last axis (the samples): count, fraction S, SE sqrt(S(1-S)/N), Wilson interval.

    Returns arrays of shape (*codes.shape[:-1], n_outcomes). The Wilson score interval keeps its
    coverage near S = 0 or 1, where S +- z SE collapses to a point.
    """
    codes = np.asarray(codes)
    n = codes.shape[-1]
    counts = np.stack([(codes == k).sum(axis=-1) for k in range(n_outcomes)], axis=-1).astype(np.int64)
    s = counts / n
    se = np.sqrt(s * (1 - s) / n)
    z2n = z * z / n
    centre = (s + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * np.sqrt(s * (1 - s) / n + z2n / (4 * n))
    # the interval contains S exactly; min/max only absorb rounding at S = 0 or 1
    return dict(count=counts, fraction=s, se=se, ci_low=np.minimum(np.clip(centre - half, 0, 1), s),
                ci_high=np.maximum(np.clip(centre + half, 0, 1), s))


def summary_rows(ds) -> list[tuple[str, int, float, float, float, float]]:
    """(outcome, count, S, SE, CI low, CI high) over the whole dataset (every grid point pooled)."""
    names = [str(x) for x in ds["outcome"].attrs["flag_meanings"].split()]
    codes = np.asarray(ds["outcome"].values).ravel()
    st = basin_stats(codes[None, :], len(names))
    return [(name, int(st["count"][0, k]), float(st["fraction"][0, k]), float(st["se"][0, k]),
             float(st["ci_low"][0, k]), float(st["ci_high"][0, k])) for k, name in enumerate(names)]


def theory_agreement(ds) -> dict | None:
    """The main theorem against the named outcomes, trajectory by trajectory, or None without a main theorem.

    Returns ``predicate``, ``doc``, ``columns`` (the outcomes that occur), ``rows`` (``"theory: guaranteed"`` and
    ``"theory: silent"`` -> a count per column) and ``guarantees`` (the outcome the predicate declares it
    guarantees, ``""`` when it declares none), ``absent`` (it names one this result does not have: a spec's
    ``[outcomes]`` replaced the model's, or discovery named the attractors; nothing is counted then). With one declared: ``red_flags`` (guaranteed, ending in another
    outcome: the simulation refutes the theorem there), ``red_flags_by_outcome``, ``undecided`` (guaranteed,
    ending unclassified or failed: neither refuted nor confirmed), ``conservative`` (silent, ending in the
    guaranteed outcome) and ``red_flag_mask``, the boolean red flags laid out as ``ds["outcome"]``.
    """
    import xarray as xr

    main = ds.attrs.get("theory_main")
    if not main or "outcome" not in ds or f"theory_{main}" not in ds:
        return None
    th_da, oc_da = xr.broadcast(ds[f"theory_{main}"], ds["outcome"])
    th_da = th_da.transpose(*oc_da.dims)
    ok = np.asarray(th_da.values).astype(bool)
    oc = np.asarray(oc_da.values)
    names = str(ds["outcome"].attrs.get("flag_meanings", "")).split()
    codes = [int(c) for c in np.asarray(ds["outcome"].attrs.get("flag_values", np.arange(len(names))))]
    cols = [(n, c) for n, c in zip(names, codes) if (oc == c).any()]
    attrs = ds[f"theory_{main}"].attrs
    out = {"predicate": main, "doc": str(attrs.get("long_name", "")), "columns": [n for n, _ in cols],
           "rows": {label: [int((want(ok) & (oc == c)).sum()) for _, c in cols]
                    for label, want in (("theory: guaranteed", lambda m: m), ("theory: silent", lambda m: ~m))},
           "guarantees": str(attrs.get("guarantees", ""))}
    out["absent"] = bool(out["guarantees"]) and out["guarantees"] not in names
    if out["guarantees"] and not out["absent"]:
        from ..model.outcomes import FAILED_NAME, UNCLASSIFIED

        good = codes[names.index(out["guarantees"])]
        # an unclassified or failed trajectory refutes nothing (the simulation did not decide): counted apart
        open_ = np.isin(oc, [c for n, c in zip(names, codes) if n in (UNCLASSIFIED, FAILED_NAME)])
        bad = ok & (oc != good) & ~open_
        out["undecided"] = int((ok & open_).sum())
        out["red_flag_mask"] = bad
        out["red_flags"] = int(bad.sum())
        out["red_flags_by_outcome"] = {n: int((bad & (oc == c)).sum()) for n, c in cols if c != good
                                       and (bad & (oc == c)).any()}
        out["conservative"] = int((~ok & (oc == good)).sum())
    return out
