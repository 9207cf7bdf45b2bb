/* Microbenchmarks behind the peak figures of bench/NOTES.md: the core clock (a chain of dependent
 * integer adds, 1 cycle each), FMA throughput with 512- and 256-bit vectors (16 independent
 * accumulators, enough to cover latency x pipes), 512-bit division and square-root throughput,
 * and a STREAM-like triad. Not part of the build (x86-64 with AVX-512 only):
 *   gcc -O3 -march=native -fopenmp bench/peak.c -o build/peak && build/peak
 * Run it on an idle machine; on a shared one take the best of several runs. */
#include <immintrin.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>

static double clock_ghz(void) {
    const long n = 400000000;
    double best = 1e30;
    for (int rep = 0; rep < 5; ++rep) {
        long x = 0;
        double t0 = omp_get_wtime();
        for (long i = 0; i < n; i += 8)
            __asm__ volatile("add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\t"
                             "add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0" : "+r"(x));
        double t = omp_get_wtime() - t0;
        if (t < best) best = t;
    }
    return n / best * 1e-9; /* the loop's own add/cmp/jump run in parallel with the chain */
}

#define NACC 16
static double fma512(long iters) {
    __m512 acc[NACC];
    for (int k = 0; k < NACC; ++k) acc[k] = _mm512_set1_ps((float)k);
    const __m512 a = _mm512_set1_ps(0.999999f), b = _mm512_set1_ps(1e-7f);
    double t0 = omp_get_wtime();
    for (long i = 0; i < iters; ++i)
#pragma GCC unroll 16
        for (int k = 0; k < NACC; ++k) acc[k] = _mm512_fmadd_ps(acc[k], a, b);
    double t = omp_get_wtime() - t0;
    float s = 0; for (int k = 0; k < NACC; ++k) s += _mm512_reduce_add_ps(acc[k]);
    if (s == 12345.f) printf("!");
    return (double)iters * NACC * 16 * 2 / t;
}
static double fma256(long iters) {
    __m256 acc[NACC];
    for (int k = 0; k < NACC; ++k) acc[k] = _mm256_set1_ps((float)k);
    const __m256 a = _mm256_set1_ps(0.999999f), b = _mm256_set1_ps(1e-7f);
    double t0 = omp_get_wtime();
    for (long i = 0; i < iters; ++i)
#pragma GCC unroll 16
        for (int k = 0; k < NACC; ++k) acc[k] = _mm256_fmadd_ps(acc[k], a, b);
    double t = omp_get_wtime() - t0;
    float out[8], s = 0;
    for (int k = 0; k < NACC; ++k) { _mm256_storeu_ps(out, acc[k]); for (int j = 0; j < 8; ++j) s += out[j]; }
    if (s == 12345.f) printf("!");
    return (double)iters * NACC * 8 * 2 / t;
}

static double div512(long iters) {
    __m512 acc[NACC];
    for (int k = 0; k < NACC; ++k) acc[k] = _mm512_set1_ps(1.0f + (float)k);
    const __m512 a = _mm512_set1_ps(1.0000001f);
    double t0 = omp_get_wtime();
    for (long i = 0; i < iters; ++i)
#pragma GCC unroll 16
        for (int k = 0; k < NACC; ++k) acc[k] = _mm512_div_ps(acc[k], a);
    double t = omp_get_wtime() - t0;
    float s = 0; for (int k = 0; k < NACC; ++k) s += _mm512_reduce_add_ps(acc[k]);
    if (s == 12345.f) printf("!");
    return (double)iters * NACC / t; /* 512-bit divisions per second */
}
static double sqrt512(long iters) {
    __m512 acc[NACC];
    for (int k = 0; k < NACC; ++k) acc[k] = _mm512_set1_ps(1.0f + (float)k);
    double t0 = omp_get_wtime();
    for (long i = 0; i < iters; ++i)
#pragma GCC unroll 16
        for (int k = 0; k < NACC; ++k) acc[k] = _mm512_sqrt_ps(acc[k]);
    double t = omp_get_wtime() - t0;
    float s = 0; for (int k = 0; k < NACC; ++k) s += _mm512_reduce_add_ps(acc[k]);
    if (s == 12345.f) printf("!");
    return (double)iters * NACC / t;
}

int main(void) {
    printf("clock (dependent adds): %.2f GHz\n", clock_ghz());
    const long it = 100000000;
    for (int th = 1; th <= 2; ++th) {
        double b512 = 0, b256 = 0;
        for (int rep = 0; rep < 3; ++rep) {
            double s512 = 0, s256 = 0;
#pragma omp parallel num_threads(th) reduction(+ : s512, s256)
            { s512 += fma512(it); s256 += fma256(it); }
            if (s512 > b512) b512 = s512;
            if (s256 > b256) b256 = s256;
        }
        printf("%d thread(s): 512-bit FMA %.1f GFLOP/s, 256-bit FMA %.1f GFLOP/s\n", th, b512 * 1e-9, b256 * 1e-9);
    }
    {
        double ghz = clock_ghz();
        double d = div512(10000000), q = sqrt512(10000000);
        printf("1 thread: vdivps zmm %.2f G/s = %.2f cycles each, vsqrtps zmm %.2f G/s = %.2f cycles each (at %.2f GHz)\n",
               d * 1e-9, ghz * 1e9 / d, q * 1e-9, ghz * 1e9 / q, ghz);
    }
    const size_t n = (size_t)1 << 25; /* 3 arrays x 128 MiB */
    float *a = malloc(n * 4), *b = malloc(n * 4), *c = malloc(n * 4);
    for (size_t i = 0; i < n; ++i) a[i] = 1, b[i] = 2, c[i] = 3;
    for (int th = 1; th <= 2; ++th) {
        double best = 1e30;
        for (int rep = 0; rep < 5; ++rep) {
            double t0 = omp_get_wtime();
#pragma omp parallel for num_threads(th)
            for (size_t i = 0; i < n; ++i) a[i] = b[i] + 1.5f * c[i];
            double t = omp_get_wtime() - t0;
            if (t < best) best = t;
        }
        printf("%d thread(s): triad %.1f GB/s (12 bytes per element, write-allocate not counted)\n", th, 12.0 * n / best * 1e-9);
    }
    return a[7] == 0;
}
