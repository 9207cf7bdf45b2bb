/* Embree scene setup shared by the voxelizer and the reference renderer: one place that knows
 * Embree's buffer formats for penumbra's triangle arrays (see embree.h). */
#include "geometry/embree.h"

#include <math.h>
#include <string.h>

int pen__embree_fill_triangles(RTCGeometry geom, const float *positions, size_t vertex_count,
                               const uint32_t *indices, size_t triangle_count) {
    float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), vertex_count);
    unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(unsigned), triangle_count);
    if (!vb || !ib) return 0;
    memcpy(vb, positions, 3 * sizeof(float) * vertex_count);
    memcpy(ib, indices, 3 * sizeof(unsigned) * triangle_count);
    return 1;
}

int pen__embree_occluded(RTCScene scene, const float org[3], const float dir[3], float tnear) {
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    struct RTCRay ray;
    ray.org_x = org[0], ray.org_y = org[1], ray.org_z = org[2];
    ray.dir_x = dir[0], ray.dir_y = dir[1], ray.dir_z = dir[2];
    ray.tnear = tnear;
    ray.tfar = INFINITY;
    ray.time = 0.0f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    rtcOccluded1(scene, &ictx, &ray);
    return ray.tfar < 0.0f; /* Embree sets tfar to -inf on a hit */
}
