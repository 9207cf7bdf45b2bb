/* Golden checksums: renders, gradients, sphere fits and an optimisation on the bundled scenes,
 * reduced to one 64-bit FNV-1a hash each and compared bit for bit with values recorded before a
 * refactoring. A change that is meant to move code without changing behaviour (the module
 * restructuring, the run-time kernel choice) must leave every hash as it was; a change that
 * means to alter results updates the table below in the same commit and says why.
 *
 * Only the public API is used (`#include <penumbra/penumbra.h>`), so the test outlives any move
 * of the code behind it. Bit-exactness holds for x86-64 with glibc's libm: the fast kernel's lane
 * count changes the order of its per-batch sums, so its rows are recorded once per kernel width
 * (16 lanes with AVX-512, 8 with AVX2, 4 with SSE2; PEN_CPU selects a narrower one), and the
 * scalar-kernel rows (lane-free) once. A run compares every row of the kernel in use; CMake runs
 * the test once per width (PEN_GOLDEN_LANES names the width a run is for), and a run whose
 * processor has no kernel of that width, or whose width has no recording, exits 77 (ctest:
 * skipped) and says so, instead of passing with rows left out.
 *
 * PEN_GOLDEN_PRINT=1 prints the current table in the source's format instead of checking (run it
 * with PEN_CPU=avx512, avx2 and sse2 and keep each width's fast rows). */
#define _POSIX_C_SOURCE 200809L /* strdup */
#include "check.h"
#include "penumbra/penumbra.h"

#include <stdint.h>
#include <string.h>

#define SIZE 96 /* render size: small enough for the sanitizer run, big enough for shadows */

static uint64_t fnv(uint64_t h, const void *data, size_t bytes) {
    const unsigned char *p = data;
    for (size_t i = 0; i < bytes; ++i)
        h = (h ^ p[i]) * 0x100000001b3ull;
    return h;
}
#define FNV_START 0xcbf29ce484222325ull

typedef struct golden {
    const char *name;
    uint64_t hash;
    int lanes; /* the fast kernel's lane count it was recorded with; 0: does not depend on it */
} golden;

/* Recorded before the module restructuring (AMD EPYC, AVX-512, 16 lanes), right after the
 * background cache was fixed to fill every pixel (it had left pixels under the object
 * uninitialised, which optimisation runs then read once the object moved). The "grad" rows of
 * scenes with the self transfer were re-recorded when the backward began to refuse the groups the
 * transfer holds constant: they now hash the exact groups only (lighting, albedo, irradiance);
 * every image, sphere-set and optimisation row kept its value. The fast rows whose pixels the
 * fast kernel lights with disk lights (no-shadows, ground-spheres, the lighting+pose
 * optimisation) were re-recorded when that light term moved into the kernel's float lanes
 * (docs/design.md sec. 1.13), and again when receivers whose disk crosses their horizon joined
 * the lanes (their clamped cosine from the float n . w): every scalar row kept its value. The
 * rows that depend on Spot's fitted spheres (its sphere set, the ground-spheres renders, the
 * lighting+pose optimisation) were re-recorded on an AVX2 machine when the fitter's Embree was
 * capped at AVX2 (src/geometry/embree.h): Embree's AVX-512 kernels had given another fit. Their
 * 16-lane rows wait for a recording on an AVX-512 machine; until then a run there checks every
 * other row and exits 77 naming them. */
static const golden table[] = {
#include "golden_table.inc"
    {NULL, 0, 0},
};

static int print_mode(void) {
    const char *e = getenv("PEN_GOLDEN_PRINT");
    return e && e[0] == '1';
}

static int unrecorded; /* rows of the kernel in use without a recording */

/* Compares the hash of row `name` (fast: it depends on the fast kernel's lane count). */
static void expect(const char *name, uint64_t hash, int fast) {
    const int lanes = fast ? pen_render_fast_lanes() : 0;
    if (print_mode()) {
        printf("    {\"%s\", 0x%016llxull, %d},\n", name, (unsigned long long)hash, lanes);
        return;
    }
    int named = 0;
    for (size_t i = 0; table[i].name; ++i) {
        if (strcmp(table[i].name, name) != 0) continue;
        named = 1;
        if (table[i].lanes != lanes) continue;
        CHECK_MSG(table[i].hash == hash, "%s (%d lanes): hash 0x%016llx, recorded 0x%016llx",
                  name, lanes, (unsigned long long)hash, (unsigned long long)table[i].hash);
        return;
    }
    if (named && fast) {
        ++unrecorded;
        printf("no recording of %s for the %d-lane fast kernel\n", name, lanes);
        return;
    }
    CHECK_MSG(0, "%s: not in the recorded table", name);
}

static uint64_t hash_grad(const pen_render_grad *g) {
    uint64_t h = fnv(FNV_START, g->sh, sizeof g->sh);
    h = fnv(h, g->ground_albedo, sizeof g->ground_albedo);
    for (int o = 0; o < g->object_count; ++o) {
        const pen_object_grad *og = &g->objects[o];
        h = fnv(h, og->albedo, sizeof og->albedo);
        if (og->texture) h = fnv(h, og->texture, sizeof(float) * 3 * (size_t)og->texel_count);
        if (og->spheres) h = fnv(h, og->spheres, sizeof(float) * 4 * (size_t)og->sphere_count);
        h = fnv(h, &og->pose, sizeof og->pose);
        if (og->positions) h = fnv(h, og->positions, sizeof(float) * 3 * (size_t)og->vertex_count);
    }
    return h;
}

static uint64_t hash_image(const pen_image *im) {
    return fnv(FNV_START, im->data,
               sizeof(float) * (size_t)im->width * (size_t)im->height * (size_t)im->channels);
}

/* Two threads, whatever OMP_NUM_THREADS says: the renderer's reductions are independent of the
 * thread count, but the sphere fit and the overlap weights measured here are not (a fit of Bob
 * and the interior scene's shadows differ at one thread), so the table holds for two. */
static pen_context *make_context(void) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, 2);
    return ctx;
}

static int load(pen_context *ctx, const char *name, pen_scene *scene) {
    char path[1024];
    snprintf(path, sizeof path, "%s/examples/%s", PEN_SOURCE_DIR, name);
    if (pen_scene_load(ctx, path, scene) != PEN_OK) {
        CHECK_MSG(0, "%s", pen_context_error(ctx));
        return 0;
    }
    scene->camera.width = scene->camera.height = SIZE;
    /* Fitted, not read from a cache, so the fitter itself is covered too. */
    for (int o = 0; o < scene->object_count; ++o) {
        pen_object *ob = &scene->objects[o];
        if (ob->fit_spheres <= 0) continue;
        pen_fit_settings fs;
        pen_fit_settings_default(&fs);
        if (pen_spheres_fit(ctx, &ob->mesh, ob->fit_spheres, &fs, &ob->spheres, NULL) != PEN_OK) {
            CHECK_MSG(0, "%s", pen_context_error(ctx));
            return 0;
        }
        ob->fit_spheres = 0;
    }
    return 1;
}

/* Forward and backward of one scene under one set of options, hashed. */
static void render_case(pen_context *ctx, const pen_scene *scene, const char *tag,
                        pen_render_options opt, int fast) {
    pen_render_state *st = NULL;
    pen_image img = {0}, d_img = {0}, target = {0};
    pen_render_grad grad = {0};
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    CHECK(pen_render_fwd(ctx, scene, &opt, st, &img) == PEN_OK);
    CHECK(pen_image_create(ctx, img.width, img.height, 3, &target) == PEN_OK);
    for (size_t i = 0; i < (size_t)img.width * img.height * 3; ++i)
        target.data[i] = 0.25f + 0.1f * (float)(i % 7);
    CHECK(pen_image_create(ctx, img.width, img.height, 3, &d_img) == PEN_OK);
    double loss = 0;
    CHECK(pen_loss_l2(ctx, &img, &target, &loss, &d_img) == PEN_OK);
    CHECK(pen_render_grad_create(ctx, scene, &grad) == PEN_OK);
    pen_render_grad_zero(&grad);
    /* Every group exact for the model (under the transfer: lighting, albedo, irradiance). */
    CHECK(pen_render_bwd(ctx, scene, &opt, st, &d_img, PEN_GRAD_ALL & pen_render_grad_exact(scene, &opt),
                         &grad) == PEN_OK);
    char name[128];
    snprintf(name, sizeof name, "%s image", tag);
    expect(name, hash_image(&img), fast);
    snprintf(name, sizeof name, "%s grad", tag);
    expect(name, hash_grad(&grad), fast);
    pen_render_grad_free(&grad);
    pen_image_free(&img);
    pen_image_free(&d_img);
    pen_image_free(&target);
    pen_render_state_free(st);
}

static void test_bundled_scenes(void) {
    static const char *scenes[] = {"scenes/spot_city.json", "scenes/spot_interior.json",
                                   "optimize/bob_truth.json"};
    pen_context *ctx = make_context();
    for (int s = 0; s < 3; ++s) {
        pen_scene scene;
        if (!load(ctx, scenes[s], &scene)) continue;
        char tag[96];
        snprintf(tag, sizeof tag, "%s spheres", scenes[s]);
        const pen_spheres *sp = &scene.objects[0].spheres;
        expect(tag, fnv(FNV_START, sp->data, sizeof(float) * 4 * (size_t)sp->count), 0);
        for (int variant = 0; variant < 4; ++variant) {
            pen_render_options opt = pen_render_options_default();
            opt.kernel = variant & 1 ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
            opt.shadows = !(variant & 2);
            snprintf(tag, sizeof tag, "%s %s %s", scenes[s], variant & 1 ? "scalar" : "fast",
                     variant & 2 ? "no-shadows" : "shadows");
            render_case(ctx, &scene, tag, opt, !(variant & 1));
        }
        /* "ground_shadow": "spheres": the ground shaded by the spheres, as before the ground
         * transfer (these rows were the shadows rows then). */
        scene.shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
        for (int variant = 0; variant < 2; ++variant) {
            pen_render_options opt = pen_render_options_default();
            opt.kernel = variant ? PEN_RENDER_KERNEL_SCALAR : PEN_RENDER_KERNEL_FAST;
            snprintf(tag, sizeof tag, "%s %s shadows ground-spheres", scenes[s],
                     variant ? "scalar" : "fast");
            render_case(ctx, &scene, tag, opt, !variant);
        }
        pen_scene_free(&scene);
    }
    pen_context_destroy(ctx);
}

/* A short lighting + pose run of the bundled scene against its own perturbed render: the
 * optimiser's parameters, losses and final image. */
static void test_optimize(void) {
    pen_context *ctx = make_context();
    pen_scene truth;
    if (!load(ctx, "scenes/spot_city.json", &truth)) {
        pen_context_destroy(ctx);
        return;
    }
    pen_optim_task task = pen_optim_task_default();
    pen_render_options opt = pen_render_options_default();
    CHECK(pen_render_fwd(ctx, &truth, &opt, NULL, &task.target) == PEN_OK);
    char path[1024];
    snprintf(path, sizeof path, "%s/examples/scenes/spot_city.json", PEN_SOURCE_DIR);
    if (!load(ctx, "scenes/spot_city.json", &task.scene)) {
        pen_optim_task_free(&task);
        pen_scene_free(&truth);
        pen_context_destroy(ctx);
        return;
    }
    task.path = strdup(path);
    task.optimize = PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE;
    task.iterations = 8;
    task.scene.objects[0].pose.rotation_axis_angle_deg[1] += 6.0f;
    task.scene.objects[0].pose.translation[0] += 0.05f;
    if (getenv("PEN_GOLDEN_DEBUG"))
        printf("dbg target %llx spheres %llx truth %llx\n",
               (unsigned long long)hash_image(&task.target),
               (unsigned long long)fnv(FNV_START, task.scene.objects[0].spheres.data, 16 * 32),
               (unsigned long long)fnv(FNV_START, truth.objects[0].spheres.data, 16 * 32));
    pen_optim_settings set = pen_optim_settings_default();
    pen_optim_result res = {0};
    pen_status st = pen_optim_run(ctx, &task, &set, &res);
    CHECK_MSG(st == PEN_OK, "%s", pen_context_error(ctx));
    if (st != PEN_OK) {
        pen_optim_task_free(&task);
        pen_scene_free(&truth);
        pen_context_destroy(ctx);
        return;
    }
    if (getenv("PEN_GOLDEN_DEBUG"))
        for (int i = 0; i <= res.iterations; ++i)
            printf("loss %d %.17g\n", i, res.losses[i]);
    uint64_t h = fnv(FNV_START, task.scene.lighting.sh, sizeof task.scene.lighting.sh);
    h = fnv(h, &task.scene.objects[0].pose, sizeof task.scene.objects[0].pose);
    h = fnv(h, res.losses, sizeof(double) * (size_t)(res.iterations + 1));
    expect("optimize lighting+pose params", h, 1);
    expect("optimize lighting+pose final", hash_image(&res.final), 1);
    pen_optim_result_free(&res);
    pen_optim_task_free(&task);
    pen_scene_free(&truth);
    pen_context_destroy(ctx);
}

int main(void) {
    /* A run for one kernel width (CMake's per-width tests) on a processor without it: nothing
     * of what it is for can be compared. */
    const char *want = getenv("PEN_GOLDEN_LANES");
    if (want && atoi(want) != pen_render_fast_lanes()) {
        printf("skipped: the %s-lane fast kernel is not available here (this processor's widest "
               "or PEN_CPU's has %d lanes)\n", want, pen_render_fast_lanes());
        return 77;
    }
    static const check_test_ tests[] = {TEST(test_bundled_scenes), TEST(test_optimize)};
    const int failed = check_run_(tests, (int)(sizeof tests / sizeof tests[0]));
    if (!failed && unrecorded) {
        printf("skipped: %d rows have no recording for the %d-lane fast kernel\n", unrecorded,
               pen_render_fast_lanes());
        return 77;
    }
    return failed;
}
