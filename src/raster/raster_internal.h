/* Internal interface of src/raster: double-precision kernels shared by the camera, rasterizer,
 * interpolation and antialiasing files, and exposed to the tests for finite-difference checks. */
#ifndef PEN_RASTER_INTERNAL_H
#define PEN_RASTER_INTERNAL_H

#include "core/internal.h"
#include "core/vec.h"
#include "penumbra/raster.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

/* pen_interpolate_bwd of one object's points and raw normals (3 floats a vertex) and, when uvs is
 * not NULL, its UVs (uv_indices, 2 floats, no d_values), in one pass with the same bits; d_bary
 * of the object's pixels is written (as if cleared first), the other pixels' left alone. */
void pen__interpolate_bwd_object(const pen_gbuffer *gb, int object, const uint32_t *indices,
                                 const float *world, const float *d_x, float *d_world,
                                 const float *vnormal, const float *d_nraw, float *d_vnormal,
                                 const uint32_t *uv_indices, const float *uvs, const float *d_uv,
                                 float *d_bary);

/* pen_raster_gbuffer that also writes pen_gbuffer_points' values (points: 3 floats a pixel, or
 * NULL) of the pixels off the objects (ground and background), the same bits, as it writes the
 * G-buffer; the objects' pixels are left alone, for a caller that interpolates them. */
pen_status pen__raster_gbuffer_points(pen_context *ctx, const pen_view *view,
                                      const pen_raster_mesh *meshes, int mesh_count,
                                      const pen_ground *ground, pen_gbuffer *gb, float *points);

/* Validates a mesh list (counts, NULL arrays, finite positions, indices in range); *total gets
 * the number of triangles. */
pen_status pen__raster_check_meshes(pen_context *ctx, const pen_raster_mesh *meshes, int mesh_count,
                                    size_t *total);

/* Whether none of the 4 surfaces s[0 .. 3] is a mesh (all negative: ground, background): most of
 * a frame's pixels, which loops over the meshes' pixels pass 4 at a time. */
static inline int pen__no_mesh4(const int32_t *s) {
#if defined(__SSE2__)
    const __m128i s4 = _mm_loadu_si128((const __m128i *)(const void *)s);
    return _mm_movemask_epi8(_mm_cmpgt_epi32(s4, _mm_set1_epi32(-1))) == 0;
#else
    return (s[0] & s[1] & s[2] & s[3]) < 0; /* every sign bit set */
#endif
}

/* The thread count (pen__threads) for a loop of `work` cheap items: one thread below a few
 * thousand, where waking a team costs more than the loop (and a lot more on a loaded machine). */
static inline int pen__raster_threads_for(const pen_context *ctx, size_t work) {
    return work < 8192 ? 1 : pen__threads(ctx);
}

/* pen_antialias_bwd that writes d_color (every pixel) as if it had been cleared first, rather
 * than adding into it: the same bits without the clear. */
pen_status pen__antialias_bwd_set(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                  const pen_raster_mesh *meshes, int mesh_count, const float *color,
                                  int channels, const float *d_out, float *d_color,
                                  float *const *d_positions);

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
