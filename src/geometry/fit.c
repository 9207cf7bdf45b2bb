/* Sphere-set fit: Adam on the Sphere-Outside-Volume energy plus surface coverage (supplement
 * sec. 2, eqs. 1-5).
 *
 * Energy. For a point x and sphere i, s_i = |x - c_i|^2 - r_i^2 and u_i = s_i / sigma^2;
 * Os_i = phi(s_i) = tanh(relu(u_i)) (eq. 2). A point's product P = prod_i Os_i is 0 as soon as one
 * sphere contains it and is 1 where every sphere is far (tanh saturated). The outside voxels
 * (Og = 1) add 1 - P each (eq. 3, the inside voxels have Og = 0 and drop out), the surface samples
 * add w_s P each (eq. 4). The sum is eq. 5. Inside a sphere relu is flat, so a point that some
 * sphere contains adds nothing to any gradient: the energy acts through the soft margin just
 * outside each sphere, where tanh rises from 0 towards 1. That is why sigma matters: with
 * sigma^2 = 2 r_N kappa h (r_N the radius of `count` equal spheres holding the mesh's volume, h the
 * voxel edge, kappa the margin setting), a sphere of radius r_N has u = 1 about kappa voxels
 * outside its surface, whatever the mesh's units.
 *
 * Gradient (analytic). Only spheres with 0 < u_i < u_max touch a point (u >= u_max means tanh == 1
 * to the working precision and a zero derivative). With P_{-i} the product of the other factors
 * (prefix and suffix products, no division, so a tiny factor costs no precision):
 *     dE/dc_i = g P_{-i} (1 - Os_i^2) (-2 (x - c_i)) / sigma^2,
 *     dE/dr_i = g P_{-i} (1 - Os_i^2) (-2 r_i) / sigma^2,
 * with g = -1 for an outside voxel and g = w_s for a surface sample.
 *
 * Optimization. k-means++ seeding and a few Lloyd steps on the inside voxel centres place the
 * spheres; a centre that falls outside the mesh moves to its cluster's member nearest to it; the
 * radius is the distance to the nearest surface sample (the sphere starts inscribed). Adam then
 * moves centres and radii with a step given in voxel edges that decays by a cosine; radii are
 * kept above a quarter voxel so that no sphere collapses to a point. Spheres that no surface sample
 * needs are moved a few times early in the run ("Relocating idle spheres" below).
 */
#include "geometry/fit_internal.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Padding of the voxel grid around the mesh bounds, as a fraction of the longest extent per side:
 * spheres that cover the surface bulge out of the bounds, and SOV must be counted there too. */
#define FIT_PAD 0.12
#define FIT_LLOYD_STEPS 12
/* Loops of fewer than this many point-sphere pairs take a millisecond or less and run on one
 * thread: the energy runs once per Adam step, and waking a thread team that often cost more than
 * it saved (on a loaded 2-core machine, spinning barriers made the small test fits 15x slower). */
#define FIT_SERIAL_PAIRS 4e6
/* Cells of the energy's culling: bricks of FIT_BRICK^3 voxels. */
#define FIT_BRICK 4

static int parallel_worth(double pairs) {
    return pairs >= FIT_SERIAL_PAIRS;
}

void pen_fit_settings_default(pen_fit_settings *s) {
    s->voxels = 64;
    s->surface_weight = 7;
    s->margin_voxels = 0.25;
    s->samples_per_voxel_area = 1;
    s->iterations = 600;
    s->learning_rate = 0.5;
    s->seed = 1;
}

pen_status pen__fit_resolve_settings(pen_context *ctx, const pen_fit_settings *in,
                                     pen_fit_settings *s) {
    pen_fit_settings d;
    pen_fit_settings_default(&d);
    *s = in ? *in : d;
    if (s->voxels == 0) s->voxels = d.voxels;
    if (s->surface_weight == 0) s->surface_weight = d.surface_weight;
    if (s->margin_voxels == 0) s->margin_voxels = d.margin_voxels;
    if (s->samples_per_voxel_area == 0) s->samples_per_voxel_area = d.samples_per_voxel_area;
    if (s->iterations == 0) s->iterations = d.iterations;
    if (s->learning_rate == 0) s->learning_rate = d.learning_rate;
    if (s->voxels < 4 || s->voxels > PEN_FIT_MAX_VOXELS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: voxels %d out of range [4, %d]", s->voxels,
                          PEN_FIT_MAX_VOXELS);
    if (!(s->surface_weight > 0 && s->surface_weight <= 1e6))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: surface weight %g out of range (0, 1e6]",
                          s->surface_weight);
    if (!(s->margin_voxels > 0 && s->margin_voxels <= 100))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: margin %g voxels out of range (0, 100]",
                          s->margin_voxels);
    if (!(s->samples_per_voxel_area > 0 && s->samples_per_voxel_area <= 100))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "fit: samples per voxel area %g out of range (0, 100]",
                          s->samples_per_voxel_area);
    if (s->iterations < 0 || s->iterations > 1000000)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: iterations %d out of range [0, 1e6]",
                          s->iterations);
    if (!(s->learning_rate > 0 && s->learning_rate <= 100))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: learning rate %g out of range (0, 100]",
                          s->learning_rate);
    return PEN_OK;
}

/* ---- Energy: forward and backward ----------------------------------------------------------- */

/* Per-thread scratch: the spheres that can reach a cell, and one point's active factors. */
typedef struct point_scratch {
    int *near;
    int *idx;
    double *os, *suffix;
} point_scratch;

/* One point's term and, when grad != NULL, its gradient times d_E added into grad. Only the
 * spheres near[0..n_near) can reach the point. g is dE/dP for this point (-1 outside voxel, w_s
 * surface sample); the term is 1 - P for an outside voxel, w_s P for a surface sample. */
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
            sc->idx[m] = near[k];
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
            const double *s = sph + 4 * sc->idx[a];
            double *gr = grad + 4 * sc->idx[a];
            gr[0] -= 2 * du * (px - s[0]);
            gr[1] -= 2 * du * (py - s[1]);
            gr[2] -= 2 * du * (pz - s[2]);
            gr[3] -= 2 * du * s[3];
        }
    }
    return g < 0 ? 1 - P : g * P;
}

/* One cell's terms. A sphere farther from every point of the cell than sqrt(r^2 + u_max sigma^2)
 * has u >= u_max there, a factor of exactly 1 that point_term would skip anyway; a sphere that
 * holds the whole cell zeroes every product. */
static double cell_terms(const pen__fit_problem *p, const pen__fit_points *pts, int cell, int count,
                         const double *sph, double g, double d_E, point_scratch *sc, double *grad) {
    long begin = pts->cells ? pts->cell_start[cell] : 0;
    long end = pts->cells ? pts->cell_start[cell + 1] : pts->count;
    int n_near = 0;
    for (int i = 0; i < count; ++i) {
        if (pts->cells) {
            const double *b = pts->cell_bound + 4 * cell, *s = sph + 4 * i;
            double dx = b[0] - s[0], dy = b[1] - s[1], dz = b[2] - s[2];
            double d = sqrt(dx * dx + dy * dy + dz * dz);
            if (d + b[3] <= s[3]) return g < 0 ? (double)(end - begin) : 0;
            double reach = sqrt(s[3] * s[3] + p->u_max / p->inv_sigma2);
            if (d - b[3] >= reach) continue;
        }
        sc->near[n_near++] = i;
    }
    double e = 0;
    if (n_near == 0) return g < 0 ? 0 : g * (double)(end - begin);
    for (long j = begin; j < end; ++j)
        e += point_term(p, sph, sc->near, n_near, pts->xyz + 3 * j, g, d_E, sc, grad);
    return e;
}

/* The whole energy; with d_spheres, also its gradient. Threads sum into their own buffers, added
 * in thread order afterwards, so a run is reproducible for a given thread count. */
static double energy_eval(const pen__fit_problem *p, int count, const double *sph, double d_E,
                          double *d_spheres) {
    int threads = pen__threads_resolve(p->threads);
    int sov_cells = p->sov.cells ? p->sov.cells : 1;
    int total = sov_cells + (p->surf.cells ? p->surf.cells : 1);
    double *partial = calloc((size_t)threads, sizeof(double));
    double *grads = d_spheres ? calloc((size_t)threads * 4 * count, sizeof(double)) : NULL;
    if (!partial || (d_spheres && !grads)) {
        free(partial);
        free(grads);
        return (double)NAN; /* the caller reports it */
    }
    int failed = 0;
    double pairs = ((double)p->sov.count + (double)p->surf.count) * count;
#pragma omp parallel num_threads(threads) if (pairs >= p->serial_pairs) reduction(| : failed)
    {
        int t = omp_get_thread_num();
        point_scratch sc;
        sc.near = malloc(sizeof(int) * (size_t)count);
        sc.idx = malloc(sizeof(int) * (size_t)count);
        sc.os = malloc(sizeof(double) * (size_t)count);
        sc.suffix = malloc(sizeof(double) * ((size_t)count + 1));
        failed = !sc.near || !sc.idx || !sc.os || !sc.suffix;
        double *g = grads ? grads + (size_t)t * 4 * count : NULL;
        double e = 0;
#pragma omp for schedule(static, 8)
        for (int c = 0; c < total; ++c) {
            if (failed) continue;
            if (c < sov_cells)
                e += cell_terms(p, &p->sov, c, count, sph, -1, d_E, &sc, g);
            else
                e += cell_terms(p, &p->surf, c - sov_cells, count, sph, p->surface_weight, d_E, &sc,
                                g);
        }
        partial[t] = e;
        free(sc.near);
        free(sc.idx);
        free(sc.os);
        free(sc.suffix);
    }
    double E = 0;
    for (int t = 0; t < threads; ++t)
        E += partial[t];
    if (grads)
        for (int t = 0; t < threads; ++t)
            for (int k = 0; k < 4 * count; ++k)
                d_spheres[k] += grads[(size_t)t * 4 * count + k];
    free(partial);
    free(grads);
    return failed ? (double)NAN : E;
}

double pen__fit_energy_fwd(const pen__fit_problem *p, int count, const double *spheres) {
    return energy_eval(p, count, spheres, 0, NULL);
}

double pen__fit_energy_bwd(const pen__fit_problem *p, int count, const double *spheres, double d_E,
                           double *d_spheres) {
    return energy_eval(p, count, spheres, d_E, d_spheres);
}

/* ---- Initialization ----------------------------------------------------------------------- */

static double dist2(const float *a, const double *b) {
    double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
    return dx * dx + dy * dy + dz * dz;
}

/* Nearest centre of every point (parallel). */
static void assign(const float *pts, long n_pts, const double *centres, int k, int threads,
                   int *label) {
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)n_pts * k))               \
    schedule(static)
    for (long j = 0; j < n_pts; ++j) {
        double best = (double)INFINITY;
        int bi = 0;
        for (int i = 0; i < k; ++i) {
            double d = dist2(pts + 3 * j, centres + 4 * i);
            if (d < best) best = d, bi = i;
        }
        label[j] = bi;
    }
}

/* k-means++ seeding and Lloyd steps on the inside voxel centres; centres go to sph[4 i + 0..2]. */
static pen_status kmeans(pen_context *ctx, const float *pts, long n_pts, int k, uint64_t seed,
                         int threads, double *sph) {
    double *d2 = pen__malloc(ctx, (size_t)n_pts, sizeof(double), "fit: k-means distances");
    int *label = pen__malloc(ctx, (size_t)n_pts, sizeof(int), "fit: k-means labels");
    double *acc = pen__malloc(ctx, (size_t)k, 4 * sizeof(double), "fit: k-means sums");
    if (!d2 || !label || !acc) {
        free(d2), free(label), free(acc);
        return PEN_ERROR_MEMORY;
    }
    uint64_t rng = seed;
    long first = (long)(pen__splitmix_uniform(&rng) * (double)n_pts);
    for (int a = 0; a < 3; ++a)
        sph[a] = (double)pts[3 * first + a];
    for (long j = 0; j < n_pts; ++j)
        d2[j] = dist2(pts + 3 * j, sph);
    for (int i = 1; i < k; ++i) {
        double sum = 0;
        for (long j = 0; j < n_pts; ++j)
            sum += d2[j];
        double x = pen__splitmix_uniform(&rng) * sum;
        long pick = n_pts - 1;
        for (long j = 0; j < n_pts; ++j)
            if ((x -= d2[j]) < 0) {
                pick = j;
                break;
            }
        for (int a = 0; a < 3; ++a)
            sph[4 * i + a] = (double)pts[3 * pick + a];
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)n_pts)) schedule(static)
        for (long j = 0; j < n_pts; ++j)
            d2[j] = fmin(d2[j], dist2(pts + 3 * j, sph + 4 * i));
    }
    for (int step = 0; step < FIT_LLOYD_STEPS; ++step) {
        assign(pts, n_pts, sph, k, threads, label);
        memset(acc, 0, sizeof(double) * 4 * (size_t)k);
        for (long j = 0; j < n_pts; ++j) {
            double *a = acc + 4 * label[j];
            for (int c = 0; c < 3; ++c)
                a[c] += (double)pts[3 * j + c];
            a[3] += 1;
        }
        for (int i = 0; i < k; ++i)
            if (acc[4 * i + 3] > 0)
                for (int a = 0; a < 3; ++a)
                    sph[4 * i + a] = acc[4 * i + a] / acc[4 * i + 3];
    }
    /* A mean of a bent cluster can lie outside the mesh: move it to the nearest member. */
    assign(pts, n_pts, sph, k, threads, label);
    for (int i = 0; i < k; ++i)
        acc[4 * i + 3] = (double)INFINITY;
    for (long j = 0; j < n_pts; ++j) {
        int i = label[j];
        double d = dist2(pts + 3 * j, sph + 4 * i);
        if (d < acc[4 * i + 3]) {
            acc[4 * i + 3] = d;
            for (int a = 0; a < 3; ++a)
                acc[4 * i + a] = (double)pts[3 * j + a];
        }
    }
    for (int i = 0; i < k; ++i)
        if (acc[4 * i + 3] < (double)INFINITY)
            for (int a = 0; a < 3; ++a)
                sph[4 * i + a] = acc[4 * i + a];
    free(d2), free(label), free(acc);
    return PEN_OK;
}

/* Radius of each sphere: the distance from its centre to the nearest surface sample. */
static void inscribe(const float *surf, int n_surf, int k, double r_min, int threads, double *sph) {
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)n_surf * k))              \
    schedule(static)
    for (int i = 0; i < k; ++i) {
        double best = (double)INFINITY;
        for (int j = 0; j < n_surf; ++j)
            best = fmin(best, dist2(surf + 3 * (size_t)j, sph + 4 * i));
        sph[4 * i + 3] = fmax(sqrt(best), r_min);
    }
}

/* ---- Metrics ------------------------------------------------------------------------------ */

/* Points inside at least one sphere; with depth != NULL also the sum over those points of the
 * number of spheres that contain them. */
static long count_covered(const float *pts, long n_pts, const double *sph, int k, int threads,
                          long *depth) {
    long hits = 0, sum = 0;
    int team = parallel_worth((double)n_pts * k);
#pragma omp parallel for num_threads(threads) if (team) schedule(static) reduction(+ : hits, sum)
    for (long j = 0; j < n_pts; ++j) {
        int c = 0;
        for (int i = 0; i < k && (c == 0 || depth); ++i)
            c += dist2(pts + 3 * j, sph + 4 * i) <= sph[4 * i + 3] * sph[4 * i + 3];
        hits += c > 0;
        sum += c;
    }
    if (depth) *depth = sum;
    return hits;
}

int pen_fit_json(const pen_fit_settings *st, const pen_fit_metrics *m, char *buf, size_t size) {
    char settings[512] = "";
    if (st)
        snprintf(settings, sizeof settings,
                 ", \"fit_settings\": {\"voxels\": %d, \"surface_weight\": %.17g, "
                 "\"margin_voxels\": %.17g, \"samples_per_voxel_area\": %.17g, "
                 "\"iterations\": %d, \"learning_rate\": %.17g, \"seed\": %llu}",
                 st->voxels, st->surface_weight, st->margin_voxels, st->samples_per_voxel_area,
                 st->iterations, st->learning_rate, st->seed);
    return snprintf(buf, size,
                    "{\"metrics\": {\"sov_fraction\": %.6f, \"surface_coverage\": %.6f, "
                    "\"volume_coverage\": %.6f, \"mean_overlap\": %.4f, \"iterations\": %d, "
                    "\"seconds\": %.3f, "
                    "\"energy\": %.9g, \"grid\": [%d, %d, %d], \"inside_voxels\": %ld, "
                    "\"surface_samples\": %d}%s}",
                    m->sov_fraction, m->surface_coverage, m->volume_coverage, m->mean_overlap,
                    m->iterations, m->seconds, m->energy, m->grid[0], m->grid[1], m->grid[2],
                    m->inside_voxels, m->surface_samples, settings);
}

/* ---- The fit ------------------------------------------------------------------------------ */

/* Points sorted into cells, with the arrays a pen__fit_points borrows. */
typedef struct fit_cells {
    int cells;
    long *start;
    double *bound;
} fit_cells;

typedef struct fit_data {
    pen__fit_grid grid;
    float *inside_pts, *outside_pts, *surf_pts;
    long n_inside, n_outside;
    int n_surf;
    fit_cells outside_cells, surf_cells;
    double *sph, *grad, *m1, *m2;
    double *inside_dist, *gap; /* relocation: per inside voxel, per surface sample */
    int *excl;
    uint8_t *moved;
} fit_data;

static void fit_data_free(fit_data *d) {
    pen__fit_grid_free(&d->grid);
    free(d->inside_pts), free(d->outside_pts), free(d->surf_pts);
    free(d->sph), free(d->grad), free(d->m1), free(d->m2);
    free(d->inside_dist), free(d->gap), free(d->excl), free(d->moved);
    free(d->outside_cells.start), free(d->outside_cells.bound);
    free(d->surf_cells.start), free(d->surf_cells.bound);
}

/* Sorts points (in place, by a counting sort) into bricks of FIT_BRICK^3 voxels and bounds each
 * non-empty brick by the midpoint of its points' box and the largest distance to it. */
static pen_status build_cells(pen_context *ctx, const pen__fit_grid *g, float *pts, long n,
                              fit_cells *out) {
    int nb[3];
    for (int a = 0; a < 3; ++a)
        nb[a] = (g->n[a] + FIT_BRICK - 1) / FIT_BRICK;
    long bricks = (long)nb[0] * nb[1] * nb[2];
    long *key = pen__malloc(ctx, (size_t)n + 1, sizeof(long), "fit: cell keys");
    long *first = pen__calloc(ctx, (size_t)bricks + 1, sizeof(long), "fit: cell offsets");
    float *sorted = pen__malloc(ctx, (size_t)n + 1, 3 * sizeof(float), "fit: sorted points");
    if (!key || !first || !sorted) {
        free(key), free(first), free(sorted);
        return PEN_ERROR_MEMORY;
    }
    for (long j = 0; j < n; ++j) {
        long b[3];
        for (int a = 0; a < 3; ++a) {
            double f = ((double)pts[3 * j + a] - g->origin[a]) / g->h;
            long i = lround(fmin(fmax(f, 0), g->n[a] - 1));
            b[a] = i / FIT_BRICK;
        }
        key[j] = b[0] + nb[0] * (b[1] + nb[1] * b[2]);
        ++first[key[j] + 1];
    }
    int cells = 0;
    for (long b = 0; b < bricks; ++b) {
        cells += first[b + 1] > 0;
        first[b + 1] += first[b];
    }
    out->start = pen__malloc(ctx, (size_t)cells + 1, sizeof(long), "fit: cells");
    out->bound = pen__malloc(ctx, (size_t)cells + 1, 4 * sizeof(double), "fit: cell bounds");
    if (!out->start || !out->bound) {
        free(key), free(first), free(sorted);
        return PEN_ERROR_MEMORY;
    }
    for (long j = 0; j < n; ++j) {
        long at = first[key[j]]++;
        memcpy(sorted + 3 * at, pts + 3 * j, 3 * sizeof(float));
    }
    /* first[b] is now the end of brick b, which is the start of brick b + 1. */
    int c = 0;
    long begin = 0;
    for (long b = 0; b < bricks; ++b) {
        long end = first[b];
        if (end == begin) continue;
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (long j = begin; j < end; ++j)
            for (int a = 0; a < 3; ++a) {
                lo[a] = fmin(lo[a], (double)sorted[3 * j + a]);
                hi[a] = fmax(hi[a], (double)sorted[3 * j + a]);
            }
        double *bd = out->bound + 4 * c, r2 = 0;
        for (int a = 0; a < 3; ++a)
            bd[a] = 0.5 * (lo[a] + hi[a]);
        for (long j = begin; j < end; ++j)
            r2 = fmax(r2, dist2(sorted + 3 * j, bd));
        bd[3] = sqrt(r2) * (1 + 1e-12) + 1e-12 * g->h; /* enclose the points despite rounding */
        out->start[c++] = begin;
        begin = end;
    }
    out->start[c] = n;
    out->cells = cells;
    memcpy(pts, sorted, 3 * sizeof(float) * (size_t)n);
    free(key), free(first), free(sorted);
    return PEN_OK;
}

/* Voxelizes, splits the voxel centres into inside and outside lists, samples the surface. */
static pen_status prepare(pen_context *ctx, const pen_mesh *mesh, const pen_fit_settings *s,
                          int count, fit_data *d) {
    pen_status st = pen__fit_voxelize(ctx, mesh, s->voxels, FIT_PAD, &d->grid);
    if (st) return st;
    const pen__fit_grid *g = &d->grid;
    long total = (long)g->n[0] * g->n[1] * g->n[2];
    for (long v = 0; v < total; ++v)
        d->n_inside += g->inside[v];
    d->n_outside = total - d->n_inside;
    if (d->n_inside < count)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "fit: only %ld of %ld voxels are inside the mesh, fewer than %d spheres "
                          "(is the mesh closed? try more voxels)",
                          d->n_inside, total, count);
    d->inside_pts = pen__malloc(ctx, (size_t)d->n_inside, 3 * sizeof(float), "fit: inside voxels");
    d->outside_pts =
        pen__malloc(ctx, (size_t)d->n_outside + 1, 3 * sizeof(float), "fit: outside voxels");
    if (!d->inside_pts || !d->outside_pts) return PEN_ERROR_MEMORY;
    long ni = 0, no = 0;
    for (int k = 0; k < g->n[2]; ++k)
        for (int j = 0; j < g->n[1]; ++j)
            for (int i = 0; i < g->n[0]; ++i) {
                long v = i + (long)g->n[0] * (j + (long)g->n[1] * k);
                float *dst = g->inside[v] ? d->inside_pts + 3 * ni++ : d->outside_pts + 3 * no++;
                dst[0] = (float)(g->origin[0] + g->h * i);
                dst[1] = (float)(g->origin[1] + g->h * j);
                dst[2] = (float)(g->origin[2] + g->h * k);
            }
    /* The sample count follows the surface area in voxel faces, so that w_s weighs a surface
     * sample against a voxel the same way at every resolution. */
    double area = 0;
    float probe[3];
    st = pen__fit_sample_surface(ctx, mesh, 1, s->seed, probe, &area);
    if (st) return st;
    double want = s->samples_per_voxel_area * area / (g->h * g->h);
    d->n_surf = (int)fmin(fmax(want, 256), 4e6);
    d->surf_pts = pen__malloc(ctx, (size_t)d->n_surf, 3 * sizeof(float), "fit: surface samples");
    if (!d->surf_pts) return PEN_ERROR_MEMORY;
    st = pen__fit_sample_surface(ctx, mesh, d->n_surf, s->seed, d->surf_pts, &area);
    if (st) return st;
    st = build_cells(ctx, g, d->outside_pts, d->n_outside, &d->outside_cells);
    if (st) return st;
    return build_cells(ctx, g, d->surf_pts, d->n_surf, &d->surf_cells);
}

/* ---- Relocating idle spheres ---------------------------------------------------------------
 * A sphere that is the only cover of no surface sample lowers E by nothing and may add SOV; once
 * other spheres bury it its gradient is exactly zero (relu is flat inside every sphere), so Adam
 * can never move it again. A few times early in the run each such sphere moves to the surface
 * sample farthest outside the sphere set, as the largest inscribed ball through that sample (its
 * centre the inside voxel farthest from the sample whose distance to the surface is at least that
 * far, less a voxel); the gradient takes over from there. This is not in the supplement, which
 * does not say how its spheres were initialized; it is measured in docs/fit-spheres.md. */

/* Distance from each inside voxel centre to the nearest surface sample. */
static void inside_distances(fit_data *d, int threads) {
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)d->n_inside * d->n_surf)) \
    schedule(static)
    for (long j = 0; j < d->n_inside; ++j) {
        double best = (double)INFINITY;
        double c[3] = {d->inside_pts[3 * j], d->inside_pts[3 * j + 1], d->inside_pts[3 * j + 2]};
        for (int k = 0; k < d->n_surf; ++k)
            best = fmin(best, dist2(d->surf_pts + 3 * (size_t)k, c));
        d->inside_dist[j] = sqrt(best);
    }
}

/* Moves idle spheres; returns how many moved and flags them in moved[]. */
static int relocate_idle(fit_data *d, int count, double h, int threads, uint8_t *moved) {
    int *excl = d->excl;
    memset(excl, 0, sizeof(int) * (size_t)count);
    double *gap = d->gap;
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)d->n_surf * count))       \
    schedule(static)
    for (int j = 0; j < d->n_surf; ++j) {
        const float *p = d->surf_pts + 3 * (size_t)j;
        int covers = 0, who = -1;
        double g = (double)INFINITY;
        for (int i = 0; i < count; ++i) {
            double e = sqrt(dist2(p, d->sph + 4 * i)) - d->sph[4 * i + 3];
            g = fmin(g, e);
            if (e <= 0) ++covers, who = i;
        }
        gap[j] = g;
        if (covers == 1) {
#pragma omp atomic
            ++excl[who];
        }
    }
    int n_moved = 0;
    memset(moved, 0, (size_t)count);
    for (int i = 0; i < count; ++i) {
        if (excl[i] > 0) continue;
        int worst = -1;
        for (int j = 0; j < d->n_surf; ++j)
            if (gap[j] > 0.5 * h && (worst < 0 || gap[j] > gap[worst])) worst = j;
        if (worst < 0) break; /* the surface is covered: nothing to gain */
        const float *p = d->surf_pts + 3 * (size_t)worst;
        double pd[3] = {p[0], p[1], p[2]};
        long best = -1;
        double best_r = -1;
        for (long v = 0; v < d->n_inside; ++v) {
            double r = sqrt(dist2(d->inside_pts + 3 * v, pd));
            int fits = d->inside_dist[v] >= r - h;
            if (fits && r > best_r) best = v, best_r = r;
        }
        if (best < 0) continue;
        for (int a = 0; a < 3; ++a)
            d->sph[4 * i + a] = d->inside_pts[3 * best + a];
        d->sph[4 * i + 3] = best_r;
        moved[i] = 1;
        ++n_moved;
        for (int j = 0; j < d->n_surf; ++j)
            gap[j] =
                fmin(gap[j], sqrt(dist2(d->surf_pts + 3 * (size_t)j, d->sph + 4 * i)) - best_r);
    }
    return n_moved;
}

static void adam_run(const pen__fit_problem *p, const pen_fit_settings *s, double h, int count,
                     fit_data *d, int *iterations) {
    const double beta1 = 0.9, beta2 = 0.999, eps = 1e-12;
    double b1t = 1, b2t = 1;
    int n = 4 * count;
    int it = 0;
    for (; it < s->iterations; ++it) {
        memset(d->grad, 0, sizeof(double) * (size_t)n);
        pen__fit_energy_bwd(p, count, d->sph, 1, d->grad);
        double decay = 0.05 + 0.95 * 0.5 * (1 + cos(PEN_PI * it / s->iterations));
        double lr = s->learning_rate * h * decay;
        b1t *= beta1, b2t *= beta2;
        for (int k = 0; k < n; ++k) {
            d->m1[k] = beta1 * d->m1[k] + (1 - beta1) * d->grad[k];
            d->m2[k] = beta2 * d->m2[k] + (1 - beta2) * d->grad[k] * d->grad[k];
            double mh = d->m1[k] / (1 - b1t), vh = d->m2[k] / (1 - b2t);
            d->sph[k] -= lr * mh / (sqrt(vh) + eps);
        }
        for (int i = 0; i < count; ++i)
            d->sph[4 * i + 3] = fmax(d->sph[4 * i + 3], 0.25 * h);
        int checkpoint = s->iterations / 8;
        if (checkpoint > 0 && it > 0 && it % checkpoint == 0 && it <= 4 * checkpoint) {
            relocate_idle(d, count, h, p->threads, d->moved);
            for (int i = 0; i < count; ++i)
                if (d->moved[i])
                    for (int a = 0; a < 4; ++a)
                        d->m1[4 * i + a] = d->m2[4 * i + a] = 0;
        }
    }
    *iterations = it;
}

pen_status pen_spheres_fit(pen_context *ctx, const pen_mesh *mesh, int count,
                           const pen_fit_settings *settings, pen_spheres *out,
                           pen_fit_metrics *metrics) {
    double t0 = omp_get_wtime();
    if (out) memset(out, 0, sizeof *out);
    if (metrics) memset(metrics, 0, sizeof *metrics);
    if (!out) return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: no output sphere set");
    if (count < 1 || count > PEN_FIT_MAX_SPHERES)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: sphere count %d out of range [1, %d]",
                          count, PEN_FIT_MAX_SPHERES);
    pen_fit_settings s;
    pen_status st = pen__fit_resolve_settings(ctx, settings, &s);
    if (st) return st;
    int threads = pen__threads(ctx);

    fit_data d;
    memset(&d, 0, sizeof d);
    st = prepare(ctx, mesh, &s, count, &d);
    if (st) {
        fit_data_free(&d);
        return st;
    }
    double h = d.grid.h;
    size_t n = 4 * (size_t)count;
    d.sph = pen__calloc(ctx, n, sizeof(double), "fit: spheres");
    d.grad = pen__calloc(ctx, n, sizeof(double), "fit: gradient");
    d.m1 = pen__calloc(ctx, n, sizeof(double), "fit: Adam moments");
    d.m2 = pen__calloc(ctx, n, sizeof(double), "fit: Adam moments");
    d.inside_dist = pen__malloc(ctx, (size_t)d.n_inside, sizeof(double), "fit: distances");
    d.gap = pen__malloc(ctx, (size_t)d.n_surf, sizeof(double), "fit: gaps");
    d.excl = pen__malloc(ctx, (size_t)count, sizeof(int), "fit: exclusive counts");
    d.moved = pen__malloc(ctx, (size_t)count, 1, "fit: moved flags");
    if (!d.sph || !d.grad || !d.m1 || !d.m2 || !d.inside_dist || !d.gap || !d.excl || !d.moved) {
        fit_data_free(&d);
        return PEN_ERROR_MEMORY;
    }
    st = kmeans(ctx, d.inside_pts, d.n_inside, count, s.seed, threads, d.sph);
    if (st) {
        fit_data_free(&d);
        return st;
    }
    inscribe(d.surf_pts, d.n_surf, count, 0.5 * h, threads, d.sph);
    inside_distances(&d, threads);

    double volume = (double)d.n_inside * h * h * h;
    double r_n = cbrt(3 * volume / (4 * PEN_PI * count));
    pen__fit_problem p = {
        .sov = {d.n_outside, d.outside_pts, d.outside_cells.cells, d.outside_cells.start,
                d.outside_cells.bound},
        .surf = {d.n_surf, d.surf_pts, d.surf_cells.cells, d.surf_cells.start, d.surf_cells.bound},
        .surface_weight = s.surface_weight,
        .inv_sigma2 = 1 / (2 * r_n * s.margin_voxels * h),
        .u_max = PEN__FIT_U_FAST,
        .threads = threads,
        .serial_pairs = FIT_SERIAL_PAIRS,
    };
    int iterations = 0;
    adam_run(&p, &s, h, count, &d, &iterations);
    double energy = pen__fit_energy_fwd(&p, count, d.sph);
    if (!isfinite(energy)) {
        fit_data_free(&d);
        return pen__error(ctx, PEN_ERROR_MEMORY, "fit: energy evaluation ran out of memory");
    }
    st = pen_spheres_create(ctx, count, out);
    if (st) {
        fit_data_free(&d);
        return st;
    }
    for (size_t k = 0; k < n; ++k)
        out->data[k] = (float)d.sph[k];
    /* Overlap weights of the spheres as returned (pen_spheres.weight, overlap.c). */
    st = pen_spheres_ensure_weights(ctx, out);
    if (st) {
        pen_spheres_free(out);
        fit_data_free(&d);
        return st;
    }
    if (metrics) {
        /* Hard tests on the float spheres that are returned. */
        for (size_t k = 0; k < n; ++k)
            d.sph[k] = (double)out->data[k];
        long depth = 0;
        long in_cov = count_covered(d.inside_pts, d.n_inside, d.sph, count, threads, &depth);
        long out_cov = count_covered(d.outside_pts, d.n_outside, d.sph, count, threads, NULL);
        long surf_cov = count_covered(d.surf_pts, d.n_surf, d.sph, count, threads, NULL);
        metrics->mean_overlap = in_cov > 0 ? (double)depth / (double)in_cov : 0;
        metrics->sov_fraction = (double)out_cov / (double)d.n_inside;
        metrics->volume_coverage = (double)in_cov / (double)d.n_inside;
        metrics->surface_coverage = (double)surf_cov / d.n_surf;
        metrics->iterations = iterations;
        metrics->energy = energy;
        for (int a = 0; a < 3; ++a)
            metrics->grid[a] = d.grid.n[a];
        metrics->inside_voxels = d.n_inside;
        metrics->surface_samples = d.n_surf;
        metrics->seconds = omp_get_wtime() - t0;
    }
    fit_data_free(&d);
    return PEN_OK;
}
