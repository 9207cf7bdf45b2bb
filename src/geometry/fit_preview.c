/* A picture of a sphere set over its mesh, for the docs and for looking at a fit: three square
 * orthographic panels side by side -- the mesh, the spheres, and the spheres blended over the
 * mesh. Not the renderer: flat-shaded triangles in a z-buffer and analytic ray-sphere hits, one
 * fixed directional light, no shadows. The view frames the union of the mesh's and the spheres'
 * bounds, so a sphere that strays out of the mesh is seen.
 */
#include "core/vec.h"
#include "geometry/fit_internal.h"

#include "penumbra/image.h"

#include <stdlib.h>
#include <string.h>

typedef struct view {
    double right[3], up[3], fwd[3]; /* orthonormal; the camera looks along fwd */
    double centre[3], scale;        /* world units per pixel */
    int size;
} view;

/* World point to (pixel x, pixel y, depth along fwd). */
static void project(const view *v, const double *p, double *px, double *py, double *depth) {
    double d[3] = {p[0] - v->centre[0], p[1] - v->centre[1], p[2] - v->centre[2]};
    *px = 0.5 * v->size + pen__dot_d(d, v->right) / v->scale;
    *py = 0.5 * v->size - pen__dot_d(d, v->up) / v->scale;
    *depth = pen__dot_d(d, v->fwd);
}

static double shade(const double *n, const double *light) {
    return 0.25 + 0.75 * fmax(0, pen__dot_d(n, light));
}

/* Mesh panel: per-pixel depth (INFINITY where empty) and grey level. */
static void raster_mesh(const view *v, const pen_mesh *m, const double *light, double *depth,
                        double *grey) {
    int S = v->size;
    for (int t = 0; t < m->triangle_count; ++t) {
        double p[3][3], sx[3], sy[3], sz[3];
        for (int k = 0; k < 3; ++k) {
            for (int a = 0; a < 3; ++a)
                p[k][a] = (double)m->positions[3 * (size_t)m->indices[3 * t + k] + a];
            project(v, p[k], sx + k, sy + k, sz + k);
        }
        double e1[3], e2[3], n[3];
        for (int a = 0; a < 3; ++a)
            e1[a] = p[1][a] - p[0][a], e2[a] = p[2][a] - p[0][a];
        n[0] = e1[1] * e2[2] - e1[2] * e2[1];
        n[1] = e1[2] * e2[0] - e1[0] * e2[2];
        n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        double len = sqrt(pen__dot_d(n, n));
        if (!(len > 0)) continue;
        for (int a = 0; a < 3; ++a)
            n[a] /= len;
        if (pen__dot_d(n, v->fwd) > 0)
            for (int a = 0; a < 3; ++a)
                n[a] = -n[a]; /* light the side we see */
        double area = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sx[2] - sx[0]) * (sy[1] - sy[0]);
        if (area == 0) continue;
        int x0 = (int)fmax(0, floor(fmin(sx[0], fmin(sx[1], sx[2]))));
        int x1 = (int)fmin(S - 1, ceil(fmax(sx[0], fmax(sx[1], sx[2]))));
        int y0 = (int)fmax(0, floor(fmin(sy[0], fmin(sy[1], sy[2]))));
        int y1 = (int)fmin(S - 1, ceil(fmax(sy[0], fmax(sy[1], sy[2]))));
        double g = shade(n, light);
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                double cx = x + 0.5, cy = y + 0.5;
                double w0 = ((sx[1] - cx) * (sy[2] - cy) - (sx[2] - cx) * (sy[1] - cy)) / area;
                double w1 = ((sx[2] - cx) * (sy[0] - cy) - (sx[0] - cx) * (sy[2] - cy)) / area;
                double w2 = 1 - w0 - w1;
                if (w0 < 0 || w1 < 0 || w2 < 0) continue;
                double z = w0 * sz[0] + w1 * sz[1] + w2 * sz[2];
                size_t i = (size_t)y * S + x;
                if (z < depth[i]) depth[i] = z, grey[i] = g;
            }
    }
}

/* A distinct, fairly saturated colour per sphere: golden-ratio hue steps, HSV with s = 0.7 and
 * v = 0.95 (channel n = 5, 3, 1 for r, g, b: v - v s clamp(min(k, 4 - k), 0, 1), k = n + 6 hue). */
static void sphere_colour(int i, double *rgb) {
    double hue = fmod(0.13 + 0.618034 * i, 1.0);
    for (int c = 0; c < 3; ++c) {
        double k = fmod(5 - 2 * c + 6 * hue, 6);
        rgb[c] = 0.95 * (1 - 0.7 * fmax(0, fmin(1, fmin(k, 4 - k))));
    }
}

/* Nearest sphere hit of the pixel's ray: returns the sphere index or -1, with depth and shade. */
static int trace_spheres(const view *v, const pen_spheres *s, double px, double py,
                         const double *light, double *depth, double *g) {
    double o[3];
    double dx = (px - 0.5 * v->size) * v->scale, dy = (0.5 * v->size - py) * v->scale;
    for (int a = 0; a < 3; ++a)
        o[a] = v->centre[a] + dx * v->right[a] + dy * v->up[a];
    int best = -1;
    *depth = (double)INFINITY;
    for (int i = 0; i < s->count; ++i) {
        const float *sp = s->data + 4 * (size_t)i;
        double c[3] = {(double)sp[0] - o[0], (double)sp[1] - o[1], (double)sp[2] - o[2]};
        double t = pen__dot_d(c, v->fwd), r = sp[3];
        double q = pen__dot_d(c, c) - t * t;
        if (q > r * r) continue;
        double hit = t - sqrt(r * r - q);
        if (hit < *depth) {
            *depth = hit, best = i;
            double n[3];
            for (int a = 0; a < 3; ++a)
                n[a] = (hit * v->fwd[a] - c[a]) / r;
            *g = shade(n, light);
        }
    }
    return best;
}

pen_status pen_spheres_preview(pen_context *ctx, const pen_mesh *mesh, const pen_spheres *spheres,
                               float azimuth_deg, float elevation_deg, int size, pen_image *out) {
    if (out) memset(out, 0, sizeof *out);
    float lo[3], hi[3];
    pen_status st = pen__fit_check_mesh(ctx, mesh, lo, hi);
    if (st) return st;
    if (!out || !spheres || (spheres->count > 0 && !spheres->data) || spheres->count < 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "preview: no sphere set or output");
    if (size < 16 || size > 4096 || !isfinite(azimuth_deg) || !isfinite(elevation_deg))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "preview: size %d out of range [16, 4096]",
                          size);
    double blo[3], bhi[3];
    for (int a = 0; a < 3; ++a)
        blo[a] = (double)lo[a], bhi[a] = (double)hi[a];
    for (int i = 0; i < spheres->count; ++i) {
        const float *s = spheres->data + 4 * (size_t)i;
        if (!pen__finite3(s) || !(s[3] >= 0) || !isfinite(s[3]))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "preview: sphere %d is not finite", i);
        for (int a = 0; a < 3; ++a)
            blo[a] = fmin(blo[a], (double)(s[a] - s[3])),
            bhi[a] = fmax(bhi[a], (double)(s[a] + s[3]));
    }
    view v;
    v.size = size;
    double az = (double)azimuth_deg * PEN_PI / 180, el = (double)elevation_deg * PEN_PI / 180;
    /* The camera sits at azimuth az about +y (0 = on +z) and elevation el, looking back. */
    v.fwd[0] = -cos(el) * sin(az), v.fwd[1] = -sin(el), v.fwd[2] = -cos(el) * cos(az);
    v.right[0] = cos(az), v.right[1] = 0, v.right[2] = -sin(az);
    v.up[0] = v.right[1] * v.fwd[2] - v.right[2] * v.fwd[1];
    v.up[1] = v.right[2] * v.fwd[0] - v.right[0] * v.fwd[2];
    v.up[2] = v.right[0] * v.fwd[1] - v.right[1] * v.fwd[0];
    double radius = 0;
    for (int a = 0; a < 3; ++a) {
        v.centre[a] = 0.5 * (blo[a] + bhi[a]);
        radius += 0.25 * (bhi[a] - blo[a]) * (bhi[a] - blo[a]);
    }
    v.scale = 2.1 * sqrt(radius) / size;
    double light[3] = {0.5 * v.right[0] + 0.7 * v.up[0] - 0.5 * v.fwd[0],
                       0.5 * v.right[1] + 0.7 * v.up[1] - 0.5 * v.fwd[1],
                       0.5 * v.right[2] + 0.7 * v.up[2] - 0.5 * v.fwd[2]};
    double ll = sqrt(pen__dot_d(light, light));
    for (int a = 0; a < 3; ++a)
        light[a] /= ll;

    size_t pixels = (size_t)size * size;
    double *depth = pen__malloc(ctx, pixels, sizeof(double), "preview: depth");
    double *grey = pen__malloc(ctx, pixels, sizeof(double), "preview: shade");
    if (!depth || !grey) {
        free(depth), free(grey);
        return PEN_ERROR_MEMORY;
    }
    st = pen_image_create(ctx, 3 * size, size, 3, out);
    if (st) {
        free(depth), free(grey);
        return st;
    }
    float *img = out->data;
    for (size_t i = 0; i < pixels; ++i)
        depth[i] = (double)INFINITY, grey[i] = 0;
    raster_mesh(&v, mesh, light, depth, grey);
    const double bg = 1.0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            size_t i = (size_t)y * size + x;
            double sd, sg = 0, rgb[3] = {bg, bg, bg};
            int si = trace_spheres(&v, spheres, x + 0.5, y + 0.5, light, &sd, &sg);
            double m = depth[i] < (double)INFINITY ? grey[i] * 0.8 : bg;
            double col[3] = {m, m, m}, sph[3] = {bg, bg, bg}, over[3] = {m, m, m};
            if (si >= 0) {
                sphere_colour(si, rgb);
                for (int a = 0; a < 3; ++a) {
                    sph[a] = rgb[a] * sg;
                    over[a] = 0.55 * sph[a] + 0.45 * m;
                }
            }
            for (int a = 0; a < 3; ++a) {
                float *row = img + 3 * ((size_t)y * 3 * size);
                row[3 * x + a] = (float)col[a];
                row[3 * (size + x) + a] = (float)sph[a];
                row[3 * (2 * size + x) + a] = (float)over[a];
            }
        }
    free(depth), free(grey);
    return PEN_OK;
}
