/* penumbra/io.h -- the file formats: scene JSON, meshes (OBJ, PLY), images (PNG, JPEG, Radiance
 * HDR, OpenEXR), sphere sets and sets of calibrated views (views JSON, COLMAP, transforms.json),
 * read into and written from the model types of scene.h, mesh.h, image.h and spheres.h.
 * Implemented in src/io, which computes nothing beyond parsing: a scene's overlap weights, for
 * instance, are not solved at load (the renderer computes them when a sphere set has none;
 * pen_spheres_ensure_weights in fit.h does it explicitly).
 *
 * Every loader zeroes *out on failure and names the file and the place (line, byte offset or
 * JSON key path) in the context's message. Every writer is atomic: it writes a temporary file in
 * the same folder and renames it, so a failure never leaves a partial file.
 */
#ifndef PENUMBRA_IO_H
#define PENUMBRA_IO_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/mesh.h"
#include "penumbra/scene.h"
#include "penumbra/spheres.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Sets of calibrated views ----------------------------------------------------------------- */

/* One camera per observed image, with the image's path: what a multi-view task reads
 * (docs/file-formats.md, "Views"). */
typedef struct pen_camera_set {
    int count;
    pen_camera *cameras; /* calibrated: fx > 0, pose as eye/target/up (pen_camera) */
    char **images;       /* the image of each view, resolved */
} pen_camera_set;
#define PEN_CAMERA_SET_MAX 100000 /* views in one set */

/* Imports a COLMAP text model: model_dir/cameras.txt (PINHOLE or SIMPLE_PINHOLE; other models
 * are refused: undistort first) and model_dir/images.txt; image names are resolved against
 * images_dir (NULL: model_dir). Views sorted by image name. */
PEN_API pen_status pen_camera_set_load_colmap(pen_context *ctx, const char *model_dir,
                                              const char *images_dir, pen_camera_set *out);
/* Imports a NeRF-style transforms.json (camera-to-world matrices in OpenGL axes; fl_x/fl_y or
 * camera_angle_x/y, cx, cy, w, h per frame or at the top; see docs/file-formats.md). Image paths
 * relative to the file. Views in file order. */
PEN_API pen_status pen_camera_set_load_transforms(pen_context *ctx, const char *path,
                                                  pen_camera_set *out);
/* Reads and writes the views JSON: {"views": [{"camera": {...}, "target": "image"}, ...]}, each
 * camera as in a scene file; image paths relative to the JSON file. Writing is atomic. */
PEN_API pen_status pen_camera_set_load_views(pen_context *ctx, const char *path,
                                             pen_camera_set *out);
PEN_API pen_status pen_camera_set_save_views(pen_context *ctx, const char *path,
                                             const pen_camera_set *set);
/* Frees a set's arrays and zeroes it; NULL is a no-op. */
PEN_API void pen_camera_set_free(pen_camera_set *set);

/* ---- Scenes ---------------------------------------------------------------------------------- */

/* Loads a scene JSON (docs/file-formats.md) with everything it references (meshes, textures,
 * sphere sets, envmap), paths relative to the JSON file. Lighting: "envmap" is projected onto
 * sh_bands bands (pen_envmap_to_sh) and kept for the background; "sh" gives the coefficients
 * directly (and wins over the projection when both are present). Errors name the file and the
 * JSON key path, e.g. "scene.json: camera.width: expected a positive integer, got -3"; errors of
 * a referenced file are prefixed with the key that named it. Unknown keys are errors (keys
 * starting with '_' are comments). Sphere sets keep the overlap weights their JSON gives and get
 * none otherwise (pen_spheres.weight NULL: computed when needed). An object's albedo is its
 * "albedo_texture", else its "albedo", else what its mesh's materials or vertex colours give
 * (pen_mesh_albedo_plan; several materials or colours are baked into one texture with
 * pen_mesh_bake_albedo, pen_object.texture_layout PEN_TEXTURE_LAYOUT_BAKED). On failure *out is
 * zeroed. Placement keys are resolved here (docs/file-formats.md, "Placing objects and the
 * camera"): an object's "units" multiplies its pose scale, "pose": {"on_ground", "centre"} sets
 * its translation from its posed vertices, and "camera": {"frame"} sets the camera's eye, target
 * and up (0, 1, 0) to frame the objects so placed; the scene holds the numbers, which
 * pen_scene_save writes. */
PEN_API pen_status pen_scene_load(pen_context *ctx, const char *path, pen_scene *out);
/* The same from JSON text (e.g. a scene embedded in a task file, printed back to text): `path`
 * names the text in messages and is the base of its relative paths. */
PEN_API pen_status pen_scene_parse(pen_context *ctx, const char *json_text, const char *path,
                                   pen_scene *out);
/* Writes a scene JSON that pen_scene_load reads back to the same scene (paths relative to the
 * new file where possible; the referenced files are not written). A baked albedo atlas is
 * written as the mesh alone while its texture_path is NULL (loading bakes it again), else as its
 * file with "albedo_texture_layout": "baked" (set texture_path after saving changed pixels).
 * Atomic. */
PEN_API pen_status pen_scene_save(pen_context *ctx, const char *path, const pen_scene *scene);
/* Flags of pen_scene_save_ex. PEN_SCENE_SAVE_SH_LIGHTING writes the SH coefficients as "sh" even
 * when there is an envmap (which is then written too, for the background): for lighting that was
 * optimized and no longer equals the map's projection. */
#define PEN_SCENE_SAVE_SH_LIGHTING 1u
PEN_API pen_status pen_scene_save_ex(pen_context *ctx, const char *path, const pen_scene *scene,
                                     unsigned flags);

/* ---- Meshes ---------------------------------------------------------------------------------- */

/* Loads a mesh by extension (.obj, .ply). Polygons are triangulated as fans; OBJ negative
 * (relative) indices are resolved; zero and out-of-range indices, NaN/Inf coordinates,
 * truncated files and absurd counts are errors naming the file and line (or byte offset); so
 * is a vertex coordinate beyond +-PEN_SCENE_MAX_COORD (penumbra/scene.h), naming the vertex.
 * OBJ materials (every mtllib: newmtl, Kd, map_Kd; usemtl per face) and vertex colours (OBJ
 * `v x y z r g b`, PLY red/green/blue) are kept (penumbra/mesh.h); texture files are not opened.
 * On success *out owns the arrays; on failure *out is zeroed. */
PEN_API pen_status pen_mesh_load(pen_context *ctx, const char *path, pen_mesh *out);
PEN_API pen_status pen_mesh_load_obj(pen_context *ctx, const char *path, pen_mesh *out);
PEN_API pen_status pen_mesh_load_ply(pen_context *ctx, const char *path, pen_mesh *out);
/* The files a mesh file names and whether each can be opened: an OBJ's material libraries (its
 * mtllib statements, each library once) and the map_Kd texture of every material in the
 * libraries found. pen_mesh_load passes over a library it cannot open (the mesh then has no
 * materials) and opens no texture, so this is how a missing one comes to light (`penumbra info`,
 * pen_scene_check in penumbra/fit.h). A PLY names no file (count 0). Reads the OBJ and its
 * libraries with the loader's limits; at most PEN_MESH_FILES_MAX_LIBRARIES libraries. On success
 * *out owns its entries (pen_mesh_files_free); on failure it is zeroed. */
typedef enum pen_mesh_file_kind {
    PEN_MESH_FILE_MTLLIB = 0, /* a material library (mtllib) */
    PEN_MESH_FILE_TEXTURE = 1 /* a material's diffuse texture (map_Kd) */
} pen_mesh_file_kind;
typedef struct pen_mesh_file {
    pen_mesh_file_kind kind;
    char *path;     /* resolved: relative to the OBJ (mtllib) or to its .mtl file (map_Kd) */
    char *source;   /* "file:line" of the statement that names it */
    char *material; /* the material of a map_Kd; NULL for a library */
    int found;      /* 1 when the file could be opened for reading */
} pen_mesh_file;
typedef struct pen_mesh_files {
    int count;
    pen_mesh_file *files; /* libraries in file order, then textures in material order */
} pen_mesh_files;
#define PEN_MESH_FILES_MAX_LIBRARIES 4096
PEN_API pen_status pen_mesh_files_load(pen_context *ctx, const char *path, pen_mesh_files *out);
/* Frees the entries and zeroes *files; NULL is a no-op. */
PEN_API void pen_mesh_files_free(pen_mesh_files *files);
/* Writes a Wavefront OBJ (v, vt, vn, f with 1-based v/vt/vn references; no material or vertex
 * colour). Atomic:
 * temporary file + rename. pen_mesh_save picks the format by extension (.obj only). */
PEN_API pen_status pen_mesh_save(pen_context *ctx, const char *path, const pen_mesh *mesh);
PEN_API pen_status pen_mesh_save_obj(pen_context *ctx, const char *path, const pen_mesh *mesh);
/* ---- Images ---------------------------------------------------------------------------------- */

/* Loads .png (8- or 16-bit), .jpg/.jpeg (8-bit), .hdr or .exr (by extension) into 3 channels
 * (RGB), linear: grey is replicated, alpha dropped. Each side must be within PEN_IMAGE_MAX_DIM,
 * the whole within 2^27 pixels (checked before decoding), the file intact (PNG CRCs, complete
 * data) and every value finite (PEN_ERROR_PARSE otherwise; docs/file-formats.md). EXR channels R, G, B (or Y) are read as 32-bit floats whatever
 * their stored type or compression; values are loaded as stored (an EXR may hold small negative
 * values from lossy compression: clamping them is the user's business, see pen_envmap_to_sh).
 * On failure *out is zeroed. */
PEN_API pen_status pen_image_load(pen_context *ctx, const char *path, pen_image *out);
/* PNG and JPEG values as stored, v / 255 (or / 65535), without sRGB decoding: for data maps. */
#define PEN_IMAGE_LOAD_RAW 1u
PEN_API pen_status pen_image_load_ex(pen_context *ctx, const char *path, unsigned flags,
                                     pen_image *out);
/* Saves by extension: .png 8-bit sRGB (values clamped to [0,1], then encoded; a 2nd or 4th
 * channel is alpha, stored linear), .hdr Radiance RGBE (negative values become 0), .exr 32-bit
 * float with ZIP compression. 1 to 4 channels. Writes to a temporary file in the same folder and
 * renames it, so a failure never leaves a partial file. NaN/Inf pixels are an error
 * (PEN_ERROR_ARGUMENT naming the pixel). */
PEN_API pen_status pen_image_save(pen_context *ctx, const char *path, const pen_image *image);
/* 1 if path ends in an image extension pen_image_load and pen_image_save both handle (.png, .hdr,
 * .exr; any case): the formats an output may have. JPEG is read only. */
PEN_API int pen_image_path_supported(const char *path);

/* ---- Sphere sets (the JSON of spheres.h) ----------------------------------------------------- */

PEN_API pen_status pen_spheres_load(pen_context *ctx, const char *path, pen_spheres *out);
/* Writes the spheres; `extra_json` (may be NULL) is a JSON object text whose members are added
 * at the top level (e.g. "metrics"). Atomic: temp file + rename. */
PEN_API pen_status pen_spheres_save(pen_context *ctx, const char *path, const pen_spheres *spheres,
                                    const char *extra_json);

#ifdef __cplusplus
}
#endif
#endif
