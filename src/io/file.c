/* Whole-file reads with a size cap, atomic writes, and paths relative to a referencing file. */
#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE /* mkstemp, realpath */
#include "io/io_internal.h"

#include <errno.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* ---- Reading --------------------------------------------------------------------------------- */

pen_status pen__io_read_file(pen_context *ctx, const char *path, size_t max_bytes, char **data,
                             size_t *size) {
    *data = NULL;
    *size = 0;
    FILE *f = fopen(path, "rb");
    if (!f) return pen__error(ctx, PEN_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    /* Read in growing chunks rather than trusting a seek to the end: pipes and /proc files have
     * no size, and a file may change while it is read. */
    size_t cap = 1 << 16, n = 0;
    char *buf = pen__malloc(ctx, cap + 1, 1, path);
    if (!buf) {
        fclose(f);
        return PEN_ERROR_MEMORY;
    }
    for (;;) {
        if (n == cap) {
            if (cap >= max_bytes) {
                free(buf);
                fclose(f);
                return pen__error(ctx, PEN_ERROR_IO, "%s: larger than the limit of %zu bytes", path,
                                  max_bytes);
            }
            size_t next = cap > max_bytes / 2 ? max_bytes : cap * 2;
            char *grown = realloc(buf, next + 1);
            if (!grown) {
                free(buf);
                fclose(f);
                return pen__error(ctx, PEN_ERROR_MEMORY, "%s: cannot allocate %zu bytes", path,
                                  next + 1);
            }
            buf = grown;
            cap = next;
        }
        size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (got == 0) break;
    }
    int failed = ferror(f);
    fclose(f);
    if (failed) {
        free(buf);
        return pen__error(ctx, PEN_ERROR_IO, "%s: read error", path);
    }
    buf[n] = '\0';
    *data = buf;
    *size = n;
    return PEN_OK;
}

/* ---- Atomic writing -------------------------------------------------------------------------- */

pen_status pen__io_temp_create(pen_context *ctx, const char *path, char **tmp_path) {
    *tmp_path = NULL;
    size_t len = strlen(path);
    char *tmp = pen__malloc(ctx, len + 16, 1, "temporary file name");
    if (!tmp) return PEN_ERROR_MEMORY;
    memcpy(tmp, path, len);
    memcpy(tmp + len, ".tmp-XXXXXX", 12);
    int fd = mkstemp(tmp);
    if (fd < 0) {
        pen_status s = pen__error(ctx, PEN_ERROR_IO, "%s: cannot create a temporary file: %s", path,
                                  strerror(errno));
        free(tmp);
        return s;
    }
    /* mkstemp makes the file private (0600); outputs are ordinary files. */
    fchmod(fd, 0644);
    close(fd);
    *tmp_path = tmp;
    return PEN_OK;
}

pen_status pen__io_temp_commit(pen_context *ctx, char *tmp_path, const char *path) {
    if (rename(tmp_path, path) != 0) {
        pen_status s = pen__error(ctx, PEN_ERROR_IO, "%s: cannot write: %s", path, strerror(errno));
        pen__io_temp_discard(tmp_path);
        return s;
    }
    free(tmp_path);
    return PEN_OK;
}

void pen__io_temp_discard(char *tmp_path) {
    if (!tmp_path) return;
    remove(tmp_path);
    free(tmp_path);
}

pen_status pen__io_write_file(pen_context *ctx, const char *path, const char *data, size_t size) {
    char *tmp = NULL;
    pen_status s = pen__io_temp_create(ctx, path, &tmp);
    if (s) return s;
    FILE *f = fopen(tmp, "wb");
    int ok = f && fwrite(data, 1, size, f) == size;
    if (f && fclose(f) != 0) ok = 0;
    if (!ok) {
        pen__io_temp_discard(tmp);
        return pen__error(ctx, PEN_ERROR_IO, "%s: write error", path);
    }
    return pen__io_temp_commit(ctx, tmp, path);
}

/* ---- Paths ----------------------------------------------------------------------------------- */

int pen__io_has_ext(const char *path, const char *ext) {
    const char *dot = strrchr(path, '.');
    const char *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash)) return 0;
    const char *a = dot + 1;
    for (; *a && *ext; ++a, ++ext) {
        char c = *a;
        if (c >= 'A' && c <= 'Z') c = (char)(c - 'A' + 'a');
        if (c != *ext) return 0;
    }
    return *a == '\0' && *ext == '\0';
}

char *pen__io_strdup(pen_context *ctx, const char *s) {
    size_t n = strlen(s) + 1;
    char *d = pen__malloc(ctx, n, 1, "string");
    if (d) memcpy(d, s, n);
    return d;
}

/* Length of the folder part of path including its final '/', 0 if none. */
static size_t dir_length(const char *path) {
    const char *slash = strrchr(path, '/');
    return slash ? (size_t)(slash - path) + 1 : 0;
}

char *pen__io_path_resolve(pen_context *ctx, const char *base_file, const char *rel) {
    size_t dn = rel[0] == '/' ? 0 : dir_length(base_file);
    size_t rn = strlen(rel);
    char *out = pen__malloc(ctx, dn + rn + 1, 1, "path");
    if (!out) return NULL;
    memcpy(out, base_file, dn);
    memcpy(out + dn, rel, rn + 1);
    return out;
}

/* realpath of the folder holding `file` (which itself need not exist); malloc'd or NULL. */
static char *real_dir(const char *file) {
    size_t dn = dir_length(file);
    char *dir = malloc(dn + 2);
    if (!dir) return NULL;
    if (dn) {
        memcpy(dir, file, dn);
        dir[dn] = '\0';
    } else {
        strcpy(dir, ".");
    }
    char *real = realpath(dir, NULL);
    free(dir);
    return real;
}

char *pen__io_path_relative(pen_context *ctx, const char *new_file, const char *target) {
    char *from = real_dir(new_file);
    char *to = realpath(target, NULL);
    if (!from || !to) {
        free(from);
        free(to);
        return pen__io_strdup(ctx, target);
    }
    /* Both are canonical absolute paths (no "." or ".." segments): skip the folders they share,
     * then climb one "../" per folder of `from` left and descend into the rest of `to`. The last
     * component of `to` is its file name and is never shared. */
    const char *f = from, *t = to;
    for (;;) {
        while (*f == '/')
            ++f;
        while (*t == '/')
            ++t;
        size_t fl = strcspn(f, "/"), tl = strcspn(t, "/");
        if (fl == 0 || t[tl] == '\0' || fl != tl || memcmp(f, t, fl) != 0) break;
        f += fl;
        t += tl;
    }
    size_t ups = 0;
    for (const char *p = f; *p;) {
        while (*p == '/')
            ++p;
        if (!*p) break;
        ++ups;
        p += strcspn(p, "/");
    }
    size_t rn = strlen(t);
    char *out = pen__malloc(ctx, ups * 3 + rn + 1, 1, "path");
    if (out) {
        for (size_t k = 0; k < ups; ++k)
            memcpy(out + 3 * k, "../", 3);
        memcpy(out + 3 * ups, t, rn + 1);
    }
    free(from);
    free(to);
    return out;
}
