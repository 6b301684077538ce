"""Theorem predicates of Aleksandrov & Tikhonov (2019), vectorised over parameter grids.

For the perturbation family Phi(t) = b cos(omega0 t^alpha) I (docs/models/monoaxial.md, "Theorems as implemented"):
Assumption 1 holds for every beta in (1 - alpha, 1] (for alpha > 1 the integral of
cos(t^alpha) stays bounded, so every beta > 0 works). Theorem 1's inequality (7),
2 sigma >= mu + 1 + beta (mu - 1), is then satisfiable iff it holds strictly at the
infimum beta -> max(1 - alpha, 0); the infimum itself is not admissible, hence ``>``.

All functions take NumPy arrays (any broadcastable shapes) and return arrays.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..model.system import Predicate, Theory


def beta_inf(alpha):
    """Infimum of admissible beta in Assumption 1 for the cos(omega0 t^alpha) family (exclusive)."""
    return np.maximum(1.0 - np.asarray(alpha, dtype=float), 0.0)


def theorem1_margin(mu, sigma, alpha):
    """2 sigma - (mu + 1 + beta_inf (mu - 1)): > 0 iff some admissible beta satisfies (7)."""
    mu, sigma = np.asarray(mu, float), np.asarray(sigma, float)
    return 2 * sigma - (mu + 1 + beta_inf(alpha) * (mu - 1))


def theorem1_beta_margin(mu, sigma, beta):
    """Margin of (7) for an explicitly given beta: 2 sigma - mu - 1 - beta (mu - 1)."""
    return 2 * np.asarray(sigma, float) - np.asarray(mu, float) - 1 - np.asarray(beta, float) * (np.asarray(mu, float) - 1)


def alpha_critical(mu, sigma):
    """Theorem 1 holds iff alpha > 2 (mu - sigma) / (mu - 1) (mu > 1). 2/3 for the paper's example."""
    mu, sigma = np.asarray(mu, float), np.asarray(sigma, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(mu > 1, 2 * (mu - sigma) / (mu - 1), np.nan)


def sigma_critical(mu, alpha):
    """Theorem 1 holds iff sigma > mu - (1 - beta_inf)(mu - 1)/2 = mu - alpha (mu - 1)/2 for alpha <= 1."""
    mu = np.asarray(mu, float)
    return (mu + 1 + beta_inf(alpha) * (mu - 1)) / 2


def evaluate(p: Mapping[str, np.ndarray]) -> Theory:
    """Every result of the paper (docs/models/monoaxial.md, "Theorems as implemented") for parameters ``p`` (batched NumPy arrays)."""
    mu = np.asarray(p["mu"], float)
    sigma = np.asarray(p["sigma"], float)
    alpha = np.asarray(p["alpha"], float)
    omega0 = np.asarray(p.get("omega0", 1.0), float)
    b = np.asarray(p.get("b", 1.0), float)
    mu, sigma, alpha, omega0, b = np.broadcast_arrays(mu, sigma, alpha, omega0, b)
    family_ok = (alpha > 0) & (omega0 != 0)  # zero mean (5) and Assumption 1 hold
    unperturbed = b == 0

    classical = Predicate(
        ok=(sigma > mu) & (mu >= 1) | unperturbed & (mu >= 1),
        margin=sigma - mu,
        doc="sigma > mu >= 1: stability by the nonlinear approximation, any bounded Phi (cited in the paper, sec. 1)",
    )
    m1 = theorem1_margin(mu, sigma, alpha)
    theorem1 = Predicate(
        ok=(mu > 1) & family_ok & (m1 > 0),
        margin=m1,
        doc="Theorem 1, (7): mu > 1, Assumption 1 with some beta in (1-alpha, 1], 2 sigma >= mu + 1 + beta (mu - 1)",
    )
    corollary1 = Predicate(
        ok=(mu > 1) & family_ok & (sigma >= mu),
        margin=sigma - mu,
        doc="Corollary 1: mu > 1, zero mean (5), sigma >= mu",
    )
    guaranteed = Predicate(
        ok=classical.ok | theorem1.ok | corollary1.ok,
        margin=np.where(mu > 1, m1, sigma - mu),
        doc="some result of the paper guarantees asymptotic stability of (0, r)",
    )
    lo = beta_inf(alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        hi7 = np.where(mu > 1, (2 * sigma - mu - 1) / (mu - 1), np.inf)
    hi = np.minimum(1.0, hi7)
    derived = {
        "beta_lo": lo,
        "beta_hi": np.where(hi > lo, hi, np.nan),
        "alpha_crit": alpha_critical(mu, sigma),
        "sigma_crit": sigma_critical(mu, alpha),
    }
    derived_doc = {
        "beta_lo": "admissible beta for Assumption 1 are > beta_lo = max(1 - alpha, 0)",
        "beta_hi": "largest beta satisfying (7) (capped at 1); NaN when the interval (beta_lo, beta_hi] is empty",
        "alpha_crit": "Theorem 1 holds iff alpha > alpha_crit = 2 (mu - sigma)/(mu - 1)",
        "sigma_crit": "Theorem 1 holds iff sigma > sigma_crit = (mu + 1 + beta_lo (mu - 1))/2",
    }
    return Theory(
        predicates={"classical": classical, "theorem1": theorem1, "corollary1": corollary1, "guaranteed": guaranteed},
        derived=derived,
        derived_doc=derived_doc,
        main="guaranteed",
    )
