/* penumbra: the command-line tool. Dispatches to one subcommand per file. */
#include "commands.h"

#include <stdio.h>
#include <string.h>

static const pen_command commands[] = {
    {"info", "what a mesh or scene holds: size, units, materials, closed, camera, lights",
     pen_cmd_info},
    {"render", "SH-shadow render of a scene JSON into .png/.exr/.hdr", pen_cmd_render},
    {"reference", "ray-traced Monte-Carlo ground truth of a scene (Embree)", pen_cmd_reference},
    {"fit-spheres", "fit a sphere set to a closed mesh", pen_cmd_fit_spheres},
    {"compare", "image error (rmse, rel_rmse, psnr) as JSON", pen_cmd_compare},
    {"optimize", "recover lighting, albedo, pose, shape or spheres from an image (inverse problem)",
     pen_cmd_optimize},
    {"import-cameras", "calibrated cameras of a COLMAP model or transforms.json as a views file",
     pen_cmd_import_cameras},
    {"bench", "performance suite: forward/backward timings and the reference ratio", pen_cmd_bench},
    {"sh-accuracy", "irradiance error of SH visibility against ray-tested truth", pen_cmd_sh_accuracy},
};
static const int command_count = (int)(sizeof commands / sizeof commands[0]);

static void print_help(FILE *f) {
    fprintf(f,
            "penumbra %s -- differentiable soft-shadow rendering with spherical-harmonics "
            "visibility\n\n"
            "Usage: penumbra <command> [options]\n"
            "       penumbra <command> --help\n"
            "       penumbra --version\n\nCommands:\n",
            pen_version());
    for (int i = 0; i < command_count; ++i)
        fprintf(f, "  %-14s %s\n", commands[i].name, commands[i].summary);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        print_help(stderr);
        return 2;
    }
    if (pen_cli_is_help(argv[1])) {
        print_help(stdout);
        return 0;
    }
    if (strcmp(argv[1], "--version") == 0 || strcmp(argv[1], "version") == 0) {
        printf("penumbra %s\n", pen_version());
        return 0;
    }
    /* optimize shares its views between the ranks of an mpirun (cli/mpi.c) */
    if (strcmp(argv[1], "optimize") == 0) {
        pen_cli_mpi_start(&argc, &argv);
        const int rc = pen_cmd_optimize(argc - 1, argv + 1);
        pen_cli_mpi_stop();
        return rc;
    }
    for (int i = 0; i < command_count; ++i)
        if (strcmp(argv[1], commands[i].name) == 0) return commands[i].run(argc - 1, argv + 1);
    fprintf(stderr, "penumbra: unknown command '%s'\n", argv[1]);
    fprintf(stderr, "Try 'penumbra --help'.\n");
    return 2;
}
