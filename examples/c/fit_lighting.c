/* Recover a scene's lighting from an image of it by gradient descent through penumbra's backward
 * pass: the inverse-rendering loop in C, against the installed library alone.
 *
 *   fit_lighting SCENE.json OUT.png [STEPS]       (STEPS: Adam steps, default 100)
 *
 * The observed image is the scene rendered with its own lighting (a photo would do as well:
 * pen_image_load, linear, the camera's size). The SH lighting then starts from black, and each
 * step renders (pen_render_fwd), takes the L2 loss and its image gradient (pen_loss_l2), runs the
 * backward pass into the SH coefficients through the soft shadows (pen_render_bwd with
 * PEN_GRAD_LIGHTING) and takes an Adam step. It prints the loss as it goes and saves the last
 * render; exit 0 when the loss fell, else 1 (with the library's error line when a call failed).
 * `penumbra optimize` (examples/optimize/spot_lighting.json) solves the same problem exactly by
 * least squares; examples/python/fit_lighting.py is this loop with torch.
 *
 * Build against an installed penumbra (this folder's CMakeLists.txt does the same with CMake):
 *   cc fit_lighting.c -o fit_lighting $(pkg-config --cflags --libs penumbra) -lm
 *   ./fit_lighting /usr/local/share/penumbra/examples/scenes/spot_city.json fit.png 50
 * tests/cli_install.sh builds and runs it, shared, static and through find_package. */
#include <penumbra/penumbra.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int fail(pen_context *ctx, const char *what) {
    fprintf(stderr, "fit_lighting: %s: %s\n", what, pen_context_error(ctx));
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 3 && argc != 4) {
        fprintf(stderr, "usage: fit_lighting SCENE.json OUT.png [STEPS]\n");
        return 2;
    }
    const int steps = argc == 4 ? atoi(argv[3]) : 100;
    if (steps < 1) {
        fprintf(stderr, "fit_lighting: STEPS must be a positive number, not %s\n", argv[3]);
        return 2;
    }
    /* The headers and the library loaded at run time must be of one version. */
    if (strcmp(pen_version(), PEN_VERSION_STRING) != 0) {
        fprintf(stderr, "fit_lighting: library %s, headers %s\n", pen_version(),
                PEN_VERSION_STRING);
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

    const pen_render_options opt = pen_render_options_default();
    const int n = scene.sh_bands * scene.sh_bands; /* SH coefficients per channel */
    /* Adam's moments (docs/optimize.md: beta1 0.9, beta2 0.999, epsilon 1e-8), per coefficient. */
    double m[PEN_SH_MAX_COEFFS][3] = {{0}}, v[PEN_SH_MAX_COEFFS][3] = {{0}};
    const double rate = 0.05;
    double first = 0.0, loss = 0.0;
    if (pen_scene_prepare(ctx, &scene, opt.shadows, NULL)) { /* fits {"fit": N} spheres */
        fail(ctx, "prepare");
    } else if (pen_render_state_create(ctx, &state) ||
               pen_render_fwd(ctx, &scene, &opt, state, &target)) {
        fail(ctx, "render the target");
    } else if (pen_render_grad_create(ctx, &scene, &grad)) {
        fail(ctx, "grad");
    } else {
        memset(scene.lighting.sh, 0, sizeof scene.lighting.sh); /* from black */
        int step = 0;
        for (; step <= steps; ++step) {
            if (pen_render_fwd(ctx, &scene, &opt, state, &image) ||
                pen_loss_l2(ctx, &image, &target, &loss, &d_image)) {
                fail(ctx, "render");
                break;
            }
            if (step == 0) first = loss;
            if (step % 20 == 0 || step == steps) printf("step %4d  loss %.4g\n", step, loss);
            if (step == steps) break; /* the last render is of the last step's lighting */
            pen_render_grad_zero(&grad);
            if (pen_render_bwd(ctx, &scene, &opt, state, &d_image, PEN_GRAD_LIGHTING, &grad)) {
                fail(ctx, "backward");
                break;
            }
            const double bias1 = 1.0 - pow(0.9, step + 1), bias2 = 1.0 - pow(0.999, step + 1);
            for (int i = 0; i < n; ++i)
                for (int c = 0; c < 3; ++c) {
                    const double g = grad.sh[i][c];
                    m[i][c] = 0.9 * m[i][c] + 0.1 * g;
                    v[i][c] = 0.999 * v[i][c] + 0.001 * g * g;
                    const double step_size =
                        rate * (m[i][c] / bias1) / (sqrt(v[i][c] / bias2) + 1e-8);
                    scene.lighting.sh[i][c] -= (float)step_size;
                }
        }
        if (step == steps && pen_image_save(ctx, argv[2], &image)) {
            fail(ctx, "save");
        } else if (step == steps) {
            printf("fit_lighting: penumbra %s, %dx%d, %d steps, loss %.4g -> %.4g\n", pen_version(),
                   image.width, image.height, steps, first, loss);
            rc = isfinite(loss) && loss < first ? 0 : 1;
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
