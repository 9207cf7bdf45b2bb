/* The disk lights' fractions traced per pixel on an object's own transfer pixels (src/render/
 * self.c, pixel_trace; docs/visibility.md, "Thin parts on the ground"): a thin rod's shadow under
 * a low, small disk light falls on a plate of the same mesh, far narrower than the plate's nodes.
 *
 * - The light's share of each plate pixel in the image follows an exact ray test of the rod much
 *   more closely than the nodes' interpolation does (which the image would show without the
 *   per-pixel trace).
 * - The backward reads the fractions the forward traced: the disk light's irradiance gradient on
 *   the pixels around the shadow against central differences summed in double (the image is
 *   linear in it).
 * - The traces are kept while nothing they depend on changes (no pass over the pixels then),
 *   and traced again when something does; a kept state renders as a fresh one, bit for bit.
 * - 1 and 2 threads render bitwise the same. */
#include "check.h"
#include "render_scenes.h"

#include "render/render_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The rod: 1.2 long, 0.04 thick, 0.3 over the plate (y = 0), turned by ROD_TURN radians about +Y
 * (x' = c x + s z, z' = c z - s x) in its vertices, as tests/test_ground_shadow.c's thin rod. */
#define ROD_TURN 0.35
#define ROD_HALF 0.02
#define ROD_Y 0.3
#define PLATE_HALF 1.2f

static void box_into(rs_builder *b, float hx, float hy, float hz) {
    const double c = cos(ROD_TURN), s = sin(ROD_TURN);
    int v[8];
    for (int k = 0; k < 8; ++k) {
        const double x = k & 1 ? hx : -hx, z = k & 4 ? hz : -hz;
        const float p[3] = {(float)(c * x + s * z), (float)ROD_Y + (k & 2 ? hy : -hy),
                            (float)(c * z - s * x)};
        v[k] = rs_vertex(b, p);
    }
    static const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                                    {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    for (int f = 0; f < 6; ++f) {
        const int *q = quads[f];
        rs_triangle(b, v[q[0]], v[q[1]], v[q[2]]), rs_triangle(b, v[q[0]], v[q[2]], v[q[3]]);
    }
}

/* Whether the ray from p towards w meets the rod (slab test in the rod's frame;
 * test_ground_shadow.c has the same test for its rod over the ground, at that rod's height). */
static int rod_blocks(const float *p, const double *w) {
    const double c = cos(ROD_TURN), s = sin(ROD_TURN), h[3] = {0.6, ROD_HALF, ROD_HALF};
    const double px = (double)p[0], pz = (double)p[2];
    const double q[3] = {c * px - s * pz, (double)p[1] - ROD_Y, s * px + c * pz};
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

/* One object: the plate (two triangles facing +Y) and the rod over it; no ground, so that the
 * plate's pixels are the transfer's; a low disk light 0.3 degrees wide. */
static pen_scene rod_plate_scene(int size) {
    pen_scene sc = rs_scene(size, size);
    sc.ground.enabled = 0;
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    const float P = PLATE_HALF;
    const float corner[4][3] = {{-P, 0.0f, -P}, {P, 0.0f, -P}, {P, 0.0f, P}, {-P, 0.0f, P}};
    for (int k = 0; k < 4; ++k)
        rs_vertex(&b, corner[k]);
    rs_triangle(&b, 0, 3, 2), rs_triangle(&b, 0, 2, 1);
    box_into(&b, 0.6f, ROD_HALF, ROD_HALF);
    const float sph[4] = {0.0f, (float)ROD_Y, 0.0f, 0.05f};
    rs_add_object(&sc, rs_builder_mesh(&b), 1, sph);
    const float eye[3] = {0.0f, 2.6f, 1.4f}, target[3] = {-0.3f, 0.0f, -0.1f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    sc.lighting.light_count = 1;
    sc.lighting.lights_mode = PEN_LIGHTS_GIVEN;
    pen_light *L = &sc.lighting.lights[0];
    const float d[3] = {0.75f, 0.45f, 0.3f};
    memcpy(L->direction, d, sizeof d);
    L->angular_radius_deg = 0.3f;
    L->irradiance[0] = 1.5f, L->irradiance[1] = 1.2f, L->irradiance[2] = 1.0f;
    return sc;
}

static int cmp_double(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The plate pixels within 3 pixels of one whose centre ray meets the rod (the shadow's band),
 * as a mask; *count of them. */
static unsigned char *band_mask(const pen_render_state *st, int *count) {
    const int W = st->width, H = st->height;
    const size_t np = (size_t)W * (size_t)H;
    unsigned char *hit = calloc(np, 1), *band = calloc(np, 1);
    for (size_t i = 0; i < np; ++i)
        if (st->gb.surface[i] == 0 && fabs((double)st->x.data[3 * i + 1]) < 1e-3)
            hit[i] = (unsigned char)rod_blocks(st->x.data + 3 * i, st->lights.w[0]);
    *count = 0;
    for (int y = 3; y < H - 3; ++y)
        for (int x = 3; x < W - 3; ++x) {
            const size_t i = (size_t)y * (size_t)W + (size_t)x;
            if (st->gb.surface[i] != 0 || fabs((double)st->x.data[3 * i + 1]) >= 1e-3) continue;
            int near = 0;
            for (int v = -3; v <= 3; ++v)
                for (int u = -3; u <= 3; ++u)
                    near |= hit[i + (size_t)((long)v * W + u)];
            band[i] = (unsigned char)near, *count += near;
        }
    free(hit);
    return band;
}

/* Measured at 128 x 128: the mean |share - exact| over the shadow's band (833 pixels, 716 of
 * them traced) is 0.018 with the per-pixel trace against 0.380 by the nodes' interpolation (what
 * the image shows without it); the check asks for less than half, which fails when the trace is
 * off (the image is then the nodes'). */
static void test_rod_on_plate(void) {
    pen_scene sc = rod_plate_scene(128);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image lit, dark;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &lit);
    CHECK(st->obj[0].self_on && st->self_pvalid);
    const float keep = sc.lighting.lights[0].irradiance[0];
    sc.lighting.lights[0].irradiance[0] = 0.0f;
    pen_render_state *s2 = rs_render_kept(ctx, &sc, &opt, &dark);
    sc.lighting.lights[0].irradiance[0] = keep;
    const size_t np = (size_t)lit.width * (size_t)lit.height;
    int nb = 0;
    unsigned char *band = band_mask(st, &nb);
    /* The light's full share: the median over the plate's pixels away from the shadow. */
    double *clear = calloc(np, sizeof(double));
    int nclear = 0;
    for (size_t i = 0; i < np; ++i)
        if (st->gb.surface[i] == 0 && fabs((double)st->x.data[3 * i + 1]) < 1e-3 && !band[i] &&
            !rod_blocks(st->x.data + 3 * i, st->lights.w[0]))
            clear[nclear++] = (double)lit.data[3 * i] - (double)dark.data[3 * i];
    qsort(clear, (size_t)nclear, sizeof(double), cmp_double);
    const double full = nclear ? clear[nclear / 2] : 0.0;
    double e_img = 0.0, e_nodes = 0.0;
    int traced = 0;
    for (size_t i = 0; i < np; ++i) {
        if (!band[i]) continue;
        const double exact = rod_blocks(st->x.data + 3 * i, st->lights.w[0]) ? 0.0 : 1.0;
        const double share = ((double)lit.data[3 * i] - (double)dark.data[3 * i]) / full;
        double f;
        const int valid = st->self_pvalid;
        st->self_pvalid = 0; /* what the nodes alone give this pixel */
        pen__self_transfer_at(st, 0, i, NULL, &f);
        st->self_pvalid = valid;
        traced += valid && st->self_pfrac.data[i] >= 0.0f; /* (one light: K = 1 per pixel) */
        e_img += fabs(share - exact), e_nodes += fabs(f - exact);
    }
    e_img /= nb, e_nodes /= nb;
    printf("  rod on plate: %d band pixels (%d traced), mean |share - exact| %.4f, nodes %.4f\n",
           nb, traced, e_img, e_nodes);
    CHECK(nb > 100 && nclear > 1000 && full > 0.0 && traced > 0);
    CHECK_MSG(e_img < 0.5 * e_nodes, "per pixel %.4f against the nodes' %.4f", e_img, e_nodes);
    free(clear);
    free(band);
    pen_image_free(&lit), pen_image_free(&dark);
    pen_render_state_free(st), pen_render_state_free(s2);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* The irradiance gradient on the shadow's band (where the traced fractions differ from the
 * nodes') against central differences: the backward shades with the forward's fractions. */
static void test_backward_reads_them(void) {
    pen_scene sc = rod_plate_scene(64);
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_context *ctx = pen_context_create();
        pen_render_options opt = pen_render_options_default();
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_image img, dimg = {0, 0, 0, NULL};
        pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
        CHECK(st->self_pvalid);
        int nb = 0;
        unsigned char *band = band_mask(st, &nb);
        CHECK(pen_image_create(ctx, img.width, img.height, 3, &dimg) == PEN_OK);
        unsigned long long seed = 11;
        const size_t np = (size_t)img.width * img.height;
        for (size_t i = 0; i < np; ++i)
            for (int ch = 0; ch < 3; ++ch)
                dimg.data[3 * i + ch] = band[i] ? (float)rs_uniform(&seed, 0.0, 1.0) : 0.0f;
        pen_render_grad g;
        CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
        pen_render_grad_zero(&g);
        CHECK(pen_render_bwd(ctx, &sc, &opt, st, &dimg,
                             PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO | PEN_GRAD_LIGHT_IRRADIANCE,
                             &g) == PEN_OK);
        float *params[3] = {&sc.lighting.lights[0].irradiance[0],
                            &sc.lighting.lights[0].irradiance[1], &sc.objects[0].albedo[2]};
        const double an[3] = {g.lights[0].irradiance[0], g.lights[0].irradiance[1],
                              g.objects[0].albedo[2]};
        for (int j = 0; j < 3; ++j) {
            const double fd = rs_central_dot(ctx, &sc, &opt, params[j], 0.05f, &dimg);
            CHECK_MSG(fabs(fd - an[j]) <= 2e-3 * fmax(1.0, fabs(fd)),
                      "kernel %d, parameter %d: analytic %.6g, FD %.6g", kernel, j, an[j], fd);
            CHECK(fabs(an[j]) > 1e-3);
        }
        free(band);
        pen_image_free(&img), pen_image_free(&dimg);
        pen_render_grad_free(&g);
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    pen_scene_free(&sc);
}

#define SENTINEL (-2.0f)

/* The per-pixel traces' caches (self_pfrac, and the ground's grid.pfrac under the plate) are
 * decided from what the frame is made of, not from its pixels: a frame that changes nothing the
 * traces depend on (the SH lighting, albedos, a light's irradiance) renders without the per-pixel
 * pass; each input they depend on (the camera, the size, the pose, a vertex, a light's direction
 * or radius, the ground, the grid) traces them again. Every frame of the kept state equals a fresh
 * state's bit for bit. Whether the pass ran shows in an entry no pixel reads (a ground pixel's in
 * self_pfrac, an object pixel's in the grid's): the pass rewrites every entry, a hit none. */
static void test_cache_hit_and_misses(void) {
    pen_scene sc = rod_plate_scene(64);
    sc.ground.enabled = 1, sc.ground.height = -0.25f; /* under the plate: its shadow falls there */
    pen_context *ctx = pen_context_create();
    const pen_render_options opt = pen_render_options_default();
    pen_image first;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &first);
    CHECK(st->self_pvalid && st->grid.on && st->grid.pvalid && st->lights.count == 1);
    /* Each change on top of the ones before, and whether the object's pixels (self) and the
     * ground's (grid) must be traced again; a float moved by `add` or an int by `iadd`. */
    pen_object *ob = &sc.objects[0];
    pen_light *L = &sc.lighting.lights[0];
    const struct {
        const char *what;
        float *p;
        float add;
        int *ip, iadd, self, grid;
    } changes[] = {
        {"nothing", NULL, 0.0f, NULL, 0, 0, 0},
        {"SH lighting", &sc.lighting.sh[2][1], 0.2f, NULL, 0, 0, 0},
        {"albedo", &ob->albedo[0], -0.3f, NULL, 0, 0, 0},
        {"ground albedo", &sc.ground.albedo[2], 0.3f, NULL, 0, 0, 0},
        {"irradiance", &L->irradiance[1], 1.0f, NULL, 0, 0, 0},
        {"eye", &sc.camera.eye[0], 0.05f, NULL, 0, 1, 1},
        {"target", &sc.camera.target[2], 0.04f, NULL, 0, 1, 1},
        {"fov", &sc.camera.fov_y_deg, 1.5f, NULL, 0, 1, 1},
        {"width", NULL, 0.0f, &sc.camera.width, 8, 1, 1}, /* (grown: the sentinels stay inside) */
        {"height", NULL, 0.0f, &sc.camera.height, 8, 1, 1},
        {"translation", &ob->pose.translation[0], 0.02f, NULL, 0, 1, 1},
        {"rotation", &ob->pose.rotation_axis_angle_deg[1], 2.0f, NULL, 0, 1, 1},
        {"a rod corner in place", &ob->mesh.positions[3 * 4 + 1], 0.01f, NULL, 0, 1, 1},
        {"light direction", &L->direction[2], 0.05f, NULL, 0, 1, 1},
        {"light radius", &L->angular_radius_deg, 0.3f, NULL, 0, 1, 1},
        {"ground height", &sc.ground.height, -0.05f, NULL, 0, 1, 1},
        {"ground size", &sc.ground.half_size, -0.5f, NULL, 0, 1, 1},
        {"ground grid", NULL, 0.0f, &sc.shadow.ground_grid, 48, 0, 1},
    };
    for (int c = 0; c < (int)(sizeof changes / sizeof changes[0]); ++c) {
        /* the first ground pixel and the first object pixel of the frame before */
        size_t ig = 0, io = 0;
        const size_t np = (size_t)st->width * (size_t)st->height;
        while (ig < np && st->gb.surface[ig] != PEN_SURFACE_GROUND)
            ++ig;
        while (io < np && st->gb.surface[io] != 0)
            ++io;
        CHECK(ig < np && io < np && st->self_pfrac.data[ig] == -1.0f &&
              st->grid.pfrac.data[io] == -1.0f);
        st->self_pfrac.data[ig] = SENTINEL, st->grid.pfrac.data[io] = SENTINEL;
        if (changes[c].p) *changes[c].p += changes[c].add;
        if (changes[c].ip) *changes[c].ip += changes[c].iadd;
        pen_image a = {0, 0, 0, NULL}, b;
        CHECK(pen_render_fwd(ctx, &sc, &opt, st, &a) == PEN_OK);
        pen_render_state *fresh = rs_render_kept(ctx, &sc, &opt, &b);
        const size_t bytes = sizeof(float) * 3 * (size_t)a.width * (size_t)a.height;
        CHECK_MSG(a.data && b.data && a.width == b.width && !memcmp(a.data, b.data, bytes),
                  "%s: the kept state's render differs from a fresh state's", changes[c].what);
        if (c == 0)
            CHECK_MSG(a.width == first.width && !memcmp(a.data, first.data, bytes),
                      "the second render differs from the first");
        CHECK_MSG((st->self_pfrac.data[ig] != SENTINEL) == changes[c].self,
                  "%s: the object's pixels %s", changes[c].what,
                  changes[c].self ? "not traced again" : "traced again");
        CHECK_MSG((st->grid.pfrac.data[io] != SENTINEL) == changes[c].grid,
                  "%s: the ground's pixels %s", changes[c].what,
                  changes[c].grid ? "not traced again" : "traced again");
        CHECK(st->self_pvalid && st->grid.pvalid);
        if (st->self_pfrac.data[ig] == SENTINEL) st->self_pfrac.data[ig] = -1.0f;
        if (st->grid.pfrac.data[io] == SENTINEL) st->grid.pfrac.data[io] = -1.0f;
        pen_image_free(&a), pen_image_free(&b);
        pen_render_state_free(fresh);
    }
    pen_image_free(&first);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* One kept state through frames that change what the traced fractions depend on (the camera, the
 * size, a frame without transfer pixels and back): each render equals a fresh state's bit for
 * bit, so the cache is never read where it no longer holds. */
static void test_cache_follows_the_frame(void) {
    pen_scene sc = rod_plate_scene(96);
    pen_context *ctx = pen_context_create();
    const pen_render_options opt = pen_render_options_default();
    pen_render_state *kept = NULL;
    CHECK(pen_render_state_create(ctx, &kept) == PEN_OK);
    const float eye0[3] = {sc.camera.eye[0], sc.camera.eye[1], sc.camera.eye[2]};
    const float target0[3] = {sc.camera.target[0], sc.camera.target[1], sc.camera.target[2]};
    /* size, eye moved along z, looking away (the plate behind the camera: no transfer pixels) */
    static const struct {
        int size;
        float dz;
        int away;
    } frames[] = {{96, 0.0f, 0}, {96, 0.3f, 0}, {64, 0.3f, 0}, {64, 0.0f, 1}, {64, 0.0f, 0}};
    for (int f = 0; f < (int)(sizeof frames / sizeof frames[0]); ++f) {
        sc.camera.width = sc.camera.height = frames[f].size;
        for (int a = 0; a < 3; ++a)
            sc.camera.eye[a] = eye0[a], sc.camera.target[a] = target0[a];
        sc.camera.eye[2] += frames[f].dz;
        if (frames[f].away) sc.camera.target[2] = sc.camera.eye[2] + 5.0f;
        pen_image a = {0, 0, 0, NULL}, b;
        CHECK(pen_render_fwd(ctx, &sc, &opt, kept, &a) == PEN_OK);
        pen_render_state *fresh = rs_render_kept(ctx, &sc, &opt, &b);
        CHECK_MSG(a.data && b.data &&
                      !memcmp(a.data, b.data, sizeof(float) * 3 * (size_t)a.width * a.height),
                  "frame %d: the kept state's render differs from a fresh state's", f);
        /* (without transfer pixels the fractions are valid too, all the nodes': none traced) */
        int traced = 0;
        for (size_t i = 0; i < (size_t)a.width * a.height; ++i)
            traced += kept->self_pfrac.data[i] >= 0.0f;
        CHECK_MSG(kept->self_pvalid && (traced > 0) == !frames[f].away,
                  "frame %d: %d pixels traced, valid %d", f, traced, kept->self_pvalid);
        pen_image_free(&a), pen_image_free(&b);
        pen_render_state_free(fresh);
    }
    pen_render_state_free(kept);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

static void test_threads(void) {
    pen_scene sc = rod_plate_scene(96);
    pen_render_options opt = pen_render_options_default();
    pen_image a, b;
    CHECK(rs_render(&sc, &opt, 1, &a) == PEN_OK);
    CHECK(rs_render(&sc, &opt, 2, &b) == PEN_OK);
    CHECK(a.data && b.data && !memcmp(a.data, b.data, sizeof(float) * 3 * 96 * 96));
    pen_image_free(&a), pen_image_free(&b);
    pen_scene_free(&sc);
}

int main(void) {
    static const check_test_ tests[] = {
        {"test_rod_on_plate", test_rod_on_plate},
        {"test_backward_reads_them", test_backward_reads_them},
        {"test_cache_follows_the_frame", test_cache_follows_the_frame},
        {"test_cache_hit_and_misses", test_cache_hit_and_misses},
        {"test_threads", test_threads},
    };
    return check_run_(tests, (int)(sizeof tests / sizeof tests[0]));
}
