/* The forward of the full differentiable frame: scene -> posed geometry -> G-buffer -> per-pixel
 * attributes -> shading with SH visibility -> silhouette antialiasing. Its backward, into
 * lighting, albedo, spheres, poses and vertex positions, is backward.c.
 *
 * Design
 * - Vertices and sphere centres are posed (pen_pose_points_fwd; radii times the pose's scale).
 *   The rasterizer gives per pixel the surface, triangle and barycentrics; the visible point x,
 *   the raw normal (interpolated area-weighted vertex normals, computed from the posed positions
 *   so that they move with the vertices) and the UV are interpolated; n = +/- raw/|raw| with the
 *   sign chosen so that n faces the camera's side of the triangle's geometric normal (closed
 *   meshes seen from outside never flip; open meshes seen from behind do). Ground pixels: x on
 *   the plane, n = +Y, the ground albedo.
 * - Shading runs over 16 x 16 tiles in parallel (tiles.c: dynamic scheduling, a workspace per
 *   thread, the tile's pixels in lighting groups): the tile's surface pixels go compacted to the
 *   fast kernel (shade_fast.c, batches of SIMD lanes) or one by one to the scalar reference
 *   kernel (shade_ops.inc), as pen_render_options.kernel and the kernel's coverage decide;
 *   background pixels show the constant background or the environment map (background.c).
 *   Antialiasing blends colours across silhouettes last.
 * - Disk lights (lights.c) are added per pixel after the kernel's SH shading, by the same
 *   scalar function whichever kernel ran (no SIMD version yet: bench/NOTES.md).
 * - Objects shaded with their own precomputed transfer (self.c, docs/design.md sec. 1.15): their
 *   pixels leave each run before the kernel and are shaded, SH and lights, by self.c's scalar
 *   path; under the fast kernel their other spheres' sum F comes from it (one call per object of
 *   the run, after the run's other pixels) and is kept after the run's batches in the store
 *   (pen__tile_run_store). The runs stay as grouped.
 *   Ground pixels under such objects leave the same way to ground_shadow.c's grid.
 * - What the backward needs stays in the state (state.c): the per-pixel attributes, the groups,
 *   and the kernel's store (F, or F and V, per pixel), kept only when the caller passed a state
 *   and shadows are on.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "render/render_internal.h"
#include "raster/raster_internal.h"
#include "scene/validate.h"

#include <omp.h>
#include <string.h>

pen_render_options pen_render_options_default(void) {
    pen_render_options o;
    o.shadows = 1;
    o.antialias = 1;
    o.kernel = PEN_RENDER_KERNEL_FAST;
    return o;
}

/* ---- Geometry and attributes ----------------------------------------------------------------- */

/* With shadows on, every object casts its shadow on the others (and, under the sphere model, on
 * itself and the ground) from its spheres: an object without any would cast none, silently.
 * Refused, naming the object and how to give it spheres. */
static pen_status check_spheres(pen_context *ctx, const pen_scene *sc) {
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        if (ob->spheres.count > 0) continue;
        const char *name = ob->mesh_path ? ob->mesh_path : "in memory";
        if (ob->fit_spheres > 0)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "render: objects[%d] (%s): \"spheres\": {\"fit\": %d} is not "
                              "fitted yet; prepare the scene first (pen_scene_prepare, as "
                              "penumbra render and Python's load_scene do)",
                              o, name, ob->fit_spheres);
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render: objects[%d] (%s): no spheres, so it would cast no shadow; give "
                          "it spheres (\"spheres\": {\"fit\": N}, pen_spheres_fit) or render "
                          "without shadows",
                          o, name);
    }
    return PEN_OK;
}

/* Corner values of pixel i's triangle (indices) interpolated with its barycentrics: the sum of
 * pen_interpolate_fwd, in the same double arithmetic (the same bits). */
static void interpolate_pixel(const pen_gbuffer *gb, size_t i, const uint32_t *indices,
                              const float *values, int dim, float *out) {
    const uint32_t *idx = indices + 3 * (size_t)gb->triangle[i];
    const double u = (double)gb->bary[2 * i], v = (double)gb->bary[2 * i + 1], w = 1.0 - u - v;
    const float *a0 = values + (size_t)idx[0] * (size_t)dim;
    const float *a1 = values + (size_t)idx[1] * (size_t)dim;
    const float *a2 = values + (size_t)idx[2] * (size_t)dim;
    for (int c = 0; c < dim; ++c)
        out[c] = (float)(w * (double)a0[c] + u * (double)a1[c] + v * (double)a2[c]);
}

/* The objects' pixels' point, raw normal and UV in one pass over the image: a pass per object
 * (pen_interpolate_fwd) costs objects x pixels, 2 x 4096 x 512^2 visits with many small objects
 * (bench/NOTES.md "Many small objects"). */
static void interpolate_attributes(const pen_scene *sc, pen_render_state *st) {
    const size_t np = (size_t)st->width * (size_t)st->height;
    for (size_t i = 0; i < np; ++i) {
        const int o = st->gb.surface[i];
        if (o < 0) continue;
        const pen_object *ob = &sc->objects[o];
        interpolate_pixel(&st->gb, i, ob->mesh.indices, st->obj[o].world.data, 3,
                          st->x.data + 3 * i);
        interpolate_pixel(&st->gb, i, ob->mesh.indices, st->obj[o].vnormal.data, 3,
                          st->nraw.data + 3 * i);
        if (ob->texture.data)
            interpolate_pixel(&st->gb, i, ob->mesh.uv_indices, ob->mesh.uvs, 2,
                              st->uv.data + 2 * i);
    }
}

/* Poses the geometry, rasterizes, and interpolates the per-pixel attributes into st. */
static pen_status prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st) {
    pen_status s = st->vouched & PEN__VOUCH_VALID ? pen_camera_validate(ctx, &sc->camera)
                                                  : pen__scene_validate(ctx, sc, "render");
    if (!s && opt->shadows) s = check_spheres(ctx, sc);
    if (s) return s;
    if ((s = pen_view_init(ctx, &sc->camera, &st->view))) return s; /* validated: fills the view */
    const int W = st->view.width, H = st->view.height;
    const size_t np = (size_t)W * (size_t)H;
    if (st->gb.width != W || st->gb.height != H) {
        pen_gbuffer_free(&st->gb);
        if ((s = pen_gbuffer_create(ctx, W, H, &st->gb))) return s;
    }
    st->width = W, st->height = H;
    if ((s = pen__render_state_reserve(ctx, st, np, sc->object_count))) return s;
    st->object_count = sc->object_count;

    /* Posed vertices, their normals and the adjacency for antialiasing. */
    int spheres = 0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen__object_buf *b = &st->obj[o];
        const size_t V = (size_t)ob->mesh.vertex_count, T = (size_t)ob->mesh.triangle_count;
        if ((s = pen__render_object_reserve(ctx, b, V, T))) return s;
        pen_pose_points_fwd(&ob->pose, (int)V, ob->mesh.positions, b->world.data);
        if ((s = pen_vertex_normals_fwd(ctx, (int)V, b->world.data, (int)T, ob->mesh.indices,
                                        b->vnormal.data)))
            return s;
        if (opt->antialias && (s = pen__render_object_adjacency(ctx, b, &ob->mesh))) return s;
        pen_raster_mesh *m = &st->meshes[o];
        m->vertex_count = (int)V;
        m->triangle_count = (int)T;
        m->positions = b->world.data;
        m->indices = ob->mesh.indices;
        m->adjacency = opt->antialias ? b->adjacency.data : NULL;
        st->sphere_first[o] = spheres;
        spheres += ob->spheres.count;
    }
    st->sphere_first[sc->object_count] = spheres;
    st->sphere_count = spheres;
    if ((s = PEN__BUF_RESERVE(ctx, st->spheres, 4 * (size_t)spheres, "posed spheres"))) return s;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *src = ob->spheres.data + 4 * (size_t)i;
            float *dst = st->spheres.data + 4 * (size_t)(st->sphere_first[o] + i);
            pen_pose_apply(&ob->pose, src, dst);
            dst[3] = src[3] * ob->pose.scale;
        }
    }
    if ((s = pen__render_overlap_weights(ctx, sc, st))) return s;

    if ((s = pen_raster_gbuffer(ctx, &st->view, st->meshes, sc->object_count, &sc->ground,
                                &st->gb)))
        return s;
    pen_gbuffer_points(&st->view, &st->gb, st->x.data);
    interpolate_attributes(sc, st);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        if (ob->texture.data) {
            if ((s = PEN__BUF_RESERVE(ctx, st->uvj, 4 * np, "texture footprints"))) return s;
            if (pen__render_footprint(ob)) pen__uv_footprint_fwd(st, ob, o, pen__threads(ctx));
        }
    }

    const pen_sh_exp_model model = pen_sh_exp_model_default(sc->shadow.exp, sc->sh_bands);
    pen__shade_params_init(&st->params, sc->sh_bands, &model, (double)sc->shadow.epsilon,
                           opt->shadows);
    if (!st->params.gaunt)
        return pen__error(ctx, PEN_ERROR_INTERNAL, "render: no product table for %d bands",
                          sc->sh_bands);
    pen__lights_init(&st->lights, &sc->lighting, st->params.epsilon, opt->shadows);
    pen__ground_occlusion_prepare(sc, opt, st);
    if ((s = pen__self_prepare(ctx, sc, opt, st))) return s;
    return pen__ground_shadow_prepare(ctx, sc, st);
}

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

/* ---- Shading and the pass -------------------------------------------------------------------- */

/* The disk lights' horizon factors of group g's pixels (NULL: 1). */
static const double *group_horizon(const pen_render_state *st, int g) {
    const int o = pen__tile_group_object(st, g);
    return o >= 0 ? st->obj[o].light_G : NULL;
}

/* Adds the disk lights to the run's pixels (the same per-pixel term after either kernel), over
 * the tile's ncull spheres ws->cull. */
static void shade_lights_fwd(pen_render_state *st, const pen__tile_ws *ws, int ncull, int g,
                             const int *pix, int cnt) {
    const double *G = group_horizon(st, g);
    for (int k0 = 0; k0 < cnt; k0 += PEN_LIGHTS_BLOCK) {
        const int nb = cnt - k0 < PEN_LIGHTS_BLOCK ? cnt - k0 : PEN_LIGHTS_BLOCK;
        pen__lights_candidates(&st->lights, ncull, st->spheres.data, ws->cull, nb, st->x.data,
                               st->n.data, pix + k0, ws->cand, ws->ncand);
        for (int k = 0; k < nb; ++k) {
            const size_t i = (size_t)pix[k0 + k];
            float *V =
                st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i : NULL;
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
                float *V = st->lights_V_valid ? st->lights_V.data + (size_t)st->lights.count * i
                                              : NULL;
                pen__self_shade_fwd(st, (const float(*)[3])sc->lighting.sh, ncull, ws->cull, i, fv,
                                    V);
                continue;
            }
            if (pen__ground_shadow_pixel(st, i)) { /* the ground's grid (ground_shadow.c) */
                pen__ground_shadow_fwd(st, sh, ncull, ws->cull, i,
                                       !st->fast && job->store ? job->store + nfv * i : NULL,
                                       st->lights_V_valid
                                           ? st->lights_V.data + (size_t)st->lights.count * i
                                           : NULL);
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
        pen__shade_fast_fwd(&st->params, sh, st->sphere_count, st->spheres.data, st->kappa.data,
                            nk, g == 0 ? nk : 0, ws->x, ws->n, ws->rho, ws->out, store,
                            ws->kernel, tk);
        for (int k = 0; k < nk; ++k)
            memcpy(st->color.data + 3 * (size_t)ws->idx[k], ws->out + 3 * k, 3 * sizeof(float));
        if (st->lights.count) shade_lights_fwd(st, ws, ncull, g, ws->idx, nk);
        /* The transfer pixels (ws is free again), their F kept after the kernel's batches. */
        if (ntr)
            pen__self_shade_fast_fwd(st, (const float(*)[3])sc->lighting.sh, ncull, ws->cull, tr,
                                     ntr, ws,
                                     store ? store + pen__shade_fast_store_floats(&st->params, nk)
                                           : NULL,
                                     tk);
        if (store) store += pen__tile_run_store(st, cnt); /* the run's layout */
    }
}

/* Refuses a camera whose frame would need more than PEN_RENDER_MAX_BYTES, before anything is
 * allocated (a size outside the camera's range is left to the scene's validation). */
static pen_status check_frame_memory(pen_context *ctx, const pen_scene *sc,
                                     const pen_render_options *opt, int store) {
    if (!sc) return PEN_OK;
    const pen_camera *c = &sc->camera;
    if (c->width < 1 || c->height < 1 || c->width > PEN_IMAGE_MAX_DIM ||
        c->height > PEN_IMAGE_MAX_DIM || sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
        return PEN_OK;
    const double lights = store && opt->shadows && sc->lighting.light_count > 0
                              ? 4.0 * (double)sc->lighting.light_count
                              : 0.0; /* the lights' visibilities kept for the backward */
    const double need =
        (double)c->width * (double)c->height *
        ((double)pen__render_pixel_bytes(sc->sh_bands, store && opt->shadows) + lights);
    if (need <= PEN_RENDER_MAX_BYTES) return PEN_OK;
    return pen__error(ctx, PEN_ERROR_ARGUMENT,
                      "render: camera %d x %d needs about %.1f GB (limit %.1f GB, "
                      "PEN_RENDER_MAX_BYTES); lower camera.width and camera.height",
                      c->width, c->height, need / 1e9, PEN_RENDER_MAX_BYTES / 1e9);
}

pen_status pen__render_fwd_vouched(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_options *opt, pen_render_state *state,
                                   pen_image *image, unsigned vouched) {
    if (!state) return pen_render_fwd(ctx, sc, opt, state, image); /* nothing to vouch for */
    state->vouched = vouched;
    const pen_status s = pen_render_fwd(ctx, sc, opt, state, image);
    state->vouched = 0;
    return s;
}

pen_status pen_render_fwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *state, pen_image *image) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    pen_render_state *own = NULL;
    pen_status s;
    if (!state) {
        if ((s = pen_render_state_create(ctx, &own))) return s;
        state = own;
    }
    if (opt->kernel != PEN_RENDER_KERNEL_FAST && opt->kernel != PEN_RENDER_KERNEL_SCALAR) {
        s = pen__error(ctx, PEN_ERROR_ARGUMENT, "render: unknown kernel %d", opt->kernel);
        goto done;
    }
    if ((s = check_frame_memory(ctx, sc, opt, own == NULL))) goto done;
    pen_render_state *st = state;
    st->valid = 0;
    pen_render_timings *tm = &st->timings;
    memset(tm, 0, sizeof *tm);
    double t0 = omp_get_wtime();
    if ((s = prepare(ctx, sc, opt, st))) goto done;
    tm->fwd_prepare_ms = pen__render_ms_since(t0);
    const int W = st->width, H = st->height;
    if (image->data) {
        if (image->width != W || image->height != H || image->channels != 3) {
            s = pen__error(ctx, PEN_ERROR_ARGUMENT,
                           "render: output image is %dx%dx%d, the camera needs %dx%dx3",
                           image->width, image->height, image->channels, W, H);
            goto done;
        }
    } else if ((s = pen_image_create(ctx, W, H, 3, image))) {
        goto done;
    }

    const int fast =
        opt->kernel == PEN_RENDER_KERNEL_FAST && pen__shade_fast_supported(&st->params);
    const int ntiles = pen__tile_count(st);
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const int nt = pen__threads(ctx);
    size_t wsb = 0;
    if ((s = pen__tile_ws_reserve(ctx, st, nt, &wsb)) ||
        (s = PEN__BUF_RESERVE(ctx, st->groups, (size_t)ntiles, "tile pixel groups")))
        goto done;
    /* Every tile's lighting groups, for the shading below, the store's layout and the backward. */
    t0 = omp_get_wtime();
    const pen__tile_job group_job = {sc, st, NULL, NULL, NULL};
    pen__tiles_run(st, nt, wsb, pen__tile_group, &group_job);
    /* Keep what the backward needs: the scalar kernel F and V per pixel (2 bands^2 floats:
     * 32 MB at 512 x 512, 4 bands), the fast kernel F per pixel in its batch layout. */
    float *fv_all = NULL;
    if (own == NULL && opt->shadows) {
        if (fast && (s = pen__tile_store_layout(ctx, st, ntiles))) goto done;
        const size_t need = fast ? st->tile_off.data[ntiles] : nfv * (size_t)W * (size_t)H;
        if ((s = PEN__BUF_RESERVE(ctx, st->fv, need, "visibility buffer"))) goto done;
        fv_all = st->fv.data;
    }
    st->fv_valid = fv_all != NULL;
    /* The disk lights' visibilities per pixel, for the backward (K floats per pixel). */
    st->lights_V_valid = 0;
    if (own == NULL && opt->shadows && st->lights.count > 0) {
        if ((s = PEN__BUF_RESERVE(ctx, st->lights_V,
                                  (size_t)st->lights.count * (size_t)W * (size_t)H,
                                  "light visibility buffer")))
            goto done;
        st->lights_V_valid = 1;
    }
    st->fast = fast;
    const pen__tile_job job = {sc, st, NULL, fv_all, fast ? st->tile_off.data : NULL};
    pen__background_prepare(ctx, sc, st);
    const pen__loop_ticks lt = pen__tiles_run(st, nt, wsb, shade_tile_fwd, &job);
    tm->fwd_shade_ms = pen__render_ms_since(t0);
    tm->fwd_visibility_ms = pen__stage_ms(tm->fwd_shade_ms, lt.visibility, lt.total);
    tm->fwd_exp_ms = pen__stage_ms(tm->fwd_shade_ms, lt.exp, lt.total);

    t0 = omp_get_wtime();
    if (opt->antialias && sc->object_count > 0) {
        if ((s = pen_antialias_fwd(ctx, &st->gb, &st->view, st->meshes, sc->object_count,
                                   st->color.data, 3, image->data)))
            goto done;
    } else {
        memcpy(image->data, st->color.data, sizeof(float) * 3 * (size_t)W * (size_t)H);
    }
    /* The ground square's border against the background, after the silhouettes (the backward
     * takes it first). */
    if (opt->antialias && sc->ground.enabled) {
        s = pen__ground_border_fwd(ctx, &st->gb, &st->view, &sc->ground, image->data, 3);
        if (s) goto done;
    }
    tm->fwd_antialias_ms = pen__render_ms_since(t0);
    st->opt = *opt;
    st->valid = 1;
    s = PEN_OK;
done:
    pen_render_state_free(own);
    return s;
}
