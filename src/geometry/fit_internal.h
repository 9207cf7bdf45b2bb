/* Internal pieces of the sphere fit (src/geometry/fit.c), shared with the tests. The voxel grid
 * and surface samples it fits to are voxelize.h's. */
#ifndef PEN_GEOMETRY_FIT_INTERNAL_H
#define PEN_GEOMETRY_FIT_INTERNAL_H

#include "core/internal.h"
#include "core/random.h"
#include "geometry/spatial.h"
#include "geometry/voxelize.h"
#include "penumbra/fit.h"

#include <stdint.h>

/* Copies the settings (defaults for NULL), fills zero fields with the defaults, checks ranges. */
pen_status pen__fit_resolve_settings(pen_context *ctx, const pen_fit_settings *in,
                                     pen_fit_settings *out);

/* ---- Energy (fit.c) ------------------------------------------------------------------------ */

/* tanh(u) rounds to 1 in double for u >= 20 (1 - tanh(20) < 1e-17), so skipping those terms is
 * exact; PEN__FIT_U_FAST skips where 1 - tanh(u) < 3e-8 (float precision), 4x fewer tanh calls. */
#define PEN__FIT_U_EXACT 20.0
#define PEN__FIT_U_FAST 9.0

/* A point set of the energy, grouped into cells (bricks of voxels) so that a sphere whose
 * influence cannot reach a cell is skipped for all of its points. */
typedef struct pen__fit_points {
    long count;
    const float *xyz;         /* 3 * count, cell by cell */
    int cells;                /* 0: one cell with every point and no bound */
    const long *cell_start;   /* cells + 1 offsets into the points */
    const double *cell_bound; /* 4 per cell: centre x, y, z and a radius enclosing its points */
} pen__fit_points;

/* The energy's scratch: which spheres reach which cell, per-cell sums (fit.c). */
typedef struct pen__fit_work pen__fit_work;

typedef struct pen__fit_problem {
    pen__fit_points sov;   /* outside voxel centres (Og = 1) */
    pen__fit_points surf;  /* surface samples */
    double surface_weight; /* w_s */
    double inv_sigma2;     /* 1 / sigma^2: phi(s) = tanh(relu(s * inv_sigma2)) */
    double u_max;          /* phi = 1 for s * inv_sigma2 >= u_max (PEN__FIT_U_*) */
    int threads;           /* 0: OpenMP default */
    double serial_pairs;   /* one thread below this many point-sphere pairs (0: never) */
    pen__fit_work *work;   /* kept across calls (pen__fit_work_create), or NULL: made per call */
} pen__fit_problem;

/* Scratch for repeated evaluations of one problem (its points and cells must not change). */
pen_status pen__fit_work_create(pen_context *ctx, const pen__fit_problem *p, pen__fit_work **out);
void pen__fit_work_free(pen__fit_work *w);

/* E(C, R) of eq. 5 for `count` spheres given as x, y, z, r (4 doubles each). The sums run per
 * cell and are added in cell order, so the result does not depend on the thread count. NaN when
 * scratch memory runs out. */
double pen__fit_energy_fwd(const pen__fit_problem *p, int count, const double *spheres);
/* d_spheres += dE/d(spheres) * d_E (4 * count). Returns E as a by-product of the same pass. */
double pen__fit_energy_bwd(const pen__fit_problem *p, int count, const double *spheres, double d_E,
                           double *d_spheres);

/* ---- Medial balls and the allocation of spheres (fit_seed.c) --------------------------------- */

/* For each surface sample j (pts[3 j], on triangle tri[j]): the largest ball inside the mesh that
 * touches the surface at the sample, found by shrinking the ball whose diameter is the inward
 * normal's chord until no part of the surface is inside it (Ma et al., "3D medial axis point
 * approximation using nearest neighbors and the normal field", 2012, on the exact surface instead
 * of samples). balls[4 j ..]: centre, radius; radius 0 where the inward ray leaves the mesh
 * without crossing it from inside (an open mesh, an inconsistent orientation). thick[j]: half the
 * inward chord, the local half-thickness (unlike the medial radius it does not shrink towards an
 * edge of a panel), 0 with the ball. Independent of the thread count. */
pen_status pen__fit_medial_balls(pen_context *ctx, const pen_mesh *mesh, const float *pts,
                                 const int *tri, int n, int threads, double *balls, double *thick);

/* Thin parts count up to this many times their area when spheres are allocated. */
#define PEN__FIT_THIN_MAX 8.0

/* Where spheres are worth most, on the hard version of the fit's energy with thin parts weighted
 * up (fit_seed.c says how): the samples, their medial balls and weights, and candidate balls
 * with their outside volume. */
typedef struct pen__fit_alloc {
    int n;                       /* surface samples */
    const float *pts;            /* 3 n, borrowed */
    const double *balls;         /* 4 n medial balls, borrowed */
    const double *thick;         /* n half-thicknesses, borrowed */
    const pen__fit_grid *voxels; /* inside flags, borrowed */
    double *weight;              /* n: clamp(r_ref / half-thickness, 1, PEN__FIT_THIN_MAX) */
    pen__grid samples;           /* the samples, for those inside a ball */
    double surface_weight;       /* w_s */
    long n_cand;
    double *cand; /* 4 per candidate ball (radius <= 0: none) */
    double *cost; /* outside voxels in each candidate */
    int threads;
} pen__fit_alloc;

pen_status pen__fit_alloc_init(pen_context *ctx, pen__fit_alloc *a, const float *pts,
                               const double *balls, const double *thick, int n,
                               const pen__fit_grid *voxels,
                               double surface_weight, double r_ref, double r_cap, double r_min,
                               int threads);
void pen__fit_alloc_free(pen__fit_alloc *a);
/* One round of moves of the `count` spheres (4 doubles each): those whose loss is at most
 * max_loss and below the best candidate's gain go there. Returns how many moved (flagged in
 * moved[], which it clears first), or -1 when out of memory. */
int pen__fit_alloc_move(pen_context *ctx, pen__fit_alloc *a, double *sph, int count,
                        uint8_t *moved, double max_loss);
/* Moves spheres (at most max_moves; flags them in moved[], which it does not clear) until no
 * sample lies more than tau / sqrt(its weight) outside the set, or no move lowers the largest
 * such gap. Returns the moves or -1. */
int pen__fit_alloc_spread(pen_context *ctx, pen__fit_alloc *a, double *sph, int count, double tau,
                          int max_moves, uint8_t *moved);

#endif
