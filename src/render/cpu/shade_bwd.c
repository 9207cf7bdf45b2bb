/* The CPU backend's backward (backend.h): from the pixels' colour gradient, per tile in
 * parallel, through the kernels' backwards into per-pixel gradients and per-tile accumulators,
 * and the accumulators' reduction into the gradient struct.
 *
 * Design
 * - The tiles and lighting groups are the forward's (tiles.c), so the fast kernel's store lines
 *   up with its batches. Each tile writes every one of its pixels' d_x, d_raw-normal, d_uv,
 *   d_footprint and d_rho (the frame's scatters read them) and adds the small dense gradients
 *   (lighting, constant albedos, ground albedo, world-space spheres, the disk lights) into its
 *   own row of double accumulators.
 * - Reduce: rows are summed in tile order, so gradients do not depend on the thread count; the
 *   objects' `seen` lightings and horizon factors are mapped back through ground.c, the lights'
 *   gradients through the normalisation of the stored direction, the world-space spheres into
 *   object space and the pose.
 */
#include "core/internal.h"
#include "render/cpu/cpu.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* Layout of the backward's double accumulators. A tile's row holds the dense part, [0, dense):
 * sh, the lighting gradient of pixels shaded with the scene's lighting, the ground's and the
 * objects' constant albedos, the world-space spheres, the lights; then, with ground occlusion,
 * one entry of `entry` doubles per object the tile shows (its runs' order): the gradient of its
 * `seen` lighting (3 bands^2) and of its horizon factors (one per light). Kept per object in every
 * tile, those took 3 bands^2 doubles per object and tile: 1.6 GB for 4096 objects at 512^2. The
 * reduction's sums lay the same dense part out first, then every object's `seen` (sh_obj) and
 * horizon factors (light_G), mapped back after it (ground.c); stride is their size. */
typedef struct row_layout {
    size_t sh, ground, albedo, spheres, lights, dense, entry, sh_obj, light_G, stride;
} row_layout;

/* Only the parts a request wants take room (albedos: `objects` of them, spheres, `lights` with
 * their own gradient); a lighting task over 4096 one-sphere objects kept 235 MB of zeros. The
 * entries' horizon factors are there for every light (the pose needs them without the lights'
 * own gradient). */
static row_layout rows_layout(int bands, int objects, int seen, int spheres, int lights,
                              int light_grads) {
    const size_t nsh = 3 * (size_t)bands * (size_t)bands;
    row_layout r;
    r.sh = 0;
    r.ground = r.sh + nsh;
    r.albedo = r.ground + 3;
    r.spheres = r.albedo + 3 * (size_t)objects;
    r.lights = r.spheres + 4 * (size_t)spheres; /* PEN_LIGHT_GRAD_DOUBLES per light */
    r.dense = r.lights + PEN_LIGHT_GRAD_DOUBLES * (size_t)light_grads;
    r.entry = seen ? nsh + (size_t)lights : 0;
    r.sh_obj = r.dense;
    r.light_G = r.sh_obj + nsh * (size_t)seen; /* per `seen` object, light */
    r.stride = r.light_G + (size_t)seen * (size_t)lights;
    return r;
}

/* The runs of tile t shaded with an object's own `seen` lighting (one per object it shows). */
static int tile_entries(const pen_render_state *st, int t) {
    int e = 0;
    for (int r = 0; r < st->groups.data[t].runs; ++r) {
        const int *pix;
        int cnt;
        e += pen__tile_group_object(st, pen__tile_run(st, t, r, &pix, &cnt)) >= 0;
    }
    return e;
}

/* What the backward computes (the request a pen__tile_job carries to shade_tile_bwd). */
typedef struct pen__bwd_want {
    int geom, spheres, light, albedo;
    int seen; /* the gradient of each object's `seen` lighting (for the lighting or the pose) */
    row_layout rl;
    int lights;  /* the disk lights' own gradient */
    int light_G; /* the gradient of the objects' horizon factors (for the lights or the pose) */
    int height;  /* the objects' heights through ground occlusion (the pose) */
} bwd_want;

/* After the kernel's backward of surface pixel i: its albedo gradient into the tile's sums (ground,
 * constant albedo) or through the texture lookup to uv, and d_n through the facing sign and the
 * normalisation to the raw normal. d_rho is st->d_rho of the pixel. */
static void pixel_bwd_tail(const pen_scene *sc, pen_render_state *st, const bwd_want *bw,
                           double *row, size_t i, int surf, float d_n[3]) {
    const float *d_rho = st->d_rho.data + 3 * i;
    if (surf < 0) {
        if (bw->albedo)
            for (int ch = 0; ch < 3; ++ch)
                row[bw->rl.ground + ch] += (double)d_rho[ch];
        return;
    }
    const pen_object *ob = &sc->objects[surf];
    if (!ob->texture.data && bw->albedo)
        for (int ch = 0; ch < 3; ++ch)
            row[bw->rl.albedo + 3 * (size_t)surf + ch] += (double)d_rho[ch];
    if (!bw->geom) return;
    if (ob->texture.data)
        pen__render_texture_bwd(st, ob, i, d_rho, NULL, st->d_uv.data + 2 * i,
                                st->d_uvj.data + 4 * i);
    const float sign = st->nsign.data[i];
    for (int a = 0; a < 3; ++a)
        d_n[a] *= sign;
    pen_normalize_bwd(1, st->nraw.data + 3 * i, d_n, st->d_nraw.data + 3 * i);
}

/* The disk lights' visibilities the forward kept for pixel i, or NULL. */
static const float *lights_V(const pen_render_state *st, size_t i) {
    return st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL;
}

/* Where the fast forward kept the F of the run's transfer pixels (after the kernel's batches of
 * the run's other pixels, pen__tile_run_store), or NULL (the scalar kernel's frame, no store). */
static const float *self_F(const pen_render_state *st, const float *store, const int *pix,
                           int cnt) {
    if (!st->fast || !store || !st->self_any) return NULL;
    int nk = 0; /* the kernel's pixels of the run, as the forward counted them */
    for (int k = 0; k < cnt; ++k) {
        const size_t i = (size_t)pix[k];
        nk += !pen__ground_shadow_pixel(st, i) && pen__self_object(st, i) < 0;
    }
    return store + pen__shade_fast_store_floats(&st->params, nk);
}

/* Backward of tile t into the tile's double accumulators and the per-pixel gradients d_x,
 * d_nraw, d_uv, d_rho (zeroed here for every pixel of the tile), in the forward's groups. */
static void shade_tile_bwd(const void *job_, int t, pen__tile_ws *ws, pen__shade_fast_ticks *tk) {
    const pen__tile_job *job = job_;
    const pen_scene *sc = job->sc;
    pen_render_state *st = job->st;
    const bwd_want *bw = job->bw;
    const float *store = pen__tile_store_of(job, t);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const size_t nsh = 3 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const int S = st->sphere_count;
    double *row = st->rows.data + st->row_off.data[t], *entry = row + bw->rl.dense;
    double *d_sph = bw->spheres ? row + bw->rl.spheres : NULL;
    int x0, y0, x1, y1;
    pen__tile_rect(st, t, &x0, &y0, &x1, &y1);
    for (int py = y0; py < y1; ++py)
        for (int px = x0; px < x1; ++px) {
            const size_t i = (size_t)py * (size_t)st->width + (size_t)px;
            float *d_x = st->d_x.data + 3 * i, *d_rho = st->d_rho.data + 3 * i;
            float *d_nraw = st->d_nraw.data + 3 * i, *d_uv = st->d_uv.data + 2 * i;
            for (int a = 0; a < 3; ++a)
                d_x[a] = d_nraw[a] = d_rho[a] = 0.0f;
            d_uv[0] = d_uv[1] = 0.0f;
            if (bw->geom) memset(st->d_uvj.data + 4 * i, 0, 4 * sizeof(float));
        }
    const int ncull = st->lights.count ? pen__tile_lights_cull(st, t, ws) : 0;
    for (int r = 0; r < st->groups.data[t].runs; ++r) {
        const int *pix;
        int cnt;
        const int g = pen__tile_run(st, t, r, &pix, &cnt);
        const float(*sh)[3] = pen__tile_group_lighting(sc, st, g);
        /* where this group's lighting gradient goes: an object's own `seen`, or the lighting */
        const int own = pen__tile_group_object(st, g);
        double *own_entry = own >= 0 ? entry : NULL; /* the tile's next object entry */
        if (own >= 0) entry += bw->rl.entry;
        double(*d_sh)[3] = own >= 0 ? (bw->seen ? (double(*)[3])own_entry : NULL)
                                    : (bw->light ? (double(*)[3])(row + bw->rl.sh) : NULL);
        /* the disk lights: their horizon factors (objects with ground occlusion) and gradients */
        const double *G = own >= 0 ? st->obj[own].light_G : NULL;
        double *d_G = own >= 0 && bw->light_G ? own_entry + nsh : NULL;
        double *d_lights = bw->lights ? row + bw->rl.lights : NULL;
        /* Pixels shaded with their object's own transfer (self.c), as the forward split them;
         * the rest, nk of them, compacted into ws (ws->idx) for the kernel. */
        const float *Ftr = self_F(st, store, pix, cnt);
        const size_t nc = (size_t)sc->sh_bands * (size_t)sc->sh_bands;
        int nk = 0, ntr = 0;
        for (int k = 0; k < cnt; ++k) {
            const size_t i = (size_t)pix[k];
            const int grid = pen__ground_shadow_pixel(st, i);
            if (!grid && pen__self_object(st, i) < 0) {
                ws->idx[nk++] = (int)i;
                continue;
            }
            /* the fast forward's F of the run's ntr-th transfer pixel (pen__tile_run_store) */
            const int itr = grid ? -1 : ntr++;
            const float *dc = st->d_color.data + 3 * i;
            if (dc[0] == 0.0f && dc[1] == 0.0f && dc[2] == 0.0f) continue;
            if (grid) { /* the ground's grid (ground_shadow.c): the ground's group, d_sh */
                pen__ground_shadow_bwd(st, sh, ncull, ws->cull, i, dc,
                                       !st->fast && job->store ? job->store + nfv * i : NULL,
                                       lights_V(st, i), d_sh, d_sph,
                                       bw->albedo ? st->d_rho.data + 3 * i : NULL, d_lights);
                pixel_bwd_tail(sc, st, bw, row, i, PEN_SURFACE_GROUND, NULL);
                continue;
            }
            const int surf = st->gb.surface[i];
            const int geom = bw->geom;
            const int need_rho = bw->albedo || (geom && sc->objects[surf].texture.data != NULL);
            float d_n[3] = {0.0f, 0.0f, 0.0f};
            /* the scene's own lighting: the traced ground replaces the object's `seen` */
            pen__self_shade_bwd(st, (const float(*)[3])sc->lighting.sh, ncull, ws->cull, i, dc,
                                !st->fast && job->store ? job->store + nfv * i : NULL,
                                Ftr ? Ftr + nc * (size_t)itr : NULL, lights_V(st, i),
                                bw->light ? (double(*)[3])(row + bw->rl.sh) : NULL, d_sph,
                                geom ? st->d_x.data + 3 * i : NULL, geom ? d_n : NULL,
                                need_rho ? st->d_rho.data + 3 * i : NULL, d_lights);
            pixel_bwd_tail(sc, st, bw, row, i, surf, d_n);
        }
        if (!st->fast) {
            for (int k = 0; k < nk; ++k) {
                const size_t i = (size_t)ws->idx[k];
                const int surf = st->gb.surface[i];
                const float *dc = st->d_color.data + 3 * i;
                if (dc[0] == 0.0f && dc[1] == 0.0f && dc[2] == 0.0f) continue;
                const int geom = surf >= 0 && bw->geom;
                const int need_rho = bw->albedo || (geom && sc->objects[surf].texture.data != NULL);
                float d_n[3] = {0.0f, 0.0f, 0.0f};
                pen__shade_bwd(&st->params, sh, S, st->spheres.data, st->kappa.data,
                               st->x.data + 3 * i, st->n.data + 3 * i, st->rho.data + 3 * i, dc,
                               job->store ? job->store + nfv * i : NULL, d_sh, d_sph,
                               geom ? st->d_x.data + 3 * i : NULL, geom ? d_n : NULL,
                               need_rho ? st->d_rho.data + 3 * i : NULL);
                if (st->lights.count)
                    pen__lights_bwd(&st->lights, G, ncull, st->spheres.data, st->kappa.data,
                                    ws->cull, st->x.data + 3 * i, st->n.data + 3 * i,
                                    st->rho.data + 3 * i, dc, lights_V(st, i), d_sph,
                                    geom ? st->d_x.data + 3 * i : NULL, geom ? d_n : NULL,
                                    need_rho ? st->d_rho.data + 3 * i : NULL, d_lights, d_G);
                pixel_bwd_tail(sc, st, bw, row, i, surf, d_n);
            }
            continue;
        }
        for (int k = 0; k < nk; ++k) {
            const size_t i = (size_t)ws->idx[k];
            memcpy(ws->out + 3 * k, st->d_color.data + 3 * i, 3 * sizeof(float));
            pen__tile_ws_push(ws, k, st, i);
        }
        memset(ws->dx, 0, 3 * sizeof(float) * (size_t)nk);
        memset(ws->dn, 0, 3 * sizeof(float) * (size_t)nk);
        memset(ws->drho, 0, 3 * sizeof(float) * (size_t)nk);
        pen__shade_fast_bwd(&st->params, sh, S, st->spheres.data, st->kappa.data, nk,
                            g == 0 ? nk : 0, ws->x, ws->n, ws->rho, ws->out, store, ws->kernel,
                            d_sh, d_sph, bw->geom ? ws->dx : NULL, bw->geom ? ws->dn : NULL,
                            ws->drho, tk);
        if (store) store += pen__tile_run_store(st, cnt); /* the run's layout */
        for (int k0 = 0; st->lights.count && k0 < nk; k0 += PEN_LIGHTS_BLOCK) {
            const int nb = nk - k0 < PEN_LIGHTS_BLOCK ? nk - k0 : PEN_LIGHTS_BLOCK;
            const int geom = g != 0 && bw->geom; /* ground pixels: no d_x, d_n wanted */
            /* the disk lights in the kernel's lanes (lights_fast.c), as the forward added them */
            pen__lights_bwd_block(&st->lights, G, ncull, st->spheres.data, st->kappa.data,
                                  ws->cull, nb, ws->x + 3 * k0, ws->n + 3 * k0, ws->rho + 3 * k0,
                                  st->d_color.data, st->lights_V_valid ? st->lights_V.data : NULL,
                                  ws->idx + k0, ws->cand, d_sph, geom ? ws->dx + 3 * k0 : NULL,
                                  geom ? ws->dn + 3 * k0 : NULL, ws->drho + 3 * k0, d_lights, d_G);
        }
        for (int k = 0; k < nk; ++k) {
            const size_t i = (size_t)ws->idx[k];
            const int surf = st->gb.surface[i];
            const int geom = surf >= 0 && bw->geom;
            if (bw->albedo || (geom && sc->objects[surf].texture.data))
                memcpy(st->d_rho.data + 3 * i, ws->drho + 3 * k, 3 * sizeof(float));
            if (geom) memcpy(st->d_x.data + 3 * i, ws->dx + 3 * k, 3 * sizeof(float));
            pixel_bwd_tail(sc, st, bw, row, i, surf, ws->dn + 3 * k);
        }
    }
}

/* What a backward of `wrt` computes on this frame. */
static bwd_want request(const pen_scene *sc, const pen_render_state *st, unsigned wrt) {
    const int O = sc->object_count, K = st->lights.count;
    const int seen = st->ground_occludes ? O : 0;
    const int want_light = (wrt & PEN_GRAD_LIGHTING) != 0;
    const int want_lights = (wrt & (PEN_GRAD_LIGHTS | PEN_GRAD_LIGHT_IRRADIANCE)) != 0 && K > 0;
    const int want_height = (wrt & PEN_GRAD_POSE) != 0 && st->ground_occludes;
    const int want_spheres = (wrt & (PEN_GRAD_SPHERES | PEN_GRAD_POSE)) != 0;
    const int want_albedo = (wrt & PEN_GRAD_ALBEDO) != 0;
    const int want_seen = seen > 0 && (want_light || want_height);
    const int want_G = seen > 0 && K > 0 && (want_lights || want_height);
    const bwd_want bw = {(wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) != 0,
                         want_spheres,
                         want_light,
                         want_albedo,
                         want_seen,
                         rows_layout(sc->sh_bands, want_albedo ? O : 0,
                                     want_seen || want_G ? seen : 0,
                                     want_spheres ? st->sphere_count : 0, K, want_lights ? K : 0),
                         want_lights,
                         want_G,
                         want_height};
    return bw;
}

pen_status pen__cpu_shade_bwd(pen_context *ctx, const pen_scene *sc, pen_render_state *st,
                              unsigned wrt) {
    pen_status s;
    const bwd_want bw = request(sc, st, wrt);
    const size_t np = (size_t)st->width * (size_t)st->height;
    const int ntiles = pen__tile_count(st);
    if ((s = PEN__BUF_RESERVE(ctx, st->row_off, (size_t)ntiles + 1, "tile gradient layout")))
        return s;
    size_t *off = st->row_off.data;
    off[0] = 0;
    for (int t = 0; t < ntiles; ++t)
        off[t + 1] = off[t] + bw.rl.dense + (bw.rl.entry ? bw.rl.entry * tile_entries(st, t) : 0);
    if ((s = PEN__BUF_RESERVE(ctx, st->rows, off[ntiles] + 1, "tile gradient buffers")) ||
        (bw.geom && (s = PEN__BUF_RESERVE(ctx, st->d_uvj, 4 * np, "footprint gradient"))))
        return s;
    memset(st->rows.data, 0, sizeof(double) * off[ntiles]);
    const int nt = pen__threads(ctx);
    size_t wsb = 0;
    if ((s = pen__tile_ws_reserve(ctx, st, nt, &wsb))) return s;
    float *fv_all = st->fv_valid ? st->fv.data : NULL;
    const pen__tile_job job = {sc, st, &bw, fv_all, st->fast ? st->tile_off.data : NULL};
    const double t0 = omp_get_wtime();
    const pen__loop_ticks lt = pen__tiles_run(st, nt, wsb, shade_tile_bwd, &job);
    const double ms = pen__render_ms_since(t0);
    st->timings.bwd_visibility_ms = pen__stage_ms(ms, lt.visibility, lt.total);
    st->timings.bwd_exp_ms = pen__stage_ms(ms, lt.exp, lt.total);
    return PEN_OK;
}

pen_status pen__cpu_reduce(pen_context *ctx, const pen_scene *sc, pen_render_state *st,
                           unsigned wrt, pen_render_grad *grad) {
    const bwd_want bw = request(sc, st, wrt);
    const int O = sc->object_count, nc = sc->sh_bands * sc->sh_bands, K = st->lights.count;
    const int ntiles = pen__tile_count(st);
    const int geometry = (wrt & PEN_GRAD_LIGHTS) != 0; /* the lights' direction and radius */
    /* Reduce the tiles in order. */
    double *sum = pen__calloc(ctx, bw.rl.stride + 1, sizeof(double), "gradient sums");
    if (!sum) return PEN_ERROR_MEMORY;
    const size_t nsh = 3 * (size_t)nc;
    for (int t = 0; t < ntiles; ++t) {
        const double *row = st->rows.data + st->row_off.data[t];
        for (size_t k = 0; k < bw.rl.dense; ++k)
            sum[k] += row[k];
        /* each object the tile shows, in its runs' order: its `seen` and horizon factors */
        const double *entry = row + bw.rl.dense;
        for (int r = 0; bw.rl.entry && r < st->groups.data[t].runs; ++r) {
            const int *pix;
            int cnt;
            const int o = pen__tile_group_object(st, pen__tile_run(st, t, r, &pix, &cnt));
            if (o < 0) continue;
            double *so = sum + bw.rl.sh_obj + nsh * (size_t)o, *go = sum + bw.rl.light_G;
            for (size_t k = 0; k < nsh; ++k)
                so[k] += entry[k];
            for (int l = 0; l < K; ++l)
                go[(size_t)o * (size_t)K + (size_t)l] += entry[nsh + (size_t)l];
            entry += bw.rl.entry;
        }
    }
    /* Lighting: the scene's own, plus what reaches it through the objects' `seen` (ground.c,
     * which also gives the objects' heights their share). */
    double d_sh[PEN_SH_MAX_COEFFS][3];
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch)
            d_sh[k][ch] = sum[bw.rl.sh + 3 * (size_t)k + ch];
    pen__ground_occlusion_bwd(sc, st, sum + bw.rl.sh_obj, bw.light ? d_sh : NULL,
                              bw.height ? grad : NULL);
    if (bw.light)
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch)
                grad->sh[k][ch] += (float)d_sh[k][ch];
    /* Disk lights: the pixels' share and the horizon factors' (ground.c), then through the
     * normalisation of the stored direction and degrees. */
    if (bw.light_G)
        pen__ground_lights_bwd(sc, st, sum + bw.rl.light_G, bw.lights ? sum + bw.rl.lights : NULL,
                               bw.height ? grad : NULL);
    if (bw.lights)
        for (int l = 0; l < K; ++l) {
            const double *dl = sum + bw.rl.lights + PEN_LIGHT_GRAD_DOUBLES * (size_t)l;
            const double *w = st->lights.w[l];
            const double wd = w[0] * dl[0] + w[1] * dl[1] + w[2] * dl[2];
            pen_light_grad *lg = &grad->lights[l];
            for (int a = 0; a < 3; ++a)
                lg->irradiance[a] += (float)dl[4 + a];
            if (!geometry) continue;
            for (int a = 0; a < 3; ++a)
                lg->direction[a] += (float)((dl[a] - w[a] * wd) / st->lights.len[l]);
            lg->angular_radius_deg += (float)(dl[3] * (PEN_PI / 180.0));
        }
    if (bw.albedo) {
        for (int ch = 0; ch < 3; ++ch)
            grad->ground_albedo[ch] += (float)sum[bw.rl.ground + ch];
        for (int o = 0; o < O; ++o)
            for (int ch = 0; ch < 3; ++ch)
                grad->objects[o].albedo[ch] += (float)sum[bw.rl.albedo + 3 * (size_t)o + ch];
    }

    /* Spheres: world-space gradients -> object space and pose. */
    if (bw.spheres)
        for (int o = 0; o < O; ++o) {
            const pen_object *ob = &sc->objects[o];
            pen_object_grad *og = &grad->objects[o];
            for (int i = 0; i < ob->spheres.count; ++i) {
                const double *dw = sum + bw.rl.spheres + 4 * (size_t)(st->sphere_first[o] + i);
                const float *c = ob->spheres.data + 4 * (size_t)i;
                const float d_c[3] = {(float)dw[0], (float)dw[1], (float)dw[2]};
                float d_co[3] = {0.0f, 0.0f, 0.0f};
                pen_pose_apply_bwd(&ob->pose, c, d_c, (wrt & PEN_GRAD_POSE) ? &og->pose : NULL,
                                   d_co);
                if (wrt & PEN_GRAD_SPHERES) {
                    for (int a = 0; a < 3; ++a)
                        og->spheres[4 * (size_t)i + a] += d_co[a];
                    og->spheres[4 * (size_t)i + 3] += (float)(dw[3] * (double)ob->pose.scale);
                }
                if (wrt & PEN_GRAD_POSE) og->pose.scale += (float)(dw[3] * (double)c[3]);
            }
        }
    free(sum);
    return PEN_OK;
}
