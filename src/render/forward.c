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
 * - Then the backend (backend.h, docs/design.md sec. 6.4) takes over: its prepare sets the
 *   kernels' parameters and the disk lights (after ground occlusion's horizons, before the
 *   transfers' traces, which read the lights), its shade_fwd writes every pixel's colour (the
 *   CPU backend: 16 x 16 tiles over threads, the fast or the scalar kernel, the disk lights, the
 *   pixels with a traced transfer: src/render/cpu). The frame itself calls no kernel.
 * - Objects shaded with their own precomputed transfer (self.c, docs/design.md sec. 1.15) and
 *   the ground's grid under them (ground_shadow.c) are traced here, before the shading, and read
 *   per pixel by the backend.
 * - Antialiasing blends colours across silhouettes last.
 * - What the backward needs stays in the state (state.c): the per-pixel attributes and what the
 *   backend keeps (its groups, the kernel's store), kept only when the caller passed a state and
 *   shadows are on.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "raster/raster_internal.h"
#include "render/backend.h"
#include "render/render_internal.h"
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

/* Corner values (a0, a1, a2: dim floats each) interpolated with pixel barycentrics (u, v) and
 * w = 1 - u - v: the sum of pen_interpolate_fwd, in the same double arithmetic (the same bits). */
static inline void interpolate_corners(double u, double v, double w, const float *a0,
                                       const float *a1, const float *a2, int dim, float *out) {
    for (int c = 0; c < dim; ++c)
        out[c] = (float)(w * (double)a0[c] + u * (double)a1[c] + v * (double)a2[c]);
}

/* The objects' pixels' point, raw normal and UV (the other pixels' points, pen_gbuffer_points',
 * came with the G-buffer: pen__raster_gbuffer_points), in one pass over the image, a band of rows
 * a thread (each pixel's values are its own, so any split gives the same bits). One pass, not a
 * pass per object (pen_interpolate_fwd), which costs objects x pixels: 2 x 4096 x 512^2 visits with
 * many small objects (bench/NOTES.md "Many small objects"). The point and the normal share the
 * triangle's corners. */
static void interpolate_attributes(const pen_scene *sc, pen_render_state *st, int nt) {
    const int W = st->width, H = st->height;
    const int chunks = nt > 1 && (size_t)W * (size_t)H >= PEN_RENDER_PARALLEL_MIN_PIXELS ? nt : 1;
    const pen_gbuffer *gb = &st->gb;
#pragma omp parallel for schedule(static) num_threads(chunks) if (chunks > 1)
    for (int c = 0; c < chunks; ++c) {
        const int y0 = (int)((long long)H * c / chunks),
                  y1 = (int)((long long)H * (c + 1) / chunks);
        const size_t end = (size_t)y1 * (size_t)W;
        for (size_t i = (size_t)y0 * (size_t)W; i < end; ++i) {
            if ((i & 3) == 0 && i + 4 <= end && pen__no_mesh4(gb->surface + i)) {
                i += 3;
                continue;
            }
            const int o = gb->surface[i];
            if (o < 0) continue;
            const pen_object *ob = &sc->objects[o];
            const size_t t = 3 * (size_t)gb->triangle[i];
            const uint32_t *idx = ob->mesh.indices + t;
            const double u = (double)gb->bary[2 * i], v = (double)gb->bary[2 * i + 1],
                         w = 1.0 - u - v;
            const size_t k0 = 3 * (size_t)idx[0], k1 = 3 * (size_t)idx[1], k2 = 3 * (size_t)idx[2];
            const float *p = st->obj[o].world.data, *n = st->obj[o].vnormal.data;
            interpolate_corners(u, v, w, p + k0, p + k1, p + k2, 3, st->x.data + 3 * i);
            interpolate_corners(u, v, w, n + k0, n + k1, n + k2, 3, st->nraw.data + 3 * i);
            if (ob->texture.data) {
                const uint32_t *uidx = ob->mesh.uv_indices + t;
                const float *uv = ob->mesh.uvs;
                interpolate_corners(u, v, w, uv + 2 * (size_t)uidx[0], uv + 2 * (size_t)uidx[1],
                                    uv + 2 * (size_t)uidx[2], 2, st->uv.data + 2 * i);
            }
        }
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

    if ((s = pen__raster_gbuffer_points(ctx, &st->view, st->meshes, sc->object_count, &sc->ground,
                                        &st->gb, st->x.data)))
        return s;
    interpolate_attributes(sc, st, pen__threads(ctx));
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        if (ob->texture.data) {
            if ((s = PEN__BUF_RESERVE(ctx, st->uvj, 4 * np, "texture footprints"))) return s;
            if (pen__render_footprint(ob)) pen__uv_footprint_fwd(st, ob, o, pen__threads(ctx));
        }
    }

    /* The backend's parameters (the kernels', the lights') after ground occlusion's horizons
     * and before the transfers' traces, which read the lights. */
    pen__ground_occlusion_prepare(sc, opt, st);
    if ((s = st->backend->prepare(ctx, sc, opt, st))) return s;
    if ((s = pen__self_prepare(ctx, sc, opt, st))) return s;
    return pen__ground_shadow_prepare(ctx, sc, st);
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
    st->backend = pen__backend_cpu(); /* the one backend (backend.h) */
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

    t0 = omp_get_wtime();
    pen__background_prepare(ctx, sc, st);
    if ((s = st->backend->shade_fwd(ctx, sc, opt, st, own == NULL))) goto done;
    tm->fwd_shade_ms = pen__render_ms_since(t0);

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
