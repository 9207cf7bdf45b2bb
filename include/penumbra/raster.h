/* penumbra/raster.h -- camera projection, rasterizer (G-buffer), attribute interpolation, edge
 * antialiasing: the differentiable visibility stage of the renderer (the rigid pose it starts
 * from, forward and backward, is the model's: penumbra/scene.h).
 *
 * Usage (one frame of a mesh and its backward, the calls the shading pipeline in src/render makes):
 *
 *     // given: ctx
 *     static const float tet[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};       // 4 vertices
 *     static const uint32_t tri[] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};    // 4 triangles
 *     enum { V = 4, T = 4, W = 32, H = 32, P = W * H };
 *     pen_camera cam = {.width = W, .height = H, .fov_y_deg = 40, .eye = {0, 1, 3},
 *                       .target = {0, 0.3f, 0}, .up = {0, 1, 0}};
 *     pen_pose pose = {.rotation_axis_angle_deg = {0, 30, 0}, .scale = 1};
 *     float world[3 * V], normals[3 * V];
 *     int32_t adjacency[3 * T];
 *     static float color[3 * P], image[3 * P];
 *     pen_view view;
 *     pen_gbuffer gb;
 *     pen_view_init(ctx, &cam, &view);
 *     pen_pose_points_fwd(&pose, V, tet, world);                         // object -> world
 *     pen_vertex_normals_fwd(ctx, V, world, T, tri, normals);            // smooth normals
 *     pen_raster_adjacency(ctx, V, T, tri, adjacency);                   // for the antialiasing
 *     pen_raster_mesh mesh = {V, T, world, tri, adjacency};
 *     pen_gbuffer_create(ctx, W, H, &gb);
 *     pen_raster_gbuffer(ctx, &view, &mesh, 1, NULL, &gb);               // visibility, no ground
 *     pen_interpolate_fwd(&gb, 0, tri, normals, 3, color);               // per-pixel attributes
 *     // ... shade every pixel into `color` (RGB): here the colour is the normal; a shader also
 *     // interpolates positions and UVs (uv_indices) and normalises (pen_normalize_fwd) ...
 *     pen_antialias_fwd(ctx, &gb, &view, &mesh, 1, color, 3, image);     // silhouette blending
 *     // backward, in reverse, of loss = the sum of the image (d_image = 1):
 *     static float d_image[3 * P], d_color[3 * P], d_bary[2 * P];
 *     float d_world[3 * V] = {0}, d_normals[3 * V] = {0}, *d_meshes[1] = {d_world};
 *     for (int i = 0; i < 3 * P; ++i) d_image[i] = 1;
 *     pen_antialias_bwd(ctx, &gb, &view, &mesh, 1, color, 3, d_image, d_color, d_meshes);
 *     // ... shading backward: d_color -> d_position, d_normal, d_uv ...
 *     pen_interpolate_bwd(&gb, 0, tri, normals, 3, d_color, d_normals, d_bary);
 *     pen_raster_bary_bwd(ctx, &view, &mesh, 1, &gb, d_bary, d_meshes);  // the point slides
 *     pen_vertex_normals_bwd(ctx, V, world, T, tri, d_normals, d_world);
 *     pen_pose_grad d_pose = {0};
 *     pen_pose_points_bwd(&pose, V, tet, d_world, &d_pose, NULL);        // world -> pose
 *     pen_gbuffer_free(&gb);
 *
 * Conventions:
 *   - Right-handed world, Y up. Camera per penumbra/scene.h: pinhole, row 0 at the top, pixel
 *     (px, py) covers [px, px+1) x [py, py+1), its centre is (px + 0.5, py + 0.5); square pixels.
 *   - Screen coordinates (sx, sy) are in pixels with the same origin; "depth" is the view-space
 *     distance along the camera's forward axis (not the ray length).
 *   - Every image-sized buffer is row-major, top row first: element (x, y) is at y * width + x
 *     (times the channel count).
 *   - Backward functions take the forward's inputs in the same order, then the gradient of the
 *     output (d_*), and ADD into the gradients of the inputs; a NULL d_* input is skipped.
 *   - Floats in the API; sensitive arithmetic (projection, barycentrics, edge crossings) runs in
 *     double inside.
 * See docs/rasterizer.md for the G-buffer, the near plane and the antialiasing scheme.
 */
#ifndef PENUMBRA_RASTER_H
#define PENUMBRA_RASTER_H

#include "penumbra/core.h"
#include "penumbra/scene.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Camera ---------------------------------------------------------------------------------- */

/* A camera prepared for projection: orthonormal frame, focal lengths in pixels, near plane. */
typedef struct pen_view {
    int width, height;
    double eye[3];
    double right[3], up[3], forward[3]; /* orthonormal, right-handed: right x up = -forward */
    double focal[2];                    /* pixels, x and y: height / (2 tan(fov_y / 2)) each,
                                           or the camera's calibrated fx, fy */
    double cx, cy;                      /* principal point: width / 2, height / 2, or cx, cy */
    double near_plane;                  /* depth below which geometry is clipped */
} pen_view;

/* Validates a camera (size in [1, PEN_IMAGE_MAX_DIM], fov_y in (0, 180) degrees, finite vectors,
 * eye != target) and prepares the view. The near plane defaults to 1e-3 * |target - eye|; a
 * caller may overwrite view->near_plane (> 0) afterwards. If `up` is parallel to the viewing
 * direction another axis is used, as pen_camera_frame does. */
PEN_API pen_status pen_view_init(pen_context *ctx, const pen_camera *cam, pen_view *view);

/* World point -> (sx, sy, depth): sx = cx + fx (d.right)/(d.forward), sy = cy - fy
 * (d.up)/(d.forward), depth = d.forward with d = p - eye. Points at depth <= 0 give non-finite
 * screen coordinates; callers test depth against near_plane first. */
PEN_API void pen_view_project_fwd(const pen_view *view, const float p[3], float s[3]);
/* d_p += J^T d_s with J = d(sx, sy, depth)/dp. */
PEN_API void pen_view_project_bwd(const pen_view *view, const float p[3], const float d_s[3],
                                  float d_p[3]);
/* The world-space ray direction through image point (px, py), scaled so that its forward
 * component is 1: the point at depth z on that ray is eye + z * dir. */
PEN_API void pen_view_ray(const pen_view *view, double px, double py, double dir[3]);

/* ---- Rasterizer ------------------------------------------------------------------------------ */

/* A triangle mesh already in world space, borrowed for the call. */
typedef struct pen_raster_mesh {
    int vertex_count;
    int triangle_count;
    const float *positions;  /* 3 * vertex_count, world space */
    const uint32_t *indices; /* 3 * triangle_count, into positions */
    /* 3 * triangle_count from pen_raster_adjacency: for edge k of triangle t (corner k to corner
     * (k+1) % 3) the same edge in the neighbouring triangle t' as its half-edge 3 t' + k', or -1.
     * Needed by pen_antialias_*, ignored by the rasterizer; may be NULL when no antialiasing is
     * done. */
    const int32_t *adjacency;
} pen_raster_mesh;

/* Surface ids of the G-buffer besides object indices 0, 1, ... */
#define PEN_SURFACE_BACKGROUND (-1)
#define PEN_SURFACE_GROUND (-2)

/* Per-pixel visibility, sampled at the pixel centre. For pixel i = y * width + x:
 *   surface[i]  object index (position in the mesh list), PEN_SURFACE_GROUND or
 *               PEN_SURFACE_BACKGROUND;
 *   triangle[i] triangle index within the object, or -1;
 *   bary[2i], bary[2i+1]  perspective-correct barycentrics (u, v) of the visible point: it is
 *               (1-u-v) p0 + u p1 + v p2 for the triangle's corners p0, p1, p2; 0 for ground and
 *               background pixels;
 *   depth[i]    view depth of the visible point (ground pixels too); INFINITY for background.
 * Owns its arrays; pen_gbuffer_free releases them. */
typedef struct pen_gbuffer {
    int width, height;
    int32_t *surface;
    int32_t *triangle;
    float *bary;
    float *depth;
} pen_gbuffer;

PEN_API pen_status pen_gbuffer_create(pen_context *ctx, int width, int height, pen_gbuffer *out);
PEN_API void pen_gbuffer_free(pen_gbuffer *gb);

/* Rasterizes the meshes and the ground plane (may be NULL or disabled) into gb, which must have
 * the view's size. Both faces of every triangle are drawn (no culling). The ground is the finite
 * square y = height, |x|, |z| <= half_size, intersected analytically with each pixel's ray.
 * Geometry in front of view->near_plane is kept; triangles crossing it are clipped exactly (the
 * per-pixel depth test), and zero-area or edge-on triangles cover nothing. Ties in depth go to
 * the earlier mesh and triangle, and meshes win ties against the ground. Tiles of 16x16 pixels
 * are processed in parallel (pen_context_threads); the result does not depend on the thread
 * count. Fails on a size mismatch, an index out of range or a non-finite position. */
PEN_API pen_status pen_raster_gbuffer(pen_context *ctx, const pen_view *view,
                                      const pen_raster_mesh *meshes, int mesh_count,
                                      const pen_ground *ground, pen_gbuffer *gb);

/* Backward of the barycentrics of the visible points: with d_bary (2 per pixel, d/du and d/dv),
 * adds into d_positions[m] (3 * vertex_count, or NULL to skip mesh m) the gradient through the
 * barycentrics of each pixel's point, which moves on its fixed pixel ray as the triangle moves.
 * Ground and background pixels are skipped. Parallel over pixels, with a fixed summation order.
 * Fails only if its scratch buffer (9 floats per pixel) cannot be allocated. */
PEN_API pen_status pen_raster_bary_bwd(pen_context *ctx, const pen_view *view,
                                       const pen_raster_mesh *meshes, int mesh_count,
                                       const pen_gbuffer *gb, const float *d_bary,
                                       float *const *d_positions);
/* The same with the caller's scratch buffer g (9 floats per pixel), so that a renderer calling it
 * every frame allocates nothing: at 1024 x 1024 a fresh 37 MB buffer is above glibc's mmap
 * threshold and its page faults cost about 24 ms per call (bench/NOTES.md). */
PEN_API void pen_raster_bary_bwd_scratch(pen_context *ctx, const pen_view *view,
                                         const pen_raster_mesh *meshes, int mesh_count,
                                         const pen_gbuffer *gb, const float *d_bary,
                                         float *const *d_positions, float *g);

/* World position of every non-background pixel's visible point, eye + depth * ray (3 floats per
 * pixel; background pixels get 0). For ground pixels this is the position to shade; mesh pixels
 * should use pen_interpolate_fwd of the positions, which carries gradients. */
PEN_API void pen_gbuffer_points(const pen_view *view, const pen_gbuffer *gb, float *out);

/* Edge adjacency of a triangle list (see pen_raster_mesh.adjacency): an edge shared by exactly
 * two triangles records the other triangle's half-edge (3 t' + k'; its third vertex is corner
 * (k' + 2) % 3); boundary and non-manifold edges get -1 and are always treated as possible
 * silhouettes. adjacency has 3 * triangle_count entries; at most INT32_MAX / 3 triangles. */
PEN_API pen_status pen_raster_adjacency(pen_context *ctx, int vertex_count, int triangle_count,
                                        const uint32_t *indices, int32_t *adjacency);

/* ---- Attribute interpolation ----------------------------------------------------------------- */

/* For every pixel whose surface is `object`: out[i*dim + c] = sum_k b_k values[idx_k*dim + c]
 * with idx_k = indices[3 * triangle + k] and (b0, b1, b2) = (1-u-v, u, v). Other pixels of out
 * are left untouched. `indices` may differ from the position indices (UV seams). */
PEN_API void pen_interpolate_fwd(const pen_gbuffer *gb, int object, const uint32_t *indices,
                                 const float *values, int dim, float *out);
/* Adds into d_values (per value, dim each) and d_bary (2 per pixel, may be NULL). */
PEN_API void pen_interpolate_bwd(const pen_gbuffer *gb, int object, const uint32_t *indices,
                                 const float *values, int dim, const float *d_out, float *d_values,
                                 float *d_bary);

/* Smooth vertex normals weighted by triangle area: normals[v] = normalize(sum over triangles
 * around v of (p1 - p0) x (p2 - p0)), summed in double. A vertex whose sum is shorter than 1e-20
 * (no non-degenerate triangle) gets (0, 0, 0) and no gradient. Fails on an index out of range. */
PEN_API pen_status pen_vertex_normals_fwd(pen_context *ctx, int vertex_count,
                                          const float *positions, int triangle_count,
                                          const uint32_t *indices, float *normals);
PEN_API pen_status pen_vertex_normals_bwd(pen_context *ctx, int vertex_count,
                                          const float *positions, int triangle_count,
                                          const uint32_t *indices, const float *d_normals,
                                          float *d_positions);

/* out[i] = v[i] / |v[i]| for n 3-vectors (interpolated normals are no longer unit); a vector of
 * length below 1e-20 gives (0, 0, 0) and no gradient. `out` may alias `v`. */
PEN_API void pen_normalize_fwd(int n, const float *v, float *out);
PEN_API void pen_normalize_bwd(int n, const float *v, const float *d_out, float *d_v);

/* ---- Edge antialiasing ----------------------------------------------------------------------- */

/* Blends the colours (channels floats per pixel) of neighbouring pixels across geometric
 * silhouette edges by the fraction of the pixel the edge leaves to the other side, so that the
 * image becomes a continuous function of vertex positions (Laine et al. 2020 in idea; the
 * scheme is in docs/rasterizer.md). Every mesh needs its adjacency. `out` may not alias `color`. */
PEN_API pen_status pen_antialias_fwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                     const pen_raster_mesh *meshes, int mesh_count,
                                     const float *color, int channels, float *out);
/* Adds into d_color (per pixel) and d_positions[m] (3 * vertex_count, or NULL). */
PEN_API pen_status pen_antialias_bwd(pen_context *ctx, const pen_gbuffer *gb, const pen_view *view,
                                     const pen_raster_mesh *meshes, int mesh_count,
                                     const float *color, int channels, const float *d_out,
                                     float *d_color, float *const *d_positions);

#ifdef __cplusplus
}
#endif
#endif
