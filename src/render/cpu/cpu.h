/* Internal interface of the CPU backend (src/render/cpu, render/backend.h): the tile scheduler
 * (tiles.c), the tiles' shading forward (shade_fwd.c) and backward with the reduction
 * (shade_bwd.c), and the pixels shaded with a traced transfer (transfer_shade.c). These are the
 * only files of the renderer that call the kernels (src/shade) or start threads for them;
 * scripts/check_layers.py holds the frame to that.
 * Who calls whom: backend.c calls shade_fwd.c and shade_bwd.c; they call tiles.c and
 * transfer_shade.c (which uses tiles.c's workspace inline); all of them call the frame's
 * state.c, footprint.c, background.c, ground.c, self.c and ground_shadow.c for their data, never
 * forward.c or backward.c. */
#ifndef PEN_RENDER_CPU_H
#define PEN_RENDER_CPU_H

#include "render/render_internal.h"

#include <string.h> /* memcpy, in pen__tile_ws_push */

/* ---- shade_fwd.c, shade_bwd.c: the backend's stages (backend.h) ---- */

pen_status pen__cpu_prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                            pen_render_state *st);
pen_status pen__cpu_shade_fwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                              pen_render_state *st, int keep);
pen_status pen__cpu_shade_bwd(pen_context *ctx, const pen_scene *sc, pen_render_state *st,
                              unsigned wrt);
pen_status pen__cpu_reduce(pen_context *ctx, const pen_scene *sc, pen_render_state *st,
                           unsigned wrt, pen_render_grad *grad);

/* ---- tiles.c ---- */

/* A thread's workspace for one tile: the tile's shaded pixels compacted (pixel index, x, n, rho,
 * the kernel's output or d_colour, and the backward's per-pixel results), and the fast kernel's
 * scratch. Allocated once per state and reused, so the pixel loops do not allocate. */
typedef struct pen__tile_ws {
    int *idx;
    float *x, *n, *rho, *out, *dx, *dn, *drho; /* 3 floats per compacted pixel */
    int *cull; /* the spheres that may shadow a disk light in the tile (pen__tile_lights_cull) */
    int *cand, *ncand; /* per receiver of a block, its own of them (pen__lights_candidates) */
    float *fstore; /* a fast call's store for up to PEN_TILE_PX pixels (the transfer pixels' F) */
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
 * backward's request (shade_bwd.c; NULL in the forward). */
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
 * shades, then, in a frame with transfer pixels, their F (transfer_shade.c) one pixel
 * after another. */
size_t pen__tile_run_store(const pen_render_state *st, int count);
/* Where each tile's part of the fast kernel's store begins (ntiles + 1 offsets in floats). */
pen_status pen__tile_store_layout(pen_context *ctx, pen_render_state *st, int ntiles);

/* ---- transfer_shade.c ---- */

/* Shades pixel i of object o (pen__self_object) into st->color: the SH part with the transfer and
 * the other objects' spheres, then the disk lights with the mesh's own unblocked fractions in
 * place of the horizon factors. sh: the scene's lighting (not the object's `seen`: with a ground
 * that occludes, the transfer traces the ground). fv: the scalar store's F and V for the pixel, or
 * NULL. V: the lights' visibilities to keep, or NULL. */
void pen__self_shade_fwd(pen_render_state *st, const float (*sh)[3], int ncull, const int *cull,
                         size_t i, float *fv, float *V);
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

#endif
