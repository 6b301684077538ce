"""Small dense linear algebra written out as scalar operations, for the lane engines.

``jnp.linalg.solve``, ``inv``, ``det`` (LAPACK ``getrf``/``trsm`` behind the primitives ``lu`` and
``triangular_solve``) and ``jnp.linalg.eigh`` (the primitive ``eigh``) are library calls on one
matrix; the lane engines (:mod:`.lanes`, and through it the fused and the native engine) hold every
array element as a separate lane vector or C variable, so there is no matrix to hand to a library.
For the sizes of a model's state (n <= ~6) the algorithms are short enough to write out: each
function below is plain JAX on statically indexed scalars (``a[i, j]``, ``jnp.where``), with no
loops left in its jaxpr, so the lane evaluator runs it with the elementwise rules it already has,
and both engines share this one implementation. :func:`expansion` traces a primitive's
replacement once per shape and parameters.

Why hand-written rather than vmapped LAPACK: a per-lane library call would leave the SIMD loop
(the native engine's whole point) and XLA:CPU's batched LAPACK calls do not fuse either. The cost
is O(n^3) scalar operations per call, unrolled: for n = 3 a solve is ~60 operations.

* :func:`lu`: Doolittle elimination with partial pivoting (the row of largest |a_ik|, the first
  on ties, as LAPACK's ``idamax``); the row exchange is a select per element (``jnp.where`` on the
  lane's pivot index), so every lane pivots on its own matrix. Same outputs as ``lax.linalg.lu``
  (packed factors, pivots, permutation); the factors agree with LAPACK's to rounding (LAPACK's
  blocked order of operations differs).
* :func:`triangular_solve`: forward or back substitution, in all four forms of the primitive
  (left/right side, transposed or not, unit diagonal or not).
* :func:`eigh`: cyclic Jacobi rotations with Rutishauser's update formulas, a fixed number of
  sweeps (:func:`jacobi_sweeps`), eigenvalues sorted ascending by a compare-and-swap network.
  Eigenvectors are unique only up to sign (and to a basis of a repeated eigenvalue's space): the
  signs here are Jacobi's, not LAPACK's, so a model should use them in sign-free forms
  (``V diag(f(w)) V^T``, projections), as it must for LAPACK's too.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

MAX_N = 12  # larger matrices are refused: the unrolled code grows as n^3 (n^3 * sweeps for eigh)


def _elems(x):
    """(n, m) array -> nested lists of 0-d arrays (static slices)."""
    return [[x[i, j] for j in range(x.shape[1])] for i in range(x.shape[0])]


def _batched(fn, *xs, core: int = 2):
    """Apply ``fn`` to every matrix of leading batch dimensions (the primitives accept a batch)."""
    batch = xs[0].shape[: xs[0].ndim - core]
    if not batch:
        return fn(*xs)
    outs = [fn(*(x[i] for x in xs)) for i in np.ndindex(batch)]
    if isinstance(outs[0], tuple):
        return tuple(jnp.stack(o).reshape(batch + o[0].shape) for o in zip(*outs))
    return jnp.stack(outs).reshape(batch + outs[0].shape)


# ---- LU with partial pivoting -----------------------------------------------------------------


def lu(x):
    """``lax.linalg.lu``: (lu, pivots, permutation) with P x = L U, L unit lower (packed below U)."""
    return _batched(_lu, x)


def _lu(x):
    m, n = x.shape
    a = _elems(x)
    k_max = min(m, n)
    perm = [jnp.int32(i) for i in range(m)]
    pivots = []
    for k in range(k_max):
        # pivot: the first row of largest |a_ik|, i >= k (LAPACK idamax)
        p, best = jnp.int32(k), jnp.abs(a[k][k])
        for i in range(k + 1, m):
            v = jnp.abs(a[i][k])
            better = v > best
            p = jnp.where(better, jnp.int32(i), p)
            best = jnp.where(better, v, best)
        pivots.append(p)
        # exchange rows k and p (p >= k), a select per element
        if k + 1 < m:
            hit = {i: p == i for i in range(k + 1, m)}
            row_k = list(a[k])
            new_k = list(a[k])
            for i in range(k + 1, m):
                new_k = [jnp.where(hit[i], a[i][j], new_k[j]) for j in range(n)]
                a[i] = [jnp.where(hit[i], row_k[j], a[i][j]) for j in range(n)]
            a[k] = new_k
            perm_k = perm[k]
            new_pk = perm_k
            for i in range(k + 1, m):
                new_pk = jnp.where(hit[i], perm[i], new_pk)
                perm[i] = jnp.where(hit[i], perm_k, perm[i])
            perm[k] = new_pk
        # eliminate below the pivot (a zero pivot gives inf/nan, as a singular matrix must)
        piv = a[k][k]
        for i in range(k + 1, m):
            l_ik = a[i][k] / piv
            a[i][k] = l_ik
            for j in range(k + 1, n):
                a[i][j] = a[i][j] - l_ik * a[k][j]
    return (jnp.stack([jnp.stack(r) for r in a]), jnp.stack(pivots).astype(jnp.int32),
            jnp.stack(perm).astype(jnp.int32))


def lu_pivots_to_permutation(pivots, *, permutation_size):
    """``lax.linalg.lu_pivots_to_permutation``: the row exchanges k <-> pivots[k] applied in order to
    0..m-1 (``jax.scipy.linalg.lu_solve`` needs it); each exchange a select per entry."""
    return _batched(functools.partial(_pivots_to_perm, m=permutation_size), pivots, core=1)


def _pivots_to_perm(pivots, *, m):
    perm = [jnp.int32(i) for i in range(m)]
    for k in range(pivots.shape[0]):
        p = pivots[k]
        old_k = perm[k]
        for i in range(k + 1, m):
            hit = p == i
            perm[k], perm[i] = jnp.where(hit, perm[i], perm[k]), jnp.where(hit, old_k, perm[i])
    return jnp.stack(perm).astype(jnp.int32)


# ---- Cholesky ------------------------------------------------------------------------------------


def cholesky(x, **_):
    """``lax.linalg.cholesky`` (lower): L L^T = x from the lower triangle; NaN where x is not
    positive definite (the square root of a negative number), as LAPACK's result in JAX."""
    return _batched(_cholesky, x)


def _cholesky(x):
    n = x.shape[0]
    a = _elems(x)
    zero = jnp.zeros((), x.dtype)
    l = [[zero] * n for _ in range(n)]
    for j in range(n):
        s = a[j][j]
        for k in range(j):
            s = s - l[j][k] * l[j][k]
        d = jnp.sqrt(s)
        l[j][j] = d
        for i in range(j + 1, n):
            s = a[i][j]
            for k in range(j):
                s = s - l[i][k] * l[j][k]
            l[i][j] = s / d
    return jnp.stack([jnp.stack(r) for r in l])


# ---- triangular solve ---------------------------------------------------------------------------


def triangular_solve(a, b, *, left_side=False, lower=False, transpose_a=False, conjugate_a=False,
                     unit_diagonal=False):
    """``lax.linalg.triangular_solve``: x with op(a) x = b (left_side) or x op(a) = b."""
    del conjugate_a  # real only (the lane engines hold float64)
    return _batched(functools.partial(_trsm, left_side=left_side, lower=lower, transpose_a=transpose_a,
                                      unit_diagonal=unit_diagonal), a, b)


def _trsm(a, b, *, left_side, lower, transpose_a, unit_diagonal):
    n = a.shape[0]
    t = _elems(a)
    # op(a): transposing swaps lower and upper
    if transpose_a:
        t = [[t[j][i] for j in range(n)] for i in range(n)]
        lower = not lower
    if not left_side:  # x op(a) = b  <=>  op(a)^T x^T = b^T
        t = [[t[j][i] for j in range(n)] for i in range(n)]
        lower = not lower
        rhs = _elems(b.T)
    else:
        rhs = _elems(b)
    k = len(rhs[0])
    x = [[None] * k for _ in range(n)]
    order = range(n) if lower else range(n - 1, -1, -1)
    for c in range(k):
        for i in order:
            s = rhs[i][c]
            for j in (range(i) if lower else range(i + 1, n)):
                s = s - t[i][j] * x[j][c]
            x[i][c] = s if unit_diagonal else s / t[i][i]
    out = jnp.stack([jnp.stack(r) for r in x])
    return out if left_side else out.T


# ---- symmetric eigenproblem: cyclic Jacobi -----------------------------------------------------


# sweeps of cyclic Jacobi by matrix size: see jacobi_sweeps
_SWEEPS = {2: 1, 3: 5, 4: 6, 5: 7, 6: 7, 7: 8, 8: 9}
MAX_EIGH_N = max(_SWEEPS)


def jacobi_sweeps(n: int) -> int:
    """Sweeps of cyclic Jacobi for an n x n symmetric matrix (n <= 8), enough for float64 accuracy.

    A 2 x 2 matrix is diagonalised by its one rotation. For n >= 3 cyclic Jacobi converges
    quadratically once the off-diagonal part is below the eigenvalue gaps (Henrici 1958;
    Wilkinson 1962, also for repeated eigenvalues: off(A_{k+1}) <= c off(A_k)^2 / gap): the sweep
    after the one that brings the relative residual ||A V - V diag(w)|| / ||A|| to 1e-8 brings it
    to rounding. Measured on 2000 random symmetric matrices per n and kind (uniform entries;
    spectra clustered as 1 + 1e-6 k, repeated, and graded over 1e-8..1), the worst residual reached
    rounding (< 1e-14; 4e-16..1e-15) after 4 sweeps for n = 3, 5 for n = 4, 6 for n = 5 and 6,
    7 for n = 7 and 8 for n = 8 (graded spectra are the slowest). The count is that plus one sweep
    of margin: a sweep after convergence changes only rounding, and by the quadratic rate one more
    sweep turns a residual of 1e-8 into 1e-16. tests/engines/test_constructs.py checks n = 2..6.
    """
    if n <= 1:
        return 0
    if n not in _SWEEPS:
        raise ValueError(f"eigh of a {n} x {n} matrix (unrolled Jacobi up to {MAX_EIGH_N})")
    return _SWEEPS[n]


def eigh(x, *, lower=True, sort_eigenvalues=True, subset_by_index=None, algorithm=None):
    """``lax.linalg.eigh``: (v, w) with x v = v diag(w), reading the ``lower`` (else upper) triangle."""
    del algorithm
    if subset_by_index not in (None, (0, x.shape[-1]), (0, -1)):
        raise NotImplementedError("eigh with subset_by_index")
    return _batched(functools.partial(_eigh, lower=lower, sort_eigenvalues=sort_eigenvalues), x)


def _eigh(x, *, lower, sort_eigenvalues):
    n = x.shape[0]
    e = _elems(x)
    a = [[e[max(i, j)][min(i, j)] if lower else e[min(i, j)][max(i, j)] for j in range(n)] for i in range(n)]
    one, zero = jnp.ones((), x.dtype), jnp.zeros((), x.dtype)
    v = [[one if i == j else zero for j in range(n)] for i in range(n)]
    for _ in range(jacobi_sweeps(n)):
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p][q]
                # rotation angle: tau = (a_qq - a_pp) / (2 a_pq), t = tan(theta), the smaller root
                # (Golub & Van Loan, Alg. 8.5.1); a_pq == 0: no rotation (t = 0)
                zero_pq = apq == 0
                tau = (a[q][q] - a[p][p]) / jnp.where(zero_pq, one, 2.0 * apq)
                t = jnp.where(tau >= 0, one, -one) / (jnp.abs(tau) + jnp.sqrt(1.0 + tau * tau))
                t = jnp.where(zero_pq, zero, t)  # |tau| > 1e154 also gives t = 0: a_pq negligible
                c = 1.0 / jnp.sqrt(1.0 + t * t)
                s = t * c
                # Rutishauser's updates: the diagonal from t * a_pq (no cancellation)
                app, aqq = a[p][p] - t * apq, a[q][q] + t * apq
                for r in range(n):
                    if r in (p, q):
                        continue
                    arp, arq = a[r][p], a[r][q]
                    a[r][p] = a[p][r] = c * arp - s * arq
                    a[r][q] = a[q][r] = s * arp + c * arq
                a[p][p], a[q][q] = app, aqq
                a[p][q] = a[q][p] = zero
                for r in range(n):
                    vrp, vrq = v[r][p], v[r][q]
                    v[r][p] = c * vrp - s * vrq
                    v[r][q] = s * vrp + c * vrq
    w = [a[i][i] for i in range(n)]
    cols = [[v[r][i] for r in range(n)] for i in range(n)]
    if sort_eigenvalues:  # ascending: odd-even transposition network, n rounds of compare-and-swap
        for rnd in range(n):
            for i in range(rnd % 2, n - 1, 2):
                swap = w[i + 1] < w[i]
                w[i], w[i + 1] = jnp.where(swap, w[i + 1], w[i]), jnp.where(swap, w[i], w[i + 1])
                cols[i], cols[i + 1] = ([jnp.where(swap, b, c) for b, c in zip(cols[i + 1], cols[i])],
                                        [jnp.where(swap, c, b) for b, c in zip(cols[i + 1], cols[i])])
    vmat = jnp.stack([jnp.stack(c) for c in cols], axis=1)
    return vmat, jnp.stack(w)


# ---- the primitives' replacements ----------------------------------------------------------------

_REPLACE = {"lu": lu, "lu_pivots_to_permutation": lu_pivots_to_permutation, "triangular_solve": triangular_solve,
            "eigh": eigh, "cholesky": cholesky}


def replaceable(name: str) -> bool:
    return name in _REPLACE


def expansion(name: str, params: dict, avals) -> jax.core.ClosedJaxpr:
    """The jaxpr of primitive ``name``'s unrolled replacement for inputs of these shapes and dtypes.

    Raises ``ValueError`` for a matrix over :data:`MAX_N` or a form without a replacement.
    """
    key = (name, tuple(sorted((k, _hashable(v)) for k, v in params.items())),
           tuple((tuple(a.shape), np.dtype(a.dtype).str) for a in avals))
    return _expansion(key, name, params, avals)


def _hashable(v):
    try:
        hash(v)
        return v
    except TypeError:
        return repr(v)


_CACHE: dict = {}  # expansion key -> ClosedJaxpr (a model has a handful of shapes)


def _expansion(key, name, params, avals):
    if key in _CACHE:
        return _CACHE[key]
    n = max(int(a.shape[-1]) for a in avals)
    if n > MAX_N:
        raise ValueError(f"{name} of a {n} x {n} matrix (unrolled up to {MAX_N})")
    if any(np.dtype(a.dtype).kind == "c" for a in avals):
        raise ValueError(f"{name} of a complex matrix")
    fn = functools.partial(_REPLACE[name], **params)
    try:
        closed = jax.make_jaxpr(fn)(*[jax.ShapeDtypeStruct(a.shape, a.dtype) for a in avals])
    except NotImplementedError as exc:
        raise ValueError(str(exc)) from None
    _CACHE[key] = closed
    return closed


__all__ = ["lu", "lu_pivots_to_permutation", "cholesky", "triangular_solve", "eigh", "jacobi_sweeps", "expansion", "replaceable", "MAX_N"]
