/* Internal interface of src/scene/place.c: where objects stand and where the camera looks, from
 * the objects' posed vertices. The scene loader resolves the JSON's "pose": {"on_ground",
 * "centre"} and "camera": {"frame"} with these (so every door gets the same numbers), and the
 * scene check (src/geometry/scene_check.c) measures the objects with the same bounds. */
#ifndef PEN_SCENE_PLACE_H
#define PEN_SCENE_PLACE_H

#include "penumbra/scene.h"

/* Axis-aligned bounds of an object's vertices under its pose, R (scale p) + t, in double (the
 * rotation as pen_pose_rotation gives it, evaluated in double). All zero for a mesh without
 * vertices. */
void pen__object_bounds_d(const pen_object *ob, double lo[3], double hi[3]);

/* Moves an object by changing its pose translation only: with on_ground, vertically so that its
 * lowest posed vertex lies translation[1] above the plane y = ground_y (0: touching it); with
 * centre, in x and z so that the centre of its posed bounds lies at translation[0],
 * translation[2]. Returns 1, or 0 (the pose unchanged) when a resulting translation would leave
 * [-PEN_SCENE_MAX_COORD, PEN_SCENE_MAX_COORD]. */
int pen__object_place(pen_object *ob, int on_ground, double ground_y, int centre);

/* Sets eye, target and up (0, 1, 0) of a camera, keeping its size and intrinsics, so that it
 * frames the posed vertices of `count` objects: it looks at the centre of their bounds from the
 * direction (cos e sin a, sin e, cos e cos a) (a = azimuth_deg about +Y from +Z towards +X, e =
 * elevation_deg above the horizon), from the nearest distance at which every vertex lies within
 * the image shrunk by 1/margin about the principal point (margin >= 1), and at least 10 % of the
 * objects' radius in front of the nearest vertex. Returns 1, or 0 (the camera unchanged) when
 * there is no vertex, or the eye would leave [-PEN_SCENE_MAX_COORD, PEN_SCENE_MAX_COORD] or equal
 * the target in float. */
int pen__camera_frame_objects(pen_camera *cam, const pen_object *objects, int count,
                              double azimuth_deg, double elevation_deg, double margin);

#endif
