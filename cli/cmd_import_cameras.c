/* penumbra import-cameras: a COLMAP text model or a NeRF-style transforms.json into the views
 * JSON (src/io/camera_sets.c, docs/file-formats.md "Views"). */
#include "commands.h"

#include <stdio.h>
#include <string.h>

static const char *const CMD = "import-cameras";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra import-cameras --colmap MODEL_DIR [--images DIR] -o VIEWS.json\n"
            "       penumbra import-cameras --transforms transforms.json -o VIEWS.json\n\n"
            "Writes the calibrated cameras of a dataset as a views file: {\"views\": [{\"camera\":\n"
            "{width, height, intrinsics, eye, target, up}, \"target\": IMAGE}, ...]}, image paths\n"
            "relative to VIEWS.json.\n"
            "  --colmap DIR      a COLMAP text model (cameras.txt, images.txt); PINHOLE and\n"
            "                    SIMPLE_PINHOLE cameras (undistort other models first); views sorted\n"
            "                    by image name\n"
            "  --images DIR      the folder of the model's images (default: MODEL_DIR)\n"
            "  --transforms F    a NeRF-style transforms.json (camera-to-world, OpenGL axes)\n"
            "  -o VIEWS.json     the output (written only when the whole import succeeded)\n"
            "Prints one JSON line: the number of views and the output.\n");
}

int pen_cmd_import_cameras(int argc, char **argv) {
    const char *colmap = NULL, *images = NULL, *transforms = NULL, *out_path = NULL;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        const char **slot = NULL;
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (strcmp(a, "--colmap") == 0) {
            slot = &colmap;
        } else if (strcmp(a, "--images") == 0) {
            slot = &images;
        } else if (strcmp(a, "--transforms") == 0) {
            slot = &transforms;
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0) {
            slot = &out_path;
        } else {
            return pen_cli_usage_error(CMD, "unexpected argument '%s'", a);
        }
        if (!v) return pen_cli_usage_error(CMD, "%s needs a value", a);
        *slot = v, ++i;
    }
    if (!colmap == !transforms)
        return pen_cli_usage_error(CMD, "give one of --colmap DIR and --transforms FILE");
    if (images && !colmap) return pen_cli_usage_error(CMD, "--images goes with --colmap");
    if (!out_path) return pen_cli_usage_error(CMD, "missing -o VIEWS.json");
    pen_cli_outputs outputs = {0};
    if (!pen_cli_outputs_add(&outputs, CMD, out_path)) return 1;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_camera_set set;
    int status = 0;
    pen_status s = colmap ? pen_camera_set_load_colmap(ctx, colmap, images, &set)
                          : pen_camera_set_load_transforms(ctx, transforms, &set);
    if (s) {
        status = pen_cli_fail_ctx(CMD, ctx);
    } else if (!pen_cli_outputs_keep(&outputs, CMD)) {
        status = 1;
    } else if (pen_camera_set_save_views(ctx, out_path, &set)) {
        status = pen_cli_fail_ctx(CMD, ctx);
    } else {
        printf("{\"views\": %d, \"output\": \"%s\"}\n", set.count, out_path);
    }
    pen_cli_outputs_end(&outputs, status == 0);
    pen_camera_set_free(&set);
    pen_context_destroy(ctx);
    return status;
}
