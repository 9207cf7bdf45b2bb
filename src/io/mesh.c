/* Meshes by file extension: pen_mesh_load and pen_mesh_save pick the OBJ or PLY reader/writer.
 * pen_mesh_load also range-checks the vertex positions (|coordinate| <= PEN_SCENE_MAX_COORD,
 * penumbra/scene.h) for both formats in one place, so that a huge but finite coordinate cannot
 * overflow the renderer or the Embree reference downstream; the format readers check syntax and
 * finiteness only. */
#include "io/io_internal.h"
#include "penumbra/io.h"
#include "penumbra/scene.h"

#include <math.h>
#include <string.h>

static pen_status check_positions(pen_context *ctx, const char *path, const pen_mesh *m) {
    for (size_t i = 0; i < 3 * (size_t)m->vertex_count; ++i) {
        const double v = (double)m->positions[i];
        if (fabs(v) <= PEN_SCENE_MAX_COORD) continue;
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: vertex %zu: coordinate %zu: %g outside [-%g, %g]",
                          path, i / 3 + 1, i % 3 + 1, v, PEN_SCENE_MAX_COORD, PEN_SCENE_MAX_COORD);
    }
    return PEN_OK;
}

pen_status pen_mesh_load(pen_context *ctx, const char *path, pen_mesh *out) {
    memset(out, 0, sizeof *out);
    pen_status s;
    if (pen__io_has_ext(path, "obj"))
        s = pen_mesh_load_obj(ctx, path, out);
    else if (pen__io_has_ext(path, "ply"))
        s = pen_mesh_load_ply(ctx, path, out);
    else
        return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                          "%s: unknown mesh format (expected a .obj or .ply file)", path);
    if (!s) s = check_positions(ctx, path, out);
    if (s) pen_mesh_free(out);
    return s;
}

pen_status pen_mesh_save(pen_context *ctx, const char *path, const pen_mesh *mesh) {
    if (pen__io_has_ext(path, "obj")) return pen_mesh_save_obj(ctx, path, mesh);
    return pen__error(ctx, PEN_ERROR_UNSUPPORTED, "%s: meshes are saved as .obj only", path);
}
