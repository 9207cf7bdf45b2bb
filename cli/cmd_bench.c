/* penumbra bench: the performance suite of docs/design.md sec. 5 (docs/bench.md).
 *
 * Every case is the bundled scene examples/scenes/spot_city.json (or --scene) with its image size,
 * SH band count and sphere count changed: the headline case (512 x 512, 32 spheres, 4 bands) and
 * one sweep per parameter through it (resolution 256 / 1024, spheres 8 / 128, bands 3 / 5 / 6),
 * disk lights (1, 3), and "transfer": the headline with the objects' own shadows from their
 * precomputed transfer (docs/design.md sec. 1.15), stepping only the lighting and albedo as a
 * lighting or texture optimisation does, the ground shadowed by the spheres as before the ground
 * transfer; "groundgrid" is the same with the ground's shadows from the transfer's grid too (the
 * scene's default). The other cases shade the objects' own shadows with their
 * spheres ("self": "spheres"), the model a pose and sphere step needs.
 * A case times what one optimisation step costs: forward render, L2 loss against a fixed target
 * (the render of a slightly perturbed scene), backward into lighting, albedo texture, spheres
 * and pose (the transfer case: lighting and albedo); the spheres are fitted (or read from the fit cache) when the case is set up, before
 * any iteration; then warm-up iterations (first-touch page faults, the Gaunt tables), then
 * --repeat timed iterations whose medians are reported, with the renderer's own per-stage times
 * (pen_render_state_timings) as medians per field.
 *
 * The reference comparison answers "how long would the ray tracer need for the same error?". The
 * truth is the Embree reference (SH lighting, so only visibility differs) at truth-spp samples;
 * the SH render's error is its relative RMSE against the truth over the pixels the truth sees a
 * surface in (coverage > 0.5: the background is the envmap in both, differing only by texture
 * detail, which would charge the rasterizer's point sampling to the shadows). The reference
 * (another seed) is then rendered at 1, 2, 4, ... spp, up to the truth's own spp, until its error
 * against the truth is no larger; its time at that spp (scene build + render, median of 3) over
 * the SH forward time is the ratio. The truth's noise does not bias this test: with an unbiased
 * estimator of variance b per sample, E|ref_s - truth|^2 = b/s + b/T and E|SH - truth|^2 =
 * |SH - exact|^2 + b/T, so both sides carry the same b/T and the comparison is b/s against the
 * SH render's exact error. T only sets how precisely the errors are measured, and the highest spp
 * the search can reach. Truths depend only on size and bands, so cases that share them share one
 * render.
 *
 * Timing: omp_get_wtime around the library calls; medians, since the machine may be shared. The
 * 1-minute load average (from /proc/loadavg) is reported next to each case for that reason.
 */
#define _POSIX_C_SOURCE 200809L
#include "commands.h"

#include "penumbra/fit.h"

#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const CMD = "bench";
static const char *const SCENE_REL = "examples/scenes/spot_city.json";

/* Gradient groups of the headline contract: everything but per-vertex positions. */
#define BENCH_WRT (PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO | PEN_GRAD_SPHERES | PEN_GRAD_POSE)
/* ... and the disk lights' own group in the cases that have lights. */
#define BENCH_WRT_LIGHTS (BENCH_WRT | PEN_GRAD_LIGHTS)
#define MAX_CASES 16
#define MAX_REPEAT 1000
#define TRUTH_SEED 7u
#define SEARCH_SEED 1u
#define REF_TIMINGS 3 /* runs of the reference at the found spp, median reported */

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra bench [--json] [--quick] [--threads N] [--repeat N] [--warmup N]\n"
            "                      [--case NAME]... [--no-reference] [--truth-spp N]\n"
            "                      [--scene SCENE.json] [--no-cache]\n\n"
            "Times forward render + L2 loss + backward (gradients of lighting, albedo texture,\n"
            "spheres and pose) on the bundled Spot scene, and how long the Embree reference takes\n"
            "to reach the SH render's error (docs/bench.md).\n\n"
            "Cases (name: size, spheres, bands):\n"
            "  headline: 512x512, 32, 4    res256, res1024: the size sweep\n"
            "  spheres8, spheres128: the sphere sweep    bands3, bands5, bands6: the band sweep\n"
            "  (the headline is the middle point of all three sweeps)\n"
            "  lights1, lights3: the headline with 1 and 3 disk lights on top of its SH lighting\n"
            "  (a sun; two lamps), gradients of the lights too; no reference comparison\n\n"
            "Options:\n"
            "  --json           one JSON object per case and line (fields in docs/bench.md)\n"
            "  --quick          seconds instead of minutes: sizes / 8 (headline 64x64), 3 timed\n"
            "                   iterations, 1 warm-up, truth at 64 spp; case names follow the\n"
            "                   sizes (res32, res128). For tests, not for figures\n"
            "  --threads N      worker threads (default 0: all cores)\n"
            "  --repeat N       timed iterations per case; medians and minima (default 10)\n"
            "  --warmup N       untimed iterations first (default 2)\n"
            "  --case NAME      run only this case (repeatable), e.g. --case headline\n"
            "  --no-reference   skip the Embree reference comparison (its fields are null)\n"
            "  --truth-spp N    samples per pixel of the reference taken as truth (default 256)\n"
            "  --scene PATH     another scene; its objects get the case's fitted spheres\n"
            "                   (default: the bundled %s, found beside the\n"
            "                   executable: ../share/penumbra when installed, else the checkout)\n"
            "  --no-cache       fit the spheres afresh, without reading or writing the fit cache\n"
            "                   ($XDG_CACHE_HOME/penumbra; also PENUMBRA_NO_CACHE=1)\n",
            SCENE_REL);
}

/* ---- Configuration and cases ----------------------------------------------------------------- */

typedef struct bench_case {
    char name[32];
    int width, height, spheres, bands;
    int lights;   /* disk lights added to the scene's own (bench_lights) */
    int transfer; /* the objects' own shadows from their transfer (else their spheres) */
    int ground_grid; /* with transfer: the ground's shadows from the grid (else the spheres) */
} bench_case;

typedef struct bench_config {
    int json, quick, threads, repeat, warmup, reference, truth_spp, no_cache;
    const char *scene_path;
    int only_count;
    const char *only[MAX_CASES];
} bench_config;

static void add_case(bench_case *cases, int *count, const char *prefix, int value, int size,
                     int spheres, int bands) {
    bench_case *c = &cases[(*count)++];
    if (prefix)
        snprintf(c->name, sizeof c->name, "%s%d", prefix, value);
    else
        snprintf(c->name, sizeof c->name, "headline");
    c->width = c->height = size;
    c->spheres = spheres;
    c->bands = bands;
    c->lights = 0;
    c->transfer = 0;
    c->ground_grid = 0;
}

/* The headline first, then each sweep without repeating the headline point. */
static int make_cases(int quick, bench_case *cases) {
    const int div = quick ? 8 : 1;
    const int size = 512 / div, spheres = 32, bands = 4;
    int n = 0;
    add_case(cases, &n, NULL, 0, size, spheres, bands);
    add_case(cases, &n, "res", 256 / div, 256 / div, spheres, bands);
    add_case(cases, &n, "res", 1024 / div, 1024 / div, spheres, bands);
    add_case(cases, &n, "spheres", 8, size, 8, bands);
    add_case(cases, &n, "spheres", 128, size, 128, bands);
    for (int b = 3; b <= 6; ++b)
        if (b != bands) add_case(cases, &n, "bands", b, size, spheres, b);
    for (int k = 1; k <= 3; k += 2) {
        add_case(cases, &n, "lights", k, size, spheres, bands);
        cases[n - 1].lights = k;
    }
    add_case(cases, &n, NULL, 0, size, spheres, bands);
    snprintf(cases[n - 1].name, sizeof cases[n - 1].name, "transfer");
    cases[n - 1].transfer = 1;
    add_case(cases, &n, NULL, 0, size, spheres, bands);
    snprintf(cases[n - 1].name, sizeof cases[n - 1].name, "groundgrid");
    cases[n - 1].transfer = 1;
    cases[n - 1].ground_grid = 1;
    return n;
}

static int selected(const bench_config *cfg, const char *name) {
    if (cfg->only_count == 0) return 1;
    for (int i = 0; i < cfg->only_count; ++i)
        if (!strcmp(cfg->only[i], name)) return 1;
    return 0;
}

static double load_average(void) {
    double load = NAN;
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf", &load) != 1) load = NAN;
        fclose(f);
    }
    return load;
}

/* ---- Statistics ------------------------------------------------------------------------------ */

static int cmp_double(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Smallest of v[0], v[stride], ... (n >= 1 values). */
static double minimum(const double *v, int n, int stride) {
    double m = v[0];
    for (int i = 1; i < n; ++i)
        if (v[(size_t)i * (size_t)stride] < m) m = v[(size_t)i * (size_t)stride];
    return m;
}

/* Median of v[0], v[stride], ... (n values); v is not changed. */
static double median(const double *v, int n, int stride, double *scratch) {
    for (int i = 0; i < n; ++i)
        scratch[i] = v[(size_t)i * (size_t)stride];
    qsort(scratch, (size_t)n, sizeof *scratch, cmp_double);
    return n % 2 ? scratch[n / 2] : 0.5 * (scratch[n / 2 - 1] + scratch[n / 2]);
}

/* pen_render_timings as an array of doubles, in the struct's order, with their names. */
#define STAGE_COUNT 10
static const char *const stage_names[STAGE_COUNT] = {
    "fwd_prepare_ms",  "fwd_shade_ms",    "fwd_visibility_ms", "fwd_exp_ms",
    "fwd_antialias_ms", "bwd_antialias_ms", "bwd_shade_ms",      "bwd_visibility_ms",
    "bwd_exp_ms",      "bwd_scatter_ms"};

static void stages_of(const pen_render_timings *t, double out[STAGE_COUNT]) {
    const double v[STAGE_COUNT] = {t->fwd_prepare_ms,   t->fwd_shade_ms,     t->fwd_visibility_ms,
                                   t->fwd_exp_ms,       t->fwd_antialias_ms, t->bwd_antialias_ms,
                                   t->bwd_shade_ms,     t->bwd_visibility_ms, t->bwd_exp_ms,
                                   t->bwd_scatter_ms};
    memcpy(out, v, sizeof v);
}

/* ---- One case -------------------------------------------------------------------------------- */

typedef struct bench_result {
    int threads;
    double load;
    double forward_ms, backward_ms, total_ms, loss;
    double first_forward_ms; /* the first warm-up forward, fresh state: the transfer's ray tracing */
    double forward_min_ms, backward_min_ms, total_min_ms; /* least affected by a shared machine */
    double stages[STAGE_COUNT];
    /* Reference comparison; NaN / 0 when skipped or not reached. */
    int truth_spp, reference_spp;
    double sh_rel_rmse, reference_rel_rmse, reference_ms;
} bench_result;

/* A truth image shared by the cases of the same size and band count. */
typedef struct truth_entry {
    int width, height, bands;
    pen_image image, coverage;
} truth_entry;

typedef struct truth_cache {
    int count;
    truth_entry entry[MAX_CASES];
} truth_cache;

/* Sets the scene to the case: size, bands, and `spheres` fitted spheres for every object. When
 * the case's band count differs from the scene's, the lighting is re-projected from the map at
 * the new count (replacing explicit "sh" rows too when the scene also names a map; without a map
 * the rows are kept, cut or zero-padded) and epsilon becomes the exponential model's default for
 * that count, replacing an explicit "epsilon". At the scene's own count both stay as loaded. */
/* The lights cases' disk lights: a sun (0.27 degrees) high enough for a shadow in view, and two
 * lamps of 5 and 10 degrees lower down; irradiances about the SH lighting's own. */
static void bench_lights(pen_scene *sc, int count) {
    static const float dir[3][3] = {{0.5f, 0.8f, 0.35f}, {-0.7f, 0.4f, 0.5f}, {0.2f, 0.3f, -0.9f}};
    static const float radius[3] = {0.27f, 5.0f, 10.0f}, E[3] = {3.0f, 1.0f, 0.5f};
    for (int l = 0; l < count && sc->lighting.light_count < PEN_SCENE_MAX_LIGHTS; ++l) {
        pen_light *L = &sc->lighting.lights[sc->lighting.light_count++];
        for (int a = 0; a < 3; ++a)
            L->direction[a] = dir[l][a], L->irradiance[a] = E[l];
        L->angular_radius_deg = radius[l];
    }
    sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
}

static pen_status configure(pen_context *ctx, pen_scene *sc, const bench_case *c) {
    if (c->lights) bench_lights(sc, c->lights);
    /* The objects' own shadows from their transfer or their spheres (the model a pose step
     * needs, pen_render_grad_model). */
    sc->shadow.self = c->transfer ? PEN_SELF_TRANSFER : PEN_SELF_SPHERES;
    sc->shadow.ground_shadow = c->ground_grid ? PEN_GROUND_SHADOW_TRANSFER
                                              : PEN_GROUND_SHADOW_SPHERES;
    sc->camera.width = c->width;
    sc->camera.height = c->height;
    if (c->bands != sc->sh_bands) {
        const int old = sc->sh_bands * sc->sh_bands, nc = c->bands * c->bands;
        for (int k = old; k < nc; ++k)
            sc->lighting.sh[k][0] = sc->lighting.sh[k][1] = sc->lighting.sh[k][2] = 0.0f;
        pen_lighting *L = &sc->lighting;
        if (L->envmap.data && L->lights_mode == PEN_LIGHTS_AUTO) {
            /* as the loader does: lights found, the rest projected, the added ones after */
            pen_light added[PEN_SCENE_MAX_LIGHTS];
            const int n_added = L->lights_added, max = L->lights_max;
            memcpy(added, L->lights + (L->light_count - n_added),
                   sizeof(pen_light) * (size_t)n_added);
            L->light_count = 0;
            pen_status s = pen_envmap_lighting(ctx, &L->envmap, c->bands, L->rotation_y_deg,
                                               L->scale, max, L->sh, L->lights, &L->light_count);
            if (s) return s;
            memcpy(L->lights + L->light_count, added, sizeof(pen_light) * (size_t)n_added);
            L->light_count += n_added;
        } else if (L->envmap.data) {
            pen_status s = pen_envmap_lighting(ctx, &L->envmap, c->bands, L->rotation_y_deg,
                                               L->scale, 0, L->sh, L->lights, &L->light_count);
            if (s) return s;
        }
        sc->sh_bands = c->bands;
        sc->shadow.epsilon = (float)pen_sh_exp_model_default(sc->shadow.exp, c->bands).epsilon;
    }
    for (int o = 0; o < sc->object_count; ++o) {
        pen_object *ob = &sc->objects[o];
        pen_spheres_free(&ob->spheres);
        free(ob->spheres_path);
        ob->spheres_path = NULL;
        ob->fit_spheres = c->spheres;
    }
    return pen_scene_prepare(ctx, sc, 1, NULL);
}

/* The target: the scene with dimmer light, a turned and shifted pose (then restored: the saved
 * values themselves, since x + 4 - 4 need not round back to x in float). */
static pen_status render_target(pen_context *ctx, pen_scene *sc, const pen_render_options *opt,
                                pen_image *target) {
    const size_t n = sc->object_count > 0 ? (size_t)sc->object_count : 1;
    pen_pose *poses = malloc(n * sizeof *poses);
    if (!poses) return PEN_ERROR_MEMORY;
    float sh[PEN_SH_MAX_COEFFS][3];
    memcpy(sh, sc->lighting.sh, sizeof sh);
    for (int k = 0; k < PEN_SH_MAX_COEFFS; ++k)
        for (int ch = 0; ch < 3; ++ch)
            sc->lighting.sh[k][ch] *= 0.9f;
    for (int o = 0; o < sc->object_count; ++o) {
        poses[o] = sc->objects[o].pose;
        sc->objects[o].pose.rotation_axis_angle_deg[1] += 4.0f;
        sc->objects[o].pose.translation[0] += 0.03f;
    }
    const pen_status s = pen_render_fwd(ctx, sc, opt, NULL, target);
    memcpy(sc->lighting.sh, sh, sizeof sh);
    for (int o = 0; o < sc->object_count; ++o)
        sc->objects[o].pose = poses[o];
    free(poses);
    return s;
}

/* The timed loop: warm-up, then cfg->repeat iterations; medians into r. `image` keeps the last
 * forward (of the unperturbed scene) for the reference comparison. */
static pen_status time_steps(pen_context *ctx, const bench_config *cfg, const bench_case *c,
                             const pen_scene *sc, const pen_image *target, pen_image *image,
                             bench_result *r) {
    unsigned wrt = sc->lighting.light_count > 0 ? BENCH_WRT_LIGHTS : BENCH_WRT;
    if (c->transfer) wrt = PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO;
    const pen_render_options opt = pen_render_options_default();
    const int n = cfg->repeat, per = 3 + STAGE_COUNT; /* forward, backward, total, stages */
    double *samples = calloc((size_t)n * (size_t)per + (size_t)n, sizeof(double));
    pen_render_state *st = NULL;
    pen_render_grad grad;
    memset(&grad, 0, sizeof grad);
    pen_image d_image = {0, 0, 0, NULL};
    pen_status s = PEN_ERROR_MEMORY;
    if (!samples) goto done;
    if ((s = pen_render_state_create(ctx, &st)) || (s = pen_render_grad_create(ctx, sc, &grad)) ||
        (s = pen_image_create(ctx, target->width, target->height, 3, &d_image)))
        goto done;
    const size_t bytes = sizeof(float) * 3 * (size_t)target->width * (size_t)target->height;
    for (int it = 0; it < cfg->warmup + n; ++it) {
        const double t0 = omp_get_wtime();
        if ((s = pen_render_fwd(ctx, sc, &opt, st, image))) goto done;
        const double t1 = omp_get_wtime();
        memset(d_image.data, 0, bytes); /* the loss adds into d_image */
        if ((s = pen_loss_l2(ctx, image, target, &r->loss, &d_image))) goto done;
        pen_render_grad_zero(&grad);
        const double t2 = omp_get_wtime();
        if ((s = pen_render_bwd(ctx, sc, &opt, st, &d_image, wrt, &grad))) goto done;
        const double t3 = omp_get_wtime();
        if (it == 0) r->first_forward_ms = 1e3 * (t1 - t0);
        if (it < cfg->warmup) continue;
        double *row = samples + (size_t)(it - cfg->warmup) * (size_t)per;
        row[0] = 1e3 * (t1 - t0);
        row[1] = 1e3 * (t3 - t2);
        row[2] = 1e3 * (t3 - t0);
        pen_render_timings tm;
        pen_render_state_timings(st, &tm);
        stages_of(&tm, row + 3);
    }
    double *scratch = samples + (size_t)n * (size_t)per;
    r->forward_ms = median(samples + 0, n, per, scratch);
    r->backward_ms = median(samples + 1, n, per, scratch);
    r->total_ms = median(samples + 2, n, per, scratch);
    r->forward_min_ms = minimum(samples + 0, n, per);
    r->backward_min_ms = minimum(samples + 1, n, per);
    r->total_min_ms = minimum(samples + 2, n, per);
    for (int k = 0; k < STAGE_COUNT; ++k)
        r->stages[k] = median(samples + 3 + k, n, per, scratch);
    s = PEN_OK;
done:
    pen_image_free(&d_image);
    pen_render_grad_free(&grad);
    pen_render_state_free(st);
    free(samples);
    return s;
}

/* The truth for this size and band count, rendered on first use (only then is the Embree scene
 * built). */
static pen_status truth_for(pen_context *ctx, const bench_config *cfg, truth_cache *cache,
                            const pen_scene *sc, const truth_entry **out) {
    for (int i = 0; i < cache->count; ++i) {
        const truth_entry *e = &cache->entry[i];
        if (e->width == sc->camera.width && e->height == sc->camera.height &&
            e->bands == sc->sh_bands) {
            *out = e;
            return PEN_OK;
        }
    }
    truth_entry *e = &cache->entry[cache->count];
    memset(e, 0, sizeof *e);
    pen_reference *ref = NULL;
    pen_status s = pen_reference_create(ctx, sc, PEN_REFERENCE_LIGHTING_SH, &ref);
    if (!s)
        s = pen_reference_render_coverage(ctx, ref, cfg->truth_spp, TRUTH_SEED, &e->image,
                                          &e->coverage);
    pen_reference_destroy(ref);
    if (s) return s;
    e->width = sc->camera.width, e->height = sc->camera.height, e->bands = sc->sh_bands;
    ++cache->count;
    *out = e;
    return PEN_OK;
}

static void truth_cache_free(truth_cache *cache) {
    for (int i = 0; i < cache->count; ++i) {
        pen_image_free(&cache->entry[i].image);
        pen_image_free(&cache->entry[i].coverage);
    }
    cache->count = 0;
}

/* One timed reference run at spp into *image (replacing it): what `penumbra reference` times,
 * the scene build and the render, in *ms. */
static pen_status timed_reference(pen_context *ctx, const pen_scene *sc, int spp, pen_image *image,
                                  double *ms) {
    pen_image_free(image);
    pen_reference *ref = NULL;
    const double t0 = omp_get_wtime();
    pen_status s = pen_reference_create(ctx, sc, PEN_REFERENCE_LIGHTING_SH, &ref);
    if (!s) s = pen_reference_render(ctx, ref, spp, SEARCH_SEED, image);
    *ms = 1e3 * (omp_get_wtime() - t0);
    pen_reference_destroy(ref);
    return s;
}

/* The SH render's error against the truth, then the smallest power-of-two spp at which the
 * reference's error is no larger (up to truth_spp), and that spp's time. */
static pen_status compare_reference(pen_context *ctx, const bench_config *cfg, truth_cache *cache,
                                    const pen_scene *sc, const pen_image *image, bench_result *r) {
    const truth_entry *truth = NULL;
    pen_image_error all, masked;
    pen_status s = truth_for(ctx, cfg, cache, sc, &truth);
    if (!s) s = pen_image_compare(ctx, image, &truth->image, &truth->coverage, &all, &masked);
    if (s) return s;
    r->truth_spp = cfg->truth_spp;
    r->sh_rel_rmse = masked.rel_rmse;
    pen_image trial = {0, 0, 0, NULL};
    double times[REF_TIMINGS];
    int found = 0;
    for (int spp = 1; spp <= cfg->truth_spp && !found && !s; spp *= 2) {
        s = timed_reference(ctx, sc, spp, &trial, &times[0]);
        if (!s) s = pen_image_compare(ctx, &trial, &truth->image, &truth->coverage, &all, &masked);
        if (!s && masked.rel_rmse <= r->sh_rel_rmse) {
            found = 1;
            r->reference_spp = spp;
            r->reference_rel_rmse = masked.rel_rmse;
        }
    }
    for (int k = 1; found && k < REF_TIMINGS && !s; ++k)
        s = timed_reference(ctx, sc, r->reference_spp, &trial, &times[k]);
    if (found && !s) {
        double scratch[REF_TIMINGS];
        r->reference_ms = median(times, REF_TIMINGS, 1, scratch);
    }
    pen_image_free(&trial);
    return s;
}

static pen_status run_case(pen_context *ctx, const bench_config *cfg, const bench_case *c,
                           truth_cache *cache, bench_result *r) {
    memset(r, 0, sizeof *r);
    r->sh_rel_rmse = r->reference_rel_rmse = r->reference_ms = NAN;
    r->threads = cfg->threads > 0 ? cfg->threads : omp_get_max_threads();
    r->load = load_average();
    pen_scene sc;
    if (pen_scene_load(ctx, cfg->scene_path, &sc)) return pen_context_status(ctx);
    const pen_render_options opt = pen_render_options_default();
    pen_image target = {0, 0, 0, NULL}, image = target;
    pen_status s;
    if (!(s = configure(ctx, &sc, c)) && !(s = render_target(ctx, &sc, &opt, &target)) &&
        !(s = time_steps(ctx, cfg, c, &sc, &target, &image, r)) && cfg->reference && !c->lights)
        s = compare_reference(ctx, cfg, cache, &sc, &image, r);
    pen_image_free(&image);
    pen_image_free(&target);
    pen_scene_free(&sc);
    return s;
}

/* ---- Output ---------------------------------------------------------------------------------- */

/* A JSON number, or null when not finite. */
static void json_num(const char *key, double v, const char *fmt) {
    printf(", \"%s\": ", key);
    if (isfinite(v))
        printf(fmt, v);
    else
        printf("null");
}

static double ratio(double num, double den) {
    return isfinite(num) && isfinite(den) && den > 0.0 ? num / den : (double)NAN;
}

static void print_json(const bench_config *cfg, const bench_case *c, const bench_result *r) {
    printf("{\"name\": \"%s\", \"width\": %d, \"height\": %d, \"spheres\": %d, \"bands\": %d, "
           "\"lights\": %d, \"self\": \"%s\", \"ground_shadow\": \"%s\", \"threads\": %d, "
           "\"repeat\": %d, \"quick\": %s",
           c->name, c->width, c->height, c->spheres, c->bands, c->lights,
           c->transfer ? "transfer" : "spheres", c->ground_grid ? "transfer" : "spheres",
           r->threads, cfg->repeat,
           cfg->quick ? "true" : "false");
    json_num("forward_ms", r->forward_ms, "%.3f");
    json_num("backward_ms", r->backward_ms, "%.3f");
    json_num("total_ms", r->total_ms, "%.3f");
    json_num("first_forward_ms", r->first_forward_ms, "%.3f");
    json_num("forward_min_ms", r->forward_min_ms, "%.3f");
    json_num("backward_min_ms", r->backward_min_ms, "%.3f");
    json_num("total_min_ms", r->total_min_ms, "%.3f");
    for (int k = 0; k < STAGE_COUNT; ++k)
        json_num(stage_names[k], r->stages[k], "%.3f");
    json_num("loss", r->loss, "%.6g");
    json_num("load_avg_1min", r->load, "%.2f");
    json_num("truth_spp", r->truth_spp > 0 ? (double)r->truth_spp : (double)NAN, "%.0f");
    json_num("sh_rel_rmse", r->sh_rel_rmse, "%.5f");
    json_num("reference_spp", r->reference_spp > 0 ? (double)r->reference_spp : (double)NAN, "%.0f");
    json_num("reference_rel_rmse", r->reference_rel_rmse, "%.5f");
    json_num("reference_ms", r->reference_ms, "%.3f");
    json_num("reference_vs_forward", ratio(r->reference_ms, r->forward_ms), "%.4f");
    json_num("reference_vs_total", ratio(r->reference_ms, r->total_ms), "%.4f");
    printf("}\n");
    fflush(stdout);
}

static void print_table_header(const bench_config *cfg) {
    printf("penumbra bench: %s, %d timed iterations after %d warm-up, medians in ms%s\n",
           cfg->scene_path, cfg->repeat, cfg->warmup, cfg->quick ? " (--quick)" : "");
    printf("%-11s %9s %7s %5s %7s %9s %9s %9s %8s %7s %8s %7s %7s %5s\n", "case", "size",
           "spheres", "bands", "threads", "forward", "backward", "total", "SH err", "ref spp",
           "ref ms", "ref/fwd", "ref/tot", "load");
}

/* "-" for a missing value. */
static void cell(double v, int width, int decimals) {
    if (isfinite(v))
        printf(" %*.*f", width, decimals, v);
    else
        printf(" %*s", width, "-");
}

static void print_table_row(const bench_case *c, const bench_result *r) {
    char size[24];
    snprintf(size, sizeof size, "%dx%d", c->width, c->height);
    printf("%-11s %9s %7d %5d %7d", c->name, size, c->spheres, c->bands, r->threads);
    cell(r->forward_ms, 9, 1);
    cell(r->backward_ms, 9, 1);
    cell(r->total_ms, 9, 1);
    cell(r->sh_rel_rmse, 8, 4);
    cell(r->reference_spp > 0 ? (double)r->reference_spp : (double)NAN, 7, 0);
    cell(r->reference_ms, 8, 1);
    cell(ratio(r->reference_ms, r->forward_ms), 7, 3);
    cell(ratio(r->reference_ms, r->total_ms), 7, 3);
    cell(r->load, 5, 2);
    printf("\n");
    if (c->transfer) /* the cache's one-time ray tracing is in the first forward */
        printf("%-11s (first forward, the transfer%s ray traced: %.1f ms)\n", "",
               c->ground_grid ? " and the ground grid" : "", r->first_forward_ms);
    fflush(stdout);
}

static void print_stage_table(const bench_case *cases, const bench_result *res, const int *ran,
                              int count) {
    printf("\nstages (medians, ms; visibility and exp are parts of shade, 0 = not split out)\n");
    printf("%-11s | %8s %8s %8s %8s %8s | %8s %8s %8s %8s %8s\n", "case", "prepare", "shade",
           "vis", "exp", "aa", "aa", "shade", "vis", "exp", "scatter");
    printf("%-11s | %44s | %44s\n", "", "forward", "backward");
    for (int i = 0; i < count; ++i) {
        if (!ran[i]) continue;
        printf("%-11s |", cases[i].name);
        for (int k = 0; k < STAGE_COUNT; ++k) {
            if (k == 5) printf(" |");
            cell(res[i].stages[k], 8, 1);
        }
        printf("\n");
    }
}

/* ---- Command --------------------------------------------------------------------------------- */

/* Parses the arguments into cfg; returns -1 to go on, else the exit status. */
static int parse_args(int argc, char **argv, bench_config *cfg) {
    int repeat = -1, warmup = -1, truth = -1;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--json")) {
            cfg->json = 1;
        } else if (!strcmp(a, "--quick")) {
            cfg->quick = 1;
        } else if (!strcmp(a, "--no-reference")) {
            cfg->reference = 0;
        } else if (!strcmp(a, "--no-cache")) {
            cfg->no_cache = 1;
        } else if (!strcmp(a, "--threads")) {
            if (!pen_cli_parse_int(CMD, a, v, 0, 4096, &cfg->threads)) return 2;
            ++i;
        } else if (!strcmp(a, "--repeat")) {
            if (!pen_cli_parse_int(CMD, a, v, 1, MAX_REPEAT, &repeat)) return 2;
            ++i;
        } else if (!strcmp(a, "--warmup")) {
            if (!pen_cli_parse_int(CMD, a, v, 0, MAX_REPEAT, &warmup)) return 2;
            ++i;
        } else if (!strcmp(a, "--truth-spp")) {
            if (!pen_cli_parse_int(CMD, a, v, 1, PEN_REFERENCE_MAX_SPP, &truth)) return 2;
            ++i;
        } else if (!strcmp(a, "--case")) {
            if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
            if (cfg->only_count == MAX_CASES)
                return pen_cli_usage_error(CMD, "--case: at most %d", MAX_CASES);
            cfg->only[cfg->only_count++] = v, ++i;
        } else if (!strcmp(a, "--scene")) {
            if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
            cfg->scene_path = v, ++i;
        } else {
            const char *none[1] = {NULL};
            return pen_cli_positional(CMD, a, none, 0);
        }
    }
    cfg->repeat = repeat > 0 ? repeat : cfg->quick ? 3 : 10;
    cfg->warmup = warmup >= 0 ? warmup : cfg->quick ? 1 : 2;
    cfg->truth_spp = truth > 0 ? truth : cfg->quick ? 64 : 256;
    return -1;
}

int pen_cmd_bench(int argc, char **argv) {
    bench_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.reference = 1;
    const int rc = parse_args(argc, argv, &cfg);
    if (rc >= 0) return rc;

    bench_case cases[MAX_CASES];
    const int count = make_cases(cfg.quick, cases);
    for (int i = 0; i < cfg.only_count; ++i) {
        int known = 0;
        for (int k = 0; k < count; ++k)
            known |= !strcmp(cfg.only[i], cases[k].name);
        if (!known)
            return pen_cli_usage_error(CMD, "--case: no case '%s' (see --help; --quick divides "
                                            "the sizes in the names by 8)",
                                       cfg.only[i]);
    }
    char scene_buf[4096];
    if (!cfg.scene_path && !(cfg.scene_path = pen_cli_data_path(CMD, SCENE_REL, "use --scene",
                                                                 scene_buf, sizeof scene_buf)))
        return 1;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_context_set_threads(ctx, cfg.threads);
    if (cfg.no_cache) pen_context_set_fit_cache(ctx, 0);
    /* A scene that does not load fails before any output. */
    pen_scene probe;
    if (pen_scene_load(ctx, cfg.scene_path, &probe)) {
        const int s = pen_cli_fail_ctx(CMD, ctx);
        pen_context_destroy(ctx);
        return s;
    }
    pen_scene_free(&probe);
    truth_cache cache;
    memset(&cache, 0, sizeof cache);
    bench_result res[MAX_CASES];
    int ran[MAX_CASES] = {0}, status = 0;
    if (!cfg.json) print_table_header(&cfg);
    for (int i = 0; i < count && !status; ++i) {
        if (!selected(&cfg, cases[i].name)) continue;
        if (run_case(ctx, &cfg, &cases[i], &cache, &res[i])) {
            status = pen_cli_fail(CMD, "case %s: %s", cases[i].name, pen_context_error(ctx));
            break;
        }
        ran[i] = 1;
        if (cfg.json)
            print_json(&cfg, &cases[i], &res[i]);
        else
            print_table_row(&cases[i], &res[i]);
    }
    if (!status && !cfg.json) print_stage_table(cases, res, ran, count);
    truth_cache_free(&cache);
    pen_context_destroy(ctx);
    return status;
}
