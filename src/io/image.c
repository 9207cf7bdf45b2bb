/* Float images and their files: PNG (8/16-bit, sRGB), Radiance HDR (RGBE), OpenEXR (float).
 *
 * PNG and HDR go through stb_image / stb_image_write (Debian's compiled libstb), EXR through
 * OpenEXR's C++ library (exr.cpp). Every file is distrusted: the header's size is checked against
 * PEN_IMAGE_MAX_DIM before pixels are decoded, the magic bytes must match the extension, and
 * loaded pixels must be finite. Loading always yields 3 channels (grey is replicated, alpha
 * dropped). Saving refuses NaN/Inf and writes a temporary file that is renamed into place.
 *
 * sRGB: the IEC 61966-2-1 curve, decoded exactly (a table for 8-bit, the formula for 16-bit) and
 * encoded with rounding to the nearest 8-bit code after clamping to [0, 1]. */
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <errno.h>
#include <limits.h>
#include <stb_image.h>
#include <stb_image_write.h>
#include <stdlib.h>
#include <string.h>

#define IMAGE_MAX_FILE_BYTES ((size_t)INT_MAX) /* stb takes an int length */

/* ---- sRGB ------------------------------------------------------------------------------------ */

static double srgb_to_linear(double c) {
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

static double linear_to_srgb(double c) {
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

/* ---- Loading --------------------------------------------------------------------------------- */

/* Converts n decoded pixels of `comp` 8- or 16-bit components (1 grey, 2 grey + alpha, 3 RGB,
 * 4 RGBA; alpha is dropped, grey replicated) into 3-channel floats, decoding sRGB unless raw. */
static void to_rgb(const void *src, int is16, int comp, size_t n, int raw, float *dst) {
    float table[256];
    for (int i = 0; i < 256; ++i)
        table[i] = raw ? (float)(i / 255.0) : (float)srgb_to_linear(i / 255.0);
    int colour = comp >= 3 ? 3 : 1;
    for (size_t p = 0; p < n; ++p) {
        for (int c = 0; c < 3; ++c) {
            size_t k = p * (size_t)comp + (size_t)(colour == 3 ? c : 0);
            float v;
            if (is16) {
                double x = ((const unsigned short *)src)[k] / 65535.0;
                v = (float)(raw ? x : srgb_to_linear(x));
            } else {
                v = table[((const unsigned char *)src)[k]];
            }
            dst[3 * p + (size_t)c] = v;
        }
    }
}

static int has_magic(const char *data, size_t size, const char *magic, size_t n) {
    return size >= n && memcmp(data, magic, n) == 0;
}

/* PNG or HDR through stb, after checking the magic and the header's size. */
static pen_status load_stb(pen_context *ctx, const char *path, int hdr, int raw, pen_image *out) {
    char *data = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, IMAGE_MAX_FILE_BYTES, &data, &size);
    if (s) return s;
    const stbi_uc *bytes = (const stbi_uc *)data;
    int len = (int)size, w = 0, h = 0, comp = 0;
    if (hdr ? !(has_magic(data, size, "#?RADIANCE\n", 11) || has_magic(data, size, "#?RGBE\n", 7))
            : !has_magic(data, size, "\x89PNG\r\n\x1a\n", 8))
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: not a %s file (bad magic bytes)", path,
                       hdr ? "Radiance HDR" : "PNG");
    else if (!stbi_info_from_memory(bytes, len, &w, &h, &comp))
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: unreadable header (%s)", path,
                       stbi_failure_reason());
    else if (w < 1 || h < 1 || w > PEN_IMAGE_MAX_DIM || h > PEN_IMAGE_MAX_DIM)
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: image size %d x %d outside [1, %d]", path, w, h,
                       PEN_IMAGE_MAX_DIM);
    else
        s = pen_image_create(ctx, w, h, 3, out);
    if (!s) {
        int is16 = !hdr && stbi_is_16_bit_from_memory(bytes, len);
        void *px = hdr    ? (void *)stbi_loadf_from_memory(bytes, len, &w, &h, &comp, 3)
                   : is16 ? (void *)stbi_load_16_from_memory(bytes, len, &w, &h, &comp, 0)
                          : (void *)stbi_load_from_memory(bytes, len, &w, &h, &comp, 0);
        if (!px || w != out->width || h != out->height) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: cannot decode (%s)", path,
                           px ? "size changed" : stbi_failure_reason());
        } else if (hdr) {
            memcpy(out->data, px, (size_t)w * (size_t)h * 3 * sizeof(float));
        } else {
            to_rgb(px, is16, comp, (size_t)w * (size_t)h, raw, out->data);
        }
        stbi_image_free(px);
    }
    free(data);
    if (s) pen_image_free(out);
    return s;
}

static pen_status check_finite(pen_context *ctx, pen_status status, const char *path,
                               const pen_image *im) {
    size_t n = (size_t)im->width * (size_t)im->height * (size_t)im->channels;
    for (size_t i = 0; i < n; ++i) {
        if (!isfinite(im->data[i])) {
            size_t p = i / (size_t)im->channels;
            return pen__error(ctx, status, "%s: pixel (%zu, %zu) channel %zu is %s", path,
                              p % (size_t)im->width, p / (size_t)im->width,
                              i % (size_t)im->channels, isnan(im->data[i]) ? "NaN" : "infinite");
        }
    }
    return PEN_OK;
}

/* OpenEXR reports a missing file as just another exception: open it first so that a missing or
 * unreadable file is an i/o error like everywhere else. */
static pen_status exr_load(pen_context *ctx, const char *path, pen_image *out) {
    FILE *f = fopen(path, "rb");
    if (!f) return pen__error(ctx, PEN_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    fclose(f);
    return pen__exr_load(ctx, path, out);
}

pen_status pen_image_load_ex(pen_context *ctx, const char *path, unsigned flags, pen_image *out) {
    memset(out, 0, sizeof *out);
    int raw = (flags & PEN_IMAGE_LOAD_RAW) != 0;
    pen_status s;
    if (pen__io_has_ext(path, "png"))
        s = load_stb(ctx, path, 0, raw, out);
    else if (pen__io_has_ext(path, "hdr"))
        s = load_stb(ctx, path, 1, raw, out);
    else if (pen__io_has_ext(path, "exr"))
        s = exr_load(ctx, path, out);
    else
        return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                          "%s: unknown image format (expected .png, .hdr or .exr)", path);
    if (!s) s = check_finite(ctx, PEN_ERROR_PARSE, path, out);
    if (s) pen_image_free(out);
    return s;
}

pen_status pen_image_load(pen_context *ctx, const char *path, pen_image *out) {
    return pen_image_load_ex(ctx, path, 0, out);
}

/* ---- Saving ---------------------------------------------------------------------------------- */

typedef struct sink {
    FILE *f;
    int failed;
} sink;

static void sink_write(void *context, void *data, int size) {
    sink *k = context;
    if (size > 0 && fwrite(data, 1, (size_t)size, k->f) != (size_t)size) k->failed = 1;
}

/* 8-bit sRGB (colour channels) or linear (alpha: channel 2 of 2, channel 4 of 4). */
static unsigned char *encode_png(pen_context *ctx, const pen_image *im) {
    size_t n = (size_t)im->width * (size_t)im->height * (size_t)im->channels;
    unsigned char *px = pen__malloc(ctx, n, 1, "PNG pixels");
    if (!px) return NULL;
    int alpha = im->channels == 2 || im->channels == 4;
    for (size_t i = 0; i < n; ++i) {
        double v = im->data[i];
        v = v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v;
        int is_alpha = alpha && (int)(i % (size_t)im->channels) == im->channels - 1;
        px[i] = (unsigned char)(255.0 * (is_alpha ? v : linear_to_srgb(v)) + 0.5);
    }
    return px;
}

static pen_status save_stb(pen_context *ctx, const char *path, const char *tmp, const pen_image *im,
                           int hdr) {
    FILE *f = fopen(tmp, "wb");
    if (!f) return pen__error(ctx, PEN_ERROR_IO, "%s: cannot write", path);
    sink k = {f, 0};
    int ok;
    if (hdr) {
        ok = stbi_write_hdr_to_func(sink_write, &k, im->width, im->height, im->channels, im->data);
    } else {
        unsigned char *px = encode_png(ctx, im);
        if (!px) {
            fclose(f);
            return PEN_ERROR_MEMORY;
        }
        ok = stbi_write_png_to_func(sink_write, &k, im->width, im->height, im->channels, px,
                                    im->width * im->channels);
        free(px);
    }
    if (fclose(f) != 0) ok = 0;
    if (!ok || k.failed) return pen__error(ctx, PEN_ERROR_IO, "%s: write error", path);
    return PEN_OK;
}

pen_status pen_image_save(pen_context *ctx, const char *path, const pen_image *image) {
    if (!image || !image->data || image->width < 1 || image->height < 1 ||
        image->width > PEN_IMAGE_MAX_DIM || image->height > PEN_IMAGE_MAX_DIM ||
        image->channels < 1 || image->channels > 4)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: invalid image to save", path);
    int kind = pen__io_has_ext(path, "png")   ? 0
               : pen__io_has_ext(path, "hdr") ? 1
               : pen__io_has_ext(path, "exr") ? 2
                                              : -1;
    if (kind < 0)
        return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                          "%s: unknown image format (expected .png, .hdr or .exr)", path);
    pen_status s = check_finite(ctx, PEN_ERROR_ARGUMENT, path, image);
    if (s) return s;
    char *tmp = NULL;
    s = pen__io_temp_create(ctx, path, &tmp);
    if (s) return s;
    s = kind == 2 ? pen__exr_save(ctx, path, tmp, image)
                  : save_stb(ctx, path, tmp, image, kind == 1);
    if (s) {
        pen__io_temp_discard(tmp);
        return s;
    }
    return pen__io_temp_commit(ctx, tmp, path);
}

int pen_image_path_supported(const char *path) {
    return path && (pen__io_has_ext(path, "png") || pen__io_has_ext(path, "hdr") ||
                    pen__io_has_ext(path, "exr"));
}
