/* Shared helpers of the subcommands: one-line errors, strict number parsing, and finding the
 * bundled data (scenes, environment maps) at run time, so that the same binary works from the
 * build folder of a checkout and once installed. */
#define _XOPEN_SOURCE 700 /* readlink, realpath */
#include "commands.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static int vfail(int status, const char *cmd, const char *fmt, va_list ap) {
    fprintf(stderr, "penumbra %s: ", cmd);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    return status;
}

int pen_cli_fail(const char *cmd, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int s = vfail(1, cmd, fmt, ap);
    va_end(ap);
    return s;
}

int pen_cli_usage_error(const char *cmd, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int s = vfail(2, cmd, fmt, ap);
    va_end(ap);
    fprintf(stderr, "Try 'penumbra %s --help'.\n", cmd);
    return s;
}

int pen_cli_fail_ctx(const char *cmd, const pen_context *ctx) {
    return pen_cli_fail(cmd, "%s", pen_context_error(ctx));
}

int pen_cli_positional(const char *cmd, const char *arg, const char **slots, int count) {
    if (arg[0] == '-' && arg[1]) return pen_cli_usage_error(cmd, "unknown option '%s'", arg);
    for (int i = 0; i < count; ++i)
        if (!slots[i]) {
            slots[i] = arg;
            return 0;
        }
    return pen_cli_usage_error(cmd, "unexpected argument '%s'", arg);
}

int pen_cli_parse_int(const char *cmd, const char *flag, const char *text, long lo, long hi,
                      int *out) {
    if (!text) {
        pen_cli_usage_error(cmd, "%s needs a value", flag);
        return 0;
    }
    char *end = NULL;
    errno = 0;
    long v = strtol(text, &end, 10);
    if (errno || end == text || *end || v < lo || v > hi) {
        pen_cli_usage_error(cmd, "%s: expected an integer in [%ld, %ld], got '%s'", flag, lo, hi,
                            text);
        return 0;
    }
    *out = (int)v;
    return 1;
}

int pen_cli_parse_float(const char *cmd, const char *flag, const char *text, double lo, double hi,
                        double *out) {
    if (!text) {
        pen_cli_usage_error(cmd, "%s needs a value", flag);
        return 0;
    }
    char *end = NULL;
    errno = 0;
    double v = strtod(text, &end);
    if (errno || end == text || *end || !isfinite(v) || v < lo || v > hi) {
        pen_cli_usage_error(cmd, "%s: expected a number in [%g, %g], got '%s'", flag, lo, hi,
                            text);
        return 0;
    }
    *out = v;
    return 1;
}

int pen_cli_is_help(const char *arg) {
    return strcmp(arg, "-h") == 0 || strcmp(arg, "--help") == 0;
}

/* ---- Bundled data ---------------------------------------------------------------------------- */

/* The installed data relative to the installed executable (CMakeLists.txt, "Install"). */
#ifndef PEN_DATA_FROM_BINDIR
#define PEN_DATA_FROM_BINDIR "../share/penumbra"
#endif

/* No absolute path is compiled in: the places are relative to the running executable (/proc/self/exe),
 * so a build moved or installed elsewhere still finds its data, and a binary reads the source
 * tree it was made from only when it lies inside that tree. */
const char *pen_cli_data_path(const char *cmd, const char *rel, const char *hint, char *buf,
                              size_t size) {
    char tried[4][4096];
    int n = 0;
    const char *env = getenv("PENUMBRA_DATA_DIR");
    if (env && *env) snprintf(tried[n++], sizeof tried[0], "%s/%s", env, rel);
    char exe[2048];
    const ssize_t len = readlink("/proc/self/exe", exe, sizeof exe - 1);
    char *slash = NULL;
    if (len > 0) {
        exe[len] = '\0';
        slash = strrchr(exe, '/');
    }
    if (slash) {
        *slash = '\0';
        /* Installed: <prefix>/bin/penumbra beside <prefix>/share/penumbra. */
        snprintf(tried[n++], sizeof tried[0], "%s/" PEN_DATA_FROM_BINDIR "/%s", exe, rel);
        /* A build folder in the checkout (build/penumbra), or one level deeper. */
        snprintf(tried[n++], sizeof tried[0], "%s/../%s", exe, rel);
        snprintf(tried[n++], sizeof tried[0], "%s/../../%s", exe, rel);
    }
    for (int i = 0; i < n; ++i)
        if (access(tried[i], R_OK) == 0) {
            char real[PATH_MAX];
            snprintf(buf, size, "%s", realpath(tried[i], real) ? real : tried[i]);
            return buf;
        }
    char list[4 * 4096 + 16] = "";
    for (int i = 0; i < n; ++i) {
        if (i) strcat(list, ", ");
        strcat(list, tried[i]);
    }
    pen_cli_fail(cmd, "bundled file %s not found (looked at %s); %s, or set PENUMBRA_DATA_DIR to "
                      "the folder holding data/ and examples/",
                 rel, n ? list : "nothing: /proc/self/exe is unreadable", hint);
    return NULL;
}
