/* The renderer at the edges of what the loaders accept: scenes that are valid but extreme
 * (spheres stacked at one place without overlap weights, the largest blocker depth, the largest
 * object count) render finite images and gradients; the largest camera is refused by the frame's
 * memory budget before allocating. */
#include "render_scenes.h"

static unsigned long long seed = 4242;

/* Renders with both kernels and runs the backward of a loss that pulls every pixel up: finite
 * pixels and gradients, and the two kernels agree (they share the saturation of sh.h, written
 * once per kernel). In the sphere model, so that every gradient group is computed. */
static void check_finite_render(const pen_scene *scene, const char *what) {
    pen_scene spheres = *scene; /* shallow: only the model differs */
    spheres.shadow.self = PEN_SELF_SPHERES;
    const pen_scene *sc = &spheres;
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, 2);
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_render_options opt = pen_render_options_default();
    pen_image img[2];
    pen_render_grad g[2];
    memset(img, 0, sizeof img);
    memset(g, 0, sizeof g);
    size_t n = 0;
    for (int kernel = 0; kernel < 2; ++kernel) {
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_status s = pen_render_fwd(ctx, sc, &opt, st, &img[kernel]);
        CHECK_MSG(s == PEN_OK, "%s: %s", what, pen_context_error(ctx));
        if (s) break;
        n = (size_t)img[kernel].width * (size_t)img[kernel].height * 3;
        CHECK_MSG(rs_all_finite(img[kernel].data, n), "%s (kernel %d): non-finite pixel", what,
                  kernel);
        pen_image d_img;
        CHECK(pen_image_create(ctx, img[kernel].width, img[kernel].height, 3, &d_img) == PEN_OK);
        for (size_t i = 0; i < n; ++i)
            d_img.data[i] = 1.0f;
        CHECK(pen_render_grad_create(ctx, sc, &g[kernel]) == PEN_OK);
        CHECK(pen_render_bwd(ctx, sc, &opt, st, &d_img, PEN_GRAD_ALL, &g[kernel]) == PEN_OK);
        CHECK_MSG(rs_all_finite(&g[kernel].sh[0][0], 3 * PEN_SH_MAX_COEFFS), "%s: d lighting",
                  what);
        for (int o = 0; o < g[kernel].object_count; ++o)
            CHECK_MSG(rs_all_finite(g[kernel].objects[o].spheres,
                                    4 * (size_t)g[kernel].objects[o].sphere_count),
                      "%s: object %d: d spheres", what, o);
        pen_image_free(&d_img);
    }
    if (img[0].data && img[1].data) {
        double worst = 0, scale = 1e-6;
        for (size_t i = 0; i < n; ++i) {
            worst = fmax(worst, fabs((double)img[0].data[i] - (double)img[1].data[i]));
            scale = fmax(scale, fabs((double)img[1].data[i]));
        }
        CHECK_MSG(worst <= 1e-3 * scale, "%s: kernels differ by %g (scale %g)", what, worst, scale);
        double gw = 0, gs = 1e-6;
        for (int k = 0; k < PEN_SH_MAX_COEFFS; ++k)
            for (int ch = 0; ch < 3; ++ch) {
                gw = fmax(gw, fabs((double)g[0].sh[k][ch] - (double)g[1].sh[k][ch]));
                gs = fmax(gs, fabs((double)g[1].sh[k][ch]));
            }
        CHECK_MSG(gw <= 1e-3 * gs, "%s: d lighting differs by %g (scale %g)", what, gw, gs);
        /* Through the exponential's backward (and its saturation): the sphere gradients. */
        double sw = 0, ss = 1e-6;
        for (int o = 0; o < g[0].object_count; ++o)
            for (int i = 0; i < 4 * g[0].objects[o].sphere_count; ++i) {
                const double a = g[0].objects[o].spheres[i], b = g[1].objects[o].spheres[i];
                sw = fmax(sw, fabs(a - b)), ss = fmax(ss, fabs(b));
            }
        CHECK_MSG(sw <= 1e-2 * ss, "%s: d spheres differ by %g (scale %g)", what, sw, ss);
    }
    for (int k = 0; k < 2; ++k)
        pen_image_free(&img[k]), pen_render_grad_free(&g[k]);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
}

/* ~100 spheres at one place with "overlap": "none": every shadow ray crosses all of them. */
static void test_stacked_spheres_without_weights(void) {
    pen_scene sc = rs_scene(24, 24);
    const int n = 128;
    float *s = malloc(sizeof(float) * 4 * (size_t)n);
    for (int i = 0; i < n; ++i)
        s[4 * i] = 0.0f, s[4 * i + 1] = 0.6f, s[4 * i + 2] = 0.0f, s[4 * i + 3] = 0.4f;
    pen_object *ob = rs_add_object(&sc, rs_far_triangle(), 0, NULL);
    CHECK(pen_spheres_create(NULL, n, &ob->spheres) == PEN_OK);
    memcpy(ob->spheres.data, s, sizeof(float) * 4 * (size_t)n);
    sc.shadow.overlap = PEN_OVERLAP_NONE;
    for (int m = 0; m < 3; ++m) {
        sc.shadow.exp = (pen_sh_exp_method)m;
        sc.shadow.epsilon = (float)pen_sh_exp_model_default(sc.shadow.exp, 4).epsilon;
        char what[64];
        snprintf(what, sizeof what, "stacked spheres, exp %s", pen_sh_exp_method_name(sc.shadow.exp));
        check_finite_render(&sc, what);
    }
    free(s);
    pen_scene_free(&sc);
}

/* The largest blocker depth the scene JSON accepts, one sphere. */
static void test_largest_epsilon(void) {
    pen_scene sc = rs_ball_scene(24, 0, &seed);
    for (int m = 0; m < 3; ++m) {
        sc.shadow.exp = (pen_sh_exp_method)m;
        sc.shadow.epsilon = 1e6f;
        check_finite_render(&sc, "epsilon 1e6");
    }
    pen_scene_free(&sc);
}

/* The scene JSON's largest object count, every object a small ball with one sphere. */
static void test_many_objects(void) {
    pen_scene sc = rs_scene(32, 32);
    const float s[4] = {0.0f, 0.0f, 0.0f, 0.1f};
    for (int i = 0; i < 4096; ++i) {
        pen_object *ob = rs_add_object(&sc, rs_octasphere(0, 0.1f, 0), 1, s);
        ob->pose.translation[0] = -1.0f + 2.0f * (float)(i % 64) / 63.0f;
        ob->pose.translation[2] = -1.0f + 2.0f * (float)(i / 64) / 63.0f;
        ob->pose.translation[1] = 0.3f;
    }
    check_finite_render(&sc, "4096 objects");
    pen_scene_free(&sc);
}

/* The largest camera the JSON accepts (16384 x 16384) would need tens of GB: refused before
 * anything is allocated, naming the size and the bytes. */
static void test_camera_memory_budget(void) {
    pen_scene sc = rs_ball_scene(16, 0, &seed);
    sc.camera.width = sc.camera.height = PEN_IMAGE_MAX_DIM;
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_image img;
    memset(&img, 0, sizeof img);
    for (int with_state = 0; with_state < 2; ++with_state) {
        pen_status s = pen_render_fwd(ctx, &sc, NULL, with_state ? st : NULL, &img);
        CHECK(s == PEN_ERROR_ARGUMENT);
        const char *e = pen_context_error(ctx);
        CHECK_MSG(strstr(e, "camera 16384 x 16384 needs about") && strstr(e, "GB (limit 17.2 GB"),
                  "%s", e);
        CHECK(img.data == NULL);
    }
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

RUN_TESTS(TEST(test_stacked_spheres_without_weights), TEST(test_largest_epsilon),
          TEST(test_many_objects), TEST(test_camera_memory_budget))
