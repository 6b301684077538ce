"""Lane-wise evaluation: run a per-trajectory JAX function on rows of lanes (shared by the engines).

``jax.vmap`` of a per-trajectory model gives XLA arrays like (3, L) that it slices, stacks,
transposes and concatenates; on CPU the fusions built from those shuffle data and recompute
shared terms per output row (measured: ~190-300 ns per lane per right-hand-side evaluation of
the monoaxial model, docs/performance.md). Here the model's jaxpr is evaluated with every array
element held separately: an element is either a NumPy constant or a (L,) vector over lanes.
Slices, reshapes, stacks and small matrix products become bookkeeping on NumPy object arrays,
and XLA only ever sees elementwise operations on contiguous (L,) vectors, which it fuses into
SIMD loops. ``pow`` with a lane-varying exponent goes through exp/log (XLA's vectorised
kernels) instead of scalar libm calls. Any primitive without a rule raises :class:`NoRule`.

What a model may use (each rule is written once here, so the fused and the native engine take
the same constructs; tests/engines/test_constructs.py runs a one-line model of each):

* elementwise math, comparisons, ``where``/``select``, ``clip``, reductions, ``dot_general``
  (``@``, ``einsum``, ``cross``, ``norm``), slicing, reshapes, ``concatenate``/``stack``, ``pad``
  (``jnp.diag``), ``cumsum``/``cumprod``/``cummax``/``cummin``, ``argmax``/``argmin``;
* indexing: ``gather``/``dynamic_slice`` and ``scatter`` (``x.at[i].set/add/mul/min/max``), also
  with an index computed from the state (a select among the positions the index may take: the
  axes are small); ``sort`` (``jnp.sort``, ``argsort``, ``median``) by a sorting network;
* ``lax.cond`` (both branches evaluated, then selected per lane), ``lax.scan`` and
  ``lax.while_loop``/``fori_loop`` whose trip count is known when tracing (unrolled, up to
  :data:`MAX_UNROLL` iterations; a condition that depends on the state has no rule: lanes would
  need different trip counts);
* ``stop_gradient`` (the identity on values), ``custom_jvp``/``custom_vjp`` functions (their
  primal), ``custom_linear_solve`` (its forward solve);
* small dense linear algebra: ``lu``, ``triangular_solve``, ``cholesky`` and ``eigh`` are
  replaced by the unrolled scalar algorithms of :mod:`stabjax.engines.unrolled` (so
  ``jnp.linalg.solve``, ``inv``, ``det``, ``eigh``, ``eigvalsh``, ``jax.scipy.linalg.cho_solve``,
  ``lu_factor``/``lu_solve`` work; ``lu_pivots_to_permutation`` too) up to 12 x 12 (eigh: 8 x 8). They are hand-written because
  there is no matrix to give LAPACK: every element is its own lane vector or C variable, and a
  per-lane library call would leave the SIMD loop.

Not supported (the engine chain then falls back to diffrax with the reason in ``engine_note``):
loops whose trip count depends on the state, larger matrices, other decompositions (``svd``, ``qr``, general ``eig``), float32 or complex values
in the native engine.

The fused engine evaluates with :class:`Lanes` directly; the native engine subclasses it to
emit one line of C per scalar operation instead.

Length: about 785 lines, over the project's ~550-line guide, because this is one evaluator: the
rule table of :meth:`Lanes.apply` and the methods its rules share (gather, scatter, loops); split
across modules, the answer to "which primitives do the fast engines run" would be in several places.
The linear-algebra algorithms, which are separate JAX functions, live in :mod:`.unrolled`.

Size (~785 lines): one rule per JAX primitive, in one table (:class:`Lanes`), so that the fused and
the native engine take exactly the same constructs; a rule split from its table would be found by
neither engine's reader.
"""
from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from . import unrolled
from .vmath import SINCOS_LIMIT, fast_cos_small, fast_log, fast_sin_small

def materialize(x):
    """Store a lane vector once instead of letting XLA recompute it in every consumer.

    XLA:CPU fuses a cheap producer into *each* of its consumers; in a Runge-Kutta step, where
    every stage derivative feeds all later stages, the error estimate and the dense output,
    that duplicates the right-hand side many times over (measured: ~8x more arithmetic than
    the jaxpr holds). A division is "expensive" to XLA's fusion heuristics and is never
    duplicated, so ``x / one`` with a run-time ``one`` (exactly 1.0, an input of the compiled
    function so it cannot be constant-folded; see :func:`materializing`) makes ``x`` a
    materialised buffer. x / 1.0 == x exactly in IEEE arithmetic. ``optimization_barrier``
    does not survive XLA:CPU's pipeline. Outside :func:`materializing`, ``x`` is returned as is.
    """
    one = _ONE[-1] if _ONE else None
    if one is None or is_const(x) or x.dtype != one.dtype:
        return x
    return x / one


_ONE: list = []  # the run-time 1.0 of the loop being traced (a stack: traces may nest)


@contextlib.contextmanager
def materializing(one):
    """Within this block :func:`materialize` divides by ``one`` (a traced scalar equal to 1.0)."""
    _ONE.append(one)
    try:
        yield
    finally:
        _ONE.pop()


MAX_UNROLL = 1000  # iterations of one scan/while loop unrolled (the traced code grows with them)

# primitives that are the identity on values: stop_gradient only matters to differentiation
_IDENTITY_PRIMS = frozenset({"stop_gradient", "optimization_barrier"})


class NoRule(Exception):
    """A primitive (or a form of it) without a lane-wise rule; the message names it."""


_ELEMENTWISE = frozenset("""
add add_any sub mul div rem pow max min atan2 nextafter and or xor not neg sign floor ceil round is_finite
exp exp2 log log1p expm1 tanh logistic sin cos tan asin acos atan sinh cosh asinh acosh atanh sqrt
rsqrt cbrt integer_pow square abs eq ne lt le gt ge convert_element_type select_n clamp erf erfc
erf_inv lgamma digamma copy copy_p reduce_precision real imag conj shift_left shift_right_logical
shift_right_arithmetic population_count
""".split())

_REDUCE = {"reduce_sum": "add", "reduce_max": "max", "reduce_min": "min", "reduce_prod": "mul",
           "reduce_and": "and", "reduce_or": "or"}


def is_const(e) -> bool:
    return isinstance(e, (np.generic, np.ndarray))


def obj(shape):
    return np.empty(shape, dtype=object)


def rows_to_objs(shapes, rows):
    """Consecutive flat rows -> one object array per shape (the lane-wise evaluator's input)."""
    out, k = [], 0
    for shape in shapes:
        o = obj(shape)
        for j, i in enumerate(np.ndindex(shape)):
            o[i] = rows[k + j]
        out.append(o)
        k += int(np.prod(shape))
    return out


def const_array(x, dtype=None):
    x = np.asarray(x, dtype=dtype)
    out = obj(x.shape)
    for i in np.ndindex(x.shape):
        out[i] = x[i]  # NumPy scalar
    return out


# elementwise primitives whose float64 (and boolean) results IEEE 754 fixes to the last bit, so that NumPy folds
# constants exactly as XLA would (transcendental functions are left to XLA: libm and XLA may differ in a bit)
_NP_EXACT = {"add": np.add, "sub": np.subtract, "mul": np.multiply, "div": np.true_divide, "neg": np.negative,
             "max": np.maximum, "min": np.minimum, "abs": np.abs, "sqrt": np.sqrt,
             "eq": np.equal, "ne": np.not_equal, "lt": np.less, "le": np.less_equal, "gt": np.greater,
             "ge": np.greater_equal, "and": np.logical_and, "or": np.logical_or, "not": np.logical_not,
             "xor": np.logical_xor}


class Lanes:
    """Evaluator of closed jaxprs on object arrays whose elements are constants or (L,) vectors."""

    # In a dot product, drop the terms whose constant factor is exactly zero (the native emitter
    # turns this on: a diagonal gain matrix K then costs 3 products instead of 9). IEEE gives NaN
    # for 0 * inf, so the result differs only when the other factor is not finite; that factor is
    # a component of the state or of a value computed from it, which makes the derivative
    # non-finite elsewhere, so the step is rejected either way. (And in the sign of an exact zero.)
    drop_zero_terms = False

    def __init__(self, L: int):
        self.L = L

    # -- elements ---------------------------------------------------------------------------
    def lift(self, e, dtype):
        if is_const(e):
            return jnp.full((self.L,), np.asarray(e).astype(dtype))
        return e

    def bind_elem(self, prim, params, es, in_dtypes):
        if prim.name == "add_any":  # the sum of two tangents (JVPs, e.g. stabjax.model.tangent): an add
            prim = lax.add_p
        if all(is_const(e) for e in es):
            exact = _NP_EXACT.get(prim.name)
            if exact is not None and all(np.dtype(d) in (np.float64, np.bool_) for d in in_dtypes):
                # IEEE-exact operations on constants in NumPy: the value XLA gives, without an eager dispatch
                # (~6 ms each, 95 of them in the fixed-point stop's trace: half its code generation)
                with np.errstate(all="ignore"):
                    return np.asarray(exact(*[np.asarray(e, dtype=d) for e, d in zip(es, in_dtypes)]))[()]
            with jax.ensure_compile_time_eval():
                r = prim.bind(*[np.asarray(e, dtype=d) for e, d in zip(es, in_dtypes)], **params)
            return np.asarray(r)[()]
        f64 = all(d == np.float64 for d in in_dtypes)
        if prim.name == "pow" and f64:
            return self.pow(es[0], es[1], in_dtypes)
        if prim.name == "log" and f64 and not params.get("accuracy"):
            return fast_log(es[0])
        if prim.name in ("sin", "cos") and f64 and not params.get("accuracy"):
            return sincos(prim.name, es[0])
        if prim.name == "select_n" and is_const(es[0]):
            return es[1 + int(es[0])]
        return prim.bind(*[self.lift(e, d) for e, d in zip(es, in_dtypes)], **params)

    def pow(self, x, y, dtypes):
        """x ** y for float x, y as exp(y log|x|) with XLA's vectorised exp and :func:`fast_log`.

        IEEE special cases as in libm. Relative error about (4 + 2 |y ln x|) ulp: exp amplifies
        the rounding of y ln x (at most ~1.6e-13 for finite results, typically 1e-15).
        """
        if is_const(y):
            yv = float(y)
            if yv == 0.0:
                return np.asarray(1.0, dtype=dtypes[0])[()]
            if yv == 1.0:
                return x
            if yv == 0.5:
                return jnp.sqrt(x)
            if yv == int(yv) and abs(yv) <= 4:
                return lax.integer_pow(x, int(yv))
        x = self.lift(x, dtypes[0])
        y = self.lift(y, dtypes[1])
        r = jnp.exp(y * fast_log(jnp.abs(x)))
        yi = jnp.round(y)
        is_int = y == yi
        odd = is_int & (yi - 2.0 * jnp.floor(0.5 * yi) != 0)
        # IEEE 754 pow special cases (libm's): negative bases, zeros, infinities, NaNs
        r = jnp.where(x < 0, jnp.where(is_int | jnp.isinf(x), jnp.where(odd & ~jnp.isinf(y), -r, r), jnp.nan), r)
        r = jnp.where((x == -1) & jnp.isinf(y), 1.0, r)
        r = jnp.where(x == 0, jnp.where(y > 0, 0.0, jnp.where(y < 0, jnp.inf, jnp.where(y == 0, 1.0, jnp.nan))), r)
        return jnp.where((y == 0) | (x == 1), 1.0, r)

    def binop(self, name, a, b, dtype):
        prim = _PRIMS[name]
        return self.bind_elem(prim, {}, [a, b], [dtype, dtype])

    # -- primitives ---------------------------------------------------------------------------
    def eval_closed(self, closed, args):
        return self.eval_jaxpr(closed.jaxpr, closed.consts, args)

    def eval_jaxpr(self, jaxpr, consts, args):
        env = {}

        def read(v):
            if isinstance(v, _Literal):
                return const_array(v.val, v.aval.dtype)
            return env[v]

        for v, c in zip(jaxpr.constvars, consts):
            if isinstance(c, jax.core.Tracer):
                raise NoRule("traced constant")
            env[v] = const_array(np.asarray(c))
        for v, a in zip(jaxpr.invars, args):
            env[v] = a
        for eqn in jaxpr.eqns:
            ins = [read(v) for v in eqn.invars]
            outs = self.apply(eqn, ins)
            for v, o in zip(eqn.outvars, outs):
                if not isinstance(v, _DropVar):
                    env[v] = o
        return [read(v) for v in jaxpr.outvars]

    def apply(self, eqn, ins):
        name = eqn.primitive.name
        p = eqn.params
        out_avals = [v.aval for v in eqn.outvars]
        if name in _ELEMENTWISE:
            shape = out_avals[0].shape
            in_dtypes = [v.aval.dtype for v in eqn.invars]
            arrs = [np.broadcast_to(a, shape) for a in ins]
            out = obj(shape)
            for i in np.ndindex(shape):
                out[i] = self.bind_elem(eqn.primitive, p, [a[i] for a in arrs], in_dtypes)
            return [out]
        if name in ("jit", "pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
                    "custom_vjp_call", "custom_vjp_call_jaxpr"):
            sub = p.get("jaxpr", p.get("call_jaxpr", p.get("fun_jaxpr")))
            if sub is None:
                raise NoRule(name)
            if hasattr(sub, "consts"):
                return self.eval_closed(sub, ins[: len(sub.jaxpr.invars)])
            return self.eval_jaxpr(sub, (), ins[: len(sub.invars)])
        if name in _IDENTITY_PRIMS:
            return list(ins[: len(out_avals)])
        if name == "custom_linear_solve":  # the forward solve; the other jaxprs serve transposes/JVPs
            cl = p["const_lengths"]
            start = cl.matvec + cl.vecmat
            solve = p["jaxprs"].solve
            return self.eval_closed(solve, ins[start: start + cl.solve] + ins[sum(cl):])
        if unrolled.replaceable(name):
            try:
                sub = unrolled.expansion(name, p, [v.aval for v in eqn.invars])
            except ValueError as exc:
                raise NoRule(f"{name}: {exc}") from None
            return self.eval_closed(sub, ins)
        if name == "scan":
            return self.scan(eqn, ins)
        if name == "while":
            return self.while_loop(eqn, ins)
        a = ins[0] if ins else None
        if name == "gather":
            return [self.gather(a, ins[1], p, out_avals[0], eqn.invars[0].aval.dtype)]
        if name == "slice":
            strides = p["strides"] or (1,) * a.ndim
            return [a[tuple(slice(s, l, st) for s, l, st in zip(p["start_indices"], p["limit_indices"], strides))]]
        if name == "squeeze":
            return [np.squeeze(a, axis=tuple(p["dimensions"]))]
        if name == "reshape":
            if p.get("dimensions") not in (None, ()):
                raise NoRule("reshape with dimensions")
            return [a.reshape(tuple(p["new_sizes"]))]
        if name == "expand_dims":
            return [np.expand_dims(a, tuple(p["dimensions"]))]
        if name == "broadcast_in_dim":
            shape = tuple(p["shape"])
            expanded = [1] * len(shape)
            for src, dst in enumerate(p["broadcast_dimensions"]):
                expanded[dst] = a.shape[src]
            return [np.broadcast_to(a.reshape(expanded), shape)]
        if name == "transpose":
            return [np.transpose(a, tuple(p["permutation"]))]
        if name == "rev":
            return [np.flip(a, tuple(p["dimensions"]))]
        if name == "concatenate":
            return [np.concatenate(ins, axis=p["dimension"])]
        if name == "stack":
            return [np.stack(ins, axis=p["axis"])]
        if name == "split":
            cuts = np.cumsum(p["sizes"])[:-1]
            return list(np.split(a, cuts, axis=p["axis"]))
        if name == "iota":
            aval = out_avals[0]
            ar = np.arange(aval.shape[p["dimension"]], dtype=aval.dtype)
            shp = [1] * len(aval.shape)
            shp[p["dimension"]] = -1
            return [const_array(np.broadcast_to(ar.reshape(shp), aval.shape))]
        if name in _REDUCE:
            axes = tuple(p["axes"])
            keep = [d for d in range(a.ndim) if d not in axes]
            moved = np.transpose(a, keep + list(axes))
            out_shape = tuple(a.shape[d] for d in keep)
            flat = moved.reshape(out_shape + (-1,))
            dtype = eqn.invars[0].aval.dtype
            out = obj(out_shape)
            for i in np.ndindex(out_shape):
                acc = flat[i][0]
                for e in flat[i][1:]:
                    acc = self.binop(_REDUCE[name], acc, e, dtype)
                out[i] = acc
            return [out]
        if name in _SCATTER:
            return [self.scatter(a, ins[1], ins[2], p, _SCATTER[name], eqn.invars[0].aval.dtype)]
        if name == "sort":
            return self.sort(ins, p, [v.aval.dtype for v in eqn.invars])
        if name in _CUMULATIVE:
            return [self.cumulative(a, p, _CUMULATIVE[name], eqn.invars[0].aval.dtype)]
        if name in ("argmax", "argmin"):
            return [self.arg_best(a, p, name == "argmax", eqn)]
        if name == "pad":
            return [self.pad(a, ins[1][()], p["padding_config"])]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], p, eqn)]
        if name == "dynamic_slice":
            sizes = tuple(p["slice_sizes"])
            idx = [i[()] for i in ins[1:]]
            if all(is_const(i) for i in idx):
                starts = [min(max(int(s), 0), d - n) for s, d, n in zip(idx, a.shape, sizes)]
                return [a[tuple(slice(s, s + n) for s, n in zip(starts, sizes))]]
            # a lane-varying start (x[i] with i computed from the state): a select among the positions
            starts = [min(max(int(s), 0), d - n) if is_const(s) else 0 for s, d, n in zip(idx, a.shape, sizes)]
            varying = {d: s for d, s in enumerate(idx) if not is_const(s)}
            dtype = eqn.invars[0].aval.dtype
            out = obj(sizes)
            for i in np.ndindex(sizes):
                out[i] = self._gather_elem(a, starts, list(i), varying, sizes, False, None, dtype)
            return [out]
        if name == "cond":
            branches = p["branches"]
            index = ins[0][()]
            ops = ins[1:]
            if is_const(index):
                k = int(np.clip(int(index), 0, len(branches) - 1))
                return self.eval_closed(branches[k], ops)
            outs = [self.eval_closed(b, ops) for b in branches]
            idx = jnp.clip(index, 0, len(branches) - 1).astype(jnp.int32)
            res = []
            for j, aval in enumerate(out_avals):
                o = obj(aval.shape)
                for i in np.ndindex(aval.shape):
                    o[i] = lax.select_n(idx, *[self.lift(b[j][i], aval.dtype) for b in outs])
                res.append(o)
            return res
        if all(is_const(e) for x in ins for e in x.flat):  # any other primitive on constants: folded
            with jax.ensure_compile_time_eval():
                outs = eqn.primitive.bind(*[np.asarray(x.tolist(), dtype=v.aval.dtype).reshape(x.shape)
                                            for x, v in zip(ins, eqn.invars)], **p)
            return [const_array(np.asarray(o)) for o in (outs if eqn.primitive.multiple_results else [outs])]
        raise NoRule(name)

    def arg_best(self, a, p, is_max, eqn):
        """argmax/argmin along one axis: a running best and its index, by selects (the first on
        ties; a NaN counts as the best, as in JAX)."""
        (axis,) = p["axes"]
        dt, it = eqn.invars[0].aval.dtype, np.dtype(p["index_dtype"])
        moved = np.moveaxis(a, axis, -1)
        out = obj(moved.shape[:-1])
        cmp = lax.gt_p if is_max else lax.lt_p
        fl = np.dtype(dt).kind == "f"
        for i in np.ndindex(out.shape):
            best, idx = moved[i + (0,)], it.type(0)
            for k in range(1, moved.shape[-1]):
                v = moved[i + (k,)]
                better = self.bind_elem(cmp, {}, [v, best], [dt, dt])
                if fl:  # a NaN beats any number; the first NaN stays
                    v_nan = self.bind_elem(lax.ne_p, {}, [v, v], [dt, dt])
                    b_num = self.bind_elem(lax.eq_p, {}, [best, best], [dt, dt])
                    better = self.binop("or", better, self.binop("and", v_nan, b_num, np.bool_), np.bool_)
                best = self.bind_elem(lax.select_n_p, {}, [better, best, v], [np.bool_, dt, dt])
                idx = self.bind_elem(lax.select_n_p, {}, [better, idx, it.type(k)], [np.bool_, it, it])
            out[i] = idx
        return out

    def cumulative(self, a, p, op, dtype):
        """cumsum/cumprod/cummax/cummin along one axis, a running sum (product, ...)."""
        axis = p["axis"]
        moved = np.moveaxis(a, axis, -1).copy()
        n = moved.shape[-1]
        ks = range(n - 2, -1, -1) if p.get("reverse") else range(1, n)
        for i in np.ndindex(moved.shape[:-1]):
            for k in ks:
                prev = k + 1 if p.get("reverse") else k - 1
                moved[i + (k,)] = self.binop(op, moved[i + (prev,)], moved[i + (k,)], dtype)
        return np.moveaxis(moved, -1, axis)

    def scatter(self, operand, indices, updates, p, op, dtype):
        """XLA scatter (``x.at[i].set(v)``, ``.add``, ``.mul``, ``.min``, ``.max``). An index known when
        tracing writes one element; one computed from the state writes, at every position it may
        take, a select between the old and the new value."""
        dn = p["dimension_numbers"]
        if dn.operand_batching_dims:
            raise NoRule("scatter with batching dimensions")
        fill = "FILL" in str(p["mode"])
        out = operand.copy()
        window_dims = [d for d in range(operand.ndim) if d not in dn.inserted_window_dims]
        win_size = [1] * operand.ndim
        for w, ud in zip(window_dims, dn.update_window_dims):
            win_size[w] = updates.shape[ud]
        scatter_pos = [d for d in range(updates.ndim) if d not in dn.update_window_dims]
        i32 = np.dtype(np.int32)
        for ui in np.ndindex(updates.shape):
            g = tuple(ui[d] for d in scatter_pos)
            start = [0] * operand.ndim
            dropped = False
            varying = {}
            for k, d in enumerate(dn.scatter_dims_to_operand_dims):
                s, hi = indices[g + (k,)], operand.shape[d] - win_size[d]
                if not is_const(s):
                    s = self.bind_elem(lax.convert_element_type_p, {"new_dtype": i32, "weak_type": False,
                                                                    "sharding": None}, [s], [_aval_dtype(s)])
                    if not fill:  # clip: the index is clamped into range
                        s = self.binop("min", self.binop("max", s, np.int32(0), i32), np.int32(hi), i32)
                    varying[d] = s
                    continue
                s = int(s)
                if fill and not 0 <= s <= hi:
                    dropped = True
                start[d] = min(max(s, 0), hi)
            if dropped:
                continue
            offs = [0] * operand.ndim
            for w, ud in zip(window_dims, dn.update_window_dims):
                offs[w] = ui[ud]
            upd = updates[ui]
            dims = list(varying)
            for cand in np.ndindex(*[operand.shape[d] - win_size[d] + 1 for d in dims]):
                st = list(start)
                hit = None
                for d, c in zip(dims, cand):
                    st[d] = c
                    eq = self.bind_elem(lax.eq_p, {}, [varying[d], np.int32(c)], [i32, i32])
                    hit = eq if hit is None else self.binop("and", hit, eq, np.bool_)
                idx = tuple(a + b for a, b in zip(st, offs))
                new = upd if op is None else self.binop(op, out[idx], upd, dtype)
                out[idx] = new if hit is None else self.bind_elem(lax.select_n_p, {}, [hit, out[idx], new],
                                                                  [np.bool_, dtype, dtype])
        return out

    def sort(self, ins, p, dtypes):
        """lax.sort along one axis (``jnp.sort``, ``argsort``, ``median``): an odd-even transposition
        network, n rounds of compare-and-swap of neighbours, each swap a select (stable: equal
        keys never swap). Keys compare as JAX orders them, NaN last (-0.0 and 0.0 compare equal)."""
        dim, nk = p["dimension"], p["num_keys"]
        moved = [np.moveaxis(x, dim, -1).copy() for x in ins]
        n = moved[0].shape[-1]
        for line in np.ndindex(moved[0].shape[:-1]):
            cols = [[m[line + (j,)] for j in range(n)] for m in moved]
            for rnd in range(n):
                for j in range(rnd % 2, n - 1, 2):
                    swap = self._sort_less([c[j + 1] for c in cols[:nk]], [c[j] for c in cols[:nk]], dtypes[:nk])
                    for c, dt in zip(cols, dtypes):
                        a, b = c[j], c[j + 1]
                        c[j] = self.bind_elem(lax.select_n_p, {}, [swap, a, b], [np.bool_, dt, dt])
                        c[j + 1] = self.bind_elem(lax.select_n_p, {}, [swap, b, a], [np.bool_, dt, dt])
            for m, c in zip(moved, cols):
                for j in range(n):
                    m[line + (j,)] = c[j]
        return [np.moveaxis(m, -1, dim) for m in moved]

    def _sort_less(self, xs, ys, dtypes):
        """x < y lexicographically over the keys, NaN after every number."""
        less, equal = None, None
        for x, y, dt in zip(xs, ys, dtypes):
            lt = self.bind_elem(lax.lt_p, {}, [x, y], [dt, dt])
            eq = self.bind_elem(lax.eq_p, {}, [x, y], [dt, dt])
            if np.dtype(dt).kind == "f":
                x_nan = self.bind_elem(lax.ne_p, {}, [x, x], [dt, dt])
                y_nan = self.bind_elem(lax.ne_p, {}, [y, y], [dt, dt])
                x_num = self.bind_elem(lax.not_p, {}, [x_nan], [np.bool_])
                lt = self.binop("or", lt, self.binop("and", y_nan, x_num, np.bool_), np.bool_)
                eq = self.binop("or", eq, self.binop("and", x_nan, y_nan, np.bool_), np.bool_)
            term = lt if equal is None else self.binop("and", equal, lt, np.bool_)
            less = term if less is None else self.binop("or", less, term, np.bool_)
            equal = eq if equal is None else self.binop("and", equal, eq, np.bool_)
        return less

    def pad(self, a, value, config):
        """lax.pad with non-negative edge padding and interior padding (``jnp.diag`` uses it)."""
        if any(lo < 0 or hi < 0 for lo, hi, _ in config):
            raise NoRule("pad with negative padding")
        shape = tuple(lo + hi + n + max(n - 1, 0) * it for (lo, hi, it), n in zip(config, a.shape))
        out = obj(shape)
        for i in np.ndindex(shape):
            out[i] = value
        for i in np.ndindex(a.shape):
            out[tuple(lo + k * (it + 1) for (lo, _, it), k in zip(config, i))] = a[i]
        return out

    # -- loops with a trip count known when tracing: unrolled -----------------------------------
    def scan(self, eqn, ins):
        """``lax.scan`` (``fori_loop`` with constant bounds): the body evaluated ``length`` times."""
        p = eqn.params
        n_c, n_carry, length = p["num_consts"], p["num_carry"], int(p["length"])
        if length > MAX_UNROLL:
            raise NoRule(f"scan of length {length} (unrolled up to {MAX_UNROLL})")
        consts, carry, xs = ins[:n_c], list(ins[n_c:n_c + n_carry]), ins[n_c + n_carry:]
        ys = [None] * length
        for k in (range(length - 1, -1, -1) if p["reverse"] else range(length)):
            outs = self.eval_closed(p["jaxpr"], consts + carry + [x[k, ...] for x in xs])
            carry, ys[k] = list(outs[:n_carry]), outs[n_carry:]
        stacked = []
        for j, v in enumerate(eqn.outvars[n_carry:]):
            o = obj(v.aval.shape)
            for k in range(length):
                for i in np.ndindex(o.shape[1:]):
                    o[(k,) + i] = ys[k][j][i]
            stacked.append(o)
        return carry + stacked

    def while_loop(self, eqn, ins):
        """``lax.while_loop`` whose condition is a constant at every iteration (``fori_loop`` with
        bounds known when tracing): unrolled. A lane-varying condition has no rule."""
        p = eqn.params
        cc, bc = p["cond_nconsts"], p["body_nconsts"]
        cconsts, bconsts, carry = ins[:cc], ins[cc:cc + bc], list(ins[cc + bc:])
        for _ in range(MAX_UNROLL + 1):
            go = self.eval_closed(p["cond_jaxpr"], cconsts + carry)[0][()]
            if not is_const(go):
                raise NoRule("while loop with a lane-varying condition")
            if not bool(go):
                return carry
            carry = list(self.eval_closed(p["body_jaxpr"], bconsts + carry))
        raise NoRule(f"while loop of more than {MAX_UNROLL} iterations")

    # -- indexing --------------------------------------------------------------------------------
    def gather(self, operand, indices, p, out_aval, dtype):
        """XLA gather; a lane-varying start index selects among the (few) positions it may take."""
        dn = p["dimension_numbers"]
        if dn.operand_batching_dims:
            raise NoRule("gather with batching dimensions")
        sizes = tuple(p["slice_sizes"])
        mode = str(p["mode"])
        fill = "FILL" in mode
        offset_dims = tuple(dn.offset_dims)
        window = [d for d in range(operand.ndim) if d not in dn.collapsed_slice_dims]
        out_shape = tuple(out_aval.shape)
        batch_pos = [d for d in range(len(out_shape)) if d not in offset_dims]
        out = obj(out_shape)
        for oi in np.ndindex(out_shape):
            g = tuple(oi[d] for d in batch_pos)
            starts = [0] * operand.ndim
            varying = {}
            for k, d in enumerate(dn.start_index_map):
                s = indices[g + (k,)]
                hi = operand.shape[d] - sizes[d]
                if is_const(s):
                    s = int(s)
                    if fill and not 0 <= s <= hi:
                        starts = None
                        break
                    starts[d] = min(max(s, 0), hi)
                else:
                    varying[d] = s
            if starts is None:
                out[oi] = _fill_value(p.get("fill_value"), dtype)
                continue
            offs = [0] * operand.ndim
            for w, od in zip(window, offset_dims):
                offs[w] = oi[od]
            out[oi] = self._gather_elem(operand, starts, offs, varying, sizes, fill, p.get("fill_value"), dtype)
        return out

    def _gather_elem(self, operand, starts, offs, varying, sizes, fill, fill_value, dtype):
        if not varying:
            return operand[tuple(s + o for s, o in zip(starts, offs))]
        d, s = next(iter(varying.items()))
        rest = {k: v for k, v in varying.items() if k != d}
        hi = operand.shape[d] - sizes[d]
        cases = []
        for c in range(hi + 1):
            st = list(starts)
            st[d] = c
            cases.append(self._gather_elem(operand, st, offs, rest, sizes, fill, fill_value, dtype))
        sdt = _aval_dtype(s)
        i32 = self.bind_elem(lax.convert_element_type_p, {"new_dtype": np.dtype(np.int32), "weak_type": False,
                                                          "sharding": None}, [s], [sdt])
        k = self.binop("min", self.binop("max", i32, np.int32(0), np.int32), np.int32(hi), np.int32)
        r = cases[0] if hi == 0 else self.bind_elem(lax.select_n_p, {}, [k] + cases, [np.int32] + [dtype] * len(cases))
        if fill:  # an out-of-range start gives the fill value
            lo_ok = self.bind_elem(lax.ge_p, {}, [i32, np.int32(0)], [np.int32, np.int32])
            hi_ok = self.bind_elem(lax.le_p, {}, [i32, np.int32(hi)], [np.int32, np.int32])
            ok = self.binop("and", lo_ok, hi_ok, np.bool_)
            r = self.bind_elem(lax.select_n_p, {}, [ok, _fill_value(fill_value, dtype), r], [np.bool_, dtype, dtype])
        return r

    def dot_general(self, x, y, p, eqn):
        (lc, rc), (lb, rb) = p["dimension_numbers"]
        lf = [d for d in range(x.ndim) if d not in lc and d not in lb]
        rf = [d for d in range(y.ndim) if d not in rc and d not in rb]
        xt = np.transpose(x, list(lb) + lf + list(lc))
        yt = np.transpose(y, list(rb) + rf + list(rc))
        bshape = tuple(x.shape[d] for d in lb)
        xs = tuple(x.shape[d] for d in lf)
        ys = tuple(y.shape[d] for d in rf)
        kn = int(np.prod([x.shape[d] for d in lc])) if lc else 1
        xt = xt.reshape(bshape + xs + (kn,))
        yt = yt.reshape(bshape + ys + (kn,))
        dtype = eqn.outvars[0].aval.dtype
        out = obj(bshape + xs + ys)
        for b in np.ndindex(bshape):
            for i in np.ndindex(xs):
                for j in np.ndindex(ys):
                    acc = None
                    for k in range(kn):
                        xe, ye = xt[b + i + (k,)], yt[b + j + (k,)]
                        if self.drop_zero_terms and any(is_const(e) and e == 0 for e in (xe, ye)):
                            continue
                        term = self.binop("mul", xe, ye, dtype)
                        acc = term if acc is None else self.binop("add", acc, term, dtype)
                    out[b + i + j] = acc if acc is not None else np.zeros((), dtype)[()]
        return out


def _fill_value(fill_value, dtype):
    """JAX's fill for an out-of-range gather: NaN for floats, the minimum of signed integers, the
    maximum of unsigned ones, True for booleans (or the given ``fill_value``)."""
    dt = np.dtype(dtype)
    if fill_value is not None:
        return np.asarray(fill_value, dt)[()]
    if dt.kind == "f":
        return np.asarray(np.nan, dt)[()]
    if dt.kind == "i":
        return np.iinfo(dt).min
    if dt.kind == "u":
        return np.iinfo(dt).max
    return np.bool_(True)


def _aval_dtype(e):
    """dtype of a lane element: a NumPy constant, a JAX array or a native-engine symbol."""
    return np.dtype(e.dtype)


_SCATTER = {"scatter": None, "scatter-add": "add", "scatter_add": "add", "scatter-mul": "mul", "scatter_mul": "mul",
            "scatter-min": "min", "scatter_min": "min", "scatter-max": "max", "scatter_max": "max"}
_CUMULATIVE = {"cumsum": "add", "cumprod": "mul", "cummax": "max", "cummin": "min"}

_PRIMS = {"add": lax.add_p, "mul": lax.mul_p, "max": lax.max_p, "min": lax.min_p, "and": lax.and_p, "or": lax.or_p}
try:
    from jax.extend.core import Literal as _Literal, DropVar as _DropVar
except ImportError:  # older JAX
    from jax.core import Literal as _Literal, DropVar as _DropVar


def rows_of(x, L):
    """Batch-last array (*shape, L) -> object array ``shape`` of (L,) rows."""
    x = jnp.asarray(x)
    out = obj(x.shape[:-1])
    for i in np.ndindex(x.shape[:-1]):
        out[i] = x[i]
    return out


def unrows(o, L, dtype):
    """Object array of rows/constants -> batch-last array (*shape, L)."""
    if o.shape == ():
        e = o[()]
        return jnp.full((L,), np.asarray(e).astype(dtype)) if is_const(e) else e.astype(dtype)
    flat = [(jnp.full((L,), np.asarray(e).astype(dtype)) if is_const(e) else e.astype(dtype)) for e in o.ravel()]
    return jnp.stack(flat).reshape(*o.shape, L)


class LaneFn:
    """A per-trajectory function evaluated lane-wise on batch-last pytrees (see above)."""

    def __init__(self, fn, *example):
        self.closed = jax.make_jaxpr(fn)(*example)
        self.out_tree = jax.tree.structure(jax.eval_shape(fn, *example))
        self.in_avals = [v.aval for v in self.closed.jaxpr.invars]

    def rows_in(self, L, *args):
        leaves = jax.tree.leaves(args)
        return [rows_of(jnp.broadcast_to(x, (*aval.shape, L)) if jnp.ndim(x) == 0 else x, L)
                for x, aval in zip(leaves, self.in_avals)]

    def call_rows(self, L, rows):
        return Lanes(L).eval_closed(self.closed, rows)

    def __call__(self, L, *args):
        outs = self.call_rows(L, self.rows_in(L, *args))
        avals = [v.aval for v in self.closed.jaxpr.outvars]
        return jax.tree.unflatten(self.out_tree, [unrows(o, L, a.dtype) for o, a in zip(outs, avals)])


class RowSpec:
    """How a pytree of per-trajectory arrays maps to a flat list of (L,) lane rows."""

    def __init__(self, tree_example):
        leaves, self.treedef = jax.tree.flatten(tree_example)
        self.shapes = [tuple(x.shape) for x in leaves]  # per-trajectory shapes
        self.dtypes = [x.dtype for x in leaves]
        self.sizes = [int(np.prod(s)) for s in self.shapes]

    def objs(self, rows):
        """Flat rows -> one object array per leaf (the lane-wise evaluator's input)."""
        return rows_to_objs(self.shapes, rows)

    def tree(self, rows, L):
        """Flat rows -> pytree of batch-last arrays (L last)."""
        leaves, k = [], 0
        for shape, n, dt in zip(self.shapes, self.sizes, self.dtypes):
            part = [r.astype(dt) for r in rows[k:k + n]]
            leaves.append(part[0] if shape == () else jnp.stack(part).reshape(*shape, L))
            k += n
        return jax.tree.unflatten(self.treedef, leaves)


def flat_rows(objs, L, dtypes=None):
    """Object arrays -> flat list of (L,) rows (constants broadcast)."""
    out = []
    for j, o in enumerate(objs):
        dt = None if dtypes is None else dtypes[j]
        for i in np.ndindex(o.shape):
            e = o[i]
            if is_const(e):
                out.append(jnp.full((L,), np.asarray(e) if dt is None else np.asarray(e).astype(dt)))
            else:
                out.append(e if dt is None else e.astype(dt))
    return out


def obj1(rows):
    o = obj((len(rows),))
    for i, r in enumerate(rows):
        o[i] = r
    return o


def obj0(x):
    o = obj(())
    o[()] = x
    return o



def sincos(name, x):
    """sin/cos of a lane vector: the fast path unless some |x| is beyond the exact reduction."""
    fast = fast_sin_small if name == "sin" else fast_cos_small
    exact = jnp.sin if name == "sin" else jnp.cos
    return lax.cond(jnp.any(jnp.abs(x) > SINCOS_LIMIT), exact, fast, x)


__all__ = ["Lanes", "LaneFn", "RowSpec", "NoRule", "materialize", "materializing", "is_const", "obj", "obj0", "obj1",
           "const_array", "rows_to_objs", "rows_of", "unrows", "flat_rows", "sincos"]
