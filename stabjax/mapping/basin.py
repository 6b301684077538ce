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
