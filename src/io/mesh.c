/* Meshes by file extension: pen_mesh_load and pen_mesh_save pick the OBJ or PLY reader/writer. */
#include "io/io_internal.h"
#include "penumbra/io.h"

#include <string.h>

pen_status pen_mesh_load(pen_context *ctx, const char *path, pen_mesh *out) {
    memset(out, 0, sizeof *out);
    if (pen__io_has_ext(path, "obj")) return pen_mesh_load_obj(ctx, path, out);
    if (pen__io_has_ext(path, "ply")) return pen_mesh_load_ply(ctx, path, out);
    return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                      "%s: unknown mesh format (expected a .obj or .ply file)", path);
}

pen_status pen_mesh_save(pen_context *ctx, const char *path, const pen_mesh *mesh) {
    if (pen__io_has_ext(path, "obj")) return pen_mesh_save_obj(ctx, path, mesh);
    return pen__error(ctx, PEN_ERROR_UNSUPPORTED, "%s: meshes are saved as .obj only", path);
}
