/* JSON values read with their key paths, so every error line says where in which file:
 *     "scene.json: objects[1].pose.scale: expected a positive number, got -2". */
#include "io/io_internal.h"

#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

/* JSON inputs are small: a scene or a sphere set. Anything larger is a mistake. */
#define JSON_MAX_BYTES ((size_t)256 << 20)

pen_status pen__json_parse(pen_context *ctx, const char *file, const char *text, size_t size,
                           cJSON **root) {
    *root = NULL;
    /* cJSON wants the terminating NUL inside the length it is given; an earlier NUL would hide
     * the rest of the file from it. */
    size_t len = strlen(text);
    if (len != size)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: byte %zu: NUL byte in JSON text", file, len);
    const char *end = NULL;
    *root = cJSON_ParseWithLengthOpts(text, size + 1, &end, 1);
    if (*root) return PEN_OK;
    /* cJSON reports where it stopped; turn that into line:column. */
    int line = 1, col = 1;
    if (end && end >= text && end <= text + size) {
        for (const char *p = text; p < end; ++p) {
            if (*p == '\n') {
                ++line;
                col = 1;
            } else {
                ++col;
            }
        }
    }
    if (end && end < text + size)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d:%d: invalid JSON near '%.12s'", file, line,
                          col, end);
    return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d:%d: invalid JSON (unexpected end)", file, line,
                      col);
}

pen_status pen__json_load(pen_context *ctx, const char *path, cJSON **root) {
    *root = NULL;
    char *text = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, JSON_MAX_BYTES, &text, &size);
    if (s) return s;
    s = pen__json_parse(ctx, path, text, size, root);
    free(text);
    return s;
}

/* Key paths longer than the buffer are cut with "..." at the end; messages stay one line. */
static void mark_truncated(pen__json_where *w, int written) {
    if (written >= (int)sizeof w->key) memcpy(w->key + sizeof w->key - 4, "...", 4);
}

void pen__json_child(const pen__json_where *parent, const char *name, pen__json_where *child) {
    child->file = parent->file;
    int n = parent->key[0] ? snprintf(child->key, sizeof child->key, "%s.%s", parent->key, name)
                           : snprintf(child->key, sizeof child->key, "%s", name);
    mark_truncated(child, n);
}

void pen__json_index(const pen__json_where *parent, int index, pen__json_where *child) {
    child->file = parent->file;
    mark_truncated(child, snprintf(child->key, sizeof child->key, "%s[%d]", parent->key, index));
}

const char *pen__json_type_name(const cJSON *item) {
    if (!item) return "nothing (missing key)";
    if (cJSON_IsNull(item)) return "null";
    if (cJSON_IsBool(item)) return "a boolean";
    if (cJSON_IsNumber(item)) return "a number";
    if (cJSON_IsString(item)) return "a string";
    if (cJSON_IsArray(item)) return "an array";
    if (cJSON_IsObject(item)) return "an object";
    return "an invalid value";
}

pen_status pen__json_error(pen_context *ctx, pen_status status, const pen__json_where *w,
                           const char *fmt, ...) {
    char what[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    if (w->key[0]) return pen__error(ctx, status, "%s: %s: %s", w->file, w->key, what);
    return pen__error(ctx, status, "%s: %s", w->file, what);
}

pen_status pen__json_wrap(pen_context *ctx, pen_status status, const pen__json_where *w) {
    if (w->key[0]) return pen__error_prefix(ctx, status, "%s: %s: ", w->file, w->key);
    return pen__error_prefix(ctx, status, "%s: ", w->file);
}

/* "expected <what>, got <the value or its type>" */
static pen_status expected(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                           const char *what) {
    if (!item) return pen__json_error(ctx, PEN_ERROR_PARSE, w, "missing (expected %s)", what);
    if (cJSON_IsNumber(item))
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected %s, got %g", what,
                               item->valuedouble);
    return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected %s, got %s", what,
                           pen__json_type_name(item));
}

pen_status pen__json_number(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            double lo, double hi, const char *what, double *out) {
    /* cJSON turns an overflowing literal such as 1e999 into inf; NaN cannot be written in JSON. */
    if (!cJSON_IsNumber(item) || !isfinite(item->valuedouble) || item->valuedouble < lo ||
        item->valuedouble > hi)
        return expected(ctx, w, item, what);
    *out = item->valuedouble;
    return PEN_OK;
}

pen_status pen__json_int(pen_context *ctx, const pen__json_where *w, const cJSON *item, int lo,
                         int hi, const char *what, int *out) {
    double v = 0;
    if (pen__json_number(ctx, w, item, lo, hi, what, &v) || v != floor(v))
        return expected(ctx, w, item, what);
    *out = (int)v;
    return PEN_OK;
}

pen_status pen__json_floats(pen_context *ctx, const pen__json_where *w, const cJSON *item, int n,
                            double lo, double hi, float *out) {
    char what[96];
    snprintf(what, sizeof what, "an array of %d numbers", n);
    if (!cJSON_IsArray(item)) return expected(ctx, w, item, what);
    int count = cJSON_GetArraySize(item);
    if (count != n)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected %s, got %d", what, count);
    char range[96];
    if (lo <= -HUGE_VAL && hi >= HUGE_VAL)
        snprintf(range, sizeof range, "a finite number");
    else
        snprintf(range, sizeof range, "a number in [%g, %g]", lo, hi);
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, item) {
        pen__json_where wi;
        pen__json_index(w, i, &wi);
        double v = 0.0; /* set on success; GCC cannot see that once the call is inlined */
        pen_status s = pen__json_number(ctx, &wi, e, lo, hi, range, &v);
        if (s) return s;
        /* A finite double can still overflow a float. */
        if (!isfinite((float)v))
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wi, "%g is out of float range", v);
        out[i++] = (float)v;
    }
    return PEN_OK;
}

pen_status pen__json_string(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            const char **out) {
    if (!cJSON_IsString(item) || !item->valuestring || !item->valuestring[0])
        return expected(ctx, w, item, "a non-empty string");
    *out = item->valuestring;
    return PEN_OK;
}

pen_status pen__json_choice(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            const char *what, const char *const names[], int *index) {
    const char *name = NULL;
    pen_status s = pen__json_string(ctx, w, item, &name);
    if (s) return s;
    char list[160] = "";
    size_t used = 0;
    for (int k = 0; names[k]; ++k) {
        if (strcmp(name, names[k]) == 0) {
            *index = k;
            return PEN_OK;
        }
        const char *sep = k == 0 ? "" : names[k + 1] ? ", " : " or ";
        const int n = snprintf(list + used, sizeof list - used, "%s\"%s\"", sep, names[k]);
        if (n > 0 && (size_t)n < sizeof list - used) used += (size_t)n;
    }
    return pen__json_error(ctx, PEN_ERROR_PARSE, w, "unknown %s \"%s\" (expected %s)", what, name,
                           list);
}

const cJSON *pen__json_member(const cJSON *obj, const char *name) {
    return cJSON_GetObjectItemCaseSensitive(obj, name);
}

pen_status pen__json_need_object(pen_context *ctx, const pen__json_where *w, const cJSON *item) {
    if (cJSON_IsObject(item)) return PEN_OK;
    if (!item) return pen__json_error(ctx, PEN_ERROR_PARSE, w, "missing (expected an object)");
    return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected an object, got %s",
                           pen__json_type_name(item));
}

pen_status pen__json_known_keys(pen_context *ctx, const pen__json_where *w, const cJSON *obj,
                                const char *const *known) {
    const cJSON *e;
    cJSON_ArrayForEach(e, obj) {
        if (!e->string || e->string[0] == '_') continue;
        for (const cJSON *d = obj->child; d != e; d = d->next) {
            if (d->string && strcmp(d->string, e->string) == 0) {
                pen__json_where wk;
                pen__json_child(w, e->string, &wk);
                return pen__json_error(ctx, PEN_ERROR_PARSE, &wk, "duplicate key");
            }
        }
        int found = 0;
        for (const char *const *k = known; *k && !found; ++k)
            found = strcmp(*k, e->string) == 0;
        if (!found) {
            pen__json_where wk;
            pen__json_child(w, e->string, &wk);
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wk, "unknown key");
        }
    }
    return PEN_OK;
}

int pen__json_add(cJSON *obj, const char *name, cJSON *item) {
    if (item && cJSON_AddItemToObject(obj, name, item)) return 1;
    cJSON_Delete(item);
    return 0;
}

cJSON *pen__json_float(float value) {
    /* The shortest of %.6g .. %.9g that reads back to the same float (9 always does). */
    char buf[32];
    for (int digits = 6; digits <= 9; ++digits) {
        snprintf(buf, sizeof buf, "%.*g", digits, (double)value);
        if (strtof(buf, NULL) == value) break;
    }
    return cJSON_CreateNumber(strtod(buf, NULL));
}

cJSON *pen__json_float_array(const float *v, int n) {
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; a && i < n; ++i) {
        cJSON *x = pen__json_float(v[i]);
        if (!x || !cJSON_AddItemToArray(a, x)) {
            cJSON_Delete(x);
            cJSON_Delete(a);
            return NULL;
        }
    }
    return a;
}
