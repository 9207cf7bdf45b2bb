/* Internal interface of src/render, the frame: the render state (state.c), texture lookups over
 * a pixel's footprint (footprint.c), the traced transfers and their values at a pixel (self.c,
 * ground_shadow.c), the background (background.c), ground occlusion (ground.c) and the passes
 * (forward.c, backward.c), which shade through a backend (backend.h; the CPU backend's own
 * interface is cpu/cpu.h). The state holds the kernels' parameter types (src/shade/shade.h), but
 * no file here outside a backend calls a kernel (docs/design.md sec. 6.4). A file only calls
 * files listed before it, never back. Scenes are validated by the model layer
 * (src/scene/validate.c) before a forward touches them. */
#ifndef PEN_RENDER_INTERNAL_H
#define PEN_RENDER_INTERNAL_H

#include "penumbra/envmap.h" /* the background along camera rays */
#include "penumbra/fit.h"    /* overlap weights, computed when a sphere set has none */
#include "penumbra/image.h"
#include "penumbra/sh.h"
#include "scene/texture.h" /* the albedo lookup shading uses */
#include "shade/shade.h"   /* the kernels: the state keeps their parameters */

/* ---- Frame: what the files of the full frame share --------------------------------------------
 * Who calls whom: forward.c calls state.c, footprint.c, background.c, ground.c, self.c,
 * ground_shadow.c and the backend's table; backward.c calls state.c, footprint.c and the
 * backend's table; self.c and ground_shadow.c call state.c and transfer_pool.c (and
 * src/geometry's transfer); background.c and footprint.c call state.c; state.c calls
 * transfer_pool.c; ground.c and transfer_pool.c call no other file of the frame. The CPU backend (cpu/) calls these files, never forward.c or backward.c. */
#include "geometry/lattice.h" /* the self transfer's nodes */
#include "penumbra/render.h" /* the state's options, view, G-buffer and timings */

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h> /* free, in PEN__BUF_FREE */

/* Screen tiles: the unit of parallel work and of the fast kernel's calls (its batches are the
 * tile's shaded pixels), and of the backward's double accumulators. */
#define PEN_TILE 16
#define PEN_TILE_PX (PEN_TILE * PEN_TILE)

/* Frames smaller than this are shaded on the calling thread: waking a team costs more than a few
 * thousand pixels take, and optimisers render many small frames. */
#define PEN_RENDER_PARALLEL_MIN_PIXELS 4096

/* A growable array of T (klib's kvec habit): data holds cap elements. Growing does not keep the
 * contents (every buffer of the state is rewritten by the pass that reserves it, or is a cache
 * that says whether it is valid). Free with PEN__BUF_FREE. */
#define PEN__BUF(T)                                                                                \
    struct {                                                                                       \
        T *data;                                                                                   \
        size_t cap;                                                                                \
    }
/* data itself when cap already holds count elements of `size` bytes; else data is freed and a new
 * block returned (NULL without memory, cap 0, error recorded with `what`). Use through
 * PEN__BUF_RESERVE. */
void *pen__buf_grow(pen_context *ctx, void *data, size_t *cap, size_t count, size_t size,
                    const char *what);
/* Makes buffer b (an lvalue, evaluated more than once) hold count elements; a pen_status. */
#define PEN__BUF_RESERVE(ctx, b, count, what)                                                      \
    (((b).data = pen__buf_grow((ctx), (b).data, &(b).cap, (count), sizeof *(b).data, (what)))      \
         ? PEN_OK                                                                                  \
         : PEN_ERROR_MEMORY)
#define PEN__BUF_FREE(b) (free((b).data), (b).data = NULL, (b).cap = 0)

typedef PEN__BUF(float) pen__buf_float;

/* A tile's shaded pixels by lighting group (pen__tile_group): indices in raster order within each
 * group, groups ascending, in runs of one group each, run r being pix[end[r - 1]] ..
 * pix[end[r] - 1] (end[-1] = 0). Made once per forward; its shading and the backward read it. */
typedef struct pen__tile_groups {
    int runs;
    int pix[PEN_TILE_PX], end[PEN_TILE_PX];
    size_t store; /* floats of the fast kernel's store for these runs */
} pen__tile_groups;

/* What an environment-map background depends on: the camera, the map (its pixels by a hash)
 * and its rotation and scale. */
typedef struct pen__bg_key {
    pen_camera camera;
    const float *data;
    int width, height, channels;
    float rotation_y_deg, scale;
    uint64_t hash;
} pen__bg_key;

/* One object's posed geometry and its gradient buffers. */
typedef struct pen__object_buf {
    pen__buf_float world, vnormal, d_world, d_vnormal; /* 3 per vertex (+ 1) */
    PEN__BUF(int32_t) adjacency;                       /* 3 per triangle (+ 1) */
    /* Ground occlusion (pen__ground_occlusion_prepare): the lighting the object's surfaces see,
     * seen = M sh, M = pen__sh_above(t) (symmetric), and d seen / d h for the backward. */
    double horizon[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS];
    float seen[PEN_SH_MAX_COEFFS][3];
    double d_seen_dh[PEN_SH_MAX_COEFFS][3];
    /* ... and the fraction of each disk light above its horizon (pen__lights_horizon), with its
     * derivatives by the object's height, the light's unit direction and its radius. */
    double light_G[PEN_SCENE_MAX_LIGHTS], light_G_dh[PEN_SCENE_MAX_LIGHTS];
    double ground_t, ground_dt_dh; /* the horizon y > -t, and dt / dh (ground.c) */
    double light_G_dw[PEN_SCENE_MAX_LIGHTS][3], light_G_db[PEN_SCENE_MAX_LIGHTS];
    /* What adjacency was built from (the topology, which optimisers do not change): sorting
     * the half-edges every frame cost about 0.5 ms at the headline. */
    int adj_valid, adj_vertices, adj_triangles;
    uint64_t adj_hash;
    /* Self-shadowing by the precomputed transfer (self.c): whether this frame shades the object
     * with it, whether any other object has spheres, and the per-node cache (bands^2
     * coefficients of the blocked part of the clamped cosine and one unblocked disk fraction per
     * light) with the key it was built from. */
    int self_on, self_others;
    /* The trace is a shared blob (transfer_pool.h): this state's reference, and views of its
     * arrays and lattice, read only (states of a pool read the same memory, never a copy). */
    struct pen__transfer_blob *self_blob;
    pen__buf_float self_B, self_frac; /* per node of self_lat; not owned: self_blob's */
    pen__lattice self_lat;            /* the nodes (vertices, refined on coarse meshes): a view */
    int self_valid;
    uint64_t self_key;
} pen__object_buf;

/* The ground's shadows of the objects shaded with their transfer (ground_shadow.c): the grid
 * of nodes on the ground square and its cache. */
typedef struct pen__ground_grid {
    int on;     /* this frame: ground pixels shade with the grid */
    int others; /* some object without the transfer has spheres (kappa not all 0) */
    int n;      /* nodes per side */
    double c[2], a[2], beta[2][2]; /* x = c + a sinh(beta[side] s) per axis (x, z), side s < 0,
                                      s >= 0 */
    /* The trace, a shared blob (transfer_pool.h) like a self transfer: this state's reference;
     * B (bands^2 per node, row z, column x) and frac (one per light per node) are its arrays. */
    struct pen__transfer_blob *blob;
    const float *B, *frac;
    pen__buf_float kappa;       /* per sphere: kappa, 0 on the transferred objects' spheres */
    int valid;
    uint64_t key;
    /* The disk lights' fractions per pixel where the grid cannot be trusted (one per light per
     * pixel, negative: the grid's), for this camera: keyed by the grid's key and the frame's
     * pixels_key (the view and the geometry that make the ground pixels' points). */
    pen__buf_float pfrac;
    int pvalid;
    uint64_t pkey;
} pen__ground_grid;

/* Traced transfers shared between render states (transfer_pool.c, pen_render_state_share): the
 * self transfers and ground grids of the most recent traces, found by their caches' keys. */
typedef struct pen__transfer_pool pen__transfer_pool;
enum { PEN__POOL_SELF = 1, PEN__POOL_GRID = 2 };
pen_status pen__pool_create(pen_context *ctx, pen__transfer_pool **out);
void pen__pool_retain(pen__transfer_pool *p);
void pen__pool_release(pen__transfer_pool *p); /* frees it with its last reference; NULL: no-op */
/* The miss path of a cache (look up, trace, put) runs between lock and unlock, so that states
 * rendering at once trace each key once; NULL: no-op. */
void pen__pool_lock(pen__transfer_pool *p);
void pen__pool_unlock(pen__transfer_pool *p);
/* Traces put over the pool's life. */
long pen__pool_traces(const pen__transfer_pool *p);

struct pen_render_state {
    int valid;              /* a forward has filled the buffers */
    unsigned vouched;       /* PEN__VOUCH_* of the forward under way (pen__render_fwd_vouched) */
    pen__transfer_pool *pool; /* shared traces (pen_render_state_share), or NULL */
    pen_render_options opt; /* the forward's options */
    int width, height;
    pen_view view;
    pen_gbuffer gb;
    const struct pen__backend *backend; /* the forward's (backend.h) */
    pen__shade_params params; /* the kernels' parameters (the backend's prepare) */
    pen__lights lights; /* the frame's disk lights (the backend's prepare: src/shade/lights.c) */
    int object_count, object_cap; /* obj, meshes: object_cap each; sphere_first: object_cap + 1 */
    pen__object_buf *obj;
    pen_raster_mesh *meshes;
    int sphere_count;
    pen__buf_float spheres; /* world space, all objects */
    int *sphere_first;      /* object o owns spheres [first[o], first[o+1]) */
    pen__buf_float kappa;   /* overlap weight per world-space sphere (all 1 with overlap "none") */
    pen__buf_float kappa_key;  /* per sphere (4 floats): the object-space set kappa was computed
                                * from, NaN where it was not computed (weights given, or "none") */
    PEN__BUF(int) kappa_first; /* the object -> sphere offsets the keys were laid out with */
    /* Per pixel, 3 floats each (uv, d_uv and d_bary use 2, nsign 1). */
    pen__buf_float x, nraw, n, rho, uv, color, nsign;
    pen__buf_float d_color, d_x, d_nraw, d_uv, d_rho, d_bary;
    pen__buf_float d_border; /* d image through the ground border's blend (pen__ground_border_bwd) */
    pen__buf_float uvj; /* per textured pixel, 4 floats: J = d(uv)/d(pixel x, y) of its triangle
                         * at the pixel centre, the texture's footprint (texture.h) */
    pen__buf_float d_uvj; /* its gradient (4 floats per pixel) */
    pen__buf_float bary_scratch; /* pen_raster_bary_bwd_scratch's 9 floats per pixel */
    PEN__BUF(int) tx_span, tx_cut; /* the texel scatter's bands (backward.c) */
    PEN__BUF(size_t) tile_off;   /* the fast store's layout per tile (pen__tile_store_layout) */
    PEN__BUF(pen__tile_groups) groups; /* per tile, of the last forward */
    pen__buf_float fv; /* scalar kernel: F and V per pixel (2 bands^2); fast: its store, per tile */
    int fv_valid;      /* the forward kept fv (only with shadows on: without, nothing is kept) */
    pen__buf_float lights_V; /* the disk lights' visibilities, lights.count per pixel */
    int lights_V_valid;      /* the forward kept lights_V (a state, shadows on, lights) */
    int fast;          /* the forward used the fast kernel */
    PEN__BUF(double) rows;      /* the backward's double accumulators, one block per tile */
    PEN__BUF(size_t) row_off;   /* where each tile's block begins (cpu/shade_bwd.c) */
    PEN__BUF(unsigned char) ws; /* per-thread workspaces (pen__tile_ws) */
    pen__buf_float bg;          /* environment-map background of the last frame, 3 per pixel */
    int bg_use;         /* this frame: 0 none, 2 read bg (filled by pen__background_prepare) */
    pen__bg_key bg_key; /* what bg was computed from (bg_valid) */
    int bg_valid;
    pen_render_timings timings;
    int ground_occludes; /* shadow.ground "occludes", shadows on, a ground: see ground.c */
    int self_any;             /* some object shades with its transfer this frame (self.c) */
    pen__buf_float kappa_self; /* per object (sphere_count each): kappa, 0 on its own spheres */
    pen__ground_grid grid;     /* the ground's shadows of those objects (ground_shadow.c) */
    /* What every pixel's surface, point and normal depend on, and the disk lights' directions
     * and radii: the view, the posed meshes, the ground (self.c, pixels_key; made by
     * pen__self_prepare). The per-pixel traces' keys start from it, so that a frame finds them
     * valid without a pass over its pixels. */
    uint64_t pixels_key;
    /* The transfer pixels' own disk fractions (K per pixel, -1: the nodes' interpolation),
     * traced where the nodes cannot be trusted (self.c, pixel_trace); kept between frames while
     * self_pkey (pixels_key, which holds the objects' transfer keys) holds, so the backward
     * reads the forward's values and a lighting or albedo optimisation traces them once. */
    pen__buf_float self_pfrac;
    int self_pvalid;
    uint64_t self_pkey;
};

/* ---- state.c ---- */

/* Milliseconds since the omp_get_wtime() t0. */
double pen__render_ms_since(double t0);

/* A 64-bit hash of n 32-bit words, for caches keyed by large arrays that may be edited in place. */
uint64_t pen__render_hash32(const void *data, size_t n);
/* Sizes the per-pixel buffers for n pixels and the per-object arrays for `objects` objects. */
pen_status pen__render_state_reserve(pen_context *ctx, pen_render_state *st, size_t n, int objects);
/* Bytes per pixel a frame allocates (state.c's pixel buffers, G-buffer, output image), with the
 * store the backward reads when `store` (its scalar-kernel size, the larger). */
size_t pen__render_pixel_bytes(int bands, int store);

/* What a caller of pen__render_fwd_vouched has established about its scene: that it passed
 * pen__scene_validate since it last changed (the camera is still checked), and that the
 * environment map's pixels are those of the state's previous forward (its hash is not taken
 * again). The optimiser renders every view of a pass from one scene: it validates it once per
 * pass, and never edits the map; per view, the scan of a 1024^2 texture for non-finite texels and
 * the map's hash took a third of a 1000-view task's time (bench/NOTES.md). */
enum { PEN__VOUCH_VALID = 1u, PEN__VOUCH_MAP = 2u };
pen_status pen__render_fwd_vouched(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_options *opt, pen_render_state *state,
                                   pen_image *image, unsigned vouched);
/* Sizes one object's buffers for V vertices and T triangles. */
pen_status pen__render_object_reserve(pen_context *ctx, pen__object_buf *b, size_t V, size_t T);
/* b->adjacency for the mesh, rebuilt only when its topology changed. */
pen_status pen__render_object_adjacency(pen_context *ctx, pen__object_buf *b, const pen_mesh *mesh);
/* st->kappa for the scene's spheres (st->sphere_first laid out): given, 1, or computed from the
 * spheres and kept with them. */
pen_status pen__render_overlap_weights(pen_context *ctx, const pen_scene *sc, pen_render_state *st);

/* ---- footprint.c ---- */

/* st->uvj at every pixel of object o (textured): J = d(uv)/d(pixel x, y) of the pixel's triangle
 * at the pixel centre, from the posed vertices and the view. */
void pen__uv_footprint_fwd(pen_render_state *st, const pen_object *ob, int o, int threads);
/* Its backward: adds the gradient of st->d_uvj (4 per pixel) at object o's pixels into d_world
 * (3 per posed vertex). */
void pen__uv_footprint_bwd(const pen_render_state *st, const pen_object *ob, int o,
                           float *d_world);
/* Whether ob's texture is looked up over the pixel's footprint: its texture_filter. */
static inline int pen__render_footprint(const pen_object *ob) {
    return ob->texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT;
}
/* The albedo of textured pixel i of ob by its texture_filter (point, or over st->uvj), and its
 * backward into d_texels, d_uv, d_J (each may be NULL; d_J is left alone by point lookups). */
void pen__render_texture_fwd(const pen_render_state *st, const pen_object *ob, size_t i,
                             float rho[3]);
void pen__render_texture_bwd(const pen_render_state *st, const pen_object *ob, size_t i,
                             const float d_rho[3], float *d_texels, float d_uv[2], float d_J[4]);

/* ---- self.c ---- */

/* Whether object o of sc shades its own shadows with its transfer under opt: shadows on, the
 * scene's shadow.self "transfer", a mesh with triangles and spheres. The one rule for the
 * forward (pen__self_prepare) and for which gradients are exact (pen_render_grad_exact). */
static inline int pen__self_transfer_on(const pen_scene *sc, const pen_render_options *opt,
                                        int o) {
    const pen_object *ob = &sc->objects[o];
    return opt->shadows && sc->shadow.self == PEN_SELF_TRANSFER && ob->mesh.triangle_count > 0 &&
           ob->spheres.count > 0;
}
/* Decides which objects shade with their own transfer this frame (pen__self_transfer_on)
 * and brings their caches up to date (ray traced only when the posed vertices, the band count or
 * the lights changed). After the lights and ground occlusion are prepared. */
pen_status pen__self_prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                             pen_render_state *st);
/* The object whose transfer shades surface pixel i, or -1 (the pixel's shading is the kernel's):
 * needs self_on and the normal facing the side the transfer was traced for (nsign > 0). */
static inline int pen__self_object(const pen_render_state *st, size_t i);
/* What a backend shades transfer pixel i (of object o = pen__self_object) with: B, the blocked
 * part of the clamped cosine (bands^2 floats), and frac, the unblocked fraction of each disk light
 * (lights.count doubles), interpolated on the node lattice at the pixel's barycentrics. */
void pen__self_transfer_at(const pen_render_state *st, int o, size_t i, float *B, double *frac);

/* ---- ground_shadow.c ---- */

/* Decides whether the ground's pixels shade with the grid this frame (a ground, shadow.
 * ground_shadow "transfer", some object with its transfer on: after pen__self_prepare) and brings
 * the grid's cache up to date (traced only when its key changed). */
pen_status pen__ground_shadow_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st);
/* Whether pixel i is shaded by the grid (a ground pixel of a frame with it on). */
static inline int pen__ground_shadow_pixel(const pen_render_state *st, size_t i) {
    return st->grid.on && st->gb.surface[i] == PEN_SURFACE_GROUND;
}
/* The same as pen__self_transfer_at for ground pixel i (pen__ground_shadow_pixel): bilinear in
 * the grid, the light fractions the pixel's own where they were traced per pixel. */
void pen__ground_grid_at(const pen_render_state *st, size_t i, float *B, double *frac);

/* ---- background.c ---- */

/* Decides st->bg_use for this frame and fills the environment-map cache when it is stale; never
 * fails the render (without memory for the cache the background is computed per pixel). */
void pen__background_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st);
/* Background pixel i at (px, py) into st->color, through the cache when there is one. */
void pen__background_pixel(const pen_scene *sc, const pen_render_state *st, int px, int py,
                           size_t i);

/* ---- ground.c ---- */

/* Sets st->ground_occludes and, when set, each object's `seen` lighting and its derivative, and
 * its horizon t with dt/dh, from which the backend's prepare makes the disk lights' factors. */
void pen__ground_occlusion_prepare(const pen_scene *sc, const pen_render_options *opt,
                                   pen_render_state *st);
/* Backward of the objects' `seen` lightings, d_seen: per object, 3 bands^2 doubles. Adds
 * M^T d_seen into d_sh (double, may be NULL) and, when grad is not NULL, the objects' height
 * gradients into their pose translation[1]. Only with st->ground_occludes. */
void pen__ground_occlusion_bwd(const pen_scene *sc, const pen_render_state *st,
                               const double *d_seen, double (*d_sh)[3], pen_render_grad *grad);
/* Backward of the objects' horizon factors, d_G: per object, one double per light. Adds into
 * d_lights (PEN_LIGHT_GRAD_DOUBLES per light, may be NULL) and, when grad is not NULL, the
 * objects' height gradients into their pose translation[1]. Only with st->ground_occludes. */
void pen__ground_lights_bwd(const pen_scene *sc, const pen_render_state *st, const double *d_G,
                            double *d_lights, pen_render_grad *grad);

static inline int pen__self_object(const pen_render_state *st, size_t i) {
    const int o = st->gb.surface[i];
    return st->self_any && o >= 0 && st->obj[o].self_on && st->nsign.data[i] > 0.0f ? o : -1;
}

#endif
