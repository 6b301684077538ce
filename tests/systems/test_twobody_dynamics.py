"""Bezglasnyi-Mysina closed loops in simulation: invariants (unit vectors, orthonormal frame),
equilibria, escape from the unstable ones, and the spec's findings (docs/models/twobody.md)."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import stabjax  # noqa: F401
from stabjax import get_system
from stabjax.engines.simulate import simulate
from stabjax.systems import twobody_theory as tt
from stabjax.systems.twobody import rotation_matrix, polar, rotation_angle

NAMES = ["twobody_uniaxial", "twobody_triaxial", "twobody_uniaxial_rotating", "twobody_triaxial_rotating"]


def theory(name, **over):
    from stabjax.engines.simulate import batch_params
    s = get_system(name)
    return s.theory(batch_params(s, over, n=1))


def rand_rot(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ---- invariants, equilibria, findings ---------------------------------------------------------------

def test_triaxial_frame_stays_orthonormal_and_polar_guards_torque():
    ds = simulate("twobody_triaxial", {"b": 3.0, "dA": 1.0, "dnu": 0.5}, t1=200.0, rtol=1e-10, atol=1e-12)
    assert ds.attrs["solver_ok"] == 1
    assert float(ds["ortho_drift"].max()) < 1e-8
    assert float(ds["angle"][-1]) < 1e-6
    # a drifted S gives the torque of its polar factor, not a fake linear restoring torque
    rng = np.random.default_rng(0)
    S = rand_rot(rng)
    Sd = S @ (np.eye(3) + 1e-4 * np.diag([1.0, -2.0, 0.5]))
    Pd = np.asarray(polar(jnp.asarray(Sd)))
    # Newton-Schulz maps a singular value 1 + e to 1 - 3/2 e^2 + O(e^3): two steps leave ~ (3/2)^3 e^4
    eps = 2e-4
    bound = 2 * 1.5 ** 3 * eps ** 4 * 1.1 + 1e-15
    assert np.abs(Pd.T @ Pd - np.eye(3)).max() < bound
    assert np.abs(Pd - S).max() < bound  # a symmetric stretch: the polar factor is S itself
    # at solver-tolerance drift (1e-9) the copy is orthonormal to rounding
    P9 = np.asarray(polar(jnp.asarray(S @ (np.eye(3) + 1e-9 * np.diag([1.0, -2.0, 0.5])))))
    assert np.abs(P9.T @ P9 - np.eye(3)).max() < 1e-15
    s = get_system("twobody_triaxial")
    a = s.prepare({k: jnp.asarray(v) for k, v in s.check(s.params.resolve({})).items()})
    t_exact = np.asarray(s.potential_torque(jnp.asarray(S), a))
    t_drift = np.asarray(s.potential_torque(jnp.asarray(Sd), a))
    t_raw = sum(np.asarray(a["alphas"])[i] * np.cross(np.eye(3)[:, i], Sd[:, i]) for i in range(3))
    assert np.abs(t_exact - t_drift).max() < 10 * bound
    assert np.abs(t_exact - t_raw).max() > 1e-5  # without the polar copy the stretch would act as a torque
    # rotation angle of a known rotation, near 0 and near pi
    for ang in (1e-9, 0.3, np.pi - 1e-7):
        assert abs(float(rotation_angle(jnp.asarray(rotation_matrix((1, 2, 3), ang)))) - ang) < 1e-12


def test_uniaxial_unit_vector_norm_preserved():
    ds = simulate("twobody_uniaxial_rotating", {}, t1=200.0)
    assert float(ds["unit_drift"].max()) < 1e-8


@pytest.mark.parametrize("name", NAMES)
def test_equilibria_stay_put(name):
    s = get_system(name)
    if s.triaxial:
        starts = [S for _, S, _ in tt.equilibria_triaxial(np.eye(3))]
        key = "S0"
    else:
        starts = [v for _, v, _ in tt.equilibria_uniaxial([0, 0, 1.0])]
        key = "s0"
    vkey = "x0" if s.rotating else "w0"
    for S in starts:
        ds = simulate(s, {key: np.asarray(S).ravel().tolist(), vkey: "0,0,0", "dA": 0.5, "dnu": 1.0}, t1=200.0)
        assert float(ds[s.observables[1]].max()) < 1e-12
        assert abs(float(ds["angle"][-1]) - float(ds["angle"][0])) < 1e-12


def test_printed_rotating_kinematics_do_not_keep_or_reach_the_target():
    # start exactly at the target: with s' = -(w0 + x) x s it is not an equilibrium (w0 not || r0)
    base = {"s0": "0,0,1", "x0": "0,0,0"}
    ds = simulate("twobody_uniaxial_rotating", {**base, "kinematics": 1}, t1=200.0)
    assert float(ds["angle"].max()) > 1e-2
    # the spec's run (b = 4.1, default start): corrected kinematics converge, printed ones do not
    good = simulate("twobody_uniaxial_rotating", {}, t1=200.0)
    bad = simulate("twobody_uniaxial_rotating", {"kinematics": 1}, t1=200.0)
    assert float(good["angle"][-1]) < 1e-8 and float(good["xnorm"][-1]) < 1e-8
    assert float(bad["angle"][-1]) > 0.3


def test_condition_is_sufficient_not_necessary():
    # docs/models/twobody.md: B = I (below b* = 2.3458): V is not monotone, yet the motion converges
    th = theory("twobody_uniaxial", b=1.0)
    assert not th.predicates["physical"].ok[0]
    ds = simulate("twobody_uniaxial", {"b": 1.0}, t1=400.0)
    V = ds["V"].values
    assert np.diff(V).max() > 1e-6
    assert float(ds["angle"][-1]) < 1e-6  # slow (rate ~0.036/s) but exponential
    # and with b = 3 > b*, V is non-increasing along the whole run
    V3 = simulate("twobody_uniaxial", {"b": 3.0}, t1=200.0)["V"].values
    assert np.diff(V3).max() <= 1e-12 * V3[0]


def test_starts_near_unstable_equilibria_leave():
    """Starts 1e-3 rad from each unstable equilibrium, at rest, leave it and settle on the target."""
    rng = np.random.default_rng(1)
    for name in NAMES:
        s = get_system(name)
        vkey = "x0" if s.rotating else "w0"
        if s.triaxial:
            eqs = [S for _, S, lab in tt.equilibria_triaxial(np.eye(3)) if lab == "unstable"]
            starts = [{"S0": (S @ rotation_matrix(rng.normal(size=3), 1e-3)).ravel().tolist()} for S in eqs]
        else:
            v = np.array([0, 0, -1.0]) + 1e-3 * rng.normal(size=(2, 3))
            starts = [{"s0": (u / np.linalg.norm(u)).tolist()} for u in v]
        for st in starts:
            ds = simulate(s, {**st, vkey: "0,0,0", "dA": 0.5, "dnu": 1.0}, t1=200.0)
            ang = ds["angle"].values
            assert ang[0] > np.pi - 2e-3 and ang[-1] < 1e-5, (name, ang[0], ang[-1])


