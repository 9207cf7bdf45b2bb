/* Self-shadowing of rigid meshes by a precomputed transfer (docs/design.md sec. 1.15): a pixel of
 * such an object shades with T = exp*(F_others) * T_self, T_self = H_n - B the exact visibility
 * of the object's own mesh times the clamped cosine: H_n at the pixel's normal as everywhere, B
 * the part the mesh blocks, projected per node (the vertices, refined on coarse meshes) by ray
 * tracing (src/geometry/transfer.c) and interpolated at the pixel (so a node that sees everything
 * shades exactly as without self-shadowing), and F_others the log-visibility of the other
 * objects' spheres (the same weights as the kernels). Disk lights on it see the mesh's own
 * unblocked fraction of each disk, per node, times the other spheres' factor.
 *
 * Design
 * - The cache. Per object, the transfer and the light fractions of every node, with a key: a
 *   hash of the posed vertex positions and the indices, the band count, and the lights' unit
 *   directions and radii (the ground too when it is traced). A lighting, albedo or texture
 *   optimisation renders the same pose every frame and pays the ray tracing once; a pose change
 *   recomputes it (the transfer is in world space: no SH rotation per frame).
 * - Constants. Ray-traced visibility is piecewise constant in the pose, the shape and the light
 *   directions, so B and the fractions carry no gradient; what stays differentiable on the object
 *   is linear in the lighting, the lights' irradiance and the albedo (exact), and the other
 *   objects' spheres, the normal through H_n, the spheres' weights and the horizon term.
 *   pen_render_bwd refuses those gradients (pen_render_grad_check); optimisers of pose, shape,
 *   spheres or light directions switch the scene to the sphere model (pen_render_grad_model).
 * - One code path. Transfer pixels go through the scalar kernel's functions whichever kernel
 *   the frame uses; the other objects' spheres enter with the per-object overlap weights
 *   kappa_self (0 on the object's own spheres, which adds nothing and skips them), so sphere
 *   indices and their gradients keep the frame's layout. Under the fast kernel only their sum F
 *   is the fast kernel's (pen__self_shade_fast_fwd: a run's transfer pixels of one object as one
 *   call with its kappa_self), kept in the store for the backward: with thousands of spheres the
 *   sum is all the cost, and the pixels then agree with the scalar kernel within float rounding
 *   (the sum's order), as the sphere model's do, not bit for bit.
 * - The ground. With a ground that occludes (ground.c) the cache traces the ground square too, and
 *   the object's transfer pixels shade with the scene's whole lighting and no horizon factors:
 *   the traced ground replaces ground.c's restriction of the lighting to one horizon per object,
 *   which darkened flat parts close to the ground (measured in docs/visibility.md sec. 8). The
 *   key then holds the ground's height and size; the transfer is in world space, so it already
 *   follows every pose change.
 * - Back faces. The transfer is traced for the side the vertex normal points to; a pixel seeing
 *   a triangle from its other side (open meshes) shades with the spheres as before.
 * - The lights per pixel. A thin part's shadow under a small disk light is narrower than the
 *   nodes, which draw it as beads and gaps; where a pixel is finer than its triangle's nodes and
 *   they cannot be trusted, the pixel traces the disks itself (pixel_trace, as the ground's
 *   pixels do in ground_shadow.c). The fractions are kept in the state (self_pfrac) under their
 *   own key, so the backward shades with the forward's (docs/visibility.md, "On the objects'
 *   own pixels").
 */
#include "core/internal.h"
#include "geometry/transfer.h"
#include "render/transfer_pool.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Receiver nodes at most this far apart (the mean edge, relative to the mesh's bounding diagonal):
 * a coarse mesh's triangles are refined (geometry/lattice.h) so that the occlusion inside creases
 * is sampled densely enough. Measured in docs/visibility.md sec. 10. */
#define PEN_SELF_NODE_SPACING (1.0 / 128.0)
/* ... but at most this many nodes (the dev meshes get 15 000 to 32 000): at about 21-40 us of CPU
 * each, a few seconds once per pose. A mesh of long thin triangles (a tube, a scan with slivers)
 * keeps its vertices' spacing instead of asking for millions of nodes. */
#define PEN_SELF_MAX_NODES 200000.0
/* The convexity test (geometry/lattice.h) costs O(V T), less for a mesh that is not convex (it
 * stops at the first vertex in front of a plane); beyond this many vertex-triangle pairs (some
 * 10 ms) a mesh is traced as not convex. */
#define PEN_SELF_CONVEX_PAIRS 1.6e7
/* B's DC coefficient of a node whose PEN_TRANSFER_DIRECTIONS directions were all blocked is
 * pi Y00 = sqrt(pi) / 2 exactly; one open direction takes pi Y00 / 256 off. Half of that below.
 * The ground counts as a blocker too: a node facing straight down onto it is left out as well,
 * which a camera above the ground barely sees (no change on the dev meshes, within 0.0004). */
#define BURIED_DC ((float)(0.88622692545275801 * (1.0 - 0.5 / PEN_TRANSFER_DIRECTIONS)))

/* The cache key of object o: what its transfer depends on. */
static uint64_t self_key(const pen_scene *sc, const pen_render_state *st, int o) {
    const pen_mesh *m = &sc->objects[o].mesh;
    const pen__lights *L = &st->lights;
    uint64_t h = pen__render_hash32(st->obj[o].world.data, 3 * (size_t)m->vertex_count);
    h = (h ^ pen__render_hash32(m->indices, 3 * (size_t)m->triangle_count)) * 0x9E3779B97F4A7C15ull;
    h = (h ^ (uint64_t)sc->sh_bands ^ ((uint64_t)L->count << 8)) * 0x9E3779B97F4A7C15ull;
    for (int l = 0; l < L->count; ++l) {
        const double wb[4] = {L->w[l][0], L->w[l][1], L->w[l][2], L->b[l]};
        h = (h ^ pen__render_hash32(wb, sizeof wb / 4)) * 0x9E3779B97F4A7C15ull;
    }
    if (st->ground_occludes) { /* the ground is traced too */
        const float g[3] = {1.0f, sc->ground.height, sc->ground.half_size};
        h = (h ^ pen__render_hash32(g, 3)) * 0x9E3779B97F4A7C15ull;
    }
    return h;
}

/* Traces object o's N nodes into its self_B and self_frac (its blob's, not yet shared); a convex
 * mesh (traced at its vertices) blocks none of their rays, so only the ground is traced. *device:
 * the frame's Embree device, made here by the first object that needs one. */
static pen_status trace_self(pen_context *ctx, const pen_scene *sc, pen_render_state *st, int o,
                             size_t N, int convex, void **device) {
    pen__object_buf *b = &st->obj[o];
    const pen_mesh *m = &sc->objects[o].mesh;
    const int K = st->lights.count;
    float *pos = pen__malloc(ctx, 6 * N, sizeof(float), "self transfer nodes");
    if (!pos) return PEN_ERROR_MEMORY;
    float *nrm = pos + 3 * N;
    pen__lattice_nodes(&b->self_lat, m->indices, b->world.data, b->vnormal.data, pos, nrm);
    const pen__transfer_mesh mesh = {m->vertex_count, m->triangle_count, b->world.data,
                                     m->indices};
    const pen__transfer_request rq = {convex ? 0 : 1,
                                      &mesh,
                                      (int)N,
                                      pos,
                                      nrm,
                                      sc->sh_bands,
                                      K,
                                      (const double(*)[3])st->lights.w,
                                      st->lights.b,
                                      st->ground_occludes ? &sc->ground : NULL};
    pen_status s = PEN_OK;
    if (!convex && !*device && !(*device = pen__transfer_device(ctx))) s = PEN_ERROR_INTERNAL;
    if (!s) s = pen__transfer_on(ctx, *device, &rq, b->self_B.data, b->self_frac.data);
    free(pos);
    return s;
}

/* Makes blob (the caller's reference, handed over) object o's trace, read through the views. */
static void self_use(pen__object_buf *b, pen__transfer_blob *blob, uint64_t key) {
    pen__blob_release(b->self_blob);
    b->self_blob = blob;
    b->self_B.data = blob->B, b->self_B.cap = 0;
    b->self_frac.data = blob->frac, b->self_frac.cap = 0;
    b->self_lat = blob->lat; /* a shallow view: the blob owns tri_edges */
    b->self_valid = 1, b->self_key = key;
}

static pen_status self_cache(pen_context *ctx, const pen_scene *sc, pen_render_state *st, int o,
                             void **device) {
    pen__object_buf *b = &st->obj[o];
    const pen_mesh *m = &sc->objects[o].mesh;
    const uint64_t key = self_key(sc, st, o);
    if (b->self_valid && b->self_key == key) return PEN_OK;
    b->self_valid = 0;
    /* The level from the unposed mesh, so that a pose never changes it. A convex mesh cannot
     * shadow its vertices (it lies behind their tangent planes): their transfer holds the
     * ground's occlusion alone, smooth over the object, and the vertices suffice. Between them
     * this drops what the lattice saw of flat faces blocking their leaning interpolated normals
     * (measured in docs/design.md sec. 1.15). */
    const int convex = pen__lattice_convex(m->vertex_count, m->positions, m->triangle_count,
                                           m->indices, PEN_SELF_CONVEX_PAIRS);
    int level = convex ? 1
                       : pen__lattice_level(m->vertex_count, m->positions, m->triangle_count,
                                            m->indices, PEN_SELF_NODE_SPACING, PEN_SELF_MAX_NODES);
    level = level < 1 ? 1 : level > PEN_LATTICE_MAX_LEVEL ? PEN_LATTICE_MAX_LEVEL : level;
    const size_t nc = (size_t)sc->sh_bands * (size_t)sc->sh_bands;
    const size_t K = (size_t)st->lights.count;
    /* Another state of the pool may have traced this key (the transfer is in world space): use
     * its blob, lattice included, if it has this mesh's shape. */
    pen__pool_lock(st->pool);
    pen__transfer_blob *blob = pen__pool_find(st->pool, PEN__POOL_SELF, key);
    if (blob) {
        const pen__lattice *L = &blob->lat;
        const size_t N = (size_t)L->node_count;
        if (L->level == level && L->vertex_count == m->vertex_count &&
            L->triangle_count == m->triangle_count && blob->nB == nc * N && blob->nfrac == K * N) {
            pen__pool_unlock(st->pool);
            self_use(b, blob, key);
            return PEN_OK;
        }
        pen__blob_release(blob);
    }
    pen__lattice lat = {0};
    pen_status s = pen__lattice_build(ctx, &lat, level, m->vertex_count, m->triangle_count,
                                      m->indices);
    const size_t N = (size_t)lat.node_count;
    if (!s && !(blob = pen__blob_create(ctx, nc * N, K * N))) s = PEN_ERROR_MEMORY;
    if (s) {
        pen__pool_unlock(st->pool);
        pen__lattice_free(&lat);
        return s;
    }
    blob->lat = lat;
    self_use(b, blob, key); /* not yet valid for others: the pool gets it once traced */
    b->self_valid = 0;
    s = trace_self(ctx, sc, st, o, N, convex, device);
    if (!s) pen__pool_insert(st->pool, PEN__POOL_SELF, key, blob);
    pen__pool_unlock(st->pool);
    if (s) return s;
    b->self_valid = 1;
    return PEN_OK;
}

static uint64_t pixels_key(const pen_scene *sc, const pen_render_state *st);
static pen_status pixel_trace(pen_context *ctx, const pen_scene *sc, pen_render_state *st);

pen_status pen__self_prepare(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                             pen_render_state *st) {
    st->self_any = 0;
    const int S = st->sphere_count;
    for (int o = 0; o < sc->object_count; ++o) {
        pen__object_buf *b = &st->obj[o];
        const int own = st->sphere_first[o + 1] - st->sphere_first[o];
        b->self_on = pen__self_transfer_on(sc, opt, o);
        b->self_others = S - own > 0;
        st->self_any |= b->self_on;
    }
    if (!st->self_any) return PEN_OK;
    pen_status s = PEN__BUF_RESERVE(ctx, st->kappa_self,
                                    (size_t)sc->object_count * (size_t)S + 1, "self kappa");
    if (s) return s;
    void *device = NULL; /* one Embree device for the frame's objects, made when first needed */
    for (int o = 0; o < sc->object_count && !s; ++o) {
        if (!st->obj[o].self_on) continue;
        float *k = st->kappa_self.data + (size_t)o * (size_t)S;
        memcpy(k, st->kappa.data, sizeof(float) * (size_t)S);
        for (int i = st->sphere_first[o]; i < st->sphere_first[o + 1]; ++i)
            k[i] = 0.0f;
        s = self_cache(ctx, sc, st, o, &device);
    }
    pen__transfer_device_free(device);
    if (s) return s;
    st->pixels_key = pixels_key(sc, st);
    return pixel_trace(ctx, sc, st);
}

/* The blocked part (B, may be NULL) and the light fractions at pixel i of object o, interpolated
 * linearly on the sub-triangle of the node lattice that holds the pixel's barycentrics (at level 1
 * the triangle itself, as the normal is interpolated). A node that found every one of its
 * directions blocked (B's DC coefficient the whole pi Y00: BURIED_DC) is buried inside another
 * closed shell of the mesh, where a part joins the body; left in, it spreads its darkness over the
 * visible part of its triangles as far as the next node. It is left out and the others' weights
 * renormalised, unless all three are buried (docs/results/accuracy.md, "A thin-limbed figure under
 * a low sun": the figure's object error 0.059 -> 0.042, the tube chair's 0.069 -> 0.037). spread
 * (may be NULL): the largest difference of a light's fraction between the nodes that count. */
static void nodes_at(const pen_render_state *st, int o, size_t i, float *B, double *frac,
                     double *spread) {
    const pen__object_buf *b = &st->obj[o];
    int node[3];
    double w[3];
    pen__lattice_locate(&b->self_lat, st->meshes[o].indices, st->gb.triangle[i],
                        (double)st->gb.bary[2 * i], (double)st->gb.bary[2 * i + 1], node, w);
    const int nc = st->params.bands * st->params.bands, K = st->lights.count;
    double kept = 0.0, wk[3];
    for (int c = 0; c < 3; ++c) {
        wk[c] = b->self_B.data[(size_t)nc * (size_t)node[c]] >= BURIED_DC ? 0.0 : w[c];
        kept += wk[c];
    }
    if (kept > 0.0) /* (all three buried: the plain interpolation, as dark as they are) */
        for (int c = 0; c < 3; ++c)
            w[c] = wk[c] / kept;
    for (int k = 0; B && k < nc; ++k) {
        double t = 0.0;
        for (int c = 0; c < 3; ++c)
            t += w[c] * (double)b->self_B.data[(size_t)nc * (size_t)node[c] + (size_t)k];
        B[k] = (float)t;
    }
    if (spread) *spread = 0.0;
    for (int l = 0; l < K; ++l) {
        double f = 0.0, lo = 1.0, hi = 0.0;
        for (int c = 0; c < 3; ++c) {
            const double v = (double)b->self_frac.data[(size_t)K * (size_t)node[c] + (size_t)l];
            f += w[c] * v;
            if (w[c] > 0.0) lo = fmin(lo, v), hi = fmax(hi, v);
        }
        frac[l] = f;
        if (spread && hi - lo > *spread) *spread = hi - lo;
    }
}

void pen__self_transfer_at(const pen_render_state *st, int o, size_t i, float *B, double *frac) {
    nodes_at(st, o, i, B, frac, NULL);
    const int K = st->lights.count;
    const float *own = st->self_pvalid && K ? st->self_pfrac.data + (size_t)K * i : NULL;
    for (int l = 0; own && l < K; ++l)
        if (own[l] >= 0.0f) frac[l] = (double)own[l];
}

/* ---- The lights per pixel -------------------------------------------------------------------- */

/* A pixel whose nodes' fractions of a light differ by more than this lies on an edge of its
 * shadow, which the linear interpolation draws as a ramp between the nodes (beads along a thin
 * part's shadow), so it traces the disk itself. */
#define NODE_SPREAD 0.02
/* Pixels around one whose centre ray disagrees with the nodes that trace their disks too (in
 * pixels, each way): a shadow one or two pixels wide is hit by some centre rays and missed by
 * their neighbours, and its penumbra reaches past the ray's hit. */
#define DILATE 2

/* The object whose transfer pixel i would shade with, or -1: as pen__self_object, which reads the
 * facing sign the shading pass sets later; here the triangle's geometric normal against the view
 * (cpu/shade_fwd.c, facing_sign), and the unit normal facing that side into n. */
static int pixel_object(const pen_scene *sc, const pen_render_state *st, size_t i, float n[3]) {
    const int o = st->gb.surface[i];
    if (o < 0 || !st->obj[o].self_on) return -1;
    const uint32_t *idx = sc->objects[o].mesh.indices + 3 * (size_t)st->gb.triangle[i];
    const float *w = st->obj[o].world.data;
    const float *p0 = w + 3 * (size_t)idx[0], *p1 = w + 3 * (size_t)idx[1],
                *p2 = w + 3 * (size_t)idx[2];
    double e1[3], e2[3], v[3], nn = 0.0;
    for (int a = 0; a < 3; ++a) {
        e1[a] = (double)p1[a] - (double)p0[a];
        e2[a] = (double)p2[a] - (double)p0[a];
        v[a] = st->view.eye[a] - (double)st->x.data[3 * i + a];
        nn += (double)st->nraw.data[3 * i + a] * (double)st->nraw.data[3 * i + a];
    }
    const double g = (e1[1] * e2[2] - e1[2] * e2[1]) * v[0] +
                     (e1[2] * e2[0] - e1[0] * e2[2]) * v[1] +
                     (e1[0] * e2[1] - e1[1] * e2[0]) * v[2];
    if (g < 0.0 || !(nn > 0.0)) return -1; /* seen from behind: the spheres shade it */
    for (int a = 0; a < 3; ++a)
        n[a] = (float)((double)st->nraw.data[3 * i + a] / sqrt(nn));
    return o;
}

/* Whether pixel i of object o is finer than the nodes around it: its footprint (the nearer of
 * its neighbours on the object, per axis) at most half the node spacing of its triangle (the
 * longest edge over the lattice's level). A pixel wider than that is better served by the nodes:
 * the truth averages a shadow edge over the pixel, which their linear ramp approximates and the
 * traced centre does not (docs/results/accuracy.md, the chair's decomposition: the dev meshes at
 * 160 x 160). */
static int finer(const pen_scene *sc, const pen_render_state *st, const int *obj, int o, int i) {
    const int W = st->width, H = st->height, x = i % W, y = i / W;
    const float *p = st->x.data + 3 * (size_t)i;
    double foot = 0.0;
    int known = 0;
    for (int a = 0; a < 2; ++a) {
        const int step = a ? W : 1, at = a ? y : x, lim = a ? H : W;
        double best = HUGE_VAL;
        for (int side = -1; side <= 1; side += 2) {
            if (at + side < 0 || at + side >= lim || obj[i + side * step] != o) continue;
            const float *q = st->x.data + 3 * (size_t)(i + side * step);
            double d2 = 0.0;
            for (int t = 0; t < 3; ++t)
                d2 += ((double)q[t] - (double)p[t]) * ((double)q[t] - (double)p[t]);
            best = fmin(best, sqrt(d2));
        }
        if (best < HUGE_VAL) foot = fmax(foot, best), known = 1;
    }
    if (!known) return 1;
    const uint32_t *idx = sc->objects[o].mesh.indices + 3 * (size_t)st->gb.triangle[i];
    const float *w = st->obj[o].world.data;
    double edge = 0.0;
    for (int c = 0; c < 3; ++c) {
        const float *a = w + 3 * (size_t)idx[c], *b = w + 3 * (size_t)idx[(c + 1) % 3];
        double d2 = 0.0;
        for (int t = 0; t < 3; ++t)
            d2 += ((double)a[t] - (double)b[t]) * ((double)a[t] - (double)b[t]);
        edge = fmax(edge, sqrt(d2));
    }
    return 2.0 * foot <= edge / st->obj[o].self_lat.level;
}

/* The key of both per-pixel traces (this file's and ground_shadow.c's): everything the traced
 * fractions depend on but the nodes' traces, whose keys the callers add. It is made from the
 * frame's inputs, not from its pixels, so that a hit costs no pass over the image (listing the
 * transfer pixels and hashing their points took a serial pass of every frame). What the
 * fractions read per pixel is the G-buffer (surface, triangle, barycentrics, depth) and the points
 * and normals interpolated from it; pen_raster_gbuffer makes it from the view, the meshes in
 * world space and the ground square alone (whatever the thread count), and the points and normals
 * follow from the same (forward.c, interpolate_attributes: the normals from the posed vertices).
 * So: the whole view (the size, the camera's frame, focal lengths, principal point, near plane),
 * each object's posed vertices and indices (its transfer key where it has one, which hashes them,
 * or a hash of them: it still hides what lies behind it), which objects shade with their transfer,
 * the ground's square, whether it occludes, and the disk lights' directions and radii, which the
 * rays aim at. */
static uint64_t pixels_key(const pen_scene *sc, const pen_render_state *st) {
    const pen_view *v = &st->view;
    const double view[19] = {v->width,    v->height,     v->eye[0],     v->eye[1],     v->eye[2],
                             v->right[0], v->right[1],   v->right[2],   v->up[0],      v->up[1],
                             v->up[2],    v->forward[0], v->forward[1], v->forward[2], v->focal[0],
                             v->focal[1], v->cx,         v->cy,         v->near_plane};
    uint64_t h = pen__render_hash32(view, sizeof view / 4) * 0x9E3779B97F4A7C15ull;
    h = (h ^ (uint64_t)sc->object_count) * 0x9E3779B97F4A7C15ull;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen__object_buf *b = &st->obj[o];
        const pen_mesh *m = &sc->objects[o].mesh;
        uint64_t g = b->self_key;
        if (!b->self_on)
            g = pen__render_hash32(b->world.data, 3 * (size_t)m->vertex_count) ^
                pen__render_hash32(m->indices, 3 * (size_t)m->triangle_count) * 31u;
        h = (h ^ (uint64_t)b->self_on) * 0x9E3779B97F4A7C15ull;
        h = (h ^ g) * 0x9E3779B97F4A7C15ull;
    }
    const float ground[4] = {(float)sc->ground.enabled, (float)st->ground_occludes,
                             sc->ground.height, sc->ground.half_size};
    h = (h ^ pen__render_hash32(ground, 4)) * 0x9E3779B97F4A7C15ull;
    const pen__lights *L = &st->lights;
    h = (h ^ (uint64_t)L->count) * 0x9E3779B97F4A7C15ull;
    for (int l = 0; l < L->count; ++l) {
        const double wb[4] = {L->w[l][0], L->w[l][1], L->w[l][2], L->b[l]};
        h = (h ^ pen__render_hash32(wb, sizeof wb / 4)) * 0x9E3779B97F4A7C15ull;
    }
    return h;
}

/* The disk lights' fractions per pixel (self_pfrac) where the nodes cannot be trusted, as the
 * ground's (ground_shadow.c, pixel_trace): per object, one ray per transfer pixel towards each
 * light's centre against its own mesh (and the ground when it occludes), then the transfer's disk
 * sampling at the pixels whose nodes disagree or whose ray disagrees with them, and around those.
 * Keyed by pixels_key (the objects' transfer keys among what it holds): a lighting or albedo
 * optimisation pays it once, and its later frames do not visit the pixels here at all. A frame
 * without transfer pixels keeps its all -1 fractions as valid too. */
static pen_status pixel_trace(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    const int K = st->lights.count, O = sc->object_count, W = st->width, H = st->height;
    const size_t np = (size_t)W * (size_t)H;
    if (!K) return PEN_OK;
    const uint64_t key = st->pixels_key;
    if (st->self_pvalid && st->self_pkey == key) return PEN_OK;
    st->self_pvalid = 0;
    int *obj = pen__malloc(ctx, np + 1, sizeof(int), "transfer pixel objects");
    size_t *first = pen__calloc(ctx, (size_t)O + 2, sizeof(size_t), "transfer pixel counts");
    float *nall = pen__malloc(ctx, 3 * np + 1, sizeof(float), "transfer pixel normals");
    if (!obj || !first || !nall) {
        free(obj), free(first), free(nall);
        return PEN_ERROR_MEMORY;
    }
    size_t m = 0;
    for (size_t i = 0; i < np; ++i) {
        obj[i] = pixel_object(sc, st, i, nall + 3 * i);
        if (obj[i] >= 0) ++first[obj[i] + 1], ++m;
    }
    for (int o = 0; o < O; ++o)
        first[o + 1] += first[o];
    float *pts = pen__malloc(ctx, 6 * m + 1, sizeof(float), "transfer pixels");
    float *c = pen__malloc(ctx, (size_t)K * m + 1, sizeof(float), "transfer pixel rays");
    int *pix = pen__malloc(ctx, m + 1, sizeof(int), "transfer pixel list");
    unsigned char *flag = pen__calloc(ctx, 2 * np, 1, "transfer pixel flags");
    size_t *at = pen__malloc(ctx, (size_t)O + 1, sizeof(size_t), "transfer pixel cursor");
    pen_status s = pts && c && pix && flag && at ? PEN_OK : PEN_ERROR_MEMORY;
    if (!s) s = PEN__BUF_RESERVE(ctx, st->self_pfrac, (size_t)K * np + 1, "transfer pixel lights");
    if (!s) {
        memcpy(at, first, (size_t)O * sizeof(size_t));
        for (size_t i = 0; i < np; ++i)
            if (obj[i] >= 0) pix[at[obj[i]]++] = (int)i;
        for (size_t i = 0; i < (size_t)K * np; ++i)
            st->self_pfrac.data[i] = -1.0f;
    }
    for (int o = 0; o < O && !s; ++o) {
        const size_t q0 = first[o], n = first[o + 1] - q0;
        if (!n) continue;
        int *px = pix + q0;
        float *nrm = pts + 3 * m; /* after the points; n <= m */
        for (size_t q = 0; q < n; ++q) {
            memcpy(pts + 3 * q, st->x.data + 3 * (size_t)px[q], 3 * sizeof(float));
            memcpy(nrm + 3 * q, nall + 3 * (size_t)px[q], 3 * sizeof(float));
        }
        const pen_mesh *me = &sc->objects[o].mesh;
        const pen__transfer_mesh mesh = {me->vertex_count, me->triangle_count,
                                         st->obj[o].world.data, me->indices};
        pen__transfer_request rq = {1,
                                    &mesh,
                                    (int)n,
                                    pts,
                                    nrm,
                                    sc->sh_bands,
                                    K,
                                    (const double(*)[3])st->lights.w,
                                    st->lights.b,
                                    st->ground_occludes ? &sc->ground : NULL};
        pen__transfer_bvh *bvh = NULL;
        s = pen__transfer_bvh_build(ctx, &rq, &bvh);
        if (!s) s = pen__transfer_lights(ctx, bvh, &rq, 1, c);
        if (!s) {
            double f[PEN_SCENE_MAX_LIGHTS], spread;
            for (size_t q = 0; q < n; ++q) {
                nodes_at(st, o, (size_t)px[q], NULL, f, &spread);
                int bad = spread > NODE_SPREAD;
                for (int l = 0; l < K && !bad; ++l)
                    bad = fabs((double)c[(size_t)K * q + (size_t)l] - f[l]) > 0.5;
                flag[px[q]] = (unsigned char)(bad && finer(sc, st, obj, o, px[q]));
            }
            for (size_t q = 0; q < n; ++q) { /* dilated over the object's transfer pixels */
                if (!flag[px[q]]) continue;
                const int x = px[q] % W, y = px[q] / W;
                for (int v = y - DILATE > 0 ? y - DILATE : 0; v <= y + DILATE && v < H; ++v)
                    for (int u = x - DILATE > 0 ? x - DILATE : 0; u <= x + DILATE && u < W; ++u) {
                        const size_t j = (size_t)v * (size_t)W + (size_t)u;
                        flag[np + j] |= obj[j] == o && finer(sc, st, obj, o, (int)j);
                    }
            }
            size_t k = 0; /* the flagged pixels, compacted in place */
            for (size_t q = 0; q < n; ++q) {
                if (!flag[np + (size_t)px[q]]) continue;
                memmove(pts + 3 * k, pts + 3 * q, 3 * sizeof(float));
                memmove(nrm + 3 * k, nrm + 3 * q, 3 * sizeof(float));
                px[k++] = px[q];
            }
            rq.point_count = (int)k;
            if (k && !(s = pen__transfer_lights(ctx, bvh, &rq, 0, c)))
                for (size_t q = 0; q < k; ++q)
                    memcpy(st->self_pfrac.data + (size_t)K * (size_t)px[q], c + (size_t)K * q,
                           (size_t)K * sizeof(float));
        }
        pen__transfer_bvh_free(bvh);
    }
    if (!s) st->self_pvalid = 1, st->self_pkey = key;
    free(obj), free(first), free(nall), free(pts), free(c), free(pix), free(flag), free(at);
    return s;
}
