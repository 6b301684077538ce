"""Saakyan theorem predicates at hand-checked points (docs/models/saakyan.md, Sections 1-4)."""
from __future__ import annotations

import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax.model.registry import get_system
from stabjax.systems import saakyan_theory as T

I432 = np.array([4.0, 3.0, 2.0])
HG = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
EX, EY, EZ = np.eye(3)


def test_c110_hand_points():
    # m1 = 4: K > 4 lam
    p = T.c110(I432, 1.0, np.array([5.0, 4.0, 3.9]))
    assert p.ok.tolist() == [True, False, False]
    assert p.margin[0] == pytest.approx(0.25)
    assert T.c110(I432, 0.5, 2.01).ok and not T.c110(I432, 0.5, 1.99).ok


def test_c121_hand_points():
    # (K - lam m1)/(lam (m1 - m2)) > 2  <=>  K > lam (3*4 - 2*2) = 8 lam
    assert T.c121(I432, EX, 1.0, 8.5).ok
    assert not T.c121(I432, EX, 1.0, 7.9).ok
    assert not T.c121(I432, HG, 1.0, 100.0).ok  # H0 not principal
    assert T.c121(I432, -EZ, 0.5, 4.01).ok  # either sense of the axis
    assert T.c121(I432, EX, 1.0, 8.5).margin == pytest.approx(8.5 / 8 - 1)


def test_middle_axis_condition():
    # I = (4, 3, 2): middle axis y; bound lam max(2*3 - 2, 3*4 - 2*3) = 6 lam
    assert T.middle_axis_bound(I432, 1.0) == pytest.approx(6.0)
    assert T.middle_axis(I432, EY, 1.0, 6.5).ok
    assert not T.middle_axis(I432, EY, 1.0, 5.5).ok
    assert not T.middle_axis(I432, EX, 1.0, 6.5).ok  # not the middle axis
    # relabelled body (5, 6, 4): middle = x (5): max(2*5 - 4, 3*6 - 2*5) = 8
    assert T.middle_axis_bound(np.array([5.0, 6.0, 4.0]), 1.0) == pytest.approx(8.0)
    assert T.middle_axis(np.array([5.0, 6.0, 4.0]), EX, 1.0, 8.1).ok


def test_exact_principal_axis_bounds_and_circles():
    # max-moment axis x (4): circles for j with I_j < 4: y -> 2*4-3 = 5, z -> 2*4-2 = 6
    assert T.exact_axis_bound(I432, EX, 1.0) == pytest.approx(6.0)
    # middle axis y (3): j = z (2): 2*3 - 2 = 4, but (1.10) needs 4 too
    assert T.exact_axis_bound(I432, EY, 1.0) == pytest.approx(4.0)
    # min axis z: no circle; only (1.10)
    assert T.exact_axis_bound(I432, EZ, 1.0) == pytest.approx(4.0)
    assert np.isnan(T.exact_axis_bound(I432, HG, 1.0))
    # docs/models/saakyan.md example (spurious spin): K = 5, lam = 1, H0 = e_x: circle j = z with delta_x = (5-2)/(2-4) = -1.5,
    # |delta| = sqrt(3); j = y gives delta_x = -2 (the inverted spin itself, not a circle)
    c = T.principal_circles(I432, EX, 1.0, 5.0)
    assert np.isnan(c[0]) and np.isnan(c[1]) and c[2] == pytest.approx(np.sqrt(3))
    assert not T.no_spurious_exact(I432, EX, 1.0, 5.0).ok
    assert T.no_spurious_exact(I432, EX, 1.0, 6.2).ok


def test_steady_spin_finder_reproduces_the_counter_example():
    l, d = T.l_spurious(I432, EX, 1.0, 5.0)
    assert l == pytest.approx(np.sqrt(3), abs=1e-8)
    S = EX + d
    assert S[0] == pytest.approx(-0.5, abs=1e-8) and np.hypot(S[1], S[2]) == pytest.approx(np.sqrt(3) / 2, abs=1e-8)
    # under (1.21) only the inverted spin is left: l = 2
    l2, d2 = T.l_spurious(I432, EX, 1.0, 8.5)
    assert l2 == pytest.approx(2.0, abs=1e-8) and np.allclose(d2, -2 * EX, atol=1e-8)


def test_finder_solutions_are_zeros_of_114_in_component_form():
    """Every spin found satisfies the three printed equations (1.14) and the constraint (1.15)."""
    lam, K = 0.5, 2.5  # (1.10) holds (K > 2), (1.21) does not
    S, ok = T.steady_spins(I432, HG, lam, K)
    A, B, C = I432
    b1, b2, b3 = HG
    assert ok.sum() >= 2
    for Sk in S[ok]:
        d1, d2, d3 = Sk - HG
        e = [
            lam * (B - C) * d2 * d3 + (K - lam * C) * b2 * d3 - (K - lam * B) * b3 * d2,
            lam * (C - A) * d3 * d1 + (K - lam * A) * b3 * d1 - (K - lam * C) * b1 * d3,
            lam * (A - B) * d1 * d2 + (K - lam * B) * b1 * d2 - (K - lam * A) * b2 * d1,
        ]
        assert np.abs(e).max() < 1e-8
        assert d1**2 + d2**2 + d3**2 + 2 * (b1 * d1 + b2 * d2 + b3 * d3) == pytest.approx(0, abs=1e-12)


@pytest.mark.parametrize("K", [2.5, 4.0, 7.2, 20.0])
def test_l_of_116_agrees_with_the_robust_algorithm(K):
    l_robust, _ = T.l_spurious(I432, HG, 0.5, K)
    l_paper = T.l_116(I432, HG, 0.5, K)
    assert l_paper == pytest.approx(float(l_robust), abs=1e-7)
    assert 0 < l_robust < 2


def test_l_of_116_depends_on_the_direction_of_H_and_is_degenerate_on_axes():
    l1 = T.l_116(I432, HG, 0.5, 4.0)
    H2 = np.array([0.6, 0.2, 0.5]) / np.linalg.norm([0.6, 0.2, 0.5])
    l2 = T.l_116(I432, H2, 0.5, 4.0)
    assert abs(l1 - l2) > 1e-3
    assert np.isnan(T.l_116(I432, EX, 0.5, 4.0))  # beta_3 = 0: (1.16) degenerate
    assert np.isfinite(T.l_spurious(I432, EX, 0.5, 4.0)[0])  # the robust algorithm is not


def test_f116_vanishes_at_the_root():
    l3 = T.l_spurious(I432, HG, 0.5, 4.0)[1][2]
    assert abs(T.f116(l3, I432, HG, 0.5, 4.0)) < 1e-8


def test_instability_bracket():
    A, B, C = I432
    b = HG
    want = b[0] ** 2 * b[1] ** 2 * (A - B) ** 2 + b[0] ** 2 * b[2] ** 2 * (A - C) ** 2 + b[1] ** 2 * b[2] ** 2 * (C - B) ** 2
    assert T.bracket_phi0(I432, HG) == pytest.approx(want)
    assert T.bracket_phi0(I432, EY) == 0
    assert T.bracket_phi0(np.array([3.0, 3.0, 3.0]), HG) == 0


def test_lam2_nu_and_c27():
    assert T.lam2_nu(np.sqrt(0.3), 0.3).ok
    assert not T.lam2_nu(0.5, 0.3).ok
    # (2.7) generalised: alpha > max (lam^2 - nu) I_i and alpha > 0
    # lam = 1, nu = 0.5: (lam^2 - nu) m1 = 2 -> K > 2
    assert T.c27(I432, 1.0, 0.5, 2.1).ok and not T.c27(I432, 1.0, 0.5, 1.9).ok
    # lam^2 < nu: any K > 0 works
    assert T.c27(I432, 0.5, 1.0, 0.01).ok


def test_c_h_and_c44_values_of_models_md():
    assert T.c_h(I432, 0.5, 2.01).ok and not T.c_h(I432, 0.5, 1.99).ok
    J = np.array([0.3, 0.2, 0.4])
    # docs/models/saakyan.md: printed bound 0.04, exact -0.42
    assert T.bound_44(I432, J, 0.5, 0.3, exact=False) == pytest.approx(0.04)
    assert T.bound_44(I432, J, 0.5, 0.3, exact=True) == pytest.approx(-0.42)
    assert not T.c44(I432, J, 0.5, 0.3, 0.03, exact=False).ok
    assert T.c44(I432, J, 0.5, 0.3, 0.03, exact=True).ok
    # h > 0 is required in both versions
    assert not T.c44(I432, J, 0.5, 0.3, -0.1, exact=True).ok


def test_region_predicates_and_radii():
    w1 = np.array([[0.1, 0, 0], [0.0, 0.0, 0.0], [2.5, 0, 0]])
    d = np.array([[0.0, 0.5, 0], [0.0, 1.99, 0.0], [0.1, 0, 0]])
    r = T.region(w1, d, 1.0, 2.0)
    assert r.ok.tolist() == [True, True, False]  # |w1| = 2.5 > lam l = 2
    assert r.margin[1] == pytest.approx(1 - 1.99 / 2)


def test_system_theory_end_to_end_batched():
    """Theory of each system on a small batch: shapes, main predicate, hand-checked values."""
    s = get_system("saakyan_fixed")
    p = s.check(s.params.resolve(dict(I=(4.0, 3.0, 2.0), H=(1.0, 0, 0), lam=1.0)))
    batch = {k: np.broadcast_to(v, (3, *np.shape(v))).copy() for k, v in p.items()}
    batch["K"] = np.array([5.0, 8.5, 3.0])
    batch["init"] = np.ones(3)
    batch["rho"] = np.array([1.0, 1.9, 0.1])
    th = s.theory(batch)
    assert th.main == "guaranteed"
    assert th.predicates["c110"].ok.tolist() == [True, True, False]
    assert th.predicates["c121"].ok.tolist() == [False, True, False]
    np.testing.assert_allclose(th.derived["l_spurious"][:2], [np.sqrt(3), 2.0], atol=1e-8)
    # K = 5: Theorem 1 region has l = sqrt(3), rho = 1 inside; K = 8.5: Corollary 1, rho = 1.9 < 2 inside
    assert th.predicates["guaranteed"].ok.tolist() == [True, True, False]
    assert th.predicates["region122"].ok[0]  # the counter-example spin region (1.22) nominally covers

    g = get_system("saakyan_gravity")
    pg = g.check(g.params.resolve(dict(lam=0.5, nu=0.25)))
    assert g.theory(pg).predicates["theorem2"].ok
    assert not g.theory(g.check(g.params.resolve(dict(lam=0.5, nu=0.3)))).predicates["theorem2"].ok

    gy = get_system("saakyan_gyrostat")
    th3 = gy.theory(gy.check(gy.params.resolve(dict(I=(4.0, 3.0, 2.0), lam=0.5, h=6.0))))
    assert th3.predicates["theorem3"].ok and th3.derived["h_over_lam_m1"] == pytest.approx(3.0)
    assert not gy.theory(gy.check(gy.params.resolve(dict(I=(4.0, 3.0, 2.0), lam=0.5, h=6.0, torque=1.0)))
                         ).predicates["theorem3"].ok

    gg = get_system("saakyan_gyrostat_gravity")
    th4 = gg.theory(gg.check(gg.params.resolve(dict(I=(4.0, 3.0, 2.0), Jw=(0.3, 0.2, 0.4), lam=0.5, nu=0.3, h=0.03))))
    assert not th4.predicates["c44_printed"].ok and th4.predicates["c44_exact"].ok
    assert th4.derived["h44_printed"] == pytest.approx(0.04)


def test_sublevel_bound_equals_the_lowest_spin_of_the_papers_equation():
    """c* (the minimum of V over the off-target steady spins that Newton finds from 48 starts on the sphere)
    equals the minimum of V = 1/2 sum_i (lam K - lam^2 I_i) delta_i^2, written out here, over the steady spins
    of the paper's route: every root of (1.16) on [-1 - b3, 1 - b3] (sign changes on a fine grid, Brent's
    method), its delta from (1.14), kept where S = H + delta lies on the sphere and zeroes the tangent field
    lam K H x delta - lam^2 S x (I delta) (poles of f also change sign). Fails if Newton misses the lowest spin, or c* is V at another spin."""
    from scipy.optimize import brentq

    lam, K = 0.5, 4.0
    b3 = HG[2]
    x = np.linspace(-1 - b3, 1 - b3, 20001)
    f = T.f116(x, I432, HG, lam, K)
    cross = np.nonzero(np.isfinite(f[:-1]) & np.isfinite(f[1:]) & (np.sign(f[:-1]) * np.sign(f[1:]) < 0))[0]
    levels = []
    for i in cross:
        r = brentq(lambda d3: T.f116(d3, I432, HG, lam, K), x[i], x[i + 1], xtol=1e-15, rtol=1e-15)
        d = T.delta_from_116(r, I432, HG, lam, K)
        S = HG + d
        F = lam * K * np.cross(HG, d) - lam**2 * np.cross(S, I432 * d)  # the steady-spin equation (nu = 0)
        if abs(np.linalg.norm(S) - 1) < 1e-9 and np.linalg.norm(F) < 1e-9 and np.linalg.norm(d) > 1e-6:
            levels.append(0.5 * np.sum((lam * K - lam**2 * I432) * d**2))
    assert len(levels) >= 1
    cs = T.c_star(I432, HG, lam, K)
    assert cs > 0
    np.testing.assert_allclose(cs, min(levels), rtol=1e-8)
