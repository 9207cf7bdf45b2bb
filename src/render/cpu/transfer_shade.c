/* The CPU backend's pixels shaded with a traced transfer (docs/design.md sec. 1.15): an object's
 * own pixels (self.c's transfer) and the ground's under such objects (ground_shadow.c's grid).
 * The frame traces and interpolates; here the kernels shade, forward and backward side by side.
 *
 * Design
 * - A transfer pixel shades with T = exp*(F_others) * (H_n - B): B the interpolated blocked part
 *   of the clamped cosine (a constant, no gradient), F_others the log-visibility of the spheres
 *   that may shadow it, through the per-object overlap weights kappa_self (0 on the object's own
 *   spheres, which adds nothing and skips them) or the grid's kappa (0 on the transferred
 *   objects'), so sphere indices and their gradients keep the frame's layout. Disk lights see the
 *   traced unblocked fraction of each disk in place of the horizon factors G.
 * - One code path: these pixels go through the scalar kernel's transfer functions
 *   (pen__shade_self_fwd / bwd, pen__lights_fwd / bwd) whichever kernel the frame uses. Under
 *   the fast kernel only an object's pixels' sum F is the fast kernel's (pen__self_shade_fast_fwd:
 *   a run's transfer pixels of one object as one call with its kappa_self), kept in the store for
 *   the backward: with thousands of spheres the sum is all the cost, and the pixels then agree
 *   with the scalar kernel within float rounding (the sum's order), not bit for bit.
 */
#include "core/internal.h"
#include "render/cpu/cpu.h"

#include <string.h>

/* ---- An object's own pixels ------------------------------------------------------------------ */

/* What both passes need at pixel i: its object's kappa_self, the number of spheres to visit for
 * the SH part, the interpolated blocked part and the light fractions (the lights' factors G). */
typedef struct self_pixel {
    const float *kap, *x, *n, *rho;
    int count;
    float B[PEN_SH_MAX_COEFFS];
    double frac[PEN_SCENE_MAX_LIGHTS];
} self_pixel;

static void self_pixel_at(const pen_render_state *st, size_t i, self_pixel *px) {
    const int o = st->gb.surface[i], S = st->sphere_count;
    px->kap = st->kappa_self.data + (size_t)o * (size_t)S;
    px->count = st->obj[o].self_others ? S : 0;
    px->x = st->x.data + 3 * i, px->n = st->n.data + 3 * i, px->rho = st->rho.data + 3 * i;
    pen__self_transfer_at(st, o, i, px->B, px->frac);
}

void pen__self_shade_fwd(pen_render_state *st, const float (*sh)[3], int ncull, const int *cull,
                         size_t i, float *fv, float *V) {
    self_pixel px;
    self_pixel_at(st, i, &px);
    float *rgb = st->color.data + 3 * i;
    pen__shade_self_fwd(&st->params, sh, px.count, st->spheres.data, px.kap, px.x, px.n, px.B,
                        px.rho, rgb, fv);
    if (st->lights.count)
        pen__lights_fwd(&st->lights, px.frac, ncull, st->spheres.data, px.kap, cull, px.x, px.n,
                        px.rho, rgb, V);
}

/* The lights' visibilities to keep for pixel i, or NULL. */
static float *lights_keep(pen_render_state *st, size_t i) {
    return st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL;
}

/* The fast kernel sums F = sum_s w_s kappa_s f_s in lanes over every sphere of the frame (the
 * cost of a transfer pixel among many objects: 4096 spheres, about half in front of the tangent
 * plane, bench/NOTES.md "Many small objects"); what depends on the transfer (V = exp*(F), T =
 * V (H_n - B), the disks with the traced fractions) stays scalar per pixel. The kernel's own
 * shading of V H_n is discarded: a few products per pixel beside the sum. */
void pen__self_shade_fast_fwd(pen_render_state *st, const float (*sh)[3], int ncull,
                              const int *cull, const int *pix, int count, pen__tile_ws *ws,
                              float *F, pen__shade_fast_ticks *tk) {
    const int S = st->sphere_count, nc = st->params.bands * st->params.bands;
    /* The pixels' order by object (stable; a run of one object, the usual case, does not move). */
    int ord[PEN_TILE_PX], obj[PEN_TILE_PX];
    for (int k = 0; k < count; ++k) {
        const int o = st->gb.surface[pix[k]];
        int j = k;
        for (; j > 0 && obj[j - 1] > o; --j)
            ord[j] = ord[j - 1], obj[j] = obj[j - 1];
        ord[j] = k, obj[j] = o;
    }
    for (int a = 0, b; a < count; a = b) {
        const int o = obj[a];
        for (b = a; b < count && obj[b] == o; ++b)
            pen__tile_ws_push(ws, b - a, st, (size_t)pix[ord[b]]);
        const int others = st->obj[o].self_others;
        if (others)
            pen__shade_fast_fwd(&st->params, sh, S, st->spheres.data,
                                st->kappa_self.data + (size_t)o * (size_t)S, b - a, 0, ws->x, ws->n,
                                ws->rho, ws->out, ws->fstore, ws->kernel, tk);
        for (int j = a; j < b; ++j) {
            const size_t i = (size_t)pix[ord[j]];
            float f[PEN_SH_MAX_COEFFS] = {0};
            if (others) pen__shade_fast_store_pixel(&st->params, ws->fstore, j - a, f);
            if (F) memcpy(F + (size_t)nc * (size_t)ord[j], f, sizeof(float) * (size_t)nc);
            self_pixel px;
            self_pixel_at(st, i, &px);
            float *rgb = st->color.data + 3 * i;
            pen__shade_self_given_fwd(&st->params, sh, px.count, st->spheres.data, px.kap, px.x,
                                      px.n, px.B, others ? f : NULL, px.rho, rgb, NULL);
            if (st->lights.count)
                pen__lights_fwd(&st->lights, px.frac, ncull, st->spheres.data, px.kap, cull, px.x,
                                px.n, px.rho, rgb, lights_keep(st, i));
        }
    }
}

void pen__self_shade_bwd(const pen_render_state *st, const float (*sh)[3], int ncull,
                         const int *cull, size_t i, const float *dc, const float *fv,
                         const float *F, const float *V, double (*d_sh)[3], double *d_sph,
                         float *d_x, float *d_n, float *d_rho, double *d_lights) {
    self_pixel px;
    self_pixel_at(st, i, &px);
    if (F)
        pen__shade_self_given_bwd(&st->params, sh, px.count, st->spheres.data, px.kap, px.x, px.n,
                                  px.B, F, px.rho, dc, d_sh, d_sph, d_x, d_n, d_rho);
    else
        pen__shade_self_bwd(&st->params, sh, px.count, st->spheres.data, px.kap, px.x, px.n, px.B,
                            px.rho, dc, fv, d_sh, d_sph, d_x, d_n, d_rho);
    if (st->lights.count) /* the fractions enter as the lights' G, constants */
        pen__lights_bwd(&st->lights, px.frac, ncull, st->spheres.data, px.kap, cull, px.x, px.n,
                        px.rho, dc, V, d_sph, d_x, d_n, d_rho, d_lights, NULL);
}

/* ---- The ground's pixels under the grid ------------------------------------------------------ */

void pen__ground_shadow_fwd(pen_render_state *st, const float (*sh)[3], int ncull, const int *cull,
                            size_t i, float *fv, float *V) {
    float B[PEN_SH_MAX_COEFFS];
    double frac[PEN_SCENE_MAX_LIGHTS];
    const float *x = st->x.data + 3 * i, *n = st->n.data + 3 * i, *rho = st->rho.data + 3 * i;
    pen__ground_grid_at(st, i, B, frac);
    const int count = st->grid.others ? st->sphere_count : 0;
    float *rgb = st->color.data + 3 * i;
    pen__shade_self_fwd(&st->params, sh, count, st->spheres.data, st->grid.kappa.data, x, n, B, rho,
                        rgb, fv);
    if (st->lights.count)
        pen__lights_fwd(&st->lights, frac, ncull, st->spheres.data, st->grid.kappa.data, cull, x, n,
                        rho, rgb, V);
}

void pen__ground_shadow_bwd(const pen_render_state *st, const float (*sh)[3], int ncull,
                            const int *cull, size_t i, const float *dc, const float *fv,
                            const float *V, double (*d_sh)[3], double *d_sph, float *d_rho,
                            double *d_lights) {
    float B[PEN_SH_MAX_COEFFS];
    double frac[PEN_SCENE_MAX_LIGHTS];
    const float *x = st->x.data + 3 * i, *n = st->n.data + 3 * i, *rho = st->rho.data + 3 * i;
    pen__ground_grid_at(st, i, B, frac);
    const int count = st->grid.others ? st->sphere_count : 0;
    pen__shade_self_bwd(&st->params, sh, count, st->spheres.data, st->grid.kappa.data, x, n, B, rho,
                        dc, fv, d_sh, d_sph, NULL, NULL, d_rho);
    if (st->lights.count) /* the fractions enter as the lights' G, constants */
        pen__lights_bwd(&st->lights, frac, ncull, st->spheres.data, st->grid.kappa.data, cull, x, n,
                        rho, dc, V, d_sph, NULL, NULL, d_rho, d_lights, NULL);
}
