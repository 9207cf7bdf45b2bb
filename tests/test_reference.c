/* The Embree reference renderer against closed-form answers, its convergence rate, determinism
 * and error handling. Scenes are built in code. Analytic facts used:
 *   - constant radiance L over the upper hemisphere: E = pi L, so L_o = rho L;
 *   - SH lighting with coefficients L_lm, unoccluded: E(n) = sum_l A_l sum_m L_lm Y_lm(n) with
 *     A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4, A_3 = 0 (odd bands above 1 vanish);
 *   - a square of half-side a, parallel to the receiver at height h and centred above it, blocks
 *     4 F of the cosine-weighted hemisphere, with the corner form factor (X = Y = a / h)
 *     F = 1/(2 pi) [X/sqrt(1+X^2) atan(Y/sqrt(1+X^2)) + Y/sqrt(1+Y^2) atan(X/sqrt(1+Y^2))].
 * Tolerances of Monte-Carlo estimates are statistical: a multiple of the standard error the test
 * measures from the samples themselves. */
#include "check.h"

#include "penumbra/penumbra.h"
#include "reference/internal.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#define PI 3.14159265358979323846

/* ---- Scene building ------------------------------------------------------------------------ */

typedef struct test_scene {
    pen_scene scene;
    pen_object objects[2];
    float positions[2][12];
    uint32_t indices[2][6];
    float uvs[8];
    uint32_t uv_indices[6];
} test_scene;

/* A camera looking straight down at the origin from height 3, a ground of albedo rho at y = 0,
 * no objects, no lighting yet, constant background. */
static void scene_ground(test_scene *t, int w, int h, float rho) {
    memset(t, 0, sizeof *t);
    pen_scene *s = &t->scene;
    s->camera = (pen_camera){w, h, 40.0f, {0, 3, 0}, {0, 0, 0}, {0, 0, -1}, 0, 0, 0, 0};
    s->sh_bands = 3;
    s->lighting.scale = 1.0f;
    s->ground = (pen_ground){1, 0.0f, {rho, rho, rho}, 4.0f};
    s->background[0] = 0.25f;
    s->objects = t->objects;
}

/* Adds a square of half-side a at height y, in the plane y (normal +Y), as object k. */
static void add_square(test_scene *t, int k, float a, float y, float rho) {
    const float p[12] = {-a, y, -a, -a, y, a, a, y, a, a, y, -a};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    memcpy(t->positions[k], p, sizeof p);
    memcpy(t->indices[k], idx, sizeof idx);
    pen_object *o = &t->objects[k];
    o->mesh.vertex_count = 4;
    o->mesh.triangle_count = 2;
    o->mesh.positions = t->positions[k];
    o->mesh.indices = t->indices[k];
    o->albedo[0] = o->albedo[1] = o->albedo[2] = rho;
    o->pose.scale = 1.0f;
    if (t->scene.object_count < k + 1) t->scene.object_count = k + 1;
}

/* Constant radiance L as SH lighting: only the DC term, L * sqrt(4 pi). */
static void constant_sh(pen_scene *s, double L) {
    for (int ch = 0; ch < 3; ++ch)
        s->lighting.sh[0][ch] = (float)(L * sqrt(4 * PI));
}

/* Real SH up to l = 2 (Condon-Shortley phase), written out independently of the library. */
static void sh9(const double n[3], double y[9]) {
    double x = n[0], yy = n[1], z = n[2];
    y[0] = 0.282094791773878;
    y[1] = -0.488602511902920 * yy;
    y[2] = 0.488602511902920 * z;
    y[3] = -0.488602511902920 * x;
    y[4] = 1.092548430592079 * x * yy;
    y[5] = -1.092548430592079 * yy * z;
    y[6] = 0.315391565252520 * (3 * z * z - 1);
    y[7] = -1.092548430592079 * x * z;
    y[8] = 0.546274215296040 * (x * x - yy * yy);
}

/* Closed-form unoccluded irradiance of SH lighting (bands <= 4; band 3 contributes nothing). */
static double sh_irradiance(float sh[][3], int ch, const double n[3]) {
    static const double A[3] = {PI, 2 * PI / 3, PI / 4};
    double y[9], e = 0;
    sh9(n, y);
    for (int i = 0; i < 9; ++i)
        e += A[i == 0 ? 0 : i < 4 ? 1 : 2] * (double)sh[i][ch] * y[i];
    return e;
}

/* Seeded SH lighting: a DC term large enough to keep radiance mostly positive, random l = 1..3. */
static void random_sh(float sh[][3], int bands, unsigned long long seed) {
    memset(sh, 0, sizeof(float) * 3 * PEN_SH_MAX_COEFFS);
    for (int i = 0; i < bands * bands; ++i)
        for (int ch = 0; ch < 3; ++ch)
            sh[i][ch] = i == 0 ? (float)(2.0 + check_rand_(&seed))
                               : (float)(0.6 * (check_rand_(&seed) - 0.5));
}

/* Fills an equirectangular map with the SH function (texel centres), through the library's
 * documented (u, v) <-> direction map. */
static void envmap_from_sh(pen_image *env, float sh[][3]) {
    for (int y = 0; y < env->height; ++y)
        for (int x = 0; x < env->width; ++x) {
            float d[3];
            pen_envmap_direction((x + 0.5f) / env->width, (y + 0.5f) / env->height, d);
            double dd[3] = {d[0], d[1], d[2]}, Y[9];
            sh9(dd, Y);
            for (int ch = 0; ch < 3; ++ch) {
                double v = 0;
                for (int i = 0; i < 9; ++i)
                    v += (double)sh[i][ch] * Y[i];
                env->data[3 * ((size_t)y * env->width + x) + ch] = (float)v;
            }
        }
}

static pen_reference *make_ref(pen_context *ctx, const pen_scene *s, pen_reference_lighting l) {
    pen_reference *ref = NULL;
    pen_status st = pen_reference_create(ctx, s, l, &ref);
    CHECK_MSG(st == PEN_OK, "%s", pen_context_error(ctx));
    return ref;
}

/* Mean and standard error (per channel 0) of the irradiance estimated as `batches` independent
 * batch means, so the tolerance comes from the estimator's own spread. */
static void irradiance_stats(pen_context *ctx, const pen_reference *ref, const float x[3],
                             const float n[3], int batches, int per_batch, double mean[3],
                             double *se) {
    double sum[3] = {0, 0, 0}, sum2 = 0;
    for (int b = 0; b < batches; ++b) {
        float E[3];
        CHECK(pen_reference_irradiance(ctx, ref, x, n, per_batch, 1000 + b, E) == PEN_OK);
        for (int ch = 0; ch < 3; ++ch)
            sum[ch] += (double)E[ch];
        sum2 += (double)E[0] * (double)E[0];
    }
    for (int ch = 0; ch < 3; ++ch)
        mean[ch] = sum[ch] / batches;
    double var = fmax(sum2 / batches - mean[0] * mean[0], 0.0) * batches / (batches - 1);
    *se = sqrt(var / batches);
}

/* ---- The envmap sampler -----------------------------------------------------------------------
 */

/* Texel frequencies of many draws match the probabilities (luminance x sin(theta)), black texels
 * are never drawn, and the density integrates to 1 over the sphere. */
static void test_envmap_sampler(void) {
    pen_context *ctx = pen_context_create();
    const int w = 8, h = 4, draws = check_quick_() ? 50000 : 400000;
    pen_image env;
    CHECK(pen_image_create(ctx, w, h, 3, &env) == PEN_OK);
    unsigned long long seed = 3;
    for (int i = 0; i < w * h; ++i)
        for (int ch = 0; ch < 3; ++ch)
            env.data[3 * i + ch] = i % 5 == 0 ? (ch == 0 ? -1.0f : 0.0f) /* black after clamping */
                                              : (float)(0.1 + 3 * check_rand_(&seed));
    pen__envmap_sampler s;
    CHECK(pen__envmap_sampler_init(ctx, &env, &s) == PEN_OK);
    int count[8 * 4] = {0};
    pen__rng rng = pen__rng_stream(7, 0, 0);
    for (int k = 0; k < draws; ++k) {
        float r[3] = {pen__rng_next(&rng), pen__rng_next(&rng), pen__rng_next(&rng)}, u, v;
        int tx, ty;
        pen__envmap_sampler_sample(&s, pen__rng_next_double(&rng), r, &u, &v, &tx, &ty);
        CHECK(u >= tx / (float)w && u <= (tx + 1) / (float)w && v >= ty / (float)h &&
              v <= (ty + 1) / (float)h);
        ++count[ty * w + tx];
    }
    /* expected probabilities from the definition: clamped luminance x sin(theta at row centre) */
    double want[8 * 4], sum = 0, integral = 0;
    for (int i = 0; i < w * h; ++i) {
        const float *t = env.data + 3 * i;
        double lum = 0.2126 * fmax((double)t[0], 0) + 0.7152 * fmax((double)t[1], 0) +
                     0.0722 * fmax((double)t[2], 0);
        want[i] = lum * sin(PI * (i / w + 0.5) / h);
        sum += want[i];
    }
    for (int i = 0; i < w * h; ++i) {
        double p = want[i] / sum;
        CHECK_NEAR(s.texel_prob[i], p, 1e-6);
        double sd = sqrt(draws * p * (1 - p));
        CHECK_MSG(fabs(count[i] - draws * p) <= 5 * sd + 1, "texel %d: %d draws, expected %g", i,
                  count[i], draws * p);
        if (i % 5 == 0) CHECK(count[i] == 0 && p == 0);
        /* integral of the density over the texel's solid angle, by the midpoint rule in v */
        int ty = i / w;
        for (int k = 0; k < 64; ++k) {
            double vv = (ty + (k + 0.5) / 64) / h, st = sin(PI * vv);
            integral += (double)pen__envmap_sampler_pdf(&s, i % w, ty, (float)st) * 2 * PI * PI *
                        st / (64.0 * w * h);
        }
    }
    CHECK_NEAR(integral, 1.0, 1e-5);
    pen__envmap_sampler_free(&s);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

/* ---- Analytic: unoccluded plane ----------------------------------------------------------------
 */

static void test_constant_sh_plane(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    const double rho = 0.7, L = 1.5;
    scene_ground(&t, 12, 10, (float)rho);
    t.scene.sh_bands = 2;
    constant_sh(&t.scene, L);
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_AUTO);
    CHECK(ref && pen_reference_lighting_mode(ref) == PEN_REFERENCE_LIGHTING_SH);
    pen_image img;
    CHECK(pen_reference_render(ctx, ref, 5, 7, &img) == PEN_OK);
    /* Constant radiance and cosine sampling: every sample is exactly pi L, so no noise at all. */
    double worst = 0;
    for (int i = 0; i < img.width * img.height * 3; ++i)
        worst = fmax(worst, fabs((double)img.data[i] - rho * L));
    CHECK_MSG(worst < 1e-5, "worst |pixel - rho L| = %g", worst);
    float E[3], x[3] = {0.3f, 0.0f, -0.2f}, n[3] = {0, 1, 0};
    CHECK(pen_reference_irradiance(ctx, ref, x, n, 100, 3, E) == PEN_OK);
    CHECK_REL(E[1], PI * L, 1e-5, 1e-6);
    pen_image_free(&img);
    pen_reference_destroy(ref);
    pen_context_destroy(ctx);
}

static void test_constant_envmap_plane(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    const double rho = 0.5, L = 2.0;
    scene_ground(&t, 8, 8, (float)rho);
    pen_image env;
    CHECK(pen_image_create(ctx, 32, 16, 3, &env) == PEN_OK);
    for (int i = 0; i < 32 * 16 * 3; ++i)
        env.data[i] = (float)L;
    t.scene.lighting.envmap = env;
    t.scene.lighting.scale = 0.5f; /* the map is scaled: radiance L / 2 */
    /* as pen_scene_load does: the SH lighting is the map's projection (so AUTO picks the map) */
    CHECK(pen_envmap_to_sh(ctx, &env, t.scene.sh_bands, 0.0f, 0.5f, t.scene.lighting.sh) == PEN_OK);
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_AUTO);
    CHECK(ref && pen_reference_lighting_mode(ref) == PEN_REFERENCE_LIGHTING_ENVMAP);
    pen_image img;
    CHECK(pen_reference_render(ctx, ref, 256, 1, &img) == PEN_OK);
    double mean = 0;
    for (int i = 0; i < img.width * img.height * 3; ++i)
        mean += (double)img.data[i];
    mean /= img.width * img.height * 3;
    /* MIS of two unbiased strategies under constant light has tiny variance: 0.5% is > 10 se. */
    CHECK_REL(mean, rho * L * 0.5, 5e-3, 1e-6);
    pen_image_free(&img);
    pen_reference_destroy(ref);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

static void test_sh_plane(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    const double rho = 0.8;
    scene_ground(&t, 16, 16, (float)rho);
    t.scene.sh_bands = 4; /* band 3 is present and must not change the irradiance */
    random_sh(t.scene.lighting.sh, 4, 11);
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    pen_image img;
    const int spp = check_quick_() ? 16 : 64;
    CHECK(pen_reference_render(ctx, ref, spp, 3, &img) == PEN_OK);
    const double up[3] = {0, 1, 0};
    for (int ch = 0; ch < 3; ++ch) {
        double want = rho / PI * sh_irradiance(t.scene.lighting.sh, ch, up);
        double s = 0, s2 = 0;
        int n = img.width * img.height;
        for (int p = 0; p < n; ++p) {
            double v = img.data[3 * p + ch];
            s += v, s2 += v * v;
        }
        double mean = s / n, se = sqrt(fmax(s2 / n - mean * mean, 0) / (n - 1));
        CHECK_MSG(fabs(mean - want) < 5 * se + 1e-5 * want, "ch %d: mean %g, want %g, se %g", ch,
                  mean, want, se);
    }
    pen_image_free(&img);

    /* Tilted normals through the point estimator: nothing occludes without the ground. */
    t.scene.ground.enabled = 0;
    pen_reference_destroy(ref);
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    unsigned long long seed = 5;
    for (int k = 0; k < 4; ++k) {
        double d[3] = {check_rand_(&seed) - 0.5, check_rand_(&seed) - 0.5,
                       check_rand_(&seed) - 0.5};
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        float x[3] = {0, 1, 0},
              n[3] = {(float)(d[0] / len), (float)(d[1] / len), (float)(d[2] / len)};
        double nd[3] = {n[0], n[1], n[2]}, mean[3], se;
        irradiance_stats(ctx, ref, x, n, 20, check_quick_() ? 200 : 2000, mean, &se);
        double want = sh_irradiance(t.scene.lighting.sh, 0, nd);
        CHECK_MSG(fabs(mean[0] - want) < 5 * se + 1e-5, "normal %d: %g vs %g (se %g)", k, mean[0],
                  want, se);
    }
    pen_reference_destroy(ref);
    pen_context_destroy(ctx);
}

/* An envmap that holds an SH function texel by texel: the envmap path (importance sampling, MIS,
 * rotation) must reproduce the SH closed form up to the map's discretisation (< 0.5% here). */
static void test_envmap_sh_function(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    scene_ground(&t, 8, 8, 1.0f);
    t.scene.ground.enabled = 0;
    float sh[PEN_SH_MAX_COEFFS][3];
    random_sh(sh, 3, 21);
    pen_image env;
    CHECK(pen_image_create(ctx, 128, 64, 3, &env) == PEN_OK);
    envmap_from_sh(&env, sh);
    t.scene.lighting.envmap = env;
    const double rot_deg = 70.0;
    t.scene.lighting.rotation_y_deg = (float)rot_deg;
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_ENVMAP);
    t.scene.sh_bands = 3;
    CHECK(pen_envmap_to_sh(ctx, &env, 3, (float)rot_deg, 1.0f, t.scene.lighting.sh) == PEN_OK);
    pen_reference *ref_sh = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    /* AUTO: the SH is the map's projection, so the map lights; other SH would win. */
    pen_reference *ref_auto = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_AUTO);
    CHECK(ref_auto && pen_reference_lighting_mode(ref_auto) == PEN_REFERENCE_LIGHTING_ENVMAP);
    pen_reference_destroy(ref_auto);
    t.scene.lighting.sh[1][0] += 0.01f;
    ref_auto = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_AUTO);
    CHECK(ref_auto && pen_reference_lighting_mode(ref_auto) == PEN_REFERENCE_LIGHTING_SH);
    pen_reference_destroy(ref_auto);
    t.scene.lighting.sh[1][0] -= 0.01f;
    unsigned long long seed = 9;
    double c = cos(rot_deg * PI / 180), s = sin(rot_deg * PI / 180);
    for (int k = 0; k < 3; ++k) {
        double d[3] = {check_rand_(&seed) - 0.5, check_rand_(&seed) - 0.5,
                       check_rand_(&seed) - 0.5};
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        float x[3] = {0, 0, 0},
              n[3] = {(float)(d[0] / len), (float)(d[1] / len), (float)(d[2] / len)};
        double nd[3] = {n[0], n[1], n[2]};
        /* world = R_y(rot) map, so the irradiance at n is the map's at R_y(-rot) n */
        double nm[3] = {c * nd[0] - s * nd[2], nd[1], s * nd[0] + c * nd[2]}, mean[3], se;
        irradiance_stats(ctx, ref, x, n, 20, check_quick_() ? 200 : 2000, mean, &se);
        double want = sh_irradiance(sh, 0, nm);
        CHECK_MSG(fabs(mean[0] - want) < 5 * se + 5e-3 * want, "normal %d: %g vs %g (se %g)", k,
                  mean[0], want, se);
        /* The same through the SH path with the io projection of the map: both must agree on
         * the rotation convention (pen_envmap_to_sh). */
        irradiance_stats(ctx, ref_sh, x, n, 20, check_quick_() ? 200 : 2000, mean, &se);
        CHECK_MSG(fabs(mean[0] - want) < 5 * se + 5e-3 * want, "SH, normal %d: %g vs %g (se %g)", k,
                  mean[0], want, se);
    }
    pen_reference_destroy(ref_sh);
    pen_reference_destroy(ref);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

/* ---- Analytic: an occluding square --------------------------------------------------------------
 */

static double corner_form_factor(double X, double Y) {
    double sx = sqrt(1 + X * X), sy = sqrt(1 + Y * Y);
    return (X / sx * atan(Y / sx) + Y / sy * atan(X / sy)) / (2 * PI);
}

static void test_occluding_square(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    scene_ground(&t, 8, 8, 1.0f);
    const double a = 0.6, h = 0.8, L = 1.0;
    add_square(&t, 0, (float)a, (float)h, 0.5f);
    double want = PI * L * (1 - 4 * corner_form_factor(a / h, a / h));
    float x[3] = {0, 0, 0}, n[3] = {0, 1, 0};
    const int per = check_quick_() ? 500 : 4000;

    constant_sh(&t.scene, L);
    t.scene.sh_bands = 1;
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    double mean[3], se;
    irradiance_stats(ctx, ref, x, n, 20, per, mean, &se);
    CHECK_MSG(fabs(mean[0] - want) < 5 * se, "SH: %g vs %g (se %g)", mean[0], want, se);
    pen_reference_destroy(ref);

    pen_image env;
    CHECK(pen_image_create(ctx, 64, 32, 3, &env) == PEN_OK);
    for (int i = 0; i < 64 * 32 * 3; ++i)
        env.data[i] = (float)L;
    t.scene.lighting.envmap = env;
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_ENVMAP);
    irradiance_stats(ctx, ref, x, n, 20, per, mean, &se);
    CHECK_MSG(fabs(mean[0] - want) < 5 * se, "envmap: %g vs %g (se %g)", mean[0], want, se);
    pen_reference_destroy(ref);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

/* ---- Surfaces: textures, back faces, background ------------------------------------------------
 */

/* A unit quad in the plane z = 0 facing +Z, seen straight on, under constant light L: each pixel
 * is albedo(uv) * L. The texture's row 0 (white) must appear at the top (v = 1). */
static void test_textured_quad(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    scene_ground(&t, 16, 16, 1.0f);
    t.scene.ground.enabled = 0;
    t.scene.camera = (pen_camera){16, 16, 30.0f, {0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 0, 0, 0, 0};
    const double L = 1.0;
    t.scene.sh_bands = 1;
    constant_sh(&t.scene, L);
    const float p[12] = {-2, -2, 0, 2, -2, 0, 2, 2, 0, -2, 2, 0};
    const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    const float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
    memcpy(t.positions[0], p, sizeof p);
    memcpy(t.indices[0], idx, sizeof idx);
    memcpy(t.uvs, uv, sizeof uv);
    memcpy(t.uv_indices, idx, sizeof idx);
    pen_object *o = &t.objects[0];
    o->mesh = (pen_mesh){.vertex_count = 4,
                         .triangle_count = 2,
                         .positions = t.positions[0],
                         .indices = t.indices[0],
                         .uv_count = 4,
                         .uvs = t.uvs,
                         .uv_indices = t.uv_indices};
    o->pose.scale = 1.0f;
    t.scene.object_count = 1;
    pen_image tex;
    CHECK(pen_image_create(ctx, 4, 64, 3, &tex) == PEN_OK);
    for (int y = 0; y < 64; ++y)
        for (int i = 0; i < 4 * 3; ++i)
            tex.data[y * 12 + i] = y < 32 ? 0.9f : 0.1f;
    o->texture = tex;
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    pen_image img;
    pen_image cov;
    CHECK(pen_reference_render_coverage(ctx, ref, 4, 1, &img, &cov) == PEN_OK);
    /* The quad fills the view; rows 2 and 13 are well inside the top and bottom halves. */
    CHECK_NEAR(img.data[3 * (2 * 16 + 8)], 0.9 * L, 1e-4);
    CHECK_NEAR(img.data[3 * (13 * 16 + 8)], 0.1 * L, 1e-4);
    CHECK(cov.channels == 1 && cov.data[0] == 1.0f && cov.data[16 * 16 - 1] == 1.0f);
    pen_image same;
    CHECK(pen_reference_render(ctx, ref, 4, 1, &same) == PEN_OK);
    CHECK(memcmp(same.data, img.data, sizeof(float) * 3 * 16 * 16) == 0);
    pen_image_free(&same);
    pen_image_free(&cov);
    pen_image_free(&img);
    /* A wider view sees the quad's edges: coverage is the covered fraction of the pixel. */
    t.scene.camera.fov_y_deg = 90.0f;
    pen_reference_destroy(ref);
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    CHECK(pen_reference_render_coverage(ctx, ref, 64, 1, &img, &cov) == PEN_OK);
    /* focal = 8 px at 90 degrees: x = 2 at depth 3 projects to 8 + 8 * 2 / 3 = 13.33 px, so
     * column 13 is a third covered; columns 12 and 14 fully and not at all. */
    CHECK_NEAR(cov.data[8 * 16 + 13], 1.0 / 3, 0.1);
    CHECK(cov.data[8 * 16 + 12] == 1.0f && cov.data[8 * 16 + 14] == 0.0f);
    pen_image_free(&cov);
    pen_image_free(&img);
    t.scene.camera.fov_y_deg = 30.0f;
    pen_reference_destroy(ref);

    /* From behind the quad faces away: lit two-sided, the same brightness (the texture mirrored
     * left-right, but uniform across columns). */
    t.scene.camera.eye[2] = -3;
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    CHECK(pen_reference_render(ctx, ref, 4, 1, &img) == PEN_OK);
    CHECK_NEAR(img.data[3 * (2 * 16 + 8)], 0.9 * L, 1e-4);
    pen_image_free(&img);

    /* Missing the quad: the constant background. */
    pen_reference_destroy(ref);
    t.scene.camera.eye[2] = 3;
    t.scene.camera.target[0] = 50; /* looks away to the side */
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    CHECK(pen_reference_render(ctx, ref, 1, 1, &img) == PEN_OK);
    CHECK_NEAR(img.data[0], 0.25, 0);
    pen_image_free(&img);
    pen_reference_destroy(ref);
    pen_image_free(&tex);
    pen_context_destroy(ctx);
}

/* ---- Convergence and determinism ---------------------------------------------------------------
 */

/* A square casting a shadow on the ground under a map with a bright "sun" and a dim sky. */
static void scene_shadow(test_scene *t, pen_image *env, int size) {
    scene_ground(t, size, size, 0.8f);
    t->scene.camera = (pen_camera){size, size, 45.0f, {0, 2.5f, 2.5f}, {0, 0, 0}, {0, 1, 0}, 0, 0, 0, 0};
    add_square(t, 0, 0.5f, 0.6f, 0.6f);
    for (int y = 0; y < env->height; ++y)
        for (int x = 0; x < env->width; ++x) {
            float *px = env->data + 3 * ((size_t)y * env->width + x);
            int sun = abs(y - env->height / 5) <= 1 && abs(x - env->width / 3) <= 1;
            px[0] = sun ? 60.0f : 0.4f;
            px[1] = sun ? 50.0f : 0.5f;
            px[2] = sun ? 40.0f : 0.8f * (1.0f - (float)y / env->height);
        }
    t->scene.lighting.envmap = *env;
    t->scene.background_envmap = 1;
}

static double image_rmse(const pen_image *a, const pen_image *b) {
    pen_context *ctx = pen_context_create();
    pen_image_error e;
    CHECK(pen_image_compare(ctx, a, b, NULL, &e, NULL) == PEN_OK);
    pen_context_destroy(ctx);
    return e.rmse;
}

static void test_convergence(void) {
    pen_context *ctx = pen_context_create();
    const int size = 24, hi = check_quick_() ? 2048 : 4096, seeds = 4;
    pen_image env;
    CHECK(pen_image_create(ctx, 64, 32, 3, &env) == PEN_OK);
    test_scene t;
    scene_shadow(&t, &env, size);
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_ENVMAP);
    pen_image truth;
    CHECK(pen_reference_render(ctx, ref, hi, 99, &truth) == PEN_OK);
    /* Mean squared error over a few independent seeds at each spp: the squared error of one image
     * is dominated by a handful of penumbra pixels, so one seed alone wanders by +-15%. */
    double mse[2] = {0, 0};
    const int spp[2] = {16, 256};
    for (int k = 0; k < 2; ++k)
        for (int sd = 0; sd < seeds; ++sd) {
            pen_image img;
            CHECK(pen_reference_render(ctx, ref, spp[k], (uint64_t)(1 + 10 * k + sd), &img) ==
                  PEN_OK);
            double e = image_rmse(&img, &truth);
            mse[k] += e * e / seeds;
            pen_image_free(&img);
        }
    /* Independent seeds: measured error^2 = var/spp + var/hi, so for 1/sqrt(spp) convergence the
     * ratio is sqrt((1/16 + 1/hi) / (1/256 + 1/hi)) (3.89 at hi = 4096). Allowed: 12% either side
     * (the spread over seeds of this 4-seed ratio is about 4%). */
    double want = sqrt((1.0 / 16 + 1.0 / hi) / (1.0 / 256 + 1.0 / hi));
    double ratio = sqrt(mse[0] / mse[1]);
    printf("  convergence: rmse(16) %.5f, rmse(256) %.5f, ratio %.3f (1/sqrt(spp): %.3f)\n",
           sqrt(mse[0]), sqrt(mse[1]), ratio, want);
    CHECK_MSG(fabs(ratio / want - 1) < 0.12, "ratio %g, want %g", ratio, want);
    pen_image_free(&truth);
    pen_reference_destroy(ref);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

static void test_determinism(void) {
    pen_context *ctx = pen_context_create();
    pen_image env;
    CHECK(pen_image_create(ctx, 64, 32, 3, &env) == PEN_OK);
    test_scene t;
    scene_shadow(&t, &env, 20);
    pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_ENVMAP);
    pen_image a, b, c;
    pen_context_set_threads(ctx, 1);
    CHECK(pen_reference_render(ctx, ref, 8, 42, &a) == PEN_OK);
    pen_context_set_threads(ctx, 3);
    CHECK(pen_reference_render(ctx, ref, 8, 42, &b) == PEN_OK);
    CHECK(pen_reference_render(ctx, ref, 8, 43, &c) == PEN_OK);
    size_t bytes = sizeof(float) * 3 * 20 * 20;
    CHECK(memcmp(a.data, b.data, bytes) == 0);
    CHECK(memcmp(a.data, c.data, bytes) != 0);
    pen_image_free(&a);
    pen_image_free(&b);
    pen_image_free(&c);
    pen_reference_destroy(ref);
    pen_image_free(&env);
    pen_context_destroy(ctx);
}

/* ---- Agreement with `render` where both are exact ----------------------------------------------
 */

/* Unoccluded surfaces under SH light: the reference (closed form + a blocked-light estimate that is
 * zero here) and the SH renderer without shadows both give rho/pi E_0(n) exactly. The ground, and
 * a tilted quad that fills the view (so the band-1 and band-2 terms matter), pixel by pixel. */
static void test_agrees_with_render(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    scene_ground(&t, 16, 12, 0.7f);
    t.scene.sh_bands = 4;
    random_sh(t.scene.lighting.sh, 4, 31);
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    for (int pass = 0; pass < 2; ++pass) {
        if (pass == 1) { /* a quad tilted 30 degrees about X, facing the camera on +Z */
            const float c = 0.8660254f, sn = 0.5f;
            const float p[12] = {-3, -3 * c, 3 * sn,  3,  -3 * c, 3 * sn,
                                 3,  3 * c,  -3 * sn, -3, 3 * c,  -3 * sn};
            const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
            memcpy(t.positions[0], p, sizeof p);
            memcpy(t.indices[0], idx, sizeof idx);
            pen_object *o = &t.objects[0];
            o->mesh.vertex_count = 4;
            o->mesh.triangle_count = 2;
            o->mesh.positions = t.positions[0];
            o->mesh.indices = t.indices[0];
            o->albedo[0] = 0.3f, o->albedo[1] = 0.5f, o->albedo[2] = 0.9f;
            o->pose.scale = 1.0f;
            t.scene.object_count = 1;
            t.scene.ground.enabled = 0;
            t.scene.camera = (pen_camera){16, 12, 40.0f, {0, 0, 4}, {0, 0, 0}, {0, 1, 0}, 0, 0, 0, 0};
        }
        pen_reference *ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
        pen_image a, b = {0, 0, 0, NULL};
        CHECK(pen_reference_render(ctx, ref, 4, 1, &a) == PEN_OK);
        pen_status st = pen_render_fwd(ctx, &t.scene, &opt, NULL, &b);
        CHECK_MSG(st == PEN_OK, "%s", pen_context_error(ctx));
        double worst = 0;
        for (int i = 0; st == PEN_OK && i < 16 * 12 * 3; ++i)
            worst = fmax(worst, fabs((double)a.data[i] - (double)b.data[i]) /
                                    fmax(fabs((double)b.data[i]), 1e-3));
        CHECK_MSG(worst < 1e-4, "pass %d: worst relative difference %g", pass, worst);
        pen_image_free(&a);
        pen_image_free(&b);
        pen_reference_destroy(ref);
    }
    pen_context_destroy(ctx);
}

/* ---- Errors ---------------------------------------------------------------------------------- */

static void test_errors(void) {
    pen_context *ctx = pen_context_create();
    test_scene t;
    scene_ground(&t, 8, 8, 1.0f);
    t.scene.sh_bands = 1;
    pen_reference *ref = NULL;
    /* envmap lighting without an envmap */
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_ENVMAP, &ref) ==
          PEN_ERROR_ARGUMENT);
    CHECK(ref == NULL && strstr(pen_context_error(ctx), "envmap"));
    /* an index out of range names the object and the triangle */
    add_square(&t, 0, 0.5f, 0.5f, 0.5f);
    t.indices[0][4] = 17;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "triangle 1") && strstr(pen_context_error(ctx), "17"));
    t.indices[0][4] = 2;
    /* non-finite lighting, bad band count */
    t.scene.lighting.sh[0][1] = NAN;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    t.scene.lighting.sh[0][1] = 1.0f;
    t.scene.sh_bands = PEN_SH_MAX_BANDS + 1;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    t.scene.sh_bands = 1;
    /* huge but finite coordinates (past the loaders' ranges, possible in memory): an error naming
     * the extent instead of Embree's abort on the first ray */
    t.scene.objects[0].pose.scale = 1e20f;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    CHECK_MSG(ref == NULL && strstr(pen_context_error(ctx), "world-space coordinates up to"),
              "%s", pen_context_error(ctx));
    t.scene.objects[0].pose.scale = 1.0f;
    t.scene.ground.half_size = 3e18f;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    t.scene.ground.half_size = 4.0f;
    t.scene.camera.eye[1] = 1e19f;
    CHECK(pen_reference_create(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH, &ref) ==
          PEN_ERROR_ARGUMENT);
    t.scene.camera.eye[1] = 3.0f;
    /* spp out of range */
    ref = make_ref(ctx, &t.scene, PEN_REFERENCE_LIGHTING_SH);
    pen_image img;
    CHECK(pen_reference_render(ctx, ref, 0, 1, &img) == PEN_ERROR_ARGUMENT && img.data == NULL);
    float x[3] = {0, 0, 0}, n0[3] = {0, 0, 0}, E[3];
    CHECK(pen_reference_irradiance(ctx, ref, x, n0, 10, 1, E) == PEN_ERROR_ARGUMENT);
    pen_reference_destroy(ref);
    pen_reference_destroy(NULL);
    CHECK(pen_reference_lighting_parse("sh") == PEN_REFERENCE_LIGHTING_SH);
    CHECK(pen_reference_lighting_parse("envmap") == PEN_REFERENCE_LIGHTING_ENVMAP);
    CHECK(pen_reference_lighting_parse("SH") == -1);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_envmap_sampler), TEST(test_constant_sh_plane), TEST(test_constant_envmap_plane),
          TEST(test_sh_plane), TEST(test_envmap_sh_function), TEST(test_occluding_square),
          TEST(test_textured_quad), TEST(test_convergence), TEST(test_determinism),
          TEST(test_agrees_with_render), TEST(test_errors))
