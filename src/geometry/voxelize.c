/* Voxel grid, inside/outside classification and surface sampling for the sphere fit.
 *
 * Inside test. The grid's voxel centres lie on lines parallel to the axes, so one ray per grid
 * line and axis (3 (n0 n1 + n1 n2 + n2 n0) rays in all, not one per voxel) finds every surface
 * crossing along that line; Embree reports them through an intersection filter that records each
 * hit and rejects it, so traversal goes on to the next one. Each crossing is signed by the
 * triangle's own normal (+1 entering, -1 leaving for counter-clockwise-from-outside triangles),
 * and a voxel centre on the line gets two votes: the winding number summed over the crossings
 * before it (the half-ray towards -axis) and after it (towards +axis, signs flipped). The
 * non-zero rule makes the vote independent of the mesh's orientation and merges overlapping
 * closed components; six votes, inside when four or more agree, outvote the half-rays that slip
 * through small holes, graze an edge or hit the same shared edge twice.
 *
 * The grid is shifted by a small irrational fraction of a voxel so that procedurally generated
 * meshes (vertices on round coordinates, symmetric about the origin) do not put grid lines
 * exactly through their vertices and edges.
 */
#include "geometry/voxelize.h"
#include "core/random.h"
#include "geometry/embree.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

pen_status pen__fit_check_mesh(pen_context *ctx, const pen_mesh *mesh, float lo[3], float hi[3]) {
    pen_status st = pen_mesh_validate(ctx, mesh);
    if (st) return st;
    pen_mesh_bounds(mesh, lo, hi);
    if (!(hi[0] > lo[0] || hi[1] > lo[1] || hi[2] > lo[2]))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: the mesh's bounding box is a point");
    /* Far from unit size the float voxel grid and Embree's rays lose the surface (measured on a
     * closed mesh: no voxel inside at a side of 2e-20 or 2e15, good fits from 2e-14 to 2e10), and
     * the fit would blame the mesh for not being closed; a bound well inside that says why. */
    double side = 0;
    for (int a = 0; a < 3; ++a)
        side = fmax(side, (double)hi[a] - (double)lo[a]);
    if (!(side >= PEN__FIT_MIN_SIDE && side <= PEN__FIT_MAX_SIDE))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "fit: the mesh's longest side is %.3g, outside the scale the fitter "
                          "handles [%g, %g]: rescale the mesh (to about 1)",
                          side, PEN__FIT_MIN_SIDE, PEN__FIT_MAX_SIDE);
    return PEN_OK;
}

pen_status pen__fit_mesh_side(pen_context *ctx, const pen_mesh *mesh, double *side) {
    float lo[3], hi[3];
    *side = 0;
    pen_status st = pen__fit_check_mesh(ctx, mesh, lo, hi);
    for (int a = 0; !st && a < 3; ++a)
        *side = fmax(*side, (double)hi[a] - (double)lo[a]);
    return st;
}

void pen__fit_grid_free(pen__fit_grid *grid) {
    if (!grid) return;
    free(grid->inside);
    memset(grid, 0, sizeof *grid);
}

/* ---- Crossings along one grid line ------------------------------------------------------------
 */

typedef struct crossing {
    float t;
    int sign;
    unsigned prim;
} crossing;

/* Embree passes the context to the filter; the hit list rides behind it (Embree's documented way
 * to hand per-ray data to a filter). */
typedef struct line_context {
    struct RTCIntersectContext rtc; /* first member: the filter receives a pointer to it */
    crossing *hits;
    int count, capacity, overflow;
} line_context;

static void record_hit(const struct RTCFilterFunctionNArguments *args) {
    line_context *lc = (line_context *)args->context;
    for (unsigned i = 0; i < args->N; ++i) {
        if (!args->valid[i]) continue;
        /* RTCRayN / RTCHitN are SOA blocks: tfar is ray field 8, primID hit field 5. */
        float t = ((const float *)args->ray)[8 * args->N + i];
        unsigned prim = ((const unsigned *)args->hit)[5 * args->N + i];
        if (lc->count < lc->capacity)
            lc->hits[lc->count++] = (crossing){t, 0, prim};
        else
            lc->overflow = 1;
        args->valid[i] = 0; /* reject: keep traversing for the next crossing */
    }
}

static int crossing_cmp(const void *a, const void *b) {
    const crossing *x = a, *y = b;
    if (x->t != y->t) return x->t < y->t ? -1 : 1;
    return x->prim < y->prim ? -1 : x->prim > y->prim;
}

/* Sign of a crossing of triangle `prim` by a ray along +axis: +1 entering (normal against the
 * ray), -1 leaving, 0 for a triangle parallel to the ray. */
static int crossing_sign(const pen_mesh *mesh, unsigned prim, int axis) {
    const uint32_t *tri = mesh->indices + 3 * (size_t)prim;
    const float *a = mesh->positions + 3 * (size_t)tri[0];
    const float *b = mesh->positions + 3 * (size_t)tri[1];
    const float *c = mesh->positions + 3 * (size_t)tri[2];
    int u = (axis + 1) % 3, v = (axis + 2) % 3;
    /* Component `axis` of (b - a) x (c - a). */
    double n = ((double)b[u] - (double)a[u]) * ((double)c[v] - (double)a[v]) -
               ((double)b[v] - (double)a[v]) * ((double)c[u] - (double)a[u]);
    return n < 0 ? 1 : n > 0 ? -1 : 0;
}

/* Sorts the hits of one line, drops repeats of a primitive (a BVH may report one twice), signs
 * them, and merges same-sign hits at the same distance (a line through a shared edge is reported
 * by both triangles). Returns the new count. */
static int tidy_crossings(const pen_mesh *mesh, int axis, double h, crossing *hits, int count) {
    qsort(hits, (size_t)count, sizeof *hits, crossing_cmp);
    int out = 0;
    for (int i = 0; i < count; ++i) {
        int dup = 0;
        for (int j = out - 1; j >= 0 && (double)(hits[i].t - hits[j].t) <= 1e-6 * h; --j)
            if (hits[j].prim == hits[i].prim) dup = 1;
        if (dup) continue;
        int sign = crossing_sign(mesh, hits[i].prim, axis);
        if (sign == 0) continue;
        if (out > 0 && hits[out - 1].sign == sign &&
            (double)(hits[i].t - hits[out - 1].t) <= 1e-6 * h)
            continue;
        hits[out] = hits[i];
        hits[out].sign = sign;
        ++out;
    }
    return out;
}

/* ---- Voxelization --------------------------------------------------------------------------- */

RTCScene pen__fit_embree_scene(pen_context *ctx, RTCDevice device, const pen_mesh *mesh,
                               RTCFilterFunctionN filter) {
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    if (!scene || !geom) {
        if (geom) rtcReleaseGeometry(geom);
        if (scene) rtcReleaseScene(scene);
        pen__error(ctx, PEN_ERROR_MEMORY, "fit: cannot create the Embree scene");
        return NULL;
    }
    rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
    if (!pen__embree_fill_triangles(geom, mesh->positions, (size_t)mesh->vertex_count,
                                    mesh->indices, (size_t)mesh->triangle_count)) {
        rtcReleaseGeometry(geom);
        rtcReleaseScene(scene);
        pen__error(ctx, PEN_ERROR_MEMORY, "fit: cannot allocate the Embree buffers");
        return NULL;
    }
    if (filter) rtcSetGeometryIntersectFilterFunction(geom, filter);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    if (rtcGetDeviceError(device) != RTC_ERROR_NONE) {
        rtcReleaseScene(scene);
        pen__error(ctx, PEN_ERROR_INTERNAL, "fit: Embree failed to build the scene");
        return NULL;
    }
    return scene;
}

/* Casts the grid lines along `axis` and adds each voxel's two votes into votes[]. Returns 0 when
 * some line had more crossings than fit in a list. */
static int vote_axis(RTCScene scene, const pen_mesh *mesh, const pen__fit_grid *g, int axis,
                     int threads, int capacity, uint8_t *votes) {
    int u = (axis + 1) % 3, v = (axis + 2) % 3;
    long lines = (long)g->n[u] * g->n[v];
    int ok = 1;
    /* A few thousand lines take a few milliseconds: not worth waking a thread team. */
#pragma omp parallel num_threads(threads) if (lines >= 16384) reduction(&& : ok)
    {
        line_context lc;
        lc.hits = malloc(sizeof(crossing) * (size_t)capacity);
        lc.capacity = lc.hits ? capacity : 0;
        lc.overflow = 0;
        ok = lc.hits != NULL;
#pragma omp for schedule(dynamic, 64)
        for (long line = 0; line < lines; ++line) {
            if (!lc.hits) continue;
            int iu = (int)(line % g->n[u]), iv = (int)(line / g->n[u]);
            struct RTCRayHit rh;
            memset(&rh, 0, sizeof rh);
            float org[3];
            org[axis] = (float)(g->origin[axis] - g->h);
            org[u] = (float)(g->origin[u] + g->h * iu);
            org[v] = (float)(g->origin[v] + g->h * iv);
            float dir[3] = {0, 0, 0};
            dir[axis] = 1;
            rh.ray.org_x = org[0], rh.ray.org_y = org[1], rh.ray.org_z = org[2];
            rh.ray.dir_x = dir[0], rh.ray.dir_y = dir[1], rh.ray.dir_z = dir[2];
            rh.ray.tnear = 0;
            rh.ray.tfar = (float)(g->h * (g->n[axis] + 1));
            rh.ray.mask = 0xFFFFFFFFu;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcInitIntersectContext(&lc.rtc);
            lc.count = 0;
            rtcIntersect1(scene, &lc.rtc, &rh);
            int count = tidy_crossings(mesh, axis, g->h, lc.hits, lc.count);
            int total = 0;
            for (int c = 0; c < count; ++c)
                total += lc.hits[c].sign;
            /* Walk the voxel centres (at t = h (i + 1)) and the sorted crossings together. */
            int before = 0, c = 0;
            for (int i = 0; i < g->n[axis]; ++i) {
                float t = (float)(g->h * (i + 1));
                while (c < count && lc.hits[c].t < t)
                    before += lc.hits[c++].sign;
                int after = -(total - before);
                long idx[3];
                idx[axis] = i, idx[u] = iu, idx[v] = iv;
                long vox = idx[0] + (long)g->n[0] * (idx[1] + (long)g->n[1] * idx[2]);
                votes[vox] = (uint8_t)(votes[vox] + (before != 0) + (after != 0));
            }
        }
        if (lc.overflow) ok = 0;
        free(lc.hits);
    }
    return ok;
}

pen_status pen__fit_voxelize(pen_context *ctx, const pen_mesh *mesh, int voxels, double pad,
                             pen__fit_grid *out) {
    memset(out, 0, sizeof *out);
    if (voxels < 2 || voxels > PEN_FIT_MAX_VOXELS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: voxels %d out of range [2, %d]", voxels,
                          PEN_FIT_MAX_VOXELS);
    float lo[3], hi[3];
    double longest;
    pen_status st = pen__fit_mesh_side(ctx, mesh, &longest);
    if (st) return st;
    pen_mesh_bounds(mesh, lo, hi);
    double padded = longest * (1 + 2 * pad);
    out->h = padded / voxels;
    static const double jitter[3] = {0.0137, 0.0291, 0.0419}; /* of a voxel, see the top */
    for (int a = 0; a < 3; ++a) {
        double ext = (double)hi[a] - (double)lo[a] + 2 * pad * longest;
        out->n[a] = (int)ceil(ext / out->h - 1e-9);
        if (out->n[a] < 1) out->n[a] = 1;
        double centre = 0.5 * ((double)lo[a] + (double)hi[a]);
        out->origin[a] = centre - 0.5 * (out->n[a] - 1) * out->h + jitter[a] * out->h;
    }
    size_t total = (size_t)out->n[0] * out->n[1] * out->n[2];
    uint8_t *votes = pen__calloc(ctx, total, 1, "fit: voxel votes");
    if (!votes) return PEN_ERROR_MEMORY;

    RTCDevice device = rtcNewDevice(PEN__FIT_EMBREE_CONFIG);
    if (!device) {
        free(votes);
        return pen__error(ctx, PEN_ERROR_INTERNAL, "fit: cannot create an Embree device");
    }
    RTCScene scene = pen__fit_embree_scene(ctx, device, mesh, record_hit);
    if (!scene) {
        rtcReleaseDevice(device);
        free(votes);
        return pen_context_status(ctx);
    }
    int threads = pen__threads(ctx);
    /* A line crosses each triangle at most once; filters may repeat one, hence the slack. */
    int capacity = mesh->triangle_count < (1 << 20) ? 2 * mesh->triangle_count + 16 : (1 << 21);
    int ok = 1;
    for (int axis = 0; axis < 3 && ok; ++axis)
        ok = vote_axis(scene, mesh, out, axis, threads, capacity, votes);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    if (!ok) {
        free(votes);
        return pen__error(ctx, PEN_ERROR_MEMORY, "fit: too many surface crossings on a grid line");
    }
    for (size_t i = 0; i < total; ++i)
        votes[i] = votes[i] >= 4;
    out->inside = votes;
    return PEN_OK;
}

/* ---- Surface samples --------------------------------------------------------------------------
 */

static double triangle_area(const pen_mesh *mesh, int t) {
    const uint32_t *tri = mesh->indices + 3 * (size_t)t;
    const float *a = mesh->positions + 3 * (size_t)tri[0];
    const float *b = mesh->positions + 3 * (size_t)tri[1];
    const float *c = mesh->positions + 3 * (size_t)tri[2];
    double e1[3], e2[3];
    for (int k = 0; k < 3; ++k)
        e1[k] = (double)b[k] - (double)a[k], e2[k] = (double)c[k] - (double)a[k];
    double n0 = e1[1] * e2[2] - e1[2] * e2[1];
    double n1 = e1[2] * e2[0] - e1[0] * e2[2];
    double n2 = e1[0] * e2[1] - e1[1] * e2[0];
    return 0.5 * sqrt(n0 * n0 + n1 * n1 + n2 * n2);
}

pen_status pen__fit_sample_surface(pen_context *ctx, const pen_mesh *mesh, int count, uint64_t seed,
                                   float *points, int *tri_of, double *area) {
    double *cdf = pen__malloc(ctx, (size_t)mesh->triangle_count, sizeof(double), "fit: area table");
    if (!cdf) return PEN_ERROR_MEMORY;
    double sum = 0;
    for (int t = 0; t < mesh->triangle_count; ++t)
        cdf[t] = (sum += triangle_area(mesh, t));
    *area = sum;
    if (!(sum > 0)) {
        free(cdf);
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: the mesh has zero surface area");
    }
    uint64_t rng = seed ^ 0x5A4D504C45ull; /* distinct stream from the k-means seeding */
    for (int s = 0; s < count; ++s) {
        double x = pen__splitmix_uniform(&rng) * sum;
        int lo = 0, hi = mesh->triangle_count - 1; /* first t with cdf[t] > x */
        while (lo < hi) {
            int mid = lo + (hi - lo) / 2;
            if (cdf[mid] > x)
                hi = mid;
            else
                lo = mid + 1;
        }
        double r1 = sqrt(pen__splitmix_uniform(&rng)), r2 = pen__splitmix_uniform(&rng);
        double wa = 1 - r1, wb = r1 * (1 - r2), wc = r1 * r2; /* uniform barycentrics */
        const uint32_t *tri = mesh->indices + 3 * (size_t)lo;
        if (tri_of) tri_of[s] = lo;
        for (int k = 0; k < 3; ++k)
            points[3 * (size_t)s + k] =
                (float)(wa * (double)mesh->positions[3 * (size_t)tri[0] + k] +
                        wb * (double)mesh->positions[3 * (size_t)tri[1] + k] +
                        wc * (double)mesh->positions[3 * (size_t)tri[2] + k]);
    }
    free(cdf);
    return PEN_OK;
}
