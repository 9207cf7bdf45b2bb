/* The background of the full frame: what a pixel that sees neither an object nor the ground shows,
 * the constant background colour or the environment map in the pixel's ray direction
 * (pen_envmap_eval: the full-resolution map, not its SH projection, and not differentiated).
 *
 * Design
 * - The background seen through the environment map costs trigonometry per pixel (a tenth of an
 *   optimisation step's forward at 512^2) yet depends on nothing that an optimiser changes. The
 *   state keeps the last frame's (st->bg) with what it was computed from (st->bg_key: the
 *   camera, the map's rotation, scale, size and a hash of its pixels) and reuses it when they are
 *   the same.
 * - A cache is an optimisation, never a reason to fail: without memory for it each background
 *   pixel is computed during the shading, as before the cache existed.
 */
#include "core/internal.h"
#include "render/render_internal.h"

#include <math.h>
#include <string.h>

/* Unit direction of the ray through the centre of pixel (px, py). */
static void pixel_dir(const pen_view *v, int px, int py, float dir[3]) {
    double d[3];
    pen_view_ray(v, px + 0.5, py + 0.5, d);
    const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int a = 0; a < 3; ++a)
        dir[a] = (float)(d[a] / len);
}

static void background_fwd(const pen_scene *sc, const pen_view *v, int px, int py, float rgb[3]) {
    if (!sc->background_envmap) {
        for (int ch = 0; ch < 3; ++ch)
            rgb[ch] = sc->background[ch];
        return;
    }
    float dir[3];
    pixel_dir(v, px, py, dir);
    pen_envmap_eval(&sc->lighting.envmap, sc->lighting.rotation_y_deg, sc->lighting.scale, dir,
                    rgb);
}

/* The pixels are compared by a 64-bit hash, so a map edited in place is noticed. */
static uint64_t envmap_hash(const pen_image *env) {
    return pen__render_hash32(env->data,
                              (size_t)env->width * (size_t)env->height * (size_t)env->channels);
}

void pen__background_prepare(pen_context *ctx, const pen_scene *sc, pen_render_state *st) {
    st->bg_use = 0;
    if (!sc->background_envmap) return;
    pen__bg_key k;
    memset(&k, 0, sizeof k);
    k.camera = sc->camera;
    k.data = sc->lighting.envmap.data;
    k.width = sc->lighting.envmap.width, k.height = sc->lighting.envmap.height;
    k.channels = sc->lighting.envmap.channels;
    k.rotation_y_deg = sc->lighting.rotation_y_deg, k.scale = sc->lighting.scale;
    /* (a caller that vouches for the map's pixels keeps the hash of the previous forward) */
    k.hash = st->vouched & PEN__VOUCH_MAP && st->bg_valid ? st->bg_key.hash
                                                          : envmap_hash(&sc->lighting.envmap);
    if (st->bg_valid && !memcmp(&k, &st->bg_key, sizeof k)) {
        st->bg_use = 2;
        return;
    }
    st->bg_valid = 0;
    const size_t np = (size_t)st->width * (size_t)st->height;
    if (PEN__BUF_RESERVE(ctx, st->bg, 3 * np, "background cache")) {
        pen_context_clear_error(ctx); /* not the render's failure: it goes on without the cache */
        return;
    }
    /* Filled for every pixel now, not only for those that show the background in this frame:
     * the cache outlives the frame, and a pixel covered by the object now may show the
     * background after the object moves (filling on the fly left such pixels uninitialised). */
    const int w = st->width, h = st->height;
    const pen_view *view = &st->view;
    float *bg = st->bg.data;
    const int threads = pen__threads(ctx);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int py = 0; py < h; ++py)
        for (int px = 0; px < w; ++px)
            background_fwd(sc, view, px, py, bg + 3 * ((size_t)py * (size_t)w + (size_t)px));
    st->bg_key = k;
    st->bg_valid = 1;
    st->bg_use = 2;
}

void pen__background_pixel(const pen_scene *sc, const pen_render_state *st, int px, int py,
                           size_t i) {
    float *rgb = st->color.data + 3 * i;
    if (st->bg_use) {
        memcpy(rgb, st->bg.data + 3 * i, 3 * sizeof(float));
        return;
    }
    background_fwd(sc, &st->view, px, py, rgb);
}
