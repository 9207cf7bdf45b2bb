/* penumbra/scene.h -- the model: a scene (camera, lighting, objects with their sphere proxies,
 * ground plane, background), the camera's frame and rays, and the rigid pose with its backward.
 * Implemented in src/scene, which depends on nothing but src/core (sh.h only gives the lighting's
 * coefficient count and exponential method); files are read and written by penumbra/io.h (the
 * scene JSON of docs/file-formats.md).
 *
 * Coordinates: right-handed, Y up, scene units. Angles in the JSON are degrees.
 * Camera: pinhole; image row 0 is the top; pixel (px, py) covers [px, px+1) x [py, py+1) and its
 * centre is (px + 0.5, py + 0.5). fov_y_deg is the full vertical field of view.
 * Lighting: SH coefficients per colour channel, sh[i][ch] for i < sh_bands^2 (index l*l + l + m),
 * radiance units; projected from an equirectangular environment map or given in the JSON. On top
 * of it, up to PEN_SCENE_MAX_LIGHTS distant disk lights (suns, lamps), each with its own shadow
 * (docs/design.md §1.13).
 * Equirectangular maps: column u in [0,1) is the azimuth, row v in [0,1) the polar angle from +Y
 * (row 0 = zenith, image centre = -Z); see pen_envmap_direction (penumbra/envmap.h).
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

/* Ranges the loaders (scene JSON, sphere JSON, OBJ/PLY through pen_mesh_load) accept, so that
 * every finite value they accept stays finite through the renderer, its backward and the Embree
 * reference (docs/file-formats.md, "Value ranges"). They are generous: a scene in millimetres or
 * in kilometres fits. World-space coordinates stay below about 2e12 (1e6 scale times 1e6
 * coordinates plus 1e6 translation), far from Embree's limit near 1.8e18, and squared distances
 * below 1e25 in float. The lighting bounds leave the shaded radiance below about 1e34. */
#define PEN_SCENE_MAX_COORD 1e6    /* |coordinate|: mesh vertices, sphere centres, camera eye,
                                      target and up, pose translation, ground height */
#define PEN_SCENE_MIN_SIZE 1e-6    /* pose scale, ground half size: at least this */
#define PEN_SCENE_MAX_SIZE 1e6     /* pose scale, sphere radius, ground half size: at most */
#define PEN_SCENE_MIN_RADIUS 1e-9  /* sphere radius: at least (1 / r^2 stays finite) */
#define PEN_SCENE_MAX_WEIGHT 1e6   /* sphere overlap weight */
#define PEN_SCENE_MAX_RADIANCE 1e9 /* |environment map value|, background value */
#define PEN_SCENE_MAX_LIGHT_SCALE 1e3 /* lighting.scale */
#define PEN_SCENE_MAX_SH 1e13      /* |lighting SH coefficient|, given or projected */
#define PEN_SCENE_MAX_ALBEDO 1e6   /* |texture value| (constant albedos are in [0, 1]) */
#define PEN_SCENE_MAX_LIGHTS 16    /* disk lights in one scene */
#define PEN_SCENE_MIN_LIGHT_RADIUS_DEG 0.01 /* a disk light's angular radius: at least */
#define PEN_SCENE_MAX_LIGHT_RADIUS_DEG 45.0 /* ... and at most */
#define PEN_SCENE_MAX_IRRADIANCE 1e9 /* |disk light irradiance| */
#define PEN_LIGHTS_DEFAULT_MAX 4    /* lights_max when lighting.lights is absent (PEN_LIGHTS_AUTO) */

/* A pinhole camera. Extrinsics: eye, target and up (a calibrated world-to-camera pose R, t is
 * converted to these by the loader: docs/file-formats.md). Intrinsics: fov_y_deg with square
 * pixels and the principal point at the image centre, or, when fx > 0, the calibrated focal
 * lengths and principal point in pixels (fx, fy, cx, cy), measured from the image's top-left
 * corner with pixel centres at +0.5 (COLMAP's convention; OpenCV's cx, cy are 0.5 smaller).
 * With fx > 0, fov_y_deg is informational (2 atan(height / (2 fy)), set by the loader). */
typedef struct pen_camera {
    int width, height;
    float fov_y_deg;
    float eye[3], target[3], up[3];
    float fx, fy, cx, cy;   /* all 0: from fov_y_deg (the look-at camera) */
} pen_camera;

/* Most focal length in pixels, and most distance of the principal point from the image. */
#define PEN_CAMERA_MAX_FOCAL 1e7
#define PEN_CAMERA_MAX_PRINCIPAL 1e6

/* Checks a camera: size in [1, PEN_IMAGE_MAX_DIM] each way; fov_y_deg in (0, 180) for a look-at
 * camera, or fx, fy in (0, PEN_CAMERA_MAX_FOCAL] and finite cx, cy within
 * PEN_CAMERA_MAX_PRINCIPAL pixels of the image; finite eye, target and up, eye != target.
 * Messages begin with "camera: ". */
PEN_API pen_status pen_camera_validate(pen_context *ctx, const pen_camera *cam);
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

/* Gradient of a pose (the backward beside its forward): the same fields as pen_pose, holding
 * d/d(field). */
typedef pen_pose pen_pose_grad;

/* Backward of pen_pose_apply: with out = R(a) * (scale * p) + t, adds d_out's pull-back into
 * d_pose (rotation_axis_angle_deg per degree, translation, scale) and d_p (each may be NULL).
 * Exact at and near angle 0 (series expansion of the Rodrigues coefficients). */
PEN_API void pen_pose_apply_bwd(const pen_pose *pose, const float p[3], const float d_out[3],
                                pen_pose_grad *d_pose, float d_p[3]);
/* pen_pose_apply over n points (3 floats each). `out` may not alias `p`. */
PEN_API void pen_pose_points_fwd(const pen_pose *pose, int n, const float *p, float *out);
/* Backward of pen_pose_points_fwd; reduces over the points in double. */
PEN_API void pen_pose_points_bwd(const pen_pose *pose, int n, const float *p, const float *d_out,
                                 pen_pose_grad *d_pose, float *d_p);

/* How an object's albedo texture relates to its mesh file (pen_object.texture_layout). */
typedef enum pen_texture_layout {
    PEN_TEXTURE_LAYOUT_FILE = 0, /* addressed by the mesh file's own UVs */
    PEN_TEXTURE_LAYOUT_BAKED = 1 /* an atlas pen_mesh_bake_albedo made from the mesh file's
                                    materials or vertex colours; the mesh holds the atlas UVs.
                                    Saved scenes name the mesh file only (it is baked again on
                                    loading), or, when texture_path is set (an optimised atlas),
                                    also the texture with "albedo_texture_layout": "baked" */
} pen_texture_layout;

/* How the renderer looks up an object's albedo texture (pen_object.texture_filter, the scene's
 * "texture_filter"). The reference renderer always takes point lookups, averaged over its own
 * samples in each pixel. */
typedef enum pen_texture_filter {
    PEN_TEXTURE_FILTER_FOOTPRINT = 0, /* "footprint": the bilinear lookup averaged over a fixed
                                         grid across the pixel's footprint on the texture (a box
                                         filter over the pixel; docs/design.md sec. 1.4) */
    PEN_TEXTURE_FILTER_POINT = 1      /* "point": one bilinear lookup at the pixel centre's uv */
} pen_texture_filter;

typedef struct pen_object {
    pen_mesh mesh;          /* object space */
    pen_image texture;      /* albedo texture (linear RGB, 3 channels), NULL data: constant */
    float albedo[3];        /* constant albedo (used when texture.data == NULL) */
    pen_spheres spheres;    /* object space; empty when none were given or fit_spheres is set */
    int fit_spheres;        /* "spheres": {"fit": N} asks for N fitted spheres (0: no request);
                               the loader leaves `spheres` empty for the fitter to fill */
    pen_pose pose;
    char *mesh_path;        /* as resolved when loading, for messages and saving */
    char *texture_path;     /* NULL for a constant albedo, and for a baked atlas as baked */
    pen_texture_layout texture_layout;
    pen_texture_filter texture_filter;
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

/* A distant disk light: a uniformly bright disk on the sky (the sun, a lamp, a window seen from
 * afar). Its radiance is irradiance / (pi sin^2 b), b the angular radius (the disk's projected
 * solid angle seen face on; about its solid angle for small disks), so a surface facing it, with
 * nothing in the way, receives exactly `irradiance` (per colour channel, linear). */
typedef struct pen_light {
    float direction[3];        /* from the scene towards the light's centre, unit length (the
                                  renderer normalises any non-zero vector; its gradient is of
                                  the vector as stored) */
    float angular_radius_deg;  /* half the apex angle of the disk, in
                                  [PEN_SCENE_MIN_LIGHT_RADIUS_DEG, PEN_SCENE_MAX_LIGHT_RADIUS_DEG] */
    float irradiance[3];
} pen_light;

/* A disk light as a row of floats, the layout the flat API (flat.h: pen_flat_scene.lights,
 * pen_flat_grad.lights), the Python binding (python/penumbra/_lib.py LIGHT_FLOATS) and the
 * optimizer's parameter vector share: pen_light's fields in order, direction (3), angular radius
 * in degrees, irradiance (3). */
#define PEN_LIGHT_FLOATS 7
#define PEN_LIGHT_OFFSET_DIRECTION 0  /* 3 floats */
#define PEN_LIGHT_OFFSET_RADIUS 3     /* 1 float */
#define PEN_LIGHT_OFFSET_IRRADIANCE 4 /* 3 floats */

/* Where a scene's disk lights come from (lighting.lights in the JSON). */
typedef enum pen_lights_mode {
    PEN_LIGHTS_AUTO = 0,  /* found in the environment map (up to lights_max), none without one,
                             then the lights_added listed under "add" */
    PEN_LIGHTS_NONE = 1,  /* "none": SH lighting only */
    PEN_LIGHTS_GIVEN = 2  /* listed in the JSON (or set by the caller) */
} pen_lights_mode;

typedef struct pen_lighting {
    float sh[PEN_SH_MAX_COEFFS][3]; /* the lighting used for shading, sh_bands^2 rows */
    int light_count;                /* disk lights in use, <= PEN_SCENE_MAX_LIGHTS */
    pen_light lights[PEN_SCENE_MAX_LIGHTS];
    pen_lights_mode lights_mode;
    int lights_max;                 /* PEN_LIGHTS_AUTO: at most this many lights are extracted */
    int lights_added;               /* PEN_LIGHTS_AUTO: the last lights_added of lights[] were
                                       listed ({"max": K, "add": [...]}), the others found in the
                                       map; ignored in the other modes (0 by default) */
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

/* What darkens an object's own surface ("shadow": {"self": ...}, docs/design.md sec. 1.15). */
typedef enum pen_shadow_self {
    PEN_SELF_TRANSFER = 0, /* exact visibility of the object's own mesh, ray traced per vertex
                              and cached (pose- and shape-constant: no gradient through it);
                              the other objects' spheres as before */
    PEN_SELF_SPHERES = 1   /* the object's own spheres, like every other occluder */
} pen_shadow_self;

/* What darkens the ground under objects whose own shadows use the transfer ("shadow":
 * {"ground_shadow": ...}, docs/design.md sec. 1.15). */
typedef enum pen_shadow_ground_shadow {
    PEN_GROUND_SHADOW_TRANSFER = 0, /* exact visibility of those objects' meshes, ray traced at
                                       a warped grid of nodes over the ground square and cached
                                       (no gradient through it); the other objects' spheres as
                                       before. Only where the objects' self transfer is on */
    PEN_GROUND_SHADOW_SPHERES = 1   /* every object's spheres, as on any other receiver */
} pen_shadow_ground_shadow;

/* Bounds of "shadow": {"ground_grid": N}, the ground transfer's nodes per side (0: the
 * renderer's default). */
#define PEN_GROUND_GRID_MIN 2
#define PEN_GROUND_GRID_MAX 1024

typedef struct pen_shadow {
    float epsilon;                  /* log-visibility depth (supplement eq. 6) */
    pen_sh_exp_method exp;
    pen_shadow_overlap overlap;
    pen_shadow_ground ground;
    pen_shadow_self self;
    pen_shadow_ground_shadow ground_shadow;
    int ground_grid; /* nodes per side of the ground transfer's grid; 0: the default */
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

/* Frees everything a scene owns (meshes, textures, sphere sets, the envmap, the paths) and
 * zeroes it; NULL is a no-op. Scenes come from pen_scene_load (penumbra/io.h) or are built in
 * memory from arrays allocated with malloc. */
PEN_API void pen_scene_free(pen_scene *scene);

/* Checks that a scene can be rendered and optimised: SH bands and finite coefficients, known
 * shadow modes, the object list, finite background and ground, an environment map when the
 * background shows one, each object's mesh (pen_mesh_validate), texture (RGB, with UVs, finite)
 * or albedo, pose (finite, scale > 0), sphere set (finite centres, radii > 0, weights finite and
 * >= 0 when present), and the camera (pen_camera_validate). The first problem is reported, e.g.
 * "scene: objects[2] (spot.obj): sphere 7: needs a finite center and a radius > 0". The
 * renderer and the optimizer run the same checks (their messages begin with "render: "). */
PEN_API pen_status pen_scene_validate(pen_context *ctx, const pen_scene *scene);

#ifdef __cplusplus
}
#endif
#endif
