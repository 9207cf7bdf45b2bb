/* Calibration of the CALIBRATED SH-exponential model against ray-tested irradiance.
 *
 * The supplement (sec. 4.3) picks a(x) = exp(0.1 x), b(x) = exp(-0.2 x) by eye and suggests
 * fitting them to data. Since what decides image accuracy is the whole chain -- the blocker
 * depth epsilon, the log projection, the exponential's a and b, band truncation -- we fit the
 * chain's free parameters together: p = (epsilon, a1, a2, b1, b2, w_1 .. w_{L-1}), where w_l
 * scales band l of the log-visibility before exponentiation (a ringing window), for a fixed
 * number of squarings k (searched over 0..5, so the model stays smooth in F). The objective is
 * the mean over all rows (sphere count x lighting) of (median + 90th percentile) / 2 of the
 * relative irradiance error on the training set: the statistics the report shows, so that no row
 * is traded away for the average. The objective is cheap (the truth is precomputed) but not smooth everywhere
 * (|E - E_true|), so we use Nelder-Mead from two starts (epsilon 2 and 4).
 */
#include "core/internal.h"
#include "penumbra_research.h"

#include <string.h>

#define MAXP (5 + PEN_SH_MAX_BANDS)

typedef struct fit_problem {
    pen_context *ctx;
    const pen_accuracy_set *set;
    int bands, squarings, np;
    int evaluations;
} fit_problem;

static pen_sh_exp_model model_from(const fit_problem *fp, const double *p, double *eps) {
    pen_sh_exp_model m = pen_sh_exp_model_default(PEN_SH_EXP_CALIBRATED, fp->bands);
    m.squarings = fp->squarings;
    *eps = fabs(p[0]);
    m.epsilon = *eps;
    m.a1 = p[1], m.a2 = p[2], m.b1 = p[3], m.b2 = p[4];
    m.window[0] = 1.0;
    for (int l = 1; l < PEN_SH_MAX_BANDS; ++l)
        m.window[l] = l < fp->bands ? fabs(p[4 + l]) : fabs(p[4 + fp->bands - 1]);
    return m;
}

static double objective(fit_problem *fp, const double *p) {
    double eps;
    pen_sh_exp_model m = model_from(fp, p, &eps);
    pen_accuracy_stats st[PEN_ACCURACY_COUNTS][PEN_ACCURACY_MAX_LIGHTS];
    if (pen_accuracy_evaluate(fp->ctx, fp->set, fp->bands, &m, eps, st)) return HUGE_VAL;
    const int nl = pen_accuracy_light_count(fp->set);
    double sum = 0;
    for (int c = 0; c < PEN_ACCURACY_COUNTS; ++c)
        for (int l = 0; l < nl; ++l) sum += 0.5 * (st[c][l].median + st[c][l].p90);
    fp->evaluations++;
    const double v = sum / (PEN_ACCURACY_COUNTS * nl);
    return isfinite(v) ? v : HUGE_VAL;
}

/* Nelder-Mead with the standard coefficients (reflection 1, expansion 2, contraction 1/2,
 * shrink 1/2); stops after `iters` iterations or when the simplex's values agree to 1e-7. */
static double nelder_mead(fit_problem *fp, double *x, const double *step, int iters) {
    const int n = fp->np;
    double S[MAXP + 1][MAXP], f[MAXP + 1];
    for (int i = 0; i <= n; ++i) {
        memcpy(S[i], x, sizeof(double) * (size_t)n);
        if (i > 0) S[i][i - 1] += step[i - 1];
        f[i] = objective(fp, S[i]);
    }
    for (int it = 0; it < iters; ++it) {
        /* order: best first */
        for (int i = 1; i <= n; ++i)
            for (int j = i; j > 0 && f[j] < f[j - 1]; --j) {
                double t = f[j];
                f[j] = f[j - 1], f[j - 1] = t;
                for (int k = 0; k < n; ++k) t = S[j][k], S[j][k] = S[j - 1][k], S[j - 1][k] = t;
            }
        if (f[n] - f[0] < 1e-7) break;
        double c[MAXP] = {0}, xr[MAXP], xe[MAXP], xc[MAXP];
        for (int i = 0; i < n; ++i)
            for (int k = 0; k < n; ++k) c[k] += S[i][k] / n;
        for (int k = 0; k < n; ++k) xr[k] = c[k] + (c[k] - S[n][k]);
        const double fr = objective(fp, xr);
        if (fr < f[0]) {
            for (int k = 0; k < n; ++k) xe[k] = c[k] + 2.0 * (c[k] - S[n][k]);
            const double fe = objective(fp, xe);
            if (fe < fr) memcpy(S[n], xe, sizeof xe), f[n] = fe;
            else memcpy(S[n], xr, sizeof xr), f[n] = fr;
        } else if (fr < f[n - 1]) {
            memcpy(S[n], xr, sizeof xr), f[n] = fr;
        } else {
            const int outside = fr < f[n];
            for (int k = 0; k < n; ++k)
                xc[k] = outside ? c[k] + 0.5 * (xr[k] - c[k]) : c[k] + 0.5 * (S[n][k] - c[k]);
            const double fc = objective(fp, xc);
            if (fc < (outside ? fr : f[n])) {
                memcpy(S[n], xc, sizeof xc), f[n] = fc;
            } else {
                for (int i = 1; i <= n; ++i) {
                    for (int k = 0; k < n; ++k) S[i][k] = S[0][k] + 0.5 * (S[i][k] - S[0][k]);
                    f[i] = objective(fp, S[i]);
                }
            }
        }
    }
    int best = 0;
    for (int i = 1; i <= n; ++i)
        if (f[i] < f[best]) best = i;
    memcpy(x, S[best], sizeof(double) * (size_t)n);
    return f[best];
}

pen_status pen_accuracy_calibrate(pen_context *ctx, const pen_accuracy_set *train, int bands,
                                  pen_sh_exp_model *out, double *objective_out) {
    if (bands < 2 || bands > PEN_ACCURACY_MAX_BANDS)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "calibration bands must be in [2, %d], got %d",
                          PEN_ACCURACY_MAX_BANDS, bands);
    fit_problem fp = {ctx, train, bands, 0, 4 + bands, 0};
    double best_f = HUGE_VAL, best_p[MAXP] = {0};
    int best_k = 0;
    for (int k = 0; k <= 5; ++k) {
        fp.squarings = k;
        const double starts[2] = {2.0, 4.0};
        for (int s = 0; s < 2; ++s) {
            double p[MAXP] = {starts[s], 0.1, 0.0, -0.2, 0.0};
            double step[MAXP] = {0.5, 0.1, 0.02, 0.1, 0.02};
            for (int l = 1; l < bands; ++l) p[4 + l] = 1.0, step[4 + l] = 0.1;
            /* two restarts shake Nelder-Mead out of a collapsed simplex */
            double f = HUGE_VAL;
            for (int r = 0; r < 3; ++r) f = nelder_mead(&fp, p, step, 300);
            /* Each squaring costs one SH product per point: take more of them only for a
             * clear (1 %) gain. */
            const double need = k > best_k && best_f < HUGE_VAL ? 0.99 * best_f : best_f;
            if (f < need || (k == best_k && f < best_f))
                best_f = f, best_k = k, memcpy(best_p, p, sizeof p);
        }
    }
    fp.squarings = best_k;
    double eps;
    *out = model_from(&fp, best_p, &eps);
    if (objective_out) *objective_out = best_f;
    return PEN_OK;
}
