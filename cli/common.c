/* Shared helpers of the subcommands: one-line errors, strict number parsing. */
#include "commands.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
