/* Scene JSON (docs/design.md sec. 3.3, docs/file-formats.md): loading with everything it
 * references, and saving back.
 *
 * The loader walks the JSON once, key by key, carrying the key path ("objects[1].pose.scale")
 * so that each error is one line naming the file, the key and the problem; errors from files the
 * scene references (a mesh, a texture) are prefixed with the key that named them. Unknown keys
 * are errors, because a misspelt optional key ("albdeo") would otherwise be silently ignored;
 * keys starting with '_' are comments. Defaults are applied here and nowhere else. The loader
 * only parses: sphere sets keep the overlap weights their JSON gives and get none otherwise
 * (the renderer computes missing weights once per render state; pen_spheres_ensure_weights
 * computes them explicitly, as the optimizer and the flat API do).
 *
 * Placement is resolved here too: "units", "pose": {"on_ground", "centre"} and "camera":
 * {"frame"} are how a file says where an object stands and where the camera looks, as
 * "world_to_camera" is another way to give the eye. They become the pose's scale and translation
 * and the camera's eye and target (src/io/scene_place.c, with the maths of src/scene/place.c)
 * once the objects are loaded, so that every door (the CLI, the C API, the flat API and Python)
 * gets the same numbers, and pen_scene_save writes those numbers: an optimised pose is saved as
 * it was found, not placed again. */
#include "io/io_internal.h"
#include "io/scene_place.h"
#include "io/spheres_json.h"
#include "scene/validate.h"
#include "penumbra/envmap.h"
#include "penumbra/io.h"

#include <stdlib.h>
#include <string.h>

#define SCENE_MAX_OBJECTS 4096
#define SCENE_MAX_FIT_SPHERES 4096
static const float DEFAULT_ALBEDO = 0.8f;
static const float DEFAULT_GROUND_HALF_SIZE = 4.0f;

typedef pen__json_where where;

/* The bound on every coordinate (penumbra/scene.h), short for the many uses below. */
#define COORD PEN_SCENE_MAX_COORD

/* The key path of member `name` of the object at `w`. */
static where at(const where *w, const char *name) {
    where c;
    pen__json_child(w, name, &c);
    return c;
}

static pen_status opt_number(pen_context *ctx, const where *w, const cJSON *obj, const char *name,
                             double lo, double hi, const char *what, float *out) {
    const cJSON *item = pen__json_member(obj, name);
    if (!item) return PEN_OK;
    where wk = at(w, name);
    double v;
    pen_status s = pen__json_number(ctx, &wk, item, lo, hi, what, &v);
    if (!s) *out = (float)v;
    return s;
}

static pen_status opt_floats(pen_context *ctx, const where *w, const cJSON *obj, const char *name,
                             double lo, double hi, float *out) {
    const cJSON *item = pen__json_member(obj, name);
    if (!item) return PEN_OK;
    where wk = at(w, name);
    return pen__json_floats(ctx, &wk, item, 3, lo, hi, out);
}

/* ---- Loading --------------------------------------------------------------------------------- */

/* Every value of an image the scene references (an environment map, a texture) finite and at
 * most `limit` in magnitude: a value near FLT_MAX would overflow in the SH projection or the
 * shading. The caller prefixes the key. */
pen_status pen__io_image_check_values(pen_context *ctx, const char *path, const pen_image *img,
                                      double limit) {
    const size_t n = (size_t)img->width * (size_t)img->height * (size_t)img->channels;
    for (size_t i = 0; i < n; ++i) {
        const float v = img->data[i];
        if (isfinite(v) && fabs((double)v) <= limit) continue;
        const size_t px = i / (size_t)img->channels;
        return pen__error(ctx, PEN_ERROR_PARSE,
                          "%s: pixel (%zu, %zu) channel %zu: %g outside [-%g, %g]", path,
                          px % (size_t)img->width, px / (size_t)img->width,
                          i % (size_t)img->channels, (double)v, limit, limit);
    }
    return PEN_OK;
}

/* One disk light, lighting.lights[i]: the direction is normalised here (any non-zero finite
 * length is accepted, docs/file-formats.md). */
static pen_status parse_light(pen_context *ctx, const where *w, const cJSON *o, pen_light *l) {
    static const char *const known[] = {"direction", "angular_radius_deg", "irradiance", NULL};
    pen_status s = pen__json_need_object(ctx, w, o);
    if (!s) s = pen__json_known_keys(ctx, w, o, known);
    if (s) return s;
    static const char *const need[] = {"direction", "angular_radius_deg", "irradiance"};
    for (int k = 0; k < 3; ++k)
        if (!pen__json_member(o, need[k])) {
            where wk = at(w, need[k]);
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wk, "missing");
        }
    where wd = at(w, "direction");
    s = pen__json_floats(ctx, &wd, pen__json_member(o, "direction"), 3, -COORD, COORD, l->direction);
    if (s) return s;
    const double len = sqrt((double)l->direction[0] * (double)l->direction[0] +
                            (double)l->direction[1] * (double)l->direction[1] +
                            (double)l->direction[2] * (double)l->direction[2]);
    if (!(len > 1e-12))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wd, "must not be the zero vector");
    for (int a = 0; a < 3; ++a)
        l->direction[a] = (float)((double)l->direction[a] / len);
    s = opt_number(ctx, w, o, "angular_radius_deg", PEN_SCENE_MIN_LIGHT_RADIUS_DEG,
                   PEN_SCENE_MAX_LIGHT_RADIUS_DEG, "a number of degrees in [0.01, 45]",
                   &l->angular_radius_deg);
    if (!s) s = opt_floats(ctx, w, o, "irradiance", 0.0, PEN_SCENE_MAX_IRRADIANCE, l->irradiance);
    return s;
}

/* An array of at most `room` lights at `w` into lights[0 .. *n). */
static pen_status parse_light_array(pen_context *ctx, const where *w, const cJSON *item, int room,
                                    const char *what, pen_light *lights, int *n) {
    const int count = cJSON_GetArraySize(item);
    if (count > room)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "%d lights, at most %d%s", count, room,
                               what);
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, item) {
        where wi;
        pen__json_index(w, i, &wi);
        pen_status s = parse_light(ctx, &wi, e, &lights[i]);
        if (s) return s;
        *n = ++i;
    }
    return PEN_OK;
}

/* lighting.lights: an array of lights (GIVEN), "none", or {"max": K, "add": [lights]} (AUTO:
 * up to K found in the map, then the added ones); absent: AUTO with PEN_LIGHTS_DEFAULT_MAX.
 * Added lights are parsed into lights[0 ..) here and moved behind the found ones by
 * envmap_lighting, once the map is read. */
static pen_status parse_lights(pen_context *ctx, const where *wl, const cJSON *o, pen_lighting *L) {
    const cJSON *item = pen__json_member(o, "lights");
    where w = at(wl, "lights");
    L->light_count = 0;
    L->lights_mode = PEN_LIGHTS_AUTO;
    L->lights_max = PEN_LIGHTS_DEFAULT_MAX;
    L->lights_added = 0;
    if (!item) return PEN_OK;
    if (cJSON_IsString(item)) {
        if (strcmp(item->valuestring, "none") != 0)
            return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                                   "unknown value \"%s\" (expected an array of lights, \"none\" "
                                   "or {\"max\": K, \"add\": [lights]})",
                                   item->valuestring);
        L->lights_mode = PEN_LIGHTS_NONE;
        L->lights_max = 0;
        return PEN_OK;
    }
    if (cJSON_IsObject(item)) {
        static const char *const known[] = {"max", "add", NULL};
        pen_status s = pen__json_known_keys(ctx, &w, item, known);
        if (!s && pen__json_member(item, "max")) {
            where wm = at(&w, "max");
            s = pen__json_int(ctx, &wm, pen__json_member(item, "max"), 0, PEN_SCENE_MAX_LIGHTS,
                              "an integer in [0, 16]", &L->lights_max);
        }
        const cJSON *add = pen__json_member(item, "add");
        if (s || !add) return s;
        where wa = at(&w, "add");
        if (!cJSON_IsArray(add))
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wa, "expected an array of lights, got %s",
                                   pen__json_type_name(add));
        /* Room for the most the map may give: the total stays within PEN_SCENE_MAX_LIGHTS
         * whatever the map holds. */
        s = parse_light_array(ctx, &wa, add, PEN_SCENE_MAX_LIGHTS - L->lights_max,
                              pen__json_member(item, "max") ? " (16 minus \"max\")"
                                                            : " (16 minus \"max\", 4 by default)",
                              L->lights, &L->light_count);
        L->lights_added = L->light_count;
        return s;
    }
    if (!cJSON_IsArray(item))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                               "expected an array of lights, \"none\" or {\"max\": K, \"add\": "
                               "[lights]}, got %s",
                               pen__json_type_name(item));
    L->lights_mode = PEN_LIGHTS_GIVEN;
    L->lights_max = 0;
    return parse_light_array(ctx, &w, item, PEN_SCENE_MAX_LIGHTS, "", L->lights, &L->light_count);
}

/* The SH lighting of a map (no "sh" given): with lights AUTO, the lights found in it and the
 * projection of the rest (docs/design.md sec. 1.14), followed by the added lights; with "none"
 * or given lights, the projection of the whole map, as before lights existed. Runs after the
 * whole "lighting" object is read, so that the lights' mode and maximum are known. */
static pen_status envmap_lighting(pen_context *ctx, int bands, pen_lighting *L) {
    int max = L->lights_mode == PEN_LIGHTS_AUTO && L->lights_max > 0 ? L->lights_max : 0;
    pen_light added[PEN_SCENE_MAX_LIGHTS];
    const int n_added = L->lights_mode == PEN_LIGHTS_AUTO ? L->lights_added : 0;
    memcpy(added, L->lights, sizeof(pen_light) * (size_t)n_added);
    if (L->lights_mode == PEN_LIGHTS_AUTO) L->light_count = 0; /* max 0 leaves the count alone */
    pen_status s = pen_envmap_lighting(ctx, &L->envmap, bands, L->rotation_y_deg, L->scale, max,
                                       L->sh, L->lights, &L->light_count);
    if (s) return s;
    if (L->lights_mode != PEN_LIGHTS_AUTO) return PEN_OK; /* given lights: kept as listed */
    memcpy(L->lights + L->light_count, added, sizeof(pen_light) * (size_t)n_added);
    L->light_count += n_added;
    return PEN_OK;
}

static pen_status parse_lighting(pen_context *ctx, const char *path, const where *top,
                                 const cJSON *root, int bands, pen_lighting *L) {
    where w = at(top, "lighting");
    const cJSON *o = pen__json_member(root, "lighting");
    static const char *const known[] = {"envmap", "scale", "rotation_y_deg", "sh", "lights", NULL};
    pen_status s = pen__json_need_object(ctx, &w, o);
    if (!s) s = pen__json_known_keys(ctx, &w, o, known);
    if (!s) s = parse_lights(ctx, &w, o, L);
    if (s) return s;
    const cJSON *env = pen__json_member(o, "envmap"), *sh = pen__json_member(o, "sh");
    L->scale = 1.0f;
    L->rotation_y_deg = 0.0f;
    if (!env && !sh) return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "needs \"envmap\" or \"sh\"");
    if (!env && (pen__json_member(o, "scale") || pen__json_member(o, "rotation_y_deg")))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                               "\"scale\" and \"rotation_y_deg\" apply to an \"envmap\" only");
    if (env) {
        where we = at(&w, "envmap");
        const char *rel;
        s = pen__json_string(ctx, &we, env, &rel);
        if (!s)
            s = opt_number(ctx, &w, o, "scale", 0.0, PEN_SCENE_MAX_LIGHT_SCALE,
                           "a number in [0, 1e3]", &L->scale);
        if (!s)
            s = opt_number(ctx, &w, o, "rotation_y_deg", -1e6, 1e6, "a number of degrees",
                           &L->rotation_y_deg);
        if (s) return s;
        L->envmap_path = pen__io_path_resolve(ctx, path, rel);
        if (!L->envmap_path) return PEN_ERROR_MEMORY;
        s = pen_image_load(ctx, L->envmap_path, &L->envmap);
        if (!s)
            s = pen__io_image_check_values(ctx, L->envmap_path, &L->envmap,
                                           PEN_SCENE_MAX_RADIANCE);
        if (s) return pen__json_wrap(ctx, s, &we);
    }
    if (sh) {
        where ws = at(&w, "sh");
        int n = bands * bands;
        if (!cJSON_IsArray(sh))
            return pen__json_error(ctx, PEN_ERROR_PARSE, &ws,
                                   "expected an array of [r, g, b] rows, got %s",
                                   pen__json_type_name(sh));
        if (cJSON_GetArraySize(sh) != n)
            return pen__json_error(ctx, PEN_ERROR_PARSE, &ws,
                                   "expected %d rows (sh_bands %d squared), got %d", n, bands,
                                   cJSON_GetArraySize(sh));
        int i = 0;
        const cJSON *row;
        cJSON_ArrayForEach(row, sh) {
            where wr;
            pen__json_index(&ws, i, &wr);
            s = pen__json_floats(ctx, &wr, row, 3, -PEN_SCENE_MAX_SH, PEN_SCENE_MAX_SH, L->sh[i++]);
            if (s) return s;
        }
    }
    if (env && !sh) {
        where we = at(&w, "envmap");
        s = envmap_lighting(ctx, bands, L);
        if (s) return pen__json_wrap(ctx, s, &we);
    }
    return PEN_OK;
}

/* The optional key `name` of obj as the index of one of `names` into *k; -1 when absent. */
static pen_status choice(pen_context *ctx, const where *w, const cJSON *obj, const char *name,
                         const char *what, const char *const *names, int *k) {
    *k = -1;
    const cJSON *v = pen__json_member(obj, name);
    if (!v) return PEN_OK;
    where wv = at(w, name);
    return pen__json_choice(ctx, &wv, v, what, names, k);
}

static pen_status parse_shadow(pen_context *ctx, const where *top, const cJSON *root, int bands,
                               pen_shadow *sh) {
    where w = at(top, "shadow");
    const cJSON *o = pen__json_member(root, "shadow");
    sh->exp = PEN_SH_EXP_CALIBRATED;
    pen_status s = PEN_OK;
    if (o) {
        static const char *const known[] = {"epsilon", "exp",           "overlap",    "ground",
                                            "self",    "ground_shadow", "ground_grid", NULL};
        s = pen__json_need_object(ctx, &w, o);
        if (!s) s = pen__json_known_keys(ctx, &w, o, known);
        const cJSON *e = pen__json_member(o, "exp");
        if (!s && e) {
            where we = at(&w, "exp");
            const char *name;
            s = pen__json_string(ctx, &we, e, &name);
            int m = s ? -1 : pen_sh_exp_method_parse(name);
            if (!s && m < 0)
                s = pen__json_error(ctx, PEN_ERROR_PARSE, &we,
                                    "unknown method '%s' (expected calibrated, default, paper or "
                                    "exact)",
                                    name);
            if (!s) sh->exp = (pen_sh_exp_method)m;
        }
        /* The two-way choices: the second name of each list selects the non-default mode. */
        static const char *const overlaps[] = {"weights", "none", NULL};
        static const char *const grounds[] = {"occludes", "receiver", NULL};
        static const char *const selfs[] = {"transfer", "spheres", NULL};
        static const char *const gshadows[] = {"transfer", "spheres", NULL};
        int k;
        if (!s && !(s = choice(ctx, &w, o, "overlap", "overlap mode", overlaps, &k)) && k >= 0)
            sh->overlap = k == 1 ? PEN_OVERLAP_NONE : PEN_OVERLAP_WEIGHTS;
        if (!s && !(s = choice(ctx, &w, o, "ground", "ground mode", grounds, &k)) && k >= 0)
            sh->ground = k == 1 ? PEN_GROUND_RECEIVER : PEN_GROUND_OCCLUDES;
        if (!s && !(s = choice(ctx, &w, o, "self", "self-shadow mode", selfs, &k)) && k >= 0)
            sh->self = k == 1 ? PEN_SELF_SPHERES : PEN_SELF_TRANSFER;
        if (!s && !(s = choice(ctx, &w, o, "ground_shadow", "ground shadow mode", gshadows, &k)) &&
            k >= 0)
            sh->ground_shadow = k == 1 ? PEN_GROUND_SHADOW_SPHERES : PEN_GROUND_SHADOW_TRANSFER;
        const cJSON *gg = pen__json_member(o, "ground_grid");
        if (!s && gg) {
            where wg = at(&w, "ground_grid");
            s = pen__json_int(ctx, &wg, gg, PEN_GROUND_GRID_MIN, PEN_GROUND_GRID_MAX,
                              "an integer in [2, 1024] (nodes per side)", &sh->ground_grid);
        }
    }
    /* The epsilon the exponential model was fitted with, unless given. */
    sh->epsilon = (float)pen_sh_exp_model_default(sh->exp, bands).epsilon;
    if (!s && o)
        s = opt_number(ctx, &w, o, "epsilon", 1e-6, 1e6, "a positive number", &sh->epsilon);
    return s;
}

static pen_status parse_pose(pen_context *ctx, const where *w, const cJSON *o, pen_pose *pose,
                             unsigned char *place) {
    memset(pose, 0, sizeof *pose);
    pose->scale = 1.0f;
    *place = 0;
    if (!o) return PEN_OK;
    static const char *const known[] = {
        "rotation_axis_angle_deg", "translation", "scale", "on_ground", "centre", NULL};
    pen_status s = pen__json_need_object(ctx, w, o);
    if (!s) s = pen__json_known_keys(ctx, w, o, known);
    if (!s) s = pen__scene_pose_place_parse(ctx, w, o, place);
    if (!s)
        s = opt_floats(ctx, w, o, "rotation_axis_angle_deg", -1e6, 1e6,
                       pose->rotation_axis_angle_deg);
    if (!s) s = opt_floats(ctx, w, o, "translation", -COORD, COORD, pose->translation);
    if (!s)
        s = opt_number(ctx, w, o, "scale", PEN_SCENE_MIN_SIZE, PEN_SCENE_MAX_SIZE,
                       "a number in [1e-6, 1e6]", &pose->scale);
    return s;
}

static pen_status parse_spheres(pen_context *ctx, const char *path, const where *w,
                                const cJSON *item, pen_object *obj) {
    if (!item || cJSON_IsNull(item)) return PEN_OK;
    if (cJSON_IsString(item)) {
        const char *rel;
        pen_status s = pen__json_string(ctx, w, item, &rel);
        if (s) return s;
        obj->spheres_path = pen__io_path_resolve(ctx, path, rel);
        if (!obj->spheres_path) return PEN_ERROR_MEMORY;
        s = pen_spheres_load(ctx, obj->spheres_path, &obj->spheres);
        return s ? pen__json_wrap(ctx, s, w) : PEN_OK;
    }
    if (cJSON_IsArray(item)) {
        return pen__spheres_from_json(ctx, w, item, &obj->spheres);
    }
    if (cJSON_IsObject(item)) {
        static const char *const known[] = {"fit", NULL};
        where wf = at(w, "fit");
        pen_status s = pen__json_known_keys(ctx, w, item, known);
        if (!s)
            s = pen__json_int(ctx, &wf, pen__json_member(item, "fit"), 1, SCENE_MAX_FIT_SPHERES,
                              "a sphere count in [1, 4096]", &obj->fit_spheres);
        return s;
    }
    return pen__json_error(ctx, PEN_ERROR_PARSE, w,
                           "expected a file name, {\"fit\": N} or an array of spheres, got %s",
                           pen__json_type_name(item));
}

/* Several materials or vertex colours: the textures of the materials the faces use, loaded with
 * the checks of any texture, baked with the Kd colours and vertex colours into one atlas. */
static pen_status bake_object(pen_context *ctx, pen_object *obj) {
    pen_mesh *m = &obj->mesh;
    pen_image *tex = NULL;
    pen_status s = PEN_OK;
    if (m->material_count > 0 && !m->colors) {
        tex = pen__calloc(ctx, (size_t)m->material_count, sizeof *tex, "textures");
        if (!tex) return PEN_ERROR_MEMORY;
    }
    for (int t = 0; tex && !s && t < m->triangle_count; ++t) {
        const int mi = m->triangle_materials[t];
        const pen_mesh_material *mat = mi >= 0 ? &m->materials[mi] : NULL;
        if (!mat || !mat->texture_path || tex[mi].data) continue;
        s = pen_image_load(ctx, mat->texture_path, &tex[mi]);
        if (!s)
            s = pen__io_image_check_values(ctx, mat->texture_path, &tex[mi],
                                           PEN_SCENE_MAX_ALBEDO);
        if (s)
            s = pen__error_prefix(ctx, s, "%s: map_Kd of material '%s': ",
                                  mat->texture_source ? mat->texture_source : obj->mesh_path,
                                  mat->name);
    }
    if (!s) {
        s = pen_mesh_bake_albedo(ctx, m, tex, obj->albedo, &obj->texture);
        if (s) s = pen__error_prefix(ctx, s, "%s: ", obj->mesh_path);
    }
    for (int i = 0; tex && i < m->material_count; ++i)
        pen_image_free(&tex[i]);
    free(tex);
    if (!s) obj->texture_layout = PEN_TEXTURE_LAYOUT_BAKED;
    return s;
}

/* The albedo of an object, by precedence: "albedo_texture" (with the mesh's UVs, or, with
 * "albedo_texture_layout": "baked", the pixels of an atlas baked from the mesh), "albedo", then
 * what the mesh's materials and vertex colours say (pen_mesh_albedo_plan), then the default. */
static pen_status parse_albedo(pen_context *ctx, const char *path, const where *w, const cJSON *o,
                               pen_object *obj) {
    where wm = at(w, "mesh"), wt = at(w, "albedo_texture"), wl = at(w, "albedo_texture_layout");
    const char *tex_rel = NULL;
    int baked_pixels = 0;
    pen_status s = PEN_OK;
    if (pen__json_member(o, "albedo_texture"))
        s = pen__json_string(ctx, &wt, pen__json_member(o, "albedo_texture"), &tex_rel);
    if (!s && pen__json_member(o, "albedo_texture_layout")) {
        static const char *const layouts[] = {"mesh", "baked", NULL};
        s = pen__json_choice(ctx, &wl, pen__json_member(o, "albedo_texture_layout"), "texture layout",
                             layouts, &baked_pixels);
        if (!s && !tex_rel)
            s = pen__json_error(ctx, PEN_ERROR_PARSE, &wl, "needs \"albedo_texture\"");
    }
    if (!s && pen__json_member(o, "texture_filter")) {
        static const char *const filters[] = {"footprint", "point", NULL};
        where wf = at(w, "texture_filter");
        int f = 0;
        s = pen__json_choice(ctx, &wf, pen__json_member(o, "texture_filter"), "texture filter",
                             filters, &f);
        obj->texture_filter = f ? PEN_TEXTURE_FILTER_POINT : PEN_TEXTURE_FILTER_FOOTPRINT;
    }
    if (!s && tex_rel && pen__json_member(o, "albedo"))
        s = pen__json_error(ctx, PEN_ERROR_PARSE, w,
                            "give \"albedo_texture\" or \"albedo\", not both");
    for (int k = 0; k < 3; ++k)
        obj->albedo[k] = DEFAULT_ALBEDO;
    if (!s) s = opt_floats(ctx, w, o, "albedo", 0.0, 1.0, obj->albedo);
    if (s) return s;

    int material = -1;
    pen_mesh_albedo_kind plan = PEN_MESH_ALBEDO_DEFAULT;
    if (baked_pixels || (!tex_rel && !pen__json_member(o, "albedo")))
        plan = pen_mesh_albedo_plan(&obj->mesh, &material);
    if (baked_pixels && plan != PEN_MESH_ALBEDO_BAKE)
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wl,
                               "\"baked\" needs a mesh with several materials or vertex colours");
    if (plan == PEN_MESH_ALBEDO_CONSTANT)
        memcpy(obj->albedo, obj->mesh.materials[material].kd, sizeof obj->albedo);
    if (plan == PEN_MESH_ALBEDO_BAKE) {
        s = bake_object(ctx, obj);
        if (s) return pen__json_wrap(ctx, s, &wm);
    }

    /* The texture: given, or the one material's map_Kd. */
    const where *wtex = &wt;
    if (tex_rel) {
        obj->texture_path = pen__io_path_resolve(ctx, path, tex_rel);
        if (!obj->texture_path) return PEN_ERROR_MEMORY;
    } else if (plan == PEN_MESH_ALBEDO_TEXTURE) {
        const char *map =
            material >= 0 ? obj->mesh.materials[material].texture_path : obj->mesh.texture_path;
        obj->texture_path = pen__io_strdup(ctx, map);
        if (!obj->texture_path) return PEN_ERROR_MEMORY;
        wtex = &wm;
    }
    if (!obj->texture_path) return PEN_OK;
    if (obj->mesh.uv_count == 0)
        return pen__json_error(ctx, PEN_ERROR_PARSE, wtex,
                               "a texture needs a mesh with texture coordinates");
    pen_image img = {0};
    s = pen_image_load(ctx, obj->texture_path, &img);
    if (!s) s = pen__io_image_check_values(ctx, obj->texture_path, &img, PEN_SCENE_MAX_ALBEDO);
    if (!s && baked_pixels &&
        (img.width != obj->texture.width || img.height != obj->texture.height))
        s = pen__error(ctx, PEN_ERROR_PARSE,
                       "%s: %d x %d pixels, but the atlas baked from the mesh is %d x %d",
                       obj->texture_path, img.width, img.height, obj->texture.width,
                       obj->texture.height);
    if (s) {
        pen_image_free(&img);
        const pen_mesh_material *mt =
            tex_rel || material < 0 ? NULL : &obj->mesh.materials[material];
        if (mt && mt->texture_source) /* the statement that named it, as baking says */
            s = pen__error_prefix(ctx, s, "%s: map_Kd of material '%s': ", mt->texture_source,
                                  mt->name);
        return pen__json_wrap(ctx, s, wtex);
    }
    pen_image_free(&obj->texture);
    obj->texture = img;
    return PEN_OK;
}

static pen_status parse_object(pen_context *ctx, const char *path, const where *w, const cJSON *o,
                               pen_object *obj, unsigned char *place) {
    static const char *const known[] = {
        "mesh", "albedo_texture", "albedo_texture_layout", "texture_filter", "albedo", "spheres",
        "pose", "units", NULL};
    pen_status s = pen__json_need_object(ctx, w, o);
    if (!s) s = pen__json_known_keys(ctx, w, o, known);
    where wm = at(w, "mesh");
    const char *mesh_rel = NULL;
    if (!s) s = pen__json_string(ctx, &wm, pen__json_member(o, "mesh"), &mesh_rel);
    where wp = at(w, "pose"), ws = at(w, "spheres");
    if (!s) s = parse_pose(ctx, &wp, pen__json_member(o, "pose"), &obj->pose, place);
    if (!s) s = pen__scene_units_parse(ctx, w, o, &obj->pose);
    if (s) return s;

    obj->mesh_path = pen__io_path_resolve(ctx, path, mesh_rel);
    if (!obj->mesh_path) return PEN_ERROR_MEMORY;
    s = pen_mesh_load(ctx, obj->mesh_path, &obj->mesh);
    if (s) return pen__json_wrap(ctx, s, &wm);
    s = parse_albedo(ctx, path, w, o, obj);
    return s ? s : parse_spheres(ctx, path, &ws, pen__json_member(o, "spheres"), obj);
}

static pen_status parse_objects(pen_context *ctx, const char *path, const where *top,
                                const cJSON *root, pen_scene *sc, pen__placement *pl) {
    where w = at(top, "objects");
    const cJSON *list = pen__json_member(root, "objects");
    if (!cJSON_IsArray(list))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "%s (expected an array of objects)",
                               list ? pen__json_type_name(list) : "missing");
    int n = cJSON_GetArraySize(list);
    if (n > SCENE_MAX_OBJECTS)
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "%d objects (limit %d)", n,
                               SCENE_MAX_OBJECTS);
    if (n == 0) return PEN_OK;
    sc->objects = pen__calloc(ctx, (size_t)n, sizeof *sc->objects, "objects");
    pl->flags = pen__calloc(ctx, (size_t)n, 1, "objects");
    if (!sc->objects || !pl->flags) return PEN_ERROR_MEMORY;
    int i = 0;
    const cJSON *o;
    cJSON_ArrayForEach(o, list) {
        where wi;
        pen__json_index(&w, i, &wi);
        sc->object_count = i + 1; /* so that pen_scene_free sees this object on failure */
        pen_status s = parse_object(ctx, path, &wi, o, &sc->objects[i], &pl->flags[i]);
        ++i;
        if (s) return s;
    }
    return PEN_OK;
}

static pen_status parse_ground(pen_context *ctx, const where *top, const cJSON *root,
                               pen_ground *g) {
    where w = at(top, "ground");
    const cJSON *o = pen__json_member(root, "ground");
    memset(g, 0, sizeof *g);
    if (!o || cJSON_IsNull(o)) return PEN_OK;
    static const char *const known[] = {"height", "albedo", "half_size", NULL};
    pen_status s = pen__json_need_object(ctx, &w, o);
    if (!s) s = pen__json_known_keys(ctx, &w, o, known);
    g->enabled = 1;
    for (int k = 0; k < 3; ++k)
        g->albedo[k] = DEFAULT_ALBEDO;
    g->half_size = DEFAULT_GROUND_HALF_SIZE;
    if (!s)
        s = opt_number(ctx, &w, o, "height", -COORD, COORD, "a number in [-1e6, 1e6]", &g->height);
    if (!s) s = opt_floats(ctx, &w, o, "albedo", 0.0, 1.0, g->albedo);
    if (!s)
        s = opt_number(ctx, &w, o, "half_size", PEN_SCENE_MIN_SIZE, PEN_SCENE_MAX_SIZE,
                       "a number in [1e-6, 1e6]", &g->half_size);
    return s;
}

static pen_status parse_background(pen_context *ctx, const where *top, const cJSON *root,
                                   pen_scene *sc) {
    where w = at(top, "background");
    const cJSON *b = pen__json_member(root, "background");
    int has_env = sc->lighting.envmap.data != NULL;
    memset(sc->background, 0, sizeof sc->background);
    sc->background_envmap = 0;
    if (!b) {
        sc->background_envmap = has_env;
        return PEN_OK;
    }
    if (cJSON_IsString(b) && strcmp(b->valuestring, "envmap") == 0) {
        if (!has_env)
            return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "\"envmap\" needs lighting.envmap");
        sc->background_envmap = 1;
        return PEN_OK;
    }
    if (!cJSON_IsArray(b))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                               "expected \"envmap\" or [r, g, b], got %s%s%s",
                               cJSON_IsString(b) ? "'" : "",
                               cJSON_IsString(b) ? b->valuestring : pen__json_type_name(b),
                               cJSON_IsString(b) ? "'" : "");
    return pen__json_floats(ctx, &w, b, 3, 0.0, PEN_SCENE_MAX_RADIANCE, sc->background);
}

static pen_status parse_scene(pen_context *ctx, const char *path, const cJSON *root,
                              pen_scene *sc) {
    where top = {.file = path, .key = ""};
    if (!cJSON_IsObject(root))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &top, "expected a JSON object, got %s",
                               pen__json_type_name(root));
    static const char *const known[] = {"camera",  "lighting", "sh_bands",   "shadow",
                                        "objects", "ground",   "background", NULL};
    pen_status s = pen__json_known_keys(ctx, &top, root, known);
    sc->sh_bands = 4;
    where wb = at(&top, "sh_bands");
    if (!s && pen__json_member(root, "sh_bands"))
        s = pen__json_int(ctx, &wb, pen__json_member(root, "sh_bands"), 1, PEN_SH_MAX_BANDS,
                          "an integer in [1, 8]", &sc->sh_bands);
    pen__placement pl = {0};
    if (!s) s = pen__scene_camera_parse(ctx, &top, root, &sc->camera, &pl);
    if (!s) s = parse_shadow(ctx, &top, root, sc->sh_bands, &sc->shadow);
    if (!s) s = parse_ground(ctx, &top, root, &sc->ground);
    if (!s) s = parse_lighting(ctx, path, &top, root, sc->sh_bands, &sc->lighting);
    if (!s) s = parse_background(ctx, &top, root, sc);
    if (!s) s = parse_objects(ctx, path, &top, root, sc, &pl);
    if (!s) s = pen__scene_place(ctx, &top, sc, &pl);
    free(pl.flags);
    return s;
}

static pen_status scene_from_text(pen_context *ctx, const char *text, size_t size, const char *path,
                                  pen_scene *out) {
    cJSON *root = NULL;
    pen_status s = pen__json_parse(ctx, path, text, size, &root);
    if (s) return s;
    out->path = pen__io_strdup(ctx, path);
    s = out->path ? parse_scene(ctx, path, root, out) : PEN_ERROR_MEMORY;
    cJSON_Delete(root);
    if (s) pen_scene_free(out);
    return s;
}

pen_status pen_scene_parse(pen_context *ctx, const char *json_text, const char *path,
                           pen_scene *out) {
    memset(out, 0, sizeof *out);
    if (!json_text) return pen__error(ctx, PEN_ERROR_ARGUMENT, "scene: no JSON text");
    return scene_from_text(ctx, json_text, strlen(json_text), path ? path : "scene", out);
}

pen_status pen_scene_load(pen_context *ctx, const char *path, pen_scene *out) {
    memset(out, 0, sizeof *out);
    char *text = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, (size_t)64 << 20, &text, &size);
    if (s) return s;
    s = scene_from_text(ctx, text, size, path, out);
    free(text);
    return s;
}

/* ---- Saving ---------------------------------------------------------------------------------- */

static int add_path(pen_context *ctx, cJSON *obj, const char *name, const char *json_path,
                    const char *target) {
    char *rel = pen__io_path_relative(ctx, json_path, target);
    int ok = rel && pen__json_add(obj, name, cJSON_CreateString(rel));
    free(rel);
    return ok;
}

/* lights[0 .. n) as a JSON array, added as `name` of o. Returns 0 on exhaustion. */
static int lights_array_json(const pen_light *lights, int n, const char *name, cJSON *o) {
    cJSON *arr = cJSON_CreateArray();
    int ok = pen__json_add(o, name, arr);
    for (int i = 0; ok && i < n; ++i) {
        const pen_light *l = &lights[i];
        cJSON *e = cJSON_CreateObject();
        if (!e || !cJSON_AddItemToArray(arr, e)) {
            cJSON_Delete(e);
            return 0;
        }
        ok = pen__json_add(e, "direction", pen__json_float_array(l->direction, 3)) &&
             pen__json_add(e, "angular_radius_deg", pen__json_float(l->angular_radius_deg)) &&
             pen__json_add(e, "irradiance", pen__json_float_array(l->irradiance, 3));
    }
    return ok;
}

/* lighting.lights as parse_lights reads it: GIVEN as the array, NONE as "none", AUTO as
 * {"max": K, "add": [the added lights]} (nothing when K is the default and none were added; the
 * found ones are found again on load, the same lights in the same order, since finding is
 * deterministic). Lights found in the map are written as an array with the added ones after them
 * when the coefficients are written (`sh_written`): a file with "sh" finds no lights on load, so
 * they would be lost. Returns 0 on exhaustion. */
static int lights_json(const pen_lighting *L, int sh_written, cJSON *o) {
    if (L->lights_mode == PEN_LIGHTS_NONE)
        return pen__json_add(o, "lights", cJSON_CreateString("none"));
    const int added = L->lights_mode == PEN_LIGHTS_AUTO ? L->lights_added : 0;
    const int found = L->lights_mode == PEN_LIGHTS_AUTO ? L->light_count - added : 0;
    if (L->lights_mode == PEN_LIGHTS_AUTO && !(sh_written && found > 0)) {
        if (L->lights_max == PEN_LIGHTS_DEFAULT_MAX && added == 0) return 1;
        cJSON *m = cJSON_CreateObject();
        return pen__json_add(o, "lights", m) &&
               pen__json_add(m, "max", cJSON_CreateNumber(L->lights_max)) &&
               (added == 0 || lights_array_json(L->lights + found, added, "add", m));
    }
    return lights_array_json(L->lights, L->light_count, "lights", o);
}

static cJSON *lighting_json(pen_context *ctx, const char *path, const pen_scene *sc,
                            unsigned flags) {
    const pen_lighting *L = &sc->lighting;
    cJSON *o = cJSON_CreateObject();
    int ok = o != NULL;
    int has_env = L->envmap.data && L->envmap_path;
    if (ok && has_env)
        ok = add_path(ctx, o, "envmap", path, L->envmap_path) &&
             pen__json_add(o, "scale", pen__json_float(L->scale)) &&
             pen__json_add(o, "rotation_y_deg", pen__json_float(L->rotation_y_deg));
    const int sh_written = !has_env || (flags & PEN_SCENE_SAVE_SH_LIGHTING);
    if (ok && sh_written) {
        cJSON *rows = cJSON_CreateArray();
        ok = pen__json_add(o, "sh", rows);
        for (int i = 0; ok && i < sc->sh_bands * sc->sh_bands; ++i)
            ok = cJSON_AddItemToArray(rows, pen__json_float_array(L->sh[i], 3));
    }
    if (ok) ok = lights_json(L, sh_written, o);
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

static cJSON *object_json(pen_context *ctx, const char *path, const pen_object *obj) {
    cJSON *o = cJSON_CreateObject();
    int ok = o && add_path(ctx, o, "mesh", path, obj->mesh_path);
    const int baked = obj->texture.data && obj->texture_layout == PEN_TEXTURE_LAYOUT_BAKED;
    if (ok && obj->texture.data && obj->texture_path)
        ok = add_path(ctx, o, "albedo_texture", path, obj->texture_path) &&
             (!baked || pen__json_add(o, "albedo_texture_layout", cJSON_CreateString("baked")));
    else if (ok && !baked) /* a baked atlas as baked: the mesh file says it all */
        ok = pen__json_add(o, "albedo", pen__json_float_array(obj->albedo, 3));
    if (ok && obj->texture.data && obj->texture_filter == PEN_TEXTURE_FILTER_POINT)
        ok = pen__json_add(o, "texture_filter", cJSON_CreateString("point"));
    if (ok && obj->spheres_path) {
        ok = add_path(ctx, o, "spheres", path, obj->spheres_path);
    } else if (ok && obj->spheres.count > 0) {
        ok = pen__json_add(o, "spheres", pen__spheres_to_json(&obj->spheres));
    } else if (ok && obj->fit_spheres > 0) {
        cJSON *fit = cJSON_CreateObject();
        ok = pen__json_add(o, "spheres", fit) &&
             pen__json_add(fit, "fit", cJSON_CreateNumber(obj->fit_spheres));
    }
    cJSON *pose = ok ? cJSON_CreateObject() : NULL;
    ok = ok && pen__json_add(o, "pose", pose) &&
         pen__json_add(pose, "rotation_axis_angle_deg",
                       pen__json_float_array(obj->pose.rotation_axis_angle_deg, 3)) &&
         pen__json_add(pose, "translation", pen__json_float_array(obj->pose.translation, 3)) &&
         pen__json_add(pose, "scale", pen__json_float(obj->pose.scale));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

/* What must hold for the written file to load again. */
static pen_status check_saveable(pen_context *ctx, const char *path, const pen_scene *sc) {
    const where wc = {path, "camera"};
    pen_status cs = pen__io_camera_check(ctx, &wc, &sc->camera);
    if (cs) return cs;
    if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: sh_bands %d outside [1, %d]", path,
                          sc->sh_bands, PEN_SH_MAX_BANDS);
    for (int i = 0; i < sc->sh_bands * sc->sh_bands; ++i)
        if (!pen__finite3(sc->lighting.sh[i]))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting coefficient %d is not finite",
                              path, i);
    if (sc->background_envmap && !sc->lighting.envmap.data)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: background shows an envmap but there is none", path);
    pen_status sl = pen__lights_validate(ctx, &sc->lighting, path);
    if (sl) return sl;
    for (int i = 0; i < sc->object_count; ++i) {
        const pen_object *o = &sc->objects[i];
        char what[64];
        snprintf(what, sizeof what, "%s: objects[%d]", path, i);
        if (!o->mesh_path)
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: no mesh path (save the mesh first)",
                              what);
        if (o->texture.data && !o->texture_path && o->texture_layout != PEN_TEXTURE_LAYOUT_BAKED)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: no texture path (save the texture first)", what);
        pen_status s = pen__spheres_check(ctx, what, &o->spheres);
        if (s) return s;
    }
    return PEN_OK;
}

static cJSON *shadow_json(const pen_shadow *sh) {
    cJSON *o = cJSON_CreateObject();
    int ok =
        o && pen__json_add(o, "epsilon", pen__json_float(sh->epsilon)) &&
        pen__json_add(o, "exp", cJSON_CreateString(pen_sh_exp_method_name(sh->exp))) &&
        pen__json_add(o, "overlap",
                      cJSON_CreateString(sh->overlap == PEN_OVERLAP_NONE ? "none" : "weights")) &&
        pen__json_add(
            o, "ground",
            cJSON_CreateString(sh->ground == PEN_GROUND_RECEIVER ? "receiver" : "occludes")) &&
        pen__json_add(o, "self",
                      cJSON_CreateString(sh->self == PEN_SELF_SPHERES ? "spheres" : "transfer")) &&
        pen__json_add(o, "ground_shadow",
                      cJSON_CreateString(sh->ground_shadow == PEN_GROUND_SHADOW_SPHERES
                                             ? "spheres"
                                             : "transfer"));
    if (ok && sh->ground_grid > 0) /* the renderer's default otherwise */
        ok = pen__json_add(o, "ground_grid", cJSON_CreateNumber(sh->ground_grid));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

static cJSON *objects_json(pen_context *ctx, const char *path, const pen_scene *sc) {
    cJSON *a = cJSON_CreateArray();
    int ok = a != NULL;
    for (int i = 0; ok && i < sc->object_count; ++i)
        ok = cJSON_AddItemToArray(a, object_json(ctx, path, &sc->objects[i]));
    if (!ok) cJSON_Delete(a);
    return ok ? a : NULL;
}

static cJSON *ground_json(const pen_ground *g) {
    if (!g->enabled) return cJSON_CreateNull();
    cJSON *o = cJSON_CreateObject();
    int ok = o && pen__json_add(o, "height", pen__json_float(g->height)) &&
             pen__json_add(o, "albedo", pen__json_float_array(g->albedo, 3)) &&
             pen__json_add(o, "half_size", pen__json_float(g->half_size));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

pen_status pen_scene_save_ex(pen_context *ctx, const char *path, const pen_scene *sc,
                             unsigned flags) {
    pen_status s = check_saveable(ctx, path, sc);
    if (s) return s;
    /* Each member is built inside its pen__json_add call, so nothing is left unowned on failure. */
    cJSON *root = cJSON_CreateObject();
    int ok = root && pen__json_add(root, "camera", pen__io_camera_json(&sc->camera)) &&
             pen__json_add(root, "lighting", lighting_json(ctx, path, sc, flags)) &&
             pen__json_add(root, "sh_bands", cJSON_CreateNumber(sc->sh_bands)) &&
             pen__json_add(root, "shadow", shadow_json(&sc->shadow)) &&
             pen__json_add(root, "objects", objects_json(ctx, path, sc)) &&
             pen__json_add(root, "ground", ground_json(&sc->ground)) &&
             pen__json_add(root, "background",
                           sc->background_envmap ? cJSON_CreateString("envmap")
                                                 : pen__json_float_array(sc->background, 3));
    char *text = ok ? cJSON_Print(root) : NULL;
    cJSON_Delete(root);
    if (!text) {
        if (pen_context_status(ctx) == PEN_ERROR_MEMORY) return PEN_ERROR_MEMORY;
        return pen__error(ctx, PEN_ERROR_MEMORY, "%s: cannot format the scene", path);
    }
    size_t n = strlen(text);
    text[n] = '\n'; /* the buffer has room: it held the NUL */
    s = pen__io_write_file(ctx, path, text, n + 1);
    cJSON_free(text);
    return s;
}

pen_status pen_scene_save(pen_context *ctx, const char *path, const pen_scene *scene) {
    return pen_scene_save_ex(ctx, path, scene, 0);
}
