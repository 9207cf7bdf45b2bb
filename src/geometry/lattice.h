/* Refined receiver nodes on a triangle mesh (lattice.c): each triangle split into L x L
 * sub-triangles by the barycentric lattice u = a / L, v = b / L, its nodes shared along edges and
 * at vertices, so that a quantity sampled at the nodes and interpolated linearly on the
 * sub-triangles is continuous over the mesh. The self transfer (src/render/self.c) samples the
 * blocked light there: a coarse mesh's vertices are too far apart for the occlusion inside a crease
 * (docs/design.md sec. 1.15). Internal. */
#ifndef PEN_GEOMETRY_LATTICE_H
#define PEN_GEOMETRY_LATTICE_H

#include "penumbra/core.h"

#include <stdint.h>

/* The most sub-triangles per edge: L = 8 makes 64 per triangle. */
#define PEN_LATTICE_MAX_LEVEL 8

typedef struct pen__lattice {
    int level;            /* L >= 1; 1: the nodes are the vertices */
    int vertex_count, triangle_count, edge_count;
    int node_count;       /* V + E (L - 1) + T (L - 1)(L - 2) / 2 */
    int32_t *tri_edges;   /* 3 per triangle: edge id of corner c -> c + 1, as 2 id + (1 when the
                             edge's stored direction, from its smaller vertex, is the other way) */
} pen__lattice;

/* Builds the node numbering of a mesh at level L (clamped to 1 .. PEN_LATTICE_MAX_LEVEL): the
 * unique edges, found by sorting. Frees and replaces what lat held. */
pen_status pen__lattice_build(pen_context *ctx, pen__lattice *lat, int level, int vertex_count,
                              int triangle_count, const uint32_t *indices);
void pen__lattice_free(pen__lattice *lat);

/* The level that brings the mean edge of the mesh (3 floats per vertex) to at most `spacing`
 * times its bounding diagonal, in 1 .. PEN_LATTICE_MAX_LEVEL, lowered while the lattice would hold
 * more than max_nodes nodes (a mesh of long thin triangles would otherwise ask for millions). */
int pen__lattice_level(int vertex_count, const float *positions, int triangle_count,
                       const uint32_t *indices, double spacing, double max_nodes);

/* Whether the mesh (3 floats per vertex) is convex: every vertex lies on or behind the plane of
 * every non-degenerate triangle (its outward side by the counter-clockwise winding), within
 * 1e-5 of the bounding diagonal (float positions read from text). Such a mesh blocks nothing of
 * a vertex's clamped cosine: with the vertex normal a positive sum of its triangles' normals, the
 * whole mesh lies behind the vertex's tangent plane (docs/design.md sec. 1.15). 0 for an empty
 * mesh, and 0 without testing when V x T exceeds max_pairs (the test is O(V T)). */
int pen__lattice_convex(int vertex_count, const float *positions, int triangle_count,
                        const uint32_t *indices, double max_pairs);

/* Node positions and normals (3 floats each per node): the vertices' own, then the linear
 * interpolation of the triangle's corners at the node's barycentrics (normals not renormalised:
 * their length does not matter to the transfer). */
void pen__lattice_nodes(const pen__lattice *lat, const uint32_t *indices, const float *positions,
                        const float *normals, float *node_pos, float *node_nrm);

/* The sub-triangle of triangle t holding barycentrics (u, v) (the weight of corner 1 and 2):
 * its three node ids and their linear weights, summing to 1. At level 1 these are the corners
 * and (1 - u - v, u, v). */
void pen__lattice_locate(const pen__lattice *lat, const uint32_t *indices, int t, double u,
                         double v, int node[3], double w[3]);

#endif
