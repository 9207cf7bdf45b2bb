/* Where the fit's spheres go: a medial ball per surface sample, and the allocation that moves
 * spheres to the parts the k-means seeds leave without (fit.c runs it after the seeds and at the
 * early checkpoints of Adam).
 *
 * Why. k-means on the inside voxel centres spreads spheres by volume: a chair's seat panel takes
 * them all and its tube frame, a few percent of the volume, gets two or three; a tube thinner
 * than a voxel has no inside voxel at all. And a sphere far from a tube feels no gradient from it
 * (the energy acts within a soft margin of each sphere), so a part that starts without spheres
 * stays without. The surface samples see every part, thin or not.
 *
 * Medial balls. For each sample, the largest ball inside the mesh that touches the surface there:
 * its radius is the local half-thickness (a tube's radius, half a panel's thickness, a body's
 * inscribed radius), whatever the voxel size. Found by shrinking (Ma et al. 2012): start with
 * the ball whose diameter is the chord along the inward normal to the opposite surface (one
 * Embree ray), then while the nearest surface point q to its centre is closer than its radius,
 * replace it by the ball tangent at the sample that passes through q,
 *     R = |p - q|^2 / (2 d . (q - p)),   d the inward unit normal,
 * which strictly shrinks it; the nearest point is an exact closest-point query on the triangles
 * (Embree's point query with a closest-point-on-triangle callback), not a nearest sample. Half
 * the chord is kept too, as the local thickness: unlike the medial radius it does not shrink
 * towards the edge of a panel, so it tells a tube from a panel's rim.
 *
 * The allocation (below) weighs samples on thin parts up and moves spheres to them: idle spheres
 * to the candidate ball of largest gain, and the spread, which no budget can meet by leaving a
 * part out. Every choice is deterministic (ties to the lower index).
 */
#include "geometry/fit_internal.h"

#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* ---- Closest point on the mesh ------------------------------------------------------------- */

/* The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection, 5.1.5). */
static void closest_on_triangle(const double p[3], const double a[3], const double b[3],
                                const double c[3], double q[3]) {
    double ab[3], ac[3], ap[3];
    for (int k = 0; k < 3; ++k)
        ab[k] = b[k] - a[k], ac[k] = c[k] - a[k], ap[k] = p[k] - a[k];
#define DOT(u, v) ((u)[0] * (v)[0] + (u)[1] * (v)[1] + (u)[2] * (v)[2])
    const double d1 = DOT(ab, ap), d2 = DOT(ac, ap);
    if (d1 <= 0 && d2 <= 0) {
        memcpy(q, a, 3 * sizeof(double));
        return;
    }
    double bp[3], cp[3];
    for (int k = 0; k < 3; ++k)
        bp[k] = p[k] - b[k], cp[k] = p[k] - c[k];
    const double d3 = DOT(ab, bp), d4 = DOT(ac, bp);
    if (d3 >= 0 && d4 <= d3) {
        memcpy(q, b, 3 * sizeof(double));
        return;
    }
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        const double v = d1 / (d1 - d3);
        for (int k = 0; k < 3; ++k)
            q[k] = a[k] + v * ab[k];
        return;
    }
    const double d5 = DOT(ab, cp), d6 = DOT(ac, cp);
    if (d6 >= 0 && d5 <= d6) {
        memcpy(q, c, 3 * sizeof(double));
        return;
    }
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        const double w = d2 / (d2 - d6);
        for (int k = 0; k < 3; ++k)
            q[k] = a[k] + w * ac[k];
        return;
    }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        for (int k = 0; k < 3; ++k)
            q[k] = b[k] + w * (c[k] - b[k]);
        return;
    }
    const double den = 1 / (va + vb + vc), v = vb * den, w = vc * den;
    for (int k = 0; k < 3; ++k)
        q[k] = a[k] + ab[k] * v + ac[k] * w;
#undef DOT
}

static void corner(const pen_mesh *m, unsigned t, int k, double out[3]) {
    const float *v = m->positions + 3 * (size_t)m->indices[3 * (size_t)t + k];
    out[0] = v[0], out[1] = v[1], out[2] = v[2];
}

typedef struct nearest {
    const pen_mesh *mesh;
    double p[3];
    double d2; /* best squared distance so far */
    double q[3];
} nearest;

static bool nearest_visit(struct RTCPointQueryFunctionArguments *args) {
    nearest *n = args->userPtr;
    double a[3], b[3], c[3], q[3];
    corner(n->mesh, args->primID, 0, a);
    corner(n->mesh, args->primID, 1, b);
    corner(n->mesh, args->primID, 2, c);
    closest_on_triangle(n->p, a, b, c, q);
    const double d2 = (q[0] - n->p[0]) * (q[0] - n->p[0]) + (q[1] - n->p[1]) * (q[1] - n->p[1]) +
                      (q[2] - n->p[2]) * (q[2] - n->p[2]);
    /* Ties keep the first found: the result may depend on the traversal, its distance does not. */
    if (!(d2 < n->d2)) return false;
    n->d2 = d2;
    memcpy(n->q, q, sizeof q);
    const float r = (float)sqrt(d2);
    if (r < args->query->radius) {
        args->query->radius = r; /* only closer triangles matter from here on */
        return true;
    }
    return false;
}

/* The surface point nearest p within `radius` (its squared distance; +inf and q untouched when
 * there is none). */
static double nearest_point(RTCScene scene, const pen_mesh *mesh, const double p[3], double radius,
                            double q[3]) {
    nearest n = {mesh, {p[0], p[1], p[2]}, HUGE_VAL, {0, 0, 0}};
    struct RTCPointQuery query;
    query.x = (float)p[0], query.y = (float)p[1], query.z = (float)p[2];
    query.radius = (float)radius * (1 + 1e-6f) + 1e-30f; /* float rounding must not drop it */
    query.time = 0;
    struct RTCPointQueryContext qc;
    rtcInitPointQueryContext(&qc);
    rtcPointQuery(scene, &query, &qc, nearest_visit, &n);
    if (n.d2 < HUGE_VAL) memcpy(q, n.q, sizeof n.q);
    return n.d2;
}

/* ---- Medial balls --------------------------------------------------------------------------- */

/* Unnormalised normal of triangle t, (b - a) x (c - a). */
static void tri_normal(const pen_mesh *m, unsigned t, double n[3]) {
    double a[3], b[3], c[3];
    corner(m, t, 0, a);
    corner(m, t, 1, b);
    corner(m, t, 2, c);
    const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[0] = u[1] * v[2] - u[2] * v[1];
    n[1] = u[2] * v[0] - u[0] * v[2];
    n[2] = u[0] * v[1] - u[1] * v[0];
}

/* +1 when the triangles wind counter-clockwise seen from outside (positive enclosed volume). */
static double orientation(const pen_mesh *m) {
    double v = 0;
    for (int t = 0; t < m->triangle_count; ++t) {
        double a[3], n[3];
        corner(m, (unsigned)t, 0, a);
        tri_normal(m, (unsigned)t, n);
        v += a[0] * n[0] + a[1] * n[1] + a[2] * n[2];
    }
    return v < 0 ? -1 : 1;
}

/* The chord from p along d to the first surface crossing, when that crossing leaves the mesh
 * (the hit triangle's outward normal along d); 0 otherwise. */
static double inward_chord(RTCScene scene, const pen_mesh *mesh, double sign, const double p[3],
                           const double d[3], double tnear) {
    struct RTCRayHit rh;
    memset(&rh, 0, sizeof rh);
    rh.ray.org_x = (float)p[0], rh.ray.org_y = (float)p[1], rh.ray.org_z = (float)p[2];
    rh.ray.dir_x = (float)d[0], rh.ray.dir_y = (float)d[1], rh.ray.dir_z = (float)d[2];
    rh.ray.tnear = (float)tnear;
    rh.ray.tfar = INFINITY;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    rtcIntersect1(scene, &ictx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return 0;
    double n[3];
    tri_normal(mesh, rh.hit.primID, n);
    return sign * (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) > 0 ? (double)rh.ray.tfar : 0;
}

/* Shrinks the ball tangent at p (inward unit normal d) from radius R until it holds no surface
 * point; returns the radius. */
static double shrink_ball(RTCScene scene, const pen_mesh *mesh, const double p[3], const double d[3],
                          double R, double r_floor) {
    for (int it = 0; it < 64 && R > r_floor; ++it) {
        const double c[3] = {p[0] + R * d[0], p[1] + R * d[1], p[2] + R * d[2]};
        double q[3] = {p[0], p[1], p[2]};
        const double d2 = nearest_point(scene, mesh, c, R, q);
        /* Empty up to rounding: the nearest point is the sample itself, at distance R. */
        if (!(d2 < R * R * (1 - 1e-6))) break;
        const double pq[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
        const double den = 2 * (d[0] * pq[0] + d[1] * pq[1] + d[2] * pq[2]);
        const double next = den > 0 ? (pq[0] * pq[0] + pq[1] * pq[1] + pq[2] * pq[2]) / den : 0;
        if (!(next < R)) break; /* no progress left in double precision */
        R = next;
    }
    return R > r_floor ? R : 0;
}

pen_status pen__fit_medial_balls(pen_context *ctx, const pen_mesh *mesh, const float *pts,
                                 const int *tri, int n, int threads, double *balls,
                                 double *thick) {
    double side;
    pen_status st = pen__fit_mesh_side(ctx, mesh, &side);
    if (st) return st;
    RTCDevice device = rtcNewDevice(PEN__FIT_EMBREE_CONFIG);
    if (!device) return pen__error(ctx, PEN_ERROR_INTERNAL, "fit: cannot create an Embree device");
    RTCScene scene = pen__fit_embree_scene(ctx, device, mesh, NULL);
    if (!scene) {
        rtcReleaseDevice(device);
        return pen_context_status(ctx);
    }
    const double sign = orientation(mesh);
    /* The ray starts past the sample's own triangle (float positions: about 1e-7 of the side);
     * balls smaller than this are no balls. */
    const double tnear = 1e-5 * side, r_floor = 1e-5 * side;
#pragma omp parallel for num_threads(threads) if (n >= 4096) schedule(dynamic, 64)
    for (int j = 0; j < n; ++j) {
        double *b = balls + 4 * (size_t)j;
        const double p[3] = {pts[3 * (size_t)j], pts[3 * (size_t)j + 1], pts[3 * (size_t)j + 2]};
        double nm[3];
        tri_normal(mesh, (unsigned)tri[j], nm);
        const double len = sqrt(nm[0] * nm[0] + nm[1] * nm[1] + nm[2] * nm[2]);
        b[0] = p[0], b[1] = p[1], b[2] = p[2], b[3] = 0;
        thick[j] = 0;
        if (!(len > 0)) continue;
        const double d[3] = {-sign * nm[0] / len, -sign * nm[1] / len, -sign * nm[2] / len};
        const double chord = inward_chord(scene, mesh, sign, p, d, tnear);
        thick[j] = 0.5 * chord;
        if (!(chord > 2 * r_floor)) continue;
        const double R = shrink_ball(scene, mesh, p, d, 0.5 * chord, r_floor);
        for (int a = 0; a < 3; ++a)
            b[a] = p[a] + R * d[a];
        b[3] = R;
    }
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    return PEN_OK;
}

/* ---- Allocation -------------------------------------------------------------------------------
 * The fit's energy trades covered surface samples (w_s each) against outside voxels (1 each); its
 * gradient acts only near the spheres, so which part gets how many spheres is decided where they
 * start and where spheres are moved. The allocation decides it on the hard version of that
 * energy, with thin parts weighted up: a sample counts clamp(r_ref / t, 1, PEN__FIT_THIN_MAX)
 * times (t its half-thickness, r_ref a share of the mesh's size, fit.c), because a tube far
 * thinner than the object costs much outside volume per covered sample, and by the energy alone a
 * chair's frame loses its spheres to the seat, while in its shadow the frame is what one misses.
 *
 * Candidates: each sample's medial ball, and the balls of 2 and 4 times its radius about the
 * same centre (on a tube: a ball reaching along and around it), clamped to [r_min, r_cap]. A
 * candidate's gain is w_s times the weight of the uncovered samples in it minus the outside
 * voxels in it; a sphere's loss is w_s times the weight of the samples only it covers minus the
 * outside voxels only it covers.
 *
 * Moves (pen__fit_alloc_move): the spheres of least loss, in turn, go to the candidate of largest
 * gain while the gain exceeds the loss by more than one sample's worth (lazy greedy over the
 * candidates, whose gains only fall as samples get covered); spheres next to a moved one wait for
 * the next round, since their loss has changed. The fit moves idle spheres (loss <= 0) this way.
 *
 * Spread (pen__fit_alloc_spread): below. */

/* Sample j's medial ball with radius min(its radius, r_cap) (moved to keep touching the sample),
 * at least r_min. */
static void capped_ball(const float *pts, const double *balls, int j, double r_cap, double r_min,
                        double out[4]) {
    const double *b = balls + 4 * (size_t)j;
    const float *p = pts + 3 * (size_t)j;
    const double r = fmin(b[3], r_cap), t = r / b[3];
    for (int a = 0; a < 3; ++a)
        out[a] = (double)p[a] + t * (b[a] - (double)p[a]);
    out[3] = fmax(r, r_min);
}

/* Outside voxel centres inside the ball c, estimated on a lattice of at most ~16 steps per axis
 * (each counted voxel stands for step^3); with sg, only those that no sphere of sph (in grid sg)
 * other than `self` holds. */
static double outside_in_ball(const pen__fit_grid *g, const double c[4], const pen__grid *sg,
                              const double *sph, int self) {
    const double R = c[3];
    int lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        lo[a] = (int)fmax(0, ceil((c[a] - R - g->origin[a]) / g->h));
        hi[a] = (int)fmin(g->n[a] - 1, floor((c[a] + R - g->origin[a]) / g->h));
        if (hi[a] < lo[a]) return 0;
    }
    const int step = (int)fmax(1, floor(2 * R / g->h / 16));
    long hits = 0;
    for (int k = lo[2]; k <= hi[2]; k += step)
        for (int j = lo[1]; j <= hi[1]; j += step)
            for (int x = lo[0]; x <= hi[0]; x += step) {
                const double p[3] = {g->origin[0] + g->h * x, g->origin[1] + g->h * j,
                                     g->origin[2] + g->h * k};
                const double dx = p[0] - c[0], dy = p[1] - c[1], dz = p[2] - c[2];
                if (dx * dx + dy * dy + dz * dz > R * R) continue;
                if (g->inside[x + (long)g->n[0] * (j + (long)g->n[1] * k)]) continue;
                int other = 0;
                long m = 0;
                const int *items = sg ? pen__grid_at(sg, p, &m) : NULL;
                for (long e = 0; e < m && !other; ++e) {
                    const double *s = sph + 4 * (size_t)items[e];
                    const double ex = p[0] - s[0], ey = p[1] - s[1], ez = p[2] - s[2];
                    other = items[e] != self && ex * ex + ey * ey + ez * ez <= s[3] * s[3];
                }
                hits += !other;
            }
    return (double)hits * step * step * step;
}

/* The weight of the uncovered samples inside the ball (with mark: marks them covered). */
static double uncovered_in_ball(const pen__fit_alloc *al, const double c[4], uint8_t *covered,
                                int mark) {
    int lo[3], hi[3];
    const double a[3] = {c[0] - c[3], c[1] - c[3], c[2] - c[3]};
    const double b[3] = {c[0] + c[3], c[1] + c[3], c[2] + c[3]};
    if (!pen__grid_range(&al->samples, a, b, lo, hi)) return 0;
    double u = 0;
    for (int z = lo[2]; z <= hi[2]; ++z)
        for (int y = lo[1]; y <= hi[1]; ++y)
            for (int x = lo[0]; x <= hi[0]; ++x) {
                long m;
                const int *items = pen__grid_cell(&al->samples, x, y, z, &m);
                for (long e = 0; e < m; ++e) {
                    const int j = items[e];
                    if (covered[j]) continue;
                    const float *p = al->pts + 3 * (size_t)j;
                    const double dx = (double)p[0] - c[0], dy = (double)p[1] - c[1],
                                 dz = (double)p[2] - c[2];
                    if (dx * dx + dy * dy + dz * dz > c[3] * c[3]) continue;
                    u += al->weight[j];
                    if (mark) covered[j] = 1;
                }
            }
    return u;
}

typedef struct heap_item {
    double gain;
    long cand;
} heap_item;

static int heap_above(heap_item a, heap_item b) {
    return a.gain > b.gain || (a.gain == b.gain && a.cand < b.cand);
}

static void heap_push(heap_item *h, long *n, heap_item x) {
    long i = (*n)++;
    while (i > 0 && heap_above(x, h[(i - 1) / 2])) {
        h[i] = h[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    h[i] = x;
}

static heap_item heap_pop(heap_item *h, long *n) {
    heap_item top = h[0], x = h[--*n];
    long i = 0;
    for (;;) {
        long c = 2 * i + 1;
        if (c >= *n) break;
        if (c + 1 < *n && heap_above(h[c + 1], h[c])) ++c;
        if (!heap_above(h[c], x)) break;
        h[i] = h[c];
        i = c;
    }
    if (*n > 0) h[i] = x;
    return top;
}

#define ALLOC_SIZES 3 /* candidate radii per sample, in medial radii: */
static const double ALLOC_SIZE[ALLOC_SIZES] = {1, 2, 4};

void pen__fit_alloc_free(pen__fit_alloc *a) {
    if (!a) return;
    free(a->weight), free(a->cand), free(a->cost);
    pen__grid_free(&a->samples);
    memset(a, 0, sizeof *a);
}

pen_status pen__fit_alloc_init(pen_context *ctx, pen__fit_alloc *a, const float *pts,
                               const double *balls, const double *thick, int n,
                               const pen__fit_grid *voxels,
                               double surface_weight, double r_ref, double r_cap, double r_min,
                               int threads) {
    memset(a, 0, sizeof *a);
    a->n = n, a->pts = pts, a->balls = balls, a->thick = thick, a->voxels = voxels;
    a->surface_weight = surface_weight, a->threads = threads;
    a->n_cand = (long)n * ALLOC_SIZES;
    a->weight = pen__malloc(ctx, (size_t)n + 1, sizeof(double), "fit: allocation");
    a->cand = pen__malloc(ctx, (size_t)a->n_cand + 1, 4 * sizeof(double), "fit: allocation");
    a->cost = pen__malloc(ctx, (size_t)a->n_cand + 1, sizeof(double), "fit: allocation");
    double *boxes = pen__malloc(ctx, (size_t)n + 1, 6 * sizeof(double), "fit: allocation");
    pen_status st = a->weight && a->cand && a->cost && boxes ? PEN_OK : PEN_ERROR_MEMORY;
    for (int j = 0; !st && j < n; ++j) {
        const double t = thick[j];
        a->weight[j] = t > 0 ? fmin(fmax(r_ref / t, 1), PEN__FIT_THIN_MAX) : 1;
        for (int k = 0; k < 3; ++k)
            boxes[6 * (size_t)j + k] = boxes[6 * (size_t)j + 3 + k] = pts[3 * (size_t)j + k];
    }
    if (!st) st = pen__grid_build(ctx, boxes, n, voxels->h, &a->samples);
    free(boxes);
    if (st) {
        pen__fit_alloc_free(a);
        return st;
    }
    for (long c = 0; c < a->n_cand; ++c) {
        const int j = (int)(c / ALLOC_SIZES), k = (int)(c % ALLOC_SIZES);
        const double *b = balls + 4 * (size_t)j;
        double *o = a->cand + 4 * c;
        o[0] = o[1] = o[2] = 0, o[3] = -1;
        if (!(b[3] > 0)) continue;
        const double R = fmin(fmax(b[3] * ALLOC_SIZE[k], r_min), r_cap);
        if (k > 0 && R <= fmin(fmax(b[3] * ALLOC_SIZE[k - 1], r_min), r_cap)) continue;
        if (R <= b[3])
            capped_ball(pts, balls, j, R, r_min, o);
        else
            o[0] = b[0], o[1] = b[1], o[2] = b[2], o[3] = R;
    }
#pragma omp parallel for num_threads(threads) if (a->n_cand >= 2048) schedule(dynamic, 64)
    for (long c = 0; c < a->n_cand; ++c)
        a->cost[c] =
            a->cand[4 * c + 3] > 0 ? outside_in_ball(voxels, a->cand + 4 * c, NULL, NULL, -1) : 0;
    return PEN_OK;
}

/* Flags (in blocked) the spheres of grid sg whose balls meet ball b. */
static void block_near(const pen__grid *sg, const double *sph, const double b[4], uint8_t *blocked) {
    int lo[3], hi[3];
    const double a0[3] = {b[0] - b[3], b[1] - b[3], b[2] - b[3]};
    const double a1[3] = {b[0] + b[3], b[1] + b[3], b[2] + b[3]};
    if (!pen__grid_range(sg, a0, a1, lo, hi)) return;
    for (int z = lo[2]; z <= hi[2]; ++z)
        for (int y = lo[1]; y <= hi[1]; ++y)
            for (int x = lo[0]; x <= hi[0]; ++x) {
                long m;
                const int *items = pen__grid_cell(sg, x, y, z, &m);
                for (long e = 0; e < m; ++e) {
                    const double *s = sph + 4 * (size_t)items[e];
                    const double dx = b[0] - s[0], dy = b[1] - s[1], dz = b[2] - s[2];
                    if (sqrt(dx * dx + dy * dy + dz * dz) <= b[3] + s[3]) blocked[items[e]] = 1;
                }
            }
}

typedef struct by_loss {
    double loss;
    int i;
} by_loss;

static int by_loss_cmp(const void *x, const void *y) {
    const by_loss *a = x, *b = y;
    if (a->loss != b->loss) return a->loss < b->loss ? -1 : 1;
    return (a->i > b->i) - (a->i < b->i);
}

int pen__fit_alloc_move(pen_context *ctx, pen__fit_alloc *a, double *sph, int count,
                        uint8_t *moved, double max_loss) {
    const int n = a->n;
    memset(moved, 0, (size_t)count);
    double *old = pen__malloc(ctx, (size_t)count, 4 * sizeof(double), "fit: allocation");
    uint8_t *covered = pen__calloc(ctx, (size_t)n + 1, 1, "fit: allocation");
    int *owner = pen__malloc(ctx, (size_t)n + 1, sizeof(int), "fit: allocation");
    by_loss *order = pen__malloc(ctx, (size_t)count, sizeof(by_loss), "fit: allocation");
    uint8_t *blocked = pen__calloc(ctx, (size_t)count, 1, "fit: allocation");
    heap_item *heap = pen__malloc(ctx, (size_t)a->n_cand + 1, sizeof(heap_item), "fit: allocation");
    double *boxes = pen__malloc(ctx, (size_t)count, 6 * sizeof(double), "fit: allocation");
    pen__grid sg;
    memset(&sg, 0, sizeof sg);
    int moves = -1;
    if (!old || !covered || !owner || !order || !blocked || !heap || !boxes) goto done;
    memcpy(old, sph, 4 * sizeof(double) * (size_t)count);
    double rsum = 0;
    for (int i = 0; i < count; ++i)
        rsum += sph[4 * (size_t)i + 3];
    pen__grid_sphere_boxes(sph, count, 0, boxes);
    if (pen__grid_build(ctx, boxes, count, fmax(2 * rsum / count, a->voxels->h), &sg)) goto done;
    /* Who covers each sample: owner is the only cover, -1 for none or several. */
    for (int j = 0; j < n; ++j) {
        const float *p = a->pts + 3 * (size_t)j;
        const double pd[3] = {p[0], p[1], p[2]};
        long m;
        const int *items = pen__grid_at(&sg, pd, &m);
        int covers = 0, who = -1;
        for (long e = 0; e < m && covers < 2; ++e) {
            const double *s = sph + 4 * (size_t)items[e];
            const double dx = pd[0] - s[0], dy = pd[1] - s[1], dz = pd[2] - s[2];
            if (dx * dx + dy * dy + dz * dz <= s[3] * s[3]) ++covers, who = items[e];
        }
        covered[j] = covers > 0;
        owner[j] = covers == 1 ? who : -1;
    }
    for (int i = 0; i < count; ++i)
        order[i] = (by_loss){0, i};
    for (int j = 0; j < n; ++j)
        if (owner[j] >= 0) order[owner[j]].loss += a->surface_weight * a->weight[j];
#pragma omp parallel for num_threads(a->threads) if (count >= 256) schedule(dynamic, 16)
    for (int i = 0; i < count; ++i)
        order[i].loss -= outside_in_ball(a->voxels, old + 4 * (size_t)i, &sg, old, i);
    qsort(order, (size_t)count, sizeof *order, by_loss_cmp);
    long hn = 0;
    for (long c = 0; c < a->n_cand; ++c) {
        if (!(a->cand[4 * c + 3] > 0)) continue;
        const double g =
            a->surface_weight * uncovered_in_ball(a, a->cand + 4 * c, covered, 0) - a->cost[c];
        if (g > 0) heap_push(heap, &hn, (heap_item){g, c});
    }
    moves = 0;
    for (int k = 0; k < count && hn > 0; ++k) {
        const int i = order[k].i;
        if (order[k].loss > max_loss) break;
        if (blocked[i]) continue;
        /* The best candidate now: pop until a fresh gain still tops the heap. */
        heap_item top;
        double g;
        for (;;) {
            top = heap_pop(heap, &hn);
            g = a->surface_weight * uncovered_in_ball(a, a->cand + 4 * top.cand, covered, 0) -
                a->cost[top.cand];
            if (hn == 0 || !heap_above(heap[0], (heap_item){g, top.cand})) break;
            heap_push(heap, &hn, (heap_item){g, top.cand});
        }
        /* Worth the move only by more than one sample (no churn between equals). */
        if (!(g > order[k].loss + a->surface_weight)) break;
        const double *b = a->cand + 4 * top.cand;
        memcpy(sph + 4 * (size_t)i, b, 4 * sizeof(double));
        moved[i] = 1;
        ++moves;
        uncovered_in_ball(a, b, covered, 1);
        /* The samples only sphere i covered are uncovered now (the next round sees them). */
        for (int j = 0; j < n; ++j)
            if (owner[j] == i) covered[j] = 0, owner[j] = -1;
        block_near(&sg, old, old + 4 * (size_t)i, blocked);
        block_near(&sg, old, b, blocked);
    }
done:
    pen__grid_free(&sg);
    free(old), free(covered), free(owner), free(order), free(blocked), free(heap), free(boxes);
    return moves;
}

/* ---- Spread: no part left far from the spheres ------------------------------------------------
 * The weighted moves still let a budget too small for everything skip a whole part (a chair's
 * seat is worth more per sphere than its legs, whatever the weights). The spread is the term
 * that cannot be met that way: while some sample lies more than tau / sqrt(weight) outside every
 * sphere, the cheapest sphere that no sample needs to stay within its limit moves to the worst
 * sample (as its best candidate); when every sphere is needed, the one whose samples stay nearest
 * without it moves, if that lowers the largest weighted gap (a swap of the k-centre local
 * search). Every part gets spheres, a chain along a tube, and a part that is covered anyway (a
 * blob's whole surface) sees no move. fit.c takes tau = max(3 % of the mesh's size, r_N), so that
 * a budget of a few spheres is not spent on a body's small extremities. */

typedef struct gaps {
    double g1, g2; /* the two smallest gaps (g2 may be +inf) */
    int a1;        /* the sphere of g1 */
} gaps;

/* Two smallest gaps of every sample; spheres in sg (reach tau) and a brute-force pass for the
 * samples that have no sphere within tau. */
static void sample_gaps(const pen__fit_alloc *a, const pen__grid *sg, const double *sph, int count,
                        double tau, gaps *out) {
#pragma omp parallel for num_threads(a->threads) if ((double)a->n * 16 >= 4e6) schedule(static)
    for (int j = 0; j < a->n; ++j) {
        const float *p = a->pts + 3 * (size_t)j;
        const double pd[3] = {p[0], p[1], p[2]};
        gaps g = {HUGE_VAL, HUGE_VAL, -1};
        long m;
        const int *items = pen__grid_at(sg, pd, &m);
        int brute = 0;
        for (int pass = 0; pass < 2; ++pass) {
            const long end = pass == 0 ? m : (brute ? count : 0);
            for (long e = 0; e < end; ++e) {
                const int i = pass == 0 ? items[e] : (int)e;
                const double *s = sph + 4 * (size_t)i;
                const double dx = pd[0] - s[0], dy = pd[1] - s[1], dz = pd[2] - s[2];
                const double d = sqrt(dx * dx + dy * dy + dz * dz) - s[3];
                if (d < g.g1 || (d == g.g1 && i < g.a1)) {
                    g.g2 = g.g1;
                    g.g1 = d, g.a1 = i;
                } else if (d < g.g2) {
                    g.g2 = d;
                }
            }
            if (pass == 0 && (brute = !(g.g1 <= tau))) g = (gaps){HUGE_VAL, HUGE_VAL, -1};
        }
        out[j] = g;
    }
}

int pen__fit_alloc_spread(pen_context *ctx, pen__fit_alloc *a, double *sph, int count, double tau,
                          int max_moves, uint8_t *moved) {
    const int n = a->n;
    double *w = pen__malloc(ctx, (size_t)n + 1, sizeof(double), "fit: spread");
    for (int j = 0; w && j < n; ++j) /* the gap a sample may keep: tau / sqrt(its weight) */
        w[j] = sqrt(a->weight[j]);
    gaps *g = pen__malloc(ctx, (size_t)n + 1, sizeof(gaps), "fit: spread");
    uint8_t *needed = pen__malloc(ctx, (size_t)count, 1, "fit: spread");
    uint8_t *covered = pen__malloc(ctx, (size_t)n + 1, 1, "fit: spread");
    double *loss = pen__malloc(ctx, (size_t)count, sizeof(double), "fit: spread");
    double *without = pen__malloc(ctx, (size_t)count, sizeof(double), "fit: spread");
    double *boxes = pen__malloc(ctx, (size_t)count, 6 * sizeof(double), "fit: spread");
    pen__grid sg;
    memset(&sg, 0, sizeof sg);
    int moves = -1;
    if (!w || !g || !needed || !covered || !loss || !without || !boxes) goto done;
    double rsum = 0;
    for (int i = 0; i < count; ++i)
        rsum += sph[4 * (size_t)i + 3];
    const double cell = fmax(2 * (rsum / count + tau), a->voxels->h);
    for (moves = 0; moves < max_moves; ++moves) {
        /* Gaps within tau (a sample's own limit is tau / its weight, never more than tau). */
        pen__grid_sphere_boxes(sph, count, tau, boxes);
        if (pen__grid_build(ctx, boxes, count, cell, &sg)) goto fail;
        sample_gaps(a, &sg, sph, count, tau, g);
        pen__grid_free(&sg);
        int worst = -1; /* among the samples with a ball: the others have no candidate */
        for (int j = 0; j < n; ++j)
            if (a->balls[4 * (size_t)j + 3] > 0 &&
                (worst < 0 || g[j].g1 * w[j] > g[worst].g1 * w[worst]))
                worst = j;
        if (worst < 0 || !(g[worst].g1 * w[worst] > tau)) break;
        /* Spheres that some sample needs to stay within its limit; the others' loss (samples
         * only they cover, as in the moves; the outside volume below). */
        memset(needed, 0, (size_t)count);
        for (int i = 0; i < count; ++i)
            loss[i] = 0;
        for (int j = 0; j < n; ++j) {
            const double lim = tau / w[j];
            if (g[j].g1 <= lim && !(g[j].g2 <= lim)) needed[g[j].a1] = 1;
            covered[j] = g[j].g1 <= 0;
            if (g[j].g1 <= 0 && !(g[j].g2 <= 0)) loss[g[j].a1] += a->surface_weight * w[j];
        }
        pen__grid_sphere_boxes(sph, count, 0, boxes);
        if (pen__grid_build(ctx, boxes, count, cell, &sg)) goto fail;
        int best = -1;
        for (int i = 0; i < count; ++i) {
            loss[i] -= outside_in_ball(a->voxels, sph + 4 * (size_t)i, &sg, sph, i);
            if (!needed[i] && (best < 0 || loss[i] < loss[best])) best = i;
        }
        pen__grid_free(&sg);
        if (best < 0) {
            /* Every sphere keeps some sample within its limit (the budget cannot meet tau): move
             * the one whose samples stay nearest without it, when that is below the worst (a
             * swap of the k-centre local search: the largest weighted gap falls). */
            const double worst_gap = g[worst].g1 * w[worst];
            pen__grid_sphere_boxes(sph, count, worst_gap, boxes);
            if (pen__grid_build(ctx, boxes, count, cell, &sg)) goto fail;
            sample_gaps(a, &sg, sph, count, worst_gap, g);
            pen__grid_free(&sg);
            for (int i = 0; i < count; ++i)
                without[i] = -HUGE_VAL;
            for (int j = 0; j < n; ++j)
                if (g[j].a1 >= 0 && g[j].g1 * w[j] <= worst_gap)
                    without[g[j].a1] = fmax(without[g[j].a1], g[j].g2 * w[j]);
            for (int i = 0; i < count; ++i)
                if (without[i] < 0.9 * worst_gap &&
                    (best < 0 || without[i] < without[best] ||
                     (without[i] == without[best] && loss[i] < loss[best])))
                    best = i;
        }
        if (best < 0) break;
        /* The worst sample's candidate of largest gain (each of them holds the sample). */
        long pick = -1;
        double pick_gain = -HUGE_VAL;
        for (int k = 0; k < ALLOC_SIZES; ++k) {
            const long c = (long)worst * ALLOC_SIZES + k;
            if (!(a->cand[4 * c + 3] > 0)) continue;
            const double gain =
                a->surface_weight * uncovered_in_ball(a, a->cand + 4 * c, covered, 0) - a->cost[c];
            if (gain > pick_gain) pick = c, pick_gain = gain;
        }
        if (pick < 0) break;
        memcpy(sph + 4 * (size_t)best, a->cand + 4 * pick, 4 * sizeof(double));
        moved[best] = 1;
    }
    goto done;
fail:
    moves = -1;
done:
    pen__grid_free(&sg);
    free(g), free(needed), free(covered), free(loss), free(without), free(boxes), free(w);
    return moves;
}
