/* Distant disk lights on top of the SH lighting (docs/design.md sec. 1.13): the disk's
 * clamped-cosine integral, the overlap of a sphere's cap with the disk, and the per-pixel light
 * term with its backward (lights_ops.inc, compiled for float and double inputs).
 *
 * Design
 * - A light is a uniform disk of angular radius b around the unit direction w, scaled so that a
 *   receiver facing it gets its irradiance E. A diffuse receiver gets rho/pi E D(n . w, b) V:
 *   D is the exact clamped-cosine integral over the disk (the horizon included: a disk half below
 *   a receiver's tangent plane lights it with the part above), V the disk's visibility.
 * - Visibility reuses the SH path's per-sphere quantities: the cap half-angle alpha_i (with the
 *   tangent-line continuation of sh.h, so a receiver on or in a sphere sees up to the whole
 *   sphere), its direction d_i, the self-shadowing weight w_i and the overlap weight kappa_i.
 *   Sphere i hides the fraction f_i of the disk that its cap covers (the two caps' intersection in
 *   closed form) with the opacity 1 - exp(-eps w_i kappa_i), so the product over spheres is exact
 *   for one blocker, reaches the SH model's full-shadow limit exp(-eps sum w kappa) when every
 *   sphere covers the disk, and widens its penumbra with b. Products of independent coverages
 *   count the overlap of two blockers' caps as if they were uncorrelated (the documented limit).
 * - Precision. A sun is 0.27 deg across: its solid angle is 2e-5 and the overlap of a cap with it
 *   is a difference of O(1) angles in the textbook formula. Here every angle comes from atan2 or
 *   half-angle forms of differences of the sides (s - a, s - b, s - g), the lens is two sectors
 *   minus the kite of two triangles (L'Huilier's formula), so the overlap keeps about 1e-12 of its
 *   relative precision down to the smallest radius accepted (0.01 deg). Disks from
 *   PEN_LIGHTS_COS_LENS_DEG (0.25 deg, under the sun's 0.27) up take the same lens from the
 *   cosines the visibility test already has (pen__cap_overlap_cos: three atan, no sincos, partials
 *   from the boundary arcs): there it agrees with the angle form to 5e-13 of the disk's area (1e-12
 *   checked; 1e-13 from 1 deg up), far under a float image's 6e-8, while under 0.1 deg the
 *   cosines' cancellation would cost it digits (tests/test_lights.c).
 * - Derivatives of the two closed forms come from forward-mode dual numbers (3 partials) over the
 *   same expressions, so the derivative is the derivative of the value that was computed.
 * - Cost. A sun is small, so most (receiver, sphere) pairs of a tile cannot touch it: the
 *   backward passes each receiver only the spheres that a float prefilter (lights_fast.c, in the
 *   machine's vector width) keeps, and a disk that is clear of a cap or wholly inside it is told
 *   from the cosines alone; only partial overlaps take the angles (atan2) and the lens formula.
 *   Both shortcuts take the branch the full computation would take, so the result is unchanged.
 *   The fast kernel's forward runs the term itself in its lanes (pen__lights_fwd_block) and
 *   comes here only for the partial overlaps (pen__lights_fraction).
 */
#include "shade/lights.h"

#include "core/internal.h"
#include "penumbra/sh.h"
#include "shade/shade.h"

#include <math.h>
#include <string.h>

/* ---- Dual numbers (value and 3 partials) ---------------------------------------------------- */

typedef struct dual {
    double v, d[3];
} dual;

static dual dconst(double v) {
    dual r = {v, {0.0, 0.0, 0.0}};
    return r;
}
static dual dvar(double v, int k) {
    dual r = dconst(v);
    r.d[k] = 1.0;
    return r;
}
/* f(x) with f'(x) = df. */
static dual dchain(dual x, double f, double df) {
    dual r = {f, {df * x.d[0], df * x.d[1], df * x.d[2]}};
    return r;
}
static dual dadd(dual a, dual b) {
    dual r = {a.v + b.v, {a.d[0] + b.d[0], a.d[1] + b.d[1], a.d[2] + b.d[2]}};
    return r;
}
static dual dsub(dual a, dual b) {
    dual r = {a.v - b.v, {a.d[0] - b.d[0], a.d[1] - b.d[1], a.d[2] - b.d[2]}};
    return r;
}
static dual dmul(dual a, dual b) {
    dual r;
    r.v = a.v * b.v;
    for (int k = 0; k < 3; ++k)
        r.d[k] = a.d[k] * b.v + a.v * b.d[k];
    return r;
}
static dual ddiv(dual a, dual b) {
    dual r;
    r.v = a.v / b.v;
    for (int k = 0; k < 3; ++k)
        r.d[k] = (a.d[k] - r.v * b.d[k]) / b.v;
    return r;
}
static dual dscale(dual a, double s) {
    return dchain(a, s * a.v, s);
}
static dual dsin(dual a) {
    return dchain(a, sin(a.v), cos(a.v));
}
static dual dcos(dual a) {
    return dchain(a, cos(a.v), -sin(a.v));
}
static dual dtan(dual a) {
    const double t = tan(a.v);
    return dchain(a, t, 1.0 + t * t);
}
static dual dsqrt(dual a) {
    const double s = sqrt(a.v);
    return dchain(a, s, s > 0.0 ? 0.5 / s : 0.0);
}
static dual datan(dual a) {
    return dchain(a, atan(a.v), 1.0 / (1.0 + a.v * a.v));
}
static dual dacos(dual a) {
    const double q = 1.0 - a.v * a.v;
    return dchain(a, acos(a.v), q > 0.0 ? -1.0 / sqrt(q) : 0.0);
}

/* ---- The disk's clamped cosine -------------------------------------------------------------- */

/* Partial visibility above the horizon (Snyder's closed form for a sphere light against a plane;
 * here normalised by the unclipped value pi sin^2 b): with x = cot b, y = -x cot(theta),
 *   I = sin^2 b (cos(theta) acos(y) - x sin(theta) sqrt(1 - y^2)) + atan(sin(theta) sqrt(1 - y^2) / x),
 * which meets pi sin^2 b cos(theta) at theta = pi/2 - b (y = -1) and 0 at pi/2 + b (y = 1). */
double pen__disk_clamped_cosine(double c, double b, double *dD_dc, double *dD_db) {
    const double sb = sin(b);
    double D, dc = 0.0, db = 0.0;
    if (c >= sb) {
        D = c, dc = 1.0;
    } else if (c <= -sb) {
        D = 0.0;
    } else {
        const dual C = dvar(c, 0), B = dvar(b, 1);
        const dual sin_b = dsin(B), sin2 = dmul(sin_b, sin_b);
        const dual x = ddiv(dcos(B), sin_b);
        const dual st = dsqrt(dsub(dconst(1.0), dmul(C, C)));
        const dual y = dscale(ddiv(dmul(x, C), st), -1.0);
        const dual q = dmul(st, dsqrt(dmul(dsub(dconst(1.0), y), dadd(dconst(1.0), y))));
        const dual I = dadd(dmul(sin2, dsub(dmul(C, dacos(y)), dmul(x, q))), datan(ddiv(q, x)));
        const dual R = ddiv(I, dscale(sin2, PEN_PI));
        D = R.v, dc = R.d[0], db = R.d[1];
    }
    if (dD_dc) *dD_dc = dc;
    if (dD_db) *dD_db = db;
    return D;
}

/* ---- Overlap of two caps --------------------------------------------------------------------- */

/* 4 pi sin^2(h/2): a cap's solid angle from its half-angle h, without cancellation. */
static dual cap_area(dual h) {
    const dual s = dsin(dscale(h, 0.5));
    return dscale(dmul(s, s), 4.0 * PEN_PI);
}

/* A cap's solid angle 4 pi sin^2(h/2) in plain doubles (the forward's full-overlap value). */
static double cap_full_area(double h) {
    const double s = sin(0.5 * h);
    return 4.0 * PEN_PI * s * s;
}

/* tan(x/2) from sin x and cos x, x in [0, pi], without cancellation at either end. */
static double half_tan(double sx, double cx) {
    return cx >= 0.0 ? sx / (1.0 + cx) : (1.0 - cx) / sx;
}

/* The lens, by Gauss-Bonnet: the sectors of the two caps spanned by the lens's corners
 * (azimuths 2 phi_a, 2 phi_b around the centres, areas 4 phi sin^2(h/2)) overlap in the kite of
 * the two triangles (centre a, centre b, corner), each of excess E; lens = sectors - 2E. In the
 * triangle with sides a, b, g and half-perimeter s, phi_a (opposite b) and E come from the
 * half-angle and L'Huilier formulas, which take only sines and tangents of s - a, s - b, s - g. */
double pen__cap_overlap(double a, double b, double g, double d[3]) {
    const double s = 0.5 * (a + b + g);
    if (!d) {
        /* the same in plain doubles: the forward's (hot) path */
        if (s - g <= 0.0) return 0.0;
        if (s - a <= 0.0) return cap_full_area(b);
        if (s - b <= 0.0) return cap_full_area(a);
        const double hb = sin(0.5 * b), ha = sin(0.5 * a);
        if (s >= PEN_PI) return 4.0 * PEN_PI * (ha * ha + hb * hb - 1.0);
        /* sine and cosine of each (one sincos each) give the half-angle tangents */
        const double ss = sin(s), ssa = sin(s - a), ssb = sin(s - b), ssg = sin(s - g);
        const double pa = 2.0 * atan(sqrt(ssa * ssg / (ss * ssb)));
        const double pb = 2.0 * atan(sqrt(ssb * ssg / (ss * ssa)));
        const double t = half_tan(ss, cos(s)) * half_tan(ssa, cos(s - a)) *
                         half_tan(ssb, cos(s - b)) * half_tan(ssg, cos(s - g));
        return 4.0 * (pa * ha * ha + pb * hb * hb) - 8.0 * atan(sqrt(t));
    }
    dual r;
    const dual A = dvar(a, 0), B = dvar(b, 1), G = dvar(g, 2);
    if (s - g <= 0.0) {
        r = dconst(0.0); /* disjoint */
    } else if (s - a <= 0.0) {
        r = cap_area(B); /* the disk inside the cap */
    } else if (s - b <= 0.0) {
        r = cap_area(A); /* the cap inside the disk */
    } else if (s >= PEN_PI) {
        /* both larger than the other's complement: a band, the whole sphere minus two caps */
        r = dsub(dadd(cap_area(A), cap_area(B)), dconst(4.0 * PEN_PI));
    } else {
        const dual S = dscale(dadd(dadd(A, B), G), 0.5);
        const dual sa = dsub(S, A), sb = dsub(S, B), sg = dsub(S, G);
        const dual ss = dsin(S), ssa = dsin(sa), ssb = dsin(sb), ssg = dsin(sg);
        const dual pa = dscale(datan(dsqrt(ddiv(dmul(ssa, ssg), dmul(ss, ssb)))), 2.0);
        const dual pb = dscale(datan(dsqrt(ddiv(dmul(ssb, ssg), dmul(ss, ssa)))), 2.0);
        const dual t = dmul(dmul(dtan(dscale(S, 0.5)), dtan(dscale(sa, 0.5))),
                            dmul(dtan(dscale(sb, 0.5)), dtan(dscale(sg, 0.5))));
        const dual E = dscale(datan(dsqrt(t)), 4.0);
        const dual ha = dsin(dscale(A, 0.5)), hb = dsin(dscale(B, 0.5));
        r = dsub(dadd(dscale(dmul(pa, dmul(ha, ha)), 4.0), dscale(dmul(pb, dmul(hb, hb)), 4.0)),
                 dscale(E, 2.0));
    }
    if (d) memcpy(d, r.d, sizeof r.d);
    return r.v;
}

/* The same lens from the cosines and sines of a, b, g (g = the angle between the centres), for
 * the wide disks (pen__cap_overlap_cos, lights.h). The triangle (cap centre, disk centre, a corner
 * of the lens) has the sides g, a, b; with Y_a = cos b - cos a cos g and X_a = sin a sin g,
 * Delta = X_a^2 - Y_a^2 is its Gram determinant (the same from each corner), phi_a =
 * atan2(sqrt Delta, Y_a) and phi_b likewise, and its excess is E = 2 atan2(sqrt Delta,
 * 1 + cos a + cos b + cos g) (the solid angle of the triangle of the three unit vectors). The
 * lens is the two sectors minus the kite, 2 phi_a (1 - cos a) + 2 phi_b (1 - cos b) - 2 E, as in
 * pen__cap_overlap, without the angles a and g (two atan2) and the half-sides' sines and
 * tangents (five sincos, tan). Cancellation: 1 - cos x from sin^2 x / (1 + cos x), each Y from
 * the 1 - cos terms (exact differences of small terms), Delta from the corner whose angle is
 * nearest pi/2 as (X - |Y|)(X + |Y|). Partials: the boundary arcs, dA/da = 2 phi_a sin a,
 * dA/db = 2 phi_b sin b, dA/dg = -2 sin b sin phi_b = -2 sqrt(Delta) / sin g. */
static double one_minus_cos(double c, double s) {
    return c > 0.0 ? s * s / (1.0 + c) : 1.0 - c;
}

/* atan2(s, c) for s > 0 with one atan (cheaper than atan2; absolute error a few ulps of pi). */
static double angle_of(double s, double c) {
    return c > 0.0 ? atan(s / c) : 0.5 * PEN_PI - atan(c / s);
}

double pen__cap_overlap_cos(double ca, double sa, double cb, double sb, double cg, double sg,
                            double d[3]) {
    if (!(ca + cb > 0.0)) return -1.0; /* a + b >= pi: the band case is possible */
    if (!(sg > 0.0)) return -1.0;      /* d along w: dA/dg = -2 sqrt(Delta) / sin g is undefined */
    const double oa = one_minus_cos(ca, sa), ob = one_minus_cos(cb, sb), og = one_minus_cos(cg, sg);
    const double Ya = oa + ca * og - ob; /* cos b - cos a cos g */
    const double Yb = ob + cb * og - oa; /* cos a - cos b cos g */
    const double Yc = oa + ca * ob - og; /* cos g - cos a cos b */
    const double Xa = sa * sg, Xb = sb * sg, Xc = sa * sb;
    /* the corner with the smallest |cos|: |Y| / X least */
    double X = Xa, Y = fabs(Ya);
    if (fabs(Yb) * X < Y * Xb) X = Xb, Y = fabs(Yb);
    if (fabs(Yc) * X < Y * Xc) X = Xc, Y = fabs(Yc);
    const double Delta = (X - Y) * (X + Y);
    if (!(Delta > 0.0)) return -1.0; /* degenerate (tangent): the closed form decides */
    const double q = sqrt(Delta);
    const double pa = angle_of(q, Ya), pb = angle_of(q, Yb);
    const double E = 2.0 * angle_of(q, 1.0 + ca + cb + cg);
    if (d) d[0] = 2.0 * pa * sa, d[1] = 2.0 * pb * sb, d[2] = -2.0 * q / sg;
    return 2.0 * (pa * oa + pb * ob) - 2.0 * E;
}

/* ---- A frame's lights ------------------------------------------------------------------------ */

void pen__lights_init(pen__lights *L, const pen_lighting *lighting, double eps, int shadows) {
    memset(L, 0, sizeof *L);
    L->count = lighting->light_count;
    L->shadows = shadows;
    L->eps = eps;
    for (int l = 0; l < L->count; ++l) {
        const pen_light *s = &lighting->lights[l];
        const double v[3] = {(double)s->direction[0], (double)s->direction[1],
                             (double)s->direction[2]};
        L->len[l] = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int a = 0; a < 3; ++a) {
            L->w[l][a] = v[a] / L->len[l];
            L->E[l][a] = (double)s->irradiance[a];
        }
        L->b[l] = (double)s->angular_radius_deg * (PEN_PI / 180.0);
        L->sin_b[l] = sin(L->b[l]);
        L->cos_b[l] = cos(L->b[l]);
        L->area[l] = 4.0 * PEN_PI * sin(0.5 * L->b[l]) * sin(0.5 * L->b[l]);
    }
    /* a sphere that reaches any light is kept: asking the widest first ends the test soonest */
    for (int l = 0; l < L->count; ++l) {
        int k = l;
        while (k > 0 && L->b[L->widest[k - 1]] < L->b[l]) {
            L->widest[k] = L->widest[k - 1];
            --k;
        }
        L->widest[k] = l;
    }
}

/* The directions y > -t are the cap of half-angle acos(-t) around +Y. */
double pen__lights_horizon(const pen__lights *L, int l, double t, double *d_t, double d_w[3],
                           double *d_b) {
    const double *w = L->w[l];
    const double sg = sqrt(w[0] * w[0] + w[2] * w[2]), g = atan2(sg, w[1]);
    const double a = acos(t < -1.0 ? -1.0 : t > 1.0 ? 1.0 : -t);
    double d[3];
    const double area = 4.0 * PEN_PI * sin(0.5 * L->b[l]) * sin(0.5 * L->b[l]);
    const double G = pen__cap_overlap(a, L->b[l], g, d) / area;
    const double st = sqrt(fmax(1.0 - t * t, 1e-300));
    if (d_t) *d_t = d[0] / area / st; /* da/dt = 1 / sqrt(1 - t^2) */
    if (d_b) *d_b = (d[1] - G * 2.0 * PEN_PI * sin(L->b[l])) / area;
    if (d_w) {
        /* g = angle(w, +Y): dg/dw = -(Y - cos g w) / sin g (0 on the axis, where f is even) */
        const double k = sg > 1e-12 ? d[2] / area / sg : 0.0;
        d_w[0] = k * w[1] * w[0];
        d_w[1] = -k * (1.0 - w[1] * w[1]);
        d_w[2] = k * w[1] * w[2];
    }
    return G;
}

/* ---- Per pixel ------------------------------------------------------------------------------- */

/* The per-pixel and per-pair tests below are inlined into the per-pixel loops: they run for
 * every receiver or visited pair, and a call cost as much as their arithmetic. */
#define HOT static inline __attribute__((always_inline))

/* What a receiver (x, n) sees of sphere (c, r), as the SH path (sh.h, shade_ops.inc): v = c - x,
 * the self-shadowing weight w = w_h(h) g(q), h = n . v / r, q = |v| / r (sphere_view_weight,
 * cheap, first: the tangent-plane and inside rules of render_internal.h); then, for
 * spheres that may reach a disk (sphere_view_reaches), the unit direction d and distance D of the
 * centre and the cap's half-angle a with cos a = sqrt(t), t = 1 - r^2/D^2, continued by its tangent
 * line below PEN_SH_CAP_T0 and clamped at a = pi (sphere_view_cap); and the derivatives the
 * backward needs. */
typedef struct sphere_view {
    double v[3], D2, r, h, w, dw_dh, q, dw_dq; /* w = w_h(h) g(q), q = |v| / r (inside rule) */
    double d[3], D, a, cos_a, sin_a, da_dD, da_dr;
    int cap; /* sphere_view_cap has run */
} sphere_view;

/* Fills v, D2, h, q, w and its derivatives; returns 0 when the sphere's weight and its
 * derivatives are 0 (it hides nothing, no gradient): behind the tangent plane, or containing the
 * receiver deeper than PEN_RENDER_INSIDE_LO r. The weight is shade_ops.inc's, so that the disk
 * lights and the SH light see the same spheres. */
HOT int sphere_view_weight(const double x[3], const double n[3], const double c[3], double r,
                           sphere_view *sv) {
    for (int k = 0; k < 3; ++k)
        sv->v[k] = c[k] - x[k];
    sv->r = r;
    const double nv = n[0] * sv->v[0] + n[1] * sv->v[1] + n[2] * sv->v[2];
    if (nv <= PEN_RENDER_SELF_H0 * r) return 0; /* h <= -1, without the division */
    sv->h = nv / r;
    const double span = PEN_RENDER_SELF_H1 - PEN_RENDER_SELF_H0;
    const double u = (sv->h - PEN_RENDER_SELF_H0) / span;
    if (u <= 0.0) return 0;
    sv->D2 = sv->v[0] * sv->v[0] + sv->v[1] * sv->v[1] + sv->v[2] * sv->v[2];
    sv->q = sqrt(sv->D2) / r;
    const double e = (sv->q - PEN_RENDER_INSIDE_LO) / PEN_RENDER_INSIDE_WIDTH;
    if (e <= 0.0) return 0;
    double wh = 1.0, dwh = 0.0, g = 1.0, dg = 0.0;
    if (u < 1.0) wh = u * u * (3.0 - 2.0 * u), dwh = 6.0 * u * (1.0 - u) / span;
    if (e < 1.0) g = e * e * (3.0 - 2.0 * e), dg = 6.0 * e * (1.0 - e) / PEN_RENDER_INSIDE_WIDTH;
    sv->w = wh * g, sv->dw_dh = dwh * g, sv->dw_dq = wh * dg;
    sv->cap = 0;
    return 1;
}

/* Whether a sphere (v = c - x, |v|^2 = D2, radius r) seen from x may overlap a disk (w, b) with
 * its cap: 0 only when certainly disjoint, g >= a + b. With T = sqrt(D2 - r^2) = D cos a and
 * r = D sin a, cos g <= cos(a + b) reads v . w + r sin b <= T cos b, tested without the square
 * root: true when the left side is <= 0, else compared squared. Receivers so close that the cap is
 * continued (t < t0) always pass. */
HOT int cap_may_reach(const double v[3], double D2, double r, const double w[3], double sin_b,
                      double cos_b) {
    const double r2 = r * r;
    if (D2 * (1.0 - PEN_SH_CAP_T0) <= r2) return 1;
    const double lhs = v[0] * w[0] + v[1] * w[1] + v[2] * w[2] + r * sin_b;
    if (lhs <= 0.0) return 0;
    return lhs * lhs > (D2 - r2) * cos_b * cos_b;
}

HOT int sphere_view_reaches(const pen__lights *L, int l, const sphere_view *sv) {
    return cap_may_reach(sv->v, sv->D2, sv->r, L->w[l], L->sin_b[l], L->cos_b[l]);
}

/* Every receiver x within R of the centre m sees sphere (c, r) inside the cap that (c, r + R)
 * covers seen from m (a ray from x that hits the sphere, shifted to start at m, passes within
 * r + R of c), unless x may be close enough for the continued cap (|c - m| - R below
 * r / sqrt(1 - t0)): then the sphere is kept. R is widened by far more than the rounding of the
 * box, m and R themselves. */
static void box_ball(const double lo[3], const double hi[3], double m[3], double *R) {
    double R2 = 0.0;
    for (int a = 0; a < 3; ++a) {
        m[a] = 0.5 * (lo[a] + hi[a]);
        R2 += 0.25 * (hi[a] - lo[a]) * (hi[a] - lo[a]);
    }
    *R = sqrt(R2) * (1.0 + 1e-6) + 1e-9 * (fabs(m[0]) + fabs(m[1]) + fabs(m[2]));
}

HOT int may_shadow(const pen__lights *L, const float s[4], const double m[3], double R) {
    const double v[3] = {(double)s[0] - m[0], (double)s[1] - m[1], (double)s[2] - m[2]};
    const double D2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2], r = (double)s[3];
    const double near = 1.01 * r + R;
    int keep = D2 <= near * near;
    for (int j = 0; j < L->count && !keep; ++j) {
        const int l = L->widest[j];
        keep = cap_may_reach(v, D2, r + R, L->w[l], L->sin_b[l], L->cos_b[l]);
    }
    return keep;
}

int pen__lights_may_shadow(const pen__lights *L, const float s[4], const double m[3], double R) {
    return may_shadow(L, s, m, R);
}

int pen__lights_cull(const pen__lights *L, int sphere_count, const float *spheres,
                     const double lo[3], const double hi[3], int *idx) {
    double m[3], R;
    box_ball(lo, hi, m, &R);
    int n = 0;
    for (int i = 0; i < sphere_count; ++i)
        if (may_shadow(L, spheres + 4 * (size_t)i, m, R)) idx[n++] = i;
    return n;
}

/* The cap: d, D, a and its derivatives by D and r. */
static void sphere_view_cap(sphere_view *sv) {
    if (sv->cap) return;
    sv->cap = 1;
    const double D = sqrt(sv->D2), r = sv->r;
    sv->da_dD = sv->da_dr = 0.0;
    if (!(D > 1e-6 * r)) { /* the floor of sh.h: then the whole sphere is blocked */
        sv->D = 1e-6 * r;
        sv->d[0] = 0.0, sv->d[1] = 1.0, sv->d[2] = 0.0;
        sv->a = PEN_PI, sv->cos_a = -1.0, sv->sin_a = 0.0;
        return;
    }
    sv->D = D;
    for (int k = 0; k < 3; ++k)
        sv->d[k] = sv->v[k] / D;
    const double t = 1.0 - (r * r) / (D * D), t0 = PEN_SH_CAP_T0, s0 = sqrt(t0);
    if (t >= t0) {
        sv->cos_a = sqrt(t), sv->sin_a = r / D;
        sv->da_dD = -(r / (D * D)) / sv->cos_a;
        sv->da_dr = (1.0 / D) / sv->cos_a;
    } else {
        sv->cos_a = s0 + (t - t0) * (0.5 / s0);
        if (sv->cos_a <= -1.0) {
            sv->a = PEN_PI, sv->cos_a = -1.0, sv->sin_a = 0.0;
            return;
        }
        sv->sin_a = sqrt((1.0 - sv->cos_a) * (1.0 + sv->cos_a));
        const double da_dt = -(0.5 / s0) / sv->sin_a;
        sv->da_dD = da_dt * 2.0 * r * r / (D * D * D);
        sv->da_dr = da_dt * -2.0 * r / (D * D);
    }
    sv->a = -1.0; /* the angle itself only where a partial overlap needs it (sphere_view_angle) */
}

static double sphere_view_angle(sphere_view *sv) {
    if (sv->a < 0.0) sv->a = atan2(sv->sin_a, sv->cos_a);
    return sv->a;
}

/* The fraction of light l's disk inside the sphere's cap, and (when fd is not NULL) its partials
 * by a, b and the angle g between d and w_l; *g_out and *sin_g the angle and its sine. */
static double disk_fraction(const pen__lights *L, int l, sphere_view *sv, double fd[3],
                            double *sin_g) {
    *sin_g = 0.0;
    if (fd) fd[0] = fd[1] = fd[2] = 0.0;
    if (!sphere_view_reaches(L, l, sv)) return 0.0;
    sphere_view_cap(sv);
    const double *w = L->w[l], *d = sv->d;
    const double cg = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
    /* The two common cases without the angles: the disk clear of the cap (g >= a + b, where
     * a + b < pi) or wholly inside it (g <= a - b), decided on cosines with a margin of 1e-9 that
     * is far above their rounding, so pen__cap_overlap would take the same branch. Inside,
     * f = 1 and its partials are 0 (the disk's own area cancels), exactly. */
    const double ca = sv->cos_a, sa = sv->sin_a, cb = L->cos_b[l], sb = L->sin_b[l];
    if (sa * cb + ca * sb > 0.0 && cg < ca * cb - sa * sb - 1e-9) return 0.0;
    if (sv->a != PEN_PI && sa * cb - ca * sb > 0.0 && cg > ca * cb + sa * sb + 1e-9)
        return 1.0; /* = cap_full_area(b) / area, the same expression as L->area */
    const double cx = d[1] * w[2] - d[2] * w[1], cy = d[2] * w[0] - d[0] * w[2],
                 cz = d[0] * w[1] - d[1] * w[0];
    const double sg = sqrt(cx * cx + cy * cy + cz * cz);
    *sin_g = sg;
    const double area = L->area[l];
    double A = -1.0;
    if (L->b[l] >= PEN_LIGHTS_COS_LENS_DEG * (PEN_PI / 180.0)) {
        /* the cosine and sine of g as atan2 takes them, whatever |d| |w| (1 to rounding here;
         * the gradient checks move w off the unit sphere by 1e-7): one Newton step of
         * 1 / sqrt(x) from 1, exact to 3/8 (x - 1)^2, instead of a square root and a division */
        const double h = 1.5 - 0.5 * (cg * cg + sg * sg);
        A = pen__cap_overlap_cos(ca, sa, cb, sb, cg * h, sg * h, fd);
    }
    if (A < 0.0) A = pen__cap_overlap(sphere_view_angle(sv), L->b[l], atan2(sg, cg), fd);
    const double f = A / area;
    if (fd) {
        fd[0] /= area;
        fd[1] = (fd[1] - f * 2.0 * PEN_PI * L->sin_b[l]) / area;
        fd[2] /= area;
    }
    return f;
}

double pen__lights_fraction(const pen__lights *L, int l, const float x[3], const float s[4]) {
    sphere_view sv;
    for (int k = 0; k < 3; ++k)
        sv.v[k] = (double)s[k] - (double)x[k];
    sv.D2 = sv.v[0] * sv.v[0] + sv.v[1] * sv.v[1] + sv.v[2] * sv.v[2];
    sv.r = (double)s[3];
    sv.cap = 0;
    double sg;
    return disk_fraction(L, l, &sv, NULL, &sg);
}

double pen__lights_pair_bwd(const pen__lights *L, int l, const float x[3], const float n[3],
                            const float s[4], float kappa, double dVV, double dv[3], double *d_r,
                            double *d_light) {
    /* the pair's weight and opacity in double, as the double term has them: a small q from the
     * lanes' 1 - exp would carry 6e-8 / q of itself into d_f */
    const double xd[3] = {(double)x[0], (double)x[1], (double)x[2]};
    const double nd[3] = {(double)n[0], (double)n[1], (double)n[2]};
    const double c[3] = {(double)s[0], (double)s[1], (double)s[2]};
    sphere_view sv;
    if (!sphere_view_weight(xd, nd, c, (double)s[3], &sv)) return 0.0;
    const double q = -expm1(-L->eps * sv.w * (double)kappa);
    double fd[3], sg;
    const double f = disk_fraction(L, l, &sv, fd, &sg);
    if (f == 0.0 && fd[0] == 0.0 && fd[1] == 0.0 && fd[2] == 0.0) return 0.0;
    /* as pen__lights_bwd's pair: d_g = dV V / (1 - q f), d_f = -q d_g */
    const double d_g = dVV / (1.0 - q * f), d_f = -q * d_g, d_a = d_f * fd[0];
    if (d_light) d_light[3] += d_f * fd[1];
    if (sg > 1e-12) {
        const double dg = d_f * fd[2] / sg, *w = L->w[l];
        const double cg = sv.d[0] * w[0] + sv.d[1] * w[1] + sv.d[2] * w[2];
        for (int a = 0; a < 3; ++a) {
            dv[a] -= dg * (w[a] - cg * sv.d[a]) / sv.D;
            if (d_light) d_light[a] -= dg * (sv.d[a] - cg * w[a]);
        }
    }
    if (sv.cap) {
        for (int a = 0; a < 3; ++a)
            dv[a] += d_a * sv.da_dD * sv.d[a];
        *d_r += d_a * sv.da_dr;
    }
    return f * d_g;
}

#define IN float
#define SUF(name) name
#include "shade/lights_ops.inc"
#undef IN
#undef SUF

#define IN double
#define SUF(name) name##_d
#include "shade/lights_ops.inc"
#undef IN
#undef SUF
