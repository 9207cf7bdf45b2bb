/* The per-pixel shading kernel in float and double (shade_ops.inc, compiled twice) and its
 * per-frame parameters. The texture lookup that feeds it the albedo is the model's
 * (src/scene/texture.c), shared with the reference renderer. */
#include "core/internal.h"
#include "shade/shade.h"

#include <tgmath.h>

#define REAL float
#define SUF(name) name
#include "shade/shade_ops.inc"
#undef REAL
#undef SUF

#define REAL double
#define SUF(name) name##_d
#include "shade/shade_ops.inc"
#undef REAL
#undef SUF

void pen__shade_params_init(pen__shade_params *p, int bands, const pen_sh_exp_model *model,
                            double epsilon, int shadows) {
    p->bands = bands;
    p->gaunt = pen_sh_gaunt_table(bands);
    p->model = *model;
    p->epsilon = (isfinite(epsilon) && epsilon > 0.0) ? epsilon : model->epsilon;
    p->shadows = shadows;
    for (int l = 0; l < PEN_SH_MAX_BANDS; ++l)
        p->hz[l] = 0.0;
    pen_sh_zonal_clamped_cosine_d(bands, p->hz);
}
