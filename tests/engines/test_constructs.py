"""The fast engines run what users write: one-line models, each using one common JAX construct, run on
the native engine (and on the fused one when asked), not on the diffrax fallback; their results
match SciPy DOP853 on the same right-hand side evaluated by XLA, within an error bound derived from
the solver's tolerances (tests/tolerances.py). The mass-matrix model (tests/models/double_pendulum.py)
is checked against DOP853 on an independent NumPy right-hand side (2 x 2 solve by Cramer's rule).
Also: the unrolled linear algebra (stabjax.engines.unrolled) against LAPACK, and the Jacobi sweep
count against its stated accuracy.

What would make these fail: a construct without a lane rule (the engine resolved would be
"diffrax", with a note naming the primitive); a wrong rule (a wrong pivot, a transposed solve, a
loop unrolled the wrong number of times) moves the final state by O(0.1), far above the bound.
"""
import importlib.util
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stabjax import engines
from stabjax.config import IntegrateConfig
from stabjax.engines import fused, native, unrolled
from stabjax.engines.lanes import LaneFn
from stabjax.fold import verdict as V
from stabjax.model.params import Param, ParamSet
from stabjax.model.system import System

from tolerances import global_error_bound

HERE = Path(__file__).parents[1]  # tests/
RTOL, ATOL, T1 = 1e-8, 1e-10, 4.0
ICFG = IntegrateConfig(t1=T1, rtol=RTOL, atol=ATOL, n_checkpoints=8, settings={"threads": 1})

# constant matrices of the one-line models
# pivoting needed (|0.1| < |-1|); P + P^T > 0, so P + c y y^T (c >= 0) is never singular
P = jnp.array([[0.1, 1.0, 0.0], [-1.0, 0.1, 0.0], [0.0, 0.0, 1.0]])
S = jnp.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.3], [0.0, 0.3, 1.5]])  # symmetric positive definite
A = jnp.array([[-0.5, 1.0, 0.0], [-1.0, -0.5, 0.0], [0.0, 0.5, -1.0]])
E3 = jnp.array([0.0, 0.0, 1.0])

# name -> rhs(y, k): each one line, one construct, a bounded 3-state flow (k = 0.5 or 1.0)
CONSTRUCTS = {
    "sin_cos": lambda y, k: jnp.stack([y[1], -jnp.sin(y[0]) - k * y[1], jnp.cos(y[0]) - 1.0 - y[2]]),
    "exp_log": lambda y, k: -k * y * jnp.exp(-0.1 * (y @ y)) + 0.1 * jnp.log1p(y ** 2)[::-1],
    "where": lambda y, k: jnp.where(y > 0, -k * y, -2.0 * k * y) + 0.3 * y[::-1],
    "clip": lambda y, k: -k * jnp.clip(y, -0.5, 0.5) - 0.2 * y + 0.3 * jnp.roll(y, 1),
    "norm": lambda y, k: -k * y * jnp.linalg.norm(y) + jnp.cross(E3, y),
    "cross": lambda y, k: jnp.cross(jnp.array([0.3, 0.0, 1.0]), y) - 0.2 * k * y,
    "matmul": lambda y, k: A @ y * k,
    "einsum": lambda y, k: jnp.einsum("ij,j->i", A, y) + 0.1 * jnp.einsum("i,i->", y, y) * E3,
    "tanh_abs_max": lambda y, k: -k * jnp.tanh(y) - 0.1 * jnp.abs(y) * jnp.maximum(y, 0.0) + jnp.cross(E3, y),
    "cond": lambda y, k: jax.lax.cond(y[0] > 0, lambda: A @ y, lambda: 2.0 * k * A @ y),
    "solve": lambda y, k: jnp.linalg.solve(P + 0.2 * jnp.outer(y, y), -k * P @ y + jnp.cross(E3, y)),
    "lu_factor_solve": lambda y, k: jax.scipy.linalg.lu_solve(jax.scipy.linalg.lu_factor(P + 0.2 * jnp.outer(y, y)), -k * P @ y),
    "inv": lambda y, k: -k * jnp.linalg.inv(P + 0.2 * jnp.outer(y, y)) @ (P @ y),
    "det": lambda y, k: -k * y * jnp.linalg.det(jnp.eye(3) + 0.1 * jnp.outer(y, y)) + jnp.cross(E3, y),
    "cholesky": lambda y, k: -k * jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(S + jnp.outer(y, y)), S @ y),
    "eigh": lambda y, k: -(lambda w, v: v @ jnp.diag(k + w ** 2) @ v.T @ y)(*jnp.linalg.eigh(S + 0.5 * jnp.outer(y, y))),
    "eigvalsh": lambda y, k: -k * y * jnp.linalg.eigvalsh(S + jnp.outer(y, y))[-1] + jnp.cross(E3, y),
    "fori_loop": lambda y, k: jax.lax.fori_loop(0, 4, lambda i, c: c + 0.25 * (A @ c * k + 0.1 * jnp.sin(c[::-1])), y) - y,
    "fori_loop_traced_bound": lambda y, k: jax.lax.fori_loop(0, jnp.int32(3), lambda i, c: c + (i + 1) * 0.1 * A @ c, y) - y,
    "scan": lambda y, k: jax.lax.scan(lambda c, a: (c + 0.5 * a @ c, None), y, jnp.stack([A * k, A.T]))[0] - y,
    "stop_gradient": lambda y, k: -k * jax.lax.stop_gradient(y) + 0.5 * jnp.sin(y[::-1]),
    "at_set": lambda y, k: (A @ y).at[2].set(-k * y[2] + 0.3 * y[0] * y[1]),
    "cumsum": lambda y, k: -k * jnp.cumsum(y) + jnp.cross(E3, y),
    "argmax_index": lambda y, k: A @ y - 0.1 * jnp.abs(y[jnp.argmax(jnp.abs(y))]) * y,
    "sort": lambda y, k: -k * y + 0.2 * jnp.sort(y),
    # continuous: the value written at the state-dependent index is zero where the index switches
    "at_argmax_add": lambda y, k: A @ y + jnp.zeros(3).at[jnp.argmax(y)].add(jnp.sort(y)[1] - jnp.max(y)),
}


def _system(name, fn):
    class Construct(System):
        params = ParamSet((Param("k", 1.0, "gain"),) + tuple(Param(f"y{i}", 0.5, "initial", kind="initial")
                                                              for i in range(3)))
        state = (("y", (3,)),)
        default_t1 = T1

        def initial_state(self, p):
            return jnp.stack([p["y0"], p["y1"], p["y2"]])

        def rhs(self, t, y, p):
            return fn(y, p["k"])

        def observe(self, t, y, p):
            n = jnp.sqrt(y @ y)
            return jnp.stack([n, n])

    Construct.name = Construct.__name__ = f"construct_{name}"
    return Construct()


SYSTEMS = {name: _system(name, fn) for name, fn in CONSTRUCTS.items()}


def _params():
    """Three trajectories: two gains, starting points in different octants (other pivots, branches)."""
    return {"k": np.array([0.5, 1.0, 1.0]), "y0": np.array([0.8, -0.6, 0.3]),
            "y1": np.array([-0.4, 0.9, 0.7]), "y2": np.array([0.5, 0.2, -0.9])}


def _reference(rhs, y0, t1):
    """(y(t1), max |y_i| along the way, kappa = max_s ||Phi(t1, s)||_2) from DOP853 at 1e-12 on the
    state and its variational equation (Jacobian by jax.jacfwd of ``rhs``, evaluated by XLA)."""
    n = len(y0)

    @jax.jit  # the whole augmented right-hand side in one call (SciPy calls it ~5,000 times per trajectory)
    def aug_j(z):
        y, phi = z[:n], z[n:].reshape(n, n)
        return jnp.concatenate([rhs(y), (jax.jacfwd(rhs)(y) @ phi).ravel()])

    def aug(t, z):
        return np.asarray(aug_j(z))

    z0 = np.concatenate([y0, np.eye(n).ravel()])
    sol = solve_ivp(aug, (0.0, t1), z0, method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
    assert sol.success
    phi1 = sol.y[n:, -1].reshape(n, n)
    ss = np.linspace(0.0, t1, 81)
    kappa = max(np.linalg.norm(phi1 @ np.linalg.inv(sol.sol(s)[n:].reshape(n, n)), 2) for s in ss)
    y_max = float(np.abs(sol.sol(ss)[:n]).max())
    return sol.y[:n, -1], y_max, kappa


def _sweep_vcfg(system):
    """The fold a sweep of these models folds (stabjax.plan.spec: no named outcomes, so discovery): the
    late-window features alone, not the attitude classifier. What these tests check (the engine chosen, the
    final states) does not depend on it; the features-only fold is far smaller to compile (C and XLA)."""
    return V.bind(system.verdict.replace(features=True, verdicts=False), ICFG.t0, ICFG.t1,
                  n_obs=len(system.observables))


def _expected_engine():
    return "native" if native.available() else "fused"


def _check_against_reference(res, rhs_of, y0s, n_state):
    for i, y0 in enumerate(y0s):
        y1, y_max, kappa = _reference(rhs_of(i), y0, T1)
        assert res["solver_status"][i] == 0
        bound = global_error_bound(int(res["n_steps"][i]), n_state, RTOL, ATOL, y_max, kappa)
        err = np.linalg.norm(res["state_t1"][i] - y1)
        assert err <= bound, (i, err, bound)


# integrated end to end in CI (a full native kernel is ~10 s of gcc on 2 cores): the linear algebra and
# loop rules of issue 25; every construct's C translation is checked above, and all integrate in the slow run
CI_RUNS = {"solve", "eigh", "fori_loop"}


@pytest.mark.skipif(not native.available(), reason="no working C compiler")
@pytest.mark.parametrize("name", list(CONSTRUCTS))
def test_construct_translates_to_c_and_equals_xla(name):
    """Every construct translates to C (the native engine declines a system exactly when this raises
    Unsupported), and the compiled right-hand side equals XLA's at random states to rounding. (The
    translation is compiled without the integration loop: a second of gcc instead of ten.)"""
    system, fn = SYSTEMS[name], CONSTRUCTS[name]
    kern, _ = native.kernel_for(system, ICFG, _sweep_vcfg(system), _params(), eval_only=True)
    rng = np.random.default_rng(2)
    xla = jax.jit(fn)  # one XLA compile, not one per operation run eagerly
    for _ in range(8):
        y, k = rng.uniform(-1.0, 1.0, 3), rng.uniform(0.5, 1.0)
        a, _ = kern.model.host_inputs({"k": np.array([k]), "y0": y[:1], "y1": y[1:2], "y2": y[2:]}, 1)
        dy, _ = native.evaluate(kern, 0.0, y, a[0])
        np.testing.assert_allclose(dy, np.asarray(xla(jnp.asarray(y), k)), rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("name", list(CONSTRUCTS))
def test_construct_translates_for_the_fused_engine(name):
    """The fused engine takes every construct (asked for by name: no fallback note), and its
    lane-wise right-hand side equals the vmapped XLA one to rounding."""
    system, fn = SYSTEMS[name], CONSTRUCTS[name]
    p = _params()
    assert engines.resolve(system, ICFG.replace(engine="fused"), _sweep_vcfg(system), p) == ("fused", "")
    rng = np.random.default_rng(1)
    ys, ks = rng.uniform(-1.0, 1.0, (16, 3)), rng.uniform(0.5, 1.0, 16)
    lane = LaneFn(fn, jnp.zeros(3), jnp.float64(1.0))(16, jnp.asarray(ys.T), jnp.asarray(ks))
    np.testing.assert_allclose(np.asarray(lane).T, jax.vmap(fn)(ys, ks), rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("name", [n if n in CI_RUNS else pytest.param(n, marks=pytest.mark.slow) for n in CONSTRUCTS])
def test_construct_runs_on_the_fast_engine_and_matches_dop853(name):
    """``engines.resolve`` (what a sweep does: translate and compile) picks the native engine (the
    fused one without a C compiler) with no fallback note; the final states are within the bound."""
    system, fn = SYSTEMS[name], CONSTRUCTS[name]
    p = _params()
    vcfg = _sweep_vcfg(system)
    choice = engines.resolve(system, ICFG, vcfg, p)
    assert choice == (_expected_engine(), ""), choice.note
    module = native if choice.engine == "native" else fused
    res = module.solve(system, p, ICFG, vcfg, with_state=True)
    y0s = np.stack([p["y0"], p["y1"], p["y2"]], axis=1)
    _check_against_reference(res, lambda i: (lambda y: fn(y, p["k"][i])), y0s, 3)


@pytest.mark.parametrize("name", ["solve", pytest.param("eigh", marks=pytest.mark.slow),
                                  pytest.param("fori_loop", marks=pytest.mark.slow)])
def test_fused_engine_integrates_linear_algebra_and_loops(name):
    """A full fused-engine run for the constructs that are new to it (the rest share its lane rules)."""
    system, fn = SYSTEMS[name], CONSTRUCTS[name]
    p = _params()
    res = fused.solve(system, p, ICFG, _sweep_vcfg(system), with_state=True, lanes=4)
    y0s = np.stack([p["y0"], p["y1"], p["y2"]], axis=1)
    _check_against_reference(res, lambda i: (lambda y: fn(y, p["k"][i])), y0s, 3)


def _load_pendulum():
    spec = importlib.util.spec_from_file_location("double_pendulum_model", HERE / "models" / "double_pendulum.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _pendulum_numpy(p):
    """The same equations with the 2 x 2 mass matrix solved by Cramer's rule (no JAX, no LAPACK)."""
    m1, m2, l1, l2, g, c = (p[k] for k in ("m1", "m2", "l1", "l2", "g", "c"))

    def rhs(y):
        th1, th2, w1, w2 = y
        d = th1 - th2
        a, b, e = (m1 + m2) * l1 ** 2, m2 * l1 * l2 * math.cos(d), m2 * l2 ** 2
        k = m2 * l1 * l2 * math.sin(d)
        f1 = -k * w2 ** 2 - (m1 + m2) * g * l1 * math.sin(th1) - c * w1
        f2 = k * w1 ** 2 - m2 * g * l2 * math.sin(th2) - c * w2
        det = a * e - b * b
        return np.array([w1, w2, (f1 * e - b * f2) / det, (a * f2 - b * f1) / det])

    return rhs


def test_mass_matrix_model_runs_natively_and_matches_dop853():
    """M(q) q'' = f with jnp.linalg.solve: the engine is the fast one (no note), and the final states
    match DOP853 on the NumPy equations within the derived bound (kappa from the variational
    equation of the JAX model)."""
    mod = _load_pendulum()
    system = mod.DoublePendulum()
    n = 3
    p = {k.name: np.full(n, k.default, float) for k in system.params}
    p["th1"] = np.array([1.0, 0.3, -2.0])
    p["th2"] = np.array([-0.5, 0.2, 1.0])
    p["m2"] = np.array([1.0, 0.5, 2.0])
    vcfg = _sweep_vcfg(system)
    choice = engines.resolve(system, ICFG, vcfg, p)
    assert choice == (_expected_engine(), ""), choice.note
    module = native if choice.engine == "native" else fused
    res = module.solve(system, p, ICFG, vcfg, with_state=True)
    for i in range(n):
        pi = {k: float(v[i]) for k, v in p.items()}
        y0 = np.array([pi["th1"], pi["th2"], 0.0, 0.0])
        ref = solve_ivp(lambda t, y: _pendulum_numpy(pi)(y), (0.0, T1), y0, method="DOP853", rtol=1e-12, atol=1e-14)
        y1, y_max, kappa = _reference(lambda y: system.rhs(0.0, y, {k: jnp.float64(v) for k, v in pi.items()}), y0, T1)
        np.testing.assert_allclose(y1, ref.y[:, -1], atol=1e-9)  # the two references agree
        bound = global_error_bound(int(res["n_steps"][i]), 4, RTOL, ATOL, y_max, kappa)
        assert np.linalg.norm(res["state_t1"][i] - ref.y[:, -1]) <= bound


# ---- the unrolled algorithms against LAPACK ------------------------------------------------------


# all 16 forms of the primitive (left/right side, lower/upper, transposed or not, unit diagonal or not)
TRSM_FORMS = [dict(left_side=left, lower=lower, transpose_a=trans, unit_diagonal=unit)
              for left in (False, True) for lower in (False, True) for trans in (False, True) for unit in (False, True)]


@jax.jit
def _lapack_triangular_solves(t, b_right, b_left):
    """The reference: the primitive itself (LAPACK's trsm on CPU) in every form, as one XLA program (~0.3 s to
    compile per n, against ~2.5 s for 16 primitives compiled one by one when run eagerly); the same
    primitive, parameters and inputs as before, so the same reference values."""
    return [jax.lax.linalg.triangular_solve(t, b_left if kw["left_side"] else b_right, **kw) for kw in TRSM_FORMS]


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
def test_unrolled_lu_and_triangular_solve_match_lapack(n):
    """Same pivots and permutation as LAPACK's getrf (first largest |a_ik|), factors to rounding;
    pivots to permutation as JAX's; triangular solves in all 16 forms of the primitive."""
    rng = np.random.default_rng(n)
    for _ in range(5):
        a = rng.normal(size=(n, n))
        ref = jax.lax.linalg.lu(a)
        got = unrolled.lu(a)
        np.testing.assert_array_equal(got[1], ref[1])
        np.testing.assert_array_equal(got[2], ref[2])
        np.testing.assert_allclose(got[0], ref[0], rtol=1e-12, atol=1e-12)
        piv = np.array([rng.integers(k, n) for k in range(n)], np.int32)
        np.testing.assert_array_equal(unrolled.lu_pivots_to_permutation(piv, permutation_size=n),
                                      jax.lax.linalg.lu_pivots_to_permutation(piv, n))
    t = a + n * np.eye(n)
    bs = {left: rng.normal(size=(n, 2) if left else (2, n)) for left in (False, True)}  # drawn in this order
    refs = _lapack_triangular_solves(t, bs[False], bs[True])
    for kw, ref in zip(TRSM_FORMS, refs):
        np.testing.assert_allclose(unrolled.triangular_solve(t, bs[kw["left_side"]], **kw), ref,
                                   rtol=1e-12, atol=1e-12, err_msg=str(kw))


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_jacobi_sweeps_reach_float64_accuracy(n):
    """With jacobi_sweeps(n) sweeps, eigh's residual ||A V - V diag(w)|| / ||A|| and V's departure
    from orthogonality are at rounding level (< 50 eps) on random, clustered, repeated and graded
    spectra, and the eigenvalues equal LAPACK's to that level (the sweep count's docstring gives the
    measured convergence it rests on)."""
    rng = np.random.default_rng(10 + n)
    m = 40
    q, _ = np.linalg.qr(rng.normal(size=(3 * m, n, n)))
    spectra = [1.0 + 1e-6 * np.arange(n), np.r_[np.ones(n - 1), 2.0], np.logspace(-8, 0, n)]
    mats = [(lambda x: (x + x.T) / 2)(rng.uniform(-1, 1, (n, n))) for _ in range(m)]
    mats += [q[j * m + i] @ np.diag(w) @ q[j * m + i].T for j, w in enumerate(spectra) for i in range(m)]
    mats = np.array(mats)
    # the (n, n, batch) layout makes every a[i, j] a vector: the algorithm runs on all matrices at once
    v, w = unrolled._eigh(np.moveaxis(mats, 0, -1), lower=True, sort_eigenvalues=True)
    v, w = np.moveaxis(np.asarray(v), -1, 0), np.moveaxis(np.asarray(w), -1, 0)
    eps = np.finfo(float).eps
    norm = np.linalg.norm(mats, axis=(1, 2))
    resid = np.linalg.norm(mats @ v - v * w[:, None, :], axis=(1, 2)) / norm
    assert resid.max() < 50 * eps, resid.max()
    orth = np.linalg.norm(np.swapaxes(v, 1, 2) @ v - np.eye(n), axis=(1, 2))
    assert orth.max() < 50 * eps
    assert np.all(np.abs(w - np.linalg.eigvalsh(mats)) <= 50 * eps * norm[:, None])
    assert np.all(np.diff(w, axis=1) >= 0)  # ascending, as LAPACK's


def test_oversized_matrices_and_lane_varying_loops_have_no_rule():
    """What is not supported says so (and the engine chain then falls back with that reason)."""
    from stabjax.engines.lanes import NoRule

    big = LaneFn(lambda y: jnp.linalg.eigvalsh(jnp.eye(9) * y[0]), jnp.zeros(3))
    with pytest.raises(NoRule, match="9 x 9"):
        big(2, jnp.ones((3, 2)))
    loop = LaneFn(lambda y: jax.lax.while_loop(lambda c: c[0] < 1.0, lambda c: c * 2.0, y), jnp.zeros(3))
    with pytest.raises(NoRule, match="lane-varying condition"):
        loop(2, jnp.ones((3, 2)) * 0.1)
