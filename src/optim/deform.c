/* Embedded deformation graph on the proxy spheres (supplement section 3; Sumner, Schmid and
 * Pauly 2007), its backward, and its regularisers.
 *
 * The nodes are the sphere centres g_j (object space, at rest). Node j carries an affine map:
 * a 3x3 matrix A_j (kept near a rotation by E_rot) and a translation t_j. A vertex v follows
 * its K nearest nodes,
 *     v' = sum_j w_j(v) [A_j (v - g_j) + g_j + t_j],
 *     w_j(v) = (1 - |v - g_j| / d_max)^2 normalised to sum 1, d_max the distance to the
 *     (K+1)-th nearest node,
 * and a sphere moves with its node, c'_j = g_j + t_j (radius unchanged). Everything is linear in
 * (A, t), so the backward is a weighted transpose. Regularisers (Sumner et al.):
 *     E_rot = sum_j (c1.c2)^2 + (c1.c3)^2 + (c2.c3)^2 + sum_a (ca.ca - 1)^2   (columns of A_j)
 *     E_reg = sum_j sum_{k in N(j)} |A_j (g_k - g_j) + g_j + t_j - (g_k + t_k)|^2
 * with N(j) the node's K nearest other nodes: neighbouring nodes must agree where each other's
 * map puts them, which keeps the deformation smooth.
 *
 * Everything runs in double (graphs are small: tens of nodes); the caller converts.
 * Parameter layout: params[9 j .. 9 j + 9) = A_j row-major for j < M, then
 * params[9 M + 3 j .. + 3) = t_j, so that the matrices and the translations form two runs that
 * take different learning rates (supplement 5.1: 1e-3 and 1e-2).
 *
 * The "spheres" group, which moves every sphere's centre and radius freely, borrows the node
 * graph (built with no vertices) for its smoothness regulariser
 *     E_smooth = sum_j sum_{k in N(j)} |d_j - d_k|^2,   d_j = s_j - s0_j,
 * s_j = (centre, radius) and s0_j its initial value: neighbouring spheres move and grow alike.
 * One shadow determines the union's outline seen from the light, not how the overlapping spheres
 * share it; without the term some spheres shrink to nothing while their neighbours swell. */
#include "optim/optim_internal.h"

#include <stdlib.h>
#include <string.h>

static double dist2(const double *a, const double *b) {
    const double x = a[0] - b[0], y = a[1] - b[1], z = a[2] - b[2];
    return x * x + y * y + z * z;
}

/* The `k` nearest of the M nodes to point p (node `skip` excluded; -1: none), nearest first, by
 * repeated selection over the scratch distances `d2` (M entries); returns how many were found
 * (<= k) and, in *next, the distance to the one after them (-1 when there is none). */
static int nearest(const double *g, int M, const double *p, int skip, int k, double *d2,
                   int *idx, double *dist, double *next) {
    for (int j = 0; j < M; ++j)
        d2[j] = j == skip ? (double)INFINITY : dist2(g + 3 * j, p);
    int n = 0;
    *next = -1.0;
    for (int a = 0; a <= k; ++a) {
        int best = -1;
        for (int j = 0; j < M; ++j)
            if (isfinite(d2[j]) && (best < 0 || d2[j] < d2[best])) best = j;
        if (best < 0) break;
        if (a == k) {
            *next = sqrt(d2[best]);
            break;
        }
        idx[n] = best;
        dist[n++] = sqrt(d2[best]);
        d2[best] = (double)INFINITY;
    }
    return n;
}

pen_status pen__optim_deform_build(pen_context *ctx, const pen_mesh *mesh,
                                   const pen_spheres *spheres, int k, pen__deform_graph *out) {
    memset(out, 0, sizeof *out);
    const int M = spheres->count, nv = mesh->vertex_count;
    if (M < 1)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "deformation: the object has no spheres");
    if (k < 1) return pen__error(ctx, PEN_ERROR_ARGUMENT, "deformation: k must be positive");
    out->nodes = M;
    out->vertices = nv;
    out->k = k < M ? k : M;
    out->kn = k < M - 1 ? k : M - 1;
    out->g = pen__malloc(ctx, 3 * (size_t)M, sizeof(double), "graph nodes");
    out->rest = pen__malloc(ctx, 3 * (size_t)nv + 1, sizeof(double), "rest positions");
    out->vnode = pen__malloc(ctx, (size_t)nv * (size_t)out->k + 1, sizeof(int), "graph links");
    out->vweight = pen__malloc(ctx, (size_t)nv * (size_t)out->k + 1, sizeof(double), "weights");
    out->nn = pen__malloc(ctx, (size_t)M * (size_t)out->kn + 1, sizeof(int), "graph edges");
    int *idx = pen__malloc(ctx, (size_t)k + 2, sizeof(int), "graph scratch");
    double *dist = pen__malloc(ctx, (size_t)k + 2, sizeof(double), "graph scratch");
    double *d2 = pen__malloc(ctx, (size_t)M, sizeof(double), "graph scratch");
    if (!out->g || !out->rest || !out->vnode || !out->vweight || !out->nn || !idx || !dist || !d2) {
        free(idx);
        free(dist);
        free(d2);
        pen__optim_deform_free(out);
        return PEN_ERROR_MEMORY;
    }
    for (int j = 0; j < M; ++j)
        for (int c = 0; c < 3; ++c)
            out->g[3 * j + c] = spheres->data[4 * j + c];
    for (size_t i = 0; i < 3 * (size_t)nv; ++i)
        out->rest[i] = mesh->positions[i];
    const int K = out->k;
    for (int v = 0; v < nv; ++v) {
        double next;
        const int n = nearest(out->g, M, out->rest + 3 * v, -1, K, d2, idx, dist, &next);
        /* Without a (K+1)-th node every node is used: d_max a little beyond the farthest, so
         * that the farthest still has a (small) weight. */
        const double dmax = next > 0.0 ? next : 1.1 * dist[n - 1] + 1e-12;
        double sum = 0.0;
        for (int a = 0; a < n; ++a) {
            const double w = fmax(1.0 - dist[a] / dmax, 0.0);
            out->vnode[v * K + a] = idx[a];
            out->vweight[v * K + a] = w * w;
            sum += w * w;
        }
        for (int a = 0; a < n; ++a) /* all at d_max (ties): equal weights */
            out->vweight[v * K + a] = sum > 0.0 ? out->vweight[v * K + a] / sum : 1.0 / n;
    }
    for (int j = 0; j < M && out->kn > 0; ++j) {
        double next;
        nearest(out->g, M, out->g + 3 * j, j, out->kn, d2, idx, dist, &next);
        for (int a = 0; a < out->kn; ++a)
            out->nn[j * out->kn + a] = idx[a];
    }
    free(idx);
    free(dist);
    free(d2);
    return PEN_OK;
}

void pen__optim_deform_free(pen__deform_graph *graph) {
    free(graph->g);
    free(graph->rest);
    free(graph->vnode);
    free(graph->vweight);
    free(graph->nn);
    memset(graph, 0, sizeof *graph);
}

void pen__optim_deform_identity(const pen__deform_graph *graph, double *params) {
    const int M = graph->nodes;
    memset(params, 0, sizeof(double) * 12 * (size_t)M);
    for (int j = 0; j < M; ++j)
        params[9 * j] = params[9 * j + 4] = params[9 * j + 8] = 1.0;
}

/* ---- Forward --------------------------------------------------------------------------------- */

void pen__optim_deform_fwd(const pen__deform_graph *graph, const double *params, double *positions,
                           double *centres) {
    const int M = graph->nodes, K = graph->k;
    const double *t = params + 9 * (size_t)M;
    for (int v = 0; v < graph->vertices; ++v) {
        const double *p = graph->rest + 3 * v;
        double out[3] = {0.0, 0.0, 0.0};
        for (int a = 0; a < K; ++a) {
            const int j = graph->vnode[v * K + a];
            const double w = graph->vweight[v * K + a];
            const double *A = params + 9 * j, *g = graph->g + 3 * j;
            const double d[3] = {p[0] - g[0], p[1] - g[1], p[2] - g[2]};
            for (int r = 0; r < 3; ++r)
                out[r] += w * (A[3 * r] * d[0] + A[3 * r + 1] * d[1] + A[3 * r + 2] * d[2] +
                               g[r] + t[3 * j + r]);
        }
        memcpy(positions + 3 * v, out, sizeof out);
    }
    for (int j = 0; j < M; ++j)
        for (int r = 0; r < 3; ++r)
            centres[3 * j + r] = graph->g[3 * j + r] + t[3 * j + r];
}

/* ---- Backward -------------------------------------------------------------------------------- */

void pen__optim_deform_bwd(const pen__deform_graph *graph, const double *params,
                           const double *d_positions, const double *d_centres, double *d_params) {
    (void)params; /* linear: the backward does not depend on the parameters */
    const int M = graph->nodes, K = graph->k;
    double *dt = d_params + 9 * (size_t)M;
    for (int v = 0; d_positions && v < graph->vertices; ++v) {
        const double *p = graph->rest + 3 * v, *dv = d_positions + 3 * v;
        for (int a = 0; a < K; ++a) {
            const int j = graph->vnode[v * K + a];
            const double w = graph->vweight[v * K + a];
            const double *g = graph->g + 3 * j;
            const double d[3] = {p[0] - g[0], p[1] - g[1], p[2] - g[2]};
            double *dA = d_params + 9 * j;
            for (int r = 0; r < 3; ++r) {
                const double wd = w * dv[r];
                dA[3 * r] += wd * d[0];
                dA[3 * r + 1] += wd * d[1];
                dA[3 * r + 2] += wd * d[2];
                dt[3 * j + r] += wd;
            }
        }
    }
    for (int j = 0; d_centres && j < M; ++j)
        for (int r = 0; r < 3; ++r)
            dt[3 * j + r] += d_centres[3 * j + r];
}

/* ---- Regularisers ---------------------------------------------------------------------------- */

double pen__optim_deform_energy(const pen__deform_graph *graph, const double *params, double w_rot,
                                double w_reg, double *d_params) {
    const int M = graph->nodes, KN = graph->kn;
    const double *t = params + 9 * (size_t)M;
    double e_rot = 0.0, e_reg = 0.0;
    for (int j = 0; j < M; ++j) {
        const double *A = params + 9 * j;
        double c[3][3]; /* columns */
        for (int a = 0; a < 3; ++a)
            for (int r = 0; r < 3; ++r)
                c[a][r] = A[3 * r + a];
        double dc[3][3] = {{0}};
        for (int a = 0; a < 3; ++a)
            for (int b = a; b < 3; ++b) {
                const double dot = c[a][0] * c[b][0] + c[a][1] * c[b][1] + c[a][2] * c[b][2];
                const double e = a == b ? dot - 1.0 : dot;
                e_rot += e * e;
                /* d(e^2) = 2 e d(dot); d(ca.cb)/dca = cb, and 2 ca for a == b */
                for (int r = 0; r < 3; ++r) {
                    if (a == b) {
                        dc[a][r] += 4.0 * e * c[a][r];
                    } else {
                        dc[a][r] += 2.0 * e * c[b][r];
                        dc[b][r] += 2.0 * e * c[a][r];
                    }
                }
            }
        if (d_params)
            for (int a = 0; a < 3; ++a)
                for (int r = 0; r < 3; ++r)
                    d_params[9 * j + 3 * r + a] += w_rot * dc[a][r];
        const double *gj = graph->g + 3 * j;
        for (int n = 0; n < KN; ++n) {
            const int k = graph->nn[j * KN + n];
            const double *gk = graph->g + 3 * k;
            const double d[3] = {gk[0] - gj[0], gk[1] - gj[1], gk[2] - gj[2]};
            double e[3];
            for (int r = 0; r < 3; ++r)
                e[r] = A[3 * r] * d[0] + A[3 * r + 1] * d[1] + A[3 * r + 2] * d[2] + gj[r] +
                       t[3 * j + r] - gk[r] - t[3 * k + r];
            e_reg += e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            if (!d_params) continue;
            double *dt = d_params + 9 * (size_t)M;
            for (int r = 0; r < 3; ++r) {
                const double ge = 2.0 * w_reg * e[r];
                for (int col = 0; col < 3; ++col)
                    d_params[9 * j + 3 * r + col] += ge * d[col];
                dt[3 * j + r] += ge;
                dt[3 * k + r] -= ge;
            }
        }
    }
    return w_rot * e_rot + w_reg * e_reg;
}

double pen__optim_spheres_energy(const pen__deform_graph *graph, const double *initial,
                                 const double *spheres, double w, double *d_spheres) {
    const int M = graph->nodes, KN = graph->kn;
    double e = 0.0;
    for (int j = 0; j < M; ++j)
        for (int n = 0; n < KN; ++n) {
            const int k = graph->nn[j * KN + n];
            for (int c = 0; c < 4; ++c) {
                const double dj = spheres[4 * j + c] - initial[4 * j + c];
                const double dk = spheres[4 * k + c] - initial[4 * k + c];
                e += (dj - dk) * (dj - dk);
                if (!d_spheres) continue;
                d_spheres[4 * j + c] += 2.0 * w * (dj - dk);
                d_spheres[4 * k + c] -= 2.0 * w * (dj - dk);
            }
        }
    return w * e;
}
