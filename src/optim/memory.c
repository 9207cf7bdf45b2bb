/* The memory a run will hold, predicted from the task's sizes before its views' render states
 * are made (pen_optim_memory_estimate, optim.h), and the machine's, so that a task too large for
 * it is refused with the numbers instead of running out of memory an hour in.
 *
 * Design
 * - What is counted. The loaded task (meshes, textures, the map, the targets and masks), every
 *   render state the run keeps (one per view, a second per view when least squares solves the
 *   lighting, and one more for the evaluations that render without a kept state) at
 *   pen_render_state_bytes, each view's images (its render, the loss's gradient, the target
 *   over the exposure, the weights), the traces the states share (each transferred object's
 *   nodes and the ground's grid, with the occluders kept for the per-pixel fractions), and the
 *   process's libraries. Under MPI a rank keeps the states of its own block of views only.
 * - An estimate from sizes: a buffer counts when the frame writes it (pages never written are
 *   not resident), and a transferred object's nodes are taken as its vertices (coarse meshes get
 *   more, few in bytes). Measured against the peak resident memory in bench/NOTES.md ("Memory
 *   before a task"): 0.89-1.32 of it. The default limit is the machine's physical memory, not a
 *   container's limit.
 * - Under MPI each rank judges its own block: a library caller with its own ranks must treat
 *   one rank's refusal as the task's (the CLI aborts every rank).
 */
#include "optim/optim_internal.h"

#include <stdio.h>
#include <sys/resource.h>
#include <unistd.h>

/* The program and its libraries (9 MB for `penumbra --help`) with what loading and the first
 * traces leave resident beyond the arrays counted here: fitted on a 1-view 16 x 16 task of
 * untextured Spot, 32.9 MB at its peak (bench/NOTES.md). */
#define PROCESS_BYTES 24e6
/* A texture's resident bytes over its float texels': the texels, their filtered levels and the
 * decoded image they were converted from (Spot's 1024² texture: 32 MB against 12.6 MB). */
#define TEXTURE_FACTOR 2.5
/* The ground's grid nodes per side (ground_shadow.c's default) and Embree's bytes per triangle
 * of a kept scene. */
#define GRID_NODES 96.0
#define BVH_TRIANGLE_BYTES 128.0

static double image_bytes(const pen_image *im) {
    return im->data ? 4.0 * im->width * im->height * im->channels : 0.0;
}

/* The scene's own arrays: meshes, textures, the map. */
static double scene_bytes(const pen_scene *sc) {
    double b = image_bytes(&sc->lighting.envmap);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        b += 24.0 * ob->mesh.vertex_count + 12.0 * ob->mesh.triangle_count;
        b += 8.0 * ob->mesh.uv_count + (ob->mesh.uv_count ? 12.0 * ob->mesh.triangle_count : 0.0);
        b += TEXTURE_FACTOR * image_bytes(&ob->texture);
        b += 20.0 * ob->spheres.count;
    }
    return b;
}

/* The traces the states share: per transferred object bands^2 + lights floats per node (its
 * vertices) and its occluders, and the ground's grid. */
static double trace_bytes(const pen_scene *sc, int transfer) {
    if (!transfer || sc->shadow.self != PEN_SELF_TRANSFER) return 0.0;
    const double per_node = 4.0 * (sc->sh_bands * sc->sh_bands + sc->lighting.light_count);
    double b = 0.0, triangles = 0.0;
    for (int o = 0; o < sc->object_count; ++o) {
        b += per_node * sc->objects[o].mesh.vertex_count + 12.0 * sc->objects[o].mesh.triangle_count;
        triangles += sc->objects[o].mesh.triangle_count;
    }
    if (sc->ground.enabled && sc->shadow.ground_shadow == PEN_GROUND_SHADOW_TRANSFER) {
        const double n = sc->shadow.ground_grid > 0 ? sc->shadow.ground_grid : GRID_NODES;
        b += per_node * n * n + BVH_TRIANGLE_BYTES * triangles;
    }
    return b;
}

/* The parameter vector and its copies (x, its gradient, the best iterate, Adam's two moments)
 * and the renderer's gradient of it: 6 floats per parameter, of which only texels are many; a
 * deformation graph's vertices in double, with their gradient. */
static double param_bytes(const pen_optim_task *t) {
    double n = 3.0 * PEN_SH_MAX_COEFFS, b = 0.0;
    for (int o = 0; o < t->scene.object_count; ++o) {
        const pen_object *ob = &t->scene.objects[o];
        if ((t->optimize & PEN_OPTIM_ALBEDO) && ob->texture.data)
            n += 3.0 * ob->texture.width * ob->texture.height;
        n += 16.0 + 4.0 * ob->spheres.count;
        if (t->optimize & PEN_OPTIM_DEFORMATION) b += 48.0 * ob->mesh.vertex_count;
    }
    return b + 24.0 * n;
}

double pen_optim_memory_estimate(pen_context *ctx, const pen_optim_task *t,
                                 const pen_optim_settings *settings) {
    if (!t) return 0.0;
    const pen_scene *sc = &t->scene;
    const int threads = pen__threads(ctx);
    const unsigned wrt = t->optimize & PEN_GRAD_ALL; /* the groups share the renderer's bits */
    const int solve = t->optimize == PEN_OPTIM_LIGHTING &&
                      t->lighting_solver != PEN_OPTIM_LIGHTING_ADAM;
    /* the transfer unless the groups need the spheres' gradients (pen_render_grad_model) */
    const int transfer = !(t->optimize & (PEN_OPTIM_POSE | PEN_OPTIM_DEFORMATION |
                                          PEN_OPTIM_SPHERES | PEN_OPTIM_LIGHTS));
    double b = PROCESS_BYTES + scene_bytes(sc) + trace_bytes(sc, transfer) + param_bytes(t);
    b += image_bytes(&t->target) + 2.0 * image_bytes(&t->target); /* render, its gradient */
    pen_scene v = *sc;
    if (t->view_count <= 0) {
        /* the loop's state(s) and the evaluations' own, which no backward uses */
        b += (1.0 + solve) * pen_render_state_bytes(sc, wrt, threads) +
             pen_render_state_bytes(sc, 0, threads);
        return b;
    }
    /* this rank's block of the views taking part (weight > 0), as pen__optim_views_plan cuts
     * them; every rank renders every view and validation view at the end (their finals) */
    const pen_optim_ranks *R =
        settings && settings->ranks && settings->ranks->size > 1 ? settings->ranks : NULL;
    int taking = 0, lo = 0, hi = 0;
    for (int i = 0; i < t->view_count; ++i)
        taking += t->views[i].weight > 0.0;
    hi = taking;
    if (R) pen__optim_block(taking, R->rank, R->size, &lo, &hi);
    for (int i = 0; i < t->validation_count; ++i) {
        const pen_optim_view *w = &t->validation[i];
        const double px = (double)w->camera.width * w->camera.height;
        b += image_bytes(&w->target) + (w->mask ? 4.0 * px : 0.0) + 12.0 * px;
    }
    double largest = 0.0;
    for (int i = 0, j = -1; i < t->view_count; ++i) {
        const pen_optim_view *w = &t->views[i];
        const double px = (double)w->camera.width * w->camera.height;
        b += image_bytes(&w->target) + (w->mask ? 4.0 * px : 0.0) + 12.0 * px; /* its final */
        j += w->weight > 0.0;
        if (!(w->weight > 0.0) || j < lo || j >= hi) continue;
        v.camera = w->camera;
        const double st = pen_render_state_bytes(&v, wrt, threads);
        const double eval = pen_render_state_bytes(&v, 0, threads);
        largest = eval > largest ? eval : largest;
        /* its state(s); its render, gradient, target over the exposure and weights */
        const int eye = (t->optimize & PEN_OPTIM_EXPOSURE) ||
                        (w->exposure != 1.0 && w->exposure != 0.0);
        b += (1.0 + solve) * st + (24.0 + 12.0 * eye + (w->mask ? 4.0 : 0.0)) * px;
    }
    return b + largest; /* the evaluations' own state, which no backward uses */
}

double pen__optim_machine_bytes(void) {
    const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    return pages > 0 && page > 0 ? (double)pages * (double)page : 0.0;
}

double pen__optim_peak_bytes(void) {
    struct rusage u;
    return getrusage(RUSAGE_SELF, &u) == 0 ? 1024.0 * (double)u.ru_maxrss : 0.0; /* KiB */
}

pen_status pen__optim_check_memory(pen_context *ctx, const pen_optim_task *t,
                                   const pen_optim_settings *settings, double *estimate) {
    const double need = pen_optim_memory_estimate(ctx, t, settings);
    const double limit = settings && settings->memory_limit > 0.0 ? settings->memory_limit
                                                                  : pen__optim_machine_bytes();
    *estimate = need;
    if (!(limit > 0.0) || need <= limit) return PEN_OK;
    char views[64] = "";
    if (t->view_count > 0) snprintf(views, sizeof views, " for %d views", t->view_count);
    return pen__error(ctx, PEN_ERROR_MEMORY,
                      "%s: needs about %.1f GB of memory%s, more than the %.1f GB %s; use fewer or "
                      "smaller views, or share the views between MPI ranks",
                      t->path ? t->path : "optimize", need / 1e9, views, limit / 1e9,
                      settings && settings->memory_limit > 0.0 ? "allowed (--memory-limit)"
                                                               : "this machine has");
}
