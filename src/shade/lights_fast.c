/* The disk lights in the machine's vector lanes, compiled once per instruction set like the fast
 * kernel (CMakeLists.txt, shade_fast_dispatch.c): the float prefilter of the backward's pairs
 * (pen__lights_candidates) and the fast kernel's forward light term (pen__lights_fwd_block).
 *
 * Design
 * - The prefilter only drops pairs, and only those that the double tests in lights.c
 *   (sphere_view_weight, cap_may_reach) drop too, so the backward's light term and gradients are
 *   bit for bit what the unfiltered loop gives, in every variant (the golden test checks it).
 * - The forward block (docs/design.md sec. 1.13, "Precision") runs the per-pixel term itself in
 *   float lanes, PEN_LIGHTS_BLOCK receivers against each of the tile's spheres: the cosine D,
 *   the sphere's weight w and opacity q = 1 - exp(-eps w kappa), the cap, and each light's
 *   fraction f when it is 0 (the disk clear of the cap) or 1 (wholly inside), told from float
 *   cosines with a margin (LANE_MARGIN) far above their rounding, so that f is exactly the double
 *   path's there. Only the partial overlaps (the penumbrae) take the double lens: a disk's from
 *   PEN_LIGHTS_COS_LENS_DEG up (the cosine form's arithmetic) in double lanes, a block's partial
 *   pairs packed (wide_lens), a narrower one's one pair at a time in lights.c; a disk across its
 *   receiver's horizon takes the clamped cosine in double (lanes_init). Receivers that no light
 *   reaches take no pairs, and a sphere clear of every disk at all of the others, by the tile
 *   cull's test for a ball around them (block_bound), costs that one test. What differs from
 *   pen__lights_fwd is the float rounding of D, w, q and the product (a few 1e-7 of the light,
 *   below the image's own float rounding; tests/test_lights_lanes.c compares the two).
 * - The backward block (pen__lights_bwd_block) visits the same pairs: where f is 0 or 1 it is
 *   constant, so such a pair's gradient is its weight's alone (through q to the sphere, x and
 *   n), taken in lanes in two passes (every pair's d/dw first, then the weights' chain); a
 *   partial pair adds f's own derivatives in double (wide_bwd in the double lanes, else
 *   pen__lights_pair_bwd) during the first; the per-light chain (rho, the light, its horizon
 *   factor, n) in lanes too. Only a receiver without the forward's V (or not finite) takes
 *   pen__lights_bwd whole, and every receiver of a block where eps kappa reaches 400 (a factor
 *   that could fall below the double term's 1e-200).
 */
#include "core/internal.h"
#include "shade/shade.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#ifndef PEN_FAST_ISA
#define PEN_FAST_ISA generic
#endif
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)

void CAT(pen__lights_candidates_,
         PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres, const int *idx, int cnt,
                       const float *x, const float *nrm, const int *at, int *list, int *count);
void CAT(pen__lights_fwd_block_,
         PEN_FAST_ISA)(const pen__lights *L, const double *G, int n, const float *spheres,
                       const float *kappa, const int *idx, int cnt, const float *x,
                       const float *nrm, const float *rho, const int *at, float *rgb, float *V_out);
void CAT(pen__lights_bwd_block_,
         PEN_FAST_ISA)(const pen__lights *L, const double *G, int n, const float *spheres,
                       const float *kappa, const int *idx, int cnt, const float *x,
                       const float *nrm, const float *rho, const float *d_rgb, const float *V_in,
                       const int *pix, void *scratch, double *d_spheres, float *d_x, float *d_n,
                       float *d_rho, double *d_lights, double *d_G);

/* Receivers and spheres in float, PEN_LIGHTS_BLOCK receivers at a time over one sphere, so that
 * the compiler keeps them in vector lanes. A pair is dropped only when the exact double tests
 * above would drop it too: the receiver deeper than 0.9 r inside the sphere (sphere_view_weight's
 * inside rule), the sphere below the receiver's tangent plane (n . v <= -r), or every light's
 * disk certainly clear of the cap (cap_may_reach). The margins cover the float rounding of v,
 * n . v, v . w and the squares (a few 1e-7 of |v| + r) many times over; a pair that a margin keeps
 * costs only the exact test. NaN receivers are kept (no comparison drops them). */
void CAT(pen__lights_candidates_,
         PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres, const int *idx, int cnt,
                       const float *x, const float *nrm, const int *at, int *list, int *count) {
    float X[3][PEN_LIGHTS_BLOCK], N[3][PEN_LIGHTS_BLOCK];
    float w[PEN_SCENE_MAX_LIGHTS][3], sb[PEN_SCENE_MAX_LIGHTS], cb2[PEN_SCENE_MAX_LIGHTS];
    for (int l = 0; l < L->count; ++l) {
        for (int a = 0; a < 3; ++a)
            w[l][a] = (float)L->w[l][a];
        sb[l] = (float)L->sin_b[l], cb2[l] = (float)(L->cos_b[l] * L->cos_b[l]);
    }
    for (int k = 0; k < PEN_LIGHTS_BLOCK; ++k) {
        const size_t i = k < cnt ? (size_t)(at ? at[k] : k) : (size_t)(at ? at[0] : 0);
        for (int a = 0; a < 3; ++a)
            X[a][k] = x[3 * i + a], N[a][k] = nrm[3 * i + a];
        if (k < cnt) count[k] = 0;
    }
    const float cont = (float)(1.0 - PEN_SH_CAP_T0) * 0.999f; /* cap_may_reach's continued cap */
    const float h0 = (float)PEN_RENDER_SELF_H0;
    const float deep = (float)(0.99 * PEN_RENDER_INSIDE_LO * PEN_RENDER_INSIDE_LO);
    for (int j = 0; j < n; ++j) {
        const int i = idx ? idx[j] : j;
        const float *sp = spheres + 4 * (size_t)i, r = sp[3], r2 = r * r;
        float vx[PEN_LIGHTS_BLOCK], vy[PEN_LIGHTS_BLOCK], vz[PEN_LIGHTS_BLOCK];
        float D2[PEN_LIGHTS_BLOCK], tol[PEN_LIGHTS_BLOCK], m2[PEN_LIGHTS_BLOCK];
        int keep[PEN_LIGHTS_BLOCK], clear[PEN_LIGHTS_BLOCK];
        for (int k = 0; k < PEN_LIGHTS_BLOCK; ++k) {
            vx[k] = sp[0] - X[0][k], vy[k] = sp[1] - X[1][k], vz[k] = sp[2] - X[2][k];
            D2[k] = vx[k] * vx[k] + vy[k] * vy[k] + vz[k] * vz[k];
            const float m = fabsf(vx[k]) + fabsf(vy[k]) + fabsf(vz[k]) + r;
            tol[k] = 1e-5f * m, m2[k] = 1e-5f * m * m;
            const float nv = N[0][k] * vx[k] + N[1][k] * vy[k] + N[2][k] * vz[k];
            keep[k] = !(nv < h0 * r - tol[k]) & !(D2[k] < deep * r2);
            clear[k] = !(D2[k] * cont <= r2); /* else the continued cap: kept */
        }
        for (int l = 0; l < L->count; ++l)
            for (int k = 0; k < PEN_LIGHTS_BLOCK; ++k) {
                const float lhs = vx[k] * w[l][0] + vy[k] * w[l][1] + vz[k] * w[l][2] + r * sb[l];
                clear[k] &= (lhs < -tol[k]) | (lhs * lhs < (D2[k] - r2) * cb2[l] - m2[k]);
            }
        for (int k = 0; k < cnt; ++k)
            if (keep[k] & !clear[k]) list[(size_t)k * (size_t)n + (size_t)count[k]++] = i;
    }
}

/* The cosines' margin of the forward block: float v carries 6e-8 of its length, cos a (from
 * t >= PEN_SH_CAP_T0) and cos g a few 1e-7, so a disk the float cosines put 1e-5 clear of the
 * cap's edge is clear of it in double too (and likewise inside), where lights.c's own margin is
 * 1e-9. Pairs within the margin take the double lens: the penumbra, widened by 2e-5 in cos g. */
#define LANE_MARGIN 1e-5f

/* exp(-y), y >= 0, in lanes: 2^z with z = -y log2 e split into the nearest integer m and
 * r in [-1/2, 1/2], e^(r ln 2) by its Taylor series to degree 6 (relative error 1.2e-7 at
 * |r ln 2| = 0.347) and 2^m put into the exponent; z is held above -125 (then q = 1 to float).
 * The clamp is written so that a NaN y (a lane the double term takes, or padding) is held too:
 * the float-to-integer conversion below never sees a NaN. */
static inline float exp_neg(float y) {
    float z = -y * 1.44269504f;
    z = z > -125.0f ? z : -125.0f;
    const float m = (z + 12582912.0f) - 12582912.0f; /* round to nearest, |z| < 2^22 */
    const float t = (z - m) * 0.693147181f;
    const float p =
        1.0f +
        t * (1.0f + t * (0.5f + t * (1.0f / 6 + t * (1.0f / 24 + t * (1.0f / 120 + t / 720)))));
    const uint32_t bits = (uint32_t)((int32_t)m + 127) << 23;
    float two_m;
    memcpy(&two_m, &bits, sizeof two_m);
    return p * two_m;
}

enum { B = PEN_LIGHTS_BLOCK, LMAX = PEN_SCENE_MAX_LIGHTS };

/* Before a loop over the block's lanes whose body selects: GCC 12 unrolls such a loop of 16 whole
 * before it vectorises, and the unrolled selections become branches, lane by lane. */
#define LANES _Pragma("GCC unroll 1")

/* A block's receivers in lanes and what is the same for all of its pairs. */
typedef struct lanes {
    int K;
    float X[3][B], N[3][B];
    float Dl[LMAX][B]; /* the disk's clamped cosine D (n . w where wholly above the horizon) */
    float dDc[LMAX][B], dDb[LMAX][B]; /* its partials by n . w and by b */
    float c[LMAX][B];                 /* n . w */
    int cross[LMAX][B];               /* the disk across the horizon */
    int exact[B];                     /* the double term's: a point not finite */
    int wide[LMAX];                   /* the disk's penumbrae in double lanes (wide_lens) */
    double m[3], R; /* a ball around the receivers that need their pairs (block_bound) */
    float w[LMAX][3], sb[LMAX], cb[LMAX], cb2[LMAX];
    float eps, h0, inv_span, lo, inv_width, t0, s0, cont, deep;
} lanes;

/* The sum of v over the lanes that use marks, in float, by halving (block_bound's mean). */
static inline float lane_sum(const float v[B], const int use[B]) {
    float h[B];
    LANES
    for (int k = 0; k < B; ++k)
        h[k] = use[k] ? v[k] : 0.0f;
    for (int w = B / 2; w >= 1; w /= 2)
        for (int k = 0; k < w; ++k)
            h[k] += h[k + w];
    return h[0];
}

/* Fills the block's lanes from the points and normals at pt + 3 at(k) (padding lanes repeat the
 * first receiver). The disk wholly above the horizon is c >= sin b with room for the float
 * cosine: D = c; one across it takes the clamped integral in double (pen__disk_clamped_cosine)
 * from the float c, whose rounding moves D by as much (|dD/dc| <= 1), as it moves c above. The
 * visibility does not depend on the horizon, so such a receiver stays in the lanes. */
static void lanes_init(lanes *z, const pen__lights *L, int cnt, const float *x, const float *nrm,
                       const int *at) {
    const int K = z->K = L->count;
    for (int l = 0; l < K; ++l) {
        for (int a = 0; a < 3; ++a)
            z->w[l][a] = (float)L->w[l][a];
        z->sb[l] = (float)L->sin_b[l], z->cb[l] = (float)L->cos_b[l];
        z->cb2[l] = (float)(L->cos_b[l] * L->cos_b[l]);
        z->wide[l] = L->b[l] >= PEN_LIGHTS_COS_LENS_DEG * (PEN_PI / 180.0);
    }
    if (!at && cnt == B) /* consecutive receivers: a loop the compiler can take in lanes */
        for (int k = 0; k < B; ++k)
            for (int a = 0; a < 3; ++a)
                z->X[a][k] = x[3 * k + a], z->N[a][k] = nrm[3 * k + a];
    else
        for (int k = 0; k < B; ++k) {
            const int kk = k < cnt ? k : 0;
            const size_t i = (size_t)(at ? at[kk] : kk);
            for (int a = 0; a < 3; ++a)
                z->X[a][k] = x[3 * i + a], z->N[a][k] = nrm[3 * i + a];
        }
    for (int k = 0; k < B; ++k) /* apart from the gather, which keeps a loop scalar */
        z->exact[k] = !(z->X[0][k] - z->X[0][k] == 0.0f) | !(z->X[1][k] - z->X[1][k] == 0.0f) |
                      !(z->X[2][k] - z->X[2][k] == 0.0f);
    for (int l = 0; l < K; ++l)
        for (int k = 0; k < B; ++k) {
            const float c =
                z->N[0][k] * z->w[l][0] + z->N[1][k] * z->w[l][1] + z->N[2][k] * z->w[l][2];
            const int above = c >= z->sb[l] + LANE_MARGIN;
            z->Dl[l][k] = above ? c : 0.0f;
            z->dDc[l][k] = above ? 1.0f : 0.0f, z->dDb[l][k] = 0.0f;
            z->cross[l][k] = !above & !(c <= -z->sb[l] - LANE_MARGIN);
            z->exact[k] |= !(c == c); /* a normal not finite: the double term's unlit light */
            z->c[l][k] = c;
        }
    for (int l = 0; l < K; ++l)
        for (int k = 0; k < B; ++k)
            if (z->cross[l][k]) {
                double dc, db;
                z->Dl[l][k] =
                    (float)pen__disk_clamped_cosine((double)z->c[l][k], L->b[l], &dc, &db);
                z->dDc[l][k] = (float)dc, z->dDb[l][k] = (float)db;
            }
    z->eps = (float)L->eps;
    z->h0 = (float)PEN_RENDER_SELF_H0;
    z->inv_span = (float)(1.0 / (PEN_RENDER_SELF_H1 - PEN_RENDER_SELF_H0));
    z->lo = (float)PEN_RENDER_INSIDE_LO, z->inv_width = (float)(1.0 / PEN_RENDER_INSIDE_WIDTH);
    z->t0 = (float)PEN_SH_CAP_T0, z->s0 = sqrtf(z->t0);
    z->cont = (float)(1.0 - PEN_SH_CAP_T0) * 0.999f; /* as pen__lights_candidates */
    z->deep = (float)(0.99 * PEN_RENDER_INSIDE_LO * PEN_RENDER_INSIDE_LO);
}

/* Marks in skip the lanes that need no pairs, besides those already marked: padding, and receivers
 * that no light reaches (D = 0: their V is not used, forward or backward), and sets the ball
 * (m, R) around the rest that pen__lights_may_shadow tests each sphere against, so that a sphere
 * that shadows none of them costs one test instead of the lanes' (exact: such a sphere's pairs are
 * all clear, f = 0, and add nothing). Returns 0 when no lane needs its pairs. */
static int block_bound(lanes *z, int cnt, int skip[B]) {
    int lit[B], use[B], n = 0;
    for (int k = 0; k < B; ++k)
        lit[k] = 0;
    for (int l = 0; l < z->K; ++l)
        for (int k = 0; k < B; ++k)
            lit[k] |= z->Dl[l][k] > 0.0f;
    for (int k = 0; k < B; ++k) {
        skip[k] |= !lit[k] | (k >= cnt);
        use[k] = !skip[k];
        n += use[k];
    }
    if (!n) return 0;
    /* the centre: the mean; the radius: the largest distance from it, found on the squares' bits
     * (non-negative floats order as their bits do, and an integer maximum stays in lanes), then
     * widened by far more than the float rounding of the squares (a few 1e-7 of them) */
    float m[3];
    for (int a = 0; a < 3; ++a)
        m[a] = lane_sum(z->X[a], use) / (float)n;
    int32_t bits[B], top = 0;
    LANES
    for (int k = 0; k < B; ++k) {
        const float dx = z->X[0][k] - m[0], dy = z->X[1][k] - m[1], dz = z->X[2][k] - m[2];
        const float d2 = use[k] ? dx * dx + dy * dy + dz * dz : 0.0f;
        memcpy(&bits[k], &d2, sizeof d2);
    }
    for (int k = 0; k < B; ++k)
        top = bits[k] > top ? bits[k] : top;
    float d2max;
    memcpy(&d2max, &top, sizeof d2max);
    for (int a = 0; a < 3; ++a)
        z->m[a] = (double)m[a];
    z->R =
        sqrt((double)d2max) * (1.0 + 1e-6) + 1e-9 * (fabs(z->m[0]) + fabs(z->m[1]) + fabs(z->m[2]));
    /* receivers near the float range's end (a mean that overflows, or a NaN from inf - inf):
     * a ball that holds everything, so that every sphere is kept */
    if (!(z->R < HUGE_VAL)) z->m[0] = z->m[1] = z->m[2] = 0.0, z->R = HUGE_VAL;
    return 1;
}

/* The pairs of one sphere (centre and radius sp, overlap weight kap) with the block's lanes that
 * skip[k] leaves: on[k] where its weight is above 0, y[k] = eps w kappa, ex[k] = exp(-y) (the
 * pair's factor where the disk is inside the cap: 1 - q), and per light l the lanes on whose disk
 * is wholly inside the cap (in[l][k]) or partly (part[l][k], the double lens; any_part[l] where
 * any lane is), the rest clear of it. Returns 0, with nothing filled, when no lane is on. The
 * classes are flags, not one code per lane: the callers' loops over them then stay in lanes. First
 * the prefilter's tests (pen__lights_candidates), for the spheres that pen__lights_may_shadow
 * keeps: most of those still shadow none of the block's receivers, and cost only these. Both arms
 * of every choice are computed and then selected, so that the compiler keeps the loops in lanes. */
static inline __attribute__((always_inline)) int sphere_pairs(const lanes *z, const int *skip,
                                                              const float *sp, float kap, int on[B],
                                                              float y[B], float ex[B], int in[][B],
                                                              int part[][B], int any_part[]) {
    const float r = sp[3], r2 = r * r, m = LANE_MARGIN;
    float vx[B], vy[B], vz[B], D2[B], nv[B], tol[B], m2[B], Dd[B], ca[B], sa[B];
    int whole[B], any = 0;
    for (int k = 0; k < B; ++k) {
        vx[k] = sp[0] - z->X[0][k], vy[k] = sp[1] - z->X[1][k], vz[k] = sp[2] - z->X[2][k];
        D2[k] = vx[k] * vx[k] + vy[k] * vy[k] + vz[k] * vz[k];
        nv[k] = z->N[0][k] * vx[k] + z->N[1][k] * vy[k] + z->N[2][k] * vz[k];
        const float mk = fabsf(vx[k]) + fabsf(vy[k]) + fabsf(vz[k]) + r;
        tol[k] = 1e-5f * mk, m2[k] = 1e-5f * mk * mk;
        on[k] = !(nv[k] < z->h0 * r - tol[k]) & !(D2[k] < z->deep * r2) & !skip[k];
        whole[k] = !(D2[k] * z->cont <= r2); /* here: clear of every light so far */
    }
    for (int l = 0; l < z->K; ++l)
        for (int k = 0; k < B; ++k) {
            const float lhs =
                vx[k] * z->w[l][0] + vy[k] * z->w[l][1] + vz[k] * z->w[l][2] + r * z->sb[l];
            whole[k] &= (lhs < -tol[k]) | (lhs * lhs < (D2[k] - r2) * z->cb2[l] - m2[k]);
        }
    LANES
    for (int k = 0; k < B; ++k) {
        on[k] &= !whole[k] & (kap != 0.0f);
        any |= on[k];
    }
    if (!any) return 0;
    for (int k = 0; k < B; ++k) {
        const float u = (nv[k] / r - z->h0) * z->inv_span;
        Dd[k] = sqrtf(D2[k]);
        const float e = (Dd[k] / r - z->lo) * z->inv_width;
        on[k] &= (u > 0.0f) & (e > 0.0f);
        const float whp = u * u * (3.0f - 2.0f * u), gp = e * e * (3.0f - 2.0f * e);
        const float wh = u < 1.0f ? whp : 1.0f, g = e < 1.0f ? gp : 1.0f;
        y[k] = z->eps * wh * g * kap;
        ex[k] = exp_neg(y[k]);
        /* the cap, continued below t0 as sh.h continues it. Near the continued cap's end
         * (cc -> -1, D/r -> 0.909) sin a = sqrt(1 - cc^2) amplifies the float rounding of cc
         * (~1.5e-6: t's few 1e-7 times 1/(2 s0) = 5) by |cc|/sin a; from cc <= -0.9 (D/r <=
         * 0.917, receivers just inside the sphere) that passes 3e-6 and would eat the margin,
         * so those pairs, and a whole-sphere cap, are left to the double lens */
        const float t = 1.0f - r2 / D2[k];
        const float cc = z->s0 + (t - z->t0) * (0.5f / z->s0);
        const float s2 = (1.0f - cc) * (1.0f + cc);
        const float st = sqrtf(t > 0.0f ? t : 0.0f), sc = sqrtf(s2 > 0.0f ? s2 : 0.0f);
        const float ra = r / Dd[k];
        ca[k] = t >= z->t0 ? st : cc;
        sa[k] = t >= z->t0 ? ra : sc;
        whole[k] = !(t >= z->t0) & !(cc > -0.9f);
    }
    for (int l = 0; l < z->K; ++l) {
        const float wx = z->w[l][0], wy = z->w[l][1], wz = z->w[l][2];
        const float cb = z->cb[l], sb = z->sb[l];
        int ap = 0;
        for (int k = 0; k < B; ++k) {
            const float cg = (vx[k] * wx + vy[k] * wy + vz[k] * wz) / Dd[k];
            const float A = sa[k] * cb + ca[k] * sb, Bm = sa[k] * cb - ca[k] * sb;
            const float C1 = ca[k] * cb - sa[k] * sb, C2 = ca[k] * cb + sa[k] * sb;
            const int clear = (A > m) & (cg < C1 - m) & !whole[k];
            const int inside = (Bm > m) & (cg > C2 + m) & !whole[k];
            in[l][k] = on[k] & !clear & inside;
            part[l][k] = on[k] & !clear & !inside;
            ap |= part[l][k];
        }
        any_part[l] = ap;
    }
    return 1;
}

/* ---- The wide disks' penumbrae in double lanes ------------------------------------------------
 */

typedef long long lmask; /* a lane's flag, as wide as a double: masks of one width vectorise */

/* atan(x) in lanes, to a few ulps: |x| > 1 through pi/2 - atan(1/|x|), then above tan(pi/12)
 * through pi/6 + atan((t - 1/sqrt 3) / (1 + t/sqrt 3)), which leaves |u| <= tan(pi/12) = 0.268
 * for the odd Taylor series to u^25 (its first term left out, 0.268^27/27, is below 1e-16 of u). */
static inline double atan_lane(double x) {
    const double ax = fabs(x), inv = 1.0 / ax;
    const lmask big = ax > 1.0;
    const double t = big ? inv : ax;
    const lmask mid = t > 0.26794919243112270; /* tan(pi/12) */
    const double u = mid ? (t - 0.57735026918962576) / (1.0 + t * 0.57735026918962576) : t;
    const double u2 = u * u;
    double p = 1.0 / 25;
    for (int n = 23; n >= 1; n -= 2)
        p = p * u2 + ((n / 2) % 2 ? -1.0 : 1.0) / n;
    const double a = (mid ? 0.52359877559829887 : 0.0) + u * p;
    const double b = big ? 1.5707963267948966 - a : a;
    return x < 0.0 ? -b : b;
}

/* atan2(s, c) for s > 0 with one atan, as lights.c's angle_of. */
static inline double angle_lane(double s, double c) {
    const lmask pos = c > 0.0;
    const double a = atan_lane(pos ? s / c : c / s);
    return pos ? a : 1.5707963267948966 - a;
}

/* One light's partial pairs with one sphere, in double lanes, for the disks from
 * PEN_LIGHTS_COS_LENS_DEG up, whose lens is the cosine form (lights.c, pen__cap_overlap_cos)
 * with no angle but three arctangents: what lights.c's disk_fraction computes for the pair, in
 * the same steps and order (the double cap test, the cap and its continuation, the 1e-9 clear
 * and inside tests, the lens), lane by lane. The pairs are the np lanes P[0 .. np) of the block,
 * packed (a block has a few penumbra receivers, and each costs ~100 double operations), so pair p
 * is lane P[p]: f[p] is its fraction and fa, fb, fg the partials by a, b and g (disk_fraction's
 * fd); back[p] marks the pairs this form does not take (the cap past a = pi or a centre at the
 * receiver, a lens the cosine form declines or rounds below 0): the caller takes those pair by
 * pair in lights.c, as the narrow disks' penumbrae. */
typedef struct wide_pairs {
    double f[B], fa[B], fb[B], fg[B];
    double d[3][B], D[B], cg[B], sg[B], da_dD[B], da_dr[B];
    lmask back[B];
} wide_pairs;

static inline __attribute__((always_inline)) void wide_lens(const lanes *z, const pen__lights *L,
                                                            int l, const float *sp, const int *P,
                                                            int np, wide_pairs *o) {
    const double r = (double)sp[3], r2 = r * r, t0 = PEN_SH_CAP_T0, s0 = sqrt(PEN_SH_CAP_T0);
    const double *w = L->w[l], cb = L->cos_b[l], sb = L->sin_b[l], area = L->area[l];
    /* the pairs' points, padded to whole vectors of doubles by repeating the last: in a loop of
     * its own, as a loop that mixes float and double, or gathers, stays scalar */
    const int npad = (np + 3) & ~3;
    double Xd[3][B];
    for (int p = 0; p < npad; ++p) {
        const int k = P[p < np ? p : np - 1];
        for (int a = 0; a < 3; ++a)
            Xd[a][p] = (double)z->X[a][k];
    }
    for (int k = 0; k < npad; ++k) { /* k: the pair */
        const double v[3] = {(double)sp[0] - Xd[0][k], (double)sp[1] - Xd[1][k],
                             (double)sp[2] - Xd[2][k]};
        const double D2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        /* cap_may_reach */
        const double lhs = v[0] * w[0] + v[1] * w[1] + v[2] * w[2] + r * sb;
        const lmask reach =
            (D2 * (1.0 - t0) <= r2) | ((lhs > 0.0) & (lhs * lhs > (D2 - r2) * cb * cb));
        /* sphere_view_cap */
        const double D = sqrt(D2), Dd = D > 1e-6 * r ? D : 1.0;
        const double t = 1.0 - r2 / (Dd * Dd);
        const lmask cont = !(t >= t0);
        const double cc = s0 + (t - t0) * (0.5 / s0);
        /* x > 0 ? x : 0, not fmax: fmax's NaN rule keeps the loop out of the vector lanes */
        const double s2 = (1.0 - cc) * (1.0 + cc), sc = sqrt(s2 > 0.0 ? s2 : 0.0);
        const double st = sqrt(t > 0.0 ? t : 0.0);
        const double ca = cont ? cc : st, sa = cont ? sc : r / Dd;
        const double da_dt = -(0.5 / s0) / sc;
        o->da_dD[k] = cont ? da_dt * 2.0 * r * r / (Dd * Dd * Dd) : -(r / (Dd * Dd)) / st;
        o->da_dr[k] = cont ? da_dt * -2.0 * r / (Dd * Dd) : (1.0 / Dd) / st;
        lmask back = reach & ((!(D > 1e-6 * r)) | (cont & (cc <= -1.0)));
        o->D[k] = Dd;
        double d[3];
        for (int a = 0; a < 3; ++a)
            o->d[a][k] = d[a] = v[a] / Dd;
        const double cg = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
        o->cg[k] = cg;
        const lmask clear =
            (!reach) | ((sa * cb + ca * sb > 0.0) & (cg < ca * cb - sa * sb - 1e-9));
        const lmask inside = (sa * cb - ca * sb > 0.0) & (cg > ca * cb + sa * sb + 1e-9);
        const double cx = d[1] * w[2] - d[2] * w[1], cy = d[2] * w[0] - d[0] * w[2],
                     cz = d[0] * w[1] - d[1] * w[0];
        const double sg = sqrt(cx * cx + cy * cy + cz * cz);
        o->sg[k] = sg;
        /* pen__cap_overlap_cos at (cg, sg) h, h the Newton step to unit length */
        const double h = 1.5 - 0.5 * (cg * cg + sg * sg), cgh = cg * h, sgh = sg * h;
        const double oa = ca > 0.0 ? sa * sa / (1.0 + ca) : 1.0 - ca;
        const double ob = cb > 0.0 ? sb * sb / (1.0 + cb) : 1.0 - cb;
        const double og = cgh > 0.0 ? sgh * sgh / (1.0 + cgh) : 1.0 - cgh;
        const double Ya = oa + ca * og - ob, Yb = ob + cb * og - oa, Yc = oa + ca * ob - og;
        const double Xa = sa * sgh, Xb = sb * sgh, Xc = sa * sb;
        double X = Xa, Y = fabs(Ya);
        const lmask ub = fabs(Yb) * X < Y * Xb;
        X = ub ? Xb : X, Y = ub ? fabs(Yb) : Y;
        const lmask uc = fabs(Yc) * X < Y * Xc;
        X = uc ? Xc : X, Y = uc ? fabs(Yc) : Y;
        const double Delta = (X - Y) * (X + Y), q = sqrt(Delta > 0.0 ? Delta : 0.0);
        const double pa = angle_lane(q, Ya), pb = angle_lane(q, Yb);
        const double E = 2.0 * angle_lane(q, 1.0 + ca + cb + cgh);
        const double A = 2.0 * (pa * oa + pb * ob) - 2.0 * E, f = A / area;
        back |= !clear & !inside & (!(ca + cb > 0.0) | !(sgh > 0.0) | !(Delta > 0.0) | !(A >= 0.0));
        const lmask part = !clear & !inside;
        o->f[k] = clear ? 0.0 : inside ? 1.0 : f;
        o->fa[k] = part ? 2.0 * pa * sa / area : 0.0;
        o->fb[k] = part ? (2.0 * pb * sb - f * 2.0 * PEN_PI * sb) / area : 0.0;
        o->fg[k] = part ? -2.0 * q / sgh / area : 0.0;
        o->back[k] = back;
    }
}

/* q = 1 - exp(-y) = -expm1(-y), y >= 0, in double lanes to a few ulps: below 1/2 its series to
 * y^15 (what it leaves out, 0.5^16 / 16!, is 1e-18 of q), above as 1 - exp(-y), where exp(-y) <=
 * 0.61 costs q at most 1.3 bits: exp(-y) = 2^n e^r, n = round(-y / ln 2) (held above -1000),
 * r = -y - n ln 2 with ln 2 in two parts (fdlibm's), |r| <= 0.347, e^r by its series to r^13
 * (4e-18), 2^n put into the exponent through the integer in the low bits of n + 1023 + 1.5 2^52. */
static inline double expm1_neg_lane(double y) {
    double h = 1.0;
    for (int n = 15; n >= 2; --n)
        h = 1.0 - y * (1.0 / n) * h;
    const double qs = y * h;
    double z = -y * 1.4426950408889634;
    z = z > -1000.0 ? z : -1000.0;
    const double m = (z + 6755399441055744.0) - 6755399441055744.0; /* round to nearest */
    const double r = (-y - m * 6.93147180369123816490e-01) - m * 1.90821492927058770002e-10;
    double e = 1.0;
    for (int n = 13; n >= 1; --n)
        e = 1.0 + r * (1.0 / n) * e;
    const double big = (m + 1023.0) + 6755399441055744.0;
    uint64_t bits;
    memcpy(&bits, &big, sizeof bits);
    bits <<= 52;
    double two_m;
    memcpy(&two_m, &bits, sizeof two_m);
    return y < 0.5 ? qs : 1.0 - e * two_m;
}

/* The backward terms of wide_lens's packed pairs, in double lanes: lights.c's
 * pen__lights_pair_bwd chain (d_g = dV V / (1 - q f), d_f = -q d_g through f's partials by g, a
 * and b), q = 1 - exp(-eps w kappa) from the lanes' exponent y[P[p]], dV V from VdV[P[p]]: the
 * pair's d/dv (dv, into x and the sphere's centre), d/dr, d/d of the light's direction (dl[0..2],
 * where tang: sin g > 1e-12) and radius (dl[3]), and its d/dq (dq); nz where f or any of its
 * partials is not 0 (else the pair adds nothing, as there). The caller adds them up in the pairs'
 * order. */
typedef struct wide_terms {
    double dv[3][B], dr[B], dl[4][B], dq[B];
    lmask nz[B], tang[B];
} wide_terms;

static inline __attribute__((always_inline)) void wide_bwd(const pen__lights *L, int l,
                                                           const wide_pairs *o, const int *P,
                                                           int np, const float *y, const float *VdV,
                                                           wide_terms *t) {
    const int npad = (np + 3) & ~3;
    const double *w = L->w[l];
    double yd[B], vv[B];
    for (int p = 0; p < npad; ++p) { /* the gather on its own, as in wide_lens */
        const int k = P[p < np ? p : np - 1];
        yd[p] = (double)y[k], vv[p] = (double)VdV[k];
    }
    for (int p = 0; p < npad; ++p) {
        const double q = expm1_neg_lane(yd[p]), f = o->f[p];
        const double d_g = vv[p] / (1.0 - q * f), d_f = -q * d_g, d_a = d_f * o->fa[p];
        t->nz[p] = !((f == 0.0) & (o->fa[p] == 0.0) & (o->fb[p] == 0.0) & (o->fg[p] == 0.0));
        t->dl[3][p] = d_f * o->fb[p];
        const lmask tang = o->sg[p] > 1e-12;
        t->tang[p] = tang;
        const double dg = d_f * o->fg[p] / o->sg[p], cg = o->cg[p];
        for (int a = 0; a < 3; ++a) {
            const double u = 0.0 - dg * (w[a] - cg * o->d[a][p]) / o->D[p];
            t->dl[a][p] = dg * (o->d[a][p] - cg * w[a]);
            t->dv[a][p] = (tang ? u : 0.0) + d_a * o->da_dD[p] * o->d[a][p];
        }
        t->dr[p] = d_a * o->da_dr[p];
        t->dq[p] = f * d_g;
    }
}

/* The forward light term of cnt <= PEN_LIGHTS_BLOCK receivers at x + 3 at[k] (nrm, rho, rgb
 * likewise), over the n spheres idx (NULL: 0 .. n - 1), into rgb and V_out + count at[k] (V_out
 * may be NULL); see the design notes above. */
void CAT(pen__lights_fwd_block_, PEN_FAST_ISA)(const pen__lights *L, const double *G, int n,
                                               const float *spheres, const float *kappa,
                                               const int *idx, int cnt, const float *x,
                                               const float *nrm, const float *rho, const int *at,
                                               float *rgb, float *V_out) {
    lanes z;
    lanes_init(&z, L, cnt, x, nrm, at);
    const int K = z.K;
    float V[LMAX][B];
    for (int l = 0; l < K; ++l)
        for (int k = 0; k < B; ++k)
            V[l][k] = 1.0f;
    int skip[B];
    for (int k = 0; k < B; ++k)
        skip[k] = z.exact[k];
    const int pairs = L->shadows && block_bound(&z, cnt, skip);
    for (int j = 0; pairs && j < n; ++j) {
        const int i = idx ? idx[j] : j;
        const float *sp = spheres + 4 * (size_t)i;
        int on[B], in[LMAX][B], part[LMAX][B], any_part[LMAX];
        float y[B], ex[B];
        if (!pen__lights_may_shadow(L, sp, z.m, z.R)) continue;
        if (!sphere_pairs(&z, skip, sp, kappa ? kappa[i] : 1.0f, on, y, ex, in, part, any_part))
            continue;
        for (int l = 0; l < K; ++l) {
            /* inside: the factor 1 - q is exp(-eps w kappa) itself (1 - (1 - e) would keep only
             * 6e-8 of it in a deep shadow) */
            LANES
            for (int k = 0; k < B; ++k)
                V[l][k] = in[l][k] ? V[l][k] * ex[k] : V[l][k];
            if (!any_part[l]) continue;
            int P[B], np = 0;
            for (int k = 0; k < cnt; ++k)
                if (part[l][k]) P[np++] = k;
            if (!np) continue;
            wide_pairs wp;
            const int wide = z.wide[l];
            if (wide) wide_lens(&z, L, l, sp, P, np, &wp);
            for (int p = 0; p < np; ++p) {
                const int k = P[p];
                const float xk[3] = {z.X[0][k], z.X[1][k], z.X[2][k]};
                const double q = 1.0 - (double)ex[k];
                const double f = wide && !wp.back[p] ? wp.f[p] : pen__lights_fraction(L, l, xk, sp);
                V[l][k] *= (float)(1.0 - q * f);
            }
        }
    }
    /* the lights' sum in lanes, then each receiver's colour and V (V = 1 where D = 0, as the
     * double term's unlit) */
    float e[3][B];
    for (int ch = 0; ch < 3; ++ch)
        for (int k = 0; k < B; ++k)
            e[ch][k] = 0.0f;
    for (int l = 0; l < K; ++l) {
        const float Gl = G ? (float)G[l] : 1.0f;
        const float E[3] = {(float)L->E[l][0], (float)L->E[l][1], (float)L->E[l][2]};
        for (int k = 0; k < B; ++k) {
            const float a = z.Dl[l][k] * V[l][k] * Gl;
            for (int ch = 0; ch < 3; ++ch)
                e[ch][k] += E[ch] * a;
            V[l][k] = z.Dl[l][k] > 0.0f ? V[l][k] : 1.0f;
        }
    }
    for (int k = 0; k < cnt; ++k) {
        const size_t i = (size_t)(at ? at[k] : k);
        float *Vo = V_out ? V_out + (size_t)K * i : NULL;
        if (z.exact[k]) {
            pen__lights_fwd(L, G, n, spheres, kappa, idx, x + 3 * i, nrm + 3 * i, rho + 3 * i,
                            rgb + 3 * i, Vo);
            continue;
        }
        for (int l = 0; Vo && l < K; ++l)
            Vo[l] = V[l][k];
        for (int ch = 0; ch < 3; ++ch)
            rgb[3 * i + ch] += rho[3 * i + ch] * e[ch][k] * (float)(1.0 / PEN_PI);
    }
}

/* The backward of the light term for cnt <= PEN_LIGHTS_BLOCK receivers k at x + 3 k (nrm, rho,
 * d_x, d_n, d_rho likewise: the run's compacted arrays), whose d_rgb and forward V are at
 * d_rgb + 3 pix[k] and V_in + count pix[k]: what pen__lights_bwd adds for each. In lanes, the
 * pairs whose fraction is 0 or 1 (f constant: the gradient is the weight's alone) and the
 * per-light chain; a partial pair adds f's own derivatives in double (wide_bwd,
 * pen__lights_pair_bwd); a receiver without a kept V or not finite takes the double term, over
 * its own candidates, after the lanes. scratch: room for the larger of n PEN_LIGHTS_BLOCK floats
 * and (n + 1) PEN_LIGHTS_BLOCK ints (used in turn). */
void CAT(pen__lights_bwd_block_,
         PEN_FAST_ISA)(const pen__lights *L, const double *G, int n, const float *spheres,
                       const float *kappa, const int *idx, int cnt, const float *x,
                       const float *nrm, const float *rho, const float *d_rgb, const float *V_in,
                       const int *pix, void *scratch, double *d_spheres, float *d_x, float *d_n,
                       float *d_rho, double *d_lights, double *d_G) {
    lanes z;
    lanes_init(&z, L, cnt, x, nrm, NULL);
    const int K = z.K;
    float V[LMAX][B], VdV[LMAX][B], sl[LMAX][B], g3[3][B], rl[3][B], dxl[3][B], dnl[3][B];
    int skip[B]; /* not in the lanes: a double receiver, or one without a gradient */
    for (int k = 0; k < B; ++k) {
        const size_t p = (size_t)pix[k < cnt ? k : 0];
        for (int a = 0; a < 3; ++a) {
            g3[a][k] = d_rgb[3 * p + (size_t)a] * (float)(1.0 / PEN_PI);
            rl[a][k] = rho[3 * (k < cnt ? k : 0) + a];
            dxl[a][k] = dnl[a][k] = 0.0f;
        }
        z.exact[k] |= !V_in;
        skip[k] = z.exact[k] | (k >= cnt) |
                  ((g3[0][k] == 0.0f) & (g3[1][k] == 0.0f) & (g3[2][k] == 0.0f));
    }
    /* A pair's factor 1 - q f >= exp(-eps kappa): above 1e-200 (the double term's own limit,
     * beyond which it takes the other factors' product instead) unless eps kappa > 460. */
    float kmax = 1.0f;
    for (int j = 0; kappa && j < n; ++j) {
        const float kj = kappa[idx ? idx[j] : j];
        kmax = kj > kmax ? kj : kmax;
    }
    if (!(L->eps * (double)kmax < 400.0))
        for (int k = 0; k < B; ++k)
            z.exact[k] = skip[k] = 1;
    const int pairs = block_bound(&z, cnt, skip);
    /* Per light: the forward's V, s = sum_ch g rho E and dV V with dV = s D G. */
    for (int l = 0; l < K; ++l) {
        const float Gl = G ? (float)G[l] : 1.0f;
        const float E0 = (float)L->E[l][0], E1 = (float)L->E[l][1], E2 = (float)L->E[l][2];
        for (int k = 0; k < B; ++k) /* the gather in a loop of its own, the rest in lanes */
            V[l][k] = V_in ? V_in[(size_t)K * (size_t)pix[k < cnt ? k : 0] + (size_t)l] : 1.0f;
        for (int k = 0; k < B; ++k) {
            sl[l][k] =
                g3[0][k] * rl[0][k] * E0 + g3[1][k] * rl[1][k] * E1 + g3[2][k] * rl[2][k] * E2;
            VdV[l][k] = sl[l][k] * z.Dl[l][k] * Gl * V[l][k];
        }
    }
    /* The pairs are visited when a gradient needs them: the spheres, x and n through the
     * weights, and the lights' own through the partial pairs (which only the double term has). */
    const int geometry = d_spheres || d_x || d_n;
    float *dw = scratch; /* d/dw of each (sphere, receiver), for the second pass */
    for (int j = 0; pairs && L->shadows && (geometry || d_lights) && j < n; ++j) {
        /* Pass 1: each pair's class and, for the lanes, d/dw; a partial pair of a lit light
         * adds f's own derivatives in double as it goes. */
        const int i = idx ? idx[j] : j;
        const float kap = kappa ? kappa[i] : 1.0f;
        float *dwj = dw + (size_t)j * B, y[B], ex[B], dq[B];
        int on[B], in[LMAX][B], part[LMAX][B], any_part[LMAX];
        for (int k = 0; k < B; ++k)
            dwj[k] = 0.0f;
        const float *sp = spheres + 4 * (size_t)i;
        if (!pen__lights_may_shadow(L, sp, z.m, z.R)) continue;
        if (!sphere_pairs(&z, skip, sp, kap, on, y, ex, in, part, any_part)) continue;
        for (int k = 0; k < B; ++k)
            dq[k] = 0.0f;
        for (int l = 0; l < K; ++l) {
            LANES
            for (int k = 0; k < B; ++k) {
                /* f = 1: the factor 1 - q, whose d/dq is -1, times dV V / (1 - q); a light with
                 * dV V = 0 (unlit, or no gradient) adds nothing, as in the double term */
                const float dqi = VdV[l][k] / ex[k];
                dq[k] = in[l][k] & (VdV[l][k] != 0.0f) ? dq[k] - dqi : dq[k];
            }
            /* partial: f's own derivatives in double, into the sphere, the point and the light
             * at once (this receiver is in the lanes for good); a wide disk's from the double
             * lanes, the rest pair by pair */
            if (!any_part[l]) continue;
            int P[B], np = 0;
            for (int k = 0; k < cnt; ++k)
                if (part[l][k] & (VdV[l][k] != 0.0f)) P[np++] = k;
            if (!np) continue;
            wide_pairs wp;
            wide_terms wt;
            const int wide = z.wide[l];
            double *ds = d_spheres ? d_spheres + 4 * (size_t)i : NULL;
            double *dl = d_lights ? d_lights + PEN_LIGHT_GRAD_DOUBLES * l : NULL;
            if (wide) {
                wide_lens(&z, L, l, sp, P, np, &wp);
                wide_bwd(L, l, &wp, P, np, y, VdV[l], &wt);
            }
            for (int p = 0; p < np; ++p) {
                const int k = P[p];
                if (wide && !wp.back[p]) {
                    if (!wt.nz[p]) continue;
                    if (dl) dl[3] += wt.dl[3][p];
                    for (int a = 0; dl && wt.tang[p] && a < 3; ++a)
                        dl[a] -= wt.dl[a][p];
                    for (int a = 0; a < 3; ++a)
                        dxl[a][k] -= (float)wt.dv[a][p];
                    dq[k] -= (float)wt.dq[p];
                    if (ds) ds[0] += wt.dv[0][p], ds[1] += wt.dv[1][p], ds[2] += wt.dv[2][p];
                    if (ds) ds[3] += wt.dr[p];
                    continue;
                }
                const float xk[3] = {z.X[0][k], z.X[1][k], z.X[2][k]};
                double dv[3] = {0.0, 0.0, 0.0}, d_r = 0.0;
                const float nk[3] = {z.N[0][k], z.N[1][k], z.N[2][k]};
                dq[k] -= (float)pen__lights_pair_bwd(L, l, xk, nk, sp, kap, (double)VdV[l][k], dv,
                                                     &d_r, dl);
                for (int a = 0; a < 3; ++a)
                    dxl[a][k] -= (float)dv[a];
                if (ds) ds[0] += dv[0], ds[1] += dv[1], ds[2] += dv[2], ds[3] += d_r;
            }
        }
        LANES
        for (int k = 0; k < B; ++k) /* d/dw = d/dq eps kappa exp(-eps w kappa) */
            dwj[k] = on[k] ? dq[k] * z.eps * kap * ex[k] : 0.0f;
    }
    /* Pass 2: the lanes' d/dw through w = w_h(h) g(p), h = n . v / r, p = |v| / r, into the
     * spheres (in the receivers' order), x and n. */
    for (int j = 0; pairs && L->shadows && geometry && j < n; ++j) {
        const float *dwj = dw + (size_t)j * B;
        int any = 0;
        for (int k = 0; k < cnt; ++k)
            any |= (dwj[k] != 0.0f) & !z.exact[k];
        if (!any) continue;
        const int i = idx ? idx[j] : j;
        const float *sp = spheres + 4 * (size_t)i, r = sp[3];
        float dv[3][B], dr[B];
        for (int k = 0; k < B; ++k) {
            const float v[3] = {sp[0] - z.X[0][k], sp[1] - z.X[1][k], sp[2] - z.X[2][k]};
            const float p = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) / r;
            const float h = (z.N[0][k] * v[0] + z.N[1][k] * v[1] + z.N[2][k] * v[2]) / r;
            const float u = (h - z.h0) * z.inv_span, e = (p - z.lo) * z.inv_width;
            const float whp = u * u * (3.0f - 2.0f * u), gp = e * e * (3.0f - 2.0f * e);
            const float dwhp = 6.0f * u * (1.0f - u) * z.inv_span;
            const float dgp = 6.0f * e * (1.0f - e) * z.inv_width;
            const float wh = u < 1.0f ? whp : 1.0f, g = e < 1.0f ? gp : 1.0f;
            const float dwh = u < 1.0f ? dwhp : 0.0f, dg = e < 1.0f ? dgp : 0.0f;
            const float d = z.exact[k] ? 0.0f : dwj[k];
            const float dh = d * dwh * g, dp = d * wh * dg;
            const float kpa = dp / (p * r * r), kp = dp != 0.0f ? kpa : 0.0f; /* p = 0: 0/0 */
            for (int a = 0; a < 3; ++a) {
                dv[a][k] = dh * z.N[a][k] / r + kp * v[a];
                dnl[a][k] += dh * v[a] / r;
                dxl[a][k] -= dv[a][k];
            }
            dr[k] = -dh * h / r - dp * p / r;
        }
        if (d_spheres) {
            double *ds = d_spheres + 4 * (size_t)i;
            for (int k = 0; k < cnt; ++k) {
                if (z.exact[k] || dwj[k] == 0.0f) continue;
                ds[0] += (double)dv[0][k], ds[1] += (double)dv[1][k];
                ds[2] += (double)dv[2][k], ds[3] += (double)dr[k];
            }
        }
    }
    /* The per-light chain of the lane receivers: rho, the light's own gradient, the horizon
     * factor and n, through D's partials (dD/dc = 1, dD/db = 0 for a disk wholly above the
     * horizon), in lanes; the light's sums over the receivers in their order. */
    float drho[3][B];
    for (int ch = 0; ch < 3; ++ch)
        for (int k = 0; k < B; ++k)
            drho[ch][k] = 0.0f;
    for (int l = 0; l < K; ++l) {
        const float Gl = G ? (float)G[l] : 1.0f;
        const float E[3] = {(float)L->E[l][0], (float)L->E[l][1], (float)L->E[l][2]};
        const float *Dl = z.Dl[l], *dDc = z.dDc[l], *dDb = z.dDb[l], *Vl = V[l], *sll = sl[l];
        const float wl[3] = {z.w[l][0], z.w[l][1], z.w[l][2]};
        float tl[7][B], tG[B];
        int lit[B];
        LANES
        for (int k = 0; k < B; ++k) {
            lit[k] = !skip[k] & (Dl[k] > 0.0f);
            const float DGV = Dl[k] * Gl * Vl[k], dD = sll[k] * Gl * Vl[k];
            for (int ch = 0; ch < 3; ++ch) {
                const float t = drho[ch][k] + g3[ch][k] * E[ch] * DGV;
                drho[ch][k] = lit[k] ? t : drho[ch][k];
                tl[4 + ch][k] = g3[ch][k] * rl[ch][k] * DGV;
            }
            for (int a = 0; a < 3; ++a) {
                const float t = dnl[a][k] + dD * dDc[k] * wl[a];
                dnl[a][k] = lit[k] ? t : dnl[a][k];
                tl[a][k] = dD * dDc[k] * z.N[a][k];
            }
            tl[3][k] = dD * dDb[k];
            tG[k] = sll[k] * Dl[k] * Vl[k];
        }
        double *dl = d_lights ? d_lights + PEN_LIGHT_GRAD_DOUBLES * l : NULL;
        for (int k = 0; k < cnt; ++k) {
            if (!lit[k]) continue;
            for (int a = 0; dl && a < 7; ++a)
                dl[a] += (double)tl[a][k];
            if (d_G && G) d_G[l] += (double)tG[k];
        }
    }
    int nx = 0, xk[B];
    for (int k = 0; k < cnt; ++k) {
        if (z.exact[k]) xk[nx++] = k;
        if (skip[k]) continue; /* the double term's, or no gradient */
        for (int ch = 0; ch < 3; ++ch)
            d_rho[3 * k + ch] += drho[ch][k];
        for (int a = 0; a < 3; ++a) {
            if (d_x) d_x[3 * k + a] += dxl[a][k];
            if (d_n) d_n[3 * k + a] += dnl[a][k];
        }
    }
    if (!nx) return;
    /* The double term for the rest, over the spheres the prefilter keeps for each. */
    int *list = scratch, *count = list + (size_t)n * B;
    CAT(pen__lights_candidates_, PEN_FAST_ISA)(L, n, spheres, idx, nx, x, nrm, xk, list, count);
    for (int f = 0; f < nx; ++f) {
        const int k = xk[f];
        const size_t p = (size_t)pix[k];
        pen__lights_bwd(L, G, count[f], spheres, kappa, list + (size_t)f * (size_t)n, x + 3 * k,
                        nrm + 3 * k, rho + 3 * k, d_rgb + 3 * p, V_in ? V_in + (size_t)K * p : NULL,
                        d_spheres, d_x ? d_x + 3 * k : NULL, d_n ? d_n + 3 * k : NULL,
                        d_rho + 3 * k, d_lights, d_G);
    }
}
