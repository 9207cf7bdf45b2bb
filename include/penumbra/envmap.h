/* penumbra/envmap.h -- equirectangular environment maps: the direction of a map coordinate and
 * back, the projection of a map onto spherical harmonics, and the radiance a map sends along a
 * direction. Implemented in src/io/envmap.c, beside the image files the maps come from.
 */
#ifndef PENUMBRA_ENVMAP_H
#define PENUMBRA_ENVMAP_H

#include "penumbra/core.h"
#include "penumbra/image.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Equirectangular maps (Y up). u in [0, 1) is the azimuth phi = 2 pi u, v in [0, 1] the polar
 * angle theta = pi v from +Y:
 *     dir(u, v) = (-sin(theta) sin(phi), cos(theta), sin(theta) cos(phi)).
 * Row 0 is the zenith, the middle row the horizon; the image centre (u = 1/2) is the direction
 * -Z, u = 3/4 is +X, u = 1/4 is -X, and u = 0 is +Z: seen from the origin looking along -Z the
 * map is not mirrored. Pixel (x, y) of a W x H map covers u in [x/W, (x+1)/W), v in
 * [y/H, (y+1)/H).
 * A rotation by rotation_y_deg = a turns the map right-handedly about +Y: map direction d lights
 * the scene from world direction R_y(a) d, R_y(a) (x, y, z) = (cos a x + sin a z, y,
 * -sin a x + cos a z). */
PEN_API void pen_envmap_direction(float u, float v, float dir[3]);
/* The inverse (dir need not be unit length; the zero vector gives u = v = 0). */
PEN_API void pen_envmap_uv(const float dir[3], float *u, float *v);
/* Projects an equirectangular map (1 or >= 3 channels; grey is repeated) onto `bands` bands,
 * after rotating it by rotation_y_deg about +Y and multiplying by scale (finite, >= 0):
 * sh[i][ch] for i < bands^2. Each pixel is weighted by the exact solid angle of its cell,
 * (2 pi / W) (cos theta_top - cos theta_bottom), and sampled at its centre; negative pixel values
 * are clamped to 0. NaN/Inf pixels are an error. */
PEN_API pen_status pen_envmap_to_sh(pen_context *ctx, const pen_image *env, int bands,
                                    float rotation_y_deg, float scale, float sh[][3]);
/* The radiance arriving from world direction dir (the background seen along a camera ray):
 * the map rotated by rotation_y_deg and multiplied by scale, bilinear between texel centres
 * (wrapping in u, clamped in v), negative texels clamped to 0. An invalid map gives black. */
PEN_API void pen_envmap_eval(const pen_image *env, float rotation_y_deg, float scale,
                             const float dir[3], float rgb[3]);

#ifdef __cplusplus
}
#endif
#endif
