/* Shared pieces of the fuzz harnesses (fuzz/fuzz_*.c): one context per process, a private
 * scratch folder for loaders that only read files, small fixed assets that scene and task
 * inputs can reference, and the checks that turn a silently wrong result into a finding.
 *
 * A harness hands the fuzzer's bytes to one parser of the library. A refusal (any status but
 * PEN_OK) is a correct answer; an accepted result must satisfy its type's invariants (finite
 * values, indices in range, sizes within the documented limits), otherwise fuzz_fail() aborts,
 * which libFuzzer and the replay test (fuzz/replay.c) both report as a failure. Not part of the
 * library: the harnesses use the public headers and, for the checkpoint, one internal one. */
#ifndef PEN_FUZZ_H
#define PEN_FUZZ_H

#include <penumbra/penumbra.h>

#include <stddef.h>
#include <stdint.h>

/* The entry point libFuzzer calls, and fuzz/replay.c for every stored input. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The process's context (single-threaded, created on first use). Its error is cleared. */
pen_context *fuzz_context(void);

/* The context's message after the last input ("" when it was accepted), for replay -v. */
const char *fuzz_message(void);

/* The scratch folder (created on first use, removed at exit) holding the fixed assets:
 * tri.obj, tri.ply (a tetrahedron), spheres.json (two spheres), tex.png (4x4), env.hdr and
 * env.exr (8x4 maps), target.exr (8x8, the camera size of the scene and task seeds). Scene and
 * task inputs are parsed as if they lay in this folder, so "mesh": "tri.obj" finds the mesh. */
const char *fuzz_dir(void);
/* Writes the input to fuzz_dir()/input.<ext> and returns that path (a static buffer). */
const char *fuzz_write(const uint8_t *data, size_t size, const char *ext);
/* A NUL-terminated copy of the input (the caller frees it). */
char *fuzz_text(const uint8_t *data, size_t size);

/* Prints "fuzz: <what>" and aborts: an accepted result broke an invariant. */
void fuzz_fail(const char *what) __attribute__((noreturn));
/* Aborts unless every one of the n values is finite. */
void fuzz_check_floats(const float *v, size_t n, const char *what);
/* The invariants of accepted results. */
void fuzz_check_mesh(const pen_mesh *mesh);
void fuzz_check_image(const pen_image *image);
void fuzz_check_spheres(const pen_spheres *spheres);
void fuzz_check_scene(const pen_scene *scene);

/* The image harnesses: writes the input as input.<ext>, loads it (sRGB and raw for PNG) and
 * checks what was accepted. */
int fuzz_image(const uint8_t *data, size_t size, const char *ext);
/* The mesh harnesses: writes the input as input.<ext>, loads it with `load` and checks what was
 * accepted (a refused mesh must come back zeroed). */
int fuzz_mesh(const uint8_t *data, size_t size, const char *ext,
              pen_status (*load)(pen_context *, const char *, pen_mesh *));

#endif
