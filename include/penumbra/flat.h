/* penumbra/flat.h -- the differentiable renderer over plain arrays and flat structs, for callers
 * through a foreign-function interface (the Python binding in python/penumbra uses ctypes).
 *
 * Every struct here holds only ints, floats, fixed float arrays and pointers, so that a binding
 * can mirror it field by field; pen_scene (scene.h) is richer and owns its arrays, this one
 * borrows them. A pen_flat_scene describes the same scene as pen_scene: pen_flat_render_fwd
 * builds a pen_scene that points into the caller's arrays and runs pen_render_fwd on it, so the
 * image is the one `penumbra render` makes of the equivalent scene JSON, bit for bit. The modes
 * have the JSON's defaults and the scene enums' values (scene.h): a zeroed field is the JSON's
 * default, so self_shadow 0 is PEN_SELF_TRANSFER ("transfer"), texture_filter 0 is
 * PEN_TEXTURE_FILTER_FOOTPRINT ("footprint"). Under "transfer" the backward refuses the pose,
 * vertex, sphere and disk-light gradients, naming the group (pen_render_grad_check): a pose or
 * shape optimiser asks for the sphere model first (pen_flat_grad_model, the rule `penumbra
 * optimize` follows).
 *
 * Usage (one object, one step: the gradients of the lighting and the pose):
 *
 *     // given: ctx
 *     static const float xyz[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};     // a tetrahedron
 *     static const uint32_t tri[] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};  // its 4 faces
 *     static const float xyzr[] = {0.25f, 0.25f, 0.25f, 0.3f};             // its one sphere
 *     float sh[16 * 3] = {1, 1, 1};                      // 4 bands; a uniform sky, RGB 1
 *     pen_flat_object ob = {0};
 *     ob.vertex_count = 4; ob.triangle_count = 4; ob.positions = xyz; ob.indices = tri;
 *     ob.albedo[0] = ob.albedo[1] = ob.albedo[2] = 0.7f;
 *     ob.sphere_count = 1; ob.spheres = xyzr;
 *     ob.pose[6] = 1.0f;                                 // scale 1, no rotation or translation
 *     pen_flat_scene sc = pen_flat_scene_default();      // fills camera, ground, options
 *     sc.width = 64; sc.height = 64; sc.sh_bands = 4; sc.sh = sh;
 *     sc.object_count = 1; sc.objects = &ob;
 *     pen_flat_grad_model(&sc, &ob, PEN_GRAD_POSE);      // self_shadow 1: a pose gradient
 *     pen_render_state *st = NULL;
 *     pen_render_state_create(ctx, &st);
 *     static float image[3 * 64 * 64], d_image[3 * 64 * 64];
 *     pen_flat_render_fwd(ctx, &sc, st, image);
 *     for (int i = 0; i < 3 * 64 * 64; ++i)              // loss = sum (image - 0.5)^2 / 2
 *         d_image[i] = image[i] - 0.5f;
 *     float d_sh[16 * 3] = {0}, d_pose[7] = {0};
 *     pen_flat_object_grad og = {0};                     // NULL fields are not computed
 *     og.pose = d_pose;
 *     pen_flat_grad g = {0};
 *     g.sh = d_sh; g.objects = &og;
 *     pen_flat_render_bwd(ctx, &sc, st, d_image, &g);    // d_sh, d_pose += dloss/dsh, dloss/dpose
 *     pen_render_state_free(st);
 *
 * For many steps, a pen_flat_renderer (below) keeps the state and the calls' scratch between
 * them; pen_flat_abi reports the structs' layout so that a binding can check its mirror of them.
 *
 * Layouts: images and textures are rows top to bottom, 3 interleaved linear RGB floats per pixel
 * (as pen_image); SH lighting is sh[3 i + channel] for coefficient i < sh_bands^2 (index
 * l*l + l + m); spheres are x, y, z, r per sphere (object space); triangles index vertices with
 * three uint32 each; a pose is 7 floats: rotation axis * angle in degrees (3), translation (3),
 * uniform scale (p_world = R (scale p) + t, as pen_pose).
 */
#ifndef PENUMBRA_FLAT_H
#define PENUMBRA_FLAT_H

#include "penumbra/core.h"
#include "penumbra/render.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* One object; every array is borrowed for the call. */
typedef struct pen_flat_object {
    int vertex_count;
    int triangle_count;
    const float *positions;     /* 3 * vertex_count, object space */
    const uint32_t *indices;    /* 3 * triangle_count, into positions, counter-clockwise outside */
    int uv_count;               /* 0: no texture coordinates */
    const float *uvs;           /* 2 * uv_count, (u, v) with v up */
    const uint32_t *uv_indices; /* 3 * triangle_count into uvs; NULL: `indices` (one uv per
                                   vertex, uv_count must then equal vertex_count) */
    int texture_width;          /* 0: constant albedo */
    int texture_height;
    const float *texture; /* 3 * width * height, linear RGB, row 0 at the top (v = 1) */
    float albedo[3];      /* used when there is no texture */
    int sphere_count;
    const float *spheres;        /* 4 * sphere_count: x, y, z, r (object space) */
    float pose[7];               /* rotation axis-angle (degrees), translation, scale (> 0) */
    const float *sphere_weights; /* sphere_count overlap weights (>= 0), or NULL: computed from
                                    the spheres by the renderer (pen_spheres_overlap_weights) at
                                    every forward; give them to hold them fixed while the
                                    spheres change (they are constants of the gradient) */
    int texture_filter;          /* pen_texture_filter: 0 (default) averaged over the pixel's
                                    footprint, 1 one bilinear lookup at the pixel's uv */
} pen_flat_object;

/* A scene; the arrays are borrowed for the call. */
typedef struct pen_flat_scene {
    int width, height; /* camera: pinhole, row 0 at the top */
    float fov_y_deg;
    float eye[3], target[3], up[3];
    float fx, fy, cx, cy; /* calibrated intrinsics in pixels (pen_camera); all 0: fov_y_deg */
    int sh_bands;    /* 1 .. PEN_SH_MAX_BANDS */
    const float *sh; /* 3 * sh_bands^2: sh[3 i + channel] */
    float epsilon;   /* log-visibility depth; <= 0: the exponential model's */
    int exp_method;  /* pen_sh_exp_method */
    int ground_enabled;
    float ground_height;
    float ground_albedo[3];
    float ground_half_size;
    int background_envmap; /* 1: pixels that see nothing show the environment map */
    float background[3];   /* the constant background otherwise */
    int envmap_width;      /* 0: no map */
    int envmap_height;
    const float *envmap; /* 3 * width * height, equirectangular (scene.h), linear RGB */
    float envmap_rotation_y_deg;
    float envmap_scale;
    int shadows; /* pen_render_options.shadows */
    int antialias;
    int object_count;
    const pen_flat_object *objects;
    int overlap; /* pen_shadow_overlap: 0 overlap weights, 1 none (the plain sum) */
    int ground_occlusion; /* pen_shadow_ground: 0 the ground hides the objects' lower horizon
                             (the default), 1 it only receives shadows */
    int light_count;      /* disk lights (scene.h pen_light), 0 .. PEN_SCENE_MAX_LIGHTS */
    const float *lights;  /* PEN_LIGHT_FLOATS (scene.h) * light_count: direction towards the
                             light (3, any non-zero length: normalised by the renderer),
                             angular radius in degrees, irradiance (3) */
    int self_shadow;      /* pen_shadow_self: 0 (default) the objects' own shadows from their
                             meshes' precomputed transfer, ray traced and cached (exact; the
                             backward then refuses gradients of the positions, pose, spheres and
                             lights, which do not see it); 1 from their spheres (every gradient) */
    int ground_shadow;    /* with self_shadow 0, the ground's shadows of those objects:
                             pen_shadow_ground_shadow (0 from their meshes at a grid of nodes,
                             the default; 1 from their spheres) */
    int ground_grid;      /* that grid's nodes per side: 0 (the default, 96) or
                             PEN_GROUND_GRID_MIN .. PEN_GROUND_GRID_MAX */
} pen_flat_scene;

/* A 64 x 64 camera at (0, 1, 3) looking at (0, 0.5, 0) with 40 degrees vertical field of view,
 * sh_bands 4 and no lighting array, no disk lights, the calibrated exponential with its own
 * epsilon, overlap weights on, the default ground (height 0, albedo 0.8, half size 4, occluding
 * the objects), black background, no map, shadows and antialiasing on, the scene JSON's model
 * (own and ground shadows from the transfer), no objects. */
PEN_API pen_flat_scene pen_flat_scene_default(void);

/* Where pen_flat_render_bwd writes; every pointer may be NULL (that gradient is not computed).
 * The backward ADDS into the arrays. */
typedef struct pen_flat_object_grad {
    float *positions; /* 3 * vertex_count */
    float *texture;   /* 3 * texture_width * texture_height */
    float *albedo;    /* 3 */
    float *spheres;   /* 4 * sphere_count */
    float *pose;      /* 7: per degree of the rotation vector, translation, scale */
} pen_flat_object_grad;

typedef struct pen_flat_grad {
    float *sh;                     /* 3 * sh_bands^2 */
    float *ground_albedo;          /* 3 */
    pen_flat_object_grad *objects; /* object_count entries, or NULL for none */
    float *lights;                 /* PEN_LIGHT_FLOATS * light_count, laid out as
                                      pen_flat_scene.lights (the direction's gradient is that
                                      of the unnormalised vector) */
} pen_flat_grad;

/* Renders into `image` (3 * width * height floats, caller-owned). `state` may be NULL when no
 * backward follows. Fails (PEN_ERROR_ARGUMENT, the message naming the field) on missing arrays,
 * bad counts or sizes, and on whatever pen_render_fwd refuses. */
PEN_API pen_status pen_flat_render_fwd(pen_context *ctx, const pen_flat_scene *scene,
                                       pen_render_state *state, float *image);

/* Backward of the last pen_flat_render_fwd with this state, whose scene (arrays included) must
 * be unchanged: adds dLoss/dparameter into the non-NULL arrays of `grad`, given d_image
 * (3 * width * height). The groups computed follow from which pointers are set (lighting:
 * sh; albedo: texture, albedo, ground_albedo; spheres; pose; vertices: positions; lights). */
PEN_API pen_status pen_flat_render_bwd(pen_context *ctx, const pen_flat_scene *scene,
                                       pen_render_state *state, const float *d_image,
                                       const pen_flat_grad *grad);

/* The gradient groups (PEN_GRAD_*) a pen_flat_grad with these pointers set asks for. */
PEN_API unsigned pen_flat_grad_groups(const pen_flat_scene *scene, const pen_flat_grad *grad);

/* pen_render_grad_check of the scene the flat description makes: PEN_OK when every group of wrt
 * is exact for its model, else the one-line refusal naming the group (the binding calls it
 * before a forward whose inputs will want gradients, so the error comes at once). */
PEN_API pen_status pen_flat_grad_check(pen_context *ctx, const pen_flat_scene *scene,
                                       unsigned wrt);

/* pen_render_grad_model on the flat description: sets scene->self_shadow and ->ground_shadow,
 * and the texture_filter of each of scene->object_count entries of `objects` (the array the
 * scene points to, passed writable; NULL leaves the filters alone), to the model in which the
 * groups of wrt are exact. Returns the groups that needed a change. */
PEN_API unsigned pen_flat_grad_model(pen_flat_scene *scene, pen_flat_object *objects,
                                     unsigned wrt);

/* ---- A renderer kept across calls ------------------------------------------------------------ */

/* A pen_render_state together with what a flat call otherwise allocates anew (the pen_scene
 * view's object array, the gradient the backward fills before adding it into pen_flat_grad),
 * kept from one call to the next. The renderer's caches then survive between optimisation steps:
 * the per-pixel buffers, the mesh adjacency, the environment-map background and overlap weights
 * computed from unchanged spheres. Images and gradients are those of pen_flat_render_fwd / _bwd
 * with a fresh state, bit for bit. One call at a time per renderer (it is not locked). */
typedef struct pen_flat_renderer pen_flat_renderer;

/* On failure *out is NULL. */
PEN_API pen_status pen_flat_renderer_create(pen_context *ctx, pen_flat_renderer **out);
/* NULL is a no-op. */
PEN_API void pen_flat_renderer_free(pen_flat_renderer *renderer);
/* pen_flat_render_fwd with the renderer's state. */
PEN_API pen_status pen_flat_renderer_fwd(pen_context *ctx, pen_flat_renderer *renderer,
                                         const pen_flat_scene *scene, float *image);
/* pen_flat_render_bwd of the renderer's last forward, whose scene must be unchanged. */
PEN_API pen_status pen_flat_renderer_bwd(pen_context *ctx, pen_flat_renderer *renderer,
                                         const pen_flat_scene *scene, const float *d_image,
                                         const pen_flat_grad *grad);
/* The renderer's state (owned by it), e.g. for pen_render_state_timings. */
PEN_API pen_render_state *pen_flat_renderer_state(pen_flat_renderer *renderer);

/* ---- Layout check ---------------------------------------------------------------------------- */

/* Raised whenever a row of pen_flat_abi's table changes (a field added, moved or resized). */
#define PEN_FLAT_ABI_VERSION 4

/* One row of the layout table. */
typedef struct pen_flat_abi_field {
    const char *type;  /* the struct's name: "pen_flat_scene", ... */
    const char *field; /* a member's name; NULL in the row that gives the struct's own size */
    size_t offset;     /* offsetof (0 in the size row) */
    size_t size;       /* sizeof the member (of the struct in the size row) */
} pen_flat_abi_field;

/* The layout, as compiled into the library, of every struct a binding mirrors: pen_flat_object,
 * pen_flat_scene, pen_flat_object_grad, pen_flat_grad, and the loaders' pen_image, pen_mesh and
 * pen_spheres. *fields points to *count static rows: per struct, its size row, then one row per
 * member in declaration order. Returns PEN_FLAT_ABI_VERSION. A binding compares the table with
 * its own mirror once, when it loads the library, and refuses a library that differs. */
PEN_API int pen_flat_abi(const pen_flat_abi_field **fields, int *count);

/* ---- Scenes from JSON ------------------------------------------------------------------------ */

/* A scene JSON loaded and seen as a pen_flat_scene (which points into the loaded arrays). */
typedef struct pen_flat_loaded pen_flat_loaded;

/* Loads a scene JSON (pen_scene_load) and makes it ready as `penumbra render` does
 * (pen_scene_prepare): with fit_spheres != 0, objects whose spheres are {"fit": N} get them
 * (cached in the user's cache folder); with 0 they are left without spheres (render them without
 * shadows). Every key of the file is kept: the model (shadow.self, ground_shadow, ground_grid,
 * each object's texture_filter), the lights given or found in the map. On failure *out is NULL. */
PEN_API pen_status pen_flat_scene_load(pen_context *ctx, const char *path, int fit_spheres,
                                       pen_flat_loaded **out);
/* The flat view; valid until pen_flat_loaded_free. Its objects' uv_indices are always set. */
PEN_API const pen_flat_scene *pen_flat_loaded_scene(const pen_flat_loaded *loaded);
/* The "fit" request of object o ({"fit": N} gives N, 0 otherwise; -1 if o is out of range). */
PEN_API int pen_flat_loaded_fit_request(const pen_flat_loaded *loaded, int o);
/* NULL is a no-op. */
PEN_API void pen_flat_loaded_free(pen_flat_loaded *loaded);

#ifdef __cplusplus
}
#endif
#endif
