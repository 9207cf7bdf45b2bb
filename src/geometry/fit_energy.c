/* The fit's energy, forward and backward (fit.c has the method; fit_internal.h the problem):
 * eqs. 2-5 of the supplement over the outside voxels and the surface samples, culled per cell of
 * points against the spheres that can reach it. The gradient test (tests/test_fit.c) checks it on
 * its own, against finite differences in double precision.
 */
#include "geometry/fit_internal.h"

#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* ---- Energy: forward and backward -----------------------------------------------------------
 * Which spheres can reach which cell is found once per evaluation by binning: the cells' bounding
 * balls sit in a uniform grid (built once), and each sphere visits only the grid cells its reach
 * sqrt(r^2 + u_max sigma^2) overlaps, in sphere order, so every cell's list is in sphere order and
 * the terms are exactly those of testing every sphere against every cell. With thousands of
 * spheres this is what keeps an evaluation near linear in the spheres rather than cells x spheres.
 * Each cell sums its energy and its gradient (one entry per sphere in its list) on its own; the
 * cells are then added in cell order, so the result does not depend on the thread count. */

struct pen__fit_work {
    int sov_cells, cells; /* cells of the outside voxels, of both sets (a set without cells: 1) */
    pen__grid grid;       /* the bounded cells' boxes */
    int *stamp;           /* per cell: the last sphere that visited it */
    uint8_t *held;        /* per cell: some sphere holds all of it */
    long *start;          /* cells + 1 offsets into near */
    int *near;            /* spheres per cell, in sphere order */
    double *gnear;        /* 4 per near entry: the cell's gradient of that sphere */
    double *ecell;        /* per cell: its energy */
    long capacity;        /* entries near and gnear hold */
    int unbounded[2], n_unbounded; /* the cells of sets without cells */
    int max_near;
};

/* The bound (centre, radius) of cell c of the problem, or NULL for a set without cells. */
static const double *cell_bound(const pen__fit_problem *p, const pen__fit_work *w, int c) {
    if (c < w->sov_cells) return p->sov.cells ? p->sov.cell_bound + 4 * (size_t)c : NULL;
    c -= w->sov_cells;
    return p->surf.cells ? p->surf.cell_bound + 4 * (size_t)c : NULL;
}

static void cell_points(const pen__fit_points *pts, int c, long *begin, long *end) {
    *begin = pts->cells ? pts->cell_start[c] : 0;
    *end = pts->cells ? pts->cell_start[c + 1] : pts->count;
}

void pen__fit_work_free(pen__fit_work *w) {
    if (!w) return;
    pen__grid_free(&w->grid);
    free(w->stamp), free(w->held), free(w->start), free(w->near), free(w->gnear), free(w->ecell);
    free(w);
}

pen_status pen__fit_work_create(pen_context *ctx, const pen__fit_problem *p, pen__fit_work **out) {
    *out = NULL;
    pen__fit_work *w = pen__calloc(ctx, 1, sizeof *w, "fit: energy scratch");
    if (!w) return PEN_ERROR_MEMORY;
    w->sov_cells = p->sov.cells ? p->sov.cells : 1;
    w->cells = w->sov_cells + (p->surf.cells ? p->surf.cells : 1);
    const size_t n = (size_t)w->cells + 1;
    w->stamp = pen__malloc(ctx, n, sizeof(int), "fit: energy scratch");
    w->held = pen__malloc(ctx, n, 1, "fit: energy scratch");
    w->start = pen__malloc(ctx, n, sizeof(long), "fit: energy scratch");
    w->ecell = pen__malloc(ctx, n, sizeof(double), "fit: energy scratch");
    double *boxes = pen__malloc(ctx, n, 6 * sizeof(double), "fit: energy scratch");
    pen_status st = w->stamp && w->held && w->start && w->ecell && boxes ? PEN_OK : PEN_ERROR_MEMORY;
    /* Unbounded cells get an empty box (they take every sphere and are not in the grid). */
    double mean = 0;
    int bounded = 0;
    for (int c = 0; !st && c < w->cells; ++c) {
        const double *b = cell_bound(p, w, c);
        for (int a = 0; a < 3; ++a) {
            boxes[6 * (size_t)c + a] = b ? b[a] - b[3] : HUGE_VAL;
            boxes[6 * (size_t)c + 3 + a] = b ? b[a] + b[3] : -HUGE_VAL;
        }
        if (b)
            mean += 2 * b[3], ++bounded;
        else
            w->unbounded[w->n_unbounded++] = c;
    }
    /* An unbounded cell's box is empty (low > high): the grid leaves it out. */
    if (!st && bounded > 0) {
        st = pen__grid_build(ctx, boxes, w->cells, fmax(mean / bounded, 1e-300), &w->grid);
    }
    free(boxes);
    if (st) {
        pen__fit_work_free(w);
        return st;
    }
    *out = w;
    return PEN_OK;
}

/* Lists, per cell, the spheres that can reach it (and flags the cells a sphere holds whole). */
static pen_status bin_spheres(const pen__fit_problem *p, pen__fit_work *w, int count,
                              const double *sph) {
    const double margin2 = p->u_max / p->inv_sigma2;
    for (int pass = 0; pass < 2; ++pass) {
        for (int c = 0; c < w->cells; ++c)
            w->stamp[c] = -1;
        if (pass == 0) {
            memset(w->held, 0, (size_t)w->cells);
            memset(w->start, 0, sizeof(long) * ((size_t)w->cells + 1));
        }
        for (int i = 0; i < count; ++i) {
            const double *s = sph + 4 * (size_t)i;
            const double reach = sqrt(s[3] * s[3] + margin2);
            /* Unbounded cells (a set without cells) take every sphere. */
            for (int k = 0; k < w->n_unbounded; ++k) {
                const int c = w->unbounded[k];
                if (pass == 0)
                    ++w->start[c + 1];
                else
                    w->near[w->start[c]++] = i;
            }
            if (!w->grid.start) continue;
            int lo[3], hi[3];
            const double a[3] = {s[0] - reach, s[1] - reach, s[2] - reach};
            const double b[3] = {s[0] + reach, s[1] + reach, s[2] + reach};
            if (!pen__grid_range(&w->grid, a, b, lo, hi)) continue;
            for (int z = lo[2]; z <= hi[2]; ++z)
                for (int y = lo[1]; y <= hi[1]; ++y)
                    for (int x = lo[0]; x <= hi[0]; ++x) {
                        long m;
                        const int *items = pen__grid_cell(&w->grid, x, y, z, &m);
                        for (long e = 0; e < m; ++e) {
                            const int c = items[e];
                            if (w->stamp[c] == i || w->held[c]) continue;
                            w->stamp[c] = i;
                            const double *bd = cell_bound(p, w, c);
                            if (!bd) continue;
                            const double dx = bd[0] - s[0], dy = bd[1] - s[1], dz = bd[2] - s[2];
                            const double d = sqrt(dx * dx + dy * dy + dz * dz);
                            if (d + bd[3] <= s[3]) { /* holds the whole cell */
                                if (pass == 0) w->held[c] = 1;
                                continue;
                            }
                            if (d - bd[3] >= reach) continue;
                            if (pass == 0)
                                ++w->start[c + 1];
                            else
                                w->near[w->start[c]++] = i;
                        }
                    }
        }
        if (pass == 0) {
            w->max_near = 0;
            for (int c = 0; c < w->cells; ++c) {
                if (w->held[c]) w->start[c + 1] = 0;
                w->max_near = (int)fmax(w->max_near, (double)w->start[c + 1]);
                w->start[c + 1] += w->start[c];
            }
            const long need = w->start[w->cells] + 1;
            if (need > w->capacity) {
                free(w->near), free(w->gnear);
                w->capacity = need + need / 2;
                w->near = malloc(sizeof(int) * (size_t)w->capacity);
                w->gnear = malloc(4 * sizeof(double) * (size_t)w->capacity);
                if (!w->near || !w->gnear) {
                    w->capacity = 0;
                    return PEN_ERROR_MEMORY;
                }
            }
        }
    }
    /* start[c] is now the end of cell c: turn it back into offsets. */
    for (int c = w->cells; c > 0; --c)
        w->start[c] = w->start[c - 1];
    w->start[0] = 0;
    return PEN_OK;
}

/* Per-thread scratch: one point's active factors. */
typedef struct point_scratch {
    int *idx;
    double *os, *suffix;
} point_scratch;

/* One point's term and, when grad != NULL, its gradient times d_E added into grad[4 k] for the
 * k-th sphere of near[0..n_near). g is dE/dP for this point (-1 outside voxel, w_s surface
 * sample); the term is 1 - P for an outside voxel, w_s P for a surface sample. */
static double point_term(const pen__fit_problem *p, const double *sph, const int *near, int n_near,
                         const float *x, double g, double d_E, point_scratch *sc, double *grad) {
    double px = (double)x[0], py = (double)x[1], pz = (double)x[2];
    int m = 0;
    for (int k = 0; k < n_near; ++k) {
        const double *s = sph + 4 * near[k];
        double dx = px - s[0], dy = py - s[1], dz = pz - s[2];
        double u = (dx * dx + dy * dy + dz * dz - s[3] * s[3]) * p->inv_sigma2;
        if (u <= 0) return g < 0 ? 1 : 0; /* contained: P = 0, and no gradient (relu flat) */
        if (u < p->u_max) {
            sc->idx[m] = k;
            sc->os[m] = tanh(u);
            ++m;
        }
    }
    double P = 1;
    for (int a = 0; a < m; ++a)
        P *= sc->os[a];
    if (grad && m > 0) {
        sc->suffix[m] = 1;
        for (int a = m - 1; a >= 0; --a)
            sc->suffix[a] = sc->suffix[a + 1] * sc->os[a];
        double prefix = 1;
        for (int a = 0; a < m; ++a) {
            double os = sc->os[a];
            double du = g * d_E * prefix * sc->suffix[a + 1] * (1 - os * os) * p->inv_sigma2;
            prefix *= os;
            const double *s = sph + 4 * near[sc->idx[a]];
            double *gr = grad + 4 * sc->idx[a];
            gr[0] -= 2 * du * (px - s[0]);
            gr[1] -= 2 * du * (py - s[1]);
            gr[2] -= 2 * du * (pz - s[2]);
            gr[3] -= 2 * du * s[3];
        }
    }
    return g < 0 ? 1 - P : g * P;
}

/* The whole energy; with d_spheres, also its gradient. */
static double energy_eval(const pen__fit_problem *p, int count, const double *sph, double d_E,
                          double *d_spheres) {
    pen__fit_work *w = p->work;
    if (!w && pen__fit_work_create(NULL, p, &w)) return (double)NAN; /* the caller reports it */
    double E = (double)NAN;
    if (bin_spheres(p, w, count, sph)) goto done;
    const int threads = pen__threads_resolve(p->threads);
    double pairs = 0;
    for (int c = 0; c < w->cells; ++c) {
        long begin, end;
        cell_points(c < w->sov_cells ? &p->sov : &p->surf,
                    c < w->sov_cells ? c : c - w->sov_cells, &begin, &end);
        pairs += (double)(end - begin) * (double)(w->start[c + 1] - w->start[c]);
    }
    int failed = 0;
#pragma omp parallel num_threads(threads) if (pairs >= p->serial_pairs) reduction(| : failed)
    {
        point_scratch sc;
        const size_t m = (size_t)w->max_near + 1;
        sc.idx = malloc(sizeof(int) * m);
        sc.os = malloc(sizeof(double) * m);
        sc.suffix = malloc(sizeof(double) * (m + 1));
        failed = !sc.idx || !sc.os || !sc.suffix;
#pragma omp for schedule(dynamic, 8)
        for (int c = 0; c < w->cells; ++c) {
            if (failed) continue;
            const int sov = c < w->sov_cells;
            const pen__fit_points *pts = sov ? &p->sov : &p->surf;
            const double g = sov ? -1 : p->surface_weight;
            long begin, end;
            cell_points(pts, sov ? c : c - w->sov_cells, &begin, &end);
            const int n_near = (int)(w->start[c + 1] - w->start[c]);
            if (w->held[c] || n_near == 0) {
                /* held: every P = 0; no sphere near: every P = 1 */
                w->ecell[c] = (w->held[c] ? g < 0 : g > 0) ? fabs(g) * (double)(end - begin) : 0;
                continue;
            }
            const int *near = w->near + w->start[c];
            double *gc = d_spheres ? w->gnear + 4 * w->start[c] : NULL;
            if (gc) memset(gc, 0, 4 * sizeof(double) * (size_t)n_near);
            double e = 0;
            for (long j = begin; j < end; ++j)
                e += point_term(p, sph, near, n_near, pts->xyz + 3 * j, g, d_E, &sc, gc);
            w->ecell[c] = e;
        }
        free(sc.idx);
        free(sc.os);
        free(sc.suffix);
    }
    if (failed) goto done;
    E = 0;
    for (int c = 0; c < w->cells; ++c)
        E += w->ecell[c];
    if (d_spheres)
        for (int c = 0; c < w->cells; ++c) {
            if (w->held[c]) continue;
            for (long e = w->start[c]; e < w->start[c + 1]; ++e)
                for (int a = 0; a < 4; ++a)
                    d_spheres[4 * (size_t)w->near[e] + a] += w->gnear[4 * e + a];
        }
done:
    if (w != p->work) pen__fit_work_free(w);
    return E;
}

double pen__fit_energy_fwd(const pen__fit_problem *p, int count, const double *spheres) {
    return energy_eval(p, count, spheres, 0, NULL);
}

double pen__fit_energy_bwd(const pen__fit_problem *p, int count, const double *spheres, double d_E,
                           double *d_spheres) {
    return energy_eval(p, count, spheres, d_E, d_spheres);
}
