/* Wavefront OBJ meshes (and the map_Kd of their MTL materials).
 *
 * Two passes over the file held in memory: the first counts v, vt, vn and the triangles the
 * faces will make, so every array is allocated once at its exact size (and absurd counts fail
 * before any allocation); the second parses and fills. Faces are triangulated as fans around
 * their first corner. Positive indices may refer to vertices defined later in the file (they are
 * checked against the final counts); negative indices are relative to the vertices defined so
 * far (-1 is the latest). Index 0 does not exist in OBJ. Every corner of every face must have
 * the same kind of reference (v, v/vt, v//vn or v/vt/vn): a mesh has one UV and one normal
 * index per triangle corner or none at all.
 *
 * Materials: every `mtllib` (several are allowed) is read in the first pass, so that a `usemtl`
 * may name a material of any of them; their newmtl / Kd / map_Kd statements become
 * mesh.materials (map_Kd resolved relative to its .mtl file, with its "file:line" kept for later
 * messages), and each triangle gets the material of the last `usemtl` before its face (the
 * triangles of an ngon share it), -1 before any `usemtl` or after one naming an unknown material
 * (like OBJ viewers, which draw such faces with a default material). A name defined twice means
 * its later definition. The texture of the first `usemtl` material whose entry has a `map_Kd`
 * also becomes mesh.texture_path, as before materials were kept per face. A missing .mtl file is
 * not an error (OBJ files often travel without theirs): the mesh simply has no materials;
 * texture files are not opened here. Kd takes 1 (grey) or 3 numbers in [0, 1].
 * Vertex colours (`v x y z r g b`, a common extension) are kept when every vertex has one; they
 * are the sRGB-encoded 8-bit colours / 255 in the files that write them, and are decoded to
 * linear like 8-bit textures.
 * Every statement other than v, vt, vn, f, mtllib and usemtl is ignored. */
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#define OBJ_MAX_BYTES ((size_t)1 << 32)
/* All the .mtl files of one OBJ together: a bound on the work an OBJ repeating `mtllib` lines
 * can cause, far above real libraries (kilobytes). */
#define MTL_MAX_BYTES ((size_t)64 << 20)

/* A line of the file: [p, end), with its 1-based number. */
typedef struct line {
    const char *p, *end;
    int number;
} line;

/* Moves *cursor to the next line; returns 0 at the end of the text. */
static int next_line(const char **cursor, const char *text_end, line *ln) {
    if (*cursor >= text_end) return 0;
    const char *p = *cursor;
    const char *nl = memchr(p, '\n', (size_t)(text_end - p));
    const char *end = nl ? nl : text_end;
    *cursor = nl ? nl + 1 : text_end;
    if (end > p && end[-1] == '\r') --end;
    ln->p = p;
    ln->end = end;
    ++ln->number;
    return 1;
}

static void skip_blanks(const char **p, const char *end) {
    while (*p < end && (**p == ' ' || **p == '\t'))
        ++*p;
}

/* The next blank-separated token of a line as [start, start + length); length 0 at the end. */
static size_t next_token(const char **p, const char *end, const char **start) {
    skip_blanks(p, end);
    *start = *p;
    while (*p < end && **p != ' ' && **p != '\t')
        ++*p;
    return (size_t)(*p - *start);
}

static int token_is(const char *t, size_t n, const char *word) {
    return strlen(word) == n && memcmp(t, word, n) == 0;
}

/* The rest of the line without surrounding blanks, as a malloc'd string with backslashes turned
 * into slashes (Windows exporters write "textures\wood.png"). */
static char *rest_of_line(pen_context *ctx, const char *p, const char *end) {
    skip_blanks(&p, end);
    while (end > p && (end[-1] == ' ' || end[-1] == '\t'))
        --end;
    size_t n = (size_t)(end - p);
    char *s = pen__malloc(ctx, n + 1, 1, "OBJ name");
    if (!s) return NULL;
    for (size_t i = 0; i < n; ++i)
        s[i] = p[i] == '\\' ? '/' : p[i];
    s[n] = '\0';
    return s;
}

/* ---- MTL ------------------------------------------------------------------------------------- */

/* The materials of every mtllib, in file order, and their names sorted for usemtl lookups. */
typedef struct materials {
    pen_mesh_material *items;
    int count, cap;
    int *sorted;  /* indices into items by name; among equal names the later definition first */
    size_t bytes; /* read from the libraries so far (MTL_MAX_BYTES in all) */
} materials;

static void materials_free(materials *m) {
    for (int i = 0; i < m->count; ++i) {
        free(m->items[i].name);
        free(m->items[i].texture_path);
        free(m->items[i].texture_source);
    }
    free(m->items);
    free(m->sorted);
    memset(m, 0, sizeof *m);
}

static pen_status materials_add(pen_context *ctx, const char *mtl_path, int number, materials *m,
                                char *name) {
    if (m->count == PEN_MESH_MAX_MATERIALS) {
        free(name);
        return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: more than %d materials", mtl_path, number,
                          PEN_MESH_MAX_MATERIALS);
    }
    if (m->count == m->cap) {
        int cap = m->cap ? 2 * m->cap : 8;
        pen_mesh_material *grown = realloc(m->items, (size_t)cap * sizeof *grown);
        if (!grown) {
            free(name);
            return pen__error(ctx, PEN_ERROR_MEMORY, "%s: too many materials", mtl_path);
        }
        m->items = grown;
        m->cap = cap;
    }
    memset(&m->items[m->count], 0, sizeof m->items[0]);
    m->items[m->count++].name = name;
    return PEN_OK;
}

/* qsort has no context argument: the items travel with the indices. */
typedef struct named {
    const char *name;
    int index;
} named;

static int by_name(const void *a, const void *b) {
    const named *x = a, *y = b;
    int c = strcmp(x->name, y->name);
    return c ? c : y->index - x->index; /* later definitions first: they override */
}

static pen_status materials_sort(pen_context *ctx, materials *m) {
    if (m->count == 0) return PEN_OK;
    named *tmp = pen__malloc(ctx, (size_t)m->count, sizeof *tmp, "materials");
    m->sorted = pen__malloc(ctx, (size_t)m->count, sizeof *m->sorted, "materials");
    if (!tmp || !m->sorted) {
        free(tmp);
        return PEN_ERROR_MEMORY;
    }
    for (int i = 0; i < m->count; ++i)
        tmp[i] = (named){m->items[i].name, i};
    qsort(tmp, (size_t)m->count, sizeof *tmp, by_name);
    for (int i = 0; i < m->count; ++i)
        m->sorted[i] = tmp[i].index;
    free(tmp);
    return PEN_OK;
}

/* The index of the material called `name` (the last definition of it), or -1. */
static int materials_find(const materials *m, const char *name) {
    int lo = 0, hi = m->count; /* the first sorted entry >= name */
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (strcmp(m->items[m->sorted[mid]].name, name) < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < m->count && strcmp(m->items[m->sorted[lo]].name, name) == 0 ? m->sorted[lo] : -1;
}

/* Skips the options of a map_Kd statement ("-s 1 1 1 -clamp on file.png"): each option is
 * followed by its arguments; -o, -s and -t take one to three numbers. */
static void skip_map_options(const char **p, const char *end) {
    static const struct {
        const char *name;
        int args;
    } options[] = {
        {"-blendu", 1},  {"-blendv", 1}, {"-bm", 1},     {"-boost", 1}, {"-cc", 1}, {"-clamp", 1},
        {"-imfchan", 1}, {"-mm", 2},     {"-texres", 1}, {"-o", -3},    {"-s", -3}, {"-t", -3},
    };
    for (;;) {
        const char *save = *p, *t;
        size_t n = next_token(p, end, &t);
        int args = 0;
        for (size_t k = 0; k < sizeof options / sizeof options[0]; ++k)
            if (token_is(t, n, options[k].name)) args = options[k].args;
        if (args == 0) {
            *p = save;
            return;
        }
        for (int a = 0; a < (args < 0 ? -args : args); ++a) {
            const char *save_arg = *p, *v;
            size_t vn = next_token(p, end, &v);
            if (args < 0 && a > 0) { /* optional numeric arguments */
                char *stop = NULL;
                strtod(v, &stop);
                if (vn == 0 || stop != v + vn) {
                    *p = save_arg;
                    break;
                }
            }
        }
    }
}

/* Kd r [g b]: one number stands for grey (as the MTL format has it); each in [0, 1]. */
static pen_status parse_kd(pen_context *ctx, const char *mtl_path, const line *ln, const char *p,
                           float kd[3]) {
    double v[4];
    int n = 0;
    const char *t;
    size_t len;
    while ((len = next_token(&p, ln->end, &t)) > 0) {
        char *stop = NULL;
        double x = n < 3 ? strtod(t, &stop) : 0.0;
        if (n == 3 || stop != t + len)
            return pen__error(ctx, PEN_ERROR_PARSE,
                              "%s:%d: Kd expects 1 or 3 numbers in [0, 1], got '%.*s'", mtl_path,
                              ln->number, (int)(ln->end - ln->p), ln->p);
        if (!(x >= 0.0 && x <= 1.0))
            return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: Kd value '%.*s' is not in [0, 1]",
                              mtl_path, ln->number, (int)len, t);
        v[n++] = x;
    }
    if (n != 1 && n != 3)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: Kd expects 1 or 3 numbers, got %d",
                          mtl_path, ln->number, n);
    for (int k = 0; k < 3; ++k)
        kd[k] = (float)v[n == 1 ? 0 : k];
    return PEN_OK;
}

/* "path:line" of a statement, for later messages. */
static char *source_of(pen_context *ctx, const char *path, int number) {
    size_t n = strlen(path) + 16;
    char *s = pen__malloc(ctx, n, 1, "OBJ name");
    if (s) snprintf(s, n, "%s:%d", path, number);
    return s;
}

/* Reads the newmtl, Kd and map_Kd statements of an MTL file into m. A file that cannot be opened
 * adds nothing (see the design note above); the texture files are not opened here (a mesh with a
 * missing texture still has geometry; the scene loader names the map_Kd line if it needs it). */
static pen_status mtl_read(pen_context *ctx, const char *mtl_path, materials *m) {
    FILE *probe = fopen(mtl_path, "rb");
    if (!probe) return PEN_OK;
    fclose(probe);
    char *text = NULL;
    size_t size = 0;
    if (m->bytes >= MTL_MAX_BYTES)
        return pen__error(ctx, PEN_ERROR_PARSE,
                          "%s: the material libraries of the mesh exceed %zu MiB in all "
                          "(counting each file read 4 KiB more)",
                          mtl_path, MTL_MAX_BYTES >> 20);
    pen_status s = pen__io_read_file(ctx, mtl_path, MTL_MAX_BYTES - m->bytes, &text, &size);
    if (s) return s;
    m->bytes += size + 4096; /* each file counts 4 KiB more: many empty ones are work too */
    const char *cursor = text;
    line ln = {0};
    const int first = m->count; /* Kd and map_Kd before any newmtl of this file are ignored */
    while (s == PEN_OK && next_line(&cursor, text + size, &ln)) {
        const char *p = ln.p, *t;
        size_t n = next_token(&p, ln.end, &t);
        pen_mesh_material *cur = m->count > first ? &m->items[m->count - 1] : NULL;
        if (token_is(t, n, "newmtl")) {
            char *name = rest_of_line(ctx, p, ln.end);
            s = name ? materials_add(ctx, mtl_path, ln.number, m, name) : PEN_ERROR_MEMORY;
        } else if (token_is(t, n, "Kd") && cur) {
            s = parse_kd(ctx, mtl_path, &ln, p, cur->kd);
            cur->has_kd = 1;
        } else if (token_is(t, n, "map_Kd") && cur) {
            skip_map_options(&p, ln.end);
            char *file = rest_of_line(ctx, p, ln.end);
            if (!file) {
                s = PEN_ERROR_MEMORY;
            } else if (!file[0]) {
                s = pen__error(ctx, PEN_ERROR_PARSE, "%s:%d: map_Kd without a file name", mtl_path,
                               ln.number);
            } else {
                free(cur->texture_path);
                free(cur->texture_source);
                cur->texture_path = pen__io_path_resolve(ctx, mtl_path, file);
                cur->texture_source = source_of(ctx, mtl_path, ln.number);
                if (!cur->texture_path || !cur->texture_source) s = PEN_ERROR_MEMORY;
            }
            free(file);
        }
    }
    free(text);
    return s;
}

/* Reads the MTL file named by an mtllib statement (relative to the OBJ file). */
static pen_status mtllib(pen_context *ctx, const char *obj_path, const line *ln, const char *p,
                         materials *m) {
    char *name = rest_of_line(ctx, p, ln->end);
    char *mtl = name ? pen__io_path_resolve(ctx, obj_path, name) : NULL;
    pen_status s = mtl ? mtl_read(ctx, mtl, m) : PEN_ERROR_MEMORY;
    free(name);
    free(mtl);
    return s;
}

/* ---- OBJ ------------------------------------------------------------------------------------- */

typedef struct obj_state {
    pen_context *ctx;
    const char *path;
    pen_mesh *mesh;
    long nv, nvt, nvn; /* final counts (pass 1) */
    long seen_v, seen_vt, seen_vn;
    long tri;           /* triangles written so far */
    int has_vt, has_vn; /* -1: not decided yet (no face seen) */
    long colored_v;     /* v statements with a colour (pass 1) */
    int material;       /* the current usemtl's index, -1 for none */
    materials mats;
} obj_state;

/* Parses `count` numbers of a v / vt / vn statement into out (at least `required`; the others
 * default to 0; extra numbers such as vertex colours are ignored). */
static pen_status parse_floats(obj_state *st, const line *ln, const char *p, int required,
                               int count, float *out) {
    for (int k = 0; k < count; ++k) {
        skip_blanks(&p, ln->end);
        if (p == ln->end) {
            if (k < required)
                return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: expected %d numbers, got %d",
                                  st->path, ln->number, required, k);
            out[k] = 0.0f;
            continue;
        }
        char *stop = NULL;
        errno = 0;
        double v = strtod(p, &stop);
        if (stop == p || stop > ln->end || (stop < ln->end && *stop != ' ' && *stop != '\t'))
            return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: malformed number '%.*s'", st->path,
                              ln->number, (int)strcspn(p, " \t\r\n"), p);
        if (!isfinite(v) || !isfinite((float)v))
            return pen__error(st->ctx, PEN_ERROR_PARSE,
                              "%s:%d: coordinate %d is not a finite float ('%.*s')", st->path,
                              ln->number, k + 1, (int)(stop - p), p);
        out[k] = (float)v;
        p = stop;
    }
    return PEN_OK;
}

/* Resolves one OBJ index (1-based, or negative relative to `seen`) to a 0-based one in
 * [0, total). `kind` names the array for messages. */
static pen_status resolve_index(obj_state *st, const line *ln, long idx, long seen, long total,
                                const char *kind, uint32_t *out) {
    if (idx == 0)
        return pen__error(st->ctx, PEN_ERROR_PARSE,
                          "%s:%d: %s index 0 is invalid (OBJ indices start at 1)", st->path,
                          ln->number, kind);
    if (idx < 0) {
        /* idx < -seen rather than -idx > seen: negating LONG_MIN is undefined. */
        if (idx < -seen)
            return pen__error(st->ctx, PEN_ERROR_PARSE,
                              "%s:%d: relative %s index %ld reaches before the first one "
                              "(%ld defined so far)",
                              st->path, ln->number, kind, idx, seen);
        *out = (uint32_t)(seen + idx);
        return PEN_OK;
    }
    if (idx > total)
        return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: %s index %ld out of range [1, %ld]",
                          st->path, ln->number, kind, idx, total);
    *out = (uint32_t)(idx - 1);
    return PEN_OK;
}

/* Parses an integer of a face corner; *p advances past it. */
static int parse_long(const char **p, const char *end, long *out) {
    char *stop = NULL;
    errno = 0;
    long v = strtol(*p, &stop, 10);
    if (stop == *p || stop > end || errno) return 0;
    *p = stop;
    *out = v;
    return 1;
}

typedef struct corner {
    uint32_t v, vt, vn;
} corner;

/* Parses one corner token "v", "v/vt", "v//vn" or "v/vt/vn" spanning [t, t + n). */
static pen_status parse_corner(obj_state *st, const line *ln, const char *t, size_t n, corner *c) {
    const char *p = t, *end = t + n;
    long iv = 0, ivt = 0, ivn = 0;
    int has_vt = 0, has_vn = 0;
    int ok = parse_long(&p, end, &iv);
    if (ok && p < end && *p == '/') {
        ++p;
        if (p < end && *p != '/') {
            ok = parse_long(&p, end, &ivt);
            has_vt = 1;
        }
        if (ok && p < end && *p == '/') {
            ++p;
            ok = parse_long(&p, end, &ivn);
            has_vn = 1;
        } else if (!has_vt) {
            ok = 0; /* "1/" */
        }
    }
    if (!ok || p != end)
        return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: malformed face corner '%.*s'", st->path,
                          ln->number, (int)n, t);
    if (st->has_vt < 0) {
        st->has_vt = has_vt;
        st->has_vn = has_vn;
    } else if (has_vt != st->has_vt || has_vn != st->has_vn) {
        return pen__error(st->ctx, PEN_ERROR_PARSE,
                          "%s:%d: face corner '%.*s' mixes reference kinds (earlier corners %s "
                          "texture coordinates and %s normals)",
                          st->path, ln->number, (int)n, t, st->has_vt ? "have" : "have no",
                          st->has_vn ? "have" : "have no");
    }
    pen_status s = resolve_index(st, ln, iv, st->seen_v, st->nv, "vertex", &c->v);
    if (!s && has_vt)
        s = resolve_index(st, ln, ivt, st->seen_vt, st->nvt, "texture coordinate", &c->vt);
    if (!s && has_vn) s = resolve_index(st, ln, ivn, st->seen_vn, st->nvn, "normal", &c->vn);
    return s;
}

static void put_triangle(obj_state *st, const corner *a, const corner *b, const corner *c) {
    pen_mesh *m = st->mesh;
    if (m->triangle_materials) m->triangle_materials[st->tri] = st->material;
    size_t o = 3 * (size_t)st->tri++;
    const corner *k[3] = {a, b, c};
    for (int i = 0; i < 3; ++i) {
        m->indices[o + i] = k[i]->v;
        if (st->has_vt) m->uv_indices[o + i] = k[i]->vt;
        if (st->has_vn) m->normal_indices[o + i] = k[i]->vn;
    }
}

static pen_status parse_face(obj_state *st, const line *ln, const char *p) {
    corner first = {0, 0, 0}, prev = first, cur = first;
    int n = 0;
    const char *t;
    size_t len;
    while ((len = next_token(&p, ln->end, &t)) > 0) {
        pen_status s = parse_corner(st, ln, t, len, &cur);
        if (s) return s;
        if (n == 0) first = cur;
        if (n >= 2) put_triangle(st, &first, &prev, &cur);
        prev = cur;
        ++n;
    }
    if (n < 3)
        return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: face with %d corner%s (needs 3)",
                          st->path, ln->number, n, n == 1 ? "" : "s");
    return PEN_OK;
}

/* Pass 1: counts. Faces contribute (corners - 2) triangles. */
static pen_status count_elements(obj_state *st, const char *text, size_t size, long *tris) {
    const char *cursor = text;
    line ln = {0};
    *tris = 0;
    while (next_line(&cursor, text + size, &ln)) {
        const char *p = ln.p, *t;
        size_t n = next_token(&p, ln.end, &t);
        if (token_is(t, n, "v")) {
            ++st->nv;
            int numbers = 0;
            while (next_token(&p, ln.end, &t) > 0)
                ++numbers;
            st->colored_v += numbers == 6;
        } else if (token_is(t, n, "vt")) {
            ++st->nvt;
        } else if (token_is(t, n, "vn")) {
            ++st->nvn;
        } else if (token_is(t, n, "f")) {
            long corners = 0;
            while (next_token(&p, ln.end, &t) > 0)
                ++corners;
            if (corners > 2) *tris += corners - 2;
        } else if (token_is(t, n, "mtllib")) {
            pen_status s = mtllib(st->ctx, st->path, &ln, p, &st->mats);
            if (s) return s;
        }
        if ((size_t)st->nv > PEN_MAX_ELEMENTS || (size_t)st->nvt > PEN_MAX_ELEMENTS ||
            (size_t)st->nvn > PEN_MAX_ELEMENTS || (size_t)*tris > PEN_MAX_ELEMENTS)
            return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: more than %zu elements of one kind",
                              st->path, ln.number, (size_t)PEN_MAX_ELEMENTS);
    }
    if (st->nv == 0) return pen__error(st->ctx, PEN_ERROR_PARSE, "%s: no vertices", st->path);
    if (*tris == 0) return pen__error(st->ctx, PEN_ERROR_PARSE, "%s: no faces", st->path);
    return materials_sort(st->ctx, &st->mats);
}

/* usemtl: later faces get the named material (-1 if no MTL file defines it: they keep the
 * object's default albedo, like faces before any usemtl). mesh.texture_path keeps its meaning
 * from before materials were kept per face: the first usemtl'd material with a map_Kd. */
static pen_status use_material(obj_state *st, const line *ln, const char *p) {
    char *name = rest_of_line(st->ctx, p, ln->end);
    if (!name) return PEN_ERROR_MEMORY;
    st->material = materials_find(&st->mats, name);
    free(name);
    const pen_mesh_material *mt = st->material >= 0 ? &st->mats.items[st->material] : NULL;
    if (!st->mesh->texture_path && mt && mt->texture_path) {
        st->mesh->texture_path = pen__io_strdup(st->ctx, mt->texture_path);
        if (!st->mesh->texture_path) return PEN_ERROR_MEMORY;
    }
    return PEN_OK;
}

/* v x y z [w] or v x y z r g b: the colour, written as sRGB-encoded values in [0, 1] by the tools
 * that write it (MeshLab, Open3D: the 8-bit colour / 255), is decoded to linear. */
static pen_status parse_vertex(obj_state *st, const line *ln, const char *p) {
    pen_mesh *m = st->mesh;
    float v[6];
    const size_t i = (size_t)st->seen_v++;
    pen_status s = parse_floats(st, ln, p, m->colors ? 6 : 3, m->colors ? 6 : 3, v);
    if (s) return s;
    memcpy(m->positions + 3 * i, v, 3 * sizeof(float));
    for (int k = 0; m->colors && k < 3; ++k) {
        if (!(v[3 + k] >= 0.0f && v[3 + k] <= 1.0f))
            return pen__error(st->ctx, PEN_ERROR_PARSE,
                              "%s:%d: vertex colour %g is not in [0, 1] (colours after x y z are "
                              "read as r g b in [0, 1])",
                              st->path, ln->number, (double)v[3 + k]);
        m->colors[3 * i + (size_t)k] = (float)pen__srgb_to_linear(v[3 + k]);
    }
    return PEN_OK;
}

/* Pass 2: fill the arrays. */
static pen_status parse_elements(obj_state *st, const char *text, size_t size) {
    pen_mesh *m = st->mesh;
    const char *cursor = text;
    line ln = {0};
    pen_status s = PEN_OK;
    while (!s && next_line(&cursor, text + size, &ln)) {
        const char *p = ln.p, *t;
        size_t n = next_token(&p, ln.end, &t);
        if (token_is(t, n, "v")) {
            s = parse_vertex(st, &ln, p);
        } else if (token_is(t, n, "vt")) {
            s = parse_floats(st, &ln, p, 1, 2, m->uvs + 2 * st->seen_vt++);
        } else if (token_is(t, n, "vn")) {
            s = parse_floats(st, &ln, p, 3, 3, m->normals + 3 * st->seen_vn++);
        } else if (token_is(t, n, "f")) {
            s = parse_face(st, &ln, p);
        } else if (token_is(t, n, "usemtl")) {
            s = use_material(st, &ln, p);
        }
    }
    return s;
}

pen_status pen_mesh_load_obj(pen_context *ctx, const char *path, pen_mesh *out) {
    memset(out, 0, sizeof *out);
    char *text = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, OBJ_MAX_BYTES, &text, &size);
    if (s) return s;
    obj_state st = {
        .ctx = ctx, .path = path, .mesh = out, .has_vt = -1, .has_vn = -1, .material = -1};
    long tris = 0;
    s = count_elements(&st, text, size, &tris);
    if (!s) {
        out->vertex_count = (int)st.nv;
        out->triangle_count = (int)tris;
        out->positions = pen__malloc(ctx, 3 * (size_t)st.nv, sizeof(float), path);
        out->indices = pen__malloc(ctx, 3 * (size_t)tris, sizeof(uint32_t), path);
        out->uvs = pen__malloc(ctx, 2 * (size_t)st.nvt, sizeof(float), path);
        out->uv_indices = pen__malloc(ctx, 3 * (size_t)tris, sizeof(uint32_t), path);
        out->normals = pen__malloc(ctx, 3 * (size_t)st.nvn, sizeof(float), path);
        out->normal_indices = pen__malloc(ctx, 3 * (size_t)tris, sizeof(uint32_t), path);
        if (!out->positions || !out->indices || !out->uvs || !out->uv_indices || !out->normals ||
            !out->normal_indices)
            s = PEN_ERROR_MEMORY;
        /* Colours only when every vertex has one: a file that colours some vertices only is
         * read for its geometry. */
        if (!s && st.colored_v == st.nv) {
            out->colors = pen__malloc(ctx, 3 * (size_t)st.nv, sizeof(float), path);
            if (!out->colors) s = PEN_ERROR_MEMORY;
        }
        if (!s && st.mats.count > 0) {
            out->triangle_materials = pen__malloc(ctx, (size_t)tris, sizeof(int32_t), path);
            if (!out->triangle_materials) s = PEN_ERROR_MEMORY;
        }
    }
    if (!s) s = parse_elements(&st, text, size);
    free(text);
    if (!s && st.mats.count > 0) { /* the mesh takes the materials over */
        out->materials = st.mats.items;
        out->material_count = st.mats.count;
        st.mats.items = NULL;
        st.mats.count = 0;
    }
    materials_free(&st.mats);
    if (s) {
        pen_mesh_free(out);
        return s;
    }
    /* Keep UVs and normals only when the faces use them. */
    if (st.has_vt == 1) {
        out->uv_count = (int)st.nvt;
    } else {
        free(out->uvs);
        free(out->uv_indices);
        out->uvs = NULL;
        out->uv_indices = NULL;
    }
    if (st.has_vn == 1) {
        out->normal_count = (int)st.nvn;
    } else {
        free(out->normals);
        free(out->normal_indices);
        out->normals = NULL;
        out->normal_indices = NULL;
    }
    return PEN_OK;
}

/* ---- The files an OBJ names ------------------------------------------------------------------ */

/* The loader passes over a library it cannot open and opens no texture (see the design note
 * above); this lists what the file names and whether each exists, for `penumbra info` and
 * pen_scene_check. The same line splitting, tokens and MTL reader as the loader, so both see the
 * same files; the OBJ itself is streamed, not held. A library named twice is listed once. */

#define FILES_LINE_MAX 8192 /* bytes of an mtllib line (a path) */

static int can_open(const char *path) {
    FILE *f = fopen(path, "rb");
    if (f) fclose(f);
    return f != NULL;
}

/* Appends an entry; takes `path`, `source` and `material` over (freeing them on failure). */
static pen_status files_add(pen_context *ctx, pen_mesh_files *out, int *cap,
                            pen_mesh_file_kind kind, char *path, char *source, char *material) {
    if (path && source && out->count == *cap) {
        const int grown = *cap ? 2 * *cap : 8;
        pen_mesh_file *f = realloc(out->files, (size_t)grown * sizeof *f);
        if (f) out->files = f, *cap = grown;
    }
    if (!path || !source || out->count == *cap) {
        free(path);
        free(source);
        free(material);
        return pen__error(ctx, PEN_ERROR_MEMORY, "out of memory listing a mesh's files");
    }
    out->files[out->count++] = (pen_mesh_file){kind, path, source, material, can_open(path)};
    return PEN_OK;
}

static int listed(const pen_mesh_files *out, const char *path) {
    for (int i = 0; i < out->count; ++i)
        if (out->files[i].kind == PEN_MESH_FILE_MTLLIB && strcmp(out->files[i].path, path) == 0)
            return 1;
    return 0;
}

/* What pen_mesh_files_load gathers: the entries, the materials of the libraries found. */
typedef struct files_state {
    pen_context *ctx;
    const char *path;
    pen_mesh_files *out;
    int cap, libraries;
    materials mats;
} files_state;

/* One line of the OBJ: an mtllib adds its library (once) and reads the materials it defines.
 * `cut`: the line was longer than the part held. */
static pen_status library_line(files_state *st, const line *ln, int cut) {
    const char *p = ln->p, *t;
    size_t n = next_token(&p, ln->end, &t);
    if (!token_is(t, n, "mtllib")) return PEN_OK;
    if (cut)
        return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: mtllib line longer than %d bytes",
                          st->path, ln->number, FILES_LINE_MAX);
    char *name = rest_of_line(st->ctx, p, ln->end);
    char *mtl = name ? pen__io_path_resolve(st->ctx, st->path, name) : NULL;
    free(name);
    if (mtl && listed(st->out, mtl)) {
        free(mtl);
        return PEN_OK;
    }
    if (mtl && ++st->libraries > PEN_MESH_FILES_MAX_LIBRARIES) {
        free(mtl);
        return pen__error(st->ctx, PEN_ERROR_PARSE, "%s:%d: more than %d material libraries",
                          st->path, ln->number, PEN_MESH_FILES_MAX_LIBRARIES);
    }
    pen_status s = files_add(st->ctx, st->out, &st->cap, PEN_MESH_FILE_MTLLIB, mtl,
                             source_of(st->ctx, st->path, ln->number), NULL);
    if (!s && st->out->files[st->out->count - 1].found) s = mtl_read(st->ctx, mtl, &st->mats);
    return s;
}

/* Streams the OBJ in chunks, holding the first FILES_LINE_MAX bytes of each line only: the file
 * may be large and only its mtllib lines matter. Lines end at '\n' (a '\r' before it dropped), as
 * the loader splits them. */
static pen_status scan_libraries(files_state *st, FILE *f) {
    enum { CHUNK = 1 << 16 };
    char *chunk = pen__malloc(st->ctx, CHUNK, 1, "mesh files");
    char *head = pen__malloc(st->ctx, FILES_LINE_MAX, 1, "mesh files");
    pen_status s = chunk && head ? PEN_OK : PEN_ERROR_MEMORY;
    size_t kept = 0, got;
    int cut = 0, number = 1, pending = 0;
    while (!s && (got = fread(chunk, 1, CHUNK, f)) > 0) {
        for (size_t i = 0; !s && i < got; ++i) {
            if (chunk[i] != '\n') {
                if (kept < FILES_LINE_MAX)
                    head[kept++] = chunk[i];
                else
                    cut = 1;
                pending = 1;
                continue;
            }
            const size_t n = kept > 0 && head[kept - 1] == '\r' ? kept - 1 : kept;
            s = library_line(st, &(line){head, head + n, number++}, cut);
            kept = 0, cut = 0, pending = 0;
        }
    }
    if (!s && ferror(f)) s = pen__error(st->ctx, PEN_ERROR_IO, "%s: read error", st->path);
    if (!s && pending) {
        const size_t n = kept > 0 && head[kept - 1] == '\r' ? kept - 1 : kept;
        s = library_line(st, &(line){head, head + n, number}, cut);
    }
    free(chunk);
    free(head);
    return s;
}

pen_status pen_mesh_files_load(pen_context *ctx, const char *path, pen_mesh_files *out) {
    memset(out, 0, sizeof *out);
    if (!path) return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh files: no path");
    if (!pen__io_has_ext(path, "obj")) return PEN_OK; /* PLY names no file */
    FILE *f = fopen(path, "rb");
    if (!f) return pen__error(ctx, PEN_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    files_state st = {.ctx = ctx, .path = path, .out = out};
    pen_status s = scan_libraries(&st, f);
    fclose(f);
    for (int k = 0; !s && k < st.mats.count; ++k) {
        const pen_mesh_material *m = &st.mats.items[k];
        if (!m->texture_path) continue;
        s = files_add(ctx, out, &st.cap, PEN_MESH_FILE_TEXTURE,
                      pen__io_strdup(ctx, m->texture_path), pen__io_strdup(ctx, m->texture_source),
                      pen__io_strdup(ctx, m->name));
    }
    materials_free(&st.mats);
    if (s) pen_mesh_files_free(out);
    return s;
}

void pen_mesh_files_free(pen_mesh_files *files) {
    if (!files) return;
    for (int i = 0; i < files->count; ++i) {
        free(files->files[i].path);
        free(files->files[i].source);
        free(files->files[i].material);
    }
    free(files->files);
    memset(files, 0, sizeof *files);
}

/* ---- Writing --------------------------------------------------------------------------------- */

pen_status pen_mesh_save_obj(pen_context *ctx, const char *path, const pen_mesh *mesh) {
    pen_status s = pen_mesh_validate(ctx, mesh);
    if (s) return s;
    char *tmp = NULL;
    s = pen__io_temp_create(ctx, path, &tmp);
    if (s) return s;
    FILE *f = fopen(tmp, "w");
    if (!f) {
        pen__io_temp_discard(tmp);
        return pen__error(ctx, PEN_ERROR_IO, "%s: cannot write", path);
    }
    fprintf(f, "# penumbra %s: %d vertices, %d triangles\n", pen_version(), mesh->vertex_count,
            mesh->triangle_count);
    for (int i = 0; i < mesh->vertex_count; ++i) {
        const float *p = mesh->positions + 3 * (size_t)i;
        fprintf(f, "v %.9g %.9g %.9g\n", (double)p[0], (double)p[1], (double)p[2]);
    }
    for (int i = 0; i < mesh->uv_count; ++i) {
        const float *t = mesh->uvs + 2 * (size_t)i;
        fprintf(f, "vt %.9g %.9g\n", (double)t[0], (double)t[1]);
    }
    for (int i = 0; i < mesh->normal_count; ++i) {
        const float *n = mesh->normals + 3 * (size_t)i;
        fprintf(f, "vn %.9g %.9g %.9g\n", (double)n[0], (double)n[1], (double)n[2]);
    }
    for (int t = 0; t < mesh->triangle_count; ++t) {
        fputc('f', f);
        for (int k = 0; k < 3; ++k) {
            size_t c = 3 * (size_t)t + (size_t)k;
            fprintf(f, " %u", mesh->indices[c] + 1);
            if (mesh->uv_count) fprintf(f, "/%u", mesh->uv_indices[c] + 1);
            if (mesh->normal_count)
                fprintf(f, mesh->uv_count ? "/%u" : "//%u", mesh->normal_indices[c] + 1);
        }
        fputc('\n', f);
    }
    int failed = ferror(f);
    if (fclose(f) != 0 || failed) {
        pen__io_temp_discard(tmp);
        return pen__error(ctx, PEN_ERROR_IO, "%s: write error", path);
    }
    return pen__io_temp_commit(ctx, tmp, path);
}
