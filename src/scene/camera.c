/* The pinhole camera of the model: its orthonormal frame, its intrinsics and the unit ray through
 * an image point (pen_camera_frame, pen_camera_ray; conventions in penumbra/scene.h and
 * src/raster/camera.c). The frame is right = normalize(forward x up), true up = right x forward;
 * the focal length in pixels is f = H / (2 tan(fov_y / 2)) with the principal point at the image
 * centre, or the calibrated fx, fy, cx, cy. Computed in double; the float entry points convert at
 * the boundary. */
#include "scene/camera.h"
#include "core/internal.h"
#include "core/vec.h"

#include <math.h>

static void normalize_d(double v[3]) {
    double n = sqrt(pen__dot_d(v, v));
    v[0] /= n, v[1] /= n, v[2] /= n;
}

void pen__camera_frame_d(const pen_camera *cam, double right[3], double up[3], double fwd[3]) {
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

void pen__camera_intrinsics_d(const pen_camera *cam, double focal[2], double *cx, double *cy) {
    if (cam->fx > 0.0f) {
        focal[0] = (double)cam->fx, focal[1] = (double)cam->fy;
        *cx = (double)cam->cx, *cy = (double)cam->cy;
        return;
    }
    double h = cam->height > 0 ? (double)cam->height : 1.0;
    double fov = (double)cam->fov_y_deg;
    if (!(fov > 0.0 && fov < 180.0)) fov = 60.0; /* only reachable without pen_view_init */
    focal[0] = focal[1] = h / (2.0 * tan(fov * (PEN_PI / 360.0)));
    *cx = 0.5 * (double)cam->width;
    *cy = 0.5 * h;
}

pen_status pen_camera_validate(pen_context *ctx, const pen_camera *cam) {
    if (cam->width < 1 || cam->height < 1 || cam->width > PEN_IMAGE_MAX_DIM ||
        cam->height > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: size %dx%d outside [1, %d]", cam->width,
                          cam->height, PEN_IMAGE_MAX_DIM);
    if (cam->fx != 0.0f || cam->fy != 0.0f || cam->cx != 0.0f || cam->cy != 0.0f) {
        const double F = PEN_CAMERA_MAX_FOCAL, P = PEN_CAMERA_MAX_PRINCIPAL;
        const double fx = cam->fx, fy = cam->fy, cx = cam->cx, cy = cam->cy;
        if (!(fx > 0.0 && fx <= F && fy > 0.0 && fy <= F))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "camera: focal lengths fx %g, fy %g outside (0, %g] pixels",
                              fx, fy, F);
        if (!(cx >= -P && cx <= cam->width + P && cy >= -P && cy <= cam->height + P))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "camera: principal point (%g, %g) more than %g pixels off the image",
                              cx, cy, P);
    } else if (!(cam->fov_y_deg > 0.0f && cam->fov_y_deg < 180.0f)) {
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: fov_y_deg %g outside (0, 180)",
                          (double)cam->fov_y_deg);
    }
    if (!pen__finite3(cam->eye) || !pen__finite3(cam->target) || !pen__finite3(cam->up))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: non-finite eye, target or up");
    if (cam->eye[0] == cam->target[0] && cam->eye[1] == cam->target[1] &&
        cam->eye[2] == cam->target[2])
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "camera: eye equals target");
    return PEN_OK;
}

void pen_camera_frame(const pen_camera *cam, float right[3], float up[3], float forward[3]) {
    double r[3], u[3], f[3];
    pen__camera_frame_d(cam, r, u, f);
    for (int i = 0; i < 3; ++i)
        right[i] = (float)r[i], up[i] = (float)u[i], forward[i] = (float)f[i];
}

void pen_camera_ray(const pen_camera *cam, float px, float py, float dir[3]) {
    double r[3], u[3], f[3], focal[2], cx, cy, d[3];
    pen__camera_frame_d(cam, r, u, f);
    pen__camera_intrinsics_d(cam, focal, &cx, &cy);
    pen__camera_ray_d(r, u, f, focal, cx, cy, (double)px, (double)py, d);
    normalize_d(d);
    dir[0] = (float)d[0], dir[1] = (float)d[1], dir[2] = (float)d[2];
}
