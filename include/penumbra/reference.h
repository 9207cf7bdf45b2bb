/* penumbra/reference.h -- the ground-truth renderer: Monte-Carlo shading on Embree.
 *
 * It integrates the same shading model as the SH renderer (docs/design.md sec. 1 and 2),
 *     L_o(x) = rho(x)/pi * integral L(w) V(x, w) max(n . w, 0) dw,
 * with the same camera, albedo and lighting, but with the visibility V ray-traced against the
 * real (posed) meshes and the ground plane: no spheres and no SH visibility. The lighting L is
 * either the environment map itself or its SH reconstruction, so the error of SH visibility and
 * the error of band-limiting the light can be told apart:
 *   PEN_REFERENCE_LIGHTING_ENVMAP  L(w) = scale * max(envmap(R_y(-rotation) w), 0), each texel a
 *                                  constant over its solid angle (nearest lookup); importance-
 *                                  sampled by luminance and by the cosine, combined by multiple
 *                                  importance sampling (balance heuristic).
 *   PEN_REFERENCE_LIGHTING_SH      L(w) = sum_k sh[k] Y_k(w) with scene->sh_bands bands,
 *                                  unclamped (negative lobes stay negative, as in the SH
 *                                  renderer); the unoccluded irradiance in closed form minus a
 *                                  cosine-sampled estimate of the light blockers remove.
 * Disk lights (lighting.lights, radiance E / (pi sin^2 b) over each disk) are rendered exactly,
 * one cone sample per light, combined with the other samples by the balance heuristic. ENVMAP
 * adds only lights the scene gives (PEN_LIGHTS_GIVEN, or the lights_added after the found ones):
 * lights found in the map are in it already.
 * SH adds every light: it is the lighting `render` uses (docs/design.md sec. 2).
 * Surfaces: meshes are shaded with smooth area-weighted vertex normals (interpolated, renormalised)
 * and lit from the side the camera sees (two-sided); the ground plane has normal +Y. Albedo is
 * the constant or a bilinear, wrapping texture lookup (v up; image row 0 is v = 1).
 * Pixels: `spp` jittered camera samples per pixel (stratified on the largest square grid that
 * fits), each with one light sample and one cosine sample (SH mode: one cosine sample).
 * Pixels that see nothing show the background: pen_envmap_eval in the ray direction, the SH
 * reconstruction for a scene without a map, or the constant colour.
 * Determinism: every random number is a hash of (seed, pixel, sample, dimension), so an image
 * depends only on the scene, spp and seed, never on the thread count or scheduling.
 * Threads: pen_context_threads (0 = all cores).
 *
 * Usage (the ground truth of a scene JSON, as `penumbra reference` renders it):
 *
 *     // given: ctx, scene_path
 *     pen_scene scene;
 *     pen_scene_load(ctx, scene_path, &scene);                 // io.h; no spheres needed
 *     pen_reference *ref = NULL;
 *     pen_reference_create(ctx, &scene, PEN_REFERENCE_LIGHTING_AUTO, &ref);
 *     pen_image img;
 *     pen_reference_render(ctx, ref, 256, 1, &img);            // 256 samples per pixel, seed 1
 *     pen_image_save(ctx, "reference.exr", &img);              // linear radiance
 *     pen_image_free(&img);
 *     pen_reference_destroy(ref);
 *     pen_scene_free(&scene);                                  // after ref, which borrows it
 */
#ifndef PENUMBRA_REFERENCE_H
#define PENUMBRA_REFERENCE_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/scene.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum pen_reference_lighting {
    PEN_REFERENCE_LIGHTING_AUTO = 0, /* the envmap if the scene has one and its SH lighting is
                                        the map's projection (of its residual when lights were
                                        found in it); else SH (a scene may give "sh" next to a
                                        map that is only its background) */
    PEN_REFERENCE_LIGHTING_ENVMAP = 1,
    PEN_REFERENCE_LIGHTING_SH = 2
} pen_reference_lighting;

/* Largest samples per pixel (or per point) any call accepts. */
#define PEN_REFERENCE_MAX_SPP (1 << 20)
/* The largest |world-space coordinate| (posed vertices, ground, camera eye) pen_reference_create
 * accepts: Embree aborts on rays with coordinates beyond about 1.8e18, so a scene past this is
 * refused with an error instead. Scenes within the loaders' ranges (penumbra/scene.h) stay below
 * about 2e12. */
#define PEN_REFERENCE_MAX_EXTENT 1e15

/* Opaque: the Embree scene of the posed meshes and the ground quad, world-space vertex normals,
 * and the envmap's sampling tables. It borrows `scene` (textures, envmap, camera, SH), which
 * must outlive it and stay unchanged. */
typedef struct pen_reference pen_reference;

/* Builds the ray-tracing scene. Validates the scene (indices, finite positions, sizes, texture
 * and envmap shapes); ENVMAP lighting on a scene without an envmap is an error. */
PEN_API pen_status pen_reference_create(pen_context *ctx, const pen_scene *scene,
                                        pen_reference_lighting lighting, pen_reference **out);
/* Frees the reference; NULL is a no-op. */
PEN_API void pen_reference_destroy(pen_reference *ref);
/* The lighting mode in use (AUTO resolved). */
PEN_API pen_reference_lighting pen_reference_lighting_mode(const pen_reference *ref);

/* Renders the camera's image: 3 channels, linear radiance, `spp` in [1, PEN_REFERENCE_MAX_SPP]
 * samples per pixel. *out is allocated here (pen_image_free releases it); zeroed on failure. */
PEN_API pen_status pen_reference_render(pen_context *ctx, const pen_reference *ref, int spp,
                                        uint64_t seed, pen_image *out);
/* The same image (bit for bit), and, when `coverage` is not NULL, a 1-channel image of the
 * fraction of each pixel's camera samples that hit a surface (mesh or ground): 0 where the pixel
 * shows only background. Thresholded at 0.5 it is a mask for pen_image_compare that leaves out
 * the background, whose box-filtered texture detail no rasterizer sampling at pixel centres
 * reproduces. */
PEN_API pen_status pen_reference_render_coverage(pen_context *ctx, const pen_reference *ref,
                                                 int spp, uint64_t seed, pen_image *out,
                                                 pen_image *coverage);

/* Irradiance E = integral L(w) V(x, w) max(n . w, 0) dw at the surface point x with unit normal
 * n (rays leave from x nudged along n), estimated with `samples` sample pairs. */
PEN_API pen_status pen_reference_irradiance(pen_context *ctx, const pen_reference *ref,
                                            const float x[3], const float n[3], int samples,
                                            uint64_t seed, float E[3]);

/* "envmap", "sh" or "auto" to the enum; -1 for anything else. */
PEN_API int pen_reference_lighting_parse(const char *name);
PEN_API const char *pen_reference_lighting_name(pen_reference_lighting lighting);

#ifdef __cplusplus
}
#endif
#endif
