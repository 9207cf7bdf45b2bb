/* A mesh's materials and vertex colours as one albedo texture (pen_mesh_albedo_plan,
 * pen_mesh_bake_albedo; penumbra/mesh.h).
 *
 * Design
 * - The renderer, both shading kernels, the reference renderer, the optimizer's albedo group and
 *   the flat API all read one texture per object through one lookup (src/scene/texture.c:
 *   bilinear between texel centres u = (i + 0.5) / W, v = 1 - (j + 0.5) / H, repeat wrap). Rather
 *   than teach each of them about materials, a mesh with several albedo sources is baked into an
 *   atlas and its UVs rewritten, once, when the scene is loaded; everything downstream is
 *   unchanged, and an optimised albedo is still one image.
 * - Exactness. A textured material's tile holds its texture repeated reps_u x reps_v times (each
 *   face's UVs are first shifted by whole periods so that their minimum lies in [0, 1)), framed
 *   by GUTTER texels continuing the repetition. A lookup at a face point then reads the same four
 *   texels with the same weights as the lookup in the material's own texture with repeat wrap;
 *   the gutter only needs one texel for that, the second absorbs the rounding of the rewritten
 *   UVs (float UVs in a 16384-texel atlas are good to about 1e-3 texel). Vertex colours get a 4x4
 *   block per triangle holding the linear function f(x, y) = c0 + (x - 1)(c1 - c0) +
 *   (y - 1)(c2 - c0) of the texel position, the corners at the centres of texels (1, 1), (2, 1),
 *   (1, 2): bilinear interpolation of a linear function is that function, so the lookup at the
 *   point with barycentrics (b0, b1, b2) is b0 c0 + b1 c1 + b2 c2, within the triangle and half a
 *   texel beyond it. Texel (2, 2) may leave [0, 1] (it is c1 + c2 - c0); it must, for exactness.
 * - Packing: tiles are placed on shelves, tallest first, in an atlas about as wide as the square
 *   root of their total area; simple, and within a few percent of optimal for the few tiles a
 *   mesh has. Colour blocks fill a grid.
 */
#include "core/internal.h"
#include "penumbra/mesh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define GUTTER 2
#define CONST_TILE 4 /* a constant tile's side; its centre lies between four equal texels */
#define BLOCK 4      /* a vertex-colour block's side */

pen_mesh_albedo_kind pen_mesh_albedo_plan(const pen_mesh *mesh, int *material) {
    if (material) *material = -1;
    if (mesh->colors) return PEN_MESH_ALBEDO_BAKE;
    if (mesh->material_count <= 0 || !mesh->triangle_materials || mesh->triangle_count <= 0)
        return mesh->texture_path ? PEN_MESH_ALBEDO_TEXTURE : PEN_MESH_ALBEDO_DEFAULT;
    const int32_t first = mesh->triangle_materials[0];
    for (int t = 1; t < mesh->triangle_count; ++t)
        if (mesh->triangle_materials[t] != first) return PEN_MESH_ALBEDO_BAKE;
    if (first < 0) return PEN_MESH_ALBEDO_DEFAULT;
    if (material) *material = first;
    const pen_mesh_material *m = &mesh->materials[first];
    if (m->texture_path) return PEN_MESH_ALBEDO_TEXTURE;
    return m->has_kd ? PEN_MESH_ALBEDO_CONSTANT : PEN_MESH_ALBEDO_DEFAULT;
}

/* One tile of the atlas: a material's (or, last, the faces without one). */
typedef struct tile {
    int used, textured;
    int reps_u, reps_v;
    int w, h, x, y;
    float rgb[3]; /* constant tiles */
} tile;

typedef struct atlas_size {
    int w, h;
} atlas_size;

static pen_status check_size(pen_context *ctx, long long w, long long h) {
    if (w >= 1 && h >= 1 && w <= PEN_IMAGE_MAX_DIM && h <= PEN_IMAGE_MAX_DIM &&
        w * h <= PEN_IMAGE_MAX_PIXELS)
        return PEN_OK;
    return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                      "bake: the albedo atlas would be %lld x %lld texels (limits: %d a side, %lld "
                      "in all); use fewer or smaller textures, or fewer triangles",
                      w, h, PEN_IMAGE_MAX_DIM, (long long)PEN_IMAGE_MAX_PIXELS);
}

static int mod_int(long a, int n) {
    long r = a % n;
    return (int)(r < 0 ? r + n : r);
}

/* Corner k of triangle t's UV. */
static const float *corner_uv(const pen_mesh *m, int t, int k) {
    return m->uvs + 2 * (size_t)m->uv_indices[3 * (size_t)t + (size_t)k];
}

/* ---- Material tiles -------------------------------------------------------------------------- */

/* The tiles the faces use, with sizes; slot material_count stands for "no material". */
static pen_status plan_tiles(pen_context *ctx, const pen_mesh *m, const pen_image *textures,
                             const float def[3], tile *tiles) {
    const int n = m->material_count;
    for (int t = 0; t < m->triangle_count; ++t) {
        int32_t mi = m->triangle_materials ? m->triangle_materials[t] : -1;
        tile *tl = &tiles[mi < 0 ? n : mi];
        if (!tl->used) {
            tl->used = 1;
            tl->reps_u = tl->reps_v = 1;
            tl->textured = mi >= 0 && textures && textures[mi].data;
            const float *c = mi >= 0 && m->materials[mi].has_kd ? m->materials[mi].kd : def;
            memcpy(tl->rgb, c, sizeof tl->rgb);
            const pen_image *tx = tl->textured ? &textures[mi] : NULL;
            if (tx && (tx->width < 1 || tx->height < 1 || tx->channels < 1 || tx->channels > 4))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "bake: material '%s': texture of %d x %d pixels, %d channels",
                                  m->materials[mi].name, tx->width, tx->height, tx->channels);
            if (tl->textured && m->uv_count == 0)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "bake: material '%s' has a texture but the mesh has no texture "
                                  "coordinates",
                                  m->materials[mi].name);
        }
        if (!tl->textured) continue;
        for (int axis = 0; axis < 2; ++axis) {
            double lo = INFINITY, hi = -INFINITY;
            for (int k = 0; k < 3; ++k) {
                const double c = corner_uv(m, t, k)[axis];
                lo = c < lo ? c : lo;
                hi = c > hi ? c : hi;
            }
            const double extent = hi - floor(lo);
            int reps =
                extent > PEN_MESH_BAKE_MAX_REPEATS ? PEN_MESH_BAKE_MAX_REPEATS : (int)ceil(extent);
            int *r = axis == 0 ? &tl->reps_u : &tl->reps_v;
            *r = reps > *r ? reps : *r;
        }
    }
    for (int i = 0; i <= n; ++i) {
        tile *tl = &tiles[i];
        if (!tl->used) continue;
        if (tl->textured) {
            const long long w = (long long)textures[i].width * tl->reps_u + 2 * GUTTER;
            const long long h = (long long)textures[i].height * tl->reps_v + 2 * GUTTER;
            pen_status s = check_size(ctx, w, h);
            if (s) return s;
            tl->w = (int)w;
            tl->h = (int)h;
        } else {
            tl->w = tl->h = CONST_TILE;
        }
    }
    return PEN_OK;
}

/* A tile's place in the packing order: tallest first, then by material. */
typedef struct order_key {
    int h, index;
} order_key;

static int by_height(const void *a, const void *b) {
    const order_key *ka = a, *kb = b;
    if (ka->h != kb->h) return ka->h > kb->h ? -1 : 1;
    return ka->index - kb->index;
}

/* Shelf packing, tallest first, into a width of about sqrt(total area). */
static pen_status pack_tiles(pen_context *ctx, tile *tiles, int count, atlas_size *out) {
    order_key *order = pen__malloc(ctx, (size_t)count, sizeof *order, "bake");
    if (!order) return PEN_ERROR_MEMORY;
    int used = 0, widest = 0;
    double area = 0.0;
    for (int i = 0; i < count; ++i) {
        if (!tiles[i].used) continue;
        order[used].h = tiles[i].h;
        order[used++].index = i;
        widest = tiles[i].w > widest ? tiles[i].w : widest;
        area += (double)tiles[i].w * tiles[i].h;
    }
    qsort(order, (size_t)used, sizeof *order, by_height);
    double target = ceil(sqrt(area));
    if (target > PEN_IMAGE_MAX_DIM) target = PEN_IMAGE_MAX_DIM;
    const long long width = target > widest ? (long long)target : widest;
    long long x = 0, y = 0, shelf = 0, right = 0;
    for (int k = 0; k < used; ++k) {
        tile *tl = &tiles[order[k].index];
        if (x + tl->w > width) {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        tl->x = (int)x;
        tl->y = (int)(y < INT32_MAX ? y : INT32_MAX);
        x += tl->w;
        right = x > right ? x : right;
        shelf = tl->h > shelf ? tl->h : shelf;
    }
    free(order);
    out->w = (int)right;
    out->h = (int)(y + shelf < INT32_MAX ? y + shelf : INT32_MAX);
    return check_size(ctx, right, y + shelf);
}

static void fill_tile(const tile *tl, const pen_image *tex, pen_image *atlas) {
    const size_t aw = (size_t)atlas->width;
    for (int y = 0; y < tl->h; ++y) {
        float *row = atlas->data + 3 * (aw * (size_t)(tl->y + y) + (size_t)tl->x);
        if (!tl->textured) {
            for (int x = 0; x < tl->w; ++x)
                memcpy(row + 3 * x, tl->rgb, sizeof tl->rgb);
            continue;
        }
        const int nch = tex->channels;
        const int j = mod_int((long)y - GUTTER, tex->height);
        for (int x = 0; x < tl->w; ++x) {
            const int i = mod_int((long)x - GUTTER, tex->width);
            const size_t at = (size_t)j * (size_t)tex->width + (size_t)i;
            const float *src = tex->data + at * (size_t)nch;
            for (int ch = 0; ch < 3; ++ch)
                row[3 * x + ch] = src[ch < nch ? ch : nch - 1];
        }
    }
}

/* The atlas UVs of triangle t's corners (6 floats). A face whose UVs span more than
 * PEN_MESH_BAKE_MAX_REPEATS periods has them clamped to the tile. */
static void tile_uvs(const pen_mesh *m, int t, const tile *tl, const pen_image *tex,
                     const atlas_size *as, float *out) {
    double shift[2] = {0.0, 0.0};
    if (tl->textured)
        for (int axis = 0; axis < 2; ++axis) {
            double lo = INFINITY;
            for (int k = 0; k < 3; ++k) {
                const double c = corner_uv(m, t, k)[axis];
                lo = c < lo ? c : lo;
            }
            shift[axis] = floor(lo);
        }
    for (int k = 0; k < 3; ++k) {
        double X = tl->x + 0.5 * CONST_TILE, Y = tl->y + 0.5 * CONST_TILE;
        if (tl->textured) {
            const float *uv = corner_uv(m, t, k);
            double u = (double)uv[0] - shift[0], v = (double)uv[1] - shift[1];
            u = u > tl->reps_u ? tl->reps_u : u;
            v = v > tl->reps_v ? tl->reps_v : v;
            X = tl->x + GUTTER + u * tex->width;
            Y = tl->y + GUTTER + (tl->reps_v - v) * tex->height;
        }
        out[2 * k] = (float)(X / as->w);
        out[2 * k + 1] = (float)(1.0 - Y / as->h);
    }
}

static pen_status bake_materials(pen_context *ctx, const pen_mesh *m, const pen_image *textures,
                                 const float def[3], pen_image *atlas, float *uvs) {
    const int n = m->material_count > 0 ? m->material_count : 0;
    tile *tiles = pen__calloc(ctx, (size_t)n + 1, sizeof *tiles, "bake");
    if (!tiles) return PEN_ERROR_MEMORY;
    atlas_size as = {0, 0};
    pen_status s = plan_tiles(ctx, m, textures, def, tiles);
    if (!s) s = pack_tiles(ctx, tiles, n + 1, &as);
    if (!s) s = pen_image_create(ctx, as.w, as.h, 3, atlas);
    for (int i = 0; !s && i <= n; ++i)
        if (tiles[i].used) fill_tile(&tiles[i], tiles[i].textured ? &textures[i] : NULL, atlas);
    for (int t = 0; !s && t < m->triangle_count; ++t) {
        const int32_t mi = m->triangle_materials ? m->triangle_materials[t] : -1;
        const int slot = mi < 0 ? n : mi;
        tile_uvs(m, t, &tiles[slot], tiles[slot].textured ? &textures[slot] : NULL, &as,
                 uvs + 6 * (size_t)t);
    }
    free(tiles);
    return s;
}

/* ---- Vertex colours -------------------------------------------------------------------------- */

static pen_status bake_colors(pen_context *ctx, const pen_mesh *m, pen_image *atlas, float *uvs) {
    const long long tris = m->triangle_count;
    long long cols = (long long)ceil(sqrt((double)tris));
    if (cols * BLOCK > PEN_IMAGE_MAX_DIM) cols = PEN_IMAGE_MAX_DIM / BLOCK;
    const long long rows = (tris + cols - 1) / cols;
    pen_status s = check_size(ctx, cols * BLOCK, rows * BLOCK);
    if (!s) s = pen_image_create(ctx, (int)(cols * BLOCK), (int)(rows * BLOCK), 3, atlas);
    if (s) return s;
    const size_t aw = (size_t)atlas->width;
    const double W = atlas->width, H = atlas->height;
    /* The corners sit on the centres of texels (1, 1), (2, 1), (1, 2) of their block. */
    static const int cx[3] = {1, 2, 1}, cy[3] = {1, 1, 2};
    for (int t = 0; t < m->triangle_count; ++t) {
        const size_t bx = (size_t)(t % cols) * BLOCK, by = (size_t)(t / cols) * BLOCK;
        const uint32_t *tri = m->indices + 3 * (size_t)t;
        const float *c0 = m->colors + 3 * (size_t)tri[0];
        const float *c1 = m->colors + 3 * (size_t)tri[1];
        const float *c2 = m->colors + 3 * (size_t)tri[2];
        for (int y = 0; y < BLOCK; ++y)
            for (int x = 0; x < BLOCK; ++x) {
                float *px = atlas->data + 3 * ((by + (size_t)y) * aw + bx + (size_t)x);
                for (int ch = 0; ch < 3; ++ch)
                    px[ch] = c0[ch] + (float)(x - 1) * (c1[ch] - c0[ch]) +
                             (float)(y - 1) * (c2[ch] - c0[ch]);
            }
        for (int k = 0; k < 3; ++k) {
            uvs[6 * (size_t)t + 2 * (size_t)k] = (float)(((double)bx + cx[k] + 0.5) / W);
            uvs[6 * (size_t)t + 2 * (size_t)k + 1] = (float)(1.0 - ((double)by + cy[k] + 0.5) / H);
        }
    }
    return PEN_OK;
}

/* ---- Entry ----------------------------------------------------------------------------------- */

pen_status pen_mesh_bake_albedo(pen_context *ctx, pen_mesh *mesh, const pen_image *textures,
                                const float default_albedo[3], pen_image *atlas) {
    memset(atlas, 0, sizeof *atlas);
    pen_status s = pen_mesh_validate(ctx, mesh);
    if (s) return s;
    if ((size_t)mesh->triangle_count > PEN_MAX_ELEMENTS / 3)
        return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                          "bake: %d triangles need more texture coordinates than a mesh may have",
                          mesh->triangle_count);
    const size_t corners = 3 * (size_t)mesh->triangle_count;
    float *uvs = pen__malloc(ctx, 2 * corners, sizeof *uvs, "bake");
    uint32_t *uv_indices = pen__malloc(ctx, corners, sizeof *uv_indices, "bake");
    s = uvs && uv_indices ? PEN_OK : PEN_ERROR_MEMORY;
    if (!s && mesh->colors)
        s = bake_colors(ctx, mesh, atlas, uvs);
    else if (!s)
        s = bake_materials(ctx, mesh, textures, default_albedo, atlas, uvs);
    if (s) {
        free(uvs);
        free(uv_indices);
        pen_image_free(atlas);
        return s;
    }
    for (size_t c = 0; c < corners; ++c)
        uv_indices[c] = (uint32_t)c;
    free(mesh->uvs);
    free(mesh->uv_indices);
    mesh->uvs = uvs;
    mesh->uv_indices = uv_indices;
    mesh->uv_count = (int)corners;
    return PEN_OK;
}
