/* penumbra/scene.h -- a scene: camera, lighting, objects with their sphere proxies, ground plane,
 * background; loaded from the scene JSON of docs/file-formats.md (DESIGN.md section 3).
 *
 * Coordinates: right-handed, Y up, scene units. Angles in the JSON are degrees.
 * Camera: pinhole; image row 0 is the top; pixel (px, py) covers [px, px+1) x [py, py+1) and its
 * centre is (px + 0.5, py + 0.5). fov_y_deg is the full vertical field of view.
 * Lighting: SH coefficients per colour channel, sh[i][ch] for i < sh_bands^2 (index l*l + l + m),
 * radiance units; projected from an equirectangular environment map or given in the JSON.
 * Equirectangular maps: column u in [0,1) is the azimuth, row v in [0,1) the polar angle from +Y
 * (row 0 = zenith); see pen_envmap_direction for the exact map.
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
void pen_camera_frame(const pen_camera *cam, float right[3], float up[3], float forward[3]);
/* The unit direction of the ray through image point (px, py) (pixel units, row 0 top). */
void pen_camera_ray(const pen_camera *cam, float px, float py, float dir[3]);

/* Rigid pose with uniform scale: p_world = R(axis_angle) * (scale * p_object) + translation. */
typedef struct pen_pose {
    float rotation_axis_angle_deg[3]; /* axis * angle, degrees; zero vector = identity */
    float translation[3];
    float scale;
} pen_pose;

/* 3x3 rotation matrix (row-major) of an axis-angle vector in degrees. */
void pen_pose_rotation(const pen_pose *pose, float R[9]);
/* Applies the pose to a point. */
void pen_pose_apply(const pen_pose *pose, const float p[3], float out[3]);

typedef struct pen_object {
    pen_mesh mesh;          /* object space */
    pen_image texture;      /* albedo texture (linear RGB), data == NULL if constant albedo */
    float albedo[3];        /* constant albedo (used when texture.data == NULL) */
    pen_spheres spheres;    /* object space */
    pen_pose pose;
    char *mesh_path;        /* as resolved when loading, for messages and saving */
    char *texture_path;
    char *spheres_path;
} pen_object;

typedef struct pen_ground {
    int enabled;
    float height;           /* the plane y = height */
    float albedo[3];
    float half_size;        /* a square [-h, h] x [-h, h] in x and z */
} pen_ground;

typedef struct pen_lighting {
    float sh[PEN_SH_MAX_COEFFS][3];
    pen_image envmap;       /* data == NULL when lighting is given as SH */
    char *envmap_path;
    float scale;
    float rotation_y_deg;
} pen_lighting;

typedef struct pen_shadow {
    float epsilon;                  /* log-visibility depth (supplement eq. 6) */
    pen_sh_exp_method exp;
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

/* Loads a scene JSON with everything it references (meshes, textures, sphere sets, envmap).
 * Errors name the file and the JSON key path, e.g. "scene.json: camera.width: expected a
 * positive integer, got -3". On failure *out is zeroed. */
pen_status pen_scene_load(pen_context *ctx, const char *path, pen_scene *out);
void pen_scene_free(pen_scene *scene);
/* Writes a scene JSON that pen_scene_load reads back to the same scene (paths relative to the
 * new file where possible). Atomic. */
pen_status pen_scene_save(pen_context *ctx, const char *path, const pen_scene *scene);

/* Equirectangular map: direction of image point (u, v) in [0,1]^2 and back. */
void pen_envmap_direction(float u, float v, float dir[3]);
void pen_envmap_uv(const float dir[3], float *u, float *v);
/* Projects an equirectangular map onto `bands` bands with solid-angle weights, after rotating the
 * map by rotation_y_deg about +Y and multiplying by scale: sh[i][ch]. */
pen_status pen_envmap_to_sh(pen_context *ctx, const pen_image *env, int bands,
                            float rotation_y_deg, float scale, float sh[][3]);

#ifdef __cplusplus
}
#endif
#endif
