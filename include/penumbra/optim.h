/* penumbra/optim.h -- inverse problems: recover lighting, albedo and pose from an image by
 * gradient descent through the differentiable soft-shadow renderer (`penumbra optimize`).
 *
 * A task (docs/design.md sec. 3.5, docs/optimize.md) names an initial scene, a target image (linear
 * radiance, usually made by `penumbra reference` from a ground-truth scene), the parameter groups
 * to optimise and optionally the ground-truth scene the metrics are computed from:
 *
 *     { "scene": "initial.json" or {...inline scene...},
 *       "target": "target.exr",
 *       "optimize": ["lighting", "albedo", "pose"],
 *       "iterations": 500, "lr": 0.01 or {"lighting": 0.01, ...}, "loss": "l2",
 *       "tolerance": 0.001, "window": 50, "init": "black",
 *       "ground_truth": "truth.json" or {...} }
 *
 * Usage (a task file, run as `penumbra optimize TASK.json -o out` runs it):
 *
 *     // given: ctx, task_path
 *     pen_optim_task task;
 *     pen_optim_task_load(ctx, task_path, &task);
 *     pen_optim_settings set = pen_optim_settings_default();
 *     pen_optim_result res;
 *     pen_optim_run(ctx, &task, &set, &res);            // task.scene: the recovered scene
 *     printf("%d iterations, loss %g\n", res.iterations, res.final_loss);
 *     pen_optim_write(ctx, "out", &task, &set, &res);   // result.json, scene.json, renders
 *     pen_optim_result_free(&res);
 *     pen_optim_task_free(&task);
 *
 * The optimiser is Adam with one learning rate per parameter group (supplement section 5.1:
 * 1e-2 for lighting, texture and pose). Rotations are optimised as axis-angle vectors in radians
 * (the scene stores degrees), so a learning rate of 1e-2 moves a rotation by about half a degree
 * per step. Albedos are kept in [0, 1], sphere radii positive, SH coefficients within
 * +-PEN_SCENE_MAX_SH (solved ones too) and exposures in [1e-6, 1e6], so that the scene and views
 * files pen_optim_write writes read back. It stops after `iterations` steps or
 * when the objective has stopped falling: the lowest loss of the last `window` iterations is
 * less than `tolerance` (relative) below the lowest before them. This is the supplement's rule
 * (Theta_{n-1} - Theta_n) / Theta_n <= 0.001 applied to best losses over a window, because
 * Adam's loss wobbles, and on pose tasks rises for tens of steps, long before the optimum. The recovered
 * parameters are those of the lowest loss seen (the best iterate), since with a constant step
 * the last iterate wanders around the optimum by about one learning rate.
 *
 * Initial guesses (supplement section 5.2, `"init": "black"`, the default): optimised lighting
 * and albedos (texels or constant) start at 0; when both are optimised together the albedo starts
 * at 0.5 instead, because at lighting = albedo = 0 both gradients vanish. The pose (and spheres)
 * start where the task's scene puts them: give a pose near the truth. `"init": "scene"` starts
 * every group from the task's scene. `"init": "fit"` is "black" except that optimised lighting
 * starts at the SH lighting that best explains the target without shadows (a linear least-
 * squares fit, one unshadowed render per coefficient): from black lighting the pose gradient of
 * a joint lighting + pose problem is noise that Adam's normalised step turns into full steps.
 */
#ifndef PENUMBRA_OPTIM_H
#define PENUMBRA_OPTIM_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/scene.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Parameter groups ("optimize" names in the task JSON). Each is the bit of the render's gradient
 * group of the same meaning (render.h PEN_GRAD_*: a task's groups are the render groups it
 * moves); "deformation" is PEN_GRAD_VERTICES, which it moves, and "exposure", no render group, a
 * bit of its own. */
#define PEN_OPTIM_LIGHTING 1u     /* "lighting": SH coefficients, every band and channel */
#define PEN_OPTIM_ALBEDO 2u       /* "albedo": every object's texels, or its constant albedo */
#define PEN_OPTIM_SPHERES 4u      /* "spheres": every object's sphere centres and radii */
#define PEN_OPTIM_POSE 8u         /* "pose": every object's rotation and translation (not scale) */
#define PEN_OPTIM_DEFORMATION 16u /* "deformation": every object's embedded deformation graph on
                                     its sphere centres (moves vertices and spheres) */
#define PEN_OPTIM_LIGHTS 32u      /* "lights": every disk light's direction, angular radius and
                                     irradiance: the scene's (given, or found in its map), or,
                                     when it has none, light_count lights that a global search
                                     over directions creates before the descent */
#define PEN_OPTIM_EXPOSURE 128u   /* "exposure": each view's exposure but the first's (a task with
                                     2 or more views; the first is the gauge, below) */

/* The image loss ("loss" in the task JSON): "l2" the mean squared error, "l1" the mean absolute
 * error over pixels and channels. Another value is refused by pen_optim_run. */
typedef enum pen_optim_loss { PEN_OPTIM_LOSS_L2 = 0, PEN_OPTIM_LOSS_L1 = 1 } pen_optim_loss;

/* Learning rates per group (Adam step sizes, in the parameter's units). */
typedef struct pen_optim_lr {
    float lighting;    /* SH coefficient (radiance) */
    float albedo;      /* texel or constant albedo */
    float rotation;    /* radians of the axis-angle vector */
    float translation; /* scene units */
    float spheres;     /* scene units (object space), centres and radii */
    float deformation_rotation;    /* entries of the graph nodes' 3x3 matrices */
    float deformation_translation; /* the graph nodes' translations (object space) */
    float lights;      /* disk lights: each direction component (a unit vector, renormalised after
                          each step), the angular radius in degrees and the irradiance */
    float exposure;    /* natural log of a view's exposure (1e-2: about 1% per step) */
} pen_optim_lr;

/* 1e-2, and 1e-3 for the deformation matrices (supplement section 5.1). */
PEN_API pen_optim_lr pen_optim_lr_default(void);

/* The embedded deformation graph (supplement section 3; Sumner et al. 2007): nodes at each
 * object's sphere centres, each carrying a 3x3 matrix A_j and a translation t_j; a vertex follows
 * its k nearest nodes, v' = sum_j w_j (A_j (v - g_j) + g_j + t_j) with w_j = (1 - d_j / d_max)^2
 * normalised (d_max: the distance to the (k+1)-th node); a sphere moves with its node. The
 * objective adds w_rot E_rot (A_j's columns orthonormal) and w_reg E_reg (neighbouring nodes,
 * the k nearest, agree on where each other's map puts them) to the image loss. */
typedef struct pen_optim_deformation {
    int k;        /* default 4 (the supplement uses 4 to 8) */
    double w_rot; /* default 1e-4 */
    double w_reg; /* default 1e-3 */
} pen_optim_deformation;

PEN_API pen_optim_deformation pen_optim_deformation_default(void);

/* The "spheres" group's regulariser: w_smooth E_smooth, E_smooth = sum_j sum_{k in N(j)}
 * |d_j - d_k|^2 with d_j = (centre, radius) of sphere j minus its initial value and N(j) its k
 * nearest spheres at the start: neighbouring spheres move and grow alike. The defaults are
 * pen_optim_spheres_default()'s (what pen_optim_task_load starts from); w_smooth = 0 turns the
 * term off, and then k is not used. */
typedef struct pen_optim_spheres {
    int k;           /* default 4 */
    double w_smooth; /* default 1e-3, in the units of the mean-squared image loss */
} pen_optim_spheres;

PEN_API pen_optim_spheres pen_optim_spheres_default(void);

/* The shadow-weighted loss (task key "shadow_weight" = s >= 0). Per pixel p of the target T,
 *     m_p = clamp(1 - Y(T_p) / Y(U_p), 0, 1),   Y = the mean of the three channels,
 * the fraction of the light an unshadowed model predicts that the target lacks (0 where
 * Y(U_p) <= 1e-6). U is the initial scene (after the initial guesses) rendered without shadows.
 * When the lighting is optimised its initial value is a guess (black by default), so U's
 * lighting is instead fitted to the target: the least-squares SH lighting of the unshadowed
 * render (the image is affine in it), refitted once over the pixels with m < 0.1 so that the
 * shadows do not darken it. The loss is
 *     sum_p w_p sum_c rho(I_pc - T_pc) / (3 sum_p w_p),   w_p = 1 + s m_p,
 * rho = r^2 (l2) or |r| (l1); with s = 0 the plain mean. The mask is computed once, before the
 * first iteration, and held fixed: the weights are constants of the objective. (The task's
 * "shadow_weight" field below.) */

/* How optimised lighting is updated (task key "lighting_solver").
 * ADAM ("adam"): Adam steps on the SH coefficients like every other group (supplement 5.1).
 * LEAST_SQUARES ("least_squares"): the render is affine in the lighting, so for the current
 * values of every other group the best lighting is a linear least-squares problem per channel
 * (one render per coefficient, sh_bands^2 + 1 renders a solve; the l2 loss, weighted by
 * "shadow_weight"). It is solved exactly before each render whenever the other parameters have
 * changed, and Adam moves only the other groups, along the loss's gradient at the solved
 * lighting (which is the gradient of the loss minimised over the lighting: variable projection).
 * A task that optimises the lighting alone ends in that one solve (0 Adam steps, stop reason
 * "solved"). Needs the l2 loss.
 * AUTO ("auto", the default): LEAST_SQUARES when the task optimises the lighting alone with the
 * l2 loss (the solve is the optimum of the stated loss, reached at once), ADAM otherwise (a
 * joint task would pay a solve at every iteration, and exposure, lights and the l1 loss need
 * Adam). pen_optim_run resolves it before anything is written (result.json and the checkpoints
 * name the solver used; resuming a checkpoint, "auto" takes the checkpoint's solver).
 *
 * The ridge (task key "lighting_ridge" = rho >= 0). One view determines some combinations of the
 * coefficients badly, so the stated loss carries a prior on the lighting, for both solvers:
 *     loss = image loss + sum_c mu_c |L_c|^2 / (3 sum_p w_p)
 * (w_p the shadow weights, 1 without them; in a multi-view task sum_p w_p is 1: the views'
 * weights over their masks' sizes normalise), mu_c = rho times the largest diagonal entry of
 * channel c's normal equations at the initial guess, divided by the number of views taking part
 * (weight > 0 and a non-empty mask, each counted once whatever its weight, so that scaling every
 * weight leaves the solution as it is; 1 with a single target), then held fixed for the run:
 * the prior weighs as much as one view, whatever the number of views, so that more views
 * outweigh it (relative to the summed equations, it would grow with them and its pull would
 * never fade). Least squares
 * minimises it exactly; Adam steps on it (the term's gradient joins the lighting's). The default
 * (NaN in the struct) is 1e-2 with least squares and 0 with Adam (Adam's runs stay those of a
 * plain image loss); a task may set it for either. The lights search (light_count) solves its SH
 * with rho as given, 1e-2 by default whatever the solver. */
typedef enum pen_optim_lighting_solver {
    PEN_OPTIM_LIGHTING_ADAM = 0,
    PEN_OPTIM_LIGHTING_LEAST_SQUARES = 1,
    PEN_OPTIM_LIGHTING_AUTO = 2
} pen_optim_lighting_solver;

/* The ridge least squares (and the lights search) take when the task sets none (above). */
#define PEN_OPTIM_LIGHTING_RIDGE_DEFAULT 1e-2

/* One observed view of a multi-view task (task key "views", docs/optimize.md): a camera of its
 * own, the image it saw, which of its pixels count and how much the view counts.
 *
 * Exposure: the render of a view is multiplied by its exposure s before the loss (and in its
 * final render and metrics): photos of one scene taken with other shutter times, apertures or
 * gains. The group "exposure" optimises log s of every view but the first: a common factor on
 * every exposure is the same image as that factor on the lighting (and on the lights'
 * irradiance), so the first view's exposure stays as given and fixes the scale (the gauge);
 * the recovered lighting is in the units the first view's exposure implies. */
typedef struct pen_optim_view {
    pen_camera camera;  /* look-at or calibrated; its own size */
    pen_image target;   /* 3 channels, linear (see target_linear), the camera's size */
    char *target_path;
    float *mask;        /* one per pixel, 1 (counts) or 0; NULL: every pixel counts */
    char *mask_path;    /* NULL without a mask */
    double weight;      /* >= 0 (default 1) */
    double exposure;    /* in [1e-6, 1e6] (default 1; 0, a view zeroed in code, stands for 1);
                           pen_optim_run leaves the recovered ones here */
} pen_optim_view;

typedef struct pen_optim_task {
    char *path;         /* the task file (messages, relative paths) */
    pen_scene scene;    /* the initial guess; pen_optim_run leaves the recovered scene here */
    pen_image target;   /* 3 channels, the camera's size; empty in a multi-view task */
    char *target_path;
    int target_linear;  /* "target_encoding": 0 ("srgb", the default): 8-bit PNG/JPEG targets
                           (the task's and the views') are decoded from sRGB to linear; 1
                           ("linear"): their codes / 255 are taken as linear values. EXR and HDR
                           targets are linear either way. Set before the target is loaded. */
    unsigned optimize;  /* PEN_OPTIM_* */
    int iterations;     /* at most this many Adam steps (default 500) */
    pen_optim_lr lr;
    pen_optim_loss loss;
    double tolerance;   /* stopping rule (default 1e-3) */
    int window;         /* stopping rule window (default 50; 1 is close to the supplement's rule) */
    int init_black;     /* 1: supplement 5.2 initial guesses (default); 0: the scene's values */
    int init_fit;       /* 1 ("init": "fit"): as init_black, but optimised lighting starts at the
                           least-squares fit of the unshadowed render to the target */
    pen_optim_deformation deformation;
    pen_optim_spheres spheres; /* with the "spheres" group */
    double shadow_weight; /* >= 0 (default 0): stresses the target's shadows in the loss,
                             below */
    pen_optim_lighting_solver lighting_solver; /* default PEN_OPTIM_LIGHTING_AUTO */
    double lighting_ridge; /* the ridge, relative (above); NaN (the default): 1e-2 with least
                              squares, 0 with Adam */
    int has_ground_truth;
    pen_scene ground_truth; /* zeroed when has_ground_truth == 0 */
    /* Multi-view ("views"): the loss is sum_v weight_v * loss_v, loss_v the view's loss over its
     * mask's pixels (a view whose weight is 0 or whose mask is empty adds nothing); the scene's
     * own camera is then not rendered except by the ground-truth metrics. view_count 0: the
     * single-view task of "target" and the scene's camera. */
    int view_count;            /* 0 .. PEN_CAMERA_SET_MAX (penumbra/io.h) */
    pen_optim_view *views;
    int validation_count;      /* "validation_views": rendered at the end, not in the loss */
    pen_optim_view *validation;
    int light_count;    /* "lights" on a scene without lights: how many the global search
                           creates, 1 .. PEN_SCENE_MAX_LIGHTS (default 1). The search tries
                           directions over the sky and down to 5 degrees below the horizon,
                           each a disk of 2 degrees whose irradiance and the SH lighting (when
                           optimised) are solved by least squares, keeps the best and refines
                           it, adds lights greedily, and starts the descent there with the
                           solved irradiances and SH (docs/optimize.md, "Lights") */
} pen_optim_task;

/* A task holding the defaults pen_optim_task_load starts from (500 iterations, the lr above,
 * l2, tolerance 1e-3, window 50, black initial guesses, the "auto" lighting solver with its
 * solver's ridge (NaN), the deformation and spheres defaults) and nothing else: no scene, target
 * or groups. */
PEN_API pen_optim_task pen_optim_task_default(void);

/* Loads a task JSON; paths (scene, target, ground truth) are relative to the task file. Errors
 * name the file and the key ("task.json: optimize[1]: unknown group \"colour\""); errors inside
 * an inline scene read "task.json:scene: camera.width: ...". The target is an image of the scene
 * camera's size: linear EXR or HDR, or 8-bit PNG or JPEG decoded from sRGB (target_linear). The
 * scene's {"fit": N} sphere requests are left for pen_optim_run. On failure *out is zeroed. */
PEN_API pen_status pen_optim_task_load(pen_context *ctx, const char *path, pen_optim_task *out);
/* The same with the target image taken from `target` (a path as given, not relative to the task;
 * NULL: the task's "target") instead of the task's "target" key, which is then not read at all. */
PEN_API pen_status pen_optim_task_load_ex(pen_context *ctx, const char *path, const char *target,
                                          pen_optim_task *out);
/* The same from JSON text; `path` names it and is the base of its relative paths. */
PEN_API pen_status pen_optim_task_parse(pen_context *ctx, const char *json_text, const char *path,
                                        pen_optim_task *out);
/* Replaces the task's target by the image at `path` (.exr, .hdr, .png, .jpg; the scene camera's
 * size; 8-bit files decoded as task->target_linear says). On failure the task is unchanged. */
PEN_API pen_status pen_optim_task_set_target(pen_context *ctx, pen_optim_task *task,
                                             const char *path);
/* Frees everything the task owns and zeroes it; NULL is a no-op. */
PEN_API void pen_optim_task_free(pen_optim_task *task);

/* Called after every iteration with the loss of that iteration's render; return non-zero to
 * stop early (e.g. on Ctrl-C: the run then ends normally with converged = 0, interrupted = 1). */
typedef int (*pen_optim_progress_fn)(void *user, int iteration, int iterations, double loss);

/* Checkpoints and snapshots. With `outdir` set, pen_optim_run writes OUTDIR/checkpoint.bin
 * every `checkpoint_every` iterations and when the run ends (limit, convergence, interrupt):
 * the parameter vector, Adam's moments and step count, the best iterate and its loss, the loss
 * history (the stopping rule's whole state) and the seconds spent, each write atomic (temporary
 * file, fsync, rename). With `resume` it first loads that checkpoint and continues from it: the
 * task run to N iterations in one go and run to K, then resumed to N, give the same parameters,
 * losses and outputs bit for bit (same task, target, shadows and thread count; the renderer
 * reduces in a fixed order). A checkpoint of another task (parameter layout, target, initial
 * guess, loss, shadow weight, shadows, lighting solver and ridge, regularisers) or a damaged one
 * is refused with one line naming the file and what differs; so is a multi-view checkpoint of
 * version 3 or 4 whose lighting took a ridge (the ridge weighed as all the views then,
 * docs/optimize.md "The ridge is one view's worth"). `snapshot_every` > 0 writes the render of every K-th iterate to
 * OUTDIR/snapshots/iter_NNNNN.png. The folder is created when first written to. */
typedef struct pen_optim_settings {
    int shadows;                    /* 0: optimise with V == 1 (`--no-shadows`, the baseline) */
    pen_optim_progress_fn progress; /* may be NULL */
    void *progress_user;
    const char *outdir;   /* NULL: no checkpoints, no snapshots, no resume */
    int checkpoint_every; /* > 0: also every K iterations; 0: only at the end */
    int snapshot_every;   /* > 0: a snapshot every K iterations; 0: none */
    int resume;           /* 1: continue from OUTDIR/checkpoint.bin (it must exist) */
    /* Multi-view tasks ("views"): how many views render at once, each with threads / view_workers
     * of the context's threads (OpenMP nesting permitting, else one). 0: automatic (as many as
     * there are threads when the process has at least as many views or nesting is on, else 1);
     * 1: one view after the other, each with every thread. The
     * result does not depend on it: the renderer's results do not depend on its thread count,
     * and the views' gradients are summed in view order (docs/optimize.md, "Several views"). */
    int view_workers;
    const struct pen_optim_ranks *ranks; /* NULL: one process; else the views are split */
    /* Bytes the run may hold (pen_optim_memory_estimate); a task estimated above it is refused
     * before its views' render states are made. 0: the machine's physical memory (not a
     * container's limit). Under ranks each judges its own block: one rank's refusal is the task's. */
    double memory_limit;
} pen_optim_settings;

/* Several processes sharing one multi-view task (`mpirun`: cli/mpi.c implements it with MPI).
 * Every rank runs pen_optim_run on the same task and settings; the views taking part are cut
 * into `size` contiguous blocks in view order, rank r renders and differentiates block r, and
 * each iteration gathers every view's loss and gradient on every rank, where they are summed in
 * view order: every rank takes the same step, and the result is bit for bit that of one process.
 * Only rank 0 writes checkpoints and snapshots (resuming reads OUTDIR on every rank: a shared
 * folder). A least-squares lighting solve is not split: every rank solves it over all views. A
 * rank that fails leaves the others waiting in the next gather: the caller aborts them (the CLI
 * calls MPI_Abort). */
typedef struct pen_optim_ranks {
    int rank, size;
    /* Collective: `all` has room for the items of every rank in rank order (counts[r] items of
     * item_bytes bytes for rank r); each rank has written its own at their place; on return
     * every rank's are there. Returns 0 on success. */
    int (*allgather)(void *user, void *all, const int *counts, size_t item_bytes);
    void *user;
} pen_optim_ranks;

/* shadows = 1, no callback, no output folder. */
PEN_API pen_optim_settings pen_optim_settings_default(void);

/* Metrics against the ground truth; NaN where a metric does not apply (no ground truth, or the
 * group was not optimised). */
typedef struct pen_optim_metrics {
    double image_rmse;          /* final render vs target, all pixels and channels */
    double lighting_rel_error;  /* |L - L_true| / |L_true| over all SH coefficients and channels */
    double lighting_rel_error_b2; /* the same over bands 0..2 only, the bands an unshadowed
                                     diffuse surface sees (band 3 reaches it only through
                                     shadows); when there are more than 3 bands */
    double lighting_rel_error_sky; /* the radiance's error over the upper hemisphere (y > 0),
                                     the integral of its square relative to the truth's: the
                                     light the ground does not hide */
    double albedo_psnr_db;      /* 10 log10(1 / mse), peak 1, of the albedo the camera sees: the
                                   recovered and the true objects rendered alone under unit
                                   radiance without shadows (pixel = albedo), over the pixels
                                   inside both (no outline blending) */
    double albedo_texel_psnr_db; /* the same over the texture's texels the view resolves (at
                                   least half a pixel of bilinear weight each), or over the
                                   constant albedos */
    double albedo_observed;     /* fraction of texels resolved in that sense (1 for constants) */
    double albedo_shadow_psnr_db; /* albedo_psnr_db over those of its pixels that the target shows
                                   in shadow: m_p >= 0.25 with m_p as for "shadow_weight" below
                                   but U the ground truth rendered without shadows (its own
                                   lighting); the pixels whose darkness an unshadowed model must
                                   explain by a darker albedo. NaN when there are none */
    double albedo_shadow_fraction; /* the fraction of albedo_psnr_db's pixels in that set */
    double rotation_error_deg;  /* largest over objects of the angle of R R_true^T */
    double translation_error;   /* largest over objects of |t - t_true| (scene units) */
    double translation_error_rel; /* largest over objects of |t - t_true| / the object's size
                                     (the diagonal of the true posed mesh's bounding box) */
    double vertex_rmse;         /* posed vertices vs the truth's, all objects (scene units) */
    double sphere_iou;          /* volume IoU of the recovered and the true objects' unions of
                                   spheres (world space, on a 96^3 grid over both) */
    double sphere_chamfer;      /* symmetric Chamfer distance of the sphere centres (world
                                   space): the mean over both sets of each centre's distance to
                                   the nearest centre of the other set, averaged */
    double shadow_iou;          /* IoU of the two unions of spheres seen from the light: their
                                   projections onto the ground along the truth's dominant light
                                   direction (the dipole of its SH lighting; straight down
                                   without one), on a 256^2 grid; what a shadow determines */
    double light_direction_error_deg; /* the largest over the recovered disk lights of the
                                   angle to the nearest of the truth's lights (given, or found
                                   in its map by the default extraction); with "lights" and a
                                   truth that has lights */
} pen_optim_metrics;

/* The recovered scene seen from one view (over the view's mask). */
typedef struct pen_optim_view_metrics {
    double loss;     /* the view's image loss over the mask (the task's kind; before the view's
                        weight and without shadow weights) */
    double rmse;     /* final render vs target, over the mask's pixels and all channels */
    double rel_rmse; /* rmse / the target's RMS over those pixels */
} pen_optim_view_metrics;

/* One stage of a run (pen_optim_result.stages), in the order the stages ran. Before the descent
 * a run may move its lighting, and only its lighting, in up to three stages: the global search
 * of disk lights ("light_search", light_count), the unshadowed fit of "init": "fit"
 * ("lighting_fit") and the first least-squares solve of "lighting_solver": "least_squares"
 * ("least_squares"; a lighting-only task ends there). Then comes the descent ("adam"), unless the
 * solve ended the task. The losses are the run's objective, as losses[] gives it (the image loss
 * with the run's shadow weights, plus the regularisers and the lighting ridge with the mu of the
 * whole run), at the parameters before and after the stage: a stage's loss_after is the next
 * one's loss_before, the last stage before the descent ends at losses[0], the descent at
 * final_loss. */
typedef struct pen_optim_stage {
    const char *name;   /* "light_search", "lighting_fit", "least_squares" or "adam" (static) */
    double loss_before;
    double loss_after;
    double seconds;     /* its time; the descent's is `seconds` */
    int iterations;     /* Adam steps: the descent's `iterations`, 0 for the other stages */
} pen_optim_stage;

/* The most stages a run has: the three before the descent and the descent. */
#define PEN_OPTIM_MAX_STAGES 4

typedef struct pen_optim_result {
    int iterations;       /* Adam steps taken */
    double seconds;       /* the optimisation loop (renders, backward passes, updates) */
    double final_loss;    /* the stated loss at the final render (the best iterate's):
                             final_image_loss + final_ridge_loss + the deformation's or the
                             spheres' regulariser when that group is optimised */
    int best_iteration;   /* the iteration whose parameters were kept (lowest loss) */
    int converged;        /* 1: the stopping rule fired, or the solve ended the task (solved);
                             0: iteration limit or interrupted */
    int interrupted;      /* 1: the progress callback asked to stop */
    int resumed_from;     /* the iteration the run continued from a checkpoint (0: none) */
    double *losses;       /* iterations + 1 losses: losses[i] of the parameters after i steps */
    pen_image initial;    /* render of the initial guess (after the init rule, before every
                             stage: a solved or searched lighting shows in `final`); view 0's */
    pen_image final;      /* render of the recovered scene; view 0's in a multi-view task */
    pen_optim_metrics metrics; /* multi-view: image_rmse over every view's mask pixels */
    int view_count;       /* the task's views (0: single view) */
    pen_optim_view_metrics *views;
    pen_image *view_finals; /* the final render of each view */
    int validation_count; /* the task's validation views */
    pen_optim_view_metrics *validation;
    pen_image *validation_finals;
    int lights_searched;  /* lights the global search created (0: none searched) */
    int search_renders;   /* the renders it took */
    double search_seconds; /* its time (not in `seconds`) */
    double final_image_loss; /* the image term of final_loss (over the views in a multi-view
                                task, each weighted) */
    double final_ridge_loss; /* the lighting ridge's term of final_loss (0 without a ridge) */
    pen_optim_lighting_solver lighting_solver; /* the solver used ("auto" resolved) */
    double lighting_ridge; /* the ridge used (the default resolved) */
    int solved;           /* 1: the least-squares solve ended the task (the lighting alone: 0
                             Adam steps; converged is 1 too) */
    double initial_loss;  /* the objective at the initial guess, before every stage:
                             stages[0].loss_before (losses[0] when the descent is the only stage) */
    int stage_count;      /* 1 .. PEN_OPTIM_MAX_STAGES */
    pen_optim_stage stages[PEN_OPTIM_MAX_STAGES];
    double memory_estimate; /* bytes, pen_optim_memory_estimate before the run */
    double memory_peak;     /* the process's peak resident bytes when the run ended (0: unknown) */
} pen_optim_result;

/* About the bytes a run of the task will hold at its peak (the loaded task, the render states
 * of its views or rank's views, their images, the shared traces, the process), from its sizes
 * and ctx's thread count alone: pen_optim_run refuses a task estimated above settings->memory_limit
 * (default the machine's memory) before it makes the views' render states. Call after the scene's spheres are
 * prepared (pen_scene_prepare). Measured against the peak resident memory in bench/NOTES.md. */
PEN_API double pen_optim_memory_estimate(pen_context *ctx, const pen_optim_task *task,
                                         const pen_optim_settings *settings);

/* Runs the task: fits sphere sets the scene asks for ({"fit": N}, cached as pen_spheres_fit_cached says; only
 * with shadows), applies the initial guesses, runs Adam until the stopping rule fires or the
 * iteration limit is reached, leaves the best iterate's parameters in task->scene and computes
 * the metrics. Threads: pen_context_threads. On failure *out is zeroed (task->scene may then be
 * partly updated). */
PEN_API pen_status pen_optim_run(pen_context *ctx, pen_optim_task *task,
                                 const pen_optim_settings *settings, pen_optim_result *out);
/* Frees the result's arrays and images and zeroes it; NULL is a no-op. */
PEN_API void pen_optim_result_free(pen_optim_result *result);

/* Writes into folder `outdir` (created if missing): result.json, scene.json (the recovered scene,
 * SH lighting inline, renderable by `penumbra render`; optimised textures beside it as
 * texture_<object>.png), final.exr and final.png (the final render), compare.png (target |
 * initial | result | 4x absolute error, side by side), loss.svg and loss.png (the loss curve
 * through the stages, log scale). Every file is written atomically; if any write fails the files
 * already written by this call are removed. */
PEN_API pen_status pen_optim_write(pen_context *ctx, const char *outdir, const pen_optim_task *task,
                                   const pen_optim_settings *settings,
                                   const pen_optim_result *result);

/* The result.json text (malloc'd; the caller frees it), as pen_optim_write writes it. */
PEN_API pen_status pen_optim_result_json(pen_context *ctx, const pen_optim_task *task,
                                         const pen_optim_settings *settings,
                                         const pen_optim_result *result, char **json);

#ifdef __cplusplus
}
#endif
#endif
