/* The shadow-weighted loss of the inverse problems (src/optim/loss.c): its gradient against
 * central differences in double, alone and through the renderer, the plain mean at weight 0, and
 * the shadow mask on known answers (a darkened patch of an unshadowed render, with the lighting
 * known and with the lighting fitted from black). */
#include "optim_scenes.h"

#include "optim/optim_internal.h"

static unsigned long long seed = 99;

static pen_image random_image(int w, int h, double lo, double hi) {
    pen_image img;
    CHECK(pen_image_create(NULL, w, h, 3, &img) == PEN_OK);
    for (int i = 0; i < 3 * w * h; ++i)
        img.data[i] = (float)(lo + (hi - lo) * check_rand_(&seed));
    return img;
}

/* d loss / d pixel against central differences, for both losses, with and without weights.
 * The loss sums in double and a pixel is perturbed by an exactly representable step (its
 * actual change is taken in double), so the differences are exact up to rounding: for l2 the
 * loss is quadratic in a pixel, for l1 linear away from the kink (|r| > step is ensured). */
static void test_loss_grad_fd(void) {
    const int w = 7, h = 5, n = 3 * w * h;
    pen_image img = random_image(w, h, 0.0, 1.0), target = random_image(w, h, 0.0, 1.0);
    float weight[35];
    for (int p = 0; p < w * h; ++p)
        weight[p] = (float)(1.0 + 9.0 * check_rand_(&seed));
    for (int i = 0; i < n; ++i) /* keep l1 away from its kink */
        if (fabsf(img.data[i] - target.data[i]) < 0.01f) img.data[i] += 0.02f;
    for (int k = 0; k < PEN__OPTIM_LOSSES; ++k) /* every loss of the table (groups.h) */
        for (int weighted = 0; weighted < 2; ++weighted) {
            const pen_optim_loss kind = pen__optim_losses[k].kind;
            const char *name = pen__optim_losses[k].name;
            const float *wt = weighted ? weight : NULL;
            pen_image d = {0, 0, 0, NULL};
            CHECK(pen_image_create(NULL, w, h, 3, &d) == PEN_OK);
            pen__optim_loss_bwd(kind, &img, &target, wt, 0.7, &d);
            double worst = 0.0;
            for (int i = 0; i < n; ++i) {
                const float keep = img.data[i];
                const float hstep = 1.0f / 512.0f;
                double f[2];
                float moved[2];
                for (int sgn = 0; sgn < 2; ++sgn) {
                    img.data[i] = keep + (sgn ? -hstep : hstep);
                    moved[sgn] = img.data[i];
                    CHECK(pen__optim_loss_fwd(NULL, kind, &img, &target, wt, &f[sgn]) == PEN_OK);
                }
                img.data[i] = keep;
                const double fd = 0.7 * (f[0] - f[1]) / ((double)moved[0] - (double)moved[1]);
                worst = fmax(worst, fabs(fd - (double)d.data[i]) / fmax(fabs(fd), 1e-12));
            }
            printf("  %s %s: worst relative error %.3g\n", name, weighted ? "weighted" : "plain",
                   worst);
            CHECK_MSG(worst < 1e-6, "%s %s: worst relative error %.3g", name,
                      weighted ? "weighted" : "plain", worst);
            /* unweighted, the plain mean of render.h, its gradient alike */
            double plain = 0.0, mean = 0.0;
            CHECK(pen__optim_loss_fwd(NULL, kind, &img, &target, NULL, &mean) == PEN_OK);
            CHECK(pen__optim_losses[k].plain(NULL, &img, &target, &plain, NULL) == PEN_OK);
            CHECK_REL(plain, mean, 1e-12, 0);
            /* the backward adds */
            pen_image d2 = {0, 0, 0, NULL};
            CHECK(pen_image_create(NULL, w, h, 3, &d2) == PEN_OK);
            for (int i = 0; i < n; ++i)
                d2.data[i] = 1.0f;
            pen__optim_loss_bwd(kind, &img, &target, wt, 0.7, &d2);
            for (int i = 0; i < n; ++i)
                CHECK_NEAR(d2.data[i] - 1.0f, d.data[i], 1e-6);
            pen_image_free(&d);
            pen_image_free(&d2);
        }
    /* Equal weights are the plain mean, which is render.h's pen_loss_l2. */
    for (int p = 0; p < w * h; ++p)
        weight[p] = 3.0f;
    double a = 0.0, b = 0.0, c = 0.0;
    CHECK(pen__optim_loss_fwd(NULL, PEN_OPTIM_LOSS_L2, &img, &target, weight, &a) == PEN_OK);
    CHECK(pen__optim_loss_fwd(NULL, PEN_OPTIM_LOSS_L2, &img, &target, NULL, &b) == PEN_OK);
    CHECK(pen_loss_l2(NULL, &img, &target, &c, NULL) == PEN_OK);
    CHECK_REL(a, b, 1e-12, 0);
    CHECK_REL(b, c, 1e-12, 0);
    /* Weights summing to zero are refused. */
    for (int p = 0; p < w * h; ++p)
        weight[p] = 0.0f;
    CHECK(pen__optim_loss_fwd(NULL, PEN_OPTIM_LOSS_L2, &img, &target, weight, &a) ==
          PEN_ERROR_ARGUMENT);
    pen_image_free(&img);
    pen_image_free(&target);
}

/* The weighted loss through the renderer: d loss / d lighting from pen_render_bwd fed with the
 * weighted loss's gradient, against central differences of the loss of renders (the render is
 * linear in the SH lighting, so the l2 loss is quadratic in it and the difference exact up to
 * the float rounding of the images). */
static void test_weighted_lighting_grad(void) {
    pen_scene sc = os_egg(24, 0, 2);
    pen_render_options opt = pen_render_options_default();
    pen_image target = {0, 0, 0, NULL}, img = {0, 0, 0, NULL}, d_img = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(NULL, &sc, &opt, NULL, &target) == PEN_OK);
    float weight[24 * 24];
    for (int p = 0; p < 24 * 24; ++p)
        weight[p] = (float)(1.0 + 20.0 * check_rand_(&seed));
    for (int k = 0; k < 4; ++k) /* away from the target */
        for (int ch = 0; ch < 3; ++ch)
            sc.lighting.sh[k][ch] *= 0.7f + 0.1f * (float)k;
    pen_render_state *st = NULL;
    pen_render_grad grad;
    CHECK(pen_render_state_create(NULL, &st) == PEN_OK);
    CHECK(pen_render_grad_create(NULL, &sc, &grad) == PEN_OK);
    CHECK(pen_render_fwd(NULL, &sc, &opt, st, &img) == PEN_OK);
    CHECK(pen_image_create(NULL, 24, 24, 3, &d_img) == PEN_OK);
    pen__optim_loss_bwd(PEN_OPTIM_LOSS_L2, &img, &target, weight, 1.0, &d_img);
    pen_render_grad_zero(&grad);
    CHECK(pen_render_bwd(NULL, &sc, &opt, st, &d_img, PEN_GRAD_LIGHTING, &grad) == PEN_OK);
    double worst = 0.0;
    for (int k = 0; k < 4; ++k)
        for (int ch = 0; ch < 3; ++ch) {
            const float keep = sc.lighting.sh[k][ch];
            double f[2];
            for (int sgn = 0; sgn < 2; ++sgn) {
                sc.lighting.sh[k][ch] = keep + (sgn ? -0.05f : 0.05f);
                CHECK(pen_render_fwd(NULL, &sc, &opt, NULL, &img) == PEN_OK);
                CHECK(pen__optim_loss_fwd(NULL, PEN_OPTIM_LOSS_L2, &img, &target, weight,
                                          &f[sgn]) == PEN_OK);
            }
            sc.lighting.sh[k][ch] = keep;
            const double fd = (f[0] - f[1]) / 0.1;
            worst = fmax(worst, fabs(fd - (double)grad.sh[k][ch]) / fmax(fabs(fd), 1e-4));
        }
    printf("  lighting gradient: worst relative error %.3g\n", worst);
    CHECK_MSG(worst < 2e-3, "worst relative error %.3g", worst);
    pen_render_grad_free(&grad);
    pen_render_state_free(st);
    pen_image_free(&target);
    pen_image_free(&img);
    pen_image_free(&d_img);
    pen_scene_free(&sc);
}

/* The mask of a target that is the unshadowed render darkened to 40% in a patch: 0.6 in the
 * patch, 0 elsewhere, when U's lighting is known and when it is fitted from a black scene (the
 * second fit excludes the patch, so it recovers the lighting up to the ridge). */
static void test_shadow_mask(void) {
    const int S = 32;
    pen_scene sc = os_egg(S, 0, 3);
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_image target = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(NULL, &sc, &opt, NULL, &target) == PEN_OK);
    for (int y = 20; y < 28; ++y)
        for (int x = 4; x < 14; ++x)
            for (int ch = 0; ch < 3; ++ch)
                target.data[3 * (y * S + x) + ch] *= 0.4f;
    float mask[32 * 32];
    for (int fit = 0; fit < 2; ++fit) {
        if (fit) memset(sc.lighting.sh, 0, sizeof sc.lighting.sh); /* the fit must not need it */
        CHECK(pen__optim_shadow_mask(NULL, &sc, &target, fit, mask) == PEN_OK);
        double in = 0.0, out = 0.0;
        for (int y = 0; y < S; ++y)
            for (int x = 0; x < S; ++x) {
                const int patch = y >= 20 && y < 28 && x >= 4 && x < 14;
                const double m = mask[y * S + x];
                CHECK(m >= 0.0 && m <= 1.0);
                if (patch) {
                    in = fmax(in, fabs(m - 0.6));
                } else {
                    out = fmax(out, m);
                }
            }
        printf("  fit %d: patch off by %.3g, outside up to %.3g\n", fit, in, out);
        CHECK_MSG(in < (fit ? 1e-4 : 1e-5) && out < (fit ? 1e-4 : 1e-5),
                  "fit %d: patch off by %.3g, outside up to %.3g", fit, in, out);
    }
    pen_image_free(&target);
    pen_scene_free(&sc);
}

/* The losses are one table (groups.h): each kind has one row and one name; a kind that is no
 * loss (a task built in code) is refused by the run and by result.json, never written as
 * another's name. */
static void test_loss_table(void) {
    for (int k = 0; k < PEN__OPTIM_LOSSES; ++k) {
        CHECK(pen__optim_loss_find((int)pen__optim_losses[k].kind) == &pen__optim_losses[k]);
        for (int j = 0; j < k; ++j)
            CHECK(strcmp(pen__optim_losses[j].name, pen__optim_losses[k].name) != 0);
    }
    CHECK(pen_optim_task_default().loss == pen__optim_losses[0].kind);
    const int unknown = PEN__OPTIM_LOSSES; /* (the enum's values are 0 .. count - 1) */
    CHECK(pen__optim_loss_find(unknown) == NULL && pen__optim_loss_find(-1) == NULL);
    pen_context *ctx = pen_context_create();
    pen_optim_task t = pen_optim_task_default();
    t.scene = os_egg(16, 0, 1);
    t.optimize = PEN_OPTIM_LIGHTING;
    t.iterations = 2;
    t.loss = (pen_optim_loss)unknown;
    CHECK(pen_image_create(ctx, 16, 16, 3, &t.target) == PEN_OK);
    pen_optim_result r;
    CHECK(pen_optim_run(ctx, &t, NULL, &r) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), "task: loss: unknown loss 2"), "%s",
              pen_context_error(ctx));
    /* a result of the same task made with a known loss, then asked for with the unknown one */
    t.loss = PEN_OPTIM_LOSS_L1;
    CHECK_MSG(pen_optim_run(ctx, &t, NULL, &r) == PEN_OK, "%s", pen_context_error(ctx));
    char *json = NULL;
    CHECK(pen_optim_result_json(ctx, &t, NULL, &r, &json) == PEN_OK);
    cJSON *root = json ? cJSON_Parse(json) : NULL;
    const cJSON *loss = cJSON_GetObjectItemCaseSensitive(root, "loss");
    CHECK(cJSON_IsString(loss) && strcmp(loss->valuestring, "l1") == 0);
    cJSON_Delete(root);
    free(json);
    json = NULL;
    t.loss = (pen_optim_loss)unknown;
    CHECK(pen_optim_result_json(ctx, &t, NULL, &r, &json) == PEN_ERROR_ARGUMENT && !json);
    CHECK_MSG(strstr(pen_context_error(ctx), "result.json: unknown loss 2"), "%s",
              pen_context_error(ctx));
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_loss_grad_fd), TEST(test_weighted_lighting_grad), TEST(test_shadow_mask),
          TEST(test_loss_table))
