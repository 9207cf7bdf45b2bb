/* The disk lights' float prefilter (pen__lights_candidates, lights.h), compiled once
 * per instruction set like the fast kernel (CMakeLists.txt, shade_fast_dispatch.c), so that its
 * lanes are the machine's vector width: it visits every (receiver, sphere) pair of a tile, and the
 * exact double tests of lights.c then run only for the pairs it keeps.
 *
 * Design
 * - Exactness. The prefilter only drops pairs, and only those that the double tests in lights.c
 *   (sphere_view_weight, cap_may_reach) drop too, so the light term and its gradients are bit for
 *   bit what the unfiltered loop gives, in every variant (the golden test checks it).
 */
#include "shade/shade.h"

#include <math.h>

#ifndef PEN_FAST_ISA
#define PEN_FAST_ISA generic
#endif
#define CAT_(a, b) a##b
#define CONT_MARGIN 1e-3f /* the continued cap's test: 50 times its rounding (below) */
#define CAT(a, b) CAT_(a, b)

void CAT(pen__lights_candidates_,
         PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres, const int *idx, int cnt,
                       const float *x, const float *nrm, const int *at, int *list, int *count);

/* Receivers and spheres in float, PEN_LIGHTS_BLOCK receivers at a time over one sphere, so that
 * the compiler keeps them in vector lanes. A pair is dropped only when the exact double tests
 * above would drop it too: the receiver deeper than 0.9 r inside the sphere (sphere_view_weight's
 * inside rule), the sphere below the receiver's tangent plane (n . v <= -r), or every light's
 * disk certainly clear of the cap (cap_may_reach). The margins cover the float rounding of v,
 * n . v, v . w and the squares (a few 1e-7 of |v| + r) many times over; a pair that a margin keeps
 * costs only the exact test. NaN receivers are kept (no comparison drops them).
 * A receiver within 1.005 r of the centre sees the continued cap (cos a on the tangent line of
 * sqrt(t) below t0), which cap_may_reach always keeps: these are the spheres around the receiver,
 * most of a pixel's visits, and most of them miss a sun. They are dropped here when the disk is
 * clear of that cap, disk_fraction's own test (cos g < cos(a + b)) with a margin of CONT_MARGIN
 * in the cosines: from |v| within 0.9 .. 1.005 r, v exact to 6e-8 (a rounded difference of two
 * floats), t = 1 - r^2 / D^2 errs by under 4e-7, cos a by 2e-6, sin a by 5e-5 (cos a kept above
 * -0.999, where d sin a / d cos a stays under 23), the test's sides by under 2e-5. The band of
 * plain caps that `cont` adds (t up to 1.1 t0) is within 1.4e-4 of the tangent line. */
void CAT(pen__lights_candidates_,
         PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres, const int *idx, int cnt,
                       const float *x, const float *nrm, const int *at, int *list, int *count) {
    float X[3][PEN_LIGHTS_BLOCK], N[3][PEN_LIGHTS_BLOCK];
    float w[PEN_SCENE_MAX_LIGHTS][3], sb[PEN_SCENE_MAX_LIGHTS], cb2[PEN_SCENE_MAX_LIGHTS];
    float cb[PEN_SCENE_MAX_LIGHTS];
    for (int l = 0; l < L->count; ++l) {
        for (int a = 0; a < 3; ++a)
            w[l][a] = (float)L->w[l][a];
        sb[l] = (float)L->sin_b[l], cb2[l] = (float)(L->cos_b[l] * L->cos_b[l]);
        cb[l] = (float)L->cos_b[l];
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
    const float t0 = (float)PEN_SH_CAP_T0, s0 = sqrtf(t0);
    for (int j = 0; j < n; ++j) {
        const int i = idx ? idx[j] : j;
        const float *sp = spheres + 4 * (size_t)i, r = sp[3], r2 = r * r;
        float vx[PEN_LIGHTS_BLOCK], vy[PEN_LIGHTS_BLOCK], vz[PEN_LIGHTS_BLOCK];
        float D2[PEN_LIGHTS_BLOCK], tol[PEN_LIGHTS_BLOCK], m2[PEN_LIGHTS_BLOCK];
        float ca[PEN_LIGHTS_BLOCK], sa[PEN_LIGHTS_BLOCK], invD[PEN_LIGHTS_BLOCK];
        int keep[PEN_LIGHTS_BLOCK], clear[PEN_LIGHTS_BLOCK], cclear[PEN_LIGHTS_BLOCK];
        for (int k = 0; k < PEN_LIGHTS_BLOCK; ++k) {
            vx[k] = sp[0] - X[0][k], vy[k] = sp[1] - X[1][k], vz[k] = sp[2] - X[2][k];
            D2[k] = vx[k] * vx[k] + vy[k] * vy[k] + vz[k] * vz[k];
            const float m = fabsf(vx[k]) + fabsf(vy[k]) + fabsf(vz[k]) + r;
            tol[k] = 1e-5f * m, m2[k] = 1e-5f * m * m;
            const float nv = N[0][k] * vx[k] + N[1][k] * vy[k] + N[2][k] * vz[k];
            keep[k] = !(nv < h0 * r - tol[k]) & !(D2[k] < deep * r2);
            const int continued = D2[k] * cont <= r2;
            clear[k] = !continued;
            /* the continued cap (keep[k] has D >= 0.9 r here: no division by 0 where it counts) */
            ca[k] = s0 + ((1.0f - r2 / D2[k]) - t0) * (0.5f / s0);
            sa[k] = sqrtf(fmaxf(1.0f - ca[k] * ca[k], 0.0f));
            invD[k] = 1.0f / sqrtf(D2[k]);
            cclear[k] = continued & (ca[k] > -0.999f);
        }
        for (int l = 0; l < L->count; ++l)
            for (int k = 0; k < PEN_LIGHTS_BLOCK; ++k) {
                const float vw = vx[k] * w[l][0] + vy[k] * w[l][1] + vz[k] * w[l][2];
                const float lhs = vw + r * sb[l];
                clear[k] &= (lhs < -tol[k]) | (lhs * lhs < (D2[k] - r2) * cb2[l] - m2[k]);
                cclear[k] &= (sa[k] * cb[l] + ca[k] * sb[l] > CONT_MARGIN) &
                             (vw * invD[k] < ca[k] * cb[l] - sa[k] * sb[l] - CONT_MARGIN);
            }
        for (int k = 0; k < cnt; ++k)
            if (keep[k] & !(clear[k] | cclear[k]))
                list[(size_t)k * (size_t)n + (size_t)count[k]++] = i;
    }
}
