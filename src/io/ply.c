/* Stanford PLY meshes: ascii, binary_little_endian and binary_big_endian.
 *
 * The header declares elements (name, count) and their properties (scalar, or list with a count
 * type and an item type). penumbra reads the `vertex` element's x, y, z, optional texture
 * coordinates (s/t, u/v, texture_u/texture_v or texture_s/texture_t), normals (nx, ny, nz) and
 * colours (red, green, blue or diffuse_red, ...: uchar and ushort as sRGB codes, decoded to
 * linear like textures; float and double as linear values, clamped to [0, 1]), and the `face`
 * element's vertex_indices (or vertex_index) list; every other element and property is read and
 * skipped, so their layout must still be valid. Polygons are triangulated as fans. Per-vertex
 * UVs, normals and colours share the position indices.
 *
 * Distrust: element counts are capped (PEN_MAX_ELEMENTS) and checked against the bytes left in
 * the file before anything is allocated, so an absurd header fails at once instead of asking for
 * gigabytes; every read checks the end of the data (truncation), integer values must be integral
 * and in their type's range, indices must be in range, coordinates finite. Errors name the line
 * (ascii) or the byte offset (binary). */
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#define PLY_MAX_BYTES ((size_t)1 << 34)
#define PLY_MAX_ELEMENTS 64
#define PLY_MAX_PROPERTIES 64
#define PLY_MAX_LIST 4096 /* corners of one polygon */
/* Header lines: comments and obj_info may be long (tools write paths and provenance there) and
 * are skipped without copying, up to this bound; any other line has at most five short words. */
#define PLY_MAX_COMMENT_LINE ((size_t)1 << 16)
#define PLY_MAX_HEADER_LINE 1024

typedef enum ply_type { T_NONE, T_I8, T_U8, T_I16, T_U16, T_I32, T_U32, T_F32, T_F64 } ply_type;
typedef enum ply_format { F_ASCII, F_LE, F_BE } ply_format;

static const struct {
    const char *names[2];
    int size;
    double lo, hi;
} type_info[] = {
    [T_NONE] = {{"", ""}, 0, 0, 0},
    [T_I8] = {{"char", "int8"}, 1, -128, 127},
    [T_U8] = {{"uchar", "uint8"}, 1, 0, 255},
    [T_I16] = {{"short", "int16"}, 2, -32768, 32767},
    [T_U16] = {{"ushort", "uint16"}, 2, 0, 65535},
    [T_I32] = {{"int", "int32"}, 4, -2147483648.0, 2147483647.0},
    [T_U32] = {{"uint", "uint32"}, 4, 0, 4294967295.0},
    [T_F32] = {{"float", "float32"}, 4, 0, 0},
    [T_F64] = {{"double", "float64"}, 8, 0, 0},
};

static int is_float_type(ply_type t) {
    return t == T_F32 || t == T_F64;
}

typedef struct ply_property {
    char name[64];
    ply_type type;       /* scalar type, or the item type of a list */
    ply_type count_type; /* T_NONE for scalars */
} ply_property;

typedef struct ply_element {
    char name[64];
    size_t count;
    int property_count;
    ply_property props[PLY_MAX_PROPERTIES];
} ply_element;

typedef struct ply_header {
    ply_format format;
    int element_count;
    ply_element elements[PLY_MAX_ELEMENTS];
} ply_header;

typedef struct ply_reader {
    pen_context *ctx;
    const char *path;
    const char *begin, *p, *end; /* whole file; cursor; end */
    ply_format format;
    int line; /* ascii: line of the cursor */
    /* ascii: the row being read (one row a line): its element, index, and whether a value of it
     * has been read yet, so that a line ending early is an error instead of the next line's
     * values silently filling this row. */
    const char *row_element;
    size_t row;
    int row_values;
} ply_reader;

/* Records an error at the reader's place: "file:line: what" (ascii) or "file: byte N: what". */
static pen_status ply_error(const ply_reader *r, const char *fmt, ...) PEN_PRINTF(2, 3);
static pen_status ply_error(const ply_reader *r, const char *fmt, ...) {
    char what[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    if (r->format == F_ASCII)
        return pen__error(r->ctx, PEN_ERROR_PARSE, "%s:%d: %s", r->path, r->line, what);
    return pen__error(r->ctx, PEN_ERROR_PARSE, "%s: byte %zu: %s", r->path,
                      (size_t)(r->p - r->begin), what);
}

/* ---- Header ---------------------------------------------------------------------------------- */

static ply_type parse_type(const char *word) {
    for (int t = T_I8; t <= T_F64; ++t)
        if (strcmp(word, type_info[t].names[0]) == 0 || strcmp(word, type_info[t].names[1]) == 0)
            return (ply_type)t;
    return T_NONE;
}

/* Parses the header; on success r->p points at the first byte of data. */
static pen_status parse_header(ply_reader *r, ply_header *h) {
    memset(h, 0, sizeof *h);
    r->format = F_ASCII; /* header errors are reported by line */
    r->line = 0;
    int have_format = 0;
    for (;;) {
        const char *nl = memchr(r->p, '\n', (size_t)(r->end - r->p));
        ++r->line;
        if (!nl) return ply_error(r, "header does not end with end_header");
        char buf[PLY_MAX_HEADER_LINE];
        size_t n = (size_t)(nl - r->p);
        if (n >= sizeof buf) {
            const char *w = r->p;
            while (w < nl && (*w == ' ' || *w == '\t'))
                ++w;
            const size_t left = (size_t)(nl - w);
            const int remark = (left >= 8 && memcmp(w, "comment", 7) == 0 &&
                                (w[7] == ' ' || w[7] == '\t')) ||
                               (left >= 9 && memcmp(w, "obj_info", 8) == 0 &&
                                (w[8] == ' ' || w[8] == '\t'));
            if (!remark)
                return ply_error(r, "header line of %zu bytes (the limit is %d)", n,
                                 PLY_MAX_HEADER_LINE - 1);
            if (n > PLY_MAX_COMMENT_LINE)
                return ply_error(r, "header comment of %zu bytes (the limit is %zu)", n,
                                 PLY_MAX_COMMENT_LINE);
            r->p = nl + 1;
            continue;
        }
        memcpy(buf, r->p, n);
        buf[n] = '\0';
        if (n && buf[n - 1] == '\r') buf[n - 1] = '\0';
        r->p = nl + 1;
        char w0[64] = "", w1[64] = "", w2[64] = "", w3[64] = "", w4[64] = "";
        int words = sscanf(buf, "%63s %63s %63s %63s %63s", w0, w1, w2, w3, w4);
        if (r->line == 1) {
            if (strcmp(w0, "ply") != 0 || words != 1)
                return ply_error(r, "not a PLY file (no 'ply' magic)");
            continue;
        }
        if (words <= 0 || strcmp(w0, "comment") == 0 || strcmp(w0, "obj_info") == 0) continue;
        if (strcmp(w0, "end_header") == 0) break;
        if (strcmp(w0, "format") == 0) {
            if (words != 3 || strcmp(w2, "1.0") != 0)
                return ply_error(r, "malformed format line '%s'", buf);
            if (strcmp(w1, "ascii") == 0)
                h->format = F_ASCII;
            else if (strcmp(w1, "binary_little_endian") == 0)
                h->format = F_LE;
            else if (strcmp(w1, "binary_big_endian") == 0)
                h->format = F_BE;
            else
                return ply_error(r, "unknown format '%s'", w1);
            have_format = 1;
        } else if (strcmp(w0, "element") == 0) {
            if (words != 3) return ply_error(r, "malformed element line '%s'", buf);
            if (h->element_count == PLY_MAX_ELEMENTS) return ply_error(r, "too many elements");
            char *stop = NULL;
            errno = 0;
            unsigned long long count = strtoull(w2, &stop, 10);
            if (*stop || errno || w2[0] == '-')
                return ply_error(r, "malformed element count '%s'", w2);
            if (count > PEN_MAX_ELEMENTS)
                return ply_error(r, "element '%s' count %llu exceeds the limit of %zu", w1, count,
                                 (size_t)PEN_MAX_ELEMENTS);
            ply_element *e = &h->elements[h->element_count++];
            snprintf(e->name, sizeof e->name, "%s", w1);
            e->count = (size_t)count;
        } else if (strcmp(w0, "property") == 0) {
            if (h->element_count == 0) return ply_error(r, "property before any element");
            ply_element *e = &h->elements[h->element_count - 1];
            if (e->property_count == PLY_MAX_PROPERTIES) return ply_error(r, "too many properties");
            ply_property *pr = &e->props[e->property_count++];
            if (strcmp(w1, "list") == 0) {
                if (words != 5) return ply_error(r, "malformed list property '%s'", buf);
                pr->count_type = parse_type(w2);
                pr->type = parse_type(w3);
                snprintf(pr->name, sizeof pr->name, "%s", w4);
                if (pr->count_type == T_NONE || pr->type == T_NONE)
                    return ply_error(r, "unknown type in '%s'", buf);
                if (is_float_type(pr->count_type))
                    return ply_error(r, "list count type must be an integer type in '%s'", buf);
            } else {
                if (words != 3) return ply_error(r, "malformed property '%s'", buf);
                pr->type = parse_type(w1);
                snprintf(pr->name, sizeof pr->name, "%s", w2);
                if (pr->type == T_NONE) return ply_error(r, "unknown type '%s'", w1);
            }
        } else {
            return ply_error(r, "unknown header line '%s'", buf);
        }
    }
    if (!have_format) return ply_error(r, "no format line");
    r->format = h->format;
    ++r->line; /* ascii data starts on the line after end_header */
    return PEN_OK;
}

/* ---- Values ---------------------------------------------------------------------------------- */

/* The value of a binary scalar: bytes put in host order, then reinterpreted. */
#define DECODE_AS(type)                                                                            \
    do {                                                                                           \
        type x_;                                                                                   \
        memcpy(&x_, v, sizeof x_);                                                                 \
        return (double)x_;                                                                         \
    } while (0)

static double decode_binary(const unsigned char *b, ply_type t, int big_endian) {
    const uint16_t one = 1;
    const int host_big = *(const unsigned char *)&one == 0;
    unsigned char v[8];
    int n = type_info[t].size;
    for (int i = 0; i < n; ++i)
        v[i] = big_endian != host_big ? b[n - 1 - i] : b[i];
    switch (t) {
    case T_I8:
        DECODE_AS(int8_t);
    case T_U8:
        DECODE_AS(uint8_t);
    case T_I16:
        DECODE_AS(int16_t);
    case T_U16:
        DECODE_AS(uint16_t);
    case T_I32:
        DECODE_AS(int32_t);
    case T_U32:
        DECODE_AS(uint32_t);
    case T_F32:
        DECODE_AS(float);
    case T_F64:
        DECODE_AS(double);
    case T_NONE:
        break;
    }
    return 0.0;
}

/* Reads one value of type t at the cursor. */
static pen_status read_value(ply_reader *r, ply_type t, double *out) {
    if (r->format != F_ASCII) {
        size_t n = (size_t)type_info[t].size;
        if ((size_t)(r->end - r->p) < n) return ply_error(r, "file truncated");
        *out = decode_binary((const unsigned char *)r->p, t, r->format == F_BE);
        r->p += n;
        return PEN_OK;
    }
    while (r->p < r->end && (*r->p == ' ' || *r->p == '\t' || *r->p == '\r' || *r->p == '\n')) {
        if (*r->p == '\n') {
            if (r->row_values > 0)
                return ply_error(r, "%s %zu: the line ends after %d values, before the header's "
                                    "properties are all read",
                                 r->row_element, r->row, r->row_values);
            ++r->line;
        }
        ++r->p;
    }
    if (r->p == r->end) return ply_error(r, "file truncated");
    char *stop = NULL;
    double v = strtod(r->p, &stop);
    if (stop == r->p ||
        (stop < r->end && *stop != ' ' && *stop != '\t' && *stop != '\r' && *stop != '\n'))
        return ply_error(r, "malformed number '%.*s'", (int)strcspn(r->p, " \t\r\n"), r->p);
    if (!is_float_type(t) && (v != floor(v) || v < type_info[t].lo || v > type_info[t].hi))
        return ply_error(r, "'%.*s' is not a valid %s", (int)(stop - r->p), r->p,
                         type_info[t].names[0]);
    r->p = stop;
    ++r->row_values;
    *out = v;
    return PEN_OK;
}

/* Ascii rows are lines: begin_row marks the start of row `row` of `element`; end_row checks that
 * nothing but blanks follows its last value on the line. Binary rows have no delimiters. */
static void begin_row(ply_reader *r, const char *element, size_t row) {
    r->row_element = element;
    r->row = row;
    r->row_values = 0;
}

static pen_status end_row(ply_reader *r) {
    if (r->format != F_ASCII) return PEN_OK;
    while (r->p < r->end && (*r->p == ' ' || *r->p == '\t' || *r->p == '\r'))
        ++r->p;
    if (r->p < r->end && *r->p != '\n')
        return ply_error(r, "%s %zu: more values on the line than the header's %d", r->row_element,
                         r->row, r->row_values);
    r->row_values = 0;
    return PEN_OK;
}

/* Reads a list's count (checked against PLY_MAX_LIST and, in binary, the bytes left). */
static pen_status read_list_count(ply_reader *r, const ply_property *pr, size_t *count) {
    double c;
    pen_status s = read_value(r, pr->count_type, &c);
    if (s) return s;
    if (c < 0 || c > PLY_MAX_LIST)
        return ply_error(r, "list '%s' has %g items (limit %d)", pr->name, c, PLY_MAX_LIST);
    *count = (size_t)c;
    if (r->format != F_ASCII && *count * (size_t)type_info[pr->type].size > (size_t)(r->end - r->p))
        return ply_error(r, "file truncated");
    return PEN_OK;
}

/* Reads and discards one property value (scalar or list). */
static pen_status skip_property(ply_reader *r, const ply_property *pr) {
    size_t n = 1;
    if (pr->count_type != T_NONE) {
        pen_status s = read_list_count(r, pr, &n);
        if (s) return s;
    }
    for (size_t i = 0; i < n; ++i) {
        double v;
        pen_status s = read_value(r, pr->type, &v);
        if (s) return s;
    }
    return PEN_OK;
}

/* Before reading an element's rows: do `count` rows fit in what is left of the file? In binary
 * each row takes at least the sizes of its scalars and list counts; in ascii at least one
 * character and one separator per value. This rejects an absurd count before allocating. */
static pen_status check_rows_fit(ply_reader *r, const ply_element *e) {
    size_t min_row = 0;
    for (int i = 0; i < e->property_count; ++i) {
        const ply_property *pr = &e->props[i];
        ply_type t = pr->count_type != T_NONE ? pr->count_type : pr->type;
        min_row += r->format == F_ASCII ? 2 : (size_t)type_info[t].size;
    }
    size_t left = (size_t)(r->end - r->p) + (r->format == F_ASCII ? 1 : 0);
    if (min_row > 0 && e->count > left / min_row)
        return ply_error(r,
                         "file truncated: element '%s' declares %zu rows but only %zu bytes follow",
                         e->name, e->count, (size_t)(r->end - r->p));
    return PEN_OK;
}

/* ---- Elements -------------------------------------------------------------------------------- */

static int find_property(const ply_element *e, const char *name) {
    for (int i = 0; i < e->property_count; ++i)
        if (strcmp(e->props[i].name, name) == 0 && e->props[i].count_type == T_NONE) return i;
    return -1;
}

/* The vertex colour properties (red, green, blue, or diffuse_red, ...): ic[] their indices, all -1
 * without colours. uchar and ushort hold sRGB-encoded codes (decoded to linear like 8- and
 * 16-bit textures); float and double hold linear values (clamped to [0, 1]). */
static pen_status find_colors(ply_reader *r, const ply_element *e, int ic[3]) {
    static const char *const names[][3] = {{"red", "green", "blue"},
                                           {"diffuse_red", "diffuse_green", "diffuse_blue"}};
    for (size_t k = 0; k < sizeof names / sizeof names[0]; ++k) {
        for (int c = 0; c < 3; ++c)
            ic[c] = find_property(e, names[k][c]);
        if (ic[0] < 0 || ic[1] < 0 || ic[2] < 0) {
            ic[0] = ic[1] = ic[2] = -1;
            continue;
        }
        for (int c = 0; c < 3; ++c) {
            const ply_property *pr = &e->props[ic[c]];
            const ply_type t = pr->type;
            if (pr->count_type != T_NONE || (t != T_U8 && t != T_U16 && !is_float_type(t)))
                return ply_error(r,
                                 "vertex property %s: a colour must be a uchar, ushort, float "
                                 "or double scalar",
                                 pr->name);
        }
        return PEN_OK;
    }
    return PEN_OK;
}

/* A colour value as linear in [0, 1] (see find_colors). */
static pen_status color_value(ply_reader *r, const ply_property *pr, size_t vertex, double v,
                              const float table8[256], double *out) {
    if (pr->type == T_U8) {
        *out = table8[(int)v];
    } else if (pr->type == T_U16) {
        *out = pen__srgb_to_linear(v / 65535.0);
    } else {
        if (!isfinite(v))
            return ply_error(r, "vertex %zu: colour %s is not finite", vertex, pr->name);
        *out = v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v;
    }
    return PEN_OK;
}

static pen_status read_vertices(ply_reader *r, const ply_element *e, pen_mesh *m) {
    int ix = find_property(e, "x"), iy = find_property(e, "y"), iz = find_property(e, "z");
    if (ix < 0 || iy < 0 || iz < 0) return ply_error(r, "vertex element lacks x, y or z");
    static const char *const uv_names[][2] = {
        {"s", "t"}, {"u", "v"}, {"texture_u", "texture_v"}, {"texture_s", "texture_t"}};
    int iu = -1, iv = -1;
    for (size_t k = 0; k < sizeof uv_names / sizeof uv_names[0] && iu < 0; ++k) {
        iu = find_property(e, uv_names[k][0]);
        iv = find_property(e, uv_names[k][1]);
        if (iu < 0 || iv < 0) iu = iv = -1;
    }
    int inx = find_property(e, "nx"), iny = find_property(e, "ny"), inz = find_property(e, "nz");
    int has_n = inx >= 0 && iny >= 0 && inz >= 0;
    int ic[3];
    pen_status cs = find_colors(r, e, ic);
    if (cs) return cs;
    size_t n = e->count;
    m->vertex_count = (int)n;
    m->positions = pen__malloc(r->ctx, 3 * n, sizeof(float), r->path);
    if (!m->positions) return PEN_ERROR_MEMORY;
    if (iu >= 0) {
        m->uvs = pen__malloc(r->ctx, 2 * n, sizeof(float), r->path);
        if (!m->uvs) return PEN_ERROR_MEMORY;
        m->uv_count = (int)n;
    }
    if (has_n) {
        m->normals = pen__malloc(r->ctx, 3 * n, sizeof(float), r->path);
        if (!m->normals) return PEN_ERROR_MEMORY;
        m->normal_count = (int)n;
    }
    float table8[256];
    if (ic[0] >= 0) {
        m->colors = pen__malloc(r->ctx, 3 * n, sizeof(float), r->path);
        if (!m->colors) return PEN_ERROR_MEMORY;
        pen__image_code_table(0, table8);
    }
    for (size_t i = 0; i < n; ++i) {
        begin_row(r, "vertex", i);
        for (int k = 0; k < e->property_count; ++k) {
            const ply_property *pr = &e->props[k];
            if (pr->count_type != T_NONE) {
                pen_status s = skip_property(r, pr);
                if (s) return s;
                continue;
            }
            double v;
            pen_status s = read_value(r, pr->type, &v);
            if (s) return s;
            float *dst = NULL;
            if (k == ix || k == iy || k == iz)
                dst = m->positions + 3 * i + (k == ix ? 0 : k == iy ? 1 : 2);
            else if (k == iu || k == iv)
                dst = m->uvs + 2 * i + (k == iu ? 0 : 1);
            else if (has_n && (k == inx || k == iny || k == inz))
                dst = m->normals + 3 * i + (k == inx ? 0 : k == iny ? 1 : 2);
            else if (k == ic[0] || k == ic[1] || k == ic[2]) {
                s = color_value(r, pr, i, v, table8, &v);
                if (s) return s;
                dst = m->colors + 3 * i + (k == ic[0] ? 0 : k == ic[1] ? 1 : 2);
            }
            if (!dst) continue;
            if (!isfinite(v) || !isfinite((float)v))
                return ply_error(r, "vertex %zu: %s is not a finite float", i, pr->name);
            *dst = (float)v;
        }
        pen_status s = end_row(r);
        if (s) return s;
    }
    return PEN_OK;
}

/* Appends triangles to a growing index array. */
typedef struct tri_list {
    uint32_t *idx;
    size_t count, cap; /* in triangles */
} tri_list;

static pen_status tri_push(ply_reader *r, tri_list *t, uint32_t a, uint32_t b, uint32_t c) {
    if (t->count == t->cap) {
        size_t cap = t->cap ? 2 * t->cap : 1024;
        if (t->count >= PEN_MAX_ELEMENTS)
            return ply_error(r, "more than %zu triangles", (size_t)PEN_MAX_ELEMENTS);
        if (cap > PEN_MAX_ELEMENTS) cap = PEN_MAX_ELEMENTS;
        uint32_t *grown = realloc(t->idx, cap * 3 * sizeof *grown);
        if (!grown)
            return pen__error(r->ctx, PEN_ERROR_MEMORY, "%s: cannot allocate triangles", r->path);
        t->idx = grown;
        t->cap = cap;
    }
    uint32_t *o = t->idx + 3 * t->count++;
    o[0] = a;
    o[1] = b;
    o[2] = c;
    return PEN_OK;
}

static pen_status read_faces(ply_reader *r, const ply_element *e, size_t vertex_count,
                             tri_list *t) {
    int iv = -1;
    for (int k = 0; k < e->property_count; ++k)
        if (e->props[k].count_type != T_NONE && (strcmp(e->props[k].name, "vertex_indices") == 0 ||
                                                 strcmp(e->props[k].name, "vertex_index") == 0))
            iv = k;
    if (iv < 0) return ply_error(r, "face element lacks a vertex_indices list");
    if (is_float_type(e->props[iv].type))
        return ply_error(r, "vertex_indices must have an integer type");
    for (size_t f = 0; f < e->count; ++f) {
        begin_row(r, "face", f);
        for (int k = 0; k < e->property_count; ++k) {
            const ply_property *pr = &e->props[k];
            pen_status s;
            if (k != iv) {
                if ((s = skip_property(r, pr))) return s;
                continue;
            }
            size_t n;
            if ((s = read_list_count(r, pr, &n))) return s;
            if (n < 3) return ply_error(r, "face %zu has %zu vertices (needs 3)", f, n);
            uint32_t first = 0, prev = 0;
            for (size_t c = 0; c < n; ++c) {
                double v;
                if ((s = read_value(r, pr->type, &v))) return s;
                if (v < 0 || v >= (double)vertex_count)
                    return ply_error(r, "face %zu: vertex index %.0f out of range [0, %zu)", f, v,
                                     vertex_count);
                uint32_t idx = (uint32_t)v;
                if (c == 0) first = idx;
                if (c >= 2 && (s = tri_push(r, t, first, prev, idx))) return s;
                prev = idx;
            }
        }
        pen_status s = end_row(r);
        if (s) return s;
    }
    return PEN_OK;
}

/* ---- Loading --------------------------------------------------------------------------------- */

static pen_status load(ply_reader *r, pen_mesh *m) {
    ply_header *h = malloc(sizeof *h);
    if (!h) return pen__error(r->ctx, PEN_ERROR_MEMORY, "%s: cannot allocate the header", r->path);
    pen_status s = parse_header(r, h);
    const ply_element *vertex = NULL, *face = NULL;
    for (int i = 0; !s && i < h->element_count; ++i) {
        if (strcmp(h->elements[i].name, "vertex") == 0) vertex = &h->elements[i];
        if (strcmp(h->elements[i].name, "face") == 0) face = &h->elements[i];
    }
    if (!s && (!vertex || vertex->count == 0))
        s = ply_error(r, "no vertex element (or zero vertices)");
    if (!s && (!face || face->count == 0)) s = ply_error(r, "no face element (or zero faces)");
    tri_list t = {0};
    for (int i = 0; !s && i < h->element_count; ++i) {
        const ply_element *e = &h->elements[i];
        s = check_rows_fit(r, e);
        if (s) break;
        if (e == vertex) {
            s = read_vertices(r, e, m);
        } else if (e == face) {
            s = read_faces(r, e, vertex->count, &t);
        } else if (e->property_count > 0) { /* rows without properties take no bytes */
            for (size_t row = 0; !s && row < e->count; ++row) {
                begin_row(r, e->name, row);
                for (int k = 0; !s && k < e->property_count; ++k)
                    s = skip_property(r, &e->props[k]);
                if (!s) s = end_row(r);
            }
        }
    }
    free(h);
    if (s) {
        free(t.idx);
        return s;
    }
    /* Per-vertex attributes share the position indices. */
    m->triangle_count = (int)t.count;
    m->indices = t.idx;
    size_t n = 3 * t.count;
    if (m->uv_count) {
        m->uv_indices = pen__malloc(r->ctx, n, sizeof(uint32_t), r->path);
        if (!m->uv_indices) return PEN_ERROR_MEMORY;
        memcpy(m->uv_indices, t.idx, n * sizeof(uint32_t));
    }
    if (m->normal_count) {
        m->normal_indices = pen__malloc(r->ctx, n, sizeof(uint32_t), r->path);
        if (!m->normal_indices) return PEN_ERROR_MEMORY;
        memcpy(m->normal_indices, t.idx, n * sizeof(uint32_t));
    }
    return PEN_OK;
}

pen_status pen_mesh_load_ply(pen_context *ctx, const char *path, pen_mesh *out) {
    memset(out, 0, sizeof *out);
    char *data = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, PLY_MAX_BYTES, &data, &size);
    if (s) return s;
    ply_reader r = {.ctx = ctx, .path = path, .begin = data, .p = data, .end = data + size};
    s = load(&r, out);
    free(data);
    if (s) pen_mesh_free(out);
    return s;
}
