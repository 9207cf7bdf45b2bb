/* Checkpoints of `penumbra optimize`: the optimiser's whole state, so that a run stopped at any
 * iteration (Ctrl-C, a crash after the last checkpoint, an iteration limit) can be continued
 * with the same result as a run that was never stopped.
 *
 * The state after i Adam steps is the parameter vector x_i, Adam's moments m, v and step count,
 * the best iterate and its loss, and the loss history (which is all the stopping rule looks
 * at), plus the seconds spent so far. Everything else the loop uses is recomputed from the task
 * (the layout, the initial guess and its render, the shadow mask) and is checked against the
 * checkpoint through an identity (parameter layout, groups, loss, shadows, image size, shadow
 * weight, lighting solver and ridge, the regularisers' k and weights, hashes of the target's
 * pixels, of the initial parameter vector and of the rest of the scene with the loop's render
 * options), so a checkpoint is never applied to another problem.
 *
 * File layout (native byte order; an order marker refuses files from another kind of machine):
 *     "PENOPTCK" u32 version u32 0x01020304
 *     u64 n  u32 segments  {u64 offset, u64 count, u32 bound} per segment
 *     u32 groups  i32 loss  i32 shadows  i32 width  i32 height  f64 shadow_weight
 *     i32 lighting_solver  f64 lighting_ridge
 *     i32 graph_k  f64 weights[3]   (the regularisers: deformation k, w_rot, w_reg or spheres k,
 *                                   w_smooth, 0; zeros without either group)
 *     u64 target_hash  u64 init_hash  u64 scene_hash (from version 6)
 *     i32 iteration  i32 recorded  i32 best_iteration  i32 adam_t  f64 best_loss  f64 seconds
 *     f32 x[n]  f32 best[n]  f32 m[n]  f32 v[n]  f64 losses[recorded]
 *     u64 FNV-1a 64 of every byte before it
 * Written to a temporary file beside the target, flushed to the disk (fsync), renamed over the
 * old checkpoint and the folder synced, so that a crash leaves either the old or the new one.
 *
 * Versions 3 and 4 have the same layout. Version 3's lighting_ridge meant nothing to Adam (the
 * ridge was not in Adam's loss then), so a version-3 Adam checkpoint reads as ridge 0, the Adam
 * default now, and its runs continue as they began. Before version 5 the ridge's weight was
 * relative to the normal equations summed over the views, not to their mean
 * (pen__optim_ridge_mu): a multi-view run with a ridge had another objective then, so such a
 * checkpoint is refused, and one whose "fit" start or lights search took a ridge had another
 * initial guess, refused by its hash with the same reason named; single-view ones read as they
 * were. Version 6 adds the scene's hash (pen__optim_scene_hash): before it, a run resumed after
 * the scene's camera, meshes, textures, ground or shadow keys had been edited went on under the
 * new scene. Older files have none and are read without that check. Version 7 gives the groups
 * the render's gradient bits (optim.h PEN_OPTIM_*: pose 8, deformation 16, spheres 4, exposure
 * 128, where they were 4, 8, 16 and 64): an older file's groups are read in the bits of its day
 * (groups.h bit_v6) and mapped, so that its run resumes as before; it also bounds the lighting
 * (PEN__BOUND_SH) and the log exposures (PEN__BOUND_LOG_EXPOSURE), unbounded in older files
 * (same_bound). */
#define _POSIX_C_SOURCE 200809L
#include "io/io_internal.h"
#include "optim/optim_internal.h"

#include <errno.h>
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define CHECKPOINT_MAGIC "PENOPTCK"
#define CHECKPOINT_VERSION 7u
#define CHECKPOINT_VERSION_MIN 3u /* read from here on: above */
#define CHECKPOINT_ORDER 0x01020304u

/* ---- The scene's hash ------------------------------------------------------------------------ */

static uint64_t mix(uint64_t h, const void *data, size_t size) {
    return data && size ? pen__fnv1a(h, data, size) : h;
}

/* The structs hashed whole below hold 4-byte fields only (ints, floats, enums), so they have no
 * padding whose bytes could differ between two runs. */
uint64_t pen__optim_scene_hash(const pen_scene *sc, const pen_render_options *opt) {
    uint64_t h = mix(PEN__FNV1A_SEED, opt, sizeof *opt);
    h = mix(h, &sc->camera, sizeof sc->camera);
    h = mix(h, &sc->sh_bands, sizeof sc->sh_bands);
    h = mix(h, sc->lighting.sh, sizeof sc->lighting.sh[0] * (size_t)(sc->sh_bands * sc->sh_bands));
    h = mix(h, &sc->lighting.light_count, sizeof sc->lighting.light_count);
    h = mix(h, sc->lighting.lights, sizeof sc->lighting.lights[0] * (size_t)sc->lighting.light_count);
    h = mix(h, &sc->shadow, sizeof sc->shadow);
    h = mix(h, &sc->ground, sizeof sc->ground);
    h = mix(h, &sc->background_envmap, sizeof sc->background_envmap);
    h = mix(h, sc->background, sizeof sc->background);
    if (sc->background_envmap) { /* the map itself is seen; otherwise only its SH and lights */
        const pen_image *e = &sc->lighting.envmap;
        h = mix(h, &sc->lighting.scale, sizeof sc->lighting.scale);
        h = mix(h, &sc->lighting.rotation_y_deg, sizeof sc->lighting.rotation_y_deg);
        h = mix(h, e->data, sizeof(float) * (size_t)e->channels * (size_t)e->width * (size_t)e->height);
    }
    h = mix(h, &sc->object_count, sizeof sc->object_count);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const pen_mesh *m = &ob->mesh;
        const size_t tri = 3 * (size_t)m->triangle_count;
        const int32_t counts[4] = {m->vertex_count, m->triangle_count, m->uv_count, m->normal_count};
        h = mix(h, counts, sizeof counts);
        h = mix(h, m->positions, sizeof(float) * 3 * (size_t)m->vertex_count);
        h = mix(h, m->indices, sizeof(uint32_t) * tri);
        h = mix(h, m->uvs, sizeof(float) * 2 * (size_t)m->uv_count);
        h = mix(h, m->uv_indices, m->uv_count ? sizeof(uint32_t) * tri : 0);
        h = mix(h, m->normals, sizeof(float) * 3 * (size_t)m->normal_count);
        h = mix(h, m->normal_indices, m->normal_count ? sizeof(uint32_t) * tri : 0);
        const pen_image *t = &ob->texture;
        const int32_t tex[5] = {t->data ? t->width : 0, t->data ? t->height : 0,
                                t->data ? t->channels : 0, (int32_t)ob->texture_layout,
                                (int32_t)ob->texture_filter};
        h = mix(h, tex, sizeof tex);
        h = mix(h, t->data, sizeof(float) * (size_t)tex[0] * (size_t)tex[1] * (size_t)tex[2]);
        h = mix(h, ob->albedo, sizeof ob->albedo);
        h = mix(h, &ob->pose, sizeof ob->pose);
        h = mix(h, &ob->spheres.count, sizeof ob->spheres.count);
        h = mix(h, ob->spheres.data, sizeof(float) * 4 * (size_t)ob->spheres.count);
        h = mix(h, ob->spheres.weight, sizeof(float) * (size_t)ob->spheres.count);
    }
    return h;
}

/* ---- Writing --------------------------------------------------------------------------------- */

typedef struct writer {
    FILE *f;
    uint64_t hash;
    int ok;
} writer;

static void put(writer *w, const void *data, size_t size) {
    if (!w->ok || size == 0) return;
    w->hash = pen__fnv1a(w->hash, data, size);
    w->ok = fwrite(data, 1, size, w->f) == size;
}

static void put_u32(writer *w, uint32_t v) { put(w, &v, sizeof v); }
static void put_i32(writer *w, int32_t v) { put(w, &v, sizeof v); }
static void put_u64(writer *w, uint64_t v) { put(w, &v, sizeof v); }
static void put_f64(writer *w, double v) { put(w, &v, sizeof v); }

static void put_identity(writer *w, const pen__optim_identity *id) {
    put_u64(w, (uint64_t)id->n);
    put_u32(w, (uint32_t)id->segment_count);
    for (int k = 0; k < id->segment_count; ++k) {
        put_u64(w, (uint64_t)id->segments[k].offset);
        put_u64(w, (uint64_t)id->segments[k].count);
        put_u32(w, (uint32_t)id->segments[k].bound);
    }
    put_u32(w, id->groups);
    put_i32(w, id->loss);
    put_i32(w, id->shadows);
    put_i32(w, id->width);
    put_i32(w, id->height);
    put_f64(w, id->shadow_weight);
    put_i32(w, id->lighting_solver);
    put_f64(w, id->lighting_ridge);
    put_i32(w, id->graph_k);
    for (int k = 0; k < 3; ++k)
        put_f64(w, id->weights[k]);
    put_u64(w, id->target_hash);
    put_u64(w, id->init_hash);
    put_u64(w, id->scene_hash);
}

/* fsync of the folder holding `path`, so that the rename itself survives a crash. Best effort:
 * some file systems refuse to sync a folder, and the file's own data is already on the disk. */
static void sync_folder(const char *path) {
    const char *slash = strrchr(path, '/');
    char dir[4096];
    if (!slash) {
        strcpy(dir, ".");
    } else if ((size_t)(slash - path) + 1 < sizeof dir) {
        memcpy(dir, path, (size_t)(slash - path) + 1);
        dir[slash - path + 1] = '\0';
    } else {
        return;
    }
    int fd = open(dir, O_RDONLY);
    if (fd < 0) return;
    (void)fsync(fd);
    close(fd);
}

pen_status pen__optim_checkpoint_save(pen_context *ctx, const char *path,
                                      const pen__optim_identity *id, const pen__optim_state *st) {
    char *tmp = NULL;
    pen_status s = pen__io_temp_create(ctx, path, &tmp);
    if (s) return s;
    writer w = {fopen(tmp, "wb"), PEN__FNV1A_SEED, 1};
    w.ok = w.f != NULL;
    const size_t n = id->n;
    put(&w, CHECKPOINT_MAGIC, 8);
    put_u32(&w, CHECKPOINT_VERSION);
    put_u32(&w, CHECKPOINT_ORDER);
    put_identity(&w, id);
    put_i32(&w, st->iteration);
    put_i32(&w, st->recorded);
    put_i32(&w, st->best_iteration);
    put_i32(&w, st->adam->t);
    put_f64(&w, st->best_loss);
    put_f64(&w, st->seconds);
    put(&w, st->x, sizeof(float) * n);
    put(&w, st->best, sizeof(float) * n);
    put(&w, st->adam->m, sizeof(float) * n);
    put(&w, st->adam->v, sizeof(float) * n);
    put(&w, st->losses, sizeof(double) * (size_t)st->recorded);
    const uint64_t sum = w.hash;
    put_u64(&w, sum);
    /* on the disk before the rename: a crash must not leave a renamed, empty checkpoint */
    if (w.f && (fflush(w.f) != 0 || fsync(fileno(w.f)) != 0)) w.ok = 0;
    if (w.f && fclose(w.f) != 0) w.ok = 0;
    if (!w.ok) {
        s = pen__error(ctx, PEN_ERROR_IO, "%s: cannot write the checkpoint: %s", path,
                       strerror(errno));
        pen__io_temp_discard(tmp);
        return s;
    }
    s = pen__io_temp_commit(ctx, tmp, path);
    if (!s) sync_folder(path);
    return s;
}

/* ---- Reading --------------------------------------------------------------------------------- */

typedef struct reader {
    FILE *f;
    uint64_t hash;
    int ok; /* 0: the file ended early */
} reader;

static void get(reader *r, void *data, size_t size) {
    if (!r->ok) {
        memset(data, 0, size);
        return;
    }
    r->ok = fread(data, 1, size, r->f) == size;
    if (r->ok) {
        r->hash = pen__fnv1a(r->hash, data, size);
    } else {
        memset(data, 0, size);
    }
}

/* Typed reads: the value, or 0 once the file has ended. */
#define READER_GET(name, type)                                                                 \
    static type name(reader *r) {                                                              \
        type v;                                                                                \
        get(r, &v, sizeof v);                                                                  \
        return v;                                                                              \
    }
READER_GET(get_u32, uint32_t)
READER_GET(get_i32, int32_t)
READER_GET(get_u64, uint64_t)
READER_GET(get_f64, double)

static const char *bound_name(unsigned b) {
    return b == PEN__BOUND_UNIT           ? "unit"
           : b == PEN__BOUND_SPHERES      ? "spheres"
           : b == PEN__BOUND_LIGHTS       ? "lights"
           : b == PEN__BOUND_SH           ? "sh"
           : b == PEN__BOUND_LOG_EXPOSURE ? "log exposure"
                                          : "none";
}

/* Before version 7 the lighting and the log exposures were unbounded: their bounds then only
 * clip values whose scene or views file would be refused, so such a file resumes under them. */
static int same_bound(uint32_t version, uint32_t file, pen__optim_bound run) {
    return file == (uint32_t)run ||
           (version < 7u && file == PEN__BOUND_NONE &&
            (run == PEN__BOUND_SH || run == PEN__BOUND_LOG_EXPOSURE));
}

/* The file's preamble: magic, version and byte-order marker. Returns 0 for a checkpoint this
 * build reads (its version in *version), else what is wrong: 1 not a checkpoint, 2 another byte
 * order, 3 a version outside CHECKPOINT_VERSION_MIN .. CHECKPOINT_VERSION. */
static int preamble(reader *r, uint32_t *version) {
    char magic[8];
    get(r, magic, 8);
    *version = get_u32(r);
    const uint32_t order = get_u32(r);
    if (!r->ok || memcmp(magic, CHECKPOINT_MAGIC, 8) != 0) return 1;
    if (order != CHECKPOINT_ORDER) return 2;
    return *version < CHECKPOINT_VERSION_MIN || *version > CHECKPOINT_VERSION ? 3 : 0;
}

/* Compares the file's identity with the run's; one line on the first difference. */
static pen_status check_identity(pen_context *ctx, const char *path, reader *r,
                                 uint32_t version, const pen__optim_identity *id) {
    const uint64_t n = get_u64(r);
    const uint32_t segs = get_u32(r);
    if (!r->ok) return pen__error(ctx, PEN_ERROR_PARSE, "%s: truncated checkpoint", path);
    if (n != (uint64_t)id->n || segs != (uint32_t)id->segment_count)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another task: %llu parameters in %u segments, this task "
                          "has %zu in %d",
                          path, (unsigned long long)n, segs, id->n, id->segment_count);
    for (int k = 0; k < id->segment_count; ++k) {
        const uint64_t off = get_u64(r), count = get_u64(r);
        const uint32_t bound = get_u32(r);
        const pen__optim_segment *g = &id->segments[k];
        if (r->ok && (off != (uint64_t)g->offset || count != (uint64_t)g->count ||
                      !same_bound(version, bound, g->bound)))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: made for another task: segment %d holds %llu parameters at "
                              "%llu (bound %s), this task's %zu at %zu (bound %s)",
                              path, k, (unsigned long long)count, (unsigned long long)off,
                              bound_name(bound), g->count, g->offset, bound_name(g->bound));
    }
    const uint32_t file_groups = get_u32(r);
    const unsigned groups = version < 7u ? pen__optim_groups_from_v6(file_groups) : file_groups;
    const int32_t loss = get_i32(r), shadows = get_i32(r), w = get_i32(r), h = get_i32(r);
    const double weight = get_f64(r);
    const int32_t solver = get_i32(r);
    double ridge = get_f64(r);
    if (version == 3u && solver == PEN_OPTIM_LIGHTING_ADAM) ridge = 0.0;
    const int32_t graph_k = get_i32(r);
    double weights[3];
    for (int k = 0; k < 3; ++k)
        weights[k] = get_f64(r);
    const uint64_t target = get_u64(r), init = get_u64(r);
    const uint64_t scene = version >= 6u ? get_u64(r) : id->scene_hash;
    if (!r->ok) return pen__error(ctx, PEN_ERROR_PARSE, "%s: truncated checkpoint", path);
    /* Flags outside their enums would be reported below as if they were valid settings ("made
     * with shadows, this run is with shadows"): a file that holds one is damaged. */
    const pen__optim_loss_kind *loss_made = pen__optim_loss_find(loss),
                               *loss_task = pen__optim_loss_find(id->loss);
    if (!loss_made || (shadows != 0 && shadows != 1) ||
        (solver != PEN_OPTIM_LIGHTING_ADAM && solver != PEN_OPTIM_LIGHTING_LEAST_SQUARES))
        return pen__error(ctx, PEN_ERROR_PARSE,
                          "%s: damaged checkpoint (loss %d, shadows %d, lighting solver %d)", path,
                          loss, shadows, solver);
    if (groups != id->groups) {
        char made[160], task[160];
        pen__optim_group_list(groups, 0, made, sizeof made);
        pen__optim_group_list(id->groups, 0, task, sizeof task);
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another task: optimised groups %s, this task's %s", path,
                          made, task);
    }
    if (shadows != id->shadows)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: made %s, this run is %s", path,
                          shadows ? "with shadows" : "with --no-shadows",
                          id->shadows ? "with shadows" : "with --no-shadows");
    if (loss != id->loss || weight != id->shadow_weight)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made with another loss (%s, shadow_weight %g), this task's is %s, "
                          "shadow_weight %g",
                          path, loss_made->name, weight, loss_task ? loss_task->name : "unknown",
                          id->shadow_weight);
    if (solver != id->lighting_solver || ridge != id->lighting_ridge)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made with another lighting solver (%s, ridge %g), this task's is "
                          "%s, ridge %g",
                          path, solver ? "least_squares" : "adam", ridge,
                          id->lighting_solver ? "least_squares" : "adam", id->lighting_ridge);
    /* (the ridge is part of the objective only where the lighting is: a task without the group
     * ignores "lighting_ridge") */
    if (version < 5u && ridge > 0.0 && (id->groups & PEN_OPTIM_LIGHTING) && id->ridge_views > 1)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: checkpoint version %u, made when the lighting ridge of a multi-view "
                          "task weighed as much as all its views (now one view's worth): this "
                          "task's objective differs, run it again without --resume",
                          path, version);
    if (graph_k != id->graph_k || memcmp(weights, id->weights, sizeof weights) != 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made with other regularisers (k %d, weights %g %g %g), this "
                          "task's are k %d, weights %g %g %g",
                          path, graph_k, weights[0], weights[1], weights[2], id->graph_k,
                          id->weights[0], id->weights[1], id->weights[2]);
    if (w != id->width || h != id->height || target != id->target_hash)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another target image (%dx%d, or other pixels)", path, w, h);
    if (init != id->init_hash && version < 5u && id->ridge_views > 1)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another initial guess: checkpoint version %u of a "
                          "multi-view task, whose \"fit\" lighting or lights search weighed "
                          "its ridge as much as all the views (now one view's worth), or the "
                          "task's scene differs; run it again without --resume",
                          path, version);
    if (init != id->init_hash)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another initial guess (the task's scene differs)", path);
    if (scene != id->scene_hash)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: made for another scene (its camera, meshes, textures, spheres, "
                          "lights, ground, background or shadow settings differ)", path);
    return PEN_OK;
}

static int all_finite_f(const float *v, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

pen_status pen__optim_checkpoint_load(pen_context *ctx, const char *path,
                                      const pen__optim_identity *id, int max_losses,
                                      pen__optim_state *st) {
    reader r = {fopen(path, "rb"), PEN__FNV1A_SEED, 1};
    if (!r.f)
        return pen__error(ctx, PEN_ERROR_IO, "%s: cannot open the checkpoint: %s", path,
                          strerror(errno));
    uint32_t version = 0;
    const int wrong = preamble(&r, &version);
    pen_status s = PEN_OK;
    if (wrong == 1) {
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: not a penumbra optimize checkpoint", path);
    } else if (wrong == 2) {
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: written on a machine of another byte order",
                       path);
    } else if (wrong == 3) {
        s = pen__error(ctx, PEN_ERROR_PARSE, "%s: checkpoint version %u, this build reads %u to %u",
                       path, version, CHECKPOINT_VERSION_MIN, CHECKPOINT_VERSION);
    }
    if (!s) s = check_identity(ctx, path, &r, version, id);
    int32_t iteration = 0, recorded = 0, best_it = 0, t = 0;
    double best_loss = 0.0, seconds = 0.0;
    if (!s) {
        iteration = get_i32(&r), recorded = get_i32(&r), best_it = get_i32(&r), t = get_i32(&r);
        best_loss = get_f64(&r), seconds = get_f64(&r);
        if (!r.ok) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: truncated checkpoint", path);
        } else if (iteration < 0 || t != iteration ||
                   /* widened: iteration + 1 overflows on a damaged INT32_MAX */
                   (recorded != iteration && (int64_t)recorded != (int64_t)iteration + 1) ||
                   best_it < -1 ||                   best_it >= recorded || (best_it < 0 && recorded > 0) ||
                   !(seconds >= 0.0) || !isfinite(seconds)) {
            s = pen__error(ctx, PEN_ERROR_PARSE,
                           "%s: damaged checkpoint (iteration %d, %d losses, best %d, Adam step "
                           "%d)",
                           path, iteration, recorded, best_it, t);
        } else if (recorded > max_losses) {
            s = pen__error(ctx, PEN_ERROR_ARGUMENT,
                           "%s: the checkpoint is at iteration %d, beyond the iteration limit %d",
                           path, iteration, max_losses - 1);
        }
    }
    if (!s) {
        const size_t n = id->n;
        get(&r, st->x, sizeof(float) * n);
        get(&r, st->best, sizeof(float) * n);
        get(&r, st->adam->m, sizeof(float) * n);
        get(&r, st->adam->v, sizeof(float) * n);
        get(&r, st->losses, sizeof(double) * (size_t)recorded);
        const uint64_t want = r.hash;
        const uint64_t sum = get_u64(&r);
        char extra;
        if (!r.ok) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: truncated checkpoint", path);
        } else if (sum != want || fread(&extra, 1, 1, r.f) != 0) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: damaged checkpoint (checksum mismatch)",
                           path);
        } else if (!all_finite_f(st->x, n) || !all_finite_f(st->best, n) ||
                   !all_finite_f(st->adam->m, n) || !all_finite_f(st->adam->v, n)) {
            s = pen__error(ctx, PEN_ERROR_PARSE, "%s: damaged checkpoint (NaN or Inf values)",
                           path);
        }
        for (int i = 0; !s && i < recorded; ++i)
            if (!isfinite(st->losses[i]))
                s = pen__error(ctx, PEN_ERROR_PARSE, "%s: damaged checkpoint (loss %d is %g)",
                               path, i, st->losses[i]);
        if (!s && best_it >= 0 && !(best_loss == st->losses[best_it]))
            s = pen__error(ctx, PEN_ERROR_PARSE,
                           "%s: damaged checkpoint (the best loss is not loss %d)", path, best_it);
    }
    fclose(r.f);
    if (s) return s;
    st->iteration = iteration;
    st->recorded = recorded;
    st->best_iteration = best_it;
    st->best_loss = best_loss;
    st->seconds = seconds;
    st->adam->t = t;
    return PEN_OK;
}

int pen__optim_checkpoint_solver(const char *path) {
    reader r = {fopen(path, "rb"), PEN__FNV1A_SEED, 1};
    if (!r.f) return -1;
    uint32_t version = 0;
    const int wrong = preamble(&r, &version);
    (void)get_u64(&r); /* n */
    const uint32_t segs = get_u32(&r);
    int ok = !wrong && r.ok && segs <= 1u << 20;
    for (uint32_t k = 0; ok && k < segs; ++k) { /* offset, count, bound */
        (void)get_u64(&r), (void)get_u64(&r), (void)get_u32(&r);
        ok = r.ok;
    }
    (void)get_u32(&r); /* groups */
    for (int k = 0; k < 4; ++k) /* loss, shadows, width, height */
        (void)get_i32(&r);
    (void)get_f64(&r); /* shadow_weight */
    const int32_t solver = get_i32(&r);
    fclose(r.f);
    return ok && r.ok && (solver == PEN_OPTIM_LIGHTING_ADAM ||
                          solver == PEN_OPTIM_LIGHTING_LEAST_SQUARES)
               ? solver
               : -1;
}
