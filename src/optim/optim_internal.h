/* Internal interface of the inverse-problem solver (src/optim/): Adam over a flat parameter
 * vector cut into segments, the stopping rule, and the ground-truth metrics. Not installed. */
#ifndef PEN_OPTIM_INTERNAL_H
#define PEN_OPTIM_INTERNAL_H

#include "core/internal.h"
#include "io/io_internal.h"
#include "optim/groups.h"
#include "penumbra/io.h"
#include "penumbra/mesh.h"
#include "penumbra/optim.h"
#include "penumbra/render.h"
#include "penumbra/spheres.h"
#include "render/loss.h"

#include <stdint.h>

/* ---- Memory (src/optim/memory.c) ------------------------------------------------------------- */

/* The machine's physical memory and the process's peak resident memory so far, in bytes (0:
 * unknown). */
double pen__optim_machine_bytes(void);
double pen__optim_peak_bytes(void);
/* *estimate = pen_optim_memory_estimate; refuses a task above settings->memory_limit (or the
 * machine's memory) with one line naming the task, the bytes and the way out. */
pen_status pen__optim_check_memory(pen_context *ctx, const pen_optim_task *t,
                                   const pen_optim_settings *settings, double *estimate);

/* ---- Adam (src/optim/adam.c) ----------------------------------------------------------------- */

#define PEN__OPTIM_MIN_RADIUS 1e-3f

/* What a view's exposure may be (pen_optim_view; views.c reads views files to it, the task's
 * checks hold tasks built in code to it, and the exposure group's log bound keeps recovered ones
 * in it): a camera's gain, 1e-6 .. 1e6 (20 stops either way, beyond any bracket), so that the
 * fits' target over the exposure (a target is at most PEN_SCENE_MAX_RADIANCE: at most 1e15) and
 * their factor s^2 stay finite (an exposure of 1e-40 is a float denormal, its target over it
 * infinite). */
#define PEN__OPTIM_MIN_EXPOSURE 1e-6
#define PEN__OPTIM_MAX_EXPOSURE 1e6

/* A run of parameters sharing a learning rate and a bound: x[offset .. offset + count). */
typedef struct pen__optim_segment {
    size_t offset, count;
    float lr;
    pen__optim_bound bound;
} pen__optim_segment;

typedef struct pen__adam {
    size_t n;
    float *m, *v; /* first and second moment estimates */
    int t;        /* steps taken */
    double beta1, beta2, eps;
} pen__adam;

/* Zeroed moments for n parameters; beta1 = 0.9, beta2 = 0.999, eps = 1e-8. */
pen_status pen__optim_adam_init(pen_context *ctx, pen__adam *adam, size_t n);
void pen__optim_adam_free(pen__adam *adam);
/* One step: x -= lr * mhat / (sqrt(vhat) + eps) per segment (bias-corrected moments), then the
 * segment's bound. Parameters outside every segment are left alone. */
void pen__optim_adam_step(pen__adam *adam, const pen__optim_segment *segments, int segment_count,
                          float *x, const float *g);
/* Projects x onto the segments' bounds. */
void pen__optim_project(const pen__optim_segment *segments, int segment_count, float *x);

/* The stopping rule: with losses[0 .. n), 1 when n > window and the lowest of the last `window`
 * losses is not more than tolerance (relative to it) below the lowest of the losses before them;
 * also 1 when that lowest loss is 0. */
int pen__optim_stalled(const double *losses, int n, int window, double tolerance);

/* ---- Embedded deformation (src/optim/deform.c) ----------------------------------------------- */

/* The graph of one object: nodes at its sphere centres, each vertex tied to its k nearest nodes,
 * each node to its k nearest other nodes (fewer when there are not enough). Doubles. */
typedef struct pen__deform_graph {
    int nodes, vertices;
    int k;           /* nodes per vertex: min(k, nodes) */
    int kn;          /* neighbours per node: min(k, nodes - 1) */
    double *g;       /* 3 per node: rest position (the sphere centre) */
    double *rest;    /* 3 per vertex: rest position */
    int *vnode;      /* k per vertex: node indices, nearest first */
    double *vweight; /* k per vertex: weights, summing to 1 */
    int *nn;         /* kn per node: neighbouring nodes */
} pen__deform_graph;

/* Builds the graph of a mesh (object space) on its spheres' centres. */
pen_status pen__optim_deform_build(pen_context *ctx, const pen_mesh *mesh,
                                   const pen_spheres *spheres, int k, pen__deform_graph *out);
void pen__optim_deform_free(pen__deform_graph *graph);
/* 12 per node: A_j row-major (9 per node) for every node, then t_j (3 per node). */
void pen__optim_deform_identity(const pen__deform_graph *graph, double *params);
/* Deformed vertex positions (3 per vertex) and sphere centres (3 per node). */
void pen__optim_deform_fwd(const pen__deform_graph *graph, const double *params, double *positions,
                           double *centres);
/* Adds the pull-back of d_positions and d_centres (either may be NULL) into d_params. */
void pen__optim_deform_bwd(const pen__deform_graph *graph, const double *params,
                           const double *d_positions, const double *d_centres, double *d_params);
/* w_rot E_rot + w_reg E_reg; adds its gradient into d_params (may be NULL). */
double pen__optim_deform_energy(const pen__deform_graph *graph, const double *params, double w_rot,
                                double w_reg, double *d_params);

/* The spheres group's smoothness w E_smooth (deform.c) over a graph built on the initial spheres
 * (no vertices); `initial` and `spheres` hold 4 values (centre, radius) per sphere, in double like
 * the deformation's parameters (the caller converts). Adds its gradient into d_spheres (may be
 * NULL). */
double pen__optim_spheres_energy(const pen__deform_graph *graph, const double *initial,
                                 const double *spheres, double w, double *d_spheres);

/* ---- Weighted loss and shadow mask (src/optim/loss.c) --------------------------------------- */

/* The task's loss weighted per pixel, by its row of the losses (groups.h): a kind that is no
 * loss is an error (the backward does nothing then). */
static inline pen_status pen__optim_loss_fwd(pen_context *ctx, pen_optim_loss kind,
                                             const pen_image *image, const pen_image *target,
                                             const float *weight, double *loss) {
    const pen__optim_loss_kind *L = pen__optim_loss_find((int)kind);
    return L ? L->fwd(ctx, image, target, weight, loss)
             : pen__error(ctx, PEN_ERROR_ARGUMENT, "loss: unknown loss %d", (int)kind);
}
static inline void pen__optim_loss_bwd(pen_optim_loss kind, const pen_image *image,
                                       const pen_image *target, const float *weight, double d_loss,
                                       pen_image *d_image) {
    const pen__optim_loss_kind *L = pen__optim_loss_find((int)kind);
    if (L) L->bwd(image, target, weight, d_loss, d_image);
}
/* The SH lighting (sh_bands^2 rows) that best explains `target` by the scene `sc` rendered
 * without shadows (least squares per channel; refitted once over the pixels the first fit's
 * shadow mask calls lit, m < 0.1). Band 3's coefficients stay 0: no unshadowed diffuse surface
 * sees them. ridge: Tikhonov weight relative to the normal equations' largest diagonal entry
 * (pen__optim_ridge_mu). */
pen_status pen__optim_fit_lighting(pen_context *ctx, const pen_scene *sc, const pen_image *target,
                                   double ridge, float (*sh)[3]);
/* The lighting-only least-squares problem of "lighting_solver": "least_squares" (optim.h): per
 * channel c the SH coefficients minimising sum_p w_p sum_c (I_pc(L) - T_pc)^2 + mu_c |L_c|^2,
 * I the scene rendered with `opt` (shadows or not) and lighting L, w = weight (NULL: 1), from one
 * render per coefficient (the render is affine in L). mu[c] < 0 on entry: set to
 * pen__optim_ridge_mu of channel c's normal equations and written back; mu[c] >= 0: used as
 * it is, so repeated solves minimise one fixed objective. The result goes into sh (bands^2).
 * state (may be NULL) is reused by the renders: a state kept across solves keeps what does not
 * depend on the lighting between them (the antialiasing adjacency, the envmap background). */
pen_status pen__optim_solve_lighting(pen_context *ctx, const pen_scene *sc,
                                     const pen_render_options *opt, pen_render_state *state,
                                     const pen_image *target,
                                     const float *weight, double ridge, double mu[3],
                                     float (*sh)[3]);
/* Solves the symmetric positive definite n x n system A x = b in place (Cholesky on A's lower
 * triangle; A and b are overwritten, x in b). Returns 0 if A is not positive definite. */
int pen__optim_solve_spd(double *A, double *b, int n);
/* Ridges (relative to the largest diagonal entry of the normal equations, pen__optim_ridge_mu):
 * the shadow mask needs an unbiased fitted image, the "fit" initial guess well-conditioned
 * coefficients. */
#define PEN__OPTIM_RIDGE_MASK 1e-9
#define PEN__OPTIM_RIDGE_INIT 1e-2
/* The shadow mask of optim.h ("shadow_weight") for the scene `sc` (the initial guess; the
 * ground truth for the metrics) against `target`: mask[p] in [0, 1] per pixel. fit_lighting:
 * U's lighting is the least-squares fit to the target instead of the scene's. Renders with the
 * context's threads. */
pen_status pen__optim_shadow_mask(pen_context *ctx, const pen_scene *sc, const pen_image *target,
                                  int fit_lighting, float *mask);

/* One image a least-squares lighting problem is fitted to: a camera (NULL: the scene's), its
 * target, per-pixel weights (NULL: 1), a factor on them (the view's share of the objective) and
 * a render state for its renders (may be NULL). */
typedef struct pen__optim_eye {
    const pen_camera *camera;
    const pen_image *target;
    const float *weight;
    double factor;
    pen_render_state *state;
} pen__optim_eye;
/* The ridge's weight mu for one channel: ridge * top / max(eyes, 1), top the largest diagonal
 * entry of the normal equations summed over `eyes` images. The ridge is a prior on the lighting
 * and each view taking part is one view's worth of data (a view's loss is a mean over its
 * pixels), so mu is relative to the views' mean normal equations: the prior stays as strong as
 * with one view while the data grow with the views. Relative to the summed equations instead,
 * the prior grew with the views and its pull stayed the same at any count (docs/optimize.md,
 * "The ridge is one view's worth"). With one image it is ridge * top. */
double pen__optim_ridge_mu(double ridge, double top, int eyes);

/* pen__optim_fit_lighting and pen__optim_solve_lighting over several images: the normal
 * equations are summed over the eyes in order (the ridge: pen__optim_ridge_mu). With one eye
 * of factor 1 and the scene's camera they give the single-image functions' results bit for
 * bit. */
pen_status pen__optim_fit_lighting_eyes(pen_context *ctx, const pen_scene *sc,
                                        const pen__optim_eye *eyes, int n, double ridge,
                                        float (*sh)[3]);
pen_status pen__optim_solve_lighting_eyes(pen_context *ctx, const pen_scene *sc,
                                          const pen_render_options *opt,
                                          const pen__optim_eye *eyes, int n, double ridge,
                                          double mu[3], float (*sh)[3]);

/* ---- The lights' global search (src/optim/lights_search.c) ---------------------------------- */

/* The angular radius (degrees) the search gives each light it creates. */
#define PEN__OPTIM_SEARCH_RADIUS_DEG 2.0
/* Creates `count` (1 .. PEN_SCENE_MAX_LIGHTS) disk lights in `sc`, which has none, by a global
 * search over directions against the eyes' images (rendered with `opt`, each eye's weights and
 * factor as in the least-squares lighting): a Fibonacci lattice over the sky and down to 5 degrees
 * below the horizon, refined coarse to fine around the best, lights added greedily; each
 * candidate scored by the l2 loss minimised over the SH lighting (solve_sh; ridge as
 * pen__optim_ridge_mu) and the irradiances (>= 0). The lights get radius
 * radius_deg and the solved irradiances; with solve_sh the scene's SH becomes the solved one.
 * Deterministic. *renders (may be NULL): the renders it took. */
pen_status pen__optim_lights_search(pen_context *ctx, pen_scene *sc,
                                    const pen_render_options *opt, const pen__optim_eye *eyes,
                                    int n, int count, int solve_sh, double ridge,
                                    double radius_deg, int *renders);

/* ---- Views (src/optim/views.c) --------------------------------------------------------------- */

/* Reads the task's "views" (or "validation_views") member at w: an array of {"camera", "target",
 * "mask", "weight"} (paths relative to the task file) or the path of a views file holding
 * {"views": [...]} (paths relative to it). Targets are read with pen_image_load_ex's
 * target_flags (0: 8-bit files decoded from sRGB; PEN_IMAGE_LOAD_RAW: taken as linear). On
 * failure what was read is left in *views, *count for pen__optim_views_free. */
pen_status pen__optim_views_parse(pen_context *ctx, const char *task_path,
                                  const pen__json_where *w, const cJSON *item,
                                  unsigned target_flags, pen_optim_view **views, int *count);
void pen__optim_views_free(pen_optim_view *views, int count);
/* Of the views' cameras, weights, targets and masks (checkpoint identity). */
uint64_t pen__optim_views_hash(const pen_optim_view *views, int count);
/* The scene seen by another camera (a shallow copy: it shares the scene's arrays). */
static inline pen_scene pen__optim_view_scene(const pen_scene *sc, const pen_camera *camera) {
    pen_scene v = *sc;
    v.camera = *camera;
    return v;
}

/* ---- Views in parallel (src/optim/parallel.c) ------------------------------------------------ */

/* The float count of a render gradient's stretches that the groups in `wrt` fill (the sh, the
 * lights, albedos and texels, poses, spheres, vertices, in a fixed order), its copy into v, and
 * the addition of such a vector into a gradient struct of the same scene. */
pen_status pen__optim_grad_floats(pen_context *ctx, const pen_render_grad *g, unsigned wrt,
                                  size_t *n);
pen_status pen__optim_grad_pack(pen_context *ctx, const pen_render_grad *g, unsigned wrt,
                                float *v);
pen_status pen__optim_grad_add(pen_context *ctx, pen_render_grad *g, unsigned wrt,
                               const float *v);
/* Rank `rank`'s contiguous block [lo, hi) of n items cut into `size` blocks. */
void pen__optim_block(int n, int rank, int size, int *lo, int *hi);
/* items: n items of item_bytes, this rank's block (pen__optim_block) filled; gathers every
 * rank's block into it. No-op without ranks or with one. */
pen_status pen__optim_exchange(pen_context *ctx, const pen_optim_ranks *ranks, int n, void *items,
                               size_t item_bytes);

/* Views rendered at once: per worker a context and a gradient struct of the scene's shape. */
typedef struct pen__optim_workers {
    int count;             /* 1: in turn, with the caller's context */
    pen_context **ctx;     /* per worker (NULL with one) */
    pen_render_grad *grad; /* per worker */
} pen__optim_workers;
/* requested as pen_optim_settings.view_workers (0: the context's thread count), at most views. */
pen_status pen__optim_workers_init(pen_context *ctx, pen__optim_workers *W, int requested,
                                   int views, const pen_scene *sc);
void pen__optim_workers_free(pen__optim_workers *W);
/* One view's share of a pass: item j of the pass, with the worker's context and gradient. */
typedef pen_status (*pen__optim_view_job)(pen_context *ctx, void *user, int j,
                                          pen_render_grad *grad);
/* Runs job for j in [lo, hi), W->count at once; returns the first failure in j order (its
 * message copied into ctx). */
pen_status pen__optim_workers_run(pen_context *ctx, pen__optim_workers *W, int lo, int hi,
                                  pen__optim_view_job job, void *user);

/* What a view's forward gives the sum, gathered across ranks as it is. The exposure's
 * derivative travels here rather than in the gradient vector: the forward makes it (from the
 * loss's image gradient), it stays a double, and it exists when no render gradient is wanted
 * (the "exposure" group alone). */
typedef struct pen__optim_view_share {
    double loss;         /* w_v E_v */
    double d_log_exposure; /* d(w_v E_v)/d(log s_v); 0 in a pass without gradient */
} pen__optim_view_share;

/* The loop's per-view state. factor[i] = weight_i / (the sum of view i's pixel weights): 0 for a
 * view left out (weight 0 or empty mask), which is neither rendered nor differentiated. */
typedef struct pen__optim_views {
    int count;
    const pen_optim_view *views;
    pen_render_state **state;       /* per view: the loop's renders */
    pen_render_state **solve_state; /* per view: the least-squares lighting's renders */
    float **weight;  /* per view: mask x shadow weights per pixel; NULL: every pixel 1 */
    double *factor;
    pen_image *img, *d_img; /* the last render (times the exposure) and its loss gradient, per
                               view */
    double *d_exposure;     /* per view: d(w_v E_v)/d(log s_v) of the last render with grad */
    pen_image *eye_target;  /* per view: the target over the exposure (pen__optim_view_eye);
                               allocated where the exposure may differ from 1 */
    size_t max_pixels;
    int taking_part; /* views with factor > 0 (counted by pen__optim_views_init) */
    /* the passes (pen__optim_views_plan): the views taking part, in view order, and per one of
     * them its forward's share (loss: w_v E_v and d(w_v E_v)/d(log s_v)) and its gradient
     * vector (grad_floats, pen__optim_grad_pack for wrt) */
    int *order;
    int lo, hi; /* this process's block of order */
    const pen_optim_ranks *ranks;
    pen__optim_view_share *loss;
    float *grads;
    size_t grad_floats;
    unsigned wrt;
    pen__optim_workers workers;
} pen__optim_views;

/* Allocates the per-view state for the task's views; shadow_weight > 0: each view's loss weights
 * 1 + s m (pen__optim_shadow_mask of the scene as it is now, fit_lighting as there). */
pen_status pen__optim_views_init(pen_context *ctx, pen__optim_views *V, const pen_optim_task *t,
                                 double shadow_weight, int fit_lighting);
void pen__optim_views_free_run(pen__optim_views *V);
/* The views taking part, as least-squares eyes (states: the solve's when `solve`); returns how
 * many were written (eyes: room for V->count). */
int pen__optim_views_eyes(const pen__optim_views *V, int solve, pen__optim_eye *eyes);
/* A view's exposure: 0, in a view made in code before the field existed (zeroed), stands for 1. */
static inline double pen__optim_exposure(const pen_optim_view *v) {
    return v->exposure > 0.0 ? v->exposure : 1.0;
}
/* The view as a least-squares eye (its camera, target, mask and `factor`): with an exposure
 * s != 1 the loss w (s I - T)^2 is s^2 w (I - T/s)^2, so the target is T/s, written into
 * *scratch (created when it has no data: ctx may be NULL when it has), and the factor is times
 * s^2. The state is NULL. */
pen_status pen__optim_view_eye(pen_context *ctx, const pen_optim_view *v, double factor,
                               pen_image *scratch, pen__optim_eye *e);
/* Multiplies the image by a view's exposure (nothing to do at 1). */
void pen__optim_view_expose(pen_image *img, double exposure);
/* How the passes run: this process's block of the views taking part (set->ranks), the views
 * at once (set->view_workers), the gradient vectors for the groups in wrt. */
pen_status pen__optim_views_plan(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                 const pen_optim_settings *set, unsigned wrt);
/* Renders every view taking part (this process's block; the others' shares gathered), each
 * render times its view's exposure, *loss = sum_v w_v E_v in view order; with grad also each of
 * the block's d_img (with respect to the unscaled render) and every view's d_exposure. */
pen_status pen__optim_views_fwd(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                const pen_render_options *opt, pen_optim_loss kind, int grad,
                                double *loss);
/* Adds every view's gradient (of the last pen__optim_views_fwd with grad) into grad, in view
 * order: the block's computed each into its own vector, the others' gathered; wrt as planned. */
pen_status pen__optim_views_bwd(pen_context *ctx, pen__optim_views *V, const pen_scene *sc,
                                const pen_render_options *opt, pen_render_grad *grad);
/* Renders the scene from every view (finals, count of them) and measures it over each view's
 * mask (metrics); sq (may be NULL) accumulates the squared error and the value count over the
 * views of positive weight. Both arrays are allocated (also on failure: free them). The renders
 * share one state, and through it the ray-traced transfers of `with` (may be NULL: the loop's
 * first view state), so that the transfers are traced once, not once per view. */
pen_status pen__optim_views_finish(pen_context *ctx, const pen_scene *sc,
                                   const pen_render_options *opt, pen_optim_loss kind,
                                   const pen_optim_view *views, int count,
                                   pen_render_state *with, pen_optim_view_metrics **metrics,
                                   pen_image **finals, double sq[2]);

/* ---- The loss curve (src/optim/loss_plot.c) ---------------------------------------------------- */

/* loss.svg's text (*svg, allocated) and loss.png's pixels (png, allocated) of r's loss curve: log10
 * of the loss through the stages and the iterations, one layout drawn both ways. */
pen_status pen__optim_loss_plots(pen_context *ctx, const pen_optim_result *r, int shadows,
                                 char **svg, pen_image *png);

/* ---- Checkpoints (src/optim/checkpoint.c) ---------------------------------------------------- */

/* What a checkpoint belongs to; a resumed run must match all of it. */
typedef struct pen__optim_identity {
    size_t n; /* parameters */
    const pen__optim_segment *segments;
    int segment_count;
    unsigned groups;
    int loss, shadows, width, height;
    double shadow_weight;
    int lighting_solver;   /* pen_optim_lighting_solver */
    double lighting_ridge;
    int ridge_views;      /* the views taking part (1: a single target): pen__optim_ridge_mu */
    int graph_k;          /* the regularisers: deformation (k; w_rot, w_reg, 0) or spheres */
    double weights[3];    /* (k; w_smooth, 0, 0); zeros without either group */
    uint64_t target_hash; /* of the target's pixels */
    uint64_t init_hash;   /* of the parameter vector of the initial guess */
    uint64_t scene_hash;  /* of the initial scene and the loop's render options
                             (pen__optim_scene_hash) */
} pen__optim_identity;

/* A hash of everything the loop's renders depend on besides the target: the render options and
 * the scene's camera, lighting (SH and disk lights; the map's pixels where the background shows
 * it), shadow settings, ground, background and objects (meshes, textures and their filter,
 * albedos, poses, spheres with their overlap weights). Taken at the initial guess, it is the same
 * in a run and in its resumption from the same task. */
uint64_t pen__optim_scene_hash(const pen_scene *sc, const pen_render_options *opt);

/* The loop's state after `iteration` Adam steps; the arrays are the loop's own buffers. */
typedef struct pen__optim_state {
    int iteration;      /* Adam steps taken; x holds the parameters after them */
    int recorded;       /* losses[0 .. recorded) are known: iteration or iteration + 1 */
    int best_iteration; /* of the lowest loss among them (-1: none yet) */
    double best_loss, seconds;
    float *x, *best;    /* n each */
    pen__adam *adam;    /* moments (n each) and step count */
    double *losses;
} pen__optim_state;

/* Writes the state atomically: a temporary file beside `path`, fsync, rename, fsync of the
 * folder. */
pen_status pen__optim_checkpoint_save(pen_context *ctx, const char *path,
                                      const pen__optim_identity *id, const pen__optim_state *st);
/* Reads a checkpoint into st's buffers (x, best, adam->m, adam->v: id->n each; losses: room for
 * max_losses values). Refuses, with one line naming the file, a file that is not a checkpoint,
 * is truncated or damaged (checksum), belongs to another problem (id), or is beyond the
 * iteration limit (recorded > max_losses). */
pen_status pen__optim_checkpoint_load(pen_context *ctx, const char *path,
                                      const pen__optim_identity *id, int max_losses,
                                      pen__optim_state *st);
/* The lighting solver a checkpoint was made with (pen_optim_lighting_solver), or -1 when the
 * file cannot be read as one (the load then says why). */
int pen__optim_checkpoint_solver(const char *path);

/* ---- Output folder (src/optim/output.c) ------------------------------------------------------ */

/* dir/name, malloc'd (NULL on exhaustion, recorded in ctx). */
char *pen__optim_join(pen_context *ctx, const char *dir, const char *name);
/* Creates the folder `dir` if it does not exist (its parent must). */
pen_status pen__optim_make_dir(pen_context *ctx, const char *dir);

/* ---- Task checks (src/optim/task.c) ---------------------------------------------------------- */

/* The task's own consistency (groups, weights, target or views, rates), before a run. */
pen_status pen__optim_task_check(pen_context *ctx, const pen_optim_task *t);
/* Every group asked for has something to move (once the {"fit": N} sphere sets exist). */
pen_status pen__optim_task_check_groups(pen_context *ctx, const pen_optim_task *t);

/* ---- Metrics (src/optim/evaluate.c) ---------------------------------------------------------- */

/* Fails when the task's ground truth does not match the scene's structure where the metrics of
 * the optimised groups need it (object count, band count, texture size, vertex count). */
pen_status pen__optim_check_truth(pen_context *ctx, const pen_optim_task *task);
/* Fills every metric of `m` that applies (the others are left alone) for the recovered scene
 * against the task's ground truth; image_rmse is the caller's. Renders (albedo views, texel
 * coverage) with the context's threads. */
pen_status pen__optim_metrics(pen_context *ctx, const pen_optim_task *task, pen_optim_metrics *m);
/* The angle in degrees between two axis-angle rotations (given in degrees), in double. */
double pen__optim_rotation_angle_deg(const float a_deg[3], const float b_deg[3]);

/* ---- The parameter vector (src/optim/params.c) ----------------------------------------------- */

/* Where each object's parameters sit in x: the offset of each per-object group's block (groups.h;
 * SIZE_MAX: not optimised, or nothing to move). */
typedef struct pen__optim_object_layout {
    size_t at[PEN__OPTIM_GROUPS];
} pen__optim_object_layout;

/* An object's deformation graph and its double-precision work buffers. */
typedef struct pen__optim_object_deform {
    pen__deform_graph graph;
    double *params, *d_params; /* 12 per node */
    double *pos, *d_pos;       /* 3 per vertex */
    double *centres, *d_centres; /* 3 per node */
    double *spheres0, *spheres, *d_spheres; /* the spheres group's smoothness: 4 per sphere */
} pen__optim_object_deform;

typedef struct pen__optim_run {
    pen_scene *sc;
    pen_render_options opt;   /* every render of the run (shadows or not) */
    uint64_t model_hash;      /* the scene's model as given (shadow keys, texture filters),
                                 before the run switched it (pen_render_grad_model): part of
                                 the checkpoint's identity with the scene as rendered */
    unsigned groups;
    /* the offset of each scene group's block (groups.h; SIZE_MAX: not optimised, or nothing to
     * move): the SH coefficients (first in x), the disk lights (PEN_LIGHT_FLOATS each), the log
     * exposures of views 1 .. */
    size_t at[PEN__OPTIM_GROUPS];
    pen_optim_view *task_views; /* the task's views, where the exposures go (multi-view) */
    int task_view_count;
    pen__optim_object_layout *objects;
    pen__optim_segment *segments;
    int segment_count;
    size_t n;
    float *x, *g;
    float *best;              /* the parameters of the lowest loss so far */
    pen__optim_object_deform *deform;    /* per object, when deformation is optimised */
    double w_rot, w_reg;
    double w_smooth;          /* the spheres group's smoothness weight */
    float *weight;            /* per pixel loss weights (shadow_weight > 0), else NULL */
    /* "lighting_solver": "least_squares": the lighting is solved, not stepped */
    int solve;
    /* The lighting ridge (optim.h) is a term of the loss when `ridged`: always with least
     * squares, with Adam when its ridge is > 0 */
    int ridged;
    double ridge;             /* "lighting_ridge", the default resolved */
    double mu[3];             /* the ridge per channel, fixed at the initial guess */
    double weight_sum;        /* of the loss weights (the pixel count without them) */
    float *solved_for;        /* the parameters the lighting in x was solved for */
    pen_render_state *solve_state; /* the solves' renders (kept: see solve_lighting) */
    int solved;               /* solved_for is valid */
    int multi;                /* the task has "views" (views.c): the loss runs over them */
    pen__optim_views views;
} pen__optim_run;


/* Cuts x into segments for the task's groups (the table of groups.h: the scene's groups, then per
 * object its own) and allocates x, g, best and the deformation graphs' buffers (r->sc, r->groups
 * set by the caller). */
pen_status pen__optim_layout(pen_context *ctx, pen__optim_run *r, const pen_optim_task *t);
void pen__optim_run_free(pen__optim_run *r);
/* to_scene 0: scene -> x; 1: x -> scene (deformed positions and sphere centres included). */
void pen__optim_transfer(pen__optim_run *r, int to_scene);
/* The lighting the scene holds now (a least-squares solve, a fit) into x, projected onto its
 * bound (PEN__BOUND_SH), and back into the scene; nothing when the lighting is not optimised. */
void pen__optim_lighting_take(pen__optim_run *r);
double pen__optim_regularisers(pen__optim_run *r);
/* The lighting ridge's term of the loss, sum_c mu_c |L_c|^2 / (3 weight_sum) over nb
 * coefficients; with d (may be NULL) its gradient with respect to sh is added to d. */
double pen__optim_ridge_term(const double mu[3], double weight_sum, int nb, const float (*sh)[3],
                             double (*d)[3]);
/* The ridge's term at the run's lighting (0 when it is not in the loss). */
double pen__optim_ridge_loss(const pen__optim_run *r);
/* The groups' starts in x, after x took the scene (transfer 0): the deformation at rest, and
 * with `black` the supplement's initial guesses (5.2: optimised lighting and albedo at 0, the
 * albedo at 0.5 when both are optimised). */
void pen__optim_start(pen__optim_run *r, int black);
/* r->g = scale x the render gradient in x's layout, plus the regularisers' gradients. */
void pen__optim_gather(pen__optim_run *r, const pen_render_grad *grad, float scale);
/* The render gradient groups the optimised groups need. */
unsigned pen__optim_grad_mask(unsigned groups, int solve);

#endif
