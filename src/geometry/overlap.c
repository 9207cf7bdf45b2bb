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
 * than N tests), and its hit list comes out in sphere index order (marked in a bitmap, read back
 * in order), so the lists, and every sum over them, are exactly those of testing every sphere in
 * order: the weights do not depend on the tree. The solve needs G only through products
 * (G kappa)_i: small sets assemble G (cheap per sweep). Above GRAM_MAX_SPHERES a line through a
 * compact set crosses a fair part of it and G fills up (2000 spheres: 0.8 N^2 entries, 20000:
 * gigabytes), so the larger sets start by sweeping over the lines, (G kappa)_i summed over the
 * lines through sphere i (memory and time per sweep linear in the total hit count, N K times the
 * hits per line). A dense set (a fitted one) leaves most weights at 0 after that first sweep, and
 * a weight at 0 adds nothing to any product: such a set continues on G assembled over the support
 * alone (a fraction of N^2, and far cheaper per sweep than the lines), which grows in rounds by
 * the spheres outside whose step would move them (solve_lines); a sparse set, most weights above
 * 0, keeps sweeping over the lines. Either way the fixed point is that of sweeping every sphere.
 * The number of sweeps grows with N (about 20 for 32 spheres, 165 for 2000, 200 to 300 for
 * Spot's 4096 fitted spheres), which is why sets above PEN_SPHERES_OVERLAP_MAX (fit.h) are
 * refused rather than left to run for minutes.
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
/* The solve on the support (solve_lines): its first rounds' stopping change, and the least
 * ratio of hits to (spheres above 0 after the first sweep)^2 for which it is taken. */
#define LINES_LOOSE 1e-4
#define SUPPORT_RATIO 2.0

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

/* 1 when the line (p, d) passes through the ball c (centre c[0..2], squared radius c[3]): closer
 * to its centre than its radius. */
static int line_hits(const double p[3], const double d[3], const double c[4]) {
    const double q[3] = {c[0] - p[0], c[1] - p[1], c[2] - p[2]};
    const double t = q[0] * d[0] + q[1] * d[1] + q[2] * d[2];
    const double d2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] - t * t;
    return d2 < c[3];
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
    int *order;        /* sphere indices, leaves' ranges */
    double (*ball)[4]; /* per entry of order: the sphere's centre and squared radius */
    double extent;     /* the largest |centre coordinate| + radius */
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
    B->ball = pen__malloc(ctx, (size_t)n, sizeof *B->ball, "overlap: tree");
    if (!B->ball) return PEN_ERROR_MEMORY;
    for (int e = 0; e < n; ++e) {
        const float *c = sph + 4 * (size_t)B->order[e];
        for (int a = 0; a < 3; ++a)
            B->ball[e][a] = (double)c[a];
        B->ball[e][3] = (double)c[3] * (double)c[3];
    }
    return PEN_OK;
}

static void bvh_free(bvh *B) {
    free(B->nodes), free(B->order), free(B->ball);
}

/* Whether the (infinite) line p + t d meets the box: the slabs' t intervals overlap. A zero
 * component of d makes inv +-inf, and where p lies on that slab's face 0 * inf = NaN: the
 * comparisons skip a NaN bound, so that slab does not cull (the exact test decides). */
static int line_meets_box(const double p[3], const double inv[3], const double lo[3],
                          const double hi[3]) {
    double t0 = -HUGE_VAL, t1 = HUGE_VAL;
    for (int a = 0; a < 3; ++a) {
        const double ta = (lo[a] - p[a]) * inv[a], tb = (hi[a] - p[a]) * inv[a];
        const double near = inv[a] >= 0.0 ? ta : tb, far = inv[a] >= 0.0 ? tb : ta;
        t0 = near > t0 ? near : t0;
        t1 = far < t1 ? far : t1;
    }
    return t0 <= t1;
}

/* The spheres line (i, k) crosses, in increasing index order, written to out; returns their
 * count. The proposal's own sphere always counts (the line was drawn through its disk). The
 * traversal marks the hits in `bits` (n bits, all clear), and reading the marked words in order
 * yields the sorted list and clears them again: a scan of n / 64 words rather than a sort of the
 * list (tens of hits per line in a dense set, whose insertion sort cost more than the tree). */
static int line_hit_list(const overlap_settings *s, const bvh *B, const float *sph, int i, int k,
                         uint64_t *bits, int *out) {
    double p[3], d[3], inv[3];
    sample_line(s, sph, i, k, p, d);
    for (int a = 0; a < 3; ++a)
        inv[a] = 1.0 / d[a]; /* +-inf for a zero component */
    int wlo = i >> 6, whi = i >> 6;
    bits[i >> 6] |= 1ull << (i & 63);
    /* The tree splits at the median, so its depth is at most log2(n) + 1 < 33: the stack holds at
     * most one entry per level plus one. */
    int stack[64], sp = 0;
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
            if (line_hits(p, d, B->ball[e])) {
                bits[j >> 6] |= 1ull << (j & 63);
                wlo = (j >> 6) < wlo ? j >> 6 : wlo, whi = (j >> 6) > whi ? j >> 6 : whi;
            }
        }
    }
    int h = 0;
    for (int w = wlo; w <= whi; ++w) {
        for (uint64_t x = bits[w]; x; x &= x - 1)
            out[h++] = 64 * w + __builtin_ctzll(x);
        bits[w] = 0;
    }
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
    const size_t words = ((size_t)n + 63) / 64;
    uint64_t *buf = pen__calloc(ctx, (size_t)threads * words, sizeof(uint64_t), "overlap: hits");
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
        uint64_t *b = buf + (size_t)omp_get_thread_num() * words;
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

/* G as sparse rows (row i: len[i] entries, column idx[i][e], value val[i][e]). */
typedef struct gram {
    int *len, **idx;
    double **val;
} gram;

static void gram_free(gram *M, int n) {
    for (int i = 0; i < n && M->idx && M->val; ++i)
        free(M->idx[i]), free(M->val[i]);
    free(M->len), free(M->idx), free(M->val);
    memset(M, 0, sizeof *M);
}

/* G is symmetric: the new rows' (marked 2) entries in the columns of the rows already there
 * (marked 1) are appended to those rows, new spheres in increasing order, each row grown once. */
static int gram_mirror(gram *M, int n, const unsigned char *in) {
    int *more = calloc((size_t)n, sizeof(int));
    if (!more) return 0;
    for (int b = 0; b < n; ++b) {
        if (in[b] != 2) continue;
        for (int e = 0; e < M->len[b]; ++e)
            more[M->idx[b][e]] += in[M->idx[b][e]] == 1;
    }
    int ok = 1;
    for (int j = 0; j < n && ok; ++j) {
        if (!more[j]) continue;
        const size_t m = (size_t)(M->len[j] + more[j]);
        int *ix = realloc(M->idx[j], sizeof(int) * m);
        if (ix) M->idx[j] = ix;
        double *v = ix ? realloc(M->val[j], sizeof(double) * m) : NULL;
        if (v) M->val[j] = v;
        ok = v != NULL;
    }
    for (int b = 0; b < n && ok; ++b) {
        if (in[b] != 2) continue;
        for (int e = 0; e < M->len[b]; ++e) {
            const int j = M->idx[b][e];
            if (in[j] == 1) M->idx[j][M->len[j]] = b, M->val[j][M->len[j]++] = M->val[b][e];
        }
    }
    free(more);
    return ok;
}

/* Adds the rows of the spheres marked 2 in `in` (all when `in` is NULL) from the lines' hit
 * lists, which hold the spheres marked 1 or 2; one pass, each row computed into its thread's
 * scratch; then gram_mirror, and all are marked 1. The order of every row's entries depends on
 * the set and the marks alone. */
static pen_status gram_grow(pen_context *ctx, const lines *L, int n, int threads, unsigned char *in,
                            gram *M) {
    if (!M->len) {
        M->len = pen__calloc(ctx, (size_t)n, sizeof(int), "overlap: Gram rows");
        M->idx = pen__calloc(ctx, (size_t)n, sizeof(int *), "overlap: Gram rows");
        M->val = pen__calloc(ctx, (size_t)n, sizeof(double *), "overlap: Gram rows");
    }
    const size_t tn = (size_t)threads * (size_t)n;
    double *acc = pen__calloc(ctx, tn, sizeof(double), "overlap: rows");
    double *vs = pen__malloc(ctx, tn, sizeof(double), "overlap: rows");
    int *touched = pen__malloc(ctx, tn, sizeof(int), "overlap: rows");
    int *is = pen__malloc(ctx, tn, sizeof(int), "overlap: rows");
    /* Allocation failures before the loop are kept apart: a reduction's private copies start
     * at 0 and would not see them. */
    const int lacking = !M->len || !M->idx || !M->val || !acc || !vs || !touched || !is;
    int failed = 0;
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads) reduction(| : failed)          \
    if (!lacking)
    for (int i = 0; i < (lacking ? 0 : n); ++i) {
        const size_t t = (size_t)omp_get_thread_num() * (size_t)n;
        if (failed || (in && in[i] != 2)) continue;
        const int m = gram_row(L, i, acc + t, touched + t, is + t, vs + t);
        M->idx[i] = malloc(sizeof(int) * (size_t)m + 1);
        M->val[i] = malloc(sizeof(double) * (size_t)m + 1);
        if (!M->idx[i] || !M->val[i]) {
            failed = 1;
            continue;
        }
        memcpy(M->idx[i], is + t, sizeof(int) * (size_t)m);
        memcpy(M->val[i], vs + t, sizeof(double) * (size_t)m);
        M->len[i] = m;
    }
    free(acc), free(vs), free(touched), free(is);
    failed |= lacking;
    if (in && !failed) failed = !gram_mirror(M, n, in);
    for (int i = 0; i < n && in; ++i)
        in[i] = in[i] != 0;
    return failed ? pen__error(ctx, PEN_ERROR_MEMORY, "overlap: out of memory for the Gram rows")
                  : PEN_OK;
}

/* (G kappa)_i. `split` sums the row in four interleaved partial sums (the larger sets' rows are
 * a thousand entries and more, and one running sum waits on each addition); 0 keeps the single
 * sum, and with it the bits of the small sets' weights as they were. */
static double gram_dot(const gram *M, int i, const double *kappa, int split) {
    const int *ix = M->idx[i], m = M->len[i];
    const double *v = M->val[i];
    if (!split) {
        double g = 0.0;
        for (int e = 0; e < m; ++e)
            g += v[e] * kappa[ix[e]];
        return g;
    }
    double g[4] = {0.0, 0.0, 0.0, 0.0};
    int e = 0;
    for (; e + 4 <= m; e += 4)
        for (int q = 0; q < 4; ++q)
            g[q] += v[e + q] * kappa[ix[e + q]];
    for (; e < m; ++e)
        g[0] += v[e] * kappa[ix[e]];
    return (g[0] + g[1]) + (g[2] + g[3]);
}

/* Projected Gauss-Seidel sweeps over the marked spheres (all when `in` is NULL) from the given
 * kappa, until no step moves a weight by `tol` (or max_sweeps). */
static void gram_sweeps(const overlap_settings *s, const gram *M, int n, const double *W,
                        const double *k0, const unsigned char *in, double tol, double *kappa) {
    for (int sweep = 0; sweep < s->max_sweeps; ++sweep) {
        double change = 0.0;
        for (int i = 0; i < n; ++i) {
            if (!(W[i] > 0.0) || (in && !in[i])) continue;
            const double g = gram_dot(M, i, kappa, in != NULL);
            change = fmax(change, fabs(gs_step(s, g, W[i], k0[i], &kappa[i])));
        }
        if (change < tol) break;
    }
}

/* The solve with G assembled: cheaper per sweep while the rows are short. A line through a
 * compact set crosses a good part of it, so the rows fill up as the set grows (about 0.8 n^2
 * entries for 2000 spheres filling a cube): larger sets use solve_lines. */
static pen_status solve_gram(pen_context *ctx, const overlap_settings *s, const lines *L, int n,
                             int threads, const double *W, const double *k0, double *kappa) {
    gram M = {0};
    pen_status st = gram_grow(ctx, L, n, threads, NULL, &M);
    if (!st) gram_sweeps(s, &M, n, W, k0, NULL, 1e-9, kappa);
    gram_free(&M, n);
    return st;
}

/* S_l = the sum of kappa over the spheres line l crosses, for every line (line[l][1]). */
static void line_sums(const lines *L, const double *kappa, int threads, double (*line)[2]) {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (long l = 0; l < L->count; ++l) {
        double sum = 0.0;
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            sum += kappa[L->hit[e]];
        line[l][1] = sum;
    }
}

/* (G kappa)_i = sum over the lines l through i of omega_l S_l. */
static double line_dot(const lines *L, int i, const double (*line)[2]) {
    double g = 0.0;
    for (long e = L->by_start[i]; e < L->by_start[i + 1]; ++e) {
        const double *ls = line[L->by_line[e]];
        g += ls[0] * ls[1];
    }
    return g;
}

/* One sweep of the same iteration without G: (G kappa)_i by line_dot, each S_l kept current as
 * kappa_i changes (line[l] = {omega_l, S_l}: one cache line per visit of a line). A sweep costs
 * twice the total hit count in scattered reads and writes; returns the largest change. */
static double lines_sweep(const overlap_settings *s, const lines *L, int n, const double *W,
                          const double *k0, double (*line)[2], double *kappa) {
    double change = 0.0;
    for (int i = 0; i < n; ++i) {
        if (!(W[i] > 0.0)) continue;
        const double d =
            gs_step(s, line_dot(L, i, (const double(*)[2])line), W[i], k0[i], &kappa[i]);
        if (d != 0.0)
            for (long e = L->by_start[i]; e < L->by_start[i + 1]; ++e)
                line[L->by_line[e]][1] += d;
        change = fmax(change, fabs(d));
    }
    return change;
}

/* The lines' hit lists cut down to the spheres marked in `in` (sharing L's weights and its
 * lines-through-each-sphere lists, which stay valid for the marked spheres). */
static pen_status lines_restrict(pen_context *ctx, const lines *L, const unsigned char *in,
                                 int threads, lines *R) {
    *R = *L;
    R->start = pen__calloc(ctx, (size_t)L->count + 1, sizeof(long), "overlap: support lines");
    if (!R->start) return PEN_ERROR_MEMORY;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (long l = 0; l < L->count; ++l) {
        long m = 0;
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            m += in[L->hit[e]] != 0;
        R->start[l + 1] = m;
    }
    for (long l = 0; l < L->count; ++l)
        R->start[l + 1] += R->start[l];
    R->hit =
        pen__malloc(ctx, (size_t)R->start[L->count] + 1, sizeof(int), "overlap: support lines");
    if (!R->hit) {
        free(R->start);
        return PEN_ERROR_MEMORY;
    }
#pragma omp parallel for num_threads(threads) schedule(static)
    for (long l = 0; l < L->count; ++l) {
        long f = R->start[l];
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            if (in[L->hit[e]]) R->hit[f++] = L->hit[e];
    }
    return PEN_OK;
}

/* Larger sets. A sweep over the lines from kappa0 (lines_sweep, G never assembled) first. If the
 * spheres left above 0 are few (their count squared below the hits / SUPPORT_RATIO), as in a
 * dense set, where most weights end at 0 (Spot's 4096 fitted spheres: 1365 above 0 after the
 * first sweep, 1310 at the end), the iteration goes on with G restricted to the marked spheres
 * (a sphere at 0 adds nothing to any (G kappa)_i): G's rows over them, assembled from the lines
 * cut down to them (Spot's 4096: a million entries, a sweep in a millisecond instead of 50), are
 * swept to a change of LINES_LOOSE, then one product over all the lines gives the step each
 * sphere outside would take; those that would move by the stopping change join (their rows are
 * added, and their columns to the rows there), and the round repeats, at LINES_TOL once none
 * joins at the loose one, until none joins at LINES_TOL: then no step of a sweep over every
 * sphere moves a weight by more than a sweep over the lines would have stopped at. Otherwise
 * (most weights above 0: G on them would be as large as the lines) the sweeps over the lines go
 * on to LINES_TOL, as they always did. Every sum runs in an order fixed by the set (per line,
 * per sphere, per row), none by the threads. */
static pen_status solve_lines(pen_context *ctx, const overlap_settings *s, const lines *L, int n,
                              int threads, const double *W, const double *k0, double *kappa) {
    double(*line)[2] = pen__malloc(ctx, (size_t)L->count, 2 * sizeof(double), "overlap: lines");
    unsigned char *in = pen__calloc(ctx, (size_t)n, 1, "overlap: support");
    if (!line || !in) {
        free(line), free(in);
        return PEN_ERROR_MEMORY;
    }
    for (long l = 0; l < L->count; ++l)
        line[l][0] = L->omega[l];
    line_sums(L, kappa, threads, line);
    double change = lines_sweep(s, L, n, W, k0, line, kappa);
    double support = 0.0;
    for (int i = 0; i < n; ++i)
        if (W[i] > 0.0 && kappa[i] > 0.0) in[i] = 2, support += 1.0;
    if (support * support * SUPPORT_RATIO > (double)L->start[L->count]) {
        /* Most weights stay above 0: G on the support would be about as large as the lines. */
        for (int sweep = 1; sweep < s->max_sweeps && change >= LINES_TOL; ++sweep)
            change = lines_sweep(s, L, n, W, k0, line, kappa);
        free(line), free(in);
        return PEN_OK;
    }
    pen_status st = PEN_OK;
    gram M = {0};
    double tol = LINES_LOOSE;
    for (int grown = 1; !st;) {
        if (grown) {
            lines R;
            st = lines_restrict(ctx, L, in, threads, &R);
            if (st) break;
            st = gram_grow(ctx, &R, n, threads, in, &M);
            free(R.start), free(R.hit);
            if (st) break;
        }
        gram_sweeps(s, &M, n, W, k0, in, tol, kappa);
        /* The would-be step of each sphere outside, from the lines' sums. */
        line_sums(L, kappa, threads, line);
        grown = 0;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 16) reduction(| : grown)
        for (int i = 0; i < n; ++i) {
            if (in[i] || !(W[i] > 0.0)) continue;
            double k = kappa[i];
            const double g = line_dot(L, i, (const double(*)[2])line);
            if (fabs(gs_step(s, g, W[i], k0[i], &k)) >= tol) in[i] = 2, grown = 1;
        }
        if (!grown && tol == LINES_TOL) break;
        if (!grown) tol = LINES_TOL;
    }
    gram_free(&M, n);
    free(line), free(in);
    return st;
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
#pragma omp parallel for num_threads(threads) schedule(dynamic, 16)
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
        for (int i = 0; i < n; ++i)
            out[i] = k0[i];
        st = n <= GRAM_MAX_SPHERES ? solve_gram(ctx, s, &L, n, threads, W, k0, out)
                                   : solve_lines(ctx, s, &L, n, threads, W, k0, out);
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
