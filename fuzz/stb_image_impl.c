/* stb_image compiled from Debian's header into the fuzz harnesses (PEN_FUZZ builds only), so
 * that the PNG and HDR decoders carry libFuzzer's coverage hooks and the sanitizers' checks:
 * the library links Debian's compiled libstb.so, which the fuzzer could not see into. The
 * definitions here take precedence over the shared library's; it is the same code (the header
 * of the installed libstb-dev). */
#define STB_IMAGE_IMPLEMENTATION
#include <stb_image.h>
