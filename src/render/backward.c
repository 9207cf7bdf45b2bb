/* The backward of the full differentiable frame (forward.c): from the image's gradient into the
 * lighting, the disk lights, albedos and texels, spheres, poses and vertex positions; and the
 * gradient struct.
 *
 * Design
 * - Antialiasing backward gives d_colour (and silhouette vertex gradients); the backend
 *   (backend.h, the forward's) runs the kernels' backward into per-pixel d_x, d_raw-normal, d_uv,
 *   d_footprint and d_rho and its own accumulators of the small dense gradients, and reduces
 *   those in a fixed order into the gradient struct (lighting, lights, albedos, spheres and their
 *   pose part), so the result does not depend on the thread count. Then the texel scatter (in
 *   pixel order) beside the per-object interpolation and vertex-normal backward (disjoint
 *   outputs), the barycentric backward (the pixel's point slides on its ray as the triangle
 *   moves), and the pose backward, which splits world-space gradients of vertices into
 *   object-space and pose parts.
 * - Gradients are added into the caller's pen_render_grad (so several losses accumulate); only
 *   the groups asked for in `wrt` are computed.
 */
#include "penumbra/render.h"

#include "core/internal.h"
#include "raster/raster_internal.h"
#include "render/backend.h"
#include "render/render_internal.h"

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
    case PEN_GRAD_LIGHTING:
        return "lighting";
    case PEN_GRAD_ALBEDO:
        return "albedo";
    case PEN_GRAD_SPHERES:
        return "sphere";
    case PEN_GRAD_POSE:
        return "pose";
    case PEN_GRAD_VERTICES:
        return "vertex";
    case PEN_GRAD_LIGHTS:
        return "disk-light";
    case PEN_GRAD_LIGHT_IRRADIANCE:
        return "disk-light irradiance";
    default:
        return "unknown";
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
    if ((wrt & TRANSFER_CONSTANT) && (sc->shadow.self != PEN_SELF_SPHERES ||
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
 * the footprints' into the vertices, the vertex normals'. Every object pixel's d_bary is written
 * (pen__interpolate_bwd_object), and those are the only ones the barycentric backward reads. */
static pen_status geometry_scatter(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    pen_status s = PEN_OK;
    for (int o = 0; o < sc->object_count && !s; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen__object_buf *b = &st->obj[o];
        const int tex = ob->texture.data != NULL;
        pen__interpolate_bwd_object(&st->gb, o, ob->mesh.indices, b->world.data, st->d_x.data,
                                    b->d_world.data, b->vnormal.data, st->d_nraw.data,
                                    b->d_vnormal.data, ob->mesh.uv_indices,
                                    tex ? ob->mesh.uvs : NULL, st->d_uv.data, st->d_bary.data);
        if (tex && pen__render_footprint(ob)) pen__uv_footprint_bwd(st, ob, o, b->d_world.data);
        s = pen_vertex_normals_bwd(ctx, ob->mesh.vertex_count, b->world.data,
                                   ob->mesh.triangle_count, ob->mesh.indices, b->d_vnormal.data,
                                   b->d_world.data);
    }
    return s;
}

/* ---- Texel scatter --------------------------------------------------------------------------- */

/* The texel scatter's bands: 4 per thread, taken dynamically. */
#define TEXEL_BANDS_PER_THREAD 4
/* Bands are cut in a texture's rows at multiples of 1 / TEXEL_BINS of its height. */
#define TEXEL_BINS 4096

/* The bin of row r of a texture of h rows, and the first row of bin c (so bin c holds rows
 * [bin_row(c), bin_row(c + 1))). */
static long row_bin(long r, long h) {
    return r * TEXEL_BINS / h;
}
static long bin_row(long c, long h) {
    return (c * h + TEXEL_BINS - 1) / TEXEL_BINS;
}

/* Cuts the texture rows into nb bands that hold about as many textured pixels each, and marks
 * each pixel with the bands its lookup may read (pen__texture_rows): band k (0-based) is the
 * rows [bin_row(cut[k]), bin_row(cut[k + 1])) of every texture, tx_span[2 i .. 2 i + 1] pixel i's
 * first and last band (the first after the last: it wraps; -1: none). Where a texture's visible
 * texels lie is the texture's business (Spot's fill a quarter of its rows): with bands of equal
 * rows one of the headline's 8 bands took 12 of the stage's 22 ms, and every band found its
 * pixels by testing every pixel's footprint (2 million tests a step), now one marking. */
static pen_status texel_bands(pen_context *ctx, const pen_scene *sc, pen_render_state *st, int nb,
                              int nt) {
    const size_t np = (size_t)st->width * (size_t)st->height;
    pen_status s;
    if ((s = PEN__BUF_RESERVE(ctx, st->tx_span, 2 * np, "texel band spans")) ||
        (s = PEN__BUF_RESERVE(ctx, st->tx_cut, TEXEL_BINS + (size_t)nb + 1, "texel bands")))
        return s;
    int *span = st->tx_span.data, *cut = st->tx_cut.data, *band_of = cut + nb + 1;
    /* The bins of each pixel's first and last row (-1: no texture, -2: any row). */
#pragma omp parallel for schedule(static) num_threads(nt) if (np >= PEN_RENDER_PARALLEL_MIN_PIXELS)
    for (long i = 0; i < (long)np; ++i) {
        const int surf = st->gb.surface[i];
        span[2 * i] = span[2 * i + 1] = -1;
        if (surf < 0 || !sc->objects[surf].texture.data) continue;
        const pen_object *ob = &sc->objects[surf];
        long a = 0, b = 0;
        if (!pen__texture_rows(&ob->texture, st->uv.data + 2 * i,
                               pen__render_footprint(ob) ? st->uvj.data + 4 * i : NULL, &a, &b)) {
            span[2 * i] = -2;
            continue;
        }
        span[2 * i] = (int)row_bin(a, ob->texture.height);
        span[2 * i + 1] = (int)row_bin(b, ob->texture.height);
        if (a > b && span[2 * i] == span[2 * i + 1])
            span[2 * i] = -2; /* wraps from a bin round to the same one */
    }
    /* Cuts at equal shares of the pixels by their first bin. */
    memset(band_of, 0, sizeof(int) * TEXEL_BINS);
    long total = 0;
    for (size_t i = 0; i < np; ++i)
        if (span[2 * i] >= 0) ++band_of[span[2 * i]], ++total;
    cut[0] = 0;
    long seen = 0;
    for (int c = 0, k = 1; c < TEXEL_BINS; ++c) {
        seen += band_of[c];
        for (; k < nb && seen * nb >= total * k; ++k)
            cut[k] = c + 1;
    }
    cut[nb] = TEXEL_BINS;
    for (int k = 0; k < nb; ++k)
        for (int c = cut[k]; c < cut[k + 1]; ++c)
            band_of[c] = k;
#pragma omp parallel for schedule(static) num_threads(nt) if (np >= PEN_RENDER_PARALLEL_MIN_PIXELS)
    for (long i = 0; i < (long)np; ++i) {
        if (span[2 * i] == -2)
            span[2 * i] = 0, span[2 * i + 1] = nb - 1;
        else if (span[2 * i] >= 0) {
            const int a = span[2 * i], b = span[2 * i + 1];
            span[2 * i] = band_of[a], span[2 * i + 1] = band_of[b];
            if (a > b && band_of[a] == band_of[b]) /* wraps round to the same band: all */
                span[2 * i] = 0, span[2 * i + 1] = nb - 1;
        }
    }
    return PEN_OK;
}

/* Whether the span (first, last band: texel_bands) holds band k. */
static int span_has(const int *span, int k) {
    const int a = span[0], b = span[1];
    if (a < 0) return 0;
    return a <= b ? a <= k && k <= b : k >= a || k <= b;
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
    const int O = sc->object_count, nt = pen__threads(ctx);
    const int want_geom = (wrt & (PEN_GRAD_POSE | PEN_GRAD_VERTICES)) != 0;
    const int want_albedo = (wrt & PEN_GRAD_ALBEDO) != 0;

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
        s = pen__antialias_bwd_set(ctx, &st->gb, &st->view, st->meshes, O, st->color.data, 3, d_img,
                                   st->d_color.data, want_geom ? d_world : NULL);
        if (s) {
            free(d_world);
            return s;
        }
    } else {
        memcpy(st->d_color.data, d_img, sizeof(float) * 3 * np);
    }
    tm->bwd_antialias_ms = pen__render_ms_since(t0);

    /* The backend's: per-pixel gradients into the state, the dense ones reduced into grad. */
    t0 = omp_get_wtime();
    if ((s = st->backend->shade_bwd(ctx, sc, st, wrt))) {
        free(d_world);
        return s;
    }
    tm->bwd_shade_ms = pen__render_ms_since(t0);
    t0 = omp_get_wtime();
    if ((s = st->backend->reduce(ctx, sc, st, wrt, grad))) {
        free(d_world);
        return s;
    }

    /* Two independent scatters in one parallel loop of work items: item 0 the geometry's
     * interpolation and vertex-normal backward (serial: into the vertex and barycentric buffers),
     * items 1 .. bands the texels, a band of texture rows each over the pixels that may read it
     * (texel_bands). A band adds only into its own rows, its pixels in pixel order, so every
     * texel sums its pixels in the same order whatever the threads and bands
     * (pen__texture_scatter_rows). */
    pen_status s_geom = PEN_OK;
    int textured = 0;
    for (int o = 0; o < O; ++o)
        textured |= sc->objects[o].texture.data != NULL;
    const int bands = want_albedo && textured ? (nt > 1 ? TEXEL_BANDS_PER_THREAD * nt : 1) : 0;
    if (bands > 1 && (s = texel_bands(ctx, sc, st, bands, nt))) {
        free(d_world);
        return s;
    }
#pragma omp parallel for schedule(dynamic, 1)                                                      \
    num_threads(nt) if (nt > 1 && np >= PEN_RENDER_PARALLEL_MIN_PIXELS)
    for (int item = 0; item <= bands; ++item) {
        if (item == 0) {
            if (want_geom) s_geom = geometry_scatter(ctx, sc, st);
            continue;
        }
        const int k = item - 1;
        for (size_t i = 0; i < np; ++i) {
            if (bands > 1 && !span_has(st->tx_span.data + 2 * i, k)) continue;
            const int surf = st->gb.surface[i];
            if (surf < 0) continue;
            const pen_object *ob = &sc->objects[surf];
            if (!ob->texture.data) continue;
            const long th = ob->texture.height;
            const long r0 = bands > 1 ? bin_row(st->tx_cut.data[k], th) : 0;
            const long r1 = bands > 1 ? bin_row(st->tx_cut.data[k + 1], th) : th;
            pen__texture_scatter_rows(&ob->texture, st->uv.data + 2 * i,
                                      pen__render_footprint(ob) ? st->uvj.data + 4 * i : NULL,
                                      st->d_rho.data + 3 * i, grad->objects[surf].texture, r0, r1);
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
