/* The image loss of `penumbra optimize`, optionally weighted towards the target's shadows.
 *
 * Shadows cover few pixels, so a plain mean over the image gives them little say in the
 * objective, although they are what tells a shadow-aware solver where the light comes from and
 * where the occluder is. The task key "shadow_weight" = s gives pixel p the weight
 * w_p = 1 + s m_p, where m_p in [0, 1] says how much p is in shadow in the target:
 *     m_p = clamp(1 - Y(T_p) / Y(U_p), 0, 1),   Y = the mean of the three channels,
 * the fraction of the light an unshadowed model U predicts at p that the target T lacks. U is
 * the initial guess rendered without shadows. Its lighting is the scene's when the lighting is
 * known; when the lighting is optimised its initial value is a guess (black by default), so U
 * takes the lighting that best explains the target without shadows instead: the unshadowed
 * render is affine in the SH coefficients (image = B + sum_k L_k A_k, B the background), so this
 * is a linear least-squares problem per channel, solved from one render per coefficient. The
 * shadows darken that fit, so it is done twice, the second time over the pixels the first mask
 * calls lit (m < 0.1). Band 3 of the lighting never reaches an unshadowed diffuse surface (its
 * clamped-cosine coefficient is 0), so its columns vanish; a ridge keeps the normal equations
 * regular and those coefficients at 0. The mask needs the fitted image, which a tiny ridge
 * (1e-9 of the largest diagonal entry) leaves unbiased; "init": "fit" needs the coefficients,
 * which one view determines badly (the ground's normals all point up: it constrains one
 * combination of them), so it takes a ridge of 1e-2: on the Spot demo scene the fitted
 * lighting's relative error is 2.46 with 1e-9, 1.18 with 1e-4, 0.65 with 1e-2, 0.69 with 1e-1,
 * while the mask's fit then darkens lit pixels by up to 23%.
 *
 * The mask is computed once, before the first iteration, and held fixed: the weights are
 * constants of the objective, whose gradient is then the plain loss's gradient times w_p / mean
 * weight. The loss is normalised by the weights' sum, so s = 0 is exactly the plain mean and the
 * loss keeps the units of a mean squared (or absolute) error. The weighted loss itself is
 * computed beside the plain ones, in src/render/loss.c; this file makes the weights. */
#include "optim/optim_internal.h"

#include "penumbra/render.h"

#include <stdlib.h>
#include <string.h>

/* ---- The losses (groups.h) ------------------------------------------------------------------- */

/* The weighted means of src/render/loss.c by kind (its flag: l1 or not), forward and backward. */
#define WEIGHTED(name, l1)                                                                     \
    static pen_status name##_fwd(pen_context *ctx, const pen_image *image,                     \
                                 const pen_image *target, const float *weight, double *loss) { \
        return pen__loss_weighted_fwd(ctx, l1, image, target, weight, loss);                   \
    }                                                                                          \
    static void name##_bwd(const pen_image *image, const pen_image *target,                    \
                           const float *weight, double d_loss, pen_image *d_image) {           \
        pen__loss_weighted_bwd(l1, image, target, weight, d_loss, d_image);                    \
    }
WEIGHTED(l2, 0)
WEIGHTED(l1, 1)

/* The first is the default (pen_optim_task_default). Only l2 is the least squares' objective. */
const pen__optim_loss_kind pen__optim_losses[PEN__OPTIM_LOSSES] = {
    {PEN_OPTIM_LOSS_L2, "l2", pen_loss_l2, l2_fwd, l2_bwd, 1},
    {PEN_OPTIM_LOSS_L1, "l1", pen_loss_l1, l1_fwd, l1_bwd, 0},
};

const pen__optim_loss_kind *pen__optim_loss_find(int kind) {
    for (int k = 0; k < PEN__OPTIM_LOSSES; ++k)
        if ((int)pen__optim_losses[k].kind == kind) return &pen__optim_losses[k];
    return NULL;
}

/* ---- The shadow mask ------------------------------------------------------------------------- */

static float luminance(const float *p) { return (p[0] + p[1] + p[2]) / 3.0f; }

/* m_p from the target and the unshadowed model (both 3 channels). */
static void mask_from(const pen_image *target, const float *model, float *mask) {
    const size_t pixels = (size_t)target->width * (size_t)target->height;
    for (size_t p = 0; p < pixels; ++p) {
        const float u = luminance(model + 3 * p), t = luminance(target->data + 3 * p);
        mask[p] = u > 1e-6f ? fminf(fmaxf(1.0f - t / u, 0.0f), 1.0f) : 0.0f;
    }
}

int pen__optim_solve_spd(double *A, double *b, int n) {
    for (int j = 0; j < n; ++j) {
        double d = A[j * n + j];
        for (int k = 0; k < j; ++k)
            d -= A[j * n + k] * A[j * n + k];
        if (!(d > 0.0)) return 0;
        d = sqrt(d);
        A[j * n + j] = d;
        for (int i = j + 1; i < n; ++i) {
            double v = A[i * n + j];
            for (int k = 0; k < j; ++k)
                v -= A[i * n + k] * A[j * n + k];
            A[i * n + j] = v / d;
        }
    }
    for (int i = 0; i < n; ++i) { /* L y = b */
        double v = b[i];
        for (int k = 0; k < i; ++k)
            v -= A[i * n + k] * b[k];
        b[i] = v / A[i * n + i];
    }
    for (int i = n - 1; i >= 0; --i) { /* L^T x = y */
        double v = b[i];
        for (int k = i + 1; k < n; ++k)
            v -= A[k * n + i] * b[k];
        b[i] = v / A[i * n + i];
    }
    return 1;
}

/* The normal equations of the lighting fit, per channel c (G: 3 nb x nb lower triangles, b: 3
 * nb), summed over images: accumulate() adds one image's
 *     sum_p f w_p (base_pc + sum_k L_kc cols[k]_pc - target_pc)^2,
 * w_p = weight[p] (NULL: 1), f = factor; base: the render with zero lighting; cols[k]: the
 * render with coefficient k = 1 in every channel, minus base. Summed in double in pixel order. */
typedef struct normal_eqs {
    int nb;
    double *G, *b, *a; /* a: one row of the design matrix */
} normal_eqs;

static pen_status eqs_alloc(pen_context *ctx, normal_eqs *q, int nb) {
    q->nb = nb;
    q->G = pen__calloc(ctx, 3 * (size_t)nb * (size_t)nb, sizeof(double), "lighting fit");
    q->b = pen__calloc(ctx, 3 * (size_t)nb, sizeof(double), "lighting fit");
    q->a = pen__calloc(ctx, (size_t)nb, sizeof(double), "lighting fit");
    return q->G && q->b && q->a ? PEN_OK : PEN_ERROR_MEMORY;
}

static void eqs_free(normal_eqs *q) {
    free(q->G);
    free(q->b);
    free(q->a);
    memset(q, 0, sizeof *q);
}

static void accumulate(normal_eqs *q, const pen_image *target, const pen_image *base,
                       const pen_image *cols, const float *weight, double factor) {
    const size_t pixels = (size_t)target->width * (size_t)target->height;
    const int nb = q->nb;
    double *a = q->a;
    for (int c = 0; c < 3; ++c) {
        double *G = q->G + (size_t)c * (size_t)nb * (size_t)nb, *b = q->b + (size_t)c * (size_t)nb;
        for (size_t p = 0; p < pixels; ++p) {
            const double wp = (weight ? (double)weight[p] : 1.0) * factor;
            if (wp == 0.0) continue;
            const size_t i = 3 * p + (size_t)c;
            const double r = (double)target->data[i] - (double)base->data[i];
            for (int j = 0; j < nb; ++j)
                a[j] = (double)cols[j].data[i];
            for (int j = 0; j < nb; ++j) {
                if (a[j] == 0.0) continue; /* background, or band 3 without shadows */
                const double wa = wp * a[j];
                b[j] += wa * r;
                for (int k = 0; k <= j; ++k)
                    G[j * nb + k] += wa * a[k];
            }
        }
    }
}

double pen__optim_ridge_mu(double ridge, double top, int eyes) {
    return ridge * top / (double)(eyes > 1 ? eyes : 1);
}

/* Per channel c, the coefficients L_c (nb of them, into sh) minimising the accumulated sum +
 * mu_c |L_c|^2. mu[c] < 0 on entry: mu_c = pen__optim_ridge_mu (ridge times the largest diagonal
 * entry of channel c's normal equations, over the `eyes` images summed into them), written back
 * to mu[c]; mu[c] >= 0: taken as it is (a fixed objective across calls). Consumes the equations
 * (solved in place). */
static void solve_eqs(normal_eqs *q, double ridge, int eyes, double mu[3], float (*sh)[3]) {
    const int nb = q->nb;
    for (int c = 0; c < 3; ++c) {
        double *G = q->G + (size_t)c * (size_t)nb * (size_t)nb, *b = q->b + (size_t)c * (size_t)nb;
        double scale = 0.0;
        for (int j = 0; j < nb; ++j)
            scale = fmax(scale, G[j * nb + j]);
        const double m = mu && mu[c] >= 0.0 ? mu[c] : pen__optim_ridge_mu(ridge, scale, eyes);
        if (mu) mu[c] = m;
        for (int j = 0; j < nb; ++j) {
            for (int k = 0; k < j; ++k)
                G[k * nb + j] = G[j * nb + k];
            G[j * nb + j] += m + 1e-30; /* band 3's columns are zero without shadows */
        }
        /* not ok: no pixel sees the light at all: 0 */
        const int ok = pen__optim_solve_spd(G, b, nb);
        for (int k = 0; k < nb; ++k)
            sh[k][c] = ok ? (float)b[k] : 0.0f;
    }
}

/* base + sum_k sh[k] cols[k], per channel. */
static void model_image(const pen_image *base, const pen_image *cols, int nb,
                        const float (*sh)[3], float *model) {
    const size_t n = 3 * (size_t)base->width * (size_t)base->height;
    for (size_t i = 0; i < n; ++i) {
        double v = (double)base->data[i];
        for (int k = 0; k < nb; ++k)
            v += (double)sh[k][i % 3] * (double)cols[k].data[i];
        model[i] = (float)v;
    }
}

/* The render is affine in the lighting: base (zero lighting) and, per coefficient k, cols[k] =
 * the render with coefficient k = 1 in every channel, minus base (cols: nb zeroed images). */
static pen_status lighting_basis(pen_context *ctx, const pen_scene *sc,
                                 const pen_render_options *opt, pen_render_state *state,
                                 pen_image *base, pen_image *cols) {
    const int nb = sc->sh_bands * sc->sh_bands;
    pen_scene v = *sc; /* shallow: only the lighting differs */
    memset(v.lighting.sh, 0, sizeof v.lighting.sh);
    pen_status s = pen_render_fwd(ctx, &v, opt, state, base);
    const size_t n = 3 * (size_t)sc->camera.width * (size_t)sc->camera.height;
    for (int k = 0; !s && k < nb; ++k) {
        v.lighting.sh[k][0] = v.lighting.sh[k][1] = v.lighting.sh[k][2] = 1.0f;
        s = pen_render_fwd(ctx, &v, opt, state, &cols[k]);
        v.lighting.sh[k][0] = v.lighting.sh[k][1] = v.lighting.sh[k][2] = 0.0f;
        for (size_t i = 0; !s && i < n; ++i)
            cols[k].data[i] -= base->data[i];
    }
    return s;
}

static void basis_free(pen_image *base, pen_image *cols, int nb) {
    for (int k = 0; cols && k < nb; ++k)
        pen_image_free(&cols[k]);
    free(cols);
    pen_image_free(base);
}

/* The basis of one eye: its camera's view of the scene. */
static pen_status eye_basis(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                            const pen__optim_eye *e, pen_image *base, pen_image *cols) {
    const pen_scene v = e->camera ? pen__optim_view_scene(sc, e->camera) : *sc;
    return lighting_basis(ctx, &v, opt, e->state, base, cols);
}

/* The unshadowed fit, then the refit over each image's lit pixels (the first fit's shadow mask
 * m < 0.1, times the image's own weights). The basis of each image is rendered again for the
 * refit (renders are deterministic), so that only one image's basis is held at a time. */
pen_status pen__optim_fit_lighting_eyes(pen_context *ctx, const pen_scene *sc,
                                        const pen__optim_eye *eyes, int n, double ridge,
                                        float (*sh)[3]) {
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    const int nb = sc->sh_bands * sc->sh_bands;
    pen_image base = {0, 0, 0, NULL};
    pen_image *cols = pen__calloc(ctx, (size_t)nb, sizeof *cols, "lighting fit");
    normal_eqs q;
    memset(&q, 0, sizeof q);
    pen_status s = cols ? eqs_alloc(ctx, &q, nb) : PEN_ERROR_MEMORY;
    for (int pass = 0; pass < 2 && !s; ++pass) {
        float fitted[PEN_SH_MAX_COEFFS][3];
        memcpy(fitted, sh, sizeof fitted[0] * (size_t)nb);
        for (int e = 0; e < n && !s; ++e) {
            const size_t pixels = (size_t)eyes[e].target->width * (size_t)eyes[e].target->height;
            float *model = NULL, *mask = NULL;
            s = eye_basis(ctx, sc, &opt, &eyes[e], &base, cols);
            if (!s && pass == 1) {
                model = pen__malloc(ctx, 3 * pixels, sizeof(float), "lighting fit");
                mask = pen__malloc(ctx, pixels, sizeof(float), "lighting fit");
                if (!model || !mask) s = PEN_ERROR_MEMORY;
            }
            if (!s && pass == 1) {
                model_image(&base, cols, nb, (const float(*)[3])fitted, model);
                mask_from(eyes[e].target, model, mask);
                for (size_t p = 0; p < pixels; ++p) /* refit over the lit pixels */
                    mask[p] = (mask[p] < 0.1f ? 1.0f : 0.0f) *
                              (eyes[e].weight ? eyes[e].weight[p] : 1.0f);
            }
            if (!s)
                accumulate(&q, eyes[e].target, &base, cols, pass ? mask : eyes[e].weight,
                           eyes[e].factor);
            free(model);
            free(mask);
        }
        if (!s) solve_eqs(&q, ridge, n, NULL, sh);
        if (!s) memset(q.G, 0, sizeof(double) * 3 * (size_t)nb * (size_t)nb);
        if (!s) memset(q.b, 0, sizeof(double) * 3 * (size_t)nb);
    }
    basis_free(&base, cols, nb);
    eqs_free(&q);
    return s;
}

pen_status pen__optim_fit_lighting(pen_context *ctx, const pen_scene *sc, const pen_image *target,
                                   double ridge, float (*sh)[3]) {
    const pen__optim_eye eye = {NULL, target, NULL, 1.0, NULL};
    return pen__optim_fit_lighting_eyes(ctx, sc, &eye, 1, ridge, sh);
}

pen_status pen__optim_solve_lighting_eyes(pen_context *ctx, const pen_scene *sc,
                                          const pen_render_options *opt,
                                          const pen__optim_eye *eyes, int n, double ridge,
                                          double mu[3], float (*sh)[3]) {
    const int nb = sc->sh_bands * sc->sh_bands;
    pen_image base = {0, 0, 0, NULL};
    pen_image *cols = pen__calloc(ctx, (size_t)nb, sizeof *cols, "lighting solve");
    normal_eqs q;
    memset(&q, 0, sizeof q);
    pen_status s = cols ? eqs_alloc(ctx, &q, nb) : PEN_ERROR_MEMORY;
    for (int e = 0; e < n && !s; ++e) {
        s = eye_basis(ctx, sc, opt, &eyes[e], &base, cols);
        if (!s) accumulate(&q, eyes[e].target, &base, cols, eyes[e].weight, eyes[e].factor);
    }
    if (!s) solve_eqs(&q, ridge, n, mu, sh);
    basis_free(&base, cols, nb);
    eqs_free(&q);
    return s;
}

pen_status pen__optim_solve_lighting(pen_context *ctx, const pen_scene *sc,
                                     const pen_render_options *opt, pen_render_state *state,
                                     const pen_image *target,
                                     const float *weight, double ridge, double mu[3],
                                     float (*sh)[3]) {
    const pen__optim_eye eye = {NULL, target, weight, 1.0, state};
    return pen__optim_solve_lighting_eyes(ctx, sc, opt, &eye, 1, ridge, mu, sh);
}

pen_status pen__optim_shadow_mask(pen_context *ctx, const pen_scene *sc, const pen_image *target,
                                  int fit_lighting, float *mask) {
    pen_render_options opt = pen_render_options_default();
    opt.shadows = 0;
    pen_scene v = *sc; /* shallow: only the lighting may differ */
    pen_status s = fit_lighting ? pen__optim_fit_lighting(ctx, sc, target, PEN__OPTIM_RIDGE_MASK,
                                                        v.lighting.sh)
                                : PEN_OK;
    pen_image u = {0, 0, 0, NULL};
    if (!s) s = pen_render_fwd(ctx, &v, &opt, NULL, &u);
    if (!s) mask_from(target, u.data, mask);
    pen_image_free(&u);
    return s;
}
