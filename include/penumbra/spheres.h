/* penumbra/spheres.h -- sphere sets, the proxy geometry that casts shadows.
 *
 * Layout: float4 per sphere, x, y, z (center) and r (radius), the layout Embree's sphere
 * geometry takes: data[4 i + 0..2] = center, data[4 i + 3] = radius (> 0).
 * File: JSON {"spheres": [{"center": [x, y, z], "radius": r}, ...], "metrics": {...}, ...};
 * a bare array of sphere objects is accepted too.
 */
#ifndef PENUMBRA_SPHERES_H
#define PENUMBRA_SPHERES_H

#include "penumbra/core.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pen_spheres {
    int count;
    float *data; /* 4 * count: x, y, z, r */
} pen_spheres;

pen_status pen_spheres_create(pen_context *ctx, int count, pen_spheres *out);
void pen_spheres_free(pen_spheres *spheres);
pen_status pen_spheres_load(pen_context *ctx, const char *path, pen_spheres *out);
/* Writes the spheres; `extra_json` (may be NULL) is a JSON object text whose members are added
 * at the top level (e.g. "metrics"). Atomic: temp file + rename. */
pen_status pen_spheres_save(pen_context *ctx, const char *path, const pen_spheres *spheres,
                            const char *extra_json);

#ifdef __cplusplus
}
#endif
#endif
