/* The SH product tensor Gamma_ijk = integral over the sphere of Y_i Y_j Y_k, per band count, and
 * the hemisphere projection matrix of ground occlusion (pen__sh_above).
 *
 * Product tensor. Its values have one source of truth, scripts/sh_common.py, which integrates
 * them once in double for PEN_SH_MAX_BANDS bands by a quadrature exact for the integrand
 * (Gauss-Legendre in cos(theta) with 2L nodes x 4L uniform phi) and writes the non-zero unordered
 * triples i <= j <= k into src/sh/tables.c (`make generate`; tests/cli_generated.sh checks that
 * the committed file matches its generator). The fast kernel's product code
 * (sh_fast_product_L.inc) is generated from the same values. Gamma does not depend on the band
 * count, so the table of L bands takes the triples with k < L^2; here they are expanded into
 * their distinct orderings and sorted by (k, i, j), lazily, one pthread_once per band count, and
 * live for the process. tests/test_sh.c checks the result against an independent quadrature.
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
    const int n = L * L;
    int count = 0;
    for (int t = 0; t < pen__sh_gaunt_triple_count; ++t)
        if (pen__sh_gaunt_triples[t].k < n) count += 6;
    pen_sh_gaunt_entry *E = malloc(sizeof *E * (size_t)(count ? count : 1));
    float *vf = malloc(sizeof(float) * (size_t)(count ? count : 1));
    if (!E || !vf) goto fail;
    count = 0;
    for (int t = 0; t < pen__sh_gaunt_triple_count; ++t) {
        const pen_sh_gaunt_entry *g = &pen__sh_gaunt_triples[t];
        if (g->k >= n) continue;
        const int i = g->i, j = g->j, k = g->k;
        /* The distinct orderings of (i, j, k). */
        const int perm[6][3] = {{i, j, k}, {i, k, j}, {j, i, k}, {j, k, i}, {k, i, j}, {k, j, i}};
        for (int p = 0; p < 6; ++p) {
            int dup = 0;
            for (int u = 0; u < p; ++u)
                dup |= perm[u][0] == perm[p][0] && perm[u][1] == perm[p][1] &&
                       perm[u][2] == perm[p][2];
            if (dup) continue;
            E[count++] =
                (pen_sh_gaunt_entry){(unsigned short)perm[p][0], (unsigned short)perm[p][1],
                                     (unsigned short)perm[p][2], g->value};
        }
    }
    qsort(E, (size_t)count, sizeof *E, cmp_entry);
    for (int e = 0; e < count; ++e) vf[e] = (float)E[e].value;
    tables[L] = (pen_sh_gaunt){L, count, E, vf};
    return;
fail: /* leaves tables[L].entries NULL: pen_sh_gaunt_table reports the table as unavailable */
    free(E);
    free(vf);
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
