/* The calibrated SH-exponential model's parameters, one row per band count, fitted offline by
 * `penumbra sh-accuracy --calibrate` against ray-tested irradiance (docs/sh-accuracy.md). */
#ifndef PEN_SH_CALIBRATION_H
#define PEN_SH_CALIBRATION_H

#include "penumbra/sh.h"

#include <stdlib.h>

typedef struct pen__sh_calibration {
    int bands;
    double epsilon;
    int squarings;
    double a1, a2, b1, b2;
    double window[PEN_SH_MAX_BANDS];
} pen__sh_calibration;

extern const pen__sh_calibration pen__sh_calibrations[];
extern const int pen__sh_calibration_count;

#endif
