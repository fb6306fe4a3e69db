/* Leaf-table traffic of one 68-point ERT prediction, alone (docs/bench/ert.md).
 * 7500 trees (15 cascades x 500), 16 leaves each, 136 floats per leaf: one prediction adds
 * one leaf vector per tree, chosen by the image, so it reads 7500 scattered 544-byte rows
 * of a 65 MB table. This program times only those additions (random leaf per tree, best of
 * 50), with and without 2 MB pages (argument given: madvise(MADV_HUGEPAGE)).
 * Build and run: gcc -O3 -march=native ert_leaf_traffic.c -o leaf && ./leaf && ./leaf 1
 */
#include <string.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <sys/mman.h>
#define T 7500
#define L 16
#define D 136
static double now(){struct timespec a; clock_gettime(CLOCK_MONOTONIC,&a); return a.tv_sec*1e3+a.tv_nsec/1e6;}
int main(int argc,char**argv){
  size_t n=(size_t)T*L*D*sizeof(float);
  float *leaf = mmap(0,n+(2<<20),PROT_READ|PROT_WRITE,MAP_PRIVATE|MAP_ANONYMOUS,-1,0);
  leaf=(float*)(((size_t)leaf+(2<<20)-1)&~((size_t)(2<<20)-1));
  if(argc>1) printf("madvise %d\n", madvise(leaf,n,MADV_HUGEPAGE));
  for(size_t i=0;i<(size_t)T*L*D;i++) leaf[i]=(float)(i%97)*1e-4f;
  int idx[T]; float acc[D]; unsigned s=1; double best=1e9;
  for(int rep=0;rep<50;rep++){
    for(int t=0;t<T;t++){ s=s*1103515245+12345; idx[t]=(s>>16)%L; }
    for(int d=0;d<D;d++) acc[d]=0;
    double a=now();
    for(int t=0;t<T;t++){ const float*p=leaf+((size_t)t*L+idx[t])*D; for(int d=0;d<D;d++) acc[d]+=p[d]; }
    double b=now(); if(b-a<best)best=b-a;
  }
  printf("best %.3f ms %f\n",best,acc[3]);
  FILE*f=fopen("/proc/self/smaps_rollup","r"); char line[256]; while(fgets(line,256,f)) if(strstr(line,"AnonHuge")) printf("%s",line);
}
