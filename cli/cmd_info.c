/* penumbra info: what a mesh or a scene holds, before one renders it. For a mesh (OBJ, PLY): its
 * counts, bounds and size, the units its size suggests, whether it is closed (the sphere fit
 * needs it) and how many of its shells face inwards (they lose the self transfer), its materials
 * and the files it names, found or not (pen_mesh_files_load). For a scene JSON: the camera, each
 * object with its bounds after its pose and where it stands against the ground, the ground, the
 * lighting with the disk lights found in the map, and the warnings `render` prints
 * (pen_scene_check). Text for people, --json for programs.
 *
 * Also the two printers `render` and `optimize` share: the lights line by line, the warnings on
 * stderr (commands.h). */
#include "commands.h"

#include "penumbra/fit.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

static const char *const CMD = "info";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra info MESH.(obj|ply) | SCENE.json [--json]\n\n"
            "What a mesh or a scene holds, before rendering it.\n"
            "A mesh: vertex and triangle counts, bounds (min, max, size, centre), the units its\n"
            "size suggests, whether it is closed (every edge in two triangles: the sphere fit\n"
            "needs it) and how many of its shells face inwards (wound clockwise seen from\n"
            "outside: they render without their own shadows), its materials and the files it\n"
            "names (material libraries, textures), found or missing.\n"
            "A scene: the camera, each object's bounds after its pose and its height over the\n"
            "ground, the ground, the lighting with the disk lights found in the map (direction,\n"
            "elevation, angular radius, share of the light), and the warnings `render` prints.\n\n"
            "Options:\n"
            "  --json              one JSON object on stdout instead of text\n");
}

/* ---- Shared with render and optimize -------------------------------------------------------- */

void pen_cli_print_lights(FILE *f, const pen_scene *sc, const pen_scene_report *report,
                          const char *indent) {
    const pen_lighting *L = &sc->lighting;
    const char *map = L->envmap_path ? strrchr(L->envmap_path, '/') : NULL;
    map = map ? map + 1 : L->envmap_path;
    if (report->light_count == L->lights_added && L->lights_mode == PEN_LIGHTS_AUTO &&
        L->envmap.data)
        fprintf(f, "%sno light found in %s%s\n", indent, map,
                L->lights_added ? "" : ": SH lighting only");
    /* With lights AUTO, the first ones were found in the map and the last lights_added given. */
    const int found = L->lights_mode == PEN_LIGHTS_AUTO ? L->light_count - L->lights_added : 0;
    for (int i = 0; i < report->light_count; ++i) {
        const pen_light *l = &L->lights[i];
        const pen_light_summary *s = &report->lights[i];
        fprintf(f,
                "%slight %d (%s%s): elevation %.1f deg, azimuth %.1f deg, angular radius %.2f "
                "deg, direction (%.3f, %.3f, %.3f), irradiance (%.4g, %.4g, %.4g), %.0f %% of "
                "the light\n",
                indent, i, i < found ? "found in " : "given", i < found && map ? map : "",
                (double)s->elevation_deg, (double)s->azimuth_deg, (double)l->angular_radius_deg,
                (double)l->direction[0], (double)l->direction[1], (double)l->direction[2],
                (double)l->irradiance[0], (double)l->irradiance[1], (double)l->irradiance[2],
                100.0 * (double)s->share);
    }
}

void pen_cli_print_warnings(const char *cmd, const pen_scene_report *report) {
    for (int i = 0; i < report->warning_count; ++i)
        fprintf(stderr, "penumbra %s: warning: %s\n", cmd, report->warnings[i].message);
}

/* ---- Output helpers ----------------------------------------------------------------------------
 */

/* A JSON string (quotes and escapes). */
static void json_string(const char *s) {
    if (!s) {
        fputs("null", stdout);
        return;
    }
    putchar('"');
    for (const unsigned char *p = (const unsigned char *)s; *p; ++p) {
        if (*p == '"' || *p == '\\')
            printf("\\%c", *p);
        else if (*p < 0x20)
            printf("\\u%04x", *p);
        else
            putchar(*p);
    }
    putchar('"');
}

/* A JSON number ("null" when not finite). */
static void json_number(double v) {
    if (isfinite(v))
        printf("%.9g", v);
    else
        fputs("null", stdout);
}

static void json_vec(const double *v, int n) {
    putchar('[');
    for (int i = 0; i < n; ++i) {
        if (i) fputs(", ", stdout);
        json_number(v[i]);
    }
    putchar(']');
}

static void json_vecf(const float *v, int n) {
    double d[4];
    for (int i = 0; i < n; ++i)
        d[i] = (double)v[i];
    json_vec(d, n);
}

static const char *base_name(const char *path) {
    const char *slash = path ? strrchr(path, '/') : NULL;
    return slash ? slash + 1 : path;
}

/* Bounds, size and centre as one JSON object. */
static void json_bounds(const double lo[3], const double hi[3]) {
    const double size[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    const double centre[3] = {0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
    fputs("{\"min\": ", stdout), json_vec(lo, 3);
    fputs(", \"max\": ", stdout), json_vec(hi, 3);
    fputs(", \"size\": ", stdout), json_vec(size, 3);
    fputs(", \"centre\": ", stdout), json_vec(centre, 3);
    putchar('}');
}

static void text_bounds(const char *indent, const double lo[3], const double hi[3]) {
    printf("%sbounds: (%.4g, %.4g, %.4g) to (%.4g, %.4g, %.4g)\n", indent, lo[0], lo[1], lo[2],
           hi[0], hi[1], hi[2]);
    printf("%ssize: %.4g x %.4g x %.4g, centre (%.4g, %.4g, %.4g)\n", indent, hi[0] - lo[0],
           hi[1] - lo[1], hi[2] - lo[2], 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]),
           0.5 * (lo[2] + hi[2]));
}

/* ---- A mesh ------------------------------------------------------------------------------------
 */

/* The unit the largest side suggests: the first of m, cm, mm, km that makes it 5 cm to 20 m (an
 * object one photographs); NULL when none does. */
static const char *units_hint(double largest) {
    static const struct {
        const char *name;
        double metres;
    } units[] = {{"m", 1.0}, {"cm", 0.01}, {"mm", 0.001}, {"km", 1000.0}};
    for (int k = 0; k < 4; ++k)
        if (largest * units[k].metres >= 0.05 && largest * units[k].metres <= 20.0)
            return units[k].name;
    return NULL;
}

/* The closed shells of a closed mesh and how many face inwards: triangles joined through shared
 * corners (vertices welded by equal position, as pen_mesh_edges_count does), each shell's signed
 * volume summed from its triangles; a negative one is wound clockwise seen from outside. The
 * renderer shades a triangle seen from its back with the spheres, not with the mesh's own ray
 * traced shadows, so an inside-out shell loses them (docs/results/accuracy.md, "A thin-limbed
 * figure under a low sun"). Returns 0 when out of memory. */
typedef struct weld_key {
    float p[3];
    int v;
} weld_key;

static int weld_cmp(const void *a, const void *b) {
    const weld_key *x = a, *y = b;
    for (int k = 0; k < 3; ++k)
        if (x->p[k] != y->p[k]) return x->p[k] < y->p[k] ? -1 : 1;
    return (x->v > y->v) - (x->v < y->v);
}

static int shell_root(int *parent, int v) {
    while (parent[v] != v)
        v = parent[v] = parent[parent[v]];
    return v;
}

static int count_shells(const pen_mesh *m, const double centre[3], long *shells, long *inward) {
    const int nv = m->vertex_count;
    *shells = *inward = 0;
    weld_key *key = malloc(sizeof *key * (size_t)(nv > 0 ? nv : 1));
    int *weld = malloc(sizeof *weld * (size_t)(nv > 0 ? nv : 1));
    int *parent = malloc(sizeof *parent * (size_t)(nv > 0 ? nv : 1));
    double *volume = calloc((size_t)(nv > 0 ? nv : 1), sizeof *volume);
    const int ok = key && weld && parent && volume;
    if (ok) {
        for (int v = 0; v < nv; ++v) {
            memcpy(key[v].p, m->positions + 3 * (size_t)v, sizeof key[v].p);
            key[v].v = v;
            parent[v] = v;
        }
        qsort(key, (size_t)nv, sizeof *key, weld_cmp);
        for (int i = 0; i < nv; ++i) /* the first of equal positions stands for them all */
            weld[key[i].v] = i > 0 && key[i].p[0] == key[i - 1].p[0] &&
                                     key[i].p[1] == key[i - 1].p[1] &&
                                     key[i].p[2] == key[i - 1].p[2] /* as weld_cmp: -0 == 0 */
                                 ? weld[key[i - 1].v]
                                 : key[i].v;
        for (int t = 0; t < m->triangle_count; ++t) {
            const uint32_t *c = m->indices + 3 * (size_t)t;
            const int a = shell_root(parent, weld[c[0]]);
            for (int k = 1; k < 3; ++k) {
                const int b = shell_root(parent, weld[c[k]]);
                if (b != a) parent[b] = a;
            }
        }
        for (int t = 0; t < m->triangle_count; ++t) {
            const uint32_t *c = m->indices + 3 * (size_t)t;
            double q[3][3];
            for (int k = 0; k < 3; ++k)
                for (int a = 0; a < 3; ++a)
                    q[k][a] = (double)m->positions[3 * (size_t)c[k] + a] - centre[a];
            volume[shell_root(parent, weld[c[0]])] +=
                (q[0][0] * (q[1][1] * q[2][2] - q[1][2] * q[2][1]) +
                 q[0][1] * (q[1][2] * q[2][0] - q[1][0] * q[2][2]) +
                 q[0][2] * (q[1][0] * q[2][1] - q[1][1] * q[2][0])) /
                6.0;
        }
        for (int v = 0; v < nv; ++v) /* a root that holds triangles is a shell */
            if (shell_root(parent, v) == v && volume[v] != 0.0)
                *shells += 1, *inward += volume[v] < 0.0;
    }
    free(key), free(weld), free(parent), free(volume);
    return ok;
}

static const char *plan_name(pen_mesh_albedo_kind k) {
    return k == PEN_MESH_ALBEDO_CONSTANT  ? "constant"
           : k == PEN_MESH_ALBEDO_TEXTURE ? "texture"
           : k == PEN_MESH_ALBEDO_BAKE    ? "baked"
                                          : "default";
}

static int mesh_info(pen_context *ctx, const char *path, int json) {
    pen_mesh m;
    if (pen_mesh_load(ctx, path, &m)) return pen_cli_fail_ctx(CMD, ctx);
    pen_mesh_files files = {0, NULL};
    pen_mesh_edges edges;
    long *used = calloc((size_t)m.material_count + 1, sizeof *used); /* [material_count]: none */
    if (!used) {
        pen_mesh_free(&m);
        return pen_cli_fail(CMD, "out of memory");
    }
    if (pen_mesh_files_load(ctx, path, &files) || pen_mesh_edges_count(ctx, &m, &edges)) {
        free(used);
        pen_mesh_free(&m);
        pen_mesh_files_free(&files);
        return pen_cli_fail_ctx(CMD, ctx);
    }
    for (int t = 0; t < m.triangle_count; ++t) {
        const int k = m.triangle_materials ? m.triangle_materials[t] : -1;
        used[k >= 0 ? k : m.material_count]++;
    }
    float lof[3], hif[3];
    pen_mesh_bounds(&m, lof, hif);
    double lo[3], hi[3], largest = 0.0;
    for (int a = 0; a < 3; ++a) {
        lo[a] = (double)lof[a], hi[a] = (double)hif[a];
        largest = fmax(largest, hi[a] - lo[a]);
    }
    const char *hint = units_hint(largest);
    const int closed = edges.open_edges == 0 && edges.nonmanifold_edges == 0;
    const double centre[3] = {0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
    long shells = 0, inward = 0; /* only for a closed mesh: an open one has no volume */
    if (closed && !count_shells(&m, centre, &shells, &inward)) {
        free(used);
        pen_mesh_free(&m);
        pen_mesh_files_free(&files);
        return pen_cli_fail(CMD, "out of memory");
    }
    int material = -1;
    const pen_mesh_albedo_kind plan = pen_mesh_albedo_plan(&m, &material);
    const char *format =
        strrchr(path, '.') && !strcasecmp(strrchr(path, '.'), ".ply") ? "ply" : "obj";
    if (json) {
        fputs("{\"file\": ", stdout), json_string(path);
        printf(", \"kind\": \"mesh\", \"format\": \"%s\", \"vertices\": %d, \"triangles\": %d, "
               "\"uvs\": %s, \"normals\": %s, \"colors\": %s, \"bounds\": ",
               format, m.vertex_count, m.triangle_count, m.uv_count ? "true" : "false",
               m.normal_count ? "true" : "false", m.colors ? "true" : "false");
        json_bounds(lo, hi);
        fputs(", \"units_hint\": ", stdout), json_string(hint);
        printf(", \"closed\": %s, \"edges\": %ld, \"open_edges\": %ld, \"nonmanifold_edges\": "
               "%ld, \"degenerate_triangles\": %ld, ",
               closed ? "true" : "false", edges.edges, edges.open_edges, edges.nonmanifold_edges,
               edges.degenerate_triangles);
        if (closed)
            printf("\"shells\": %ld, \"inward_shells\": %ld, ", shells, inward);
        else
            fputs("\"shells\": null, \"inward_shells\": null, ", stdout);
        printf("\"albedo\": \"%s\", \"materials\": [", plan_name(plan));
        for (int k = 0; k < m.material_count; ++k) {
            const pen_mesh_material *mt = &m.materials[k];
            fputs(k ? ", {\"name\": " : "{\"name\": ", stdout), json_string(mt->name);
            fputs(", \"kd\": ", stdout);
            if (mt->has_kd)
                json_vecf(mt->kd, 3);
            else
                fputs("null", stdout);
            fputs(", \"texture\": ", stdout), json_string(mt->texture_path);
            printf(", \"triangles\": %ld}", used[k]);
        }
        printf("], \"triangles_without_material\": %ld, \"files\": [", used[m.material_count]);
        for (int i = 0; i < files.count; ++i) {
            const pen_mesh_file *f = &files.files[i];
            printf("%s{\"kind\": \"%s\", \"path\": ", i ? ", " : "",
                   f->kind == PEN_MESH_FILE_MTLLIB ? "mtllib" : "texture");
            json_string(f->path);
            fputs(", \"source\": ", stdout), json_string(f->source);
            fputs(", \"material\": ", stdout), json_string(f->material);
            printf(", \"found\": %s}", f->found ? "true" : "false");
        }
        fputs("]}\n", stdout);
    } else {
        printf("%s: %s mesh, %d vertices, %d triangles%s%s%s\n", path,
               format[0] == 'p' ? "PLY" : "OBJ", m.vertex_count, m.triangle_count,
               m.uv_count ? ", texture coordinates" : "", m.normal_count ? ", normals" : "",
               m.colors ? ", vertex colours" : "");
        text_bounds("  ", lo, hi);
        printf("  units: the largest side is %.4g: %.4g m as metres, %.4g m as centimetres, %.4g "
               "m as millimetres; ",
               largest, largest, largest * 0.01, largest * 0.001);
        if (!hint)
            printf("no unit makes it 5 cm to 20 m: give the object a pose \"scale\"\n");
        else if (!strcmp(hint, "m"))
            printf("likely metres, the scene's unit (no \"units\" needed)\n");
        else
            printf("likely %s: give the object \"units\": \"%s\"\n", hint, hint);
        if (closed && inward)
            printf("  closed: yes, every edge in two triangles ({\"fit\": N} spheres can be "
                   "fitted); but %ld of its %ld shells face inwards (wound clockwise seen from "
                   "outside): the renderer shades triangles seen from their back with the "
                   "spheres, without the mesh's own shadows: reverse their triangles (unless "
                   "they are the walls of a cavity inside another shell)\n",
                   inward, shells);
        else if (closed)
            printf("  closed: yes, every edge in two triangles ({\"fit\": N} spheres can be "
                   "fitted), %ld shell%s facing outwards\n",
                   shells, shells == 1 ? "" : "s");
        else
            printf("  closed: no: %ld open edges (borders of holes), %ld edges in three or more "
                   "triangles. The sphere fit tells inside from outside by rays: small holes are "
                   "outvoted, but an open surface leaves few inside voxels, and {\"fit\": N} fails "
                   "or its spheres spill out: close the mesh or give \"spheres\" yourself\n",
                   edges.open_edges, edges.nonmanifold_edges);
        printf("  materials: %d; a scene takes its albedo from the mesh as: %s%s%s%s\n",
               m.material_count, plan_name(plan), material >= 0 ? " (material '" : "",
               material >= 0 ? m.materials[material].name : "", material >= 0 ? "')" : "");
        for (int k = 0; k < m.material_count; ++k) {
            const pen_mesh_material *mt = &m.materials[k];
            printf("    %s:", mt->name);
            if (mt->has_kd)
                printf(" Kd (%.3g, %.3g, %.3g)", (double)mt->kd[0], (double)mt->kd[1],
                       (double)mt->kd[2]);
            if (mt->texture_path) printf(" map_Kd %s", base_name(mt->texture_path));
            printf(", %ld triangles\n", used[k]);
        }
        if (m.material_count > 0 && used[m.material_count] > 0)
            printf("    (no material): %ld triangles\n", used[m.material_count]);
        for (int i = 0; i < files.count; ++i) {
            const pen_mesh_file *f = &files.files[i];
            printf("  %s %s (%s): %s\n",
                   f->kind == PEN_MESH_FILE_MTLLIB ? "material library" : "texture", f->path,
                   base_name(f->source), f->found ? "found" : "MISSING");
        }
    }
    free(used);
    pen_mesh_files_free(&files);
    pen_mesh_free(&m);
    return 0;
}

/* ---- A scene -----------------------------------------------------------------------------------
 */

/* The lowest point of an object against the ground: "touches", "floats" or "sinks". */
static const char *ground_contact(const pen_scene *sc, const float *b, double *gap) {
    double size = 0.0;
    for (int a = 0; a < 3; ++a)
        size = fmax(size, (double)b[3 + a] - (double)b[a]);
    *gap = (double)b[1] - (double)sc->ground.height;
    if (fabs(*gap) <= 1e-5 * fmax(size, 1e-30) + 1e-7 * fabs((double)sc->ground.height))
        return "touches";
    return *gap > 0.0 ? "floats above" : "sinks into";
}

static const char *lights_mode_name(pen_lights_mode m) {
    return m == PEN_LIGHTS_NONE ? "none" : m == PEN_LIGHTS_GIVEN ? "given" : "found in the map";
}

static void scene_json(const pen_scene *sc, const pen_scene_report *r) {
    const pen_camera *c = &sc->camera;
    fputs("{\"file\": ", stdout), json_string(sc->path);
    printf(", \"kind\": \"scene\", \"sh_bands\": %d, \"camera\": {\"width\": %d, \"height\": %d, "
           "\"fov_y_deg\": %.9g, \"eye\": ",
           sc->sh_bands, c->width, c->height, (double)c->fov_y_deg);
    json_vecf(c->eye, 3);
    fputs(", \"target\": ", stdout), json_vecf(c->target, 3);
    fputs(", \"up\": ", stdout), json_vecf(c->up, 3);
    fputs("}, \"objects\": [", stdout);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const float *b = r->bounds + 6 * o;
        double lo[3] = {b[0], b[1], b[2]}, hi[3] = {b[3], b[4], b[5]}, gap;
        fputs(o ? ", {\"mesh\": " : "{\"mesh\": ", stdout), json_string(ob->mesh_path);
        printf(", \"vertices\": %d, \"triangles\": %d, \"spheres\": %d, \"fit_spheres\": %d, "
               "\"pose\": {\"rotation_axis_angle_deg\": ",
               ob->mesh.vertex_count, ob->mesh.triangle_count, ob->spheres.count, ob->fit_spheres);
        json_vecf(ob->pose.rotation_axis_angle_deg, 3);
        fputs(", \"translation\": ", stdout), json_vecf(ob->pose.translation, 3);
        printf(", \"scale\": %.9g}, \"bounds\": ", (double)ob->pose.scale);
        json_bounds(lo, hi);
        if (sc->ground.enabled) {
            const char *contact = ground_contact(sc, b, &gap);
            printf(", \"ground_contact\": \"%s\", \"above_ground\": ", contact[0] == 't' ? "touches"
                                                                       : contact[0] == 'f'
                                                                           ? "floats"
                                                                           : "sinks");
            json_number(gap);
        }
        putchar('}');
    }
    fputs("], \"ground\": ", stdout);
    if (sc->ground.enabled) {
        printf("{\"height\": %.9g, \"half_size\": %.9g, \"albedo\": ", (double)sc->ground.height,
               (double)sc->ground.half_size);
        json_vecf(sc->ground.albedo, 3);
        putchar('}');
    } else {
        fputs("null", stdout);
    }
    fputs(", \"lighting\": {\"envmap\": ", stdout), json_string(sc->lighting.envmap_path);
    printf(", \"scale\": %.9g, \"rotation_y_deg\": %.9g, \"lights_mode\": \"%s\", \"lights\": [",
           (double)sc->lighting.scale, (double)sc->lighting.rotation_y_deg,
           lights_mode_name(sc->lighting.lights_mode));
    for (int i = 0; i < r->light_count; ++i) {
        const pen_light *l = &sc->lighting.lights[i];
        const pen_light_summary *s = &r->lights[i];
        fputs(i ? ", {\"direction\": " : "{\"direction\": ", stdout), json_vecf(l->direction, 3);
        printf(", \"elevation_deg\": %.9g, \"azimuth_deg\": %.9g, \"angular_radius_deg\": %.9g, "
               "\"irradiance\": ",
               (double)s->elevation_deg, (double)s->azimuth_deg, (double)l->angular_radius_deg);
        json_vecf(l->irradiance, 3);
        printf(", \"share\": %.9g}", (double)s->share);
    }
    fputs("]}, \"warnings\": [", stdout);
    for (int i = 0; i < r->warning_count; ++i) {
        if (i) fputs(", ", stdout);
        json_string(r->warnings[i].message);
    }
    fputs("]}\n", stdout);
}

static void scene_text(const pen_scene *sc, const pen_scene_report *r) {
    const pen_camera *c = &sc->camera;
    printf("%s: scene, %d SH bands\n", sc->path, sc->sh_bands);
    printf("  camera: %d x %d, ", c->width, c->height);
    if (c->fx > 0.0f)
        printf("fx %.6g, fy %.6g, cx %.6g, cy %.6g", (double)c->fx, (double)c->fy, (double)c->cx,
               (double)c->cy);
    else
        printf("fov_y %.4g deg", (double)c->fov_y_deg);
    printf(", eye (%.4g, %.4g, %.4g), target (%.4g, %.4g, %.4g), up (%.3g, %.3g, %.3g)\n",
           (double)c->eye[0], (double)c->eye[1], (double)c->eye[2], (double)c->target[0],
           (double)c->target[1], (double)c->target[2], (double)c->up[0], (double)c->up[1],
           (double)c->up[2]);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const pen_pose *p = &ob->pose;
        const float *b = r->bounds + 6 * o;
        const double lo[3] = {b[0], b[1], b[2]}, hi[3] = {b[3], b[4], b[5]};
        printf("  objects[%d]: %s, %d vertices, %d triangles, ", o, ob->mesh_path,
               ob->mesh.vertex_count, ob->mesh.triangle_count);
        if (ob->spheres.count > 0)
            printf("%d spheres\n", ob->spheres.count);
        else if (ob->fit_spheres > 0)
            printf("{\"fit\": %d} spheres (fitted by render)\n", ob->fit_spheres);
        else
            printf("no spheres\n");
        printf("    pose: rotation (%.4g, %.4g, %.4g) deg, translation (%.4g, %.4g, %.4g), scale "
               "%.6g\n",
               (double)p->rotation_axis_angle_deg[0], (double)p->rotation_axis_angle_deg[1],
               (double)p->rotation_axis_angle_deg[2], (double)p->translation[0],
               (double)p->translation[1], (double)p->translation[2], (double)p->scale);
        text_bounds("    ", lo, hi);
        if (sc->ground.enabled) {
            double gap;
            const char *contact = ground_contact(sc, b, &gap);
            if (contact[0] == 't')
                printf("    touches the ground\n");
            else
                printf("    %s the ground by %.4g\n", contact, fabs(gap));
        }
    }
    if (sc->ground.enabled)
        printf("  ground: y = %.4g, square %.4g x %.4g (half_size %.4g), albedo (%.3g, %.3g, "
               "%.3g)\n",
               (double)sc->ground.height, 2.0 * (double)sc->ground.half_size,
               2.0 * (double)sc->ground.half_size, (double)sc->ground.half_size,
               (double)sc->ground.albedo[0], (double)sc->ground.albedo[1],
               (double)sc->ground.albedo[2]);
    else
        printf("  ground: none\n");
    const pen_lighting *L = &sc->lighting;
    if (L->envmap_path)
        printf("  lighting: envmap %s (scale %.4g, rotation %.4g deg); disk lights: %s",
               L->envmap_path, (double)L->scale, (double)L->rotation_y_deg,
               lights_mode_name(L->lights_mode));
    else
        printf("  lighting: SH coefficients; disk lights: %s", lights_mode_name(L->lights_mode));
    if (L->lights_mode == PEN_LIGHTS_AUTO) printf(" (at most %d)", L->lights_max);
    if (L->lights_mode == PEN_LIGHTS_AUTO && L->lights_added > 0)
        printf(" plus %d given", L->lights_added);
    printf(", %d\n", r->light_count);
    pen_cli_print_lights(stdout, sc, r, "    ");
    if (r->warning_count == 0) printf("  warnings: none\n");
    for (int i = 0; i < r->warning_count; ++i)
        printf("  warning: %s\n", r->warnings[i].message);
}

static int scene_info(pen_context *ctx, const char *path, int json) {
    pen_scene sc;
    if (pen_scene_load(ctx, path, &sc)) return pen_cli_fail_ctx(CMD, ctx);
    pen_scene_report report;
    if (pen_scene_check(ctx, &sc, &report)) {
        pen_scene_free(&sc);
        return pen_cli_fail_ctx(CMD, ctx);
    }
    if (json)
        scene_json(&sc, &report);
    else
        scene_text(&sc, &report);
    pen_scene_report_free(&report);
    pen_scene_free(&sc);
    return 0;
}

int pen_cmd_info(int argc, char **argv) {
    const char *path = NULL;
    int json = 0;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (pen_cli_positional(CMD, a, &path, 1)) {
            return 2;
        }
    }
    if (!path) return pen_cli_usage_error(CMD, "missing MESH.(obj|ply) or SCENE.json");
    const char *dot = strrchr(path, '.');
    const int scene = dot && !strcasecmp(dot, ".json");
    if (!scene && !(dot && (!strcasecmp(dot, ".obj") || !strcasecmp(dot, ".ply"))))
        return pen_cli_usage_error(CMD, "%s: expected a mesh (.obj, .ply) or a scene (.json)",
                                   path);
    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    const int rc = scene ? scene_info(ctx, path, json) : mesh_info(ctx, path, json);
    fflush(stdout);
    pen_context_destroy(ctx);
    return rc;
}
