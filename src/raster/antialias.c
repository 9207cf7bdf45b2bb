/* Edge antialiasing: blends colours across geometric silhouette edges so that the image is a
 * continuous function of vertex positions, and differentiates that blend (the idea of Laine et
 * al. 2020, "Modular primitives for high-performance differentiable rendering"; the derivation
 * below is our own).
 *
 * Design. A rasterized image is piecewise constant in the vertex positions: a silhouette edge
 * moving by less than a pixel changes nothing until it crosses a pixel centre. We look at every
 * pair of 4-neighbouring pixels A, B whose G-buffer entries differ. The pixel whose surface is a
 * mesh and is closer (A, say; the ground and the background never occlude) has triangle T, and
 * T covers A's centre. If B is not covered by T, the segment from A's centre to B's centre leaves
 * T through exactly one edge of T, at a fraction alpha in [0, 1] of the way (in screen space,
 * where T's projected edges are straight lines). That edge is a silhouette when it has no single
 * neighbouring triangle or when the neighbour lies on the same side of the plane through the eye
 * and the edge as T does (the surface folds away, so the far side shows something else); else
 * the surface continues across it, and the segment is followed into the neighbour and out
 * through its next edge, until it crosses a silhouette edge (the pair blends there) or reaches
 * B's centre (no blend): see analyze_pair.
 *
 * Treat each pixel as a unit box around its centre, and the edge as locally straight. Along the
 * segment, T reaches alpha pixels from A's centre, so it covers (alpha - 1/2) of B's box when
 * alpha > 1/2, and leaves (1/2 - alpha) of A's box uncovered when alpha < 1/2:
 *     alpha >= 1/2:  c'_B = c_B + (alpha - 1/2) (c_A - c_B)
 *     alpha <  1/2:  c'_A = c_A + (1/2 - alpha) (c_B - c_A)
 * Both branches change the image at the rate d/d alpha = c_A - c_B (in B, resp. in A), so the
 * image sum is continuous and differentiable across alpha = 1/2; and when the edge crosses B's
 * centre (alpha -> 1) the half-blended B hands over to the next pair (alpha -> 0) with the same
 * colour, so the image is continuous as coverage changes. Moving the edge perpendicular to
 * itself by delta shifts the crossing of a horizontal pair by delta / |sin theta| (theta the
 * edge's angle to the pair axis), while the edge meets |sin theta| rows per unit length: the
 * rate of change of the image per unit edge length is exactly delta (c_A - c_B), as for the box-
 * filtered image. Using both horizontal and vertical pairs would count it twice, so horizontal
 * pairs take the edges at least as steep as 45 degrees (|dy| >= |dx| on screen) and vertical
 * pairs the flatter ones; this also bounds the slope factor in the derivative below by 1.
 *
 * Derivative. With pair axis u and cross axis v (u = x for horizontal pairs), edge endpoints
 * P, Q on screen and the centres' common cross coordinate v_c: s = (v_c - P_v) / (Q_v - P_v),
 * u_c = P_u + s (Q_u - P_u), alpha = dir (u_c - u_A) with dir = +-1 pointing from A to B. So
 *     d alpha / d(P_u, P_v, Q_u, Q_v) = dir ((1-s), -k(1-s), s, -k s),  k = du/dv of the edge,
 * and the screen gradients go to the world vertices through the projection's Jacobian. The
 * colours get d c_R += (1 - w) d c'_R, d c_S += w d c'_R for receiver R, source S, weight w.
 *
 * Limits (documented in docs/rasterizer.md): the occluder is chosen by comparing the two pixels'
 * depths; interpenetrations and the ground square's own border give no gradient; a pair whose
 * triangle has a vertex behind the near plane is skipped. The 45-degree rule leaves measure-zero
 * jumps: when a silhouette vertex whose two edges lie on both sides of 45 degrees crosses a row
 * (column) of pixel centres, the pair there changes exit edge and with it scheme.
 *
 * Passes: (1) in parallel over chunks of rows, each pair's receiver and weight, of which only
 * the pairs that blend are kept (the hits, row by row in x order: the outline's pairs, a small
 * part of the 2 W H); (2) in parallel over rows, the pixels no hit touches are copied (added,
 * backward) and each touched pixel gathers its up-to-four hits. The backward mirrors this and
 * scatters the vertex gradients serially in pair order, so the results do not depend on the
 * thread count. The ground border blend (below) finds its candidate pixels by one branch-free
 * scan of each row's surfaces and casts rays only from them.
 */
#include "core/internal.h"
#include "raster/raster_internal.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

/* ---- Pair analysis --------------------------------------------------------------------------- */

typedef struct aa_ctx {
    const pen_gbuffer *gb;
    const pen_view *view;
    const pen_raster_mesh *meshes;
    int mesh_count;
    const size_t *first_vertex; /* per mesh, into screen */
    const double *screen;       /* per vertex of every mesh: sx, sy, depth */
    const size_t *first_edge;   /* per mesh, into silhouette */
    const uint8_t *silhouette;  /* per half-edge 3 t + k of every mesh: silhouettes */
} aa_ctx;

typedef struct aa_pair {
    float weight;    /* blend fraction of the receiver towards the source */
    int8_t receiver; /* 0: no blend, 1: the first pixel (left / top) receives, 2: the second */
    int8_t slope;    /* d weight / d alpha: +1 or -1 */
} aa_pair;

typedef struct aa_edge {
    int mesh;
    uint32_t v[2];    /* world vertices of the edge: P, Q */
    double dalpha[4]; /* d alpha / d(P.x, P.y, Q.x, Q.y) in screen pixels */
} aa_edge;

/* The longest walk over triangles of a continuing surface (below) before a pair gives up. */
#define AA_WALK_MAX 16

/* The silhouette flags of triangle t's three edges (k to k+1): an edge is one, seen from the
 * eye, when it has no neighbour across it (pen_raster_adjacency: -1) or the neighbour's far
 * vertex lies on the same side as t's own of the plane through the eye and the edge. The
 * corners relative to the eye are taken once for the three edges. */
static void silhouettes(const pen_raster_mesh *mesh, const pen_view *view, int t, uint8_t sil[3]) {
    const uint32_t *idx = mesh->indices + 3 * (size_t)t;
    double q[3][3];
    for (int j = 0; j < 3; ++j) {
        double p[3];
        pen__load3_d(mesh->positions + 3 * (size_t)idx[j], p);
        pen__sub_d(p, view->eye, q[j]);
    }
    for (int k = 0; k < 3; ++k) {
        const int32_t neighbour = mesh->adjacency[3 * (size_t)t + (size_t)k];
        if (neighbour < 0) {
            sil[k] = 1;
            continue;
        }
        const size_t nb = (size_t)neighbour;
        const uint32_t far = mesh->indices[nb - nb % 3 + (nb % 3 + 2) % 3];
        double p[3], o[3], nrm[3];
        pen__load3_d(mesh->positions + 3 * (size_t)far, p);
        pen__sub_d(p, view->eye, o);
        pen__cross_d(q[k], q[(k + 1) % 3], nrm);
        sil[k] = (uint8_t)(pen__dot_d(nrm, q[(k + 2) % 3]) * pen__dot_d(nrm, o) >= 0.0);
    }
}

/* The blend of a pair whose outline crosses the segment between the two pixel centres at alpha
 * (0 at the occluding pixel's centre, 1 at the other's; occ: which pixel of the pair occludes, 0
 * the left or upper one): from alpha = 1/2 on the other pixel receives alpha - 1/2 of the
 * occluder's colour, below it the occluder's pixel receives 1/2 - alpha of the other's. */
static aa_pair pair_at(double alpha, int occ) {
    aa_pair out;
    if (alpha >= 0.5) {
        out.weight = (float)(alpha - 0.5), out.slope = 1;
        out.receiver = (int8_t)(occ ? 1 : 2);
    } else {
        out.weight = (float)(0.5 - alpha), out.slope = -1;
        out.receiver = (int8_t)(occ ? 2 : 1);
    }
    return out;
}

/* Analyzes the pair of pixels (x, y) and its right (axis 0) or lower (axis 1) neighbour.
 *
 * The segment from the occluder's centre leaves its triangle T through one edge. When that edge
 * is not a silhouette the surface continues across it, and on a mesh whose triangles are about
 * a pixel or smaller the silhouette is often an edge of a neighbour of T: the segment is
 * followed across continuing edges, triangle by triangle (screen space, where the continuing
 * surface's triangles tile the plane without folding), until it leaves through a silhouette
 * edge, ends (alpha > 1: the other pixel's centre is on the same surface), or AA_WALK_MAX
 * triangles are passed. Without the walk 31% of Spot's and 13% of Bob's outline pairs blended
 * at 256x256; the rest had neither the continuous image nor the silhouette gradient. */
static aa_pair analyze_pair(const aa_ctx *ac, int x, int y, int axis, aa_edge *edge) {
    aa_pair none = {0.0f, 0, 0};
    const pen_gbuffer *gb = ac->gb;
    size_t i0 = (size_t)y * (size_t)gb->width + (size_t)x;
    size_t i1 = axis ? i0 + (size_t)gb->width : i0 + 1;
    int s0 = gb->surface[i0], s1 = gb->surface[i1];
    if (s0 == s1 && gb->triangle[i0] == gb->triangle[i1]) return none;
    int m0 = s0 >= 0 && s0 < ac->mesh_count, m1 = s1 >= 0 && s1 < ac->mesh_count;
    float z0 = gb->depth[i0], z1 = gb->depth[i1];
    int occ; /* 0: the first pixel holds the occluding triangle, 1: the second */
    if (m0 && (z0 < z1 || (m1 && z0 == z1)))
        occ = 0;
    else if (m1 && z1 < z0)
        occ = 1;
    else
        return none;
    size_t io = occ ? i1 : i0;
    const pen_raster_mesh *mesh = ac->meshes + gb->surface[io];
    const double *screen = ac->screen + 3 * ac->first_vertex[gb->surface[io]];
    const uint8_t *silhouette = ac->silhouette + ac->first_edge[gb->surface[io]];
    const pen_view *view = ac->view;
    int t = gb->triangle[io];
    if (t < 0 || t >= mesh->triangle_count) return none;
    /* Pair coordinates: u along the pair, v across; the occluder's centre and the direction. */
    int ua = axis, va = 1 - axis;
    double uo = (axis ? y : x) + 0.5 + occ, vc = (axis ? x : y) + 0.5;
    double dir = occ ? -1.0 : 1.0;
    int entry = -1;       /* the edge the walk entered t through */
    double entered = 0.0; /* alpha there */
    for (int step = 0; step < AA_WALK_MAX; ++step) {
        const uint32_t *idx = mesh->indices + 3 * (size_t)t;
        const double *s[3];
        for (int k = 0; k < 3; ++k) {
            s[k] = screen + 3 * (size_t)idx[k];
            if (!(s[k][2] >= view->near_plane)) return none;
        }
        /* The edge through which the segment leaves t: the furthest crossing ahead of the
         * entry (T contains the occluder's centre, so it has exactly one crossing ahead). */
        int k_out = -1;
        double alpha = -1.0, sp = 0.0;
        for (int k = 0; k < 3; ++k) {
            if (k == entry) continue;
            const double *P = s[k], *Q = s[(k + 1) % 3];
            double dv = Q[va] - P[va];
            if (dv == 0.0 || (P[va] - vc) * (Q[va] - vc) > 0.0) continue;
            double sk = (vc - P[va]) / dv;
            double ak = dir * (P[ua] + sk * (Q[ua] - P[ua]) - uo);
            if (!(ak >= entered) || ak <= alpha) continue;
            k_out = k, alpha = ak, sp = sk;
        }
        if (k_out < 0 || alpha > 1.0) return none;
        int32_t neighbour = mesh->adjacency[3 * (size_t)t + (size_t)k_out];
        if (!silhouette[3 * (size_t)t + (size_t)k_out]) {
            t = neighbour / 3, entry = neighbour % 3, entered = alpha;
            continue;
        }
        const double *P = s[k_out], *Q = s[(k_out + 1) % 3];
        double dv = Q[va] - P[va], du = Q[ua] - P[ua];
        if (axis == 0 ? !(fabs(dv) >= fabs(du)) : !(fabs(dv) > fabs(du))) return none;
        aa_pair out = pair_at(alpha, occ);
        if (edge) {
            double kk = du / dv, d[4] = {0};
            d[ua] = dir * (1.0 - sp);
            d[va] = -dir * kk * (1.0 - sp);
            d[2 + ua] = dir * sp;
            d[2 + va] = -dir * kk * sp;
            edge->mesh = gb->surface[io];
            edge->v[0] = idx[k_out], edge->v[1] = idx[(k_out + 1) % 3];
            memcpy(edge->dalpha, d, sizeof d);
        }
        return out;
    }
    return none;
}

/* The (up to) four pairs around pixel (x, y): pair index, whether the pixel is its first
 * member, and the other pixel. Returns the count. */
static int pixel_pairs(int W, int H, int x, int y, size_t idx[4], int first[4], size_t other[4]) {
    size_t nh = (size_t)(W - 1) * (size_t)H, i = (size_t)y * (size_t)W + (size_t)x;
    int n = 0;
    if (x > 0)
        idx[n] = (size_t)y * (size_t)(W - 1) + (size_t)(x - 1), first[n] = 0, other[n++] = i - 1;
    if (x + 1 < W)
        idx[n] = (size_t)y * (size_t)(W - 1) + (size_t)x, first[n] = 1, other[n++] = i + 1;
    if (y > 0)
        idx[n] = nh + (size_t)(y - 1) * (size_t)W + (size_t)x, first[n] = 0,
        other[n++] = i - (size_t)W;
    if (y + 1 < H)
        idx[n] = nh + (size_t)y * (size_t)W + (size_t)x, first[n] = 1, other[n++] = i + (size_t)W;
    return n;
}

static pen_status check_args(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                             const pen_raster_mesh *meshes, int mesh_count, int channels) {
    if (!gb || !view || !gb->surface)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "antialias: NULL G-buffer or view");
    if (gb->width != view->width || gb->height != view->height)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "antialias: G-buffer %dx%d, camera %dx%d",
                          gb->width, gb->height, view->width, view->height);
    if (channels < 1)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "antialias: %d channels", channels);
    size_t total;
    pen_status st = pen__raster_check_meshes(ctx, meshes, mesh_count, &total);
    if (st) return st;
    for (int m = 0; m < mesh_count; ++m) {
        if (meshes[m].triangle_count > 0 && !meshes[m].adjacency)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "antialias: mesh %d has no adjacency (pen_raster_adjacency)", m);
        /* The walk follows these entries: a wrong one must not read outside the mesh. */
        const int32_t n = 3 * meshes[m].triangle_count; /* fits: at most INT32_MAX / 3 */
        for (int32_t h = 0; h < n; ++h)
            if (meshes[m].adjacency[h] < -1 || meshes[m].adjacency[h] >= n)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "antialias: mesh %d: adjacency[%d] = %d is not a half-edge "
                                  "of its %d triangles",
                                  m, (int)h, (int)meshes[m].adjacency[h],
                                  meshes[m].triangle_count);
    }
    return PEN_OK;
}

/* A pair that blends (receiver != 0), at column x of its row. */
typedef struct aa_hit {
    int x;
    aa_pair pr;
} aa_hit;

/* Everything both directions need: validated arguments, the screen position of every vertex,
 * and the pairs that blend, row by row: row y's horizontal pairs (x, y)-(x+1, y) are
 * hits[row[3y] .. row[3y+1]), its vertical pairs (x, y)-(x, y+1) hits[row[3y+1] .. row[3y+2]),
 * each in increasing x. Only a pixel touched by one of them changes (few: the outline), so the
 * blend, its transpose and the position gradient visit these, never the whole image's pairs. */
typedef struct aa_state {
    aa_ctx ac;
    aa_hit *hits;
    size_t *row;
    size_t *first_vertex, *first_edge;
    double *screen;
    uint8_t *silhouette;
} aa_state;

static void aa_end(aa_state *st) {
    free(st->hits);
    free(st->row);
    free(st->first_vertex);
    free(st->first_edge);
    free(st->screen);
    free(st->silhouette);
}

/* Pairs scanned at once for a difference: inside a surface's triangle, and on the ground and the
 * background, whole runs of pairs match, and one test in vector lanes passes them instead of a
 * test and a branch per pair. */
#define AA_SCAN 8

/* Whether all AA_SCAN pairs (sa[k], sb[k]) of surfaces and (ta[k], tb[k]) of triangles match. */
static inline int pairs_match(const int32_t *sa, const int32_t *sb, const int32_t *ta,
                              const int32_t *tb) {
#if defined(__SSE2__)
#define LOAD4(p) _mm_loadu_si128((const __m128i *)(const void *)(p))
    const __m128i a =
        _mm_and_si128(_mm_cmpeq_epi32(LOAD4(sa), LOAD4(sb)), _mm_cmpeq_epi32(LOAD4(ta), LOAD4(tb)));
    const __m128i b = _mm_and_si128(_mm_cmpeq_epi32(LOAD4(sa + 4), LOAD4(sb + 4)),
                                    _mm_cmpeq_epi32(LOAD4(ta + 4), LOAD4(tb + 4)));
#undef LOAD4
    return _mm_movemask_epi8(_mm_and_si128(a, b)) == 0xffff;
#else
    uint32_t d = 0;
    for (int k = 0; k < AA_SCAN; ++k)
        d |= (uint32_t)(sa[k] ^ sb[k]) | (uint32_t)(ta[k] ^ tb[k]);
    return d == 0;
#endif
}

/* Analyzes the pairs of rows [y0, y1), writing the blending ones from hits[at] on and their
 * ranges into row[3 y0 .. 3 y1). A pair of two pixels with the same surface and triangle never
 * blends (analyze_pair's first test), and most pairs are such: they are passed without a call. */
static void analyze_rows(const aa_ctx *ac, int y0, int y1, aa_hit *hits, size_t at, size_t *row) {
    const int W = ac->gb->width, H = ac->gb->height;
    const int32_t *surface = ac->gb->surface, *triangle = ac->gb->triangle;
    for (int y = y0; y < y1; ++y) {
        const size_t i = (size_t)y * (size_t)W;
        const int32_t *s = surface + i, *t = triangle + i;
        row[3 * (size_t)y] = at;
        /* Horizontal pairs x = 0 .. W - 2, a block of AA_SCAN at a time, pair by pair in a
         * block that differs somewhere (and in the last, short one). */
        for (int x = 0, end; x + 1 < W; x = end) {
            end = x + AA_SCAN < W ? x + AA_SCAN : W - 1;
            if (end - x == AA_SCAN && pairs_match(s + x, s + x + 1, t + x, t + x + 1)) continue;
            for (int u = x; u < end; ++u) {
                if (s[u] == s[u + 1] && t[u] == t[u + 1]) continue;
                aa_pair pr = analyze_pair(ac, u, y, 0, NULL);
                if (pr.receiver) hits[at].x = u, hits[at++].pr = pr;
            }
        }
        row[3 * (size_t)y + 1] = at;
        if (y + 1 < H) /* vertical pairs x = 0 .. W - 1, likewise */
            for (int x = 0, end; x < W; x = end) {
                end = x + AA_SCAN <= W ? x + AA_SCAN : W;
                if (end - x == AA_SCAN && pairs_match(s + x, s + x + W, t + x, t + x + W)) continue;
                for (int u = x; u < end; ++u) {
                    if (s[u] == s[u + W] && t[u] == t[u + W]) continue;
                    aa_pair pr = analyze_pair(ac, u, y, 1, NULL);
                    if (pr.receiver) hits[at].x = u, hits[at++].pr = pr;
                }
            }
        row[3 * (size_t)y + 2] = at;
    }
}

static pen_status aa_begin(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                           const pen_raster_mesh *meshes, int mesh_count, int channels,
                           aa_state *st) {
    memset(st, 0, sizeof *st);
    pen_status status = check_args(ctx, gb, view, meshes, mesh_count, channels);
    if (status) return status;
    int W = gb->width, H = gb->height;
    int threads = pen__raster_threads_for(ctx, (size_t)W * (size_t)H);
    size_t total = 0, edges = 0;
    st->first_vertex = pen__malloc(ctx, (size_t)mesh_count + 1, sizeof(size_t), "antialias");
    st->first_edge = pen__malloc(ctx, (size_t)mesh_count + 1, sizeof(size_t), "antialias");
    if (!st->first_vertex || !st->first_edge) {
        aa_end(st);
        return PEN_ERROR_MEMORY;
    }
    for (int m = 0; m < mesh_count; ++m) {
        st->first_vertex[m] = total, st->first_edge[m] = edges;
        total += (size_t)meshes[m].vertex_count;
        edges += 3 * (size_t)meshes[m].triangle_count;
    }
    /* Room for every pair (2W - 1 a row); each chunk of rows packs its hits from its first
     * row's share on, so only the pages the few hits reach are ever touched. */
    const size_t per_row = 2 * (size_t)W - 1;
    st->screen = pen__malloc(ctx, 3 * total + 1, sizeof(double), "antialias screen vertices");
    st->silhouette = pen__malloc(ctx, edges + 1, 1, "antialias silhouette flags");
    st->hits = pen__malloc(ctx, per_row * (size_t)H + 1, sizeof *st->hits, "antialias pairs");
    st->row = pen__malloc(ctx, 3 * (size_t)H + 1, sizeof *st->row, "antialias rows");
    if (!st->screen || !st->silhouette || !st->hits || !st->row) {
        aa_end(st);
        return PEN_ERROR_MEMORY;
    }
    for (int m = 0; m < mesh_count; ++m) {
        double *out = st->screen + 3 * st->first_vertex[m];
        const float *pos = meshes[m].positions;
        int vthreads = pen__raster_threads_for(ctx, (size_t)meshes[m].vertex_count);
#pragma omp parallel for num_threads(vthreads) schedule(static)
        for (int v = 0; v < meshes[m].vertex_count; ++v) {
            double p[3];
            pen__load3_d(pos + 3 * (size_t)v, p);
            pen__raster_project_d(view, p, out + 3 * (size_t)v, NULL);
        }
        /* Each edge's silhouette test once per frame, not once per pair and walk step: with
         * triangles of about a pixel nearly every pair of covered pixels walks. */
        uint8_t *sil = st->silhouette + st->first_edge[m];
        const pen_raster_mesh *mesh = &meshes[m];
        int ethreads = pen__raster_threads_for(ctx, 3 * (size_t)mesh->triangle_count);
#pragma omp parallel for num_threads(ethreads) schedule(static)
        for (int t = 0; t < mesh->triangle_count; ++t)
            silhouettes(mesh, view, t, sil + 3 * (size_t)t);
    }
    aa_ctx ac = {gb,         view,           meshes,        mesh_count, st->first_vertex,
                 st->screen, st->first_edge, st->silhouette};
    st->ac = ac;
    /* The walks crowd into the outline's rows: chunks of a few rows, handed out dynamically,
     * keep the threads busy. What a pair gets does not depend on which thread analyzes it. */
    const int chunks = threads > 1 ? (H < 8 * threads ? H : 8 * threads) : 1;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
    for (int c = 0; c < chunks; ++c) {
        const int y0 = (int)((long long)H * c / chunks);
        const int y1 = (int)((long long)H * (c + 1) / chunks);
        analyze_rows(&st->ac, y0, y1, st->hits, (size_t)y0 * per_row, st->row);
    }
    return PEN_OK;
}

/* The blend is linear in the colours: out = A c with, for each pair (receiver R, source S,
 * weight w), A_RR -= w and A_RS += w on top of the identity. The forward applies A (each pixel
 * gathers its row), the backward A^T (each pixel gathers its column) and adds into dst, or
 * (BLEND_T_SET) writes into dst what adding into a cleared dst would (+0 + x: the same bits,
 * a -0 made +0), which spares the caller clearing a whole image for it. */
enum { BLEND_A = 0, BLEND_T_ADD = 1, BLEND_T_SET = 2 };

/* Pixel i's row of A (its column with `transpose`) applied to v, from the n pairs touching it
 * (pr[j], with i its first pixel when first[j], the other pixel other[j]): written to out, the
 * pixel's `channels` values (the forward), or added to them (the backward). */
static void blend_pixel(const aa_pair *pr, const int *first, const size_t *other, int n,
                        size_t i, const float *v, int channels, int transpose, float *out) {
    /* The pairs that touch this pixel: receiving (+1) or, for A^T, giving (-1). */
    double w[4];
    int role[4], m = 0;
    size_t from[4];
    for (int j = 0; j < n; ++j) {
        int recv = pr[j].receiver == (first[j] ? 1 : 2);
        if (!recv && !(transpose && pr[j].receiver)) continue;
        w[m] = (double)pr[j].weight, role[m] = recv, from[m++] = other[j];
    }
    for (int c = 0; c < channels; ++c) {
        double vi = (double)v[i * channels + c], acc = vi;
        for (int j = 0; j < m; ++j) {
            double vo = (double)v[from[j] * channels + c];
            if (role[j]) /* this pixel receives */
                acc += transpose ? -w[j] * vi : w[j] * (vo - vi);
            else /* the other pixel receives from this one */
                acc += w[j] * vo;
        }
        if (transpose == BLEND_T_SET)
            out[c] = 0.0f + (float)acc;
        else if (transpose)
            out[c] += (float)acc;
        else
            out[c] = (float)acc;
    }
}

/* One row of the blend: pixels that no hit touches get A's identity row and column (a copy
 * forward, an add backward: blend_pixel with no pairs gives exactly these), and each touched
 * pixel gathers its pairs in pixel_pairs' order (left, right, up, down) by merging the row's
 * horizontal hits, the vertical hits above it and those below it, all sorted by x. */
static void blend_row(const aa_state *st, int y, const float *v, int channels, int transpose,
                      float *dst) {
    const int W = st->ac.gb->width;
    const size_t *row = st->row + 3 * (size_t)y, base = (size_t)y * (size_t)W;
    const aa_hit *hl = st->hits + row[0], *hr = hl, *he = st->hits + row[1];
    const aa_hit *d = he, *de = st->hits + row[2];
    const aa_hit *u = y > 0 ? st->hits + row[-2] : de, *ue = y > 0 ? st->hits + row[-1] : de;
    int done = 0; /* the row's pixels before this one are written */
    for (;;) {
        int x = W;
        if (hl < he && hl->x + 1 < x) x = hl->x + 1;
        if (hr < he && hr->x < x) x = hr->x;
        if (u < ue && u->x < x) x = u->x;
        if (d < de && d->x < x) x = d->x;
        const size_t i = base + (size_t)x, ch = (size_t)channels, k0 = (base + (size_t)done) * ch;
        if (transpose == BLEND_T_SET)
            for (size_t k = k0; k < i * ch; ++k)
                dst[k] = 0.0f + v[k];
        else if (transpose)
            for (size_t k = k0; k < i * ch; ++k)
                dst[k] += v[k];
        else
            memcpy(dst + k0, v + k0, sizeof(float) * (i * ch - k0));
        if (x == W) return;
        aa_pair pr[4];
        int first[4], n = 0;
        size_t other[4];
        if (hl < he && hl->x + 1 == x) pr[n] = hl++->pr, first[n] = 0, other[n++] = i - 1;
        if (hr < he && hr->x == x) pr[n] = hr++->pr, first[n] = 1, other[n++] = i + 1;
        if (u < ue && u->x == x) pr[n] = u++->pr, first[n] = 0, other[n++] = i - (size_t)W;
        if (d < de && d->x == x) pr[n] = d++->pr, first[n] = 1, other[n++] = i + (size_t)W;
        blend_pixel(pr, first, other, n, i, v, channels, transpose, dst + i * ch);
        done = x + 1;
    }
}

static void apply_blend(int threads, const aa_state *st, const float *v, int channels,
                        int transpose, float *dst) {
    const int H = st->ac.gb->height;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y)
        blend_row(st, y, v, channels, transpose, dst);
}

/* ---- The ground square's border ----------------------------------------------------------------
 * The ground never occludes a mesh, so analyze_pair leaves a pair of a ground pixel and a
 * background pixel alone, and the square's far border (seen at a grazing angle, often against a
 * bright sky) stayed aliased: a pixel half covered by the ground showed the ground alone or the
 * background alone. Such a pair is blended by the same rule as a silhouette: alpha is where the
 * segment from the ground pixel's centre to the background pixel's centre leaves the square (its
 * ray misses the square from there on), found by bisection of the rasterizer's own hit test; the
 * 45-degree rule takes the border's screen direction there. The ground is fixed, so the blend has
 * no position gradient; its colour transpose is the backward. */

/* 1 when the ray through screen point (px, py) hits the ground square in front of the near
 * plane: the rasterizer's test (raster.c), in double. */
static int ground_hit(const pen_view *view, const pen_ground *g, double px, double py,
                      double hit[3]) {
    double D[3];
    pen_view_ray(view, px, py, D);
    double z = ((double)g->height - view->eye[1]) / D[1];
    if (!(z >= view->near_plane) || !isfinite(z)) return 0;
    double hx = view->eye[0] + z * D[0], hz = view->eye[2] + z * D[2];
    double hs = (double)g->half_size;
    if (hit) hit[0] = hx, hit[1] = (double)g->height, hit[2] = hz;
    return fabs(hx) <= hs && fabs(hz) <= hs;
}

static aa_pair ground_pair(const pen_gbuffer *gb, const pen_view *view, const pen_ground *g,
                           int x, int y, int axis) {
    aa_pair none = {0.0f, 0, 0};
    size_t i0 = (size_t)y * (size_t)gb->width + (size_t)x;
    size_t i1 = axis ? i0 + (size_t)gb->width : i0 + 1;
    int s0 = gb->surface[i0], s1 = gb->surface[i1];
    int occ; /* the ground pixel: 0 the first, 1 the second */
    if (s0 == PEN_SURFACE_GROUND && s1 == PEN_SURFACE_BACKGROUND)
        occ = 0;
    else if (s1 == PEN_SURFACE_GROUND && s0 == PEN_SURFACE_BACKGROUND)
        occ = 1;
    else
        return none;
    double ax = x + 0.5 + (axis ? 0.0 : occ), ay = y + 0.5 + (axis ? occ : 0.0);
    double dx = axis ? 0.0 : (occ ? -1.0 : 1.0), dy = axis ? (occ ? -1.0 : 1.0) : 0.0;
    double p[3];
    if (!ground_hit(view, g, ax, ay, p) || ground_hit(view, g, ax + dx, ay + dy, NULL)) return none;
    double lo = 0.0, hi = 1.0;
    for (int it = 0; it < 24; ++it) { /* to 2^-24 of a pixel: below a float weight's rounding */
        double mid = 0.5 * (lo + hi), q[3];
        if (ground_hit(view, g, ax + mid * dx, ay + mid * dy, q))
            lo = mid, p[0] = q[0], p[1] = q[1], p[2] = q[2];
        else
            hi = mid;
    }
    double alpha = 0.5 * (lo + hi);
    /* The border's screen direction at the crossing: the square's side there, or (a square
     * reaching the horizon) the horizon line D.y = 0. */
    double du, dv, hs = (double)g->half_size, sdir[2];
    if (fmax(fabs(p[0]), fabs(p[2])) >= (1.0 - 1e-6) * hs && hs > 0.0) {
        double e[3] = {0.0, 0.0, 0.0}, a[3], b[3], sa[3], sb[3];
        e[fabs(p[0]) >= fabs(p[2]) ? 2 : 0] = 1e-3 * hs;
        for (int k = 0; k < 3; ++k)
            a[k] = p[k] - e[k], b[k] = p[k] + e[k];
        pen__raster_project_d(view, a, sa, NULL);
        pen__raster_project_d(view, b, sb, NULL);
        if (!(sa[2] > 0.0 && sb[2] > 0.0)) return none;
        sdir[0] = sb[0] - sa[0], sdir[1] = sb[1] - sa[1];
    } else {
        sdir[0] = view->focal[0] * view->up[1], sdir[1] = view->focal[1] * view->right[1];
    }
    du = sdir[axis], dv = sdir[1 - axis];
    if (axis == 0 ? !(fabs(dv) >= fabs(du)) : !(fabs(dv) > fabs(du))) return none;
    return pair_at(alpha, occ);
}

/* 1 when a pixel of surface c whose neighbours are l, r, u, d may lie on the border: ground
 * beside background or the reverse. */
static inline int border_test(int32_t c, int32_t l, int32_t r, int32_t u, int32_t d) {
    const int nb = (l == PEN_SURFACE_BACKGROUND) | (r == PEN_SURFACE_BACKGROUND) |
                   (u == PEN_SURFACE_BACKGROUND) | (d == PEN_SURFACE_BACKGROUND);
    const int ng = (l == PEN_SURFACE_GROUND) | (r == PEN_SURFACE_GROUND) |
                   (u == PEN_SURFACE_GROUND) | (d == PEN_SURFACE_GROUND);
    return ((c == PEN_SURFACE_GROUND) & nb) | ((c == PEN_SURFACE_BACKGROUND) & ng);
}

/* Marks mask[x] = 1 for the pixels of row y that may lie on the border, told from the surfaces
 * alone; returns how many. A neighbour off the image is replaced by the pixel itself, which is
 * never the other kind, so the inner loop has no branch and vectorizes (every pixel is looked
 * at, and most rows have none). */
static int border_row(const pen_gbuffer *gb, int y, uint8_t *mask) {
    const int W = gb->width, H = gb->height;
    const int32_t *s = gb->surface + (size_t)y * (size_t)W;
    const int32_t *up = y > 0 ? s - W : s, *dn = y + 1 < H ? s + W : s;
    int count = mask[0] = (uint8_t)border_test(s[0], s[0], s[W > 1], up[0], dn[0]);
    for (int x = 1; x + 1 < W; ++x) {
        const int m = border_test(s[x], s[x - 1], s[x + 1], up[x], dn[x]);
        mask[x] = (uint8_t)m;
        count += m;
    }
    if (W > 1) {
        mask[W - 1] = (uint8_t)border_test(s[W - 1], s[W - 2], s[W - 1], up[W - 1], dn[W - 1]);
        count += mask[W - 1];
    }
    return count;
}

/* Bit 0: row y holds a ground pixel, bit 1: a background pixel (a branch-free pass that
 * vectorizes). A border candidate needs both among its own row and the rows beside it, which
 * only the few rows about the square's far border have: the other rows skip border_row. */
static uint8_t row_kinds(const pen_gbuffer *gb, int y) {
    const int32_t *s = gb->surface + (size_t)y * (size_t)gb->width;
    int g = 0, b = 0;
    for (int x = 0; x < gb->width; ++x)
        g |= s[x] == PEN_SURFACE_GROUND, b |= s[x] == PEN_SURFACE_BACKGROUND;
    return (uint8_t)(g | b << 1);
}

/* border_row, or 0 without looking when rows y - 1 .. y + 1 lack ground or background (kinds:
 * row_kinds of every row). */
static int border_row_if(const pen_gbuffer *gb, const uint8_t *kinds, int y, uint8_t *mask) {
    const int near =
        kinds[y] | (y > 0 ? kinds[y - 1] : 0) | (y + 1 < gb->height ? kinds[y + 1] : 0);
    return near == 3 ? border_row(gb, y, mask) : 0;
}

/* The pairs touching a candidate pixel (x, y) (pixel_pairs' order) as the border sees them;
 * returns how many blend (0: the pixel keeps its colour). ground_pair leaves any pair but a
 * ground pixel and a background one alone. */
static int border_pixel(const pen_gbuffer *gb, const pen_view *view, const pen_ground *g, int x,
                        int y, aa_pair pr[4], int first[4], size_t other[4], int *n) {
    const int W = gb->width, H = gb->height;
    const size_t nh = (size_t)(W - 1) * (size_t)H;
    size_t idx[4];
    *n = pixel_pairs(W, H, x, y, idx, first, other);
    int blending = 0;
    for (int j = 0; j < *n; ++j) {
        const int axis = idx[j] >= nh;
        const size_t k = axis ? idx[j] - nh : idx[j];
        const int row = axis ? W : W - 1;
        pr[j] = ground_pair(gb, view, g, (int)(k % (size_t)row), (int)(k / (size_t)row), axis);
        blending += pr[j].receiver != 0;
    }
    return blending;
}

/* A pixel whose colour the border blend changes, and its new colour (the forward's staging). */
typedef struct border_out {
    size_t i;
    float c[4];
} border_out;

pen_status pen__ground_border_fwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_ground *ground, float *color, int channels) {
    if (!gb || !view || !gb->surface || !ground || !ground->enabled) return PEN_OK;
    if (channels < 1 || channels > 4)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "ground border: %d channels", channels);
    /* Few pixels blend (the square's outline): their new colours are staged, per row, from the
     * unchanged image, and written once every row is done (rows read their neighbours). */
    const int W = gb->width, H = gb->height;
    int *count = pen__calloc(ctx, (size_t)H + 1, sizeof *count, "ground border");
    uint8_t *mask = pen__malloc(ctx, (size_t)W * (size_t)H + (size_t)H, 1, "ground border");
    if (!count || !mask) {
        free(count);
        free(mask);
        return PEN_ERROR_MEMORY;
    }
    uint8_t *kinds = mask + (size_t)W * (size_t)H;
    const int threads = pen__raster_threads_for(ctx, (size_t)W * (size_t)H);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y)
        kinds[y] = row_kinds(gb, y);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y) /* (room for each candidate: a bound) */
        count[y + 1] = border_row_if(gb, kinds, y, mask + (size_t)y * (size_t)W);
    for (int y = 0; y < H; ++y)
        count[y + 1] += count[y];
    border_out *staged = NULL;
    if (count[H] > 0) {
        staged = pen__malloc(ctx, (size_t)count[H], sizeof *staged, "ground border");
        if (!staged) {
            free(count);
            free(mask);
            return PEN_ERROR_MEMORY;
        }
    }
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y) {
        const uint8_t *m = mask + (size_t)y * (size_t)W, *hit;
        int at = count[y];
        for (int x = 0; at < count[y + 1]; ++x, ++at) {
            hit = memchr(m + x, 1, (size_t)(W - x)); /* there is one: count[] says so */
            x = (int)(hit - m);
            aa_pair pr[4];
            int first[4], n;
            size_t other[4], i = (size_t)y * (size_t)W + (size_t)x;
            staged[at].i = SIZE_MAX; /* a candidate that does not blend */
            if (border_pixel(gb, view, ground, x, y, pr, first, other, &n)) {
                staged[at].i = i;
                blend_pixel(pr, first, other, n, i, color, channels, BLEND_A, staged[at].c);
            }
        }
    }
    for (int k = 0; k < count[H]; ++k)
        if (staged[k].i != SIZE_MAX)
            memcpy(color + staged[k].i * (size_t)channels, staged[k].c,
                   sizeof(float) * (size_t)channels);
    free(staged);
    free(count);
    free(mask);
    return PEN_OK;
}

pen_status pen__ground_border_bwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_ground *ground, int channels, const float *d_out,
                                  float *d_color) {
    if (!gb || channels < 1 || channels > 4)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "ground border: %d channels", channels);
    const int W = gb->width, H = gb->height;
    memcpy(d_color, d_out, sizeof(float) * (size_t)channels * (size_t)W * (size_t)H);
    if (!view || !gb->surface || !ground || !ground->enabled) return PEN_OK;
    /* Off the border A's column is the identity's (the copy above); on it each pixel gathers
     * its column from d_out, which nothing writes, so rows run in parallel. */
    uint8_t *mask = pen__malloc(ctx, (size_t)W * (size_t)H + (size_t)H, 1, "ground border");
    if (!mask) return PEN_ERROR_MEMORY;
    uint8_t *kinds = mask + (size_t)W * (size_t)H;
    const int threads = pen__raster_threads_for(ctx, (size_t)W * (size_t)H);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y)
        kinds[y] = row_kinds(gb, y);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y) {
        uint8_t *m = mask + (size_t)y * (size_t)W;
        int left = border_row_if(gb, kinds, y, m);
        for (int x = 0; left > 0; ++x, --left) {
            x = (int)((uint8_t *)memchr(m + x, 1, (size_t)(W - x)) - m);
            aa_pair pr[4];
            int first[4], n;
            size_t other[4], i = (size_t)y * (size_t)W + (size_t)x;
            if (!border_pixel(gb, view, ground, x, y, pr, first, other, &n)) continue;
            float *out = d_color + i * (size_t)channels;
            for (int c = 0; c < channels; ++c)
                out[c] = 0.0f;
            blend_pixel(pr, first, other, n, i, d_out, channels, BLEND_T_ADD, out);
        }
    }
    free(mask);
    return PEN_OK;
}

/* ---- Forward --------------------------------------------------------------------------------- */

pen_status pen_antialias_fwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                             const pen_raster_mesh *meshes, int mesh_count, const float *color,
                             int channels, float *out) {
    aa_state st;
    pen_status status = aa_begin(ctx, gb, view, meshes, mesh_count, channels, &st);
    if (status) return status;
    apply_blend(pen__raster_threads_for(ctx, (size_t)gb->width * (size_t)gb->height), &st, color,
                channels, BLEND_A, out);
    aa_end(&st);
    return PEN_OK;
}

/* ---- Backward -------------------------------------------------------------------------------- */

static pen_status antialias_bwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                const pen_raster_mesh *meshes, int mesh_count, const float *color,
                                int channels, const float *d_out, float *d_color, int mode,
                                float *const *d_positions) {
    aa_state st;
    pen_status status = aa_begin(ctx, gb, view, meshes, mesh_count, channels, &st);
    if (status) return status;
    int W = gb->width, H = gb->height;
    if (d_color)
        apply_blend(pen__raster_threads_for(ctx, (size_t)W * (size_t)H), &st, d_out, channels, mode,
                    d_color);
    if (d_positions) {
        /* Serial, in pair order (every row's horizontal hits, then every row's vertical ones):
         * few pairs blend, and vertices are shared between them. */
        for (int axis = 0; axis < 2; ++axis)
            for (int y = 0; y < H; ++y)
                for (size_t h = st.row[3 * (size_t)y + (size_t)axis];
                     h < st.row[3 * (size_t)y + (size_t)axis + 1]; ++h) {
                    int x = st.hits[h].x;
                    aa_edge e;
                    aa_pair pr = analyze_pair(&st.ac, x, y, axis, &e);
                    if (!pr.receiver || !d_positions[e.mesh]) continue;
                    size_t i0 = (size_t)y * (size_t)W + (size_t)x;
                    size_t i1 = axis ? i0 + (size_t)W : i0 + 1;
                    size_t ir = pr.receiver == 1 ? i0 : i1, is = pr.receiver == 1 ? i1 : i0;
                    double dw = 0.0;
                    for (int c = 0; c < channels; ++c)
                        dw +=
                            ((double)color[is * channels + c] - (double)color[ir * channels + c]) *
                            (double)d_out[ir * channels + c];
                    double da = dw * pr.slope;
                    if (da == 0.0) continue;
                    const float *pos = meshes[e.mesh].positions;
                    for (int k = 0; k < 2; ++k) {
                        double p[3], s[3], J[9];
                        pen__load3_d(pos + 3 * (size_t)e.v[k], p);
                        pen__raster_project_d(view, p, s, J);
                        double gx = da * e.dalpha[2 * k], gy = da * e.dalpha[2 * k + 1];
                        float *dp = d_positions[e.mesh] + 3 * (size_t)e.v[k];
                        for (int c = 0; c < 3; ++c)
                            dp[c] += (float)(J[c] * gx + J[3 + c] * gy);
                    }
                }
    }
    aa_end(&st);
    return PEN_OK;
}

pen_status pen_antialias_bwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                             const pen_raster_mesh *meshes, int mesh_count, const float *color,
                             int channels, const float *d_out, float *d_color,
                             float *const *d_positions) {
    return antialias_bwd(ctx, gb, view, meshes, mesh_count, color, channels, d_out, d_color,
                         BLEND_T_ADD, d_positions);
}

pen_status pen__antialias_bwd_set(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_raster_mesh *meshes, int mesh_count, const float *color,
                                  int channels, const float *d_out, float *d_color,
                                  float *const *d_positions) {
    return antialias_bwd(ctx, gb, view, meshes, mesh_count, color, channels, d_out, d_color,
                         BLEND_T_SET, d_positions);
}
