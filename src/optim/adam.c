/* Adam (Kingma and Ba 2015) over segments of a flat parameter vector, the projection onto
 * simple bounds, and the stopping rule.
 *
 * Each segment (a parameter group of one object: its texels, its pose translation, ...) has its
 * own step size; Adam's per-coordinate normalisation makes the step about `lr` in the
 * parameter's own units whatever the scale of the gradient, which is why one learning rate
 * (1e-2, supplement section 5.1) serves textures, lighting and poses alike. Moments are kept in
 * float; the bias corrections in double. Bounds are enforced by projecting after the step
 * (projected gradient descent), which keeps albedos physical and radii positive without changing
 * the objective.
 *
 * Stopping: the supplement stops when (Theta_{n-1} - Theta_n) / Theta_n <= 0.001. Applied to
 * single iterations that fires at the first wobble of Adam's loss. Comparing the means of two
 * consecutive windows of 10 (this file's first rule) still fired on the transient rise Adam's
 * momentum causes on pose tasks: it overshoots for 20-50 steps before the loss falls below its
 * first values (Bob's pose under the interior map: stopped at iteration 37 and 10.2 degrees off,
 * 0.14 degrees when let run). So the ratio is taken between best losses: stop when the lowest
 * loss of the last `window` iterations is not `tolerance` (relative) below the lowest before
 * them, i.e. no real progress for `window` steps. The loop returns the best iterate, so the rule
 * only decides how long to look for a better one. Window 1 is the supplement's rule measured
 * against the best loss so far instead of the previous one. The default window, 50, is the
 * longest such transient seen in the experiment table (docs/optimize.md). */
#include "optim/optim_internal.h"

#include <math.h>
#include <stdlib.h>

pen_status pen__optim_adam_init(pen_context *ctx, pen__adam *adam, size_t n) {
    adam->n = n;
    adam->t = 0;
    adam->beta1 = 0.9;
    adam->beta2 = 0.999;
    adam->eps = 1e-8;
    adam->m = pen__calloc(ctx, n ? n : 1, sizeof(float), "Adam moments");
    adam->v = pen__calloc(ctx, n ? n : 1, sizeof(float), "Adam moments");
    if (!adam->m || !adam->v) {
        pen__optim_adam_free(adam);
        return PEN_ERROR_MEMORY;
    }
    return PEN_OK;
}

void pen__optim_adam_free(pen__adam *adam) {
    free(adam->m);
    free(adam->v);
    adam->m = adam->v = NULL;
    adam->n = 0;
}

/* Clamps to [-bound, bound]; NaN stays NaN (a failure the run reports, not a value to hide). */
static void clamp_symmetric(float *p, size_t n, float bound) {
    for (size_t i = 0; i < n; ++i)
        p[i] = p[i] < -bound ? -bound : p[i] > bound ? bound : p[i];
}

/* The largest float b with exp(b) <= PEN__OPTIM_MAX_EXPOSURE and exp(-b) >=
 * PEN__OPTIM_MIN_EXPOSURE: a log exposure in [-b, b] makes (exp in double, params.c) an exposure
 * that a views file holds (views.c), so views.json reads back. */
static float log_exposure_bound(void) {
    float b = (float)log(PEN__OPTIM_MAX_EXPOSURE);
    while (exp((double)b) > PEN__OPTIM_MAX_EXPOSURE || exp(-(double)b) < PEN__OPTIM_MIN_EXPOSURE)
        b = nextafterf(b, 0.0f);
    return b;
}

static void project_segment(const pen__optim_segment *s, float *x) {
    float *p = x + s->offset;
    switch (s->bound) {
    case PEN__BOUND_NONE:
        break;
    case PEN__BOUND_SH: /* what a scene file holds: the written scene.json reads back */
        clamp_symmetric(p, s->count, (float)PEN_SCENE_MAX_SH);
        break;
    case PEN__BOUND_LOG_EXPOSURE:
        clamp_symmetric(p, s->count, log_exposure_bound());
        break;
    case PEN__BOUND_UNIT:
        for (size_t i = 0; i < s->count; ++i)
            p[i] = fminf(fmaxf(p[i], 0.0f), 1.0f);
        break;
    case PEN__BOUND_SPHERES:
        for (size_t i = 3; i < s->count; i += 4)
            p[i] = fmaxf(p[i], PEN__OPTIM_MIN_RADIUS);
        break;
    case PEN__BOUND_LIGHTS:
        /* The renderer normalises the direction, so its length is free; kept at 1 so that the
         * step (about the rate) stays an angle and the vector never shrinks towards zero. */
        for (size_t i = 0; i + PEN_LIGHT_FLOATS <= s->count; i += PEN_LIGHT_FLOATS) {
            float *d = p + i + PEN_LIGHT_OFFSET_DIRECTION, *e = p + i + PEN_LIGHT_OFFSET_IRRADIANCE;
            float *radius = p + i + PEN_LIGHT_OFFSET_RADIUS;
            const double a = d[0], b = d[1], c = d[2];
            const double n = sqrt(a * a + b * b + c * c);
            if (n > 1e-12)
                for (int k = 0; k < 3; ++k)
                    d[k] = (float)((double)d[k] / n);
            *radius = fminf(fmaxf(*radius, (float)PEN_SCENE_MIN_LIGHT_RADIUS_DEG),
                            (float)PEN_SCENE_MAX_LIGHT_RADIUS_DEG);
            for (int k = 0; k < 3; ++k)
                e[k] = fminf(fmaxf(e[k], 0.0f), (float)PEN_SCENE_MAX_IRRADIANCE);
        }
        break;
    }
}

void pen__optim_project(const pen__optim_segment *segments, int segment_count, float *x) {
    for (int k = 0; k < segment_count; ++k)
        project_segment(&segments[k], x);
}

void pen__optim_adam_step(pen__adam *adam, const pen__optim_segment *segments, int segment_count,
                          float *x, const float *g) {
    adam->t++;
    const double c1 = 1.0 - pow(adam->beta1, adam->t), c2 = 1.0 - pow(adam->beta2, adam->t);
    const float b1 = (float)adam->beta1, b2 = (float)adam->beta2;
    for (int k = 0; k < segment_count; ++k) {
        const pen__optim_segment *s = &segments[k];
        /* lr * mhat / (sqrt(vhat) + eps) = (lr / c1) m / (sqrt(v / c2) + eps) */
        const float step = (float)((double)s->lr / c1), inv_c2 = (float)(1.0 / c2);
        const float eps = (float)adam->eps;
        for (size_t i = s->offset; i < s->offset + s->count; ++i) {
            adam->m[i] = b1 * adam->m[i] + (1.0f - b1) * g[i];
            adam->v[i] = b2 * adam->v[i] + (1.0f - b2) * g[i] * g[i];
            x[i] -= step * adam->m[i] / (sqrtf(adam->v[i] * inv_c2) + eps);
        }
        project_segment(s, x);
    }
}

int pen__optim_stalled(const double *losses, int n, int window, double tolerance) {
    if (window < 1 || n < window + 1) return 0;
    double before = losses[0], recent = losses[n - window];
    for (int i = 1; i < n - window; ++i)
        before = fmin(before, losses[i]);
    for (int i = n - window + 1; i < n; ++i)
        recent = fmin(recent, losses[i]);
    if (!(recent > 0.0)) return 1; /* a zero loss cannot fall further */
    return (before - recent) / recent <= tolerance;
}
