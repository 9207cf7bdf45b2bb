/* Image files: round trips through PNG (sRGB), HDR (RGBE) and EXR (float), the bundled
 * environment maps, grey/alpha/16-bit/palette/interlaced PNG inputs, JPEG written here by libjpeg,
 * and malformed files of every format (truncated at every length, bad CRCs, bad palette indices,
 * broken run-length data, sizes over the limits) that must be refused with one line naming the
 * file and the place. */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "io/io_internal.h"

#include <jpeglib.h>
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

/* ---- Decoders on crafted input ---------------------------------------------------------------- */

/* A growing byte buffer for files built here. */
typedef struct bytes {
    unsigned char *p;
    size_t n, cap;
} bytes;

static void put(bytes *b, const void *data, size_t n) {
    if (b->n + n > b->cap) {
        b->cap = 2 * (b->n + n) + 64;
        b->p = realloc(b->p, b->cap);
        CHECK(b->p != NULL);
    }
    memcpy(b->p + b->n, data, n);
    b->n += n;
}

static void put_text(bytes *b, const char *text) {
    put(b, text, strlen(text));
}

static bytes slurp(const char *path) {
    bytes b = {0};
    FILE *f = fopen(path, "rb");
    CHECK(f != NULL);
    unsigned char chunk[4096];
    for (size_t n; f && (n = fread(chunk, 1, sizeof chunk, f)) > 0;)
        put(&b, chunk, n);
    if (f) fclose(f);
    return b;
}

/* Loading every proper prefix of a file (from `from` bytes on) fails with PEN_ERROR_PARSE and a
 * message naming the file; none hangs or reads outside the bytes (under ASan). */
static void check_every_prefix_refused(const char *name, const bytes *b, size_t from) {
    for (size_t n = from; n < b->n; ++n) {
        pen_image im;
        pen_status s = pen__image_decode(ctx, name, b->p, n, 0, &im);
        CHECK_MSG(s == PEN_ERROR_PARSE && strstr(pen_context_error(ctx), name) &&
                      im.data == NULL,
                  "%s cut at %zu of %zu: status %d, '%s'", name, n, b->n, (int)s,
                  pen_context_error(ctx));
        if (s == PEN_OK) pen_image_free(&im);
    }
}

/* Radiance RGBE value of one pixel component, as the format defines it. */
static float rgbe_value(int mantissa, int exponent) {
    return exponent ? (float)ldexp((double)mantissa, exponent - 136) : 0.0f;
}

/* A new-style run-length row of width w: literal spans of at most 128 bytes per channel. */
static void put_rle_row(bytes *b, const unsigned char *rgbe, int w) {
    unsigned char head[4] = {2, 2, (unsigned char)(w >> 8), (unsigned char)w};
    put(b, head, 4);
    for (int c = 0; c < 4; ++c) {
        for (int x = 0; x < w;) {
            int n = w - x < 128 ? w - x : 128;
            unsigned char code = (unsigned char)n;
            put(b, &code, 1);
            for (int k = 0; k < n; ++k)
                put(b, &rgbe[4 * (x + k) + c], 1);
            x += n;
        }
    }
}

static const char *HDR_HEAD = "#?RADIANCE\n# made by test_io_image\nFORMAT=32-bit_rle_rgbe\n"
                              "EXPOSURE=1.0\n\n";

/* A mixed file: row 0 run-length encoded, row 1 flat, row 2 run-length with runs. Radiance reads
 * each row on its own; stb restarted the whole image as flat data at row 1. */
static bytes hdr_mixed(unsigned char rgbe[3][8 * 4]) {
    bytes b = {0};
    put_text(&b, HDR_HEAD);
    put_text(&b, "-Y 3 +X 8\n");
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 8; ++x)
            for (int c = 0; c < 4; ++c)
                rgbe[y][4 * x + c] = (unsigned char)(c == 3 ? 120 + 3 * y + (x & 1) * 20
                                                            : 1 + 37 * c + 11 * x + 70 * y);
    rgbe[1][4 * 5 + 3] = 0; /* a zero exponent: black */
    put_rle_row(&b, rgbe[0], 8);
    put(&b, rgbe[1], sizeof rgbe[1]);
    for (int x = 0; x < 8; ++x) /* row 2: each channel constant over 4-pixel halves */
        for (int c = 0; c < 4; ++c)
            rgbe[2][4 * x + c] = rgbe[2][4 * (x & 4) + c];
    unsigned char head[4] = {2, 2, 0, 8};
    put(&b, head, 4);
    for (int c = 0; c < 4; ++c) {
        unsigned char runs[4] = {128 + 4, rgbe[2][c], 128 + 4, rgbe[2][16 + c]};
        put(&b, runs, 4);
    }
    return b;
}

static void test_hdr_decoder(void) {
    unsigned char rgbe[3][8 * 4];
    bytes b = hdr_mixed(rgbe);
    const char *p = fixture_write("mixed.hdr", b.p, b.n);
    pen_image im;
    CHECK_MSG(pen_image_load(ctx, p, &im) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(im.width == 8 && im.height == 3);
    for (int y = 0; y < 3 && im.data; ++y)
        for (int x = 0; x < 8; ++x)
            for (int c = 0; c < 3; ++c)
                CHECK(im.data[3 * (8 * y + x) + c] ==
                      rgbe_value(rgbe[y][4 * x + c], rgbe[y][4 * x + 3]));
    CHECK(im.data && im.data[3 * (8 + 5)] == 0.0f);
    pen_image_free(&im);
    /* Truncated anywhere, header included: refused, never filled from uninitialised memory. */
    check_every_prefix_refused("mixed.hdr", &b, 0);
    size_t pixels = b.n - (strlen(HDR_HEAD) + strlen("-Y 3 +X 8\n"));
    CHECK(pixels == 4 + 4 * 9 + 32 + 4 + 16);

    /* Broken run-length data in row 0: each names the scanline and byte offset. */
    size_t row0 = b.n - pixels;
    struct {
        size_t at;
        unsigned char value;
        const char *want;
    } cases[] = {
        {row0 + 3, 9, "run-length encoded for 9 pixels in an image 8 wide"},
        {row0 + 4, 0, "literal span of 0 in channel 0"},
        {row0 + 4, 128 + 9, "run of 9 in channel 0 at pixel 0 of 8"},
        {row0 + 4 + 9, 9, "literal span of 9 in channel 1"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; ++k) {
        bytes c = {0};
        put(&c, b.p, b.n);
        c.p[cases[k].at] = cases[k].value;
        p = fixture_write("rle.hdr", c.p, c.n);
        CHECK_ERROR(ctx, pen_image_load(ctx, p, &im), PEN_ERROR_PARSE, "rle.hdr", "scanline 0",
                    "byte offset", cases[k].want);
        free(c.p);
    }
    free(b.p);

    /* The bundled map cut short: the first 3000 bytes (too short for its size, refused before
     * allocating) and 9/10 of it (refused at the scanline where the bytes end). Debian's stb span
     * forever on both. */
    char city[512];
    snprintf(city, sizeof city, "%s/data/envmaps/city.hdr", PEN_SOURCE_DIR);
    b = slurp(city);
    CHECK(b.n > 30000);
    CHECK_ERROR(ctx, pen__image_decode(ctx, "city_cut.hdr", b.p, 3000, 0, &im), PEN_ERROR_PARSE,
                "city_cut.hdr", "byte offset 50", "cannot hold 512 scanlines of 1024 pixels");
    CHECK_ERROR(ctx, pen__image_decode(ctx, "city_cut.hdr", b.p, b.n / 10 * 9, 0, &im),
                PEN_ERROR_PARSE, "city_cut.hdr", "truncated", "byte offset");
    free(b.p);

    /* A flat file (width below 8) round-trips and refuses every truncation. */
    pen_image a = random_image(4, 3, 3, 0.0, 5.0, 9);
    p = fixture_path("flat.hdr");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    CHECK(pen_image_load(ctx, p, &im) == PEN_OK);
    for (size_t i = 0; i < 36 && im.data; ++i)
        CHECK_NEAR(im.data[i], a.data[i], 5.0 / 128);
    pen_image_free(&im);
    pen_image_free(&a);
    b = slurp(p);
    check_every_prefix_refused("flat.hdr", &b, 0);
    free(b.p);

    /* Headers. */
    struct {
        const char *text, *want;
        pen_status status;
    } heads[] = {
        {"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 2\n", "cannot hold 2 scanlines",
         PEN_ERROR_PARSE},
        {"#?RGBE\nFORMAT=32-bit_rle_rgbe\n-Y 2 +X 2\n", "header not closed", PEN_ERROR_PARSE},
        {"#?RADIANCE\n\n+Y 2 +X 2\n", "resolution line at byte offset 12", PEN_ERROR_PARSE},
        {"#?RADIANCE\n\n-Y 2 +X 2 junk\n", "resolution line", PEN_ERROR_PARSE},
        {"#?RADIANCE\n\n-Y 99999999999999 +X 2\n", "resolution line", PEN_ERROR_PARSE},
        {"#?RADIANCE\n\n-Y 2 +X 2", "no resolution line", PEN_ERROR_PARSE},
        {"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 2 +X 2\n", "header line 2 (byte offset 11)",
         PEN_ERROR_UNSUPPORTED},
        {"#?RADIANCE\n\n-Y 16384 +X 16384\n", "over the limit", PEN_ERROR_PARSE},
        {"#?RADIANCE\n\n-Y 1 +X 16385\n", "16385 x 1 outside", PEN_ERROR_PARSE},
        {"#?RADIANCEX\n\n-Y 1 +X 1\n", "not a Radiance", PEN_ERROR_PARSE},
    };
    for (size_t k = 0; k < sizeof heads / sizeof heads[0]; ++k)
        CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("head.hdr", heads[k].text), &im),
                    heads[k].status, "head.hdr", heads[k].want);
    /* Without FORMAT (optional in Radiance) and with a flat 1-pixel body: accepted. */
    static const char noformat[] = "#?RADIANCE\n\n-Y 1 +X 1\n\x80\x40\x20\x81";
    CHECK(pen_image_load(ctx, fixture_write("noformat.hdr", noformat, sizeof noformat - 1), &im) ==
          PEN_OK);
    CHECK(im.data && im.data[0] == rgbe_value(0x80, 0x81) && im.data[2] == rgbe_value(0x20, 0x81));
    pen_image_free(&im);
}

/* The offset of the first chunk of the given type in a PNG, or 0. */
static size_t png_chunk(const bytes *b, const char *type) {
    for (size_t at = 8; at + 12 <= b->n;) {
        size_t len = (size_t)b->p[at] << 24 | (size_t)b->p[at + 1] << 16 |
                     (size_t)b->p[at + 2] << 8 | b->p[at + 3];
        if (memcmp(b->p + at + 4, type, 4) == 0) return at;
        at += 12 + len;
    }
    return 0;
}

static void png_quiet(png_structp png, png_const_charp message) {}

/* A w x h PNG written by libpng: palette (with `ncolours` entries of `palette`, bit depth
 * `depth`) when palette is non-NULL, else 8-bit RGB, or grey of bit depth `depth` when ncolours
 * is -1; interlaced on request. px: one byte per index or grey value, three per RGB pixel. */
static const char *png_write(const char *name, int w, int h, const unsigned char *palette,
                             int ncolours, int depth, int interlaced, const unsigned char *px) {
    int grey = ncolours == -1;
    const char *path = fixture_path(name);
    FILE *f = fopen(path, "wb");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, png_quiet);
    png_infop info = png_create_info_struct(png);
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, palette || grey ? depth : 8,
                 palette ? PNG_COLOR_TYPE_PALETTE : grey ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB,
                 interlaced ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    if (palette) {
        png_color colours[16];
        for (int i = 0; i < ncolours; ++i)
            colours[i] = (png_color){palette[3 * i], palette[3 * i + 1], palette[3 * i + 2]};
        png_set_PLTE(png, info, colours, ncolours);
        png_set_check_for_invalid_index(png, 0); /* let an index past the palette through */
    }
    png_write_info(png, info);
    if ((palette || grey) && depth < 8) png_set_packing(png);
    int passes = png_set_interlace_handling(png);
    size_t stride = (size_t)w * (palette || grey ? 1 : 3);
    for (int pass = 0; pass < passes; ++pass)
        for (int y = 0; y < h; ++y)
            png_write_row(png, px + (size_t)y * stride);
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    fclose(f);
    return path;
}

static void test_png_decoder(void) {
    /* Palette images, 8-bit and 4-bit, decode to their colours. */
    const unsigned char palette[9] = {255, 0, 0, 0, 128, 0, 10, 20, 30};
    unsigned char idx[4 * 3] = {0, 1, 2, 0, 2, 2, 1, 0, 1, 1, 1, 2};
    float table[256];
    pen__image_code_table(0, table);
    for (int depth = 4; depth <= 8; depth += 4) {
        const char *p = png_write("pal.png", 4, 3, palette, 3, depth, 0, idx);
        pen_image im;
        CHECK_MSG(pen_image_load(ctx, p, &im) == PEN_OK, "%s", pen_context_error(ctx));
        for (int i = 0; i < 12 && im.data; ++i)
            for (int c = 0; c < 3; ++c)
                CHECK(im.data[3 * i + c] == table[palette[3 * idx[i] + c]]);
        pen_image_free(&im);
        /* An index past the palette is refused, naming the pixel (stb read past the palette). */
        idx[6] = 7;
        p = png_write("badpal.png", 4, 3, palette, 3, depth, 0, idx);
        CHECK_ERROR(ctx, pen_image_load(ctx, p, &im), PEN_ERROR_PARSE, "badpal.png",
                    "pixel (2, 1) has palette index 7, the palette has 3 entries");
        idx[6] = 1;
    }
    /* 2-bit grey: values 0..3 scaled to the 8-bit codes 0, 85, 170, 255. */
    const unsigned char grey2[4] = {0, 1, 2, 3};
    pen_image g;
    CHECK(pen_image_load(ctx, png_write("grey2.png", 4, 1, NULL, -1, 2, 0, grey2), &g) == PEN_OK);
    for (int i = 0; i < 4 && g.data; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK(g.data[3 * i + c] == table[85 * i]);
    pen_image_free(&g);
    /* Interlaced (Adam7) RGB: the same pixels as written. */
    unsigned char rgb[9 * 7 * 3];
    for (size_t i = 0; i < sizeof rgb; ++i)
        rgb[i] = (unsigned char)(i * 37 + 5);
    const char *p = png_write("adam7.png", 9, 7, NULL, 0, 8, 1, rgb);
    pen_image im;
    CHECK_MSG(pen_image_load(ctx, p, &im) == PEN_OK, "%s", pen_context_error(ctx));
    for (size_t i = 0; i < sizeof rgb && im.data; ++i)
        CHECK(im.data[i] == table[rgb[i]]);
    pen_image_free(&im);
    bytes b = slurp(p);
    check_every_prefix_refused("adam7.png", &b, 0);

    /* A flipped bit in a chunk: the CRC no longer matches (stb never checked it). In IHDR the
     * width stays plausible (9 -> 8); in IDAT the flipped bit is in the CRC itself, so the data
     * still inflates and only the CRC can tell. */
    size_t idat = png_chunk(&b, "IDAT");
    size_t idat_len = (size_t)b.p[idat + 2] << 8 | b.p[idat + 3];
    CHECK(idat > 0 && png_chunk(&b, "IHDR") == 8 && b.p[19] == 9);
    size_t flips[2] = {19, idat + 8 + idat_len + 3};
    for (int k = 0; k < 2; ++k) {
        b.p[flips[k]] ^= 1;
        CHECK_ERROR(ctx, pen__image_decode(ctx, "flip.png", b.p, b.n, 0, &im), PEN_ERROR_PARSE,
                    "flip.png", "byte offset", "CRC");
        b.p[flips[k]] ^= 1;
    }
    /* An ancillary chunk with a bad CRC is refused too (libpng's default would drop it). */
    bytes t = {0};
    size_t after_ihdr = 8 + 12 + 13;
    put(&t, b.p, after_ihdr);
    put(&t, "\0\0\0\5tEXtA\0xyz\1\2\3\4", 17);
    put(&t, b.p + after_ihdr, b.n - after_ihdr);
    CHECK_ERROR(ctx, pen__image_decode(ctx, "text.png", t.p, t.n, 0, &im), PEN_ERROR_PARSE,
                "text.png", "CRC");
    free(t.p);
    /* The same file with a good CRC on that chunk loads. */
    t = (bytes){0};
    put(&t, b.p, after_ihdr);
    unsigned char chunk[17] = {0, 0, 0, 5, 't', 'E', 'X', 't', 'A', 0, 'x', 'y', 'z'};
    uLong crc = crc32(0, chunk + 4, 9);
    for (int i = 0; i < 4; ++i)
        chunk[13 + i] = (unsigned char)(crc >> (24 - 8 * i));
    put(&t, chunk, 17);
    put(&t, b.p + after_ihdr, b.n - after_ihdr);
    CHECK_MSG(pen__image_decode(ctx, "text.png", t.p, t.n, 0, &im) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_image_free(&im);
    free(t.p);
    free(b.p);

    /* Sizes: each side and the pixel budget, judged from IHDR before anything is allocated. */
    CHECK_ERROR(ctx, pen_image_load(ctx, png_header_only("big.png", 16384, 16384), &im),
                PEN_ERROR_PARSE, "big.png", "16384 x 16384 is 268435456 pixels",
                "over the limit");
    CHECK_ERROR(ctx, pen_image_load(ctx, png_header_only("zero.png", 0, 4), &im),
                PEN_ERROR_PARSE, "zero.png", "0 x 4 outside");
}

/* A JPEG written by libjpeg into memory (free the result). */
static unsigned char *jpeg_write(int w, int h, int comp, J_COLOR_SPACE space, int progressive,
                                 const unsigned char *px, unsigned long *size) {
    struct jpeg_compress_struct c;
    struct jpeg_error_mgr e;
    c.err = jpeg_std_error(&e);
    jpeg_create_compress(&c);
    unsigned char *out = NULL;
    *size = 0;
    jpeg_mem_dest(&c, &out, size);
    c.image_width = (JDIMENSION)w;
    c.image_height = (JDIMENSION)h;
    c.input_components = comp;
    c.in_color_space = space;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, 95, TRUE);
    if (progressive) jpeg_simple_progression(&c);
    jpeg_start_compress(&c, TRUE);
    while (c.next_scanline < c.image_height) {
        JSAMPROW row = (JSAMPROW)(px + (size_t)c.next_scanline * (size_t)(w * comp));
        jpeg_write_scanlines(&c, &row, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    return out;
}

/* The samples libjpeg itself decodes from a valid file (comp per pixel; free the result). */
static unsigned char *jpeg_read_plain(const unsigned char *data, unsigned long size, int *comp) {
    struct jpeg_decompress_struct d;
    struct jpeg_error_mgr e;
    d.err = jpeg_std_error(&e);
    jpeg_create_decompress(&d);
    jpeg_mem_src(&d, data, size);
    jpeg_read_header(&d, TRUE);
    d.out_color_space = d.jpeg_color_space == JCS_GRAYSCALE ? JCS_GRAYSCALE : JCS_RGB;
    jpeg_start_decompress(&d);
    *comp = d.output_components;
    size_t stride = (size_t)d.output_width * (size_t)*comp;
    unsigned char *px = malloc(stride * d.output_height);
    while (d.output_scanline < d.output_height) {
        JSAMPROW row = px + stride * d.output_scanline;
        jpeg_read_scanlines(&d, &row, 1);
    }
    jpeg_finish_decompress(&d);
    jpeg_destroy_decompress(&d);
    return px;
}

/* The position of the first SOFn marker's height field in a JPEG, or 0. */
static size_t jpeg_sof(const unsigned char *b, unsigned long n) {
    for (size_t i = 2; i + 9 < n; ++i)
        if (b[i] == 0xff && (b[i + 1] == 0xc0 || b[i + 1] == 0xc2)) return i + 5;
    return 0;
}

static void test_jpeg(void) {
    enum { W = 19, H = 11 };
    unsigned char px[W * H * 3];
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x)
            for (int c = 0; c < 3; ++c)
                px[3 * (W * y + x) + c] = (unsigned char)(10 + 4 * x + 6 * y + 40 * c);
    float srgb[256], raw[256];
    pen__image_code_table(0, srgb);
    pen__image_code_table(1, raw);
    for (int progressive = 0; progressive < 2; ++progressive) {
        unsigned long n;
        unsigned char *jpg = jpeg_write(W, H, 3, JCS_RGB, progressive, px, &n);
        const char *p = fixture_write(progressive ? "prog.jpeg" : "photo.JPG", jpg, n);
        int comp = 0;
        unsigned char *want = jpeg_read_plain(jpg, n, &comp);
        CHECK(comp == 3);
        pen_image im, im_raw;
        CHECK_MSG(pen_image_load(ctx, p, &im) == PEN_OK, "%s", pen_context_error(ctx));
        CHECK(pen_image_load_ex(ctx, p, PEN_IMAGE_LOAD_RAW, &im_raw) == PEN_OK);
        CHECK(im.width == W && im.height == H && im.channels == 3);
        int worst = 0;
        for (int i = 0; i < W * H * 3 && im.data && im_raw.data; ++i) {
            CHECK(im.data[i] == srgb[want[i]]);
            CHECK(im_raw.data[i] == raw[want[i]]);
            worst = abs((int)want[i] - (int)px[i]) > worst ? abs((int)want[i] - (int)px[i]) : worst;
        }
        CHECK_MSG(worst <= 12, "quality-95 JPEG off by %d codes", worst);
        pen_image_free(&im);
        pen_image_free(&im_raw);
        free(want);
        /* Cut anywhere (libjpeg alone would pad the missing part grey with a warning). */
        bytes b = {0};
        put(&b, jpg, n);
        check_every_prefix_refused(progressive ? "prog.jpeg" : "photo.jpg", &b, 0);
        CHECK_ERROR(ctx, pen__image_decode(ctx, "half.jpg", jpg, n / 2, 0, &im), PEN_ERROR_PARSE,
                    "half.jpg", "corrupt JPEG at byte offset");
        /* Sizes from the frame header, judged before decoding. */
        size_t sof = jpeg_sof(jpg, n);
        CHECK(sof > 0);
        jpg[sof] = 16000 >> 8, jpg[sof + 1] = 16000 & 255;     /* height */
        jpg[sof + 2] = 16000 >> 8, jpg[sof + 3] = 16000 & 255; /* width */
        CHECK_ERROR(ctx, pen__image_decode(ctx, "wide.jpg", jpg, n, 0, &im), PEN_ERROR_PARSE,
                    "wide.jpg", "16000 x 16000 is 256000000 pixels", "over the limit");
        jpg[sof + 2] = 20000 >> 8, jpg[sof + 3] = 20000 & 255;
        jpg[sof] = 0, jpg[sof + 1] = 8;
        CHECK_ERROR(ctx, pen__image_decode(ctx, "wide.jpg", jpg, n, 0, &im), PEN_ERROR_PARSE,
                    "wide.jpg", "20000 x 8 outside");
        jpg[sof + 4] = 0; /* no components */
        CHECK_ERROR(ctx, pen__image_decode(ctx, "nocomp.jpg", jpg, n, 0, &im), PEN_ERROR_PARSE,
                    "nocomp.jpg", "corrupt JPEG");
        free(b.p);
        free(jpg);
    }
    /* Grey: replicated into RGB. */
    unsigned long n;
    unsigned char *jpg = jpeg_write(W, H, 1, JCS_GRAYSCALE, 0, px, &n);
    int comp = 0;
    unsigned char *want = jpeg_read_plain(jpg, n, &comp);
    pen_image im;
    CHECK(comp == 1);
    CHECK_MSG(pen__image_decode(ctx, "grey.jpg", jpg, n, 0, &im) == PEN_OK, "%s",
              pen_context_error(ctx));
    for (int i = 0; i < W * H && im.data; ++i)
        for (int c = 0; c < 3; ++c)
            CHECK(im.data[3 * i + c] == srgb[want[i]]);
    pen_image_free(&im);
    free(want);
    free(jpg);
    /* CMYK: refused by name (no colour management here). */
    unsigned char cmyk[4 * 4 * 4];
    memset(cmyk, 90, sizeof cmyk);
    jpg = jpeg_write(4, 4, 4, JCS_CMYK, 0, cmyk, &n);
    CHECK_ERROR(ctx, pen__image_decode(ctx, "print.jpg", jpg, n, 0, &im), PEN_ERROR_UNSUPPORTED,
                "print.jpg", "CMYK");
    free(jpg);
    CHECK_ERROR(ctx, pen_image_load(ctx, fixture_text("text.jpg", "hello"), &im),
                PEN_ERROR_PARSE, "text.jpg", "not a JPEG");
    CHECK_ERROR(ctx, pen__image_decode(ctx, "x.tga", (const unsigned char *)"x", 1, 0, &im),
                PEN_ERROR_UNSUPPORTED, "x.tga", "unknown image format");
    /* Saving JPEG is not offered. */
    CHECK(!pen_image_path_supported("x.jpg"));
}

/* EXR from memory (the fuzzers' way in): the same pixels as from the file; cut anywhere, refused
 * with the file named. */
static void test_exr_from_memory(void) {
    pen_image a = random_image(6, 5, 3, 0.0, 4.0, 11), from_file, im;
    const char *p = fixture_path("mem.exr");
    CHECK(pen_image_save(ctx, p, &a) == PEN_OK);
    CHECK(pen_image_load(ctx, p, &from_file) == PEN_OK);
    bytes b = slurp(p);
    CHECK_MSG(pen__image_decode(ctx, "mem.exr", b.p, b.n, 0, &im) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(im.data && from_file.data && memcmp(im.data, from_file.data, 6 * 5 * 3 * 4) == 0 &&
          memcmp(im.data, a.data, 6 * 5 * 3 * 4) == 0);
    pen_image_free(&im);
    pen_image_free(&from_file);
    pen_image_free(&a);
    check_every_prefix_refused("mem.exr", &b, 0);
    free(b.p);
}

/* `penumbra render` with a JPEG texture: Spot's texture re-encoded as JPEG renders like the PNG. */
static void test_render_jpeg_texture(void) {
    char png_path[512];
    snprintf(png_path, sizeof png_path, "%s/data/meshes/spot_texture.png", PEN_SOURCE_DIR);
    pen_image tex;
    CHECK(pen_image_load_ex(ctx, png_path, PEN_IMAGE_LOAD_RAW, &tex) == PEN_OK);
    size_t n = (size_t)tex.width * (size_t)tex.height * 3;
    unsigned char *codes = malloc(n);
    for (size_t i = 0; i < n; ++i)
        codes[i] = (unsigned char)lround(255.0 * (double)tex.data[i]);
    unsigned long size;
    unsigned char *jpg = jpeg_write(tex.width, tex.height, 3, JCS_RGB, 1, codes, &size);
    fixture_write("spot.jpg", jpg, size);
    free(jpg);
    free(codes);
    pen_image_free(&tex);
    const char *kinds[2] = {png_path, fixture_path("spot.jpg")};
    pen_image out[2];
    for (int k = 0; k < 2; ++k) {
        char scene[2048], cmd[4096];
        snprintf(scene, sizeof scene,
                 "{\"camera\": {\"width\": 48, \"height\": 40, \"fov_y_deg\": 40, \"eye\": [2.5, "
                 "1.8, 3.0], \"target\": [0, 0.5, 0]},\n"
                 " \"sh_bands\": 2, \"lighting\": {\"sh\": [[1.5, 1.5, 1.5], [-1, -1, -1], "
                 "[0.2, 0.2, 0.2], [-0.3, -0.3, -0.3]]},\n"
                 " \"objects\": [{\"mesh\": \"%s/data/meshes/spot_triangulated.obj\", "
                 "\"albedo_texture\": \"%s\", \"spheres\": [{\"center\": [0, 0, 0.3], "
                 "\"radius\": 0.4}], \"pose\": {\"translation\": [0, 0.737, 0]}}]}\n",
                 PEN_SOURCE_DIR, kinds[k]);
        fixture_text("tex_scene.json", scene);
        snprintf(cmd, sizeof cmd, "'%s' render '%s' -o '%s' -q", PEN_CLI,
                 fixture_path("tex_scene.json"), fixture_path(k ? "jpg.exr" : "png.exr"));
        CHECK_MSG(system(cmd) == 0, "%s", cmd);
        CHECK(pen_image_load(ctx, fixture_path(k ? "jpg.exr" : "png.exr"), &out[k]) == PEN_OK);
    }
    double diff = 0, sum = 0;
    for (size_t i = 0; out[0].data && out[1].data && i < 48 * 40 * 3; ++i) {
        diff += fabs((double)out[0].data[i] - (double)out[1].data[i]);
        sum += fabs((double)out[0].data[i]);
    }
    CHECK_MSG(sum > 0 && diff < 0.02 * sum, "JPEG texture render differs by %g of %g", diff, sum);
    pen_image_free(&out[0]);
    pen_image_free(&out[1]);
}

RUN_TESTS(TEST(test_create), TEST(test_png_round_trip), TEST(test_png_layouts),
          TEST(test_hdr_exr_round_trip), TEST(test_bundled_envmaps), TEST(test_malformed),
          TEST(test_hdr_decoder), TEST(test_png_decoder), TEST(test_jpeg),
          TEST(test_exr_from_memory), TEST(test_render_jpeg_texture))
