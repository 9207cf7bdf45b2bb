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
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

/* The frame's three interpolations of one object (points, raw normals, UVs: the last optional)
 * in one pass: pen_interpolate_bwd three times costs three scans of every pixel and reloads each
 * pixel's triangle and barycentrics; here each object pixel is visited once. Each sum runs in
 * the same order as the three calls (every vertex's terms in pixel order; a pixel's barycentric
 * terms points, normals, UVs), so the bits are the same. The pixel's d_bary is written, not
 * added: its entry starts at +0 as after a clear (0 + g turns a -0 into +0, as the clear did),
 * so the caller need not clear the buffer. */
/* What pen__interpolate_bwd_object does for one pixel i of the object. */
static inline void bwd_object_pixel(const pen_gbuffer *gb, size_t i, const uint32_t *indices,
                                    const float *world, const float *d_x, float *d_world,
                                    const float *vnormal, const float *d_nraw, float *d_vnormal,
                                    const uint32_t *uv_indices, const float *uvs, const float *d_uv,
                                    float *d_bary) {
    const size_t t = 3 * (size_t)gb->triangle[i];
    const uint32_t *idx = indices + t;
    const double u = (double)gb->bary[2 * i], v = (double)gb->bary[2 * i + 1], w = 1.0 - u - v;
    const size_t k0 = 3 * (size_t)idx[0], k1 = 3 * (size_t)idx[1], k2 = 3 * (size_t)idx[2];
    const float *src[2] = {world, vnormal}, *grad[2] = {d_x + 3 * i, d_nraw + 3 * i};
    float *dst[2] = {d_world, d_vnormal};
    float bu = 0.0f, bv = 0.0f;
    for (int a = 0; a < 2; ++a) {
        /* The gradient and the corners read once, before the scatter (the buffers are distinct,
         * so the order of reads and writes changes nothing but the reloads). */
        const float *a0 = src[a] + k0, *a1 = src[a] + k1, *a2 = src[a] + k2;
        const double g[3] = {(double)grad[a][0], (double)grad[a][1], (double)grad[a][2]};
        double du = 0.0, dv = 0.0;
        for (int c = 0; c < 3; ++c) {
            du += g[c] * ((double)a1[c] - (double)a0[c]);
            dv += g[c] * ((double)a2[c] - (double)a0[c]);
        }
        float *d = dst[a];
        for (int c = 0; c < 3; ++c) {
            d[k0 + c] += (float)(w * g[c]);
            d[k1 + c] += (float)(u * g[c]);
            d[k2 + c] += (float)(v * g[c]);
        }
        bu += (float)du;
        bv += (float)dv;
    }
    if (uvs) {
        const uint32_t *uidx = uv_indices + t;
        const float *g = d_uv + 2 * i, *a0 = uvs + 2 * (size_t)uidx[0];
        const float *a1 = uvs + 2 * (size_t)uidx[1], *a2 = uvs + 2 * (size_t)uidx[2];
        double du = 0.0, dv = 0.0;
        for (int c = 0; c < 2; ++c) {
            du += (double)g[c] * ((double)a1[c] - (double)a0[c]);
            dv += (double)g[c] * ((double)a2[c] - (double)a0[c]);
        }
        bu += (float)du;
        bv += (float)dv;
    }
    d_bary[2 * i] = bu;
    d_bary[2 * i + 1] = bv;
}

void pen__interpolate_bwd_object(const pen_gbuffer *gb, int object, const uint32_t *indices,
                                 const float *world, const float *d_x, float *d_world,
                                 const float *vnormal, const float *d_nraw, float *d_vnormal,
                                 const uint32_t *uv_indices, const float *uvs, const float *d_uv,
                                 float *d_bary) {
    if (object < 0) return;
    const size_t n = (size_t)gb->width * (size_t)gb->height;
    size_t i = 0;
#if defined(__SSE2__)
    /* The object's pixels found 4 at a time (most of the image is other surfaces), in order. */
    const __m128i want = _mm_set1_epi32(object);
    for (; i + 4 <= n; i += 4) {
        const __m128i s4 = _mm_loadu_si128((const __m128i *)(const void *)(gb->surface + i));
        const int hit = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(s4, want)));
        if (!hit) continue;
        for (int k = 0; k < 4; ++k)
            if (hit >> k & 1)
                bwd_object_pixel(gb, i + (size_t)k, indices, world, d_x, d_world, vnormal, d_nraw,
                                 d_vnormal, uv_indices, uvs, d_uv, d_bary);
    }
#endif
    for (; i < n; ++i)
        if (gb->surface[i] == object)
            bwd_object_pixel(gb, i, indices, world, d_x, d_world, vnormal, d_nraw, d_vnormal,
                             uv_indices, uvs, d_uv, d_bary);
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
