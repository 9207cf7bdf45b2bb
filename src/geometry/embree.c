/* Embree scene setup shared by the voxelizer and the reference renderer: one place that knows
 * Embree's buffer formats for penumbra's triangle arrays (see embree.h). */
#include "geometry/embree.h"

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
