/* penumbra optimize: solve an inverse problem (lighting, albedo, pose, deformation, spheres, lights)
 * described by a task JSON and write the results into a folder (pen_optim_run, pen_optim_write).
 *
 * On a terminal a progress line (iteration, loss, iterations per second, time left at most) is
 * redrawn on stderr; elsewhere (logs, tests) nothing but the final summary is printed. The run
 * checkpoints into the output folder every K iterations and at its end; --resume continues from
 * there. Ctrl-C stops the optimisation after the current iteration and still writes the results
 * and the checkpoint, marked "interrupted"; a second Ctrl-C kills; one pressed while the task
 * loads ends the run before it starts, without output.
 *
 * Under mpirun (cli/mpi.c) the ranks share the task's views: every rank loads the task and runs
 * it, only rank 0 shows progress, writes the folder and prints the summary. A rank that fails
 * prints its error (ranks other than 0 name themselves) and aborts the job, since the others
 * would wait for it in the next gather; Ctrl-C is left to mpirun, which ends the job (the last
 * checkpoint stays: --resume continues from it). */
#define _POSIX_C_SOURCE 200809L
#include "commands.h"

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
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
    int first;     /* the first iteration reported (-1: none yet) */
    double t0;     /* when it was reported (seconds, monotonic) */
} progress;

static double now_seconds(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* "iteration 120/500  loss 0.00123  8.3 it/s  left <= 0:45": the time left is that of the
 * iteration limit, an upper bound since the stopping rule may end the run earlier. The rate is
 * measured from the first iteration this run reported (a resumed run starts late). */
static int on_progress(void *user, int iteration, int iterations, double loss) {
    progress *p = user;
    if (p->tty) {
        const double t = now_seconds();
        if (p->first < 0) p->first = iteration, p->t0 = t;
        fprintf(stderr, "\riteration %d/%d  loss %.6g", iteration + 1, iterations, loss);
        const int done = iteration - p->first;
        if (done > 0 && t > p->t0) {
            const double rate = done / (t - p->t0);
            const long left = lround((iterations - 1 - iteration) / rate);
            fprintf(stderr, "  %.3g it/s  left <= %ld:%02ld", rate, left / 60, left % 60);
        }
        fprintf(stderr, "   ");
        fflush(stderr);
    }
    return interrupted != 0;
}

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra optimize TASK.json -o OUTDIR [options]\n\n"
            "Recovers the task's parameter groups (lighting, albedo, pose, deformation,\n"
            "spheres, disk lights, views' exposures) from its target image by Adam through the\n"
            "differentiable renderer (the lighting solved exactly by least squares instead\n"
            "when it is the only group: \"lighting_solver\": \"auto\", the default), and\n"
            "writes OUTDIR/result.json (iterations, timing, losses, each stage's loss before\n"
            "and after it, stop reason, metrics against the ground truth), scene.json (the\n"
            "recovered scene), final.exr/.png, compare.png, loss.svg, loss.png,\n"
            "checkpoint.bin and snapshots/iter_NNNNN.png. A task with \"views\" (several\n"
            "cameras and images) also writes final_<i>.exr per view, views.png, views.json, and\n"
            "validation_<i>.exr per \"validation_views\" entry. See docs/optimize.md.\n\n"
            "Options:\n"
            "  -o, --output DIR    output folder (created if missing; required)\n"
            "  --no-shadows        optimise without shadows (visibility 1: the baseline)\n"
            "  --iterations N      override the task's iteration limit\n"
            "  --target IMAGE      override the task's target (.exr, .hdr; .png, .jpg in sRGB)\n"
            "  --resume            continue from OUTDIR/checkpoint.bin (same result as one run)\n"
            "  --checkpoint-every K  checkpoint every K iterations (default 50; 0: at the end)\n"
            "  --snapshot-every K  render snapshot every K iterations (default 50; 0: none)\n"
            "  --threads N         worker threads (default: all cores; per rank under mpirun)\n"
            "  --memory-limit GB   refuse a task estimated to need more memory (default:\n"
            "                      the machine's; result.json has the estimate and the peak)\n"
            "  --view-workers N    views rendered at once (default 0: as many as threads when\n"
            "                      there are as many views; 1: one after the other, each with\n"
            "                      every thread); the result does not depend on it\n"
            "  --no-cache          fit {\"fit\": N} spheres afresh, without reading or writing\n"
            "                      the fit cache ($XDG_CACHE_HOME/penumbra; PENUMBRA_NO_CACHE=1)\n"
            "  -q, --quiet         no summary line\n\n"
            "Under mpirun (a build with MPI: README, \"Running on a cluster\") the ranks share\n"
            "the views of a task with \"views\"; the result is that of one process, and only\n"
            "rank 0 writes OUTDIR.\n");
}

/* The error line of a failure; under several ranks (not 0: naming the rank) and then the job's
 * end, since the other ranks may be waiting for this one. */
static int fail_rank(const pen_optim_ranks *ranks, const pen_context *ctx) {
    if (!ranks) return pen_cli_fail_ctx(CMD, ctx);
    if (ranks->rank == 0) pen_cli_fail_ctx(CMD, ctx);
    else pen_cli_fail(CMD, "rank %d: %s", ranks->rank, pen_context_error(ctx));
    fflush(stderr);
    pen_cli_mpi_abort(1);
    return 1;
}

static void print_metric(const char *name, double v) {
    if (!isnan(v)) printf(", %s %.4g", name, v);
}

/* One line per stage under the summary: "  least squares: 0.0412 -> 0.006319 (0.52 s)",
 * "  adam (60 iterations, 0.012 s/it): 0.006319 -> 0.00131 (0.72 s)" (no s/it without a step). */
static void print_stages(const pen_optim_result *res) {
    for (int k = 0; k < res->stage_count; ++k) {
        const pen_optim_stage *st = &res->stages[k];
        printf("  ");
        for (const char *c = st->name; *c; ++c)
            putchar(*c == '_' ? ' ' : *c);
        if (!strcmp(st->name, "adam") && st->iterations > 0)
            printf(" (%d iterations, %.3g s/it)", st->iterations, st->seconds / st->iterations);
        else if (!strcmp(st->name, "adam"))
            printf(" (0 iterations)");
        printf(": %.4g -> %.4g (%.2f s)\n", st->loss_before, st->loss_after, st->seconds);
    }
}

int pen_cmd_optimize(int argc, char **argv) {
    const char *task_path = NULL, *outdir = NULL, *target = NULL;
    int threads = 0, quiet = 0, iterations = 0, no_cache = 0;
    pen_optim_settings set = pen_optim_settings_default();
    set.checkpoint_every = 50;
    set.snapshot_every = 50;
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
            set.resume = 1;
        } else if (!strcmp(a, "--checkpoint-every")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 0, 1000000,
                                   &set.checkpoint_every))
                return 2;
        } else if (!strcmp(a, "--snapshot-every")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 0, 1000000,
                                   &set.snapshot_every))
                return 2;
        } else if (!strcmp(a, "--no-shadows")) {
            set.shadows = 0;
        } else if (!strcmp(a, "--iterations")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 1, 1000000,
                                   &iterations))
                return 2;
        } else if (!strcmp(a, "--threads")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 1, 4096, &threads))
                return 2;
        } else if (!strcmp(a, "--view-workers")) {
            if (!pen_cli_parse_int(CMD, a, i + 1 < argc ? argv[++i] : NULL, 0, 4096,
                                   &set.view_workers))
                return 2;
        } else if (!strcmp(a, "--memory-limit")) {
            double gb = 0.0;
            if (!pen_cli_parse_float(CMD, a, i + 1 < argc ? argv[++i] : NULL, 0.001, 1e6, &gb))
                return 2;
            set.memory_limit = gb * 1e9;
        } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (!strcmp(a, "--no-cache")) {
            no_cache = 1;
        } else if (pen_cli_positional(CMD, a, &task_path, 1)) {
            return 2;
        }
    }
    if (!task_path) return pen_cli_usage_error(CMD, "missing TASK.json");
    if (!outdir) return pen_cli_usage_error(CMD, "missing -o OUTDIR");
    set.ranks = pen_cli_mpi_ranks();
    const int root = !set.ranks || set.ranks->rank == 0;
    if (!root) quiet = 1;

    /* Ctrl-C is caught from here on, so that one pressed while the task loads is not lost: the
     * run then stops before it starts. A SIGINT ignored on entry (a background job of a
     * non-interactive shell) stays ignored. */
    void (*old)(int) = set.ranks ? signal(SIGINT, SIG_DFL) : signal(SIGINT, on_sigint);
    if (old == SIG_IGN) signal(SIGINT, SIG_IGN);
    pen_context *ctx = pen_context_create();
    if (!ctx) {
        signal(SIGINT, old == SIG_ERR ? SIG_DFL : old);
        return pen_cli_fail(CMD, "out of memory");
    }
    pen_context_set_threads(ctx, threads);
    if (no_cache) pen_context_set_fit_cache(ctx, 0);
    pen_optim_task task;
    pen_optim_result res;
    memset(&res, 0, sizeof res);
    int rc = 1;
    if (pen_optim_task_load_ex(ctx, task_path, target, &task)) {
        rc = fail_rank(set.ranks, ctx);
        goto out_ctx;
    }
    if (iterations > 0) task.iterations = iterations;
    /* The fits first (cached; pen_optim_run prepares the same way and finds them made), so that
     * the check below measures what the fitted spheres leave uncovered, as `render` does. */
    const unsigned needs_spheres = PEN_OPTIM_DEFORMATION | PEN_OPTIM_SPHERES;
    if (pen_scene_prepare(ctx, &task.scene, set.shadows || (task.optimize & needs_spheres),
                          NULL)) {
        rc = fail_rank(set.ranks, ctx);
        goto out_task;
    }
    pen_scene_report report; /* the scene's likely mistakes (pen_scene_check), on stderr */
    if (pen_scene_check(ctx, &task.scene, &report)) {
        rc = fail_rank(set.ranks, ctx);
        goto out_task;
    }
    if (root) pen_cli_print_warnings(CMD, &report);
    pen_scene_report_free(&report);
    if (interrupted) {
        pen_cli_fail(CMD, "interrupted before the optimisation started");
        rc = 130;
        goto out_task;
    }
    /* A task that will hold gigabytes says so before it starts (pen_optim_run refuses one the
     * machine or --memory-limit cannot hold). */
    const double need = pen_optim_memory_estimate(ctx, &task, &set);
    if (root && !quiet && need >= 1e9)
        fprintf(stderr, "%s: %s: about %.1f GB of memory estimated\n", CMD, task_path, need / 1e9);
    progress p = {root && isatty(fileno(stderr)), -1, 0.0};
    set.outdir = outdir;
    set.progress = on_progress;
    set.progress_user = &p;
    pen_status s = pen_optim_run(ctx, &task, &set, &res);
    if (p.tty) fputc('\n', stderr);
    if (s) {
        rc = fail_rank(set.ranks, ctx);
        goto out_task;
    }
    if (root && pen_optim_write(ctx, outdir, &task, &set, &res)) {
        rc = fail_rank(set.ranks, ctx);
        goto out_task;
    }
    if (!quiet) {
        printf("%s: %d iterations (%s), %.2f s, loss %.4g -> %.4g", outdir, res.iterations,
               res.interrupted ? "interrupted"
               : res.solved    ? "solved"
                               : (res.converged ? "converged" : "iteration limit"),
               res.seconds, res.initial_loss, res.final_loss);
        if (res.resumed_from > 0) printf(", resumed at %d", res.resumed_from);
        if (res.view_count > 0) printf(", %d views", res.view_count);
        const pen_optim_metrics *m = &res.metrics;
        print_metric("lighting_rel_error", m->lighting_rel_error);
        print_metric("albedo_psnr_db", m->albedo_psnr_db);
        print_metric("rotation_error_deg", m->rotation_error_deg);
        print_metric("translation_error", m->translation_error);
        if (task.optimize & PEN_OPTIM_DEFORMATION) print_metric("vertex_rmse", m->vertex_rmse);
        print_metric("sphere_iou", m->sphere_iou);
        print_metric("sphere_chamfer", m->sphere_chamfer);
        print_metric("shadow_iou", m->shadow_iou);
        if (res.validation_count > 0) printf(", validation_rel_rmse"); /* the held-back views' */
        for (int i = 0; i < res.validation_count; ++i)
            printf(" %.4g", res.validation[i].rel_rmse);
        printf("\n");
        print_stages(&res);
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
