/* Refined receiver nodes on a triangle mesh (see lattice.h).
 *
 * Design
 * - Numbering: the vertices first (so level 1 is the mesh itself), then L - 1 nodes per unique
 *   edge counted from its smaller vertex, then the (L - 1)(L - 2) / 2 interior nodes of each
 *   triangle. A triangle reaches an edge's nodes through tri_edges, which says whether it runs
 *   the edge the stored way; two triangles sharing an edge therefore share its nodes, and the
 *   interpolated field is continuous across it.
 * - Edge nodes are computed from the edge's two vertices alone (not from either triangle's
 *   barycentrics), so every triangle that writes one writes the same bits.
 * - Unique edges by sorting (smaller, larger) vertex pairs: O(T log T), rebuilt by the renderer
 *   whenever it traces the transfer again (a pose change), which costs far more.
 */
#include "geometry/lattice.h"

#include "core/internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct half {
    uint64_t key; /* smaller << 32 | larger */
    int32_t slot; /* 3 t + c */
} half;

static int half_cmp(const void *a_, const void *b_) {
    const half *a = a_, *b = b_;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    return (a->slot > b->slot) - (a->slot < b->slot);
}

void pen__lattice_free(pen__lattice *lat) {
    if (!lat) return;
    free(lat->tri_edges);
    memset(lat, 0, sizeof *lat);
}

pen_status pen__lattice_build(pen_context *ctx, pen__lattice *lat, int level, int vertex_count,
                              int triangle_count, const uint32_t *indices) {
    pen__lattice_free(lat);
    const int L = level < 1 ? 1 : level > PEN_LATTICE_MAX_LEVEL ? PEN_LATTICE_MAX_LEVEL : level;
    const size_t H = 3 * (size_t)triangle_count;
    half *h = pen__malloc(ctx, H ? H : 1, sizeof *h, "lattice edges");
    lat->tri_edges = pen__malloc(ctx, H ? H : 1, sizeof *lat->tri_edges, "lattice edges");
    if (!h || !lat->tri_edges) {
        free(h);
        pen__lattice_free(lat);
        return PEN_ERROR_MEMORY;
    }
    for (size_t s = 0; s < H; ++s) {
        const uint32_t p = indices[s], q = indices[s - s % 3 + (s % 3 + 1) % 3];
        const uint32_t lo = p < q ? p : q, hi = p < q ? q : p;
        h[s].key = (uint64_t)lo << 32 | hi;
        h[s].slot = (int32_t)s;
    }
    qsort(h, H, sizeof *h, half_cmp);
    int e = -1;
    for (size_t s = 0; s < H; ++s) {
        if (s == 0 || h[s].key != h[s - 1].key) ++e;
        const size_t slot = (size_t)h[s].slot;
        const uint32_t p = indices[slot];
        const int reversed = (uint64_t)p != h[s].key >> 32; /* the edge starts at its larger end */
        lat->tri_edges[slot] = 2 * e + reversed;
    }
    free(h);
    lat->level = L;
    lat->vertex_count = vertex_count, lat->triangle_count = triangle_count;
    lat->edge_count = e + 1;
    lat->node_count = vertex_count + lat->edge_count * (L - 1) +
                      triangle_count * ((L - 1) * (L - 2) / 2);
    return PEN_OK;
}

/* The diagonal of the vertices' bounding box. */
static double bbox_diagonal(int vertex_count, const float *positions) {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int v = 0; v < vertex_count; ++v)
        for (int a = 0; a < 3; ++a) {
            lo[a] = fmin(lo[a], (double)positions[3 * (size_t)v + a]);
            hi[a] = fmax(hi[a], (double)positions[3 * (size_t)v + a]);
        }
    return sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                (hi[2] - lo[2]) * (hi[2] - lo[2]));
}

int pen__lattice_level(int vertex_count, const float *positions, int triangle_count,
                       const uint32_t *indices, double spacing, double max_nodes) {
    if (vertex_count <= 0 || triangle_count <= 0 || !(spacing > 0.0)) return 1;
    const double diag = bbox_diagonal(vertex_count, positions);
    double sum = 0.0;
    for (size_t s = 0; s < 3 * (size_t)triangle_count; ++s) {
        const float *p = positions + 3 * (size_t)indices[s];
        const float *q = positions + 3 * (size_t)indices[s - s % 3 + (s % 3 + 1) % 3];
        const double d[3] = {(double)q[0] - (double)p[0], (double)q[1] - (double)p[1],
                            (double)q[2] - (double)p[2]};
        sum += sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    }
    const double mean = sum / (3.0 * triangle_count);
    if (!(diag > 0.0) || !(mean > 0.0)) return 1;
    const double want = ceil(mean / (spacing * diag) - 1e-9);
    int L = want < 1.0 ? 1 : want > PEN_LATTICE_MAX_LEVEL ? PEN_LATTICE_MAX_LEVEL : (int)want;
    /* nodes: V + E (L - 1) + T (L - 1)(L - 2) / 2, with E at most 3 T */
    while (L > 1 && vertex_count + 3.0 * triangle_count * (L - 1) +
                            0.5 * triangle_count * (L - 1) * (L - 2) >
                        max_nodes)
        --L;
    return L;
}

static void sub3(const float *p, const float *q, double d[3]) {
    for (int a = 0; a < 3; ++a)
        d[a] = (double)p[a] - (double)q[a];
}

int pen__lattice_convex(int vertex_count, const float *positions, int triangle_count,
                        const uint32_t *indices, double max_pairs) {
    if (vertex_count <= 0 || triangle_count <= 0) return 0;
    if ((double)vertex_count * (double)triangle_count > max_pairs) return 0;
    const double diag = bbox_diagonal(vertex_count, positions);
    if (!(diag > 0.0) || !isfinite(diag)) return 0;
    const double tol = 1e-5 * diag;
    int faces = 0;
    for (int t = 0; t < triangle_count; ++t) {
        const float *p0 = positions + 3 * (size_t)indices[3 * (size_t)t];
        const float *p1 = positions + 3 * (size_t)indices[3 * (size_t)t + 1];
        const float *p2 = positions + 3 * (size_t)indices[3 * (size_t)t + 2];
        double e1[3], e2[3];
        sub3(p1, p0, e1), sub3(p2, p0, e2);
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        /* A sliver has no reliable plane; its neighbours' planes and its vertices still count. */
        if (!(len > 1e-12 * diag * diag)) continue;
        for (int a = 0; a < 3; ++a)
            n[a] /= len;
        ++faces;
        for (int v = 0; v < vertex_count; ++v) {
            double d[3];
            sub3(positions + 3 * (size_t)v, p0, d);
            const double h = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
            if (h > tol) return 0;
        }
    }
    return faces > 0;
}

/* The node at lattice point (a, b) of triangle t: barycentrics (L - a - b, a, b) / L. */
static int node_of(const pen__lattice *lat, const uint32_t *idx, int t, int a, int b) {
    const int L = lat->level;
    const uint32_t *c = idx + 3 * (size_t)t;
    if (a == 0 && b == 0) return (int)c[0];
    if (a == L) return (int)c[1];
    if (b == L) return (int)c[2];
    int slot, m; /* the edge (corner slot -> slot + 1) and the step from its start */
    if (b == 0)
        slot = 0, m = a;
    else if (a + b == L)
        slot = 1, m = b;
    else if (a == 0)
        slot = 2, m = L - b;
    else /* interior: a >= 1, b >= 1, a + b <= L - 1 */
        return lat->vertex_count + lat->edge_count * (L - 1) + t * ((L - 1) * (L - 2) / 2) +
               (a - 1) * (L - 1) - (a - 1) * a / 2 + (b - 1);
    const int32_t te = lat->tri_edges[3 * (size_t)t + (size_t)slot];
    const int e = te >> 1, s = (te & 1) ? L - m : m;
    return lat->vertex_count + e * (L - 1) + (s - 1);
}

static void lerp3(const float *p, const float *q, double t, float *out) {
    for (int a = 0; a < 3; ++a)
        out[a] = (float)((double)p[a] + t * ((double)q[a] - (double)p[a]));
}

void pen__lattice_nodes(const pen__lattice *lat, const uint32_t *indices, const float *positions,
                        const float *normals, float *node_pos, float *node_nrm) {
    const int L = lat->level;
    memcpy(node_pos, positions, sizeof(float) * 3 * (size_t)lat->vertex_count);
    memcpy(node_nrm, normals, sizeof(float) * 3 * (size_t)lat->vertex_count);
    if (L == 1) return;
    for (int t = 0; t < lat->triangle_count; ++t) {
        const uint32_t *c = indices + 3 * (size_t)t;
        for (int slot = 0; slot < 3; ++slot) { /* edge nodes, from the edge's smaller vertex */
            const uint32_t p = c[slot], q = c[(slot + 1) % 3];
            const uint32_t lo = p < q ? p : q, hi = p < q ? q : p;
            const int e = lat->tri_edges[3 * (size_t)t + (size_t)slot] >> 1;
            for (int s = 1; s < L; ++s) {
                const size_t n = (size_t)(lat->vertex_count + e * (L - 1) + (s - 1));
                lerp3(positions + 3 * (size_t)lo, positions + 3 * (size_t)hi, (double)s / L,
                      node_pos + 3 * n);
                lerp3(normals + 3 * (size_t)lo, normals + 3 * (size_t)hi, (double)s / L,
                      node_nrm + 3 * n);
            }
        }
        for (int a = 1; a < L; ++a)
            for (int b = 1; a + b < L; ++b) {
                const size_t n = (size_t)node_of(lat, indices, t, a, b);
                const double w[3] = {(double)(L - a - b) / L, (double)a / L, (double)b / L};
                for (int k = 0; k < 3; ++k) {
                    double x = 0.0, y = 0.0;
                    for (int j = 0; j < 3; ++j) {
                        x += w[j] * (double)positions[3 * (size_t)c[j] + (size_t)k];
                        y += w[j] * (double)normals[3 * (size_t)c[j] + (size_t)k];
                    }
                    node_pos[3 * n + (size_t)k] = (float)x, node_nrm[3 * n + (size_t)k] = (float)y;
                }
            }
    }
}

void pen__lattice_locate(const pen__lattice *lat, const uint32_t *indices, int t, double u,
                         double v, int node[3], double w[3]) {
    const int L = lat->level;
    u = u > 0.0 ? u : 0.0, v = v > 0.0 ? v : 0.0; /* rasterizer barycentrics may stray by ulps */
    if (u + v > 1.0) {
        const double s = u + v;
        u /= s, v /= s;
    }
    const double x = u * L, y = v * L;
    int a = (int)x, b = (int)y;
    if (a > L - 1) a = L - 1;
    if (b > L - 1 - a) b = L - 1 - a;
    const double fu = x - a, fv = y - b;
    if (fu + fv <= 1.0) { /* the sub-triangle (a, b), (a + 1, b), (a, b + 1) */
        node[0] = node_of(lat, indices, t, a, b), w[0] = 1.0 - fu - fv;
        node[1] = node_of(lat, indices, t, a + 1, b), w[1] = fu;
        node[2] = node_of(lat, indices, t, a, b + 1), w[2] = fv;
    } else { /* the upside-down one (a + 1, b + 1), (a, b + 1), (a + 1, b) */
        node[0] = node_of(lat, indices, t, a + 1, b + 1), w[0] = fu + fv - 1.0;
        node[1] = node_of(lat, indices, t, a, b + 1), w[1] = 1.0 - fu;
        node[2] = node_of(lat, indices, t, a + 1, b), w[2] = 1.0 - fv;
    }
}
