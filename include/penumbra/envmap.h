/* penumbra/envmap.h -- equirectangular environment maps: the direction of a map coordinate and
 * back, the projection of a map onto spherical harmonics, the radiance a map sends along a
 * direction, and the compact bright sources (sun, lamps) found in a map as disk lights.
 * Implemented in src/lighting/ (envmap.c, envmap_lights.c), below src/io, whose scene loader
 * calls it for a map's SH and lights (docs/design.md sec. 1.14, 6.1); the maps themselves are
 * images (pen_image_load, io.h).
 */
#ifndef PENUMBRA_ENVMAP_H
#define PENUMBRA_ENVMAP_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/scene.h"

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

/* ---- Lights from an environment map (docs/design.md sec. 1.14) -------------------------------
 * The criterion, with the constants below (lum = 0.2126 R + 0.7152 G + 0.0722 B, texels clamped
 * at 0, every sum weighted by the texels' exact solid angles):
 *  1. base = the solid-angle-weighted median luminance of the map (to 1/32 of an octave);
 *     thresholds t_k = PEN_ENVMAP_LIGHT_THRESHOLD * base * PEN_ENVMAP_LIGHT_STEP^k.
 *  2. The texels above t_0 form connected regions (8-neighbours, wrapping in u). A region whose
 *     texels all lie within PEN_ENVMAP_LIGHT_MAX_EXTENT_DEG of its luminance centroid is a
 *     candidate; a larger one (a bright sky, a wall of windows) is split again at the next
 *     threshold, inside itself only, until its parts are compact or nothing is left above it.
 *  3. A candidate's surroundings level b (per channel) is the solid-angle-weighted mean of the
 *     texels within PEN_ENVMAP_LIGHT_RING texels of it (not in it). Each of its texels keeps
 *     min(L, b) in the residual; the excess L - min(L, b) >= 0 becomes the light.
 *  4. The light: direction = the excess-luminance-weighted mean direction; angular radius b_r =
 *     sqrt(2 <theta^2>) (a uniform disk's second moment), theta the angle to that direction with
 *     each texel's own spread added, clamped to [PEN_SCENE_MIN_LIGHT_RADIUS_DEG,
 *     PEN_ENVMAP_LIGHT_MAX_EXTENT_DEG]; irradiance = (1 + cos b_r) / 2 * integral of the excess,
 *     so that the disk's radiance E / (pi sin^2 b_r) (pen_light) times its solid angle is the
 *     excess's integral: the residual plus the lights hold the map's energy exactly.
 *  5. A candidate counts when its excess carries at least PEN_ENVMAP_LIGHT_MIN_SHARE of the
 *     luminance integral of the whole map; the largest (by that share) come first, ties by
 *     position, up to max_lights. Only those are taken out of the residual.
 * Everything runs in a fixed order in double: the result depends only on the map. */
#define PEN_ENVMAP_LIGHT_THRESHOLD 8.0   /* t_0 over the median luminance */
#define PEN_ENVMAP_LIGHT_STEP 4.0        /* ratio between successive thresholds */
#define PEN_ENVMAP_LIGHT_MAX_EXTENT_DEG 20.0 /* a light's texels within this of its centre */
#define PEN_ENVMAP_LIGHT_RING 2          /* surroundings: texels at most this far (Chebyshev) */
#define PEN_ENVMAP_LIGHT_MIN_SHARE 0.02  /* of the map's luminance integral */

/* Finds up to max_lights (>= 0, at most PEN_SCENE_MAX_LIGHTS) compact bright sources in `env`
 * by the criterion above, in world directions (the map rotated by rotation_y_deg about +Y and
 * multiplied by scale, as in pen_envmap_to_sh). lights[] receives *count lights, largest first.
 * `residual`, when not NULL, receives a new 3-channel map of the same size (in map space, not
 * rotated or scaled: project it with the same rotation and scale) with the lights' excess
 * removed; the caller frees it with pen_image_free. NaN/Inf texels are an error. */
PEN_API pen_status pen_envmap_extract_lights(pen_context *ctx, const pen_image *env,
                                             float rotation_y_deg, float scale, int max_lights,
                                             pen_light *lights, int *count, pen_image *residual);
/* The lighting a scene takes from a map: with max_lights == 0 exactly pen_envmap_to_sh, lights
 * and *count left as they are (a scene's own lights, or none); otherwise the lights
 * pen_envmap_extract_lights finds and the SH projection of its residual. */
PEN_API pen_status pen_envmap_lighting(pen_context *ctx, const pen_image *env, int bands,
                                       float rotation_y_deg, float scale, int max_lights,
                                       float sh[][3], pen_light *lights, int *count);
/* The SH projection (bands bands, radiance) of a disk light: its uniform radiance
 * E / (pi sin^2 b) over the cap of angular radius b around its direction. */
PEN_API void pen_light_to_sh(int bands, const pen_light *light, float sh[][3]);

#ifdef __cplusplus
}
#endif
#endif
