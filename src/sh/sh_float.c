/* The SH engine in float: the hot-path flavour. See sh_ops.inc. */
#include "core/internal.h"
#include "sh/sh_internal.h"

#include <tgmath.h>

#define REAL float
#define SUF(name) name
#define PEN_SH_REAL_IS_FLOAT 1
#include "sh/sh_ops.inc"
