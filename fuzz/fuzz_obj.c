/* Fuzz harness: OBJ meshes through pen_mesh_load_obj (written to a scratch file first: the mesh
 * loaders read files). An accepted mesh must have finite values and indices in range. */
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    return fuzz_mesh(data, size, "obj", pen_mesh_load_obj);
}
