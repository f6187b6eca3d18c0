/* metraw.codec._simd, the portable path: the kernels of _simd_vec.h compiled for the build's default target (any
 * CPU: SSE2 on x86-64, NEON on 64-bit ARM, scalar code elsewhere), the functions metraw_<name>_portable. */
#pragma GCC diagnostic ignored "-Wpsabi"
#define VEC_PATH portable
#include "_simd_vec.h"
