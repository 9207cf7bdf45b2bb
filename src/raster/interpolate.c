/* Attribute interpolation over the G-buffer, area-weighted vertex normals, and normalization,
 * each with its backward.
 *
 * A pixel's attribute is a = (1-u-v) a0 + u a1 + v a2 with the G-buffer's perspective-correct
 * barycentrics, so its backward splits in two: d a_k += b_k d_a to the corner values, and
 * d_u = d_a . (a1 - a0), d_v = d_a . (a2 - a0) to the barycentrics, which pen_raster_bary_bwd
 * turns into vertex-position gradients. Attribute indices may differ from position indices
 * (UV seams): the barycentrics belong to the triangle, not to the index buffer.
 *
 * Vertex normals: m_v = sum over the triangles around v of c = (p1 - p0) x (p2 - p0), whose
 * length is twice the area (hence the area weighting), then n_v = m_v / |m_v|. Backward:
 * d m = (d n - n (n . d n)) / |m|, and for c = e1 x e2 with e1 = p1 - p0, e2 = p2 - p0,
 * d e1 = e2 x d c, d e2 = d c x e1 (from c . g = e1 . (e2 x g) = e2 . (g x e1)).
 * Sums run serially in double: vertices are shared, and a fixed order keeps results repeatable.
 */
#include "core/internal.h"
#include "raster/raster_internal.h"

#include <stdlib.h>

#define TINY_LENGTH 1e-20

/* ---- Interpolation --------------------------------------------------------------------------- */

void pen_interpolate_fwd(const pen_gbuffer *gb, int object, const uint32_t *indices,
                         const float *values, int dim, float *out) {
    size_t n = (size_t)gb->width * (size_t)gb->height;
    for (size_t i = 0; i < n; ++i) {
        if (gb->surface[i] != object || object < 0) continue;
        const uint32_t *idx = indices + 3 * (size_t)gb->triangle[i];
        double u = (double)gb->bary[2 * i], v = (double)gb->bary[2 * i + 1], w = 1.0 - u - v;
        const float *a0 = values + (size_t)idx[0] * dim, *a1 = values + (size_t)idx[1] * dim;
        const float *a2 = values + (size_t)idx[2] * dim;
        for (int c = 0; c < dim; ++c)
            out[i * dim + c] = (float)(w * (double)a0[c] + u * (double)a1[c] + v * (double)a2[c]);
    }
}

void pen_interpolate_bwd(const pen_gbuffer *gb, int object, const uint32_t *indices,
                         const float *values, int dim, const float *d_out, float *d_values,
                         float *d_bary) {
    size_t n = (size_t)gb->width * (size_t)gb->height;
    for (size_t i = 0; i < n; ++i) {
        if (gb->surface[i] != object || object < 0) continue;
        const uint32_t *idx = indices + 3 * (size_t)gb->triangle[i];
        double u = (double)gb->bary[2 * i], v = (double)gb->bary[2 * i + 1], w = 1.0 - u - v;
        const float *g = d_out + i * dim;
        if (d_values)
            for (int c = 0; c < dim; ++c) {
                d_values[(size_t)idx[0] * dim + c] += (float)(w * (double)g[c]);
                d_values[(size_t)idx[1] * dim + c] += (float)(u * (double)g[c]);
                d_values[(size_t)idx[2] * dim + c] += (float)(v * (double)g[c]);
            }
        if (d_bary) {
            const float *a0 = values + (size_t)idx[0] * dim, *a1 = values + (size_t)idx[1] * dim;
            const float *a2 = values + (size_t)idx[2] * dim;
            double du = 0.0, dv = 0.0;
            for (int c = 0; c < dim; ++c) {
                du += (double)g[c] * ((double)a1[c] - (double)a0[c]);
                dv += (double)g[c] * ((double)a2[c] - (double)a0[c]);
            }
            d_bary[2 * i] += (float)du;
            d_bary[2 * i + 1] += (float)dv;
        }
    }
}

/* ---- Vertex normals -------------------------------------------------------------------------- */

static pen_status check_indices(pen_context *ctx, int vertex_count, int triangle_count,
                                const uint32_t *indices) {
    if (vertex_count < 0 || triangle_count < 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "vertex normals: bad counts %d, %d",
                          vertex_count, triangle_count);
    for (size_t i = 0; i < 3 * (size_t)triangle_count; ++i)
        if (indices[i] >= (uint32_t)vertex_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "vertex normals: triangle %zu: index %u out of range [0, %d)", i / 3,
                              indices[i], vertex_count);
    return PEN_OK;
}

static void tri_edges(const float *positions, const uint32_t *idx, double e1[3], double e2[3]) {
    double p[3][3];
    for (int k = 0; k < 3; ++k)
        pen__load3_d(positions + 3 * (size_t)idx[k], p[k]);
    pen__sub_d(p[1], p[0], e1);
    pen__sub_d(p[2], p[0], e2);
}

/* m (3 doubles per vertex) = sum of the adjacent triangles' doubled-area normals. */
static double *accumulate_normals(pen_context *ctx, int vertex_count, const float *positions,
                                  int triangle_count, const uint32_t *indices) {
    double *m = pen__calloc(ctx, 3 * (size_t)(vertex_count ? vertex_count : 1), sizeof(double),
                            "vertex normal sums");
    if (!m) return NULL;
    for (int t = 0; t < triangle_count; ++t) {
        const uint32_t *idx = indices + 3 * (size_t)t;
        double e1[3], e2[3], c[3];
        tri_edges(positions, idx, e1, e2);
        pen__cross_d(e1, e2, c);
        for (int k = 0; k < 3; ++k)
            for (int i = 0; i < 3; ++i)
                m[3 * (size_t)idx[k] + i] += c[i];
    }
    return m;
}

pen_status pen_vertex_normals_fwd(pen_context *ctx, int vertex_count, const float *positions,
                                  int triangle_count, const uint32_t *indices, float *normals) {
    pen_status st = check_indices(ctx, vertex_count, triangle_count, indices);
    if (st) return st;
    double *m = accumulate_normals(ctx, vertex_count, positions, triangle_count, indices);
    if (!m) return PEN_ERROR_MEMORY;
    for (size_t v = 0; v < (size_t)vertex_count; ++v) {
        double len = sqrt(pen__dot_d(m + 3 * v, m + 3 * v));
        double s = len > TINY_LENGTH ? 1.0 / len : 0.0;
        for (int i = 0; i < 3; ++i)
            normals[3 * v + i] = (float)(m[3 * v + i] * s);
    }
    free(m);
    return PEN_OK;
}

pen_status pen_vertex_normals_bwd(pen_context *ctx, int vertex_count, const float *positions,
                                  int triangle_count, const uint32_t *indices,
                                  const float *d_normals, float *d_positions) {
    if (!d_positions) return PEN_OK;
    pen_status st = check_indices(ctx, vertex_count, triangle_count, indices);
    if (st) return st;
    double *m = accumulate_normals(ctx, vertex_count, positions, triangle_count, indices);
    if (!m) return PEN_ERROR_MEMORY;
    /* Turn m into d m in place: the normalization's backward. */
    for (size_t v = 0; v < (size_t)vertex_count; ++v) {
        double *mv = m + 3 * v, len = sqrt(pen__dot_d(mv, mv)), g[3];
        pen__load3_d(d_normals + 3 * v, g);
        if (!(len > TINY_LENGTH)) {
            mv[0] = mv[1] = mv[2] = 0.0;
            continue;
        }
        double n[3] = {mv[0] / len, mv[1] / len, mv[2] / len}, ng = pen__dot_d(n, g);
        for (int i = 0; i < 3; ++i)
            mv[i] = (g[i] - n[i] * ng) / len;
    }
    for (int t = 0; t < triangle_count; ++t) {
        const uint32_t *idx = indices + 3 * (size_t)t;
        double e1[3], e2[3], dc[3] = {0.0, 0.0, 0.0}, de1[3], de2[3];
        tri_edges(positions, idx, e1, e2);
        for (int k = 0; k < 3; ++k)
            for (int i = 0; i < 3; ++i)
                dc[i] += m[3 * (size_t)idx[k] + i];
        pen__cross_d(e2, dc, de1);
        pen__cross_d(dc, e1, de2);
        for (int i = 0; i < 3; ++i) {
            d_positions[3 * (size_t)idx[0] + i] -= (float)(de1[i] + de2[i]);
            d_positions[3 * (size_t)idx[1] + i] += (float)de1[i];
            d_positions[3 * (size_t)idx[2] + i] += (float)de2[i];
        }
    }
    free(m);
    return PEN_OK;
}

/* ---- Normalization --------------------------------------------------------------------------- */

void pen_normalize_fwd(int n, const float *v, float *out) {
    for (size_t i = 0; i < (size_t)(n > 0 ? n : 0); ++i) {
        double a[3];
        pen__load3_d(v + 3 * i, a);
        double len = sqrt(pen__dot_d(a, a)), s = len > TINY_LENGTH ? 1.0 / len : 0.0;
        for (int c = 0; c < 3; ++c)
            out[3 * i + c] = (float)(a[c] * s);
    }
}

void pen_normalize_bwd(int n, const float *v, const float *d_out, float *d_v) {
    if (!d_v) return;
    for (size_t i = 0; i < (size_t)(n > 0 ? n : 0); ++i) {
        double a[3], g[3];
        pen__load3_d(v + 3 * i, a);
        pen__load3_d(d_out + 3 * i, g);
        double len = sqrt(pen__dot_d(a, a));
        if (!(len > TINY_LENGTH)) continue;
        double u[3] = {a[0] / len, a[1] / len, a[2] / len}, ug = pen__dot_d(u, g);
        for (int c = 0; c < 3; ++c)
            d_v[3 * i + c] += (float)((g[c] - u[c] * ug) / len);
    }
}
