/* Fuzz harness: sphere-set JSON through pen_spheres_load (written to a scratch file first: the
 * sphere loader reads files). An accepted set must have finite centres, positive finite radii
 * and finite non-negative weights. */
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    const char *path = fuzz_write(data, size, "json");
    pen_spheres spheres;
    if (pen_spheres_load(fuzz_context(), path, &spheres) == PEN_OK) {
        fuzz_check_spheres(&spheres);
        pen_spheres_free(&spheres);
    } else if (spheres.data || spheres.weight) {
        fuzz_fail("spheres: refused but not zeroed");
    }
    return 0;
}
