/* Sphere sets as JSON values, shared by the sphere files (spheres.c) and scenes that give their
 * spheres inline (scene.c). */
#ifndef PEN_IO_SPHERES_JSON_H
#define PEN_IO_SPHERES_JSON_H

#include "io/io_internal.h"
#include "penumbra/spheres.h"

/* Reads an array of {"center": [x, y, z], "radius": r} at key path w. */
pen_status pen__spheres_from_json(pen_context *ctx, const pen__json_where *w, const cJSON *list,
                                  pen_spheres *out);
/* The array form of a sphere set (NULL on exhaustion). */
cJSON *pen__spheres_to_json(const pen_spheres *spheres);
/* Finite centers and positive finite radii; errors name `what` and the sphere. */
pen_status pen__spheres_check(pen_context *ctx, const char *what, const pen_spheres *spheres);

#endif
