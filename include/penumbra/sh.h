/* penumbra/sh.h -- the spherical-harmonics engine: basis, zonal functions, rotation, product,
 * per-sphere log-visibility and the SH exponential, each a forward/backward pair.
 *
 * Conventions (one definition everywhere):
 *   - Real SH with the Condon-Shortley phase; coefficient index i = l*l + l + m, so a vector of
 *     `bands` bands has bands*bands coefficients, l = 0..bands-1, m = -l..l.
 *       Y_00 = 0.282095, Y_1,-1 = -0.488603 y, Y_10 = 0.488603 z, Y_11 = -0.488603 x.
 *   - Directions are unit 3-vectors (x, y, z). Y is up in scenes, but the SH basis itself is
 *     defined on (x, y, z) as above.
 *   - Supported band counts: 1 .. PEN_SH_MAX_BANDS.
 *   - Every function exists in float (hot paths, no suffix) and double (`_d`: tables, reference,
 *     gradient checks). Both are compiled from one source.
 *   - Backward functions take the forward's inputs in the same order, then the gradient of the
 *     forward's output (d_out), and ADD into the gradients of the inputs (d_*); a NULL d_* is
 *     skipped.
 *   - Gradients with respect to a direction are those of the polynomial extension of Y to R^3,
 *     evaluated at the unit direction. Callers that normalise a vector themselves pass the result
 *     through the normalisation's backward, which removes the radial part.
 */
#ifndef PENUMBRA_SH_H
#define PENUMBRA_SH_H

#include "penumbra/core.h"

#ifdef __cplusplus
extern "C" {
#endif

#define PEN_SH_MAX_BANDS 8
#define PEN_SH_MAX_COEFFS (PEN_SH_MAX_BANDS * PEN_SH_MAX_BANDS)

static inline int pen_sh_coeffs(int bands) { return bands * bands; }
static inline int pen_sh_index(int l, int m) { return l * l + l + m; }

/* ---- Basis -------------------------------------------------------------------------------- */

/* y[i] = Y_i(dir) for i < bands^2. */
PEN_API void pen_sh_eval(int bands, const float dir[3], float *y);
PEN_API void pen_sh_eval_d(int bands, const double dir[3], double *y);
/* d_dir += sum_i d_y[i] * dY_i/d(dir). */
PEN_API void pen_sh_eval_bwd(int bands, const float dir[3], const float *d_y, float d_dir[3]);
PEN_API void pen_sh_eval_bwd_d(int bands, const double dir[3], const double *d_y, double d_dir[3]);

/* ---- Zonal functions ------------------------------------------------------------------------
 * A zonal function (symmetric about +z) is given by its m = 0 coefficients z[l], l < bands. */

/* Indicator of a spherical cap of half-angle alpha around +z, given cos(alpha) in [-1, 1]:
 *   z_0 = sqrt(pi) (1 - cos a),  z_l = sqrt(pi / (2l+1)) (P_{l-1}(cos a) - P_{l+1}(cos a)).
 * dz_dcos[l] (may be NULL) receives dz_l / d(cos a) = -sqrt(pi (2l+1)) P_l(cos a). */
PEN_API void pen_sh_zonal_cap(int bands, float cos_alpha, float *z, float *dz_dcos);
PEN_API void pen_sh_zonal_cap_d(int bands, double cos_alpha, double *z, double *dz_dcos);

/* Clamped cosine max(cos theta, 0) around +z: 0.886227, 1.023327, 0.495416, 0, -0.110778, ... */
PEN_API void pen_sh_zonal_clamped_cosine(int bands, float *z);
PEN_API void pen_sh_zonal_clamped_cosine_d(int bands, double *z);

/* Rotates a zonal function so that its axis points along dir:
 *   out[l, m] = sqrt(4 pi / (2l+1)) z[l] Y_lm(dir). */
PEN_API void pen_sh_rotate_zonal(int bands, const float *z, const float dir[3], float *out);
PEN_API void pen_sh_rotate_zonal_d(int bands, const double *z, const double dir[3], double *out);
PEN_API void pen_sh_rotate_zonal_bwd(int bands, const float *z, const float dir[3],
                                     const float *d_out, float *d_z, float d_dir[3]);
PEN_API void pen_sh_rotate_zonal_bwd_d(int bands, const double *z, const double dir[3],
                                       const double *d_out, double *d_z, double d_dir[3]);

/* ---- Product ---------------------------------------------------------------------------------
 * The product tensor Gamma_ijk = integral of Y_i Y_j Y_k over the sphere, computed once per band
 * count in double by exact quadrature (Gauss-Legendre in cos theta x uniform phi), stored sparse.
 * The SH product c = a * b is the projection of the product of two `bands`-band functions back
 * onto `bands` bands: c_k = sum_ij Gamma_ijk a_i b_j. */

typedef struct pen_sh_gaunt_entry {
    unsigned short i, j, k; /* coefficient indices */
    double value;           /* Gamma_ijk */
} pen_sh_gaunt_entry;

typedef struct pen_sh_gaunt {
    int bands;
    int count;                         /* number of non-zero ordered (i, j, k) entries */
    const pen_sh_gaunt_entry *entries; /* sorted by k, then i, then j */
    const float *values_f;             /* the values in float, same order */
} pen_sh_gaunt;

/* The table for `bands` (1 .. PEN_SH_MAX_BANDS); built on first use (thread-safe), owned by the
 * library, never freed by the caller. Returns NULL if bands is out of range. */
PEN_API const pen_sh_gaunt *pen_sh_gaunt_table(int bands);

/* c = a * b (c must not alias a or b). */
PEN_API void pen_sh_product(const pen_sh_gaunt *g, const float *a, const float *b, float *c);
PEN_API void pen_sh_product_d(const pen_sh_gaunt *g, const double *a, const double *b, double *c);
PEN_API void pen_sh_product_bwd(const pen_sh_gaunt *g, const float *a, const float *b,
                                const float *d_c, float *d_a, float *d_b);
PEN_API void pen_sh_product_bwd_d(const pen_sh_gaunt *g, const double *a, const double *b,
                                  const double *d_c, double *d_a, double *d_b);

/* ---- Log-visibility of one sphere ------------------------------------------------------------
 * Seen from receiver x, a sphere (c, r) covers the cap of half-angle alpha = asin(r / |c - x|)
 * around d = (c - x) / |c - x|. Its log-visibility is -eps inside the cap and 0 outside
 * (supplement eq. 7); projected into SH:
 *   f_lm = -eps * sqrt(4 pi / (2l+1)) * z_l(alpha) * Y_lm(d).
 * Singular spots (rule, continuous in x, c and r, with finite gradients everywhere):
 *   cos(alpha) = sqrt(t), t = 1 - r^2/|c-x|^2, for t >= PEN_SH_CAP_T0; below that the square root
 *   is continued by its tangent line (C1), and the result is clamped to cos(alpha) >= -1, so a
 *   receiver on the sphere's surface sees a cap slightly larger than a hemisphere and a receiver
 *   deep inside sees the whole sphere blocked (f = DC only). |c - x| is floored at 1e-6 r. */
#define PEN_SH_CAP_T0 1e-2

PEN_API void pen_sh_logvis(int bands, const float x[3], const float c[3], float r, float eps,
                           float *f);
PEN_API void pen_sh_logvis_d(int bands, const double x[3], const double c[3], double r, double eps,
                             double *f);
PEN_API void pen_sh_logvis_bwd(int bands, const float x[3], const float c[3], float r, float eps,
                               const float *d_f, float d_x[3], float d_c[3], float *d_r,
                               float *d_eps);
PEN_API void pen_sh_logvis_bwd_d(int bands, const double x[3], const double c[3], double r,
                                 double eps, const double *d_f, double d_x[3], double d_c[3],
                                 double *d_r, double *d_eps);

/* ---- SH exponential ---------------------------------------------------------------------------
 * V = exp*(F), the SH coefficients of exp(F(omega)) (supplement sec. 4.2):
 *   DC isolation      exp*(F) = exp(F_0 / sqrt(4 pi)) * exp*(F^),  F^ = F with F_0 = 0
 *   scaling/squaring  exp*(F^) = (exp*(F^ / 2^k))^{*2^k}
 *   linear model      exp*(g) ~ a(|g|) 1 + b(|g|) g,  1 = (sqrt(4 pi), 0, ...)
 * Methods:
 *   PEN_SH_EXP_PAPER      a(x) = exp(0.1 x), b(x) = exp(-0.2 x); k = the fewest squarings that
 *                         bring |F^| / 2^k to at most 1 (piecewise constant in |F^|: the result
 *                         jumps where k changes, as in the supplement).
 *   PEN_SH_EXP_EXACT      reference: k brings |F^| / 2^k to at most 1/16, then a degree-10 Taylor
 *                         series in the SH product algebra; the exponential of the truncated
 *                         algebra to about 1e-12.
 *   PEN_SH_EXP_CALIBRATED the default: a(x) = exp(a1 x + a2 x^2), b(x) = exp(b1 x + b2 x^2) with a
 *                         fixed number of squarings (so it is smooth in F), a per-band window
 *                         on F^ and a log-visibility depth eps, all fitted against ray-traced
 *                         irradiance (see docs/sh-accuracy.md).
 * Saturation (all methods): a windowed |F^| above PEN_SH_EXP_KNEE is replaced, direction kept, by
 *   K + W u / (W + u) (u = |F^| - K, K = PEN_SH_EXP_KNEE, W = PEN_SH_EXP_NORM_MAX - K), which is
 *   continuous with slope 1 at K and approaches PEN_SH_EXP_NORM_MAX. The linear models grow like
 *   exp(c |F^|^2) and overflow a float near |F^| = 100 (calibrated) or 500 (paper, exact), which a
 *   valid scene reaches: a hundred spheres stacked at one place without overlap weights, thousands
 *   of objects above one ground, or a large shadow.epsilon. The DC factor carries the depth: it
 *   still goes to 0 as F_0 does, so deep shadows stay black. The bundled scenes stay below
 *   |F^| = 4.1, where nothing changes (the models are fitted for |F^| of a few units). */
#define PEN_SH_EXP_KNEE 12.0
#define PEN_SH_EXP_NORM_MAX 24.0
typedef enum pen_sh_exp_method {
    PEN_SH_EXP_CALIBRATED = 0,
    PEN_SH_EXP_PAPER = 1,
    PEN_SH_EXP_EXACT = 2
} pen_sh_exp_method;

typedef struct pen_sh_exp_model {
    pen_sh_exp_method method;
    int squarings;                     /* CALIBRATED: fixed k */
    double a1, a2, b1, b2;             /* CALIBRATED: a and b */
    double window[PEN_SH_MAX_BANDS];   /* CALIBRATED: factor on band l of F^ (window[0] unused) */
    double epsilon;                    /* log-visibility depth the model was fitted with */
} pen_sh_exp_model;

/* The model for a method at a band count: PAPER and EXACT have fixed definitions (with
 * epsilon = 4, the supplement's setting); CALIBRATED comes from the shipped parameter table
 * (src/sh/calibration.c) for bands 3..6 and falls back to the nearest fitted band count. */
PEN_API pen_sh_exp_model pen_sh_exp_model_default(pen_sh_exp_method method, int bands);
/* Parses "paper", "exact", "calibrated" (or "default"); returns -1 for anything else. */
PEN_API int pen_sh_exp_method_parse(const char *name);
PEN_API const char *pen_sh_exp_method_name(pen_sh_exp_method method);

/* V = exp*(F) under model m (g is the product table for the band count). */
PEN_API void pen_sh_exp(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const float *F, float *V);
PEN_API void pen_sh_exp_d(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const double *F,
                          double *V);
/* d_F += (dV/dF)^T d_V. Recomputes the forward's intermediates. */
PEN_API void pen_sh_exp_bwd(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const float *F,
                            const float *d_V, float *d_F);
PEN_API void pen_sh_exp_bwd_d(const pen_sh_exp_model *m, const pen_sh_gaunt *g, const double *F,
                              const double *d_V, double *d_F);

#ifdef __cplusplus
}
#endif
#endif
