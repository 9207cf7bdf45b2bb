/* The SH-visibility accuracy protocol of research/penumbra_research.h.
 *
 * Truth. For each sphere set we integrate, over a full-sphere grid equal-area in cos(theta) and
 * uniform in phi, with a ray-sphere test per direction:
 *     T_k = integral Y_k(w) V_true(w) max(w_y, 0) dw   (irradiance transfer, receiver normal +Y)
 *     P_k = integral Y_k(w) V_true(w) dw               (projected true visibility)
 * for k < PEN_ACCURACY_MAX_BANDS^2. Because the SH basis is orthonormal and nested, the lower band
 * counts use prefixes of these vectors, and any band-limited lighting L gives E_true = L . T
 * exactly; the unoccluded irradiance L . H_n is exact as well. Truth costs
 * (sets x directions x spheres) ray tests once; a model evaluation then costs only its own SH
 * work, which is what makes calibration by direct search affordable.
 *
 * Lighting. Sky + sun: radiance 1 everywhere plus a lobe S exp(kappa (w.s - 1)) with kappa = 100
 * and S = 1.5 kappa, so the sun's irradiance at normal incidence is about three times the sky's on
 * a horizontal receiver. Environment maps are box-filtered to 128 x 64 (plenty for six bands),
 * rotated about +Y by a random angle and projected; all lighting is reduced to luminance
 * (Rec. 709 weights) since visibility is colour-blind.
 */
#include "core/internal.h"
#include "core/random.h"
#include "penumbra_research.h"
#include "penumbra/scene.h"
#include "sh/sh_internal.h"

#include <stdlib.h>
#include <string.h>

#define NB PEN_ACCURACY_MAX_BANDS
#define NC (NB * NB)
#define MAX_SPHERES PEN_ACCURACY_MAX_SPHERES

static const int sphere_counts[PEN_ACCURACY_COUNTS] = {1, 8, 32};

typedef struct sample {
    int count;
    float spheres[MAX_SPHERES][4];
    double T[NC], P[NC];
    double L[PEN_ACCURACY_MAX_LIGHTS][NC]; /* luminance SH of each lighting */
} sample;

struct pen_accuracy_set {
    int sets_per_count;
    int light_count;
    const char *light_names[PEN_ACCURACY_MAX_LIGHTS];
    sample *samples; /* [PEN_ACCURACY_COUNTS * sets_per_count] */
};

pen_accuracy_options pen_accuracy_options_default(void) {
    pen_accuracy_options o;
    memset(&o, 0, sizeof o);
    o.seed = 2;
    o.sets_per_count = 100;
    o.quadrature = 256;
    return o;
}

int pen_accuracy_sphere_count(int c) {
    return c >= 0 && c < PEN_ACCURACY_COUNTS ? sphere_counts[c] : 0;
}

int pen_accuracy_light_count(const pen_accuracy_set *set) {
    return set->light_count;
}

const char *pen_accuracy_light_name(const pen_accuracy_set *set, int light) {
    return light >= 0 && light < set->light_count ? set->light_names[light] : "";
}

/* A unit direction with sin(elevation above the y = 0 plane) uniform in [lo, hi]. */
static void random_upper_direction(uint64_t *s, double lo, double hi, double d[3]) {
    const double sy = lo + (hi - lo) * pen__splitmix_uniform(s);
    const double phi = 2.0 * PEN_PI * pen__splitmix_uniform(s), c = sqrt(1.0 - sy * sy);
    d[0] = c * cos(phi), d[1] = sy, d[2] = c * sin(phi);
}

/* ---- Lighting ------------------------------------------------------------------------------ */

static void sky_sun_sh(uint64_t *s, double L[NC]) {
    const double kappa = 100.0, S = 1.5 * kappa;
    double sun[3], zl[NB];
    random_upper_direction(s, 0.1, 1.0, sun);
    /* Zonal coefficients of the lobe, 2 pi integral exp(kappa (t - 1)) Y_l0(t) dt, by Simpson's
     * rule in u with t = 1 - u^2 (u in [0, sqrt 2]), which packs the nodes where the lobe lives. */
    for (int l = 0; l < NB; ++l) zl[l] = 0.0;
    const int n = 4000;
    const double h = sqrt(2.0) / n;
    for (int i = 0; i <= n; ++i) {
        const double u = i * h, t = 1.0 - u * u;
        const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        const double f = S * exp(kappa * (t - 1.0)) * 2.0 * u; /* dt = 2u du */
        double P[NB];
        P[0] = 1.0, P[1] = t;
        for (int l = 1; l + 1 < NB; ++l) P[l + 1] = ((2.0 * l + 1.0) * t * P[l] - l * P[l - 1]) / (l + 1.0);
        for (int l = 0; l < NB; ++l) zl[l] += w * f * P[l] * sqrt((2.0 * l + 1.0) / (4.0 * PEN_PI));
    }
    for (int l = 0; l < NB; ++l) zl[l] *= 2.0 * PEN_PI * h / 3.0;
    pen_sh_rotate_zonal_d(NB, zl, sun, L);
    L[0] += sqrt(4.0 * PEN_PI); /* the constant sky, radiance 1 */
}

/* Box-filters an equirectangular map down to w x h (w, h divide the source size or not: each
 * output pixel averages the source pixels whose centres fall in it). */
static pen_status downsample(pen_context *ctx, const pen_image *src, int w, int h, pen_image *out) {
    pen_status st = pen_image_create(ctx, w, h, 3, out);
    if (st) return st;
    double *acc = pen__calloc(ctx, (size_t)w * h * 4, sizeof(double), "envmap downsample");
    if (!acc) return pen_image_free(out), PEN_ERROR_MEMORY;
    for (int y = 0; y < src->height; ++y)
        for (int x = 0; x < src->width; ++x) {
            const int ox = (int)((x + 0.5) * w / src->width), oy = (int)((y + 0.5) * h / src->height);
            const float *p = src->data + ((size_t)y * src->width + x) * src->channels;
            double *a = acc + ((size_t)oy * w + ox) * 4;
            for (int c = 0; c < 3; ++c) a[c] += (double)p[src->channels >= 3 ? c : 0];
            a[3] += 1.0;
        }
    for (size_t i = 0; i < (size_t)w * h; ++i)
        for (int c = 0; c < 3; ++c)
            out->data[i * 3 + c] = acc[i * 4 + 3] > 0 ? (float)(acc[i * 4 + c] / acc[i * 4 + 3]) : 0.0f;
    free(acc);
    return PEN_OK;
}

/* ---- Truth --------------------------------------------------------------------------------- */

static int blocked(const sample *s, const double w[3]) {
    for (int i = 0; i < s->count; ++i) {
        const float *sp = s->spheres[i];
        const double c[3] = {sp[0], sp[1], sp[2]}, r = sp[3];
        const double b = c[0] * w[0] + c[1] * w[1] + c[2] * w[2];
        const double cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        if (cc <= r * r) return 1;                   /* receiver inside */
        if (b > 0.0 && cc - b * b < r * r) return 1; /* ray from the origin hits it */
    }
    return 0;
}

void pen__accuracy_truth(const float (*spheres)[4], int count, int nq, double *T, double *P) {
    sample s;
    s.count = count;
    if (count > 0) memcpy(s.spheres, spheres, sizeof(float[4]) * (size_t)count);
    const int nz = nq, np = 2 * nq;
    const double dw = (2.0 / nz) * (2.0 * PEN_PI / np);
    memset(T, 0, sizeof(double) * NC);
    memset(P, 0, sizeof(double) * NC);
    double y[NC];
    for (int a = 0; a < nz; ++a) {
        /* rows of equal area: w_y uniform in [-1, 1] */
        const double wy = -1.0 + (a + 0.5) * 2.0 / nz, sxz = sqrt(1.0 - wy * wy);
        for (int b = 0; b < np; ++b) {
            const double phi = 2.0 * PEN_PI * (b + 0.5) / np;
            const double w[3] = {sxz * cos(phi), wy, sxz * sin(phi)};
            if (blocked(&s, w)) continue;
            pen_sh_eval_d(NB, w, y);
            const double cosw = wy > 0.0 ? wy : 0.0;
            for (int k = 0; k < NC; ++k) {
                P[k] += dw * y[k];
                T[k] += dw * cosw * y[k];
            }
        }
    }
}

pen_status pen_accuracy_set_create(pen_context *ctx, const pen_accuracy_options *opt,
                                   pen_accuracy_set **out) {
    *out = NULL;
    if (opt->sets_per_count < 1 || opt->sets_per_count > 100000)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "sets per count must be in [1, 100000], got %d",
                          opt->sets_per_count);
    if (opt->quadrature < 16 || opt->quadrature > 8192)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "quadrature must be in [16, 8192], got %d",
                          opt->quadrature);
    if (opt->envmap_count < 0 || opt->envmap_count > PEN_ACCURACY_MAX_LIGHTS - 1)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "at most %d environment maps",
                          PEN_ACCURACY_MAX_LIGHTS - 1);
    pen_accuracy_set *set = pen__calloc(ctx, 1, sizeof *set, "accuracy set");
    if (!set) return PEN_ERROR_MEMORY;
    set->sets_per_count = opt->sets_per_count;
    set->light_count = 1 + opt->envmap_count;
    set->light_names[0] = "sky+sun";
    for (int e = 0; e < opt->envmap_count; ++e)
        set->light_names[1 + e] = opt->envmap_names ? opt->envmap_names[e] : "envmap";
    const int total = PEN_ACCURACY_COUNTS * opt->sets_per_count;
    set->samples = pen__calloc(ctx, (size_t)total, sizeof(sample), "accuracy samples");
    if (!set->samples) return pen_accuracy_set_destroy(set), PEN_ERROR_MEMORY;

    /* Small copies of the maps, projected per sample under its own rotation. */
    pen_image small[PEN_ACCURACY_MAX_LIGHTS - 1];
    memset(small, 0, sizeof small);
    pen_status st = PEN_OK;
    for (int e = 0; e < opt->envmap_count && !st; ++e)
        st = downsample(ctx, &opt->envmaps[e], 128, 64, &small[e]);

    /* Draw every random number serially (each sample from its own stream), then integrate. */
    for (int i = 0; i < total && !st; ++i) {
        sample *s = &set->samples[i];
        /* One stream per sample, so results do not depend on thread scheduling. */
        uint64_t rs = opt->seed * 0x100000001B3ull + (uint64_t)i * 7919ull + 1;
        s->count = sphere_counts[i / opt->sets_per_count];
        for (int k = 0; k < s->count; ++k) {
            double d[3];
            const double D = 0.4 + 1.2 * pen__splitmix_uniform(&rs);
            const double r = (0.1 + 0.3 * pen__splitmix_uniform(&rs)) * D;
            random_upper_direction(&rs, 0.15, 1.0, d);
            for (int a = 0; a < 3; ++a) s->spheres[k][a] = (float)(D * d[a]);
            s->spheres[k][3] = (float)r;
        }
        sky_sun_sh(&rs, s->L[0]);
        for (int e = 0; e < opt->envmap_count && !st; ++e) {
            float sh[NC][3];
            const float rot = (float)(360.0 * pen__splitmix_uniform(&rs));
            st = pen_envmap_to_sh(ctx, &small[e], NB, rot, 1.0f, sh);
            for (int k = 0; k < NC; ++k)
                s->L[1 + e][k] = 0.2126 * (double)sh[k][0] + 0.7152 * (double)sh[k][1] + 0.0722 * (double)sh[k][2];
        }
    }
    for (int e = 0; e < opt->envmap_count; ++e) pen_image_free(&small[e]);
    if (st) return pen_accuracy_set_destroy(set), st;

#pragma omp parallel for schedule(dynamic, 1)
    for (int i = 0; i < total; ++i) {
        sample *sm = &set->samples[i];
        pen__accuracy_truth((const float(*)[4])sm->spheres, sm->count, opt->quadrature, sm->T, sm->P);
    }
    *out = set;
    return PEN_OK;
}

void pen_accuracy_set_destroy(pen_accuracy_set *set) {
    if (!set) return;
    free(set->samples);
    free(set);
}

/* ---- Evaluation ---------------------------------------------------------------------------- */

static int cmp_double(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double quantile(double *v, int n, double q) {
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    const double pos = q * (n - 1);
    const int i = (int)pos;
    return i + 1 < n ? v[i] + (pos - i) * (v[i + 1] - v[i]) : v[n - 1];
}

/* The model's visibility of one sample at `bands`, in float (the renderer's path). */
static void model_visibility(const sample *s, int bands, const pen_sh_gaunt *g,
                             const pen_sh_exp_model *m, float eps, float V[NC]) {
    const int n = bands * bands;
    float F[NC] = {0}, f[NC];
    const float x[3] = {0, 0, 0};
    for (int i = 0; i < s->count; ++i) {
        pen_sh_logvis(bands, x, s->spheres[i], s->spheres[i][3], eps, f);
        for (int k = 0; k < n; ++k) F[k] += f[k];
    }
    pen_sh_exp(m, g, F, V);
}

pen_status pen_accuracy_evaluate(pen_context *ctx, const pen_accuracy_set *set, int bands,
                                 const pen_sh_exp_model *m, double epsilon,
                                 pen_accuracy_stats stats[PEN_ACCURACY_COUNTS][PEN_ACCURACY_MAX_LIGHTS]) {
    if (bands < 1 || bands > NB)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "bands must be in [1, %d], got %d", NB, bands);
    const int n = bands * bands, per = set->sets_per_count, nl = set->light_count;
    const pen_sh_gaunt *g = pen_sh_gaunt_table(bands);
    if (!g) return pen__error(ctx, PEN_ERROR_MEMORY, "SH product table for %d bands", bands);
    double *err = pen__malloc(ctx, (size_t)(per * (nl + 1)), sizeof(double), "accuracy errors");
    if (!err) return PEN_ERROR_MEMORY;
    /* H_n for n = +Y, at this band count */
    float zc[NB], H[NC];
    const float up[3] = {0, 1, 0};
    pen_sh_zonal_clamped_cosine(bands, zc);
    pen_sh_rotate_zonal(bands, zc, up, H);
    for (int c = 0; c < PEN_ACCURACY_COUNTS; ++c) {
#pragma omp parallel for schedule(static)
        for (int j = 0; j < per; ++j) {
            const sample *s = &set->samples[c * per + j];
            float V[NC], VH[NC];
            model_visibility(s, bands, g, m, (float)epsilon, V);
            pen_sh_product(g, V, H, VH);
            for (int li = 0; li < nl; ++li) {
                double E = 0, Et = 0, E0 = 0;
                for (int k = 0; k < n; ++k) {
                    E += s->L[li][k] * (double)VH[k];
                    Et += s->L[li][k] * s->T[k];
                    E0 += s->L[li][k] * (double)H[k];
                }
                err[li * per + j] = fabs(E - Et) / E0;
            }
            double dv = 0, pv = 0;
            for (int k = 0; k < n; ++k) dv += pow((double)V[k] - s->P[k], 2), pv += s->P[k] * s->P[k];
            err[nl * per + j] = sqrt(dv / pv);
        }
        const double coef = quantile(err + nl * per, per, 0.5);
        for (int li = 0; li < nl; ++li) {
            double mean = 0;
            for (int j = 0; j < per; ++j) mean += err[li * per + j];
            stats[c][li].mean = mean / per;
            stats[c][li].median = quantile(err + li * per, per, 0.5);
            stats[c][li].p90 = quantile(err + li * per, per, 0.9);
            stats[c][li].coef_median = coef;
        }
    }
    free(err);
    return PEN_OK;
}
