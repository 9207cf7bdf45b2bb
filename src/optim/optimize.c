/* The inverse-problem loop: render, compare with the target, back-propagate, take an Adam step.
 *
 * Every optimised quantity of the scene is copied into one flat float vector x, cut into
 * segments (the lighting; per object its texels or constant albedo, its rotation, its
 * translation, its spheres, its deformation graph's matrices and translations), each with its
 * learning rate and bound. One iteration writes x into the scene, solves the lighting when it is
 * solved by least squares rather than stepped (solve_lighting), renders (pen_render_fwd),
 * evaluates the loss against the target, runs pen_render_bwd for the groups being optimised
 * only, gathers the gradient (plus the regularisers') into the layout of x and steps. Rotations live in x as radians (the scene keeps degrees) so that the supplement's
 * learning rate 1e-2 means about half a degree per step; their gradient is converted with the
 * same factor.
 *
 * The loss is a mean over pixels and channels; its gradient is multiplied by that count before
 * Adam sees it (the gradient of the sum). Adam is invariant to the scale of the gradient except
 * through its epsilon (1e-8), which would otherwise dominate the tiny per-texel gradients of a
 * large image and slow textures down.
 *
 * Record keeping: losses[i] is the objective after i steps (the image loss plus the regularisers:
 * the deformation's, the spheres' smoothness, the least-squares lighting's ridge); the stopping
 * rule looks at them after each
 * render, and when it fires no further step is taken. The parameters of the lowest objective
 * are kept (the best iterate) and rendered once more if they are not the last ones. */
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

static const double DEG_PER_RAD = 180.0 / PEN_PI;

/* Where each object's parameters sit in x (SIZE_MAX: not optimised). */
typedef struct object_layout {
    size_t albedo, rotation, translation, spheres, deform;
    size_t albedo_count; /* texel floats, or 3 */
} object_layout;

/* An object's deformation graph and its double-precision work buffers. */
typedef struct object_deform {
    pen__deform_graph graph;
    double *params, *d_params; /* 12 per node */
    double *pos, *d_pos;       /* 3 per vertex */
    double *centres, *d_centres; /* 3 per node */
    double *spheres0, *spheres, *d_spheres; /* the spheres group's smoothness: 4 per sphere */
} object_deform;

typedef struct run {
    pen_scene *sc;
    pen_render_options opt;   /* every render of the run (shadows or not) */
    unsigned groups;
    size_t lighting; /* offset of the SH block, SIZE_MAX if not optimised */
    size_t lights;   /* offset of the disk lights' block (7 per light), SIZE_MAX if not */
    object_layout *objects;
    pen__optim_segment *segments;
    int segment_count;
    size_t n;
    float *x, *g;
    float *best;              /* the parameters of the lowest loss so far */
    object_deform *deform;    /* per object, when deformation is optimised */
    double w_rot, w_reg;
    double w_smooth;          /* the spheres group's smoothness weight */
    float *weight;            /* per pixel loss weights (shadow_weight > 0), else NULL */
    /* "lighting_solver": "least_squares": the lighting is solved, not stepped */
    int solve;
    double mu[3];             /* the ridge per channel, fixed at the initial guess */
    double weight_sum;        /* of the loss weights (the pixel count without them) */
    float *solved_for;        /* the parameters the lighting in x was solved for */
    pen_render_state *solve_state; /* the solves' renders (kept: see solve_lighting) */
    int solved;               /* solved_for is valid */
    int multi;                /* the task has "views" (views.c): the loss runs over them */
    pen__optim_views views;
} run;

pen_optim_settings pen_optim_settings_default(void) {
    pen_optim_settings s = {1, NULL, NULL, NULL, 0, 0, 0};
    return s;
}

static size_t add_segment(run *r, size_t count, float lr, pen__optim_bound bound) {
    pen__optim_segment *s = &r->segments[r->segment_count++];
    s->offset = r->n;
    s->count = count;
    s->lr = lr;
    s->bound = bound;
    r->n += count;
    return s->offset;
}

static size_t albedo_floats(const pen_object *ob) {
    return ob->texture.data ? (size_t)ob->texture.width * (size_t)ob->texture.height *
                                  (size_t)ob->texture.channels
                            : 3;
}

static pen_status layout(pen_context *ctx, run *r, const pen_optim_task *t) {
    const pen_scene *sc = r->sc;
    r->objects = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *r->objects, "layout");
    r->segments = pen__calloc(ctx, 6 * (size_t)sc->object_count + 2, sizeof *r->segments,
                              "segments");
    r->deform = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *r->deform, "graphs");
    if (!r->objects || !r->segments || !r->deform) return PEN_ERROR_MEMORY;
    r->w_rot = t->deformation.w_rot;
    r->w_reg = t->deformation.w_reg;
    r->w_smooth = t->spheres.w_smooth;
    r->lighting = SIZE_MAX;
    if (r->groups & PEN_OPTIM_LIGHTING)
        r->lighting = add_segment(r, 3 * (size_t)sc->sh_bands * (size_t)sc->sh_bands,
                                  t->lr.lighting, PEN__BOUND_NONE);
    r->lights = SIZE_MAX; /* after the SH block, which solve_lighting expects first */
    if ((r->groups & PEN_OPTIM_LIGHTS) && sc->lighting.light_count > 0)
        r->lights = add_segment(r, 7 * (size_t)sc->lighting.light_count, t->lr.lights,
                                PEN__BOUND_LIGHTS);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        object_layout *L = &r->objects[o];
        L->albedo = L->rotation = L->translation = L->spheres = L->deform = SIZE_MAX;
        if (r->groups & PEN_OPTIM_ALBEDO) {
            L->albedo_count = albedo_floats(ob);
            L->albedo = add_segment(r, L->albedo_count, t->lr.albedo, PEN__BOUND_UNIT);
        }
        if (r->groups & PEN_OPTIM_POSE) {
            L->rotation = add_segment(r, 3, t->lr.rotation, PEN__BOUND_NONE);
            L->translation = add_segment(r, 3, t->lr.translation, PEN__BOUND_NONE);
        }
        if ((r->groups & PEN_OPTIM_SPHERES) && ob->spheres.count > 0) {
            const size_t n = 4 * (size_t)ob->spheres.count;
            L->spheres = add_segment(r, n, t->lr.spheres, PEN__BOUND_SPHERES);
            if (r->w_smooth > 0.0) { /* the neighbours and the start of the smoothness term */
                object_deform *D = &r->deform[o];
                const pen_mesh none = {0};
                pen_status s =
                    pen__optim_deform_build(ctx, &none, &ob->spheres, t->spheres.k, &D->graph);
                if (s) return s;
                D->spheres0 = pen__malloc(ctx, n, sizeof(double), "initial spheres");
                D->spheres = pen__malloc(ctx, n, sizeof(double), "spheres");
                D->d_spheres = pen__malloc(ctx, n, sizeof(double), "sphere gradient");
                if (!D->spheres0 || !D->spheres || !D->d_spheres) return PEN_ERROR_MEMORY;
                for (size_t i = 0; i < n; ++i)
                    D->spheres0[i] = ob->spheres.data[i];
            }
        }
        if (r->groups & PEN_OPTIM_DEFORMATION) {
            object_deform *D = &r->deform[o];
            pen_status s = pen__optim_deform_build(ctx, &ob->mesh, &ob->spheres, t->deformation.k,
                                                   &D->graph);
            if (s) return s;
            const size_t M = (size_t)ob->spheres.count, nv = (size_t)ob->mesh.vertex_count;
            D->params = pen__calloc(ctx, 12 * M, sizeof(double), "deformation");
            D->d_params = pen__calloc(ctx, 12 * M, sizeof(double), "deformation");
            D->centres = pen__calloc(ctx, 3 * M, sizeof(double), "deformation");
            D->d_centres = pen__calloc(ctx, 3 * M, sizeof(double), "deformation");
            D->pos = pen__calloc(ctx, 3 * nv + 1, sizeof(double), "deformation");
            D->d_pos = pen__calloc(ctx, 3 * nv + 1, sizeof(double), "deformation");
            if (!D->params || !D->d_params || !D->centres || !D->d_centres || !D->pos || !D->d_pos)
                return PEN_ERROR_MEMORY;
            L->deform = add_segment(r, 9 * M, t->lr.deformation_rotation, PEN__BOUND_NONE);
            add_segment(r, 3 * M, t->lr.deformation_translation, PEN__BOUND_NONE);
        }
    }
    r->x = pen__calloc(ctx, r->n + 1, sizeof(float), "parameters");
    r->g = pen__calloc(ctx, r->n + 1, sizeof(float), "parameter gradient");
    r->best = pen__calloc(ctx, r->n + 1, sizeof(float), "best parameters");
    return r->x && r->g && r->best ? PEN_OK : PEN_ERROR_MEMORY;
}

static void run_free(run *r) {
    free(r->objects);
    free(r->segments);
    free(r->x);
    free(r->g);
    free(r->best);
    free(r->weight);
    free(r->solved_for);
    pen_render_state_free(r->solve_state);
    pen__optim_views_free_run(&r->views);
    for (int o = 0; r->deform && o < r->sc->object_count; ++o) {
        object_deform *D = &r->deform[o];
        pen__optim_deform_free(&D->graph);
        free(D->params);
        free(D->d_params);
        free(D->pos);
        free(D->d_pos);
        free(D->centres);
        free(D->d_centres);
        free(D->spheres0);
        free(D->spheres);
        free(D->d_spheres);
    }
    free(r->deform);
}

/* ---- Scene <-> parameter vector -------------------------------------------------------------- */

static float *albedo_data(pen_object *ob) {
    return ob->texture.data ? ob->texture.data : ob->albedo;
}

/* dir 0: scene -> x; dir 1: x -> scene. */
static void transfer(run *r, int to_scene) {
    pen_scene *sc = r->sc;
    if (r->lighting != SIZE_MAX) {
        float *x = r->x + r->lighting;
        for (int k = 0; k < sc->sh_bands * sc->sh_bands; ++k)
            for (int ch = 0; ch < 3; ++ch) {
                if (to_scene)
                    sc->lighting.sh[k][ch] = x[3 * k + ch];
                else
                    x[3 * k + ch] = sc->lighting.sh[k][ch];
            }
    }
    if (r->lights != SIZE_MAX)
        for (int l = 0; l < sc->lighting.light_count; ++l) {
            pen_light *li = &sc->lighting.lights[l];
            float *x = r->x + r->lights + 7 * (size_t)l;
            float *v[7] = {&li->direction[0],   &li->direction[1],  &li->direction[2],
                           &li->angular_radius_deg, &li->irradiance[0], &li->irradiance[1],
                           &li->irradiance[2]};
            for (int k = 0; k < 7; ++k) {
                if (to_scene)
                    *v[k] = x[k];
                else
                    x[k] = *v[k];
            }
        }
    for (int o = 0; o < sc->object_count; ++o) {
        pen_object *ob = &sc->objects[o];
        const object_layout *L = &r->objects[o];
        if (L->albedo != SIZE_MAX) {
            float *a = albedo_data(ob);
            if (to_scene)
                memcpy(a, r->x + L->albedo, sizeof(float) * L->albedo_count);
            else
                memcpy(r->x + L->albedo, a, sizeof(float) * L->albedo_count);
        }
        if (L->rotation != SIZE_MAX)
            for (int k = 0; k < 3; ++k) {
                if (to_scene) {
                    ob->pose.rotation_axis_angle_deg[k] =
                        (float)((double)r->x[L->rotation + k] * DEG_PER_RAD);
                    ob->pose.translation[k] = r->x[L->translation + k];
                } else {
                    r->x[L->rotation + k] =
                        (float)((double)ob->pose.rotation_axis_angle_deg[k] / DEG_PER_RAD);
                    r->x[L->translation + k] = ob->pose.translation[k];
                }
            }
        if (L->deform != SIZE_MAX && to_scene) {
            object_deform *D = &r->deform[o];
            const size_t M = (size_t)D->graph.nodes;
            for (size_t i = 0; i < 12 * M; ++i)
                D->params[i] = r->x[L->deform + i];
            pen__optim_deform_fwd(&D->graph, D->params, D->pos, D->centres);
            for (size_t i = 0; i < 3 * (size_t)D->graph.vertices; ++i)
                ob->mesh.positions[i] = (float)D->pos[i];
            for (size_t j = 0; j < M; ++j)
                for (int k = 0; k < 3; ++k)
                    ob->spheres.data[4 * j + (size_t)k] = (float)D->centres[3 * j + (size_t)k];
        }
        if (L->spheres != SIZE_MAX) {
            size_t n = 4 * (size_t)ob->spheres.count;
            if (to_scene)
                memcpy(ob->spheres.data, r->x + L->spheres, sizeof(float) * n);
            else
                memcpy(r->x + L->spheres, ob->spheres.data, sizeof(float) * n);
            for (size_t i = 0; to_scene && r->deform[o].spheres && i < n; ++i)
                r->deform[o].spheres[i] = r->x[L->spheres + i];
        }
    }
}

/* The deformation starts at rest (identity matrices, zero translations) whatever `init` says:
 * the scene holds the rest shape. */
static void deformation_rest(run *r) {
    for (int o = 0; o < r->sc->object_count; ++o) {
        const object_layout *L = &r->objects[o];
        if (L->deform == SIZE_MAX) continue;
        object_deform *D = &r->deform[o];
        pen__optim_deform_identity(&D->graph, D->params);
        for (size_t i = 0; i < 12 * (size_t)D->graph.nodes; ++i)
            r->x[L->deform + i] = (float)D->params[i];
    }
}

/* The ridge term of the least-squares lighting in the loss's units (0 otherwise). */
static double ridge_penalty(const run *r) {
    if (!r->solve) return 0.0;
    double e = 0.0;
    for (int k = 0; k < r->sc->sh_bands * r->sc->sh_bands; ++k)
        for (int c = 0; c < 3; ++c)
            e += r->mu[c] * (double)r->sc->lighting.sh[k][c] * (double)r->sc->lighting.sh[k][c];
    return e / (3.0 * r->weight_sum);
}

/* The regularisers at the current parameters (D->params and D->spheres, set by transfer; their
 * gradient is added in gather()): every deformed object's, the spheres' smoothness, and the
 * least-squares lighting's ridge. */
static double regularisers(run *r) {
    double e = ridge_penalty(r);
    for (int o = 0; o < r->sc->object_count; ++o) {
        const object_deform *D = &r->deform[o];
        if (r->objects[o].deform != SIZE_MAX)
            e += pen__optim_deform_energy(&D->graph, D->params, r->w_rot, r->w_reg, NULL);
        if (D->spheres0)
            e += pen__optim_spheres_energy(&D->graph, D->spheres0, D->spheres, r->w_smooth, NULL);
    }
    return e;
}

/* Supplement 5.2: optimised lighting and albedo start black (albedo grey when both are
 * optimised, since their gradients vanish together at zero). */
static void initial_guess(run *r) {
    const float albedo0 = (r->groups & PEN_OPTIM_LIGHTING) ? 0.5f : 0.0f;
    if (r->lighting != SIZE_MAX)
        memset(r->x + r->lighting, 0,
               sizeof(float) * 3 * (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands);
    for (int o = 0; o < r->sc->object_count; ++o) {
        const object_layout *L = &r->objects[o];
        if (L->albedo == SIZE_MAX) continue;
        for (size_t i = 0; i < L->albedo_count; ++i)
            r->x[L->albedo + i] = albedo0;
    }
}

static void gather(run *r, const pen_render_grad *grad, float scale) {
    const pen_scene *sc = r->sc;
    if (r->lighting != SIZE_MAX)
        for (int k = 0; k < sc->sh_bands * sc->sh_bands; ++k)
            for (int ch = 0; ch < 3; ++ch)
                r->g[r->lighting + 3 * (size_t)k + ch] = scale * grad->sh[k][ch];
    if (r->lights != SIZE_MAX)
        for (int l = 0; l < grad->light_count; ++l) {
            const pen_light_grad *lg = &grad->lights[l];
            float *g = r->g + r->lights + 7 * (size_t)l;
            for (int k = 0; k < 3; ++k) {
                g[k] = scale * lg->direction[k];
                g[4 + k] = scale * lg->irradiance[k];
            }
            g[3] = scale * lg->angular_radius_deg;
        }
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object_grad *og = &grad->objects[o];
        const object_layout *L = &r->objects[o];
        if (L->albedo != SIZE_MAX) {
            const float *src = og->texture ? og->texture : og->albedo;
            for (size_t i = 0; i < L->albedo_count; ++i)
                r->g[L->albedo + i] = scale * src[i];
        }
        if (L->rotation != SIZE_MAX)
            for (int k = 0; k < 3; ++k) {
                r->g[L->rotation + k] =
                    (float)((double)(scale * og->pose.rotation_axis_angle_deg[k]) * DEG_PER_RAD);
                r->g[L->translation + k] = scale * og->pose.translation[k];
            }
        if (L->spheres != SIZE_MAX) {
            const size_t n = 4 * (size_t)og->sphere_count;
            for (size_t i = 0; i < n; ++i)
                r->g[L->spheres + i] = scale * og->spheres[i];
            object_deform *D = &r->deform[o];
            if (D->spheres0) { /* in the loss's units, scaled like its gradient */
                memset(D->d_spheres, 0, sizeof(double) * n);
                pen__optim_spheres_energy(&D->graph, D->spheres0, D->spheres,
                                          (double)scale * r->w_smooth, D->d_spheres);
                for (size_t i = 0; i < n; ++i)
                    r->g[L->spheres + i] += (float)D->d_spheres[i];
            }
        }
        if (L->deform != SIZE_MAX) {
            object_deform *D = &r->deform[o];
            const size_t M = (size_t)D->graph.nodes;
            for (size_t i = 0; i < 3 * (size_t)D->graph.vertices; ++i)
                D->d_pos[i] = (double)og->positions[i] * (double)scale;
            for (size_t j = 0; j < M; ++j)
                for (int k = 0; k < 3; ++k)
                    D->d_centres[3 * j + (size_t)k] =
                        (double)og->spheres[4 * j + (size_t)k] * (double)scale;
            memset(D->d_params, 0, sizeof(double) * 12 * M);
            pen__optim_deform_bwd(&D->graph, D->params, D->d_pos, D->d_centres, D->d_params);
            /* the regularisers are in the loss's units: scaled like its gradient */
            pen__optim_deform_energy(&D->graph, D->params, (double)scale * r->w_rot,
                                     (double)scale * r->w_reg, D->d_params);
            for (size_t i = 0; i < 12 * M; ++i)
                r->g[L->deform + i] = (float)D->d_params[i];
        }
    }
}

static unsigned grad_mask(unsigned groups, int solve) {
    unsigned wrt = 0;
    if ((groups & PEN_OPTIM_LIGHTING) && !solve) wrt |= PEN_GRAD_LIGHTING;
    if (groups & PEN_OPTIM_ALBEDO) wrt |= PEN_GRAD_ALBEDO;
    if (groups & PEN_OPTIM_POSE) wrt |= PEN_GRAD_POSE;
    if (groups & PEN_OPTIM_SPHERES) wrt |= PEN_GRAD_SPHERES;
    if (groups & PEN_OPTIM_DEFORMATION) wrt |= PEN_GRAD_SPHERES | PEN_GRAD_VERTICES;
    if (groups & PEN_OPTIM_LIGHTS) wrt |= PEN_GRAD_LIGHTS;
    return wrt;
}

/* ---- Least-squares lighting ----------------------------------------------------------------- */

/* With "lighting_solver": "least_squares", makes the lighting in x and the scene the solution for
 * the current values of every other parameter, unless it already is (a lighting-only task solves
 * once). Adam never moves the lighting segment (its gradient is not computed, so it stays 0 and
 * so do Adam's steps there). */
static pen_status solve_lighting(pen_context *ctx, const pen_optim_task *t,
                                 const pen_render_options *opt, run *r) {
    if (!r->solve) return PEN_OK;
    const size_t nl = 3 * (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands;
    const size_t rest = r->n - nl; /* the lighting segment comes first (layout) */
    if (r->solved && memcmp(r->solved_for, r->x + nl, sizeof(float) * rest) == 0) return PEN_OK;
    pen_status s;
    if (r->multi) { /* one system over every view (views.c) */
        pen__optim_eye *eyes = pen__calloc(ctx, (size_t)r->views.count, sizeof *eyes, "views");
        s = eyes ? pen__optim_solve_lighting_eyes(ctx, r->sc, opt, eyes,
                                                  pen__optim_views_eyes(&r->views, 1, eyes),
                                                  t->lighting_ridge, r->mu, r->sc->lighting.sh)
                 : PEN_ERROR_MEMORY;
        free(eyes);
    } else {
        s = pen__optim_solve_lighting(ctx, r->sc, opt, r->solve_state, &t->target, r->weight,
                                      t->lighting_ridge, r->mu, r->sc->lighting.sh);
    }
    if (s) return s;
    for (size_t k = 0; k < nl; ++k)
        r->x[r->lighting + k] = r->sc->lighting.sh[k / 3][k % 3];
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
    return t->loss == PEN_OPTIM_LOSS_L1 ? pen_loss_l1(ctx, img, &t->target, loss, d_img)
                                        : pen_loss_l2(ctx, img, &t->target, loss, d_img);
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
    id.lighting_solver = (int)t->lighting_solver;
    id.lighting_ridge = t->lighting_ridge;
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
    if (!s) transfer(r, 1);
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

/* The picture of the current parameters (initial, final, snapshots): the scene's camera, or the
 * first view's in a multi-view task. */
static pen_status picture(pen_context *ctx, const pen_optim_task *t, const run *r,
                          pen_image *img) {
    const pen_scene v =
        r->multi ? pen__optim_view_scene(&t->scene, &t->views[0].camera) : t->scene;
    return pen_render_fwd(ctx, &v, &r->opt, NULL, img);
}

static pen_status optimise(pen_context *ctx, pen_optim_task *t, const pen_optim_settings *set,
                           run *r, pen_optim_result *res) {
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
    if (!s) s = picture(ctx, t, r, &res->initial);
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
    const unsigned wrt = grad_mask(r->groups, r->solve);
    const int K = set->outdir ? set->checkpoint_every : 0;
    const int S = set->outdir ? set->snapshot_every : 0;
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
        loss += regularisers(r);
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
        if (pen__optim_stalled(res->losses, i + 1, t->window, t->tolerance) ||
            (r->solve && r->n == 3 * (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands)) {
            /* (solved lighting alone: nothing for Adam to move, the solve is the answer) */
            res->converged = 1;
            break;
        }
        pen_render_grad_zero(&grad);
        s = r->multi ? pen__optim_views_bwd(ctx, &r->views, &t->scene, &opt, wrt, &grad)
                     : pen_render_bwd(ctx, &t->scene, &opt, state, &d_img, wrt, &grad);
        if (s) break;
        gather(r, &grad, scale);
        pen__optim_adam_step(&adam, r->segments, r->segment_count, r->x, r->g);
        transfer(r, 1);
        shown = -1;
    }
    res->iterations = i;
    if (!s && shown < 0) { /* the iteration limit: the loss after the last step */
        s = solve_lighting(ctx, t, &opt, r);
        if (!s) s = image_term(ctx, t, r, NULL, &img, &res->losses[i], NULL);
        if (!s) res->losses[i] += regularisers(r);
        if (!s && res->losses[i] < best) {
            best = res->losses[i];
            res->best_iteration = i;
            memcpy(r->best, r->x, sizeof(float) * r->n);
        }
        shown = i;
    }
    res->seconds = before + (omp_get_wtime() - t0);
    if (!s && set->outdir) { /* the final state, so that a later run can continue it */
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
        transfer(r, 1);
        if (!r->multi) s = pen_render_fwd(ctx, &t->scene, &opt, NULL, &img);
    }
    if (!s && r->multi) s = picture(ctx, t, r, &img);
    if (!s && r->multi) s = image_term(ctx, t, r, NULL, &img, &res->final_loss, NULL);
    if (!s && !r->multi) s = evaluate(ctx, t, r->weight, &img, &res->final_loss, NULL);
    if (!s) res->final_loss += regularisers(r);
    if (!s) {
        res->final = img;
        img.data = NULL;
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

/* "init": "fit": the lighting starts at the unshadowed least-squares fit to the target. */
static pen_status fitted_lighting(pen_context *ctx, const pen_optim_task *t, run *r) {
    if (!r->multi) {
        pen_status s = pen__optim_fit_lighting(ctx, &t->scene, &t->target, PEN__OPTIM_RIDGE_INIT,
                                              r->sc->lighting.sh);
        if (!s) transfer(r, 0);
        return s;
    }
    /* every view taking part, weighted as in the loss (its weight over its mask's size) */
    pen__optim_eye *eyes = pen__calloc(ctx, (size_t)t->view_count, sizeof *eyes, "views");
    if (!eyes) return PEN_ERROR_MEMORY;
    int n = 0;
    for (int i = 0; i < t->view_count; ++i) {
        const pen_optim_view *v = &t->views[i];
        const size_t pixels = (size_t)v->camera.width * (size_t)v->camera.height;
        const double count = pen__loss_weight_sum(v->mask, pixels);
        if (v->weight > 0.0 && count > 0.0)
            eyes[n++] = (pen__optim_eye){&v->camera, &v->target, v->mask, v->weight / count, NULL};
    }
    pen_status s = pen__optim_fit_lighting_eyes(ctx, &t->scene, eyes, n, PEN__OPTIM_RIDGE_INIT,
                                                r->sc->lighting.sh);
    free(eyes);
    if (!s) transfer(r, 0);
    return s;
}

/* Least-squares lighting: the ridge is fixed at the initial guess, whose lighting is then solved
 * for (so the first render, the loss curve's start, shows the solved lighting). */
static pen_status lighting_solver_init(pen_context *ctx, const pen_optim_task *t, run *r) {
    r->weight_sum = r->multi ? 1.0 /* the views' factors normalise (views.c) */
                             : pen__loss_weight_sum(r->weight, (size_t)t->target.width *
                                                                   (size_t)t->target.height);
    r->mu[0] = r->mu[1] = r->mu[2] = -1.0;
    r->solved_for = pen__calloc(ctx, r->n + 1, sizeof(float), "lighting solve");
    if (!r->solved_for) return PEN_ERROR_MEMORY;
    pen_status s = pen_render_state_create(ctx, &r->solve_state);
    if (s) return s;
    return solve_lighting(ctx, t, &r->opt, r);
}

static pen_status check_settings(pen_context *ctx, const pen_optim_settings *set) {
    if (set->checkpoint_every < 0 || set->snapshot_every < 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: checkpoint and snapshot intervals must be >= 0");
    if (set->resume && !set->outdir)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: resuming needs the output folder of the earlier run");
    return PEN_OK;
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
    if (set.shadows || (task->optimize & needs)) {
        s = pen_scene_fit_spheres(ctx, &task->scene);
        if (s) return s;
    }
    if (task->has_ground_truth && (task->optimize & PEN_OPTIM_SPHERES)) { /* sphere metrics */
        s = pen_scene_fit_spheres(ctx, &task->ground_truth);
        if (s) return s;
    }
    s = pen__optim_task_check_groups(ctx, task);
    if (s) return s;
    /* Overlap weights of the initial spheres, held fixed while spheres, deformation or pose move
     * (an in-memory set without them would otherwise get them recomputed every frame). */
    for (int o = 0; o < task->scene.object_count && !s; ++o)
        s = pen_spheres_ensure_weights(ctx, &task->scene.objects[o].spheres);
    if (s) return s;
    run r;
    memset(&r, 0, sizeof r);
    r.sc = &task->scene;
    r.opt = pen_render_options_default();
    r.opt.shadows = set.shadows;
    r.groups = task->optimize;
    r.solve = task->lighting_solver == PEN_OPTIM_LIGHTING_LEAST_SQUARES;
    r.multi = task->view_count > 0;
    s = layout(ctx, &r, task);
    if (!s) {
        transfer(&r, 0);
        if (task->init_black) initial_guess(&r);
        deformation_rest(&r);
        pen__optim_project(r.segments, r.segment_count, r.x);
        transfer(&r, 1);
        if (task->init_fit && r.lighting != SIZE_MAX) s = fitted_lighting(ctx, task, &r);
        if (!s && r.multi)
            s = pen__optim_views_init(ctx, &r.views, task, task->shadow_weight,
                                      (task->optimize & PEN_OPTIM_LIGHTING) != 0);
        else if (!s && task->shadow_weight > 0.0)
            s = shadow_weights(ctx, task, &r);
        if (!s && r.solve) s = lighting_solver_init(ctx, task, &r);
    }
    if (!s) s = optimise(ctx, task, &set, &r, out);
    if (!s) {
        pen_image_error e = {0.0, 0.0, 0.0, 0};
        if (r.multi) { /* every view of the recovered scene; image_rmse over all of them */
            double sq[2] = {0.0, 0.0};
            out->view_count = task->view_count;
            s = pen__optim_views_finish(ctx, &task->scene, &r.opt, task->loss, task->views,
                                        task->view_count, &out->views, &out->view_finals, sq);
            e.rmse = sq[1] > 0.0 ? sqrt(sq[0] / sq[1]) : (double)NAN;
        } else {
            s = pen_image_compare(ctx, &out->final, &task->target, NULL, &e, NULL);
        }
        if (!s && task->validation_count > 0) { /* held back: rendered, never in the loss */
            out->validation_count = task->validation_count;
            s = pen__optim_views_finish(ctx, &task->scene, &r.opt, task->loss, task->validation,
                                        task->validation_count, &out->validation,
                                        &out->validation_finals, NULL);
        }
        if (!s && task->has_ground_truth) s = pen__optim_metrics(ctx, task, &out->metrics);
        out->metrics.image_rmse = s ? (double)NAN : e.rmse;
    }
    run_free(&r);
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
