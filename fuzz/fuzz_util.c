/* The shared pieces of the fuzz harnesses (fuzz.h): context, scratch folder and its assets,
 * and the invariant checks of accepted results. */
#define _POSIX_C_SOURCE 200809L
#include "fuzz.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static pen_context *ctx_;
static char dir_[512];
static char input_[600];

void fuzz_fail(const char *what) {
    fprintf(stderr, "fuzz: %s\n", what);
    abort();
}

pen_context *fuzz_context(void) {
    if (!ctx_) {
        ctx_ = pen_context_create();
        if (!ctx_) fuzz_fail("cannot create a context");
        pen_context_set_threads(ctx_, 1);
    }
    pen_context_clear_error(ctx_);
    return ctx_;
}

const char *fuzz_message(void) {
    return ctx_ ? pen_context_error(ctx_) : "";
}

/* ---- Scratch folder and assets ---------------------------------------------------------- */

static const char *const asset_names[] = {
    "tri.obj",    "tri.ply",   "spheres.json", "tex.png",    "env.hdr",   "env.exr",
    "target.exr", "two.mtl",   "two.obj",      "input.obj",  "input.ply", "input.png",
    "input.hdr",  "input.exr", "input.jpg",    "input.json", "input.bin", NULL};

static void remove_dir(void) {
    char path[700];
    for (int i = 0; asset_names[i]; ++i) {
        snprintf(path, sizeof path, "%s/%s", dir_, asset_names[i]);
        unlink(path);
    }
    rmdir(dir_);
}

static void write_text(const char *name, const char *text) {
    char path[700];
    snprintf(path, sizeof path, "%s/%s", dir_, name);
    FILE *f = fopen(path, "wb");
    if (!f || fputs(text, f) < 0 || fclose(f) != 0) fuzz_fail("cannot write an asset");
}

/* A w x h image whose values vary smoothly (positive, as a map or albedo would be). */
static void write_image(const char *name, int w, int h) {
    pen_context *ctx = fuzz_context();
    pen_image im;
    if (pen_image_create(ctx, w, h, 3, &im)) fuzz_fail(pen_context_error(ctx));
    for (int i = 0; i < w * h * 3; ++i)
        im.data[i] = 0.2f + 0.6f * (float)((i * 7) % 11) / 10.0f;
    char path[700];
    snprintf(path, sizeof path, "%s/%s", dir_, name);
    pen_status s = pen_image_save(ctx, path, &im);
    pen_image_free(&im);
    if (s) fuzz_fail(pen_context_error(ctx));
}

const char *fuzz_dir(void) {
    if (dir_[0]) return dir_;
    const char *tmp = getenv("TMPDIR");
    snprintf(dir_, sizeof dir_, "%s/pen-fuzz-XXXXXX", tmp && tmp[0] ? tmp : "/tmp");
    if (!mkdtemp(dir_)) fuzz_fail("cannot create the scratch folder");
    atexit(remove_dir);
    write_text("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
                          "f 1/1 3/3 2/2\nf 1/1 2/2 4/3\nf 1/1 4/3 3/2\nf 2/1 3/2 4/3\n");
    write_text("tri.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"
                          "property float y\nproperty float z\nelement face 4\n"
                          "property list uchar int vertex_indices\nend_header\n"
                          "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n");
    write_text("spheres.json", "{\"spheres\": [{\"center\": [0.2, 0.2, 0.2], \"radius\": 0.2},"
                               " {\"center\": [0.5, 0.1, 0.1], \"radius\": 0.1}]}\n");
    /* Materials: a fuzzed OBJ with `mtllib two.mtl` and `usemtl red|blue|tiled` reaches the
     * per-face materials (and, through fuzz_mesh, the baker); two.obj brings them to scenes. */
    write_text("two.mtl", "newmtl red\nKd 0.8 0.1 0.1\nmap_Kd tex.png\n"
                          "newmtl blue\nKd 0.1 0.2 0.8\n"
                          "newmtl tiled\nmap_Kd -s 2 2 1 tex.png\n");
    write_text("two.obj", "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n"
                          "v 2 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 2.5 -1\n"
                          "usemtl red\nf 1/1 2/2 3/3 4/4\nusemtl blue\nf -5/-5 -2/-4 -1/-3 -4/-2\n"
                          "usemtl tiled\nf 1/5 3/3 4/4\n");
    write_image("tex.png", 4, 4);
    write_image("env.hdr", 8, 4);
    write_image("env.exr", 8, 4);
    write_image("target.exr", 8, 8);
    return dir_;
}

const char *fuzz_write(const uint8_t *data, size_t size, const char *ext) {
    snprintf(input_, sizeof input_, "%s/input.%s", fuzz_dir(), ext);
    FILE *f = fopen(input_, "wb");
    if (!f || (size && fwrite(data, 1, size, f) != size) || fclose(f) != 0)
        fuzz_fail("cannot write the input file");
    return input_;
}

char *fuzz_text(const uint8_t *data, size_t size) {
    char *text = malloc(size + 1);
    if (!text) fuzz_fail("out of memory");
    if (size) memcpy(text, data, size);
    text[size] = '\0';
    return text;
}

/* ---- Invariants of accepted results ----------------------------------------------------- */

void fuzz_check_floats(const float *v, size_t n, const char *what) {
    if (n && !v) fuzz_fail(what);
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) fuzz_fail(what);
}

static void check_indices(const uint32_t *idx, int triangles, int count, const char *what) {
    if (!idx) fuzz_fail(what);
    for (size_t i = 0; i < 3 * (size_t)triangles; ++i)
        if (idx[i] >= (uint32_t)count) fuzz_fail(what);
}

void fuzz_check_mesh(const pen_mesh *m) {
    if (m->vertex_count < 0 || m->triangle_count < 0 || m->uv_count < 0 || m->normal_count < 0)
        fuzz_fail("mesh: negative count");
    fuzz_check_floats(m->positions, 3 * (size_t)m->vertex_count, "mesh: non-finite position");
    fuzz_check_floats(m->uvs, 2 * (size_t)m->uv_count, "mesh: non-finite texture coordinate");
    fuzz_check_floats(m->normals, 3 * (size_t)m->normal_count, "mesh: non-finite normal");
    check_indices(m->indices, m->triangle_count, m->vertex_count, "mesh: vertex index");
    if (m->uv_count) check_indices(m->uv_indices, m->triangle_count, m->uv_count, "mesh: uv index");
    if (m->normal_count)
        check_indices(m->normal_indices, m->triangle_count, m->normal_count, "mesh: normal index");
    if (m->material_count < 0 ||
        (m->material_count > 0 && (!m->materials || !m->triangle_materials)))
        fuzz_fail("mesh: material arrays");
    for (int i = 0; i < m->material_count; ++i) {
        const pen_mesh_material *mt = &m->materials[i];
        if (!mt->name) fuzz_fail("mesh: material without a name");
        for (int k = 0; mt->has_kd && k < 3; ++k)
            if (!(mt->kd[k] >= 0.0f && mt->kd[k] <= 1.0f)) fuzz_fail("mesh: Kd outside [0, 1]");
        if (mt->texture_path && !mt->texture_source) fuzz_fail("mesh: map_Kd without its source");
    }
    for (int t = 0; m->material_count > 0 && t < m->triangle_count; ++t)
        if (m->triangle_materials[t] < -1 || m->triangle_materials[t] >= m->material_count)
            fuzz_fail("mesh: material index");
    if (m->colors) {
        fuzz_check_floats(m->colors, 3 * (size_t)m->vertex_count, "mesh: non-finite colour");
        for (size_t i = 0; i < 3 * (size_t)m->vertex_count; ++i)
            if (m->colors[i] < 0.0f || m->colors[i] > 1.0f)
                fuzz_fail("mesh: colour outside [0, 1]");
    }
}

void fuzz_check_image(const pen_image *im) {
    if (im->width < 1 || im->height < 1 || im->width > PEN_IMAGE_MAX_DIM ||
        im->height > PEN_IMAGE_MAX_DIM || im->channels != 3)
        fuzz_fail("image: size or channels out of range");
    fuzz_check_floats(im->data, (size_t)im->width * (size_t)im->height * 3,
                      "image: non-finite pixel");
}

void fuzz_check_spheres(const pen_spheres *sp) {
    if (sp->count < 0) fuzz_fail("spheres: negative count");
    fuzz_check_floats(sp->data, 4 * (size_t)sp->count, "spheres: non-finite value");
    for (int i = 0; i < sp->count; ++i)
        if (!(sp->data[4 * i + 3] > 0.0f)) fuzz_fail("spheres: radius not positive");
    if (sp->weight) {
        fuzz_check_floats(sp->weight, (size_t)sp->count, "spheres: non-finite weight");
        for (int i = 0; i < sp->count; ++i)
            if (sp->weight[i] < 0.0f) fuzz_fail("spheres: negative weight");
    }
}

void fuzz_check_scene(const pen_scene *sc) {
    const pen_camera *c = &sc->camera;
    if (c->width < 1 || c->height < 1) fuzz_fail("scene: camera size");
    fuzz_check_floats(&c->fov_y_deg, 1, "scene: camera.fov_y_deg");
    fuzz_check_floats(c->eye, 3, "scene: camera.eye");
    fuzz_check_floats(c->target, 3, "scene: camera.target");
    fuzz_check_floats(c->up, 3, "scene: camera.up");
    if (sc->sh_bands < 1 || sc->sh_bands * sc->sh_bands > PEN_SH_MAX_COEFFS)
        fuzz_fail("scene: sh_bands");
    fuzz_check_floats(&sc->lighting.sh[0][0], 3 * (size_t)(sc->sh_bands * sc->sh_bands),
                      "scene: lighting.sh");
    fuzz_check_floats(&sc->lighting.scale, 1, "scene: lighting.scale");
    fuzz_check_floats(&sc->lighting.rotation_y_deg, 1, "scene: lighting.rotation_y_deg");
    if (sc->lighting.envmap.data) fuzz_check_image(&sc->lighting.envmap);
    fuzz_check_floats(&sc->shadow.epsilon, 1, "scene: shadow.epsilon");
    if (sc->object_count < 0 || (sc->object_count > 0 && !sc->objects))
        fuzz_fail("scene: objects");
    for (int i = 0; i < sc->object_count; ++i) {
        const pen_object *o = &sc->objects[i];
        fuzz_check_mesh(&o->mesh);
        if (o->texture.data) fuzz_check_image(&o->texture);
        fuzz_check_floats(o->albedo, 3, "scene: object albedo");
        fuzz_check_spheres(&o->spheres);
        fuzz_check_floats(o->pose.rotation_axis_angle_deg, 3, "scene: pose rotation");
        fuzz_check_floats(o->pose.translation, 3, "scene: pose translation");
        fuzz_check_floats(&o->pose.scale, 1, "scene: pose scale");
    }
    fuzz_check_floats(&sc->ground.height, 1, "scene: ground.height");
    fuzz_check_floats(sc->ground.albedo, 3, "scene: ground.albedo");
    fuzz_check_floats(&sc->ground.half_size, 1, "scene: ground.half_size");
    fuzz_check_floats(sc->background, 3, "scene: background");
}

/* ---- Images --------------------------------------------------------------------------------- */

int fuzz_image(const uint8_t *data, size_t size, const char *ext) {
    const char *path = fuzz_write(data, size, ext);
    pen_context *ctx = fuzz_context();
    for (unsigned flags = 0; flags <= PEN_IMAGE_LOAD_RAW; ++flags) {
        pen_image im;
        if (pen_image_load_ex(ctx, path, flags, &im) == PEN_OK) {
            fuzz_check_image(&im);
            pen_image_free(&im);
        } else if (im.data) {
            fuzz_fail("image: refused but not zeroed");
        }
        if (strcmp(ext, "png") != 0) break; /* the raw flag changes PNG decoding only */
    }
    return 0;
}

/* ---- Meshes --------------------------------------------------------------------------------- */

/* Bakes an accepted mesh's materials or colours (every map_Kd stands for one fixed 3 x 2
 * texture, so no file is read) and checks the atlas and the rewritten UVs. */
static void fuzz_bake(pen_mesh *mesh) {
    if (pen_mesh_albedo_plan(mesh, NULL) != PEN_MESH_ALBEDO_BAKE) return;
    static float texels[18] = {0.1f, 0.2f, 0.3f, 0.9f, 0.8f, 0.7f, 0.5f,  0.5f, 0.5f,
                               0.0f, 1.0f, 0.0f, 1.0f, 0.0f, 1.0f, 0.25f, 0.5f, 0.75f};
    pen_image *tex = NULL;
    if (mesh->material_count > 0) {
        tex = calloc((size_t)mesh->material_count, sizeof *tex);
        if (!tex) fuzz_fail("out of memory");
        for (int i = 0; i < mesh->material_count; ++i)
            if (mesh->materials[i].texture_path) tex[i] = (pen_image){3, 2, 3, texels};
    }
    const float def[3] = {0.8f, 0.8f, 0.8f};
    pen_image atlas;
    pen_context *ctx = fuzz_context();
    if (pen_mesh_bake_albedo(ctx, mesh, tex, def, &atlas) == PEN_OK) {
        fuzz_check_image(&atlas);
        fuzz_check_mesh(mesh);
        if (mesh->uv_count != 3 * mesh->triangle_count) fuzz_fail("bake: UV count");
        fuzz_check_floats(mesh->uvs, 2 * (size_t)mesh->uv_count, "bake: UVs");
        pen_image_free(&atlas);
    } else if (atlas.data) {
        fuzz_fail("bake: refused but not zeroed");
    }
    free(tex);
}

int fuzz_mesh(const uint8_t *data, size_t size, const char *ext,
              pen_status (*load)(pen_context *, const char *, pen_mesh *)) {
    const char *path = fuzz_write(data, size, ext);
    pen_mesh mesh;
    if (load(fuzz_context(), path, &mesh) == PEN_OK) {
        fuzz_check_mesh(&mesh);
        fuzz_bake(&mesh);
        pen_mesh_free(&mesh);
    } else if (mesh.positions || mesh.indices) {
        fuzz_fail("mesh: refused but not zeroed");
    }
    return 0;
}
