/* Mesh files: the bundled OBJs, OBJ and PLY features, round trips, and malformed inputs that
 * must fail with a message naming the file and the line or byte. */
#include "io_fixtures.h"

#include <stdint.h>

#define ctx fixture_ctx()

static const char *data_path(const char *name) {
    static char buf[4][512];
    static int next = 0;
    char *b = buf[next++ & 3];
    snprintf(b, 512, "%s/data/meshes/%s", PEN_SOURCE_DIR, name);
    return b;
}

/* ---- Bundled meshes -------------------------------------------------------------------------- */

static void test_bundled(void) {
    pen_mesh m;
    CHECK(pen_mesh_load(ctx, data_path("spot_triangulated.obj"), &m) == PEN_OK);
    CHECK(m.vertex_count == 2930 && m.triangle_count == 5856);
    CHECK(m.uv_count > 0 && m.uv_indices && m.normal_count == 0 && !m.normals);
    CHECK(m.texture_path == NULL);
    CHECK(pen_mesh_validate(ctx, &m) == PEN_OK);
    float lo[3], hi[3];
    pen_mesh_bounds(&m, lo, hi);
    for (int k = 0; k < 3; ++k)
        CHECK(lo[k] < hi[k] && hi[k] - lo[k] < 10.0f);
    pen_mesh_free(&m);
    CHECK(m.positions == NULL && m.vertex_count == 0);

    CHECK(pen_mesh_load(ctx, data_path("bob_tri.obj"), &m) == PEN_OK);
    CHECK(m.vertex_count == 5344 && m.triangle_count == 10688);
    CHECK(m.uv_count > 0 && m.normal_count > 0);
    CHECK(m.texture_path && strstr(m.texture_path, "data/meshes/bob_diffuse.png"));
    CHECK(m.texture_path && fixture_exists(m.texture_path));
    CHECK(pen_mesh_validate(ctx, &m) == PEN_OK);
    pen_mesh_free(&m);

    CHECK(pen_mesh_load(ctx, data_path("blub.obj"), &m) == PEN_OK);
    CHECK(m.vertex_count == 945 && m.triangle_count == 1886);
    CHECK(m.uv_count == 0 && m.normal_count > 0);
    pen_mesh_free(&m);
    pen_mesh_free(NULL);
}

/* ---- OBJ features ---------------------------------------------------------------------------- */

static void test_obj_features(void) {
    /* A quad and a pentagon (fans), negative indices, comments, unknown statements, CRLF. */
    const char *p = fixture_text("feat.obj", "# comment\r\n"
                                             "o thing\r\n"
                                             "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0 1.0\r\n"
                                             "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                                             "vn 0 0 1\n"
                                             "s off\n"
                                             "bsdf pbr\n"
                                             "f 1/1/1 2/2/1 3/3/1 4/4/1\n"
                                             "v 2 0 0\n"
                                             "f -5/-4/-1 -4/-3/-1 -1/-2/-1 -3/-1/-1 -2/-1/1\n");
    pen_mesh m;
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.vertex_count == 5 && m.triangle_count == 2 + 3);
    CHECK(m.uv_count == 4 && m.normal_count == 1);
    uint32_t want[] = {0, 1, 2, 0, 2, 3, 0, 1, 4, 0, 4, 2, 0, 2, 3};
    for (int i = 0; i < 15; ++i)
        CHECK(m.indices[i] == want[i]);
    uint32_t want_uv[] = {0, 1, 2, 0, 2, 3, 0, 1, 2, 0, 2, 3, 0, 3, 3};
    for (int i = 0; i < 15; ++i)
        CHECK(m.uv_indices[i] == want_uv[i]);
    for (int i = 0; i < 15; ++i)
        CHECK(m.normal_indices[i] == 0);
    CHECK(m.positions[3 * 4] == 2.0f);
    pen_mesh_free(&m);

    /* v//vn, and positive references to vertices defined later in the file. */
    p = fixture_text("late.obj", "vn 0 1 0\nf 1//1 2//1 3//1\nv 0 0 0\nv 1 0 0\nv 0 0 1\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.triangle_count == 1 && m.uv_count == 0 && m.normal_count == 1);
    pen_mesh_free(&m);

    /* Material in a sub-folder, map_Kd with options, first textured material used wins; an
     * unused vt set is dropped. */
    mkdir(fixture_path("mat"), 0755);
    fixture_text("mat/lib.mtl",
                 "newmtl plain\nKd 1 0 0\n"
                 "newmtl wood\nKs 0.5 0.5 0.5\nmap_Kd -s 1 1 1 -clamp on tex/wood.png\n"
                 "newmtl other\nmap_Kd other.png\n");
    p = fixture_text("mat.obj",
                     "mtllib mat/lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n"
                     "usemtl plain\nf 1 2 3\nusemtl wood\nf 3 2 1\nusemtl other\nf 1 3 2\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.uv_count == 0 && m.uvs == NULL);
    CHECK(m.texture_path && strcmp(m.texture_path, fixture_path("mat/tex/wood.png")) == 0);
    pen_mesh_free(&m);

    /* A missing .mtl is not an error: no texture. */
    p = fixture_text("nomtl.obj",
                     "mtllib missing.mtl\nusemtl x\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    CHECK(m.texture_path == NULL);
    pen_mesh_free(&m);
}

static int same_mesh(const pen_mesh *a, const pen_mesh *b) {
    if (a->vertex_count != b->vertex_count || a->triangle_count != b->triangle_count ||
        a->uv_count != b->uv_count || a->normal_count != b->normal_count)
        return 0;
    size_t t = 3 * (size_t)a->triangle_count;
    int ok = memcmp(a->positions, b->positions, 3 * (size_t)a->vertex_count * sizeof(float)) == 0 &&
             memcmp(a->indices, b->indices, t * sizeof(uint32_t)) == 0;
    if (ok && a->uv_count)
        ok = memcmp(a->uvs, b->uvs, 2 * (size_t)a->uv_count * sizeof(float)) == 0 &&
             memcmp(a->uv_indices, b->uv_indices, t * sizeof(uint32_t)) == 0;
    if (ok && a->normal_count)
        ok = memcmp(a->normals, b->normals, 3 * (size_t)a->normal_count * sizeof(float)) == 0 &&
             memcmp(a->normal_indices, b->normal_indices, t * sizeof(uint32_t)) == 0;
    return ok;
}

static void test_obj_round_trip(void) {
    const char *names[] = {"bob_tri.obj", "blub.obj", "spot_triangulated.obj"};
    for (int i = 0; i < 3; ++i) {
        pen_mesh a, b;
        CHECK(pen_mesh_load(ctx, data_path(names[i]), &a) == PEN_OK);
        const char *out = fixture_path("round.obj");
        CHECK(pen_mesh_save(ctx, out, &a) == PEN_OK);
        CHECK(pen_mesh_load(ctx, out, &b) == PEN_OK);
        CHECK_MSG(same_mesh(&a, &b), "%s", names[i]);
        pen_mesh_free(&a);
        pen_mesh_free(&b);
    }
    CHECK(fixture_temp_files() == 0);
    /* Invalid meshes are refused before anything is written. */
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint32_t idx[3] = {0, 1, 3};
    pen_mesh bad = {.vertex_count = 3, .triangle_count = 1, .positions = pos, .indices = idx};
    CHECK_ERROR(ctx, pen_mesh_save(ctx, fixture_path("bad_out.obj"), &bad), PEN_ERROR_ARGUMENT,
                "triangle 0", "index 3");
    CHECK(!fixture_exists(fixture_path("bad_out.obj")));
    CHECK_ERROR(ctx, pen_mesh_save(ctx, fixture_path("x.ply"), &bad), PEN_ERROR_UNSUPPORTED,
                "x.ply");
}

/* ---- PLY ------------------------------------------------------------------------------------- */

/* A binary PLY writer for the tests: appends values in either byte order. */
typedef struct bytes {
    unsigned char d[4096];
    size_t n;
    int big;
} bytes;

static void put(bytes *b, const void *v, size_t size) {
    for (size_t i = 0; i < size; ++i)
        b->d[b->n + i] = ((const unsigned char *)v)[b->big ? size - 1 - i : i];
    b->n += size;
}
static void put_text(bytes *b, const char *s) {
    memcpy(b->d + b->n, s, strlen(s));
    b->n += strlen(s);
}
static void put_f(bytes *b, float v) {
    put(b, &v, 4);
}
static void put_u8(bytes *b, unsigned v) {
    unsigned char c = (unsigned char)v;
    put(b, &c, 1);
}
static void put_i32(bytes *b, int32_t v) {
    put(b, &v, 4);
}

/* The same quad mesh (4 vertices with u, v and normals; a quad face plus an extra element and
 * an extra face property) in ascii and both binary orders. */
static const char *write_quad_ply(const char *name, int format) {
    static const char *formats[] = {"ascii", "binary_little_endian", "binary_big_endian"};
    static const float pos[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0.5f}};
    bytes b = {.n = 0, .big = format == 2};
    char header[1024];
    snprintf(header, sizeof header,
             "ply\nformat %s 1.0\ncomment made by a test\n"
             "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
             "property float nx\nproperty float ny\nproperty float nz\n"
             "property float u\nproperty float v\nproperty uchar red\n"
             "element face 1\nproperty list uchar int vertex_indices\nproperty int flags\n"
             "element edge 1\nproperty list int int verts\nend_header\n",
             formats[format]);
    put_text(&b, header);
    for (int i = 0; i < 4; ++i) {
        if (format == 0) {
            char line[128];
            snprintf(line, sizeof line, "%g %g %g 0 0 1 %g %g 200\n", (double)pos[i][0],
                     (double)pos[i][1], (double)pos[i][2], (double)pos[i][0], (double)pos[i][1]);
            put_text(&b, line);
        } else {
            for (int k = 0; k < 3; ++k)
                put_f(&b, pos[i][k]);
            put_f(&b, 0), put_f(&b, 0), put_f(&b, 1);
            put_f(&b, pos[i][0]), put_f(&b, pos[i][1]);
            put_u8(&b, 200);
        }
    }
    if (format == 0) {
        put_text(&b, "4 0 1 2 3 7\n2 0 2\n");
    } else {
        put_u8(&b, 4);
        for (int i = 0; i < 4; ++i)
            put_i32(&b, i);
        put_i32(&b, 7);
        put_i32(&b, 2), put_i32(&b, 0), put_i32(&b, 2);
    }
    return fixture_write(name, b.d, b.n);
}

static void test_ply(void) {
    pen_mesh m[3];
    const char *names[] = {"q_ascii.ply", "q_le.ply", "q_be.ply"};
    for (int f = 0; f < 3; ++f) {
        CHECK_MSG(pen_mesh_load(ctx, write_quad_ply(names[f], f), &m[f]) == PEN_OK, "%s: %s",
                  names[f], pen_context_error(ctx));
        CHECK(m[f].vertex_count == 4 && m[f].triangle_count == 2);
        CHECK(m[f].uv_count == 4 && m[f].normal_count == 4);
    }
    uint32_t want[] = {0, 1, 2, 0, 2, 3};
    for (int i = 0; i < 6; ++i)
        CHECK(m[0].indices[i] == want[i] && m[0].uv_indices[i] == want[i]);
    CHECK(m[0].positions[11] == 0.5f && m[0].uvs[5] == 1.0f && m[0].normals[2] == 1.0f);
    CHECK(same_mesh(&m[0], &m[1]) && same_mesh(&m[0], &m[2]));
    for (int f = 0; f < 3; ++f)
        pen_mesh_free(&m[f]);

    /* Minimal file: "vertex_index" list with a uint count, no UVs or normals. */
    const char *p =
        fixture_text("min.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                                "property double x\nproperty double y\nproperty double z\n"
                                "element face 1\nproperty list uint uint vertex_index\n"
                                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 2 1 0\n");
    CHECK(pen_mesh_load(ctx, p, &m[0]) == PEN_OK);
    CHECK(m[0].triangle_count == 1 && m[0].uv_count == 0 && m[0].normal_count == 0);
    CHECK(m[0].indices[0] == 2 && m[0].indices[2] == 0);
    pen_mesh_free(&m[0]);
}

/* ---- Malformed inputs ------------------------------------------------------------------------ */

typedef struct bad_case {
    const char *name, *text;
    pen_status status;
    const char *place, *what; /* substrings the message must contain (besides the file name) */
} bad_case;

#define PLY_HEAD                                                                                   \
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"                \
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"

/* A header comment longer than any fixed line buffer (tools write provenance there) is valid. */
static void test_ply_long_comment(void) {
    static char text[8192];
    int n = snprintf(text, sizeof text, "ply\nformat ascii 1.0\ncomment ");
    for (int i = 0; i < 3000; ++i)
        text[n++] = (char)('a' + i % 26);
    snprintf(text + n, sizeof text - (size_t)n,
             "\n  obj_info   %0600d\nelement vertex 3\nproperty float x\nproperty float y\n"
             "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
             "end_header\n0 0 0\n1 0 0\n\n0 1 0  \r\n3 0 1 2\n",
             7);
    pen_mesh m;
    CHECK_MSG(pen_mesh_load(ctx, fixture_text("long_comment.ply", text), &m) == PEN_OK, "%s",
              pen_context_error(ctx));
    CHECK(m.vertex_count == 3 && m.triangle_count == 1 && m.positions[7] == 1.0f);
    pen_mesh_free(&m);
}

static void test_malformed_text(void) {
    static const bad_case cases[] = {
        {"idx.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", PEN_ERROR_PARSE,
         ":4:", "index 9 out of range [1, 3]"},
        {"zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", PEN_ERROR_PARSE, ":4:", "index 0"},
        {"nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", PEN_ERROR_PARSE, ":2:", "finite"},
        {"inf.obj", "v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", PEN_ERROR_PARSE, ":2:", "finite"},
        {"rel.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", PEN_ERROR_PARSE,
         ":3:", "relative vertex index -3"},
        {"vt.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n", PEN_ERROR_PARSE,
         ":5:", "texture coordinate index 2"},
        {"mix.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1 2 3\n", PEN_ERROR_PARSE,
         ":6:", "mixes"},
        {"two.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\n", PEN_ERROR_PARSE,
         ":5:", "2 corners"},
        {"corner.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3x\n", PEN_ERROR_PARSE,
         ":4:", "malformed face corner '3x'"},
        {"slash.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/ 2/ 3/\n", PEN_ERROR_PARSE,
         ":4:", "malformed face corner"},
        {"short.obj", "v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", PEN_ERROR_PARSE,
         ":1:", "expected 3 numbers"},
        {"num.obj", "v 0 0 0\nv 1 0x 0\nv 0 1 0\nf 1 2 3\n", PEN_ERROR_PARSE,
         ":2:", "malformed number '0x'"},
        {"noface.obj", "v 0 0 0\nv 1 0 0\n", PEN_ERROR_PARSE, "noface.obj", "no faces"},
        {"empty.obj", "", PEN_ERROR_PARSE, "empty.obj", "no vertices"},
        {"fmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n", PEN_ERROR_PARSE,
         ":2:", "unknown format"},
        {"magic.ply", "plx\nformat ascii 1.0\nend_header\n", PEN_ERROR_PARSE, ":1:", "not a PLY"},
        {"noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", PEN_ERROR_PARSE, "noend.ply",
         "end_header"},
        {"absurd.ply",
         "ply\nformat ascii 1.0\nelement vertex 4000000000\nproperty float x\nend_header\n",
         PEN_ERROR_PARSE, ":3:", "exceeds the limit"},
        {"big.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 100000000\nproperty float x\n"
         "property float y\nproperty float z\nelement face 1\nproperty list uchar int "
         "vertex_indices\nend_header\n0000",
         PEN_ERROR_PARSE, "byte", "declares 100000000 rows"},
        {"trunc.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1 0\n3 0 1", PEN_ERROR_PARSE, ":13:", "truncated"},
        {"rows.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1", PEN_ERROR_PARSE,
         ":10:", "truncated: element 'vertex' declares 3 rows"},
        {"range.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", PEN_ERROR_PARSE,
         ":13:", "vertex index 3 out of range [0, 3)"},
        {"frac.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n", PEN_ERROR_PARSE,
         ":13:", "not a valid int"},
        {"count.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1 0\n2 0 1\n", PEN_ERROR_PARSE,
         ":13:", "2 vertices"},
        {"nanply.ply", PLY_HEAD "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", PEN_ERROR_PARSE,
         ":11:", "vertex 1: y is not a finite"},
        {"noxyz.ply",
         "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nelement face 1\n"
         "property list uchar int vertex_indices\nend_header\n0\n3 0 0 0\n",
         PEN_ERROR_PARSE, "noxyz.ply", "lacks x, y or z"},
        {"ftype.ply",
         "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty list float int "
         "v\nend_header\n",
         PEN_ERROR_PARSE, ":5:", "count type must be an integer"},
        {"mesh.stl", "solid x\n", PEN_ERROR_UNSUPPORTED, "mesh.stl", "unknown mesh format"},
        /* -2^63: the relative-index check must not negate it (UBSan). */
        {"min.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n", PEN_ERROR_PARSE,
         ":4:", "reaches before the first one"},
        /* A row short of one value: every later vertex would shift by one. */
        {"short_row.ply", PLY_HEAD "0 0\n1 0 0\n0 1 0\n3 0 1 2\n", PEN_ERROR_PARSE,
         ":10:", "vertex 0: the line ends after 2 values"},
        {"long_row.ply", PLY_HEAD "0 0 0\n1 0 0 7\n0 1 0\n3 0 1 2\n", PEN_ERROR_PARSE,
         ":11:", "vertex 1: more values on the line"},
        {"face_row.ply", PLY_HEAD "0 0 0\n1 0 0\n0 1 0\n3 0 1\n2\n", PEN_ERROR_PARSE,
         ":13:", "face 0: the line ends after 3 values"},
        {"long_header.ply",
         "ply\nformat ascii 1.0\nelement vertex 3 "
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111"
         "1111111111111111111111111111111111111111111111111111111111111111111111111111111111111111\n"
         "end_header\n",
         PEN_ERROR_PARSE, ":3:", "header line of 1073 bytes"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        const bad_case *c = &cases[i];
        const char *path = fixture_text(c->name, c->text);
        pen_mesh m;
        memset(&m, 0xff, sizeof m);
        pen_status s = pen_mesh_load(ctx, path, &m);
        CHECK_ERROR(ctx, s, c->status, c->name, c->place, c->what);
        CHECK(m.positions == NULL && m.indices == NULL && m.vertex_count == 0);
    }
    pen_mesh m;
    CHECK_ERROR(ctx, pen_mesh_load(ctx, fixture_path("does_not_exist.obj"), &m), PEN_ERROR_IO,
                "does_not_exist.obj", "cannot open");
}

static void test_malformed_binary(void) {
    /* A binary PLY cut inside the face list, and one with a NaN coordinate. */
    bytes b = {.n = 0, .big = 0};
    put_text(&b, "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                 "property float y\nproperty float z\nelement face 1\n"
                 "property list uchar int vertex_indices\nend_header\n");
    size_t data_start = b.n;
    for (int i = 0; i < 9; ++i)
        put_f(&b, i == 4 ? NAN : (float)i);
    put_u8(&b, 3);
    put_i32(&b, 0), put_i32(&b, 1), put_i32(&b, 2);
    pen_mesh m;
    const char *p = fixture_write("nan_bin.ply", b.d, b.n);
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "nan_bin.ply", "byte",
                "vertex 1: y is not a finite");
    memcpy(b.d + data_start + 16, &(float){4.0f}, 4);
    p = fixture_write("ok_bin.ply", b.d, b.n);
    CHECK(pen_mesh_load(ctx, p, &m) == PEN_OK);
    pen_mesh_free(&m);
    p = fixture_write("cut_bin.ply", b.d, b.n - 3);
    char where[32];
    snprintf(where, sizeof where, "byte %zu", data_start + 37); /* the indices start there */
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "cut_bin.ply", where, "truncated");
    /* A list count larger than the bytes left. */
    b.d[data_start + 36] = 200;
    p = fixture_write("list_bin.ply", b.d, b.n);
    CHECK_ERROR(ctx, pen_mesh_load(ctx, p, &m), PEN_ERROR_PARSE, "list_bin.ply", "truncated");
}

/* Random byte edits and truncations of valid files: every load either succeeds with a valid mesh
 * or fails with a message; under the sanitizers this also checks every read stays in bounds. */
static void test_mutations(void) {
    const char *sources[] = {write_quad_ply("m_ascii.ply", 0), write_quad_ply("m_le.ply", 1),
                             write_quad_ply("m_be.ply", 2),
                             fixture_text("m.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\n"
                                                   "vt 1 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/2/1 4/1/1\n"
                                                   "f -1//1 -2//1 -3//1\n")};
    static const char charset[] = "0123456789 -+./\nefvtnx\xff\x00";
    unsigned long long seed = 99;
    int rounds = check_quick_() ? 60 : 400, loaded = 0, failed = 0;
    for (int k = 0; k < 4; ++k) {
        FILE *f = fopen(sources[k], "rb");
        unsigned char orig[4096];
        size_t n = f ? fread(orig, 1, sizeof orig, f) : 0;
        if (f) fclose(f);
        for (int r = 0; r < rounds; ++r) {
            unsigned char buf[4096];
            memcpy(buf, orig, n);
            size_t len = n;
            int edits = 1 + (int)(4 * check_rand_(&seed));
            for (int e = 0; e < edits; ++e) {
                size_t at = (size_t)(check_rand_(&seed) * (double)len);
                if (check_rand_(&seed) < 0.5)
                    buf[at] =
                        (unsigned char)charset[(int)(check_rand_(&seed) * (sizeof charset - 1))];
                else
                    buf[at] = (unsigned char)(256 * check_rand_(&seed));
            }
            if (check_rand_(&seed) < 0.3) len = (size_t)(check_rand_(&seed) * (double)len);
            const char *p = fixture_write(k == 3 ? "mut.obj" : "mut.ply", buf, len);
            pen_mesh m;
            pen_status s = pen_mesh_load(ctx, p, &m);
            if (s == PEN_OK) {
                ++loaded;
                CHECK(pen_mesh_validate(ctx, &m) == PEN_OK);
                pen_mesh_free(&m);
            } else {
                ++failed;
                CHECK(strstr(pen_context_error(ctx), "mut.") != NULL);
                CHECK(m.positions == NULL);
                pen_context_clear_error(ctx);
            }
        }
    }
    CHECK(loaded > 0 && failed > 0);
}

RUN_TESTS(TEST(test_bundled), TEST(test_obj_features), TEST(test_obj_round_trip), TEST(test_ply),
          TEST(test_ply_long_comment),
          TEST(test_malformed_text), TEST(test_malformed_binary), TEST(test_mutations))
