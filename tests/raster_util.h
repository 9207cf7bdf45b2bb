/* Shared fixtures of the rasterizer tests: cameras, views, meshes built from screen positions,
 * and buffer checks. Header-only (static), included by tests/test_raster*.c. */
#ifndef PEN_TEST_RASTER_UTIL_H
#define PEN_TEST_RASTER_UTIL_H

#include "check.h"
#include "penumbra/io.h"
#include "penumbra/raster.h"
#include "raster/raster_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static inline pen_camera ru_camera(int w, int h, float fov, float ex, float ey, float ez, float tx,
                                   float ty, float tz) {
    pen_camera cam;
    memset(&cam, 0, sizeof cam);
    cam.width = w, cam.height = h, cam.fov_y_deg = fov;
    cam.eye[0] = ex, cam.eye[1] = ey, cam.eye[2] = ez;
    cam.target[0] = tx, cam.target[1] = ty, cam.target[2] = tz;
    cam.up[1] = 1.0f;
    return cam;
}

static inline pen_view ru_view(const pen_camera *cam) {
    pen_view view;
    pen_context *ctx = pen_context_create();
    pen_status st = pen_view_init(ctx, cam, &view);
    CHECK(st == PEN_OK);
    pen_context_destroy(ctx);
    return view;
}

/* The world point that projects to screen (sx, sy) at view depth z. */
static inline void ru_unproject(const pen_view *view, double sx, double sy, double z, float *p) {
    double d[3];
    pen_view_ray(view, sx, sy, d);
    for (int i = 0; i < 3; ++i)
        p[i] = (float)(view->eye[i] + z * d[i]);
}

static inline pen_raster_mesh ru_mesh(int nv, const float *pos, int nt, const uint32_t *idx,
                                      const int32_t *adj) {
    pen_raster_mesh m = {nv, nt, pos, idx, adj};
    return m;
}

static inline pen_gbuffer ru_gbuffer(int w, int h) {
    pen_gbuffer gb;
    pen_status st = pen_gbuffer_create(NULL, w, h, &gb);
    CHECK(st == PEN_OK);
    return gb;
}

/* Rasterizes with a fresh context and `threads` threads (0: default); returns the status. */
static inline pen_status ru_raster(const pen_view *view, const pen_raster_mesh *meshes, int n,
                                   const pen_ground *ground, pen_gbuffer *gb, int threads) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    pen_status st = pen_raster_gbuffer(ctx, view, meshes, n, ground, gb);
    pen_context_destroy(ctx);
    return st;
}

/* 1 if every depth and barycentric is a number (background depth is +inf by design). */
static inline int ru_gbuffer_sane(const pen_gbuffer *gb) {
    size_t n = (size_t)gb->width * (size_t)gb->height;
    for (size_t i = 0; i < n; ++i) {
        if (isnan(gb->depth[i]) || !isfinite(gb->bary[2 * i]) || !isfinite(gb->bary[2 * i + 1]))
            return 0;
        if (gb->surface[i] != PEN_SURFACE_BACKGROUND && !isfinite(gb->depth[i])) return 0;
    }
    return 1;
}

static inline int ru_all_finite(const float *v, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* 1 if two G-buffers have the same surfaces and triangles everywhere. */
static inline int ru_same_coverage(const pen_gbuffer *a, const pen_gbuffer *b) {
    size_t n = (size_t)a->width * (size_t)a->height;
    for (size_t i = 0; i < n; ++i)
        if (a->surface[i] != b->surface[i] || a->triangle[i] != b->triangle[i]) return 0;
    return 1;
}

/* Two objects over a ground plane: a tilted quad (object 0, two triangles, with a separate
 * colour index buffer as for UV seams) and a triangle partly in front of it (object 1). */
typedef struct ru_scene {
    float pos0[12], pos1[9], col0[5 * 3];
    uint32_t idx0[6], idx1[3], cidx0[6];
    int32_t adj0[6], adj1[3];
    pen_raster_mesh meshes[2];
    pen_camera cam;
    pen_view view;
    pen_ground ground;
} ru_scene;

static inline void ru_scene_init_size(ru_scene *s, int width, int height) {
    const float p0[12] = {-1.0f, -0.8f, 0.2f,  1.1f,  -0.9f, -0.3f,
                          0.9f,  1.0f,  -0.1f, -1.2f, 0.9f,  0.4f};
    const float p1[9] = {-0.3f, -0.5f, 1.2f, 0.8f, 0.1f, 1.0f, 0.0f, 0.7f, 1.3f};
    const uint32_t i0[6] = {0, 1, 2, 0, 2, 3}, i1[3] = {0, 1, 2}, c0[6] = {0, 1, 2, 4, 2, 3};
    memcpy(s->pos0, p0, sizeof p0);
    memcpy(s->pos1, p1, sizeof p1);
    memcpy(s->idx0, i0, sizeof i0);
    memcpy(s->idx1, i1, sizeof i1);
    memcpy(s->cidx0, c0, sizeof c0);
    for (int i = 0; i < 15; ++i)
        s->col0[i] = (float)(0.1 + 0.8 * ((i * 7) % 11) / 11.0);
    CHECK(pen_raster_adjacency(NULL, 4, 2, s->idx0, s->adj0) == PEN_OK);
    CHECK(pen_raster_adjacency(NULL, 3, 1, s->idx1, s->adj1) == PEN_OK);
    s->meshes[0] = ru_mesh(4, s->pos0, 2, s->idx0, s->adj0);
    s->meshes[1] = ru_mesh(3, s->pos1, 1, s->idx1, s->adj1);
    s->cam = ru_camera(width, height, 50.0f, 0.3f, 0.4f, 4.0f, 0, 0, 0);
    s->view = ru_view(&s->cam);
    pen_ground g = {1, -1.1f, {1, 1, 1}, 3};
    s->ground = g;
}

static inline void ru_scene_init(ru_scene *s) {
    ru_scene_init_size(s, 32, 28);
}

/* Thread-count tests need images above the size where loops go parallel (8192 pixels). */
#define RU_PARALLEL_W 131
#define RU_PARALLEL_H 97

/* A G-buffer of the scene's size with the scene rasterized into it. */
static inline pen_gbuffer ru_scene_gbuffer(const ru_scene *s) {
    pen_gbuffer gb = ru_gbuffer(s->cam.width, s->cam.height);
    CHECK(ru_raster(&s->view, s->meshes, 2, &s->ground, &gb, 0) == PEN_OK);
    return gb;
}

#endif
