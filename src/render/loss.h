/* The weighted image loss (src/render/loss.c), beside the plain pen_loss_l1/l2 of render.h: the
 * optimizer's objective with per-pixel weights. Internal. */
#ifndef PEN_RENDER_LOSS_H
#define PEN_RENDER_LOSS_H

#include "core/internal.h"
#include "penumbra/image.h"

/* loss = sum_p w_p sum_c rho(image_pc - target_pc) / (C sum_p w_p) over the pixels p and the C
 * channels, rho = |r| (l1 != 0) or r^2; `weight` (one per pixel) NULL means w = 1, the plain
 * mean. Summed in double in pixel order. Shapes must match; the weights must be >= 0 with a
 * positive sum. */
pen_status pen__loss_weighted_fwd(pen_context *ctx, int l1, const pen_image *image,
                                  const pen_image *target, const float *weight, double *loss);
/* Adds d_loss * dloss/dimage into d_image (the image's shape). */
void pen__loss_weighted_bwd(int l1, const pen_image *image, const pen_image *target,
                            const float *weight, double d_loss, pen_image *d_image);
/* sum_p w_p, summed in pixel order (the pixel count when weight is NULL). */
double pen__loss_weight_sum(const float *weight, size_t pixels);

#endif
