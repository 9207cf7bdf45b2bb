/* Tests of the SH engine (src/sh): basis, zonal functions, rotation, product tensor, log-visibility,
 * exponential. Reference values come from independent quadrature in this file, closed forms, and
 * finite differences in double; the float path is checked against the double path. */
#include "check.h"
#include "penumbra/sh.h"

#include <string.h>

static unsigned long long rng = 12345;
static double urand(double lo, double hi) {
    return lo + (hi - lo) * check_rand_(&rng);
}
static void rand_dir(double d[3]) {
    double z = urand(-1, 1), phi = urand(0, 2 * M_PI), s = sqrt(1 - z * z);
    d[0] = s * cos(phi), d[1] = s * sin(phi), d[2] = z;
}

/* A quadrature independent of the generated product tensor (scripts/sh_common.py): midpoint in
 * cos(theta) (many nodes) x uniform phi. Exact in phi, O(h^2) in theta; used with enough nodes for
 * 1e-7 agreement. */
typedef struct {
    int count;
    double (*dir)[3];
    double *w;
} quad;
static quad make_quad(int nt, int np) {
    quad q = {nt * np, malloc(sizeof(double[3]) * (size_t)(nt * np)), malloc(sizeof(double) * (size_t)(nt * np))};
    for (int a = 0; a < nt; ++a)
        for (int b = 0; b < np; ++b) {
            /* Substitution z = sin(u) clusters nodes near the poles; still midpoint in u. */
            double u = -M_PI / 2 + M_PI * (a + 0.5) / nt, z = sin(u), s = cos(u);
            double phi = 2 * M_PI * (b + 0.5) / np;
            int p = a * np + b;
            q.dir[p][0] = s * cos(phi), q.dir[p][1] = s * sin(phi), q.dir[p][2] = z;
            q.w[p] = cos(u) * (M_PI / nt) * (2 * M_PI / np);
        }
    return q;
}
static void free_quad(quad *q) {
    free(q->dir);
    free(q->w);
}

/* ---- Basis ---------------------------------------------------------------------------------- */

static void test_basis_known_values(void) {
    double d[3] = {0.36, -0.48, 0.8}, y[64];
    pen_sh_eval_d(8, d, y);
    CHECK_NEAR(y[0], 0.28209479177387814, 1e-15);
    CHECK_NEAR(y[1], -0.48860251190291992 * d[1], 1e-15);
    CHECK_NEAR(y[2], 0.48860251190291992 * d[2], 1e-15);
    CHECK_NEAR(y[3], -0.48860251190291992 * d[0], 1e-15);
    /* l = 2: Y_2,-2 = 1.092548 x y, Y_20 = 0.315392 (3 z^2 - 1), Y_22 = 0.546274 (x^2 - y^2) */
    CHECK_NEAR(y[4], 1.0925484305920792 * d[0] * d[1], 1e-14);
    CHECK_NEAR(y[5], -1.0925484305920792 * d[1] * d[2], 1e-14);
    CHECK_NEAR(y[6], 0.31539156525252005 * (3 * d[2] * d[2] - 1), 1e-14);
    CHECK_NEAR(y[7], -1.0925484305920792 * d[0] * d[2], 1e-14);
    CHECK_NEAR(y[8], 0.54627421529603959 * (d[0] * d[0] - d[1] * d[1]), 1e-14);
}

static void test_basis_orthonormal(void) {
    quad q = make_quad(400, 64);
    enum { L = 8, N = 64 };
    static double G[N][N];
    memset(G, 0, sizeof G);
    double y[N];
    for (int p = 0; p < q.count; ++p) {
        pen_sh_eval_d(L, q.dir[p], y);
        for (int i = 0; i < N; ++i)
            for (int j = 0; j < N; ++j) G[i][j] += q.w[p] * y[i] * y[j];
    }
    double worst = 0;
    for (int i = 0; i < N; ++i)
        for (int j = 0; j < N; ++j) worst = fmax(worst, fabs(G[i][j] - (i == j)));
    CHECK_MSG(worst < 1e-4, "max |<Y_i,Y_j> - delta| = %g", worst);
    free_quad(&q);
}

static void test_basis_gradient_fd(void) {
    for (int trial = 0; trial < 20; ++trial) {
        double d[3], w[64], g[3] = {0, 0, 0};
        rand_dir(d);
        for (int i = 0; i < 64; ++i) w[i] = urand(-1, 1);
        pen_sh_eval_bwd_d(8, d, w, g);
        for (int k = 0; k < 3; ++k) {
            double h = 1e-6, dp[3] = {d[0], d[1], d[2]}, dm[3] = {d[0], d[1], d[2]}, yp[64], ym[64];
            dp[k] += h, dm[k] -= h;
            pen_sh_eval_d(8, dp, yp);
            pen_sh_eval_d(8, dm, ym);
            double fd = 0;
            for (int i = 0; i < 64; ++i) fd += w[i] * (yp[i] - ym[i]) / (2 * h);
            CHECK_REL(g[k], fd, 1e-6, 1e-3);
        }
    }
}

/* ---- Zonal ---------------------------------------------------------------------------------- */

static double legendre(int l, double t) {
    double p0 = 1, p1 = t;
    if (l == 0) return 1;
    for (int k = 1; k < l; ++k) {
        double p2 = ((2 * k + 1) * t * p1 - k * p0) / (k + 1);
        p0 = p1, p1 = p2;
    }
    return p1;
}

static void test_zonal_cap_by_quadrature(void) {
    const double cosines[] = {0.999, 0.9, 0.5, 0.0, -0.3};
    for (int c = 0; c < 5; ++c) {
        double t0 = cosines[c], z[8];
        pen_sh_zonal_cap_d(8, t0, z, NULL);
        for (int l = 0; l < 8; ++l) {
            /* z_l = 2 pi integral_{t0}^1 sqrt((2l+1)/(4 pi)) P_l(t) dt, Simpson's rule */
            int n = 2000;
            double h = (1 - t0) / n, s = 0;
            for (int i = 0; i <= n; ++i) {
                double wt = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
                s += wt * legendre(l, t0 + i * h);
            }
            double ref = 2 * M_PI * sqrt((2 * l + 1) / (4 * M_PI)) * s * h / 3;
            CHECK_NEAR(z[l], ref, 1e-10);
        }
    }
}

static void test_zonal_cap_derivative_fd(void) {
    const double cosines[] = {0.99999, 0.8, 0.1, -0.7};
    for (int c = 0; c < 4; ++c) {
        double t = cosines[c], z[8], dz[8], zp[8], zm[8], h = 1e-6;
        pen_sh_zonal_cap_d(8, t, z, dz);
        pen_sh_zonal_cap_d(8, t + h, zp, NULL);
        pen_sh_zonal_cap_d(8, t - h, zm, NULL);
        for (int l = 0; l < 8; ++l) CHECK_REL(dz[l], (zp[l] - zm[l]) / (2 * h), 1e-6, 1e-3);
    }
}

static void test_clamped_cosine(void) {
    double z[8];
    pen_sh_zonal_clamped_cosine_d(8, z);
    const double expect[5] = {0.886227, 1.023327, 0.495416, 0, -0.110778};
    for (int l = 0; l < 5; ++l) CHECK_NEAR(z[l], expect[l], 1e-6);
    CHECK_NEAR(z[5], 0, 1e-15);
    CHECK_NEAR(z[7], 0, 1e-15);
    /* l = 6 by quadrature: 2 pi sqrt(13/(4 pi)) integral_0^1 t P_6(t) dt */
    int n = 4000;
    double s = 0, h = 1.0 / n;
    for (int i = 0; i <= n; ++i) {
        double wt = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
        s += wt * (i * h) * legendre(6, i * h);
    }
    CHECK_NEAR(z[6], 2 * M_PI * sqrt(13 / (4 * M_PI)) * s * h / 3, 1e-10);
}

static void test_rotate_zonal_addition_theorem(void) {
    /* sum_i out_i Y_i(w) must equal sum_l z_l sqrt((2l+1)/(4 pi)) P_l(d . w). */
    for (int trial = 0; trial < 10; ++trial) {
        double z[8], d[3], w[3], out[64], y[64];
        for (int l = 0; l < 8; ++l) z[l] = urand(-1, 1);
        rand_dir(d), rand_dir(w);
        pen_sh_rotate_zonal_d(8, z, d, out);
        pen_sh_eval_d(8, w, y);
        double lhs = 0, rhs = 0, cw = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
        for (int i = 0; i < 64; ++i) lhs += out[i] * y[i];
        for (int l = 0; l < 8; ++l) rhs += z[l] * sqrt((2 * l + 1) / (4 * M_PI)) * legendre(l, cw);
        CHECK_NEAR(lhs, rhs, 1e-12);
    }
}

static void test_rotate_zonal_bwd_fd(void) {
    for (int trial = 0; trial < 10; ++trial) {
        double z[8], d[3], w[64], d_z[8] = {0}, d_d[3] = {0, 0, 0};
        for (int l = 0; l < 8; ++l) z[l] = urand(-1, 1);
        for (int i = 0; i < 64; ++i) w[i] = urand(-1, 1);
        rand_dir(d);
        pen_sh_rotate_zonal_bwd_d(8, z, d, w, d_z, d_d);
        double h = 1e-6, op[64], om[64];
        for (int l = 0; l < 8; ++l) {
            double zp[8], zm[8];
            memcpy(zp, z, sizeof z), memcpy(zm, z, sizeof z);
            zp[l] += h, zm[l] -= h;
            pen_sh_rotate_zonal_d(8, zp, d, op);
            pen_sh_rotate_zonal_d(8, zm, d, om);
            double fd = 0;
            for (int i = 0; i < 64; ++i) fd += w[i] * (op[i] - om[i]) / (2 * h);
            CHECK_REL(d_z[l], fd, 1e-6, 1e-3);
        }
        for (int k = 0; k < 3; ++k) {
            double dp[3] = {d[0], d[1], d[2]}, dm[3] = {d[0], d[1], d[2]};
            dp[k] += h, dm[k] -= h;
            pen_sh_rotate_zonal_d(8, z, dp, op);
            pen_sh_rotate_zonal_d(8, z, dm, om);
            double fd = 0;
            for (int i = 0; i < 64; ++i) fd += w[i] * (op[i] - om[i]) / (2 * h);
            CHECK_REL(d_d[k], fd, 1e-6, 1e-3);
        }
    }
}

/* ---- Product -------------------------------------------------------------------------------- */

static void test_gaunt_identity_and_symmetry(void) {
    for (int L = 1; L <= 8; ++L) {
        const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
        CHECK(g != NULL && g->bands == L);
        if (!g) continue;
        int n = L * L;
        /* Gamma_0jk = delta_jk / sqrt(4 pi) */
        double *G0 = calloc((size_t)(n * n), sizeof(double));
        for (int e = 0; e < g->count; ++e)
            if (g->entries[e].i == 0) G0[g->entries[e].j * n + g->entries[e].k] = g->entries[e].value;
        double worst = 0;
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                worst = fmax(worst, fabs(G0[j * n + k] - (j == k) / sqrt(4 * M_PI)));
        CHECK_MSG(worst < 1e-13, "bands %d: max |Gamma_0jk - delta/sqrt(4pi)| = %g", L, worst);
        free(G0);
    }
    CHECK(pen_sh_gaunt_table(0) == NULL);
    CHECK(pen_sh_gaunt_table(9) == NULL);
    const pen_sh_gaunt *g4 = pen_sh_gaunt_table(4);
    /* Unordered triples i <= j <= k at 4 bands (the ordered entries are their permutations). */
    int unordered = 0;
    for (int e = 0; e < g4->count; ++e)
        unordered += g4->entries[e].i <= g4->entries[e].j && g4->entries[e].j <= g4->entries[e].k;
    printf("  4 bands: %d ordered non-zero entries, %d unordered triples\n", g4->count, unordered);
    CHECK(g4->count > 0 && g4->count < 16 * 16 * 16);
}

static void test_gaunt_by_quadrature(void) {
    /* Every entry, and every triple's absence, against the independent quadrature. */
    const int L = 4, n = 16;
    quad q = make_quad(600, 32);
    static double T[16][16][16];
    memset(T, 0, sizeof T);
    double y[16];
    for (int p = 0; p < q.count; ++p) {
        pen_sh_eval_d(L, q.dir[p], y);
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j)
                for (int k = 0; k < n; ++k) T[i][j][k] += q.w[p] * y[i] * y[j] * y[k];
    }
    const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
    static double G[16][16][16];
    memset(G, 0, sizeof G);
    for (int e = 0; e < g->count; ++e) G[g->entries[e].i][g->entries[e].j][g->entries[e].k] += g->entries[e].value;
    double worst = 0;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k) worst = fmax(worst, fabs(G[i][j][k] - T[i][j][k]));
    CHECK_MSG(worst < 1e-5, "max |Gamma - quadrature| = %g", worst);
    free_quad(&q);
}

static void test_gaunt_all_bands(void) {
    /* The generated table (scripts/sh_common.py via src/sh/tables.c) at every band count: the
     * table of L bands is exactly the part of the 8-band one with indices < L^2, and every 8-band
     * entry agrees with the independent quadrature (phi exact; midpoint in theta). */
    const pen_sh_gaunt *g8 = pen_sh_gaunt_table(8);
    CHECK(g8 != NULL);
    if (!g8) return;
    for (int L = 1; L < 8; ++L) {
        const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
        const int n = L * L;
        int e8 = 0, same = 1;
        for (int e = 0; e < g8->count; ++e) {
            const pen_sh_gaunt_entry *a = &g8->entries[e];
            if (a->i >= n || a->j >= n || a->k >= n) continue;
            const pen_sh_gaunt_entry *b = e8 < g->count ? &g->entries[e8] : NULL;
            same &= b && b->i == a->i && b->j == a->j && b->k == a->k && b->value == a->value &&
                    g->values_f[e8] == (float)a->value;
            ++e8;
        }
        CHECK_MSG(same && e8 == g->count, "bands %d: not the 8-band table restricted", L);
    }
    quad q = make_quad(4000, 64);
    double *acc = calloc((size_t)g8->count, sizeof(double)), y[64];
    for (int p = 0; p < q.count; ++p) {
        pen_sh_eval_d(8, q.dir[p], y);
        for (int e = 0; e < g8->count; ++e) {
            const pen_sh_gaunt_entry *a = &g8->entries[e];
            acc[e] += q.w[p] * y[a->i] * y[a->j] * y[a->k];
        }
    }
    double worst = 0;
    for (int e = 0; e < g8->count; ++e) worst = fmax(worst, fabs(acc[e] - g8->entries[e].value));
    printf("  8 bands: %d ordered entries, max |Gamma - quadrature| = %.2g\n", g8->count, worst);
    CHECK_MSG(worst < 1e-5, "8 bands: max |Gamma - quadrature| = %g", worst);
    free(acc);
    free_quad(&q);
}

static void test_product_is_projection(void) {
    /* The product of two 5-band functions projected back onto 5 bands, by quadrature. */
    const int L = 5, n = 25;
    double a[25], b[25], c[25], ref[25] = {0}, ya[25];
    for (int i = 0; i < n; ++i) a[i] = urand(-1, 1), b[i] = urand(-1, 1);
    pen_sh_product_d(pen_sh_gaunt_table(L), a, b, c);
    quad q = make_quad(800, 64);
    for (int p = 0; p < q.count; ++p) {
        pen_sh_eval_d(L, q.dir[p], ya);
        double fa = 0, fb = 0;
        for (int i = 0; i < n; ++i) fa += a[i] * ya[i], fb += b[i] * ya[i];
        for (int k = 0; k < n; ++k) ref[k] += q.w[p] * fa * fb * ya[k];
    }
    for (int k = 0; k < n; ++k) CHECK_NEAR(c[k], ref[k], 1e-5);
    free_quad(&q);
}

static void test_product_bwd_fd(void) {
    const int L = 4, n = 16;
    const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
    double a[16], b[16], w[16], da[16] = {0}, db[16] = {0}, cp[16], cm[16], h = 1e-6;
    for (int i = 0; i < n; ++i) a[i] = urand(-1, 1), b[i] = urand(-1, 1), w[i] = urand(-1, 1);
    pen_sh_product_bwd_d(g, a, b, w, da, db);
    for (int i = 0; i < n; ++i) {
        double s = a[i];
        a[i] = s + h, pen_sh_product_d(g, a, b, cp);
        a[i] = s - h, pen_sh_product_d(g, a, b, cm);
        a[i] = s;
        double fd = 0;
        for (int k = 0; k < n; ++k) fd += w[k] * (cp[k] - cm[k]) / (2 * h);
        CHECK_REL(da[i], fd, 1e-6, 1e-3);
        s = b[i];
        b[i] = s + h, pen_sh_product_d(g, a, b, cp);
        b[i] = s - h, pen_sh_product_d(g, a, b, cm);
        b[i] = s;
        fd = 0;
        for (int k = 0; k < n; ++k) fd += w[k] * (cp[k] - cm[k]) / (2 * h);
        CHECK_REL(db[i], fd, 1e-6, 1e-3);
    }
}

/* ---- Log-visibility ------------------------------------------------------------------------- */

static void test_logvis_matches_cap_projection(void) {
    /* f projected by quadrature: -eps * integral over the cap of Y_i. */
    const int L = 4, n = 16;
    double x[3] = {0.1, -0.2, 0.05}, c[3] = {0.5, 0.7, -0.3}, r = 0.35, eps = 3.0, f[16];
    pen_sh_logvis_d(L, x, c, r, eps, f);
    double v[3] = {c[0] - x[0], c[1] - x[1], c[2] - x[2]};
    double D = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), cos_a = sqrt(1 - r * r / (D * D));
    quad q = make_quad(3000, 600);
    double ref[16] = {0}, y[16];
    for (int p = 0; p < q.count; ++p) {
        double cw = (v[0] * q.dir[p][0] + v[1] * q.dir[p][1] + v[2] * q.dir[p][2]) / D;
        if (cw < cos_a) continue;
        pen_sh_eval_d(L, q.dir[p], y);
        for (int i = 0; i < n; ++i) ref[i] -= eps * q.w[p] * y[i];
    }
    for (int i = 0; i < n; ++i) CHECK_NEAR(f[i], ref[i], 2e-3);
    free_quad(&q);
}

/* FD check of pen_sh_logvis_bwd_d w.r.t. x, c, r, eps at one configuration. */
static void check_logvis_fd(const double x[3], const double c[3], double r, double eps) {
    const int L = 5, n = 25;
    double w[25], dx[3] = {0, 0, 0}, dc[3] = {0, 0, 0}, dr = 0, de = 0, fp[25], fm[25];
    for (int i = 0; i < n; ++i) w[i] = urand(-1, 1);
    pen_sh_logvis_bwd_d(L, x, c, r, eps, w, dx, dc, &dr, &de);
    double p[8] = {x[0], x[1], x[2], c[0], c[1], c[2], r, eps};
    double an[8] = {dx[0], dx[1], dx[2], dc[0], dc[1], dc[2], dr, de};
    for (int k = 0; k < 8; ++k) {
        double h = 1e-7 * fmax(1.0, fabs(p[k])), pp[8], pm[8];
        memcpy(pp, p, sizeof p), memcpy(pm, p, sizeof p);
        pp[k] += h, pm[k] -= h;
        pen_sh_logvis_d(L, pp, pp + 3, pp[6], pp[7], fp);
        pen_sh_logvis_d(L, pm, pm + 3, pm[6], pm[7], fm);
        double fd = 0;
        for (int i = 0; i < n; ++i) fd += w[i] * (fp[i] - fm[i]) / (2 * h);
        CHECK_REL(an[k], fd, 1e-6, 1e-2);
        CHECK(isfinite(an[k]));
    }
}

static void test_logvis_bwd_fd(void) {
    for (int trial = 0; trial < 20; ++trial) {
        double x[3], c[3], dir[3];
        rand_dir(dir);
        for (int k = 0; k < 3; ++k) x[k] = urand(-1, 1);
        double D = urand(0.5, 3), r = urand(0.05, 0.9) * D;
        for (int k = 0; k < 3; ++k) c[k] = x[k] + D * dir[k];
        check_logvis_fd(x, c, r, urand(1, 6));
    }
    /* Edge cases: alpha -> 0, receiver just outside / on / inside the sphere. */
    const double x[3] = {0, 0, 0}, c[3] = {0.3, 0.8, 0.2};
    const double D = sqrt(0.09 + 0.64 + 0.04);
    check_logvis_fd(x, c, 1e-4 * D, 4.0);     /* tiny cap */
    check_logvis_fd(x, c, D / 1.0005, 4.0);   /* t just below PEN_SH_CAP_T0: linear branch */
    check_logvis_fd(x, c, D / 1.02, 4.0);     /* t above it */
    check_logvis_fd(x, c, D / 0.95, 4.0);     /* inside, not yet fully blocked */
    check_logvis_fd(x, c, D / 0.5, 4.0);      /* deep inside: clamped, gradients zero */
}

static void test_logvis_singular_finite(void) {
    const double x[3] = {0.2, 0.3, 0.4};
    const double radii[] = {1e-30, 1e-8, 0.5, 10, 1e6};
    for (int a = 0; a < 5; ++a) {
        double f[64], w[64], dx[3] = {0, 0, 0}, dc[3] = {0, 0, 0}, dr = 0;
        for (int i = 0; i < 64; ++i) w[i] = 1;
        /* the receiver at the centre, and at the surface exactly */
        const double cs[2][3] = {{0.2, 0.3, 0.4}, {0.2 + radii[a], 0.3, 0.4}};
        for (int s = 0; s < 2; ++s) {
            pen_sh_logvis_d(8, x, cs[s], radii[a], 4.0, f);
            pen_sh_logvis_bwd_d(8, x, cs[s], radii[a], 4.0, w, dx, dc, &dr, NULL);
            int ok = isfinite(dx[0] + dx[1] + dx[2] + dc[0] + dc[1] + dc[2] + dr);
            for (int i = 0; i < 64; ++i) ok &= isfinite(f[i]);
            CHECK_MSG(ok, "radius %g, case %d", radii[a], s);
        }
    }
    /* Deep inside: the whole sphere of directions is blocked, f = -eps sqrt(4 pi) Y_00 only. */
    double f[16], c[3] = {0.2, 0.3, 0.41};
    pen_sh_logvis_d(4, x, c, 1.0, 2.0, f);
    CHECK_NEAR(f[0], -2.0 * sqrt(4 * M_PI), 1e-12);
    for (int i = 1; i < 16; ++i) CHECK_NEAR(f[i], 0, 1e-12);
}

/* ---- Exponential ---------------------------------------------------------------------------- */

static void random_F(int n, double norm, double dc, double *F) {
    double s = 0;
    for (int i = 1; i < n; ++i) F[i] = urand(-1, 1), s += F[i] * F[i];
    for (int i = 1; i < n; ++i) F[i] *= norm / sqrt(s);
    F[0] = dc;
}

static void test_exp_dc_isolation_exact(void) {
    const pen_sh_exp_method methods[] = {PEN_SH_EXP_PAPER, PEN_SH_EXP_EXACT, PEN_SH_EXP_CALIBRATED};
    for (int mi = 0; mi < 3; ++mi) {
        pen_sh_exp_model m = pen_sh_exp_model_default(methods[mi], 4);
        double F[16] = {-2.5}, V[16];
        pen_sh_exp_d(&m, pen_sh_gaunt_table(4), F, V);
        /* exp of a constant function c = F_0 Y_00 is the constant exp(c). */
        CHECK_NEAR(V[0], exp(-2.5 / sqrt(4 * M_PI)) * sqrt(4 * M_PI), 1e-12);
        for (int i = 1; i < 16; ++i) CHECK_NEAR(V[i], 0, 1e-14);
    }
}

static void test_exp_paper_formula(void) {
    /* |F^| < 1: no squaring, V = exp(F_0/sqrt(4pi)) (exp(0.1x) 1 + exp(-0.2x) F^). */
    pen_sh_exp_model m = pen_sh_exp_model_default(PEN_SH_EXP_PAPER, 4);
    double F[16], V[16];
    random_F(16, 0.7, -1.0, F);
    pen_sh_exp_d(&m, pen_sh_gaunt_table(4), F, V);
    double dc = exp(-1.0 / sqrt(4 * M_PI));
    CHECK_NEAR(V[0], dc * exp(0.07) * sqrt(4 * M_PI), 1e-12);
    for (int i = 1; i < 16; ++i) CHECK_NEAR(V[i], dc * exp(-0.14) * F[i], 1e-12);
}

static void test_exp_exact_against_series(void) {
    /* Small |F^| (no squaring): EXACT equals the Taylor series to high order. */
    const pen_sh_gaunt *g = pen_sh_gaunt_table(4);
    pen_sh_exp_model m = pen_sh_exp_model_default(PEN_SH_EXP_EXACT, 4);
    double F[16], V[16], term[16] = {0}, next[16], sum[16] = {0};
    random_F(16, 0.05, 0.0, F);
    pen_sh_exp_d(&m, g, F, V);
    term[0] = sqrt(4 * M_PI);
    for (int j = 0; j < 40; ++j) {
        for (int i = 0; i < 16; ++i) sum[i] += term[i];
        pen_sh_product_d(g, term, F, next);
        for (int i = 0; i < 16; ++i) term[i] = next[i] / (j + 1);
    }
    for (int i = 0; i < 16; ++i) CHECK_NEAR(V[i], sum[i], 1e-14);
    /* A 1-band-wide zonal F^ at larger norm: exp of the band-limited function projected, compared
     * loosely (the truncated algebra differs from the true projection by the truncation). */
}

static void check_exp_fd(pen_sh_exp_method method, int L, double norm) {
    const int n = L * L;
    const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
    pen_sh_exp_model m = pen_sh_exp_model_default(method, L);
    double F[64], w[64], dF[64] = {0}, Vp[64], Vm[64];
    random_F(n, norm, urand(-3, 0), F);
    for (int i = 0; i < n; ++i) w[i] = urand(-1, 1);
    pen_sh_exp_bwd_d(&m, g, F, w, dF);
    /* Many squarings amplify rounding, so a plain central difference is noisy at large |F^|:
     * use the fourth-order stencil (8 (f(h) - f(-h)) - (f(2h) - f(-2h))) / 12h with a larger h. */
    for (int i = 0; i < n; ++i) {
        double h = 1e-3 * fmin(1.0, norm), s = F[i], V2p[64], V2m[64];
        F[i] = s + h, pen_sh_exp_d(&m, g, F, Vp);
        F[i] = s - h, pen_sh_exp_d(&m, g, F, Vm);
        F[i] = s + 2 * h, pen_sh_exp_d(&m, g, F, V2p);
        F[i] = s - 2 * h, pen_sh_exp_d(&m, g, F, V2m);
        F[i] = s;
        double fd = 0, scale = 0;
        for (int k = 0; k < n; ++k) {
            fd += w[k] * (8 * (Vp[k] - Vm[k]) - (V2p[k] - V2m[k])) / (12 * h);
            scale += fabs(w[k] * Vp[k]);
        }
        CHECK_MSG(fabs(dF[i] - fd) <= 1e-6 * fmax(fabs(fd), scale * 1e-2),
                  "%s L=%d |F^|=%g i=%d: analytic %.12g, fd %.12g", pen_sh_exp_method_name(method),
                  L, norm, i, dF[i], fd);
    }
}

static void test_exp_bwd_fd(void) {
    const pen_sh_exp_method methods[] = {PEN_SH_EXP_PAPER, PEN_SH_EXP_EXACT, PEN_SH_EXP_CALIBRATED};
    /* Norms chosen away from the powers of two where PAPER and EXACT change their squarings;
     * 23 and 300 are past the saturation's knee (sh.h), 300 where the models alone overflow. */
    const double norms[] = {0.03, 0.7, 5.3, 23.0, 300.0};
    for (int mi = 0; mi < 3; ++mi)
        for (int a = 0; a < 5; ++a)
            for (int L = 3; L <= 5; ++L) check_exp_fd(methods[mi], L, norms[a]);
}

/* ---- Float path against double -------------------------------------------------------------- */

static void test_float_matches_double(void) {
    const int L = 4, n = 16;
    const pen_sh_gaunt *g = pen_sh_gaunt_table(L);
    for (int trial = 0; trial < 50; ++trial) {
        double dd[3], x[3] = {0, 0, 0}, c[3], fd_[16], Vd[16], gd[3] = {0, 0, 0};
        float df[3], xf[3] = {0, 0, 0}, cf[3], ff[16], Vf[16], gf[3] = {0, 0, 0};
        rand_dir(dd);
        double D = urand(0.4, 2), r = urand(0.1, 0.6) * D;
        for (int k = 0; k < 3; ++k) c[k] = D * dd[k], cf[k] = (float)c[k], df[k] = (float)dd[k];
        pen_sh_logvis_d(L, x, c, r, 4.0, fd_);
        pen_sh_logvis(L, xf, cf, (float)r, 4.0f, ff);
        for (int i = 0; i < n; ++i) CHECK_NEAR(ff[i], fd_[i], 1e-4 * (1 + fabs(fd_[i])));
        for (int mi = 0; mi < 3; ++mi) {
            pen_sh_exp_model m = pen_sh_exp_model_default((pen_sh_exp_method)mi, L);
            float Ff[16];
            for (int i = 0; i < n; ++i) Ff[i] = (float)fd_[i];
            pen_sh_exp_d(&m, g, fd_, Vd);
            pen_sh_exp(&m, g, Ff, Vf);
            for (int i = 0; i < n; ++i) CHECK_NEAR(Vf[i], Vd[i], 2e-4 * (1 + fabs(Vd[i])));
        }
        double wd[16];
        float wf[16];
        for (int i = 0; i < n; ++i) wd[i] = urand(-1, 1), wf[i] = (float)wd[i];
        pen_sh_eval_bwd_d(L, dd, wd, gd);
        pen_sh_eval_bwd(L, df, wf, gf);
        for (int k = 0; k < 3; ++k) CHECK_NEAR(gf[k], gd[k], 1e-4 * (1 + fabs(gd[k])));
    }
}

static void test_method_names(void) {
    CHECK(pen_sh_exp_method_parse("paper") == PEN_SH_EXP_PAPER);
    CHECK(pen_sh_exp_method_parse("exact") == PEN_SH_EXP_EXACT);
    CHECK(pen_sh_exp_method_parse("calibrated") == PEN_SH_EXP_CALIBRATED);
    CHECK(pen_sh_exp_method_parse("default") == PEN_SH_EXP_CALIBRATED);
    CHECK(pen_sh_exp_method_parse("Paper") == -1);
    CHECK(pen_sh_exp_method_parse(NULL) == -1);
}

RUN_TESTS(TEST(test_basis_known_values), TEST(test_basis_orthonormal), TEST(test_basis_gradient_fd),
          TEST(test_zonal_cap_by_quadrature), TEST(test_zonal_cap_derivative_fd),
          TEST(test_clamped_cosine), TEST(test_rotate_zonal_addition_theorem),
          TEST(test_rotate_zonal_bwd_fd), TEST(test_gaunt_identity_and_symmetry),
          TEST(test_gaunt_by_quadrature), TEST(test_gaunt_all_bands),
          TEST(test_product_is_projection),
          TEST(test_product_bwd_fd), TEST(test_logvis_matches_cap_projection),
          TEST(test_logvis_bwd_fd), TEST(test_logvis_singular_finite),
          TEST(test_exp_dc_isolation_exact), TEST(test_exp_paper_formula),
          TEST(test_exp_exact_against_series), TEST(test_exp_bwd_fd),
          TEST(test_float_matches_double), TEST(test_method_names))
