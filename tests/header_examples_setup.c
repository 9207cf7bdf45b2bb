/* The inputs the usage examples of the public headers take as given (tests/header_examples.h
 * says what each is), made once per run of tests/cli_header_examples.sh with the library itself.
 * Usage: header_examples_setup BUNDLED_SCENE.json DIR
 *   writes DIR/scene.json (the scene at HARNESS_SIZE pixels, spheres fitted and inline, Spot's
 *   translation x 0) and DIR/target.exr (that scene with Spot at x = HARNESS_TRUTH_DX). */
#include "header_examples.h"

static int fail(pen_context *ctx, const char *what) {
    fprintf(stderr, "header_examples_setup: %s: %s\n", what, pen_context_error(ctx));
    pen_context_destroy(ctx);
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: header_examples_setup BUNDLED_SCENE.json DIR\n");
        return 2;
    }
    char path[4096];
    pen_context *ctx = harness_begin();
    pen_scene scene;
    if (pen_scene_load(ctx, argv[1], &scene)) return fail(ctx, "load");
    scene.camera.width = scene.camera.height = HARNESS_SIZE;
    scene.objects[0].pose.translation[0] = 0.0f;
    pen_image target = {0};
    const pen_render_options opt = pen_render_options_default();
    int bad = pen_scene_prepare(ctx, &scene, 1, NULL) != PEN_OK;
    if (!bad) {
        snprintf(path, sizeof path, "%s/scene.json", argv[2]);
        bad = pen_scene_save(ctx, path, &scene) != PEN_OK;
    }
    if (!bad) {
        scene.objects[0].pose.translation[0] = HARNESS_TRUTH_DX;
        snprintf(path, sizeof path, "%s/target.exr", argv[2]);
        bad = pen_render_fwd(ctx, &scene, &opt, NULL, &target) != PEN_OK ||
              pen_image_save(ctx, path, &target) != PEN_OK;
    }
    pen_image_free(&target);
    pen_scene_free(&scene);
    if (bad) return fail(ctx, argv[1]);
    pen_context_destroy(ctx);
    return 0;
}
