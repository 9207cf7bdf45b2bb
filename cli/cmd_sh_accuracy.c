/* penumbra sh-accuracy: placeholder until the SH engine lands (same session). */
#include "commands.h"

int pen_cmd_sh_accuracy(int argc, char **argv) {
    return pen_cli_fail("sh-accuracy", "not built yet");
}
