/* penumbra/render.h -- the differentiable soft-shadow renderer: forward image, image losses, and
 * the backward pass into every scene parameter.
 *
 * Usage (one optimisation step):
 *
 *     pen_render_options opt = pen_render_options_default();
 *     pen_render_state *st = NULL;   pen_render_state_create(ctx, &st);
 *     pen_render_grad grad;          pen_render_grad_create(ctx, &scene, &grad);
 *     pen_image img = {0}, d_img = {0};
 *     pen_render_fwd(ctx, &scene, &opt, st, &img);             allocates img on first use
 *     pen_image_create(ctx, img.width, img.height, 3, &d_img);
 *     double loss; pen_loss_l2(ctx, &img, &target, &loss, &d_img);
 *     pen_render_grad_zero(&grad);
 *     pen_render_bwd(ctx, &scene, &opt, st, &d_img, PEN_GRAD_ALL, &grad);
 *     ... update scene parameters from grad, repeat ...
 *
 * What is rendered (docs/renderer.md): per pixel, the visible surface point x of an object or the
 * ground plane, its unit normal n and albedo rho; the visibility V = exp*(sum_i w_i f_i) over all
 * spheres of all objects (posed), with the self-shadowing weight w_i (smoothstep of
 * n . (c_i - x) / r_i from -1 to +1); the radiance rho / pi * sum_k L_k (V * H_n)_k, plus for
 * each disk light l (lighting.lights) rho / pi * E_l * D(n . w_l, b_l) * V_l(x), D the disk's
 * horizon-clipped clamped cosine and V_l the fraction of the disk the spheres leave visible
 * (docs/design.md sec. 1.13). Background
 * pixels show the constant background or the environment map in the ray direction. Silhouettes
 * are antialiased analytically (pen_antialias_fwd) so that the image is continuous in the vertex
 * positions. The image is linear RGB, 3 channels, the camera's size, row 0 at the top.
 *
 * Gradients: of a scalar loss, given d_image = dLoss/dimage; the backward ADDS into the gradient
 * struct. Object-space quantities (vertices, sphere centres and radii) get object-space
 * gradients; the pose gets gradients per field of pen_pose (rotation per degree). Determinism:
 * every reduction runs in a fixed order (per-tile buffers in double, summed in tile order), so
 * results do not depend on the thread count.
 *
 * The scene must not change between pen_render_fwd and the matching pen_render_bwd (the state
 * keeps the G-buffer and per-pixel attributes of the forward).
 */
#ifndef PENUMBRA_RENDER_H
#define PENUMBRA_RENDER_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/raster.h"
#include "penumbra/scene.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Options --------------------------------------------------------------------------------- */

/* Shading kernels (pen_render_options.kernel). FAST processes the pixels of a screen tile in
 * batches of SIMD lanes (16 floats with AVX-512) with SH code generated per band count; it covers
 * bands 3..6, with shadows the calibrated and paper exponentials, without shadows every method
 * (no exponential is taken), and falls back to SCALAR otherwise. SCALAR is the per-pixel
 * reference kernel. Both compute in float and agree to float rounding. */
#define PEN_RENDER_KERNEL_FAST 0
#define PEN_RENDER_KERNEL_SCALAR 1

/* The memory a frame may need (16 GiB). pen_render_fwd computes it from the camera size before
 * allocating (about 190 bytes per pixel, plus 8 bands^2 with a state for the backward and shadows
 * on: 256 at 4 bands, so about 8192 x 8192 at most) and refuses a larger camera with an error
 * naming the size and the bytes. */
#define PEN_RENDER_MAX_BYTES 17179869184.0

/* What shadows an object's own surface (pen_render_options.self_shadow). SCENE follows the scene's
 * "shadow": {"self": ...} (default: the precomputed transfer of the object's own mesh, exact
 * self-visibility but constant in pose, shape, spheres and light directions); SPHERES forces the
 * object's own spheres whatever the scene says, as an optimiser of pose, deformation, spheres or
 * light directions needs (docs/design.md sec. 1.15); it also turns off the ground's shadows from
 * the transfer ("ground_shadow"), so the ground is shadowed by the spheres too. */
#define PEN_RENDER_SELF_SCENE 0
#define PEN_RENDER_SELF_SPHERES 1

/* How albedo textures are looked up (pen_render_options.texture_filter). SCENE follows each
 * object's "texture_filter" (default: box-filtered over the pixel's footprint, docs/design.md
 * sec. 1.4, whose per-triangle footprint steps where a facet edge crosses a pixel centre); POINT
 * forces one bilinear lookup at the pixel's UV, continuous in the geometry, as an optimiser of
 * pose or deformation wants. */
#define PEN_RENDER_TEXTURE_SCENE 0
#define PEN_RENDER_TEXTURE_POINT 1

typedef struct pen_render_options {
    int shadows;     /* 1: SH visibility from the sphere sets; 0: V == 1 (`--no-shadows`) */
    int antialias;   /* 1: analytic silhouette antialiasing (needed for silhouette gradients) */
    int kernel;      /* PEN_RENDER_KERNEL_* */
    int self_shadow; /* PEN_RENDER_SELF_* */
    int texture_filter; /* PEN_RENDER_TEXTURE_* */
} pen_render_options;

/* shadows = 1, antialias = 1, kernel = PEN_RENDER_KERNEL_FAST, self_shadow = SCENE,
 * texture_filter = SCENE. */
PEN_API pen_render_options pen_render_options_default(void);

/* How many pixels the fast kernel in use shades per SIMD batch (16 with AVX-512). Its per-batch
 * sums run in lane order, so fast-kernel results are bitwise reproducible between machines that
 * report the same count. */
PEN_API int pen_render_fast_lanes(void);

/* ---- Gradients ------------------------------------------------------------------------------- */

/* What pen_render_bwd computes (bit mask). Skipping unwanted groups saves time; the fields of
 * groups not asked for are left untouched. */
#define PEN_GRAD_LIGHTING 1u  /* sh */
#define PEN_GRAD_ALBEDO 2u    /* constant albedo, texture texels, ground albedo */
#define PEN_GRAD_SPHERES 4u   /* sphere centres and radii (object space) */
#define PEN_GRAD_POSE 8u      /* rigid pose of each object (moves vertices and spheres) */
#define PEN_GRAD_VERTICES 16u /* vertex positions (object space), incl. silhouettes */
#define PEN_GRAD_LIGHTS 32u   /* disk lights: direction, angular radius, irradiance */
#define PEN_GRAD_ALL 63u

typedef struct pen_object_grad {
    float albedo[3]; /* d constant albedo (objects without a texture) */
    float *texture;  /* 3 per texel, the texture's layout; NULL if the object has none */
    int texel_count;
    float *spheres; /* 4 per sphere: d center (x, y, z), d radius; object space */
    int sphere_count;
    pen_pose_grad pose; /* d rotation_axis_angle_deg (per degree), d translation, d scale */
    float *positions;   /* 3 per vertex, object space */
    int vertex_count;
} pen_object_grad;

/* Gradient of a disk light: the fields of pen_light holding d/d(field). `direction` is the
 * gradient of the vector as stored (the renderer normalises it, so it is orthogonal to a unit
 * direction); angular_radius_deg per degree. */
typedef pen_light pen_light_grad;

typedef struct pen_render_grad {
    int bands;
    float sh[PEN_SH_MAX_COEFFS][3]; /* d lighting coefficient [i][channel] */
    float ground_albedo[3];
    int object_count;
    pen_object_grad *objects;
    int light_count;                             /* the scene's lighting.light_count */
    pen_light_grad lights[PEN_SCENE_MAX_LIGHTS]; /* d lighting.lights[l] */
} pen_render_grad;

/* Allocates a zeroed gradient shaped like the scene. On failure *out is zeroed. */
PEN_API pen_status pen_render_grad_create(pen_context *ctx, const pen_scene *scene,
                                          pen_render_grad *out);
/* Sets every gradient to 0. */
PEN_API void pen_render_grad_zero(pen_render_grad *grad);
/* Frees the arrays and zeroes the struct; NULL is a no-op. */
PEN_API void pen_render_grad_free(pen_render_grad *grad);

/* ---- Forward and backward -------------------------------------------------------------------- */

/* Buffers kept between a forward and its backward, reused across frames of the same size. */
typedef struct pen_render_state pen_render_state;

PEN_API pen_status pen_render_state_create(pen_context *ctx, pen_render_state **out);
PEN_API void pen_render_state_free(pen_render_state *state);

/* Renders the scene into `image`: if image->data is NULL it is allocated (3 channels, camera
 * size), otherwise it must already have that shape. `state` may be NULL when no backward
 * follows. Fails on an invalid camera, mesh, sphere set or lighting (NaN/Inf, bad indices), or a
 * scene whose objects need a sphere set they do not have while shadows are on. Threads:
 * pen_context_threads. */
PEN_API pen_status pen_render_fwd(pen_context *ctx, const pen_scene *scene,
                                  const pen_render_options *opt, pen_render_state *state,
                                  pen_image *image);

/* Backward of the last pen_render_fwd with this state: adds the gradient of the loss into
 * `grad` for the groups in `wrt` (PEN_GRAD_*), given d_image (3 channels, image size). `opt`
 * must equal the forward's (NULL: the defaults); the scene must be the forward's, unchanged. */
PEN_API pen_status pen_render_bwd(pen_context *ctx, const pen_scene *scene,
                                  const pen_render_options *opt, pen_render_state *state,
                                  const pen_image *d_image, unsigned wrt, pen_render_grad *grad);

/* ---- Timings ------------------------------------------------------------------------------- */

/* Wall-clock milliseconds of the last pen_render_fwd / pen_render_bwd with a state, by stage
 * (what `penumbra bench` reports). Stages that run inside the parallel pixel loop (visibility,
 * exp, shading) are measured per thread and reported as their share of the loop's wall time, so
 * the stages of one pass add up to about its total. A stage the pass did not split out is 0 and
 * its time is in the enclosing one (`*_shade_ms`). */
typedef struct pen_render_timings {
    double fwd_prepare_ms;    /* posing, rasterization, attribute interpolation */
    double fwd_shade_ms;      /* the whole per-pixel loop */
    double fwd_visibility_ms; /* of which: per-sphere log-visibility sums */
    double fwd_exp_ms;        /* of which: the SH exponential */
    double fwd_antialias_ms;  /* silhouette antialiasing */
    double bwd_antialias_ms;
    double bwd_shade_ms;      /* the whole per-pixel backward loop */
    double bwd_visibility_ms; /* of which: log-visibility backward */
    double bwd_exp_ms;        /* of which: the exponential's backward */
    double bwd_scatter_ms;    /* reductions, texels, interpolation, normals, pose (serial) */
} pen_render_timings;

/* The stage times of the state's last forward and backward (zeros before any). */
PEN_API void pen_render_state_timings(const pen_render_state *state, pen_render_timings *out);

/* ---- Image losses ---------------------------------------------------------------------------- */

/* Mean squared error over all pixels and channels, loss = (1/N) sum (image - target)^2;
 * d_image (may be NULL; allocated if its data is NULL) += dLoss/dimage. Shapes must match. */
PEN_API pen_status pen_loss_l2(pen_context *ctx, const pen_image *image, const pen_image *target,
                               double *loss, pen_image *d_image);
/* Mean absolute error, loss = (1/N) sum |image - target|; the gradient is sign(image - target)/N
 * (0 where equal). */
PEN_API pen_status pen_loss_l1(pen_context *ctx, const pen_image *image, const pen_image *target,
                               double *loss, pen_image *d_image);

#ifdef __cplusplus
}
#endif
#endif
