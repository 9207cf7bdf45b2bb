/* Shared fixtures of the renderer tests: small scenes built in memory (a subdivided octahedron
 * projected onto a sphere, a ground plane, SH lighting with a strong overhead lobe), projected
 * losses and image checks. Header-only (static), included by tests/test_render*.c. */
#ifndef PEN_TEST_RENDER_SCENES_H
#define PEN_TEST_RENDER_SCENES_H

#include "check.h"
#include "penumbra/penumbra.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Real SH up to l = 2 written out (Condon-Shortley phase), independent of src/sh: for closed-form
 * irradiance references. */
static inline void rs_y_band2(const double n[3], double y[9]) {
    const double x = n[0], yy = n[1], z = n[2];
    y[0] = 0.28209479177387814;
    y[1] = -0.48860251190291992 * yy;
    y[2] = 0.48860251190291992 * z;
    y[3] = -0.48860251190291992 * x;
    y[4] = 1.0925484305920792 * x * yy;
    y[5] = -1.0925484305920792 * yy * z;
    y[6] = 0.31539156525252005 * (3 * z * z - 1);
    y[7] = -1.0925484305920792 * x * z;
    y[8] = 0.54627421529603959 * (x * x - yy * yy);
}

/* Random test inputs from a seed: uniform in [lo, hi), and a uniform unit vector. */
static inline double rs_uniform(unsigned long long *seed, double lo, double hi) {
    return lo + (hi - lo) * check_rand_(seed);
}
static inline void rs_unit_vector(unsigned long long *seed, double d[3]) {
    double z = rs_uniform(seed, -1, 1), phi = rs_uniform(seed, 0, 2 * M_PI), s = sqrt(1 - z * z);
    d[0] = s * cos(phi), d[1] = s * sin(phi), d[2] = z;
}

/* ---- Meshes ---------------------------------------------------------------------------------- */

typedef struct rs_builder {
    int nv, nt, cap_v, cap_t;
    float *pos;
    uint32_t *idx;
} rs_builder;

static inline int rs_vertex(rs_builder *b, const float p[3]) {
    for (int i = 0; i < b->nv; ++i)
        if (fabsf(b->pos[3 * i] - p[0]) < 1e-6f && fabsf(b->pos[3 * i + 1] - p[1]) < 1e-6f &&
            fabsf(b->pos[3 * i + 2] - p[2]) < 1e-6f)
            return i;
    if (b->nv == b->cap_v) {
        b->cap_v = b->cap_v ? 2 * b->cap_v : 64;
        b->pos = realloc(b->pos, sizeof(float) * 3 * (size_t)b->cap_v);
    }
    memcpy(b->pos + 3 * b->nv, p, sizeof(float) * 3);
    return b->nv++;
}

static inline void rs_triangle(rs_builder *b, int a, int c, int d) {
    if (b->nt == b->cap_t) {
        b->cap_t = b->cap_t ? 2 * b->cap_t : 64;
        b->idx = realloc(b->idx, sizeof(uint32_t) * 3 * (size_t)b->cap_t);
    }
    b->idx[3 * b->nt] = (uint32_t)a, b->idx[3 * b->nt + 1] = (uint32_t)c;
    b->idx[3 * b->nt + 2] = (uint32_t)d;
    b->nt++;
}

/* The builder's vertices and triangles as a mesh (which takes them). */
static inline pen_mesh rs_builder_mesh(const rs_builder *b) {
    pen_mesh m;
    memset(&m, 0, sizeof m);
    m.vertex_count = b->nv, m.triangle_count = b->nt;
    m.positions = b->pos, m.indices = b->idx;
    return m;
}

static inline void rs_unit(float p[3]) {
    float l = sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    p[0] /= l, p[1] /= l, p[2] /= l;
}

/* Recursively subdivided octant triangle (corners on the unit sphere, CCW from outside). */
static inline void rs_subdivide(rs_builder *b, const float *a, const float *c, const float *d,
                                int level) {
    if (level == 0) {
        rs_triangle(b, rs_vertex(b, a), rs_vertex(b, c), rs_vertex(b, d));
        return;
    }
    float ac[3], cd[3], da[3];
    for (int k = 0; k < 3; ++k)
        ac[k] = 0.5f * (a[k] + c[k]), cd[k] = 0.5f * (c[k] + d[k]), da[k] = 0.5f * (d[k] + a[k]);
    rs_unit(ac), rs_unit(cd), rs_unit(da);
    rs_subdivide(b, a, ac, da, level - 1);
    rs_subdivide(b, ac, c, cd, level - 1);
    rs_subdivide(b, da, cd, d, level - 1);
    rs_subdivide(b, ac, cd, da, level - 1);
}

/* A sphere of the given radius around the origin: 8 * 4^level triangles. With `uv`, planar
 * texture coordinates (x, z) / (2 radius) + 1/2 shared with the position indices. */
static inline pen_mesh rs_octasphere(int level, float radius, int uv) {
    static const float P[6][3] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                  {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
    /* Faces (x, y, z) sign octants, ordered counter-clockwise seen from outside. */
    static const int F[8][3] = {{0, 2, 4}, {4, 2, 1}, {1, 2, 5}, {5, 2, 0},
                                {0, 4, 3}, {4, 1, 3}, {1, 5, 3}, {5, 0, 3}};
    rs_builder b = {0, 0, 0, 0, NULL, NULL};
    for (int f = 0; f < 8; ++f)
        rs_subdivide(&b, P[F[f][0]], P[F[f][1]], P[F[f][2]], level);
    pen_mesh m;
    memset(&m, 0, sizeof m);
    m.vertex_count = b.nv;
    m.triangle_count = b.nt;
    m.positions = b.pos;
    m.indices = b.idx;
    for (int i = 0; i < 3 * b.nv; ++i)
        m.positions[i] *= radius;
    if (uv) {
        m.uv_count = b.nv;
        m.uvs = malloc(sizeof(float) * 2 * (size_t)b.nv);
        m.uv_indices = malloc(sizeof(uint32_t) * 3 * (size_t)b.nt);
        memcpy(m.uv_indices, m.indices, sizeof(uint32_t) * 3 * (size_t)b.nt);
        for (int i = 0; i < b.nv; ++i) {
            m.uvs[2 * i] = m.positions[3 * i] / (2 * radius) + 0.5f;
            m.uvs[2 * i + 1] = m.positions[3 * i + 2] / (2 * radius) + 0.5f;
        }
    }
    return m;
}

/* A small triangle far out of view (x, z = 50): for objects that only cast shadows through their
 * spheres. */
static inline pen_mesh rs_far_triangle(void) {
    pen_mesh tri;
    memset(&tri, 0, sizeof tri);
    tri.vertex_count = 3, tri.triangle_count = 1;
    tri.positions = calloc(9, sizeof(float));
    tri.indices = malloc(3 * sizeof(uint32_t));
    const float P[9] = {50, 0, 50, 51, 0, 50, 50, 1, 50};
    memcpy(tri.positions, P, sizeof P);
    tri.indices[0] = 0, tri.indices[1] = 1, tri.indices[2] = 2;
    return tri;
}

/* ---- Scenes ---------------------------------------------------------------------------------- */

/* Lighting: a bright overhead lobe with a side component and some colour, 4 bands. */
static inline void rs_lighting(pen_scene *sc) {
    memset(sc->lighting.sh, 0, sizeof sc->lighting.sh);
    const float base[16] = {1.6f,  -1.1f, 0.25f, -0.35f, 0.1f,  -0.3f, 0.45f, 0.2f,
                            -0.1f, 0.05f, -0.1f, 0.15f,  -0.1f, 0.05f, 0.08f, -0.05f};
    const float tint[3] = {1.0f, 0.9f, 0.8f};
    for (int k = 0; k < 16; ++k)
        for (int ch = 0; ch < 3; ++ch)
            sc->lighting.sh[k][ch] = base[k] * (k ? 1.0f : tint[ch]);
    sc->lighting.scale = 1.0f;
}

/* Camera (w x h), lighting, ground at y = 0; no objects. */
static inline pen_scene rs_scene(int w, int h) {
    pen_scene sc;
    memset(&sc, 0, sizeof sc);
    sc.camera.width = w, sc.camera.height = h, sc.camera.fov_y_deg = 40.0f;
    const float eye[3] = {0.3f, 1.5f, 2.4f}, target[3] = {0.0f, 0.35f, 0.0f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    sc.camera.up[1] = 1.0f;
    sc.sh_bands = 4;
    rs_lighting(&sc);
    sc.shadow.exp = PEN_SH_EXP_CALIBRATED;
    sc.shadow.epsilon = (float)pen_sh_exp_model_default(PEN_SH_EXP_CALIBRATED, 4).epsilon;
    sc.ground.enabled = 1;
    sc.ground.height = 0.0f;
    sc.ground.half_size = 3.0f;
    sc.ground.albedo[0] = 0.7f, sc.ground.albedo[1] = 0.6f, sc.ground.albedo[2] = 0.5f;
    sc.background[0] = 0.2f, sc.background[1] = 0.3f, sc.background[2] = 0.4f;
    return sc;
}

/* Adds an object (takes the mesh) with `count` spheres (x, y, z, r, object space). */
static inline pen_object *rs_add_object(pen_scene *sc, pen_mesh mesh, int count,
                                        const float *spheres) {
    sc->objects = realloc(sc->objects, sizeof(pen_object) * (size_t)(sc->object_count + 1));
    pen_object *ob = &sc->objects[sc->object_count++];
    memset(ob, 0, sizeof *ob);
    ob->mesh = mesh;
    ob->albedo[0] = 0.8f, ob->albedo[1] = 0.5f, ob->albedo[2] = 0.3f;
    ob->pose.scale = 1.0f;
    if (count) {
        pen_status s = pen_spheres_create(NULL, count, &ob->spheres);
        CHECK(s == PEN_OK);
        memcpy(ob->spheres.data, spheres, sizeof(float) * 4 * (size_t)count);
        /* The overlap weights a scene loader would give these spheres, fixed from here on (the
         * renderer would otherwise recompute them from the current spheres at every forward,
         * which finite differences of the sphere parameters would see). */
        CHECK(pen_spheres_ensure_weights(NULL, &ob->spheres) == PEN_OK);
    }
    return ob;
}

/* A small RGB texture with random texels in [0.2, 0.9]. */
static inline pen_image rs_texture(int w, int h, unsigned long long *seed) {
    pen_image t;
    pen_status s = pen_image_create(NULL, w, h, 3, &t);
    CHECK(s == PEN_OK);
    for (int i = 0; i < 3 * w * h; ++i)
        t.data[i] = (float)(0.2 + 0.7 * check_rand_(seed));
    return t;
}

/* The standard test scene: an octasphere of radius 0.45 stretched to an ellipsoid (x 1.25,
 * y 0.8, so that rotations change its outline) hovering over the ground (pose translation
 * y = 0.55, a small rotation), two proxy spheres inside it, optionally textured. */
static inline pen_scene rs_ball_scene(int size, int textured, unsigned long long *seed) {
    pen_scene sc = rs_scene(size, size);
    const float spheres[8] = {-0.15f, 0.0f, 0.02f, 0.32f, 0.17f, 0.02f, -0.03f, 0.3f};
    pen_mesh mesh = rs_octasphere(2, 0.45f, textured);
    for (int i = 0; i < mesh.vertex_count; ++i)
        mesh.positions[3 * i] *= 1.25f, mesh.positions[3 * i + 1] *= 0.8f;
    pen_object *ob = rs_add_object(&sc, mesh, 2, spheres);
    ob->pose.translation[1] = 0.55f;
    ob->pose.rotation_axis_angle_deg[0] = 10.0f;
    ob->pose.rotation_axis_angle_deg[1] = 25.0f;
    if (textured) ob->texture = rs_texture(6, 5, seed);
    return sc;
}

/* ---- Rendering helpers ----------------------------------------------------------------------- */

static inline int rs_all_finite(const float *v, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Relative RMS error of image a against b (3 channels, the same size). */
static inline double rs_rel_error(const pen_image *a, const pen_image *b) {
    double e = 0.0, r = 0.0;
    for (size_t i = 0; i < 3 * (size_t)a->width * (size_t)a->height; ++i) {
        const double d = (double)a->data[i] - (double)b->data[i];
        e += d * d;
        r += (double)b->data[i] * (double)b->data[i];
    }
    return sqrt(e / r);
}

/* Renders with a fresh context; returns the status and fills *img (allocated). */
static inline pen_status rs_render(const pen_scene *sc, const pen_render_options *opt, int threads,
                                   pen_image *img) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    memset(img, 0, sizeof *img);
    pen_status s = pen_render_fwd(ctx, sc, opt, NULL, img);
    if (s) fprintf(stderr, "render: %s\n", pen_context_error(ctx));
    pen_context_destroy(ctx);
    return s;
}

/* The central difference (L(p + h) - L(p - h)) / 2h of L = <d_img, render>, summed in double,
 * for the float parameter *param of sc (renders without a state; *param restored): the number a
 * backward's gradient of that parameter against d_img is checked with. */
static inline double rs_central_dot(pen_context *ctx, const pen_scene *sc,
                                    const pen_render_options *opt, float *param, float h,
                                    const pen_image *d_img) {
    const float keep = *param;
    pen_image tmp = {0, 0, 0, NULL};
    double l[2];
    for (int sgn = 0; sgn < 2; ++sgn) {
        *param = keep + (sgn ? -h : h);
        CHECK(pen_render_fwd(ctx, sc, opt, NULL, &tmp) == PEN_OK);
        l[sgn] = 0.0;
        for (size_t i = 0; i < 3 * (size_t)d_img->width * (size_t)d_img->height; ++i)
            l[sgn] += (double)d_img->data[i] * (double)tmp.data[i];
    }
    *param = keep;
    pen_image_free(&tmp);
    return (l[0] - l[1]) / (2.0 * (double)h);
}

/* A forward into a new render state, kept for the caller to look into (its caches) and free. */
static inline pen_render_state *rs_render_kept(pen_context *ctx, const pen_scene *sc,
                                               const pen_render_options *opt, pen_image *img) {
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    memset(img, 0, sizeof *img);
    CHECK(pen_render_fwd(ctx, sc, opt, st, img) == PEN_OK);
    return st;
}

#endif
