"""The optional compiled CPU baseline of the benchmark (benchmarks/numba_baseline.py): final states
against SciPy DOP853 at tight tolerance, step counts against diffrax's Dopri5 (same method and
controller), and the interface benchmarks.bench.run_numba relies on."""
import importlib

import numpy as np
import pytest

pytest.importorskip("numba")

from benchmarks import bench  # noqa: E402

ALPHAS = np.array([1.0 / 3.0, 7.0 / 9.0, 1.0])
T1 = 50.0


@pytest.fixture(scope="module")
def nb():
    return importlib.import_module("benchmarks.numba_baseline")


@pytest.fixture(scope="module")
def problem():
    c = bench.paper_constants()
    return c, np.concatenate([c["w0"], c["s0"]])


@pytest.fixture(scope="module")
def solved(nb, problem):
    c, y0 = problem
    return nb.solve_many(np.tile(y0, (len(ALPHAS), 1)), ALPHAS, c, T1, bench.RTOL, bench.ATOL, return_stats=True)


def test_final_states_match_scipy_dop853(problem, solved):
    from scipy.integrate import solve_ivp

    c, y0 = problem
    ys, acc, rej, status = solved
    assert ys.shape == (3, 6) and acc.shape == (3,) and np.issubdtype(acc.dtype, np.integer)
    assert (status == 0).all()
    for i, a in enumerate(ALPHAS):
        ref = solve_ivp(bench.numpy_rhs, (0.0, T1), y0, method="DOP853", rtol=1e-12, atol=1e-12, args=(a, c))
        assert ref.success
        np.testing.assert_allclose(ys[i], ref.y[:, -1], rtol=0, atol=1e-6)
    # steps: positive and in the range of an order-5 method at rtol 1e-8 over 50 s (~160-270 measured)
    assert (acc > 20).all() and (acc < 5000).all()
    assert (rej >= 0).all() and (rej < acc).all()


@pytest.mark.slow  # ~5-10 s of diffrax compile
def test_step_counts_match_diffrax_dopri5(problem, solved):
    import jax.numpy as jnp

    _, y0 = problem
    ys, acc, _, _ = solved
    solve, y0_bench = bench._diffrax_baseline_fn(T1, solver="Dopri5")
    np.testing.assert_array_equal(y0, y0_bench)
    yd, accd, _, _ = (np.asarray(x) for x in solve(jnp.tile(jnp.asarray(y0), (len(ALPHAS), 1)), jnp.asarray(ALPHAS)))
    # same tableau, error norm, controller and initial step: the same step sequence up to rounding
    assert np.all(np.abs(acc - accd) <= np.maximum(2, 0.01 * accd)), (acc, accd)
    np.testing.assert_allclose(ys, yd, rtol=0, atol=1e-7)


def test_interface_and_options(nb, problem):
    c, y0 = problem
    # D given as its 3 diagonal entries is the same model as the 3x3 matrix
    cd = dict(c, D=np.diag(c["D"]))
    y_a, n_a = nb.solve_many(y0[None], ALPHAS[1:2], c, 5.0, 1e-8, 1e-10)
    y_b, n_b = nb.solve_many(y0[None], ALPHAS[1:2], cd, 5.0, 1e-8, 1e-10)
    np.testing.assert_array_equal(y_a, y_b)
    assert n_a[0] == n_b[0] > 0
    # the step budget is honoured and reported
    _, n, _, status = nb.solve_many(y0[None], ALPHAS[:1], c, 5.0, 1e-8, 1e-10, max_steps=3, return_stats=True)
    assert status[0] == 1 and n[0] <= 3
    with pytest.raises(ValueError):
        nb.solve_many(np.zeros((2, 6)), ALPHAS, c, 1.0, 1e-8, 1e-10)
