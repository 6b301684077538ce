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


def test_growth_past_diverge_size_then_solver_failure_is_diverged():
    """A runaway whose spun-up state then exhausts max_steps: the finite checkpoints already show it."""
    cfg = CFG.replace(diverge_size=1.0)  # attitude in rad, as for the gyrodyne
    e = 1.0 / (1 + TS)
    size = np.geomspace(1e-3, 1e3, len(TS))  # passes diverge_size at t = 5000
    cut = 3 * len(TS) // 4
    size[cut:] = np.inf  # unreached checkpoints after the solver stopped (diffrax fills inf)
    e[cut:] = np.inf
    assert size[cut - 1] > cfg.diverge_size
    r = run(e, size=size, ok=False, cfg=cfg)
    assert r["verdict"] == V.DIVERGED
    np.testing.assert_allclose(r["size_max"], size[cut - 1])  # largest finite size, not inf
    # NaN instead of inf, and solver "ok" but state non-finite: the same evidence, the same verdict
    size[cut:] = np.nan
    assert run(e, size=size, ok=False, cfg=cfg)["verdict"] == V.DIVERGED
    assert run(e, size=size, ok=True, cfg=cfg)["verdict"] == V.DIVERGED
    # the same history cut before the size reached diverge_size: no evidence, failed
    size[len(TS) // 2 - 10:] = np.nan
    assert run(e, size=size, ok=False, cfg=cfg)["verdict"] == V.FAILED


def test_nan_without_prior_growth_is_failed():
    e = 1.0 / (1 + TS)
    size = np.full_like(TS, 0.1)
    e[-10:] = np.nan
    size[-10:] = np.nan
    r = run(e, size=size)
    assert r["verdict"] == V.FAILED
    np.testing.assert_allclose(r["size_max"], 0.1)
    size[-10:] = np.inf  # an infinite size is not evidence either: only finite checkpoints count
    assert run(e, size=size)["verdict"] == V.FAILED


def test_solver_failure_without_growth_is_failed():
    e = 1.0 / (1 + TS)
    size = np.full_like(TS, CFG.diverge_size * 0.99)
    assert run(e, size=size, ok=False)["verdict"] == V.FAILED
    # growth of the error alone (never settled, late slope > growth_tol) does not override a failure
    assert run(np.geomspace(0.5, 1.0, len(TS)), ok=False)["verdict"] == V.FAILED
