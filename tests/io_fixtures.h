/* Helpers for the file-format tests: a private temporary folder, files written into it, and a
 * check that a call failed with the expected status and a message containing given substrings. */
#ifndef PEN_TEST_IO_FIXTURES_H
#define PEN_TEST_IO_FIXTURES_H

#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE
#include "check.h"
#include "penumbra/penumbra.h"

#include <dirent.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static char fixture_dir_[256];

/* The test's temporary folder (created on first use, removed by fixture_cleanup). */
static inline const char *fixture_dir(void) {
    if (!fixture_dir_[0]) {
        snprintf(fixture_dir_, sizeof fixture_dir_, "/tmp/pen_test_XXXXXX");
        if (!mkdtemp(fixture_dir_)) {
            perror("mkdtemp");
            exit(2);
        }
    }
    return fixture_dir_;
}

/* fixture_dir()/name in one of 8 rotating buffers (so a call may use several). */
static inline const char *fixture_path(const char *name) {
    static char bufs[8][512];
    static int next = 0;
    char *b = bufs[next++ & 7];
    snprintf(b, 512, "%s/%s", fixture_dir(), name);
    return b;
}

static inline const char *fixture_write(const char *name, const void *data, size_t size) {
    const char *path = fixture_path(name);
    /* A new file rather than a truncated one: ext4 flushes a truncated-and-rewritten file on
     * close (auto_da_alloc), which made the mutation test wait on the disk. */
    unlink(path);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, size, f) != size || fclose(f) != 0) {
        perror(path);
        exit(2);
    }
    return path;
}

static inline const char *fixture_text(const char *name, const char *text) {
    return fixture_write(name, text, strlen(text));
}

static inline int fixture_exists(const char *path) {
    struct stat st;
    return stat(path, &st) == 0;
}

/* Number of entries of the folder whose name contains ".tmp-" (left-over temporary files). */
static inline int fixture_temp_files(void) {
    DIR *d = opendir(fixture_dir());
    int n = 0;
    for (struct dirent *e; d && (e = readdir(d));)
        n += strstr(e->d_name, ".tmp-") != NULL;
    if (d) closedir(d);
    return n;
}

static inline void fixture_cleanup_dir_(const char *dir) {
    DIR *d = opendir(dir);
    for (struct dirent *e; d && (e = readdir(d));) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
        char p[1024];
        if (snprintf(p, sizeof p, "%s/%s", dir, e->d_name) >= (int)sizeof p) continue;
        struct stat st;
        if (lstat(p, &st) == 0 && S_ISDIR(st.st_mode))
            fixture_cleanup_dir_(p);
        else
            unlink(p);
    }
    if (d) closedir(d);
    rmdir(dir);
}

/* Removes the folder, unless PEN_TEST_KEEP is set (to look at what a test wrote). */
static inline void fixture_cleanup(void) {
    if (fixture_dir_[0] && getenv("PEN_TEST_KEEP"))
        fprintf(stderr, "kept %s\n", fixture_dir_);
    else if (fixture_dir_[0])
        fixture_cleanup_dir_(fixture_dir_);
    fixture_dir_[0] = '\0';
}

/* One context for the whole test program, created on first use; it and the temporary folder are
 * released at exit. */
static pen_context *fixture_ctx_;
static inline void fixture_exit_(void) {
    pen_context_destroy(fixture_ctx_);
    fixture_cleanup();
}
static inline pen_context *fixture_ctx(void) {
    if (!fixture_ctx_) {
        fixture_ctx_ = pen_context_create();
        atexit(fixture_exit_);
    }
    return fixture_ctx_;
}

/* Checks that `got` equals `want` and that the context's message contains each of the
 * NULL-terminated substrings. */
static inline void check_error_(int line, pen_context *ctx, pen_status got, pen_status want, ...) {
    const char *msg = pen_context_error(ctx);
    ++check_count_;
    if (got != want) {
        ++check_failures_;
        fprintf(stderr, "line %d: status %s, expected %s (message: %s)\n", line,
                pen_status_string(got), pen_status_string(want), msg);
    }
    va_list ap;
    va_start(ap, want);
    for (const char *sub; (sub = va_arg(ap, const char *));) {
        ++check_count_;
        if (!strstr(msg, sub)) {
            ++check_failures_;
            fprintf(stderr, "line %d: message '%s' lacks '%s'\n", line, msg, sub);
        }
    }
    va_end(ap);
    pen_context_clear_error(ctx);
}
#define CHECK_ERROR(ctx, got, want, ...) check_error_(__LINE__, ctx, got, want, __VA_ARGS__, NULL)

#endif
