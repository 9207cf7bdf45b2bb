/* The shading kernels (src/shade, docs/design.md sec. 6.4): visibility from spheres, the SH
 * exponential and diffuse SH shading per pixel, in a scalar form compiled in float (the renderer)
 * and double (`_d`, gradient checks) from shade_ops.inc, and a fast form over lanes of pixels per
 * instruction set (shade_fast.c). Each is a forward/backward pair over plain arrays: a kernel
 * knows nothing of the frame (its tiles, threads, buffers and render state), which reaches it
 * only through a backend (src/render/backend.h; the CPU backend in src/render/cpu). The disk
 * lights' per-pixel term is lights.h. */
#ifndef PEN_SHADE_SHADE_H
#define PEN_SHADE_SHADE_H

#include "penumbra/sh.h"
#include "shade/lights.h" /* the disk lights' per-pixel term */

#include <stddef.h>

/* Everything about a frame's shading that is the same for every pixel. */
typedef struct pen__shade_params {
    int bands;                   /* SH bands of lighting and visibility */
    const pen_sh_gaunt *gaunt;   /* product table for `bands` */
    pen_sh_exp_model model;      /* the SH exponential */
    double epsilon;              /* log-visibility depth of a sphere */
    int shadows;                 /* 0: V == 1 (no-shadows mode) */
    double hz[PEN_SH_MAX_BANDS]; /* clamped cosine, zonal */
} pen__shade_params;

/* Fills p; the model's epsilon is used when epsilon is not a positive finite number. */
void pen__shade_params_init(pen__shade_params *p, int bands, const pen_sh_exp_model *model,
                            double epsilon, int shadows);

/* Self-shadowing rule: a sphere (c, r) counts towards the log-visibility of a receiver (x, n)
 * with weight w(h), h = n . (c - x) / r, where w is the smoothstep from h = -1 (the sphere lies
 * wholly behind the tangent plane: w = 0) to h = +1 (wholly in front: w = 1). C1 in h. */
#define PEN_RENDER_SELF_H0 (-1.0)
#define PEN_RENDER_SELF_H1 (1.0)

/* Receivers inside a sphere: the weight above is multiplied by g(q) = smoothstep of
 * (q - PEN_RENDER_INSIDE_LO) / PEN_RENDER_INSIDE_WIDTH, q = |c - x| / r, so a sphere that contains
 * the receiver deeper than LO r counts 0, one that does not contain it counts as before, C1 in
 * between. Inside a sphere the cap is the whole sphere and darkens every direction, also those the
 * surface sees freely; fitted spheres overhang the surface, so most receivers lie inside some of
 * their own object's spheres. Measured in docs/visibility.md sec. 5.1: dropping such spheres cuts
 * the object's error on the scanned meshes by 28-43 %, and this narrow fade keeps that gain. */
#define PEN_RENDER_INSIDE_LO (0.9)
#define PEN_RENDER_INSIDE_WIDTH (0.1)

/* Outgoing radiance of a diffuse receiver at x with unit normal n and albedo rho:
 *   rgb[ch] = rho[ch] / pi * sum_k sh[k][ch] (V * H_n)_k,
 *   V = exp*(sum_i w_i kappa_i logvis_i(x)), H_n = clamped cosine rotated to n.
 * spheres: sphere_count world-space spheres (x, y, z, r); kappa: their overlap weights (NULL: all
 * 1), constants of the backward. fv (may be NULL) receives F and V (2 bands^2 values) for the
 * backward when shadows are on. */
void pen__shade_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], float rgb[3], float *fv);
void pen__shade_fwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], double rgb[3], double *fv);
/* Backward: adds into d_sh (bands^2 x 3, double), d_spheres (4 per sphere, double), d_x, d_n
 * (the gradient of the polynomial extension in n: normalise's backward removes the radial part)
 * and d_rho; any may be NULL. fv: the forward's F and V for this pixel, or NULL to recompute. */
void pen__shade_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], const float d_rgb[3], const float *fv, double (*d_sh)[3],
                    double *d_spheres, float d_x[3], float d_n[3], float d_rho[3]);
void pen__shade_bwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], const double d_rgb[3],
                      const double *fv, double (*d_sh)[3], double *d_spheres, double d_x[3],
                      double d_n[3], double d_rho[3]);

/* The same with the object's own precomputed transfer: B (bands^2 values) is the part of the
 * clamped cosine its own mesh blocks, interpolated at the pixel (a constant: no gradient flows to
 * it), so its transfer is T_self = H_n - B; only the spheres that may shadow it count (kappa 0 for
 * the object's own): T = exp*(F) * T_self, or T_self itself when sphere_count is 0 (no
 * exponential). self.c calls these for pixels of objects shaded with their transfer, whichever
 * kernel the frame uses. */
void pen__shade_self_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, const float x[3],
                         const float n[3], const float *B, const float rho[3], float rgb[3],
                         float *fv);
void pen__shade_self_fwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                           const double *spheres, const double *kappa, const double x[3],
                           const double n[3], const double *B, const double rho[3],
                           double rgb[3], double *fv);
void pen__shade_self_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, const float x[3],
                         const float n[3], const float *B, const float rho[3],
                         const float d_rgb[3], const float *fv, double (*d_sh)[3],
                         double *d_spheres, float d_x[3], float d_n[3], float d_rho[3]);
void pen__shade_self_bwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                           const double *spheres, const double *kappa, const double x[3],
                           const double n[3], const double *B, const double rho[3],
                           const double d_rgb[3], const double *fv, double (*d_sh)[3],
                           double *d_spheres, double d_x[3], double d_n[3], double d_rho[3]);
/* The same with F, the other spheres' log-visibility, summed by the caller (the fast kernel's
 * lanes, pen__shade_fast_fwd with the object's kappa; bands^2 values): V = exp*(F) and the rest
 * are done here, in the backward from F again (V recomputed). The spheres are still passed for
 * the backward's gradients by x, n and the spheres (not wanted under the transfer model). */
void pen__shade_self_given_fwd(const pen__shade_params *p, const float (*sh)[3],
                               int sphere_count, const float *spheres, const float *kappa,
                               const float x[3], const float n[3], const float *B,
                               const float *F, const float rho[3], float rgb[3], float *fv);
void pen__shade_self_given_fwd_d(const pen__shade_params *p, const double (*sh)[3],
                                 int sphere_count, const double *spheres, const double *kappa,
                                 const double x[3], const double n[3], const double *B,
                                 const double *F, const double rho[3], double rgb[3], double *fv);
void pen__shade_self_given_bwd(const pen__shade_params *p, const float (*sh)[3],
                               int sphere_count, const float *spheres, const float *kappa,
                               const float x[3], const float n[3], const float *B,
                               const float *F, const float rho[3], const float d_rgb[3],
                               double (*d_sh)[3], double *d_spheres, float d_x[3], float d_n[3],
                               float d_rho[3]);
void pen__shade_self_given_bwd_d(const pen__shade_params *p, const double (*sh)[3],
                                 int sphere_count, const double *spheres, const double *kappa,
                                 const double x[3], const double n[3], const double *B,
                                 const double *F, const double rho[3], const double d_rgb[3],
                                 double (*d_sh)[3], double *d_spheres, double d_x[3],
                                 double d_n[3], double d_rho[3]);

/* ---- Fast kernel (shade_fast.c, shade_fast_dispatch.c) -----------------------------------------
 * The same shading as pen__shade_fwd / pen__shade_bwd, for many pixels at once: pixels go in
 * batches of lanes through structure-of-arrays lane vectors (16 lanes: one AVX-512 register of
 * floats), with straight-line SH products generated per band count (src/sh/sh_fast_product_L.inc).
 * Supports bands 3..6, with shadows the CALIBRATED and PAPER exponentials, without shadows
 * (V == 1) every method (pen__shade_fast_supported); the renderer uses the scalar kernel for
 * anything else. kappa (may be NULL: all 1) scales
 * sphere i's log-visibility, F = sum_i w_i kappa_i f_i; it is not differentiated.
 * The kernel exists in one variant per instruction set; the functions below call the variant
 * chosen once per process (the widest the processor runs, or a lower one named by the environment
 * variable PEN_CPU: avx512, avx2, sse2). Lane count, store layout and sums differ between variants:
 * a forward and its backward must run with the same one. */

/* Clock ticks spent in the stages of a fast call, added to by each call (for the renderer's
 * stage timings; only ratios of ticks are meaningful). Inline: the kernel reads it per batch. */
typedef struct pen__shade_fast_ticks {
    unsigned long long visibility, exp;
} pen__shade_fast_ticks;
#if defined(__x86_64__) || defined(__i386__)
static inline unsigned long long pen__shade_fast_now(void) {
    return (unsigned long long)__builtin_ia32_rdtsc();
}
#else
#include <time.h>
static inline unsigned long long pen__shade_fast_now(void) {
    struct timespec ts;
    timespec_get(&ts, TIME_UTC);
    return (unsigned long long)ts.tv_sec * 1000000000ull + (unsigned long long)ts.tv_nsec;
}
#endif

int pen__shade_fast_supported(const pen__shade_params *p);
/* Floats per pixel of the forward's store (F, for the backward), in whole batches: a call with
 * `count` pixels needs pen__shade_fast_store_floats(p, count) floats. */
size_t pen__shade_fast_store_floats(const pen__shade_params *p, int count);
/* Pixel j's F (bands^2 floats) from the store of a forward call (batches of lanes, F_k of a
 * batch's lanes side by side). */
void pen__shade_fast_store_pixel(const pen__shade_params *p, const float *store, int j, float *F);
/* Bytes of per-thread scratch for calls of up to max_count pixels. */
size_t pen__shade_fast_scratch_bytes(const pen__shade_params *p, int sphere_count, int max_count);
/* count pixels, AoS: x, n, rho and rgb 3 floats per pixel; the first `ground` of them lie on the
 * ground plane (n = +Y; their d_x and d_n are not wanted), which saves batches of them the
 * per-pixel product. store (may be NULL) receives what the backward needs when shadows are on.
 * ticks may be NULL. */
void pen__shade_fast_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, float *rgb,
                         float *store, void *scratch, pen__shade_fast_ticks *ticks);
/* Backward of the same call: ADDS into d_sh, d_spheres (double; summed over the call's pixels
 * in a fixed order), and per pixel into d_x, d_n, d_rho (3 floats per pixel; for the ground
 * pixels d_x and d_n are unspecified); any may be NULL. store: the forward's, or NULL to
 * recompute. */
void pen__shade_fast_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, const float *d_rgb,
                         const float *store, void *scratch, double (*d_sh)[3], double *d_spheres,
                         float *d_x, float *d_n, float *d_rho, pen__shade_fast_ticks *ticks);

/* One variant: its entry points (the functions above without the dispatch), exported by each
 * compilation of shade_fast.c as pen__shade_fast_ops_<name>. */
typedef struct pen__shade_fast_ops {
    const char *name; /* "avx512", "avx2", "sse2" or "generic" (not x86) */
    int lanes;
    size_t (*store_floats)(const pen__shade_params *p, int count);
    size_t (*scratch_bytes)(const pen__shade_params *p, int sphere_count, int max_count);
    void (*fwd)(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                const float *spheres, const float *kappa, int count, int ground, const float *x,
                const float *n, const float *rho, float *rgb, float *store, void *scratch,
                pen__shade_fast_ticks *ticks);
    void (*bwd)(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                const float *spheres, const float *kappa, int count, int ground, const float *x,
                const float *n, const float *rho, const float *d_rgb, const float *store,
                void *scratch, double (*d_sh)[3], double *d_spheres, float *d_x, float *d_n,
                float *d_rho, pen__shade_fast_ticks *ticks);
} pen__shade_fast_ops;

/* Test and benchmark hooks. Variants are numbered widest first, 0 .. pen__shade_fast_variants()-1;
 * pen__shade_fast_variant_ops(v) is variant v's table, or NULL when this processor cannot run it.
 * pen__shade_fast_use(v) makes v the one in use (returns 0 when it cannot run here); not while
 * another thread renders. pen__shade_fast_current() is the one in use. */
int pen__shade_fast_variants(void);
const pen__shade_fast_ops *pen__shade_fast_variant_ops(int v);
int pen__shade_fast_use(int v);
const pen__shade_fast_ops *pen__shade_fast_current(void);

#endif
