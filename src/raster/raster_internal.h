/* Internal interface of src/raster: double-precision kernels shared by the camera, rasterizer,
 * interpolation and antialiasing files, and exposed to the tests for finite-difference checks. */
#ifndef PEN_RASTER_INTERNAL_H
#define PEN_RASTER_INTERNAL_H

#include "core/internal.h"
#include "core/vec.h"
#include "penumbra/raster.h"

/* Projection of a world point: s = (sx, sy, depth); J (may be NULL) = ds/dp, row-major 3x3. */
void pen__raster_project_d(const pen_view *view, const double p[3], double s[3], double J[9]);

/* The pixel ray eye + t * dir meets the plane of (p0, p1, p2) at the point
 * (1 - b1 - b2) p0 + b1 p1 + b2 p2: x = (t, b1, b2). Returns 0 when the ray is parallel to the
 * plane (x untouched). */
int pen__raster_ray_bary_d(const double eye[3], const double dir[3], const double p0[3],
                           const double p1[3], const double p2[3], double x[3]);
/* Backward of pen__raster_ray_bary_d at its solution x, for gradient d_x of (t, b1, b2):
 * adds into d_p0, d_p1, d_p2 (eye and dir are constants). */
void pen__raster_ray_bary_bwd_d(const double eye[3], const double dir[3], const double p0[3],
                                const double p1[3], const double p2[3], const double x[3],
                                const double d_x[3], double d_p0[3], double d_p1[3],
                                double d_p2[3]);

/* pen_gbuffer_points for the rows [y0, y1) only (a caller's threads take a band of rows each). */
void pen__gbuffer_points_rows(const pen_view *view, const pen_gbuffer *gb, int y0, int y1,
                              float *out);

/* Validates a mesh list (counts, NULL arrays, finite positions, indices in range); *total gets
 * the number of triangles. */
pen_status pen__raster_check_meshes(pen_context *ctx, const pen_raster_mesh *meshes, int mesh_count,
                                    size_t *total);

/* The thread count (pen__threads) for a loop of `work` cheap items: one thread below a few
 * thousand, where waking a team costs more than the loop (and a lot more on a loaded machine). */
static inline int pen__raster_threads_for(const pen_context *ctx, size_t work) {
    return work < 8192 ? 1 : pen__threads(ctx);
}

/* The ground square's border against the background, blended like a silhouette (antialias.c):
 * color = A color in place (1 to 4 channels); the backward writes d_color = A^T d_out (d_out
 * and d_color must not alias). Nothing blends without an enabled ground (A = I). No position
 * gradient (the ground is fixed). */
pen_status pen__ground_border_fwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_ground *ground, float *color, int channels);
pen_status pen__ground_border_bwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_ground *ground, int channels, const float *d_out,
                                  float *d_color);

#endif
