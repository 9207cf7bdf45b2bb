/* The replay driver of the fuzz harnesses: links one fuzz/fuzz_<path>.c into an ordinary
 * executable (gcc or clang, no libFuzzer) that feeds every file of the folders named on the
 * command line to LLVMFuzzerTestOneInput, in name order. ctest runs it on fuzz/corpus/<path>
 * (which must hold at least one file) and fuzz/regressions/<path> (may be missing or empty),
 * so every stored input, crashers and hangs included, is rerun in seconds, also under ASan and
 * UBSan. A harness that finds an invariant broken aborts, which fails the test; the file being
 * replayed is printed first. Files whose names start with '.' are skipped. With -v first, each
 * file's outcome follows its name: "accepted" or the library's error line. */
#define _POSIX_C_SOURCE 200809L
#include "fuzz.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int verbose;

static int by_name(const void *a, const void *b) {
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Replays the files of `dir`; returns how many, or -1 when the folder cannot be listed. */
static long replay_dir(const char *dir) {
    DIR *d = opendir(dir);
    if (!d) return -1;
    char **names = NULL;
    size_t n = 0, cap = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.') continue;
        if (n == cap && !(names = realloc(names, (cap = cap ? 2 * cap : 64) * sizeof *names)))
            fuzz_fail("out of memory");
        if (!(names[n++] = strdup(e->d_name))) fuzz_fail("out of memory");
    }
    closedir(d);
    if (n) qsort(names, n, sizeof *names, by_name);
    for (size_t i = 0; i < n; ++i) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, names[i]);
        FILE *f = fopen(path, "rb");
        if (!f) fuzz_fail("cannot open an input");
        fseek(f, 0, SEEK_END);
        long size = ftell(f);
        fseek(f, 0, SEEK_SET);
        uint8_t *data = malloc(size > 0 ? (size_t)size : 1);
        if (size < 0 || !data || fread(data, 1, (size_t)size, f) != (size_t)size)
            fuzz_fail("cannot read an input");
        fclose(f);
        fprintf(stderr, "%s\n", path);
        LLVMFuzzerTestOneInput(data, (size_t)size);
        if (verbose) {
            const char *m = fuzz_message();
            fprintf(stderr, "    %s\n", m[0] ? m : "accepted");
        }
        free(data);
        free(names[i]);
    }
    free(names);
    return (long)n;
}

int main(int argc, char **argv) {
    int first = 1;
    if (argc > 1 && strcmp(argv[1], "-v") == 0) verbose = first = 2;
    if (argc <= first) {
        fprintf(stderr, "usage: %s [-v] CORPUS_DIR [MORE_DIRS...]\n", argv[0]);
        return 2;
    }
    /* stderr lists the files as they go, so that a crash names its input; stdout sums up. */
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    long total = 0;
    for (int i = first; i < argc; ++i) {
        long n = replay_dir(argv[i]);
        if (i == first && n <= 0) {
            fprintf(stderr, "%s: no inputs in %s\n", argv[0], argv[i]);
            return 1;
        }
        if (n > 0) total += n;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("%s: %ld inputs replayed in %.2f s\n", argv[0], total,
           (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec));
    return 0;
}
