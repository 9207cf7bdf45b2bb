/* Image losses with their gradients: mean squared and mean absolute error over all pixels and
 * channels, summed in double in pixel order (repeatable). */
#include "penumbra/render.h"

#include "core/internal.h"

static pen_status prepare(pen_context *ctx, const char *name, const pen_image *image,
                          const pen_image *target, pen_image *d_image) {
    if (!image || !target || !image->data || !target->data || image->width != target->width ||
        image->height != target->height || image->channels != target->channels)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s loss: image and target shapes differ", name);
    if (!d_image) return PEN_OK;
    if (!d_image->data)
        return pen_image_create(ctx, image->width, image->height, image->channels, d_image);
    if (d_image->width != image->width || d_image->height != image->height ||
        d_image->channels != image->channels)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s loss: gradient image has the wrong shape",
                          name);
    return PEN_OK;
}

static pen_status loss(pen_context *ctx, int l1, const pen_image *image, const pen_image *target,
                       double *out, pen_image *d_image) {
    pen_status s = prepare(ctx, l1 ? "L1" : "L2", image, target, d_image);
    if (s) return s;
    const size_t n = (size_t)image->width * (size_t)image->height * (size_t)image->channels;
    const double inv = 1.0 / (double)n;
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const double r = (double)image->data[i] - (double)target->data[i];
        sum += l1 ? fabs(r) : r * r;
        if (d_image) {
            const double g = l1 ? (r > 0.0 ? inv : r < 0.0 ? -inv : 0.0) : 2.0 * r * inv;
            d_image->data[i] += (float)g;
        }
    }
    if (out) *out = sum * inv;
    if (!isfinite(sum))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s loss: not finite (NaN/Inf pixels)",
                          l1 ? "L1" : "L2");
    return PEN_OK;
}

pen_status pen_loss_l2(pen_context *ctx, const pen_image *image, const pen_image *target,
                       double *out, pen_image *d_image) {
    return loss(ctx, 0, image, target, out, d_image);
}

pen_status pen_loss_l1(pen_context *ctx, const pen_image *image, const pen_image *target,
                       double *out, pen_image *d_image) {
    return loss(ctx, 1, image, target, out, d_image);
}
