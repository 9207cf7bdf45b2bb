/* The disk lights in the fast kernel's lanes (src/shade/lights_fast.c, docs/design.md sec. 1.13,
 * "Precision of the fast kernel's term"): the forward block and its backward against the double
 * per-pixel term (src/shade/lights.c, itself checked against finite differences in
 * test_lights.c), in every variant this processor runs, on receivers placed behind spheres along
 * a light (full shadows, penumbrae, clear, inside a sphere), normals across the horizon, kappa 0,
 * horizon factors, no shadows, zero output gradients. */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "render_scenes.h"
#include "shade/lights.h"
#include "shade/shade.h"

#include <math.h>

static unsigned long long seed = 4242;

enum { S = 12, B = PEN_LIGHTS_BLOCK };

/* One random block: lights, spheres, receivers and output gradients. */
typedef struct block_case {
    pen__lights L;
    int K, cnt;
    float sph[4 * S], kap[S];
    double G[PEN_SCENE_MAX_LIGHTS];
    const double *Gp; /* G or NULL */
    float x[3 * B], nrm[3 * B], rho[3 * B], drgb[3 * B];
} block_case;

static void make_case(block_case *c, int trial) {
    pen_lighting lt;
    memset(&lt, 0, sizeof lt);
    /* 0.1 deg: under PEN_LIGHTS_COS_LENS_DEG, its penumbrae pair by pair; the rest in the packed
     * double lanes (a sun's 0.27 deg among them) */
    const double radii[4] = {0.1, 0.27, 3.0, 20.0};
    c->K = lt.light_count = 1 + trial % 3;
    for (int l = 0; l < c->K; ++l) {
        double d[3];
        rs_unit_vector(&seed, d);
        d[1] = fabs(d[1]) + 0.2;
        const double E = rs_uniform(&seed, 0.5, 3.0);
        for (int a = 0; a < 3; ++a) {
            lt.lights[l].direction[a] = (float)d[a];
            lt.lights[l].irradiance[a] = (float)(E * (1 + 0.3 * a));
        }
        lt.lights[l].angular_radius_deg = (float)radii[(trial + l) % 4];
    }
    pen__lights_init(&c->L, &lt, rs_uniform(&seed, 1.0, 6.0), trial % 17 != 0);
    for (int i = 0; i < S; ++i) {
        for (int a = 0; a < 3; ++a)
            c->sph[4 * i + a] = (float)rs_uniform(&seed, -1, 1);
        c->sph[4 * i + 3] = (float)rs_uniform(&seed, 0.05, 0.4);
        c->kap[i] = i % 5 == 4 ? 0.0f : (float)rs_uniform(&seed, 0.3, 1.0);
    }
    for (int l = 0; l < c->K; ++l)
        c->G[l] = rs_uniform(&seed, 0.2, 1.0);
    c->Gp = trial % 2 ? c->G : NULL;
    c->cnt = 1 + trial % B;
    for (int k = 0; k < c->cnt; ++k) {
        /* behind sphere i along light l, up to 1.3 r across; mostly facing the light */
        const int i = (int)rs_uniform(&seed, 0, S - 0.001), l = k % c->K;
        const double r = (double)c->sph[4 * i + 3], back = rs_uniform(&seed, 0.5 * r, 2.5);
        const double across = rs_uniform(&seed, 0.0, 1.3 * r);
        double off[3], nn[3];
        rs_unit_vector(&seed, off);
        rs_unit_vector(&seed, nn);
        for (int a = 0; a < 3; ++a) {
            c->x[3 * k + a] =
                (float)((double)c->sph[4 * i + a] - back * c->L.w[l][a] + across * off[a]);
            if (k % 4 != 3) nn[a] = c->L.w[l][a] + 0.6 * nn[a];
        }
        const double len = sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
        for (int a = 0; a < 3; ++a) {
            c->nrm[3 * k + a] = (float)(nn[a] / len), c->rho[3 * k + a] = (float)(0.3 + 0.2 * a);
            c->drgb[3 * k + a] = k % 7 == 6 ? 0.0f : (float)rs_uniform(&seed, -1, 1);
        }
    }
}

/* Runs check(case, variant, trial) over 300 cases in every variant this processor runs, then
 * restores the variant in use; returns the number of variants. */
static int each_variant(void (*check)(const block_case *, int, int)) {
    const pen__shade_fast_ops *was = pen__shade_fast_current();
    int variants = 0;
    for (int v = 0; v < pen__shade_fast_variants(); ++v) {
        if (!pen__shade_fast_use(v)) continue;
        ++variants;
        for (int trial = 0; trial < 300; ++trial) {
            block_case c;
            make_case(&c, trial);
            check(&c, v, trial);
        }
    }
    for (int v = 0; v < pen__shade_fast_variants(); ++v)
        if (pen__shade_fast_variant_ops(v) == was) pen__shade_fast_use(v);
    return variants;
}

static int shadowed, partial;
static double worst, worst_V;

/* The block's fractions are the double ones (0, 1 or the lens), so what differs is the float
 * rounding of D, q and the product: a few 1e-7 of the light, a few 1e-6 of V. */
static void check_fwd(const block_case *c, int v, int trial) {
    const int K = c->K;
    float got[3 * B] = {0}, Vg[PEN_SCENE_MAX_LIGHTS * B];
    pen__lights_fwd_block(&c->L, c->Gp, S, c->sph, c->kap, NULL, c->cnt, c->x, c->nrm, c->rho, NULL,
                          got, Vg);
    double scale = 0.0;
    for (int l = 0; l < K; ++l)
        scale += c->L.E[l][0];
    for (int k = 0; k < c->cnt; ++k) {
        float want[3] = {0, 0, 0}, Vw[PEN_SCENE_MAX_LIGHTS];
        pen__lights_fwd(&c->L, c->Gp, S, c->sph, c->kap, NULL, c->x + 3 * k, c->nrm + 3 * k,
                        c->rho + 3 * k, want, Vw);
        for (int ch = 0; ch < 3; ++ch) {
            const double d = fabs((double)got[3 * k + ch] - (double)want[ch]);
            worst = fmax(worst, d / scale);
            CHECK_MSG(d <= 2e-6 * scale, "variant %d trial %d receiver %d: %.9g vs %.9g", v, trial,
                      k, (double)got[3 * k + ch], (double)want[ch]);
        }
        for (int l = 0; l < K; ++l) {
            worst_V = fmax(worst_V, fabs((double)Vg[K * k + l] - (double)Vw[l]));
            CHECK_MSG(fabs((double)Vg[K * k + l] - (double)Vw[l]) <= 1e-5, "V %d: %.9g vs %.9g", l,
                      (double)Vg[K * k + l], (double)Vw[l]);
            shadowed += Vw[l] < 0.999f;
            partial += Vw[l] > 0.01f && Vw[l] < 0.99f;
        }
    }
}

static void test_fwd_block(void) {
    shadowed = partial = 0, worst = worst_V = 0.0;
    const int variants = each_variant(check_fwd);
    CHECK_MSG(variants > 0, "no variant of the fast kernel runs here");
    CHECK_MSG(shadowed > 500 && partial > 100, "the cases shadowed %d receivers, %d partly",
              shadowed, partial);
    if (getenv("PEN_TEST_VERBOSE"))
        printf("  %d variants; %d shadowed, %d partly; worst %.3g of the light, %.3g in V\n",
               variants, shadowed, partial, worst, worst_V);
}

/* |a - b| <= 1e-4 size, the float lanes' sums against the double ones, relative to the size of
 * the gradient group (sums of terms of both signs cancel). The inside rule's fade (shade.h: a
 * smoothstep over 0.1 of |c - x| / r) turns the float rounding of |c - x| / r into up to ~4e-5 of
 * its derivative, for receivers just inside a sphere. */
static void close_to(double a, double b, double size, const char *what, int v, int trial, int i) {
    worst = fmax(worst, fabs(a - b) / size);
    CHECK_MSG(fabs(a - b) <= 1e-4 * size, "variant %d trial %d %s[%d]: %.9g vs %.9g", v, trial,
              what, i, a, b);
}

/* The backward block against pen__lights_bwd of each receiver, both given the double V, each
 * into its own sums; by trial every gradient, the lights' alone, no x and n (ground pixels), or
 * no kept V. */
static void check_bwd(const block_case *c, int v, int trial) {
    const int K = c->K, cnt = c->cnt, form = trial % 4;
    const int with_s = form != 1, xn = form != 1 && form != 2, keep = form != 3;
    float V[PEN_SCENE_MAX_LIGHTS * B] = {0};
    int pix[B] = {0};
    for (int k = 0; k < cnt; ++k) {
        float rgb[3] = {0, 0, 0};
        pen__lights_fwd(&c->L, c->Gp, S, c->sph, c->kap, NULL, c->x + 3 * k, c->nrm + 3 * k,
                        c->rho + 3 * k, rgb, V + K * k);
        pix[k] = k;
    }
    enum { NL = PEN_LIGHT_GRAD_DOUBLES * PEN_SCENE_MAX_LIGHTS };
    double ds[2][4 * S] = {{0}}, dl[2][NL] = {{0}}, dG[2][PEN_SCENE_MAX_LIGHTS] = {{0}};
    float dx[2][3 * B] = {{0}}, dn[2][3 * B] = {{0}}, dr[2][3 * B] = {{0}};
    int scratch[(S + 1) * B];
    pen__lights_bwd_block(&c->L, c->Gp, S, c->sph, c->kap, NULL, cnt, c->x, c->nrm, c->rho, c->drgb,
                          keep ? V : NULL, pix, scratch, with_s ? ds[0] : NULL, xn ? dx[0] : NULL,
                          xn ? dn[0] : NULL, dr[0], dl[0], c->Gp ? dG[0] : NULL);
    for (int k = 0; k < cnt; ++k)
        pen__lights_bwd(&c->L, c->Gp, S, c->sph, c->kap, NULL, c->x + 3 * k, c->nrm + 3 * k,
                        c->rho + 3 * k, c->drgb + 3 * k, keep ? V + K * k : NULL,
                        with_s ? ds[1] : NULL, xn ? dx[1] + 3 * k : NULL, xn ? dn[1] + 3 * k : NULL,
                        dr[1] + 3 * k, dl[1], c->Gp ? dG[1] : NULL);
    double geo = 1e-3, light = 1e-3, hor = 1e-3;
    for (int a = 0; a < 4 * S; ++a)
        geo = fmax(geo, fabs(ds[1][a]));
    for (int a = 0; a < 3 * cnt; ++a)
        geo = fmax(geo, fmax(fabs((double)dx[1][a]), fabs((double)dn[1][a])));
    for (int a = 0; a < PEN_LIGHT_GRAD_DOUBLES * K; ++a)
        light = fmax(light, fabs(dl[1][a]));
    for (int l = 0; l < K; ++l)
        hor = fmax(hor, fabs(dG[1][l]));
    for (int a = 0; a < 4 * S; ++a)
        close_to(ds[0][a], ds[1][a], geo, "d_sphere", v, trial, a);
    for (int a = 0; a < 3 * cnt; ++a) {
        close_to((double)dx[0][a], (double)dx[1][a], geo, "d_x", v, trial, a);
        close_to((double)dn[0][a], (double)dn[1][a], geo, "d_n", v, trial, a);
        close_to((double)dr[0][a], (double)dr[1][a], fmax(1e-3, fabs((double)dr[1][a])), "d_rho", v,
                 trial, a);
    }
    for (int a = 0; a < PEN_LIGHT_GRAD_DOUBLES * K; ++a)
        close_to(dl[0][a], dl[1][a], light, "d_light", v, trial, a);
    for (int l = 0; l < K; ++l)
        close_to(dG[0][l], dG[1][l], hor, "d_G", v, trial, l);
}

static void test_bwd_block(void) {
    worst = 0.0;
    const int variants = each_variant(check_bwd);
    CHECK_MSG(variants > 0, "no variant of the fast kernel runs here");
    if (getenv("PEN_TEST_VERBOSE"))
        printf("  %d variants; worst %.3g of a gradient's size\n", variants, worst);
}

/* One 0.27 deg sun straight up, eps 3. */
static void sun_overhead(pen__lights *L) {
    pen_lighting lt;
    memset(&lt, 0, sizeof lt);
    lt.light_count = 1;
    lt.lights[0].direction[1] = 1.0f, lt.lights[0].angular_radius_deg = 0.27f;
    lt.lights[0].irradiance[0] = lt.lights[0].irradiance[1] = lt.lights[0].irradiance[2] = 2.0f;
    pen__lights_init(L, &lt, 3.0, 1);
}

/* A receiver at a sphere's very centre (its weight 0, |c - x| / r = 0) in a block where another
 * receiver is in that sphere's full shadow: the lanes compute the pair's chain for every lane,
 * and this one's must stay 0, not 0 / 0. */
static void test_bwd_centre(void) {
    pen__lights L;
    sun_overhead(&L);
    const float sph[4] = {0.0f, 0.0f, 0.0f, 0.3f}, kap[1] = {1.0f};
    /* the second's normal nearly across the sphere (h = n . v / r = 0.66: its weight in the
     * smoothstep, so the pair has a gradient) but above the horizon for the light */
    const float x[6] = {0, 0, 0, 0, -2, 0}, nrm[6] = {0, 1, 0, 0.99498744f, 0.1f, 0};
    const float rho[6] = {0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f}, drgb[6] = {1, 1, 1, 1, 1, 1};
    float V[2], rgb[6] = {0};
    const int pix[2] = {0, 1};
    pen__lights_fwd_block(&L, NULL, 1, sph, kap, NULL, 2, x, nrm, rho, NULL, rgb, V);
    CHECK_MSG(V[1] < 0.5f, "the second receiver is in the sphere's shadow: V %g", (double)V[1]);
    double ds[2][4] = {{0}};
    float dx[2][6] = {{0}}, dn[2][6] = {{0}}, dr[2][6] = {{0}};
    int scratch[2 * PEN_LIGHTS_BLOCK];
    pen__lights_bwd_block(&L, NULL, 1, sph, kap, NULL, 2, x, nrm, rho, drgb, V, pix, scratch, ds[0],
                          dx[0], dn[0], dr[0], NULL, NULL);
    for (int k = 0; k < 2; ++k)
        pen__lights_bwd(&L, NULL, 1, sph, kap, NULL, x + 3 * k, nrm + 3 * k, rho + 3 * k,
                        drgb + 3 * k, V + k, ds[1], dx[1] + 3 * k, dn[1] + 3 * k, dr[1] + 3 * k,
                        NULL, NULL);
    for (int a = 0; a < 6; ++a)
        CHECK_MSG(isfinite(dx[0][a]) && fabs((double)dx[0][a] - (double)dx[1][a]) <= 1e-4,
                  "d_x[%d]: %g vs %g", a, (double)dx[0][a], (double)dx[1][a]);
    CHECK_MSG(fabs(ds[0][1] - ds[1][1]) <= 1e-4 * fabs(ds[1][1]) && ds[1][1] != 0.0,
              "d_sphere y: %g vs %g", ds[0][1], ds[1][1]);
}

/* Receivers just inside a sphere (|c - x| / r in [0.9, 0.93]), where the cap is continued below
 * t0 almost to the whole sphere and its sine amplifies the float rounding of its cosine, each
 * placed with the light's disk within 1e-4 rad of the cap's edge: the block must still give the
 * double term's V there (the lanes leave the deepest of them to the double lens). */
static void test_fwd_cap_end(void) {
    pen_lighting lt;
    memset(&lt, 0, sizeof lt);
    lt.light_count = 1;
    lt.lights[0].irradiance[0] = lt.lights[0].irradiance[1] = lt.lights[0].irradiance[2] = 1.0f;
    const float sph[4] = {0.1f, -0.2f, 0.3f, 0.3f}, kap[1] = {1.0f};
    double worst_cap = 0.0;
    int variants = 0, checked = 0;
    const pen__shade_fast_ops *was = pen__shade_fast_current();
    for (int v = 0; v < pen__shade_fast_variants(); ++v) {
        if (!pen__shade_fast_use(v)) continue;
        ++variants;
        for (int trial = 0; trial < 200; ++trial) {
            double w[3];
            rs_unit_vector(&seed, w);
            for (int a = 0; a < 3; ++a)
                lt.lights[0].direction[a] = (float)w[a];
            lt.lights[0].angular_radius_deg = trial % 3 == 0 ? 3.0f : trial % 3 == 1 ? 0.27f : 0.1f;
            pen__lights L;
            pen__lights_init(&L, &lt, rs_uniform(&seed, 1.0, 6.0), 1);
            float x[3 * B], nrm[3 * B], rho[3 * B], rgb[3 * B] = {0}, V[B];
            for (int k = 0; k < B; ++k) {
                /* the continued cap of sh.h at this depth, and v at its edge +- the disk */
                const double s = rs_uniform(&seed, 0.9, 0.93), t = 1.0 - 1.0 / (s * s);
                const double cc = fmax(0.1 + (t - PEN_SH_CAP_T0) * 5.0, -1.0); /* a = pi */
                const double b = (double)lt.lights[0].angular_radius_deg * (M_PI / 180.0);
                const double th = acos(cc) + (k % 2 ? b : -b) + rs_uniform(&seed, -1e-4, 1e-4);
                double u[3], e[3];
                rs_unit_vector(&seed, e);
                const double ew = e[0] * L.w[0][0] + e[1] * L.w[0][1] + e[2] * L.w[0][2];
                double el = 0.0;
                for (int a = 0; a < 3; ++a)
                    e[a] -= ew * L.w[0][a], el += e[a] * e[a];
                /* the normal just above the light's horizon, towards the centre's side: the
                 * pair's weight is then large (h = n . v / r near 0.3) */
                const double nl = sqrt(1.0 + 0.05 * 0.05);
                for (int a = 0; a < 3; ++a) {
                    u[a] = cos(th) * L.w[0][a] + sin(th) * e[a] / sqrt(el);
                    nrm[3 * k + a] = (float)((0.05 * L.w[0][a] + e[a] / sqrt(el)) / nl);
                    x[3 * k + a] = (float)((double)sph[a] - s * (double)sph[3] * u[a]);
                    rho[3 * k + a] = 0.5f;
                }
            }
            pen__lights_fwd_block(&L, NULL, 1, sph, kap, NULL, B, x, nrm, rho, NULL, rgb, V);
            for (int k = 0; k < B; ++k) {
                float want[3] = {0, 0, 0}, Vw[1];
                pen__lights_fwd(&L, NULL, 1, sph, kap, NULL, x + 3 * k, nrm + 3 * k, rho + 3 * k,
                                want, Vw);
                worst_cap = fmax(worst_cap, fabs((double)V[k] - (double)Vw[0]));
                checked += Vw[0] < 0.9999f;
                CHECK_MSG(fabs((double)V[k] - (double)Vw[0]) <= 1e-5,
                          "variant %d trial %d receiver %d: V %.9g vs %.9g", v, trial, k,
                          (double)V[k], (double)Vw[0]);
            }
        }
    }
    for (int v = 0; v < pen__shade_fast_variants(); ++v)
        if (pen__shade_fast_variant_ops(v) == was) pen__shade_fast_use(v);
    CHECK_MSG(variants > 0 && checked > 100 * variants, "%d variants, %d shadowed receivers",
              variants, checked);
    if (getenv("PEN_TEST_VERBOSE"))
        printf("  %d shadowed receivers; worst V %.3g\n", checked, worst_cap);
}

/* A receiver with a normal that is not finite, at a finite point in a sphere's shadow, beside
 * a lit one: the double term leaves its light unlit (no colour, no gradient); so must the lanes,
 * for a narrow disk (under PEN_LIGHTS_COS_LENS_DEG) and a wide one, and the other receiver keeps
 * the double term's values. */
static void test_nan_normal(void) {
    for (int wide = 0; wide < 2; ++wide) {
        pen_lighting lt;
        memset(&lt, 0, sizeof lt);
        lt.light_count = 1;
        lt.lights[0].direction[1] = 1.0f, lt.lights[0].angular_radius_deg = wide ? 3.0f : 0.1f;
        lt.lights[0].irradiance[0] = lt.lights[0].irradiance[1] = lt.lights[0].irradiance[2] = 2.0f;
        pen__lights L;
        pen__lights_init(&L, &lt, 3.0, 1);
        const float sph[4] = {0.0f, 0.0f, 0.0f, 0.3f}, kap[1] = {1.0f};
        const float x[6] = {0.05f, -2, 0, 0.3f, -2, 0}, nrm[6] = {NAN, 1, 0, 0, 1, 0};
        const float rho[6] = {0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f}, drgb[6] = {1, 1, 1, 1, 1, 1};
        float V[2], rgb[6] = {0}, want[6] = {0}, Vw[2];
        const int pix[2] = {0, 1};
        pen__lights_fwd_block(&L, NULL, 1, sph, kap, NULL, 2, x, nrm, rho, NULL, rgb, V);
        for (int k = 0; k < 2; ++k)
            pen__lights_fwd(&L, NULL, 1, sph, kap, NULL, x + 3 * k, nrm + 3 * k, rho + 3 * k,
                            want + 3 * k, Vw + k);
        for (int a = 0; a < 6; ++a)
            CHECK_MSG(fabs((double)rgb[a] - (double)want[a]) <= 1e-6, "wide %d rgb[%d]: %g vs %g",
                      wide, a, (double)rgb[a], (double)want[a]);
        double ds[4] = {0};
        float dx[6] = {0}, dn[6] = {0}, dr[6] = {0};
        int scratch[2 * PEN_LIGHTS_BLOCK];
        pen__lights_bwd_block(&L, NULL, 1, sph, kap, NULL, 2, x, nrm, rho, drgb, V, pix, scratch,
                              ds, dx, dn, dr, NULL, NULL);
        for (int a = 0; a < 3; ++a)
            CHECK_MSG(dx[a] == 0.0f && dr[a] == 0.0f, "wide %d d_x[%d] %g, d_rho %g", wide, a,
                      (double)dx[a], (double)dr[a]);
        for (int a = 0; a < 4; ++a)
            CHECK_MSG(isfinite(ds[a]), "wide %d d_sphere[%d] %g", wide, a, ds[a]);
    }
}

/* Receivers near the end of the float range: the block's ball (its float mean overflows to +-inf,
 * or to NaN where both meet) must still keep the spheres that shadow them, as the double term's
 * own test does: each receiver has a sphere just above it, under a light straight up. */
static void test_huge_points(void) {
    enum { NB = PEN_LIGHTS_BLOCK };
    pen__lights L;
    sun_overhead(&L);
    float x[3 * NB], nrm[3 * NB], rho[3 * NB], sph[4 * NB], kap[NB], rgb[3 * NB] = {0}, V[NB];
    for (int k = 0; k < NB; ++k) {
        const float at = (k % 2 ? -2e38f : 2e38f) * (1.0f - 0.01f * (float)k);
        for (int a = 0; a < 3; ++a)
            x[3 * k + a] = a == 0 ? at : 0.0f, nrm[3 * k + a] = a == 1 ? 1.0f : 0.0f;
        for (int a = 0; a < 3; ++a)
            rho[3 * k + a] = 0.5f;
        sph[4 * k] = at, sph[4 * k + 1] = 1.0f, sph[4 * k + 2] = 0.0f, sph[4 * k + 3] = 0.5f;
        kap[k] = 1.0f;
    }
    pen__lights_fwd_block(&L, NULL, NB, sph, kap, NULL, NB, x, nrm, rho, NULL, rgb, V);
    for (int k = 0; k < NB; ++k) {
        float want[3] = {0}, Vw;
        pen__lights_fwd(&L, NULL, NB, sph, kap, NULL, x + 3 * k, nrm + 3 * k, rho + 3 * k, want,
                        &Vw);
        CHECK_MSG(Vw < 0.5f, "receiver %d: the double term sees no shadow (V %g)", k, (double)Vw);
        CHECK_MSG(fabs((double)V[k] - (double)Vw) <= 1e-6, "receiver %d: V %g, double term %g", k,
                  (double)V[k], (double)Vw);
    }
}

/* The loss sum_k,ch drgb rgb of the model in double (pen__lights_fwd_d), which the forward block
 * renders to float rounding (test_fwd_block). */
static double model_loss(const block_case *c, const double *sph, const double *x) {
    double kap[S], sum = 0.0;
    for (int i = 0; i < S; ++i)
        kap[i] = (double)c->kap[i];
    for (int k = 0; k < c->cnt; ++k) {
        double n[3], rho[3], rgb[3] = {0, 0, 0};
        for (int a = 0; a < 3; ++a)
            n[a] = (double)c->nrm[3 * k + a], rho[a] = (double)c->rho[3 * k + a];
        pen__lights_fwd_d(&c->L, c->Gp, S, sph, kap, NULL, x + 3 * k, n, rho, rgb, NULL);
        for (int ch = 0; ch < 3; ++ch)
            sum += (double)c->drgb[3 * k + ch] * rgb[ch];
    }
    return sum;
}

/* The backward block against central differences in double (step 1e-6) of the model it renders,
 * in the spheres and the points, in the variant in use: penumbrae, full shadows and inside pairs
 * as in the cases above. The block's gradient is float: within 1e-3 of the largest. */
static void test_bwd_block_fd(void) {
    double worst_fd = 0.0;
    for (int trial = 0; trial < 60; ++trial) {
        block_case c;
        make_case(&c, trial);
        const int cnt = c.cnt;
        float V[PEN_SCENE_MAX_LIGHTS * B] = {0}, rgb[3 * B] = {0};
        int pix[B];
        for (int k = 0; k < B; ++k)
            pix[k] = k < cnt ? k : 0;
        pen__lights_fwd_block(&c.L, c.Gp, S, c.sph, c.kap, NULL, cnt, c.x, c.nrm, c.rho, NULL, rgb,
                              V);
        double ds[4 * S] = {0}, dl[PEN_LIGHT_GRAD_DOUBLES * PEN_SCENE_MAX_LIGHTS] = {0};
        float dx[3 * B] = {0}, dn[3 * B] = {0}, dr[3 * B] = {0};
        int scratch[(S + 1) * B];
        pen__lights_bwd_block(&c.L, c.Gp, S, c.sph, c.kap, NULL, cnt, c.x, c.nrm, c.rho, c.drgb, V,
                              pix, scratch, ds, dx, dn, dr, dl, NULL);
        double sph[4 * S], x[3 * B];
        for (int a = 0; a < 4 * S; ++a)
            sph[a] = (double)c.sph[a];
        for (int a = 0; a < 3 * cnt; ++a)
            x[a] = (double)c.x[a];
        double big = 1e-2;
        for (int a = 0; a < 4 * S; ++a)
            big = fmax(big, fabs(ds[a]));
        const double h = 1e-6;
        for (int a = 0; a < 4 * S + 3 * cnt; ++a) {
            double *p = a < 4 * S ? sph + a : x + (a - 4 * S), keep = *p;
            *p = keep + h;
            const double up = model_loss(&c, sph, x);
            *p = keep - h;
            const double down = model_loss(&c, sph, x);
            *p = keep;
            const double fd = (up - down) / (2.0 * h);
            const double an = a < 4 * S ? ds[a] : (double)dx[a - 4 * S];
            worst_fd = fmax(worst_fd, fabs(fd - an) / big);
            CHECK_MSG(fabs(fd - an) <= 1e-3 * big, "trial %d %s[%d]: lanes %.6g, fd %.6g", trial,
                      a < 4 * S ? "d_sphere" : "d_x", a < 4 * S ? a : a - 4 * S, an, fd);
        }
    }
    if (getenv("PEN_TEST_VERBOSE")) printf("  worst %.3g of the largest gradient\n", worst_fd);
}

RUN_TESTS(TEST(test_fwd_block), TEST(test_bwd_block), TEST(test_bwd_centre), TEST(test_fwd_cap_end),
          TEST(test_nan_normal), TEST(test_huge_points), TEST(test_bwd_block_fd))
