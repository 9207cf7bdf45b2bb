/* Metrics of a recovered scene against the ground truth (result.json's "metrics").
 *
 * Lighting: ||L - L_true|| / ||L_true|| over every SH coefficient and channel (both scenes must
 * use the same band count). Albedo: PSNR with peak 1 of the albedo the camera sees (each scene's
 * objects rendered alone under unit radiance without shadows, so that a pixel shows its bilinear
 * texture lookup; pixels inside both outlines), which is what one view can determine: a 1024^2
 * texture seen at 256^2 has four texels per pixel, and no image says how a pixel's value splits
 * among them. Texel-space PSNR is reported too, over the texels with at least half a pixel of
 * bilinear weight in the view, and over constant albedos. The albedo PSNR is also reported over
 * the compared pixels that the target shows in shadow: m_p >= 0.25 with loss.c's shadow mask
 * m_p = clamp(1 - Y(T_p) / Y(U_p), 0, 1) of the run's target T against the ground truth rendered
 * without shadows U (its own lighting, albedo and pose), i.e. at least a quarter of the
 * unoccluded light missing. Those are the pixels whose darkness a model without shadows can only
 * explain by a darker albedo, so this is where a shadow-aware solver should gain; over the whole
 * view the lit pixels, which both solvers fit alike, dilute the difference. The threshold is
 * fixed up front (a quarter is well above the few percent by which the SH model and a ray-traced
 * target disagree on lit pixels). Pose: the geodesic angle between the rotations, computed from unit
 * quaternions in double as 2 atan2(|v|, |w|) of q q_true^-1, which stays accurate for small
 * angles where acos((tr R - 1) / 2) loses half its digits; the translation's Euclidean error;
 * the RMSE of the posed vertices, which weighs both by the object's extent. Multiple objects:
 * the albedo PSNR pools all texels, the pose errors are the largest over objects. Spheres (shape
 * from shadow): the volume IoU of the two unions of spheres in world space, counted on a 96^3
 * grid of cell centres over both bounding boxes (what the shadows constrain: the occluding
 * volume, not which sphere is which), the symmetric Chamfer distance of the centres, and the
 * IoU of the two sets' silhouettes seen from the light (projected along the truth's dominant
 * light direction onto the ground): one shadow fixes that silhouette but not where along the
 * light the occluder is, nor, with a soft light, much of its size. */
#include "optim/optim_internal.h"

#include "penumbra/render.h"
#include "sh/sh_internal.h"

#include <stdlib.h>
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

pen_status pen__optim_check_truth(pen_context *ctx, const pen_optim_task *t) {
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
        if ((t->optimize & PEN_OPTIM_ALBEDO) && o == 0 &&
            (sc->camera.width != gt->camera.width || sc->camera.height != gt->camera.height))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: ground_truth: camera: %dx%d, but the scene's is %dx%d (the "
                              "albedo metrics compare the two views pixel by pixel)",
                              name, gt->camera.width, gt->camera.height, sc->camera.width,
                              sc->camera.height);
        if ((t->optimize & (PEN_OPTIM_POSE | PEN_OPTIM_DEFORMATION)) &&
            a->mesh.vertex_count != b->mesh.vertex_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: ground_truth: objects[%d].mesh: %d vertices, but the scene's "
                              "mesh has %d",
                              name, o, b->mesh.vertex_count, a->mesh.vertex_count);
    }
    return PEN_OK;
}

/* Over the first `bands` bands. */
static double lighting_error(const pen_scene *sc, const pen_scene *gt, int bands) {
    double num = 0.0, den = 0.0;
    for (int k = 0; k < bands * bands; ++k)
        for (int ch = 0; ch < 3; ++ch) {
            const double d = (double)sc->lighting.sh[k][ch] - (double)gt->lighting.sh[k][ch];
            num += d * d;
            den += (double)gt->lighting.sh[k][ch] * (double)gt->lighting.sh[k][ch];
        }
    return den > 0.0 ? sqrt(num / den) : (num > 0.0 ? (double)INFINITY : 0.0);
}

/* The same for the radiance over the sky, the directions above the horizon (y > 0): the
 * integral of the squared error function over them, e^T M e with M = pen__sh_above(0) the
 * basis's Gram matrix on the upper hemisphere, relative to the truth's. The ground hides the
 * lower hemisphere from the scene, so no image of it determines the light from below. */
static double lighting_error_sky(const pen_scene *sc, const pen_scene *gt) {
    const int n = sc->sh_bands * sc->sh_bands;
    double M[PEN_SH_MAX_COEFFS * PEN_SH_MAX_COEFFS];
    pen__sh_above(sc->sh_bands, 0.0, M, NULL);
    double num = 0.0, den = 0.0;
    for (int ch = 0; ch < 3; ++ch)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k) {
                const double tj = gt->lighting.sh[j][ch], tk = gt->lighting.sh[k][ch];
                const double ej = (double)sc->lighting.sh[j][ch] - tj;
                const double ek = (double)sc->lighting.sh[k][ch] - tk;
                num += ej * M[j * n + k] * ek;
                den += tj * M[j * n + k] * tk;
            }
    return den > 0.0 ? sqrt(fmax(num, 0.0) / den) : (num > 0.0 ? (double)INFINITY : 0.0);
}

/* ---- Albedo ---------------------------------------------------------------------------------- */

/* A shallow copy of the scene that renders each pixel's albedo: objects alone (no ground, black
 * background) under radiance 1 from every direction without shadows, so that L_o = rho / pi * pi.
 * With `white` the objects' albedo is 1: the image is the objects' coverage. The caller frees
 * the returned objects array (NULL on exhaustion). */
static pen_object *albedo_view(pen_context *ctx, const pen_scene *sc, int white, pen_scene *out) {
    *out = *sc;
    pen_object *objects = pen__calloc(ctx, (size_t)sc->object_count + 1, sizeof *objects, "view");
    if (!objects) return NULL;
    for (int o = 0; o < sc->object_count; ++o) {
        objects[o] = sc->objects[o];
        if (white) {
            objects[o].texture.data = NULL;
            objects[o].albedo[0] = objects[o].albedo[1] = objects[o].albedo[2] = 1.0f;
        }
    }
    out->objects = objects;
    out->ground.enabled = 0;
    out->background_envmap = 0;
    memset(out->background, 0, sizeof out->background);
    memset(out->lighting.sh, 0, sizeof out->lighting.sh);
    for (int ch = 0; ch < 3; ++ch)
        out->lighting.sh[0][ch] = (float)sqrt(4.0 * PEN_PI); /* Y_00 = 1 / sqrt(4 pi) */
    return objects;
}

static pen_status render_albedo(pen_context *ctx, const pen_scene *sc, int white, pen_image *img) {
    pen_scene view;
    pen_object *objects = albedo_view(ctx, sc, white, &view);
    if (!objects) return PEN_ERROR_MEMORY;
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_status s = pen_render_fwd(ctx, &view, &opt, NULL, img);
    free(objects);
    return s;
}

/* A pixel is in shadow in the target when at least this fraction of the light the unshadowed
 * truth predicts is missing from it. */
#define SHADOWED 0.25f

static double psnr(double sum, long long n) {
    return n ? 10.0 * log10((double)n / sum) : (double)NAN; /* sum 0: +inf, written as null */
}

/* PSNR of the albedo images over the pixels that both scenes' objects cover fully; with a shadow
 * mask (one per pixel), also over those of them with mask >= SHADOWED, and their fraction. */
static pen_status albedo_view_psnr(pen_context *ctx, const pen_optim_task *t, const float *mask,
                                   pen_optim_metrics *m) {
    pen_image img[4];
    memset(img, 0, sizeof img);
    pen_status s = render_albedo(ctx, &t->scene, 0, &img[0]);
    if (!s) s = render_albedo(ctx, &t->ground_truth, 0, &img[1]);
    if (!s) s = render_albedo(ctx, &t->scene, 1, &img[2]);
    if (!s) s = render_albedo(ctx, &t->ground_truth, 1, &img[3]);
    if (!s) {
        double sum = 0.0, shadow_sum = 0.0;
        long long n = 0, shadow_n = 0;
        for (size_t i = 0; i < 3 * (size_t)img[0].width * (size_t)img[0].height; ++i) {
            if (img[2].data[i] < 0.999f || img[3].data[i] < 0.999f) continue;
            const double d = (double)img[0].data[i] - (double)img[1].data[i];
            sum += d * d;
            ++n;
            if (mask && mask[i / 3] >= SHADOWED) shadow_sum += d * d, ++shadow_n;
        }
        m->albedo_psnr_db = psnr(sum, n);
        if (mask) {
            m->albedo_shadow_psnr_db = psnr(shadow_sum, shadow_n);
            m->albedo_shadow_fraction = n ? (double)shadow_n / (double)n : (double)NAN;
        }
    }
    for (int k = 0; k < 4; ++k)
        pen_image_free(&img[k]);
    return s;
}

/* Per texel of object o's texture, its total bilinear weight over the pixels of the view: the
 * albedo gradient of the image sum in the albedo view (dI/drho = 1 at every unblended pixel). */
static pen_status texel_coverage(pen_context *ctx, const pen_scene *sc, pen_render_grad *grad) {
    pen_scene view;
    pen_object *objects = albedo_view(ctx, sc, 0, &view);
    if (!objects) return PEN_ERROR_MEMORY;
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_render_state *state = NULL;
    pen_image img = {0, 0, 0, NULL}, ones = {0, 0, 0, NULL};
    pen_status s = pen_render_state_create(ctx, &state);
    if (!s) s = pen_render_grad_create(ctx, &view, grad);
    if (!s) s = pen_render_fwd(ctx, &view, &opt, state, &img);
    if (!s) s = pen_image_create(ctx, img.width, img.height, 3, &ones);
    if (!s) {
        for (size_t i = 0; i < (size_t)img.width * (size_t)img.height; ++i)
            ones.data[3 * i] = 1.0f; /* channel 0 suffices */
        s = pen_render_bwd(ctx, &view, &opt, state, &ones, PEN_GRAD_ALBEDO, grad);
    }
    pen_image_free(&img);
    pen_image_free(&ones);
    pen_render_state_free(state);
    free(objects);
    return s;
}

/* Texel-space PSNR over the resolved texels (coverage >= 1/2 pixel), constants counted whole. */
static pen_status albedo_texels(pen_context *ctx, const pen_optim_task *t, pen_optim_metrics *m) {
    pen_render_grad cov;
    memset(&cov, 0, sizeof cov);
    pen_status s = texel_coverage(ctx, &t->scene, &cov);
    double sum = 0.0;
    long long values = 0, seen = 0, texels = 0;
    for (int o = 0; !s && o < t->scene.object_count; ++o) {
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
        texels += n;
        for (long long i = 0; i < n; ++i) {
            if (!(cov.objects[o].texture[i * ch] >= 0.5f)) continue;
            ++seen;
            for (int c = 0; c < ch; ++c) {
                const double d = (double)a->texture.data[i * ch + c] -
                                 (double)b->texture.data[i * ch + c];
                sum += d * d;
            }
            values += ch;
        }
    }
    if (!s) {
        m->albedo_observed = texels ? (double)seen / (double)texels : (double)NAN;
        m->albedo_texel_psnr_db = psnr(sum, values);
    }
    pen_render_grad_free(&cov);
    return s;
}

/* ---- Pose ------------------------------------------------------------------------------------ */

/* The diagonal of the true object's posed bounding box: "the object's size". */
static double object_size(const pen_object *ob) {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int v = 0; v < ob->mesh.vertex_count; ++v) {
        float p[3];
        pen_pose_apply(&ob->pose, ob->mesh.positions + 3 * v, p);
        for (int k = 0; k < 3; ++k)
            lo[k] = fmin(lo[k], (double)p[k]), hi[k] = fmax(hi[k], (double)p[k]);
    }
    double d2 = 0.0;
    for (int k = 0; k < 3; ++k)
        d2 += ob->mesh.vertex_count ? (hi[k] - lo[k]) * (hi[k] - lo[k]) : 0.0;
    return sqrt(d2);
}

static void pose_error(const pen_optim_task *t, pen_optim_metrics *m) {
    double rot = 0.0, trans = 0.0, rel = 0.0, sq = 0.0;
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
        const double size = object_size(b);
        rel = fmax(rel, size > 0.0 ? sqrt(d2) / size : (double)NAN);
        for (int v = 0; v < a->mesh.vertex_count; ++v) {
            float pa[3], pb[3];
            pen_pose_apply(&a->pose, a->mesh.positions + 3 * v, pa);
            pen_pose_apply(&b->pose, b->mesh.positions + 3 * v, pb);
            for (int k = 0; k < 3; ++k)
                sq += ((double)pa[k] - (double)pb[k]) * ((double)pa[k] - (double)pb[k]);
            ++n;
        }
    }
    if (t->optimize & PEN_OPTIM_POSE) {
        m->rotation_error_deg = rot;
        m->translation_error = trans;
        m->translation_error_rel = rel;
    }
    m->vertex_rmse = n ? sqrt(sq / (double)n) : (double)NAN;
}

/* ---- Spheres --------------------------------------------------------------------------------- */

/* Every object's spheres in world space (x, y, z, r), malloc'd; *count receives their number. */
static double *world_spheres(pen_context *ctx, const pen_scene *sc, int *count) {
    int n = 0;
    for (int o = 0; o < sc->object_count; ++o)
        n += sc->objects[o].spheres.count;
    double *out = pen__malloc(ctx, 4 * (size_t)n + 1, sizeof(double), "sphere metrics");
    if (!out) return NULL;
    int k = 0;
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        for (int j = 0; j < ob->spheres.count; ++j, ++k) {
            float c[3];
            pen_pose_apply(&ob->pose, ob->spheres.data + 4 * j, c);
            for (int a = 0; a < 3; ++a)
                out[4 * k + a] = c[a];
            out[4 * k + 3] = (double)ob->pose.scale * (double)ob->spheres.data[4 * j + 3];
        }
    }
    *count = n;
    return out;
}

static int inside(const double *sp, int n, const double p[3]) {
    for (int j = 0; j < n; ++j) {
        const double *q = sp + 4 * j;
        const double x = p[0] - q[0], y = p[1] - q[1], z = p[2] - q[2];
        if (x * x + y * y + z * z <= q[3] * q[3]) return 1;
    }
    return 0;
}

/* Mean over a's centres of the distance to the nearest centre of b. */
static double mean_nearest(const double *a, int na, const double *b, int nb) {
    double sum = 0.0;
    for (int i = 0; i < na; ++i) {
        double best = (double)INFINITY;
        for (int j = 0; j < nb; ++j) {
            const double x = a[4 * i] - b[4 * j], y = a[4 * i + 1] - b[4 * j + 1],
                         z = a[4 * i + 2] - b[4 * j + 2];
            best = fmin(best, x * x + y * y + z * z);
        }
        sum += sqrt(best);
    }
    return sum / na;
}

#define IOU_GRID 96
#define SHADOW_GRID 256

/* The direction the light mostly comes from: the dipole of the truth's SH lighting (band 1,
 * luminance), Y_1,-1 = -c y, Y_1,0 = c z, Y_1,1 = -c x; straight down when it has no dipole or
 * the dipole points below the horizon. */
static void light_direction(const pen_scene *gt, double d[3]) {
    d[0] = d[1] = d[2] = 0.0;
    if (gt->sh_bands >= 2)
        for (int ch = 0; ch < 3; ++ch) {
            d[0] -= (double)gt->lighting.sh[3][ch];
            d[1] -= (double)gt->lighting.sh[1][ch];
            d[2] += (double)gt->lighting.sh[2][ch];
        }
    const double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(n > 0.0) || d[1] <= 0.05 * n) {
        d[0] = d[2] = 0.0, d[1] = 1.0;
        return;
    }
    d[0] /= n, d[1] /= n, d[2] /= n;
}

/* 1 if the line through ground point g along d meets one of the n spheres. */
static int shades(const double *sp, int n, const double g[3], const double d[3]) {
    for (int j = 0; j < n; ++j) {
        const double *q = sp + 4 * j;
        const double v[3] = {q[0] - g[0], q[1] - g[1], q[2] - g[2]};
        const double along = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
        if (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - along * along <= q[3] * q[3]) return 1;
    }
    return 0;
}

/* IoU of the two sphere sets' silhouettes seen from the light: their projections along the
 * light direction onto the ground plane (what a sharp shadow of them would cover). */
static double shadow_iou(const double *a, int na, const double *b, int nb, const pen_scene *gt) {
    double d[3];
    light_direction(gt, d);
    const double h = gt->ground.enabled ? (double)gt->ground.height : 0.0;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int k = 0; k < na + nb; ++k) {
        const double *q = k < na ? a + 4 * k : b + 4 * (k - na);
        const double t = (q[1] - h) / d[1], reach = q[3] / d[1]; /* the ellipse's half axes */
        const double g[2] = {q[0] - t * d[0], q[2] - t * d[2]};
        for (int c = 0; c < 2; ++c) {
            lo[c] = fmin(lo[c], g[c] - reach);
            hi[c] = fmax(hi[c], g[c] + reach);
        }
    }
    long long both = 0, either = 0;
    for (int z = 0; z < SHADOW_GRID; ++z)
        for (int x = 0; x < SHADOW_GRID; ++x) {
            const double g[3] = {lo[0] + (hi[0] - lo[0]) * (x + 0.5) / SHADOW_GRID, h,
                                 lo[1] + (hi[1] - lo[1]) * (z + 0.5) / SHADOW_GRID};
            const int ia = shades(a, na, g, d), ib = shades(b, nb, g, d);
            both += ia && ib;
            either += ia || ib;
        }
    return either ? (double)both / (double)either : (double)NAN;
}

/* Volume IoU of the two unions of spheres (cell centres of a grid over both bounding boxes), the
 * symmetric Chamfer distance of their centres and the IoU of their silhouettes from the light. */
static pen_status sphere_error(pen_context *ctx, const pen_optim_task *t, pen_optim_metrics *m) {
    int na = 0, nb = 0;
    double *a = world_spheres(ctx, &t->scene, &na), *b = world_spheres(ctx, &t->ground_truth, &nb);
    if (!a || !b) {
        free(a);
        free(b);
        return PEN_ERROR_MEMORY;
    }
    if (na > 0 && nb > 0) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (int k = 0; k < na + nb; ++k) {
            const double *q = k < na ? a + 4 * k : b + 4 * (k - na);
            for (int c = 0; c < 3; ++c) {
                lo[c] = fmin(lo[c], q[c] - q[3]);
                hi[c] = fmax(hi[c], q[c] + q[3]);
            }
        }
        long long both = 0, either = 0;
        for (int z = 0; z < IOU_GRID; ++z)
            for (int y = 0; y < IOU_GRID; ++y)
                for (int x = 0; x < IOU_GRID; ++x) {
                    const int g[3] = {x, y, z};
                    double p[3];
                    for (int c = 0; c < 3; ++c)
                        p[c] = lo[c] + (hi[c] - lo[c]) * (g[c] + 0.5) / IOU_GRID;
                    const int ia = inside(a, na, p), ib = inside(b, nb, p);
                    both += ia && ib;
                    either += ia || ib;
                }
        m->sphere_iou = either ? (double)both / (double)either : (double)NAN;
        m->sphere_chamfer = 0.5 * (mean_nearest(a, na, b, nb) + mean_nearest(b, nb, a, na));
        m->shadow_iou = shadow_iou(a, na, b, nb, &t->ground_truth);
    }
    free(a);
    free(b);
    return PEN_OK;
}

/* The largest over the scene's lights of the angle (degrees, in double) to the nearest of the
 * truth's: each recovered light is matched with the true light it is closest to. */
static double light_direction_error(const pen_scene *sc, const pen_scene *gt) {
    double worst = 0.0;
    for (int i = 0; i < sc->lighting.light_count; ++i) {
        const float *af = sc->lighting.lights[i].direction;
        const double a[3] = {af[0], af[1], af[2]};
        double nearest = 180.0;
        for (int j = 0; j < gt->lighting.light_count; ++j) {
            const float *bf = gt->lighting.lights[j].direction;
            const double b[3] = {bf[0], bf[1], bf[2]};
            const double cr[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                                  a[0] * b[1] - a[1] * b[0]};
            const double d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            /* atan2 of |a x b| and a.b: accurate at small angles, where acos is not */
            const double ang =
                atan2(sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]), d) * 180.0 / PEN_PI;
            nearest = fmin(nearest, ang);
        }
        worst = fmax(worst, nearest);
    }
    return worst;
}

pen_status pen__optim_metrics(pen_context *ctx, const pen_optim_task *t, pen_optim_metrics *m) {
    if (!t->has_ground_truth) return PEN_OK;
    pen_status s = pen__optim_check_truth(ctx, t);
    if (s) return s;
    if (t->optimize & PEN_OPTIM_LIGHTING) {
        m->lighting_rel_error = lighting_error(&t->scene, &t->ground_truth, t->scene.sh_bands);
        if (t->scene.sh_bands > 3)
            m->lighting_rel_error_b2 = lighting_error(&t->scene, &t->ground_truth, 3);
        m->lighting_rel_error_sky = lighting_error_sky(&t->scene, &t->ground_truth);
    }
    if ((t->optimize & PEN_OPTIM_LIGHTS) && t->scene.lighting.light_count > 0 &&
        t->ground_truth.lighting.light_count > 0)
        m->light_direction_error_deg = light_direction_error(&t->scene, &t->ground_truth);
    if (t->optimize & (PEN_OPTIM_POSE | PEN_OPTIM_DEFORMATION)) pose_error(t, m);
    if (t->optimize & PEN_OPTIM_SPHERES) s = sphere_error(ctx, t, m);
    if (s) return s;
    if (t->optimize & PEN_OPTIM_ALBEDO) {
        /* The shadow mask of the target against the unshadowed truth, when there is a target of
         * the view's size (the run's always is; a caller may evaluate a scene without one). */
        const pen_image *tg = &t->target;
        const int has_target = tg->data && tg->channels == 3 &&
                               tg->width == t->ground_truth.camera.width &&
                               tg->height == t->ground_truth.camera.height;
        float *mask = has_target ? pen__malloc(ctx, (size_t)tg->width * (size_t)tg->height,
                                               sizeof(float), "shadow mask")
                                 : NULL;
        if (has_target && !mask) return PEN_ERROR_MEMORY;
        if (mask) s = pen__optim_shadow_mask(ctx, &t->ground_truth, tg, 0, mask);
        if (!s) s = albedo_view_psnr(ctx, t, mask, m);
        if (!s) s = albedo_texels(ctx, t, m);
        free(mask);
    }
    return s;
}
