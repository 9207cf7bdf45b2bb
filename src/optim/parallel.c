/* Views in parallel (docs/optimize.md, "Several views"): several views of one process rendered
 * at once by a set of workers, and the views of a task split across processes (pen_optim_ranks).
 *
 * The rule that makes both bitwise reproducible: a view's loss and gradient are computed alone,
 * into a buffer of their own (the gradient flattened to a float vector here), and the sum over
 * the views runs afterwards, in view order, over those buffers. A view's buffer does not depend
 * on which worker or rank computed it (the renderer's results do not depend on its thread count:
 * its reductions run in tile order), so neither does the sum: one process in turn, several views
 * at once, or any split across ranks give the same bits.
 *
 * Workers: with W > 1 views at once, an OpenMP loop over the views hands each to a thread, which
 * renders it with its own context (threads: the caller's / W, which OpenMP grants only when
 * nesting is on; else 1) and its own gradient struct. W = 1 keeps the caller's context: each
 * view in turn with every thread. Rendering views at once pays where a render alone does not
 * keep the threads busy: its serial parts (posing, rasterization setup, the backward's scatter),
 * small images, and threads that wait at the render's barriers on a loaded machine (the
 * measurements are in docs/optimize.md). The automatic choice takes W = T (the thread count)
 * when the process has at least T views, or nesting is on; with fewer views and nesting off,
 * W = min(T, views) would leave threads idle, so the views go in turn with every thread.
 *
 * Ranks: the views taking part are cut into contiguous blocks of nearly equal size (the first
 * n mod size ranks get one more); after each pass every rank's block is gathered on every rank
 * (pen_optim_ranks.allgather: MPI_Allgatherv under the CLI). */
#include "optim/optim_internal.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* ---- A render gradient as a flat vector ------------------------------------------------------ */

/* A stretch of floats of a gradient struct. */
typedef struct span {
    float *p;
    size_t n;
} span;

/* The stretches of g that the groups in `wrt` fill and the optimizer reads (params.c's gather),
 * in a fixed order; returns how many (out: room for 3 + 5 * objects). */
static int spans(const pen_render_grad *g, unsigned wrt, span *out) {
    pen_render_grad *m = (pen_render_grad *)g; /* (spans of a const struct are only read) */
    int k = 0;
    if (wrt & PEN_GRAD_LIGHTING)
        out[k++] = (span){&m->sh[0][0], 3 * (size_t)g->bands * (size_t)g->bands};
    if (wrt & PEN_GRAD_LIGHTS) /* pen_light: PEN_LIGHT_FLOATS floats (params.c checks) */
        out[k++] = (span){m->lights[0].direction, PEN_LIGHT_FLOATS * (size_t)g->light_count};
    if (wrt & PEN_GRAD_ALBEDO) out[k++] = (span){m->ground_albedo, 3};
    for (int o = 0; o < g->object_count; ++o) {
        pen_object_grad *og = &m->objects[o];
        if (wrt & PEN_GRAD_ALBEDO) {
            out[k++] = (span){og->albedo, 3};
            if (og->texture) out[k++] = (span){og->texture, 3 * (size_t)og->texel_count};
        }
        if (wrt & PEN_GRAD_POSE)
            out[k++] = (span){og->pose.rotation_axis_angle_deg, sizeof(pen_pose) / sizeof(float)};
        if (wrt & PEN_GRAD_SPHERES) out[k++] = (span){og->spheres, 4 * (size_t)og->sphere_count};
        if (wrt & PEN_GRAD_VERTICES) out[k++] = (span){og->positions, 3 * (size_t)og->vertex_count};
    }
    return k;
}

/* Applies f to every span of g (a stack array for scenes of up to 64 objects, else the heap). */
static pen_status each_span(pen_context *ctx, const pen_render_grad *g, unsigned wrt,
                            void (*f)(void *user, const span *sp), void *user) {
    span local[3 + 5 * 64], *sp = local;
    if (g->object_count > 64 &&
        !(sp = pen__malloc(ctx, 3 + 5 * (size_t)g->object_count, sizeof *sp, "gradient")))
        return PEN_ERROR_MEMORY;
    const int n = spans(g, wrt, sp);
    for (int k = 0; k < n; ++k)
        f(user, &sp[k]);
    if (sp != local) free(sp);
    return PEN_OK;
}

typedef struct cursor {
    float *v;
    size_t at;
} cursor;

static void count_span(void *user, const span *sp) {
    ((cursor *)user)->at += sp->n;
}
static void pack_span(void *user, const span *sp) {
    cursor *c = user;
    memcpy(c->v + c->at, sp->p, sizeof(float) * sp->n);
    c->at += sp->n;
}
static void add_span(void *user, const span *sp) {
    cursor *c = user;
    for (size_t i = 0; i < sp->n; ++i)
        sp->p[i] += c->v[c->at + i];
    c->at += sp->n;
}

pen_status pen__optim_grad_floats(pen_context *ctx, const pen_render_grad *g, unsigned wrt,
                                  size_t *n) {
    cursor c = {NULL, 0};
    pen_status s = each_span(ctx, g, wrt, count_span, &c);
    *n = c.at;
    return s;
}

pen_status pen__optim_grad_pack(pen_context *ctx, const pen_render_grad *g, unsigned wrt,
                                float *v) {
    cursor c = {v, 0};
    return each_span(ctx, g, wrt, pack_span, &c);
}

pen_status pen__optim_grad_add(pen_context *ctx, pen_render_grad *g, unsigned wrt, const float *v) {
    cursor c = {(float *)v, 0};
    return each_span(ctx, g, wrt, add_span, &c);
}

/* ---- Ranks ----------------------------------------------------------------------------------- */

void pen__optim_block(int n, int rank, int size, int *lo, int *hi) {
    const int q = n / size, extra = n % size;
    *lo = rank * q + (rank < extra ? rank : extra);
    *hi = *lo + q + (rank < extra ? 1 : 0);
}

pen_status pen__optim_exchange(pen_context *ctx, const pen_optim_ranks *ranks, int n, void *items,
                               size_t item_bytes) {
    if (!ranks || ranks->size <= 1 || item_bytes == 0) return PEN_OK;
    int *counts = pen__malloc(ctx, (size_t)ranks->size, sizeof *counts, "ranks");
    if (!counts) return PEN_ERROR_MEMORY;
    for (int r = 0; r < ranks->size; ++r) {
        int lo, hi;
        pen__optim_block(n, r, ranks->size, &lo, &hi);
        counts[r] = hi - lo;
    }
    const int failed = ranks->allgather(ranks->user, items, counts, item_bytes);
    free(counts);
    return failed ? pen__error(ctx, PEN_ERROR_INTERNAL,
                               "optimize: rank %d: gathering the views' results across ranks "
                               "failed",
                               ranks->rank)
                  : PEN_OK;
}

/* ---- Workers --------------------------------------------------------------------------------- */

void pen__optim_workers_free(pen__optim_workers *W) {
    for (int w = 0; w < W->count; ++w) {
        if (W->ctx) pen_context_destroy(W->ctx[w]);
        if (W->grad) pen_render_grad_free(&W->grad[w]);
    }
    free(W->ctx);
    free(W->grad);
    memset(W, 0, sizeof *W);
}

pen_status pen__optim_workers_init(pen_context *ctx, pen__optim_workers *W, int requested,
                                   int views, const pen_scene *sc) {
    memset(W, 0, sizeof *W);
    const int threads = pen__threads(ctx);
    int count = requested;
    if (count <= 0) /* automatic: see the top of the file */
        count = views >= threads || omp_get_max_active_levels() > 1 ? threads : 1;
    if (count > views) count = views;
    if (count < 1) count = 1;
    W->ctx = pen__calloc(ctx, (size_t)count, sizeof *W->ctx, "view workers");
    W->grad = pen__calloc(ctx, (size_t)count, sizeof *W->grad, "view workers");
    if (!W->ctx || !W->grad) {
        pen__optim_workers_free(W);
        return PEN_ERROR_MEMORY;
    }
    W->count = count;
    pen_status s = PEN_OK;
    for (int w = 0; !s && w < count; ++w) {
        s = pen_render_grad_create(ctx, sc, &W->grad[w]);
        if (s || count == 1) continue; /* one worker: the caller's context */
        if (!(W->ctx[w] = pen_context_create())) {
            s = pen__error(ctx, PEN_ERROR_MEMORY, "out of memory (view workers)");
            break;
        }
        pen_context_set_threads(W->ctx[w], threads / count > 1 ? threads / count : 1);
        pen_context_set_fit_cache(W->ctx[w], pen_context_fit_cache(ctx));
    }
    if (s) pen__optim_workers_free(W);
    return s;
}

pen_status pen__optim_workers_run(pen_context *ctx, pen__optim_workers *W, int lo, int hi,
                                  pen__optim_view_job job, void *user) {
    if (W->count <= 1 || hi - lo <= 1) {
        for (int j = lo; j < hi; ++j) {
            pen_status s = job(ctx, user, j, &W->grad[0]);
            if (s) return s;
        }
        return PEN_OK;
    }
    const int n = hi - lo;
    pen_status *status = pen__calloc(ctx, (size_t)n, sizeof *status, "view workers");
    int *by = pen__calloc(ctx, (size_t)n, sizeof *by, "view workers");
    if (!status || !by) {
        free(status);
        free(by);
        return PEN_ERROR_MEMORY;
    }
#pragma omp parallel for num_threads(W->count) schedule(dynamic, 1)
    for (int j = 0; j < n; ++j) {
        const int w = omp_get_thread_num();
        by[j] = w;
        status[j] = job(W->ctx[w], user, lo + j, &W->grad[w]);
    }
    pen_status s = PEN_OK;
    for (int j = 0; j < n && !s; ++j) /* the first failure in view order */
        if (status[j]) s = pen__error(ctx, status[j], "%s", pen_context_error(W->ctx[by[j]]));
    free(status);
    free(by);
    return s;
}
