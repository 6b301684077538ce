"""Bezglasnyi-Mysina: theory predicates at hand-checked points, Lyapunov identities, invariants,
equilibria and the spec's findings (docs/models/twobody.md)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax import ValidationError, get_system
from stabjax.engines.simulate import batch_params
from stabjax.systems import twobody_theory as tt

NAMES = ["twobody_uniaxial", "twobody_triaxial", "twobody_uniaxial_rotating", "twobody_triaxial_rotating"]
I2_SPEC = np.array([[2, 0.3, 0.2], [0.3, 1.5, -0.1], [0.2, -0.1, 1.0]])


def theory(name, **over):
    s = get_system(name)
    p = batch_params(s, over, n=1)
    return s.theory(p)


def rand_rot(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ---- theory: hand-checked points --------------------------------------------------------------------

def test_physical_koenig_bstar_spec_value_and_explicit_formula():
    # docs/models/twobody.md: lambda_min(J') = -2.3458 for the spec's I2 and delta' = 3, constant in time
    th = theory("twobody_uniaxial")
    assert abs(th.derived["b_star_physical"][0] - 2.3458) < 1e-4
    # explicit form b* = -delta' lambda_min(M0) (delta' > 0) / -delta' lambda_max(M0) (delta' < 0), M0 by hand
    Ixx, Iyy, Ixy, Ixz, Iyz = 2.0, 1.5, 0.3, 0.2, -0.1
    M0 = np.array([[-2 * Ixy, Ixx - Iyy, -Iyz], [Ixx - Iyy, 2 * Ixy, Ixz], [-Iyz, Ixz, 0.0]])
    ev = np.linalg.eigvalsh(M0)
    for Om in (3.0, -2.0, 0.7):
        th = theory("twobody_uniaxial", Omega_r=Om)
        want = -Om * ev[0] if Om > 0 else -Om * ev[-1]
        assert abs(th.derived["b_star_physical"][0] - want) < 1e-9
        assert abs(tt.b_star_explicit(I2_SPEC, Om) - want) < 1e-12
        # margin of B = b I is b - b*
        assert abs(th.predicates["physical"].margin[0] - (3.0 - want)) < 1e-9


def test_rotating_bstar_spec_value():
    # docs/models/twobody.md: min_{t <= 200} lambda_min(J' + sym([w0]x J)) = -3.1005 for w0 = (0.3 sin .5t, .2, .4 cos .3t)
    th = theory("twobody_uniaxial_rotating")
    assert abs(th.derived["b_star_physical"][0] - 3.1005) < 2e-3
    assert th.predicates["guaranteed"].ok[0]  # default b = 4.1
    assert not theory("twobody_uniaxial_rotating", b=3.0).predicates["guaranteed"].ok[0]


def test_diagonal_unbalanced_rotor_by_hand():
    # I2 = diag(a, b, c): M0 = (a - b) [[0,1,0],[1,0,0],[0,0,0]] -> physical b* = |Omega| (a - b)
    a, bb, Om = 2.0, 1.0, 1.0
    th = theory("twobody_uniaxial", I2="2,1,1", Omega_r=Om, b=0.0)
    assert abs(th.derived["b_star_physical"][0] - Om * (a - bb)) < 1e-9
    # paper variant, by hand: sym([w02]x I2 D^T) + J'/2 has the 2x2 block
    # Om [[b s - (a-b) sin2d/2, ((a-b)/2)(c + cos2d)], [.., a s + (a-b) sin2d/2]] and a zero z row
    d = np.linspace(0, 2 * np.pi, 200001)
    s, c = np.sin(d), np.cos(d)
    p11 = Om * (bb * s - (a - bb) * np.sin(2 * d) / 2)
    p22 = Om * (a * s + (a - bb) * np.sin(2 * d) / 2)
    p12 = Om * (a - bb) / 2 * (c + np.cos(2 * d))
    lam = 0.5 * (p11 + p22) - np.sqrt(0.25 * (p11 - p22) ** 2 + p12 ** 2)
    want = -min(lam.min(), 0.0)
    assert abs(th.derived["b_star_paper"][0] - want) < 1e-4 * max(want, 1)
    assert want > 2.0  # the printed gyroscopic term asks for more than twice the physical damping here


def test_axisymmetric_rotor_rotating_frame_by_hand():
    # I2 = diag(1, 1, 2) (balanced): J' = 0. Constant w0 = (0, 0, w):
    #   physical: sym([w0]x J) = w [[0,1,0],[1,0,0],0] (J = diag(11, 9, 8)) -> b* = |w|
    #   paper:    sym([w0]x I1) + sym([w0+w02]x I2 D^T) = [[u s, w],[w, u s]], u = w + Om -> b* = |u| + |w|
    #   printed (21): the c11 misprint drops the u s in c11 and the I1 term is missing -> b* = |u|
    w, Om = 0.4, 1.0
    th = theory("twobody_uniaxial_rotating", I2="1,1,2", om0_c=f"0,0,{w}", om0_a="0,0,0", Omega_r=Om, b=0.0,
                T_theory=2 * np.pi)
    u = w + Om
    assert abs(th.derived["b_star_physical"][0] - abs(w)) < 1e-9
    assert abs(th.derived["b_star_paper"][0] - (abs(u) + abs(w))) < 1e-5
    assert abs(th.derived["b_star_printed"][0] - abs(u)) < 1e-5
    # König frame: a balanced rotor needs no damping at all in the physical model
    th0 = theory("twobody_uniaxial", I2="1,1,2", Omega_r=5.0, b=0.0)
    assert abs(th0.derived["b_star_physical"][0]) < 1e-12


def test_printed_c9_matches_uncorrected_form_except_c11_misprint():
    rng = np.random.default_rng(3)
    for _ in range(5):
        A = rng.normal(size=(3, 3))
        I2 = A @ A.T + 3 * np.eye(3)
        d = rng.uniform(0, 2 * np.pi)
        w = rng.normal(size=3)
        D = tt.rotz(d)
        direct = tt.sym(tt.hat(w) @ I2 @ D.T)
        pr = tt.c_printed(w, w[2], d, I2)
        diff = pr - direct
        s, c = np.sin(d), np.cos(d)
        mis = w[2] * ((I2[0, 1] * s + I2[1, 2] * c) - (I2[1, 1] * s - I2[0, 1] * c))
        assert abs(diff[0, 0] - mis) < 1e-12
        diff[0, 0] = 0.0
        assert np.abs(diff).max() < 1e-12


def test_theory_is_vectorised_and_consistent_with_b():
    s = get_system("twobody_uniaxial")
    n = 7
    p = batch_params(s, {}, n=n)
    p["b"] = np.linspace(0.0, 6.0, n)
    p["Omega_r"] = np.linspace(-3, 3, n)
    th = s.theory(p)
    m = th.predicates["physical"].margin
    assert m.shape == (n,)
    np.testing.assert_allclose(m, p["b"] - th.derived["b_star_physical"], atol=1e-9)
    np.testing.assert_array_equal(th.predicates["physical"].ok, p["b"] > th.derived["b_star_physical"])
    # variant selects the main predicate
    p["variant"] = np.array([0, 1, 0, 1, 0, 1, 0], float)
    th = s.theory(p)
    want = np.where(p["variant"] == 1, th.predicates["paper"].margin, th.predicates["physical"].margin)
    np.testing.assert_array_equal(th.predicates["guaranteed"].margin, want)


def test_equilibria_claims():
    eq = tt.equilibria_uniaxial([0, 0, 1.0])
    assert [e[2] for e in eq] == ["asymptotically stable", "unstable"]
    eqs = tt.equilibria_triaxial(np.eye(3))
    assert len(eqs) == 4 and [e[2] for e in eqs].count("unstable") == 3
    for _, S, _ in eqs:
        assert abs(np.linalg.det(S) - 1) < 1e-12
    assert theory("twobody_triaxial").derived["alphas_distinct"][0]
    assert not theory("twobody_triaxial", alphas="1,1,2").derived["alphas_distinct"][0]


# ---- traced: Lyapunov identity by automatic differentiation -------------------------------------------

def _vdot(s, a):
    def f(t, y):
        return jax.jvp(lambda tt_, yy: s.lyapunov(tt_, yy, a), (t, y), (jnp.ones_like(t), s.rhs(t, y, a)))[1]
    return jax.jit(f)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("variant", [0.0, 1.0])
def test_vdot_equals_minus_quadratic_form(name, variant):
    """dV/dt (autodiff of the paper's V along the closed loop) = -x^T (B + C + J'/2) x.

    The paper drops 'higher-order terms'; there are none [D], so the identity is checked at
    small x (the quadratic part) and at O(1) x. The C of the *other* variant does not fit.
    """
    s = get_system(name)
    over = dict(variant=variant, dA=0.7, dnu=1.1)
    p = s.check(s.params.resolve(over))
    a = s.prepare({k: jnp.asarray(v) for k, v in p.items()})
    vdot = _vdot(s, a)
    P = jax.jit(lambda t, k: s.cond_matrix(t, a, k), static_argnums=1)
    rng = np.random.default_rng(int(variant) + len(name))
    kind, other = ("physical", "paper") if variant == 0 else ("paper", "physical")
    for scale in (1e-4, 1e-2, 1.0):
        for _ in range(3):
            t = jnp.asarray(rng.uniform(0, 20))
            x = scale * rng.normal(size=3)
            att = rand_rot(rng).ravel() if s.triaxial else rng.normal(size=3)
            if not s.triaxial:
                att = att / np.linalg.norm(att)
            y = jnp.asarray(np.concatenate([x, att]))
            lhs = float(vdot(t, y))
            q = -float(x @ np.asarray(P(t, kind)) @ x)
            assert abs(lhs - q) <= 1e-10 * scale ** 2 + 1e-13, (scale, lhs, q)
            q_other = -float(x @ np.asarray(P(t, other)) @ x)
            assert abs(lhs - q_other) > 1e-4 * scale ** 2  # unbalanced rotor: the two C really differ


def test_cond_matrix_traced_equals_theory_module():
    for name in ("twobody_uniaxial", "twobody_uniaxial_rotating"):
        s = get_system(name)
        p = s.check(s.params.resolve(dict(dA=0.7, dnu=1.1)))
        a = s.prepare({k: jnp.asarray(v) for k, v in p.items()})
        t = 3.7
        r = s.rotor(jnp.asarray(t), a)
        d = np.arctan2(float(r["D"][1, 0]), float(r["D"][0, 0]))
        dd = float(r["w02"][2])
        om0 = np.asarray(s.omega0(jnp.asarray(t), a)[0]) if s.rotating else None
        mats = tt.c_matrices(p["I1"], p["I2"], np.asarray(d), np.asarray(dd), om0)
        Bt = p["B"] + p["b"] * np.eye(3)
        for kind in ("physical", "paper"):
            np.testing.assert_allclose(np.asarray(s.cond_matrix(jnp.asarray(t), a, kind)), mats[kind] + Bt, atol=1e-12)


def test_printed_kinematics_break_the_lyapunov_identity():
    """With s' = -(w0 + x) x s (as printed), V' != 0 at x = 0 unless w0 || r0 x s0 ... i.e. V' is not a quadratic form."""
    s = get_system("twobody_uniaxial_rotating")
    p = s.check(s.params.resolve(dict(kinematics=1)))
    a = s.prepare({k: jnp.asarray(v) for k, v in p.items()})
    vdot = _vdot(s, a)
    y = jnp.asarray(np.concatenate([np.zeros(3), np.array(p["s0"])]))
    assert abs(float(vdot(jnp.asarray(1.0), y))) > 1e-3
    p0 = s.check(s.params.resolve(dict(kinematics=0)))
    a0 = s.prepare({k: jnp.asarray(v) for k, v in p0.items()})
    assert abs(float(_vdot(s, a0)(jnp.asarray(1.0), y))) < 1e-14


# ---- validation -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("name,over,field", [
    ("twobody_uniaxial", {"I1": "1,-2,3"}, "I1"),
    ("twobody_uniaxial", {"I2": "1,0.5,0,0,1,0,0,0,1"}, "I2"),
    ("twobody_uniaxial", {"B": "1,0.5,0,0,1,0,0,0,1"}, "B"),
    ("twobody_uniaxial", {"alpha": 0.0}, "alpha"),
    ("twobody_uniaxial", {"r0": "1,1,0"}, "r0"),
    ("twobody_uniaxial", {"s0": "0,0,0.5"}, "s0"),
    ("twobody_uniaxial", {"tau": 0.0}, "tau"),
    ("twobody_uniaxial", {"variant": 2.0}, "variant"),
    ("twobody_triaxial", {"alphas": "1,0,2"}, "alphas"),
    ("twobody_triaxial", {"r02": "0.6,0.8,0"}, "r02"),
    ("twobody_triaxial", {"S0": "1,0,0,0,1,0,0,0,2"}, "S0"),
    ("twobody_triaxial", {"S0": "1,0,0,0,1,0,0,0,-1"}, "S0"),
    ("twobody_uniaxial_rotating", {"kinematics": 0.5}, "kinematics"),
    ("twobody_triaxial_rotating", {"dnu": -1.0}, "dnu"),
])
def test_bad_input_names_the_field(name, over, field):
    s = get_system(name)
    with pytest.raises(ValidationError) as exc:
        s.check(s.params.resolve(over))
    assert exc.value.field == field


def test_rotating_window_minimum_matches_brute_force():
    """min over t in [0, 200] by the module (grid + zoom) vs a 400001-point brute force written here."""
    I1 = np.diag([10.0, 8.0, 6.0])
    t = np.linspace(0.0, 200.0, 400001)
    d, dd = 3.0 * t, 3.0
    c, s = np.cos(d), np.sin(d)
    z, o = np.zeros_like(t), np.ones_like(t)
    D = np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)
    Dd = dd * np.stack([np.stack([-s, -c, z], -1), np.stack([c, -s, z], -1), np.stack([z, z, z], -1)], -2)
    Dt, Ddt = np.swapaxes(D, -1, -2), np.swapaxes(Dd, -1, -2)
    J = I1 + D @ I2_SPEC @ Dt
    Jd = Dd @ I2_SPEC @ Dt + D @ I2_SPEC @ Ddt
    w0 = np.stack([0.3 * np.sin(0.5 * t), 0.2 * o, 0.4 * np.cos(0.3 * t)], -1)
    W = np.zeros((len(t), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w0[:, 2], w0[:, 1], -w0[:, 0]
    W -= np.swapaxes(W, -1, -2)
    X = W @ J
    P = Jd + 0.5 * (X + np.swapaxes(X, -1, -2))
    want = -np.linalg.eigvalsh(P)[:, 0].min()
    got = theory("twobody_uniaxial_rotating").derived["b_star_physical"][0]
    assert abs(got - want) < 2e-6, (got, want)
