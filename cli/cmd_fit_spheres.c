/* penumbra fit-spheres: fit a sphere set to a closed mesh and write it as JSON with its metrics. */
#include "commands.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const CMD = "fit-spheres";

static void usage(FILE *f) {
    fprintf(f,
            "Usage: penumbra fit-spheres MESH -n N -o SPHERES.json [options]\n\n"
            "Fits N spheres to a closed mesh (.obj, .ply) by minimizing outside volume plus\n"
            "uncovered surface (docs/fit-spheres.md) and writes them with their metrics.\n"
            "Prints the metrics as JSON on stdout, and a warning on stderr when the spheres\n"
            "leave more than %.0f%% of the surface uncovered (metrics \"uncovered\").\n\n"
            "Options (defaults in brackets):\n"
            "  -n N                    number of spheres, 1..%d\n"
            "  -o FILE                 output sphere set (.json)\n"
            "  --voxels R              voxels along the longest axis [64]\n"
            "  --surface-weight W      weight w_s of the surface term [7]\n"
            "  --margin K              soft margin in voxels (sets sigma) [0.25]\n"
            "  --samples-per-area A    surface samples per voxel face of area [1]\n"
            "  --iterations I          Adam iterations [600]\n"
            "  --learning-rate L       Adam step in voxels [0.5]\n"
            "  --seed S                seed of the initialization and samples [1]\n"
            "  --threads T             threads (0: all cores) [0]\n"
            "  --preview FILE          also write a picture of the spheres over the mesh\n"
            "  --view AZ EL            the picture's azimuth and elevation in degrees [145 20]\n",
            100 * PEN_SPHERES_COVERAGE_WARN, PEN_FIT_MAX_SPHERES);
}

/* Value of the option at argv[*i] (advancing *i), or NULL when it is missing. */
static const char *value(int argc, char **argv, int *i) {
    return *i + 1 < argc ? argv[++*i] : NULL;
}

int pen_cmd_fit_spheres(int argc, char **argv) {
    const char *mesh_path = NULL, *out_path = NULL, *preview_path = NULL;
    int count = 0, threads = 0;
    double az = 145, el = 20;
    pen_fit_settings s;
    pen_fit_settings_default(&s);
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        double x = 0;
        int ok = 1;
        if (pen_cli_is_help(a)) {
            usage(stdout);
            return 0;
        } else if (strcmp(a, "-n") == 0) {
            ok = pen_cli_parse_int(CMD, a, value(argc, argv, &i), 1, PEN_FIT_MAX_SPHERES, &count);
        } else if (strcmp(a, "-o") == 0) {
            if (!(out_path = value(argc, argv, &i)))
                return pen_cli_usage_error(CMD, "-o needs a file");
        } else if (strcmp(a, "--voxels") == 0) {
            ok = pen_cli_parse_int(CMD, a, value(argc, argv, &i), 4, PEN_FIT_MAX_VOXELS, &s.voxels);
        } else if (strcmp(a, "--surface-weight") == 0) {
            ok = pen_cli_parse_float(CMD, a, value(argc, argv, &i), 1e-6, 1e6, &s.surface_weight);
        } else if (strcmp(a, "--margin") == 0) {
            ok = pen_cli_parse_float(CMD, a, value(argc, argv, &i), 1e-3, 100, &s.margin_voxels);
        } else if (strcmp(a, "--samples-per-area") == 0) {
            ok = pen_cli_parse_float(CMD, a, value(argc, argv, &i), 1e-3, 100,
                                     &s.samples_per_voxel_area);
        } else if (strcmp(a, "--iterations") == 0) {
            ok = pen_cli_parse_int(CMD, a, value(argc, argv, &i), 1, 1000000, &s.iterations);
        } else if (strcmp(a, "--learning-rate") == 0) {
            ok = pen_cli_parse_float(CMD, a, value(argc, argv, &i), 1e-6, 100, &s.learning_rate);
        } else if (strcmp(a, "--seed") == 0) {
            int seed = 0;
            ok = pen_cli_parse_int(CMD, a, value(argc, argv, &i), 0, 2147483647, &seed);
            s.seed = (unsigned long long)seed;
        } else if (strcmp(a, "--threads") == 0) {
            ok = pen_cli_parse_int(CMD, a, value(argc, argv, &i), 0, 1024, &threads);
        } else if (strcmp(a, "--preview") == 0) {
            if (!(preview_path = value(argc, argv, &i)))
                return pen_cli_usage_error(CMD, "--preview needs a file");
        } else if (strcmp(a, "--view") == 0) {
            ok = pen_cli_parse_float(CMD, "--view azimuth", value(argc, argv, &i), -360, 360, &x);
            az = x;
            ok = ok &&
                 pen_cli_parse_float(CMD, "--view elevation", value(argc, argv, &i), -90, 90, &el);
        } else if (pen_cli_positional(CMD, a, &mesh_path, 1)) {
            return 2;
        }
        if (!ok) return 2;
    }
    if (!mesh_path) return pen_cli_usage_error(CMD, "no mesh given");
    if (count == 0) return pen_cli_usage_error(CMD, "-n N is required");
    if (!out_path) return pen_cli_usage_error(CMD, "-o SPHERES.json is required");
    /* Both outputs are checked before the fit (seconds) and written all or nothing. */
    pen_cli_outputs outputs = {0};
    if (!pen_cli_outputs_add(&outputs, CMD, out_path) ||
        (preview_path && !pen_cli_outputs_add(&outputs, CMD, preview_path)))
        return 1;

    pen_context *ctx = pen_context_create();
    if (!ctx) return pen_cli_fail(CMD, "out of memory");
    pen_context_set_threads(ctx, threads);
    pen_mesh mesh;
    pen_spheres spheres = {0, NULL, NULL};
    pen_image picture = {0, 0, 0, NULL};
    pen_fit_metrics m;
    memset(&m, 0, sizeof m);
    int rc = 0;
    if (pen_mesh_load(ctx, mesh_path, &mesh)) {
        rc = pen_cli_fail_ctx(CMD, ctx);
    } else if (pen_spheres_fit(ctx, &mesh, count, &s, &spheres, &m)) {
        /* the fitter knows triangles, not files: name the mesh */
        rc = pen_cli_fail(CMD, "%s: %s", mesh_path, pen_context_error(ctx));
    }
    /* The picture is made before anything is written. */
    if (!rc && preview_path &&
        pen_spheres_preview(ctx, &mesh, &spheres, (float)az, (float)el, 400, &picture))
        rc = pen_cli_fail(CMD, "%s: %s", mesh_path, pen_context_error(ctx));
    char json[4096];
    pen_fit_json(&s, &m, json, sizeof json);
    if (!rc && !pen_cli_outputs_keep(&outputs, CMD)) rc = 1;
    if (!rc && pen_spheres_save(ctx, out_path, &spheres, json)) rc = pen_cli_fail_ctx(CMD, ctx);
    if (!rc && preview_path && pen_image_save(ctx, preview_path, &picture))
        rc = pen_cli_fail_ctx(CMD, ctx);
    pen_cli_outputs_end(&outputs, rc == 0); /* a failed write puts the old files back */
    if (!rc) printf("%s\n", json);
    /* A part left without spheres is missing from the shadow: say where (fit.h, coverage). */
    const pen_coverage_report *c = &m.coverage;
    if (!rc && c->uncovered > PEN_SPHERES_COVERAGE_WARN)
        fprintf(stderr,
                "penumbra %s: warning: %s: %d sphere%s leave%s %.1f%% of the surface farther than "
                "%.3g outside; the largest such part, %.1f%% of the surface, is around "
                "(%.3g, %.3g, %.3g), within (%.3g, %.3g, %.3g) to (%.3g, %.3g, %.3g); raise -n\n",
                CMD, mesh_path, count, count == 1 ? "" : "s", count == 1 ? "s" : "",
                100 * c->uncovered, c->tolerance, 100 * c->largest_share,
                (double)c->largest_centre[0], (double)c->largest_centre[1],
                (double)c->largest_centre[2], (double)c->largest_lo[0], (double)c->largest_lo[1],
                (double)c->largest_lo[2], (double)c->largest_hi[0], (double)c->largest_hi[1],
                (double)c->largest_hi[2]);
    pen_image_free(&picture);
    pen_spheres_free(&spheres);
    pen_mesh_free(&mesh);
    pen_context_destroy(ctx);
    return rc;
}
