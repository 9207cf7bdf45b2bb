/* Internal interface of src/render: the per-pixel shading kernel (visibility from spheres, SH
 * exponential, diffuse SH shading) and texture sampling, each a forward/backward pair. The kernel
 * is compiled in float (the renderer) and double (`_d`, gradient checks) from shade_ops.inc.
 * Below them, the frame's internals shared by the files of the full differentiable frame: the
 * render state (state.c), the tile scheduler (tiles.c), the
 * background (background.c), ground occlusion (ground.c) and the passes (forward.c,
 * backward.c). A file only calls files listed before it, never back. Scenes are validated by the
 * model layer (src/scene/validate.c) before a forward touches them. */
#ifndef PEN_RENDER_INTERNAL_H
#define PEN_RENDER_INTERNAL_H

#include "penumbra/envmap.h" /* the background along camera rays */
#include "penumbra/fit.h"    /* overlap weights, computed when a sphere set has none */
#include "penumbra/image.h"
#include "penumbra/sh.h"
#include "render/lights_internal.h" /* the disk lights' per-pixel term */
#include "scene/texture.h" /* the albedo lookup shading uses */

/* Everything about a frame's shading that is the same for every pixel. */
typedef struct pen__shade_params {
    int bands;                   /* SH bands of lighting and visibility */
    const pen_sh_gaunt *gaunt;   /* product table for `bands` */
    pen_sh_exp_model model;      /* the SH exponential */
    double epsilon;              /* log-visibility depth of a sphere */
    int shadows;                 /* 0: V == 1 (no-shadows mode) */
    double hz[PEN_SH_MAX_BANDS]; /* clamped cosine, zonal */
} pen__shade_params;

/* Fills p; the model's epsilon is used when epsilon is not a positive finite number. */
void pen__shade_params_init(pen__shade_params *p, int bands, const pen_sh_exp_model *model,
                            double epsilon, int shadows);

/* Self-shadowing rule: a sphere (c, r) counts towards the log-visibility of a receiver (x, n)
 * with weight w(h), h = n . (c - x) / r, where w is the smoothstep from h = -1 (the sphere lies
 * wholly behind the tangent plane: w = 0) to h = +1 (wholly in front: w = 1). C1 in h. */
#define PEN_RENDER_SELF_H0 (-1.0)
#define PEN_RENDER_SELF_H1 (1.0)

/* Receivers inside a sphere: the weight above is multiplied by g(q) = smoothstep of
 * (q - PEN_RENDER_INSIDE_LO) / PEN_RENDER_INSIDE_WIDTH, q = |c - x| / r, so a sphere that contains
 * the receiver deeper than LO r counts 0, one that does not contain it counts as before, C1 in
 * between. Inside a sphere the cap is the whole sphere and darkens every direction, also those the
 * surface sees freely; fitted spheres overhang the surface, so most receivers lie inside some of
 * their own object's spheres. Measured in docs/visibility.md sec. 5.1: dropping such spheres cuts
 * the object's error on the scanned meshes by 28-43 %, and this narrow fade keeps that gain. */
#define PEN_RENDER_INSIDE_LO (0.9)
#define PEN_RENDER_INSIDE_WIDTH (0.1)

/* Outgoing radiance of a diffuse receiver at x with unit normal n and albedo rho:
 *   rgb[ch] = rho[ch] / pi * sum_k sh[k][ch] (V * H_n)_k,
 *   V = exp*(sum_i w_i kappa_i logvis_i(x)), H_n = clamped cosine rotated to n.
 * spheres: sphere_count world-space spheres (x, y, z, r); kappa: their overlap weights (NULL: all
 * 1), constants of the backward. fv (may be NULL) receives F and V (2 bands^2 values) for the
 * backward when shadows are on. */
void pen__shade_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], float rgb[3], float *fv);
void pen__shade_fwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], double rgb[3], double *fv);
/* Backward: adds into d_sh (bands^2 x 3, double), d_spheres (4 per sphere, double), d_x, d_n
 * (the gradient of the polynomial extension in n: normalise's backward removes the radial part)
 * and d_rho; any may be NULL. fv: the forward's F and V for this pixel, or NULL to recompute. */
void pen__shade_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], const float d_rgb[3], const float *fv, double (*d_sh)[3],
                    double *d_spheres, float d_x[3], float d_n[3], float d_rho[3]);
void pen__shade_bwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], const double d_rgb[3],
                      const double *fv, double (*d_sh)[3], double *d_spheres, double d_x[3],
                      double d_n[3], double d_rho[3]);

/* The same with the object's own precomputed transfer: B (bands^2 values) is the part of the
 * clamped cosine its own mesh blocks, interpolated at the pixel (a constant: no gradient flows to
 * it), so its transfer is T_self = H_n - B; only the spheres that may shadow it count (kappa 0 for
 * the object's own): T = exp*(F) * T_self, or T_self itself when sphere_count is 0 (no
 * exponential). self.c calls these for pixels of objects shaded with their transfer, whichever
 * kernel the frame uses. */
void pen__shade_self_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, const float x[3],
                         const float n[3], const float *B, const float rho[3], float rgb[3],
                         float *fv);
void pen__shade_self_fwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                           const double *spheres, const double *kappa, const double x[3],
                           const double n[3], const double *B, const double rho[3],
                           double rgb[3], double *fv);
void pen__shade_self_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, const float x[3],
                         const float n[3], const float *B, const float rho[3],
                         const float d_rgb[3], const float *fv, double (*d_sh)[3],
                         double *d_spheres, float d_x[3], float d_n[3], float d_rho[3]);
void pen__shade_self_bwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                           const double *spheres, const double *kappa, const double x[3],
                           const double n[3], const double *B, const double rho[3],
                           const double d_rgb[3], const double *fv, double (*d_sh)[3],
                           double *d_spheres, double d_x[3], double d_n[3], double d_rho[3]);
/* The same with F, the other spheres' log-visibility, summed by the caller (the fast kernel's
 * lanes, pen__shade_fast_fwd with the object's kappa; bands^2 values): V = exp*(F) and the rest
 * are done here, in the backward from F again (V recomputed). The spheres are still passed for
 * the backward's gradients by x, n and the spheres (not wanted under the transfer model). */
void pen__shade_self_given_fwd(const pen__shade_params *p, const float (*sh)[3],
                               int sphere_count, const float *spheres, const float *kappa,
                               const float x[3], const float n[3], const float *B,
                               const float *F, const float rho[3], float rgb[3], float *fv);
void pen__shade_self_given_fwd_d(const pen__shade_params *p, const double (*sh)[3],
                                 int sphere_count, const double *spheres, const double *kappa,
                                 const double x[3], const double n[3], const double *B,
                                 const double *F, const double rho[3], double rgb[3], double *fv);
void pen__shade_self_given_bwd(const pen__shade_params *p, const float (*sh)[3],
                               int sphere_count, const float *spheres, const float *kappa,
                               const float x[3], const float n[3], const float *B,
                               const float *F, const float rho[3], const float d_rgb[3],
                               double (*d_sh)[3], double *d_spheres, float d_x[3], float d_n[3],
                               float d_rho[3]);
void pen__shade_self_given_bwd_d(const pen__shade_params *p, const double (*sh)[3],
                                 int sphere_count, const double *spheres, const double *kappa,
                                 const double x[3], const double n[3], const double *B,
                                 const double *F, const double rho[3], const double d_rgb[3],
                                 double (*d_sh)[3], double *d_spheres, double d_x[3],
                                 double d_n[3], double d_rho[3]);

/* ---- Fast kernel (shade_fast.c, shade_fast_dispatch.c) -----------------------------------------
 * The same shading as pen__shade_fwd / pen__shade_bwd, for many pixels at once: pixels go in
 * batches of lanes through structure-of-arrays lane vectors (16 lanes: one AVX-512 register of
 * floats), with straight-line SH products generated per band count (src/sh/sh_fast_product_L.inc).
 * Supports bands 3..6, with shadows the CALIBRATED and PAPER exponentials, without shadows
 * (V == 1) every method (pen__shade_fast_supported); the renderer uses the scalar kernel for
 * anything else. kappa (may be NULL: all 1) scales
 * sphere i's log-visibility, F = sum_i w_i kappa_i f_i; it is not differentiated.
 * The kernel exists in one variant per instruction set; the functions below call the variant
 * chosen once per process (the widest the processor runs, or a lower one named by the environment
 * variable PEN_CPU: avx512, avx2, sse2). Lane count, store layout and sums differ between variants:
 * a forward and its backward must run with the same one. */

/* Clock ticks spent in the stages of a fast call, added to by each call (for the renderer's
 * stage timings; only ratios of ticks are meaningful). Inline: the kernel reads it per batch. */
typedef struct pen__shade_fast_ticks {
    unsigned long long visibility, exp;
} pen__shade_fast_ticks;
#if defined(__x86_64__) || defined(__i386__)
static inline unsigned long long pen__shade_fast_now(void) {
    return (unsigned long long)__builtin_ia32_rdtsc();
}
#else
#include <omp.h>
static inline unsigned long long pen__shade_fast_now(void) {
    return (unsigned long long)(omp_get_wtime() * 1e9);
}
#endif

int pen__shade_fast_supported(const pen__shade_params *p);
/* Floats per pixel of the forward's store (F, for the backward), in whole batches: a call with
 * `count` pixels needs pen__shade_fast_store_floats(p, count) floats. */
size_t pen__shade_fast_store_floats(const pen__shade_params *p, int count);
/* Pixel j's F (bands^2 floats) from the store of a forward call (batches of lanes, F_k of a
 * batch's lanes side by side). */
void pen__shade_fast_store_pixel(const pen__shade_params *p, const float *store, int j, float *F);
/* Bytes of per-thread scratch for calls of up to max_count pixels. */
size_t pen__shade_fast_scratch_bytes(const pen__shade_params *p, int sphere_count, int max_count);
/* count pixels, AoS: x, n, rho and rgb 3 floats per pixel; the first `ground` of them lie on the
 * ground plane (n = +Y; their d_x and d_n are not wanted), which saves batches of them the
 * per-pixel product. store (may be NULL) receives what the backward needs when shadows are on.
 * ticks may be NULL. */
void pen__shade_fast_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, float *rgb,
                         float *store, void *scratch, pen__shade_fast_ticks *ticks);
/* Backward of the same call: ADDS into d_sh, d_spheres (double; summed over the call's pixels
 * in a fixed order), and per pixel into d_x, d_n, d_rho (3 floats per pixel; for the ground
 * pixels d_x and d_n are unspecified); any may be NULL. store: the forward's, or NULL to
 * recompute. */
void pen__shade_fast_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                         const float *spheres, const float *kappa, int count, int ground,
                         const float *x, const float *n, const float *rho, const float *d_rgb,
                         const float *store, void *scratch, double (*d_sh)[3], double *d_spheres,
                         float *d_x, float *d_n, float *d_rho, pen__shade_fast_ticks *ticks);

/* One variant: its entry points (the functions above without the dispatch), exported by each
 * compilation of shade_fast.c as pen__shade_fast_ops_<name>. */
typedef struct pen__shade_fast_ops {
    const char *name; /* "avx512", "avx2", "sse2" or "generic" (not x86) */
    int lanes;
    size_t (*store_floats)(const pen__shade_params *p, int count);
    size_t (*scratch_bytes)(const pen__shade_params *p, int sphere_count, int max_count);
    void (*fwd)(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                const float *spheres, const float *kappa, int count, int ground, const float *x,
                const float *n, const float *rho, float *rgb, float *store, void *scratch,
                pen__shade_fast_ticks *ticks);
    void (*bwd)(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                const float *spheres, const float *kappa, int count, int ground, const float *x,
                const float *n, const float *rho, const float *d_rgb, const float *store,
                void *scratch, double (*d_sh)[3], double *d_spheres, float *d_x, float *d_n,
                float *d_rho, pen__shade_fast_ticks *ticks);
} pen__shade_fast_ops;

/* Test and benchmark hooks. Variants are numbered widest first, 0 .. pen__shade_fast_variants()-1;
 * pen__shade_fast_variant_ops(v) is variant v's table, or NULL when this processor cannot run it.
 * pen__shade_fast_use(v) makes v the one in use (returns 0 when it cannot run here); not while
 * another thread renders. pen__shade_fast_current() is the one in use. */
int pen__shade_fast_variants(void);
const pen__shade_fast_ops *pen__shade_fast_variant_ops(int v);
int pen__shade_fast_use(int v);
const pen__shade_fast_ops *pen__shade_fast_current(void);

/* ---- Frame: what the files of the full frame share --------------------------------------------
 * Who calls whom: forward.c calls state.c, tiles.c, background.c, ground.c, lights.c, self.c and
 * ground_shadow.c; backward.c calls state.c, tiles.c, ground.c, lights.c, self.c and
 * ground_shadow.c; self.c and ground_shadow.c call state.c, lights.c and the scalar kernel (and
 * src/geometry's transfer); background.c calls tiles.c and
 * state.c; tiles.c calls state.c (pen__buf_grow, behind PEN__BUF_RESERVE, is state.c's) and
 * lights.c (the tile's sphere cull); ground.c calls lights.c (the disks' horizon factors);
 * state.c and lights.c call no other file of the frame. */
#include "geometry/lattice.h" /* the self transfer's nodes */
#include "penumbra/render.h" /* the state's options, view, G-buffer and timings */

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h> /* free, in PEN__BUF_FREE */
#include <string.h> /* memcpy, in pen__tile_ws_push */

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
     * pixel, negative: the grid's), for this camera: keyed by the grid's key and the ground
     * pixels' points. */
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
    pen__shade_params params;
    pen__lights lights; /* the frame's disk lights (lights.c) */
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
    PEN__BUF(size_t) tile_off;   /* the fast store's layout per tile (pen__tile_store_layout) */
    PEN__BUF(pen__tile_groups) groups; /* per tile, of the last forward */
    pen__buf_float fv; /* scalar kernel: F and V per pixel (2 bands^2); fast: its store, per tile */
    int fv_valid;      /* the forward kept fv (only with shadows on: without, nothing is kept) */
    pen__buf_float lights_V; /* the disk lights' visibilities, lights.count per pixel */
    int lights_V_valid;      /* the forward kept lights_V (a state, shadows on, lights) */
    int fast;          /* the forward used the fast kernel */
    PEN__BUF(double) rows;      /* the backward's double accumulators, one block per tile */
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
};

/* ---- state.c ---- */

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
/* Shades pixel i of object o (pen__self_object) into st->color: the SH part with the transfer and
 * the other objects' spheres, then the disk lights with the mesh's own unblocked fractions in
 * place of the horizon factors. sh: the scene's lighting (not the object's `seen`: with a ground
 * that occludes, the transfer traces the ground). fv: the scalar store's F and V for the pixel, or
 * NULL. V: the lights' visibilities to keep, or NULL. */
void pen__self_shade_fwd(pen_render_state *st, const float (*sh)[3], int ncull, const int *cull,
                         size_t i, float *fv, float *V);
struct pen__tile_ws; /* a thread's workspace (tiles.c, below) */
/* The same for the fast kernel's frames: a run's transfer pixels pix[0 .. count - 1] (in the
 * run's order), their other spheres' sum F by pen__shade_fast_fwd with each object's kappa_self
 * (compacted per object into ws), the rest per pixel as above. Within float rounding of
 * pen__self_shade_fwd (the sum's order differs), not bit for bit. F: where to keep each pixel's F
 * for the backward (bands^2 floats each, in pix order), or NULL. */
void pen__self_shade_fast_fwd(pen_render_state *st, const float (*sh)[3], int ncull,
                              const int *cull, const int *pix, int count, struct pen__tile_ws *ws,
                              float *F, pen__shade_fast_ticks *tk);
/* Its backward (either forward), the arguments as pen__shade_bwd and pen__lights_bwd. F: the
 * pixel's F kept by pen__self_shade_fast_fwd (then fv is NULL), or NULL. */
void pen__self_shade_bwd(const pen_render_state *st, const float (*sh)[3], int ncull,
                         const int *cull, size_t i, const float *dc, const float *fv,
                         const float *F, const float *V, double (*d_sh)[3], double *d_sph,
                         float *d_x, float *d_n, float *d_rho, double *d_lights);

/* ---- ground_shadow.c ---- */

/* Decides whether the ground's pixels shade with the grid this frame (a ground, shadow.
 * ground_shadow "transfer", some object with its transfer on: after pen__self_prepare) and brings
 * the grid's cache up to date (traced only when its key changed). */
pen_status pen__ground_shadow_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st);
/* Whether pixel i is shaded by the grid (a ground pixel of a frame with it on). */
static inline int pen__ground_shadow_pixel(const pen_render_state *st, size_t i) {
    return st->grid.on && st->gb.surface[i] == PEN_SURFACE_GROUND;
}
/* Shades ground pixel i into st->color: the SH part with the grid's transfer and the other
 * objects' spheres, then the disk lights with the grid's unblocked fractions. The arguments as
 * pen__self_shade_fwd. */
void pen__ground_shadow_fwd(pen_render_state *st, const float (*sh)[3], int ncull, const int *cull,
                            size_t i, float *fv, float *V);
/* Its backward (no d_x, d_n: the ground's pixels have none). */
void pen__ground_shadow_bwd(const pen_render_state *st, const float (*sh)[3], int ncull,
                            const int *cull, size_t i, const float *dc, const float *fv,
                            const float *V, double (*d_sh)[3], double *d_sph, float *d_rho,
                            double *d_lights);

/* ---- tiles.c ---- */

/* Milliseconds since the omp_get_wtime() t0. */
double pen__render_ms_since(double t0);

/* A thread's workspace for one tile: the tile's shaded pixels compacted (pixel index, x, n, rho,
 * the kernel's output or d_colour, and the backward's per-pixel results), and the fast kernel's
 * scratch. Allocated once per state and reused, so the pixel loops do not allocate. */
typedef struct pen__tile_ws {
    int *idx;
    float *x, *n, *rho, *out, *dx, *dn, *drho; /* 3 floats per compacted pixel */
    int *cull; /* the spheres that may shadow a disk light in the tile (pen__tile_lights_cull) */
    int *cand, *ncand; /* per receiver of a block, its own of them (pen__lights_candidates) */
    float *fstore;     /* a fast call's store for up to PEN_TILE_PX pixels (self.c's F) */
    void *kernel;
} pen__tile_ws;

/* Sizes st->ws for `threads` workspaces; *bytes: one workspace's size. */
pen_status pen__tile_ws_reserve(pen_context *ctx, pen_render_state *st, int threads, size_t *bytes);

/* Appends surface pixel i (index, x, n, rho) as the j-th compacted pixel. */
static inline void pen__tile_ws_push(pen__tile_ws *ws, int j, const pen_render_state *st,
                                     size_t i) {
    ws->idx[j] = (int)i;
    memcpy(ws->x + 3 * j, st->x.data + 3 * i, 3 * sizeof(float));
    memcpy(ws->n + 3 * j, st->n.data + 3 * i, 3 * sizeof(float));
    memcpy(ws->rho + 3 * j, st->rho.data + 3 * i, 3 * sizeof(float));
}

int pen__tile_count(const pen_render_state *st);
/* The spheres that may shadow a disk light at some shaded pixel of tile t (pen__lights_cull over
 * the box of the pixels' points), into ws->cull; returns their count. */
int pen__tile_lights_cull(const pen_render_state *st, int t, pen__tile_ws *ws);
/* Pixel rectangle [x0, x1) x [y0, y1) of tile t. */
void pen__tile_rect(const pen_render_state *st, int t, int *x0, int *y0, int *x1, int *y1);

/* Per-thread stage ticks of a pixel loop, summed over threads. */
typedef struct pen__loop_ticks {
    unsigned long long visibility, exp, total;
} pen__loop_ticks;

/* Runs fn on every tile, threads over tiles with dynamic scheduling (small frames on the calling
 * thread), each thread with its own workspace (ws_bytes each, pen__tile_ws_reserve); returns the
 * threads' summed stage ticks. */
typedef void (*pen__tile_fn)(const void *job, int t, pen__tile_ws *ws, pen__shade_fast_ticks *tk);
pen__loop_ticks pen__tiles_run(pen_render_state *st, int threads, size_t ws_bytes, pen__tile_fn fn,
                               const void *job);
/* A stage's share of a loop's wall time. */
double pen__stage_ms(double loop_ms, unsigned long long stage, unsigned long long total);

/* A pass over the tiles: store is the fast kernel's store (tile t's part at tile_off[t]) or the
 * scalar kernel's per-pixel F and V (tile_off NULL), or NULL when nothing is kept; bw is the
 * backward's request (backward.c; NULL in the forward). */
struct pen__bwd_want;
typedef struct pen__tile_job {
    const pen_scene *sc;
    pen_render_state *st;
    const struct pen__bwd_want *bw;
    float *store;
    const size_t *tile_off;
} pen__tile_job;

/* Tile t's part of the job's store, or NULL. */
float *pen__tile_store_of(const pen__tile_job *job, int t);
/* Groups the shaded pixels of tile t into st->groups (a pen__tile_fn on a pen__tile_job: the
 * forward runs it over the tiles in parallel before shading). */
void pen__tile_group(const void *job, int t, pen__tile_ws *ws, pen__shade_fast_ticks *tk);
/* Run r of tile t (as pen__tile_group made it): its pixels pix[0 .. count - 1]; returns its
 * group. */
int pen__tile_run(const pen_render_state *st, int t, int r, const int **pix, int *count);
/* The object whose own `seen` lighting group g shades with, or -1 for the scene's lighting. */
int pen__tile_group_object(const pen_render_state *st, int g);
/* The lighting of group g. */
const float (*pen__tile_group_lighting(const pen_scene *sc, const pen_render_state *st, int g))[3];
/* Floats of the fast store for a run of count pixels: the kernel's batches of the pixels it
 * shades, then, in a frame with transfer pixels, their F (self.c) one pixel after another. */
size_t pen__tile_run_store(const pen_render_state *st, int count);
/* Where each tile's part of the fast kernel's store begins (ntiles + 1 offsets in floats). */
pen_status pen__tile_store_layout(pen_context *ctx, pen_render_state *st, int ntiles);

/* ---- background.c ---- */

/* Decides st->bg_use for this frame and fills the environment-map cache when it is stale; never
 * fails the render (without memory for the cache the background is computed per pixel). */
void pen__background_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st);
/* Background pixel i at (px, py) into st->color, through the cache when there is one. */
void pen__background_pixel(const pen_scene *sc, const pen_render_state *st, int px, int py,
                           size_t i);

/* ---- ground.c ---- */

/* Sets st->ground_occludes and, when set, each object's `seen` lighting and its derivative, and
 * (st->lights initialised) each object's horizon factors of the disk lights. */
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
