/* Sphere sets: their JSON files
 *     {"spheres": [{"center": [x, y, z], "radius": r, "weight": k}, ...], "metrics": {...}, ...}
 * (or a bare array of sphere objects). Other top-level members are kept by writers and ignored
 * by the reader; inside a sphere object only "center", "radius", the optional overlap "weight"
 * (finite, >= 0; given for every sphere or for none) and "_comments" may appear. Values are
 * range-checked as the scene's are (penumbra/scene.h): centre coordinates within
 * +-PEN_SCENE_MAX_COORD, radius in [PEN_SCENE_MIN_RADIUS, PEN_SCENE_MAX_SIZE], weight at most
 * PEN_SCENE_MAX_WEIGHT. */
#include "io/io_internal.h"
#include "io/spheres_json.h"
#include "penumbra/io.h"
#include "penumbra/scene.h"

#include <stdlib.h>
#include <string.h>

pen_status pen__spheres_from_json(pen_context *ctx, const pen__json_where *w, const cJSON *list,
                                  pen_spheres *out) {
    memset(out, 0, sizeof *out);
    if (!cJSON_IsArray(list))
        return pen__json_error(ctx, PEN_ERROR_PARSE, w, "expected an array of spheres, got %s",
                               pen__json_type_name(list));
    pen_status s = pen_spheres_create(ctx, cJSON_GetArraySize(list), out);
    if (s) return s;
    static const char *const known[] = {"center", "radius", "weight", NULL};
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, list) {
        pen__json_where wi, wc, wr, ww;
        pen__json_index(w, i, &wi);
        pen__json_child(&wi, "center", &wc);
        pen__json_child(&wi, "radius", &wr);
        pen__json_child(&wi, "weight", &ww);
        double r = 0, k = 0;
        if (!cJSON_IsObject(e))
            s = pen__json_error(ctx, PEN_ERROR_PARSE, &wi, "expected a sphere object, got %s",
                                pen__json_type_name(e));
        if (!s) s = pen__json_known_keys(ctx, &wi, e, known);
        if (!s)
            s = pen__json_floats(ctx, &wc, cJSON_GetObjectItemCaseSensitive(e, "center"), 3,
                                 -PEN_SCENE_MAX_COORD, PEN_SCENE_MAX_COORD,
                                 out->data + 4 * (size_t)i);
        if (!s)
            s = pen__json_number(ctx, &wr, cJSON_GetObjectItemCaseSensitive(e, "radius"),
                                 PEN_SCENE_MIN_RADIUS, PEN_SCENE_MAX_SIZE,
                                 "a number in [1e-9, 1e6]", &r);
        /* Weights: all spheres or none, so that a partly weighted set is not silently mixed. */
        const cJSON *wt = cJSON_IsObject(e) ? cJSON_GetObjectItemCaseSensitive(e, "weight") : NULL;
        if (!s && i > 0 && (wt != NULL) != (out->weight != NULL))
            s = pen__json_error(ctx, PEN_ERROR_PARSE, wt ? &ww : &wi,
                                wt ? "a weight, but sphere 0 has none (give all or none)"
                                   : "missing weight (sphere 0 has one: give all or none)");
        if (!s && wt && !out->weight &&
            !(out->weight = pen__calloc(ctx, (size_t)out->count, sizeof(float), "weights")))
            s = PEN_ERROR_MEMORY;
        if (!s && wt)
            s = pen__json_number(ctx, &ww, wt, 0.0, PEN_SCENE_MAX_WEIGHT, "a number in [0, 1e6]",
                                 &k);
        if (s) {
            pen_spheres_free(out);
            return s;
        }
        out->data[4 * (size_t)i + 3] = (float)r;
        if (out->weight) out->weight[i] = (float)k;
        ++i;
    }
    return PEN_OK;
}

pen_status pen_spheres_load(pen_context *ctx, const char *path, pen_spheres *out) {
    memset(out, 0, sizeof *out);
    cJSON *root = NULL;
    pen_status s = pen__json_load(ctx, path, &root);
    if (s) return s;
    pen__json_where top = {.file = path, .key = ""}, w = top;
    const cJSON *list = root;
    if (cJSON_IsObject(root)) {
        list = cJSON_GetObjectItemCaseSensitive(root, "spheres");
        pen__json_child(&top, "spheres", &w);
        if (!list) s = pen__json_error(ctx, PEN_ERROR_PARSE, &w, "missing");
    }
    if (!s) s = pen__spheres_from_json(ctx, &w, list, out);
    cJSON_Delete(root);
    return s;
}

cJSON *pen__spheres_to_json(const pen_spheres *spheres) {
    cJSON *list = cJSON_CreateArray();
    for (int i = 0; list && i < spheres->count; ++i) {
        const float *d = spheres->data + 4 * (size_t)i;
        cJSON *o = cJSON_CreateObject();
        int ok =
            o && pen__json_add(o, "center", pen__json_float_array(d, 3)) &&
            pen__json_add(o, "radius", pen__json_float(d[3])) &&
            (!spheres->weight || pen__json_add(o, "weight", pen__json_float(spheres->weight[i])));
        if (!ok || !cJSON_AddItemToArray(list, o)) {
            cJSON_Delete(o);
            cJSON_Delete(list);
            return NULL;
        }
    }
    return list;
}

pen_status pen__spheres_check(pen_context *ctx, const char *what, const pen_spheres *spheres) {
    if (spheres->count < 0 || (spheres->count > 0 && !spheres->data))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: invalid sphere set", what);
    for (int i = 0; i < spheres->count; ++i) {
        const float *d = spheres->data + 4 * (size_t)i;
        if (!pen__finite3(d) || !isfinite(d[3]) || !(d[3] > 0.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: sphere %d has a non-finite center or a radius that is not a "
                              "positive number",
                              what, i);
        if (spheres->weight && !(isfinite(spheres->weight[i]) && spheres->weight[i] >= 0.0f))
            return pen__error(
                ctx, PEN_ERROR_ARGUMENT,
                "%s: sphere %d has an overlap weight that is not a finite number >= 0", what, i);
    }
    return PEN_OK;
}

pen_status pen_spheres_save(pen_context *ctx, const char *path, const pen_spheres *spheres,
                            const char *extra_json) {
    pen_status s = pen__spheres_check(ctx, path, spheres);
    if (s) return s;
    cJSON *extra = NULL;
    if (extra_json) {
        extra = cJSON_Parse(extra_json);
        if (!cJSON_IsObject(extra) || cJSON_GetObjectItemCaseSensitive(extra, "spheres")) {
            cJSON_Delete(extra);
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: extra_json must be a JSON object without a \"spheres\" member",
                              path);
        }
    }
    cJSON *root = cJSON_CreateObject();
    cJSON *list = pen__spheres_to_json(spheres);
    int ok = root && list && cJSON_AddItemToObject(root, "spheres", list);
    if (!ok) cJSON_Delete(list);
    /* Move the extra members over, in order. */
    while (ok && extra && extra->child) {
        cJSON *m = cJSON_DetachItemViaPointer(extra, extra->child);
        ok = cJSON_AddItemToObject(root, m->string, m);
        if (!ok) cJSON_Delete(m);
    }
    cJSON_Delete(extra);
    char *text = ok ? cJSON_Print(root) : NULL;
    cJSON_Delete(root);
    if (!text) return pen__error(ctx, PEN_ERROR_MEMORY, "%s: cannot format JSON", path);
    size_t n = strlen(text);
    text[n] = '\n'; /* overwrite the NUL: the buffer is not used as a string afterwards */
    s = pen__io_write_file(ctx, path, text, n + 1);
    cJSON_free(text);
    return s;
}
