/* Meshes with several materials and vertex colours: the OBJ/MTL and PLY readers, the albedo
 * baker (its lookups equal the materials' own, exactly up to float rounding), the scene loader's
 * choice, save/reload of baked atlases, and the done-when case of the reliability audit
 * (docs/reliability.md): an OBJ with quads, negative indices and two materials with JPEG textures
 * renders with both textures, in pen_render_fwd, in `penumbra render` and in the reference
 * renderer. */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "scene/texture.h"

#include <jpeglib.h>
#include <math.h>

#define ctx fixture_ctx()

/* ---- Fixtures -------------------------------------------------------------------------------- */

/* A w x h RGB JPEG of a two-colour checker of 4-texel squares, written with libjpeg. */
static void write_checker_jpeg(const char *name, int w, int h, const unsigned char a[3],
                               const unsigned char b[3]) {
    FILE *f = fopen(fixture_path(name), "wb");
    CHECK(f != NULL);
    if (!f) return;
    struct jpeg_compress_struct c;
    struct jpeg_error_mgr err;
    c.err = jpeg_std_error(&err);
    jpeg_create_compress(&c);
    jpeg_stdio_dest(&c, f);
    c.image_width = (JDIMENSION)w;
    c.image_height = (JDIMENSION)h;
    c.input_components = 3;
    c.in_color_space = JCS_RGB;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, 98, TRUE);
    jpeg_start_compress(&c, TRUE);
    unsigned char *row = malloc(3 * (size_t)w);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x)
            memcpy(row + 3 * x, ((x / 4 + y / 4) & 1) ? a : b, 3);
        JSAMPROW r = row;
        jpeg_write_scanlines(&c, &r, 1);
    }
    free(row);
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    fclose(f);
}

/* Two unit quads side by side in z = 0 (x in [-1, 0] and [0, 1], y in [-0.5, 0.5]), facing +z,
 * as ngons with negative indices for the second; materials from two mtllib files. */
static void write_two_material_obj(void) {
    static const unsigned char red_a[3] = {220, 40, 30}, red_b[3] = {180, 50, 40};
    static const unsigned char blue_a[3] = {30, 60, 220}, blue_b[3] = {40, 80, 180};
    write_checker_jpeg("red.jpg", 16, 16, red_a, red_b);
    write_checker_jpeg("blue.jpg", 8, 16, blue_a, blue_b);
    fixture_text("red.mtl", "# first library\nnewmtl red\nKd 1 0 0\nmap_Kd red.jpg\n");
    fixture_text("blue.mtl", "newmtl blue\nmap_Kd -s 1 1 1 blue.jpg\n");
    fixture_text("two.obj", "mtllib red.mtl\nmtllib blue.mtl\n"
                            "v -1 -0.5 0\nv 0 -0.5 0\nv 0 0.5 0\nv -1 0.5 0\n"
                            "v 1 -0.5 0\nv 1 0.5 0\n"
                            "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                            "usemtl red\nf 1/1 2/2 3/3 4/4\n"
                            "usemtl blue\nf -5/-4 -2/-3 -1/-2 -4/-1\n");
}

/* A 64 x 32 view of the quads under constant SH light, black background, no ground. */
static const char *quads_scene(const char *name, const char *object_extra) {
    char json[1024];
    snprintf(json, sizeof json,
             "{\"camera\": {\"width\": 64, \"height\": 32, \"fov_y_deg\": 30, \"eye\": [0, 0, 2.2],"
             " \"target\": [0, 0, 0]}, \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]},"
             " \"objects\": [{\"mesh\": \"two.obj\"%s}], \"background\": [0, 0, 0]}",
             object_extra);
    return fixture_text(name, json);
}

/* Per-channel range of an image's values. */
static void image_range(const pen_image *im, float lo[3], float hi[3]) {
    for (int c = 0; c < 3; ++c) {
        lo[c] = INFINITY;
        hi[c] = -INFINITY;
    }
    for (size_t i = 0; i < (size_t)im->width * (size_t)im->height; ++i)
        for (int c = 0; c < 3; ++c) {
            const float v = im->data[3 * i + (size_t)c];
            lo[c] = v < lo[c] ? v : lo[c];
            hi[c] = v > hi[c] ? v : hi[c];
        }
}

/* ---- The done-when case ---------------------------------------------------------------------- */

/* Every pixel well inside a quad: its albedo (image / image of a white object) lies within the
 * range of that quad's decoded JPEG (bilinear lookups stay inside it), with a little slack. */
static void check_halves(const pen_image *img, const pen_image *white, const pen_image *red,
                         const pen_image *blue, float tol) {
    float rlo[3], rhi[3], blo[3], bhi[3];
    image_range(red, rlo, rhi);
    image_range(blue, blo, bhi);
    int checked = 0;
    for (int y = 8; y < 24; ++y)
        for (int x = 6; x < 58; ++x) {
            if (x > 26 && x < 38) continue; /* the seam */
            const int left = x < 32;
            const float *lo = left ? rlo : blo, *hi = left ? rhi : bhi;
            for (int c = 0; c < 3; ++c) {
                const size_t i = 3 * ((size_t)y * 64 + (size_t)x) + (size_t)c;
                const float a = img->data[i] / white->data[i];
                CHECK_MSG(a >= lo[c] - tol && a <= hi[c] + tol,
                          "pixel (%d, %d) channel %d: albedo %g outside [%g, %g]", x, y, c,
                          (double)a, (double)lo[c], (double)hi[c]);
                ++checked;
            }
            const size_t i = 3 * ((size_t)y * 64 + (size_t)x);
            if (left)
                CHECK(img->data[i] > 2.0f * img->data[i + 2]);
            else
                CHECK(img->data[i + 2] > 2.0f * img->data[i]);
        }
    CHECK(checked > 1000);
}

static void test_two_jpeg_materials(void) {
    write_two_material_obj();
    pen_scene sc, white;
    CHECK(pen_scene_load(ctx, quads_scene("two.json", ""), &sc) == PEN_OK);
    CHECK(pen_scene_load(ctx, quads_scene("white.json", ", \"albedo\": [1, 1, 1]"), &white) ==
          PEN_OK);
    const pen_mesh *m = &sc.objects[0].mesh;
    CHECK(m->material_count == 2 && m->triangle_count == 4);
    CHECK(m->triangle_materials[0] == 0 && m->triangle_materials[1] == 0);
    CHECK(m->triangle_materials[2] == 1 && m->triangle_materials[3] == 1);
    CHECK(m->indices[6] == 1 && m->indices[7] == 4 && m->indices[8] == 5); /* -5, -2, -1 */
    CHECK(sc.objects[0].texture_layout == PEN_TEXTURE_LAYOUT_BAKED);
    CHECK(sc.objects[0].texture.data && sc.objects[0].texture_path == NULL);
    /* Tiles: 16x16 and 8x16 texels, each with a 2-texel gutter. */
    CHECK(sc.objects[0].texture.width >= 20 && sc.objects[0].texture.height >= 20);

    pen_image red, blue;
    CHECK(pen_image_load(ctx, fixture_path("red.jpg"), &red) == PEN_OK);
    CHECK(pen_image_load(ctx, fixture_path("blue.jpg"), &blue) == PEN_OK);
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_image img = {0}, wimg = {0};
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &img) == PEN_OK);
    CHECK(pen_render_fwd(ctx, &white, &opt, NULL, &wimg) == PEN_OK);
    check_halves(&img, &wimg, &red, &blue, 1e-4f);

    /* The command line: the same image, bit for bit. */
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "'%s' render '%s' -o '%s' --no-shadows -q", PEN_CLI,
             fixture_path("two.json"), fixture_path("cli.exr"));
    CHECK(system(cmd) == 0);
    pen_image cli = {0};
    CHECK(pen_image_load(ctx, fixture_path("cli.exr"), &cli) == PEN_OK);
    CHECK(cli.width == 64 && cli.height == 32 &&
          memcmp(cli.data, img.data, 3 * 64 * 32 * sizeof(float)) == 0);

    /* The reference renderer reads the same albedo (noisier: a looser tolerance). */
    pen_reference *ref = NULL, *wref = NULL;
    pen_image r = {0}, wr = {0};
    CHECK(pen_reference_create(ctx, &sc, PEN_REFERENCE_LIGHTING_SH, &ref) == PEN_OK);
    CHECK(pen_reference_create(ctx, &white, PEN_REFERENCE_LIGHTING_SH, &wref) == PEN_OK);
    CHECK(ref && pen_reference_render(ctx, ref, 4, 11, &r) == PEN_OK);
    CHECK(wref && pen_reference_render(ctx, wref, 4, 11, &wr) == PEN_OK);
    if (r.data && wr.data) check_halves(&r, &wr, &red, &blue, 0.05f);
    pen_reference_destroy(ref);
    pen_reference_destroy(wref);
    pen_image_free(&r);
    pen_image_free(&wr);
    pen_image_free(&cli);
    pen_image_free(&img);
    pen_image_free(&wimg);
    pen_image_free(&red);
    pen_image_free(&blue);
    pen_scene_free(&sc);
    pen_scene_free(&white);
}

/* ---- The baker ------------------------------------------------------------------------------- */

static uint64_t rng = 88172645463325252ull;
static float uniform(void) {
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (float)((rng >> 40) * (1.0 / 16777216.0));
}

static void random_image(int w, int h, pen_image *im) {
    CHECK(pen_image_create(ctx, w, h, 3, im) == PEN_OK);
    for (size_t i = 0; i < 3 * (size_t)w * (size_t)h; ++i)
        im->data[i] = uniform();
}

/* The lookup of triangle t at barycentrics b with the mesh's UVs into tex. */
static void lookup(const pen_mesh *m, const pen_image *tex, int t, const float b[3], float rgb[3]) {
    float uv[2] = {0, 0};
    for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 2; ++a)
            uv[a] += b[k] * m->uvs[2 * m->uv_indices[3 * t + k] + (uint32_t)a];
    pen__texture_fwd(tex, uv, rgb);
}

static void random_barycentrics(float b[3]) {
    b[0] = uniform();
    b[1] = uniform() * (1.0f - b[0]);
    b[2] = 1.0f - b[0] - b[1];
}

/* Four triangles: two of material 0 (textured, UVs beyond [0, 1]: shifted by whole periods and
 * repeated), one of material 1 (textured), one with material 2 (Kd only), one with none. */
static void test_bake_materials(void) {
    float pos[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
    uint32_t idx[] = {0, 1, 2, 1, 3, 2, 0, 1, 2, 1, 3, 2, 0, 3, 2};
    float uvs[] = {2.3f, -1.6f, 3.9f, -1.2f, 2.5f, 0.1f, /* extent 1.6 x 1.7: reps 2 x 2 */
                   0.1f, 0.2f,  0.9f, 0.3f,  0.4f, 0.8f, 0.25f, 0.5f, 0.75f, 0.5f, 0.5f, 0.25f};
    uint32_t uv_idx[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0, 0, 0, 0, 0};
    int32_t tm[] = {0, 0, 1, 2, -1};
    pen_mesh_material mats[3] = {{.name = "a"}, {.name = "b"}, {.name = "c"}};
    mats[2].has_kd = 1;
    mats[2].kd[0] = 0.1f, mats[2].kd[1] = 0.7f, mats[2].kd[2] = 0.2f;
    pen_mesh m = {.vertex_count = 4,
                  .triangle_count = 5,
                  .positions = pos,
                  .indices = idx,
                  .uv_count = 9,
                  .uvs = uvs,
                  .uv_indices = uv_idx,
                  .material_count = 3,
                  .materials = mats,
                  .triangle_materials = tm};
    pen_image tex[3] = {{0}};
    random_image(5, 3, &tex[0]);
    random_image(4, 6, &tex[1]);
    const pen_mesh before = m;
    float want[5][8][3];
    float bs[8][3];
    for (int s = 0; s < 8; ++s)
        random_barycentrics(bs[s]);
    for (int t = 0; t < 3; ++t)
        for (int s = 0; s < 8; ++s)
            lookup(&before, &tex[tm[t]], t, bs[s], want[t][s]);

    /* The baker replaces uvs/uv_indices with its own allocations: work on heap copies. */
    m.uvs = malloc(sizeof uvs);
    m.uv_indices = malloc(sizeof uv_idx);
    memcpy(m.uvs, uvs, sizeof uvs);
    memcpy(m.uv_indices, uv_idx, sizeof uv_idx);
    const float def[3] = {0.8f, 0.6f, 0.4f};
    pen_image atlas;
    CHECK(pen_mesh_bake_albedo(ctx, &m, tex, def, &atlas) == PEN_OK);
    CHECK(m.uv_count == 15 && atlas.channels == 3);
    CHECK(pen_mesh_validate(ctx, &m) == PEN_OK);
    /* Material 0 needs 2 x 2 repeats: a tile of 10 + 4 by 6 + 4 texels at least. */
    CHECK(atlas.width >= 14 && atlas.height >= 10);
    for (int t = 0; t < 5; ++t)
        for (int s = 0; s < 8; ++s) {
            float got[3];
            lookup(&m, &atlas, t, bs[s], got);
            const float *w = t < 3 ? want[t][s] : t == 3 ? mats[2].kd : def;
            for (int c = 0; c < 3; ++c)
                CHECK_MSG(fabsf(got[c] - w[c]) < 2e-5f, "triangle %d sample %d: %g vs %g", t, s,
                          (double)got[c], (double)w[c]);
        }
    free(m.uvs);
    free(m.uv_indices);
    pen_image_free(&atlas);

    /* A face spanning 20 periods: its tile stops at PEN_MESH_BAKE_MAX_REPEATS, UVs clamped. */
    float wide[] = {0, 0, 20, 0, 0, 1};
    uint32_t wide_idx[] = {0, 1, 2};
    pen_mesh one = {.vertex_count = 4,
                    .triangle_count = 1,
                    .positions = pos,
                    .indices = idx,
                    .uv_count = 3,
                    .uvs = malloc(sizeof wide),
                    .uv_indices = malloc(12),
                    .material_count = 2,
                    .materials = mats,
                    .triangle_materials = tm};
    memcpy(one.uvs, wide, sizeof wide);
    memcpy(one.uv_indices, wide_idx, sizeof wide_idx);
    CHECK(pen_mesh_bake_albedo(ctx, &one, tex, def, &atlas) == PEN_OK);
    CHECK(atlas.width == 5 * PEN_MESH_BAKE_MAX_REPEATS + 4 && atlas.height == 3 + 4);
    for (int k = 0; k < 3; ++k)
        CHECK(one.uvs[2 * k] >= 0.0f && one.uvs[2 * k] <= 1.0f);
    pen_image_free(&atlas);

    /* The pixel budget: a 4096^2 texture repeated 8 times is refused before any texel is read
     * (the image's data is a stand-in). */
    memcpy(one.uvs, wide, sizeof wide); /* the baker rewrote them */
    memcpy(one.uv_indices, wide_idx, sizeof wide_idx);
    float stand_in[3] = {0, 0, 0};
    pen_image huge[2] = {{4096, 4096, 3, stand_in}, {0}};
    CHECK_ERROR(ctx, pen_mesh_bake_albedo(ctx, &one, huge, def, &atlas), PEN_ERROR_UNSUPPORTED,
                "bake:", "32772", "16384");
    CHECK(atlas.data == NULL && one.uv_count == 3); /* the mesh is unchanged */
    free(one.uvs);
    free(one.uv_indices);
    /* A textured material without UVs. */
    pen_mesh nouv = {.vertex_count = 4,
                     .triangle_count = 1,
                     .positions = pos,
                     .indices = idx,
                     .material_count = 2,
                     .materials = mats,
                     .triangle_materials = tm};
    CHECK_ERROR(ctx, pen_mesh_bake_albedo(ctx, &nouv, tex, def, &atlas), PEN_ERROR_ARGUMENT,
                "material 'a'", "no texture coordinates");
    pen_image_free(&tex[0]);
    pen_image_free(&tex[1]);
}

/* Vertex colours: the lookup equals the barycentric interpolation of the corner colours. */
static void test_bake_colors(void) {
    enum { V = 7, T = 9 };
    float pos[3 * V], col[3 * V];
    for (int i = 0; i < 3 * V; ++i) {
        pos[i] = uniform();
        col[i] = uniform();
    }
    uint32_t idx[3 * T];
    for (int i = 0; i < 3 * T; ++i)
        idx[i] = (uint32_t)((i * 5 + i / 3) % V);
    pen_mesh m = {
        .vertex_count = V, .triangle_count = T, .positions = pos, .indices = idx, .colors = col};
    const float def[3] = {0.8f, 0.8f, 0.8f};
    pen_image atlas;
    CHECK(pen_mesh_albedo_plan(&m, NULL) == PEN_MESH_ALBEDO_BAKE);
    CHECK(pen_mesh_bake_albedo(ctx, &m, NULL, def, &atlas) == PEN_OK);
    CHECK(atlas.width == 12 && atlas.height == 12); /* a 3 x 3 grid of 4 x 4 blocks */
    float worst = 0.0f;
    for (int t = 0; t < T; ++t)
        for (int s = 0; s < 20; ++s) {
            float b[3], got[3];
            random_barycentrics(b);
            if (s == 0) b[0] = 1, b[1] = b[2] = 0; /* the corners and an edge too */
            if (s == 1) b[1] = 1, b[0] = b[2] = 0;
            if (s == 2) b[2] = 1, b[0] = b[1] = 0;
            if (s == 3) b[0] = 0, b[1] = b[2] = 0.5f;
            lookup(&m, &atlas, t, b, got);
            for (int c = 0; c < 3; ++c) {
                float w = 0.0f;
                for (int k = 0; k < 3; ++k)
                    w += b[k] * col[3 * idx[3 * t + k] + (uint32_t)c];
                worst = fmaxf(worst, fabsf(got[c] - w));
            }
        }
    CHECK_MSG(worst < 1e-5f, "largest difference %g", (double)worst);
    free(m.uvs);
    free(m.uv_indices);
    pen_image_free(&atlas);
}

/* ---- Readers --------------------------------------------------------------------------------- */

static void test_obj_materials(void) {
    fixture_text("three.mtl", "Kd 0.5 0.5 0.5\n" /* before any newmtl: ignored */
                              "newmtl tex\nmap_Kd tex.png\n"
                              "newmtl green\nKd 0.1 0.8 0.1\n"
                              "newmtl grey\nKd 0.25\n"
                              "newmtl green\nKd 0 1 0\n"); /* a later definition wins */
    const char *p = fixture_text("three.obj", "mtllib three.mtl\n"
                                              "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                                              "f 1 2 3\n"
                                              "usemtl green\nf 1 2 3 4\n"
                                              "usemtl nosuch\nf 1 3 4\n"
                                              "usemtl grey\nf 4 3 2\n");
    pen_mesh m;
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.material_count == 4 && m.triangle_count == 5);
    const int32_t want[] = {-1, 3, 3, -1, 2};
    for (int t = 0; t < 5; ++t)
        CHECK_MSG(m.triangle_materials[t] == want[t], "triangle %d: %d", t,
                  (int)m.triangle_materials[t]);
    CHECK(m.materials[3].has_kd && m.materials[3].kd[1] == 1.0f);
    CHECK(m.materials[2].kd[0] == 0.25f && m.materials[2].kd[2] == 0.25f);
    CHECK(!m.materials[0].has_kd && strstr(m.materials[0].texture_path, "tex.png"));
    CHECK(strstr(m.materials[0].texture_source, "three.mtl:3"));
    CHECK(m.texture_path == NULL); /* no face used the textured material */
    CHECK(pen_mesh_albedo_plan(&m, NULL) == PEN_MESH_ALBEDO_BAKE);
    pen_mesh_free(&m);

    /* usemtl before the mtllib that defines it: the libraries are read first. */
    p = fixture_text("late.obj", "usemtl grey\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                                 "mtllib three.mtl\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.material_count == 4 && m.triangle_materials[0] == 2);
    pen_mesh_free(&m);
    /* One Kd-only material for every face: a constant albedo. */
    p = fixture_text("green.obj", "mtllib three.mtl\nusemtl grey\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                  "f 1 2 3\n");
    int mi = 0;
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(pen_mesh_albedo_plan(&m, &mi) == PEN_MESH_ALBEDO_CONSTANT && mi == 2);
    pen_mesh_free(&m);

    /* Malformed MTL lines name the .mtl file and line. */
    const char *obj = "mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    fixture_text("bad.mtl", "newmtl a\nKd 0.5 0.5\n");
    p = fixture_text("bad.obj", obj);
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "bad.mtl:2", "Kd");
    fixture_text("bad.mtl", "newmtl a\n\nKd nan 0 0\n");
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "bad.mtl:3", "nan");
    fixture_text("bad.mtl", "newmtl a\nKd 0.5 2 0\n");
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "bad.mtl:2", "[0, 1]");
    fixture_text("bad.mtl", "newmtl a\nKd 0.1 0.2 0.3 0.4\n");
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "bad.mtl:2", "1 or 3");

    /* An OBJ repeating `mtllib` without end is stopped by the libraries' byte budget. */
    fixture_text("tiny.mtl", "newmtl t\nKd 1 0 0\n");
    const char *line = "mtllib tiny.mtl\n";
    size_t n = strlen(line), lines = 20000;
    char *big = malloc(n * lines + 64);
    for (size_t i = 0; i < lines; ++i)
        memcpy(big + i * n, line, n);
    strcpy(big + n * lines, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    p = fixture_text("many.obj", big);
    free(big);
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "tiny.mtl", "64 MiB");

    /* OBJ vertex colours: sRGB-encoded values, decoded; only when every vertex has one. */
    p = fixture_text("col.obj", "v 0 0 0 1 0 0.5\nv 1 0 0 0 1 0\nv 0 1 0 0.2 0.2 0.2\nf 1 2 3\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.colors && m.colors[0] == 1.0f && m.colors[1] == 0.0f);
    CHECK(fabsf(m.colors[2] - 0.2140411f) < 1e-6f); /* sRGB 0.5 */
    pen_mesh_free(&m);
    p = fixture_text("halfcol.obj", "v 0 0 0 1 0 0.5\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.colors == NULL);
    pen_mesh_free(&m);
    p = fixture_text("badcol.obj", "v 0 0 0 255 0 0\nv 1 0 0 0 0 0\nv 0 1 0 0 0 0\nf 1 2 3\n");
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "badcol.obj:1", "[0, 1]");
}

static void test_ply_colors(void) {
    const char *p = fixture_text("uc.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                                           "property float x\nproperty float y\nproperty float z\n"
                                           "property uchar red\nproperty uchar green\n"
                                           "property uchar blue\nproperty uchar alpha\n"
                                           "element face 1\n"
                                           "property list uchar int vertex_indices\n"
                                           "end_header\n"
                                           "0 0 0 255 0 128 255\n1 0 0 0 255 0 255\n"
                                           "0 1 0 10 20 30 255\n3 0 1 2\n");
    pen_mesh m;
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.colors && m.colors[0] == 1.0f && m.colors[1] == 0.0f && m.colors[4] == 1.0f);
    CHECK(fabsf(m.colors[2] - 0.2158605f) < 1e-6f); /* sRGB 128/255 */
    CHECK(pen_mesh_validate(ctx, &m) == PEN_OK);
    pen_mesh_free(&m);
    p = fixture_text("fc.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                               "property float x\nproperty float y\nproperty float z\n"
                               "property float red\nproperty float green\nproperty double blue\n"
                               "element face 1\nproperty list uchar int vertex_indices\n"
                               "end_header\n"
                               "0 0 0 0.5 1.5 -1\n1 0 0 0 1 0\n0 1 0 0.25 0.25 0.25\n3 0 1 2\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.colors && m.colors[0] == 0.5f && m.colors[1] == 1.0f && m.colors[2] == 0.0f);
    pen_mesh_free(&m);
    p = fixture_text("ic.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                               "property float x\nproperty float y\nproperty float z\n"
                               "property int red\nproperty int green\nproperty int blue\n"
                               "element face 1\nproperty list uchar int vertex_indices\n"
                               "end_header\n0 0 0 1 1 1\n1 0 0 0 1 0\n0 1 0 1 1 1\n3 0 1 2\n");
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "ic.ply", "red", "uchar");
    /* Binary: a NaN float colour is refused, naming the vertex; ushort codes are sRGB. */
    const char *head = "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                       "property float x\nproperty float y\nproperty float z\n"
                       "property float red\nproperty float green\nproperty float blue\n"
                       "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    unsigned char buf[512];
    size_t n = strlen(head);
    memcpy(buf, head, n);
    float rows[3][6] = {{0, 0, 0, 0.5f, 0.5f, 0.5f}, {1, 0, 0, 0, 0, 0}, {0, 1, 0, 0, NAN, 0}};
    memcpy(buf + n, rows, sizeof rows);
    n += sizeof rows;
    const unsigned char face[13] = {3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0};
    memcpy(buf + n, face, sizeof face);
    p = fixture_write("nan.ply", buf, n + sizeof face);
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "nan.ply", "vertex 2", "green",
                "not finite");
    p = fixture_text("us.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                               "property float x\nproperty float y\nproperty float z\n"
                               "property ushort diffuse_red\nproperty ushort diffuse_green\n"
                               "property ushort diffuse_blue\nelement face 1\n"
                               "property list uchar int vertex_indices\nend_header\n"
                               "0 0 0 65535 0 32768\n1 0 0 0 0 0\n0 1 0 0 0 0\n3 0 1 2\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.colors && m.colors[0] == 1.0f && m.colors[1] == 0.0f);
    CHECK(fabsf(m.colors[2] - 0.2140411f) < 1e-4f); /* sRGB 32768 / 65535 */
    pen_mesh_free(&m);
}

/* ---- The scene loader ------------------------------------------------------------------------ */

static void test_scene_choice(void) {
    write_two_material_obj(); /* red.jpg, blue.jpg */
    /* A map_Kd naming a missing file fails when the scene needs it, naming the .mtl line. */
    fixture_text("gone.mtl", "newmtl a\nKd 0.2 0.2 0.2\nnewmtl b\nmap_Kd gone.png\n");
    fixture_text("gone.obj", "mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n"
                             "usemtl a\nf 1/1 2/1 3/1\nusemtl b\nf 3/1 2/1 1/1\n");
    const char *cam = "{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 30, \"eye\": "
                      "[0, 0, 3], \"target\": [0, 0, 0]}, \"sh_bands\": 1, \"lighting\": "
                      "{\"sh\": [[1, 1, 1]]}, \"objects\": [";
    char json[1024];
    pen_scene sc;
    snprintf(json, sizeof json, "%s{\"mesh\": \"gone.obj\"}]}", cam);
    CHECK_ERROR(ctx, pen_scene_load(ctx, fixture_text("gone.json", json), &sc), PEN_ERROR_IO,
                "objects[0].mesh", "gone.mtl:4", "map_Kd", "gone.png");
    /* ... and not when the scene gives the albedo. */
    snprintf(json, sizeof json, "%s{\"mesh\": \"gone.obj\", \"albedo\": [0.5, 0.5, 0.5]}]}", cam);
    CHECK(pen_scene_load(ctx, fixture_text("gone2.json", json), &sc) == PEN_OK);
    CHECK(sc.objects[0].texture.data == NULL && sc.objects[0].albedo[0] == 0.5f);
    pen_scene_free(&sc);
    /* One Kd-only material: its Kd. */
    fixture_text("kd.obj", "mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n");
    snprintf(json, sizeof json, "%s{\"mesh\": \"kd.obj\"}]}", cam);
    CHECK(pen_scene_load(ctx, fixture_text("kd.json", json), &sc) == PEN_OK);
    CHECK(sc.objects[0].texture.data == NULL && sc.objects[0].albedo[1] == 0.2f);
    pen_scene_free(&sc);
    /* A layout key without a texture, or for a mesh that bakes nothing. */
    snprintf(json, sizeof json, "%s{\"mesh\": \"kd.obj\", \"albedo_texture_layout\": \"baked\"}]}",
             cam);
    CHECK_ERROR(ctx, pen_scene_load(ctx, fixture_text("lay.json", json), &sc), PEN_ERROR_PARSE,
                "objects[0].albedo_texture_layout", "albedo_texture");
    snprintf(json, sizeof json,
             "%s{\"mesh\": \"kd.obj\", \"albedo_texture\": \"red.jpg\", "
             "\"albedo_texture_layout\": \"baked\"}]}",
             cam);
    CHECK_ERROR(ctx, pen_scene_load(ctx, fixture_text("lay.json", json), &sc), PEN_ERROR_PARSE,
                "objects[0].albedo_texture_layout", "several materials");
}

/* Saving a baked object: as baked, the scene names the mesh only; an atlas with new pixels (as
 * the optimizer writes it) is named with its layout and reloads with the same UVs. */
static void test_save_reload(void) {
    write_two_material_obj();
    pen_scene a, b;
    CHECK(pen_scene_load(ctx, quads_scene("sv.json", ""), &a) == PEN_OK);
    CHECK(pen_scene_save(ctx, fixture_path("sv_out.json"), &a) == PEN_OK);
    CHECK(pen_scene_load(ctx, fixture_path("sv_out.json"), &b) == PEN_OK);
    const pen_object *oa = &a.objects[0], *ob = &b.objects[0];
    CHECK(ob->texture_layout == PEN_TEXTURE_LAYOUT_BAKED && ob->texture_path == NULL);
    const size_t texels = 3 * (size_t)oa->texture.width * (size_t)oa->texture.height;
    CHECK(ob->texture.width == oa->texture.width && ob->texture.height == oa->texture.height &&
          memcmp(ob->texture.data, oa->texture.data, texels * sizeof(float)) == 0);
    CHECK(ob->mesh.uv_count == oa->mesh.uv_count &&
          memcmp(ob->mesh.uvs, oa->mesh.uvs, 2 * (size_t)oa->mesh.uv_count * sizeof(float)) == 0);
    pen_scene_free(&b);

    /* Changed pixels, saved as EXR (lossless) beside the scene. */
    for (size_t i = 0; i < texels; ++i)
        a.objects[0].texture.data[i] = 0.5f * a.objects[0].texture.data[i] + 0.125f;
    CHECK(pen_image_save(ctx, fixture_path("atlas.exr"), &a.objects[0].texture) == PEN_OK);
    a.objects[0].texture_path = strdup(fixture_path("atlas.exr"));
    CHECK(pen_scene_save(ctx, fixture_path("sv_out.json"), &a) == PEN_OK);
    char *text = NULL;
    FILE *f = fopen(fixture_path("sv_out.json"), "rb");
    if (f) {
        text = calloc(1, 65536);
        CHECK(fread(text, 1, 65535, f) > 0);
        fclose(f);
    }
    CHECK(text && strstr(text, "\"albedo_texture_layout\":\t\"baked\"") &&
          strstr(text, "atlas.exr"));
    free(text);
    CHECK(pen_scene_load(ctx, fixture_path("sv_out.json"), &b) == PEN_OK);
    ob = &b.objects[0];
    CHECK(ob->texture_layout == PEN_TEXTURE_LAYOUT_BAKED && ob->texture_path);
    CHECK(ob->texture.width == oa->texture.width &&
          memcmp(ob->texture.data, oa->texture.data, texels * sizeof(float)) == 0);
    CHECK(memcmp(ob->mesh.uvs, oa->mesh.uvs, 2 * (size_t)oa->mesh.uv_count * sizeof(float)) == 0);
    pen_scene_free(&b);

    /* An atlas of the wrong size is refused, naming both sizes. */
    pen_image small;
    CHECK(pen_image_create(ctx, 3, 2, 3, &small) == PEN_OK);
    CHECK(pen_image_save(ctx, fixture_path("atlas.exr"), &small) == PEN_OK);
    pen_image_free(&small);
    CHECK_ERROR(ctx, pen_scene_load(ctx, fixture_path("sv_out.json"), &b), PEN_ERROR_PARSE,
                "objects[0].albedo_texture", "atlas.exr", "3 x 2", "baked");
    pen_scene_free(&a);
}

RUN_TESTS(TEST(test_two_jpeg_materials), TEST(test_bake_materials), TEST(test_bake_colors),
          TEST(test_obj_materials), TEST(test_ply_colors), TEST(test_scene_choice),
          TEST(test_save_reload))
