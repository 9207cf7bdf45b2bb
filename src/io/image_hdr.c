/* Radiance RGBE (.hdr) decoding: a strict, bounded reader of our own.
 *
 * Why not stb_image: Debian's stb spins forever on a truncated run-length file (a zero count
 * never advances), fills truncated flat or header-only files from uninitialised memory, and
 * restarts the whole image as flat data when one scanline is not run-length encoded (values up to
 * 1e36). The format is small enough that reading it ourselves, with every count checked against
 * the row and the bytes left, is shorter and clearer than validating the stream for stb.
 *
 * The file: "#?RADIANCE" or "#?RGBE", header lines up to an empty line (FORMAT, if given, must be
 * 32-bit_rle_rgbe; EXPOSURE and the rest are ignored, as every renderer that writes them
 * expects), the resolution line "-Y <height> +X <width>" (rows top to bottom, the only
 * orientation written in practice), then one scanline per row. A scanline is either new-style
 * run-length encoded (only for widths 8..32767: the bytes 2, 2, then the width in 15 bits, then
 * the four byte planes R, G, B, E one after the other, each as runs (128 + n, value) and dumps
 * (n, n values)) or flat (width x 4 RGBE bytes). Each row is judged on its own, as Radiance's own
 * reader does. Old-style runs (a pixel 1, 1, 1, n repeating the previous one) are not
 * interpreted: no writer of the last thirty years emits them, and stb did not either.
 *
 * Values: mantissa * 2^(E - 136), 0 for E = 0 (stb's conversion, so the bundled maps load to the
 * same floats as before). */
#include "io/io_internal.h"

#include <stdlib.h>
#include <string.h>

typedef struct hdr_reader {
    pen_context *ctx;
    const char *name;
    const unsigned char *bytes;
    size_t size, pos;
} hdr_reader;

/* The next header line (without its '\n') or 0 if the file ends before a newline. */
static int next_line(hdr_reader *r, const char **line, size_t *len) {
    const unsigned char *start = r->bytes + r->pos;
    const unsigned char *nl = memchr(start, '\n', r->size - r->pos);
    if (!nl) return 0;
    *line = (const char *)start;
    *len = (size_t)(nl - start);
    r->pos += *len + 1;
    return 1;
}

static int starts_with(const char *line, size_t len, const char *prefix) {
    size_t n = strlen(prefix);
    return len >= n && memcmp(line, prefix, n) == 0;
}

/* A decimal integer in [1, 10^9] at *p (before end); advances *p. 0 if none. */
static long long parse_count(const char **p, const char *end) {
    long long v = 0;
    const char *q = *p;
    while (q < end && *q >= '0' && *q <= '9' && v <= 1000000000)
        v = 10 * v + (*q++ - '0');
    if (q == *p || v < 1 || v > 1000000000) return 0;
    *p = q;
    return v;
}

/* Reads the magic line, the header and the resolution line. */
static pen_status read_header(hdr_reader *r, long long *width, long long *height) {
    const char *line;
    size_t len;
    if (!next_line(r, &line, &len) || !((len == 10 && memcmp(line, "#?RADIANCE", 10) == 0) ||
                                        (len == 6 && memcmp(line, "#?RGBE", 6) == 0)))
        return pen__error(r->ctx, PEN_ERROR_PARSE, "%s: not a Radiance HDR file (bad magic bytes)",
                          r->name);
    for (int lineno = 2;; ++lineno) {
        size_t at = r->pos;
        if (!next_line(r, &line, &len))
            return pen__error(r->ctx, PEN_ERROR_PARSE,
                              "%s: header not closed by an empty line (ends at byte offset %zu)",
                              r->name, r->size);
        if (len == 0) break;
        if (starts_with(line, len, "FORMAT=") &&
            !(len == 22 && memcmp(line + 7, "32-bit_rle_rgbe", 15) == 0))
            return pen__error(r->ctx, PEN_ERROR_UNSUPPORTED,
                              "%s: header line %d (byte offset %zu): %.*s (only 32-bit_rle_rgbe "
                              "is supported)",
                              r->name, lineno, at, (int)(len > 60 ? 60 : len), line);
    }
    size_t at = r->pos;
    if (!next_line(r, &line, &len))
        return pen__error(r->ctx, PEN_ERROR_PARSE,
                          "%s: no resolution line after the header (byte offset %zu)", r->name, at);
    const char *p = line, *end = line + len;
    long long h = 0, w = 0;
    if (starts_with(p, len, "-Y ")) {
        p += 3;
        h = parse_count(&p, end);
        if (h && end - p >= 4 && memcmp(p, " +X ", 4) == 0) {
            p += 4;
            w = parse_count(&p, end);
        }
    }
    if (!h || !w || p != end)
        return pen__error(r->ctx, PEN_ERROR_PARSE,
                          "%s: resolution line at byte offset %zu is \"%.*s\" (expected "
                          "\"-Y <height> +X <width>\", the only orientation supported)",
                          r->name, at, (int)(len > 60 ? 60 : len), line);
    *width = w;
    *height = h;
    return PEN_OK;
}

static pen_status truncated(hdr_reader *r, int row, size_t need) {
    return pen__error(r->ctx, PEN_ERROR_PARSE,
                      "%s: scanline %d truncated: needs %zu more bytes at byte offset %zu, %zu "
                      "left",
                      r->name, row, need, r->pos, r->size - r->pos);
}

/* One new-style run-length scanline into rgbe (width x 4 bytes). r->pos is at its 4-byte start. */
static pen_status read_rle_row(hdr_reader *r, int row, int width, unsigned char *rgbe) {
    const unsigned char *b = r->bytes;
    int declared = (b[r->pos + 2] << 8) | b[r->pos + 3];
    if (declared != width)
        return pen__error(r->ctx, PEN_ERROR_PARSE,
                          "%s: scanline %d (byte offset %zu) is run-length encoded for %d pixels "
                          "in an image %d wide",
                          r->name, row, r->pos, declared, width);
    r->pos += 4;
    for (int plane = 0; plane < 4; ++plane) {
        for (int x = 0; x < width;) {
            if (r->pos >= r->size) return truncated(r, row, 1);
            size_t at = r->pos;
            int code = b[r->pos++];
            int run = code > 128, n = run ? code - 128 : code;
            if (n == 0 || n > width - x)
                return pen__error(r->ctx, PEN_ERROR_PARSE,
                                  "%s: scanline %d, byte offset %zu: %s of %d in channel %d at "
                                  "pixel %d of %d",
                                  r->name, row, at, run ? "run" : "literal span", n, plane, x,
                                  width);
            size_t need = run ? 1 : (size_t)n;
            if (need > r->size - r->pos) return truncated(r, row, need);
            for (int k = 0; k < n; ++k)
                rgbe[4 * (size_t)(x + k) + (size_t)plane] = b[r->pos + (run ? 0 : (size_t)k)];
            r->pos += need;
            x += n;
        }
    }
    return PEN_OK;
}

static void rgbe_to_float(const unsigned char *rgbe, int width, float *dst) {
    for (int x = 0; x < width; ++x, rgbe += 4, dst += 3) {
        if (rgbe[3] == 0) {
            dst[0] = dst[1] = dst[2] = 0.0f;
            continue;
        }
        float scale = (float)ldexp(1.0, rgbe[3] - 136);
        for (int c = 0; c < 3; ++c)
            dst[c] = rgbe[c] * scale;
    }
}

pen_status pen__hdr_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                           size_t size, pen_image *out) {
    memset(out, 0, sizeof *out);
    hdr_reader r = {ctx, name, bytes, size, 0};
    long long w = 0, h = 0;
    pen_status s = read_header(&r, &w, &h);
    if (!s) s = pen__image_check_size(ctx, name, w, h);
    if (s) return s;
    int width = (int)w;
    size_t row_bytes = 4 * (size_t)width;
    /* Run-length rows exist only for widths 8..32767; a row whose first bytes are 2, 2 and a
     * 15-bit count is one, anything else is flat. The shortest row is flat below width 8, else
     * run-length with runs of 127 (2 bytes each per channel): a file too short for its header's
     * size is refused before the image is allocated. */
    int rle_width = width >= 8 && width < 32768;
    size_t shortest = rle_width ? 4 + 8 * (((size_t)width + 126) / 127) : row_bytes;
    if ((size_t)h * shortest > size - r.pos)
        return pen__error(ctx, PEN_ERROR_PARSE,
                          "%s: the %zu bytes of pixel data from byte offset %zu cannot hold %lld "
                          "scanlines of %d pixels (at least %zu bytes)",
                          name, size - r.pos, r.pos, h, width, (size_t)h * shortest);
    s = pen_image_create(ctx, width, (int)h, 3, out);
    if (s) return s;
    unsigned char *rgbe = pen__malloc(ctx, row_bytes, 1, "HDR scanline");
    if (!rgbe) s = PEN_ERROR_MEMORY;
    for (int y = 0; !s && y < (int)h; ++y) {
        const unsigned char *b = bytes + r.pos;
        if (rle_width && size - r.pos >= 4 && b[0] == 2 && b[1] == 2 && b[2] < 128) {
            s = read_rle_row(&r, y, width, rgbe);
        } else if (row_bytes > size - r.pos) {
            s = truncated(&r, y, row_bytes);
        } else {
            memcpy(rgbe, b, row_bytes);
            r.pos += row_bytes;
        }
        if (!s) rgbe_to_float(rgbe, width, out->data + 3 * (size_t)y * (size_t)width);
    }
    free(rgbe);
    if (s) pen_image_free(out);
    return s;
}
