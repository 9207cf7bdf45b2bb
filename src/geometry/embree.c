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

void pen__embree_occluded16(RTCScene scene, const float org[3], const float (*dir)[3], int n,
                            const int *want, float tnear, int *hit) {
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    struct RTCRay16 r; /* RTC_ALIGN(64) in its declaration */
    /* Embree asks for the mask aligned like the packet (its debug build refuses one that is not);
     * the AVX-512 traversal loads it as one vector. */
    _Alignas(64) int valid[16];
    for (int i = 0; i < 16; ++i) {
        const int on = i < n && want[i];
        valid[i] = on ? -1 : 0;
        r.org_x[i] = org[0], r.org_y[i] = org[1], r.org_z[i] = org[2];
        r.dir_x[i] = on ? dir[i][0] : 0.0f, r.dir_y[i] = on ? dir[i][1] : 0.0f;
        r.dir_z[i] = on ? dir[i][2] : 1.0f;
        /* an empty interval as well: Embree's fallback without 16-wide packets traces the packet
         * as a stream, which skips rays by tnear > tfar and ignores the mask */
        r.tnear[i] = tnear, r.tfar[i] = on ? INFINITY : -INFINITY, r.time[i] = 0.0f;
        r.mask[i] = 0xFFFFFFFFu, r.id[i] = (unsigned)i, r.flags[i] = 0;
    }
    rtcOccluded16(valid, scene, &ictx, &r);
    for (int i = 0; i < n; ++i)
        hit[i] = want[i] && r.tfar[i] < 0.0f;
}
