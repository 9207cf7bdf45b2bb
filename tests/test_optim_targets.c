/* Real targets of a task (src/optim/task.c, src/optim/views.c): 8-bit PNG targets decoded from
 * sRGB to linear (or taken as linear with "target_encoding": "linear"), in the single-view and
 * the multi-view forms. */
#define _POSIX_C_SOURCE 200809L
#include "check.h"

#include "optim/optim_internal.h"
#include "penumbra/penumbra.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define W 16
#define H 8

static char *path_in(const char *dir, const char *name) {
    static char buf[4][200];
    static int k = 0;
    k = (k + 1) % 4;
    snprintf(buf[k], sizeof buf[k], "%s/%s", dir, name);
    return buf[k];
}

static double to_srgb(double c) {
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

/* A task JSON text: an empty scene seen by a W x H camera, `target` or one view of it. */
static void task_text(char *out, size_t size, const char *target_part, const char *encoding) {
    char enc[64] = "";
    if (encoding) snprintf(enc, sizeof enc, ", \"target_encoding\": \"%s\"", encoding);
    snprintf(out, size,
             "{\"scene\": {\"camera\": {\"width\": %d, \"height\": %d, \"fov_y_deg\": 30, "
             "\"eye\": [0, 0, 1], \"target\": [0, 0, 0]}, \"sh_bands\": 1, "
             "\"lighting\": {\"sh\": [[1, 1, 1]]}, \"objects\": []}, "
             "\"optimize\": [\"lighting\"]%s, %s}",
             W, H, enc, target_part);
}

/* A linear ramp over [0, 1] (every channel its own phase) written as an 8-bit sRGB PNG comes
 * back, as a task's target, within half a code of the sRGB curve; "linear" takes the codes as
 * they are. */
static void test_srgb_targets(void) {
    char dir[] = "/tmp/pen_targets_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    pen_context *ctx = pen_context_create();
    pen_image lin = {0, 0, 0, NULL};
    CHECK(pen_image_create(ctx, W, H, 3, &lin) == PEN_OK);
    for (int p = 0; p < W * H; ++p)
        for (int c = 0; c < 3; ++c)
            lin.data[3 * p + c] = (float)fmod((p + 37.0 * c) / (W * H - 1.0), 1.0000001);
    CHECK(pen_image_save(ctx, path_in(dir, "t.png"), &lin) == PEN_OK);
    char json[1024];
    for (int form = 0; form < 2; ++form)
        for (int linear = 0; linear < 2; ++linear) {
            task_text(json, sizeof json,
                      form ? "\"views\": [{\"camera\": {\"width\": 16, \"height\": 8, \"fov_y_deg\": "
                             "30, \"eye\": [0, 0, 1], \"target\": [0, 0, 0]}, \"target\": \"t.png\"}]"
                           : "\"target\": \"t.png\"",
                      linear ? "linear" : (form ? NULL : "srgb"));
            pen_optim_task t;
            pen_status s = pen_optim_task_parse(ctx, json, path_in(dir, "task.json"), &t);
            CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
            if (s) continue;
            CHECK(t.target_linear == linear);
            const pen_image *img = form ? &t.views[0].target : &t.target;
            CHECK(img->width == W && img->height == H && img->channels == 3);
            double worst = 0.0;
            for (int i = 0; i < 3 * W * H; ++i) {
                /* decoded: linear within half a code in sRGB; raw: the code itself */
                const double x = (double)lin.data[i], y = (double)img->data[i];
                const double want = linear ? to_srgb(x) : x;
                const double got = linear ? y : to_srgb(y);
                const double e = fabs(linear ? got - want : got - to_srgb(want));
                if (e > worst) worst = e;
            }
            CHECK_MSG(worst <= 0.5 / 255.0 + 1e-6, "form %d linear %d: %g codes", form, linear,
                      worst * 255.0);
            pen_optim_task_free(&t);
        }
    /* the public setter reads PNG too, with the task's encoding */
    pen_optim_task t = pen_optim_task_default();
    t.scene.camera.width = W;
    t.scene.camera.height = H;
    CHECK_MSG(pen_optim_task_set_target(ctx, &t, path_in(dir, "t.png")) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(t.target.data && fabs(t.target.data[3] - lin.data[3]) < 0.01);
    pen_image_free(&t.target);
    free(t.target_path);
    /* errors name the key */
    task_text(json, sizeof json, "\"target\": \"t.png\"", "gamma");
    pen_optim_task bad;
    CHECK(pen_optim_task_parse(ctx, json, path_in(dir, "task.json"), &bad) == PEN_ERROR_PARSE);
    CHECK_MSG(strstr(pen_context_error(ctx), "task.json: target_encoding: "), "%s",
              pen_context_error(ctx));
    pen_image_free(&lin);
    pen_context_destroy(ctx);
    remove(path_in(dir, "t.png"));
    rmdir(dir);
}

RUN_TESTS(TEST(test_srgb_targets))
