/* Scene validation: the one place that decides whether a pen_scene is complete and consistent
 * enough to render or optimise, with messages that name the object and the field ("render:
 * objects[2] (spot.obj): sphere 7: needs a finite center and a radius > 0"; the first word is the
 * caller's: the renderer and the optimizer say "render", pen_scene_validate says "scene").
 *
 * Design
 * - It runs at the start of every forward, before anything is allocated or written, so it is
 *   cheap: one pass over each array, the float tests branch-free in vector lanes (a texture is
 *   millions of values). Meshes are checked by pen_mesh_validate (indices in range, finite
 *   positions and UVs) and the camera by pen_camera_validate; the mesh's messages come through
 *   behind the object's name, the camera's as they are ("camera: ...").
 * - Callers that build a pen_scene from other descriptions (the flat API, the optimizer) rely on
 *   this function for the scene's contents and keep only the checks about their own inputs.
 */
#include "scene/validate.h"

#include "core/internal.h"
#include "penumbra/mesh.h"

#include <math.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include <stdio.h>
#include <string.h>

/* Whether all n floats are finite. Textures make this a per-frame scan of millions of values, so
 * it is branch-free, in blocks: x * 0 is a zero for every finite x and a NaN for an Inf or a
 * NaN, and a sum of such terms is a NaN exactly when one is: in vector lanes, a multiply and an
 * add for every 4 values (the exponent-bit test took twice the instructions). */
static int finite_n(const float *v, size_t n) {
    for (size_t i = 0; i < n; i += 4096) {
        const size_t end = n - i < 4096 ? n : i + 4096;
        size_t j = i;
        float acc = 0.0f;
#if defined(__SSE__)
        const __m128 zero = _mm_setzero_ps();
        __m128 a0 = zero, a1 = zero, a2 = zero, a3 = zero;
        for (; j + 16 <= end; j += 16) {
            a0 = _mm_add_ps(a0, _mm_mul_ps(_mm_loadu_ps(v + j), zero));
            a1 = _mm_add_ps(a1, _mm_mul_ps(_mm_loadu_ps(v + j + 4), zero));
            a2 = _mm_add_ps(a2, _mm_mul_ps(_mm_loadu_ps(v + j + 8), zero));
            a3 = _mm_add_ps(a3, _mm_mul_ps(_mm_loadu_ps(v + j + 12), zero));
        }
        float lanes[4];
        _mm_storeu_ps(lanes, _mm_add_ps(_mm_add_ps(a0, a1), _mm_add_ps(a2, a3)));
        acc = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
#endif
        for (; j < end; ++j)
            acc += v[j] * 0.0f;
        if (acc != acc) return 0; /* a NaN */
    }
    return 1;
}

static const char *object_name(const pen_object *ob) {
    return ob->mesh_path ? ob->mesh_path : "in memory";
}

pen_status pen__lights_validate(pen_context *ctx, const pen_lighting *L, const char *who) {
    if (L->lights_mode != PEN_LIGHTS_AUTO && L->lights_mode != PEN_LIGHTS_NONE &&
        L->lights_mode != PEN_LIGHTS_GIVEN)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting.lights: unknown mode %d", who,
                          (int)L->lights_mode);
    if (L->lights_max < 0 || L->lights_max > PEN_SCENE_MAX_LIGHTS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting.lights: max %d outside [0, %d]",
                          who, L->lights_max, PEN_SCENE_MAX_LIGHTS);
    if (L->light_count < 0 || L->light_count > PEN_SCENE_MAX_LIGHTS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting.lights: %d lights, at most %d",
                          who, L->light_count, PEN_SCENE_MAX_LIGHTS);
    /* The loader's bound: K found plus the added ones stay within PEN_SCENE_MAX_LIGHTS. */
    const int room = PEN_SCENE_MAX_LIGHTS - L->lights_max,
              added_hi = L->light_count < room ? L->light_count : room;
    if (L->lights_mode == PEN_LIGHTS_AUTO && (L->lights_added < 0 || L->lights_added > added_hi))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: lighting.lights: %d added lights outside [0, %d] (%d lights, max "
                          "%d)",
                          who, L->lights_added, added_hi, L->light_count, L->lights_max);
    for (int i = 0; i < L->light_count; ++i) {
        const pen_light *l = &L->lights[i];
        const double len2 = (double)l->direction[0] * (double)l->direction[0] +
                            (double)l->direction[1] * (double)l->direction[1] +
                            (double)l->direction[2] * (double)l->direction[2];
        if (!finite_n(l->direction, 3) || !(len2 > 1e-24))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: lighting.lights[%d]: direction must be finite and non-zero", who,
                              i);
        /* In float, as the radius is held: the float nearest the documented minimum 0.01 (what
         * the JSON loader stores for 0.01) lies below the double 0.01. The reference and the
         * optimizer's projection compare the same way. */
        const float b = l->angular_radius_deg;
        if (!(b >= (float)PEN_SCENE_MIN_LIGHT_RADIUS_DEG &&
              b <= (float)PEN_SCENE_MAX_LIGHT_RADIUS_DEG))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: lighting.lights[%d]: angular_radius_deg %g outside [%g, %g]",
                              who, i, (double)b, PEN_SCENE_MIN_LIGHT_RADIUS_DEG,
                              PEN_SCENE_MAX_LIGHT_RADIUS_DEG);
        for (int ch = 0; ch < 3; ++ch)
            if (!(l->irradiance[ch] >= 0.0f && (double)l->irradiance[ch] <= PEN_SCENE_MAX_IRRADIANCE))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "%s: lighting.lights[%d]: irradiance %g outside [0, %g]", who, i,
                                  (double)l->irradiance[ch], PEN_SCENE_MAX_IRRADIANCE);
    }
    return PEN_OK;
}

pen_status pen__scene_validate(pen_context *ctx, const pen_scene *sc, const char *who) {
    if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: sh_bands %d out of range [1, %d]", who,
                          sc->sh_bands, PEN_SH_MAX_BANDS);
    const int nc = sc->sh_bands * sc->sh_bands;
    if (!finite_n(&sc->lighting.sh[0][0], 3 * (size_t)nc))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: lighting: non-finite SH coefficient", who);
    pen_status sl = pen__lights_validate(ctx, &sc->lighting, who);
    if (sl) return sl;
    if (sc->shadow.exp != PEN_SH_EXP_CALIBRATED && sc->shadow.exp != PEN_SH_EXP_PAPER &&
        sc->shadow.exp != PEN_SH_EXP_EXACT)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: shadow.exp: unknown method %d", who,
                          (int)sc->shadow.exp);
    if (sc->shadow.overlap != PEN_OVERLAP_WEIGHTS && sc->shadow.overlap != PEN_OVERLAP_NONE)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: shadow.overlap: unknown mode %d", who,
                          (int)sc->shadow.overlap);
    if (sc->shadow.self != PEN_SELF_TRANSFER && sc->shadow.self != PEN_SELF_SPHERES)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: shadow.self: unknown mode %d", who,
                          (int)sc->shadow.self);
    if (sc->shadow.ground_shadow != PEN_GROUND_SHADOW_TRANSFER &&
        sc->shadow.ground_shadow != PEN_GROUND_SHADOW_SPHERES)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: shadow.ground_shadow: unknown mode %d",
                          who, (int)sc->shadow.ground_shadow);
    if (sc->shadow.ground_grid != 0 && (sc->shadow.ground_grid < PEN_GROUND_GRID_MIN ||
                                        sc->shadow.ground_grid > PEN_GROUND_GRID_MAX))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: shadow.ground_grid: %d nodes per side (expected 0 for the default, "
                          "or %d to %d)",
                          who, sc->shadow.ground_grid, PEN_GROUND_GRID_MIN, PEN_GROUND_GRID_MAX);
    if (sc->object_count < 0 || (sc->object_count > 0 && !sc->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: bad object list", who);
    if (!finite_n(sc->background, 3) ||
        (sc->ground.enabled && (!finite_n(sc->ground.albedo, 3) || !isfinite(sc->ground.height) ||
                                !isfinite(sc->ground.half_size))))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: non-finite background or ground", who);
    if (sc->ground.enabled && !(sc->ground.half_size > 0.0f))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: ground.half_size must be > 0 (got %g)", who,
                          (double)sc->ground.half_size);
    if (sc->background_envmap && (!sc->lighting.envmap.data || !isfinite(sc->lighting.scale) ||
                                  !isfinite(sc->lighting.rotation_y_deg)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "%s: the background shows the environment map, but there is none", who);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *ob = &sc->objects[o];
        const char *name = object_name(ob);
        pen_status s = pen_mesh_validate(ctx, &ob->mesh);
        if (s) {
            char msg[sizeof((pen_context *)0)->message];
            snprintf(msg, sizeof msg, "%s", pen_context_error(ctx));
            return pen__error(ctx, s, "%s: objects[%d] (%s): %s", who, o, name, msg);
        }
        if (ob->texture.data) {
            /* RGB only: the texture's gradient (pen_object_grad.texture) is 3 floats a texel,
             * as the flat ABI's; the loaders make every file RGB */
            if (ob->texture.width < 1 || ob->texture.height < 1 || ob->texture.channels != 3)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "%s: objects[%d] (%s): texture has %d channels; an albedo texture "
                                  "is RGB (3)",
                                  who, o, name, ob->texture.channels);
            if (ob->mesh.uv_count <= 0)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "%s: objects[%d] (%s): texture but no texture coordinates", who,
                                  o, name);
            if (!finite_n(ob->texture.data, (size_t)ob->texture.width * (size_t)ob->texture.height *
                                                (size_t)ob->texture.channels))
                return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: objects[%d] (%s): non-finite texel",
                                  who, o, name);
        } else if (!finite_n(ob->albedo, 3)) {
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: objects[%d] (%s): bad albedo", who, o,
                              name);
        }
        const pen_pose *ps = &ob->pose;
        if (!finite_n(ps->rotation_axis_angle_deg, 3) || !finite_n(ps->translation, 3) ||
            !isfinite(ps->scale) || !(ps->scale > 0.0f))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "%s: objects[%d] (%s): pose must be finite with scale > 0", who, o,
                              name);
        if (ob->spheres.count < 0 || (ob->spheres.count > 0 && !ob->spheres.data))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "%s: objects[%d] (%s): bad sphere set", who,
                              o, name);
        for (int i = 0; i < ob->spheres.count; ++i) {
            const float *s4 = ob->spheres.data + 4 * (size_t)i;
            if (!finite_n(s4, 4) || !(s4[3] > 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "%s: objects[%d] (%s): sphere %d: needs a finite center and "
                                  "a radius > 0",
                                  who, o, name, i);
            const float *k = ob->spheres.weight;
            if (k && !(isfinite(k[i]) && k[i] >= 0.0f))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "%s: objects[%d] (%s): sphere %d: overlap weight %g is not a "
                                  "finite number >= 0",
                                  who, o, name, i, (double)k[i]);
        }
    }
    /* The camera last: the forward checked it after the rest. */
    return pen_camera_validate(ctx, &sc->camera);
}

pen_status pen_scene_validate(pen_context *ctx, const pen_scene *scene) {
    if (!scene) return pen__error(ctx, PEN_ERROR_ARGUMENT, "pen_scene_validate: NULL argument");
    return pen__scene_validate(ctx, scene, "scene");
}
