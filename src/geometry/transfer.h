/* Precomputed self-transfer of a rigid mesh (transfer.c, docs/design.md sec. 1.15): per vertex, the
 * SH projection of what the mesh's own surfaces block of the clamped cosine, and the unblocked fraction
 * of each disk light, ray traced with Embree. Internal; the renderer caches the result. */
#ifndef PEN_GEOMETRY_TRANSFER_H
#define PEN_GEOMETRY_TRANSFER_H

#include "penumbra/core.h"
#include "penumbra/scene.h"

#include <stdint.h>

/* Directions per vertex of the SH transfer (a square: stratified in the unit square) and samples
 * per disk light. */
#define PEN_TRANSFER_DIRECTIONS 256
#define PEN_TRANSFER_DISK_SAMPLES 64

typedef struct pen__transfer_request {
    int vertex_count, triangle_count;
    const float *positions; /* 3 per vertex, world space */
    const float *normals;   /* 3 per vertex (need not be unit; a zero one gets a zero transfer) */
    const uint32_t *indices;
    int bands;
    int light_count;
    const double (*light_w)[3]; /* unit directions towards the lights */
    const double *light_b;      /* angular radii, radians */
    const pen_ground *ground;   /* traced as an occluder too when not NULL and enabled */
} pen__transfer_request;

/* B (bands^2 floats per vertex): B_k = integral of (1 - V(x, w)) max(n . w, 0) Y_k(w) dw, the
 * part of the clamped cosine H_n the mesh (and the ground when asked) blocks from the vertex, V
 * the binary visibility of rays leaving a point offset along n, so that the vertex's transfer is
 * T_self = H_n - B. A cosine-weighted stratified estimate: an unoccluded vertex gets B = 0 exactly.
 * frac (light_count floats per vertex, may be NULL): the share of each disk's samples above the
 * vertex's tangent plane that no triangle blocks (1 when none is above). Deterministic: each
 * vertex's samples come from its index, so any thread count gives the same result. */
pen_status pen__mesh_transfer(pen_context *ctx, const pen__transfer_request *rq, float *B,
                              float *frac);

#endif
