/* Float images and their files: PNG (8/16-bit, sRGB), JPEG (8-bit sRGB, read only), Radiance HDR
 * (RGBE), OpenEXR (float).
 *
 * Reading: every file is distrusted, and each format goes to a decoder that is safe on any bytes,
 * chosen per format (the decoders' files say more):
 *  - Radiance .hdr: our own strict reader (image_hdr.c). Debian's stb hangs on truncated
 *    run-length data and reads uninitialised memory on truncated flat data; the format is small
 *    enough that a bounded reader is simpler than validating the stream for stb.
 *  - PNG: libpng (image_png.c), which verifies chunk CRCs and the zlib checksum; palette indices
 *    are checked there. stb checks neither.
 *  - JPEG: libjpeg-turbo (image_jpeg.c) with its error exits caught and its warnings fatal.
 *  - OpenEXR: OpenEXR's C++ library (exr.cpp), its exceptions turned into one error line.
 * Every decoder checks the header's size against PEN_IMAGE_MAX_DIM and PEN__IMAGE_MAX_PIXELS
 * before it allocates pixels, the magic bytes must match the extension, and loaded values must
 * be finite. Loading always yields 3 channels (grey is replicated, alpha dropped).
 * pen__image_decode takes the bytes from memory (every format), so a fuzzer needs no files.
 *
 * Writing: PNG and HDR through stb_image_write (it only ever sees our own checked pixels), EXR
 * through exr.cpp. Saving refuses NaN/Inf and writes a temporary file that is renamed into place.
 *
 * sRGB: the IEC 61966-2-1 curve; decoding is in image_pixels.c, encoding here rounds to the
 * nearest 8-bit code after clamping to [0, 1]. */
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <errno.h>
#include <limits.h>
#include <stb_image_write.h>
#include <stdlib.h>
#include <string.h>

#define IMAGE_MAX_FILE_BYTES ((size_t)INT_MAX) /* far above what the pixel budget admits */

static double linear_to_srgb(double c) {
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

/* ---- Loading --------------------------------------------------------------------------------- */

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

static int is_jpeg_name(const char *name) {
    return pen__io_has_ext(name, "jpg") || pen__io_has_ext(name, "jpeg");
}

/* The extensions pen_image_load reads; anything else is refused before the file is read. */
static pen_status check_readable(pen_context *ctx, const char *name) {
    if (pen__io_has_ext(name, "png") || pen__io_has_ext(name, "hdr") ||
        pen__io_has_ext(name, "exr") || is_jpeg_name(name))
        return PEN_OK;
    return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                      "%s: unknown image format (expected .png, .hdr, .exr, .jpg or .jpeg)", name);
}

pen_status pen__image_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                             size_t size, unsigned flags, pen_image *out) {
    memset(out, 0, sizeof *out);
    int raw = (flags & PEN_IMAGE_LOAD_RAW) != 0;
    pen_status s = check_readable(ctx, name);
    if (s) return s;
    if (pen__io_has_ext(name, "png"))
        s = pen__png_decode(ctx, name, bytes, size, raw, out);
    else if (pen__io_has_ext(name, "hdr"))
        s = pen__hdr_decode(ctx, name, bytes, size, out);
    else if (is_jpeg_name(name))
        s = pen__jpeg_decode(ctx, name, bytes, size, raw, out);
    else
        s = pen__exr_decode(ctx, name, bytes, size, out);
    if (!s) s = check_finite(ctx, PEN_ERROR_PARSE, name, out);
    if (s) pen_image_free(out);
    return s;
}

/* OpenEXR reports a missing file as just another exception: open it first so that a missing or
 * unreadable file is an i/o error like everywhere else. */
static pen_status exr_load(pen_context *ctx, const char *path, pen_image *out) {
    FILE *f = fopen(path, "rb");
    if (!f) return pen__error(ctx, PEN_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    fclose(f);
    pen_status s = pen__exr_load(ctx, path, out);
    if (!s) s = check_finite(ctx, PEN_ERROR_PARSE, path, out);
    if (s) pen_image_free(out);
    return s;
}

pen_status pen_image_load_ex(pen_context *ctx, const char *path, unsigned flags, pen_image *out) {
    memset(out, 0, sizeof *out);
    pen_status s = check_readable(ctx, path);
    if (s) return s;
    if (pen__io_has_ext(path, "exr")) return exr_load(ctx, path, out);
    char *data = NULL;
    size_t size = 0;
    s = pen__io_read_file(ctx, path, IMAGE_MAX_FILE_BYTES, &data, &size);
    if (!s) s = pen__image_decode(ctx, path, (const unsigned char *)data, size, flags, out);
    free(data);
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
