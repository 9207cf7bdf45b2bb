/* Scene validation shared by the renderer and the optimizer (src/scene/validate.c): the checks of
 * pen_scene_validate with the caller's name as the messages' first word ("render: ..."). */
#ifndef PEN_SCENE_VALIDATE_H
#define PEN_SCENE_VALIDATE_H

#include "penumbra/scene.h"

pen_status pen__scene_validate(pen_context *ctx, const pen_scene *sc, const char *who);

#endif
