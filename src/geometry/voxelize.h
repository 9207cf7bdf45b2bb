/* The inside/outside voxel grid of a mesh and area-uniform surface samples (voxelize.c): what
 * the sphere fit (fit.c) fits to. Internal to src/geometry, shared with the tests. */
#ifndef PEN_GEOMETRY_VOXELIZE_H
#define PEN_GEOMETRY_VOXELIZE_H

#include "core/internal.h"
#include "geometry/embree.h"
#include "penumbra/fit.h" /* PEN_FIT_MAX_VOXELS */
#include "penumbra/mesh.h"

#include <stdint.h>

/* Cubic voxels of edge h; voxel (i, j, k) has its centre at origin + h * (i, j, k) (the origin is
 * the first centre) and index i + n[0] * (j + n[1] * k). */
typedef struct pen__fit_grid {
    double origin[3];
    double h;
    int n[3];
    uint8_t *inside; /* n[0] n[1] n[2] flags, 1 = inside the mesh */
} pen__fit_grid;

/* The longest side of a mesh's bounding box that the fitter accepts (voxelize.c says why). */
#define PEN__FIT_MIN_SIDE 1e-9
#define PEN__FIT_MAX_SIDE 1e9

/* pen_mesh_validate, a bounding box that is not a point and whose longest side is within
 * [PEN__FIT_MIN_SIDE, PEN__FIT_MAX_SIDE]; on success lo/hi are the bounds. */
pen_status pen__fit_check_mesh(pen_context *ctx, const pen_mesh *mesh, float lo[3], float hi[3]);
/* pen__fit_check_mesh, and the longest side of the bounds into *side. */
pen_status pen__fit_mesh_side(pen_context *ctx, const pen_mesh *mesh, double *side);
/* Builds the grid over the mesh bounds padded by `pad` of the longest extent on every side, with
 * `voxels` voxels along the longest padded axis, and classifies every centre (six-vote winding
 * number test, see fit.h). */
pen_status pen__fit_voxelize(pen_context *ctx, const pen_mesh *mesh, int voxels, double pad,
                             pen__fit_grid *out);
void pen__fit_grid_free(pen__fit_grid *grid);

/* Area-uniform random points on the surface: 3 * count floats, and when tri is not NULL the
 * triangle of each point. Also returns the total area. */
pen_status pen__fit_sample_surface(pen_context *ctx, const pen_mesh *mesh, int count, uint64_t seed,
                                   float *points, int *tri, double *area);

/* The Embree device configuration of every fit step (voxels, medial balls). One build thread: the
 * BVH of such a mesh builds in milliseconds, less than it takes to start Embree's worker pool for
 * every fit. */
#define PEN__FIT_EMBREE_CONFIG "threads=1," PEN__EMBREE_ISA

/* A committed Embree scene of the mesh's triangles on `device` (geometry 0, primitive = triangle
 * index), with `filter` as its intersection filter when not NULL. NULL on failure (recorded in
 * ctx). */
RTCScene pen__fit_embree_scene(pen_context *ctx, RTCDevice device, const pen_mesh *mesh,
                               RTCFilterFunctionN filter);

#endif
