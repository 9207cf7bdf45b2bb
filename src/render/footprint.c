/* The footprint of a pixel's texture lookup: J = d(uv)/d(pixel x, y) of the pixel's triangle at
 * the pixel centre, forward and backward, for the footprint-filtered albedo lookup
 * (src/scene/texture.c, docs/design.md sec. 1.4).
 *
 * Design
 * - The pixel's ray eye + t D (D = pen_view_ray at the pixel centre, forward component 1) meets
 *   the triangle p0 + b1 e1 + b2 e2 (e1 = p1 - p0, e2 = p2 - p0) where, by Cramer's rule with
 *   w = eye - p0 and n = e1 x e2, b1 = D.a / D.n and b2 = D.b / D.n, a = w x e2, b = e1 x w.
 *   These are the rasterizer's perspective-correct barycentrics. Their derivatives in D are
 *   g1 = (a - b1 n) / D.n and g2 = (b - b2 n) / D.n, and dD/dx = right / fx, dD/dy = -up / fy;
 *   the uv is affine in (b1, b2), so J = [uv1 - uv0, uv2 - uv0] [g1.dD/dx, g1.dD/dy;
 *   g2.dD/dx, g2.dD/dy]. All in double; an edge-on triangle (D.n = 0) gets J = 0. The forward
 *   runs over the pixels in parallel (each its own).
 * - Objects with texture_filter "point" skip all of it (one lookup at the pixel's uv).
 * - The backward runs the same chain in reverse into the three posed corners (the uvs and the
 *   view carry no gradient), so the pose and vertex gradients include how the footprint itself
 *   changes with the geometry. It is serial over the object's pixels (fixed summation order).
 */
#include "core/vec.h"
#include "render/render_internal.h"
#include "scene/camera.h"

#include <math.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

/* The per-pixel quantities of the derivation above. Those of the triangle alone (e1, e2, w, n, a,
 * b, duv) and of the view (Q) are kept from the object's previous pixel while it lies on the same
 * triangle (tri), as neighbouring pixels mostly do: footprint_at recomputes only D and what
 * depends on it, with the same operations, so the values are the same. */
typedef struct footprint {
    double e1[3], e2[3], w[3], n[3], a[3], b[3], D[3];
    double dn, b1, b2, g1[3], g2[3];
    double Q[2][3];      /* dD/dx, dD/dy */
    double duv[2][2];    /* duv[r][m]: component r of uv_{m+1} - uv0 */
    long tri;            /* the triangle of e1 .. duv, or -1 */
} footprint;

/* Sets f up for footprint_at: the view's part, no triangle yet. */
static void footprint_init(const pen_render_state *st, footprint *f) {
    const pen_view *vw = &st->view;
    for (int c = 0; c < 3; ++c) {
        f->Q[0][c] = vw->right[c] / vw->focal[0];
        f->Q[1][c] = -vw->up[c] / vw->focal[1];
    }
    f->tri = -1;
}

/* Fills f for pixel i of object o; returns 0 when the triangle is edge-on to the ray. */
static int footprint_at(const pen_render_state *st, const pen_object *ob, int o, size_t i,
                        footprint *f) {
    const pen_view *vw = &st->view;
    const size_t W = (size_t)st->width, t = (size_t)st->gb.triangle[i];
    if (f->tri != (long)t) {
        const uint32_t *vi = ob->mesh.indices + 3 * t, *ti = ob->mesh.uv_indices + 3 * t;
        const float *world = st->obj[o].world.data;
        double p[3][3];
        for (int k = 0; k < 3; ++k)
            for (int c = 0; c < 3; ++c)
                p[k][c] = (double)world[3 * (size_t)vi[k] + (size_t)c];
        pen__sub_d(p[1], p[0], f->e1), pen__sub_d(p[2], p[0], f->e2);
        pen__sub_d(vw->eye, p[0], f->w);
        pen__cross_d(f->e1, f->e2, f->n), pen__cross_d(f->w, f->e2, f->a);
        pen__cross_d(f->e1, f->w, f->b);
        const float *uv0 = ob->mesh.uvs + 2 * (size_t)ti[0],
                    *uv1 = ob->mesh.uvs + 2 * (size_t)ti[1],
                    *uv2 = ob->mesh.uvs + 2 * (size_t)ti[2];
        for (int r = 0; r < 2; ++r) {
            f->duv[r][0] = (double)uv1[r] - (double)uv0[r];
            f->duv[r][1] = (double)uv2[r] - (double)uv0[r];
        }
        f->tri = (long)t;
    }
    /* pen_view_ray, inlined */
    pen__camera_ray_d(vw->right, vw->up, vw->forward, vw->focal, vw->cx, vw->cy,
                      (double)(i % W) + 0.5, (double)(i / W) + 0.5, f->D);
    f->dn = pen__dot_d(f->D, f->n);
    if (!(fabs(f->dn) > 1e-300)) return 0;
    f->b1 = pen__dot_d(f->D, f->a) / f->dn, f->b2 = pen__dot_d(f->D, f->b) / f->dn;
    for (int c = 0; c < 3; ++c) {
        f->g1[c] = (f->a[c] - f->b1 * f->n[c]) / f->dn;
        f->g2[c] = (f->b[c] - f->b2 * f->n[c]) / f->dn;
    }
    return 1;
}

/* J = duv [g1.Q; g2.Q] at the pixel of f, each entry finite or 0. */
static void footprint_J(const footprint *f, float J[4]) {
#if defined(__SSE2__)
    /* Two entries at a time, lane c for Q[c]: each with the scalar loop's operations in its order
     * (pen__dot_d left to right, then duv's two terms); cvtpd2ps rounds as the (float) cast. */
    __m128d q1 = _mm_setzero_pd(), q2 = _mm_setzero_pd();
    for (int k = 0; k < 3; ++k) {
        const __m128d Qk = _mm_setr_pd(f->Q[0][k], f->Q[1][k]);
        const __m128d t1 = _mm_mul_pd(_mm_set1_pd(f->g1[k]), Qk);
        const __m128d t2 = _mm_mul_pd(_mm_set1_pd(f->g2[k]), Qk);
        q1 = k ? _mm_add_pd(q1, t1) : t1, q2 = k ? _mm_add_pd(q2, t2) : t2;
    }
    const __m128d mag = _mm_castsi128_pd(_mm_set1_epi64x(0x7fffffffffffffffLL));
    const __m128d inf = _mm_set1_pd(INFINITY);
    __m128 v[2], ok[2];
    for (int r = 0; r < 2; ++r) {
        const __m128d j = _mm_add_pd(_mm_mul_pd(_mm_set1_pd(f->duv[r][0]), q1),
                                     _mm_mul_pd(_mm_set1_pd(f->duv[r][1]), q2));
        v[r] = _mm_cvtpd_ps(j);
        ok[r] = _mm_castpd_ps(_mm_cmplt_pd(_mm_and_pd(j, mag), inf)); /* isfinite */
    }
    const __m128 m = _mm_shuffle_ps(ok[0], ok[1], _MM_SHUFFLE(2, 0, 2, 0));
    _mm_storeu_ps(J, _mm_and_ps(_mm_movelh_ps(v[0], v[1]), m));
#else
    for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 2; ++c) {
            const double j = f->duv[r][0] * pen__dot_d(f->g1, f->Q[c]) +
                             f->duv[r][1] * pen__dot_d(f->g2, f->Q[c]);
            J[2 * r + c] = isfinite(j) ? (float)j : 0.0f;
        }
#endif
}

void pen__uv_footprint_fwd(pen_render_state *st, const pen_object *ob, int o, int threads) {
    const long np = (long)st->width * (long)st->height;
    /* every pixel on its own (a thread's footprint keeps only what footprint_at would recompute
     * the same): the result does not depend on the threads */
#pragma omp parallel num_threads(threads) if (threads > 1 && np >= PEN_RENDER_PARALLEL_MIN_PIXELS)
    {
        footprint f;
        footprint_init(st, &f);
#pragma omp for schedule(static)
        for (long ii = 0; ii < np; ++ii) {
            const size_t i = (size_t)ii;
            if (st->gb.surface[i] != o) continue;
            float *J = st->uvj.data + 4 * i;
            if (!footprint_at(st, ob, o, i, &f)) {
                J[0] = J[1] = J[2] = J[3] = 0.0f;
                continue;
            }
            footprint_J(&f, J);
        }
    }
}

/* d_y += x x d_c and d_x += d_c x ... : the backward of c = x x y into d_x, d_y (either NULL). */
static void cross_bwd(const double x[3], const double y[3], const double d_c[3], double d_x[3],
                      double d_y[3]) {
    double t[3];
    if (d_x) {
        pen__cross_d(y, d_c, t);
        for (int k = 0; k < 3; ++k)
            d_x[k] += t[k];
    }
    if (d_y) {
        pen__cross_d(d_c, x, t);
        for (int k = 0; k < 3; ++k)
            d_y[k] += t[k];
    }
}

/* The backward of g = (v - beta n) / dn with beta = D.v / dn, given d_g: adds into d_v, d_n and
 * d_dn. */
static void bary_grad_bwd(const footprint *f, double beta, const double g[3], const double d_g[3],
                          double d_v[3], double d_n[3], double *d_dn) {
    const double d_beta = -pen__dot_d(d_g, f->n) / f->dn;
    *d_dn -= pen__dot_d(d_g, g) / f->dn + d_beta * beta / f->dn;
    for (int c = 0; c < 3; ++c) {
        d_v[c] += d_g[c] / f->dn + d_beta * f->D[c] / f->dn;
        d_n[c] -= beta * d_g[c] / f->dn;
    }
}

void pen__uv_footprint_bwd(const pen_render_state *st, const pen_object *ob, int o,
                           float *d_world) {
    const size_t np = (size_t)st->width * (size_t)st->height;
    footprint f;
    footprint_init(st, &f);
    for (size_t i = 0; i < np; ++i) {
        if (st->gb.surface[i] != o) continue;
        const float *dJ = st->d_uvj.data + 4 * i;
        if (dJ[0] == 0.0f && dJ[1] == 0.0f && dJ[2] == 0.0f && dJ[3] == 0.0f) continue;
        if (!footprint_at(st, ob, o, i, &f)) continue;
        double d_g1[3] = {0, 0, 0}, d_g2[3] = {0, 0, 0};
        for (int r = 0; r < 2; ++r)
            for (int c = 0; c < 2; ++c)
                for (int k = 0; k < 3; ++k) {
                    d_g1[k] += (double)dJ[2 * r + c] * f.duv[r][0] * f.Q[c][k];
                    d_g2[k] += (double)dJ[2 * r + c] * f.duv[r][1] * f.Q[c][k];
                }
        double d_a[3] = {0, 0, 0}, d_b[3] = {0, 0, 0}, d_n[3] = {0, 0, 0}, d_dn = 0.0;
        bary_grad_bwd(&f, f.b1, f.g1, d_g1, d_a, d_n, &d_dn);
        bary_grad_bwd(&f, f.b2, f.g2, d_g2, d_b, d_n, &d_dn);
        for (int c = 0; c < 3; ++c)
            d_n[c] += d_dn * f.D[c];
        double d_e1[3] = {0, 0, 0}, d_e2[3] = {0, 0, 0}, d_w[3] = {0, 0, 0};
        cross_bwd(f.e1, f.e2, d_n, d_e1, d_e2); /* n = e1 x e2 */
        cross_bwd(f.w, f.e2, d_a, d_w, d_e2);   /* a = w x e2 */
        cross_bwd(f.e1, f.w, d_b, d_e1, d_w);   /* b = e1 x w */
        const uint32_t *vi = ob->mesh.indices + 3 * (size_t)st->gb.triangle[i];
        float *d0 = d_world + 3 * (size_t)vi[0], *d1 = d_world + 3 * (size_t)vi[1],
              *d2 = d_world + 3 * (size_t)vi[2];
        if (!isfinite(d_e1[0] + d_e1[1] + d_e1[2] + d_e2[0] + d_e2[1] + d_e2[2] + d_w[0] + d_w[1] +
                      d_w[2]))
            continue;
        for (int c = 0; c < 3; ++c) {
            d1[c] += (float)d_e1[c];
            d2[c] += (float)d_e2[c];
            d0[c] -= (float)(d_e1[c] + d_e2[c] + d_w[c]);
        }
    }
}

void pen__render_texture_fwd(const pen_render_state *st, const pen_object *ob, size_t i,
                             float rho[3]) {
    const float *uv = st->uv.data + 2 * i;
    if (!pen__render_footprint(ob))
        pen__texture_fwd(&ob->texture, uv, rho);
    else
        pen__texture_footprint_fwd(&ob->texture, uv, st->uvj.data + 4 * i, rho);
}

void pen__render_texture_bwd(const pen_render_state *st, const pen_object *ob, size_t i,
                             const float d_rho[3], float *d_texels, float d_uv[2], float d_J[4]) {
    const float *uv = st->uv.data + 2 * i;
    if (!pen__render_footprint(ob))
        pen__texture_bwd(&ob->texture, uv, d_rho, d_texels, d_uv);
    else
        pen__texture_footprint_bwd(&ob->texture, uv, st->uvj.data + 4 * i, d_rho, d_texels, d_uv,
                                   d_J);
}
