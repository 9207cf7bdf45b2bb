/* The library's one random-number generator: splitmix64 (Steele, Lea and Flood, "Fast splittable
 * pseudorandom number generators", OOPSLA 2014), a Weyl sequence with step 0x9E37...7C15 passed
 * through a 64-bit finaliser. Small, seedable and well mixed, so every stochastic step (the
 * sphere fit's samples, the overlap weights' lines, the reference renderer's paths) is
 * reproducible from its seed and independent of threads. Header-only: the state is a plain
 * uint64_t owned by the caller. */
#ifndef PEN_CORE_RANDOM_H
#define PEN_CORE_RANDOM_H

#include <stdint.h>

/* The Weyl step: the golden ratio in 64-bit fixed point (odd, so the sequence has full period). */
#define PEN__SPLITMIX_GAMMA 0x9E3779B97F4A7C15ull

/* The finaliser: a bijection of 64-bit words with good avalanche (also a hash of counters). */
static inline uint64_t pen__splitmix_mix(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Advances the state and returns the next 64 random bits. */
static inline uint64_t pen__splitmix_next(uint64_t *state) {
    return pen__splitmix_mix(*state += PEN__SPLITMIX_GAMMA);
}

/* Uniform in [0, 1) with 53 random bits (every value exactly representable as a double). */
static inline double pen__splitmix_uniform(uint64_t *state) {
    return (double)(pen__splitmix_next(state) >> 11) * (1.0 / 9007199254740992.0);
}

#endif
