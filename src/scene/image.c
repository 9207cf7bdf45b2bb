/* Float images as data: creation (size checked against PEN_IMAGE_MAX_DIM) and freeing. Their
 * files are src/io/image.c's; comparing two images is metrics.c's. */
#include "penumbra/image.h"
#include "core/internal.h"

#include <stdlib.h>
#include <string.h>

pen_status pen_image_create(pen_context *ctx, int width, int height, int channels, pen_image *out) {
    memset(out, 0, sizeof *out);
    if (width < 1 || height < 1 || width > PEN_IMAGE_MAX_DIM || height > PEN_IMAGE_MAX_DIM ||
        channels < 1 || channels > 4)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "image: size %d x %d x %d outside [1, %d]^2 x [1, 4]", width, height,
                          channels, PEN_IMAGE_MAX_DIM);
    size_t n = (size_t)width * (size_t)height;
    out->data = pen__calloc(ctx, n, (size_t)channels * sizeof(float), "image");
    if (!out->data) return PEN_ERROR_MEMORY;
    out->width = width;
    out->height = height;
    out->channels = channels;
    return PEN_OK;
}

void pen_image_free(pen_image *image) {
    if (!image) return;
    free(image->data);
    memset(image, 0, sizeof *image);
}
