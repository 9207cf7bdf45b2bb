/* Calibrated cameras in the scene JSON: intrinsics (fx, fy, cx, cy) and world-to-camera poses
 * (R, t and 4x4) against the pinhole model written out here (COLMAP's convention: x right,
 * y down, z forward, pixel centres at +0.5), the errors with their key paths, the save/load round
 * trip (also through the flat API) and a look-at camera given both ways. The projection
 * Jacobian of a calibrated camera is checked in test_raster_camera.c. */
#include "check.h"
#include "penumbra/penumbra.h"

#include <stdio.h>
#include <string.h>

/* A rotation (about an oblique axis) and translation, the camera's world-to-camera pose. */
static const double R[9] = {0.936293, -0.275096, 0.218350,  /* rows: x, y, z of the camera */
                            0.289629, 0.956425, -0.036957, -0.198669, 0.097843, 0.975170};
static const double T[3] = {0.3, -0.2, 4.0};

static const char *scene_with(const char *camera, char *buf, size_t size) {
    snprintf(buf, size,
             "{\"camera\": %s, \"lighting\": {\"sh\": [[1, 1, 1]]}, \"sh_bands\": 1, "
             "\"objects\": []}",
             camera);
    return buf;
}

static pen_status parse_camera(pen_context *ctx, const char *camera, pen_scene *sc) {
    char buf[2048];
    return pen_scene_parse(ctx, scene_with(camera, buf, sizeof buf), "cam.json", sc);
}

static void rt_camera_json(char *out, size_t size, int as_matrix) {
    if (as_matrix)
        snprintf(out, size,
                 "{\"width\": 80, \"height\": 60, \"intrinsics\": {\"fx\": 70, \"fy\": 64, "
                 "\"cx\": 41.5, \"cy\": 28.25}, \"world_to_camera\": [[%.6f, %.6f, %.6f, %g], "
                 "[%.6f, %.6f, %.6f, %g], [%.6f, %.6f, %.6f, %g], [0, 0, 0, 1]]}",
                 R[0], R[1], R[2], T[0], R[3], R[4], R[5], T[1], R[6], R[7], R[8], T[2]);
    else
        snprintf(out, size,
                 "{\"width\": 80, \"height\": 60, \"intrinsics\": {\"fx\": 70, \"fy\": 64, "
                 "\"cx\": 41.5, \"cy\": 28.25}, \"world_to_camera\": {\"R\": [[%.6f, %.6f, "
                 "%.6f], [%.6f, %.6f, %.6f], [%.6f, %.6f, %.6f]], \"t\": [%g, %g, %g]}}",
                 R[0], R[1], R[2], R[3], R[4], R[5], R[6], R[7], R[8], T[0], T[1], T[2]);
}

/* Projection of world points through the loaded camera equals K (R p + t). */
static void test_projection_matches_pinhole(void) {
    pen_context *ctx = pen_context_create();
    for (int as_matrix = 0; as_matrix < 2; ++as_matrix) {
        char cam[1024];
        rt_camera_json(cam, sizeof cam, as_matrix);
        pen_scene sc;
        CHECK_MSG(parse_camera(ctx, cam, &sc) == PEN_OK, "%s", pen_context_error(ctx));
        pen_view view;
        CHECK(pen_view_init(ctx, &sc.camera, &view) == PEN_OK);
        CHECK_NEAR(sc.camera.fov_y_deg, 2 * atan(30.0 / 64.0) * 180 / M_PI, 1e-4);
        static const float pts[4][3] = {{0, 0, 0}, {0.5f, 0.3f, -0.2f}, {-1, 0.7f, 0.4f},
                                        {0.2f, -0.6f, 1.1f}};
        for (int k = 0; k < 4; ++k) {
            double c[3];
            for (int i = 0; i < 3; ++i)
                c[i] = R[3 * i] * (double)pts[k][0] + R[3 * i + 1] * (double)pts[k][1] +
                       R[3 * i + 2] * (double)pts[k][2] + T[i];
            double u = 70.0 * c[0] / c[2] + 41.5, v = 64.0 * c[1] / c[2] + 28.25;
            float s[3];
            pen_view_project_fwd(&view, pts[k], s);
            CHECK_NEAR(s[0], u, 2e-3);
            CHECK_NEAR(s[1], v, 2e-3);
            CHECK_NEAR(s[2], c[2], 1e-4);
            /* The ray through the projected point passes through the world point. */
            float d[3];
            pen_camera_ray(&sc.camera, (float)u, (float)v, d);
            double e[3], dot = 0, n2 = 0;
            for (int i = 0; i < 3; ++i) {
                e[i] = (double)pts[k][i] - (double)sc.camera.eye[i];
                dot += e[i] * (double)d[i], n2 += e[i] * e[i];
            }
            CHECK_NEAR(dot / sqrt(n2), 1.0, 1e-6);
        }
        pen_scene_free(&sc);
    }
    pen_context_destroy(ctx);
}

/* The look-at camera of a fov and the calibrated camera with the same K and pose render the
 * same image. */
static void test_look_at_equals_calibrated(void) {
    pen_context *ctx = pen_context_create();
    pen_scene a, b;
    const char *look = "{\"width\": 48, \"height\": 32, \"fov_y_deg\": 50, \"eye\": [0, 0, 3], "
                       "\"target\": [0, 0, 0], \"up\": [0, 1, 0]}";
    const double f = 16.0 / tan(25.0 * M_PI / 180.0);
    char cal[512];
    /* Looking down -Z from (0, 0, 3): camera x = world x, camera y = -world y, camera z = -world z;
     * t = -R eye = (0, 0, 3). */
    snprintf(cal, sizeof cal,
             "{\"width\": 48, \"height\": 32, \"intrinsics\": {\"fx\": %.9g, \"fy\": %.9g, "
             "\"cx\": 24, \"cy\": 16}, \"world_to_camera\": {\"R\": [[1, 0, 0], [0, -1, 0], "
             "[0, 0, -1]], \"t\": [0, 0, 3]}}",
             f, f);
    CHECK(parse_camera(ctx, look, &a) == PEN_OK);
    CHECK_MSG(parse_camera(ctx, cal, &b) == PEN_OK, "%s", pen_context_error(ctx));
    pen_view va, vb;
    CHECK(pen_view_init(ctx, &a.camera, &va) == PEN_OK);
    CHECK(pen_view_init(ctx, &b.camera, &vb) == PEN_OK);
    for (int i = 0; i < 3; ++i) {
        CHECK_NEAR(va.eye[i], vb.eye[i], 1e-6);
        CHECK_NEAR(va.right[i], vb.right[i], 1e-6);
        CHECK_NEAR(va.up[i], vb.up[i], 1e-6);
        CHECK_NEAR(va.forward[i], vb.forward[i], 1e-6);
    }
    CHECK_NEAR(va.focal[0], vb.focal[0], 1e-4);
    CHECK_NEAR(va.focal[1], vb.focal[1], 1e-4);
    CHECK_NEAR(va.cx, vb.cx, 0);
    CHECK_NEAR(va.cy, vb.cy, 0);
    pen_scene_free(&a);
    pen_scene_free(&b);
    pen_context_destroy(ctx);
}

/* Saving writes eye/target/up plus "intrinsics"; loading that file gives the same camera. */
static void test_round_trip(void) {
    pen_context *ctx = pen_context_create();
    char cam[1024];
    rt_camera_json(cam, sizeof cam, 0);
    pen_scene sc, back;
    CHECK(parse_camera(ctx, cam, &sc) == PEN_OK);
    const char *path = "camera_round_trip.json";
    CHECK_MSG(pen_scene_save(ctx, path, &sc) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK_MSG(pen_scene_load(ctx, path, &back) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(memcmp(&sc.camera, &back.camera, sizeof sc.camera) == 0);
    /* The flat API (and Python through it) carries the intrinsics. */
    pen_flat_loaded *flat = NULL;
    CHECK_MSG(pen_flat_scene_load(ctx, path, 0, &flat) == PEN_OK, "%s", pen_context_error(ctx));
    if (flat) {
        const pen_flat_scene *f = pen_flat_loaded_scene(flat);
        CHECK(f->fx == 70.0f && f->fy == 64.0f && f->cx == 41.5f && f->cy == 28.25f);
        pen_flat_loaded_free(flat);
    }
    pen_scene_free(&sc);
    pen_scene_free(&back);
    remove(path);
    pen_context_destroy(ctx);
}

/* Each malformed camera is refused with one line naming the key. */
static void test_errors(void) {
    pen_context *ctx = pen_context_create();
    static const struct {
        const char *camera, *expect;
    } cases[] = {
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"intrinsics\": {\"fx\": 1, \"fy\": 1, "
         "\"cx\": 4, \"cy\": 4}, \"eye\": [0, 0, 3], \"target\": [0, 0, 0]}",
         "camera: give \"fov_y_deg\" or \"intrinsics\", not both"},
        {"{\"width\": 8, \"height\": 8, \"eye\": [0, 0, 3], \"target\": [0, 0, 0]}",
         "camera: needs \"fov_y_deg\" or \"intrinsics\""},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40}",
         "camera: needs \"eye\"/\"target\"/\"up\" or \"world_to_camera\""},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], \"target\": [0, 0, "
         "0], \"world_to_camera\": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}",
         "give \"eye\"/\"target\"/\"up\" or \"world_to_camera\", not both"},
        {"{\"width\": 8, \"height\": 8, \"intrinsics\": {\"fx\": 0, \"fy\": 1, \"cx\": 4, \"cy\": "
         "4}, \"eye\": [0, 0, 3], \"target\": [0, 0, 0]}",
         "camera.intrinsics.fx:"},
        {"{\"width\": 8, \"height\": 8, \"intrinsics\": {\"fx\": 5, \"fy\": 5, \"cx\": 4}, "
         "\"eye\": [0, 0, 3], \"target\": [0, 0, 0]}",
         "camera.intrinsics.cy:"},
        {"{\"width\": 8, \"height\": 8, \"intrinsics\": {\"fx\": 5, \"fy\": 5, \"cx\": 4, "
         "\"cy\": 4e7}, \"eye\": [0, 0, 3], \"target\": [0, 0, 0]}",
         "camera.intrinsics.cy:"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": {\"R\": [[1, 0, "
         "0], [0, 1, 0], [0, 0, -1]], \"t\": [0, 0, 3]}}",
         "camera.world_to_camera: R has determinant -1: a reflection"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": {\"R\": [[1, 0.1, "
         "0], [0, 1, 0], [0, 0, 1]], \"t\": [0, 0, 3]}}",
         "camera.world_to_camera: R is not a rotation"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": [[1, 0, 0, 0], "
         "[0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 1, 1]]}",
         "camera.world_to_camera: the last row of a 4x4 pose must be [0, 0, 0, 1]"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": {\"R\": [[1, 0, "
         "0], [0, 1, 0]], \"t\": [0, 0, 3]}}",
         "camera.world_to_camera.R: expected an array of 3 rows"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": {\"R\": [[1, 0, "
         "0], [0, 1, 0], [0, 0, 1]], \"t\": [0, 0, 3e7]}}",
         "camera.world_to_camera.t[2]:"},
        {"{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"world_to_camera\": {\"R\": [[1, 0, "
         "0], [0, 1, 0], [0, 0, 1]], \"t\": [0, 0, 3], \"s\": 1}}",
         "camera.world_to_camera.s: unknown key"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; ++i) {
        pen_scene sc;
        pen_status s = parse_camera(ctx, cases[i].camera, &sc);
        CHECK_MSG(s == PEN_ERROR_PARSE, "case %zu accepted", i);
        CHECK_MSG(strstr(pen_context_error(ctx), cases[i].expect) != NULL,
                  "case %zu: \"%s\" lacks \"%s\"", i, pen_context_error(ctx), cases[i].expect);
    }
    /* The validator refuses a bad calibrated camera built in memory. */
    pen_camera c = {16, 16, 40.0f, {0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 10.0f, -1.0f, 8.0f, 8.0f};
    CHECK(pen_camera_validate(ctx, &c) == PEN_ERROR_ARGUMENT);
    c.fy = 10.0f, c.cx = NAN;
    CHECK(pen_camera_validate(ctx, &c) == PEN_ERROR_ARGUMENT);
    c.cx = 8.0f;
    CHECK(pen_camera_validate(ctx, &c) == PEN_OK);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_projection_matches_pinhole), TEST(test_look_at_equals_calibrated),
          TEST(test_round_trip), TEST(test_errors))
