/* Environment maps: the direction convention, lookups, and the projection onto SH, checked
 * against maps whose SH coefficients are known. */
#include "io_fixtures.h"

#define ctx fixture_ctx()

static const double SQRT_4PI = 3.5449077018110318;

/* A W x H map whose value at each pixel centre is f(direction), per channel. */
typedef void (*map_fn)(const double d[3], const void *arg, double rgb[3]);

static pen_image make_map(int W, int H, map_fn f, const void *arg) {
    pen_image im;
    CHECK(pen_image_create(ctx, W, H, 3, &im) == PEN_OK);
    for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
            float d[3];
            pen_envmap_direction((x + 0.5f) / (float)W, (y + 0.5f) / (float)H, d);
            double dd[3] = {d[0], d[1], d[2]}, rgb[3];
            f(dd, arg, rgb);
            for (int c = 0; c < 3; ++c)
                im.data[3 * ((size_t)y * W + x) + c] = (float)rgb[c];
        }
    }
    return im;
}

static void constant_fn(const double d[3], const void *arg, double rgb[3]) {
    const double *v = arg;
    for (int c = 0; c < 3; ++c)
        rgb[c] = v[c];
}

/* Sum of c[i][ch] Y_i(d) for 4 bands. */
static void sh_fn(const double d[3], const void *arg, double rgb[3]) {
    const double(*c)[3] = arg;
    double y[16];
    pen_sh_eval_d(4, d, y);
    for (int ch = 0; ch < 3; ++ch) {
        rgb[ch] = 0;
        for (int i = 0; i < 16; ++i)
            rgb[ch] += c[i][ch] * y[i];
    }
}

static void test_convention(void) {
    float d[3], u, v;
    pen_envmap_direction(0.5f, 0.5f, d); /* image centre: -Z */
    CHECK_NEAR(d[0], 0, 1e-6);
    CHECK_NEAR(d[1], 0, 1e-6);
    CHECK_NEAR(d[2], -1, 1e-6);
    pen_envmap_direction(0.75f, 0.5f, d); /* right of centre: +X */
    CHECK_NEAR(d[0], 1, 1e-6);
    CHECK_NEAR(d[2], 0, 1e-6);
    pen_envmap_direction(0.25f, 0.5f, d);
    CHECK_NEAR(d[0], -1, 1e-6);
    pen_envmap_direction(0.0f, 0.5f, d);
    CHECK_NEAR(d[2], 1, 1e-6);
    pen_envmap_direction(0.3f, 0.0f, d); /* row 0: zenith */
    CHECK_NEAR(d[1], 1, 1e-6);
    pen_envmap_direction(0.3f, 1.0f, d);
    CHECK_NEAR(d[1], -1, 1e-6);
    /* uv inverts direction (away from the poles, where u is undefined). */
    unsigned long long seed = 7;
    for (int i = 0; i < 200; ++i) {
        float u0 = (float)check_rand_(&seed), v0 = (float)(0.01 + 0.98 * check_rand_(&seed));
        pen_envmap_direction(u0, v0, d);
        double n2 = 0;
        for (int k = 0; k < 3; ++k)
            n2 += (double)d[k] * (double)d[k];
        CHECK_NEAR(n2, 1, 1e-6);
        d[0] *= 3, d[1] *= 3, d[2] *= 3; /* any length */
        pen_envmap_uv(d, &u, &v);
        double du = fabs((double)u - (double)u0);
        CHECK_MSG(fmin(du, 1 - du) < 1e-5, "u %g vs %g", (double)u, (double)u0);
        CHECK_NEAR(v, v0, 1e-5);
        CHECK(u >= 0 && u < 1);
    }
    float zero[3] = {0, 0, 0};
    pen_envmap_uv(zero, &u, &v);
    CHECK(u == 0 && v == 0);
}

static void test_constant_map(void) {
    const double value[3] = {0.5, 1.0, 2.0};
    int W = 128, H = 64;
    pen_image im = make_map(W, H, constant_fn, value);
    float sh[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_envmap_to_sh(ctx, &im, 8, 33.0f, 1.0f, sh) == PEN_OK);
    for (int c = 0; c < 3; ++c)
        CHECK_REL(sh[0][c], SQRT_4PI * value[c], 1e-6, 0);
    /* l > 0: only the quadrature error of sampling each row at its centre, O(l^2 / H^2); at
     * H = 64 and l < 8 it stays below 1e-3 of the DC term (measured: 2.5e-4). */
    for (int i = 1; i < 64; ++i) {
        for (int c = 0; c < 3; ++c) {
            double got = sh[i][c], dc = sh[0][c];
            CHECK_MSG(fabs(got) < 1e-3 * dc, "coefficient %d: %g", i, got);
        }
    }
    /* Scale multiplies; negative pixels are clamped to 0 (a map of -1 projects to nothing). */
    float sh2[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_envmap_to_sh(ctx, &im, 2, 0.0f, 3.0f, sh2) == PEN_OK);
    CHECK_REL(sh2[0][1], 3.0 * SQRT_4PI, 1e-6, 0);
    for (size_t i = 0; i < (size_t)W * H * 3; ++i)
        im.data[i] = -1.0f;
    CHECK(pen_envmap_to_sh(ctx, &im, 2, 0.0f, 1.0f, sh2) == PEN_OK);
    for (int i = 0; i < 4; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK(sh2[i][c] == 0.0f);
    pen_image_free(&im);
}

static void test_known_sh(void) {
    /* A positive 4-band function: DC 5, the others in [-0.1, 0.1] (the largest |Y_l| for l < 4
     * is below 0.75, so the function stays above 5 * 0.28 - 15 * 0.1 * 0.75 > 0). */
    double c[16][3];
    unsigned long long seed = 11;
    for (int i = 0; i < 16; ++i)
        for (int ch = 0; ch < 3; ++ch)
            c[i][ch] = i == 0 ? 5.0 : 0.2 * check_rand_(&seed) - 0.1;
    pen_image im = make_map(256, 128, sh_fn, c);
    float sh[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_envmap_to_sh(ctx, &im, 6, 0.0f, 1.0f, sh) == PEN_OK);
    /* Recovered to the error of sampling cells at their centres, O(1/H^2) (measured 2.7e-4 at
     * H = 128 with a DC of 5); bands 4 and 5 vanish to the same error. */
    for (int i = 0; i < 36; ++i)
        for (int ch = 0; ch < 3; ++ch)
            CHECK_NEAR(sh[i][ch], i < 16 ? c[i][ch] : 0.0, 1e-3);
    pen_image_free(&im);

    /* Rotation about +Y: the l = 1 part of a + b (k . d) is the vector k; projecting with
     * rotation a must give R_y(a) k. With Y_1,-1 = -0.4886 y, Y_10 = 0.4886 z,
     * Y_11 = -0.4886 x, k is proportional to (-L_11, -L_1-1, L_10). */
    double k[3] = {0.6, 0.0, 0.8}, lin[16][3];
    memset(lin, 0, sizeof lin);
    for (int ch = 0; ch < 3; ++ch) {
        lin[0][ch] = 4.0;
        lin[pen_sh_index(1, 1)][ch] = -k[0];
        lin[pen_sh_index(1, -1)][ch] = -k[1];
        lin[pen_sh_index(1, 0)][ch] = k[2];
    }
    im = make_map(256, 128, sh_fn, lin);
    CHECK(pen_envmap_to_sh(ctx, &im, 2, 90.0f, 1.0f, sh) == PEN_OK);
    /* R_y(90) (x, y, z) = (z, y, -x) */
    CHECK_NEAR(-sh[pen_sh_index(1, 1)][0], k[2], 2e-3);
    CHECK_NEAR(-sh[pen_sh_index(1, -1)][0], k[1], 2e-3);
    CHECK_NEAR(sh[pen_sh_index(1, 0)][0], -k[0], 2e-3);
    pen_image_free(&im);
}

static void test_eval(void) {
    pen_image im;
    CHECK(pen_image_create(ctx, 8, 4, 3, &im) == PEN_OK);
    for (size_t i = 0; i < 8 * 4 * 3; ++i)
        im.data[i] = (float)i;
    im.data[3 * (8 + 2)] = -5.0f; /* pixel (2, 1), red */
    /* At a texel centre the lookup is that texel, times scale; negatives read as 0. */
    float d[3], rgb[3];
    pen_envmap_direction(5.5f / 8, 2.5f / 4, d);
    pen_envmap_eval(&im, 0.0f, 2.0f, d, rgb);
    for (int c = 0; c < 3; ++c)
        CHECK_NEAR(rgb[c], 2.0 * (3 * (8 * 2 + 5) + c), 1e-3);
    pen_envmap_direction(2.5f / 8, 1.5f / 4, d);
    pen_envmap_eval(&im, 0.0f, 1.0f, d, rgb);
    CHECK_NEAR(rgb[0], 0.0, 1e-4);
    /* Halfway between two texel centres: their mean (bilinear), also across the u seam. */
    pen_envmap_direction(1.0f / 8, 2.5f / 4, d);
    pen_envmap_eval(&im, 0.0f, 1.0f, d, rgb);
    CHECK_NEAR(rgb[1], 0.5 * ((3 * 16 + 1) + (3 * 17 + 1)), 1e-3);
    pen_envmap_direction(0.0f, 2.5f / 4, d);
    pen_envmap_eval(&im, 0.0f, 1.0f, d, rgb);
    CHECK_NEAR(rgb[1], 0.5 * ((3 * 16 + 1) + (3 * 23 + 1)), 1e-3);
    /* A rotated map seen along R_y(a) d shows what the unrotated map shows along d. */
    unsigned long long seed = 5;
    for (int i = 0; i < 50; ++i) {
        pen_envmap_direction((float)check_rand_(&seed), (float)check_rand_(&seed), d);
        double a = 1.1, ca = cos(a), sa = sin(a);
        float r[3] = {(float)(ca * (double)d[0] + sa * (double)d[2]), d[1],
                      (float)(-sa * (double)d[0] + ca * (double)d[2])};
        float want[3];
        pen_envmap_eval(&im, 0.0f, 1.0f, d, want);
        pen_envmap_eval(&im, (float)(a * 180.0 / 3.14159265358979323846), 1.0f, r, rgb);
        for (int c = 0; c < 3; ++c)
            CHECK_NEAR(rgb[c], want[c], 1e-2);
    }
    pen_image_free(&im);
}

static void test_errors_and_bundled(void) {
    pen_image im;
    float sh[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_image_create(ctx, 8, 4, 3, &im) == PEN_OK);
    CHECK_ERROR(ctx, pen_envmap_to_sh(ctx, &im, 0, 0.0f, 1.0f, sh), PEN_ERROR_ARGUMENT, "bands 0");
    CHECK_ERROR(ctx, pen_envmap_to_sh(ctx, &im, 9, 0.0f, 1.0f, sh), PEN_ERROR_ARGUMENT, "bands 9");
    CHECK_ERROR(ctx, pen_envmap_to_sh(ctx, &im, 2, 0.0f, -1.0f, sh), PEN_ERROR_ARGUMENT, "scale");
    im.data[3 * (8 * 3 + 6) + 1] = NAN;
    CHECK_ERROR(ctx, pen_envmap_to_sh(ctx, &im, 2, 0.0f, 1.0f, sh), PEN_ERROR_ARGUMENT,
                "pixel (6, 3)");
    pen_image_free(&im);
    CHECK_ERROR(ctx, pen_envmap_to_sh(ctx, &im, 2, 0.0f, 1.0f, sh), PEN_ERROR_ARGUMENT, "image");

    /* The bundled maps: the EXR and its RGBE copy project to the same lighting. */
    char pe[512], ph[512];
    snprintf(pe, sizeof pe, "%s/data/envmaps/city.exr", PEN_SOURCE_DIR);
    snprintf(ph, sizeof ph, "%s/data/envmaps/city.hdr", PEN_SOURCE_DIR);
    pen_image e, h;
    CHECK(pen_image_load(ctx, pe, &e) == PEN_OK);
    CHECK(pen_image_load(ctx, ph, &h) == PEN_OK);
    float se[PEN_SH_MAX_COEFFS][3], shh[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_envmap_to_sh(ctx, &e, 4, 0.0f, 1.0f, se) == PEN_OK);
    CHECK(pen_envmap_to_sh(ctx, &h, 4, 0.0f, 1.0f, shh) == PEN_OK);
    for (int c = 0; c < 3; ++c)
        CHECK(se[0][c] > 0);
    for (int i = 0; i < 16; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK_NEAR(se[i][c], shh[i][c], 0.02 * (double)se[0][c]);
    pen_image_free(&e);
    pen_image_free(&h);
}

RUN_TESTS(TEST(test_convention), TEST(test_constant_map), TEST(test_known_sh), TEST(test_eval),
          TEST(test_errors_and_bundled))
