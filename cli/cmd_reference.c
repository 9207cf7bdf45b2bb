/* penumbra reference: the Embree Monte-Carlo ground truth of a scene (src/reference/). */
#include "commands.h"

#include <omp.h>
#include <stdio.h>
#include <string.h>

static const char *const CMD = "reference";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra reference SCENE.json -o OUT [--spp N] [--seed S]\n"
            "                          [--lighting envmap|sh|auto] [--threads N] [--coverage M]\n\n"
            "Ray-traced ground truth of the scene: the same camera, albedo and diffuse shading as\n"
            "`render`, with visibility traced against the real meshes and the ground plane.\n"
            "  -o OUT        output image: .exr or .hdr (linear) or .png (sRGB, 8-bit)\n"
            "  --spp N       camera samples per pixel (default 64)\n"
            "  --seed S      random seed, 0 .. 2147483647 (default 1); same seed, same image\n"
            "  --lighting L  envmap: the environment map itself (importance-sampled), plus the\n"
            "                disk lights the scene gives (those found in the map are in it);\n"
            "                sh: what `render` lights with: the SH part with the scene's\n"
            "                sh_bands (unclamped) plus every disk light, found or given;\n"
            "                auto (default): envmap when the scene's SH is its map's, else sh\n"
            "  --threads N   threads (default 0: all cores)\n"
            "  --coverage M  also write the fraction of each pixel's samples that hit a surface\n"
            "                (1-channel image; `compare --mask M` then leaves the background out)\n"
            "Both outputs are written, or neither (an existing file is kept on failure).\n"
            "Prints one JSON line: size, spp, lighting, threads and seconds.\n");
}

int pen_cmd_reference(int argc, char **argv) {
    const char *scene_path = NULL, *out_path = NULL, *cov_path = NULL;
    int spp = 64, seed = 1, threads = 0, lighting = PEN_REFERENCE_LIGHTING_AUTO;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0) {
            if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
            out_path = v, ++i;
        } else if (strcmp(a, "--coverage") == 0) {
            if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
            cov_path = v, ++i;
        } else if (strcmp(a, "--spp") == 0) {
            if (!pen_cli_parse_int(CMD, a, v, 1, PEN_REFERENCE_MAX_SPP, &spp)) return 2;
            ++i;
        } else if (strcmp(a, "--seed") == 0) {
            if (!pen_cli_parse_int(CMD, a, v, 0, 2147483647L, &seed)) return 2;
            ++i;
        } else if (strcmp(a, "--threads") == 0) {
            if (!pen_cli_parse_int(CMD, a, v, 0, 4096, &threads)) return 2;
            ++i;
        } else if (strcmp(a, "--lighting") == 0) {
            if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
            lighting = pen_reference_lighting_parse(v);
            if (lighting < 0)
                return pen_cli_usage_error(CMD, "--lighting: expected envmap, sh or auto, got '%s'",
                                           v);
            ++i;
        } else if (pen_cli_positional(CMD, a, &scene_path, 1)) {
            return 2;
        }
    }
    if (!scene_path) return pen_cli_usage_error(CMD, "missing SCENE.json");
    if (!out_path) return pen_cli_usage_error(CMD, "missing -o OUT");
    if (!pen_image_path_supported(out_path))
        return pen_cli_usage_error(CMD, "%s: the output must end in .exr, .hdr or .png", out_path);
    if (cov_path && !pen_image_path_supported(cov_path))
        return pen_cli_usage_error(CMD, "%s: the coverage must end in .exr, .hdr or .png",
                                   cov_path);
    pen_cli_outputs outputs = {0}; /* checked before the (long) render */
    if (!pen_cli_outputs_add(&outputs, CMD, out_path) ||
        (cov_path && !pen_cli_outputs_add(&outputs, CMD, cov_path)))
        return 1;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_context_set_threads(ctx, threads);
    pen_scene scene;
    pen_reference *ref = NULL;
    pen_image img = {0, 0, 0, NULL}, cov = img;
    int status = 0;
    if (pen_scene_load(ctx, scene_path, &scene)) {
        status = pen_cli_fail_ctx(CMD, ctx);
        pen_context_destroy(ctx);
        return status;
    }
    double t0 = omp_get_wtime();
    if (pen_reference_create(ctx, &scene, (pen_reference_lighting)lighting, &ref) ||
        pen_reference_render_coverage(ctx, ref, spp, (uint64_t)seed, &img,
                                      cov_path ? &cov : NULL)) {
        status = pen_cli_fail_ctx(CMD, ctx);
    } else {
        double seconds = omp_get_wtime() - t0;
        /* All or nothing: a failed write puts back the files the paths held before. */
        if (!pen_cli_outputs_keep(&outputs, CMD)) {
            status = 1;
        } else if (cov_path && pen_image_save(ctx, cov_path, &cov)) {
            status = pen_cli_fail_ctx(CMD, ctx);
        } else if (pen_image_save(ctx, out_path, &img)) {
            status = pen_cli_fail_ctx(CMD, ctx);
        } else {
            printf("{\"output\": \"%s\", \"width\": %d, \"height\": %d, \"spp\": %d, \"seed\": %d, "
                   "\"lighting\": \"%s\", \"threads\": %d, \"seconds\": %.3f}\n",
                   out_path, img.width, img.height, spp, seed,
                   pen_reference_lighting_name(pen_reference_lighting_mode(ref)),
                   threads > 0 ? threads : omp_get_max_threads(), seconds);
        }
    }
    pen_cli_outputs_end(&outputs, status == 0);
    pen_image_free(&img);
    pen_image_free(&cov);
    pen_reference_destroy(ref);
    pen_scene_free(&scene);
    pen_context_destroy(ctx);
    return status;
}
