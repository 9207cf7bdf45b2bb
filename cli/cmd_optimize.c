/* penumbra optimize: solve an inverse problem (lighting, albedo, pose) described by a task JSON
 * and write the results into a folder (pen_optim_run, pen_optim_write).
 *
 * On a terminal a progress line (iteration, loss) is redrawn on stderr; elsewhere (logs, tests)
 * nothing but the final summary is printed. Ctrl-C stops the optimisation after the current
 * iteration and still writes the results, marked "interrupted"; a second Ctrl-C kills; one
 * pressed while the task loads ends the run before it starts, without output. */
#define _POSIX_C_SOURCE 200809L
#include "commands.h"

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

static const char *const CMD = "optimize";

static volatile sig_atomic_t interrupted = 0;

static void on_sigint(int sig) {
    (void)sig;
    interrupted = 1;
    signal(SIGINT, SIG_DFL); /* the second Ctrl-C ends the process */
}

typedef struct progress {
    int tty;
} progress;

static int on_progress(void *user, int iteration, int iterations, double loss) {
    const progress *p = user;
    if (p->tty) {
        fprintf(stderr, "\riteration %d/%d  loss %.6g   ", iteration + 1, iterations, loss);
        fflush(stderr);
    }
    return interrupted != 0;
}

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra optimize TASK.json -o OUTDIR [options]\n\n"
            "Recovers the task's parameter groups (lighting, albedo, pose, spheres) from its\n"
            "target image by Adam through the differentiable renderer, and writes OUTDIR/\n"
            "result.json (iterations, timing, losses, metrics against the ground truth),\n"
            "scene.json (the recovered scene), final.exr/.png, compare.png and loss.svg.\n"
            "See docs/optimize.md for the task JSON.\n\n"
            "Options:\n"
            "  -o, --output DIR    output folder (created if missing; required)\n"
            "  --no-shadows        optimise without shadows (visibility 1: the baseline)\n"
            "  --iterations N      override the task's iteration limit\n"
            "  --target IMAGE      override the task's target (.exr or .hdr)\n"
            "  --resume            start from OUTDIR/scene.json (an earlier run's result)\n"
            "  --threads N         worker threads (default: all cores)\n"
            "  -q, --quiet         no summary line\n");
}

/* --resume: the earlier run's recovered scene replaces the task's initial guess, taken as it
 * is (no black initial guesses). Adam's moments and the loss history start afresh. Returns 0, or
 * the exit status after printing the error. */
static int resume_from(pen_context *ctx, const char *outdir, pen_optim_task *task) {
    char path[4096];
    if (snprintf(path, sizeof path, "%s/scene.json", outdir) >= (int)sizeof path)
        return pen_cli_fail(CMD, "--resume: %s: path too long", outdir);
    pen_scene scene;
    if (pen_scene_load(ctx, path, &scene))
        return pen_cli_fail(CMD, "--resume: %s", pen_context_error(ctx));
    if (scene.camera.width != task->target.width || scene.camera.height != task->target.height) {
        pen_scene_free(&scene);
        return pen_cli_fail(CMD, "--resume: %s: the camera is %dx%d but the target is %dx%d", path,
                            scene.camera.width, scene.camera.height, task->target.width,
                            task->target.height);
    }
    pen_scene_free(&task->scene);
    task->scene = scene;
    task->init_black = 0;
    return 0;
}

static void print_metric(const char *name, double v) {
    if (!isnan(v)) printf(", %s %.4g", name, v);
}

int pen_cmd_optimize(int argc, char **argv) {
    const char *task_path = NULL, *outdir = NULL, *target = NULL;
    int threads = 0, quiet = 0, iterations = 0, resume = 0;
    pen_optim_settings set = pen_optim_settings_default();
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            if (++i >= argc) return pen_cli_usage_error(CMD, "%s needs a value", a);
            outdir = argv[i];
        } else if (!strcmp(a, "--target")) {
            if (++i >= argc) return pen_cli_usage_error(CMD, "%s needs a value", a);
            target = argv[i];
        } else if (!strcmp(a, "--resume")) {
            resume = 1;
        } else if (!strcmp(a, "--no-shadows")) {
            set.shadows = 0;
        } else if (!strcmp(a, "--iterations")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 1, 1000000,
                                   &iterations))
                return 2;
        } else if (!strcmp(a, "--threads")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 1, 4096, &threads))
                return 2;
        } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (pen_cli_positional(CMD, a, &task_path, 1)) {
            return 2;
        }
    }
    if (!task_path) return pen_cli_usage_error(CMD, "missing TASK.json");
    if (!outdir) return pen_cli_usage_error(CMD, "missing -o OUTDIR");

    /* Ctrl-C is caught from here on, so that one pressed while the task loads is not lost: the
     * run then stops before it starts. A SIGINT ignored on entry (a background job of a
     * non-interactive shell) stays ignored. */
    void (*old)(int) = signal(SIGINT, on_sigint);
    if (old == SIG_IGN) signal(SIGINT, SIG_IGN);
    pen_context *ctx = pen_context_create();
    if (!ctx) {
        signal(SIGINT, old == SIG_ERR ? SIG_DFL : old);
        return pen_cli_fail(CMD, "out of memory");
    }
    pen_context_set_threads(ctx, threads);
    pen_optim_task task;
    pen_optim_result res;
    memset(&res, 0, sizeof res);
    int rc = 1;
    if (pen_optim_task_load_ex(ctx, task_path, target, &task)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_ctx;
    }
    if (iterations > 0) task.iterations = iterations;
    if (resume && (rc = resume_from(ctx, outdir, &task)) != 0) goto out_task;
    if (interrupted) {
        pen_cli_fail(CMD, "interrupted before the optimisation started");
        rc = 130;
        goto out_task;
    }
    progress p = {isatty(fileno(stderr))};
    set.progress = on_progress;
    set.progress_user = &p;
    pen_status s = pen_optim_run(ctx, &task, &set, &res);
    if (p.tty) fputc('\n', stderr);
    if (s) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_task;
    }
    if (pen_optim_write(ctx, outdir, &task, &set, &res)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
        goto out_task;
    }
    if (!quiet) {
        printf("%s: %d iterations (%s), %.2f s, loss %.4g -> %.4g", outdir, res.iterations,
               res.interrupted ? "interrupted"
                               : (res.converged ? "converged" : "iteration limit"),
               res.seconds, res.losses[0], res.final_loss);
        const pen_optim_metrics *m = &res.metrics;
        print_metric("lighting_rel_error", m->lighting_rel_error);
        print_metric("albedo_psnr_db", m->albedo_psnr_db);
        print_metric("rotation_error_deg", m->rotation_error_deg);
        print_metric("translation_error", m->translation_error);
        printf("\n");
    }
    rc = res.interrupted ? 130 : 0;
out_task:
    pen_optim_result_free(&res);
    pen_optim_task_free(&task);
out_ctx:
    pen_context_destroy(ctx);
    signal(SIGINT, old == SIG_ERR ? SIG_DFL : old);
    return rc;
}
