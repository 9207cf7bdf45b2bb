/* penumbra/api.h -- which functions libpenumbra.so exports.
 *
 * The library is compiled with -fvisibility=hidden, so a function is visible to programs that
 * link the shared library only when its declaration carries PEN_API. Every function of the public
 * headers does (the rule: each function declaration in a public header whose return type starts
 * at column 0; scripts/pen_api.sh applies and checks it); the internal `pen__` functions shared
 * between the library's files do not, so they stay out of the dynamic symbol table and can change
 * without breaking anyone. For a program using the library PEN_API expands to nothing.
 */
#ifndef PENUMBRA_API_H
#define PENUMBRA_API_H

#if defined(PEN_BUILDING_LIBRARY) && (defined(__GNUC__) || defined(__clang__))
#define PEN_API __attribute__((visibility("default")))
#else
#define PEN_API
#endif

#endif
