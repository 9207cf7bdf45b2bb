/* Fuzz harness: sets of calibrated views (src/io/camera_sets.c). The input is read three ways:
 * as a transforms.json and as a views file (both written as scratch files beside the fixed
 * assets, so "tex.png" names an existing image), and as a COLMAP text model whose cameras.txt is
 * the input up to its first form feed (\f) and whose images.txt is the rest, with the fixed
 * assets as the images folder. An accepted set must hold valid cameras and an image per view. */
#include "fuzz.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static void check_set(const pen_camera_set *set) {
    if (set->count < 1 || set->count > PEN_CAMERA_SET_MAX || !set->cameras || !set->images)
        fuzz_fail("camera set: bad count or arrays");
    for (int i = 0; i < set->count; ++i) {
        if (pen_camera_validate(fuzz_context(), &set->cameras[i]) != PEN_OK)
            fuzz_fail("camera set: accepted an invalid camera");
        if (!set->images[i]) fuzz_fail("camera set: view without an image");
    }
}

static void write_part(const char *path, const uint8_t *data, size_t size) {
    FILE *f = fopen(path, "wb");
    if (!f) fuzz_fail("cannot write a scratch file");
    if (size && fwrite(data, 1, size, f) != size) fuzz_fail("cannot write a scratch file");
    fclose(f);
}

static char model_[600];

/* Runs before fuzz_util's own clean-up (atexit is last in, first out), which removes the folder. */
static void remove_model(void) {
    char path[700];
    snprintf(path, sizeof path, "%s/cameras.txt", model_);
    remove(path);
    snprintf(path, sizeof path, "%s/images.txt", model_);
    remove(path);
    rmdir(model_);
}

typedef pen_status (*set_loader)(pen_context *, const char *, pen_camera_set *);

static void load_json(set_loader load, const char *path) {
    pen_camera_set set;
    if (load(fuzz_context(), path, &set) == PEN_OK) {
        check_set(&set);
        pen_camera_set_free(&set);
    } else if (set.cameras || set.images || set.count) {
        fuzz_fail("camera set: refused but not zeroed");
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    load_json(pen_camera_set_load_transforms, fuzz_write(data, size, "json"));
    load_json(pen_camera_set_load_views, fuzz_write(data, size, "json"));

    const char *model = model_;
    char path[700];
    if (!model_[0]) {
        snprintf(model_, sizeof model_, "%s/colmap", fuzz_dir());
        mkdir(model_, 0755);
        atexit(remove_model);
    }
    const uint8_t *ff = memchr(data, '\f', size);
    size_t split = ff ? (size_t)(ff - data) : size;
    snprintf(path, sizeof path, "%s/cameras.txt", model);
    write_part(path, data, split);
    snprintf(path, sizeof path, "%s/images.txt", model);
    write_part(path, ff ? ff + 1 : data, ff ? size - split - 1 : 0);
    pen_camera_set set;
    if (pen_camera_set_load_colmap(fuzz_context(), model, fuzz_dir(), &set) == PEN_OK) {
        check_set(&set);
        pen_camera_set_free(&set);
    } else if (set.cameras || set.images || set.count) {
        fuzz_fail("camera set: refused but not zeroed");
    }
    return 0;
}
