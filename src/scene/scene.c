/* The model layer's scene: freeing what a scene owns. The folder src/scene holds the data types
 * every stage shares (scene, mesh, spheres, image, camera, pose) with their create/free/validate
 * and the small differentiable maps defined on them (pose, texture lookup); it depends on
 * src/core only. Reading and writing files is src/io's job; computing on the model (fitting,
 * rasterizing, shading) is the folders above. */
#include "penumbra/scene.h"

#include <stdlib.h>
#include <string.h>

void pen_scene_free(pen_scene *scene) {
    if (!scene) return;
    for (int i = 0; i < scene->object_count; ++i) {
        pen_object *o = &scene->objects[i];
        pen_mesh_free(&o->mesh);
        pen_image_free(&o->texture);
        pen_spheres_free(&o->spheres);
        free(o->mesh_path);
        free(o->texture_path);
        free(o->spheres_path);
    }
    free(scene->objects);
    pen_image_free(&scene->lighting.envmap);
    free(scene->lighting.envmap_path);
    free(scene->path);
    memset(scene, 0, sizeof *scene);
}
