/* The harness around the usage examples of the public headers, include/penumbra/<name>.h
 * (tests/cli_header_examples.sh extracts each example, wraps it in a main() that includes this
 * file, compiles it against the build's libpenumbra.so and runs it in a folder of its own).
 *
 * What an example may take as given (the names on its first line, `// given: ...`):
 *   ctx         pen_context *, from pen_context_create(); the harness destroys it
 *   scene_path  const char *: the bundled examples/scenes/spot_city.json (Spot under the city
 *               map) at 64 x 64 pixels with its 32 spheres already fitted (inline), Spot's
 *               translation x set to 0
 *   mesh_path   const char *: the bundled data/meshes/spot_triangulated.obj, a closed mesh
 *   target      pen_image: what scene_path's camera sees with Spot moved HARNESS_TRUTH_DX along x
 *               (rendered as `penumbra render` does): the image a pose fit should reach; the
 *               harness frees it
 *   task_path   const char *: a task JSON recovering Spot's pose in scene_path's scene from
 *               target (10 iterations)
 * Any other name on the line is refused by the script. After the example's last statement the
 * harness fails the run if the context holds an error (examples may leave statuses unchecked:
 * a failed call leaves its message there).
 *
 * Checks: the script inserts each example's checks (CHECK(...), below) before the example's
 * first top-level pen_*_free / pen_*_destroy call, so they see its results before it frees them.
 */
#ifndef PENUMBRA_TESTS_HEADER_EXAMPLES_H
#define PENUMBRA_TESTS_HEADER_EXAMPLES_H

#include <penumbra/penumbra.h>

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The target's pose: Spot's translation x, from 0 in scene_path. */
#define HARNESS_TRUTH_DX 0.1f
/* The size of scene_path's camera. */
#define HARNESS_SIZE 64

static int harness_failures;

#define CHECK(cond)                                                                               \
    do {                                                                                          \
        if (!(cond)) {                                                                            \
            fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond);             \
            ++harness_failures;                                                                   \
        }                                                                                         \
    } while (0)

/* n floats, all finite and not all zero. */
static inline int harness_floats_ok(const float *v, size_t n) {
    int nonzero = 0;
    if (!v || n == 0) return 0;
    for (size_t i = 0; i < n; ++i) {
        if (!isfinite(v[i])) return 0;
        if (v[i] != 0.0f) nonzero = 1;
    }
    return nonzero;
}

static inline int harness_image_ok(const pen_image *im) {
    return im->width > 0 && im->height > 0 && im->channels > 0 &&
           harness_floats_ok(im->data, (size_t)im->width * im->height * im->channels);
}

/* A file that exists and is not empty. */
static inline int harness_file_ok(const char *path) {
    FILE *f = fopen(path, "rb");
    int ok = f && fgetc(f) != EOF;
    if (f) fclose(f);
    return ok;
}

static inline pen_context *harness_begin(void) {
    pen_context *ctx = pen_context_create();
    if (!ctx) {
        fprintf(stderr, "harness: no context\n");
        exit(1);
    }
    return ctx;
}

static inline pen_image harness_image(pen_context *ctx, const char *path) {
    pen_image im;
    if (pen_image_load(ctx, path, &im) != PEN_OK) {
        fprintf(stderr, "harness: %s\n", pen_context_error(ctx));
        exit(1);
    }
    return im;
}

/* After the example: its errors, its checks; then the context goes. The exit status. */
static inline int harness_end(pen_context *ctx) {
    int rc = harness_failures != 0;
    if (pen_context_status(ctx) != PEN_OK) {
        fprintf(stderr, "the example left an error in the context: %s: %s\n",
                pen_status_string(pen_context_status(ctx)), pen_context_error(ctx));
        rc = 1;
    }
    pen_context_destroy(ctx);
    return rc;
}

#endif
