/* penumbra_research.h -- how accurate is SH visibility where it matters: irradiance.
 *
 * The research harnesses (the accuracy protocol and the calibration of the CALIBRATED model) are
 * their own static library, penumbra_research (folder research/), linked by the CLI's
 * `penumbra sh-accuracy` and by the tests that need it; they are not part of libpenumbra, and this
 * header is not installed. They use the library's public API and a few of its internals (src/).
 * What the renderer needs of the calibration, the fitted constants, stays in the library
 * (src/sh/calibration.c).
 *
 * Protocol (docs/sh-accuracy.md): a receiver at the origin with normal +Y; seeded random sets of
 * 1, 8 and 32 spheres above its tangent plane (centre distance D in [0.4, 1.6], radius 10-40 % of
 * D, sine of the centre's elevation in [0.15, 1]); band-limited lighting: the SH projection of
 * (a) a constant sky plus a sun lobe from a random direction above the horizon and (b) each given
 * environment map under a random rotation about +Y. The error of a model is
 *     |E - E_true| / E_unoccluded,  E = sum_k L_k (V * H_n)_k,
 *     E_true = integral L(w) V_true(w) max(n.w, 0) dw   (dense quadrature, ray-sphere tests),
 * with the same band-limited L in both. Also reported: the raw coefficient error of V against the
 * projection of the true visibility, |V - P V_true| / |P V_true|.
 * A set holds the sphere sets with their ray-traced truth, computed once for up to
 * PEN_ACCURACY_MAX_BANDS bands; models are evaluated on it cheaply at any band count <= that.
 */
#ifndef PENUMBRA_RESEARCH_H
#define PENUMBRA_RESEARCH_H

#include "penumbra/core.h"
#include "penumbra/envmap.h" /* pen_envmap_to_sh: the projection whose accuracy is measured */
#include "penumbra/image.h"
#include "penumbra/sh.h"

#ifdef __cplusplus
extern "C" {
#endif

#define PEN_ACCURACY_MAX_BANDS 6
#define PEN_ACCURACY_COUNTS 3        /* sphere counts 1, 8, 32 */
#define PEN_ACCURACY_MAX_LIGHTS 4    /* sky+sun and up to three environment maps */

typedef struct pen_accuracy_options {
    unsigned long long seed;         /* seed of the sphere sets and lightings */
    int sets_per_count;              /* sphere sets per sphere count (default 100) */
    int quadrature;                  /* directions: n cos-theta rows x 2n phi columns (default 256) */
    int envmap_count;                /* up to PEN_ACCURACY_MAX_LIGHTS - 1 */
    const pen_image *envmaps;        /* equirectangular maps (borrowed during create) */
    const char *const *envmap_names; /* their names for the report */
} pen_accuracy_options;

/* Sensible defaults: seed 2 (the held-out set; calibration uses seed 1), 100 sets, 256. */
pen_accuracy_options pen_accuracy_options_default(void);

typedef struct pen_accuracy_set pen_accuracy_set;

pen_status pen_accuracy_set_create(pen_context *ctx, const pen_accuracy_options *opt,
                                           pen_accuracy_set **out);
void pen_accuracy_set_destroy(pen_accuracy_set *set);

/* The sphere count of row c (0..PEN_ACCURACY_COUNTS-1), the number of lightings, their names. */
int pen_accuracy_sphere_count(int c);
int pen_accuracy_light_count(const pen_accuracy_set *set);
const char *pen_accuracy_light_name(const pen_accuracy_set *set, int light);

typedef struct pen_accuracy_stats {
    double median, p90, mean;        /* of |E - E_true| / E_unoccluded */
    double coef_median;              /* of |V - P V_true| / |P V_true| */
} pen_accuracy_stats;

/* Evaluates model m with log-visibility depth epsilon at `bands` (<= PEN_ACCURACY_MAX_BANDS),
 * in the float hot path, filling stats[c][light]. */
pen_status pen_accuracy_evaluate(
    pen_context *ctx, const pen_accuracy_set *set, int bands, const pen_sh_exp_model *m,
    double epsilon, pen_accuracy_stats stats[PEN_ACCURACY_COUNTS][PEN_ACCURACY_MAX_LIGHTS]);

/* Fits the CALIBRATED model's parameters (epsilon, a, b, band windows; squarings by search) at
 * `bands` on `train`, minimising the mean irradiance error over all rows. *objective receives the
 * mean error reached. Deterministic. */
pen_status pen_accuracy_calibrate(pen_context *ctx, const pen_accuracy_set *train,
                                          int bands, pen_sh_exp_model *out, double *objective);

/* Ray-tested truth of the protocol (research/accuracy.c; exposed for tests/test_sh_accuracy.c)
 * for up to PEN_ACCURACY_MAX_SPHERES spheres seen from the origin, receiver normal +Y, on an
 * nq x 2nq grid: T_k = integral Y_k V max(w_y, 0) dw and P_k = integral Y_k V dw for
 * k < PEN_ACCURACY_MAX_BANDS^2. */
#define PEN_ACCURACY_MAX_SPHERES 32
void pen__accuracy_truth(const float (*spheres)[4], int count, int nq, double *T, double *P);

#ifdef __cplusplus
}
#endif
#endif
