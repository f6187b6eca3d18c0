/* metraw.codec._simd, the AVX2 path: the kernels of _simd_vec.h compiled for AVX2 with FMA and BMI2 (x86-64 CPUs
 * since Haswell and Zen), the functions metraw_<name>_avx2. Floating-point results stay IEEE operation by operation:
 * the extension is built with -ffp-contract=off, so no multiply-add is fused. */
#include "_simd.h"
#if METRAW_X86
#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2,fma,bmi,bmi2"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2,fma,bmi,bmi2")
#endif
#pragma GCC diagnostic ignored "-Wpsabi"
#define VEC_PATH avx2
#define VEC_AVX2 1
#include "_simd_vec.h"
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif
#endif
