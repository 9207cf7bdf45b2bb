/* Shared fixture of the inverse-problem tests (tests/test_optim*.c): an ellipsoid hovering over
 * the ground under render_scenes.h's strong overhead light. Header-only (static). */
#ifndef PEN_TEST_OPTIM_SCENES_H
#define PEN_TEST_OPTIM_SCENES_H

#include "render_scenes.h"

#include "core/internal.h" /* pen__fnv1a: the checkpoints' checksum */
#include "optim/groups.h"  /* the segments' bounds in a checkpoint */

#include <stdio.h>
#include <string.h>

/* render_scenes.h's octasphere stretched to an ellipsoid (semi-axes 0.5625, 0.36, 0.45),
 * optionally textured (6x5 random texels from a fixed seed), 0.55 over the ground, turned
 * (10, 25, 0) degrees, size x size pixels, `bands` lighting bands, with five proxy spheres
 * inscribed along its long axis (fewer proxies leave its shadow too faint: with the render
 * fixture's two the SH render is 0.031 RMSE off the reference, with these five 0.019). */
static inline pen_scene os_egg(int size, int textured, int bands) {
    unsigned long long s = 4242;
    pen_scene sc = rs_scene(size, size);
    sc.sh_bands = bands;
    const float spheres[20] = {0.0f,  0, 0, 0.36f, 0.2f,   0, 0, 0.32f, -0.2f, 0,
                               0,     0.32f, 0.35f, 0, 0, 0.21f, -0.35f, 0, 0, 0.21f};
    pen_mesh mesh = rs_octasphere(2, 0.45f, textured);
    for (int i = 0; i < mesh.vertex_count; ++i)
        mesh.positions[3 * i] *= 1.25f, mesh.positions[3 * i + 1] *= 0.8f;
    pen_object *ob = rs_add_object(&sc, mesh, 5, spheres);
    ob->pose.translation[1] = 0.55f;
    ob->pose.rotation_axis_angle_deg[0] = 10.0f;
    ob->pose.rotation_axis_angle_deg[1] = 25.0f;
    if (textured) ob->texture = rs_texture(6, 5, &s);
    return sc;
}

/* A low sun (elevation 35 degrees, from +x and a little +z) over an ambient sky, 4 bands: the
 * sun's SH projection with a Hann window (1, 0.85, 0.5, 0.15 per band) against ringing. */
static inline void os_sun(pen_scene *sc, float sun, float sky) {
    const float el = 35.0f * (float)M_PI / 180.0f;
    float d[3] = {cosf(el) * 0.95f, sinf(el), cosf(el) * 0.31f}, y[16];
    const float n = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    d[0] /= n, d[1] /= n, d[2] /= n;
    pen_sh_eval(4, d, y);
    memset(sc->lighting.sh, 0, sizeof sc->lighting.sh);
    for (int l = 0; l < 4; ++l) {
        const float c = cosf((float)M_PI * (float)l / 8.0f), window = c * c;
        for (int m = -l; m <= l; ++m)
            for (int ch = 0; ch < 3; ++ch)
                sc->lighting.sh[l * l + l + m][ch] = sun * window * y[l * l + l + m];
    }
    for (int ch = 0; ch < 3; ++ch)
        sc->lighting.sh[0][ch] += sky * sqrtf(4.0f * (float)M_PI);
    sc->sh_bands = 4;
}

/* Shape from shadow: the ellipsoid under os_sun, seen from straight above over its shadow, which
 * falls towards -x; the frame (ground x in [-1.55, -0.45]) leaves the object outside: only its
 * shadow on the ground is seen. */
static inline pen_scene os_shadow_view(int size) {
    pen_scene sc = os_egg(size, 0, 4);
    os_sun(&sc, 6.0f, 0.5f);
    const float eye[3] = {-1.0f, 4.0f, -0.3f}, target[3] = {-1.0f, 0.0f, -0.3f},
                up[3] = {0.0f, 0.0f, -1.0f};
    memcpy(sc.camera.eye, eye, sizeof eye);
    memcpy(sc.camera.target, target, sizeof target);
    memcpy(sc.camera.up, up, sizeof up);
    sc.camera.fov_y_deg = 16.0f;
    return sc;
}

/* The SH-lit reference render of a scene (256 spp, seed 1: pixel noise about 0.007 RMSE). */
static inline pen_image os_reference(const pen_scene *sc) {
    pen_image img = {0, 0, 0, NULL};
    pen_context *ctx = pen_context_create();
    pen_reference *ref = NULL;
    CHECK(pen_reference_create(ctx, sc, PEN_REFERENCE_LIGHTING_SH, &ref) == PEN_OK);
    CHECK(pen_reference_render(ctx, ref, 256, 1, &img) == PEN_OK);
    pen_reference_destroy(ref);
    pen_context_destroy(ctx);
    return img;
}

/* The joint lighting + pose tests' start: 8.9 degrees and 0.072 away from the truth. */
static inline void os_perturb_pose(pen_scene *sc) {
    pen_pose *p = &sc->objects[0].pose;
    p->rotation_axis_angle_deg[1] += 8.0f;
    p->rotation_axis_angle_deg[0] -= 4.0f;
    p->translation[0] += 0.06f;
    p->translation[2] -= 0.04f;
}

/* A task with the library's defaults (pen_optim_task_default) on scene `scene` (the initial guess) with ground truth `truth`, whose
 * reference render is the target; both scenes are taken over. */
static inline pen_optim_task os_task(pen_scene scene, pen_scene truth, unsigned groups,
                                     int iterations) {
    pen_optim_task t = pen_optim_task_default();
    t.scene = scene;
    t.ground_truth = truth;
    t.has_ground_truth = 1;
    t.optimize = groups;
    t.iterations = iterations;
    t.target = os_reference(&t.ground_truth);
    return t;
}

/* A checkpoint file's bytes, to be edited as an older build would have written them: read
 * whole into buf (room for cap bytes; returns the size, 0 on failure), then written back with
 * its checksum (the trailing FNV-1a 64 of every byte before it, checkpoint.c) recomputed. */
static inline size_t os_checkpoint_read(const char *path, unsigned char *buf, size_t cap) {
    FILE *f = fopen(path, "rb");
    CHECK(f != NULL);
    if (!f) return 0;
    const size_t n = fread(buf, 1, cap, f);
    fclose(f);
    CHECK(n > 100 && n < cap);
    return n > 100 && n < cap ? n : 0;
}

static inline void os_checkpoint_write(const char *path, unsigned char *buf, size_t n) {
    const uint64_t sum = pen__fnv1a(PEN__FNV1A_SEED, buf, n - 8);
    memcpy(buf + n - 8, &sum, 8);
    FILE *f = fopen(path, "wb");
    CHECK(f && fwrite(buf, 1, n, f) == n);
    if (f) fclose(f);
}

/* Where the lighting solver's field of a checkpoint in buf starts (the layout in checkpoint.c:
 * 28 bytes, 20 a segment, then groups, 4 ints and the shadow weight). */
static inline size_t os_checkpoint_solver_at(const unsigned char *buf) {
    uint32_t segs;
    memcpy(&segs, buf + 24, 4);
    return 28 + 20 * (size_t)segs + 4 + 16 + 8;
}

/* The optimised groups as checkpoints before version 7 held them: the bits of optim.h then
 * (lighting 1, albedo 2, pose 4, deformation 8, spheres 16, lights 32, exposure 64). */
static inline uint32_t os_groups_v6(uint32_t groups) {
    static const uint32_t now[] = {PEN_OPTIM_LIGHTING, PEN_OPTIM_ALBEDO, PEN_OPTIM_POSE,
                                   PEN_OPTIM_DEFORMATION, PEN_OPTIM_SPHERES, PEN_OPTIM_LIGHTS,
                                   PEN_OPTIM_EXPOSURE};
    uint32_t old = 0;
    for (int k = 0; k < 7; ++k)
        if (groups & now[k]) old |= 1u << k;
    return old;
}

/* Rewrites the checkpoint at `path` as a build of an older `version` wrote it where the fields
 * did not change since: the version field set; below version 7 the groups in the bits of then
 * (os_groups_v6, after the segments) and the lighting's and the log exposures' segments
 * unbounded (their bounds came with version 7); below version 6 the scene's hash (after the
 * solver, ridge, k, the 3 weights, the target's and the initial guess's hashes) taken out; the
 * checksum recomputed. */
static inline void os_checkpoint_downgrade(const char *path, uint32_t version) {
    static unsigned char buf[1 << 16];
    size_t n = os_checkpoint_read(path, buf, sizeof buf);
    if (!n) return;
    memcpy(buf + 8, &version, 4);
    if (version < 7u) {
        uint32_t groups;
        const size_t at = os_checkpoint_solver_at(buf) - 28; /* groups, 4 ints, shadow weight */
        memcpy(&groups, buf + at, 4);
        groups = os_groups_v6(groups);
        memcpy(buf + at, &groups, 4);
        uint32_t segs, bound;
        memcpy(&segs, buf + 24, 4);
        for (uint32_t k = 0; k < segs; ++k) { /* {u64 offset, u64 count, u32 bound} from 28 */
            memcpy(&bound, buf + 28 + 20 * (size_t)k + 16, 4);
            if (bound == PEN__BOUND_SH || bound == PEN__BOUND_LOG_EXPOSURE) bound = PEN__BOUND_NONE;
            memcpy(buf + 28 + 20 * (size_t)k + 16, &bound, 4);
        }
    }
    if (version < 6u) {
        const size_t at = os_checkpoint_solver_at(buf) + 4 + 8 + 4 + 24 + 8 + 8;
        memmove(buf + at, buf + at + 8, n - at - 8);
        n -= 8;
    }
    os_checkpoint_write(path, buf, n);
}

#endif
