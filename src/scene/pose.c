/* Rigid pose with uniform scale: p_world = R(w) (scale p) + t, and its backward.
 *
 * The rotation comes from an axis-angle vector (degrees in the API, w in radians inside) by
 * Rodrigues' formula written without dividing by the angle:
 *     R = I + A W + B W^2,   W = [w]x,  A = sin(theta)/theta,  B = (1 - cos theta)/theta^2,  theta
 * = |w|, and W^2 = w w^T - theta^2 I. A and B are smooth functions of s = theta^2; below s = 1e-4
 * they and their s-derivatives come from Taylor series (truncation < 1e-17), above from the closed
 * forms dA/ds = (cos theta - A) / (2 s), dB/ds = (A - 2 B) / (2 s), B = 2 sin^2(theta/2) / s. So
 *     dR/dw_j = A E_j + B (e_j w^T + w e_j^T - 2 w_j I) + 2 w_j (A' W + B' W^2),  E_j = [e_j]x,
 * holds at and near theta = 0 (where it is E_j), which matters because optimizations start from the
 * identity. The backward over many points first reduces G = sum_i d_out_i p_i^T in double, then
 * contracts G with dR/dw once, so its cost is one pass over the points.
 */
#include "penumbra/scene.h"
#include "scene/pose_internal.h"

#include <math.h>

#define DEG (3.14159265358979323846 / 180.0)

/* ---- Forward --------------------------------------------------------------------------------- */

/* A, B, dA/ds, dB/ds of Rodrigues' formula at s = theta^2. */
static void rodrigues_coeffs(double s, double c[4]) {
    if (s < 1e-4) {
        c[0] = 1.0 - s / 6.0 * (1.0 - s / 20.0 * (1.0 - s / 42.0));
        c[1] = 0.5 - s / 24.0 * (1.0 - s / 30.0 * (1.0 - s / 56.0));
        c[2] = -1.0 / 6.0 + s / 60.0 - s * s / 1680.0;
        c[3] = -1.0 / 24.0 + s / 360.0 - s * s / 13440.0;
        return;
    }
    double t = sqrt(s), h = sin(0.5 * t);
    c[0] = sin(t) / t;
    c[1] = 2.0 * h * h / s;
    c[2] = (cos(t) - c[0]) / (2.0 * s);
    c[3] = (c[0] - 2.0 * c[1]) / (2.0 * s);
}

void pen__pose_rotation_d(const double w[3], double R[9], double dR[27]) {
    double s = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    double c[4];
    rodrigues_coeffs(s, c);
    double W[9] = {0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0};
    double W2[9];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            W2[3 * a + b] = w[a] * w[b] - (a == b ? s : 0.0);
    for (int i = 0; i < 9; ++i)
        R[i] = (i % 4 == 0 ? 1.0 : 0.0) + c[0] * W[i] + c[1] * W2[i];
    if (!dR) return;
    for (int j = 0; j < 3; ++j) {
        double *D = dR + 9 * j;
        double E[9] = {0};
        /* E_j = [e_j]x: the cross-product matrix of the unit vector e_j. */
        int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
        E[3 * j2 + j1] = 1.0;
        E[3 * j1 + j2] = -1.0;
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                double dW2 =
                    (a == j ? w[b] : 0.0) + (b == j ? w[a] : 0.0) - (a == b ? 2.0 * w[j] : 0.0);
                int i = 3 * a + b;
                D[i] = c[0] * E[i] + c[1] * dW2 + 2.0 * w[j] * (c[2] * W[i] + c[3] * W2[i]);
            }
    }
}

static void pose_matrix(const pen_pose *pose, double R[9], double dR[27]) {
    double w[3];
    for (int i = 0; i < 3; ++i)
        w[i] = (double)pose->rotation_axis_angle_deg[i] * DEG;
    pen__pose_rotation_d(w, R, dR);
}

void pen_pose_rotation(const pen_pose *pose, float R[9]) {
    double Rd[9];
    pose_matrix(pose, Rd, NULL);
    for (int i = 0; i < 9; ++i)
        R[i] = (float)Rd[i];
}

static void apply_d(const double R[9], double scale, const float t[3], const float *p, float *out) {
    for (int a = 0; a < 3; ++a)
        out[a] = (float)(scale * (R[3 * a] * (double)p[0] + R[3 * a + 1] * (double)p[1] +
                                  R[3 * a + 2] * (double)p[2]) +
                         (double)t[a]);
}

void pen_pose_apply(const pen_pose *pose, const float p[3], float out[3]) {
    pen_pose_points_fwd(pose, 1, p, out);
}

void pen_pose_points_fwd(const pen_pose *pose, int n, const float *p, float *out) {
    double R[9];
    pose_matrix(pose, R, NULL);
    for (int i = 0; i < n; ++i)
        apply_d(R, (double)pose->scale, pose->translation, p + 3 * i, out + 3 * i);
}

/* ---- Backward -------------------------------------------------------------------------------- */

void pen_pose_points_bwd(const pen_pose *pose, int n, const float *p, const float *d_out,
                         pen_pose_grad *d_pose, float *d_p) {
    double R[9], dR[27];
    pose_matrix(pose, R, d_pose ? dR : NULL);
    double scale = (double)pose->scale;
    double G[9] = {0}, dt[3] = {0};
    for (int i = 0; i < n; ++i) {
        const float *g = d_out + 3 * i;
        const float *q = p + 3 * i;
        for (int a = 0; a < 3; ++a) {
            dt[a] += (double)g[a];
            for (int b = 0; b < 3; ++b)
                G[3 * a + b] += (double)g[a] * (double)q[b];
        }
        if (d_p)
            for (int b = 0; b < 3; ++b)
                d_p[3 * i + b] += (float)(scale * (R[b] * (double)g[0] + R[3 + b] * (double)g[1] +
                                                   R[6 + b] * (double)g[2]));
    }
    if (!d_pose) return;
    double ds = 0.0;
    for (int i = 0; i < 9; ++i)
        ds += R[i] * G[i];
    d_pose->scale += (float)ds;
    for (int j = 0; j < 3; ++j) {
        double dw = 0.0;
        for (int i = 0; i < 9; ++i)
            dw += dR[9 * j + i] * G[i];
        d_pose->rotation_axis_angle_deg[j] += (float)(scale * dw * DEG);
        d_pose->translation[j] += (float)dt[j];
    }
}

void pen_pose_apply_bwd(const pen_pose *pose, const float p[3], const float d_out[3],
                        pen_pose_grad *d_pose, float d_p[3]) {
    pen_pose_points_bwd(pose, 1, p, d_out, d_pose, d_p);
}
