/* Scene validation shared by the renderer and the optimizer (src/scene/validate.c): the checks of
 * pen_scene_validate with the caller's name as the messages' first word ("render: ..."). */
#ifndef PEN_SCENE_VALIDATE_H
#define PEN_SCENE_VALIDATE_H

#include "penumbra/scene.h"

pen_status pen__scene_validate(pen_context *ctx, const pen_scene *sc, const char *who);

/* The disk lights alone (part of pen__scene_validate; the scene saver runs it too): a count in
 * [0, PEN_SCENE_MAX_LIGHTS], each direction finite and non-zero, the angular radius and the
 * irradiance in their ranges (penumbra/scene.h), a known mode and lights_max. Messages name the
 * light: "render: lighting.lights[1]: angular_radius_deg 90 outside [0.01, 45]". */
pen_status pen__lights_validate(pen_context *ctx, const pen_lighting *L, const char *who);

#endif
