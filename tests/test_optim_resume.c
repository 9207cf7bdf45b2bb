/* Checkpoints and resuming (src/optim/checkpoint.c, the loop in src/optim/optimize.c): a run of
 * N iterations in one go and the same run stopped (interrupted at iteration j, or "crashed" with
 * only the periodic checkpoint of iteration K left) and resumed to N end with the same losses,
 * parameters and final render, bit for bit, also when the stopping rule ends the run after the
 * resume; and refused checkpoints (damaged, another problem).
 *
 * Bitwise equality holds because the state written is all the loop carries from one iteration
 * to the next (parameters, Adam's moments and step, best iterate, loss history) and the renderer
 * reduces its gradients in a fixed order whatever the thread count. */
#define _POSIX_C_SOURCE 200809L
#include "optim_scenes.h"

#include "optim/optim_internal.h"

#include <stdio.h>
#include <sys/stat.h>
#include <unistd.h>

#define SIZE 32
#define STOP_TOLERANCE 1e-3

/* window > 0: a stopping window short enough for the rule to stop the run after the resume, on
 * a loss history that began before it (the default window, 50, outlasts these runs). */
static pen_optim_task make_task(unsigned groups, int window) {
    /* The sphere model for the egg's own shadows: these tasks step the pose and the shape, which
     * the precomputed self transfer (the scene default) neither follows in its gradient nor
     * keeps fixed between steps (docs/design.md sec. 1.15). */
    pen_scene guess = os_egg(SIZE, 1, 3), truth = os_egg(SIZE, 1, 3);
    guess.shadow.self = truth.shadow.self = PEN_SELF_SPHERES;
    pen_optim_task t = os_task(guess, truth, groups, check_quick_() ? 12 : 30);
    if (window > 0) {
        t.window = window;
        t.tolerance = STOP_TOLERANCE;
    }
    t.shadow_weight = 2.0; /* the weights are recomputed on resume: they must match too */
    pen_pose *p = &t.scene.objects[0].pose;
    p->rotation_axis_angle_deg[1] += 5.0f;
    p->translation[0] += 0.04f;
    return t;
}

typedef struct stopper {
    int stop_at;           /* interrupt after this iteration's loss (-1: never) */
    int copy_at;           /* copy the checkpoint away at this iteration (-1: never) */
    const char *from, *to; /* checkpoint paths */
} stopper;

static void copy_file(const char *from, const char *to) {
    FILE *a = fopen(from, "rb"), *b = fopen(to, "wb");
    CHECK(a && b);
    char buf[4096];
    size_t n;
    while (a && b && (n = fread(buf, 1, sizeof buf, a)) > 0)
        CHECK(fwrite(buf, 1, n, b) == n);
    if (a) fclose(a);
    if (b) fclose(b);
}

static int on_progress(void *user, int iteration, int iterations, double loss) {
    (void)iterations, (void)loss;
    const stopper *s = user;
    if (iteration == s->copy_at) copy_file(s->from, s->to);
    return iteration == s->stop_at;
}

static pen_optim_result run(unsigned groups, int window, const char *outdir, int every,
                            int resume, stopper *stop, pen_optim_task *task) {
    *task = make_task(groups, window);
    pen_context *ctx = pen_context_create();
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = outdir;
    set.checkpoint_every = every;
    set.resume = resume;
    set.progress = stop ? on_progress : NULL;
    set.progress_user = stop;
    pen_optim_result r;
    pen_status s = pen_optim_run(ctx, task, &set, &r);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    pen_context_destroy(ctx);
    return r;
}

/* Everything but the timing. */
static void check_same(const pen_optim_result *a, const pen_optim_task *ta,
                       const pen_optim_result *b, const pen_optim_task *tb, const char *what) {
    CHECK_MSG(a->iterations == b->iterations && a->converged == b->converged &&
                  a->best_iteration == b->best_iteration && a->final_loss == b->final_loss,
              "%s: %d vs %d iterations, best %d vs %d, loss %.17g vs %.17g", what, a->iterations,
              b->iterations, a->best_iteration, b->best_iteration, a->final_loss, b->final_loss);
    if (a->iterations != b->iterations || !a->losses || !b->losses) return;
    CHECK_MSG(memcmp(a->losses, b->losses, sizeof(double) * (size_t)(a->iterations + 1)) == 0,
              "%s: loss curves differ", what);
    const size_t px = 3 * (size_t)a->final.width * (size_t)a->final.height;
    CHECK_MSG(memcmp(a->final.data, b->final.data, sizeof(float) * px) == 0,
              "%s: final renders differ", what);
    CHECK_MSG(memcmp(a->initial.data, b->initial.data, sizeof(float) * px) == 0,
              "%s: initial renders differ", what);
    const pen_object *oa = &ta->scene.objects[0], *ob = &tb->scene.objects[0];
    CHECK_MSG(memcmp(ta->scene.lighting.sh, tb->scene.lighting.sh, sizeof ta->scene.lighting.sh) ==
                      0 &&
                  memcmp(&oa->pose, &ob->pose, sizeof oa->pose) == 0 &&
                  memcmp(oa->mesh.positions, ob->mesh.positions,
                         sizeof(float) * 3 * (size_t)oa->mesh.vertex_count) == 0 &&
                  memcmp(oa->spheres.data, ob->spheres.data,
                         sizeof(float) * 4 * (size_t)oa->spheres.count) == 0,
              "%s: recovered scenes differ", what);
    CHECK(a->metrics.vertex_rmse == b->metrics.vertex_rmse ||
          (isnan(a->metrics.vertex_rmse) && isnan(b->metrics.vertex_rmse)));
}

static char *path_in(const char *dir, const char *name) {
    static char buf[4][96];
    static int k = 0;
    k = (k + 1) % 4;
    snprintf(buf[k], sizeof buf[k], "%s/%s", dir, name);
    return buf[k];
}

static void cleanup(const char *dir) {
    remove(path_in(dir, "checkpoint.bin"));
    rmdir(dir);
}

/* One task: once, interrupted at j and resumed, crashed after the checkpoint at K and resumed. */
static void check_resume(unsigned groups, int window, const char *name) {
    char base[] = "/tmp/pen_resume_XXXXXX";
    CHECK(mkdtemp(base) != NULL);
    char once[64], cut[64], crash[64];
    snprintf(once, sizeof once, "%s/once", base);
    snprintf(cut, sizeof cut, "%s/cut", base);
    snprintf(crash, sizeof crash, "%s/crash", base);
    CHECK(mkdir(crash, 0755) == 0);
    const int K = check_quick_() ? 3 : 5, j = check_quick_() ? 8 : 17; /* 2 K < j */
    pen_optim_task ta, tb, tc;
    pen_optim_result a = run(groups, window, once, 0, 0, NULL, &ta);
    /* Interrupted at j; the checkpoint of iteration 2K is copied away when it is written (the
     * loop writes it before that iteration's render, so the callback sees it). */
    stopper stop = {j, 2 * K, NULL, NULL};
    char from[96], to[96];
    snprintf(from, sizeof from, "%s/checkpoint.bin", cut);
    snprintf(to, sizeof to, "%s/checkpoint.bin", crash);
    stop.from = from, stop.to = to;
    pen_optim_result b = run(groups, window, cut, K, 0, &stop, &tb);
    CHECK(b.interrupted && b.iterations == j);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    b = run(groups, window, cut, K, 1, NULL, &tb);
    CHECK(b.resumed_from == j && !b.interrupted);
    pen_optim_result c = run(groups, window, crash, K, 1, NULL, &tc);
    CHECK(c.resumed_from == 2 * K);
    if (window > 0) /* the stopping rule decided after the resume, on history from before it */
        CHECK_MSG(a.converged && a.iterations > j, "%d iterations%s, interrupted at %d",
                  a.iterations, a.converged ? " (converged)" : "", j);
    printf("  %-12s %d iterations%s, loss %.5g -> %.5g; resumed at %d and at %d\n", name,
           a.iterations, a.converged ? " (converged)" : "", a.losses ? a.losses[0] : 0.0, a.final_loss, b.resumed_from,
           c.resumed_from);
    check_same(&a, &ta, &b, &tb, "interrupted + resumed");
    check_same(&a, &ta, &c, &tc, "crashed + resumed");
    pen_optim_result_free(&a);
    pen_optim_result_free(&b);
    pen_optim_result_free(&c);
    pen_optim_task_free(&ta);
    pen_optim_task_free(&tb);
    pen_optim_task_free(&tc);
    cleanup(once);
    cleanup(cut);
    cleanup(crash);
    rmdir(base);
}

static void test_resume_lighting_pose(void) {
    check_resume(PEN_OPTIM_LIGHTING | PEN_OPTIM_POSE, 0, "lighting+pose");
}

static void test_resume_deformation(void) { check_resume(PEN_OPTIM_DEFORMATION, 0, "deformation"); }

static void test_resume_stopping(void) {
    /* the rule stops after j (measured: 24 iterations of 30 with window 10, j = 17; 9 of 12
     * with window 5, j = 8, in the quick build) */
    check_resume(PEN_OPTIM_POSE, check_quick_() ? 5 : 10, "pose, stops");
}

/* Runs `groups` into the fresh folder made from the template `dir`, then resumes it with `edit`
 * applied to the task, which must be refused with `message`; returns the folder (the caller
 * cleans it up). */
static char *refused_resume(unsigned groups, void (*edit)(pen_optim_task *), const char *message,
                            char *dir) {
    CHECK(mkdtemp(dir) != NULL);
    pen_optim_task t;
    pen_optim_result r = run(groups, 0, dir, 0, 0, NULL, &t);
    pen_optim_result_free(&r);
    pen_optim_task_free(&t);
    t = make_task(groups, 0);
    edit(&t);
    pen_context *ctx = pen_context_create();
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = dir;
    set.resume = 1;
    CHECK(pen_optim_run(ctx, &t, &set, &r) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), message), "%s", pen_context_error(ctx));
    CHECK(r.losses == NULL && r.final.data == NULL);
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
    return dir;
}

static void move_start(pen_optim_task *t) { t->scene.objects[0].pose.translation[2] += 0.01f; }

/* A checkpoint is refused by a task with another initial guess, and when damaged. */
static void test_resume_refused(void) {
    char dir[] = "/tmp/pen_resume_XXXXXX";
    refused_resume(PEN_OPTIM_POSE, move_start, "checkpoint.bin: made for another initial guess",
                   dir);
    /* one flipped bit anywhere is caught: here in Adam's moments */
    const char *path = path_in(dir, "checkpoint.bin");
    FILE *f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (f) {
        CHECK(fseek(f, -40, SEEK_END) == 0);
        const int c = fgetc(f);
        CHECK(fseek(f, -40, SEEK_END) == 0);
        fputc(c ^ 4, f);
        fclose(f);
    }
    pen_optim_task t = make_task(PEN_OPTIM_POSE, 0);
    pen_context *ctx = pen_context_create();
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = dir;
    set.resume = 1;
    pen_optim_result r;
    CHECK(pen_optim_run(ctx, &t, &set, &r) == PEN_ERROR_PARSE);
    CHECK(strstr(pen_context_error(ctx), "checkpoint.bin: damaged checkpoint (checksum mismatch)"));
    /* An iteration (and Adam step) of INT32_MAX is refused from the counts alone, before the
     * checksum is read, without computing iteration + 1 in 32 bits (UBSan). The counts follow
     * the identity: 28 bytes, 20 a segment, then 92 (see the layout in checkpoint.c). */
    f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (f) {
        uint32_t segs = 0;
        CHECK(fseek(f, 24, SEEK_SET) == 0 && fread(&segs, 4, 1, f) == 1);
        const int32_t big[4] = {INT32_MAX, 3, 0, INT32_MAX}; /* iteration, losses, best, step */
        CHECK(fseek(f, 120 + 20 * (long)segs, SEEK_SET) == 0);
        CHECK(fwrite(big, sizeof big, 1, f) == 1);
        fclose(f);
    }
    pen_context_clear_error(ctx);
    CHECK(pen_optim_run(ctx, &t, &set, &r) == PEN_ERROR_PARSE);
    CHECK_MSG(strstr(pen_context_error(ctx), "damaged checkpoint (iteration 2147483647"), "%s",
              pen_context_error(ctx));
    pen_optim_task_free(&t);
    pen_context_destroy(ctx);
    cleanup(dir);
}

static void move_camera(pen_optim_task *t) { t->scene.camera.eye[0] += 0.01f; }
static void paint_ground(pen_optim_task *t) { t->scene.ground.albedo[1] *= 0.9f; }
static void filter_texture(pen_optim_task *t) {
    t->scene.objects[0].texture_filter = PEN_TEXTURE_FILTER_POINT;
}
static void overlap_none(pen_optim_task *t) { t->scene.shadow.overlap = PEN_OVERLAP_NONE; }

/* What the renders depend on besides the parameters and the target is part of the identity
 * (version 6): a resume after the scene's camera, its ground, an object's texture filter key or
 * the spheres' overlap rule was edited is refused, where it used to go on under the new scene. */
static void test_resume_other_scene(void) {
    void (*const edits[])(pen_optim_task *) = {move_camera, paint_ground, filter_texture,
                                               overlap_none};
    for (size_t k = 0; k < sizeof edits / sizeof edits[0]; ++k) {
        char dir[] = "/tmp/pen_resume_XXXXXX";
        cleanup(refused_resume(PEN_OPTIM_POSE, edits[k], "checkpoint.bin: made for another scene",
                               dir));
    }
}

static void stiffer(pen_optim_task *t) { t->spheres.w_smooth *= 2.0; }

/* The regularisers are part of the objective: a checkpoint of the spheres group is refused by
 * the same task with another smoothness weight. */
static void test_resume_other_regularisers(void) {
    char dir[] = "/tmp/pen_resume_XXXXXX";
    cleanup(refused_resume(PEN_OPTIM_SPHERES, stiffer,
                           "checkpoint.bin: made with other regularisers", dir));
}

/* Rewrites the checkpoint at `path` as the version-3 build wrote it for a default (Adam) task:
 * version 3, ridge 1e-2 (which Adam's loss then ignored), the checksum recomputed. */
static void make_version_3(const char *path) {
    os_checkpoint_downgrade(path, 3);
    static unsigned char buf[1 << 16];
    const size_t n = os_checkpoint_read(path, buf, sizeof buf);
    if (!n) return;
    int32_t solver = -1;
    const double ridge = 1e-2;
    const size_t at = os_checkpoint_solver_at(buf);
    memcpy(&solver, buf + at, 4);
    CHECK(solver == PEN_OPTIM_LIGHTING_ADAM);
    memcpy(buf + at + 4, &ridge, 8);
    os_checkpoint_write(path, buf, n);
}

/* A lighting task of the default solver ("auto") resumed from a checkpoint of the build before
 * it (version 3, Adam: the default then): it continues with Adam and no ridge, as that build
 * would have, bit for bit the run made in one go, although "auto" alone would take least
 * squares. */
/* An Adam lighting task with `ridge` run in one go into *a (its task *ta), and again into the
 * fresh folder made from the template `dir`, interrupted after j iterations; returns j. */
static int lighting_interrupted(pen_context *ctx, double ridge, char *dir, pen_optim_task *ta,
                                pen_optim_result *a) {
    CHECK(mkdtemp(dir) != NULL);
    const int j = check_quick_() ? 5 : 9;
    *ta = make_task(PEN_OPTIM_LIGHTING, 0);
    pen_optim_task tb = make_task(PEN_OPTIM_LIGHTING, 0);
    ta->lighting_solver = tb.lighting_solver = PEN_OPTIM_LIGHTING_ADAM;
    ta->lighting_ridge = tb.lighting_ridge = ridge;
    pen_optim_settings set = pen_optim_settings_default();
    CHECK(pen_optim_run(ctx, ta, &set, a) == PEN_OK);
    stopper stop = {j, -1, NULL, NULL};
    set.outdir = dir;
    set.progress = on_progress;
    set.progress_user = &stop;
    pen_optim_result b;
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_OK);
    CHECK(b.interrupted && b.iterations == j);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    return j;
}

static void test_resume_old_checkpoint(void) {
    char dir[] = "/tmp/pen_resume_XXXXXX";
    pen_context *ctx = pen_context_create();
    pen_optim_task ta, tb;
    pen_optim_result a, b;
    const int j = lighting_interrupted(ctx, NAN, dir, &ta, &a);
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = dir;
    make_version_3(path_in(dir, "checkpoint.bin"));
    tb = make_task(PEN_OPTIM_LIGHTING, 0);
    CHECK(tb.lighting_solver == PEN_OPTIM_LIGHTING_AUTO && isnan(tb.lighting_ridge));
    set.resume = 1;
    pen_status s = pen_optim_run(ctx, &tb, &set, &b);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    if (!s) {
        CHECK(b.resumed_from == j && b.lighting_solver == PEN_OPTIM_LIGHTING_ADAM &&
              b.lighting_ridge == 0.0);
        check_same(&a, &ta, &b, &tb, "version 3 + resumed");
        pen_optim_result_free(&b);
    }
    /* the same file against an explicit Adam ridge: another loss, refused */
    pen_optim_task_free(&tb);
    tb = make_task(PEN_OPTIM_LIGHTING, 0);
    tb.lighting_solver = PEN_OPTIM_LIGHTING_ADAM;
    tb.lighting_ridge = 1e-2;
    make_version_3(path_in(dir, "checkpoint.bin"));
    CHECK(pen_optim_run(ctx, &tb, &set, &b) == PEN_ERROR_ARGUMENT);
    CHECK_MSG(strstr(pen_context_error(ctx), "made with another lighting solver (adam, ridge 0)"),
              "%s", pen_context_error(ctx));
    pen_optim_result_free(&a);
    pen_optim_task_free(&ta);
    pen_optim_task_free(&tb);
    pen_context_destroy(ctx);
    cleanup(dir);
}

/* Version 4 weighed a multi-view task's ridge as all its views; a single-view task's ridge was
 * the same then as now, so its checkpoint still resumes (Adam with a lighting ridge: the ridge
 * is part of the loop's objective), bit for bit the run made in one go. */
static void test_resume_version_4_single_view(void) {
    char dir[] = "/tmp/pen_resume_XXXXXX";
    pen_context *ctx = pen_context_create();
    pen_optim_task ta, tb;
    pen_optim_result a, b;
    const int j = lighting_interrupted(ctx, 1e-2, dir, &ta, &a);
    pen_optim_settings set = pen_optim_settings_default();
    set.outdir = dir;
    os_checkpoint_downgrade(path_in(dir, "checkpoint.bin"), 4);
    tb = make_task(PEN_OPTIM_LIGHTING, 0);
    tb.lighting_solver = PEN_OPTIM_LIGHTING_ADAM;
    tb.lighting_ridge = 1e-2;
    set.resume = 1;
    const pen_status s = pen_optim_run(ctx, &tb, &set, &b);
    CHECK_MSG(s == PEN_OK, "%s", pen_context_error(ctx));
    if (!s) {
        CHECK(b.resumed_from == j && b.lighting_ridge == 1e-2);
        check_same(&a, &ta, &b, &tb, "version 4 + resumed");
        pen_optim_result_free(&b);
    }
    pen_optim_result_free(&a);
    pen_optim_task_free(&ta);
    pen_optim_task_free(&tb);
    pen_context_destroy(ctx);
    cleanup(dir);
}

/* Version 7 gave the groups the render's gradient bits (optim.h): a version-6 checkpoint holds a
 * deformation task's groups as 8 (pose's bit now), is read in the bits of then and resumes as
 * the run made in one go, bit for bit. */
static void test_resume_version_6_groups(void) {
    char dir[] = "/tmp/pen_resume_XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    const int j = check_quick_() ? 5 : 9;
    pen_optim_task ta, tb;
    pen_optim_result a = run(PEN_OPTIM_DEFORMATION, 0, NULL, 0, 0, NULL, &ta);
    stopper stop = {j, -1, NULL, NULL};
    pen_optim_result b = run(PEN_OPTIM_DEFORMATION, 0, dir, 0, 0, &stop, &tb);
    CHECK(b.interrupted && b.iterations == j);
    pen_optim_result_free(&b);
    pen_optim_task_free(&tb);
    os_checkpoint_downgrade(path_in(dir, "checkpoint.bin"), 6);
    b = run(PEN_OPTIM_DEFORMATION, 0, dir, 0, 1, NULL, &tb);
    CHECK(b.resumed_from == j);
    check_same(&a, &ta, &b, &tb, "version 6 + resumed");
    pen_optim_result_free(&a);
    pen_optim_result_free(&b);
    pen_optim_task_free(&ta);
    pen_optim_task_free(&tb);
    cleanup(dir);
}

RUN_TESTS(TEST(test_resume_lighting_pose), TEST(test_resume_deformation), TEST(test_resume_stopping),
          TEST(test_resume_refused), TEST(test_resume_other_scene),
          TEST(test_resume_other_regularisers),
          TEST(test_resume_old_checkpoint), TEST(test_resume_version_4_single_view),
          TEST(test_resume_version_6_groups))
