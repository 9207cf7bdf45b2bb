/* Internal helpers shared by every module: error reporting, checked allocation, numerics.
 * Not installed; public code includes only include/penumbra/. */
#ifndef PEN_INTERNAL_H
#define PEN_INTERNAL_H

#include "penumbra/core.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>

struct pen_context {
    pen_status status;
    int threads;
    int no_fit_cache; /* pen_context_set_fit_cache(ctx, 0); zero (calloc) keeps the cache on */
    char message[1024];
};

#if defined(__GNUC__)
#define PEN_PRINTF(f, a) __attribute__((format(printf, f, a)))
#else
#define PEN_PRINTF(f, a)
#endif

/* Records an error in ctx (if not NULL) and returns status, so callers can write
 *     return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: bad index", path, line);            */
pen_status pen__error(pen_context *ctx, pen_status status, const char *fmt, ...) PEN_PRINTF(3, 4);

/* Re-records the context's current error behind a prefix: the prefix is formatted from fmt and
 * the old message follows it unchanged, so an error of a referenced file keeps its place, e.g.
 *     pen__error_prefix(ctx, s, "%s: objects[%d].mesh: ", json, o)
 * gives "scene.json: objects[0].mesh: spot.obj:12: ...". Returns status. */
pen_status pen__error_prefix(pen_context *ctx, pen_status status, const char *fmt, ...)
    PEN_PRINTF(3, 4);

/* The thread count a parallel pass uses: `requested` when positive, else the OpenMP runtime's
 * default (all cores). pen__threads resolves a context's setting (pen_context_set_threads). */
int pen__threads_resolve(int requested);
int pen__threads(const pen_context *ctx);

/* Allocation with overflow-checked sizes (stb's mul2sizes habit). Return NULL on overflow or
 * exhaustion and record PEN_ERROR_MEMORY in ctx with `what` in the message. */
void *pen__malloc(pen_context *ctx, size_t count, size_t size, const char *what);
void *pen__calloc(pen_context *ctx, size_t count, size_t size, const char *what);
/* Largest element count any loader will accept for one array (guards against absurd headers). */
#define PEN_MAX_ELEMENTS ((size_t)1 << 28)

/* FNV-1a 64 of `size` bytes, continuing from h (start: PEN__FNV1A_SEED): the checksums and keys
 * of files penumbra writes (checkpoints, the sphere-fit cache). Byte at a time; the large-array
 * cache keys of the renderer use a vectorised hash instead. */
#define PEN__FNV1A_SEED 0xCBF29CE484222325ull
static inline uint64_t pen__fnv1a(uint64_t h, const void *data, size_t size) {
    const unsigned char *p = (const unsigned char *)data; /* (also compiled as C++) */
    for (size_t i = 0; i < size; ++i)
        h = (h ^ p[i]) * 0x100000001B3ull;
    return h;
}

static inline int pen__finite3(const float v[3]) {
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

#define PEN_PI 3.14159265358979323846
#define PEN_PI_F 3.14159265358979323846f

#endif
