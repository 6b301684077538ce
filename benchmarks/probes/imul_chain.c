/* A dependent imul chain (mode 0, latency-bound) or six independent ones (mode 1, throughput-bound)
   per thread, N concurrent threads (NOTES.md N24): on two real cores mode 0 keeps its one-thread time.
   gcc -O2 imul_chain.c -o imul_chain -lpthread && ./imul_chain 1 0 && ./imul_chain 2 0 */
#include <stdio.h>
#include <stdlib.h>
#include <pthread.h>
#include <time.h>
static double now(){struct timespec t;clock_gettime(CLOCK_MONOTONIC,&t);return t.tv_sec+1e-9*t.tv_nsec;}
static int MODE;
static void* work(void*arg){
  unsigned long a=1,b=3,c=5,d=7,e=9,f=11,m=0x9E3779B97F4A7C15UL;
  for(long it=0; it<300000000L; it++){
    if (MODE==0) { a*=m; __asm__("" : "+r"(a)); }
    else { a*=m; b*=m; c*=m; d*=m; e*=m; f*=m; __asm__("" : "+r"(a),"+r"(b),"+r"(c),"+r"(d),"+r"(e),"+r"(f)); }
  }
  *(unsigned long*)arg=a+b+c+d+e+f; return 0;
}
int main(int argc,char**argv){
  int n=atoi(argv[1]); MODE=atoi(argv[2]); pthread_t th[4]; unsigned long r[4];
  double t0=now();
  for(int i=0;i<n;i++) pthread_create(&th[i],0,work,&r[i]);
  for(int i=0;i<n;i++) pthread_join(th[i],0);
  printf("mode %d, %d threads: %.3f s\n", MODE, n, now()-t0);
}
