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
 * radius is the distance to the nearest surface sample, at most 2 r_N (the sphere starts
 * inscribed). The allocation then moves spheres to parts the seeds left without (a chair's thin
 * frame beside its seat), from each surface sample's medial ball (fit_seed.c). Adam then moves
 * centres and radii with a step given in voxel edges that decays by a cosine; radii are kept
 * above a quarter voxel so that no sphere collapses to a point. Idle spheres, and parts left far
 * from every sphere, are seen to a few times early in the run (the Adam section below).
 *
 * Scale and threads. Every query of points against spheres goes through a uniform grid
 * (spatial.h): the energy bins the spheres into the cells they can reach, the metrics and the
 * allocation test a point against the spheres of its grid cell, so a fit of thousands of spheres
 * costs about linearly in the spheres. Sums run per cell (per point, per sphere) and are added in
 * a fixed order, so a fit gives the same spheres, bit for bit, on any number of threads.
 */
#include "geometry/fit_internal.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Padding of the voxel grid around the mesh bounds, as a fraction of the longest extent per side:
 * spheres that cover the surface bulge out of the bounds, and SOV must be counted there too. */
#define FIT_PAD 0.12
/* Loops of fewer than this many point-sphere pairs take a millisecond or less and run on one
 * thread: the energy runs once per Adam step, and waking a thread team that often cost more than
 * it saved (on a loaded 2-core machine, spinning barriers made the small test fits 15x slower). */
#define FIT_SERIAL_PAIRS 4e6
/* Cells of the energy's culling: bricks of FIT_BRICK^3 voxels. */
#define FIT_BRICK 4
/* The seeds' and relocated spheres' radius cap, in units of r_N (fit_seed.c). */
#define FIT_SEED_CAP 2.0
/* Parts thinner than FIT_THIN x the mesh's longest side count more in the allocation; the spread
 * leaves no sample more than max(FIT_SPREAD x that side, r_N) outside the spheres (less on thin
 * parts) where the budget allows (fit_seed.c, docs/fit-spheres.md). */
#define FIT_THIN 0.04
#define FIT_SPREAD 0.03
#define FIT_LLOYD_STEPS 12

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

/* ---- Initialization ------------------------------------------------------------------------
 * k-means++ seeding and Lloyd steps on the inside voxel centres, each sphere then inscribed (the
 * distance to the nearest surface sample, at most 2 r_N). Nearest-centre and nearest-sample
 * queries go through a uniform grid (spatial.h), so that thousands of spheres cost about what a
 * few do per point; the answers are those of testing every item (ties to the lower index). */

static double dist2(const float *a, const double *b) {
    double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
    return dx * dx + dy * dy + dz * dz;
}

/* The item (4 doubles each, x y z first) of grid g nearest p, the lowest index among equals, or
 * -1 for an empty grid: rings of cells around p's cell, outwards, until no unvisited cell can
 * hold anything nearer (after ring r, the cells left are at least r cells away). */
static int grid_nearest(const pen__grid *g, const double *items, const double p[3], double *d2) {
    int c[3], rmax = 0;
    for (int a = 0; a < 3; ++a) {
        const double f = floor((p[a] - g->lo[a]) / g->cell);
        c[a] = f < 0 ? 0 : f > g->n[a] - 1 ? g->n[a] - 1 : (int)f;
        rmax = rmax > g->n[a] ? rmax : g->n[a];
    }
    double best = (double)INFINITY;
    int bi = -1;
    for (int r = 0; r <= rmax; ++r) {
        for (int z = c[2] - r; z <= c[2] + r; ++z) {
            if (z < 0 || z >= g->n[2]) continue;
            for (int y = c[1] - r; y <= c[1] + r; ++y) {
                if (y < 0 || y >= g->n[1]) continue;
                const int shell = abs(z - c[2]) == r || abs(y - c[1]) == r;
                for (int x = c[0] - r; x <= c[0] + r; x += shell ? 1 : 2 * r) {
                    if (x >= 0 && x < g->n[0]) {
                        long m;
                        const int *its = pen__grid_cell(g, x, y, z, &m);
                        for (long e = 0; e < m; ++e) {
                            const double *q = items + 4 * (size_t)its[e];
                            const double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
                            const double d = dx * dx + dy * dy + dz * dz;
                            if (d < best || (d == best && its[e] < bi)) best = d, bi = its[e];
                        }
                    }
                    if (r == 0) break;
                }
            }
        }
        if (bi >= 0 && best <= (double)r * r * g->cell * g->cell) break;
    }
    *d2 = best;
    return bi;
}

/* A grid over points (4 doubles each) with about `per_cell` of them per cell. */
static pen_status point_grid(pen_context *ctx, const double *items, long n, double per_cell,
                             pen__grid *g) {
    double *boxes = pen__malloc(ctx, (size_t)n + 1, 6 * sizeof(double), "fit: point grid");
    if (!boxes) return PEN_ERROR_MEMORY;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (long i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) {
            boxes[6 * i + a] = boxes[6 * i + 3 + a] = items[4 * i + a];
            lo[a] = fmin(lo[a], items[4 * i + a]), hi[a] = fmax(hi[a], items[4 * i + a]);
        }
    double ext = 0;
    for (int a = 0; a < 3; ++a)
        ext = fmax(ext, hi[a] - lo[a]);
    /* At most n / per_cell cells (fewer for a flat or thin spread): a point finds its nearest
     * item within a few rings, however the items are spread. */
    const double cell = fmax(ext / cbrt(fmax((double)n / per_cell, 1)), 1e-300);
    pen_status st = pen__grid_build(ctx, boxes, n, cell, g);
    free(boxes);
    return st;
}

/* Nearest centre of every point (parallel; each point's answer alone). */
static pen_status assign(pen_context *ctx, const float *pts, long n_pts, const double *centres,
                         int k, int threads, int *label) {
    pen__grid g;
    pen_status st = point_grid(ctx, centres, k, 2, &g);
    if (st) return st;
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)n_pts * 32))              \
    schedule(static)
    for (long j = 0; j < n_pts; ++j) {
        const double p[3] = {pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]};
        double d2;
        const int i = grid_nearest(&g, centres, p, &d2);
        label[j] = i < 0 ? 0 : i;
    }
    pen__grid_free(&g);
    return PEN_OK;
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
    pen_status st = PEN_OK;
    for (int step = 0; !st && step < FIT_LLOYD_STEPS; ++step) {
        st = assign(ctx, pts, n_pts, sph, k, threads, label);
        if (st) break;
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
    if (!st) st = assign(ctx, pts, n_pts, sph, k, threads, label);
    if (st) {
        free(d2), free(label), free(acc);
        return st;
    }
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

/* Radius of each sphere: the distance from its centre to the nearest surface sample, at most
 * r_cap (deep inside a large mesh a sphere of a large set would otherwise hold dozens of others),
 * at least r_min. */
static pen_status inscribe(pen_context *ctx, const float *surf, int n_surf, int k, double r_min,
                           double r_cap, int threads, double *sph) {
    double *items = pen__malloc(ctx, (size_t)n_surf + 1, 4 * sizeof(double), "fit: samples");
    if (!items) return PEN_ERROR_MEMORY;
    for (int j = 0; j < n_surf; ++j)
        for (int a = 0; a < 4; ++a)
            items[4 * (size_t)j + a] = a < 3 ? (double)surf[3 * (size_t)j + a] : 0;
    pen__grid g;
    pen_status st = point_grid(ctx, items, n_surf, 2, &g);
    if (!st) {
#pragma omp parallel for num_threads(threads) if (parallel_worth((double)k * 256)) schedule(static)
        for (int i = 0; i < k; ++i) {
            double d2;
            grid_nearest(&g, items, sph + 4 * i, &d2);
            sph[4 * i + 3] = fmax(fmin(sqrt(d2), r_cap), r_min);
        }
        pen__grid_free(&g);
    }
    free(items);
    return st;
}

/* ---- Metrics ------------------------------------------------------------------------------ */


/* Points inside at least one sphere; with depth != NULL also the sum over those points of the
 * number of spheres that contain them. The spheres sit in `grid` (pen__grid_sphere_boxes with
 * reach 0): a point tests the spheres of its cell only. */
static long count_covered(const pen__grid *grid, const float *pts, long n_pts, const double *sph,
                          int threads, long *depth) {
    long hits = 0, sum = 0;
    int team = parallel_worth((double)n_pts * 8);
#pragma omp parallel for num_threads(threads) if (team) schedule(static) reduction(+ : hits, sum)
    for (long j = 0; j < n_pts; ++j) {
        const double p[3] = {pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]};
        long m;
        const int *items = pen__grid_at(grid, p, &m);
        int c = 0;
        for (long e = 0; e < m && (c == 0 || depth); ++e) {
            const double *s = sph + 4 * (size_t)items[e];
            c += dist2(pts + 3 * j, s) <= s[3] * s[3];
        }
        hits += c > 0;
        sum += c;
    }
    if (depth) *depth = sum;
    return hits;
}

/* The spheres (4 doubles each) in a grid whose cells are about a sphere across. */
static pen_status sphere_grid(pen_context *ctx, const double *sph, int count, double reach,
                              double h, pen__grid *g) {
    double *boxes = pen__malloc(ctx, (size_t)count + 1, 6 * sizeof(double), "fit: sphere boxes");
    if (!boxes) return PEN_ERROR_MEMORY;
    double rsum = 0;
    for (int i = 0; i < count; ++i)
        rsum += sph[4 * (size_t)i + 3];
    pen__grid_sphere_boxes(sph, count, reach, boxes);
    pen_status st = pen__grid_build(ctx, boxes, count, fmax(2 * (rsum / count + reach), h), g);
    free(boxes);
    return st;
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
    const pen_coverage_report *c = &m->coverage;
    return snprintf(buf, size,
                    "{\"metrics\": {\"sov_fraction\": %.6f, \"surface_coverage\": %.6f, "
                    "\"volume_coverage\": %.6f, \"mean_overlap\": %.4f, \"iterations\": %d, "
                    "\"seconds\": %.3f, "
                    "\"energy\": %.9g, \"grid\": [%d, %d, %d], \"inside_voxels\": %ld, "
                    "\"surface_samples\": %d, \"uncovered\": {\"tolerance\": %.6g, "
                    "\"fraction\": %.6f, \"parts\": %d, \"largest_share\": %.6f, "
                    "\"largest_centre\": [%.6g, %.6g, %.6g], \"largest_lo\": [%.6g, %.6g, %.6g], "
                    "\"largest_hi\": [%.6g, %.6g, %.6g], \"samples\": %d}}%s}",
                    m->sov_fraction, m->surface_coverage, m->volume_coverage, m->mean_overlap,
                    m->iterations, m->seconds, m->energy, m->grid[0], m->grid[1], m->grid[2],
                    m->inside_voxels, m->surface_samples, c->tolerance, c->uncovered, c->parts,
                    c->largest_share, (double)c->largest_centre[0], (double)c->largest_centre[1],
                    (double)c->largest_centre[2], (double)c->largest_lo[0],
                    (double)c->largest_lo[1], (double)c->largest_lo[2], (double)c->largest_hi[0],
                    (double)c->largest_hi[1], (double)c->largest_hi[2], c->samples, settings);
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
    int *surf_tri;  /* the triangle of each surface sample */
    double *balls;  /* the medial ball of each surface sample (fit_seed.c) */
    double *thick;  /* the half-thickness at each surface sample (fit_seed.c) */
    fit_cells outside_cells, surf_cells;
    pen__fit_alloc alloc;
    double *sph, *grad, *m1, *m2;
    uint8_t *moved;
    double tau; /* the spread's gap (fit_seed.c) */
    double side; /* the mesh's longest side */
} fit_data;

static void fit_data_free(fit_data *d) {
    pen__fit_grid_free(&d->grid);
    free(d->inside_pts), free(d->outside_pts), free(d->surf_pts);
    free(d->surf_tri), free(d->balls), free(d->thick);
    pen__fit_alloc_free(&d->alloc);
    free(d->sph), free(d->grad), free(d->m1), free(d->m2);
    free(d->moved);
    free(d->outside_cells.start), free(d->outside_cells.bound);
    free(d->surf_cells.start), free(d->surf_cells.bound);
}

/* Sorts points (in place, by a counting sort) into bricks of FIT_BRICK^3 voxels and bounds each
 * non-empty brick by the midpoint of its points' box and the largest distance to it. `tag`
 * (NULL, or one int per point) is sorted along. */
static pen_status build_cells(pen_context *ctx, const pen__fit_grid *g, float *pts, int *tag,
                              long n, fit_cells *out) {
    int nb[3];
    for (int a = 0; a < 3; ++a)
        nb[a] = (g->n[a] + FIT_BRICK - 1) / FIT_BRICK;
    long bricks = (long)nb[0] * nb[1] * nb[2];
    long *key = pen__malloc(ctx, (size_t)n + 1, sizeof(long), "fit: cell keys");
    long *first = pen__calloc(ctx, (size_t)bricks + 1, sizeof(long), "fit: cell offsets");
    float *sorted = pen__malloc(ctx, (size_t)n + 1, 3 * sizeof(float), "fit: sorted points");
    int *sorted_tag = tag ? pen__malloc(ctx, (size_t)n + 1, sizeof(int), "fit: sorted tags") : NULL;
    if (!key || !first || !sorted || (tag && !sorted_tag)) {
        free(key), free(first), free(sorted), free(sorted_tag);
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
        free(key), free(first), free(sorted), free(sorted_tag);
        return PEN_ERROR_MEMORY;
    }
    for (long j = 0; j < n; ++j) {
        long at = first[key[j]]++;
        memcpy(sorted + 3 * at, pts + 3 * j, 3 * sizeof(float));
        if (tag) sorted_tag[at] = tag[j];
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
    if (tag) memcpy(tag, sorted_tag, sizeof(int) * (size_t)n);
    free(key), free(first), free(sorted), free(sorted_tag);
    return PEN_OK;
}

/* Voxelizes, splits the voxel centres into inside and outside lists, samples the surface and
 * finds each sample's medial ball. */
static pen_status prepare(pen_context *ctx, const pen_mesh *mesh, const pen_fit_settings *s,
                          int threads, fit_data *d) {
    pen_status st = pen__fit_voxelize(ctx, mesh, s->voxels, FIT_PAD, &d->grid);
    if (st) return st;
    st = pen__fit_mesh_side(ctx, mesh, &d->side);
    if (st) return st;
    const pen__fit_grid *g = &d->grid;
    long total = (long)g->n[0] * g->n[1] * g->n[2];
    for (long v = 0; v < total; ++v)
        d->n_inside += g->inside[v];
    d->n_outside = total - d->n_inside;
    /* The spheres start from the surface (fit_seed.c), so a mesh of parts thinner than a voxel
     * fits; a mesh with no voxel inside at all is open or flat. */
    if (d->n_inside == 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "fit: only 0 of %ld voxels are inside the mesh (is the mesh closed? try "
                          "more voxels)",
                          total);
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
    st = pen__fit_sample_surface(ctx, mesh, 1, s->seed, probe, NULL, &area);
    if (st) return st;
    double want = s->samples_per_voxel_area * area / (g->h * g->h);
    d->n_surf = (int)fmin(fmax(want, 256), 4e6);
    d->surf_pts = pen__malloc(ctx, (size_t)d->n_surf, 3 * sizeof(float), "fit: surface samples");
    d->surf_tri = pen__malloc(ctx, (size_t)d->n_surf, sizeof(int), "fit: surface samples");
    d->balls = pen__malloc(ctx, (size_t)d->n_surf, 4 * sizeof(double), "fit: medial balls");
    d->thick = pen__malloc(ctx, (size_t)d->n_surf, sizeof(double), "fit: medial balls");
    if (!d->surf_pts || !d->surf_tri || !d->balls || !d->thick) return PEN_ERROR_MEMORY;
    st = pen__fit_sample_surface(ctx, mesh, d->n_surf, s->seed, d->surf_pts, d->surf_tri, &area);
    if (st) return st;
    st = build_cells(ctx, g, d->outside_pts, NULL, d->n_outside, &d->outside_cells);
    if (!st) st = build_cells(ctx, g, d->surf_pts, d->surf_tri, d->n_surf, &d->surf_cells);
    if (!st)
        st = pen__fit_medial_balls(ctx, mesh, d->surf_pts, d->surf_tri, d->n_surf, threads,
                                   d->balls, d->thick);
    return st;
}

/* ---- Adam, with the allocation's moves ------------------------------------------------------
 * A sphere that is the only cover of no surface sample lowers E by nothing and may add SOV; once
 * other spheres bury it its gradient is exactly zero (relu is flat inside every sphere), so Adam
 * can never move it again. And a part that starts without spheres feels no gradient from any. So
 * after the seeds and a few times early in the run the allocation (fit_seed.c) moves spheres:
 * idle ones (their loss <= 0) to where a candidate ball gains most, then the spread, which leaves
 * no part farther than tau from the spheres while the budget allows; the gradient takes over
 * from there. Neither is in the supplement, which does not say how its spheres were initialized;
 * both are measured in docs/fit-spheres.md. */

static pen_status adam_run(pen_context *ctx, const pen__fit_problem *p, const pen_fit_settings *s,
                           double h, int count, fit_data *d, int *iterations) {
    const double beta1 = 0.9, beta2 = 0.999, eps = 1e-12;
    double b1t = 1, b2t = 1;
    int n = 4 * count;
    int it = 0;
    for (; it < s->iterations; ++it) {
        memset(d->grad, 0, sizeof(double) * (size_t)n);
        if (isnan(pen__fit_energy_bwd(p, count, d->sph, 1, d->grad)))
            return pen__error(ctx, PEN_ERROR_MEMORY, "fit: energy evaluation ran out of memory");
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
            /* Idle spheres (loss <= 0) to where they gain most, then the spread (fit_seed.c). */
            if (pen__fit_alloc_move(ctx, &d->alloc, d->sph, count, d->moved, 0) < 0 ||
                pen__fit_alloc_spread(ctx, &d->alloc, d->sph, count, d->tau, count, d->moved) < 0)
                return pen__error(ctx, PEN_ERROR_MEMORY, "fit: out of memory moving spheres");
            for (int i = 0; i < count; ++i)
                if (d->moved[i])
                    for (int a = 0; a < 4; ++a)
                        d->m1[4 * i + a] = d->m2[4 * i + a] = 0;
        }
    }
    *iterations = it;
    return PEN_OK;
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
    pen__fit_work *work = NULL;
    st = prepare(ctx, mesh, &s, threads, &d);
    double h = d.grid.h;
    size_t n = 4 * (size_t)count;
    if (!st) {
        d.sph = pen__calloc(ctx, n, sizeof(double), "fit: spheres");
        d.grad = pen__calloc(ctx, n, sizeof(double), "fit: gradient");
        d.m1 = pen__calloc(ctx, n, sizeof(double), "fit: Adam moments");
        d.m2 = pen__calloc(ctx, n, sizeof(double), "fit: Adam moments");
        d.moved = pen__malloc(ctx, (size_t)count, 1, "fit: moved flags");
        if (!d.sph || !d.grad || !d.m1 || !d.m2 || !d.moved) st = PEN_ERROR_MEMORY;
    }
    /* sigma and the seeds' cap from r_N, the radius of `count` equal spheres holding the inside
     * voxels' volume (fit.h, docs/fit-spheres.md). */
    double volume = (double)d.n_inside * h * h * h;
    double r_n = cbrt(3 * volume / (4 * PEN_PI * count));
    double r_cap = FIT_SEED_CAP * r_n;
    if (!st) st = kmeans(ctx, d.inside_pts, d.n_inside, count, s.seed, threads, d.sph);
    if (!st) st = inscribe(ctx, d.surf_pts, d.n_surf, count, 0.5 * h, r_cap, threads, d.sph);
    if (!st)
        st = pen__fit_alloc_init(ctx, &d.alloc, d.surf_pts, d.balls, d.thick, d.n_surf, &d.grid,
                                 s.surface_weight, FIT_THIN * d.side, r_cap, 0.5 * h, threads);
    d.tau = fmax(FIT_SPREAD * d.side, r_n);
    if (!st && pen__fit_alloc_spread(ctx, &d.alloc, d.sph, count, d.tau, count, d.moved) < 0)
        st = pen__error(ctx, PEN_ERROR_MEMORY, "fit: out of memory moving spheres");
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
    if (!st) st = pen__fit_work_create(ctx, &p, &work);
    p.work = work;
    int iterations = 0;
    if (!st) st = adam_run(ctx, &p, &s, h, count, &d, &iterations);
    double energy = st ? 0 : pen__fit_energy_fwd(&p, count, d.sph);
    if (!st && !isfinite(energy))
        st = pen__error(ctx, PEN_ERROR_MEMORY, "fit: energy evaluation ran out of memory");
    if (!st) st = pen_spheres_create(ctx, count, out);
    if (!st) {
        for (size_t k = 0; k < n; ++k)
            out->data[k] = (float)d.sph[k];
        /* Overlap weights of the spheres as returned (pen_spheres.weight, overlap.c). */
        st = pen_spheres_ensure_weights(ctx, out);
    }
    if (!st && metrics) {
        /* Hard tests on the float spheres that are returned. */
        for (size_t k = 0; k < n; ++k)
            d.sph[k] = (double)out->data[k];
        pen__grid grid;
        st = sphere_grid(ctx, d.sph, count, 0, h, &grid);
        if (!st) {
            long depth = 0;
            long in_cov = count_covered(&grid, d.inside_pts, d.n_inside, d.sph, threads, &depth);
            long out_cov = count_covered(&grid, d.outside_pts, d.n_outside, d.sph, threads, NULL);
            long surf_cov = count_covered(&grid, d.surf_pts, d.n_surf, d.sph, threads, NULL);
            pen__grid_free(&grid);
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
            st = pen_spheres_coverage(ctx, mesh, out, &metrics->coverage);
            metrics->seconds = omp_get_wtime() - t0;
        }
    }
    pen__fit_work_free(work);
    fit_data_free(&d);
    if (st) {
        pen_spheres_free(out);
        if (metrics) memset(metrics, 0, sizeof *metrics);
    }
    return st;
}
