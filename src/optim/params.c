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

/* ---- The groups' own maths ------------------------------------------------------------------ */

/* What params.c does for each group of the table (groups.h), by its row: how many items its
 * block holds (SIZE_MAX: none here), what it prepares beside x (NULL: nothing), its copy between
 * x and the scene (to_scene 1: x -> scene), its start (NULL: where the scene puts it; black: the
 * supplement's initial guesses, pen__optim_start) and the gather of its gradient into g (the
 * render gradient times scale, plus its regulariser's). o is the object, -1 for a scene group;
 * x and g point at the group's block. */
typedef struct group_ops {
    size_t (*items)(const run *r, const pen_optim_task *t, int o);
    pen_status (*prepare)(pen_context *ctx, run *r, const pen_optim_task *t, int o);
    void (*transfer)(run *r, int o, float *x, int to_scene);
    void (*start)(run *r, int o, float *x, int black);
    void (*gather)(run *r, const pen_render_grad *grad, int o, float *g, float scale);
} group_ops;

/* Lighting: the SH coefficients, 3 channels each. */
static size_t lighting_items(const run *r, const pen_optim_task *t, int o) {
    (void)t, (void)o;
    return (size_t)r->sc->sh_bands * (size_t)r->sc->sh_bands;
}

static void lighting_transfer(run *r, int o, float *x, int to_scene) {
    (void)o;
    pen_scene *sc = r->sc;
    for (int k = 0; k < sc->sh_bands * sc->sh_bands; ++k)
        for (int ch = 0; ch < 3; ++ch) {
            if (to_scene)
                sc->lighting.sh[k][ch] = x[3 * k + ch];
            else
                x[3 * k + ch] = sc->lighting.sh[k][ch];
        }
}

/* black: supplement 5.2, the lighting starts at 0 */
static void lighting_start(run *r, int o, float *x, int black) {
    (void)o;
    if (black) memset(x, 0, sizeof(float) * 3 * lighting_items(r, NULL, -1));
}

static void lighting_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    (void)o;
    const int nb = r->sc->sh_bands * r->sc->sh_bands;
    for (int k = 0; k < nb; ++k)
        for (int ch = 0; ch < 3; ++ch)
            g[3 * (size_t)k + ch] = scale * grad->sh[k][ch];
    if (r->ridged && !r->solve) { /* Adam on the ridged loss: in its units, scaled alike */
        double d[PEN_SH_MAX_COEFFS][3];
        memset(d, 0, sizeof d);
        pen__optim_ridge_term(r->mu, r->weight_sum, nb, (const float(*)[3])r->sc->lighting.sh, d);
        for (int k = 0; k < nb; ++k)
            for (int ch = 0; ch < 3; ++ch)
                g[3 * (size_t)k + ch] =
                    (float)((double)(scale * grad->sh[k][ch]) + (double)scale * d[k][ch]);
    }
}

/* Albedo: an object's texel floats, or its constant albedo's 3. */
static size_t albedo_floats(const pen_object *ob) {
    return ob->texture.data ? (size_t)ob->texture.width * (size_t)ob->texture.height *
                                  (size_t)ob->texture.channels
                            : 3;
}

static size_t albedo_items(const run *r, const pen_optim_task *t, int o) {
    (void)t;
    return albedo_floats(&r->sc->objects[o]);
}

static void albedo_transfer(run *r, int o, float *x, int to_scene) {
    pen_object *ob = &r->sc->objects[o];
    float *a = ob->texture.data ? ob->texture.data : ob->albedo;
    if (to_scene)
        memcpy(a, x, sizeof(float) * albedo_floats(ob));
    else
        memcpy(x, a, sizeof(float) * albedo_floats(ob));
}

/* black: 0, or 0.5 when the lighting is optimised too (the image is bilinear in the two: both
 * gradients vanish at lighting = albedo = 0) */
static void albedo_start(run *r, int o, float *x, int black) {
    const float albedo0 = (r->groups & PEN_OPTIM_LIGHTING) ? 0.5f : 0.0f;
    for (size_t i = 0, n = albedo_floats(&r->sc->objects[o]); black && i < n; ++i)
        x[i] = albedo0;
}

static void albedo_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    const pen_object_grad *og = &grad->objects[o];
    const float *src = og->texture ? og->texture : og->albedo;
    for (size_t i = 0, n = albedo_floats(&r->sc->objects[o]); i < n; ++i)
        g[i] = scale * src[i];
}

/* Pose: the rotation (radians) then the translation. */
static size_t pose_items(const run *r, const pen_optim_task *t, int o) {
    (void)r, (void)t, (void)o;
    return 1;
}

static void pose_transfer(run *r, int o, float *x, int to_scene) {
    pen_pose *p = &r->sc->objects[o].pose;
    for (int k = 0; k < 3; ++k) {
        if (to_scene) {
            p->rotation_axis_angle_deg[k] = (float)((double)x[k] * DEG_PER_RAD);
            p->translation[k] = x[3 + k];
        } else {
            x[k] = (float)((double)p->rotation_axis_angle_deg[k] / DEG_PER_RAD);
            x[3 + k] = p->translation[k];
        }
    }
}

static void pose_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    (void)r;
    const pen_object_grad *og = &grad->objects[o];
    for (int k = 0; k < 3; ++k) {
        g[k] = (float)((double)(scale * og->pose.rotation_axis_angle_deg[k]) * DEG_PER_RAD);
        g[3 + k] = scale * og->pose.translation[k];
    }
}

/* Deformation: per graph node its 3x3 matrix, then per node its translation. */
static size_t deformation_items(const run *r, const pen_optim_task *t, int o) {
    (void)t;
    return (size_t)r->sc->objects[o].spheres.count;
}

static pen_status deformation_prepare(pen_context *ctx, run *r, const pen_optim_task *t, int o) {
    const pen_object *ob = &r->sc->objects[o];
    object_deform *D = &r->deform[o];
    pen_status s =
        pen__optim_deform_build(ctx, &ob->mesh, &ob->spheres, t->deformation.k, &D->graph);
    if (s) return s;
    const size_t M = (size_t)ob->spheres.count, nv = (size_t)ob->mesh.vertex_count;
    D->params = pen__calloc(ctx, 12 * M, sizeof(double), "deformation");
    D->d_params = pen__calloc(ctx, 12 * M, sizeof(double), "deformation");
    D->centres = pen__calloc(ctx, 3 * M, sizeof(double), "deformation");
    D->d_centres = pen__calloc(ctx, 3 * M, sizeof(double), "deformation");
    D->pos = pen__calloc(ctx, 3 * nv + 1, sizeof(double), "deformation");
    D->d_pos = pen__calloc(ctx, 3 * nv + 1, sizeof(double), "deformation");
    return D->params && D->d_params && D->centres && D->d_centres && D->pos && D->d_pos
               ? PEN_OK
               : PEN_ERROR_MEMORY;
}

/* (scene -> x: nothing; the scene holds the rest shape, pen__optim_deformation_rest) */
static void deformation_transfer(run *r, int o, float *x, int to_scene) {
    if (!to_scene) return;
    pen_object *ob = &r->sc->objects[o];
    object_deform *D = &r->deform[o];
    const size_t M = (size_t)D->graph.nodes;
    for (size_t i = 0; i < 12 * M; ++i)
        D->params[i] = x[i];
    pen__optim_deform_fwd(&D->graph, D->params, D->pos, D->centres);
    for (size_t i = 0; i < 3 * (size_t)D->graph.vertices; ++i)
        ob->mesh.positions[i] = (float)D->pos[i];
    for (size_t j = 0; j < M; ++j)
        for (int k = 0; k < 3; ++k)
            ob->spheres.data[4 * j + (size_t)k] = (float)D->centres[3 * j + (size_t)k];
}

/* At rest (identity matrices, zero translations) whatever `init` says: the scene holds the
 * rest shape. */
static void deformation_start(run *r, int o, float *x, int black) {
    (void)black;
    object_deform *D = &r->deform[o];
    pen__optim_deform_identity(&D->graph, D->params);
    for (size_t i = 0; i < 12 * (size_t)D->graph.nodes; ++i)
        x[i] = (float)D->params[i];
}

static void deformation_gather(run *r, const pen_render_grad *grad, int o, float *g,
                               float scale) {
    const pen_object_grad *og = &grad->objects[o];
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
        g[i] = (float)D->d_params[i];
}

/* Spheres: centre and radius per sphere (objects without spheres have no block). */
static size_t spheres_items(const run *r, const pen_optim_task *t, int o) {
    (void)t;
    const int n = r->sc->objects[o].spheres.count;
    return n > 0 ? (size_t)n : SIZE_MAX;
}

/* The smoothness term's neighbours and start (w_smooth > 0). */
static pen_status spheres_prepare(pen_context *ctx, run *r, const pen_optim_task *t, int o) {
    if (!(r->w_smooth > 0.0)) return PEN_OK;
    const pen_object *ob = &r->sc->objects[o];
    object_deform *D = &r->deform[o];
    const pen_mesh none = {0};
    const size_t n = 4 * (size_t)ob->spheres.count;
    pen_status s = pen__optim_deform_build(ctx, &none, &ob->spheres, t->spheres.k, &D->graph);
    if (s) return s;
    D->spheres0 = pen__malloc(ctx, n, sizeof(double), "initial spheres");
    D->spheres = pen__malloc(ctx, n, sizeof(double), "spheres");
    D->d_spheres = pen__malloc(ctx, n, sizeof(double), "sphere gradient");
    if (!D->spheres0 || !D->spheres || !D->d_spheres) return PEN_ERROR_MEMORY;
    for (size_t i = 0; i < n; ++i)
        D->spheres0[i] = ob->spheres.data[i];
    return PEN_OK;
}

static void spheres_transfer(run *r, int o, float *x, int to_scene) {
    pen_object *ob = &r->sc->objects[o];
    const size_t n = 4 * (size_t)ob->spheres.count;
    if (to_scene)
        memcpy(ob->spheres.data, x, sizeof(float) * n);
    else
        memcpy(x, ob->spheres.data, sizeof(float) * n);
    for (size_t i = 0; to_scene && r->deform[o].spheres && i < n; ++i)
        r->deform[o].spheres[i] = x[i];
}

static void spheres_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    const pen_object_grad *og = &grad->objects[o];
    const size_t n = 4 * (size_t)og->sphere_count;
    for (size_t i = 0; i < n; ++i)
        g[i] = scale * og->spheres[i];
    object_deform *D = &r->deform[o];
    if (D->spheres0) { /* in the loss's units, scaled like its gradient */
        memset(D->d_spheres, 0, sizeof(double) * n);
        pen__optim_spheres_energy(&D->graph, D->spheres0, D->spheres, (double)scale * r->w_smooth,
                                  D->d_spheres);
        for (size_t i = 0; i < n; ++i)
            g[i] += (float)D->d_spheres[i];
    }
}

/* Lights: PEN_LIGHT_FLOATS per disk light (a scene without lights has no block). */
static size_t lights_items(const run *r, const pen_optim_task *t, int o) {
    (void)t, (void)o;
    const int n = r->sc->lighting.light_count;
    return n > 0 ? (size_t)n : SIZE_MAX;
}

static void lights_transfer(run *r, int o, float *x, int to_scene) {
    (void)o;
    for (int l = 0; l < r->sc->lighting.light_count; ++l) {
        pen_light *li = &r->sc->lighting.lights[l];
        float *xl = x + PEN_LIGHT_FLOATS * (size_t)l;
        float *v[PEN_LIGHT_FLOATS];
        for (int k = 0; k < 3; ++k) {
            v[PEN_LIGHT_OFFSET_DIRECTION + k] = &li->direction[k];
            v[PEN_LIGHT_OFFSET_IRRADIANCE + k] = &li->irradiance[k];
        }
        v[PEN_LIGHT_OFFSET_RADIUS] = &li->angular_radius_deg;
        for (int k = 0; k < PEN_LIGHT_FLOATS; ++k) {
            if (to_scene)
                *v[k] = xl[k];
            else
                xl[k] = *v[k];
        }
    }
}

static void lights_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    (void)r, (void)o;
    for (int l = 0; l < grad->light_count; ++l) {
        const pen_light_grad *lg = &grad->lights[l];
        float *gl = g + PEN_LIGHT_FLOATS * (size_t)l;
        for (int k = 0; k < 3; ++k) {
            gl[PEN_LIGHT_OFFSET_DIRECTION + k] = scale * lg->direction[k];
            gl[PEN_LIGHT_OFFSET_IRRADIANCE + k] = scale * lg->irradiance[k];
        }
        gl[PEN_LIGHT_OFFSET_RADIUS] = scale * lg->angular_radius_deg;
    }
}

/* Exposure: log s of every view but the first (the gauge, optim.h). */
static size_t exposure_items(const run *r, const pen_optim_task *t, int o) {
    (void)r, (void)o;
    return t->view_count > 1 ? (size_t)t->view_count - 1 : SIZE_MAX;
}

static void exposure_transfer(run *r, int o, float *x, int to_scene) {
    (void)o;
    for (int v = 1; v < r->task_view_count; ++v) {
        /* log s in x: positive whatever the step, and a step is a relative change */
        if (to_scene)
            r->task_views[v].exposure = exp((double)x[v - 1]);
        else
            x[v - 1] = (float)log(pen__optim_exposure(&r->task_views[v]));
    }
}

static void exposure_gather(run *r, const pen_render_grad *grad, int o, float *g, float scale) {
    (void)grad, (void)o;
    for (int v = 1; v < r->task_view_count; ++v)
        g[v - 1] = (float)((double)scale * r->views.d_exposure[v]);
}

static const group_ops OPS[PEN__OPTIM_GROUPS] = {
    [PEN__OPTIM_G_LIGHTING] = {lighting_items, NULL, lighting_transfer, lighting_start,
                               lighting_gather},
    [PEN__OPTIM_G_ALBEDO] = {albedo_items, NULL, albedo_transfer, albedo_start, albedo_gather},
    [PEN__OPTIM_G_POSE] = {pose_items, NULL, pose_transfer, NULL, pose_gather},
    [PEN__OPTIM_G_DEFORMATION] = {deformation_items, deformation_prepare, deformation_transfer,
                                  deformation_start, deformation_gather},
    [PEN__OPTIM_G_SPHERES] = {spheres_items, spheres_prepare, spheres_transfer, NULL,
                              spheres_gather},
    [PEN__OPTIM_G_LIGHTS] = {lights_items, NULL, lights_transfer, NULL, lights_gather},
    [PEN__OPTIM_G_EXPOSURE] = {exposure_items, NULL, exposure_transfer, NULL, exposure_gather},
};

/* ---- The layout ------------------------------------------------------------------------------ */

static size_t add_segment(run *r, size_t count, float lr, pen__optim_bound bound) {
    pen__optim_segment *s = &r->segments[r->segment_count++];
    s->offset = r->n;
    s->count = count;
    s->lr = lr;
    s->bound = bound;
    r->n += count;
    return s->offset;
}

/* Group g's block for object o (-1: the scene) at the end of x, if the task optimises it and it
 * has one here; *at its offset, else SIZE_MAX. */
static pen_status add_block(pen_context *ctx, run *r, const pen_optim_task *t, int g, int o,
                            size_t *at) {
    const pen__optim_group *G = &pen__optim_groups[g];
    *at = SIZE_MAX;
    if (!(r->groups & G->bit)) return PEN_OK;
    const size_t items = OPS[g].items(r, t, o);
    if (items == SIZE_MAX) return PEN_OK;
    pen_status s = OPS[g].prepare ? OPS[g].prepare(ctx, r, t, o) : PEN_OK;
    if (s) return s;
    *at = r->n;
    for (int k = 0; k < G->segment_count; ++k) {
        const pen__optim_group_segment *seg = &G->segments[k];
        add_segment(r, items * seg->floats_per_item, pen__optim_rate_value(&t->lr, seg->rate),
                    seg->bound);
    }
    return PEN_OK;
}

pen_status pen__optim_layout(pen_context *ctx, run *r, const pen_optim_task *t) {
    const pen_scene *sc = r->sc;
    size_t scene_segments = 0, object_segments = 0;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        *(pen__optim_groups[g].per_object ? &object_segments : &scene_segments) +=
            (size_t)pen__optim_groups[g].segment_count;
    r->objects = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *r->objects, "layout");
    r->segments = pen__calloc(ctx, object_segments * (size_t)sc->object_count + scene_segments,
                              sizeof *r->segments, "segments");
    r->deform = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *r->deform, "graphs");
    if (!r->objects || !r->segments || !r->deform) return PEN_ERROR_MEMORY;
    r->w_rot = t->deformation.w_rot;
    r->w_reg = t->deformation.w_reg;
    r->w_smooth = t->spheres.w_smooth;
    /* the scene's groups first (the SH block first of all, which solve_lighting expects), then
     * per object its groups */
    pen_status s = PEN_OK;
    for (int g = 0; !s && g < PEN__OPTIM_GROUPS; ++g)
        if (!pen__optim_groups[g].per_object) s = add_block(ctx, r, t, g, -1, &r->at[g]);
        else r->at[g] = SIZE_MAX;
    for (int o = 0; !s && o < sc->object_count; ++o)
        for (int g = 0; !s && g < PEN__OPTIM_GROUPS; ++g) {
            size_t *at = &r->objects[o].at[g];
            if (pen__optim_groups[g].per_object) s = add_block(ctx, r, t, g, o, at);
            else *at = SIZE_MAX;
        }
    if (s) return s;
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

void pen__optim_transfer(run *r, int to_scene) {
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (r->at[g] != SIZE_MAX) OPS[g].transfer(r, -1, r->x + r->at[g], to_scene);
    for (int o = 0; o < r->sc->object_count; ++o)
        for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
            if (r->objects[o].at[g] != SIZE_MAX)
                OPS[g].transfer(r, o, r->x + r->objects[o].at[g], to_scene);
}

void pen__optim_lighting_take(run *r) {
    const size_t at = r->at[PEN__OPTIM_G_LIGHTING];
    if (at == SIZE_MAX) return;
    lighting_transfer(r, -1, r->x + at, 0);
    for (int k = 0; k < r->segment_count; ++k)
        if (r->segments[k].offset == at) pen__optim_project(&r->segments[k], 1, r->x);
    lighting_transfer(r, -1, r->x + at, 1);
}

void pen__optim_start(run *r, int black) {
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (r->at[g] != SIZE_MAX && OPS[g].start) OPS[g].start(r, -1, r->x + r->at[g], black);
    for (int o = 0; o < r->sc->object_count; ++o)
        for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
            if (r->objects[o].at[g] != SIZE_MAX && OPS[g].start)
                OPS[g].start(r, o, r->x + r->objects[o].at[g], black);
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
        if (r->objects[o].at[PEN__OPTIM_G_DEFORMATION] != SIZE_MAX)
            e += pen__optim_deform_energy(&D->graph, D->params, r->w_rot, r->w_reg, NULL);
        if (D->spheres0)
            e += pen__optim_spheres_energy(&D->graph, D->spheres0, D->spheres, r->w_smooth, NULL);
    }
    return e;
}

void pen__optim_gather(run *r, const pen_render_grad *grad, float scale) {
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (r->at[g] != SIZE_MAX) OPS[g].gather(r, grad, -1, r->g + r->at[g], scale);
    for (int o = 0; o < r->sc->object_count; ++o)
        for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
            if (r->objects[o].at[g] != SIZE_MAX)
                OPS[g].gather(r, grad, o, r->g + r->objects[o].at[g], scale);
}

unsigned pen__optim_grad_mask(unsigned groups, int solve) {
    unsigned wrt = 0;
    for (int g = 0; g < PEN__OPTIM_GROUPS; ++g)
        if (groups & pen__optim_groups[g].bit) wrt |= pen__optim_groups[g].grad;
    /* (a solved lighting takes no gradient) */
    return solve ? wrt & ~pen__optim_groups[PEN__OPTIM_G_LIGHTING].grad : wrt;
}
