/* Fuzz harness: optimisation task JSON through pen_optim_task_parse, from memory, parsed as if
 * it were fuzz_dir()/task.json (its scene, target and ground truth can name the fixed assets
 * there, e.g. "target": "target.exr", 8x8). An accepted task must hold a finite scene, target
 * and ground truth and finite settings. */
#include "fuzz.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

static void check_task(const pen_optim_task *t) {
    fuzz_check_scene(&t->scene);
    fuzz_check_image(&t->target);
    if (t->target.width != t->scene.camera.width || t->target.height != t->scene.camera.height)
        fuzz_fail("task: target size differs from the camera's");
    if (t->has_ground_truth) fuzz_check_scene(&t->ground_truth);
    const float lr[] = {t->lr.lighting,    t->lr.albedo,  t->lr.rotation,
                        t->lr.translation, t->lr.spheres, t->lr.deformation_rotation,
                        t->lr.deformation_translation};
    fuzz_check_floats(lr, sizeof lr / sizeof lr[0], "task: lr");
    const double d[] = {t->tolerance,          t->shadow_weight,
                        t->deformation.w_rot,  t->deformation.w_reg,   t->spheres.w_smooth};
    for (size_t i = 0; i < sizeof d / sizeof d[0]; ++i)
        if (!isfinite(d[i])) fuzz_fail("task: non-finite setting");
    /* (NaN: the solver's default ridge, penumbra/optim.h) */
    if (!isnan(t->lighting_ridge) && !(isfinite(t->lighting_ridge) && t->lighting_ridge >= 0.0))
        fuzz_fail("task: lighting_ridge");
    if (t->iterations < 0 || t->window < 1) fuzz_fail("task: iterations or window");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static char path[600];
    if (!path[0]) snprintf(path, sizeof path, "%s/task.json", fuzz_dir());
    char *text = fuzz_text(data, size);
    pen_optim_task task;
    if (pen_optim_task_parse(fuzz_context(), text, path, &task) == PEN_OK) {
        check_task(&task);
        pen_optim_task_free(&task);
    } else if (task.scene.objects || task.target.data || task.path) {
        fuzz_fail("task: refused but not zeroed");
    }
    free(text);
    return 0;
}
