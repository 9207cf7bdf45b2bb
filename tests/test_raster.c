/* Rasterizer: coverage, barycentrics and depth against independent references (2D edge
 * functions for screen-space triangles, a brute-force double-precision ray caster for random
 * scenes and near-plane crossings, the analytic ray-plane intersection for the ground), depth
 * order, watertightness, degenerate input, thread-count independence, adjacency, validation. */
#include "raster_util.h"

/* ---- References ---------------------------------------------------------------------------- */

/* Brute-force ray cast of pixel (x, y): the closest hit at depth >= near. Returns the surface
 * (object index or background) with *tri, *depth, *b1, *b2; *ambiguous is set when the pixel
 * lies within eps of an edge or two hits are within eps in depth, where either answer is right. */
static int cast_pixel(const pen_view *view, const pen_raster_mesh *meshes, int n, int x, int y,
                      int *tri, double *depth, double *b1, double *b2, int *ambiguous) {
    const double eps = 1e-6;
    double D[3];
    pen_view_ray(view, x + 0.5, y + 0.5, D);
    int best = PEN_SURFACE_BACKGROUND;
    *depth = INFINITY, *ambiguous = 0, *tri = -1;
    for (int m = 0; m < n; ++m)
        for (int t = 0; t < meshes[m].triangle_count; ++t) {
            double p[3][3], sol[3];
            for (int k = 0; k < 3; ++k)
                pen__load3_d(meshes[m].positions + 3 * meshes[m].indices[3 * t + k], p[k]);
            if (!pen__raster_ray_bary_d(view->eye, D, p[0], p[1], p[2], sol)) continue;
            double b0 = 1 - sol[1] - sol[2], bmin = fmin(b0, fmin(sol[1], sol[2]));
            if (sol[0] < view->near_plane * (1 - eps)) continue;
            if (fabs(bmin) < eps || fabs(sol[0] - view->near_plane) < eps * sol[0]) {
                *ambiguous = 1;
                continue;
            }
            if (bmin < 0) continue;
            if (fabs(sol[0] - *depth) < eps * sol[0]) *ambiguous = 1;
            if (sol[0] < *depth) {
                *depth = sol[0], best = m, *tri = t, *b1 = sol[1], *b2 = sol[2];
            }
        }
    return best;
}

/* Compares a G-buffer with the ray caster; returns the number of unambiguous pixels checked. */
static int check_against_caster(const pen_view *view, const pen_raster_mesh *meshes, int n,
                                const pen_gbuffer *gb) {
    int checked = 0, bad = 0;
    for (int y = 0; y < gb->height; ++y)
        for (int x = 0; x < gb->width; ++x) {
            int tri, amb;
            double z, b1 = 0, b2 = 0;
            int s = cast_pixel(view, meshes, n, x, y, &tri, &z, &b1, &b2, &amb);
            if (amb) continue;
            size_t i = (size_t)y * gb->width + x;
            ++checked;
            if (gb->surface[i] != s || gb->triangle[i] != tri) {
                if (++bad < 5)
                    fprintf(stderr, "pixel %d,%d: got %d/%d, want %d/%d\n", x, y, gb->surface[i],
                            gb->triangle[i], s, tri);
                continue;
            }
            if (s < 0) continue;
            CHECK_REL(gb->depth[i], z, 1e-5, 0);
            CHECK_NEAR(gb->bary[2 * i], b1, 1e-5);
            CHECK_NEAR(gb->bary[2 * i + 1], b2, 1e-5);
        }
    CHECK(bad == 0);
    return checked;
}

/* ---- Known pixels ------------------------------------------------------------------------- */

/* A triangle given by screen positions and per-vertex depths; checks coverage and barycentrics
 * against 2D edge functions (exact for a triangle of constant depth; coverage in general). */
static void check_screen_triangle(const double S[3][2], const double Z[3]) {
    pen_camera cam = ru_camera(32, 32, 45.0f, 0.2f, 0.1f, 5.0f, 0.0f, 0.0f, 0.0f);
    pen_view view = ru_view(&cam);
    float pos[9];
    for (int k = 0; k < 3; ++k)
        ru_unproject(&view, S[k][0], S[k][1], Z[k], pos + 3 * k);
    uint32_t idx[3] = {0, 1, 2};
    pen_raster_mesh mesh = ru_mesh(3, pos, 1, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(32, 32);
    CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    double area =
        (S[1][0] - S[0][0]) * (S[2][1] - S[0][1]) - (S[2][0] - S[0][0]) * (S[1][1] - S[0][1]);
    int covered = 0, expected = 0;
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x) {
            double c[2] = {x + 0.5, y + 0.5}, l[3];
            for (int k = 0; k < 3; ++k) {
                const double *a = S[(k + 1) % 3], *b = S[(k + 2) % 3];
                l[k] = ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / area;
            }
            double lmin = fmin(l[0], fmin(l[1], l[2]));
            size_t i = (size_t)y * 32 + x;
            covered += gb.surface[i] == 0;
            if (fabs(lmin) < 1e-4) continue;
            expected += lmin > 0;
            CHECK(gb.surface[i] == (lmin > 0 ? 0 : PEN_SURFACE_BACKGROUND));
            if (lmin <= 0) {
                CHECK(isinf(gb.depth[i]) && gb.triangle[i] == -1);
                continue;
            }
            /* Perspective-correct barycentrics: b_k = (l_k / z_k) / sum_j (l_j / z_j). */
            double q[3], sum = 0;
            for (int k = 0; k < 3; ++k)
                sum += q[k] = l[k] / Z[k];
            CHECK_NEAR(gb.bary[2 * i], q[1] / sum, 1e-5);
            CHECK_NEAR(gb.bary[2 * i + 1], q[2] / sum, 1e-5);
            CHECK_REL(gb.depth[i], 1.0 / sum, 1e-5, 0);
            CHECK(gb.triangle[i] == 0);
        }
    CHECK(expected > 100);
    CHECK(abs(covered - expected) <= 2);
    pen_gbuffer_free(&gb);
}

static void test_triangle_known_pixels(void) {
    const double S[3][2] = {{4.2, 3.1}, {27.9, 5.3}, {10.4, 28.7}};
    const double flat[3] = {5, 5, 5}, tilted[3] = {2, 6, 3.5};
    check_screen_triangle(S, flat);
    check_screen_triangle(S, tilted);
    /* Clockwise on screen (seen from behind): both faces are drawn. */
    const double R[3][2] = {{4.2, 3.1}, {10.4, 28.7}, {27.9, 5.3}};
    check_screen_triangle(R, tilted);
}

/* ---- Depth order and random scenes --------------------------------------------------------- */

static void test_depth_order(void) {
    pen_camera cam = ru_camera(32, 32, 45.0f, 0, 0, 5, 0, 0, 0);
    pen_view view = ru_view(&cam);
    const double A[3][2] = {{2, 2}, {30, 4}, {6, 30}}, B[3][2] = {{30, 30}, {4, 28}, {28, 3}};
    float pos[18];
    for (int k = 0; k < 3; ++k) {
        ru_unproject(&view, A[k][0], A[k][1], 3.0, pos + 3 * k);
        ru_unproject(&view, B[k][0], B[k][1], 4.0, pos + 9 + 3 * k);
    }
    uint32_t idx[6] = {0, 1, 2, 3, 4, 5}, rev[6] = {3, 4, 5, 0, 1, 2};
    for (int order = 0; order < 2; ++order) {
        pen_raster_mesh mesh = ru_mesh(6, pos, 2, order ? rev : idx, NULL);
        pen_gbuffer gb = ru_gbuffer(32, 32);
        CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
        /* Pixel (16, 16) is inside both; the nearer (A, depth 3) wins in both orders. */
        size_t i = 16 * 32 + 16;
        CHECK(gb.triangle[i] == (order ? 1 : 0));
        CHECK_NEAR(gb.depth[i], 3.0, 1e-5);
        CHECK(check_against_caster(&view, &mesh, 1, &gb) > 900);
        pen_gbuffer_free(&gb);
    }
    /* As two objects: surface ids are object indices. */
    pen_raster_mesh two[2] = {ru_mesh(6, pos, 1, idx + 3, NULL), ru_mesh(6, pos, 1, idx, NULL)};
    pen_gbuffer gb = ru_gbuffer(32, 32);
    CHECK(ru_raster(&view, two, 2, NULL, &gb, 0) == PEN_OK);
    CHECK(gb.surface[16 * 32 + 16] == 1 && gb.surface[27 * 32 + 27] == 0);
    CHECK(check_against_caster(&view, two, 2, &gb) > 900);
    pen_gbuffer_free(&gb);
}

/* n random triangles (some large, some interpenetrating) in a box in front of the camera. */
static void random_soup(unsigned long long *seed, int n, float *pos, uint32_t *idx) {
    for (int t = 0; t < n; ++t) {
        double c[3], size = t % 7 == 0 ? 1.5 : 0.4;
        for (int i = 0; i < 3; ++i)
            c[i] = 2 * check_rand_(seed) - 1;
        for (int k = 0; k < 3; ++k) {
            for (int i = 0; i < 3; ++i)
                pos[9 * t + 3 * k + i] = (float)(c[i] + size * (2 * check_rand_(seed) - 1));
            idx[3 * t + k] = (uint32_t)(3 * t + k);
        }
    }
}

static void test_random_scenes_match_ray_caster(void) {
    unsigned long long seed = 21;
    int n = check_quick_() ? 20 : 60;
    float *pos = malloc(sizeof(float) * 9 * n);
    uint32_t *idx = malloc(sizeof(uint32_t) * 3 * n);
    for (int rep = 0; rep < 3; ++rep) {
        random_soup(&seed, n, pos, idx);
        pen_camera cam = ru_camera(45, 37, 50.0f, 0.5f, 0.8f, 4.0f, 0, 0, 0);
        pen_view view = ru_view(&cam);
        pen_raster_mesh mesh = ru_mesh(3 * n, pos, n, idx, NULL);
        pen_gbuffer gb = ru_gbuffer(45, 37);
        CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
        CHECK(ru_gbuffer_sane(&gb));
        CHECK(check_against_caster(&view, &mesh, 1, &gb) > 45 * 37 * 9 / 10);
        pen_gbuffer_free(&gb);
    }
    free(pos);
    free(idx);
}

static void test_near_plane_clipping(void) {
    /* Large triangles reaching behind the eye and crossing the near plane, from a camera inside
     * a random soup; the near plane is moved out so it cuts many pixels. */
    pen_camera cam = ru_camera(40, 30, 70.0f, 0, 0, 0.3f, 0, 0, -1);
    pen_view view = ru_view(&cam);
    view.near_plane = 0.4;
    float pos[] = {-3, -1, 2,  3,    -1, 2, 0, 1.5f, -3,   /* through the eye's side */
                   -1, 2,  -2, 1,    -2, 1, 2, 2,    0.2f, /* crossing near */
                   0,  0,  5,  0.1f, 0,  5, 0, 0.1f, 5};   /* fully behind */
    uint32_t idx[9] = {0, 1, 2, 3, 4, 5, 6, 7, 8};
    pen_raster_mesh mesh = ru_mesh(9, pos, 3, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(40, 30);
    CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    int covered = 0;
    for (int i = 0; i < 40 * 30; ++i)
        if (gb.surface[i] >= 0) {
            ++covered;
            CHECK(gb.depth[i] >= 0.4f);
            CHECK(gb.triangle[i] != 2);
        }
    CHECK(covered > 100 && covered < 40 * 30);
    CHECK(check_against_caster(&view, &mesh, 1, &gb) > 1000);
    pen_gbuffer_free(&gb);
}

/* ---- Ground plane -------------------------------------------------------------------------- */

static void test_ground_plane_analytic(void) {
    pen_camera cam = ru_camera(48, 32, 60.0f, 0.4f, 1.5f, 4.0f, 0, 0, 0);
    pen_view view = ru_view(&cam);
    pen_ground ground = {1, -0.25f, {0.8f, 0.8f, 0.8f}, 2.0f};
    /* A triangle standing on the ground occludes part of it. */
    float pos[9] = {-0.5f, -0.25f, 0.5f, 0.5f, -0.25f, 0.5f, 0.0f, 0.8f, 0.5f};
    uint32_t idx[3] = {0, 1, 2};
    pen_raster_mesh mesh = ru_mesh(3, pos, 1, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(48, 32);
    CHECK(ru_raster(&view, &mesh, 1, &ground, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    float fwd[3], r[3], u[3];
    pen_camera_frame(&cam, r, u, fwd);
    int ground_pixels = 0, checked = 0;
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 48; ++x) {
            size_t i = (size_t)y * 48 + x;
            float d[3];
            pen_camera_ray(&cam, x + 0.5f, y + 0.5f, d); /* unit direction */
            double dd[3] = {d[0], d[1], d[2]};
            double t = (-0.25 - 1.5) / dd[1];
            double hx = 0.4 + t * dd[0], hz = 4.0 + t * dd[2];
            int tri, amb;
            double zm, b1, b2;
            int s_mesh = cast_pixel(&view, &mesh, 1, x, y, &tri, &zm, &b1, &b2, &amb);
            ground_pixels += gb.surface[i] == PEN_SURFACE_GROUND;
            if (s_mesh == 0) {
                CHECK(gb.surface[i] == 0);
                continue;
            }
            if (fabs(fabs(hx) - 2) < 1e-3 || fabs(fabs(hz) - 2) < 1e-3) continue;
            int hit = t > 0 && fabs(hx) <= 2 && fabs(hz) <= 2;
            if (amb) continue;
            ++checked;
            CHECK(gb.surface[i] == (hit ? PEN_SURFACE_GROUND : PEN_SURFACE_BACKGROUND));
            if (!hit) continue;
            double depth =
                t * (dd[0] * (double)fwd[0] + dd[1] * (double)fwd[1] + dd[2] * (double)fwd[2]);
            CHECK_REL(gb.depth[i], depth, 1e-5, 0);
            CHECK(gb.triangle[i] == -1);
        }
    CHECK(ground_pixels > 300 && ground_pixels < 48 * 32);
    CHECK(checked > 1400);
    /* A disabled ground is ignored. */
    ground.enabled = 0;
    CHECK(ru_raster(&view, &mesh, 1, &ground, &gb, 0) == PEN_OK);
    for (int i = 0; i < 48 * 32; ++i)
        CHECK(gb.surface[i] != PEN_SURFACE_GROUND);
    pen_gbuffer_free(&gb);
}

/* ---- Robustness ---------------------------------------------------------------------------- */

static void test_degenerate_and_grazing(void) {
    pen_camera cam = ru_camera(32, 24, 45.0f, 0, 0, 3, 0, 0, 0);
    pen_view view = ru_view(&cam);
    float pos[] = {
        -1,     -1,     0,      1,      1,
        0,      0.5f,   0.5f,   0, /* collinear */
        0.2f,   0.3f,   0,      0.2f,   0.3f,
        0,      0.7f,   -0.1f,  0, /* repeated vertex */
        0,      0,      0,      0,      0,
        0,      0,      0,      0, /* a point */
        0,      -1,     3,      0,      1,
        -1,     0,      0.5f,   0, /* edge-on: plane x = 0 through the eye */
        -1e-7f, 0,      0,      1e-7f,  0,
        0,      0,      1e-7f,  0, /* far below a pixel */
        -1e30f, -1e30f, -1e30f, 1e30f,  0,
        0,      0,      1e30f,  -1e30f, /* huge */
    };
    uint32_t idx[18];
    for (int i = 0; i < 18; ++i)
        idx[i] = (uint32_t)i;
    pen_raster_mesh mesh = ru_mesh(18, pos, 6, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(32, 24);
    pen_ground grazing = {1, -1e-4f, {1, 1, 1}, 1e4f};
    CHECK(ru_raster(&view, &mesh, 1, &grazing, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    for (int i = 0; i < 32 * 24; ++i)
        CHECK(gb.surface[i] < 0 || gb.triangle[i] >= 4);
    /* Eye just above a huge ground looking at the horizon: depths grow without bound but stay
     * finite and ordered by row. */
    pen_camera low = ru_camera(32, 24, 45.0f, 0, 0.01f, 0, 0, 0.01f, -1);
    pen_view lv = ru_view(&low);
    CHECK(ru_raster(&lv, NULL, 0, &grazing, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    CHECK(gb.surface[23 * 32 + 5] == PEN_SURFACE_GROUND && gb.surface[5] == PEN_SURFACE_BACKGROUND);
    CHECK(gb.depth[23 * 32 + 5] < gb.depth[13 * 32 + 5]);
    pen_gbuffer_free(&gb);
}

static void test_watertight_grid(void) {
    /* A tilted, slightly warped grid of quads split along alternating diagonals, larger than
     * the view: every pixel must be covered (no cracks along shared edges). */
    enum { N = 13 };
    float pos[(N + 1) * (N + 1) * 3];
    uint32_t idx[N * N * 6];
    unsigned long long seed = 31;
    for (int j = 0; j <= N; ++j)
        for (int i = 0; i <= N; ++i) {
            float *p = pos + 3 * (j * (N + 1) + i);
            double jit = i % N && j % N ? 0.05 * (2 * check_rand_(&seed) - 1) : 0.0;
            double px = -3 + 6.0 * i / N + jit, py = -3 + 6.0 * j / N - jit;
            p[0] = (float)px;
            p[1] = (float)py;
            p[2] = (float)(0.3 * px + 0.2 * py + 0.1 * sin(3.0 * i * j));
        }
    int t = 0;
    for (int j = 0; j < N; ++j)
        for (int i = 0; i < N; ++i) {
            uint32_t a = (uint32_t)(j * (N + 1) + i), b = a + 1, c = a + N + 1, d = c + 1;
            uint32_t q[6] = {a, b, d, a, d, c}, r[6] = {a, b, c, b, d, c};
            memcpy(idx + 6 * t++, (i + j) % 2 ? q : r, sizeof q);
        }
    pen_camera cam = ru_camera(53, 41, 40.0f, 0.1f, 0.2f, 4.0f, 0, 0, 0);
    pen_view view = ru_view(&cam);
    pen_raster_mesh mesh = ru_mesh((N + 1) * (N + 1), pos, 2 * N * N, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(53, 41);
    CHECK(ru_raster(&view, &mesh, 1, NULL, &gb, 0) == PEN_OK);
    int holes = 0;
    for (int i = 0; i < 53 * 41; ++i)
        holes += gb.surface[i] != 0;
    CHECK(holes == 0);
    pen_gbuffer_free(&gb);
}

static void test_thread_count_independent(void) {
    unsigned long long seed = 41;
    int n = 300;
    float *pos = malloc(sizeof(float) * 9 * n);
    uint32_t *idx = malloc(sizeof(uint32_t) * 3 * n);
    random_soup(&seed, n, pos, idx);
    pen_camera cam = ru_camera(RU_PARALLEL_W, RU_PARALLEL_H, 50.0f, 0.5f, 0.8f, 3.0f, 0, 0, 0);
    pen_view view = ru_view(&cam);
    pen_raster_mesh mesh = ru_mesh(3 * n, pos, n, idx, NULL);
    pen_ground ground = {1, -0.5f, {1, 1, 1}, 3};
    pen_gbuffer g1 = ru_gbuffer(RU_PARALLEL_W, RU_PARALLEL_H);
    pen_gbuffer g[2] = {ru_gbuffer(RU_PARALLEL_W, RU_PARALLEL_H),
                        ru_gbuffer(RU_PARALLEL_W, RU_PARALLEL_H)};
    CHECK(ru_raster(&view, &mesh, 1, &ground, &g1, 1) == PEN_OK);
    for (int k = 0; k < 2; ++k) {
        CHECK(ru_raster(&view, &mesh, 1, &ground, &g[k], k + 2) == PEN_OK);
        size_t n_px = RU_PARALLEL_W * RU_PARALLEL_H;
        CHECK(memcmp(g1.surface, g[k].surface, n_px * 4) == 0);
        CHECK(memcmp(g1.triangle, g[k].triangle, n_px * 4) == 0);
        CHECK(memcmp(g1.bary, g[k].bary, n_px * 8) == 0);
        CHECK(memcmp(g1.depth, g[k].depth, n_px * 4) == 0);
        pen_gbuffer_free(&g[k]);
    }
    pen_gbuffer_free(&g1);
    free(pos);
    free(idx);
}

/* The bundled Spot mesh on the ground: the G-buffer matches the ray caster, its smooth normals
 * are unit, and it is a closed mesh (every edge has one neighbour). */
static void test_spot_mesh(void) {
    pen_context *ctx = pen_context_create();
    pen_mesh mesh;
    pen_status st = pen_mesh_load(ctx, PEN_SOURCE_DIR "/data/meshes/spot_triangulated.obj", &mesh);
    CHECK_MSG(st == PEN_OK, "%s", pen_context_error(ctx));
    if (st) {
        pen_context_destroy(ctx);
        return;
    }
    int size = check_quick_() ? 20 : 40;
    pen_camera cam = ru_camera(size, size, 35.0f, 0.5f, 1.2f, 3.0f, 0, 0.1f, 0);
    pen_view view = ru_view(&cam);
    int32_t *adj = malloc(sizeof(int32_t) * 3 * (size_t)mesh.triangle_count);
    float *nrm = malloc(sizeof(float) * 3 * (size_t)mesh.vertex_count);
    CHECK(pen_raster_adjacency(ctx, mesh.vertex_count, mesh.triangle_count, mesh.indices, adj) ==
          PEN_OK);
    int boundary = 0;
    for (int i = 0; i < 3 * mesh.triangle_count; ++i)
        boundary += adj[i] < 0;
    CHECK(boundary == 0);
    CHECK(pen_vertex_normals_fwd(ctx, mesh.vertex_count, mesh.positions, mesh.triangle_count,
                                 mesh.indices, nrm) == PEN_OK);
    for (int v = 0; v < mesh.vertex_count; ++v) {
        const float *n = nrm + 3 * v;
        CHECK_NEAR(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1, 1e-5);
    }
    pen_raster_mesh rm =
        ru_mesh(mesh.vertex_count, mesh.positions, mesh.triangle_count, mesh.indices, adj);
    pen_ground ground = {1, -0.75f, {1, 1, 1}, 3};
    pen_gbuffer gb = ru_gbuffer(size, size);
    CHECK(ru_raster(&view, &rm, 1, &ground, &gb, 0) == PEN_OK);
    CHECK(ru_gbuffer_sane(&gb));
    int covered = 0;
    for (int i = 0; i < size * size; ++i)
        covered += gb.surface[i] == 0;
    CHECK(covered > size * size / 10);
    /* Without the ground, the mesh pixels agree with the ray caster. */
    CHECK(ru_raster(&view, &rm, 1, NULL, &gb, 0) == PEN_OK);
    CHECK(check_against_caster(&view, &rm, 1, &gb) > size * size * 9 / 10);
    free(adj);
    free(nrm);
    pen_gbuffer_free(&gb);
    pen_mesh_free(&mesh);
    pen_context_destroy(ctx);
}

/* ---- Adjacency and validation -------------------------------------------------------------- */

static void test_adjacency(void) {
    /* Tetrahedron: every edge has one neighbour, which holds the same edge reversed, and whose
     * third vertex is the one vertex not on t; the relation is symmetric. */
    uint32_t tet[12] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3};
    int32_t adj[12];
    CHECK(pen_raster_adjacency(NULL, 4, 4, tet, adj) == PEN_OK);
    for (int t = 0; t < 4; ++t) {
        uint32_t missing = 6 - tet[3 * t] - tet[3 * t + 1] - tet[3 * t + 2];
        for (int k = 0; k < 3; ++k) {
            int32_t h = adj[3 * t + k];
            CHECK(h >= 0 && h < 12 && h / 3 != t && adj[h] == 3 * t + k);
            if (h < 0 || h >= 12) continue;
            int u = h / 3, j = h % 3;
            CHECK(tet[3 * u + j] == tet[3 * t + (k + 1) % 3] &&
                  tet[3 * u + (j + 1) % 3] == tet[3 * t + k]);
            CHECK(tet[3 * u + (j + 2) % 3] == missing);
        }
    }
    /* Quad: the diagonal (edge 2 of the first, edge 0 of the second) is shared, the rim is
     * boundary. */
    uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    CHECK(pen_raster_adjacency(NULL, 4, 2, quad, adj) == PEN_OK);
    CHECK(adj[0] == -1 && adj[1] == -1 && adj[2] == 3);
    CHECK(adj[3] == 2 && adj[4] == -1 && adj[5] == -1);
    /* Three triangles on one edge (non-manifold): -1 there. */
    uint32_t fan[9] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    CHECK(pen_raster_adjacency(NULL, 5, 3, fan, adj) == PEN_OK);
    CHECK(adj[0] == -1 && adj[3] == -1 && adj[6] == -1);
    /* A degenerate triangle (repeated vertex) pairs with nothing. */
    uint32_t deg[6] = {0, 0, 1, 0, 1, 2};
    CHECK(pen_raster_adjacency(NULL, 3, 2, deg, adj) == PEN_OK);
    CHECK(adj[0] == -1 && adj[3] == -1);
    pen_context *ctx = pen_context_create();
    uint32_t oob[3] = {0, 1, 7};
    CHECK(pen_raster_adjacency(ctx, 3, 1, oob, adj) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "index 7") != NULL);
    pen_context_destroy(ctx);
}

static void test_validation(void) {
    pen_context *ctx = pen_context_create();
    pen_camera cam = ru_camera(16, 16, 45.0f, 0, 0, 3, 0, 0, 0);
    pen_view view = ru_view(&cam);
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint32_t idx[3] = {0, 1, 3};
    pen_raster_mesh mesh = ru_mesh(3, pos, 1, idx, NULL);
    pen_gbuffer gb = ru_gbuffer(16, 16), small = ru_gbuffer(8, 16);
    CHECK(pen_raster_gbuffer(ctx, &view, &mesh, 1, NULL, &gb) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "mesh 0: triangle 0: index 3") != NULL);
    idx[2] = 2, pos[4] = NAN;
    CHECK(pen_raster_gbuffer(ctx, &view, &mesh, 1, NULL, &gb) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "vertex 1") != NULL);
    pos[4] = 0;
    CHECK(pen_raster_gbuffer(ctx, &view, &mesh, 1, NULL, &small) == PEN_ERROR_ARGUMENT);
    pen_ground bad = {1, 0, {1, 1, 1}, -1};
    CHECK(pen_raster_gbuffer(ctx, &view, &mesh, 1, &bad, &gb) == PEN_ERROR_ARGUMENT);
    CHECK(pen_raster_gbuffer(ctx, &view, &mesh, 1, NULL, &gb) == PEN_OK);
    pen_gbuffer none;
    CHECK(pen_gbuffer_create(ctx, 0, 5, &none) == PEN_ERROR_ARGUMENT && none.surface == NULL);
    pen_gbuffer_free(&none);
    pen_gbuffer_free(NULL);
    pen_gbuffer_free(&gb);
    pen_gbuffer_free(&small);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_triangle_known_pixels), TEST(test_depth_order),
          TEST(test_random_scenes_match_ray_caster), TEST(test_near_plane_clipping),
          TEST(test_ground_plane_analytic), TEST(test_degenerate_and_grazing),
          TEST(test_watertight_grid), TEST(test_thread_count_independent), TEST(test_spot_mesh),
          TEST(test_adjacency), TEST(test_validation))
