/* The CPU backend's table (render/backend.h): the stages of shade_fwd.c and shade_bwd.c. */
#include "render/backend.h"
#include "render/cpu/cpu.h"

static const pen__backend CPU = {
    "cpu", pen__cpu_prepare, pen__cpu_shade_fwd, pen__cpu_shade_bwd, pen__cpu_reduce,
};

const pen__backend *pen__backend_cpu(void) {
    return &CPU;
}

/* The lane count of the fast kernel this process runs (src/shade/shade_fast_dispatch.c). */
int pen_render_fast_lanes(void) {
    return pen__shade_fast_current()->lanes;
}
