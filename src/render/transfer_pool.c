/* Ray-traced transfers shared between render states (pen_render_state_share, render.h).
 *
 * Design
 * - What is shared. An object's self transfer (self.c) and the ground's grid (ground_shadow.c)
 *   are in world space: they depend on the posed meshes, the band count, the lights and the
 *   ground, never on the camera. States that render the same objects from several cameras (the
 *   views of a task, a batch of cameras) would each trace them once per pose; through a pool the
 *   first state to need a trace makes it and the others use it.
 * - By reference. A trace is an immutable blob (transfer_pool.h) with a counted reference per
 *   holder: the pool's entry and every state that renders with it. A state reads the blob's
 *   arrays and, for a self transfer, its node lattice through its reference, so a task of a
 *   thousand views holds one copy of each trace, not one per view (a copy per state cost the
 *   1000-view lighting task some 2.3 GB and a memcpy per view per pose), and the lattice is
 *   built once per trace instead of once per state. A state drops its reference when its key
 *   changes or it is freed; the blob goes with its last holder, so evicting an entry never frees
 *   arrays a state still reads. The ground's grid is held the same way.
 * - Keys. An entry is found by the key the state's own cache uses (which hashes everything the
 *   trace depends on) together with its kind and the arrays' sizes, so a pool never hands a state
 *   arrays of another shape. The shared blob is bitwise the trace the state would have made:
 *   renders do not depend on which state traced.
 * - Threads. States of one pool may render at once on different threads: the whole miss path
 *   (look up, trace, insert) runs under the pool's lock, so a trace is made once and the others
 *   wait for it instead of tracing it again; the trace inside runs its own threads as always.
 *   Blobs are never written once inserted, so readers need no lock; the counts are atomic.
 * - Bounds. The pool keeps the PEN_POOL_ENTRIES most recent traces (a pose task moves on and never
 *   asks for an old pose again); states add at most their own current trace each.
 * - Lifetime. Counted references: the pool goes with the last state that holds it.
 */
#include "core/internal.h"
#include "geometry/transfer.h"
#include "render/transfer_pool.h"

#include <omp.h>
#include <stdlib.h>

#define PEN_POOL_ENTRIES 16

typedef struct pool_entry {
    int kind; /* PEN__POOL_SELF or PEN__POOL_GRID; 0: empty */
    uint64_t key;
    pen__transfer_blob *blob; /* the pool's reference */
} pool_entry;

struct pen__transfer_pool {
    omp_lock_t lock;
    int refs;
    int next; /* the entry a new trace replaces (oldest first) */
    long traces; /* traces inserted over the pool's life (tests read it) */
    pool_entry entries[PEN_POOL_ENTRIES];
};

pen_status pen__pool_create(pen_context *ctx, pen__transfer_pool **out) {
    pen__transfer_pool *p = pen__calloc(ctx, 1, sizeof *p, "transfer pool");
    if (!p) return PEN_ERROR_MEMORY;
    omp_init_lock(&p->lock);
    p->refs = 1;
    *out = p;
    return PEN_OK;
}

void pen__pool_retain(pen__transfer_pool *p) {
    if (p) __atomic_add_fetch(&p->refs, 1, __ATOMIC_ACQ_REL);
}

void pen__pool_release(pen__transfer_pool *p) {
    if (!p || __atomic_sub_fetch(&p->refs, 1, __ATOMIC_ACQ_REL) > 0) return;
    for (int i = 0; i < PEN_POOL_ENTRIES; ++i)
        pen__blob_release(p->entries[i].blob);
    omp_destroy_lock(&p->lock);
    free(p);
}

void pen__pool_lock(pen__transfer_pool *p) {
    if (p) omp_set_lock(&p->lock);
}

void pen__pool_unlock(pen__transfer_pool *p) {
    if (p) omp_unset_lock(&p->lock);
}

/* ---- Blobs ----------------------------------------------------------------------------------- */

pen__transfer_blob *pen__blob_create(pen_context *ctx, size_t nB, size_t nfrac) {
    pen__transfer_blob *b = pen__calloc(ctx, 1, sizeof *b, "shared transfer");
    if (!b) return NULL;
    if (!(b->B = pen__malloc(ctx, nB + nfrac + 1, sizeof(float), "shared transfer"))) {
        free(b);
        return NULL;
    }
    b->frac = b->B + nB;
    b->nB = nB, b->nfrac = nfrac, b->refs = 1;
    return b;
}

void pen__blob_retain(pen__transfer_blob *b) {
    if (b) __atomic_add_fetch(&b->refs, 1, __ATOMIC_ACQ_REL);
}

void pen__blob_release(pen__transfer_blob *b) {
    if (!b || __atomic_sub_fetch(&b->refs, 1, __ATOMIC_ACQ_REL) > 0) return;
    pen__lattice_free(&b->lat);
    pen__transfer_bvh_free(b->bvh);
    free(b->B);
    free(b);
}

/* ---- Entries --------------------------------------------------------------------------------- */

pen__transfer_blob *pen__pool_find(const pen__transfer_pool *p, int kind, uint64_t key) {
    for (int i = 0; p && i < PEN_POOL_ENTRIES; ++i) {
        const pool_entry *e = &p->entries[i];
        if (e->kind != kind || e->key != key) continue;
        pen__blob_retain(e->blob);
        return e->blob;
    }
    return NULL;
}

void pen__pool_insert(pen__transfer_pool *p, int kind, uint64_t key, pen__transfer_blob *blob) {
    if (!p || !blob) return;
    pen__blob_retain(blob);
    pool_entry *e = &p->entries[p->next];
    pen__blob_release(e->blob); /* states that still read it keep it */
    *e = (pool_entry){kind, key, blob};
    p->next = (p->next + 1) % PEN_POOL_ENTRIES;
    ++p->traces;
}

long pen__pool_traces(const pen__transfer_pool *p) {
    return p ? p->traces : 0;
}

pen_status pen_render_state_share(pen_context *ctx, pen_render_state *st, pen_render_state *with) {
    if (!st || !with)
        return pen__error(ctx, PEN_ERROR_ARGUMENT, "render state share: NULL state");
    if (st == with || (st->pool && st->pool == with->pool)) return PEN_OK;
    if (!with->pool) {
        pen_status s = pen__pool_create(ctx, &with->pool);
        if (s) return s;
    }
    pen__pool_release(st->pool);
    pen__pool_retain(with->pool);
    st->pool = with->pool;
    return PEN_OK;
}
