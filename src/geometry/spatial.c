/* A uniform grid of boxes (spatial.h): counting sort of (cell, item) pairs, so that building costs
 * one pass to count, one to fill, and the items of each cell stay in index order. */
#include "geometry/spatial.h"

#include <stdlib.h>
#include <string.h>

void pen__grid_free(pen__grid *g) {
    if (!g) return;
    free(g->start);
    free(g->items);
    memset(g, 0, sizeof *g);
}

int pen__grid_range(const pen__grid *g, const double a[3], const double b[3], int lo[3],
                    int hi[3]) {
    for (int k = 0; k < 3; ++k) {
        const double fa = floor((a[k] - g->lo[k]) / g->cell), fb = floor((b[k] - g->lo[k]) / g->cell);
        if (!(fb >= 0) || !(fa <= g->n[k] - 1)) return 0; /* also NaN */
        lo[k] = fa < 0 ? 0 : (int)fa;
        hi[k] = fb > g->n[k] - 1 ? g->n[k] - 1 : (int)fb;
    }
    return 1;
}

const int *pen__grid_at(const pen__grid *g, const double p[3], long *n) {
    int lo[3], hi[3];
    if (!pen__grid_range(g, p, p, lo, hi)) {
        *n = 0;
        return g->items;
    }
    return pen__grid_cell(g, lo[0], lo[1], lo[2], n);
}

void pen__grid_sphere_boxes(const double *spheres, int count, double reach, double *boxes) {
    for (int i = 0; i < count; ++i) {
        const double *s = spheres + 4 * (size_t)i;
        const double r = s[3] + reach;
        for (int k = 0; k < 3; ++k)
            boxes[6 * (size_t)i + k] = s[k] - r, boxes[6 * (size_t)i + 3 + k] = s[k] + r;
    }
}

pen_status pen__grid_build(pen_context *ctx, const double *boxes, long count, double cell,
                           pen__grid *g) {
    memset(g, 0, sizeof *g);
    double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (long i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            lo[k] = fmin(lo[k], boxes[6 * i + k]);
            hi[k] = fmax(hi[k], boxes[6 * i + 3 + k]);
        }
    if (count == 0)
        for (int k = 0; k < 3; ++k)
            lo[k] = hi[k] = 0;
    double extent = 0;
    for (int k = 0; k < 3; ++k)
        extent = fmax(extent, hi[k] - lo[k]);
    if (!(cell > 0) || !isfinite(extent))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "grid: bad cell %g or extent %g", cell, extent);
    /* Coarsen until the cells fit the budget (each doubling divides the count by about 8). */
    for (;;) {
        long total = 1;
        for (int k = 0; k < 3; ++k) {
            const double m = floor((hi[k] - lo[k]) / cell) + 1;
            g->n[k] = m > PEN__GRID_MAX_CELLS ? (int)PEN__GRID_MAX_CELLS : (int)m;
            total *= g->n[k];
            if (total > PEN__GRID_MAX_CELLS) break;
        }
        if (total <= PEN__GRID_MAX_CELLS) break;
        cell *= 2;
    }
    g->cell = cell;
    memcpy(g->lo, lo, sizeof lo);
    const long cells = (long)g->n[0] * g->n[1] * g->n[2];
    g->start = pen__calloc(ctx, (size_t)cells + 2, sizeof(long), "grid: cells");
    if (!g->start) return PEN_ERROR_MEMORY;
    /* Pass 1 counts into start[c + 2]; the prefix sum makes start[c + 1] the fill position of
     * cell c; pass 2 fills, leaving start[c] the first item of cell c. */
    for (int pass = 0; pass < 2; ++pass) {
        for (long i = 0; i < count; ++i) {
            int a[3], b[3];
            if (!pen__grid_range(g, boxes + 6 * i, boxes + 6 * i + 3, a, b)) continue;
            for (int z = a[2]; z <= b[2]; ++z)
                for (int y = a[1]; y <= b[1]; ++y)
                    for (int x = a[0]; x <= b[0]; ++x) {
                        const long c = x + (long)g->n[0] * (y + (long)g->n[1] * z);
                        if (pass == 0)
                            ++g->start[c + 2];
                        else
                            g->items[g->start[c + 1]++] = (int)i;
                    }
        }
        if (pass == 0) {
            for (long c = 0; c < cells; ++c)
                g->start[c + 2] += g->start[c + 1];
            g->items = pen__malloc(ctx, (size_t)g->start[cells + 1] + 1, sizeof(int), "grid: items");
            if (!g->items) {
                pen__grid_free(g);
                return PEN_ERROR_MEMORY;
            }
        }
    }
    return PEN_OK;
}
