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

/* One occluding triangle mesh (world space). */
typedef struct pen__transfer_mesh {
    int vertex_count, triangle_count;
    const float *positions; /* 3 per vertex */
    const uint32_t *indices;
} pen__transfer_mesh;

typedef struct pen__transfer_request {
    int mesh_count;                   /* occluders: traced together */
    const pen__transfer_mesh *meshes;
    int point_count;                  /* receivers: where the transfer is wanted */
    const float *points;              /* 3 per point, world space */
    const float *normals;             /* 3 per point (need not be unit; a zero one gets B = 0) */
    int bands;
    int light_count;
    const double (*light_w)[3]; /* unit directions towards the lights */
    const double *light_b;      /* angular radii, radians */
    const pen_ground *ground;   /* an occluder too when not NULL and enabled */
} pen__transfer_request;

/* B (bands^2 floats per point): B_k = integral of (1 - V(x, w)) max(n . w, 0) Y_k(w) dw, the
 * part of the clamped cosine H_n the meshes (and the ground when asked) block from the point, V
 * the binary visibility of rays leaving the point offset along n (by 1e-4 of the occluders'
 * bounding diagonal), so that the point's transfer is T = H_n - B. A cosine-weighted stratified
 * estimate: an unoccluded point gets B = 0 exactly. frac (light_count floats per point, may be
 * NULL): the share of each disk's samples above the point's tangent plane that nothing blocks (1
 * when none is above). Deterministic: each point's samples come from its index, so any thread
 * count gives the same result. The points are typically the meshes' own vertices (self transfer)
 * or nodes refined from them. */
pen_status pen__transfer(pen_context *ctx, const pen__transfer_request *rq, float *B, float *frac);

/* The same on an Embree device made by pen__transfer_device (NULL: one for this call), for a
 * caller with many requests (the renderer: one per object with the transfer), which would
 * otherwise pay a device per request (about 0.5 ms, bench/NOTES.md "Many small objects"). */
pen_status pen__transfer_on(pen_context *ctx, void *device, const pen__transfer_request *rq,
                            float *B, float *frac);
/* A request's occluders built once (an Embree scene on a device of its own) for many requests
 * with the same meshes; immutable once built, so threads may trace it at once. */
typedef struct pen__transfer_bvh pen__transfer_bvh;
pen_status pen__transfer_bvh_build(pen_context *ctx, const pen__transfer_request *rq,
                                   pen__transfer_bvh **out);
void pen__transfer_bvh_free(pen__transfer_bvh *bvh); /* NULL: nothing */
/* pen__transfer on occluders built by pen__transfer_bvh_build from the same meshes. */
pen_status pen__transfer_bvh_trace(pen_context *ctx, const pen__transfer_bvh *bvh,
                                   const pen__transfer_request *rq, float *B, float *frac);
/* The light fractions alone (rq->bands and B unused): with centres 0, the disk samples as
 * pen__transfer draws them; with centres 1, one ray towards each light's centre, frac 0 where it
 * is blocked and 1 otherwise (or below the tangent plane). frac must hold light_count floats per
 * point. bvh: rq's occluders built by pen__transfer_bvh_build, or NULL to build them here. */
pen_status pen__transfer_lights(pen_context *ctx, const pen__transfer_bvh *bvh,
                                const pen__transfer_request *rq, int centres, float *frac);
/* An Embree device with the context's thread count, or NULL after setting ctx's error; released
 * by pen__transfer_device_free (NULL: nothing). */
void *pen__transfer_device(pen_context *ctx);
void pen__transfer_device_free(void *device);

#endif
