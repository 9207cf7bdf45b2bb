/* Fuzz harness: JPEG images (libjpeg-turbo) through pen_image_load_ex (written to a scratch
 * file first: the image loaders read files). */
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    return fuzz_image(data, size, "jpg");
}
