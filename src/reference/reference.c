/* The ground-truth renderer: Monte-Carlo integration of the diffuse shading integral on Embree.
 *
 * For a camera ray that hits a surface point x (normal n, albedo rho) the pixel receives
 *     L_o = rho / pi * E,   E = integral L(w) V(x, w) max(n . w, 0) dw,
 * and E is estimated per camera sample with
 *   - envmap lighting: one direction drawn from the map's luminance distribution and one from the
 *     cosine distribution, combined with the balance heuristic. For a strategy's sample w the
 *     weighted term f(w) / p_s(w) * p_s(w) / (p_l(w) + p_c(w)) simplifies to
 *     f(w) / (p_l(w) + p_c(w)), so both samples use the same expression. The cosine strategy
 *     covers every direction of the hemisphere, so the sum is unbiased even where the map is black
 *     and the light strategy has no density.
 *   - SH lighting: E = E_0(n) - integral L(w) (1 - V(x, w)) max(n . w, 0) dw, where the
 *     unoccluded irradiance E_0(n) = sum_lm sqrt(4 pi / (2l+1)) c_l L_lm Y_lm(n) is exact (c_l the
 *     clamped cosine's zonal coefficients) and the blocked part is estimated with one
 *     cosine-distributed direction, pi L(w) (1 - V(w)). The closed form is a control variate:
 *     unshadowed points are exact, shadowed ones carry only the noise of what is blocked.
 *     L(w) may be negative (the band-limited reconstruction rings); it is used as is, like the
 *     SH renderer does, so that `--lighting sh` isolates the error of SH visibility.
 * V is one occlusion ray against every posed mesh and the ground quad, leaving from x nudged off
 * the surface by eps (1e-5 of the scene's extent, at least 1e-5) along the geometric normal.
 *
 * Surfaces. Meshes use smooth vertex normals, the sum of the (area-weighted) face normals around
 * each vertex, interpolated with the hit's barycentrics and renormalised; faces are lit from the
 * side the camera sees (both normals flipped when the geometric normal faces away from the ray).
 * The ground is the square [-h, h]^2 at y = height with normal +Y (-Y seen from below).
 *
 * Parallelism and determinism. The image is cut into 16x16 tiles shared dynamically among the
 * OpenMP threads; each pixel sums its own samples in double, and every random number comes from a
 * counter-based stream keyed by (seed, pixel, sample), so the image is the same bits for any
 * thread count and schedule.
 */
#include "penumbra/reference.h"

#include "penumbra/envmap.h"
#include "penumbra/raster.h"

#include "core/internal.h"
#include "core/vec.h"
#include "geometry/embree.h"
#include "reference/internal.h"
#include "scene/texture.h"

#include <omp.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define TILE 16

struct pen_reference {
    const pen_scene *scene;
    pen_reference_lighting lighting; /* ENVMAP or SH */
    RTCDevice device;
    RTCScene rtc;
    int object_count;
    float **positions;      /* per object: world positions, 3 * vertex_count */
    float **normals;        /* per object: world smooth normals, 3 * vertex_count */
    unsigned ground_id;     /* geometry ID of the ground quad, or RTC_INVALID_... */
    float eps;              /* ray-origin offset */
    float rot_cos, rot_sin; /* the envmap's rotation about +Y */
    int sh_bands;
    float cosine_zonal[PEN_SH_MAX_BANDS]; /* clamped cosine as a zonal function, SH lighting */
    pen__envmap_sampler sampler;          /* ENVMAP lighting only */
    pen__ref_lights lights;               /* the disk lights rendered (see lights_in_use) */
};

/* ---- Lighting -------------------------------------------------------------------------------
 * World direction w and map direction m are related by w = R_y(rotation) m: the map is rotated
 * by rotation_y_deg about +Y, the convention of pen_envmap_to_sh. */

static void world_to_map(const pen_reference *ref, const float w[3], float m[3]) {
    float c = ref->rot_cos, s = ref->rot_sin;
    m[0] = c * w[0] - s * w[2];
    m[1] = w[1];
    m[2] = s * w[0] + c * w[2];
}

static void map_to_world(const pen_reference *ref, const float m[3], float w[3]) {
    float c = ref->rot_cos, s = ref->rot_sin;
    w[0] = c * m[0] + s * m[2];
    w[1] = m[1];
    w[2] = -s * m[0] + c * m[2];
}

static void envmap_texel_radiance(const pen_reference *ref, int tx, int ty, float L[3]) {
    const pen_lighting *lt = &ref->scene->lighting;
    for (int ch = 0; ch < 3; ++ch)
        L[ch] = lt->scale * fmaxf(pen__texel(&lt->envmap, tx, ty, ch), 0.0f);
}

/* The SH reconstruction sum_k sh[k] Y_k(w), unclamped. */
static void sh_radiance(const pen_reference *ref, const float w[3], float L[3]) {
    float y[PEN_SH_MAX_COEFFS];
    int n = pen_sh_coeffs(ref->sh_bands);
    pen_sh_eval(ref->sh_bands, w, y);
    L[0] = L[1] = L[2] = 0;
    for (int k = 0; k < n; ++k)
        for (int ch = 0; ch < 3; ++ch)
            L[ch] += ref->scene->lighting.sh[k][ch] * y[k];
}

/* What a ray that leaves the scene shows: the envmap (pen_envmap_eval: bilinear, rotated,
 * scaled, clamped at 0), its SH reconstruction when the scene has no map, or the constant. */
static void background(const pen_reference *ref, const float dir[3], float out[3]) {
    const pen_scene *sc = ref->scene;
    if (!sc->background_envmap) {
        for (int ch = 0; ch < 3; ++ch)
            out[ch] = sc->background[ch];
        return;
    }
    const pen_lighting *lt = &sc->lighting;
    if (!lt->envmap.data) {
        sh_radiance(ref, dir, out);
        return;
    }
    pen_envmap_eval(&lt->envmap, lt->rotation_y_deg, lt->scale, dir, out);
}

/* ---- Rays ------------------------------------------------------------------------------------ */

static int occluded(const pen_reference *ref, const float org[3], const float dir[3]) {
    return pen__embree_occluded(ref->rtc, org, dir, 0.0f);
}

/* A cosine-distributed direction around the unit normal n (pdf cos / pi); returns the cosine. */
static float sample_cosine(const float n[3], float r1, float r2, float w[3]) {
    /* Orthonormal basis without a branch on the axis (Duff et al. 2017). */
    float sign = copysignf(1.0f, n[2]);
    float a = -1.0f / (sign + n[2]), b = n[0] * n[1] * a;
    float t[3] = {1.0f + sign * n[0] * n[0] * a, sign * b, -sign * n[0]};
    float bt[3] = {b, sign + n[1] * n[1] * a, -n[1]};
    float phi = 2.0f * PEN_PI_F * r1;
    float sin_t = sqrtf(r2), cos_t = sqrtf(1.0f - r2);
    float x = sin_t * cosf(phi), y = sin_t * sinf(phi);
    for (int i = 0; i < 3; ++i)
        w[i] = x * t[i] + y * bt[i] + cos_t * n[i];
    return cos_t;
}

/* The map's radiance along world direction w (its texel, as the light strategy sees it) and
 * the light strategy's density there. */
static float map_lookup(const pen_reference *ref, const float w[3], float L[3]) {
    float m[3], u, v;
    int tx, ty;
    world_to_map(ref, w, m);
    pen_envmap_uv(m, &u, &v);
    pen__envmap_texel(&ref->scene->lighting.envmap, u, v, &tx, &ty);
    float sin_t = sqrtf(fmaxf(0.0f, 1.0f - m[1] * m[1]));
    envmap_texel_radiance(ref, tx, ty, L);
    return pen__envmap_sampler_pdf(&ref->sampler, tx, ty, sin_t);
}

/* Adds the disk lights' radiance along w to L; returns their cone-sampling densities' sum. */
static float add_lights(const pen_reference *ref, const float w[3], float L[3]) {
    float Ld[3];
    float p = (float)pen__ref_lights_eval(&ref->lights, w, Ld);
    for (int ch = 0; ch < 3; ++ch)
        L[ch] += Ld[ch];
    return p;
}

/* One cone sample per disk light, in the same balance heuristic as the other strategies: the
 * integrand is the lights' radiance (plus the map's when with_map) times V cos, over the sum of
 * every strategy's density (the map's when with_map, the cosine's, each light's). */
static void light_samples(const pen_reference *ref, const float org[3], const float n[3],
                          int with_map, pen__rng *rng, float E[3]) {
    const pen__ref_lights *ls = &ref->lights;
    for (int k = 0; k < ls->count; ++k) {
        float r1 = pen__rng_next(rng), r2 = pen__rng_next(rng), w[3], L[3];
        pen__ref_light_sample(&ls->l[k], r1, r2, w);
        float c = pen__dot_f(n, w);
        if (!(c > 0)) continue;
        float p = c / PEN_PI_F;
        if (with_map) p += map_lookup(ref, w, L);
        else L[0] = L[1] = L[2] = 0.0f;
        p += add_lights(ref, w, L);
        if (occluded(ref, org, w)) continue;
        for (int ch = 0; ch < 3; ++ch)
            E[ch] += L[ch] * (c / p);
    }
}

/* One sample (pair) of the irradiance estimator at origin `org` (already off the surface) with
 * unit normal n, plus one sample per disk light in use; adds to E. */
static void irradiance_sample(const pen_reference *ref, const float org[3], const float n[3],
                              pen__rng *rng, float E[3]) {
    float w[3], L[3];
    const int lights = ref->lights.count;
    if (ref->lighting == PEN_REFERENCE_LIGHTING_SH) {
        /* Control variate: the unoccluded irradiance is known in closed form, so only the light
         * that blockers remove is estimated; unshadowed points get no noise at all. */
        float a[PEN_SH_MAX_COEFFS];
        const int nc = pen_sh_coeffs(ref->sh_bands);
        pen_sh_rotate_zonal(ref->sh_bands, ref->cosine_zonal, n, a);
        for (int k = 0; k < nc; ++k)
            for (int ch = 0; ch < 3; ++ch)
                E[ch] += ref->scene->lighting.sh[k][ch] * a[k];
        float r1 = pen__rng_next(rng), r2 = pen__rng_next(rng);
        float c = sample_cosine(n, r1, r2, w);
        if (c > 0 && occluded(ref, org, w)) {
            sh_radiance(ref, w, L);
            for (int ch = 0; ch < 3; ++ch)
                E[ch] -= PEN_PI_F * L[ch];
        } else if (c > 0 && lights) { /* the cosine sample as a strategy for the lights */
            float p = (float)pen__ref_lights_eval(&ref->lights, w, L);
            if (p > 0)
                for (int ch = 0; ch < 3; ++ch)
                    E[ch] += L[ch] * (c / (p + c / PEN_PI_F));
        }
        if (lights) light_samples(ref, org, n, 0, rng, E);
        return;
    }
    float m[3], u, v;
    int tx, ty;
    if (ref->sampler.total > 0) { /* light strategy */
        double pick = pen__rng_next_double(rng);
        float r[3];
        for (int i = 0; i < 3; ++i)
            r[i] = pen__rng_next(rng);
        pen__envmap_sampler_sample(&ref->sampler, pick, r, &u, &v, &tx, &ty);
        pen_envmap_direction(u, v, m);
        map_to_world(ref, m, w);
        float c = pen__dot_f(n, w);
        float pl = pen__envmap_sampler_pdf(&ref->sampler, tx, ty, sinf(PEN_PI_F * v));
        if (c > 0 && pl > 0 && !occluded(ref, org, w)) {
            envmap_texel_radiance(ref, tx, ty, L);
            if (lights) pl += add_lights(ref, w, L); /* given on top of the map */
            float k = c / (pl + c / PEN_PI_F);
            for (int ch = 0; ch < 3; ++ch)
                E[ch] += L[ch] * k;
        }
    }
    { /* cosine strategy */
        float r1 = pen__rng_next(rng), r2 = pen__rng_next(rng);
        float c = sample_cosine(n, r1, r2, w);
        if (c > 0 && !occluded(ref, org, w)) {
            float pl = map_lookup(ref, w, L);
            if (lights) pl += add_lights(ref, w, L);
            float k = c / (pl + c / PEN_PI_F);
            for (int ch = 0; ch < 3; ++ch)
                E[ch] += L[ch] * k;
        }
    }
    if (lights) light_samples(ref, org, n, 1, rng, E);
}

/* ---- Surfaces ---------------------------------------------------------------------------------
 */

typedef struct surface {
    float p[3], ng[3], ns[3], albedo[3];
} surface;

/* Fills the surface at a mesh hit (object g, triangle t, barycentrics b1, b2). */
static void mesh_surface(const pen_reference *ref, unsigned g, unsigned t, float b1, float b2,
                         const float dir[3], surface *s) {
    const pen_object *obj = &ref->scene->objects[g];
    const pen_mesh *mesh = &obj->mesh;
    const float *P = ref->positions[g], *N = ref->normals[g];
    const uint32_t *idx = mesh->indices + 3 * (size_t)t;
    float b[3] = {1.0f - b1 - b2, b1, b2};
    float e1[3], e2[3];
    for (int i = 0; i < 3; ++i) {
        s->p[i] = b[0] * P[3 * idx[0] + i] + b[1] * P[3 * idx[1] + i] + b[2] * P[3 * idx[2] + i];
        s->ns[i] = b[0] * N[3 * idx[0] + i] + b[1] * N[3 * idx[1] + i] + b[2] * N[3 * idx[2] + i];
        e1[i] = P[3 * idx[1] + i] - P[3 * idx[0] + i];
        e2[i] = P[3 * idx[2] + i] - P[3 * idx[0] + i];
    }
    pen__cross_f(e1, e2, s->ng);
    /* Embree does not report hits on degenerate triangles, but be safe. */
    if (!pen__normalize_f(s->ng)) {
        for (int i = 0; i < 3; ++i)
            s->ng[i] = -dir[i];
    }
    if (!pen__normalize_f(s->ns)) memcpy(s->ns, s->ng, sizeof s->ns);
    if (pen__dot_f(s->ng, dir) > 0) /* the camera sees the back: light that side */
        for (int i = 0; i < 3; ++i)
            s->ng[i] = -s->ng[i], s->ns[i] = -s->ns[i];
    if (pen__dot_f(s->ns, s->ng) <= 0) memcpy(s->ns, s->ng, sizeof s->ns);

    if (obj->texture.data) {
        const uint32_t *ti = mesh->uv_indices + 3 * (size_t)t;
        float uv[2];
        for (int i = 0; i < 2; ++i)
            uv[i] = b[0] * mesh->uvs[2 * ti[0] + i] + b[1] * mesh->uvs[2 * ti[1] + i] +
                    b[2] * mesh->uvs[2 * ti[2] + i];
        /* the renderer's bilinear lookup at a point; the pixel's samples box-filter it, as the
         * renderer's footprint filter does (texture.c) */
        pen__texture_fwd(&obj->texture, uv, s->albedo);
    } else {
        memcpy(s->albedo, obj->albedo, sizeof s->albedo);
    }
}

/* The radiance arriving along the camera ray (org, dir): one sample. Returns 1 if the ray hit a
 * surface, 0 if it shows the background. */
static int radiance(const pen_reference *ref, const float org[3], const float dir[3], pen__rng *rng,
                    float out[3]) {
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    struct RTCRayHit rh;
    rh.ray.org_x = org[0], rh.ray.org_y = org[1], rh.ray.org_z = org[2];
    rh.ray.dir_x = dir[0], rh.ray.dir_y = dir[1], rh.ray.dir_z = dir[2];
    rh.ray.tnear = 0.0f;
    rh.ray.tfar = INFINITY;
    rh.ray.time = 0.0f;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(ref->rtc, &ictx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
        background(ref, dir, out);
        return 0;
    }
    surface s;
    if (rh.hit.geomID == ref->ground_id) {
        const pen_ground *gr = &ref->scene->ground;
        s.p[0] = org[0] + rh.ray.tfar * dir[0];
        s.p[1] = gr->height;
        s.p[2] = org[2] + rh.ray.tfar * dir[2];
        float ny = dir[1] > 0 ? -1.0f : 1.0f;
        s.ng[0] = s.ng[2] = s.ns[0] = s.ns[2] = 0.0f;
        s.ng[1] = s.ns[1] = ny;
        memcpy(s.albedo, gr->albedo, sizeof s.albedo);
    } else {
        mesh_surface(ref, rh.hit.geomID, rh.hit.primID, rh.hit.u, rh.hit.v, dir, &s);
    }
    float o[3], E[3] = {0, 0, 0};
    for (int i = 0; i < 3; ++i)
        o[i] = s.p[i] + ref->eps * s.ng[i];
    irradiance_sample(ref, o, s.ns, rng, E);
    for (int ch = 0; ch < 3; ++ch)
        out[ch] = s.albedo[ch] / PEN_PI_F * E[ch];
    return 1;
}

/* ---- Building the scene ------------------------------------------------------------------------
 */

static const char *object_name(const pen_object *obj) {
    return obj->mesh_path ? obj->mesh_path : "(mesh)";
}

static pen_status check_image(pen_context *ctx, const pen_image *img, const char *what, int i) {
    if (img->width <= 0 || img->height <= 0 || img->width > PEN_IMAGE_MAX_DIM ||
        img->height > PEN_IMAGE_MAX_DIM || !(img->channels == 1 || img->channels >= 3))
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "reference: %s %d: bad image shape %dx%d with %d channels", what, i,
                          img->width, img->height, img->channels);
    return PEN_OK;
}

static pen_status check_scene(pen_context *ctx, const pen_scene *sc, int need_sh) {
    const pen_camera *cam = &sc->camera;
    if (cam->width <= 0 || cam->height <= 0 || cam->width > PEN_IMAGE_MAX_DIM ||
        cam->height > PEN_IMAGE_MAX_DIM)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: camera: bad size %dx%d", cam->width,
                          cam->height);
    if (!(cam->fov_y_deg > 0 && cam->fov_y_deg < 180) || !pen__finite3(cam->eye))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: camera: bad fov or eye");
    if (need_sh) {
        if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS)
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: sh_bands %d out of [1, %d]",
                              sc->sh_bands, PEN_SH_MAX_BANDS);
        for (int k = 0; k < pen_sh_coeffs(sc->sh_bands); ++k)
            if (!pen__finite3(sc->lighting.sh[k]))
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "reference: lighting.sh[%d] is not finite", k);
    }
    if (!isfinite(sc->lighting.scale) || !isfinite(sc->lighting.rotation_y_deg))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: lighting: bad scale or rotation");
    if (sc->lighting.envmap.data && check_image(ctx, &sc->lighting.envmap, "envmap", 0))
        return PEN_ERROR_ARGUMENT;
    if (sc->lighting.light_count < 0 || sc->lighting.light_count > PEN_SCENE_MAX_LIGHTS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: %d lights, expected [0, %d]",
                          sc->lighting.light_count, PEN_SCENE_MAX_LIGHTS);
    for (int k = 0; k < sc->lighting.light_count; ++k) {
        const pen_light *l = &sc->lighting.lights[k];
        if (!pen__finite3(l->direction) || !pen__finite3(l->irradiance) ||
            !(pen__dot_f(l->direction, l->direction) > 0) ||
            !(l->angular_radius_deg >= (float)PEN_SCENE_MIN_LIGHT_RADIUS_DEG &&
              l->angular_radius_deg <= (float)PEN_SCENE_MAX_LIGHT_RADIUS_DEG))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "reference: lighting.lights[%d]: needs a finite nonzero direction, "
                              "a finite irradiance and an angular radius in [%g, %g] degrees",
                              k, PEN_SCENE_MIN_LIGHT_RADIUS_DEG, PEN_SCENE_MAX_LIGHT_RADIUS_DEG);
    }
    if (sc->object_count < 0 || (sc->object_count > 0 && !sc->objects))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: bad object count %d",
                          sc->object_count);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_object *obj = &sc->objects[o];
        const pen_mesh *m = &obj->mesh;
        if (m->vertex_count < 0 || m->triangle_count < 0 ||
            (m->triangle_count > 0 && (!m->positions || !m->indices)))
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: object %d (%s): empty mesh", o,
                              object_name(obj));
        for (size_t i = 0; i < 3 * (size_t)m->triangle_count; ++i) {
            if (m->indices[i] >= (uint32_t)m->vertex_count)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "reference: object %d (%s): triangle %zu: index %u out of "
                                  "range [0, %d)",
                                  o, object_name(obj), i / 3, (unsigned)m->indices[i],
                                  m->vertex_count);
        }
        if (obj->texture.data) {
            if (check_image(ctx, &obj->texture, "texture of object", o)) return PEN_ERROR_ARGUMENT;
            if (m->uv_count <= 0 || !m->uvs || !m->uv_indices)
                return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                  "reference: object %d (%s): a texture but no UVs", o,
                                  object_name(obj));
            for (size_t i = 0; i < 3 * (size_t)m->triangle_count; ++i)
                if (m->uv_indices[i] >= (uint32_t)m->uv_count)
                    return pen__error(ctx, PEN_ERROR_ARGUMENT,
                                      "reference: object %d (%s): triangle %zu: uv index %u out "
                                      "of range [0, %d)",
                                      o, object_name(obj), i / 3, (unsigned)m->uv_indices[i],
                                      m->uv_count);
        } else if (!pen__finite3(obj->albedo)) {
            return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: object %d: albedo not finite",
                              o);
        }
    }
    const pen_ground *g = &sc->ground;
    if (g->enabled && (!(g->half_size > 0) || !isfinite(g->half_size) || !isfinite(g->height) ||
                       !pen__finite3(g->albedo)))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: ground: bad height, size or albedo");
    return PEN_OK;
}

/* Poses an object's vertices into world space and computes its smooth normals there, with the
 * rasterizer's functions so that both renderers shade the same normals. */
static pen_status pose_object(pen_context *ctx, const pen_object *obj, int o, float **pos_out,
                              float **nrm_out, float *extent) {
    const pen_mesh *m = &obj->mesh;
    size_t n = (size_t)m->vertex_count;
    float *P = pen__malloc(ctx, n ? n : 1, 3 * sizeof(float), "reference positions");
    float *N = pen__malloc(ctx, n ? n : 1, 3 * sizeof(float), "reference normals");
    *pos_out = P;
    *nrm_out = N;
    if (!P || !N) return PEN_ERROR_MEMORY;
    pen_pose_points_fwd(&obj->pose, m->vertex_count, m->positions, P);
    for (size_t v = 0; v < n; ++v) {
        if (!pen__finite3(P + 3 * v))
            return pen__error(ctx, PEN_ERROR_ARGUMENT,
                              "reference: object %d (%s): vertex %zu is not finite once posed", o,
                              object_name(obj), v);
        for (int i = 0; i < 3; ++i)
            *extent = fmaxf(*extent, fabsf(P[3 * v + i]));
    }
    /* Vertices of no usable triangle get (0, 0, 0); mesh_surface then falls back to the face. */
    return pen_vertex_normals_fwd(ctx, m->vertex_count, P, m->triangle_count, m->indices, N);
}

static pen_status embree_status(pen_context *ctx, RTCDevice device, const char *when) {
    enum RTCError e = rtcGetDeviceError(device);
    if (e == RTC_ERROR_NONE) return PEN_OK;
    return pen__error(ctx, e == RTC_ERROR_OUT_OF_MEMORY ? PEN_ERROR_MEMORY : PEN_ERROR_INTERNAL,
                      "reference: Embree error %d while %s", (int)e, when);
}

static pen_status build_embree(pen_context *ctx, pen_reference *ref) {
    const pen_scene *sc = ref->scene;
    char config[64] = PEN__EMBREE_ISA;
    int threads = pen_context_threads(ctx);
    if (threads > 0) snprintf(config, sizeof config, "threads=%d," PEN__EMBREE_ISA, threads);
    ref->device = rtcNewDevice(config);
    if (!ref->device)
        return pen__error(ctx, PEN_ERROR_INTERNAL, "reference: Embree device: error %d",
                          (int)rtcGetDeviceError(NULL));
    ref->rtc = rtcNewScene(ref->device);
    rtcSetSceneBuildQuality(ref->rtc, RTC_BUILD_QUALITY_HIGH);
    for (int o = 0; o < sc->object_count; ++o) {
        const pen_mesh *m = &sc->objects[o].mesh;
        if (m->triangle_count == 0) continue;
        RTCGeometry geom = rtcNewGeometry(ref->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        if (!pen__embree_fill_triangles(geom, ref->positions[o], (size_t)m->vertex_count,
                                        m->indices, (size_t)m->triangle_count)) {
            rtcReleaseGeometry(geom);
            return embree_status(ctx, ref->device, "allocating mesh buffers");
        }
        rtcCommitGeometry(geom);
        rtcAttachGeometryByID(ref->rtc, geom, (unsigned)o);
        rtcReleaseGeometry(geom);
    }
    if (sc->ground.enabled) {
        float h = sc->ground.half_size, y = sc->ground.height;
        RTCGeometry geom = rtcNewGeometry(ref->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        const float corners[12] = {-h, y, -h, -h, y, h, h, y, h, h, y, -h};
        const uint32_t tris[6] = {0, 1, 2, 0, 2, 3}; /* counter-clockwise seen from +Y */
        if (!pen__embree_fill_triangles(geom, corners, 4, tris, 2)) {
            rtcReleaseGeometry(geom);
            return embree_status(ctx, ref->device, "allocating ground buffers");
        }
        rtcCommitGeometry(geom);
        ref->ground_id = (unsigned)sc->object_count;
        rtcAttachGeometryByID(ref->rtc, geom, ref->ground_id);
        rtcReleaseGeometry(geom);
    }
    rtcCommitScene(ref->rtc);
    return embree_status(ctx, ref->device, "building the scene");
}

/* Whether the scene's SH lighting is its envmap's projection (with lights found in the map, the
 * projection of what they leave: pen_envmap_lighting, as the loader does). A scene may give "sh"
 * next to an envmap (optimized lighting saved with PEN_SCENE_SAVE_SH_LIGHTING): then the SH is
 * the lighting `render` uses and the map only the background, so AUTO must not light with the
 * map. The projection is deterministic, so a scene loaded from an envmap matches it to
 * rounding. */
static int sh_is_projection(pen_context *ctx, const pen_scene *sc) {
    const pen_lighting *lt = &sc->lighting;
    if (sc->sh_bands < 1 || sc->sh_bands > PEN_SH_MAX_BANDS) return 1; /* check_scene reports */
    float proj[PEN_SH_MAX_COEFFS][3];
    pen_light found[PEN_SCENE_MAX_LIGHTS];
    int count = 0, max = lt->lights_mode == PEN_LIGHTS_AUTO ? lt->lights_max : 0;
    max = max < 0 ? 0 : max > PEN_SCENE_MAX_LIGHTS ? PEN_SCENE_MAX_LIGHTS : max;
    pen_status st = pen_envmap_lighting(ctx, &lt->envmap, sc->sh_bands, lt->rotation_y_deg,
                                        lt->scale, max, proj, found, &count);
    if (st) {
        pen_context_clear_error(ctx); /* a broken map is reported by the envmap checks */
        return 1;
    }
    double diff = 0, norm = 0;
    for (int k = 0; k < pen_sh_coeffs(sc->sh_bands); ++k)
        for (int ch = 0; ch < 3; ++ch) {
            double d = (double)lt->sh[k][ch] - (double)proj[k][ch];
            diff += d * d;
            norm += (double)proj[k][ch] * (double)proj[k][ch];
        }
    return diff <= 1e-10 * norm;
}

pen_status pen_reference_create(pen_context *ctx, const pen_scene *scene,
                                pen_reference_lighting lighting, pen_reference **out) {
    if (!out) return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: no output");
    *out = NULL;
    if (!scene) return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: no scene");
    const int has_env = scene->lighting.envmap.data != NULL;
    if (lighting == PEN_REFERENCE_LIGHTING_AUTO)
        lighting = has_env && sh_is_projection(ctx, scene) ? PEN_REFERENCE_LIGHTING_ENVMAP
                                                           : PEN_REFERENCE_LIGHTING_SH;
    if (lighting != PEN_REFERENCE_LIGHTING_ENVMAP && lighting != PEN_REFERENCE_LIGHTING_SH)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: unknown lighting mode %d",
                          (int)lighting);
    if (lighting == PEN_REFERENCE_LIGHTING_ENVMAP && !has_env)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "reference: envmap lighting, but the scene's lighting has no envmap");
    int need_sh = lighting == PEN_REFERENCE_LIGHTING_SH || (scene->background_envmap && !has_env);
    pen_status st = check_scene(ctx, scene, need_sh);
    if (st) return st;

    pen_reference *ref = pen__calloc(ctx, 1, sizeof *ref, "reference");
    if (!ref) return PEN_ERROR_MEMORY;
    ref->scene = scene;
    ref->lighting = lighting;
    ref->ground_id = RTC_INVALID_GEOMETRY_ID;
    ref->sh_bands = scene->sh_bands;
    if (lighting == PEN_REFERENCE_LIGHTING_SH)
        pen_sh_zonal_clamped_cosine(ref->sh_bands, ref->cosine_zonal);
    double rot = (double)scene->lighting.rotation_y_deg * PEN_PI / 180.0;
    ref->rot_cos = (float)cos(rot);
    ref->rot_sin = (float)sin(rot);
    ref->object_count = scene->object_count;
    int n = scene->object_count;
    ref->positions = pen__calloc(ctx, n ? (size_t)n : 1, sizeof(float *), "reference objects");
    ref->normals = pen__calloc(ctx, n ? (size_t)n : 1, sizeof(float *), "reference objects");
    if (!ref->positions || !ref->normals) st = PEN_ERROR_MEMORY;
    float extent = 0.0f;
    for (int o = 0; o < n && !st; ++o)
        st = pose_object(ctx, &scene->objects[o], o, &ref->positions[o], &ref->normals[o], &extent);
    if (!st && scene->ground.enabled)
        extent = fmaxf(extent, fmaxf(fabsf(scene->ground.height), scene->ground.half_size));
    for (int k = 0; k < 3 && !st; ++k)
        extent = fmaxf(extent, fabsf(scene->camera.eye[k]));
    /* Embree asserts (aborts) on ray coordinates beyond about 1.8e18; the loaders' ranges keep
     * world space below about 2e12 (penumbra/scene.h), but a scene built in memory may not. */
    if (!st && !((double)extent <= PEN_REFERENCE_MAX_EXTENT))
        st = pen__error(ctx, PEN_ERROR_ARGUMENT,
                        "reference: world-space coordinates up to %g (posed meshes, ground, camera "
                        "eye), beyond the %g the ray tracer handles",
                        (double)extent, PEN_REFERENCE_MAX_EXTENT);
    /* Float positions carry about 1e-7 relative error and Embree's hit points a few ulps more:
     * 1e-5 of the extent clears them with a margin while staying far below visible detail. */
    ref->eps = 1e-5f * fmaxf(extent, 1.0f);
    if (!st && lighting == PEN_REFERENCE_LIGHTING_ENVMAP)
        st = pen__envmap_sampler_init(ctx, &scene->lighting.envmap, &ref->sampler);
    /* The full map already holds the lights found in it: only given ones (listed, or added
     * after the found ones) are added to it. The SH lighting is render's, the SH part plus every
     * light (docs/design.md sec. 2). */
    const pen_lighting *lt = &scene->lighting;
    const int added = lt->lights_mode == PEN_LIGHTS_GIVEN  ? lt->light_count
                      : lt->lights_mode == PEN_LIGHTS_AUTO ? lt->lights_added
                                                           : 0;
    if (!st && lighting == PEN_REFERENCE_LIGHTING_SH)
        pen__ref_lights_init(lt->lights, lt->light_count, &ref->lights);
    else if (!st && added > 0 && added <= lt->light_count)
        pen__ref_lights_init(lt->lights + (lt->light_count - added), added, &ref->lights);
    if (!st) st = build_embree(ctx, ref);
    if (st) {
        pen_reference_destroy(ref);
        return st;
    }
    *out = ref;
    return PEN_OK;
}

void pen_reference_destroy(pen_reference *ref) {
    if (!ref) return;
    if (ref->rtc) rtcReleaseScene(ref->rtc);
    if (ref->device) rtcReleaseDevice(ref->device);
    for (int o = 0; o < ref->object_count; ++o) {
        if (ref->positions) free(ref->positions[o]);
        if (ref->normals) free(ref->normals[o]);
    }
    free(ref->positions);
    free(ref->normals);
    pen__envmap_sampler_free(&ref->sampler);
    free(ref);
}

pen_reference_lighting pen_reference_lighting_mode(const pen_reference *ref) {
    return ref->lighting;
}

/* ---- Rendering --------------------------------------------------------------------------------
 */

static void render_pixel(const pen_reference *ref, int x, int y, int spp, int grid, uint64_t seed,
                         float out[3], float *coverage) {
    const pen_camera *cam = &ref->scene->camera;
    uint64_t pixel = (uint64_t)y * (uint64_t)cam->width + (uint64_t)x;
    double acc[3] = {0, 0, 0};
    int hits = 0;
    for (int s = 0; s < spp; ++s) {
        pen__rng rng = pen__rng_stream(seed, pixel, (uint64_t)s);
        float jx = pen__rng_next(&rng), jy = pen__rng_next(&rng);
        if (s < grid * grid) { /* stratified jitter on the grid x grid cells */
            jx = ((float)(s % grid) + jx) / (float)grid;
            jy = ((float)(s / grid) + jy) / (float)grid;
        }
        float dir[3], L[3];
        pen_camera_ray(cam, (float)x + jx, (float)y + jy, dir);
        hits += radiance(ref, cam->eye, dir, &rng, L);
        for (int ch = 0; ch < 3; ++ch)
            acc[ch] += (double)L[ch];
    }
    for (int ch = 0; ch < 3; ++ch)
        out[ch] = (float)(acc[ch] / spp);
    if (coverage) *coverage = (float)((double)hits / spp);
}

pen_status pen_reference_render(pen_context *ctx, const pen_reference *ref, int spp, uint64_t seed,
                                pen_image *out) {
    return pen_reference_render_coverage(ctx, ref, spp, seed, out, NULL);
}

pen_status pen_reference_render_coverage(pen_context *ctx, const pen_reference *ref, int spp,
                                         uint64_t seed, pen_image *out, pen_image *coverage) {
    if (!out) return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: no output image");
    memset(out, 0, sizeof *out);
    if (coverage) memset(coverage, 0, sizeof *coverage);
    if (!ref) return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: no reference");
    if (spp < 1 || spp > PEN_REFERENCE_MAX_SPP)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: spp %d out of [1, %d]", spp,
                          PEN_REFERENCE_MAX_SPP);
    const int w = ref->scene->camera.width, h = ref->scene->camera.height;
    pen_image img, cov = {0, 0, 0, NULL};
    pen_status st = pen_image_create(ctx, w, h, 3, &img);
    if (st) return st;
    if (coverage && (st = pen_image_create(ctx, w, h, 1, &cov))) {
        pen_image_free(&img);
        return st;
    }
    int grid = (int)floor(sqrt((double)spp));
    const int tiles_x = (w + TILE - 1) / TILE, tiles = tiles_x * ((h + TILE - 1) / TILE);
    int threads = pen__threads(ctx);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int t = 0; t < tiles; ++t) {
        int x0 = (t % tiles_x) * TILE, y0 = (t / tiles_x) * TILE;
        for (int y = y0; y < y0 + TILE && y < h; ++y)
            for (int x = x0; x < x0 + TILE && x < w; ++x) {
                size_t p = (size_t)y * (size_t)w + (size_t)x;
                render_pixel(ref, x, y, spp, grid, seed, img.data + 3 * p,
                             cov.data ? cov.data + p : NULL);
            }
    }
    for (size_t i = 0; i < 3 * (size_t)w * (size_t)h; ++i)
        if (!isfinite(img.data[i])) {
            size_t p = i / 3;
            pen_image_free(&img);
            pen_image_free(&cov);
            return pen__error(ctx, PEN_ERROR_INTERNAL,
                              "reference: pixel (%zu, %zu) is not finite (lighting or scene "
                              "values too large?)",
                              p % (size_t)w, p / (size_t)w);
        }
    *out = img;
    if (coverage) *coverage = cov;
    return PEN_OK;
}

pen_status pen_reference_irradiance(pen_context *ctx, const pen_reference *ref, const float x[3],
                                    const float n[3], int samples, uint64_t seed, float E[3]) {
    if (!ref || !x || !n || !E) return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: NULL input");
    if (samples < 1 || samples > PEN_REFERENCE_MAX_SPP)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: samples %d out of [1, %d]", samples,
                          PEN_REFERENCE_MAX_SPP);
    float nn[3] = {n[0], n[1], n[2]};
    if (!pen__finite3(x) || !pen__finite3(n) || !pen__normalize_f(nn))
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "reference: bad point or normal");
    float org[3];
    for (int i = 0; i < 3; ++i)
        org[i] = x[i] + ref->eps * nn[i];
    double acc[3] = {0, 0, 0};
    for (int s = 0; s < samples; ++s) {
        /* The stream key UINT64_MAX is outside the range of pixel indices used by render. */
        pen__rng rng = pen__rng_stream(seed, UINT64_MAX, (uint64_t)s);
        float e[3] = {0, 0, 0};
        irradiance_sample(ref, org, nn, &rng, e);
        for (int ch = 0; ch < 3; ++ch)
            acc[ch] += (double)e[ch];
    }
    for (int ch = 0; ch < 3; ++ch)
        E[ch] = (float)(acc[ch] / samples);
    return PEN_OK;
}

int pen_reference_lighting_parse(const char *name) {
    if (!name) return -1;
    if (strcmp(name, "envmap") == 0) return PEN_REFERENCE_LIGHTING_ENVMAP;
    if (strcmp(name, "sh") == 0) return PEN_REFERENCE_LIGHTING_SH;
    if (strcmp(name, "auto") == 0) return PEN_REFERENCE_LIGHTING_AUTO;
    return -1;
}

const char *pen_reference_lighting_name(pen_reference_lighting lighting) {
    switch (lighting) {
    case PEN_REFERENCE_LIGHTING_AUTO:
        return "auto";
    case PEN_REFERENCE_LIGHTING_ENVMAP:
        return "envmap";
    case PEN_REFERENCE_LIGHTING_SH:
        return "sh";
    }
    return "unknown";
}
