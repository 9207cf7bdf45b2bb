/* Shipped parameters of the calibrated SH exponential (see calibration.h and
 * docs/sh-accuracy.md), one row per band count: bands, epsilon, squarings, a1, a2, b1, b2,
 * per-band gains w_l of the log-visibility (w_0 = 1; entries past the band count are unused).
 * Produced by `penumbra sh-accuracy --sets 150 --calibrate` (training seed 1, 150 sphere sets per
 * sphere count, sky+sun, city.hdr and interior.hdr lighting); the comments give the training
 * objective, the mean over rows of (median + p90) / 2 of the relative irradiance error. */
#include "sh/calibration.h"

const pen__sh_calibration pen__sh_calibrations[] = {
    {3, 2.04712, 2, -0.00405546, -0.0136669, -0.563217, 0.238899, {1, 0.0868428, 1.11718, 1.11718, 1.11718, 1.11718, 1.11718, 1.11718}}, /* training objective 0.03185 */
    {4, 1.19469, 2, 0.0119169, 0.0337381, 0.0283923, 0.032014, {1, 1.0735, 0.6447, 1.2398, 1.2398, 1.2398, 1.2398, 1.2398}}, /* training objective 0.03323 */
    {5, 1.35989, 2, 0.00173152, -0.0211398, -0.138925, 0.0443387, {1, 0.809943, 1.1722, 0.576807, 1.46302, 1.46302, 1.46302, 1.46302}}, /* training objective 0.03312 */
    {6, 1.08962, 1, 0.0067709, -0.00654455, 0.244439, -0.148176, {1, 1.19914, 0.737174, 1.41954, 0.484921, 1.59368, 1.59368, 1.59368}}, /* training objective 0.02942 */
};
const int pen__sh_calibration_count =
    (int)(sizeof pen__sh_calibrations / sizeof pen__sh_calibrations[0]);
