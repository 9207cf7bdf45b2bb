/* penumbra/spheres.h -- sphere sets, the proxy geometry that casts shadows: layout, creation,
 * freeing (src/scene). Files: penumbra/io.h; fitting and overlap weights: penumbra/fit.h.
 *
 * Layout: float4 per sphere, x, y, z (center) and r (radius), the layout Embree's sphere
 * geometry takes: data[4 i + 0..2] = center, data[4 i + 3] = radius (> 0).
 * File: JSON {"spheres": [{"center": [x, y, z], "radius": r, "weight": k}, ...], "metrics": {...},
 * ...}; a bare array of sphere objects is accepted too. "weight" (optional, all spheres or none)
 * is the sphere's overlap weight, see pen_spheres_overlap_weights (penumbra/fit.h).
 */
#ifndef PENUMBRA_SPHERES_H
#define PENUMBRA_SPHERES_H

#include "penumbra/core.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The weighted count of spheres along a line through a set (see pen_spheres_overlap_weights in
 * fit.h): a shadow ray through an object gets this many times the blocker depth epsilon. 2, not 1:
 * the calibrated epsilon was fitted on small isolated caps, and proxied objects near a receiver
 * subtend large ones, which band-limited visibility darkens less; 2 had the lowest mean render
 * error for Spot and Bob at 1 to 64 spheres under both bundled maps, never more than 9 % above
 * each case's best (docs/fit-spheres.md, "Overlap weights"). */
#define PEN_SPHERES_OVERLAP_TARGET 2.0

typedef struct pen_spheres {
    int count;
    float *data;   /* 4 * count: x, y, z, r */
    float *weight; /* count overlap weights (>= 0), or NULL when not (yet) computed; owned like
                      data (pen_spheres_free frees both) */
} pen_spheres;

/* Allocates `count` zeroed spheres (count in [0, 2^28]; weight stays NULL). */
PEN_API pen_status pen_spheres_create(pen_context *ctx, int count, pen_spheres *out);
/* Frees data and weight and zeroes the set; NULL is a no-op. */
PEN_API void pen_spheres_free(pen_spheres *spheres);

#ifdef __cplusplus
}
#endif
#endif
