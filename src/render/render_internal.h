/* Internal interface of src/render: the per-pixel shading kernel (visibility from spheres, SH
 * exponential, diffuse SH shading) and texture sampling, each a forward/backward pair. The kernel
 * is compiled in float (the renderer) and double (`_d`, gradient checks) from shade_ops.inc. */
#ifndef PEN_RENDER_INTERNAL_H
#define PEN_RENDER_INTERNAL_H

#include "penumbra/image.h"
#include "penumbra/sh.h"

/* Everything about a frame's shading that is the same for every pixel. */
typedef struct pen__shade_params {
    int bands;                   /* SH bands of lighting and visibility */
    const pen_sh_gaunt *gaunt;   /* product table for `bands` */
    pen_sh_exp_model model;      /* the SH exponential */
    double epsilon;              /* log-visibility depth of a sphere */
    int shadows;                 /* 0: V == 1 (no-shadows mode) */
    double hz[PEN_SH_MAX_BANDS]; /* clamped cosine, zonal */
} pen__shade_params;

/* Fills p; the model's epsilon is used when epsilon is not a positive finite number. */
void pen__shade_params_init(pen__shade_params *p, int bands, const pen_sh_exp_model *model,
                            double epsilon, int shadows);

/* Self-shadowing rule: a sphere (c, r) counts towards the log-visibility of a receiver (x, n)
 * with weight w(h), h = n . (c - x) / r, where w is the smoothstep from h = -1 (the sphere lies
 * wholly behind the tangent plane: w = 0) to h = +1 (wholly in front: w = 1). C1 in h. */
#define PEN_RENDER_SELF_H0 (-1.0)
#define PEN_RENDER_SELF_H1 (1.0)

/* Outgoing radiance of a diffuse receiver at x with unit normal n and albedo rho:
 *   rgb[ch] = rho[ch] / pi * sum_k sh[k][ch] (V * H_n)_k,
 *   V = exp*(sum_i w_i kappa_i logvis_i(x)), H_n = clamped cosine rotated to n.
 * spheres: sphere_count world-space spheres (x, y, z, r); kappa: their overlap weights (NULL: all
 * 1), constants of the backward. fv (may be NULL) receives F and V (2 bands^2 values) for the
 * backward when shadows are on. */
void pen__shade_fwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], float rgb[3], float *fv);
void pen__shade_fwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], double rgb[3], double *fv);
/* Backward: adds into d_sh (bands^2 x 3, double), d_spheres (4 per sphere, double), d_x, d_n
 * (the gradient of the polynomial extension in n: normalise's backward removes the radial part)
 * and d_rho; any may be NULL. fv: the forward's F and V for this pixel, or NULL to recompute. */
void pen__shade_bwd(const pen__shade_params *p, const float (*sh)[3], int sphere_count,
                    const float *spheres, const float *kappa, const float x[3], const float n[3],
                    const float rho[3], const float d_rgb[3], const float *fv, double (*d_sh)[3],
                    double *d_spheres, float d_x[3], float d_n[3], float d_rho[3]);
void pen__shade_bwd_d(const pen__shade_params *p, const double (*sh)[3], int sphere_count,
                      const double *spheres, const double *kappa, const double x[3],
                      const double n[3], const double rho[3], const double d_rgb[3],
                      const double *fv, double (*d_sh)[3], double *d_spheres, double d_x[3],
                      double d_n[3], double d_rho[3]);

/* Bilinear texture lookup (3 channels), repeat wrap, texel centres at ((i + 0.5) / W,
 * 1 - (j + 0.5) / H) in (u, v) with v up (row 0 is the top of the image). */
void pen__texture_fwd(const pen_image *tex, const float uv[2], float rgb[3]);
/* Adds into d_texels (3 per texel, may be NULL) and d_uv (may be NULL). */
void pen__texture_bwd(const pen_image *tex, const float uv[2], const float d_rgb[3],
                      float *d_texels, float d_uv[2]);

#endif
