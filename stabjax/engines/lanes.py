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

The fused engine evaluates with :class:`Lanes` directly; the native engine subclasses it to
emit one line of C per scalar operation instead.
"""
from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

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


class NoRule(Exception):
    """A primitive (or a form of it) without a lane-wise rule; the message names it."""


_ELEMENTWISE = frozenset("""
add add_any sub mul div rem pow max min atan2 nextafter and or xor not neg sign floor ceil round is_finite
exp exp2 log log1p expm1 tanh logistic sin cos tan asin acos atan sinh cosh asinh acosh atanh sqrt
rsqrt cbrt integer_pow square abs eq ne lt le gt ge convert_element_type select_n clamp erf erfc
erf_inv lgamma digamma copy copy_p reduce_precision real imag conj shift_left shift_right_logical
shift_right_arithmetic population_count
""".split())

MAX_UNROLL = 64  # lax.scan / fori_loop steps unrolled by the lane engines (a longer loop goes to diffrax)
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
        if prim.name == "add_any":  # the sum of two tangents (JVPs, e.g. stabjax.lyapunov): an add
            prim = lax.add_p
        if all(is_const(e) for e in es):
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
        a = ins[0] if ins else None
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
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], p, eqn)]
        if name == "dynamic_slice":
            idx = ins[1:]
            if not all(is_const(i[()]) for i in idx):
                raise NoRule("dynamic_slice with lane-varying index")
            starts = [int(i[()]) for i in idx]
            starts = [min(max(s, 0), d - n) for s, d, n in zip(starts, a.shape, p["slice_sizes"])]
            return [a[tuple(slice(s, s + n) for s, n in zip(starts, p["slice_sizes"]))]]
        if name == "stop_gradient":  # no derivative is taken through a model: the identity (jnp.linalg.solve uses it)
            return [a]
        if name == "scan":  # a loop with a static trip count (lax.fori_loop with constant bounds, lax.scan): unrolled
            return self.scan(p, ins, out_avals)
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
        raise NoRule(name)

    def scan(self, p, ins, out_avals):
        """``lax.scan`` unrolled: the body evaluated ``length`` times on the lanes' expressions (consts, carry,
        the i-th slice of each scanned input), the per-step outputs stacked. Up to :data:`MAX_UNROLL` steps: a
        model's small loops (over bodies, modes, a fixed-point iteration), not a long time loop."""
        n_c, n_carry, length = p["num_consts"], p["num_carry"], int(p["length"])
        if length > MAX_UNROLL:
            raise NoRule(f"scan of {length} steps (loops of up to {MAX_UNROLL} are unrolled)")
        consts, carry, xs = ins[:n_c], list(ins[n_c:n_c + n_carry]), ins[n_c + n_carry:]
        steps = range(length - 1, -1, -1) if p["reverse"] else range(length)
        ys = {}
        for i in steps:
            outs = self.eval_closed(p["jaxpr"], [*consts, *carry, *[x[i, ...] for x in xs]])
            carry, ys[i] = list(outs[:n_carry]), outs[n_carry:]
        stacked = []
        for j, aval in enumerate(out_avals[n_carry:]):
            o = obj(aval.shape)
            for i in range(length):
                o[i, ...] = ys[i][j]
            stacked.append(o)
        return [*carry, *stacked]

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
