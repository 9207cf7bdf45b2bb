/* Pieces every image decoder shares: the size limits checked before pixels are allocated, and
 * integer samples turned into linear floats.
 *
 * Limits: each side within PEN_IMAGE_MAX_DIM and the whole image within PEN__IMAGE_MAX_PIXELS.
 * A compressed file is tiny next to what it expands to (a 780 KB PNG can declare 16384^2 pixels,
 * 3 GiB of floats), so the file size bounds nothing: the header's size alone is judged, before
 * the first allocation.
 *
 * sRGB: the IEC 61966-2-1 curve, decoded exactly (a table for 8-bit codes, the formula for 16-bit
 * ones), so that every 8-bit code decodes to the same float whatever the decoder. */
#include "io/io_internal.h"

pen_status pen__image_check_size(pen_context *ctx, const char *name, long long width,
                                 long long height) {
    if (width < 1 || height < 1 || width > PEN_IMAGE_MAX_DIM || height > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: image size %lld x %lld outside [1, %d]", name,
                          width, height, PEN_IMAGE_MAX_DIM);
    if (width * height > PEN__IMAGE_MAX_PIXELS)
        return pen__error(ctx, PEN_ERROR_PARSE,
                          "%s: image size %lld x %lld is %lld pixels, over the limit of %lld "
                          "(16384 x 8192)",
                          name, width, height, width * height, PEN__IMAGE_MAX_PIXELS);
    return PEN_OK;
}

double pen__srgb_to_linear(double c) {
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

void pen__image_code_table(int raw, float table[256]) {
    for (int i = 0; i < 256; ++i)
        table[i] = raw ? (float)(i / 255.0) : (float)pen__srgb_to_linear(i / 255.0);
}

void pen__image_samples_to_rgb(const unsigned char *src, int bits, int comp, size_t n,
                               const float table8[256], int raw, float *dst) {
    int colour = comp >= 3;
    for (size_t p = 0; p < n; ++p) {
        for (int c = 0; c < 3; ++c) {
            size_t k = p * (size_t)comp + (size_t)(colour ? c : 0);
            float v;
            if (bits == 16) {
                double x = ((unsigned)src[2 * k] << 8 | src[2 * k + 1]) / 65535.0;
                v = (float)(raw ? x : pen__srgb_to_linear(x));
            } else {
                v = table8[src[k]];
            }
            dst[3 * p + (size_t)c] = v;
        }
    }
}
