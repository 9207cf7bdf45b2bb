/* Inputs at their bounds, each made here: files penumbra writes read back (a calibrated camera
 * far from the origin looking away: COLMAP import, scene and views files, cameras built in code),
 * COLMAP text with a NUL byte, lens distortion and projective rows in a transforms.json, the
 * exposure group's gauge left out of the objective, view exposures and target values that would
 * overflow mid-run, and the minimum disk-light radius in the renderer and the reference. Every
 * refusal is one line naming the file and the place (line, key, pixel). */
#define _POSIX_C_SOURCE 200809L
#include "check.h"
#include "penumbra/penumbra.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>
#include <sys/stat.h>
#include <unistd.h>

static char dir_[64];

/* dir_/name (a few at a time). */
static const char *at(const char *name) {
    static char buf[4][256];
    static int k = 0;
    k = (k + 1) % 4;
    snprintf(buf[k], sizeof buf[k], "%s/%s", dir_, name);
    return buf[k];
}

static void write_bytes(const char *path, const char *data, size_t size) {
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f) return;
    CHECK(fwrite(data, 1, size, f) == size);
    fclose(f);
}

static void write_text(const char *path, const char *text) { write_bytes(path, text, strlen(text)); }

/* A w x h image of one value everywhere. */
static void write_image(pen_context *ctx, const char *path, int w, int h, float value) {
    pen_image img;
    CHECK(pen_image_create(ctx, w, h, 3, &img) == PEN_OK);
    for (size_t i = 0; img.data && i < 3 * (size_t)w * (size_t)h; ++i)
        img.data[i] = value;
    CHECK_MSG(pen_image_save(ctx, path, &img) == PEN_OK, "%s", pen_context_error(ctx));
    pen_image_free(&img);
}

static void expect_error(pen_status s, pen_context *ctx, const char *text) {
    CHECK_MSG(s != PEN_OK, "accepted; expected \"%s\"", text);
    const char *e = pen_context_error(ctx);
    CHECK_MSG(strstr(e, text) != NULL, "\"%s\" lacks \"%s\"", e, text);
    CHECK_MSG(strchr(e, '\n') == NULL, "not one line: \"%s\"", e);
}

static int within_bound(const float v[3]) {
    for (int k = 0; k < 3; ++k)
        if (!((double)v[k] >= -PEN_SCENE_MAX_COORD && (double)v[k] <= PEN_SCENE_MAX_COORD))
            return 0;
    return 1;
}

/* The two cameras look the same way from the same place, with the same intrinsics. */
static void same_frame(const pen_camera *a, const pen_camera *b, const char *what) {
    float ra[3], ua[3], fa[3], rb[3], ub[3], fb[3];
    pen_camera_frame(a, ra, ua, fa);
    pen_camera_frame(b, rb, ub, fb);
    for (int k = 0; k < 3; ++k) {
        CHECK_MSG(a->eye[k] == b->eye[k], "%s: eye[%d] %.9g vs %.9g", what, k, (double)a->eye[k],
                  (double)b->eye[k]);
        CHECK_MSG(fabs((double)fa[k] - (double)fb[k]) <= 1e-6, "%s: forward[%d]", what, k);
        CHECK_MSG(fabs((double)ua[k] - (double)ub[k]) <= 1e-6, "%s: up[%d]", what, k);
        CHECK_MSG(fabs((double)ra[k] - (double)rb[k]) <= 1e-6, "%s: right[%d]", what, k);
    }
    CHECK(a->width == b->width && a->height == b->height && a->fx == b->fx && a->fy == b->fy &&
          a->cx == b->cx && a->cy == b->cy);
}

/* ---- 1. A camera far out looking away --------------------------------------------------------- */

/* A COLMAP model of two cameras far out looking away from the origin: image 1 from (0, 0, 9e5)
 * along +z (identity rotation), image 2 from 6e5 (1, 1, 1) along (1, 1, 1)/sqrt 3, where the old
 * target, the centre plus its distance to the origin along the view, was 1.2e6 on every axis. */
static void far_colmap(const char *model) {
    mkdir(model, 0755);
    char path[300];
    snprintf(path, sizeof path, "%s/cameras.txt", model);
    write_text(path, "1 PINHOLE 8 8 8 8 4 4\n");
    /* Image 2's rotation has rows right = f x (0, 1, 0), down = f x right, forward f; its unit
     * quaternion (w, x, y, z) to 9 digits. t = -R c with c along f: (0, 0, -6e5 sqrt 3). */
    char text[1024];
    snprintf(text, sizeof text,
             "# images\n"
             "1 1 0 0 0 0 0 -900000 1 a.exr\n\n"
             "2 0.115916896 0.364705200 0.279848142 0.880476239 0 0 %.3f 1 b.exr\n\n",
             -6e5 * sqrt(3.0));
    snprintf(path, sizeof path, "%s/images.txt", model);
    write_text(path, text);
}

static void test_far_camera_round_trip(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("a.exr"), 8, 8, 0.5f);
    write_image(ctx, at("b.exr"), 8, 8, 0.5f);
    far_colmap(at("far"));
    pen_camera_set set;
    CHECK_MSG(pen_camera_set_load_colmap(ctx, at("far"), dir_, &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(set.count == 2);
    for (int i = 0; i < set.count; ++i) {
        const pen_camera *c = &set.cameras[i];
        CHECK_MSG(within_bound(c->target), "view %d: target %g %g %g beyond the bound", i,
                  (double)c->target[0], (double)c->target[1], (double)c->target[2]);
        float r[3], u[3], f[3];
        pen_camera_frame(c, r, u, f);
        const double want = i == 0 ? 1.0 : 1.0 / sqrt(3.0); /* looking away from the origin */
        CHECK_NEAR(f[2], want, 1e-5);
        if (i == 1) {
            CHECK_NEAR(f[0], want, 1e-5);
            CHECK_NEAR(f[1], want, 1e-5);
        }
        CHECK_NEAR(c->eye[2], i == 0 ? 9e5 : 6e5, 0.07);
    }
    /* import-cameras' views file reads back to the same cameras, bit for bit */
    CHECK_MSG(pen_camera_set_save_views(ctx, at("far_views.json"), &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_camera_set back;
    CHECK_MSG(pen_camera_set_load_views(ctx, at("far_views.json"), &back) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(back.count == set.count);
    for (int i = 0; i < set.count && i < back.count; ++i) {
        CHECK(memcmp(&back.cameras[i], &set.cameras[i], sizeof(pen_camera)) == 0);
        same_frame(&back.cameras[i], &set.cameras[i], "views file");
    }
    pen_camera_set_free(&back);

    /* a scene with that pose as "world_to_camera", saved (as `penumbra optimize` saves its
     * scene) and loaded again */
    static const char *const scene_text =
        "{\"camera\": {\"width\": 8, \"height\": 8, \"intrinsics\": {\"fx\": 8, \"fy\": 8, "
        "\"cx\": 4, \"cy\": 4}, \"world_to_camera\": [[1, 0, 0, 0], [0, 1, 0, 0], "
        "[0, 0, 1, -900000], [0, 0, 0, 1]]}, \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, "
        "\"objects\": []}";
    pen_scene sc, sc2;
    CHECK_MSG(pen_scene_parse(ctx, scene_text, at("far_scene.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(within_bound(sc.camera.target));
    same_frame(&sc.camera, &set.cameras[0], "world_to_camera vs COLMAP");
    CHECK_MSG(pen_scene_save(ctx, at("far_saved.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK_MSG(pen_scene_load(ctx, at("far_saved.json"), &sc2) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(memcmp(&sc.camera, &sc2.camera, sizeof(pen_camera)) == 0);
    same_frame(&sc.camera, &sc2.camera, "scene file");
    pen_scene_free(&sc2);

    /* a camera built in code with its target beyond the bound: written pulled in along its ray */
    sc.camera.target[2] = 5e6f;
    CHECK_MSG(pen_scene_save(ctx, at("far_code.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK_MSG(pen_scene_load(ctx, at("far_code.json"), &sc2) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(within_bound(sc2.camera.target));
    same_frame(&sc.camera, &sc2.camera, "a target beyond the bound");
    pen_scene_free(&sc2);
    /* ... and one whose eye lies beyond it is refused before anything is written */
    sc.camera.eye[0] = 2e6f;
    expect_error(pen_scene_save(ctx, at("far_refused.json"), &sc), ctx,
                 "far_refused.json: camera.eye[0]: expected a number in [-1e+06, 1e+06], got "
                 "2e+06 (not written");
    CHECK(access(at("far_refused.json"), F_OK) != 0);
    set.cameras[1].eye[1] = -3e6f;
    expect_error(pen_camera_set_save_views(ctx, at("far_refused.json"), &set), ctx,
                 "far_refused.json: views[1].camera.eye[1]: expected a number");
    CHECK(access(at("far_refused.json"), F_OK) != 0);
    pen_scene_free(&sc);
    pen_camera_set_free(&set);

    /* a centre just inside the bound looking out of it: no target gives the direction */
    write_text(at("far/images.txt"), "1 1 0 0 0 0 0 -999999 1 a.exr\n\n");
    expect_error(pen_camera_set_load_colmap(ctx, at("far"), dir_, &set), ctx,
                 "far/images.txt:1: the camera centre lies 1 from the coordinate bound 1e+06 "
                 "and looks out of it");
    pen_context_destroy(ctx);
}

/* ---- 2. NUL bytes in COLMAP text -------------------------------------------------------------- */

static void test_colmap_nul(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("a.exr"), 8, 8, 0.5f);
    write_image(ctx, at("b.exr"), 8, 8, 0.5f);
    mkdir(at("nul"), 0755);
    write_text(at("nul/cameras.txt"), "1 PINHOLE 8 8 8 8 4 4\n");
    static const char images[] = "1 1 0 0 0 0 0 3 1 a.exr\n\n2 1 0 0 0 0 0 3 1 b.exr\n\n";
    write_text(at("nul/images.txt"), images);
    pen_camera_set set;
    CHECK_MSG(pen_camera_set_load_colmap(ctx, at("nul"), dir_, &set) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(set.count == 2);
    pen_camera_set_free(&set);
    /* a NUL at the start of line 3 once dropped image 2 and everything after it */
    char bad[sizeof images + 1];
    const size_t line3 = (size_t)(strstr(images, "2 1") - images);
    memcpy(bad, images, line3);
    bad[line3] = '\0';
    memcpy(bad + line3 + 1, images + line3, sizeof images - 1 - line3);
    write_bytes(at("nul/images.txt"), bad, sizeof images);
    expect_error(pen_camera_set_load_colmap(ctx, at("nul"), dir_, &set), ctx,
                 "nul/images.txt:3: NUL byte");
    CHECK(set.count == 0 && set.cameras == NULL);
    write_text(at("nul/images.txt"), images);
    static const char two[] = "1 PINHOLE 8 8 8 8 4 4\n\0002 PINHOLE 8 8 8 8 4 4\n";
    write_bytes(at("nul/cameras.txt"), two, sizeof two - 1);
    expect_error(pen_camera_set_load_colmap(ctx, at("nul"), dir_, &set), ctx,
                 "nul/cameras.txt:2: NUL byte");
    static const char mid[] = "1 PINHOLE 8 8\0008 8 4 4\n";
    write_bytes(at("nul/cameras.txt"), mid, sizeof mid - 1);
    expect_error(pen_camera_set_load_colmap(ctx, at("nul"), dir_, &set), ctx,
                 "nul/cameras.txt:1: NUL byte");
    pen_context_destroy(ctx);
}

/* ---- 3, 4. transforms.json: lens distortion, the matrix's last row --------------------------- */

/* A transforms.json of one frame (a.exr) with `top` and `frame` spliced in (each may be ""). */
static pen_status load_transforms(pen_context *ctx, const char *top, const char *frame,
                                  const char *matrix) {
    char text[1024];
    snprintf(text, sizeof text,
             "{%s\"fl_x\": 8, \"frames\": [{%s\"file_path\": \"a.exr\", \"transform_matrix\": "
             "%s}]}",
             top, frame,
             matrix ? matrix : "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]");
    write_text(at("transforms.json"), text);
    pen_camera_set set;
    pen_status s = pen_camera_set_load_transforms(ctx, at("transforms.json"), &set);
    pen_camera_set_free(&set);
    return s;
}

static void test_transforms_distortion(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("a.exr"), 8, 8, 0.5f);
    CHECK_MSG(load_transforms(ctx, "", "", NULL) == PEN_OK, "%s", pen_context_error(ctx));
    static const char *const keys[] = {"k1", "k2", "k3", "k4", "p1", "p2"};
    char part[64], msg[128];
    for (int k = 0; k < 6; ++k)
        for (int in_frame = 0; in_frame < 2; ++in_frame) {
            snprintf(part, sizeof part, "\"%s\": 0.01, ", keys[k]);
            snprintf(msg, sizeof msg, "transforms.json: %s%s: 0.01: lens distortion",
                     in_frame ? "frames[0]." : "", keys[k]);
            expect_error(load_transforms(ctx, in_frame ? "" : part, in_frame ? part : "", NULL),
                         ctx, msg);
            /* zero coefficients are a pinhole's */
            snprintf(part, sizeof part, "\"%s\": 0, ", keys[k]);
            CHECK_MSG(load_transforms(ctx, in_frame ? "" : part, in_frame ? part : "", NULL) ==
                          PEN_OK,
                      "%s", pen_context_error(ctx));
        }
    static const char *const models[] = {"OPENCV", "OPENCV_FISHEYE", "EQUIRECTANGULAR"};
    for (int m = 0; m < 3; ++m)
        for (int in_frame = 0; in_frame < 2; ++in_frame) {
            snprintf(part, sizeof part, "\"camera_model\": \"%s\", ", models[m]);
            snprintf(msg, sizeof msg,
                     "transforms.json: %scamera_model: camera model %s has lens distortion or "
                     "is not a pinhole",
                     in_frame ? "frames[0]." : "", models[m]);
            expect_error(load_transforms(ctx, in_frame ? "" : part, in_frame ? part : "", NULL),
                         ctx, msg);
        }
    /* a model with its coefficients is named by its model, the coefficient beside it */
    expect_error(load_transforms(ctx, "\"camera_model\": \"OPENCV\", \"k1\": 0, \"k2\": -0.02, ",
                                 "", NULL),
                 ctx, "transforms.json: camera_model: camera model OPENCV (k2 -0.02) has lens");
    CHECK_MSG(load_transforms(ctx, "\"camera_model\": \"PINHOLE\", ", "", NULL) == PEN_OK, "%s",
              pen_context_error(ctx));
    expect_error(load_transforms(ctx, "\"is_fisheye\": true, ", "", NULL), ctx,
                 "transforms.json: is_fisheye: a fisheye camera is not a pinhole");
    expect_error(load_transforms(ctx, "\"k1\": \"x\", ", "", NULL), ctx,
                 "transforms.json: k1: expected a distortion coefficient, got a string");
    pen_context_destroy(ctx);
}

static void test_transforms_matrix(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("a.exr"), 8, 8, 0.5f);
    /* the last row; then the rotation part: a scaled rotation, a shear, a reflection */
    static const char *const cases[][2] = {
        {"[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0.5, 1]]",
         "transforms.json: frames[0].transform_matrix[3]: the last row of a 4x4 pose must be "
         "[0, 0, 0, 1], got [0, 0, 0.5, 1]"},
        {"[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 2]]",
         "frames[0].transform_matrix[3]: the last row"},
        {"[[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 3], [0, 0, 0, 1]]",
         "frames[0].transform_matrix: R is not a rotation"},
        {"[[1, 0.1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]",
         "frames[0].transform_matrix: R is not a rotation"},
        {"[[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]",
         "frames[0].transform_matrix: R has determinant -1"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i)
        expect_error(load_transforms(ctx, "", "", cases[i][0]), ctx, cases[i][1]);
    pen_context_destroy(ctx);
}

/* ---- 5, 6. The optimizer's views: the exposure gauge, values that would overflow ------------ */

static const char *const CAM =
    "{\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 1, 3], \"target\": [0, 0, 0]}";

/* A task on an empty 8x8 scene over a ground ({`ground`}), the task's other keys in `rest`. */
static pen_status parse_text(pen_context *ctx, const char *ground, const char *rest,
                             pen_optim_task *t) {
    char text[2048];
    snprintf(text, sizeof text,
             "{\"scene\": {\"camera\": %s, \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, "
             "\"objects\": [], \"ground\": {%s}}, %s}",
             CAM, ground, rest);
    return pen_optim_task_parse(ctx, text, at("task.json"), t);
}

/* Two views of it (a.exr, b.exr), `v0` and `v1` spliced into the views' objects, `groups` the
 * optimize list. */
static pen_status parse_task(pen_context *ctx, const char *groups, const char *v0, const char *v1,
                             pen_optim_task *t) {
    char rest[1024];
    snprintf(rest, sizeof rest,
             "\"optimize\": [%s], \"iterations\": 3, "
             "\"views\": [{\"camera\": %s, \"target\": \"a.exr\"%s}, "
             "{\"camera\": %s, \"target\": \"b.exr\"%s}]",
             groups, CAM, v0, CAM, v1);
    return parse_text(ctx, "", rest, t);
}

/* Runs t to the end and checks that the loss and the lighting came out finite; frees t. */
static void run_finite(pen_context *ctx, pen_optim_task *t) {
    pen_optim_result r;
    CHECK_MSG(pen_optim_run(ctx, t, NULL, &r) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK_MSG(isfinite(r.final_loss), "final loss %g", r.final_loss);
    for (int k = 0; k < 3; ++k)
        CHECK(isfinite(t->scene.lighting.sh[0][k]));
    pen_optim_result_free(&r);
    pen_optim_task_free(t);
}

/* A context, and the two views' targets parse_task names. */
static pen_context *views_context(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("a.exr"), 8, 8, 0.5f);
    write_image(ctx, at("b.exr"), 8, 8, 0.4f);
    return ctx;
}

static void test_exposure_gauge(void) {
    pen_context *ctx = views_context();
    write_image(ctx, at("none.png"), 8, 8, 0.0f);
    write_image(ctx, at("all.png"), 8, 8, 1.0f);
    const char *exposure = "\"lighting\", \"exposure\"";
    pen_optim_task t;
    static const char *const out[] = {", \"mask\": \"none.png\"", ", \"weight\": 0"};
    static const char *const why[] = {"a mask without a pixel above 0.5", "weight 0"};
    for (int k = 0; k < 2; ++k) {
        char msg[256];
        snprintf(msg, sizeof msg,
                 "task.json: views: views[0] has %s, but with \"exposure\" its exposure is the "
                 "fixed gauge",
                 why[k]);
        expect_error(parse_task(ctx, exposure, out[k], "", &t), ctx, msg);
        CHECK(t.views == NULL && t.view_count == 0);
        /* without the group, or with views[1] left out instead, nothing is wrong */
        CHECK_MSG(parse_task(ctx, "\"lighting\"", out[k], "", &t) == PEN_OK, "%s",
                  pen_context_error(ctx));
        pen_optim_task_free(&t);
        CHECK_MSG(parse_task(ctx, exposure, "", out[k], &t) == PEN_OK, "%s",
                  pen_context_error(ctx));
        pen_optim_task_free(&t);
    }
    CHECK_MSG(parse_task(ctx, exposure, ", \"mask\": \"all.png\"", "", &t) == PEN_OK, "%s",
              pen_context_error(ctx));
    /* a task built in code is refused when the run starts, the same way */
    for (int p = 0; p < 64; ++p)
        t.views[0].mask[p] = 0.0f;
    pen_optim_result r;
    expect_error(pen_optim_run(ctx, &t, NULL, &r), ctx,
                 "task.json: views: views[0] has a mask without a pixel above 0.5");
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
}

static void test_overflow_bounds(void) {
    pen_context *ctx = views_context();
    const char *exposure = "\"lighting\", \"exposure\"";
    pen_optim_task t;
    /* exposures: a float denormal made the target over it infinite */
    expect_error(parse_task(ctx, exposure, "", ", \"exposure\": 1e-40", &t), ctx,
                 "task.json: views[1].exposure: expected an exposure in [1e-6, 1e6], got 1e-40");
    expect_error(parse_task(ctx, exposure, ", \"exposure\": 2e6", "", &t), ctx,
                 "task.json: views[0].exposure: expected an exposure in [1e-6, 1e6], got 2e+06");
    expect_error(parse_task(ctx, exposure, "", ", \"exposure\": 0", &t), ctx,
                 "views[1].exposure: expected an exposure");
    /* at the bounds the run stays finite */
    CHECK_MSG(parse_task(ctx, exposure, ", \"exposure\": 1e6", ", \"exposure\": 1e-6", &t) ==
                  PEN_OK,
              "%s", pen_context_error(ctx));
    run_finite(ctx, &t);

    /* target values: 3e38 made the solved lighting infinite ("non-finite SH coefficient") */
    write_image(ctx, at("huge.exr"), 8, 8, 0.5f);
    {
        pen_image img;
        CHECK(pen_image_load(ctx, at("huge.exr"), &img) == PEN_OK);
        img.data[3 * (2 * 8 + 5) + 1] = 3e38f;
        CHECK(pen_image_save(ctx, at("huge.exr"), &img) == PEN_OK);
        pen_image_free(&img);
    }
    char rest[1024];
    snprintf(rest, sizeof rest,
             "\"optimize\": [\"lighting\"], \"views\": [{\"camera\": %s, \"target\": \"huge.exr\"}]",
             CAM);
    expect_error(parse_text(ctx, "", rest, &t), ctx,
                 "task.json: views[0].target: huge.exr: pixel (5, 2) channel 1: 3e+38 outside "
                 "[-1e+09, 1e+09]");
    const char *single = "\"optimize\": [\"lighting\"], \"target\": \"huge.exr\"";
    expect_error(parse_text(ctx, "", single, &t), ctx, "task.json: target: ");
    expect_error(parse_text(ctx, "", single, &t), ctx,
                 "huge.exr: pixel (5, 2) channel 1: 3e+38 outside [-1e+09, 1e+09]");
    /* the bound itself runs, the least-squares lighting finite, with the largest weight and
     * the smallest exposure on a dark ground */
    write_image(ctx, at("bright.exr"), 8, 8, (float)PEN_SCENE_MAX_RADIANCE);
    snprintf(rest, sizeof rest,
             "\"optimize\": [\"lighting\"], \"lighting_solver\": \"least_squares\", "
             "\"views\": [{\"camera\": %s, \"target\": \"bright.exr\", \"weight\": 1e6}, "
             "{\"camera\": %s, \"target\": \"bright.exr\", \"exposure\": 1e-6}]",
             CAM, CAM);
    CHECK_MSG(parse_text(ctx, "\"albedo\": [0.01, 0.01, 0.01]", rest, &t) == PEN_OK, "%s",
              pen_context_error(ctx));
    run_finite(ctx, &t);
    pen_context_destroy(ctx);
}

/* ---- 8. What the optimizer writes reads back ------------------------------------------------- */

/* Removes the files of the folder dir_/name and the folder. */
static void remove_folder(const char *name) {
    DIR *d = opendir(at(name));
    if (!d) return;
    const struct dirent *e;
    char path[512];
    while ((e = readdir(d)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
        snprintf(path, sizeof path, "%s/%s", at(name), e->d_name);
        remove(path);
    }
    closedir(d);
    CHECK_MSG(rmdir(at(name)) == 0, "%s: not empty", at(name));
}

/* A 1e9 target on a ground of albedo 1e-6 solves by least squares to SH coefficients of about
 * 3.4e14, beyond what a scene file holds (PEN_SCENE_MAX_SH): the solved lighting is held to that
 * bound, as Adam's steps are (test_optim.c: test_adam_bounds), and the written scene.json loads
 * (and renders). */
static void test_written_scene_reads_back(void) {
    pen_context *ctx = pen_context_create();
    write_image(ctx, at("bright.exr"), 8, 8, (float)PEN_SCENE_MAX_RADIANCE);
    pen_optim_task t;
    CHECK_MSG(parse_text(ctx, "\"albedo\": [1e-6, 1e-6, 1e-6]",
                         "\"optimize\": [\"lighting\"], \"target\": \"bright.exr\"", &t) == PEN_OK,
              "%s", pen_context_error(ctx));
    pen_optim_result r;
    CHECK_MSG(pen_optim_run(ctx, &t, NULL, &r) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(r.solved && r.lighting_solver == PEN_OPTIM_LIGHTING_LEAST_SQUARES);
    for (int c = 0; c < 3; ++c) /* at the bound: the solve wanted more */
        CHECK_MSG(t.scene.lighting.sh[0][c] == (float)PEN_SCENE_MAX_SH, "%g",
                  (double)t.scene.lighting.sh[0][c]);
    CHECK_MSG(pen_optim_write(ctx, at("sh_out"), &t, NULL, &r) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_scene back;
    CHECK_MSG(pen_scene_load(ctx, at("sh_out/scene.json"), &back) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(back.lighting.sh[0][0] == t.scene.lighting.sh[0][0]);
    pen_image img = {0, 0, 0, NULL};
    pen_render_options opt = pen_render_options_default();
    CHECK_MSG(pen_render_fwd(ctx, &back, &opt, NULL, &img) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_image_free(&img);
    pen_scene_free(&back);
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    remove_folder("sh_out");
    pen_context_destroy(ctx);
}

/* Adam at rate 10 on the log exposure of a view whose target is 1e8 times brighter than the
 * render took its exposure to 1.7e9, and the written views.json was refused on reload (exposures
 * in [1e-6, 1e6], views.c): the log exposure is held to that range, and views.json reads back as
 * a later task's views. A task built in code with an exposure out of it is refused by the run. */
static void test_written_views_read_back(void) {
    pen_context *ctx = views_context();
    write_image(ctx, at("far_bright.exr"), 8, 8, 1e8f);
    char rest[1024];
    snprintf(rest, sizeof rest,
             "\"optimize\": [\"exposure\"], \"iterations\": 4, \"lr\": {\"exposure\": 10}, "
             "\"views\": [{\"camera\": %s, \"target\": \"a.exr\"}, "
             "{\"camera\": %s, \"target\": \"far_bright.exr\"}]",
             CAM, CAM);
    pen_optim_task t;
    CHECK_MSG(parse_text(ctx, "", rest, &t) == PEN_OK, "%s", pen_context_error(ctx));
    pen_optim_result r;
    CHECK_MSG(pen_optim_run(ctx, &t, NULL, &r) == PEN_OK, "%s", pen_context_error(ctx));
    const double x = t.views[1].exposure;
    CHECK_MSG(x <= 1e6 && x > 0.99999e6, "exposure %.17g", x); /* at the bound */
    CHECK_MSG(pen_optim_write(ctx, at("views_out"), &t, NULL, &r) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_optim_task back;
    CHECK_MSG(parse_text(ctx, "",
                         "\"optimize\": [\"lighting\"], \"views\": \"views_out/views.json\"",
                         &back) == PEN_OK,
              "%s", pen_context_error(ctx));
    /* (the file's 15 digits: cJSON prints a double that way when it reads back within rounding) */
    CHECK_MSG(back.view_count == 2 && back.views && fabs(back.views[1].exposure - x) <= 1e-9 * x,
              "%d views, exposure %.17g", back.view_count,
              back.views ? back.views[1].exposure : 0.0);
    pen_optim_task_free(&back);
    pen_optim_result_free(&r);
    remove_folder("views_out");
    /* built in code: refused when the run starts, as the reader refuses it */
    t.views[1].exposure = 2e6;
    expect_error(pen_optim_run(ctx, &t, NULL, &r), ctx,
                 "task.json: views[1].exposure: expected an exposure in [1e-6, 1e6] (or 0, which "
                 "stands for 1), got 2e+06");
    t.views[1].exposure = 0.0; /* (stands for 1) */
    CHECK_MSG(pen_optim_run(ctx, &t, NULL, &r) == PEN_OK, "%s", pen_context_error(ctx));
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
}

/* ---- 7. The minimum disk-light radius --------------------------------------------------------- */

static pen_status light_scene(pen_context *ctx, const char *radius, pen_scene *sc) {
    char text[1024];
    snprintf(text, sizeof text,
             "{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 1, 3], "
             "\"target\": [0, 0, 0]}, \"sh_bands\": 1, \"lighting\": {\"sh\": [[0.1, 0.1, 0.1]], "
             "\"lights\": [{\"direction\": [0, 1, 0.2], \"angular_radius_deg\": %s, "
             "\"irradiance\": [2, 2, 2]}]}, \"objects\": [], \"ground\": {}}",
             radius);
    return pen_scene_parse(ctx, text, at("light.json"), sc);
}

/* The renderer and the reference on sc: both PEN_OK, or both refused with the same reason. */
static void render_both(pen_context *ctx, const pen_scene *sc, int ok, const char *why) {
    pen_render_options opt = pen_render_options_default();
    pen_image img = {0, 0, 0, NULL};
    pen_status s = pen_render_fwd(ctx, sc, &opt, NULL, &img);
    if (ok) CHECK_MSG(s == PEN_OK, "render: %s", pen_context_error(ctx));
    else expect_error(s, ctx, why);
    pen_image_free(&img);
    pen_reference *ref = NULL;
    s = pen_reference_create(ctx, sc, PEN_REFERENCE_LIGHTING_SH, &ref);
    if (!s) s = pen_reference_render(ctx, ref, 1, 1, &img);
    if (ok) CHECK_MSG(s == PEN_OK, "reference: %s", pen_context_error(ctx));
    else expect_error(s, ctx, why);
    pen_image_free(&img);
    pen_reference_destroy(ref);
}

static void test_light_radius(void) {
    pen_context *ctx = pen_context_create();
    pen_scene sc;
    CHECK_MSG(light_scene(ctx, "0.01", &sc) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(sc.lighting.light_count == 1 && sc.lighting.lights[0].angular_radius_deg == 0.01f);
    render_both(ctx, &sc, 1, NULL);
    /* saved and loaded, it stays the same float and renders */
    CHECK_MSG(pen_scene_save(ctx, at("light_saved.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_scene back;
    CHECK_MSG(pen_scene_load(ctx, at("light_saved.json"), &back) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(back.lighting.lights[0].angular_radius_deg == 0.01f);
    pen_scene_free(&back);
    /* the float below it, set in code, is refused by both */
    sc.lighting.lights[0].angular_radius_deg = nextafterf(0.01f, 0.0f);
    render_both(ctx, &sc, 0, "angular");
    sc.lighting.lights[0].angular_radius_deg = 45.0f;
    render_both(ctx, &sc, 1, NULL);
    sc.lighting.lights[0].angular_radius_deg = nextafterf(45.0f, 90.0f);
    render_both(ctx, &sc, 0, "angular");
    pen_scene_free(&sc);
    /* in a file, 0.0099 is refused where it is read, so with one message for both commands */
    expect_error(light_scene(ctx, "0.0099", &sc), ctx,
                 "light.json: lighting.lights[0].angular_radius_deg: expected a number of degrees "
                 "in [0.01, 45], got 0.0099");
    pen_context_destroy(ctx);
}

static void setup(void) {
    snprintf(dir_, sizeof dir_, "/tmp/pen_inputs_XXXXXX");
    CHECK(mkdtemp(dir_) != NULL);
}

static void teardown(void) {
    static const char *const files[] = {
        "a.exr", "b.exr", "none.png", "all.png", "huge.exr", "bright.exr", "transforms.json",
        "far_views.json", "far_saved.json", "far_code.json", "light_saved.json", "far/cameras.txt",
        "far/images.txt", "nul/cameras.txt", "nul/images.txt", "far", "nul", "far_bright.exr"};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; ++i)
        remove(at(files[i]));
    CHECK_MSG(rmdir(dir_) == 0, "%s: left files behind", dir_);
}

RUN_TESTS(TEST(setup), TEST(test_far_camera_round_trip), TEST(test_colmap_nul),
          TEST(test_transforms_distortion), TEST(test_transforms_matrix),
          TEST(test_exposure_gauge), TEST(test_overflow_bounds), TEST(test_light_radius),
          TEST(test_written_scene_reads_back), TEST(test_written_views_read_back), TEST(teardown))
