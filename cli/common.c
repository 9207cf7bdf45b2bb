/* Shared helpers of the subcommands: one-line errors, strict number parsing, and finding the
 * bundled data (scenes, environment maps) at run time, so that the same binary works from the
 * build folder of a checkout and once installed. */
#define _XOPEN_SOURCE 700 /* readlink, realpath, link */
#include "commands.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
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

/* ---- All-or-nothing outputs ----------------------------------------------------------------- */

int pen_cli_outputs_add(pen_cli_outputs *out, const char *cmd, const char *path) {
    if (out->count == PEN_CLI_MAX_OUTPUTS) {
        pen_cli_fail(cmd, "%s: too many outputs", path);
        return 0;
    }
    struct stat st;
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) {
        pen_cli_fail(cmd, "%s: cannot write: it is a folder", path);
        return 0;
    }
    const char *slash = strrchr(path, '/');
    char dir[PATH_MAX];
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else
        snprintf(dir, sizeof dir, "%.*s", slash == path ? 1 : (int)(slash - path), path);
    if (access(dir, W_OK | X_OK) != 0) {
        pen_cli_fail(cmd, "%s: cannot write into the folder %s: %s", path, dir, strerror(errno));
        return 0;
    }
    out->path[out->count] = path;
    out->kept[out->count++] = NULL;
    return 1;
}

/* A copy of src at dst, for file systems without hard links. 1 on success. */
static int copy_file(const char *src, const char *dst) {
    FILE *in = fopen(src, "rb"), *to = in ? fopen(dst, "wbx") : NULL;
    int ok = in && to;
    char buf[1 << 16];
    size_t n;
    while (ok && (n = fread(buf, 1, sizeof buf, in)) > 0)
        ok = fwrite(buf, 1, n, to) == n;
    if (in && ferror(in)) ok = 0;
    if (to && fclose(to) != 0) ok = 0;
    if (in) fclose(in);
    if (!ok && to) remove(dst);
    return ok;
}

int pen_cli_outputs_keep(pen_cli_outputs *out, const char *cmd) {
    for (int i = 0; i < out->count; ++i) {
        const char *path = out->path[i];
        if (access(path, F_OK) != 0) continue; /* a new file: removed again on failure */
        const size_t n = strlen(path) + 40;
        char *kept = malloc(n);
        if (kept) snprintf(kept, n, "%s.penumbra-keep-%ld", path, (long)getpid());
        if (!kept || (link(path, kept) != 0 && !copy_file(path, kept))) {
            pen_cli_fail(cmd, "%s: cannot keep the existing file while writing: %s", path,
                         strerror(errno));
            free(kept);
            pen_cli_outputs_end(out, 1); /* drops what was kept so far; nothing was written */
            return 0;
        }
        out->kept[i] = kept;
    }
    out->kept_all = 1;
    return 1;
}

void pen_cli_outputs_end(pen_cli_outputs *out, int ok) {
    for (int i = 0; i < out->count; ++i) {
        if (out->kept[i]) {
            if (ok)
                remove(out->kept[i]);
            else
                rename(out->kept[i], out->path[i]); /* atomic: the old file is back whole */
        } else if (!ok && out->kept_all) {
            remove(out->path[i]);
        }
        free(out->kept[i]);
        out->kept[i] = NULL;
    }
    out->count = 0;
    out->kept_all = 0;
}

/* ---- Bundled data ---------------------------------------------------------------------------- */

/* The installed data relative to the installed executable (CMakeLists.txt, "Install"). */
#ifndef PEN_DATA_FROM_BINDIR
#define PEN_DATA_FROM_BINDIR "../share/penumbra"
#endif

/* The source tree a build folder was configured from: CMake writes its path into the file
 * `penumbra-source` beside the executable (CMakeLists.txt), so a build outside the checkout
 * (cmake -B /elsewhere) finds the bundled data; an installed executable has no such file. Into
 * buf (size bytes); 0 when there is none. */
static int build_source_dir(const char *exe_dir, char *buf, size_t size) {
    char path[4096];
    snprintf(path, sizeof path, "%s/penumbra-source", exe_dir);
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    const int ok = fgets(buf, (int)size, f) != NULL;
    fclose(f);
    if (!ok) return 0;
    buf[strcspn(buf, "\r\n")] = '\0';
    return buf[0] == '/';
}

/* No absolute path is compiled in: the places are relative to the running executable (/proc/self/exe),
 * so a build moved or installed elsewhere still finds its data, and a binary reads the source
 * tree it was made from only when it lies inside that tree or its build folder names it. */
const char *pen_cli_data_path(const char *cmd, const char *rel, const char *hint, char *buf,
                              size_t size) {
    char tried[5][4096];
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
        /* A build folder anywhere, through the source path CMake left in it. */
        char src[2048];
        if (build_source_dir(exe, src, sizeof src))
            snprintf(tried[n++], sizeof tried[0], "%s/%s", src, rel);
    }
    for (int i = 0; i < n; ++i)
        if (access(tried[i], R_OK) == 0) {
            char real[PATH_MAX];
            snprintf(buf, size, "%s", realpath(tried[i], real) ? real : tried[i]);
            return buf;
        }
    char list[5 * 4096 + 16] = "";
    for (int i = 0; i < n; ++i) {
        if (i) strcat(list, ", ");
        strcat(list, tried[i]);
    }
    pen_cli_fail(cmd, "bundled file %s not found (looked at %s); %s, or set PENUMBRA_DATA_DIR to "
                      "the folder holding data/ and examples/",
                 rel, n ? list : "nothing: /proc/self/exe is unreadable", hint);
    return NULL;
}
