/* The scene JSON's placement keys (docs/file-formats.md, "Placing objects and the camera"):
 * "units", "pose": {"on_ground", "centre"}, "camera": {"frame"}, resolved by the loader into the
 * pose and the camera, saved as those numbers and read back the same; their errors. Also what a
 * user is told about a scene and a mesh: pen_scene_check's warnings and light summaries,
 * pen_mesh_files_load's found and missing files, pen_mesh_edges_count's closedness. */
#include "io_fixtures.h" /* first: it sets the feature-test macros */

#include "scene/camera.h"

#include <math.h>

#define ctx fixture_ctx()

/* A box in centimetres, 40 x 90 x 20, its corner at (100, 30, -50): far off the origin, as
 * modelling tools leave assets. */
static const char *BOX = "v 100 30 -50\nv 140 30 -50\nv 100 120 -50\nv 140 120 -50\n"
                         "v 100 30 -30\nv 140 30 -30\nv 100 120 -30\nv 140 120 -30\n"
                         "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

static void write_assets(void) {
    static int done = 0;
    if (done) return;
    done = 1;
    fixture_text("box.obj", BOX);
    char text[1024];
    snprintf(text, sizeof text, "mtllib gone.mtl\nmtllib box.mtl\nmtllib gone.mtl\n%s", BOX);
    fixture_text("box_mtl.obj", text);
    fixture_text("box.mtl", "newmtl used\nKd 0.5 0.5 0.5\nnewmtl unused\nmap_Kd nowhere.png\n"
                            "newmtl there\nmap_Kd tex.png\n");
    pen_image im;
    CHECK(pen_image_create(ctx, 2, 2, 3, &im) == PEN_OK);
    CHECK(pen_image_save(ctx, fixture_path("tex.png"), &im) == PEN_OK);
    pen_image_free(&im);
}

static pen_status load(const char *json, pen_scene *sc) {
    write_assets();
    return pen_scene_parse(ctx, json, fixture_path("scene.json"), sc);
}

/* The posed bounds of an object, as the renderer places its vertices (float). */
static void posed_bounds(const pen_object *ob, float lo[3], float hi[3]) {
    for (int i = 0; i < ob->mesh.vertex_count; ++i) {
        float q[3];
        pen_pose_apply(&ob->pose, ob->mesh.positions + 3 * i, q);
        for (int a = 0; a < 3; ++a) {
            if (i == 0 || q[a] < lo[a]) lo[a] = q[a];
            if (i == 0 || q[a] > hi[a]) hi[a] = q[a];
        }
    }
}

static void test_on_ground_units_centre(void) {
    pen_scene sc;
    /* Rotated a quarter turn about z first: the lowest vertex is then one of the box's x = 140
     * corners; the ground at 0.5 and a lift of 0.25 above it. */
    CHECK_MSG(load("{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40,"
                   " \"eye\": [0, 1, 5], \"target\": [0, 0, 0]},"
                   " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]},"
                   " \"ground\": {\"height\": 0.5},"
                   " \"objects\": [{\"mesh\": \"box.obj\", \"units\": \"cm\","
                   "  \"pose\": {\"rotation_axis_angle_deg\": [0, 0, 90], \"scale\": 2,"
                   "   \"translation\": [1, 0.25, -2], \"on_ground\": true, \"centre\": true}},"
                   "  {\"mesh\": \"box.obj\", \"units\": \"mm\"}]}",
                   &sc) == PEN_OK,
              "%s", pen_context_error(ctx));
    CHECK(sc.object_count == 2);
    if (sc.object_count != 2) return;
    CHECK(sc.objects[0].pose.scale == (float)(2.0 * 0.01));
    CHECK(sc.objects[1].pose.scale == (float)0.001);
    float lo[3], hi[3];
    posed_bounds(&sc.objects[0], lo, hi);
    CHECK_NEAR(lo[1], 0.75, 1e-6);
    CHECK_NEAR(0.5 * ((double)lo[0] + (double)hi[0]), 1.0, 1e-6);
    CHECK_NEAR(0.5 * ((double)lo[2] + (double)hi[2]), -2.0, 1e-6);
    CHECK_NEAR(hi[1] - lo[1], 0.8, 1e-6); /* the 40 cm side, doubled, stands up after the turn */
    /* Without the keys, the mm box stays where its file puts it. */
    posed_bounds(&sc.objects[1], lo, hi);
    CHECK_NEAR(lo[1], 0.03, 1e-7);
    pen_scene_free(&sc);

    /* Without a ground, on_ground stands on y = 0. */
    CHECK_MSG(load("{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40,"
                   " \"eye\": [0, 1, 5], \"target\": [0, 0, 0]},"
                   " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]},"
                   " \"objects\": [{\"mesh\": \"box.obj\", \"pose\": {\"on_ground\": true}}]}",
                   &sc) == PEN_OK,
              "%s", pen_context_error(ctx));
    posed_bounds(&sc.objects[0], lo, hi);
    CHECK(lo[1] == 0.0f && lo[0] == 100.0f);
    pen_scene_free(&sc);
}

/* Every vertex of the scene inside the image shrunk by 1/margin, and one on its edge. */
static void check_framed(const pen_scene *sc, double margin) {
    double r[3], u[3], f[3], focal[2], cx, cy;
    pen__camera_frame_d(&sc->camera, r, u, f);
    pen__camera_intrinsics_d(&sc->camera, focal, &cx, &cy);
    const double tx = fmin(cx, sc->camera.width - cx) / focal[0];
    const double ty = fmin(cy, sc->camera.height - cy) / focal[1];
    double worst = 0.0;
    for (int o = 0; o < sc->object_count; ++o)
        for (int i = 0; i < sc->objects[o].mesh.vertex_count; ++i) {
            float q[3];
            pen_pose_apply(&sc->objects[o].pose, sc->objects[o].mesh.positions + 3 * i, q);
            double d[3];
            for (int a = 0; a < 3; ++a)
                d[a] = (double)q[a] - (double)sc->camera.eye[a];
            const double z = d[0] * f[0] + d[1] * f[1] + d[2] * f[2];
            CHECK(z > 0.0);
            const double x = fabs(d[0] * r[0] + d[1] * r[1] + d[2] * r[2]) / (z * tx);
            const double y = fabs(d[0] * u[0] + d[1] * u[1] + d[2] * u[2]) / (z * ty);
            worst = fmax(worst, fmax(x, y));
        }
    CHECK_MSG(worst <= (1.0 + 1e-5) / margin && worst >= (1.0 - 1e-5) / margin,
              "the farthest vertex at %.6f of the half-image, expected 1/%g", worst, margin);
}

static void test_frame(void) {
    pen_scene sc;
    CHECK_MSG(
        load("{\"camera\": {\"width\": 64, \"height\": 32, \"fov_y_deg\": 30, \"frame\": true},"
             " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, \"ground\": {},"
             " \"objects\": [{\"mesh\": \"box.obj\", \"units\": \"cm\","
             "  \"pose\": {\"on_ground\": true, \"centre\": true}}]}",
             &sc) == PEN_OK,
        "%s", pen_context_error(ctx));
    CHECK(pen_scene_validate(ctx, &sc) == PEN_OK);
    check_framed(&sc, 1.1);
    /* The default view: azimuth 30, elevation 20 degrees, looking at the bounds' centre. */
    const float *e = sc.camera.eye, *t = sc.camera.target;
    const double dx = e[0] - t[0], dy = e[1] - t[1], dz = e[2] - t[2];
    CHECK_NEAR(atan2(dx, dz) * 180.0 / 3.14159265358979, 30.0, 1e-3);
    CHECK_NEAR(atan2(dy, sqrt(dx * dx + dz * dz)) * 180.0 / 3.14159265358979, 20.0, 1e-3);
    CHECK_NEAR(t[1], 0.45, 1e-6);
    CHECK(sc.camera.up[0] == 0.0f && sc.camera.up[1] == 1.0f && sc.camera.up[2] == 0.0f);

    /* Saved as numbers, read back the same: the file holds no placement key. */
    const char *out = fixture_path("framed_saved.json");
    CHECK(pen_scene_save(ctx, out, &sc) == PEN_OK);
    FILE *f = fopen(out, "rb");
    char text[8192] = {0};
    if (f) {
        CHECK(fread(text, 1, sizeof text - 1, f) > 0);
        fclose(f);
    }
    CHECK(!strstr(text, "frame") && !strstr(text, "on_ground") && !strstr(text, "units") &&
          strstr(text, "\"eye\""));
    pen_scene back;
    CHECK_MSG(pen_scene_load(ctx, out, &back) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(memcmp(&back.camera, &sc.camera, sizeof sc.camera) == 0);
    CHECK(back.object_count == 1 &&
          memcmp(&back.objects[0].pose, &sc.objects[0].pose, sizeof sc.objects[0].pose) == 0);
    pen_scene_free(&back);
    pen_scene_free(&sc);

    /* Its settings, two objects, and a calibrated camera with its principal point off the
     * centre: the nearer edge bounds the frame. */
    CHECK_MSG(load("{\"camera\": {\"width\": 40, \"height\": 60,"
                   "  \"intrinsics\": {\"fx\": 50, \"fy\": 55, \"cx\": 16, \"cy\": 33},"
                   "  \"frame\": {\"azimuth_deg\": -120, \"elevation_deg\": 60, \"margin\": 1.5}},"
                   " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]},"
                   " \"objects\": [{\"mesh\": \"box.obj\", \"units\": \"cm\"},"
                   "  {\"mesh\": \"box.obj\", \"units\": \"mm\","
                   "   \"pose\": {\"rotation_axis_angle_deg\": [30, 0, 0]}}]}",
                   &sc) == PEN_OK,
              "%s", pen_context_error(ctx));
    check_framed(&sc, 1.5);
    pen_scene_free(&sc);

    /* "frame": false is a camera as before. */
    CHECK_MSG(load("{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"frame\": false,"
                   " \"eye\": [0, 1, 5], \"target\": [0, 0, 0]},"
                   " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, \"objects\": []}",
                   &sc) == PEN_OK,
              "%s", pen_context_error(ctx));
    CHECK(sc.camera.eye[2] == 5.0f);
    pen_scene_free(&sc);
}

static void test_errors(void) {
    static const struct {
        const char *camera, *object, *want;
    } cases[] = {
        {"\"frame\": true, \"eye\": [0, 0, 1]", "{\"mesh\": \"box.obj\"}",
         "scene.json: camera.frame: places the camera: leave out \"eye\""},
        {"\"frame\": true, \"world_to_camera\": {\"R\": [[1,0,0],[0,1,0],[0,0,1]], \"t\": [0,0,1]}",
         "{\"mesh\": \"box.obj\"}",
         "camera.frame: places the camera: leave out \"world_to_camera\""},
        {"\"frame\": 1", "{\"mesh\": \"box.obj\"}",
         "camera.frame: expected true, false or {\"azimuth_deg\""},
        {"\"frame\": {\"elevation_deg\": 90}", "{\"mesh\": \"box.obj\"}",
         "camera.frame.elevation_deg: "},
        {"\"frame\": {\"margin\": 0.5}", "{\"mesh\": \"box.obj\"}", "camera.frame.margin: "},
        {"\"frame\": {\"zoom\": 2}", "{\"mesh\": \"box.obj\"}", "camera.frame.zoom: unknown key"},
        {"\"frame\": true", NULL, "camera.frame: no object to frame"},
        {"\"eye\": [0, 0, 1], \"target\": [0, 0, 0]",
         "{\"mesh\": \"box.obj\", \"units\": \"furlong\"}", "objects[0].units: unknown unit"},
        {"\"eye\": [0, 0, 1], \"target\": [0, 0, 0]",
         "{\"mesh\": \"box.obj\", \"units\": \"mm\", \"pose\": {\"scale\": 1e-4}}",
         "objects[0].units: \"mm\" with pose.scale 0.0001 gives the scale 1e-07, outside"},
        {"\"eye\": [0, 0, 1], \"target\": [0, 0, 0]",
         "{\"mesh\": \"box.obj\", \"pose\": {\"on_ground\": 1}}",
         "objects[0].pose.on_ground: expected true or false"},
        {"\"eye\": [0, 0, 1], \"target\": [0, 0, 0]",
         "{\"mesh\": \"box.obj\", \"pose\": {\"centre\": true, \"translation\": [-1e6, 0, 0]}}",
         "objects[0].pose: placed as asked, the translation would leave"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; ++k) {
        char json[1024];
        snprintf(json, sizeof json,
                 "{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, %s},"
                 " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]]}, \"objects\": [%s]}",
                 cases[k].camera, cases[k].object ? cases[k].object : "");
        pen_scene sc;
        CHECK_ERROR(ctx, load(json, &sc), PEN_ERROR_PARSE, cases[k].want);
    }
}

static int has_warning(const pen_scene_report *r, pen_scene_warning_kind kind, const char *text) {
    for (int i = 0; i < r->warning_count; ++i)
        if (r->warnings[i].kind == kind && strstr(r->warnings[i].message, text)) return 1;
    return 0;
}

static void test_check(void) {
    pen_scene sc;
    pen_scene_report r;
    /* A centimetre box read as metres, the camera inside it, two libraries (one missing), a
     * missing texture of an unused material, a light straight up and one 45 degrees up. */
    CHECK_MSG(
        load("{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40,"
             " \"eye\": [120, 60, -40], \"target\": [0, 0, 0]},"
             " \"sh_bands\": 1, \"lighting\": {\"sh\": [[0, 0, 0]], \"lights\": ["
             "  {\"direction\": [0, 2, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, 1, 1]},"
             "  {\"direction\": [1, 1, 0], \"angular_radius_deg\": 3, \"irradiance\": [3, 3, 3]}]},"
             " \"ground\": {}, \"objects\": [{\"mesh\": \"box_mtl.obj\"}]}",
             &sc) == PEN_OK,
        "%s", pen_context_error(ctx));
    CHECK_MSG(pen_scene_check(ctx, &sc, &r) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(r.warning_count == 4);
    CHECK(has_warning(&r, PEN_SCENE_WARNING_CAMERA_INSIDE, "is inside objects[0] (box_mtl.obj)"));
    CHECK(has_warning(&r, PEN_SCENE_WARNING_OBJECT_HUGE, "\"units\": \"cm\""));
    CHECK(has_warning(&r, PEN_SCENE_WARNING_MTLLIB_MISSING, "gone.mtl (named at box_mtl.obj:1)"));
    CHECK(has_warning(&r, PEN_SCENE_WARNING_TEXTURE_MISSING,
                      "nowhere.png (map_Kd of material "
                      "'unused', box.mtl:4) is not found; "
                      "no face uses that material"));
    CHECK(r.object_count == 1 && r.bounds && r.bounds[1] == 30.0f && r.bounds[5] == -30.0f);
    CHECK(r.light_count == 2);
    CHECK_NEAR(r.lights[0].elevation_deg, 90.0, 1e-4);
    CHECK_NEAR(r.lights[1].elevation_deg, 45.0, 1e-4);
    CHECK_NEAR(r.lights[1].azimuth_deg, 90.0, 1e-4);
    /* Shares of the lights alone: 2 E / (1 + cos b). */
    const double a = 2.0 / (1.0 + cos(1.0 * 3.14159265358979 / 180.0));
    const double b = 3.0 * 2.0 / (1.0 + cos(3.0 * 3.14159265358979 / 180.0));
    CHECK_NEAR(r.lights[0].share, a / (a + b), 1e-6);
    CHECK_NEAR(r.lights[0].share + r.lights[1].share, 1.0, 1e-6);
    pen_scene_report_free(&r);
    pen_scene_free(&sc);

    /* Tiny (4.5 cm against 8 m), then well placed (no warning), with the SH's share of the
     * light. */
    CHECK_MSG(
        load("{\"camera\": {\"width\": 8, \"height\": 8, \"fov_y_deg\": 40, \"frame\": true},"
             " \"sh_bands\": 1, \"lighting\": {\"sh\": [[1, 1, 1]], \"lights\": ["
             "  {\"direction\": [0, 1, 0], \"angular_radius_deg\": 1, \"irradiance\": [1, 1, 1]}]},"
             " \"ground\": {}, \"objects\": [{\"mesh\": \"box.obj\", \"units\": \"mm\","
             "   \"pose\": {\"scale\": 0.5}},"
             "  {\"mesh\": \"box.obj\", \"units\": \"cm\", \"pose\": {\"on_ground\": true}}]}",
             &sc) == PEN_OK,
        "%s", pen_context_error(ctx));
    CHECK_MSG(pen_scene_check(ctx, &sc, &r) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(r.warning_count == 1 && has_warning(&r, PEN_SCENE_WARNING_OBJECT_TINY, "objects[0]"));
    const double l = 2.0 / (1.0 + cos(3.14159265358979 / 180.0));
    CHECK_NEAR(r.lights[0].share, l / (l + sqrt(4.0 * 3.14159265358979)), 1e-6);
    pen_scene_report_free(&r);
    pen_scene_free(&sc);
}

static void test_mesh_files(void) {
    write_assets();
    pen_mesh_files files;
    CHECK_MSG(pen_mesh_files_load(ctx, fixture_path("box_mtl.obj"), &files) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(files.count == 4); /* gone.mtl once, box.mtl, then the two textures */
    if (files.count == 4) {
        CHECK(files.files[0].kind == PEN_MESH_FILE_MTLLIB && !files.files[0].found &&
              strstr(files.files[0].source, "box_mtl.obj:1"));
        CHECK(files.files[1].kind == PEN_MESH_FILE_MTLLIB && files.files[1].found &&
              !files.files[1].material);
        CHECK(files.files[2].kind == PEN_MESH_FILE_TEXTURE && !files.files[2].found &&
              !strcmp(files.files[2].material, "unused") &&
              strstr(files.files[2].source, "box.mtl:4"));
        CHECK(files.files[3].found && strstr(files.files[3].path, "tex.png"));
    }
    pen_mesh_files_free(&files);
    pen_mesh_files_free(&files); /* freed twice: zeroed the first time */
    CHECK(pen_mesh_files_load(ctx, fixture_path("box.obj"), &files) == PEN_OK && files.count == 0);
    /* CRLF, blanks before the statement, a last line without its newline. */
    char text[1024];
    snprintf(text, sizeof text, "%s  mtllib box.mtl\r\nmtllib last.mtl", BOX);
    CHECK(pen_mesh_files_load(ctx, fixture_text("crlf.obj", text), &files) == PEN_OK);
    CHECK(files.count == 4 && files.files[0].found &&
          strstr(files.files[0].source, "crlf.obj:15") && !files.files[1].found &&
          strstr(files.files[1].path, "last.mtl") && strstr(files.files[1].source, "crlf.obj:16"));
    pen_mesh_files_free(&files);
    CHECK_ERROR(ctx, pen_mesh_files_load(ctx, fixture_path("absent.obj"), &files), PEN_ERROR_IO,
                "absent.obj");
}

static void check_edges(const char *obj, long open, long nonmanifold, long degenerate) {
    pen_mesh m;
    CHECK_MSG(pen_mesh_load(ctx, fixture_text("edges.obj", obj), &m) == PEN_OK, "%s",
              pen_context_error(ctx));
    pen_mesh_edges e;
    CHECK(pen_mesh_edges_count(ctx, &m, &e) == PEN_OK);
    CHECK_MSG(e.open_edges == open && e.nonmanifold_edges == nonmanifold &&
                  e.degenerate_triangles == degenerate,
              "open %ld nonmanifold %ld degenerate %ld", e.open_edges, e.nonmanifold_edges,
              e.degenerate_triangles);
    pen_mesh_free(&m);
}

static void test_edges(void) {
    check_edges(BOX, 0, 0, 0);
    /* One quad less: its four sides are open. */
    char text[1024];
    snprintf(text, sizeof text, "%.*s", (int)(strrchr(BOX, 'f') - BOX), BOX);
    check_edges(text, 4, 0, 0);
    /* A tetrahedron whose faces have vertices of their own: welded by position, closed. */
    check_edges("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 0\nv 0 1 0\nv 0 0 1\n"
                "v 0 0 0\nv 0 0 1\nv 1 0 0\nv 1 0 0\nv 0 0 1\nv 0 1 0\n"
                "f 1 3 2\nf 4 6 5\nf 7 9 8\nf 10 12 11\n",
                0, 0, 0);
    /* Three triangles on one edge, and a degenerate one. */
    check_edges(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\nf 1 1 2\n", 6, 1,
        1);
}

RUN_TESTS(TEST(test_on_ground_units_centre), TEST(test_frame), TEST(test_errors), TEST(test_check),
          TEST(test_mesh_files), TEST(test_edges))
