/* Tests of the per-pixel shading kernel (src/shade/shade_ops.inc) and texture sampling:
 * closed-form irradiance without occluders, finite differences in double for every input of the
 * backward, float against double, the self-shadowing rule (continuity, spheres behind the tangent
 * plane), and finite results at singular inputs. */
#include "core/internal.h"
#include "render/render_internal.h"
#include "render_scenes.h"

#include <string.h>

static unsigned long long rng = 777;
static double urand(double lo, double hi) {
    return rs_uniform(&rng, lo, hi);
}

static pen__shade_params params(int bands, pen_sh_exp_method method, int shadows) {
    pen__shade_params p;
    pen_sh_exp_model m = pen_sh_exp_model_default(method, bands);
    pen__shade_params_init(&p, bands, &m, 4.0, shadows);
    return p;
}

/* Unoccluded receiver: rho / pi * sum_l A_l sum_m L_lm Y_lm(n) with A = (pi, 2pi/3, pi/4, 0)
 * (Ramamoorthi-Hanrahan); lighting with band-3 energy checks that A_3 = 0 is honoured. */
static void test_irradiance_closed_form(void) {
    const double A[4] = {M_PI, 2 * M_PI / 3, M_PI / 4, 0};
    for (int shadows = 0; shadows < 2; ++shadows) {
        pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, shadows);
        double worst = 0;
        for (int trial = 0; trial < 50; ++trial) {
            double L[16][3], n[3], x[3] = {urand(-1, 1), urand(-1, 1), urand(-1, 1)};
            double rho[3] = {urand(0.1, 1), urand(0.1, 1), urand(0.1, 1)}, rgb[3];
            for (int k = 0; k < 16; ++k)
                for (int ch = 0; ch < 3; ++ch)
                    L[k][ch] = urand(-0.5, 0.5) + (k == 0 ? 2 : 0);
            rs_unit_vector(&rng, n);
            pen__shade_fwd_d(&p, (const double(*)[3])L, 0, NULL, NULL, x, n, rho, rgb, NULL);
            double y[9];
            rs_y_band2(n, y);
            for (int ch = 0; ch < 3; ++ch) {
                double e = 0;
                for (int l = 0; l < 3; ++l)
                    for (int m = -l; m <= l; ++m)
                        e += A[l] * L[l * l + l + m][ch] * y[l * l + l + m];
                double want = rho[ch] / M_PI * e;
                worst = fmax(worst, fabs(rgb[ch] - want));
            }
        }
        /* Shadows on with no spheres: V = exp*(0) = 1 exactly up to the model's rounding. */
        CHECK_MSG(worst < 1e-9, "shadows %d: max |error| %.3g", shadows, worst);
    }
}

/* A receiver at the origin with normal n and spheres around it, some partly behind the tangent
 * plane (so the self-shadowing weight is between 0 and 1). */
typedef struct {
    double x[3], n[3], rho[3], L[16][3];
    int count;
    double s[4 * 8];
    double kappa[8]; /* overlap weights, random in [0.2, 1.5] */
    const double *k; /* kappa or NULL (all 1) */
} setup;

static setup make_setup(int count) {
    setup S;
    memset(&S, 0, sizeof S);
    rs_unit_vector(&rng, S.n);
    for (int a = 0; a < 3; ++a)
        S.x[a] = urand(-0.2, 0.2), S.rho[a] = urand(0.2, 0.9);
    for (int k = 0; k < 16; ++k)
        for (int ch = 0; ch < 3; ++ch)
            S.L[k][ch] = urand(-0.3, 0.3) + (k == 0 ? 1.5 : 0);
    S.count = count;
    for (int i = 0; i < count; ++i) {
        double d[3];
        rs_unit_vector(&rng, d);
        double r = urand(0.2, 0.6), dist = urand(0.8, 2.5);
        /* Height along n in [-0.8 r, 2 r]: partly behind the plane for some spheres. */
        double h = urand(-0.8, 2.0) * r;
        double dn = d[0] * S.n[0] + d[1] * S.n[1] + d[2] * S.n[2];
        for (int a = 0; a < 3; ++a) {
            double t = d[a] - dn * S.n[a]; /* tangential part */
            S.s[4 * i + a] = S.x[a] + dist * t + h * S.n[a];
        }
        S.s[4 * i + 3] = r;
        /* From a stream of their own, so the other tests draw the same values as before. */
        static unsigned long long krng = 4242;
        S.kappa[i] = 0.2 + 1.3 * check_rand_(&krng);
    }
    return S;
}

static double loss_of(const pen__shade_params *p, const setup *S, const double q[3]) {
    double rgb[3];
    pen__shade_fwd_d(p, (const double(*)[3])S->L, S->count, S->s, S->k, S->x, S->n, S->rho, rgb,
                     NULL);
    return q[0] * rgb[0] + q[1] * rgb[1] + q[2] * rgb[2];
}

/* Central differences in double, step 1e-6: every analytic derivative within `tol` relative
 * (floor 1e-6) of the FD: 1e-6 for the smooth calibrated model, 1e-5 for the exact one, whose
 * series is accurate to about 1e-12 only (so its FD carries noise of 1e-12 / h). With
 * `weighted`, the spheres carry overlap weights kappa != 1 (constants of the backward). */
static void fd_setup(const pen__shade_params *pp, setup *S_, double tol, const char *what) {
    const pen__shade_params p = *pp;
    setup S = *S_;
    {
        double q[3] = {urand(0.5, 1.5), urand(0.5, 1.5), urand(0.5, 1.5)};
        double d_sh[16][3] = {{0}}, d_s[32] = {0}, d_x[3] = {0}, d_n[3] = {0}, d_rho[3] = {0};
        pen__shade_bwd_d(&p, (const double(*)[3])S.L, S.count, S.s, S.k, S.x, S.n, S.rho, q, NULL,
                         d_sh, d_s, d_x, d_n, d_rho);
        const double h = 1e-6;
        double *params_[5] = {&S.L[0][0], S.s, S.x, S.n, S.rho};
        double *grads[5] = {&d_sh[0][0], d_s, d_x, d_n, d_rho};
        int sizes[5] = {48, 4 * S.count, 3, 3, 3};
        const char *names[5] = {"sh", "spheres", "x", "n", "rho"};
        for (int g = 0; g < 5; ++g)
            for (int i = 0; i < sizes[g]; ++i) {
                double keep = params_[g][i];
                params_[g][i] = keep + h;
                double lp = loss_of(&p, &S, q);
                params_[g][i] = keep - h;
                double lm = loss_of(&p, &S, q);
                params_[g][i] = keep;
                double fd = (lp - lm) / (2 * h);
                double s = fmax(fmax(fabs(fd), fabs(grads[g][i])), 1e-6);
                CHECK_MSG(fabs(fd - grads[g][i]) <= tol * s + 1e-9, "%s: d%s[%d] = %.10g, fd %.10g",
                          what, names[g], i, grads[g][i], fd);
            }
    }
}

static void check_fd(pen_sh_exp_method method, int shadows, double tol, int weighted) {
    pen__shade_params p = params(4, method, shadows);
    char what[64];
    snprintf(what, sizeof what, "%s shadows %d", pen_sh_exp_method_name(method), shadows);
    for (int trial = 0; trial < 4; ++trial) {
        setup S = make_setup(6);
        S.k = weighted ? S.kappa : NULL;
        fd_setup(&p, &S, tol, what);
    }
}

/* Sphere i of S placed so that the receiver is at q = |c - x| / r from its centre, on the side
 * the normal faces (so the tangent-plane weight is above 0 and, for some, inside its ramp). */
static void place_at(setup *S, int i, double q, double r) {
    double d[3];
    rs_unit_vector(&rng, d);
    double dn = d[0] * S->n[0] + d[1] * S->n[1] + d[2] * S->n[2];
    if (dn < 0)
        for (int a = 0; a < 3; ++a)
            d[a] -= 2 * dn * S->n[a], dn = -dn;
    for (int a = 0; a < 3; ++a)
        S->s[4 * i + a] = S->x[a] + q * r * d[a];
    S->s[4 * i + 3] = r;
}

/* The inside rule (shade/shade.h): finite differences in double with receivers in the fade
 * band (0.9 r < |c - x| < r), deeper inside (weight 0, gradient 0) and outside, with and without
 * overlap weights; then the weight's ends: a sphere containing the receiver deeper than 0.9 r
 * shades exactly as no sphere, with exactly zero gradient. */
static void test_inside_rule_fd(void) {
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    for (int trial = 0; trial < 6; ++trial) {
        setup S = make_setup(6);
        const double qs[6] = {urand(0.905, 0.995), urand(0.905, 0.995), urand(0.91, 0.99),
                              urand(0.2, 0.88),    urand(1.02, 1.5),    urand(0.905, 0.995)};
        for (int i = 0; i < 6; ++i)
            place_at(&S, i, qs[i], urand(0.2, 0.6));
        S.k = trial & 1 ? S.kappa : NULL;
        fd_setup(&p, &S, 1e-6, "inside rule");
    }
    for (int trial = 0; trial < 4; ++trial) {
        setup S = make_setup(2);
        place_at(&S, 0, urand(0.0, 0.899), urand(0.2, 0.6));
        double a[3], b[3], q[3] = {1, 1, 1};
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 1, S.s, NULL, S.x, S.n, S.rho, a, NULL);
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 0, NULL, NULL, S.x, S.n, S.rho, b, NULL);
        CHECK(memcmp(a, b, sizeof a) == 0);
        double d_sh[16][3] = {{0}}, d_s[4] = {0}, d_x[3] = {0}, d_n[3] = {0}, d_rho[3] = {0};
        double e_sh[16][3] = {{0}}, e_x[3] = {0}, e_n[3] = {0}, e_rho[3] = {0};
        pen__shade_bwd_d(&p, (const double(*)[3])S.L, 1, S.s, NULL, S.x, S.n, S.rho, q, NULL, d_sh,
                         d_s, d_x, d_n, d_rho);
        pen__shade_bwd_d(&p, (const double(*)[3])S.L, 0, NULL, NULL, S.x, S.n, S.rho, q, NULL, e_sh,
                         NULL, e_x, e_n, e_rho);
        CHECK(d_s[0] == 0 && d_s[1] == 0 && d_s[2] == 0 && d_s[3] == 0);
        CHECK(memcmp(d_x, e_x, sizeof d_x) == 0 && memcmp(d_n, e_n, sizeof d_n) == 0);
        CHECK(memcmp(d_sh, e_sh, sizeof d_sh) == 0);
    }
}

/* Continuity across the fade: a receiver moved from the sphere's centre out through its surface
 * changes the result by a bounded slope, and the weight's end points are exact. */
static void test_inside_rule_continuous(void) {
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    double L[16][3] = {{0}};
    L[0][0] = L[0][1] = L[0][2] = 1.0;
    L[2][0] = L[2][1] = L[2][2] = 0.8;
    double n[3] = {0, 0, 1}, rho[3] = {0.5, 0.5, 0.5}, s[4] = {0, 0, 0, 0.5}, b[3];
    double prev = 0, worst = 0;
    /* Steps of 1e-5 r: the fade's slope gives steps below 1e-4, a jump would be about 0.3. */
    for (int i = 0; i <= 40000; ++i) {
        const double q = 0.8 + 0.4 * i / 40000.0; /* through [0.9, 1] */
        double x[3] = {0, 0, -q * 0.5};           /* below the centre: the sphere is in front */
        pen__shade_fwd_d(&p, (const double(*)[3])L, 1, s, NULL, x, n, rho, b, NULL);
        if (i) worst = fmax(worst, fabs(b[0] - prev));
        prev = b[0];
    }
    CHECK_MSG(worst < 1e-4, "largest step %.3g", worst);
}

static void test_bwd_fd_calibrated(void) {
    check_fd(PEN_SH_EXP_CALIBRATED, 1, 1e-6, 0);
}
static void test_bwd_fd_exact(void) {
    check_fd(PEN_SH_EXP_EXACT, 1, 1e-5, 0);
}
static void test_bwd_fd_no_shadows(void) {
    check_fd(PEN_SH_EXP_CALIBRATED, 0, 1e-6, 0);
}
static void test_bwd_fd_overlap_weights(void) {
    check_fd(PEN_SH_EXP_CALIBRATED, 1, 1e-6, 1);
    check_fd(PEN_SH_EXP_PAPER, 1, 1e-6, 1);
}

/* F is linear in the weights: kappa = 1 is the unweighted sum bit for bit, two coincident copies
 * at 1/2 each shade like one sphere at 1, and kappa = 0 removes a sphere. */
static void test_overlap_weights_linear(void) {
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    for (int trial = 0; trial < 10; ++trial) {
        setup S = make_setup(3);
        double a[3], b[3], ones[3] = {1, 1, 1};
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 3, S.s, NULL, S.x, S.n, S.rho, a, NULL);
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 3, S.s, ones, S.x, S.n, S.rho, b, NULL);
        CHECK(memcmp(a, b, sizeof a) == 0);
        /* Sphere 1 doubled: (0, 1, 1, 2) with weights (1, 1/2, 1/2, 1) == (0, 1, 2) plain. */
        double s4[16], k4[4] = {1, 0.5, 0.5, 1};
        memcpy(s4, S.s, sizeof(double) * 8);
        memcpy(s4 + 8, S.s + 4, sizeof(double) * 4);
        memcpy(s4 + 12, S.s + 8, sizeof(double) * 4);
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 4, s4, k4, S.x, S.n, S.rho, b, NULL);
        for (int ch = 0; ch < 3; ++ch)
            CHECK_NEAR(b[ch], a[ch], 1e-12);
        /* kappa = 0 on sphere 2 == spheres 0 and 1 alone. */
        double k3[3] = {1, 1, 0};
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 3, S.s, k3, S.x, S.n, S.rho, b, NULL);
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 2, S.s, NULL, S.x, S.n, S.rho, a, NULL);
        for (int ch = 0; ch < 3; ++ch)
            CHECK_NEAR(b[ch], a[ch], 1e-12);
    }
}

/* The float kernel against the double one, forward and backward. */
static void test_float_matches_double(void) {
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    for (int trial = 0; trial < 10; ++trial) {
        setup S = make_setup(5);
        float L[16][3], s[20], x[3], n[3], rho[3], rgb[3], q[3] = {1, 0.5f, 0.25f}, kf[5];
        /* Odd trials with overlap weights. */
        const int weighted = trial & 1;
        for (int i = 0; i < 5; ++i)
            kf[i] = (float)S.kappa[i];
        const float *kp = weighted ? kf : NULL;
        S.k = weighted ? S.kappa : NULL;
        for (int k = 0; k < 16; ++k)
            for (int ch = 0; ch < 3; ++ch)
                L[k][ch] = (float)S.L[k][ch];
        for (int i = 0; i < 20; ++i)
            s[i] = (float)S.s[i];
        for (int a = 0; a < 3; ++a)
            x[a] = (float)S.x[a], n[a] = (float)S.n[a], rho[a] = (float)S.rho[a];
        pen__shade_fwd(&p, (const float(*)[3])L, 5, s, kp, x, n, rho, rgb, NULL);
        double rgbd[3], qd[3] = {1, 0.5, 0.25};
        pen__shade_fwd_d(&p, (const double(*)[3])S.L, 5, S.s, S.k, S.x, S.n, S.rho, rgbd, NULL);
        for (int ch = 0; ch < 3; ++ch)
            CHECK_REL(rgb[ch], rgbd[ch], 1e-4, 1e-3);
        float d_x[3] = {0}, d_n[3] = {0}, d_rho[3] = {0};
        double d_sh[16][3] = {{0}}, d_s[20] = {0};
        double d_xd[3] = {0}, d_nd[3] = {0}, d_rhod[3] = {0};
        double d_shd[16][3] = {{0}}, d_sd[20] = {0};
        pen__shade_bwd(&p, (const float(*)[3])L, 5, s, kp, x, n, rho, q, NULL, d_sh, d_s, d_x, d_n,
                       d_rho);
        pen__shade_bwd_d(&p, (const double(*)[3])S.L, 5, S.s, S.k, S.x, S.n, S.rho, qd, NULL, d_shd,
                         d_sd, d_xd, d_nd, d_rhod);
        /* With the forward's F and V kept, the backward gives the same bits. */
        float fv[32], rgb2[3], e_x[3] = {0}, e_n[3] = {0}, e_rho[3] = {0};
        double e_sh[16][3] = {{0}}, e_s[20] = {0};
        pen__shade_fwd(&p, (const float(*)[3])L, 5, s, kp, x, n, rho, rgb2, fv);
        pen__shade_bwd(&p, (const float(*)[3])L, 5, s, kp, x, n, rho, q, fv, e_sh, e_s, e_x, e_n,
                       e_rho);
        CHECK(memcmp(rgb, rgb2, sizeof rgb) == 0);
        CHECK(memcmp(d_x, e_x, sizeof d_x) == 0 && memcmp(d_n, e_n, sizeof d_n) == 0);
        CHECK(memcmp(d_rho, e_rho, sizeof d_rho) == 0 && memcmp(d_s, e_s, sizeof d_s) == 0);
        CHECK(memcmp(d_sh, e_sh, sizeof d_sh) == 0);
        for (int a = 0; a < 3; ++a) {
            CHECK_REL(d_x[a], d_xd[a], 1e-3, 1e-2);
            CHECK_REL(d_n[a], d_nd[a], 1e-3, 1e-2);
            CHECK_REL(d_rho[a], d_rhod[a], 1e-4, 1e-3);
        }
        for (int i = 0; i < 20; ++i)
            CHECK_REL(d_s[i], d_sd[i], 1e-3, 1e-2);
        for (int k = 0; k < 16; ++k)
            CHECK_REL(d_sh[k][0], d_shd[k][0], 1e-4, 1e-3);
    }
}

/* Spheres wholly behind the tangent plane leave the receiver exactly unshadowed; a big sphere
 * straight above darkens it; the result is continuous as a sphere crosses the plane. */
static void test_self_shadowing_rule(void) {
    pen__shade_params on = params(4, PEN_SH_EXP_CALIBRATED, 1);
    pen__shade_params off = params(4, PEN_SH_EXP_CALIBRATED, 0);
    double L[16][3] = {{0}};
    L[0][0] = L[0][1] = L[0][2] = 1.0;
    L[2][0] = L[2][1] = L[2][2] = 0.8; /* brighter from +z */
    double x[3] = {0, 0, 0}, n[3] = {0, 0, 1}, rho[3] = {0.5, 0.5, 0.5}, a[3], b[3];
    pen__shade_fwd_d(&off, (const double(*)[3])L, 0, NULL, NULL, x, n, rho, a, NULL);
    /* Below the plane, even touching the receiver and containing nearly half its hemisphere. */
    double below[8] = {0.3, 0.1, -0.5, 0.5, -1, 0, -2.0, 1.0};
    pen__shade_fwd_d(&on, (const double(*)[3])L, 2, below, NULL, x, n, rho, b, NULL);
    CHECK_NEAR(b[0], a[0], 1e-12);
    double above[4] = {0, 0, 1.5, 1.0};
    pen__shade_fwd_d(&on, (const double(*)[3])L, 1, above, NULL, x, n, rho, b, NULL);
    CHECK_MSG(b[0] < 0.7 * a[0], "shadowed %.4g vs open %.4g", b[0], a[0]);
    /* Sweep a sphere through the plane: consecutive steps of 1e-4 r change the result by a
     * bounded slope (no jump), and the ends match the rule. */
    double prev = 0, worst = 0;
    for (int i = 0; i <= 30000; ++i) {
        double h = -1.5 + 3.0 * i / 30000.0;
        double s[4] = {0.8, 0.0, h * 0.4, 0.4};
        pen__shade_fwd_d(&on, (const double(*)[3])L, 1, s, NULL, x, n, rho, b, NULL);
        if (i) worst = fmax(worst, fabs(b[0] - prev));
        prev = b[0];
    }
    CHECK_MSG(worst < 1e-4, "largest step %.3g", worst);
}

/* Receiver inside or at the centre of a sphere, tiny and huge spheres, zero normal: finite
 * values and gradients (float kernel, as rendered). */
static void test_singular_inputs_finite(void) {
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    float L[16][3];
    for (int k = 0; k < 16; ++k)
        L[k][0] = L[k][1] = L[k][2] = k == 0 ? 1.0f : 0.1f;
    float x[3] = {0, 0, 0}, n[3] = {0, 1, 0}, rho[3] = {1, 1, 1}, q[3] = {1, 1, 1};
    const float s[7][4] = {{0, 0, 0, 1},        {0, 0.5f, 0, 1}, {0, 1, 0, 1}, {0, 1e-7f, 0, 1e-7f},
                           {0, 1e4f, 0, 1e-6f}, {0, 1, 0, 1e6f}, {0, -1, 0, 1}};
    float nz[3] = {0, 0, 0};
    for (int i = 0; i < 7; ++i)
        for (int zn = 0; zn < 2; ++zn) {
            float rgb[3], d_x[3] = {0}, d_n[3] = {0}, d_rho[3] = {0};
            double d_sh[16][3] = {{0}}, d_s[4] = {0};
            const float *nn = zn ? nz : n;
            pen__shade_fwd(&p, (const float(*)[3])L, 1, s[i], NULL, x, nn, rho, rgb, NULL);
            pen__shade_bwd(&p, (const float(*)[3])L, 1, s[i], NULL, x, nn, rho, q, NULL, d_sh, d_s,
                           d_x, d_n, d_rho);
            int ok = 1;
            for (int a = 0; a < 3; ++a)
                ok &=
                    isfinite(rgb[a]) && isfinite(d_x[a]) && isfinite(d_n[a]) && isfinite(d_rho[a]);
            for (int a = 0; a < 4; ++a)
                ok &= isfinite(d_s[a]);
            for (int k = 0; k < 16; ++k)
                ok &= isfinite(d_sh[k][0]);
            CHECK_MSG(ok, "sphere %d, zero normal %d", i, zn);
        }
}

/* Texture: exact at texel centres, bilinear in between, repeat wrap, FD of d_uv and the texel
 * gradient as the lookup's weights. */
static void test_texture(void) {
    float data[4 * 3 * 3];
    for (int i = 0; i < 36; ++i)
        data[i] = (float)urand(0, 1);
    pen_image tex = {4, 3, 3, data};
    float rgb[3];
    /* Texel (2, 1): u = 2.5/4, v = 1 - 1.5/3. */
    float uv[2] = {2.5f / 4, 1 - 1.5f / 3};
    pen__texture_fwd(&tex, uv, rgb);
    for (int ch = 0; ch < 3; ++ch)
        CHECK_NEAR(rgb[ch], data[(1 * 4 + 2) * 3 + ch], 1e-6);
    /* Half way between texel (3, 0) and its wrapped neighbour (0, 0). */
    float uvw[2] = {1.0f, 1 - 0.5f / 3}, uvw2[2] = {0.0f, 1 - 0.5f / 3}, rgb2[3];
    pen__texture_fwd(&tex, uvw, rgb);
    pen__texture_fwd(&tex, uvw2, rgb2);
    for (int ch = 0; ch < 3; ++ch) {
        CHECK_NEAR(rgb[ch], 0.5f * (data[3 * 3 + ch] + data[ch]), 1e-6);
        CHECK_NEAR(rgb[ch], rgb2[ch], 1e-6);
    }
    for (int trial = 0; trial < 20; ++trial) {
        float p[2] = {(float)urand(-1, 2), (float)urand(-1, 2)}, d[3] = {1, -0.5f, 2};
        float d_uv[2] = {0, 0}, d_t[36] = {0};
        pen__texture_bwd(&tex, p, d, d_t, d_uv);
        for (int a = 0; a < 2; ++a) {
            const float h = 1e-3f;
            float pp[2] = {p[0], p[1]}, pm[2] = {p[0], p[1]}, r1[3], r2[3];
            pp[a] += h, pm[a] -= h;
            pen__texture_fwd(&tex, pp, r1);
            pen__texture_fwd(&tex, pm, r2);
            double fd = 0;
            for (int ch = 0; ch < 3; ++ch)
                fd += (double)(d[ch] * (r1[ch] - r2[ch]) / (2 * h));
            /* Skip the rare sample whose step crosses a texel centre (a kink). */
            double a0 = (double)p[0] * 4 - 0.5, b0 = (1 - (double)p[1]) * 3 - 0.5;
            double frac = a == 0 ? a0 - floor(a0) : b0 - floor(b0);
            double margin = (double)(a == 0 ? 4 * h : 3 * h);
            if (frac < margin || frac > 1 - margin) continue;
            CHECK_REL(d_uv[a], fd, 2e-3, 1e-2);
        }
        /* The lookup is linear in the texels: d_t . data == d . rgb. */
        pen__texture_fwd(&tex, p, rgb);
        double lhs = 0, rhs = (double)(d[0] * rgb[0] + d[1] * rgb[1] + d[2] * rgb[2]);
        for (int i = 0; i < 36; ++i)
            lhs += (double)(d_t[i] * data[i]);
        CHECK_REL(lhs, rhs, 1e-5, 1e-3);
    }
}

/* The footprint-filtered lookup: K = 1 / zero footprint is the point lookup bit for bit; FD of its
 * uv and J gradients (J held at a footprint of about a texel, the kinks skipped by a robust
 * comparison); the texel gradient as the lookup's weights. */
static void test_texture_footprint(void) {
    float data[5 * 4 * 3];
    for (int i = 0; i < 60; ++i)
        data[i] = (float)urand(0, 1);
    pen_image tex = {5, 4, 3, data};
    const float zero[4] = {0, 0, 0, 0};
    for (int trial = 0; trial < 10; ++trial) {
        float p[2] = {(float)urand(-1, 2), (float)urand(-1, 2)}, a[3], b[3];
        pen__texture_fwd(&tex, p, a);
        pen__texture_footprint_fwd(&tex, p, zero, b);
        for (int ch = 0; ch < 3; ++ch)
            CHECK_NEAR(a[ch], b[ch], 1e-6);
    }
    int checked = 0, bad = 0;
    for (int trial = 0; trial < 40; ++trial) {
        float p[2] = {(float)urand(-1, 2), (float)urand(-1, 2)}, d[3] = {1, -0.5f, 2}, rgb[3];
        float J[4] = {(float)urand(-0.3, 0.3), (float)urand(-0.3, 0.3), (float)urand(-0.3, 0.3),
                      (float)urand(-0.3, 0.3)};
        float d_uv[2] = {0, 0}, d_J[4] = {0, 0, 0, 0}, d_t[60] = {0};
        pen__texture_footprint_bwd(&tex, p, J, d, d_t, d_uv, d_J);
        for (int a = 0; a < 6; ++a) {
            const float h = 1e-4f;
            float pp[2] = {p[0], p[1]}, pm[2] = {p[0], p[1]}, Jp[4], Jm[4], r1[3], r2[3];
            memcpy(Jp, J, sizeof J), memcpy(Jm, J, sizeof J);
            if (a < 2)
                pp[a] += h, pm[a] -= h;
            else
                Jp[a - 2] += h, Jm[a - 2] -= h;
            pen__texture_footprint_fwd(&tex, pp, Jp, r1);
            pen__texture_footprint_fwd(&tex, pm, Jm, r2);
            double fd = 0;
            for (int ch = 0; ch < 3; ++ch)
                fd += (double)d[ch] * ((double)r1[ch] - (double)r2[ch]) / (2.0 * (double)h);
            const double an = a < 2 ? (double)d_uv[a] : (double)d_J[a - 2];
            ++checked;
            /* a sample whose step crosses a texel centre (a kink) differs; they are rare */
            if (fabs(fd - an) > 2e-2 * fmax(1.0, fabs(fd))) ++bad;
        }
        pen__texture_footprint_fwd(&tex, p, J, rgb);
        double lhs = 0, rhs = (double)(d[0] * rgb[0] + d[1] * rgb[1] + d[2] * rgb[2]);
        for (int i = 0; i < 60; ++i)
            lhs += (double)(d_t[i] * data[i]);
        CHECK_REL(lhs, rhs, 1e-5, 1e-3);
    }
    CHECK_MSG(bad * 20 <= checked, "%d of %d uv / J derivatives off", bad, checked);
}

/* One footprint lookup, two implementations: a 3-channel texture takes the vector loops (SSE2)
 * where the samples fall inside it, the same texels as a 4-channel texture the scalar loops; the
 * lookup, its uv and J gradients and the texel gradients (the backward's and the scatter's, all
 * rows and a band) must agree bit for bit. */
static void test_texture_footprint_vector_scalar(void) {
    enum { W = 37, H = 23 };
    static float t3[W * H * 3 + 1], t4[W * H * 4], g3[W * H * 3 + 1], g4[W * H * 4];
    static float s3[W * H * 3 + 1], s4[W * H * 4];
    for (int i = 0; i < W * H; ++i)
        for (int ch = 0; ch < 4; ++ch) {
            const float v = (float)urand(-0.5, 1.5);
            if (ch < 3) t3[3 * i + ch] = v;
            t4[4 * i + ch] = ch < 3 ? v : 7.0f;
        }
    pen_image tex3 = {W, H, 3, t3}, tex4 = {W, H, 4, t4};
    int differ = 0;
    for (int trial = 0; trial < 400; ++trial) {
        const float uv[2] = {(float)urand(-0.1, 1.1), (float)urand(-0.1, 1.1)};
        float J[4];
        for (int k = 0; k < 4; ++k)
            J[k] = (float)urand(-0.05, 0.05) * (trial % 5 == 0 ? 0.0f : 1.0f);
        const float d[3] = {(float)urand(-2, 2), (float)urand(-2, 2), (float)urand(-2, 2)};
        float a[3], b[3];
        pen__texture_footprint_fwd(&tex3, uv, J, a);
        pen__texture_footprint_fwd(&tex4, uv, J, b);
        differ += memcmp(a, b, sizeof a) != 0;
        memset(g3, 0, sizeof g3), memset(g4, 0, sizeof g4);
        memset(s3, 0, sizeof s3), memset(s4, 0, sizeof s4);
        float uv3[2] = {0.25f, -0.0f}, uv4[2] = {0.25f, -0.0f}, J3[4] = {0}, J4[4] = {0};
        pen__texture_footprint_bwd(&tex3, uv, J, d, g3, uv3, J3);
        pen__texture_footprint_bwd(&tex4, uv, J, d, g4, uv4, J4);
        differ += memcmp(uv3, uv4, sizeof uv3) != 0 || memcmp(J3, J4, sizeof J3) != 0;
        pen__texture_footprint_bwd(&tex3, uv, J, d, NULL, uv3, NULL);
        pen__texture_footprint_bwd(&tex4, uv, J, d, NULL, uv4, NULL);
        differ += memcmp(uv3, uv4, sizeof uv3) != 0;
        const long r0 = trial % 3 ? 0 : (long)(trial % H), r1 = trial % 3 ? H : r0 + 3;
        pen__texture_scatter_rows(&tex3, uv, J, d, s3, 0, H);
        pen__texture_scatter_rows(&tex4, uv, J, d, s4, 0, H);
        pen__texture_scatter_rows(&tex3, uv, J, d, s3, r0, r1);
        pen__texture_scatter_rows(&tex4, uv, J, d, s4, r0, r1);
        for (int i = 0; i < W * H; ++i)
            differ += memcmp(g3 + 3 * i, g4 + 4 * i, 3 * sizeof(float)) != 0 ||
                      memcmp(s3 + 3 * i, s4 + 4 * i, 3 * sizeof(float)) != 0;
    }
    CHECK_MSG(differ == 0, "%d lookups differ between the 3- and 4-channel textures", differ);
}

RUN_TESTS(TEST(test_irradiance_closed_form), TEST(test_bwd_fd_calibrated), TEST(test_bwd_fd_exact),
          TEST(test_bwd_fd_no_shadows), TEST(test_bwd_fd_overlap_weights),
          TEST(test_overlap_weights_linear), TEST(test_float_matches_double),
          TEST(test_self_shadowing_rule), TEST(test_inside_rule_fd),
          TEST(test_inside_rule_continuous), TEST(test_singular_inputs_finite), TEST(test_texture),
          TEST(test_texture_footprint), TEST(test_texture_footprint_vector_scalar))
