/* A minimal test harness: CHECK macros that count failures, and a runner that prints the plain
 * closing line "N passed, M failed". Each tests/test_*.c is one ctest executable. */
#ifndef PEN_TEST_CHECK_H
#define PEN_TEST_CHECK_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#ifndef M_PI /* strict C11 does not define it */
#define M_PI 3.14159265358979323846
#endif

static int check_failures_ = 0;
static int check_count_ = 0;

#define CHECK(cond)                                                                          \
    do {                                                                                     \
        ++check_count_;                                                                      \
        if (!(cond)) {                                                                       \
            ++check_failures_;                                                               \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);         \
        }                                                                                    \
    } while (0)

#define CHECK_MSG(cond, ...)                                                                 \
    do {                                                                                     \
        ++check_count_;                                                                      \
        if (!(cond)) {                                                                       \
            ++check_failures_;                                                               \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond);         \
            fprintf(stderr, __VA_ARGS__);                                                    \
            fputc('\n', stderr);                                                             \
        }                                                                                    \
    } while (0)

/* |a - b| <= tol (absolute), NaN fails. */
#define CHECK_NEAR(a, b, tol)                                                                \
    do {                                                                                     \
        double a_ = (double)(a), b_ = (double)(b), t_ = (double)(tol);                       \
        CHECK_MSG(fabs(a_ - b_) <= t_, "%s = %.12g, %s = %.12g, tol %.3g", #a, a_, #b, b_, t_); \
    } while (0)

/* Relative check with an absolute floor: |a - b| <= tol * max(|a|, |b|, floor). */
#define CHECK_REL(a, b, tol, floor)                                                          \
    do {                                                                                     \
        double a_ = (double)(a), b_ = (double)(b);                                           \
        double s_ = fmax(fmax(fabs(a_), fabs(b_)), (double)(floor));                         \
        CHECK_MSG(fabs(a_ - b_) <= (double)(tol) * s_, "%s = %.12g, %s = %.12g, rel %.3g",   \
                  #a, a_, #b, b_, fabs(a_ - b_) / s_);                                       \
    } while (0)

typedef struct {
    const char *name;
    void (*fn)(void);
} check_test_;

/* Runs the tests, prints one line per test and the closing line; returns the exit status. */
static inline int check_run_(const check_test_ *tests, int n) {
    int passed = 0, failed = 0;
    for (int i = 0; i < n; ++i) {
        int before = check_failures_;
        tests[i].fn();
        int ok = check_failures_ == before;
        printf("%s %s\n", ok ? "ok  " : "FAIL", tests[i].name);
        ok ? ++passed : ++failed;
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}

#define TEST(fn) {#fn, fn}
#define RUN_TESTS(...)                                                                       \
    int main(void) {                                                                         \
        static const check_test_ tests_[] = {__VA_ARGS__};                                   \
        return check_run_(tests_, (int)(sizeof tests_ / sizeof tests_[0]));                  \
    }

/* Deterministic random numbers for tests (splitmix64). */
static inline double check_rand_(unsigned long long *s) {
    unsigned long long z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}

#if defined(_POSIX_C_SOURCE) && _POSIX_C_SOURCE >= 200809L
/* Tests that fit spheres call this first: the fit cache (pen_spheres_fit_cached writes into
 * $XDG_CACHE_HOME/penumbra) then goes to a fresh folder under /tmp, removed at exit, never into
 * the user's own cache, however the test is run. Needs _POSIX_C_SOURCE >= 200809L (mkdtemp,
 * setenv) defined before the first include. */
static char check_cache_dir_[] = "/tmp/pen_test_cache_XXXXXX";
static inline void check_cache_remove_(void) {
    char cmd[64];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", check_cache_dir_);
    if (system(cmd) != 0) fprintf(stderr, "could not remove %s\n", check_cache_dir_);
}
static inline void check_private_cache_(void) {
    if (!mkdtemp(check_cache_dir_) || setenv("XDG_CACHE_HOME", check_cache_dir_, 1) != 0) {
        fprintf(stderr, "cannot make a private cache folder\n");
        exit(1);
    }
    atexit(check_cache_remove_);
}
#endif

/* 1 when PEN_TEST_QUICK is set (sanitizer builds run smaller problem sizes). */
static inline int check_quick_(void) {
    const char *q = getenv("PEN_TEST_QUICK");
    return q && *q && *q != '0';
}

#endif
