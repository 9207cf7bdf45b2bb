/* The scene JSON's placement keys (src/io/scene_place.c), read by src/io/scene.c: an object's
 * "units" and "pose": {"on_ground", "centre"}, and "camera": {"frame"}. Reading them records the
 * request; pen__scene_place carries it out once the objects are loaded. */
#ifndef PEN_IO_SCENE_PLACE_H
#define PEN_IO_SCENE_PLACE_H

#include "io/io_internal.h"

enum { PEN__PLACE_GROUND = 1, PEN__PLACE_CENTRE = 2 };

/* What a file asks to be placed. */
typedef struct pen__placement {
    unsigned char *flags; /* per object, PEN__PLACE_ bits (malloc'd by the objects' reader) */
    int frame;            /* "camera": {"frame": ...} given and not false */
    float azimuth_deg, elevation_deg, margin;
} pen__placement;

/* The "on_ground" and "centre" booleans of the pose object o at w into *flags. */
pen_status pen__scene_pose_place_parse(pen_context *ctx, const pen__json_where *w, const cJSON *o,
                                       unsigned char *flags);
/* The object o's "units" (m, cm, mm, km, in, ft: the mesh file's length unit, the scene being in
 * metres): multiplies pose->scale by that unit in metres, within [1e-6, 1e6]. */
pen_status pen__scene_units_parse(pen_context *ctx, const pen__json_where *w, const cJSON *o,
                                  pen_pose *pose);
/* The root's "camera" into *cam: as pen__io_camera_parse reads it, or, with "frame", its size and
 * intrinsics only (eye, target, up and world_to_camera refused), the frame's settings into *pl. */
pen_status pen__scene_camera_parse(pen_context *ctx, const pen__json_where *top, const cJSON *root,
                                   pen_camera *cam, pen__placement *pl);
/* Carries out *pl on a loaded scene: objects stood on the ground (its height, 0 without one) and
 * centred, then the camera framed on them (src/scene/place.c). Errors name the key. */
pen_status pen__scene_place(pen_context *ctx, const pen__json_where *top, pen_scene *sc,
                            const pen__placement *pl);

#endif
