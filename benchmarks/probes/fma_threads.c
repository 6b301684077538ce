/* Float64 FMA throughput per thread, N concurrent threads (NOTES.md N24).
   gcc -O2 -mavx512f -mfma fma_threads.c -o fma_threads -lpthread && ./fma_threads 1 && ./fma_threads 2 */
#include <immintrin.h>
#include <stdlib.h>
#include <stdio.h>
#include <pthread.h>
#include <time.h>
static double now(){struct timespec t;clock_gettime(CLOCK_MONOTONIC,&t);return t.tv_sec+1e-9*t.tv_nsec;}
static void* work(void*arg){
  __m512d a[12]; __m512d m=_mm512_set1_pd(0.9999999), c=_mm512_set1_pd(1e-9);
  for(int i=0;i<12;i++) a[i]=_mm512_set1_pd(i);
  for(long it=0; it<200000000L; it++){
    #pragma GCC unroll 12
    for(int i=0;i<12;i++) a[i]=_mm512_fmadd_pd(a[i],m,c);
  }
  double s=0; for(int i=0;i<12;i++) s+=_mm512_reduce_add_pd(a[i]);
  *(double*)arg=s; return 0;
}
int main(int argc,char**argv){
  int n=atoi(argv[1]); pthread_t th[4]; double r[4];
  double t0=now();
  for(int i=0;i<n;i++) pthread_create(&th[i],0,work,&r[i]);
  for(int i=0;i<n;i++) pthread_join(th[i],0);
  double t=now()-t0;
  printf("%d threads: %.3f s, %.2f GFMA-vec/s per thread -> %.1f GF/s total\n", n, t, 200e6*12/t/1e9, n*200e6*12*16/t/1e9);
}
