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
 * Cost: N * K lines, each tested against the N spheres (K = lines per sphere), so O(N^2 K); the
 * line count per sphere shrinks for large sets to keep the work bounded.
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

/* The spheres line (i, k) crosses, written to out (if not NULL); returns their count. The
 * proposal's own sphere always counts (the line was drawn through its disk). */
static int line_hit_list(const overlap_settings *s, const float *sph, int n, int i, int k,
                         int *out) {
    double p[3], d[3];
    sample_line(s, sph, i, k, p, d);
    int h = 0;
    for (int j = 0; j < n; ++j)
        if (j == i || line_hits(p, d, sph + 4 * (size_t)j)) {
            if (out) out[h] = j;
            ++h;
        }
    return h;
}

typedef struct lines {
    long count;     /* n * K */
    long *start;    /* count + 1 offsets into hit */
    int *hit;       /* sphere indices per line */
    double *omega;  /* per line: 1 / sum r_j^-2 (relative to the largest radius) */
    long *by_start; /* n + 1 offsets into by_line: the lines through each sphere */
    long *by_line;
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
    if (!L->start || !L->omega || !L->by_start) return PEN_ERROR_MEMORY;
        /* Pass 1: hit counts; pass 2 (after the prefix sum) regenerates the same lines and fills.
         */
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int i = 0; i < n; ++i)
        for (int k = 0; k < K; ++k)
            L->start[(long)i * K + k + 1] = line_hit_list(s, sph, n, i, k, NULL);
    for (long l = 0; l < L->count; ++l)
        L->start[l + 1] += L->start[l];
    L->hit = pen__malloc(ctx, (size_t)L->start[L->count], sizeof(int), "overlap: line hits");
    if (!L->hit) return PEN_ERROR_MEMORY;
    double rmax = 0.0;
    for (int j = 0; j < n; ++j)
        rmax = fmax(rmax, (double)sph[4 * (size_t)j + 3]);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int i = 0; i < n; ++i)
        for (int k = 0; k < K; ++k) {
            const long l = (long)i * K + k;
            int *h = L->hit + L->start[l];
            const int m = line_hit_list(s, sph, n, i, k, h);
            double inv = 0.0;
            for (int q = 0; q < m; ++q) {
                const double r = (double)sph[4 * (size_t)h[q] + 3] / rmax;
                inv += 1.0 / (r * r);
            }
            L->omega[l] = 1.0 / inv;
        }
    /* Transpose: for each sphere, the lines that cross it (in line order). */
    for (long e = 0; e < L->start[L->count]; ++e)
        L->by_start[L->hit[e] + 1]++;
    for (int j = 0; j < n; ++j)
        L->by_start[j + 1] += L->by_start[j];
    L->by_line = pen__malloc(ctx, (size_t)L->start[L->count] + 1, sizeof(long), "overlap: lines");
    long *fill = pen__malloc(ctx, (size_t)n, sizeof(long), "overlap: fill");
    if (!L->by_line || !fill) {
        free(fill);
        return PEN_ERROR_MEMORY;
    }
    memcpy(fill, L->by_start, sizeof(long) * (size_t)n);
    for (long l = 0; l < L->count; ++l)
        for (long e = L->start[l]; e < L->start[l + 1]; ++e)
            L->by_line[fill[L->hit[e]]++] = l;
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

/* Projected Gauss-Seidel on (G + ridge D) kappa = W + ridge D kappa0, D = diag(W), W_i = G_ii. */
static pen_status solve(pen_context *ctx, const overlap_settings *s, const lines *L, int n,
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
    const double lam = s->ridge;
    for (int sweep = 0; sweep < s->max_sweeps && !st; ++sweep) {
        double change = 0.0;
        for (int i = 0; i < n; ++i) {
            if (!(W[i] > 0.0)) continue;
            double g = 0.0; /* (G kappa)_i */
            for (long e = rs[i]; e < rs[i + 1]; ++e)
                g += val[e] * kappa[idx[e]];
            const double grad = g - W[i] + lam * W[i] * (kappa[i] - k0[i]);
            const double next = fmax(0.0, kappa[i] - grad / ((1.0 + lam) * W[i]));
            change = fmax(change, fabs(next - kappa[i]));
            kappa[i] = next;
        }
        if (change < 1e-9) break;
    }
    free(rs), free(idx), free(val);
    return st;
}

pen_status pen_spheres_overlap_weights(pen_context *ctx, const pen_spheres *spheres, float *kappa) {
    const overlap_settings *s = &SETTINGS;
    const int n = spheres ? spheres->count : 0;
    if (!spheres || n < 0 || (n > 0 && (!spheres->data || !kappa)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "overlap weights: invalid arguments");
    if (n == 0) return PEN_OK;
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
        st = solve(ctx, s, &L, n, threads, W, k0, out);
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
