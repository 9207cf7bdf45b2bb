/* Internal pieces of the reference renderer shared by its files: the counter-based random
 * numbers, the environment map's importance-sampling tables and the disk lights' sampling. */
#ifndef PEN_REFERENCE_INTERNAL_H
#define PEN_REFERENCE_INTERNAL_H

#include "core/random.h"
#include "penumbra/image.h"
#include "penumbra/scene.h"

#include <stdint.h>

/* ---- Counter-based random numbers -------------------------------------------------------------
 * A stream is keyed by (seed, a, b) -- e.g. (seed, pixel, sample) -- through the splitmix64
 * finaliser, and then steps a Weyl sequence through the same finaliser. No state is shared
 * between streams, so the numbers a sample sees do not depend on which thread runs it or when. */
typedef struct pen__rng {
    uint64_t state;
} pen__rng;

static inline pen__rng pen__rng_stream(uint64_t seed, uint64_t a, uint64_t b) {
    pen__rng r;
    uint64_t k = pen__splitmix_mix(seed + PEN__SPLITMIX_GAMMA);
    k = pen__splitmix_mix(k ^ (a + 0x632BE59BD9B4E019ull));
    r.state = pen__splitmix_mix(k ^ (b + 0x85157AF5ull));
    return r;
}

/* Uniform in [0, 1) with 24 random bits (every value exactly representable as a float). */
static inline float pen__rng_next(pen__rng *r) {
    return (float)(pen__splitmix_next(&r->state) >> 40) * 0x1p-24f;
}

/* Uniform in [0, 1) with 53 random bits, for choices among more than 2^24 items. */
static inline double pen__rng_next_double(pen__rng *r) {
    return (double)(pen__splitmix_next(&r->state) >> 11) * 0x1p-53;
}

/* ---- Environment-map sampling ------------------------------------------------------------------
 * A piecewise-constant 2-D distribution over the texels of an equirectangular map, weight =
 * luminance of the (clamped) texel times the sine of its row's polar angle, i.e. proportional to
 * the texel's contribution to the light arriving from it. Drawn in O(1) by an alias table. */
typedef struct pen__alias_cell {
    float threshold; /* keep the cell with this probability, else take `alias` */
    uint32_t alias;
} pen__alias_cell;

typedef struct pen__envmap_sampler {
    int width, height;
    double total;           /* sum of the weights; 0 for a black map (sampling disabled) */
    pen__alias_cell *cells; /* width * height, row-major like the image */
    float *texel_prob;      /* width * height probabilities, summing to 1 */
} pen__envmap_sampler;

/* Builds the tables of `env` (any channel count >= 1; channels >= 3 are RGB). */
pen_status pen__envmap_sampler_init(pen_context *ctx, const pen_image *env, pen__envmap_sampler *s);
void pen__envmap_sampler_free(pen__envmap_sampler *s);
/* Draws a texel (from pick, in [0,1) with enough bits to index every texel, and r[0]) and a point
 * uniform in it (r[1], r[2]), r in [0,1)^3. Returns the map coordinates (u, v) and the texel; the
 * density is pen__envmap_sampler_pdf there. */
void pen__envmap_sampler_sample(const pen__envmap_sampler *s, double pick, const float r[3],
                                float *u, float *v, int *tx, int *ty);
/* Density in solid angle of a direction that falls in texel (tx, ty), whose polar angle has
 * sine sin_theta: prob(texel) * width * height / (2 pi^2 sin_theta). 0 when sampling is off. */
float pen__envmap_sampler_pdf(const pen__envmap_sampler *s, int tx, int ty, float sin_theta);

/* The texel of map coordinates (u, v) in [0,1]^2 (clamped to the image). */
void pen__envmap_texel(const pen_image *env, float u, float v, int *tx, int *ty);
/* Channel ch (0..2) of a texel; one-channel images are grey. */
static inline float pen__texel(const pen_image *img, int x, int y, int ch) {
    int c = img->channels >= 3 ? ch : 0;
    return img
        ->data[((size_t)y * (size_t)img->width + (size_t)x) * (size_t)img->channels + (size_t)c];
}

/* ---- Disk lights (src/reference/lights.c) ------------------------------------------------------
 * Each light as a disk of uniform radiance E / (pi sin^2 b), sampled uniformly in solid angle. */
typedef struct pen__ref_light {
    double d[3], t[3], s[3]; /* unit direction and a basis around it */
    double one_minus_cos;    /* 1 - cos b, as 2 sin^2(b / 2) */
    double sin2;             /* sin^2 b */
    double pdf;              /* cone sampling's density, 1 / (2 pi (1 - cos b)) */
    double radiance[3];
} pen__ref_light;

typedef struct pen__ref_lights {
    int count;
    pen__ref_light l[PEN_SCENE_MAX_LIGHTS];
} pen__ref_lights;

/* The lights in use (count of them; a light without a direction or size is skipped). */
void pen__ref_lights_init(const pen_light *lights, int count, pen__ref_lights *out);
/* The summed radiance of the lights whose disks hold the unit direction w, into L; returns the
 * sum of their cone-sampling densities (0 when w is in none). */
double pen__ref_lights_eval(const pen__ref_lights *ls, const float w[3], float L[3]);
/* A direction uniform in solid angle over light l's disk, from r1, r2 in [0, 1). */
void pen__ref_light_sample(const pen__ref_light *l, float r1, float r2, float w[3]);

#endif
