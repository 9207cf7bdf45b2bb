/* Immutable traced arrays shared by reference (transfer_pool.c): a blob holds one trace (the
 * blocked part B, the light fractions, and for a self transfer the node lattice it was traced
 * on), and every holder (a pool entry, a render state) keeps a counted reference, so that the
 * states of a multi-view task read one copy and an evicted pool entry never frees arrays that a
 * state still reads. Internal. */
#ifndef PEN_RENDER_TRANSFER_POOL_H
#define PEN_RENDER_TRANSFER_POOL_H

#include "geometry/lattice.h"
#include "render/render_internal.h"

typedef struct pen__transfer_blob {
    int refs;              /* atomic */
    size_t nB, nfrac;      /* floats in B and frac */
    float *B, *frac;       /* one allocation: nB then nfrac floats */
    pen__lattice lat;      /* the nodes of a self transfer (level 0: none, the ground's grid) */
    struct pen__transfer_bvh *bvh; /* the grid's occluders, traced again per camera; or NULL */
} pen__transfer_blob;

/* A blob of nB + nfrac uninitialised floats and an empty lattice, with one reference (the
 * caller's); the caller fills it before anyone else sees it. NULL without memory. */
pen__transfer_blob *pen__blob_create(pen_context *ctx, size_t nB, size_t nfrac);
void pen__blob_retain(pen__transfer_blob *b);
/* Drops a reference; frees the arrays, the lattice and the occluders with the last one. NULL:
 * no-op. */
void pen__blob_release(pen__transfer_blob *b);

/* The entry of (kind, key), with a new reference for the caller (who releases it), or NULL.
 * The caller checks the blob's shape (a self transfer's sizes follow from its lattice). Call
 * between pen__pool_lock and pen__pool_unlock. */
pen__transfer_blob *pen__pool_find(const pen__transfer_pool *p, int kind, uint64_t key);
/* Makes blob the entry of (kind, key), the pool taking its own reference (the oldest entry
 * makes room, dropping the pool's reference only). NULL pool: no-op. */
void pen__pool_insert(pen__transfer_pool *p, int kind, uint64_t key, pen__transfer_blob *blob);

#endif
