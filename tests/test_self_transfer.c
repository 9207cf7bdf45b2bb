/* Self-shadowing by the precomputed transfer of the object's own mesh (src/render/self.c,
 * src/geometry/transfer.c; docs/design.md sec. 1.15).
 *
 * - A convex mesh blocks nothing of its own clamped cosine: B = 0 at every vertex, every light
 *   fraction 1, so it shades exactly as the clamped cosine. Convexity is detected (box,
 *   octahedron, not an L prism), and a convex object is traced at its vertices, against the
 *   ground only, with the same B as tracing its mesh too.
 * - A concave mesh (a V of two subdivided quads) against the ray-traced reference's exact
 *   visibility: the transfer is much closer than the object's own spheres; with a disk light too.
 * - The node lattice refining coarse meshes: exact on linear fields, continuous across edges; a
 *   coarse V (8 triangles) against the reference.
 * - The kernel with a transfer against central differences in double: lighting, albedo, and the
 *   other objects' spheres, x and n (the blocked part a constant).
 * - A frame's lighting and albedo gradients with the transfer on (the image is linear in them).
 * - The cache: kept while the pose stays, rebuilt when it moves.
 * - The same transfer and the same image for any thread count, and from either kernel.
 * - "self": "spheres" (scene) and pen_render_grad_model's switch render as the sphere model. */
#include "check.h"
#include "render_scenes.h"

#include "core/random.h"
#include "geometry/lattice.h"
#include "geometry/transfer.h"
#include "render/transfer_pool.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ---- Scenes ---------------------------------------------------------------------------------- */

/* A V of two quads meeting along the z axis at height 0.3, each rising 0.55 over 0.55 sideways,
 * 1.1 deep, subdivided k x k; faces wound so that the normals point into the V (up and inwards). */
static pen_mesh v_mesh(int k) {
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    for (int side = -1; side <= 1; side += 2) {
        int id[17][17];
        for (int i = 0; i <= k; ++i)
            for (int j = 0; j <= k; ++j) {
                const float s = (float)i / (float)k, t = (float)j / (float)k;
                const float p[3] = {side * 0.55f * s, 0.3f + 0.55f * s, -0.55f + 1.1f * t};
                id[i][j] = rs_vertex(&b, p);
            }
        for (int i = 0; i < k; ++i)
            for (int j = 0; j < k; ++j) {
                const int a = id[i][j], c = id[i + 1][j], d = id[i + 1][j + 1], e = id[i][j + 1];
                if (side > 0)
                    rs_triangle(&b, a, e, d), rs_triangle(&b, a, d, c);
                else
                    rs_triangle(&b, a, c, d), rs_triangle(&b, a, d, e);
            }
    }
    pen_mesh m;
    memset(&m, 0, sizeof m);
    m.vertex_count = b.nv, m.triangle_count = b.nt;
    m.positions = b.pos, m.indices = b.idx;
    return m;
}

/* The V (k x k quads per wall) with four spheres along its walls, no ground, size x size, the
 * camera looking into it. */
static pen_scene v_scene_k(int size, int k) {
    pen_scene sc = rs_scene(size, size);
    sc.ground.enabled = 0;
    const float sph[16] = {-0.2f, 0.52f, -0.25f, 0.2f, -0.2f, 0.52f, 0.25f, 0.2f,
                           0.2f,  0.52f, -0.25f, 0.2f, 0.2f,  0.52f, 0.25f, 0.2f};
    rs_add_object(&sc, v_mesh(k), 4, sph);
    const float eye[3] = {0.2f, 1.9f, 1.6f}, target[3] = {0.0f, 0.45f, 0.0f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    return sc;
}

static pen_scene v_scene(int size) { return v_scene_k(size, 16); }

/* The scene's one disk light: direction d, angular radius in degrees, grey irradiance. */
static void one_light(pen_scene *sc, const float d[3], float radius_deg, float irradiance) {
    sc->lighting.light_count = 1;
    sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
    pen_light *L = &sc->lighting.lights[0];
    memcpy(L->direction, d, 3 * sizeof(float));
    L->angular_radius_deg = radius_deg;
    L->irradiance[0] = L->irradiance[1] = L->irradiance[2] = irradiance;
}

static pen_image reference_of(const pen_scene *sc, int spp) {
    pen_image img = {0, 0, 0, NULL};
    pen_context *ctx = pen_context_create();
    pen_reference *ref = NULL;
    CHECK(pen_reference_create(ctx, sc, PEN_REFERENCE_LIGHTING_SH, &ref) == PEN_OK);
    CHECK(pen_reference_render(ctx, ref, spp, 1, &img) == PEN_OK);
    pen_reference_destroy(ref);
    pen_context_destroy(ctx);
    return img;
}

/* The mesh as its own occluder, its vertices as the receivers (the renderer's self transfer). */
static pen__transfer_mesh tmesh;
static pen__transfer_request request_of(const pen_mesh *m, const float *normals, int bands) {
    pen__transfer_request rq;
    memset(&rq, 0, sizeof rq);
    tmesh = (pen__transfer_mesh){m->vertex_count, m->triangle_count, m->positions, m->indices};
    rq.mesh_count = 1, rq.meshes = &tmesh;
    rq.point_count = m->vertex_count, rq.points = m->positions, rq.normals = normals;
    rq.bands = bands;
    return rq;
}

/* ---- Tests ----------------------------------------------------------------------------------- */

static void test_convex_blocks_nothing(void) {
    pen_context *ctx = pen_context_create();
    pen_mesh m = rs_octasphere(3, 0.5f, 0);
    float *nrm = malloc(sizeof(float) * 3 * (size_t)m.vertex_count);
    CHECK(pen_vertex_normals_fwd(ctx, m.vertex_count, m.positions, m.triangle_count, m.indices,
                                 nrm) == PEN_OK);
    pen__transfer_request rq = request_of(&m, nrm, 4);
    const double w[2][3] = {{0.0, 1.0, 0.0}, {0.6, 0.0, 0.8}}, b[2] = {0.05, 0.3};
    rq.light_count = 2, rq.light_w = w, rq.light_b = b;
    float *B = malloc(sizeof(float) * 16 * (size_t)m.vertex_count);
    float *frac = malloc(sizeof(float) * 2 * (size_t)m.vertex_count);
    CHECK(pen__transfer(ctx, &rq, B, frac) == PEN_OK);
    double worst = 0.0, fworst = 0.0;
    for (int i = 0; i < 16 * m.vertex_count; ++i)
        worst = fmax(worst, fabs((double)B[i]));
    for (int i = 0; i < 2 * m.vertex_count; ++i)
        fworst = fmax(fworst, fabs((double)frac[i] - 1.0));
    CHECK_MSG(worst == 0.0 && fworst == 0.0, "convex mesh: |B| up to %g, |1 - frac| up to %g",
              worst, fworst);
    /* The transfer H_n - B is then the clamped cosine's projection: the whole scene renders as
     * with the sphere model switched off for the object (no other object). */
    free(B), free(frac), free(nrm);
    pen_mesh_free(&m);
    pen_context_destroy(ctx);
}

/* A box [-a, a]^3 (12 triangles, outward); `inverted` winds every triangle the other way. */
static pen_mesh box_mesh(float a, int inverted) {
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    static const int Q[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                                {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
    for (int i = 0; i < 8; ++i) {
        const float p[3] = {(i & 4) ? a : -a, (i & 2) ? a : -a, (i & 1) ? a : -a};
        rs_vertex(&b, p);
    }
    for (int f = 0; f < 6; ++f) {
        const int *q = Q[f];
        if (inverted)
            rs_triangle(&b, q[0], q[2], q[1]), rs_triangle(&b, q[0], q[3], q[2]);
        else
            rs_triangle(&b, q[0], q[1], q[2]), rs_triangle(&b, q[0], q[2], q[3]);
    }
    return rs_builder_mesh(&b);
}

/* An L-shaped prism, closed and outward: the L (0,0) (2,0) (2,1) (1,1) (1,2) (0,2) extruded along
 * z from 0 to 1, its caps fanned from the reflex corner (1,1) so that every triangle is inside the
 * L. Not convex: the reflex corner's walls face vertices of the other arm. */
static pen_mesh l_mesh(void) {
    static const float L[6][2] = {{0, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2}, {0, 2}};
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    for (int z = 0; z < 2; ++z)
        for (int i = 0; i < 6; ++i) {
            const float p[3] = {L[i][0], L[i][1], (float)z};
            rs_vertex(&b, p); /* vertex i + 6 z */
        }
    static const int fan[4][3] = {{3, 4, 5}, {3, 5, 0}, {3, 0, 1}, {3, 1, 2}};
    for (int f = 0; f < 4; ++f) {
        rs_triangle(&b, fan[f][0] + 6, fan[f][1] + 6, fan[f][2] + 6); /* top, +z, CCW */
        rs_triangle(&b, fan[f][0], fan[f][2], fan[f][1]);             /* bottom, -z */
    }
    for (int i = 0; i < 6; ++i) { /* walls: the polygon is CCW, so outward is to its right */
        const int j = (i + 1) % 6;
        rs_triangle(&b, i, j, j + 6), rs_triangle(&b, i, j + 6, i + 6);
    }
    return rs_builder_mesh(&b);
}

/* The convexity test that sends a mesh to the vertices alone (docs/design.md sec. 1.15): a box,
 * an octahedron and an octasphere are convex, in any position and scale; an L prism, the open V,
 * an inside-out box and a box with a dented corner are not; nor is a mesh over
 * the pair budget. */
static void test_convexity(void) {
    pen_mesh box = box_mesh(0.5f, 0), inv = box_mesh(0.5f, 1), lm = l_mesh(), v = v_mesh(2);
    pen_mesh oct = rs_octasphere(0, 0.1f, 0), ball = rs_octasphere(3, 7.0f, 0);
    CHECK(box.vertex_count == 8 && box.triangle_count == 12);
    CHECK(oct.vertex_count == 6 && oct.triangle_count == 8);
    CHECK(lm.vertex_count == 12 && lm.triangle_count == 20);
#define CONVEX(m)                                                                                  \
    pen__lattice_convex((m).vertex_count, (m).positions, (m).triangle_count, (m).indices, 1e9)
    CHECK(CONVEX(box) == 1);
    CHECK(CONVEX(oct) == 1);
    CHECK(CONVEX(ball) == 1);
    CHECK(CONVEX(lm) == 0);
    CHECK(CONVEX(v) == 0);
    CHECK(CONVEX(inv) == 0);
    for (int i = 0; i < 3 * box.vertex_count; ++i) /* far from the origin: relative tolerance */
        box.positions[i] = 1000.0f + 3.0f * box.positions[i];
    CHECK(CONVEX(box) == 1);
    for (int a = 0; a < 3; ++a) /* corner 7 dented inwards: its faces' other corners stick out */
        box.positions[3 * 7 + a] -= 0.1f;
    CHECK(CONVEX(box) == 0);
    CHECK(pen__lattice_convex(ball.vertex_count, ball.positions, ball.triangle_count, ball.indices,
                              (double)ball.vertex_count * ball.triangle_count - 1.0) == 0);
#undef CONVEX
    pen_mesh_free(&box), pen_mesh_free(&inv), pen_mesh_free(&lm), pen_mesh_free(&v);
    pen_mesh_free(&oct), pen_mesh_free(&ball);
}

/* A convex object over the ground (the ellipsoid of rs_ball_scene) gets the vertices alone
 * (level 1), traced against the ground only; the result is bit for bit what tracing its own mesh
 * too gives at those vertices (the mesh cannot block them), and the image stays close to the
 * ray-traced reference: the ground's occlusion is smooth over the object, so the vertices
 * interpolate it as well as the old lattice of 1/128 of the diagonal. */
static void test_convex_vertices(void) {
    unsigned long long seed = 7;
    pen_scene sc = rs_ball_scene(64, 0, &seed);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image img;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
    const pen__object_buf *b = &st->obj[0];
    const pen_mesh *m = &sc.objects[0].mesh;
    CHECK(b->self_on && b->self_valid && st->ground_occludes);
    CHECK(b->self_lat.level == 1 && b->self_lat.node_count == m->vertex_count);
    /* The same vertices traced with the mesh as an occluder too. */
    const pen__transfer_mesh tm = {m->vertex_count, m->triangle_count, b->world.data, m->indices};
    pen__transfer_request rq;
    memset(&rq, 0, sizeof rq);
    rq.mesh_count = 1, rq.meshes = &tm, rq.point_count = m->vertex_count;
    rq.points = b->world.data, rq.normals = b->vnormal.data, rq.bands = sc.sh_bands;
    rq.ground = &sc.ground;
    const size_t nc = (size_t)sc.sh_bands * (size_t)sc.sh_bands;
    float *B = malloc(sizeof(float) * nc * (size_t)m->vertex_count);
    CHECK(pen__transfer(ctx, &rq, B, NULL) == PEN_OK);
    size_t differ = 0, ground = 0;
    for (size_t i = 0; i < nc * (size_t)m->vertex_count; ++i) {
        differ += B[i] != b->self_B.data[i];
        ground += B[i] != 0.0f;
    }
    CHECK_MSG(differ == 0, "%zu of %zu values differ with the mesh traced", differ,
              nc * (size_t)m->vertex_count);
    CHECK(ground > 0); /* the ground does block the lower vertices */
    free(B);
    pen_image ref = reference_of(&sc, check_quick_() ? 64 : 256);
    const double e = rs_rel_error(&img, &ref);
    printf("  convex ellipsoid over the ground: rel. error against the reference %.4f\n", e);
    /* Measured at 256 spp: 0.0211, against 0.0207 with the lattice of 1/128 of the diagonal
     * that traced the mesh too; 64 spp (quick) adds noise. */
    CHECK(e < (check_quick_() ? 0.05 : 0.025));
    pen_image_free(&img), pen_image_free(&ref);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* Measured: transfer 0.011, own spheres 0.116 (SH only); with a disk light 0.021 and 0.140. */
static void test_concave_against_reference(void) {
    for (int lit = 0; lit < 2; ++lit) {
        pen_scene sc = v_scene(64);
        if (lit) {
            const float d[3] = {0.8f, 0.45f, 0.2f};
            one_light(&sc, d, 3.0f, 2.5f);
        }
        pen_image ref = reference_of(&sc, check_quick_() ? 64 : 512);
        pen_render_options opt = pen_render_options_default();
        pen_image tr = {0, 0, 0, NULL}, sp = {0, 0, 0, NULL};
        CHECK(rs_render(&sc, &opt, 2, &tr) == PEN_OK);
        sc.shadow.self = PEN_SELF_SPHERES;
        CHECK(rs_render(&sc, &opt, 2, &sp) == PEN_OK);
        sc.shadow.self = PEN_SELF_TRANSFER;
        const double et = rs_rel_error(&tr, &ref), es = rs_rel_error(&sp, &ref);
        printf("  V %s: rel. error against the reference: transfer %.4f, own spheres %.4f\n",
               lit ? "with a disk light" : "under SH light", et, es);
        CHECK(et < 0.05);
        CHECK(et < 0.5 * es);
        pen_image_free(&tr), pen_image_free(&sp), pen_image_free(&ref);
        pen_scene_free(&sc);
    }
}

/* The default render's rel. error against the exact-visibility reference (512 spp; 64 quick). */
static double default_error(const pen_scene *sc) {
    pen_image ref = reference_of(sc, check_quick_() ? 64 : 512);
    pen_render_options opt = pen_render_options_default();
    pen_image tr = {0, 0, 0, NULL};
    CHECK(rs_render(sc, &opt, 2, &tr) == PEN_OK);
    const double e = tr.data ? rs_rel_error(&tr, &ref) : 1.0;
    pen_image_free(&tr), pen_image_free(&ref);
    return e;
}

/* A ball with a thin square rod pushed half into it: two closed shells meeting as a scanned
 * animal's legs meet its body. The rod's nodes inside the ball see nothing; left in the
 * interpolation they darkened its visible part out to the next node (docs/results/accuracy.md,
 * "A thin-limbed figure under a low sun"). Against the exact visibility under a disk light low
 * over the rod's side, with the ground off so that only the object is measured. */
static void test_buried_nodes(void) {
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    pen_mesh ball = rs_octasphere(3, 0.35f, 0);
    for (int t = 0; t < ball.triangle_count; ++t) {
        int v[3];
        for (int c = 0; c < 3; ++c) {
            const float *q = ball.positions + 3 * (size_t)ball.indices[3 * t + c];
            const float p[3] = {q[0], q[1] + 0.5f, q[2]};
            v[c] = rs_vertex(&b, p);
        }
        rs_triangle(&b, v[0], v[1], v[2]);
    }
    free(ball.positions), free(ball.indices);
    /* the rod along +x from the ball's centre, half width 0.03, its far end capped */
    const float r = 0.03f, x0 = 0.0f, x1 = 0.9f;
    int q[2][4];
    for (int e = 0; e < 2; ++e)
        for (int k = 0; k < 4; ++k) {
            const float p[3] = {e ? x1 : x0, 0.5f + ((k == 1 || k == 2) ? r : -r),
                                (k >= 2 ? r : -r)};
            q[e][k] = rs_vertex(&b, p);
        }
    for (int k = 0; k < 4; ++k) { /* sides, outwards */
        const int n = (k + 1) % 4;
        rs_triangle(&b, q[0][k], q[0][n], q[1][n]), rs_triangle(&b, q[0][k], q[1][n], q[1][k]);
    }
    rs_triangle(&b, q[1][0], q[1][1], q[1][2]), rs_triangle(&b, q[1][0], q[1][2], q[1][3]);
    rs_triangle(&b, q[0][0], q[0][2], q[0][1]), rs_triangle(&b, q[0][0], q[0][3], q[0][2]);
    pen_scene sc = rs_scene(96, 96);
    sc.ground.enabled = 0;
    const float sph[8] = {0.0f, 0.5f, 0.0f, 0.35f, 0.6f, 0.5f, 0.0f, 0.08f};
    rs_add_object(&sc, rs_builder_mesh(&b), 2, sph);
    const float eye[3] = {0.6f, 1.3f, 1.6f}, target[3] = {0.4f, 0.5f, 0.0f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    const float d[3] = {0.3f, 0.35f, 0.9f};
    one_light(&sc, d, 1.0f, 3.0f);
    const double et = default_error(&sc);
    printf("  rod in a ball: rel. error against the reference %.4f\n", et);
    CHECK(et < 0.025); /* 0.048 with the buried nodes in the interpolation */
    pen_scene_free(&sc);
}

/* The node lattice: level 1 is the mesh; at level 4 on the coarse V the node count is
 * V + 3 E + 3 T, a linear function sampled at the nodes is reproduced exactly inside every
 * triangle, and a field of random node values is continuous across every shared edge (both
 * triangles interpolate the same nodes there). */
static void test_lattice(void) {
    pen_context *ctx = pen_context_create();
    pen_mesh m = v_mesh(3);
    pen__lattice lat;
    memset(&lat, 0, sizeof lat);
    CHECK(pen__lattice_build(ctx, &lat, 1, m.vertex_count, m.triangle_count, m.indices) == PEN_OK);
    CHECK(lat.node_count == m.vertex_count);
    int node[3];
    double w[3];
    pen__lattice_locate(&lat, m.indices, 5, 0.25, 0.5, node, w);
    for (int c = 0; c < 3; ++c)
        CHECK(node[c] == (int)m.indices[15 + c]);
    CHECK(w[0] == 0.25 && w[1] == 0.25 && w[2] == 0.5);
    /* the V's mean edge is about 1/5 of its diagonal: 1/128 asks for the most, 8; a node budget
     * lowers it (level L holds about 3 T (L - 1) + T (L - 1)(L - 2) / 2 nodes beyond the
     * vertices), down to the vertices alone */
    const int top = pen__lattice_level(m.vertex_count, m.positions, m.triangle_count, m.indices,
                                        1.0 / 128.0, 1e9);
    CHECK(top == PEN_LATTICE_MAX_LEVEL);
    CHECK(pen__lattice_level(m.vertex_count, m.positions, m.triangle_count, m.indices,
                             1.0 / 128.0, 300.0) == 3);
    CHECK(pen__lattice_level(m.vertex_count, m.positions, m.triangle_count, m.indices,
                             1.0 / 128.0, (double)m.vertex_count) == 1);
    const int L = 4;
    CHECK(pen__lattice_build(ctx, &lat, L, m.vertex_count, m.triangle_count, m.indices) == PEN_OK);
    /* each wall: a 4 x 4 vertex grid, 33 edges; the two walls share the crease's 4 vertices */
    CHECK(lat.edge_count == 2 * 33 - 3);
    CHECK(lat.node_count == m.vertex_count + 3 * lat.edge_count + 3 * m.triangle_count);
    const int N = lat.node_count;
    float *pos = malloc(sizeof(float) * 6 * (size_t)N);
    float *nrm0 = calloc(3 * (size_t)m.vertex_count, sizeof(float));
    double *val = malloc(sizeof(double) * (size_t)N);
    pen__lattice_nodes(&lat, m.indices, m.positions, nrm0, pos, pos + 3 * (size_t)N);
    uint64_t rng = 7;
    double worst_lin = 0.0, worst_seam = 0.0;
    for (int pass = 0; pass < 2; ++pass) {
        for (int n = 0; n < N; ++n) /* pass 0: linear in the position; 1: random */
            val[n] = pass ? pen__splitmix_uniform(&rng)
                          : 0.3 * (double)pos[3 * n] - 1.7 * (double)pos[3 * n + 1] +
                                0.9 * (double)pos[3 * n + 2] + 0.1;
        for (int t = 0; t < m.triangle_count; ++t) {
            const uint32_t *c = m.indices + 3 * (size_t)t;
            for (int k = 0; k < 20; ++k) {
                double u = pen__splitmix_uniform(&rng), v = pen__splitmix_uniform(&rng);
                if (u + v > 1.0) u = 1.0 - u, v = 1.0 - v;
                pen__lattice_locate(&lat, m.indices, t, u, v, node, w);
                double f = 0.0, want = 0.1;
                for (int j = 0; j < 3; ++j)
                    f += w[j] * val[node[j]];
                const double bw[3] = {1.0 - u - v, u, v};
                for (int j = 0; j < 3; ++j) {
                    const float *p = m.positions + 3 * (size_t)c[j];
                    want += bw[j] * (0.3 * (double)p[0] - 1.7 * (double)p[1] + 0.9 * (double)p[2]);
                }
                if (!pass) worst_lin = fmax(worst_lin, fabs(f - want));
            }
            for (int e = 0; e < 3 && pass; ++e) { /* the same edge point from the neighbour */
                const uint32_t p = c[e], q = c[(e + 1) % 3];
                for (int t2 = 0; t2 < m.triangle_count; ++t2) {
                    const uint32_t *c2 = m.indices + 3 * (size_t)t2;
                    for (int e2 = 0; e2 < 3 && t2 != t; ++e2) {
                        if (c2[e2] != q || c2[(e2 + 1) % 3] != p) continue;
                        const double s = pen__splitmix_uniform(&rng); /* p + s (q - p) */
                        double b1[3] = {0, 0, 0}, b2[3] = {0, 0, 0}, f1 = 0.0, f2 = 0.0;
                        b1[e] = 1.0 - s, b1[(e + 1) % 3] = s;
                        b2[e2] = s, b2[(e2 + 1) % 3] = 1.0 - s;
                        pen__lattice_locate(&lat, m.indices, t, b1[1], b1[2], node, w);
                        for (int j = 0; j < 3; ++j)
                            f1 += w[j] * val[node[j]];
                        pen__lattice_locate(&lat, m.indices, t2, b2[1], b2[2], node, w);
                        for (int j = 0; j < 3; ++j)
                            f2 += w[j] * val[node[j]];
                        worst_seam = fmax(worst_seam, fabs(f1 - f2));
                    }
                }
            }
        }
    }
    printf("  lattice L = %d: %d nodes; linear field off by %.2e, seams by %.2e\n", L, N,
           worst_lin, worst_seam);
    CHECK(worst_lin < 1e-5);
    CHECK(worst_seam < 1e-9);
    free(pos), free(nrm0), free(val);
    pen__lattice_free(&lat);
    pen_mesh_free(&m);
    pen_context_destroy(ctx);
}

/* A coarse V (2 x 2 quads a wall, 8 triangles): its few vertices alone miss the crease's
 * occlusion between them; the refined nodes bring it within the fine V's accuracy. */
static void test_coarse_against_reference(void) {
    pen_scene sc = v_scene_k(64, 2);
    const double et = default_error(&sc);
    printf("  coarse V under SH light: rel. error against the reference %.4f\n", et);
    CHECK(et < (check_quick_() ? 0.05 : 0.015)); /* the vertices alone: 0.0187 at 512 spp */
    pen_scene_free(&sc);
}

/* The kernel's loss sum_ch q_ch rgb_ch and its gradient, in double. */
typedef struct kcase {
    pen__shade_params p;
    double sh[PEN_SH_MAX_COEFFS][3], spheres[12], kappa[3], x[3], n[3], B[PEN_SH_MAX_COEFFS],
        rho[3], q[3];
    int count;
} kcase;

static double kloss(const kcase *c) {
    double rgb[3];
    pen__shade_self_fwd_d(&c->p, (const double(*)[3])c->sh, c->count, c->spheres, c->kappa, c->x,
                          c->n, c->B, c->rho, rgb, NULL);
    return c->q[0] * rgb[0] + c->q[1] * rgb[1] + c->q[2] * rgb[2];
}

static void fd_check(kcase *c, double *v, int m, const double *an, const char *what) {
    for (int j = 0; j < m; ++j) {
        const double keep = v[j], h = 1e-6;
        v[j] = keep + h;
        const double lp = kloss(c);
        v[j] = keep - h;
        const double lm = kloss(c);
        v[j] = keep;
        const double fd = (lp - lm) / (2.0 * h);
        CHECK_MSG(fabs(fd - an[j]) <= 1e-6 * fmax(1.0, fabs(fd)), "%s[%d]: analytic %.9g, FD %.9g",
                  what, j, an[j], fd);
    }
}

static void test_kernel_gradients(void) {
    unsigned long long seed = 19;
    for (int trial = 0; trial < 6; ++trial) {
        kcase c;
        memset(&c, 0, sizeof c);
        const pen_sh_exp_model model = pen_sh_exp_model_default(PEN_SH_EXP_CALIBRATED, 4);
        pen__shade_params_init(&c.p, 4, &model, 0.0, 1);
        for (int k = 0; k < 16; ++k)
            for (int ch = 0; ch < 3; ++ch)
                c.sh[k][ch] = rs_uniform(&seed, -0.5, 1.0);
        rs_unit_vector(&seed, c.n);
        c.n[1] = fabs(c.n[1]);
        for (int a = 0; a < 3; ++a) {
            c.x[a] = rs_uniform(&seed, -0.2, 0.2);
            c.rho[a] = rs_uniform(&seed, 0.2, 0.9);
            c.q[a] = rs_uniform(&seed, 0.5, 1.5);
        }
        for (int k = 0; k < 16; ++k)
            c.B[k] = rs_uniform(&seed, -0.1, 0.1);
        /* Three spheres above the receiver; the second is the object's own (kappa 0). */
        for (int i = 0; i < 3; ++i) {
            double d[3];
            rs_unit_vector(&seed, d);
            const double dist = rs_uniform(&seed, 0.6, 1.2);
            for (int a = 0; a < 3; ++a)
                c.spheres[4 * i + a] = c.x[a] + dist * (0.5 * d[a] + 0.8 * c.n[a]);
            c.spheres[4 * i + 3] = rs_uniform(&seed, 0.15, 0.35);
            c.kappa[i] = i == 1 ? 0.0 : rs_uniform(&seed, 0.5, 1.0);
        }
        c.count = trial % 3 == 2 ? 0 : 3; /* no other sphere: T = H_n - B, no exponential */
        double d_sh[PEN_SH_MAX_COEFFS][3] = {{0}}, d_sph[12] = {0}, d_x[3] = {0}, d_n[3] = {0},
               d_rho[3] = {0};
        pen__shade_self_bwd_d(&c.p, (const double(*)[3])c.sh, c.count, c.spheres, c.kappa, c.x,
                              c.n, c.B, c.rho, c.q, NULL, d_sh, d_sph, d_x, d_n, d_rho);
        fd_check(&c, &c.sh[0][0], 48, &d_sh[0][0], "d_sh");
        fd_check(&c, c.rho, 3, d_rho, "d_rho");
        fd_check(&c, c.x, 3, d_x, "d_x");
        fd_check(&c, c.n, 3, d_n, "d_n");
        fd_check(&c, c.spheres, 12, d_sph, "d_spheres");
        CHECK(d_sph[4] == 0.0 && d_sph[5] == 0.0 && d_sph[6] == 0.0 && d_sph[7] == 0.0);
        /* The fast kernel's route (F summed elsewhere, handed in): with F the kernel's own, the
         * same colour and the same lighting and albedo gradients as the checked ones above. */
        double fv[2 * PEN_SH_MAX_COEFFS] = {0}, rgb_f[3], rgb_g[3];
        pen__shade_self_fwd_d(&c.p, (const double(*)[3])c.sh, c.count, c.spheres, c.kappa, c.x,
                              c.n, c.B, c.rho, rgb_f, fv);
        pen__shade_self_given_fwd_d(&c.p, (const double(*)[3])c.sh, c.count, c.spheres, c.kappa,
                                    c.x, c.n, c.B, fv, c.rho, rgb_g, NULL);
        double g_sh[PEN_SH_MAX_COEFFS][3] = {{0}}, g_sph[12] = {0}, g_x[3] = {0}, g_n[3] = {0},
               g_rho[3] = {0};
        pen__shade_self_given_bwd_d(&c.p, (const double(*)[3])c.sh, c.count, c.spheres,
                                    c.kappa, c.x, c.n, c.B, fv, c.rho, c.q, g_sh, g_sph, g_x,
                                    g_n, g_rho);
        for (int ch = 0; ch < 3; ++ch) {
            CHECK(fabs(rgb_g[ch] - rgb_f[ch]) <= 1e-12 * fmax(1.0, fabs(rgb_f[ch])));
            CHECK(fabs(g_rho[ch] - d_rho[ch]) <= 1e-12 * fmax(1.0, fabs(d_rho[ch])));
            for (int k = 0; k < 16; ++k)
                CHECK(fabs(g_sh[k][ch] - d_sh[k][ch]) <= 1e-12 * fmax(1.0, fabs(d_sh[k][ch])));
        }
        /* With the blocked part zero and no other sphere: the clamped cosine's shading. */
        if (c.count == 0) {
            double rgb[3], ref[3], zero[PEN_SH_MAX_COEFFS] = {0};
            pen__shade_self_fwd_d(&c.p, (const double(*)[3])c.sh, 0, c.spheres, c.kappa, c.x,
                                  c.n, zero, c.rho, rgb, NULL);
            pen__shade_params q = c.p;
            q.shadows = 0;
            pen__shade_fwd_d(&q, (const double(*)[3])c.sh, 0, c.spheres, c.kappa, c.x, c.n, c.rho,
                             ref, NULL);
            for (int ch = 0; ch < 3; ++ch)
                CHECK(rgb[ch] == ref[ch]);
        }
    }
}

/* loss = sum q . image with the transfer on: its lighting and albedo gradients against central
 * differences of the float render (the image is linear in both, so the differences are exact up
 * to rounding), with a second object whose spheres shadow the V, both kernels. */
static void test_frame_lighting_albedo(void) {
    pen_scene sc = v_scene(48);
    const float ball[4] = {0.0f, 0.0f, 0.0f, 0.2f};
    pen_object *o2 = rs_add_object(&sc, rs_octasphere(2, 0.2f, 0), 1, ball);
    o2->pose.translation[0] = 0.25f, o2->pose.translation[1] = 1.15f;
    sc.lighting.light_count = 1;
    sc.lighting.lights_mode = PEN_LIGHTS_GIVEN;
    const float d[3] = {0.5f, 0.8f, 0.3f};
    memcpy(sc.lighting.lights[0].direction, d, sizeof d);
    sc.lighting.lights[0].angular_radius_deg = 5.0f;
    sc.lighting.lights[0].irradiance[0] = 1.5f, sc.lighting.lights[0].irradiance[1] = 1.2f;
    sc.lighting.lights[0].irradiance[2] = 1.0f;
    for (int kernel = 0; kernel < 2; ++kernel) {
        pen_context *ctx = pen_context_create();
        pen_render_options opt = pen_render_options_default();
        opt.kernel = kernel ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
        pen_render_state *st = NULL;
        CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
        pen_image img = {0, 0, 0, NULL}, dimg = {0, 0, 0, NULL};
        CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
        CHECK(st->obj[0].self_on && st->obj[0].self_others); /* the ball's sphere shadows the V */
        CHECK(pen_image_create(ctx, img.width, img.height, 3, &dimg) == PEN_OK);
        unsigned long long seed = 5;
        for (size_t i = 0; i < 3 * (size_t)img.width * img.height; ++i)
            dimg.data[i] = (float)rs_uniform(&seed, 0.0, 1.0);
        pen_render_grad g;
        CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
        pen_render_grad_zero(&g);
        CHECK(pen_render_bwd(ctx, &sc, &opt, st, &dimg, PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO |
                                                             PEN_GRAD_LIGHT_IRRADIANCE, &g) == PEN_OK);
        float *params[6] = {&sc.lighting.sh[0][0], &sc.lighting.sh[2][1], &sc.lighting.sh[6][2],
                            &sc.objects[0].albedo[0], &sc.objects[0].albedo[2],
                            &sc.lighting.lights[0].irradiance[1]};
        const double an[6] = {g.sh[0][0], g.sh[2][1], g.sh[6][2], g.objects[0].albedo[0],
                              g.objects[0].albedo[2], g.lights[0].irradiance[1]};
        for (int j = 0; j < 6; ++j) {
            const double fd = rs_central_dot(ctx, &sc, &opt, params[j], 0.05f, &dimg);
            CHECK_MSG(fabs(fd - an[j]) <= 2e-3 * fmax(1.0, fabs(fd)),
                      "kernel %d, parameter %d: analytic %.6g, FD %.6g", kernel, j, an[j], fd);
        }
        pen_image_free(&img), pen_image_free(&dimg);
        pen_render_grad_free(&g);
        pen_render_state_free(st);
        pen_context_destroy(ctx);
    }
    pen_scene_free(&sc);
}

static void test_cache(void) {
    pen_scene sc = v_scene(32);
    pen_context *ctx = pen_context_create();
    pen_render_options opt = pen_render_options_default();
    pen_image img;
    pen_render_state *st = rs_render_kept(ctx, &sc, &opt, &img);
    pen__object_buf *b = &st->obj[0];
    CHECK(b->self_on && b->self_valid);
    const uint64_t key = b->self_key;
    /* The same pose, other lighting and albedo: the cache is kept (a marker survives). */
    const float marker = 12345.0f, kept = b->self_B.data[0];
    b->self_B.data[0] = marker;
    sc.lighting.sh[1][0] += 0.3f;
    sc.objects[0].albedo[1] = 0.2f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(b->self_key == key && b->self_B.data[0] == marker);
    /* The pose moves: rebuilt. */
    sc.objects[0].pose.rotation_axis_angle_deg[1] = 20.0f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(b->self_key != key && b->self_B.data[0] != marker);
    /* Back to the first pose: the first transfer again. */
    sc.objects[0].pose.rotation_axis_angle_deg[1] = 0.0f;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(b->self_key == key && b->self_B.data[0] == kept);
    /* The band count is part of the key. */
    sc.sh_bands = 3;
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(b->self_key != key);
    pen_image_free(&img);
    pen_render_state_free(st);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

static void test_threads_and_kernels(void) {
    pen_scene sc = v_scene(48);
    pen_mesh *m = &sc.objects[0].mesh;
    float *nrm = malloc(sizeof(float) * 3 * (size_t)m->vertex_count);
    float *B[2] = {malloc(sizeof(float) * 16 * (size_t)m->vertex_count),
                   malloc(sizeof(float) * 16 * (size_t)m->vertex_count)};
    for (int r = 0; r < 2; ++r) {
        pen_context *ctx = pen_context_create();
        pen_context_set_threads(ctx, r ? 3 : 1);
        CHECK(pen_vertex_normals_fwd(ctx, m->vertex_count, m->positions, m->triangle_count,
                                     m->indices, nrm) == PEN_OK);
        pen__transfer_request rq = request_of(m, nrm, 4);
        CHECK(pen__transfer(ctx, &rq, B[r], NULL) == PEN_OK);
        pen_context_destroy(ctx);
    }
    CHECK(!memcmp(B[0], B[1], sizeof(float) * 16 * (size_t)m->vertex_count));
    double blocked = 0.0;
    for (int i = 0; i < m->vertex_count; ++i)
        blocked = fmax(blocked, (double)B[0][16 * i]);
    CHECK(blocked > 0.1); /* the V's crease sees its other wall */
    /* Alone (no other sphere: T = H_n - B, no exponential), then under a ball whose sphere
     * shadows it (the fast kernel sums F over the other spheres, with the V's kappa_self). */
    for (int others = 0; others < 2; ++others) {
        if (others) {
            const float ball[4] = {0.0f, 0.0f, 0.0f, 0.2f};
            pen_object *o2 = rs_add_object(&sc, rs_octasphere(2, 0.2f, 0), 1, ball);
            o2->pose.translation[0] = 0.25f, o2->pose.translation[1] = 1.15f;
        }
        pen_image a = {0, 0, 0, NULL}, b = {0, 0, 0, NULL}, c = {0, 0, 0, NULL};
        pen_render_options opt = pen_render_options_default();
        CHECK(rs_render(&sc, &opt, 1, &a) == PEN_OK);
        CHECK(rs_render(&sc, &opt, 3, &b) == PEN_OK);
        opt.kernel = PEN_RENDER_KERNEL_SCALAR;
        CHECK(rs_render(&sc, &opt, 2, &c) == PEN_OK);
        const size_t n = 3 * (size_t)a.width * a.height;
        CHECK(!memcmp(a.data, b.data, sizeof(float) * n));
        double worst = 0.0;
        for (size_t i = 0; i < n; ++i)
            worst = fmax(worst, fabs((double)a.data[i] - (double)c.data[i]));
        /* alone the same functions shade both (bit for bit); with the ball, F's sum in another
         * order (float rounding) */
        CHECK_MSG(others ? worst < 1e-5 : worst == 0.0, "others %d: fast and scalar kernels "
                  "differ by %g", others, worst);
        pen_image_free(&a), pen_image_free(&b), pen_image_free(&c);
    }
    free(B[0]), free(B[1]), free(nrm);
    pen_scene_free(&sc);
}

static void test_spheres_mode(void) {
    pen_scene sc = v_scene(32);
    pen_render_options opt = pen_render_options_default();
    pen_image t = {0, 0, 0, NULL}, s1 = {0, 0, 0, NULL}, s2 = {0, 0, 0, NULL};
    CHECK(rs_render(&sc, &opt, 2, &t) == PEN_OK);
    sc.shadow.self = PEN_SELF_SPHERES;
    CHECK(rs_render(&sc, &opt, 2, &s1) == PEN_OK);
    sc.shadow.self = PEN_SELF_TRANSFER; /* the rule's switch renders as the JSON key */
    CHECK(pen_render_grad_model(&sc, PEN_GRAD_SPHERES) == PEN_GRAD_SPHERES);
    CHECK(rs_render(&sc, &opt, 2, &s2) == PEN_OK);
    const size_t n = 3 * (size_t)t.width * t.height;
    CHECK(!memcmp(s1.data, s2.data, sizeof(float) * n));
    CHECK(memcmp(t.data, s1.data, sizeof(float) * n) != 0);
    pen_image_free(&t), pen_image_free(&s1), pen_image_free(&s2);
    pen_scene_free(&sc);
}

/* States that share (pen_render_state_share) trace each object's transfer and the ground's grid
 * once per pose for every camera, even rendering at once on two threads, and render bitwise as
 * states that do not share; a new pose traces again. */
static void test_shared_states(void) {
    unsigned long long seed = 21;
    pen_scene sc = rs_ball_scene(40, 1, &seed);
    CHECK(sc.shadow.self == PEN_SELF_TRANSFER && sc.ground.enabled);
    pen_camera cams[3] = {sc.camera, sc.camera, sc.camera};
    cams[1].eye[0] += 0.7f, cams[2].eye[2] -= 0.5f;
    pen_context *ctx = pen_context_create();
    pen_render_state *shared[3], *alone[3];
    for (int v = 0; v < 3; ++v) {
        CHECK(pen_render_state_create(ctx, &shared[v]) == PEN_OK);
        CHECK(pen_render_state_create(ctx, &alone[v]) == PEN_OK);
    }
    CHECK(pen_render_state_share(ctx, shared[1], shared[0]) == PEN_OK);
    CHECK(pen_render_state_share(ctx, shared[2], shared[1]) == PEN_OK);
    CHECK(shared[0]->pool && shared[0]->pool == shared[2]->pool);
    for (int pose = 0; pose < 2; ++pose) {
        sc.objects[0].pose.translation[0] = 0.1f * (float)pose;
        pen_image a[3], b[3];
        pen_status sa[3], sb[3];
        memset(a, 0, sizeof a), memset(b, 0, sizeof b);
#pragma omp parallel for num_threads(3) schedule(static, 1)
        for (int v = 0; v < 3; ++v) { /* the views at once, as a task's workers render them */
            pen_context *c = pen_context_create();
            pen_scene vs = sc;
            vs.camera = cams[v];
            sa[v] = pen_render_fwd(c, &vs, NULL, shared[v], &a[v]);
            sb[v] = pen_render_fwd(c, &vs, NULL, alone[v], &b[v]);
            pen_context_destroy(c);
        }
        for (int v = 0; v < 3; ++v) {
            CHECK(sa[v] == PEN_OK && sb[v] == PEN_OK);
            CHECK(a[v].data && b[v].data &&
                  !memcmp(a[v].data, b[v].data, sizeof(float) * 3 * 40 * 40));
            pen_image_free(&a[v]), pen_image_free(&b[v]);
        }
        /* one self transfer and one ground grid per pose, whatever the cameras */
        CHECK_MSG(pen__pool_traces(shared[0]->pool) == 2 * (pose + 1), "pose %d: %ld traces", pose,
                  pen__pool_traces(shared[0]->pool));
        CHECK(shared[1]->grid.on && shared[2]->obj[0].self_valid);
    }
    for (int v = 0; v < 3; ++v) {
        pen_render_state_free(shared[v]);
        pen_render_state_free(alone[v]);
    }
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

/* The states of a pool read one trace by reference, not each a copy: the same arrays and the
 * same lattice after rendering the same pose from two cameras; and a state keeps reading its
 * trace, rendering bitwise as before, after the pool evicted it (more than PEN_POOL_ENTRIES
 * other keys put), the blob living on with the state's reference (ASan sees a use after free). */
static void test_shared_by_reference(void) {
    unsigned long long seed = 23;
    pen_scene sc = rs_ball_scene(40, 1, &seed);
    pen_camera cams[2] = {sc.camera, sc.camera};
    cams[1].eye[0] += 0.7f;
    pen_context *ctx = pen_context_create();
    pen_render_state *st[2];
    for (int v = 0; v < 2; ++v)
        CHECK(pen_render_state_create(ctx, &st[v]) == PEN_OK);
    CHECK(pen_render_state_share(ctx, st[1], st[0]) == PEN_OK);
    pen_image img[2], again = {0};
    memset(img, 0, sizeof img);
    for (int v = 0; v < 2; ++v) {
        pen_scene vs = sc;
        vs.camera = cams[v];
        CHECK(pen_render_fwd(ctx, &vs, NULL, st[v], &img[v]) == PEN_OK);
    }
    const pen__object_buf *b0 = &st[0]->obj[0], *b1 = &st[1]->obj[0];
    CHECK(b0->self_valid && b1->self_valid && b0->self_blob);
    CHECK(b0->self_blob == b1->self_blob);
    CHECK(b0->self_B.data == b1->self_B.data && b0->self_frac.data == b1->self_frac.data);
    CHECK(b0->self_lat.tri_edges == b1->self_lat.tri_edges);
    CHECK(pen__pool_traces(st[0]->pool) == 2); /* one self transfer, one ground grid */
    CHECK(st[0]->grid.valid && st[0]->grid.blob && st[0]->grid.blob == st[1]->grid.blob);
    CHECK(st[0]->grid.B == st[1]->grid.B && st[0]->grid.blob->refs == 3); /* pool, 2 states */
    CHECK(st[0]->grid.blob->bvh); /* the occluders both cameras' pixels were traced against */
    /* Evict: the pool drops its reference to the trace, the states keep theirs. */
    for (uint64_t k = 1; k <= 40; ++k) {
        pen__transfer_blob *dummy = pen__blob_create(ctx, 1, 1);
        CHECK(dummy);
        dummy->B[0] = 1.0f, dummy->frac[0] = 2.0f;
        pen__pool_insert(st[0]->pool, PEN__POOL_SELF, k * 0x9E3779B97F4A7C15ull, dummy);
        pen__blob_release(dummy);
    }
    CHECK(!pen__pool_find(st[0]->pool, PEN__POOL_SELF, b0->self_key));
    CHECK(b0->self_blob->refs == 2); /* the two states */
    CHECK(st[0]->grid.blob->refs == 2);
    pen_scene vs = sc;
    vs.camera = cams[1];
    CHECK(pen_render_fwd(ctx, &vs, NULL, st[1], &again) == PEN_OK);
    CHECK(again.data && !memcmp(again.data, img[1].data, sizeof(float) * 3 * 40 * 40));
    pen_image_free(&again);
    /* The first state frees its reference; the second still renders from the blob. */
    pen_render_state_free(st[0]);
    CHECK(b1->self_blob->refs == 1 && st[1]->grid.blob->refs == 1);
    CHECK(pen_render_fwd(ctx, &vs, NULL, st[1], &again) == PEN_OK);
    CHECK(again.data && !memcmp(again.data, img[1].data, sizeof(float) * 3 * 40 * 40));
    pen_image_free(&again);
    pen_render_state_free(st[1]);
    for (int v = 0; v < 2; ++v)
        pen_image_free(&img[v]);
    pen_context_destroy(ctx);
    pen_scene_free(&sc);
}

int main(void) {
    static const check_test_ tests[] = {
        {"test_shared_states", test_shared_states},
        {"test_shared_by_reference", test_shared_by_reference},
        {"test_convex_blocks_nothing", test_convex_blocks_nothing},
        {"test_convexity", test_convexity},
        {"test_convex_vertices", test_convex_vertices},
        {"test_concave_against_reference", test_concave_against_reference},
        {"test_buried_nodes", test_buried_nodes},
        {"test_lattice", test_lattice},
        {"test_coarse_against_reference", test_coarse_against_reference},
        {"test_kernel_gradients", test_kernel_gradients},
        {"test_frame_lighting_albedo", test_frame_lighting_albedo},
        {"test_cache", test_cache},
        {"test_threads_and_kernels", test_threads_and_kernels},
        {"test_spheres_mode", test_spheres_mode},
    };
    return check_run_(tests, (int)(sizeof tests / sizeof tests[0]));
}
