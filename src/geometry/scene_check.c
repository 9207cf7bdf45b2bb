/* What to tell a user about a scene before it renders (pen_scene_check) and how closed a mesh is
 * (pen_mesh_edges_count).
 *
 * The library prints nothing: the check returns facts (each object's posed bounds, each disk
 * light's elevation and share of the light) and warnings as lines of text, and the doors decide
 * where they go (`penumbra render` and `optimize` print the warnings on stderr, `penumbra info`
 * prints everything). The warnings are the mistakes a first scene of one's own makes and that
 * would otherwise render without a word: a mesh in centimetres read as metres (huge against the
 * ground, the camera inside it), a material library or texture that did not travel with the OBJ
 * (the mesh loader passes over a missing library, as OBJ viewers do). Bounds come from
 * src/scene/place.c, the same measure the loader stands objects and frames cameras with. */
#include "core/internal.h"
#include "penumbra/fit.h"
#include "penumbra/io.h"
#include "scene/place.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- The report ------------------------------------------------------------------------------ */

typedef struct report_builder {
    pen_context *ctx;
    pen_scene_report *out;
    int cap;
} report_builder;

static pen_status warn(report_builder *b, pen_scene_warning_kind kind, int object, const char *fmt,
                       ...) PEN_PRINTF(4, 5);

static pen_status warn(report_builder *b, pen_scene_warning_kind kind, int object, const char *fmt,
                       ...) {
    pen_scene_report *r = b->out;
    if (r->warning_count == b->cap) {
        const int cap = b->cap ? 2 * b->cap : 4;
        pen_scene_warning *w = realloc(r->warnings, (size_t)cap * sizeof *w);
        if (!w) return pen__error(b->ctx, PEN_ERROR_MEMORY, "check: out of memory");
        r->warnings = w, b->cap = cap;
    }
    pen_scene_warning *w = &r->warnings[r->warning_count++];
    w->kind = kind;
    w->object = object;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(w->message, sizeof w->message, fmt, ap);
    va_end(ap);
    return PEN_OK;
}

/* The file name without its folders, for messages. */
static const char *base_name(const char *path) {
    if (!path) return "in memory";
    const char *slash = strrchr(path, '/');
    return slash ? slash + 1 : path;
}

static double luminance(const float rgb[3]) {
    return 0.2126 * (double)rgb[0] + 0.7152 * (double)rgb[1] + 0.0722 * (double)rgb[2];
}

/* Elevation, azimuth and share of each disk light (pen_light_summary). */
static void summarise_lights(const pen_scene *sc, pen_scene_report *r) {
    const pen_lighting *L = &sc->lighting;
    r->light_count = L->light_count < 0                      ? 0
                     : L->light_count > PEN_SCENE_MAX_LIGHTS ? PEN_SCENE_MAX_LIGHTS
                                                             : L->light_count;
    double light[PEN_SCENE_MAX_LIGHTS], total = fmax(0.0, luminance(L->sh[0]) * sqrt(4.0 * PEN_PI));
    for (int i = 0; i < r->light_count; ++i) {
        const pen_light *l = &L->lights[i];
        const double x = l->direction[0], y = l->direction[1], z = l->direction[2];
        const double n = sqrt(x * x + y * y + z * z);
        pen_light_summary *s = &r->lights[i];
        s->elevation_deg =
            n > 0.0 ? (float)(asin(fmax(-1.0, fmin(1.0, y / n))) * 180.0 / PEN_PI) : 0.0f;
        s->azimuth_deg = (float)(atan2(x, z) * 180.0 / PEN_PI);
        const double b = (double)l->angular_radius_deg * PEN_PI / 180.0;
        light[i] = fmax(0.0, luminance(l->irradiance) * 2.0 / (1.0 + cos(b)));
        total += light[i];
    }
    for (int i = 0; i < r->light_count; ++i)
        r->lights[i].share = total > 0.0 ? (float)(light[i] / total) : 0.0f;
}

/* The eye inside object o's bounds, or inside one of its posed spheres. */
static pen_status check_camera(report_builder *b, const pen_scene *sc, int o, const double lo[3],
                               const double hi[3]) {
    const pen_object *ob = &sc->objects[o];
    const float *e = sc->camera.eye;
    int inside = 1;
    for (int a = 0; a < 3; ++a)
        inside &= (double)e[a] > lo[a] && (double)e[a] < hi[a];
    for (int k = 0; !inside && ob->spheres.data && k < ob->spheres.count; ++k) {
        float c[3];
        pen_pose_apply(&ob->pose, ob->spheres.data + 4 * (size_t)k, c);
        const double r = (double)ob->spheres.data[4 * (size_t)k + 3] * (double)ob->pose.scale;
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a)
            d2 += ((double)e[a] - (double)c[a]) * ((double)e[a] - (double)c[a]);
        inside = d2 < r * r;
    }
    if (!inside) return PEN_OK;
    return warn(b, PEN_SCENE_WARNING_CAMERA_INSIDE, o,
                "the camera's eye (%g, %g, %g) is inside objects[%d] (%s), which spans (%g, %g, "
                "%g) to (%g, %g, %g): the image shows it from inside. Move the eye out, or let "
                "the camera frame the objects: \"camera\": {..., \"frame\": true}",
                (double)e[0], (double)e[1], (double)e[2], o, base_name(ob->mesh_path), lo[0], lo[1],
                lo[2], hi[0], hi[1], hi[2]);
}

/* An object tiny or huge against the ground square. */
static pen_status check_size(report_builder *b, const pen_scene *sc, int o, const double lo[3],
                             const double hi[3]) {
    if (!sc->ground.enabled) return PEN_OK;
    const double side = 2.0 * (double)sc->ground.half_size;
    const double size[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    const double ext = fmax(size[0], fmax(size[1], size[2]));
    const char *name = base_name(sc->objects[o].mesh_path);
    if (ext > side)
        return warn(b, PEN_SCENE_WARNING_OBJECT_HUGE, o,
                    "objects[%d] (%s) is %.3g x %.3g x %.3g but the ground square is %.3g x "
                    "%.3g: %s, or give the ground a larger \"half_size\"",
                    o, name, size[0], size[1], size[2], side, side,
                    ext / 100.0 <= side ? "a mesh in centimetres? give the object \"units\": \"cm\""
                    : ext / 1000.0 <= side
                        ? "a mesh in millimetres? give the object \"units\": \"mm\""
                        : "give the object \"units\" or a pose \"scale\"");
    if (ext < 0.01 * side)
        return warn(b, PEN_SCENE_WARNING_OBJECT_TINY, o,
                    "objects[%d] (%s) is %.3g x %.3g x %.3g, under 1 %% of the ground square "
                    "(%.3g x %.3g): give the object \"units\" or a pose \"scale\", or the ground "
                    "a smaller \"half_size\"",
                    o, name, size[0], size[1], size[2], side, side);
    return PEN_OK;
}

/* The triangles of object o that use material `name` (its last definition, as usemtl takes). */
static long material_use(const pen_mesh *m, const char *name) {
    int k = -1;
    for (int i = 0; name && i < m->material_count; ++i)
        if (m->materials[i].name && strcmp(m->materials[i].name, name) == 0) k = i;
    long n = 0;
    for (int t = 0; k >= 0 && m->triangle_materials && t < m->triangle_count; ++t)
        n += m->triangle_materials[t] == k;
    return n;
}

/* Material libraries and textures the OBJ names that are not there. */
static pen_status check_files(report_builder *b, const pen_scene *sc, int o) {
    const pen_object *ob = &sc->objects[o];
    if (!ob->mesh_path) return PEN_OK;
    pen_mesh_files files;
    pen_status s = pen_mesh_files_load(b->ctx, ob->mesh_path, &files);
    if (s) return pen__error_prefix(b->ctx, s, "check: objects[%d]: ", o);
    const char *name = base_name(ob->mesh_path);
    for (int i = 0; !s && i < files.count; ++i) {
        const pen_mesh_file *f = &files.files[i];
        if (f->found) continue;
        if (f->kind == PEN_MESH_FILE_MTLLIB && ob->texture.data)
            s = warn(b, PEN_SCENE_WARNING_MTLLIB_MISSING, o,
                     "objects[%d] (%s): the material library %s (named at %s) is not found: its "
                     "materials are lost",
                     o, name, f->path, base_name(f->source));
        else if (f->kind == PEN_MESH_FILE_MTLLIB)
            s = warn(b, PEN_SCENE_WARNING_MTLLIB_MISSING, o,
                     "objects[%d] (%s): the material library %s (named at %s) is not found: its "
                     "materials are lost and the object renders with the albedo [%g, %g, %g]",
                     o, name, f->path, base_name(f->source), (double)ob->albedo[0],
                     (double)ob->albedo[1], (double)ob->albedo[2]);
        else
            s = warn(b, PEN_SCENE_WARNING_TEXTURE_MISSING, o,
                     "objects[%d] (%s): the texture %s (map_Kd of material '%s', %s) is not "
                     "found%s",
                     o, name, f->path, f->material ? f->material : "?", base_name(f->source),
                     material_use(&ob->mesh, f->material) > 0
                         ? ": the object's own \"albedo\" or \"albedo_texture\" stands in"
                         : "; no face uses that material");
    }
    pen_mesh_files_free(&files);
    return s;
}

/* An object whose fitted spheres leave a large part of its surface uncovered: its shadow lacks
 * that part (a chair's frame beside its seat). Measured in the mesh's own coordinates. Sets given
 * in the scene or a file are the author's choice (a test's three rough spheres, a set made for
 * another purpose) and are not judged. */
static pen_status check_coverage(report_builder *b, const pen_scene *sc, int o) {
    const pen_object *ob = &sc->objects[o];
    if (ob->fit_spheres <= 0 || ob->spheres.count <= 0 || ob->mesh.triangle_count <= 0)
        return PEN_OK;
    pen_coverage_report c;
    if (pen_spheres_coverage(b->ctx, &ob->mesh, &ob->spheres, &c)) {
        pen_context_clear_error(b->ctx); /* a mesh the fitter refuses: no measure, no warning */
        return PEN_OK;
    }
    if (!(c.uncovered > PEN_SPHERES_COVERAGE_WARN)) return PEN_OK;
    return warn(b, PEN_SCENE_WARNING_SPHERES_UNCOVERED, o,
                "objects[%d] (%s): its %d sphere%s leave%s %.1f%% of the surface uncovered (the "
                "largest part, %.1f%% of the surface, around (%.3g, %.3g, %.3g) in the mesh's "
                "coordinates): its shadow lacks it; %s",
                o, base_name(ob->mesh_path), ob->spheres.count, ob->spheres.count == 1 ? "" : "s",
                ob->spheres.count == 1 ? "s" : "", 100 * c.uncovered,
                100 * c.largest_share, (double)c.largest_centre[0], (double)c.largest_centre[1],
                (double)c.largest_centre[2], "raise \"fit\" in \"spheres\": {\"fit\": N}");
}

pen_status pen_scene_check(pen_context *ctx, const pen_scene *scene, pen_scene_report *out) {
    memset(out, 0, sizeof *out);
    if (!scene || scene->object_count < 0 || (scene->object_count > 0 && !scene->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "check: no scene");
    report_builder b = {ctx, out, 0};
    summarise_lights(scene, out);
    out->object_count = scene->object_count;
    out->bounds = pen__calloc(ctx, (size_t)scene->object_count + 1, 6 * sizeof(float), "check");
    pen_status s = out->bounds ? PEN_OK : PEN_ERROR_MEMORY;
    for (int o = 0; !s && o < scene->object_count; ++o) {
        double lo[3], hi[3];
        pen__object_bounds_d(&scene->objects[o], lo, hi);
        for (int a = 0; a < 3; ++a)
            out->bounds[6 * o + a] = (float)lo[a], out->bounds[6 * o + 3 + a] = (float)hi[a];
        s = check_camera(&b, scene, o, lo, hi);
        if (!s) s = check_size(&b, scene, o, lo, hi);
        if (!s) s = check_files(&b, scene, o);
        if (!s) s = check_coverage(&b, scene, o);
    }
    if (s) pen_scene_report_free(out);
    return s;
}

void pen_scene_report_free(pen_scene_report *report) {
    if (!report) return;
    free(report->bounds);
    free(report->warnings);
    memset(report, 0, sizeof *report);
}

/* ---- How closed a mesh is -------------------------------------------------------------------- */

typedef struct weld_key {
    const float *p;
    uint32_t index;
} weld_key;

static int compare_position(const float *a, const float *b) {
    for (int k = 0; k < 3; ++k)
        if (a[k] != b[k]) return a[k] < b[k] ? -1 : 1;
    return 0;
}

static int by_position(const void *x, const void *y) {
    const weld_key *a = x, *b = y;
    const int c = compare_position(a->p, b->p);
    return c ? c : (a->index < b->index ? -1 : a->index > b->index);
}

static int by_value(const void *x, const void *y) {
    const uint64_t a = *(const uint64_t *)x, b = *(const uint64_t *)y;
    return a < b ? -1 : a > b;
}

pen_status pen_mesh_edges_count(pen_context *ctx, const pen_mesh *mesh, pen_mesh_edges *out) {
    memset(out, 0, sizeof *out);
    pen_status s = pen_mesh_validate(ctx, mesh);
    if (s) return s;
    const size_t nv = (size_t)mesh->vertex_count, nt = (size_t)mesh->triangle_count;
    weld_key *keys = pen__malloc(ctx, nv, sizeof *keys, "edges");
    uint32_t *weld = pen__malloc(ctx, nv, sizeof *weld, "edges");
    uint64_t *edges = pen__malloc(ctx, 3 * nt, sizeof *edges, "edges");
    if (!keys || !weld || !edges) {
        free(keys), free(weld), free(edges);
        return PEN_ERROR_MEMORY;
    }
    /* Each vertex's representative: the first of the vertices at its position. */
    for (size_t i = 0; i < nv; ++i)
        keys[i] = (weld_key){mesh->positions + 3 * i, (uint32_t)i};
    qsort(keys, nv, sizeof *keys, by_position);
    for (size_t i = 0; i < nv; ++i)
        weld[keys[i].index] = i > 0 && compare_position(keys[i].p, keys[i - 1].p) == 0
                                  ? weld[keys[i - 1].index]
                                  : keys[i].index;
    size_t ne = 0;
    for (size_t t = 0; t < nt; ++t) {
        uint32_t v[3];
        for (int k = 0; k < 3; ++k)
            v[k] = weld[mesh->indices[3 * t + (size_t)k]];
        if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) {
            ++out->degenerate_triangles;
            continue;
        }
        for (int k = 0; k < 3; ++k) {
            const uint32_t a = v[k], c = v[(k + 1) % 3];
            edges[ne++] = a < c ? ((uint64_t)a << 32 | c) : ((uint64_t)c << 32 | a);
        }
    }
    qsort(edges, ne, sizeof *edges, by_value);
    for (size_t i = 0; i < ne;) {
        size_t j = i;
        while (j < ne && edges[j] == edges[i])
            ++j;
        ++out->edges;
        if (j - i == 1) ++out->open_edges;
        if (j - i > 2) ++out->nonmanifold_edges;
        i = j;
    }
    free(keys), free(weld), free(edges);
    return PEN_OK;
}
