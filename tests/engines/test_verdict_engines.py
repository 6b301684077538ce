"""The multi-horizon classifier is the same fold in every engine: the native (C) and fused (XLA)
engines translate ``verdict.update`` lane-wise, the diffrax path scans it over saved checkpoints.
On a small monoaxial alpha sweep the three give identical verdicts at every horizon."""
import numpy as np
import pytest

from stabjax.fold import verdict as V
from stabjax.config import IntegrateConfig
from stabjax.engines.simulate import batch_params
from stabjax.engines import fused as fast
from stabjax.engines import native
from stabjax.engines.diffrax_engine import solve as _solve_diffrax
from stabjax.model.registry import get_system

SYS = get_system("monoaxial")
ICFG = IntegrateConfig(t1=1000.0, rtol=1e-10, atol=1e-12, n_checkpoints=200)
VCFG = V.bind(SYS.verdict, ICFG.t0, ICFG.t1, n_obs=len(SYS.observables))


def params():
    p = batch_params(SYS, None, 8)
    p["alpha"] = np.linspace(0.3, 1.0, 8)
    return p


@pytest.fixture(scope="module")
def ref():
    return _solve_diffrax(SYS, params(), ICFG, VCFG)


def _check(out, ref):
    assert out["verdict"].shape == (8, len(VCFG.horizons)) == ref["verdict"].shape
    np.testing.assert_array_equal(out["verdict"], ref["verdict"])
    for k in ("n_excursions", "n_flips", "decay_reason", "decay_n", "t_settle", "t_last_excursion"):
        np.testing.assert_array_equal(out[k], ref[k], err_msg=k)
    # trajectories agree to the solver tolerance (rtol 1e-10), not bitwise
    for k in ("error_t1", "error_max_late", "peak_last", "peak_ratio", "decay_exponent", "decay_exponent_se"):
        np.testing.assert_allclose(out[k], ref[k], rtol=1e-5, atol=1e-8, err_msg=k)


# slow: covered in the fast suite by test_native.py's test_verdicts_summaries_and_steps_match_diffrax_engine (the same
# check, on 40 trajectories to t1 = 800 with 4 horizons: several outcomes, and verdicts that change between horizons)
@pytest.mark.slow
def test_several_outcomes_and_horizons_are_exercised(ref):
    v = ref["verdict"]
    assert len(np.unique(v)) >= 2 and np.any(v[:, 0] != v[:, -1])


# slow: covered in the fast suite by test_native.py's test_verdicts_summaries_and_steps_match_diffrax_engine (the same
# keys compared the same way, exact or at rtol 1e-5 / atol 1e-8, native against the diffrax engine at every horizon)
@pytest.mark.slow
@pytest.mark.skipif(not native.available(), reason="no working C compiler")
def test_native_equals_diffrax_at_every_horizon(ref):
    _check(native.solve(SYS, params(), ICFG, VCFG, threads=1), ref)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: test_fused.py's verdicts and summaries against the diffrax engine
def test_fused_equals_diffrax_at_every_horizon(ref):
    _check(fast.solve(SYS, params(), ICFG, VCFG, lanes=4), ref)


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: features across engines: tests/fold/test_verdict.py's window-std test, the examples against SciPy
def test_observable_features_in_every_engine():
    """feat_* per observable over the feature window, the same in every engine."""
    cfg = VCFG.replace(features=True)
    p = {k: v[:4] for k, v in params().items()}
    ref = _solve_diffrax(SYS, p, ICFG, cfg)
    assert ref["feat_max"].shape == (4, len(SYS.observables))
    assert np.all(ref["feat_min"] <= ref["feat_mean"]) and np.all(ref["feat_mean"] <= ref["feat_max"])
    runs = [fast.solve(SYS, p, ICFG, cfg, lanes=4)]
    if native.available():
        runs.append(native.solve(SYS, p, ICFG, cfg, threads=1))
    for out in runs:
        for k in ("feat_max", "feat_min", "feat_mean", "feat_std", "feat_final"):
            np.testing.assert_allclose(out[k], ref[k], rtol=1e-5, atol=1e-9, err_msg=k)
