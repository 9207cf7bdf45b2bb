/* The outputs of `penumbra optimize`: result.json, the recovered scene, the final render, a
 * side-by-side picture and the loss curve (SVG and PNG).
 *
 * All or nothing: each file is written atomically (temporary file + rename) and the paths
 * written so far are remembered, with a second name (hard link) for a file of an earlier run that
 * a path held; if a later write fails the new files are removed and the earlier ones put back, so
 * a failed write leaves the folder as it found it. result.json is written last, so a folder
 * holding a result.json holds the whole set of that run.
 *
 * Pictures: compare.png shows target | initial | result | error side by side, all with one
 * exposure (1 / the 99th percentile of the target's largest channel when that exceeds 1, so HDR
 * targets are not clipped flat), the error panel being 4x the mean absolute difference over the
 * channels, in grey; its initial panel is the initial guess before any stage (a solve or a search
 * shows in the result). loss.svg and loss.png (the same layout, drawn as text and as pixels)
 * plot log10(loss) through the stages and the iterations; result.json lists the stages.
 *
 * A multi-view task (views.c) adds final_<i>.exr per view and validation_<i>.exr per held-back
 * view (the task's order), views.png (a small contact sheet, target | result | 4x error, a row a
 * view, each row at its target's exposure), views.json (the views file of the task's views
 * with their exposures as recovered: a later task's "views") and per-view metrics in
 * result.json; compare.png and final.exr show the first view. */
#define _POSIX_C_SOURCE 200809L
#include "io/io_internal.h"
#include "optim/optim_internal.h"

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

typedef struct outputs {
    const char *dir;
    char **written;
    char **kept; /* the earlier file's second name, NULL if the path was free */
    int count, cap;
} outputs;

char *pen__optim_join(pen_context *ctx, const char *dir, const char *name) {
    size_t n = strlen(dir) + strlen(name) + 2;
    char *p = pen__malloc(ctx, n, 1, "output path");
    if (p) snprintf(p, n, "%s/%s", dir, name);
    return p;
}

/* Called before writing `path` (taking ownership of it: freed on failure): remembers it, and
 * gives a file already there a second name "<path>.previous" so that it can be put back. */
static pen_status remember(pen_context *ctx, outputs *o, char *path) {
    if (o->count == o->cap) { /* (one final render per view: no fixed bound) */
        const int cap = o->cap ? 2 * o->cap : 64;
        char **w = realloc(o->written, (size_t)cap * sizeof *w);
        if (w) o->written = w;
        char **k = w ? realloc(o->kept, (size_t)cap * sizeof *k) : NULL;
        if (k) o->kept = k;
        if (!w || !k) {
            free(path);
            return pen__error(ctx, PEN_ERROR_MEMORY, "%s: out of memory", o->dir);
        }
        o->cap = cap;
    }
    char *kept = NULL;
    struct stat st;
    if (stat(path, &st) == 0) {
        const size_t n = strlen(path) + sizeof ".previous";
        kept = pen__malloc(ctx, n, 1, "output path");
        if (kept) snprintf(kept, n, "%s.previous", path);
        if (kept) remove(kept); /* a leftover of a crashed run */
        if (!kept || link(path, kept) != 0) {
            pen_status s = pen__error(ctx, PEN_ERROR_IO, "%s: cannot keep the earlier file: %s",
                                      path, strerror(errno));
            free(kept);
            free(path);
            return s;
        }
    }
    o->written[o->count] = path;
    o->kept[o->count++] = kept;
    return PEN_OK;
}

/* Success: drops the second names. Failure: removes the new files and puts the earlier back. */
static void outputs_finish(outputs *o, int failed) {
    for (int i = o->count - 1; i >= 0; --i) {
        if (o->kept[i] && failed)
            rename(o->kept[i], o->written[i]); /* atomic: the earlier file is back whole */
        else if (o->kept[i])
            remove(o->kept[i]);
        else if (failed)
            remove(o->written[i]);
        free(o->written[i]);
        free(o->kept[i]);
    }
    free(o->written);
    free(o->kept);
    o->written = o->kept = NULL;
    o->count = o->cap = 0;
}

static pen_status save_image(pen_context *ctx, outputs *o, const char *name, const pen_image *img) {
    char *path = pen__optim_join(ctx, o->dir, name);
    if (!path) return PEN_ERROR_MEMORY;
    pen_status s = remember(ctx, o, path);
    return s ? s : pen_image_save(ctx, path, img);
}

static pen_status save_text(pen_context *ctx, outputs *o, const char *name, const char *text) {
    char *path = pen__optim_join(ctx, o->dir, name);
    if (!path) return PEN_ERROR_MEMORY;
    pen_status s = remember(ctx, o, path);
    return s ? s : pen__io_write_file(ctx, path, text, strlen(text));
}

/* ---- The recovered scene --------------------------------------------------------------------- */

/* Optimised textures are written beside the scene; the scene is saved from a shallow copy whose
 * objects point at them, with SH lighting written inline and optimised spheres inline. An
 * unchanged baked atlas is not written (the scene names the mesh, whose materials bake it
 * again). */
static pen_status save_scene(pen_context *ctx, outputs *o, const pen_optim_task *t) {
    const pen_scene *sc = &t->scene;
    pen_scene copy = *sc;
    copy.objects = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *copy.objects, "scene");
    char **textures = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *textures, "names");
    pen_status s = copy.objects && textures ? PEN_OK : PEN_ERROR_MEMORY;
    char **meshes = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *meshes, "names");
    if (!meshes) s = PEN_ERROR_MEMORY;
    for (int i = 0; !s && i < sc->object_count; ++i) {
        copy.objects[i] = sc->objects[i];
        if (t->optimize & (PEN_OPTIM_SPHERES | PEN_OPTIM_DEFORMATION))
            copy.objects[i].spheres_path = NULL;
        if (t->optimize & PEN_OPTIM_DEFORMATION) { /* the deformed mesh, beside the scene */
            char name[64];
            snprintf(name, sizeof name, "mesh_%d.obj", i);
            char *path = pen__optim_join(ctx, o->dir, name);
            s = path ? remember(ctx, o, path) : PEN_ERROR_MEMORY;
            if (!s) s = pen_mesh_save_obj(ctx, path, &sc->objects[i].mesh);
            if (!s) meshes[i] = pen__io_strdup(ctx, o->written[o->count - 1]);
            if (!s && !meshes[i]) s = PEN_ERROR_MEMORY;
            if (s) break;
            copy.objects[i].mesh_path = meshes[i];
        }
        /* A baked atlas (several materials, vertex colours) is written when it changed, and
         * when the mesh was written: the written mesh carries the atlas UVs, not the materials
         * to bake again. As EXR: lossless, and vertex-colour blocks hold values outside [0, 1]
         * that a PNG would clip. */
        const int baked = sc->objects[i].texture_layout == PEN_TEXTURE_LAYOUT_BAKED;
        const int deformed = (t->optimize & PEN_OPTIM_DEFORMATION) != 0;
        const int changed = (t->optimize & PEN_OPTIM_ALBEDO) != 0;
        if (!sc->objects[i].texture.data || !(changed || (baked && deformed))) continue;
        if (baked && deformed) copy.objects[i].texture_layout = PEN_TEXTURE_LAYOUT_FILE;
        char name[64];
        snprintf(name, sizeof name, baked ? "texture_%d.exr" : "texture_%d.png", i);
        s = save_image(ctx, o, name, &sc->objects[i].texture);
        if (!s) {
            textures[i] = pen__io_strdup(ctx, o->written[o->count - 1]);
            if (!textures[i]) s = PEN_ERROR_MEMORY;
            copy.objects[i].texture_path = textures[i];
        }
    }
    char *path = s ? NULL : pen__optim_join(ctx, o->dir, "scene.json");
    if (!s && !path) s = PEN_ERROR_MEMORY;
    if (!s) s = remember(ctx, o, path);
    if (!s) s = pen_scene_save_ex(ctx, path, &copy, PEN_SCENE_SAVE_SH_LIGHTING);
    for (int i = 0; textures && i < sc->object_count; ++i)
        free(textures[i]);
    for (int i = 0; meshes && i < sc->object_count; ++i)
        free(meshes[i]);
    free(textures);
    free(meshes);
    free(copy.objects);
    return s;
}

/* ---- compare.png ----------------------------------------------------------------------------- */

static int cmp_float(const void *a, const void *b) {
    const float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static float exposure(pen_context *ctx, const pen_image *target) {
    const size_t n = (size_t)target->width * (size_t)target->height;
    float *v = pen__malloc(ctx, n, sizeof(float), "exposure");
    if (!v) return 1.0f; /* a picture with clipped highlights is still a picture */
    for (size_t i = 0; i < n; ++i) {
        const float *p = target->data + 3 * i;
        v[i] = fmaxf(p[0], fmaxf(p[1], p[2]));
    }
    qsort(v, n, sizeof(float), cmp_float);
    const float p99 = v[(size_t)(0.99 * (double)(n - 1))];
    free(v);
    return p99 > 1.0f ? 1.0f / p99 : 1.0f;
}

/* The image compare.png and result.json's size describe: the first view's in a multi-view task. */
static const pen_image *main_target(const pen_optim_task *t) {
    return t->view_count > 0 ? &t->views[0].target : &t->target;
}

static pen_status compare_picture(pen_context *ctx, const pen_optim_task *t,
                                  const pen_optim_result *r, pen_image *out) {
    const pen_image *target = main_target(t);
    const int w = target->width, h = target->height, gap = 4;
    pen_status s = pen_image_create(ctx, 4 * w + 3 * gap, h, 3, out);
    if (s) return s;
    for (size_t i = 0; i < (size_t)out->width * (size_t)out->height * 3; ++i)
        out->data[i] = 1.0f; /* white gaps */
    const float e = exposure(ctx, target);
    const pen_image *panels[3] = {target, &r->initial, &r->final};
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const size_t src = 3 * ((size_t)y * (size_t)w + (size_t)x);
            float err = 0.0f;
            for (int ch = 0; ch < 3; ++ch)
                err += fabsf(r->final.data[src + ch] - target->data[src + ch]) / 3.0f;
            for (int p = 0; p < 4; ++p) {
                float *dst =
                    out->data + 3 * ((size_t)y * (size_t)out->width + (size_t)(p * (w + gap) + x));
                for (int ch = 0; ch < 3; ++ch)
                    dst[ch] = p < 3 ? e * panels[p]->data[src + ch] : 4.0f * e * err;
            }
        }
    return PEN_OK;
}

/* ---- The contact sheet ----------------------------------------------------------------------- */

/* Nearest-neighbour scaling of one panel into the sheet at (x0, y0), size pw x ph. */
static void blit(pen_image *sheet, int x0, int y0, int pw, int ph, const pen_image *src,
                 const pen_image *err_of, float gain) {
    for (int y = 0; y < ph; ++y)
        for (int x = 0; x < pw; ++x) {
            const int sx = (int)(((long)x * src->width) / pw), sy = (int)(((long)y * src->height) / ph);
            const size_t i = 3 * ((size_t)sy * (size_t)src->width + (size_t)sx);
            float *d = sheet->data + 3 * ((size_t)(y0 + y) * (size_t)sheet->width + (size_t)(x0 + x));
            if (err_of) { /* 4x the mean absolute difference, grey */
                float e = 0.0f;
                for (int c = 0; c < 3; ++c)
                    e += fabsf(src->data[i + (size_t)c] - err_of->data[i + (size_t)c]) / 3.0f;
                d[0] = d[1] = d[2] = 4.0f * e * gain;
            } else {
                for (int c = 0; c < 3; ++c)
                    d[c] = src->data[i + (size_t)c] * gain;
            }
        }
}

static pen_status views_sheet(pen_context *ctx, const pen_optim_view *views, int count,
                                  const pen_image *finals, pen_image *sheet) {
    enum { PANEL = 96, GAP = 4, MAX_ROWS = 64 }; /* small: a look at every view, not a render */
    const int rows = count < MAX_ROWS ? count : MAX_ROWS;
    pen_status s = pen_image_create(ctx, 3 * PANEL + 2 * GAP, rows * PANEL + (rows - 1) * GAP, 3,
                                    sheet);
    if (s) return s;
    for (int i = 0; i < rows; ++i) {
        const pen_image *t = &views[i].target;
        const int big = t->width > t->height ? t->width : t->height;
        const int pw = t->width * PANEL / big > 0 ? t->width * PANEL / big : 1;
        const int ph = t->height * PANEL / big > 0 ? t->height * PANEL / big : 1;
        const float gain = exposure(ctx, t);
        const int y0 = i * (PANEL + GAP);
        blit(sheet, 0, y0, pw, ph, t, NULL, gain);
        blit(sheet, PANEL + GAP, y0, pw, ph, &finals[i], NULL, gain);
        blit(sheet, 2 * (PANEL + GAP), y0, pw, ph, &finals[i], t, gain);
    }
    return PEN_OK;
}

/* A metric, or null where it does not apply (NaN). */
static cJSON *number_or_null(double v) {
    return isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull();
}

/* The "views" (or "validation_views") array of result.json. */
static cJSON *views_json(const pen_optim_view *views, int count,
                             const pen_optim_view_metrics *m) {
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; a && i < count; ++i) {
        cJSON *o = cJSON_CreateObject();
        const char *target = views[i].target_path ? views[i].target_path : "";
        const int ok = o && pen__json_add(o, "target", cJSON_CreateString(target)) &&
                       pen__json_add(o, "weight", cJSON_CreateNumber(views[i].weight)) &&
                       pen__json_add(o, "exposure",
                                     cJSON_CreateNumber(pen__optim_exposure(&views[i]))) &&
                       pen__json_add(o, "loss", number_or_null(m[i].loss)) &&
                       pen__json_add(o, "image_rmse", number_or_null(m[i].rmse)) &&
                       pen__json_add(o, "image_rel_rmse", number_or_null(m[i].rel_rmse));
        if (!ok || !cJSON_AddItemToArray(a, o)) {
            cJSON_Delete(o);
            cJSON_Delete(a);
            return NULL;
        }
    }
    return a;
}

/* ---- result.json ----------------------------------------------------------------------------- */

/* A metric if it applies (finite); infinite values (a perfect PSNR) are written as null. */
static int add_metric(cJSON *m, const char *name, double v) {
    if (isnan(v)) return 1;
    return pen__json_add(m, name, isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull());
}

/* The groups' names in the table's order (groups.h). */
static cJSON *groups_json(unsigned groups) {
    cJSON *a = cJSON_CreateArray();
    for (int k = 0; a && k < PEN__OPTIM_GROUPS; ++k)
        if ((groups & pen__optim_groups[k].bit) &&
            !cJSON_AddItemToArray(a, cJSON_CreateString(pen__optim_groups[k].name))) {
            cJSON_Delete(a);
            return NULL;
        }
    return a;
}

static cJSON *metrics_json(const pen_optim_metrics *mt) {
    cJSON *m = cJSON_CreateObject();
    int ok = m && add_metric(m, "image_rmse", mt->image_rmse) &&
             add_metric(m, "lighting_rel_error", mt->lighting_rel_error) &&
             add_metric(m, "lighting_rel_error_bands_0_2", mt->lighting_rel_error_b2) &&
             add_metric(m, "lighting_rel_error_sky", mt->lighting_rel_error_sky) &&
             add_metric(m, "albedo_psnr_db", mt->albedo_psnr_db) &&
             add_metric(m, "albedo_shadow_psnr_db", mt->albedo_shadow_psnr_db) &&
             add_metric(m, "albedo_shadow_fraction", mt->albedo_shadow_fraction) &&
             add_metric(m, "albedo_texel_psnr_db", mt->albedo_texel_psnr_db) &&
             add_metric(m, "albedo_observed", mt->albedo_observed) &&
             add_metric(m, "rotation_error_deg", mt->rotation_error_deg) &&
             add_metric(m, "translation_error", mt->translation_error) &&
             add_metric(m, "translation_error_rel", mt->translation_error_rel) &&
             add_metric(m, "vertex_rmse", mt->vertex_rmse) &&
             add_metric(m, "sphere_iou", mt->sphere_iou) &&
             add_metric(m, "sphere_chamfer", mt->sphere_chamfer) &&
             add_metric(m, "shadow_iou", mt->shadow_iou) &&
             add_metric(m, "light_direction_error_deg", mt->light_direction_error_deg);
    if (!ok) cJSON_Delete(m);
    return ok ? m : NULL;
}

/* Every rate by its name in the task's "lr" (groups.h), in pen_optim_lr's order. */
static cJSON *lr_json(const pen_optim_lr *lr) {
    cJSON *o = cJSON_CreateObject();
    int ok = o != NULL;
    for (int k = 0; ok && k < PEN__OPTIM_RATES; ++k)
        ok = pen__json_add(o, pen__optim_rates[k].name,
                           pen__json_float(pen__optim_rate_value(lr, k)));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

/* {"k": k, names[0]: w[0], ...}: a regulariser's neighbour count and weights, as the task
 * JSON spells them. */
static cJSON *graph_json(int k, const char *const names[], const double *w, int n) {
    cJSON *o = cJSON_CreateObject();
    int ok = o && pen__json_add(o, "k", cJSON_CreateNumber(k));
    for (int i = 0; ok && i < n; ++i)
        ok = pen__json_add(o, names[i], cJSON_CreateNumber(w[i]));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

/* The lights' global search: how many it created, its renders and seconds. */
static cJSON *search_json(const pen_optim_result *r) {
    cJSON *o = cJSON_CreateObject();
    int ok = o && pen__json_add(o, "lights", cJSON_CreateNumber(r->lights_searched)) &&
             pen__json_add(o, "renders", cJSON_CreateNumber(r->search_renders)) &&
             pen__json_add(o, "seconds", cJSON_CreateNumber(r->search_seconds));
    if (!ok) cJSON_Delete(o);
    return ok ? o : NULL;
}

/* The objective before every stage (optim.h); a result made without stages starts at losses[0]. */
static double initial_loss(const pen_optim_result *r) {
    if (r->stage_count > 0) return r->initial_loss;
    return r->losses ? r->losses[0] : (double)NAN;
}

/* The "stages" array: each stage's name, its losses before and after, seconds and Adam steps. */
static cJSON *stages_json(const pen_optim_result *r) {
    cJSON *a = cJSON_CreateArray();
    for (int k = 0; a && k < r->stage_count && k < PEN_OPTIM_MAX_STAGES; ++k) {
        const pen_optim_stage *st = &r->stages[k];
        cJSON *o = cJSON_CreateObject();
        const char *name = st->name ? st->name : "";
        const int ok = o && pen__json_add(o, "name", cJSON_CreateString(name)) &&
                       pen__json_add(o, "loss_before", number_or_null(st->loss_before)) &&
                       pen__json_add(o, "loss_after", number_or_null(st->loss_after)) &&
                       pen__json_add(o, "seconds", cJSON_CreateNumber(st->seconds)) &&
                       pen__json_add(o, "iterations", cJSON_CreateNumber(st->iterations));
        if (!ok || !cJSON_AddItemToArray(a, o)) {
            cJSON_Delete(o);
            cJSON_Delete(a);
            return NULL;
        }
    }
    return a;
}

pen_status pen_optim_result_json(pen_context *ctx, const pen_optim_task *t,
                                 const pen_optim_settings *settings, const pen_optim_result *r,
                                 char **json) {
    *json = NULL;
    const int shadows = settings ? settings->shadows : 1;
    const int it = r->iterations;
    const pen__optim_loss_kind *loss = pen__optim_loss_find((int)t->loss);
    if (!loss) /* (never written as another: a reader would take it for that one) */
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "result.json: unknown loss %d", (int)t->loss);
    cJSON *root = cJSON_CreateObject();
    cJSON *losses = cJSON_CreateDoubleArray(r->losses, r->losses ? it + 1 : 0);
    static const char *const deform_names[] = {"w_rot", "w_reg"};
    static const char *const sphere_names[] = {"w_smooth"};
    const double deform_w[] = {t->deformation.w_rot, t->deformation.w_reg};
    int ok = root && pen__json_add(root, "task", cJSON_CreateString(t->path ? t->path : "")) &&
             pen__json_add(root, "optimize", groups_json(t->optimize)) &&
             pen__json_add(root, "shadows", cJSON_CreateBool(shadows)) &&
             pen__json_add(root, "loss", cJSON_CreateString(loss->name)) &&
             pen__json_add(root, "shadow_weight", cJSON_CreateNumber(t->shadow_weight)) &&
             /* the solver and ridge used ("auto" and the default resolved) */
             pen__json_add(root, "lighting_solver",
                           cJSON_CreateString(r->lighting_solver == PEN_OPTIM_LIGHTING_LEAST_SQUARES
                                                  ? "least_squares"
                                                  : "adam")) &&
             pen__json_add(root, "lighting_ridge", cJSON_CreateNumber(r->lighting_ridge)) &&
             pen__json_add(root, "iterations", cJSON_CreateNumber(it)) &&
             pen__json_add(root, "seconds", cJSON_CreateNumber(r->seconds)) &&
             /* the descent's own time per step: none without a step */
             pen__json_add(root, "seconds_per_iteration",
                           it > 0 ? cJSON_CreateNumber(r->seconds / it) : cJSON_CreateNull()) &&
             /* what the run was estimated to need before it started, and what it held */
             pen__json_add(root, "memory_estimate_bytes", cJSON_CreateNumber(r->memory_estimate)) &&
             pen__json_add(root, "memory_peak_bytes", cJSON_CreateNumber(r->memory_peak)) &&
             pen__json_add(root, "initial_loss", cJSON_CreateNumber(initial_loss(r))) &&
             pen__json_add(root, "final_loss", cJSON_CreateNumber(r->final_loss)) &&
             pen__json_add(root, "final_image_loss", cJSON_CreateNumber(r->final_image_loss)) &&
             pen__json_add(root, "final_ridge_loss", cJSON_CreateNumber(r->final_ridge_loss)) &&
             pen__json_add(root, "converged", cJSON_CreateBool(r->converged)) &&
             pen__json_add(root, "interrupted", cJSON_CreateBool(r->interrupted)) &&
             pen__json_add(root, "resumed_from", cJSON_CreateNumber(r->resumed_from)) &&
             pen__json_add(root, "metrics", metrics_json(&r->metrics)) &&
             pen__json_add(root, "lr", lr_json(&t->lr)) &&
             (!(t->optimize & PEN_OPTIM_DEFORMATION) ||
              pen__json_add(root, "deformation",
                            graph_json(t->deformation.k, deform_names, deform_w, 2))) &&
             (!(t->optimize & PEN_OPTIM_SPHERES) ||
              pen__json_add(root, "spheres",
                            graph_json(t->spheres.k, sphere_names, &t->spheres.w_smooth, 1))) &&
             (!r->lights_searched ||
              pen__json_add(root, "light_search", search_json(r))) &&
             pen__json_add(root, "tolerance", cJSON_CreateNumber(t->tolerance)) &&
             pen__json_add(root, "window", cJSON_CreateNumber(t->window)) &&
             pen__json_add(root, "width", cJSON_CreateNumber(main_target(t)->width)) &&
             pen__json_add(root, "height", cJSON_CreateNumber(main_target(t)->height)) &&
             pen__json_add(root, "stop_reason",
                           cJSON_CreateString(r->solved        ? "solved"
                                              : r->converged   ? "converged"
                                              : r->interrupted ? "interrupted"
                                                               : "iteration_limit")) &&
             /* the gauge of the exposures: the first view's stays as given (optim.h) */
             (!(t->optimize & PEN_OPTIM_EXPOSURE) ||
              pen__json_add(root, "exposure_fixed_view", cJSON_CreateNumber(0))) &&
             (!r->views ||
              pen__json_add(root, "views",
                            views_json(t->views, r->view_count, r->views))) &&
             (!r->validation ||
              pen__json_add(root, "validation_views",
                            views_json(t->validation, r->validation_count,
                                                  r->validation))) &&
             pen__json_add(root, "stages", stages_json(r)) &&
             pen__json_add(root, "losses", losses);
    char *text = ok ? cJSON_Print(root) : NULL;
    cJSON_Delete(root);
    if (!text) return pen__error(ctx, PEN_ERROR_MEMORY, "result.json: out of memory");
    size_t n = strlen(text);
    char *out = pen__malloc(ctx, n + 2, 1, "result.json");
    if (out) {
        memcpy(out, text, n);
        out[n] = '\n', out[n + 1] = '\0';
    }
    cJSON_free(text);
    *json = out;
    return out ? PEN_OK : PEN_ERROR_MEMORY;
}

/* ---- Everything ------------------------------------------------------------------------------ */

pen_status pen__optim_make_dir(pen_context *ctx, const char *dir) {
    struct stat st;
    if (stat(dir, &st) == 0) {
        if (S_ISDIR(st.st_mode)) return PEN_OK;
        return pen__error(ctx, PEN_ERROR_IO, "%s: exists and is not a folder", dir);
    }
    if (mkdir(dir, 0755) != 0)
        return pen__error(ctx, PEN_ERROR_IO, "%s: cannot create the folder: %s", dir,
                          strerror(errno));
    return PEN_OK;
}

/* A path of the task written relative to outdir/views.json into o[key] (absent: nothing). */
static int add_path(pen_context *ctx, cJSON *o, const char *key, const char *file,
                    const char *path) {
    if (!path) return 1;
    char *rel = pen__io_path_relative(ctx, file, path);
    const int ok = rel && pen__json_add(o, key, cJSON_CreateString(rel));
    free(rel);
    return ok;
}

/* views.json: the task's views as a views file (paths relative to the output folder) with each
 * view's exposure as recovered, so that a later task can start from them. */
static pen_status views_file(pen_context *ctx, outputs *o, const pen_optim_task *t) {
    char *file = pen__optim_join(ctx, o->dir, "views.json");
    cJSON *root = file ? cJSON_CreateObject() : NULL;
    cJSON *views = root ? cJSON_AddArrayToObject(root, "views") : NULL;
    int ok = views != NULL;
    for (int i = 0; ok && i < t->view_count; ++i) {
        const pen_optim_view *v = &t->views[i];
        cJSON *e = cJSON_CreateObject();
        ok = e && pen__json_add(e, "camera", pen__io_camera_json(&v->camera)) &&
             add_path(ctx, e, "target", file, v->target_path) &&
             add_path(ctx, e, "mask", file, v->mask_path) &&
             pen__json_add(e, "weight", cJSON_CreateNumber(v->weight)) &&
             pen__json_add(e, "exposure", cJSON_CreateNumber(pen__optim_exposure(v)));
        if (ok) ok = cJSON_AddItemToArray(views, e);
        else cJSON_Delete(e);
    }
    char *text = ok ? cJSON_Print(root) : NULL;
    cJSON_Delete(root);
    free(file);
    if (!text) return pen__error(ctx, PEN_ERROR_MEMORY, "views.json: out of memory");
    pen_status s = save_text(ctx, o, "views.json", text);
    cJSON_free(text);
    return s;
}

/* Multi-view and validation views: final_<i>.exr and validation_<i>.exr (the task's order),
 * views.png, the contact sheet of the views (views.c), and views.json, the views file. */
static pen_status view_outputs(pen_context *ctx, outputs *o, const pen_optim_task *t,
                               const pen_optim_result *r) {
    pen_status s = PEN_OK;
    char name[64];
    for (int i = 0; !s && r->view_finals && i < r->view_count; ++i) {
        snprintf(name, sizeof name, "final_%d.exr", i);
        s = save_image(ctx, o, name, &r->view_finals[i]);
    }
    for (int i = 0; !s && r->validation_finals && i < r->validation_count; ++i) {
        snprintf(name, sizeof name, "validation_%d.exr", i);
        s = save_image(ctx, o, name, &r->validation_finals[i]);
    }
    if (s || !r->view_finals) return s;
    pen_image sheet = {0, 0, 0, NULL};
    s = views_sheet(ctx, t->views, r->view_count, r->view_finals, &sheet);
    if (!s) s = save_image(ctx, o, "views.png", &sheet);
    pen_image_free(&sheet);
    if (!s) s = views_file(ctx, o, t);
    return s;
}

pen_status pen_optim_write(pen_context *ctx, const char *outdir, const pen_optim_task *task,
                           const pen_optim_settings *settings, const pen_optim_result *result) {
    if (!result->final.data || !result->initial.data || !result->losses)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: no result to write", outdir);
    const int shadows = settings ? settings->shadows : 1;
    pen_status s = pen__optim_make_dir(ctx, outdir);
    if (s) return s;
    outputs o;
    memset(&o, 0, sizeof o);
    o.dir = outdir;
    pen_image side = {0, 0, 0, NULL}, plot_image = {0, 0, 0, NULL};
    char *svg = NULL, *json = NULL;
    s = save_scene(ctx, &o, task);
    if (!s) s = save_image(ctx, &o, "final.exr", &result->final);
    if (!s) s = save_image(ctx, &o, "final.png", &result->final);
    if (!s) s = compare_picture(ctx, task, result, &side);
    if (!s) s = save_image(ctx, &o, "compare.png", &side);
    if (!s) s = view_outputs(ctx, &o, task, result);
    if (!s) s = pen__optim_loss_plots(ctx, result, shadows, &svg, &plot_image);
    if (!s) s = save_text(ctx, &o, "loss.svg", svg);
    if (!s) s = save_image(ctx, &o, "loss.png", &plot_image);
    if (!s) s = pen_optim_result_json(ctx, task, settings, result, &json);
    if (!s) s = save_text(ctx, &o, "result.json", json);
    outputs_finish(&o, s != PEN_OK);
    pen_image_free(&side);
    pen_image_free(&plot_image);
    free(svg);
    free(json);
    return s;
}
