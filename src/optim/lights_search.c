/* The global search that creates disk lights when a task optimises "lights" and its scene has
 * none: a user does not know where the sun is, and local descent on a light's direction fails
 * when the predicted and the observed shadow do not overlap (supplement section 7), so the
 * direction is first found by trying many and keeping the one that explains the images best.
 *
 * At a fixed direction w and angular radius b the render is linear in the light's irradiance
 * and affine in the SH lighting: I = B + sum_k L_k A_k + E C(w, b), B the render with zero SH and
 * no light, A_k the SH basis images (as in the least-squares lighting, loss.c) and C the render
 * of the light alone with irradiance 1, minus B. A candidate direction therefore costs one render
 * per image (C), and its score is the exact minimum over the SH coefficients and the irradiance
 * of the task's l2 loss: per channel a small linear least-squares problem whose normal equations
 * reuse the SH block (summed once) and add one row. The SH block carries the least-squares
 * lighting's ridge (pen__optim_ridge_mu: "lighting_ridge" times its largest diagonal entry over the
 * number of images), the light none; an
 * irradiance must be >= 0, so a channel whose solution has a negative one drops that light and is
 * solved again (an active set; a light cannot subtract light). When the SH is not optimised it
 * stays as the scene has it and only the irradiances are solved.
 *
 * Directions: a Fibonacci lattice of SEARCH_POINTS points over the sphere (about 9 degrees apart),
 * of which those above SEARCH_BELOW_DEG below the horizon are tried (about 280), each as a disk of
 * radius max(start radius, half the spacing) so that the coarse score is smooth at the lattice's
 * scale; then SEARCH_LEVELS refinements around the best, each trying a 3 x 3 pattern in its
 * tangent plane with half the previous step (4.5 ... 0.28 degrees) and the radius max(start
 * radius, step). Cost per light: about 280 + 9 * 5 = 325 renders per image, plus sh_bands^2 + 1
 * renders per image for the basis. With K > 1 lights the search is greedy: the lights found so
 * far keep their directions, their columns join the fixed block, their irradiances are solved
 * again with every candidate for the next one. Everything runs in a fixed order (ties keep the
 * first), so the search is deterministic. */
#include "optim/optim_internal.h"

#include "penumbra/render.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define SEARCH_POINTS 512   /* lattice points over the whole sphere: sqrt(4 pi / 512) = 9 deg */
#define SEARCH_BELOW_DEG 5.0 /* directions down to this far below the horizon are tried */
#define SEARCH_LEVELS 5      /* refinements, each halving the step: 9 / 2^5 = 0.28 deg */
#define MAX_COLS (PEN_SH_MAX_COEFFS + PEN_SCENE_MAX_LIGHTS + 1)

static const double DEG = PEN_PI / 180.0;

/* One image of the search: its scene (the eye's camera; lighting as the basis needs it), the
 * renders it keeps and the weighted residual target - base. */
typedef struct eye_data {
    pen_scene view;
    const pen__optim_eye *eye;
    pen_image base, cand;
    pen_render_state *state; /* the eye's, or one of the search's own */
    pen_render_state *own;
    pen_image *cols; /* MAX_COLS: the SH basis, then the lights found so far */
    float *resid;    /* target - base */
} eye_data;

/* The normal equations per channel over every eye: the fixed columns (m of them: nb SH, then the
 * lights found) in G, b, and rr = the weighted squared residual; a candidate adds one row. */
typedef struct search {
    int nb, m;
    double G[3][MAX_COLS * MAX_COLS], b[3][MAX_COLS], rr[3], mu[3];
    double A[MAX_COLS * MAX_COLS], y[MAX_COLS]; /* solve scratch */
    double x[3][MAX_COLS];                       /* the last solve's solution per channel */
    int renders;
} search;

/* sum_p f w_p X_pc Y_pc over one eye's pixels (Y NULL: X itself), in pixel order. */
static double dot(const pen__optim_eye *e, const float *X, const float *Y, int c) {
    const size_t pixels = (size_t)e->target->width * (size_t)e->target->height;
    double sum = 0.0;
    for (size_t p = 0; p < pixels; ++p) {
        const double w = e->weight ? (double)e->weight[p] : 1.0;
        if (w == 0.0) continue;
        const double xv = (double)X[3 * p + (size_t)c];
        sum += w * xv * (Y ? (double)Y[3 * p + (size_t)c] : xv);
    }
    return sum * e->factor;
}

/* The light column of one eye: the view with the single light (direction d, radius r, unit
 * irradiance) minus the base. */
static pen_status light_column(pen_context *ctx, const pen_render_options *opt, eye_data *E,
                               const double d[3], double radius_deg, pen_image *out) {
    pen_scene v = E->view;
    pen_light *l = &v.lighting.lights[0];
    for (int k = 0; k < 3; ++k) {
        l->direction[k] = (float)d[k];
        l->irradiance[k] = 1.0f;
    }
    l->angular_radius_deg = (float)radius_deg;
    v.lighting.light_count = 1;
    v.lighting.lights_mode = PEN_LIGHTS_GIVEN;
    pen_status s = pen_render_fwd(ctx, &v, opt, E->state, out);
    const size_t n = 3 * (size_t)out->width * (size_t)out->height;
    for (size_t i = 0; !s && i < n; ++i)
        out->data[i] -= E->base.data[i];
    return s;
}

/* Per channel c: min over x of rr - 2 x.b + x^T G x + mu |x_SH|^2 with the light entries of x
 * >= 0, for the columns 0 .. m (G, b: m x m and m of S's fixed block; row: the extra column's
 * products, m + 1 of them, NULL for none; bc: its product with the residual). Fills S->x[c];
 * returns the minimum. */
static double solve_channel(search *S, int c, const double *row, double bc) {
    const int m = S->m + (row ? 1 : 0), nb = S->nb;
    int active[MAX_COLS];
    for (int j = 0; j < m; ++j)
        active[j] = 1;
    for (;;) {
        int idx[MAX_COLS], k = 0;
        for (int j = 0; j < m; ++j)
            if (active[j]) idx[k++] = j;
        for (int i = 0; i < k; ++i) {
            const int a = idx[i];
            S->y[i] = a < S->m ? S->b[c][a] : bc;
            for (int j = 0; j <= i; ++j) {
                const int bj = idx[j];
                double g = a < S->m ? S->G[c][a * MAX_COLS + bj] : row[bj];
                if (i == j) g += a < nb ? S->mu[c] : 1e-12 * g + 1e-30; /* SH: the ridge */
                S->A[i * k + j] = S->A[j * k + i] = g;
            }
        }
        memset(S->x[c], 0, sizeof S->x[c]);
        if (k == 0 || !pen__optim_solve_spd(S->A, S->y, k)) return S->rr[c];
        int worst = -1;
        double most = 0.0;
        for (int i = 0; i < k; ++i) {
            S->x[c][idx[i]] = S->y[i];
            if (idx[i] >= nb && S->y[i] < most) most = S->y[i], worst = idx[i];
        }
        if (worst < 0) break;
        active[worst] = 0; /* a light with negative irradiance: solve without it */
    }
    double v = S->rr[c]; /* at the optimum x^T (G + ridge) x = x.b */
    for (int j = 0; j < m; ++j)
        v -= S->x[c][j] * (j < S->m ? S->b[c][j] : bc);
    return v;
}

/* The score of a candidate light (the loss minimised over the SH and the irradiances, summed
 * over the channels); each eye's column is left in its `cand`. */
static pen_status score(pen_context *ctx, const pen_render_options *opt, search *S, eye_data *E,
                        int n, const double d[3], double radius_deg, double *out) {
    double row[3][MAX_COLS], bc[3];
    memset(row, 0, sizeof row);
    memset(bc, 0, sizeof bc);
    for (int e = 0; e < n; ++e) {
        pen_status s = light_column(ctx, opt, &E[e], d, radius_deg, &E[e].cand);
        if (s) return s;
        ++S->renders;
        for (int c = 0; c < 3; ++c) {
            for (int j = 0; j < S->m; ++j)
                row[c][j] += dot(E[e].eye, E[e].cand.data, E[e].cols[j].data, c);
            row[c][S->m] += dot(E[e].eye, E[e].cand.data, NULL, c);
            bc[c] += dot(E[e].eye, E[e].cand.data, E[e].resid, c);
        }
    }
    *out = 0.0;
    for (int c = 0; c < 3; ++c)
        *out += solve_channel(S, c, row[c], bc[c]);
    return PEN_OK;
}

/* Adds each eye's `cand` as a fixed column (a light found). */
static void fix_candidate(search *S, eye_data *E, int n) {
    const int j = S->m;
    for (int e = 0; e < n; ++e) {
        pen_image t = E[e].cols[j];
        E[e].cols[j] = E[e].cand;
        E[e].cand = t;
    }
    for (int c = 0; c < 3; ++c) {
        double *G = S->G[c];
        for (int k = 0; k <= j; ++k) {
            double g = 0.0;
            for (int e = 0; e < n; ++e)
                g += dot(E[e].eye, E[e].cols[j].data, k == j ? NULL : E[e].cols[k].data, c);
            G[j * MAX_COLS + k] = G[k * MAX_COLS + j] = g;
        }
        S->b[c][j] = 0.0;
        for (int e = 0; e < n; ++e)
            S->b[c][j] += dot(E[e].eye, E[e].cols[j].data, E[e].resid, c);
    }
    S->m = j + 1;
}

static void normalise(double d[3]) {
    const double l = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int k = 0; k < 3; ++k)
        d[k] /= l;
}

/* One resolution of the search: its images and normal equations. The coarse one holds the
 * images downsampled k x k (its own cameras, targets and weights); with k = 1 it is the fine one. */
typedef struct level {
    search *S;
    eye_data *E;
    int n, k;
    pen__optim_eye *eyes; /* k > 1: the downsampled eyes and what they point at */
    pen_camera *cams;
    pen_image *targets;
    float **weights;
} level;

/* One light: the lattice on the coarse level, then the refinements on the fine one; its
 * direction into best. */
static pen_status find_one(pen_context *ctx, const pen_render_options *opt, level *coarse,
                           level *fine, double r0, double best[3]) {
    const double spacing = sqrt(4.0 * PEN_PI / SEARCH_POINTS) / DEG; /* degrees */
    const double ymin = -sin(SEARCH_BELOW_DEG * DEG);
    double lowest = INFINITY;
    pen_status s = PEN_OK;
    for (int i = 0; !s && i < SEARCH_POINTS; ++i) {
        const double y = 1.0 - (2.0 * i + 1.0) / SEARCH_POINTS;
        if (y < ymin) break; /* y falls with i */
        const double rho = sqrt(fmax(0.0, 1.0 - y * y)), phi = i * PEN_PI * (3.0 - sqrt(5.0));
        double d[3] = {rho * cos(phi), y, rho * sin(phi)}, v;
        s = score(ctx, opt, coarse->S, coarse->E, coarse->n, d, fmax(r0, 0.5 * spacing), &v);
        if (!s && v < lowest) lowest = v, memcpy(best, d, sizeof d);
    }
    if (!s && !isfinite(lowest)) /* every candidate's loss not finite: no direction to refine */
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "optimize: lights search: no candidate direction has a finite loss "
                          "(are the target's values finite?)");
    double step = spacing;
    for (int lv = 0; !s && lv < SEARCH_LEVELS; ++lv) {
        step *= 0.5;
        const double radius = fmax(r0, step);
        /* a tangent frame at the best direction */
        const double *c = best;
        double t1[3] = {c[2], 0.0, -c[0]}; /* horizontal, unless c is vertical */
        if (t1[0] * t1[0] + t1[2] * t1[2] < 1e-12) t1[0] = 1.0, t1[2] = 0.0;
        normalise(t1);
        const double t2[3] = {c[1] * t1[2] - c[2] * t1[1], c[2] * t1[0] - c[0] * t1[2],
                              c[0] * t1[1] - c[1] * t1[0]};
        const double centre[3] = {c[0], c[1], c[2]}, tn = tan(step * DEG);
        static const int order[9][2] = {{0, 0},  {-1, -1}, {-1, 0}, {-1, 1}, {0, -1},
                                        {0, 1}, {1, -1},  {1, 0},  {1, 1}};
        lowest = INFINITY;
        for (int q = 0; !s && q < 9; ++q) {
            double d[3], v;
            for (int k = 0; k < 3; ++k)
                d[k] = centre[k] + tn * (order[q][0] * t1[k] + order[q][1] * t2[k]);
            normalise(d);
            if (d[1] < ymin) continue;
            s = score(ctx, opt, fine->S, fine->E, fine->n, d, radius, &v);
            if (!s && v < lowest) lowest = v, memcpy(best, d, sizeof d);
        }
    }
    return s;
}

/* The basis of one eye: base (zero SH when it is solved, else the scene's; no lights), the SH
 * columns, the residual. */
static pen_status eye_setup(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                            const pen__optim_eye *eye, int nb, search *S, eye_data *E) {
    E->eye = eye;
    E->view = eye->camera ? pen__optim_view_scene(sc, eye->camera) : *sc;
    E->view.lighting.light_count = 0;
    if (nb) memset(E->view.lighting.sh, 0, sizeof E->view.lighting.sh);
    E->cols = pen__calloc(ctx, MAX_COLS, sizeof *E->cols, "light search");
    const size_t n = 3 * (size_t)eye->target->width * (size_t)eye->target->height;
    E->resid = pen__malloc(ctx, n, sizeof(float), "light search");
    if (!E->cols || !E->resid) return PEN_ERROR_MEMORY;
    pen_status s = eye->state ? PEN_OK : pen_render_state_create(ctx, &E->own);
    E->state = eye->state ? eye->state : E->own;
    if (!s) s = pen_render_fwd(ctx, &E->view, opt, E->state, &E->base);
    ++S->renders;
    for (int k = 0; !s && k < nb; ++k) {
        pen_scene v = E->view;
        v.lighting.sh[k][0] = v.lighting.sh[k][1] = v.lighting.sh[k][2] = 1.0f;
        s = pen_render_fwd(ctx, &v, opt, E->state, &E->cols[k]);
        ++S->renders;
        for (size_t i = 0; !s && i < n; ++i)
            E->cols[k].data[i] -= E->base.data[i];
    }
    for (size_t i = 0; !s && i < n; ++i)
        E->resid[i] = eye->target->data[i] - E->base.data[i];
    return s;
}

/* The level's SH block and residual norm, summed over its eyes in order. */
static void level_block(level *L, int nb, double ridge) {
    search *S = L->S;
    eye_data *E = L->E;
    S->nb = S->m = nb;
    for (int c = 0; c < 3; ++c) {
        double top = 0.0;
        for (int j = 0; j < nb; ++j) {
            for (int k = 0; k <= j; ++k) {
                double g = 0.0;
                for (int e = 0; e < L->n; ++e)
                    g += dot(E[e].eye, E[e].cols[j].data, k == j ? NULL : E[e].cols[k].data, c);
                S->G[c][j * MAX_COLS + k] = S->G[c][k * MAX_COLS + j] = g;
            }
            for (int e = 0; e < L->n; ++e)
                S->b[c][j] += dot(E[e].eye, E[e].cols[j].data, E[e].resid, c);
            top = fmax(top, S->G[c][j * MAX_COLS + j]);
        }
        S->mu[c] = pen__optim_ridge_mu(ridge, top, L->n);
        for (int e = 0; e < L->n; ++e)
            S->rr[c] += dot(E[e].eye, E[e].resid, NULL, c);
    }
}

/* The coarse level's factor: the largest power of 2 dividing both sides of every image whose
 * images keep at least COARSE_MIN pixels on their shorter side (1: no coarse level). */
#define COARSE_MIN 48
static int coarse_factor(const pen__optim_eye *eyes, int n) {
    int k = 1;
    for (;;) {
        const int k2 = 2 * k;
        for (int e = 0; e < n; ++e) {
            const int w = eyes[e].target->width, h = eyes[e].target->height;
            if (w % k2 || h % k2 || (w < h ? w : h) / k2 < COARSE_MIN) return k;
        }
        k = k2;
    }
}

/* The eyes downsampled k x k: cameras with 1/k the pixels (a calibrated camera's intrinsics
 * scaled), block means of the targets and weights, factors times k^2 (a coarse pixel stands for
 * k^2 fine ones). */
static pen_status downsample(pen_context *ctx, const pen_scene *sc, const pen__optim_eye *eyes,
                             int n, int k, level *L) {
    L->k = k;
    L->eyes = pen__calloc(ctx, (size_t)n, sizeof *L->eyes, "light search");
    L->cams = pen__calloc(ctx, (size_t)n, sizeof *L->cams, "light search");
    L->targets = pen__calloc(ctx, (size_t)n, sizeof *L->targets, "light search");
    L->weights = pen__calloc(ctx, (size_t)n, sizeof *L->weights, "light search");
    if (!L->eyes || !L->cams || !L->targets || !L->weights) return PEN_ERROR_MEMORY;
    for (int e = 0; e < n; ++e) {
        const pen__optim_eye *f = &eyes[e];
        pen_camera *c = &L->cams[e];
        *c = f->camera ? *f->camera : sc->camera;
        c->width /= k, c->height /= k;
        c->fx /= (float)k, c->fy /= (float)k, c->cx /= (float)k, c->cy /= (float)k;
        const int w = c->width, h = c->height, W = f->target->width;
        pen_status s = pen_image_create(ctx, w, h, 3, &L->targets[e]);
        if (s) return s;
        if (f->weight) {
            L->weights[e] = pen__calloc(ctx, (size_t)w * (size_t)h, sizeof(float), "light search");
            if (!L->weights[e]) return PEN_ERROR_MEMORY;
        }
        const float inv = 1.0f / (float)(k * k);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                float sum[4] = {0.0f, 0.0f, 0.0f, 0.0f};
                for (int j = 0; j < k; ++j)
                    for (int i = 0; i < k; ++i) {
                        const size_t p = (size_t)(k * y + j) * (size_t)W + (size_t)(k * x + i);
                        for (int ch = 0; ch < 3; ++ch)
                            sum[ch] += f->target->data[3 * p + (size_t)ch];
                        if (f->weight) sum[3] += f->weight[p];
                    }
                const size_t q = (size_t)y * (size_t)w + (size_t)x;
                for (int ch = 0; ch < 3; ++ch)
                    L->targets[e].data[3 * q + (size_t)ch] = sum[ch] * inv;
                if (f->weight) L->weights[e][q] = sum[3] * inv;
            }
        L->eyes[e] = (pen__optim_eye){c, &L->targets[e], L->weights[e],
                                      f->factor * (double)(k * k), NULL};
    }
    return PEN_OK;
}

static pen_status level_init(pen_context *ctx, const pen_scene *sc, const pen_render_options *opt,
                             const pen__optim_eye *eyes, int n, int nb, double ridge, level *L) {
    L->n = n;
    L->S = pen__calloc(ctx, 1, sizeof *L->S, "light search");
    L->E = pen__calloc(ctx, (size_t)n, sizeof *L->E, "light search");
    pen_status s = L->S && L->E ? PEN_OK : PEN_ERROR_MEMORY;
    for (int e = 0; !s && e < n; ++e)
        s = eye_setup(ctx, sc, opt, &eyes[e], nb, L->S, &L->E[e]);
    if (!s) level_block(L, nb, ridge);
    return s;
}

static void level_free(level *L) {
    for (int e = 0; L->E && e < L->n; ++e) {
        for (int k = 0; L->E[e].cols && k < MAX_COLS; ++k)
            pen_image_free(&L->E[e].cols[k]);
        free(L->E[e].cols);
        free(L->E[e].resid);
        pen_image_free(&L->E[e].base);
        pen_image_free(&L->E[e].cand);
        pen_render_state_free(L->E[e].own);
    }
    for (int e = 0; L->targets && e < L->n; ++e)
        pen_image_free(&L->targets[e]);
    for (int e = 0; L->weights && e < L->n; ++e)
        free(L->weights[e]);
    free(L->E);
    free(L->S);
    free(L->eyes);
    free(L->cams);
    free(L->targets);
    free(L->weights);
}

pen_status pen__optim_lights_search(pen_context *ctx, pen_scene *sc,
                                    const pen_render_options *opt, const pen__optim_eye *eyes,
                                    int n, int count, int solve_sh, double ridge,
                                    double radius_deg, int *renders) {
    if (count < 1 || count > PEN_SCENE_MAX_LIGHTS || n < 1 || sc->lighting.light_count != 0)
        return pen__error(ctx, PEN_ERROR_ARGUMENT,
                          "light search: 1 .. %d lights into a scene without lights, from at "
                          "least one image",
                          PEN_SCENE_MAX_LIGHTS);
    const int nb = solve_sh ? sc->sh_bands * sc->sh_bands : 0;
    level fine, coarse_level;
    memset(&fine, 0, sizeof fine);
    memset(&coarse_level, 0, sizeof coarse_level);
    fine.k = 1;
    level *coarse = &fine;
    pen_status s = level_init(ctx, sc, opt, eyes, n, nb, ridge, &fine);
    const int k = coarse_factor(eyes, n);
    if (!s && k > 1) {
        coarse = &coarse_level;
        coarse->n = n; /* (for level_free, also on failure) */
        s = downsample(ctx, sc, eyes, n, k, coarse);
        if (!s) s = level_init(ctx, sc, opt, coarse->eyes, n, nb, ridge, coarse);
    }
    double dirs[PEN_SCENE_MAX_LIGHTS][3];
    for (int l = 0; !s && l < count; ++l) { /* greedy: one light at a time */
        double v;
        s = find_one(ctx, opt, coarse, &fine, radius_deg, dirs[l]);
        /* its column at the start radius joins the fixed block of both levels */
        if (!s) s = score(ctx, opt, fine.S, fine.E, n, dirs[l], radius_deg, &v);
        if (!s) fix_candidate(fine.S, fine.E, n);
        if (!s && coarse != &fine)
            s = score(ctx, opt, coarse->S, coarse->E, n, dirs[l], radius_deg, &v);
        if (!s && coarse != &fine) fix_candidate(coarse->S, coarse->E, n);
    }
    if (!s) { /* every light and the SH together, at full resolution */
        search *S = fine.S;
        for (int c = 0; c < 3; ++c)
            solve_channel(S, c, NULL, 0.0);
        for (int j = 0; j < nb; ++j)
            for (int c = 0; c < 3; ++c)
                sc->lighting.sh[j][c] = (float)S->x[c][j];
        for (int l = 0; l < count; ++l) {
            pen_light *li = &sc->lighting.lights[l];
            for (int c = 0; c < 3; ++c) {
                li->direction[c] = (float)dirs[l][c];
                li->irradiance[c] = (float)fmin(S->x[c][nb + l], PEN_SCENE_MAX_IRRADIANCE);
            }
            li->angular_radius_deg = (float)radius_deg;
        }
        sc->lighting.light_count = count;
        sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
        if (renders) *renders = fine.S->renders + (coarse != &fine ? coarse->S->renders : 0);
    }
    level_free(&fine);
    if (coarse != &fine) level_free(coarse);
    return s;
}
