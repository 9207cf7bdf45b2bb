/* Image files: round trips through PNG (sRGB), HDR (RGBE) and EXR (float), the bundled
 * environment maps, grey/alpha/16-bit PNG inputs, and malformed files. */
#include "io_fixtures.h"

#include <png.h>
#include <stb_image_write.h>
#include <zlib.h>

#define ctx fixture_ctx()

/* A w x h x c image with values in [lo, hi) from a fixed seed. */
static pen_image random_image(int w, int h, int c, double lo, double hi, unsigned long long seed) {
    pen_image im;
    CHECK(pen_image_create(ctx, w, h, c, &im) == PEN_OK);
    for (size_t i = 0; i < (size_t)w * h * c; ++i)
        im.data[i] = (float)(lo + (hi - lo) * check_rand_(&seed));
    return im;
}

static double srgb_decode(double c) {
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

static void test_create(void) {
    pen_image im;
    CHECK(pen_image_create(ctx, 3, 2, 3, &im) == PEN_OK);
    CHECK(im.width == 3 && im.height == 2 && im.channels == 3 && im.data[17] == 0.0f);
    pen_image_free(&im);
    CHECK(im.data == NULL);
    pen_image_free(NULL);
    CHECK_ERROR(ctx, pen_image_create(ctx, PEN_IMAGE_MAX_DIM + 1, 1, 3, &im), PEN_ERROR_ARGUMENT,
                "outside");
    CHECK_ERROR(ctx, pen_image_create(ctx, 4, 4, 5, &im), PEN_ERROR_ARGUMENT, "x 5");
    CHECK(im.data == NULL);
}

static void test_png_round_trip(void) {
    /* Values beyond [0, 1] are clamped; inside, the error is at most half an 8-bit sRGB step
     * times the largest slope of the decoding curve (2.4 / 1.055 at 1): 0.5 / 255 * 2.275 =
     * 0.0045 in linear units. */
    pen_image a = random_image(17, 9, 3, -0.2, 1.2, 1);
    const char *p = fixture_path("rt.png");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    pen_image b;
    CHECK(pen_image_load(ctx, p, &b) == PEN_OK);
    CHECK(b.width == 17 && b.height == 9 && b.channels == 3);
    double worst = 0;
    for (size_t i = 0; i < 17 * 9 * 3; ++i) {
        double want = fmin(fmax((double)a.data[i], 0.0), 1.0);
        worst = fmax(worst, fabs((double)b.data[i] - want));
    }
    CHECK_MSG(worst < 0.005, "worst %g", worst);
    /* Loading decodes every 8-bit code to exactly the sRGB curve's value: re-saving is lossless. */
    const char *q = fixture_path("rt2.png");
    CHECK(pen_image_save(ctx, q, &b) == PEN_OK);
    pen_image c;
    CHECK(pen_image_load(ctx, q, &c) == PEN_OK);
    CHECK(memcmp(b.data, c.data, 17 * 9 * 3 * sizeof(float)) == 0);
    pen_image_free(&c);
    /* Raw loading skips the sRGB decoding. */
    CHECK(pen_image_load_ex(ctx, q, PEN_IMAGE_LOAD_RAW, &c) == PEN_OK);
    for (size_t i = 0; i < 17 * 9 * 3; i += 7) {
        double code = round((double)c.data[i] * 255.0);
        CHECK_NEAR(c.data[i], code / 255.0, 1e-6);
        CHECK_NEAR(b.data[i], srgb_decode(code / 255.0), 1e-6);
    }
    pen_image_free(&a);
    pen_image_free(&b);
    pen_image_free(&c);
    CHECK(fixture_temp_files() == 0);
}

/* Grey, grey+alpha and RGBA 8-bit PNGs (written by stb) and a 16-bit grey PNG (libpng). */
static void test_png_layouts(void) {
    unsigned char px[2 * 2 * 4] = {0,  64, 128, 255, 10, 20,  30,  40,
                                   50, 60, 70,  80,  90, 100, 110, 120};
    const int comps[] = {1, 2, 4};
    for (int k = 0; k < 3; ++k) {
        int comp = comps[k];
        char name[32];
        snprintf(name, sizeof name, "layout%d.png", comp);
        const char *p = fixture_path(name);
        CHECK(stbi_write_png(p, 2, 2, comp, px, 2 * comp));
        pen_image im;
        CHECK(pen_image_load(ctx, p, &im) == PEN_OK);
        CHECK(im.channels == 3 && im.width == 2 && im.height == 2);
        for (int i = 0; i < 4; ++i) {
            for (int c = 0; c < 3; ++c) {
                int code = px[i * comp + (comp == 4 ? c : 0)];
                CHECK_NEAR(im.data[3 * i + c], srgb_decode(code / 255.0), 1e-6);
            }
        }
        pen_image_free(&im);
    }
    /* 16-bit grey through libpng. */
    const char *p = fixture_path("grey16.png");
    FILE *f = fopen(p, "wb");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png_create_info_struct(png);
    png_init_io(png, f);
    png_set_IHDR(png, info, 3, 1, 16, PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    unsigned short vals[3] = {0, 1000, 65535};
    unsigned char row[6];
    for (int i = 0; i < 3; ++i)
        row[2 * i] = (unsigned char)(vals[i] >> 8), row[2 * i + 1] = (unsigned char)vals[i];
    png_write_row(png, row);
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    fclose(f);
    pen_image im;
    CHECK(pen_image_load(ctx, p, &im) == PEN_OK);
    for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK_NEAR(im.data[3 * i + c], srgb_decode(vals[i] / 65535.0), 1e-6);
    pen_image_free(&im);
}

static void test_hdr_exr_round_trip(void) {
    pen_image a = random_image(13, 7, 3, 0.0, 50.0, 2);
    a.data[5] = 1e4f;
    a.data[6] = 1e-3f;
    pen_image b;
    /* RGBE: 8-bit mantissas sharing the exponent e of the pixel's largest channel m
     * (2^(e-1) <= m < 2^e), truncated: the error is below 2^e / 256 < m / 128. */
    const char *p = fixture_path("rt.hdr");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    CHECK(pen_image_load(ctx, p, &b) == PEN_OK);
    CHECK(b.width == 13 && b.height == 7);
    for (size_t px = 0; px < 13 * 7; ++px) {
        double big = fmax(fmax((double)a.data[3 * px], (double)a.data[3 * px + 1]),
                          (double)a.data[3 * px + 2]);
        for (int c = 0; c < 3; ++c)
            CHECK_NEAR(b.data[3 * px + c], a.data[3 * px + c], big / 128.0);
    }
    pen_image_free(&b);
    /* EXR: 32-bit floats, lossless. Negative values survive. */
    a.data[7] = -0.25f;
    p = fixture_path("rt.exr");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    CHECK(pen_image_load(ctx, p, &b) == PEN_OK);
    CHECK(b.width == 13 && b.height == 7 && b.channels == 3);
    CHECK(memcmp(a.data, b.data, 13 * 7 * 3 * sizeof(float)) == 0);
    pen_image_free(&b);
    pen_image_free(&a);
    /* A one-channel image is written as Y and read back as grey RGB. */
    a = random_image(5, 4, 1, 0.0, 3.0, 3);
    p = fixture_path("grey.exr");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    CHECK(pen_image_load(ctx, p, &b) == PEN_OK);
    for (size_t i = 0; i < 20; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK(b.data[3 * i + c] == a.data[i]);
    pen_image_free(&a);
    pen_image_free(&b);
    CHECK(fixture_temp_files() == 0);
}

/* The bundled maps: the DWAB-compressed EXR and its RGBE conversion describe the same light. */
static void test_bundled_envmaps(void) {
    const char *names[] = {"city", "interior"};
    for (int k = 0; k < 2; ++k) {
        char pe[512], ph[512];
        snprintf(pe, sizeof pe, "%s/data/envmaps/%s.exr", PEN_SOURCE_DIR, names[k]);
        snprintf(ph, sizeof ph, "%s/data/envmaps/%s.hdr", PEN_SOURCE_DIR, names[k]);
        pen_image e, h;
        CHECK_MSG(pen_image_load(ctx, pe, &e) == PEN_OK, "%s", pen_context_error(ctx));
        CHECK(pen_image_load(ctx, ph, &h) == PEN_OK);
        CHECK(e.width == 1024 && e.height == 512 && h.width == 1024 && h.height == 512);
        double se = 0, sh = 0, most_negative = 0;
        for (size_t i = 0; i < 1024 * 512 * 3; ++i) {
            se += (double)e.data[i];
            sh += (double)h.data[i];
            most_negative = fmin(most_negative, (double)e.data[i]);
        }
        CHECK_REL(se, sh, 0.02, 1e-9);
        CHECK(se > 0);
        /* Loaded faithfully: the codec's tiny negatives are still there, and tiny. */
        CHECK(most_negative > -0.01);
        pen_image_free(&e);
        pen_image_free(&h);
    }
}

/* A PNG whose IHDR claims the given size (valid CRC, no pixel data). */
static const char *png_header_only(const char *name, uint32_t w, uint32_t h) {
    unsigned char b[33] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n',
                           0,    0,   0,   13,  'I',  'H',  'D',  'R'};
    for (int i = 0; i < 4; ++i) {
        b[16 + i] = (unsigned char)(w >> (24 - 8 * i));
        b[20 + i] = (unsigned char)(h >> (24 - 8 * i));
    }
    b[24] = 8; /* bit depth */
    b[25] = 2; /* RGB */
    uLong crc = crc32(0, b + 12, 17);
    for (int i = 0; i < 4; ++i)
        b[29 + i] = (unsigned char)(crc >> (24 - 8 * i));
    return fixture_write(name, b, sizeof b);
}

static void test_malformed(void) {
    pen_image im;
    memset(&im, 0xff, sizeof im);
    CHECK_ERROR(ctx, pen_image_load(ctx, png_header_only("huge.png", 100000, 4), &im),
                PEN_ERROR_PARSE, "huge.png", "100000 x 4", "outside");
    CHECK(im.data == NULL);
    CHECK_ERROR(ctx, pen_image_load(ctx, png_header_only("cut.png", 4, 4), &im), PEN_ERROR_PARSE,
                "cut.png", "byte offset 33", "truncated");
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("text.png", "hello"), &im), PEN_ERROR_PARSE,
                "text.png", "not a PNG");
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("text.hdr", "hello"), &im), PEN_ERROR_PARSE,
                "text.hdr", "not a Radiance");
    CHECK_ERROR(
        ctx,
        pen_image_load(
            ctx, fixture_text("huge.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 20 +X 20000\n"),
            &im),
        PEN_ERROR_PARSE, "huge.hdr", "20000 x 20");
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("text.exr", "hello"), &im), PEN_ERROR_PARSE,
                "text.exr", "OpenEXR");
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_path("missing.png"), &im), PEN_ERROR_IO,
                "missing.png");
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("x.bmp", "BM"), &im), PEN_ERROR_UNSUPPORTED,
                "x.bmp");
    CHECK(im.data == NULL && im.width == 0);

    /* A NaN in a saved EXR is refused at load; saving NaN/Inf is refused and leaves no file. */
    pen_image a = random_image(4, 3, 3, 0.0, 1.0, 4);
    a.data[3 * (4 * 2 + 1) + 2] = NAN;
    const char *names[] = {"nan.png", "nan.hdr", "nan.exr"};
    for (int k = 0; k < 3; ++k) {
        CHECK_ERROR(ctx, pen_image_save(ctx, fixture_path(names[k]), &a), PEN_ERROR_ARGUMENT,
                    names[k], "pixel (1, 2) channel 2 is NaN");
        CHECK(!fixture_exists(fixture_path(names[k])));
    }
    a.data[3 * (4 * 2 + 1) + 2] = INFINITY;
    CHECK_ERROR(ctx, pen_image_save(ctx, fixture_path("inf.exr"), &a), PEN_ERROR_ARGUMENT,
                "infinite");
    CHECK_ERROR(ctx, pen_image_save(ctx, fixture_path("x.tiff"), &a), PEN_ERROR_UNSUPPORTED,
                "x.tiff");
    a.data[3 * (4 * 2 + 1) + 2] = 0.5f;
    CHECK_ERROR(ctx, pen_image_save(ctx, fixture_path("no/such/dir/x.png"), &a), PEN_ERROR_IO,
                "x.png");
    CHECK(fixture_temp_files() == 0);
    pen_image_free(&a);
}

RUN_TESTS(TEST(test_create), TEST(test_png_round_trip), TEST(test_png_layouts),
          TEST(test_hdr_exr_round_trip), TEST(test_bundled_envmaps), TEST(test_malformed))
