/* penumbra/mesh.h -- triangle meshes: layout, validation, bounds, freeing (src/scene). Files (OBJ,
 * PLY) are read and written by penumbra/io.h.
 *
 * Layout: positions are float x,y,z per vertex (3 * vertex_count floats); triangles index
 * positions with three uint32 each (counter-clockwise seen from outside). UVs and normals, when
 * present, have their own index triples per triangle (OBJ style), so seams need no duplication:
 *   uv of corner k of triangle t = uvs[2 * uv_indices[3 t + k]] (u, v with v up, [0,1]^2),
 *   normal of that corner        = normals[3 * normal_indices[3 t + k]].
 * A mesh owns all its arrays; pen_mesh_free releases them.
 */
#ifndef PENUMBRA_MESH_H
#define PENUMBRA_MESH_H

#include "penumbra/core.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pen_mesh {
    int vertex_count;
    int triangle_count;
    float *positions;          /* 3 * vertex_count */
    uint32_t *indices;         /* 3 * triangle_count, into positions */
    int uv_count;              /* 0 if the mesh has no texture coordinates */
    float *uvs;                /* 2 * uv_count */
    uint32_t *uv_indices;      /* 3 * triangle_count, into uvs; NULL if uv_count == 0 */
    int normal_count;          /* 0 if the file had no normals */
    float *normals;            /* 3 * normal_count */
    uint32_t *normal_indices;  /* 3 * triangle_count; NULL if normal_count == 0 */
    char *texture_path;        /* diffuse map from an OBJ's mtllib/map_Kd (resolved path), or NULL */
} pen_mesh;

/* Checks a mesh (loaded, or built in memory): positive counts within the loaders' cap, finite
 * coordinates, every index in range. Errors (PEN_ERROR_ARGUMENT) name the triangle or vertex. */
PEN_API pen_status pen_mesh_validate(pen_context *ctx, const pen_mesh *mesh);
/* Frees the arrays of a mesh and zeroes it; NULL is a no-op. */
PEN_API void pen_mesh_free(pen_mesh *mesh);
/* Axis-aligned bounds of the positions (all zero for a mesh without vertices). */
PEN_API void pen_mesh_bounds(const pen_mesh *mesh, float lo[3], float hi[3]);

#ifdef __cplusplus
}
#endif
#endif
