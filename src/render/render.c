/* The full differentiable frame: scene -> posed geometry -> G-buffer -> per-pixel attributes ->
 * shading with SH visibility -> silhouette antialiasing, and its backward into lighting, albedo,
 * spheres, poses and vertex positions.
 *
 * Design
 * - Forward. Vertices and sphere centres are posed (pen_pose_points_fwd; radii times the pose's
 *   scale). The rasterizer gives per pixel the surface, triangle and barycentrics; the visible
 *   point x, the raw normal (interpolated area-weighted vertex normals, computed from the posed
 *   positions so that they move with the vertices) and the UV are interpolated; n = +/- raw/|raw|
 *   with the sign chosen so that n faces the camera's side of the triangle's geometric normal
 *   (closed meshes seen from outside never flip; open meshes seen from behind do). Ground pixels:
 *   x on the plane, n = +Y, the ground albedo. The shading kernel (shade_ops.inc) runs per pixel
 *   in parallel over rows; background pixels show the constant background or the environment map
 *   in the ray direction (pen_envmap_eval: the full-resolution map, not its SH projection, and
 *   not differentiated). Antialiasing blends colours across silhouettes last.
 * - What the state keeps. The G-buffer and per-pixel x, raw normal, n, rho, uv and the
 *   pre-antialiasing colour; visibility is recomputed in the backward (it is cheaper to redo the
 *   sphere sum than to store bands^2 x spheres floats per pixel).
 * - Backward. Antialiasing backward gives d_colour (and silhouette vertex gradients); a parallel
 *   pass over rows runs the kernel's backward per pixel, writing per-pixel d_x, d_raw-normal,
 *   d_uv, d_rho, and per-row double buffers for the small dense gradients (lighting, constant
 *   albedos, ground albedo, world-space spheres). Rows are reduced in order, so the result does
 *   not depend on the thread count. Then, serially per object: interpolation backward (to
 *   vertices and barycentrics), vertex-normal backward, the barycentric backward (the pixel's
 *   point slides on its ray as the triangle moves), the texel scatter, and the pose backward,
 *   which splits world-space gradients of vertices and spheres into object-space and pose parts.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "render/render_internal.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Frames smaller than this are shaded on the calling thread: waking a team costs more than a few
 * thousand pixels take, and optimisers render many small frames. */
#define PARALLEL_MIN_PIXELS 4096

/* ---- State ----------------------------------------------------------------------------------- */

typedef struct object_buf {
    float *world, *vnormal, *d_world, *d_vnormal; /* 3 per vertex */
    int32_t *adjacency;                           /* 3 per triangle */
    size_t cap_v, cap_t;
} object_buf;

struct pen_render_state {
    int valid;              /* a forward has filled the buffers */
    pen_render_options opt; /* the forward's options */
    int width, height;
    pen_view view;
    pen_gbuffer gb;
    pen__shade_params params;
    int object_count, object_cap;
    object_buf *obj;
    pen_raster_mesh *meshes;
    int sphere_count;
    size_t sphere_cap;
    float *spheres;    /* world space, all objects */
    int *sphere_first; /* object o owns spheres [first[o], first[o+1]) */
    float *kappa;      /* overlap weight per world-space sphere (all 1 with overlap "none") */
    size_t kappa_cap;
    size_t pixel_cap;
    float *x, *nraw, *n, *rho, *uv, *color, *nsign;
    float *d_color, *d_x, *d_nraw, *d_uv, *d_rho, *d_bary;
    size_t fv_cap, rows_cap;
    float *fv; /* per pixel F and V (2 bands^2) when shadows are on */
    int fv_valid;
    double *rows;
    pen_render_timings timings;
};

void pen_render_state_timings(const pen_render_state *st, pen_render_timings *out) {
    memset(out, 0, sizeof *out);
    if (st) *out = st->timings;
}

static double ms_since(double t0) {
    return 1e3 * (omp_get_wtime() - t0);
}

pen_status pen_render_state_create(pen_context *ctx, pen_render_state **out) {
    *out = pen__calloc(ctx, 1, sizeof **out, "render state");
    return *out ? PEN_OK : PEN_ERROR_MEMORY;
}

void pen_render_state_free(pen_render_state *st) {
    if (!st) return;
    pen_gbuffer_free(&st->gb);
    for (int o = 0; o < st->object_cap; ++o) {
        object_buf *b = &st->obj[o];
        free(b->world), free(b->vnormal), free(b->d_world), free(b->d_vnormal), free(b->adjacency);
    }
    free(st->obj), free(st->meshes), free(st->spheres), free(st->sphere_first), free(st->kappa);
    float *px[] = {st->x,       st->nraw, st->n,      st->rho,  st->uv,    st->color, st->nsign,
                   st->d_color, st->d_x,  st->d_nraw, st->d_uv, st->d_rho, st->d_bary};
    for (size_t i = 0; i < sizeof px / sizeof px[0]; ++i)
        free(px[i]);
    free(st->fv), free(st->rows);
    free(st);
}

/* Grows *p to hold count elements of `size` bytes (contents are not kept). */
static pen_status ensure(pen_context *ctx, void **p, size_t *cap, size_t count, size_t size,
                         const char *what) {
    if (*p && *cap >= count) return PEN_OK;
    free(*p);
    *p = pen__malloc(ctx, count ? count : 1, size, what);
    *cap = *p ? count : 0;
    return *p ? PEN_OK : PEN_ERROR_MEMORY;
}

/* Sizes one object's buffers for V vertices and T triangles. */
static pen_status ensure_object(pen_context *ctx, object_buf *b, size_t V, size_t T) {
    if (b->world && b->cap_v >= V && b->cap_t >= T) return PEN_OK;
    free(b->world), free(b->vnormal), free(b->d_world), free(b->d_vnormal), free(b->adjacency);
    b->world = pen__malloc(ctx, 3 * V + 1, sizeof(float), "posed vertices");
    b->vnormal = pen__malloc(ctx, 3 * V + 1, sizeof(float), "vertex normals");
    b->d_world = pen__malloc(ctx, 3 * V + 1, sizeof(float), "vertex gradient");
    b->d_vnormal = pen__malloc(ctx, 3 * V + 1, sizeof(float), "normal gradient");
    b->adjacency = pen__malloc(ctx, 3 * T + 1, sizeof(int32_t), "adjacency");
    int ok = b->world && b->vnormal && b->d_world && b->d_vnormal && b->adjacency;
    b->cap_v = ok ? V : 0;
    b->cap_t = ok ? T : 0;
    return ok ? PEN_OK : PEN_ERROR_MEMORY;
}

static pen_status ensure_objects(pen_context *ctx, pen_render_state *st, int count) {
    if (count < 1) count = 1; /* sphere_first always has an entry */
    if (count <= st->object_cap) return PEN_OK;
    object_buf *obj = pen__calloc(ctx, (size_t)count, sizeof *obj, "render objects");
    pen_raster_mesh *meshes = pen__calloc(ctx, (size_t)count, sizeof *meshes, "render meshes");
    int *first = pen__calloc(ctx, (size_t)count + 1, sizeof *first, "render sphere offsets");
    if (!obj || !meshes || !first) {
        free(obj), free(meshes), free(first);
        return PEN_ERROR_MEMORY;
    }
    if (st->object_cap) memcpy(obj, st->obj, sizeof *obj * (size_t)st->object_cap);
    free(st->obj), free(st->meshes), free(st->sphere_first);
    st->obj = obj, st->meshes = meshes, st->sphere_first = first;
    st->object_cap = count;
    return PEN_OK;
}

static pen_status ensure_pixels(pen_context *ctx, pen_render_state *st, size_t n) {
    if (st->pixel_cap >= n) return PEN_OK;
    float **px[] = {&st->x,     &st->nraw,  &st->n,       &st->rho, &st->uv,
                    &st->color, &st->nsign, &st->d_color, &st->d_x, &st->d_nraw,
                    &st->d_uv,  &st->d_rho, &st->d_bary};
    /* 3 floats per pixel is enough for every buffer (uv and d_bary use 2, nsign 1). */
    for (size_t i = 0; i < sizeof px / sizeof px[0]; ++i) {
        free(*px[i]);
        *px[i] = pen__malloc(ctx, n, 3 * sizeof(float), "render pixel buffer");
        if (!*px[i]) {
            st->pixel_cap = 0;
            return PEN_ERROR_MEMORY;
        }
    }
    st->pixel_cap = n;
    return PEN_OK;
}

/* ---- Validation ------------------------------------------------------------------------------ */

static int finite_n(const float *v, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

static const char *object_name(const pen_object *ob) {
    return ob->mesh_path ? ob->mesh_path : "in memory";
}

static pen_status validate(pen_context *ctx, const pen_scene *sc) {
    if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: sh_bands %d out of range [1, %d]",
                          sc->sh_bands, PEN_SH_MAX_BANDS);
    const int nc = sc->sh_bands * sc->sh_bands;
    if (!finite_n(&sc->lighting.sh[0][0], 3 * (size_t)nc))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: lighting: non-finite SH coefficient");
    if (sc->shadow.exp != PEN_SH_EXP_CALIBRATED && sc->shadow.exp != PEN_SH_EXP_PAPER &&
        sc->shadow.exp != PEN_SH_EXP_EXACT)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: shadow.exp: unknown method %d",
                          (int)sc->shadow.exp);
    if (sc->shadow.overlap != PEN_OVERLAP_WEIGHTS && sc->shadow.overlap != PEN_OVERLAP_NONE)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: shadow.overlap: unknown mode %d",
                          (int)sc->shadow.overlap);
    if (sc->object_count < 0 || (sc->object_count > 0 && !sc->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: bad object list");
    if (!finite_n(sc->background, 3) ||
        (sc->ground.enabled && (!finite_n(sc->ground.albedo, 3) || !isfinite(sc->ground.height) ||
                                !isfinite(sc->ground.half_size))))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: non-finite background or ground");
    if (sc->background_envmap && (!sc->lighting.envmap.data || !isfinite(sc->lighting.scale) ||
                                  !isfinite(sc->lighting.rotation_y_deg)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render: the background shows the environment map, but there is none");
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const char *name = object_name(ob);
        pen_status s = pen_mesh_validate(ctx, &ob->mesh);
        if (s) {
            char msg[sizeof((pen_context *)0)->message];
            snprintf(msg, sizeof msg, "%s", pen_context_error(ctx));
            return pen__error(ctx, s, "render: objects[%d] (%s): %s", o, name, msg);
        }
        if (ob->texture.data) {
            if (ob->texture.width < 1 || ob->texture.height < 1 || ob->texture.channels < 3)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): texture must be RGB", o, name);
            if (ob->mesh.uv_count <= 0)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): texture but no texture coordinates", o,
                                  name);
            if (!finite_n(ob->texture.data, (size_t)ob->texture.width * (size_t)ob->texture.height *
                                                (size_t)ob->texture.channels))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): non-finite texel", o, name);
        } else if (!finite_n(ob->albedo, 3)) {
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: objects[%d] (%s): bad albedo", o,
                              name);
        }
        const pen_pose *ps = &ob->pose;
        if (!finite_n(ps->rotation_axis_angle_deg, 3) || !finite_n(ps->translation, 3) ||
            !isfinite(ps->scale) || !(ps->scale > 0.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "render: objects[%d] (%s): pose must be finite with scale > 0", o,
                              name);
        if (ob->spheres.count < 0 || (ob->spheres.count > 0 && !ob->spheres.data))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "render: objects[%d] (%s): bad sphere set",
                              o, name);
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *s4 = ob->spheres.data + 4 * (size_t)i;
            if (!finite_n(s4, 4) || !(s4[3] > 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): sphere %d: needs a finite center and "
                                  "a radius > 0",
                                  o, name, i);
            const float *k = ob->spheres.weight;
            if (k && !(isfinite(k[i]) && k[i] >= 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "render: objects[%d] (%s): sphere %d: overlap weight %g is not a "
                                  "finite number >= 0",
                                  o, name, i, (double)k[i]);
        }
    }
    return PEN_OK;
}

/* ---- Background ------------------------------------------------------------------------------ */

/* Unit direction of the ray through the centre of pixel (px, py). */
static void pixel_dir(const pen_view *v, int px, int py, float dir[3]) {
    double d[3];
    pen_view_ray(v, px + 0.5, py + 0.5, d);
    const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int a = 0; a < 3; ++a)
        dir[a] = (float)(d[a] / len);
}

static void background_fwd(const pen_scene *sc, const pen_view *v, int px, int py, float rgb[3]) {
    if (!sc->background_envmap) {
        for (int ch = 0; ch < 3; ++ch)
            rgb[ch] = sc->background[ch];
        return;
    }
    float dir[3];
    pixel_dir(v, px, py, dir);
    pen_envmap_eval(&sc->lighting.envmap, sc->lighting.rotation_y_deg, sc->lighting.scale, dir,
                    rgb);
}

/* ---- Forward --------------------------------------------------------------------------------- */

pen_render_options pen_render_options_default(void) {
    pen_render_options o;
    o.shadows = 1;
    o.antialias = 1;
    return o;
}

static int thread_count(const pen_context *ctx) {
    int t = pen_context_threads(ctx);
    return t > 0 ? t : omp_get_max_threads();
}

/* Poses the geometry, rasterizes, and interpolates the per-pixel attributes into st. */
static pen_status prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st) {
    pen_status s = validate(ctx, sc);
    if (s) return s;
    if ((s = pen_view_init(ctx, &sc->camera, &st->view))) return s;
    const int W = st->view.width, H = st->view.height;
    const size_t np = (size_t)W * (size_t)H;
    if (st->gb.width != W || st->gb.height != H) {
        pen_gbuffer_free(&st->gb);
        if ((s = pen_gbuffer_create(ctx, W, H, &st->gb))) return s;
    }
    st->width = W, st->height = H;
    if ((s = ensure_pixels(ctx, st, np))) return s;
    if ((s = ensure_objects(ctx, st, sc->object_count))) return s;
    st->object_count = sc->object_count;

    /* Posed vertices, their normals and the adjacency for antialiasing. */
    int spheres = 0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        object_buf *b = &st->obj[o];
        const size_t V = (size_t)ob->mesh.vertex_count, T = (size_t)ob->mesh.triangle_count;
        if ((s = ensure_object(ctx, b, V, T))) return s;
        pen_pose_points_fwd(&ob->pose, (int)V, ob->mesh.positions, b->world);
        if ((s = pen_vertex_normals_fwd(ctx, (int)V, b->world, (int)T, ob->mesh.indices,
                                        b->vnormal)))
            return s;
        if (opt->antialias &&
            (s = pen_raster_adjacency(ctx, (int)V, (int)T, ob->mesh.indices, b->adjacency)))
            return s;
        pen_raster_mesh *m = &st->meshes[o];
        m->vertex_count = (int)V;
        m->triangle_count = (int)T;
        m->positions = b->world;
        m->indices = ob->mesh.indices;
        m->adjacency = opt->antialias ? b->adjacency : NULL;
        st->sphere_first[o] = spheres;
        spheres += ob->spheres.count;
    }
    st->sphere_first[sc->object_count] = spheres;
    st->sphere_count = spheres;
    if ((s = ensure(ctx, (void **)&st->spheres, &st->sphere_cap, 4 * (size_t)spheres, sizeof(float),
                    "posed spheres")))
        return s;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *src = ob->spheres.data + 4 * (size_t)i;
            float *dst = st->spheres + 4 * (size_t)(st->sphere_first[o] + i);
            pen_pose_apply(&ob->pose, src, dst);
            dst[3] = src[3] * ob->pose.scale;
        }
    }
    /* Overlap weights: the object's own, computed from its spheres when it has none (so that an
     * in-memory set renders as the same set loaded from a file), or 1 with overlap "none". */
    if ((s = ensure(ctx, (void **)&st->kappa, &st->kappa_cap, (size_t)spheres, sizeof(float),
                    "overlap weights")))
        return s;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_spheres *sp = &sc->objects[o].spheres;
        float *k = st->kappa + st->sphere_first[o];
        if (sc->shadow.overlap == PEN_OVERLAP_NONE)
            for (int i = 0; i < sp->count; ++i)
                k[i] = 1.0f;
        else if (sp->weight)
            memcpy(k, sp->weight, sizeof(float) * (size_t)sp->count);
        else if ((s = pen_spheres_overlap_weights(ctx, sp, k)))
            return s;
    }

    if ((s = pen_raster_gbuffer(ctx, &st->view, st->meshes, sc->object_count, &sc->ground,
                                &st->gb)))
        return s;
    pen_gbuffer_points(&st->view, &st->gb, st->x);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen_interpolate_fwd(&st->gb, o, ob->mesh.indices, st->obj[o].world, 3, st->x);
        pen_interpolate_fwd(&st->gb, o, ob->mesh.indices, st->obj[o].vnormal, 3, st->nraw);
        if (ob->texture.data)
            pen_interpolate_fwd(&st->gb, o, ob->mesh.uv_indices, ob->mesh.uvs, 2, st->uv);
    }

    const pen_sh_exp_model model = pen_sh_exp_model_default(sc->shadow.exp, sc->sh_bands);
    pen__shade_params_init(&st->params, sc->sh_bands, &model, (double)sc->shadow.epsilon,
                           opt->shadows);
    if (!st->params.gaunt)
        return pen__error(ctx, PEN_ERROR_INTERNAL, "render: no product table for %d bands",
                          sc->sh_bands);
    return PEN_OK;
}

/* Sign that turns the interpolated normal towards the viewer's side of the triangle. */
static float facing_sign(const pen_render_state *st, const pen_object *ob, int o, size_t i) {
    const uint32_t *idx = ob->mesh.indices + 3 * (size_t)st->gb.triangle[i];
    const float *w = st->obj[o].world;
    const float *p0 = w + 3 * (size_t)idx[0], *p1 = w + 3 * (size_t)idx[1],
                *p2 = w + 3 * (size_t)idx[2];
    double e1[3], e2[3], g[3], v[3];
    for (int a = 0; a < 3; ++a) {
        e1[a] = (double)p1[a] - (double)p0[a];
        e2[a] = (double)p2[a] - (double)p0[a];
        v[a] = st->view.eye[a] - (double)st->x[3 * i + a];
    }
    g[0] = e1[1] * e2[2] - e1[2] * e2[1];
    g[1] = e1[2] * e2[0] - e1[0] * e2[2];
    g[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return g[0] * v[0] + g[1] * v[1] + g[2] * v[2] < 0.0 ? -1.0f : 1.0f;
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
    pen_render_state *st = state;
    st->valid = 0;
    pen_render_timings *tm = &st->timings;
    memset(tm, 0, sizeof *tm);
    double t0 = omp_get_wtime();
    if ((s = prepare(ctx, sc, opt, st))) goto done;
    tm->fwd_prepare_ms = ms_since(t0);
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

    /* Keep F and V per pixel for the backward (2 bands^2 floats: 32 MB at 512 x 512, 4 bands),
     * which saves it the sphere sum and the exponential's squarings. */
    const size_t nfv = 2 * (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    float *fv_all = NULL;
    if (own == NULL && opt->shadows) {
        if ((s = ensure(ctx, (void **)&st->fv, &st->fv_cap, nfv * (size_t)W * (size_t)H,
                        sizeof(float), "visibility buffer")))
            goto done;
        fv_all = st->fv;
    }
    st->fv_valid = fv_all != NULL;
    const int nt = thread_count(ctx);
    t0 = omp_get_wtime();
#pragma omp parallel for schedule(dynamic, 1) num_threads(nt) if (W * H >= PARALLEL_MIN_PIXELS)
    for (int py = 0; py < H; ++py) {
        for (int px = 0; px < W; ++px) {
            const size_t i = (size_t)py * (size_t)W + (size_t)px;
            const int surf = st->gb.surface[i];
            float *n = st->n + 3 * i, *rho = st->rho + 3 * i, *col = st->color + 3 * i;
            if (surf == PEN_SURFACE_BACKGROUND) {
                background_fwd(sc, &st->view, px, py, col);
                continue;
            }
            if (surf == PEN_SURFACE_GROUND) {
                n[0] = 0.0f, n[1] = 1.0f, n[2] = 0.0f;
                for (int ch = 0; ch < 3; ++ch)
                    rho[ch] = sc->ground.albedo[ch];
            } else {
                const pen_object *ob = &sc->objects[surf];
                const float sign = facing_sign(st, ob, surf, i);
                st->nsign[i] = sign;
                pen_normalize_fwd(1, st->nraw + 3 * i, n);
                for (int a = 0; a < 3; ++a)
                    n[a] *= sign;
                if (ob->texture.data)
                    pen__texture_fwd(&ob->texture, st->uv + 2 * i, rho);
                else
                    for (int ch = 0; ch < 3; ++ch)
                        rho[ch] = ob->albedo[ch];
            }
            pen__shade_fwd(&st->params, (const float(*)[3])sc->lighting.sh, st->sphere_count,
                           st->spheres, st->kappa, st->x + 3 * i, n, rho, col,
                           fv_all ? fv_all + nfv * i : NULL);
        }
    }
    tm->fwd_shade_ms = ms_since(t0);

    t0 = omp_get_wtime();
    if (opt->antialias && sc->object_count > 0) {
        if ((s = pen_antialias_fwd(ctx, &st->gb, &st->view, st->meshes, sc->object_count, st->color,
                                   3, image->data)))
            goto done;
    } else {
        memcpy(image->data, st->color, sizeof(float) * 3 * (size_t)W * (size_t)H);
    }
    tm->fwd_antialias_ms = ms_since(t0);
    st->opt = *opt;
    st->valid = 1;
    s = PEN_OK;
done:
    pen_render_state_free(own);
    return s;
}

/* ---- Gradient struct ------------------------------------------------------------------------- */

pen_status pen_render_grad_create(pen_context *ctx, const pen_scene *sc, pen_render_grad *out) {
    memset(out, 0, sizeof *out);
    out->bands = sc->sh_bands;
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

/* Layout of one row's double accumulators. */
typedef struct row_layout {
    size_t sh, ground, albedo, spheres, stride;
} row_layout;

static row_layout rows_layout(int bands, int objects, int spheres) {
    row_layout r;
    r.sh = 0;
    r.ground = r.sh + 3 * (size_t)bands * (size_t)bands;
    r.albedo = r.ground + 3;
    r.spheres = r.albedo + 3 * (size_t)objects;
    r.stride = r.spheres + 4 * (size_t)spheres;
    return r;
}

static pen_status check_grad_shape(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_grad *g) {
    if (g->object_count != sc->object_count || g->bands != sc->sh_bands)
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

pen_status pen_render_bwd(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st, const pen_image *d_image, unsigned wrt,
                          pen_render_grad *grad) {
    pen_render_options def = pen_render_options_default();
    if (!opt) opt = &def;
    if (!st || !st->valid)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render backward: no forward pass to undo");
    if (opt->shadows != st->opt.shadows || opt->antialias != st->opt.antialias)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: options differ from the forward pass");
    const int W = st->width, H = st->height;
    if (!d_image || !d_image->data || d_image->width != W || d_image->height != H ||
        d_image->channels != 3)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: d_image must be %dx%d with 3 channels", W, H);
    int changed = st->object_count != sc->object_count;
    for (int o = 0; o < sc->object_count && !changed; ++o)
        changed = st->meshes[o].vertex_count != sc->objects[o].mesh.vertex_count ||
                  st->meshes[o].triangle_count != sc->objects[o].mesh.triangle_count ||
                  st->sphere_first[o + 1] - st->sphere_first[o] != sc->objects[o].spheres.count;
    if (changed)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render backward: the scene changed since the forward pass");
    pen_status s = check_grad_shape(ctx, sc, grad);
    if (s) return s;
    const size_t np = (size_t)W * (size_t)H;
    const int O = sc->object_count, S = st->sphere_count, nc = sc->sh_bands * sc->sh_bands;
    const int want_geom = (wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) != 0;
    const int want_sph = (wrt & (PEN_GRAD_SPHERES | PEN_GRAD_POSE)) != 0;
    const int want_light = (wrt & PEN_GRAD_LIGHTING) != 0;
    const int want_albedo = (wrt & PEN_GRAD_ALBEDO) != 0;

    /* World-space vertex gradient buffers. */
    float **d_world = NULL;
    if (want_geom) {
        d_world = pen__calloc(ctx, (size_t)O + 1, sizeof *d_world, "vertex gradient pointers");
        if (!d_world) return PEN_ERROR_MEMORY;
        for (int o = 0; o < O; ++o) {
            object_buf *b = &st->obj[o];
            const size_t V = (size_t)sc->objects[o].mesh.vertex_count;
            memset(b->d_world, 0, sizeof(float) * 3 * V);
            memset(b->d_vnormal, 0, sizeof(float) * 3 * V);
            d_world[o] = b->d_world;
        }
    }

    pen_render_timings *tm = &st->timings;
    tm->bwd_antialias_ms = tm->bwd_shade_ms = tm->bwd_visibility_ms = tm->bwd_exp_ms = 0.0;
    tm->bwd_scatter_ms = 0.0;
    double t0 = omp_get_wtime();

    /* Antialiasing backward: d_image -> d_colour (+ silhouette vertex gradients). */
    if (opt->antialias && O > 0) {
        memset(st->d_color, 0, sizeof(float) * 3 * np);
        s = pen_antialias_bwd(ctx, &st->gb, &st->view, st->meshes, O, st->color, 3, d_image->data,
                              st->d_color, want_geom ? d_world : NULL);
        if (s) {
            free(d_world);
            return s;
        }
    } else {
        memcpy(st->d_color, d_image->data, sizeof(float) * 3 * np);
    }
    tm->bwd_antialias_ms = ms_since(t0);

    /* Per-pixel backward, rows in parallel, each row into its own accumulators. */
    const row_layout rl = rows_layout(sc->sh_bands, O, S);
    if ((s = ensure(ctx, (void **)&st->rows, &st->rows_cap, rl.stride * (size_t)H, sizeof(double),
                    "row gradient buffers"))) {
        free(d_world);
        return s;
    }
    memset(st->rows, 0, sizeof(double) * rl.stride * (size_t)H);
    const int nt = thread_count(ctx);
    const size_t nfv = 2 * (size_t)nc;
    const float *fv_all = st->fv_valid && st->params.shadows ? st->fv : NULL;
    t0 = omp_get_wtime();
#pragma omp parallel for schedule(dynamic, 1) num_threads(nt) if (W * H >= PARALLEL_MIN_PIXELS)
    for (int py = 0; py < H; ++py) {
        double *row = st->rows + rl.stride * (size_t)py;
        double(*d_sh)[3] = want_light ? (double(*)[3])(row + rl.sh) : NULL;
        double *d_sph = want_sph ? row + rl.spheres : NULL;
        for (int px = 0; px < W; ++px) {
            const size_t i = (size_t)py * (size_t)W + (size_t)px;
            const int surf = st->gb.surface[i];
            const float *dc = st->d_color + 3 * i;
            float *d_x = st->d_x + 3 * i, *d_nraw = st->d_nraw + 3 * i;
            float *d_uv = st->d_uv + 2 * i, *d_rho = st->d_rho + 3 * i;
            d_x[0] = d_x[1] = d_x[2] = 0.0f;
            d_nraw[0] = d_nraw[1] = d_nraw[2] = 0.0f;
            d_uv[0] = d_uv[1] = 0.0f;
            d_rho[0] = d_rho[1] = d_rho[2] = 0.0f;
            if (dc[0] == 0.0f && dc[1] == 0.0f && dc[2] == 0.0f) continue;
            if (surf == PEN_SURFACE_BACKGROUND) continue; /* no parameters */
            const int is_obj = surf >= 0;
            const pen_object *ob = is_obj ? &sc->objects[surf] : NULL;
            const int textured = is_obj && ob->texture.data;
            float d_n[3] = {0.0f, 0.0f, 0.0f};
            const int geom = is_obj && want_geom;
            const int need_rho = want_albedo || (textured && geom);
            pen__shade_bwd(&st->params, (const float(*)[3])sc->lighting.sh, S, st->spheres,
                           st->kappa, st->x + 3 * i, st->n + 3 * i, st->rho + 3 * i, dc,
                           fv_all ? fv_all + nfv * i : NULL, d_sh, d_sph, geom ? d_x : NULL,
                           geom ? d_n : NULL, need_rho ? d_rho : NULL);
            if (!is_obj) {
                if (want_albedo)
                    for (int ch = 0; ch < 3; ++ch)
                        row[rl.ground + ch] += (double)d_rho[ch];
                continue;
            }
            if (!textured && want_albedo)
                for (int ch = 0; ch < 3; ++ch)
                    row[rl.albedo + 3 * (size_t)surf + ch] += (double)d_rho[ch];
            if (!geom) continue;
            if (textured) pen__texture_bwd(&ob->texture, st->uv + 2 * i, d_rho, NULL, d_uv);
            const float sign = st->nsign[i];
            for (int a = 0; a < 3; ++a)
                d_n[a] *= sign;
            pen_normalize_bwd(1, st->nraw + 3 * i, d_n, d_nraw);
        }
    }

    tm->bwd_shade_ms = ms_since(t0);
    t0 = omp_get_wtime();

    /* Reduce the rows in order. */
    double *sum = pen__calloc(ctx, rl.stride + 1, sizeof(double), "gradient sums");
    if (!sum) {
        free(d_world);
        return PEN_ERROR_MEMORY;
    }
    for (int py = 0; py < H; ++py) {
        const double *row = st->rows + rl.stride * (size_t)py;
        for (size_t k = 0; k < rl.stride; ++k)
            sum[k] += row[k];
    }
    if (want_light)
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch)
                grad->sh[k][ch] += (float)sum[rl.sh + 3 * (size_t)k + ch];
    if (want_albedo) {
        for (int ch = 0; ch < 3; ++ch)
            grad->ground_albedo[ch] += (float)sum[rl.ground + ch];
        for (int o = 0; o < O; ++o)
            for (int ch = 0; ch < 3; ++ch)
                grad->objects[o].albedo[ch] += (float)sum[rl.albedo + 3 * (size_t)o + ch];
        /* Texels: a serial scatter in pixel order. */
        for (size_t i = 0; i < np; ++i) {
            const int surf = st->gb.surface[i];
            if (surf < 0 || !sc->objects[surf].texture.data) continue;
            pen__texture_bwd(&sc->objects[surf].texture, st->uv + 2 * i, st->d_rho + 3 * i,
                             grad->objects[surf].texture, NULL);
        }
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

    /* Geometry: interpolation, normals, barycentrics, pose. */
    if (want_geom) {
        memset(st->d_bary, 0, sizeof(float) * 2 * np);
        for (int o = 0; o < O && !s; ++o) {
            const pen_object *ob = &sc->objects[o];
            object_buf *b = &st->obj[o];
            pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->world, 3, st->d_x, b->d_world,
                                st->d_bary);
            pen_interpolate_bwd(&st->gb, o, ob->mesh.indices, b->vnormal, 3, st->d_nraw,
                                b->d_vnormal, st->d_bary);
            if (ob->texture.data)
                pen_interpolate_bwd(&st->gb, o, ob->mesh.uv_indices, ob->mesh.uvs, 2, st->d_uv,
                                    NULL, st->d_bary);
            s = pen_vertex_normals_bwd(ctx, ob->mesh.vertex_count, b->world,
                                       ob->mesh.triangle_count, ob->mesh.indices, b->d_vnormal,
                                       b->d_world);
        }
        if (!s)
            s = pen_raster_bary_bwd(ctx, &st->view, st->meshes, O, &st->gb, st->d_bary, d_world);
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
    tm->bwd_scatter_ms = ms_since(t0);
    return s;
}
