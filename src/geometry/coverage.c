/* What a sphere set leaves of its mesh's surface uncovered (pen_spheres_coverage, fit.h).
 *
 * A fit can meet its energy while a whole part goes without spheres (a chair's thin frame beside
 * its seat: the frame is a few percent of the area), and its shadow then lacks that part; the
 * surface coverage metric says so only as a share. This report names the part: the samples
 * farther than a tolerance outside every sphere, linked into connected parts (two samples closer
 * than a few sample spacings belong together), and the largest part's area share, centre and box,
 * so that `fit-spheres`, `render` and `optimize` can point at it. It depends on the mesh and the
 * spheres alone (its own samples, a fixed seed), not on the settings of the fit that made them.
 */
#include "geometry/fit_internal.h"

#include <stdlib.h>
#include <string.h>

#define COVERAGE_SEED 0x636F7665726167ull /* "coverag" */
/* Uncovered samples closer than this many mean sample spacings are one part: random samples
 * leave holes of two spacings or so, a part a tolerance away from another is still apart. */
#define COVERAGE_LINK 3.0

static int find(int *parent, int j) {
    while (parent[j] != j) {
        parent[j] = parent[parent[j]]; /* path halving */
        j = parent[j];
    }
    return j;
}

/* Joins the parts of a and b under the lower index, so that roots do not depend on the order. */
static void join(int *parent, int a, int b) {
    a = find(parent, a), b = find(parent, b);
    if (a < b)
        parent[b] = a;
    else if (b < a)
        parent[a] = b;
}

/* 1 for each sample farther than tol outside every sphere (spheres: 4 doubles each). */
static pen_status mark_uncovered(pen_context *ctx, const float *pts, int n, const double *sph,
                                 int count, double tol, double side, uint8_t *uncovered) {
    if (count == 0) {
        memset(uncovered, 1, (size_t)n);
        return PEN_OK;
    }
    double *boxes = pen__malloc(ctx, (size_t)count, 6 * sizeof(double), "coverage: boxes");
    if (!boxes) return PEN_ERROR_MEMORY;
    double rsum = 0;
    for (int i = 0; i < count; ++i)
        rsum += sph[4 * (size_t)i + 3];
    pen__grid_sphere_boxes(sph, count, tol, boxes);
    pen__grid g;
    pen_status st = pen__grid_build(ctx, boxes, count, fmax(2 * (rsum / count + tol), side / 64), &g);
    free(boxes);
    if (st) return st;
    for (int j = 0; j < n; ++j) {
        const double p[3] = {pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]};
        long m;
        const int *items = pen__grid_at(&g, p, &m);
        int covered = 0;
        for (long e = 0; e < m && !covered; ++e) {
            const double *s = sph + 4 * (size_t)items[e];
            const double dx = p[0] - s[0], dy = p[1] - s[1], dz = p[2] - s[2];
            covered = sqrt(dx * dx + dy * dy + dz * dz) - s[3] <= tol;
        }
        uncovered[j] = (uint8_t)!covered;
    }
    pen__grid_free(&g);
    return PEN_OK;
}

/* Links the uncovered samples into parts and describes the largest in out. */
static pen_status largest_part(pen_context *ctx, const float *pts, int n, const uint8_t *uncovered,
                               double link, pen_coverage_report *out) {
    int *parent = pen__malloc(ctx, (size_t)n, sizeof(int), "coverage: parts");
    double *boxes = pen__malloc(ctx, (size_t)n, 6 * sizeof(double), "coverage: parts");
    pen__grid g;
    memset(&g, 0, sizeof g);
    pen_status st = parent && boxes ? PEN_OK : PEN_ERROR_MEMORY;
    if (!st) {
        /* Covered samples get an empty box (low > high): the grid leaves them out. */
        for (int j = 0; j < n; ++j) {
            parent[j] = j;
            for (int a = 0; a < 3; ++a) {
                boxes[6 * (size_t)j + a] = uncovered[j] ? (double)pts[3 * j + a] : HUGE_VAL;
                boxes[6 * (size_t)j + 3 + a] = uncovered[j] ? (double)pts[3 * j + a] : -HUGE_VAL;
            }
        }
        st = pen__grid_build(ctx, boxes, n, link, &g);
    }
    for (int j = 0; !st && j < n; ++j) {
        if (!uncovered[j]) continue;
        const double p[3] = {pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]};
        const double a[3] = {p[0] - link, p[1] - link, p[2] - link};
        const double b[3] = {p[0] + link, p[1] + link, p[2] + link};
        int lo[3], hi[3];
        if (!pen__grid_range(&g, a, b, lo, hi)) continue;
        for (int z = lo[2]; z <= hi[2]; ++z)
            for (int y = lo[1]; y <= hi[1]; ++y)
                for (int x = lo[0]; x <= hi[0]; ++x) {
                    long m;
                    const int *items = pen__grid_cell(&g, x, y, z, &m);
                    for (long e = 0; e < m; ++e) {
                        const int k = items[e];
                        if (k >= j) break; /* each pair once; items are in index order */
                        const double dx = p[0] - (double)pts[3 * k],
                                     dy = p[1] - (double)pts[3 * k + 1],
                                     dz = p[2] - (double)pts[3 * k + 2];
                        if (dx * dx + dy * dy + dz * dz <= link * link) join(parent, j, k);
                    }
                }
    }
    /* Sizes per root (reusing boxes' first column as counts); the largest, lowest root first. */
    int best = -1, parts = 0;
    for (int j = 0; !st && j < n; ++j) {
        if (!uncovered[j]) continue;
        const int r = find(parent, j);
        if (r == j) boxes[6 * (size_t)j] = 0, ++parts;
        boxes[6 * (size_t)r] += 1;
    }
    for (int j = 0; !st && j < n; ++j)
        if (uncovered[j] && parent[j] == j && (best < 0 || boxes[6 * (size_t)j] > boxes[6 * (size_t)best]))
            best = j;
    out->parts = parts;
    if (!st && best >= 0) {
        double sum[3] = {0, 0, 0}, lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL},
               hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
        long size = 0;
        for (int j = 0; j < n; ++j) {
            if (!uncovered[j] || find(parent, j) != best) continue;
            ++size;
            for (int a = 0; a < 3; ++a) {
                sum[a] += (double)pts[3 * j + a];
                lo[a] = fmin(lo[a], (double)pts[3 * j + a]);
                hi[a] = fmax(hi[a], (double)pts[3 * j + a]);
            }
        }
        out->largest_share = (double)size / n;
        for (int a = 0; a < 3; ++a) {
            out->largest_centre[a] = (float)(sum[a] / (double)size);
            out->largest_lo[a] = (float)lo[a];
            out->largest_hi[a] = (float)hi[a];
        }
    }
    pen__grid_free(&g);
    free(parent);
    free(boxes);
    return st;
}

pen_status pen_spheres_coverage(pen_context *ctx, const pen_mesh *mesh, const pen_spheres *spheres,
                                pen_coverage_report *out) {
    if (out) memset(out, 0, sizeof *out);
    if (!out || !mesh || !spheres || spheres->count < 0 || (spheres->count > 0 && !spheres->data))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "coverage: invalid arguments");
    double side;
    pen_status st = pen__fit_mesh_side(ctx, mesh, &side);
    if (st) return st;
    const int count = spheres->count;
    for (int i = 0; i < count; ++i) {
        const float *s = spheres->data + 4 * (size_t)i;
        if (!pen__finite3(s) || !isfinite(s[3]) || s[3] < 0)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "coverage: sphere %d needs a finite center and a radius >= 0", i);
    }
    const int n = PEN_SPHERES_COVERAGE_SAMPLES;
    float *pts = pen__malloc(ctx, (size_t)n, 3 * sizeof(float), "coverage: samples");
    double *sph = pen__malloc(ctx, (size_t)count + 1, 4 * sizeof(double), "coverage: spheres");
    uint8_t *uncovered = pen__malloc(ctx, (size_t)n, 1, "coverage: samples");
    double area = 0;
    st = pts && sph && uncovered ? PEN_OK : PEN_ERROR_MEMORY;
    if (!st) st = pen__fit_sample_surface(ctx, mesh, n, COVERAGE_SEED, pts, NULL, &area);
    for (size_t k = 0; !st && k < 4 * (size_t)count; ++k)
        sph[k] = (double)spheres->data[k];
    const double tol = PEN_SPHERES_COVERAGE_TOLERANCE * side;
    if (!st) st = mark_uncovered(ctx, pts, n, sph, count, tol, side, uncovered);
    if (!st) {
        long left = 0;
        for (int j = 0; j < n; ++j)
            left += uncovered[j];
        out->tolerance = tol;
        out->samples = n;
        out->uncovered = (double)left / n;
        const double spacing = sqrt(area / n);
        if (left > 0) st = largest_part(ctx, pts, n, uncovered, COVERAGE_LINK * spacing, out);
    }
    free(pts), free(sph), free(uncovered);
    if (st) memset(out, 0, sizeof *out);
    return st;
}
