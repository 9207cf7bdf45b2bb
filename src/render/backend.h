/* The frame's backend (docs/design.md sec. 6.4): the stages of a forward and backward pass that
 * run the shading kernels (src/shade), behind one interface, so that the frame (forward.c,
 * backward.c) never calls a kernel and another backend (a GPU's) is a new folder beside cpu/
 * with its own table, not edits across the frame's files.
 *
 * What the frame does itself, and hands over in the render state: the camera and the posed
 * geometry, the rasterized G-buffer, the per-pixel attributes (point, raw normal, facing sign,
 * uv and the texture's footprint), the posed spheres and their overlap weights, ground occlusion's
 * per-object lighting, the traced transfers (self.c, ground_shadow.c, which a backend reads
 * per pixel through pen__self_transfer_at and pen__ground_grid_at) and the background's cache;
 * after the backend: the silhouettes' antialiasing, and in the backward the texel, interpolation,
 * barycentric and pose scatters from the per-pixel gradients.
 *
 * What a backend does, in this order within a pass:
 * - prepare: the kernels' per-frame parameters into the state (st->params: bands, product table,
 *   exponential, epsilon; st->lights: the disk lights), and what depends on them alone (each
 *   object's horizon factors of the lights under ground occlusion, after
 *   pen__ground_occlusion_prepare). The frame's transfer traces read st->lights after it.
 * - shade_fwd: every pixel's colour into st->color (background, surface attributes n and rho,
 *   the SH term, the disk lights), keeping what its backward needs when `keep`; the shading
 *   stage's timings.
 * - shade_bwd: from st->d_color, the per-pixel gradients into st->d_x, d_nraw, d_uv, d_uvj and
 *   d_rho (every pixel written), and the small dense ones (lighting, constant albedos, spheres,
 *   the lights) into the backend's own accumulators, for the gradient groups of `wrt`.
 * - reduce: those accumulators summed in a fixed order (gradients independent of the thread
 *   count) and added into grad: the lighting (with the objects' `seen` mapped back), the lights,
 *   the albedos, the spheres and through them the pose.
 * The CPU backend keeps its buffers (tile groups, the kernel's store, accumulator rows,
 * workspaces) in the render state, whose struct, release and memory estimate are the frame's
 * (render_internal.h, state.c): a second backend would add its own there too. */
#ifndef PEN_RENDER_BACKEND_H
#define PEN_RENDER_BACKEND_H

#include "penumbra/render.h"

typedef struct pen__backend {
    const char *name;
    pen_status (*prepare)(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                          pen_render_state *st);
    pen_status (*shade_fwd)(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                            pen_render_state *st, int keep);
    pen_status (*shade_bwd)(pen_context *ctx, const pen_scene *sc, pen_render_state *st,
                            unsigned wrt);
    pen_status (*reduce)(pen_context *ctx, const pen_scene *sc, pen_render_state *st, unsigned wrt,
                         pen_render_grad *grad);
} pen__backend;

/* The CPU backend (src/render/cpu): tiles of 16 x 16 pixels over OpenMP threads, the fast kernel
 * of the processor's widest instruction set or the scalar one. */
const pen__backend *pen__backend_cpu(void);

#endif
