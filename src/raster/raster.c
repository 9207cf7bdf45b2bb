/* Rasterizer: per-pixel visibility (G-buffer) of world-space triangle meshes and the ground
 * plane, sampled at pixel centres, and the backward of the visible points' barycentrics.
 *
 * Design. Vertices are moved to camera space (x along right, y along up, z = view depth) in
 * double. A pixel centre defines the ray direction r = (rx, ry, 1) in that space, and the ray
 * point at depth z is z r. For a triangle (v0, v1, v2) the three "homogeneous edge functions"
 *     E_k(r) = r . (v_{k+1} x v_{k+2})
 * are linear in the pixel position and proportional to the barycentrics of the point where the
 * ray meets the triangle's plane: b_k = E_k / (E_0 + E_1 + E_2), perspective-correct by
 * construction, and the depth there is z = det / (E_0 + E_1 + E_2), det = v0 . (v1 x v2)
 * (Olano & Greer 1997). The ray hits the triangle in front of the eye exactly when every E_k has
 * the sign of det, so no vertex needs to be projected for coverage: triangles crossing the near
 * plane are handled by the per-pixel test z >= near (exact clipping), and only their pixel
 * bounding box comes from the polygon clipped against z = near. A zero-area triangle, or one
 * whose plane passes through the eye, has det = 0 and is skipped, so no division by zero can
 * produce a NaN. Shared edges are watertight: the edge coefficients of a shared edge are exact
 * negatives in the two triangles, and a pixel exactly on an edge goes to the side selected by a
 * fixed sign rule on the coefficients (a top-left rule).
 *
 * Work is split into 16x16 tiles. Triangles are set up in parallel, binned to tiles serially in
 * their order (mesh order, then triangle order), and tiles are rasterized in parallel, each by
 * one thread, depth-testing its triangles in that order with a strict "closer" test. The result
 * is therefore the same for every thread count. The ground square is intersected analytically
 * with each pixel's ray after the triangles (meshes win depth ties).
 *
 * Backward. A pixel's point x = eye + t D lies on the fixed pixel ray D and on the triangle:
 * -t D + b1 (p1 - p0) + b2 (p2 - p0) = eye - p0, i.e. M (t, b1, b2)^T = eye - p0 with
 * M = [-D, p1 - p0, p2 - p0]. Differentiating, dM x + M dx = -dp0, so for an upstream gradient
 * g on (t, b1, b2) with w = M^-T g the vertex gradients are simply d p_k = -b_k w.
 */
#include "core/internal.h"
#include "raster/raster_internal.h"

#include <limits.h>
#include <omp.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <stdlib.h>
#include <string.h>

#define TILE 16

/* ---- G-buffer -------------------------------------------------------------------------------- */

pen_status pen_gbuffer_create(pen_context *ctx, int width, int height, pen_gbuffer *out) {
    memset(out, 0, sizeof *out);
    if (width < 1 || height < 1 || width > PEN_IMAGE_MAX_DIM || height > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "gbuffer: size %dx%d outside [1, %d]", width,
                          height, PEN_IMAGE_MAX_DIM);
    size_t n = (size_t)width * (size_t)height;
    out->width = width;
    out->height = height;
    out->surface = pen__malloc(ctx, n, sizeof(int32_t), "gbuffer surface");
    out->triangle = pen__malloc(ctx, n, sizeof(int32_t), "gbuffer triangle");
    out->bary = pen__malloc(ctx, n, 2 * sizeof(float), "gbuffer barycentrics");
    out->depth = pen__malloc(ctx, n, sizeof(float), "gbuffer depth");
    if (!out->surface || !out->triangle || !out->bary || !out->depth) {
        pen_gbuffer_free(out);
        return PEN_ERROR_MEMORY;
    }
    for (size_t i = 0; i < n; ++i) {
        out->surface[i] = PEN_SURFACE_BACKGROUND;
        out->triangle[i] = -1;
        out->bary[2 * i] = out->bary[2 * i + 1] = 0.0f;
        out->depth[i] = INFINITY;
    }
    return PEN_OK;
}

void pen_gbuffer_free(pen_gbuffer *gb) {
    if (!gb) return;
    free(gb->surface);
    free(gb->triangle);
    free(gb->bary);
    free(gb->depth);
    memset(gb, 0, sizeof *gb);
}

/* ---- Setup ----------------------------------------------------------------------------------- */

typedef struct tri_setup {
    double n[3][3];     /* E_k(r) = n[k] . r */
    double det;         /* v0 . (v1 x v2) */
    int x0, y0, x1, y1; /* inclusive pixel bounds; x0 > x1 when culled */
    int object, tri;
} tri_setup;

pen_status pen__raster_check_meshes(pen_context *ctx, const pen_raster_mesh *meshes, int mesh_count,
                                    size_t *total) {
    if (mesh_count < 0 || (mesh_count > 0 && !meshes))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: bad mesh list (count %d)", mesh_count);
    *total = 0;
    for (int m = 0; m < mesh_count; ++m) {
        const pen_raster_mesh *mesh = meshes + m;
        if (mesh->vertex_count < 0 || mesh->triangle_count < 0 ||
            mesh->triangle_count > INT32_MAX / 3 || /* half-edge ids are int32 */
            (mesh->vertex_count > 0 && !mesh->positions) ||
            (mesh->triangle_count > 0 && !mesh->indices))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "raster: mesh %d: bad counts (%d vertices, %d triangles) or NULL "
                              "arrays",
                              m, mesh->vertex_count, mesh->triangle_count);
        for (int v = 0; v < mesh->vertex_count; ++v)
            if (!pen__finite3(mesh->positions + 3 * (size_t)v))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "raster: mesh %d: vertex %d has a non-finite position", m, v);
        for (size_t i = 0; i < 3 * (size_t)mesh->triangle_count; ++i)
            if (mesh->indices[i] >= (uint32_t)mesh->vertex_count)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "raster: mesh %d: triangle %zu: index %u out of range [0, %d)", m,
                                  i / 3, mesh->indices[i], mesh->vertex_count);
        *total += (size_t)mesh->triangle_count;
    }
    if (*total > (size_t)INT_MAX)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: %zu triangles exceed the limit %d",
                          *total, INT_MAX);
    return PEN_OK;
}

static void to_camera(const pen_view *view, const float *p, double out[3]) {
    double d[3], q[3];
    pen__load3_d(p, q);
    pen__sub_d(q, view->eye, d);
    out[0] = pen__dot_d(d, view->right);
    out[1] = pen__dot_d(d, view->up);
    out[2] = pen__dot_d(d, view->forward);
}

/* Screen bounds of the part of triangle v (camera space) at depth >= near, as an inclusive
 * pixel range whose centres may be covered; returns 0 if nothing can be. */
static int tri_bounds(const pen_view *view, const double v[3][3], int *x0, int *y0, int *x1,
                      int *y1) {
    double near = view->near_plane;
    double poly[4][3];
    int count = 0;
    /* Sutherland-Hodgman against z >= near: at most one corner is cut off or added. */
    for (int k = 0; k < 3; ++k) {
        const double *a = v[k], *b = v[(k + 1) % 3];
        int ain = a[2] >= near, bin = b[2] >= near;
        if (ain) memcpy(poly[count++], a, sizeof poly[0]);
        if (ain != bin) {
            double t = (near - a[2]) / (b[2] - a[2]);
            for (int i = 0; i < 3; ++i)
                poly[count][i] = a[i] + t * (b[i] - a[i]);
            poly[count++][2] = near;
        }
    }
    if (count == 0) return 0;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int k = 0; k < count; ++k) {
        double sx = view->cx + view->focal[0] * poly[k][0] / poly[k][2];
        double sy = view->cy - view->focal[1] * poly[k][1] / poly[k][2];
        lo[0] = fmin(lo[0], sx), hi[0] = fmax(hi[0], sx);
        lo[1] = fmin(lo[1], sy), hi[1] = fmax(hi[1], sy);
    }
    /* Centres px + 0.5 in [lo, hi], widened by a hair for rounding in the projection: the
     * coverage test itself is exact, the box only has to contain it. */
    const double eps = 1e-6;
    double bx0 = fmax(ceil(lo[0] - 0.5 - eps), 0.0), by0 = fmax(ceil(lo[1] - 0.5 - eps), 0.0);
    double bx1 = fmin(floor(hi[0] - 0.5 + eps), view->width - 1.0);
    double by1 = fmin(floor(hi[1] - 0.5 + eps), view->height - 1.0);
    if (!(bx0 <= bx1 && by0 <= by1)) return 0; /* off screen (or NaN) */
    *x0 = (int)bx0, *y0 = (int)by0, *x1 = (int)bx1, *y1 = (int)by1;
    return 1;
}

static void tri_setup_one(const pen_view *view, const double *cam, const uint32_t *idx,
                          tri_setup *s) {
    double v[3][3];
    for (int k = 0; k < 3; ++k)
        memcpy(v[k], cam + 3 * (size_t)idx[k], sizeof v[k]);
    for (int k = 0; k < 3; ++k)
        pen__cross_d(v[(k + 1) % 3], v[(k + 2) % 3], s->n[k]);
    s->det = pen__dot_d(v[0], s->n[0]);
    s->x0 = 1, s->x1 = 0;
    if (s->det == 0.0 || !isfinite(s->det)) return; /* degenerate or edge-on: covers nothing */
    tri_bounds(view, v, &s->x0, &s->y0, &s->x1, &s->y1);
}

/* A pixel exactly on an edge (E == 0) belongs to the triangle whose signed edge coefficients
 * point right (or down when vertical); the neighbour across the edge sees them negated. */
static int edge_owns_ties(const double n[3], double sign) {
    double a = sign * n[0], b = sign * n[1];
    return a > 0.0 || (a == 0.0 && b > 0.0);
}

/* ---- Tiles ----------------------------------------------------------------------------------- */

typedef struct tile_ctx {
    const pen_view *view;
    const pen_ground *ground;
    const tri_setup *setups;
    const int *bin_start; /* per tile, into bin_items */
    const int *bin_items;
    const double *rx, *ry; /* per column / row: camera-space ray of the pixel centre */
    const double *rxr;     /* per column: rx right, pen_view_ray's first term (x, y, z: 3 rows) */
    pen_gbuffer *gb;
    float *points; /* NULL, or pen_gbuffer_points' values of the pixels off the objects */
} tile_ctx;

/* The ground square over the columns x0 .. x1 of row y (the tile row's buffers, from column x0):
 * the ray meets the plane at depth z = (height - eye_y) / D_y, a hit in front of the near plane,
 * closer than the triangles and inside the square. D is pen_view_ray's sum from the tables
 * ((rx right + ry up) + forward, the products the same), so its bits are too; with SSE2 two
 * columns at a time, each lane the scalar's operations and comparisons (false on a NaN alike). */
static void ground_row(const tile_ctx *tc, int y, double num, double hs, int x0, int x1,
                       double *depth, double *bu, double *bv, int *surf, int *tri) {
    const pen_view *view = tc->view;
    const double ry = tc->ry[y], near = view->near_plane;
    const double ryu[3] = {ry * view->up[0], ry * view->up[1], ry * view->up[2]};
    const double *r0 = tc->rxr, *r1 = r0 + view->width, *r2 = r1 + view->width;
    int x = x0;
#if defined(__SSE2__)
    const __m128d u0 = _mm_set1_pd(ryu[0]), u1 = _mm_set1_pd(ryu[1]), u2 = _mm_set1_pd(ryu[2]);
    const __m128d f0 = _mm_set1_pd(view->forward[0]), f1 = _mm_set1_pd(view->forward[1]);
    const __m128d f2 = _mm_set1_pd(view->forward[2]), e0 = _mm_set1_pd(view->eye[0]);
    const __m128d e2 = _mm_set1_pd(view->eye[2]), nm = _mm_set1_pd(num), nr = _mm_set1_pd(near);
    const __m128d h = _mm_set1_pd(hs), sign = _mm_set1_pd(-0.0);
    for (; x + 1 <= x1; x += 2) {
        const int i = x - x0;
        const __m128d D0 = _mm_add_pd(_mm_add_pd(_mm_loadu_pd(r0 + x), u0), f0);
        const __m128d D1 = _mm_add_pd(_mm_add_pd(_mm_loadu_pd(r1 + x), u1), f1);
        const __m128d D2 = _mm_add_pd(_mm_add_pd(_mm_loadu_pd(r2 + x), u2), f2);
        const __m128d z = _mm_div_pd(nm, D1);
        const __m128d hx = _mm_add_pd(e0, _mm_mul_pd(z, D0));
        const __m128d hz = _mm_add_pd(e2, _mm_mul_pd(z, D2));
        const __m128d in =
            _mm_and_pd(_mm_and_pd(_mm_cmpge_pd(z, nr), _mm_cmplt_pd(z, _mm_loadu_pd(depth + i))),
                       _mm_and_pd(_mm_cmple_pd(_mm_andnot_pd(sign, hx), h),
                                  _mm_cmple_pd(_mm_andnot_pd(sign, hz), h)));
        const int hit = _mm_movemask_pd(in);
        if (!hit) continue;
        double zz[2];
        _mm_storeu_pd(zz, z);
        for (int k = 0; k < 2; ++k)
            if (hit >> k & 1) {
                depth[i + k] = zz[k], bu[i + k] = bv[i + k] = 0.0;
                surf[i + k] = PEN_SURFACE_GROUND, tri[i + k] = -1;
            }
    }
#endif
    for (; x <= x1; ++x) {
        const int i = x - x0;
        const double D0 = r0[x] + ryu[0] + view->forward[0];
        const double D1 = r1[x] + ryu[1] + view->forward[1];
        const double D2 = r2[x] + ryu[2] + view->forward[2];
        double z = num / D1;
        double hx = view->eye[0] + z * D0, hz = view->eye[2] + z * D2;
        if (z >= near && z < depth[i] && fabs(hx) <= hs && fabs(hz) <= hs) {
            depth[i] = z, bu[i] = bv[i] = 0.0;
            surf[i] = PEN_SURFACE_GROUND, tri[i] = -1;
        }
    }
}

static void raster_tile(const tile_ctx *tc, int tx, int ty, int tiles_x) {
    const pen_view *view = tc->view;
    int X0 = tx * TILE, Y0 = ty * TILE;
    int X1 = X0 + TILE - 1 < view->width - 1 ? X0 + TILE - 1 : view->width - 1;
    int Y1 = Y0 + TILE - 1 < view->height - 1 ? Y0 + TILE - 1 : view->height - 1;
    double depth[TILE * TILE], bu[TILE * TILE], bv[TILE * TILE];
    int surf[TILE * TILE], tri[TILE * TILE];
    for (int i = 0; i < TILE * TILE; ++i) {
        depth[i] = INFINITY, bu[i] = bv[i] = 0.0;
        surf[i] = PEN_SURFACE_BACKGROUND, tri[i] = -1;
    }
    double near = view->near_plane;
    int tile = ty * tiles_x + tx;
    for (int it = tc->bin_start[tile]; it < tc->bin_start[tile + 1]; ++it) {
        const tri_setup *s = tc->setups + tc->bin_items[it];
        double sign = s->det > 0.0 ? 1.0 : -1.0;
        int own[3];
        for (int k = 0; k < 3; ++k)
            own[k] = edge_owns_ties(s->n[k], sign);
        int xa = s->x0 > X0 ? s->x0 : X0, xb = s->x1 < X1 ? s->x1 : X1;
        int ya = s->y0 > Y0 ? s->y0 : Y0, yb = s->y1 < Y1 ? s->y1 : Y1;
        for (int y = ya; y <= yb; ++y) {
            const double ry = tc->ry[y]; /* n[k][1] ry once a row: the same product */
            const double nry[3] = {s->n[0][1] * ry, s->n[1][1] * ry, s->n[2][1] * ry};
            for (int x = xa; x <= xb; ++x) {
                double rx = tc->rx[x], e[3];
                int inside = 1;
                for (int k = 0; k < 3 && inside; ++k) {
                    e[k] = sign * (s->n[k][0] * rx + nry[k] + s->n[k][2]);
                    inside = e[k] > 0.0 || (e[k] == 0.0 && own[k]);
                }
                if (!inside) continue;
                double sum = e[0] + e[1] + e[2];
                if (!(sum > 0.0)) continue; /* all three on edges: no well-defined point */
                double z = sign * s->det / sum;
                int i = (y - Y0) * TILE + (x - X0);
                if (!(z >= near && z < depth[i])) continue;
                depth[i] = z, bu[i] = e[1] / sum, bv[i] = e[2] / sum;
                surf[i] = s->object, tri[i] = s->tri;
            }
        }
    }
    /* The ground after the triangles, and the tile written out. */
    const pen_ground *g = tc->ground;
    const int ground = g && g->enabled;
    const double num = ground ? (double)g->height - view->eye[1] : 0.0;
    const double hs = ground ? (double)g->half_size : 0.0;
    for (int y = Y0; y <= Y1; ++y) {
        const int r = (y - Y0) * TILE;
        if (ground)
            ground_row(tc, y, num, hs, X0, X1, depth + r, bu + r, bv + r, surf + r, tri + r);
        const size_t row = (size_t)y * (size_t)view->width;
        /* With points: pen_gbuffer_points' value of each pixel off the objects, the point at
         * the float depth on the pixel's ray (D as pen_view_ray's sum from the tables, as
         * there), zeros on the background. */
        float *pts = tc->points ? tc->points + 3 * row : NULL;
        const double ry = tc->ry[y];
        const double ryu[3] = {ry * view->up[0], ry * view->up[1], ry * view->up[2]};
        const double e[3] = {view->eye[0], view->eye[1], view->eye[2]};
        const double f[3] = {view->forward[0], view->forward[1], view->forward[2]};
        const double *rr[3] = {tc->rxr, tc->rxr + view->width, tc->rxr + 2 * view->width};
        for (int x = X0; x <= X1; ++x) {
            const int i = r + (x - X0);
            size_t o = row + (size_t)x;
            const float d = (float)depth[i];
            tc->gb->surface[o] = surf[i];
            tc->gb->triangle[o] = tri[i];
            tc->gb->bary[2 * o] = (float)bu[i];
            tc->gb->bary[2 * o + 1] = (float)bv[i];
            tc->gb->depth[o] = d;
            if (!pts || surf[i] >= 0) continue;
            float *p = pts + 3 * (size_t)x;
            if (surf[i] == PEN_SURFACE_BACKGROUND) {
                p[0] = p[1] = p[2] = 0.0f;
            } else if (surf[i] == PEN_SURFACE_GROUND) {
                for (int c = 0; c < 3; ++c)
                    p[c] = (float)(e[c] + (double)d * (rr[c][x] + ryu[c] + f[c]));
            }
        }
    }
}

/* ---- Rasterization --------------------------------------------------------------------------- */

pen_status pen_raster_gbuffer(pen_context *ctx, const pen_view *view, const pen_raster_mesh *meshes,
                              int mesh_count, const pen_ground *ground, pen_gbuffer *gb) {
    return pen__raster_gbuffer_points(ctx, view, meshes, mesh_count, ground, gb, NULL);
}

pen_status pen__raster_gbuffer_points(pen_context *ctx, const pen_view *view,
                                      const pen_raster_mesh *meshes, int mesh_count,
                                      const pen_ground *ground, pen_gbuffer *gb, float *points) {
    if (!view || !gb || !gb->surface)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: NULL view or G-buffer");
    if (gb->width != view->width || gb->height != view->height)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: G-buffer %dx%d, camera %dx%d",
                          gb->width, gb->height, view->width, view->height);
    if (!(view->near_plane > 0.0) || !isfinite(view->near_plane))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: near plane %g is not positive",
                          view->near_plane);
    if (ground && ground->enabled &&
        (!isfinite(ground->height) || !isfinite(ground->half_size) || ground->half_size < 0.0f))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "raster: ground height %g, half_size %g",
                          (double)ground->height, (double)ground->half_size);
    size_t total = 0;
    pen_status st = pen__raster_check_meshes(ctx, meshes, mesh_count, &total);
    if (st) return st;

    int W = view->width, H = view->height;
    int tiles_x = (W + TILE - 1) / TILE, tiles_y = (H + TILE - 1) / TILE;
    size_t tiles = (size_t)tiles_x * (size_t)tiles_y;
    size_t max_vertices = 0;
    for (int m = 0; m < mesh_count; ++m)
        if ((size_t)meshes[m].vertex_count > max_vertices)
            max_vertices = (size_t)meshes[m].vertex_count;

    tri_setup *setups = pen__malloc(ctx, total ? total : 1, sizeof *setups, "raster setups");
    double *cam = pen__malloc(ctx, 3 * (max_vertices ? max_vertices : 1), sizeof(double),
                              "raster camera-space vertices");
    int *bin_start = pen__calloc(ctx, tiles + 1, sizeof(int), "raster bins");
    double *rx = pen__malloc(ctx, 4 * (size_t)W + (size_t)H, sizeof(double), "raster rays");
    int *bin_items = NULL;
    if (!setups || !cam || !bin_start || !rx) {
        st = PEN_ERROR_MEMORY;
        goto done;
    }
    double *ry = rx + W, *rxr = ry + H;
    for (int x = 0; x < W; ++x) {
        rx[x] = (x + 0.5 - view->cx) / view->focal[0];
        for (int c = 0; c < 3; ++c)
            rxr[(size_t)c * (size_t)W + (size_t)x] = rx[x] * view->right[c];
    }
    for (int y = 0; y < H; ++y)
        ry[y] = (view->cy - (y + 0.5)) / view->focal[1];

    /* Setup, mesh by mesh (camera-space vertices shared by a mesh's triangles). */
    size_t base = 0;
    for (int m = 0; m < mesh_count; ++m) {
        const pen_raster_mesh *mesh = meshes + m;
        int nv = mesh->vertex_count, nt = mesh->triangle_count;
        int vthreads = pen__raster_threads_for(ctx, (size_t)nv);
        int tthreads = pen__raster_threads_for(ctx, (size_t)nt);
#pragma omp parallel for num_threads(vthreads) schedule(static)
        for (int v = 0; v < nv; ++v)
            to_camera(view, mesh->positions + 3 * (size_t)v, cam + 3 * (size_t)v);
#pragma omp parallel for num_threads(tthreads) schedule(static)
        for (int t = 0; t < nt; ++t) {
            tri_setup *s = setups + base + (size_t)t;
            tri_setup_one(view, cam, mesh->indices + 3 * (size_t)t, s);
            s->object = m, s->tri = t;
        }
        base += (size_t)nt;
    }

    /* Binning in triangle order: count, prefix sum, fill. */
    size_t items = 0;
    for (size_t i = 0; i < total; ++i) {
        const tri_setup *s = setups + i;
        if (s->x0 > s->x1) continue;
        for (int ty = s->y0 / TILE; ty <= s->y1 / TILE; ++ty)
            for (int tx = s->x0 / TILE; tx <= s->x1 / TILE; ++tx)
                ++bin_start[ty * tiles_x + tx + 1];
    }
    for (size_t t = 0; t < tiles; ++t) {
        items += (size_t)bin_start[t + 1];
        if (items > (size_t)INT_MAX) {
            st = pen__error(ctx, PEN_ERROR_MEMORY, "raster: %zu tile entries exceed %d", items,
                            INT_MAX);
            goto done;
        }
        bin_start[t + 1] = (int)items;
    }
    bin_items = pen__malloc(ctx, items ? items : 1, sizeof(int), "raster bin items");
    if (!bin_items) {
        st = PEN_ERROR_MEMORY;
        goto done;
    }
    {
        int *fill = pen__malloc(ctx, tiles, sizeof(int), "raster bin cursor");
        if (!fill) {
            st = PEN_ERROR_MEMORY;
            goto done;
        }
        memcpy(fill, bin_start, tiles * sizeof(int));
        for (size_t i = 0; i < total; ++i) {
            const tri_setup *s = setups + i;
            if (s->x0 > s->x1) continue;
            for (int ty = s->y0 / TILE; ty <= s->y1 / TILE; ++ty)
                for (int tx = s->x0 / TILE; tx <= s->x1 / TILE; ++tx)
                    bin_items[fill[ty * tiles_x + tx]++] = (int)i;
        }
        free(fill);
    }

    tile_ctx tc = {view, ground, setups, bin_start, bin_items, rx, ry, rxr, gb, points};
    int ntiles = (int)tiles;
    int threads = pen__raster_threads_for(ctx, (size_t)W * (size_t)H);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
    for (int t = 0; t < ntiles; ++t)
        raster_tile(&tc, t % tiles_x, t / tiles_x, tiles_x);

done:
    free(setups);
    free(cam);
    free(bin_start);
    free(bin_items);
    free(rx);
    return st;
}

/* ---- Barycentrics of a ray: forward and backward --------------------------------------------- */

int pen__raster_ray_bary_d(const double eye[3], const double dir[3], const double p0[3],
                           const double p1[3], const double p2[3], double x[3]) {
    double c[3][3], rhs[3];
    for (int i = 0; i < 3; ++i)
        c[0][i] = -dir[i], c[1][i] = p1[i] - p0[i], c[2][i] = p2[i] - p0[i];
    pen__sub_d(eye, p0, rhs);
    double r[3][3];
    for (int k = 0; k < 3; ++k)
        pen__cross_d(c[(k + 1) % 3], c[(k + 2) % 3], r[k]);
    double det = pen__dot_d(c[0], r[0]);
    if (det == 0.0 || !isfinite(det)) return 0;
    /* Cramer: the rows of M^-1 are (c_{k+1} x c_{k+2}) / det. */
    for (int k = 0; k < 3; ++k)
        x[k] = pen__dot_d(r[k], rhs) / det;
    return 1;
}

void pen__raster_ray_bary_bwd_d(const double eye[3], const double dir[3], const double p0[3],
                                const double p1[3], const double p2[3], const double x[3],
                                const double d_x[3], double d_p0[3], double d_p1[3],
                                double d_p2[3]) {
    (void)eye;
    double c[3][3];
    for (int i = 0; i < 3; ++i)
        c[0][i] = -dir[i], c[1][i] = p1[i] - p0[i], c[2][i] = p2[i] - p0[i];
    double r[3][3];
    for (int k = 0; k < 3; ++k)
        pen__cross_d(c[(k + 1) % 3], c[(k + 2) % 3], r[k]);
    double det = pen__dot_d(c[0], r[0]);
    if (det == 0.0 || !isfinite(det)) return;
    double w[3];
    for (int i = 0; i < 3; ++i)
        w[i] = (d_x[0] * r[0][i] + d_x[1] * r[1][i] + d_x[2] * r[2][i]) / det;
    double b0 = 1.0 - x[1] - x[2];
    for (int i = 0; i < 3; ++i) {
        d_p0[i] -= b0 * w[i];
        d_p1[i] -= x[1] * w[i];
        d_p2[i] -= x[2] * w[i];
    }
}

/* pen_view_ray's first term rx right for every column (3 doubles a column; NULL when out of
 * memory): with ry up per row, summed in its order ((rx right + ry up) + forward), a pixel's ray
 * has the same bits without two divisions and a call a pixel. */
static double *ray_right_terms(const pen_view *view) {
    double *rxr = malloc(sizeof(double) * 3 * (size_t)view->width);
    if (rxr)
        for (int x = 0; x < view->width; ++x) {
            const double rx = (x + 0.5 - view->cx) / view->focal[0];
            for (int c = 0; c < 3; ++c)
                rxr[3 * x + c] = rx * view->right[c];
        }
    return rxr;
}

/* pen__raster_ray_bary_d and then pen__raster_ray_bary_bwd_d at its solution, into dp (written,
 * as the backward's sums into zeros), sharing the matrix, its cofactors and determinant: the same
 * arithmetic, so the same bits. Returns 0 (dp untouched) when the ray is parallel to the plane. */
static int ray_bary_solve_bwd(const double eye[3], const double dir[3], const double p[3][3],
                              const double d_x[3], double dp[3][3]) {
    double c[3][3], rhs[3], r[3][3];
    for (int i = 0; i < 3; ++i)
        c[0][i] = -dir[i], c[1][i] = p[1][i] - p[0][i], c[2][i] = p[2][i] - p[0][i];
    pen__sub_d(eye, p[0], rhs);
    for (int k = 0; k < 3; ++k)
        pen__cross_d(c[(k + 1) % 3], c[(k + 2) % 3], r[k]);
    double det = pen__dot_d(c[0], r[0]);
    if (det == 0.0 || !isfinite(det)) return 0;
    const double x1 = pen__dot_d(r[1], rhs) / det, x2 = pen__dot_d(r[2], rhs) / det;
    double w[3];
    for (int i = 0; i < 3; ++i)
        w[i] = (d_x[0] * r[0][i] + d_x[1] * r[1][i] + d_x[2] * r[2][i]) / det;
    const double b0 = 1.0 - x1 - x2;
    for (int i = 0; i < 3; ++i) {
        dp[0][i] = 0.0 - b0 * w[i];
        dp[1][i] = 0.0 - x1 * w[i];
        dp[2][i] = 0.0 - x2 * w[i];
    }
    return 1;
}

pen_status pen_raster_bary_bwd(pen_context *ctx, const pen_view *view,
                               const pen_raster_mesh *meshes, int mesh_count, const pen_gbuffer *gb,
                               const float *d_bary, float *const *d_positions) {
    if (!d_positions || !d_bary) return PEN_OK;
    float *g = pen__malloc(ctx, 9 * (size_t)gb->width * (size_t)gb->height, sizeof(float),
                           "barycentric backward");
    if (!g) return PEN_ERROR_MEMORY;
    pen_raster_bary_bwd_scratch(ctx, view, meshes, mesh_count, gb, d_bary, d_positions, g);
    free(g);
    return PEN_OK;
}

void pen_raster_bary_bwd_scratch(pen_context *ctx, const pen_view *view,
                                 const pen_raster_mesh *meshes, int mesh_count,
                                 const pen_gbuffer *gb, const float *d_bary,
                                 float *const *d_positions, float *g) {
    if (!d_positions || !d_bary) return;
    size_t n = (size_t)gb->width * (size_t)gb->height;
    /* Each pixel's three vertex gradients are solved in parallel into the scratch buffer, then
     * added to the shared vertices serially in pixel order, so sums do not depend on threads. */
    int W = gb->width, H = gb->height, threads = pen__raster_threads_for(ctx, n);
    double *rxr = ray_right_terms(view); /* NULL: pen_view_ray per pixel */
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y) {
        const double ry = (view->cy - (y + 0.5)) / view->focal[1];
        for (int x = 0; x < W; ++x) {
            size_t i = (size_t)y * (size_t)W + (size_t)x;
            if ((x & 3) == 0 && x + 4 <= W && pen__no_mesh4(gb->surface + i)) {
                x += 3;
                continue;
            }
            int m = gb->surface[i];
            if (m < 0 || m >= mesh_count || !d_positions[m]) continue; /* (not read below) */
            float *gi = g + 9 * i;
            gi[0] = NAN; /* marks "nothing to add" */
            double dx[3] = {0.0, (double)d_bary[2 * i], (double)d_bary[2 * i + 1]};
            if (dx[1] == 0.0 && dx[2] == 0.0) continue;
            const pen_raster_mesh *mesh = meshes + m;
            const uint32_t *idx = mesh->indices + 3 * (size_t)gb->triangle[i];
            double p[3][3], D[3], dp[3][3];
            for (int k = 0; k < 3; ++k)
                pen__load3_d(mesh->positions + 3 * (size_t)idx[k], p[k]);
            if (rxr)
                for (int c = 0; c < 3; ++c) /* pen_view_ray's sum, from the tables */
                    D[c] = rxr[3 * x + c] + ry * view->up[c] + view->forward[c];
            else
                pen_view_ray(view, x + 0.5, y + 0.5, D);
            if (!ray_bary_solve_bwd(view->eye, D, p, dx, dp)) continue;
            for (int k = 0; k < 9; ++k)
                gi[k] = (float)dp[k / 3][k % 3];
        }
    }
    free(rxr);
    for (size_t i = 0; i < n; ++i) {
        if ((i & 3) == 0 && i + 4 <= n && pen__no_mesh4(gb->surface + i)) {
            i += 3;
            continue;
        }
        int m = gb->surface[i];
        if (m < 0 || m >= mesh_count || !d_positions[m]) continue;
        const float *gi = g + 9 * i;
        if (isnan(gi[0])) continue;
        const uint32_t *idx = meshes[m].indices + 3 * (size_t)gb->triangle[i];
        for (int k = 0; k < 9; ++k)
            d_positions[m][3 * (size_t)idx[k / 3] + k % 3] += gi[k];
    }
}

void pen_gbuffer_points(const pen_view *view, const pen_gbuffer *gb, float *out) {
    const int W = gb->width;
    double *rxr = ray_right_terms(view); /* NULL: pen_view_ray per pixel */
    for (int y = 0; y < gb->height; ++y) {
        const double ry = (view->cy - (y + 0.5)) / view->focal[1];
        const double ryu[3] = {ry * view->up[0], ry * view->up[1], ry * view->up[2]};
        for (int x = 0; x < W; ++x) {
            size_t i = (size_t)y * (size_t)W + (size_t)x;
            float *o = out + 3 * i;
            if (gb->surface[i] == PEN_SURFACE_BACKGROUND) {
                o[0] = o[1] = o[2] = 0.0f;
                continue;
            }
            double D[3], z = (double)gb->depth[i];
            if (rxr)
                for (int c = 0; c < 3; ++c)
                    D[c] = rxr[3 * x + c] + ryu[c] + view->forward[c];
            else
                pen_view_ray(view, x + 0.5, y + 0.5, D);
            for (int c = 0; c < 3; ++c)
                o[c] = (float)(view->eye[c] + z * D[c]);
        }
    }
    free(rxr);
}

/* ---- Edge adjacency -------------------------------------------------------------------------- */

typedef struct half_edge {
    uint64_t key; /* (min vertex << 32) | max vertex */
    uint32_t id;  /* 3 * triangle + edge */
} half_edge;

static int half_edge_cmp(const void *a, const void *b) {
    const half_edge *x = a, *y = b;
    if (x->key != y->key) return x->key < y->key ? -1 : 1;
    return x->id < y->id ? -1 : x->id > y->id;
}

pen_status pen_raster_adjacency(pen_context *ctx, int vertex_count, int triangle_count,
                                const uint32_t *indices, int32_t *adjacency) {
    if (triangle_count < 0 || triangle_count > INT32_MAX / 3 || vertex_count < 0 ||
        (triangle_count > 0 && (!indices || !adjacency)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "adjacency: bad arguments (%d triangles)",
                          triangle_count);
    size_t n = 3 * (size_t)triangle_count;
    for (size_t i = 0; i < n; ++i)
        if (indices[i] >= (uint32_t)vertex_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "adjacency: triangle %zu: index %u out of range [0, %d)", i / 3,
                              indices[i], vertex_count);
    /* Sorted by (key, id) as one qsort would, but by a counting sort on the lower vertex (ids
     * ascending within each vertex's bucket) and then each bucket by the upper one: a bucket holds
     * a vertex's few edges, and a qsort of every half-edge cost more than the rest of a frame's
     * setup. A stable insertion sort keeps equal keys in id order; a crowded vertex gets qsort. */
    half_edge *he = pen__malloc(ctx, n ? n : 1, sizeof *he, "adjacency half-edges");
    size_t *start = pen__calloc(ctx, (size_t)vertex_count + 1, sizeof *start, "adjacency buckets");
    if (!he || !start) {
        free(he);
        free(start);
        return PEN_ERROR_MEMORY;
    }
    for (size_t i = 0; i < n; ++i) {
        uint32_t a = indices[i], b = indices[i - i % 3 + (i % 3 + 1) % 3];
        ++start[(a < b ? a : b) + 1];
        adjacency[i] = -1;
    }
    for (int v = 0; v < vertex_count; ++v)
        start[v + 1] += start[v];
    for (size_t i = 0; i < n; ++i) {
        uint32_t a = indices[i], b = indices[i - i % 3 + (i % 3 + 1) % 3];
        uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
        half_edge *e = he + start[lo]++; /* start[lo] ends at the bucket's end */
        e->key = ((uint64_t)lo << 32) | hi;
        e->id = (uint32_t)i;
    }
    for (int v = 0; v < vertex_count; ++v) {
        half_edge *b = he + (v ? start[v - 1] : 0);
        const size_t count = (size_t)(he + start[v] - b);
        if (count > 32) {
            qsort(b, count, sizeof *b, half_edge_cmp);
            continue;
        }
        for (size_t j = 1; j < count; ++j) {
            const half_edge x = b[j];
            size_t k = j;
            for (; k > 0 && b[k - 1].key > x.key; --k)
                b[k] = b[k - 1];
            b[k] = x;
        }
    }
    free(start);
    for (size_t i = 0; i < n;) {
        size_t j = i + 1;
        while (j < n && he[j].key == he[i].key)
            ++j;
        uint32_t e0 = he[i].id, e1 = he[i + (j - i > 1)].id;
        int degenerate = (he[i].key >> 32) == (he[i].key & 0xffffffffu);
        if (j - i == 2 && e0 / 3 != e1 / 3 && !degenerate) {
            adjacency[e0] = (int32_t)e1;
            adjacency[e1] = (int32_t)e0;
        }
        i = j;
    }
    free(he);
    return PEN_OK;
}
