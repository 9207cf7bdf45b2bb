/* One scene, one image, whichever door it comes through (docs/design.md sec. 1.15): each bundled
 * scene, and a scene of our own with textures, an OBJ's materials, a disk light and two objects,
 * is rendered by `penumbra render` (EXR, linear float), by the C API as render.h's usage writes it
 * (pen_scene_load, pen_scene_prepare, pen_render_fwd) and by the flat API's loader and renderer
 * (what Python's load_scene and render_scene call), with the thread count pinned. The images must
 * agree within 1e-6 relative RMSE (today they are equal bit for bit). python/tests/test_doors.py
 * holds the binding to the same command images. Also: the sphere-fit cache hands every thread
 * count the same file, since the fit does not depend on the count. */
#include "io_fixtures.h"

#include "penumbra/fit.h"
#include "penumbra/flat.h"

#include <math.h>

#define THREADS 2

/* Our own scene: Spot with its texture and Bob with its OBJ material (baked), a given disk light on
 * top of the map's SH, the map as background; small, so that the sanitizer build runs it too. */
static const char *own_scene(void) {
    static char json[4096];
    snprintf(json, sizeof json,
             "{\"camera\": {\"width\": 96, \"height\": 72, \"fov_y_deg\": 40,"
             " \"eye\": [2.6, 1.6, 3.0], \"target\": [0.2, 0.45, 0]},"
             " \"lighting\": {\"envmap\": \"%s/data/envmaps/interior.hdr\", \"scale\": 0.5,"
             "  \"lights\": [{\"direction\": [0.6, 1.0, 0.3], \"angular_radius_deg\": 2.5,"
             "  \"irradiance\": [2.0, 1.9, 1.7]}]},"
             " \"objects\": ["
             "  {\"mesh\": \"%s/data/meshes/spot_triangulated.obj\","
             "   \"albedo_texture\": \"%s/data/meshes/spot_texture.png\","
             "   \"spheres\": {\"fit\": 12},"
             "   \"pose\": {\"rotation_axis_angle_deg\": [0, 140, 0], \"translation\": [0, 0.737, 0]}},"
             "  {\"mesh\": \"%s/data/meshes/bob_tri.obj\", \"spheres\": {\"fit\": 8},"
             "   \"pose\": {\"translation\": [1.0, 0.3, -0.6], \"scale\": 0.6}}],"
             " \"ground\": {\"albedo\": [0.7, 0.7, 0.7]},"
             " \"background\": \"envmap\"}",
             PEN_SOURCE_DIR, PEN_SOURCE_DIR, PEN_SOURCE_DIR, PEN_SOURCE_DIR);
    return fixture_text("own.json", json);
}

static double rel_rmse(const float *a, const float *b, size_t n) {
    double num = 0.0, den = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const double d = (double)a[i] - (double)b[i];
        num += d * d, den += (double)b[i] * (double)b[i];
    }
    return den > 0.0 ? sqrt(num / den) : sqrt(num);
}

static void compare(const char *door, const char *scene, const float *got, const pen_image *want) {
    const size_t n = 3 * (size_t)want->width * (size_t)want->height;
    const double e = rel_rmse(got, want->data, n);
    const int same = memcmp(got, want->data, n * sizeof(float)) == 0;
    printf("  %s: %s against the command: rel. RMSE %.3g%s\n", scene, door, e,
           same ? " (bit for bit)" : "");
    CHECK_MSG(e <= 1e-6, "%s: %s differs from penumbra render: %g", scene, door, e);
}

static void check_doors(const char *path, const char *name) {
    /* The command. */
    const char *out = fixture_path("cli.exr");
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "'%s' render '%s' -o '%s' -q --threads %d", PEN_CLI, path, out,
             THREADS);
    CHECK_MSG(system(cmd) == 0, "%s", cmd);
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, THREADS);
    pen_image want = {0, 0, 0, NULL};
    CHECK(pen_image_load(ctx, out, &want) == PEN_OK);
    if (!want.data) {
        pen_context_destroy(ctx);
        return;
    }
    const size_t n = 3 * (size_t)want.width * (size_t)want.height;

    /* The C API, as render.h's usage writes it. */
    pen_scene sc;
    pen_image img = {0, 0, 0, NULL};
    CHECK(pen_scene_load(ctx, path, &sc) == PEN_OK);
    CHECK_MSG(pen_scene_prepare(ctx, &sc, 1, NULL) == PEN_OK, "%s", pen_context_error(ctx));
    const pen_render_options opt = pen_render_options_default();
    CHECK_MSG(pen_render_fwd(ctx, &sc, &opt, NULL, &img) == PEN_OK, "%s", pen_context_error(ctx));
    if (img.data && img.width == want.width && img.height == want.height)
        compare("C API", name, img.data, &want);
    pen_image_free(&img);
    pen_scene_free(&sc);

    /* The flat API: the loader and the renderer the Python binding calls. */
    pen_flat_loaded *l = NULL;
    CHECK(pen_flat_scene_load(ctx, path, 1, &l) == PEN_OK);
    float *flat = calloc(n, sizeof(float));
    if (l && flat) {
        CHECK_MSG(pen_flat_render_fwd(ctx, pen_flat_loaded_scene(l), NULL, flat) == PEN_OK, "%s",
                  pen_context_error(ctx));
        compare("flat API", name, flat, &want);
    }
    free(flat);
    pen_flat_loaded_free(l);
    pen_image_free(&want);
    pen_context_destroy(ctx);
}

static void test_bundled_scenes(void) {
    if (check_quick_()) { /* 512 x 512 with fits: left to the full build */
        printf("  (quick: the bundled scenes are left to the full build)\n");
        return;
    }
    check_doors(PEN_SOURCE_DIR "/examples/scenes/spot_city.json", "spot_city");
    check_doors(PEN_SOURCE_DIR "/examples/scenes/spot_interior.json", "spot_interior");
}

static void test_own_scene(void) {
    check_doors(own_scene(), "textures, a light, two objects");
}

/* The fit is the same on every thread count (its sums are added in a fixed order), so every
 * count reads the same cache file. */
static void test_fit_cache_threads(void) {
    pen_context *ctx = pen_context_create();
    pen_mesh m;
    CHECK(pen_mesh_load(ctx, PEN_SOURCE_DIR "/data/meshes/blub.obj", &m) == PEN_OK);
    char *one = NULL, *two = NULL;
    pen_context_set_threads(ctx, 1);
    CHECK(pen_spheres_fit_cache_path(ctx, &m, "blub.obj", 8, NULL, &one) == PEN_OK);
    pen_context_set_threads(ctx, 2);
    CHECK(pen_spheres_fit_cache_path(ctx, &m, "blub.obj", 8, NULL, &two) == PEN_OK);
    CHECK(one && two && strcmp(one, two) == 0);
    free(one), free(two);
    pen_mesh_free(&m);
    pen_context_destroy(ctx);
}

static void test_private_cache(void) {
    check_private_cache_(); /* the fits below go to a folder of this test */
}

RUN_TESTS(TEST(test_private_cache), TEST(test_fit_cache_threads), TEST(test_own_scene),
          TEST(test_bundled_scenes))
