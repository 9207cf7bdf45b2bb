/* Fuzz harness: scene JSON through pen_scene_parse, from memory. The text is parsed as if it
 * were fuzz_dir()/scene.json, so its references reach the fixed assets there (tri.obj, two.obj
 * with its two.mtl materials, tri.ply, spheres.json, tex.png, env.hdr, env.exr): the fuzzer
 * explores the scene's own keys with files that load. An accepted scene must hold finite values
 * throughout. */
#include "fuzz.h"

#include <stdio.h>
#include <stdlib.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static char path[600];
    if (!path[0]) snprintf(path, sizeof path, "%s/scene.json", fuzz_dir());
    char *text = fuzz_text(data, size);
    pen_scene scene;
    if (pen_scene_parse(fuzz_context(), text, path, &scene) == PEN_OK) {
        fuzz_check_scene(&scene);
        pen_scene_free(&scene);
    } else if (scene.objects || scene.path) {
        fuzz_fail("scene: refused but not zeroed");
    }
    free(text);
    return 0;
}
