/* PNG decoding through libpng, from memory.
 *
 * Why libpng and not stb_image: stb never checks chunk CRCs and reads palette indices past the
 * palette (uninitialised memory). libpng verifies every CRC (told here to refuse a bad one in
 * ancillary chunks too, where its default is to drop the chunk with a warning) and the zlib
 * checksum of the image data, and reports truncation; the size is checked here after the header,
 * before any row is allocated. It does not refuse
 * a palette index past the palette (it reads a zeroed 256-entry table), so palette images are
 * read as indices and every index is checked here, naming the pixel.
 *
 * libpng reports errors by longjmp. All state that changes after setjmp lives in a png_job owned
 * by the caller of the function that calls setjmp, so nothing is indeterminate after the jump and
 * the caller frees whatever was allocated. Warnings (benign problems such as a questionable ICC
 * profile) are dropped: a library prints nothing. tRNS transparency is ignored like alpha. */
#include "io/io_internal.h"

#include <png.h>
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>

typedef struct png_job {
    pen_context *ctx;
    const char *name;
    const unsigned char *bytes;
    size_t size, pos; /* pos: bytes handed to libpng so far, the place named in errors */
    int raw;
    pen_image *out;
    png_structp png;
    png_infop info;
    unsigned char *pixels; /* decoded rows: one row, or all of them for an interlaced file */
    png_bytep *row_pointers;
    unsigned char *rgb; /* a palette row expanded to RGB */
    char message[256];  /* libpng's error */
} png_job;

static void on_error(png_structp png, png_const_charp message) {
    png_job *job = png_get_error_ptr(png);
    snprintf(job->message, sizeof job->message, "%s", message);
    png_longjmp(png, 1);
}

static void on_warning(png_structp png, png_const_charp message) {}

static void on_read(png_structp png, png_bytep dst, size_t n) {
    png_job *job = png_get_io_ptr(png);
    if (n > job->size - job->pos) {
        snprintf(job->message, sizeof job->message, "file truncated (%zu bytes wanted, %zu left)",
                 n, job->size - job->pos);
        png_longjmp(png, 1);
    }
    memcpy(dst, job->bytes + job->pos, n);
    job->pos += n;
}

/* Decoded rows [y0, y1) of job->pixels (stride `stride`) into the image. */
static pen_status convert_rows(png_job *job, const unsigned char *rows, size_t stride, int y0,
                               int y1, int bits, int comp, int palette) {
    float table[256];
    pen__image_code_table(job->raw, table);
    int w = job->out->width;
    png_colorp colours = NULL;
    int ncolours = 0;
    if (palette) png_get_PLTE(job->png, job->info, &colours, &ncolours);
    for (int y = y0; y < y1; ++y) {
        const unsigned char *src = rows + (size_t)(y - y0) * stride;
        float *dst = job->out->data + 3 * (size_t)y * (size_t)w;
        if (!palette) {
            pen__image_samples_to_rgb(src, bits, comp, (size_t)w, table, job->raw, dst);
            continue;
        }
        for (int x = 0; x < w; ++x) {
            if (src[x] >= ncolours)
                return pen__error(job->ctx, PEN_ERROR_PARSE,
                                  "%s: pixel (%d, %d) has palette index %d, the palette has %d "
                                  "entries",
                                  job->name, x, y, src[x], ncolours);
            job->rgb[3 * x] = colours[src[x]].red;
            job->rgb[3 * x + 1] = colours[src[x]].green;
            job->rgb[3 * x + 2] = colours[src[x]].blue;
        }
        pen__image_samples_to_rgb(job->rgb, 8, 3, (size_t)w, table, job->raw, dst);
    }
    return PEN_OK;
}

/* Everything after setjmp; libpng errors leave it by longjmp. */
static pen_status decode(png_job *job) {
    png_structp png = job->png;
    png_infop info = job->info;
    png_set_read_fn(png, job, on_read);
    png_set_crc_action(png, PNG_CRC_ERROR_QUIT, PNG_CRC_ERROR_QUIT);
    png_read_info(png, info);
    png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
    pen_status s = pen__image_check_size(job->ctx, job->name, w, h); /* as libpng read it */
    if (s) return s;
    int type = png_get_color_type(png, info), depth = png_get_bit_depth(png, info);
    int palette = type == PNG_COLOR_TYPE_PALETTE;
    if (palette || depth < 8) png_set_packing(png); /* one byte per index or sample */
    if (type == PNG_COLOR_TYPE_GRAY && depth < 8) png_set_expand_gray_1_2_4_to_8(png);
    int passes = png_set_interlace_handling(png);
    png_read_update_info(png, info);
    int comp = png_get_channels(png, info), bits = png_get_bit_depth(png, info);
    size_t stride = png_get_rowbytes(png, info);
    if (stride != (size_t)w * (size_t)comp * (size_t)(bits / 8) || (bits != 8 && bits != 16))
        png_error(png, "unexpected row layout"); /* not reached with the transforms above */
    s = pen_image_create(job->ctx, (int)w, (int)h, 3, job->out);
    if (s) return s;
    size_t nrows = passes > 1 ? h : 1;
    job->pixels = pen__malloc(job->ctx, nrows, stride, "PNG rows");
    job->rgb = pen__malloc(job->ctx, w, 3, "PNG palette row");
    if (!job->pixels || !job->rgb) return PEN_ERROR_MEMORY;
    if (passes > 1) {
        job->row_pointers = pen__malloc(job->ctx, h, sizeof *job->row_pointers, "PNG rows");
        if (!job->row_pointers) return PEN_ERROR_MEMORY;
        for (png_uint_32 y = 0; y < h; ++y)
            job->row_pointers[y] = job->pixels + (size_t)y * stride;
        png_read_image(png, job->row_pointers);
        s = convert_rows(job, job->pixels, stride, 0, (int)h, bits, comp, palette);
    } else {
        for (png_uint_32 y = 0; !s && y < h; ++y) {
            png_read_row(png, job->pixels, NULL);
            s = convert_rows(job, job->pixels, stride, (int)y, (int)y + 1, bits, comp, palette);
        }
    }
    /* The chunks after the image data, their CRCs and IEND. */
    if (!s) png_read_end(png, NULL);
    return s;
}

/* setjmp's frame: changes nothing after setjmp (the state is in *job, the caller's). */
static pen_status run(png_job *job) {
    if (setjmp(png_jmpbuf(job->png))) return PEN_ERROR_PARSE;
    return decode(job);
}

pen_status pen__png_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                           size_t size, int raw, pen_image *out) {
    memset(out, 0, sizeof *out);
    if (size < 8 || png_sig_cmp(bytes, 0, 8) != 0)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: not a PNG file (bad magic bytes)", name);
    /* IHDR comes first (libpng refuses anything else): its size is judged before libpng reads on
     * through the chunks to the image data. */
    if (size >= 24 && memcmp(bytes + 12, "IHDR", 4) == 0) {
        pen_status s = pen__image_check_size(ctx, name, png_get_uint_32(bytes + 16),
                                             png_get_uint_32(bytes + 20));
        if (s) return s;
    }
    png_job job = {ctx, name, bytes, size, 0, raw, out, NULL, NULL, NULL, NULL, NULL, ""};
    job.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &job, on_error, on_warning);
    if (job.png) job.info = png_create_info_struct(job.png);
    pen_status s;
    if (!job.png || !job.info) {
        s = pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory starting libpng", name);
    } else {
        s = run(&job);
        if (s && job.message[0])
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: corrupt PNG at byte offset %zu: %s", name,
                           job.pos, job.message);
    }
    png_destroy_read_struct(job.png ? &job.png : NULL, job.info ? &job.info : NULL, NULL);
    free(job.pixels);
    free(job.row_pointers);
    free(job.rgb);
    if (s) pen_image_free(out);
    return s;
}
