/* Pinhole camera: frame, rays, and the world -> screen projection with its Jacobian.
 *
 * The camera looks from eye towards target. Its frame is right = normalize(forward x up),
 * true up = right x forward, so (right, up, -forward) is a right-handed basis. With
 * d = p - eye and depth z = d.forward, a point projects to
 *     sx = cx + f (d.right) / z,   sy = cy - f (d.up) / z,     f = H / (2 tan(fov_y / 2)),
 * with (cx, cy) = (W/2, H/2): row 0 is the top, pixel centres sit at +0.5, and pixels are square
 * (the horizontal field of view follows from the aspect W/H). The ray through image point
 * (px, py) is eye + z * (rx right + ry up + forward) with rx = (px - cx)/f, ry = (cy - py)/f, so
 * a ray's parameter is the view depth itself. Everything is computed in double; the float
 * entry points convert at the boundary.
 */
#include "core/internal.h"
#include "raster/raster_internal.h"

#include <math.h>

/* ---- Frame ----------------------------------------------------------------------------------- */

static void normalize_d(double v[3]) {
    double n = sqrt(pen__dot_d(v, v));
    v[0] /= n, v[1] /= n, v[2] /= n;
}

/* Orthonormal frame of a camera without failing: a degenerate forward falls back to -Z, an up
 * vector parallel to forward to the world axis least aligned with forward. */
static void camera_frame_d(const pen_camera *cam, double right[3], double up[3], double fwd[3]) {
    double f[3] = {(double)cam->target[0] - (double)cam->eye[0],
                   (double)cam->target[1] - (double)cam->eye[1],
                   (double)cam->target[2] - (double)cam->eye[2]};
    double fl = sqrt(pen__dot_d(f, f));
    if (!(fl > 0.0) || !isfinite(fl)) f[0] = 0.0, f[1] = 0.0, f[2] = -1.0, fl = 1.0;
    f[0] /= fl, f[1] /= fl, f[2] /= fl;
    double u[3];
    pen__load3_d(cam->up, u);
    double r[3];
    pen__cross_d(f, u, r);
    double ul = sqrt(pen__dot_d(u, u));
    double rl = sqrt(pen__dot_d(r, r));
    if (!(rl > 1e-6 * ul) || !isfinite(rl)) {
        /* up is zero, non-finite or parallel to the view direction: pick the axis with the
         * smallest component along f, which is at least ~0.8 away from parallel. */
        int k = 0;
        for (int i = 1; i < 3; ++i)
            if (fabs(f[i]) < fabs(f[k])) k = i;
        u[0] = u[1] = u[2] = 0.0;
        u[k] = 1.0;
        pen__cross_d(f, u, r);
    }
    normalize_d(r);
    pen__cross_d(r, f, up);
    normalize_d(up);
    for (int i = 0; i < 3; ++i)
        right[i] = r[i], fwd[i] = f[i];
}

static void view_setup(const pen_camera *cam, pen_view *view) {
    view->width = cam->width;
    view->height = cam->height;
    pen__load3_d(cam->eye, view->eye);
    camera_frame_d(cam, view->right, view->up, view->forward);
    double h = cam->height > 0 ? (double)cam->height : 1.0;
    double fov = (double)cam->fov_y_deg;
    if (!(fov > 0.0 && fov < 180.0)) fov = 60.0; /* only reachable without pen_view_init */
    view->focal = h / (2.0 * tan(fov * (PEN_PI / 360.0)));
    view->cx = 0.5 * (double)cam->width;
    view->cy = 0.5 * h;
    double d[3];
    pen__load3_d(cam->target, d);
    pen__sub_d(d, view->eye, d);
    double dist = sqrt(pen__dot_d(d, d));
    view->near_plane = dist > 0.0 && isfinite(dist) ? 1e-3 * dist : 1e-3;
}

void pen_camera_frame(const pen_camera *cam, float right[3], float up[3], float forward[3]) {
    double r[3], u[3], f[3];
    camera_frame_d(cam, r, u, f);
    for (int i = 0; i < 3; ++i)
        right[i] = (float)r[i], up[i] = (float)u[i], forward[i] = (float)f[i];
}

void pen_camera_ray(const pen_camera *cam, float px, float py, float dir[3]) {
    pen_view view;
    view_setup(cam, &view);
    double d[3];
    pen_view_ray(&view, (double)px, (double)py, d);
    normalize_d(d);
    dir[0] = (float)d[0], dir[1] = (float)d[1], dir[2] = (float)d[2];
}

pen_status pen_view_init(pen_context *ctx, const pen_camera *cam, pen_view *view) {
    if (!cam || !view) return pen__error(ctx, PEN_ERROR_ARGUMENT, "pen_view_init: NULL argument");
    if (cam->width < 1 || cam->height < 1 || cam->width > PEN_IMAGE_MAX_DIM ||
        cam->height > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: size %dx%d outside [1, %d]", cam->width,
                          cam->height, PEN_IMAGE_MAX_DIM);
    if (!(cam->fov_y_deg > 0.0f && cam->fov_y_deg < 180.0f))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: fov_y_deg %g outside (0, 180)",
                          (double)cam->fov_y_deg);
    if (!pen__finite3(cam->eye) || !pen__finite3(cam->target) || !pen__finite3(cam->up))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: non-finite eye, target or up");
    if (cam->eye[0] == cam->target[0] && cam->eye[1] == cam->target[1] &&
        cam->eye[2] == cam->target[2])
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: eye equals target");
    view_setup(cam, view);
    return PEN_OK;
}

void pen_view_ray(const pen_view *view, double px, double py, double dir[3]) {
    double rx = (px - view->cx) / view->focal;
    double ry = (view->cy - py) / view->focal;
    for (int i = 0; i < 3; ++i)
        dir[i] = rx * view->right[i] + ry * view->up[i] + view->forward[i];
}

/* ---- Projection: forward and backward ------------------------------------------------------- */

void pen__raster_project_d(const pen_view *view, const double p[3], double s[3], double J[9]) {
    double d[3];
    pen__sub_d(p, view->eye, d);
    double x = pen__dot_d(d, view->right), y = pen__dot_d(d, view->up);
    double z = pen__dot_d(d, view->forward);
    double iz = 1.0 / z, f = view->focal;
    s[0] = view->cx + f * x * iz;
    s[1] = view->cy - f * y * iz;
    s[2] = z;
    if (!J) return;
    /* d(x/z)/dp = (right - (x/z) forward) / z, likewise for y. */
    for (int i = 0; i < 3; ++i) {
        J[i] = f * iz * (view->right[i] - x * iz * view->forward[i]);
        J[3 + i] = -f * iz * (view->up[i] - y * iz * view->forward[i]);
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
