/* The scene JSON's placement keys: an object's "units" and "pose": {"on_ground", "centre"}, and
 * "camera": {"frame"} (docs/file-formats.md, "Placing objects and the camera").
 *
 * They are read with the rest of the scene (src/io/scene.c) and resolved once the objects are
 * loaded into the numbers every other key gives: the pose's scale and translation, the camera's
 * eye, target and up. So a scene placed by the loader is an ordinary scene to everything after
 * it, pen_scene_save writes the numbers (an optimised pose stays as found), and the maths lives
 * once in src/scene/place.c. */
#include "io/scene_place.h"
#include "scene/place.h"

#include <stdlib.h>
#include <string.h>

typedef pen__json_where where;

/* An optional true or false (absent: false). */
static pen_status opt_bool(pen_context *ctx, const where *w, const cJSON *obj, const char *name,
                           int *out) {
    const cJSON *item = pen__json_member(obj, name);
    *out = cJSON_IsTrue(item);
    if (!item || cJSON_IsBool(item)) return PEN_OK;
    where wk;
    pen__json_child(w, name, &wk);
    return pen__json_error(ctx, PEN_ERROR_PARSE, &wk, "expected true or false, got %s",
                           pen__json_type_name(item));
}

pen_status pen__scene_pose_place_parse(pen_context *ctx, const where *w, const cJSON *o,
                                       unsigned char *flags) {
    int ground = 0, centre = 0;
    pen_status s = opt_bool(ctx, w, o, "on_ground", &ground);
    if (!s) s = opt_bool(ctx, w, o, "centre", &centre);
    *flags = (unsigned char)((ground ? PEN__PLACE_GROUND : 0) | (centre ? PEN__PLACE_CENTRE : 0));
    return s;
}

pen_status pen__scene_units_parse(pen_context *ctx, const where *w, const cJSON *o,
                                  pen_pose *pose) {
    static const char *const names[] = {"m", "cm", "mm", "km", "in", "ft", NULL};
    static const double metres[] = {1.0, 0.01, 0.001, 1000.0, 0.0254, 0.3048};
    const cJSON *item = pen__json_member(o, "units");
    if (!item) return PEN_OK;
    where wu;
    pen__json_child(w, "units", &wu);
    int k = 0;
    pen_status s = pen__json_choice(ctx, &wu, item, "unit", names, &k);
    if (s) return s;
    const double scale = (double)pose->scale * metres[k];
    if (!(scale >= PEN_SCENE_MIN_SIZE && scale <= PEN_SCENE_MAX_SIZE))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wu,
                               "\"%s\" with pose.scale %g gives the scale %g, outside [1e-6, 1e6]",
                               names[k], (double)pose->scale, scale);
    pose->scale = (float)scale;
    return PEN_OK;
}

/* The frame's settings: true, false or {"azimuth_deg", "elevation_deg", "margin"}. */
static pen_status frame_parse(pen_context *ctx, const where *wf, const cJSON *f,
                              pen__placement *pl) {
    pl->frame = !cJSON_IsFalse(f);
    if (cJSON_IsBool(f)) return PEN_OK;
    if (!cJSON_IsObject(f))
        return pen__json_error(ctx, PEN_ERROR_PARSE, wf,
                               "expected true, false or {\"azimuth_deg\", \"elevation_deg\", "
                               "\"margin\"}, got %s",
                               pen__json_type_name(f));
    static const char *const known[] = {"azimuth_deg", "elevation_deg", "margin", NULL};
    static const struct {
        double lo, hi;
        const char *what;
    } range[] = {{-360.0, 360.0, "a number of degrees in [-360, 360]"},
                 {-89.0, 89.0, "a number of degrees in [-89, 89]"},
                 {1.0, 100.0, "a number in [1, 100]"}};
    float *const value[] = {&pl->azimuth_deg, &pl->elevation_deg, &pl->margin};
    pen_status s = pen__json_known_keys(ctx, wf, f, known);
    for (int k = 0; !s && k < 3; ++k) {
        const cJSON *item = pen__json_member(f, known[k]);
        if (!item) continue;
        where wk;
        pen__json_child(wf, known[k], &wk);
        double v;
        s = pen__json_number(ctx, &wk, item, range[k].lo, range[k].hi, range[k].what, &v);
        if (!s) *value[k] = (float)v;
    }
    return s;
}

pen_status pen__scene_camera_parse(pen_context *ctx, const where *top, const cJSON *root,
                                   pen_camera *cam, pen__placement *pl) {
    where wc, wf;
    pen__json_child(top, "camera", &wc);
    pen__json_child(&wc, "frame", &wf);
    const cJSON *o = pen__json_member(root, "camera"), *f = pen__json_member(o, "frame");
    pl->azimuth_deg = 30.0f, pl->elevation_deg = 20.0f, pl->margin = 1.1f;
    if (!f) return pen__io_camera_parse(ctx, &wc, o, cam);
    pen_status s = frame_parse(ctx, &wf, f, pl);
    static const char *const placed[] = {"eye", "target", "up", "world_to_camera"};
    for (int k = 0; !s && pl->frame && k < 4; ++k)
        if (pen__json_member(o, placed[k]))
            s = pen__json_error(ctx, PEN_ERROR_PARSE, &wf,
                                "places the camera: leave out \"%s\" (or the frame)", placed[k]);
    if (s) return s;
    /* The rest of the camera as any camera reads it, with a stand-in eye and target that the
     * frame replaces once the objects are loaded. */
    cJSON *copy = cJSON_Duplicate(o, 1);
    int ok = copy != NULL;
    if (ok) cJSON_DeleteItemFromObjectCaseSensitive(copy, "frame");
    static const float eye[3] = {0.0f, 0.0f, 1.0f}, target[3] = {0.0f, 0.0f, 0.0f};
    if (ok && pl->frame)
        ok = pen__json_add(copy, "eye", pen__json_float_array(eye, 3)) &&
             pen__json_add(copy, "target", pen__json_float_array(target, 3));
    s = ok ? pen__io_camera_parse(ctx, &wc, copy, cam)
           : pen__error(ctx, PEN_ERROR_MEMORY, "%s: camera: out of memory", wc.file);
    cJSON_Delete(copy);
    return s;
}

pen_status pen__scene_place(pen_context *ctx, const where *top, pen_scene *sc,
                            const pen__placement *pl) {
    const double ground_y = sc->ground.enabled ? (double)sc->ground.height : 0.0;
    where wo, wi, wp, wc, wf;
    pen__json_child(top, "objects", &wo);
    for (int i = 0; pl->flags && i < sc->object_count; ++i) {
        const int f = pl->flags[i];
        if (!f || pen__object_place(&sc->objects[i], f & PEN__PLACE_GROUND, ground_y,
                                    f & PEN__PLACE_CENTRE))
            continue;
        pen__json_index(&wo, i, &wi);
        pen__json_child(&wi, "pose", &wp);
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wp,
                               "placed as asked, the translation would leave [-1e6, 1e6]");
    }
    if (!pl->frame) return PEN_OK;
    pen__json_child(top, "camera", &wc);
    pen__json_child(&wc, "frame", &wf);
    if (sc->object_count == 0)
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wf, "no object to frame");
    if (!pen__camera_frame_objects(&sc->camera, sc->objects, sc->object_count,
                                   (double)pl->azimuth_deg, (double)pl->elevation_deg,
                                   (double)pl->margin))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &wf,
                               "the objects cannot be framed: the eye would leave [-1e6, 1e6] or, "
                               "in float, equal the target (objects tiny against their distance "
                               "from the origin)");
    return PEN_OK;
}
