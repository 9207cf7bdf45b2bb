/* Disk lights (src/shade/lights.c, docs/design.md sec. 1.13): the disk's clamped cosine against
 * quadrature over the disk, the cap-disk overlap against Monte Carlo on the sphere (overlapping,
 * contained, disjoint, tiny suns), the per-pixel light term's backward against central finite
 * differences in double, and lighting.lights in the scene JSON (forms, errors, round trip). */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "optim/optim_internal.h"
#include "shade/lights.h"
#include "render_scenes.h"

#include <math.h>

static unsigned long long seed = 1818;

/* A direction at angle th from `axis` (unit) and azimuth ph, with (e1, e2) completing the frame. */
static void frame_of(const double z[3], double e1[3], double e2[3]) {
    const double h[3] = {fabs(z[0]) < 0.9 ? 1.0 : 0.0, fabs(z[0]) < 0.9 ? 0.0 : 1.0, 0.0};
    e1[0] = h[1] * z[2] - h[2] * z[1], e1[1] = h[2] * z[0] - h[0] * z[2];
    e1[2] = h[0] * z[1] - h[1] * z[0];
    const double l = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
    for (int k = 0; k < 3; ++k)
        e1[k] /= l;
    e2[0] = z[1] * e1[2] - z[2] * e1[1], e2[1] = z[2] * e1[0] - z[0] * e1[2];
    e2[2] = z[0] * e1[1] - z[1] * e1[0];
}

/* A direction in the cap of half-angle b around z, from u, v in [0, 1): uniform in solid angle,
 * 1 - cos(theta) = u (1 - cos b) in the half-angle form so that tiny caps keep their precision. */
static void cap_sample(const double z[3], double b, double u, double v, double out[3]) {
    double e1[3], e2[3];
    frame_of(z, e1, e2);
    const double omc = u * 2.0 * sin(0.5 * b) * sin(0.5 * b); /* 1 - cos theta */
    const double st = sqrt(omc * (2.0 - omc)), ph = 2.0 * M_PI * v;
    for (int k = 0; k < 3; ++k)
        out[k] = (1.0 - omc) * z[k] + st * (cos(ph) * e1[k] + sin(ph) * e2[k]);
}

static double angle_between(const double a[3], const double b[3]) {
    const double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                         a[0] * b[1] - a[1] * b[0]};
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]),
                 a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
}

/* D(c, b) against a midpoint rule over the disk in its own polar coordinates (the integrand
 * max(cos, 0) weighted by the solid angle element), at elevations across the horizon. */
static void test_disk_clamped_cosine(void) {
    const double radii[] = {0.3, 5.0, 20.0, 45.0};
    for (int ri = 0; ri < 4; ++ri) {
        const double b = radii[ri] * M_PI / 180.0;
        for (int k = 0; k <= 24; ++k) {
            const double th = M_PI / 2 - 1.3 * b + 2.6 * b * k / 24.0, c = cos(th);
            const double z[3] = {sin(th), 0.0, c}, n[3] = {0, 0, 1};
            double e1[3], e2[3];
            frame_of(z, e1, e2);
            const int NT = 400, NP = 400;
            double sum = 0.0;
            for (int i = 0; i < NT; ++i) {
                const double t = b * (i + 0.5) / NT;
                for (int j = 0; j < NP; ++j) {
                    const double p = 2 * M_PI * (j + 0.5) / NP;
                    double d[3];
                    for (int a = 0; a < 3; ++a)
                        d[a] = cos(t) * z[a] + sin(t) * (cos(p) * e1[a] + sin(p) * e2[a]);
                    const double cs = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
                    sum += (cs > 0 ? cs : 0) * sin(t) * (b / NT) * (2 * M_PI / NP);
                }
            }
            const double ref = sum / (M_PI * sin(b) * sin(b));
            double dc, db;
            const double D = pen__disk_clamped_cosine(c, b, &dc, &db);
            CHECK_MSG(fabs(D - ref) < 2e-4 * sin(b) + 1e-9, "b %g deg theta %g: D %.9g quad %.9g",
                      radii[ri], th, D, ref);
            /* derivatives against central differences */
            const double h = 1e-5 * b;
            const double fc = (pen__disk_clamped_cosine(c + h, b, NULL, NULL) -
                               pen__disk_clamped_cosine(c - h, b, NULL, NULL)) / (2 * h);
            const double fb = (pen__disk_clamped_cosine(c, b + h, NULL, NULL) -
                               pen__disk_clamped_cosine(c, b - h, NULL, NULL)) / (2 * h);
            CHECK_MSG(fabs(fc - dc) < 1e-5 * (1 + fabs(dc)), "dD/dc %g vs fd %g", dc, fc);
            CHECK_MSG(fabs(fb - db) < 1e-5 * (1 + fabs(db)), "b %g th %g: dD/db %g vs fd %g",
                      radii[ri], th, db, fb);
        }
    }
    /* the limits: wholly above is the cosine, wholly below 0 */
    CHECK(pen__disk_clamped_cosine(0.5, 0.1, NULL, NULL) == 0.5);
    CHECK(pen__disk_clamped_cosine(-0.2, 0.1, NULL, NULL) == 0.0);
}

/* The fraction of the disk (b around w) inside the cap (a around d), by sampling the disk. */
static double overlap_mc(double a, double b, double g, int N, unsigned long long *s) {
    const double w[3] = {0, 0, 1}, d[3] = {sin(g), 0, cos(g)};
    int in = 0;
    for (int i = 0; i < N; ++i) {
        double o[3];
        cap_sample(w, b, check_rand_(s), check_rand_(s), o);
        in += angle_between(o, d) < a;
    }
    return (double)in / N;
}

static void test_cap_overlap(void) {
    /* cases: a, b, g in degrees (overlapping, disk inside, cap inside, disjoint, band, tiny) */
    static const double cases[][3] = {
        {30, 10, 35},   {30, 10, 25},   {5, 10, 8},      {20, 20, 5},    {60, 45, 90},
        {100, 45, 120}, {170, 45, 160}, {150, 40, 175},  {10, 10, 25},   {30, 10, 15},
        {3, 0.27, 3.1}, {3, 0.27, 2.9}, {0.2, 0.27, 0.3}, {40, 0.01, 40.005}, {90, 0.27, 90.1},
        {1e-3, 0.27, 0.1}, {120, 30, 100}};
    const int N = 400000;
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; ++c) {
        const double a = cases[c][0] * M_PI / 180, b = cases[c][1] * M_PI / 180,
                     g = cases[c][2] * M_PI / 180;
        const double area = 4 * M_PI * sin(b / 2) * sin(b / 2);
        double d[3];
        const double f = pen__cap_overlap(a, b, g, d) / area;
        CHECK_MSG(fabs(pen__cap_overlap(a, b, g, NULL) / area - f) < 1e-12,
                  "case %zu: value and dual paths differ", c);
        const double ref = overlap_mc(a, b, g, N, &seed);
        const double sd = sqrt(ref * (1 - ref) / N) + 1.0 / N;
        CHECK_MSG(fabs(f - ref) < 5 * sd, "case %zu (%g, %g, %g): f %.6f mc %.6f", c, cases[c][0],
                  cases[c][1], cases[c][2], f, ref);
        CHECK_MSG(f >= -1e-12 && f <= 1 + 1e-12, "case %zu: f %g", c, f);
        /* partials against central differences (relative to the disk's area) */
        const double arg[3] = {a, b, g};
        for (int k = 0; k < 3; ++k) {
            double p[3] = {a, b, g}, m[3] = {a, b, g};
            const double h = 1e-6 * (b < 1e-2 ? b : 1e-2) + 0 * arg[k];
            p[k] += h, m[k] -= h;
            const double fd = (pen__cap_overlap(p[0], p[1], p[2], NULL) -
                               pen__cap_overlap(m[0], m[1], m[2], NULL)) /
                              (2 * h);
            CHECK_MSG(fabs(fd - d[k]) < 1e-5 * (area / b + fabs(d[k])),
                      "case %zu partial %d: %.9g vs fd %.9g", c, k, d[k], fd);
        }
    }
    /* continuity across the cases' borders (external and internal tangency, band) */
    const double b = 0.2, a = 0.7;
    const double e = 1e-9;
    CHECK(fabs(pen__cap_overlap(a, b, a + b - e, NULL)) < 1e-9);
    CHECK(fabs(pen__cap_overlap(a, b, a - b + e, NULL) - 4 * M_PI * sin(b / 2) * sin(b / 2)) <
          1e-9);
    CHECK(fabs(pen__cap_overlap(2.9, 0.5, 2 * M_PI - 3.4 - e, NULL) -
               pen__cap_overlap(2.9, 0.5, 2 * M_PI - 3.4 + e, NULL)) < 1e-7);
}

/* The cosine form of the lens (the wide disks' path) against the closed form, relative to the
 * disk's area, and its partials against central differences of its own value, over random
 * partial overlaps: caps from 0.1 deg to 143 deg, centres within 1.2 b of the cap's edge. The
 * renderer takes it from PEN_LIGHTS_COS_LENS_DEG (0.25 deg) up, where the two forms agree to 5e-13
 * of the disk's area; below, they part further (at 0.01 deg about 1e-11), hence the closed form
 * there.
 */
static void test_cap_overlap_cos(void) {
    const double bs[] = {PEN_LIGHTS_COS_LENS_DEG, 2.45, 5, 10, 30, 60};
    int used = 0;
    for (size_t ib = 0; ib < sizeof bs / sizeof bs[0]; ++ib) {
        const double b = bs[ib] * M_PI / 180, area = 4 * M_PI * sin(b / 2) * sin(b / 2);
        double worst = 0, worst_d = 0;
        for (int t = 0; t < 20000; ++t) {
            const double a = rs_uniform(&seed, 0.1, 143.0) * M_PI / 180;
            const double g = fabs(a + rs_uniform(&seed, -1.2, 1.2) * b);
            if (g > M_PI) continue;
            double d[3], dc[3];
            const double A = pen__cap_overlap(a, b, g, d);
            const double C =
                pen__cap_overlap_cos(cos(a), sin(a), cos(b), sin(b), cos(g), sin(g), dc);
            if (C < 0) { /* only where a + b >= pi or the caps do not cross */
                CHECK_MSG(a + b >= M_PI - 1e-9 || g >= a + b - 1e-9 || g <= fabs(a - b) + 1e-9,
                          "b %g: cosine form refused a crossing (%g, %g)", bs[ib], a, g);
                continue;
            }
            ++used;
            worst = fmax(worst, fabs(C - A) / area);
            for (int k = 0; k < 3; ++k)
                worst_d = fmax(worst_d, fabs(dc[k] - d[k]) / (area / b + fabs(d[k])));
            if (t % 50) continue;
            const double arg[3] = {a, b, g}, h = 1e-6 * b;
            for (int k = 0; k < 3; ++k) {
                double p[3] = {a, b, g}, m[3] = {a, b, g};
                p[k] += h, m[k] -= h;
                const double fd = (pen__cap_overlap_cos(cos(p[0]), sin(p[0]), cos(p[1]), sin(p[1]),
                                                        cos(p[2]), sin(p[2]), NULL) -
                                   pen__cap_overlap_cos(cos(m[0]), sin(m[0]), cos(m[1]), sin(m[1]),
                                                        cos(m[2]), sin(m[2]), NULL)) /
                                  (2 * h);
                CHECK_MSG(fabs(fd - dc[k]) < 1e-5 * (area / b + fabs(dc[k])),
                          "b %g (%g %g %g) partial %d: %.9g vs fd %.9g", bs[ib], arg[0], arg[1],
                          arg[2], k, dc[k], fd);
            }
        }
        CHECK_MSG(worst < 1e-12, "b %g deg: cosine form off by %.3g of the disk", bs[ib], worst);
        CHECK_MSG(worst_d < 1e-10, "b %g deg: partials off by %.3g", bs[ib], worst_d);
    }
    CHECK(used > 50000);
}

/* ---- Per-pixel backward against central differences in double --------------------------------- */

typedef struct px_case {
    pen__lights L;
    int S;
    double sph[4 * 6], kappa[6], x[3], n[3], rho[3], G[PEN_SCENE_MAX_LIGHTS];
    int use_G;
} px_case;

static double px_loss(const px_case *c, const double q[3]) {
    double rgb[3] = {0, 0, 0};
    pen__lights_fwd_d(&c->L, c->use_G ? c->G : NULL, c->S, c->sph, c->kappa, NULL, c->x, c->n, c->rho,
                      rgb, NULL);
    return q[0] * rgb[0] + q[1] * rgb[1] + q[2] * rgb[2];
}

static void set_light(pen__lights *L, int l, const double dir[3], double b_deg, double E) {
    pen_lighting lt;
    memset(&lt, 0, sizeof lt);
    lt.light_count = 1;
    for (int a = 0; a < 3; ++a) {
        lt.lights[0].direction[a] = (float)dir[a];
        lt.lights[0].irradiance[a] = (float)(E * (1 + 0.3 * a));
    }
    lt.lights[0].angular_radius_deg = (float)b_deg;
    pen__lights one;
    pen__lights_init(&one, &lt, L->eps, L->shadows);
    const double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int a = 0; a < 3; ++a) {
        L->w[l][a] = dir[a] / len;
        L->E[l][a] = one.E[0][a];
    }
    L->len[l] = 1.0;
    L->b[l] = b_deg * M_PI / 180, L->sin_b[l] = sin(L->b[l]), L->cos_b[l] = cos(L->b[l]);
    L->area[l] = 4 * M_PI * sin(L->b[l] / 2) * sin(L->b[l] / 2);
    L->widest[l] = l; /* any order of the lights will do for the culls */
    if (l + 1 > L->count) L->count = l + 1;
}

/* The radius's derived values after a change of b. */
static void sync_b(pen__lights *L) {
    for (int l = 0; l < L->count; ++l) {
        L->sin_b[l] = sin(L->b[l]), L->cos_b[l] = cos(L->b[l]);
        L->area[l] = 4 * M_PI * sin(L->b[l] / 2) * sin(L->b[l] / 2);
    }
}

/* Checks every derivative of one case; `what` names it. */
static void px_check(px_case *c, const char *what) {
    const double q[3] = {0.7, 1.1, 0.4};
    double d_sph[4 * 6] = {0}, d_x[3] = {0}, d_n[3] = {0}, d_rho[3] = {0};
    double d_l[PEN_LIGHT_GRAD_DOUBLES * PEN_SCENE_MAX_LIGHTS] = {0}, d_G[PEN_SCENE_MAX_LIGHTS] = {0};
    pen__lights_bwd_d(&c->L, c->use_G ? c->G : NULL, c->S, c->sph, c->kappa, NULL, c->x, c->n, c->rho, q, NULL,
                      d_sph, d_x, d_n, d_rho, d_l, d_G);
    const double base = px_loss(c, q);
    CHECK_MSG(isfinite(base), "%s: loss %g", what, base);
    double *params[64], grads[64];
    char names[64][24];
    int np = 0;
#define ADD(ptr, g, ...)                                                                           \
    (params[np] = (ptr), grads[np] = (g), snprintf(names[np], 24, __VA_ARGS__), ++np)
    for (int i = 0; i < c->S; ++i)
        for (int k = 0; k < 4; ++k)
            ADD(&c->sph[4 * i + k], d_sph[4 * i + k], "sphere %d.%d", i, k);
    for (int a = 0; a < 3; ++a) {
        ADD(&c->x[a], d_x[a], "x%d", a);
        ADD(&c->n[a], d_n[a], "n%d", a);
        ADD(&c->rho[a], d_rho[a], "rho%d", a);
    }
    for (int l = 0; l < c->L.count; ++l) {
        for (int a = 0; a < 3; ++a) {
            ADD(&c->L.w[l][a], d_l[PEN_LIGHT_GRAD_DOUBLES * l + a], "w%d.%d", l, a);
            ADD(&c->L.E[l][a], d_l[PEN_LIGHT_GRAD_DOUBLES * l + 4 + a], "E%d.%d", l, a);
        }
        ADD(&c->L.b[l], d_l[PEN_LIGHT_GRAD_DOUBLES * l + 3], "b%d", l);
        if (c->use_G) ADD(&c->G[l], d_G[l], "G%d", l);
    }
#undef ADD
    double gmax = 0;
    for (int k = 0; k < np; ++k)
        gmax = fmax(gmax, fabs(grads[k]));
    for (int k = 0; k < np; ++k) {
        const double h = 1e-7, v = *params[k];
        *params[k] = v + h;
        sync_b(&c->L);
        const double lp = px_loss(c, q);
        *params[k] = v - h;
        sync_b(&c->L);
        const double lm = px_loss(c, q);
        *params[k] = v;
        sync_b(&c->L);
        const double fd = (lp - lm) / (2 * h);
        CHECK_MSG(fabs(fd - grads[k]) <= 1e-5 * fmax(fabs(fd), 1e-3 * gmax) + 1e-10,
                  "%s: d %s analytic %.9g fd %.9g", what, names[k], grads[k], fd);
    }
}

/* A receiver on a horizontal plane under two blockers, lit by a light whose disk one sphere
 * half covers (penumbra), a second light near the horizon, and random cases. */
static void test_pixel_grad(void) {
    px_case c;
    memset(&c, 0, sizeof c);
    c.L.eps = 2.0, c.L.shadows = 1;
    const double up[3] = {0.3, 1.0, 0.2}, low[3] = {1.0, 0.05, -0.4};
    set_light(&c.L, 0, up, 5.0, 2.0);
    set_light(&c.L, 1, low, 8.0, 1.0);
    c.S = 2;
    /* sphere 0: its cap's edge through light 0's direction seen from x = 0 */
    const double D = 2.0, r = 0.3;
    double w0[3];
    for (int a = 0; a < 3; ++a)
        w0[a] = c.L.w[0][a];
    const double al = asin(r / D);
    /* rotate w0 by alpha about an axis perpendicular to it in the x-z plane */
    double e1[3], e2[3];
    frame_of(w0, e1, e2);
    for (int a = 0; a < 3; ++a)
        c.sph[a] = D * (cos(al) * w0[a] + sin(al) * e1[a]);
    c.sph[3] = r;
    c.sph[4] = 0.5, c.sph[5] = 0.4, c.sph[6] = 0.1, c.sph[7] = 0.25;
    c.kappa[0] = 1.0, c.kappa[1] = 0.7;
    c.n[1] = 1.0;
    c.rho[0] = 0.5, c.rho[1] = 0.6, c.rho[2] = 0.7;
    px_check(&c, "penumbra");
    /* horizon: the receiver's normal tilted so that light 1 straddles its tangent plane */
    {
        const double *w1 = c.L.w[1];
        double l = 0;
        for (int a = 0; a < 3; ++a)
            c.n[a] = (a == 1) - w1[1] * w1[a];
        for (int a = 0; a < 3; ++a)
            l += c.n[a] * c.n[a];
        for (int a = 0; a < 3; ++a)
            c.n[a] = c.n[a] / sqrt(l) + 0.05 * w1[a];
        const double cs = c.n[0] * c.L.w[1][0] + c.n[1] * c.L.w[1][1] + c.n[2] * c.L.w[1][2];
        CHECK_MSG(fabs(cs) < c.L.sin_b[1], "horizon case not on the horizon (%g)", cs);
    }
    c.use_G = 1, c.G[0] = 0.8, c.G[1] = 0.6;
    px_check(&c, "horizon");
    /* random receivers, spheres, lights (some partly behind the tangent plane: w in its ramp) */
    for (int trial = 0; trial < 40; ++trial) {
        px_case r2;
        memset(&r2, 0, sizeof r2);
        r2.L.eps = rs_uniform(&seed, 0.5, 4.0), r2.L.shadows = 1;
        double d[3];
        rs_unit_vector(&seed, r2.n);
        if (r2.n[1] < 0) r2.n[1] = -r2.n[1];
        for (int l = 0; l < 2; ++l) {
            rs_unit_vector(&seed, d);
            if (d[0] * r2.n[0] + d[1] * r2.n[1] + d[2] * r2.n[2] < 0)
                for (int a = 0; a < 3; ++a)
                    d[a] = -d[a];
            /* every third trial's first light under PEN_LIGHTS_COS_LENS_DEG: the angle form */
            const double b = trial % 3 == 0 && l == 0 ? rs_uniform(&seed, 0.05, 0.2)
                                                      : rs_uniform(&seed, 0.3, 30.0);
            set_light(&r2.L, l, d, b, rs_uniform(&seed, 0.5, 3.0));
        }
        r2.S = 1 + trial % 5;
        for (int i = 0; i < r2.S; ++i) {
            /* centres near the lights' directions so that their caps overlap the disks */
            const int l = i % 2;
            const double dist = rs_uniform(&seed, 0.5, 3.0);
            for (int a = 0; a < 3; ++a)
                r2.sph[4 * i + a] = dist * r2.L.w[l][a] + rs_uniform(&seed, -0.3, 0.3);
            r2.sph[4 * i + 3] = rs_uniform(&seed, 0.1, 0.5);
            r2.kappa[i] = rs_uniform(&seed, 0.2, 1.5);
        }
        for (int a = 0; a < 3; ++a)
            r2.rho[a] = rs_uniform(&seed, 0.1, 0.9);
        char what[32];
        snprintf(what, sizeof what, "random %d", trial);
        px_check(&r2, what);
    }
    /* The inside rule (shade/shade.h): receivers in the fade band of spheres (0.9 r < |c - x|
     * < r), deeper inside and just outside, the centres towards the lights. */
    for (int trial = 0; trial < 20; ++trial) {
        px_case r2;
        memset(&r2, 0, sizeof r2);
        r2.L.eps = rs_uniform(&seed, 0.5, 4.0), r2.L.shadows = 1;
        double d[3];
        r2.n[1] = 1.0;
        for (int l = 0; l < 2; ++l) {
            rs_unit_vector(&seed, d);
            if (d[1] < 0) d[1] = -d[1];
            /* every third trial's first light under PEN_LIGHTS_COS_LENS_DEG: the angle form */
            const double b = trial % 3 == 0 && l == 0 ? rs_uniform(&seed, 0.05, 0.2)
                                                      : rs_uniform(&seed, 0.3, 30.0);
            set_light(&r2.L, l, d, b, rs_uniform(&seed, 0.5, 3.0));
        }
        r2.S = 3;
        const double qs[3] = {rs_uniform(&seed, 0.905, 0.995), rs_uniform(&seed, 0.2, 0.88),
                              rs_uniform(&seed, 0.905, 1.2)};
        for (int i = 0; i < r2.S; ++i) {
            const double rad = rs_uniform(&seed, 0.1, 0.5);
            rs_unit_vector(&seed, d);
            for (int a = 0; a < 3; ++a)
                d[a] = r2.L.w[i % 2][a] + 0.3 * d[a];
            const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int a = 0; a < 3; ++a)
                r2.sph[4 * i + a] = qs[i] * rad * d[a] / len;
            r2.sph[4 * i + 3] = rad;
            r2.kappa[i] = rs_uniform(&seed, 0.2, 1.5);
        }
        for (int a = 0; a < 3; ++a)
            r2.rho[a] = rs_uniform(&seed, 0.1, 0.9);
        char what[32];
        snprintf(what, sizeof what, "inside %d", trial);
        px_check(&r2, what);
        /* The sphere containing the receiver deeper than 0.9 r hides nothing: the same light as
         * without it, bit for bit. */
        double a3[3] = {0, 0, 0}, b3[3] = {0, 0, 0};
        pen__lights_fwd_d(&r2.L, NULL, 1, r2.sph + 4, r2.kappa + 1, NULL, r2.x, r2.n, r2.rho, a3,
                          NULL);
        pen__lights_fwd_d(&r2.L, NULL, 0, NULL, NULL, NULL, r2.x, r2.n, r2.rho, b3, NULL);
        CHECK(memcmp(a3, b3, sizeof a3) == 0);
    }
}

/* Exactness for one blocker: with a single sphere, V = 1 - (1 - exp(-eps)) f, and f is the
 * fraction of the disk whose rays hit the sphere (ray-cast here, many samples). */
static void test_one_blocker_raycast(void) {
    pen__lights L;
    memset(&L, 0, sizeof L);
    L.eps = 40.0, L.shadows = 1; /* opaque */
    const double dir[3] = {0.2, 1.0, 0.1};
    set_light(&L, 0, dir, 3.0, 1.0);
    const double x[3] = {0, 0, 0}, n[3] = {0, 1, 0}, rho[3] = {1, 1, 1};
    for (int k = 0; k < 9; ++k) {
        /* the sphere slides across the light's disk */
        double e1[3], e2[3];
        frame_of(L.w[0], e1, e2);
        const double D = 3.0, r = 0.1, off = (k - 4) * 0.04;
        double sph[4];
        for (int a = 0; a < 3; ++a)
            sph[a] = D * L.w[0][a] + off * e1[a];
        sph[3] = r;
        double rgb[3] = {0, 0, 0}, rgb0[3] = {0, 0, 0};
        pen__lights_fwd_d(&L, NULL, 1, sph, NULL, NULL, x, n, rho, rgb, NULL);
        pen__lights_fwd_d(&L, NULL, 0, sph, NULL, NULL, x, n, rho, rgb0, NULL);
        /* ray cast: the fraction of cosine-weighted disk directions that hit the sphere */
        const int N = 200000;
        double hit = 0, all = 0;
        for (int i = 0; i < N; ++i) {
            double o[3];
            cap_sample(L.w[0], L.b[0], check_rand_(&seed), check_rand_(&seed), o);
            const double cs = o[1];
            const double oc[3] = {sph[0] - x[0], sph[1] - x[1], sph[2] - x[2]};
            const double t = oc[0] * o[0] + oc[1] * o[1] + oc[2] * o[2];
            const double d2 = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - t * t;
            all += cs;
            if (t > 0 && d2 < r * r) hit += cs;
        }
        const double ref = 1 - hit / all, model = rgb[0] / rgb0[0];
        CHECK_MSG(fabs(model - ref) < 5e-3, "offset %g: model V %.5f ray cast %.5f", off, model,
                  ref);
        if (getenv("PEN_TEST_VERBOSE"))
            printf("  offset %+.2f: model V %.5f, ray cast %.5f\n", off, model, ref);
    }
}

/* The tile cull is conservative: over random boxes, spheres and lights, the light term at random
 * receivers in the box is the same (bitwise) over the culled list as over every sphere. */
static void test_cull(void) {
    int kept = 0, total = 0;
    for (int trial = 0; trial < 200; ++trial) {
        pen__lights L;
        memset(&L, 0, sizeof L);
        L.eps = 3.0, L.shadows = 1;
        for (int l = 0; l < 3; ++l) {
            double d[3];
            rs_unit_vector(&seed, d);
            d[1] = fabs(d[1]) + 0.1;
            set_light(&L, l, d, rs_uniform(&seed, 0.05, 20.0), 1.0);
        }
        double lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
            lo[a] = rs_uniform(&seed, -1, 1);
            hi[a] = lo[a] + rs_uniform(&seed, 0.0, 0.3);
        }
        float sph[4 * 40];
        double sphd[4 * 40];
        for (int i = 0; i < 40; ++i) {
            for (int a = 0; a < 3; ++a)
                sph[4 * i + a] = (float)rs_uniform(&seed, -2, 2);
            sph[4 * i + 3] = (float)rs_uniform(&seed, 0.02, 0.4);
            for (int k = 0; k < 4; ++k)
                sphd[4 * i + k] = (double)sph[4 * i + k];
        }
        int idx[40];
        const int n = pen__lights_cull(&L, 40, sph, lo, hi, idx);
        kept += n, total += 40;
        for (int p = 0; p < 20; ++p) {
            double x[3], nrm[3], rho[3] = {1, 1, 1}, all[3] = {0, 0, 0}, some[3] = {0, 0, 0};
            for (int a = 0; a < 3; ++a)
                x[a] = rs_uniform(&seed, lo[a], hi[a]);
            rs_unit_vector(&seed, nrm);
            nrm[1] = fabs(nrm[1]);
            pen__lights_fwd_d(&L, NULL, 40, sphd, NULL, NULL, x, nrm, rho, all, NULL);
            pen__lights_fwd_d(&L, NULL, n, sphd, NULL, idx, x, nrm, rho, some, NULL);
            CHECK_MSG(all[0] == some[0] && all[1] == some[1] && all[2] == some[2],
                      "trial %d: culled %.17g, all %.17g", trial, some[0], all[0]);
        }
    }
    CHECK_MSG(kept < total / 2, "the cull kept %d of %d spheres", kept, total);
    if (getenv("PEN_TEST_VERBOSE")) printf("  the cull kept %d of %d spheres\n", kept, total);
}

/* ---- In the frame ---------------------------------------------------------------------------- */

/* The ball scene with a sun (elevation 50 deg) and a light across the horizon. */
static pen_scene lit_scene(int size) {
    pen_scene sc = rs_ball_scene(size, 0, &seed);
    const double el[2] = {50.0, -5.0}, az[2] = {-150.0, 150.0}, rad[2] = {3.0, 8.0};
    for (int l = 0; l < 2; ++l) {
        pen_light *L = &sc.lighting.lights[l];
        const double e = el[l] * M_PI / 180, a = az[l] * M_PI / 180;
        L->direction[0] = (float)(cos(e) * cos(a)), L->direction[1] = (float)sin(e);
        L->direction[2] = (float)(cos(e) * sin(a));
        L->angular_radius_deg = (float)rad[l];
        L->irradiance[0] = 2.0f, L->irradiance[1] = 1.8f, L->irradiance[2] = 1.4f;
    }
    sc.lighting.light_count = 2;
    sc.lighting.lights_mode = PEN_LIGHTS_GIVEN;
    return sc;
}

/* Both kernels give the same light term; a ground pixel far from the ball gets exactly
 * rho / pi E sin(elevation) from the sun; a scene whose lights are off renders as before. */
static void test_frame(void) {
    pen_scene sc = lit_scene(48);
    pen_render_options opt = pen_render_options_default();
    pen_image fast, scalar, none;
    CHECK(rs_render(&sc, &opt, 2, &fast) == PEN_OK);
    opt.kernel = PEN_RENDER_KERNEL_SCALAR;
    CHECK(rs_render(&sc, &opt, 2, &scalar) == PEN_OK);
    double worst = 0, peak = 0;
    for (int i = 0; i < 3 * 48 * 48; ++i) {
        worst = fmax(worst, fabs((double)fast.data[i] - (double)scalar.data[i]));
        peak = fmax(peak, fabs((double)fast.data[i]));
    }
    CHECK_MSG(worst <= 1e-4 * peak, "fast vs scalar with lights: %g of %g", worst, peak);
    /* the difference the lights make on the ground, far from the ball, without shadows */
    opt.kernel = PEN_RENDER_KERNEL_FAST, opt.shadows = 0;
    pen_image lit, dark;
    CHECK(rs_render(&sc, &opt, 1, &lit) == PEN_OK);
    const int count = sc.lighting.light_count;
    sc.lighting.light_count = 0;
    CHECK(rs_render(&sc, &opt, 1, &dark) == PEN_OK);
    opt.shadows = 1;
    CHECK(rs_render(&sc, &opt, 1, &none) == PEN_OK);
    sc.lighting.light_count = count;
    /* bottom-left pixel: ground, lit by the sun (50 deg) and by the horizon light's upper part */
    const size_t i = 3 * (size_t)(47 * 48 + 0);
    const double Dsun = sin(50 * M_PI / 180);
    const double Dlow = pen__disk_clamped_cosine(sin(-5 * M_PI / 180), 8 * M_PI / 180, NULL, NULL);
    const double want = 0.7 / M_PI * 2.0 * (Dsun + Dlow);
    CHECK_MSG(fabs((double)(lit.data[i] - dark.data[i]) - want) < 1e-5 * want,
              "ground pixel: lights add %.7g, expected %.7g", (double)(lit.data[i] - dark.data[i]),
              want);
    pen_image_free(&fast), pen_image_free(&scalar), pen_image_free(&lit), pen_image_free(&dark);
    pen_image_free(&none);
    pen_scene_free(&sc);
}

/* Images and gradients (the lights' included) are bitwise the same for 1 and 3 threads. */
static void test_threads(void) {
    pen_scene sc = lit_scene(80); /* above PEN_RENDER_PARALLEL_MIN_PIXELS */
    pen_render_grad_model(&sc, PEN_GRAD_ALL); /* every group has its gradient */
    pen_image img[2];
    pen_render_grad g[2];
    for (int k = 0; k < 2; ++k) {
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, k ? 3 : 1);
        pen_render_state *st = NULL;
        pen_render_state_create(ctx, &st);
        memset(&img[k], 0, sizeof img[k]);
        CHECK(pen_render_fwd(ctx, &sc, NULL, st, &img[k]) == PEN_OK);
        pen_image d = {0, 0, 0, NULL};
        pen_image_create(ctx, 80, 80, 3, &d);
        for (int i = 0; i < 3 * 80 * 80; ++i)
            d.data[i] = (float)(0.5 + 0.5 * sin(0.37 * i));
        CHECK(pen_render_grad_create(ctx, &sc, &g[k]) == PEN_OK);
        CHECK(pen_render_bwd(ctx, &sc, NULL, st, &d, PEN_GRAD_ALL, &g[k]) == PEN_OK);
        pen_image_free(&d);
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    CHECK(memcmp(img[0].data, img[1].data, sizeof(float) * 3 * 80 * 80) == 0);
    CHECK(memcmp(g[0].lights, g[1].lights, sizeof g[0].lights) == 0);
    CHECK(memcmp(g[0].objects[0].spheres, g[1].objects[0].spheres, 8 * sizeof(float)) == 0);
    CHECK(memcmp(&g[0].objects[0].pose, &g[1].objects[0].pose, sizeof(pen_pose)) == 0);
    CHECK(g[0].lights[0].irradiance[0] != 0.0f && g[0].lights[1].angular_radius_deg != 0.0f);
    for (int k = 0; k < 2; ++k) {
        pen_image_free(&img[k]);
        pen_render_grad_free(&g[k]);
    }
    pen_scene_free(&sc);
}

/* The least-squares lighting solver (src/optim/loss.c) on an image with lights: the render is
 * affine in the SH coefficients (the lights are in its SH = 0 base), so it recovers them. */
static void test_optim_solver_with_lights(void) {
    pen_scene sc = lit_scene(40);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image target = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &target) == PEN_OK);
    float want[PEN_SH_MAX_COEFFS][3], got[PEN_SH_MAX_COEFFS][3];
    memcpy(want, sc.lighting.sh, sizeof want);
    memset(sc.lighting.sh, 0, sizeof sc.lighting.sh);
    double mu[3] = {-1, -1, -1};
    CHECK(pen__optim_solve_lighting(ctx, &sc, &opt, NULL, &target, NULL, 1e-12, mu, got) ==
          PEN_OK);
    /* the image it predicts matches the target (coefficients the image does not see may differ) */
    memcpy(sc.lighting.sh, got, sizeof got);
    pen_image back = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &back) == PEN_OK);
    double err = 0, ref = 0;
    for (int k = 0; k < 3 * 40 * 40; ++k) {
        const double e = (double)back.data[k] - (double)target.data[k];
        err += e * e;
        ref += (double)target.data[k] * (double)target.data[k];
    }
    CHECK_MSG(sqrt(err / ref) < 1e-4, "solved lighting misses the target by %g", sqrt(err / ref));
    CHECK_MSG(fabs(got[0][0] - want[0][0]) < 1e-3 * fabs(want[0][0]), "DC %g vs %g",
              (double)got[0][0], (double)want[0][0]);
    pen_image_free(&target), pen_image_free(&back);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* ---- JSON ------------------------------------------------------------------------------------ */

#define J_CAM                                                                                      \
    "\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "           \
    "\"target\": [0, 0, 0]}, \"sh_bands\": 1, \"objects\": [{\"mesh\": \"tri.obj\"}]"

/* A scene whose lighting ends with `extra` loads with the given mode and max, and so does its
 * saved copy. */
static void json_mode(pen_context *ctx, const char *extra, pen_lights_mode mode, int max) {
    char t[1024];
    snprintf(t, sizeof t, "{" J_CAM ", \"lighting\": {\"sh\": [[1, 1, 1]]%s}}", extra);
    pen_scene sc;
    for (int pass = 0; pass < 2; ++pass) {
        const pen_status s = pass ? pen_scene_load(ctx, fixture_path("mode.json"), &sc)
                                  : pen_scene_parse(ctx, t, fixture_path("a.json"), &sc);
        CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
        if (s) return;
        CHECK_MSG(sc.lighting.lights_mode == mode && sc.lighting.lights_max == max &&
                      sc.lighting.light_count == 0,
                  "%s (pass %d): mode %d max %d", extra, pass, (int)sc.lighting.lights_mode,
                  sc.lighting.lights_max);
        if (!pass) CHECK(pen_scene_save(ctx, fixture_path("mode.json"), &sc) == PEN_OK);
        pen_scene_free(&sc);
    }
}

static void test_json(void) {
    fixture_text("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    pen_context *ctx = pen_context_create();
    pen_scene sc;
    /* absent: AUTO with the default max; "none"; {"max": 2}; each saved and loaded back */
    json_mode(ctx, "", PEN_LIGHTS_AUTO, PEN_LIGHTS_DEFAULT_MAX);
    json_mode(ctx, ", \"lights\": \"none\"", PEN_LIGHTS_NONE, 0);
    json_mode(ctx, ", \"lights\": {\"max\": 2}", PEN_LIGHTS_AUTO, 2);
    /* given: normalised directions, round trip */
    const char *t = "{" J_CAM ", \"lighting\": {\"sh\": [[1, 1, 1]], \"lights\": ["
        "{\"direction\": [0, 2, 0], \"angular_radius_deg\": 0.27, \"irradiance\": [3, 2, 1]},"
        "{\"direction\": [1, 1, 0], \"angular_radius_deg\": 10, \"irradiance\": [0, 0.5, 1]}]}}";
    CHECK_MSG(pen_scene_parse(ctx, t, fixture_path("a.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(sc.lighting.lights_mode == PEN_LIGHTS_GIVEN && sc.lighting.light_count == 2);
    CHECK(sc.lighting.lights[0].direction[1] == 1.0f && sc.lighting.lights[0].irradiance[0] == 3);
    CHECK(fabsf(sc.lighting.lights[1].direction[0] - 0.70710678f) < 1e-7f);
    CHECK(sc.lighting.lights[0].angular_radius_deg == 0.27f);
    CHECK(pen_scene_save(ctx, fixture_path("given.json"), &sc) == PEN_OK);
    pen_scene back;
    CHECK(pen_scene_load(ctx, fixture_path("given.json"), &back) == PEN_OK);
    CHECK(back.lighting.light_count == 2 && back.lighting.lights_mode == PEN_LIGHTS_GIVEN &&
          memcmp(back.lighting.lights, sc.lighting.lights, 2 * sizeof(pen_light)) == 0);
    pen_scene_free(&back);
    pen_scene_free(&sc);
    /* errors name the key */
    static const char *const bad[][2] = {
        {"\"lights\": [{\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, "
         "1, 1]}, {\"direction\": [0, 1, 0], \"angular_radius_deg\": 90, \"irradiance\": [1, 1, "
         "1]}]",
         "lighting.lights[1].angular_radius_deg"},
        {"\"lights\": [{\"direction\": [0, 0, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, "
         "1, 1]}]",
         "lighting.lights[0].direction: must not be the zero vector"},
        {"\"lights\": [{\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, \"irradiance\": [-1, "
         "1, 1]}]",
         "lighting.lights[0].irradiance[0]"},
        {"\"lights\": [{\"direction\": [0, 1, 0], \"irradiance\": [1, 1, 1]}]",
         "lighting.lights[0].angular_radius_deg: missing"},
        {"\"lights\": [{\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, "
         "1, 1], \"size\": 2}]",
         "lighting.lights[0]"},
        {"\"lights\": \"all\"", "lighting.lights: unknown value \"all\""},
        {"\"lights\": {\"max\": 17}", "lighting.lights.max"},
        {"\"lights\": 3", "lighting.lights: expected an array of lights"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i) {
        char text[1024];
        snprintf(text, sizeof text, "{" J_CAM ", \"lighting\": {\"sh\": [[1, 1, 1]], %s}}",
                 bad[i][0]);
        const pen_status s = pen_scene_parse(ctx, text, fixture_path("bad.json"), &sc);
        CHECK_MSG(s == PEN_ERROR_PARSE, "case %zu parsed", i);
        CHECK_MSG(strstr(pen_context_error(ctx), bad[i][1]) != NULL, "case %zu: %s", i,
                  pen_context_error(ctx));
        if (s == PEN_OK) pen_scene_free(&sc);
    }
    /* 17 lights */
    {
        char text[8192];
        int o = snprintf(text, sizeof text, "{" J_CAM ", \"lighting\": {\"sh\": [[1, 1, 1]], "
                                            "\"lights\": [");
        for (int i = 0; i < 17; ++i)
            o += snprintf(text + o, sizeof text - (size_t)o,
                          "%s{\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, "
                          "\"irradiance\": [1, 1, 1]}",
                          i ? ", " : "");
        snprintf(text + o, sizeof text - (size_t)o, "]}}");
        CHECK(pen_scene_parse(ctx, text, fixture_path("bad.json"), &sc) == PEN_ERROR_PARSE);
        CHECK(strstr(pen_context_error(ctx), "17 lights, at most 16") != NULL);
    }
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_disk_clamped_cosine), TEST(test_cap_overlap), TEST(test_cap_overlap_cos),
          TEST(test_pixel_grad),
          TEST(test_one_blocker_raycast), TEST(test_cull), TEST(test_frame), TEST(test_threads),
          TEST(test_optim_solver_with_lights),
          TEST(test_json))
