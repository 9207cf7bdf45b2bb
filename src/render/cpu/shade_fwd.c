/* The CPU backend's forward (backend.h): the kernels' parameters, and every pixel's colour over
 * 16 x 16 tiles in parallel.
 *
 * Design
 * - Tiles (tiles.c: dynamic scheduling, a workspace per thread, the tile's pixels in lighting
 *   groups). Per tile, background pixels show the constant background or the environment map
 *   (background.c); surface pixels get their normal (facing the camera) and albedo (the texture
 *   lookup, footprint.c), then go compacted to the fast kernel (src/shade/shade_fast.c, batches of
 *   SIMD lanes) or one by one to the scalar reference kernel (shade_ops.inc), as
 *   pen_render_options.kernel and the kernel's coverage decide.
 * - Disk lights are added after the kernel's SH shading: under the scalar kernel by the double
 *   per-pixel term (src/shade/lights.c), under the fast kernel by the same term in its lanes
 *   (lights_fast.c, docs/design.md sec. 1.13, "Precision of the fast kernel's forward").
 * - Objects shaded with their own precomputed transfer (docs/design.md sec. 1.15): their pixels
 *   leave each run before the kernel and are shaded, SH and lights, by transfer_shade.c; under
 *   the fast kernel their other spheres' sum F comes from it (one call per object of the run,
 *   after the run's other pixels) and is kept after the run's batches in the store
 *   (pen__tile_run_store). The runs stay as grouped. Ground pixels under such objects go to the
 *   ground's grid likewise.
 * - What the backward needs stays in the state: the groups, the kernel's store (F, or F and V,
 *   per pixel) and the lights' visibilities, kept only when the frame asks (a caller's state,
 *   shadows on).
 */
#include "core/internal.h"
#include "render/cpu/cpu.h"

#include <omp.h>
#include <string.h>

/* ---- Prepare --------------------------------------------------------------------------------- */

pen_status pen__cpu_prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                            pen_render_state *st) {
    const pen_sh_exp_model model = pen_sh_exp_model_default(sc->shadow.exp, sc->sh_bands);
    pen__shade_params_init(&st->params, sc->sh_bands, &model, (double)sc->shadow.epsilon,
                           opt->shadows);
    if (!st->params.gaunt)
        return pen__error(ctx, PEN_ERROR_INTERNAL, "render: no product table for %d bands",
                          sc->sh_bands);
    pen__lights_init(&st->lights, &sc->lighting, st->params.epsilon, opt->shadows);
    /* Under ground occlusion each object receives the part of each disk above its horizon
     * y > -t (ground.c), with the derivatives by its height, the light's direction and radius. */
    if (st->ground_occludes)
        for (int o = 0; o < sc->object_count; ++o) {
            pen__object_buf *b = &st->obj[o];
            for (int l = 0; l < st->lights.count; ++l) {
                double d_t;
                b->light_G[l] = pen__lights_horizon(&st->lights, l, b->ground_t, &d_t,
                                                    b->light_G_dw[l], &b->light_G_db[l]);
                b->light_G_dh[l] = d_t * b->ground_dt_dh;
            }
        }
    return PEN_OK;
}

/* ---- Shading --------------------------------------------------------------------------------- */

/* Sign that turns the interpolated normal towards the viewer's side of the triangle. */
static float facing_sign(const pen_render_state *st, const pen_object *ob, int o, size_t i) {
    const uint32_t *idx = ob->mesh.indices + 3 * (size_t)st->gb.triangle[i];
    const float *w = st->obj[o].world.data;
    const float *p0 = w + 3 * (size_t)idx[0], *p1 = w + 3 * (size_t)idx[1],
                *p2 = w + 3 * (size_t)idx[2];
    double e1[3], e2[3], g[3], v[3];
    for (int a = 0; a < 3; ++a) {
        e1[a] = (double)p1[a] - (double)p0[a];
        e2[a] = (double)p2[a] - (double)p0[a];
        v[a] = st->view.eye[a] - (double)st->x.data[3 * i + a];
    }
    g[0] = e1[1] * e2[2] - e1[2] * e2[1];
    g[1] = e1[2] * e2[0] - e1[0] * e2[2];
    g[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return g[0] * v[0] + g[1] * v[1] + g[2] * v[2] < 0.0 ? -1.0f : 1.0f;
}

/* Normal (facing the camera) and albedo of surface pixel i. */
static void surface_attributes(const pen_scene *sc, pen_render_state *st, size_t i, int surf) {
    float *n = st->n.data + 3 * i, *rho = st->rho.data + 3 * i;
    if (surf == PEN_SURFACE_GROUND) {
        n[0] = 0.0f, n[1] = 1.0f, n[2] = 0.0f;
        for (int ch = 0; ch < 3; ++ch)
            rho[ch] = sc->ground.albedo[ch];
        return;
    }
    const pen_object *ob = &sc->objects[surf];
    const float sign = facing_sign(st, ob, surf, i);
    st->nsign.data[i] = sign;
    pen_normalize_fwd(1, st->nraw.data + 3 * i, n);
    for (int a = 0; a < 3; ++a)
        n[a] *= sign;
    if (ob->texture.data)
        pen__render_texture_fwd(st, ob, i, rho);
    else
        for (int ch = 0; ch < 3; ++ch)
            rho[ch] = ob->albedo[ch];
}

/* The disk lights' horizon factors of group g's pixels (NULL: 1). */
static const double *group_horizon(const pen_render_state *st, int g) {
    const int o = pen__tile_group_object(st, g);
    return o >= 0 ? st->obj[o].light_G : NULL;
}

/* Adds the disk lights to the run's pixels (the scalar kernel's frame: the double per-pixel term;
 * the fast kernel's: the same term in lanes, pen__lights_fwd_block), over
 * the tile's ncull spheres ws->cull. */
static void shade_lights_fwd(pen_render_state *st, const pen__tile_ws *ws, int ncull, int g,
                             const int *pix, int cnt) {
    const double *G = group_horizon(st, g);
    for (int k0 = 0; k0 < cnt; k0 += PEN_LIGHTS_BLOCK) {
        const int nb = cnt - k0 < PEN_LIGHTS_BLOCK ? cnt - k0 : PEN_LIGHTS_BLOCK;
        if (st->fast) { /* the fast kernel's frame: the term in the variant's lanes */
            pen__lights_fwd_block(&st->lights, G, ncull, st->spheres.data, st->kappa.data, ws->cull,
                                  nb, st->x.data, st->n.data, st->rho.data, pix + k0,
                                  st->color.data, st->lights_V_valid ? st->lights_V.data : NULL);
            continue;
        }
        pen__lights_candidates(&st->lights, ncull, st->spheres.data, ws->cull, nb, st->x.data,
                               st->n.data, pix + k0, ws->cand, ws->ncand);
        for (int k = 0; k < nb; ++k) {
            const size_t i = (size_t)pix[k0 + k];
            float *V = st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL;
            pen__lights_fwd(&st->lights, G, ws->ncand[k], st->spheres.data, st->kappa.data,
                            ws->cand + (size_t)k * (size_t)ncull, st->x.data + 3 * i,
                            st->n.data + 3 * i, st->rho.data + 3 * i, st->color.data + 3 * i, V);
        }
    }
}

/* Shades tile t: background pixels directly, surface pixels through the fast kernel (compacted
 * into ws, one call per group) or the scalar kernel one by one, then the disk lights. */
static void shade_tile_fwd(const void *job_, int t, pen__tile_ws *ws, pen__shade_fast_ticks *tk) {
    const pen__tile_job *job = job_;
    const pen_scene *sc = job->sc;
    pen_render_state *st = job->st;
    float *store = pen__tile_store_of(job, t);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    int x0, y0, x1, y1;
    pen__tile_rect(st, t, &x0, &y0, &x1, &y1);
    for (int py = y0; py < y1; ++py)
        for (int px = x0; px < x1; ++px) {
            const size_t i = (size_t)py * (size_t)st->width + (size_t)px;
            const int surf = st->gb.surface[i];
            if (surf == PEN_SURFACE_BACKGROUND)
                pen__background_pixel(sc, st, px, py, i);
            else
                surface_attributes(sc, st, i, surf);
        }
    const int ncull = st->lights.count ? pen__tile_lights_cull(st, t, ws) : 0;
    for (int r = 0; r < st->groups.data[t].runs; ++r) {
        const int *pix;
        int cnt;
        const int g = pen__tile_run(st, t, r, &pix, &cnt);
        const float(*sh)[3] = pen__tile_group_lighting(sc, st, g);
        /* Pixels shaded with their object's own transfer (self.c) leave the run (under the fast
         * kernel collected in tr, shaded after the run's other pixels); the rest, nk of them, go
         * compacted into ws (their indices in ws->idx) to the kernel. */
        int nk = 0, ntr = 0, tr[PEN_TILE_PX];
        for (int k = 0; k < cnt; ++k) {
            const size_t i = (size_t)pix[k];
            if (pen__self_object(st, i) >= 0 && st->fast) {
                tr[ntr++] = (int)i;
                continue;
            }
            if (pen__self_object(st, i) >= 0) {
                float *fv = job->store ? job->store + nfv * i : NULL;
                float *V =
                    st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL;
                pen__self_shade_fwd(st, (const float(*)[3])sc->lighting.sh, ncull, ws->cull, i, fv,
                                    V);
                continue;
            }
            if (pen__ground_shadow_pixel(st, i)) { /* the ground's grid (ground_shadow.c) */
                pen__ground_shadow_fwd(
                    st, sh, ncull, ws->cull, i,
                    !st->fast && job->store ? job->store + nfv * i : NULL,
                    st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL);
                continue;
            }
            pen__tile_ws_push(ws, nk++, st, i);
        }
        if (!st->fast) {
            for (int k = 0; k < nk; ++k) {
                const size_t i = (size_t)ws->idx[k];
                pen__shade_fwd(&st->params, sh, st->sphere_count, st->spheres.data, st->kappa.data,
                               st->x.data + 3 * i, st->n.data + 3 * i, st->rho.data + 3 * i,
                               st->color.data + 3 * i, job->store ? job->store + nfv * i : NULL);
            }
            if (st->lights.count) shade_lights_fwd(st, ws, ncull, g, ws->idx, nk);
            continue;
        }
        pen__shade_fast_fwd(&st->params, sh, st->sphere_count, st->spheres.data, st->kappa.data, nk,
                            g == 0 ? nk : 0, ws->x, ws->n, ws->rho, ws->out, store, ws->kernel, tk);
        for (int k = 0; k < nk; ++k)
            memcpy(st->color.data + 3 * (size_t)ws->idx[k], ws->out + 3 * k, 3 * sizeof(float));
        if (st->lights.count) shade_lights_fwd(st, ws, ncull, g, ws->idx, nk);
        /* The transfer pixels (ws is free again), their F kept after the kernel's batches. */
        if (ntr)
            pen__self_shade_fast_fwd(
                st, (const float(*)[3])sc->lighting.sh, ncull, ws->cull, tr, ntr, ws,
                store ? store + pen__shade_fast_store_floats(&st->params, nk) : NULL, tk);
        if (store) store += pen__tile_run_store(st, cnt); /* the run's layout */
    }
}

pen_status pen__cpu_shade_fwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                              pen_render_state *st, int keep) {
    pen_status s;
    const int W = st->width, H = st->height;
    const int fast =
        opt->kernel == PEN_RENDER_KERNEL_FAST && pen__shade_fast_supported(&st->params);
    const int ntiles = pen__tile_count(st);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const int nt = pen__threads(ctx);
    size_t wsb = 0;
    if ((s = pen__tile_ws_reserve(ctx, st, nt, &wsb)) ||
        (s = PEN__BUF_RESERVE(ctx, st->groups, (size_t)ntiles, "tile pixel groups")))
        return s;
    /* Every tile's lighting groups, for the shading below, the store's layout and the backward. */
    const double t0 = omp_get_wtime();
    const pen__tile_job group_job = {sc, st, NULL, NULL, NULL};
    pen__tiles_run(st, nt, wsb, pen__tile_group, &group_job);
    /* Keep what the backward needs: the scalar kernel F and V per pixel (2 bands^2 floats:
     * 32 MB at 512 x 512, 4 bands), the fast kernel F per pixel in its batch layout. */
    float *fv_all = NULL;
    if (keep && opt->shadows) {
        if (fast && (s = pen__tile_store_layout(ctx, st, ntiles))) return s;
        const size_t need = fast ? st->tile_off.data[ntiles] : nfv * (size_t)W * (size_t)H;
        if ((s = PEN__BUF_RESERVE(ctx, st->fv, need, "visibility buffer"))) return s;
        fv_all = st->fv.data;
    }
    st->fv_valid = fv_all != NULL;
    /* The disk lights' visibilities per pixel, for the backward (K floats per pixel). */
    st->lights_V_valid = 0;
    if (keep && opt->shadows && st->lights.count > 0) {
        if ((s = PEN__BUF_RESERVE(ctx, st->lights_V,
                                  (size_t)st->lights.count * (size_t)W * (size_t)H,
                                  "light visibility buffer")))
            return s;
        st->lights_V_valid = 1;
    }
    st->fast = fast;
    const pen__tile_job job = {sc, st, NULL, fv_all, fast ? st->tile_off.data : NULL};
    const pen__loop_ticks lt = pen__tiles_run(st, nt, wsb, shade_tile_fwd, &job);
    const double ms = pen__render_ms_since(t0);
    st->timings.fwd_visibility_ms = pen__stage_ms(ms, lt.visibility, lt.total);
    st->timings.fwd_exp_ms = pen__stage_ms(ms, lt.exp, lt.total);
    return PEN_OK;
}
