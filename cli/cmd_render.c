/* penumbra render: the SH-shadow render of a scene JSON into a PNG (sRGB), EXR or HDR (linear).
 * The scene is made ready by pen_scene_prepare, the call every door makes: objects whose spheres
 * are {"fit": N} get a fitted set first (cached in the user's cache folder and reused); each
 * fit's metrics are printed. */
#include "commands.h"

#include "penumbra/fit.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
            "  -q, --quiet         do not print the summary line\n");
}

int pen_cmd_render(int argc, char **argv) {
    const char *scene_path = NULL, *out_path = NULL;
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
    /* Checked before the fits and the render; one output, written atomically by pen_image_save,
     * so a failure leaves an existing file as it was without keeping a second name. */
    pen_cli_outputs outputs = {0};
    if (!pen_cli_outputs_add(&outputs, CMD, out_path)) return 1;

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
    const double t0 = omp_get_wtime();
    if (pen_render_fwd(ctx, &scene, &opt, NULL, &image)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_scene;
    }
    const double seconds = omp_get_wtime() - t0;
    if (pen_image_save(ctx, out_path, &image)) {
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
