/* Task JSON of `penumbra optimize` (docs/design.md sec. 3.5, docs/optimize.md): the initial scene,
 * the target image, the groups to optimise, the optimiser's settings and the ground truth.
 *
 * Like the scene loader it walks the JSON key by key so that every error is one line naming the
 * file and the key; unknown keys are errors (a misspelt "iteratoins" would otherwise silently
 * run the default), keys starting with '_' are comments. Scenes may be given as a path (relative
 * to the task file) or inline; an inline scene is parsed with the name "<task>:scene", so its
 * errors read "task.json:scene: camera.width: ..." and its relative paths resolve against the
 * task file's folder. */
#include "io/io_internal.h"
#include "optim/optim_internal.h"

#include <stdlib.h>
#include <string.h>

#define TASK_MAX_ITERATIONS 1000000
#define TASK_MAX_WINDOW 10000

typedef pen__json_where where;

static where at(const where *w, const char *name) {
    where c;
    pen__json_child(w, name, &c);
    return c;
}

pen_optim_lr pen_optim_lr_default(void) {
    pen_optim_lr lr;
    for (int k = 0; k < PEN__OPTIM_RATES; ++k)
        *pen__optim_rate_field(&lr, k) = pen__optim_rates[k].value;
    return lr;
}

pen_optim_deformation pen_optim_deformation_default(void) {
    pen_optim_deformation d = {4, 1e-4, 1e-3};
    return d;
}

pen_optim_spheres pen_optim_spheres_default(void) {
    pen_optim_spheres d = {4, 1e-3};
    return d;
}

pen_optim_task pen_optim_task_default(void) {
    pen_optim_task t;
    memset(&t, 0, sizeof t);
    t.iterations = 500;
    t.lr = pen_optim_lr_default();
    t.loss = pen__optim_losses[0].kind;
    t.tolerance = 1e-3;
    t.window = 50;
    t.init_black = 1;
    t.lighting_solver = PEN_OPTIM_LIGHTING_AUTO;
    t.lighting_ridge = (double)NAN; /* the solver's (optim.h) */
    t.deformation = pen_optim_deformation_default();
    t.spheres = pen_optim_spheres_default();
    t.light_count = 1;
    return t;
}

/* "scene" / "ground_truth": a path or an inline object. */
static pen_status parse_scene_ref(pen_context *ctx, const char *path, const where *top,
                                  const cJSON *root, const char *name, pen_scene *out) {
    where w = at(top, name);
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(root, name);
    if (cJSON_IsString(item)) {
        const char *rel = NULL;
        pen_status s = pen__json_string(ctx, &w, item, &rel);
        if (s) return s;
        char *full = pen__io_path_resolve(ctx, path, rel);
        if (!full) return PEN_ERROR_MEMORY;
        s = pen_scene_load(ctx, full, out);
        free(full);
        return s ? pen__json_wrap(ctx, s, &w) : PEN_OK;
    }
    if (cJSON_IsObject(item)) {
        char *text = cJSON_PrintUnformatted(item);
        if (!text) return pen__json_error(ctx, PEN_ERROR_MEMORY, &w, "cannot print the scene");
        size_t n = strlen(path) + strlen(name) + 2;
        char *inner = pen__malloc(ctx, n, 1, "scene name");
        pen_status s = PEN_ERROR_MEMORY;
        if (inner) {
            snprintf(inner, n, "%s:%s", path, name);
            s = pen_scene_parse(ctx, text, inner, out);
        }
        free(inner);
        cJSON_free(text);
        return s;
    }
    if (!item) return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "missing (expected a scene)");
    return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                           "expected a scene JSON path or an inline scene object, got %s",
                           pen__json_type_name(item));
}

/* pen_image_load_ex's flags for a target: 8-bit codes decoded from sRGB unless the task says
 * they are linear already (a PNG written from linear data, a normal-map-like capture). */
static unsigned target_flags(const pen_optim_task *t) {
    return t->target_linear ? PEN_IMAGE_LOAD_RAW : 0u;
}

pen_status pen_optim_task_set_target(pen_context *ctx, pen_optim_task *task, const char *path) {
    if (task->view_count > 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "\"%s\": the task has \"views\": a target replaces no view's image", path);
    pen_image img = {0, 0, 0, NULL};
    char *name = pen__io_strdup(ctx, path);
    pen_status s = name ? pen_image_load_ex(ctx, path, target_flags(task), &img)
                        : PEN_ERROR_MEMORY;
    const pen_camera *c = &task->scene.camera;
    if (!s && (img.width != c->width || img.height != c->height))
        s = pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: the image is %dx%d but the scene's camera is %dx%d",
                       path, img.width, img.height, c->width, c->height);
    /* radiance, bounded as a scene's is, so that the loss and the lighting solve stay finite
     * (views.c says why) */
    if (!s) s = pen__io_image_check_values(ctx, path, &img, PEN_SCENE_MAX_RADIANCE);
    if (s) {
        pen_image_free(&img);
        free(name);
        return s;
    }
    pen_image_free(&task->target);
    free(task->target_path);
    task->target = img;
    task->target_path = name;
    return PEN_OK;
}

static pen_status parse_target(pen_context *ctx, const char *path, const where *top,
                               const cJSON *root, pen_optim_task *t) {
    where w = at(top, "target");
    const char *rel = NULL;
    pen_status s = pen__json_string(ctx, &w, cJSON_GetObjectItemCaseSensitive(root, "target"),
                                    &rel);
    if (s) return s;
    char *full = pen__io_path_resolve(ctx, path, rel);
    if (!full) return PEN_ERROR_MEMORY;
    s = pen_optim_task_set_target(ctx, t, full);
    free(full);
    return s ? pen__json_wrap(ctx, s, &w) : PEN_OK;
}

/* The group of `groups` that `g` cannot be optimised with (groups.h: "excludes"), or NULL. */
static const pen__optim_group *excluded(const pen__optim_group *g, unsigned groups) {
    for (int k = 0; k < PEN__OPTIM_GROUPS; ++k)
        if ((g->excludes & pen__optim_groups[k].bit) && (groups & pen__optim_groups[k].bit))
            return &pen__optim_groups[k];
    return NULL;
}

static pen_status parse_groups(pen_context *ctx, const where *top, const cJSON *root,
                               unsigned *groups) {
    const char *names[PEN__OPTIM_GROUPS + 1];
    for (int k = 0; k < PEN__OPTIM_GROUPS; ++k)
        names[k] = pen__optim_groups[k].name;
    names[PEN__OPTIM_GROUPS] = NULL;
    where w = at(top, "optimize");
    const cJSON *a = cJSON_GetObjectItemCaseSensitive(root, "optimize");
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) == 0) {
        char list[256];
        pen__optim_group_list(~0u, 1, list, sizeof list);
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                               "expected a non-empty array of groups (%s), got %s", list,
                               a ? (cJSON_IsArray(a) ? "an empty array" : pen__json_type_name(a))
                                 : "nothing (missing key)");
    }
    *groups = 0;
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, a) {
        where wi;
        pen__json_index(&w, i++, &wi);
        int k = -1;
        pen_status s = pen__json_choice(ctx, &wi, e, "group", names, &k);
        if (s) return s;
        const pen__optim_group *g = &pen__optim_groups[k];
        if (*groups & g->bit)
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wi, "\"%s\" is listed twice", g->name);
        const pen__optim_group *other = excluded(g, *groups);
        if (other) { /* (named in the table's order) */
            const pen__optim_group *first = other < g ? other : g, *second = other < g ? g : other;
            return pen__json_error(ctx, PEN_ERROR_PARSE, &wi,
                                   "\"%s\" and \"%s\" both move %s: choose one", first->name,
                                   second->name, g->shares);
        }
        *groups |= g->bit;
    }
    return PEN_OK;
}

/* A learning rate at wk. */
static pen_status parse_rate(pen_context *ctx, const where *wk, const cJSON *e, double *v) {
    const char *what = "a positive learning rate (at most 10)";
    pen_status s = pen__json_number(ctx, wk, e, 0.0, 10.0, what, v);
    if (!s && *v <= 0.0) s = pen__json_error(ctx, PEN_ERROR_PARSE, wk, "expected %s", what);
    return s;
}

/* "lr": one number for every rate, or an object of rates by name (pen__optim_rates) and of
 * groups' keys (lr_key: "pose") setting every rate of their group, those after the rates. */
static pen_status parse_lr(pen_context *ctx, const where *top, const cJSON *root,
                           pen_optim_lr *lr) {
    where w = at(top, "lr");
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(root, "lr");
    if (!item) return PEN_OK;
    double v;
    if (cJSON_IsNumber(item)) {
        pen_status s = parse_rate(ctx, &w, item, &v);
        for (int k = 0; !s && k < PEN__OPTIM_RATES; ++k)
            *pen__optim_rate_field(lr, k) = (float)v;
        return s;
    }
    if (!cJSON_IsObject(item))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                               "expected a number or an object of per-group rates, got %s",
                               pen__json_type_name(item));
    const char *known[PEN__OPTIM_RATES + PEN__OPTIM_GROUPS + 1];
    int n = 0;
    for (int k = 0; k < PEN__OPTIM_RATES; ++k)
        known[n++] = pen__optim_rates[k].name;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (pen__optim_groups[g].lr_key) known[n++] = pen__optim_groups[g].lr_key;
    known[n] = NULL;
    pen_status s = pen__json_known_keys(ctx, &w, item, known);
    for (int k = 0; !s && k < PEN__OPTIM_RATES; ++k) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(item, pen__optim_rates[k].name);
        where wk = at(&w, pen__optim_rates[k].name);
        if (e && !(s = parse_rate(ctx, &wk, e, &v))) *pen__optim_rate_field(lr, k) = (float)v;
    }
    for (int g = 0; !s && g < PEN__OPTIM_GROUPS; ++g) {
        const pen__optim_group *G = &pen__optim_groups[g];
        const cJSON *e = G->lr_key ? cJSON_GetObjectItemCaseSensitive(item, G->lr_key) : NULL;
        where wk = at(&w, G->lr_key ? G->lr_key : "");
        if (!e || (s = parse_rate(ctx, &wk, e, &v))) continue;
        for (int k = 0; k < G->segment_count; ++k)
            *pen__optim_rate_field(lr, G->segments[k].rate) = (float)v;
    }
    return s;
}

/* An optional {"k": int, "<weight>": number, ...} member (a graph's neighbour count and weights):
 * keys[0] is "k", keys[1..] name weights[0..]. */
static pen_status parse_graph(pen_context *ctx, const where *top, const cJSON *root,
                              const char *name, const char *const keys[], int *k,
                              double *const weights[]) {
    const cJSON *e = cJSON_GetObjectItemCaseSensitive(root, name);
    if (!e) return PEN_OK;
    where w = at(top, name);
    if (!cJSON_IsObject(e))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &w, "expected an object, got %s",
                               pen__json_type_name(e));
    pen_status s = pen__json_known_keys(ctx, &w, e, keys);
    for (int i = 0; !s && keys[i]; ++i) {
        const cJSON *f = cJSON_GetObjectItemCaseSensitive(e, keys[i]);
        if (!f) continue;
        where wf = at(&w, keys[i]);
        s = i == 0 ? pen__json_int(ctx, &wf, f, 1, 32, "an integer in [1, 32]", k)
                   : pen__json_number(ctx, &wf, f, 0.0, 1e9, "a weight >= 0", weights[i - 1]);
    }
    return s;
}

static pen_status parse_options(pen_context *ctx, const where *top, const cJSON *root,
                                pen_optim_task *t) {
    const cJSON *e;
    pen_status s = PEN_OK;
    where w;
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "iterations"))) {
        w = at(top, "iterations");
        s = pen__json_int(ctx, &w, e, 1, TASK_MAX_ITERATIONS, "an integer in [1, 1000000]",
                          &t->iterations);
        if (s) return s;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "window"))) {
        w = at(top, "window");
        s = pen__json_int(ctx, &w, e, 1, TASK_MAX_WINDOW, "an integer in [1, 10000]", &t->window);
        if (s) return s;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "tolerance"))) {
        w = at(top, "tolerance");
        s = pen__json_number(ctx, &w, e, 0.0, 1.0, "a number in [0, 1]", &t->tolerance);
        if (s) return s;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "shadow_weight"))) {
        w = at(top, "shadow_weight");
        s = pen__json_number(ctx, &w, e, 0.0, 1e6, "a weight in [0, 1e6]", &t->shadow_weight);
        if (s) return s;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "light_count"))) {
        w = at(top, "light_count");
        s = pen__json_int(ctx, &w, e, 1, PEN_SCENE_MAX_LIGHTS, "an integer in [1, 16]",
                          &t->light_count);
        if (!s && !(t->optimize & PEN_OPTIM_LIGHTS))
            s = pen__json_error(ctx, PEN_ERROR_PARSE, &w,
                                "needs \"lights\" in optimize (it sets how many lights the "
                                "search creates)");
        if (s) return s;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "lighting_ridge"))) {
        w = at(top, "lighting_ridge");
        s = pen__json_number(ctx, &w, e, 0.0, 1e6, "a ridge in [0, 1e6]", &t->lighting_ridge);
        if (s) return s;
    }
    static const char *const encodings[] = {"srgb", "linear", NULL};
    static const char *const solvers[] = {"adam", "least_squares", "auto", NULL};
    static const char *const inits[] = {"black", "scene", "fit", NULL};
    int k = -1;
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "lighting_solver"))) {
        w = at(top, "lighting_solver");
        s = pen__json_choice(ctx, &w, e, "lighting solver", solvers, &k);
        if (s) return s;
        t->lighting_solver = k == 2   ? PEN_OPTIM_LIGHTING_AUTO
                             : k == 1 ? PEN_OPTIM_LIGHTING_LEAST_SQUARES
                                      : PEN_OPTIM_LIGHTING_ADAM;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "target_encoding"))) {
        w = at(top, "target_encoding");
        s = pen__json_choice(ctx, &w, e, "target encoding", encodings, &k);
        if (s) return s;
        t->target_linear = k == 1;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "loss"))) {
        w = at(top, "loss");
        const char *losses[PEN__OPTIM_LOSSES + 1];
        for (int i = 0; i < PEN__OPTIM_LOSSES; ++i)
            losses[i] = pen__optim_losses[i].name;
        losses[PEN__OPTIM_LOSSES] = NULL;
        s = pen__json_choice(ctx, &w, e, "loss", losses, &k);
        if (s) return s;
        t->loss = pen__optim_losses[k].kind;
    }
    if ((e = cJSON_GetObjectItemCaseSensitive(root, "init"))) {
        w = at(top, "init");
        s = pen__json_choice(ctx, &w, e, "initialisation", inits, &k);
        if (s) return s;
        t->init_black = k != 1;
        t->init_fit = k == 2;
    }
    static const char *const deform_keys[] = {"k", "w_rot", "w_reg", NULL};
    static const char *const sphere_keys[] = {"k", "w_smooth", NULL};
    double *const deform_w[] = {&t->deformation.w_rot, &t->deformation.w_reg};
    double *const sphere_w[] = {&t->spheres.w_smooth};
    s = parse_graph(ctx, top, root, "deformation", deform_keys, &t->deformation.k, deform_w);
    if (!s) s = parse_graph(ctx, top, root, "spheres", sphere_keys, &t->spheres.k, sphere_w);
    if (s) return s;
    return parse_lr(ctx, top, root, &t->lr);
}

/* Why view v takes no part in the objective (weight 0, or a mask without a pixel), or NULL. */
static const char *left_out(const pen_optim_view *v) {
    if (!(v->weight > 0.0)) return "weight 0";
    const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
    for (size_t p = 0; v->mask && p < pixels; ++p)
        if (v->mask[p] > 0.0f) return NULL;
    return v->mask ? "a mask without a pixel above 0.5" : NULL;
}

/* The exposure group's gauge, views[0] (optim.h: its exposure stays as given and the others are
 * recovered relative to it), must take part: a view left out of the objective ties its exposure
 * to nothing, so the others and the lighting would be determined only up to a common factor.
 * Refused rather than moved to another view, so that views[0] always means what the docs and
 * result.json's "exposure_fixed_view" say. */
static pen_status check_gauge(pen_context *ctx, const where *w, const pen_optim_task *t) {
    const char *why = t->view_count > 0 ? left_out(&t->views[0]) : NULL;
    if (!(t->optimize & PEN_OPTIM_EXPOSURE) || !why) return PEN_OK;
    return pen__json_error(ctx, PEN_ERROR_ARGUMENT, w,
                           "views[0] has %s, but with \"exposure\" its exposure is the fixed "
                           "gauge of the others: it must take part, or the exposures are not "
                           "determined (put a view that takes part first)",
                           why);
}

static pen_status parse_task(pen_context *ctx, const char *path, const cJSON *root,
                             const char *target, pen_optim_task *t) {
    where top = {path, ""};
    if (!cJSON_IsObject(root))
        return pen__json_error(ctx, PEN_ERROR_PARSE, &top, "expected a JSON object, got %s",
                               pen__json_type_name(root));
    static const char *const known[] = {"scene", "target",    "optimize", "iterations",
                                        "lr",    "loss",      "tolerance", "window",
                                        "init",  "deformation", "spheres", "ground_truth",
                                        "shadow_weight", "lighting_solver",
                                        "lighting_ridge", "light_count", "views",
                                        "validation_views", "target_encoding", NULL};
    pen_status s = pen__json_known_keys(ctx, &top, root, known);
    const cJSON *views = cJSON_GetObjectItemCaseSensitive(root, "views");
    const cJSON *validation = cJSON_GetObjectItemCaseSensitive(root, "validation_views");
    where wv = at(&top, "views"), wval = at(&top, "validation_views");
    if (!s && views && (target || cJSON_GetObjectItemCaseSensitive(root, "target")))
        s = pen__json_error(ctx, PEN_ERROR_PARSE, &wv,
                            "a task has either \"views\" or a \"target\", not both");
    if (!s) s = parse_groups(ctx, &top, root, &t->optimize);
    if (!s) s = parse_options(ctx, &top, root, t);
    if (!s) s = parse_scene_ref(ctx, path, &top, root, "scene", &t->scene);
    if (!s && views) {
        s = pen__optim_views_parse(ctx, path, &wv, views, target_flags(t), &t->views,
                                   &t->view_count);
        if (!s) s = check_gauge(ctx, &wv, t);
    } else if (!s && target) {
        s = pen_optim_task_set_target(ctx, t, target);
    } else if (!s) {
        s = parse_target(ctx, path, &top, root, t);
    }
    if (!s && validation)
        s = pen__optim_views_parse(ctx, path, &wval, validation, target_flags(t),
                                   &t->validation, &t->validation_count);
    if (!s && cJSON_GetObjectItemCaseSensitive(root, "ground_truth")) {
        s = parse_scene_ref(ctx, path, &top, root, "ground_truth", &t->ground_truth);
        t->has_ground_truth = s == PEN_OK;
    }
    return s;
}

static pen_status task_from_text(pen_context *ctx, const char *text, size_t size,
                                 const char *path, const char *target, pen_optim_task *out) {
    *out = pen_optim_task_default();
    cJSON *root = NULL;
    pen_status s = pen__json_parse(ctx, path, text, size, &root);
    if (s) return s;
    out->path = pen__io_strdup(ctx, path);
    s = out->path ? parse_task(ctx, path, root, target, out) : PEN_ERROR_MEMORY;
    cJSON_Delete(root);
    if (s) pen_optim_task_free(out);
    return s;
}

pen_status pen_optim_task_parse(pen_context *ctx, const char *json_text, const char *path,
                                pen_optim_task *out) {
    memset(out, 0, sizeof *out);
    if (!json_text) return pen__error(ctx, PEN_ERROR_ARGUMENT, "task: no JSON text");
    return task_from_text(ctx, json_text, strlen(json_text), path ? path : "task", NULL, out);
}

pen_status pen_optim_task_load(pen_context *ctx, const char *path, pen_optim_task *out) {
    return pen_optim_task_load_ex(ctx, path, NULL, out);
}

pen_status pen_optim_task_load_ex(pen_context *ctx, const char *path, const char *target,
                                  pen_optim_task *out) {
    memset(out, 0, sizeof *out);
    char *text = NULL;
    size_t size = 0;
    pen_status s = pen__io_read_file(ctx, path, (size_t)64 << 20, &text, &size);
    if (s) return s;
    s = task_from_text(ctx, text, size, path, target, out);
    free(text);
    return s;
}

void pen_optim_task_free(pen_optim_task *task) {
    if (!task) return;
    free(task->path);
    pen_scene_free(&task->scene);
    pen_image_free(&task->target);
    free(task->target_path);
    pen_scene_free(&task->ground_truth);
    pen__optim_views_free(task->views, task->view_count);
    pen__optim_views_free(task->validation, task->validation_count);
    memset(task, 0, sizeof *task);
}

/* ---- Checks before a run --------------------------------------------------------------------- */

/* Every group asked for must have something to move: ["spheres"] on a scene whose objects have
 * no spheres would otherwise run with zero parameters, change nothing and report success.
 * Called once the {"fit": N} sphere sets exist. */
pen_status pen__optim_task_check_groups(pen_context *ctx, const pen_optim_task *t) {
    const char *name = t->path ? t->path : "task";
    const pen_scene *sc = &t->scene;
    if ((t->optimize & PEN_OPTIM_LIGHTS) && sc->lighting.light_count == 0 &&
        (t->light_count < 1 || t->light_count > PEN_SCENE_MAX_LIGHTS))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: light_count: %d lights to search for, expected 1 .. %d", name,
                          t->light_count, PEN_SCENE_MAX_LIGHTS);
    long spheres = 0;
    for (int o = 0; o < sc->object_count; ++o)
        spheres += sc->objects[o].spheres.count;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g) {
        const pen__optim_group *G = &pen__optim_groups[g];
        if (!(t->optimize & G->bit)) continue;
        if ((G->needs & PEN__OPTIM_NEEDS_OBJECTS) && sc->object_count == 0)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: optimize: \"%s\": the scene has no objects, nothing to optimise",
                              name, G->name);
        if ((G->needs & PEN__OPTIM_NEEDS_SPHERES) && spheres == 0)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: optimize: \"%s\": no object of the scene has spheres, nothing "
                              "to optimise (give an object \"spheres\": a file, a list or "
                              "{\"fit\": N})",
                              name, G->name);
    }
    return PEN_OK;
}

/* The "exposure" group and the views' exposures (optim.h, pen_optim_view). */
static pen_status check_exposure(pen_context *ctx, const pen_optim_task *t) {
    const char *name = t->path ? t->path : "task";
    if ((t->optimize & PEN_OPTIM_EXPOSURE) && t->view_count < 2)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: optimize: \"exposure\" needs \"views\" with at least 2 views: "
                          "the first view's exposure is fixed (a common exposure is the lighting's "
                          "scale), so %s has none to move",
                          name, t->view_count ? "one view" : "a single-view task");
    const where w = {name, "views"};
    return check_gauge(ctx, &w, t);
}

pen_status pen__optim_task_check(pen_context *ctx, const pen_optim_task *t) {
    const char *name = t->path ? t->path : "task";
    pen_status s;
    int excluded_pair = 0;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        excluded_pair |= (t->optimize & pen__optim_groups[g].bit) &&
                         (t->optimize & pen__optim_groups[g].excludes);
    if (!t->optimize || (t->optimize & ~pen__optim_group_bits()) || excluded_pair)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: optimize: no group, an unknown one, or both spheres and "
                          "deformation",
                          name);
    if ((t->optimize & PEN_OPTIM_DEFORMATION) &&
        (t->deformation.k < 1 || !(t->deformation.w_rot >= 0.0) || !(t->deformation.w_reg >= 0.0)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: deformation: k must be positive, the weights >= 0", name);
    if ((t->optimize & PEN_OPTIM_SPHERES) &&
        (!(t->spheres.w_smooth >= 0.0) || !isfinite(t->spheres.w_smooth) ||
         (t->spheres.w_smooth > 0.0 && t->spheres.k < 1)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: spheres: k must be positive, w_smooth a finite number >= 0", name);
    if (t->view_count < 0 || t->view_count > PEN_CAMERA_SET_MAX || (t->view_count && !t->views) ||
        t->validation_count < 0 || t->validation_count > PEN_CAMERA_SET_MAX ||
        (t->validation_count && !t->validation))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: views: expected 0 .. %d views", name,
                          PEN_CAMERA_SET_MAX);
    for (int i = 0; i < t->view_count + t->validation_count; ++i) {
        const int val = i >= t->view_count;
        const pen_optim_view *v = val ? &t->validation[i - t->view_count] : &t->views[i];
        const char *key = val ? "validation_views" : "views";
        const int k = val ? i - t->view_count : i;
        if (pen_camera_validate(ctx, &v->camera))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: %s[%d].%s", name, key, k,
                              pen_context_error(ctx));
        if (!v->target.data || v->target.channels != 3 || v->target.width != v->camera.width ||
            v->target.height != v->camera.height)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: %s[%d].target: expected a 3-channel image of the camera's "
                              "size %dx%d",
                              name, key, k, v->camera.width, v->camera.height);
        if (!(v->weight >= 0.0) || !isfinite(v->weight))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: %s[%d].weight: expected a finite number >= 0", name, key, k);
        /* as a views file holds it (views.c; 0, a view zeroed in code, stands for 1: optim.h) */
        if (v->exposure != 0.0 && !(v->exposure >= PEN__OPTIM_MIN_EXPOSURE &&
                                    v->exposure <= PEN__OPTIM_MAX_EXPOSURE))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: %s[%d].exposure: expected an exposure in [1e-6, 1e6] (or 0, "
                              "which stands for 1), got %g",
                              name, key, k, v->exposure);
    }
    s = check_exposure(ctx, t);
    if (s) return s;
    if (t->view_count > 0 && t->target.data)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: views and a target: choose one", name);
    if (t->view_count == 0 &&
        (!t->target.data || t->target.channels != 3 || t->target.width != t->scene.camera.width ||
         t->target.height != t->scene.camera.height))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: target: expected a 3-channel image of the camera's size %dx%d",
                          name, t->scene.camera.width, t->scene.camera.height);
    if (t->iterations < 1 || t->window < 1 || !(t->tolerance >= 0.0))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: iterations and window must be positive, tolerance >= 0", name);
    if (!(t->shadow_weight >= 0.0) || !isfinite(t->shadow_weight))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: shadow_weight must be a finite number >= 0",
                          name);
    const pen__optim_loss_kind *loss = pen__optim_loss_find((int)t->loss);
    if (!loss)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: loss: unknown loss %d", name,
                          (int)t->loss);
    if (t->lighting_solver == PEN_OPTIM_LIGHTING_LEAST_SQUARES &&
        (!(t->optimize & PEN_OPTIM_LIGHTING) || !loss->least_squares))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: lighting_solver: \"least_squares\" needs \"lighting\" in optimize "
                          "and the l2 loss",
                          name);
    if (t->lighting_solver != PEN_OPTIM_LIGHTING_ADAM &&
        t->lighting_solver != PEN_OPTIM_LIGHTING_LEAST_SQUARES &&
        t->lighting_solver != PEN_OPTIM_LIGHTING_AUTO)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting_solver: unknown solver %d", name,
                          (int)t->lighting_solver);
    /* (NaN: the solver's default, optim.h) */
    if (!isnan(t->lighting_ridge) && (!(t->lighting_ridge >= 0.0) || !isfinite(t->lighting_ridge)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: lighting_ridge must be a finite number >= 0", name);
    for (int k = 0; k < PEN__OPTIM_RATES; ++k) {
        const float lr = pen__optim_rate_value(&t->lr, k);
        if (!(lr > 0.0f) || !isfinite(lr))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lr: rates must be positive", name);
    }
    return PEN_OK;
}
