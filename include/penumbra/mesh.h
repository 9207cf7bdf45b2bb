/* penumbra/mesh.h -- triangle meshes: layout, validation, bounds, freeing (src/scene). Files (OBJ,
 * PLY) are read and written by penumbra/io.h.
 *
 * Layout: positions are float x,y,z per vertex (3 * vertex_count floats); triangles index
 * positions with three uint32 each (counter-clockwise seen from outside). UVs and normals, when
 * present, have their own index triples per triangle (OBJ style), so seams need no duplication:
 *   uv of corner k of triangle t = uvs[2 * uv_indices[3 t + k]] (u, v with v up, [0,1]^2),
 *   normal of that corner        = normals[3 * normal_indices[3 t + k]].
 * Materials (OBJ/MTL): materials[k] holds material k's name, diffuse colour Kd and diffuse map;
 * triangle_materials[t] is triangle t's material index, or -1 for a face before any `usemtl` or
 * naming a material no MTL file defines. Vertex colours (PLY red/green/blue, OBJ `v x y z r g b`)
 * are linear RGB in [0, 1], 3 per vertex.
 * The renderer reads one albedo texture per object, so several materials or vertex colours are
 * first baked into one atlas (pen_mesh_bake_albedo below); the scene loader does that.
 * A mesh owns all its arrays; pen_mesh_free releases them.
 */
#ifndef PENUMBRA_MESH_H
#define PENUMBRA_MESH_H

#include "penumbra/core.h"
#include "penumbra/image.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Most materials one mesh may have (the OBJ loader's cap). */
#define PEN_MESH_MAX_MATERIALS 65536

/* One OBJ material, as its MTL file gives it. */
typedef struct pen_mesh_material {
    char *name;
    float kd[3]; /* diffuse colour (linear, as written); meaningful when has_kd */
    int has_kd;
    char *texture_path;   /* map_Kd, resolved relative to the .mtl file, or NULL */
    char *texture_source; /* "file.mtl:line" of that map_Kd statement (for messages), or NULL */
} pen_mesh_material;

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
    char *texture_path;        /* map_Kd of the first material a face uses that has one (resolved
                                  path), or NULL */
    int material_count;        /* 0 without materials */
    pen_mesh_material *materials; /* material_count entries */
    int32_t *triangle_materials;  /* triangle_count entries in [-1, material_count), or NULL when
                                     material_count == 0 */
    float *colors;                /* 3 * vertex_count, linear RGB in [0, 1]; NULL without colours */
} pen_mesh;

/* Checks a mesh (loaded, or built in memory): positive counts within the loaders' cap, finite
 * coordinates, every index in range (material indices in [-1, material_count)), vertex colours
 * finite and in [0, 1]. Errors (PEN_ERROR_ARGUMENT) name the triangle or vertex. */
PEN_API pen_status pen_mesh_validate(pen_context *ctx, const pen_mesh *mesh);
/* Frees the arrays of a mesh and zeroes it; NULL is a no-op. */
PEN_API void pen_mesh_free(pen_mesh *mesh);
/* Axis-aligned bounds of the positions (all zero for a mesh without vertices). */
PEN_API void pen_mesh_bounds(const pen_mesh *mesh, float lo[3], float hi[3]);

/* How the albedo of a mesh's materials and colours reaches the renderer (pen_mesh_albedo_plan). */
typedef enum pen_mesh_albedo_kind {
    PEN_MESH_ALBEDO_DEFAULT = 0,  /* nothing in the mesh says: the object's constant albedo */
    PEN_MESH_ALBEDO_CONSTANT = 1, /* the faces use one material, with a Kd and no map */
    PEN_MESH_ALBEDO_TEXTURE = 2,  /* the faces use one material with a map_Kd: the mesh's UVs
                                     into that texture, as they are */
    PEN_MESH_ALBEDO_BAKE = 3      /* several materials used, or vertex colours: bake an atlas */
} pen_mesh_albedo_kind;

/* Decides how a mesh's albedo is rendered: BAKE when it has vertex colours, or its faces use two
 * or more materials (faces without one count as one more); when all faces use one material,
 * *material (may be NULL) is set to its index (else -1) and the result is TEXTURE if it has a
 * map_Kd, CONSTANT if it has a Kd only, DEFAULT otherwise. A mesh without materials but with a
 * texture_path (built in memory) gives TEXTURE. */
PEN_API pen_mesh_albedo_kind pen_mesh_albedo_plan(const pen_mesh *mesh, int *material);

/* Bakes the albedo of a mesh's materials or vertex colours into one texture and rewrites the
 * mesh's UVs to address it, so that one bilinear, repeat-wrapped lookup per point (the
 * renderer's) gives what the materials give:
 * - with vertex colours (they take precedence over materials): each triangle gets a 4x4 texel
 *   block holding the linear function of its corner colours, its corners on three texel centres,
 *   so the lookup equals the barycentric interpolation of the colours exactly (in real numbers);
 * - otherwise one tile per material the faces use: a textured material's texture, repeated as
 *   often as its faces' UVs need (each face's UVs shifted by whole periods towards [0, 1); at most
 *   PEN_MESH_BAKE_MAX_REPEATS periods per direction, larger faces have their UVs clamped),
 *   surrounded by a 2-texel gutter of wrapped texels so the lookup matches the texture's own
 *   repeat-wrapped lookup; a material with a Kd only, or faces with no material, get a constant
 *   tile (Kd, or default_albedo), their UVs on its centre.
 * textures[k] is material k's texture (linear RGB(A) as pen_image_load gives it; data NULL for a
 * material without one); textures may be NULL when no material has one. The mesh gets one UV per
 * triangle corner. Fails (PEN_ERROR_UNSUPPORTED) when the atlas would exceed PEN_IMAGE_MAX_DIM a
 * side or PEN_IMAGE_MAX_PIXELS in all, and (PEN_ERROR_ARGUMENT) when a textured material's faces
 * have no UVs; messages begin with "bake: ". On failure the mesh is unchanged. The atlas is
 * allocated (3 channels); free it with pen_image_free. */
#define PEN_MESH_BAKE_MAX_REPEATS 8
PEN_API pen_status pen_mesh_bake_albedo(pen_context *ctx, pen_mesh *mesh, const pen_image *textures,
                                        const float default_albedo[3], pen_image *atlas);

#ifdef __cplusplus
}
#endif
#endif
