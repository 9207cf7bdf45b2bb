/* penumbra/image.h -- float images: layout, creation, freeing (src/scene). Their files (PNG,
 * Radiance HDR, OpenEXR) are read and written by penumbra/io.h, compared by penumbra/metrics.h.
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

/* Largest width or height of an image (pen_image_create and every loader). */
#define PEN_IMAGE_MAX_DIM 16384
/* Largest pixel count of an image a loader reads or the albedo baker makes: 2^27 = 16384 x 8192
 * (a 16k equirectangular map), 1.5 GiB as 3 floats. */
#define PEN_IMAGE_MAX_PIXELS (1ll << 27)

/* Allocates a zeroed image (width, height in [1, PEN_IMAGE_MAX_DIM], channels in [1, 4]). */
PEN_API pen_status pen_image_create(pen_context *ctx, int width, int height, int channels,
                                    pen_image *out);
PEN_API void pen_image_free(pen_image *image);

#ifdef __cplusplus
}
#endif
#endif
