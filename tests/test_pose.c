/* Rigid pose: Rodrigues rotation against an independent axis-angle formula, its derivative and
 * the pose backward against central finite differences in double, at and near angle zero. */
#include "check.h"
#include "penumbra/raster.h"
#include "scene/pose_internal.h"

#include <math.h>
#include <string.h>

#define DEG (3.14159265358979323846 / 180.0)

/* Independent reference: R = cos theta I + sin theta [k]x + (1 - cos theta) k k^T with a unit axis
 * k. */
static void rotation_ref(const double w[3], double R[9]) {
    double th = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double k[3] = {1, 0, 0};
    if (th > 0) k[0] = w[0] / th, k[1] = w[1] / th, k[2] = w[2] / th;
    double c = cos(th), s = sin(th);
    double K[9] = {0, -k[2], k[1], k[2], 0, -k[0], -k[1], k[0], 0};
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            R[3 * a + b] = (a == b ? c : 0.0) + s * K[3 * a + b] + (1 - c) * k[a] * k[b];
}

static void random_w(unsigned long long *seed, double scale, double w[3]) {
    for (int i = 0; i < 3; ++i)
        w[i] = scale * (2 * check_rand_(seed) - 1);
}

static void test_rotation_matches_reference(void) {
    unsigned long long seed = 1;
    const double scales[] = {0.0, 1e-8, 1e-3, 5e-3, 0.0099, 0.0101, 0.3, 2.0, 3.1, 6.0};
    for (int s = 0; s < (int)(sizeof scales / sizeof scales[0]); ++s)
        for (int rep = 0; rep < 5; ++rep) {
            double w[3], R[9], Rr[9];
            random_w(&seed, scales[s], w);
            pen__pose_rotation_d(w, R, NULL);
            rotation_ref(w, Rr);
            for (int i = 0; i < 9; ++i)
                CHECK_NEAR(R[i], Rr[i], 1e-14);
            /* Orthonormal with determinant 1. */
            for (int a = 0; a < 3; ++a)
                for (int b = 0; b < 3; ++b) {
                    double d = 0;
                    for (int c = 0; c < 3; ++c)
                        d += R[3 * a + c] * R[3 * b + c];
                    CHECK_NEAR(d, a == b, 1e-14);
                }
        }
    /* +90 degrees about +Y takes +X to -Z (right-handed). */
    pen_pose pose = {{0, 90, 0}, {0, 0, 0}, 1};
    float p[3] = {1, 0, 0}, out[3];
    pen_pose_apply(&pose, p, out);
    CHECK_NEAR(out[0], 0, 1e-7);
    CHECK_NEAR(out[1], 0, 1e-7);
    CHECK_NEAR(out[2], -1, 1e-7);
}

static void test_rotation_derivative_fd(void) {
    unsigned long long seed = 2;
    const double scales[] = {0.0, 1e-7, 1e-3, 0.00995, 0.0100, 0.0105, 0.5, 2.5, 4.0};
    const double h = 1e-6;
    for (int s = 0; s < (int)(sizeof scales / sizeof scales[0]); ++s)
        for (int rep = 0; rep < 4; ++rep) {
            double w[3], R[9], dR[27];
            random_w(&seed, scales[s], w);
            if (s == 0 && rep > 0) continue;
            pen__pose_rotation_d(w, R, dR);
            for (int j = 0; j < 3; ++j) {
                double wp[3], wm[3], Rp[9], Rm[9];
                memcpy(wp, w, sizeof wp), memcpy(wm, w, sizeof wm);
                wp[j] += h, wm[j] -= h;
                pen__pose_rotation_d(wp, Rp, NULL);
                pen__pose_rotation_d(wm, Rm, NULL);
                for (int i = 0; i < 9; ++i)
                    CHECK_NEAR(dR[9 * j + i], (Rp[i] - Rm[i]) / (2 * h), 1e-8);
            }
        }
}

/* The pose applied in double (the forward under test is checked against rotation_ref above). */
static void apply_ref(const double aa[3], const double t[3], double scale, const double p[3],
                      double out[3]) {
    double w[3] = {aa[0] * DEG, aa[1] * DEG, aa[2] * DEG}, R[9];
    pen__pose_rotation_d(w, R, NULL);
    for (int a = 0; a < 3; ++a)
        out[a] = scale * (R[3 * a] * p[0] + R[3 * a + 1] * p[1] + R[3 * a + 2] * p[2]) + t[a];
}

static double loss_ref(const double prm[10], const double g[3]) {
    double out[3];
    apply_ref(prm, prm + 3, prm[6], prm + 7, out);
    return g[0] * out[0] + g[1] * out[1] + g[2] * out[2];
}

static void test_pose_backward_fd(void) {
    unsigned long long seed = 3;
    const double angles[] = {0.0, 1e-5, 0.3, 0.57, 0.58, 30.0, 170.0, 300.0}; /* degrees */
    for (int a = 0; a < (int)(sizeof angles / sizeof angles[0]); ++a)
        for (int rep = 0; rep < 3; ++rep) {
            pen_pose pose;
            float p[3], g[3];
            double axis[3];
            random_w(&seed, 1.0, axis);
            double n = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
            for (int i = 0; i < 3; ++i) {
                pose.rotation_axis_angle_deg[i] = (float)(angles[a] * axis[i] / n);
                pose.translation[i] = (float)(2 * check_rand_(&seed) - 1);
                p[i] = (float)(2 * check_rand_(&seed) - 1);
                g[i] = (float)(2 * check_rand_(&seed) - 1);
            }
            pose.scale = (float)(0.5 + check_rand_(&seed));
            pen_pose_grad d = {{0, 0, 0}, {0, 0, 0}, 0};
            float dp[3] = {0, 0, 0};
            pen_pose_apply_bwd(&pose, p, g, &d, dp);
            double prm[10], gd[3] = {g[0], g[1], g[2]};
            for (int i = 0; i < 3; ++i) {
                prm[i] = pose.rotation_axis_angle_deg[i];
                prm[3 + i] = pose.translation[i];
                prm[7 + i] = p[i];
            }
            prm[6] = pose.scale;
            float an[10] = {d.rotation_axis_angle_deg[0],
                            d.rotation_axis_angle_deg[1],
                            d.rotation_axis_angle_deg[2],
                            d.translation[0],
                            d.translation[1],
                            d.translation[2],
                            d.scale,
                            dp[0],
                            dp[1],
                            dp[2]};
            for (int i = 0; i < 10; ++i) {
                double h = i < 3 ? 1e-4 : 1e-6, pp[10], pm[10];
                memcpy(pp, prm, sizeof pp), memcpy(pm, prm, sizeof pm);
                pp[i] += h, pm[i] -= h;
                double fd = (loss_ref(pp, gd) - loss_ref(pm, gd)) / (2 * h);
                CHECK_REL(an[i], fd, 1e-5, 1e-3);
            }
        }
}

static void test_points_match_single(void) {
    unsigned long long seed = 4;
    pen_pose pose = {{10, -20, 35}, {0.1f, 0.2f, -0.3f}, 1.3f};
    float p[5 * 3], g[5 * 3], out[5 * 3], dp[5 * 3] = {0}, dp1[3];
    for (int i = 0; i < 15; ++i) {
        p[i] = (float)(2 * check_rand_(&seed) - 1);
        g[i] = (float)(2 * check_rand_(&seed) - 1);
    }
    pen_pose_points_fwd(&pose, 5, p, out);
    pen_pose_grad dsum = {{0}, {0}, 0}, d = {{0}, {0}, 0};
    pen_pose_points_bwd(&pose, 5, p, g, &dsum, dp);
    for (int k = 0; k < 5; ++k) {
        float o[3];
        pen_pose_apply(&pose, p + 3 * k, o);
        for (int i = 0; i < 3; ++i)
            CHECK(o[i] == out[3 * k + i]);
        dp1[0] = dp1[1] = dp1[2] = 0;
        pen_pose_apply_bwd(&pose, p + 3 * k, g + 3 * k, &d, dp1);
        for (int i = 0; i < 3; ++i)
            CHECK_NEAR(dp1[i], dp[3 * k + i], 1e-6);
    }
    for (int i = 0; i < 3; ++i) {
        CHECK_NEAR(d.rotation_axis_angle_deg[i], dsum.rotation_axis_angle_deg[i], 1e-5);
        CHECK_NEAR(d.translation[i], dsum.translation[i], 1e-5);
    }
    CHECK_NEAR(d.scale, dsum.scale, 1e-5);
    /* NULL gradients are skipped. */
    pen_pose_points_bwd(&pose, 5, p, g, NULL, NULL);
    float R[9];
    pen_pose_rotation(&pose, R);
    CHECK(isfinite(R[0]) && fabsf(R[0] * R[0] + R[3] * R[3] + R[6] * R[6] - 1) < 1e-6f);
}

RUN_TESTS(TEST(test_rotation_matches_reference), TEST(test_rotation_derivative_fd),
          TEST(test_pose_backward_fd), TEST(test_points_match_single))
