"""Theorem predicates of paper A at hand-checked points and against a brute-force beta search."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from stabjax.model.registry import get_system
from stabjax.systems import monoaxial_theory as T

SYS = get_system("monoaxial")


def th(**kw):
    p = SYS.params.resolve(kw)
    return SYS.theory(p)


def test_paper_examples():
    # alpha = 1/3 violates (7); alpha = 7/9 satisfies it (docs/models/monoaxial.md)
    assert not th(alpha=1 / 3).predicates["theorem1"].ok
    assert th(alpha=7 / 9).predicates["theorem1"].ok
    assert np.isclose(th(alpha=1 / 3).predicates["theorem1"].margin, 8 / 3 - (2.5 + (2 / 3) * 0.5))
    assert np.isclose(th().derived["alpha_crit"], 2 / 3)
    # admissible beta in (2/9, 1/3] for alpha = 7/9
    d = th(alpha=7 / 9).derived
    assert np.isclose(d["beta_lo"], 2 / 9) and np.isclose(d["beta_hi"], 1 / 3)
    assert np.isnan(th(alpha=1 / 3).derived["beta_hi"])


def test_sigma_above_mu_always_stable():
    for alpha in (0.1, 0.5, 1.0):
        t = th(alpha=alpha, mu=1.5, sigma=1.6)
        assert t.predicates["classical"].ok and t.predicates["guaranteed"].ok


def test_corollary1_and_mu_one():
    t = th(mu=2.0, sigma=2.0, alpha=0.2)
    assert t.predicates["corollary1"].ok and t.predicates["theorem1"].ok
    t = th(mu=1.0, sigma=1.0)
    assert not t.predicates["theorem1"].ok and not t.predicates["corollary1"].ok and not t.predicates["guaranteed"].ok


def test_periodic_case():
    # alpha = 1: condition becomes sigma > (mu + 1)/2
    assert np.isclose(T.sigma_critical(2.0, 1.0), 1.5)


def test_vectorised_over_grid():
    a, s = np.meshgrid(np.linspace(0.3, 1, 8), np.linspace(1.2, 1.6, 5))
    p = SYS.params.resolve({})
    p = {k: v for k, v in p.items()}
    p["alpha"], p["sigma"] = a, s
    t = SYS.theory(p)
    assert t.predicates["theorem1"].ok.shape == a.shape
    np.testing.assert_array_equal(t.predicates["theorem1"].ok, s > 1.5 - a / 4)


@settings(max_examples=200, deadline=None)
@given(mu=st.floats(1.01, 4), sigma=st.floats(1, 5), alpha=st.floats(0.05, 1))
def test_theorem1_equals_bruteforce_beta_search(mu, sigma, alpha):
    """(7) holds for some admissible beta in (1 - alpha, 1]  <=>  the closed-form predicate."""
    betas = np.linspace(1 - alpha, 1, 20001)[1:]
    exists = bool(np.any(2 * sigma >= mu + 1 + betas * (mu - 1)))
    margin = float(T.theorem1_margin(mu, sigma, alpha))
    if abs(margin) > 1e-3:  # away from the boundary, where the grid resolves the infimum
        assert exists == (margin > 0)
