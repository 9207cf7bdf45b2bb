/* Image losses with their gradients, all in this one file: the plain mean squared and mean
 * absolute error of render.h (over all pixels and channels, summed in double in element order)
 * and the optimizer's per-pixel weighted mean (loss.h; summed per pixel, then over pixels). Both
 * reductions are deterministic and kept as they were recorded (the golden hashes hold their
 * bits); the residual term and its derivative are shared. */
#include "render/loss.h"

#include "penumbra/render.h"

/* rho(r) = |r| or r^2, and drho/dr (0 at r = 0 for |r|). */
static inline double rho(int l1, double r) {
    return l1 ? fabs(r) : r * r;
}

static inline double drho(int l1, double r) {
    return l1 ? (r > 0.0 ? 1.0 : r < 0.0 ? -1.0 : 0.0) : 2.0 * r;
}

/* ---- Plain means (render.h) -------------------------------------------------------------------
 */

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
        sum += rho(l1, r);
        if (d_image) d_image->data[i] = (float)(drho(l1, r) * inv); /* set: render.h */
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

/* ---- Weighted mean (loss.h) -------------------------------------------------------------------
 */

double pen__loss_weight_sum(const float *weight, size_t pixels) {
    if (!weight) return (double)pixels;
    double sum = 0.0;
    for (size_t p = 0; p < pixels; ++p)
        sum += (double)weight[p];
    return sum;
}

pen_status pen__loss_weighted_fwd(pen_context *ctx, int l1, const pen_image *image,
                                  const pen_image *target, const float *weight, double *loss) {
    if (!image->data || !target->data || image->width != target->width ||
        image->height != target->height || image->channels != target->channels)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "loss: image and target shapes differ");
    const size_t pixels = (size_t)image->width * (size_t)image->height;
    const int C = image->channels;
    const double wsum = pen__loss_weight_sum(weight, pixels);
    if (!(wsum > 0.0) || !isfinite(wsum))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "loss: the pixel weights sum to %g", wsum);
    double sum = 0.0;
    for (size_t p = 0; p < pixels; ++p) {
        double e = 0.0;
        for (int c = 0; c < C; ++c) {
            const size_t i = p * (size_t)C + (size_t)c;
            e += rho(l1, (double)image->data[i] - (double)target->data[i]);
        }
        sum += weight ? (double)weight[p] * e : e;
    }
    *loss = sum / ((double)C * wsum);
    if (!isfinite(*loss))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "loss: not finite (NaN/Inf pixels)");
    return PEN_OK;
}

void pen__loss_weighted_bwd(int l1, const pen_image *image, const pen_image *target,
                            const float *weight, double d_loss, pen_image *d_image) {
    const size_t pixels = (size_t)image->width * (size_t)image->height;
    const int C = image->channels;
    const double k = d_loss / ((double)C * pen__loss_weight_sum(weight, pixels));
    for (size_t p = 0; p < pixels; ++p) {
        const double kp = weight ? k * (double)weight[p] : k;
        for (int c = 0; c < C; ++c) {
            const size_t i = p * (size_t)C + (size_t)c;
            const double r = (double)image->data[i] - (double)target->data[i];
            d_image->data[i] += (float)(kp * drho(l1, r));
        }
    }
}
