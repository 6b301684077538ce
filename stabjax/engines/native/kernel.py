"""Native engine, the C kernel: one SIMD Tsit5 loop over blocks of ``W`` trajectories.

This module is one C template (about 400 lines of C in a Python f-string) with the generated
functions of :mod:`stabjax.engines.native.emit` pasted in; it is longer than the project's ~500
line guide would like because the loop's parts (stages, error norm and controller, checkpoint
rounds, classifier passes, refill) share its local arrays and macros and are only readable in
one piece. Why each part is written the way it is: the comments in the C, and docs/performance.md.

* **SIMD over trajectories.** ``W`` trajectories are stepped side by side in
  structure-of-arrays blocks; every stage is an ``omp simd`` loop over the block, and glibc's
  vector math library (libmvec) supplies AVX-512 exp, log, sin, cos, pow and atan2.
  Each lane has its own time, step size, checkpoint index and classifier state; a lane whose
  trajectory finished is refilled at once from a queue shared by all threads (an atomic
  counter), so no lane idles until the queue runs dry.
* **The method is diffrax's** (:mod:`stabjax.engines.tsit5`). Unlike the fused engine a step
  may contain any number of checkpoints (each from the dense output), so the step sequence is the
  one ``diffeqsolve`` takes with ``SaveAt(t1=True)`` (up to rounding: the sixth stage is taken at
  the step's end time, where diffrax computes ``t + 1.0 * h``, and libmvec's last bits differ
  from XLA's).
* **Checkpoints.** Each lane's first checkpoint of a step is interpolated and observed in lane
  layout; later ones of the same step become items observed in SIMD batches over items; the
  observables wait in per-lane FIFOs for vectorised classifier passes.
* **Stops.** A lane stops at t1, at ``max_steps``, at once when its derivative is not finite or
  its step size collapses (status 1, what diffrax would end with; :data:`..tsit5.MIN_STEP_REL`), and, with an escape radius, at once when an accepted
  state leaves the ball (status :data:`stabjax.fold.status.ESCAPED`).
"""
from __future__ import annotations

import ctypes
from typing import Callable

from ...fold.status import ESCAPED as STATUS_ESCAPED, MAX_STEPS as STATUS_MAX_STEPS, OK as STATUS_OK
from ..tsit5 import A, C, E, FACTORMAX, FACTORMIN, MIN_STEP_REL, SAFETY
from .emit import NativeModel, flit

# ==== the kernel ==================================================================================

# libm functions for which glibc's libmvec has x86-64 vector variants (declared ``omp declare simd``)
_VECTOR_LIBM = ("exp", "log", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh",
                "atanh", "cbrt", "log1p", "expm1", "exp2", "erf", "pow:2", "atan2:2")
# (rint, floor, ceil, trunc, fabs, sqrt are single instructions: no declaration needed)


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
    return flit(x)


# A model function of at least this many lines of C is compiled once and called from each site (rhs_lanes,
# upd_lanes); a smaller one is inlined at each, as before: its copies cost GCC little, and a call per stage measurably
# slowed the pendulum's rhs of a dozen lines (kernel alone, one thread, min of 5 runs in each of five
# alternating pairs of processes: 1.30-1.53 s inlined, 1.36-1.67 s called; docs/performance.md)
CALL_LINES = 100


def _lines(functions: str, name: str) -> int:
    """Lines of C in the body of the generated function ``name`` (0 where there is none)."""
    head = f"void {name}("
    if head not in functions:
        return 0
    return functions.split(head, 1)[1].split("\n}\n", 1)[0].count("\n")


def _unrolled(n: int, line: Callable[[int], str]) -> str:
    """``n`` statements, unrolled here: GCC does not vectorise a loop over lanes that still holds
    an inner loop (measured: the error estimate and classifier loops stayed scalar)."""
    return "\n            ".join(line(q) for q in range(n))


def kernel_source(model: NativeModel, W: int, escape: float | None = None, fp_every: int = 8,
                  window_from: int = 0, eval_entries: bool = False) -> str:
    """C source of the integration loop for ``model`` with blocks of ``W`` lanes; ``escape``: the
    escape radius (None: no escape test, and the source is that of a kernel without one).
    ``window_from``: for a fold of the late-window features alone, the index of the first checkpoint in
    the window; of the checkpoints before it only the last one of each step is observed and folded (the
    others' updates change nothing the last one does not overwrite: the last value, the span), so results
    are those of every checkpoint, bit for bit. 0: every checkpoint (the attitude classifier reads all).
    ``eval_entries``: also the scalar entry points ``stabjax_eval*`` / ``stabjax_update`` that the tests
    compare with JAX (a sweep never calls them, and each is another compiled copy of the model)."""
    NS, NA, NC, NO = model.n_state, max(model.n_args, 1), model.n_c, max(model.n_obs, 1)
    stage_loops = []
    call_rhs, call_upd = (_lines(model.functions, name) >= CALL_LINES for name in ("f_rhs", "f_upd"))
    # The sixth stage and the next step's first are both at t + h: the t-only part of the
    # right-hand side (paper A: cos(omega0 t**alpha), a log, an exp and a cos) is computed once for
    # both, at TN (diffrax takes the sixth at t + 1.0 * h, which can differ from TN in the last bit)
    share = model.n_tv > 0 and C[4] == 1.0 and C[5] == 1.0
    # stages 2..6 of Tsit5 (FSAL: K0 = f(t, y)); stage i uses row A[i-1] and node C[i-1]
    for i in range(1, 6):
        row = A[i - 1]
        body = _unrolled(NS, lambda q: f"YT[{q} * W + l] = Y[{q} * W + l] + h * ("
                         + " + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(row) if c != 0.0) + ");")
        pre = ""
        call = (f"""#pragma omp simd
        for (int l = 0; l < W; l++) TS[l] = T[l] + {_coef(C[i - 1])} * H[l];
        rhs_lanes(TS, YT, A, KS[{i}]);""" if call_rhs else f"""#pragma omp simd
        for (int l = 0; l < W; l++) f_rhs(T[l] + {_coef(C[i - 1])} * H[l], YT + l, A + l, KS[{i}] + l, W);""")
        if share and i == 5:
            pre = """
        #pragma omp simd
        for (int l = 0; l < W; l++) f_rhs_t(TN[l], A + l, TV + l, W);"""
            call = f"""#pragma omp simd
        for (int l = 0; l < W; l++) f_rhs_y(TN[l], TV + l, YT + l, A + l, KS[{i}] + l, W);"""
        stage_loops.append(f"""{pre}
        #pragma omp simd
        for (int l = 0; l < W; l++) {{
            const double h = H[l];
            {body}
        }}
        {call}""")
    # the t-only values TV stay in the same function as the two stages that read them: behind a call,
    # GCC could no longer fuse a product of them into a multiply-add, and results moved in the last bit
    last_call = ("""#pragma omp simd
        for (int l = 0; l < W; l++) f_rhs_y(TN[l], TV + l, YN + l, A + l, KS[6] + l, W);""" if share
                 else "rhs_lanes(TN, YN, A, KS[6]);" if call_rhs else
                 "#pragma omp simd\n        for (int l = 0; l < W; l++) f_rhs(TN[l], YN + l, A + l, KS[6] + l, W);")
    row = A[5]
    new_body = _unrolled(NS, lambda q: f"YN[{q} * W + l] = Y[{q} * W + l] + h * ("
                         + " + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(row) if c != 0.0) + ");")
    probe = " + ".join(f"(YN[{q} * W + l] - YN[{q} * W + l])" for q in range(NS))
    fin_probe = " + ".join(f"(KS[0][{q} * W + l] - KS[0][{q} * W + l])" for q in range(NS))
    if escape is None:
        esc_vec, esc_term, esc_scalar = "", "", ""
        reached, stuck, done, status = ("(T[l] >= t1) & (CK[l] >= K)", "!reached & ", "reached | stuck",
                                        f"reached ? {STATUS_OK} : {STATUS_MAX_STEPS}")
    else:  # max_i |y_i| of an accepted state above the radius: stop at once (STATUS_ESCAPED)
        esc_vec = "double ym = 0.0;\n            " + "\n            ".join(
            f"{{ const double a_ = fabs(Y[{q} * W + l]); ym = a_ > ym ? a_ : ym; }}" for q in range(NS))
        esc_term = f" + (ym > {flit(escape)} ? KEEP[l] : 0.0)"
        esc_scalar = ("int escaped = 0;\n            if (KEEP[l] != 0.0) for (int q = 0; q < NS; q++) "
                      f"escaped |= fabs(Y[q * W + l]) > {flit(escape)};\n            ")
        reached, stuck, done, status = ("!escaped & (T[l] >= t1) & (CK[l] >= K)", "!escaped & !reached & ",
                                        "reached | stuck | escaped",
                                        f"escaped ? {STATUS_ESCAPED} : reached ? {STATUS_OK} : {STATUS_MAX_STEPS}")
    err_body = _unrolled(NS, lambda q: f"""{{
                double e = h * ({" + ".join(f"{_coef(c)} * KS[{j}][{q} * W + l]" for j, c in enumerate(E) if c != 0.0)});
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
    upd_call = ("upd_lanes(C, TC, OBS, CN);" if call_upd else
                "#pragma omp simd\n    for (int l = 0; l < W; l++) f_upd(C + l, TC[l], OBS + l, CN + l, W);")
    lanes = ("" if not call_rhs else """
static __attribute__((noinline)) void rhs_lanes(const double *restrict TT, const double *restrict YY,
                                                const double *restrict AA, double *restrict KK) {
    #pragma omp simd
    for (int l = 0; l < W; l++) f_rhs(TT[l], YY + l, AA + l, KK + l, W);
}
""") + ("" if not call_upd else """
static __attribute__((noinline)) void upd_lanes(const double *restrict CC, const double *restrict TT,
                                                const double *restrict OO, double *restrict NN) {
    #pragma omp simd
    for (int l = 0; l < W; l++) f_upd(CC + l, TT[l], OO + l, NN + l, W);
}
""")
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

/* The rhs and the classifier update of a block's W lanes. A large one (CALL_LINES) is compiled once and
   called from every site: GCC compiles each inlined copy anew, and the stages' copies of the rhs and the
   classifier's two made most of a large model's compile time (the drain below was the first;
   docs/performance.md), while a call per block of W lanes costs nothing measurable beside their work. The
   results are those of the inlined copies, bit for bit (every shipped sweep and example compared). Not
   behind a call: the two stages that share the rhs's t-only values, and a new lane's first rhs (either
   changed GCC's fusing of multiply-adds, and so the last bits). */
{lanes}
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
    double *tout;
    int32_t *fp_out;
    double *oout;
    int64_t *drains;  /* [0] items drained from a full FIFO (overflow), [1] drained when a lane finished */
    const double *known;  /* the recurrence stop's clouds (stabjax.fold.stops.attractor_data), or NULL */
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

/* each lane's FIFO of observed checkpoints (time, observables): per thread, too large for the stack */
static __thread double FT[W * QCAP], FO[W * QCAP * NO];

/* one item of lane L through the same vector code as a classifier pass (the scalar build of f_upd
   calls scalar libm, whose last bit may differ: results would depend on which lanes shared a block).
   A function, not a macro: three sites drain, and each inlined copy of the classifier update costs GCC
   about as much as the pass itself (paper A's kernel: 14.3 / 11.2 s -> 8.3 / 8.9 s of code generation and
   compile, results bit for bit; docs/performance.md) */
static __attribute__((noinline)) void drain_one(const int L, const double *T, double *TC, double *OBS, double *C,
                                                 double *CN, int *QH, int *QN) {{
    const int p_ = QH[L];
    for (int l_ = 0; l_ < W; l_++) TC[l_] = T[l_];  /* other lanes: computed, discarded */
    TC[L] = FT[L * QCAP + p_];
    for (int q = 0; q < NO; q++) OBS[q * W + L] = FO[(L * QCAP + p_) * NO + q];
    {upd_call}
    for (int q = 0; q < NC; q++) C[q * W + L] = CN[q * W + L];
    QH[L] = (p_ + 1) % QCAP; QN[L]--;
}}

int64_t stabjax_run(const job_t *jb) {{
    /* per-lane flags and counters are doubles too (see CEmit): every simd loop is pure V8DF */
    double Y[NS * W] ALIGN, KS[7][NS * W] ALIGN, YT[NS * W] ALIGN, YN[NS * W] ALIGN, A[NA * W] ALIGN, C[NC * W] ALIGN,
        CN[NC * W] ALIGN, OBS[NO * W] ALIGN, T[W] ALIGN, TN[W] ALIGN, H[W] ALIGN, TP[W] ALIGN, TNX[W] ALIGN, TC[W] ALIGN,
        NACC[W] ALIGN, NREJ[W] ALIGN, KEEP[W] ALIGN, HAS[W] ALIGN, ACT[W] ALIGN, TV[NTV * W] ALIGN{", TS[W] ALIGN" if call_rhs else ""};
    /*FP_DECL*/
    int64_t CK[W] ALIGN, IDX[W] ALIGN;
    /* checkpoint items of one step */
    double IT_[NI] ALIGN, PYT[NS * NI] ALIGN, PA[NA * NI] ALIGN, POBS[NO * NI] ALIGN;
    /* round 0: each lane's first checkpoint in a step (time of its next checkpoint, whether it has
       one in this step, its time, state and observables) */
    double NEXTT[W] ALIGN, R0[W] ALIGN, TC0[W] ALIGN, PY0[NS * W] ALIGN, OB0[NO * W] ALIGN;
    int IL[NI] ALIGN;
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
            IDX[l] = j_; ACT[l] = 1.0; /*FP_REFILL*/ \\
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

#define DRAIN_ONE(L) drain_one((L), T, TC, OBS, C, CN, QH, QN)

/* append an observed checkpoint (time TT, observables OO[q * STRIDE]) to lane L's FIFO */
#define PUSH(L, TT, OO, STRIDE) do {{ \\
        if (QN[L] == QCAP) {{ DRAIN_ONE(L); n_over++; }} \\
        const int pos_ = (QH[L] + QN[L]) % QCAP; \\
        FT[(L) * QCAP + pos_] = (TT); \\
        for (int q = 0; q < NO; q++) FO[((L) * QCAP + pos_) * NO + q] = (OO)[q * (STRIDE)]; \\
        QN[L]++; \\
    }} while (0)

    for (int l = 0; l < W; l++) {{ QH[l] = 0; QN[l] = 0; }}
    int64_t n_over = 0, n_late = 0;  /* drains (observable, tests: jb->drains); they change no result */
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
        {last_call}

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
        /*SKIP*/
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
           per-lane sequence of updates, and every result, is unchanged (docs/performance.md). */
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
            {upd_call.replace(chr(10) + "    ", chr(10) + "            ")}
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
        /*FP_TEST*/

        /* finished or stuck lanes: write out, refill from the queue. A lane finishes once in
           thousands of steps; a vector test of a superset of the condition skips the scalar loop
           (-10% median wall in 10 interleaved pairs, docs/performance.md) */
        double cand = 0.0;
        #pragma omp simd reduction(max:cand)
        for (int l = 0; l < W; l++) {{
            const double probe = {fin_probe};  /* NaN iff some component of f is not finite */
            {esc_vec}const double c1 = T[l] >= t1 ? 1.0 : 0.0, c2 = NACC[l] + NREJ[l] >= max_steps_d ? 1.0 : 0.0;
            /* step-size collapse: the next step is within ~10 ulp of t, no progress is possible */
            const double c3 = !(TN[l] - T[l] > {flit(MIN_STEP_REL)} * fabs(T[l])) && T[l] < t1 ? 1.0 : 0.0;  /* NaN step too */
            const double c = c1 + c2 + c3 + (probe != probe ? 1.0 : 0.0){esc_term}/*FP_CAND*/ > 0.0 ? ACT[l] : 0.0;
            cand = c > cand ? c : cand;
        }}
        if (cand != 0.0) for (int l = 0; l < W; l++) {{
            if (ACT[l] == 0.0) continue;
            {esc_scalar}/*FP_SCALAR*/
            const int reached = {reached};
            const int stuck = {stuck}((NACC[l] + NREJ[l] >= max_steps_d) | !finite_row(KS[0] + l)
                                      | (!(TN[l] - T[l] > {flit(MIN_STEP_REL)} * fabs(T[l])) & (T[l] < t1)));
            if (!({done} | fixedp)) continue;
            const int64_t j = IDX[l];
            while (QN[l] > 0) {{ DRAIN_ONE(l); n_late++; }}
            for (int q = 0; q < NC; q++) jb->cout[j * NC + q] = C[q * W + l];
            for (int q = 0; q < NS; q++) jb->yout[j * NS + q] = Y[q * W + l];
            jb->tout[j] = T[l];
            jb->nacc_out[j] = (int32_t)NACC[l]; jb->nrej_out[j] = (int32_t)NREJ[l];
            jb->status_out[j] = fixedp ? {STATUS_OK} : {status};
            /*FP_OUT*/
            __atomic_fetch_add(jb->ndone, 1, __ATOMIC_RELAXED);
            finished++;
            REFILL(l);
            n_active += (ACT[l] != 0.0) - 1;
        }}
    }}
    __atomic_fetch_add(jb->drains, n_over, __ATOMIC_RELAXED);
    __atomic_fetch_add(jb->drains + 1, n_late, __ATOMIC_RELAXED);
    return finished;
}}

/*EVAL*/
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
    if not eval_entries:
        src = src[: src.index("/*EVAL*/")]
    if window_from > 1:  # a features-only fold: skip to the last checkpoint before the window in each step
        src = src.replace("/*SKIP*/", f"""/* features-only fold: a checkpoint before the feature window (index {int(window_from)}) sets the
           last value alone, so of those a step crosses only the last is observed (the pendulum's 2000
           log-spaced checkpoints before t = 100 queued, overflowed and were folded one by one) */
        for (int l = 0; l < W; l++) {{
            if (KEEP[l] != 0.0 && CK[l] + 1 < {int(window_from)} && ts[CK[l] + 1] <= TN[l]) {{
                do CK[l]++; while (CK[l] + 1 < {int(window_from)} && ts[CK[l] + 1] <= TN[l]);
                NEXTT[l] = ts[CK[l]];
            }}
        }}""")
    else:
        src = src.replace("/*SKIP*/", "")
    known = model.known
    if model.fixed_point is None and known is None:
        src = src.replace("/*FP_DECL*/", "").replace("/*FP_REFILL*/", "").replace("/*FP_TEST*/", "").replace("/*FP_CAND*/", "")
        src = src.replace("/*FP_SCALAR*/", "const int fixedp = 0;").replace("/*FP_OUT*/", "")
    else:  # the stop tests of stabjax.fold.stops, after a step that reached a checkpoint: FP[l] = its stop code
        from ...fold.stops import HIT_ATTRACTOR0, HIT_FIXED_POINT, TEST_EVERY

        # FPT: the test's verdict (row 0) and the equilibrium it reached (rows 1 .. NS)
        src = src.replace("/*FP_DECL*/", "double FP[W] ALIGN, FPT[(1 + NS) * W] ALIGN, FPM[W] ALIGN, NT[W] ALIGN, "
                                         "FPP[W] ALIGN;\n"
                                         "    double AKT[W] ALIGN, AK[W] ALIGN, AS[W] ALIGN, ATM[W] ALIGN, NXA[W] ALIGN;\n"
                                         "    for (int l = 0; l < W; l++) { NT[l] = 0.0; NXA[l] = 0.0; AK[l] = -1.0; AS[l] = 0.0; }")
        src = src.replace("/*FP_REFILL*/", "NT[l] = 0.0; NXA[l] = 0.0; AK[l] = -1.0; AS[l] = 0.0;")
        every_fp = int(fp_every)  # checkpoints between fixed-point tests (stabjax.fold.stops.fixed_point_every)
        # the cheap question first (near a stable equilibrium), the whole test only where a lane says yes
        fp_call = ("""#pragma omp simd
                for (int l = 0; l < W; l++) f_fpre(T[l], Y + l, A + l, FPP + l, W);
                double anyp = 0.0;
                #pragma omp simd reduction(max:anyp)
                for (int l = 0; l < W; l++) { FPP[l] = FPM[l] != 0.0 && FPP[l] != 0.0 ? 1.0 : 0.0; anyp = FPP[l] > anyp ? FPP[l] : anyp; }
                if (anyp != 0.0) {
                    #pragma omp simd
                    for (int l = 0; l < W; l++) f_fp(T[l], Y + l, A + l, FPT + l, W);
                }""" if model.fixed_point is not None else "")
        at_call = ("#pragma omp simd\n                for (int l = 0; l < W; l++) f_at(T[l], Y + l, A + l, jb->known, AKT + l, W);"
                   if known is not None else "")
        fp_mask = "R0[l] != 0.0 && (double)CK[l] >= NT[l] ? 1.0 : 0.0" if model.fixed_point is not None else "0.0"
        at_mask = "R0[l] != 0.0 && (double)CK[l] >= NXA[l] ? 1.0 : 0.0" if known is not None else "0.0"
        fp_hit = (f"FPM[l] != 0.0 && FPP[l] != 0.0 && FPT[l] != 0.0 ? {HIT_FIXED_POINT}.0 : 0.0"
                  if model.fixed_point is not None else "0.0")
        # the recurrence stop: the same attractor at every test over a span of dwell (stabjax.fold.stops)
        at_hit = "" if known is None else f"""
                    const double k = AKT[l], m = ATM[l];
                    const double same = k >= 0.0 && k == AK[l] ? 1.0 : 0.0;
                    const double held = m != 0.0 && same != 0.0 && T[l] - AS[l] >= {known.dwell!r} ? 1.0 : 0.0;
                    AS[l] = m != 0.0 && same == 0.0 ? T[l] : AS[l];
                    AK[l] = m != 0.0 ? k : AK[l];
                    hit = hit != 0.0 ? hit : (held != 0.0 ? {HIT_ATTRACTOR0}.0 + k : 0.0);"""
        # a lane asks when a step reached a checkpoint and enough checkpoints passed since it last asked
        src = src.replace("/*FP_TEST*/", """
        #pragma omp simd
        for (int l = 0; l < W; l++) FP[l] = 0.0;
        if (any0 != 0.0) {
            double anyf = 0.0, anya = 0.0;
            #pragma omp simd reduction(max:anyf) reduction(max:anya)
            for (int l = 0; l < W; l++) {
                const double mf = %s, ma = %s;
                FPM[l] = mf; ATM[l] = ma;
                anyf = mf > anyf ? mf : anyf;
                anya = ma > anya ? ma : anya;
            }
            if (anyf != 0.0) {
                %s
            }
            if (anya != 0.0) {
                %s
            }
            if (anyf != 0.0 || anya != 0.0) {
                #pragma omp simd
                for (int l = 0; l < W; l++) {
                    double hit = %s;%s
                    FP[l] = hit;
                    NT[l] = FPM[l] != 0.0 ? (double)CK[l] + %d.0 : NT[l];
                    NXA[l] = ATM[l] != 0.0 ? (double)CK[l] + %d.0 : NXA[l];
                }
            }
        }""" % (fp_mask, at_mask, fp_call, at_call, fp_hit, at_hit, every_fp, TEST_EVERY))
        src = src.replace("/*FP_CAND*/", " + FP[l]")
        esc_guard = " && !escaped" if escape is not None else ""
        src = src.replace("/*FP_SCALAR*/", f"const int fixedp = FP[l] != 0.0{esc_guard};")
        src = src.replace("/*FP_OUT*/", f"""jb->fp_out[j] = fixedp ? (int32_t)FP[l] : 0;
            if (fixedp) {{  /* the observables at the equilibrium itself (a fixed point), else at the state */
                f_obs(T[l], (FP[l] == {HIT_FIXED_POINT}.0 ? FPT + W : Y) + l, A + l, OB0 + l, W);
                for (int q = 0; q < NO; q++) jb->oout[j * NO + q] = OB0[q * W + l];
            }}""")
    return src


def eval_only(src: str) -> str:
    """The kernel source without the integration loop (tests of the translation compile faster)."""
    i = src.index("typedef struct {")
    j = src.index("/* one trajectory's rhs")
    return src[:i] + "int64_t stabjax_run(const void *jb) { return -1; }\n\n" + src[j:]



class Job(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int64), ("K", ctypes.c_int64), ("max_steps", ctypes.c_int64),
                ("t0", ctypes.c_double), ("t1", ctypes.c_double), ("t1_floor", ctypes.c_double),
                ("rtol", ctypes.c_double), ("atol", ctypes.c_double), ("dt0", ctypes.c_double),
                ("ain", ctypes.c_void_p), ("y0in", ctypes.c_void_p), ("c0", ctypes.c_void_p), ("ts", ctypes.c_void_p),
                ("cout", ctypes.c_void_p), ("yout", ctypes.c_void_p),
                ("nacc_out", ctypes.c_void_p), ("nrej_out", ctypes.c_void_p), ("status_out", ctypes.c_void_p),
                ("next", ctypes.c_void_p), ("ndone", ctypes.c_void_p), ("stop", ctypes.c_void_p),
                ("tout", ctypes.c_void_p), ("fp_out", ctypes.c_void_p), ("oout", ctypes.c_void_p),
                ("drains", ctypes.c_void_p), ("known", ctypes.c_void_p)]

