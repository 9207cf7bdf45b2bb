/* The optimizer's parameter groups and learning rates, one row each (groups.h says who reads
 * them). A group's bit is the render gradient bit of the same meaning (render.h PEN_GRAD_*), so
 * that the groups a task moves are the render's groups as they stand (optimize.c hands them to
 * pen_render_grad_model as a mask); "deformation" moves the vertices (and the spheres, its graph's
 * nodes), "exposure" is no render group and takes a bit of its own. */
#include "optim/groups.h"

#include "penumbra/render.h"

#include <stdio.h>
#include <string.h>

_Static_assert(PEN_OPTIM_LIGHTING == PEN_GRAD_LIGHTING && PEN_OPTIM_ALBEDO == PEN_GRAD_ALBEDO &&
                   PEN_OPTIM_SPHERES == PEN_GRAD_SPHERES && PEN_OPTIM_POSE == PEN_GRAD_POSE &&
                   PEN_OPTIM_DEFORMATION == PEN_GRAD_VERTICES &&
                   PEN_OPTIM_LIGHTS == PEN_GRAD_LIGHTS && (PEN_OPTIM_EXPOSURE & PEN_GRAD_ALL) == 0,
               "the optimizer's group bits are the render's gradient bits");

/* The rates in pen_optim_lr's order, which is also result.json's. */
enum { LIGHTING, ALBEDO, ROTATION, TRANSLATION, SPHERES, DEFORMATION_ROTATION,
       DEFORMATION_TRANSLATION, LIGHTS, EXPOSURE };

#define RATE(field, value) {#field, offsetof(pen_optim_lr, field), value}
const pen__optim_rate pen__optim_rates[PEN__OPTIM_RATES] = {
    [LIGHTING] = RATE(lighting, 1e-2f),
    [ALBEDO] = RATE(albedo, 1e-2f),
    [ROTATION] = RATE(rotation, 1e-2f),
    [TRANSLATION] = RATE(translation, 1e-2f),
    [SPHERES] = RATE(spheres, 1e-2f),
    /* supplement section 5.1: 1e-3 for the graph's matrices */
    [DEFORMATION_ROTATION] = RATE(deformation_rotation, 1e-3f),
    [DEFORMATION_TRANSLATION] = RATE(deformation_translation, 1e-2f),
    [LIGHTS] = RATE(lights, 1e-2f),
    [EXPOSURE] = RATE(exposure, 1e-2f),
};
_Static_assert(sizeof(pen_optim_lr) == PEN__OPTIM_RATES * sizeof(float),
               "every field of pen_optim_lr has a row in pen__optim_rates");

#define NEEDS_OBJECTS PEN__OPTIM_NEEDS_OBJECTS
#define NEEDS_SPHERES (PEN__OPTIM_NEEDS_OBJECTS | PEN__OPTIM_NEEDS_SPHERES)
#define ONE(floats, rate, bound) 1, {{floats, rate, bound}}

const pen__optim_group pen__optim_groups[PEN__OPTIM_GROUPS] = {
    /* SH coefficients, 3 channels each */
    [PEN__OPTIM_G_LIGHTING] = {"lighting", PEN_OPTIM_LIGHTING, 1u, PEN_GRAD_LIGHTING, 0, 0,
                               ONE(3, LIGHTING, PEN__BOUND_SH), NULL, 0, NULL},
    /* texel floats, or the constant albedo's 3 */
    [PEN__OPTIM_G_ALBEDO] = {"albedo", PEN_OPTIM_ALBEDO, 2u, PEN_GRAD_ALBEDO, 1, NEEDS_OBJECTS,
                             ONE(1, ALBEDO, PEN__BOUND_UNIT), NULL, 0, NULL},
    /* rotation (radians), translation */
    [PEN__OPTIM_G_POSE] = {"pose", PEN_OPTIM_POSE, 4u, PEN_GRAD_POSE, 1, NEEDS_OBJECTS, 2,
                           {{3, ROTATION, PEN__BOUND_NONE}, {3, TRANSLATION, PEN__BOUND_NONE}},
                           "pose", 0, NULL},
    /* per graph node: its 3x3 matrix, then per node its translation */
    [PEN__OPTIM_G_DEFORMATION] = {"deformation", PEN_OPTIM_DEFORMATION, 8u,
                                  PEN_GRAD_SPHERES | PEN_GRAD_VERTICES, 1, NEEDS_SPHERES, 2,
                                  {{9, DEFORMATION_ROTATION, PEN__BOUND_NONE},
                                   {3, DEFORMATION_TRANSLATION, PEN__BOUND_NONE}},
                                  NULL, PEN_OPTIM_SPHERES, "the spheres"},
    /* centre and radius per sphere */
    [PEN__OPTIM_G_SPHERES] = {"spheres", PEN_OPTIM_SPHERES, 16u, PEN_GRAD_SPHERES, 1,
                              NEEDS_SPHERES, ONE(4, SPHERES, PEN__BOUND_SPHERES), NULL,
                              PEN_OPTIM_DEFORMATION, "the spheres"},
    /* per disk light (scene.h PEN_LIGHT_FLOATS) */
    [PEN__OPTIM_G_LIGHTS] = {"lights", PEN_OPTIM_LIGHTS, 32u, PEN_GRAD_LIGHTS, 0, 0,
                             ONE(PEN_LIGHT_FLOATS, LIGHTS, PEN__BOUND_LIGHTS), NULL, 0, NULL},
    /* log exposure per view but the first (the gauge); no render group: views.c */
    [PEN__OPTIM_G_EXPOSURE] = {"exposure", PEN_OPTIM_EXPOSURE, 64u, 0u, 0, 0,
                               ONE(1, EXPOSURE, PEN__BOUND_LOG_EXPOSURE), NULL, 0, NULL},
};

unsigned pen__optim_group_bits(void) {
    unsigned bits = 0;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        bits |= pen__optim_groups[g].bit;
    return bits;
}

void pen__optim_group_list(unsigned bits, int quoted, char *buf, size_t size) {
    size_t used = 0;
    const char *q = quoted ? "\"" : "";
    buf[0] = '\0';
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g) {
        if (!(bits & pen__optim_groups[g].bit)) continue;
        const int n = snprintf(buf + used, size - used, "%s%s%s%s", used ? ", " : "", q,
                               pen__optim_groups[g].name, q);
        if (n > 0 && (size_t)n < size - used) used += (size_t)n;
    }
    const unsigned rest = bits & ~pen__optim_group_bits();
    if (rest && bits != ~0u)
        snprintf(buf + used, size - used, "%s0x%x", used ? ", " : "", rest);
    else if (!used)
        snprintf(buf, size, "none");
}

unsigned pen__optim_groups_from_v6(unsigned bits_v6) {
    unsigned bits = 0;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (pen__optim_groups[g].bit_v6 & bits_v6) {
            bits |= pen__optim_groups[g].bit;
            bits_v6 &= ~pen__optim_groups[g].bit_v6;
        }
    /* bits no group had then (a damaged file): one no group has now, refused as another task */
    return bits_v6 ? bits | 0x80000000u : bits;
}
