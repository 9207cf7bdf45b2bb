/* Importance sampling of an equirectangular environment map.
 *
 * The reference renderer treats each texel as a constant radiance over its patch of the sphere
 * (the same model the SH projection integrates), so a piecewise-constant density over texels is
 * exact: pick a row from the marginal CDF, a column from that row's conditional CDF, then a point
 * uniform in (u, v) inside the texel. With v = theta / pi and u = phi / (2 pi), the solid angle of
 * du dv is 2 pi^2 sin(theta) du dv, so the density in solid angle is
 *     p(w) = prob(texel) * W * H / (2 pi^2 sin(theta)).
 * Weights are the luminance of the texel, clamped at 0 like the lighting itself, times sin(theta)
 * at the row's centre: close to proportional to the light each texel sends. The CDFs are built in
 * double so that million-texel maps with a bright sun keep their small entries distinct.
 */
#include "reference/internal.h"

#include "core/internal.h"

#include <math.h>
#include <stdlib.h>

static double luminance_clamped(const pen_image *env, int x, int y) {
    double r = fmax((double)pen__texel(env, x, y, 0), 0.0);
    double g = fmax((double)pen__texel(env, x, y, 1), 0.0);
    double b = fmax((double)pen__texel(env, x, y, 2), 0.0);
    return 0.2126 * r + 0.7152 * g + 0.0722 * b;
}

pen_status pen__envmap_sampler_init(pen_context *ctx, const pen_image *env,
                                    pen__envmap_sampler *s) {
    *s = (pen__envmap_sampler){0};
    const int w = env->width, h = env->height;
    s->width = w;
    s->height = h;
    s->row_cdf = pen__malloc(ctx, (size_t)h + 1, sizeof(double), "envmap sampler rows");
    s->col_cdf = pen__malloc(ctx, (size_t)h, ((size_t)w + 1) * sizeof(double),
                             "envmap sampler columns");
    s->texel_prob = pen__malloc(ctx, (size_t)h, (size_t)w * sizeof(float),
                                "envmap sampler texels");
    if (!s->row_cdf || !s->col_cdf || !s->texel_prob) {
        pen__envmap_sampler_free(s);
        return PEN_ERROR_MEMORY;
    }
    s->row_cdf[0] = 0;
    for (int y = 0; y < h; ++y) {
        double sin_theta = sin(PEN_PI * (y + 0.5) / h);
        double *cdf = s->col_cdf + (size_t)y * ((size_t)w + 1);
        cdf[0] = 0;
        for (int x = 0; x < w; ++x) cdf[x + 1] = cdf[x] + luminance_clamped(env, x, y) * sin_theta;
        s->row_cdf[y + 1] = s->row_cdf[y] + cdf[w];
    }
    s->total = s->row_cdf[h];
    if (!(s->total > 0) || !isfinite(s->total)) {
        /* A black (or broken) map: nothing to importance-sample; the caller falls back to
         * cosine sampling alone, which is then exact (zero radiance) or at least unbiased. */
        s->total = 0;
        return PEN_OK;
    }
    for (int y = 0; y < h; ++y) {
        double *cdf = s->col_cdf + (size_t)y * ((size_t)w + 1);
        double row = cdf[w];
        for (int x = 0; x < w; ++x)
            s->texel_prob[(size_t)y * (size_t)w + (size_t)x] = (float)((cdf[x + 1] - cdf[x]) / s->total);
        for (int x = 1; x <= w; ++x) cdf[x] = row > 0 ? cdf[x] / row : (double)x / w;
        s->row_cdf[y + 1] /= s->total;
    }
    s->row_cdf[h] = 1.0;
    return PEN_OK;
}

void pen__envmap_sampler_free(pen__envmap_sampler *s) {
    if (!s) return;
    free(s->row_cdf);
    free(s->col_cdf);
    free(s->texel_prob);
    *s = (pen__envmap_sampler){0};
}

/* The index i in [0, n) with cdf[i] <= x < cdf[i + 1], skipping empty intervals. */
static int search_cdf(const double *cdf, int n, double x) {
    int lo = 0, hi = n; /* invariant: cdf[lo] <= x, answer in [lo, hi) */
    while (hi - lo > 1) {
        int mid = lo + (hi - lo) / 2;
        if (cdf[mid] <= x) lo = mid;
        else hi = mid;
    }
    /* x may sit on a run of equal entries (zero-weight cells); step to a cell with weight. */
    while (lo < n - 1 && cdf[lo + 1] <= cdf[lo]) ++lo;
    return lo;
}

void pen__envmap_sampler_sample(const pen__envmap_sampler *s, const float r[4], float *u, float *v,
                                int *tx, int *ty) {
    const int w = s->width, h = s->height;
    int y = search_cdf(s->row_cdf, h, (double)r[0]);
    int x = search_cdf(s->col_cdf + (size_t)y * ((size_t)w + 1), w, (double)r[1]);
    *tx = x;
    *ty = y;
    *u = ((float)x + r[2]) / (float)w;
    *v = ((float)y + r[3]) / (float)h;
}

float pen__envmap_sampler_pdf(const pen__envmap_sampler *s, int tx, int ty, float sin_theta) {
    if (s->total <= 0 || sin_theta <= 0) return 0.0f;
    double p = (double)s->texel_prob[(size_t)ty * (size_t)s->width + (size_t)tx];
    return (float)(p * s->width * s->height / (2.0 * PEN_PI * PEN_PI * (double)sin_theta));
}

void pen__envmap_texel(const pen_image *env, float u, float v, int *tx, int *ty) {
    int x = (int)floorf(u * (float)env->width), y = (int)floorf(v * (float)env->height);
    *tx = x < 0 ? 0 : x >= env->width ? env->width - 1 : x;
    *ty = y < 0 ? 0 : y >= env->height ? env->height - 1 : y;
}
