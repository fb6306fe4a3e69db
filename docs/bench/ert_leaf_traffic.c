/* Leaf-table traffic of one 68-point ERT prediction, alone (docs/bench/ert.md).
 * 7500 trees (15 cascades x 500), 16 leaves each, 136 floats per leaf: one prediction adds
 * one leaf vector per tree, chosen by the image, so it reads 7500 scattered 544-byte rows
 * of a 65 MB table. This program times only those additions (random leaf per tree, leaf
 * addresses known before the loop, as in our predictor), best of 50; the argument is a
 * software-prefetch distance in trees (0 = none).
 * Build and run: gcc -O3 -march=native ert_leaf_traffic.c -o leaf && for a in 0 4 8 16; do ./leaf $a; done
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#define T 7500
#define L 16
#define D 136
static double now(){struct timespec a; clock_gettime(CLOCK_MONOTONIC,&a); return a.tv_sec*1e3+a.tv_nsec/1e6;}
int main(int argc,char**argv){
  int ahead = argc>1? atoi(argv[1]):0;
  float *leaf = aligned_alloc(64,(size_t)T*L*D*sizeof(float));
  for(size_t i=0;i<(size_t)T*L*D;i++) leaf[i]=(float)(i%97)*1e-4f;
  static const float* ptr[T]; float acc[D]; unsigned s=1; double best=1e9;
  for(int rep=0;rep<50;rep++){
    for(int t=0;t<T;t++){ s=s*1103515245+12345; ptr[t]=leaf+((size_t)t*L+(s>>16)%L)*D; }
    for(int d=0;d<D;d++) acc[d]=0;
    double a=now();
    for(int t=0;t<T;t++){
      if(ahead && t+ahead<T){ const char*q=(const char*)ptr[t+ahead]; for(int c=0;c<544;c+=64) __builtin_prefetch(q+c); }
      const float*p=ptr[t]; for(int d=0;d<D;d++) acc[d]+=p[d]; }
    double b=now(); if(b-a<best)best=b-a;
  }
  printf("ahead %d best %.3f ms %f\n",ahead,best,acc[3]);
}
