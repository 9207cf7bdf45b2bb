/* Internal interface of src/scene/texture.c: bilinear texture sampling and its backward. */
#ifndef PEN_SCENE_TEXTURE_H
#define PEN_SCENE_TEXTURE_H

#include "penumbra/image.h"

/* Bilinear texture lookup (3 channels), repeat wrap, texel centres at ((i + 0.5) / W,
 * 1 - (j + 0.5) / H) in (u, v) with v up (row 0 is the top of the image). */
void pen__texture_fwd(const pen_image *tex, const float uv[2], float rgb[3]);
/* Adds into d_texels (3 per texel, may be NULL) and d_uv (may be NULL). */
void pen__texture_bwd(const pen_image *tex, const float uv[2], const float d_rgb[3],
                      float *d_texels, float d_uv[2]);

/* Footprint-filtered lookup (the renderer's): the mean of pen__texture_fwd at the K =
 * PEN__TEXTURE_GRID^2 points uv + J o, o on a fixed grid of cell centres over [-1/2, 1/2]^2 and
 * J = d(u, v)/d(pixel x, y) row-major ({du/dx, du/dy, dv/dx, dv/dy}): a box filter of the
 * texture over the pixel. */
#define PEN__TEXTURE_GRID 3
#define PEN__TEXTURE_SAMPLES (PEN__TEXTURE_GRID * PEN__TEXTURE_GRID)
void pen__texture_footprint_fwd(const pen_image *tex, const float uv[2], const float J[4],
                                float rgb[3]);
/* Adds into d_texels, d_uv and d_J (each may be NULL). */
void pen__texture_footprint_bwd(const pen_image *tex, const float uv[2], const float J[4],
                                const float d_rgb[3], float *d_texels, float d_uv[2],
                                float d_J[4]);

/* The rows a lookup at uv (over the footprint J, or NULL for a point) may read: first .. last,
 * wrapped (first > last: first .. height - 1 and 0 .. last), a row more on each side than its
 * samples reach. Returns 0, leaving them alone, when it may read any row (a footprint over the
 * whole image, or coordinates that are not finite). */
int pen__texture_rows(const pen_image *tex, const float uv[2], const float J[4], long *first,
                      long *last);

/* The texel part of pen__texture_bwd (J NULL) or pen__texture_footprint_bwd, for the texels of
 * rows [r0, r1) only: each texel receives exactly the terms, in the same order, that the full
 * backward gives it, so disjoint row bands can be scattered by different threads with the same
 * result (the renderer's texel scatter). */
void pen__texture_scatter_rows(const pen_image *tex, const float uv[2], const float J[4],
                               const float d_rgb[3], float *d_texels, long r0, long r1);

#endif
