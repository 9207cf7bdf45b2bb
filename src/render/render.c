/* The full differentiable frame: scene -> posed geometry -> G-buffer -> per-pixel attributes ->
 * shading with SH visibility -> silhouette antialiasing, and its backward into lighting, albedo,
 * spheres, poses and vertex positions.
 *
 * Design
 * - Forward. Vertices and sphere centres are posed (pen_pose_points_fwd; radii times the pose's
 *   scale). The rasterizer gives per pixel the surface, triangle and barycentrics; the visible
 *   point x, the raw normal (interpolated area-weighted vertex normals, computed from the posed
 *   positions so that they move with the vertices) and the UV are interpolated; n = +/- raw/|raw|
 *   with the sign chosen so that n faces the camera's side of the triangle's geometric normal
 *   (closed meshes seen from outside never flip; open meshes seen from behind do). Ground pixels:
 *   x on the plane, n = +Y, the ground albedo. Shading runs over 16 x 16 tiles in parallel
 *   (dynamic scheduling, a workspace per thread): the tile's surface pixels go compacted to the
 *   fast kernel (shade_fast.c, batches of SIMD lanes) or one by one to the scalar reference
 *   kernel (shade_ops.inc), as pen_render_options.kernel and the kernel's coverage decide;
 *   background pixels show the constant background or the environment map in the ray direction
 *   (pen_envmap_eval: the full-resolution map, not its SH projection, and not differentiated;
 *   kept between frames, see background_prepare). Antialiasing blends colours across
 *   silhouettes last.
 * - What the state keeps. The G-buffer and per-pixel x, raw normal, n, rho, uv and the
 *   pre-antialiasing colour, each tile's shaded pixels in lighting groups (tile_group: one
 *   parallel pass before the shading, read again by the backward), and the kernel's store: F
 *   per pixel (fast kernel, in its batch layout per tile) or F and V per pixel (scalar kernel).
 *   The per-sphere terms are recomputed in the backward (cheaper than storing bands^2 x spheres
 *   floats per pixel).
 * - Backward. Antialiasing backward gives d_colour (and silhouette vertex gradients); a parallel
 *   pass over tiles runs the kernel's backward, writing per-pixel d_x, d_raw-normal, d_uv, d_rho,
 *   and per-tile double buffers for the small dense gradients (lighting, constant albedos,
 *   ground albedo, world-space spheres). Tiles are reduced in order, so the result does not
 *   depend on the thread count. Then the texel scatter (in pixel order) beside the per-object
 *   interpolation and vertex-normal backward (two threads, disjoint outputs), the barycentric
 *   backward (the pixel's point slides on its ray as the triangle moves), and the pose backward,
 *   which splits world-space gradients of vertices and spheres into object-space and pose parts.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "render/render_internal.h"
#include "sh/sh_internal.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Frames smaller than this are shaded on the calling thread: waking a team costs more than a few
 * thousand pixels take, and optimisers render many small frames. */
#define PARALLEL_MIN_PIXELS 4096

/* Screen tiles: the unit of parallel work and of the fast kernel's calls (its batches are the
 * tile's shaded pixels), and of the backward's double accumulators. */
#define TILE 16
#define TILE_PX (TILE * TILE)

/* A tile's shaded pixels by lighting group (tile_group): indices in raster order within each
 * group, groups ascending, in runs of one group each, run r being pix[end[r - 1]] ..
 * pix[end[r] - 1] (end[-1] = 0). Made once per forward; its shading and the backward read it. */
typedef struct tile_groups {
    int runs;
    int pix[TILE_PX], end[TILE_PX];
    size_t store; /* floats of the fast kernel's store for these runs */
} tile_groups;

/* ---- State ----------------------------------------------------------------------------------- */

/* What an environment-map background depends on: the camera, the map (its pixels by a hash)
 * and its rotation and scale. */
typedef struct bg_key {
    pen_camera camera;
    const float *data;
    int width, height, channels;
    float rotation_y_deg, scale;
    uint64_t hash;
} bg_key;

typedef struct object_buf {
    float *world, *vnormal, *d_world, *d_vnormal; /* 3 per vertex */
    int32_t *adjacency;                           /* 3 per triangle */
    size_t cap_v, cap_t;
    /* Ground occlusion (ground_occlusion_prepare): the lighting the object's surfaces see,
     * seen = M sh, M = pen__sh_above(t) (symmetric), and d seen / d h for the backward. */
    double horizon[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS];
    float seen[PEN_SH_MAX_COEFFS][3];
    double d_seen_dh[PEN_SH_MAX_COEFFS][3];
    /* What adjacency was built from (the topology, which optimisers do not change): sorting
     * the half-edges every frame cost about 0.5 ms at the headline. */
    int adj_valid, adj_vertices, adj_triangles;
    uint64_t adj_hash;
} object_buf;

struct pen_render_state {
    int valid;              /* a forward has filled the buffers */
    pen_render_options opt; /* the forward's options */
    int width, height;
    pen_view view;
    pen_gbuffer gb;
    pen__shade_params params;
    int object_count, object_cap;
    object_buf *obj;
    pen_raster_mesh *meshes;
    int sphere_count;
    size_t sphere_cap;
    float *spheres;    /* world space, all objects */
    int *sphere_first; /* object o owns spheres [first[o], first[o+1]) */
    float *kappa;      /* overlap weight per world-space sphere (all 1 with overlap "none") */
    size_t kappa_cap;
    float *kappa_key;  /* per sphere (4 floats): the object-space set kappa was computed from,
                        * NaN where it was not computed (weights given, or overlap "none") */
    size_t kappa_key_cap;
    int *kappa_first; /* the object -> sphere offsets the keys were laid out with */
    size_t kappa_first_cap;
    size_t pixel_cap;
    float *x, *nraw, *n, *rho, *uv, *color, *nsign;
    float *d_color, *d_x, *d_nraw, *d_uv, *d_rho, *d_bary;
    float *bary_scratch; /* pen_raster_bary_bwd_scratch's 9 floats per pixel, kept between frames */
    size_t *tile_off;    /* the fast store's layout per tile (tile_store_layout) */
    size_t tile_off_cap;
    tile_groups *groups; /* per tile, of the last forward */
    size_t groups_cap;
    size_t bary_cap;
    size_t fv_cap, rows_cap, ws_cap;
    float *fv; /* scalar kernel: F and V per pixel (2 bands^2); fast: its store, per tile */
    int fv_valid;    /* the forward kept fv (only with shadows on: without, nothing is kept) */
    int fast;        /* the forward used the fast kernel */
    double *rows;    /* the backward's double accumulators, one block per tile */
    unsigned char *ws; /* per-thread workspaces (tile_ws) */
    float *bg;         /* environment-map background of the last frame, 3 per pixel */
    size_t bg_cap;
    int bg_use;        /* this frame: 0 none, 2 read bg (filled by background_prepare) */
    bg_key bg_key;     /* what bg was computed from (bg_valid) */
    int bg_valid;
    pen_render_timings timings;
    int ground_occludes; /* shadow.ground "occludes", shadows on, a ground: see below */
};

void pen_render_state_timings(const pen_render_state *st, pen_render_timings *out) {
    memset(out, 0, sizeof *out);
    if (st) *out = st->timings;
}

static double ms_since(double t0) {
    return 1e3 * (omp_get_wtime() - t0);
}

pen_status pen_render_state_create(pen_context *ctx, pen_render_state **out) {
    *out = pen__calloc(ctx, 1, sizeof **out, "render state");
    return *out ? PEN_OK : PEN_ERROR_MEMORY;
}

void pen_render_state_free(pen_render_state *st) {
    if (!st) return;
    pen_gbuffer_free(&st->gb);
    for (int o = 0; o < st->object_cap; ++o) {
        object_buf *b = &st->obj[o];
        free(b->world), free(b->vnormal), free(b->d_world), free(b->d_vnormal), free(b->adjacency);
    }
    free(st->obj), free(st->meshes), free(st->spheres), free(st->sphere_first), free(st->kappa);
    free(st->kappa_key), free(st->kappa_first);
    float *px[] = {st->x,       st->nraw, st->n,      st->rho,  st->uv,    st->color, st->nsign,
                   st->d_color, st->d_x,  st->d_nraw, st->d_uv, st->d_rho, st->d_bary};
    for (size_t i = 0; i < sizeof px / sizeof px[0]; ++i)
        free(px[i]);
    free(st->fv), free(st->rows), free(st->ws), free(st->bg), free(st->bary_scratch);
    free(st->tile_off), free(st->groups);
    free(st);
}

/* Grows *p to hold count elements of `size` bytes (contents are not kept). */
static pen_status ensure(pen_context *ctx, void **p, size_t *cap, size_t count, size_t size,
                         const char *what) {
    if (*p && *cap >= count) return PEN_OK;
    free(*p);
    *p = pen__malloc(ctx, count ? count : 1, size, what);
    *cap = *p ? count : 0;
    return *p ? PEN_OK : PEN_ERROR_MEMORY;
}

/* Sizes one object's buffers for V vertices and T triangles. */
static pen_status ensure_object(pen_context *ctx, object_buf *b, size_t V, size_t T) {
    if (b->world && b->cap_v >= V && b->cap_t >= T) return PEN_OK;
    free(b->world), free(b->vnormal), free(b->d_world), free(b->d_vnormal), free(b->adjacency);
    b->adj_valid = 0;
    b->world = pen__malloc(ctx, 3 * V + 1, sizeof(float), "posed vertices");
    b->vnormal = pen__malloc(ctx, 3 * V + 1, sizeof(float), "vertex normals");
    b->d_world = pen__malloc(ctx, 3 * V + 1, sizeof(float), "vertex gradient");
    b->d_vnormal = pen__malloc(ctx, 3 * V + 1, sizeof(float), "normal gradient");
    b->adjacency = pen__malloc(ctx, 3 * T + 1, sizeof(int32_t), "adjacency");
    int ok = b->world && b->vnormal && b->d_world && b->d_vnormal && b->adjacency;
    b->cap_v = ok ? V : 0;
    b->cap_t = ok ? T : 0;
    return ok ? PEN_OK : PEN_ERROR_MEMORY;
}

/* A 64-bit hash of n 32-bit words (8 interleaved multiplicative lanes, vectorised): for caches
 * keyed by large arrays that may be edited in place (the envmap's pixels, a mesh's indices). */
static uint64_t hash32(const void *data, size_t n) {
    const unsigned char *b = data;
    uint64_t h[8] = {1, 2, 3, 4, 5, 6, 7, 8};
    size_t i = 0;
    for (; i + 16 <= n; i += 16)
        for (int l = 0; l < 8; ++l) {
            uint64_t w;
            memcpy(&w, b + 4 * (i + 2 * (size_t)l), sizeof w);
            h[l] = (h[l] ^ w) * 0x9E3779B97F4A7C15ull;
        }
    uint64_t r = (uint64_t)n;
    for (; i < n; ++i) {
        uint32_t w;
        memcpy(&w, b + 4 * i, sizeof w);
        r = (r ^ w) * 0x100000001B3ull;
    }
    for (int l = 0; l < 8; ++l)
        r = (r ^ h[l] ^ (h[l] >> 29)) * 0x9E3779B97F4A7C15ull;
    return r;
}

static pen_status ensure_objects(pen_context *ctx, pen_render_state *st, int count) {
    if (count < 1) count = 1; /* sphere_first always has an entry */
    if (count <= st->object_cap) return PEN_OK;
    object_buf *obj = pen__calloc(ctx, (size_t)count, sizeof *obj, "render objects");
    pen_raster_mesh *meshes = pen__calloc(ctx, (size_t)count, sizeof *meshes, "render meshes");
    int *first = pen__calloc(ctx, (size_t)count + 1, sizeof *first, "render sphere offsets");
    if (!obj || !meshes || !first) {
        free(obj), free(meshes), free(first);
        return PEN_ERROR_MEMORY;
    }
    if (st->object_cap) memcpy(obj, st->obj, sizeof *obj * (size_t)st->object_cap);
    free(st->obj), free(st->meshes), free(st->sphere_first);
    st->obj = obj, st->meshes = meshes, st->sphere_first = first;
    st->object_cap = count;
    return PEN_OK;
}

static pen_status ensure_pixels(pen_context *ctx, pen_render_state *st, size_t n) {
    if (st->pixel_cap >= n) return PEN_OK;
    float **px[] = {&st->x,     &st->nraw,  &st->n,       &st->rho, &st->uv,
                    &st->color, &st->nsign, &st->d_color, &st->d_x, &st->d_nraw,
                    &st->d_uv,  &st->d_rho, &st->d_bary};
    /* 3 floats per pixel is enough for every buffer (uv and d_bary use 2, nsign 1). */
    for (size_t i = 0; i < sizeof px / sizeof px[0]; ++i) {
        free(*px[i]);
        *px[i] = pen__malloc(ctx, n, 3 * sizeof(float), "render pixel buffer");
        if (!*px[i]) {
            st->pixel_cap = 0;
            return PEN_ERROR_MEMORY;
        }
    }
    st->pixel_cap = n;
    return PEN_OK;
}

/* ---- Tiles ------------------------------------------------------------------------------------ */

/* A thread's workspace for one tile: the tile's shaded pixels compacted (pixel index, x, n, rho,
 * the kernel's output or d_colour, and the backward's per-pixel results), and the fast kernel's
 * scratch. Allocated once per state and reused, so the pixel loops do not allocate. */
typedef struct tile_ws {
    int *idx;
    float *x, *n, *rho, *out, *dx, *dn, *drho; /* 3 floats per compacted pixel */
    void *kernel;
} tile_ws;

static size_t tile_ws_bytes(const pen__shade_params *p, int spheres) {
    const size_t b = sizeof(int) * TILE_PX + 7 * 3 * sizeof(float) * TILE_PX +
                     pen__shade_fast_scratch_bytes(p, spheres, TILE_PX);
    return (b + 127) & ~(size_t)127; /* threads' blocks on separate cache lines */
}

static pen_status ensure_ws(pen_context *ctx, pen_render_state *st, int threads, size_t *bytes) {
    *bytes = tile_ws_bytes(&st->params, st->sphere_count);
    return ensure(ctx, (void **)&st->ws, &st->ws_cap, *bytes * (size_t)threads, 1,
                  "render workspaces");
}

static tile_ws tile_ws_at(pen_render_state *st, size_t bytes) {
    const int tid = omp_get_thread_num();
    unsigned char *b = st->ws + bytes * (size_t)tid;
    tile_ws w;
    w.idx = (int *)b;
    float *f = (float *)(b + sizeof(int) * TILE_PX);
    w.x = f, w.n = f + 3 * TILE_PX, w.rho = f + 6 * TILE_PX, w.out = f + 9 * TILE_PX;
    w.dx = f + 12 * TILE_PX, w.dn = f + 15 * TILE_PX, w.drho = f + 18 * TILE_PX;
    w.kernel = f + 21 * TILE_PX;
    return w;
}

/* Appends surface pixel i (index, x, n, rho) as the j-th compacted pixel. */
static void ws_push(tile_ws *ws, int j, const pen_render_state *st, size_t i) {
    ws->idx[j] = (int)i;
    memcpy(ws->x + 3 * j, st->x + 3 * i, 3 * sizeof(float));
    memcpy(ws->n + 3 * j, st->n + 3 * i, 3 * sizeof(float));
    memcpy(ws->rho + 3 * j, st->rho + 3 * i, 3 * sizeof(float));
}

/* Pixel rectangle [x0, x1) x [y0, y1) of tile t. */
static void tile_rect(const pen_render_state *st, int t, int *x0, int *y0, int *x1, int *y1) {
    const int tiles_x = (st->width + TILE - 1) / TILE;
    *x0 = (t % tiles_x) * TILE, *y0 = (t / tiles_x) * TILE;
    *x1 = *x0 + TILE < st->width ? *x0 + TILE : st->width;
    *y1 = *y0 + TILE < st->height ? *y0 + TILE : st->height;
}

static int tile_count(const pen_render_state *st) {
    return ((st->width + TILE - 1) / TILE) * ((st->height + TILE - 1) / TILE);
}

/* Per-thread stage ticks of a pixel loop, summed over threads. */
typedef struct loop_ticks {
    unsigned long long visibility, exp, total;
} loop_ticks;

static void loop_ticks_add(loop_ticks *sum, const pen__shade_fast_ticks *tk,
                           unsigned long long total) {
#pragma omp critical(pen_render_ticks)
    {
        sum->visibility += tk->visibility;
        sum->exp += tk->exp;
        sum->total += total;
    }
}

/* Runs fn on every tile, threads over tiles with dynamic scheduling (small frames on the calling
 * thread), each thread with its own workspace; returns the threads' summed stage ticks. */
typedef void (*tile_fn)(const void *job, int t, tile_ws *ws, pen__shade_fast_ticks *tk);

static loop_ticks run_tiles(pen_render_state *st, int threads, size_t ws_bytes, tile_fn fn,
                            const void *job) {
    loop_ticks lt = {0, 0, 0};
    const int ntiles = tile_count(st);
#pragma omp parallel num_threads(threads) if (st->width * st->height >= PARALLEL_MIN_PIXELS)
    {
        tile_ws ws = tile_ws_at(st, ws_bytes);
        pen__shade_fast_ticks tk = {0, 0};
        const unsigned long long start = pen__shade_fast_now();
#pragma omp for schedule(dynamic, 1) nowait
        for (int t = 0; t < ntiles; ++t)
            fn(job, t, &ws, &tk);
        loop_ticks_add(&lt, &tk, pen__shade_fast_now() - start);
    }
    return lt;
}

/* A stage's share of a loop's wall time. */
static double stage_ms(double loop_ms, unsigned long long stage, unsigned long long total) {
    return total ? loop_ms * (double)stage / (double)total : 0.0;
}

/* ---- Validation ------------------------------------------------------------------------------ */

/* Whether all n floats are finite. Textures make this a per-frame scan of millions of values, so
 * it tests the exponent bits without branches (the compiler vectorises it) in blocks. */
static int finite_n(const float *v, size_t n) {
    for (size_t i = 0; i < n; i += 4096) {
        const size_t end = n - i < 4096 ? n : i + 4096;
        uint32_t bad = 0;
        for (size_t j = i; j < end; ++j) {
            uint32_t bits;
            memcpy(&bits, v + j, sizeof bits);
            bad |= (bits & 0x7f800000u) == 0x7f800000u; /* Inf or NaN */
        }
        if (bad) return 0;
    }
    return 1;
}

static const char *object_name(const pen_object *ob) {
    return ob->mesh_path ? ob->mesh_path : "in memory";
}

static pen_status validate(pen_context *ctx, const pen_scene *sc) {
    if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: sh_bands %d out of range [1, %d]",
                          sc->sh_bands, PEN_SH_MAX_BANDS);
    const int nc = sc->sh_bands * sc->sh_bands;
    if (!finite_n(&sc->lighting.sh[0][0], 3 * (size_t)nc))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: lighting: non-finite SH coefficient");
    if (sc->shadow.exp != PEN_SH_EXP_CALIBRATED && sc->shadow.exp != PEN_SH_EXP_PAPER &&
        sc->shadow.exp != PEN_SH_EXP_EXACT)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: shadow.exp: unknown method %d",
                          (int)sc->shadow.exp);
    if (sc->shadow.overlap != PEN_OVERLAP_WEIGHTS && sc->shadow.overlap != PEN_OVERLAP_NONE)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: shadow.overlap: unknown mode %d",
                          (int)sc->shadow.overlap);
    if (sc->object_count < 0 || (sc->object_count > 0 && !sc->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: bad object list");
    if (!finite_n(sc->background, 3) ||
        (sc->ground.enabled && (!finite_n(sc->ground.albedo, 3) || !isfinite(sc->ground.height) ||
                                !isfinite(sc->ground.half_size))))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: non-finite background or ground");
    if (sc->background_envmap && (!sc->lighting.envmap.data || !isfinite(sc->lighting.scale) ||
                                  !isfinite(sc->lighting.rotation_y_deg)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render: the background shows the environment map, but there is none");
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const char *name = object_name(ob);
        pen_status s = pen_mesh_validate(ctx, &ob->mesh);
        if (s) {
            char msg[sizeof((pen_context *)0)->message];
            snprintf(msg, sizeof msg, "%s", pen_context_error(ctx));
            return pen__error(ctx, s, "render: objects[%d] (%s): %s", o, name, msg);
        }
        if (ob->texture.data) {
            if (ob->texture.width < 1 || ob->texture.height < 1 || ob->texture.channels < 3)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): texture must be RGB", o, name);
            if (ob->mesh.uv_count <= 0)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): texture but no texture coordinates", o,
                                  name);
            if (!finite_n(ob->texture.data, (size_t)ob->texture.width * (size_t)ob->texture.height *
                                                (size_t)ob->texture.channels))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): non-finite texel", o, name);
        } else if (!finite_n(ob->albedo, 3)) {
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: objects[%d] (%s): bad albedo", o,
                              name);
        }
        const pen_pose *ps = &ob->pose;
        if (!finite_n(ps->rotation_axis_angle_deg, 3) || !finite_n(ps->translation, 3) ||
            !isfinite(ps->scale) || !(ps->scale > 0.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "render: objects[%d] (%s): pose must be finite with scale > 0", o,
                              name);
        if (ob->spheres.count < 0 || (ob->spheres.count > 0 && !ob->spheres.data))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: objects[%d] (%s): bad sphere set",
                              o, name);
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *s4 = ob->spheres.data + 4 * (size_t)i;
            if (!finite_n(s4, 4) || !(s4[3] > 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): sphere %d: needs a finite center and "
                                  "a radius > 0",
                                  o, name, i);
            const float *k = ob->spheres.weight;
            if (k && !(isfinite(k[i]) && k[i] >= 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): sphere %d: overlap weight %g is not a "
                                  "finite number >= 0",
                                  o, name, i, (double)k[i]);
        }
    }
    return PEN_OK;
}

/* ---- Background ------------------------------------------------------------------------------ */

/* Unit direction of the ray through the centre of pixel (px, py). */
static void pixel_dir(const pen_view *v, int px, int py, float dir[3]) {
    double d[3];
    pen_view_ray(v, px + 0.5, py + 0.5, d);
    const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int a = 0; a < 3; ++a)
        dir[a] = (float)(d[a] / len);
}

static void background_fwd(const pen_scene *sc, const pen_view *v, int px, int py, float rgb[3]) {
    if (!sc->background_envmap) {
        for (int ch = 0; ch < 3; ++ch)
            rgb[ch] = sc->background[ch];
        return;
    }
    float dir[3];
    pixel_dir(v, px, py, dir);
    pen_envmap_eval(&sc->lighting.envmap, sc->lighting.rotation_y_deg, sc->lighting.scale, dir,
                    rgb);
}

/* The background seen through the environment map costs trigonometry per pixel (a tenth of an
 * optimisation step's forward at 512^2) yet depends on nothing that an optimiser changes. The
 * state keeps the last frame's and reuses it when the camera, the map's rotation, scale, size
 * and pixels are the same; the pixels are compared by a 64-bit hash (8 interleaved multiplicative
 * lanes, vectorised: a fraction of a millisecond for a 1024 x 512 map), so a map edited in place
 * is noticed. */
static uint64_t envmap_hash(const pen_image *env) {
    return hash32(env->data, (size_t)env->width * (size_t)env->height * (size_t)env->channels);
}

/* Decides st->bg_use for this frame (and sizes the cache); never fails the render: without
 * memory for the cache the background is computed as usual. */
static void background_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    st->bg_use = 0;
    if (!sc->background_envmap) return;
    bg_key k;
    memset(&k, 0, sizeof k);
    k.camera = sc->camera;
    k.data = sc->lighting.envmap.data;
    k.width = sc->lighting.envmap.width, k.height = sc->lighting.envmap.height;
    k.channels = sc->lighting.envmap.channels;
    k.rotation_y_deg = sc->lighting.rotation_y_deg, k.scale = sc->lighting.scale;
    k.hash = envmap_hash(&sc->lighting.envmap);
    if (st->bg_valid && !memcmp(&k, &st->bg_key, sizeof k)) {
        st->bg_use = 2;
        return;
    }
    st->bg_valid = 0;
    const size_t np = (size_t)st->width * (size_t)st->height;
    if (ensure(ctx, (void **)&st->bg, &st->bg_cap, np, 3 * sizeof(float), "background cache")) {
        pen_context_clear_error(ctx); /* not the render's failure: it goes on without the cache */
        return;
    }
    /* Filled for every pixel now, not only for those that show the background in this frame:
     * the cache outlives the frame, and a pixel covered by the object now may show the
     * background after the object moves (filling on the fly left such pixels uninitialised). */
    const int w = st->width, h = st->height;
    const pen_view *view = &st->view;
    float *bg = st->bg;
    const int threads = pen_context_threads(ctx) > 0 ? pen_context_threads(ctx)
                                                     : omp_get_max_threads();
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int py = 0; py < h; ++py)
        for (int px = 0; px < w; ++px)
            background_fwd(sc, view, px, py, bg + 3 * ((size_t)py * (size_t)w + (size_t)px));
    st->bg_key = k;
    st->bg_valid = 1;
    st->bg_use = 2;
}

/* Background pixel i at (px, py), through the cache when there is one. */
static void background_pixel(const pen_scene *sc, const pen_render_state *st, int px, int py,
                             size_t i) {
    float *rgb = st->color + 3 * i;
    if (st->bg_use) {
        memcpy(rgb, st->bg + 3 * i, 3 * sizeof(float));
        return;
    }
    background_fwd(sc, &st->view, px, py, rgb);
}

/* ---- Forward --------------------------------------------------------------------------------- */

pen_render_options pen_render_options_default(void) {
    pen_render_options o;
    o.shadows = 1;
    o.antialias = 1;
    o.kernel = PEN_RENDER_KERNEL_FAST;
    return o;
}

static int thread_count(const pen_context *ctx) {
    int t = pen_context_threads(ctx);
    return t > 0 ? t : omp_get_max_threads();
}

/* The ground plane as an occluder of the objects. The reference ray-traces the ground, so a
 * surface facing down or sideways loses the light from below the horizon; spheres cannot say
 * that (a plane is no sphere), and without it the model lights the undersides of objects with
 * the lower half of the environment. Seen from a point at height h over a disc of radius s (the
 * ground's half size), the ground covers the directions within atan(s / h) of straight down,
 * i.e. the point sees the directions with y > -t, t = h / sqrt(h^2 + s^2). The product of the
 * lighting with that indicator, projected back to the bands, is a linear map of the lighting,
 * seen = M(t) sh (pen__sh_above), so it costs nothing per pixel when t is one per object: h is
 * taken at the object's origin (the pose's translation; the bundled meshes are centred), and the
 * object's pixels shade with `seen`, the ground's own pixels with sh. The backward maps the
 * gradient of `seen` back through M^T = M into the lighting, and through dM/dt dt/dh into the
 * pose's vertical translation. With shadows off (V = 1 everywhere) nothing is occluded. */
static void ground_occlusion_prepare(const pen_scene *sc, const pen_render_options *opt,
                                     pen_render_state *st) {
    st->ground_occludes = opt->shadows && sc->ground.enabled && sc->object_count > 0 &&
                          sc->shadow.ground == PEN_GROUND_OCCLUDES;
    if (!st->ground_occludes) return;
    const int n = sc->sh_bands * sc->sh_bands;
    double dM[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS]; /* 32 KB */
    for (int o = 0; o < sc->object_count; ++o) {
        object_buf *b = &st->obj[o];
        const double h = (double)sc->objects[o].pose.translation[1] - (double)sc->ground.height;
        const double s = (double)sc->ground.half_size, r = sqrt(h * h + s * s);
        const double t = r > 0.0 ? h / r : 0.0, dt_dh = r > 0.0 ? s * s / (r * r * r) : 0.0;
        pen__sh_above(sc->sh_bands, t, b->horizon, dM);
        for (int j = 0; j < n; ++j)
            for (int ch = 0; ch < 3; ++ch) {
                double v = 0.0, dv = 0.0;
                for (int k = 0; k < n; ++k) {
                    v += b->horizon[j * n + k] * (double)sc->lighting.sh[k][ch];
                    dv += dM[j * n + k] * (double)sc->lighting.sh[k][ch];
                }
                b->seen[j][ch] = (float)v;
                b->d_seen_dh[j][ch] = dv * dt_dh;
            }
    }
}

/* Poses the geometry, rasterizes, and interpolates the per-pixel attributes into st. */
static pen_status prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st) {
    pen_status s = validate(ctx, sc);
    if (s) return s;
    if ((s = pen_view_init(ctx, &sc->camera, &st->view))) return s;
    const int W = st->view.width, H = st->view.height;
    const size_t np = (size_t)W * (size_t)H;
    if (st->gb.width != W || st->gb.height != H) {
        pen_gbuffer_free(&st->gb);
        if ((s = pen_gbuffer_create(ctx, W, H, &st->gb))) return s;
    }
    st->width = W, st->height = H;
    if ((s = ensure_pixels(ctx, st, np))) return s;
    if ((s = ensure_objects(ctx, st, sc->object_count))) return s;
    st->object_count = sc->object_count;

    /* Posed vertices, their normals and the adjacency for antialiasing. */
    int spheres = 0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        object_buf *b = &st->obj[o];
        const size_t V = (size_t)ob->mesh.vertex_count, T = (size_t)ob->mesh.triangle_count;
        if ((s = ensure_object(ctx, b, V, T))) return s;
        pen_pose_points_fwd(&ob->pose, (int)V, ob->mesh.positions, b->world);
        if ((s = pen_vertex_normals_fwd(ctx, (int)V, b->world, (int)T, ob->mesh.indices,
                                        b->vnormal)))
            return s;
        if (opt->antialias) {
            const uint64_t h = hash32(ob->mesh.indices, 3 * T);
            if (!b->adj_valid || b->adj_vertices != (int)V || b->adj_triangles != (int)T ||
                b->adj_hash != h) {
                b->adj_valid = 0;
                if ((s = pen_raster_adjacency(ctx, (int)V, (int)T, ob->mesh.indices,
                                              b->adjacency)))
                    return s;
                b->adj_valid = 1, b->adj_vertices = (int)V, b->adj_triangles = (int)T;
                b->adj_hash = h;
            }
        }
        pen_raster_mesh *m = &st->meshes[o];
        m->vertex_count = (int)V;
        m->triangle_count = (int)T;
        m->positions = b->world;
        m->indices = ob->mesh.indices;
        m->adjacency = opt->antialias ? b->adjacency : NULL;
        st->sphere_first[o] = spheres;
        spheres += ob->spheres.count;
    }
    st->sphere_first[sc->object_count] = spheres;
    st->sphere_count = spheres;
    if ((s = ensure(ctx, (void **)&st->spheres, &st->sphere_cap, 4 * (size_t)spheres, sizeof(float),
                    "posed spheres")))
        return s;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *src = ob->spheres.data + 4 * (size_t)i;
            float *dst = st->spheres + 4 * (size_t)(st->sphere_first[o] + i);
            pen_pose_apply(&ob->pose, src, dst);
            dst[3] = src[3] * ob->pose.scale;
        }
    }
    /* Overlap weights: the object's own, computed from its spheres when it has none (so that an
     * in-memory set renders as the same set loaded from a file), or 1 with overlap "none".
     * Computed weights are kept with the set they came from: an optimiser that renders the
     * same in-memory set every frame computes them once (they cost more than a forward). */
    const size_t nfirst = (size_t)sc->object_count + 1;
    const int kept = st->kappa && st->kappa_key && st->kappa_first &&
                     st->kappa_cap >= (size_t)spheres &&
                     st->kappa_key_cap >= 4 * (size_t)spheres && st->kappa_first_cap >= nfirst &&
                     !memcmp(st->kappa_first, st->sphere_first, sizeof(int) * nfirst);
    if ((s = ensure(ctx, (void **)&st->kappa, &st->kappa_cap, (size_t)spheres, sizeof(float),
                    "overlap weights")) ||
        (s = ensure(ctx, (void **)&st->kappa_key, &st->kappa_key_cap, 4 * (size_t)spheres,
                    sizeof(float), "overlap weight keys")) ||
        (s = ensure(ctx, (void **)&st->kappa_first, &st->kappa_first_cap, nfirst, sizeof(int),
                    "overlap weight layout")))
        return s;
    if (!kept) {
        for (size_t i = 0; i < 4 * (size_t)spheres; ++i)
            st->kappa_key[i] = NAN;
        memcpy(st->kappa_first, st->sphere_first, sizeof(int) * nfirst);
    }
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_spheres *sp = &sc->objects[o].spheres;
        float *k = st->kappa + st->sphere_first[o];
        float *key = st->kappa_key + 4 * (size_t)st->sphere_first[o];
        const size_t nkey = 4 * (size_t)sp->count;
        const int computed = sc->shadow.overlap != PEN_OVERLAP_NONE && !sp->weight;
        if (nkey == 0) continue; /* no spheres, no weights (and sp->data may be NULL) */
        if (computed && !memcmp(key, sp->data, sizeof(float) * nkey)) continue; /* as before */
        for (size_t i = 0; i < nkey; ++i)
            key[i] = NAN;
        if (sc->shadow.overlap == PEN_OVERLAP_NONE) {
            for (int i = 0; i < sp->count; ++i)
                k[i] = 1.0f;
        } else if (sp->weight) {
            memcpy(k, sp->weight, sizeof(float) * (size_t)sp->count);
        } else {
            if ((s = pen_spheres_overlap_weights(ctx, sp, k))) return s;
            memcpy(key, sp->data, sizeof(float) * nkey);
        }
    }

    if ((s = pen_raster_gbuffer(ctx, &st->view, st->meshes, sc->object_count, &sc->ground,
                                &st->gb)))
        return s;
    pen_gbuffer_points(&st->view, &st->gb, st->x);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen_interpolate_fwd(&st->gb, o, ob->mesh.indices, st->obj[o].world, 3, st->x);
        pen_interpolate_fwd(&st->gb, o, ob->mesh.indices, st->obj[o].vnormal, 3, st->nraw);
        if (ob->texture.data)
            pen_interpolate_fwd(&st->gb, o, ob->mesh.uv_indices, ob->mesh.uvs, 2, st->uv);
    }

    const pen_sh_exp_model model = pen_sh_exp_model_default(sc->shadow.exp, sc->sh_bands);
    pen__shade_params_init(&st->params, sc->sh_bands, &model, (double)sc->shadow.epsilon,
                           opt->shadows);
    if (!st->params.gaunt)
        return pen__error(ctx, PEN_ERROR_INTERNAL, "render: no product table for %d bands",
                          sc->sh_bands);
    ground_occlusion_prepare(sc, opt, st);
    return PEN_OK;
}

/* Sign that turns the interpolated normal towards the viewer's side of the triangle. */
static float facing_sign(const pen_render_state *st, const pen_object *ob, int o, size_t i) {
    const uint32_t *idx = ob->mesh.indices + 3 * (size_t)st->gb.triangle[i];
    const float *w = st->obj[o].world;
    const float *p0 = w + 3 * (size_t)idx[0], *p1 = w + 3 * (size_t)idx[1],
                *p2 = w + 3 * (size_t)idx[2];
    double e1[3], e2[3], g[3], v[3];
    for (int a = 0; a < 3; ++a) {
        e1[a] = (double)p1[a] - (double)p0[a];
        e2[a] = (double)p2[a] - (double)p0[a];
        v[a] = st->view.eye[a] - (double)st->x[3 * i + a];
    }
    g[0] = e1[1] * e2[2] - e1[2] * e2[1];
    g[1] = e1[2] * e2[0] - e1[0] * e2[2];
    g[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return g[0] * v[0] + g[1] * v[1] + g[2] * v[2] < 0.0 ? -1.0f : 1.0f;
}

/* Normal (facing the camera) and albedo of surface pixel i. */
static void surface_attributes(const pen_scene *sc, pen_render_state *st, size_t i, int surf) {
    float *n = st->n + 3 * i, *rho = st->rho + 3 * i;
    if (surf == PEN_SURFACE_GROUND) {
        n[0] = 0.0f, n[1] = 1.0f, n[2] = 0.0f;
        for (int ch = 0; ch < 3; ++ch)
            rho[ch] = sc->ground.albedo[ch];
        return;
    }
    const pen_object *ob = &sc->objects[surf];
    const float sign = facing_sign(st, ob, surf, i);
    st->nsign[i] = sign;
    pen_normalize_fwd(1, st->nraw + 3 * i, n);
    for (int a = 0; a < 3; ++a)
        n[a] *= sign;
    if (ob->texture.data)
        pen__texture_fwd(&ob->texture, st->uv + 2 * i, rho);
    else
        for (int ch = 0; ch < 3; ++ch)
            rho[ch] = ob->albedo[ch];
}

/* Layout of one tile's double accumulators (the backward's small dense gradients). */
typedef struct row_layout {
    size_t sh, sh_obj, ground, albedo, spheres, stride;
} row_layout;

/* sh: the lighting gradient of pixels shaded with the scene's lighting; sh_obj (with ground
 * occlusion, `seen` objects, else none): per object, of its pixels shaded with its `seen`, mapped
 * back after the reduction. */
static row_layout rows_layout(int bands, int objects, int seen, int spheres) {
    row_layout r;
    r.sh = 0;
    r.sh_obj = r.sh + 3 * (size_t)bands * (size_t)bands;
    r.ground = r.sh_obj + 3 * (size_t)bands * (size_t)bands * (size_t)seen;
    r.albedo = r.ground + 3;
    r.spheres = r.albedo + 3 * (size_t)objects;
    r.stride = r.spheres + 4 * (size_t)spheres;
    return r;
}

/* What the backward computes. */
typedef struct bwd_want {
    int geom, spheres, light, albedo;
    int seen; /* the gradient of each object's `seen` lighting (for the lighting or the pose) */
    row_layout rl;
} bwd_want;

/* A pass over the tiles: store is the fast kernel's store (tile t's part at tile_off[t]) or the
 * scalar kernel's per-pixel F and V (tile_off NULL), or NULL when nothing is kept; bw is the
 * backward's request (NULL in the forward). */
typedef struct tile_job {
    const pen_scene *sc;
    pen_render_state *st;
    const bwd_want *bw;
    float *store;
    const size_t *tile_off;
} tile_job;

static float *tile_store_of(const tile_job *job, int t) {
    return job->store && job->tile_off ? job->store + job->tile_off[t] : NULL;
}

/* The kernels shade a tile's pixels in groups of one lighting each: the ground's (group 0), then
 * the objects' (group 1 for all of them, or 1 + o per object o with ground occlusion, whose
 * objects see their own lighting). Background pixels belong to none (-1). */
static int pixel_group(const pen_render_state *st, int surf) {
    if (surf == PEN_SURFACE_BACKGROUND) return -1;
    if (surf == PEN_SURFACE_GROUND) return 0;
    return st->ground_occludes ? 1 + surf : 1;
}

/* The object whose own `seen` lighting group g shades with, or -1 for the scene's lighting (the
 * ground's group, and every group without ground occlusion). */
static int group_seen_object(const pen_render_state *st, int g) {
    return st->ground_occludes && g > 0 ? g - 1 : -1;
}

/* The lighting of group g. */
static const float (*group_lighting(const pen_scene *sc, const pen_render_state *st, int g))[3] {
    const int o = group_seen_object(st, g);
    return o >= 0 ? (const float(*)[3])st->obj[o].seen : (const float(*)[3])sc->lighting.sh;
}

/* Groups the shaded pixels of tile t into st->groups[t] (a tile_fn: the forward runs it over the
 * tiles in parallel before shading). The stable insertion sort moves each pixel past the earlier
 * pixels of higher groups: nothing for a tile of one group, but a pixels of one group above b of
 * a lower one (an object over the ground) cost a * b moves, up to TILE_PX^2 / 4. */
static void tile_group(const void *job_, int t, tile_ws *ws, pen__shade_fast_ticks *tk) {
    (void)ws, (void)tk;
    const pen_render_state *st = ((const tile_job *)job_)->st;
    tile_groups *tg = &st->groups[t];
    int x0, y0, x1, y1, n = 0, grp[TILE_PX];
    tile_rect(st, t, &x0, &y0, &x1, &y1);
    for (int py = y0; py < y1; ++py)
        for (int px = x0; px < x1; ++px) {
            const size_t i = (size_t)py * (size_t)st->width + (size_t)px;
            const int g = pixel_group(st, st->gb.surface[i]);
            if (g < 0) continue;
            int k = n++;
            for (; k > 0 && grp[k - 1] > g; --k)
                tg->pix[k] = tg->pix[k - 1], grp[k] = grp[k - 1];
            tg->pix[k] = (int)i, grp[k] = g;
        }
    tg->runs = 0, tg->store = 0; /* each run is one kernel call, its pixels in whole batches */
    for (int a = 0, b; a < n; a = b) {
        for (b = a; b < n && grp[b] == grp[a]; ++b) {}
        tg->end[tg->runs++] = b;
        tg->store += pen__shade_fast_store_floats(&st->params, b - a);
    }
}

/* Run r of tile t (as tile_group made it): its pixels pix[0 .. count - 1]; returns its group. */
static int tile_run(const pen_render_state *st, int t, int r, const int **pix, int *count) {
    const tile_groups *tg = &st->groups[t];
    const int a = r > 0 ? tg->end[r - 1] : 0;
    *pix = tg->pix + a, *count = tg->end[r] - a;
    return pixel_group(st, st->gb.surface[tg->pix[a]]);
}

/* Where each tile's part of the fast kernel's store begins (ntiles + 1 offsets in floats). */
static pen_status tile_store_layout(pen_context *ctx, pen_render_state *st, int ntiles) {
    pen_status s = ensure(ctx, (void **)&st->tile_off, &st->tile_off_cap, (size_t)ntiles + 1,
                          sizeof(size_t), "store layout");
    if (s) return s;
    st->tile_off[0] = 0;
    for (int t = 0; t < ntiles; ++t)
        st->tile_off[t + 1] = st->tile_off[t] + st->groups[t].store;
    return PEN_OK;
}

/* Shades tile t: background pixels directly, surface pixels through the fast kernel (compacted
 * into ws, one call per group) or the scalar kernel one by one. */
static void shade_tile_fwd(const void *job_, int t, tile_ws *ws, pen__shade_fast_ticks *tk) {
    const tile_job *job = job_;
    const pen_scene *sc = job->sc;
    pen_render_state *st = job->st;
    float *store = tile_store_of(job, t);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    int x0, y0, x1, y1;
    tile_rect(st, t, &x0, &y0, &x1, &y1);
    for (int py = y0; py < y1; ++py)
        for (int px = x0; px < x1; ++px) {
            const size_t i = (size_t)py * (size_t)st->width + (size_t)px;
            const int surf = st->gb.surface[i];
            if (surf == PEN_SURFACE_BACKGROUND)
                background_pixel(sc, st, px, py, i);
            else
                surface_attributes(sc, st, i, surf);
        }
    for (int r = 0; r < st->groups[t].runs; ++r) {
        const int *pix;
        int cnt;
        const int g = tile_run(st, t, r, &pix, &cnt);
        const float(*sh)[3] = group_lighting(sc, st, g);
        if (!st->fast) {
            for (int k = 0; k < cnt; ++k) {
                const size_t i = (size_t)pix[k];
                pen__shade_fwd(&st->params, sh, st->sphere_count, st->spheres, st->kappa,
                               st->x + 3 * i, st->n + 3 * i, st->rho + 3 * i, st->color + 3 * i,
                               job->store ? job->store + nfv * i : NULL);
            }
            continue;
        }
        for (int k = 0; k < cnt; ++k)
            ws_push(ws, k, st, (size_t)pix[k]);
        pen__shade_fast_fwd(&st->params, sh, st->sphere_count, st->spheres, st->kappa, cnt,
                            g == 0 ? cnt : 0, ws->x, ws->n, ws->rho, ws->out, store,
                            ws->kernel, tk);
        if (store) store += pen__shade_fast_store_floats(&st->params, cnt);
        for (int k = 0; k < cnt; ++k)
            memcpy(st->color + 3 * (size_t)ws->idx[k], ws->out + 3 * k, 3 * sizeof(float));
    }
}

pen_status pen_render_fwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *state, pen_image *image) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    pen_render_state *own = NULL;
    pen_status s;
    if (!state) {
        if ((s = pen_render_state_create(ctx, &own))) return s;
        state = own;
    }
    if (opt->kernel != PEN_RENDER_KERNEL_FAST && opt->kernel != PEN_RENDER_KERNEL_SCALAR) {
        s = pen__error(ctx, PEN_ERROR_ARGUMENT, "render: unknown kernel %d", opt->kernel);
        goto done;
    }
    pen_render_state *st = state;
    st->valid = 0;
    pen_render_timings *tm = &st->timings;
    memset(tm, 0, sizeof *tm);
    double t0 = omp_get_wtime();
    if ((s = prepare(ctx, sc, opt, st))) goto done;
    tm->fwd_prepare_ms = ms_since(t0);
    const int W = st->width, H = st->height;
    if (image->data) {
        if (image->width != W || image->height != H || image->channels != 3) {
            s = pen__error(ctx, PEN_ERROR_ARGUMENT,
                           "render: output image is %dx%dx%d, the camera needs %dx%dx3",
                           image->width, image->height, image->channels, W, H);
            goto done;
        }
    } else if ((s = pen_image_create(ctx, W, H, 3, image))) {
        goto done;
    }

    const int fast =
        opt->kernel == PEN_RENDER_KERNEL_FAST && pen__shade_fast_supported(&st->params);
    const int ntiles = tile_count(st);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const int nt = thread_count(ctx);
    size_t wsb = 0;
    if ((s = ensure_ws(ctx, st, nt, &wsb)) ||
        (s = ensure(ctx, (void **)&st->groups, &st->groups_cap, (size_t)ntiles,
                    sizeof(tile_groups), "tile pixel groups")))
        goto done;
    /* Every tile's lighting groups, for the shading below, the store's layout and the backward. */
    t0 = omp_get_wtime();
    const tile_job group_job = {sc, st, NULL, NULL, NULL};
    run_tiles(st, nt, wsb, tile_group, &group_job);
    /* Keep what the backward needs: the scalar kernel F and V per pixel (2 bands^2 floats:
     * 32 MB at 512 x 512, 4 bands), the fast kernel F per pixel in its batch layout. */
    float *fv_all = NULL;
    if (own == NULL && opt->shadows) {
        if (fast && (s = tile_store_layout(ctx, st, ntiles))) goto done;
        const size_t need = fast ? st->tile_off[ntiles] : nfv * (size_t)W * (size_t)H;
        if ((s = ensure(ctx, (void **)&st->fv, &st->fv_cap, need, sizeof(float),
                        "visibility buffer")))
            goto done;
        fv_all = st->fv;
    }
    st->fv_valid = fv_all != NULL;
    st->fast = fast;
    const tile_job job = {sc, st, NULL, fv_all, fast ? st->tile_off : NULL};
    background_prepare(ctx, sc, st);
    const loop_ticks lt = run_tiles(st, nt, wsb, shade_tile_fwd, &job);
    tm->fwd_shade_ms = ms_since(t0);
    tm->fwd_visibility_ms = stage_ms(tm->fwd_shade_ms, lt.visibility, lt.total);
    tm->fwd_exp_ms = stage_ms(tm->fwd_shade_ms, lt.exp, lt.total);

    t0 = omp_get_wtime();
    if (opt->antialias && sc->object_count > 0) {
        if ((s = pen_antialias_fwd(ctx, &st->gb, &st->view, st->meshes, sc->object_count, st->color,
                                   3, image->data)))
            goto done;
    } else {
        memcpy(image->data, st->color, sizeof(float) * 3 * (size_t)W * (size_t)H);
    }
    tm->fwd_antialias_ms = ms_since(t0);
    st->opt = *opt;
    st->valid = 1;
    s = PEN_OK;
done:
    pen_render_state_free(own);
    return s;
}

/* ---- Gradient struct ------------------------------------------------------------------------- */

pen_status pen_render_grad_create(pen_context *ctx, const pen_scene *sc, pen_render_grad *out) {
    memset(out, 0, sizeof *out);
    out->bands = sc->sh_bands;
    if (sc->object_count <= 0) return PEN_OK;
    out->objects =
        pen__calloc(ctx, (size_t)sc->object_count, sizeof *out->objects, "gradient objects");
    if (!out->objects) return PEN_ERROR_MEMORY;
    out->object_count = sc->object_count;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen_object_grad *g = &out->objects[o];
        g->vertex_count = ob->mesh.vertex_count > 0 ? ob->mesh.vertex_count : 0;
        g->sphere_count = ob->spheres.count > 0 ? ob->spheres.count : 0;
        g->positions =
            pen__calloc(ctx, 3 * (size_t)g->vertex_count + 1, sizeof(float), "vertex gradient");
        g->spheres =
            pen__calloc(ctx, 4 * (size_t)g->sphere_count + 1, sizeof(float), "sphere gradient");
        if (!g->positions || !g->spheres) goto fail;
        if (ob->texture.data) {
            g->texel_count = ob->texture.width * ob->texture.height;
            g->texture =
                pen__calloc(ctx, (size_t)g->texel_count,
                            sizeof(float) * (size_t)ob->texture.channels, "texture gradient");
            if (!g->texture) goto fail;
        }
    }
    return PEN_OK;
fail:
    pen_render_grad_free(out);
    return PEN_ERROR_MEMORY;
}

void pen_render_grad_zero(pen_render_grad *g) {
    memset(g->sh, 0, sizeof g->sh);
    memset(g->ground_albedo, 0, sizeof g->ground_albedo);
    for (int o = 0; o < g->object_count; ++o) {
        pen_object_grad *og = &g->objects[o];
        memset(og->albedo, 0, sizeof og->albedo);
        memset(&og->pose, 0, sizeof og->pose);
        memset(og->positions, 0, sizeof(float) * 3 * (size_t)og->vertex_count);
        memset(og->spheres, 0, sizeof(float) * 4 * (size_t)og->sphere_count);
        if (og->texture) memset(og->texture, 0, sizeof(float) * 3 * (size_t)og->texel_count);
    }
}

void pen_render_grad_free(pen_render_grad *g) {
    if (!g) return;
    for (int o = 0; o < g->object_count; ++o) {
        free(g->objects[o].positions);
        free(g->objects[o].spheres);
        free(g->objects[o].texture);
    }
    free(g->objects);
    memset(g, 0, sizeof *g);
}

/* ---- Backward -------------------------------------------------------------------------------- */


/* After the kernel's backward of surface pixel i: its albedo gradient into the tile's sums (ground,
 * constant albedo) or through the texture lookup to uv, and d_n through the facing sign and the
 * normalisation to the raw normal. d_rho is st->d_rho of the pixel. */
static void pixel_bwd_tail(const pen_scene *sc, pen_render_state *st, const bwd_want *bw,
                           double *row, size_t i, int surf, float d_n[3]) {
    const float *d_rho = st->d_rho + 3 * i;
    if (surf < 0) {
        if (bw->albedo)
            for (int ch = 0; ch < 3; ++ch)
                row[bw->rl.ground + ch] += (double)d_rho[ch];
        return;
    }
    const pen_object *ob = &sc->objects[surf];
    if (!ob->texture.data && bw->albedo)
        for (int ch = 0; ch < 3; ++ch)
            row[bw->rl.albedo + 3 * (size_t)surf + ch] += (double)d_rho[ch];
    if (!bw->geom) return;
    if (ob->texture.data) pen__texture_bwd(&ob->texture, st->uv + 2 * i, d_rho, NULL, st->d_uv + 2 * i);
    const float sign = st->nsign[i];
    for (int a = 0; a < 3; ++a)
        d_n[a] *= sign;
    pen_normalize_bwd(1, st->nraw + 3 * i, d_n, st->d_nraw + 3 * i);
}

/* Backward of tile t into the tile's double accumulators and the per-pixel gradients d_x,
 * d_nraw, d_uv, d_rho (zeroed here for every pixel of the tile), in the forward's groups. */
static void shade_tile_bwd(const void *job_, int t, tile_ws *ws, pen__shade_fast_ticks *tk) {
    const tile_job *job = job_;
    const pen_scene *sc = job->sc;
    pen_render_state *st = job->st;
    const bwd_want *bw = job->bw;
    const float *store = tile_store_of(job, t);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const size_t nsh = 3 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const int S = st->sphere_count;
    double *row = st->rows + bw->rl.stride * (size_t)t;
    double *d_sph = bw->spheres ? row + bw->rl.spheres : NULL;
    int x0, y0, x1, y1;
    tile_rect(st, t, &x0, &y0, &x1, &y1);
    for (int py = y0; py < y1; ++py)
        for (int px = x0; px < x1; ++px) {
            const size_t i = (size_t)py * (size_t)st->width + (size_t)px;
            float *d_x = st->d_x + 3 * i, *d_rho = st->d_rho + 3 * i;
            float *d_nraw = st->d_nraw + 3 * i, *d_uv = st->d_uv + 2 * i;
            for (int a = 0; a < 3; ++a)
                d_x[a] = d_nraw[a] = d_rho[a] = 0.0f;
            d_uv[0] = d_uv[1] = 0.0f;
        }
    for (int r = 0; r < st->groups[t].runs; ++r) {
        const int *pix;
        int cnt;
        const int g = tile_run(st, t, r, &pix, &cnt);
        const float(*sh)[3] = group_lighting(sc, st, g);
        /* where this group's lighting gradient goes: an object's own `seen`, or the lighting */
        const int own = group_seen_object(st, g);
        double(*d_sh)[3] =
            own >= 0 ? (bw->seen ? (double(*)[3])(row + bw->rl.sh_obj + nsh * (size_t)own) : NULL)
                     : (bw->light ? (double(*)[3])(row + bw->rl.sh) : NULL);
        if (!st->fast) {
            for (int k = 0; k < cnt; ++k) {
                const size_t i = (size_t)pix[k];
                const int surf = st->gb.surface[i];
                const float *dc = st->d_color + 3 * i;
                if (dc[0] == 0.0f && dc[1] == 0.0f && dc[2] == 0.0f) continue;
                const int geom = surf >= 0 && bw->geom;
                const int need_rho =
                    bw->albedo || (geom && sc->objects[surf].texture.data != NULL);
                float d_n[3] = {0.0f, 0.0f, 0.0f};
                pen__shade_bwd(&st->params, sh, S, st->spheres, st->kappa, st->x + 3 * i,
                               st->n + 3 * i, st->rho + 3 * i, dc,
                               job->store ? job->store + nfv * i : NULL, d_sh, d_sph,
                               geom ? st->d_x + 3 * i : NULL, geom ? d_n : NULL,
                               need_rho ? st->d_rho + 3 * i : NULL);
                pixel_bwd_tail(sc, st, bw, row, i, surf, d_n);
            }
            continue;
        }
        for (int k = 0; k < cnt; ++k) {
            memcpy(ws->out + 3 * k, st->d_color + 3 * (size_t)pix[k], 3 * sizeof(float));
            ws_push(ws, k, st, (size_t)pix[k]);
        }
        memset(ws->dx, 0, 3 * sizeof(float) * (size_t)cnt);
        memset(ws->dn, 0, 3 * sizeof(float) * (size_t)cnt);
        memset(ws->drho, 0, 3 * sizeof(float) * (size_t)cnt);
        pen__shade_fast_bwd(&st->params, sh, S, st->spheres, st->kappa, cnt, g == 0 ? cnt : 0,
                            ws->x, ws->n, ws->rho, ws->out, store, ws->kernel, d_sh, d_sph,
                            bw->geom ? ws->dx : NULL, bw->geom ? ws->dn : NULL, ws->drho, tk);
        if (store) store += pen__shade_fast_store_floats(&st->params, cnt);
        for (int k = 0; k < cnt; ++k) {
            const size_t i = (size_t)ws->idx[k];
            const int surf = st->gb.surface[i];
            const int geom = surf >= 0 && bw->geom;
            if (bw->albedo || (geom && sc->objects[surf].texture.data))
                memcpy(st->d_rho + 3 * i, ws->drho + 3 * k, 3 * sizeof(float));
            if (geom) memcpy(st->d_x + 3 * i, ws->dx + 3 * k, 3 * sizeof(float));
            pixel_bwd_tail(sc, st, bw, row, i, surf, ws->dn + 3 * k);
        }
    }
}

static pen_status check_grad_shape(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_grad *g) {
    if (g->object_count != sc->object_count || g->bands != sc->sh_bands)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: gradient struct does not match the scene");
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object_grad *og = &g->objects[o];
        const pen_object *ob = &sc->objects[o];
        if (og->vertex_count != ob->mesh.vertex_count || og->sphere_count != ob->spheres.count ||
            (!ob->texture.data != !og->texture) ||
            (ob->texture.data && og->texel_count != ob->texture.width * ob->texture.height))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "render backward: gradient of objects[%d] does not match the scene",
                              o);
    }
    return PEN_OK;
}

pen_status pen_render_bwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st, const pen_image *d_image, unsigned wrt,
                          pen_render_grad *grad) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    if (!st || !st->valid)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render backward: no forward pass to undo");
    if (opt->shadows != st->opt.shadows || opt->antialias != st->opt.antialias ||
        opt->kernel != st->opt.kernel)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: options differ from the forward pass");
    const int W = st->width, H = st->height;
    if (!d_image || !d_image->data || d_image->width != W || d_image->height != H ||
        d_image->channels != 3)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: d_image must be %dx%d with 3 channels", W, H);
    int changed = st->object_count != sc->object_count;
    for (int o = 0; o < sc->object_count && !changed; ++o)
        changed = st->meshes[o].vertex_count != sc->objects[o].mesh.vertex_count ||
                  st->meshes[o].triangle_count != sc->objects[o].mesh.triangle_count ||
                  st->sphere_first[o + 1] - st->sphere_first[o] != sc->objects[o].spheres.count;
    if (changed)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: the scene changed since the forward pass");
    pen_status s = check_grad_shape(ctx, sc, grad);
    if (s) return s;
    const size_t np = (size_t)W * (size_t)H;
    const int O = sc->object_count, S = st->sphere_count, nc = sc->sh_bands * sc->sh_bands;
    const int want_geom = (wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) != 0;
    const int want_sph = (wrt & (PEN_GRAD_SPHERES | PEN_GRAD_POSE)) != 0;
    const int want_light = (wrt & PEN_GRAD_LIGHTING) != 0;
    const int want_albedo = (wrt & PEN_GRAD_ALBEDO) != 0;

    /* World-space vertex gradient buffers. */
    float **d_world = NULL;
    if (want_geom) {
        d_world = pen__calloc(ctx, (size_t)O + 1, sizeof *d_world, "vertex gradient pointers");
        if (!d_world) return PEN_ERROR_MEMORY;
        for (int o = 0; o < O; ++o) {
            object_buf *b = &st->obj[o];
            const size_t V = (size_t)sc->objects[o].mesh.vertex_count;
            memset(b->d_world, 0, sizeof(float) * 3 * V);
            memset(b->d_vnormal, 0, sizeof(float) * 3 * V);
            d_world[o] = b->d_world;
        }
    }

    pen_render_timings *tm = &st->timings;
    tm->bwd_antialias_ms = tm->bwd_shade_ms = tm->bwd_visibility_ms = tm->bwd_exp_ms = 0.0;
    tm->bwd_scatter_ms = 0.0;
    double t0 = omp_get_wtime();

    /* Antialiasing backward: d_image -> d_colour (+ silhouette vertex gradients). */
    if (opt->antialias && O > 0) {
        memset(st->d_color, 0, sizeof(float) * 3 * np);
        s = pen_antialias_bwd(ctx, &st->gb, &st->view, st->meshes, O, st->color, 3, d_image->data,
                              st->d_color, want_geom ? d_world : NULL);
        if (s) {
            free(d_world);
            return s;
        }
    } else {
        memcpy(st->d_color, d_image->data, sizeof(float) * 3 * np);
    }
    tm->bwd_antialias_ms = ms_since(t0);

    /* Per-pixel backward, tiles in parallel, each tile into its own accumulators. */
    const int seen = st->ground_occludes ? O : 0;
    const row_layout rl = rows_layout(sc->sh_bands, O, seen, S);
    const int ntiles = tile_count(st);
    if ((s = ensure(ctx, (void **)&st->rows, &st->rows_cap, rl.stride * (size_t)ntiles,
                    sizeof(double), "tile gradient buffers"))) {
        free(d_world);
        return s;
    }
    memset(st->rows, 0, sizeof(double) * rl.stride * (size_t)ntiles);
    const int nt = thread_count(ctx);
    size_t wsb = 0;
    if ((s = ensure_ws(ctx, st, nt, &wsb))) {
        free(d_world);
        return s;
    }
    const int want_height = (wrt & PEN_GRAD_POSE) != 0 && st->ground_occludes;
    const bwd_want bw = {want_geom, want_sph,    want_light, want_albedo,
                         seen > 0 && (want_light || want_height), rl};
    float *fv_all = st->fv_valid ? st->fv : NULL;
    const tile_job job = {sc, st, &bw, fv_all, st->fast ? st->tile_off : NULL};
    t0 = omp_get_wtime();
    const loop_ticks lt = run_tiles(st, nt, wsb, shade_tile_bwd, &job);
    tm->bwd_shade_ms = ms_since(t0);
    tm->bwd_visibility_ms = stage_ms(tm->bwd_shade_ms, lt.visibility, lt.total);
    tm->bwd_exp_ms = stage_ms(tm->bwd_shade_ms, lt.exp, lt.total);
    t0 = omp_get_wtime();

    /* Reduce the tiles in order. */
    double *sum = pen__calloc(ctx, rl.stride + 1, sizeof(double), "gradient sums");
    if (!sum) {
        free(d_world);
        return PEN_ERROR_MEMORY;
    }
    for (int t = 0; t < ntiles; ++t) {
        const double *row = st->rows + rl.stride * (size_t)t;
        for (size_t k = 0; k < rl.stride; ++k)
            sum[k] += row[k];
    }
    const size_t nsh = 3 * (size_t)nc;
    if (want_light)
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch) {
                double d = sum[rl.sh + 3 * (size_t)k + ch];
                for (int o = 0; o < seen; ++o) { /* seen = M sh: d sh += M^T d seen, M = M^T */
                    const double *ds = sum + rl.sh_obj + nsh * (size_t)o, *M = st->obj[o].horizon;
                    for (int j = 0; j < nc; ++j)
                        d += M[k * nc + j] * ds[3 * (size_t)j + ch];
                }
                grad->sh[k][ch] += (float)d;
            }
    if (want_height) /* seen depends on the object's height through M(t(h)) */
        for (int o = 0; o < O; ++o) {
            const double *ds = sum + rl.sh_obj + nsh * (size_t)o;
            double d = 0.0;
            for (int j = 0; j < nc; ++j)
                for (int ch = 0; ch < 3; ++ch)
                    d += ds[3 * (size_t)j + ch] * st->obj[o].d_seen_dh[j][ch];
            grad->objects[o].pose.translation[1] += (float)d;
        }
    if (want_albedo) {
        for (int ch = 0; ch < 3; ++ch)
            grad->ground_albedo[ch] += (float)sum[rl.ground + ch];
        for (int o = 0; o < O; ++o)
            for (int ch = 0; ch < 3; ++ch)
                grad->objects[o].albedo[ch] += (float)sum[rl.albedo + 3 * (size_t)o + ch];
    }

    /* Spheres: world-space gradients -> object space and pose. */
    if (want_sph)
        for (int o = 0; o < O; ++o) {
            const pen_object *ob = &sc->objects[o];
            pen_object_grad *og = &grad->objects[o];
            for (int i = 0; i < ob->spheres.count; ++i) {
                const double *dw = sum + rl.spheres + 4 * (size_t)(st->sphere_first[o] + i);
                const float *c = ob->spheres.data + 4 * (size_t)i;
                const float d_c[3] = {(float)dw[0], (float)dw[1], (float)dw[2]};
                float d_co[3] = {0.0f, 0.0f, 0.0f};
                pen_pose_apply_bwd(&ob->pose, c, d_c, (wrt & PEN_GRAD_POSE) ? &og->pose : NULL,
                                   d_co);
                if (wrt & PEN_GRAD_SPHERES) {
                    for (int a = 0; a < 3; ++a)
                        og->spheres[4 * (size_t)i + a] += d_co[a];
                    og->spheres[4 * (size_t)i + 3] += (float)(dw[3] * (double)ob->pose.scale);
                }
                if (wrt & PEN_GRAD_POSE) og->pose.scale += (float)(dw[3] * (double)c[3]);
            }
        }
    free(sum);

    /* Two independent serial scatters, side by side on two threads: the texels (in pixel order,
     * so every texel sums its pixels in the same order whatever the threads) and the geometry's
     * interpolation and vertex-normal backward (into the vertex and barycentric buffers). */
    pen_status s_geom = PEN_OK;
    if (want_geom) memset(st->d_bary, 0, sizeof(float) * 2 * np);
#pragma omp parallel sections num_threads(nt > 1 ? 2 : 1) if (np >= PARALLEL_MIN_PIXELS)
    {
#pragma omp section
        if (want_albedo)
            for (size_t i = 0; i < np; ++i) {
                const int surf = st->gb.surface[i];
                if (surf < 0 || !sc->objects[surf].texture.data) continue;
                pen__texture_bwd(&sc->objects[surf].texture, st->uv + 2 * i, st->d_rho + 3 * i,
                                 grad->objects[surf].texture, NULL);
            }
#pragma omp section
        if (want_geom)
            for (int o = 0; o < O && !s_geom; ++o) {
                const pen_object *ob = &sc->objects[o];
                object_buf *b = &st->obj[o];
                pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->world, 3, st->d_x,
                                    b->d_world, st->d_bary);
                pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->vnormal, 3, st->d_nraw,
                                    b->d_vnormal, st->d_bary);
                if (ob->texture.data)
                    pen_interpolate_bwd(&st->gb, o, ob->mesh.uv_indices, ob->mesh.uvs, 2, st->d_uv,
                                        NULL, st->d_bary);
                s_geom = pen_vertex_normals_bwd(ctx, ob->mesh.vertex_count, b->world,
                                                ob->mesh.triangle_count, ob->mesh.indices,
                                                b->d_vnormal, b->d_world);
            }
    }

    /* Geometry: barycentrics, pose. */
    if (want_geom) {
        s = s_geom;
        if (!s)
            s = ensure(ctx, (void **)&st->bary_scratch, &st->bary_cap, 9 * np, sizeof(float),
                       "barycentric backward");
        if (!s)
            pen_raster_bary_bwd_scratch(ctx, &st->view, st->meshes, O, &st->gb, st->d_bary,
                                        d_world, st->bary_scratch);
        if (!s) {
            for (int o = 0; o < O; ++o) {
                const pen_object *ob = &sc->objects[o];
                pen_object_grad *og = &grad->objects[o];
                pen_pose_points_bwd(&ob->pose, ob->mesh.vertex_count, ob->mesh.positions,
                                    d_world[o], (wrt & PEN_GRAD_POSE) ? &og->pose : NULL,
                                    (wrt & PEN_GRAD_VERTICES) ? og->positions : NULL);
            }
        }
    }
    free(d_world);
    tm->bwd_scatter_ms = ms_since(t0);
    return s;
}
