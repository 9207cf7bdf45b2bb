/* Multi-view tasks (src/optim/views.c, the loop in src/optim/optimize.c): the ellipsoid of
 * optim_scenes.h under its low sun, seen by cameras around it at 32x32, targets rendered by
 * penumbra from the true scene. Lighting from 1 view against 4; the multi-view gradient against
 * the sum of the views' own; zero weights and empty masks leave the run unchanged; the task JSON
 * forms (inline, views file) and their errors; checkpoints of another view set refused, a
 * resumed multi-view run equal bit for bit; the outputs (per-view metrics, views.png, final
 * renders, validation views). */
#define _POSIX_C_SOURCE 200809L
#include "optim_scenes.h"

#include "optim/optim_internal.h"

#include <pthread.h>
#include <stdio.h>
#include <sys/stat.h>
#include <unistd.h>

#define SIZE 32
#define VIEWS 4

/* Camera i of n around the object, 2.6 away, looking down at 30 degrees. */
static pen_camera around(int i, int n) {
    pen_camera c;
    memset(&c, 0, sizeof c);
    c.width = c.height = SIZE;
    c.fov_y_deg = 40.0f;
    const float a = 0.35f + 2.0f * (float)M_PI * (float)i / (float)n;
    const float eye[3] = {2.25f * sinf(a), 1.65f, 2.25f * cosf(a)};
    memcpy(c.eye, eye, sizeof eye);
    c.target[1] = 0.35f;
    c.up[1] = 1.0f;
    return c;
}

static pen_scene truth_scene(void) {
    pen_scene sc = os_egg(SIZE, 0, 4);
    os_sun(&sc, 6.0f, 0.5f);
    return sc;
}

static pen_image render_view(const pen_scene *sc, const pen_camera *cam) {
    pen_context *ctx = pen_context_create();
    const pen_scene v = pen__optim_view_scene(sc, cam);
    pen_image img = {0, 0, 0, NULL};
    CHECK(pen_render_fwd(ctx, &v, NULL, NULL, &img) == PEN_OK);
    pen_context_destroy(ctx);
    return img;
}

/* A lighting task over views 0 .. n-1 of `total` cameras around the object (targets: the true
 * scene's renders), weights 1; `extra` more views allocated (zeroed) for the caller to fill. */
static pen_optim_task views_task(int n, int total, int extra, unsigned groups, int iterations) {
    pen_optim_task t = pen_optim_task_default();
    /* Adam unless a test says otherwise (a lighting-only task's default is least squares) */
    t.lighting_solver = PEN_OPTIM_LIGHTING_ADAM;
    t.ground_truth = truth_scene();
    t.has_ground_truth = 1;
    t.scene = os_egg(SIZE, 0, 4);
    t.optimize = groups;
    t.iterations = iterations;
    t.view_count = n + extra;
    t.views = calloc((size_t)(n + extra), sizeof *t.views);
    for (int i = 0; i < n; ++i) {
        t.views[i].camera = around(i, total);
        t.views[i].target = render_view(&t.ground_truth, &t.views[i].camera);
        t.views[i].weight = 1.0;
    }
    return t;
}

/* pen_optim_run with `threads` (0: all cores). */
static pen_optim_result run_task_threads(pen_optim_task *t, const pen_optim_settings *set,
                                         int threads) {
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, threads);
    pen_optim_result r;
    pen_status s = pen_optim_run(ctx, t, set, &r);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    pen_context_destroy(ctx);
    return r;
}

static pen_optim_result run_task(pen_optim_task *t, const pen_optim_settings *set) {
    return run_task_threads(t, set, 0);
}

/* ---- Lighting from 1 view and from 4 ---------------------------------------------------------- */

/* One view sees one side of the object and the ground; four views around it see every side, and
 * the same solver recovers the lighting better. Compared: the error of the radiance over the
 * upper hemisphere ("sky"), the light the ground lets through. The lower hemisphere reaches no
 * view (the ground hides it), so no number of views determines it, and it dominates the error
 * over all coefficients: with least squares (ridge 1e-4, one view's worth) 0.189 from 1 view and
 * 0.159 from 4, while the sky's error falls to a fifth (0.0222 to 0.0040); Adam after 150 steps
 * from black: sky 0.533 to 0.337. */
static void test_lighting_one_vs_four(void) {
    double err[2][2]; /* [adam, least squares][1 view, 4 views]: the sky's lighting error */
    for (int solver = 0; solver < 2; ++solver)
        for (int k = 0; k < 2; ++k) {
            const int n = k ? VIEWS : 1;
            pen_optim_task t = views_task(n, VIEWS, 0, PEN_OPTIM_LIGHTING, 150);
            if (solver) {
                t.lighting_solver = PEN_OPTIM_LIGHTING_LEAST_SQUARES;
                t.lighting_ridge = 1e-4;
            } else {
                t.lr.lighting = 0.05f;
                t.window = 150; /* the whole run: the same step count for both */
            }
            pen_optim_settings set = pen_optim_settings_default();
            pen_optim_result r = run_task(&t, &set);
            err[solver][k] = r.metrics.lighting_rel_error_sky;
            CHECK(r.view_count == n && r.views && r.view_finals);
            CHECK(r.views && isfinite(r.views[0].rmse) && r.views[0].rel_rmse < 0.5);
            printf("  %-13s %d view%s: lighting error %.4f (bands 0-2 %.4f, sky %.4f), image "
                   "RMSE %.4g, %d iterations%s\n",
                   solver ? "least squares" : "adam", n, n > 1 ? "s" : " ",
                   r.metrics.lighting_rel_error, r.metrics.lighting_rel_error_b2, err[solver][k],
                   r.metrics.image_rmse, r.iterations, r.converged ? " (converged)" : "");
            pen_optim_result_free(&r);
            pen_optim_task_free(&t);
        }
    CHECK_MSG(err[0][1] < 0.8 * err[0][0], "adam: 4 views %.4f vs 1 view %.4f", err[0][1],
              err[0][0]);
    CHECK_MSG(err[1][1] < 0.6 * err[1][0], "least squares: 4 views %.4f vs 1 view %.4f",
              err[1][1], err[1][0]);
}

/* ---- The ridge is one view's worth ----------------------------------------------------------- */

/* The lighting ridge is a prior of fixed strength and each view one view's worth of data
 * (pen__optim_ridge_mu): the same view given twice is twice the data, so least squares at ridge
 * rho over the pair solves what one copy solves at rho / 2 (the summed normal equations are
 * twice one copy's, and so is mu's top entry: mu = rho * 2 top / 2). Under the rule before it
 * (mu relative to the summed equations) the pair solved what one copy solves at rho: duplicates
 * did not count. The stated loss is the pair's image loss plus its ridge term, both twice those
 * of the one copy at rho / 2: one objective, scaled. */
static void test_ridge_per_view(void) {
    pen_optim_task two = views_task(2, VIEWS, 0, PEN_OPTIM_LIGHTING, 10);
    pen_image_free(&two.views[1].target);
    two.views[1].camera = two.views[0].camera;
    two.views[1].target = render_view(&two.ground_truth, &two.views[1].camera);
    pen_optim_task one = views_task(1, VIEWS, 0, PEN_OPTIM_LIGHTING, 10);
    pen_optim_task same = views_task(1, VIEWS, 0, PEN_OPTIM_LIGHTING, 10);
    two.lighting_solver = one.lighting_solver = same.lighting_solver =
        PEN_OPTIM_LIGHTING_LEAST_SQUARES;
    two.lighting_ridge = same.lighting_ridge = 1e-2;
    one.lighting_ridge = 0.5e-2;
    pen_optim_settings set = pen_optim_settings_default();
    pen_optim_result r2 = run_task(&two, &set), r1 = run_task(&one, &set),
                     rs = run_task(&same, &set);
    CHECK(r2.solved && r1.solved && rs.solved);
    const int nb = two.scene.sh_bands * two.scene.sh_bands;
    double diff = 0.0, norm = 0.0, apart = 0.0;
    for (int k = 0; k < nb; ++k)
        for (int c = 0; c < 3; ++c) {
            const double a = (double)two.scene.lighting.sh[k][c],
                         b = (double)one.scene.lighting.sh[k][c];
            diff = fmax(diff, fabs(a - b));
            norm = fmax(norm, fabs(b));
            apart = fmax(apart, fabs(a - (double)same.scene.lighting.sh[k][c]));
        }
    printf("  two copies at 1e-2 against one at 0.5e-2: max difference %.3g of %.3g (against "
           "one at 1e-2: %.3g); lighting errors %.4f, %.4f, %.4f\n",
           diff, norm, apart, r2.metrics.lighting_rel_error, r1.metrics.lighting_rel_error,
           rs.metrics.lighting_rel_error);
    CHECK_MSG(diff < 1e-5 * norm, "two copies: %.3g off one at half the ridge", diff);
    CHECK_MSG(apart > 1e3 * diff, "the ridge made no difference (%.3g)", apart);
    CHECK_MSG(fabs(r2.final_ridge_loss - 2.0 * r1.final_ridge_loss) < 1e-9 * r2.final_ridge_loss &&
                  fabs(r2.final_image_loss - 2.0 * r1.final_image_loss) <
                      1e-9 * r2.final_image_loss &&
                  r2.final_ridge_loss > 0.0,
              "stated losses: two copies %.9g + %.9g, one copy %.9g + %.9g", r2.final_image_loss,
              r2.final_ridge_loss, r1.final_image_loss, r1.final_ridge_loss);
    pen_optim_result_free(&r2);
    pen_optim_result_free(&r1);
    pen_optim_result_free(&rs);
    pen_optim_task_free(&two);
    pen_optim_task_free(&one);
    pen_optim_task_free(&same);
}

/* ---- The gradient of the sum is the sum of the gradients -------------------------------------- */

static void test_gradient_sum(void) {
    pen_optim_task t = views_task(3, 3, 0, PEN_OPTIM_LIGHTING, 1);
    t.scene.objects[0].pose.translation[0] += 0.05f;
    t.views[1].weight = 0.5;
    t.views[2].weight = 2.0;
    const size_t pixels = SIZE * SIZE;
    t.views[1].mask = malloc(pixels * sizeof(float));
    for (size_t p = 0; p < pixels; ++p)
        t.views[1].mask[p] = (p % SIZE) < SIZE / 2 ? 1.0f : 0.0f; /* the left half */
    pen_context *ctx = pen_context_create();
    const pen_render_options opt = pen_render_options_default();
    pen__optim_views V;
    CHECK(pen__optim_views_init(ctx, &V, &t, 0.0, 0) == PEN_OK);
    pen_render_grad all, one;
    CHECK(pen_render_grad_create(ctx, &t.scene, &all) == PEN_OK);
    CHECK(pen_render_grad_create(ctx, &t.scene, &one) == PEN_OK);
    const unsigned wrt = PEN_GRAD_LIGHTING | PEN_GRAD_ALBEDO | PEN_GRAD_POSE;
    pen_render_grad_model(&t.scene, wrt); /* a pose gradient needs the sphere model (render.h) */
    double loss = 0.0, sum_loss = 0.0, sh[PEN_SH_MAX_COEFFS][3], pose[6];
    memset(sh, 0, sizeof sh);
    memset(pose, 0, sizeof pose);
    const pen_optim_settings set = pen_optim_settings_default();
    CHECK(pen__optim_views_plan(ctx, &V, &t.scene, &set, wrt) == PEN_OK);
    CHECK(pen__optim_views_fwd(ctx, &V, &t.scene, &opt, t.loss, 1, &loss) == PEN_OK);
    CHECK(pen__optim_views_bwd(ctx, &V, &t.scene, &opt, &all) == PEN_OK);
    for (int v = 0; v < 3; ++v) { /* each view alone: its loss and gradient, weighted */
        const pen_scene vs = pen__optim_view_scene(&t.scene, &t.views[v].camera);
        pen_image img = {0, 0, 0, NULL}, d = {0, 0, 0, NULL};
        pen_render_state *st = NULL;
        double e = 0.0;
        CHECK(pen_render_state_create(ctx, &st) == PEN_OK);
        CHECK(pen_render_fwd(ctx, &vs, &opt, st, &img) == PEN_OK);
        CHECK(pen_image_create(ctx, SIZE, SIZE, 3, &d) == PEN_OK);
        CHECK(pen__optim_loss_fwd(ctx, t.loss, &img, &t.views[v].target, t.views[v].mask, &e) ==
              PEN_OK);
        pen__optim_loss_bwd(t.loss, &img, &t.views[v].target, t.views[v].mask, t.views[v].weight,
                            &d);
        pen_render_grad_zero(&one);
        CHECK(pen_render_bwd(ctx, &vs, &opt, st, &d, wrt, &one) == PEN_OK);
        sum_loss += t.views[v].weight * e;
        for (int k = 0; k < 16; ++k)
            for (int c = 0; c < 3; ++c)
                sh[k][c] += (double)one.sh[k][c];
        for (int k = 0; k < 3; ++k) {
            pose[k] += (double)one.objects[0].pose.rotation_axis_angle_deg[k];
            pose[3 + k] += (double)one.objects[0].pose.translation[k];
        }
        pen_image_free(&img);
        pen_image_free(&d);
        pen_render_state_free(st);
    }
    CHECK_REL(loss, sum_loss, 1e-12, 1e-12);
    double worst = 0.0, scale = 0.0;
    for (int k = 0; k < 16; ++k)
        for (int c = 0; c < 3; ++c) {
            worst = fmax(worst, fabs((double)all.sh[k][c] - sh[k][c]));
            scale = fmax(scale, fabs(sh[k][c]));
        }
    for (int k = 0; k < 3; ++k) {
        CHECK_REL(all.objects[0].pose.rotation_axis_angle_deg[k], pose[k], 1e-6, 1e-9);
        CHECK_REL(all.objects[0].pose.translation[k], pose[3 + k], 1e-6, 1e-9);
    }
    CHECK_MSG(worst <= 1e-6 * scale, "lighting gradient: max difference %.3g of %.3g", worst,
              scale);
    printf("  loss %.6g; lighting gradient: max |multi - sum| %.3g (largest entry %.3g)\n", loss,
           worst, scale);
    pen_render_grad_free(&all);
    pen_render_grad_free(&one);
    pen__optim_views_free_run(&V);
    pen_context_destroy(ctx);
    pen_optim_task_free(&t);
}

/* ---- Weights and masks ------------------------------------------------------------------------ */

static void check_same_run(const pen_optim_result *a, const pen_optim_task *ta,
                           const pen_optim_result *b, const pen_optim_task *tb, const char *what) {
    CHECK_MSG(a->iterations == b->iterations && a->final_loss == b->final_loss &&
                  memcmp(a->losses, b->losses, sizeof(double) * (size_t)(a->iterations + 1)) == 0,
              "%s: %d vs %d iterations, loss %.17g vs %.17g", what, a->iterations, b->iterations,
              a->final_loss, b->final_loss);
    CHECK_MSG(memcmp(ta->scene.lighting.sh, tb->scene.lighting.sh, sizeof ta->scene.lighting.sh) ==
                  0 &&
                  memcmp(&ta->scene.objects[0].pose, &tb->scene.objects[0].pose,
                         sizeof ta->scene.objects[0].pose) == 0,
              "%s: recovered scenes differ", what);
    for (int v = 0; v < ta->view_count && v < tb->view_count; ++v)
        CHECK_MSG(memcmp(&ta->views[v].exposure, &tb->views[v].exposure, sizeof(double)) == 0,
                  "%s: view %d's exposure %.17g vs %.17g", what, v, ta->views[v].exposure,
                  tb->views[v].exposure);
}

/* With the "exposure" group: the views' exposures start off the truth's 1 (1.2, 0.85, 1.2, ...
 * after the gauge), so they have a gradient and move. */
static void expose_views(pen_optim_task *t) {
    for (int v = 0; v < t->view_count; ++v)
        t->views[v].exposure = v == 0 ? 1.0 : v % 2 ? 1.2 : 0.85;
}

/* A fifth view of weight 0 changes nothing; neither does a fifth view whose mask excludes every
 * pixel; and a view's weight 0 equals its mask excluding everything. The runs carry a lighting
 * ridge, whose mu divides by the views taking part (pen__optim_ridge_mu): an idle view counted
 * there would change mu, and the run. */
static void test_weights_and_masks(void) {
    const unsigned groups = PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE;
    const int iterations = check_quick_() ? 4 : 8;
    pen_optim_settings set = pen_optim_settings_default();
    pen_optim_task t4 = views_task(VIEWS, VIEWS, 0, groups, iterations);
    t4.lighting_ridge = 1e-2;
    pen_optim_result r4 = run_task(&t4, &set);
    for (int variant = 0; variant < 2; ++variant) {
        pen_optim_task t = views_task(VIEWS, VIEWS, 1, groups, iterations);
        t.lighting_ridge = 1e-2;
        pen_optim_view *v = &t.views[VIEWS];
        v->camera = around(1, 3);
        v->target = render_view(&t.scene, &v->camera); /* far from the truth: would matter */
        v->weight = variant ? 1.0 : 0.0;
        if (variant) v->mask = calloc(SIZE * SIZE, sizeof(float));
        pen_optim_result r = run_task(&t, &set);
        check_same_run(&r4, &t4, &r, &t, variant ? "empty mask" : "zero weight");
        CHECK(r.view_count == VIEWS + 1 && r.views && (isnan(r.views[VIEWS].rmse) ? 1 : 0) == variant);
        pen_optim_result_free(&r);
        pen_optim_task_free(&t);
    }
    /* a pixel mask weights the pixels it keeps like the weight-1 view */
    pen_optim_task tm = views_task(VIEWS, VIEWS, 0, groups, iterations);
    tm.views[2].mask = malloc(SIZE * SIZE * sizeof(float));
    for (int p = 0; p < SIZE * SIZE; ++p)
        tm.views[2].mask[p] = p < SIZE * SIZE / 2 ? 1.0f : 0.0f;
    pen_optim_result rm = run_task(&tm, &set);
    CHECK(rm.final_loss != r4.final_loss); /* the mask changes the objective */
    CHECK(rm.views && isfinite(rm.views[2].loss));
    pen_optim_result_free(&rm);
    pen_optim_task_free(&tm);
    pen_optim_result_free(&r4);
    pen_optim_task_free(&t4);
}

/* ---- Views at once and views across ranks (src/optim/parallel.c) ------------------------------ */

/* One after the other with 1 thread, with 2, two and three views at once (2 and 3 threads): the
 * same losses and recovered scene bit for bit (a view's gradient is computed alone and the sum
 * runs in view order; the renderer does not depend on its thread count). */
static void test_views_at_once(void) {
    const int iterations = check_quick_() ? 3 : 6;
    /* threads, view_workers, with the exposure group */
    static const int setting[][3] = {{2, 1, 0}, {2, 2, 0}, {3, 0, 0}, {2, 2, 1}};
    for (int exposure = 0; exposure < 2; ++exposure) {
        const unsigned groups =
            PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE | (exposure ? PEN_OPTIM_EXPOSURE : 0u);
        pen_optim_settings set = pen_optim_settings_default();
        set.view_workers = 1;
        pen_optim_task t1 = views_task(VIEWS, VIEWS, 0, groups, iterations);
        if (exposure) expose_views(&t1);
        pen_optim_result r1 = run_task_threads(&t1, &set, 1);
        for (int k = 0; k < 4; ++k) {
            if (setting[k][2] != exposure) continue;
            char what[80];
            snprintf(what, sizeof what, "%d threads, view_workers %d%s", setting[k][0],
                     setting[k][1], exposure ? ", exposure" : "");
            set.view_workers = setting[k][1];
            pen_optim_task t = views_task(VIEWS, VIEWS, 0, groups, iterations);
            if (exposure) expose_views(&t);
            pen_optim_result r = run_task_threads(&t, &set, setting[k][0]);
            check_same_run(&r1, &t1, &r, &t, what);
            pen_optim_result_free(&r);
            pen_optim_task_free(&t);
        }
        if (exposure) /* the group moved them: the comparison above saw steps, not constants */
            CHECK_MSG(t1.views[1].exposure != 1.2 && t1.views[2].exposure != 0.85,
                      "the exposures did not move: %.17g %.17g", t1.views[1].exposure,
                      t1.views[2].exposure);
        pen_optim_result_free(&r1);
        pen_optim_task_free(&t1);
    }
}

/* Ranks played by threads of this process: a shared-memory allgather between two barriers. */
#define MAX_RANKS 4
typedef struct world {
    pthread_barrier_t barrier;
    void *all[MAX_RANKS];
} world;

typedef struct rank_run {
    world *w;
    pen_optim_ranks ranks;
    pen_optim_task task;
    pen_optim_result result;
    pen_status status;
} rank_run;

static int shared_allgather(void *user, void *all, const int *counts, size_t item_bytes) {
    rank_run *me = user;
    me->w->all[me->ranks.rank] = all;
    pthread_barrier_wait(&me->w->barrier); /* every rank's block is in its buffer */
    size_t at = 0;
    for (int r = 0; r < me->ranks.size; ++r) {
        const size_t bytes = (size_t)counts[r] * item_bytes;
        if (r != me->ranks.rank)
            memcpy((char *)all + at, (const char *)me->w->all[r] + at, bytes);
        at += bytes;
    }
    pthread_barrier_wait(&me->w->barrier); /* all read before anyone writes again */
    return 0;
}

static void *rank_main(void *arg) {
    rank_run *me = arg;
    pen_context *ctx = pen_context_create();
    pen_context_set_threads(ctx, 1);
    pen_optim_settings set = pen_optim_settings_default();
    set.ranks = &me->ranks;
    me->status = pen_optim_run(ctx, &me->task, &set, &me->result);
    if (me->status) fprintf(stderr, "rank %d: %s\n", me->ranks.rank, pen_context_error(ctx));
    pen_context_destroy(ctx);
    return NULL;
}

/* n views plus one of weight 0 (it takes no part, not even in the split) over `size` ranks:
 * every rank ends with one process's losses and scene, bit for bit. 3 views over 2 ranks (an
 * uneven split) and over 3, 4 over 4 (one view each); 3 over 2 with the exposure group (each
 * view's exposure derivative is gathered with its loss: every rank steps every exposure). */
static void test_ranks(void) {
    const int iterations = check_quick_() ? 3 : 6;
    static const int cases[][3] = {{3, 2, 0}, {3, 3, 0}, {4, 4, 0}, {3, 2, 1}}; /* views, ranks,
                                                                                  exposure */
    for (int c = 0; c < 4; ++c) {
        const int n = cases[c][0], size = cases[c][1], exposure = cases[c][2];
        const unsigned groups = exposure ? PEN_OPTIM_LIGHTING | PEN_OPTIM_EXPOSURE
                                         : PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE;
        pen_optim_settings set = pen_optim_settings_default();
        pen_optim_task t1 = views_task(n, n, 1, groups, iterations);
        t1.lighting_ridge = 1e-2; /* mu counts every rank's views, not its own block's */
        if (exposure) expose_views(&t1);
        t1.views[n].camera = around(1, 5);
        t1.views[n].target = render_view(&t1.scene, &t1.views[n].camera);
        pen_optim_result r1 = run_task_threads(&t1, &set, 1);
        world w;
        pthread_barrier_init(&w.barrier, NULL, (unsigned)size);
        rank_run runs[MAX_RANKS];
        pthread_t threads[MAX_RANKS];
        for (int r = 0; r < size; ++r) {
            rank_run *me = &runs[r];
            memset(me, 0, sizeof *me);
            me->w = &w;
            me->ranks = (pen_optim_ranks){r, size, shared_allgather, me};
            me->task = views_task(n, n, 1, groups, iterations);
            me->task.lighting_ridge = t1.lighting_ridge;
            if (exposure) expose_views(&me->task);
            me->task.views[n].camera = t1.views[n].camera;
            me->task.views[n].target = render_view(&me->task.scene, &me->task.views[n].camera);
            CHECK(pthread_create(&threads[r], NULL, rank_main, me) == 0);
        }
        for (int r = 0; r < size; ++r) {
            pthread_join(threads[r], NULL);
            char what[64];
            snprintf(what, sizeof what, "%d views, rank %d of %d", n, r, size);
            CHECK_MSG(runs[r].status == PEN_OK, "%s failed", what);
            if (!runs[r].status) check_same_run(&r1, &t1, &runs[r].result, &runs[r].task, what);
            pen_optim_result_free(&runs[r].result);
            pen_optim_task_free(&runs[r].task);
        }
        pthread_barrier_destroy(&w.barrier);
        printf("  %d views over %d ranks%s: %d iterations, loss %.9g, as one process\n", n,
               size, exposure ? " (exposure)" : "", r1.iterations, r1.final_loss);
        pen_optim_result_free(&r1);
        pen_optim_task_free(&t1);
    }
}

/* ---- The task JSON ---------------------------------------------------------------------------- */

static char *path_in(const char *dir, const char *name) {
    static char buf[8][160];
    static int k = 0;
    k = (k + 1) % 8;
    snprintf(buf[k], sizeof buf[k], "%s/%s", dir, name);
    return buf[k];
}

static void write_text(const char *path, const char *text) {
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

/* A folder with scene.json, the targets t0.exr .. t3.exr, a mask m.png, views.json (as
 * `penumbra import-cameras` writes it, plus a mask and a weight). */
static void make_files(char *dir) {
    CHECK(mkdtemp(dir) != NULL);
    pen_context *ctx = pen_context_create();
    pen_scene truth = truth_scene();
    pen_camera_set set = {VIEWS, calloc(VIEWS, sizeof(pen_camera)), calloc(VIEWS, sizeof(char *))};
    for (int i = 0; i < VIEWS; ++i) {
        char name[16];
        snprintf(name, sizeof name, "t%d.exr", i);
        set.cameras[i] = around(i, VIEWS);
        set.cameras[i].fx = set.cameras[i].fy = 44.0f; /* calibrated, like an import */
        set.cameras[i].cx = set.cameras[i].cy = 16.0f;
        pen_image img = render_view(&truth, &set.cameras[i]);
        set.images[i] = strdup(path_in(dir, name));
        CHECK(pen_image_save(ctx, set.images[i], &img) == PEN_OK);
        pen_image_free(&img);
    }
    CHECK(pen_camera_set_save_views(ctx, path_in(dir, "views.json"), &set) == PEN_OK);
    pen_image small = {0, 0, 0, NULL}, mask = {0, 0, 0, NULL};
    CHECK(pen_image_create(ctx, 8, 8, 3, &small) == PEN_OK);
    CHECK(pen_image_save(ctx, path_in(dir, "small.exr"), &small) == PEN_OK);
    CHECK(pen_image_create(ctx, SIZE, SIZE, 3, &mask) == PEN_OK);
    for (int p = 0; p < SIZE * SIZE; ++p)
        mask.data[3 * p] = mask.data[3 * p + 1] = mask.data[3 * p + 2] = p % 2 ? 1.0f : 0.0f;
    CHECK(pen_image_save(ctx, path_in(dir, "m.png"), &mask) == PEN_OK);
    pen_image_free(&small);
    pen_image_free(&mask);
    CHECK(pen_mesh_save_obj(ctx, path_in(dir, "egg.obj"), &truth.objects[0].mesh) == PEN_OK);
    truth.objects[0].mesh_path = strdup(path_in(dir, "egg.obj"));
    CHECK(pen_scene_save(ctx, path_in(dir, "scene.json"), &truth) == PEN_OK);
    pen_camera_set_free(&set);
    pen_scene_free(&truth);
    pen_context_destroy(ctx);
    /* the views file with a mask and a weight on view 1 */
    FILE *f = fopen(path_in(dir, "views.json"), "r");
    char text[16384];
    size_t n = f ? fread(text, 1, sizeof text - 1, f) : 0;
    if (f) fclose(f);
    text[n] = '\0';
    char *second = strstr(text, "\"t1.exr\"");
    CHECK(second != NULL);
    if (second) {
        char edited[16600];
        const size_t head = (size_t)(second - text) + strlen("\"t1.exr\"");
        snprintf(edited, sizeof edited, "%.*s, \"mask\": \"m.png\", \"weight\": 0.25%s", (int)head,
                 text, text + head);
        write_text(path_in(dir, "views_mw.json"), edited);
    }
}

static pen_status parse(const char *dir, const char *json, pen_optim_task *t, pen_context *ctx) {
    return pen_optim_task_parse(ctx, json, path_in(dir, "task.json"), t);
}

static void test_task_json(void) {
    char dir[] = "/tmp/pen_views_XXXXXX";
    make_files(dir);
    pen_context *ctx = pen_context_create();
    pen_optim_task a, b;
    CHECK_MSG(parse(dir, "{\"scene\": \"scene.json\", \"optimize\": [\"lighting\"], "
                         "\"views\": \"views_mw.json\", \"validation_views\": \"views.json\"}",
                    &a, ctx) == PEN_OK,
              "%s", pen_context_error(ctx));
    CHECK(a.view_count == VIEWS && a.validation_count == VIEWS && !a.target.data);
    if (a.view_count == VIEWS) {
        CHECK(a.views[1].weight == 0.25 && a.views[1].mask && !a.views[0].mask);
        CHECK(a.views[1].mask && a.views[1].mask[0] == 0.0f && a.views[1].mask[1] == 1.0f);
        CHECK(a.views[3].camera.fx == 44.0f && a.views[3].camera.width == SIZE);
    }
    /* the inline form of the same views */
    char json[4096];
    snprintf(json, sizeof json,
             "{\"scene\": \"scene.json\", \"optimize\": [\"lighting\"], \"views\": ["
             "{\"camera\": {\"width\": 32, \"height\": 32, \"eye\": [1, 1.6, 2], \"target\": "
             "[0, 0.35, 0], \"fov_y_deg\": 40}, \"target\": \"t0.exr\"},"
             "{\"camera\": {\"width\": 32, \"height\": 32, \"eye\": [2, 1.6, 1], \"target\": "
             "[0, 0.35, 0], \"fov_y_deg\": 40}, \"target\": \"t1.exr\", \"mask\": \"m.png\", "
             "\"weight\": 3}]}");
    CHECK_MSG(parse(dir, json, &b, ctx) == PEN_OK, "%s", pen_context_error(ctx));
    CHECK(b.view_count == 2 && b.views && b.views[1].weight == 3.0 && b.views[1].mask);
    if (a.view_count == VIEWS && b.view_count == 2)
        CHECK(memcmp(a.views[1].target.data, b.views[1].target.data,
                     sizeof(float) * 3 * SIZE * SIZE) == 0);
    pen_optim_task_free(&a);
    pen_optim_task_free(&b);
    /* errors, each naming its key */
    static const struct {
        const char *views, *message;
    } bad[] = {
        {"[{\"camera\": {\"width\": 32, \"height\": 32, \"eye\": [1, 1, 2], \"target\": [0, 0, 0],"
         " \"fov_y_deg\": 40}, \"target\": \"t0.exr\"}, {\"camera\": {\"width\": 32, \"height\":"
         " 32, \"eye\": [1, 1, 2], \"target\": [0, 0, 0], \"fov_y_deg\": 40}, \"target\":"
         " \"small.exr\"}]",
         "task.json: views[1].target: small.exr: the image is 8x8 but the view's camera is 32x32"},
        {"[{\"camera\": {\"width\": 32, \"height\": 32, \"eye\": [1, 1, 2], \"target\": [0, 0, 0],"
         " \"fov_y_deg\": 40}, \"target\": \"t0.exr\", \"weight\": -1}]",
         "views[0].weight: expected a weight in [0, 1e6]"},
        {"[{\"camera\": {\"width\": 32, \"height\": 32, \"eye\": [1, 1, 2], \"target\": [0, 0, 0],"
         " \"fov_y_deg\": 40}, \"target\": \"m.tif\"}]",
         "views[0].target: "},
        {"[{\"camera\": {\"width\": 16, \"height\": 32, \"eye\": [1, 1, 2], \"target\": [0, 0, 0],"
         " \"fov_y_deg\": 40}, \"target\": \"t0.exr\", \"mask\": \"small.exr\"}]",
         "views[0].target: t0.exr: the image is 32x32 but the view's camera is 16x32"},
        {"[]", "task.json: views: expected an array of 1 .. 100000 views"},
        {"\"nothere.json\"", "task.json: views: "},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i) {
        snprintf(json, sizeof json,
                 "{\"scene\": \"scene.json\", \"optimize\": [\"lighting\"], \"views\": %s}",
                 bad[i].views);
        CHECK(parse(dir, json, &a, ctx) != PEN_OK);
        CHECK_MSG(strstr(pen_context_error(ctx), bad[i].message), "%zu: %s", i,
                  pen_context_error(ctx));
    }
    CHECK(parse(dir, "{\"scene\": \"scene.json\", \"optimize\": [\"lighting\"], \"target\": "
                     "\"t0.exr\", \"views\": \"views.json\"}",
                &a, ctx) == PEN_ERROR_PARSE);
    CHECK_MSG(strstr(pen_context_error(ctx), "task.json: views: a task has either \"views\" or a "
                                             "\"target\", not both"),
              "%s", pen_context_error(ctx));
    pen_context_destroy(ctx);
    static const char *const names[] = {"t0.exr", "t1.exr", "t2.exr", "t3.exr", "small.exr",
                                        "m.png", "views.json", "views_mw.json", "scene.json", "egg.obj"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; ++i)
        remove(path_in(dir, names[i]));
    rmdir(dir);
}

/* ---- Checkpoints and outputs ------------------------------------------------------------------ */

static int stop_at_3(void *user, int iteration, int iterations, double loss) {
    (void)user, (void)iterations, (void)loss;
    return iteration == 3;
}

static void test_resume_and_outputs(void) {
    const unsigned groups = PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE;
    const int iterations = check_quick_() ? 6 : 10;
    char once[] = "/tmp/pen_views_once_XXXXXX", cut[] = "/tmp/pen_views_cut_XXXXXX";
    CHECK(mkdtemp(once) && mkdtemp(cut));
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = once;
    pen_optim_task ta = views_task(3, 3, 0, groups, iterations);
    ta.shadow_weight = 2.0;
    pen_optim_result a = run_task(&ta, &set);
    /* interrupted after iteration 3, then resumed */
    pen_optim_task tb = views_task(3, 3, 0, groups, iterations);
    tb.shadow_weight = 2.0;
    set.outdir = cut;
    set.progress = stop_at_3;
    pen_optim_result b = run_task(&tb, &set);
    CHECK(b.interrupted && b.iterations == 3);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    tb = views_task(3, 3, 0, groups, iterations);
    tb.shadow_weight = 2.0;
    set.progress = NULL;
    set.resume = 1;
    b = run_task(&tb, &set);
    CHECK(b.resumed_from == 3);
    check_same_run(&a, &ta, &b, &tb, "interrupted + resumed");
    CHECK(b.views && a.views && b.views[2].rmse == a.views[2].rmse);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    /* another view set (one weight changed) is refused */
    pen_context *ctx = pen_context_create();
    tb = views_task(3, 3, 0, groups, iterations);
    tb.shadow_weight = 2.0;
    tb.views[1].weight = 0.5;
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), "checkpoint.bin: made for another target"), "%s",
              pen_context_error(ctx));
    pen_optim_task_free(&tb);
    /* a version-4 checkpoint of a multi-view task whose initial guess differs names the ridge
     * rule of version 4 as a possible reason (its "fit" start or search took the old one) */
    os_checkpoint_downgrade(path_in(cut, "checkpoint.bin"), 4);
    tb = views_task(3, 3, 0, groups, iterations);
    tb.shadow_weight = 2.0;
    tb.scene.objects[0].pose.translation[0] += 0.01f;
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), "checkpoint.bin: made for another initial guess: "
                                             "checkpoint version 4 of a multi-view task"),
              "%s", pen_context_error(ctx));
    pen_optim_task_free(&tb);
    /* a checkpoint of a multi-view task with a lighting ridge from before the ridge was one
     * view's worth (version 4) is refused: its objective was another */
    tb = views_task(3, 3, 0, groups, iterations);
    tb.lighting_ridge = 1e-2;
    set.resume = 0;
    set.progress = stop_at_3;
    b = run_task(&tb, &set);
    CHECK(b.interrupted && b.iterations == 3);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    os_checkpoint_downgrade(path_in(cut, "checkpoint.bin"), 4);
    tb = views_task(3, 3, 0, groups, iterations);
    tb.lighting_ridge = 1e-2;
    set.progress = NULL;
    set.resume = 1;
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), "checkpoint.bin: checkpoint version 4, made when the "
                                             "lighting ridge of a multi-view task"),
              "%s", pen_context_error(ctx));
    /* and a version this build does not know, with its range */
    os_checkpoint_downgrade(path_in(cut, "checkpoint.bin"), 8);
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_ERROR_PARSE);
    CHECK_MSG(strstr(pen_context_error(ctx), "checkpoint.bin: checkpoint version 8, this build "
                                             "reads 3 to 7"),
              "%s", pen_context_error(ctx));
    pen_optim_task_free(&tb);
    /* the outputs, with two held-back views */
    set.resume = 0;
    set.outdir = NULL;
    pen_optim_result_free(&a);
    pen_optim_task_free(&ta);
    ta = views_task(3, 3, 0, groups, iterations);
    ta.validation_count = 2;
    ta.validation = calloc(2, sizeof *ta.validation);
    for (int i = 0; i < 2; ++i) {
        pen_optim_view *v = &ta.validation[i];
        v->camera = around(2 * i + 1, 6);
        v->target = render_view(&ta.ground_truth, &v->camera);
        v->weight = 1.0;
    }
    a = run_task(&ta, &set);
    CHECK(pen_mesh_save_obj(ctx, path_in(once, "egg.obj"), &ta.scene.objects[0].mesh) == PEN_OK);
    ta.scene.objects[0].mesh_path = strdup(path_in(once, "egg.obj"));
    CHECK(a.validation_count == 2 && a.validation && isfinite(a.validation[1].rel_rmse));
    CHECK_MSG(pen_optim_write(ctx, once, &ta, &set, &a) == PEN_OK, "%s", pen_context_error(ctx));
    static const char *const files[] = {"final_0.exr", "final_2.exr", "validation_1.exr",
                                        "views.png", "result.json", "compare.png"};
    struct stat st;
    for (size_t i = 0; i < sizeof files / sizeof files[0]; ++i)
        CHECK_MSG(stat(path_in(once, files[i]), &st) == 0, "%s missing", files[i]);
    char *json = NULL;
    CHECK(pen_optim_result_json(ctx, &ta, &set, &a, &json) == PEN_OK);
    CHECK(json && strstr(json, "\"validation_views\":") && strstr(json, "\"image_rel_rmse\":") &&
          strstr(json, "\"stop_reason\":\t\"iteration_limit\""));
    free(json);
    pen_image sheet = {0, 0, 0, NULL};
    CHECK(pen_image_load(ctx, path_in(once, "views.png"), &sheet) == PEN_OK);
    CHECK(sheet.width == 3 * 96 + 8 && sheet.height == 3 * 96 + 2 * 4);
    pen_image_free(&sheet);
    printf("  validation views: image rel. RMSE %.4f, %.4f\n", a.validation[0].rel_rmse,
           a.validation[1].rel_rmse);
    pen_optim_result_free(&a);
    pen_optim_task_free(&ta);
    pen_context_destroy(ctx);
    static const char *const all[] = {"final_0.exr", "final_1.exr", "final_2.exr",
                                      "validation_0.exr", "validation_1.exr", "views.png",
                                      "result.json", "compare.png", "checkpoint.bin",
                                      "scene.json", "final.exr", "final.png", "loss.svg", "egg.obj"};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; ++i) {
        remove(path_in(once, all[i]));
        remove(path_in(cut, all[i]));
    }
    rmdir(once);
    rmdir(cut);
}

RUN_TESTS(TEST(test_lighting_one_vs_four), TEST(test_gradient_sum), TEST(test_weights_and_masks),
          TEST(test_task_json), TEST(test_resume_and_outputs), TEST(test_ridge_per_view),
          TEST(test_views_at_once),
          TEST(test_ranks))
