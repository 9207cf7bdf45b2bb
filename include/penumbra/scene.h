/* penumbra/scene.h -- a scene: camera, lighting, objects with their sphere proxies, ground plane,
 * background; loaded from the scene JSON of docs/file-formats.md (docs/design.md sec. 3.3).
 *
 * Coordinates: right-handed, Y up, scene units. Angles in the JSON are degrees.
 * Camera: pinhole; image row 0 is the top; pixel (px, py) covers [px, px+1) x [py, py+1) and its
 * centre is (px + 0.5, py + 0.5). fov_y_deg is the full vertical field of view.
 * Lighting: SH coefficients per colour channel, sh[i][ch] for i < sh_bands^2 (index l*l + l + m),
 * radiance units; projected from an equirectangular environment map or given in the JSON.
 * Equirectangular maps: column u in [0,1) is the azimuth, row v in [0,1) the polar angle from +Y
 * (row 0 = zenith, image centre = -Z); see pen_envmap_direction for the exact map.
 */
#ifndef PENUMBRA_SCENE_H
#define PENUMBRA_SCENE_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/mesh.h"
#include "penumbra/sh.h"
#include "penumbra/spheres.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pen_camera {
    int width, height;
    float fov_y_deg;
    float eye[3], target[3], up[3];
} pen_camera;

/* Orthonormal camera frame: right, up (true up), forward (towards target). */
PEN_API void pen_camera_frame(const pen_camera *cam, float right[3], float up[3], float forward[3]);
/* The unit direction of the ray through image point (px, py) (pixel units, row 0 top). */
PEN_API void pen_camera_ray(const pen_camera *cam, float px, float py, float dir[3]);

/* Rigid pose with uniform scale: p_world = R(axis_angle) * (scale * p_object) + translation. */
typedef struct pen_pose {
    float rotation_axis_angle_deg[3]; /* axis * angle, degrees; zero vector = identity */
    float translation[3];
    float scale;
} pen_pose;

/* 3x3 rotation matrix (row-major) of an axis-angle vector in degrees. */
PEN_API void pen_pose_rotation(const pen_pose *pose, float R[9]);
/* Applies the pose to a point. */
PEN_API void pen_pose_apply(const pen_pose *pose, const float p[3], float out[3]);

typedef struct pen_object {
    pen_mesh mesh;          /* object space */
    pen_image texture;      /* albedo texture (linear RGB), data == NULL if constant albedo */
    float albedo[3];        /* constant albedo (used when texture.data == NULL) */
    pen_spheres spheres;    /* object space; empty when none were given or fit_spheres is set */
    int fit_spheres;        /* "spheres": {"fit": N} asks for N fitted spheres (0: no request);
                               the loader leaves `spheres` empty for the fitter to fill */
    pen_pose pose;
    char *mesh_path;        /* as resolved when loading, for messages and saving */
    char *texture_path;     /* NULL for a constant albedo */
    char *spheres_path;     /* NULL when the spheres were inline, fitted or absent; clear it (free
                               and set NULL) after changing the spheres so that pen_scene_save
                               writes them inline instead of referencing the old file */
} pen_object;

typedef struct pen_ground {
    int enabled;
    float height;           /* the plane y = height */
    float albedo[3];
    float half_size;        /* a square [-h, h] x [-h, h] in x and z */
} pen_ground;

typedef struct pen_lighting {
    float sh[PEN_SH_MAX_COEFFS][3]; /* the lighting used for shading, sh_bands^2 rows */
    pen_image envmap;       /* raw map as loaded (not rotated or scaled); data == NULL if none */
    char *envmap_path;
    float scale;            /* applied to the map (projection and lookups); 1 without a map */
    float rotation_y_deg;   /* applied to the map; 0 without a map */
} pen_lighting;

/* How the spheres of one object add up ("shadow": {"overlap": ...}, docs/file-formats.md). */
typedef enum pen_shadow_overlap {
    PEN_OVERLAP_WEIGHTS = 0, /* sphere i's log-visibility times its overlap weight kappa_i
                                (pen_spheres.weight; computed from the spheres when NULL) */
    PEN_OVERLAP_NONE = 1     /* the plain sum: every kappa_i = 1 */
} pen_shadow_overlap;

/* What the ground plane does to the objects' light ("shadow": {"ground": ...}). */
typedef enum pen_shadow_ground {
    PEN_GROUND_OCCLUDES = 0, /* it hides what lies below the horizon from the objects: each
                                shades with the lighting times the indicator of y > -t, t from
                                its height over the ground (docs/renderer.md) */
    PEN_GROUND_RECEIVER = 1  /* it only receives shadows; the objects see the whole sphere */
} pen_shadow_ground;

typedef struct pen_shadow {
    float epsilon;                  /* log-visibility depth (supplement eq. 6) */
    pen_sh_exp_method exp;
    pen_shadow_overlap overlap;
    pen_shadow_ground ground;
} pen_shadow;

typedef struct pen_scene {
    pen_camera camera;
    int sh_bands;
    pen_lighting lighting;
    pen_shadow shadow;
    int object_count;
    pen_object *objects;
    pen_ground ground;
    int background_envmap;          /* 1: background shows the environment map */
    float background[3];            /* constant background otherwise */
    char *path;                     /* the JSON file, for relative paths and messages */
} pen_scene;

/* Loads a scene JSON (docs/file-formats.md) with everything it references (meshes, textures,
 * sphere sets, envmap), paths relative to the JSON file. Lighting: "envmap" is projected onto
 * sh_bands bands (pen_envmap_to_sh) and kept for the background; "sh" gives the coefficients
 * directly (and wins over the projection when both are present). Errors name the file and the
 * JSON key path, e.g. "scene.json: camera.width: expected a positive integer, got -3"; errors of
 * a referenced file are prefixed with the key that named it. Unknown keys are errors (keys
 * starting with '_' are comments). On failure *out is zeroed. */
PEN_API pen_status pen_scene_load(pen_context *ctx, const char *path, pen_scene *out);
/* The same from JSON text (e.g. a scene embedded in a task file, printed back to text): `path`
 * names the text in messages and is the base of its relative paths. */
PEN_API pen_status pen_scene_parse(pen_context *ctx, const char *json_text, const char *path,
                                   pen_scene *out);
PEN_API void pen_scene_free(pen_scene *scene);
/* Writes a scene JSON that pen_scene_load reads back to the same scene (paths relative to the
 * new file where possible; the referenced files are not written). Atomic. */
PEN_API pen_status pen_scene_save(pen_context *ctx, const char *path, const pen_scene *scene);
/* Flags of pen_scene_save_ex. PEN_SCENE_SAVE_SH_LIGHTING writes the SH coefficients as "sh" even
 * when there is an envmap (which is then written too, for the background): for lighting that was
 * optimized and no longer equals the map's projection. */
#define PEN_SCENE_SAVE_SH_LIGHTING 1u
PEN_API pen_status pen_scene_save_ex(pen_context *ctx, const char *path, const pen_scene *scene,
                                     unsigned flags);

/* Equirectangular maps (Y up). u in [0, 1) is the azimuth phi = 2 pi u, v in [0, 1] the polar
 * angle theta = pi v from +Y:
 *     dir(u, v) = (-sin(theta) sin(phi), cos(theta), sin(theta) cos(phi)).
 * Row 0 is the zenith, the middle row the horizon; the image centre (u = 1/2) is the direction
 * -Z, u = 3/4 is +X, u = 1/4 is -X, and u = 0 is +Z: seen from the origin looking along -Z the
 * map is not mirrored. Pixel (x, y) of a W x H map covers u in [x/W, (x+1)/W), v in
 * [y/H, (y+1)/H).
 * A rotation by rotation_y_deg = a turns the map right-handedly about +Y: map direction d lights
 * the scene from world direction R_y(a) d, R_y(a) (x, y, z) = (cos a x + sin a z, y,
 * -sin a x + cos a z). */
PEN_API void pen_envmap_direction(float u, float v, float dir[3]);
/* The inverse (dir need not be unit length; the zero vector gives u = v = 0). */
PEN_API void pen_envmap_uv(const float dir[3], float *u, float *v);
/* Projects an equirectangular map (1 or >= 3 channels; grey is repeated) onto `bands` bands,
 * after rotating it by rotation_y_deg about +Y and multiplying by scale (finite, >= 0):
 * sh[i][ch] for i < bands^2. Each pixel is weighted by the exact solid angle of its cell,
 * (2 pi / W) (cos theta_top - cos theta_bottom), and sampled at its centre; negative pixel values
 * are clamped to 0. NaN/Inf pixels are an error. */
PEN_API pen_status pen_envmap_to_sh(pen_context *ctx, const pen_image *env, int bands,
                                    float rotation_y_deg, float scale, float sh[][3]);
/* The radiance arriving from world direction dir (the background seen along a camera ray):
 * the map rotated by rotation_y_deg and multiplied by scale, bilinear between texel centres
 * (wrapping in u, clamped in v), negative texels clamped to 0. An invalid map gives black. */
PEN_API void pen_envmap_eval(const pen_image *env, float rotation_y_deg, float scale,
                             const float dir[3], float rgb[3]);

#ifdef __cplusplus
}
#endif
#endif
