/* Cached sphere fits: a fit is stored in the user's cache folder under a name that carries a
 * hash of everything the result depends on, so asking again for the same fit reads the file
 * instead of fitting (a scene with "spheres": {"fit": N} loads instantly the second time).
 *
 * Place: $XDG_CACHE_HOME/penumbra (XDG base directory spec; a relative XDG_CACHE_HOME is ignored,
 * as the spec asks), else ~/.cache/penumbra, created on the first write. Never beside the mesh:
 * users' data folders are not ours to fill, and may be read-only or shared.
 * Name: <mesh file name>-<hash of the mesh's absolute path>-<count>-<key>.json, so fits of two
 * meshes with the same name in different folders do not replace each other's files, and a user
 * can tell which cache file belongs to which mesh.
 * Key: FNV-1a 64 over the fitter's version, the sphere count, the resolved settings (as text, so
 * defaults given explicitly or by zero fields hash alike) and the bytes of the mesh's positions
 * and indices; not the thread count, since the fit's sums are added in a fixed order whatever
 * the threads (fit.c). The file repeats the key ("fit_key"); a file whose key, sphere count or
 * format is wrong is ignored and overwritten, never trusted.
 */
#define _DEFAULT_SOURCE /* realpath */
#include "geometry/fit_internal.h"
#include "penumbra/io.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* Bump when a change of the fitter changes its results, so old cache files are not reused (3:
 * the fits cached by an earlier fitter differed from what the fitter now computes under the
 * same key, found when a fresh clone's demo disagreed with the working tree's; 4: spheres
 * allocated to thin parts, fits independent of the thread count, the coverage report; 5: Embree
 * capped at AVX2, so fits made on an AVX-512 processor changed). */
#define FIT_VERSION "penumbra-fit-5"
/* Cache files are small (a few kB per hundred spheres); anything larger is not ours. */
#define FIT_CACHE_MAX_BYTES (16u << 20)

static uint64_t fit_key(const pen_mesh *mesh, int count, const pen_fit_settings *s) {
    char text[512];
    int n = snprintf(text, sizeof text, "%s %d %d %.17g %.17g %.17g %d %.17g %llu", FIT_VERSION,
                     count, s->voxels, s->surface_weight, s->margin_voxels,
                     s->samples_per_voxel_area, s->iterations, s->learning_rate, s->seed);
    uint64_t h = pen__fnv1a(PEN__FNV1A_SEED, text, (size_t)n);
    h = pen__fnv1a(h, mesh->positions, 3 * sizeof(float) * (size_t)mesh->vertex_count);
    return pen__fnv1a(h, mesh->indices, 3 * sizeof(uint32_t) * (size_t)mesh->triangle_count);
}

/* Reads a whole small file; NULL if it is missing, unreadable or too large. */
static char *read_small_file(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    char *buf = NULL;
    if (fseek(f, 0, SEEK_END) == 0) {
        long size = ftell(f);
        if (size >= 0 && (unsigned long)size <= FIT_CACHE_MAX_BYTES && fseek(f, 0, SEEK_SET) == 0) {
            buf = malloc((size_t)size + 1);
            if (buf && fread(buf, 1, (size_t)size, f) == (size_t)size) {
                buf[size] = '\0';
            } else {
                free(buf);
                buf = NULL;
            }
        }
    }
    fclose(f);
    return buf;
}

static double number_or(const cJSON *obj, const char *name, double fallback) {
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, name);
    return cJSON_IsNumber(v) && isfinite(v->valuedouble) ? v->valuedouble : fallback;
}

/* 1 when the file holds a fit with this key and count: *out then owns its spheres. */
static int cache_read(const char *path, const char *key, int count, pen_spheres *out,
                      pen_fit_metrics *metrics) {
    char *text = read_small_file(path);
    if (!text) return 0;
    cJSON *root = cJSON_Parse(text);
    free(text);
    const cJSON *k = cJSON_GetObjectItemCaseSensitive(root, "fit_key");
    int ok = cJSON_IsString(k) && strcmp(k->valuestring, key) == 0;
    if (ok && metrics) {
        const cJSON *m = cJSON_GetObjectItemCaseSensitive(root, "metrics");
        metrics->sov_fraction = number_or(m, "sov_fraction", NAN);
        metrics->surface_coverage = number_or(m, "surface_coverage", NAN);
        metrics->volume_coverage = number_or(m, "volume_coverage", NAN);
        metrics->mean_overlap = number_or(m, "mean_overlap", NAN);
        metrics->iterations = (int)number_or(m, "iterations", 0);
        metrics->seconds = number_or(m, "seconds", NAN);
        metrics->energy = number_or(m, "energy", NAN);
        metrics->inside_voxels = (long)number_or(m, "inside_voxels", 0);
        metrics->surface_samples = (int)number_or(m, "surface_samples", 0);
        const cJSON *g = cJSON_GetObjectItemCaseSensitive(m, "grid");
        for (int a = 0; a < 3; ++a) {
            const cJSON *e = cJSON_GetArrayItem(g, a);
            metrics->grid[a] = cJSON_IsNumber(e) ? e->valueint : 0;
        }
        const cJSON *u = cJSON_GetObjectItemCaseSensitive(m, "uncovered");
        pen_coverage_report *c = &metrics->coverage;
        c->tolerance = number_or(u, "tolerance", NAN);
        c->uncovered = number_or(u, "fraction", NAN);
        c->parts = (int)number_or(u, "parts", 0);
        c->largest_share = number_or(u, "largest_share", NAN);
        c->samples = (int)number_or(u, "samples", 0);
        static const char *const vec[3] = {"largest_centre", "largest_lo", "largest_hi"};
        float *dst[3] = {c->largest_centre, c->largest_lo, c->largest_hi};
        for (int v = 0; v < 3; ++v)
            for (int a = 0; a < 3; ++a) {
                const cJSON *e = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(u, vec[v]), a);
                dst[v][a] = cJSON_IsNumber(e) ? (float)e->valuedouble : NAN;
            }
        metrics->from_cache = 1;
    }
    cJSON_Delete(root);
    if (!ok) return 0;
    /* The spheres go through the library's validating reader; a context of our own keeps a
     * broken cache file's error out of the caller's context. */
    pen_context *tmp = pen_context_create();
    ok = tmp && pen_spheres_load(tmp, path, out) == PEN_OK && out->count == count;
    if (!ok) pen_spheres_free(out);
    pen_context_destroy(tmp);
    return ok;
}

/* The cache folder (see the top of this file) into buf; 0 when neither XDG_CACHE_HOME nor HOME
 * gives one. */
static int cache_dir(char *buf, size_t size) {
    const char *xdg = getenv("XDG_CACHE_HOME"), *home = getenv("HOME");
    int n;
    if (xdg && xdg[0] == '/')
        n = snprintf(buf, size, "%s/penumbra", xdg);
    else if (home && home[0] == '/')
        n = snprintf(buf, size, "%s/.cache/penumbra", home);
    else
        return 0;
    return n > 0 && (size_t)n < size;
}

/* mkdir -p of the cache folder, private to the user (0700, as the XDG spec asks). */
static int make_dirs(const char *dir) {
    char buf[PATH_MAX];
    if (snprintf(buf, sizeof buf, "%s", dir) >= (int)sizeof buf) return 0;
    for (char *p = buf + 1;; ++p) {
        if (*p != '/' && *p != '\0') continue;
        const char c = *p;
        *p = '\0';
        if (mkdir(buf, 0700) != 0 && errno != EEXIST) return 0;
        *p = c;
        if (!c) break;
    }
    return 1;
}

/* The key as 16 hex digits and the cache file's path (malloc'd). Without a cache folder (no
 * HOME) the status is PEN_ERROR_IO and *path NULL. */
static pen_status cache_name(pen_context *ctx, const pen_mesh *mesh, const char *mesh_path,
                             int count, const pen_fit_settings *s, char key[17], char **path) {
    *path = NULL;
    float lo[3], hi[3];
    pen_status st = pen__fit_check_mesh(ctx, mesh, lo, hi);
    if (st) return st;
    if (!mesh_path) return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: no mesh path for the cache");
    snprintf(key, 17, "%016llx", (unsigned long long)fit_key(mesh, count, s));
    char dir[PATH_MAX];
    if (!cache_dir(dir, sizeof dir))
        return pen__error(ctx, PEN_ERROR_IO,
                          "fit: no cache folder (neither XDG_CACHE_HOME nor HOME is an absolute "
                          "path)");
    /* The absolute path when the mesh file exists (it may not: the mesh can come from memory). */
    char *real = realpath(mesh_path, NULL);
    const char *abs = real ? real : mesh_path;
    const uint64_t where = pen__fnv1a(PEN__FNV1A_SEED, abs, strlen(abs));
    const char *slash = strrchr(abs, '/');
    char base[65];
    snprintf(base, sizeof base, "%s", slash ? slash + 1 : abs);
    for (char *c = base; *c; ++c) /* a readable hint only: keep it to portable characters */
        if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') ||
              *c == '.' || *c == '_' || *c == '-'))
            *c = '_';
    free(real);
    size_t len = strlen(dir) + strlen(base) + 96;
    *path = pen__malloc(ctx, len, 1, "fit: cache path");
    if (!*path) return PEN_ERROR_MEMORY;
    snprintf(*path, len, "%s/%s-%016llx-%d-%s.json", dir, base, (unsigned long long)where, count,
             key);
    return PEN_OK;
}

pen_status pen_spheres_fit_cache_path(pen_context *ctx, const pen_mesh *mesh, const char *mesh_path,
                                      int count, const pen_fit_settings *settings, char **path) {
    *path = NULL;
    pen_fit_settings s;
    char key[17];
    pen_status st = pen__fit_resolve_settings(ctx, settings, &s);
    return st ? st : cache_name(ctx, mesh, mesh_path, count, &s, key, path);
}

/* The fit behind the cache; errors name the mesh file ("spot.obj: fit: ..."), since the fitter
 * itself only knows the mesh's triangles. */
static pen_status cached_fit(pen_context *ctx, const pen_mesh *mesh, const char *mesh_path,
                             int count, const pen_fit_settings *settings, pen_spheres *out,
                             pen_fit_metrics *metrics) {
    if (out) memset(out, 0, sizeof *out);
    if (metrics) memset(metrics, 0, sizeof *metrics);
    if (!out) return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: no output sphere set");
    pen_fit_settings s;
    pen_status st = pen__fit_resolve_settings(ctx, settings, &s);
    if (st) return st;
    if (!pen_context_fit_cache(ctx)) return pen_spheres_fit(ctx, mesh, count, &s, out, metrics);
    char key[17], *path = NULL;
    st = cache_name(ctx, mesh, mesh_path, count, &s, key, &path);
    if (st == PEN_ERROR_IO) { /* no cache folder: the cache only saves time */
        pen_context_clear_error(ctx);
        return pen_spheres_fit(ctx, mesh, count, &s, out, metrics);
    }
    if (st) return st;
    if (cache_read(path, key, count, out, metrics)) {
        free(path);
        /* A cache written before overlap weights existed has none: compute them. */
        st = pen_spheres_ensure_weights(ctx, out);
        if (st) pen_spheres_free(out);
        return st;
    }
    pen_fit_metrics m;
    st = pen_spheres_fit(ctx, mesh, count, &s, out, &m);
    if (st) {
        free(path);
        return st;
    }
    if (metrics) *metrics = m;
    char body[4096], extra[4200];
    pen_fit_json(&s, &m, body, sizeof body);
    snprintf(extra, sizeof extra, "{\"fit_key\": \"%s\", %s", key, body + 1);
    /* The cache only saves time: a folder we cannot write to is not an error. */
    char dir[PATH_MAX];
    pen_context *tmp = pen_context_create();
    if (tmp && cache_dir(dir, sizeof dir) && make_dirs(dir)) pen_spheres_save(tmp, path, out, extra);
    pen_context_destroy(tmp);
    free(path);
    return PEN_OK;
}

pen_status pen_spheres_fit_cached(pen_context *ctx, const pen_mesh *mesh, const char *mesh_path,
                                  int count, const pen_fit_settings *settings, pen_spheres *out,
                                  pen_fit_metrics *metrics) {
    if (!mesh_path) return pen_spheres_fit(ctx, mesh, count, settings, out, metrics);
    pen_status st = cached_fit(ctx, mesh, mesh_path, count, settings, out, metrics);
    return st ? pen__error_prefix(ctx, st, "%s: ", mesh_path) : PEN_OK;
}

pen_status pen_scene_prepare(pen_context *ctx, pen_scene *scene, int shadows,
                             pen_fit_metrics *metrics) {
    if (!scene) return pen__error(ctx, PEN_ERROR_ARGUMENT, "prepare: no scene");
    for (int o = 0; metrics && o < scene->object_count; ++o)
        memset(&metrics[o], 0, sizeof metrics[o]);
    for (int o = 0; o < scene->object_count; ++o) {
        pen_object *ob = &scene->objects[o];
        pen_status st = PEN_OK;
        /* Without shadows no sphere is used: the fit (seconds) is left for a render with them. */
        if (shadows && ob->fit_spheres > 0 && ob->spheres.count == 0)
            st = pen_spheres_fit_cached(ctx, &ob->mesh, ob->mesh_path, ob->fit_spheres, NULL,
                                        &ob->spheres, metrics ? &metrics[o] : NULL);
        /* Weights once here rather than in every render state that meets the set (with
         * "overlap": "none" the renderer takes none). */
        if (!st && scene->shadow.overlap == PEN_OVERLAP_WEIGHTS)
            st = pen_spheres_ensure_weights(ctx, &ob->spheres);
        /* The input at fault, as the renderer names it: the scene file, the object, its spheres'
         * file. */
        if (st)
            return pen__error_prefix(ctx, st, "%s: objects[%d].spheres%s%s%s: ",
                                     scene->path ? scene->path : "scene", o,
                                     ob->spheres_path ? " (" : "",
                                     ob->spheres_path ? ob->spheres_path : "",
                                     ob->spheres_path ? ")" : "");
    }
    return PEN_OK;
}

pen_status pen_scene_fit_spheres(pen_context *ctx, pen_scene *scene) {
    if (!scene) return pen__error(ctx, PEN_ERROR_ARGUMENT, "fit: no scene");
    for (int i = 0; i < scene->object_count; ++i) {
        pen_object *o = scene->objects + i;
        if (o->fit_spheres <= 0 || o->spheres.count > 0) continue;
        pen_status st = pen_spheres_fit_cached(ctx, &o->mesh, o->mesh_path, o->fit_spheres, NULL,
                                               &o->spheres, NULL);
        if (st) return st;
    }
    return PEN_OK;
}
