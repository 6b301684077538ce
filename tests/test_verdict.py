"""The excursion classifier on synthetic error histories with known answers."""
import jax
import jax.numpy as jnp
import numpy as np

from stabjax import verdict as V
from stabjax.system import VerdictConfig

CFG = VerdictConfig()
TS = np.linspace(0, 1e4, 4001)


def run(e, size=None, ok=True, cfg=CFG):
    size = np.zeros_like(e) if size is None else size
    obs = jnp.stack([jnp.asarray(e), jnp.asarray(size)], axis=1)
    return jax.tree.map(np.asarray, V.classify(jnp.asarray(TS), obs, jnp.asarray(ok), cfg, 0.0))


def bump(t, t0, width, peak):
    return peak * np.exp(-(((t - t0) / width) ** 2))


def test_power_law_convergence():
    e = 1.0 / (1 + TS) ** 1.5
    r = run(e)
    assert r["verdict"] == V.CONVERGED
    np.testing.assert_allclose(r["decay_exponent"], 1.5, rtol=0.01)


def test_persisting_flips_are_flipped():
    e = 1e-6 + bump(TS, 300, 50, 3.0) + bump(TS, 2300, 80, 2.6) + bump(TS, 7600, 120, 2.2)
    r = run(e)
    assert r["verdict"] == V.FLIPPED
    assert r["n_flips"] == 3 and r["n_excursions"] == 3
    np.testing.assert_allclose(r["peak_last"], 2.2, rtol=1e-3)
    np.testing.assert_allclose(r["peak_prev"], 2.6, rtol=1e-3)


def test_early_flip_then_convergence_is_converged():
    e = 1e-7 / (1 + TS) + bump(TS, 600, 50, 2.5)
    r = run(e)
    assert r["verdict"] == V.CONVERGED and r["n_flips"] == 1
    assert 400 < r["t_first_flip"] < 600


def test_shrinking_excursions_below_flip_are_undecided():
    e = 1e-6 + bump(TS, 3000, 100, 2.0) + bump(TS, 8000, 150, 1.0)
    assert run(e)["verdict"] == V.UNDECIDED


def test_resting_inverted_is_flipped():
    assert run(np.full_like(TS, 3.1))["verdict"] == V.FLIPPED


def test_failures_and_blowup():
    e = 1.0 / (1 + TS)
    bad = e.copy()
    bad[-10:] = np.nan
    assert run(bad)["verdict"] == V.FAILED
    assert run(e, ok=False)["verdict"] == V.FAILED
    assert run(e, size=np.geomspace(1, 1e8, len(TS)))["verdict"] == V.DIVERGED


def test_slow_decay_not_reaching_tolerance_is_undecided():
    e = 0.05 * (1 + TS) ** -0.1  # ~0.02 at t1: settled but above converged_tol
    assert run(e)["verdict"] == V.UNDECIDED


def test_thresholds_are_configurable():
    e = 0.05 * (1 + TS) ** -0.1
    assert run(e, cfg=CFG.replace(converged_tol=0.05))["verdict"] == V.CONVERGED


def test_noise_floor_does_not_block_convergence():
    """At the solver's noise floor (~rtol) the late slope is noise; that must not make it undecided."""
    rng = np.random.default_rng(0)
    e = np.where(TS < 100, 1.0 / (1 + TS), 3e-8 * (1 + rng.uniform(0, 1, len(TS))) * (TS / 1e4) ** 2)
    r = run(e)
    assert r["decay_exponent"] < 0  # the floor's fitted trend is "growing"
    assert r["verdict"] == V.CONVERGED


def test_small_bumps_in_late_window_are_not_converged():
    """Paper A: returning to 1e-12 between bumps of 0.1 rad is not convergence (no final-error shortcut)."""
    e = 1e-12 + bump(TS, 2000, 50, 2.5) + bump(TS, 8000, 80, 0.1)
    assert run(e)["verdict"] == V.UNDECIDED
