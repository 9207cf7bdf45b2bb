/* Equirectangular environment maps: the direction of each pixel, radiance lookup, and the
 * projection onto spherical harmonics.
 *
 * Convention (Y up, right-handed): u in [0, 1) is the azimuth phi = 2 pi u, v in [0, 1] the
 * polar angle theta = pi v from +Y, and
 *     dir(u, v) = (-sin(theta) sin(phi), cos(theta), sin(theta) cos(phi)),
 * so row 0 is the zenith, the middle row the horizon, the image centre (u = 1/2) looks along -Z
 * (the direction a default camera looks), u = 3/4 is +X and u = 1/4 is -X: standing at the
 * origin looking at -Z, the map appears as it does in an image viewer, not mirrored.
 *
 * Rotation by rotation_y_deg = a (right-handed about +Y) carries the map's direction d to the
 * world direction R_y(a) d, with R_y(a) (x, y, z) = (cos a x + sin a z, y, -sin a x + cos a z).
 *
 * Projection: L_i = sum over pixels of L(pixel) Y_i(R_y(a) dir(pixel centre)) dOmega(pixel),
 * where dOmega is the exact solid angle of the pixel's cell, (2 pi / W) (cos theta_top -
 * cos theta_bottom) (the brief's sin(theta) dtheta dphi, integrated over the cell). The weights
 * sum to 4 pi exactly, so a constant map c gives L_0 = sqrt(4 pi) c to rounding; the other
 * coefficients of a constant map are the error of sampling each cell at its centre, O(l^2 / H^2)
 * (the SH basis has its pole on z, the map on y, so no discrete orthogonality makes them vanish
 * exactly; at H = 64 they stay below 1e-3 of L_0 up to l = 7). Negative pixels (the
 * small undershoots of lossy EXR codecs) are clamped to 0 before projecting, as in lookups. The
 * sums run in double, row by row, in a fixed order (deterministic). */
#include "core/internal.h"
#include "penumbra/envmap.h"
#include "penumbra/sh.h"

#include <stdlib.h>
#include <string.h>

void pen_envmap_direction(float u, float v, float dir[3]) {
    double theta = PEN_PI * (double)v, phi = 2.0 * PEN_PI * (double)u;
    double st = sin(theta);
    dir[0] = (float)(-st * sin(phi));
    dir[1] = (float)cos(theta);
    dir[2] = (float)(st * cos(phi));
}

void pen_envmap_uv(const float dir[3], float *u, float *v) {
    double x = dir[0], y = dir[1], z = dir[2];
    double n = sqrt(x * x + y * y + z * z);
    if (!(n > 0.0)) {
        *u = 0.0f;
        *v = 0.0f;
        return;
    }
    double ct = y / n;
    ct = ct < -1.0 ? -1.0 : ct > 1.0 ? 1.0 : ct;
    double phi = atan2(-x, z); /* (-pi, pi] */
    double uu = phi / (2.0 * PEN_PI);
    if (uu < 0.0) uu += 1.0;
    float fu = (float)uu;
    *u = fu >= 1.0f ? 0.0f : fu;
    *v = (float)(acos(ct) / PEN_PI);
}

/* Rotation about +Y by angle a (radians), applied to d. */
static void rotate_y(double c, double s, const double d[3], double out[3]) {
    out[0] = c * d[0] + s * d[2];
    out[1] = d[1];
    out[2] = -s * d[0] + c * d[2];
}

static pen_status check_envmap(pen_context *ctx, const pen_image *env) {
    if (!env || !env->data || env->width < 1 || env->height < 1 ||
        (env->channels != 1 && env->channels < 3))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "environment map: expected a non-empty 1- or 3-channel image");
    return PEN_OK;
}

/* The clamped radiance of texel (x, y), channel c (grey maps repeat their channel). */
static double texel(const pen_image *env, int x, int y, int c) {
    size_t i = ((size_t)y * (size_t)env->width + (size_t)x) * (size_t)env->channels;
    double v = env->data[i + (env->channels == 1 ? 0 : (size_t)c)];
    return v > 0.0 ? v : 0.0;
}

pen_status pen_envmap_to_sh(pen_context *ctx, const pen_image *env, int bands, float rotation_y_deg,
                            float scale, float sh[][3]) {
    pen_status s = check_envmap(ctx, env);
    if (s) return s;
    if (bands < 1 || bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "environment map: bands %d outside [1, %d]",
                          bands, PEN_SH_MAX_BANDS);
    if (!isfinite(rotation_y_deg) || !isfinite(scale) || scale < 0.0f)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "environment map: rotation must be finite and scale finite and >= 0");
    const int W = env->width, H = env->height, n = bands * bands;
    /* Clamping would turn NaN into 0 silently: refuse non-finite maps first. */
    for (size_t i = 0; i < (size_t)W * (size_t)H * (size_t)env->channels; ++i) {
        if (!isfinite(env->data[i])) {
            size_t p = i / (size_t)env->channels;
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "environment map: pixel (%zu, %zu) is not finite", p % (size_t)W,
                              p / (size_t)W);
        }
    }
    double acc[PEN_SH_MAX_COEFFS][3];
    memset(acc, 0, sizeof acc);
    const double a = (double)rotation_y_deg * PEN_PI / 180.0, ca = cos(a), sa = sin(a);
    const double dphi = 2.0 * PEN_PI / W;
    double y[PEN_SH_MAX_COEFFS];
    for (int row = 0; row < H; ++row) {
        double t0 = PEN_PI * row / H, t1 = PEN_PI * (row + 1) / H;
        double weight = dphi * (cos(t0) - cos(t1));
        double theta = 0.5 * (t0 + t1), st = sin(theta), ct = cos(theta);
        double row_acc[PEN_SH_MAX_COEFFS][3];
        memset(row_acc, 0, sizeof row_acc);
        for (int col = 0; col < W; ++col) {
            double phi = dphi * (col + 0.5);
            double d[3] = {-st * sin(phi), ct, st * cos(phi)}, wd[3];
            rotate_y(ca, sa, d, wd);
            pen_sh_eval_d(bands, wd, y);
            double L[3] = {texel(env, col, row, 0), texel(env, col, row, 1),
                           texel(env, col, row, 2)};
            for (int i = 0; i < n; ++i)
                for (int c = 0; c < 3; ++c)
                    row_acc[i][c] += L[c] * y[i];
        }
        for (int i = 0; i < n; ++i)
            for (int c = 0; c < 3; ++c)
                acc[i][c] += weight * row_acc[i][c];
    }
    for (int i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c)
            sh[i][c] = (float)((double)scale * acc[i][c]);
    return PEN_OK;
}

void pen_envmap_eval(const pen_image *env, float rotation_y_deg, float scale, const float dir[3],
                     float rgb[3]) {
    if (check_envmap(NULL, env) != PEN_OK) {
        rgb[0] = rgb[1] = rgb[2] = 0.0f;
        return;
    }
    /* World direction to map direction: the inverse rotation R_y(-a). */
    const double a = (double)rotation_y_deg * PEN_PI / 180.0;
    double w[3] = {dir[0], dir[1], dir[2]}, d[3];
    rotate_y(cos(a), -sin(a), w, d);
    float md[3] = {(float)d[0], (float)d[1], (float)d[2]}, u, v;
    pen_envmap_uv(md, &u, &v);
    /* Bilinear between texel centres (x + 0.5) / W: wraps in u, clamps in v. */
    const int W = env->width, H = env->height;
    double fx = (double)u * W - 0.5, fy = (double)v * H - 0.5;
    double x0f = floor(fx), y0f = floor(fy);
    double tx = fx - x0f, ty = fy - y0f;
    int x0 = ((int)x0f % W + W) % W, x1 = (x0 + 1) % W;
    int y0 = (int)y0f, y1 = y0 + 1;
    y0 = y0 < 0 ? 0 : y0 >= H ? H - 1 : y0;
    y1 = y1 < 0 ? 0 : y1 >= H ? H - 1 : y1;
    for (int c = 0; c < 3; ++c) {
        double top = (1 - tx) * texel(env, x0, y0, c) + tx * texel(env, x1, y0, c);
        double bottom = (1 - tx) * texel(env, x0, y1, c) + tx * texel(env, x1, y1, c);
        rgb[c] = (float)((double)scale * ((1 - ty) * top + ty * bottom));
    }
}
