/* Camera: frame, rays and projection conventions, and the projection Jacobian against central
 * finite differences in double. */
#include "raster_util.h"

static void test_frame_and_rays(void) {
    pen_camera cam = ru_camera(64, 48, 40.0f, 0, 0, 5, 0, 0, 0);
    float r[3], u[3], f[3];
    pen_camera_frame(&cam, r, u, f);
    CHECK_NEAR(r[0], 1, 1e-7);
    CHECK_NEAR(u[1], 1, 1e-7);
    CHECK_NEAR(f[2], -1, 1e-7);
    /* A general camera: orthonormal, right x up = -forward. */
    cam = ru_camera(64, 48, 40.0f, 1.0f, 2.0f, 3.0f, -0.5f, 0.3f, 0.1f);
    pen_camera_frame(&cam, r, u, f);
    double rr = r[0] * r[0] + r[1] * r[1] + r[2] * r[2],
           ru = r[0] * u[0] + r[1] * u[1] + r[2] * u[2];
    CHECK_NEAR(rr, 1, 1e-6);
    CHECK_NEAR(ru, 0, 1e-6);
    CHECK_NEAR(r[1] * u[2] - r[2] * u[1], -f[0], 1e-6);
    CHECK_NEAR(r[2] * u[0] - r[0] * u[2], -f[1], 1e-6);
    CHECK_NEAR(u[1] > 0, 1, 0);
    /* The image centre looks along forward; rays at the top and bottom rows' outer edges span
     * fov_y; the top-left pixel looks up and left. */
    float d[3], top[3], bot[3];
    pen_camera_ray(&cam, 32.0f, 24.0f, d);
    for (int i = 0; i < 3; ++i)
        CHECK_NEAR(d[i], f[i], 1e-6);
    pen_camera_ray(&cam, 32.0f, 0.0f, top);
    pen_camera_ray(&cam, 32.0f, 48.0f, bot);
    double c = top[0] * bot[0] + top[1] * bot[1] + top[2] * bot[2];
    CHECK_NEAR(acos(c) * 180 / 3.14159265358979, 40.0, 1e-4);
    pen_camera_ray(&cam, 0.5f, 0.5f, d);
    CHECK(d[0] * r[0] + d[1] * r[1] + d[2] * r[2] < 0);
    CHECK(d[0] * u[0] + d[1] * u[1] + d[2] * u[2] > 0);
    /* Square pixels: horizontal half-angle from the aspect. */
    float left[3];
    pen_camera_ray(&cam, 0.0f, 24.0f, left);
    double cl = left[0] * f[0] + left[1] * f[1] + left[2] * f[2];
    CHECK_NEAR(tan(acos(cl)), tan(20.0 * 3.14159265358979 / 180) * 64.0 / 48.0, 1e-5);
}

static void test_degenerate_cameras(void) {
    pen_context *ctx = pen_context_create();
    pen_view view;
    /* Looking straight down with up = +Y falls back to another axis, without NaN. */
    pen_camera cam = ru_camera(16, 16, 50.0f, 0, 3, 0, 0, 0, 0);
    CHECK(pen_view_init(ctx, &cam, &view) == PEN_OK);
    for (int i = 0; i < 3; ++i)
        CHECK(isfinite(view.right[i]) && isfinite(view.up[i]));
    CHECK_NEAR(view.forward[1], -1, 1e-12);
    CHECK_NEAR(pen__dot_d(view.right, view.up), 0, 1e-12);
    float d[3];
    pen_camera_ray(&cam, 3.0f, 7.0f, d);
    CHECK(isfinite(d[0]) && isfinite(d[1]) && isfinite(d[2]));
    /* Invalid cameras are errors naming the field. */
    pen_camera bad = cam;
    bad.width = 0;
    CHECK(pen_view_init(ctx, &bad, &view) == PEN_ERROR_ARGUMENT);
    bad = cam, bad.fov_y_deg = 180.0f;
    CHECK(pen_view_init(ctx, &bad, &view) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "fov_y_deg") != NULL);
    bad = cam, bad.eye[0] = NAN;
    CHECK(pen_view_init(ctx, &bad, &view) == PEN_ERROR_ARGUMENT);
    bad = cam, bad.target[1] = 3.0f;
    CHECK(pen_view_init(ctx, &bad, &view) == PEN_ERROR_ARGUMENT);
    pen_context_destroy(ctx);
}

static void test_projection_roundtrip(void) {
    pen_camera cam = ru_camera(40, 30, 55.0f, 0.3f, 1.2f, 3.0f, 0.0f, 0.4f, 0.0f);
    pen_view view = ru_view(&cam);
    unsigned long long seed = 11;
    for (int k = 0; k < 50; ++k) {
        double sx = 40 * check_rand_(&seed), sy = 30 * check_rand_(&seed);
        double z = 0.5 + 4 * check_rand_(&seed), D[3], p[3], s[3];
        pen_view_ray(&view, sx, sy, D);
        for (int i = 0; i < 3; ++i)
            p[i] = view.eye[i] + z * D[i];
        pen__raster_project_d(&view, p, s, NULL);
        CHECK_NEAR(s[0], sx, 1e-10);
        CHECK_NEAR(s[1], sy, 1e-10);
        CHECK_NEAR(s[2], z, 1e-10);
    }
    /* The target projects to the image centre; float entry point agrees. */
    float t[3] = {0.0f, 0.4f, 0.0f}, s[3];
    pen_view_project_fwd(&view, t, s);
    CHECK_NEAR(s[0], 20, 1e-4);
    CHECK_NEAR(s[1], 15, 1e-4);
    CHECK_NEAR(s[2], sqrt(0.09 + 0.64 + 9.0), 1e-5);
}

static void projection_jacobian_fd(const pen_camera *cam) {
    pen_view view = ru_view(cam);
    unsigned long long seed = 12;
    const double h = 1e-6;
    for (int k = 0; k < 20; ++k) {
        double p[3], s[3], J[9];
        for (int i = 0; i < 3; ++i)
            p[i] = 2 * check_rand_(&seed) - 1;
        pen__raster_project_d(&view, p, s, J);
        for (int j = 0; j < 3; ++j) {
            double pp[3] = {p[0], p[1], p[2]}, pm[3] = {p[0], p[1], p[2]}, sp[3], sm[3];
            pp[j] += h, pm[j] -= h;
            pen__raster_project_d(&view, pp, sp, NULL);
            pen__raster_project_d(&view, pm, sm, NULL);
            for (int r = 0; r < 3; ++r)
                CHECK_REL(J[3 * r + j], (sp[r] - sm[r]) / (2 * h), 1e-7, 1e-2);
        }
        /* The float backward is J^T d_s, added. */
        float pf[3] = {(float)p[0], (float)p[1], (float)p[2]}, ds[3] = {0.3f, -0.7f, 0.2f};
        float dp[3] = {1, 1, 1};
        pen_view_project_bwd(&view, pf, ds, dp);
        for (int j = 0; j < 3; ++j)
            CHECK_REL(dp[j] - 1, J[j] * 0.3 - J[3 + j] * 0.7 + J[6 + j] * 0.2, 1e-5, 1e-2);
    }
}

/* A look-at camera, and a calibrated one (fx != fy, principal point off the centre). */
static void test_projection_jacobian_fd(void) {
    for (int calibrated = 0; calibrated < 2; ++calibrated) {
        pen_camera cam = ru_camera(40, 30, 55.0f, 0.3f, 1.2f, 3.0f, 0.0f, 0.4f, 0.0f);
        if (calibrated) cam.fx = 41.0f, cam.fy = 29.5f, cam.cx = 23.25f, cam.cy = 12.5f;
        projection_jacobian_fd(&cam);
    }
}

RUN_TESTS(TEST(test_frame_and_rays), TEST(test_degenerate_cameras), TEST(test_projection_roundtrip),
          TEST(test_projection_jacobian_fd))
