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
#define CAT(a, b) CAT_(a, b)

void CAT(pen__lights_candidates_, PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres,
                                                const int *idx, int cnt, const float *x,
                                                const float *nrm, const int *at, int *list,
                                                int *count);

/* Receivers and spheres in float, PEN_LIGHTS_BLOCK receivers at a time over one sphere, so that
 * the compiler keeps them in vector lanes. A pair is dropped only when the exact double tests
 * above would drop it too: the receiver deeper than 0.9 r inside the sphere (sphere_view_weight's
 * inside rule), the sphere below the receiver's tangent plane (n . v <= -r), or every light's
 * disk certainly clear of the cap (cap_may_reach). The margins cover the float rounding of v,
 * n . v, v . w and the squares (a few 1e-7 of |v| + r) many times over; a pair that a margin keeps
 * costs only the exact test. NaN receivers are kept (no comparison drops them). */
void CAT(pen__lights_candidates_, PEN_FAST_ISA)(const pen__lights *L, int n, const float *spheres, const int *idx,
                            int cnt, const float *x, const float *nrm, const int *at, int *list,
                            int *count) {
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

