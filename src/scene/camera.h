/* Internal interface of the model's camera (src/scene/camera.c), in double: what the rasterizer's
 * prepared view (src/raster/camera.c) is built from, so both compute the same frame and rays. */
#ifndef PEN_SCENE_CAMERA_H
#define PEN_SCENE_CAMERA_H

#include "penumbra/scene.h"

/* Orthonormal frame of a camera without failing: a degenerate forward falls back to -Z, an up
 * vector parallel to forward to the world axis least aligned with forward. */
void pen__camera_frame_d(const pen_camera *cam, double right[3], double up[3], double fwd[3]);
/* Focal lengths in pixels and the principal point: the calibrated fx, fy, cx, cy when fx > 0,
 * else fx = fy = H / (2 tan(fov_y / 2)) and (W/2, H/2). A size or field of view out of range
 * (only reachable without validation) gives H = 1, 60 degrees. */
void pen__camera_intrinsics_d(const pen_camera *cam, double focal[2], double *cx, double *cy);

/* The ray direction through image point (px, py), scaled so that its forward component is 1:
 * (px - cx)/fx right + (cy - py)/fy up + forward. */
static inline void pen__camera_ray_d(const double right[3], const double up[3], const double fwd[3],
                                     const double focal[2], double cx, double cy, double px,
                                     double py, double dir[3]) {
    double rx = (px - cx) / focal[0];
    double ry = (cy - py) / focal[1];
    for (int i = 0; i < 3; ++i)
        dir[i] = rx * right[i] + ry * up[i] + fwd[i];
}

#endif
