"""Variants of the generated native kernel, measured against it in one process (NOTES.md N26).

``benchmarks/ab_kernels.py`` compares two git revisions of the emitter; this script compares
*source transforms* of the kernel the working tree generates (the benchmark's monoaxial alpha sweep,
T = 1e4, integration only through ``native.run_raw``), which is how ideas are tried before they are
worth a change to the emitter. Four commands:

    python benchmarks/source_variants.py ab --n 4096 --pairs 4 --threads 1 nockpt noobs noupd
    python benchmarks/source_variants.py regions --n 4096 --threads 1
    python benchmarks/source_variants.py rhs
    python benchmarks/source_variants.py herm-check    (tonly_herm's truncation error, N30)

``ab``: the base kernel and each named variant run in turn, order reversed every other round; per run
the wall time, accepted/rejected steps, whether the raw summaries equal the base's bit for bit, and at
the end each variant's wall over the base's, per round. Variants (``VARIANTS``) are candidate changes
(results must stay bit-identical), ablations (results wrong on purpose, step sequence unchanged, to
bound what a part of the loop costs) or probes (``lfence`` between regions: same results, no overlap
of the regions it separates, to see how much they overlap today).

``regions``: the kernel with ``rdtsc`` between the loop's regions, cycles per loop iteration (one
step attempt of 16 lanes). ``rdtsc`` does not wait for earlier instructions to finish, so a region
that consumes a long-latency result is charged for the wait: read it as where the loop waits, not
as what each region computes (N26).

``rhs``: the kernel's own ``f_rhs``, and its ``f_obs`` + ``f_upd`` (observe a checkpoint, update the
classifier), 16 lanes, each evaluation feeding the next: alone, one after the other, and side by side
in one loop body (whether independent work overlaps); next to it the cost of each libmvec call
(latency and throughput) from ``benchmarks/probes/libmvec_calls.c``. ``rhs --standins``: the rhs alone
against versions with one part (square roots and division, cbrt, the t-only part) replaced by cheap
arithmetic (N32).
"""
from __future__ import annotations

import argparse
import copy
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stabjax import bench, native

HERE = Path(__file__).resolve().parent


def _one(src: str, old: str, new: str) -> str:
    if src.count(old) != 1:
        raise SystemExit(f"variant anchor not found exactly once in the generated kernel:\n{old}")
    return src.replace(old, new)


# ---- candidate changes (bit-identical results expected) ----------------------------------------

_PUSH0 = """            for (int l = 0; l < W; l++) {
                if (R0[l] == 0.0) continue;
                PUSH(l, TC0[l], OB0 + l, W);
                CK[l]++;
                NEXTT[l] = CK[l] < K ? ts[CK[l]] : INFINITY;
            }
"""

_VPUSH = r"""#if defined(__AVX512F__) && (W % 8) == 0 && (QCAP & (QCAP - 1)) == 0
            for (int b = 0; b < W; b += 8) {
                const __mmask8 m = _mm512_cmp_pd_mask(_mm512_load_pd(R0 + b), _mm512_setzero_pd(), _CMP_NEQ_UQ);
                if (!m) continue;
                const __m256i qn = _mm256_loadu_si256((const __m256i *)(QN + b));
                if (_mm256_mask_cmpeq_epi32_mask(m, qn, _mm256_set1_epi32(QCAP))) {
                    for (int l = b; l < b + 8; l++) {
                        if (R0[l] == 0.0) continue;
                        PUSH(l, TC0[l], OB0 + l, W);
                        CK[l]++;
                        NEXTT[l] = CK[l] < K ? ts[CK[l]] : INFINITY;
                    }
                    continue;
                }
                const __m256i qh = _mm256_loadu_si256((const __m256i *)(QH + b));
                const __m256i lane = _mm256_add_epi32(_mm256_set1_epi32(b), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
                const __m256i pos = _mm256_and_si256(_mm256_add_epi32(qh, qn), _mm256_set1_epi32(QCAP - 1));
                const __m256i it = _mm256_add_epi32(_mm256_mullo_epi32(lane, _mm256_set1_epi32(QCAP)), pos);
                _mm512_mask_i32scatter_pd(FT, m, it, _mm512_load_pd(TC0 + b), 8);
                const __m256i io = _mm256_mullo_epi32(it, _mm256_set1_epi32(NO));
                for (int q = 0; q < NO; q++) _mm512_mask_i32scatter_pd(FO + q, m, io, _mm512_load_pd(OB0 + q * W + b), 8);
                _mm256_storeu_si256((__m256i *)(QN + b), _mm256_mask_add_epi32(qn, m, qn, _mm256_set1_epi32(1)));
                __m512i ck = _mm512_load_si512((const void *)(CK + b));
                ck = _mm512_mask_add_epi64(ck, m, ck, _mm512_set1_epi64(1));
                _mm512_store_si512((void *)(CK + b), ck);
                const __mmask8 in = _mm512_mask_cmplt_epi64_mask(m, ck, _mm512_set1_epi64(K));
                __m512d nx = _mm512_mask_blend_pd(m, _mm512_load_pd(NEXTT + b), _mm512_set1_pd(INFINITY));
                _mm512_store_pd(NEXTT + b, _mm512_mask_i64gather_pd(nx, in, ck, ts, 8));
            }
#else
"""

_POP0 = """            int any = 0;
            for (int l = 0; l < W; l++) {
                if (QN[l] > 0) {
                    const int pos = QH[l];
                    HAS[l] = 1.0; TC[l] = FT[l * QCAP + pos];
                    for (int q = 0; q < NO; q++) OBS[q * W + l] = FO[(l * QCAP + pos) * NO + q];
                    QH[l] = (pos + 1) % QCAP; QN[l]--; any = 1;
                } else {
                    HAS[l] = 0.0; TC[l] = T[l];
                }
            }
"""

_VPOP = r"""#if defined(__AVX512F__) && (W % 8) == 0 && (QCAP & (QCAP - 1)) == 0
            int any = 0;
            for (int b = 0; b < W; b += 8) {
                const __m256i qn = _mm256_loadu_si256((const __m256i *)(QN + b));
                const __mmask8 m = _mm256_cmpgt_epi32_mask(qn, _mm256_setzero_si256());
                _mm512_store_pd(HAS + b, _mm512_mask_blend_pd(m, _mm512_setzero_pd(), _mm512_set1_pd(1.0)));
                if (!m) { _mm512_store_pd(TC + b, _mm512_load_pd(T + b)); continue; }
                any = 1;
                const __m256i qh = _mm256_loadu_si256((const __m256i *)(QH + b));
                const __m256i lane = _mm256_add_epi32(_mm256_set1_epi32(b), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
                const __m256i it = _mm256_add_epi32(_mm256_mullo_epi32(lane, _mm256_set1_epi32(QCAP)), qh);
                _mm512_store_pd(TC + b, _mm512_mask_i32gather_pd(_mm512_load_pd(T + b), m, it, FT, 8));
                const __m256i io = _mm256_mullo_epi32(it, _mm256_set1_epi32(NO));
                for (int q = 0; q < NO; q++)
                    _mm512_store_pd(OBS + q * W + b, _mm512_mask_i32gather_pd(_mm512_load_pd(OBS + q * W + b), m, io, FO + q, 8));
                const __m256i qh1 = _mm256_and_si256(_mm256_add_epi32(qh, _mm256_set1_epi32(1)), _mm256_set1_epi32(QCAP - 1));
                _mm256_storeu_si256((__m256i *)(QH + b), _mm256_mask_mov_epi32(qh, m, qh1));
                _mm256_storeu_si256((__m256i *)(QN + b), _mm256_mask_sub_epi32(qn, m, qn, _mm256_set1_epi32(1)));
            }
#else
"""


def _intrinsics(src: str) -> str:
    return _one(src, "#include <string.h>\n", "#include <string.h>\n#include <immintrin.h>\n")


def vpush(src: str) -> str:
    """Round 0's FIFO push as masked AVX-512 scatters (no per-lane branch); scalar when a FIFO is full."""
    return _intrinsics(_one(src, _PUSH0, _VPUSH + _PUSH0 + "#endif\n"))


def vpop(src: str) -> str:
    """The classifier pass's FIFO pop as masked AVX-512 gathers."""
    return _intrinsics(_one(src, _POP0, _VPOP + _POP0 + "#endif\n"))


_DIRECT0 = """            /* one classifier pass per step that crosses a checkpoint, for every lane with something to
               classify: a lane with an empty FIFO takes its round-0 checkpoint directly (no push, no
               pop), a lane with a backlog pops its oldest item and queues the round-0 checkpoint behind
               the rest, so each lane's sequence of updates is unchanged */
            int anyq_ = 0;
            for (int l = 0; l < W; l++) anyq_ |= QN[l] > 0;
            #pragma omp simd
            for (int l = 0; l < W; l++) {
                HAS[l] = R0[l]; TC[l] = R0[l] != 0.0 ? TC0[l] : T[l];
                for (int q = 0; q < NO; q++) OBS[q * W + l] = OB0[q * W + l];
            }
            if (anyq_) for (int l = 0; l < W; l++) {
                if (QN[l] == 0) continue;
                const int pos = QH[l];
                const double tq = FT[l * QCAP + pos];
                double oq[NO];
                for (int q = 0; q < NO; q++) oq[q] = FO[(l * QCAP + pos) * NO + q];
                QH[l] = (pos + 1) % QCAP; QN[l]--;
                if (R0[l] != 0.0) PUSH(l, TC0[l], OB0 + l, W);  /* never full: one item was just popped */
                HAS[l] = 1.0; TC[l] = tq;
                for (int q = 0; q < NO; q++) OBS[q * W + l] = oq[q];
            }
            for (int l = 0; l < W; l++) {
                if (R0[l] == 0.0) continue;
                CK[l]++;
                NEXTT[l] = CK[l] < K ? ts[CK[l]] : INFINITY;
            }
            #pragma omp simd
            for (int l = 0; l < W; l++) f_upd(C + l, TC[l], OBS + l, CN + l, W);
            #pragma omp simd
            for (int l = 0; l < W; l++) {
                const double has = HAS[l];
                for (int q = 0; q < NC; q++) C[q * W + l] = has != 0.0 ? CN[q * W + l] : C[q * W + l];
            }
"""


def direct(src: str) -> str:
    """Round 0's checkpoints folded into the classifier at once where the lane's FIFO is empty (one
    combined pass per step; backlogged lanes pop their oldest item in the same pass): the FIFO only
    holds a step's second and later checkpoints and what queues behind them. Bit-identical."""
    return _one(src, _PUSH0, _DIRECT0)


def direct_busy(src: str) -> str:
    """``direct`` only in steps where the combined pass would find QBUSY lanes with something to
    classify (the rule the FIFO passes use); other steps push round 0 as the kernel does."""
    body = _DIRECT0.replace("            int anyq_ = 0;\n            for (int l = 0; l < W; l++) anyq_ |= QN[l] > 0;\n",
                            "")
    gate = ("            int anyq_ = 0, busy_ = 0;\n"
            "            for (int l = 0; l < W; l++) { anyq_ |= QN[l] > 0; busy_ += (QN[l] > 0) | (R0[l] != 0.0); }\n"
            "            if (busy_ >= QBUSY) {\n" + body + "            } else {\n" + _PUSH0 + "            }\n")
    return _one(src, _PUSH0, gate)


def vboth(src: str) -> str:
    return vpop(vpush(src))


def stageloop(src: str) -> str:
    """Stages 2-5 in a runtime loop over the stage: one inlined rhs body instead of four (-6.4 KB code)."""
    head = "        #pragma omp simd\n        for (int l = 0; l < W; l++) {\n            const double h = H[l];\n            YT[0 * W"
    start = src.index(head)
    tail = "KS[4] + l, W);\n"
    end = src.index(tail, start) + len(tail)
    parts = src[start:end].split("        #pragma omp simd\n")[1:]
    combos, rhss = parts[0::2], parts[1::2]
    cs = [re.search(r"T\[l\] \+ \(([^)]*)\) \* H\[l\]", r).group(1) for r in rhss]
    out = ["        {\n            static const double SC_[5] = {0.0, " + ", ".join(cs) + "};\n",
           "            #pragma GCC unroll 1\n            for (int s_ = 1; s_ <= 4; s_++) {\n                switch (s_) {\n"]
    for i, c in enumerate(combos):
        out.append(f"                case {i + 1}: {{\n        #pragma omp simd\n{c}                break; }}\n")
    out.append("                }\n        #pragma omp simd\n        for (int l = 0; l < W; l++) "
               "f_rhs(T[l] + SC_[s_] * H[l], YT + l, A + l, KS[s_] + l, W);\n            }\n        }\n")
    return src[:start] + "".join(out) + src[end:]


# ---- ablations (summaries wrong on purpose; the step sequence is unchanged) ---------------------

def nockpt(src: str) -> str:
    """Checkpoints are passed (CK advances, lanes still finish) but not interpolated, observed,
    queued or classified."""
    src = _one(src, "            for (int l = 0; l < W; l++) f_obs(TC0[l], PY0 + l, A + l, OB0 + l, W);\n", "")
    src = _one(src, "                PUSH(l, TC0[l], OB0 + l, W);\n", "")
    return _one(src, "                if (m == 0) break;\n", "                if (m == 0) break;\n                continue;\n")


def noobs(src: str) -> str:
    """Checkpoints interpolated and observed, never queued (so never classified)."""
    src = _one(src, "                PUSH(l, TC0[l], OB0 + l, W);\n", "")
    return _one(src, "                for (int i = 0; i < m; i++) PUSH(IL[i], IT_[i], POBS + i, NI);\n",
                "                __asm__ volatile(\"\" :: \"r\"(POBS) : \"memory\");\n")


def noupd(src: str) -> str:
    """Checkpoints observed, queued and popped by the classifier passes; the update itself skipped."""
    return _one(src, "            #pragma omp simd\n            for (int l = 0; l < W; l++) f_upd(C + l, TC[l], OBS + l, CN + l, W);\n", "")


# ---- probes (same results; they only take away the overlap of neighbouring regions) --------------

def lfence_ckpt(src: str) -> str:
    """lfence before the checkpoint path (round 0) and before the commit: no instruction of the
    checkpoint path overlaps the error estimate before it or the commit and next step after it."""
    src = _one(src, "        double any0 = 0.0;\n", "        __builtin_ia32_lfence();\n        double any0 = 0.0;\n")
    return _one(src, "        /* commit */\n", "        __builtin_ia32_lfence();\n        /* commit */\n")


def lfence_step(src: str) -> str:
    """lfence at the top of each iteration: one step attempt never overlaps the next."""
    return _one(src, "        if (*jb->stop) break;\n", "        if (*jb->stop) break;\n        __builtin_ia32_lfence();\n")


def _stage_rhs_calls(src: str) -> list[tuple[str, str]]:
    """(stage-time coefficient c, source line) of the four ``f_rhs`` calls at t + c h (stages 2-5)."""
    pat = (r"        for \(int l = 0; l < W; l\+\+\) f_rhs\(T\[l\] \+ \(([^)]*)\) \* H\[l\], YT \+ l, A \+ l, "
           r"KS\[\d\] \+ l, W\);\n")
    calls = [(m.group(1), m.group(0)) for m in re.finditer(pat, src)]
    if len(calls) != 4:
        raise SystemExit(f"expected the four stage rhs calls, found {len(calls)}")
    return calls


def tonly_twice(src: str) -> str:
    """The rhs's t-only part (``f_rhs_t``: for paper A ``cos(omega0 t**alpha)``, i.e. log, exp, cos)
    evaluated once more at each of stages 2-5, at a time moved by 2**-30 relative (else GCC reuses the
    rhs's own evaluation), into a scratch array: same results and step sequence,
    so the extra time is what four t-only evaluations per attempt cost (an upper bound on what a
    cheaper t-only part could save)."""
    for c, line in _stage_rhs_calls(src):
        extra = ("        #pragma omp simd\n"
                 f"        for (int l = 0; l < W; l++) f_rhs_t((T[l] + ({c}) * H[l]) * (1.0 + 0x1p-30), A + l, TVX_ + l, W);\n"
                 "        __asm__ volatile(\"\" :: \"r\"(TVX_) : \"memory\");\n")
        src = _one(src, line, line + extra)
    return _one(src, "    int QH[W], QN[W];\n", "    int QH[W], QN[W];\n    double TVX_[NTV * W] ALIGN;\n")


def _poly(var: str, coefs: list[str]) -> str:
    """Horner: coefs[0] + var * (coefs[1] + var * (...))."""
    out = coefs[-1]
    for c in reversed(coefs[:-1]):
        out = f"({c} + {var} * {out})"
    return out


def _estrin(var: str, coefs: list[str]) -> str:
    """Estrin's scheme: the same polynomial as :func:`_poly` with a dependency chain of depth
    ~log2(degree) instead of degree (more multiplications, shorter latency)."""
    terms, power = list(coefs), var
    while len(terms) > 1:
        nxt = [f"({terms[i]} + {power} * {terms[i + 1]})" for i in range(0, len(terms) - 1, 2)]
        if len(terms) % 2:
            nxt.append(terms[-1])
        terms, power = nxt, f"({power} * {power})"
    return terms[0]


def tonly_carry_estrin(src: str) -> str:
    """``tonly_carry`` with every polynomial by Estrin's scheme instead of Horner's (NOTES N29:
    whether the polynomials' latency or their operation count is what costs)."""
    return tonly_carry(src, poly=_estrin)


def _stages_with_forcing(src: str, forcing) -> str:
    """Stages 2-5: where ``INCR_`` holds, the t-only value TVS_[l] from ``forcing(c)`` (C statements in
    a loop over the lanes, c the stage's time coefficient) and ``f_rhs_y``; elsewhere the kernel's own
    ``f_rhs``."""
    for c, line in _stage_rhs_calls(src):
        k = re.search(r"KS\[(\d)\]", line).group(1)
        repl = ("        if (INCR_) {\n"
                "            #pragma omp simd\n"
                "            for (int l = 0; l < W; l++) {\n"
                + forcing(c) +
                "            }\n"
                "            #pragma omp simd\n"
                f"            for (int l = 0; l < W; l++) f_rhs_y(T[l] + ({c}) * H[l], TVS_ + l, YT + l, A + l, KS[{k}] + l, W);\n"
                "        } else {\n"
                "        #pragma omp simd\n" + line + "        }\n")
        src = _one(src, "        #pragma omp simd\n" + line, repl)
    return src


def _incremental_stages(src: str, om: str, l1p: str, em1: str, phase_code: str) -> str:
    """Stages 2-5 with the forcing at t + c h from the phase step d_ (``phase_code`` turns d_ into
    TVS_[l]) where ``INCR_`` holds."""
    return _stages_with_forcing(src, lambda c: (
        f"                const double x_ = ({c}) * H[l] * RT_[l];\n"
        f"                const double z_ = A[l] * ({l1p});\n"
        f"                const double d_ = ({om}) * P0_[l] * ({em1});\n"
        + phase_code))


def _forcing_and_series(src: str, name: str, angle: str, poly) -> tuple[str, str, str, str, str]:
    """omega0 of paper A's t-only part ``cos(omega0 t**alpha)`` (asserted), and C expressions for
    log1p(x_), expm1(z_) (|x_|, |z_| <= 2**-6, Taylor to the 11th power) and sin/cos of ``angle``
    (to the 19th/18th power, in ``angle``2_ = angle**2) by ``poly``."""
    body = src[src.index("void f_rhs_t("):]
    body = body[: body.index("\n}\n")]
    m = re.search(r"const double (v\d+) = jpow\(t, (v\d+)\);\n\s*const double (v\d+) = \(([^)]*)\) \* \1;\n"
                  r"\s*const double (v\d+) = cos\(\3\);", body)
    if m is None or "a[0*S]" not in body:
        raise SystemExit(f"{name}: the rhs's t-only part is not cos(omega0 * t**alpha) with alpha = a[0]")
    fact = [1.0]
    for k in range(1, 20):
        fact.append(fact[-1] * k)
    a2 = angle[:-1] + "2_"
    l1p = "x_ * " + poly("x_", [f"({(-1.0) ** k / (k + 1)!r})" for k in range(11)])
    em1 = "z_ * " + poly("z_", [f"({1.0 / fact[k + 1]!r})" for k in range(11)])
    sn = f"{angle} * " + poly(a2, [f"({(-1.0) ** k / fact[2 * k + 1]!r})" for k in range(10)])
    cs = poly(a2, [f"({(-1.0) ** k / fact[2 * k]!r})" for k in range(10)])
    return m.group(4), l1p, em1, sn, cs


def tonly_incr(src: str) -> str:
    """Probe for NOTES N28 (results differ from the kernel at the rounding level): at stages 2-5 the
    forcing cos(omega0 t**alpha) at t + c h is computed from t**alpha and cos/sin of the phase at t
    (recomputed every attempt) by log1p/expm1 Taylor polynomials in c h / t and angle addition with
    sin/cos polynomials of the phase step, for blocks where every lane has h <= 2**-6 t and a phase
    step <= 0.5; other blocks take the libm path. Only for paper A's t-only part (asserted)."""
    om, l1p, em1, sn, cs = _forcing_and_series(src, "tonly_incr", "d_", _poly)
    decl = "    double RT_[W] ALIGN, P0_[W] ALIGN, C0_[W] ALIGN, S0_[W] ALIGN, TVS_[W] ALIGN;\n    int INCR_ = 0;\n"
    src = _one(src, "    int QH[W], QN[W];\n", "    int QH[W], QN[W];\n" + decl)
    top = "        for (int l = 0; l < W; l++) H[l] = TN[l] - T[l];\n"
    start = (top + "        INCR_ = 1;\n"
             "        for (int l = 0; l < W; l++) if (!(T[l] > 0.0 && H[l] <= 0x1p-6 * T[l])) { INCR_ = 0; break; }\n"
             "        if (INCR_) {\n"
             "            #pragma omp simd\n"
             "            for (int l = 0; l < W; l++) {\n"
             "                RT_[l] = 1.0 / T[l];\n"
             "                P0_[l] = jpow(T[l], A[l]);\n"
             f"                C0_[l] = cos(({om}) * P0_[l]);\n"
             "            }\n"
             "            #pragma omp simd\n"  # its own loop: GCC would fuse sin and cos into a scalar sincos
             f"            for (int l = 0; l < W; l++) S0_[l] = sin(({om}) * P0_[l]);\n"
             f"            for (int l = 0; l < W; l++) if (!(fabs(({om}) * P0_[l] * A[l]) * (H[l] * RT_[l]) * 1.0625 <= 0.5)) {{ INCR_ = 0; break; }}\n"
             "        }\n")
    src = _one(src, top, start)
    return _incremental_stages(src, om, l1p, em1,
                               "                const double d2_ = d_ * d_;\n"
                               f"                TVS_[l] = C0_[l] * ({cs}) - S0_[l] * ({sn});\n")


def tonly_carry(src: str, poly=None) -> str:
    """Probe for NOTES N29: ``tonly_incr`` with the two changes N28 asked for. The phase step is
    reduced by quadrants (two-part pi/2, |step| <= 64) before the sin/cos polynomials, so only
    h <= t/64 limits the incremental path; t**alpha and cos/sin of the phase at t are carried from the
    previous attempt's t + h (computed there with the forcing the loop needs anyway, plus a sin),
    recomputed only after a refill."""
    # |r_| <= pi/4 after the quadrant reduction
    om, l1p, em1, sn, cs = _forcing_and_series(src, "tonly_carry", "r_", poly or _poly)
    arrays = ("RT_", "P0_", "C0_", "S0_", "TVS_", "PN_", "CN_", "SN_", "VAL_")
    decl = ("    double " + ", ".join(f"{a}[W] ALIGN" for a in arrays) + ";\n    int INCR_ = 0;\n"
            "    for (int l = 0; l < W; l++) VAL_[l] = 0.0;\n")
    src = _one(src, "    int QH[W], QN[W];\n", "    int QH[W], QN[W];\n" + decl)
    src = _one(src, "T[l] = t0; CK[l] = 0;", "T[l] = t0; CK[l] = 0; VAL_[l] = 0.0;")
    top = "        for (int l = 0; l < W; l++) H[l] = TN[l] - T[l];\n"
    start = (top + "        INCR_ = 1;\n"
             "        for (int l = 0; l < W; l++) if (!(T[l] > 0.0 && H[l] <= 0x1p-6 * T[l])) { INCR_ = 0; break; }\n"
             "        if (INCR_) {\n"
             "            int need_ = 0;\n"
             "            for (int l = 0; l < W; l++) need_ |= VAL_[l] == 0.0;\n"
             "            if (need_) {\n"
             "                #pragma omp simd\n"
             f"                for (int l = 0; l < W; l++) {{ P0_[l] = jpow(T[l], A[l]); C0_[l] = cos(({om}) * P0_[l]); VAL_[l] = 1.0; }}\n"
             "                #pragma omp simd\n"
             f"                for (int l = 0; l < W; l++) S0_[l] = sin(({om}) * P0_[l]);\n"
             "            }\n"
             "            #pragma omp simd\n"
             "            for (int l = 0; l < W; l++) RT_[l] = 1.0 / T[l];\n"
             f"            for (int l = 0; l < W; l++) if (!(fabs(({om}) * P0_[l] * A[l]) * (H[l] * RT_[l]) * 1.0625 <= 64.0)) {{ INCR_ = 0; break; }}\n"
             "        }\n")
    src = _one(src, top, start)
    quad = ("                const double k_ = rint(d_ * 0x1.45f306dc9c883p-1);\n"  # 2/pi
            "                const double r_ = (d_ - k_ * 0x1.921fb54400000p+0) - k_ * 0x1.0b4611a626331p-34;\n"
            "                const double r2_ = r_ * r_;\n"
            f"                const double sr_ = {sn};\n"
            f"                const double cr_ = {cs};\n"
            "                const double q_ = k_ - 4.0 * floor(0.25 * k_);\n"
            "                const double cd_ = q_ == 0.0 ? cr_ : (q_ == 1.0 ? -sr_ : (q_ == 2.0 ? -cr_ : sr_));\n"
            "                const double sd_ = q_ == 0.0 ? sr_ : (q_ == 1.0 ? cr_ : (q_ == 2.0 ? -sr_ : -cr_));\n")
    src = _incremental_stages(src, om, l1p, em1, quad + "                TVS_[l] = C0_[l] * cd_ - S0_[l] * sd_;\n")
    # the forcing at t + h: the same expression as f_rhs_t (so TV is unchanged), keeping t**alpha and sin
    tn = "        for (int l = 0; l < W; l++) f_rhs_t(TN[l], A + l, TV + l, W);\n"
    src = _one(src, tn, f"        for (int l = 0; l < W; l++) {{ PN_[l] = jpow(TN[l], A[l]); CN_[l] = cos(({om}) * PN_[l]); TV[l] = CN_[l]; }}\n"
               "        #pragma omp simd\n"
               f"        for (int l = 0; l < W; l++) SN_[l] = sin(({om}) * PN_[l]);\n")
    commit_end = "            T[l] = TP[l]; TN[l] = TNX[l];\n        }\n"
    src = _one(src, commit_end, commit_end +
               "        #pragma omp simd\n"
               "        for (int l = 0; l < W; l++) {\n"
               "            const double kp_ = KEEP[l];\n"
               "            P0_[l] = kp_ != 0.0 ? PN_[l] : P0_[l]; C0_[l] = kp_ != 0.0 ? CN_[l] : C0_[l];\n"
               "            S0_[l] = kp_ != 0.0 ? SN_[l] : S0_[l]; VAL_[l] = kp_ != 0.0 ? 1.0 : VAL_[l];\n"
               "        }\n")
    return src


def _hermite_weights(th: float) -> tuple[float, ...]:
    """Quintic Hermite basis on [0, 1] at ``th`` for (p1 - p0, h p0', h p1', h^2 p0'', h^2 p1'')
    (the weight of p0 is 1 - that of p1, so p0 enters exactly)."""
    return (10 * th**3 - 15 * th**4 + 6 * th**5, th - 6 * th**3 + 8 * th**4 - 3 * th**5,
            -4 * th**3 + 7 * th**4 - 3 * th**5, 0.5 * th**2 - 1.5 * th**3 + 1.5 * th**4 - 0.5 * th**5,
            0.5 * th**3 - th**4 + 0.5 * th**5)


def cmd_herm_check(a) -> None:
    """The worst relative error of ``tonly_herm``'s interpolated t**alpha at the four stage times, in
    40-digit decimal arithmetic (so only the truncation error shows), at h = t/128 (its bound) and
    h = t/256, for alpha and t across the benchmark's range (NOTES N30)."""
    import decimal

    decimal.getcontext().prec = 40
    D = decimal.Decimal
    kern, _, _ = bench.native_kernel(64)
    stages = [float.fromhex(c.strip("()")) for c, _ in _stage_rhs_calls(kern.source)]
    for x in (2.0**-7, 2.0**-8):
        worst = 0.0
        for alpha in (0.25, 0.3, 0.5, 7 / 9, 1.0):
            for t in (1.0, 10.0, 1000.0, 9999.0):
                al, tt, h = D(alpha), D(t), D(t) * D(x)
                p0, pn = tt**al, (tt + h) ** al
                d0, dn = h * al * p0 / tt, h * al * pn / (tt + h)
                e0, en = h * (al - 1) / tt * d0, h * (al - 1) / (tt + h) * dn
                for th in stages:
                    w1, w2, w3, w4, w5 = (D(w) for w in _hermite_weights(th))
                    p = p0 + w1 * (pn - p0) + w2 * d0 + w3 * dn + w4 * e0 + w5 * en
                    exact = (tt + D(th) * h) ** al
                    worst = max(worst, float(abs(p - exact) / exact))
        print(f"h = t * 2**{int(np.log2(x))}: worst relative error {worst:.2e} (stage times {stages})")


def tonly_herm(src: str, count: bool = False) -> str:
    """Probe for NOTES N30 (results differ from the kernel at the rounding level): t**alpha at stages
    2-5 by quintic Hermite interpolation between the step's ends, from t**alpha and its first two
    derivatives (alpha p / t, (alpha - 1) p' / t: no libm) at t (carried from the previous attempt)
    and at t + h (computed there anyway for the sixth stage); cos stays libmvec's. Truncation error
    <= |alpha (alpha-1)...(alpha-5)| / 720 * max theta^3 (1-theta)^3 * (h/t)^6 relative: below 1.1e-16
    for alpha in (0, 1] and h <= t/128, the bound every lane of a block must meet (otherwise the block
    takes the kernel's jpow). Only for paper A's t-only part (asserted)."""
    om = _forcing_and_series(src, "tonly_herm", "r_", _poly)[0]
    arrays = ("RT_", "RTN_", "P0_", "PN_", "D0_", "DN_", "E0_", "EN_", "TVS_", "VAL_")
    decl = ("    double " + ", ".join(f"{a}[W] ALIGN" for a in arrays) + ";\n    int INCR_ = 0;\n"
            "    for (int l = 0; l < W; l++) VAL_[l] = 0.0;\n")
    src = _one(src, "    int QH[W], QN[W];\n", "    int QH[W], QN[W];\n" + decl)
    src = _one(src, "T[l] = t0; CK[l] = 0;", "T[l] = t0; CK[l] = 0; VAL_[l] = 0.0;")
    # the forcing at t + h moves to the top of the iteration: the stages need t**alpha there
    tn = "        #pragma omp simd\n        for (int l = 0; l < W; l++) f_rhs_t(TN[l], A + l, TV + l, W);\n"
    src = _one(src, tn, "")
    top = "        for (int l = 0; l < W; l++) H[l] = TN[l] - T[l];\n"
    start = (top + "        #pragma omp simd\n"
             f"        for (int l = 0; l < W; l++) {{ PN_[l] = jpow(TN[l], A[l]); TV[l] = cos(({om}) * PN_[l]); }}\n"
             "        INCR_ = 1;\n"
             "        for (int l = 0; l < W; l++)\n"
             "            if (ACT[l] != 0.0 && !(VAL_[l] != 0.0 && T[l] > 0.0 && H[l] <= 0x1p-7 * T[l])) { INCR_ = 0; break; }\n"
             + ("        HN_[INCR_]++;\n" if count else "") +
             "        if (INCR_) {\n"
             "            #pragma omp simd\n"
             "            for (int l = 0; l < W; l++) {\n"
             "                const double rt = 1.0 / T[l], rtn = 1.0 / TN[l], a = A[l], h = H[l];\n"
             "                D0_[l] = h * a * P0_[l] * rt; E0_[l] = h * (a - 1.0) * rt * D0_[l];\n"
             "                DN_[l] = h * a * PN_[l] * rtn; EN_[l] = h * (a - 1.0) * rtn * DN_[l];\n"
             "            }\n"
             "        }\n")
    src = _one(src, top, start)
    def forcing(c: str) -> str:
        w1, w2, w3, w4, w5 = (native._flit(x) for x in _hermite_weights(float.fromhex(c.strip("()"))))
        return (f"                const double p_ = P0_[l] + {w1} * (PN_[l] - P0_[l]) + ({w2} * D0_[l] + {w3} * DN_[l])"
                f" + ({w4} * E0_[l] + {w5} * EN_[l]);\n"
                f"                TVS_[l] = cos(({om}) * p_);\n")

    src = _stages_with_forcing(src, forcing)
    commit_end = "            T[l] = TP[l]; TN[l] = TNX[l];\n        }\n"
    src = _one(src, commit_end, commit_end +
               "        #pragma omp simd\n"
               "        for (int l = 0; l < W; l++) {\n"
               "            const double kp_ = KEEP[l];\n"
               "            P0_[l] = kp_ != 0.0 ? PN_[l] : P0_[l]; VAL_[l] = kp_ != 0.0 ? 1.0 : VAL_[l];\n"
               "        }\n")
    if count:
        src = _one(src, "int64_t stabjax_run(const job_t *jb) {",
                   "#include <stdio.h>\nstatic __thread long HN_[2];\nint64_t stabjax_run(const job_t *jb) {")
        src = _one(src, "    }\n    return finished;\n",
                   "    }\n    fprintf(stderr, \"tonly_herm: incremental path in %ld of %ld iterations\\n\", HN_[1], HN_[0] + HN_[1]);\n"
                   "    return finished;\n")
    return src


def tonly_herm_count(src: str) -> str:
    """``tonly_herm`` counting the iterations that take the interpolated path (printed per thread)."""
    return tonly_herm(src, count=True)


VARIANTS = {f.__name__: f for f in (vpush, vpop, vboth, direct, direct_busy, stageloop, nockpt, noobs, noupd, lfence_ckpt, lfence_step,
                                    tonly_twice, tonly_incr, tonly_carry, tonly_carry_estrin, tonly_herm,
                                    tonly_herm_count)}


# ---- region timing ------------------------------------------------------------------------------

_REGIONS = [
    ("        /* error estimate and diffrax's PIDController", "stages"),
    ("        double any0 = 0.0;\n", "error+controller"),
    ("            for (int l = 0; l < W; l++) {\n                if (R0[l] == 0.0) continue;\n", "round0: interp+observe"),
    ("        double more = 0.0;\n", "round0: push"),
    ("        for (;;) {\n            int busy = 0", "later checkpoints"),
    ("            #pragma omp simd\n            for (int l = 0; l < W; l++) f_upd(", "classifier: scan+pop"),
    ("        }\n\n        /* commit */\n", "classifier: update"),
]


def timed(src: str) -> str:
    """rdtsc between the loop's regions; per-thread cycle sums printed to stderr when a thread ends."""
    src = _one(src, "        if (*jb->stop) break;\n", "        if (*jb->stop) break;\n        uint64_t tk_ = __rdtsc();\n")
    names = []
    for anchor, name in _REGIONS:
        k = len(names)
        names.append(name)
        indent = " " * (len(anchor) - len(anchor.lstrip(" ")))
        src = _one(src, anchor, f"{indent}{{ uint64_t t2_ = __rdtsc(); TACC_[{k}] += t2_ - tk_; tk_ = t2_; }}\n" + anchor)
    names.append("commit+finish")
    n = len(names)
    report = ("    { static const char *nm[] = {" + ", ".join(f'"{x}"' for x in names) + "}; double tot = 0;\n"
              f"      for (int i = 0; i < {n}; i++) tot += TACC_[i];\n"
              f"      for (int i = 0; i < {n}; i++) fprintf(stderr, \"%-24s %5.1f%% %8.0f cycles per iteration\\n\","
              " nm[i], 100 * TACC_[i] / tot, TACC_[i] / (double)NIT_);\n"
              "      fprintf(stderr, \"%ld iterations, %.3g cycles (TSC)\\n\", NIT_, tot); }\n")
    end = "    }\n    return finished;\n"
    src = _one(src, end, f"        {{ uint64_t t2_ = __rdtsc(); TACC_[{n - 1}] += t2_ - tk_; NIT_++; }}\n    }}\n"
               + report + "    return finished;\n")
    return _one(src, "int64_t stabjax_run(const job_t *jb) {",
                "#include <x86intrin.h>\n#include <stdio.h>\nstatic __thread double TACC_[16]; static __thread long NIT_;\n"
                "int64_t stabjax_run(const job_t *jb) {")


# ---- the rhs alone --------------------------------------------------------------------------------

_RHS_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
static double now_(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
static double Y_[NS * W] ALIGN, K_[NS * W] ALIGN, A_[NA * W] ALIGN, T_[W] ALIGN;
static double PY_[NS * W] ALIGN, OB_[NO * W] ALIGN, C_[NC * W] ALIGN, CN_[NC * W] ALIGN, TC_[W] ALIGN;
/* mode 1: the rhs, each evaluation feeding the next (state += 1e-9 f, time += 1e-3 f);
   mode 2: observe + classifier update, each update feeding the next, in their own loops;
   mode 3: both, one after the other; mode 4: both in one loop body (independent work side by side) */
int main(int argc, char **argv) {
    const int mode = MODE;  /* a compile-time constant: each mode is its own program */
    const long R = argc > 1 ? atol(argv[1]) : 1000000;
    for (int l = 0; l < W; l++) {
        for (int q = 0; q < NS; q++) { Y_[q * W + l] = Y0_[q] + 1e-3 * l; PY_[q * W + l] = 0.9 * Y_[q * W + l]; }
        for (int q = 0; q < NA; q++) A_[q * W + l] = A0_[q];
        for (int q = 0; q < NC; q++) C_[q * W + l] = C0_[q];
        T_[l] = 100.0 + l; TC_[l] = 0.9 * T1_ + l;
    }
    const double t0 = now_();
    for (long r = 0; r < R; r++) {
        if (mode == 1 || mode == 3) {
            #pragma omp simd
            for (int l = 0; l < W; l++) f_rhs(T_[l], Y_ + l, A_ + l, K_ + l, W);
        }
        if (mode == 2 || mode == 3) {
            #pragma omp simd
            for (int l = 0; l < W; l++) f_obs(TC_[l], PY_ + l, A_ + l, OB_ + l, W);
            #pragma omp simd
            for (int l = 0; l < W; l++) f_upd(C_ + l, TC_[l], OB_ + l, CN_ + l, W);
        }
        if (mode == 4) {
            #pragma omp simd
            for (int l = 0; l < W; l++) {
                f_rhs(T_[l], Y_ + l, A_ + l, K_ + l, W);
                f_obs(TC_[l], PY_ + l, A_ + l, OB_ + l, W);
                f_upd(C_ + l, TC_[l], OB_ + l, CN_ + l, W);
            }
        }
        #pragma omp simd
        for (int l = 0; l < W; l++) {
            if (mode != 2) { for (int q = 0; q < NS; q++) Y_[q * W + l] += 1e-9 * K_[q * W + l]; T_[l] += 1e-3 * K_[l]; }
            if (mode != 1) { for (int q = 0; q < NC; q++) C_[q * W + l] = CN_[q * W + l]; TC_[l] += 1e-3; PY_[l] += 1e-12 * OB_[l]; }
        }
    }
    const double dt = now_() - t0;
    double s = 0;  /* what each mode computed (the classifier state holds infinities and NaNs by design) */
    for (int i = 0; i < NS * W; i++) s += K_[i];
    for (int i = 0; i < NO * W; i++) s += OB_[i];
    static const char *what[] = {"", "rhs", "observe + classifier update", "both, one after the other", "both in one loop body"};
    printf("mode %d, %-28s %d lanes: %6.2f ns per lane (checksum %g)\n", mode, what[mode], W, dt / (R * W) * 1e9, s);
    return 0;
}
"""


def _variant_kernel(kern, transform):
    k = copy.copy(kern)
    k.source = transform(kern.source)
    k.lib = native._build(k.source)
    return k


def _flags() -> list[str]:
    for flags in native._flag_sets():
        if "-DSTABJAX_LIBMVEC" in flags:
            return [f for f in flags if f not in ("-fPIC", "-shared")]
    raise SystemExit("needs the x86-64 libmvec build of the kernel")


def cmd_ab(a) -> None:
    kern, ain, y0 = bench.native_kernel(a.n)
    names = ["base", *a.variants]
    kerns = {"base": kern, **{v: _variant_kernel(kern, VARIANTS[v]) for v in a.variants}}
    walls: dict[str, list[float]] = {v: [] for v in names}
    ref = None
    for rnd in range(a.rounds):
        for v in names if rnd % 2 == 0 else names[::-1]:
            t = time.perf_counter()
            r = native.run_raw(kerns[v], ain, y0, threads=a.threads)
            w = time.perf_counter() - t
            walls[v].append(w)
            ref = r if ref is None else ref
            same = np.array_equal(r["c"], ref["c"], equal_nan=True) and np.array_equal(r["y"], ref["y"], equal_nan=True)
            dy = "" if same else f" (final states: max |difference| {np.nanmax(np.abs(r['y'] - ref['y'])):.1e})"
            print(f"{v:10s} round {rnd}: wall {w:.3f} s, {int(r['nacc'].sum())} accepted, {int(r['nrej'].sum())} "
                  f"rejected, results {'equal to' if same else 'DIFFER from'} base{dy}", flush=True)
    for v in a.variants:
        ratios = [x / b for b, x in zip(walls["base"], walls[v])]
        print(f"{v}/base wall per round: " + ", ".join(f"{x:.3f}" for x in ratios)
              + f"; median {np.median(ratios):.3f}, faster in {sum(x < 1 for x in ratios)}/{len(ratios)}")


def cmd_regions(a) -> None:
    kern, ain, y0 = bench.native_kernel(a.n)
    k = _variant_kernel(kern, timed)
    t = time.perf_counter()
    r = native.run_raw(k, ain, y0, threads=a.threads)
    w = time.perf_counter() - t
    att = int(r["nacc"].sum() + r["nrej"].sum())
    print(f"wall {w:.3f} s, {att} attempts, {w * a.threads / att * 1e9:.0f} ns of one thread per attempt")


# Stand-ins for parts of f_rhs (wrong values on purpose; mode 1's chained evaluations only): what
# each part costs the rhs alone (NOTES N30). Each maps the body of f_rhs to a cheaper one.
_STANDINS = {
    "no sqrt/div": lambda b: b.replace("sqrt(", "(0.25 + 0.5 * ").replace("1.0 / v27", "(v27 * 0.9 + 0.1)"),
    "no cbrt": lambda b: b.replace("cbrt(", "(0.3 + 0.5 * "),
    "no t-only (jpow, cos)": lambda b: b.replace("jpow(t, v6)", "(t * v6)").replace("cos(", "(0.1 + 0.2 * "),
}


def _rhs_standins(src: str, d: Path, a) -> None:
    i = src.index("static inline __attribute__((always_inline)) void f_rhs(")
    j = src.index("static inline __attribute__((always_inline)) void f_rhs_t(")
    exes = {"kernel's rhs": d / "rhs1"}
    for k, (name, f) in enumerate(_STANDINS.items()):
        body = f(src[i:j])
        if body == src[i:j]:
            raise SystemExit(f"stand-in {name!r} changes nothing in this model's rhs")
        c = d / f"standin{k}.c"
        c.write_text(src[:i] + body + src[j:])
        exes[name] = d / f"standin{k}"
        subprocess.run([native.compiler(), *_flags(), "-DMODE=1", str(c), "-o", str(exes[name]), "-lmvec", "-lm"],
                       check=True)
    for _ in range(a.rounds):
        for name, exe in exes.items():
            out = subprocess.run([str(exe), str(a.reps)], check=True, capture_output=True, text=True).stdout
            print(f"{name:24s} {out.split('lanes:')[1].split('(')[0].strip()}", flush=True)


def cmd_rhs(a) -> None:
    kern, ain, y0 = bench.native_kernel(64)
    src = kern.source
    pre = src[: src.index("static inline int finite_row")]
    a0 = np.asarray(ain[32]).ravel()  # alpha near the middle of the benchmark's range
    def arr(name, size, xs):
        return f"static const double {name}[{size}] = {{" + ", ".join(native._flit(x) for x in xs) + "};\n"

    consts = (arr("Y0_", "NS", np.asarray(y0[0])) + arr("A0_", "NA", a0)
              + arr("C0_", "NC", np.asarray(kern.model.c0).ravel()) + f"#define T1_ {float(kern.icfg.t1)!r}\n")
    with tempfile.TemporaryDirectory() as d:
        c = Path(d) / "rhs.c"
        c.write_text(pre + consts + _RHS_MAIN)
        for mode in (1, 2, 3, 4):
            subprocess.run([native.compiler(), *_flags(), f"-DMODE={mode}", str(c), "-o", str(Path(d) / f"rhs{mode}"),
                            "-lmvec", "-lm"], check=True)
        if a.standins:
            _rhs_standins(pre + consts + _RHS_MAIN, Path(d), a)
            return
        probe, pexe = HERE / "probes" / "libmvec_calls.c", Path(d) / "calls"
        subprocess.run([native.compiler(), "-O2", "-march=native", str(probe), "-o", str(pexe), "-lmvec", "-lm"], check=True)
        for _ in range(a.rounds):
            for mode in (1, 2, 3, 4):
                subprocess.run([str(Path(d) / f"rhs{mode}"), str(a.reps)], check=True)
            subprocess.run([str(pexe)], check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ab", help="base kernel against variants, interleaved rounds")
    p.add_argument("variants", nargs="+", choices=sorted(VARIANTS))
    p.add_argument("--n", type=int, default=4096)
    p.add_argument("--rounds", "--pairs", type=int, default=4)
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("regions", help="cycles per loop region (rdtsc)")
    p.add_argument("--n", type=int, default=4096)
    p.add_argument("--threads", type=int, default=1)
    sub.add_parser("herm-check", help="truncation error of tonly_herm's interpolation (40 digits)")
    p = sub.add_parser("rhs", help="the rhs alone and the libmvec calls")
    p.add_argument("--reps", type=int, default=1000000)
    p.add_argument("--standins", action="store_true", help="the rhs with stand-ins for its sqrt/div, cbrt, t-only part")
    p.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    {"ab": cmd_ab, "regions": cmd_regions, "rhs": cmd_rhs, "herm-check": cmd_herm_check}[a.cmd](a)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
