/* Overlap weights of a sphere set: one kappa_i >= 0 per sphere such that, along a line through
 * the set, the weights of the spheres it crosses add up to about T = PEN_SPHERES_OVERLAP_TARGET.
 *
 * Why. The renderer sums per-sphere log-visibilities, F = sum_i w_i kappa_i f_i: without weights
 * a shadow ray that crosses k spheres of a fitted set gets k times the blocker depth eps (a line
 * through Spot's 32 crosses 4.4 on average, a quarter of the lines 6 or more), and shadows darken
 * as the set gets denser, although the true visibility of a solid is blocked-or-not. With kappa
 * the depth along every ray through the object is about T eps, whatever the sphere count. T = 2
 * rather than 1 is measured (spheres.h, docs/fit-spheres.md).
 *
 * Method. The objective is over the isotropic uniform measure on lines (the one for which a set
 * of lines hitting a ball of radius r has measure proportional to r^2), restricted to lines that
 * hit the set:
 *     E(kappa) = integral over lines l of (sum_i kappa_i hit_i(l) - 1)^2
 *              + ridge * sum_i integral over lines hitting i of (kappa_i - kappa0_i)^2,
 * minimised over kappa >= 0 (a non-negative least squares), then scaled by T (the objective is
 * quadratic: the solution for target T is T times the one for 1). kappa0_i is the line average of
 * 1 / (spheres crossed), over the lines that cross sphere i; it is the answer when no line can
 * tell two spheres apart (two coincident spheres get T/2 each instead of any split) and a light
 * pull elsewhere.
 * - Sampling. Every sphere gets the same number of lines (uniform direction, uniform point in
 *   the disk it shows along that direction), so that small spheres are as well determined as
 *   large ones; a line is then weighted by 1 / sum over the spheres it crosses of r_j^-2 (the
 *   balance heuristic: the inverse of the mixture density of the per-sphere proposals relative
 *   to the uniform line measure), which makes the sums unbiased for the integrals above.
 *   Each sphere's lines come from its own seeded stream: the result depends on the sphere set
 *   alone (not on threads), and is invariant (up to sampling) under the pose.
 * - Solve. The normal equations G kappa = b with G_ij = sum over lines of omega_l hit_i hit_j
 *   (sparse: spheres that never share a line do not interact) plus the ridge's diagonal, by
 *   projected Gauss-Seidel (cyclic coordinate descent with clamping at 0), which converges for
 *   this convex box-constrained quadratic; it starts from kappa0.
 * Cost: N * K lines (K = lines per sphere, fewer for large sets). Each line finds the spheres it
 * crosses through a bounding-volume tree over the spheres' boxes (O(log N + hits) per line rather
 * than N tests), and its hit list is sorted by sphere index, so the lists, and every sum over
 * them, are exactly those of testing every sphere in order: the weights do not depend on the tree.
 * The solve needs G only through products (G kappa)_i: small sets assemble G (cheap per sweep),
 * larger ones (above GRAM_MAX_SPHERES) sum over the lines through sphere i instead, since a line
 * through a compact set crosses a fair part of it and G fills up (2000 spheres: 0.8 N^2 entries,
 * 20000: gigabytes). Memory and the time of one sweep are then linear in the total hit count, N K
 * times the hits per line (plus N K log N for the tree); the number of sweeps grows with N too
 * (about 20 for 32 spheres, 165 for 2000), which is why sets above PEN_SPHERES_OVERLAP_MAX (fit.h)
 * are refused rather than left to run for minutes.
 */
#include "core/internal.h"
#include "core/random.h"
#include "penumbra/fit.h"
#include "penumbra/spheres.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* Work bound: line-sphere tests at most about this many for large sets. */
#define MAX_TESTS 2.0e8
#define MIN_LINES 64
/* Sets up to this size solve with the assembled Gram matrix (solve_gram), larger ones without. */
#define GRAM_MAX_SPHERES 1024
/* The larger sets' stopping change (solve_lines says why). */
#define LINES_TOL 1e-7

/* The settings pen_spheres_overlap_weights uses (docs/fit-spheres.md has the measurements). */
typedef struct overlap_settings {
    int lines_per_sphere; /* K (fewer for large sets, see MAX_TESTS) */
    double ridge;         /* weight of the pull towards the line average */
    uint64_t seed;
    int max_sweeps; /* Gauss-Seidel sweeps at most */
} overlap_settings;

static const overlap_settings SETTINGS = {
    .lines_per_sphere = 1024,
    .ridge = 0.3,
    .seed = 0x6f7665726c6170ull, /* "overlap" */
    .max_sweeps = 5000,
};

/* Line k of sphere i's proposal: a point p and a unit direction d. */
static void sample_line(const overlap_settings *s, const float *sph, int i, int k, double p[3],
                        double d[3]) {
    uint64_t st = s->seed ^ (PEN__SPLITMIX_GAMMA * (uint64_t)(i + 1)) ^
                  (0xD1B54A32D192ED03ull * (uint64_t)(k + 1));
    (void)pen__splitmix_next(&st); /* decorrelate nearby seeds */
    const double z = 1.0 - 2.0 * pen__splitmix_uniform(&st),
                 phi = 2.0 * PEN_PI * pen__splitmix_uniform(&st);
    const double sz = sqrt(fmax(0.0, 1.0 - z * z));
    d[0] = sz * cos(phi), d[1] = sz * sin(phi), d[2] = z;
    /* An orthonormal pair perpendicular to d (Frisvad / Duff et al.). */
    const double sg = d[2] >= 0.0 ? 1.0 : -1.0, a = -1.0 / (sg + d[2]), b = d[0] * d[1] * a;
    const double e1[3] = {1.0 + sg * d[0] * d[0] * a, sg * b, -sg * d[0]};
    const double e2[3] = {b, sg + d[1] * d[1] * a, -d[1]};
    const float *c = sph + 4 * (size_t)i;
    const double rho = (double)c[3] * sqrt(pen__splitmix_uniform(&st));
    const double th = 2.0 * PEN_PI * pen__splitmix_uniform(&st);
    const double u = rho * cos(th), v = rho * sin(th);
    for (int a3 = 0; a3 < 3; ++a3)
        p[a3] = (double)c[a3] + u * e1[a3] + v * e2[a3];
}

/* 1 when the line (p, d) passes through sphere j (closer to its centre than its radius). */
static int line_hits(const double p[3], const double d[3], const float *s4) {
    const double q[3] = {(double)s4[0] - p[0], (double)s4[1] - p[1], (double)s4[2] - p[2]};
    const double t = q[0] * d[0] + q[1] * d[1] + q[2] * d[2];
    const double d2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] - t * t;
    return d2 < (double)s4[3] * (double)s4[3];
}

/* ---- Bounding-volume tree over the spheres' boxes ---------------------------------------- */

/* A node: its box, and either two children (left = node + 1, right = `right`) or a leaf's range
 * [first, first + count) of `order`. */
typedef struct bvh_node {
    double lo[3], hi[3];
    int right, first, count; /* count 0: inner node */
} bvh_node;

typedef struct bvh {
    bvh_node *nodes;
    int *order;    /* sphere indices, leaves' ranges */
    double extent; /* the largest |centre coordinate| + radius */
    int node_count;
} bvh;

#define BVH_LEAF 4

/* The box of sphere j, widened so that a line the exact test counts as a hit never misses the
 * box through rounding: line_hits' d2 = |q|^2 - t^2 carries an error of about 2^-52 |q|^2
 * (|q| <= 2 extent), which moves the distance it compares with r by that over 2 r; the slab test
 * rounds at about 2^-52 extent. */
static void sphere_box(const float *sph, int j, double extent, double lo[3], double hi[3]) {
    const float *c = sph + 4 * (size_t)j;
    const double r = (double)c[3];
    const double pad = 1e-9 * r + 1e-12 * extent + 1e-15 * extent * (extent / r);
    for (int a = 0; a < 3; ++a)
        lo[a] = (double)c[a] - r - pad, hi[a] = (double)c[a] + r + pad;
}

/* Builds the subtree over order[first, first + count) at node `at`; returns the next free node. */
static int bvh_build_node(bvh *B, const float *sph, int first, int count, int at) {
    bvh_node *nd = &B->nodes[at];
    double clo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, chi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (int a = 0; a < 3; ++a) nd->lo[a] = HUGE_VAL, nd->hi[a] = -HUGE_VAL;
    for (int e = first; e < first + count; ++e) {
        double lo[3], hi[3];
        const int j = B->order[e];
        sphere_box(sph, j, B->extent, lo, hi);
        for (int a = 0; a < 3; ++a) {
            const double c = (double)sph[4 * (size_t)j + a];
            nd->lo[a] = fmin(nd->lo[a], lo[a]), nd->hi[a] = fmax(nd->hi[a], hi[a]);
            clo[a] = fmin(clo[a], c), chi[a] = fmax(chi[a], c);
        }
    }
    if (count <= BVH_LEAF) {
        nd->first = first, nd->count = count, nd->right = -1;
        return at + 1;
    }
    /* Split at the median centre along the widest extent of the centres. */
    int axis = 0;
    for (int a = 1; a < 3; ++a)
        if (chi[a] - clo[a] > chi[axis] - clo[axis]) axis = a;
    const int half = count / 2;
    int *o = B->order + first;
    /* Partial selection (quickselect) of the median by centre coordinate, ties by index. */
    int lo = 0, hi = count - 1;
    while (lo < hi) {
        const int piv = o[(lo + hi) / 2];
        const double pv = (double)sph[4 * (size_t)piv + axis];
        int a = lo, b = hi;
        while (a <= b) {
            while ((double)sph[4 * (size_t)o[a] + axis] < pv ||
                   ((double)sph[4 * (size_t)o[a] + axis] == pv && o[a] < piv))
                ++a;
            while ((double)sph[4 * (size_t)o[b] + axis] > pv ||
                   ((double)sph[4 * (size_t)o[b] + axis] == pv && o[b] > piv))
                --b;
            if (a <= b) {
                const int t = o[a];
                o[a] = o[b], o[b] = t;
                ++a, --b;
            }
        }
        if (half <= b) hi = b;
        else if (half >= a) lo = a;
        else break;
    }
    nd->count = 0;
    const int next = bvh_build_node(B, sph, first, half, at + 1);
    B->nodes[at].right = next;
    return bvh_build_node(B, sph, first + half, count - half, next);
}

static pen_status bvh_build(pen_context *ctx, const float *sph, int n, bvh *B) {
    memset(B, 0, sizeof *B);
    B->nodes = pen__malloc(ctx, 2 * (size_t)n, sizeof(bvh_node), "overlap: tree");
    B->order = pen__malloc(ctx, (size_t)n, sizeof(int), "overlap: tree");
    if (!B->nodes || !B->order) return PEN_ERROR_MEMORY;
    for (int j = 0; j < n; ++j) {
        B->order[j] = j;
        const float *c = sph + 4 * (size_t)j;
        const double m = fmax(fabs((double)c[0]), fmax(fabs((double)c[1]), fabs((double)c[2])));
        B->extent = fmax(B->extent, m + (double)c[3]);
    }
    B->node_count = bvh_build_node(B, sph, 0, n, 0);
    return PEN_OK;
}

static void bvh_free(bvh *B) {
    free(B->nodes), free(B->order);
}

/* Whether the (infinite) line p + t d meets the box: the slabs' t intervals overlap. */
static int line_meets_box(const double p[3], const double inv[3], const double lo[3],
                          const double hi[3]) {
    double t0 = -HUGE_VAL, t1 = HUGE_VAL;
    for (int a = 0; a < 3; ++a) {
        if (isinf(inv[a])) {
            if (p[a] < lo[a] || p[a] > hi[a]) return 0;
            continue;
        }
        double ta = (lo[a] - p[a]) * inv[a], tb = (hi[a] - p[a]) * inv[a];
        if (ta > tb) {
            const double t = ta;
            ta = tb, tb = t;
        }
        t0 = ta > t0 ? ta : t0, t1 = tb < t1 ? tb : t1;
        if (t0 > t1) return 0;
    }
    return 1;
}

/* The spheres line (i, k) crosses, in increasing index order, written to out (if not NULL);
 * returns their count. The proposal's own sphere always counts (the line was drawn through its
 * disk). `buf` has room for n indices (the hits before sorting). */
static int line_hit_list(const overlap_settings *s, const bvh *B, const float *sph, int i, int k,
                         int *buf, int *out) {
    double p[3], d[3], inv[3];
    sample_line(s, sph, i, k, p, d);
    for (int a = 0; a < 3; ++a)
        inv[a] = 1.0 / d[a]; /* +-inf for a zero component */
    /* The tree splits at the median, so its depth is at most log2(n) + 1 < 33: the stack holds at
     * most one entry per level plus one. */
    int h = 0, own = 0, stack[64], sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        const bvh_node *nd = &B->nodes[stack[--sp]];
        if (!line_meets_box(p, inv, nd->lo, nd->hi)) continue;
        if (nd->count == 0) {
            stack[sp++] = nd->right;
            stack[sp++] = (int)(nd - B->nodes) + 1;
            continue;
        }
        for (int e = nd->first; e < nd->first + nd->count; ++e) {
            const int j = B->order[e];
            if (j == i || line_hits(p, d, sph + 4 * (size_t)j)) {
                buf[h++] = j;
                own |= j == i;
            }
        }
    }
    if (!own) buf[h++] = i;
    /* Insertion sort: hit lists are short. */
    for (int a = 1; a < h; ++a) {
        const int v = buf[a];
        int b = a - 1;
        while (b >= 0 && buf[b] > v)
            buf[b + 1] = buf[b], --b;
        buf[b + 1] = v;
    }
    if (out) memcpy(out, buf, sizeof(int) * (size_t)h);
    return h;
}

typedef struct lines {
    long count;     /* n * K */
    long *start;    /* count + 1 offsets into hit */
    int *hit;       /* sphere indices per line */
    double *omega;  /* per line: 1 / sum r_j^-2 (relative to the largest radius) */
    long *by_start; /* n + 1 offsets into by_line: the lines through each sphere */
    int *by_line;   /* line indices (n K < 2^31: n <= PEN_SPHERES_OVERLAP_MAX, K <= 1024) */
} lines;

static void lines_free(lines *L) {
    free(L->start), free(L->hit), free(L->omega), free(L->by_start), free(L->by_line);
}

static pen_status lines_build(pen_context *ctx, const overlap_settings *s, const float *sph, int n,
                              int K, int threads, lines *L) {
    memset(L, 0, sizeof *L);
    L->count = (long)n * K;
    L->start = pen__calloc(ctx, (size_t)L->count + 1, sizeof(long), "overlap: line offsets");
    L->omega = pen__malloc(ctx, (size_t)L->count, sizeof(double), "overlap: line weights");
    L->by_start = pen__calloc(ctx, (size_t)n + 1, sizeof(long), "overlap: sphere offsets");
    int *buf = pen__malloc(ctx, (size_t)threads * (size_t)n, sizeof(int), "overlap: hit lists");
    bvh B;
    pen_status st = bvh_build(ctx, sph, n, &B);
    if (!st && (!L->start || !L->omega || !L->by_start || !buf)) st = PEN_ERROR_MEMORY;
    if (st) {
        bvh_free(&B), free(buf);
        return st;
    }
    /* One traversal per line: each sphere's K hit lists go to an array of its own (a thread
     * collects them in its buffer), then all are joined in sphere order. */
    double rmax = 0.0;
    for (int j = 0; j < n; ++j)
        rmax = fmax(rmax, (double)sph[4 * (size_t)j + 3]);
    int **own = pen__calloc(ctx, (size_t)n, sizeof(int *), "overlap: hit lists");
    if (!own) {
        bvh_free(&B), free(buf);
        return PEN_ERROR_MEMORY;
    }
    int failed = 0;
#pragma omp parallel num_threads(threads) reduction(| : failed)
    {
        int *b = buf + (size_t)omp_get_thread_num() * (size_t)n;
        long cap = 0;
        int *acc = NULL;
#pragma omp for schedule(dynamic, 1)
        for (int i = 0; i < n; ++i) {
            if (failed) continue;
            long used = 0;
            for (int k = 0; k < K; ++k) {
                const long l = (long)i * K + k;
                if (cap - used < n) {
                    long grown = 2 * cap + n;
                    int *t = realloc(acc, sizeof(int) * (size_t)grown);
                    if (!t) {
                        failed = 1;
                        break;
                    }
                    acc = t, cap = grown;
                }
                const int m = line_hit_list(s, &B, sph, i, k, b, acc + used);
                double inv = 0.0;
                for (int q = 0; q < m; ++q) {
                    const double r = (double)sph[4 * (size_t)acc[used + q] + 3] / rmax;
                    inv += 1.0 / (r * r);
                }
                L->omega[l] = 1.0 / inv;
                L->start[l + 1] = m;
                used += m;
            }
            if (failed || !(own[i] = malloc(sizeof(int) * (size_t)(used + 1)))) {
                failed = 1;
                continue;
            }
            memcpy(own[i], acc, sizeof(int) * (size_t)used);
        }
        free(acc);
    }
    for (long l = 0; l < L->count; ++l)
        L->start[l + 1] += L->start[l];
    if (!failed)
        L->hit = pen__malloc(ctx, (size_t)L->start[L->count] + 1, sizeof(int), "overlap: line hits");
    for (int i = 0; i < n; ++i) {
        const long first = L->start[(long)i * K], end = L->start[(long)(i + 1) * K];
        if (L->hit && own[i]) memcpy(L->hit + first, own[i], sizeof(int) * (size_t)(end - first));
        free(own[i]);
    }
    free(own);
    if (failed || !L->hit) {
        bvh_free(&B), free(buf);
        return pen__error(ctx, PEN_ERROR_MEMORY, "overlap: out of memory for the line hits");
    }
    bvh_free(&B), free(buf);
    /* Transpose: for each sphere, the lines that cross it (in line order). */
    for (long e = 0; e < L->start[L->count]; ++e)
        L->by_start[L->hit[e] + 1]++;
    for (int j = 0; j < n; ++j)
        L->by_start[j + 1] += L->by_start[j];
    L->by_line = pen__malloc(ctx, (size_t)L->start[L->count] + 1, sizeof(int), "overlap: lines");
    long *fill = pen__malloc(ctx, (size_t)n, sizeof(long), "overlap: fill");
    if (!L->by_line || !fill) {
        free(fill);
        return PEN_ERROR_MEMORY;
    }
    memcpy(fill, L->by_start, sizeof(long) * (size_t)n);
    for (long l = 0; l < L->count; ++l)
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            L->by_line[fill[L->hit[e]]++] = (int)l;
    free(fill);
    return PEN_OK;
}

/* Row i of G (sum over lines of omega hit_i hit_j), sparse: `acc` is an n-vector of zeros,
 * `touched` room for n indices. Writes the row's nonzeros to (idx, val) when not NULL and
 * returns their count. acc is zeroed again on return. */
static int gram_row(const lines *L, int i, double *acc, int *touched, int *idx, double *val) {
    int nt = 0;
    for (long e = L->by_start[i]; e < L->by_start[i + 1]; ++e) {
        const long l = L->by_line[e];
        for (long f = L->start[l]; f < L->start[l + 1]; ++f) {
            const int j = L->hit[f];
            if (acc[j] == 0.0) touched[nt++] = j;
            acc[j] += L->omega[l];
        }
    }
    for (int t = 0; t < nt; ++t) {
        if (idx) idx[t] = touched[t], val[t] = acc[touched[t]];
        acc[touched[t]] = 0.0;
    }
    return nt;
}

/* One projected Gauss-Seidel step of sphere i on (G + ridge D) kappa = W + ridge D kappa0,
 * D = diag(W), W_i = G_ii, given g = (G kappa)_i; returns the change of kappa_i. */
static double gs_step(const overlap_settings *s, double g, double W, double k0, double *kappa) {
    const double lam = s->ridge;
    const double grad = g - W + lam * W * (*kappa - k0);
    const double next = fmax(0.0, *kappa - grad / ((1.0 + lam) * W));
    const double change = next - *kappa;
    *kappa = next;
    return change;
}

/* The solve with G assembled as sparse rows: cheaper per sweep while the rows are short. A line
 * through a compact set crosses a good part of it, so the rows fill up as the set grows (about
 * 0.8 n^2 entries for 2000 spheres filling a cube): larger sets use solve_lines. */
static pen_status solve_gram(pen_context *ctx, const overlap_settings *s, const lines *L, int n,
                             int threads, const double *W, const double *k0, double *kappa) {
    long *rs = pen__calloc(ctx, (size_t)n + 1, sizeof(long), "overlap: Gram offsets");
    double *acc = pen__calloc(ctx, (size_t)threads * (size_t)n, sizeof(double), "overlap: rows");
    int *touched = pen__malloc(ctx, (size_t)threads * (size_t)n, sizeof(int), "overlap: rows");
    int *idx = NULL;
    double *val = NULL;
    pen_status st = rs && acc && touched ? PEN_OK : PEN_ERROR_MEMORY;
    /* Two passes over the rows: their sizes, then (after the prefix sum) their entries. */
    for (int pass = 0; pass < 2 && !st; ++pass) {
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads)
        for (int i = 0; i < n; ++i) {
            const size_t t = (size_t)omp_get_thread_num() * (size_t)n;
            if (pass == 0)
                rs[i + 1] = gram_row(L, i, acc + t, touched + t, NULL, NULL);
            else
                gram_row(L, i, acc + t, touched + t, idx + rs[i], val + rs[i]);
        }
        if (pass == 0) {
            for (int i = 0; i < n; ++i)
                rs[i + 1] += rs[i];
            idx = pen__malloc(ctx, (size_t)rs[n] + 1, sizeof(int), "overlap: Gram indices");
            val = pen__malloc(ctx, (size_t)rs[n] + 1, sizeof(double), "overlap: Gram values");
            if (!idx || !val) st = PEN_ERROR_MEMORY;
        }
    }
    free(acc), free(touched);
    for (int i = 0; i < n; ++i)
        kappa[i] = k0[i];
    for (int sweep = 0; sweep < s->max_sweeps && !st; ++sweep) {
        double change = 0.0;
        for (int i = 0; i < n; ++i) {
            if (!(W[i] > 0.0)) continue;
            double g = 0.0; /* (G kappa)_i */
            for (long e = rs[i]; e < rs[i + 1]; ++e)
                g += val[e] * kappa[idx[e]];
            change = fmax(change, fabs(gs_step(s, g, W[i], k0[i], &kappa[i])));
        }
        if (change < 1e-9) break;
    }
    free(rs), free(idx), free(val);
    return st;
}

/* The same iteration without G: (G kappa)_i = sum over the lines l through i of omega_l S_l with
 * S_l = sum of kappa over the spheres l crosses, kept current as kappa_i changes. A sweep costs
 * the total hit count (n K times the mean hits per line) and the memory is two doubles per line
 * (omega_l beside S_l: one cache line per visit of a line instead of two), both linear in n. It
 * stops at a change of LINES_TOL (solve_gram: 1e-9): the weights of thousands of spheres are
 * limited by the line sampling long before (K = 32 or 64 lines per sphere give weights that differ
 * by a few hundredths), and the sweeps, hundreds of them, are the cost. */
static pen_status solve_lines(pen_context *ctx, const overlap_settings *s, const lines *L, int n,
                              const double *W, const double *k0, double *kappa) {
    double(*line)[2] = pen__malloc(ctx, (size_t)L->count, 2 * sizeof(double), "overlap: lines");
    if (!line) return PEN_ERROR_MEMORY;
    for (int i = 0; i < n; ++i)
        kappa[i] = k0[i];
    for (long l = 0; l < L->count; ++l) {
        double sum = 0.0;
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            sum += kappa[L->hit[e]];
        line[l][0] = L->omega[l];
        line[l][1] = sum;
    }
    for (int sweep = 0; sweep < s->max_sweeps; ++sweep) {
        double change = 0.0;
        for (int i = 0; i < n; ++i) {
            if (!(W[i] > 0.0)) continue;
            double g = 0.0;
            for (long e = L->by_start[i]; e < L->by_start[i + 1]; ++e) {
                const double *ls = line[L->by_line[e]];
                g += ls[0] * ls[1];
            }
            const double d = gs_step(s, g, W[i], k0[i], &kappa[i]);
            if (d != 0.0)
                for (long e = L->by_start[i]; e < L->by_start[i + 1]; ++e)
                    line[L->by_line[e]][1] += d;
            change = fmax(change, fabs(d));
        }
        if (change < LINES_TOL) break;
    }
    free(line);
    return PEN_OK;
}

pen_status pen_spheres_overlap_weights(pen_context *ctx, const pen_spheres *spheres, float *kappa) {
    const overlap_settings *s = &SETTINGS;
    const int n = spheres ? spheres->count : 0;
    if (!spheres || n < 0 || (n > 0 && (!spheres->data || !kappa)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "overlap weights: invalid arguments");
    if (n == 0) return PEN_OK;
    if (n > PEN_SPHERES_OVERLAP_MAX)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "overlap weights: %d spheres (limit %d); give the set weights in its "
                          "file or use \"overlap\": \"none\"",
                          n, PEN_SPHERES_OVERLAP_MAX);
    for (int i = 0; i < n; ++i) {
        const float *d = spheres->data + 4 * (size_t)i;
        if (!pen__finite3(d) || !isfinite(d[3]) || !(d[3] > 0.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "overlap weights: sphere %d needs a finite center and a radius > 0",
                              i);
    }
    if (n == 1) {
        kappa[0] = (float)PEN_SPHERES_OVERLAP_TARGET;
        return PEN_OK;
    }
    const int threads = pen__threads(ctx);
    int K = s->lines_per_sphere;
    const double cap = MAX_TESTS / ((double)n * (double)n);
    if (K > cap) K = cap > MIN_LINES ? (int)cap : MIN_LINES;
    double *w = pen__calloc(ctx, 3 * (size_t)n, sizeof(double), "overlap: weights");
    if (!w) return PEN_ERROR_MEMORY;
    double *W = w, *k0 = w + n, *out = w + 2 * (size_t)n;
    lines L;
    pen_status st = lines_build(ctx, s, spheres->data, n, K, threads, &L);
    if (!st) {
        for (int i = 0; i < n; ++i) {
            double a = 0.0, b = 0.0;
            for (long e = L.by_start[i]; e < L.by_start[i + 1]; ++e) {
                const long l = L.by_line[e];
                a += L.omega[l];
                b += L.omega[l] / (double)(L.start[l + 1] - L.start[l]);
            }
            W[i] = a;
            k0[i] = a > 0.0 ? b / a : 1.0;
        }
        st = n <= GRAM_MAX_SPHERES ? solve_gram(ctx, s, &L, n, threads, W, k0, out)
                                   : solve_lines(ctx, s, &L, n, W, k0, out);
    }
    lines_free(&L);
    /* Solved for a count of 1; the objective is quadratic, so the solution for the target T is
     * T times it (the ridge's kappa0 scales with it). */
    for (int i = 0; i < n && !st; ++i)
        kappa[i] = (float)(PEN_SPHERES_OVERLAP_TARGET * out[i]);
    free(w);
    return st;
}

pen_status pen_spheres_ensure_weights(pen_context *ctx, pen_spheres *spheres) {
    if (!spheres) return pen__error(ctx, PEN_ERROR_ARGUMENT, "overlap weights: no sphere set");
    if (spheres->weight || spheres->count <= 0) return PEN_OK;
    float *w = pen__malloc(ctx, (size_t)spheres->count, sizeof(float), "overlap weights");
    if (!w) return PEN_ERROR_MEMORY;
    pen_status st = pen_spheres_overlap_weights(ctx, spheres, w);
    if (st) {
        free(w);
        return st;
    }
    spheres->weight = w;
    return PEN_OK;
}
