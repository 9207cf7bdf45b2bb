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

/* Allocates a zeroed image (width, height in [1, PEN_IMAGE_MAX_DIM], channels in [1, 4]). */
PEN_API pen_status pen_image_create(pen_context *ctx, int width, int height, int channels,
                                    pen_image *out);
PEN_API void pen_image_free(pen_image *image);

/* Loads .png (8- or 16-bit), .hdr or .exr (by extension) into 3 channels (RGB), linear: grey is
 * replicated, alpha dropped. The size must be within PEN_IMAGE_MAX_DIM and every value finite
 * (PEN_ERROR_PARSE otherwise). EXR channels R, G, B (or Y) are read as 32-bit floats whatever
 * their stored type or compression; values are loaded as stored (an EXR may hold small negative
 * values from lossy compression: clamping them is the user's business, see pen_envmap_to_sh).
 * On failure *out is zeroed. */
PEN_API pen_status pen_image_load(pen_context *ctx, const char *path, pen_image *out);
/* PNG values as stored, v / 255 (or / 65535), without sRGB decoding: for data maps. */
#define PEN_IMAGE_LOAD_RAW 1u
PEN_API pen_status pen_image_load_ex(pen_context *ctx, const char *path, unsigned flags,
                                     pen_image *out);
/* Saves by extension: .png 8-bit sRGB (values clamped to [0,1], then encoded; a 2nd or 4th
 * channel is alpha, stored linear), .hdr Radiance RGBE (negative values become 0), .exr 32-bit
 * float with ZIP compression. 1 to 4 channels. Writes to a temporary file in the same folder and
 * renames it, so a failure never leaves a partial file. NaN/Inf pixels are an error
 * (PEN_ERROR_ARGUMENT naming the pixel). */
PEN_API pen_status pen_image_save(pen_context *ctx, const char *path, const pen_image *image);
/* 1 if path ends in an image extension pen_image_load/save handle (.png, .hdr, .exr; any case). */
PEN_API int pen_image_path_supported(const char *path);

#ifdef __cplusplus
}
#endif
#endif
