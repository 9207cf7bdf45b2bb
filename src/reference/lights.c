/* Disk lights in the reference renderer: their exact radiance, the density of sampling each one
 * uniformly in solid angle (cone sampling), and the samples.
 *
 * A pen_light of irradiance E and angular radius b is a disk of uniform radiance
 * E / (pi sin^2 b) (penumbra/scene.h): a surface facing it, wholly above its horizon, receives
 * that radiance times the disk's projected solid angle pi sin^2 b, i.e. E. Cone sampling draws
 * cos(theta) uniform in [cos b, 1] around the light's direction, density 1 / (2 pi (1 - cos b)).
 * Suns are tiny (b = 0.27 deg is 1 - cos b = 1.1e-5, and the smallest accepted radius, 0.01 deg,
 * is 1.5e-8, below float's resolution near 1), so everything here runs in double, with
 * 1 - cos b written 2 sin^2(b / 2), and a direction is in a disk when the squared sine of its
 * angle to the centre, |w x d|^2, is at most sin^2 b (with w . d > 0): a test that keeps its
 * precision near the centre, where 1 - w . d would cancel. The estimator that combines these
 * samples with the map's and the cosine's (multiple importance sampling) is in reference.c. */
#include "reference/internal.h"

#include "core/internal.h"

#include <math.h>

void pen__ref_lights_init(const pen_light *lights, int count, pen__ref_lights *out) {
    out->count = 0;
    for (int k = 0; k < count && k < PEN_SCENE_MAX_LIGHTS; ++k) {
        const pen_light *src = &lights[k];
        double d[3] = {src->direction[0], src->direction[1], src->direction[2]};
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        double b = (double)src->angular_radius_deg * PEN_PI / 180.0;
        if (!(len > 0.0) || !(b > 0.0) || !(b < 0.5 * PEN_PI)) continue; /* validated earlier */
        pen__ref_light *l = &out->l[out->count++];
        for (int i = 0; i < 3; ++i)
            l->d[i] = d[i] / len;
        /* Orthonormal basis around d without a branch on the axis (Duff et al. 2017). */
        double sign = copysign(1.0, l->d[2]);
        double a = -1.0 / (sign + l->d[2]), bb = l->d[0] * l->d[1] * a;
        l->t[0] = 1.0 + sign * l->d[0] * l->d[0] * a, l->t[1] = sign * bb, l->t[2] = -sign * l->d[0];
        l->s[0] = bb, l->s[1] = sign + l->d[1] * l->d[1] * a, l->s[2] = -l->d[1];
        double sh = sin(0.5 * b);
        l->one_minus_cos = 2.0 * sh * sh;
        l->sin2 = sin(b) * sin(b);
        l->pdf = 1.0 / (2.0 * PEN_PI * l->one_minus_cos);
        for (int ch = 0; ch < 3; ++ch)
            l->radiance[ch] = (double)src->irradiance[ch] / (PEN_PI * l->sin2);
    }
}

/* 1 if w (unit) lies in light l's disk. */
static int in_disk(const pen__ref_light *l, const double w[3]) {
    double dot = w[0] * l->d[0] + w[1] * l->d[1] + w[2] * l->d[2];
    if (!(dot > 0.0)) return 0;
    double c[3] = {w[1] * l->d[2] - w[2] * l->d[1], w[2] * l->d[0] - w[0] * l->d[2],
                   w[0] * l->d[1] - w[1] * l->d[0]};
    return c[0] * c[0] + c[1] * c[1] + c[2] * c[2] <= l->sin2;
}

double pen__ref_lights_eval(const pen__ref_lights *ls, const float w[3], float L[3]) {
    double wd[3] = {w[0], w[1], w[2]}, acc[3] = {0, 0, 0}, pdf = 0.0;
    for (int k = 0; k < ls->count; ++k) {
        const pen__ref_light *l = &ls->l[k];
        if (!in_disk(l, wd)) continue;
        pdf += l->pdf;
        for (int ch = 0; ch < 3; ++ch)
            acc[ch] += l->radiance[ch];
    }
    for (int ch = 0; ch < 3; ++ch)
        L[ch] = (float)acc[ch];
    return pdf;
}

void pen__ref_light_sample(const pen__ref_light *l, float r1, float r2, float w[3]) {
    /* 1 - cos(theta) uniform in [0, 1 - cos b]; sin(theta) from it without cancellation. */
    double omc = (double)r1 * l->one_minus_cos;
    double ct = 1.0 - omc, st = sqrt(fmax(0.0, omc * (2.0 - omc)));
    double phi = 2.0 * PEN_PI * (double)r2;
    double x = st * cos(phi), y = st * sin(phi);
    double v[3], n = 0.0;
    for (int i = 0; i < 3; ++i) {
        v[i] = x * l->t[i] + y * l->s[i] + ct * l->d[i];
        n += v[i] * v[i];
    }
    n = sqrt(n);
    for (int i = 0; i < 3; ++i)
        w[i] = (float)(v[i] / n);
}
