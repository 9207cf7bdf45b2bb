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

#endif
