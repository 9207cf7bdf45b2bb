/* penumbra/image.h -- float images and their files (PNG, Radiance HDR, OpenEXR).
 *
 * Layout: `channels` interleaved floats per pixel, rows top to bottom, pixels left to right:
 *   value(x, y, ch) = data[(y * width + x) * channels + ch].
 * Values are linear radiance. PNG files are 8-bit sRGB: loading decodes sRGB to linear (unless
 * asked for raw values, e.g. for data maps), saving clamps to [0,1] and encodes to sRGB.
 * HDR and EXR hold linear floats. An image owns its data; pen_image_free releases it.
 */
#ifndef PENUMBRA_IMAGE_H
#define PENUMBRA_IMAGE_H

#include "penumbra/core.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pen_image {
    int width, height, channels;
    float *data;
} pen_image;

/* Largest width or height any loader accepts. */
#define PEN_IMAGE_MAX_DIM 16384

/* Allocates a zeroed image. */
pen_status pen_image_create(pen_context *ctx, int width, int height, int channels,
                            pen_image *out);
void pen_image_free(pen_image *image);

/* Loads .png, .hdr or .exr (by extension) into 3 channels (RGB), linear. */
pen_status pen_image_load(pen_context *ctx, const char *path, pen_image *out);
/* Saves by extension (.png sRGB 8-bit, .hdr, .exr). Writes to a temporary file in the same folder
 * and renames it, so a failure never leaves a partial file. NaN/Inf pixels are an error. */
pen_status pen_image_save(pen_context *ctx, const char *path, const pen_image *image);

#ifdef __cplusplus
}
#endif
#endif
