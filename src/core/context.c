/* Context: last error with its place, thread count. No global state. */
#include "core/internal.h"
#include "penumbra/version.h"

#include <omp.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

pen_context *pen_context_create(void) {
    return calloc(1, sizeof(pen_context));
}

void pen_context_destroy(pen_context *ctx) {
    free(ctx);
}

const char *pen_context_error(const pen_context *ctx) {
    return ctx ? ctx->message : "";
}

pen_status pen_context_status(const pen_context *ctx) {
    return ctx ? ctx->status : PEN_OK;
}

void pen_context_clear_error(pen_context *ctx) {
    if (!ctx) return;
    ctx->status = PEN_OK;
    ctx->message[0] = '\0';
}

void pen_context_set_threads(pen_context *ctx, int threads) {
    if (ctx) ctx->threads = threads < 0 ? 0 : threads;
}

int pen_context_threads(const pen_context *ctx) {
    return ctx ? ctx->threads : 0;
}

void pen_context_set_fit_cache(pen_context *ctx, int enabled) {
    if (ctx) ctx->no_fit_cache = !enabled;
}

int pen_context_fit_cache(const pen_context *ctx) {
    const char *env = getenv("PENUMBRA_NO_CACHE");
    if (env && *env && strcmp(env, "0") != 0) return 0;
    return ctx ? !ctx->no_fit_cache : 1;
}

int pen__threads_resolve(int requested) {
    return requested > 0 ? requested : omp_get_max_threads();
}

int pen__threads(const pen_context *ctx) {
    return pen__threads_resolve(pen_context_threads(ctx));
}

const char *pen_status_string(pen_status status) {
    switch (status) {
    case PEN_OK: return "ok";
    case PEN_ERROR_ARGUMENT: return "invalid argument";
    case PEN_ERROR_IO: return "i/o error";
    case PEN_ERROR_PARSE: return "parse error";
    case PEN_ERROR_MEMORY: return "out of memory";
    case PEN_ERROR_UNSUPPORTED: return "unsupported";
    case PEN_ERROR_INTERNAL: return "internal error";
    }
    return "unknown status";
}

const char *pen_version(void) {
    return PEN_VERSION_STRING;
}

pen_status pen__error(pen_context *ctx, pen_status status, const char *fmt, ...) {
    if (!ctx) return status;
    ctx->status = status;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(ctx->message, sizeof ctx->message, fmt, ap);
    va_end(ap);
    /* One line: the CLI prints the message as is, so keep newlines out of it. */
    for (char *p = ctx->message; *p; ++p)
        if (*p == '\n' || *p == '\r') *p = ' ';
    return status;
}

pen_status pen__error_prefix(pen_context *ctx, pen_status status, const char *fmt, ...) {
    if (!ctx) return status;
    char prefix[sizeof ctx->message], inner[sizeof ctx->message];
    snprintf(inner, sizeof inner, "%s", ctx->message); /* the old message, before it is replaced */
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(prefix, sizeof prefix, fmt, ap);
    va_end(ap);
    return pen__error(ctx, status, "%s%s", prefix, inner);
}

static void *checked_alloc(pen_context *ctx, size_t count, size_t size, const char *what,
                           int zero) {
    if (size != 0 && count > SIZE_MAX / size) {
        pen__error(ctx, PEN_ERROR_MEMORY, "%s: size %zu x %zu overflows", what, count, size);
        return NULL;
    }
    size_t bytes = count * size;
    void *p = zero ? calloc(1, bytes ? bytes : 1) : malloc(bytes ? bytes : 1);
    if (!p) pen__error(ctx, PEN_ERROR_MEMORY, "%s: cannot allocate %zu bytes", what, bytes);
    return p;
}

void *pen__malloc(pen_context *ctx, size_t count, size_t size, const char *what) {
    return checked_alloc(ctx, count, size, what, 0);
}

void *pen__calloc(pen_context *ctx, size_t count, size_t size, const char *what) {
    return checked_alloc(ctx, count, size, what, 1);
}
