/* Real targets of a task (src/optim/task.c, src/optim/views.c, src/optim/params.c): 8-bit PNG
 * targets decoded from sRGB to linear (or taken as linear with "target_encoding": "linear"), in
 * the single-view and the multi-view forms; per-view exposures: the gradient of the objective
 * with respect to log s against central differences, their recovery from photos of other
 * exposures, the gauge (the first view's stays), result.json, and the tasks refused. */
#define _POSIX_C_SOURCE 200809L
#include "optim_scenes.h"

#include "optim/optim_internal.h"

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
            static const char *const forms[2] = {
                "\"target\": \"t.png\"",
                "\"views\": [{\"camera\": {\"width\": 16, \"height\": 8, \"fov_y_deg\": 30, "
                "\"eye\": [0, 0, 1], \"target\": [0, 0, 0]}, \"target\": \"t.png\"}]"};
            task_text(json, sizeof json, forms[form], linear ? "linear" : (form ? NULL : "srgb"));
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
    /* a view's exposure must be positive */
    task_text(json, sizeof json,
              "\"views\": [{\"camera\": {\"width\": 16, \"height\": 8, \"fov_y_deg\": 30, "
              "\"eye\": [0, 0, 1], \"target\": [0, 0, 0]}, \"target\": \"t.png\", "
              "\"exposure\": 0}]",
              NULL);
    CHECK(pen_optim_task_parse(ctx, json, path_in(dir, "task.json"), &bad) == PEN_ERROR_PARSE);
    CHECK_MSG(strstr(pen_context_error(ctx), "task.json: views[0].exposure: expected an exposure"),
              "%s", pen_context_error(ctx));
    pen_image_free(&lin);
    pen_context_destroy(ctx);
    remove(path_in(dir, "t.png"));
    rmdir(dir);
}

/* ---- Exposure ------------------------------------------------------------------------------- */

#define ES 24 /* pixels a side */

/* The ellipsoid under its low sun seen from `n` cameras on a circle; view v's target is the true
 * scene's render times truth_exposure[v]; the task's views start at exposure 1. */
static pen_optim_task exposure_task(int n, const double *truth_exposure, unsigned groups) {
    pen_context *ctx = pen_context_create();
    pen_optim_task t = pen_optim_task_default();
    /* Adam unless a test says otherwise (a lighting-only task's default is least squares) */
    t.lighting_solver = PEN_OPTIM_LIGHTING_ADAM;
    t.ground_truth = os_egg(ES, 0, 4);
    os_sun(&t.ground_truth, 6.0f, 0.5f);
    t.has_ground_truth = 1;
    t.scene = os_egg(ES, 0, 4);
    os_sun(&t.scene, 6.0f, 0.5f);
    t.optimize = groups;
    t.view_count = n;
    t.views = calloc((size_t)n, sizeof *t.views);
    for (int v = 0; v < n; ++v) {
        pen_optim_view *w = &t.views[v];
        const double a = 0.4 + 2.0 * M_PI * v / n;
        w->camera = t.scene.camera;
        w->camera.eye[0] = (float)(2.3 * sin(a));
        w->camera.eye[1] = 1.7f;
        w->camera.eye[2] = (float)(2.3 * cos(a));
        w->camera.target[0] = w->camera.target[2] = 0.0f;
        w->camera.target[1] = 0.35f;
        w->weight = 1.0;
        w->exposure = 1.0;
        const pen_scene seen = pen__optim_view_scene(&t.ground_truth, &w->camera);
        CHECK(pen_render_fwd(ctx, &seen, NULL, NULL, &w->target) == PEN_OK);
        pen__optim_view_expose(&w->target, truth_exposure[v]);
    }
    pen_context_destroy(ctx);
    return t;
}

/* The objective of the views at the task's exposures (and the gradients with grad). */
static double views_loss(pen_context *ctx, pen__optim_views *V, pen_optim_task *t, int grad) {
    double loss = 0.0;
    const pen_render_options opt = pen_render_options_default();
    CHECK(pen__optim_views_fwd(ctx, V, &t->scene, &opt, t->loss, grad, &loss) == PEN_OK);
    return loss;
}

/* dE/d(log s_v) = sum_p dE/dJ_p J_p (J = s I, the image the loss sees) against central
 * differences in log s (E is quadratic in s, so the only error is O(h^2) and the float image's
 * rounding), with weights and a half mask; and the lighting gradient of an exposed view, against
 * central differences in its DC coefficient (the render is affine in it). */
static void test_exposure_gradient(void) {
    const double truth[3] = {1.0, 1.6, 0.7};
    pen_optim_task t = exposure_task(3, truth, PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE);
    t.views[1].exposure = 1.25;
    t.views[2].exposure = 0.9;
    t.views[2].weight = 0.5;
    t.views[2].mask = malloc(sizeof(float) * ES * ES);
    for (int p = 0; p < ES * ES; ++p)
        t.views[2].mask[p] = p % ES < ES / 2 ? 1.0f : 0.0f;
    t.scene.lighting.sh[0][0] *= 0.8f; /* off the truth: a gradient to see */
    pen_context *ctx = pen_context_create();
    pen__optim_views V;
    CHECK(pen__optim_views_init(ctx, &V, &t, 0.0, 0) == PEN_OK);
    const pen_optim_settings set = pen_optim_settings_default();
    CHECK(pen__optim_views_plan(ctx, &V, &t.scene, &set, PEN_GRAD_LIGHTING) == PEN_OK);
    views_loss(ctx, &V, &t, 1);
    double analytic[3];
    memcpy(analytic, V.d_exposure, sizeof analytic);
    pen_render_grad g;
    CHECK(pen_render_grad_create(ctx, &t.scene, &g) == PEN_OK);
    pen_render_grad_zero(&g);
    const pen_render_options opt = pen_render_options_default();
    CHECK(pen__optim_views_bwd(ctx, &V, &t.scene, &opt, &g) == PEN_OK);
    const double h = 1e-3;
    for (int v = 0; v < 3; ++v) {
        const double s0 = t.views[v].exposure;
        t.views[v].exposure = s0 * exp(h);
        const double up = views_loss(ctx, &V, &t, 0);
        t.views[v].exposure = s0 * exp(-h);
        const double down = views_loss(ctx, &V, &t, 0);
        t.views[v].exposure = s0;
        const double fd = (up - down) / (2.0 * h);
        printf("  view %d: dE/dlog s %.8g, central difference %.8g\n", v, analytic[v], fd);
        CHECK_REL(analytic[v], fd, 1e-4, 1e-9);
    }
    const double l0 = (double)t.scene.lighting.sh[0][0], hl = 1e-2;
    t.scene.lighting.sh[0][0] = (float)(l0 + hl);
    const double up = views_loss(ctx, &V, &t, 0);
    t.scene.lighting.sh[0][0] = (float)(l0 - hl);
    const double down = views_loss(ctx, &V, &t, 0);
    t.scene.lighting.sh[0][0] = (float)l0;
    const double fd = (up - down) / (2.0 * hl);
    printf("  dE/dL00: %.8g, central difference %.8g\n", (double)g.sh[0][0], fd);
    CHECK_REL((double)g.sh[0][0], fd, 2e-3, 1e-9);
    pen_render_grad_free(&g);
    pen__optim_views_free_run(&V);
    pen_context_destroy(ctx);
    pen_optim_task_free(&t);
}

/* Three photos of the scene at exposures 1, 1.6 and 0.7, the lighting 20% too dim to start:
 * lighting + exposure bring views 1 and 2 to their exposures relative to view 0's (the gauge,
 * which stays at 1) and the lighting to the truth. result.json lists the exposures and the
 * gauge. */
static pen_optim_task dim_task(unsigned groups) {
    static const double truth[3] = {1.0, 1.6, 0.7};
    pen_optim_task t = exposure_task(3, truth, groups);
    t.init_black = 0;
    for (int k = 0; k < 16; ++k)
        for (int c = 0; c < 3; ++c)
            t.scene.lighting.sh[k][c] *= 0.8f;
    t.iterations = 200;
    t.lr.exposure = 0.02f;
    return t;
}

static void test_exposure_recovery(void) {
    const double truth[3] = {1.0, 1.6, 0.7};
    pen_context *ctx = pen_context_create();
    pen_optim_settings set = pen_optim_settings_default();
    pen_optim_result r;
    /* without the group: the lighting alone cannot explain the three exposures */
    pen_optim_task t = dim_task(PEN_OPTIM_LIGHTING);
    CHECK(pen_optim_run(ctx, &t, &set, &r) == PEN_OK);
    const double rmse_fixed = r.metrics.image_rmse, sky_fixed = r.metrics.lighting_rel_error_sky;
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    t = dim_task(PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE);
    char dir[] = "/tmp/pen_exposure_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    for (int v = 0; v < 3; ++v) { /* the targets as files: the views file names them */
        char name[32];
        snprintf(name, sizeof name, "t%d.exr", v);
        CHECK(pen_image_save(ctx, path_in(dir, name), &t.views[v].target) == PEN_OK);
        t.views[v].target_path = strdup(path_in(dir, name));
    }
    pen_status s = pen_optim_run(ctx, &t, &set, &r);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    if (s) {
        pen_context_destroy(ctx);
        pen_optim_task_free(&t);
        return;
    }
    printf("  without the group: image RMSE %.4g, sky lighting error %.4f\n", rmse_fixed,
           sky_fixed);
    printf("  with it: image RMSE %.4g, sky lighting error %.4f\n", r.metrics.image_rmse,
           r.metrics.lighting_rel_error_sky);
    CHECK(r.metrics.image_rmse < 0.25 * rmse_fixed);
    CHECK(r.metrics.lighting_rel_error_sky < 0.5 * sky_fixed);
    printf("  exposures %.4f %.4f %.4f (truth 1, 1.6, 0.7), %d iterations\n", t.views[0].exposure,
           t.views[1].exposure, t.views[2].exposure, r.iterations);
    CHECK(t.views[0].exposure == 1.0);
    for (int v = 1; v < 3; ++v)
        CHECK_REL(t.views[v].exposure, truth[v], 0.03, 0.0);
    char *json = NULL;
    CHECK(pen_optim_result_json(ctx, &t, &set, &r, &json) == PEN_OK);
    CHECK(json && strstr(json, "\"exposure_fixed_view\"") && strstr(json, "\"exposure\":"));
    free(json);
    /* views.json of the outputs: a later task reads the recovered exposures back */
    CHECK(pen_mesh_save_obj(ctx, path_in(dir, "egg.obj"), &t.scene.objects[0].mesh) == PEN_OK);
    t.scene.objects[0].mesh_path = strdup(path_in(dir, "egg.obj"));
    CHECK_MSG(pen_optim_write(ctx, path_in(dir, "out"), &t, &set, &r) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_optim_task again;
    s = pen_optim_task_parse(ctx,
                             "{\"scene\": {\"camera\": {\"width\": 8, \"height\": 8, "
                             "\"fov_y_deg\": 30, \"eye\": [0, 0, 1], \"target\": [0, 0, 0]}, "
                             "\"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, "
                             "\"objects\": []}, "
                             "\"optimize\": [\"lighting\", \"exposure\"], "
                             "\"views\": \"out/views.json\"}",
                             path_in(dir, "task.json"), &again);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    for (int v = 0; !s && v < 3; ++v) {
        /* (cJSON writes 15 digits) */
        CHECK_REL(again.views[v].exposure, t.views[v].exposure, 1e-14, 0.0);
        CHECK(memcmp(again.views[v].target.data, t.views[v].target.data,
                     sizeof(float) * 3 * ES * ES) == 0);
    }
    if (!s) pen_optim_task_free(&again);
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    CHECK(system(cmd) == 0);
}

/* The least-squares lighting through exposures: with the exposures given as they were, the
 * solved lighting is the one solved from targets without them and the views' weights times s^2
 * (the same objective; within the float rounding of T/s); with the group, Adam moves the
 * exposures of views 1 and 2, the lighting solved afresh for each, and they come back as well
 * as with Adam on the lighting. */
static void test_exposure_least_squares(void) {
    static const double truth[3] = {1.0, 1.6, 0.7}, one[3] = {1.0, 1.0, 1.0};
    pen_context *ctx = pen_context_create();
    pen_optim_result r;
    double sh[2][3];
    for (int given = 0; given < 2; ++given) {
        pen_optim_task t = exposure_task(3, given ? truth : one, PEN_OPTIM_LIGHTING);
        for (int v = 0; v < 3; ++v) { /* the same objective: w (s I - s T)^2 = s^2 w (I - T)^2 */
            t.views[v].exposure = given ? truth[v] : 1.0;
            t.views[v].weight = given ? 1.0 : truth[v] * truth[v];
        }
        t.lighting_solver = PEN_OPTIM_LIGHTING_LEAST_SQUARES;
        t.lighting_ridge = 1e-4;
        pen_status s = pen_optim_run(ctx, &t, NULL, &r);
        CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
        for (int c = 0; c < 3; ++c)
            sh[given][c] = t.scene.lighting.sh[c][0];
        if (!s) pen_optim_result_free(&r);
        pen_optim_task_free(&t);
    }
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
        CHECK_REL(sh[1][c], sh[0][c], 1e-4, 1e-6);
        worst = fmax(worst, fabs(sh[1][c] - sh[0][c]) / fabs(sh[0][c]));
    }
    printf("  given exposures vs weights s^2: DC lighting within %.2g (relative)\n", worst);
    pen_optim_task t = exposure_task(3, truth, PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE);
    t.lighting_solver = PEN_OPTIM_LIGHTING_LEAST_SQUARES;
    t.lighting_ridge = 1e-4;
    t.iterations = 200;
    t.lr.exposure = 0.02f;
    pen_status s = pen_optim_run(ctx, &t, NULL, &r);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    if (!s) {
        printf("  least squares: exposures %.4f %.4f %.4f, sky lighting error %.4f, %d "
               "iterations\n",
               t.views[0].exposure, t.views[1].exposure, t.views[2].exposure,
               r.metrics.lighting_rel_error_sky, r.iterations);
        CHECK(t.views[0].exposure == 1.0);
        for (int v = 1; v < 3; ++v)
            CHECK_REL(t.views[v].exposure, truth[v], 0.03, 0.0);
        pen_optim_result_free(&r);
    }
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
}

/* The tasks the group cannot serve are refused with one line saying why. */
static void test_exposure_refused(void) {
    const double truth[2] = {1.0, 1.0};
    pen_context *ctx = pen_context_create();
    static const struct {
        int views;
        unsigned groups;
        const char *message;
    } cases[] = {
        {0, PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE, "a single-view task has none to move"},
        {1, PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE, "one view has none to move"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        pen_optim_task t = exposure_task(cases[i].views ? cases[i].views : 1, truth,
                                         cases[i].groups);
        if (!cases[i].views) { /* the single-view form of the same */
            t.target = t.views[0].target;
            t.views[0].target.data = NULL;
            t.scene.camera = t.views[0].camera;
            pen__optim_views_free(t.views, t.view_count);
            t.views = NULL;
            t.view_count = 0;
        }
        pen_optim_result r;
        CHECK(pen_optim_run(ctx, &t, NULL, &r) == PEN_ERROR_ARGUMENT);
        CHECK_MSG(strstr(pen_context_error(ctx), cases[i].message), "%zu: %s", i,
                  pen_context_error(ctx));
        pen_optim_task_free(&t);
    }
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_srgb_targets), TEST(test_exposure_gradient), TEST(test_exposure_recovery),
          TEST(test_exposure_least_squares), TEST(test_exposure_refused))
