/* Cost of one 8-lane libmvec call (glibc's AVX-512 cos, exp, log, cbrt) and of a 512-bit sqrt and
   division: latency (each call's result feeds the next through one cheap op) and throughput (four
   independent calls per round), in cycles of the 2.0 GHz clock (NOTES.md N26).
   gcc -O2 -march=native libmvec_calls.c -o libmvec_calls -lmvec -lm && ./libmvec_calls */
#include <immintrin.h>
#include <stdio.h>
#include <time.h>
__m512d _ZGVeN8v_cos(__m512d); __m512d _ZGVeN8v_exp(__m512d); __m512d _ZGVeN8v_log(__m512d); __m512d _ZGVeN8v_cbrt(__m512d);
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
#define GHZ 2.0
#define BENCH(NAME, F, X0, FIX) { \
    const long R = 4000000; \
    __m512d a = _mm512_set1_pd(X0), b = _mm512_set1_pd(X0 * 1.1), c = _mm512_set1_pd(X0 * 1.2), d = _mm512_set1_pd(X0 * 1.3); \
    double t = now(); \
    for (long r = 0; r < R; r++) { a = F(a); a = FIX(a); } \
    const double lat = (now() - t) / R * GHZ * 1e9; \
    __m512d s = _mm512_setzero_pd(); t = now(); \
    for (long r = 0; r < R; r++) { s = _mm512_add_pd(s, F(b)); s = _mm512_add_pd(s, F(c)); s = _mm512_add_pd(s, F(d)); s = _mm512_add_pd(s, F(a)); } \
    const double thr = (now() - t) / (4 * R) * GHZ * 1e9; \
    double o[8]; _mm512_storeu_pd(o, _mm512_add_pd(a, s)); \
    printf("%-5s latency %5.1f cycles per call, throughput %5.1f cycles per call (checksum %g)\n", NAME, lat, thr, o[0]); }
/* keep the chained argument in range, so that every call takes the fast path */
static inline __m512d fix_cos(__m512d x) { return _mm512_add_pd(x, _mm512_set1_pd(100.0)); }
static inline __m512d fix_exp(__m512d x) { return _mm512_mul_pd(x, _mm512_set1_pd(1e-3)); }
static inline __m512d fix_log(__m512d x) { return _mm512_add_pd(_mm512_abs_pd(x), _mm512_set1_pd(2.0)); }
static inline __m512d fix_cbrt(__m512d x) { return _mm512_add_pd(x, _mm512_set1_pd(0.5)); }
int main(void) {
    BENCH("cos", _ZGVeN8v_cos, 3.0, fix_cos)
    BENCH("exp", _ZGVeN8v_exp, 0.5, fix_exp)
    BENCH("log", _ZGVeN8v_log, 5.0, fix_log)
    BENCH("cbrt", _ZGVeN8v_cbrt, 5.0, fix_cbrt)
    {
        const long R = 4000000; __m512d a = _mm512_set1_pd(2.0); double t = now();
        for (long r = 0; r < R; r++) { a = _mm512_sqrt_pd(a); a = _mm512_add_pd(a, _mm512_set1_pd(1.0)); }
        printf("sqrt  latency %5.1f cycles (with one add; checksum %g)\n", (now() - t) / R * GHZ * 1e9, a[0]);
        a = _mm512_set1_pd(2.0); t = now();
        for (long r = 0; r < R; r++) { a = _mm512_div_pd(_mm512_set1_pd(1.0), a); a = _mm512_add_pd(a, _mm512_set1_pd(1.0)); }
        printf("div   latency %5.1f cycles (with one add; checksum %g)\n", (now() - t) / R * GHZ * 1e9, a[0]);
    }
    return 0;
}
