/* Tests of the fast shading kernel (src/shade/shade_fast.c) against the scalar double-precision
 * reference (pen__shade_fwd_d / pen__shade_bwd_d): random pixels for every supported band count,
 * both fast exponentials and no-shadows, sphere counts 0 .. 33 (not multiples of the lane count),
 * pixel counts not multiples of the lane count, receivers inside spheres, overlap weights kappa
 * (some 0); then whole frames
 * through pen_render_fwd / pen_render_bwd (fast vs scalar kernel option), and thread-count
 * independence of the fast path. The kernel's checks run once per variant (instruction set) this
 * processor runs, from the one the process chose (PEN_CPU may name a narrower one) down to the
 * baseline.
 *
 * Tolerances. Both kernels compute in float; the reference is double. The error budget is float
 * rounding through the chain: sums of up to 33 sphere terms, two or more squarings (each a sum of
 * a few hundred products, which doubles the relative error of its input), and the shading sum.
 * Receivers inside a sphere amplify it most: there cos(alpha) follows the tangent line of sqrt
 * (slope 5) in t = 1 - r^2/D^2, whose rounding near D = r is relative to 1, and dt/dD = 2r^2/D^3
 * multiplies again, so a few float ulps become about 1e-5 of a gradient group's scale. The scalar
 * float kernel on the same inputs is measured alongside, and the fast kernel must be within 4x
 * its error plus 1e-5 of the group's scale (max |reference| of the image or of the gradient
 * group): as accurate as the kernel it replaces, up to the order of float operations. */
#include "core/internal.h"
#include "render/render_internal.h"
#include "render_scenes.h"

#include <stdlib.h>
#include <string.h>

static unsigned long long rng = 4242;
static double urand(double lo, double hi) {
    return rs_uniform(&rng, lo, hi);
}

static pen__shade_params params(int bands, pen_sh_exp_method method, int shadows) {
    pen__shade_params p;
    pen_sh_exp_model m = pen_sh_exp_model_default(method, bands);
    pen__shade_params_init(&p, bands, &m, -1.0, shadows); /* the model's epsilon */
    return p;
}

/* Largest |a - ref| and largest |ref| over n values. */
typedef struct err_acc {
    double err, scale;
} err_acc;
static void err_add(err_acc *e, double a, double ref) {
    e->err = fmax(e->err, isfinite(a) ? fabs(a - ref) : HUGE_VAL);
    e->scale = fmax(e->scale, fabs(ref));
}

enum { G_RGB, G_SH, G_SPH, G_X, G_N, G_RHO, G_COUNT };
static const char *group_name[G_COUNT] = {"rgb", "d_sh", "d_spheres", "d_x", "d_n", "d_rho"};

/* One random configuration: `count` pixels around a cluster of `S` spheres (some receivers
 * inside spheres, some spheres behind tangent planes), checked group by group. */
static void check_random_pixels(int bands, pen_sh_exp_method method, int shadows, int S,
                                int count, int verbose) {
    /* The first third on the ground plane: a call that mixes ground and other pixels, with a
     * batch across the boundary (the renderer's calls are all ground or none). */
    const int nground = count / 3;
    const int nc = bands * bands;
    pen__shade_params p = params(bands, method, shadows);
    CHECK(pen__shade_fast_supported(&p));
    float (*Lf)[3] = calloc((size_t)nc, sizeof *Lf);
    double (*Ld)[3] = calloc((size_t)nc, sizeof *Ld);
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch) {
            Lf[k][ch] = (float)(urand(-0.3, 0.3) + (k == 0 ? 1.5 : 0.0));
            Ld[k][ch] = Lf[k][ch];
        }
    float *sf = malloc(sizeof(float) * (4 * (size_t)S + 1));
    double *sd = malloc(sizeof(double) * (4 * (size_t)S + 1));
    /* Overlap weights kappa: random in [0.3, 1.2], every fifth sphere 0. */
    float *kf = malloc(sizeof(float) * ((size_t)S + 1));
    double *kd = malloc(sizeof(double) * ((size_t)S + 1));
    for (int i = 0; i < S; ++i) {
        sf[4 * i] = (float)urand(-0.6, 0.6), sf[4 * i + 1] = (float)urand(0.1, 0.9);
        sf[4 * i + 2] = (float)urand(-0.6, 0.6), sf[4 * i + 3] = (float)urand(0.05, 0.3);
        for (int a = 0; a < 4; ++a)
            sd[4 * i + a] = sf[4 * i + a];
        kf[i] = i % 5 == 4 ? 0.0f : (float)urand(0.3, 1.2);
        kd[i] = kf[i];
    }
    const size_t n3 = 3 * (size_t)count;
    float *x = malloc(sizeof(float) * n3), *n = malloc(sizeof(float) * n3);
    float *rho = malloc(sizeof(float) * n3), *drgb = malloc(sizeof(float) * n3);
    for (int i = 0; i < count; ++i) {
        double nn[3];
        rs_unit_vector(&rng, nn);
        const int ground = i < nground;
        for (int a = 0; a < 3; ++a) {
            n[3 * i + a] = ground ? (a == 1 ? 1.0f : 0.0f) : (float)nn[a];
            x[3 * i + a] = (float)(a == 1 ? (ground ? 0.0 : urand(0.0, 1.0)) : urand(-1, 1));
            rho[3 * i + a] = (float)urand(0.1, 0.9);
            drgb[3 * i + a] = (float)urand(-1, 1);
        }
        if (i % 7 == 5 && S > 0) /* inside a sphere */
            for (int a = 0; a < 3; ++a)
                x[3 * i + a] = sf[4 * (i % S) + a] + 0.3f * sf[4 * (i % S) + 3];
        if (i % 7 == 6 && S > 0) { /* in the inside rule's fade band (0.9 r, r) of a sphere */
            const float q = (float)urand(0.9, 1.0);
            for (int a = 0; a < 3; ++a)
                x[3 * i + a] = sf[4 * (i % S) + a] + q * sf[4 * (i % S) + 3] * (float)nn[a];
        }
    }
    /* Fast kernel. */
    void *scratch = malloc(pen__shade_fast_scratch_bytes(&p, S, count));
    float *store = malloc(sizeof(float) * (pen__shade_fast_store_floats(&p, count) + 1));
    float *rgb = malloc(sizeof(float) * n3), *d_x = calloc(n3, sizeof(float));
    float *d_n = calloc(n3, sizeof(float)), *d_rho = calloc(n3, sizeof(float));
    double (*d_sh)[3] = calloc((size_t)nc, sizeof *d_sh);
    double *d_s = calloc(4 * (size_t)S + 1, sizeof(double));
    pen__shade_fast_fwd(&p, (const float(*)[3])Lf, S, sf, kf, count, nground, x, n, rho, rgb,
                        store, scratch, NULL);
    pen__shade_fast_bwd(&p, (const float(*)[3])Lf, S, sf, kf, count, nground, x, n, rho, drgb,
                        store, scratch, d_sh, d_s, d_x, d_n, d_rho, NULL);
    /* Without the store the backward recomputes F: the same bits. */
    float *e_x = calloc(n3, sizeof(float)), *e_n = calloc(n3, sizeof(float));
    float *e_rho = calloc(n3, sizeof(float));
    double (*e_sh)[3] = calloc((size_t)nc, sizeof *e_sh);
    double *e_s = calloc(4 * (size_t)S + 1, sizeof(double));
    pen__shade_fast_bwd(&p, (const float(*)[3])Lf, S, sf, kf, count, nground, x, n, rho, drgb,
                        NULL, scratch, e_sh, e_s, e_x, e_n, e_rho, NULL);
    CHECK(!memcmp(d_x, e_x, sizeof(float) * n3) && !memcmp(d_n, e_n, sizeof(float) * n3));
    CHECK(!memcmp(d_rho, e_rho, sizeof(float) * n3));
    CHECK(!memcmp(d_sh, e_sh, sizeof(double) * 3 * (size_t)nc));
    CHECK(!memcmp(d_s, e_s, sizeof(double) * 4 * (size_t)S));

    /* References: scalar double and scalar float, per pixel. */
    err_acc ef[G_COUNT], es[G_COUNT];
    memset(ef, 0, sizeof ef), memset(es, 0, sizeof es);
    double (*r_sh)[3] = calloc((size_t)nc, sizeof *r_sh), (*f_sh)[3] = calloc((size_t)nc, sizeof *f_sh);
    double *r_s = calloc(4 * (size_t)S + 1, sizeof(double));
    double *f_s = calloc(4 * (size_t)S + 1, sizeof(double));
    for (int i = 0; i < count; ++i) {
        double xd[3], nd[3], rd[3], gd[3], rgbd[3], dxd[3] = {0}, dnd[3] = {0}, drd[3] = {0};
        float rgbf[3], dxf[3] = {0}, dnf[3] = {0}, drf[3] = {0};
        for (int a = 0; a < 3; ++a)
            xd[a] = x[3 * i + a], nd[a] = n[3 * i + a], rd[a] = rho[3 * i + a],
            gd[a] = drgb[3 * i + a];
        pen__shade_fwd_d(&p, (const double(*)[3])Ld, S, sd, kd, xd, nd, rd, rgbd, NULL);
        pen__shade_bwd_d(&p, (const double(*)[3])Ld, S, sd, kd, xd, nd, rd, gd, NULL, r_sh, r_s, dxd,
                         dnd, drd);
        pen__shade_fwd(&p, (const float(*)[3])Lf, S, sf, kf, x + 3 * i, n + 3 * i, rho + 3 * i, rgbf,
                       NULL);
        pen__shade_bwd(&p, (const float(*)[3])Lf, S, sf, kf, x + 3 * i, n + 3 * i, rho + 3 * i,
                       drgb + 3 * i, NULL, f_sh, f_s, dxf, dnf, drf);
        for (int a = 0; a < 3; ++a) {
            err_add(&ef[G_RGB], rgb[3 * i + a], rgbd[a]), err_add(&es[G_RGB], rgbf[a], rgbd[a]);
            if (i >= nground) { /* d_x, d_n of ground pixels are not the kernel's business */
                err_add(&ef[G_X], d_x[3 * i + a], dxd[a]), err_add(&es[G_X], dxf[a], dxd[a]);
                err_add(&ef[G_N], d_n[3 * i + a], dnd[a]), err_add(&es[G_N], dnf[a], dnd[a]);
            }
            err_add(&ef[G_RHO], d_rho[3 * i + a], drd[a]), err_add(&es[G_RHO], drf[a], drd[a]);
        }
    }
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch)
            err_add(&ef[G_SH], d_sh[k][ch], r_sh[k][ch]), err_add(&es[G_SH], f_sh[k][ch], r_sh[k][ch]);
    for (int i = 0; i < 4 * S; ++i)
        err_add(&ef[G_SPH], d_s[i], r_s[i]), err_add(&es[G_SPH], f_s[i], r_s[i]);
    for (int g = 0; g < G_COUNT; ++g) {
        const double scale = fmax(ef[g].scale, 1e-30);
        const double tol = 4 * es[g].err + 1e-5 * scale;
        if (verbose)
            printf("  bands %d %s shadows %d S %2d: %-9s fast %.2e scalar %.2e (scale %.2e)\n",
                   bands, pen_sh_exp_method_name(method), shadows, S, group_name[g],
                   ef[g].err / scale, es[g].err / scale, scale);
        CHECK_MSG(ef[g].err <= tol,
                  "bands %d %s shadows %d spheres %d: %s error %.3g > tol %.3g (scalar %.3g, "
                  "scale %.3g)",
                  bands, pen_sh_exp_method_name(method), shadows, S, group_name[g], ef[g].err, tol,
                  es[g].err, scale);
    }
    free(Lf), free(Ld), free(sf), free(sd), free(kf), free(kd), free(x), free(n), free(rho), free(drgb);
    free(scratch), free(store), free(rgb), free(d_x), free(d_n), free(d_rho), free(d_sh), free(d_s);
    free(e_x), free(e_n), free(e_rho), free(e_sh), free(e_s);
    free(r_sh), free(f_sh), free(r_s), free(f_s);
}

/* kappa scales each sphere's log-visibility: kappa = 0 removes a sphere (image and every gradient
 * as without it, and no gradient for it), kappa = 2 everywhere doubles epsilon. */
static void test_kappa(void) {
    enum { S = 6, N = 40, nc = 16 };
    pen__shade_params p = params(4, PEN_SH_EXP_CALIBRATED, 1);
    pen__shade_params p2 = p;
    p2.epsilon = 2.0 * p.epsilon;
    float L[16][3], sph[24], kap0[6], kap2[6], x[3 * N], n[3 * N], rho[3 * N], drgb[3 * N];
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch)
            L[k][ch] = (float)(urand(-0.3, 0.3) + (k == 0 ? 1.5 : 0.0));
    for (int i = 0; i < S; ++i) {
        sph[4 * i] = (float)urand(-0.5, 0.5), sph[4 * i + 1] = (float)urand(0.2, 0.8);
        sph[4 * i + 2] = (float)urand(-0.5, 0.5), sph[4 * i + 3] = (float)urand(0.1, 0.3);
        kap0[i] = i % 2 ? 0.0f : 1.0f, kap2[i] = 2.0f;
    }
    for (int i = 0; i < N; ++i) {
        double d[3];
        rs_unit_vector(&rng, d);
        for (int a = 0; a < 3; ++a) {
            x[3 * i + a] = (float)(a == 1 ? urand(0, 0.5) : urand(-1, 1));
            n[3 * i + a] = (float)d[a], rho[3 * i + a] = 0.5f, drgb[3 * i + a] = (float)urand(-1, 1);
        }
    }
    float even[12]; /* the spheres kap0 keeps */
    for (int i = 0; i < 3; ++i)
        memcpy(even + 4 * i, sph + 8 * i, 4 * sizeof(float));
    void *scr = malloc(pen__shade_fast_scratch_bytes(&p, S, N));
    float rgb[4][3 * N], dx[4][3 * N] = {{0}};
    double dsh[4][16][3] = {{{0}}}, ds[4][24] = {{0}};
    /* 0: kappa 0/1, 1: the kept spheres alone, 2: kappa 2, 3: 2 epsilon. */
    const pen__shade_params *pp[4] = {&p, &p, &p, &p2};
    const float *sp[4] = {sph, even, sph, sph}, *kp[4] = {kap0, NULL, kap2, NULL};
    const int cnt[4] = {S, 3, S, S};
    for (int v = 0; v < 4; ++v) {
        float dn[3 * N] = {0}, dr[3 * N] = {0};
        pen__shade_fast_fwd(pp[v], (const float(*)[3])L, cnt[v], sp[v], kp[v], N, 0, x, n, rho,
                            rgb[v], NULL, scr, NULL);
        pen__shade_fast_bwd(pp[v], (const float(*)[3])L, cnt[v], sp[v], kp[v], N, 0, x, n, rho,
                            drgb, NULL, scr, dsh[v], ds[v], dx[v], dn, dr, NULL);
    }
    for (int i = 0; i < 3 * N; ++i) {
        CHECK_NEAR(rgb[0][i], rgb[1][i], 1e-6);
        CHECK_NEAR(dx[0][i], dx[1][i], 1e-5);
        CHECK_NEAR(rgb[2][i], rgb[3][i], 1e-5);
        CHECK_NEAR(dx[2][i], dx[3][i], 1e-4);
    }
    for (int k = 0; k < 16; ++k)
        CHECK_NEAR(dsh[0][k][0], dsh[1][k][0], 1e-5);
    for (int i = 0; i < S; ++i)
        for (int c = 0; c < 4; ++c) {
            if (i % 2) CHECK(ds[0][4 * i + c] == 0.0);
            else CHECK_NEAR(ds[0][4 * i + c], ds[1][4 * (i / 2) + c], 1e-5);
            CHECK_NEAR(ds[2][4 * i + c], ds[3][4 * i + c], 1e-4);
        }
    free(scr);
}

static void test_random_pixels(void) {
    const int verbose = getenv("PEN_TEST_VERBOSE") != NULL;
    const int counts[] = {0, 1, 7, 19, 33};
    const int pixels = check_quick_() ? 29 : 77;
    for (int bands = 3; bands <= 6; ++bands)
        for (int c = 0; c < 5; ++c) {
            check_random_pixels(bands, PEN_SH_EXP_CALIBRATED, 1, counts[c], pixels, verbose);
            if (c == 3) {
                check_random_pixels(bands, PEN_SH_EXP_PAPER, 1, counts[c], pixels, verbose);
                check_random_pixels(bands, PEN_SH_EXP_CALIBRATED, 0, counts[c], pixels, verbose);
            }
        }
    /* A single pixel and a batch and a half. */
    check_random_pixels(4, PEN_SH_EXP_CALIBRATED, 1, 5, 1, verbose);
    const int lanes = pen_render_fast_lanes();
    check_random_pixels(4, PEN_SH_EXP_CALIBRATED, 1, 5, lanes + lanes / 2, verbose);
}

/* ---- Whole frames ------------------------------------------------------------------------------ */

typedef struct frame_out {
    pen_image img;
    pen_render_grad g;
    pen_render_timings tm;
} frame_out;

/* Renders sc forward and backward (d_image = q, every gradient group). */
static frame_out render_frame(const pen_scene *sc, int kernel, int shadows, int threads,
                              const float *q) {
    frame_out f;
    memset(&f, 0, sizeof f);
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    pen_render_options opt = pen_render_options_default();
    opt.kernel = kernel;
    opt.shadows = shadows;
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_status s = pen_render_fwd(ctx, sc, &opt, st, &f.img);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(pen_render_grad_create(ctx, sc, &f.g) == PEN_OK);
    pen_image d = {f.img.width, f.img.height, 3, (float *)q};
    /* Every group the model has an exact gradient of (render.h). */
    s = pen_render_bwd(ctx, sc, &opt, st, &d, PEN_GRAD_ALL & pen_render_grad_exact(sc, &opt),
                       &f.g);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    pen_render_state_timings(st, &f.tm);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    return f;
}

static void frame_free(frame_out *f) {
    pen_image_free(&f->img);
    pen_render_grad_free(&f->g);
}

/* Groups of a frame's outputs as flat arrays: image, sh, ground albedo, object albedo, texture,
 * spheres, pose, vertices (object 0). */
#define FG_COUNT 8
static const char *fg_name[FG_COUNT] = {"image",   "d_sh",     "d_ground", "d_albedo",
                                        "d_texel", "d_sphere", "d_pose",   "d_vertex"};
static const float *fg_data(const frame_out *f, int g, size_t *n) {
    const pen_object_grad *og = &f->g.objects[0];
    switch (g) {
    case 0: *n = 3 * (size_t)f->img.width * (size_t)f->img.height; return f->img.data;
    case 1: *n = 3 * (size_t)f->g.bands * (size_t)f->g.bands; return &f->g.sh[0][0];
    case 2: *n = 3; return f->g.ground_albedo;
    case 3: *n = 3; return og->albedo;
    case 4: *n = og->texture ? 3 * (size_t)og->texel_count : 0; return og->texture;
    case 5: *n = 4 * (size_t)og->sphere_count; return og->spheres;
    case 6: *n = sizeof og->pose / sizeof(float); return (const float *)&og->pose;
    default: *n = 3 * (size_t)og->vertex_count; return og->positions;
    }
}

/* The ball scene with `bands` bands of lighting (random beyond the fixture's 16 coefficients)
 * and `count` proxy spheres: the fixture's two, then random ones in and around the ball and above
 * the ground. */
static pen_scene frame_scene(int size_w, int size_h, int bands, int count, pen_sh_exp_method m) {
    unsigned long long seed = 99;
    pen_scene sc = rs_ball_scene(size_w, 1, &seed);
    sc.camera.height = size_h;
    sc.sh_bands = bands;
    for (int k = 16; k < bands * bands; ++k)
        for (int ch = 0; ch < 3; ++ch)
            sc.lighting.sh[k][ch] = (float)rs_uniform(&seed, -0.05, 0.05);
    sc.shadow.exp = m;
    sc.shadow.epsilon = (float)pen_sh_exp_model_default(m, bands).epsilon;
    /* Every pixel through the kernels, and every gradient group (with the transfer the object's
     * own pixels and the ground's would take the scalar transfer path in both, tested in
     * test_self_transfer.c, and the geometric groups have no gradient). */
    sc.shadow.self = PEN_SELF_SPHERES;
    sc.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
    pen_spheres *sp = &sc.objects[0].spheres;
    pen_spheres grown;
    CHECK(pen_spheres_create(NULL, count, &grown) == PEN_OK);
    for (int i = 0; i < count; ++i) {
        float *s4 = grown.data + 4 * i;
        if (i < sp->count) {
            memcpy(s4, sp->data + 4 * i, 4 * sizeof(float));
            continue;
        }
        s4[0] = (float)rs_uniform(&seed, -0.5, 0.5), s4[1] = (float)rs_uniform(&seed, -0.3, 0.3);
        s4[2] = (float)rs_uniform(&seed, -0.5, 0.5), s4[3] = (float)rs_uniform(&seed, 0.05, 0.2);
    }
    pen_spheres_free(sp);
    *sp = grown;
    return sc;
}

/* Fast against scalar on one frame: every group within tol of the group's largest scalar value.
 * Both kernels are float and differ in summation order and the exponential's rounding only;
 * tests/test_render_shade.c ties the scalar one to double precision. */
static void check_frame(int w, int h, int bands, int count, pen_sh_exp_method m, int shadows,
                        int objects, int verbose) {
    pen_scene sc = frame_scene(w, h, bands, count, m);
    if (objects == 3) { /* two more at other heights: a lighting group each (ground occlusion) */
        for (int k = 0; k < 2; ++k) {
            const float s4[4] = {0, 0, 0, 0.18f};
            pen_object *ob = rs_add_object(&sc, rs_octasphere(2, 0.2f, 0), 1, s4);
            ob->pose.translation[0] = k ? 0.45f : -0.5f;
            ob->pose.translation[1] = k ? 0.9f : 0.25f;
            ob->pose.translation[2] = 0.2f;
        }
    }
    const size_t n = 3 * (size_t)w * (size_t)h;
    float *q = malloc(sizeof(float) * n);
    unsigned long long seed = 5;
    for (size_t i = 0; i < n; ++i)
        q[i] = (float)rs_uniform(&seed, -1, 1);
    frame_out a = render_frame(&sc, PEN_RENDER_KERNEL_FAST, shadows, 1, q);
    frame_out b = render_frame(&sc, PEN_RENDER_KERNEL_SCALAR, shadows, 1, q);
    for (int g = 0; g < FG_COUNT; ++g) {
        size_t na, nb;
        const float *va = fg_data(&a, g, &na), *vb = fg_data(&b, g, &nb);
        CHECK(na == nb);
        double err = 0, scale = 0;
        for (size_t i = 0; i < na && na == nb; ++i) {
            err = fmax(err, isfinite(va[i]) ? fabs((double)va[i] - (double)vb[i]) : HUGE_VAL);
            scale = fmax(scale, fabs((double)vb[i]));
        }
        /* 2e-5: the random-pixel test's float budget (a few 1e-6 of the scale per pixel) with
         * room for the sums over a frame's pixels; the vertex group is the sum of the
         * silhouette and the (tiny) shading parts and gets its own floor. */
        const double tol = 2e-5 * fmax(scale, 1e-3);
        if (verbose)
            printf("  %dx%d bands %d S %2d %s shadows %d: %-9s rel %.2e (scale %.2e)\n", w, h,
                   bands, count, pen_sh_exp_method_name(m), shadows, fg_name[g],
                   err / fmax(scale, 1e-30), scale);
        CHECK_MSG(err <= tol, "%dx%d bands %d spheres %d %s shadows %d: %s differs by %.3g "
                  "(scale %.3g)", w, h, bands, count, pen_sh_exp_method_name(m), shadows,
                  fg_name[g], err, scale);
    }
    frame_free(&a), frame_free(&b);
    free(q);
    pen_scene_free(&sc);
}

static void test_frames_fast_vs_scalar(void) {
    const int verbose = getenv("PEN_TEST_VERBOSE") != NULL;
    const int w = check_quick_() ? 23 : 45, h = check_quick_() ? 19 : 37; /* not tile multiples */
    for (int bands = 3; bands <= 6; ++bands)
        check_frame(w, h, bands, 19, PEN_SH_EXP_CALIBRATED, 1, 1, verbose);
    check_frame(w, h, 4, 0, PEN_SH_EXP_CALIBRATED, 0, 1, verbose); /* no spheres: no shadows */
    check_frame(w, h, 4, 7, PEN_SH_EXP_CALIBRATED, 1, 3, verbose);
    check_frame(w, h, 4, 2, PEN_SH_EXP_PAPER, 1, 1, verbose);
    check_frame(w, h, 4, 33, PEN_SH_EXP_CALIBRATED, 0, 1, verbose);
    /* EXACT and 2 bands take the scalar kernel inside the fast option: identical. */
    check_frame(w, h, 4, 2, PEN_SH_EXP_EXACT, 1, 1, verbose);
    check_frame(w, h, 2, 2, PEN_SH_EXP_CALIBRATED, 1, 1, verbose);
}

/* Threads take tiles in any order; every sum runs in tile order: 1 and 2 threads give the same
 * bits (the frame is above the renderer's size for threading). */
static void test_threads_bitwise(void) {
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_scene sc = frame_scene(83, 61, 4, 19, PEN_SH_EXP_CALIBRATED);
        const size_t n = 3 * 83 * 61;
        float *q = malloc(sizeof(float) * n);
        unsigned long long seed = 6;
        for (size_t i = 0; i < n; ++i)
            q[i] = (float)rs_uniform(&seed, -1, 1);
        frame_out a = render_frame(&sc, kernel, 1, 1, q);
        frame_out b = render_frame(&sc, kernel, 1, 2, q);
        for (int g = 0; g < FG_COUNT; ++g) {
            size_t na, nb;
            const float *va = fg_data(&a, g, &na), *vb = fg_data(&b, g, &nb);
            CHECK_MSG(na == nb && (!na || !memcmp(va, vb, sizeof(float) * na)),
                      "kernel %d: %s differs between 1 and 2 threads", kernel, fg_name[g]);
        }
        if (kernel == PEN_RENDER_KERNEL_FAST) /* the fast kernel reports its stages */
            CHECK(a.tm.fwd_visibility_ms > 0 && a.tm.fwd_visibility_ms < a.tm.fwd_shade_ms &&
                  a.tm.bwd_visibility_ms > 0 && a.tm.bwd_exp_ms > 0 &&
                  a.tm.bwd_visibility_ms + a.tm.bwd_exp_ms <= a.tm.bwd_shade_ms * 1.0001);
        frame_free(&a), frame_free(&b);
        free(q);
        pen_scene_free(&sc);
    }
}

/* The environment-map background kept in the state between frames: a second frame is bitwise
 * the first; a map edited in place, a rotated map or a moved camera are noticed (the state's
 * image equals a fresh state's). */
static void test_background_cache(void) {
    pen_scene sc = frame_scene(40, 30, 4, 2, PEN_SH_EXP_CALIBRATED);
    unsigned long long seed = 8;
    sc.lighting.envmap = rs_texture(16, 8, &seed);
    sc.lighting.scale = 1.0f;
    sc.background_envmap = 1;
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    pen_render_state_create(ctx, &st);
    const pen_render_options opt = pen_render_options_default();
    const size_t n = 3 * 40 * 30;
    for (int step = 0; step < 4; ++step) {
        if (step == 1) sc.lighting.envmap.data[5] += 0.25f; /* one texel, in place */
        if (step == 2) sc.lighting.rotation_y_deg = 30.0f;
        if (step == 3) sc.camera.eye[0] += 0.1f;
        pen_image a = {0}, b = {0}, c = {0};
        CHECK(pen_render_fwd(ctx, &sc, &opt, st, &a) == PEN_OK); /* after a change: refilled */
        CHECK(pen_render_fwd(ctx, &sc, &opt, st, &b) == PEN_OK); /* from the cache */
        CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &c) == PEN_OK); /* no state, no cache */
        CHECK_MSG(!memcmp(a.data, c.data, sizeof(float) * n) &&
                      !memcmp(b.data, c.data, sizeof(float) * n),
                  "step %d: cached background differs", step);
        pen_image_free(&a), pen_image_free(&b), pen_image_free(&c);
    }
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* An unknown kernel is an argument error; a backward with another kernel than its forward too. */
static void test_kernel_option(void) {
    pen_scene sc = frame_scene(20, 20, 4, 2, PEN_SH_EXP_CALIBRATED);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    CHECK(opt.kernel == PEN_RENDER_KERNEL_FAST);
    pen_render_state *st = NULL;
    pen_render_state_create(ctx, &st);
    pen_image img = {0};
    opt.kernel = 7;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_ERROR_ARGUMENT);
    opt.kernel = PEN_RENDER_KERNEL_FAST;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    pen_render_grad g;
    pen_render_grad_create(ctx, &sc, &g);
    opt.kernel = PEN_RENDER_KERNEL_SCALAR;
    CHECK(pen_render_bwd(ctx, &sc, &opt, st, &img, PEN_GRAD_ALL, &g) == PEN_ERROR_ARGUMENT);
    pen_render_grad_free(&g);
    pen_image_free(&img);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* ---- Every variant --------------------------------------------------------------------------- */

/* Runs fn with each variant of the fast kernel this processor runs, from the process's choice down
 * to the baseline, then restores the choice. */
static void each_variant(void (*fn)(void)) {
    const pen__shade_fast_ops *chosen = pen__shade_fast_current();
    int first = 0;
    while (pen__shade_fast_variant_ops(first) != chosen)
        ++first;
    for (int v = first; v < pen__shade_fast_variants(); ++v) {
        if (!pen__shade_fast_use(v)) continue;
        const pen__shade_fast_ops *o = pen__shade_fast_current();
        CHECK(pen_render_fast_lanes() == o->lanes);
        printf("  variant %s (%d lanes)\n", o->name, o->lanes);
        fn();
    }
    CHECK(pen__shade_fast_use(first));
}

static void test_random_pixels_each(void) {
    each_variant(test_random_pixels);
}
static void test_kappa_each(void) {
    each_variant(test_kappa);
}
static void test_frames_each(void) {
    each_variant(test_frames_fast_vs_scalar);
}
static void test_threads_each(void) {
    each_variant(test_threads_bitwise);
}

/* The choice: the baseline always runs; PEN_CPU naming a variant this processor runs is obeyed;
 * without PEN_CPU the widest is taken. */
static void test_variant_choice(void) {
    const int nv = pen__shade_fast_variants();
    CHECK(nv >= 1 && pen__shade_fast_variant_ops(nv - 1) != NULL);
    CHECK(pen__shade_fast_variant_ops(nv) == NULL && pen__shade_fast_variant_ops(-1) == NULL);
    CHECK(!pen__shade_fast_use(nv));
    const char *want = getenv("PEN_CPU");
    int widest = 0;
    while (!pen__shade_fast_variant_ops(widest))
        ++widest;
    const char *expect = pen__shade_fast_variant_ops(widest)->name;
    for (int v = widest; want && v < nv; ++v)
        if (!strcmp(want, pen__shade_fast_variant_ops(v)->name)) expect = want;
    printf("  in use: %s (%d lanes); PEN_CPU %s\n", pen__shade_fast_current()->name,
           pen_render_fast_lanes(), want ? want : "unset");
    CHECK_MSG(!strcmp(pen__shade_fast_current()->name, expect), "in use %s, expected %s",
              pen__shade_fast_current()->name, expect);
}

RUN_TESTS(TEST(test_variant_choice), TEST(test_random_pixels_each), TEST(test_kappa_each),
          TEST(test_frames_each), TEST(test_threads_each), TEST(test_kernel_option),
          TEST(test_background_cache))
