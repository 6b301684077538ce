"""Native CPU sweep engine: the model's jaxprs translated to C, one SIMD Tsit5 loop per core.

Why (measurements in ``benchmarks/NOTES.md``): the fused XLA engine (:mod:`stabjax.fast`)
reached ~5% of the CPU's float64 peak because XLA:CPU splits one Runge-Kutta step into ~400
fusions that pass every intermediate through memory, and calls scalar libm for sin, cos,
log, pow and atan2. Here the same per-trajectory functions are compiled by a C compiler into
one loop that keeps a whole step in registers:

* **Code generation from jaxprs.** ``system.rhs``, ``system.observe`` and the classifier fold
  :func:`stabjax.verdict.update` are traced once and evaluated by the lane-wise evaluator of
  :mod:`stabjax.fast` with every array element a C variable (:class:`_CEmit`): slices,
  stacks and 3x3 products become bookkeeping, each scalar operation one line of C.
  Parameters equal across the sweep are folded in as constants (``pow(x, 0.5)`` becomes
  ``sqrt``); ``prepare`` and ``initial_state`` run on the host (vmapped JAX), so any primitive
  is allowed there.
* **SIMD over trajectories.** ``W`` trajectories are stepped side by side in
  structure-of-arrays blocks; every stage is an ``omp simd`` loop over the block, and glibc's
  vector math library (libmvec) supplies AVX-512 exp, log, sin, cos, pow and atan2.
  Each lane has its own time, step size, checkpoint index and classifier state; a lane whose
  trajectory finished is refilled at once from a queue shared by all threads (an atomic
  counter), so no lane idles until the queue runs dry.
* **The method is diffrax's** (as in :mod:`stabjax.fast`): Tsit5 with diffrax's tableau,
  error norm, I-controller defaults, Hairer's initial step and last-step clipping. Unlike the
  fused engine a step may contain any number of checkpoints (each from the dense output), so
  the step sequence is the one ``diffeqsolve`` takes with ``SaveAt(t1=True)`` (up to rounding:
  the sixth stage is taken at the step's end time, where diffrax computes ``t + 1.0 * h``, and
  libmvec's last bits differ from XLA's).
* **Checkpoints.** Each lane's first checkpoint of a step is interpolated and observed in lane
  layout; later ones of the same step become items observed in SIMD batches over items; the
  observables wait in per-lane FIFOs for vectorised classifier passes (benchmarks/NOTES.md N5,
  N14, N17).
* **Threads.** One call of the compiled function per core from Python threads (ctypes
  releases the GIL); the calls share the queue, a progress counter and a stop flag (Ctrl-C
  stops every thread after its current step).

The compiled library is cached by a hash of its source, the compiler flags and the CPU
(``$STABJAX_CACHE_DIR``, default ``~/.cache/stabjax``). Without a working C compiler, or for
a system whose right-hand side uses a primitive without a C rule, :func:`solve` raises
:class:`Unsupported` and :func:`stabjax.engine.solve_batch` uses the fused or diffrax path.
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Iterable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from . import fast
from . import verdict as V
from .fast import _A, _C, _E, FACTORMAX, FACTORMIN, SAFETY, STATUS_MAX_STEPS, STATUS_OK

SUPPORTED_SOLVERS = ("tsit5",)
DEFAULT_WIDTH = int(os.environ.get("STABJAX_NATIVE_WIDTH", "16"))  # lanes per SIMD block


class Unsupported(fast.Unsupported):
    """The native engine cannot run this system/config (no compiler, a primitive without a C rule)."""


# ==== C expressions ===========================================================================


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
    raise fast._Unsupported(f"dtype {dt}")


def _flit(x: float) -> str:
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
        return _flit(float(int(v)))
    return _flit(v)


_INFIX = {"add": "+", "sub": "-", "mul": "*"}
_CMP = {"eq": "==", "ne": "!=", "lt": "<", "le": "<=", "gt": ">", "ge": ">="}
_LIBM1 = {n: n for n in ("exp", "log", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh",
                         "acosh", "atanh", "sqrt", "cbrt", "log1p", "expm1", "exp2", "erf", "erfc", "floor", "ceil",
                         "lgamma")}
_IDENTITY = frozenset({"copy", "copy_p", "reduce_precision", "optimization_barrier"})
# libm functions for which glibc's libmvec has x86-64 vector variants (declared ``omp declare simd``)
_VECTOR_LIBM = ("exp", "log", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh",
                "atanh", "cbrt", "log1p", "expm1", "exp2", "erf", "pow:2", "atan2:2")
# (rint, floor, ceil, trunc, fabs, sqrt are single instructions: no declaration needed)


class _CEmit(fast._Lanes):
    """The lane-wise evaluator of :mod:`stabjax.fast`, emitting one line of C per scalar operation.

    Every value is a C ``double``: booleans are 0.0/1.0 and integers integral doubles (exact below
    2**53; the classifier's counters are far below). Why: GCC does not vectorise a loop that
    mixes boolean masks of different widths (int flags selected by double comparisons were
    left scalar), while a loop of doubles only becomes AVX-512 code throughout.
    """

    drop_zero_terms = True  # see fast._Lanes

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
        if all(fast._is_const(e) for e in es):
            return super().bind_elem(prim, params, es, in_dtypes)
        if name in _IDENTITY:
            return es[0]
        if name == "select_n" and fast._is_const(es[0]):
            return es[1 + int(es[0])]
        dt = _check_dtype(in_dtypes[0])
        r = [self.ref(e, d) for e, d in zip(es, in_dtypes)]
        fl = dt.kind == "f"
        boolean = dt == np.bool_
        if name in _INFIX and not boolean:
            return self.new(dt, f"{r[0]} {_INFIX[name]} {r[1]}")
        if name == "div":
            if fl and isinstance(es[1], Sym):
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
            # unvectorised (benchmarks/NOTES.md, N2). The classifier never sees NaN here (it
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
        raise fast._Unsupported(f"{name} on {dt}")

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
        if fast._is_const(y) and np.dtype(dtypes[0]).kind == "f":
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
        if eqn.primitive.name == "cond" and not fast._is_const(ins[0][()]):
            branches = eqn.params["branches"]
            outs = [self.eval_closed(b, ins[1:]) for b in branches]
            top = float(len(branches) - 1)
            i0 = ins[0][()].name
            idx = self.new(np.int32, f"({i0} < 0.0) ? 0.0 : (({i0} > {top}) ? {top} : {i0})")
            res = []
            for j, v in enumerate(eqn.outvars):
                o = fast._obj(v.aval.shape)
                for i in np.ndindex(v.aval.shape):
                    o[i] = self.bind_elem(jax.lax.select_n_p, {}, [idx] + [b[j][i] for b in outs],
                                          [np.int32] + [v.aval.dtype] * len(outs))
                res.append(o)
            return res
        return super().apply(eqn, ins)


def _inputs(emit: _CEmit, shapes_dtypes, ptr: str, offset: int = 0):
    """Object arrays of loads ``ptr[k*S]`` (every element a double) and the next offset."""
    out = []
    k = offset
    for shape, dt in shapes_dtypes:
        o = fast._obj(shape)
        for i in np.ndindex(shape):
            o[i] = emit.new(dt, f"{ptr}[{k}*S]")
            k += 1
        out.append(o)
    return out, k


def _store(emit: _CEmit, outs, ptr: str, out_dtypes) -> int:
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


def _split_t(lines: list[str]):
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
        # arithmetic, bit for bit (tests/test_native.py).
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


class _NativeModel:
    """C source of a system's rhs/observe and the classifier update, with the prepared-args layout.

    ``args`` are the outputs of ``system.prepare``: elements that are constants of the sweep are
    folded into the C code, the others ("dynamic slots") are computed on the host per
    trajectory and passed in.
    """

    def __init__(self, system, static: Mapping[str, np.ndarray], dyn_shapes: Mapping[str, tuple], vcfg, t_late):
        sds = jax.ShapeDtypeStruct
        f64 = jnp.float64
        self.system = system
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
        c0 = V.init_for(vcfg, self.n_obs, f64)
        self.c_leaves, self.c_tree = jax.tree.flatten(c0)
        self.c_shapes = [(tuple(x.shape), np.dtype(x.dtype)) for x in self.c_leaves]
        self.n_c = sum(int(np.prod(s)) for s, _ in self.c_shapes)
        self.c0 = np.concatenate([np.asarray(x, np.float64).ravel() for x in self.c_leaves])
        args_leaves, self.args_tree = jax.tree.flatten(ex_args)
        self.args_shapes = [(tuple(x.shape), np.dtype(x.dtype)) for x in args_leaves]
        try:
            self._build(system, ex_pd, ex_t, ex_y, ex_args, ex_obs, c0, vcfg, float(t_late))
        except fast._Unsupported as exc:
            raise Unsupported(f"no C rule for {exc}") from None

    def _build(self, system, ex_pd, ex_t, ex_y, ex_args, ex_obs, c0, vcfg, t_late):
        full = self.full
        # -- which prepared-args elements are constants of the sweep (structure, not values) --
        closed = jax.make_jaxpr(lambda pd: system.prepare(full(pd)))(ex_pd)
        em = _CEmit("p")
        try:
            ins, _ = _inputs(em, [(self.dyn_shapes[k], np.float64) for k in self.dyn_keys], "P")
            outs = em.eval_closed(closed, ins)
            template = []
            for o in outs:
                template.append([o[i] if fast._is_const(o[i]) else None for i in np.ndindex(o.shape)])
        except fast._Unsupported:  # e.g. a matrix inverse: every element is passed in
            template = [[None] * int(np.prod(s)) for s, _ in self.args_shapes]
        self.template = template
        self.dyn_slots = [(j, i) for j, t in enumerate(template) for i, e in enumerate(t) if e is None]
        self.n_args = len(self.dyn_slots)

        def args_objs(emit):
            out, k = [], 0
            for (shape, dt), tpl in zip(self.args_shapes, template):
                o = fast._obj(shape)
                for flat, i in enumerate(np.ndindex(shape)):
                    if tpl[flat] is None:
                        o[i] = emit.new(dt, f"a[{k}*S]")
                        k += 1
                    else:
                        o[i] = tpl[flat]
                out.append(o)
            return out

        # -- rhs(t, y, a) -> dy --
        em = _CEmit()
        y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
        outs = em.eval_closed(jax.make_jaxpr(system.rhs)(ex_t, ex_y, ex_args), [fast._obj0(Sym("t", np.float64)), y[0]]
                              + args_objs(em))
        if outs[0].shape != (self.n_state,):
            raise fast._Unsupported(f"rhs output shape {outs[0].shape}")
        _store(em, outs, "out", [np.float64])
        rhs = _function("f_rhs", em.lines, "const double t, const double *restrict y, const double *restrict a, "
                                           "double *restrict out")
        split = _split_t(em.lines)
        self.n_tv = 0 if split is None else len(split[1])
        if split is not None:
            rhs += "\n" + _function("f_rhs_t", split[0], "const double t, const double *restrict a, double *restrict tv")
            rhs += "\n" + _function("f_rhs_y", split[2], "const double t, const double *restrict tv, "
                                                         "const double *restrict y, const double *restrict a, "
                                                         "double *restrict out")
        # -- observe(t, y, a) -> obs --
        em = _CEmit()
        y, _ = _inputs(em, [((self.n_state,), np.float64)], "y")
        outs = em.eval_closed(jax.make_jaxpr(system.observe)(ex_t, ex_y, ex_args),
                              [fast._obj0(Sym("t", np.float64)), y[0]] + args_objs(em))
        _store(em, [o.reshape(-1) for o in outs], "out", [np.float64])
        obs = _function("f_obs", em.lines, "const double t, const double *restrict y, const double *restrict a, "
                                           "double *restrict out")
        # -- classifier update(c, t, obs) -> c --
        em = _CEmit()
        c_in, _ = _inputs(em, self.c_shapes, "c")
        o_in, _ = _inputs(em, [((self.n_obs,), np.float64)], "o")
        upd_closed = jax.make_jaxpr(lambda c, t, o: V.update(c, t, o, vcfg, t_late))(c0, ex_t, ex_obs)
        outs = em.eval_closed(upd_closed, c_in + [fast._obj0(Sym("t", np.float64)), o_in[0].reshape(ex_obs.shape)])
        _store(em, outs, "out", [d for _, d in self.c_shapes])
        upd = _function("f_upd", em.lines, "const double *restrict c, const double t, const double *restrict o, "
                                           "double *restrict out")
        self.functions = rhs + "\n" + obs + "\n" + upd

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


# ==== the kernel ==================================================================================

_HEADER = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__x86_64__) && defined(STABJAX_LIBMVEC)
/* glibc's libmvec: vector variants the vectoriser may call inside "omp simd" loops */
%(decls)s
#endif
"""


def _vector_decls() -> str:
    out = []
    for spec in _VECTOR_LIBM:
        name, _, n = spec.partition(":")
        args = ", ".join(["double"] * int(n or 1))
        out.append(f"#pragma omp declare simd notinbranch\ndouble {name}({args});")
    return "\n".join(out)


def _coef(x) -> str:
    return _flit(x)


def _unrolled(n: int, line: Callable[[int], str]) -> str:
    """``n`` statements, unrolled here: GCC does not vectorise a loop over lanes that still holds
    an inner loop (measured: the error estimate and classifier loops stayed scalar)."""
    return "\n            ".join(line(q) for q in range(n))


def _kernel_source(model: _NativeModel, W: int) -> str:
    NS, NA, NC, NO = model.n_state, max(model.n_args, 1), model.n_c, max(model.n_obs, 1)
    stage_loops = []
    # The sixth stage and the next step's first are both at t + h: the t-only part of the
    # right-hand side (paper A: cos(omega0 t**alpha), a log, an exp and a cos) is computed once for
    # both, at TN (diffrax takes the sixth at t + 1.0 * h, which can differ from TN in the last bit)
    share = model.n_tv > 0 and _C[4] == 1.0 and _C[5] == 1.0
    # stages 2..6 of Tsit5 (FSAL: K0 = f(t, y)); stage i uses row _A[i-1] and node _C[i-1]
    for i in range(1, 6):
        row = _A[i - 1]
        body = _unrolled(NS, lambda q: f"YT[{q} * W + l] = Y[{q} * W + l] + h * ("
                         + " + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(row) if c != 0.0) + ");")
        pre = ""
        call = f"f_rhs(T[l] + {_coef(_C[i - 1])} * H[l], YT + l, A + l, KS[{i}] + l, W);"
        if share and i == 5:
            pre = """
        #pragma omp simd
        for (int l = 0; l < W; l++) f_rhs_t(TN[l], A + l, TV + l, W);"""
            call = f"f_rhs_y(TN[l], TV + l, YT + l, A + l, KS[{i}] + l, W);"
        stage_loops.append(f"""{pre}
        #pragma omp simd
        for (int l = 0; l < W; l++) {{
            const double h = H[l];
            {body}
        }}
        #pragma omp simd
        for (int l = 0; l < W; l++) {call}""")
    last_call = ("f_rhs_y(TN[l], TV + l, YN + l, A + l, KS[6] + l, W)" if share
                 else "f_rhs(TN[l], YN + l, A + l, KS[6] + l, W)")
    row = _A[5]
    new_body = _unrolled(NS, lambda q: f"YN[{q} * W + l] = Y[{q} * W + l] + h * ("
                         + " + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(row) if c != 0.0) + ");")
    probe = " + ".join(f"(YN[{q} * W + l] - YN[{q} * W + l])" for q in range(NS))
    fin_probe = " + ".join(f"(KS[0][{q} * W + l] - KS[0][{q} * W + l])" for q in range(NS))
    err_body = _unrolled(NS, lambda q: f"""{{
                double e = h * ({" + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(_E) if c != 0.0)});
                e = e != e ? INFINITY : e;
                const double y0 = Y[{q} * W + l], y1 = bad_new != 0.0 ? y0 : YN[{q} * W + l];
                const double ysc = fabs(y0) > fabs(y1) ? fabs(y0) : fabs(y1);
                const double r = e / (atol + ysc * rtol);
                s += r * r;
            }}""")
    interp_body = _unrolled(NS, lambda q: f"PYT[{q} * NI + i] = Y[{q} * W + L] + h * (" + " + ".join(
        f"b{j + 1} * KS[{j}][{q} * W + L]" for j in range(7)) + ");")
    pack_a_body = _unrolled(model.n_args, lambda q: f"PA[{q} * NI + i] = A[{q} * W + L];")
    interp0_body = _unrolled(NS, lambda q: f"PY0[{q} * W + l] = Y[{q} * W + l] + h * (" + " + ".join(
        f"b{j + 1} * KS[{j}][{q} * W + l]" for j in range(7)) + ");")
    # Tsit5's dense-output weights b_j(theta) (diffrax's Tsit5Interpolation)
    bpoly = """const double th2 = th * th;
            const double b1 = -1.0530884977290216 * th * (th - 1.3299890189751412) * (th2 - 1.4364028541716351 * th + 0.7139816917074209);
            const double b2 = 0.1017 * th2 * (th2 - 2.1966568338249754 * th + 1.2949852507374631);
            const double b3 = 2.490627285651252793 * th2 * (th2 - 2.38535645472061657 * th + 1.57803468208092486);
            const double b4 = -16.54810288924490272 * (th - 1.21712927295533244) * (th - 0.61620406037800089) * th2;
            const double b5 = 47.37952196281928122 * (th - 1.203071208372362603) * (th - 0.658047292653547382) * th2;
            const double b6 = -34.87065786149660974 * (th - 1.2) * (th - 0.666666666666666667) * th2;
            const double b7 = 2.5 * (th - 1) * (th - 0.6) * th2;"""
    cmix_body = _unrolled(model.n_c, lambda q: f"C[{q} * W + l] = has != 0.0 ? CN[{q} * W + l] : C[{q} * W + l];")
    commit_body = _unrolled(NS, lambda q: f"Y[{q} * W + l] = kp != 0.0 ? YN[{q} * W + l] : Y[{q} * W + l]; "
                                          f"KS[0][{q} * W + l] = kp != 0.0 ? KS[6][{q} * W + l] : KS[0][{q} * W + l];")
    decls = _vector_decls()
    src = (_HEADER % {"decls": decls}) + f"""
#define W {W}
#define NS {NS}
#define NA {NA}
#define NC {NC}
#define NO {NO}
#define NTV {max(model.n_tv, 1)}  /* t-only values of the rhs shared by the sixth and seventh stage */
#define ALIGN __attribute__((aligned(64)))
#define NI (4 * W)      /* checkpoint items observed together */
#define QCAP 256        /* FIFO capacity per lane; a full FIFO is drained one item at a time (DRAIN_ONE) */
#define QLONG 240       /* extra classifier passes in a step while some FIFO is longer than this */
#define QBUSY (3 * W / 4) /* a classifier pass runs only while this many lanes have an item waiting */

/* x**y as exp(y log|x|) with libm's special cases for y = 0 and negative x (glibc's vector pow is
   ~2x the cost of exp + log; measured). Relative error about (2 + |y log x|) ulp. */
static inline double jpow(const double x, const double y) {{
    const double r = exp(y * log(fabs(x)));
    const double yi = rint(y);
    const double half = 0.5 * yi;
    const double sgn = rint(half) != half ? -1.0 : 1.0;
    const double neg = y == yi ? sgn * r : NAN;
    const double r1 = x < 0.0 ? neg : r;
    return y == 0.0 ? 1.0 : r1;
}}

{model.functions}

static inline int finite_row(const double *x) {{
    int ok = 1;
    for (int q = 0; q < NS; q++) ok &= isfinite(x[q * W]);
    return ok;
}}

typedef struct {{
    int64_t n, K, max_steps;
    double t0, t1, t1_floor, rtol, atol, dt0;
    const double *ain, *y0in, *c0, *ts;
    double *cout, *yout;
    int32_t *nacc_out, *nrej_out, *status_out;
    int64_t *next, *ndone;
    volatile int32_t *stop;
}} job_t;

static inline double rms_scaled(const double *v, const double *scale) {{
    double s = 0.0;
    for (int q = 0; q < NS; q++) {{ const double r = v[q * W] / scale[q]; s += r * r; }}
    return sqrt(s / NS);
}}

/* diffrax _select_initial_step (Hairer, Norsett & Wanner II.4) for lane l */
static double initial_step(const job_t *jb, double *Y, double *F, double *YT, double *F1, double *A, int l) {{
    if (jb->dt0 > 0) return jb->dt0;
    double scale[NS];
    for (int q = 0; q < NS; q++) scale[q] = jb->atol + fabs(Y[q * W + l]) * jb->rtol;
    const double d0 = rms_scaled(Y + l, scale), d1 = rms_scaled(F + l, scale);
    const int small = (d0 < 1e-5) | (d1 < 1e-5);
    const double h0 = small ? 1e-6 : 0.01 * (d0 / d1);
    for (int q = 0; q < NS; q++) YT[q * W + l] = Y[q * W + l] + h0 * F[q * W + l];
    f_rhs(jb->t0 + h0, YT + l, A + l, F1 + l, W);
    double s = 0.0;
    for (int q = 0; q < NS; q++) {{ const double r = (F1[q * W + l] - F[q * W + l]) / scale[q]; s += r * r; }}
    const double d2 = sqrt(s / NS) / h0;
    const double max_d = d1 > d2 ? d1 : d2;
    const double h1 = max_d <= 1e-15 ? (h0 * 1e-3 > 1e-6 ? h0 * 1e-3 : 1e-6) : exp(log(0.01 / max_d) / 5.0);
    return 100 * h0 < h1 ? 100 * h0 : h1;
}}

int64_t stabjax_run(const job_t *jb) {{
    /* per-lane flags and counters are doubles too (see _CEmit): every simd loop is pure V8DF */
    double Y[NS * W] ALIGN, KS[7][NS * W] ALIGN, YT[NS * W] ALIGN, YN[NS * W] ALIGN, A[NA * W] ALIGN, C[NC * W] ALIGN,
        CN[NC * W] ALIGN, OBS[NO * W] ALIGN, T[W] ALIGN, TN[W] ALIGN, H[W] ALIGN, TP[W] ALIGN, TNX[W] ALIGN, TC[W] ALIGN,
        NACC[W] ALIGN, NREJ[W] ALIGN, KEEP[W] ALIGN, HAS[W] ALIGN, ACT[W] ALIGN, TV[NTV * W] ALIGN;
    int64_t CK[W] ALIGN, IDX[W] ALIGN;
    /* checkpoint items of one step, and each lane's FIFO of observed checkpoints (time, observables) */
    double IT_[NI] ALIGN, PYT[NS * NI] ALIGN, PA[NA * NI] ALIGN, POBS[NO * NI] ALIGN;
    /* round 0: each lane's first checkpoint in a step (time of its next checkpoint, whether it has
       one in this step, its time, state and observables) */
    double NEXTT[W] ALIGN, R0[W] ALIGN, TC0[W] ALIGN, PY0[NS * W] ALIGN, OB0[NO * W] ALIGN;
    int IL[NI] ALIGN;
    static __thread double FT[W * QCAP], FO[W * QCAP * NO];
    int QH[W], QN[W];
    const int64_t n = jb->n, K = jb->K;
    const double *ts = jb->ts;
    const double t0 = jb->t0, t1 = jb->t1, t1_floor = jb->t1_floor, rtol = jb->rtol, atol = jb->atol;
    int64_t finished = 0;
    const double max_steps_d = (double)jb->max_steps;
    memset(Y, 0, sizeof Y); memset(KS, 0, sizeof KS); memset(A, 0, sizeof A); memset(C, 0, sizeof C);
    memset(T, 0, sizeof T); memset(TN, 0, sizeof TN);

#define REFILL(l) do {{ \\
        const int64_t j_ = __atomic_fetch_add(jb->next, 1, __ATOMIC_RELAXED); \\
        if (j_ < n) {{ \\
            IDX[l] = j_; ACT[l] = 1.0; \\
            for (int q = 0; q < NA; q++) A[q * W + (l)] = jb->ain[j_ * NA + q]; \\
            for (int q = 0; q < NS; q++) Y[q * W + (l)] = jb->y0in[j_ * NS + q]; \\
            for (int q = 0; q < NC; q++) C[q * W + (l)] = jb->c0[q]; \\
            T[l] = t0; CK[l] = 0; NEXTT[l] = ts[0]; NACC[l] = 0; NREJ[l] = 0; QH[l] = 0; QN[l] = 0; \\
            f_rhs(t0, Y + (l), A + (l), KS[0] + (l), W); \\
            const double h_ = initial_step(jb, Y, KS[0], YT, KS[1], A, (l)); \\
            double tn_ = t0 + h_ < t1 ? t0 + h_ : t1; \\
            TN[l] = tn_ > t1_floor ? t1 : tn_; \\
        }} else {{ IDX[l] = -1; ACT[l] = 0.0; NEXTT[l] = INFINITY; }} \\
    }} while (0)

/* one item of lane L through the same vector code as a classifier pass (the scalar build of f_upd
   calls scalar libm, whose last bit may differ: results would depend on which lanes shared a block) */
#define DRAIN_ONE(L) do {{ \\
        const int p_ = QH[L]; \\
        for (int l_ = 0; l_ < W; l_++) TC[l_] = T[l_];  /* other lanes: computed, discarded */ \\
        TC[L] = FT[(L) * QCAP + p_]; \\
        for (int q = 0; q < NO; q++) OBS[q * W + (L)] = FO[((L) * QCAP + p_) * NO + q]; \\
        _Pragma("omp simd") \\
        for (int l = 0; l < W; l++) f_upd(C + l, TC[l], OBS + l, CN + l, W); \\
        for (int q = 0; q < NC; q++) C[q * W + (L)] = CN[q * W + (L)]; \\
        QH[L] = (p_ + 1) % QCAP; QN[L]--; \\
    }} while (0)

/* append an observed checkpoint (time TT, observables OO[q * STRIDE]) to lane L's FIFO */
#define PUSH(L, TT, OO, STRIDE) do {{ \\
        if (QN[L] == QCAP) DRAIN_ONE(L); \\
        const int pos_ = (QH[L] + QN[L]) % QCAP; \\
        FT[(L) * QCAP + pos_] = (TT); \\
        for (int q = 0; q < NO; q++) FO[((L) * QCAP + pos_) * NO + q] = (OO)[q * (STRIDE)]; \\
        QN[L]++; \\
    }} while (0)

    for (int l = 0; l < W; l++) {{ QH[l] = 0; QN[l] = 0; }}
    int n_active = 0;
    for (int l = 0; l < W; l++) {{ REFILL(l); n_active += ACT[l] != 0.0; }}

    while (n_active > 0) {{
        if (*jb->stop) break;
        #pragma omp simd
        for (int l = 0; l < W; l++) H[l] = TN[l] - T[l];
        {"".join(stage_loops)}
        #pragma omp simd
        for (int l = 0; l < W; l++) {{
            const double h = H[l];
            {new_body}
        }}
        #pragma omp simd
        for (int l = 0; l < W; l++) {last_call};

        /* error estimate and diffrax's PIDController (I-controller defaults) */
        #pragma omp simd
        for (int l = 0; l < W; l++) {{
            const double h = H[l];
            /* NaN when a component of y1 is NaN or infinite (diffrax: NaN only; either way the step is
               rejected); arithmetic, not a chain of selects, so that GCC vectorises the loop */
            const double probe = {probe};
            const double bad_new = probe != probe ? 1.0 : 0.0;
            double s = 0.0;
            {err_body}
            const double err = sqrt(s / NS);
            const double kp = err < 1.0 ? 1.0 : 0.0;
            double fac = {_coef(SAFETY)} * exp(-0.2 * log(err));
            const double lo = kp != 0.0 ? 1.0 : {_coef(FACTORMIN)}, hi = kp != 0.0 ? {_coef(FACTORMAX)} : {_coef(SAFETY)};
            /* err is in [0, inf] (NaN errors became inf above), so fac is never NaN: plain clip */
            fac = fac > lo ? fac : lo;
            fac = fac < hi ? fac : hi;
            const double dt = h * fac;
            double tp = kp != 0.0 ? TN[l] : T[l];
            tp = tp < t1 ? tp : t1;
            double tnx = tp + dt;
            const double t_end = kp != 0.0 ? t1 : tp + 0.5 * (t1 - tp);
            tnx = tnx > t1_floor ? t_end : tnx;
            KEEP[l] = kp * ACT[l]; TP[l] = tp; TNX[l] = tnx;
        }}

        /* Checkpoints inside an accepted step. Observing (dense output + observe) needs this step's
           stages, folding into the classifier needs the previous checkpoint's state. So every
           checkpoint of every lane becomes an item, observed in SIMD batches over items (a lane that
           crosses 20 checkpoints in one step costs 20 items, not 20 passes over all lanes), and its
           observables wait in the lane's FIFO; one vectorised classifier pass per step pops one item
           per lane (more passes while a FIFO is long). Measured before: 2.9 masked passes over 16
           lanes per step, 4 lanes busy in each. */
        /* Round 0: the first checkpoint of each lane in this step, observed in lane layout. Most
           steps that cross a checkpoint cross exactly one (N = 1024: 1.15 M of 2.05 M items came
           one per lane-step, 0.49 M two), and an item costs 7 * NS gathered loads in the item batches
           below; here the same arithmetic reads the lane's own slots. Same formulas, same vector
           code: the items' values do not depend on which path observed them. */
        double any0 = 0.0;
        #pragma omp simd reduction(max:any0)
        for (int l = 0; l < W; l++) {{
            const double r0 = KEEP[l] != 0.0 ? (NEXTT[l] <= TN[l] ? 1.0 : 0.0) : 0.0;
            const double tc = r0 != 0.0 ? NEXTT[l] : T[l];
            const double h = H[l];
            const double th = h > 0 ? (tc - T[l]) / h : 0.0;
            {bpoly}
            {interp0_body}
            R0[l] = r0; TC0[l] = tc;
            any0 = r0 > any0 ? r0 : any0;
        }}
        if (any0 != 0.0) {{
            #pragma omp simd
            for (int l = 0; l < W; l++) f_obs(TC0[l], PY0 + l, A + l, OB0 + l, W);
            for (int l = 0; l < W; l++) {{
                if (R0[l] == 0.0) continue;
                PUSH(l, TC0[l], OB0 + l, W);
                CK[l]++;
                NEXTT[l] = CK[l] < K ? ts[CK[l]] : INFINITY;
            }}
        }}
        double more = 0.0;
        #pragma omp simd reduction(max:more)
        for (int l = 0; l < W; l++) {{
            const double mo = KEEP[l] != 0.0 ? (NEXTT[l] <= TN[l] ? 1.0 : 0.0) : 0.0;
            more = mo > more ? mo : more;
        }}
        if (more != 0.0) {{
            int l0 = 0;
            for (;;) {{
                int m = 0;
                for (; l0 < W && m < NI; l0++) {{
                    if (KEEP[l0] == 0.0 || NEXTT[l0] > TN[l0]) continue;
                    while (CK[l0] < K && ts[CK[l0]] <= TN[l0] && m < NI) {{ IL[m] = l0; IT_[m] = ts[CK[l0]]; CK[l0]++; m++; }}
                    NEXTT[l0] = CK[l0] < K ? ts[CK[l0]] : INFINITY;
                    if (NEXTT[l0] <= TN[l0]) break;  /* item buffer full: this lane again */
                }}
                if (m == 0) break;
                /* pad the batch to whole 8-wide vectors with copies of its last item (observed, never
                   queued): every item then takes the vector path, whose atan2 may differ from the
                   scalar epilogue's in the last bit, and results do not depend on how items fell
                   into batches (that is, on thread scheduling) */
                const int mv = ((m + 7) & ~7) < NI ? ((m + 7) & ~7) : NI;
                for (int i = m; i < mv; i++) {{ IL[i] = IL[m - 1]; IT_[i] = IT_[m - 1]; }}
                #pragma omp simd
                for (int i = 0; i < mv; i++) {{
                    const int L = IL[i];
                    const double h = H[L];
                    const double th = h > 0 ? (IT_[i] - T[L]) / h : 0.0;
                    {bpoly}
                    {interp_body}
                    {pack_a_body}
                }}
                #pragma omp simd
                for (int i = 0; i < mv; i++) f_obs(IT_[i], PYT + i, PA + i, POBS + i, NI);
                for (int i = 0; i < m; i++) PUSH(IL[i], IT_[i], POBS + i, NI);
            }}
        }}
        /* Classifier passes pop one item per lane. A lane early in its trajectory queues hundreds of
           checkpoints while the others queue none, so passing whenever any item waits left 2 of 3
           lanes idle (385k passes for 2.05M items at N = 1024). Items now wait until most lanes
           have one (or a FIFO is long); a lane's FIFO is drained before it is written out, so the
           per-lane sequence of updates, and every result, is unchanged (NOTES.md N14). */
        for (;;) {{
            int busy = 0, qmax = 0;
            for (int l = 0; l < W; l++) {{ busy += QN[l] > 0; qmax = QN[l] > qmax ? QN[l] : qmax; }}
            if (busy == 0 || (busy < QBUSY && qmax <= QLONG)) break;
            int any = 0;
            for (int l = 0; l < W; l++) {{
                if (QN[l] > 0) {{
                    const int pos = QH[l];
                    HAS[l] = 1.0; TC[l] = FT[l * QCAP + pos];
                    for (int q = 0; q < NO; q++) OBS[q * W + l] = FO[(l * QCAP + pos) * NO + q];
                    QH[l] = (pos + 1) % QCAP; QN[l]--; any = 1;
                }} else {{
                    HAS[l] = 0.0; TC[l] = T[l];
                }}
            }}
            if (!any) break;
            #pragma omp simd
            for (int l = 0; l < W; l++) f_upd(C + l, TC[l], OBS + l, CN + l, W);
            #pragma omp simd
            for (int l = 0; l < W; l++) {{
                const double has = HAS[l];
                {cmix_body}
            }}
        }}

        /* commit */
        #pragma omp simd
        for (int l = 0; l < W; l++) {{
            const double kp = KEEP[l], stepped = H[l] > 0.0 ? ACT[l] : 0.0;
            NACC[l] += stepped * kp;
            NREJ[l] += stepped * (1.0 - kp);
            {commit_body}
            T[l] = TP[l]; TN[l] = TNX[l];
        }}

        /* finished or stuck lanes: write out, refill from the queue. A lane finishes once in
           thousands of steps; a vector test of a superset of the condition skips the scalar loop
           (-10% median wall in 10 interleaved pairs, NOTES.md N15) */
        double cand = 0.0;
        #pragma omp simd reduction(max:cand)
        for (int l = 0; l < W; l++) {{
            const double probe = {fin_probe};  /* NaN iff some component of f is not finite */
            const double c1 = T[l] >= t1 ? 1.0 : 0.0, c2 = NACC[l] + NREJ[l] >= max_steps_d ? 1.0 : 0.0;
            const double c = c1 + c2 + (probe != probe ? 1.0 : 0.0) > 0.0 ? ACT[l] : 0.0;
            cand = c > cand ? c : cand;
        }}
        if (cand != 0.0) for (int l = 0; l < W; l++) {{
            if (ACT[l] == 0.0) continue;
            const int reached = (T[l] >= t1) & (CK[l] >= K);
            const int stuck = !reached & ((NACC[l] + NREJ[l] >= max_steps_d) | !finite_row(KS[0] + l));
            if (!(reached | stuck)) continue;
            const int64_t j = IDX[l];
            while (QN[l] > 0) DRAIN_ONE(l);
            for (int q = 0; q < NC; q++) jb->cout[j * NC + q] = C[q * W + l];
            for (int q = 0; q < NS; q++) jb->yout[j * NS + q] = Y[q * W + l];
            jb->nacc_out[j] = (int32_t)NACC[l]; jb->nrej_out[j] = (int32_t)NREJ[l];
            jb->status_out[j] = reached ? {STATUS_OK} : {STATUS_MAX_STEPS};
            __atomic_fetch_add(jb->ndone, 1, __ATOMIC_RELAXED);
            finished++;
            REFILL(l);
            n_active += (ACT[l] != 0.0) - 1;
        }}
    }}
    return finished;
}}

/* one trajectory's rhs, observables and classifier update at stride 1 (tests compare them with JAX) */
void stabjax_eval(const double t, const double *y, const double *a, double *dy, double *obs) {{
    f_rhs(t, y, a, dy, 1);
    f_obs(t, y, a, obs, 1);
}}

/* the rhs as the loop takes it at t + h: t-only part and the rest (tests: equal to f_rhs bit for bit) */
void stabjax_eval_split(const double t, const double *y, const double *a, double *dy) {{
    {"double tv[NTV]; f_rhs_t(t, a, tv, 1); f_rhs_y(t, tv, y, a, dy, 1);" if model.n_tv else "f_rhs(t, y, a, dy, 1);"}
}}

void stabjax_update(const double *c, const double t, const double *o, double *out) {{
    f_upd(c, t, o, out, 1);
}}
"""
    return src


def _eval_only(src: str) -> str:
    """The kernel source without the integration loop (tests of the translation compile faster)."""
    i = src.index("typedef struct {")
    j = src.index("/* one trajectory's rhs")
    return src[:i] + "int64_t stabjax_run(const void *jb) { return -1; }\n\n" + src[j:]


# ==== compiling and loading ==================================================================


class _Job(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int64), ("K", ctypes.c_int64), ("max_steps", ctypes.c_int64),
                ("t0", ctypes.c_double), ("t1", ctypes.c_double), ("t1_floor", ctypes.c_double),
                ("rtol", ctypes.c_double), ("atol", ctypes.c_double), ("dt0", ctypes.c_double),
                ("ain", ctypes.c_void_p), ("y0in", ctypes.c_void_p), ("c0", ctypes.c_void_p), ("ts", ctypes.c_void_p),
                ("cout", ctypes.c_void_p), ("yout", ctypes.c_void_p),
                ("nacc_out", ctypes.c_void_p), ("nrej_out", ctypes.c_void_p), ("status_out", ctypes.c_void_p),
                ("next", ctypes.c_void_p), ("ndone", ctypes.c_void_p), ("stop", ctypes.c_void_p)]


def compiler() -> str | None:
    """The C compiler to use ($CC, else cc/gcc on PATH), or None."""
    for cand in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cand and shutil.which(cand):
            return shutil.which(cand)
    return None


@functools.lru_cache(maxsize=4)
def _is_gcc(cc: str | None) -> bool:
    if cc is None:
        return False
    try:
        return "Free Software Foundation" in subprocess.run([cc, "--version"], capture_output=True, text=True).stdout
    except OSError:
        return False


def _flag_sets() -> list[list[str]]:
    base = ["-O3", "-fPIC", "-shared", "-fopenmp-simd", "-fno-math-errno", "-fno-trapping-math", "-std=gnu11"]
    sets = []
    if platform.machine() in ("x86_64", "AMD64"):
        vec = base + ["-march=native", "-mprefer-vector-width=512", "-DSTABJAX_LIBMVEC"]
        if _is_gcc(compiler()):
            # GCC schedules instructions before register allocation only when asked (off on x86):
            # -4% (one thread) to -6% (two) median wall in interleaved pairs, same results (NOTES
            # N19); -fno-plt calls libmvec through the GOT, without the PLT's extra jump
            sets.append(vec + ["-fschedule-insns", "-fsched-pressure", "-fno-plt"])
        sets.append(vec)
        sets.append(base + ["-march=native"])
    else:
        sets.append(base + ["-mcpu=native"])
    sets.append(base)
    return sets


def _cpu_key() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text()
        lines = [ln for ln in text.splitlines() if ln.startswith(("model name", "flags", "Features"))]
        return "\n".join(sorted(set(lines)))
    except OSError:
        return platform.processor()


def cache_dir() -> Path:
    d = os.environ.get("STABJAX_CACHE_DIR")
    return Path(d) if d else Path.home() / ".cache" / "stabjax" / "native"


_LOAD_LOCK = threading.Lock()


def compile_library(source: str) -> ctypes.CDLL:
    """Compile C ``source`` into a cached shared library with the first flag set the compiler accepts."""
    cc = compiler()
    if cc is None:
        raise Unsupported("no C compiler on PATH (set CC)")
    errors = []
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[:1]
    for flags in _flag_sets():
        libs = ["-lmvec", "-lm"] if "-DSTABJAX_LIBMVEC" in flags else ["-lm"]
        key = hashlib.sha256("\0".join([source, cc, *version, *flags, *libs, _cpu_key()]).encode()).hexdigest()[:24]
        d = cache_dir()
        so = d / f"stabjax_{key}.so"
        with _LOAD_LOCK:
            if not so.exists():
                d.mkdir(parents=True, exist_ok=True)
                with tempfile.TemporaryDirectory(dir=d) as tmp:
                    c_path = Path(tmp) / "kernel.c"
                    c_path.write_text(source)
                    out = Path(tmp) / "kernel.so"
                    proc = subprocess.run([cc, *flags, str(c_path), "-o", str(out), *libs], capture_output=True, text=True)
                    if proc.returncode != 0:
                        errors.append(f"{' '.join(flags)}: {proc.stderr.strip()[-2000:]}")
                        continue
                    os.replace(out, so)  # atomic: concurrent processes never load a half-written file
            try:
                lib = ctypes.CDLL(str(so))
            except OSError as exc:
                errors.append(f"{' '.join(flags)}: load failed: {exc}")
                continue
        return lib
    raise Unsupported("C compiler failed:\n" + "\n".join(errors))


def _build(source: str) -> ctypes.CDLL:
    lib = compile_library(source)
    lib.stabjax_run.argtypes = [ctypes.POINTER(_Job)]
    lib.stabjax_run.restype = ctypes.c_int64
    dp = ctypes.POINTER(ctypes.c_double)
    if hasattr(lib, "stabjax_eval"):
        lib.stabjax_eval.argtypes = [ctypes.c_double, dp, dp, dp, dp]
        lib.stabjax_update.argtypes = [dp, ctypes.c_double, dp, dp]
        lib.stabjax_eval_split.argtypes = [ctypes.c_double, dp, dp, dp]
    return lib


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Whether a C compiler builds and loads a small kernel here (checked once per process)."""
    try:
        _build("#include <stdint.h>\nint64_t stabjax_run(void *p) { return 0; }\n")
        return True
    except Unsupported:
        return False


class _Kernel:
    def __init__(self, system, icfg, vcfg, static, dyn_shapes, width, eval_only=False):
        ts = icfg.checkpoints()
        self.ts = np.ascontiguousarray(ts, np.float64)
        t_late = V.late_start(vcfg, float(icfg.t0), float(ts[-1]))
        self.model = _NativeModel(system, static, dyn_shapes, vcfg, t_late)
        self.width = width
        self.source = _kernel_source(self.model, width)
        if eval_only:
            self.source = _eval_only(self.source)
        self.lib = _build(self.source)
        self.vcfg = vcfg
        self.icfg = icfg
        self._finalize = jax.jit(jax.vmap(lambda c, ok: V.finalize(c, ok, vcfg)))


@functools.lru_cache(maxsize=32)
def _kernel(system, icfg, vcfg, static: fast._Static, dyn_shapes: tuple, width: int, eval_only=False) -> _Kernel:
    return _Kernel(system, icfg, vcfg, static.values, dict(dyn_shapes), width, eval_only)


def evaluate(kern: _Kernel, t: float, y: np.ndarray, a: np.ndarray, *,
             split: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The compiled rhs and observables of one trajectory (prepared args ``a`` as from host_inputs).

    ``split=True`` computes the rhs as the loop's sixth and seventh stages do: its t-only part
    first (:func:`_split_t`), then the rest.
    """
    m = kern.model
    y = np.ascontiguousarray(y, np.float64)
    a = np.ascontiguousarray(a if m.n_args else np.zeros(1), np.float64)
    dy, obs = np.empty(m.n_state), np.empty(max(m.n_obs, 1))
    dp = ctypes.POINTER(ctypes.c_double)
    kern.lib.stabjax_eval(float(t), y.ctypes.data_as(dp), a.ctypes.data_as(dp), dy.ctypes.data_as(dp),
                          obs.ctypes.data_as(dp))
    if split:
        kern.lib.stabjax_eval_split(float(t), y.ctypes.data_as(dp), a.ctypes.data_as(dp), dy.ctypes.data_as(dp))
    return dy, obs[: m.n_obs]


def update(kern: _Kernel, c: np.ndarray, t: float, obs: np.ndarray) -> np.ndarray:
    """The compiled classifier update of one trajectory (``c`` flat, as ``model.c0``)."""
    c = np.ascontiguousarray(c, np.float64)
    o = np.ascontiguousarray(obs, np.float64)
    out = np.empty(kern.model.n_c)
    dp = ctypes.POINTER(ctypes.c_double)
    kern.lib.stabjax_update(c.ctypes.data_as(dp), float(t), o.ctypes.data_as(dp), out.ctypes.data_as(dp))
    return out


_TRANSCENDENTAL = ("exp(", "log(", "cos(", "sin(", "atan2(", "cbrt(", "tan(", "atan(", "asin(", "acos(", "tanh(",
                   "sinh(", "cosh(", "log1p(", "expm1(", "erf(")


def op_counts(kern: _Kernel) -> dict[str, int]:
    """Arithmetic operations (+ - * /, sqrt) and libm calls per evaluation of each generated function,
    counted in the C source (jpow counts as exp + log), for the roofline estimate of the benchmark."""
    out = {}
    names = ("f_rhs", "f_obs", "f_upd") + (("f_rhs_t",) if kern.model.n_tv else ())
    for name in names:
        body = kern.model.functions.split(f"void {name}(", 1)[1].split("\n}\n", 1)[0]
        lines = [ln.split("=", 1)[1] for ln in body.splitlines() if ln.strip().startswith("const double v")]
        arith = sum(ln.count(" + ") + ln.count(" - ") + ln.count(" * ") + ln.count(" / ") + ln.count("sqrt(")
                    for ln in lines)
        calls = sum(ln.count(f) for ln in lines for f in _TRANSCENDENTAL) + 2 * sum(ln.count("jpow(") for ln in lines)
        out[name] = {"arith": int(arith), "libm_calls": int(calls)}
    return out


def flops_per_step(kern: _Kernel, checkpoints_per_step: float, libm_flops: int = 20) -> dict[str, float]:
    """Floating-point operations of one Tsit5 step (6 rhs, stage sums, error norm, controller) plus
    the checkpoint work per step; a libm call counted as ``libm_flops`` (an assumption: a vectorised
    exp/log/cos is a polynomial of ~10 FMAs plus range reduction)."""
    c = op_counts(kern)
    ns = kern.model.n_state
    nnz = [sum(1 for x in row if x != 0.0) for row in _A]
    stages = sum(ns * (2 * k + 1) for k in nnz) + 6  # y + h * sum(a_ij k_j), stage times
    err = ns * (2 * sum(1 for x in _E if x != 0.0) + 8) + 12  # error estimate, scale, ratio, rms, controller
    rhs = 6 * (c["f_rhs"]["arith"] + libm_flops * c["f_rhs"]["libm_calls"])
    if "f_rhs_t" in c:  # the sixth and seventh stage share their t-only part
        rhs -= c["f_rhs_t"]["arith"] + libm_flops * c["f_rhs_t"]["libm_calls"]
    per_ck = 30 + ns * 15 + c["f_obs"]["arith"] + c["f_upd"]["arith"] + libm_flops * (
        c["f_obs"]["libm_calls"] + c["f_upd"]["libm_calls"])
    step = rhs + stages + err + 2 * libm_flops
    return {"step": float(step), "checkpoints": float(per_ck * checkpoints_per_step),
            "total": float(step + per_ck * checkpoints_per_step), "counts": c, "libm_flops": libm_flops}


def warm(system, icfg, vcfg, params, *, static=None) -> float:
    """Build everything a :func:`solve` of these shapes needs (C kernel, host-side JAX functions);
    returns the seconds taken (the benchmark's compile time)."""
    t = time.perf_counter()
    n = int(next(iter(params.values())).shape[0])
    kern, dyn = kernel_for(system, icfg, vcfg, params, static=static)
    kern.model.host_inputs(dyn, n)
    c = kern.model.c_tree_from(np.zeros((n, kern.model.n_c)))
    jax.block_until_ready(kern._finalize(c, jnp.zeros((n,), bool)))
    return time.perf_counter() - t


def would_run(system, icfg) -> bool:
    """Whether the native engine takes this system/config (a primitive without a C rule is only
    found when generating code; :func:`solve` then raises :class:`Unsupported`)."""
    return (icfg.solver in SUPPORTED_SOLVERS and getattr(system, "classify", None) is None
            and jax.default_backend() == "cpu" and available())


def default_threads() -> int:
    env = os.environ.get("STABJAX_THREADS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def kernel_for(system, icfg, vcfg, params, *, static=None, width: int | None = None, check: bool = True,
               eval_only: bool = False):
    """The compiled kernel for this batch's shapes and constants, and the dynamic parameters.

    ``check=False`` builds it even for a system with its own ``classify``, ``eval_only=True``
    without the integration loop (both for tests of the translation: :func:`evaluate`, :func:`update`).
    """
    if icfg.solver not in SUPPORTED_SOLVERS:
        raise Unsupported(f"solver {icfg.solver!r} (native engine: {', '.join(SUPPORTED_SOLVERS)})")
    if check and getattr(system, "classify", None) is not None:
        raise Unsupported(f"{system.name} has its own classify()")
    st, dyn = fast.split_static(params, static)
    shapes = tuple(sorted((k, v.shape[1:]) for k, v in dyn.items()))
    return _kernel(system, icfg, vcfg, fast._Static(st), shapes, int(width or DEFAULT_WIDTH), eval_only), dyn


def solve(system, params: Mapping[str, np.ndarray], icfg, vcfg, *, static: Iterable[str] | None = None,
          with_state: bool = False, threads: int | None = None, width: int | None = None,
          progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Integrate and classify ``params`` (every parameter, leading dim N) natively. Returns summaries (N,).

    Same contract as :func:`stabjax.fast.solve`. ``progress(done, n)`` is called from the calling
    thread about twice a second while the threads run. Raises :class:`Unsupported` when the
    system cannot be translated or no C compiler works.
    """
    n = int(next(iter(params.values())).shape[0])
    kern, dyn = kernel_for(system, icfg, vcfg, params, static=static, width=width)
    model = kern.model
    ain, y0 = model.host_inputs(dyn, n)
    raw = run_raw(kern, ain, y0, threads=threads, progress=progress)
    c = model.c_tree_from(raw["c"])
    summ = {k: np.asarray(v) for k, v in kern._finalize(c, jnp.asarray(raw["status"] == STATUS_OK)).items()}
    summ["n_steps"] = raw["nacc"]
    summ["n_rejected"] = raw["nrej"]
    summ["solver_status"] = raw["status"]
    if with_state:
        summ["state_t1"] = raw["y"]
    return summ


def run_raw(kern: _Kernel, ain: np.ndarray, y0: np.ndarray, *, threads: int | None = None,
            progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Run the compiled loop on prepared inputs; returns the raw per-trajectory outputs."""
    model, icfg = kern.model, kern.icfg
    n = int(y0.shape[0])
    NA = max(model.n_args, 1)
    if ain.shape[1] != NA:
        ain = np.ascontiguousarray(np.zeros((n, NA)) if model.n_args == 0 else ain)
    cout = np.empty((n, model.n_c), np.float64)
    yout = np.empty((n, model.n_state), np.float64)
    nacc = np.zeros(n, np.int32)
    nrej = np.zeros(n, np.int32)
    status = np.full(n, STATUS_MAX_STEPS, np.int32)
    nxt = np.zeros(1, np.int64)
    ndone = np.zeros(1, np.int64)
    stop = np.zeros(1, np.int32)
    c0 = np.ascontiguousarray(model.c0, np.float64)

    def ptr(a):
        return a.ctypes.data_as(ctypes.c_void_p)

    job = _Job(n=n, K=len(kern.ts), max_steps=int(icfg.max_steps), t0=float(icfg.t0), t1=float(icfg.t1),
               t1_floor=fast._t1_clip_floor(float(icfg.t1)), rtol=float(icfg.rtol), atol=float(icfg.atol),
               dt0=float(icfg.dt0) if icfg.dt0 is not None else -1.0,
               ain=ptr(ain), y0in=ptr(y0), c0=ptr(c0), ts=ptr(kern.ts), cout=ptr(cout), yout=ptr(yout),
               nacc_out=ptr(nacc), nrej_out=ptr(nrej), status_out=ptr(status), next=ptr(nxt), ndone=ptr(ndone),
               stop=ptr(stop))
    n_threads = max(1, min(int(threads or default_threads()), -(-n // kern.width)))
    workers = [threading.Thread(target=kern.lib.stabjax_run, args=(ctypes.byref(job),), daemon=True)
               for _ in range(n_threads)]
    for w in workers:
        w.start()
    try:
        while any(w.is_alive() for w in workers):
            workers[0].join(0.5)
            if progress is not None:
                progress(int(ndone[0]), n)
    except BaseException:
        stop[0] = 1  # every thread stops after its current step; nothing of this call is kept
        for w in workers:
            w.join()
        raise
    for w in workers:
        w.join()
    if int(ndone[0]) != n:
        raise RuntimeError(f"native engine finished {int(ndone[0])} of {n} trajectories")
    return {"c": cout, "y": yout, "nacc": nacc, "nrej": nrej, "status": status}


__all__ = ["solve", "would_run", "available", "Unsupported", "compiler", "kernel_for", "run_raw"]
