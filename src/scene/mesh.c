/* Triangle meshes as data: freeing, bounds and validation (the checks every loader's result and
 * every mesh built in memory must pass). File formats are src/io's (obj.c, ply.c, mesh.c). */
#include "penumbra/mesh.h"
#include "core/internal.h"

#include <stdlib.h>
#include <string.h>

void pen_mesh_free(pen_mesh *mesh) {
    if (!mesh) return;
    free(mesh->positions);
    free(mesh->indices);
    free(mesh->uvs);
    free(mesh->uv_indices);
    free(mesh->normals);
    free(mesh->normal_indices);
    free(mesh->texture_path);
    for (int i = 0; mesh->materials && i < mesh->material_count; ++i) {
        free(mesh->materials[i].name);
        free(mesh->materials[i].texture_path);
        free(mesh->materials[i].texture_source);
    }
    free(mesh->materials);
    free(mesh->triangle_materials);
    free(mesh->colors);
    memset(mesh, 0, sizeof *mesh);
}

void pen_mesh_bounds(const pen_mesh *mesh, float lo[3], float hi[3]) {
    for (int k = 0; k < 3; ++k) {
        lo[k] = mesh->vertex_count > 0 ? mesh->positions[k] : 0.0f;
        hi[k] = lo[k];
    }
    for (int i = 1; i < mesh->vertex_count; ++i) {
        const float *p = mesh->positions + 3 * (size_t)i;
        for (int k = 0; k < 3; ++k) {
            lo[k] = p[k] < lo[k] ? p[k] : lo[k];
            hi[k] = p[k] > hi[k] ? p[k] : hi[k];
        }
    }
}

/* Every index of `which` below count. */
static pen_status check_indices(pen_context *ctx, const uint32_t *idx, int triangles, int count,
                                const char *which) {
    for (size_t c = 0; c < 3 * (size_t)triangles; ++c)
        if (idx[c] >= (uint32_t)count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "mesh: triangle %zu: %s index %u out of range [0, %d)", c / 3, which,
                              idx[c], count);
    return PEN_OK;
}

static pen_status check_finite(pen_context *ctx, const float *v, int count, int dim,
                               const char *which) {
    for (size_t i = 0; i < (size_t)count * (size_t)dim; ++i)
        if (!isfinite(v[i]))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: %s %zu is not finite", which,
                              i / (size_t)dim);
    return PEN_OK;
}

/* Material entries with names, Kd in [0, 1] when given, and every triangle's index in
 * [-1, material_count). */
static pen_status check_materials(pen_context *ctx, const pen_mesh *mesh) {
    if (mesh->material_count < 0 || mesh->material_count > PEN_MESH_MAX_MATERIALS ||
        (mesh->material_count > 0 && (!mesh->materials || !mesh->triangle_materials)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: material count %d or its arrays invalid",
                          mesh->material_count);
    for (int i = 0; i < mesh->material_count; ++i) {
        const pen_mesh_material *m = &mesh->materials[i];
        if (!m->name)
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: material %d has no name", i);
        for (int k = 0; m->has_kd && k < 3; ++k)
            if (!(m->kd[k] >= 0.0f && m->kd[k] <= 1.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "mesh: material %d (%s): Kd %g outside [0, 1]", i, m->name,
                                  (double)m->kd[k]);
    }
    for (int t = 0; mesh->material_count > 0 && t < mesh->triangle_count; ++t)
        if (mesh->triangle_materials[t] < -1 || mesh->triangle_materials[t] >= mesh->material_count)
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "mesh: triangle %d: material index %d out of range [-1, %d)", t,
                              (int)mesh->triangle_materials[t], mesh->material_count);
    return PEN_OK;
}

static pen_status check_colors(pen_context *ctx, const pen_mesh *mesh) {
    for (size_t i = 0; i < 3 * (size_t)mesh->vertex_count; ++i)
        if (!(mesh->colors[i] >= 0.0f && mesh->colors[i] <= 1.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: vertex %zu: colour %g outside [0, 1]",
                              i / 3, (double)mesh->colors[i]);
    return PEN_OK;
}

pen_status pen_mesh_validate(pen_context *ctx, const pen_mesh *mesh) {
    if (!mesh || mesh->vertex_count <= 0 || mesh->triangle_count <= 0 || !mesh->positions ||
        !mesh->indices)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: no vertices or no triangles");
    if ((size_t)mesh->vertex_count > PEN_MAX_ELEMENTS ||
        (size_t)mesh->triangle_count > PEN_MAX_ELEMENTS ||
        (size_t)mesh->uv_count > PEN_MAX_ELEMENTS ||
        (size_t)mesh->normal_count > PEN_MAX_ELEMENTS || mesh->uv_count < 0 ||
        mesh->normal_count < 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: counts out of range");
    if ((mesh->uv_count > 0 && (!mesh->uvs || !mesh->uv_indices)) ||
        (mesh->normal_count > 0 && (!mesh->normals || !mesh->normal_indices)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "mesh: missing UV or normal arrays");
    pen_status s = check_finite(ctx, mesh->positions, mesh->vertex_count, 3, "vertex");
    if (!s)
        s = check_indices(ctx, mesh->indices, mesh->triangle_count, mesh->vertex_count, "vertex");
    if (!s && mesh->uv_count > 0) {
        s = check_finite(ctx, mesh->uvs, mesh->uv_count, 2, "texture coordinate");
        if (!s)
            s = check_indices(ctx, mesh->uv_indices, mesh->triangle_count, mesh->uv_count,
                              "texture coordinate");
    }
    if (!s && mesh->normal_count > 0) {
        s = check_finite(ctx, mesh->normals, mesh->normal_count, 3, "normal");
        if (!s)
            s = check_indices(ctx, mesh->normal_indices, mesh->triangle_count, mesh->normal_count,
                              "normal");
    }
    if (!s) s = check_materials(ctx, mesh);
    if (!s && mesh->colors) s = check_colors(ctx, mesh);
    return s;
}
