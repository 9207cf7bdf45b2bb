/* The optimizer's vocabulary, each part listed once (src/optim/groups.c, loss.c): the parameter
 * groups a task may optimise, the learning rates of pen_optim_lr, and the losses. Every reader
 * of a group, a rate or a loss (the task reader, the parameter vector's layout, the checkpoint,
 * result.json, the checks before a run) walks these tables, so that a new group is a row here
 * plus its own maths (params.c: its item count, its copy to and from the scene, its gradient), a
 * new rate a field of pen_optim_lr and a row, a new loss an enum value and a row with its
 * functions. Internal (not installed). */
#ifndef PEN_OPTIM_GROUPS_H
#define PEN_OPTIM_GROUPS_H

#include "penumbra/optim.h"

#include <stddef.h>

/* ---- Bounds ---------------------------------------------------------------------------------- */

/* What a segment's values must satisfy after each step (a projection, applied in place, adam.c).
 * The values are stored in checkpoints (checkpoint.c): append, never renumber. */
typedef enum pen__optim_bound {
    PEN__BOUND_NONE = 0,
    PEN__BOUND_UNIT,    /* every value in [0, 1] (albedos) */
    PEN__BOUND_SPHERES, /* x, y, z, r per sphere: r >= PEN__OPTIM_MIN_RADIUS */
    PEN__BOUND_LIGHTS,  /* per disk light: direction (renormalised to unit length), angular
                           radius in the scene's range, irradiance >= 0 */
    PEN__BOUND_SH,      /* every value in [-PEN_SCENE_MAX_SH, PEN_SCENE_MAX_SH] (SH lighting: what
                           a scene file holds, so that the recovered scene.json reads back) */
    PEN__BOUND_LOG_EXPOSURE /* every value a log exposure whose exposure is in
                               [PEN__OPTIM_MIN_EXPOSURE, PEN__OPTIM_MAX_EXPOSURE] (optim_internal.h:
                               what a views file holds, so that views.json reads back) */
} pen__optim_bound;

/* ---- Parameter groups ------------------------------------------------------------------------ */

/* The groups by index, in the order the task JSON, result.json and the docs list them; the
 * parameter vector holds the scene's groups first, then per object its groups, each in this
 * order (params.c). */
typedef enum pen__optim_group_id {
    PEN__OPTIM_G_LIGHTING,
    PEN__OPTIM_G_ALBEDO,
    PEN__OPTIM_G_POSE,
    PEN__OPTIM_G_DEFORMATION,
    PEN__OPTIM_G_SPHERES,
    PEN__OPTIM_G_LIGHTS,
    PEN__OPTIM_G_EXPOSURE,
    PEN__OPTIM_GROUPS
} pen__optim_group_id;

/* What a group needs of the scene to have something to move (pen__optim_task_check_groups). */
#define PEN__OPTIM_NEEDS_OBJECTS 1u
#define PEN__OPTIM_NEEDS_SPHERES 2u

/* One segment of a group's block: floats_per_item floats per item (the group's maths counts the
 * items: coefficients, lights, views, texel floats, spheres, graph nodes), one learning rate
 * (a field of pen_optim_lr, by name in pen__optim_rates) and one bound. */
typedef struct pen__optim_group_segment {
    size_t floats_per_item;
    int rate; /* index into pen__optim_rates */
    pen__optim_bound bound;
} pen__optim_group_segment;

typedef struct pen__optim_group {
    const char *name;  /* in "optimize", result.json's "optimize" and messages */
    unsigned bit;      /* PEN_OPTIM_* (optim.h): the PEN_GRAD_* bit of the same meaning */
    unsigned bit_v6;   /* its bit in checkpoints before version 7 (0: none then) */
    unsigned grad;     /* the render gradient groups (PEN_GRAD_*) its parameters are moved by */
    int per_object;    /* 1: one block per object; 0: one block for the scene */
    unsigned needs;    /* PEN__OPTIM_NEEDS_* */
    int segment_count; /* 1 or 2 */
    pen__optim_group_segment segments[2];
    const char *lr_key; /* a key of the task's "lr" setting every rate of the group, or NULL */
    unsigned excludes;  /* groups it cannot be optimised with (bits), and what both would move */
    const char *shares;
} pen__optim_group;

extern const pen__optim_group pen__optim_groups[PEN__OPTIM_GROUPS];

/* Every group's bit. */
unsigned pen__optim_group_bits(void);
/* The names of the groups in `bits` (all groups for ~0u) into buf, in table order, separated by
 * ", ", quoted when `quoted`; "none" for none, and unknown bits as a hexadecimal rest. */
void pen__optim_group_list(unsigned bits, int quoted, char *buf, size_t size);
/* Checkpoints before version 7 held the groups by their bits then: the bits of today. */
unsigned pen__optim_groups_from_v6(unsigned bits_v6);

/* ---- Learning rates -------------------------------------------------------------------------- */

/* One field of pen_optim_lr: its key in the task's "lr" object and in result.json's, its place
 * in the struct and its default (pen_optim_lr_default). */
typedef struct pen__optim_rate {
    const char *name;
    size_t offset;
    float value;
} pen__optim_rate;

#define PEN__OPTIM_RATES 9
extern const pen__optim_rate pen__optim_rates[PEN__OPTIM_RATES];

static inline float *pen__optim_rate_field(pen_optim_lr *lr, int rate) {
    return (float *)((char *)lr + pen__optim_rates[rate].offset);
}
static inline float pen__optim_rate_value(const pen_optim_lr *lr, int rate) {
    return *(const float *)((const char *)lr + pen__optim_rates[rate].offset);
}

/* ---- Losses (src/optim/loss.c) --------------------------------------------------------------- */

typedef struct pen__optim_loss_kind {
    pen_optim_loss kind;
    const char *name; /* the task's "loss", result.json's, checkpoints' messages */
    /* The plain mean over pixels and channels (render.h): the loss, and with d_image (may be
     * NULL) its gradient image, set. */
    pen_status (*plain)(pen_context *ctx, const pen_image *image, const pen_image *target,
                        double *loss, pen_image *d_image);
    /* The mean weighted per pixel (weight NULL: 1; render/loss.h), and its backward, which adds
     * d_loss times the gradient into d_image. */
    pen_status (*fwd)(pen_context *ctx, const pen_image *image, const pen_image *target,
                      const float *weight, double *loss);
    void (*bwd)(const pen_image *image, const pen_image *target, const float *weight,
                double d_loss, pen_image *d_image);
    int least_squares; /* 1: the least-squares lighting minimises it exactly (optim.h) */
} pen__optim_loss_kind;

#define PEN__OPTIM_LOSSES 2
extern const pen__optim_loss_kind pen__optim_losses[PEN__OPTIM_LOSSES];

/* The row of `kind`, or NULL when it is no loss (a task built in code with another value). */
const pen__optim_loss_kind *pen__optim_loss_find(int kind);

#endif
