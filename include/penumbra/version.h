/* penumbra/version.h -- the version of these headers.
 *
 * Kept equal to project(VERSION) in CMakeLists.txt: configuring fails when the two disagree, so
 * a release changes both lines together. pen_version() returns the library's PEN_VERSION_STRING,
 * which lets a program compare the headers it was compiled against with the library it runs on.
 * Semantic versioning; before 1.0 a minor release may change the API, and the shared library's
 * SONAME (libpenumbra.so.0) stays at 0 until then.
 */
#ifndef PENUMBRA_VERSION_H
#define PENUMBRA_VERSION_H

#define PEN_VERSION_MAJOR 0
#define PEN_VERSION_MINOR 2
#define PEN_VERSION_PATCH 0
#define PEN_VERSION_STRING "0.2.0"

/* One number that orders versions: 0.1.0 -> 100, 1.2.3 -> 10203. */
#define PEN_VERSION_NUMBER (PEN_VERSION_MAJOR * 10000 + PEN_VERSION_MINOR * 100 + PEN_VERSION_PATCH)

#endif
