/* Importance sampling of an equirectangular environment map.
 *
 * The reference renderer treats each texel as a constant radiance over its patch of the sphere
 * (the same model the SH projection integrates), so a piecewise-constant density over texels is
 * exact: pick a texel with probability prob(texel), then a point uniform in (u, v) inside it.
 * With v = theta / pi and u = phi / (2 pi), the solid angle of du dv is 2 pi^2 sin(theta) du dv,
 * so the density in solid angle is
 *     p(w) = prob(texel) * W * H / (2 pi^2 sin(theta)).
 * Weights are the luminance of the texel, clamped at 0 like the lighting itself, times sin(theta)
 * at the row's centre: close to proportional to the light each texel sends.
 * Texels are drawn with Walker's alias method (Vose's construction): one table lookup per sample.
 * A binary search through row and column CDFs of a 1024x512 map costs some twenty cache misses per
 * sample and took a third of the render time; the alias table takes one or two.
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

/* Vose's alias table for the n probabilities p (summing to 1). `work` holds 2n indices. */
static void build_alias(size_t n, const double *p, uint32_t *work, pen__alias_cell *cells,
                        double *scaled) {
    uint32_t *small = work, *large = work + n;
    size_t ns = 0, nl = 0;
    for (size_t i = 0; i < n; ++i) {
        scaled[i] = p[i] * (double)n;
        if (scaled[i] < 1.0)
            small[ns++] = (uint32_t)i;
        else
            large[nl++] = (uint32_t)i;
    }
    while (ns > 0 && nl > 0) {
        uint32_t s = small[--ns], l = large[nl - 1];
        cells[s].threshold = (float)scaled[s];
        cells[s].alias = l;
        scaled[l] -= 1.0 - scaled[s];
        if (scaled[l] < 1.0) {
            --nl;
            small[ns++] = l;
        }
    }
    /* What is left is 1 up to rounding: keep those cells always. */
    while (nl > 0) {
        uint32_t l = large[--nl];
        cells[l].threshold = 1.0f, cells[l].alias = l;
    }
    while (ns > 0) {
        uint32_t s = small[--ns];
        cells[s].threshold = 1.0f, cells[s].alias = s;
    }
}

pen_status pen__envmap_sampler_init(pen_context *ctx, const pen_image *env,
                                    pen__envmap_sampler *s) {
    *s = (pen__envmap_sampler){0};
    const int w = env->width, h = env->height;
    const size_t n = (size_t)w * (size_t)h;
    s->width = w;
    s->height = h;
    s->cells = pen__malloc(ctx, n, sizeof(pen__alias_cell), "envmap alias table");
    s->texel_prob = pen__malloc(ctx, n, sizeof(float), "envmap texel probabilities");
    double *weight = pen__malloc(ctx, n, 2 * sizeof(double), "envmap weights");
    uint32_t *work = pen__malloc(ctx, n, 2 * sizeof(uint32_t), "envmap alias work");
    pen_status st = PEN_OK;
    if (!s->cells || !s->texel_prob || !weight || !work) {
        st = PEN_ERROR_MEMORY;
        goto done;
    }
    double total = 0;
    for (int y = 0; y < h; ++y) {
        double sin_theta = sin(PEN_PI * (y + 0.5) / h);
        for (int x = 0; x < w; ++x) {
            double wt = luminance_clamped(env, x, y) * sin_theta;
            weight[(size_t)y * (size_t)w + (size_t)x] = wt;
            total += wt;
        }
    }
    if (!(total > 0) || !isfinite(total)) {
        /* A black (or broken) map: nothing to importance-sample; the caller falls back to
         * cosine sampling alone, which is then exact (zero radiance) or at least unbiased. */
        goto done;
    }
    s->total = total;
    for (size_t i = 0; i < n; ++i) {
        weight[i] /= total;
        s->texel_prob[i] = (float)weight[i];
    }
    build_alias(n, weight, work, s->cells, weight + n);
done:
    free(weight);
    free(work);
    if (st) pen__envmap_sampler_free(s);
    return st;
}

void pen__envmap_sampler_free(pen__envmap_sampler *s) {
    if (!s) return;
    free(s->cells);
    free(s->texel_prob);
    *s = (pen__envmap_sampler){0};
}

void pen__envmap_sampler_sample(const pen__envmap_sampler *s, double pick, const float r[3],
                                float *u, float *v, int *tx, int *ty) {
    const size_t n = (size_t)s->width * (size_t)s->height;
    size_t i = (size_t)(pick * (double)n);
    if (i >= n) i = n - 1;
    const pen__alias_cell *c = &s->cells[i];
    if (r[0] >= c->threshold) i = c->alias;
    int x = (int)(i % (size_t)s->width), y = (int)(i / (size_t)s->width);
    *tx = x;
    *ty = y;
    *u = ((float)x + r[1]) / (float)s->width;
    *v = ((float)y + r[2]) / (float)s->height;
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
