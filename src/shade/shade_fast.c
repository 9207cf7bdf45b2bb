/* The fast shading kernel: the per-pixel shading of shade_ops.inc (visibility from spheres, SH
 * exponential, diffuse SH shading, and their backward) for batches of pixels at once.
 *
 * Design
 * - Variants. This file is compiled once per instruction set (CMakeLists.txt): PEN_FAST_ISA names
 *   it (avx512: 16 lanes, avx2: 8 lanes with FMA, sse2: 4 lanes, the x86-64 baseline; generic:
 *   4 lanes of plain vector code, other processors) and suffixes the one symbol each copy
 *   exports, its table of entry points (pen__shade_fast_ops_<isa>). shade_fast_dispatch.c picks
 *   the widest copy the processor runs, so that a build for any x86-64 still shades with AVX-512
 *   where it exists; the rest of the library needs no special instructions.
 * - Lanes. A batch is LANES pixels (16 with AVX-512: one register of floats) held as
 *   structure-of-arrays lane vectors (GCC vector extensions), so that every operation of the chain
 *   is one vector instruction for the whole batch. The renderer hands over the shaded pixels of
 *   one lighting group of a screen tile (background pixels removed), so the lanes are full except
 *   in each group's last batch, whose spare lanes repeat its last pixel and carry no gradient.
 * - Generated SH code. The band count is fixed per frame; the basis, its gradient and the Gaunt
 *   products are written out per band count (3..6) by scripts/gen_sh_fast.py into
 *   src/sh/sh_fast_product_L.inc, with the Gaunt values as constants, and the stages of
 *   shade_fast_ops.inc are compiled once per band count. Other band counts and the EXACT
 *   exponential (a Taylor series in the product algebra, made for reference not speed) use the
 *   scalar kernel.
 * - Exact culling. A sphere whose overlap weight kappa is 0 contributes nothing and has no
 *   gradient anywhere: it is left out of the call's sphere list (frame_setup). A sphere whose
 *   self-shadowing weight is 0 in every lane of a batch (it lies behind every lane's tangent
 *   plane) contributes nothing and has no gradient there; it is skipped after the weight's dot
 *   product. In the backward, the weight's two ramps are skipped where both are flat in every
 *   lane. Each leaves out only exact zeros (shade_fast_ops.inc), so no result changes.
 * - Per-sphere scalars (1/r, -r^2, the floor of |c - x|^2, kappa, ...) are formed once per call
 *   in the sphere list rather than once per sphere and batch.
 * - The ground plane. A call's first `ground` pixels lie on the ground; batches made only of them
 *   (n = +Y) use the lighting's product with the ground's clamped cosine, formed once per call,
 *   instead of a product per pixel (shade_fast_ops.inc, "The ground plane"). The renderer's
 *   calls are one lighting group each and the ground is a group of its own, so it passes `ground`
 *   = count or 0; a mixed call (the tests make some) is shaded just as well.
 * - Precision. All lane arithmetic is float, as in the scalar kernel; fused multiply-adds are
 *   explicit (the build is ISO C, which turns off the compiler's contraction). exp is a
 *   polynomial (Cephes' expf: about 1 ulp) instead of a per-lane libm call; 1/sqrt and 1/x in
 *   the sphere loop are the AVX-512 estimates refined by a Newton step (about 2 ulp, 9% faster
 *   than the divider). The double sums of d_sh and d_spheres take, per call, the sum over the
 *   call's batches of each lane in float (at most a render tile's 256 pixels / LANES batches: 16
 *   with AVX-512), then the lanes in order in double; the result depends only on the call's
 *   pixels, never on threads.
 * - What the forward keeps. F per pixel (bands^2 floats), from which the backward recomputes the
 *   exponential's squaring chain: a few hundred FMAs per pixel, cheaper than writing and reading
 *   the chain through memory (see bench/NOTES.md).
 */
#include "core/internal.h"
#include "shade/shade.h"
#include "sh/sh_internal.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__x86_64__)
#include <immintrin.h>
#define HAVE_X86 1
#else
#define HAVE_X86 0
#endif

/* The variant: lanes from PEN_FAST_ISA, which CMake sets together with the instruction-set flags
 * (the intrinsics below need them); a compilation outside CMake gets the widest its flags allow. */
#define ISA_avx512 16
#define ISA_avx2 8
#define ISA_sse2 4
#define ISA_generic 4
#ifndef PEN_FAST_ISA
#if defined(__AVX512F__)
#define PEN_FAST_ISA avx512
#elif defined(__AVX2__) && defined(__FMA__)
#define PEN_FAST_ISA avx2
#elif HAVE_X86
#define PEN_FAST_ISA sse2
#else
#define PEN_FAST_ISA generic
#endif
#endif
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define LANES CAT(ISA_, PEN_FAST_ISA)
#if LANES == 16 && !defined(__AVX512F__)
#error "the avx512 variant needs -mavx512f (and -mfma)"
#endif
#if LANES == 8 && !(defined(__AVX2__) && defined(__FMA__))
#error "the avx2 variant needs -mavx2 -mfma"
#endif
#define INLINE static inline __attribute__((always_inline))

typedef float vf __attribute__((vector_size(4 * LANES)));
typedef int32_t vi __attribute__((vector_size(4 * LANES)));

/* ---- Lane vector helpers ------------------------------------------------------------------------ */

/* x in every lane (x - 0 is x exactly, so this is a plain broadcast; x + 0 is not, for x = -0). */
INLINE vf vk(float x) {
    return x - (vf){0};
}
INLINE vi vk_i(int32_t x) {
    return x - (vi){0};
}
INLINE vf vfma(vf a, vf b, vf c) {
#if LANES == 16
    return _mm512_fmadd_ps(a, b, c);
#elif LANES == 8 && defined(__FMA__)
    return _mm256_fmadd_ps(a, b, c);
#elif LANES == 4 && defined(__FMA__)
    return _mm_fmadd_ps(a, b, c);
#else
    return a * b + c;
#endif
}
INLINE vf vsqrt(vf a) {
#if LANES == 16
    return _mm512_sqrt_ps(a);
#elif LANES == 8
    return _mm256_sqrt_ps(a);
#elif HAVE_X86
    return _mm_sqrt_ps(a);
#else
    vf r;
    for (int i = 0; i < LANES; ++i)
        r[i] = sqrtf(a[i]);
    return r;
#endif
}
/* 1 / sqrt(x) and 1 / x for x > 0. With AVX-512: the 14-bit estimates and one Newton step
 * (within about 2 ulp; measured 9% faster per sphere than sqrt and division); elsewhere the exact
 * operations. */
INLINE vf vrsqrt(vf x) {
#if LANES == 16
    const vf y = _mm512_rsqrt14_ps(x);
    return y * vfma(vk(-0.5f) * x * y, y, vk(1.5f));
#else
    return vk(1.0f) / vsqrt(x);
#endif
}
INLINE vf vrcp(vf x) {
#if LANES == 16
    const vf y = _mm512_rcp14_ps(x);
    return vfma(y, vfma(-x, y, vk(1.0f)), y);
#else
    return vk(1.0f) / x;
#endif
}
/* m ? a : b per lane (m: all bits set or clear). */
INLINE vf vsel(vi m, vf a, vf b) {
    return (vf)(((vi)a & m) | ((vi)b & ~m));
}
INLINE vf vmin(vf a, vf b) {
#if LANES == 16
    return _mm512_min_ps(a, b);
#elif LANES == 8
    return _mm256_min_ps(a, b);
#elif HAVE_X86
    return _mm_min_ps(a, b);
#else
    return vsel(a < b, a, b);
#endif
}
INLINE vf vmax(vf a, vf b) {
#if LANES == 16
    return _mm512_max_ps(a, b);
#elif LANES == 8
    return _mm256_max_ps(a, b);
#elif HAVE_X86
    return _mm_max_ps(a, b);
#else
    return vsel(a > b, a, b);
#endif
}
/* Whether any lane of a mask is set. */
INLINE int vany(vi m) {
#if LANES == 16
    return _mm512_test_epi32_mask((__m512i)m, (__m512i)m) != 0;
#elif LANES == 8
    return _mm256_movemask_ps((__m256)m) != 0;
#elif HAVE_X86
    return _mm_movemask_ps((__m128)m) != 0;
#else
    int any = 0;
    for (int i = 0; i < LANES; ++i)
        any |= m[i] != 0;
    return any;
#endif
}
INLINE vi lane_index(void) {
    int32_t a[LANES];
    for (int i = 0; i < LANES; ++i)
        a[i] = i;
    vi r;
    memcpy(&r, a, sizeof r);
    return r;
}
/* exp(x) for x in [-87, 88] (clamped outside): Cephes' expf, exp(x) = 2^n exp(r), |r| <= ln2/2,
 * with ln 2 split in two for an exact reduction; about 1 ulp. */
INLINE vf vexp(vf x) {
    x = vmin(vmax(x, vk(-87.3f)), vk(88.3f));
    const vf big = vk(12582912.0f); /* 1.5 * 2^23: adding it rounds to an integer */
    const vf nf = vfma(x, vk(1.44269504088896341f), big) - big;
    vf r = vfma(nf, vk(-0.693359375f), x);
    r = vfma(nf, vk(2.12194440e-4f), r);
    vf p = vk(1.9875691500e-4f);
    p = vfma(p, r, vk(1.3981999507e-3f));
    p = vfma(p, r, vk(8.3334519073e-3f));
    p = vfma(p, r, vk(4.1665795894e-2f));
    p = vfma(p, r, vk(1.6666665459e-1f));
    p = vfma(p, r, vk(5.0000001201e-1f));
    const vf y = vfma(p, r * r, r) + vk(1.0f);
    const vi e = (__builtin_convertvector(nf, vi) + 127) << 23;
    return y * (vf)e;
}
/* Sum of the lanes in order, in double. */
static double lane_sum(vf v) {
    double s = 0.0;
    for (int i = 0; i < LANES; ++i)
        s += (double)v[i];
    return s;
}
/* Lanes [first, first + LANES) of an AoS array of 3-vectors with `count` entries; lanes past the
 * end repeat the last entry (finite values, no gradient: see the callers). */
static inline void gather3(const float *src, int first, int count, vf out[3]) {
    float buf[3][LANES];
    for (int l = 0; l < LANES; ++l) {
        const int i = first + l < count ? first + l : count - 1;
        buf[0][l] = src[3 * (size_t)i];
        buf[1][l] = src[3 * (size_t)i + 1];
        buf[2][l] = src[3 * (size_t)i + 2];
    }
    memcpy(out, buf, sizeof buf);
}
/* Writes (add = 0) or adds (add = 1) the valid lanes back. */
static inline void scatter3(const vf v[3], int first, int count, float *dst, int add) {
    const int m = count - first < LANES ? count - first : LANES;
    for (int l = 0; l < m; ++l) {
        float *d = dst + 3 * (size_t)(first + l);
        if (add) d[0] += v[0][l], d[1] += v[1][l], d[2] += v[2][l];
        else d[0] = v[0][l], d[1] = v[1][l], d[2] = v[2][l];
    }
}

/* ---- Frame constants ---------------------------------------------------------------------------- */

/* One sphere of a call with the scalars its pairs share, formed once per call (the same float
 * operations the sphere loop did per pair, so the results are the same bits). */
typedef struct sphere_k {
    float c[3];  /* centre */
    float inv_r; /* 1 / r */
    float kappa; /* scale of the log-visibility (1 without overlap weights) */
    float nrr;   /* -r^2 */
    float dmin2; /* (1e-6 r)^2: the floor of |c - x|^2 */
    float rr2;   /* 2 r^2 */
    float m2r;   /* -2 r */
    int s;       /* index in the call's spheres */
} sphere_k;

/* What every batch of a call shares, in float. */
typedef struct frame {
    int S;              /* spheres */
    int ns;             /* spheres that can contribute: those with kappa != 0 */
    const sphere_k *sk; /* those spheres, in the call's order */
    int shadows;
    int squarings;                   /* fixed k (CALIBRATED), or -1: per lane (PAPER) */
    float kscale;                    /* 2^-k for a fixed k (a libm call, once per call) */
    vf ce_v[PEN_SH_MAX_BANDS];       /* -eps 2 pi / (2l + 1), broadcast */
    float eps2pi;                    /* eps 2 pi */
    float win[PEN_SH_MAX_COEFFS];    /* window per coefficient */
    float a1, a2, b1, b2;            /* a(x) = exp(a1 x + a2 x^2), b likewise */
    float hzs[PEN_SH_MAX_BANDS];     /* sqrt(4 pi / (2l+1)) times the clamped cosine's z_l */
    vf hzs_v[PEN_SH_MAX_BANDS];      /* the same, broadcast */
    float L[PEN_SH_MAX_COEFFS][3];   /* lighting */
} frame;

static void frame_init(frame *fr, const pen__shade_params *p, const float (*sh)[3], int S,
                       const sphere_k *sk, int ns) {
    memset(fr, 0, sizeof *fr);
    fr->S = p->shadows ? S : 0;
    fr->sk = sk;
    fr->ns = p->shadows ? ns : 0;
    fr->shadows = p->shadows;
    const double eps = p->epsilon;
    for (int l = 0; l < p->bands; ++l) {
        fr->ce_v[l] = vk((float)(-eps * 2.0 * PEN_PI / (2 * l + 1)));
        fr->hzs[l] = (float)(sqrt(4.0 * PEN_PI / (2 * l + 1)) * p->hz[l]);
        fr->hzs_v[l] = vk(fr->hzs[l]);
    }
    fr->eps2pi = (float)(eps * 2.0 * PEN_PI);
    const pen_sh_exp_model *m = &p->model;
    if (m->method == PEN_SH_EXP_PAPER) {
        fr->squarings = -1;
        fr->a1 = 0.1f, fr->a2 = 0.0f, fr->b1 = -0.2f, fr->b2 = 0.0f;
    } else {
        fr->squarings = m->squarings;
        fr->kscale = ldexpf(1.0f, -m->squarings);
        fr->a1 = (float)m->a1, fr->a2 = (float)m->a2, fr->b1 = (float)m->b1, fr->b2 = (float)m->b2;
    }
    for (int l = 0; l < p->bands; ++l)
        for (int i = l * l; i < (l + 1) * (l + 1); ++i)
            fr->win[i] = m->method == PEN_SH_EXP_CALIBRATED ? (float)m->window[l] : 1.0f;
    for (int k = 0; k < p->bands * p->bands; ++k)
        for (int ch = 0; ch < 3; ++ch)
            fr->L[k][ch] = sh[k][ch];
}

/* ---- Generated SH code and the per-band stages --------------------------------------------------- */

#define FP_VF vf
#define FP_MUL(a, b) ((a) * (b))
#define FP_FMA(a, b, c) vfma(a, b, c)
#define FP_K(x) vk(x)
#include "sh/sh_fast_product_3.inc"
#include "sh/sh_fast_product_4.inc"
#include "sh/sh_fast_product_5.inc"
#include "sh/sh_fast_product_6.inc"

#define FB 3
#include "shade/shade_fast_ops.inc"
#undef FB
#define FB 4
#include "shade/shade_fast_ops.inc"
#undef FB
#define FB 5
#include "shade/shade_fast_ops.inc"
#undef FB
#define FB 6
#include "shade/shade_fast_ops.inc"
#undef FB

/* ---- Entry points -------------------------------------------------------------------------------- */

static size_t store_floats(const pen__shade_params *p, int count) {
    if (!p->shadows) return 0;
    const size_t nb = ((size_t)count + LANES - 1) / LANES;
    return nb * LANES * (size_t)p->bands * (size_t)p->bands;
}

/* Scratch: the call's sphere list (sphere_k), then (aligned) the lane arrays: forward F and V of
 * every batch; backward the lane accumulators of d_sh (two sets: see bwd_FB) and d_spheres. */
static size_t scratch_bytes(const pen__shade_params *p, int sphere_count, int max_count) {
    const size_t nc = (size_t)p->bands * (size_t)p->bands;
    const size_t nb = ((size_t)max_count + LANES - 1) / LANES;
    size_t fwd = 2 * nb * nc, bwd = 6 * nc + 4 * (size_t)sphere_count;
    return sizeof(sphere_k) * ((size_t)sphere_count + 1) + sizeof(vf) * (fwd > bwd ? fwd : bwd) +
           2 * sizeof(vf);
}

static unsigned char *scratch_lanes(void *scratch, int S) {
    uintptr_t a = (uintptr_t)((sphere_k *)scratch + S + 1);
    a = (a + sizeof(vf) - 1) & ~(uintptr_t)(sizeof(vf) - 1);
    return (unsigned char *)a;
}

/* The call's frame constants and sphere list (into the scratch); returns the lane scratch.
 * A sphere with kappa = 0 is left out of the list: its every pair adds w 0 f = +-0 to F, and in
 * the backward its every gradient term carries the factor kappa (w kappa, dw kappa), so it adds
 * +-0 to accumulators that start at +0 and never become -0: leaving it out changes no bit (for
 * finite inputs, which the renderer validates). */
static unsigned char *frame_setup(frame *fr, const pen__shade_params *p, const float (*sh)[3],
                                  int sphere_count, const float *spheres, const float *kappa,
                                  void *scratch) {
    const int S = p->shadows ? sphere_count : 0;
    sphere_k *sk = scratch;
    int ns = 0;
    for (int s = 0; s < S; ++s) {
        const float *sp = spheres + 4 * (size_t)s;
        const float kap = kappa ? kappa[s] : 1.0f;
        if (kap == 0.0f) continue;
        const float r = sp[3];
        sphere_k *k = &sk[ns++];
        k->c[0] = sp[0], k->c[1] = sp[1], k->c[2] = sp[2];
        k->inv_r = 1.0f / r;
        k->kappa = kap;
        k->nrr = -r * r;
        k->dmin2 = (1e-6f * r) * (1e-6f * r);
        k->rr2 = 2.0f * r * r;
        k->m2r = -2.0f * r;
        k->s = s;
    }
    frame_init(fr, p, sh, S, sk, ns);
    return scratch_lanes(scratch, S);
}

static void shade_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                      const float *spheres, const float *kappa, int count, int ground,
                      const float *x, const float *n, const float *rho, float *rgb, float *store,
                      void *scratch, pen__shade_fast_ticks *ticks) {
    if (count <= 0) return;
    frame fr;
    unsigned char *lanes = frame_setup(&fr, p, sh, sphere_count, spheres, kappa, scratch);
    switch (p->bands) {
    case 3: fwd_3(&fr, count, ground, x, n, rho, rgb, store, lanes, ticks); break;
    case 4: fwd_4(&fr, count, ground, x, n, rho, rgb, store, lanes, ticks); break;
    case 5: fwd_5(&fr, count, ground, x, n, rho, rgb, store, lanes, ticks); break;
    case 6: fwd_6(&fr, count, ground, x, n, rho, rgb, store, lanes, ticks); break;
    default: break; /* not supported: the caller checks pen__shade_fast_supported */
    }
}

static void shade_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                      const float *spheres, const float *kappa, int count, int ground,
                      const float *x, const float *n, const float *rho, const float *d_rgb,
                      const float *store, void *scratch, double (*d_sh)[3], double *d_spheres,
                      float *d_x, float *d_n, float *d_rho, pen__shade_fast_ticks *ticks) {
    if (count <= 0) return;
    frame fr;
    unsigned char *lanes = frame_setup(&fr, p, sh, sphere_count, spheres, kappa, scratch);
    switch (p->bands) {
    case 3:
        bwd_3(&fr, count, ground, x, n, rho, d_rgb, store, lanes, d_sh, d_spheres, d_x, d_n, d_rho,
              ticks);
        break;
    case 4:
        bwd_4(&fr, count, ground, x, n, rho, d_rgb, store, lanes, d_sh, d_spheres, d_x, d_n, d_rho,
              ticks);
        break;
    case 5:
        bwd_5(&fr, count, ground, x, n, rho, d_rgb, store, lanes, d_sh, d_spheres, d_x, d_n, d_rho,
              ticks);
        break;
    case 6:
        bwd_6(&fr, count, ground, x, n, rho, d_rgb, store, lanes, d_sh, d_spheres, d_x, d_n, d_rho,
              ticks);
        break;
    default: break;
    }
}

#define STR_(x) #x
#define STR(x) STR_(x)
const pen__shade_fast_ops CAT(pen__shade_fast_ops_, PEN_FAST_ISA) = {
    STR(PEN_FAST_ISA), LANES, store_floats, scratch_bytes, shade_fwd, shade_bwd,
};
