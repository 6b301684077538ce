/* Whether the two 8-lane halves of a 16-lane block overlap across libmvec calls (NOTES.md N30):
   paper A's t-only chain cos(exp(alpha log t)) on 16 lanes, each round's t fed by the last round's
   result (a latency-bound chain). Mode 0: an "omp simd" loop as the kernel has it (GCC emits half 0's
   log, exp, cos, then half 1's); mode 1: the same calls by hand with the halves interleaved (log, log,
   exp, exp, cos, cos). Equal times mean the out-of-order core already overlaps the halves.
   gcc -O3 -fopenmp-simd -fno-math-errno -march=native -mprefer-vector-width=512 tonly_chain.c -o tonly_chain -lmvec -lm
   ./tonly_chain 2000000 0 && ./tonly_chain 2000000 1 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <immintrin.h>
#pragma omp declare simd notinbranch
double exp(double);
#pragma omp declare simd notinbranch
double log(double);
#pragma omp declare simd notinbranch
double cos(double);
__m512d _ZGVeN8v_log(__m512d); __m512d _ZGVeN8v_exp(__m512d); __m512d _ZGVeN8v_cos(__m512d);
#define W 16
static double now_(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
static double T[W] __attribute__((aligned(64))), A[W] __attribute__((aligned(64))), O[W] __attribute__((aligned(64)));
int main(int argc, char **argv) {
    const long R = atol(argv[1]); const int mode = atoi(argv[2]);
    for (int l = 0; l < W; l++) { T[l] = 100.0 + l; A[l] = 0.3 + 0.04 * l; }
    double t0 = now_();
    if (mode == 0) {
        for (long r = 0; r < R; r++) {
            #pragma omp simd
            for (int l = 0; l < W; l++) O[l] = cos(exp(A[l] * log(T[l])));
            #pragma omp simd
            for (int l = 0; l < W; l++) T[l] += 1e-3 * O[l];
        }
    } else {
        for (long r = 0; r < R; r++) {
            __m512d t0v = _mm512_load_pd(T), t1v = _mm512_load_pd(T + 8);
            __m512d l0 = _ZGVeN8v_log(t0v), l1 = _ZGVeN8v_log(t1v);
            __m512d e0 = _ZGVeN8v_exp(_mm512_mul_pd(_mm512_load_pd(A), l0)), e1 = _ZGVeN8v_exp(_mm512_mul_pd(_mm512_load_pd(A + 8), l1));
            __m512d c0 = _ZGVeN8v_cos(e0), c1 = _ZGVeN8v_cos(e1);
            _mm512_store_pd(T, _mm512_fmadd_pd(_mm512_set1_pd(1e-3), c0, t0v));
            _mm512_store_pd(T + 8, _mm512_fmadd_pd(_mm512_set1_pd(1e-3), c1, t1v));
        }
    }
    double dt = now_() - t0;
    double s = 0; for (int l = 0; l < W; l++) s += T[l];
    printf("mode %d: %.2f ns per lane (%.1f cycles at 2 GHz) checksum %.17g\n", mode, dt / (R * W) * 1e9, dt / (R * W) * 2e9, s);
}
