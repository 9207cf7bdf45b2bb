/* Image metrics (pen_image_compare) on images whose errors are known by construction. */
#include "check.h"

#include "penumbra/penumbra.h"

#include <math.h>
#include <string.h>

static pen_image make(pen_context *ctx, int w, int h, int c, float value) {
    pen_image img;
    CHECK(pen_image_create(ctx, w, h, c, &img) == PEN_OK);
    for (size_t i = 0; i < (size_t)w * h * c; ++i)
        img.data[i] = value;
    return img;
}

static void test_identical(void) {
    pen_context *ctx = pen_context_create();
    pen_image a = make(ctx, 5, 4, 3, 0.3f);
    pen_image_error e;
    CHECK(pen_image_compare(ctx, &a, &a, NULL, &e, NULL) == PEN_OK);
    CHECK(e.rmse == 0 && e.rel_rmse == 0 && isinf(e.psnr_db) && e.pixels == 20);
    pen_image_free(&a);
    pen_context_destroy(ctx);
}

/* A = B + 0.1 everywhere, B = 0.5: rmse 0.1, rel 0.2, psnr 20 dB. */
static void test_offset(void) {
    pen_context *ctx = pen_context_create();
    pen_image a = make(ctx, 7, 3, 3, 0.6f), b = make(ctx, 7, 3, 3, 0.5f);
    pen_image_error e;
    CHECK(pen_image_compare(ctx, &a, &b, NULL, &e, NULL) == PEN_OK);
    CHECK_REL(e.rmse, 0.1, 1e-6, 0);
    CHECK_REL(e.rel_rmse, 0.2, 1e-6, 0);
    CHECK_REL(e.psnr_db, 20.0, 1e-6, 0);
    pen_image_free(&a);
    pen_image_free(&b);
    pen_context_destroy(ctx);
}

/* Errors in one channel of one pixel, and a mask that selects (or avoids) it. */
static void test_mask(void) {
    pen_context *ctx = pen_context_create();
    const int w = 4, h = 4;
    pen_image a = make(ctx, w, h, 3, 1.0f), b = make(ctx, w, h, 3, 1.0f);
    pen_image m = make(ctx, w, h, 1, 0.0f);
    a.data[3 * (1 * w + 2) + 1] = 3.0f; /* pixel (2, 1), green: error 2 */
    m.data[1 * w + 2] = 1.0f;
    m.data[3 * w + 0] = 0.75f; /* selected too (> 0.5) */
    m.data[0] = 0.5f;          /* not selected (not above 0.5) */
    pen_image_error all, in;
    CHECK(pen_image_compare(ctx, &a, &b, &m, &all, &in) == PEN_OK);
    CHECK(all.pixels == 16 && in.pixels == 2);
    CHECK_REL(all.rmse, sqrt(4.0 / 48), 1e-9, 0);
    CHECK_REL(in.rmse, sqrt(4.0 / 6), 1e-9, 0);
    CHECK_REL(in.rel_rmse, sqrt(4.0 / 6), 1e-9, 0); /* rms of B is 1 */
    CHECK_REL(in.psnr_db, -10 * log10(4.0 / 6), 1e-9, 0);
    /* A mask that avoids the bad pixel sees no error; an empty mask gives NaN and 0 pixels. */
    m.data[1 * w + 2] = 0.0f;
    CHECK(pen_image_compare(ctx, &a, &b, &m, &all, &in) == PEN_OK);
    CHECK(in.pixels == 1 && in.rmse == 0);
    memset(m.data, 0, sizeof(float) * w * h);
    CHECK(pen_image_compare(ctx, &a, &b, &m, &all, &in) == PEN_OK);
    CHECK(in.pixels == 0 && isnan(in.rmse));
    pen_image_free(&a);
    pen_image_free(&b);
    pen_image_free(&m);
    pen_context_destroy(ctx);
}

static void test_zero_reference(void) {
    pen_context *ctx = pen_context_create();
    pen_image a = make(ctx, 2, 2, 3, 0.5f), z = make(ctx, 2, 2, 3, 0.0f);
    pen_image_error e;
    CHECK(pen_image_compare(ctx, &a, &z, NULL, &e, NULL) == PEN_OK);
    CHECK(isinf(e.rel_rmse) && e.rmse == 0.5);
    CHECK(pen_image_compare(ctx, &z, &z, NULL, &e, NULL) == PEN_OK);
    CHECK(e.rel_rmse == 0);
    pen_image_free(&a);
    pen_image_free(&z);
    pen_context_destroy(ctx);
}

static void test_errors(void) {
    pen_context *ctx = pen_context_create();
    pen_image a = make(ctx, 4, 4, 3, 0.5f), b = make(ctx, 4, 3, 3, 0.5f);
    pen_image c = make(ctx, 4, 4, 3, 0.5f), m = make(ctx, 3, 4, 1, 1.0f);
    pen_image_error e, em;
    CHECK(pen_image_compare(ctx, &a, &b, NULL, &e, NULL) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "4x4") && strstr(pen_context_error(ctx), "4x3"));
    CHECK(pen_image_compare(ctx, &a, &c, &m, &e, &em) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "mask"));
    c.data[3 * 5 + 2] = NAN;
    CHECK(pen_image_compare(ctx, &a, &c, NULL, &e, NULL) == PEN_ERROR_ARGUMENT);
    CHECK(strstr(pen_context_error(ctx), "B: pixel (1, 1)"));
    pen_image empty = {0, 0, 0, NULL};
    CHECK(pen_image_compare(ctx, &empty, &a, NULL, &e, NULL) == PEN_ERROR_ARGUMENT);
    pen_image_free(&a);
    pen_image_free(&b);
    pen_image_free(&c);
    pen_image_free(&m);
    pen_context_destroy(ctx);
}

RUN_TESTS(TEST(test_identical), TEST(test_offset), TEST(test_mask), TEST(test_zero_reference),
          TEST(test_errors))
