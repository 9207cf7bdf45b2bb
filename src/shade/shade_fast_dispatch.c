/* Run-time choice of the fast shading kernel: the pen__shade_fast_* entry points the renderer
 * calls, forwarded to one of the kernel's variants (shade_fast.c, compiled once per instruction
 * set); the disk lights' prefilter (lights_fast.c) goes with the
 * same variant.
 *
 * Design
 * - Why at run time. The kernel is nearly all of a step's arithmetic, and its speed is the width
 *   of its lane vectors: built only for the x86-64 baseline it runs 4 lanes where the machine has
 *   16. Building the whole library for the build machine (PEN_NATIVE) gets the width but makes a
 *   binary that dies on an older processor. So only the kernel is built per instruction set,
 *   and this file picks the widest variant the processor runs.
 * - When. Once per process, at the first call (every thread computes the same answer, so a race
 *   between first calls is harmless; the choice is an atomic int). The store a forward leaves for
 *   its backward has the variant's layout, which is why the choice is never changed behind the
 *   renderer's back: only the test hook pen__shade_fast_use changes it.
 * - PEN_CPU. The environment variable PEN_CPU = avx512, avx2 or sse2 asks for a variant no wider
 *   than the processor allows (for tests and benchmarks of the narrower ones on a wide machine);
 *   an unknown name, or a variant the processor cannot run, is ignored and the widest is used.
 *   pen_render_fast_lanes (the CPU backend's) tells which width a process ended up with.
 * - What the processor runs. libgcc's __builtin_cpu_supports reads CPUID and, for AVX and
 *   AVX-512, whether the operating system saves the wide registers; the variant's compiler flags
 *   (CMakeLists.txt) and the features tested here are the same list.
 */
#include "shade/shade.h"

#include <stdlib.h>
#include <string.h>

#if defined(__x86_64__)
extern const pen__shade_fast_ops pen__shade_fast_ops_avx512, pen__shade_fast_ops_avx2,
    pen__shade_fast_ops_sse2;
static const pen__shade_fast_ops *const variants[] = {
    &pen__shade_fast_ops_avx512, &pen__shade_fast_ops_avx2, &pen__shade_fast_ops_sse2};
#define CANDIDATES(isa) pen__lights_candidates_##isa
#define CANDIDATE_VARIANTS {CANDIDATES(avx512), CANDIDATES(avx2), CANDIDATES(sse2)}
#define LIGHTS_FWD(isa) pen__lights_fwd_block_##isa
#define LIGHTS_FWD_VARIANTS {LIGHTS_FWD(avx512), LIGHTS_FWD(avx2), LIGHTS_FWD(sse2)}
#define LIGHTS_BWD(isa) pen__lights_bwd_block_##isa
#define LIGHTS_BWD_VARIANTS {LIGHTS_BWD(avx512), LIGHTS_BWD(avx2), LIGHTS_BWD(sse2)}

static int cpu_runs(int v) {
    __builtin_cpu_init();
    switch (v) {
    case 0:
        return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
               __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl") &&
               __builtin_cpu_supports("avx512cd") && __builtin_cpu_supports("avx2") &&
               __builtin_cpu_supports("fma");
    case 1:
        return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    default:
        return 1; /* SSE2 is part of x86-64 */
    }
}
#else
extern const pen__shade_fast_ops pen__shade_fast_ops_generic;
static const pen__shade_fast_ops *const variants[] = {&pen__shade_fast_ops_generic};
#define CANDIDATES(isa) pen__lights_candidates_##isa
#define CANDIDATE_VARIANTS {CANDIDATES(generic)}
#define LIGHTS_FWD(isa) pen__lights_fwd_block_##isa
#define LIGHTS_FWD_VARIANTS {LIGHTS_FWD(generic)}
#define LIGHTS_BWD(isa) pen__lights_bwd_block_##isa
#define LIGHTS_BWD_VARIANTS {LIGHTS_BWD(generic)}

static int cpu_runs(int v) {
    (void)v;
    return 1;
}
#endif

#define VARIANTS ((int)(sizeof variants / sizeof variants[0]))

static int chosen = -1; /* index into variants; -1 until the first call */

/* The widest variant this processor runs, or PEN_CPU's when it names a narrower one. */
static int choose(void) {
    int v = 0;
    while (v < VARIANTS - 1 && !cpu_runs(v))
        ++v;
    const char *want = getenv("PEN_CPU");
    for (int i = v + 1; want && i < VARIANTS; ++i)
        if (strcmp(want, variants[i]->name) == 0) v = i;
    return v;
}

static const pen__shade_fast_ops *ops(void) {
    int v = __atomic_load_n(&chosen, __ATOMIC_ACQUIRE);
    if (v < 0) {
        v = choose();
        __atomic_store_n(&chosen, v, __ATOMIC_RELEASE);
    }
    return variants[v];
}

int pen__shade_fast_variants(void) {
    return VARIANTS;
}

const pen__shade_fast_ops *pen__shade_fast_variant_ops(int v) {
    return v >= 0 && v < VARIANTS && cpu_runs(v) ? variants[v] : NULL;
}

int pen__shade_fast_use(int v) {
    if (!pen__shade_fast_variant_ops(v)) return 0;
    __atomic_store_n(&chosen, v, __ATOMIC_RELEASE);
    return 1;
}

const pen__shade_fast_ops *pen__shade_fast_current(void) {
    return ops();
}

int pen__shade_fast_supported(const pen__shade_params *p) {
    return p->bands >= 3 && p->bands <= 6 &&
           (!p->shadows || p->model.method == PEN_SH_EXP_CALIBRATED ||
            p->model.method == PEN_SH_EXP_PAPER);
}

size_t pen__shade_fast_store_floats(const pen__shade_params *p, int count) {
    return ops()->store_floats(p, count);
}

size_t pen__shade_fast_scratch_bytes(const pen__shade_params *p, int sphere_count, int max_count) {
    return ops()->scratch_bytes(p, sphere_count, max_count);
}

void pen__shade_fast_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, float *rgb, float *store,
                         void *scratch, pen__shade_fast_ticks *ticks) {
    ops()->fwd(p, sh, sphere_count, spheres, kappa, count, ground, x, n, rho, rgb, store, scratch,
               ticks);
}

void pen__shade_fast_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, const float *d_rgb,
                         const float *store, void *scratch, double (*d_sh)[3], double *d_spheres,
                         float *d_x, float *d_n, float *d_rho, pen__shade_fast_ticks *ticks) {
    ops()->bwd(p, sh, sphere_count, spheres, kappa, count, ground, x, n, rho, d_rgb, store, scratch,
               d_sh, d_spheres, d_x, d_n, d_rho, ticks);
}

void pen__shade_fast_store_pixel(const pen__shade_params *p, const float *store, int j,
                                 float *F) {
    const size_t L = (size_t)ops()->lanes, nc = (size_t)p->bands * (size_t)p->bands;
    const float *b = store + ((size_t)j / L) * L * nc + (size_t)j % L; /* batch j / L, lane j % L */
    for (size_t k = 0; k < nc; ++k)
        F[k] = b[k * L];
}


/* The disk lights' prefilter (lights_fast.c), in the variant the kernel uses. */
#define CANDIDATES_DECL(isa)                                                                     \
    void CANDIDATES(isa)(const pen__lights *L, int n, const float *spheres, const int *idx,       \
                         int cnt, const float *x, const float *nrm, const int *at, int *list,     \
                         int *count)
#if defined(__x86_64__)
CANDIDATES_DECL(avx512);
CANDIDATES_DECL(avx2);
CANDIDATES_DECL(sse2);
#else
CANDIDATES_DECL(generic);
#endif
typedef void (*candidates_fn)(const pen__lights *, int, const float *, const int *, int,
                              const float *, const float *, const int *, int *, int *);
static const candidates_fn candidates[] = CANDIDATE_VARIANTS;

void pen__lights_candidates(const pen__lights *L, int n, const float *spheres, const int *idx,
                            int cnt, const float *x, const float *nrm, const int *at, int *list,
                            int *count) {
    (void)ops(); /* the variant chosen */
    candidates[__atomic_load_n(&chosen, __ATOMIC_ACQUIRE)](L, n, spheres, idx, cnt, x, nrm, at,
                                                            list, count);
}

/* The fast forward's light term (lights_fast.c), in the same variant. */
#define LIGHTS_FWD_DECL(isa)                                                                     \
    void LIGHTS_FWD(isa)(const pen__lights *L, const double *G, int n, const float *spheres,      \
                         const float *kappa, const int *idx, int cnt, const float *x,             \
                         const float *nrm, const float *rho, const int *at, float *rgb,           \
                         float *V_out)
#if defined(__x86_64__)
LIGHTS_FWD_DECL(avx512);
LIGHTS_FWD_DECL(avx2);
LIGHTS_FWD_DECL(sse2);
#else
LIGHTS_FWD_DECL(generic);
#endif
typedef void (*lights_fwd_fn)(const pen__lights *, const double *, int, const float *,
                              const float *, const int *, int, const float *, const float *,
                              const float *, const int *, float *, float *);
static const lights_fwd_fn lights_fwd[] = LIGHTS_FWD_VARIANTS;

void pen__lights_fwd_block(const pen__lights *L, const double *G, int n, const float *spheres,
                           const float *kappa, const int *idx, int cnt, const float *x,
                           const float *nrm, const float *rho, const int *at, float *rgb,
                           float *V_out) {
    (void)ops(); /* the variant chosen */
    lights_fwd[__atomic_load_n(&chosen, __ATOMIC_ACQUIRE)](L, G, n, spheres, kappa, idx, cnt, x,
                                                            nrm, rho, at, rgb, V_out);
}

/* Its backward (lights_fast.c), in the same variant. */
#define LIGHTS_BWD_DECL(isa)                                                                     \
    void LIGHTS_BWD(isa)(const pen__lights *L, const double *G, int n, const float *spheres,      \
                         const float *kappa, const int *idx, int cnt, const float *x,             \
                         const float *nrm, const float *rho, const float *d_rgb,                  \
                         const float *V_in, const int *pix, void *scratch, double *d_spheres,     \
                         float *d_x, float *d_n, float *d_rho, double *d_lights, double *d_G)
#if defined(__x86_64__)
LIGHTS_BWD_DECL(avx512);
LIGHTS_BWD_DECL(avx2);
LIGHTS_BWD_DECL(sse2);
#else
LIGHTS_BWD_DECL(generic);
#endif
typedef void (*lights_bwd_fn)(const pen__lights *, const double *, int, const float *,
                              const float *, const int *, int, const float *, const float *,
                              const float *, const float *, const float *, const int *, void *,
                              double *, float *, float *, float *, double *, double *);
static const lights_bwd_fn lights_bwd[] = LIGHTS_BWD_VARIANTS;

void pen__lights_bwd_block(const pen__lights *L, const double *G, int n, const float *spheres,
                           const float *kappa, const int *idx, int cnt, const float *x,
                           const float *nrm, const float *rho, const float *d_rgb,
                           const float *V_in, const int *pix, void *scratch, double *d_spheres,
                           float *d_x, float *d_n, float *d_rho, double *d_lights, double *d_G) {
    (void)ops(); /* the variant chosen */
    lights_bwd[__atomic_load_n(&chosen, __ATOMIC_ACQUIRE)](L, G, n, spheres, kappa, idx, cnt, x,
                                                            nrm, rho, d_rgb, V_in, pix, scratch,
                                                            d_spheres, d_x, d_n, d_rho, d_lights,
                                                            d_G);
}
