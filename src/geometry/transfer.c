/* Precomputed transfer of rigid meshes: what their surfaces (and the ground) hide from each of a
 * set of receiver points, typically the meshes' own vertices, ray traced once with Embree (see
 * transfer.h).
 *
 * Design
 * - One Embree scene of the mesh, built per call: the renderer calls this only when the posed
 *   vertices, the band count or the lights change, on one device for all objects of a frame.
 *   The ground square, when asked, is a plane test from the vertex itself (ground_blocks), not a
 *   triangle in the scene; a request without triangles (a convex mesh's own vertices, which it
 *   cannot shadow) makes no Embree device.
 * - SH transfer by a control variate: T_self = H_n - B, the clamped cosine H_n known exactly
 *   (the renderer evaluates it at the pixel's own normal), and only its blocked part B estimated,
 *   by N = 256 cosine-weighted directions stratified on a 16 x 16 grid of the unit square (pdf
 *   cos / pi, so each blocked direction w adds pi / N Y_k(w) to B). A vertex that sees everything
 *   gets B = 0 exactly, so a convex mesh shades exactly as without self-shadowing.
 * - Rays start at the point moved along its normal by 1e-4 of the meshes' bounding diagonal (a
 *   vertex lies on its own triangles; a smaller offset lets rays graze them at creases).
 * - Disk lights: 64 directions uniform over the disk's cap (8 x 8 strata in cos and azimuth); the
 *   fraction counts only those above the tangent plane, since the renderer's horizon term already
 *   weighs the part below.
 * - Jitter within each stratum comes from splitmix64 seeded by the vertex index, and vertices are
 *   independent, so the result is the same for any thread count.
 * - The lights alone (pen__transfer_lights) skip B's 256 rays: the ground's shadows per pixel
 *   (ground_shadow.c) need only the disks' fractions, and first one ray per light to find where.
 *   Those come per camera, twice per render state, on the occluders the grid was traced against:
 *   built once with the grid (pen__transfer_bvh) instead of per call: a 1000-view task of 16 x 16
 *   views built 4000 scenes of its mesh, which took its run from 14 to 24 s (bench/NOTES.md).
 */
#include "geometry/transfer.h"

#include "core/internal.h"
#include "core/random.h"
#include "geometry/embree.h"
#include "penumbra/sh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static pen_status embree_status(pen_context *ctx, RTCDevice device, const char *when) {
    enum RTCError e = rtcGetDeviceError(device);
    if (e == RTC_ERROR_NONE) return PEN_OK;
    return pen__error(ctx, e == RTC_ERROR_OUT_OF_MEMORY ? PEN_ERROR_MEMORY : PEN_ERROR_INTERNAL,
                      "self transfer: Embree error %d while %s", (int)e, when);
}

static int attach(RTCDevice dev, RTCScene scene, const float *p, size_t nv, const uint32_t *idx,
                  size_t nt) {
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    if (!g) return 0;
    const int ok = pen__embree_fill_triangles(g, p, nv, idx, nt);
    if (ok) {
        rtcCommitGeometry(g);
        rtcAttachGeometry(scene, g);
    }
    rtcReleaseGeometry(g);
    return ok;
}

/* The ground square blocks direction d from the vertex p when d points down and meets the plane
 * inside the square. Tested from the vertex itself, not from the offset origin: a vertex resting
 * on the ground with its normal pointing down would otherwise start its rays below the plane and
 * see the lower sky through it (measured: blub under the interior map, 0.146 rel. RMSE on the
 * object, too bright where it touches the ground). */
static int ground_blocks(const pen_ground *g, const double p[3], const double d[3]) {
    if (!g || d[1] >= 0.0) return 0;
    const double t = fmax(p[1] - (double)g->height, 0.0) / -d[1];
    const double x = p[0] + t * d[0], z = p[2] + t * d[2], h = (double)g->half_size;
    return fabs(x) <= h && fabs(z) <= h;
}

/* Which of n <= 16 directions d from the point p (rays from o, p moved along its normal) are
 * blocked: the ground first, by the plane test, then the rest as one Embree packet (none when
 * scene is NULL: no triangles). */
static void blocked16(RTCScene scene, const pen_ground *g, const double p[3], const double o[3],
                      const double (*d)[3], const int *want, int n, int *hit) {
    const float of[3] = {(float)o[0], (float)o[1], (float)o[2]};
    float df[16][3];
    int trace[16], any = 0;
    for (int i = 0; i < n; ++i) {
        hit[i] = want[i] && ground_blocks(g, p, d[i]);
        trace[i] = want[i] && !hit[i];
        any |= trace[i];
        for (int a = 0; a < 3; ++a)
            df[i][a] = (float)d[i][a];
    }
    if (!any || !scene) return;
    int h[16];
    pen__embree_occluded16(scene, of, (const float(*)[3])df, n, trace, 0.0f, h);
    for (int i = 0; i < n; ++i)
        hit[i] |= h[i];
}

/* Two unit vectors completing the unit a to a right-handed frame (Duff et al. 2017). */
static void frame(const double a[3], double t[3], double b[3]) {
    const double s = a[2] >= 0.0 ? 1.0 : -1.0, e = -1.0 / (s + a[2]), f = a[0] * a[1] * e;
    t[0] = 1.0 + s * a[0] * a[0] * e, t[1] = s * f, t[2] = -s * a[0];
    b[0] = f, b[1] = s + a[1] * a[1] * e, b[2] = -a[1];
}

/* What a call traces per point: B and the disk samples, the disk samples alone, or one ray to
 * each light's centre. */
enum { TRACE_ALL, TRACE_DISKS, TRACE_CENTRES };

/* One point: the blocked part B of its clamped cosine (nc values, unless mode skips it) and its
 * light fractions; scene NULL when only the ground occludes. */
static void point_transfer(RTCScene scene, const pen__transfer_request *rq, double offset, int v,
                           int mode, float *B, float *frac) {
    const int nc = rq->bands * rq->bands, K = frac ? rq->light_count : 0;
    const float *pn = rq->normals + 3 * (size_t)v, *pp = rq->points + 3 * (size_t)v;
    double n[3] = {pn[0], pn[1], pn[2]};
    const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(len > 1e-30)) {
        for (int k = 0; k < nc && mode == TRACE_ALL; ++k)
            B[k] = 0.0f;
        for (int l = 0; l < K; ++l)
            frac[l] = 1.0f;
        return;
    }
    for (int a = 0; a < 3; ++a)
        n[a] /= len;
    const pen_ground *g = rq->ground && rq->ground->enabled ? rq->ground : NULL;
    const double p[3] = {pp[0], pp[1], pp[2]};
    double o[3], t[3], b[3];
    for (int a = 0; a < 3; ++a)
        o[a] = p[a] + offset * n[a];
    frame(n, t, b);
    uint64_t rng = pen__splitmix_mix(0x5E1F7A45ull ^ (uint64_t)v);
    double lost[PEN_SH_MAX_COEFFS] = {0}, y[PEN_SH_MAX_COEFFS];
    const int side = 16, N = side * side; /* PEN_TRANSFER_DIRECTIONS: 16 packets of 16 */
    double d[16][3];
    int want[16], hit[16];
    for (int s0 = 0; s0 < N && mode == TRACE_ALL; s0 += 16) {
        for (int i = 0; i < 16; ++i) {
            const int s = s0 + i;
            const double u1 = ((s / side) + pen__splitmix_uniform(&rng)) / side;
            const double u2 = ((s % side) + pen__splitmix_uniform(&rng)) / side;
            const double r = sqrt(u1), phi = 2.0 * PEN_PI * u2, c = sqrt(fmax(0.0, 1.0 - u1));
            for (int a = 0; a < 3; ++a)
                d[i][a] = r * cos(phi) * t[a] + r * sin(phi) * b[a] + c * n[a];
            want[i] = 1;
        }
        blocked16(scene, g, p, o, (const double(*)[3])d, want, 16, hit);
        for (int i = 0; i < 16; ++i) { /* in direction order, as the sum always ran */
            if (!hit[i]) continue;
            pen_sh_eval_d(rq->bands, d[i], y);
            for (int k = 0; k < nc; ++k)
                lost[k] += y[k];
        }
    }
    for (int k = 0; k < nc && mode == TRACE_ALL; ++k)
        B[k] = (float)(PEN_PI / N * lost[k]);
    if (mode == TRACE_CENTRES) {
        for (int l = 0; l < K; ++l) {
            const double *w = rq->light_w[l];
            want[0] = w[0] * n[0] + w[1] * n[1] + w[2] * n[2] > 0.0;
            blocked16(scene, g, p, o, (const double(*)[3])w, want, 1, hit);
            frac[l] = want[0] && hit[0] ? 0.0f : 1.0f;
        }
        return;
    }
    const int dside = 8; /* PEN_TRANSFER_DISK_SAMPLES: 4 packets of 16 */
    for (int l = 0; l < K; ++l) {
        const double *w = rq->light_w[l], cb = cos(rq->light_b[l]);
        double lt[3], lb[3];
        frame(w, lt, lb);
        int above = 0, open = 0;
        for (int s0 = 0; s0 < dside * dside; s0 += 16) {
            for (int i = 0; i < 16; ++i) {
                const int s = s0 + i;
                const double u1 = ((s / dside) + pen__splitmix_uniform(&rng)) / dside;
                const double u2 = ((s % dside) + pen__splitmix_uniform(&rng)) / dside;
                const double c = 1.0 - u1 * (1.0 - cb), sn = sqrt(fmax(0.0, 1.0 - c * c));
                const double phi = 2.0 * PEN_PI * u2;
                for (int a = 0; a < 3; ++a)
                    d[i][a] = sn * cos(phi) * lt[a] + sn * sin(phi) * lb[a] + c * w[a];
                want[i] = d[i][0] * n[0] + d[i][1] * n[1] + d[i][2] * n[2] > 0.0;
                above += want[i];
            }
            blocked16(scene, g, p, o, (const double(*)[3])d, want, 16, hit);
            for (int i = 0; i < 16; ++i)
                open += want[i] && !hit[i];
        }
        frac[l] = above ? (float)open / (float)above : 1.0f;
    }
}

void *pen__transfer_device(pen_context *ctx) {
    char config[64];
    snprintf(config, sizeof config, "threads=%d," PEN__EMBREE_ISA, pen__threads(ctx));
    RTCDevice dev = rtcNewDevice(config);
    if (!dev)
        pen__error(ctx, PEN_ERROR_INTERNAL, "self transfer: Embree device: error %d",
                   (int)rtcGetDeviceError(NULL));
    return dev;
}

void pen__transfer_device_free(void *device) {
    if (device) rtcReleaseDevice((RTCDevice)device);
}

pen_status pen__transfer(pen_context *ctx, const pen__transfer_request *rq, float *B, float *frac) {
    return pen__transfer_on(ctx, NULL, rq, B, frac);
}

/* The occluders of a request made traceable: its meshes in one Embree scene (none without
 * triangles), and the rays' start offset, 1e-4 of their bounding diagonal. */
struct pen__transfer_bvh {
    RTCDevice device; /* owned when made here (own_device) */
    int own_device;
    RTCScene scene;   /* NULL: no triangles, the ground's plane tests alone */
    double offset;
};

static pen_status bvh_build(pen_context *ctx, void *device, const pen__transfer_request *rq,
                            struct pen__transfer_bvh *bv) {
    memset(bv, 0, sizeof *bv);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int g = 0; g < rq->mesh_count; ++g)
        for (int v = 0; v < rq->meshes[g].vertex_count; ++v)
            for (int a = 0; a < 3; ++a) {
                lo[a] = fmin(lo[a], (double)rq->meshes[g].positions[3 * (size_t)v + a]);
                hi[a] = fmax(hi[a], (double)rq->meshes[g].positions[3 * (size_t)v + a]);
            }
    const double diag = lo[0] <= hi[0] ? sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) +
                                              (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                                              (hi[2] - lo[2]) * (hi[2] - lo[2]))
                                       : 0.0;
    bv->offset = 1e-4 * (diag > 0.0 ? diag : 1.0);
    size_t triangles = 0;
    for (int g = 0; g < rq->mesh_count; ++g)
        triangles += rq->meshes[g].triangle_count > 0 ? (size_t)rq->meshes[g].triangle_count : 0;
    /* Without triangles (a convex mesh's own nodes, self.c) the ground's plane tests alone, no
     * Embree. */
    if (!triangles) return PEN_OK;
    if (!(bv->device = device ? (RTCDevice)device : pen__transfer_device(ctx)))
        return PEN_ERROR_INTERNAL;
    bv->own_device = !device;
    bv->scene = rtcNewScene(bv->device);
    pen_status s = PEN_OK;
    for (int g = 0; g < rq->mesh_count && !s; ++g) {
        const pen__transfer_mesh *m = &rq->meshes[g];
        if (m->triangle_count > 0 && !attach(bv->device, bv->scene, m->positions,
                                             (size_t)m->vertex_count, m->indices,
                                             (size_t)m->triangle_count))
            s = embree_status(ctx, bv->device, "allocating mesh buffers");
    }
    if (!s) {
        rtcCommitScene(bv->scene);
        s = embree_status(ctx, bv->device, "building the scene");
    }
    return s;
}

static void bvh_release(struct pen__transfer_bvh *bv) {
    if (bv->scene) rtcReleaseScene(bv->scene);
    if (bv->own_device) rtcReleaseDevice(bv->device);
    memset(bv, 0, sizeof *bv);
}

pen_status pen__transfer_bvh_build(pen_context *ctx, const pen__transfer_request *rq,
                                   pen__transfer_bvh **out) {
    *out = pen__calloc(ctx, 1, sizeof **out, "transfer occluders");
    if (!*out) return PEN_ERROR_MEMORY;
    pen_status s = bvh_build(ctx, NULL, rq, *out);
    if (s) {
        pen__transfer_bvh_free(*out);
        *out = NULL;
    }
    return s;
}

void pen__transfer_bvh_free(pen__transfer_bvh *bvh) {
    if (!bvh) return;
    bvh_release(bvh);
    free(bvh);
}

/* Traces the request in one of the modes above against bvh (NULL: its own, built for this call
 * on device, or on a device of its own when device is NULL); B is not touched unless TRACE_ALL. */
static pen_status trace(pen_context *ctx, void *device, const pen__transfer_bvh *bvh,
                        const pen__transfer_request *rq, int mode, float *B, float *frac) {
    const int P = rq->point_count, nc = rq->bands * rq->bands;
    if (P <= 0) return PEN_OK;
    struct pen__transfer_bvh own;
    pen_status s = PEN_OK;
    if (!bvh) {
        s = bvh_build(ctx, device, rq, &own);
        bvh = &own;
    }
    if (!s) {
        const int threads = pen__threads(ctx);
        RTCScene scene = bvh->scene;
        const double offset = bvh->offset;
#pragma omp parallel for schedule(dynamic, 64) num_threads(threads) if (P > 64)
        for (int v = 0; v < P; ++v)
            point_transfer(scene, rq, offset, v, mode,
                           mode == TRACE_ALL ? B + (size_t)nc * (size_t)v : NULL,
                           frac ? frac + (size_t)rq->light_count * (size_t)v : NULL);
    }
    if (bvh == &own) bvh_release(&own);
    return s;
}

pen_status pen__transfer_on(pen_context *ctx, void *device, const pen__transfer_request *rq,
                            float *B, float *frac) {
    return trace(ctx, device, NULL, rq, TRACE_ALL, B, frac);
}

pen_status pen__transfer_bvh_trace(pen_context *ctx, const pen__transfer_bvh *bvh,
                                   const pen__transfer_request *rq, float *B, float *frac) {
    return trace(ctx, NULL, bvh, rq, TRACE_ALL, B, frac);
}

pen_status pen__transfer_lights(pen_context *ctx, const pen__transfer_bvh *bvh,
                                const pen__transfer_request *rq, int centres, float *frac) {
    return trace(ctx, NULL, bvh, rq, centres ? TRACE_CENTRES : TRACE_DISKS, NULL, frac);
}
