/* Writes the binary seeds of fuzz/corpus that only the library can make (see docs/reliability.md):
 * downsampled copies of the bundled maps and textures (the bundled files are 0.1 to 1.5 MB;
 * the corpus stays small), JPEG variants of the textures (the library reads JPEG but writes none:
 * libjpeg encodes them here) and checkpoints of the checkpoint harness's fixed identity.
 *     build/fuzz/fuzz_make_seeds SOURCE_DIR    (writes into SOURCE_DIR/fuzz/corpus)
 * Not a test: rerun by hand when a format changes (e.g. the checkpoint version). */
#define _POSIX_C_SOURCE 200809L
#include "optim/optim_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <math.h>
#include <string.h>

#include <jpeglib.h>

static pen_context *ctx;
static const char *root;

static void die(void) {
    fprintf(stderr, "fuzz_make_seeds: %s\n", pen_context_error(ctx));
    exit(1);
}

/* The box-filtered w x h version of the bundled image `src`. */
static pen_image box_filtered(const char *src, int w, int h) {
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", root, src);
    pen_image in, small;
    if (pen_image_load(ctx, path, &in) || pen_image_create(ctx, w, h, 3, &small)) die();
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) {
                int x0 = x * in.width / w, x1 = (x + 1) * in.width / w;
                int y0 = y * in.height / h, y1 = (y + 1) * in.height / h;
                double sum = 0;
                for (int yy = y0; yy < y1; ++yy)
                    for (int xx = x0; xx < x1; ++xx)
                        sum += (double)in.data[3 * ((size_t)yy * (size_t)in.width + (size_t)xx) +
                                               (size_t)c];
                small.data[3 * (y * w + x) + c] = (float)(sum / ((x1 - x0) * (y1 - y0)));
            }
    pen_image_free(&in);
    return small;
}

/* The box-filtered w x h version of the bundled image `src`, saved as corpus/<out>. */
static void shrink(const char *src, int w, int h, const char *out) {
    pen_image small = box_filtered(src, w, h);
    char path[1024];
    snprintf(path, sizeof path, "%s/fuzz/corpus/%s", root, out);
    if (pen_image_save(ctx, path, &small)) die();
    pen_image_free(&small);
}

/* The box-filtered w x h version of the bundled 8-bit texture `src` as a JPEG in corpus/jpeg:
 * `grey` one component, else YCbCr with chroma subsampled `sub` times in each direction;
 * `progressive` a progressive scan script; `restart` a restart marker every that many MCU rows
 * (0: none). Values are the texture's own sRGB bytes (pen_image holds them linearised). */
static void jpeg_seed(const char *src, int w, int h, int grey, int sub, int progressive,
                      int restart, int quality, const char *out) {
    pen_image small = box_filtered(src, w, h);
    char path[1024];
    snprintf(path, sizeof path, "%s/fuzz/corpus/jpeg/%s", root, out);
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "fuzz_make_seeds: cannot write %s\n", path);
        exit(1);
    }
    struct jpeg_compress_struct c;
    struct jpeg_error_mgr e;
    c.err = jpeg_std_error(&e);
    jpeg_create_compress(&c);
    jpeg_stdio_dest(&c, f);
    c.image_width = (JDIMENSION)w;
    c.image_height = (JDIMENSION)h;
    c.input_components = grey ? 1 : 3;
    c.in_color_space = grey ? JCS_GRAYSCALE : JCS_RGB;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, quality, TRUE);
    if (!grey) c.comp_info[0].h_samp_factor = c.comp_info[0].v_samp_factor = sub;
    if (progressive) jpeg_simple_progression(&c);
    c.restart_in_rows = restart;
    jpeg_start_compress(&c, TRUE);
    unsigned char *row = malloc((size_t)w * 3);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
            const float *p = small.data + 3 * ((size_t)y * (size_t)w + (size_t)x);
            for (int k = 0; k < 3; ++k) {
                float v = p[k] <= 0.0031308f ? 12.92f * p[k]
                                             : 1.055f * powf(p[k], 1.0f / 2.4f) - 0.055f;
                row[grey ? x : 3 * x + k] = (unsigned char)(fminf(fmaxf(v, 0.0f), 1.0f) * 255.0f + 0.5f);
                if (grey) break;
            }
        }
        JSAMPROW r = row;
        jpeg_write_scanlines(&c, &r, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    free(row);
    fclose(f);
    pen_image_free(&small);
}

/* A checkpoint of fuzz_checkpoint.c's identity (kept equal to it by hand) after `iteration`
 * steps. */
static void checkpoint(int iteration, const char *out) {
    enum { N = 6 };
    static const pen__optim_segment segments[] = {{0, 3, 1.0f, PEN__BOUND_UNIT},
                                                  {3, 3, 1.0f, PEN__BOUND_NONE}};
    const pen__optim_identity id = {
        .n = N, .segments = segments, .segment_count = 2, .groups = PEN_OPTIM_LIGHTING,
        .loss = PEN_OPTIM_LOSS_L2, .shadows = 1, .width = 8, .height = 8, .shadow_weight = 0.0,
        .lighting_solver = PEN_OPTIM_LIGHTING_ADAM, .lighting_ridge = 0.0, .graph_k = 0,
        .weights = {0.0, 0.0, 0.0}, .target_hash = 0x1234u, .init_hash = 0x5678u,
        .ridge_views = 2, .scene_hash = 0x9abcu};
    float x[N], best[N], m[N], v[N];
    double losses[64];
    for (int i = 0; i < N; ++i) {
        x[i] = 0.1f * (float)i;
        best[i] = 0.05f * (float)i;
        m[i] = 0.01f;
        v[i] = 0.001f;
    }
    for (int i = 0; i <= iteration; ++i)
        losses[i] = 1.0 / (1.0 + i);
    pen__adam adam = {.n = N, .m = m, .v = v, .t = iteration};
    pen__optim_state st = {.iteration = iteration, .recorded = iteration + 1,
                           .best_iteration = iteration, .best_loss = losses[iteration],
                           .seconds = 1.5, .x = x, .best = best, .adam = &adam,
                           .losses = losses};
    char path[1024];
    snprintf(path, sizeof path, "%s/fuzz/corpus/checkpoint/%s", root, out);
    if (pen__optim_checkpoint_save(ctx, path, &id, &st)) die();
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: fuzz_make_seeds SOURCE_DIR\n");
        return 2;
    }
    root = argv[1];
    ctx = pen_context_create();
    shrink("data/envmaps/city.hdr", 64, 32, "hdr/city_64x32.hdr");
    shrink("data/envmaps/interior.hdr", 16, 8, "hdr/interior_16x8.hdr");
    shrink("data/envmaps/city.exr", 32, 16, "exr/city_32x16.exr");
    shrink("data/envmaps/interior.exr", 8, 4, "exr/interior_8x4.exr");
    shrink("data/meshes/spot_texture.png", 32, 32, "png/spot_texture_32.png");
    shrink("data/meshes/bob_diffuse.png", 16, 16, "png/bob_diffuse_16.png");
    jpeg_seed("data/meshes/spot_texture.png", 16, 16, 0, 1, 0, 0, 90, "spot_16_444.jpg");
    jpeg_seed("data/meshes/spot_texture.png", 17, 9, 0, 2, 0, 0, 70, "spot_17x9_420.jpg");
    jpeg_seed("data/meshes/bob_diffuse.png", 24, 8, 0, 2, 1, 0, 80, "bob_24x8_progressive.jpg");
    jpeg_seed("data/meshes/bob_diffuse.png", 8, 8, 1, 1, 0, 0, 95, "bob_8_grey.jpg");
    jpeg_seed("data/meshes/spot_texture.png", 32, 16, 0, 2, 0, 1, 60, "spot_32x16_restart.jpg");
    checkpoint(0, "iter0.bin");
    checkpoint(4, "iter4.bin");
    checkpoint(20, "iter20.bin");
    pen_context_destroy(ctx);
    return 0;
}
