/* Internal pieces of the sphere fit (src/geometry/fit.c), shared with the tests. The voxel grid
 * and surface samples it fits to are voxelize.h's. */
#ifndef PEN_GEOMETRY_FIT_INTERNAL_H
#define PEN_GEOMETRY_FIT_INTERNAL_H

#include "core/internal.h"
#include "core/random.h"
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

typedef struct pen__fit_problem {
    pen__fit_points sov;   /* outside voxel centres (Og = 1) */
    pen__fit_points surf;  /* surface samples */
    double surface_weight; /* w_s */
    double inv_sigma2;     /* 1 / sigma^2: phi(s) = tanh(relu(s * inv_sigma2)) */
    double u_max;          /* phi = 1 for s * inv_sigma2 >= u_max (PEN__FIT_U_*) */
    int threads;           /* 0: OpenMP default */
    double serial_pairs;   /* one thread below this many point-sphere pairs (0: never) */
} pen__fit_problem;

/* E(C, R) of eq. 5 for `count` spheres given as x, y, z, r (4 doubles each). */
double pen__fit_energy_fwd(const pen__fit_problem *p, int count, const double *spheres);
/* d_spheres += dE/d(spheres) * d_E (4 * count). Returns E as a by-product of the same pass. */
double pen__fit_energy_bwd(const pen__fit_problem *p, int count, const double *spheres, double d_E,
                           double *d_spheres);

#endif
