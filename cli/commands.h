/* The penumbra subcommands: one file each (cli/cmd_<name>.c), dispatched by cli/main.c.
 * Each takes the arguments after the command name (argv[0] is the command name) and returns the
 * process exit status. Shared helpers for argument parsing and error reporting live in
 * cli/common.c. */
#ifndef PEN_CLI_COMMANDS_H
#define PEN_CLI_COMMANDS_H

#include "penumbra/penumbra.h"

#include <stdio.h>

typedef struct pen_command {
    const char *name;
    const char *summary;                 /* one line for `penumbra --help` */
    int (*run)(int argc, char **argv);
} pen_command;

/* Every command. Add a line here and in cli/main.c's table. */
int pen_cmd_sh_accuracy(int argc, char **argv);
int pen_cmd_render(int argc, char **argv);
int pen_cmd_fit_spheres(int argc, char **argv);
int pen_cmd_reference(int argc, char **argv);
int pen_cmd_compare(int argc, char **argv);
int pen_cmd_optimize(int argc, char **argv);
int pen_cmd_bench(int argc, char **argv);
int pen_cmd_import_cameras(int argc, char **argv);
int pen_cmd_info(int argc, char **argv);

/* ---- What a scene holds, printed (cli/cmd_info.c; pen_scene_check in penumbra/fit.h) ---- */

/* One line per disk light of the scene (from the report of pen_scene_check), each beginning with
 * indent: "light 0 (found in sky.hdr): elevation 40.0 deg, azimuth 60.0 deg, angular radius 2.10
 * deg, direction (...), irradiance (...), 61 % of the light"; "no light found in sky.hdr: SH
 * lighting only" when a map gave none. */
void pen_cli_print_lights(FILE *f, const pen_scene *sc, const pen_scene_report *report,
                          const char *indent);
/* Each warning of the report as one line on stderr: "penumbra <cmd>: warning: <message>". */
void pen_cli_print_warnings(const char *cmd, const pen_scene_report *report);

/* ---- MPI (cli/mpi.c) ---- */

/* MPI_Init when an MPI launcher started the process (and the tool was built with MPI). */
void pen_cli_mpi_start(int *argc, char ***argv);
/* The ranks sharing `optimize`'s views; NULL for one process. */
const pen_optim_ranks *pen_cli_mpi_ranks(void);
/* MPI_Abort of every rank (a failed rank would leave the others waiting); no-op alone. */
void pen_cli_mpi_abort(int status);
void pen_cli_mpi_stop(void);

/* ---- Helpers (cli/common.c) ---- */

/* Prints "penumbra <cmd>: <message>" on stderr and returns exit status 1 (or 2 for usage). */
int pen_cli_fail(const char *cmd, const char *fmt, ...);
int pen_cli_usage_error(const char *cmd, const char *fmt, ...);
/* Prints the context's error as the one error line and returns 1. */
int pen_cli_fail_ctx(const char *cmd, const pen_context *ctx);
/* Parses an integer / float option value; on error prints a usage line and returns 0. */
int pen_cli_parse_int(const char *cmd, const char *flag, const char *text, long lo, long hi,
                      int *out);
int pen_cli_parse_float(const char *cmd, const char *flag, const char *text, double lo, double hi,
                        double *out);
/* A command-line word that matched no option: an unknown option ("-x") or the next of `count`
 * positional arguments, stored in the first empty slot. Returns 0, or 2 after printing the usage
 * error (unknown option, or one argument too many). */
int pen_cli_positional(const char *cmd, const char *arg, const char **slots, int count);
/* 1 if arg is -h or --help. */
int pen_cli_is_help(const char *arg);

/* All-or-nothing outputs of one command: a command that fails leaves every output path as it
 * found it (an existing file keeps its old contents, a new one is removed), and one that cannot
 * write an output says so before doing its work.
 *     pen_cli_outputs out = {0};
 *     if (!pen_cli_outputs_add(&out, CMD, path_a) || !pen_cli_outputs_add(&out, CMD, path_b))
 *         return 1;                                   (checked before the work)
 *     ... work ...
 *     if (!pen_cli_outputs_keep(&out, CMD)) fail;    (right before writing: keeps old files)
 *     ok = write a && write b;
 *     pen_cli_outputs_end(&out, ok);                 (restores or drops the kept files)
 * The library's writers are atomic (temporary file + rename), so each file is whole; this makes
 * the set whole. A kept file is a hard link (or a copy) named "<path>.penumbra-keep-<pid>". */
#define PEN_CLI_MAX_OUTPUTS 4
typedef struct pen_cli_outputs {
    int count;
    int kept_all; /* pen_cli_outputs_keep succeeded: outputs may have been written since */
    const char *path[PEN_CLI_MAX_OUTPUTS];
    char *kept[PEN_CLI_MAX_OUTPUTS]; /* the old file's second name, or NULL if none existed */
} pen_cli_outputs;
/* Adds an output path (not copied) after checking that it can be written: not a folder, and in
 * an existing folder this user may write. Returns 1, or 0 after printing the error line. */
int pen_cli_outputs_add(pen_cli_outputs *out, const char *cmd, const char *path);
/* Gives every existing output a second name so that it can be restored. Returns 1, or 0 after
 * printing the error line (then nothing is kept and nothing should be written). */
int pen_cli_outputs_keep(pen_cli_outputs *out, const char *cmd);
/* ok: drops the kept names. Not ok: puts each kept file back and removes outputs that did not
 * exist before (after pen_cli_outputs_keep only: before it nothing was written). */
void pen_cli_outputs_end(pen_cli_outputs *out, int ok);
/* The bundled file `rel` (e.g. "data/envmaps/city.hdr"), looked for at run time, first found of:
 * $PENUMBRA_DATA_DIR/rel, <exe dir>/../share/penumbra/rel (installed), <exe dir>/../rel and
 * <exe dir>/../../rel (a build folder inside the checkout), <source>/rel where <exe
 * dir>/penumbra-source names the source tree (a build folder anywhere). Writes the path into buf and returns
 * it; otherwise prints one error line naming every place tried, then `hint` (what the user can
 * do instead), and returns NULL. */
const char *pen_cli_data_path(const char *cmd, const char *rel, const char *hint, char *buf,
                              size_t size);

#endif
