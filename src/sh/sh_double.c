/* The SH engine in double: tables, the reference path and gradient checks. See sh_ops.inc. */
#include "core/internal.h"
#include "sh/sh_internal.h"

#include <tgmath.h>

#define REAL double
#define SUF(name) name##_d
#define PEN_SH_REAL_IS_FLOAT 0
#include "sh/sh_ops.inc"
