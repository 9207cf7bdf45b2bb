/* The prepared pinhole camera (pen_view): the world -> screen projection with its Jacobian, and
 * pixel rays. The camera's frame and intrinsics are the model's (src/scene/camera.c):
 *
 * The camera looks from eye towards target. Its frame is right = normalize(forward x up),
 * true up = right x forward, so (right, up, -forward) is a right-handed basis. With
 * d = p - eye and depth z = d.forward, a point projects to
 *     sx = cx + fx (d.right) / z,   sy = cy - fy (d.up) / z,
 * with fx = fy = H / (2 tan(fov_y / 2)) and (cx, cy) = (W/2, H/2) for a look-at camera (square
 * pixels; the horizontal field of view follows from the aspect W/H), or a calibrated camera's
 * own fx, fy, cx, cy. Row 0 is the top and pixel centres sit at +0.5. The ray through image
 * point (px, py) is eye + z * (rx right + ry up + forward) with rx = (px - cx)/fx,
 * ry = (cy - py)/fy, so a ray's parameter is the view depth itself. Everything is computed in double; the float
 * entry points convert at the boundary.
 */
#include "scene/camera.h"
#include "core/internal.h"
#include "raster/raster_internal.h"

#include <math.h>

/* ---- View ------------------------------------------------------------------------------------ */

static void view_setup(const pen_camera *cam, pen_view *view) {
    view->width = cam->width;
    view->height = cam->height;
    pen__load3_d(cam->eye, view->eye);
    pen__camera_frame_d(cam, view->right, view->up, view->forward);
    pen__camera_intrinsics_d(cam, view->focal, &view->cx, &view->cy);
    double d[3];
    pen__load3_d(cam->target, d);
    pen__sub_d(d, view->eye, d);
    double dist = sqrt(pen__dot_d(d, d));
    view->near_plane = dist > 0.0 && isfinite(dist) ? 1e-3 * dist : 1e-3;
}

pen_status pen_view_init(pen_context *ctx, const pen_camera *cam, pen_view *view) {
    if (!cam || !view) return pen__error(ctx, PEN_ERROR_ARGUMENT, "pen_view_init: NULL argument");
    pen_status s = pen_camera_validate(ctx, cam);
    if (s) return s;
    view_setup(cam, view);
    return PEN_OK;
}

void pen_view_ray(const pen_view *view, double px, double py, double dir[3]) {
    pen__camera_ray_d(view->right, view->up, view->forward, view->focal, view->cx, view->cy, px, py,
                      dir);
}

/* ---- Projection: forward and backward ------------------------------------------------------- */

void pen__raster_project_d(const pen_view *view, const double p[3], double s[3], double J[9]) {
    double d[3];
    pen__sub_d(p, view->eye, d);
    double x = pen__dot_d(d, view->right), y = pen__dot_d(d, view->up);
    double z = pen__dot_d(d, view->forward);
    double iz = 1.0 / z, fx = view->focal[0], fy = view->focal[1];
    s[0] = view->cx + fx * x * iz;
    s[1] = view->cy - fy * y * iz;
    s[2] = z;
    if (!J) return;
    /* d(x/z)/dp = (right - (x/z) forward) / z, likewise for y. */
    for (int i = 0; i < 3; ++i) {
        J[i] = fx * iz * (view->right[i] - x * iz * view->forward[i]);
        J[3 + i] = -fy * iz * (view->up[i] - y * iz * view->forward[i]);
        J[6 + i] = view->forward[i];
    }
}

void pen_view_project_fwd(const pen_view *view, const float p[3], float s[3]) {
    double pd[3], sd[3];
    pen__load3_d(p, pd);
    pen__raster_project_d(view, pd, sd, NULL);
    s[0] = (float)sd[0], s[1] = (float)sd[1], s[2] = (float)sd[2];
}

void pen_view_project_bwd(const pen_view *view, const float p[3], const float d_s[3],
                          float d_p[3]) {
    if (!d_p) return;
    double pd[3], sd[3], J[9];
    pen__load3_d(p, pd);
    pen__raster_project_d(view, pd, sd, J);
    for (int i = 0; i < 3; ++i)
        d_p[i] +=
            (float)(J[i] * (double)d_s[0] + J[3 + i] * (double)d_s[1] + J[6 + i] * (double)d_s[2]);
}
