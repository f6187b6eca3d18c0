/* metraw.codec._simd: what its two C files share (the C types, the x86-64 switch, the AVX-512 target attribute).
 * _simd.c: the predictive coder's loops (decoder, residual pass, rANS, causal buffer, alphabet indices);
 * _simd_prepare.c: the per-pixel dither and transforms (metraw.codec.prepare) and the encoder's plane buffer. */
#ifndef METRAW_SIMD_H
#define METRAW_SIMD_H
#include <stdint.h>
#include <stdlib.h>

typedef int64_t i64;
typedef uint64_t u64;

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define METRAW_X86 1
#include <immintrin.h>
#define SIMD_FN __attribute__((target("avx512f,avx512dq")))
#else
#define METRAW_X86 0
#endif

#define INLINE __attribute__((always_inline)) static inline

INLINE i64 iabs64(i64 a) { return a < 0 ? -a : a; }

#endif
