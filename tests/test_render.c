/* Forward tests of the renderer (src/render/forward.c) against references that are not our own
 * output: closed-form irradiance of an unoccluded plane and of a tessellated sphere, the exact
 * cosine-weighted occlusion of a sphere above a plane, the self-shadowing rule on a convex
 * object, background colours; image losses; argument errors. */
#include "io_fixtures.h"
#include "render_scenes.h"

static unsigned long long seed = 31337;

/* Ramamoorthi-Hanrahan: E(n) = sum_l A_l sum_m L_lm Y_lm(n), A = (pi, 2 pi / 3, pi / 4, 0). */
static double irradiance(const pen_scene *sc, int ch, const double n[3]) {
    const double A[3] = {M_PI, 2 * M_PI / 3, M_PI / 4};
    double y[9], e = 0.0;
    rs_y_band2(n, y);
    for (int l = 0; l < 3; ++l)
        for (int m = -l; m <= l; ++m)
            e += A[l] * (double)sc->lighting.sh[l * l + l + m][ch] * y[l * l + l + m];
    return e;
}

/* Golden image 1: the unoccluded ground under 4-band lighting equals rho / pi * E(+Y) at every
 * ground pixel; metric: max relative error, threshold 1e-5 (float rounding), with shadows on
 * (no spheres: V = exp*(0) = 1) and off. */
static void test_golden_plane(void) {
    pen_scene sc = rs_scene(48, 32);
    for (int shadows = 0; shadows < 2; ++shadows) {
        pen_render_options opt = pen_render_options_default();
        opt.shadows = shadows;
        pen_image img;
        CHECK(rs_render(&sc, &opt, 0, &img) == PEN_OK);
        const double up[3] = {0, 1, 0};
        double worst = 0.0;
        int ground = 0;
        for (int i = 0; i < 48 * 32; ++i) {
            const float *p = img.data + 3 * i;
            if (p[0] == sc.background[0] && p[1] == sc.background[1]) continue;
            /* The square's border is blended with the background (pen__ground_border_fwd):
             * only pixels whose 4 neighbours are ground too keep the closed form. */
            int x = i % 48, y = i / 48, border = 0;
            const int nb[4][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}};
            for (int k = 0; k < 4; ++k) {
                int xx = x + nb[k][0], yy = y + nb[k][1];
                if (xx < 0 || xx >= 48 || yy < 0 || yy >= 32) continue;
                const float *q = img.data + 3 * (yy * 48 + xx);
                border |= q[0] == sc.background[0] && q[1] == sc.background[1];
            }
            if (border) continue;
            ++ground;
            for (int ch = 0; ch < 3; ++ch) {
                const double want = (double)sc.ground.albedo[ch] / M_PI * irradiance(&sc, ch, up);
                worst = fmax(worst, fabs((double)p[ch] - want) / want);
            }
        }
        CHECK(ground > 1000);
        CHECK_MSG(worst < 1e-5, "shadows %d: max relative error %.3g", shadows, worst);
        pen_image_free(&img);
    }
    pen_scene_free(&sc);
}

/* Golden image 2: a tessellated sphere (2048 triangles) without shadows against the closed form
 * at the analytic sphere's normal where each pixel's ray meets it. Metric: RMSE over pixels
 * whose 3x3 neighbourhood is all sphere (no silhouette blending), relative to the mean;
 * threshold 1% (the tessellation: chords and interpolated vertex normals). */
static void test_golden_sphere(void) {
    pen_scene sc = rs_scene(64, 64);
    sc.ground.enabled = 0;
    const float eye[3] = {0.4f, 0.9f, 3.0f}, target[3] = {0, 0, 0};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    const float R = 0.8f;
    pen_object *ob = rs_add_object(&sc, rs_octasphere(4, R, 0), 0, NULL);
    ob->albedo[0] = 0.9f, ob->albedo[1] = 0.6f, ob->albedo[2] = 0.4f;
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_image img;
    CHECK(rs_render(&sc, &opt, 0, &img) == PEN_OK);
    pen_context *ctx = pen_context_create();
    pen_view view;
    CHECK(pen_view_init(ctx, &sc.camera, &view) == PEN_OK);
    double se = 0.0, sum = 0.0;
    int count = 0;
    for (int y = 1; y < 63; ++y)
        for (int x = 1; x < 63; ++x) {
            /* Interior test on the analytic sphere: all 9 neighbours' rays hit it with margin. */
            int inside = 1;
            double hit_n[3] = {0, 0, 0};
            for (int dy = -1; dy <= 1 && inside; ++dy)
                for (int dx = -1; dx <= 1 && inside; ++dx) {
                    double d[3];
                    pen_view_ray(&view, x + dx + 0.5, y + dy + 0.5, d);
                    double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                    double b = 0, c = -(double)R * (double)R;
                    for (int a = 0; a < 3; ++a)
                        b += d[a] * view.eye[a], c += view.eye[a] * view.eye[a];
                    double disc = b * b - dd * c;
                    if (disc < 0.02 * dd) inside = 0;
                    if (dx == 0 && dy == 0 && inside) {
                        double t = (-b - sqrt(disc)) / dd;
                        for (int a = 0; a < 3; ++a)
                            hit_n[a] = (view.eye[a] + t * d[a]) / (double)R;
                    }
                }
            if (!inside) continue;
            for (int ch = 0; ch < 3; ++ch) {
                const double want = (double)ob->albedo[ch] / M_PI * irradiance(&sc, ch, hit_n);
                const double got = img.data[3 * (y * 64 + x) + ch];
                se += (got - want) * (got - want);
                sum += fabs(want);
                ++count;
            }
        }
    CHECK(count > 3 * 1000);
    const double rel_rmse = sqrt(se / count) / (sum / count);
    if (getenv("PEN_TEST_VERBOSE")) printf("  sphere: relative RMSE %.4g\n", rel_rmse);
    CHECK_MSG(rel_rmse < 1e-2, "relative RMSE %.4g over %d values", rel_rmse, count);
    pen_image_free(&img);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* A scene looking straight down at the ground's origin (33 x 33: the centre pixel's ray is the
 * axis), DC-only lighting of radiance 1, and one occluding sphere (c, r) whose mesh is a small
 * triangle far out of view. */
static pen_scene occluder_scene(float height, float radius) {
    pen_scene sc = rs_scene(33, 33);
    const float eye[3] = {0, 4, 0}, target[3] = {0, 0, 0}, up[3] = {0, 0, -1};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    memcpy(sc.camera.up, up, sizeof up);
    sc.camera.fov_y_deg = 10.0f;
    memset(sc.lighting.sh, 0, sizeof sc.lighting.sh);
    for (int ch = 0; ch < 3; ++ch)
        sc.lighting.sh[0][ch] = (float)sqrt(4 * M_PI);
    const float s[4] = {0, height, 0, radius};
    rs_add_object(&sc, rs_far_triangle(), 1, s);
    /* The sphere is the occluder, not the far triangle: no ground transfer of that mesh. */
    sc.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
    return sc;
}

/* The shadow's depth: directly below a sphere of angular radius alpha, the true irradiance of a
 * plane under uniform radiance 1 is pi (1 - sin^2 alpha) (the cap's cosine-weighted solid angle
 * is pi sin^2 alpha). Metric: |E - E_true| / E_unoccluded (docs/design.md sec. 4.1), threshold 0.1
 * for spheres covering sin^2 alpha = 0.04 .. 0.36 of the hemisphere; the shadow must deepen with
 * the sphere's size. */
static void test_shadow_depth_against_exact_occlusion(void) {
    const float radii[4] = {0.2f, 0.3f, 0.45f, 0.6f};
    double prev = 1e9;
    for (int k = 0; k < 4; ++k) {
        pen_scene sc = occluder_scene(1.0f, radii[k]);
        pen_image img;
        CHECK(rs_render(&sc, NULL, 1, &img) == PEN_OK);
        const float *p = img.data + 3 * (16 * 33 + 16);
        const double E = (double)p[1] / (double)sc.ground.albedo[1] * M_PI; /* radiance -> E */
        const double s2 = (double)radii[k] * (double)radii[k];
        const double E_true = M_PI * (1.0 - s2), E_open = M_PI;
        const double err = fabs(E - E_true) / E_open;
        if (getenv("PEN_TEST_VERBOSE"))
            printf("  r %.2f: E %.4f, exact %.4f, error %.4f of unoccluded\n", (double)radii[k], E,
                   E_true, err);
        CHECK_MSG(err < 0.1, "r %.2f: E %.4f, exact %.4f, error %.3f of unoccluded",
                  (double)radii[k], E, E_true, err);
        CHECK_MSG(E < prev, "shadow does not deepen: %.4f after %.4f", E, prev);
        prev = E;
        pen_image_free(&img);
        pen_scene_free(&sc);
    }
}

/* Self-shadowing rule on a convex object: a proxy sphere inside the tessellated sphere (radius
 * 0.97 of the mesh's) lies wholly behind every surface point's tangent plane, so the object's
 * pixels equal those of the unshadowed render (up to 1e-5: the float model's exp*(0)), while the
 * ground under it darkens. With the precomputed transfer instead (the default), the points inside
 * a facet see the facet's own plane cut off the part of the interpolated normal's hemisphere that
 * dips below it (as the reference's rays from the facet do): within 1 % (darker, or brighter
 * where the band-limited light is negative there). */
static void test_convex_object_does_not_shadow_itself(void) {
    pen_scene sc = rs_scene(48, 48);
    sc.shadow.ground = PEN_GROUND_RECEIVER; /* the ground's own occlusion: test_ground_occlusion */
    sc.shadow.self = PEN_SELF_SPHERES;      /* the rule under test; the transfer below */
    const float R = 0.45f, s[4] = {0, 0, 0, 0.97f * R};
    pen_object *ob = rs_add_object(&sc, rs_octasphere(3, R, 0), 1, s);
    ob->pose.translation[1] = 0.6f;
    pen_render_options on = pen_render_options_default(), off = on;
    off.shadows = 0;
    pen_image a, b;
    CHECK(rs_render(&sc, &on, 0, &a) == PEN_OK);
    CHECK(rs_render(&sc, &off, 0, &b) == PEN_OK);
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    pen_render_state_create(ctx, &st);
    pen_image c = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, &on, st, &c) == PEN_OK);
    /* Which pixels are object interior: from the G-buffer. */
    int interior = 0, ground_darker = 0, ground = 0;
    double worst = 0.0;
    char *inside = calloc(48 * 48, 1);
    pen_view view;
    pen_view_init(ctx, &sc.camera, &view);
    pen_gbuffer gb;
    pen_gbuffer_create(ctx, 48, 48, &gb);
    float *world = malloc(sizeof(float) * 3 * (size_t)ob->mesh.vertex_count);
    pen_pose_points_fwd(&ob->pose, ob->mesh.vertex_count, ob->mesh.positions, world);
    pen_raster_mesh m = {ob->mesh.vertex_count, ob->mesh.triangle_count, world, ob->mesh.indices,
                         NULL};
    CHECK(pen_raster_gbuffer(ctx, &view, &m, 1, &sc.ground, &gb) == PEN_OK);
    for (int y = 1; y < 47; ++y)
        for (int x = 1; x < 47; ++x) {
            const int i = y * 48 + x;
            int all = 1;
            for (int d = -1; d <= 1; ++d)
                all &= gb.surface[i + d] == 0 && gb.surface[i + 48 * d] == 0;
            if (gb.surface[i] == PEN_SURFACE_GROUND) {
                ++ground;
                ground_darker += a.data[3 * i] < b.data[3 * i] - 1e-3f;
            }
            if (!all) continue;
            ++interior, inside[i] = 1;
            for (int ch = 0; ch < 3; ++ch)
                worst = fmax(worst, fabs((double)a.data[3 * i + ch] - (double)b.data[3 * i + ch]));
        }
    CHECK(interior > 100);
    /* V = exp*(0) is 1 up to the float model's rounding (about 1e-6). */
    CHECK_MSG(worst < 1e-5, "object pixels differ by %.3g with shadows on", worst);
    CHECK_MSG(ground_darker > 20, "only %d of %d ground pixels darkened", ground_darker, ground);
    for (int i = 0; i < 3 * 48 * 48; ++i)
        CHECK(c.data[i] == a.data[i]); /* with a state */
    sc.shadow.self = PEN_SELF_TRANSFER;
    pen_image t;
    CHECK(rs_render(&sc, &on, 0, &t) == PEN_OK);
    double tworst = 0.0;
    for (int i = 0; i < 48 * 48; ++i)
        for (int ch = 0; inside[i] && ch < 3; ++ch)
            tworst = fmax(tworst, fabs((double)b.data[3 * i + ch] - (double)t.data[3 * i + ch]) /
                                      (double)b.data[3 * i + ch]);
    printf("  transfer: object pixels within %.2g (relative) of the unshadowed render\n", tworst);
    CHECK(tworst < 0.01);
    pen_image_free(&t);
    free(inside);
    free(world);
    pen_gbuffer_free(&gb);
    pen_image_free(&a), pen_image_free(&b), pen_image_free(&c);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* Background pixels show the constant background exactly (no geometry there to blend). */
/* The render state keeps the antialiasing adjacency between frames; a mesh whose indices are
 * edited in place (same counts) must get it rebuilt: the next frame equals a fresh state's. */
static void test_state_notices_new_topology(void) {
    unsigned long long rng = 99;
    pen_scene sc = rs_ball_scene(32, 0, &rng);
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_image a = {0, 0, 0, NULL}, b = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, NULL, st, &a) == PEN_OK);
    pen_mesh *m = &sc.objects[0].mesh;
    for (int t = 0; t + 1 < m->triangle_count; t += 2) /* swap pairs of triangles */
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = m->indices[3 * t + k];
            m->indices[3 * t + k] = m->indices[3 * (t + 1) + k];
            m->indices[3 * (t + 1) + k] = v;
        }
    CHECK(pen_render_fwd(ctx, &sc, NULL, st, &a) == PEN_OK);
    CHECK(pen_render_fwd(ctx, &sc, NULL, NULL, &b) == PEN_OK);
    CHECK(memcmp(a.data, b.data, sizeof(float) * 3 * 32 * 32) == 0);
    pen_image_free(&a), pen_image_free(&b);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

static void test_background_constant(void) {
    pen_scene sc = rs_scene(16, 16);
    sc.ground.enabled = 0;
    pen_image img;
    CHECK(rs_render(&sc, NULL, 0, &img) == PEN_OK);
    for (int i = 0; i < 16 * 16; ++i)
        for (int ch = 0; ch < 3; ++ch)
            CHECK(img.data[3 * i + ch] == sc.background[ch]);
    pen_image_free(&img);
    pen_scene_free(&sc);
}

/* ---- Losses ---------------------------------------------------------------------------------- */

static void test_losses(void) {
    pen_image a, b, d = {0, 0, 0, NULL};
    pen_image_create(NULL, 5, 4, 3, &a);
    pen_image_create(NULL, 5, 4, 3, &b);
    double l2 = 0.0, l1 = 0.0;
    for (int i = 0; i < 60; ++i) {
        a.data[i] = (float)check_rand_(&seed);
        b.data[i] = (float)check_rand_(&seed);
        const double r = (double)a.data[i] - (double)b.data[i];
        l2 += r * r / 60.0, l1 += fabs(r) / 60.0;
    }
    pen_context *ctx = pen_context_create();
    double got;
    CHECK(pen_loss_l2(ctx, &a, &b, &got, &d) == PEN_OK);
    CHECK_NEAR(got, l2, 1e-12);
    for (int i = 0; i < 60; ++i) {
        const float h = 1e-3f, keep = a.data[i];
        double lp, lm;
        a.data[i] = keep + h;
        pen_loss_l2(ctx, &a, &b, &lp, NULL);
        a.data[i] = keep - h;
        pen_loss_l2(ctx, &a, &b, &lm, NULL);
        a.data[i] = keep;
        CHECK_REL(d.data[i], (lp - lm) / (2.0 * (double)h), 1e-3, 1e-3);
    }
    memset(d.data, 0, sizeof(float) * 60);
    CHECK(pen_loss_l1(ctx, &a, &b, &got, &d) == PEN_OK);
    CHECK_NEAR(got, l1, 1e-12);
    for (int i = 0; i < 60; ++i) {
        const double want = a.data[i] > b.data[i] ? 1.0 / 60 : -1.0 / 60;
        CHECK_NEAR(d.data[i], want, 1e-8);
    }
    /* The gradient is set, not added: a loop reusing d_image without zeroing it (render.h's
     * usage) gets the same gradient every step, and a stale value is overwritten. */
    for (int i = 0; i < 60; ++i)
        d.data[i] = 1e3f;
    CHECK(pen_loss_l1(ctx, &a, &b, &got, &d) == PEN_OK);
    CHECK_NEAR(fabs(d.data[0]), 1.0 / 60, 1e-8);
    CHECK(pen_loss_l2(ctx, &a, &b, &got, &d) == PEN_OK);
    CHECK(pen_loss_l2(ctx, &a, &b, &got, &d) == PEN_OK);
    CHECK_NEAR(d.data[5], 2.0 * ((double)a.data[5] - (double)b.data[5]) / 60, 1e-7);
    pen_image c;
    pen_image_create(NULL, 4, 4, 3, &c);
    CHECK(pen_loss_l2(ctx, &a, &c, &got, NULL) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "shape") != NULL);
    pen_image_free(&a), pen_image_free(&b), pen_image_free(&c), pen_image_free(&d);
    pen_context_destroy(ctx);
}

/* ---- Errors ---------------------------------------------------------------------------------- */

static void expect_error(pen_scene *sc, const char *fragment) {
    pen_context *ctx = pen_context_create();
    pen_image img = {0, 0, 0, NULL};
    pen_status s = pen_render_fwd(ctx, sc, NULL, NULL, &img);
    CHECK_MSG(s != PEN_OK, "expected an error mentioning '%s'", fragment);
    CHECK_MSG(strstr(pen_context_error(ctx), fragment) != NULL, "message '%s' lacks '%s'",
              pen_context_error(ctx), fragment);
    CHECK(img.data == NULL);
    /* The model layer's pen_scene_validate runs the same checks: the same message, its first
     * word "scene" where the renderer's is "render". */
    char rendered[512];
    snprintf(rendered, sizeof rendered, "%s", pen_context_error(ctx));
    CHECK(pen_scene_validate(ctx, sc) != PEN_OK);
    const char *v = pen_context_error(ctx);
    if (!strncmp(rendered, "render: ", 8))
        CHECK_MSG(!strncmp(v, "scene: ", 7) && !strcmp(v + 7, rendered + 8), "'%s' vs '%s'", v,
                  rendered);
    else
        CHECK_MSG(!strcmp(v, rendered), "'%s' vs '%s'", v, rendered);
    pen_context_destroy(ctx);
}

static void test_invalid_inputs(void) {
    pen_scene sc = rs_ball_scene(16, 0, &seed);
    pen_context *vctx = pen_context_create();
    CHECK(pen_scene_validate(vctx, &sc) == PEN_OK);
    pen_context_destroy(vctx);
    float *r = &sc.objects[0].spheres.data[3];
    *r = -1.0f;
    expect_error(&sc, "sphere 0");
    *r = NAN;
    expect_error(&sc, "sphere 0");
    *r = 0.3f;
    sc.objects[0].pose.scale = 0.0f;
    expect_error(&sc, "pose");
    sc.objects[0].pose.scale = 1.0f;
    const float half = sc.ground.half_size;
    sc.ground.half_size = 0.0f; /* the JSON loader bounds it; the C API must too */
    expect_error(&sc, "ground.half_size");
    sc.ground.half_size = -1.0f;
    expect_error(&sc, "ground.half_size");
    sc.ground.half_size = half;
    sc.lighting.sh[3][1] = INFINITY;
    expect_error(&sc, "lighting");
    sc.lighting.sh[3][1] = 0.0f;
    sc.sh_bands = 9;
    expect_error(&sc, "sh_bands");
    sc.sh_bands = 4;
    sc.objects[0].mesh.indices[5] = 100000;
    expect_error(&sc, "objects[0]");
    sc.objects[0].mesh.indices[5] = 0;
    sc.camera.width = 0;
    expect_error(&sc, "");
    sc.camera.width = 16;
    /* an RGBA texture through the C API: refused (its gradient is 3 floats a texel) */
    CHECK(pen_image_create(NULL, 4, 4, 4, &sc.objects[0].texture) == PEN_OK);
    expect_error(&sc, "4 channels");
    pen_image_free(&sc.objects[0].texture);

    /* Output image of the wrong shape; backward without forward; gradient of another scene. */
    pen_context *ctx = pen_context_create();
    pen_image img;
    pen_image_create(ctx, 8, 8, 3, &img);
    CHECK(pen_render_fwd(ctx, &sc, NULL, NULL, &img) == PEN_ERROR_ARGUMENT);
    pen_render_state *st = NULL;
    pen_render_state_create(ctx, &st);
    pen_render_grad g;
    pen_render_grad_create(ctx, &sc, &g);
    CHECK(pen_render_bwd(ctx, &sc, NULL, st, &img, PEN_GRAD_ALL, &g) == PEN_ERROR_ARGUMENT);
    pen_image_free(&img);
    CHECK(pen_render_fwd(ctx, &sc, NULL, st, &img) == PEN_OK);
    pen_render_grad other;
    pen_scene sc2 = rs_ball_scene(16, 1, &seed);
    pen_render_grad_create(ctx, &sc2, &other);
    CHECK(pen_render_bwd(ctx, &sc, NULL, st, &img, PEN_GRAD_ALL, &other) == PEN_ERROR_ARGUMENT);
    const unsigned exact = pen_render_grad_exact(&sc, NULL);
    CHECK(pen_render_bwd(ctx, &sc, NULL, st, &img, PEN_GRAD_ALL & exact, &g) == PEN_OK);
    pen_render_grad_free(&g), pen_render_grad_free(&other);
    pen_render_grad_free(NULL);
    pen_render_state_free(st);
    pen_render_state_free(NULL);
    pen_image_free(&img);
    pen_context_destroy(ctx);
    pen_scene_free(&sc2);
    pen_scene_free(&sc);
}

/* The mask, depth and normals of the last forward (render.h): the mask is the G-buffer's objects,
 * depth the visible point's distance along the camera axis, normals unit and facing the camera;
 * refused before a forward and into an image of another shape. */
static void test_aovs(void) {
    pen_scene sc = rs_ball_scene(24, 1, &seed);
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    pen_image img = {0, 0, 0, NULL}, mask = {0, 0, 0, NULL}, depth = {0, 0, 0, NULL},
              normals = {0, 0, 0, NULL};
    CHECK_ERROR(ctx, pen_render_state_aovs(ctx, st, &mask, NULL, NULL), PEN_ERROR_ARGUMENT,
                "no forward pass");
    CHECK(pen_render_fwd(ctx, &sc, NULL, st, &img) == PEN_OK);
    CHECK(pen_render_state_aovs(ctx, st, &mask, &depth, &normals) == PEN_OK);
    CHECK(mask.width == 24 && mask.channels == 1 && depth.channels == 1 && normals.channels == 3);
    int objects = 0, ground = 0;
    for (int y = 0; y < 24; ++y)
        for (int x = 0; x < 24; ++x) {
            const size_t i = (size_t)y * 24 + (size_t)x;
            const float *n = normals.data + 3 * i;
            const double len = sqrt((double)n[0] * (double)n[0] + (double)n[1] * (double)n[1] +
                                    (double)n[2] * (double)n[2]);
            objects += mask.data[i] == 1.0f;
            CHECK(mask.data[i] == 0.0f || mask.data[i] == 1.0f);
            if (depth.data[i] == 0.0f) { /* the background: nothing seen */
                CHECK(mask.data[i] == 0.0f && len == 0.0);
                continue;
            }
            CHECK_MSG(fabs(len - 1.0) < 1e-5, "pixel %d %d: |n| = %g", x, y, len);
            /* The point at that depth on the pixel's ray, seen from the side its normal faces. */
            float dir[3];
            pen_camera_ray(&sc.camera, (float)x + 0.5f, (float)y + 0.5f, dir);
            double facing = 0.0;
            for (int a = 0; a < 3; ++a)
                facing += (double)n[a] * (double)dir[a];
            CHECK_MSG(facing <= 1e-4, "pixel %d %d: normal faces away (%g)", x, y, facing);
            ground += mask.data[i] == 0.0f && n[1] == 1.0f;
        }
    CHECK(objects > 20 && ground > 20);
    pen_image small = {0, 0, 0, NULL};
    CHECK(pen_image_create(ctx, 8, 8, 1, &small) == PEN_OK);
    CHECK_ERROR(ctx, pen_render_state_aovs(ctx, st, &small, NULL, NULL), PEN_ERROR_ARGUMENT,
                "mask image is 8x8x1");
    pen_image_free(&small), pen_image_free(&img), pen_image_free(&mask), pen_image_free(&depth),
        pen_image_free(&normals);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* A non-finite texel anywhere (in the validation's vector blocks, across a block's end, in the
 * tail) is refused with its message; the texture is 51 x 40 x 3 = 6120 floats: blocks of 4096
 * and 2024, the second 126 vector steps and 8 left over. */
static void test_invalid_texels(void) {
    pen_scene sc = rs_ball_scene(16, 1, &seed);
    pen_image_free(&sc.objects[0].texture);
    sc.objects[0].texture = rs_texture(51, 40, &seed);
    float *t = sc.objects[0].texture.data;
    pen_context *ctx = pen_context_create();
    CHECK(pen_scene_validate(ctx, &sc) == PEN_OK);
    const size_t at[] = {0, 15, 16, 4095, 4096, 6111, 6112, 6119};
    const float bad[] = {NAN, INFINITY, -INFINITY};
    for (size_t k = 0; k < sizeof at / sizeof at[0]; ++k)
        for (int b = 0; b < 3; ++b) {
            const float keep = t[at[k]];
            t[at[k]] = bad[b];
            expect_error(&sc, "non-finite texel");
            t[at[k]] = keep;
        }
    t[6119] = 3.0e38f; /* large but finite */
    CHECK(pen_scene_validate(ctx, &sc) == PEN_OK);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

RUN_TESTS(TEST(test_aovs), TEST(test_golden_plane), TEST(test_golden_sphere),
          TEST(test_shadow_depth_against_exact_occlusion),
          TEST(test_convex_object_does_not_shadow_itself), TEST(test_state_notices_new_topology),
          TEST(test_background_constant), TEST(test_losses), TEST(test_invalid_inputs),
          TEST(test_invalid_texels))
