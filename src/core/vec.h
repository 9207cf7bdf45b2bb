/* Small 3-vector helpers shared by every folder that does geometry by hand (the rasterizer's
 * double-precision kernels, the reference renderer's float shading frames, the fit preview).
 * Plain expressions in one place so that each copy computes bit for bit the same thing; the
 * double versions take no aliasing assumptions (out may be an input). */
#ifndef PEN_CORE_VEC_H
#define PEN_CORE_VEC_H

#include <math.h>

/* ---- double ---------------------------------------------------------------------------------- */

static inline void pen__cross_d(const double a[3], const double b[3], double out[3]) {
    double x = a[1] * b[2] - a[2] * b[1];
    double y = a[2] * b[0] - a[0] * b[2];
    double z = a[0] * b[1] - a[1] * b[0];
    out[0] = x, out[1] = y, out[2] = z;
}

static inline double pen__dot_d(const double a[3], const double b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void pen__sub_d(const double a[3], const double b[3], double out[3]) {
    out[0] = a[0] - b[0], out[1] = a[1] - b[1], out[2] = a[2] - b[2];
}

static inline void pen__load3_d(const float *p, double out[3]) {
    out[0] = (double)p[0], out[1] = (double)p[1], out[2] = (double)p[2];
}

/* ---- float ----------------------------------------------------------------------------------- */

static inline float pen__dot_f(const float a[3], const float b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* out must not alias a or b. */
static inline void pen__cross_f(const float a[3], const float b[3], float out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Normalises v in place; returns 0 (and leaves v) if it has no usable length. */
static inline int pen__normalize_f(float v[3]) {
    float len = sqrtf(pen__dot_f(v, v));
    if (!(len > 1e-30f) || !isfinite(len)) return 0;
    v[0] /= len, v[1] /= len, v[2] /= len;
    return 1;
}

#endif
