/* penumbra.h -- differentiable soft-shadow rendering with spherical-harmonics visibility.
 *
 * penumbra approximates objects by spheres, computes visibility in spherical harmonics as the SH
 * exponential of the summed per-sphere log-visibilities (Lyu et al., ICCV 2021), shades diffuse
 * surfaces under SH environment lighting on top of a rasterizer, and differentiates every stage.
 * Include this header for the whole public API; each concern has its own header below.
 *
 * The headers' usage examples (under a " * Usage" line in their first comment, render.h's for
 * one) are C that compiles and runs as written inside a main(), given the names their first line
 * lists (`// given: ctx, scene_path`); tests/cli_header_examples.sh runs every one. They leave
 * most statuses unchecked to stay short: a failed call leaves its message in the context
 * (pen_context_error, core.h), and a program checks each (README.md's C program shows how).
 */
#ifndef PENUMBRA_H
#define PENUMBRA_H

#include "penumbra/core.h"
#include "penumbra/envmap.h"
#include "penumbra/fit.h"
#include "penumbra/flat.h"
#include "penumbra/image.h"
#include "penumbra/io.h"
#include "penumbra/mesh.h"
#include "penumbra/metrics.h"
#include "penumbra/optim.h"
#include "penumbra/raster.h"
#include "penumbra/reference.h"
#include "penumbra/render.h"
#include "penumbra/scene.h"
#include "penumbra/sh.h"
#include "penumbra/spheres.h"
#include "penumbra/version.h"

#endif
