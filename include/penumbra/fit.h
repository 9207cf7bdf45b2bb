/* penumbra/fit.h -- fitting a set of spheres to a closed triangle mesh (supplement sec. 2); with
 * it, a scene made ready to render (pen_scene_prepare: the fits and overlap weights) and what a
 * user is told before it renders (pen_scene_check: bounds, lights, likely mistakes;
 * pen_mesh_edges_count: whether a mesh is closed, as the fit needs).
 *
 * The fit voxelizes the mesh's padded bounding box, classifies every voxel centre as inside or
 * outside the mesh, samples points on the surface, places N spheres inside the mesh (k-means on
 * the inside voxels, radius = distance to the surface), moves some of them to parts the seeds
 * left without (thin parts, from each sample's medial ball: the allocation, docs/fit-spheres.md)
 * and then minimizes with Adam
 *
 *     E = E_SOV + w_s * E_surface                                   (supplement eq. 5)
 *     E_SOV     = sum over outside voxels v   of 1 - prod_i phi(s_i(v))   (eq. 3, Og = 1 only)
 *     E_surface = sum over surface samples p  of     prod_i phi(s_i(p))   (eq. 4)
 *     phi(s) = tanh(relu(s / sigma^2)),  s_i(x) = |x - c_i|^2 - r_i^2      (eq. 2)
 *
 * sigma^2 is a length scale that makes the energy independent of the mesh's units and keeps tanh
 * out of saturation; see docs/fit-spheres.md for its definition and the measured defaults.
 *
 * Usage (32 spheres for a mesh file, saved as a scene's "spheres" file, as `fit-spheres` does):
 *
 *     // given: ctx, mesh_path (a closed mesh)
 *     pen_mesh mesh;
 *     pen_mesh_load(ctx, mesh_path, &mesh);                      // io.h
 *     pen_fit_settings s;
 *     pen_fit_settings_default(&s);
 *     pen_spheres spheres;
 *     pen_fit_metrics m;
 *     if (pen_spheres_fit(ctx, &mesh, 32, &s, &spheres, &m) != PEN_OK) {
 *         fprintf(stderr, "%s\n", pen_context_error(ctx));       // what is wrong, and where
 *         return 1;
 *     }
 *     printf("%.1f %% of the surface covered\n", 100 * m.surface_coverage);
 *     char extra[2048];                                          // the metrics and settings
 *     pen_fit_json(&s, &m, extra, sizeof extra);
 *     pen_spheres_save(ctx, "spheres.json", &spheres, extra);    // io.h
 *     pen_spheres_free(&spheres);
 *     pen_mesh_free(&mesh);
 *
 * Inside test: every voxel centre gets six votes, one per half-ray along +-x, +-y, +-z from the
 * centre to outside the bounds; a vote says "inside" when the winding number counted along that
 * half-ray (signed crossings: +1 entering, -1 leaving) is non-zero. The voxel is inside when at
 * least four of the six votes say so. For a closed mesh (any orientation, overlapping closed
 * components included) all votes agree; for a mesh with small holes only the half-rays that pass
 * through a hole vote wrongly, and the majority stays right.
 */
#ifndef PENUMBRA_FIT_H
#define PENUMBRA_FIT_H

#include "penumbra/core.h"
#include "penumbra/image.h"
#include "penumbra/mesh.h"
#include "penumbra/scene.h"
#include "penumbra/spheres.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Largest sphere count and voxel resolution the fitter accepts. */
#define PEN_FIT_MAX_SPHERES 4096
#define PEN_FIT_MAX_VOXELS 512

/* Fit settings. A field left at 0 takes its default (pen_fit_settings_default fills them in). The
 * result depends on the settings and the mesh only: the same spheres, bit for bit, for any
 * thread count (sums run per cell and are added in a fixed order). */
typedef struct pen_fit_settings {
    int voxels;            /* voxels along the longest axis of the padded bounds (cubic voxels) */
    double surface_weight; /* w_s of eq. 5 */
    double margin_voxels;  /* kappa: soft margin, see sigma^2 in docs/fit-spheres.md */
    double samples_per_voxel_area; /* surface samples per h^2 of surface (h = voxel edge) */
    int iterations;                /* Adam iterations (the most; it stops early when E settles) */
    double learning_rate;          /* Adam step in voxel edges (decays by a cosine to 5 % of it) */
    unsigned long long seed;       /* k-means++ seeding and surface sampling */
} pen_fit_settings;

/* What a sphere set leaves of a mesh's surface uncovered (pen_spheres_coverage): the surface
 * points farther than `tolerance` outside every sphere, measured on area-uniform samples, and
 * the largest connected part they form (samples closer than a few sample spacings linked). */
typedef struct pen_coverage_report {
    double tolerance;         /* PEN_SPHERES_COVERAGE_TOLERANCE x the mesh's longest side */
    double uncovered;         /* share of the surface area left uncovered, in [0, 1] */
    double largest_share;     /* share of the whole surface area in the largest uncovered part */
    float largest_centre[3];  /* that part's centre (mean of its samples), mesh coordinates */
    float largest_lo[3];      /* its bounding box */
    float largest_hi[3];
    int parts;                /* connected uncovered parts */
    int samples;              /* surface samples measured (PEN_SPHERES_COVERAGE_SAMPLES) */
} pen_coverage_report;

/* The tolerance, as a share of the mesh's longest side: a gap of 1 % between spheres and surface
 * changes a shadow little; a part left out entirely (a leg, a handle) is farther out than that. */
#define PEN_SPHERES_COVERAGE_TOLERANCE 0.01
#define PEN_SPHERES_COVERAGE_SAMPLES 16384
/* Above this uncovered share `penumbra fit-spheres`, `render` and `optimize` warn (the fits of
 * the bundled scenes leave 1 to 3 %; docs/fit-spheres.md, "Coverage report"). */
#define PEN_SPHERES_COVERAGE_WARN 0.10

/* Measures what `spheres` leave of `mesh`'s surface uncovered (both in the same coordinates),
 * on PEN_SPHERES_COVERAGE_SAMPLES area-uniform samples with a fixed seed: deterministic, and
 * independent of the thread count and of any fit setting. An empty set leaves everything
 * uncovered. Errors: an invalid mesh, a sphere with a non-finite value or a negative radius. */
PEN_API pen_status pen_spheres_coverage(pen_context *ctx, const pen_mesh *mesh,
                                        const pen_spheres *spheres, pen_coverage_report *out);

/* What the fit achieved, measured with hard sphere tests on its own voxel grid and samples (the
 * coverage report on samples of its own). */
typedef struct pen_fit_metrics {
    double sov_fraction;     /* voxels inside some sphere and outside the mesh / voxels inside */
    double surface_coverage; /* surface samples inside some sphere / surface samples */
    double volume_coverage;  /* inside voxels inside some sphere / inside voxels */
    double mean_overlap;     /* spheres containing an inside voxel, averaged over covered ones */
    int iterations;          /* Adam iterations run */
    double seconds;          /* wall time of the whole fit (voxelization included) */
    double energy;           /* final E (eq. 5) */
    int grid[3];             /* voxel grid size */
    long inside_voxels;
    int surface_samples;
    int from_cache; /* pen_spheres_fit_cached: 1 if read from the cache file */
    pen_coverage_report coverage; /* what the returned spheres leave uncovered
                                      (pen_spheres_coverage of the returned set) */
} pen_fit_metrics;

/* The defaults (measured on the bundled meshes; docs/fit-spheres.md). */
PEN_API void pen_fit_settings_default(pen_fit_settings *settings);

/* Fits `count` spheres (1 .. PEN_FIT_MAX_SPHERES) to a closed mesh. settings may be NULL
 * (defaults); metrics may be NULL. Uses the context's thread count. On success *out owns a new
 * array of `count` spheres (free with pen_spheres_free); on failure *out is zeroed. Errors: a
 * mesh with no triangles, out-of-range indices, NaN/Inf positions, a degenerate (flat) bounding
 * box, a bounding box whose longest side is outside [1e-9, 1e9] (rescale the mesh), no voxel
 * inside the mesh (not closed, or thinner than the grid everywhere). Parts thinner than a voxel
 * get spheres too (they start from the surface, docs/fit-spheres.md); metrics->coverage says
 * what the spheres leave uncovered. */
PEN_API pen_status pen_spheres_fit(pen_context *ctx, const pen_mesh *mesh, int count,
                                   const pen_fit_settings *settings, pen_spheres *out,
                                   pen_fit_metrics *metrics);

/* Like pen_spheres_fit, but first looks for a cached fit in the user's cache folder,
 * $XDG_CACHE_HOME/penumbra (else ~/.cache/penumbra):
 *     <mesh file name>-<hash of the absolute mesh path>-<count>-<key>.json
 * where key is a 64-bit hash (16 hex digits) of the mesh's positions and indices, `count`, every
 * setting and the fitter's version. A cache hit returns the stored spheres and metrics (with
 * from_cache = 1) without fitting. After a fit the result is written there (atomically, the
 * folder created); failing to write the cache (read-only folder, no HOME) is not an error.
 * Nothing is written beside the mesh. mesh_path may be NULL: no cache. With the cache off
 * (pen_context_set_fit_cache, PENUMBRA_NO_CACHE=1) this is pen_spheres_fit. Errors are those of
 * pen_spheres_fit behind "<mesh_path>: ". */
PEN_API pen_status pen_spheres_fit_cached(pen_context *ctx, const pen_mesh *mesh,
                                          const char *mesh_path, int count,
                                          const pen_fit_settings *settings, pen_spheres *out,
                                          pen_fit_metrics *metrics);

/* The cache file pen_spheres_fit_cached uses for these arguments (malloc'd into *path; the
 * caller frees it), e.g. to remove a cached fit. */
PEN_API pen_status pen_spheres_fit_cache_path(pen_context *ctx, const pen_mesh *mesh,
                                              const char *mesh_path, int count,
                                              const pen_fit_settings *settings, char **path);

/* A picture of a sphere set over its mesh: three square orthographic panels of size x size
 * pixels side by side (the mesh, the spheres, the spheres blended over the mesh), seen from
 * azimuth_deg about +Y (0 looks from +Z towards -Z) and elevation_deg above the horizon.
 * Flat shading with one fixed light; linear RGB in [0, 1], white background. On success *out owns
 * a new (3 size) x size RGB image (free with pen_image_free). */
PEN_API pen_status pen_spheres_preview(pen_context *ctx, const pen_mesh *mesh,
                                       const pen_spheres *spheres, float azimuth_deg,
                                       float elevation_deg, int size, pen_image *out);

/* Gets a loaded scene (pen_scene_load) ready to render as `penumbra render` renders it: the one
 * call the CLI, the optimizer and the Python binding's load_scene make. With shadows != 0, every
 * object that asks for fitted spheres ("spheres": {"fit": N}: fit_spheres > 0, none yet) gets
 * them from pen_spheres_fit_cached with the default settings (cached in the user's cache folder);
 * then every sphere set gets its overlap weights
 * (pen_spheres_ensure_weights), computed once here. The lights of the environment map
 * ("lights": {"max": K}, the default) were found by pen_scene_load. metrics: NULL, or
 * object_count entries, each set to that object's fit (zero for an object not fitted by this
 * call), its coverage included; pen_scene_check (after this call) turns a large uncovered share
 * into a warning. Errors name the scene file and the object: "scene.json: objects[1].spheres:
 * ...". */
PEN_API pen_status pen_scene_prepare(pen_context *ctx, pen_scene *scene, int shadows,
                                     pen_fit_metrics *metrics);

/* ---- What to tell a user about a scene and a mesh (src/geometry/scene_check.c) -------------- */

/* Likely mistakes in a scene that loads and renders; none stops a render. */
typedef enum pen_scene_warning_kind {
    PEN_SCENE_WARNING_CAMERA_INSIDE = 1,  /* the camera's eye inside an object's posed bounds, or
                                             inside one of its spheres */
    PEN_SCENE_WARNING_OBJECT_TINY = 2,    /* an object's largest side under 1 % of the ground
                                             square's side */
    PEN_SCENE_WARNING_OBJECT_HUGE = 3,    /* ... over the ground square's side */
    PEN_SCENE_WARNING_MTLLIB_MISSING = 4, /* an OBJ's material library not found: its materials
                                             are lost (the mesh loader passes over it) */
    PEN_SCENE_WARNING_TEXTURE_MISSING = 5, /* a material's map_Kd not found (a used one fails the
                                              load unless the object's own albedo overrides it) */
    PEN_SCENE_WARNING_SPHERES_UNCOVERED = 6 /* an object's fitted spheres ("fit": N) leave
                                               more than PEN_SPHERES_COVERAGE_WARN of its surface
                                               uncovered (pen_spheres_coverage): its shadow lacks
                                               a part (a set given in a file is not judged) */
} pen_scene_warning_kind;

#define PEN_SCENE_WARNING_CHARS 1024
typedef struct pen_scene_warning {
    pen_scene_warning_kind kind;
    int object;                            /* the object concerned (objects[object]), or -1 */
    char message[PEN_SCENE_WARNING_CHARS]; /* one line without a newline: what is wrong and
                                              what to do, e.g. "objects[0] (chair.obj) is 90 x
                                              84 x 60 but the ground square is 8 x 8: ..." */
} pen_scene_warning;

/* A disk light in the words a person uses. */
typedef struct pen_light_summary {
    float elevation_deg; /* above the horizon: asin of the direction's y */
    float azimuth_deg;   /* about +Y, from +Z towards +X (as the camera frame's azimuth_deg) */
    float share;         /* its part of all the light reaching the scene, in [0, 1]: the
                            luminance (0.2126 R + 0.7152 G + 0.0722 B) integrated over the sky of
                            the disk, 2 E / (1 + cos b), over that of the lights and the SH
                            lighting (sqrt(4 pi) times its first coefficient). For lights found in
                            a map, their share of the map's light */
} pen_light_summary;

typedef struct pen_scene_report {
    int object_count;
    float *bounds;   /* 6 floats per object: the posed vertices' lowest x, y, z, then highest
                        x, y, z (world coordinates) */
    int light_count; /* the scene's lighting.light_count */
    pen_light_summary lights[PEN_SCENE_MAX_LIGHTS];
    int warning_count;
    pen_scene_warning *warnings;
} pen_scene_report;

/* Measures a loaded scene and lists its likely mistakes (pen_scene_warning_kind), without
 * printing anything: `penumbra render` and `optimize` print the warnings on stderr, `penumbra
 * info` prints everything. Reads each OBJ's material libraries again (pen_mesh_files_load) to
 * find missing files. Measures what each object's spheres leave of its surface uncovered
 * (pen_spheres_coverage; a few milliseconds an object): call it after pen_scene_prepare, so that
 * the fitted sets ("spheres": {"fit": N}) are measured too; an object still waiting for its fit
 * is passed over. On success *out owns its arrays (pen_scene_report_free); on failure it is
 * zeroed. */
PEN_API pen_status pen_scene_check(pen_context *ctx, const pen_scene *scene, pen_scene_report *out);
/* Frees the report's arrays and zeroes it; NULL is a no-op. */
PEN_API void pen_scene_report_free(pen_scene_report *report);

/* How closed a mesh is, as the fit's inside test needs it: positions welded (equal coordinates
 * are one vertex), each edge counted over the triangles that use it. Closed (watertight): no
 * open and no non-manifold edge. */
typedef struct pen_mesh_edges {
    long edges;                /* distinct edges */
    long open_edges;           /* in one triangle only: the border of a hole */
    long nonmanifold_edges;    /* in three or more triangles */
    long degenerate_triangles; /* with two corners at one position (left out of the count) */
} pen_mesh_edges;
PEN_API pen_status pen_mesh_edges_count(pen_context *ctx, const pen_mesh *mesh,
                                        pen_mesh_edges *out);

/* Fits every object of a loaded scene that asks for it ("spheres": {"fit": N}, so fit_spheres > 0
 * and no spheres yet) with pen_spheres_fit_cached and the default settings (cached in the user's
 * cache folder). Objects that have spheres are left alone. pen_scene_prepare does this and the
 * overlap weights. */
PEN_API pen_status pen_scene_fit_spheres(pen_context *ctx, pen_scene *scene);

/* Writes {"metrics": {...}, "fit_settings": {...}} (the settings member only when settings is
 * not NULL) into buf, NUL-terminated and cut at size; returns the length it needed, as snprintf
 * does. The text is what pen_spheres_save takes as extra_json. */
PEN_API int pen_fit_json(const pen_fit_settings *settings, const pen_fit_metrics *metrics,
                         char *buf, size_t size);

/* ---- Overlap weights (src/geometry/overlap.c) ------------------------------------------------ */

/* Overlap weights: kappa[i] >= 0 per sphere (count floats), chosen so that along a line through
 * the set the weights of the spheres it crosses add up to about PEN_SPHERES_OVERLAP_TARGET (a
 * non-negative least-squares fit over random lines, docs/fit-spheres.md). The renderer multiplies
 * sphere i's log-visibility by kappa[i], so that a shadow ray through an object has about the same
 * depth however many of its overlapping proxy spheres it crosses. Deterministic (fixed seed,
 * independent of the thread count); a single sphere gets exactly the target, disjoint spheres
 * about the target, k coincident copies about target / k each. Invariant under a pose (computed
 * in object space). Fails on a radius <= 0 or a non-finite value, and on a set of more than
 * PEN_SPHERES_OVERLAP_MAX spheres (the time grows about linearly with the count, from a fraction
 * of a second for 32 spheres to about 10 s for a fitted set of 4096 on two cores, and faster than
 * linearly beyond:
 * give such a set weights in its file, or render it with "overlap": "none"). */
#define PEN_SPHERES_OVERLAP_MAX 4096
PEN_API pen_status pen_spheres_overlap_weights(pen_context *ctx, const pen_spheres *spheres,
                                               float *kappa);
/* Computes spheres->weight when it is NULL (allocating it); leaves existing weights alone. */
PEN_API pen_status pen_spheres_ensure_weights(pen_context *ctx, pen_spheres *spheres);
#ifdef __cplusplus
}
#endif
#endif
