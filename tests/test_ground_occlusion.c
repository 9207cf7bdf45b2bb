/* The ground plane as an occluder of the objects (src/render/ground.c, pen__ground_occlusion_prepare;
 * src/sh/gaunt.c, pen__sh_above).
 *
 * - The matrix M(t) = integral over y > -t of Y_j Y_k against Monte-Carlo integration, its
 *   limits (t = 1: the identity; t = -1: zero) and its t-derivative against central differences
 *   in double.
 * - Under a light from just below the horizon, the ray-traced reference (whose ground blocks it)
 *   is much closer to the occluding model than to the receiver-only one.
 * - Shadows off, or no ground: no effect.
 * - Gradients with occlusion against central differences: the lighting (the image is linear in
 *   it) and the pose's vertical translation, which moves the hidden cap. */
#include "optim_scenes.h"

#include "sh/sh_internal.h"

static void test_above_matrix(void) {
    const int L = 4, n = L * L;
    static double M[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS], dM[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS],
        Mp[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS], Mm[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS],
        mc[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS];
    pen__sh_above(L, 1.0, M, NULL);
    for (int j = 0; j < n; ++j)
        for (int k = 0; k < n; ++k)
            CHECK_NEAR(M[j * n + k], j == k ? 1.0 : 0.0, 1e-12);
    pen__sh_above(L, -1.0, M, NULL);
    for (int j = 0; j < n * n; ++j)
        CHECK_NEAR(M[j], 0.0, 1e-12);
    const double ts[3] = {0.0, 0.3, -0.2};
    unsigned long long seed = 77;
    for (int c = 0; c < 3; ++c) {
        const double t = ts[c];
        pen__sh_above(L, t, M, dM);
        /* Monte Carlo: N uniform directions; the integrand is at most about 1, so the error
         * is about sqrt(4 pi / N) ~ 4e-3 at worst. */
        const int N = check_quick_() ? 20000 : 400000;
        memset(mc, 0, sizeof mc);
        for (int s = 0; s < N; ++s) {
            const double y = 2.0 * check_rand_(&seed) - 1.0, phi = 2.0 * M_PI * check_rand_(&seed);
            if (!(y > -t)) continue;
            const double r = sqrt(1.0 - y * y), d[3] = {r * cos(phi), y, r * sin(phi)};
            double Y[PEN_SH_MAX_COEFFS];
            pen_sh_eval_d(L, d, Y);
            for (int j = 0; j < n; ++j)
                for (int k = 0; k < n; ++k)
                    mc[j * n + k] += 4.0 * M_PI / N * Y[j] * Y[k];
        }
        double worst = 0.0;
        for (int j = 0; j < n * n; ++j)
            worst = fmax(worst, fabs(mc[j] - M[j]));
        CHECK_MSG(worst < (check_quick_() ? 0.05 : 0.012), "t = %g: Monte Carlo differs by %.3g",
                  t, worst);
        /* M is a polynomial in t: central differences in double. */
        const double h = 1e-5;
        pen__sh_above(L, t + h, Mp, NULL);
        pen__sh_above(L, t - h, Mm, NULL);
        for (int j = 0; j < n * n; ++j)
            CHECK_NEAR(dM[j], (Mp[j] - Mm[j]) / (2.0 * h), 1e-7);
    }
}

/* The ellipsoid under a light from 25 degrees below the horizon (4-band projection, windowed)
 * and a little sky; 64x64. */
static pen_scene low_light_scene(void) {
    pen_scene sc = os_egg(64, 1, 4);
    const float el = -25.0f * (float)M_PI / 180.0f;
    const float d[3] = {cosf(el) * 0.8f, sinf(el), cosf(el) * 0.6f};
    float y[16];
    pen_sh_eval(4, d, y);
    memset(sc.lighting.sh, 0, sizeof sc.lighting.sh);
    for (int l = 0; l < 4; ++l) {
        const float c = cosf((float)M_PI * (float)l / 8.0f);
        for (int m = -l; m <= l; ++m)
            for (int ch = 0; ch < 3; ++ch)
                sc.lighting.sh[l * l + l + m][ch] = 3.0f * c * c * y[l * l + l + m];
    }
    for (int ch = 0; ch < 3; ++ch)
        sc.lighting.sh[0][ch] += 0.3f * sqrtf(4.0f * (float)M_PI);
    return sc;
}

/* Measured: 0.053 occluding, 0.35 receiver only. */
static void test_closer_to_reference(void) {
    pen_scene sc = low_light_scene();
    pen_image ref = os_reference(&sc);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image a = {0, 0, 0, NULL}, b = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &a) == PEN_OK);
    sc.shadow.ground = PEN_GROUND_RECEIVER;
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &b) == PEN_OK);
    const double ea = rs_rel_error(&a, &ref), eb = rs_rel_error(&b, &ref);
    printf("  relative error against the reference: occludes %.4f, receiver %.4f\n", ea, eb);
    CHECK(ea < 0.5 * eb);
    pen_image_free(&a), pen_image_free(&b), pen_image_free(&ref);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* Shadows off or no ground: the setting changes nothing, bit for bit. */
static void test_no_effect_without(void) {
    pen_context *ctx = pen_context_create();
    for (int k = 0; k < 2; ++k) {
        pen_scene sc = low_light_scene();
        pen_render_options opt = pen_render_options_default();
        if (k == 0) opt.shadows = 0;
        else sc.ground.enabled = 0;
        pen_image a = {0, 0, 0, NULL}, b = {0, 0, 0, NULL};
        CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &a) == PEN_OK);
        sc.shadow.ground = PEN_GROUND_RECEIVER;
        CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &b) == PEN_OK);
        CHECK(memcmp(a.data, b.data, sizeof(float) * 3 * 64 * 64) == 0);
        pen_image_free(&a), pen_image_free(&b);
        pen_scene_free(&sc);
    }
    pen_context_destroy(ctx);
}

/* sum_p q_p I_p for fixed random weights q. */
static double projected(pen_context *ctx, const pen_scene *sc, const float *q) {
    pen_image img = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, sc, NULL, NULL, &img) == PEN_OK);
    double l = 0.0;
    for (size_t i = 0; i < 3 * (size_t)img.width * (size_t)img.height; ++i)
        l += (double)q[i] * (double)img.data[i];
    pen_image_free(&img);
    return l;
}

/* The lighting (linear: step 0.05, 1e-3 relative) and the vertical translation (step 1e-4, about
 * 1/500 pixel, as the pose checks of test_render_grad.c: larger steps cross the rasteriser's
 * jumps; 2e-2 relative), with the ground occluding, scalar and fast kernels. Measured on ty:
 * -15.463 against -15.448 (with the ground a receiver only the same check gives 71.29 against
 * 71.32: the moving cap accounts for most of this derivative under a light from below). */
static void test_gradients(void) {
    pen_context *ctx = pen_context_create();
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_scene sc = low_light_scene();
        sc.camera.width = sc.camera.height = 32;
        /* The height gradient belongs to the sphere model's ground occlusion: with the object's
         * own transfer (the default) the ground is traced, a constant of the pose. */
        sc.shadow.self = PEN_SELF_SPHERES;
        const size_t nq = 3 * 32 * 32;
        float *q = malloc(sizeof(float) * nq);
        unsigned long long seed = 5;
        for (size_t i = 0; i < nq; ++i)
            q[i] = (float)check_rand_(&seed);
        pen_render_options opt = pen_render_options_default();
        opt.kernel = kernel ? PEN_RENDER_KERNEL_FAST : PEN_RENDER_KERNEL_SCALAR;
        pen_render_state *st = NULL;
        pen_render_grad g;
        pen_image img = {0, 0, 0, NULL}, d_img = {0, 0, 0, NULL};
        CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
        CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
        CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
        d_img = img;
        d_img.data = q;
        pen_render_grad_zero(&g);
        CHECK(pen_render_bwd(ctx, &sc, &opt, st, &d_img, PEN_GRAD_LIGHTING | PEN_GRAD_POSE, &g) ==
              PEN_OK);
        const int ks[3] = {0, 2, 9};
        for (int c = 0; c < 3; ++c) {
            float *v = &sc.lighting.sh[ks[c]][1];
            const float v0 = *v;
            *v = v0 + 0.05f;
            const double lp = projected(ctx, &sc, q);
            *v = v0 - 0.05f;
            const double lm = projected(ctx, &sc, q);
            *v = v0;
            CHECK_REL((double)g.sh[ks[c]][1], (lp - lm) / 0.1, 1e-3, 1e-6);
        }
        float *ty = &sc.objects[0].pose.translation[1];
        const float t0 = *ty;
        *ty = t0 + 1e-4f;
        const double lp = projected(ctx, &sc, q);
        *ty = t0 - 1e-4f;
        const double lm = projected(ctx, &sc, q);
        *ty = t0;
        const double fd = (lp - lm) / (double)(2.0f * 1e-4f), an = (double)g.objects[0].pose.translation[1];
        printf("  kernel %s: d/d ty analytic %.5g, central differences %.5g\n",
               kernel ? "fast" : "scalar", an, fd);
        CHECK_REL(an, fd, 2e-2, 0.0);
        pen_image_free(&img);
        pen_render_grad_free(&g);
        pen_render_state_free(st);
        free(q);
        pen_scene_free(&sc);
    }
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_above_matrix), TEST(test_closer_to_reference), TEST(test_no_effect_without),
          TEST(test_gradients))
