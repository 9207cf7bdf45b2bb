/* Sphere sets as data: allocation and freeing. Their files are src/io/spheres.c's; their fit and
 * overlap weights src/geometry's. */
#include "penumbra/spheres.h"
#include "core/internal.h"

#include <stdlib.h>
#include <string.h>

pen_status pen_spheres_create(pen_context *ctx, int count, pen_spheres *out) {
    memset(out, 0, sizeof *out);
    if (count < 0 || (size_t)count > PEN_MAX_ELEMENTS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "spheres: count %d out of range [0, %zu]", count,
                          (size_t)PEN_MAX_ELEMENTS);
    if (count == 0) return PEN_OK;
    out->data = pen__calloc(ctx, 4 * (size_t)count, sizeof(float), "spheres");
    if (!out->data) return PEN_ERROR_MEMORY;
    out->count = count;
    return PEN_OK;
}

void pen_spheres_free(pen_spheres *spheres) {
    if (!spheres) return;
    free(spheres->data);
    free(spheres->weight);
    memset(spheres, 0, sizeof *spheres);
}
