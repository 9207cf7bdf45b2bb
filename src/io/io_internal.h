/* Internal helpers of the file formats (src/io/): whole-file reads with a size cap, atomic
 * writes (temporary file + rename), paths relative to a referencing file, JSON values with key
 * paths in their error messages, and the OpenEXR bridge. Not installed. */
#ifndef PEN_IO_INTERNAL_H
#define PEN_IO_INTERNAL_H

#include "core/internal.h"
#include "penumbra/image.h"
#include "penumbra/scene.h"

#include <cjson/cJSON.h>
#include <stdio.h>

/* ---- Files (src/io/file.c) ------------------------------------------------------------------- */

/* Reads a whole file into a NUL-terminated buffer (*size excludes the NUL). Files larger than
 * max_bytes are an error (PEN_ERROR_IO naming the file), so a stray multi-gigabyte input fails
 * before it is read. The caller frees *data. */
pen_status pen__io_read_file(pen_context *ctx, const char *path, size_t max_bytes, char **data,
                             size_t *size);

/* Atomic writes: pen__io_temp_create makes an empty file "<path>.tmp-XXXXXX" beside `path`
 * (mode 0644) and returns its name (malloc'd); the caller writes it completely, then
 * pen__io_temp_commit renames it over `path`, or pen__io_temp_discard removes it. Both free
 * the name. */
pen_status pen__io_temp_create(pen_context *ctx, const char *path, char **tmp_path);
pen_status pen__io_temp_commit(pen_context *ctx, char *tmp_path, const char *path);
void pen__io_temp_discard(char *tmp_path);
/* Writes `size` bytes of text atomically (temp + rename). */
pen_status pen__io_write_file(pen_context *ctx, const char *path, const char *data, size_t size);

/* ---- Paths (src/io/file.c) ------------------------------------------------------------------- */

/* 1 if the extension of path (after the last '.', case-insensitive) equals ext (no dot). */
int pen__io_has_ext(const char *path, const char *ext);
/* A malloc'd copy of s (NULL on exhaustion, recorded in ctx). */
char *pen__io_strdup(pen_context *ctx, const char *s);
/* `rel` resolved against the folder holding `base_file`: absolute paths and a base without a
 * folder leave rel as is. malloc'd. */
char *pen__io_path_resolve(pen_context *ctx, const char *base_file, const char *rel);
/* The path of the existing file `target` written relative to the folder that will hold
 * `new_file` (which need not exist yet; its folder must). Falls back to the absolute path of
 * target, or target itself, when no relative form can be computed. malloc'd. */
char *pen__io_path_relative(pen_context *ctx, const char *new_file, const char *target);

/* ---- JSON with key paths (src/io/json.c) ---------------------------------------------------
 * Every reader takes the file name and the key path of the item ("camera.eye[2]") so that its
 * one error line reads "scene.json: camera.eye[2]: expected a finite number, got a string". */

typedef struct pen__json_where {
    const char *file;
    char key[256];
} pen__json_where;

/* Parses a JSON text (NUL-terminated at text[size]); a syntax error names file:line:column. */
pen_status pen__json_parse(pen_context *ctx, const char *file, const char *text, size_t size,
                           cJSON **root);
/* Reads and parses a file (size-capped). */
pen_status pen__json_load(pen_context *ctx, const char *path, cJSON **root);
/* Child key paths: "parent.name" or "name" at the top, and "parent[i]". */
void pen__json_child(const pen__json_where *parent, const char *name, pen__json_where *child);
void pen__json_index(const pen__json_where *parent, int index, pen__json_where *child);
/* A short description of an item's type for messages ("a string", "null", ...). */
const char *pen__json_type_name(const cJSON *item);
/* Records "file: key: <what>" (what is a printf format) and returns status. */
pen_status pen__json_error(pen_context *ctx, pen_status status, const pen__json_where *w,
                           const char *fmt, ...) PEN_PRINTF(4, 5);

/* Re-records the context's current error (from a file the key named) behind "file: key: ", e.g.
 * "scene.json: objects[0].mesh: spot.obj:12: ...", and returns status. */
pen_status pen__json_wrap(pen_context *ctx, pen_status status, const pen__json_where *w);

/* A finite number in [lo, hi]. `what` describes the expectation ("a positive number"). */
pen_status pen__json_number(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            double lo, double hi, const char *what, double *out);
/* An integer in [lo, hi]. */
pen_status pen__json_int(pen_context *ctx, const pen__json_where *w, const cJSON *item, int lo,
                         int hi, const char *what, int *out);
/* An array of exactly n finite numbers in [lo, hi], stored as floats. */
pen_status pen__json_floats(pen_context *ctx, const pen__json_where *w, const cJSON *item, int n,
                            double lo, double hi, float *out);
/* A non-empty string. */
pen_status pen__json_string(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            const char **out);
/* A string that must be one of `names` (NULL-terminated): its index into *index, or one error
 * naming the place and listing the choices ('unknown <what> "x" (expected "a", "b" or "c")'). */
pen_status pen__json_choice(pen_context *ctx, const pen__json_where *w, const cJSON *item,
                            const char *what, const char *const names[], int *index);
/* Member `name` of obj, or NULL (absent, or obj not an object). */
const cJSON *pen__json_member(const cJSON *obj, const char *name);
/* PEN_OK if item is an object; else "missing (expected an object)" or "expected an object, got
 * <type>" at w. */
pen_status pen__json_need_object(pen_context *ctx, const pen__json_where *w, const cJSON *item);
/* Fails on any member of object `obj` whose name is not in the NULL-terminated list `known`
 * (members whose names start with '_' are comments and allowed). */
pen_status pen__json_known_keys(pen_context *ctx, const pen__json_where *w, const cJSON *obj,
                                const char *const *known);
/* Adds item to object obj under name; returns 1, or 0 on failure (item NULL or not added), in
 * which case item is deleted, so that a chain of "ok && pen__json_add(o, k, make())" leaves
 * nothing unowned. */
int pen__json_add(cJSON *obj, const char *name, cJSON *item);
/* A JSON number for a float with the fewest decimal digits that read back to the same float
 * (so 0.3f is written 0.3, not 0.30000001192092896). NULL on exhaustion. */
cJSON *pen__json_float(float value);
cJSON *pen__json_float_array(const float *v, int n);

/* PEN_OK if every value of img is finite and at most `limit` in magnitude, else "path: pixel
 * (x, y) channel c: v outside [-limit, limit]" (the caller prefixes the key). src/io/scene.c. */
pen_status pen__io_image_check_values(pen_context *ctx, const char *path, const pen_image *img,
                                      double limit);

/* ---- The camera in JSON (src/io/camera.c) -------------------------------------------------- */

/* Reads the scene's "camera" object o (at key path w) into *cam (zeroed first). */
pen_status pen__io_camera_parse(pen_context *ctx, const pen__json_where *w, const cJSON *o,
                                pen_camera *cam);
/* Sets eye, target and up of *cam from a world-to-camera pose x_cam = R x + t in OpenCV axes
 * (x right, y down, z forward), as src/io/camera.c describes. Returns 1, or 0 with the reason in
 * `why` (R not a rotation, or the centre out of range). */
int pen__io_camera_pose(const double R[9], const double t[3], pen_camera *cam, char *why,
                        size_t why_size);
/* The "camera" object of a scene file; NULL on exhaustion. */
cJSON *pen__io_camera_json(const pen_camera *cam);
/* PEN_OK if the object pen__io_camera_json writes for cam reads back (a camera built in code may
 * hold values no file accepts); else the reader's error at w, marked as not written. The savers
 * call it before they write. */
pen_status pen__io_camera_check(pen_context *ctx, const pen__json_where *w, const pen_camera *cam);

/* ---- Image decoders (src/io/image_*.c) ------------------------------------------------------
 * Each decoder reads a whole file held in memory, distrusts every byte, checks the size against
 * the limits below before it allocates pixels, and names `name` and the place (byte offset,
 * scanline or pixel) in its one error line. They yield 3 linear channels like pen_image_load;
 * *out is zeroed on failure. src/io/image.c picks the decoder (pen__image_decode). */

/* Pixel budget of a loaded image, on top of each side's PEN_IMAGE_MAX_DIM (penumbra/image.h). */
#define PEN__IMAGE_MAX_PIXELS PEN_IMAGE_MAX_PIXELS

/* PEN_OK if 1 <= width, height <= PEN_IMAGE_MAX_DIM and width * height <= PEN__IMAGE_MAX_PIXELS;
 * otherwise one PEN_ERROR_PARSE line naming `name` and the size. */
pen_status pen__image_check_size(pen_context *ctx, const char *name, long long width,
                                 long long height);
/* The sRGB transfer curve (IEC 61966-2-1) decoded: an encoded value in [0, 1] to linear. */
double pen__srgb_to_linear(double c);
/* The 256 values of 8-bit codes: code / 255, sRGB-decoded unless raw. */
void pen__image_code_table(int raw, float table[256]);
/* Converts n pixels of `comp` interleaved samples (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA) of 8
 * bits (through table8, from pen__image_code_table) or 16 bits (big-endian, as PNG stores them)
 * into 3 floats each: grey replicated, alpha dropped, sRGB decoded unless raw. */
void pen__image_samples_to_rgb(const unsigned char *src, int bits, int comp, size_t n,
                               const float table8[256], int raw, float *dst);

/* Radiance RGBE (.hdr): src/io/image_hdr.c. */
pen_status pen__hdr_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                           size_t size, pen_image *out);
/* PNG through libpng: src/io/image_png.c. */
pen_status pen__png_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                           size_t size, int raw, pen_image *out);
/* JPEG (baseline, progressive, arithmetic; grey or YCbCr) through libjpeg: src/io/image_jpeg.c. */
pen_status pen__jpeg_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                            size_t size, int raw, pen_image *out);
/* Decodes an image file held in memory, the format chosen by the extension of `name` (.png,
 * .hdr, .jpg/.jpeg, .exr; the magic bytes must agree), as pen_image_load_ex does with a file
 * (flags: PEN_IMAGE_LOAD_RAW), including the check that every value is finite. For fuzzers, and
 * for pen_image_load_ex but for EXR, which it hands OpenEXR as a file. */
pen_status pen__image_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                             size_t size, unsigned flags, pen_image *out);

/* ---- OpenEXR (src/io/exr.cpp) -------------------------------------------------------------
 * C++ because the bundled maps use DWAB compression, which OpenEXR 3.1 decodes only in its C++
 * library (OpenEXRCore's C decoder stops at "not yet implemented"), and its C RGBA interface
 * rounds everything to half floats. Exceptions never leave these functions. */

/* Loads R, G, B (or Y as grey) as 32-bit floats into a 3-channel image; A is ignored. */
pen_status pen__exr_load(pen_context *ctx, const char *path, pen_image *out);
/* The same from a file held in memory (`name` for messages): for pen__image_decode. */
pen_status pen__exr_decode(pen_context *ctx, const char *name, const unsigned char *bytes,
                           size_t size, pen_image *out);
/* Writes 32-bit float channels (1: Y, 2: Y A, 3: R G B, 4: R G B A) with ZIP compression to
 * file_name; messages name `path` (the caller writes a temporary file and renames it). */
pen_status pen__exr_save(pen_context *ctx, const char *path, const char *file_name,
                         const pen_image *image);

#endif
