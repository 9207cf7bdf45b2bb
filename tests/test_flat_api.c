/* Tests of the flat renderer API (penumbra/flat.h) that the Python binding calls: it must render
 * and differentiate exactly what pen_render does for the equivalent pen_scene (bitwise: it only
 * rearranges pointers), ask only for the gradient groups whose arrays are set, add into them,
 * load scene JSON the way `penumbra render` does, and refuse malformed flat descriptions with a
 * message naming the field. The gradients themselves are checked against finite differences in
 * test_render_grad.c (C) and python/tests (torch.autograd.gradcheck through this API). */
#include "io_fixtures.h"
#include "render_scenes.h"

#include "penumbra/flat.h"

#include <sys/stat.h>

/* A flat view of sc (objects must hold room for sc->object_count; sh for 3 * 64 floats). */
static pen_flat_scene flat_of(const pen_scene *sc, pen_flat_object *objects, float *sh) {
    pen_flat_scene f = pen_flat_scene_default();
    f.width = sc->camera.width, f.height = sc->camera.height, f.fov_y_deg = sc->camera.fov_y_deg;
    memcpy(f.eye, sc->camera.eye, sizeof f.eye);
    memcpy(f.target, sc->camera.target, sizeof f.target);
    memcpy(f.up, sc->camera.up, sizeof f.up);
    f.sh_bands = sc->sh_bands;
    memcpy(sh, sc->lighting.sh, sizeof sc->lighting.sh);
    f.sh = sh;
    f.epsilon = sc->shadow.epsilon;
    f.exp_method = (int)sc->shadow.exp;
    f.ground_enabled = sc->ground.enabled;
    f.ground_height = sc->ground.height;
    memcpy(f.ground_albedo, sc->ground.albedo, sizeof f.ground_albedo);
    f.ground_half_size = sc->ground.half_size;
    memcpy(f.background, sc->background, sizeof f.background);
    f.self_shadow = (int)sc->shadow.self; /* the same enums' values (flat.h) */
    f.ground_shadow = (int)sc->shadow.ground_shadow;
    f.object_count = sc->object_count;
    f.objects = objects;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        pen_flat_object *fo = &objects[o];
        memset(fo, 0, sizeof *fo);
        fo->vertex_count = ob->mesh.vertex_count, fo->triangle_count = ob->mesh.triangle_count;
        fo->positions = ob->mesh.positions, fo->indices = ob->mesh.indices;
        fo->uv_count = ob->mesh.uv_count, fo->uvs = ob->mesh.uvs;
        fo->uv_indices = ob->mesh.uv_indices;
        if (ob->texture.data) {
            fo->texture_width = ob->texture.width, fo->texture_height = ob->texture.height;
            fo->texture = ob->texture.data;
        }
        memcpy(fo->albedo, ob->albedo, sizeof fo->albedo);
        fo->sphere_count = ob->spheres.count, fo->spheres = ob->spheres.data;
        fo->texture_filter = (int)ob->texture_filter;
        memcpy(fo->pose, ob->pose.rotation_axis_angle_deg, 3 * sizeof(float));
        memcpy(fo->pose + 3, ob->pose.translation, 3 * sizeof(float));
        fo->pose[6] = ob->pose.scale;
    }
    return f;
}

static int same_floats(const float *a, const float *b, size_t n) {
    return memcmp(a, b, n * sizeof(float)) == 0;
}

/* The flat lighting and ground-albedo gradients (d_sh: 3 * 16) are pen_render's, bit for bit. */
static int same_lighting(const float *d_sh, const float *d_ground, const pen_render_grad *g) {
    int same = same_floats(d_ground, g->ground_albedo, 3);
    for (int i = 0; i < 16; ++i)
        same &= same_floats(d_sh + 3 * i, g->sh[i], 3);
    return same;
}

/* The flat forward and backward are pen_render's, bit for bit, for every gradient group. */
static void test_flat_matches_render(void) {
    pen_context *ctx = fixture_ctx();
    unsigned long long seed = 7;
    pen_scene sc = rs_ball_scene(24, 1, &seed);
    /* The model in which every group is exact: the objects' own shadows from their spheres,
     * textures looked up at the pixel's uv (pen_render_grad_model). */
    CHECK(pen_render_grad_model(&sc, PEN_GRAD_ALL) != 0);
    CHECK(sc.shadow.self == PEN_SELF_SPHERES &&
          sc.objects[0].texture_filter == PEN_TEXTURE_FILTER_POINT);
    pen_object *ob = &sc.objects[0];
    pen_flat_object fo;
    float sh[3 * PEN_SH_MAX_COEFFS];
    const pen_flat_scene f = flat_of(&sc, &fo, sh);
    const size_t np = 3 * 24 * 24;

    pen_render_state *st = NULL, *fst = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    CHECK(pen_render_state_create(ctx, &fst) == PEN_OK);
    pen_image img = {0, 0, 0, NULL};
    float *fimg = calloc(np, sizeof(float)), *d_img = malloc(np * sizeof(float));
    const pen_render_options opt = pen_render_options_default();
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(pen_flat_render_fwd(ctx, &f, fst, fimg) == PEN_OK);
    CHECK(same_floats(img.data, fimg, np));
    for (size_t i = 0; i < np; ++i)
        d_img[i] = (float)(check_rand_(&seed) - 0.5);

    pen_render_grad g;
    CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
    const pen_image d = {24, 24, 3, d_img};
    CHECK(pen_render_bwd(ctx, &sc, &opt, st, &d, PEN_GRAD_ALL, &g) == PEN_OK);

    const int V = ob->mesh.vertex_count, nt = 3 * ob->texture.width * ob->texture.height;
    float d_sh[3 * 16] = {0}, d_ground[3] = {0}, d_albedo[3] = {0}, d_spheres[8] = {0},
                   d_pose[7] = {0};
    float *d_pos = calloc(3 * (size_t)V, sizeof(float)), *d_tex = calloc((size_t)nt, sizeof(float));
    pen_flat_object_grad og = {d_pos, d_tex, d_albedo, d_spheres, d_pose};
    pen_flat_grad fg = {d_sh, d_ground, &og, NULL};
    CHECK(pen_flat_render_bwd(ctx, &f, fst, d_img, &fg) == PEN_OK);
    CHECK(same_lighting(d_sh, d_ground, &g));
    CHECK(same_floats(d_pos, g.objects[0].positions, 3 * (size_t)V));
    CHECK(same_floats(d_tex, g.objects[0].texture, (size_t)nt));
    CHECK(same_floats(d_spheres, g.objects[0].spheres, 8));
    const pen_pose_grad *pg = &g.objects[0].pose;
    CHECK(same_floats(d_pose, pg->rotation_axis_angle_deg, 3));
    CHECK(same_floats(d_pose + 3, pg->translation, 3));
    CHECK(d_pose[6] == pg->scale);
    float norm = 0.0f;
    for (int i = 0; i < 8; ++i)
        norm += fabsf(d_spheres[i]);
    CHECK(norm > 0.0f); /* the spheres shadow the ground in view */

    /* Only the lighting asked for: the other arrays stay as they are, and the result adds. */
    float d_sh2[3 * 16], mark[8];
    memcpy(d_sh2, d_sh, sizeof d_sh2);
    for (int i = 0; i < 8; ++i)
        mark[i] = 123.0f;
    memcpy(d_spheres, mark, sizeof mark);
    pen_flat_object_grad og2 = {NULL, NULL, NULL, NULL, NULL};
    pen_flat_grad fg2 = {d_sh2, NULL, &og2, NULL};
    CHECK(pen_flat_render_bwd(ctx, &f, fst, d_img, &fg2) == PEN_OK);
    for (int i = 0; i < 48; ++i)
        CHECK(d_sh2[i] == 2.0f * d_sh[i]);
    CHECK(same_floats(d_spheres, mark, 8));

    pen_render_grad_free(&g);
    free(d_pos), free(d_tex), free(fimg), free(d_img);
    pen_image_free(&img);
    pen_render_state_free(st);
    pen_render_state_free(fst);
    pen_scene_free(&sc);
}

/* The defaults (the objects' own shadows from the transfer, textures over the footprint, as in
 * the JSON), bit for bit, forward and backward of the lighting, textures and albedos; gradients
 * the transfer does not follow are refused in the same words as pen_render_bwd's, not returned
 * as 0. */
static void test_flat_transfer(void) {
    pen_context *ctx = fixture_ctx();
    unsigned long long seed = 11;
    pen_scene sc = rs_ball_scene(24, 1, &seed);
    CHECK(sc.shadow.self == PEN_SELF_TRANSFER);
    CHECK(sc.objects[0].texture.data &&
          sc.objects[0].texture_filter == PEN_TEXTURE_FILTER_FOOTPRINT);
    pen_flat_object fo;
    float sh[3 * PEN_SH_MAX_COEFFS];
    pen_flat_scene f = flat_of(&sc, &fo, sh);
    CHECK(f.self_shadow == 0 && fo.texture_filter == 0); /* zeros are the JSON's defaults */
    const size_t np = 3 * 24 * 24;
    pen_render_state *st = NULL, *fst = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    CHECK(pen_render_state_create(ctx, &fst) == PEN_OK);
    pen_image img = {0, 0, 0, NULL}, pts = {0, 0, 0, NULL};
    float *fimg = calloc(np, sizeof(float)), *d_img = malloc(np * sizeof(float));
    const pen_render_options opt = pen_render_options_default();
    CHECK(pen_render_fwd(ctx, &sc, &opt, st, &img) == PEN_OK);
    CHECK(pen_flat_render_fwd(ctx, &f, fst, fimg) == PEN_OK);
    CHECK(same_floats(img.data, fimg, np));
    pen_scene sph = sc; /* shallow: the model's fields differ, the arrays are shared */
    pen_object sph_ob = sc.objects[0];
    sph.objects = &sph_ob;
    pen_render_grad_model(&sph, PEN_GRAD_POSE);
    CHECK(pen_render_fwd(ctx, &sph, &opt, NULL, &pts) == PEN_OK);
    CHECK(!same_floats(pts.data, fimg, np)); /* the switches do something here */
    for (size_t i = 0; i < np; ++i)
        d_img[i] = (float)(check_rand_(&seed) - 0.5);
    pen_render_grad g;
    CHECK(pen_render_grad_create(ctx, &sc, &g) == PEN_OK);
    const pen_image d = {24, 24, 3, d_img};
    CHECK(pen_render_bwd(ctx, &sc, &opt, st, &d, PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO, &g) ==
          PEN_OK);
    const int nt = 3 * sc.objects[0].texture.width * sc.objects[0].texture.height;
    float d_sh[3 * 16] = {0}, d_ground[3] = {0}, d_albedo[3] = {0};
    float *d_tex = calloc((size_t)nt, sizeof(float));
    pen_flat_object_grad og = {NULL, d_tex, d_albedo, NULL, NULL};
    pen_flat_grad fg = {d_sh, d_ground, &og, NULL};
    CHECK(pen_flat_render_bwd(ctx, &f, fst, d_img, &fg) == PEN_OK);
    CHECK(same_lighting(d_sh, d_ground, &g));
    CHECK(same_floats(d_tex, g.objects[0].texture, (size_t)nt));
    float d_pose[7] = {0};
    pen_flat_object_grad og2 = {NULL, NULL, NULL, NULL, d_pose};
    pen_flat_grad fg2 = {d_sh, NULL, &og2, NULL};
    CHECK_ERROR(ctx, pen_flat_render_bwd(ctx, &f, fst, d_img, &fg2), PEN_ERROR_ARGUMENT,
                "no pose gradient under", "\"self\": \"spheres\"");
    CHECK_ERROR(ctx, pen_flat_grad_check(ctx, &f, PEN_GRAD_POSE), PEN_ERROR_ARGUMENT,
                "no pose gradient");
    CHECK(pen_flat_grad_check(ctx, &f, PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO) == PEN_OK);
    /* The flat rule is the C rule. */
    pen_flat_scene fm = f;
    pen_flat_object fom = fo;
    fm.objects = &fom;
    CHECK(pen_flat_grad_model(&fm, &fom, PEN_GRAD_POSE) == PEN_GRAD_POSE);
    CHECK(fm.self_shadow == (int)sph.shadow.self && fm.ground_shadow == (int)sph.shadow.ground_shadow &&
          fom.texture_filter == (int)sph_ob.texture_filter);
    CHECK(pen_flat_grad_check(ctx, &fm, PEN_GRAD_ALL) == PEN_OK);
    f.self_shadow = 2;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, fimg), PEN_ERROR_ARGUMENT,
                "self_shadow 2 is not 0 (transfer) or 1 (spheres)");
    f.self_shadow = 0, fo.texture_filter = 3;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, fimg), PEN_ERROR_ARGUMENT, "objects[0]",
                "texture_filter 3");
    pen_render_grad_free(&g);
    free(d_tex), free(fimg), free(d_img);
    pen_image_free(&img), pen_image_free(&pts);
    pen_render_state_free(st);
    pen_render_state_free(fst);
    pen_scene_free(&sc);
}

/* Per-vertex uvs (uv_indices NULL) are read through the position indices. */
static void test_flat_per_vertex_uvs(void) {
    pen_context *ctx = fixture_ctx();
    unsigned long long seed = 3;
    pen_scene sc = rs_ball_scene(20, 1, &seed);
    pen_flat_object fo;
    float sh[3 * PEN_SH_MAX_COEFFS];
    const pen_flat_scene f = flat_of(&sc, &fo, sh);
    const size_t np = 3 * 20 * 20;
    float *a = malloc(np * sizeof(float)), *b = malloc(np * sizeof(float));
    CHECK(pen_flat_render_fwd(ctx, &f, NULL, a) == PEN_OK);
    fo.uv_indices = NULL; /* rs_octasphere's uv indices equal its indices */
    CHECK(pen_flat_render_fwd(ctx, &f, NULL, b) == PEN_OK);
    CHECK(same_floats(a, b, np));
    fo.uv_count = fo.vertex_count - 1;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, b), PEN_ERROR_ARGUMENT, "objects[0]",
                "uvs for");
    free(a), free(b);
    pen_scene_free(&sc);
}

static const char CUBE_OBJ[] = "v -0.3 0 -0.3\nv 0.3 0 -0.3\nv 0.3 0.6 -0.3\nv -0.3 0.6 -0.3\n"
                               "v -0.3 0 0.3\nv 0.3 0 0.3\nv 0.3 0.6 0.3\nv -0.3 0.6 0.3\n"
                               "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n";

/* A scene JSON loaded through the flat API renders as pen_scene_load + pen_render_fwd does, every
 * key kept; a {"fit": N} request is left empty or fitted as asked, and an object left without
 * spheres is refused by a render with shadows. */
static void test_flat_scene_load(void) {
    check_private_cache_(); /* the fit cache below goes to a folder of this test */
    pen_context *ctx = fixture_ctx();
    fixture_text("cube.obj", CUBE_OBJ);
    const char *json =
        "{\"camera\": {\"width\": 20, \"height\": 16, \"fov_y_deg\": 40, \"eye\": [1.2, 1.3, 2],"
        " \"target\": [0, 0.3, 0]},"
        " \"lighting\": {\"sh\": [[1.2, 1.1, 1], [-0.8, -0.8, -0.8], [0.2, 0.2, 0.2], [0, 0, 0]]},"
        " \"sh_bands\": 2,"
        " \"objects\": [{\"mesh\": \"cube.obj\", \"albedo\": [0.6, 0.5, 0.4],"
        "   \"spheres\": [{\"center\": [0, 0.3, 0], \"radius\": 0.3}],"
        "   \"pose\": {\"rotation_axis_angle_deg\": [0, 30, 0], \"translation\": [0.1, 0, 0]}},"
        "  {\"mesh\": \"cube.obj\", \"spheres\": {\"fit\": 2},"
        "   \"pose\": {\"translation\": [-0.8, 0, -0.5], \"scale\": 0.5}}],"
        " \"ground\": {\"albedo\": [0.7, 0.7, 0.7]}, \"background\": [0.1, 0.2, 0.3]}";
    const char *path = fixture_text("scene.json", json);

    pen_flat_loaded *l = NULL;
    CHECK(pen_flat_scene_load(ctx, path, 0, &l) == PEN_OK);
    if (!l) return;
    const pen_flat_scene *f = pen_flat_loaded_scene(l);
    CHECK(f->object_count == 2 && f->width == 20 && f->height == 16 && f->sh_bands == 2);
    CHECK(f->objects[0].sphere_count == 1 && f->objects[1].sphere_count == 0);
    CHECK(pen_flat_loaded_fit_request(l, 1) == 2 && pen_flat_loaded_fit_request(l, 0) == 0);
    CHECK(pen_flat_loaded_fit_request(l, 2) == -1);
    CHECK(f->objects[1].pose[6] == 0.5f && f->objects[0].triangle_count == 12);
    CHECK(f->sh[3] == -0.8f);

    pen_scene sc;
    CHECK(pen_scene_load(ctx, path, &sc) == PEN_OK);
    pen_image img = {0, 0, 0, NULL};
    pen_render_options opt = pen_render_options_default();
    float fimg[3 * 20 * 16];
    /* objects[1] asked for a fit that was not made: with shadows it would cast none. */
    CHECK_ERROR(ctx, pen_render_fwd(ctx, &sc, &opt, NULL, &img), PEN_ERROR_ARGUMENT,
                "objects[1]", "{\"fit\": 2} is not fitted yet");
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, f, NULL, fimg), PEN_ERROR_ARGUMENT, "objects[1]",
                "no spheres");
    opt.shadows = 0;
    pen_flat_scene unshadowed = *f;
    unshadowed.shadows = 0;
    CHECK(f->self_shadow == (int)sc.shadow.self && f->ground_shadow == (int)sc.shadow.ground_shadow);
    CHECK(pen_render_fwd(ctx, &sc, &opt, NULL, &img) == PEN_OK);
    CHECK(pen_flat_render_fwd(ctx, &unshadowed, NULL, fimg) == PEN_OK);
    CHECK(img.data && same_floats(img.data, fimg, 3 * 20 * 16));
    pen_image_free(&img);
    pen_flat_loaded_free(l);

    /* With fit_spheres the request goes to the fitter's cache; a cache file written here
     * stands in for a fit (a real one takes seconds, and is tested in test_fit). */
    char cache_dir[64];
    snprintf(cache_dir, sizeof cache_dir, "%s/penumbra", check_cache_dir_);
    CHECK(mkdir(cache_dir, 0700) == 0);
    char *cache = NULL;
    CHECK(pen_spheres_fit_cache_path(ctx, &sc.objects[1].mesh, sc.objects[1].mesh_path, 2, NULL,
                                     &cache) == PEN_OK);
    const char *key = cache ? strrchr(cache, '-') : NULL;
    if (key) {
        char text[256];
        snprintf(text, sizeof text,
                 "{\"fit_key\": \"%.16s\", \"spheres\": [{\"center\": [0, 0.2, 0], "
                 "\"radius\": 0.2}, {\"center\": [0, 0.4, 0], \"radius\": 0.25}]}",
                 key + 1);
        FILE *fc = fopen(cache, "w");
        CHECK(fc && fputs(text, fc) >= 0 && fclose(fc) == 0);
    }
    free(cache);
    pen_scene_free(&sc);
    CHECK(pen_flat_scene_load(ctx, path, 1, &l) == PEN_OK);
    if (l) {
        const pen_flat_object *o1 = &pen_flat_loaded_scene(l)->objects[1];
        CHECK(o1->sphere_count == 2 && o1->spheres[7] == 0.25f);
    }
    pen_flat_loaded_free(l);

    CHECK_ERROR(ctx, pen_flat_scene_load(ctx, fixture_path("nosuch.json"), 0, &l), PEN_ERROR_IO,
                "nosuch.json");
    CHECK(l == NULL);
    pen_flat_loaded_free(NULL);
}

/* Malformed flat descriptions: each refused with the field named, nothing rendered. */
static void test_flat_errors(void) {
    pen_context *ctx = fixture_ctx();
    unsigned long long seed = 5;
    pen_scene sc = rs_ball_scene(16, 1, &seed);
    pen_flat_object fo, good;
    float sh[3 * PEN_SH_MAX_COEFFS];
    pen_flat_scene f = flat_of(&sc, &fo, sh);
    good = fo;
    float img[3 * 16 * 16], d_img[3 * 16 * 16] = {0};
    const pen_flat_scene fgood = f;

    f.sh = NULL;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "SH lighting");
    f = fgood, f.sh_bands = 9;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "sh_bands 9");
    f = fgood, f.object_count = 1, f.objects = NULL;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "object list");
    f = fgood, f.ground_occlusion = 2;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT,
                "ground_occlusion 2 is not 0 or 1");
    f = fgood, f.overlap = -1;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "overlap -1");
    f = fgood, f.width = 0;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "0x16");
    f = fgood, f.envmap_width = 8, f.envmap_height = 4;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "envmap",
                "no pixels");
    f = fgood, f.envmap_width = -1, f.envmap_height = 4;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "envmap", "-1x4");
    f = fgood;
    fo.triangle_count = 0;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "objects[0]",
                "triangles");
    fo = good, fo.texture = NULL;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT,
                "objects[0].texture", "no pixels");
    fo = good, fo.sphere_count = 2, fo.spheres = NULL;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "objects[0]",
                "sphere array");
    fo = good, fo.uv_count = -2;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "uv array");
    fo = good, fo.pose[6] = 0.0f; /* the renderer's own checks come through */
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "pose");
    uint32_t bad_idx[3] = {0, 1, 99999};
    fo = good, fo.triangle_count = 1, fo.indices = bad_idx, fo.uv_indices = bad_idx;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, &f, NULL, img), PEN_ERROR_ARGUMENT, "objects[0]",
                "99999");
    fo = good;
    CHECK_ERROR(ctx, pen_flat_render_fwd(ctx, NULL, NULL, img), PEN_ERROR_ARGUMENT, "NULL");

    /* Backward without a forward on this state. */
    pen_render_state *st = NULL;
    CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
    float d_sh[3 * 16] = {0};
    pen_flat_grad g = {d_sh, NULL, NULL, NULL};
    CHECK_ERROR(ctx, pen_flat_render_bwd(ctx, &f, st, d_img, &g), PEN_ERROR_ARGUMENT, "no forward");
    CHECK(pen_flat_render_fwd(ctx, &f, st, img) == PEN_OK);
    CHECK(pen_flat_render_bwd(ctx, &f, st, d_img, &g) == PEN_OK);
    CHECK_ERROR(ctx, pen_flat_render_bwd(ctx, &f, st, NULL, &g), PEN_ERROR_ARGUMENT, "NULL");
    pen_render_state_free(st);
    pen_scene_free(&sc);
}

/* A renderer kept across calls gives what a fresh state gives, bit for bit, step after step,
 * while the parameters change between steps and the frame changes size. */
static void test_flat_renderer_reuse(void) {
    pen_context *ctx = fixture_ctx();
    unsigned long long seed = 11;
    pen_scene sc = rs_ball_scene(24, 1, &seed);
    pen_render_grad_model(&sc, PEN_GRAD_ALL); /* every group below has its gradient */
    const pen_object *ob = &sc.objects[0];
    pen_flat_object fo;
    float sh[3 * PEN_SH_MAX_COEFFS];
    pen_flat_scene f = flat_of(&sc, &fo, sh);
    const int V = ob->mesh.vertex_count, nt = 3 * ob->texture.width * ob->texture.height;
    const size_t np = 3 * 24 * 24, nv = 3 * (size_t)V;
    float *img[2], *d_img = malloc(np * sizeof(float)), *d_pos[2], *d_tex[2];
    float d_sh[2][3 * 16], d_ground[2][3], d_albedo[2][3], d_spheres[2][8], d_pose[2][7];
    for (int k = 0; k < 2; ++k) {
        img[k] = malloc(np * sizeof(float));
        d_pos[k] = malloc(nv * sizeof(float));
        d_tex[k] = malloc((size_t)nt * sizeof(float));
    }
    pen_flat_renderer *r = NULL;
    CHECK(pen_flat_renderer_create(ctx, &r) == PEN_OK);
    CHECK(pen_flat_renderer_state(r) != NULL);
    float *pos = malloc(nv * sizeof(float)), sph[8];
    memcpy(pos, ob->mesh.positions, nv * sizeof(float));
    memcpy(sph, ob->spheres.data, sizeof sph);
    fo.positions = pos, fo.spheres = sph;
    for (int step = 0; step < 4; ++step) {
        /* Every differentiable input moves a little; step 2 renders a smaller frame. */
        sh[3] += 0.05f, fo.pose[4] += 0.01f, fo.albedo[1] *= 0.97f;
        sph[3] *= 1.02f, pos[1] += 0.003f;
        f.width = f.height = step == 2 ? 20 : 24;
        const size_t n = 3 * (size_t)f.width * (size_t)f.height;
        for (size_t i = 0; i < n; ++i)
            d_img[i] = (float)(check_rand_(&seed) - 0.5);
        for (int k = 0; k < 2; ++k) {
            memset(d_sh[k], 0, sizeof d_sh[k]), memset(d_ground[k], 0, sizeof d_ground[k]);
            memset(d_albedo[k], 0, sizeof d_albedo[k]);
            memset(d_spheres[k], 0, sizeof d_spheres[k]), memset(d_pose[k], 0, sizeof d_pose[k]);
            memset(d_pos[k], 0, nv * sizeof(float));
            memset(d_tex[k], 0, (size_t)nt * sizeof(float));
            pen_flat_object_grad og = {d_pos[k], d_tex[k], d_albedo[k], d_spheres[k], d_pose[k]};
            pen_flat_grad fg = {d_sh[k], d_ground[k], &og, NULL};
            if (k == 0) {
                pen_render_state *st = NULL;
                CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
                CHECK(pen_flat_render_fwd(ctx, &f, st, img[k]) == PEN_OK);
                CHECK(pen_flat_render_bwd(ctx, &f, st, d_img, &fg) == PEN_OK);
                pen_render_state_free(st);
            } else {
                CHECK(pen_flat_renderer_fwd(ctx, r, &f, img[k]) == PEN_OK);
                CHECK(pen_flat_renderer_bwd(ctx, r, &f, d_img, &fg) == PEN_OK);
            }
        }
        CHECK(same_floats(img[0], img[1], n));
        CHECK(same_floats(d_sh[0], d_sh[1], 48) && same_floats(d_ground[0], d_ground[1], 3));
        CHECK(same_floats(d_albedo[0], d_albedo[1], 3));
        CHECK(same_floats(d_spheres[0], d_spheres[1], 8) && same_floats(d_pose[0], d_pose[1], 7));
        CHECK(same_floats(d_pos[0], d_pos[1], nv) && same_floats(d_tex[0], d_tex[1], (size_t)nt));
    }
    CHECK_ERROR(ctx, pen_flat_renderer_fwd(ctx, NULL, &f, img[0]), PEN_ERROR_ARGUMENT, "NULL");
    pen_flat_renderer_free(r);
    pen_flat_renderer_free(NULL);
    for (int k = 0; k < 2; ++k)
        free(img[k]), free(d_pos[k]), free(d_tex[k]);
    free(d_img), free(pos);
    pen_scene_free(&sc);
}

/* The layout table names every member of each struct: members follow one another with no gap
 * beyond alignment (4 bytes for ints, floats and float arrays, 8 for pointers), and the struct
 * ends after its last member (rounded to 8 when it holds a pointer). */
static void test_flat_abi(void) {
    const pen_flat_abi_field *t = NULL;
    int n = 0;
    CHECK(pen_flat_abi(&t, &n) == PEN_FLAT_ABI_VERSION);
    CHECK(t != NULL && n > 0 && t[0].field == NULL);
    int structs = 0;
    for (int i = 0; i < n;) {
        CHECK(t[i].field == NULL);
        const char *type = t[i].type;
        const size_t size = t[i].size;
        size_t end = 0, align_max = 4;
        int j = i + 1;
        for (; j < n && t[j].field; ++j) {
            CHECK(strcmp(t[j].type, type) == 0);
            const size_t align = t[j].size == 8 ? 8 : 4;
            align_max = align > align_max ? align : align_max;
            const size_t at = (end + align - 1) / align * align;
            if (t[j].offset != at)
                printf("  %s.%s at %zu, expected %zu\n", type, t[j].field, t[j].offset, at);
            CHECK(t[j].offset == at);
            end = t[j].offset + t[j].size;
        }
        CHECK(j > i + 1);
        CHECK(size == (end + align_max - 1) / align_max * align_max);
        ++structs, i = j;
    }
    CHECK(structs == 7);
    int found = 0;
    for (int i = 0; i < n; ++i)
        if (t[i].field && !strcmp(t[i].type, "pen_flat_scene") &&
            !strcmp(t[i].field, "ground_occlusion"))
            found = t[i].offset == offsetof(pen_flat_scene, ground_occlusion) &&
                    t[i].size == sizeof(int);
    CHECK(found);
}

RUN_TESTS(TEST(test_flat_matches_render), TEST(test_flat_transfer), TEST(test_flat_per_vertex_uvs),
          TEST(test_flat_scene_load), TEST(test_flat_errors), TEST(test_flat_renderer_reuse),
          TEST(test_flat_abi))
