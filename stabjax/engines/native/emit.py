"""Native engine, code generation: a system's jaxprs as C (one line per scalar operation).

``system.rhs``, ``system.observe`` and the classifier fold :func:`stabjax.fold.verdict.update` are
traced once and evaluated by the lane-wise evaluator (:class:`stabjax.engines.lanes.Lanes`) with
every array element a C variable (:class:`CEmit`): slices, stacks and 3x3 products become
bookkeeping, each scalar operation one line of C. Parameters equal across the sweep are folded in
as constants (``pow(x, 0.5)`` becomes ``sqrt``); ``prepare`` and ``initial_state`` run on the host
(vmapped JAX), so any primitive is allowed there.

The constructs a right-hand side may use are those of the lane evaluator (the list in
:mod:`stabjax.engines.lanes`): loops with a trip count known when tracing are unrolled and
small dense linear algebra (``jnp.linalg.solve``, ``inv``, ``det``, ``eigh``, Cholesky) is
written out as scalar operations (:mod:`stabjax.engines.unrolled`), so it becomes straight-line C
in the SIMD loop like the rest of the model; a lane-dependent pivot or index is a select.
"""
from __future__ import annotations

import functools
import re
from typing import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ...fold import verdict as V
from ..base import Unsupported
from ..lanes import Lanes, NoRule, is_const, obj, obj0



class Sym:
    """A C variable (or load expression) holding one array element of a traced function."""

    __slots__ = ("name", "dtype")

    def __init__(self, name: str, dtype):
        self.name = name
        self.dtype = np.dtype(dtype)

    def __repr__(self):
        return f"Sym({self.name}, {self.dtype})"


def _check_dtype(dtype) -> np.dtype:
    dt = np.dtype(dtype)
    if dt == np.bool_ or dt.kind in "iu" or (dt.kind == "f" and dt.itemsize == 8):
        return dt
    raise NoRule(f"dtype {dt}")


def flit(x: float) -> str:
    x = float(x)
    if np.isnan(x):
        return "NAN"
    if np.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    return f"({x.hex()})"  # exact: C99 hexadecimal floating constant


def _lit(v, dtype) -> str:
    dt = _check_dtype(dtype)
    if dt == np.bool_:
        return "1.0" if bool(v) else "0.0"
    if dt.kind in "iu":
        return flit(float(int(v)))
    return flit(v)


_INFIX = {"add": "+", "add_any": "+", "sub": "-", "mul": "*"}  # add_any: a sum of tangents (JVP)
_CMP = {"eq": "==", "ne": "!=", "lt": "<", "le": "<=", "gt": ">", "ge": ">="}
_LIBM1 = {n: n for n in ("exp", "log", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh",
                         "acosh", "atanh", "sqrt", "cbrt", "log1p", "expm1", "exp2", "erf", "erfc", "floor", "ceil",
                         "lgamma")}
_IDENTITY = frozenset({"copy", "copy_p", "reduce_precision", "optimization_barrier"})


class CEmit(Lanes):
    """The lane-wise evaluator of :mod:`stabjax.engines.lanes`, emitting one line of C per scalar operation.

    Every value is a C ``double``: booleans are 0.0/1.0 and integers integral doubles (exact below
    2**53; the classifier's counters are far below). Why: GCC does not vectorise a loop that
    mixes boolean masks of different widths (int flags selected by double comparisons were
    left scalar), while a loop of doubles only becomes AVX-512 code throughout.
    """

    drop_zero_terms = True  # see Lanes.drop_zero_terms
    reciprocal = True  # x / d as x * (1 / d) for a variable d (see bind_elem); False: a true division

    def __init__(self, prefix="v"):
        super().__init__(1)
        self.lines: list[str] = []
        self.prefix = prefix
        self.n = 0
        self.recip: dict[str, Sym] = {}

    def new(self, dtype, expr: str) -> Sym:
        name = f"{self.prefix}{self.n}"
        self.n += 1
        self.lines.append(f"const double {name} = {expr};")
        return Sym(name, _check_dtype(dtype))

    def ref(self, e, dtype) -> str:
        if isinstance(e, Sym):
            return e.name
        return _lit(np.asarray(e).item(), dtype)

    def lift(self, e, dtype):
        return e

    def bind_elem(self, prim, params, es, in_dtypes):
        name = prim.name
        if all(is_const(e) for e in es):
            return super().bind_elem(prim, params, es, in_dtypes)
        if name in _IDENTITY:
            return es[0]
        if name == "select_n" and is_const(es[0]):
            return es[1 + int(es[0])]
        dt = _check_dtype(in_dtypes[0])
        r = [self.ref(e, d) for e, d in zip(es, in_dtypes)]
        fl = dt.kind == "f"
        boolean = dt == np.bool_
        if name in _INFIX and not boolean:
            return self.new(dt, f"{r[0]} {_INFIX[name]} {r[1]}")
        if name == "div":
            if fl and isinstance(es[1], Sym) and self.reciprocal:
                # one reciprocal per denominator (s/|s| divides three components by one norm): a
                # division costs ~8x a multiplication on AVX-512; x * (1/d) is within 1 ulp of x / d
                inv = self.recip.get(es[1].name)
                if inv is None:
                    inv = self.recip[es[1].name] = self.new(dt, f"1.0 / {r[1]}")
                return self.new(dt, f"{r[0]} * {inv.name}")
            return self.new(dt, f"{r[0]} / {r[1]}" if fl else f"trunc({r[0]} / {r[1]})")
        if name in _CMP:
            return self.new(np.bool_, f"({r[0]} {_CMP[name]} {r[1]}) ? 1.0 : 0.0")
        if name in ("max", "min"):
            op = ">" if name == "max" else "<"
            # XLA's max/min propagate NaN
            # One select. XLA's max/min propagate a NaN in either operand; this returns the NaN only
            # when it is the second one. Exact NaN propagation needs a second select on the same
            # value, which GCC 12 merges into an OR of masks and then leaves the whole loop
            # unvectorised (docs/performance.md). The classifier never sees NaN here (it
            # maps non-finite errors to inf first) and a NaN state fails the trajectory anyway.
            return self.new(dt, f"({r[0]} {op} {r[1]}) ? {r[0]} : {r[1]}")
        if name == "neg" and not boolean:
            return self.new(dt, f"-{r[0]}")
        if name == "abs":
            return self.new(dt, f"fabs({r[0]})")
        if name == "square":
            return self.new(dt, f"{r[0]} * {r[0]}")
        if name == "integer_pow":
            return self.int_pow(es[0], int(params["y"]), dt)
        if name == "pow":
            return self.pow_(es[0], es[1], r, in_dtypes)
        if name == "sign":
            return self.new(dt, f"{r[0]} > 0.0 ? 1.0 : ({r[0]} < 0.0 ? -1.0 : {r[0]})")
        if name == "is_finite":
            return self.new(np.bool_, f"isfinite({r[0]}) ? 1.0 : 0.0")
        if name == "rsqrt":
            return self.new(dt, f"1.0 / sqrt({r[0]})")
        if name == "logistic":
            return self.new(dt, f"1.0 / (1.0 + exp(-{r[0]}))")
        if name == "round":
            method = int(params.get("rounding_method", 0))
            return self.new(dt, f"{'round' if method == 0 else 'rint'}({r[0]})")
        if name == "atan2":
            return self.new(dt, f"atan2({r[0]}, {r[1]})")
        if name == "nextafter":
            return self.new(dt, f"nextafter({r[0]}, {r[1]})")
        if name == "rem":
            return self.new(dt, f"fmod({r[0]}, {r[1]})")
        if name in _LIBM1 and fl and not params.get("accuracy"):
            return self.new(dt, f"{_LIBM1[name]}({r[0]})")
        if boolean and name in ("and", "or", "xor", "not"):
            expr = {"and": lambda: f"{r[0]} * {r[1]}", "or": lambda: f"({r[0]} + {r[1]} > 0.0) ? 1.0 : 0.0",
                    "xor": lambda: f"({r[0]} != {r[1]}) ? 1.0 : 0.0", "not": lambda: f"1.0 - {r[0]}"}[name]()
            return self.new(dt, expr)
        if name == "convert_element_type":
            new = _check_dtype(params["new_dtype"])
            if new == np.bool_:
                return self.new(new, f"({r[0]} != 0.0) ? 1.0 : 0.0")
            if new.kind in "iu" and fl:
                return self.new(new, f"trunc({r[0]})")
            return Sym(es[0].name, new)  # bool/int -> float/int, float -> float: the same double
        if name == "select_n":
            cdt = _check_dtype(in_dtypes[1])
            cases = [self.ref(e, cdt) for e in es[1:]]
            if len(cases) == 2:
                return self.new(cdt, f"({r[0]} != 0.0) ? {cases[1]} : {cases[0]}")
            expr = cases[-1]
            for k in range(len(cases) - 2, -1, -1):
                expr = f"({r[0]} == {k}.0 ? {cases[k]} : {expr})"
            return self.new(cdt, expr)
        if name == "clamp":  # clamp(lo, x, hi)
            lo = self.bind_elem(jax.lax.max_p, {}, [es[1], es[0]], [in_dtypes[1], in_dtypes[0]])
            return self.bind_elem(jax.lax.min_p, {}, [lo, es[2]], [in_dtypes[1], in_dtypes[2]])
        raise NoRule(f"{name} on {dt}")

    def int_pow(self, x, n: int, dt):
        if n == 0:
            return np.asarray(1, dt)[()]
        base = x
        acc = None
        m = abs(n)
        while m:  # square and multiply
            if m & 1:
                acc = base if acc is None else self.new(dt, f"{acc.name} * {self.ref(base, dt)}")
            m >>= 1
            if m:
                base = self.new(dt, f"{self.ref(base, dt)} * {self.ref(base, dt)}")
        if n < 0:
            return self.new(dt, f"1.0 / {self.ref(acc, dt)}")
        return acc

    def pow_(self, x, y, r, dtypes):
        if is_const(y) and np.dtype(dtypes[0]).kind == "f":
            yv = float(y)
            if yv == 0.0:
                return np.asarray(1.0, dtypes[0])[()]
            if yv == 1.0:
                return x
            if yv == 0.5:
                return self.new(dtypes[0], f"sqrt({r[0]})")
            if abs(yv - 1.0 / 3.0) <= 1e-15:  # sigma - 1 with sigma = 4/3 is 1/3 - 1 ulp; cbrt is within rounding
                return self.new(dtypes[0], f"cbrt({r[0]})")
            if yv == -0.5:
                return self.new(dtypes[0], f"1.0 / sqrt({r[0]})")
            if yv == int(yv) and abs(yv) <= 4:
                return self.int_pow(x, int(yv), np.dtype(dtypes[0]))
        return self.new(dtypes[0], f"jpow({r[0]}, {r[1]})")

    def apply(self, eqn, ins):
        if eqn.primitive.name == "cond" and not is_const(ins[0][()]):
            branches = eqn.params["branches"]
            outs = [self.eval_closed(b, ins[1:]) for b in branches]
            top = float(len(branches) - 1)
            i0 = ins[0][()].name
            idx = self.new(np.int32, f"({i0} < 0.0) ? 0.0 : (({i0} > {top}) ? {top} : {i0})")
            res = []
            for j, v in enumerate(eqn.outvars):
                o = obj(v.aval.shape)
                for i in np.ndindex(v.aval.shape):
                    o[i] = self.bind_elem(jax.lax.select_n_p, {}, [idx] + [b[j][i] for b in outs],
                                          [np.int32] + [v.aval.dtype] * len(outs))
                res.append(o)
            return res
        return super().apply(eqn, ins)


def _inputs(emit: CEmit, shapes_dtypes, ptr: str, offset: int = 0):
    """Object arrays of loads ``ptr[k*S]`` (every element a double) and the next offset."""
    out = []
    k = offset
    for shape, dt in shapes_dtypes:
        o = obj(shape)
        for i in np.ndindex(shape):
            o[i] = emit.new(dt, f"{ptr}[{k}*S]")
            k += 1
        out.append(o)
    return out, k


def _store(emit: CEmit, outs, ptr: str, out_dtypes) -> int:
    k = 0
    for o, dt in zip(outs, out_dtypes):
        for i in np.ndindex(o.shape):
            emit.lines.append(f"{ptr}[{k}*S] = {emit.ref(o[i], dt)};")
            k += 1
    return k


def _function(name: str, body: list[str], params: str) -> str:
    lines = "\n    ".join(body)
    return (f"static inline __attribute__((always_inline)) void {name}({params}, const int S)\n"
            f"{{\n    {lines}\n}}\n")


_DEF = re.compile(r"const double (v\d+) = (.*);$")
_VAR = re.compile(r"\bv\d+\b")


def split_t(lines: list[str]):
    """Split a right-hand side into the part that depends on ``t`` and args only, and the rest.

    Tsit5's sixth stage and the next step's first (FSAL) one are both taken at ``t + h``, so the
    t-only part (in paper A ``cos(omega0 t**alpha)``: a log, an exp and a cos) is computed once
    for both. Returns ``(t_lines, frontier, y_lines)``: ``t_lines`` compute the t-only values
    that the rest reads (``frontier``) and store them as ``tv[k*S]``; ``y_lines`` load them and
    compute the derivative (they may still read ``t``, e.g. in a term ``t * y``). None when no
    such value exists (an autonomous system).
    """
    cls: dict[str, str] = {}
    defs = []
    for ln in lines:
        m = _DEF.match(ln)
        if m is None:  # a store of an output
            defs.append((None, ln))
            continue
        name, expr = m.groups()
        refs = _VAR.findall(expr)
        if "y[" in expr or any(cls[r] == "y" for r in refs):
            cls[name] = "y"
        elif re.search(r"\bt\b", expr) or any(cls[r] == "t" for r in refs):
            cls[name] = "t"
        else:
            cls[name] = "a"
        defs.append((name, ln))
    exprs = {name: _DEF.match(ln).group(2) for name, ln in defs if name is not None}
    t_side = {name for name, c in cls.items() if c != "y"}
    while True:
        frontier = []
        for name, ln in defs:
            if name is not None and cls[name] != "y":
                continue
            for r in _VAR.findall(ln if name is None else exprs[name]):
                if cls[r] == "t" and r not in frontier:
                    frontier.append(r)
        # GCC contracts a product (or a negated one) into the FMA of the sum that consumes it; a
        # product stored between the two parts would be rounded once more. Such values are
        # computed in the second part from their factors instead, so both forms are the same
        # arithmetic, bit for bit (tests/engines/test_native.py).
        fused = [v for v in frontier if re.fullmatch(r"-?\S+ \* \S+|-\S+", exprs[v])]
        if not fused:
            break
        for v in fused:
            cls[v] = "y"
    if not frontier:
        return None
    t_lines = [ln for name, ln in defs if name in t_side]
    t_lines += [f"tv[{k}*S] = {v};" for k, v in enumerate(frontier)]
    y_lines = [f"const double {v} = tv[{k}*S];" for k, v in enumerate(frontier)]
    y_lines += [ln for name, ln in defs if name is None or cls[name] != "t"]
    return t_lines, frontier, y_lines


# ==== the model ==================================================================================


class NativeModel:
    """C source of a system's rhs/observe and the classifier update, with the prepared-args layout.

    ``args`` are the outputs of ``system.prepare``: elements that are constants of the sweep are
    folded into the C code, the others ("dynamic slots") are computed on the host per
    trajectory and passed in.
    """

    def __init__(self, system, static: Mapping[str, np.ndarray], dyn_shapes: Mapping[str, tuple], vcfg, t_late,
                 fixed_point: tuple[float, float, float] | None = None, known=None):
        sds = jax.ShapeDtypeStruct
        f64 = jnp.float64
        self.system = system
        # (rtol, atol, t_window): also emit f_fp, the stop test of stabjax.fold.equilibrium
        self.fixed_point = fixed_point
        self.known = known  # stabjax.fold.stops.AttractorLayout: also emit f_at, the recurrence stop's test
        self.static = {k: np.asarray(v, np.float64) for k, v in static.items()}
        self.dyn_keys = sorted(dyn_shapes)
        self.dyn_shapes = {k: tuple(dyn_shapes[k]) for k in self.dyn_keys}
        st = self.static

        def full(pd):
            return {**st, **pd}

        self.full = full
        ex_pd = {k: sds(self.dyn_shapes[k], f64) for k in self.dyn_keys}
        ex_args = jax.eval_shape(lambda pd: system.prepare(full(pd)), ex_pd)
        self.n_state = system.state_size
        ex_t, ex_y = sds((), f64), sds((self.n_state,), f64)
        ex_obs = jax.eval_shape(system.observe, ex_t, ex_y, ex_args)
        self.n_obs = int(np.prod(ex_obs.shape))
        c0 = V.init(f64, vcfg)
        self.c_leaves, self.c_tree = jax.tree.flatten(c0)
        self.c_shapes = [(tuple(x.shape), np.dtype(x.dtype)) for x in self.c_leaves]
        self.n_c = sum(int(np.prod(s)) for s, _ in self.c_shapes)
        self.c0 = np.concatenate([np.asarray(x, np.float64).ravel() for x in self.c_leaves])
        args_leaves, self.args_tree = jax.tree.flatten(ex_args)
        self.args_shapes = [(tuple(x.shape), np.dtype(x.dtype)) for x in args_leaves]
        try:
            self._build(system, ex_pd, ex_t, ex_y, ex_args, ex_obs, c0, vcfg, float(t_late))
        except NoRule as exc:
            raise Unsupported(f"no C rule for {exc}") from None

    def _build(self, system, ex_pd, ex_t, ex_y, ex_args, ex_obs, c0, vcfg, t_late):
        full = self.full
        # -- which prepared-args elements are constants of the sweep (structure, not values) --
        closed = jax.make_jaxpr(lambda pd: system.prepare(full(pd)))(ex_pd)
        em = CEmit("p")
        try:
            ins, _ = _inputs(em, [(self.dyn_shapes[k], np.float64) for k in self.dyn_keys], "P")
            outs = em.eval_closed(closed, ins)
            template = []
            for o in outs:
                template.append([o[i] if is_const(o[i]) else None for i in np.ndindex(o.shape)])
        except NoRule:  # e.g. a decomposition without a rule (svd): every element is passed in
            template = [[None] * int(np.prod(s)) for s, _ in self.args_shapes]
        self.template = template
        self.dyn_slots = [(j, i) for j, t in enumerate(template) for i, e in enumerate(t) if e is None]
        self.n_args = len(self.dyn_slots)

        def args_objs(emit):
            out, k = [], 0
            for (shape, dt), tpl in zip(self.args_shapes, template):
                o = obj(shape)
                for flat, i in enumerate(np.ndindex(shape)):
                    if tpl[flat] is None:
                        o[i] = emit.new(dt, f"a[{k}*S]")
                        k += 1
                    else:
                        o[i] = tpl[flat]
                out.append(o)
            return out

        # -- rhs(t, y, a) -> dy --
        em = CEmit()
        y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
        outs = em.eval_closed(jax.make_jaxpr(system.rhs)(ex_t, ex_y, ex_args), [obj0(Sym("t", np.float64)), y[0]]
                              + args_objs(em))
        if outs[0].shape != (self.n_state,):
            raise NoRule(f"rhs output shape {outs[0].shape}")
        _store(em, outs, "out", [np.float64])
        rhs = _function("f_rhs", em.lines, "const double t, const double *restrict y, const double *restrict a, "
                                           "double *restrict out")
        split = split_t(em.lines)
        self.n_tv = 0 if split is None else len(split[1])
        if split is not None:
            rhs += "\n" + _function("f_rhs_t", split[0], "const double t, const double *restrict a, double *restrict tv")
            rhs += "\n" + _function("f_rhs_y", split[2], "const double t, const double *restrict tv, "
                                                         "const double *restrict y, const double *restrict a, "
                                                         "double *restrict out")
        # -- observe(t, y, a) -> obs --
        em = CEmit()
        y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
        outs = em.eval_closed(jax.make_jaxpr(system.observe)(ex_t, ex_y, ex_args),
                              [obj0(Sym("t", np.float64)), y[0]] + args_objs(em))
        _store(em, [o.reshape(-1) for o in outs], "out", [np.float64])
        obs = _function("f_obs", em.lines, "const double t, const double *restrict y, const double *restrict a, "
                                           "double *restrict out")
        # -- classifier update(c, t, obs) -> c --
        em = CEmit()
        c_in, _ = _inputs(em, self.c_shapes, "c")
        o_in, _ = _inputs(em, [((self.n_obs,), np.float64)], "o")
        upd_closed = jax.make_jaxpr(lambda c, t, o: V.update(c, t, o, vcfg, t_late))(c0, ex_t, ex_obs)
        outs = em.eval_closed(upd_closed, c_in + [obj0(Sym("t", np.float64)), o_in[0].reshape(ex_obs.shape)])
        _store(em, outs, "out", [d for _, d in self.c_shapes])
        upd = _function("f_upd", em.lines, "const double *restrict c, const double t, const double *restrict o, "
                                           "double *restrict out")
        self.functions = rhs + "\n" + obs + "\n" + upd
        if self.fixed_point is not None:
            # -- the fixed-point stop test (stabjax.fold.equilibrium.fixed_point_stop) -> out[0] = 1.0 / 0.0,
            #    out[1 .. n] = the equilibrium it reached
            from ...fold import equilibrium

            em = CEmit()
            y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
            rt, at, tw = self.fixed_point
            closed = jax.make_jaxpr(lambda t, yy, a: equilibrium.fixed_point_stop(system.rhs, t, yy, a, rt, at, tw))(
                ex_t, ex_y, ex_args)
            outs = em.eval_closed(closed, [obj0(Sym("t", np.float64)), y[0]] + args_objs(em))
            _store(em, [o.reshape(-1) for o in outs], "out", [np.bool_, np.float64])
            self.functions += "\n" + _function("f_fp", em.lines, "const double t, const double *restrict y, "
                                                "const double *restrict a, double *restrict out")
            # -- its cheap first question (stabjax.fold.equilibrium.near_stable) -> out[0] = 1.0 / 0.0 --
            em = CEmit()
            y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
            closed = jax.make_jaxpr(lambda t, yy, a: equilibrium.near_stable(system.rhs, t, yy, a, rt, at))(
                ex_t, ex_y, ex_args)
            outs = em.eval_closed(closed, [obj0(Sym("t", np.float64)), y[0]] + args_objs(em))
            _store(em, [o.reshape(-1) for o in outs], "out", [np.bool_])
            self.functions += "\n" + _function("f_fpre", em.lines, "const double t, const double *restrict y, "
                                                "const double *restrict a, double *restrict out")
        if self.known is not None:
            # -- the recurrence stop's test (stabjax.fold.stops.near_attractor_data) -> out[0] = k or -1.0; the
            #    clouds are data (kd: stabjax.fold.stops.attractor_data), so one kernel serves every set of
            #    this shape; a true division by the scale, as by the constants it replaces (bit for bit)
            from ...fold import stops

            sds, f64 = jax.ShapeDtypeStruct, jnp.float64
            em = CEmit()
            em.reciprocal = False
            y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
            K, P, n = self.known.shape
            data = []
            k = 0
            for shape in ((K, P, n), (n,), (K,)):
                o = obj(shape)
                for i in np.ndindex(shape):
                    o[i] = Sym(f"kd[{k}]", np.float64)
                    k += 1
                data.append(o)
            closed = jax.make_jaxpr(lambda t, yy, a, sp, sc, e2: stops.near_attractor_data(
                jnp.ravel(system.observe(t, yy, a)), sp, sc, e2))(
                ex_t, ex_y, ex_args, sds((K, P, n), f64), sds((n,), f64), sds((K,), f64))
            outs = em.eval_closed(closed, [obj0(Sym("t", np.float64)), y[0]] + args_objs(em) + data)
            _store(em, [o.reshape(-1) for o in outs], "out", [np.float64])
            self.functions += "\n" + _function("f_at", em.lines, "const double t, const double *restrict y, "
                                                "const double *restrict a, const double *restrict kd, "
                                                "double *restrict out")

    # -- host side ----------------------------------------------------------------------------
    @functools.cached_property
    def _host_prepare(self):
        system, full, slots = self.system, self.full, self.dyn_slots

        def one(pd, _):
            leaves = [jnp.ravel(x) for x in jax.tree.leaves(system.prepare(full(pd)))]
            a = [leaves[j][i] for j, i in slots]
            y0 = jnp.ravel(system.initial_state(full(pd)))
            return (jnp.stack(a) if a else jnp.zeros((1,))), y0

        return jax.jit(jax.vmap(one))

    def host_inputs(self, dyn: Mapping[str, np.ndarray], n: int):
        """(args (N, n_args), y0 (N, n_state)) in C order, computed with vmapped JAX."""
        a, y0 = self._host_prepare({k: jnp.asarray(dyn[k], jnp.float64) for k in self.dyn_keys}, jnp.zeros((n,)))
        return np.ascontiguousarray(np.asarray(a, np.float64)), np.ascontiguousarray(np.asarray(y0, np.float64))

    def c_tree_from(self, cout: np.ndarray):
        """(N, n_c) doubles -> the classifier state pytree, batch first."""
        leaves, k = [], 0
        n = cout.shape[0]
        for shape, dt in self.c_shapes:
            m = int(np.prod(shape))
            leaves.append(cout[:, k:k + m].reshape((n,) + shape).astype(dt))
            k += m
        return jax.tree.unflatten(self.c_tree, leaves)
