/* Embree scene setup shared by the sphere fit's voxelizer (voxelize.c) and the reference renderer
 * (src/reference): triangle geometry filled from penumbra's mesh arrays, and the shadow-ray query (also used by the
 * self transfer, transfer.c). Internal. */
#ifndef PEN_GEOMETRY_EMBREE_H
#define PEN_GEOMETRY_EMBREE_H

#include <embree3/rtcore.h>
#include <stddef.h>
#include <stdint.h>

/* The instruction set every Embree device here is capped at, appended to its configuration.
 * Embree picks its kernels (BVH width, triangle tests) by the processor, and its AVX-512 kernels
 * round a few hits of the same ray differently from its AVX2 kernels: enough to move a sphere fit
 * (Spot's 32 spheres came out different on an AVX-512 and an AVX2 machine). Capped, a fit, a
 * transfer and a reference render are the same on every processor with AVX2; one without it gets
 * Embree's SSE kernels. */
#define PEN__EMBREE_ISA "max_isa=avx2"

/* Gives a triangle geometry (RTC_GEOMETRY_TYPE_TRIANGLE, not yet committed) new vertex and index
 * buffers holding copies of `positions` (3 floats a vertex) and `indices` (3 a triangle). Copies,
 * not shared buffers: Embree reads up to 16 bytes past the last vertex, which a caller's array
 * need not have. Returns 0 when a buffer could not be allocated. */
int pen__embree_fill_triangles(RTCGeometry geom, const float *positions, size_t vertex_count,
                               const uint32_t *indices, size_t triangle_count);

/* Whether the ray from org along dir (need not be unit) hits anything of the committed scene
 * beyond tnear. */
int pen__embree_occluded(RTCScene scene, const float org[3], const float dir[3], float tnear);

/* The same for n <= 16 rays from one origin, traced as one packet: hit[i] = 1 when ray i is
 * blocked; rays with want[i] == 0 are not traced (hit[i] = 0). A packet of rays from one point
 * shares the traversal's upper levels, which single rays repeat. */
void pen__embree_occluded16(RTCScene scene, const float org[3], const float (*dir)[3], int n,
                            const int *want, float tnear, int *hit);

#endif
