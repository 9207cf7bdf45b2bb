/* Internal declarations of the SH engine (src/sh). */
#ifndef PEN_SH_INTERNAL_H
#define PEN_SH_INTERNAL_H

#include "penumbra/sh.h"

extern const double pen__sh_K[PEN_SH_MAX_BANDS][PEN_SH_MAX_BANDS];

/* The SH product tensor, generated into src/sh/tables.c from scripts/sh_common.py (its one
 * definition): the non-zero Gamma_ijk for i <= j <= k < PEN_SH_MAX_COEFFS, sorted by (i, j, k).
 * pen_sh_gaunt_table (src/sh/gaunt.c) builds each band count's ordered table from it. */
extern const int pen__sh_gaunt_triple_count;
extern const pen_sh_gaunt_entry pen__sh_gaunt_triples[];

/* M[j * n + k] = the integral of Y_j Y_k over the directions with y > -t (t in [-1, 1]),
 * n = bands^2: the matrix that multiplies an SH function by the indicator of y > -t and projects
 * the product back to `bands` (symmetric; t = 0: the upper hemisphere). dM (may be NULL)
 * receives its derivative in t, the integral of Y_j Y_k over the circle y = -t. Exact
 * quadrature in double. */
void pen__sh_above(int bands, double t, double *M, double *dM);

/* sqrt(4 pi): the DC coefficient of the constant function 1. */
#define PEN_SH_SQRT_4PI 3.5449077018110320546

/* Most squarings any method takes (EXACT on huge inputs); bounds the backward's stack use. */
#define PEN_SH_EXP_MAX_SQUARINGS 20
/* Degree of the EXACT method's Taylor series: after scaling |g| <= 1/16, the remainder
 * |g|^11 / 11! is below 1e-20. */
#define PEN_SH_EXP_TAYLOR_ORDER 10

#endif
