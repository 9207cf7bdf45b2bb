/* penumbra/core.h -- status codes, the context, and ownership rules.
 *
 * Every fallible call takes a pen_context and returns a pen_status (PEN_OK == 0). On failure the
 * context keeps one line saying where and what went wrong, e.g.
 *     "spot.obj:1207: face index 9001 out of range [1, 812]"
 * There is no global error state: two threads with two contexts never see each other's errors.
 *
 * Ownership: an object made by pen_X_create/load is freed by pen_X_destroy/free, which accept NULL.
 * Arrays passed in are borrowed for the call unless a comment says otherwise.
 */
#ifndef PENUMBRA_CORE_H
#define PENUMBRA_CORE_H

#include "penumbra/api.h"

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum pen_status {
    PEN_OK = 0,
    PEN_ERROR_ARGUMENT,  /* a value out of range, NaN/Inf, wrong shape */
    PEN_ERROR_IO,        /* a file could not be opened, read or written */
    PEN_ERROR_PARSE,     /* a file's contents are malformed */
    PEN_ERROR_MEMORY,    /* an allocation failed or a size would overflow */
    PEN_ERROR_UNSUPPORTED,
    PEN_ERROR_INTERNAL
} pen_status;

/* Opaque per-thread (or per-caller) state: the last error message and the thread count. */
typedef struct pen_context pen_context;

/* Creates a context. Returns NULL only if memory is exhausted. */
PEN_API pen_context *pen_context_create(void);
/* Frees a context; NULL is a no-op. */
PEN_API void pen_context_destroy(pen_context *ctx);
/* The last error's message ("" if none). Owned by the context; valid until the next call. */
PEN_API const char *pen_context_error(const pen_context *ctx);
/* The last error's status. */
PEN_API pen_status pen_context_status(const pen_context *ctx);
/* Clears the last error. */
PEN_API void pen_context_clear_error(pen_context *ctx);
/* Threads used by parallel passes; 0 (the default) means all cores (OpenMP's default). */
PEN_API void pen_context_set_threads(pen_context *ctx, int threads);
PEN_API int pen_context_threads(const pen_context *ctx);
/* Whether sphere fits read and write the fit cache (pen_spheres_fit_cached, in the user's cache
 * folder): on by default; off after pen_context_set_fit_cache(ctx, 0) or while the environment
 * sets PENUMBRA_NO_CACHE to anything but "" or "0" (`--no-cache` of the CLI). */
PEN_API void pen_context_set_fit_cache(pen_context *ctx, int enabled);
PEN_API int pen_context_fit_cache(const pen_context *ctx);

/* A short name for a status code ("parse error", ...). */
PEN_API const char *pen_status_string(pen_status status);
/* The library's version string, e.g. "0.2.0": PEN_VERSION_STRING of penumbra/version.h as the
 * library was built (compare it with the macro to catch a header/library mismatch). */
PEN_API const char *pen_version(void);

#ifdef __cplusplus
}
#endif
#endif
