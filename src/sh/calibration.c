/* Shipped parameters of the calibrated SH exponential (see calibration.h). Provisional values
 * until the calibration run replaces them: the paper's a and b with three fixed squarings. */
#include "sh/calibration.h"

const pen__sh_calibration pen__sh_calibrations[] = {
    {4, 4.0, 3, 0.1, 0.0, -0.2, 0.0, {1, 1, 1, 1, 1, 1, 1, 1}},
};
const int pen__sh_calibration_count =
    (int)(sizeof pen__sh_calibrations / sizeof pen__sh_calibrations[0]);
