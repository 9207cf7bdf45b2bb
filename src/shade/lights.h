/* Internal interface of the disk lights (src/shade/lights.c, docs/design.md sec. 1.13): the
 * disk's clamped-cosine integral, the overlap of a sphere's cap with a disk, a frame's lights,
 * and the per-pixel light term with its backward. Everything is computed in double; the
 * per-pixel pair exists for float inputs (the renderer) and double inputs (`_d`, the gradient
 * checks). The scalar kernel's frame calls the per-pixel functions; the fast kernel's runs the
 * same term in its lanes (pen__lights_fwd_block / bwd_block, lights_fast.c), which come back here
 * for the partial overlaps. */
#ifndef PEN_SHADE_LIGHTS_H
#define PEN_SHADE_LIGHTS_H

#include "penumbra/scene.h"

/* Doubles per light of the backward's light gradient: d unit direction (3, before the
 * normalisation's backward), d angular radius (radians), d irradiance (3). */
#define PEN_LIGHT_GRAD_DOUBLES 7

/* D(c, b): the integral of max(n . omega, 0) over a uniform disk of angular radius b whose centre
 * is at cos(theta) = c from the normal n, divided by pi sin^2 b. D = c when the disk is wholly
 * above the horizon (c >= sin b), 0 wholly below (c <= -sin b), the exact horizon-clipped integral
 * in between (C1 in c). dD_dc and dD_db may be NULL. */
double pen__disk_clamped_cosine(double c, double b, double *dD_dc, double *dD_db);

/* The solid angle of the intersection of two caps of angular radii a and b in [0, pi] whose
 * centres are g in [0, pi] apart (closed form from the triangle of the two centres and a corner
 * of the lens, evaluated without cancellation for tiny caps), and its partials d[0..2] by a, b,
 * g (d may be NULL). */
double pen__cap_overlap(double a, double b, double g, double d[3]);

/* The same overlap from the cosines and sines of a, b and g (a + b < pi), without their angles
 * (the Gram determinant of the triangle of the two centres and a corner of the lens), and its
 * partials d[0..2] by a, b, g (d may be NULL); -1 where it does not apply (a + b >= pi, or the
 * caps tangent or one inside the other to rounding): then pen__cap_overlap. Cheaper than the
 * angle form (three atan, no sincos); relative to the disk's area within 1e-12 of it for disks from
 * PEN_LIGHTS_COS_LENS_DEG up (5e-13 at 0.25 deg, 1e-13 from 1 deg; tests/test_lights.c checks
 * both), 1e-11 at 0.01 deg. From 0.25 deg, so that a sun's penumbrae (0.27 deg) take it too, and
 * with it the fast kernel's packed double lanes. */
#define PEN_LIGHTS_COS_LENS_DEG 0.25
double pen__cap_overlap_cos(double ca, double sa, double cb, double sb, double cg, double sg,
                            double d[3]);

/* A frame's disk lights, as the per-pixel functions use them. */
typedef struct pen__lights {
    int count;
    int shadows;                          /* 0: V_l == 1 (no-shadows mode) */
    double eps;                           /* log-visibility depth of a sphere (as the SH path) */
    double w[PEN_SCENE_MAX_LIGHTS][3];    /* unit directions */
    double len[PEN_SCENE_MAX_LIGHTS];     /* |direction| as stored */
    double b[PEN_SCENE_MAX_LIGHTS];       /* angular radius, radians */
    double sin_b[PEN_SCENE_MAX_LIGHTS], cos_b[PEN_SCENE_MAX_LIGHTS];
    double area[PEN_SCENE_MAX_LIGHTS];    /* the disk's solid angle, 4 pi sin^2(b/2) */
    double E[PEN_SCENE_MAX_LIGHTS][3];    /* irradiance */
    int widest[PEN_SCENE_MAX_LIGHTS];     /* 0 .. count - 1 by b, widest first (the culls' order;
                                             any order gives the same result) */
} pen__lights;

void pen__lights_init(pen__lights *L, const pen_lighting *lighting, double eps, int shadows);

/* The fraction of light l's disk above the horizon y > -t that a ground which occludes leaves an
 * object (ground.c's t), with its partials by t, by the light's unit direction (3) and by b. */
double pen__lights_horizon(const pen__lights *L, int l, double t, double *d_t, double d_w[3],
                           double *d_b);

/* The spheres that may shadow any of the lights at some receiver in the box [lo, hi] (a tile's
 * points): their indices into idx (room for sphere_count), their count returned. Conservative:
 * a sphere left out has f = 0 for every light at every receiver of the box. */
int pen__lights_cull(const pen__lights *L, int sphere_count, const float *spheres,
                     const double lo[3], const double hi[3], int *idx);

/* pen__lights_cull's test for one sphere s (centre, radius) and the receivers within R of m: 0
 * only where f = 0 for every light at all of them. */
int pen__lights_may_shadow(const pen__lights *L, const float s[4], const double m[3], double R);

/* Receivers that pen__lights_candidates takes at once. */
#define PEN_LIGHTS_BLOCK 16

/* A float prefilter of the n spheres idx (NULL: 0 .. n - 1) for cnt <= PEN_LIGHTS_BLOCK
 * receivers k at x + 3 at[k], nrm + 3 at[k] (at NULL: k): into list + k n the spheres, in idx's
 * order, that may shadow some light at receiver k, their number into count[k]. Conservative: a
 * sphere left out has weight 0 or f = 0 for every light there, so passing a receiver's list to
 * pen__lights_fwd / bwd gives the same result, bit for bit, as passing idx. */
void pen__lights_candidates(const pen__lights *L, int n, const float *spheres, const int *idx,
                            int cnt, const float *x, const float *nrm, const int *at, int *list,
                            int *count);

/* The fast kernel's forward light term of cnt <= PEN_LIGHTS_BLOCK receivers at x + 3 at[k] (nrm,
 * rho and rgb likewise; at NULL: k) over the n spheres idx (NULL: 0 .. n - 1): adds into rgb what
 * pen__lights_fwd adds, and the lights' V into V_out + count at[k] (V_out may be NULL), in the
 * variant's float lanes (lights_fast.c): the same fractions where they are 0 or 1 and the double
 * lens for the rest, float rounding in D, the weights and the product. */
void pen__lights_fwd_block(const pen__lights *L, const double *G, int n, const float *spheres,
                           const float *kappa, const int *idx, int cnt, const float *x,
                           const float *nrm, const float *rho, const int *at, float *rgb,
                           float *V_out);

/* The backward of the fast kernel's light term for cnt <= PEN_LIGHTS_BLOCK receivers k at
 * x + 3 k (nrm, rho, d_x, d_n and d_rho likewise: compacted), whose d_rgb and forward V are at
 * d_rgb + 3 pix[k] and V_in + count pix[k] (V_in NULL: recomputed): adds what pen__lights_bwd
 * adds for each, in the variant's lanes (lights_fast.c; the partial pairs' own derivatives in
 * double lanes for wide disks, else by pen__lights_pair_bwd), by pen__lights_bwd for a receiver
 * whose point or normal is not finite.
 * scratch: room for the larger of n PEN_LIGHTS_BLOCK floats and (n + 1) PEN_LIGHTS_BLOCK ints
 * (used in turn). */
void pen__lights_bwd_block(const pen__lights *L, const double *G, int n, const float *spheres,
                           const float *kappa, const int *idx, int cnt, const float *x,
                           const float *nrm, const float *rho, const float *d_rgb,
                           const float *V_in, const int *pix, void *scratch, double *d_spheres,
                           float *d_x, float *d_n, float *d_rho, double *d_lights, double *d_G);

/* The fraction of light l's disk inside the cap of sphere s (x, y, z, r) seen from x, in double
 * (0 when the disk is certainly clear of it): the block's partial overlaps. */
double pen__lights_fraction(const pen__lights *L, int l, const float x[3], const float s[4]);

/* The backward block's partial pair (receiver x, n, sphere s with overlap weight kappa, light
 * l, dV V of the light at the receiver): adds what f's own derivatives give besides the
 * weight's, through the cap's angle, the disk's radius and the angle to the light, into dv (the
 * sphere's centre; the receiver's point gets -dv), *d_r and d_light (the light's
 * PEN_LIGHT_GRAD_DOUBLES; may be NULL), in double as pen__lights_bwd; returns f d_g, the pair's
 * share of -d/dq. */
double pen__lights_pair_bwd(const pen__lights *L, int l, const float x[3], const float n[3],
                            const float s[4], float kappa, double dVV, double dv[3], double *d_r,
                            double *d_light);

/* Adds the lights' radiance at a receiver (x, n, rho) into rgb:
 *   rgb[ch] += rho[ch] / pi * sum_l E_l[ch] D(n . w_l, b_l) G_l V_l(x),
 *   V_l = prod_i (1 - (1 - exp(-eps w_i kappa_i)) f_il),
 * f_il the fraction of disk l inside sphere i's cap, w_i the self-shadowing weight. G: per light
 * (the object's horizon factor), NULL for 1. spheres/kappa as pen__shade_fwd; idx (may be
 * NULL: spheres 0 .. sphere_count - 1) lists the sphere_count spheres to visit
 * (pen__lights_cull), by their index into spheres, kappa and d_spheres. V_out (may be NULL)
 * receives V_l of every light (1 where the disk is below the horizon) for the backward. */
void pen__lights_fwd(const pen__lights *L, const double *G, int sphere_count, const float *spheres,
                     const float *kappa, const int *idx, const float x[3], const float n[3],
                     const float rho[3], float rgb[3], float *V_out);
void pen__lights_fwd_d(const pen__lights *L, const double *G, int sphere_count,
                       const double *spheres, const double *kappa, const int *idx,
                       const double x[3], const double n[3], const double rho[3], double rgb[3],
                       double *V_out);
/* Backward: adds into d_spheres (4 per sphere), d_x, d_n, d_rho, d_lights (per light
 * PEN_LIGHT_GRAD_DOUBLES) and d_G (per light); any may be NULL. V_in: the forward's V_out for
 * this pixel (one per light), or NULL to recompute the visibilities. */
void pen__lights_bwd(const pen__lights *L, const double *G, int sphere_count, const float *spheres,
                     const float *kappa, const int *idx, const float x[3], const float n[3],
                     const float rho[3], const float d_rgb[3], const float *V_in,
                     double *d_spheres, float d_x[3], float d_n[3], float d_rho[3],
                     double *d_lights, double *d_G);
void pen__lights_bwd_d(const pen__lights *L, const double *G, int sphere_count,
                       const double *spheres, const double *kappa, const int *idx,
                       const double x[3], const double n[3], const double rho[3],
                       const double d_rgb[3], const double *V_in, double *d_spheres,
                       double d_x[3], double d_n[3], double d_rho[3], double *d_lights,
                       double *d_G);

#endif
