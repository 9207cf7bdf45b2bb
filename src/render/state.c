/* The render state: the buffers a forward fills and its backward reads, and the caches that live
 * from frame to frame.
 *
 * Design
 * - What the state keeps. The G-buffer and per-pixel x, raw normal, n, rho, uv and the
 *   pre-antialiasing colour, each tile's shaded pixels in lighting groups (cpu/tiles.c: one
 *   parallel pass before the shading, read again by the backward), and the kernel's store: F per pixel
 *   (fast kernel, in its batch layout per tile) or F and V per pixel (scalar kernel). The
 *   per-sphere terms are recomputed in the backward (cheaper than storing bands^2 x spheres
 *   floats per pixel). Per object: the posed vertices, their normals and gradient buffers.
 * - Every buffer is a PEN__BUF (render_internal.h), sized by the pass that needs it and grown,
 *   never shrunk, so that an optimiser's frames after the first allocate nothing. Growing drops
 *   the contents: the passes rewrite what they reserve.
 * - Four caches outlive a frame, each with the key it was built from, because an optimiser
 *   renders the same topology, sphere set and background again and again: the antialiasing
 *   adjacency per object (keyed by the topology: vertex and triangle counts, a hash of the
 *   indices), the overlap weights computed from sphere sets that came without them (keyed by the
 *   object-space spheres themselves), the environment-map background (background.c), and each
 *   object's precomputed self transfer (self.c, keyed by the posed vertices, bands and lights).
 */
#include "core/internal.h"
#include "render/transfer_pool.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

void *pen__buf_grow(pen_context *ctx, void *data, size_t *cap, size_t count, size_t size,
                    const char *what) {
    if (data && *cap >= count) return data;
    free(data);
    void *p = pen__malloc(ctx, count ? count : 1, size, what);
    *cap = p ? count : 0;
    return p;
}

double pen__render_ms_since(double t0) {
    return 1e3 * (omp_get_wtime() - t0);
}

/* 8 interleaved multiplicative lanes, vectorised: a fraction of a millisecond for a 1024 x 512
 * map. */
uint64_t pen__render_hash32(const void *data, size_t n) {
    const unsigned char *b = data;
    uint64_t h[8] = {1, 2, 3, 4, 5, 6, 7, 8};
    size_t i = 0;
    for (; i + 16 <= n; i += 16)
        for (int l = 0; l < 8; ++l) {
            uint64_t w;
            memcpy(&w, b + 4 * (i + 2 * (size_t)l), sizeof w);
            h[l] = (h[l] ^ w) * 0x9E3779B97F4A7C15ull;
        }
    uint64_t r = (uint64_t)n;
    for (; i < n; ++i) {
        uint32_t w;
        memcpy(&w, b + 4 * i, sizeof w);
        r = (r ^ w) * 0x100000001B3ull;
    }
    for (int l = 0; l < 8; ++l)
        r = (r ^ h[l] ^ (h[l] >> 29)) * 0x9E3779B97F4A7C15ull;
    return r;
}

/* The per-pixel buffers, 3 floats per pixel each. */
#define PIXEL_BUFFERS 14
static void pixel_buffers(pen_render_state *st, pen__buf_float *px[PIXEL_BUFFERS]) {
    pen__buf_float *all[PIXEL_BUFFERS] = {
        &st->x,       &st->nraw, &st->n,      &st->rho,  &st->uv,    &st->color, &st->nsign,
        &st->d_color, &st->d_x,  &st->d_nraw, &st->d_uv, &st->d_rho, &st->d_bary, &st->d_border};
    memcpy(px, all, sizeof all);
}

size_t pen__render_pixel_bytes(int bands, int store) {
    /* The pixel buffers above, the G-buffer (surface, triangle, 2 barycentrics, depth), the
     * output image, and the backward's store at its larger (scalar kernel) size: F and V. */
    const size_t gbuffer = 2 * sizeof(int32_t) + 3 * sizeof(float);
    /* (+ the texture footprints J and their gradient, 4 floats each, allocated when an object is
     * textured: counted always, an estimate that errs on the safe side) */
    size_t b = PIXEL_BUFFERS * 3 * sizeof(float) + gbuffer + 3 * sizeof(float) + 8 * sizeof(float);
    if (store) b += 2 * (size_t)bands * (size_t)bands * sizeof(float);
    return b;
}

double pen_render_state_bytes(const pen_scene *sc, unsigned wrt, int threads) {
    if (!sc || sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS) return 0.0;
    const double px = (double)sc->camera.width * (double)sc->camera.height;
    const double K = (double)sc->lighting.light_count, nc = (double)sc->sh_bands * sc->sh_bands;
    int textured = 0, texels = 0;
    double spheres = 0.0, b = 0.0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        textured |= ob->texture.data && ob->texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT;
        texels |= ob->texture.data != NULL;
        b += 24.0 * ob->mesh.vertex_count + 12.0 * ob->mesh.triangle_count; /* posed, adjacency */
        spheres += ob->spheres.count;
    }
    const unsigned geometry = PEN_GRAD_SPHERES | PEN_GRAD_POSE | PEN_GRAD_VERTICES;
    /* Per pixel, the buffers a frame writes (pages never written are not resident, so a buffer
     * counts only when the frame uses it): the forward's seven, the G-buffer, the background
     * cache, the footprints, the lights' visibilities and the ground's own disk fractions; with
     * a backward the fast kernel's store (bands^2) and the colour and albedo gradients, and the
     * geometry's five, its barycentric scratch and footprint gradients when it is asked for. */
    double per = 7.0 * 12.0 + 20.0 + 12.0 * (sc->background_envmap != 0) + 16.0 * textured +
                 8.0 * K;
    /* with the self transfer and disk lights, the transfer pixels' own disk fractions (kept
     * between frames) and, while self.c's pixel_trace runs, its lists: object and normal per
     * pixel, two flags, and per transfer pixel its point, normal, index and K ray results (taken
     * as every pixel: an estimate that errs on the safe side) */
    if (sc->shadow.self == PEN_SELF_TRANSFER && K > 0.0) per += 4.0 * K + 46.0 + 4.0 * K;
    if (wrt) per += 4.0 * nc + 24.0;
    if (wrt & geometry) per += 5.0 * 12.0 + 36.0 + 16.0 * textured;
    b += px * per;
    if (wrt & geometry)
        for (int o = 0; o < sc->object_count; ++o)
            b += 24.0 * sc->objects[o].mesh.vertex_count; /* vertex and normal gradients */
    /* about 20 buffers, each resident in whole 4 KiB pages: half a page each on average (a
     * tenth of a 16 x 16 view's state) */
    b += 20.0 * 2048.0;
    /* the state and its per-object caches; posed spheres, weights and their keys; each
     * thread's tile workspace (pixel lists, the fast kernel's lane arrays of F and V) */
    b += (double)sizeof(pen_render_state) + (double)sizeof(pen__object_buf) * sc->object_count;
    b += 40.0 * spheres + (threads > 0 ? threads : 1) * PEN_TILE_PX * (88.0 + 8.0 * nc);
    /* the backward's rows, in double (the CPU backend's layout, cpu/shade_bwd.c): per tile the
     * lighting and the ground's albedo, and what wrt asks for of the objects' albedos, the
     * spheres and the lights; under ground occlusion an entry for each object a tile shows (its
     * `seen` lighting and horizon factors), taken as one per tile and one per object beyond */
    const double O = (double)sc->object_count, tiles = px / PEN_TILE_PX + 1.0;
    const unsigned through_seen =
        PEN_GRAD_LIGHTING | PEN_GRAD_POSE | PEN_GRAD_LIGHTS | PEN_GRAD_LIGHT_IRRADIANCE;
    const int seen = sc->ground.enabled && sc->shadow.ground == PEN_GROUND_OCCLUDES && O > 0.0 &&
                     (wrt & through_seen) != 0;
    const double dense = 3.0 * nc + 3.0 + 3.0 * O * ((wrt & PEN_GRAD_ALBEDO) != 0) +
                         4.0 * spheres * ((wrt & (PEN_GRAD_SPHERES | PEN_GRAD_POSE)) != 0) +
                         7.0 * K * ((wrt & (PEN_GRAD_LIGHTS | PEN_GRAD_LIGHT_IRRADIANCE)) != 0);
    if (wrt) b += 8.0 * (dense * tiles + (seen ? (3.0 * nc + K) * (tiles + O) : 0.0));
    /* the texel scatter's bands of each pixel (backward.c), with more than one thread */
    if ((wrt & PEN_GRAD_ALBEDO) && texels && threads > 1) b += 8.0 * px;
    return b;
}

/* ---- Create, free, timings ------------------------------------------------------------------- */

void pen_render_state_timings(const pen_render_state *st, pen_render_timings *out) {
    memset(out, 0, sizeof *out);
    if (st) *out = st->timings;
}

/* ---- Per-pixel geometry of the last forward ---------------------------------------------------- */

/* Shapes *im as width x height x channels (allocated when its data is NULL). */
static pen_status aov_image(pen_context *ctx, const char *what, int w, int h, int channels,
                            pen_image *im) {
    if (!im->data) return pen_image_create(ctx, w, h, channels, im);
    if (im->width != w || im->height != h || im->channels != channels)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "render aovs: %s image is %dx%dx%d, the frame needs %dx%dx%d", what,
                          im->width, im->height, im->channels, w, h, channels);
    return PEN_OK;
}

pen_status pen_render_state_aovs(pen_context *ctx, const pen_render_state *st, pen_image *mask,
                                 pen_image *depth, pen_image *normals) {
    if (!st || !st->valid)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render aovs: no forward pass in this state");
    const int W = st->width, H = st->height;
    pen_status s = PEN_OK;
    if (mask && (s = aov_image(ctx, "mask", W, H, 1, mask))) return s;
    if (depth && (s = aov_image(ctx, "depth", W, H, 1, depth))) return s;
    if (normals && (s = aov_image(ctx, "normals", W, H, 3, normals))) return s;
    for (size_t i = 0; i < (size_t)W * (size_t)H; ++i) {
        const int surf = st->gb.surface[i];
        const int seen = surf >= 0 || surf == PEN_SURFACE_GROUND;
        if (mask) mask->data[i] = surf >= 0 ? 1.0f : 0.0f;
        if (depth) depth->data[i] = seen ? st->gb.depth[i] : 0.0f;
        for (int a = 0; normals && a < 3; ++a)
            normals->data[3 * i + a] = seen ? st->n.data[3 * i + a] : 0.0f;
    }
    return PEN_OK;
}

pen_status pen_render_state_create(pen_context *ctx, pen_render_state **out) {
    *out = pen__calloc(ctx, 1, sizeof **out, "render state");
    return *out ? PEN_OK : PEN_ERROR_MEMORY;
}

void pen_render_state_free(pen_render_state *st) {
    if (!st) return;
    pen_gbuffer_free(&st->gb);
    for (int o = 0; o < st->object_cap; ++o) {
        pen__object_buf *b = &st->obj[o];
        PEN__BUF_FREE(b->world), PEN__BUF_FREE(b->vnormal), PEN__BUF_FREE(b->d_world);
        PEN__BUF_FREE(b->d_vnormal), PEN__BUF_FREE(b->adjacency);
        pen__blob_release(b->self_blob); /* self_B, self_frac and self_lat are its views */
    }
    free(st->obj), free(st->meshes), free(st->sphere_first);
    PEN__BUF_FREE(st->spheres), PEN__BUF_FREE(st->kappa), PEN__BUF_FREE(st->kappa_key);
    PEN__BUF_FREE(st->kappa_first), PEN__BUF_FREE(st->kappa_self);
    pen__blob_release(st->grid.blob); /* grid.B and grid.frac are its arrays */
    PEN__BUF_FREE(st->grid.kappa);
    PEN__BUF_FREE(st->grid.pfrac);
    PEN__BUF_FREE(st->self_pfrac);
    pen__buf_float *px[PIXEL_BUFFERS];
    pixel_buffers(st, px);
    for (int i = 0; i < PIXEL_BUFFERS; ++i)
        PEN__BUF_FREE(*px[i]);
    PEN__BUF_FREE(st->fv), PEN__BUF_FREE(st->lights_V), PEN__BUF_FREE(st->rows), PEN__BUF_FREE(st->ws), PEN__BUF_FREE(st->bg);
    PEN__BUF_FREE(st->uvj), PEN__BUF_FREE(st->d_uvj);
    PEN__BUF_FREE(st->bary_scratch), PEN__BUF_FREE(st->tile_off), PEN__BUF_FREE(st->groups);
    PEN__BUF_FREE(st->tx_span), PEN__BUF_FREE(st->tx_cut), PEN__BUF_FREE(st->row_off);
    pen__pool_release(st->pool);
    free(st);
}

/* ---- Buffers --------------------------------------------------------------------------------- */

pen_status pen__render_object_reserve(pen_context *ctx, pen__object_buf *b, size_t V, size_t T) {
    if (b->adjacency.cap < 3 * T + 1) b->adj_valid = 0; /* the cache goes with the old block */
    pen_status s;
    if ((s = PEN__BUF_RESERVE(ctx, b->world, 3 * V + 1, "posed vertices")) ||
        (s = PEN__BUF_RESERVE(ctx, b->vnormal, 3 * V + 1, "vertex normals")) ||
        (s = PEN__BUF_RESERVE(ctx, b->d_world, 3 * V + 1, "vertex gradient")) ||
        (s = PEN__BUF_RESERVE(ctx, b->d_vnormal, 3 * V + 1, "normal gradient")) ||
        (s = PEN__BUF_RESERVE(ctx, b->adjacency, 3 * T + 1, "adjacency")))
        return s;
    return PEN_OK;
}

/* The per-object arrays; obj keeps its entries (their buffers and caches) when it grows. */
static pen_status reserve_objects(pen_context *ctx, pen_render_state *st, int count) {
    if (count < 1) count = 1; /* sphere_first always has an entry */
    if (count <= st->object_cap) return PEN_OK;
    pen__object_buf *obj = pen__calloc(ctx, (size_t)count, sizeof *obj, "render objects");
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

pen_status pen__render_state_reserve(pen_context *ctx, pen_render_state *st, size_t n,
                                     int objects) {
    pen__buf_float *px[PIXEL_BUFFERS];
    pixel_buffers(st, px);
    for (int i = 0; i < PIXEL_BUFFERS; ++i) {
        pen_status s = PEN__BUF_RESERVE(ctx, *px[i], 3 * n, "render pixel buffer");
        if (s) return s;
    }
    return reserve_objects(ctx, st, objects);
}

/* ---- Caches: adjacency, overlap weights ------------------------------------------------------ */

pen_status pen__render_object_adjacency(pen_context *ctx, pen__object_buf *b,
                                        const pen_mesh *mesh) {
    const int V = mesh->vertex_count, T = mesh->triangle_count;
    const uint64_t h = pen__render_hash32(mesh->indices, 3 * (size_t)T);
    if (b->adj_valid && b->adj_vertices == V && b->adj_triangles == T && b->adj_hash == h)
        return PEN_OK;
    b->adj_valid = 0;
    pen_status s = pen_raster_adjacency(ctx, V, T, mesh->indices, b->adjacency.data);
    if (s) return s;
    b->adj_valid = 1, b->adj_vertices = V, b->adj_triangles = T;
    b->adj_hash = h;
    return PEN_OK;
}

/* Overlap weights: the object's own, computed from its spheres when it has none (so that an
 * in-memory set renders as the same set loaded from a file), or 1 with overlap "none". Computed
 * weights are kept with the set they came from: an optimiser that renders the same in-memory set
 * every frame computes them once (they cost more than a forward). */
pen_status pen__render_overlap_weights(pen_context *ctx, const pen_scene *sc,
                                       pen_render_state *st) {
    const int spheres = st->sphere_count;
    const size_t nfirst = (size_t)sc->object_count + 1;
    const int kept = st->kappa.data && st->kappa_key.data && st->kappa_first.data &&
                     st->kappa.cap >= (size_t)spheres && st->kappa_key.cap >= 4 * (size_t)spheres &&
                     st->kappa_first.cap >= nfirst &&
                     !memcmp(st->kappa_first.data, st->sphere_first, sizeof(int) * nfirst);
    pen_status s;
    if ((s = PEN__BUF_RESERVE(ctx, st->kappa, (size_t)spheres, "overlap weights")) ||
        (s = PEN__BUF_RESERVE(ctx, st->kappa_key, 4 * (size_t)spheres, "overlap weight keys")) ||
        (s = PEN__BUF_RESERVE(ctx, st->kappa_first, nfirst, "overlap weight layout")))
        return s;
    if (!kept) {
        for (size_t i = 0; i < 4 * (size_t)spheres; ++i)
            st->kappa_key.data[i] = NAN;
        memcpy(st->kappa_first.data, st->sphere_first, sizeof(int) * nfirst);
    }
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_spheres *sp = &sc->objects[o].spheres;
        float *k = st->kappa.data + st->sphere_first[o];
        float *key = st->kappa_key.data + 4 * (size_t)st->sphere_first[o];
        const size_t nkey = 4 * (size_t)sp->count;
        const int computed = sc->shadow.overlap != PEN_OVERLAP_NONE && !sp->weight;
        if (nkey == 0) continue; /* no spheres, no weights (and sp->data may be NULL) */
        if (computed && !memcmp(key, sp->data, sizeof(float) * nkey)) continue; /* as before */
        for (size_t i = 0; i < nkey; ++i)
            key[i] = NAN;
        if (sc->shadow.overlap == PEN_OVERLAP_NONE) {
            for (int i = 0; i < sp->count; ++i)
                k[i] = 1.0f;
        } else if (sp->weight) {
            memcpy(k, sp->weight, sizeof(float) * (size_t)sp->count);
        } else {
            /* Name the input at fault: the scene file, the object and its sphere file. */
            if ((s = pen_spheres_overlap_weights(ctx, sp, k))) {
                const pen_object *ob = &sc->objects[o];
                return pen__error_prefix(ctx, s, "%s: objects[%d].spheres%s%s%s: ",
                                         sc->path ? sc->path : "scene", o,
                                         ob->spheres_path ? " (" : "",
                                         ob->spheres_path ? ob->spheres_path : "",
                                         ob->spheres_path ? ")" : "");
            }
            memcpy(key, sp->data, sizeof(float) * nkey);
        }
    }
    return PEN_OK;
}
