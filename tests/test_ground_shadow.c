/* The ground's shadows of objects shaded with their transfer, by the grid of ray-traced nodes
 * (src/render/ground_shadow.c; docs/design.md sec. 1.15).
 *
 * - A frame's lighting, ground albedo and disk-light irradiance gradients on the ground's pixels
 *   with the grid on, against central differences summed in double (the image is linear in them,
 *   so the differences are exact up to the float image's rounding); both kernels.
 * - An object far outside the ground square: no node sees it (B = 0, every fraction 1), so the
 *   ground's pixels equal the unshadowed render.
 * - "ground_shadow": "spheres" shades the ground exactly as the sphere model (bit for bit: the
 *   ground's pixels of a render with "self": "spheres"); the grid and the image are the
 *   same for any thread count.
 * - A thin bar over the ground, covered by fat spheres: against the ray-traced reference the
 *   grid's ground shadow is much closer than the spheres'.
 * - A thin rod whose shadow falls between the grid's nodes: the light's share of each ground
 *   pixel follows an exact ray test (the pixels' own disk fractions), without beads.
 * - "self": "spheres" (what pose, shape, sphere and light-direction optimisers switch to)
 *   turns the grid off; the cache is kept while the pose stays and rebuilt when it moves; the
 *   pixels' light fractions are kept with it and traced again when the camera moves. */
#include "check.h"
#include "render_scenes.h"

#include "render/render_internal.h"
#include "render/transfer_pool.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ---- Scenes ---------------------------------------------------------------------------------- */

/* A box [-hx, hx] x [-hy, hy] x [-hz, hz], faces wound outwards. */
static pen_mesh box_mesh(float hx, float hy, float hz) {
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    for (int k = 0; k < 8; ++k) {
        const float p[3] = {k & 1 ? hx : -hx, k & 2 ? hy : -hy, k & 4 ? hz : -hz};
        rs_vertex(&b, p);
    }
    static const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                                     {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    for (int f = 0; f < 6; ++f) {
        const int *q = quads[f];
        rs_triangle(&b, q[0], q[1], q[2]), rs_triangle(&b, q[0], q[2], q[3]);
    }
    return rs_builder_mesh(&b);
}

/* A thin bar (1.2 long, 0.08 thick) lying 0.3 over the ground, covered by three fat spheres
 * (what a fit gives a thin part): their ground shadow is too wide and too dark. */
static pen_scene bar_scene(int size) {
    pen_scene sc = rs_scene(size, size);
    const float sph[12] = {-0.4f, 0.0f, 0.0f, 0.2f, 0.0f, 0.0f, 0.0f, 0.2f,
                           0.4f,  0.0f, 0.0f, 0.2f};
    pen_object *ob = rs_add_object(&sc, box_mesh(0.6f, 0.04f, 0.04f), 3, sph);
    ob->pose.translation[1] = 0.3f;
    ob->pose.rotation_axis_angle_deg[1] = 20.0f;
    const float eye[3] = {0.4f, 1.8f, 1.8f}, target[3] = {0.0f, 0.0f, 0.0f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    return sc;
}

/* One disk light, for the fractions. */
static void add_light(pen_scene *sc) {
    sc->lighting.light_count = 1;
    sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
    pen_light *L = &sc->lighting.lights[0];
    const float d[3] = {0.4f, 0.85f, 0.25f};
    memcpy(L->direction, d, sizeof d);
    L->angular_radius_deg = 4.0f;
    L->irradiance[0] = 1.5f, L->irradiance[1] = 1.2f, L->irradiance[2] = 1.0f;
}

/* ---- Tests ----------------------------------------------------------------------------------- */

/* The thin rod of test_thin_rod: 1.2 long, 0.04 thick, 0.3 over the ground, turned by ROD_TURN
 * radians about +Y (x' = c x + s z, z' = c z - s x) in its vertices, so that the analytic ray
 * test below needs no pose convention. */
#define ROD_TURN 0.35
#define ROD_HALF 0.02
static int cmp_double(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int rod_blocks(const float *p, const double *w) {
    const double c = cos(ROD_TURN), s = sin(ROD_TURN), h[3] = {0.6, ROD_HALF, ROD_HALF};
    const double px = (double)p[0], pz = (double)p[2];
    const double q[3] = {c * px - s * pz, (double)p[1] - 0.3, s * px + c * pz};
    const double d[3] = {c * w[0] - s * w[2], w[1], s * w[0] + c * w[2]};
    double t0 = 0.0, t1 = 1e30;
    for (int a = 0; a < 3; ++a) {
        if (fabs(d[a]) < 1e-12) {
            if (fabs(q[a]) > h[a]) return 0;
            continue;
        }
        const double ta = (-h[a] - q[a]) / d[a], tb = (h[a] - q[a]) / d[a];
        t0 = fmax(t0, fmin(ta, tb)), t1 = fmin(t1, fmax(ta, tb));
    }
    return t0 <= t1;
}

static void test_frame_gradients(void) {
    pen_scene sc = bar_scene(40);
    add_light(&sc);
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_context *ctx = pen_context_create();
        pen_render_options opt = pen_render_options_default();
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_image img, dimg = {0, 0, 0, NULL};
        pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
        CHECK(st->grid.on && st->grid.valid);
        /* loss = sum q . image over the ground's pixels only */
        CHECK(pen_image_create(ctx, img.width, img.height, 3, &dimg) == PEN_OK);
        unsigned long long seed = 7;
        const size_t np = (size_t)img.width * img.height;
        for (size_t i = 0; i < np; ++i)
            for (int ch = 0; ch < 3; ++ch)
                dimg.data[3 * i + ch] = st->gb.surface[i] == PEN_SURFACE_GROUND
                                            ? (float)rs_uniform(&seed, 0.0, 1.0)
                                            : 0.0f;
        pen_render_grad g;
        CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
        pen_render_grad_zero(&g);
        CHECK(pen_render_bwd(ctx, &sc, &opt, st, &dimg,
                             PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO | PEN_GRAD_LIGHT_IRRADIANCE, &g) == PEN_OK);
        float *params[6] = {&sc.lighting.sh[0][0], &sc.lighting.sh[2][1], &sc.lighting.sh[7][2],
                            &sc.ground.albedo[0],  &sc.ground.albedo[2],
                            &sc.lighting.lights[0].irradiance[1]};
        const double an[6] = {g.sh[0][0],         g.sh[2][1],         g.sh[7][2],
                              g.ground_albedo[0], g.ground_albedo[2], g.lights[0].irradiance[1]};
        for (int j = 0; j < 6; ++j) {
            const double fd = rs_central_dot(ctx, &sc, &opt, params[j], 0.05f, &dimg);
            CHECK_MSG(fabs(fd - an[j]) <= 2e-3 * fmax(1.0, fabs(fd)),
                      "kernel %d, parameter %d: analytic %.6g, FD %.6g", kernel, j, an[j], fd);
            CHECK(fabs(an[j]) > 1e-3); /* the ground's pixels do depend on it */
        }
        pen_image_free(&img), pen_image_free(&dimg);
        pen_render_grad_free(&g);
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    pen_scene_free(&sc);
}

static void test_far_object_sees_nothing(void) {
    pen_scene sc = bar_scene(32);
    add_light(&sc);
    sc.objects[0].pose.translation[0] = 500.0f; /* far outside the square (half size 3) */
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    opt.kernel = PEN_RENDER_KERNEL_SCALAR;
    pen_image img, off;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
    const pen__ground_grid *gr = &st->grid;
    CHECK(gr->on && gr->n >= 2);
    const size_t nodes = (size_t)gr->n * (size_t)gr->n;
    double worst = 0.0, fworst = 0.0;
    for (size_t k = 0; k < 16 * nodes; ++k)
        worst = fmax(worst, fabs((double)gr->B[k]));
    for (size_t k = 0; k < nodes; ++k)
        fworst = fmax(fworst, fabs((double)gr->frac[k] - 1.0));
    CHECK_MSG(worst == 0.0 && fworst == 0.0, "far object: |B| up to %g, |1 - frac| up to %g",
              worst, fworst);
    opt.shadows = 0;
    pen_render_state *st2 = rs_render_kept(ctx, &sc, &opt, &off);
    size_t ground = 0;
    double diff = 0.0;
    for (size_t i = 0; i < (size_t)img.width * img.height; ++i) {
        if (st->gb.surface[i] != PEN_SURFACE_GROUND) continue;
        ++ground;
        for (int ch = 0; ch < 3; ++ch)
            diff = fmax(diff, fabs((double)img.data[3 * i + ch] - (double)off.data[3 * i + ch]) /
                                  fmax(1e-3, fabs((double)off.data[3 * i + ch])));
    }
    CHECK(ground > 100);
    CHECK_MSG(diff < 1e-5, "ground pixels differ from the unshadowed render by %g (relative)",
              diff);
    pen_image_free(&img), pen_image_free(&off);
    pen_render_state_free(st), pen_render_state_free(st2);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* "spheres": the ground's pixels bit for bit those of the sphere model (no antialiasing, which
 * blends the object's colours into them); threads do not change the grid's render. */
static void test_spheres_mode_and_threads(void) {
    pen_scene sc = bar_scene(48);
    add_light(&sc);
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_context *ctx = pen_context_create();
        pen_render_options opt = pen_render_options_default();
        opt.antialias = 0;
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_image a, b, grid;
        sc.shadow.self = PEN_SELF_SPHERES;
        pen_render_state *sa = rs_render_kept(ctx, &sc, &opt, &a);
        CHECK(!sa->grid.on); /* without the self transfer there is no grid */
        sc.shadow.self = PEN_SELF_TRANSFER;
        sc.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
        pen_render_state *sb = rs_render_kept(ctx, &sc, &opt, &b);
        CHECK(!sb->grid.on && sb->self_any);
        sc.shadow.ground_shadow = PEN_GROUND_SHADOW_TRANSFER;
        pen_render_state *sg = rs_render_kept(ctx, &sc, &opt, &grid);
        CHECK(sg->grid.on);
        size_t ground = 0, same = 0, moved = 0;
        for (size_t i = 0; i < (size_t)a.width * a.height; ++i) {
            if (sa->gb.surface[i] != PEN_SURFACE_GROUND) continue;
            ++ground;
            same += !memcmp(a.data + 3 * i, b.data + 3 * i, 3 * sizeof(float));
            moved += memcmp(a.data + 3 * i, grid.data + 3 * i, 3 * sizeof(float)) != 0;
        }
        CHECK_MSG(same == ground, "kernel %d: %zu of %zu ground pixels differ", kernel,
                  ground - same, ground);
        CHECK(moved > 0); /* the grid does change the ground's shadow */
        pen_image_free(&a), pen_image_free(&b), pen_image_free(&grid);
        pen_render_state_free(sa), pen_render_state_free(sb), pen_render_state_free(sg);
        pen_context_destroy(ctx);
    }
    pen_image one, three;
    pen_render_options opt = pen_render_options_default();
    CHECK(rs_render(&sc, &opt, 1, &one) == PEN_OK);
    CHECK(rs_render(&sc, &opt, 3, &three) == PEN_OK);
    CHECK(!memcmp(one.data, three.data, sizeof(float) * 3 * (size_t)one.width * one.height));
    pen_image_free(&one), pen_image_free(&three);
    pen_scene_free(&sc);
}

/* Measured at 64 x 64, 512 spp: grid 0.0125, spheres 0.133 (rel. RMSE over the ground's pixels). */
static void test_bar_against_reference(void) {
    pen_scene sc = bar_scene(64);
    pen_context *ctx = pen_context_create();
    pen_reference *ref = NULL;
    pen_image truth = {0, 0, 0, NULL};
    CHECK(pen_reference_create(ctx, &sc, PEN_REFERENCE_LIGHTING_SH, &ref) == PEN_OK);
    CHECK(pen_reference_render(ctx, ref, check_quick_() ? 64 : 512, 1, &truth) == PEN_OK);
    pen_reference_destroy(ref);
    pen_render_options opt = pen_render_options_default();
    pen_image grid, sph;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &grid);
    sc.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
    pen_render_state *s2 = rs_render_kept(ctx, &sc, &opt, &sph);
    double eg = 0.0, es = 0.0, r = 0.0;
    for (size_t i = 0; i < (size_t)grid.width * grid.height; ++i) {
        if (st->gb.surface[i] != PEN_SURFACE_GROUND) continue;
        for (int ch = 0; ch < 3; ++ch) {
            const double t = (double)truth.data[3 * i + ch];
            eg += ((double)grid.data[3 * i + ch] - t) * ((double)grid.data[3 * i + ch] - t);
            es += ((double)sph.data[3 * i + ch] - t) * ((double)sph.data[3 * i + ch] - t);
            r += t * t;
        }
    }
    eg = sqrt(eg / r), es = sqrt(es / r);
    printf("  bar: ground rel. error against the reference: grid %.4f, spheres %.4f\n", eg, es);
    CHECK(eg < 0.5 * es);
    pen_image_free(&grid), pen_image_free(&sph), pen_image_free(&truth);
    pen_render_state_free(st), pen_render_state_free(s2);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* A rod whose ground shadow (two pixels wide) is far narrower than the grid's spacing (a 16-node
 * grid: about 0.1 apart near it): interpolated, the nodes miss the line or catch it at a few of
 * them (beads). The disk light's share of each ground pixel (its render with the light minus
 * without, over the brightest) must follow an exact ray test of the rod: dark where the pixel's
 * ray meets it, lit two pixels away from every such pixel. */
static void test_thin_rod(void) {
    pen_scene sc = bar_scene(96);
    pen_mesh m = box_mesh(0.6f, ROD_HALF, ROD_HALF);
    const double c = cos(ROD_TURN), s = sin(ROD_TURN);
    for (int v = 0; v < m.vertex_count; ++v) {
        float *p = m.positions + 3 * (size_t)v;
        const double x = p[0], z = p[2];
        p[0] = (float)(c * x + s * z), p[2] = (float)(c * z - s * x), p[1] += 0.3f;
    }
    pen_mesh_free(&sc.objects[0].mesh);
    sc.objects[0].mesh = m;
    sc.objects[0].pose.translation[1] = 0.0f, sc.objects[0].pose.rotation_axis_angle_deg[1] = 0.0f;
    for (int k = 0; k < 3; ++k) /* the spheres sit on the rod; they shade only other objects */
        sc.objects[0].spheres.data[4 * k + 1] = 0.3f;
    add_light(&sc);
    const float dir[3] = {0.3f, 0.9f, 0.2f};
    memcpy(sc.lighting.lights[0].direction, dir, sizeof dir);
    sc.lighting.lights[0].angular_radius_deg = 0.3f;
    sc.shadow.ground_grid = 16;
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image lit, dark;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &lit);
    for (int ch = 0; ch < 3; ++ch)
        sc.lighting.lights[0].irradiance[ch] = 0.0f;
    pen_render_state *s2 = rs_render_kept(ctx, &sc, &opt, &dark);
    const int W = lit.width, H = lit.height;
    const size_t np = (size_t)W * (size_t)H;
    unsigned char *hit = calloc(np, 1);
    double *clear = calloc(np, sizeof(double)), in = 0.0;
    for (size_t i = 0; i < np; ++i)
        if (st->gb.surface[i] == PEN_SURFACE_GROUND)
            hit[i] = (unsigned char)rod_blocks(st->x.data + 3 * i, st->lights.w[0]);
    int nin = 0, nout = 0;
    for (int y = 2; y < H - 2; ++y)
        for (int x = 2; x < W - 2; ++x) {
            const size_t i = (size_t)y * (size_t)W + (size_t)x;
            if (st->gb.surface[i] != PEN_SURFACE_GROUND) continue;
            const double share = (double)lit.data[3 * i] - (double)dark.data[3 * i];
            int near = 0;
            for (int v = -2; v <= 2; ++v)
                for (int u = -2; u <= 2; ++u)
                    near |= hit[i + (size_t)((long)v * W + u)];
            if (hit[i]) in += share, ++nin;
            else if (!near) clear[nout++] = share;
        }
    /* The light's full share: the median over the clear pixels (the same on the whole plane). */
    qsort(clear, (size_t)nout, sizeof(double), cmp_double);
    const double full = clear[nout / 2];
    int lit_ok = 0;
    for (int k = 0; k < nout; ++k)
        lit_ok += fabs(clear[k] - full) <= 0.03 * full;
    in /= nin * full;
    printf("  thin rod: light's share on %d pixels the rod blocks %.3f; %d of %d clear ones lit\n",
           nin, in, lit_ok, nout);
    CHECK(nin > 40 && in < 0.25 && lit_ok >= 0.99 * nout);
    free(clear);
    free(hit);
    pen_image_free(&lit), pen_image_free(&dark);
    pen_render_state_free(st), pen_render_state_free(s2);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

static void test_cache(void) {
    pen_scene sc = bar_scene(32);
    add_light(&sc);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image img;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
    pen__ground_grid *gr = &st->grid;
    CHECK(gr->on && gr->valid && gr->n == 96);
    const uint64_t key = gr->key, pkey = gr->pkey;
    CHECK(gr->pvalid);
    const float marker = 4321.0f;
    gr->blob->B[0] = marker; /* the state's own trace: no pool shares it */
    /* Other lighting and albedos: kept. */
    sc.lighting.sh[1][0] += 0.3f;
    sc.ground.albedo[1] = 0.2f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key == key && gr->B[0] == marker);
    CHECK(gr->pvalid && gr->pkey == pkey); /* the pixels' fractions too */
    /* The camera moves: the grid is kept, the pixels' fractions traced again. */
    sc.camera.eye[0] += 0.2f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key == key && gr->B[0] == marker && gr->pvalid && gr->pkey != pkey);
    /* The pose moves: traced again. */
    sc.objects[0].pose.translation[2] = 0.1f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key != key && gr->B[0] != marker);
    /* The light's irradiance: kept (a gradient, not a trace); its direction or size: traced
     * again (the key takes them through the object's own transfer key, self.c). */
    uint64_t k1 = gr->key;
    sc.lighting.lights[0].irradiance[0] = 2.0f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key == k1);
    sc.lighting.lights[0].direction[0] = 0.5f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key != k1);
    k1 = gr->key;
    sc.lighting.lights[0].angular_radius_deg = 6.0f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key != k1);
    /* The scene's grid size is part of the key. */
    const uint64_t k2 = gr->key;
    sc.shadow.ground_grid = 16;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(gr->key != k2 && gr->n == 16);
    /* No ground: off. */
    sc.ground.enabled = 0;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(!gr->on);
    pen_image_free(&img);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

int main(void) {
    static const check_test_ tests[] = {
        {"test_frame_gradients", test_frame_gradients},
        {"test_far_object_sees_nothing", test_far_object_sees_nothing},
        {"test_spheres_mode_and_threads", test_spheres_mode_and_threads},
        {"test_bar_against_reference", test_bar_against_reference},
        {"test_thin_rod", test_thin_rod},
        {"test_cache", test_cache},
    };
    return check_run_(tests, (int)(sizeof tests / sizeof tests[0]));
}
