/* JPEG decoding through libjpeg (Debian's libjpeg-turbo), from memory: textures from scanners and
 * asset stores come as JPEG. 8-bit samples, sRGB decoded to linear like PNG (raw on request).
 *
 * libjpeg is safe on malformed input provided its error exits are caught: they are turned into a
 * longjmp here, with the state in a jpeg_job owned by the caller of the function that calls
 * setjmp (as in image_png.c). It is forgiving by default: corrupt or truncated data is only a
 * warning and the missing part decodes grey. Here every warning is an error (djpeg's -strict), so
 * a damaged file is refused rather than loaded half grey. Two resource bounds beyond the size
 * check: at most JPEG_MAX_SCANS scans (a progressive file can repeat tiny scans without end, each
 * one a pass over the whole coefficient buffer) and at most a fixed multiple of the pixel count
 * for libjpeg's whole-image buffers.
 *
 * Colour: grey stays one channel (replicated on output), YCbCr and RGB come out as RGB; CMYK and
 * YCCK are refused (no colour management). EXIF orientation is not applied: textures are stored
 * as they are meant to be sampled. */
#include "io/io_internal.h"

#include <limits.h>
#include <setjmp.h>
#include <stdio.h> /* jpeglib.h needs FILE and size_t first */
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>

#define JPEG_MAX_SCANS 500

typedef struct jpeg_job {
    struct jpeg_error_mgr err; /* first: libjpeg's err pointer is the job */
    struct jpeg_progress_mgr progress;
    struct jpeg_decompress_struct cinfo;
    jmp_buf jump;
    pen_context *ctx;
    const char *name;
    const unsigned char *bytes;
    size_t size;
    int raw;
    pen_image *out;
    unsigned char *row;
    char message[JMSG_LENGTH_MAX + 64];
} jpeg_job;

static void on_error(j_common_ptr cinfo) {
    jpeg_job *job = (jpeg_job *)cinfo->err;
    cinfo->err->format_message(cinfo, job->message);
    longjmp(job->jump, 1);
}

/* level < 0: a warning about corrupt data, fatal here; level >= 0: trace output, dropped. */
static void on_message(j_common_ptr cinfo, int level) {
    if (level < 0) on_error(cinfo);
}

/* An error of our own, reported like libjpeg's. */
static void fail(jpeg_job *job, const char *what) {
    snprintf(job->message, sizeof job->message, "%s", what);
    longjmp(job->jump, 1);
}

static void on_progress(j_common_ptr cinfo) {
    jpeg_job *job = (jpeg_job *)cinfo->err;
    if (job->cinfo.input_scan_number > JPEG_MAX_SCANS) {
        char what[64];
        snprintf(what, sizeof what, "more than %d scans", JPEG_MAX_SCANS);
        fail(job, what);
    }
}

/* Everything after setjmp; libjpeg errors leave it by longjmp. */
static pen_status decode(jpeg_job *job) {
    j_decompress_ptr cinfo = &job->cinfo;
    jpeg_create_decompress(cinfo);
    cinfo->progress = &job->progress;
    jpeg_mem_src(cinfo, job->bytes, (unsigned long)job->size);
    jpeg_read_header(cinfo, TRUE);
    pen_status s =
        pen__image_check_size(job->ctx, job->name, cinfo->image_width, cinfo->image_height);
    if (s) return s;
    if (cinfo->jpeg_color_space == JCS_GRAYSCALE) {
        cinfo->out_color_space = JCS_GRAYSCALE;
    } else if (cinfo->num_components == 3) {
        cinfo->out_color_space = JCS_RGB;
    } else {
        return pen__error(job->ctx, PEN_ERROR_UNSUPPORTED,
                          "%s: JPEG with %d colour components (CMYK or YCCK) is not supported; "
                          "convert it to RGB",
                          job->name, cinfo->num_components);
    }
    /* The coefficient buffers of a progressive file take 2 bytes per sample and component;
     * 16 bytes per pixel plus 16 MiB covers any legal layout of this size. */
    cinfo->mem->max_memory_to_use =
        (long)(16 * (long long)cinfo->image_width * cinfo->image_height + (16 << 20));
    jpeg_start_decompress(cinfo);
    int comp = cinfo->output_components, w = (int)cinfo->output_width;
    if ((comp != 1 && comp != 3) || w != (int)cinfo->image_width ||
        cinfo->output_height != cinfo->image_height)
        fail(job, "unexpected output layout"); /* not reached with the colour spaces above */
    s = pen_image_create(job->ctx, w, (int)cinfo->output_height, 3, job->out);
    if (s) return s;
    job->row = pen__malloc(job->ctx, (size_t)w, (size_t)comp, "JPEG row");
    if (!job->row) return PEN_ERROR_MEMORY;
    float table[256];
    pen__image_code_table(job->raw, table);
    while (cinfo->output_scanline < cinfo->output_height) {
        size_t y = cinfo->output_scanline;
        JSAMPROW rows[1] = {job->row};
        if (jpeg_read_scanlines(cinfo, rows, 1) != 1) fail(job, "no scanline decoded");
        pen__image_samples_to_rgb(job->row, 8, comp, (size_t)w, table, job->raw,
                                  job->out->data + 3 * y * (size_t)w);
    }
    jpeg_finish_decompress(cinfo); /* reads to EOI: trailing corruption is caught too */
    return PEN_OK;
}

static pen_status run(jpeg_job *job) {
    if (setjmp(job->jump)) return PEN_ERROR_PARSE;
    return decode(job);
}

pen_status pen__jpeg_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                            size_t size, int raw, pen_image *out) {
    memset(out, 0, sizeof *out);
    if (size < 3 || bytes[0] != 0xff || bytes[1] != 0xd8 || bytes[2] != 0xff)
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: not a JPEG file (bad magic bytes)", name);
    if (size > (size_t)ULONG_MAX) return pen__error(ctx, PEN_ERROR_IO, "%s: file too large", name);
    jpeg_job *job = pen__malloc(ctx, 1, sizeof *job, "JPEG decoder");
    if (!job) return PEN_ERROR_MEMORY;
    memset(job, 0, sizeof *job);
    job->ctx = ctx;
    job->name = name;
    job->bytes = bytes;
    job->size = size;
    job->raw = raw;
    job->out = out;
    job->cinfo.err = jpeg_std_error(&job->err);
    job->err.error_exit = on_error;
    job->err.emit_message = on_message;
    job->progress.progress_monitor = on_progress;
    pen_status s = run(job);
    if (s && job->message[0]) {
        /* The place: how far libjpeg has read, and the row being produced once rows are. */
        size_t read = job->cinfo.src ? size - job->cinfo.src->bytes_in_buffer : 0;
        char row[64] = "";
        if (job->cinfo.output_height)
            snprintf(row, sizeof row, " (output row %u of %u)", job->cinfo.output_scanline,
                     job->cinfo.output_height);
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: corrupt JPEG at byte offset %zu%s: %s", name,
                       read, row, job->message);
    }
    jpeg_destroy_decompress(&job->cinfo);
    free(job->row);
    free(job);
    if (s) pen_image_free(out);
    return s;
}
