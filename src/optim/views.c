/* Multi-view tasks (docs/optimize.md, "Several views"; docs/design.md sec. 3.5): one scene seen
 * by N calibrated cameras, each with its observed image, an optional pixel mask and a weight.
 *
 * The objective is E = sum_v w_v E_v, E_v the task's loss of view v (a mean over its mask's
 * pixels, weighted by the shadow weights when the task has them). A weighted sum rather than a
 * weighted mean, so that a view's weight is what it says and the gradient of E is exactly the
 * sum of the views' weighted gradients; the regularisers keep their own scale, so with many views
 * they count relatively less (as they would with a larger image). A view whose weight is 0 or
 * whose mask holds no pixel contributes nothing and is not even rendered in the loop.
 *
 * Determinism: each view has its own render state (kept across iterations: a view's
 * antialiasing adjacency and background do not change); its loss w_v E_v and its gradient are
 * computed alone into buffers of their own (view_fwd, view_bwd: the one place a view's share is
 * made), by whichever worker or rank (parallel.c), and summed afterwards in the task's view
 * order. So the result is bitwise the same for any thread count, views at once or split across
 * MPI ranks.
 *
 * Exposure (optim.h, pen_optim_view): a view's render is multiplied by its exposure s before the
 * loss; the backward turns dE/dJ (J = s I) into dE/dI = s dE/dJ and dE/d(log s) = sum_p dE/dJ J,
 * which params.c gathers for the "exposure" group. The latter is made in the forward (view_fwd,
 * from the loss's image gradient) and travels with the view's loss (pen__optim_view_share),
 * gathered across ranks like it, so an exposure's step is the same on every rank. The fits of the
 * lighting (least squares, "init": "fit", the shadow masks) see w (s I - T)^2 as s^2 w (I - T/s)^2:
 * the target T/s with the factor times s^2. At s = 1 nothing is multiplied or divided, so views
 * without exposures are bitwise as before.
 *
 * The least-squares lighting ("lighting_solver": "least_squares", "init": "fit") sees every view:
 * its normal equations sum the views' with factor w_v / sum_p m_vp (loss.c), the same weighting
 * as E, so the solve minimises the objective the loop reports. */
#include "optim/optim_internal.h"
#include "render/render_internal.h"
#include "scene/validate.h"

#include "penumbra/metrics.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef pen__json_where where;

/* What a view's numbers may be, so that none overflows in the run. A target is radiance, held to
 * the bound of every radiance a scene holds (PEN_SCENE_MAX_RADIANCE: its map, its background;
 * pen_optim_task_set_target holds a single target to it too): its squares and the least-squares
 * lighting that explains it stay far inside float (a 3e38 target made the solved SH
 * coefficients infinite). An exposure is in [PEN__OPTIM_MIN_EXPOSURE, PEN__OPTIM_MAX_EXPOSURE]
 * (optim_internal.h says why). */

/* ---- Parsing --------------------------------------------------------------------------------- */

/* An image of the camera's size at `rel` (relative to base), into *img and *name; flags as
 * pen_image_load_ex's (a target: 0, 8-bit files decoded from sRGB, or RAW for "target_encoding":
 * "linear"; a mask: RAW). */
static pen_status load_image(pen_context *ctx, const where *w, const char *base, const char *rel,
                             const pen_camera *cam, unsigned flags, pen_image *img, char **name) {
    *name = pen__io_path_resolve(ctx, base, rel);
    if (!*name) return PEN_ERROR_MEMORY;
    pen_status s = pen_image_load_ex(ctx, *name, flags, img);
    if (s) return pen__json_wrap(ctx, s, w);
    if (img->width != cam->width || img->height != cam->height)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w,
                               "%s: the image is %dx%d but the view's camera is %dx%d", rel,
                               img->width, img->height, cam->width, cam->height);
    return PEN_OK;
}

static pen_status parse_view(pen_context *ctx, const char *base, const where *w, const cJSON *o,
                             unsigned target_flags, pen_optim_view *v) {
    static const char *const known[] = {"camera", "target", "mask", "weight", "exposure", NULL};
    where wc, wt, wm, ww, we;
    pen__json_child(w, "camera", &wc);
    pen__json_child(w, "target", &wt);
    pen__json_child(w, "mask", &wm);
    pen__json_child(w, "weight", &ww);
    pen__json_child(w, "exposure", &we);
    v->weight = 1.0;
    v->exposure = 1.0;
    pen_status s = pen__json_need_object(ctx, w, o);
    if (!s) s = pen__json_known_keys(ctx, w, o, known);
    if (!s) s = pen__io_camera_parse(ctx, &wc, pen__json_member(o, "camera"), &v->camera);
    const char *rel = NULL;
    if (!s) s = pen__json_string(ctx, &wt, pen__json_member(o, "target"), &rel);
    if (!s)
        s = load_image(ctx, &wt, base, rel, &v->camera, target_flags, &v->target,
                       &v->target_path);
    if (!s && pen__io_image_check_values(ctx, rel, &v->target, PEN_SCENE_MAX_RADIANCE))
        s = pen__json_wrap(ctx, PEN_ERROR_PARSE, &wt);
    const cJSON *m = pen__json_member(o, "mask");
    if (!s && m) {
        pen_image mask = {0, 0, 0, NULL};
        s = pen__json_string(ctx, &wm, m, &rel);
        if (!s)
            s = load_image(ctx, &wm, base, rel, &v->camera, PEN_IMAGE_LOAD_RAW, &mask,
                           &v->mask_path);
        const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
        if (!s && !(v->mask = pen__malloc(ctx, pixels, sizeof(float), "mask")))
            s = PEN_ERROR_MEMORY;
        for (size_t p = 0; !s && p < pixels; ++p) { /* a pixel counts above 0.5 */
            const float *c = mask.data + 3 * p;
            v->mask[p] = (c[0] + c[1] + c[2]) / 3.0f > 0.5f ? 1.0f : 0.0f;
        }
        pen_image_free(&mask);
    }
    const cJSON *e = pen__json_member(o, "weight");
    if (!s && e) s = pen__json_number(ctx, &ww, e, 0.0, 1e6, "a weight in [0, 1e6]", &v->weight);
    const cJSON *x = pen__json_member(o, "exposure");
    if (!s && x)
        s = pen__json_number(ctx, &we, x, PEN__OPTIM_MIN_EXPOSURE, PEN__OPTIM_MAX_EXPOSURE,
                             "an exposure in [1e-6, 1e6]", &v->exposure);
    return s;
}

/* The array of views at w (paths relative to base). */
static pen_status parse_array(pen_context *ctx, const char *base, const where *w, const cJSON *a,
                              unsigned target_flags, pen_optim_view **views, int *count) {
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) < 1 ||
        cJSON_GetArraySize(a) > PEN_CAMERA_SET_MAX)
        return pen__json_error(ctx, PEN_ERROR_PARSE, w,
                               "expected an array of 1 .. %d views (or a views file), got %s",
                               PEN_CAMERA_SET_MAX,
                               cJSON_IsArray(a) ? "an array of another length"
                                                : pen__json_type_name(a));
    const int n = cJSON_GetArraySize(a);
    *views = pen__calloc(ctx, (size_t)n, sizeof **views, "views");
    if (!*views) return PEN_ERROR_MEMORY;
    int i = 0;
    const cJSON *o;
    pen_status s = PEN_OK;
    cJSON_ArrayForEach(o, a) {
        where wi;
        pen__json_index(w, i, &wi);
        *count = ++i; /* (freed with the rest on failure) */
        s = parse_view(ctx, base, &wi, o, target_flags, &(*views)[i - 1]);
        if (s) break;
    }
    return s;
}

pen_status pen__optim_views_parse(pen_context *ctx, const char *task_path, const where *w,
                                  const cJSON *item, unsigned target_flags,
                                  pen_optim_view **views, int *count) {
    *views = NULL;
    *count = 0;
    if (!cJSON_IsString(item))
        return parse_array(ctx, task_path, w, item, target_flags, views, count);
    char *file = pen__io_path_resolve(ctx, task_path, item->valuestring);
    if (!file) return PEN_ERROR_MEMORY;
    cJSON *root = NULL;
    static const char *const known[] = {"views", NULL};
    where top = {file, ""}, wv;
    pen__json_child(&top, "views", &wv);
    pen_status s = pen__json_load(ctx, file, &root);
    if (!s) s = pen__json_need_object(ctx, &top, root);
    if (!s) s = pen__json_known_keys(ctx, &top, root, known);
    if (!s) s = parse_array(ctx, file, &wv, pen__json_member(root, "views"), target_flags, views,
                            count);
    cJSON_Delete(root);
    free(file);
    return s ? pen__json_wrap(ctx, s, w) : PEN_OK;
}

void pen__optim_views_free(pen_optim_view *views, int count) {
    for (int i = 0; views && i < count; ++i) {
        pen_image_free(&views[i].target);
        free(views[i].target_path);
        free(views[i].mask);
        free(views[i].mask_path);
    }
    free(views);
}

uint64_t pen__optim_views_hash(const pen_optim_view *views, int count) {
    uint64_t h = pen__fnv1a(PEN__FNV1A_SEED, &count, sizeof count);
    for (int i = 0; i < count; ++i) {
        const pen_optim_view *v = &views[i];
        const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
        h = pen__fnv1a(h, &v->camera, sizeof v->camera); /* ints and floats: no padding */
        h = pen__fnv1a(h, &v->weight, sizeof v->weight);
        h = pen__fnv1a(h, v->target.data, 3 * pixels * sizeof(float));
        if (v->mask) h = pen__fnv1a(h, v->mask, pixels * sizeof(float));
        /* (only when given: the checkpoints of tasks without exposures keep their identity) */
        const double x = pen__optim_exposure(v);
        if (x != 1.0) h = pen__fnv1a(h, &x, sizeof x);
    }
    return h;
}

/* ---- The objective over the views ------------------------------------------------------------ */

void pen__optim_view_expose(pen_image *img, double exposure) {
    if (exposure == 1.0) return; /* (the views without one stay bitwise as they were) */
    const float k = (float)exposure;
    const size_t n = 3 * (size_t)img->width * (size_t)img->height;
    for (size_t i = 0; i < n; ++i)
        img->data[i] *= k;
}

pen_status pen__optim_view_eye(pen_context *ctx, const pen_optim_view *v, double factor,
                               pen_image *scratch, pen__optim_eye *e) {
    const double x = pen__optim_exposure(v);
    *e = (pen__optim_eye){&v->camera, &v->target, v->mask, factor, NULL};
    if (x == 1.0) return PEN_OK;
    if (!scratch->data) {
        pen_status s = pen_image_create(ctx, v->target.width, v->target.height, 3, scratch);
        if (s) return s;
    }
    const size_t n = 3 * (size_t)v->target.width * (size_t)v->target.height;
    for (size_t i = 0; i < n; ++i)
        scratch->data[i] = (float)((double)v->target.data[i] / x);
    e->target = scratch;
    e->factor = factor * x * x;
    return PEN_OK;
}

/* The exposure's part of a view's backward: J = s I is the image the loss saw and d = dE/dJ;
 * dE/d(log s) = sum_p d_p J_p (in pixel order, double), and the render's gradient is
 * dE/dI = s d, written over d. */
static void expose_bwd(const pen_image *exposed, double exposure, pen_image *d, double *d_log) {
    const size_t n = 3 * (size_t)d->width * (size_t)d->height;
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i)
        sum += (double)d->data[i] * (double)exposed->data[i];
    *d_log = sum;
    if (exposure == 1.0) return;
    const float k = (float)exposure;
    for (size_t i = 0; i < n; ++i)
        d->data[i] *= k;
}

void pen__optim_views_free_run(pen__optim_views *V) {
    for (int i = 0; i < V->count; ++i) {
        if (V->state) pen_render_state_free(V->state[i]);
        if (V->solve_state) pen_render_state_free(V->solve_state[i]);
        if (V->weight) free(V->weight[i]);
        if (V->img) pen_image_free(&V->img[i]);
        if (V->d_img) pen_image_free(&V->d_img[i]);
        if (V->eye_target) pen_image_free(&V->eye_target[i]);
    }
    pen__optim_workers_free(&V->workers);
    free(V->order);
    free(V->loss);
    free(V->grads);
    free(V->state);
    free(V->solve_state);
    free(V->weight);
    free(V->factor);
    free(V->img);
    free(V->d_img);
    free(V->d_exposure);
    free(V->eye_target);
    memset(V, 0, sizeof *V);
}

pen_status pen__optim_views_init(pen_context *ctx, pen__optim_views *V, const pen_optim_task *t,
                                 double shadow_weight, int fit_lighting) {
    const int n = t->view_count;
    memset(V, 0, sizeof *V);
    V->count = n;
    V->views = t->views;
    V->state = pen__calloc(ctx, (size_t)n, sizeof *V->state, "views");
    V->solve_state = pen__calloc(ctx, (size_t)n, sizeof *V->solve_state, "views");
    V->weight = pen__calloc(ctx, (size_t)n, sizeof *V->weight, "views");
    V->factor = pen__calloc(ctx, (size_t)n, sizeof *V->factor, "views");
    V->img = pen__calloc(ctx, (size_t)n, sizeof *V->img, "views");
    V->d_img = pen__calloc(ctx, (size_t)n, sizeof *V->d_img, "views");
    V->d_exposure = pen__calloc(ctx, (size_t)n, sizeof *V->d_exposure, "views");
    V->eye_target = pen__calloc(ctx, (size_t)n, sizeof *V->eye_target, "views");
    pen_status s = V->state && V->solve_state && V->weight && V->factor && V->img && V->d_img &&
                           V->d_exposure && V->eye_target
                       ? PEN_OK
                       : PEN_ERROR_MEMORY;
    for (int i = 0; !s && i < n; ++i) {
        const pen_optim_view *v = &t->views[i];
        const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
        if (pixels > V->max_pixels) V->max_pixels = pixels;
        s = pen_render_state_create(ctx, &V->state[i]);
        if (!s) s = pen_render_state_create(ctx, &V->solve_state[i]);
        /* The views see one scene: the transfers are traced once per pose for all of them
         * (pen_render_state_share), not once per view. */
        if (!s && i > 0) s = pen_render_state_share(ctx, V->state[i], V->state[0]);
        if (!s) s = pen_render_state_share(ctx, V->solve_state[i], V->state[0]);
        if (!s) s = pen_image_create(ctx, v->camera.width, v->camera.height, 3, &V->d_img[i]);
        /* the target over the exposure, for the fits of the lighting (pen__optim_view_eye) */
        pen__optim_eye eye;
        if (!s && ((t->optimize & PEN_OPTIM_EXPOSURE) || pen__optim_exposure(v) != 1.0))
            s = pen_image_create(ctx, v->camera.width, v->camera.height, 3, &V->eye_target[i]);
        if (!s) s = pen__optim_view_eye(ctx, v, 1.0, &V->eye_target[i], &eye);
        if (s || (!v->mask && shadow_weight == 0.0)) {
            if (!s) V->factor[i] = v->weight / (double)pixels;
            continue;
        }
        float *w = V->weight[i] = pen__malloc(ctx, pixels, sizeof(float), "view weights");
        if (!w) s = PEN_ERROR_MEMORY;
        if (!s && shadow_weight > 0.0) { /* 1 + s m, m the view's shadow mask (loss.c) */
            const pen_scene vs = pen__optim_view_scene(&t->scene, &v->camera);
            s = pen__optim_shadow_mask(ctx, &vs, eye.target, fit_lighting, w);
            for (size_t p = 0; !s && p < pixels; ++p)
                w[p] = 1.0f + (float)shadow_weight * w[p];
        } else if (!s) {
            for (size_t p = 0; p < pixels; ++p)
                w[p] = 1.0f;
        }
        for (size_t p = 0; !s && v->mask && p < pixels; ++p)
            w[p] *= v->mask[p];
        const double sum = s ? 0.0 : pen__loss_weight_sum(w, pixels);
        V->factor[i] = sum > 0.0 ? v->weight / sum : 0.0; /* empty mask: the view is out */
    }
    V->taking_part = 0;
    for (int i = 0; !s && i < n; ++i)
        V->taking_part += V->factor[i] > 0.0;
    if (!s && V->taking_part == 0)
        s = pen__error(ctx, PEN_ERROR_ARGUMENT,
                       "%s: views: every view has weight 0 or an empty mask: nothing to fit",
                       t->path ? t->path : "task");
    return s;
}

int pen__optim_views_eyes(const pen__optim_views *V, int solve, pen__optim_eye *eyes) {
    int n = 0;
    for (int i = 0; i < V->count; ++i) {
        if (!(V->factor[i] > 0.0)) continue;
        pen__optim_eye *e = &eyes[n++];
        /* (cannot fail: the scratch image exists wherever an exposure may differ from 1) */
        pen__optim_view_eye(NULL, &V->views[i], V->factor[i], &V->eye_target[i], e);
        e->weight = V->weight[i];
        e->state = solve ? V->solve_state[i] : NULL;
    }
    return n;
}

/* What a pass gives every view's job. */
typedef struct pass {
    pen__optim_views *V;
    const pen_scene *sc;
    const pen_render_options *opt;
    pen_optim_loss kind;
    int grad;
} pass;

/* What the views' renders are vouched for (pen__render_fwd_vouched): the scene of a pass is
 * validated once before its views render, and no task edits the environment map's pixels. */
#define VOUCHED (PEN__VOUCH_VALID | PEN__VOUCH_MAP)

/* View order[j]'s image term: its render times the exposure, V->loss[j] (w_v E_v and, with
 * p->grad, its derivative in log s_v) and (with p->grad) its d_img. */
static pen_status view_fwd(pen_context *ctx, void *user, int j, pen_render_grad *unused) {
    (void)unused;
    const pass *p = user;
    pen__optim_views *V = p->V;
    const int i = V->order[j];
    const pen_optim_view *v = &V->views[i];
    const pen_scene vs = pen__optim_view_scene(p->sc, &v->camera);
    double e = 0.0;
    pen_status s =
        pen__render_fwd_vouched(ctx, &vs, p->opt, V->state[i], &V->img[i], VOUCHED);
    if (!s) pen__optim_view_expose(&V->img[i], pen__optim_exposure(v));
    if (!s) s = pen__optim_loss_fwd(ctx, p->kind, &V->img[i], &v->target, V->weight[i], &e);
    if (s) return s;
    V->loss[j] = (pen__optim_view_share){v->weight * e, 0.0};
    if (p->grad) {
        pen_image *d = &V->d_img[i];
        memset(d->data, 0, sizeof(float) * 3 * (size_t)d->width * (size_t)d->height);
        pen__optim_loss_bwd(p->kind, &V->img[i], &v->target, V->weight[i], v->weight, d);
        expose_bwd(&V->img[i], pen__optim_exposure(v), d, &V->loss[j].d_log_exposure);
    }
    return PEN_OK;
}

/* View order[j]'s gradient alone (g zeroed first), flattened into its vector. */
static pen_status view_bwd(pen_context *ctx, void *user, int j, pen_render_grad *g) {
    const pass *p = user;
    pen__optim_views *V = p->V;
    const int i = V->order[j];
    const pen_scene vs = pen__optim_view_scene(p->sc, &V->views[i].camera);
    pen_render_grad_zero(g);
    pen_status s = pen_render_bwd(ctx, &vs, p->opt, V->state[i], &V->d_img[i], V->wrt, g);
    return s ? s : pen__optim_grad_pack(ctx, g, V->wrt, V->grads + (size_t)j * V->grad_floats);
}

pen_status pen__optim_views_plan(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                 const pen_optim_settings *set, unsigned wrt) {
    V->order = pen__calloc(ctx, (size_t)V->count, sizeof *V->order, "views");
    V->loss = pen__calloc(ctx, (size_t)V->count, sizeof *V->loss, "views");
    if (!V->order || !V->loss) return PEN_ERROR_MEMORY;
    V->taking_part = 0;
    for (int i = 0; i < V->count; ++i)
        if (V->factor[i] > 0.0) V->order[V->taking_part++] = i;
    V->ranks = set->ranks && set->ranks->size > 1 ? set->ranks : NULL;
    V->lo = 0, V->hi = V->taking_part;
    if (V->ranks)
        pen__optim_block(V->taking_part, V->ranks->rank, V->ranks->size, &V->lo, &V->hi);
    V->wrt = wrt;
    pen_status s = pen__optim_workers_init(ctx, &V->workers, set->view_workers, V->hi - V->lo, sc);
    if (!s) s = pen__optim_grad_floats(ctx, &V->workers.grad[0], wrt, &V->grad_floats);
    if (!s && V->grad_floats > 0 &&
        !(V->grads = pen__calloc(ctx, (size_t)V->taking_part * V->grad_floats, sizeof(float),
                                 "view gradients")))
        s = PEN_ERROR_MEMORY;
    return s;
}

pen_status pen__optim_views_fwd(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                const pen_render_options *opt, pen_optim_loss kind, int grad,
                                double *loss) {
    pass p = {V, sc, opt, kind, grad};
    pen_status s = pen__scene_validate(ctx, sc, "render"); /* once for every view (VOUCHED) */
    if (!s) s = pen__optim_workers_run(ctx, &V->workers, V->lo, V->hi, view_fwd, &p);
    if (!s) s = pen__optim_exchange(ctx, V->ranks, V->taking_part, V->loss, sizeof *V->loss);
    if (s) return s;
    double sum = 0.0;
    for (int j = 0; j < V->taking_part; ++j) {
        sum += V->loss[j].loss;
        V->d_exposure[V->order[j]] = V->loss[j].d_log_exposure;
    }
    *loss = sum;
    return PEN_OK;
}

pen_status pen__optim_views_bwd(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                const pen_render_options *opt, pen_render_grad *grad) {
    if (V->grad_floats == 0) return PEN_OK; /* nothing differentiated */
    pass p = {V, sc, opt, PEN_OPTIM_LOSS_L2, 1}; /* (the loss kind: the forward's business) */
    pen_status s = pen__optim_workers_run(ctx, &V->workers, V->lo, V->hi, view_bwd, &p);
    if (!s)
        s = pen__optim_exchange(ctx, V->ranks, V->taking_part, V->grads,
                                sizeof(float) * V->grad_floats);
    for (int j = 0; !s && j < V->taking_part; ++j)
        s = pen__optim_grad_add(ctx, grad, V->wrt, V->grads + (size_t)j * V->grad_floats);
    return s;
}

/* ---- The recovered scene from each view ------------------------------------------------------ */

static pen_status views_finish(pen_context *ctx, const pen_scene *sc,
                               const pen_render_options *opt, pen_optim_loss kind,
                               const pen_optim_view *views, int count, pen_render_state *st,
                               pen_optim_view_metrics *metrics_, pen_image *finals, double sq[2]);

pen_status pen__optim_views_finish(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_options *opt, pen_optim_loss kind,
                                   const pen_optim_view *views, int count,
                                   pen_render_state *with, pen_optim_view_metrics **metrics,
                                   pen_image **finals, double sq[2]) {
    *metrics = pen__calloc(ctx, (size_t)count + 1, sizeof **metrics, "view metrics");
    *finals = pen__calloc(ctx, (size_t)count + 1, sizeof **finals, "view renders");
    if (!*metrics || !*finals) return PEN_ERROR_MEMORY;
    pen_render_state *st = NULL;
    pen_status s = pen_render_state_create(ctx, &st);
    if (!s && with) s = pen_render_state_share(ctx, st, with);
    if (!s) s = views_finish(ctx, sc, opt, kind, views, count, st, *metrics, *finals, sq);
    pen_render_state_free(st);
    return s;
}

static pen_status views_finish(pen_context *ctx, const pen_scene *sc,
                               const pen_render_options *opt, pen_optim_loss kind,
                               const pen_optim_view *views, int count, pen_render_state *st,
                               pen_optim_view_metrics *metrics_, pen_image *finals, double sq[2]) {
    pen_status s = pen__scene_validate(ctx, sc, "render"); /* once for every view (VOUCHED) */
    for (int i = 0; !s && i < count; ++i) {
        const pen_optim_view *v = &views[i];
        const pen_scene vs = pen__optim_view_scene(sc, &v->camera);
        pen_image *img = &finals[i];
        s = pen__render_fwd_vouched(ctx, &vs, opt, st, img, VOUCHED);
        if (s) return s;
        pen__optim_view_expose(img, pen__optim_exposure(v));
        const size_t pixels = (size_t)img->width * (size_t)img->height;
        double err = 0.0, ref = 0.0, counted = 0.0;
        for (size_t p = 0; p < pixels; ++p) { /* in pixel order, double */
            if (v->mask && v->mask[p] == 0.0f) continue;
            counted += 1.0;
            for (int c = 0; c < 3; ++c) {
                const double a = (double)img->data[3 * p + (size_t)c];
                const double b = (double)v->target.data[3 * p + (size_t)c];
                err += (a - b) * (a - b);
                ref += b * b;
            }
        }
        pen_optim_view_metrics *m = &metrics_[i];
        m->loss = m->rmse = m->rel_rmse = (double)NAN;
        if (counted > 0.0) {
            s = pen__optim_loss_fwd(ctx, kind, img, &v->target, v->mask, &m->loss);
            if (s) return s;
            m->rmse = sqrt(err / (3.0 * counted));
            m->rel_rmse = ref > 0.0 ? sqrt(err / ref) : (double)NAN;
        }
        if (sq && v->weight > 0.0) {
            sq[0] += err;
            sq[1] += 3.0 * counted;
        }
    }
    return s;
}
