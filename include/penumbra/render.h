/* penumbra/render.h -- the differentiable soft-shadow renderer: forward image, image losses, and
 * the backward pass into every scene parameter.
 *
 * Usage (an object's position recovered from an image by gradient descent, from a scene JSON):
 *
 *     // given: ctx, scene_path, target (an image of the scene camera's size)
 *     pen_scene scene;
 *     pen_scene_load(ctx, scene_path, &scene);          // io.h
 *     pen_scene_prepare(ctx, &scene, 1, NULL);          // fits {"fit": N} spheres (fit.h)
 *     pen_render_grad_model(&scene, PEN_GRAD_POSE);     // the model whose pose gradient is exact
 *     pen_render_options opt = pen_render_options_default();
 *     pen_render_state *st = NULL;
 *     pen_render_state_create(ctx, &st);
 *     pen_render_grad grad;
 *     pen_render_grad_create(ctx, &scene, &grad);
 *     pen_image img = {0}, d_img = {0};                 // allocated by their first use
 *     double loss = 0;
 *     for (int step = 0; step < 50; ++step) {
 *         pen_render_fwd(ctx, &scene, &opt, st, &img);
 *         pen_loss_l2(ctx, &img, &target, &loss, &d_img);   // sets (not adds) d_img
 *         pen_render_grad_zero(&grad);                      // the backward adds into grad
 *         pen_render_bwd(ctx, &scene, &opt, st, &d_img, PEN_GRAD_POSE, &grad);
 *         for (int k = 0; k < 3; ++k)                       // a step against the gradient
 *             scene.objects[0].pose.translation[k] -= 0.3f * grad.objects[0].pose.translation[k];
 *     }
 *     pen_image_free(&img);
 *     pen_image_free(&d_img);
 *     pen_render_grad_free(&grad);
 *     pen_render_state_free(st);
 *     pen_scene_free(&scene);
 *
 * The step 0.3 suits this loss's scale, not every scene's; pen_optim_run (optim.h) moves every
 * group with Adam instead.
 *
 * The model (docs/design.md sec. 1.15): a scene's objects shade their own shadows, and their
 * shadows on the ground, with the ray-traced transfer of their meshes by default ("shadow":
 * {"self": "transfer"}), which is exact but traced once per pose and so has no gradient in the
 * pose, the vertices, the spheres or the lights' directions. Every gradient pen_render_bwd returns
 * is exact for the model the forward rendered, or it fails naming the group and the setting that
 * gives it (pen_render_grad_check); pen_render_grad_model switches a scene to the model in which
 * the groups asked for are exact (the rule `penumbra optimize` follows).
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
typedef enum pen_render_kernel {
    PEN_RENDER_KERNEL_FAST = 0,
    PEN_RENDER_KERNEL_SCALAR = 1
} pen_render_kernel;

/* The memory a frame may need (16 GiB). pen_render_fwd computes it from the camera size before
 * allocating (about 190 bytes per pixel, plus 8 bands^2 with a state for the backward and shadows
 * on: 256 at 4 bands, so about 8192 x 8192 at most) and refuses a larger camera with an error
 * naming the size and the bytes. */
#define PEN_RENDER_MAX_BYTES 17179869184.0

/* How to render; what is rendered (the model: which shadows come from the transfer or the
 * spheres, how textures are looked up) is the scene's own (pen_shadow, pen_object.texture_filter),
 * the same in the JSON, the C structs, the flat API and Python. */
typedef struct pen_render_options {
    int shadows;     /* 1: shadows (SH visibility, disk-light visibility); 0: V == 1
                        (`--no-shadows`) */
    int antialias;   /* 1: analytic silhouette antialiasing (needed for silhouette gradients) */
    pen_render_kernel kernel;
} pen_render_options;

/* shadows = 1, antialias = 1, kernel = PEN_RENDER_KERNEL_FAST: what `penumbra render` does. */
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
#define PEN_GRAD_LIGHT_IRRADIANCE 64u /* disk lights' irradiance alone (part of PEN_GRAD_LIGHTS;
                                         exact under the transfer too, where the direction and
                                         radius are not) */
#define PEN_GRAD_ALL 127u

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

/* ---- The model a gradient needs --------------------------------------------------------------- */

/* The gradient groups (PEN_GRAD_*) that are exact for the model `scene` renders with `opt` (NULL:
 * the defaults). With shadows on and "shadow": {"self": "transfer"} (PEN_SELF_TRANSFER, the
 * default), the objects' own shadows and their shadows on the ground are ray traced from their
 * meshes, once per pose, lights and shape: constant to the renderer's backward, so the groups
 * that move them (PEN_GRAD_POSE, PEN_GRAD_VERTICES, PEN_GRAD_SPHERES, PEN_GRAD_LIGHTS) are not
 * exact and are left out; lighting, albedo and the lights' irradiance alone
 * (PEN_GRAD_LIGHT_IRRADIANCE) always are. Under "self": "spheres" every group is.
 * (Texture lookups over the pixel's footprint have gradients in the geometry too, exact between
 * the steps where a facet edge crosses a pixel centre, as any rasterizer's are between edges.) */
PEN_API unsigned pen_render_grad_exact(const pen_scene *scene, const pen_render_options *opt);

/* PEN_OK when every group of `wrt` is exact for the model (pen_render_grad_exact); otherwise
 * PEN_ERROR_ARGUMENT with one line naming the first group that is not, the model and the setting
 * that gives it, e.g. 'render backward: no pose gradient under "shadow": {"self": "transfer"}
 * (...); use "self": "spheres" (pen_render_grad_model)'. pen_render_bwd runs it first. */
PEN_API pen_status pen_render_grad_check(pen_context *ctx, const pen_scene *scene,
                                         const pen_render_options *opt, unsigned wrt);

/* Switches `scene` to the model a task moving the groups of `wrt` renders with, the rule
 * `penumbra optimize` follows: for pose, vertices, spheres or lights, the objects' own shadows and
 * their ground shadows from the spheres (shadow.self = PEN_SELF_SPHERES, shadow.ground_shadow =
 * PEN_GROUND_SHADOW_SPHERES), which makes those gradients exact; for pose or vertices also point
 * texture lookups (texture_filter = PEN_TEXTURE_FILTER_POINT), continuous in the geometry where
 * the footprint filter steps between facets (docs/design.md sec. 1.4). Lighting and albedo keep
 * the scene's model. Returns the groups of wrt that needed a change. */
PEN_API unsigned pen_render_grad_model(pen_scene *scene, unsigned wrt);

/* ---- Forward and backward -------------------------------------------------------------------- */

/* Buffers kept between a forward and its backward, reused across frames of the same size. */
typedef struct pen_render_state pen_render_state;

PEN_API pen_status pen_render_state_create(pen_context *ctx, pen_render_state **out);
PEN_API void pen_render_state_free(pen_render_state *state);
/* About the bytes a render state holds once it has rendered sc with `threads` threads, forward
 * and, when wrt (PEN_GRAD_*) is not 0, backward for those groups: its pixel, per-object and
 * per-thread buffers, not the traces it shares nor sc itself. For sizing many states (the views
 * of a task) before making them; from the sizes alone (bench/NOTES.md, "Memory before a task",
 * has it against the resident memory). */
PEN_API double pen_render_state_bytes(const pen_scene *sc, unsigned wrt, int threads);

/* Lets `state` share the ray-traced transfers of `with` (and of every state `with` shares with):
 * the objects' self transfers and the ground's grid (docs/design.md sec. 1.15) are in world space,
 * so states rendering the same objects from several cameras (the views of a task, a batch) trace
 * them once per pose instead of once per state. Images and gradients are bitwise those without
 * sharing. States that share may render at once on different threads: a trace is made once and
 * the others wait for it. The most recent 16 traces are kept, freed with the last state. */
PEN_API pen_status pen_render_state_share(pen_context *ctx, pen_render_state *state,
                                          pen_render_state *with);

/* Renders the scene into `image`: if image->data is NULL it is allocated (3 channels, camera
 * size), otherwise it must already have that shape. `state` may be NULL when no backward
 * follows. Fails on an invalid camera, mesh, sphere set or lighting (NaN/Inf, bad indices), and,
 * with shadows on, on an object without spheres (it would cast no shadow: fit them with
 * pen_scene_prepare, fit.h, or give them). Threads: pen_context_threads. */
PEN_API pen_status pen_render_fwd(pen_context *ctx, const pen_scene *scene,
                                  const pen_render_options *opt, pen_render_state *state,
                                  pen_image *image);

/* Backward of the last pen_render_fwd with this state: adds the gradient of the loss into
 * `grad` for the groups in `wrt` (PEN_GRAD_*), given d_image (3 channels, image size). `opt`
 * must equal the forward's (NULL: the defaults); the scene must be the forward's, unchanged.
 * Fails, computing nothing, when a group of wrt is not exact for the model the forward rendered
 * (pen_render_grad_check): ask for PEN_GRAD_ALL & pen_render_grad_exact(scene, opt) to take
 * whatever the model gives. */
PEN_API pen_status pen_render_bwd(pen_context *ctx, const pen_scene *scene,
                                  const pen_render_options *opt, pen_render_state *state,
                                  const pen_image *d_image, unsigned wrt, pen_render_grad *grad);

/* What a user makes targets and loss weights from, beside the image: the last pen_render_fwd of
 * this state as images of the camera's size, each sampled at the pixel centres (the G-buffer's
 * visible surface, not antialiased). mask (1 channel): 1 where an object is visible, 0 for the
 * ground and the background; depth (1 channel): the view depth of the visible point (objects and
 * ground; the distance along the camera's forward axis), 0 for the background; normals (3
 * channels): the unit world-space normal of the visible surface, turned towards the camera (the
 * ground's is +Y), 0 for the background. Each may be NULL; an image whose data is NULL is
 * allocated, otherwise it must have that shape. Fails before any forward with this state. */
PEN_API pen_status pen_render_state_aovs(pen_context *ctx, const pen_render_state *state,
                                         pen_image *mask, pen_image *depth, pen_image *normals);

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
 * d_image (may be NULL; allocated if its data is NULL) is set to dLoss/dimage (overwritten, not
 * added to, so that a loop reusing it needs no zeroing). Shapes must match. */
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
