/* The renderer over flat structs and borrowed arrays (include/penumbra/flat.h), for bindings.
 *
 * Design
 * - No rendering logic of its own: a pen_flat_scene is turned into a pen_scene whose arrays point
 *   into the caller's memory (never freed here), and pen_render_fwd / pen_render_bwd do the
 *   work, so the binding and the CLI render the same scene identically.
 * - Checks at this boundary are those pen_render's own validation cannot make because they are
 *   about the flat description itself, and must pass before a pen_scene can be built over it:
 *   NULL arrays behind positive counts, counts and sizes out of range, per-vertex UVs whose count
 *   does not match the vertices. Everything else (indices in range, NaN/Inf, radii, the camera
 *   and so the output image's size) is left to the renderer's one scene validation
 *   (src/scene/validate.c, which pen_render_fwd runs before it writes), whose messages name the
 *   object.
 * - The backward allocates a pen_render_grad shaped like the scene, asks only for the groups
 *   whose output arrays are set, and adds the result into them.
 */
#include "penumbra/flat.h"

#include "core/internal.h"
#include "penumbra/fit.h"
#include "penumbra/io.h"
#include "penumbra/scene.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* More objects than any scene JSON holds; keeps the allocation below bounded. */
#define MAX_OBJECTS 65536

pen_flat_scene pen_flat_scene_default(void) {
    pen_flat_scene s;
    memset(&s, 0, sizeof s);
    s.width = 64, s.height = 64;
    s.fov_y_deg = 40.0f;
    s.eye[1] = 1.0f, s.eye[2] = 3.0f;
    s.target[1] = 0.5f;
    s.up[1] = 1.0f;
    s.sh_bands = 4;
    s.exp_method = PEN_SH_EXP_CALIBRATED;
    s.ground_enabled = 1;
    s.ground_albedo[0] = s.ground_albedo[1] = s.ground_albedo[2] = 0.8f;
    s.ground_half_size = 4.0f;
    s.envmap_scale = 1.0f;
    s.shadows = 1;
    s.antialias = 1;
    return s;
}

/* ---- Flat description -> pen_scene ------------------------------------------------------------
 */

static pen_status image_view(pen_context *ctx, const char *what, int w, int h, const float *data,
                             pen_image *out) {
    memset(out, 0, sizeof *out);
    if (w == 0 && h == 0) return PEN_OK;
    if (w < 1 || h < 1 || w > PEN_IMAGE_MAX_DIM || h > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "flat scene: %s: size %dx%d out of range [1, %d]", what, w, h,
                          PEN_IMAGE_MAX_DIM);
    if (!data) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: %s: no pixels", what);
    out->width = w, out->height = h, out->channels = 3;
    out->data = (float *)data; /* borrowed; the renderer only reads it */
    return PEN_OK;
}

static pen_status object_view(pen_context *ctx, int o, const pen_flat_object *f, pen_object *ob) {
    memset(ob, 0, sizeof *ob);
    if (f->vertex_count < 1 || f->triangle_count < 1 || !f->positions || !f->indices)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "flat scene: objects[%d]: needs vertices and triangles (%d, %d)", o,
                          f->vertex_count, f->triangle_count);
    if (f->texture_filter != PEN_TEXTURE_FILTER_FOOTPRINT &&
        f->texture_filter != PEN_TEXTURE_FILTER_POINT)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "flat scene: objects[%d]: texture_filter %d is not 0 (footprint) or 1 "
                          "(point)",
                          o, f->texture_filter);
    ob->texture_filter = (pen_texture_filter)f->texture_filter;
    pen_mesh *m = &ob->mesh;
    m->vertex_count = f->vertex_count;
    m->triangle_count = f->triangle_count;
    m->positions = (float *)f->positions;
    m->indices = (uint32_t *)f->indices;
    if (f->uv_count < 0 || (f->uv_count > 0 && !f->uvs))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: objects[%d]: bad uv array", o);
    if (f->uv_count > 0) {
        if (!f->uv_indices && f->uv_count != f->vertex_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "flat scene: objects[%d]: %d uvs for %d vertices (per-vertex uvs "
                              "need one per vertex, or give uv indices)",
                              o, f->uv_count, f->vertex_count);
        m->uv_count = f->uv_count;
        m->uvs = (float *)f->uvs;
        m->uv_indices = (uint32_t *)(f->uv_indices ? f->uv_indices : f->indices);
    }
    char what[48];
    snprintf(what, sizeof what, "objects[%d].texture", o);
    pen_status s =
        image_view(ctx, what, f->texture_width, f->texture_height, f->texture, &ob->texture);
    if (s) return s;
    memcpy(ob->albedo, f->albedo, sizeof ob->albedo);
    if (f->sphere_count < 0 || (f->sphere_count > 0 && !f->spheres))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: objects[%d]: bad sphere array", o);
    ob->spheres.count = f->sphere_count;
    ob->spheres.data = (float *)f->spheres;
    ob->spheres.weight = f->sphere_count > 0 ? (float *)f->sphere_weights : NULL;
    memcpy(ob->pose.rotation_axis_angle_deg, f->pose, 3 * sizeof(float));
    memcpy(ob->pose.translation, f->pose + 3, 3 * sizeof(float));
    ob->pose.scale = f->pose[6];
    return PEN_OK;
}

/* Room for n pen_objects in *buf (holding *cap), grown as needed; contents are not kept. */
static pen_status object_room(pen_context *ctx, pen_object **buf, int *cap, int n) {
    if (*buf && *cap >= n) return PEN_OK;
    free(*buf);
    *buf = pen__calloc(ctx, (size_t)n, sizeof **buf, "flat objects");
    *cap = *buf ? n : 0;
    return *buf ? PEN_OK : PEN_ERROR_MEMORY;
}

/* Fills *sc from *f; sc->objects is *buf, grown to the object count (free it when done, never the
 * arrays it points to). */
static pen_status scene_view(pen_context *ctx, const pen_flat_scene *f, pen_object **buf, int *cap,
                             pen_scene *sc) {
    memset(sc, 0, sizeof *sc);
    if (f->sh_bands < 1 || f->sh_bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: sh_bands %d out of range [1, %d]",
                          f->sh_bands, PEN_SH_MAX_BANDS);
    if (!f->sh) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: no SH lighting");
    if ((f->overlap != 0 && f->overlap != 1) ||
        (f->ground_occlusion != 0 && f->ground_occlusion != 1))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "flat scene: overlap %d or ground_occlusion %d is not 0 or 1", f->overlap,
                          f->ground_occlusion);
    if (f->object_count < 0 || f->object_count > MAX_OBJECTS ||
        (f->object_count > 0 && !f->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: bad object list (%d objects)",
                          f->object_count);
    if (f->light_count < 0 || f->light_count > PEN_SCENE_MAX_LIGHTS ||
        (f->light_count > 0 && !f->lights))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat scene: bad light list (%d lights, at most "
                          "%d)", f->light_count, PEN_SCENE_MAX_LIGHTS);
    /* The lights as given (the renderer validates them with the scene). */
    sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
    sc->lighting.light_count = f->light_count;
    for (int l = 0; l < f->light_count; ++l) {
        const float *v = f->lights + PEN_LIGHT_FLOATS * (size_t)l;
        pen_light *L = &sc->lighting.lights[l];
        memcpy(L->direction, v + PEN_LIGHT_OFFSET_DIRECTION, sizeof L->direction);
        L->angular_radius_deg = v[PEN_LIGHT_OFFSET_RADIUS];
        memcpy(L->irradiance, v + PEN_LIGHT_OFFSET_IRRADIANCE, sizeof L->irradiance);
    }
    pen_camera *c = &sc->camera;
    c->width = f->width, c->height = f->height, c->fov_y_deg = f->fov_y_deg;
    memcpy(c->eye, f->eye, sizeof c->eye);
    memcpy(c->target, f->target, sizeof c->target);
    memcpy(c->up, f->up, sizeof c->up);
    c->fx = f->fx, c->fy = f->fy, c->cx = f->cx, c->cy = f->cy;
    sc->sh_bands = f->sh_bands;
    memcpy(sc->lighting.sh, f->sh, 3 * sizeof(float) * (size_t)(f->sh_bands * f->sh_bands));
    pen_status s = image_view(ctx, "envmap", f->envmap_width, f->envmap_height, f->envmap,
                              &sc->lighting.envmap);
    if (s) return s;
    sc->lighting.scale = f->envmap_scale;
    sc->lighting.rotation_y_deg = f->envmap_rotation_y_deg;
    sc->shadow.epsilon = f->epsilon;
    sc->shadow.exp = (pen_sh_exp_method)f->exp_method;
    sc->shadow.overlap = (pen_shadow_overlap)f->overlap;
    sc->shadow.ground = (pen_shadow_ground)f->ground_occlusion;
    if (f->self_shadow != PEN_SELF_TRANSFER && f->self_shadow != PEN_SELF_SPHERES)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "flat scene: self_shadow %d is not 0 (transfer) or 1 (spheres)",
                          f->self_shadow);
    sc->shadow.self = (pen_shadow_self)f->self_shadow;
    sc->shadow.ground_shadow = (pen_shadow_ground_shadow)f->ground_shadow; /* validated there */
    sc->shadow.ground_grid = f->ground_grid;
    sc->ground.enabled = f->ground_enabled != 0;
    sc->ground.height = f->ground_height;
    memcpy(sc->ground.albedo, f->ground_albedo, sizeof sc->ground.albedo);
    sc->ground.half_size = f->ground_half_size;
    sc->background_envmap = f->background_envmap != 0;
    memcpy(sc->background, f->background, sizeof sc->background);
    if (f->object_count == 0) return PEN_OK;
    if ((s = object_room(ctx, buf, cap, f->object_count))) return s;
    sc->objects = *buf;
    sc->object_count = f->object_count;
    for (int o = 0; o < f->object_count; ++o)
        if ((s = object_view(ctx, o, &f->objects[o], &sc->objects[o]))) return s;
    return PEN_OK;
}

/* The options: the model is the scene's (scene_view), as in the JSON. */
static pen_render_options options_of(const pen_flat_scene *f) {
    pen_render_options opt = pen_render_options_default();
    opt.shadows = f->shadows != 0;
    opt.antialias = f->antialias != 0;
    return opt;
}

/* ---- Forward and backward -------------------------------------------------------------------- */

/* The flat forward with the caller's state and object buffer (see scene_view). */
static pen_status flat_fwd(pen_context *ctx, const pen_flat_scene *f, pen_render_state *state,
                           pen_object **buf, int *cap, float *image) {
    if (!f || !image) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat render: NULL argument");
    pen_scene sc;
    pen_status s = scene_view(ctx, f, buf, cap, &sc);
    if (s) return s;
    const pen_render_options opt = options_of(f);
    /* The image has the camera's size by construction; the renderer validates the camera (its
     * size in [1, PEN_IMAGE_MAX_DIM]) before it writes. */
    pen_image img = {f->width, f->height, 3, image};
    return pen_render_fwd(ctx, &sc, &opt, state, &img);
}

pen_status pen_flat_render_fwd(pen_context *ctx, const pen_flat_scene *f, pen_render_state *state,
                               float *image) {
    pen_object *objects = NULL;
    int cap = 0;
    pen_status s = flat_fwd(ctx, f, state, &objects, &cap, image);
    free(objects);
    return s;
}

static void add_n(float *dst, const float *src, size_t n) {
    for (size_t i = 0; i < n; ++i)
        dst[i] += src[i];
}

unsigned pen_flat_grad_groups(const pen_flat_scene *f, const pen_flat_grad *g) {
    unsigned wrt = 0;
    if (!f || !g) return 0;
    if (g->sh) wrt |= PEN_GRAD_LIGHTING;
    if (g->ground_albedo) wrt |= PEN_GRAD_ALBEDO;
    if (g->lights && f->light_count > 0) wrt |= PEN_GRAD_LIGHTS;
    for (int o = 0; g->objects && o < f->object_count; ++o) {
        const pen_flat_object_grad *og = &g->objects[o];
        if (og->texture || og->albedo) wrt |= PEN_GRAD_ALBEDO;
        if (og->spheres) wrt |= PEN_GRAD_SPHERES;
        if (og->pose) wrt |= PEN_GRAD_POSE;
        if (og->positions) wrt |= PEN_GRAD_VERTICES;
    }
    return wrt;
}

/* Adds the render gradient of object o into the caller's arrays. */
static void scatter_object(const pen_object_grad *src, const pen_object *ob,
                           const pen_flat_object_grad *dst) {
    if (dst->positions) add_n(dst->positions, src->positions, 3 * (size_t)src->vertex_count);
    if (dst->texture && ob->texture.data)
        add_n(dst->texture, src->texture, 3 * (size_t)src->texel_count);
    if (dst->albedo) add_n(dst->albedo, src->albedo, 3);
    if (dst->spheres && src->sphere_count > 0)
        add_n(dst->spheres, src->spheres, 4 * (size_t)src->sphere_count);
    if (dst->pose) {
        add_n(dst->pose, src->pose.rotation_axis_angle_deg, 3);
        add_n(dst->pose + 3, src->pose.translation, 3);
        dst->pose[6] += src->pose.scale;
    }
}

/* Whether g is shaped like sc (as pen_render_grad_create would make it). */
static int grad_fits(const pen_render_grad *g, const pen_scene *sc) {
    if (g->bands != sc->sh_bands || g->object_count != sc->object_count ||
        g->light_count != sc->lighting.light_count)
        return 0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const pen_object_grad *og = &g->objects[o];
        const int texels = ob->texture.data ? ob->texture.width * ob->texture.height : 0;
        if (og->vertex_count != ob->mesh.vertex_count || og->sphere_count != ob->spheres.count ||
            og->texel_count != texels || (og->texture != NULL) != (ob->texture.data != NULL) ||
            (ob->texture.data && ob->texture.channels != 3))
            return 0;
    }
    return 1;
}

/* The flat backward with the caller's state, object buffer and gradient (*g zeroed or made
 * anew to fit the scene; kept for the next call). */
static pen_status flat_bwd(pen_context *ctx, const pen_flat_scene *f, pen_render_state *state,
                           pen_object **buf, int *cap, pen_render_grad *g, const float *d_image,
                           const pen_flat_grad *grad) {
    if (!f || !d_image || !grad)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat render backward: NULL argument");
    pen_scene sc;
    pen_status s = scene_view(ctx, f, buf, cap, &sc);
    if (s) return s;
    if (grad_fits(g, &sc)) {
        pen_render_grad_zero(g);
    } else {
        pen_render_grad_free(g);
        if ((s = pen_render_grad_create(ctx, &sc, g))) return s;
    }
    const pen_render_options opt = options_of(f);
    const pen_image d_img = {f->width, f->height, 3, (float *)d_image};
    s = pen_render_bwd(ctx, &sc, &opt, state, &d_img, pen_flat_grad_groups(f, grad), g);
    if (s) return s;
    const int nc = sc.sh_bands * sc.sh_bands;
    for (int i = 0; grad->sh && i < nc; ++i)
        add_n(grad->sh + 3 * i, g->sh[i], 3);
    if (grad->ground_albedo) add_n(grad->ground_albedo, g->ground_albedo, 3);
    for (int l = 0; grad->lights && l < g->light_count; ++l) {
        float *dst = grad->lights + PEN_LIGHT_FLOATS * (size_t)l;
        add_n(dst + PEN_LIGHT_OFFSET_DIRECTION, g->lights[l].direction, 3);
        dst[PEN_LIGHT_OFFSET_RADIUS] += g->lights[l].angular_radius_deg;
        add_n(dst + PEN_LIGHT_OFFSET_IRRADIANCE, g->lights[l].irradiance, 3);
    }
    for (int o = 0; grad->objects && o < sc.object_count; ++o)
        scatter_object(&g->objects[o], &sc.objects[o], &grad->objects[o]);
    return PEN_OK;
}

pen_status pen_flat_render_bwd(pen_context *ctx, const pen_flat_scene *f, pen_render_state *state,
                               const float *d_image, const pen_flat_grad *grad) {
    pen_object *objects = NULL;
    int cap = 0;
    pen_render_grad g;
    memset(&g, 0, sizeof g);
    pen_status s = flat_bwd(ctx, f, state, &objects, &cap, &g, d_image, grad);
    pen_render_grad_free(&g);
    free(objects);
    return s;
}

pen_status pen_flat_grad_check(pen_context *ctx, const pen_flat_scene *f, unsigned wrt) {
    if (!f) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat gradient check: NULL scene");
    pen_object *objects = NULL;
    int cap = 0;
    pen_scene sc;
    pen_status s = scene_view(ctx, f, &objects, &cap, &sc);
    const pen_render_options opt = options_of(f);
    if (!s) s = pen_render_grad_check(ctx, &sc, &opt, wrt);
    free(objects);
    return s;
}

unsigned pen_flat_grad_model(pen_flat_scene *f, pen_flat_object *objects, unsigned wrt) {
    if (!f) return 0;
    /* The rule applied to a minimal pen_scene holding what it reads and writes. */
    const int n = objects && f->object_count > 0 ? f->object_count : 0;
    pen_object *view = n ? calloc((size_t)n, sizeof *view) : NULL;
    pen_scene sc;
    memset(&sc, 0, sizeof sc);
    sc.shadow.self = (pen_shadow_self)f->self_shadow;
    sc.shadow.ground_shadow = (pen_shadow_ground_shadow)f->ground_shadow;
    sc.object_count = view ? n : 0;
    sc.objects = view;
    for (int o = 0; o < sc.object_count; ++o) {
        view[o].texture_filter = (pen_texture_filter)objects[o].texture_filter;
        view[o].texture.data = (float *)objects[o].texture; /* only tested for NULL */
    }
    const unsigned changed = pen_render_grad_model(&sc, wrt);
    f->self_shadow = (int)sc.shadow.self;
    f->ground_shadow = (int)sc.shadow.ground_shadow;
    for (int o = 0; o < sc.object_count; ++o)
        objects[o].texture_filter = (int)view[o].texture_filter;
    free(view);
    return changed;
}

/* ---- A renderer kept across calls ------------------------------------------------------------ */

struct pen_flat_renderer {
    pen_render_state *state;
    pen_object *objects; /* scene_view's buffer */
    int object_cap;
    pen_render_grad grad; /* flat_bwd's, reused while the scene keeps its shape */
};

pen_status pen_flat_renderer_create(pen_context *ctx, pen_flat_renderer **out) {
    *out = pen__calloc(ctx, 1, sizeof **out, "flat renderer");
    if (!*out) return PEN_ERROR_MEMORY;
    pen_status s = pen_render_state_create(ctx, &(*out)->state);
    if (s) {
        free(*out);
        *out = NULL;
    }
    return s;
}

void pen_flat_renderer_free(pen_flat_renderer *r) {
    if (!r) return;
    pen_render_state_free(r->state);
    pen_render_grad_free(&r->grad);
    free(r->objects);
    free(r);
}

pen_render_state *pen_flat_renderer_state(pen_flat_renderer *r) {
    return r ? r->state : NULL;
}

pen_status pen_flat_renderer_fwd(pen_context *ctx, pen_flat_renderer *r, const pen_flat_scene *f,
                                 float *image) {
    if (!r) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat renderer: NULL renderer");
    return flat_fwd(ctx, f, r->state, &r->objects, &r->object_cap, image);
}

pen_status pen_flat_renderer_bwd(pen_context *ctx, pen_flat_renderer *r, const pen_flat_scene *f,
                                 const float *d_image, const pen_flat_grad *grad) {
    if (!r) return pen__error(ctx, PEN_ERROR_ARGUMENT, "flat renderer backward: NULL renderer");
    return flat_bwd(ctx, f, r->state, &r->objects, &r->object_cap, &r->grad, d_image, grad);
}

/* ---- Scenes from JSON ------------------------------------------------------------------------ */

struct pen_flat_loaded {
    pen_scene scene;
    pen_flat_scene flat;
    pen_flat_object *objects;
    float sh[3 * PEN_SH_MAX_COEFFS];
    float lights[PEN_LIGHT_FLOATS * PEN_SCENE_MAX_LIGHTS];
};

void pen_flat_loaded_free(pen_flat_loaded *l) {
    if (!l) return;
    pen_scene_free(&l->scene);
    free(l->objects);
    free(l);
}

const pen_flat_scene *pen_flat_loaded_scene(const pen_flat_loaded *l) {
    return &l->flat;
}

int pen_flat_loaded_fit_request(const pen_flat_loaded *l, int o) {
    if (!l || o < 0 || o >= l->scene.object_count) return -1;
    return l->scene.objects[o].fit_spheres;
}

/* The flat view of one loaded object (arrays owned by the scene). */
static pen_status flat_object(pen_context *ctx, const pen_object *ob, int o, pen_flat_object *f) {
    memset(f, 0, sizeof *f);
    f->vertex_count = ob->mesh.vertex_count;
    f->triangle_count = ob->mesh.triangle_count;
    f->positions = ob->mesh.positions;
    f->indices = ob->mesh.indices;
    f->uv_count = ob->mesh.uv_count;
    f->uvs = ob->mesh.uvs;
    f->uv_indices = ob->mesh.uv_indices;
    if (ob->texture.data) {
        if (ob->texture.channels != 3)
            return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                              "flat scene: objects[%d]: texture has %d channels, not 3", o,
                              ob->texture.channels);
        f->texture_width = ob->texture.width;
        f->texture_height = ob->texture.height;
        f->texture = ob->texture.data;
    }
    memcpy(f->albedo, ob->albedo, sizeof f->albedo);
    f->sphere_count = ob->spheres.count;
    f->spheres = ob->spheres.data;
    f->sphere_weights = ob->spheres.weight;
    f->texture_filter = (int)ob->texture_filter;
    memcpy(f->pose, ob->pose.rotation_axis_angle_deg, 3 * sizeof(float));
    memcpy(f->pose + 3, ob->pose.translation, 3 * sizeof(float));
    f->pose[6] = ob->pose.scale;
    return PEN_OK;
}

/* Fills l->flat (and l->objects, l->sh) from l->scene. */
static pen_status flatten(pen_context *ctx, pen_flat_loaded *l) {
    const pen_scene *sc = &l->scene;
    pen_flat_scene *f = &l->flat;
    *f = pen_flat_scene_default();
    f->width = sc->camera.width, f->height = sc->camera.height;
    f->fov_y_deg = sc->camera.fov_y_deg;
    memcpy(f->eye, sc->camera.eye, sizeof f->eye);
    memcpy(f->target, sc->camera.target, sizeof f->target);
    memcpy(f->up, sc->camera.up, sizeof f->up);
    f->fx = sc->camera.fx, f->fy = sc->camera.fy, f->cx = sc->camera.cx, f->cy = sc->camera.cy;
    f->sh_bands = sc->sh_bands;
    memcpy(l->sh, sc->lighting.sh, sizeof l->sh);
    f->sh = l->sh;
    /* The scene's lights, those found in its environment map included. */
    f->light_count = sc->lighting.light_count;
    f->lights = l->lights;
    for (int i = 0; i < sc->lighting.light_count; ++i) {
        const pen_light *L = &sc->lighting.lights[i];
        float *v = l->lights + PEN_LIGHT_FLOATS * i;
        memcpy(v + PEN_LIGHT_OFFSET_DIRECTION, L->direction, 3 * sizeof(float));
        v[PEN_LIGHT_OFFSET_RADIUS] = L->angular_radius_deg;
        memcpy(v + PEN_LIGHT_OFFSET_IRRADIANCE, L->irradiance, 3 * sizeof(float));
    }
    f->epsilon = sc->shadow.epsilon;
    f->exp_method = (int)sc->shadow.exp;
    f->overlap = (int)sc->shadow.overlap;
    f->ground_occlusion = (int)sc->shadow.ground;
    f->self_shadow = (int)sc->shadow.self;
    f->ground_shadow = (int)sc->shadow.ground_shadow;
    f->ground_grid = sc->shadow.ground_grid;
    f->ground_enabled = sc->ground.enabled;
    f->ground_height = sc->ground.height;
    memcpy(f->ground_albedo, sc->ground.albedo, sizeof f->ground_albedo);
    f->ground_half_size = sc->ground.half_size;
    f->background_envmap = sc->background_envmap;
    memcpy(f->background, sc->background, sizeof f->background);
    const pen_image *env = &sc->lighting.envmap;
    if (env->data) {
        if (env->channels != 3)
            return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                              "flat scene: environment map has %d channels, not 3", env->channels);
        f->envmap_width = env->width, f->envmap_height = env->height;
        f->envmap = env->data;
    }
    f->envmap_rotation_y_deg = sc->lighting.rotation_y_deg;
    f->envmap_scale = sc->lighting.scale;
    f->object_count = sc->object_count;
    if (sc->object_count > 0) {
        l->objects = pen__calloc(ctx, (size_t)sc->object_count, sizeof *l->objects, "flat objects");
        if (!l->objects) return PEN_ERROR_MEMORY;
        for (int o = 0; o < sc->object_count; ++o) {
            pen_status s = flat_object(ctx, &sc->objects[o], o, &l->objects[o]);
            if (s) return s;
        }
    }
    f->objects = l->objects;
    return PEN_OK;
}

pen_status pen_flat_scene_load(pen_context *ctx, const char *path, int fit_spheres,
                               pen_flat_loaded **out) {
    *out = NULL;
    pen_flat_loaded *l = pen__calloc(ctx, 1, sizeof *l, "loaded scene");
    if (!l) return PEN_ERROR_MEMORY;
    pen_status s = pen_scene_load(ctx, path, &l->scene);
    /* Made ready as every door makes it; the flat scene carries the overlap weights, so the
     * binding's renders do not solve them again for every render state. */
    if (!s) s = pen_scene_prepare(ctx, &l->scene, fit_spheres, NULL);
    if (!s) s = flatten(ctx, l);
    if (s) {
        pen_flat_loaded_free(l);
        return s;
    }
    *out = l;
    return PEN_OK;
}
