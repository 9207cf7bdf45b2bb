/* The renderer at the edges of what the loaders accept: scenes that are valid but extreme
 * (spheres stacked at one place without overlap weights, the largest blocker depth, the largest
 * object count) render finite images and gradients; the largest camera is refused by the frame's
 * memory budget before allocating. */
#include "render_scenes.h"

static unsigned long long seed = 4242;

static void check_finite_render(const pen_scene *sc, const char *what) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, 2);
    pen_render_state *st = NULL;
    pen_image img;
    memset(&img, 0, sizeof img);
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_render_options opt = pen_render_options_default();
    for (int kernel = 0; kernel < 2; ++kernel) {
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_status s = pen_render_fwd(ctx, sc, &opt, st, &img);
        CHECK_MSG(s == PEN_OK, "%s: %s", what, pen_context_error(ctx));
        if (s) break;
        size_t n = (size_t)img.width * (size_t)img.height * (size_t)img.channels;
        CHECK_MSG(rs_all_finite(img.data, n), "%s (kernel %d): non-finite pixel", what, kernel);
        /* The backward of a loss that pulls every pixel up: finite gradients. */
        pen_image d_img;
        pen_render_grad g;
        CHECK(pen_image_create(ctx, img.width, img.height, 3, &d_img) == PEN_OK);
        for (size_t i = 0; i < n; ++i)
            d_img.data[i] = 1.0f;
        CHECK(pen_render_grad_create(ctx, sc, &g) == PEN_OK);
        CHECK(pen_render_bwd(ctx, sc, &opt, st, &d_img, PEN_GRAD_ALL, &g) == PEN_OK);
        CHECK_MSG(rs_all_finite(&g.sh[0][0], 3 * PEN_SH_MAX_COEFFS), "%s: d lighting", what);
        for (int o = 0; o < g.object_count; ++o)
            CHECK_MSG(rs_all_finite(g.objects[o].spheres, 4 * (size_t)g.objects[o].sphere_count),
                      "%s: object %d: d spheres", what, o);
        pen_render_grad_free(&g);
        pen_image_free(&d_img);
    }
    pen_image_free(&img);
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
