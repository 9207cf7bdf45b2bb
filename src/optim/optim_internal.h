/* Internal interface of the inverse-problem solver (src/optim/): Adam over a flat parameter
 * vector cut into segments, the stopping rule, and the ground-truth metrics. Not installed. */
#ifndef PEN_OPTIM_INTERNAL_H
#define PEN_OPTIM_INTERNAL_H

#include "core/internal.h"
#include "penumbra/optim.h"

/* ---- Adam (src/optim/adam.c) ----------------------------------------------------------------- */

/* What a segment's values must satisfy after each step (a projection, applied in place). */
typedef enum pen__optim_bound {
    PEN__BOUND_NONE = 0,
    PEN__BOUND_UNIT,   /* every value in [0, 1] (albedos) */
    PEN__BOUND_SPHERES /* x, y, z, r per sphere: r >= PEN__OPTIM_MIN_RADIUS */
} pen__optim_bound;

#define PEN__OPTIM_MIN_RADIUS 1e-3f

/* A run of parameters sharing a learning rate and a bound: x[offset .. offset + count). */
typedef struct pen__optim_segment {
    size_t offset, count;
    float lr;
    pen__optim_bound bound;
} pen__optim_segment;

typedef struct pen__adam {
    size_t n;
    float *m, *v; /* first and second moment estimates */
    int t;        /* steps taken */
    double beta1, beta2, eps;
} pen__adam;

/* Zeroed moments for n parameters; beta1 = 0.9, beta2 = 0.999, eps = 1e-8. */
pen_status pen__optim_adam_init(pen_context *ctx, pen__adam *adam, size_t n);
void pen__optim_adam_free(pen__adam *adam);
/* One step: x -= lr * mhat / (sqrt(vhat) + eps) per segment (bias-corrected moments), then the
 * segment's bound. Parameters outside every segment are left alone. */
void pen__optim_adam_step(pen__adam *adam, const pen__optim_segment *segments, int segment_count,
                          float *x, const float *g);
/* Projects x onto the segments' bounds. */
void pen__optim_project(const pen__optim_segment *segments, int segment_count, float *x);

/* The stopping rule: with losses[0 .. n), 1 when n >= 2 window and the mean of the last
 * `window` losses is less than tolerance (relative to that mean) below the mean of the window
 * before it (a rise counts as stalled too). */
int pen__optim_stalled(const double *losses, int n, int window, double tolerance);

/* ---- Metrics (src/optim/evaluate.c) ---------------------------------------------------------- */

/* Fails when the task's ground truth does not match the scene's structure where the metrics of
 * the optimised groups need it (object count, band count, texture size, vertex count). */
pen_status pen__optim_check_truth(pen_context *ctx, const pen_optim_task *task);
/* Fills every metric of `m` that applies (the others are left alone) for the recovered scene
 * against the task's ground truth; image_rmse is the caller's. Renders (albedo views, texel
 * coverage) with the context's threads. */
pen_status pen__optim_metrics(pen_context *ctx, const pen_optim_task *task, pen_optim_metrics *m);
/* The angle in degrees between two axis-angle rotations (given in degrees), in double. */
double pen__optim_rotation_angle_deg(const float a_deg[3], const float b_deg[3]);

#endif
