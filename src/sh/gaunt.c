/* The SH product tensor Gamma_ijk = integral over the sphere of Y_i Y_j Y_k.
 *
 * Computed once per band count, in double, by quadrature that is exact for the integrand: the
 * product of three SH of degree < L is a polynomial of degree <= 3(L-1) in (x, y, z), so
 * Gauss-Legendre in cos(theta) with n >= (3(L-1)+1)/2 nodes and a uniform phi grid with
 * M >= 3(L-1)+1 points integrate it to rounding. We take n = 2L and M = 4L. Only the unordered
 * triples i <= j <= k are integrated; the ordered entries are their permutations. Entries below
 * 1e-12 in magnitude are zero by the selection rules (m and parity) and are dropped.
 * Tables are built lazily, one pthread_once per band count, and live for the process.
 */
#include "core/internal.h"
#include "sh/sh_internal.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

static pen_sh_gaunt tables[PEN_SH_MAX_BANDS + 1];
static pthread_once_t once[PEN_SH_MAX_BANDS + 1] = {
    PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT,
    PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT, PTHREAD_ONCE_INIT};

/* Gauss-Legendre nodes and weights on [-1, 1] by Newton's method on P_n. */
static void gauss_legendre(int n, double *x, double *w) {
    for (int i = 0; i < n; ++i) {
        double t = cos(PEN_PI * (i + 0.75) / (n + 0.5));
        double dp = 1.0;
        for (int it = 0; it < 100; ++it) {
            double p0 = 1.0, p1 = t;
            for (int l = 1; l < n; ++l) {
                double p2 = ((2.0 * l + 1.0) * t * p1 - l * p0) / (l + 1.0);
                p0 = p1, p1 = p2;
            }
            dp = n * (t * p1 - p0) / (t * t - 1.0);
            double dt = p1 / dp;
            t -= dt;
            if (fabs(dt) < 1e-16) break;
        }
        x[i] = t;
        w[i] = 2.0 / ((1.0 - t * t) * dp * dp);
    }
}

/* Adds w Y_j Y_k over a ring of np directions at height y (uniform in phi) into M. */
static void add_ring(int L, double y, double w, int np, double *M) {
    const int n = L * L;
    const double s = sqrt(fmax(0.0, 1.0 - y * y));
    double Y[PEN_SH_MAX_COEFFS];
    for (int b = 0; b < np; ++b) {
        const double phi = 2.0 * PEN_PI * (b + 0.5) / np;
        const double d[3] = {s * cos(phi), y, s * sin(phi)};
        pen_sh_eval_d(L, d, Y);
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                M[j * n + k] += w * 2.0 * PEN_PI / np * Y[j] * Y[k];
    }
}

void pen__sh_above(int bands, double t, double *M, double *dM) {
    /* Over a ring, Y_j Y_k integrates to a polynomial of degree <= 2(L-1) in y (the odd powers
     * of sqrt(1 - y^2) average out in phi): Gauss-Legendre in y over [-t, 1] with L nodes and
     * a uniform phi grid with 2L points integrate it exactly. */
    const int L = bands, n = L * L, np = 2 * L;
    double xs[PEN_SH_MAX_BANDS], ws[PEN_SH_MAX_BANDS];
    gauss_legendre(L, xs, ws);
    memset(M, 0, sizeof(double) * (size_t)n * (size_t)n);
    const double half = 0.5 * (1.0 + t); /* [-1, 1] -> [-t, 1] */
    for (int a = 0; a < L; ++a)
        add_ring(L, -t + half * (xs[a] + 1.0), half * ws[a], np, M);
    if (dM) {
        memset(dM, 0, sizeof(double) * (size_t)n * (size_t)n);
        add_ring(L, -t, 1.0, np, dM);
    }
}

static int cmp_entry(const void *pa, const void *pb) {
    const pen_sh_gaunt_entry *a = pa, *b = pb;
    if (a->k != b->k) return a->k - b->k;
    if (a->i != b->i) return a->i - b->i;
    return a->j - b->j;
}

static void build(int L) {
    const int n = L * L, nt = 2 * L, np = 4 * L, q = nt * np;
    double *Y = malloc(sizeof(double) * (size_t)q * (size_t)n);
    double *W = malloc(sizeof(double) * (size_t)q);
    int cap = 1024, count = 0;
    pen_sh_gaunt_entry *E = malloc(sizeof *E * (size_t)cap);
    if (!Y || !W || !E) goto fail;
    double xs[2 * PEN_SH_MAX_BANDS], ws[2 * PEN_SH_MAX_BANDS];
    gauss_legendre(nt, xs, ws);
    for (int a = 0; a < nt; ++a)
        for (int b = 0; b < np; ++b) {
            const double z = xs[a], s = sqrt(fmax(0.0, 1.0 - z * z));
            const double phi = 2.0 * PEN_PI * (b + 0.5) / np;
            const double d[3] = {s * cos(phi), s * sin(phi), z};
            const int p = a * np + b;
            pen_sh_eval_d(L, d, Y + (size_t)p * n);
            W[p] = ws[a] * 2.0 * PEN_PI / np;
        }
    for (int i = 0; i < n; ++i)
        for (int j = i; j < n; ++j)
            for (int k = j; k < n; ++k) {
                double s = 0.0;
                for (int p = 0; p < q; ++p) {
                    const double *y = Y + (size_t)p * n;
                    s += W[p] * y[i] * y[j] * y[k];
                }
                if (fabs(s) < 1e-12) continue;
                /* The distinct orderings of (i, j, k). */
                const int perm[6][3] = {{i, j, k}, {i, k, j}, {j, i, k},
                                        {j, k, i}, {k, i, j}, {k, j, i}};
                for (int t = 0; t < 6; ++t) {
                    int dup = 0;
                    for (int u = 0; u < t; ++u)
                        dup |= perm[u][0] == perm[t][0] && perm[u][1] == perm[t][1] &&
                               perm[u][2] == perm[t][2];
                    if (dup) continue;
                    if (count == cap) {
                        pen_sh_gaunt_entry *grown = realloc(E, sizeof *E * (size_t)cap * 2);
                        if (!grown) goto fail;
                        E = grown, cap *= 2;
                    }
                    E[count++] = (pen_sh_gaunt_entry){(unsigned short)perm[t][0],
                                                      (unsigned short)perm[t][1],
                                                      (unsigned short)perm[t][2], s};
                }
            }
    qsort(E, (size_t)count, sizeof *E, cmp_entry);
    float *vf = malloc(sizeof(float) * (size_t)count);
    if (!vf) goto fail;
    for (int e = 0; e < count; ++e) vf[e] = (float)E[e].value;
    free(Y);
    free(W);
    tables[L] = (pen_sh_gaunt){L, count, E, vf};
    return;
fail: /* leaves tables[L].entries NULL: pen_sh_gaunt_table reports the table as unavailable */
    free(Y);
    free(W);
    free(E);
}

#define ONCE_FN(L) \
    static void build_##L(void) { build(L); }
ONCE_FN(1)
ONCE_FN(2)
ONCE_FN(3)
ONCE_FN(4)
ONCE_FN(5)
ONCE_FN(6)
ONCE_FN(7)
ONCE_FN(8)
static void (*const builders[PEN_SH_MAX_BANDS + 1])(void) = {
    NULL, build_1, build_2, build_3, build_4, build_5, build_6, build_7, build_8};

const pen_sh_gaunt *pen_sh_gaunt_table(int bands) {
    if (bands < 1 || bands > PEN_SH_MAX_BANDS) return NULL;
    pthread_once(&once[bands], builders[bands]);
    return tables[bands].entries ? &tables[bands] : NULL;
}
