/* penumbra sh-accuracy: the irradiance error of SH visibility against ray-tested truth, per
 * exponential method, sphere count, lighting and band count (protocol:
 * research/penumbra_research.h, docs/sh-accuracy.md). With --calibrate it also fits the calibrated
 * model on the training seed and prints the parameter rows for src/sh/calibration.c. The harness
 * is the penumbra_research library, not libpenumbra. */
#include "commands.h"
#include "penumbra_research.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const char *usage =
    "Usage: penumbra sh-accuracy [--bands N] [--json] [--seed S] [--sets N] [--quadrature N]\n"
    "                            [--envmap PATH]... [--no-envmaps] [--calibrate]\n\n"
    "Measures the irradiance error |E - E_true| / E_unoccluded of SH visibility (V = exp*(sum of\n"
    "sphere log-visibilities), E = L . (V * H_n)) against dense ray-tested quadrature, for seeded\n"
    "random sets of 1, 8 and 32 spheres over a receiver, under band-limited lighting: a sky with a\n"
    "sun and each environment map under a random rotation. Prints median and 90th percentile per\n"
    "method, sphere count and lighting, and the median raw coefficient error of V.\n\n"
    "  --bands N       one band count (3..6); default: 3, 4, 5 and 6\n"
    "  --json          one JSON object per row on stdout\n"
    "  --seed S        seed of the evaluation set (default 2, held out from calibration)\n"
    "  --sets N        sphere sets per sphere count (default 100)\n"
    "  --quadrature N  truth quadrature: N rows x 2N columns of directions (default 256)\n"
    "  --envmap PATH   an environment map (.hdr/.exr/.png); repeatable, at most 3\n"
    "                  (default: the bundled city.hdr and interior.hdr)\n"
    "  --no-envmaps    sky+sun lighting only\n"
    "  --calibrate     fit the calibrated model on seed 1 for each band count, print the rows for\n"
    "                  src/sh/calibration.c, then evaluate the fitted model on the held-out seed\n";

typedef struct method_row {
    const char *label;
    pen_sh_exp_model model;
    double epsilon;
} method_row;

/* Nanoseconds per receiver point: 8 sphere log-visibilities, the exponential and V * H_n. */
static double time_per_point(int bands, const pen_sh_exp_model *m, double eps) {
    const pen_sh_gaunt *g = pen_sh_gaunt_table(bands);
    float zc[PEN_SH_MAX_BANDS], H[PEN_SH_MAX_COEFFS], V[PEN_SH_MAX_COEFFS], VH[PEN_SH_MAX_COEFFS];
    const float up[3] = {0, 1, 0}, x[3] = {0, 0, 0};
    pen_sh_zonal_clamped_cosine(bands, zc);
    pen_sh_rotate_zonal(bands, zc, up, H);
    const int n = bands * bands, reps = 20000;
    volatile float sink = 0;
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int r = 0; r < reps; ++r) {
        float F[PEN_SH_MAX_COEFFS] = {0}, f[PEN_SH_MAX_COEFFS];
        for (int s = 0; s < 8; ++s) {
            const float c[3] = {0.3f * (float)(s % 3) - 0.3f, 0.8f + 0.001f * (float)r, 0.2f * (float)s - 0.7f};
            pen_sh_logvis(bands, x, c, 0.25f, (float)eps, f);
            for (int k = 0; k < n; ++k) F[k] += f[k];
        }
        pen_sh_exp(m, g, F, V);
        pen_sh_product(g, V, H, VH);
        sink += VH[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    (void)sink;
    return ((double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec)) / reps;
}

static int report(pen_context *ctx, const pen_accuracy_set *set, int bands, const method_row *rows,
                  int nrows, int json) {
    const int nl = pen_accuracy_light_count(set);
    if (!json) {
        printf("\nbands %d: irradiance error |E - E_true| / E_unoccluded, median / p90 "
               "(coef = median |V - P V_true| / |P V_true|)\n",
               bands);
        printf("%-22s %4s %7s", "method", "eps", "spheres");
        for (int l = 0; l < nl; ++l) printf(" %17s", pen_accuracy_light_name(set, l));
        printf(" %7s %9s\n", "coef", "ns/point");
    }
    for (int r = 0; r < nrows; ++r) {
        pen_accuracy_stats st[PEN_ACCURACY_COUNTS][PEN_ACCURACY_MAX_LIGHTS];
        if (pen_accuracy_evaluate(ctx, set, bands, &rows[r].model, rows[r].epsilon, st))
            return pen_cli_fail_ctx("sh-accuracy", ctx);
        const double ns = time_per_point(bands, &rows[r].model, rows[r].epsilon);
        for (int c = 0; c < PEN_ACCURACY_COUNTS; ++c) {
            if (json) {
                for (int l = 0; l < nl; ++l)
                    printf("{\"bands\":%d,\"method\":\"%s\",\"epsilon\":%g,\"spheres\":%d,"
                           "\"lighting\":\"%s\",\"median\":%.5f,\"p90\":%.5f,\"mean\":%.5f,"
                           "\"coef_median\":%.5f,\"ns_per_point\":%.0f}\n",
                           bands, rows[r].label, rows[r].epsilon, pen_accuracy_sphere_count(c),
                           pen_accuracy_light_name(set, l), st[c][l].median, st[c][l].p90,
                           st[c][l].mean, st[c][l].coef_median, ns);
                continue;
            }
            printf("%-22s %4.2g %7d", rows[r].label, rows[r].epsilon, pen_accuracy_sphere_count(c));
            for (int l = 0; l < nl; ++l) printf("     %5.3f / %5.3f", st[c][l].median, st[c][l].p90);
            printf(" %7.3f %9.0f\n", st[c][0].coef_median, ns);
        }
    }
    return 0;
}

static void print_calibration_row(int bands, const pen_sh_exp_model *m, double objective) {
    printf("    {%d, %.6g, %d, %.6g, %.6g, %.6g, %.6g, {1", bands, m->epsilon, m->squarings, m->a1,
           m->a2, m->b1, m->b2);
    for (int l = 1; l < PEN_SH_MAX_BANDS; ++l) printf(", %.6g", m->window[l]);
    printf("}}, /* training objective %.5f */\n", objective);
}

int pen_cmd_sh_accuracy(int argc, char **argv) {
    const char *cmd = "sh-accuracy";
    int band_lo = 3, band_hi = 6, json = 0, calibrate = 0, no_env = 0, nenv = 0;
    const char *envpaths[PEN_ACCURACY_MAX_LIGHTS - 1];
    pen_accuracy_options opt = pen_accuracy_options_default();
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int iv;
        if (pen_cli_is_help(a)) {
            fputs(usage, stdout);
            return 0;
        } else if (!strcmp(a, "--bands")) {
            if (!pen_cli_parse_int(cmd, a, v, 3, PEN_ACCURACY_MAX_BANDS, &iv)) return 2;
            band_lo = band_hi = iv, ++i;
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (!strcmp(a, "--seed")) {
            if (!pen_cli_parse_int(cmd, a, v, 0, 2147483647, &iv)) return 2;
            opt.seed = (unsigned long long)iv, ++i;
        } else if (!strcmp(a, "--sets")) {
            if (!pen_cli_parse_int(cmd, a, v, 1, 100000, &opt.sets_per_count)) return 2;
            ++i;
        } else if (!strcmp(a, "--quadrature")) {
            if (!pen_cli_parse_int(cmd, a, v, 16, 8192, &opt.quadrature)) return 2;
            ++i;
        } else if (!strcmp(a, "--envmap")) {
            if (!v) return pen_cli_usage_error(cmd, "--envmap needs a path");
            if (nenv == PEN_ACCURACY_MAX_LIGHTS - 1)
                return pen_cli_usage_error(cmd, "at most %d --envmap", PEN_ACCURACY_MAX_LIGHTS - 1);
            envpaths[nenv++] = v, ++i;
        } else if (!strcmp(a, "--no-envmaps")) {
            no_env = 1;
        } else if (!strcmp(a, "--calibrate")) {
            calibrate = 1;
        } else {
            return pen_cli_usage_error(cmd, "unknown option '%s'", a);
        }
    }
    char bundled[2][4096];
    if (!nenv && !no_env) {
        const char *hint = "use --envmap PATH or --no-envmaps";
        if (!(envpaths[0] = pen_cli_data_path(cmd, "data/envmaps/city.hdr", hint, bundled[0],
                                              sizeof bundled[0])) ||
            !(envpaths[1] = pen_cli_data_path(cmd, "data/envmaps/interior.hdr", hint, bundled[1],
                                              sizeof bundled[1])))
            return 1;
        nenv = 2;
    }
    if (no_env) nenv = 0;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(cmd, "out of memory");
    pen_image envs[PEN_ACCURACY_MAX_LIGHTS - 1];
    const char *names[PEN_ACCURACY_MAX_LIGHTS - 1];
    memset(envs, 0, sizeof envs);
    int status = 0;
    pen_accuracy_set *set = NULL, *train = NULL;
    for (int e = 0; e < nenv && !status; ++e) {
        if (pen_image_load(ctx, envpaths[e], &envs[e])) status = pen_cli_fail_ctx(cmd, ctx);
        const char *slash = strrchr(envpaths[e], '/');
        names[e] = slash ? slash + 1 : envpaths[e];
    }
    opt.envmaps = envs, opt.envmap_count = nenv, opt.envmap_names = names;
    if (!status && pen_accuracy_set_create(ctx, &opt, &set)) status = pen_cli_fail_ctx(cmd, ctx);
    if (!status && calibrate) {
        pen_accuracy_options topt = opt;
        topt.seed = 1;
        if (pen_accuracy_set_create(ctx, &topt, &train)) status = pen_cli_fail_ctx(cmd, ctx);
    }
    if (!status && !json)
        printf("penumbra sh-accuracy: seed %llu, %d sets per sphere count, %d x %d quadrature\n",
               opt.seed, opt.sets_per_count, opt.quadrature, 2 * opt.quadrature);
    for (int bands = band_lo; bands <= band_hi && !status; ++bands) {
        method_row rows[6];
        int n = 0;
        pen_sh_exp_model cal = pen_sh_exp_model_default(PEN_SH_EXP_CALIBRATED, bands);
        if (calibrate) {
            double obj = 0;
            if (pen_accuracy_calibrate(ctx, train, bands, &cal, &obj)) {
                status = pen_cli_fail_ctx(cmd, ctx);
                break;
            }
            if (!json) print_calibration_row(bands, &cal, obj);
        }
        rows[n++] = (method_row){"calibrated", cal, cal.epsilon};
        rows[n++] = (method_row){"paper", pen_sh_exp_model_default(PEN_SH_EXP_PAPER, bands), 4.0};
        rows[n++] = (method_row){"paper", pen_sh_exp_model_default(PEN_SH_EXP_PAPER, bands), 2.0};
        rows[n++] = (method_row){"exact", pen_sh_exp_model_default(PEN_SH_EXP_EXACT, bands), 4.0};
        rows[n++] = (method_row){"exact", pen_sh_exp_model_default(PEN_SH_EXP_EXACT, bands), 2.0};
        status = report(ctx, set, bands, rows, n, json);
    }
    pen_accuracy_set_destroy(set);
    pen_accuracy_set_destroy(train);
    for (int e = 0; e < nenv; ++e) pen_image_free(&envs[e]);
    pen_context_destroy(ctx);
    return status;
}
