/* penumbra/metrics.h -- image error metrics (what `penumbra compare` prints).
 *
 * Over the compared pixels P and all channels C of images A and B (B is the reference):
 *   rmse     = sqrt( sum (A - B)^2 / (|P| |C|) )
 *   rel_rmse = rmse / sqrt( sum B^2 / (|P| |C|) )       (scale-free; +inf if B is all zero and
 *                                                        A is not, 0 if both are all zero)
 *   psnr_db  = 10 log10( 1 / mse )                      (peak 1: the display white of a linear
 *                                                        image; +inf when A == B)
 * A mask restricts P to the pixels whose mask value (mean over the mask's channels) exceeds 0.5;
 * with no pixel selected the masked metrics are NaN and `pixels` is 0.
 */
#ifndef PENUMBRA_METRICS_H
#define PENUMBRA_METRICS_H

#include "penumbra/core.h"
#include "penumbra/image.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pen_image_error {
    double rmse;
    double rel_rmse;
    double psnr_db;
    long long pixels; /* pixels compared */
} pen_image_error;

/* Compares A against the reference B. They must have the same width, height and channels, and
 * finite values. `mask` may be NULL; otherwise it must have the same width and height (any
 * channel count), and *masked receives the metrics restricted to it (`masked` may be NULL when
 * mask is NULL). Errors name the image ("A", "B", "mask") and the pixel. */
PEN_API pen_status pen_image_compare(pen_context *ctx, const pen_image *a, const pen_image *b,
                                     const pen_image *mask, pen_image_error *all,
                                     pen_image_error *masked);

#ifdef __cplusplus
}
#endif
#endif
