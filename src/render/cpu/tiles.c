/* The CPU backend's tile scheduler: 16 x 16 screen tiles, the threads' workspaces, and each
 * tile's shaded pixels sorted into lighting groups.
 *
 * Design
 * - A tile is the unit of parallel work (threads take tiles with dynamic scheduling: the cost of a
 *   tile follows how much of it is surface), of the fast kernel's calls (its batches are a
 *   group's pixels, compacted into the thread's workspace), and of the backward's double
 *   accumulators, which are reduced in tile order so that gradients do not depend on the
 *   thread count. Frames smaller than PEN_RENDER_PARALLEL_MIN_PIXELS stay on the calling thread.
 * - Lighting groups: the kernels shade a tile's pixels in groups that share one lighting: the
 *   ground's (group 0), then the objects' (group 1 for all of them, or 1 + o per object o with
 *   ground occlusion, whose objects see their own lighting: ground.c). Background pixels belong to
 *   none. pen__tile_group sorts each tile once per forward; the forward's shading, the fast
 *   store's layout and the backward all read the same runs, so the store's batches line up.
 * - Stage timings: the fast kernel counts clock ticks per stage; each pass sums them over its
 *   threads and splits its wall time in their ratios (pen__stage_ms).
 */
#include "core/internal.h"
#include "render/cpu/cpu.h"

#include <math.h>
#include <omp.h>
#include <string.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

/* ---- Workspaces ------------------------------------------------------------------------------ */

static size_t tile_ws_bytes(const pen__shade_params *p, int spheres) {
    const size_t b = sizeof(int) * PEN_TILE_PX + 7 * 3 * sizeof(float) * PEN_TILE_PX +
                     sizeof(int) * (size_t)spheres * (1 + PEN_LIGHTS_BLOCK) +
                     sizeof(int) * PEN_LIGHTS_BLOCK +
                     sizeof(float) * pen__shade_fast_store_floats(p, PEN_TILE_PX) +
                     pen__shade_fast_scratch_bytes(p, spheres, PEN_TILE_PX);
    return (b + 127) & ~(size_t)127; /* threads' blocks on separate cache lines */
}

pen_status pen__tile_ws_reserve(pen_context *ctx, pen_render_state *st, int threads,
                                size_t *bytes) {
    *bytes = tile_ws_bytes(&st->params, st->sphere_count);
    return PEN__BUF_RESERVE(ctx, st->ws, *bytes * (size_t)threads, "render workspaces");
}

/* The calling thread's workspace. */
static pen__tile_ws tile_ws_at(pen_render_state *st, size_t bytes, int spheres) {
    const size_t fstore = pen__shade_fast_store_floats(&st->params, PEN_TILE_PX);
    const int tid = omp_get_thread_num();
    unsigned char *b = st->ws.data + bytes * (size_t)tid;
    pen__tile_ws w;
    w.idx = (int *)b;
    float *f = (float *)(b + sizeof(int) * PEN_TILE_PX);
    w.x = f, w.n = f + 3 * PEN_TILE_PX, w.rho = f + 6 * PEN_TILE_PX, w.out = f + 9 * PEN_TILE_PX;
    w.dx = f + 12 * PEN_TILE_PX, w.dn = f + 15 * PEN_TILE_PX, w.drho = f + 18 * PEN_TILE_PX;
    w.cull = (int *)(f + 21 * PEN_TILE_PX);
    w.cand = w.cull + spheres;
    w.ncand = w.cand + (size_t)spheres * PEN_LIGHTS_BLOCK;
    w.fstore = (float *)(w.ncand + PEN_LIGHTS_BLOCK);
    w.kernel = w.fstore + fstore; /* the kernel's scratch is float data: 4 bytes */
    return w;
}

/* ---- Tiles and the parallel loop ------------------------------------------------------------- */

void pen__tile_rect(const pen_render_state *st, int t, int *x0, int *y0, int *x1, int *y1) {
    const int tiles_x = (st->width + PEN_TILE - 1) / PEN_TILE;
    *x0 = (t % tiles_x) * PEN_TILE, *y0 = (t / tiles_x) * PEN_TILE;
    *x1 = *x0 + PEN_TILE < st->width ? *x0 + PEN_TILE : st->width;
    *y1 = *y0 + PEN_TILE < st->height ? *y0 + PEN_TILE : st->height;
}

int pen__tile_lights_cull(const pen_render_state *st, int t, pen__tile_ws *ws) {
    const pen__tile_groups *tg = &st->groups.data[t];
    const int n = tg->runs ? tg->end[tg->runs - 1] : 0;
    if (n == 0) return 0;
    /* the box in float (a NaN coordinate left out, as fmin / fmax would), then widened exactly:
     * the same box as one taken in double, without a libm call per coordinate */
    float flo[3] = {INFINITY, INFINITY, INFINITY}, fhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    int k = 0;
#if defined(__SSE__)
    /* A pixel's point in one 4-lane load (its fourth lane, the next pixel's, is ignored; the
     * image's last pixel, which has no next, goes below): minps (a < b ? a : b) and maxps are
     * the scalar selects lane by lane, so the box has the same bits. */
    const int last = st->width * st->height - 1;
    __m128 lo4 = _mm_set1_ps(INFINITY), hi4 = _mm_set1_ps(-INFINITY);
    for (; k < n; ++k) {
        if (tg->pix[k] == last) break;
        const __m128 x4 = _mm_loadu_ps(st->x.data + 3 * (size_t)tg->pix[k]);
        lo4 = _mm_min_ps(x4, lo4), hi4 = _mm_max_ps(x4, hi4);
    }
    float l4[4], h4[4];
    _mm_storeu_ps(l4, lo4), _mm_storeu_ps(h4, hi4);
    for (int a = 0; a < 3; ++a)
        flo[a] = l4[a], fhi[a] = h4[a];
#endif
    for (; k < n; ++k) {
        const float *x = st->x.data + 3 * (size_t)tg->pix[k];
        for (int a = 0; a < 3; ++a) {
            flo[a] = x[a] < flo[a] ? x[a] : flo[a];
            fhi[a] = x[a] > fhi[a] ? x[a] : fhi[a];
        }
    }
    const double lo[3] = {(double)flo[0], (double)flo[1], (double)flo[2]};
    const double hi[3] = {(double)fhi[0], (double)fhi[1], (double)fhi[2]};
    return pen__lights_cull(&st->lights, st->sphere_count, st->spheres.data, lo, hi, ws->cull);
}

int pen__tile_count(const pen_render_state *st) {
    return ((st->width + PEN_TILE - 1) / PEN_TILE) * ((st->height + PEN_TILE - 1) / PEN_TILE);
}

static void loop_ticks_add(pen__loop_ticks *sum, const pen__shade_fast_ticks *tk,
                           unsigned long long total) {
/* Unnamed: a named critical section is a global symbol (.gomp_critical_user_NAME) that the shared
 * library would export; this one runs once per thread and pass, so sharing libgomp's default lock
 * costs nothing. */
#pragma omp critical
    {
        sum->visibility += tk->visibility;
        sum->exp += tk->exp;
        sum->total += total;
    }
}

pen__loop_ticks pen__tiles_run(pen_render_state *st, int threads, size_t ws_bytes, pen__tile_fn fn,
                               const void *job) {
    pen__loop_ticks lt = {0, 0, 0};
    const int ntiles = pen__tile_count(st);
#pragma omp parallel num_threads(threads) if (st->width * st->height >=                            \
                                              PEN_RENDER_PARALLEL_MIN_PIXELS)
    {
        pen__tile_ws ws = tile_ws_at(st, ws_bytes, st->sphere_count);
        pen__shade_fast_ticks tk = {0, 0};
        const unsigned long long start = pen__shade_fast_now();
#pragma omp for schedule(dynamic, 1) nowait
        for (int t = 0; t < ntiles; ++t)
            fn(job, t, &ws, &tk);
        loop_ticks_add(&lt, &tk, pen__shade_fast_now() - start);
    }
    return lt;
}

double pen__stage_ms(double loop_ms, unsigned long long stage, unsigned long long total) {
    return total ? loop_ms * (double)stage / (double)total : 0.0;
}

/* ---- Lighting groups ------------------------------------------------------------------------- */

float *pen__tile_store_of(const pen__tile_job *job, int t) {
    return job->store && job->tile_off ? job->store + job->tile_off[t] : NULL;
}

/* The group of a pixel showing surface `surf` (-1: none). */
static int pixel_group(const pen_render_state *st, int surf) {
    if (surf == PEN_SURFACE_BACKGROUND) return -1;
    if (surf == PEN_SURFACE_GROUND) return 0;
    return st->ground_occludes ? 1 + surf : 1;
}

/* The ground's group, and every group without ground occlusion, shade with the scene's lighting. */
int pen__tile_group_object(const pen_render_state *st, int g) {
    return st->ground_occludes && g > 0 ? g - 1 : -1;
}

const float (*pen__tile_group_lighting(const pen_scene *sc, const pen_render_state *st, int g))[3] {
    const int o = pen__tile_group_object(st, g);
    return o >= 0 ? (const float(*)[3])st->obj[o].seen : (const float(*)[3])sc->lighting.sh;
}

/* The tile's shaded pixels in row order first, their runs of one group marked on the way; then,
 * only when a pixel of a lower group follows a higher one (an object over the ground), a stable
 * sort by group and the runs again: a counting sort over the few groups a tile holds, or (groups
 * far apart: ground occlusion's per-object groups) an insertion sort, which costs a * b moves
 * for a pixels of one group above b of a lower one. */
void pen__tile_group(const void *job_, int t, pen__tile_ws *ws, pen__shade_fast_ticks *tk) {
    (void)ws, (void)tk;
    const pen_render_state *st = ((const pen__tile_job *)job_)->st;
    pen__tile_groups *tg = &st->groups.data[t];
    int x0, y0, x1, y1, n = 0, grp[PEN_TILE_PX], prev = INT32_MIN, unsorted = 0;
    pen__tile_rect(st, t, &x0, &y0, &x1, &y1);
    const int occludes = st->ground_occludes;
    tg->runs = 0, tg->store = 0; /* each run is one kernel call, its pixels in whole batches */
    for (int py = y0; py < y1; ++py) {
        const size_t row = (size_t)py * (size_t)st->width;
        const int32_t *surf = st->gb.surface + row;
        for (int px = x0; px < x1; ++px) {
            const int32_t s = surf[px];
            if (s == PEN_SURFACE_BACKGROUND) continue;
            const int g = s == PEN_SURFACE_GROUND ? 0 : occludes ? 1 + s : 1; /* pixel_group */
            if (g != prev) { /* a run ends here, if the pixels are in order */
                unsorted |= g < prev;
                if (n) tg->end[tg->runs++] = n;
                prev = g;
            }
            tg->pix[n] = (int)(row + (size_t)px), grp[n++] = g;
        }
    }
    if (n) tg->end[tg->runs++] = n;
    if (unsorted) {
        int lo = grp[0], hi = grp[0];
        for (int k = 1; k < n; ++k)
            lo = grp[k] < lo ? grp[k] : lo, hi = grp[k] > hi ? grp[k] : hi;
        if (hi - lo < 64) {
            int start[65] = {0}, pix[PEN_TILE_PX];
            for (int k = 0; k < n; ++k)
                ++start[grp[k] - lo + 1];
            for (int g = 0; g < hi - lo; ++g)
                start[g + 1] += start[g];
            memcpy(pix, tg->pix, sizeof(int) * (size_t)n);
            for (int k = 0; k < n; ++k)
                tg->pix[start[grp[k] - lo]++] = pix[k];
            for (int g = 0, k = 0; g <= hi - lo; ++g)
                for (; k < start[g]; ++k)
                    grp[k] = g + lo;
        } else {
            for (int j = 1; j < n; ++j) {
                const int p = tg->pix[j], g = grp[j];
                int k = j;
                for (; k > 0 && grp[k - 1] > g; --k)
                    tg->pix[k] = tg->pix[k - 1], grp[k] = grp[k - 1];
                tg->pix[k] = p, grp[k] = g;
            }
        }
        tg->runs = 0;
        for (int a = 0, b; a < n; a = b) {
            for (b = a; b < n && grp[b] == grp[a]; ++b) {
            }
            tg->end[tg->runs++] = b;
        }
    }
    for (int r = 0; r < tg->runs; ++r)
        tg->store += pen__tile_run_store(st, tg->end[r] - (r ? tg->end[r - 1] : 0));
}

size_t pen__tile_run_store(const pen_render_state *st, int count) {
    /* The kernel's batches of the run's other pixels, then F of its transfer pixels one after
     * another: store_floats(nk) + (count - nk) bands^2 < store_floats(count) + one batch. */
    return pen__shade_fast_store_floats(&st->params, count) +
           (st->self_any ? pen__shade_fast_store_floats(&st->params, 1) : 0);
}

int pen__tile_run(const pen_render_state *st, int t, int r, const int **pix, int *count) {
    const pen__tile_groups *tg = &st->groups.data[t];
    const int a = r > 0 ? tg->end[r - 1] : 0;
    *pix = tg->pix + a, *count = tg->end[r] - a;
    return pixel_group(st, st->gb.surface[tg->pix[a]]);
}

pen_status pen__tile_store_layout(pen_context *ctx, pen_render_state *st, int ntiles) {
    pen_status s = PEN__BUF_RESERVE(ctx, st->tile_off, (size_t)ntiles + 1, "store layout");
    if (s) return s;
    size_t *off = st->tile_off.data;
    off[0] = 0;
    for (int t = 0; t < ntiles; ++t)
        off[t + 1] = off[t] + st->groups.data[t].store;
    return PEN_OK;
}
