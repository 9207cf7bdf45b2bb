/* Scene and sphere-set JSON: a full scene with every kind of reference, defaults, save -> load
 * round trips, and a table of malformed scenes whose errors must name the file and key path. */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "io/io_internal.h"

#define ctx fixture_ctx()

/* assets/: a textured triangle pair with a material, a UV-less triangle, a texture, a small EXR
 * sky, sphere files. The scenes live in scenes/ and reference ../assets/. */
static void write_assets(void) {
    static int done = 0;
    if (done) return;
    done = 1;
    mkdir(fixture_path("assets"), 0755);
    mkdir(fixture_path("scenes"), 0755);
    mkdir(fixture_path("out"), 0755);
    fixture_text("assets/quad.obj", "mtllib quad.mtl\nusemtl m\n"
                                    "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n"
                                    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 4/4 3/3 2/2\n");
    fixture_text("assets/quad.mtl", "newmtl m\nmap_Kd mat_tex.png\n");
    fixture_text("assets/nouv.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    fixture_text("assets/bad_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
    fixture_text("assets/s.json", "{\"spheres\": [{\"center\": [0, 0.5, 0], \"radius\": 0.5},"
                                  " {\"center\": [0.25, 0.75, -0.5], \"radius\": 0.125}],"
                                  " \"metrics\": {\"sov\": 0.1}}");
    fixture_text("assets/bad_spheres.json", "{\"spheres\": [{\"center\": [0, 0, 0], \"radius\": 1},"
                                            " {\"center\": [0, 0, 0], \"radius\": -1}]}");
    pen_image im;
    CHECK(pen_image_create(ctx, 4, 2, 3, &im) == PEN_OK);
    for (int i = 0; i < 24; ++i)
        im.data[i] = (float)(i % 5) / 4.0f;
    CHECK(pen_image_save(ctx, fixture_path("assets/tex.png"), &im) == PEN_OK);
    CHECK(pen_image_save(ctx, fixture_path("assets/mat_tex.png"), &im) == PEN_OK);
    pen_image_free(&im);
    /* A sky: bright above, dim below, brighter towards +X. */
    CHECK(pen_image_create(ctx, 32, 16, 3, &im) == PEN_OK);
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 32; ++x)
            for (int c = 0; c < 3; ++c)
                im.data[3 * (y * 32 + x) + c] =
                    (y < 8 ? 2.0f : 0.2f) + 0.05f * (float)x + 0.1f * (float)c;
    CHECK(pen_image_save(ctx, fixture_path("assets/sky.exr"), &im) == PEN_OK);
    pen_image_free(&im);
}

static const char *FULL_SCENE =
    "{\n"
    "  \"_note\": \"a comment\",\n"
    "  \"camera\": {\"width\": 64, \"height\": 48, \"fov_y_deg\": 35, \"eye\": [0, 1.2, 3],"
    " \"target\": [0, 0.4, 0]},\n"
    "  \"lighting\": {\"envmap\": \"../assets/sky.exr\", \"scale\": 0.5, \"rotation_y_deg\": 30},\n"
    "  \"sh_bands\": 3,\n"
    "  \"shadow\": {\"exp\": \"paper\"},\n"
    "  \"objects\": [\n"
    "    {\"mesh\": \"../assets/quad.obj\", \"albedo_texture\": \"../assets/tex.png\","
    " \"texture_filter\": \"point\","
    " \"spheres\": \"../assets/s.json\", \"pose\": {\"rotation_axis_angle_deg\": [0, 90, 0],"
    " \"translation\": [1, 0, 0.3], \"scale\": 2}},\n"
    "    {\"mesh\": \"../assets/quad.obj\"},\n"
    "    {\"mesh\": \"../assets/nouv.obj\", \"albedo\": [0.2, 0.3, 0.4], \"spheres\": {\"fit\": "
    "16}},\n"
    "    {\"mesh\": \"../assets/nouv.obj\", \"spheres\": [{\"center\": [0, 0.1, 0], \"radius\": "
    "0.3}]}\n"
    "  ],\n"
    "  \"ground\": {\"height\": -0.5, \"albedo\": [0.5, 0.6, 0.7], \"half_size\": 3},\n"
    "  \"background\": \"envmap\"\n"
    "}\n";

static void check_full(const pen_scene *sc) {
    CHECK(sc->objects[0].texture_filter == PEN_TEXTURE_FILTER_POINT &&
          sc->objects[1].texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT);
    CHECK(sc->camera.width == 64 && sc->camera.height == 48 && sc->camera.fov_y_deg == 35.0f);
    CHECK(sc->camera.eye[1] == 1.2f && sc->camera.target[1] == 0.4f && sc->camera.up[1] == 1.0f);
    CHECK(sc->sh_bands == 3);
    CHECK(sc->shadow.exp == PEN_SH_EXP_PAPER);
    CHECK(sc->shadow.epsilon == (float)pen_sh_exp_model_default(PEN_SH_EXP_PAPER, 3).epsilon);
    CHECK(sc->lighting.scale == 0.5f && sc->lighting.rotation_y_deg == 30.0f);
    CHECK(sc->lighting.envmap.width == 32 && sc->lighting.envmap_path);
    CHECK(sc->background_envmap == 1);
    CHECK(sc->ground.enabled && sc->ground.height == -0.5f && sc->ground.albedo[2] == 0.7f &&
          sc->ground.half_size == 3.0f);
    CHECK(sc->object_count == 4);
    if (sc->object_count != 4) return;
    const pen_object *o = sc->objects;
    CHECK(o[0].mesh.vertex_count == 4 && o[0].mesh.triangle_count == 2);
    CHECK(o[0].texture.width == 4 && o[0].texture.height == 2);
    CHECK(o[0].texture_path && strstr(o[0].texture_path, "assets/tex.png"));
    CHECK(o[0].spheres.count == 2 && o[0].spheres.data[7] == 0.125f && o[0].spheres_path);
    CHECK(o[0].pose.rotation_axis_angle_deg[1] == 90.0f && o[0].pose.translation[2] == 0.3f &&
          o[0].pose.scale == 2.0f);
    CHECK(o[1].texture.width == 4 && o[1].texture_path && strstr(o[1].texture_path, "mat_tex.png"));
    CHECK(o[1].spheres.count == 0 && o[1].fit_spheres == 0 && o[1].pose.scale == 1.0f);
    CHECK(o[2].texture.data == NULL && o[2].albedo[1] == 0.3f && o[2].fit_spheres == 16);
    CHECK(o[2].spheres.count == 0);
    CHECK(o[3].albedo[0] == 0.8f && o[3].spheres.count == 1 && o[3].spheres.data[3] == 0.3f);
    CHECK(o[3].spheres_path == NULL);
}

static int same_scene(const pen_scene *a, const pen_scene *b) {
    int ok = memcmp(&a->camera, &b->camera, sizeof a->camera) == 0 && a->sh_bands == b->sh_bands &&
             memcmp(&a->shadow, &b->shadow, sizeof a->shadow) == 0 &&
             memcmp(&a->ground, &b->ground, sizeof a->ground) == 0 &&
             a->background_envmap == b->background_envmap &&
             memcmp(a->background, b->background, sizeof a->background) == 0 &&
             memcmp(a->lighting.sh, b->lighting.sh,
                    sizeof(float) * 3 * (size_t)(a->sh_bands * a->sh_bands)) == 0 &&
             a->lighting.scale == b->lighting.scale &&
             a->lighting.rotation_y_deg == b->lighting.rotation_y_deg &&
             (a->lighting.envmap.data != NULL) == (b->lighting.envmap.data != NULL) &&
             a->object_count == b->object_count;
    for (int i = 0; ok && i < a->object_count; ++i) {
        const pen_object *x = &a->objects[i], *y = &b->objects[i];
        ok = x->mesh.vertex_count == y->mesh.vertex_count &&
             x->mesh.triangle_count == y->mesh.triangle_count &&
             (x->texture.data != NULL) == (y->texture.data != NULL) &&
             x->texture.width == y->texture.width &&
             memcmp(x->albedo, y->albedo, sizeof x->albedo) == 0 &&
             x->spheres.count == y->spheres.count && x->fit_spheres == y->fit_spheres &&
             memcmp(&x->pose, &y->pose, sizeof x->pose) == 0 &&
             (x->spheres.count == 0 || memcmp(x->spheres.data, y->spheres.data,
                                              4 * sizeof(float) * (size_t)x->spheres.count) == 0);
        CHECK_MSG(ok, "object %d differs", i);
    }
    return ok;
}

static void test_full_scene(void) {
    write_assets();
    const char *p = fixture_text("scenes/full.json", FULL_SCENE);
    pen_scene sc;
    CHECK_MSG(pen_scene_load(ctx, p, &sc) == PEN_OK, "%s", pen_context_error(ctx));
    check_full(&sc);
    /* The lighting is the envmap's projection with the scene's rotation and scale. */
    float sh[PEN_SH_MAX_COEFFS][3];
    CHECK(pen_envmap_to_sh(ctx, &sc.lighting.envmap, 3, 30.0f, 0.5f, sh) == PEN_OK);
    CHECK(memcmp(sh, sc.lighting.sh, 9 * 3 * sizeof(float)) == 0);

    /* Save into another folder, load again: the same scene, with relative paths. */
    const char *out = fixture_path("out/saved.json");
    CHECK(pen_scene_save(ctx, out, &sc) == PEN_OK);
    char *text = NULL;
    FILE *f = fopen(out, "rb");
    if (f) {
        text = calloc(1, 1 << 16);
        if (text) fread(text, 1, (1 << 16) - 1, f);
        fclose(f);
    }
    CHECK(text && strstr(text, "\"../assets/quad.obj\"") && strstr(text, "\"../assets/sky.exr\""));
    CHECK(text && !strstr(text, fixture_dir()));
    CHECK(text && !strstr(text, "\"sh\"") && strstr(text, "\"fit\":\t16"));
    CHECK(text && strstr(text, "\"scale\":\t0.5,") && strstr(text, "1.2")); /* shortest floats */
    free(text);
    pen_scene back;
    CHECK_MSG(pen_scene_load(ctx, out, &back) == PEN_OK, "%s", pen_context_error(ctx));
    check_full(&back);
    CHECK(same_scene(&sc, &back));
    pen_scene_free(&back);

    /* Lighting written as SH (e.g. optimized): coefficients written, the envmap kept for the
     * background; changed coefficients survive the round trip. */
    sc.lighting.sh[4][1] = 0.123f;
    out = fixture_path("out/sh.json");
    CHECK(pen_scene_save_ex(ctx, out, &sc, PEN_SCENE_SAVE_SH_LIGHTING) == PEN_OK);
    CHECK(pen_scene_load(ctx, out, &back) == PEN_OK);
    CHECK(back.lighting.sh[4][1] == 0.123f && back.lighting.envmap.data && back.background_envmap);
    CHECK(same_scene(&sc, &back));
    pen_scene_free(&back);

    /* Changed spheres are written inline once their file reference is dropped. */
    sc.objects[0].spheres.data[0] = 0.75f;
    free(sc.objects[0].spheres_path);
    sc.objects[0].spheres_path = NULL;
    CHECK(pen_scene_save(ctx, out, &sc) == PEN_OK);
    CHECK(pen_scene_load(ctx, out, &back) == PEN_OK);
    CHECK(back.object_count == 4 && back.objects[0].spheres.count == 2 &&
          back.objects[0].spheres.data[0] == 0.75f);
    pen_scene_free(&back);

    /* Unsaveable: a mesh built in memory has no path. */
    free(sc.objects[1].mesh_path);
    sc.objects[1].mesh_path = NULL;
    CHECK_ERROR(ctx, pen_scene_save(ctx, fixture_path("out/no.json"), &sc), PEN_ERROR_ARGUMENT,
                "objects[1]", "no mesh path");
    CHECK(!fixture_exists(fixture_path("out/no.json")) && fixture_temp_files() == 0);
    pen_scene_free(&sc);
    CHECK(sc.objects == NULL && sc.object_count == 0);
    pen_scene_free(NULL);
}

#define CAM                                                                                        \
    "\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "            \
    "\"target\": [0, 0, 0]}"
#define LIGHT "\"lighting\": {\"sh\": [[1, 1, 1]]}, \"sh_bands\": 1"
#define OBJ "\"objects\": [{\"mesh\": \"../assets/nouv.obj\"}]"

static void test_defaults_and_parse(void) {
    write_assets();
    pen_scene sc;
    const char *text =
        "{" CAM ", \"lighting\": {\"sh\": [[1, 2, 3], [0, 0, 0], [0.5, 0, 0], [0, 0, 0],"
        " [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0],"
        " [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, -1]]}, " OBJ "}";
    /* pen_scene_parse: paths relative to the given name. */
    CHECK_MSG(pen_scene_parse(ctx, text, fixture_path("scenes/inline.json"), &sc) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(sc.sh_bands == 4 && sc.lighting.sh[0][2] == 3.0f && sc.lighting.sh[15][2] == -1.0f);
    CHECK(sc.lighting.envmap.data == NULL && sc.lighting.scale == 1.0f);
    CHECK(sc.shadow.exp == PEN_SH_EXP_CALIBRATED);
    CHECK(sc.shadow.epsilon == (float)pen_sh_exp_model_default(PEN_SH_EXP_CALIBRATED, 4).epsilon);
    CHECK(!sc.ground.enabled && !sc.background_envmap && sc.background[0] == 0.0f);
    CHECK(sc.camera.up[0] == 0.0f && sc.camera.up[1] == 1.0f);
    CHECK(sc.object_count == 1 && sc.objects[0].albedo[0] == 0.8f &&
          sc.objects[0].pose.scale == 1.0f);
    CHECK(sc.objects[0].texture.data == NULL && sc.objects[0].spheres.count == 0);
    const char *out = fixture_path("out/defaults.json");
    CHECK(pen_scene_save(ctx, out, &sc) == PEN_OK);
    pen_scene back;
    CHECK(pen_scene_load(ctx, out, &back) == PEN_OK);
    CHECK(same_scene(&sc, &back));
    pen_scene_free(&back);
    pen_scene_free(&sc);

    /* Ground with defaults; a constant background; an epsilon and method given. */
    text = "{" CAM ", " LIGHT ", " OBJ ", \"ground\": {}, \"background\": [0.1, 0.2, 0.3],"
           " \"shadow\": {\"epsilon\": 2.5, \"exp\": \"exact\"}}";
    CHECK(pen_scene_parse(ctx, text, fixture_path("scenes/g.json"), &sc) == PEN_OK);
    CHECK(sc.ground.enabled && sc.ground.height == 0.0f && sc.ground.half_size == 4.0f &&
          sc.ground.albedo[1] == 0.8f);
    CHECK(sc.background[2] == 0.3f && !sc.background_envmap);
    CHECK(sc.shadow.epsilon == 2.5f && sc.shadow.exp == PEN_SH_EXP_EXACT);
    pen_scene_free(&sc);
}

typedef struct bad_scene {
    const char *text;
    pen_status status;
    const char *key, *what;
} bad_scene;

static void test_malformed(void) {
    write_assets();
    static const bad_scene cases[] = {
        {"{" LIGHT ", " OBJ "}", PEN_ERROR_PARSE, "bad.json: camera: missing", "object"},
        {"{\"camera\": {\"width\": -3, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.width: expected a positive integer", "got -3"},
        {"{\"camera\": {\"width\": \"8\", \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.width", "got a string"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 1e999, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.eye[1]: expected a number in [-1e+06, 1e+06]", "inf"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, NaN, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "bad.json:1:", "invalid JSON"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.eye", "expected an array of 3 numbers, got 2"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 180, \"eye\": [0, 0, 3], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.fov_y_deg", "(0, 180)"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "
         "\"target\": [0, 0, 3]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.target", "equals camera.eye"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "
         "\"target\": [0, 0, 0], \"up\": [0, 0, 2]}, " LIGHT ", " OBJ "}",
         PEN_ERROR_PARSE, "camera.up", "parallel"},
        {"{" CAM ", " LIGHT
         ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"albdo\": [1, 1, 1]}]}",
         PEN_ERROR_PARSE, "objects[0].albdo", "unknown key"},
        {"{" CAM ", " LIGHT ", \"sh_bands\": 1, " OBJ "}", PEN_ERROR_PARSE, "sh_bands",
         "duplicate key"},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1, 1]]}, \"sh_bands\": 2, " OBJ "}",
         PEN_ERROR_PARSE, "lighting.sh: expected 4 rows (sh_bands 2 squared)", "got 1"},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1]]}, \"sh_bands\": 1, " OBJ "}", PEN_ERROR_PARSE,
         "lighting.sh[0]", "expected an array of 3 numbers"},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1, \"x\"]]}, \"sh_bands\": 1, " OBJ "}",
         PEN_ERROR_PARSE, "lighting.sh[0][2]", "got a string"},
        {"{" CAM ", \"lighting\": {}, " OBJ "}", PEN_ERROR_PARSE, "lighting",
         "needs \"envmap\" or \"sh\""},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1, 1]], \"scale\": 2}, \"sh_bands\": 1, " OBJ "}",
         PEN_ERROR_PARSE, "lighting", "envmap"},
        {"{" CAM ", \"lighting\": {\"envmap\": \"../assets/none.exr\"}, " OBJ "}", PEN_ERROR_IO,
         "lighting.envmap", "none.exr"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"shadow\": {\"exp\": \"magic\"}}", PEN_ERROR_PARSE,
         "shadow.exp", "unknown method 'magic'"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"shadow\": {\"epsilon\": -1}}", PEN_ERROR_PARSE,
         "shadow.epsilon", "positive"},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1, 1]]}, \"sh_bands\": 9, " OBJ "}",
         PEN_ERROR_PARSE, "sh_bands", "[1, 8]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{}]}", PEN_ERROR_PARSE, "objects[0].mesh", "missing"},
        {"{" CAM ", " LIGHT ", \"objects\": {}}", PEN_ERROR_PARSE, "objects", "expected an array"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nope.obj\"}]}", PEN_ERROR_IO,
         "objects[0].mesh", "nope.obj: cannot open"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/bad_index.obj\"}]}",
         PEN_ERROR_PARSE, "objects[0].mesh: ", "bad_index.obj:4: vertex index 4 out of range"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "\"../assets/bad_spheres.json\"}]}",
         PEN_ERROR_PARSE, "objects[0].spheres: ",
         "bad_spheres.json: spheres[1].radius: expected a number in [1e-9, 1e6], got -1"},
        {"{" CAM ", " LIGHT
         ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": {\"fit\": 0}}]}",
         PEN_ERROR_PARSE, "objects[0].spheres.fit", "[1, 4096]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": 3}]}",
         PEN_ERROR_PARSE, "objects[0].spheres", "{\"fit\": N}"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "[{\"center\": [0, 0, 0], \"radius\": 0}]}]}",
         PEN_ERROR_PARSE, "objects[0].spheres[0].radius", "[1e-9, 1e6]"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"background\": \"sky\"}", PEN_ERROR_PARSE, "background",
         "'sky'"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"background\": \"envmap\"}", PEN_ERROR_PARSE, "background",
         "needs lighting.envmap"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"background\": [1, -1, 0]}", PEN_ERROR_PARSE,
         "background[1]", "got -1"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"ground\": {\"half_size\": 0}}", PEN_ERROR_PARSE,
         "ground.half_size", "[1e-6, 1e6]"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"ground\": 5}", PEN_ERROR_PARSE, "ground",
         "expected an object"},
        {"{" CAM ", " LIGHT
         ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"pose\": {\"scale\": -1}}]}",
         PEN_ERROR_PARSE, "objects[0].pose.scale", "[1e-6, 1e6]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/quad.obj\", \"albedo\": [1, 1, "
         "1], \"albedo_texture\": \"../assets/tex.png\"}]}",
         PEN_ERROR_PARSE, "objects[0]", "not both"},
        {"{" CAM ", " LIGHT
         ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"albedo\": [2, 0, 0]}]}",
         PEN_ERROR_PARSE, "objects[0].albedo[0]", "[0, 1]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", "
         "\"albedo_texture\": \"../assets/tex.png\"}]}",
         PEN_ERROR_PARSE, "objects[0].albedo_texture", "texture coordinates"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/quad.obj\", "
         "\"albedo_texture\": \"../assets/gone.png\"}]}",
         PEN_ERROR_IO, "objects[0].albedo_texture", "gone.png"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/quad.obj\", "
         "\"albedo_texture\": \"../assets/tex.png\", \"texture_filter\": \"box\"}]}",
         PEN_ERROR_PARSE, "objects[0].texture_filter", "footprint"},
        {"[1, 2]", PEN_ERROR_PARSE, "bad.json", "expected a JSON object"},
        {"{\n\"camera\": {\n  ,}\n}", PEN_ERROR_PARSE, "bad.json:3:", "invalid JSON"},
        {"", PEN_ERROR_PARSE, "bad.json:1:", "invalid JSON"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        const char *p = fixture_text("scenes/bad.json", cases[i].text);
        pen_scene sc;
        memset(&sc, 0x5a, sizeof sc);
        pen_status s = pen_scene_load(ctx, p, &sc);
        CHECK_MSG(s != PEN_OK, "case %zu loaded", i);
        CHECK_ERROR(ctx, s, cases[i].status, cases[i].key, cases[i].what);
        CHECK(sc.objects == NULL && sc.path == NULL && sc.object_count == 0);
    }
    pen_scene sc;
    CHECK_ERROR(ctx, pen_scene_load(ctx, fixture_path("scenes/missing.json"), &sc), PEN_ERROR_IO,
                "missing.json");
}

/* ---- Sphere sets ----------------------------------------------------------------------------- */

static void test_spheres(void) {
    pen_spheres a, b;
    CHECK(pen_spheres_create(ctx, 3, &a) == PEN_OK);
    for (int i = 0; i < 12; ++i)
        a.data[i] = (i % 4 == 3) ? 0.1f * (float)(i + 1) : 0.3f * (float)i - 1.0f;
    const char *p = fixture_path("spheres.json");
    CHECK(pen_spheres_save(ctx, p, &a, "{\"metrics\": {\"sov\": 0.25}, \"note\": \"x\"}") ==
          PEN_OK);
    CHECK(pen_spheres_load(ctx, p, &b) == PEN_OK);
    CHECK(b.count == 3 && memcmp(a.data, b.data, 12 * sizeof(float)) == 0);
    pen_spheres_free(&b);
    /* The extra members are in the file. */
    char buf[4096] = {0};
    FILE *f = fopen(p, "rb");
    if (f) {
        fread(buf, 1, sizeof buf - 1, f);
        fclose(f);
    }
    CHECK(strstr(buf, "\"metrics\"") && strstr(buf, "\"sov\":\t0.25") && strstr(buf, "\"note\""));
    /* A bare array is accepted; zero spheres too. */
    p = fixture_text("bare.json", "[{\"center\": [1, 2, 3], \"radius\": 4}]");
    CHECK(pen_spheres_load(ctx, p, &b) == PEN_OK);
    CHECK(b.count == 1 && b.data[2] == 3.0f && b.data[3] == 4.0f);
    pen_spheres_free(&b);
    p = fixture_text("none.json", "{\"spheres\": []}");
    CHECK(pen_spheres_load(ctx, p, &b) == PEN_OK && b.count == 0);
    pen_spheres_free(&b);

    static const struct {
        const char *name, *text, *key, *what;
    } bad[] = {
        {"r.json",
         "{\"spheres\": [{\"center\": [0,0,0], \"radius\": 1}, {\"center\": [0,0,0], \"radius\": "
         "1},"
         " {\"center\": [0,0,0], \"radius\": 1}, {\"center\": [0,0,0], \"radius\": -2}]}",
         "r.json: spheres[3].radius: expected a number in [1e-9, 1e6]", "got -2"},
        {"c.json", "{\"spheres\": [{\"radius\": 1}]}", "c.json: spheres[0].center", "missing"},
        {"n.json", "{\"spheres\": [{\"center\": [0, 1e400, 0], \"radius\": 1}]}",
         "spheres[0].center[1]", "got inf"},
        {"f.json", "{\"spheres\": [{\"center\": [0, 1e39, 0], \"radius\": 1}]}",
         "spheres[0].center[1]", "got 1e+39"},
        {"k.json", "{\"spheres\": [{\"center\": [0, 0, 0], \"radius\": 1, \"radus\": 2}]}",
         "spheres[0].radus", "unknown key"},
        {"m.json", "{\"balls\": []}", "m.json: spheres", "missing"},
        {"t.json", "{\"spheres\": {}}", "t.json: spheres", "expected an array"},
        {"e.json", "[3]", "e.json: [0]", "expected a sphere object, got a number"},
        {"s.json", "{\"spheres\": [", "s.json:1:", "invalid JSON"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i) {
        p = fixture_text(bad[i].name, bad[i].text);
        memset(&b, 0x5a, sizeof b);
        CHECK_ERROR(ctx, pen_spheres_load(ctx, p, &b), PEN_ERROR_PARSE, bad[i].key, bad[i].what);
        CHECK(b.data == NULL && b.count == 0);
    }
    /* Saving refuses what loading would refuse. */
    a.data[7] = 0.0f;
    CHECK_ERROR(ctx, pen_spheres_save(ctx, fixture_path("bad_out.json"), &a, NULL),
                PEN_ERROR_ARGUMENT, "sphere 1");
    a.data[7] = 1.0f;
    CHECK_ERROR(ctx, pen_spheres_save(ctx, fixture_path("bad_out.json"), &a, "[1]"),
                PEN_ERROR_ARGUMENT, "extra_json");
    CHECK(!fixture_exists(fixture_path("bad_out.json")) && fixture_temp_files() == 0);
    CHECK_ERROR(ctx, pen_spheres_create(ctx, -1, &b), PEN_ERROR_ARGUMENT, "count -1");
    pen_spheres_free(&a);
    pen_spheres_free(NULL);
}

/* Relative paths for saved references: same folder, parent, child, and through a "..". */
static void test_paths(void) {
    write_assets();
    mkdir(fixture_path("assets/sub"), 0755);
    fixture_text("assets/sub/deep.obj", "");
    static const struct {
        const char *from, *to, *want;
    } cases[] = {
        {"assets/new.json", "assets/quad.obj", "quad.obj"},
        {"scenes/new.json", "assets/quad.obj", "../assets/quad.obj"},
        {"new.json", "assets/sub/deep.obj", "assets/sub/deep.obj"},
        {"assets/sub/new.json", "assets/quad.obj", "../quad.obj"},
        {"scenes/../assets/sub/new.json", "scenes/../assets/quad.obj", "../quad.obj"},
        {"out/new.json", "assets/sub/deep.obj", "../assets/sub/deep.obj"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        char from[512];
        snprintf(from, sizeof from, "%s", fixture_path(cases[i].from));
        char *rel = pen__io_path_relative(ctx, from, fixture_path(cases[i].to));
        CHECK_MSG(rel && strcmp(rel, cases[i].want) == 0, "case %zu: %s", i, rel ? rel : "NULL");
        free(rel);
    }
    /* A target that does not exist is written as given. */
    char *rel = pen__io_path_relative(ctx, fixture_path("out/x.json"), "no/such/file.obj");
    CHECK(rel && strcmp(rel, "no/such/file.obj") == 0);
    free(rel);
    char *res = pen__io_path_resolve(ctx, "a/b/scene.json", "../m.obj");
    CHECK(res && strcmp(res, "a/b/../m.obj") == 0);
    free(res);
    res = pen__io_path_resolve(ctx, "scene.json", "/abs/m.obj");
    CHECK(res && strcmp(res, "/abs/m.obj") == 0);
    free(res);
    CHECK(pen__io_has_ext("a.b/MESH.OBJ", "obj") && !pen__io_has_ext("a.obj/mesh", "obj") &&
          !pen__io_has_ext("mesh.objx", "obj"));
}

/* ---- Value ranges ------------------------------------------------------------------------------ */

/* Finite values that would overflow downstream (penumbra/scene.h's ranges) are refused where they
 * enter, naming the key (and the file, vertex or pixel); the largest accepted values load. */
static void test_value_ranges(void) {
    write_assets();
    fixture_text("assets/huge.obj", "v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n");
    fixture_text("assets/huge.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                                    "property float x\nproperty float y\nproperty float z\n"
                                    "element face 1\nproperty list uchar int vertex_indices\n"
                                    "end_header\n0 0 0\n1 0 0\n0 -2e7 0\n3 0 1 2\n");
    fixture_text("assets/edge.obj", "v 0 0 0\nv 1e6 0 0\nv 0 -1e6 0\nf 1 2 3\n");
    pen_image im;
    CHECK(pen_image_create(ctx, 8, 4, 3, &im) == PEN_OK);
    for (int i = 0; i < 96; ++i)
        im.data[i] = 0.5f;
    im.data[3 * (2 * 8 + 5) + 1] = 3e37f;
    CHECK(pen_image_save(ctx, fixture_path("assets/hot.exr"), &im) == PEN_OK);
    pen_image_free(&im);
    typedef struct {
        const char *text, *key, *what;
    } bad;
    static const bad cases[] = {
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 1e30], "
         "\"target\": [0, 0, 0]}, " LIGHT ", " OBJ "}",
         "camera.eye[2]", "got 1e+30"},
        {"{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 3], "
         "\"target\": [-2e6, 0, 0]}, " LIGHT ", " OBJ "}",
         "camera.target[0]", "[-1e+06, 1e+06]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"pose\": "
         "{\"scale\": 1e30}}]}",
         "objects[0].pose.scale", "got 1e+30"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"pose\": "
         "{\"translation\": [0, 3e38, 0]}}]}",
         "objects[0].pose.translation[1]", "got 3e+38"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "[{\"center\": [0, 0, 0], \"radius\": 1e30}]}]}",
         "objects[0].spheres[0].radius", "got 1e+30"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "[{\"center\": [0, 0, 0], \"radius\": 1e-12}]}]}",
         "objects[0].spheres[0].radius", "got 1e-12"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "[{\"center\": [1e7, 0, 0], \"radius\": 1}]}]}",
         "objects[0].spheres[0].center[0]", "got 1e+07"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/nouv.obj\", \"spheres\": "
         "[{\"center\": [0, 0, 0], \"radius\": 1, \"weight\": 1e30}]}]}",
         "objects[0].spheres[0].weight", "got 1e+30"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"ground\": {\"half_size\": 1e30}}", "ground.half_size",
         "got 1e+30"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"ground\": {\"height\": -1e9}}", "ground.height",
         "got -1e+09"},
        {"{" CAM ", " LIGHT ", " OBJ ", \"shadow\": {\"epsilon\": 1e7}}", "shadow.epsilon",
         "got 1e+07"},
        {"{" CAM ", \"lighting\": {\"sh\": [[1, 1e30, 1]]}, \"sh_bands\": 1, " OBJ "}",
         "lighting.sh[0][1]", "got 1e+30"},
        {"{" CAM ", \"lighting\": {\"envmap\": \"../assets/sky.exr\", \"scale\": 1e30}, " OBJ "}",
         "lighting.scale", "got 1e+30"},
        {"{" CAM ", \"lighting\": {\"envmap\": \"../assets/hot.exr\"}, " OBJ "}",
         "lighting.envmap: ", "hot.exr: pixel (5, 2) channel 1: 3e+37 outside [-1e+09, 1e+09]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/quad.obj\", "
         "\"albedo_texture\": \"../assets/hot.exr\"}]}",
         "objects[0].albedo_texture: ", "hot.exr: pixel (5, 2) channel 1: 3e+37 outside"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/huge.obj\"}]}",
         "objects[0].mesh: ", "huge.obj: vertex 2: coordinate 1: 1e+30 outside [-1e+06, 1e+06]"},
        {"{" CAM ", " LIGHT ", \"objects\": [{\"mesh\": \"../assets/huge.ply\"}]}",
         "objects[0].mesh: ", "huge.ply: vertex 3: coordinate 2: -2e+07 outside"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        const char *p = fixture_text("scenes/bad.json", cases[i].text);
        pen_scene sc;
        pen_status s = pen_scene_load(ctx, p, &sc);
        CHECK_MSG(s != PEN_OK, "case %zu loaded", i);
        CHECK_ERROR(ctx, s, PEN_ERROR_PARSE, cases[i].key, cases[i].what);
    }
    /* The edges themselves load. */
    const char *edge =
        "{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"eye\": [0, 0, 1e6], "
        "\"target\": [0, 0, -1e6]}, \"lighting\": {\"envmap\": \"../assets/sky.exr\", \"scale\": "
        "1e3}, \"shadow\": {\"epsilon\": 1e6}, \"ground\": {\"height\": -1e6, \"half_size\": "
        "1e6}, \"objects\": [{\"mesh\": \"../assets/edge.obj\", \"pose\": {\"scale\": 1e6, "
        "\"translation\": [1e6, -1e6, 1e6]}, \"spheres\": [{\"center\": [1e6, 0, -1e6], \"radius\": "
        "1e6, \"weight\": 1e6}, {\"center\": [0, 0, 0], \"radius\": 1e-9, \"weight\": 0}]}]}";
    pen_scene sc;
    pen_status s = pen_scene_load(ctx, fixture_text("scenes/edge.json", edge), &sc);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    if (s) return;
    /* ... and render finite (the camera looks along the sphere's and the mesh's 1e12 extent). */
    pen_image img = {0};
    s = pen_render_fwd(ctx, &sc, NULL, NULL, &img);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    for (int i = 0; !s && i < img.width * img.height * img.channels; ++i)
        CHECK_MSG(isfinite(img.data[i]), "edge scene: value %d is %g", i, (double)img.data[i]);
    pen_image_free(&img);
    pen_scene_free(&sc);
}

RUN_TESTS(TEST(test_paths), TEST(test_full_scene), TEST(test_defaults_and_parse),
          TEST(test_malformed), TEST(test_spheres), TEST(test_value_ranges))
