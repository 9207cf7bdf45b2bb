/* The ground's shadows of rigid objects by a precomputed transfer (docs/design.md sec. 1.15): the
 * shadows that objects shaded with their own transfer (self.c) cast on the ground, ray traced
 * against their meshes at a grid of nodes on the ground square instead of read from their
 * spheres. A ground pixel then shades with T = exp*(F_others) * (H_up - B(x)): H_up the clamped
 * cosine around +Y, B the part of it the meshes block, interpolated from the nodes, and F_others
 * the log-visibility of the spheres of the objects without the transfer (the same weights as the
 * kernels). Disk lights see the meshes' unblocked fraction of each disk, interpolated likewise,
 * times the other spheres' factor.
 *
 * Design
 * - Why. Fitted spheres cover thin parts (legs, tails) fatly, and their shadows on the ground are
 *   too dark in long streaks; on the dev meshes that was 90-98 % of the image's squared error
 *   once the objects' own pixels used the transfer (docs/visibility.md sec. 10).
 * - The grid. N x N nodes, x = c + A sinh(beta s) per axis (z alike), s in [-1, 1] uniform over
 *   the nodes, c the transferred objects' centre (clamped into the square). The scale A follows
 *   the objects (GRID_SCALE times their horizontal half-extent R) and beta, per side of c, is
 *   what lands s = +-1 on the square's edge, asinh(D / A) for an edge D away: the spacing near
 *   the objects is then A beta / (N / 2), set by their size and only logarithmically by the
 *   square's (a ground drawn out to the horizon keeps its contact shadows), and at a distance
 *   x >> A it is about beta x / (N / 2), a fixed share of the distance. The warp puts the nodes
 *   where shadows have detail (contact lines, thin parts close to the ground) and few where the
 *   ground is far from everything and its shadow smooth. Pixels interpolate bilinearly in s, so
 *   the warp costs two asinh per pixel. GRID_N and GRID_SCALE were chosen by measurement
 *   (bench/NOTES.md, docs/visibility.md sec. 11); "shadow": {"ground_grid": N} overrides N.
 * - One trace for all: the meshes of every object with the transfer are the occluders of one
 *   pen__transfer request (the ground does not shadow itself), the nodes its receivers (+Y).
 * - The cache. In the render state with a key: every transferred object's posed vertices and
 *   indices, the band count, the lights, the ground's height and size and the grid's size. A
 *   lighting, albedo or texture optimisation pays the trace once; a pose change pays it again.
 *   The grid is in world space: the states of a pool (the views of a task) hold one immutable
 *   trace by reference (transfer_pool.h), not a copy each (0.6 MB a view at 4 bands).
 * - The lights per pixel. A thin part's shadow under a low sun is narrower than the node spacing
 *   where it falls: interpolated, the fractions draw it as beads where nodes catch it and lose it
 *   between (a tube frame under a sun 8 degrees up: cast-shadow error 1.35 times an 8x finer
 *   grid's, docs/visibility.md "Thin parts on the ground"). B is smooth and stays on the grid;
 *   the fractions are traced per pixel where the grid cannot be trusted: one ray per ground
 *   pixel to each light's centre, then the full disk sampling of the transfer where that ray
 *   disagrees with the interpolation or the cell's corners differ, and around such pixels
 *   (pixel_trace). About 5 % of that render's time, against 2.8 times for a 384 grid that still
 *   beaded. Per render state, not in the pool: it depends on the camera.
 * - Constants. As for the self transfer, B and the fractions carry no gradient (pose, shape and
 *   light directions); the lighting, the lights' irradiance, the ground albedo and the other
 *   objects' spheres get theirs exactly. Optimisers of pose, shape, spheres or light directions
 *   force PEN_RENDER_SELF_SPHERES, which leaves no object with the transfer and so turns the grid
 *   off with it.
 * - One code path. Ground pixels with the grid go through the scalar kernel's transfer functions
 *   (pen__shade_self_fwd / bwd, pen__lights_fwd / bwd) whichever kernel the frame uses, with
 *   kappa_grid: the overlap weights, 0 on the transferred objects' spheres.
 */
#include "core/internal.h"
#include "geometry/transfer.h"
#include "render/render_internal.h"
#include "render/transfer_pool.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Nodes per side. Measured on the six dev meshes x six maps at 160 x 160 (docs/visibility.md
 * sec. 10), mean / worst image rel. RMSE: 32: 0.0327 / 0.054, 64: 0.0291 / 0.038, 96: 0.0281 /
 * 0.035, 128: 0.0276 / 0.035; the gain left is on the interior map's sharp lamps. The trace costs
 * about 21 us of CPU per node (bench/NOTES.md): 0.2 s at 96, as a 6k-vertex mesh's own transfer;
 * 128 would pay 1.8 times that for 0.0005. */
#define GRID_N 96
/* The warp's scale A, relative to the objects' horizontal half-extent R. On the dev scenes (a
 * 1.7-unit object, R about 0.8, on a square of half size 4) 0.5 gives beta about 3, where a fixed
 * beta of 2 / 3 / 4 had given mean image rel. RMSE 0.0298 / 0.0291 / 0.0296 at N = 64
 * (docs/visibility.md sec. 11). A fixed beta instead (A from the square) let the spacing near the
 * objects grow with the square: blub's image error was 0.034, 0.076, 0.208 at half sizes 10, 100,
 * 500 (the spheres: 0.11). */
#define GRID_SCALE 0.5

/* ---- The grid -------------------------------------------------------------------------------- */

/* Position on one axis of grid coordinate s in [-1, 1]. */
static double grid_pos(const pen__ground_grid *gr, int axis, double s) {
    const double b = s < 0.0 ? gr->beta[axis][0] : gr->beta[axis][1];
    return gr->c[axis] + gr->a[axis] * sinh(b * s);
}

/* Its inverse, clamped to [-1, 1]. */
static double grid_coord(const pen__ground_grid *gr, int axis, double x) {
    const double d = x - gr->c[axis], b = d < 0.0 ? gr->beta[axis][0] : gr->beta[axis][1];
    if (!(b > 0.0)) return d < 0.0 ? -1.0 : 1.0;
    const double s = asinh(d / gr->a[axis]) / b;
    return s < -1.0 ? -1.0 : s > 1.0 ? 1.0 : s;
}

/* The grid's shape for this frame: nodes per side, the centre of the transferred objects' posed
 * vertices (x and z) clamped into the square, and the scales per side. */
static void grid_shape(const pen_scene *sc, const pen_render_state *st, pen__ground_grid *gr) {
    gr->n = sc->shadow.ground_grid > 0 ? sc->shadow.ground_grid : GRID_N;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int o = 0; o < sc->object_count; ++o) {
        if (!st->obj[o].self_on) continue;
        const float *w = st->obj[o].world.data;
        for (int v = 0; v < sc->objects[o].mesh.vertex_count; ++v)
            for (int a = 0; a < 2; ++a) {
                const double x = (double)w[3 * (size_t)v + 2 * (size_t)a];
                lo[a] = fmin(lo[a], x), hi[a] = fmax(hi[a], x);
            }
    }
    const double h = (double)sc->ground.half_size, room = 0.5 * h;
    double R = 0.0; /* the objects' horizontal half-extent */
    for (int a = 0; a < 2; ++a)
        R = lo[a] <= hi[a] ? fmax(R, 0.5 * (hi[a] - lo[a])) : R;
    /* at least 1e-3 of the square: a flat or point-like object still gets a finite warp */
    const double A = fmax(GRID_SCALE * R, 1e-3 * h);
    for (int a = 0; a < 2; ++a) {
        double c = lo[a] <= hi[a] ? 0.5 * (lo[a] + hi[a]) : 0.0;
        c = c < -room ? -room : c > room ? room : c; /* both sides keep room for nodes */
        gr->c[a] = c, gr->a[a] = A;
        gr->beta[a][0] = asinh((c + h) / A);
        gr->beta[a][1] = asinh((h - c) / A);
    }
}

/* The cache key: what the nodes' transfer depends on. The transferred objects' own keys (self.c)
 * were made this frame by pen__self_prepare, which runs first, and already hash their posed
 * vertices, indices, the band count and the lights (with at least one such object, or no grid),
 * so they stand for the meshes here instead of hashing every vertex a second time. */
static uint64_t grid_key(const pen_scene *sc, const pen_render_state *st,
                         const pen__ground_grid *gr) {
    uint64_t h = ((uint64_t)sc->sh_bands ^ ((uint64_t)gr->n << 16)) * 0x9E3779B97F4A7C15ull;
    for (int o = 0; o < sc->object_count; ++o) {
        if (!st->obj[o].self_on) continue;
        h = (h ^ (uint64_t)o) * 0x9E3779B97F4A7C15ull;
        h = (h ^ st->obj[o].self_key) * 0x9E3779B97F4A7C15ull;
    }
    const double g[9] = {(double)sc->ground.height, (double)sc->ground.half_size,
                         gr->c[0],
                         gr->c[1],
                         gr->a[0],
                         gr->beta[0][0],
                         gr->beta[0][1],
                         gr->beta[1][0],
                         gr->beta[1][1]};
    return (h ^ pen__render_hash32(g, sizeof g / 4)) * 0x9E3779B97F4A7C15ull;
}

/* The request of P receivers facing +Y against the transferred objects' meshes, which it lists
 * in meshes (room for one per object). */
static pen__transfer_request request(const pen_scene *sc, const pen_render_state *st,
                                     pen__transfer_mesh *meshes, int P, const float *pts,
                                     const float *nrm) {
    int nm = 0;
    for (int o = 0; o < sc->object_count; ++o) {
        if (!st->obj[o].self_on) continue;
        const pen_mesh *m = &sc->objects[o].mesh;
        meshes[nm++] = (pen__transfer_mesh){m->vertex_count, m->triangle_count,
                                            st->obj[o].world.data, m->indices};
    }
    return (pen__transfer_request){nm,
                                   meshes,
                                   P,
                                   pts,
                                   nrm,
                                   sc->sh_bands,
                                   st->lights.count,
                                   (const double(*)[3])st->lights.w,
                                   st->lights.b,
                                   NULL}; /* the ground does not shadow itself */
}

/* Traces the nodes of grid gr against the transferred objects' meshes into blob's arrays. */
static pen_status grid_trace(pen_context *ctx, const pen_scene *sc, const pen_render_state *st,
                             const pen__ground_grid *gr, pen__transfer_blob *blob) {
    const int N = gr->n, O = sc->object_count;
    const size_t P = (size_t)N * (size_t)N;
    pen_status s;
    float *pts = pen__malloc(ctx, 6 * P, sizeof(float), "ground grid nodes");
    pen__transfer_mesh *meshes = pen__calloc(ctx, (size_t)O + 1, sizeof *meshes, "grid meshes");
    if (!pts || !meshes) {
        free(pts), free(meshes);
        return PEN_ERROR_MEMORY;
    }
    float *nrm = pts + 3 * P;
    for (int j = 0; j < N; ++j)
        for (int i = 0; i < N; ++i) {
            const size_t k = (size_t)j * (size_t)N + (size_t)i;
            const double si = -1.0 + 2.0 * i / (N - 1), sj = -1.0 + 2.0 * j / (N - 1);
            pts[3 * k] = (float)grid_pos(gr, 0, si);
            pts[3 * k + 1] = sc->ground.height;
            pts[3 * k + 2] = (float)grid_pos(gr, 1, sj);
            nrm[3 * k] = 0.0f, nrm[3 * k + 1] = 1.0f, nrm[3 * k + 2] = 0.0f;
        }
    /* The occluders stay with the trace: every camera's pixels trace them again (pixel_trace). */
    const pen__transfer_request rq = request(sc, st, meshes, (int)P, pts, nrm);
    s = pen__transfer_bvh_build(ctx, &rq, &blob->bvh);
    if (!s) s = pen__transfer_bvh_trace(ctx, blob->bvh, &rq, blob->B, blob->frac);
    free(pts), free(meshes);
    return s;
}

/* The grid cell of ground point x: its four nodes and their bilinear weights in s. */
static void grid_cell(const pen__ground_grid *gr, const float *x, size_t k[4], double w[4]) {
    const int N = gr->n;
    int i0[2];
    double t[2];
    for (int a = 0; a < 2; ++a) {
        const double u = 0.5 * (grid_coord(gr, a, (double)x[2 * a]) + 1.0) * (N - 1);
        int j = (int)u;
        j = j > N - 2 ? N - 2 : j;
        i0[a] = j, t[a] = u - j;
    }
    const size_t k00 = (size_t)i0[1] * (size_t)N + (size_t)i0[0];
    k[0] = k00, k[1] = k00 + 1, k[2] = k00 + (size_t)N, k[3] = k00 + (size_t)N + 1;
    w[0] = (1.0 - t[0]) * (1.0 - t[1]), w[1] = t[0] * (1.0 - t[1]);
    w[2] = (1.0 - t[0]) * t[1], w[3] = t[0] * t[1];
}

/* ---- The lights per pixel -------------------------------------------------------------------- */

/* A cell whose corners' fractions of a light differ by more than this holds an edge of its
 * shadow: bilinear there draws the edge as a ramp along the cells (beads along a thin part's
 * shadow), so its pixels trace the disk themselves. */
#define CORNER_SPREAD 0.02
/* Pixels around one whose centre ray disagrees with the grid that trace their disks too (in
 * pixels, each way): a shadow one or two pixels wide is hit by some centre rays and missed by
 * their neighbours, and its penumbra reaches past the ray's hit. */
#define DILATE 2

/* Which ground pixels the grid cannot be trusted at: flag[i] where some light's cell corners
 * differ, or where the ray towards its centre (c, 0 or 1 per light for the m pixels of pix)
 * disagrees with the interpolation (a shadow, or a gap in one, between the nodes). */
static void pixel_flags(const pen_render_state *st, size_t m, const int *pix, const float *pts,
                        const float *c, unsigned char *flag) {
    const pen__ground_grid *gr = &st->grid;
    const int K = st->lights.count;
    for (size_t q = 0; q < m; ++q) {
        size_t k[4];
        double w[4];
        grid_cell(gr, pts + 3 * q, k, w);
        for (int l = 0; l < K && !flag[pix[q]]; ++l) {
            double v = 0.0, lo = 1.0, hi = 0.0;
            for (int r = 0; r < 4; ++r) {
                const double f = (double)gr->frac[(size_t)K * k[r] + (size_t)l];
                v += w[r] * f, lo = fmin(lo, f), hi = fmax(hi, f);
            }
            flag[pix[q]] = hi - lo > CORNER_SPREAD || fabs((double)c[(size_t)K * q + l] - v) > 0.5;
        }
    }
}

/* flag grown by DILATE pixels each way over the ground's pixels, into out. */
static void dilate(const pen_render_state *st, const unsigned char *flag, unsigned char *out) {
    const int W = st->gb.width, H = st->gb.height;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            if (!flag[(size_t)y * (size_t)W + (size_t)x]) continue;
            for (int v = y - DILATE > 0 ? y - DILATE : 0; v <= y + DILATE && v < H; ++v)
                for (int u = x - DILATE > 0 ? x - DILATE : 0; u <= x + DILATE && u < W; ++u) {
                    const size_t j = (size_t)v * (size_t)W + (size_t)u;
                    out[j] |= st->gb.surface[j] == PEN_SURFACE_GROUND;
                }
        }
}

/* The disk lights' fractions per pixel (gr->pfrac) where the grid cannot be trusted: one ray
 * per ground pixel towards each light's centre, then the full disk sampling of the transfer at
 * the flagged pixels and their neighbours. Keyed by the grid's key and the frame's pixels_key
 * (self.c: the view and the geometry, which make the ground pixels and their points), so an
 * optimisation of lighting or albedo pays it once and its later frames do not visit the pixels
 * here at all. A frame without ground pixels keeps its all -1 fractions as valid too. */
static pen_status pixel_trace(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    pen__ground_grid *gr = &st->grid;
    const int K = st->lights.count;
    const size_t np = (size_t)st->gb.width * (size_t)st->gb.height;
    if (!K) return PEN_OK;
    const uint64_t key = (gr->key ^ st->pixels_key) * 0x9E3779B97F4A7C15ull;
    if (gr->pvalid && gr->pkey == key) return PEN_OK;
    gr->pvalid = 0;
    size_t m = 0;
    for (size_t i = 0; i < np; ++i)
        m += st->gb.surface[i] == PEN_SURFACE_GROUND;
    float *pts = pen__malloc(ctx, 6 * m + 1, sizeof(float), "ground pixels");
    float *c = pen__malloc(ctx, (size_t)K * m + 1, sizeof(float), "ground pixel rays");
    int *pix = pen__malloc(ctx, m + 1, sizeof(int), "ground pixel list");
    unsigned char *flag = pen__calloc(ctx, 2 * np, 1, "ground pixel flags");
    pen__transfer_mesh *meshes =
        pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *meshes, "pixel meshes");
    pen_status s = pts && c && pix && flag && meshes ? PEN_OK : PEN_ERROR_MEMORY;
    float *nrm = pts ? pts + 3 * m : NULL;
    for (size_t i = 0, q = 0; i < np && !s; ++i) {
        if (st->gb.surface[i] != PEN_SURFACE_GROUND) continue;
        memcpy(pts + 3 * q, st->x.data + 3 * i, 3 * sizeof(float));
        nrm[3 * q] = 0.0f, nrm[3 * q + 1] = 1.0f, nrm[3 * q + 2] = 0.0f;
        pix[q++] = (int)i;
    }
    if (!s) {
        pen__transfer_request rq = request(sc, st, meshes, (int)m, pts, nrm);
        if (!(s = PEN__BUF_RESERVE(ctx, gr->pfrac, (size_t)K * np + 1, "ground pixel lights")) &&
            !(s = m ? pen__transfer_lights(ctx, gr->blob->bvh, &rq, 1, c) : PEN_OK)) {
            pixel_flags(st, m, pix, pts, c, flag);
            dilate(st, flag, flag + np);
            size_t f = 0; /* the flagged pixels, compacted in place */
            for (size_t q = 0; q < m; ++q) {
                if (!flag[np + (size_t)pix[q]]) continue;
                memmove(pts + 3 * f, pts + 3 * q, 3 * sizeof(float));
                pix[f++] = pix[q];
            }
            for (size_t i = 0; i < (size_t)K * np; ++i)
                gr->pfrac.data[i] = -1.0f;
            rq.point_count = (int)f, rq.normals = nrm; /* still +Y: nrm is past the m points */
            if (f && !(s = pen__transfer_lights(ctx, gr->blob->bvh, &rq, 0, c)))
                for (size_t q = 0; q < f; ++q)
                    memcpy(gr->pfrac.data + (size_t)K * (size_t)pix[q], c + (size_t)K * q,
                           (size_t)K * sizeof(float));
            if (!s) gr->pvalid = 1, gr->pkey = key;
        }
    }
    free(pts), free(c), free(pix), free(flag), free(meshes);
    return s;
}

pen_status pen__ground_shadow_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    pen__ground_grid *gr = &st->grid;
    gr->on = 0;
    if (!st->self_any || !sc->ground.enabled ||
        sc->shadow.ground_shadow != PEN_GROUND_SHADOW_TRANSFER)
        return PEN_OK;
    const int S = st->sphere_count;
    pen_status s = PEN__BUF_RESERVE(ctx, gr->kappa, (size_t)S + 1, "ground grid kappa");
    if (s) return s;
    gr->others = 0;
    for (int o = 0; o < sc->object_count; ++o)
        for (int i = st->sphere_first[o]; i < st->sphere_first[o + 1]; ++i) {
            gr->kappa.data[i] = st->obj[o].self_on ? 0.0f : st->kappa.data[i];
            gr->others |= !st->obj[o].self_on;
        }
    pen__ground_grid shape = *gr;
    grid_shape(sc, st, &shape);
    const uint64_t key = grid_key(sc, st, &shape);
    if (!gr->valid || gr->key != key) {
        gr->valid = 0;
        gr->n = shape.n;
        memcpy(gr->c, shape.c, sizeof gr->c);
        memcpy(gr->a, shape.a, sizeof gr->a);
        memcpy(gr->beta, shape.beta, sizeof gr->beta);
        const size_t P = (size_t)gr->n * (size_t)gr->n, K = (size_t)st->lights.count;
        const size_t nc = (size_t)sc->sh_bands * (size_t)sc->sh_bands;
        /* Another state of the pool may have traced it (the grid is in world space): its blob
         * is used by reference, as a self transfer's (self.c). */
        pen__pool_lock(st->pool);
        pen__transfer_blob *blob = pen__pool_find(st->pool, PEN__POOL_GRID, key);
        if (blob && (blob->nB != nc * P || blob->nfrac != K * P)) {
            pen__blob_release(blob);
            blob = NULL;
        }
        if (!blob) {
            blob = pen__blob_create(ctx, nc * P, K * P);
            s = blob ? grid_trace(ctx, sc, st, gr, blob) : PEN_ERROR_MEMORY;
            if (!s) pen__pool_insert(st->pool, PEN__POOL_GRID, key, blob);
        }
        pen__pool_unlock(st->pool);
        if (s) {
            pen__blob_release(blob);
            return s;
        }
        pen__blob_release(gr->blob);
        gr->blob = blob, gr->B = blob->B, gr->frac = blob->frac;
        gr->valid = 1, gr->key = key;
    }
    gr->on = 1;
    return pixel_trace(ctx, sc, st);
}

/* ---- At a pixel: what the backend shades with ----------------------------------------------- */

/* The blocked part and the light fractions at ground pixel i (point x): bilinear in the grid's
 * s, the fractions the pixel's own where it has them. */
void pen__ground_grid_at(const pen_render_state *st, size_t i, float *B, double *frac) {
    const float *x = st->x.data + 3 * i;
    const pen__ground_grid *gr = &st->grid;
    const int nc = st->params.bands * st->params.bands, K = st->lights.count;
    size_t k[4];
    double w[4];
    grid_cell(gr, x, k, w);
    for (int c = 0; c < nc; ++c) {
        double v = 0.0;
        for (int q = 0; q < 4; ++q)
            v += w[q] * (double)gr->B[(size_t)nc * k[q] + (size_t)c];
        B[c] = (float)v;
    }
    const float *own = gr->pvalid && K ? gr->pfrac.data + (size_t)K * i : NULL;
    for (int l = 0; l < K; ++l) {
        double v = 0.0;
        for (int q = 0; q < 4; ++q)
            v += w[q] * (double)gr->frac[(size_t)K * k[q] + (size_t)l];
        frac[l] = own && own[l] >= 0.0f ? (double)own[l] : v;
    }
}
