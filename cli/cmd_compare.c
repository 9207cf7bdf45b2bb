/* penumbra compare: image error metrics as one JSON object on stdout (src/scene/metrics.c). */
#include "commands.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static const char *const CMD = "compare";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra compare A B [--mask M]\n\n"
            "Error of image A against the reference B (same size; .exr, .hdr or .png, linear):\n"
            "  {\"rmse\": ..., \"rel_rmse\": ..., \"psnr_db\": ..., \"pixels\": N,\n"
            "   \"mask\": {the same over the pixels where M is above 0.5}}   (with --mask)\n"
            "rel_rmse = rmse / rms(B); psnr_db = 10 log10(1 / mse) (peak 1). Values that are not\n"
            "finite (identical images: psnr; an empty mask: all) are printed as null.\n");
}

static void print_number(const char *key, double v, const char *sep) {
    if (isfinite(v))
        printf("\"%s\": %.9g%s", key, v, sep);
    else
        printf("\"%s\": null%s", key, sep);
}

static void print_error(const pen_image_error *e) {
    print_number("rmse", e->rmse, ", ");
    print_number("rel_rmse", e->rel_rmse, ", ");
    print_number("psnr_db", e->psnr_db, ", ");
    printf("\"pixels\": %lld", e->pixels);
}

static int load(pen_context *ctx, const char *path, pen_image *img) {
    if (pen_image_load(ctx, path, img) == PEN_OK) return 1;
    pen_cli_fail_ctx(CMD, ctx);
    return 0;
}

int pen_cmd_compare(int argc, char **argv) {
    const char *paths[2] = {NULL, NULL}, *mask_path = NULL;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (strcmp(a, "--mask") == 0) {
            if (i + 1 >= argc) return pen_cli_usage_error(CMD, "--mask needs a value");
            mask_path = argv[++i];
        } else if (pen_cli_positional(CMD, a, paths, 2)) {
            return 2;
        }
    }
    if (!paths[1]) return pen_cli_usage_error(CMD, "expected two images A and B");

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_image a = {0, 0, 0, NULL}, b = a, m = a;
    pen_image_error all, masked;
    int status = 1;
    if (load(ctx, paths[0], &a) && load(ctx, paths[1], &b) &&
        (!mask_path || load(ctx, mask_path, &m))) {
        if (mask_path && (m.width != a.width || m.height != a.height)) {
            /* the mask is the file at fault: its name first */
            pen_cli_fail(CMD, "%s: the mask is %dx%d but the images are %dx%d (%s)", mask_path,
                         m.width, m.height, a.width, a.height, paths[0]);
        } else if (pen_image_compare(ctx, &a, &b, mask_path ? &m : NULL, &all, &masked)) {
            /* Name the files: the library only knows them as A, B and mask. */
            if (mask_path)
                pen_cli_fail(CMD, "%s vs %s (mask %s): %s", paths[0], paths[1], mask_path,
                             pen_context_error(ctx));
            else
                pen_cli_fail(CMD, "%s vs %s: %s", paths[0], paths[1], pen_context_error(ctx));
        } else {
            printf("{");
            print_error(&all);
            if (mask_path) {
                printf(", \"mask\": {");
                print_error(&masked);
                printf("}");
            }
            printf("}\n");
            status = 0;
        }
    }
    pen_image_free(&a);
    pen_image_free(&b);
    pen_image_free(&m);
    pen_context_destroy(ctx);
    return status;
}
