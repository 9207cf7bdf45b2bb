/* The inverse-problem loop: render, compare with the target, back-propagate, take an Adam step.
 *
 * Every optimised quantity of the scene is copied into one flat float vector x, cut into
 * segments (the lighting; per object its texels or constant albedo, its rotation, its
 * translation, its spheres, its deformation graph's matrices and translations), each with its
 * learning rate and bound. One iteration writes x into the scene, solves the lighting when it is
 * solved by least squares rather than stepped (solve_lighting), renders (pen_render_fwd),
 * evaluates the loss against the target, runs pen_render_bwd for the groups being optimised
 * only, gathers the gradient (plus the regularisers') into the layout of x and steps. The
 * vector's layout, its copies to and from the scene and the gather are params.c. A task that
 * optimises "lights" on a scene without lights first has them created by the global search of
 * lights_search.c (descent cannot move a light whose shadow misses the observed one), after the
 * initial guesses, and the vector is laid out again to hold them.
 *
 * The loss is a mean over pixels and channels; its gradient is multiplied by that count before
 * Adam sees it (the gradient of the sum). Adam is invariant to the scale of the gradient except
 * through its epsilon (1e-8), which would otherwise dominate the tiny per-texel gradients of a
 * large image and slow textures down.
 *
 * Record keeping: losses[i] is the objective after i steps (the image loss plus the regularisers:
 * the deformation's, the spheres' smoothness, the lighting's ridge); the stopping rule looks at
 * them after each render, and when it fires no further step is taken. The parameters of the lowest objective
 * are kept (the best iterate) and rendered once more if they are not the last ones. The stages
 * before the first step (the lights' search, the "fit" lighting, the first least-squares solve)
 * move only the lighting: each is recorded with the lighting it started from, and the objective
 * there is measured just before the loop (stage_losses), so that the result's stages, its initial
 * loss and its initial render start from the initial guess, not from the descent's start. */
#include "optim/optim_internal.h"
#include "scene/validate.h"

#include "penumbra/fit.h"
#include "penumbra/metrics.h"
#include "penumbra/render.h"

#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

typedef pen__optim_run run;

pen_optim_settings pen_optim_settings_default(void) {
    pen_optim_settings s = {1, NULL, NULL, NULL, 0, 0, 0, 0, NULL, 0.0};
    return s;
}

/* ---- Least-squares lighting ----------------------------------------------------------------- */

/* The least-squares lighting for the current values of every other parameter into sh: one
 * system over every view (views.c) or the target's (optim.h; mu as there). */
static pen_status solve_into(pen_context *ctx, const pen_optim_task *t,
                             const pen_render_options *opt, run *r, float (*sh)[3]) {
    if (!r->multi)
        return pen__optim_solve_lighting(ctx, r->sc, opt, r->solve_state, &t->target, r->weight,
                                         r->ridge, r->mu, sh);
    pen__optim_eye *eyes = pen__calloc(ctx, (size_t)r->views.count, sizeof *eyes, "views");
    pen_status s = eyes ? pen__optim_solve_lighting_eyes(ctx, r->sc, opt, eyes,
                                                         pen__optim_views_eyes(&r->views, 1, eyes),
                                                         r->ridge, r->mu, sh)
                        : PEN_ERROR_MEMORY;
    free(eyes);
    return s;
}

/* With the least-squares lighting solver, makes the lighting in x and the scene the solution
 * for the current values of every other parameter, unless it already is (a lighting-only task
 * solves once). Adam never moves the lighting segment (its gradient is not computed, so it
 * stays 0 and so do Adam's steps there). */
static pen_status solve_lighting(pen_context *ctx, const pen_optim_task *t,
                                 const pen_render_options *opt, run *r) {
    if (!r->solve) return PEN_OK;
    const size_t nl = 3 * (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands;
    const size_t rest = r->n - nl; /* the lighting segment comes first (layout) */
    if (r->solved && memcmp(r->solved_for, r->x + nl, sizeof(float) * rest) == 0) return PEN_OK;
    pen_status s = solve_into(ctx, t, opt, r, r->sc->lighting.sh);
    if (s) return s;
    /* within what a scene file holds, as Adam's steps are: a 1e9 target on a ground of albedo
     * 1e-6 solves to coefficients of 3e14, which the written scene.json could not hold */
    pen__optim_lighting_take(r);
    memcpy(r->solved_for, r->x + nl, sizeof(float) * rest);
    r->solved = 1;
    return PEN_OK;
}

/* ---- The loop -------------------------------------------------------------------------------- */

/* The objective's image term and (with d_img) its gradient image. Without shadow weights the
 * plain means of render.h, with them the weighted mean of loss.c. */
static pen_status evaluate(pen_context *ctx, const pen_optim_task *t, const float *weight,
                           const pen_image *img, double *loss, pen_image *d_img) {
    if (d_img)
        memset(d_img->data, 0,
               sizeof(float) * (size_t)d_img->width * (size_t)d_img->height *
                   (size_t)d_img->channels);
    if (weight) {
        pen_status s = pen__optim_loss_fwd(ctx, t->loss, img, &t->target, weight, loss);
        if (!s && d_img) pen__optim_loss_bwd(t->loss, img, &t->target, weight, 1.0, d_img);
        return s;
    }
    const pen__optim_loss_kind *L = pen__optim_loss_find((int)t->loss);
    return L ? L->plain(ctx, img, &t->target, loss, d_img)
             : pen__error(ctx, PEN_ERROR_ARGUMENT, "loss: unknown loss %d", (int)t->loss);
}

/* ---- Checkpoints and snapshots --------------------------------------------------------------- */

/* What the checkpoints of this run belong to (see checkpoint.c). */
static pen__optim_identity identity(const pen_optim_task *t, const pen_optim_settings *set,
                                    const run *r) {
    pen__optim_identity id;
    memset(&id, 0, sizeof id);
    id.n = r->n;
    id.segments = r->segments;
    id.segment_count = r->segment_count;
    id.groups = r->groups;
    id.loss = (int)t->loss;
    id.shadows = set->shadows ? 1 : 0;
    id.width = t->target.width;
    id.height = t->target.height;
    id.shadow_weight = t->shadow_weight;
    id.lighting_solver = r->solve ? PEN_OPTIM_LIGHTING_LEAST_SQUARES : PEN_OPTIM_LIGHTING_ADAM;
    id.lighting_ridge = r->ridge; /* (both resolved: a checkpoint never holds "auto") */
    id.ridge_views = r->multi ? r->views.taking_part : 1;
    if (r->groups & PEN_OPTIM_DEFORMATION) {
        id.graph_k = t->deformation.k;
        id.weights[0] = t->deformation.w_rot, id.weights[1] = t->deformation.w_reg;
    } else if (r->groups & PEN_OPTIM_SPHERES) {
        id.graph_k = t->spheres.k;
        id.weights[0] = t->spheres.w_smooth;
    }
    id.target_hash = pen__fnv1a(PEN__FNV1A_SEED, t->target.data,
                                     sizeof(float) * 3 * (size_t)id.width * (size_t)id.height);
    if (r->multi) { /* the views stand for the target: cameras, images, masks, weights */
        id.width = t->views[0].camera.width;
        id.height = t->views[0].camera.height;
        id.target_hash = pen__optim_views_hash(t->views, t->view_count);
    }
    id.init_hash = pen__fnv1a(PEN__FNV1A_SEED, r->x, sizeof(float) * r->n);
    id.scene_hash = pen__optim_scene_hash(&t->scene, &r->opt);
    id.scene_hash = pen__fnv1a(id.scene_hash, &r->model_hash, sizeof r->model_hash);
    return id;
}

/* The files and folders this run created in OUTDIR (those that did not exist before it wrote
 * them), newest last: a run that fails removes them again, so that it leaves the folder as it
 * found it (snapshots of a failed run are not results). A finished or interrupted run keeps
 * them; files that existed before are never removed. */
typedef struct created {
    char **path;
    int count, cap;
} created;

static int exists(const char *path) {
    struct stat st;
    return stat(path, &st) == 0;
}

/* Records `path` (a copy) when it did not exist before (`existed`); best effort: a path that
 * cannot be recorded is only not removed. */
static void created_add(created *c, const char *path, int existed) {
    if (existed) return;
    if (c->count == c->cap) {
        const int cap = c->cap ? 2 * c->cap : 16;
        char **grown = realloc(c->path, (size_t)cap * sizeof *grown);
        if (!grown) return;
        c->path = grown;
        c->cap = cap;
    }
    const size_t n = strlen(path) + 1;
    char *copy = malloc(n);
    if (copy) c->path[c->count++] = memcpy(copy, path, n);
}

/* Removes (when `undo`) and forgets the recorded paths, newest first, so that folders are empty
 * when their turn comes (remove() deletes an empty folder; a folder holding older files stays). */
static void created_finish(created *c, int undo) {
    for (int i = c->count - 1; i >= 0; --i) {
        if (undo) remove(c->path[i]);
        free(c->path[i]);
    }
    free(c->path);
    memset(c, 0, sizeof *c);
}

/* pen__optim_make_dir, recording a folder it creates. */
static pen_status make_dir(pen_context *ctx, created *c, const char *dir) {
    const int existed = exists(dir);
    pen_status s = pen__optim_make_dir(ctx, dir);
    if (!s) created_add(c, dir, existed);
    return s;
}

static pen_status save_checkpoint(pen_context *ctx, const pen_optim_settings *set, created *c,
                                  const pen__optim_identity *id, const pen__optim_state *st) {
    pen_status s = make_dir(ctx, c, set->outdir);
    char *path = s ? NULL : pen__optim_join(ctx, set->outdir, "checkpoint.bin");
    if (!s && !path) s = PEN_ERROR_MEMORY;
    const int existed = path && exists(path);
    if (!s) s = pen__optim_checkpoint_save(ctx, path, id, st);
    if (!s) created_add(c, path, existed);
    free(path);
    return s;
}

/* OUTDIR/snapshots/iter_NNNNN.png: the render of the parameters after `iteration` steps. */
static pen_status save_snapshot(pen_context *ctx, const pen_optim_settings *set, created *c,
                                int iteration, const pen_image *img) {
    char name[64];
    snprintf(name, sizeof name, "snapshots/iter_%05d.png", iteration);
    char *dir = pen__optim_join(ctx, set->outdir, "snapshots"), *path = pen__optim_join(ctx, set->outdir, name);
    pen_status s = dir && path ? make_dir(ctx, c, set->outdir) : PEN_ERROR_MEMORY;
    if (!s) s = make_dir(ctx, c, dir);
    const int existed = path && exists(path);
    if (!s) s = pen_image_save(ctx, path, img);
    if (!s) created_add(c, path, existed);
    free(dir);
    free(path);
    return s;
}

/* ---- The loop -------------------------------------------------------------------------------- */

/* Resuming: the state after st->iteration steps replaces the initial guess. */
static pen_status resume(pen_context *ctx, const pen_optim_task *t, const pen_optim_settings *set,
                         const pen__optim_identity *id, run *r, pen__optim_state *st) {
    char *path = pen__optim_join(ctx, set->outdir, "checkpoint.bin");
    if (!path) return PEN_ERROR_MEMORY;
    pen_status s = pen__optim_checkpoint_load(ctx, path, id, t->iterations + 1, st);
    free(path);
    if (!s) pen__optim_transfer(r, 1);
    return s;
}

/* The objective's image term at the current parameters. Single view: the render into img (with
 * `state`) and the loss, with d_img also its gradient image; multi-view: every view's (views.c),
 * img untouched. */
static pen_status image_term(pen_context *ctx, const pen_optim_task *t, run *r,
                             pen_render_state *state, pen_image *img, double *loss,
                             pen_image *d_img) {
    if (r->multi)
        return pen__optim_views_fwd(ctx, &r->views, r->sc, &r->opt, t->loss, d_img != NULL, loss);
    pen_status s = pen_render_fwd(ctx, &t->scene, &r->opt, state, img);
    return s ? s : evaluate(ctx, t, r->weight, img, loss, d_img);
}

/* The loop's first view state, whose ray-traced transfers the other renders of a multi-view task
 * share (NULL when there is none). */
static pen_render_state *views_state(const run *r) {
    return r->multi && r->views.count > 0 && r->views.state ? r->views.state[0] : NULL;
}

/* The picture of the current parameters (initial, final, snapshots): the scene's camera, or the
 * first view's in a multi-view task, there with a state sharing the views' transfers (traced
 * once per pose, not once per picture). */
static pen_status picture(pen_context *ctx, const pen_optim_task *t, const run *r,
                          pen_image *img) {
    const pen_scene v =
        r->multi ? pen__optim_view_scene(&t->scene, &t->views[0].camera) : t->scene;
    pen_render_state *st = NULL, *with = views_state(r);
    pen_status s = with ? pen_render_state_create(ctx, &st) : PEN_OK;
    if (!s && with) s = pen_render_state_share(ctx, st, with);
    if (!s) s = pen_render_fwd(ctx, &v, &r->opt, st, img);
    pen_render_state_free(st);
    if (!s && r->multi) pen__optim_view_expose(img, pen__optim_exposure(&t->views[0]));
    return s;
}

/* ---- Stages before the descent --------------------------------------------------------------- */

/* A stage before the descent (optim.h, pen_optim_stage: the light search, the "fit" lighting, the
 * first least-squares solve). Each moves the scene's lighting and nothing else, so the lighting it
 * started from is all it takes to measure the loss before it. That is done once the objective is
 * whole (the shadow weights and the ridge's mu exist only after the stages), just before the
 * descent, with the same renders as the loop's. */
typedef struct prestage {
    const char *name; /* pen_optim_stage's */
    double seconds;
    float sh[PEN_SH_MAX_COEFFS][3]; /* the scene's lighting when the stage began */
    int light_count;
} prestage;

typedef struct prestages {
    prestage at[PEN_OPTIM_MAX_STAGES - 1];
    int count;
} prestages;

/* Records the start of a stage named `name` from the scene's lighting now. */
static prestage *stage_begin(prestages *p, const pen_scene *sc, const char *name) {
    prestage *a = &p->at[p->count++];
    a->name = name;
    a->seconds = 0.0;
    memcpy(a->sh, sc->lighting.sh, sizeof a->sh);
    a->light_count = sc->lighting.light_count;
    return a;
}

/* The objective at the start of every stage into before[] (image term and regularisers, as
 * losses[] has them), and the render of the first stage's start, the initial guess, into
 * initial. The scene's lighting is put back as it was, bit for bit. */
static pen_status stage_losses(pen_context *ctx, pen_optim_task *t, run *r, const prestages *p,
                               pen_image *img, double *before, pen_image *initial) {
    pen_lighting *L = &t->scene.lighting;
    float sh[PEN_SH_MAX_COEFFS][3];
    memcpy(sh, L->sh, sizeof sh);
    const int light_count = L->light_count;
    pen_status s = PEN_OK;
    for (int j = 0; !s && j < p->count; ++j) {
        memcpy(L->sh, p->at[j].sh, sizeof L->sh);
        L->light_count = p->at[j].light_count;
        s = image_term(ctx, t, r, NULL, img, &before[j], NULL);
        if (!s) before[j] += pen__optim_regularisers(r);
        if (!s && j == 0) s = picture(ctx, t, r, initial);
    }
    memcpy(L->sh, sh, sizeof sh);
    L->light_count = light_count;
    return s;
}

/* res->stages and res->initial_loss, once the descent is over: the stages before it (their start
 * losses in before[]; the last ends where the descent starts, at losses[0]) and the descent,
 * unless the solve ended the task. */
static void stages_record(const prestages *p, const double *before, pen_optim_result *res) {
    int n = 0;
    for (int j = 0; j < p->count; ++j)
        res->stages[n++] = (pen_optim_stage){p->at[j].name, before[j],
                                             j + 1 < p->count ? before[j + 1] : res->losses[0],
                                             p->at[j].seconds, 0};
    if (!res->solved)
        res->stages[n++] = (pen_optim_stage){"adam", res->losses[0], res->final_loss,
                                             res->seconds, res->iterations};
    res->stage_count = n;
    res->initial_loss = res->stages[0].loss_before;
}

static pen_status optimise(pen_context *ctx, pen_optim_task *t, const pen_optim_settings *set,
                           run *r, const prestages *pre, pen_optim_result *res) {
    const pen_render_options opt = r->opt;
    pen_render_state *state = NULL;
    pen_render_grad grad;
    memset(&grad, 0, sizeof grad);
    pen__adam adam = {0, NULL, NULL, 0, 0.0, 0.0, 0.0};
    pen_image img = {0, 0, 0, NULL}, d_img = {0, 0, 0, NULL};
    created made = {NULL, 0, 0};
    const int w = t->scene.camera.width, h = t->scene.camera.height;
    pen_status s = pen_render_state_create(ctx, &state);
    if (!s) s = pen_render_grad_create(ctx, &t->scene, &grad);
    if (!s) s = pen__optim_adam_init(ctx, &adam, r->n);
    if (!s) s = pen_image_create(ctx, w, h, 3, &d_img);
    if (!s) {
        res->losses = pen__calloc(ctx, (size_t)t->iterations + 1, sizeof(double), "loss curve");
        if (!res->losses) s = PEN_ERROR_MEMORY;
    }
    const unsigned wrt = pen__optim_grad_mask(r->groups, r->solve);
    /* (the views' plan before their first pass: the stages' losses render them) */
    if (!s && r->multi) s = pen__optim_views_plan(ctx, &r->views, &t->scene, set, wrt);
    double pre_loss[PEN_OPTIM_MAX_STAGES];
    if (!s)
        s = pre->count ? stage_losses(ctx, t, r, pre, &img, pre_loss, &res->initial)
                       : picture(ctx, t, r, &res->initial);
    /* (the hashes read the target and the parameters: only checkpoints need them) */
    pen__optim_identity id;
    memset(&id, 0, sizeof id);
    if (set->outdir) id = identity(t, set, r);
    pen__optim_state st = {0, 0, -1, (double)INFINITY, 0.0, r->x, r->best, &adam, res->losses};
    if (!s && set->resume) s = resume(ctx, t, set, &id, r, &st);
    const int start = st.iteration;
    res->resumed_from = start;
    res->best_iteration = st.best_iteration;
    double best = st.best_loss;
    const double before = st.seconds; /* spent by the runs this one continues */
    const float scale =
        r->multi ? 3.0f * (float)r->views.max_pixels : 3.0f * (float)w * (float)h;
    /* solved lighting alone: nothing for Adam to move, the solve is the answer */
    const int alone = r->solve && r->n == 3 * (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands;
    /* (under several ranks only rank 0 writes: pen_optim_ranks) */
    const int writes = set->outdir && (!set->ranks || set->ranks->rank == 0);
    const int K = writes ? set->checkpoint_every : 0;
    const int S = writes ? set->snapshot_every : 0;
    const double t0 = omp_get_wtime();
    int i = start, shown = -1; /* the iteration whose parameters img shows, -1 after a step */
    for (; !s && i < t->iterations; ++i) {
        if (K > 0 && i > start && i % K == 0) { /* the state after i steps, before its render */
            st.iteration = st.recorded = i;
            st.best_iteration = res->best_iteration;
            st.best_loss = best;
            st.seconds = before + (omp_get_wtime() - t0);
            s = save_checkpoint(ctx, set, &made, &id, &st);
            if (s) break;
        }
        double loss = 0.0;
        s = solve_lighting(ctx, t, &opt, r);
        if (!s) s = image_term(ctx, t, r, state, &img, &loss, &d_img);
        if (!s && S > 0 && i % S == 0 && r->multi) s = picture(ctx, t, r, &img);
        if (!s && S > 0 && i % S == 0) s = save_snapshot(ctx, set, &made, i, &img);
        if (s) break;
        loss += pen__optim_regularisers(r);
        shown = i;
        res->losses[i] = loss;
        if (loss < best) {
            best = loss;
            res->best_iteration = i;
            memcpy(r->best, r->x, sizeof(float) * r->n);
        }
        if (set->progress && set->progress(set->progress_user, i, t->iterations, loss)) {
            res->interrupted = 1;
            break;
        }
        if (alone || pen__optim_stalled(res->losses, i + 1, t->window, t->tolerance)) {
            res->converged = 1;
            res->solved = alone;
            break;
        }
        pen_render_grad_zero(&grad);
        s = r->multi ? pen__optim_views_bwd(ctx, &r->views, &t->scene, &opt, &grad)
                     : pen_render_bwd(ctx, &t->scene, &opt, state, &d_img, wrt, &grad);
        if (s) break;
        pen__optim_gather(r, &grad, scale);
        pen__optim_adam_step(&adam, r->segments, r->segment_count, r->x, r->g);
        pen__optim_transfer(r, 1);
        shown = -1;
    }
    res->iterations = i;
    if (!s && shown < 0) { /* the iteration limit: the loss after the last step */
        s = solve_lighting(ctx, t, &opt, r);
        if (!s) s = image_term(ctx, t, r, NULL, &img, &res->losses[i], NULL);
        if (!s) res->losses[i] += pen__optim_regularisers(r);
        if (!s && res->losses[i] < best) {
            best = res->losses[i];
            res->best_iteration = i;
            memcpy(r->best, r->x, sizeof(float) * r->n);
        }
        shown = i;
    }
    res->seconds = before + (omp_get_wtime() - t0);
    if (!s && writes) { /* the final state, so that a later run can continue it */
        st.iteration = i;
        st.recorded = i + 1;
        st.best_iteration = res->best_iteration;
        st.best_loss = best;
        st.seconds = res->seconds;
        s = save_checkpoint(ctx, set, &made, &id, &st);
    }
    /* The recovered scene is the best iterate: Adam's constant step makes the last one wander
     * around the optimum by about a learning rate. */
    if (!s && shown != res->best_iteration) {
        memcpy(r->x, r->best, sizeof(float) * r->n);
        pen__optim_transfer(r, 1);
        if (!r->multi) s = pen_render_fwd(ctx, &t->scene, &opt, NULL, &img);
    }
    if (!s && r->multi) s = picture(ctx, t, r, &img);
    if (!s && r->multi) s = image_term(ctx, t, r, NULL, &img, &res->final_image_loss, NULL);
    if (!s && !r->multi) s = evaluate(ctx, t, r->weight, &img, &res->final_image_loss, NULL);
    if (!s) {
        res->final_ridge_loss = pen__optim_ridge_loss(r);
        res->final_loss = res->final_image_loss + pen__optim_regularisers(r);
    }
    if (!s) {
        res->final = img;
        img.data = NULL;
        stages_record(pre, pre_loss, res);
    }
    created_finish(&made, s != PEN_OK);
    pen_image_free(&img);
    pen_image_free(&d_img);
    pen__optim_adam_free(&adam);
    pen_render_grad_free(&grad);
    pen_render_state_free(state);
    return s;
}

static void metrics_none(pen_optim_metrics *m) {
    const double none = (double)NAN;
    m->image_rmse = m->lighting_rel_error = m->albedo_psnr_db = m->albedo_observed = none;
    m->albedo_texel_psnr_db = m->lighting_rel_error_b2 = m->lighting_rel_error_sky = none;
    m->albedo_shadow_psnr_db = m->albedo_shadow_fraction = none;
    m->rotation_error_deg = m->translation_error = m->vertex_rmse = none;
    m->translation_error_rel = none;
    m->sphere_iou = m->sphere_chamfer = m->shadow_iou = none;
    m->light_direction_error_deg = none;
}

/* The loss weights 1 + shadow_weight * mask of the initial guess (loss.c). */
static pen_status shadow_weights(pen_context *ctx, const pen_optim_task *t, run *r) {
    const size_t pixels = (size_t)t->target.width * (size_t)t->target.height;
    r->weight = pen__malloc(ctx, pixels, sizeof(float), "shadow weights");
    if (!r->weight) return PEN_ERROR_MEMORY;
    pen_status s = pen__optim_shadow_mask(ctx, &t->scene, &t->target,
                                          (t->optimize & PEN_OPTIM_LIGHTING) != 0, r->weight);
    for (size_t p = 0; !s && p < pixels; ++p)
        r->weight[p] = 1.0f + (float)t->shadow_weight * r->weight[p];
    return s;
}

/* Every view taking part, weighted as in the loss (its weight over its mask's size), as
 * least-squares eyes, each target over its view's exposure (pen__optim_view_eye; scratch holds
 * the targets whose exposure differs from 1), so that a fit or a search sees the loss's
 * objective with the exposures as they stand. */
typedef struct view_eyes {
    pen__optim_eye *eyes;
    pen_image *scratch; /* one per view of the task */
    int n, count;
} view_eyes;

static void view_eyes_free(view_eyes *e) {
    for (int i = 0; e->scratch && i < e->count; ++i)
        pen_image_free(&e->scratch[i]);
    free(e->scratch);
    free(e->eyes);
}

/* On failure *e is freed. */
static pen_status view_eyes_make(pen_context *ctx, const pen_optim_task *t, view_eyes *e) {
    *e = (view_eyes){NULL, NULL, 0, t->view_count};
    e->eyes = pen__calloc(ctx, (size_t)t->view_count, sizeof *e->eyes, "views");
    e->scratch = pen__calloc(ctx, (size_t)t->view_count, sizeof *e->scratch, "views");
    pen_status s = e->eyes && e->scratch ? PEN_OK : PEN_ERROR_MEMORY;
    for (int i = 0; !s && i < t->view_count; ++i) {
        const pen_optim_view *v = &t->views[i];
        const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
        const double count = pen__loss_weight_sum(v->mask, pixels);
        if (v->weight > 0.0 && count > 0.0)
            s = pen__optim_view_eye(ctx, v, v->weight / count, &e->scratch[i], &e->eyes[e->n++]);
    }
    if (s) view_eyes_free(e);
    return s;
}

/* "init": "fit": the lighting starts at the unshadowed least-squares fit to the target. */
static pen_status fitted_lighting(pen_context *ctx, const pen_optim_task *t, run *r) {
    if (!r->multi) {
        pen_status s = pen__optim_fit_lighting(ctx, &t->scene, &t->target, PEN__OPTIM_RIDGE_INIT,
                                              r->sc->lighting.sh);
        if (!s) pen__optim_transfer(r, 0);
        if (!s) pen__optim_lighting_take(r); /* (on its bound) */
        return s;
    }
    view_eyes e;
    pen_status s = view_eyes_make(ctx, t, &e);
    if (s) return s;
    s = pen__optim_fit_lighting_eyes(ctx, &t->scene, e.eyes, e.n, PEN__OPTIM_RIDGE_INIT,
                                     r->sc->lighting.sh);
    view_eyes_free(&e);
    if (!s) pen__optim_transfer(r, 0);
    if (!s) pen__optim_lighting_take(r);
    return s;
}

/* Lays the parameter vector out again for the scene as it now is (the lights the search
 * created), from the scene's values: the initial guesses were applied before. */
static pen_status relayout(pen_context *ctx, const pen_optim_task *t, run *r) {
    const run fresh = {.sc = r->sc, .opt = r->opt, .groups = r->groups, .solve = r->solve,
                       .ridge = r->ridge, .model_hash = r->model_hash,
                       .multi = r->multi, .task_views = r->task_views,
                       .task_view_count = r->task_view_count};
    pen__optim_run_free(r);
    *r = fresh;
    pen_status s = pen__optim_layout(ctx, r, t);
    if (s) return s;
    pen__optim_transfer(r, 0);
    pen__optim_start(r, 0);
    pen__optim_project(r->segments, r->segment_count, r->x);
    pen__optim_transfer(r, 1);
    return PEN_OK;
}

/* "lights" on a scene without lights: the global search (lights_search.c) creates
 * t->light_count of them against the target or every view taking part, the optimised SH
 * starting at the lighting it solved with them; then the vector is laid out to hold them. */
static pen_status search_lights(pen_context *ctx, pen_optim_task *t, run *r,
                                pen_optim_result *out) {
    pen__optim_eye one = {NULL, &t->target, NULL, 1.0, NULL};
    view_eyes e = {&one, NULL, 1, 0};
    if (r->multi) {
        pen_status s = view_eyes_make(ctx, t, &e);
        if (s) return s;
    }
    const double t0 = omp_get_wtime();
    pen_status s = pen__optim_lights_search(
        ctx, r->sc, &r->opt, e.eyes, e.n, t->light_count, (r->groups & PEN_OPTIM_LIGHTING) != 0,
        isnan(t->lighting_ridge) ? PEN_OPTIM_LIGHTING_RIDGE_DEFAULT : t->lighting_ridge,
        PEN__OPTIM_SEARCH_RADIUS_DEG, &out->search_renders);
    out->search_seconds = omp_get_wtime() - t0;
    out->lights_searched = s ? 0 : t->light_count;
    if (r->multi) view_eyes_free(&e);
    return s ? s : relayout(ctx, t, r);
}

/* The lighting ridge (optim.h): mu is fixed at the initial guess from its normal equations.
 * Least squares then solves the initial guess's lighting (so the first render, the loss curve's
 * start, shows the solved lighting); Adam with a ridge keeps its initial lighting and takes only
 * mu from the solve. */
static pen_status ridge_init(pen_context *ctx, const pen_optim_task *t, run *r) {
    r->ridged = 1;
    r->weight_sum = r->multi ? 1.0 /* the views' factors normalise (views.c) */
                             : pen__loss_weight_sum(r->weight, (size_t)t->target.width *
                                                                   (size_t)t->target.height);
    r->mu[0] = r->mu[1] = r->mu[2] = -1.0;
    /* a state for the basis renders, so that they share one trace of the transfer */
    pen_status s = pen_render_state_create(ctx, &r->solve_state);
    if (s) return s;
    if (!r->solve) {
        float sh[PEN_SH_MAX_COEFFS][3];
        s = solve_into(ctx, t, &r->opt, r, sh);
        pen_render_state_free(r->solve_state); /* Adam needs it no more */
        r->solve_state = NULL;
        return s;
    }
    r->solved_for = pen__calloc(ctx, r->n + 1, sizeof(float), "lighting solve");
    if (!r->solved_for) return PEN_ERROR_MEMORY;
    return solve_lighting(ctx, t, &r->opt, r);
}

/* "auto" resolved (optim.h): least squares for the lighting alone with the l2 loss, Adam
 * otherwise; resuming, the checkpoint's solver, so that a run continues as it began (a
 * checkpoint of a task least squares cannot solve is refused later, by its identity). */
static pen_optim_lighting_solver resolve_solver(pen_context *ctx, const pen_optim_task *t,
                                                const pen_optim_settings *set) {
    if (t->lighting_solver != PEN_OPTIM_LIGHTING_AUTO) return t->lighting_solver;
    const pen__optim_loss_kind *L = pen__optim_loss_find((int)t->loss);
    const int solvable = (t->optimize & PEN_OPTIM_LIGHTING) && L && L->least_squares;
    if (set->resume && set->outdir) {
        char *path = pen__optim_join(ctx, set->outdir, "checkpoint.bin");
        const int k = path ? pen__optim_checkpoint_solver(path) : -1;
        free(path);
        if (k == PEN_OPTIM_LIGHTING_ADAM || (k == PEN_OPTIM_LIGHTING_LEAST_SQUARES && solvable))
            return (pen_optim_lighting_solver)k;
    }
    return solvable && t->optimize == PEN_OPTIM_LIGHTING ? PEN_OPTIM_LIGHTING_LEAST_SQUARES
                                                         : PEN_OPTIM_LIGHTING_ADAM;
}

static pen_status check_settings(pen_context *ctx, const pen_optim_settings *set) {
    if (set->checkpoint_every < 0 || set->snapshot_every < 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: checkpoint and snapshot intervals must be >= 0");
    if (!(set->memory_limit >= 0.0)) /* NaN too */
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: memory_limit must be 0 (the machine's) or a number of bytes");
    if (set->resume && !set->outdir)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: resuming needs the output folder of the earlier run");
    return PEN_OK;
}

/* ---- The model of the task's gradients --------------------------------------------------------- */

/* The render gradient groups a task's parameter groups move: its bits are theirs (optim.h). */
static unsigned render_groups(unsigned optim) { return optim & PEN_GRAD_ALL; }

/* The scene's model as the user gave it, while the run renders with pen_render_grad_model's. */
typedef struct saved_model {
    int active;
    pen_shadow_self self;
    pen_shadow_ground_shadow ground_shadow;
    pen_texture_filter *filters; /* per object */
} saved_model;

/* Saves the scene's model into *m, its hash into *hash, and switches the scene to the model of
 * the render groups wrt. */
static pen_status model_switch(pen_context *ctx, pen_scene *sc, unsigned wrt, saved_model *m,
                               uint64_t *hash) {
    memset(m, 0, sizeof *m);
    m->filters = pen__calloc(ctx, sc->object_count > 0 ? (size_t)sc->object_count : 1,
                             sizeof *m->filters, "optimize: model");
    if (!m->filters) return PEN_ERROR_MEMORY;
    m->self = sc->shadow.self;
    m->ground_shadow = sc->shadow.ground_shadow;
    for (int o = 0; o < sc->object_count; ++o)
        m->filters[o] = sc->objects[o].texture_filter;
    const int32_t keys[2] = {(int32_t)m->self, (int32_t)m->ground_shadow};
    *hash = pen__fnv1a(PEN__FNV1A_SEED, keys, sizeof keys);
    for (int o = 0; o < sc->object_count; ++o) {
        const int32_t f = (int32_t)m->filters[o];
        *hash = pen__fnv1a(*hash, &f, sizeof f);
    }
    m->active = 1;
    pen_render_grad_model(sc, wrt);
    return PEN_OK;
}

/* Puts the user's model back (once; later calls do nothing). */
static void model_restore(pen_scene *sc, saved_model *m) {
    if (!m->active) return;
    sc->shadow.self = m->self;
    sc->shadow.ground_shadow = m->ground_shadow;
    for (int o = 0; o < sc->object_count; ++o)
        sc->objects[o].texture_filter = m->filters[o];
    free(m->filters);
    memset(m, 0, sizeof *m);
}

pen_status pen_optim_run(pen_context *ctx, pen_optim_task *task, const pen_optim_settings *settings,
                         pen_optim_result *out) {
    memset(out, 0, sizeof *out);
    metrics_none(&out->metrics);
    pen_optim_settings set = settings ? *settings : pen_optim_settings_default();
    pen_status s = pen__optim_task_check(ctx, task);
    if (!s) s = check_settings(ctx, &set);
    /* The scene as the renderer takes it (the renderer's own checks and messages), before the
     * checks against the ground truth, the sphere fit and the layout read its arrays. */
    if (!s) s = pen__scene_validate(ctx, &task->scene, "render");
    if (s) return s;
    if (task->has_ground_truth) {
        s = pen__optim_check_truth(ctx, task);
        metrics_none(&out->metrics);
        if (s) return s;
    }
    /* Sphere sets asked for as {"fit": N}: the shadows need them, so do the deformation graph's
     * nodes and the spheres group; without shadows and those no spheres are needed. */
    const unsigned needs = PEN_OPTIM_DEFORMATION | PEN_OPTIM_SPHERES;
    /* The scene made ready as `penumbra render` makes it (pen_scene_prepare): the fits, and the
     * overlap weights of the initial spheres, held fixed while spheres, deformation or pose move
     * (an in-memory set without them would otherwise get them recomputed every frame). */
    s = pen_scene_prepare(ctx, &task->scene, set.shadows || (task->optimize & needs), NULL);
    if (s) return s;
    if (task->has_ground_truth && (task->optimize & PEN_OPTIM_SPHERES)) { /* sphere metrics */
        s = pen_scene_fit_spheres(ctx, &task->ground_truth);
        if (s) return s;
    }
    s = pen__optim_task_check_groups(ctx, task);
    double estimate = 0.0; /* before the views' states exist: a task too large is refused */
    if (!s) s = pen__optim_check_memory(ctx, task, &set, &estimate);
    if (s) return s;
    run r;
    memset(&r, 0, sizeof r);
    r.sc = &task->scene;
    r.opt = pen_render_options_default();
    r.opt.shadows = set.shadows;
    r.groups = task->optimize;
    /* The model the task's gradients need, by the one rule every door follows
     * (pen_render_grad_model, docs/design.md sec. 1.15): the precomputed self transfer is
     * constant in the pose, the shape, the spheres and the lights' directions, so a task moving
     * any of them sees its objects' own shadows through their spheres (and a light search would
     * otherwise ray trace the transfer again for every candidate direction); a task moving the
     * geometry looks textures up at the pixel's uv, continuous in it. Lighting, albedo and
     * exposure keep the scene's model. The user's model is put back before the metrics and the
     * outputs, which describe the scene as given. */
    saved_model model;
    s = model_switch(ctx, &task->scene, render_groups(r.groups), &model, &r.model_hash);
    if (s) return s;
    r.solve = resolve_solver(ctx, task, &set) == PEN_OPTIM_LIGHTING_LEAST_SQUARES;
    r.ridge = !isnan(task->lighting_ridge) ? task->lighting_ridge
              : r.solve                    ? PEN_OPTIM_LIGHTING_RIDGE_DEFAULT
                                           : 0.0;
    out->lighting_solver = r.solve ? PEN_OPTIM_LIGHTING_LEAST_SQUARES : PEN_OPTIM_LIGHTING_ADAM;
    out->lighting_ridge = r.ridge;
    r.multi = task->view_count > 0;
    r.task_views = task->views;
    r.task_view_count = task->view_count;
    s = pen__optim_layout(ctx, &r, task);
    prestages pre = {.count = 0};
    if (!s) {
        pen__optim_transfer(&r, 0);
        pen__optim_start(&r, task->init_black);
        pen__optim_project(r.segments, r.segment_count, r.x);
        pen__optim_transfer(&r, 1);
        const int search =
            (task->optimize & PEN_OPTIM_LIGHTS) && task->scene.lighting.light_count == 0;
        double t0 = omp_get_wtime();
        if (search) { /* (its SH replaces "fit"'s) */
            prestage *p = stage_begin(&pre, &task->scene, "light_search");
            s = search_lights(ctx, task, &r, out);
            p->seconds = out->search_seconds;
        } else if (task->init_fit && r.at[PEN__OPTIM_G_LIGHTING] != SIZE_MAX) {
            prestage *p = stage_begin(&pre, &task->scene, "lighting_fit");
            s = fitted_lighting(ctx, task, &r);
            p->seconds = omp_get_wtime() - t0;
        }
        if (!s && r.multi)
            s = pen__optim_views_init(ctx, &r.views, task, task->shadow_weight,
                                      (task->optimize & PEN_OPTIM_LIGHTING) != 0);
        else if (!s && task->shadow_weight > 0.0)
            s = shadow_weights(ctx, task, &r);
        if (!s && (r.solve || (r.ridge > 0.0 && r.at[PEN__OPTIM_G_LIGHTING] != SIZE_MAX))) {
            /* (Adam's ridge takes only mu from its solve: no stage, the lighting stays) */
            prestage *p = r.solve ? stage_begin(&pre, &task->scene, "least_squares") : NULL;
            t0 = omp_get_wtime();
            s = ridge_init(ctx, task, &r);
            if (p) p->seconds = omp_get_wtime() - t0;
        }
    }
    if (!s) s = optimise(ctx, task, &set, &r, &pre, out);
    if (!s) {
        pen_image_error e = {0.0, 0.0, 0.0, 0};
        if (r.multi) { /* every view of the recovered scene; image_rmse over all of them */
            double sq[2] = {0.0, 0.0};
            out->view_count = task->view_count;
            s = pen__optim_views_finish(ctx, &task->scene, &r.opt, task->loss, task->views,
                                        task->view_count, views_state(&r), &out->views,
                                        &out->view_finals, sq);
            e.rmse = sq[1] > 0.0 ? sqrt(sq[0] / sq[1]) : (double)NAN;
        } else {
            s = pen_image_compare(ctx, &out->final, &task->target, NULL, &e, NULL);
        }
        if (!s && task->validation_count > 0) { /* held back: rendered, never in the loss */
            out->validation_count = task->validation_count;
            s = pen__optim_views_finish(ctx, &task->scene, &r.opt, task->loss, task->validation,
                                        task->validation_count, views_state(&r),
                                        &out->validation, &out->validation_finals, NULL);
        }
        model_restore(&task->scene, &model);
        if (!s && task->has_ground_truth) s = pen__optim_metrics(ctx, task, &out->metrics);
        out->metrics.image_rmse = s ? (double)NAN : e.rmse;
    }
    model_restore(&task->scene, &model);
    pen__optim_run_free(&r);
    out->memory_estimate = estimate, out->memory_peak = pen__optim_peak_bytes();
    if (s) pen_optim_result_free(out);
    return s;
}

void pen_optim_result_free(pen_optim_result *result) {
    if (!result) return;
    free(result->losses);
    pen_image_free(&result->initial);
    pen_image_free(&result->final);
    for (int i = 0; result->view_finals && i < result->view_count; ++i)
        pen_image_free(&result->view_finals[i]);
    for (int i = 0; result->validation_finals && i < result->validation_count; ++i)
        pen_image_free(&result->validation_finals[i]);
    free(result->views);
    free(result->view_finals);
    free(result->validation);
    free(result->validation_finals);
    memset(result, 0, sizeof *result);
    metrics_none(&result->metrics);
}
