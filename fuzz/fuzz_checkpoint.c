/* Fuzz harness: `penumbra optimize` checkpoints through pen__optim_checkpoint_load (written to a
 * scratch file first: the loader reads files), against one fixed task identity (FUZZ_IDENTITY
 * below; fuzz/corpus/checkpoint holds checkpoints of it written by
 * pen__optim_checkpoint_save). A checksum closes every checkpoint, which random mutations
 * would almost never satisfy, so the harness rewrites the input's last 8 bytes to the checksum
 * of the bytes before them and the fuzzer reaches the fields behind it (the checksum test itself
 * is a plain comparison). An accepted state must be consistent and finite. */
#include "fuzz.h"
#include "optim/optim_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { N = 6, MAX_LOSSES = 32 };

static const pen__optim_segment segments[] = {{0, 3, 1.0f, PEN__BOUND_UNIT},
                                              {3, 3, 1.0f, PEN__BOUND_NONE}};
/* (Adam with ridge 0: also what the corpus's version-3 seeds, ridge 1e-2, read as) */
static const pen__optim_identity FUZZ_IDENTITY = {
    .n = N, .segments = segments, .segment_count = 2, .groups = PEN_OPTIM_LIGHTING,
    .loss = PEN_OPTIM_LOSS_L2, .shadows = 1, .width = 8, .height = 8, .shadow_weight = 0.0,
    .lighting_solver = PEN_OPTIM_LIGHTING_ADAM, .lighting_ridge = 0.0, .graph_k = 0,
    .weights = {0.0, 0.0, 0.0}, .target_hash = 0x1234u, .init_hash = 0x5678u,
    .ridge_views = 2, /* (a multi-view task: the older versions' refusals are reachable) */
    .scene_hash = 0x9abcu};

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    uint8_t *bytes = malloc(size ? size : 1);
    if (!bytes) fuzz_fail("out of memory");
    memcpy(bytes, data, size);
    if (size >= 16) {
        uint64_t sum = pen__fnv1a(PEN__FNV1A_SEED, bytes, size - 8);
        memcpy(bytes + size - 8, &sum, 8);
    }
    const char *path = fuzz_write(bytes, size, "bin");
    free(bytes);

    float x[N], best[N], m[N], v[N];
    double losses[MAX_LOSSES];
    pen__adam adam = {.n = N, .m = m, .v = v};
    pen__optim_state st = {.x = x, .best = best, .adam = &adam, .losses = losses};
    pen_context *ctx = fuzz_context();
    if (pen__optim_checkpoint_load(ctx, path, &FUZZ_IDENTITY, MAX_LOSSES, &st) == PEN_OK) {
        if (st.iteration < 0 || st.recorded < 0 || st.recorded > MAX_LOSSES ||
            st.best_iteration < -1 || st.best_iteration >= st.recorded || adam.t != st.iteration)
            fuzz_fail("checkpoint: inconsistent state");
        fuzz_check_floats(x, N, "checkpoint: x");
        fuzz_check_floats(best, N, "checkpoint: best");
        fuzz_check_floats(m, N, "checkpoint: m");
        fuzz_check_floats(v, N, "checkpoint: v");
        for (int i = 0; i < st.recorded; ++i)
            if (!isfinite(losses[i])) fuzz_fail("checkpoint: loss");
        if (!isfinite(st.seconds) || !(st.seconds >= 0.0)) fuzz_fail("checkpoint: seconds");
    }
    return 0;
}
