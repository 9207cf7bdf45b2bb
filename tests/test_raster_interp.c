/* Attribute interpolation, the barycentric backward, vertex normals and normalization: each
 * backward against central finite differences (double kernels at h = 1e-6; whole-pipeline checks
 * on float buffers at dyadic steps, which are exact in float, with losses summed in double). */
#include "raster_util.h"

/* ---- Ray barycentrics ---------------------------------------------------------------------- */

static void test_ray_bary_backward_fd(void) {
    unsigned long long seed = 51;
    const double h = 1e-6;
    for (int rep = 0; rep < 30; ++rep) {
        double eye[3], dir[3], p[3][3], g[3], x[3];
        for (int i = 0; i < 3; ++i) {
            eye[i] = 0.2 * (2 * check_rand_(&seed) - 1) + (i == 2 ? 4 : 0);
            dir[i] = 0.4 * (2 * check_rand_(&seed) - 1) - (i == 2 ? 1 : 0);
            g[i] = 2 * check_rand_(&seed) - 1;
            for (int k = 0; k < 3; ++k)
                p[k][i] = 2 * check_rand_(&seed) - 1;
        }
        if (rep % 5 == 0) g[0] = 0; /* the G-buffer path passes no depth gradient */
        CHECK(pen__raster_ray_bary_d(eye, dir, p[0], p[1], p[2], x));
        /* The solution is the ray point and the barycentric point at once. */
        for (int i = 0; i < 3; ++i)
            CHECK_NEAR(eye[i] + x[0] * dir[i],
                       (1 - x[1] - x[2]) * p[0][i] + x[1] * p[1][i] + x[2] * p[2][i], 1e-9);
        double dp[3][3] = {{0}};
        pen__raster_ray_bary_bwd_d(eye, dir, p[0], p[1], p[2], x, g, dp[0], dp[1], dp[2]);
        for (int k = 0; k < 3; ++k)
            for (int i = 0; i < 3; ++i) {
                double save = p[k][i], xp[3], xm[3];
                p[k][i] = save + h;
                pen__raster_ray_bary_d(eye, dir, p[0], p[1], p[2], xp);
                p[k][i] = save - h;
                pen__raster_ray_bary_d(eye, dir, p[0], p[1], p[2], xm);
                p[k][i] = save;
                double fd = 0;
                for (int j = 0; j < 3; ++j)
                    fd += g[j] * (xp[j] - xm[j]) / (2 * h);
                CHECK_REL(dp[k][i], fd, 1e-6, 1e-3);
            }
    }
    /* A ray parallel to the plane has no solution and no gradient. */
    double eye[3] = {0, 0, 1}, dir[3] = {1, 0, 0}, p0[3] = {0, 0, 0}, p1[3] = {1, 0, 0};
    double p2[3] = {0, 1, 0}, x[3] = {7, 7, 7}, g[3] = {1, 1, 1}, d[3][3] = {{0}};
    CHECK(!pen__raster_ray_bary_d(eye, dir, p0, p1, p2, x) && x[0] == 7);
    pen__raster_ray_bary_bwd_d(eye, dir, p0, p1, p2, x, g, d[0], d[1], d[2]);
    CHECK(d[0][0] == 0 && d[2][2] == 0);
}

/* ---- A small scene ------------------------------------------------------------------------- */

/* loss = sum W . position (both objects) + sum V . colour (object 0), summed in double. */
static double scene_loss(const ru_scene *s, const float *W, const float *V, pen_gbuffer *gb) {
    size_t n = (size_t)s->cam.width * s->cam.height;
    float *pos = calloc(3 * n, sizeof(float)), *col = calloc(3 * n, sizeof(float));
    CHECK(ru_raster(&s->view, s->meshes, 2, &s->ground, gb, 0) == PEN_OK);
    pen_interpolate_fwd(gb, 0, s->idx0, s->pos0, 3, pos);
    pen_interpolate_fwd(gb, 1, s->idx1, s->pos1, 3, pos);
    pen_interpolate_fwd(gb, 0, s->cidx0, s->col0, 3, col);
    double loss = 0;
    for (size_t i = 0; i < 3 * n; ++i)
        loss += (double)W[i] * (double)pos[i] + (double)V[i] * (double)col[i];
    free(pos);
    free(col);
    return loss;
}

static void test_interpolation_pipeline_fd(void) {
    ru_scene s;
    ru_scene_init(&s);
    size_t n = (size_t)s.cam.width * s.cam.height;
    float *W = malloc(3 * n * sizeof(float)), *V = malloc(3 * n * sizeof(float));
    unsigned long long seed = 52;
    for (size_t i = 0; i < 3 * n; ++i) {
        W[i] = (float)(2 * check_rand_(&seed) - 1);
        V[i] = (float)(2 * check_rand_(&seed) - 1);
    }
    pen_gbuffer gb = ru_gbuffer(s.cam.width, s.cam.height), gp = gb, gm = gb;
    gp = ru_gbuffer(s.cam.width, s.cam.height), gm = ru_gbuffer(s.cam.width, s.cam.height);
    scene_loss(&s, W, V, &gb);
    int obj0 = 0, obj1 = 0;
    for (size_t i = 0; i < n; ++i)
        obj0 += gb.surface[i] == 0, obj1 += gb.surface[i] == 1;
    CHECK(obj0 > 60 && obj1 > 20);
    /* Backward: direct terms into the values, barycentric terms through the pixel rays. */
    float d_pos0[12] = {0}, d_pos1[9] = {0}, d_col0[15] = {0};
    float *d_bary = calloc(2 * n, sizeof(float));
    pen_interpolate_bwd(&gb, 0, s.idx0, s.pos0, 3, W, d_pos0, d_bary);
    pen_interpolate_bwd(&gb, 1, s.idx1, s.pos1, 3, W, d_pos1, d_bary);
    pen_interpolate_bwd(&gb, 0, s.cidx0, s.col0, 3, V, d_col0, d_bary);
    float *d_positions[2] = {d_pos0, d_pos1};
    CHECK(pen_raster_bary_bwd(NULL, &s.view, s.meshes, 2, &gb, d_bary, d_positions) == PEN_OK);
    const float h = 1.0f / 2048;
    int tested = 0;
    for (int m = 0; m < 2; ++m) {
        float *pos = m ? s.pos1 : s.pos0;
        for (int j = 0; j < (m ? 9 : 12); ++j) {
            float save = pos[j];
            pos[j] = save + h;
            double lp = scene_loss(&s, W, V, &gp);
            pos[j] = save - h;
            double lm = scene_loss(&s, W, V, &gm);
            pos[j] = save;
            if (!ru_same_coverage(&gp, &gb) || !ru_same_coverage(&gm, &gb)) continue;
            ++tested;
            CHECK_REL(d_positions[m][j], (lp - lm) / (2.0 * (double)h), 2e-3, 0.5);
        }
    }
    CHECK(tested >= 15);
    /* Colours enter linearly: exact finite differences. */
    for (int j = 0; j < 15; ++j) {
        float save = s.col0[j];
        s.col0[j] = save + 0.25f;
        double lp = scene_loss(&s, W, V, &gp);
        s.col0[j] = save - 0.25f;
        double lm = scene_loss(&s, W, V, &gm);
        s.col0[j] = save;
        CHECK_REL(d_col0[j], (lp - lm) / 0.5, 1e-5, 1e-3);
    }
    /* The interpolated positions are the G-buffer's points (ground pixels too, analytically). */
    float *pts = malloc(3 * n * sizeof(float)), *ip = calloc(3 * n, sizeof(float));
    pen_gbuffer_points(&s.view, &gb, pts);
    pen_interpolate_fwd(&gb, 0, s.idx0, s.pos0, 3, ip);
    pen_interpolate_fwd(&gb, 1, s.idx1, s.pos1, 3, ip);
    int ground = 0;
    for (size_t i = 0; i < n; ++i) {
        if (gb.surface[i] >= 0)
            for (int c = 0; c < 3; ++c)
                CHECK_NEAR(pts[3 * i + c], ip[3 * i + c], 1e-5);
        if (gb.surface[i] == PEN_SURFACE_GROUND) {
            ++ground;
            CHECK_NEAR(pts[3 * i + 1], s.ground.height, 1e-5);
        }
        if (gb.surface[i] == PEN_SURFACE_BACKGROUND) CHECK(pts[3 * i] == 0 && ip[3 * i] == 0);
    }
    CHECK(ground > 10);
    free(pts), free(ip), free(d_bary), free(W), free(V);
    pen_gbuffer_free(&gb), pen_gbuffer_free(&gp), pen_gbuffer_free(&gm);
}

static void test_bary_backward_threads(void) {
    /* The same sums with 1 and 3 threads: the vertex scatter runs in pixel order. */
    ru_scene s;
    ru_scene_init_size(&s, RU_PARALLEL_W, RU_PARALLEL_H);
    size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_scene_gbuffer(&s);
    float *d_bary = malloc(2 * n * sizeof(float));
    unsigned long long seed = 56;
    for (size_t i = 0; i < 2 * n; ++i)
        d_bary[i] = (float)(2 * check_rand_(&seed) - 1);
    float r0[2][12] = {{0}}, r1[2][9] = {{0}};
    for (int k = 0; k < 2; ++k) {
        float *d[2] = {r0[k], r1[k]};
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, 1 + 2 * k);
        CHECK(pen_raster_bary_bwd(ctx, &s.view, s.meshes, 2, &gb, d_bary, d) == PEN_OK);
        pen_context_destroy(ctx);
    }
    CHECK(memcmp(r0[0], r0[1], sizeof r0[0]) == 0 && memcmp(r1[0], r1[1], sizeof r1[0]) == 0);
    CHECK(r0[0][0] != 0 && r1[0][0] != 0);
    free(d_bary);
    pen_gbuffer_free(&gb);
}

static void test_interpolation_bary_fd(void) {
    /* d_bary against finite differences of the barycentrics themselves (linear: exact). */
    ru_scene s;
    ru_scene_init(&s);
    size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_scene_gbuffer(&s);
    float *d_out = malloc(3 * n * sizeof(float)), *out = calloc(3 * n, sizeof(float));
    float *d_bary = calloc(2 * n, sizeof(float));
    unsigned long long seed = 53;
    for (size_t i = 0; i < 3 * n; ++i)
        d_out[i] = (float)(2 * check_rand_(&seed) - 1);
    pen_interpolate_bwd(&gb, 0, s.cidx0, s.col0, 3, d_out, NULL, d_bary);
    int checked = 0;
    for (size_t i = 0; i < n && checked < 40; ++i) {
        if (gb.surface[i] != 0) continue;
        for (int k = 0; k < 2; ++k) {
            float save = gb.bary[2 * i + k];
            double l[2];
            for (int sgn = 0; sgn < 2; ++sgn) {
                gb.bary[2 * i + k] = save + (sgn ? -0.125f : 0.125f);
                pen_interpolate_fwd(&gb, 0, s.cidx0, s.col0, 3, out);
                l[sgn] = 0;
                for (int c = 0; c < 3; ++c)
                    l[sgn] += (double)d_out[3 * i + c] * (double)out[3 * i + c];
            }
            gb.bary[2 * i + k] = save;
            CHECK_NEAR(d_bary[2 * i + k], (l[0] - l[1]) / 0.25, 1e-5);
        }
        ++checked;
    }
    CHECK(checked == 40);
    free(d_out), free(out), free(d_bary);
    pen_gbuffer_free(&gb);
}

/* ---- Vertex normals and normalization ------------------------------------------------------ */

/* An icosahedron (vertex normals are radial by symmetry), jittered for the gradient test. */
/* The frame's fused backward of one object's points, normals and UVs gives the bits of the three
 * pen_interpolate_bwd calls into a cleared d_bary, writes d_bary only at the object's pixels,
 * and turns a -0 there into +0 as the clear-and-add does. */
static void test_interpolation_object_fused(void) {
    ru_scene s;
    ru_scene_init(&s);
    const size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_gbuffer(s.cam.width, s.cam.height);
    CHECK(ru_raster(&s.view, s.meshes, 2, &s.ground, &gb, 0) == PEN_OK);
    float *W = malloc(3 * n * sizeof(float)), *V = malloc(3 * n * sizeof(float));
    float *U = malloc(2 * n * sizeof(float)), nrm[12], uv[10];
    unsigned long long seed = 53;
    for (size_t i = 0; i < 3 * n; ++i) {
        W[i] = (float)(2 * check_rand_(&seed) - 1);
        V[i] = (float)(2 * check_rand_(&seed) - 1);
    }
    for (size_t i = 0; i < 2 * n; ++i)
        U[i] = i % 7 == 0 ? -0.0f : (float)(2 * check_rand_(&seed) - 1);
    for (int i = 0; i < 12; ++i)
        nrm[i] = (float)(2 * check_rand_(&seed) - 1);
    for (int i = 0; i < 10; ++i)
        uv[i] = (float)check_rand_(&seed);
    size_t first = n; /* an object pixel whose gradients are all -0 */
    for (size_t i = 0; i < n && first == n; ++i)
        if (gb.surface[i] == 0) first = i;
    CHECK(first < n);
    W[3 * first] = W[3 * first + 1] = W[3 * first + 2] = -0.0f;
    V[3 * first] = V[3 * first + 1] = V[3 * first + 2] = -0.0f;
    U[2 * first] = U[2 * first + 1] = -0.0f;
    float dw_ref[12] = {0}, dn_ref[12] = {0}, dw[12] = {0}, dn[12] = {0};
    float *bary_ref = calloc(2 * n, sizeof(float)), *bary = malloc(2 * n * sizeof(float));
    for (size_t i = 0; i < 2 * n; ++i)
        bary[i] = 7.0f; /* not cleared: the fused pass writes the object's pixels */
    pen_interpolate_bwd(&gb, 0, s.idx0, s.pos0, 3, W, dw_ref, bary_ref);
    pen_interpolate_bwd(&gb, 0, s.idx0, nrm, 3, V, dn_ref, bary_ref);
    pen_interpolate_bwd(&gb, 0, s.cidx0, uv, 2, U, NULL, bary_ref);
    pen__interpolate_bwd_object(&gb, 0, s.idx0, s.pos0, W, dw, nrm, V, dn, s.cidx0, uv, U, bary);
    CHECK(memcmp(dw, dw_ref, sizeof dw) == 0 && memcmp(dn, dn_ref, sizeof dn) == 0);
    int same = 1;
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 2; ++k)
            same &= gb.surface[i] == 0 ? memcmp(&bary[2 * i + k], &bary_ref[2 * i + k], 4) == 0
                                       : bary[2 * i + k] == 7.0f;
    CHECK(same);
    CHECK(!signbit(bary[2 * first]) && !signbit(bary[2 * first + 1]));
    free(W), free(V), free(U), free(bary_ref), free(bary);
    pen_gbuffer_free(&gb);
}

/* The rasterizer's points off the objects (the frame's: pen__raster_gbuffer_points) are
 * pen_gbuffer_points' bits, for 1 and 2 threads; the objects' pixels are left alone. */
static void test_gbuffer_points_with_raster(void) {
    ru_scene s;
    ru_scene_init(&s);
    const size_t n = (size_t)s.cam.width * s.cam.height;
    pen_gbuffer gb = ru_gbuffer(s.cam.width, s.cam.height);
    CHECK(ru_raster(&s.view, s.meshes, 2, &s.ground, &gb, 0) == PEN_OK);
    float *ref = malloc(3 * n * sizeof(float)), *pts = malloc(3 * n * sizeof(float));
    pen_gbuffer_points(&s.view, &gb, ref);
    int ground = 0, background = 0, object = 0;
    for (size_t i = 0; i < n; ++i)
        ground += gb.surface[i] == PEN_SURFACE_GROUND,
            background += gb.surface[i] == PEN_SURFACE_BACKGROUND, object += gb.surface[i] >= 0;
    CHECK(ground > 0 && background > 0 && object > 0);
    for (int threads = 1; threads <= 2; ++threads) {
        pen_gbuffer g2 = ru_gbuffer(s.cam.width, s.cam.height);
        for (size_t i = 0; i < 3 * n; ++i)
            pts[i] = 7.0f;
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, threads);
        CHECK(pen__raster_gbuffer_points(ctx, &s.view, s.meshes, 2, &s.ground, &g2, pts) == PEN_OK);
        pen_context_destroy(ctx);
        CHECK(memcmp(g2.surface, gb.surface, n * sizeof(int32_t)) == 0 &&
              memcmp(g2.depth, gb.depth, n * sizeof(float)) == 0);
        int same = 1;
        for (size_t i = 0; i < n; ++i)
            same &= gb.surface[i] < 0 ? memcmp(pts + 3 * i, ref + 3 * i, 3 * sizeof(float)) == 0
                                      : pts[3 * i] == 7.0f && pts[3 * i + 2] == 7.0f;
        CHECK(same);
        pen_gbuffer_free(&g2);
    }
    free(ref), free(pts);
    pen_gbuffer_free(&gb);
}

static void icosahedron(float *pos, uint32_t *idx) {
    const double t = (1 + sqrt(5.0)) / 2;
    const double v[12][3] = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                             {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                             {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    const uint32_t f[60] = {0, 11, 5,  0, 5,  1, 0, 1, 7, 0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11,
                            4, 11, 10, 2, 10, 7, 6, 7, 1, 8, 3,  9,  4, 3,  4,  2, 3, 2, 6, 3,
                            6, 8,  3,  8, 9,  4, 9, 5, 2, 4, 11, 6,  2, 10, 8,  6, 7, 9, 8, 1};
    for (int i = 0; i < 36; ++i)
        pos[i] = (float)(v[i / 3][i % 3] / sqrt(1 + t * t));
    memcpy(idx, f, sizeof f);
}

static double normals_loss(const float *pos, const uint32_t *idx, const float *G, float *nrm) {
    CHECK(pen_vertex_normals_fwd(NULL, 14, pos, 22, idx, nrm) == PEN_OK);
    double l = 0;
    for (int i = 0; i < 42; ++i)
        l += (double)G[i] * (double)nrm[i];
    return l;
}

static void test_vertex_normals(void) {
    /* 20 icosahedron faces, one degenerate triangle on vertex 12, vertex 13 unused. */
    float pos[42], nrm[42], G[42];
    uint32_t idx[66];
    icosahedron(pos, idx);
    pos[36] = 0.1f, pos[37] = 0.2f, pos[38] = 0.3f, pos[39] = pos[40] = pos[41] = 5.0f;
    uint32_t extra[6] = {12, 12, 0, 0, 1, 1};
    memcpy(idx + 60, extra, sizeof extra);
    CHECK(pen_vertex_normals_fwd(NULL, 14, pos, 22, idx, nrm) == PEN_OK);
    for (int v = 0; v < 12; ++v)
        for (int c = 0; c < 3; ++c)
            CHECK_NEAR(nrm[3 * v + c], pos[3 * v + c], 1e-6);
    for (int c = 0; c < 3; ++c)
        CHECK(nrm[36 + c] == 0 && nrm[39 + c] == 0);
    /* Gradient on a jittered copy. */
    unsigned long long seed = 54;
    for (int i = 0; i < 36; ++i)
        pos[i] += (float)(0.1 * (2 * check_rand_(&seed) - 1));
    for (int i = 0; i < 42; ++i)
        G[i] = (float)(2 * check_rand_(&seed) - 1);
    float d_pos[42] = {0};
    CHECK(pen_vertex_normals_bwd(NULL, 14, pos, 22, idx, G, d_pos) == PEN_OK);
    const float h = 1.0f / 512;
    for (int i = 0; i < 42; ++i) {
        float save = pos[i];
        pos[i] = save + h;
        double lp = normals_loss(pos, idx, G, nrm);
        pos[i] = save - h;
        double lm = normals_loss(pos, idx, G, nrm);
        pos[i] = save;
        CHECK_REL(d_pos[i], (lp - lm) / (2.0 * (double)h), 2e-3, 0.1);
    }
    for (int i = 36; i < 42; ++i)
        CHECK(d_pos[i] == 0);
    pen_context *ctx = pen_context_create();
    idx[5] = 14;
    CHECK(pen_vertex_normals_fwd(ctx, 14, pos, 22, idx, nrm) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "triangle 1") != NULL);
    pen_context_destroy(ctx);
}

static void test_normalize(void) {
    float v[12] = {3, 4, 0, -0.2f, 0.5f, 0.9f, 0, 0, 0, 1e-30f, 0, 0}, out[12], g[12], dv[12] = {0};
    unsigned long long seed = 55;
    for (int i = 0; i < 12; ++i)
        g[i] = (float)(2 * check_rand_(&seed) - 1);
    pen_normalize_fwd(4, v, out);
    CHECK_NEAR(out[0], 0.6, 1e-7);
    CHECK_NEAR(out[1], 0.8, 1e-7);
    for (int i = 6; i < 12; ++i)
        CHECK(out[i] == 0);
    pen_normalize_bwd(4, v, g, dv);
    for (int i = 0; i < 6; ++i) {
        double vp[3], vm[3], fd = 0, base = 3 * (i / 3);
        for (int c = 0; c < 3; ++c)
            vp[c] = vm[c] = v[(int)base + c];
        vp[i % 3] += 1e-6, vm[i % 3] -= 1e-6;
        double lp = sqrt(vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2]);
        double lm = sqrt(vm[0] * vm[0] + vm[1] * vm[1] + vm[2] * vm[2]);
        for (int c = 0; c < 3; ++c)
            fd += (double)g[(int)base + c] * (vp[c] / lp - vm[c] / lm) / 2e-6;
        CHECK_REL(dv[i], fd, 1e-5, 1e-3);
    }
    for (int i = 6; i < 12; ++i)
        CHECK(dv[i] == 0);
    /* In place. */
    pen_normalize_fwd(4, v, v);
    CHECK_NEAR(v[3] * v[3] + v[4] * v[4] + v[5] * v[5], 1, 1e-6);
}

RUN_TESTS(TEST(test_ray_bary_backward_fd), TEST(test_interpolation_pipeline_fd),
          TEST(test_interpolation_bary_fd), TEST(test_bary_backward_threads),
          TEST(test_interpolation_object_fused), TEST(test_gbuffer_points_with_raster),
          TEST(test_vertex_normals), TEST(test_normalize))
