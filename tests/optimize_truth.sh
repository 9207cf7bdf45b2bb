# Sourced by tests/cli_optimize.sh and tests/mpi_optimize.sh (not a test of its own): the ground
# truth their tasks recover, written by `truth ALBEDO-MEMBER` to standard output; needs $SRC.
# Ground truth: Spot (textured or not) with three inline spheres over the ground, 32x32, 2 bands.
truth() { # albedo-member
    cat <<JSON
{"camera": {"width": 32, "height": 32, "fov_y_deg": 40, "eye": [2.5, 1.8, 3.0], "target": [0, 0.5, 0]},
 "lighting": {"sh": [[1.5,1.4,1.3],[-1,-1,-1],[0.2,0.2,0.2],[-0.3,-0.3,-0.3]]},
 "sh_bands": 2,
 "objects": [{"mesh": "$SRC/data/meshes/spot_triangulated.obj",
              $1,
              "spheres": [{"center": [0, -0.07, 0.3], "radius": 0.36},
                          {"center": [0, 0.45, -0.4], "radius": 0.28},
                          {"center": [0, -0.55, 0.35], "radius": 0.2}],
              "pose": {"rotation_axis_angle_deg": [0, 30, 0], "translation": [0, 0.737, 0]}}],
 "ground": {"albedo": [0.7, 0.7, 0.7]},
 "background": [0.1, 0.2, 0.3]}
JSON
}
