/* Render a scene JSON to an image: the smallest program against libpenumbra, what
 * `penumbra render SCENE.json -o OUT.png` does.
 *
 *   render SCENE.json OUT.png          (OUT: .png 8-bit sRGB; .exr or .hdr linear)
 *
 * It loads the scene (meshes, textures, the environment map and the disk lights found in it),
 * prepares it (fits the proxy spheres of "spheres": {"fit": N}, cached as the command caches
 * them), renders the soft shadows and saves the image. Every call returns a status (PEN_OK is 0);
 * on failure the context holds one line naming the file, the place and what is wrong.
 *
 * Build against an installed penumbra (this folder's CMakeLists.txt does the same with CMake):
 *   cc render.c -o render $(pkg-config --cflags --libs penumbra)
 *   ./render /usr/local/share/penumbra/examples/scenes/spot_city.json spot.png
 * tests/cli_install.sh builds and runs it. fit_lighting.c adds the loss and the backward pass. */
#include <penumbra/penumbra.h>

#include <stdio.h>

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: render SCENE.json OUT.png\n");
        return 2;
    }
    pen_context *ctx = pen_context_create();
    if (!ctx) return 1;
    pen_scene scene;
    pen_render_state *state = NULL;
    pen_image image = {0};
    const pen_render_options opt = pen_render_options_default();
    int rc = pen_scene_load(ctx, argv[1], &scene);
    if (!rc) {
        rc = pen_scene_prepare(ctx, &scene, opt.shadows, NULL) ||
             pen_render_state_create(ctx, &state) ||
             pen_render_fwd(ctx, &scene, &opt, state, &image) ||
             pen_image_save(ctx, argv[2], &image);
        pen_scene_free(&scene);
    }
    if (rc) fprintf(stderr, "render: %s\n", pen_context_error(ctx));
    pen_image_free(&image);
    pen_render_state_free(state);
    pen_context_destroy(ctx);
    return rc != 0;
}
