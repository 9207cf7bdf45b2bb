/* Lights from an environment map: the compact bright sources (a sun, lamps, a window seen from
 * afar) found in an equirectangular map, each turned into a disk light (penumbra/scene.h,
 * pen_light), and the residual map they leave behind. The criterion is written out in
 * penumbra/envmap.h and docs/design.md sec. 1.14; this paragraph says why it has that shape.
 *
 * Why a split instead of a single threshold: a sun sits inside a sky that is itself many times
 * brighter than the ground, so any one threshold either takes the whole sky (not a light: its
 * SH projection is already good) or misses the night's dim lamp. Thresholds relative to the
 * map's median, rising by a fixed ratio inside the regions that are still too wide, find the
 * sun inside the sky and the lamp in the dark street alike, and stop at compact regions.
 *
 * Why the excess over the surroundings: the light is what a band-limited projection cannot
 * carry, the peak above its neighbourhood. Each texel of a light keeps min(L, b) (b the mean
 * of a thin ring around it) and the light gets L - min(L, b) >= 0, so residual + light = map
 * texel by texel, in every channel: no energy is created or lost, and the residual's SH plus the
 * lights' SH is the map's SH up to the disk-shape approximation of each light (a higher-band
 * effect of its size; the DC term is exact, see the irradiance below).
 *
 * Why (1 + cos b) / 2 in the irradiance: a pen_light of irradiance E and angular radius b has
 * radiance E / (pi sin^2 b), so that a surface facing it receives E; its integral over the
 * disk's solid angle 2 pi (1 - cos b) is 2 E / (1 + cos b). Setting that equal to the excess's
 * integral keeps the energy exact; for a 1 degree light the factor is 0.99992.
 *
 * Texels across the poles are not neighbours (only u wraps): a source straddling a pole splits
 * in two, which no map of the development set has. */
#include "core/internal.h"
#include "penumbra/envmap.h"
#include "penumbra/sh.h"

#include <stdlib.h>
#include <string.h>

#define HIST_PER_OCTAVE 32
#define HIST_MIN_LOG2 (-64)
#define HIST_BINS (128 * HIST_PER_OCTAVE)

/* The map's clamped texels, their luminance and their cells' solid angles. */
typedef struct texmap {
    const pen_image *env;
    int W, H;
    double *lum;     /* W * H */
    double *omega;   /* H: solid angle of one texel of each row */
} texmap;

static double texel_ch(const pen_image *env, size_t p, int c) {
    double v = env->data[p * (size_t)env->channels + (env->channels == 1 ? 0 : (size_t)c)];
    return v > 0.0 ? v : 0.0;
}

static double luminance(const double rgb[3]) {
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
}

static void texel_dir(const texmap *m, size_t p, double d[3]) {
    int x = (int)(p % (size_t)m->W), y = (int)(p / (size_t)m->W);
    double t0 = PEN_PI * y / m->H, t1 = PEN_PI * (y + 1) / m->H;
    double theta = 0.5 * (t0 + t1), phi = 2.0 * PEN_PI * (x + 0.5) / m->W;
    double st = sin(theta);
    d[0] = -st * sin(phi);
    d[1] = cos(theta);
    d[2] = st * cos(phi);
}

/* The solid-angle-weighted median luminance, from a histogram of log2(lum) with
 * HIST_PER_OCTAVE bins per octave (deterministic, O(texels)); 0 when half the sphere is black. */
static double median_luminance(pen_context *ctx, const texmap *m, double *out) {
    double *hist = pen__calloc(ctx, HIST_BINS, sizeof(double), "envmap lights histogram");
    if (!hist) return -1.0;
    double zero = 0.0, total = 0.0;
    for (size_t p = 0; p < (size_t)m->W * (size_t)m->H; ++p) {
        double w = m->omega[p / (size_t)m->W], l = m->lum[p];
        total += w;
        if (!(l > 0.0)) {
            zero += w;
            continue;
        }
        double b = floor((log2(l) - HIST_MIN_LOG2) * HIST_PER_OCTAVE);
        int bin = b < 0 ? 0 : b >= HIST_BINS ? HIST_BINS - 1 : (int)b;
        hist[bin] += w;
    }
    double acc = zero, med = 0.0;
    if (acc < 0.5 * total) {
        for (int b = 0; b < HIST_BINS; ++b) {
            acc += hist[b];
            if (acc >= 0.5 * total) { /* the bin's centre */
                med = exp2(HIST_MIN_LOG2 + (b + 0.5) / HIST_PER_OCTAVE);
                break;
            }
        }
    }
    free(hist);
    *out = med;
    return 0.0;
}

/* ---- Regions ----------------------------------------------------------------------------------
 * A region is a list of texel indices. Splitting a region at threshold t labels the connected
 * parts of its texels above t; `mark` holds, per texel, the id of the region it last joined. */

typedef struct region {
    int *pix;
    int n;
    double t; /* the threshold it was cut at */
    int leaf; /* compact: a candidate, not split further */
} region;

typedef struct regions {
    region *r;
    int n, cap;
} regions;

static int regions_push(pen_context *ctx, regions *rs, int *pix, int n, double t) {
    if (rs->n == rs->cap) {
        int cap = rs->cap ? 2 * rs->cap : 64;
        region *nr = realloc(rs->r, (size_t)cap * sizeof *nr);
        if (!nr) {
            pen__error(ctx, PEN_ERROR_MEMORY, "envmap lights: out of memory");
            return 0;
        }
        rs->r = nr;
        rs->cap = cap;
    }
    rs->r[rs->n++] = (region){pix, n, t, 0};
    return 1;
}

static void regions_free(regions *rs) {
    for (int i = 0; i < rs->n; ++i)
        free(rs->r[i].pix);
    free(rs->r);
}

/* The connected parts (8-neighbours, u wraps) of the texels of `parent` (whose mark is
 * parent_id) with luminance above t, appended to `out` with new ids from *next_id. `stack` has
 * room for W * H indices. */
static pen_status split(pen_context *ctx, const texmap *m, const region *parent, int parent_id,
                        double t, int *mark, int *next_id, int *stack, regions *out) {
    const int W = m->W, H = m->H;
    for (int i = 0; i < parent->n; ++i) {
        int seed = parent->pix[i];
        if (mark[seed] != parent_id || !(m->lum[seed] > t)) continue;
        int id = (*next_id)++;
        int n = 0, top = 0;
        mark[seed] = id;
        stack[top++] = seed;
        /* The stack's bottom doubles as the region's list: popped texels stay below `n`. */
        while (n < top) {
            int p = stack[n++];
            int x = p % W, y = p / W;
            for (int dy = -1; dy <= 1; ++dy) {
                int yy = y + dy;
                if (yy < 0 || yy >= H) continue;
                for (int dx = -1; dx <= 1; ++dx) {
                    int q = yy * W + (x + dx + W) % W;
                    if (mark[q] != parent_id || !(m->lum[q] > t)) continue;
                    mark[q] = id;
                    stack[top++] = q;
                }
            }
        }
        int *pix = pen__malloc(ctx, (size_t)n, sizeof(int), "envmap lights region");
        if (!pix) return PEN_ERROR_MEMORY;
        memcpy(pix, stack, (size_t)n * sizeof(int));
        if (!regions_push(ctx, out, pix, n, t)) {
            free(pix);
            return PEN_ERROR_MEMORY;
        }
    }
    return PEN_OK;
}

/* The luminance centroid's direction of a region and the largest angle (radians) from it to a
 * texel centre, plus half a texel diagonal. */
static double region_extent(const texmap *m, const region *r, double c[3]) {
    c[0] = c[1] = c[2] = 0.0;
    for (int i = 0; i < r->n; ++i) {
        double d[3], w = m->lum[r->pix[i]] * m->omega[r->pix[i] / m->W];
        texel_dir(m, (size_t)r->pix[i], d);
        for (int k = 0; k < 3; ++k)
            c[k] += w * d[k];
    }
    double len = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    if (!(len > 0.0)) return PEN_PI;
    double worst = 1.0;
    for (int k = 0; k < 3; ++k)
        c[k] /= len;
    for (int i = 0; i < r->n; ++i) {
        double d[3];
        texel_dir(m, (size_t)r->pix[i], d);
        double cs = c[0] * d[0] + c[1] * d[1] + c[2] * d[2];
        worst = cs < worst ? cs : worst;
    }
    double half_diag = 0.5 * PEN_PI / m->H * sqrt(5.0); /* the cell is at most pi/H x 2 pi/W */
    return acos(worst > 1.0 ? 1.0 : worst < -1.0 ? -1.0 : worst) + half_diag;
}

/* ---- Candidates -------------------------------------------------------------------------------
 */

/* Texel p's excess over the surroundings level, per channel: L - min(L, level) >= 0. */
static void texel_excess(const texmap *m, size_t p, const double level[3], double e[3]) {
    for (int c = 0; c < 3; ++c) {
        double L = texel_ch(m->env, p, c);
        e[c] = L - (L < level[c] ? L : level[c]);
    }
}

typedef struct candidate {
    const region *r;
    double level[3];  /* surroundings b */
    double excess[3]; /* integral of the excess radiance (unscaled map) */
    double dir[3];    /* map space */
    double radius;    /* radians */
    double share;
    int first;        /* smallest texel index, for ties */
} candidate;

/* Fills the surroundings level, the excess integral, direction and radius of region r. `stamp`
 * (W * H ints) marks ring texels already counted with the value `key`. */
static void measure(const texmap *m, const region *r, const int *mark, int rid, int *stamp,
                    int key, candidate *cd) {
    const int W = m->W, H = m->H, R = PEN_ENVMAP_LIGHT_RING;
    double ring[3] = {0, 0, 0}, ring_w = 0.0;
    cd->r = r;
    cd->first = r->pix[0];
    for (int i = 0; i < r->n; ++i) {
        int p = r->pix[i], x = p % W, y = p / W;
        cd->first = p < cd->first ? p : cd->first;
        for (int dy = -R; dy <= R; ++dy) {
            int yy = y + dy;
            if (yy < 0 || yy >= H) continue;
            for (int dx = -R; dx <= R; ++dx) {
                int q = yy * W + ((x + dx) % W + W) % W;
                if (mark[q] == rid || stamp[q] == key) continue;
                stamp[q] = key;
                double w = m->omega[yy];
                for (int c = 0; c < 3; ++c)
                    ring[c] += w * texel_ch(m->env, (size_t)q, c);
                ring_w += w;
            }
        }
    }
    for (int c = 0; c < 3; ++c)
        cd->level[c] = ring_w > 0.0 ? ring[c] / ring_w : 0.0;
    /* Excess, its luminance-weighted direction. */
    double sum_w = 0.0, dir[3] = {0, 0, 0};
    for (int c = 0; c < 3; ++c)
        cd->excess[c] = 0.0;
    for (int i = 0; i < r->n; ++i) {
        size_t p = (size_t)r->pix[i];
        double om = m->omega[p / (size_t)W], e[3], d[3];
        texel_excess(m, p, cd->level, e);
        for (int c = 0; c < 3; ++c)
            cd->excess[c] += om * e[c];
        double w = om * luminance(e);
        texel_dir(m, p, d);
        for (int k = 0; k < 3; ++k)
            dir[k] += w * d[k];
        sum_w += w;
    }
    double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    if (!(len > 0.0) || !(sum_w > 0.0)) {
        cd->radius = 0.0;
        cd->excess[0] = cd->excess[1] = cd->excess[2] = 0.0;
        cd->dir[0] = 0.0, cd->dir[1] = 1.0, cd->dir[2] = 0.0;
        return;
    }
    for (int k = 0; k < 3; ++k)
        cd->dir[k] = dir[k] / len;
    /* Second moment of the angle to the centre; a texel's own spread is the variance of a
     * uniform dtheta x (sin theta dphi) cell, (dtheta^2 + (sin theta dphi)^2) / 12. */
    double m2 = 0.0, dth = PEN_PI / H, dph = 2.0 * PEN_PI / W;
    for (int i = 0; i < r->n; ++i) {
        size_t p = (size_t)r->pix[i];
        double om = m->omega[p / (size_t)W], e[3], d[3];
        texel_excess(m, p, cd->level, e);
        texel_dir(m, p, d);
        double cs = cd->dir[0] * d[0] + cd->dir[1] * d[1] + cd->dir[2] * d[2];
        double th = acos(cs > 1.0 ? 1.0 : cs < -1.0 ? -1.0 : cs);
        double st = sqrt(d[0] * d[0] + d[2] * d[2]);
        m2 += om * luminance(e) * (th * th + (dth * dth + st * st * dph * dph) / 12.0);
    }
    cd->radius = sqrt(2.0 * m2 / sum_w);
}

static int candidate_order(const void *a, const void *b) {
    const candidate *x = a, *y = b;
    if (x->share != y->share) return x->share > y->share ? -1 : 1;
    return (x->first > y->first) - (x->first < y->first);
}

/* ---- Extraction -------------------------------------------------------------------------------
 */

static pen_status check_inputs(pen_context *ctx, const pen_image *env, float rot, float scale,
                               int max_lights) {
    if (!env || !env->data || env->width < 1 || env->height < 1 ||
        (env->channels != 1 && env->channels < 3))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "environment map: expected a non-empty 1- or 3-channel image");
    if (!isfinite(rot) || !isfinite(scale) || scale < 0.0f)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "environment map: rotation must be finite and scale finite and >= 0");
    if (max_lights < 0 || max_lights > PEN_SCENE_MAX_LIGHTS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "environment map: max_lights %d outside [0, %d]",
                          max_lights, PEN_SCENE_MAX_LIGHTS);
    const size_t n = (size_t)env->width * (size_t)env->height * (size_t)env->channels;
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(env->data[i]))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "environment map: texel %zu is not finite",
                              i / (size_t)env->channels);
    return PEN_OK;
}

/* The regions of step 2 of the criterion, in `all` (region 0 is the whole map); the compact
 * ones are marked leaf. Region i's texels carry mark i unless a part of it was cut out. */
static pen_status find_regions(pen_context *ctx, const texmap *m, double t0, double lum_max,
                               int *mark, regions *all) {
    const size_t N = (size_t)m->W * (size_t)m->H;
    int *stack = pen__malloc(ctx, N, sizeof(int), "envmap lights stack");
    int *every = pen__malloc(ctx, N, sizeof(int), "envmap lights region");
    if (!stack || !every) {
        free(stack);
        free(every);
        return PEN_ERROR_MEMORY;
    }
    for (size_t p = 0; p < N; ++p)
        every[p] = (int)p, mark[p] = 0;
    int next_id = 1;
    pen_status s = PEN_OK;
    if (!regions_push(ctx, all, every, (int)N, 0.0)) {
        free(every);
        s = PEN_ERROR_MEMORY;
    }
    /* Ids are region indices: split() takes the next id exactly when it appends a region. */
    const double max_extent = PEN_ENVMAP_LIGHT_MAX_EXTENT_DEG * PEN_PI / 180.0;
    for (int i = 0; !s && i < all->n; ++i) {
        region r = all->r[i];
        double t = i == 0 ? t0 : r.t * PEN_ENVMAP_LIGHT_STEP;
        if (i > 0) {
            double c[3];
            if (region_extent(m, &r, c) <= max_extent) {
                all->r[i].leaf = 1;
                continue;
            }
        }
        if (!(t < lum_max)) continue;
        s = split(ctx, m, &r, i, t, mark, &next_id, stack, all);
    }
    free(stack);
    return s;
}

pen_status pen_envmap_extract_lights(pen_context *ctx, const pen_image *env, float rotation_y_deg,
                                     float scale, int max_lights, pen_light *lights, int *count,
                                     pen_image *residual) {
    if (count) *count = 0;
    if (residual) memset(residual, 0, sizeof *residual);
    if (!count || (max_lights > 0 && !lights))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "environment map: no output for the lights");
    pen_status s = check_inputs(ctx, env, rotation_y_deg, scale, max_lights);
    if (s) return s;
    const int W = env->width, H = env->height;
    const size_t N = (size_t)W * (size_t)H;
    texmap m = {env, W, H, NULL, NULL};
    m.lum = pen__malloc(ctx, N, sizeof(double), "envmap lights luminance");
    m.omega = pen__malloc(ctx, (size_t)H, sizeof(double), "envmap lights solid angles");
    int *mark = pen__malloc(ctx, N, sizeof(int), "envmap lights marks");
    int *stamp = pen__malloc(ctx, N, sizeof(int), "envmap lights marks");
    candidate *cands = NULL;
    regions all = {NULL, 0, 0};
    if (!m.lum || !m.omega || !mark || !stamp) {
        s = PEN_ERROR_MEMORY;
        goto done;
    }
    double total_lum = 0.0, lum_max = 0.0;
    for (int y = 0; y < H; ++y)
        m.omega[y] = 2.0 * PEN_PI / W * (cos(PEN_PI * y / H) - cos(PEN_PI * (y + 1) / H));
    for (size_t p = 0; p < N; ++p) {
        double rgb[3] = {texel_ch(env, p, 0), texel_ch(env, p, 1), texel_ch(env, p, 2)};
        m.lum[p] = luminance(rgb);
        total_lum += m.omega[p / (size_t)W] * m.lum[p];
        lum_max = m.lum[p] > lum_max ? m.lum[p] : lum_max;
        stamp[p] = -1;
    }
    double med;
    if (median_luminance(ctx, &m, &med) < 0.0) {
        s = PEN_ERROR_MEMORY;
        goto done;
    }
    /* A map that is black over half the sphere has median 0: fall back to its mean. */
    double base = med > 0.0 ? med : total_lum / (4.0 * PEN_PI);
    if (max_lights > 0 && base > 0.0) {
        s = find_regions(ctx, &m, PEN_ENVMAP_LIGHT_THRESHOLD * base, lum_max, mark, &all);
        if (s) goto done;
        int nc = 0;
        cands = pen__calloc(ctx, (size_t)all.n + 1, sizeof *cands, "envmap lights candidates");
        if (!cands) {
            s = PEN_ERROR_MEMORY;
            goto done;
        }
        for (int i = 1; i < all.n; ++i) {
            if (!all.r[i].leaf) continue; /* a leaf's texels all still carry its mark */
            candidate cd;
            measure(&m, &all.r[i], mark, i, stamp, i, &cd);
            cd.share = total_lum > 0.0 ? luminance(cd.excess) / total_lum : 0.0;
            if (cd.share >= PEN_ENVMAP_LIGHT_MIN_SHARE) cands[nc++] = cd;
        }
        qsort(cands, (size_t)nc, sizeof *cands, candidate_order);
        *count = nc < max_lights ? nc : max_lights;
        const double a = (double)rotation_y_deg * PEN_PI / 180.0, ca = cos(a), sa = sin(a);
        for (int k = 0; k < *count; ++k) {
            const candidate *cd = &cands[k];
            double lo = PEN_SCENE_MIN_LIGHT_RADIUS_DEG * PEN_PI / 180.0;
            double hi = PEN_ENVMAP_LIGHT_MAX_EXTENT_DEG * PEN_PI / 180.0;
            double b = cd->radius < lo ? lo : cd->radius > hi ? hi : cd->radius;
            pen_light *L = &lights[k];
            /* Map direction to world: R_y(a) (penumbra/envmap.h). */
            double w[3] = {ca * cd->dir[0] + sa * cd->dir[2], cd->dir[1],
                           -sa * cd->dir[0] + ca * cd->dir[2]};
            double len = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
            for (int c = 0; c < 3; ++c) {
                L->direction[c] = (float)(w[c] / len);
                L->irradiance[c] = (float)((double)scale * 0.5 * (1.0 + cos(b)) * cd->excess[c]);
            }
            L->angular_radius_deg = (float)(b * 180.0 / PEN_PI);
        }
    }
    if (residual) {
        s = pen_image_create(ctx, W, H, 3, residual);
        if (s) goto done;
        for (size_t p = 0; p < N; ++p)
            for (int c = 0; c < 3; ++c)
                residual->data[3 * p + (size_t)c] =
                    env->data[p * (size_t)env->channels + (env->channels == 1 ? 0 : (size_t)c)];
        for (int k = 0; k < *count; ++k) {
            const candidate *cd = &cands[k];
            for (int i = 0; i < cd->r->n; ++i) {
                size_t p = (size_t)cd->r->pix[i];
                for (int c = 0; c < 3; ++c) {
                    double L = texel_ch(env, p, c);
                    residual->data[3 * p + (size_t)c] =
                        (float)(L < cd->level[c] ? L : cd->level[c]);
                }
            }
        }
    }
done:
    regions_free(&all);
    free(cands);
    free(stamp);
    free(mark);
    free(m.omega);
    free(m.lum);
    if (s) {
        if (count) *count = 0;
        if (residual) pen_image_free(residual);
    }
    return s;
}

pen_status pen_envmap_lighting(pen_context *ctx, const pen_image *env, int bands,
                               float rotation_y_deg, float scale, int max_lights, float sh[][3],
                               pen_light *lights, int *count) {
    if (max_lights == 0) return pen_envmap_to_sh(ctx, env, bands, rotation_y_deg, scale, sh);
    pen_image residual;
    pen_status s = pen_envmap_extract_lights(ctx, env, rotation_y_deg, scale, max_lights, lights,
                                             count, &residual);
    if (s) return s;
    s = pen_envmap_to_sh(ctx, &residual, bands, rotation_y_deg, scale, sh);
    pen_image_free(&residual);
    if (s && count) *count = 0;
    return s;
}

void pen_light_to_sh(int bands, const pen_light *light, float sh[][3]) {
    double b = (double)light->angular_radius_deg * PEN_PI / 180.0, s = sin(b);
    double z[PEN_SH_MAX_BANDS], out[PEN_SH_MAX_COEFFS];
    double d[3] = {light->direction[0], light->direction[1], light->direction[2]};
    double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    const int n = bands * bands;
    if (!(len > 0.0) || !(s > 0.0)) {
        for (int i = 0; i < n; ++i)
            sh[i][0] = sh[i][1] = sh[i][2] = 0.0f;
        return;
    }
    for (int k = 0; k < 3; ++k)
        d[k] /= len;
    pen_sh_zonal_cap_d(bands, cos(b), z, NULL);
    pen_sh_rotate_zonal_d(bands, z, d, out);
    for (int i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c)
            sh[i][c] = (float)((double)light->irradiance[c] / (PEN_PI * s * s) * out[i]);
}
