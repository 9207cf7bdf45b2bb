/* Lights found in environment maps (pen_envmap_extract_lights, docs/design.md sec. 1.14): a
 * synthetic sun is found where it is, with its size and irradiance; the residual plus the lights
 * carry the map's SH (the DC exactly); a map without a compact source gives none; max_lights 0
 * is the plain projection bit for bit; the bundled city map's sun is found; loading a scene with
 * a map finds it (lights AUTO); with "lights": "none" it loads the scene as before lights
 * existed (the whole map's projection, no lights); and {"max": 4, "add": [...]} gives the found
 * lights, then the added ones, over the default's SH, saved and read back the same. */
#include "io_fixtures.h"

#include <stdint.h>

#define ctx fixture_ctx()

static const double DEG = 3.14159265358979323846 / 180.0;

/* A W x H sky of radiance `sky` with a disk of radius r_deg around dir of radiance sun (RGB). */
static pen_image sun_map(int W, int H, const double dir[3], double r_deg, const double sun[3],
                         double sky) {
    pen_image im;
    CHECK(pen_image_create(ctx, W, H, 3, &im) == PEN_OK);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            float d[3];
            pen_envmap_direction((x + 0.5f) / (float)W, (y + 0.5f) / (float)H, d);
            double c = (double)d[0] * dir[0] + (double)d[1] * dir[1] + (double)d[2] * dir[2];
            for (int ch = 0; ch < 3; ++ch)
                im.data[3 * ((size_t)y * W + x) + ch] =
                    (float)(sky + (c >= cos(r_deg * DEG) ? sun[ch] : 0.0));
        }
    return im;
}

/* The integral of channel ch of a map over the sphere (exact texel solid angles). */
static double map_integral(const pen_image *im, int ch) {
    double s = 0.0;
    for (int y = 0; y < im->height; ++y) {
        double om = 2.0 * 3.14159265358979323846 / im->width *
                    (cos(3.14159265358979323846 * y / im->height) -
                     cos(3.14159265358979323846 * (y + 1) / im->height));
        for (int x = 0; x < im->width; ++x)
            s += om * fmax(0.0, im->data[3 * ((size_t)y * im->width + x) + ch]);
    }
    return s;
}

static double angle_deg(const float a[3], const double b[3]) {
    double c = ((double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2]) /
               sqrt((double)(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]));
    return acos(fmin(1.0, fmax(-1.0, c))) / DEG;
}

static void test_synthetic_sun(void) {
    const double el = 35 * DEG, az = 0.8;
    const double dir[3] = {cos(el) * sin(az), sin(el), cos(el) * cos(az)};
    const double sun[3] = {2000.0, 1500.0, 900.0}, r = 2.0;
    pen_image im = sun_map(512, 256, dir, r, sun, 1.0);
    pen_light L[4];
    int n = -1;
    pen_image res;
    CHECK(pen_envmap_extract_lights(ctx, &im, 0.0f, 1.0f, 4, L, &n, &res) == PEN_OK);
    CHECK(n == 1);
    CHECK(angle_deg(L[0].direction, dir) < 0.2);
    CHECK_NEAR(L[0].angular_radius_deg, r, 0.25);
    /* The disk's excess over the sky: sun times its solid angle (up to the texel raster), and
     * the residual is the sky. */
    const double omega = 2.0 * 3.14159265358979323846 * (1.0 - cos(r * DEG));
    for (int ch = 0; ch < 3; ++ch)
        CHECK_REL(L[0].irradiance[ch], sun[ch] * omega, 0.05, 0.0);
    for (size_t i = 0; i < 3 * (size_t)res.width * (size_t)res.height; ++i)
        CHECK_NEAR(res.data[i], 1.0, 1e-5);
    /* Energy: residual + light = map in every channel, through the irradiance convention. */
    for (int ch = 0; ch < 3; ++ch) {
        double b = (double)L[0].angular_radius_deg * DEG;
        double light = 2.0 * (double)L[0].irradiance[ch] / (1.0 + cos(b));
        CHECK_REL(map_integral(&res, ch) + light, map_integral(&im, ch), 1e-5, 0.0);
    }
    /* SH: the residual's projection plus the light's is the map's (DC to rounding, the other
     * coefficients up to the disk-versus-raster shape, a small fraction of the sun's). */
    float sm[64][3], sr[64][3], sl[64][3];
    CHECK(pen_envmap_to_sh(ctx, &im, 8, 0.0f, 1.0f, sm) == PEN_OK);
    CHECK(pen_envmap_to_sh(ctx, &res, 8, 0.0f, 1.0f, sr) == PEN_OK);
    pen_light_to_sh(8, &L[0], sl);
    for (int ch = 0; ch < 3; ++ch) {
        CHECK_REL(sr[0][ch] + sl[0][ch], sm[0][ch], 1e-5, 0.0);
        for (int i = 1; i < 64; ++i)
            CHECK_NEAR(sr[i][ch] + sl[i][ch], sm[i][ch], 0.01 * (double)sm[0][ch]);
    }
    /* A rotated, scaled map: the light turns with it and scales; the residual is in map space. */
    pen_light Lr[4];
    int nr = -1;
    CHECK(pen_envmap_extract_lights(ctx, &im, 40.0f, 2.0f, 4, Lr, &nr, NULL) == PEN_OK);
    CHECK(nr == 1);
    const double a = 40 * DEG;
    const double wdir[3] = {cos(a) * dir[0] + sin(a) * dir[2], dir[1],
                            -sin(a) * dir[0] + cos(a) * dir[2]};
    CHECK(angle_deg(Lr[0].direction, wdir) < 0.2);
    for (int ch = 0; ch < 3; ++ch)
        CHECK_REL(Lr[0].irradiance[ch], 2.0 * (double)L[0].irradiance[ch], 1e-5, 0.0);
    /* Deterministic. */
    pen_light L2[4];
    int n2 = -1;
    CHECK(pen_envmap_extract_lights(ctx, &im, 0.0f, 1.0f, 4, L2, &n2, NULL) == PEN_OK);
    CHECK(n2 == n && memcmp(L, L2, sizeof(pen_light) * (size_t)n) == 0);
    pen_image_free(&res);
    pen_image_free(&im);
}

static void test_no_lights(void) {
    /* A smooth sky (a gradient with no compact peak) has none; the residual is the map. */
    pen_image im;
    CHECK(pen_image_create(ctx, 64, 32, 3, &im) == PEN_OK);
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 64; ++x)
            for (int ch = 0; ch < 3; ++ch)
                im.data[3 * (y * 64 + x) + ch] = (float)(1.0 + 0.5 * ch + 3.0 * (32 - y) / 32.0);
    pen_light L[4];
    int n = -1;
    pen_image res;
    CHECK(pen_envmap_extract_lights(ctx, &im, 0.0f, 1.0f, 4, L, &n, &res) == PEN_OK);
    CHECK(n == 0);
    CHECK(memcmp(res.data, im.data, sizeof(float) * 3 * 64 * 32) == 0);
    pen_image_free(&res);
    /* max_lights 0: the plain projection, bit for bit, and no lights. */
    const double dir[3] = {0.0, 0.6, 0.8}, sun[3] = {500, 500, 500};
    pen_image sm = sun_map(128, 64, dir, 3.0, sun, 0.5);
    float a[16][3], b[16][3];
    CHECK(pen_envmap_to_sh(ctx, &sm, 4, 20.0f, 1.5f, a) == PEN_OK);
    n = 7; /* a scene's own count: left alone */
    CHECK(pen_envmap_lighting(ctx, &sm, 4, 20.0f, 1.5f, 0, b, L, &n) == PEN_OK);
    CHECK(n == 7 && memcmp(a, b, sizeof a) == 0);
    /* ... and with lights, the residual's projection with the light found. */
    CHECK(pen_envmap_lighting(ctx, &sm, 4, 20.0f, 1.5f, 2, b, L, &n) == PEN_OK);
    CHECK(n == 1);
    CHECK(b[0][0] < 0.8f * a[0][0] && b[0][0] > 0.4f * a[0][0]); /* the sun holds about 40% */
    /* Errors. */
    CHECK_ERROR(ctx, pen_envmap_extract_lights(ctx, &sm, 0.0f, 1.0f, 17, L, &n, NULL),
                PEN_ERROR_ARGUMENT, "max_lights 17");
    CHECK_ERROR(ctx, pen_envmap_extract_lights(ctx, &sm, 0.0f, -1.0f, 1, L, &n, NULL),
                PEN_ERROR_ARGUMENT, "scale");
    sm.data[7] = NAN;
    CHECK_ERROR(ctx, pen_envmap_extract_lights(ctx, &sm, 0.0f, 1.0f, 1, L, &n, NULL),
                PEN_ERROR_ARGUMENT, "not finite");
    pen_image_free(&sm);
    pen_image_free(&im);
}

static void test_bundled_city(void) {
    /* The city map's sun: u, v = 0.600, 0.235 (data/README.md), about 48 degrees up. */
    char path[512];
    snprintf(path, sizeof path, "%s/data/envmaps/city.exr", PEN_SOURCE_DIR);
    pen_image im;
    CHECK(pen_image_load(ctx, path, &im) == PEN_OK);
    pen_light L[PEN_LIGHTS_DEFAULT_MAX];
    int n = -1;
    CHECK(pen_envmap_extract_lights(ctx, &im, 0.0f, 1.0f, PEN_LIGHTS_DEFAULT_MAX, L, &n, NULL) ==
          PEN_OK);
    CHECK(n >= 1);
    float want[3];
    pen_envmap_direction(0.600f, 0.235f, want);
    double w[3] = {want[0], want[1], want[2]};
    CHECK(angle_deg(L[0].direction, w) < 1.0);
    CHECK(L[0].angular_radius_deg < 2.0f);
    pen_image_free(&im);
}

static void test_scene_auto_and_none(void) {
    char path[512];
    snprintf(path, sizeof path, "%s/examples/scenes/spot_city.json", PEN_SOURCE_DIR);
    pen_context *c2 = pen_context_create();
    pen_context_set_threads(c2, 2); /* as test_golden recorded it */
    pen_scene sc;
    CHECK(pen_scene_load(c2, path, &sc) == PEN_OK);
    /* AUTO (no "lights" key): the sun, and the residual's projection. */
    const pen_lighting *L = &sc.lighting;
    CHECK(L->lights_mode == PEN_LIGHTS_AUTO && L->lights_max == PEN_LIGHTS_DEFAULT_MAX);
    CHECK(L->light_count == 1);
    float sh[PEN_SH_MAX_COEFFS][3], full[PEN_SH_MAX_COEFFS][3];
    pen_light found[PEN_SCENE_MAX_LIGHTS];
    int n = 0;
    CHECK(pen_envmap_lighting(c2, &L->envmap, sc.sh_bands, L->rotation_y_deg, L->scale,
                              L->lights_max, sh, found, &n) == PEN_OK);
    CHECK(n == 1 && memcmp(found, L->lights, sizeof(pen_light)) == 0);
    CHECK(memcmp(sh, L->sh, sizeof(float) * 3 * (size_t)(sc.sh_bands * sc.sh_bands)) == 0);
    /* "none": the loader keeps the whole map's projection and finds no lights, so the scene is
     * the one before lights existed (the renderer then draws it as it did). */
    CHECK(pen_envmap_lighting(c2, &L->envmap, sc.sh_bands, L->rotation_y_deg, L->scale, 0, full,
                              found, &n) == PEN_OK);
    char *text = NULL;
    {
        FILE *f = fopen(path, "rb");
        CHECK(f != NULL);
        if (f) {
            text = calloc(1, 1 << 16);
            size_t got = fread(text, 1, (1 << 16) - 1, f);
            CHECK(got > 0);
            fclose(f);
        }
    }
    const char *key = "\"lighting\": {";
    char *at = text ? strstr(text, key) : NULL;
    CHECK(at != NULL);
    if (at) {
        /* The same scene with "lights": "none", parsed as if it lay beside the original. */
        char *edited = calloc(1, strlen(text) + 64);
        size_t head = (size_t)(at - text) + strlen(key);
        memcpy(edited, text, head);
        strcat(edited, "\"lights\": \"none\", ");
        strcat(edited, text + head);
        pen_scene none;
        CHECK_MSG(pen_scene_parse(c2, edited, path, &none) == PEN_OK, "%s", pen_context_error(c2));
        CHECK(none.lighting.lights_mode == PEN_LIGHTS_NONE && none.lighting.light_count == 0);
        CHECK(memcmp(none.lighting.sh, full,
                     sizeof(float) * 3 * (size_t)(sc.sh_bands * sc.sh_bands)) == 0);
        pen_scene_free(&none);
        free(edited);
    }
    free(text);
    pen_scene_free(&sc);
    pen_context_destroy(c2);
}

/* The file at `path` as a NUL-terminated string (at most 64 KiB); NULL if unreadable. */
static char *read_text(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    char *text = calloc(1, 1 << 16);
    size_t got = text ? fread(text, 1, (1 << 16) - 1, f) : 0;
    fclose(f);
    if (got == 0) free(text);
    return got ? text : NULL;
}

/* `text` with `insert` put right after the first `key`; NULL when key is absent. */
static char *insert_after(const char *text, const char *key, const char *insert) {
    const char *at = strstr(text, key);
    if (!at) return NULL;
    char *out = calloc(1, strlen(text) + strlen(insert) + 1);
    size_t head = (size_t)(at - text) + strlen(key);
    memcpy(out, text, head);
    strcat(out, insert);
    strcat(out, text + head);
    return out;
}

static int same_lighting(const pen_scene *a, const pen_scene *b) {
    const pen_lighting *x = &a->lighting, *y = &b->lighting;
    return a->sh_bands == b->sh_bands && x->light_count == y->light_count &&
           memcmp(x->lights, y->lights, sizeof(pen_light) * (size_t)x->light_count) == 0 &&
           memcmp(x->sh, y->sh, sizeof(float) * 3 * (size_t)(a->sh_bands * a->sh_bands)) == 0;
}

#define ADDED_LIGHTS                                                                               \
    "[{\"direction\": [0, 0, 2], \"angular_radius_deg\": 0.5, \"irradiance\": [3, 2, 1]}, "        \
    "{\"direction\": [-1, 0, 0], \"angular_radius_deg\": 5, \"irradiance\": [0.5, 0.5, 0.5]}]"

static void test_scene_found_and_added(void) {
    char path[512];
    snprintf(path, sizeof path, "%s/examples/scenes/spot_city.json", PEN_SOURCE_DIR);
    pen_context *c2 = pen_context_create();
    pen_context_set_threads(c2, 2);
    pen_scene def, sc;
    CHECK(pen_scene_load(c2, path, &def) == PEN_OK);
    CHECK(def.lighting.light_count == 1); /* the city's sun */
    char *text = read_text(path);
    CHECK(text != NULL);
    char *edited = text ? insert_after(text, "\"lighting\": {",
                                       "\"lights\": {\"max\": 4, \"add\": " ADDED_LIGHTS "}, ")
                        : NULL;
    CHECK(edited != NULL);
    if (!edited || pen_scene_parse(c2, edited, path, &sc) != PEN_OK) {
        CHECK_MSG(0, "%s", pen_context_error(c2));
        free(edited), free(text), pen_scene_free(&def), pen_context_destroy(c2);
        return;
    }
    /* The found sun first, then the added lights as listed (normalised); the SH is the
     * default's, the projection of the map without the sun. */
    const pen_lighting *L = &sc.lighting;
    CHECK(L->lights_mode == PEN_LIGHTS_AUTO && L->lights_max == 4 && L->lights_added == 2);
    CHECK(L->light_count == 3);
    CHECK(memcmp(&L->lights[0], &def.lighting.lights[0], sizeof(pen_light)) == 0);
    CHECK(L->lights[1].direction[0] == 0.0f && L->lights[1].direction[2] == 1.0f);
    CHECK(L->lights[1].angular_radius_deg == 0.5f && L->lights[1].irradiance[0] == 3.0f);
    CHECK(L->lights[2].direction[0] == -1.0f && L->lights[2].angular_radius_deg == 5.0f);
    CHECK(memcmp(L->sh, def.lighting.sh, sizeof(float) * 3 * (size_t)(sc.sh_bands * sc.sh_bands)) ==
          0);

    /* Saved and read back: {"max": 4, "add": [...]} again, the same lights, order and SH. */
    pen_scene back;
    CHECK_MSG(pen_scene_save(c2, fixture_path("added.json"), &sc) == PEN_OK, "%s",
              pen_context_error(c2));
    char *saved = read_text(fixture_path("added.json"));
    CHECK(saved && strstr(saved, "\"add\"") && strstr(saved, "\"max\""));
    free(saved);
    CHECK_MSG(pen_scene_load(c2, fixture_path("added.json"), &back) == PEN_OK, "%s",
              pen_context_error(c2));
    CHECK(same_lighting(&sc, &back));
    CHECK(back.lighting.lights_mode == PEN_LIGHTS_AUTO && back.lighting.lights_max == 4 &&
          back.lighting.lights_added == 2);
    pen_scene_free(&back);
    /* With the coefficients written (recovered lighting), the sun cannot be found again: every
     * light is listed, found ones first, and the same scene loads. */
    CHECK(pen_scene_save_ex(c2, fixture_path("added_sh.json"), &sc, PEN_SCENE_SAVE_SH_LIGHTING) ==
          PEN_OK);
    CHECK_MSG(pen_scene_load(c2, fixture_path("added_sh.json"), &back) == PEN_OK, "%s",
              pen_context_error(c2));
    CHECK(same_lighting(&sc, &back) && back.lighting.lights_mode == PEN_LIGHTS_GIVEN);
    pen_scene_free(&back);

    /* "max": 0 with "add": the added lights only, over the whole map's projection. */
    free(edited);
    edited = insert_after(text, "\"lighting\": {",
                          "\"lights\": {\"max\": 0, \"add\": " ADDED_LIGHTS "}, ");
    CHECK(edited && pen_scene_parse(c2, edited, path, &back) == PEN_OK);
    if (edited && back.lighting.light_count == 2) {
        float full[PEN_SH_MAX_COEFFS][3];
        const pen_lighting *B = &back.lighting;
        CHECK(pen_envmap_to_sh(c2, &B->envmap, back.sh_bands, B->rotation_y_deg, B->scale, full) ==
              PEN_OK);
        CHECK(memcmp(&B->lights[0], &L->lights[1], 2 * sizeof(pen_light)) == 0);
        CHECK(memcmp(B->sh, full, sizeof(float) * 3 * (size_t)(back.sh_bands * back.sh_bands)) ==
              0);
    } else {
        CHECK_MSG(0, "max 0 + add: %d lights", edited ? back.lighting.light_count : -1);
    }
    pen_scene_free(&back);
    free(edited);
    free(text);
    pen_scene_free(&sc);
    pen_scene_free(&def);
    pen_context_destroy(c2);
}

/* "add" without a map (only the added lights, round trip included) and each bad "add" with its
 * one-line error naming the file and the key. */
static void test_scene_add_forms(void) {
    fixture_text("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
#define SCENE_HEAD                                                                                 \
    "{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "           \
    "\"target\": [0, 0, 0]}, \"sh_bands\": 1, \"objects\": [{\"mesh\": \"tri.obj\"}], "            \
    "\"lighting\": {\"sh\": [[1, 1, 1]], \"lights\": "
    pen_scene sc, back;
    CHECK(pen_scene_parse(ctx, SCENE_HEAD "{\"add\": " ADDED_LIGHTS "}}}", fixture_path("a.json"),
                          &sc) == PEN_OK);
    CHECK(sc.lighting.lights_mode == PEN_LIGHTS_AUTO && sc.lighting.light_count == 2 &&
          sc.lighting.lights_added == 2 && sc.lighting.lights_max == PEN_LIGHTS_DEFAULT_MAX);
    CHECK(pen_scene_save(ctx, fixture_path("a_saved.json"), &sc) == PEN_OK);
    CHECK(pen_scene_load(ctx, fixture_path("a_saved.json"), &back) == PEN_OK);
    CHECK(same_lighting(&sc, &back) && back.lighting.lights_mode == PEN_LIGHTS_AUTO &&
          back.lighting.lights_added == 2);
    pen_scene_free(&back);
    pen_scene_free(&sc);
    static const char *const bad[][2] = {
        {"{\"max\": 2, \"add\": 3}",
         "bad.json: lighting.lights.add: expected an array of lights, got"},
        {"{\"add\": {}}", "bad.json: lighting.lights.add: expected an array of lights, got"},
        {"{\"add\": [{\"direction\": [0, 0, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, 1, "
         "1]}]}",
         "bad.json: lighting.lights.add[0].direction: must not be the zero vector"},
        {"{\"add\": [{\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, 1, "
         "1]}, {\"direction\": [0, 1, 0], \"irradiance\": [1, 1, 1]}]}",
         "bad.json: lighting.lights.add[1].angular_radius_deg: missing"},
        {"{\"add\": [3]}", "bad.json: lighting.lights.add[0]"},
        {"{\"max\": 15, \"add\": " ADDED_LIGHTS "}",
         "bad.json: lighting.lights.add: 2 lights, at most 1 (16 minus \"max\")"},
        {"{\"max\": 2, \"added\": []}", "bad.json: lighting.lights"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i) {
        char text[2048];
        snprintf(text, sizeof text, SCENE_HEAD "%s}}", bad[i][0]);
        const pen_status s = pen_scene_parse(ctx, text, fixture_path("bad.json"), &sc);
        CHECK_MSG(s == PEN_ERROR_PARSE, "case %zu parsed", i);
        const char *msg = pen_context_error(ctx);
        CHECK_MSG(strstr(msg, bad[i][1]) != NULL && !strchr(msg, '\n'), "case %zu: %s", i, msg);
        if (s == PEN_OK) pen_scene_free(&sc);
    }
#undef SCENE_HEAD
}

RUN_TESTS(TEST(test_synthetic_sun), TEST(test_no_lights), TEST(test_bundled_city),
          TEST(test_scene_auto_and_none), TEST(test_scene_found_and_added),
          TEST(test_scene_add_forms))
