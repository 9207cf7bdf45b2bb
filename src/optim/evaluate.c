/* Metrics of a recovered scene against the ground truth (result.json's "metrics").
 *
 * Lighting: ||L - L_true|| / ||L_true|| over every SH coefficient and channel (both scenes must
 * use the same band count). Albedo: PSNR with peak 1 over the texels the camera saw (a texel that
 * never received a gradient keeps its initial value and says nothing about the method), or over
 * the constant albedos. Pose: the geodesic angle between the rotations, computed from unit
 * quaternions in double as 2 atan2(|v|, |w|) of q q_true^-1, which stays accurate for small
 * angles where acos((tr R - 1) / 2) loses half its digits; the translation's Euclidean error;
 * the RMSE of the posed vertices, which weighs both by the object's extent. Multiple objects:
 * the albedo PSNR pools all texels, the pose errors are the largest over objects. */
#include "optim/optim_internal.h"

#include <string.h>

static void quaternion(const float a_deg[3], double q[4]) {
    const double x = (double)a_deg[0] * PEN_PI / 180.0, y = (double)a_deg[1] * PEN_PI / 180.0,
                 z = (double)a_deg[2] * PEN_PI / 180.0;
    const double angle = sqrt(x * x + y * y + z * z);
    const double half = 0.5 * angle;
    /* sin(half) / angle -> 1/2 as angle -> 0 */
    const double k = angle > 1e-12 ? sin(half) / angle : 0.5;
    q[0] = cos(half), q[1] = k * x, q[2] = k * y, q[3] = k * z;
}

double pen__optim_rotation_angle_deg(const float a_deg[3], const float b_deg[3]) {
    double p[4], q[4];
    quaternion(a_deg, p);
    quaternion(b_deg, q);
    /* r = p * conj(q) */
    const double w = p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3];
    const double v[3] = {-p[0] * q[1] + p[1] * q[0] - p[2] * q[3] + p[3] * q[2],
                         -p[0] * q[2] + p[2] * q[0] - p[3] * q[1] + p[1] * q[3],
                         -p[0] * q[3] + p[3] * q[0] - p[1] * q[2] + p[2] * q[1]};
    const double vn = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    return 2.0 * atan2(vn, fabs(w)) * 180.0 / PEN_PI;
}

/* The ground truth must have the scene's structure for the metrics to mean anything. */
static pen_status check_structure(pen_context *ctx, const pen_optim_task *t) {
    const pen_scene *sc = &t->scene, *gt = &t->ground_truth;
    const char *name = t->path ? t->path : "task";
    if (sc->object_count != gt->object_count)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: ground_truth: %d objects, but the scene has %d", name,
                          gt->object_count, sc->object_count);
    if ((t->optimize & PEN_OPTIM_LIGHTING) && sc->sh_bands != gt->sh_bands)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: ground_truth: sh_bands: %d, but the scene has %d", name,
                          gt->sh_bands, sc->sh_bands);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *a = &sc->objects[o], *b = &gt->objects[o];
        if ((t->optimize & PEN_OPTIM_ALBEDO) && (!a->texture.data) != (!b->texture.data))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: ground_truth: objects[%d]: a %s albedo, but the scene's is %s",
                              name, o, b->texture.data ? "texture" : "constant",
                              a->texture.data ? "a texture" : "constant");
        if ((t->optimize & PEN_OPTIM_ALBEDO) && a->texture.data &&
            (a->texture.width != b->texture.width || a->texture.height != b->texture.height ||
             a->texture.channels != b->texture.channels))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: ground_truth: objects[%d].albedo_texture: %dx%d, but the "
                              "scene's texture is %dx%d",
                              name, o, b->texture.width, b->texture.height, a->texture.width,
                              a->texture.height);
        if ((t->optimize & PEN_OPTIM_POSE) && a->mesh.vertex_count != b->mesh.vertex_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: ground_truth: objects[%d].mesh: %d vertices, but the scene's "
                              "mesh has %d",
                              name, o, b->mesh.vertex_count, a->mesh.vertex_count);
    }
    return PEN_OK;
}

static double lighting_error(const pen_scene *sc, const pen_scene *gt) {
    double num = 0.0, den = 0.0;
    for (int k = 0; k < sc->sh_bands * sc->sh_bands; ++k)
        for (int ch = 0; ch < 3; ++ch) {
            const double d = (double)sc->lighting.sh[k][ch] - (double)gt->lighting.sh[k][ch];
            num += d * d;
            den += (double)gt->lighting.sh[k][ch] * (double)gt->lighting.sh[k][ch];
        }
    return den > 0.0 ? sqrt(num / den) : (num > 0.0 ? (double)INFINITY : 0.0);
}

static void albedo_error(const pen_optim_task *t, unsigned char *const *observed,
                         pen_optim_metrics *m) {
    double sum = 0.0;
    long long values = 0, seen = 0, texels = 0;
    for (int o = 0; o < t->scene.object_count; ++o) {
        const pen_object *a = &t->scene.objects[o], *b = &t->ground_truth.objects[o];
        if (!a->texture.data) {
            for (int ch = 0; ch < 3; ++ch) {
                const double d = (double)a->albedo[ch] - (double)b->albedo[ch];
                sum += d * d;
            }
            values += 3, seen += 1, texels += 1;
            continue;
        }
        const int ch = a->texture.channels;
        const long long n = (long long)a->texture.width * a->texture.height;
        const unsigned char *obs = observed ? observed[o] : NULL;
        texels += n;
        for (long long i = 0; i < n; ++i) {
            if (obs && !obs[i]) continue;
            ++seen;
            for (int c = 0; c < ch; ++c) {
                const double d = (double)a->texture.data[i * ch + c] -
                                 (double)b->texture.data[i * ch + c];
                sum += d * d;
            }
            values += ch;
        }
    }
    m->albedo_observed = texels ? (double)seen / (double)texels : (double)NAN;
    m->albedo_psnr_db = values ? 10.0 * log10((double)values / sum) : (double)NAN;
}

static void pose_error(const pen_optim_task *t, pen_optim_metrics *m) {
    double rot = 0.0, trans = 0.0, sq = 0.0;
    long long n = 0;
    for (int o = 0; o < t->scene.object_count; ++o) {
        const pen_object *a = &t->scene.objects[o], *b = &t->ground_truth.objects[o];
        rot = fmax(rot, pen__optim_rotation_angle_deg(a->pose.rotation_axis_angle_deg,
                                                      b->pose.rotation_axis_angle_deg));
        double d2 = 0.0;
        for (int k = 0; k < 3; ++k) {
            const double d = (double)a->pose.translation[k] - (double)b->pose.translation[k];
            d2 += d * d;
        }
        trans = fmax(trans, sqrt(d2));
        for (int v = 0; v < a->mesh.vertex_count; ++v) {
            float pa[3], pb[3];
            pen_pose_apply(&a->pose, a->mesh.positions + 3 * v, pa);
            pen_pose_apply(&b->pose, b->mesh.positions + 3 * v, pb);
            for (int k = 0; k < 3; ++k)
                sq += ((double)pa[k] - (double)pb[k]) * ((double)pa[k] - (double)pb[k]);
            ++n;
        }
    }
    m->rotation_error_deg = rot;
    m->translation_error = trans;
    m->vertex_rmse = n ? sqrt(sq / (double)n) : (double)NAN;
}

pen_status pen__optim_metrics(pen_context *ctx, const pen_optim_task *t,
                              unsigned char *const *observed, pen_optim_metrics *m) {
    if (!t->has_ground_truth) return PEN_OK;
    pen_status s = check_structure(ctx, t);
    if (s) return s;
    if (t->optimize & PEN_OPTIM_LIGHTING)
        m->lighting_rel_error = lighting_error(&t->scene, &t->ground_truth);
    if (t->optimize & PEN_OPTIM_ALBEDO) albedo_error(t, observed, m);
    if (t->optimize & PEN_OPTIM_POSE) pose_error(t, m);
    return PEN_OK;
}
