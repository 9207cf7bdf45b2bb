/* penumbra/spheres.h -- sphere sets, the proxy geometry that casts shadows.
 *
 * Layout: float4 per sphere, x, y, z (center) and r (radius), the layout Embree's sphere
 * geometry takes: data[4 i + 0..2] = center, data[4 i + 3] = radius (> 0).
 * File: JSON {"spheres": [{"center": [x, y, z], "radius": r, "weight": k}, ...], "metrics": {...},
 * ...}; a bare array of sphere objects is accepted too. "weight" (optional, all spheres or none)
 * is the sphere's overlap weight, see pen_spheres_overlap_weights.
 */
#ifndef PENUMBRA_SPHERES_H
#define PENUMBRA_SPHERES_H

#include "penumbra/core.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The weighted count of spheres along a line through a set (see pen_spheres_overlap_weights): a
 * shadow ray through an object gets this many times the blocker depth epsilon. 2, not 1: the
 * calibrated epsilon was fitted on small isolated caps, and proxied objects near a receiver
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

PEN_API pen_status pen_spheres_create(pen_context *ctx, int count, pen_spheres *out);
PEN_API void pen_spheres_free(pen_spheres *spheres);
PEN_API pen_status pen_spheres_load(pen_context *ctx, const char *path, pen_spheres *out);
/* Overlap weights: kappa[i] >= 0 per sphere (count floats), chosen so that along a line through
 * the set the weights of the spheres it crosses add up to about PEN_SPHERES_OVERLAP_TARGET (a
 * non-negative least-squares fit over random lines, docs/fit-spheres.md). The renderer multiplies
 * sphere i's log-visibility by kappa[i], so that a shadow ray through an object has about the same
 * depth however many of its overlapping proxy spheres it crosses. Deterministic (fixed seed,
 * independent of the thread count); a single sphere gets exactly the target, disjoint spheres
 * about the target, k coincident copies about target / k each. Invariant under a pose (computed
 * in object space). Fails on a radius <= 0 or a non-finite value. */
PEN_API pen_status pen_spheres_overlap_weights(pen_context *ctx, const pen_spheres *spheres,
                                               float *kappa);
/* Computes spheres->weight when it is NULL (allocating it); leaves existing weights alone. */
PEN_API pen_status pen_spheres_ensure_weights(pen_context *ctx, pen_spheres *spheres);
/* Writes the spheres; `extra_json` (may be NULL) is a JSON object text whose members are added
 * at the top level (e.g. "metrics"). Atomic: temp file + rename. */
PEN_API pen_status pen_spheres_save(pen_context *ctx, const char *path, const pen_spheres *spheres,
                                    const char *extra_json);

#ifdef __cplusplus
}
#endif
#endif
