/* A uniform grid of boxes (spatial.c): each item is registered in every cell its box overlaps, so
 * that a point finds the items whose box holds it in its own cell, and a ball finds the items
 * near it in the cells it overlaps, instead of testing every item. The sphere fit (fit.c,
 * fit_seed.c) and the coverage report (coverage.c) put spheres (box: the ball grown by a reach)
 * and surface samples (box: the point) in it. Internal to src/geometry. */
#ifndef PEN_GEOMETRY_SPATIAL_H
#define PEN_GEOMETRY_SPATIAL_H

#include "core/internal.h"

typedef struct pen__grid {
    double lo[3]; /* corner of cell (0, 0, 0) */
    double cell;  /* cell edge */
    int n[3];
    long *start; /* n[0] n[1] n[2] + 1 offsets into items */
    int *items;  /* item indices per cell, increasing within a cell */
} pen__grid;

/* Cells of at most this many in all: a larger request gets a coarser cell. */
#define PEN__GRID_MAX_CELLS (1L << 21)

/* Builds the grid over `count` boxes (6 doubles each: low x, y, z, high x, y, z) with cells of
 * edge `cell` (> 0; made coarser to keep within PEN__GRID_MAX_CELLS). The items of a cell come in
 * increasing index order, so a walk over them is deterministic. */
pen_status pen__grid_build(pen_context *ctx, const double *boxes, long count, double cell,
                           pen__grid *g);
void pen__grid_free(pen__grid *g);

/* The cell index range [lo, hi] (inclusive, clamped to the grid) that the box [a, b] overlaps;
 * returns 0 when the box misses the grid. */
int pen__grid_range(const pen__grid *g, const double a[3], const double b[3], int lo[3],
                    int hi[3]);

/* The items of cell (i, j, k): *n of them. */
static inline const int *pen__grid_cell(const pen__grid *g, int i, int j, int k, long *n) {
    const long c = i + (long)g->n[0] * (j + (long)g->n[1] * k);
    *n = g->start[c + 1] - g->start[c];
    return g->items + g->start[c];
}

/* The items whose box holds p (and possibly others of its cell): *n of them, none outside. */
const int *pen__grid_at(const pen__grid *g, const double p[3], long *n);

/* Sphere boxes for pen__grid_build: sphere i (x, y, z, r: 4 doubles) grown by `reach` >= 0. */
void pen__grid_sphere_boxes(const double *spheres, int count, double reach, double *boxes);

#endif
