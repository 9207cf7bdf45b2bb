/* Image error metrics: RMSE, relative RMSE and PSNR, over the whole image and inside a mask.
 *
 * Sums run in double over every pixel and channel in one pass (sum of squared differences, sum
 * of squared reference values), so images of any size reduce without loss; the definitions are
 * in include/penumbra/metrics.h. Non-finite pixels are an error rather than a silent NaN result,
 * since a NaN in a render is a bug worth a message with its place.
 */
#include "penumbra/metrics.h"

#include "core/internal.h"

#include <math.h>

typedef struct sums {
    double sq_diff, sq_ref;
    long long pixels;
} sums;

static pen_image_error finish(const sums *s, int channels) {
    pen_image_error e;
    e.pixels = s->pixels;
    if (s->pixels == 0) {
        e.rmse = e.rel_rmse = e.psnr_db = (double)NAN;
        return e;
    }
    double n = (double)s->pixels * channels;
    double mse = s->sq_diff / n;
    e.rmse = sqrt(mse);
    double rms_ref = sqrt(s->sq_ref / n);
    if (rms_ref > 0)
        e.rel_rmse = e.rmse / rms_ref;
    else
        e.rel_rmse = e.rmse > 0 ? HUGE_VAL : 0.0;
    e.psnr_db = mse > 0 ? -10.0 * log10(mse) : HUGE_VAL;
    return e;
}

static pen_status check_image(pen_context *ctx, const char *name, const pen_image *img) {
    if (!img || !img->data || img->width <= 0 || img->height <= 0 || img->channels <= 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "compare: %s: empty image", name);
    return PEN_OK;
}

pen_status pen_image_compare(pen_context *ctx, const pen_image *a, const pen_image *b,
                             const pen_image *mask, pen_image_error *all, pen_image_error *masked) {
    pen_status st;
    if ((st = check_image(ctx, "A", a)) || (st = check_image(ctx, "B", b))) return st;
    if (mask && (st = check_image(ctx, "mask", mask))) return st;
    if (!all || (mask && !masked))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "compare: no place for the result");
    if (a->width != b->width || a->height != b->height || a->channels != b->channels)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "compare: A is %dx%d with %d channels but B is %dx%d with %d", a->width,
                          a->height, a->channels, b->width, b->height, b->channels);
    if (mask && (mask->width != a->width || mask->height != a->height))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "compare: mask is %dx%d but the images are %dx%d", mask->width,
                          mask->height, a->width, a->height);

    sums s_all = {0, 0, 0}, s_mask = {0, 0, 0};
    const int c = a->channels;
    for (int y = 0; y < a->height; ++y)
        for (int x = 0; x < a->width; ++x) {
            size_t p = (size_t)y * (size_t)a->width + (size_t)x;
            double d2 = 0, r2 = 0;
            for (int ch = 0; ch < c; ++ch) {
                float va = a->data[p * (size_t)c + (size_t)ch];
                float vb = b->data[p * (size_t)c + (size_t)ch];
                if (!isfinite(va) || !isfinite(vb))
                    return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                      "compare: %s: pixel (%d, %d) channel %d is not finite",
                                      isfinite(va) ? "B" : "A", x, y, ch);
                double d = (double)va - (double)vb;
                d2 += d * d;
                r2 += (double)vb * (double)vb;
            }
            s_all.sq_diff += d2;
            s_all.sq_ref += r2;
            ++s_all.pixels;
            if (!mask) continue;
            double m = 0;
            for (int ch = 0; ch < mask->channels; ++ch)
                m += (double)mask->data[p * (size_t)mask->channels + (size_t)ch];
            m /= mask->channels;
            if (!isfinite(m))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "compare: mask: pixel (%d, %d) is not finite", x, y);
            if (m > 0.5) {
                s_mask.sq_diff += d2;
                s_mask.sq_ref += r2;
                ++s_mask.pixels;
            }
        }
    *all = finish(&s_all, c);
    if (mask) *masked = finish(&s_mask, c);
    return PEN_OK;
}
