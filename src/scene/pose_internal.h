/* Internal interface of src/scene/pose.c: the rotation in double with its derivative, for the
 * pose backward and its finite-difference tests. */
#ifndef PEN_POSE_INTERNAL_H
#define PEN_POSE_INTERNAL_H

/* R (row-major 3x3) of the rotation vector w (radians, axis * angle). dR (may be NULL) receives
 * dR/dw_j as 9 entries at dR + 9 j. */
void pen__pose_rotation_d(const double w[3], double R[9], double dR[27]);

#endif
