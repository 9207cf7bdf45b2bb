/* penumbra render: the SH-shadow render of a scene JSON into a PNG (sRGB), EXR or HDR (linear).
 * The scene is made ready by pen_scene_prepare, the call every door makes: objects whose spheres
 * are {"fit": N} get a fitted set first (cached in the user's cache folder and reused); each
 * fit's metrics are printed, then the disk lights found in the map (or given) and, on stderr, the
 * scene's likely mistakes (pen_scene_check: the camera inside an object, an object tiny or huge
 * against the ground, a material library or texture missing). */
#include "commands.h"

#include "penumbra/fit.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

static const char *const CMD = "render";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra render SCENE.json -o OUT.(png|exr|hdr) [options]\n\n"
            "Renders the scene with soft shadows from its sphere sets (SH visibility) and writes\n"
            "the image: .png is 8-bit sRGB, .exr and .hdr are linear radiance. By default an\n"
            "object's own shadows and its shadows on the ground come from its mesh instead,\n"
            "ray traced once (\"shadow\": {\"self\", \"ground_shadow\"}). Objects with\n"
            "\"spheres\": {\"fit\": N} get N fitted spheres first (seconds per object; the fit\n"
            "is cached in $XDG_CACHE_HOME/penumbra, else ~/.cache/penumbra, and reused).\n\n"
            "Options:\n"
            "  -o, --output PATH   output image (required)\n"
            "  --no-shadows        visibility 1 everywhere (unshadowed SH irradiance)\n"
            "  --no-antialias      no silhouette antialiasing\n"
            "  --threads N         worker threads (default: all cores)\n"
            "  --no-cache          fit {\"fit\": N} spheres afresh, without reading or writing\n"
            "                      the fit cache (also PENUMBRA_NO_CACHE=1)\n"
            "  --mask PATH         also write the object mask (1 where an object is visible,\n"
            "                      0 for ground and background; .png, .exr or .hdr)\n"
            "  --depth PATH        also write the view depth of the visible point (0 for the\n"
            "                      background; .exr or .hdr: PNG would clamp it)\n"
            "  --normals PATH      also write the world normals of the visible surface (.exr:\n"
            "                      in [-1, 1]; .png: (n + 1) / 2, a normal map; 0 for background)\n"
            "  -q, --quiet         do not print the summary line\n");
}

/* Whether path ends in ext (".png", ".exr"; any case). */
static int ends_with(const char *path, const char *ext) {
    const size_t n = strlen(path), e = strlen(ext);
    return n >= e && !strcasecmp(path + n - e, ext);
}
static int is_png(const char *path) { return ends_with(path, ".png"); }
static int is_exr(const char *path) { return ends_with(path, ".exr"); }

/* The --mask/--depth/--normals images of the forward kept in st, saved to their paths (NULL:
 * not asked for). The outputs were checked and kept by the caller. */
static int save_aovs(pen_context *ctx, const pen_render_state *st, const char *mask_path,
                     const char *depth_path, const char *normals_path) {
    pen_image mask = {0, 0, 0, NULL}, depth = {0, 0, 0, NULL}, normals = {0, 0, 0, NULL};
    pen_status s = pen_render_state_aovs(ctx, st, mask_path ? &mask : NULL,
                                         depth_path ? &depth : NULL,
                                         normals_path ? &normals : NULL);
    /* A PNG holds [0, 1]: a normal map stores (n + 1) / 2. */
    const size_t nn = 3 * (size_t)normals.width * (size_t)normals.height;
    if (!s && normals_path && is_png(normals_path))
        for (size_t i = 0; i < nn; ++i)
            normals.data[i] = 0.5f * (normals.data[i] + 1.0f);
    if (!s && mask_path) s = pen_image_save(ctx, mask_path, &mask);
    if (!s && depth_path) s = pen_image_save(ctx, depth_path, &depth);
    if (!s && normals_path) s = pen_image_save(ctx, normals_path, &normals);
    pen_image_free(&mask), pen_image_free(&depth), pen_image_free(&normals);
    return s == PEN_OK;
}

int pen_cmd_render(int argc, char **argv) {
    const char *scene_path = NULL, *out_path = NULL;
    const char *mask_path = NULL, *depth_path = NULL, *normals_path = NULL;
    int threads = 0, quiet = 0, no_cache = 0;
    pen_render_options opt = pen_render_options_default();
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            if (++i >= argc) return pen_cli_usage_error(CMD, "%s needs a value", a);
            out_path = argv[i];
        } else if (!strcmp(a, "--mask") || !strcmp(a, "--depth") || !strcmp(a, "--normals")) {
            if (++i >= argc) return pen_cli_usage_error(CMD, "%s needs a value", a);
            *(a[2] == 'm' ? &mask_path : a[2] == 'd' ? &depth_path : &normals_path) = argv[i];
        } else if (!strcmp(a, "--no-shadows")) {
            opt.shadows = 0;
        } else if (!strcmp(a, "--no-antialias")) {
            opt.antialias = 0;
        } else if (!strcmp(a, "--threads")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 1, 4096, &threads))
                return 2;
        } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (!strcmp(a, "--no-cache")) {
            no_cache = 1;
        } else if (pen_cli_positional(CMD, a, &scene_path, 1)) {
            return 2;
        }
    }
    if (!scene_path) return pen_cli_usage_error(CMD, "missing SCENE.json");
    if (!out_path) return pen_cli_usage_error(CMD, "missing -o OUT.(png|exr|hdr)");
    if (!pen_image_path_supported(out_path))
        return pen_cli_usage_error(CMD, "%s: the output must end in .png, .exr or .hdr", out_path);
    const char *const aov_paths[3] = {mask_path, depth_path, normals_path};
    for (int k = 0; k < 3; ++k)
        if (aov_paths[k] && !pen_image_path_supported(aov_paths[k]))
            return pen_cli_usage_error(CMD, "%s: the output must end in .png, .exr or .hdr",
                                       aov_paths[k]);
    if (depth_path && is_png(depth_path))
        return pen_cli_usage_error(CMD, "%s: depth needs .exr or .hdr (a PNG holds [0, 1])",
                                   depth_path);
    if (normals_path && !is_png(normals_path) && !is_exr(normals_path))
        return pen_cli_usage_error(CMD, "%s: normals need .exr or .png (HDR drops negative "
                                   "values)", normals_path);
    /* Checked before the fits and the render; written atomically by pen_image_save, and as a
     * set: a failure leaves every existing output as it was. */
    pen_cli_outputs outputs = {0};
    if (!pen_cli_outputs_add(&outputs, CMD, out_path)) return 1;
    for (int k = 0; k < 3; ++k)
        if (aov_paths[k] && !pen_cli_outputs_add(&outputs, CMD, aov_paths[k])) return 1;
    const int aovs = mask_path || depth_path || normals_path;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_context_set_threads(ctx, threads);
    if (no_cache) pen_context_set_fit_cache(ctx, 0);
    pen_scene scene;
    pen_image image = {0, 0, 0, NULL};
    int rc = 1;
    if (pen_scene_load(ctx, scene_path, &scene)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_ctx;
    }
    /* The scene made ready as every door makes it (pen_scene_prepare): fits, cache, weights. */
    pen_fit_metrics *fits = calloc(scene.object_count > 0 ? (size_t)scene.object_count : 1,
                                   sizeof *fits);
    if (!fits) {
        rc = pen_cli_fail(CMD, "out of memory");
        goto out_scene;
    }
    const pen_status prepared = pen_scene_prepare(ctx, &scene, opt.shadows, fits);
    int spheres = 0;
    for (int o = 0; !prepared && o < scene.object_count; ++o) {
        const pen_object *ob = &scene.objects[o];
        if (!quiet && ob->fit_spheres > 0 && opt.shadows)
            printf("objects[%d]: %d fitted spheres (%s, surface coverage %.3f)\n", o,
                   ob->spheres.count, fits[o].from_cache ? "from the cache" : "fitted now",
                   fits[o].surface_coverage);
        spheres += ob->spheres.count;
    }
    free(fits);
    if (prepared) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_scene;
    }
    /* What the user should know before looking at the image: likely mistakes on stderr (even
     * with -q), the disk lights that cast the main shadows on stdout. */
    pen_scene_report report;
    if (pen_scene_check(ctx, &scene, &report)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_scene;
    }
    pen_cli_print_warnings(CMD, &report);
    if (!quiet) pen_cli_print_lights(stdout, &scene, &report, "");
    pen_scene_report_free(&report);
    const double t0 = omp_get_wtime();
    pen_render_state *state = NULL; /* kept only for the --mask/--depth/--normals images */
    if ((aovs && pen_render_state_create(ctx, &state)) ||
        pen_render_fwd(ctx, &scene, &opt, state, &image)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        pen_render_state_free(state);
        goto out_scene;
    }
    const double seconds = omp_get_wtime() - t0;
    if (!pen_cli_outputs_keep(&outputs, CMD)) {
        pen_render_state_free(state);
        goto out_image;
    }
    const int saved = !pen_image_save(ctx, out_path, &image) &&
                      (!aovs || save_aovs(ctx, state, mask_path, depth_path, normals_path));
    pen_render_state_free(state);
    pen_cli_outputs_end(&outputs, saved);
    if (!saved) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_image;
    }
    if (!quiet)
        printf("%s: %dx%d, %d objects, %d spheres, %s, %.3f s\n", out_path, image.width,
               image.height, scene.object_count, spheres, opt.shadows ? "shadows" : "no shadows",
               seconds);
    rc = 0;
out_image:
    pen_image_free(&image);
out_scene:
    pen_scene_free(&scene);
out_ctx:
    pen_context_destroy(ctx);
    return rc;
}
