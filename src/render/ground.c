/* Ground occlusion: the ground plane as an occluder of the objects, in the forward and the
 * backward.
 *
 * Design
 * - The reference ray-traces the ground, so a surface facing down or sideways loses the light
 *   from below the horizon; spheres cannot say that (a plane is no sphere), and without it the
 *   model lights the undersides of objects with the lower half of the environment.
 * - Seen from a point at height h over a disc of radius s (the ground's half size), the ground
 *   covers the directions within atan(s / h) of straight down, i.e. the point sees the
 *   directions with y > -t, t = h / sqrt(h^2 + s^2). The product of the lighting with that
 *   indicator, projected back to the bands, is a linear map of the lighting, seen = M(t) sh
 *   (pen__sh_above), so it costs nothing per pixel when t is one per object: h is taken at the
 *   object's origin (the pose's translation; the bundled meshes are centred), and the object's
 *   pixels shade with `seen`, the ground's own pixels with sh. With shadows off (V = 1
 *   everywhere) nothing is occluded.
 * - The backward maps the gradient of `seen` back through M^T = M into the lighting, and through
 *   dM/dt dt/dh into the pose's vertical translation. It takes the per-object gradients of
 *   `seen` that the tiles summed (the pixels of object o shade with its own `seen`: cpu/tiles.c's
 *   lighting groups).
 * - Disk lights (docs/design.md sec. 1.13): an object receives the fraction of each disk above
 *   the same horizon y > -t (the overlap of the disk with the cap of half-angle acos(-t) around
 *   +Y, continuous as the sun sets), one factor per object and light, with its derivatives by the
 *   height and by the light's direction and radius for the backward. The backend's prepare
 *   computes them from t and dt/dh kept here (a kernel: src/shade/lights.c); the backward's map
 *   back to the height and the lights is here.
 */
#include "core/internal.h"
#include "render/render_internal.h"
#include "sh/sh_internal.h"

#include <math.h>
#include <stddef.h>

void pen__ground_occlusion_prepare(const pen_scene *sc, const pen_render_options *opt,
                                   pen_render_state *st) {
    st->ground_occludes = opt->shadows && sc->ground.enabled && sc->object_count > 0 &&
                          sc->shadow.ground == PEN_GROUND_OCCLUDES;
    if (!st->ground_occludes) return;
    const int n = sc->sh_bands * sc->sh_bands;
    double dM[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS]; /* 32 KB */
    for (int o = 0; o < sc->object_count; ++o) {
        pen__object_buf *b = &st->obj[o];
        const double h = (double)sc->objects[o].pose.translation[1] - (double)sc->ground.height;
        const double s = (double)sc->ground.half_size, r = sqrt(h * h + s * s);
        const double t = r > 0.0 ? h / r : 0.0, dt_dh = r > 0.0 ? s * s / (r * r * r) : 0.0;
        pen__sh_above(sc->sh_bands, t, b->horizon, dM);
        for (int j = 0; j < n; ++j)
            for (int ch = 0; ch < 3; ++ch) {
                double v = 0.0, dv = 0.0;
                for (int k = 0; k < n; ++k) {
                    v += b->horizon[j * n + k] * (double)sc->lighting.sh[k][ch];
                    dv += dM[j * n + k] * (double)sc->lighting.sh[k][ch];
                }
                b->seen[j][ch] = (float)v;
                b->d_seen_dh[j][ch] = dv * dt_dh;
            }
        /* The disk lights see the same horizon: their factors are the backend's (backend.h). */
        b->ground_t = t, b->ground_dt_dh = dt_dh;
    }
}

void pen__ground_lights_bwd(const pen_scene *sc, const pen_render_state *st, const double *d_G,
                            double *d_lights, pen_render_grad *grad) {
    if (!st->ground_occludes) return;
    const int K = st->lights.count;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen__object_buf *b = &st->obj[o];
        double dh = 0.0;
        for (int l = 0; l < K; ++l) {
            const double g = d_G[(size_t)o * (size_t)K + (size_t)l];
            dh += g * b->light_G_dh[l];
            if (!d_lights) continue;
            double *dl = d_lights + PEN_LIGHT_GRAD_DOUBLES * l;
            for (int a = 0; a < 3; ++a)
                dl[a] += g * b->light_G_dw[l][a];
            dl[3] += g * b->light_G_db[l];
        }
        if (grad) grad->objects[o].pose.translation[1] += (float)dh;
    }
}

void pen__ground_occlusion_bwd(const pen_scene *sc, const pen_render_state *st,
                               const double *d_seen, double (*d_sh)[3], pen_render_grad *grad) {
    if (!st->ground_occludes) return;
    const int nc = sc->sh_bands * sc->sh_bands, O = sc->object_count;
    const size_t nsh = 3 * (size_t)nc;
    if (d_sh)
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch) {
                double d = d_sh[k][ch];
                for (int o = 0; o < O; ++o) { /* seen = M sh: d sh += M^T d seen, M = M^T */
                    const double *ds = d_seen + nsh * (size_t)o, *M = st->obj[o].horizon;
                    for (int j = 0; j < nc; ++j)
                        d += M[k * nc + j] * ds[3 * (size_t)j + ch];
                }
                d_sh[k][ch] = d;
            }
    if (grad) /* seen depends on the object's height through M(t(h)) */
        for (int o = 0; o < O; ++o) {
            const double *ds = d_seen + nsh * (size_t)o;
            double d = 0.0;
            for (int j = 0; j < nc; ++j)
                for (int ch = 0; ch < 3; ++ch)
                    d += ds[3 * (size_t)j + ch] * st->obj[o].d_seen_dh[j][ch];
            grad->objects[o].pose.translation[1] += (float)d;
        }
}
