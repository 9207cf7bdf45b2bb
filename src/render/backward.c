/* The backward of the full differentiable frame (forward.c): from the image's gradient into the
 * lighting, the disk lights, albedos and texels, spheres, poses and vertex positions; and the
 * gradient struct.
 *
 * Design
 * - Antialiasing backward gives d_colour (and silhouette vertex gradients); a parallel pass over
 *   the forward's tiles and lighting groups (tiles.c) runs the kernel's backward, writing per-pixel
 *   d_x, d_raw-normal, d_uv, d_rho, and per-tile double buffers for the small dense gradients
 *   (lighting, constant albedos, ground albedo, world-space spheres). Tiles are reduced in order,
 *   so the result does not depend on the thread count. Then the texel scatter (in pixel order)
 *   beside the per-object interpolation and vertex-normal backward (two threads, disjoint
 *   outputs), the barycentric backward (the pixel's point slides on its ray as the triangle
 *   moves), and the pose backward, which splits world-space gradients of vertices and spheres
 *   into object-space and pose parts.
 * - Gradients are added into the caller's pen_render_grad (so several losses accumulate); only
 *   the groups asked for in `wrt` are computed.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "render/render_internal.h"
#include "raster/raster_internal.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* ---- Gradient struct ------------------------------------------------------------------------- */

pen_status pen_render_grad_create(pen_context *ctx, const pen_scene *sc, pen_render_grad *out) {
    memset(out, 0, sizeof *out);
    out->bands = sc->sh_bands;
    out->light_count = sc->lighting.light_count;
    if (sc->object_count <= 0) return PEN_OK;
    out->objects =
        pen__calloc(ctx, (size_t)sc->object_count, sizeof *out->objects, "gradient objects");
    if (!out->objects) return PEN_ERROR_MEMORY;
    out->object_count = sc->object_count;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen_object_grad *g = &out->objects[o];
        g->vertex_count = ob->mesh.vertex_count > 0 ? ob->mesh.vertex_count : 0;
        g->sphere_count = ob->spheres.count > 0 ? ob->spheres.count : 0;
        g->positions =
            pen__calloc(ctx, 3 * (size_t)g->vertex_count + 1, sizeof(float), "vertex gradient");
        g->spheres =
            pen__calloc(ctx, 4 * (size_t)g->sphere_count + 1, sizeof(float), "sphere gradient");
        if (!g->positions || !g->spheres) goto fail;
        if (ob->texture.data) {
            g->texel_count = ob->texture.width * ob->texture.height;
            g->texture =
                pen__calloc(ctx, (size_t)g->texel_count,
                            sizeof(float) * (size_t)ob->texture.channels, "texture gradient");
            if (!g->texture) goto fail;
        }
    }
    return PEN_OK;
fail:
    pen_render_grad_free(out);
    return PEN_ERROR_MEMORY;
}

void pen_render_grad_zero(pen_render_grad *g) {
    memset(g->sh, 0, sizeof g->sh);
    memset(g->ground_albedo, 0, sizeof g->ground_albedo);
    memset(g->lights, 0, sizeof g->lights);
    for (int o = 0; o < g->object_count; ++o) {
        pen_object_grad *og = &g->objects[o];
        memset(og->albedo, 0, sizeof og->albedo);
        memset(&og->pose, 0, sizeof og->pose);
        memset(og->positions, 0, sizeof(float) * 3 * (size_t)og->vertex_count);
        memset(og->spheres, 0, sizeof(float) * 4 * (size_t)og->sphere_count);
        if (og->texture) memset(og->texture, 0, sizeof(float) * 3 * (size_t)og->texel_count);
    }
}

void pen_render_grad_free(pen_render_grad *g) {
    if (!g) return;
    for (int o = 0; o < g->object_count; ++o) {
        free(g->objects[o].positions);
        free(g->objects[o].spheres);
        free(g->objects[o].texture);
    }
    free(g->objects);
    memset(g, 0, sizeof *g);
}

/* ---- Backward -------------------------------------------------------------------------------- */

/* Layout of one tile's double accumulators (the backward's small dense gradients). */
typedef struct row_layout {
    size_t sh, sh_obj, ground, albedo, spheres, lights, light_G, stride;
} row_layout;

/* sh: the lighting gradient of pixels shaded with the scene's lighting; sh_obj (with ground
 * occlusion, `seen` objects, else none): per object, of its pixels shaded with its `seen`, mapped
 * back after the reduction. */
static row_layout rows_layout(int bands, int objects, int seen, int spheres, int lights) {
    row_layout r;
    r.sh = 0;
    r.sh_obj = r.sh + 3 * (size_t)bands * (size_t)bands;
    r.ground = r.sh_obj + 3 * (size_t)bands * (size_t)bands * (size_t)seen;
    r.albedo = r.ground + 3;
    r.spheres = r.albedo + 3 * (size_t)objects;
    r.lights = r.spheres + 4 * (size_t)spheres;            /* PEN_LIGHT_GRAD_DOUBLES per light */
    r.light_G = r.lights + PEN_LIGHT_GRAD_DOUBLES * (size_t)lights; /* per `seen` object, light */
    r.stride = r.light_G + (size_t)seen * (size_t)lights;
    return r;
}

/* What the backward computes (the request a pen__tile_job carries to shade_tile_bwd). */
typedef struct pen__bwd_want {
    int geom, spheres, light, albedo;
    int seen; /* the gradient of each object's `seen` lighting (for the lighting or the pose) */
    row_layout rl;
    int lights;  /* the disk lights' own gradient */
    int light_G; /* the gradient of the objects' horizon factors (for the lights or the pose) */
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
    double *row = st->rows.data + bw->rl.stride * (size_t)t;
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
        double(*d_sh)[3] =
            own >= 0 ? (bw->seen ? (double(*)[3])(row + bw->rl.sh_obj + nsh * (size_t)own) : NULL)
                     : (bw->light ? (double(*)[3])(row + bw->rl.sh) : NULL);
        /* the disk lights: their horizon factors (objects with ground occlusion) and gradients */
        const double *G = own >= 0 ? st->obj[own].light_G : NULL;
        double *d_G = own >= 0 && bw->light_G
                          ? row + bw->rl.light_G + (size_t)own * (size_t)st->lights.count
                          : NULL;
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
                                    st->rho.data + 3 * i, dc, lights_V(st, i), d_sph, geom ? st->d_x.data + 3 * i : NULL,
                                    geom ? d_n : NULL, need_rho ? st->d_rho.data + 3 * i : NULL,
                                    d_lights, d_G);
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
            pen__lights_candidates(&st->lights, ncull, st->spheres.data, ws->cull, nb,
                                   ws->x + 3 * k0, ws->n + 3 * k0, NULL, ws->cand, ws->ncand);
            for (int kb = 0; kb < nb; ++kb) {
                const int k = k0 + kb;
                const size_t i = (size_t)ws->idx[k];
                const int geom = g != 0 && bw->geom; /* ground pixels: no d_x, d_n wanted */
                pen__lights_bwd(&st->lights, G, ws->ncand[kb], st->spheres.data, st->kappa.data,
                                ws->cand + (size_t)kb * (size_t)ncull, ws->x + 3 * k,
                                ws->n + 3 * k, ws->rho + 3 * k, st->d_color.data + 3 * i,
                                lights_V(st, i), d_sph, geom ? ws->dx + 3 * k : NULL,
                                geom ? ws->dn + 3 * k : NULL, ws->drho + 3 * k, d_lights, d_G);
            }
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

static pen_status check_grad_shape(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_grad *g) {
    if (g->object_count != sc->object_count || g->bands != sc->sh_bands ||
        g->light_count != sc->lighting.light_count)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: gradient struct does not match the scene");
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object_grad *og = &g->objects[o];
        const pen_object *ob = &sc->objects[o];
        if (og->vertex_count != ob->mesh.vertex_count || og->sphere_count != ob->spheres.count ||
            (!ob->texture.data != !og->texture) ||
            (ob->texture.data && og->texel_count != ob->texture.width * ob->texture.height))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "render backward: gradient of objects[%d] does not match the scene",
                              o);
    }
    return PEN_OK;
}

/* ---- The model a gradient needs -------------------------------------------------------------- */

/* The groups the ray-traced transfer (self.c, ground_shadow.c) holds constant. */
#define TRANSFER_CONSTANT (PEN_GRAD_POSE | PEN_GRAD_VERTICES | PEN_GRAD_SPHERES | PEN_GRAD_LIGHTS)

unsigned pen_render_grad_exact(const pen_scene *sc, const pen_render_options *opt) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    for (int o = 0; sc && o < sc->object_count; ++o)
        if (pen__self_transfer_on(sc, opt, o)) return PEN_GRAD_ALL & ~TRANSFER_CONSTANT;
    return PEN_GRAD_ALL;
}

static const char *group_name(unsigned bit) {
    switch (bit) {
    case PEN_GRAD_LIGHTING: return "lighting";
    case PEN_GRAD_ALBEDO: return "albedo";
    case PEN_GRAD_SPHERES: return "sphere";
    case PEN_GRAD_POSE: return "pose";
    case PEN_GRAD_VERTICES: return "vertex";
    case PEN_GRAD_LIGHTS: return "disk-light";
    case PEN_GRAD_LIGHT_IRRADIANCE: return "disk-light irradiance";
    default: return "unknown";
    }
}

pen_status pen_render_grad_check(pen_context *ctx, const pen_scene *sc,
                                 const pen_render_options *opt, unsigned wrt) {
    if (!sc) return pen__error(ctx, PEN_ERROR_ARGUMENT, "render backward: no scene");
    if (wrt & ~PEN_GRAD_ALL)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render backward: unknown gradient bits 0x%x",
                          wrt & ~PEN_GRAD_ALL);
    const unsigned missing = wrt & ~pen_render_grad_exact(sc, opt);
    if (!missing) return PEN_OK;
    const unsigned bit = missing & (~missing + 1u); /* the lowest group asked for and refused */
    return pen__error(ctx, PEN_ERROR_ARGUMENT,
                      "render backward: no %s gradient under \"shadow\": {\"self\": "
                      "\"transfer\"} (the objects' own and ground shadows are ray traced, constant "
                      "in pose, vertices, spheres and light directions); render with \"self\": "
                      "\"spheres\" for it (pen_render_grad_model; gradient_model in Python)",
                      group_name(bit));
}

unsigned pen_render_grad_model(pen_scene *sc, unsigned wrt) {
    unsigned changed = 0;
    if (!sc) return 0;
    if ((wrt & TRANSFER_CONSTANT) &&
        (sc->shadow.self != PEN_SELF_SPHERES ||
         sc->shadow.ground_shadow != PEN_GROUND_SHADOW_SPHERES)) {
        sc->shadow.self = PEN_SELF_SPHERES;
        sc->shadow.ground_shadow = PEN_GROUND_SHADOW_SPHERES;
        changed |= wrt & TRANSFER_CONSTANT;
    }
    /* Point lookups are continuous in the geometry; the footprint steps between facets. */
    for (int o = 0; (wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) && o < sc->object_count; ++o) {
        pen_object *ob = &sc->objects[o];
        if (!ob->texture.data || ob->texture_filter == PEN_TEXTURE_FILTER_POINT) continue;
        ob->texture_filter = PEN_TEXTURE_FILTER_POINT;
        changed |= wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES);
    }
    return changed;
}

/* The geometry's serial scatter: the interpolations' backward into the vertices and barycentrics,
 * the footprints' into the vertices, the vertex normals'. */
static pen_status geometry_scatter(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    pen_status s = PEN_OK;
    for (int o = 0; o < sc->object_count && !s; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen__object_buf *b = &st->obj[o];
        pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->world.data, 3, st->d_x.data,
                            b->d_world.data, st->d_bary.data);
        pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->vnormal.data, 3, st->d_nraw.data,
                            b->d_vnormal.data, st->d_bary.data);
        if (ob->texture.data) {
            pen_interpolate_bwd(&st->gb, o, ob->mesh.uv_indices, ob->mesh.uvs, 2, st->d_uv.data,
                                NULL, st->d_bary.data);
            if (pen__render_footprint(ob)) pen__uv_footprint_bwd(st, ob, o, b->d_world.data);
        }
        s = pen_vertex_normals_bwd(ctx, ob->mesh.vertex_count, b->world.data,
                                   ob->mesh.triangle_count, ob->mesh.indices, b->d_vnormal.data,
                                   b->d_world.data);
    }
    return s;
}

pen_status pen_render_bwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st, const pen_image *d_image, unsigned wrt,
                          pen_render_grad *grad) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    if (!st || !st->valid)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render backward: no forward pass to undo");
    if (opt->shadows != st->opt.shadows || opt->antialias != st->opt.antialias ||
        opt->kernel != st->opt.kernel)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: options differ from the forward pass");
    pen_status s = pen_render_grad_check(ctx, sc, opt, wrt);
    if (s) return s;
    const int W = st->width, H = st->height;
    if (!d_image || !d_image->data || d_image->width != W || d_image->height != H ||
        d_image->channels != 3)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: d_image must be %dx%d with 3 channels", W, H);
    int changed = st->object_count != sc->object_count;
    for (int o = 0; o < sc->object_count && !changed; ++o)
        changed = st->meshes[o].vertex_count != sc->objects[o].mesh.vertex_count ||
                  st->meshes[o].triangle_count != sc->objects[o].mesh.triangle_count ||
                  st->sphere_first[o + 1] - st->sphere_first[o] != sc->objects[o].spheres.count ||
                  st->obj[o].self_on != pen__self_transfer_on(sc, opt, o);
    if (changed)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: the scene changed since the forward pass");
    if ((s = check_grad_shape(ctx, sc, grad))) return s;
    const size_t np = (size_t)W * (size_t)H;
    const int O = sc->object_count, S = st->sphere_count, nc = sc->sh_bands * sc->sh_bands;
    const int want_geom = (wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) != 0;
    const int want_sph = (wrt & (PEN_GRAD_SPHERES | PEN_GRAD_POSE)) != 0;
    const int want_light = (wrt & PEN_GRAD_LIGHTING) != 0;
    const int want_albedo = (wrt & PEN_GRAD_ALBEDO) != 0;
    const int want_lights =
        (wrt & (PEN_GRAD_LIGHTS | PEN_GRAD_LIGHT_IRRADIANCE)) != 0 && st->lights.count > 0;
    const int want_light_geometry = (wrt & PEN_GRAD_LIGHTS) != 0; /* direction and radius */
    const int K = st->lights.count;

    /* World-space vertex gradient buffers. */
    float **d_world = NULL;
    if (want_geom) {
        d_world = pen__calloc(ctx, (size_t)O + 1, sizeof *d_world, "vertex gradient pointers");
        if (!d_world) return PEN_ERROR_MEMORY;
        for (int o = 0; o < O; ++o) {
            pen__object_buf *b = &st->obj[o];
            const size_t V = (size_t)sc->objects[o].mesh.vertex_count;
            memset(b->d_world.data, 0, sizeof(float) * 3 * V);
            memset(b->d_vnormal.data, 0, sizeof(float) * 3 * V);
            d_world[o] = b->d_world.data;
        }
    }

    pen_render_timings *tm = &st->timings;
    tm->bwd_antialias_ms = tm->bwd_shade_ms = tm->bwd_visibility_ms = tm->bwd_exp_ms = 0.0;
    tm->bwd_scatter_ms = 0.0;
    double t0 = omp_get_wtime();

    /* Antialiasing backward: d_image -> d_colour (+ silhouette vertex gradients). */
    /* The ground's border blend came last in the forward: its transpose first. */
    const float *d_img = d_image->data;
    if (opt->antialias && sc->ground.enabled) {
        s = pen__ground_border_bwd(ctx, &st->gb, &st->view, &sc->ground, 3, d_image->data,
                                   st->d_border.data);
        if (s) {
            free(d_world);
            return s;
        }
        d_img = st->d_border.data;
    }
    if (opt->antialias && O > 0) {
        memset(st->d_color.data, 0, sizeof(float) * 3 * np);
        s = pen_antialias_bwd(ctx, &st->gb, &st->view, st->meshes, O, st->color.data, 3,
                              d_img, st->d_color.data, want_geom ? d_world : NULL);
        if (s) {
            free(d_world);
            return s;
        }
    } else {
        memcpy(st->d_color.data, d_img, sizeof(float) * 3 * np);
    }
    tm->bwd_antialias_ms = pen__render_ms_since(t0);

    /* Per-pixel backward, tiles in parallel, each tile into its own accumulators. */
    const int seen = st->ground_occludes ? O : 0;
    const row_layout rl = rows_layout(sc->sh_bands, O, seen, S, K);
    const int ntiles = pen__tile_count(st);
    if ((s = PEN__BUF_RESERVE(ctx, st->rows, rl.stride * (size_t)ntiles,
                              "tile gradient buffers")) ||
        (want_geom && (s = PEN__BUF_RESERVE(ctx, st->d_uvj, 4 * np, "footprint gradient")))) {
        free(d_world);
        return s;
    }
    memset(st->rows.data, 0, sizeof(double) * rl.stride * (size_t)ntiles);
    const int nt = pen__threads(ctx);
    size_t wsb = 0;
    if ((s = pen__tile_ws_reserve(ctx, st, nt, &wsb))) {
        free(d_world);
        return s;
    }
    const int want_height = (wrt & PEN_GRAD_POSE) != 0 && st->ground_occludes;
    const bwd_want bw = {want_geom,
                         want_sph,
                         want_light,
                         want_albedo,
                         seen > 0 && (want_light || want_height),
                         rl,
                         want_lights,
                         seen > 0 && K > 0 && (want_lights || want_height)};
    float *fv_all = st->fv_valid ? st->fv.data : NULL;
    const pen__tile_job job = {sc, st, &bw, fv_all, st->fast ? st->tile_off.data : NULL};
    t0 = omp_get_wtime();
    const pen__loop_ticks lt = pen__tiles_run(st, nt, wsb, shade_tile_bwd, &job);
    tm->bwd_shade_ms = pen__render_ms_since(t0);
    tm->bwd_visibility_ms = pen__stage_ms(tm->bwd_shade_ms, lt.visibility, lt.total);
    tm->bwd_exp_ms = pen__stage_ms(tm->bwd_shade_ms, lt.exp, lt.total);
    t0 = omp_get_wtime();

    /* Reduce the tiles in order. */
    double *sum = pen__calloc(ctx, rl.stride + 1, sizeof(double), "gradient sums");
    if (!sum) {
        free(d_world);
        return PEN_ERROR_MEMORY;
    }
    for (int t = 0; t < ntiles; ++t) {
        const double *row = st->rows.data + rl.stride * (size_t)t;
        for (size_t k = 0; k < rl.stride; ++k)
            sum[k] += row[k];
    }
    /* Lighting: the scene's own, plus what reaches it through the objects' `seen` (ground.c,
     * which also gives the objects' heights their share). */
    double d_sh[PEN_SH_MAX_COEFFS][3];
    for (int k = 0; k < nc; ++k)
        for (int ch = 0; ch < 3; ++ch)
            d_sh[k][ch] = sum[rl.sh + 3 * (size_t)k + ch];
    pen__ground_occlusion_bwd(sc, st, sum + rl.sh_obj, want_light ? d_sh : NULL,
                              want_height ? grad : NULL);
    if (want_light)
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch)
                grad->sh[k][ch] += (float)d_sh[k][ch];
    /* Disk lights: the pixels' share and the horizon factors' (ground.c), then through the
     * normalisation of the stored direction and degrees. */
    if (bw.light_G)
        pen__ground_lights_bwd(sc, st, sum + rl.light_G, want_lights ? sum + rl.lights : NULL,
                               want_height ? grad : NULL);
    if (want_lights)
        for (int l = 0; l < K; ++l) {
            const double *dl = sum + rl.lights + PEN_LIGHT_GRAD_DOUBLES * (size_t)l;
            const double *w = st->lights.w[l];
            const double wd = w[0] * dl[0] + w[1] * dl[1] + w[2] * dl[2];
            pen_light_grad *lg = &grad->lights[l];
            for (int a = 0; a < 3; ++a)
                lg->irradiance[a] += (float)dl[4 + a];
            if (!want_light_geometry) continue;
            for (int a = 0; a < 3; ++a)
                lg->direction[a] += (float)((dl[a] - w[a] * wd) / st->lights.len[l]);
            lg->angular_radius_deg += (float)(dl[3] * (PEN_PI / 180.0));
        }
    if (want_albedo) {
        for (int ch = 0; ch < 3; ++ch)
            grad->ground_albedo[ch] += (float)sum[rl.ground + ch];
        for (int o = 0; o < O; ++o)
            for (int ch = 0; ch < 3; ++ch)
                grad->objects[o].albedo[ch] += (float)sum[rl.albedo + 3 * (size_t)o + ch];
    }

    /* Spheres: world-space gradients -> object space and pose. */
    if (want_sph)
        for (int o = 0; o < O; ++o) {
            const pen_object *ob = &sc->objects[o];
            pen_object_grad *og = &grad->objects[o];
            for (int i = 0; i < ob->spheres.count; ++i) {
                const double *dw = sum + rl.spheres + 4 * (size_t)(st->sphere_first[o] + i);
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

    /* Two independent scatters in one parallel loop of work items: item 0 the geometry's
     * interpolation and vertex-normal backward (serial: into the vertex and barycentric buffers),
     * items 1 .. bands the texels, a band of texture rows each. A band visits every pixel in
     * pixel order and adds only into its own rows, so every texel sums its pixels in the same
     * order whatever the threads (pen__texture_scatter_rows). */
    pen_status s_geom = PEN_OK;
    if (want_geom) memset(st->d_bary.data, 0, sizeof(float) * 2 * np);
    const int bands = want_albedo ? (nt > 1 ? 4 * nt : 1) : 0;
#pragma omp parallel for schedule(dynamic, 1) num_threads(nt)                                     \
    if (nt > 1 && np >= PEN_RENDER_PARALLEL_MIN_PIXELS)
    for (int item = 0; item <= bands; ++item) {
        if (item == 0) {
            if (want_geom) s_geom = geometry_scatter(ctx, sc, st);
            continue;
        }
        for (size_t i = 0; i < np; ++i) {
            const int surf = st->gb.surface[i];
            if (surf < 0) continue;
            const pen_object *ob = &sc->objects[surf];
            if (!ob->texture.data) continue;
            const long th = ob->texture.height;
            const long r0 = th * (item - 1) / bands, r1 = th * item / bands;
            pen__texture_scatter_rows(&ob->texture, st->uv.data + 2 * i,
                                      pen__render_footprint(ob) ? st->uvj.data + 4 * i : NULL,
                                      st->d_rho.data + 3 * i, grad->objects[surf].texture, r0,
                                      r1);
        }
    }

    /* Geometry: barycentrics, pose. */
    if (want_geom) {
        s = s_geom;
        if (!s) s = PEN__BUF_RESERVE(ctx, st->bary_scratch, 9 * np, "barycentric backward");
        if (!s)
            pen_raster_bary_bwd_scratch(ctx, &st->view, st->meshes, O, &st->gb, st->d_bary.data,
                                        d_world, st->bary_scratch.data);
        if (!s) {
            for (int o = 0; o < O; ++o) {
                const pen_object *ob = &sc->objects[o];
                pen_object_grad *og = &grad->objects[o];
                pen_pose_points_bwd(&ob->pose, ob->mesh.vertex_count, ob->mesh.positions,
                                    d_world[o], (wrt & PEN_GRAD_POSE) ? &og->pose : NULL,
                                    (wrt & PEN_GRAD_VERTICES) ? og->positions : NULL);
            }
        }
    }
    free(d_world);
    tm->bwd_scatter_ms = pen__render_ms_since(t0);
    return s;
}
