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
 * lighting's ridge ("lighting_ridge" times its largest diagonal entry), the light none; an
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

/* One light: the lattice, then the refinements; its direction into best. */
static pen_status find_one(pen_context *ctx, const pen_render_options *opt, search *S,
                           eye_data *E, int n, double r0, double best[3]) {
    const double spacing = sqrt(4.0 * PEN_PI / SEARCH_POINTS) / DEG; /* degrees */
    const double ymin = -sin(SEARCH_BELOW_DEG * DEG);
    double lowest = INFINITY;
    pen_status s = PEN_OK;
    for (int i = 0; !s && i < SEARCH_POINTS; ++i) {
        const double y = 1.0 - (2.0 * i + 1.0) / SEARCH_POINTS;
        if (y < ymin) break; /* y falls with i */
        const double rho = sqrt(fmax(0.0, 1.0 - y * y)), phi = i * PEN_PI * (3.0 - sqrt(5.0));
        double d[3] = {rho * cos(phi), y, rho * sin(phi)}, v;
        s = score(ctx, opt, S, E, n, d, fmax(r0, 0.5 * spacing), &v);
        if (!s && v < lowest) lowest = v, memcpy(best, d, sizeof d);
    }
    double step = spacing;
    for (int level = 0; !s && level < SEARCH_LEVELS; ++level) {
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
            s = score(ctx, opt, S, E, n, d, radius, &v);
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
    search *S = pen__calloc(ctx, 1, sizeof *S, "light search");
    eye_data *E = pen__calloc(ctx, (size_t)n, sizeof *E, "light search");
    pen_status s = S && E ? PEN_OK : PEN_ERROR_MEMORY;
    for (int e = 0; !s && e < n; ++e)
        s = eye_setup(ctx, sc, opt, &eyes[e], nb, S, &E[e]);
    if (!s) { /* the SH block, summed over the eyes in order */
        S->nb = S->m = nb;
        for (int c = 0; c < 3; ++c) {
            double top = 0.0;
            for (int j = 0; j < nb; ++j) {
                for (int k = 0; k <= j; ++k) {
                    double g = 0.0;
                    for (int e = 0; e < n; ++e)
                        g += dot(E[e].eye, E[e].cols[j].data, k == j ? NULL : E[e].cols[k].data,
                                 c);
                    S->G[c][j * MAX_COLS + k] = S->G[c][k * MAX_COLS + j] = g;
                }
                for (int e = 0; e < n; ++e)
                    S->b[c][j] += dot(E[e].eye, E[e].cols[j].data, E[e].resid, c);
                top = fmax(top, S->G[c][j * MAX_COLS + j]);
            }
            S->mu[c] = ridge * top;
            for (int e = 0; e < n; ++e)
                S->rr[c] += dot(E[e].eye, E[e].resid, NULL, c);
        }
    }
    double dirs[PEN_SCENE_MAX_LIGHTS][3];
    for (int l = 0; !s && l < count; ++l) { /* greedy: one light at a time */
        double v;
        s = find_one(ctx, opt, S, E, n, radius_deg, dirs[l]);
        if (!s) s = score(ctx, opt, S, E, n, dirs[l], radius_deg, &v); /* its column at r0 */
        if (!s) fix_candidate(S, E, n);
    }
    if (!s) { /* every light and the SH together */
        for (int c = 0; c < 3; ++c)
            solve_channel(S, c, NULL, 0.0);
        for (int k = 0; k < nb; ++k)
            for (int c = 0; c < 3; ++c)
                sc->lighting.sh[k][c] = (float)S->x[c][k];
        for (int l = 0; l < count; ++l) {
            pen_light *li = &sc->lighting.lights[l];
            for (int k = 0; k < 3; ++k) {
                li->direction[k] = (float)dirs[l][k];
                li->irradiance[k] = (float)fmin(S->x[k][nb + l], PEN_SCENE_MAX_IRRADIANCE);
            }
            li->angular_radius_deg = (float)radius_deg;
        }
        sc->lighting.light_count = count;
        sc->lighting.lights_mode = PEN_LIGHTS_GIVEN;
        if (renders) *renders = S->renders;
    }
    for (int e = 0; E && e < n; ++e) {
        for (int k = 0; E[e].cols && k < MAX_COLS; ++k)
            pen_image_free(&E[e].cols[k]);
        free(E[e].cols);
        free(E[e].resid);
        pen_image_free(&E[e].base);
        pen_image_free(&E[e].cand);
        pen_render_state_free(E[e].own);
    }
    free(E);
    free(S);
    return s;
}
