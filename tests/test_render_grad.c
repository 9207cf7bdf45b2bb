/* Whole-image gradient checks of the renderer (src/render/forward.c, backward.c) against central finite
 * differences of the rendered image, for every parameter kind: SH lighting, constant and ground
 * albedo, texels, sphere centres and radii, pose rotation, translation and scale, and vertex
 * positions (interior and silhouettes, the latter through the antialiased render).
 *
 * The loss is a random projection of the image, L = sum_p q_p I_p with q_p in [0, 1], so that
 * d_image = q. The pipeline runs in float; each check states its step and tolerance:
 *   - lighting, albedo, texels: the image is linear in them, step 0.05, tolerance 1e-3 relative;
 *   - spheres: step 1e-3 scene units (1/50 pixel), tolerance 2e-2 relative to max(|FD|,
 *     |analytic|, 5% of the group's largest derivative);
 *   - pose, vertices: the geometry moves, and the antialiased image has isolated jumps; a
 *     jump-tolerant difference (fd_robust) with steps of about 1/500 pixel; random vertex
 *     directions 5e-2 relative on the textured ball (texel-centre kinks), 1e-2 for silhouettes
 *     alone; pose translations POSE_TOL relative to max(|FD|, |analytic|, POSE_FLOOR of the
 *     group's largest derivative), below.
 * The shading kernel itself is checked in double precision in tests/test_render_shade.c. Objects
 * shadow themselves through their spheres here ("self": "spheres"), the model whose pose,
 * shape and sphere gradients exist. */
#include "io_fixtures.h"
#include "render_scenes.h"
#include "render/render_internal.h" /* the footprint J, per-pixel albedo */

static unsigned long long seed = 4242;

/* A translation moves every outline pair of the image at once. The antialiasing blends each
 * pair at the silhouette edge its segment crosses, and on the ball's poles those edges are a
 * fraction of a pixel long: the crossing's position is curved in the translation (its second
 * derivative grows as 1 / edge length) and kinks where it passes from one edge to the next. 20
 * difference quotients at 1e-5 steps across +-1e-4 drift by up to 1 unit of derivative on
 * components whose analytic value is 0.2-1.2, around the analytic value, so a central difference
 * over +-1e-4 differs from it by up to 0.5% of the group's largest derivative (measured 0.17 of
 * 37, 0.006 of 2.5): a 2% tolerance with a 5% floor flagged those small components. */
#define POSE_TOL 5e-2
#define POSE_FLOOR 0.1

typedef struct fd_rig {
    pen_context *ctx;
    pen_render_state *st;
    pen_render_options opt;
    pen_image img;
    float *q;
} fd_rig;

static double projected(fd_rig *r, const pen_scene *sc) {
    pen_status s = pen_render_fwd(r->ctx, sc, &r->opt, r->st, &r->img);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(r->ctx));
    double l = 0.0;
    for (size_t i = 0; i < 3 * (size_t)r->img.width * (size_t)r->img.height; ++i)
        l += (double)r->q[i] * (double)r->img.data[i];
    return l;
}

/* Renders once and runs the backward with d_image = q. */
static fd_rig rig_grad(pen_scene *sc, int shadows, pen_render_grad *g) {
    fd_rig r;
    memset(&r, 0, sizeof r);
    r.ctx = pen_context_create();
    pen_context_set_threads(r.ctx, 1); /* many small renders: threads would only add overhead */
    r.opt = pen_render_options_default();
    r.opt.shadows = shadows;
    /* The sphere model for the objects' own shadows: the precomputed transfer (the default) is a
     * constant of the pose and shape, with no gradient (tests/test_self_transfer.c). */
    sc->shadow.self = PEN_SELF_SPHERES;
    pen_render_state_create(r.ctx, &r.st);
    pen_status s = pen_render_fwd(r.ctx, sc, &r.opt, r.st, &r.img);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(r.ctx));
    size_t n = 3 * (size_t)r.img.width * (size_t)r.img.height;
    r.q = malloc(sizeof(float) * n);
    for (size_t i = 0; i < n; ++i)
        r.q[i] = (float)check_rand_(&seed);
    pen_image d = {r.img.width, r.img.height, 3, r.q};
    s = pen_render_grad_create(r.ctx, sc, g);
    CHECK(s == PEN_OK);
    s = pen_render_bwd(r.ctx, sc, &r.opt, r.st, &d, PEN_GRAD_ALL, g);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(r.ctx));
    return r;
}

static void rig_free(fd_rig *r) {
    pen_render_state_free(r->st);
    pen_image_free(&r->img);
    free(r->q);
    pen_context_destroy(r->ctx);
}

/* Central difference of the projected loss in parameter *p. */
static double fd_of(fd_rig *r, const pen_scene *sc, float *p, float h) {
    const float keep = *p;
    *p = keep + h;
    const double lp = projected(r, sc);
    *p = keep - h;
    const double lm = projected(r, sc);
    *p = keep;
    return (lp - lm) / (2.0 * (double)h);
}

static int cmp_double(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Finite difference that tolerates isolated jumps. Moving geometry makes the antialiased image
 * continuous only up to isolated jumps (a silhouette corner crossing a pixel centre leaves about
 * half a pixel's colour difference, see docs/rasterizer.md), which the analytic gradient rightly
 * ignores but a central difference straddling one would not. So sample the loss at 17 points
 * across [-h, h], take the 16 consecutive difference quotients, drop those farther than 4 MADs
 * from their median (the jumps), and average the rest: the derivative of the continuous part. */
#define FD_SUB 16
static double fd_robust(double (*eval)(void *, double), void *arg, double h) {
    double l[FD_SUB + 1], q[FD_SUB], sorted[FD_SUB], dev[FD_SUB];
    for (int j = 0; j <= FD_SUB; ++j)
        l[j] = eval(arg, h * (2.0 * j / FD_SUB - 1.0));
    const double step = 2.0 * h / FD_SUB;
    for (int j = 0; j < FD_SUB; ++j)
        q[j] = sorted[j] = (l[j + 1] - l[j]) / step;
    qsort(sorted, FD_SUB, sizeof(double), cmp_double);
    const double med = 0.5 * (sorted[FD_SUB / 2 - 1] + sorted[FD_SUB / 2]);
    for (int j = 0; j < FD_SUB; ++j)
        dev[j] = fabs(q[j] - med);
    qsort(dev, FD_SUB, sizeof(double), cmp_double);
    const double mad = 0.5 * (dev[FD_SUB / 2 - 1] + dev[FD_SUB / 2]);
    double sum = 0.0;
    int kept = 0;
    for (int j = 0; j < FD_SUB; ++j)
        if (fabs(q[j] - med) <= 4.0 * mad + 1e-3 * fabs(med)) sum += q[j], ++kept;
    return sum / kept;
}

typedef struct param_arg {
    fd_rig *r;
    const pen_scene *sc;
    float *p;
    float keep;
} param_arg;

static double eval_param(void *arg, double offset) {
    param_arg *a = arg;
    *a->p = a->keep + (float)offset;
    const double l = projected(a->r, a->sc);
    *a->p = a->keep;
    return l;
}

static double fd_param(fd_rig *r, const pen_scene *sc, float *p, float h, int robust) {
    if (!robust) return fd_of(r, sc, p, h);
    param_arg a = {r, sc, p, *p};
    return fd_robust(eval_param, &a, (double)h);
}

/* Checks n parameters p[i * stride] against g[i * gstride]; scale_floor: fraction of the
 * group's largest |analytic| below which values count as that floor; robust: use fd_robust
 * (parameters that move geometry). Returns the worst ratio. */
static double check_group(fd_rig *r, const pen_scene *sc, const char *name, float *p, int stride,
                          const float *g, int gstride, int n, float h, double tol,
                          double scale_floor, int robust) {
    double gmax = 0.0;
    for (int i = 0; i < n; ++i)
        gmax = fmax(gmax, fabs((double)g[i * gstride]));
    double worst = 0.0;
    for (int i = 0; i < n; ++i) {
        const double fd = fd_param(r, sc, p + (size_t)i * (size_t)stride, h, robust);
        const double an = (double)g[i * gstride];
        const double scale = fmax(fmax(fabs(fd), fabs(an)), fmax(scale_floor * gmax, 1e-6));
        const double err = fabs(fd - an) / scale;
        worst = fmax(worst, err);
        CHECK_MSG(err <= tol, "%s[%d]: analytic %.6g, FD %.6g (rel %.3g)", name, i, an, fd, err);
    }
    CHECK_MSG(gmax > 0.0, "%s: all gradients are zero", name);
    if (getenv("PEN_TEST_VERBOSE"))
        printf("  %s: %d checked, worst relative error %.2g\n", name, n, worst);
    return worst;
}

/* ---- Linear parameters ----------------------------------------------------------------------- */

static void test_lighting_and_albedo(void) {
    for (int textured = 0; textured < 2; ++textured) {
        pen_scene sc = rs_ball_scene(32, textured, &seed);
        pen_render_grad g;
        fd_rig r = rig_grad(&sc, 1, &g);
        check_group(&r, &sc, "sh", &sc.lighting.sh[0][0], 1, &g.sh[0][0], 1, 48, 0.05f, 1e-3, 1e-3,
                    0);
        check_group(&r, &sc, "ground albedo", sc.ground.albedo, 1, g.ground_albedo, 1, 3, 0.05f,
                    1e-3, 1e-3, 0);
        if (!textured) {
            check_group(&r, &sc, "albedo", sc.objects[0].albedo, 1, g.objects[0].albedo, 1, 3,
                        0.05f, 1e-3, 1e-3, 0);
        } else {
            pen_image *t = &sc.objects[0].texture;
            check_group(&r, &sc, "texels", t->data, 1, g.objects[0].texture, 1,
                        3 * t->width * t->height, 0.05f, 1e-3, 1e-3, 0);
        }
        rig_free(&r);
        pen_render_grad_free(&g);
        pen_scene_free(&sc);
    }
}

/* The ground square shrunk until its far border lies in the image: the border's pixels blend
 * ground and background (pen__ground_border_fwd), and the lighting's and the ground albedo's
 * gradients pass through that blend's transpose. */
static void test_ground_border_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 0, &seed);
    sc.ground.half_size = 1.2f;
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    const pen_gbuffer *gb = &r.st->gb;
    int pairs = 0;
    for (int y = 0; y < gb->height; ++y)
        for (int x = 0; x + 1 < gb->width; ++x) {
            const int a = gb->surface[y * gb->width + x], b = gb->surface[y * gb->width + x + 1];
            pairs += (a == PEN_SURFACE_GROUND) != (b == PEN_SURFACE_GROUND) &&
                     (a == PEN_SURFACE_BACKGROUND || b == PEN_SURFACE_BACKGROUND);
        }
    CHECK_MSG(pairs >= 4, "the ground's border is not in view (%d pairs)", pairs);
    check_group(&r, &sc, "sh", &sc.lighting.sh[0][0], 1, &g.sh[0][0], 1, 48, 0.05f, 1e-3, 1e-3, 0);
    check_group(&r, &sc, "ground albedo", sc.ground.albedo, 1, g.ground_albedo, 1, 3, 0.05f, 1e-3,
                1e-3, 0);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* ---- Spheres (occluders of the ground, self-shadowing of the ball) --------------------------- */

static void test_sphere_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 0, &seed);
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    /* Step 1e-3 scene units (a pixel is about 0.05 at this distance). */
    check_group(&r, &sc, "sphere", sc.objects[0].spheres.data, 1, g.objects[0].spheres, 1, 8, 1e-3f,
                2e-2, 0.05, 0);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* A sphere set alone over the ground, its mesh out of view: the gradient comes only through the
 * shadow on the receiver. */
static void test_occluder_only(void) {
    pen_scene sc = rs_ball_scene(32, 0, &seed);
    pen_pose *ps = &sc.objects[0].pose;
    /* The mesh far outside the ground and the view, the spheres where they were. */
    ps->rotation_axis_angle_deg[0] = ps->rotation_axis_angle_deg[1] = 0.0f;
    ps->translation[0] = 40.0f;
    for (int i = 0; i < 2; ++i)
        sc.objects[0].spheres.data[4 * i] -= 40.0f;
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    check_group(&r, &sc, "occluder sphere", sc.objects[0].spheres.data, 1, g.objects[0].spheres, 1,
                8, 1e-3f, 2e-2, 0.05, 0);
    for (int i = 0; i < 3 * g.objects[0].vertex_count; ++i)
        CHECK(g.objects[0].positions[i] == 0.0f);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* Self-shadowing in the pipeline: proxy spheres that stick out of the ellipsoid put many of its
 * surface points inside the self-shadowing weight's ramp (-1 < h < 1), so the weight's
 * derivative carries part of the sphere and pose gradients. */
static void test_self_shadowing_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 0, &seed);
    pen_object *ob = &sc.objects[0];
    const float big[8] = {-0.22f, 0.05f, 0.0f, 0.42f, 0.25f, 0.0f, 0.05f, 0.38f};
    memcpy(ob->spheres.data, big, sizeof big);
    /* Share of vertices (with their smooth normals) that see an own sphere inside the ramp. */
    const int V = ob->mesh.vertex_count;
    float *nrm = malloc(sizeof(float) * 3 * (size_t)V);
    pen_vertex_normals_fwd(NULL, V, ob->mesh.positions, ob->mesh.triangle_count, ob->mesh.indices,
                           nrm);
    int ramp = 0;
    for (int v = 0; v < V; ++v) {
        int in = 0;
        for (int i = 0; i < 2; ++i) {
            const float *c = big + 4 * i, *x = ob->mesh.positions + 3 * v, *n = nrm + 3 * v;
            const float h =
                (n[0] * (c[0] - x[0]) + n[1] * (c[1] - x[1]) + n[2] * (c[2] - x[2])) / c[3];
            in |= h > -1.0f && h < 1.0f;
        }
        ramp += in;
    }
    free(nrm);
    CHECK_MSG(ramp > V / 5, "only %d of %d vertices in the ramp", ramp, V);
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    check_group(&r, &sc, "self-shadowing sphere", ob->spheres.data, 1, g.objects[0].spheres, 1, 8,
                1e-3f, 2e-2, 0.05, 0);
    check_group(&r, &sc, "self-shadowing translation", ob->pose.translation, 1,
                g.objects[0].pose.translation, 1, 3, 1e-4f, POSE_TOL, POSE_FLOOR, 1);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* Two objects: a small ball whose spheres shadow the ellipsoid and the ground. Its sphere and
 * pose gradients flow through the other object's pixels too. */
static void test_two_objects(void) {
    pen_scene sc = rs_ball_scene(32, 1, &seed);
    /* The proxy lies just inside the ball (its surface points see it behind their tangent
     * planes), large and close enough that the float render resolves its cap's motion: a small
     * far cap's coefficients cancel in float (P_{l-1} - P_{l+1} near cos a = 1), which makes
     * differences of the render noisy while the analytic gradient stays exact. */
    const float s[4] = {0.0f, 0.0f, 0.0f, 0.24f};
    pen_object *b = rs_add_object(&sc, rs_octasphere(2, 0.25f, 0), 1, s);
    b->pose.translation[0] = -0.45f, b->pose.translation[1] = 1.0f;
    b->pose.translation[2] = 0.2f;
    b->albedo[0] = 0.3f, b->albedo[1] = 0.7f, b->albedo[2] = 0.4f;
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    check_group(&r, &sc, "second object's sphere", b->spheres.data, 1, g.objects[1].spheres, 1, 4,
                1e-3f, 2e-2, 0.05, 0);
    check_group(&r, &sc, "second object's translation", b->pose.translation, 1,
                g.objects[1].pose.translation, 1, 3, 1e-4f, POSE_TOL, POSE_FLOOR, 1);
    check_group(&r, &sc, "second object's albedo", b->albedo, 1, g.objects[1].albedo, 1, 3, 0.05f,
                1e-3, 1e-3, 0);
    check_group(&r, &sc, "first object's sphere", sc.objects[0].spheres.data, 1,
                g.objects[0].spheres, 1, 8, 1e-3f, 2e-2, 0.05, 0);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* ---- Pose ------------------------------------------------------------------------------------ */

static void test_pose_gradients(void) {
    for (int shadows = 0; shadows < 2; ++shadows) {
        pen_scene sc = rs_ball_scene(32, 1, &seed);
        /* The plain sphere sum (every overlap weight 1). The float FD of the pose groups has
         * percent-level rounding noise that moves with the image (the scale's error was 0.1 to
         * 3.7 % as both weights went from 1 to 2, erratically, against a tolerance of 2 %, with
         * larger and smaller FD steps confirming the analytic value); the weights are constant
         * factors of the kernel, checked in double in test_render_shade.c and through the
         * sphere groups above. */
        sc.shadow.overlap = PEN_OVERLAP_NONE;
        /* Point lookups: the footprint filter's J is the triangle's own, and jumps slightly
         * where an edge between facets of the coarse ball crosses a pixel centre, which these
         * steps do (test_footprint_gradients). */
        sc.objects[0].texture_filter = PEN_TEXTURE_FILTER_POINT;
        pen_render_grad g;
        fd_rig r = rig_grad(&sc, shadows, &g);
        pen_pose *ps = &sc.objects[0].pose;
        pen_pose_grad *gp = &g.objects[0].pose;
        /* Steps: 0.02 degrees, 1e-4 units (about 1/500 pixel: the bilinear texture has kinks
         * at texel centres, dense enough that larger steps average over them). */
        check_group(&r, &sc, shadows ? "rotation" : "rotation (no shadows)",
                    ps->rotation_axis_angle_deg, 1, gp->rotation_axis_angle_deg, 1, 3, 0.02f, 2e-2,
                    0.05, 1);
        check_group(&r, &sc, shadows ? "translation" : "translation (no shadows)", ps->translation,
                    1, gp->translation, 1, 3, 1e-4f, POSE_TOL, POSE_FLOOR, 1);
        check_group(&r, &sc, "scale", &ps->scale, 1, &gp->scale, 1, 1, 1e-4f, 2e-2, 0.05, 1);
        rig_free(&r);
        pen_render_grad_free(&g);
        pen_scene_free(&sc);
    }
}

/* ---- Vertices -------------------------------------------------------------------------------- */

typedef struct vertex_arg {
    fd_rig *r;
    const pen_scene *sc;
    float *pos;
    const float *keep, *delta;
    size_t n;
} vertex_arg;

static double eval_vertices(void *arg, double offset) {
    vertex_arg *a = arg;
    for (size_t i = 0; i < a->n; ++i)
        a->pos[i] = a->keep[i] + (float)offset * a->delta[i];
    return projected(a->r, a->sc);
}

/* Directional derivative along random vertex displacements delta (object space, each coordinate
 * in [-1, 1]) against fd_robust of the render with step 1e-4. */
static void check_vertex_directions(const char *name, pen_scene *sc, int shadows, int trials,
                                    double tol) {
    pen_render_grad g;
    fd_rig r = rig_grad(sc, shadows, &g);
    pen_mesh *m = &sc->objects[0].mesh;
    const size_t n = 3 * (size_t)m->vertex_count;
    float *keep = malloc(sizeof(float) * n), *delta = malloc(sizeof(float) * n);
    memcpy(keep, m->positions, sizeof(float) * n);
    double gnorm = 0.0;
    for (size_t i = 0; i < n; ++i)
        gnorm += (double)g.objects[0].positions[i] * (double)g.objects[0].positions[i];
    CHECK_MSG(gnorm > 0.0, "%s: zero vertex gradient", name);
    for (int t = 0; t < trials; ++t) {
        double an = 0.0;
        for (size_t i = 0; i < n; ++i) {
            delta[i] = (float)(2.0 * check_rand_(&seed) - 1.0);
            an += (double)delta[i] * (double)g.objects[0].positions[i];
        }
        vertex_arg va = {&r, sc, m->positions, keep, delta, n};
        const double fd = fd_robust(eval_vertices, &va, 1e-4);
        memcpy(m->positions, keep, sizeof(float) * n);
        /* Floor: 5% of the gradient's norm times the typical |delta| (a random direction). */
        const double scale = fmax(fmax(fabs(fd), fabs(an)), 0.05 * sqrt(gnorm / 3.0));
        if (getenv("PEN_TEST_VERBOSE"))
            printf("  %s trial %d: analytic %.6g, FD %.6g, relative error %.2g\n", name, t, an, fd,
                   fabs(fd - an) / scale);
        CHECK_MSG(fabs(fd - an) <= tol * scale, "%s trial %d: analytic %.6g, FD %.6g (rel %.3g)",
                  name, t, an, fd, fabs(fd - an) / scale);
    }
    free(keep), free(delta);
    rig_free(&r);
    pen_render_grad_free(&g);
}

static void test_vertex_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 1, &seed);
    sc.objects[0].texture_filter = PEN_TEXTURE_FILTER_POINT; /* as in test_pose_gradients */
    /* Tolerance 5e-2: the bilinear texture's kinks at texel centres bend the image within the
     * step (measured worst 3.9%, on a small directional derivative). */
    check_vertex_directions("vertices (textured, shadows)", &sc, 1, 4, 5e-2);
    pen_scene_free(&sc);
}

/* Silhouettes alone: DC-only lighting and no shadows make the ball's colour independent of its
 * normals, positions and UVs, so every vertex gradient comes from the antialiased silhouette
 * against the ground and the background. */
static void test_silhouette_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 0, &seed);
    for (int k = 1; k < 16; ++k)
        sc.lighting.sh[k][0] = sc.lighting.sh[k][1] = sc.lighting.sh[k][2] = 0;
    sc.camera.eye[1] = 0.9f; /* lower, so the silhouette crosses the background too */
    check_vertex_directions("vertices (silhouettes only)", &sc, 0, 4, 1e-2);
    /* With antialiasing off, the same scene has no vertex gradient at all. */
    pen_context *ctx = pen_context_create();
    pen_render_state *st = NULL;
    pen_render_state_create(ctx, &st);
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0, opt.antialias = 0;
    pen_image img = {0, 0, 0, NULL}, d = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    pen_image_create(ctx, img.width, img.height, 3, &d);
    for (int i = 0; i < 3 * img.width * img.height; ++i)
        d.data[i] = 1.0f;
    pen_render_grad g;
    pen_render_grad_create(ctx, &sc, &g);
    CHECK(pen_render_bwd(ctx, &sc, &opt, st, &d, PEN_GRAD_VERTICES, &g) == PEN_OK);
    double gmax = 0.0;
    for (int i = 0; i < 3 * g.objects[0].vertex_count; ++i)
        gmax = fmax(gmax, fabs((double)g.objects[0].positions[i]));
    CHECK_MSG(gmax < 1e-4, "no-antialias vertex gradient %.3g", gmax);
    pen_render_grad_free(&g);
    pen_image_free(&img), pen_image_free(&d);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* ---- Disk lights ----------------------------------------------------------------------------- */

/* Adds a disk light at elevation `elev_deg` above the horizon, azimuth `az_deg`. */
static void add_light(pen_scene *sc, double elev_deg, double az_deg, float radius_deg, float E) {
    pen_light *l = &sc->lighting.lights[sc->lighting.light_count++];
    const double el = elev_deg * M_PI / 180, az = az_deg * M_PI / 180;
    l->direction[0] = (float)(cos(el) * cos(az));
    l->direction[1] = (float)sin(el);
    l->direction[2] = (float)(cos(el) * sin(az));
    l->angular_radius_deg = radius_deg;
    l->irradiance[0] = E, l->irradiance[1] = 0.9f * E, l->irradiance[2] = 0.7f * E;
    sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
}

/* The ball scene under a sun (3 degrees, casting the ball's shadow into view with a penumbra)
 * and a wide light straddling both the ground's horizon seen from the ball and the ground's own
 * tangent plane: every group against finite differences of the float render, the lights' own
 * derivatives included (the per-pixel term is checked in double in tests/test_lights.c). */
static void test_disk_light_gradients(void) {
    pen_scene sc = rs_ball_scene(40, 0, &seed);
    add_light(&sc, 50.0, -150.0, 3.0f, 2.0f);
    add_light(&sc, -5.0, 150.0, 8.0f, 1.5f);
    sc.shadow.overlap = PEN_OVERLAP_NONE; /* as test_pose_gradients: float noise of the pose */
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 1, &g);
    CHECK(g.light_count == 2);
    for (int l = 0; l < 2; ++l) {
        pen_light *L = &sc.lighting.lights[l];
        pen_light_grad *G = &g.lights[l];
        char name[64];
        snprintf(name, sizeof name, "light %d direction", l);
        check_group(&r, &sc, name, L->direction, 1, G->direction, 1, 3, 2e-3f, 2e-2, 0.05, 0);
        /* step 0.005 degrees: the penumbra pixels' curvature in b shows at larger steps (FD off
         * the analytic value by 1%, 11%, 23% at 0.005, 0.05, 0.2 degrees on the sun) */
        snprintf(name, sizeof name, "light %d radius", l);
        check_group(&r, &sc, name, &L->angular_radius_deg, 1, &G->angular_radius_deg, 1, 1, 0.005f,
                    2e-2, 0.05, 0);
        snprintf(name, sizeof name, "light %d irradiance", l);
        check_group(&r, &sc, name, L->irradiance, 1, G->irradiance, 1, 3, 0.05f, 1e-3, 1e-3, 0);
    }
    check_group(&r, &sc, "albedo (lights)", sc.objects[0].albedo, 1, g.objects[0].albedo, 1, 3,
                0.05f, 1e-3, 1e-3, 0);
    check_group(&r, &sc, "ground albedo (lights)", sc.ground.albedo, 1, g.ground_albedo, 1, 3,
                0.05f, 1e-3, 1e-3, 0);
    check_group(&r, &sc, "sphere (lights)", sc.objects[0].spheres.data, 1, g.objects[0].spheres, 1,
                8, 1e-3f, 2e-2, 0.05, 0);
    pen_pose *ps = &sc.objects[0].pose;
    pen_pose_grad *gp = &g.objects[0].pose;
    check_group(&r, &sc, "rotation (lights)", ps->rotation_axis_angle_deg, 1,
                gp->rotation_axis_angle_deg, 1, 3, 0.02f, 2e-2, 0.05, 1);
    check_group(&r, &sc, "translation (lights)", ps->translation, 1, gp->translation, 1, 3, 1e-4f,
                POSE_TOL, POSE_FLOOR, 1);
    check_group(&r, &sc, "scale (lights)", &ps->scale, 1, &gp->scale, 1, 1, 1e-4f, 2e-2, 0.05, 1);
    rig_free(&r);
    pen_render_grad_free(&g);
    check_vertex_directions("vertices (lights)", &sc, 1, 4, 5e-2);
    pen_scene_free(&sc);
}

/* ---- Determinism and finiteness -------------------------------------------------------------- */

/* 1 and 3 threads give bitwise equal images and gradients. */
static void test_thread_count_independent(void) {
    pen_scene sc = rs_ball_scene(32, 1, &seed);
    pen_render_grad_model(&sc, PEN_GRAD_ALL); /* every group has its gradient */
    pen_render_grad g[2];
    float *img[2];
    for (int k = 0; k < 2; ++k) {
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, k ? 3 : 1);
        pen_render_state *st = NULL;
        pen_render_state_create(ctx, &st);
        pen_image im = {0, 0, 0, NULL}, d = {0, 0, 0, NULL};
        CHECK(pen_render_fwd(ctx, &sc, NULL, st, &im) == PEN_OK);
        pen_image_create(ctx, im.width, im.height, 3, &d);
        unsigned long long s2 = 99;
        for (int i = 0; i < 3 * im.width * im.height; ++i)
            d.data[i] = (float)check_rand_(&s2);
        pen_render_grad_create(ctx, &sc, &g[k]);
        CHECK(pen_render_bwd(ctx, &sc, NULL, st, &d, PEN_GRAD_ALL, &g[k]) == PEN_OK);
        img[k] = im.data;
        pen_image_free(&d);
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    const size_t n = 3 * 32 * 32;
    CHECK(memcmp(img[0], img[1], sizeof(float) * n) == 0);
    CHECK(memcmp(g[0].sh, g[1].sh, sizeof g[0].sh) == 0);
    const pen_object_grad *a = &g[0].objects[0], *b = &g[1].objects[0];
    CHECK(memcmp(a->positions, b->positions, sizeof(float) * 3 * (size_t)a->vertex_count) == 0);
    CHECK(memcmp(a->spheres, b->spheres, sizeof(float) * 4 * (size_t)a->sphere_count) == 0);
    CHECK(memcmp(a->texture, b->texture, sizeof(float) * 3 * (size_t)a->texel_count) == 0);
    CHECK(memcmp(&a->pose, &b->pose, sizeof a->pose) == 0);
    for (int k = 0; k < 2; ++k)
        free(img[k]), pen_render_grad_free(&g[k]);
    pen_scene_free(&sc);
}

/* The texel gradient of footprint lookups, scattered by row bands in parallel, equals the serial
 * scatter's bit for bit: a frame large enough for the threads, 1 against 2 and 3 threads, and
 * against pen__texture_footprint_bwd pixel by pixel in pixel order. */
static void texel_scatter_case(pen_scene sc) {
    CHECK(sc.objects[0].texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT);
    const unsigned wrt = PEN_GRAD_ALBEDO | PEN_GRAD_LIGHTING;
    pen_render_grad g[3];
    pen_render_state *st0 = NULL;
    pen_context *ctx0 = NULL;
    for (int k = 0; k < 3; ++k) {
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, k + 1);
        pen_render_state *st = NULL;
        pen_render_state_create(ctx, &st);
        pen_image im = {0, 0, 0, NULL}, d = {0, 0, 0, NULL};
        CHECK(pen_render_fwd(ctx, &sc, NULL, st, &im) == PEN_OK);
        pen_image_create(ctx, im.width, im.height, 3, &d);
        unsigned long long s2 = 7;
        for (int i = 0; i < 3 * im.width * im.height; ++i)
            d.data[i] = (float)check_rand_(&s2);
        pen_render_grad_create(ctx, &sc, &g[k]);
        CHECK(pen_render_bwd(ctx, &sc, NULL, st, &d, wrt, &g[k]) == PEN_OK);
        pen_image_free(&im), pen_image_free(&d);
        if (k == 0) {
            st0 = st, ctx0 = ctx;
            continue;
        }
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    const pen_object_grad *a = &g[0].objects[0];
    size_t nonzero = 0;
    for (size_t i = 0; i < 3 * (size_t)a->texel_count; ++i)
        nonzero += a->texture[i] != 0.0f;
    CHECK(nonzero > 0);
    for (int k = 1; k < 3; ++k)
        CHECK(memcmp(a->texture, g[k].objects[0].texture, sizeof(float) * 3 * (size_t)a->texel_count) ==
              0);
    /* the serial reference, from the 1-thread state's pixels */
    float *ref = calloc(3 * (size_t)a->texel_count, sizeof(float));
    const size_t np = (size_t)st0->width * (size_t)st0->height;
    for (size_t i = 0; i < np; ++i)
        if (st0->gb.surface[i] == 0)
            pen__texture_footprint_bwd(&sc.objects[0].texture, st0->uv.data + 2 * i,
                                       st0->uvj.data + 4 * i, st0->d_rho.data + 3 * i, ref, NULL,
                                       NULL);
    CHECK(memcmp(ref, a->texture, sizeof(float) * 3 * (size_t)a->texel_count) == 0);
    free(ref);
    for (int k = 0; k < 3; ++k)
        pen_render_grad_free(&g[k]);
    pen_render_state_free(st0);
    pen_context_destroy(ctx0);
    pen_scene_free(&sc);
}

/* The bands (backward.c, texel_bands) are cut where the pixels' rows fall: the ball's own
 * texture coordinates; coordinates repeated 3.3 times down the texture from 0.37, so lookups wrap
 * across its last row into its first; and repeated 150 times, so footprints reach every row; the
 * same three on a texture of 5000 rows (more than the 4096 bins: a bin holds two rows, and a band
 * many), where footprints are a few rows high and bands have rows to split. */
static void test_texel_scatter_threads(void) {
    const float repeat[3] = {1.0f, 3.3f, 150.0f};
    for (int c = 0; c < 6; ++c) {
        pen_scene sc = rs_ball_scene(96, 1, &seed);
        if (c >= 3) {
            pen_image_free(&sc.objects[0].texture);
            sc.objects[0].texture = rs_texture(7, 5000, &seed);
        }
        pen_mesh *m = &sc.objects[0].mesh;
        for (int k = 0; c % 3 > 0 && k < m->uv_count; ++k) {
            m->uvs[2 * k] *= repeat[c % 3];
            m->uvs[2 * k + 1] = 0.37f + repeat[c % 3] * m->uvs[2 * k + 1];
        }
        texel_scatter_case(sc);
    }
}

static int grad_finite(const pen_render_grad *g) {
    int ok = rs_all_finite(&g->sh[0][0], sizeof g->sh / sizeof(float)) &&
             rs_all_finite(g->ground_albedo, 3);
    for (int o = 0; o < g->object_count; ++o) {
        const pen_object_grad *og = &g->objects[o];
        ok = ok && rs_all_finite(og->albedo, 3) &&
             rs_all_finite(og->positions, 3 * (size_t)og->vertex_count) &&
             rs_all_finite(og->spheres, 4 * (size_t)og->sphere_count) &&
             rs_all_finite(og->pose.rotation_axis_angle_deg, 3) &&
             rs_all_finite(og->pose.translation, 3) && isfinite(og->pose.scale) &&
             (!og->texture || rs_all_finite(og->texture, 3 * (size_t)og->texel_count));
    }
    return ok;
}

/* Torture inputs: the ground inside a big sphere (receivers inside and on it), a sphere centred
 * on the ground, zero-area and repeated-vertex triangles, a grazing camera. */
static void test_torture_finite(void) {
    for (int variant = 0; variant < 3; ++variant) {
        pen_scene sc = rs_ball_scene(32, 1, &seed);
        pen_object *ob = &sc.objects[0];
        if (variant == 0) {
            /* A sphere swallowing part of the ground and of the ball; one centred on the ground. */
            float sph[8] = {0.0f, -0.55f, 0.0f, 1.2f, 0.5f, -0.55f, 0.5f, 0.4f};
            memcpy(ob->spheres.data, sph, sizeof sph);
        } else if (variant == 1) {
            /* Degenerate triangles: collapse some triangles to a point or a segment. */
            pen_mesh *m = &ob->mesh;
            for (int t = 0; t < m->triangle_count; t += 7)
                m->indices[3 * t + 1] = m->indices[3 * t];
            for (int t = 3; t < m->triangle_count; t += 11) {
                const uint32_t a = m->indices[3 * t], b = m->indices[3 * t + 1];
                for (int k = 0; k < 3; ++k)
                    m->positions[3 * b + k] = m->positions[3 * a + k];
            }
        } else {
            /* Grazing: the eye just above the ground looking along it. */
            sc.camera.eye[0] = 0.0f, sc.camera.eye[1] = 0.02f, sc.camera.eye[2] = 2.9f;
            sc.camera.target[0] = 0.0f, sc.camera.target[1] = 0.0f, sc.camera.target[2] = -3.0f;
        }
        pen_render_grad g;
        fd_rig r = rig_grad(&sc, 1, &g);
        CHECK_MSG(rs_all_finite(r.img.data, 3 * 32 * 32), "variant %d: image", variant);
        CHECK_MSG(grad_finite(&g), "variant %d: gradient", variant);
        rig_free(&r);
        pen_render_grad_free(&g);
        pen_scene_free(&sc);
    }
}

/* ---- Footprint-filtered texture ------------------------------------------------------------ */

/* The footprint filter (src/render/footprint.c): the backward of J = d(uv)/d(pixel) against a
 * central difference in double of the posed vertices (pixels that keep their triangle), and the
 * pose translation through the filtered texture. */
static void test_footprint_gradients(void) {
    pen_scene sc = rs_ball_scene(32, 1, &seed);
    pen_render_grad g;
    fd_rig r = rig_grad(&sc, 0, &g);
    pen_render_state *st = r.st;
    pen_object *ob = &sc.objects[0];
    const size_t np = (size_t)st->width * (size_t)st->height, V = (size_t)ob->mesh.vertex_count;
    int32_t *tri = malloc(sizeof(int32_t) * np);
    float *c = malloc(sizeof(float) * 4 * np), *dw = calloc(3 * V, sizeof(float));
    memcpy(tri, st->gb.triangle, sizeof(int32_t) * np);
    for (size_t i = 0; i < 4 * np; ++i)
        c[i] = (float)(2.0 * check_rand_(&seed) - 1.0);
    CHECK(PEN__BUF_RESERVE(r.ctx, st->d_uvj, 4 * np, "test") == PEN_OK);
    memcpy(st->d_uvj.data, c, sizeof(float) * 4 * np);
    pen__uv_footprint_bwd(st, ob, 0, dw);
    float *w = st->obj[0].world.data;
    int checked = 0;
    for (size_t v = 0; v < V; v += 3)
        for (int a = 0; a < 3; ++a) {
            const float keep = w[3 * v + a];
            double L[2];
            for (int side = 0; side < 2; ++side) {
                w[3 * v + a] = keep + (side ? -1e-4f : 1e-4f);
                pen__uv_footprint_fwd(st, ob, 0, 1);
                L[side] = 0.0;
                for (size_t i = 0; i < np; ++i)
                    if (st->gb.surface[i] == 0 && st->gb.triangle[i] == tri[i])
                        for (int k = 0; k < 4; ++k)
                            L[side] += (double)c[4 * i + k] * (double)st->uvj.data[4 * i + k];
            }
            w[3 * v + a] = keep;
            const double h = ((double)(keep + 1e-4f) - (double)(keep - 1e-4f)) / 2.0;
            const double fd = (L[0] - L[1]) / (2.0 * h), an = (double)dw[3 * v + a];
            CHECK_REL(an, fd, 1e-2, 1e-2 * fmax(1.0, fabs(fd)));
            checked += fd != 0.0;
        }
    CHECK(checked > 10);
    /* Rigid translations: the pixels' triangles shift by a fraction of a pixel only. */
    check_group(&r, &sc, "translation (footprint)", ob->pose.translation, 1,
                g.objects[0].pose.translation, 1, 3, 1e-4f, POSE_TOL, POSE_FLOOR, 1);
    free(tri), free(c), free(dw);
    rig_free(&r);
    pen_render_grad_free(&g);
    pen_scene_free(&sc);
}

/* A checkerboard of 1-texel squares, several to a pixel, seen through the footprint filter
 * comes out close to its mean grey (measured rms 0.057 from 0.5); one point lookup per pixel
 * aliases it (0.174; bilinear lookups between the squares already blend them partly). */
static void test_footprint_checkerboard(void) {
    double spread[2];
    for (int point = 0; point < 2; ++point) {
        pen_scene sc = rs_ball_scene(32, 1, &seed);
        pen_image *t = &sc.objects[0].texture;
        pen_image_free(t);
        CHECK(pen_image_create(NULL, 256, 256, 3, t) == PEN_OK);
        for (int y = 0; y < 256; ++y)
            for (int x = 0; x < 256; ++x)
                for (int ch = 0; ch < 3; ++ch)
                    t->data[3 * (y * 256 + x) + ch] = (float)((x + y) & 1);
        sc.objects[0].texture_filter = point ? PEN_TEXTURE_FILTER_POINT
                                             : PEN_TEXTURE_FILTER_FOOTPRINT;
        pen_render_grad g;
        fd_rig r = rig_grad(&sc, 0, &g);
        double sum = 0.0;
        int n = 0;
        for (size_t i = 0; i < (size_t)r.st->width * (size_t)r.st->height; ++i)
            if (r.st->gb.surface[i] == 0) {
                const double d = (double)r.st->rho.data[3 * i] - 0.5;
                sum += d * d, ++n;
            }
        spread[point] = sqrt(sum / n);
        if (getenv("PEN_TEST_VERBOSE"))
            printf("  checkerboard, %s: rms albedo - 0.5 = %.3f over %d pixels\n",
                   point ? "point" : "footprint", spread[point], n);
        rig_free(&r);
        pen_render_grad_free(&g);
        pen_scene_free(&sc);
    }
    CHECK_MSG(spread[0] < 0.1 && spread[1] > 2.5 * spread[0],
              "rms from grey: footprint %.3f, point %.3f",
              spread[0], spread[1]);
}

/* The model a gradient needs (render.h): under the transfer (the default) the groups it holds
 * constant are refused, naming the group and the setting, computing nothing; lighting and albedo
 * pass; pen_render_grad_model switches to the model whose gradients are all exact (the rule the
 * optimizer follows), which renders as a scene keyed that way in its JSON, bit for bit. */
static void test_grad_model_rule(void) {
    pen_scene a = rs_ball_scene(24, 1, &seed), b = rs_ball_scene(24, 1, &seed);
    const size_t texels = (size_t)a.objects[0].texture.width * a.objects[0].texture.height * 3;
    for (size_t i = 0; i < texels; ++i)
        b.objects[0].texture.data[i] = a.objects[0].texture.data[i];
    CHECK(a.shadow.self == PEN_SELF_TRANSFER &&
          a.objects[0].texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT);
    b.shadow.self = PEN_SELF_SPHERES, b.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
    b.objects[0].texture_filter = PEN_TEXTURE_FILTER_POINT;
    const pen_render_options opt = pen_render_options_default();
    pen_render_options off = opt;
    off.shadows = 0;
    const unsigned constant =
        PEN_GRAD_POSE | PEN_GRAD_VERTICES | PEN_GRAD_SPHERES | PEN_GRAD_LIGHTS;
    CHECK(pen_render_grad_exact(&a, &opt) == (PEN_GRAD_ALL & ~constant));
    CHECK(pen_render_grad_exact(&a, &off) == PEN_GRAD_ALL); /* no transfer without shadows */
    CHECK(pen_render_grad_exact(&b, &opt) == PEN_GRAD_ALL);

    pen_context *ctx = pen_context_create();
    pen_image ia = {0, 0, 0, NULL}, ib = {0, 0, 0, NULL}, d = {0, 0, 0, NULL};
    pen_render_state *sa = NULL, *sb = NULL;
    pen_render_grad ga, gb;
    CHECK(pen_render_state_create(ctx, &sa) == PEN_OK);
    CHECK(pen_render_state_create(ctx, &sb) == PEN_OK);
    CHECK(pen_render_fwd(ctx, &a, &opt, sa, &ia) == PEN_OK);
    const size_t n = 3 * (size_t)ia.width * (size_t)ia.height;
    CHECK(pen_image_create(ctx, ia.width, ia.height, 3, &d) == PEN_OK);
    for (size_t i = 0; i < n; ++i) d.data[i] = (float)((i % 7) + 1) / 7.0f;
    CHECK(pen_render_grad_create(ctx, &a, &ga) == PEN_OK);
    static const struct { unsigned bit; const char *name; } refused[] = {
        {PEN_GRAD_SPHERES, "no sphere gradient"}, {PEN_GRAD_POSE, "no pose gradient"},
        {PEN_GRAD_VERTICES, "no vertex gradient"}, {PEN_GRAD_LIGHTS, "no disk-light gradient"}};
    for (int k = 0; k < 4; ++k) {
        ga.objects[0].pose.translation[0] = 7.0f; /* a refusal computes nothing */
        CHECK_ERROR(ctx, pen_render_bwd(ctx, &a, &opt, sa, &d, refused[k].bit | PEN_GRAD_LIGHTING,
                                        &ga),
                    PEN_ERROR_ARGUMENT, refused[k].name, "\"self\": \"transfer\"",
                    "\"self\": \"spheres\"");
        CHECK(ga.objects[0].pose.translation[0] == 7.0f && ga.sh[0][0] == 0.0f);
    }
    pen_render_grad_zero(&ga);
    CHECK(pen_render_bwd(ctx, &a, &opt, sa, &d, PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO, &ga) ==
          PEN_OK);
    CHECK(ga.sh[0][0] != 0.0f);

    /* The rule: pose switches shadows and textures; lighting alone changes nothing. */
    pen_scene c = a;
    CHECK(pen_render_grad_model(&c, PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO) == 0);
    CHECK(pen_render_grad_model(&a, PEN_GRAD_POSE) == PEN_GRAD_POSE);
    CHECK(a.shadow.self == PEN_SELF_SPHERES && a.shadow.ground_shadow == PEN_GROUND_SHADOW_SPHERES &&
          a.objects[0].texture_filter == PEN_TEXTURE_FILTER_POINT);
    CHECK(pen_render_grad_model(&a, PEN_GRAD_ALL) == 0);
    /* A backward after the model changed under it is refused. */
    CHECK_ERROR(ctx, pen_render_bwd(ctx, &a, &opt, sa, &d, PEN_GRAD_LIGHTING, &ga),
                PEN_ERROR_ARGUMENT, "scene changed");
    CHECK(pen_render_fwd(ctx, &a, &opt, sa, &ia) == PEN_OK);
    CHECK(pen_render_fwd(ctx, &b, &opt, sb, &ib) == PEN_OK);
    CHECK(memcmp(ia.data, ib.data, sizeof(float) * n) == 0);
    CHECK(pen_render_grad_create(ctx, &b, &gb) == PEN_OK);
    pen_render_grad_zero(&ga);
    CHECK(pen_render_bwd(ctx, &a, &opt, sa, &d, PEN_GRAD_ALL, &ga) == PEN_OK);
    CHECK(pen_render_bwd(ctx, &b, &opt, sb, &d, PEN_GRAD_ALL, &gb) == PEN_OK);
    CHECK(memcmp(ga.objects[0].texture, gb.objects[0].texture, sizeof(float) * texels) == 0);
    const float *ta = ga.objects[0].pose.translation, *tb = gb.objects[0].pose.translation;
    CHECK(memcmp(ta, tb, sizeof(float) * 3) == 0 && ta[0] != 0.0f);
    pen_render_options other = opt;
    other.antialias = 0;
    CHECK(pen_render_bwd(ctx, &a, &other, sa, &d, PEN_GRAD_ALL, &ga) != PEN_OK);
    pen_image_free(&ia), pen_image_free(&ib), pen_image_free(&d);
    pen_render_grad_free(&ga), pen_render_grad_free(&gb);
    pen_render_state_free(sa), pen_render_state_free(sb);
    pen_scene_free(&a), pen_scene_free(&b);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_lighting_and_albedo), TEST(test_ground_border_gradients), TEST(test_sphere_gradients), TEST(test_occluder_only),
          TEST(test_self_shadowing_gradients), TEST(test_two_objects), TEST(test_pose_gradients),
          TEST(test_vertex_gradients), TEST(test_silhouette_gradients),
          TEST(test_disk_light_gradients),
          TEST(test_thread_count_independent), TEST(test_texel_scatter_threads),
          TEST(test_torture_finite),
          TEST(test_footprint_gradients), TEST(test_footprint_checkerboard),
          TEST(test_grad_model_rule))
