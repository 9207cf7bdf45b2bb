/* Camera-set imports on small files written here: a COLMAP text model (PINHOLE and
 * SIMPLE_PINHOLE, ids out of order, an empty points line) and a NeRF-style transforms.json
 * (camera_angle_x, fl_x/cx/cy per frame, w/h read from the image, ".png" appended), each checked
 * by projecting world points with the dataset's own convention written out here; the views JSON
 * round trip; and the refusals, each naming the file and line or key. */
#define _POSIX_C_SOURCE 200809L
#include "check.h"
#include "penumbra/penumbra.h"

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static void write_text(const char *path, const char *text) {
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f) return;
    fputs(text, f);
    fclose(f);
}

static const float POINTS[4][3] = {{0, 0, 0}, {0.4f, 0.3f, -0.2f}, {-0.5f, 0.6f, 0.3f},
                                   {0.2f, -0.3f, 0.5f}};

/* Where pen_view puts world point p (pixel coordinates). */
static void project(const pen_camera *cam, const float p[3], double *u, double *v) {
    pen_context *ctx = pen_context_create();
    pen_view view;
    CHECK(pen_view_init(ctx, cam, &view) == PEN_OK);
    float s[3];
    pen_view_project_fwd(&view, p, s);
    *u = s[0], *v = s[1];
    pen_context_destroy(ctx);
}

static void quat_rot(const double q[4], double R[9]) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - w * z), R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z), R[4] = 1 - 2 * (x * x + z * z), R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y), R[7] = 2 * (y * z + w * x), R[8] = 1 - 2 * (x * x + y * y);
}

static const char *CAMERAS_TXT =
    "# Camera list with one line of data per camera:\n"
    "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
    "7 PINHOLE 64 48 60.5 58 33.25 22.5\n"
    "2 SIMPLE_PINHOLE 40 40 45 20 19.5\n";
/* Image 9 (b.png) uses camera 7, image 4 (a.png) camera 2: sorted by name, a.png comes first. */
static const double Q[2][4] = {{0.9659258, 0.0, 0.2588190, 0.0}, {0.9914449, 0.1305262, 0.0, 0.0}};
static const double T[2][3] = {{0.1, -0.2, 3.0}, {-0.3, 0.25, 2.5}};

static void write_colmap(const char *dir, const char *cameras) {
    char path[512], text[2048];
    mkdir(dir, 0755);
    snprintf(path, sizeof path, "%s/cameras.txt", dir);
    write_text(path, cameras);
    snprintf(text, sizeof text,
             "# Image list with two lines of data per image:\n"
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
             "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
             "9 %.7f %.7f %.7f %.7f %g %g %g 7 b.png\n"
             "10.5 20.25 -1 11 12 3\n"
             "4 %.7f %.7f %.7f %.7f %g %g %g 2 a.png\n"
             "\n",
             Q[0][0], Q[0][1], Q[0][2], Q[0][3], T[0][0], T[0][1], T[0][2], Q[1][0], Q[1][1],
             Q[1][2], Q[1][3], T[1][0], T[1][1], T[1][2]);
    snprintf(path, sizeof path, "%s/images.txt", dir);
    write_text(path, text);
}

/* A small image file at path. */
static void write_image(pen_context *ctx, const char *path, int w, int h) {
    pen_image img;
    CHECK(pen_image_create(ctx, w, h, 3, &img) == PEN_OK);
    CHECK(pen_image_save(ctx, path, &img) == PEN_OK);
    pen_image_free(&img);
}

static void test_colmap(void) {
    pen_context *ctx = pen_context_create();
    write_colmap("colmap_model", CAMERAS_TXT);
    mkdir("photos", 0755);
    write_image(ctx, "photos/a.png", 4, 4);
    write_image(ctx, "photos/b.png", 4, 4);
    pen_camera_set set;
    CHECK_MSG(pen_camera_set_load_colmap(ctx, "colmap_model", "photos", &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(set.count == 2);
    if (set.count == 2) {
        CHECK(strcmp(set.images[0], "photos/a.png") == 0);
        CHECK(strcmp(set.images[1], "photos/b.png") == 0);
        CHECK(set.cameras[0].width == 40 && set.cameras[1].width == 64);
        /* x_cam = R(q) X + t; u = fx x/z + cx, v = fy y/z + cy (pixel centres at +0.5). */
        const double K[2][4] = {{45, 45, 20, 19.5}, {60.5, 58, 33.25, 22.5}};
        for (int i = 0; i < 2; ++i) {
            const int src = 1 - i; /* a.png is the second image line */
            double R[9];
            quat_rot(Q[src], R);
            for (int k = 0; k < 4; ++k) {
                double c[3];
                for (int r = 0; r < 3; ++r)
                    c[r] = R[3 * r] * (double)POINTS[k][0] + R[3 * r + 1] * (double)POINTS[k][1] +
                           R[3 * r + 2] * (double)POINTS[k][2] + T[src][r];
                double u, v;
                project(&set.cameras[i], POINTS[k], &u, &v);
                CHECK_NEAR(u, K[i][0] * c[0] / c[2] + K[i][2], 2e-3);
                CHECK_NEAR(v, K[i][1] * c[1] / c[2] + K[i][3], 2e-3);
            }
        }
    }
    /* The views JSON round trip. */
    CHECK_MSG(pen_camera_set_save_views(ctx, "colmap_views.json", &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_camera_set back;
    CHECK_MSG(pen_camera_set_load_views(ctx, "colmap_views.json", &back) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(back.count == set.count);
    for (int i = 0; i < set.count && i < back.count; ++i) {
        CHECK(memcmp(&back.cameras[i], &set.cameras[i], sizeof(pen_camera)) == 0);
        CHECK_MSG(strcmp(back.images[i], set.images[i]) == 0, "%s vs %s", back.images[i],
                  set.images[i]);
    }
    pen_camera_set_free(&back);
    pen_camera_set_free(&set);
    pen_context_destroy(ctx);
}

static void expect_error(pen_status s, pen_context *ctx, const char *text) {
    CHECK_MSG(s != PEN_OK, "accepted; expected \"%s\"", text);
    CHECK_MSG(strstr(pen_context_error(ctx), text) != NULL, "\"%s\" lacks \"%s\"",
              pen_context_error(ctx), text);
}

static void test_colmap_errors(void) {
    pen_context *ctx = pen_context_create();
    pen_camera_set set;
    write_colmap("colmap_bad", "1 OPENCV 64 48 60 60 32 24 0.1 0.01 0 0\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "colmap_bad/cameras.txt:1: camera model OPENCV has lens distortion");
    CHECK(set.count == 0 && set.cameras == NULL);
    write_colmap("colmap_bad", "7 PINHOLE 64 48 60 58 33\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "colmap_bad/cameras.txt:1: PINHOLE takes 4 parameters");
    write_colmap("colmap_bad", "7 PINHOLE 64 0 60 58 33 20\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "cameras.txt:1: camera id, width or height out of range");
    write_colmap("colmap_bad", "7 PINHOLE 64 48 -60 58 33 20\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "cameras.txt:1: focal length or principal point out of range");
    write_colmap("colmap_bad", "7 PINHOLE 64 48 60 58 33 20\n"); /* camera 2 is missing */
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", "photos", &set), ctx,
                 "colmap_bad/images.txt:6: camera 2 is not in cameras.txt");
    write_colmap("colmap_bad", CAMERAS_TXT); /* valid, but the images are elsewhere */
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "colmap_bad/images.txt:4: image colmap_bad/b.png not found");
    write_text("colmap_bad/images.txt", "1 0.5 0 0 0 0 0 3 7 a.png\n\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "images.txt:1: quaternion of norm 0.5, not 1");
    write_text("colmap_bad/images.txt", "1 1 0 0 0 0 nan 3 7 a.png\n\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "images.txt:1: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME");
    write_text("colmap_bad/images.txt", "# nothing\n");
    expect_error(pen_camera_set_load_colmap(ctx, "colmap_bad", NULL, &set), ctx,
                 "images.txt: no images");
    expect_error(pen_camera_set_load_colmap(ctx, "no_such_model", NULL, &set), ctx,
                 "no_such_model/cameras.txt");
    pen_context_destroy(ctx);
}

/* A camera-to-world matrix (OpenGL axes) looking at the origin from `eye`, rows written out. */
static void c2w_json(const double eye[3], char *out, size_t size) {
    double f[3] = {-eye[0], -eye[1], -eye[2]}, n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int k = 0; k < 3; ++k)
        f[k] /= n;
    double up0[3] = {0, 1, 0}, r[3], u[3];
    r[0] = f[1] * up0[2] - f[2] * up0[1], r[1] = f[2] * up0[0] - f[0] * up0[2],
    r[2] = f[0] * up0[1] - f[1] * up0[0];
    n = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    for (int k = 0; k < 3; ++k)
        r[k] /= n;
    u[0] = r[1] * f[2] - r[2] * f[1], u[1] = r[2] * f[0] - r[0] * f[2],
    u[2] = r[0] * f[1] - r[1] * f[0];
    /* columns: right, up, backward (-f), centre */
    snprintf(out, size, "[[%.9f, %.9f, %.9f, %g], [%.9f, %.9f, %.9f, %g], [%.9f, %.9f, %.9f, %g], "
                        "[0, 0, 0, 1]]",
             r[0], u[0], -f[0], eye[0], r[1], u[1], -f[1], eye[1], r[2], u[2], -f[2], eye[2]);
}

/* Projects world point p through a camera-to-world matrix's camera (OpenGL axes). */
static void gl_project(const double eye[3], double fx, double fy, double cx, double cy,
                       const float p[3], double *u, double *v) {
    double f[3] = {-eye[0], -eye[1], -eye[2]}, n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int k = 0; k < 3; ++k)
        f[k] /= n;
    double r[3] = {-f[2], 0, f[0]}; /* f x (0, 1, 0) */
    n = sqrt(r[0] * r[0] + r[2] * r[2]);
    r[0] /= n, r[2] /= n;
    double up[3] = {r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2],
                    r[0] * f[1] - r[1] * f[0]};
    double d[3] = {(double)p[0] - eye[0], (double)p[1] - eye[1], (double)p[2] - eye[2]};
    double x = d[0] * r[0] + d[1] * r[1] + d[2] * r[2];
    double y = d[0] * up[0] + d[1] * up[1] + d[2] * up[2];
    double z = d[0] * f[0] + d[1] * f[1] + d[2] * f[2]; /* depth along the view */
    *u = cx + fx * x / z;
    *v = cy - fy * y / z;
}

static void test_transforms(void) {
    pen_context *ctx = pen_context_create();
    mkdir("nerf", 0755);
    mkdir("nerf/train", 0755);
    /* r_1 has no w/h anywhere: its size comes from the image, found as r_1.png. */
    write_image(ctx, "nerf/train/r_1.png", 30, 20);
    write_image(ctx, "nerf/train/r_0.png", 50, 40);
    write_image(ctx, "nerf/x.png", 8, 8);
    const double eye0[3] = {0.5, 1.0, 3.0}, eye1[3] = {-2.0, 0.8, 1.5};
    char m0[512], m1[512], text[2048];
    c2w_json(eye0, m0, sizeof m0);
    c2w_json(eye1, m1, sizeof m1);
    snprintf(text, sizeof text,
             "{\"camera_angle_x\": 0.6911112, \"frames\": [\n"
             " {\"file_path\": \"./train/r_0.png\", \"w\": 50, \"h\": 40, \"transform_matrix\": %s},\n"
             " {\"file_path\": \"./train/r_1\", \"fl_x\": 33, \"fl_y\": 31, \"cx\": 14.5, "
             "\"cy\": 10.25, \"transform_matrix\": %s}]}",
             m0, m1);
    write_text("nerf/transforms.json", text);
    pen_camera_set set;
    CHECK_MSG(pen_camera_set_load_transforms(ctx, "nerf/transforms.json", &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(set.count == 2);
    if (set.count == 2) {
        CHECK(strcmp(set.images[0], "nerf/./train/r_0.png") == 0);
        CHECK_MSG(strcmp(set.images[1], "nerf/./train/r_1.png") == 0, "%s", set.images[1]);
        CHECK(set.cameras[0].width == 50 && set.cameras[0].height == 40);
        CHECK(set.cameras[1].width == 30 && set.cameras[1].height == 20);
        const double f0 = 25.0 / tan(0.5 * 0.6911112);
        for (int k = 0; k < 4; ++k) {
            double u, v, eu, ev;
            project(&set.cameras[0], POINTS[k], &u, &v);
            gl_project(eye0, f0, f0, 25.0, 20.0, POINTS[k], &eu, &ev);
            CHECK_NEAR(u, eu, 2e-3);
            CHECK_NEAR(v, ev, 2e-3);
            project(&set.cameras[1], POINTS[k], &u, &v);
            gl_project(eye1, 33, 31, 14.5, 10.25, POINTS[k], &eu, &ev);
            CHECK_NEAR(u, eu, 2e-3);
            CHECK_NEAR(v, ev, 2e-3);
        }
    }
    pen_camera_set_free(&set);
    /* Refusals name the key. */
    write_text("nerf/bad.json", "{\"frames\": [{\"file_path\": \"x.png\", \"w\": 8, \"h\": 8, "
                                "\"transform_matrix\": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], "
                                "[0, 0, 0, 1]]}]}");
    expect_error(pen_camera_set_load_transforms(ctx, "nerf/bad.json", &set), ctx,
                 "nerf/bad.json: frames[0]: needs \"fl_x\" or \"camera_angle_x\"");
    write_text("nerf/bad.json", "{\"fl_x\": 8, \"frames\": [{\"file_path\": \"x.png\", \"w\": 8, "
                                "\"h\": 8, \"transform_matrix\": [[1, 0, 0, 0], [0, 1, 0, 0], "
                                "[0, 0, -1, 3], [0, 0, 0, 1]]}]}");
    expect_error(pen_camera_set_load_transforms(ctx, "nerf/bad.json", &set), ctx,
                 "frames[0].transform_matrix: R has determinant -1");
    write_text("nerf/bad.json", "{\"fl_x\": 8, \"frames\": [{\"file_path\": \"missing\", "
                                "\"transform_matrix\": [[1, 0, 0, 0], [0, 1, 0, 0], "
                                "[0, 0, 1, 3], [0, 0, 0, 1]]}]}");
    expect_error(pen_camera_set_load_transforms(ctx, "nerf/bad.json", &set), ctx,
                 "frames[0].file_path: image nerf/missing.png not found");
    write_text("nerf/bad.json", "{\"fl_x\": 8, \"frames\": []}");
    expect_error(pen_camera_set_load_transforms(ctx, "nerf/bad.json", &set), ctx,
                 "nerf/bad.json: frames: expected an array of 1 .. 100000 frames");
    write_text("nerf/bad.json", "{\"views\": [{\"camera\": {\"width\": 8}, \"target\": \"a\"}]}");
    expect_error(pen_camera_set_load_views(ctx, "nerf/bad.json", &set), ctx,
                 "nerf/bad.json: views[0].camera.height");
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_colmap), TEST(test_colmap_errors), TEST(test_transforms))
