/* A program outside the penumbra tree, built by tests/cli_install.sh against an installed copy
 * with nothing but `pkg-config --cflags --libs penumbra` (and, as a second consumer, with
 * find_package(penumbra)): it uses only <penumbra/penumbra.h> and the exported symbols of
 * libpenumbra.so. It loads a bundled scene at a small size, fits a few proxy spheres, renders,
 * takes an L2 loss against a constant grey image, runs the backward pass and saves the render.
 * Usage: outside SCENE.json OUT.png; prints one line with the loss and a gradient, exit 0 on
 * success, 1 with the library's error line otherwise. */
#include <penumbra/penumbra.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

static int fail(pen_context *ctx, const char *what) {
    fprintf(stderr, "outside: %s: %s\n", what, pen_context_error(ctx));
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: outside SCENE.json OUT.png\n");
        return 2;
    }
    if (strcmp(pen_version(), PEN_VERSION_STRING) != 0) {
        fprintf(stderr, "outside: library %s, headers %s\n", pen_version(), PEN_VERSION_STRING);
        return 1;
    }
    pen_context *ctx = pen_context_create();
    if (!ctx) return 1;
    pen_scene scene;
    pen_image image = {0}, target = {0}, d_image = {0};
    pen_render_state *state = NULL;
    pen_render_grad grad;
    memset(&grad, 0, sizeof grad);
    int rc = 1;
    if (pen_scene_load(ctx, argv[1], &scene)) {
        fail(ctx, "load");
        goto done_ctx;
    }
    scene.camera.width = scene.camera.height = 48;
    for (int i = 0; i < scene.object_count; ++i)
        if (!scene.objects[i].spheres.count) scene.objects[i].fit_spheres = 8;

    const pen_render_options opt = pen_render_options_default();
    double loss = 0.0;
    if (pen_scene_prepare(ctx, &scene, opt.shadows, NULL)) {
        fail(ctx, "prepare");
    } else if (pen_render_state_create(ctx, &state) ||
               pen_render_fwd(ctx, &scene, &opt, state, &image)) {
        fail(ctx, "render");
    } else if (pen_image_create(ctx, image.width, image.height, 3, &target)) {
        fail(ctx, "target");
    } else {
        for (int i = 0; i < image.width * image.height * 3; ++i) target.data[i] = 0.5f;
        if (pen_loss_l2(ctx, &image, &target, &loss, &d_image)) {
            fail(ctx, "loss");
        } else if (pen_render_grad_create(ctx, &scene, &grad)) {
            fail(ctx, "grad");
        } else {
            pen_render_grad_zero(&grad);
            /* Every group the scene's model has an exact gradient of (render.h). */
            const unsigned wrt = PEN_GRAD_ALL & pen_render_grad_exact(&scene, &opt);
            if (pen_render_bwd(ctx, &scene, &opt, state, &d_image, wrt, &grad)) {
                fail(ctx, "backward");
            } else if (pen_image_save(ctx, argv[2], &image)) {
                fail(ctx, "save");
            } else if (!isfinite(loss) || loss <= 0.0 || !isfinite(grad.sh[0][0]) ||
                       grad.sh[0][0] == 0.0f) {
                fprintf(stderr, "outside: implausible loss %g or d sh[0] %g\n", loss,
                        (double)grad.sh[0][0]);
            } else {
                printf("outside: penumbra %s, %dx%d, loss %.6g, d sh[0][0] %.6g\n", pen_version(),
                       image.width, image.height, loss, (double)grad.sh[0][0]);
                rc = 0;
            }
        }
    }
    pen_render_grad_free(&grad);
    pen_image_free(&d_image);
    pen_image_free(&target);
    pen_image_free(&image);
    pen_render_state_free(state);
    pen_scene_free(&scene);
done_ctx:
    pen_context_destroy(ctx);
    return rc;
}
