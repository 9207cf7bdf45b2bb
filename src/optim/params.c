/* The optimizer's parameter vector: where each optimised quantity of the scene sits in the flat
 * float vector x (the layout, cut into segments with their learning rates and bounds), the copy
 * between x and the scene both ways, the gather of a render gradient into x's layout, and the
 * regularisers that belong to the parameters (the deformation's energy, the spheres' smoothness,
 * the lighting's ridge). The loop that uses them is optimize.c.
 *
 * The views' exposures (the "exposure" group) live in x as natural logs, so that they stay
 * positive and a step is a relative change; the first view's is not in x (the gauge, optim.h).
 *
 * Rotations live in x as radians (the scene keeps degrees), so that the supplement's learning
 * rate 1e-2 means about half a degree per step; their gradient is converted with the same factor. */
#include "optim/optim_internal.h"

#include "penumbra/render.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef pen__optim_run run;
typedef pen__optim_object_layout object_layout;
typedef pen__optim_object_deform object_deform;

static const double DEG_PER_RAD = 180.0 / PEN_PI;

/* The lights' block holds each light's fields as PEN_LIGHT_FLOATS floats (scene.h), the order of
 * pen_light, which parallel.c also flattens as one run of floats. */
_Static_assert(sizeof(pen_light) == PEN_LIGHT_FLOATS * sizeof(float),
               "pen_light is PEN_LIGHT_FLOATS floats");

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

pen_status pen__optim_layout(pen_context *ctx, run *r, const pen_optim_task *t) {
    const pen_scene *sc = r->sc;
    r->objects = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *r->objects, "layout");
    r->segments = pen__calloc(ctx, 6 * (size_t)sc->object_count + 3, sizeof *r->segments,
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
        r->lights = add_segment(r, PEN_LIGHT_FLOATS * (size_t)sc->lighting.light_count,
                                t->lr.lights, PEN__BOUND_LIGHTS);
    r->exposure = SIZE_MAX; /* every view's but the first's, the gauge (optim.h) */
    if ((r->groups & PEN_OPTIM_EXPOSURE) && t->view_count > 1)
        r->exposure = add_segment(r, (size_t)t->view_count - 1, t->lr.exposure, PEN__BOUND_NONE);
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

void pen__optim_run_free(run *r) {
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
void pen__optim_transfer(run *r, int to_scene) {
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
            float *x = r->x + r->lights + PEN_LIGHT_FLOATS * (size_t)l;
            float *v[PEN_LIGHT_FLOATS];
            for (int k = 0; k < 3; ++k) {
                v[PEN_LIGHT_OFFSET_DIRECTION + k] = &li->direction[k];
                v[PEN_LIGHT_OFFSET_IRRADIANCE + k] = &li->irradiance[k];
            }
            v[PEN_LIGHT_OFFSET_RADIUS] = &li->angular_radius_deg;
            for (int k = 0; k < PEN_LIGHT_FLOATS; ++k) {
                if (to_scene)
                    *v[k] = x[k];
                else
                    x[k] = *v[k];
            }
        }
    for (int v = 1; r->exposure != SIZE_MAX && v < r->task_view_count; ++v) {
        /* log s in x: positive whatever the step, and a step is a relative change */
        float *x = r->x + r->exposure + (size_t)(v - 1);
        if (to_scene)
            r->task_views[v].exposure = exp((double)*x);
        else
            *x = (float)log(pen__optim_exposure(&r->task_views[v]));
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
void pen__optim_deformation_rest(run *r) {
    for (int o = 0; o < r->sc->object_count; ++o) {
        const object_layout *L = &r->objects[o];
        if (L->deform == SIZE_MAX) continue;
        object_deform *D = &r->deform[o];
        pen__optim_deform_identity(&D->graph, D->params);
        for (size_t i = 0; i < 12 * (size_t)D->graph.nodes; ++i)
            r->x[L->deform + i] = (float)D->params[i];
    }
}

double pen__optim_ridge_term(const double mu[3], double weight_sum, int nb, const float (*sh)[3],
                             double (*d)[3]) {
    double e = 0.0;
    for (int k = 0; k < nb; ++k)
        for (int c = 0; c < 3; ++c) {
            e += mu[c] * (double)sh[k][c] * (double)sh[k][c];
            if (d) d[k][c] += 2.0 * mu[c] * (double)sh[k][c] / (3.0 * weight_sum);
        }
    return e / (3.0 * weight_sum);
}

double pen__optim_ridge_loss(const run *r) {
    if (!r->ridged) return 0.0;
    return pen__optim_ridge_term(r->mu, r->weight_sum, r->sc->sh_bands * r->sc->sh_bands,
                                 (const float(*)[3])r->sc->lighting.sh, NULL);
}

/* The regularisers at the current parameters (D->params and D->spheres, set by transfer; their
 * gradient is added in pen__optim_gather()): every deformed object's, the spheres' smoothness, and the
 * lighting's ridge. */
double pen__optim_regularisers(run *r) {
    double e = pen__optim_ridge_loss(r);
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
void pen__optim_initial_guess(run *r) {
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

void pen__optim_gather(run *r, const pen_render_grad *grad, float scale) {
    const pen_scene *sc = r->sc;
    if (r->lighting != SIZE_MAX) {
        const int nb = sc->sh_bands * sc->sh_bands;
        for (int k = 0; k < nb; ++k)
            for (int ch = 0; ch < 3; ++ch)
                r->g[r->lighting + 3 * (size_t)k + ch] = scale * grad->sh[k][ch];
        if (r->ridged && !r->solve) { /* Adam on the ridged loss: in its units, scaled alike */
            double d[PEN_SH_MAX_COEFFS][3];
            memset(d, 0, sizeof d);
            pen__optim_ridge_term(r->mu, r->weight_sum, nb, (const float(*)[3])sc->lighting.sh,
                                  d);
            for (int k = 0; k < nb; ++k)
                for (int ch = 0; ch < 3; ++ch)
                    r->g[r->lighting + 3 * (size_t)k + ch] =
                        (float)((double)(scale * grad->sh[k][ch]) + (double)scale * d[k][ch]);
        }
    }
    if (r->lights != SIZE_MAX)
        for (int l = 0; l < grad->light_count; ++l) {
            const pen_light_grad *lg = &grad->lights[l];
            float *g = r->g + r->lights + PEN_LIGHT_FLOATS * (size_t)l;
            for (int k = 0; k < 3; ++k) {
                g[PEN_LIGHT_OFFSET_DIRECTION + k] = scale * lg->direction[k];
                g[PEN_LIGHT_OFFSET_IRRADIANCE + k] = scale * lg->irradiance[k];
            }
            g[PEN_LIGHT_OFFSET_RADIUS] = scale * lg->angular_radius_deg;
        }
    for (int v = 1; r->exposure != SIZE_MAX && v < r->task_view_count; ++v)
        r->g[r->exposure + (size_t)(v - 1)] = (float)((double)scale * r->views.d_exposure[v]);
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

unsigned pen__optim_grad_mask(unsigned groups, int solve) {
    unsigned wrt = 0;
    if ((groups & PEN_OPTIM_LIGHTING) && !solve) wrt |= PEN_GRAD_LIGHTING;
    if (groups & PEN_OPTIM_ALBEDO) wrt |= PEN_GRAD_ALBEDO;
    if (groups & PEN_OPTIM_POSE) wrt |= PEN_GRAD_POSE;
    if (groups & PEN_OPTIM_SPHERES) wrt |= PEN_GRAD_SPHERES;
    if (groups & PEN_OPTIM_DEFORMATION) wrt |= PEN_GRAD_SPHERES | PEN_GRAD_VERTICES;
    if (groups & PEN_OPTIM_LIGHTS) wrt |= PEN_GRAD_LIGHTS;
    return wrt;
}
