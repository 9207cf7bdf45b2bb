/* SH exponential models: the fixed PAPER and EXACT definitions, the CALIBRATED parameters, and
 * method names. The operations themselves are in sh_ops.inc. */
#include "sh/calibration.h"
#include "sh/sh_internal.h"

#include <string.h>

pen_sh_exp_model pen_sh_exp_model_default(pen_sh_exp_method method, int bands) {
    pen_sh_exp_model m;
    memset(&m, 0, sizeof m);
    m.method = method;
    m.epsilon = 4.0; /* the supplement's blocker depth */
    for (int l = 0; l < PEN_SH_MAX_BANDS; ++l) m.window[l] = 1.0;
    if (method != PEN_SH_EXP_CALIBRATED) return m;
    /* The nearest calibrated band count. */
    const pen__sh_calibration *best = NULL;
    for (int i = 0; i < pen__sh_calibration_count; ++i) {
        const pen__sh_calibration *c = &pen__sh_calibrations[i];
        if (!best || abs(c->bands - bands) < abs(best->bands - bands)) best = c;
    }
    if (!best) return m;
    m.squarings = best->squarings;
    m.a1 = best->a1, m.a2 = best->a2, m.b1 = best->b1, m.b2 = best->b2;
    m.epsilon = best->epsilon;
    for (int l = 1; l < PEN_SH_MAX_BANDS; ++l)
        m.window[l] = l < best->bands ? best->window[l] : best->window[best->bands - 1];
    return m;
}

int pen_sh_exp_method_parse(const char *name) {
    if (!name) return -1;
    if (!strcmp(name, "calibrated") || !strcmp(name, "default")) return PEN_SH_EXP_CALIBRATED;
    if (!strcmp(name, "paper")) return PEN_SH_EXP_PAPER;
    if (!strcmp(name, "exact")) return PEN_SH_EXP_EXACT;
    return -1;
}

const char *pen_sh_exp_method_name(pen_sh_exp_method method) {
    switch (method) {
    case PEN_SH_EXP_CALIBRATED: return "calibrated";
    case PEN_SH_EXP_PAPER: return "paper";
    case PEN_SH_EXP_EXACT: return "exact";
    }
    return "unknown";
}
