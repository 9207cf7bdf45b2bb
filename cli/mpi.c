/* `penumbra optimize` under mpirun: the ranks of MPI_COMM_WORLD share one multi-view task
 * (pen_optim_ranks in penumbra/optim.h; README, "Running on a cluster").
 *
 * MPI is optional at build time (CMake PENUMBRA_MPI): without it, or when the process was not
 * started by an MPI launcher, every function here reports one process and the tool behaves as it
 * always did. MPI is started only for `optimize` and only under a launcher (its environment
 * names a rank), so that the other commands, and `optimize` run by hand, pay nothing for it and
 * never depend on a working MPI installation.
 *
 * The library gathers each pass's per-view results with one MPI_Allgatherv in place; an item
 * (one view's loss, or its gradient vector) travels as a contiguous type of item_bytes bytes, so
 * the counts stay view counts and cannot overflow an int. */
#include "commands.h"

#include <stdlib.h>

#ifdef PEN_HAVE_MPI
#include <limits.h>
#include <mpi.h>

static pen_optim_ranks ranks;
static int started = 0;

/* Whether an MPI launcher started this process: Open MPI, PMIx, and Hydra (MPICH) set these. */
static int launched(void) {
    return getenv("OMPI_COMM_WORLD_SIZE") || getenv("PMIX_RANK") || getenv("PMI_RANK");
}

static int allgather(void *user, void *all, const int *counts, size_t item_bytes) {
    (void)user;
    if (item_bytes > INT_MAX) return 1;
    int *displs = malloc(sizeof(int) * (size_t)ranks.size);
    if (!displs) return 1;
    for (int r = 0, at = 0; r < ranks.size; ++r) {
        displs[r] = at;
        at += counts[r];
    }
    MPI_Datatype item;
    int rc = MPI_Type_contiguous((int)item_bytes, MPI_BYTE, &item);
    if (rc == MPI_SUCCESS) rc = MPI_Type_commit(&item);
    if (rc == MPI_SUCCESS) {
        rc = MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, all, counts, displs, item,
                            MPI_COMM_WORLD);
        MPI_Type_free(&item);
    }
    free(displs);
    return rc != MPI_SUCCESS;
}

void pen_cli_mpi_start(int *argc, char ***argv) {
    if (!launched()) return;
    MPI_Init(argc, argv);
    started = 1;
    MPI_Comm_rank(MPI_COMM_WORLD, &ranks.rank);
    MPI_Comm_size(MPI_COMM_WORLD, &ranks.size);
    ranks.allgather = allgather;
}

const pen_optim_ranks *pen_cli_mpi_ranks(void) {
    return started && ranks.size > 1 ? &ranks : NULL;
}

void pen_cli_mpi_abort(int status) {
    if (started && ranks.size > 1) MPI_Abort(MPI_COMM_WORLD, status);
}

void pen_cli_mpi_stop(void) {
    if (started) MPI_Finalize();
    started = 0;
}

#else /* built without MPI: always one process */

void pen_cli_mpi_start(int *argc, char ***argv) {
    (void)argc;
    (void)argv;
}
const pen_optim_ranks *pen_cli_mpi_ranks(void) {
    return NULL;
}
void pen_cli_mpi_abort(int status) {
    (void)status;
}
void pen_cli_mpi_stop(void) {}

#endif
