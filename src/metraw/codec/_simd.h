/* metraw.codec._simd: what its C files share (the C types, the x86-64 switch, the AVX-512 target attribute, the
 * decoder's model, the kernels' signatures and the drivers that run them).
 * _simd_driver.c: the scalar parts (the decoder's general path and row-group schedule, the rANS pass's scalar part,
 *   the alphabet counts), the paths this CPU can run, the interface version;
 * _simd.c, _simd_prepare.c: the AVX-512 kernels (the coder's loops; the dither and transforms);
 * _simd_vec.h: the same kernels once more in GCC / Clang vector extensions (vectors of a register's width: 4 or 2
 *   lanes of 64 bits), instantiated for AVX2 by _simd_avx2.c and for any CPU by _simd_portable.c.
 * Every path exports the same functions, metraw_<name>_<path> (path avx512, avx2, portable); metraw.codec.native binds
 * those of the path it runs. */
#ifndef METRAW_SIMD_H
#define METRAW_SIMD_H
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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

#define PROB_BITS 12          /* metraw.codec.decoder.PROB_BITS */
#define RANS_L (1 << 16)      /* metraw.codec.decoder.RANS_L */

/* the paths (bits of metraw_simd_paths()) */
#define PATH_PORTABLE 1
#define PATH_AVX2 2
#define PATH_AVX512 4

INLINE i64 iabs64(i64 a) { return a < 0 ? -a : a; }

typedef struct {
    const i64 *thr;     /* 7 activity thresholds (padded with INT64_MAX) */
    const i64 *coef;    /* 8 contexts x 13: 11 coefficients, their sum, the bias (unused contexts zero) */
    i64 tab0, pshift, alpha, amax;
    const void *lut; int lut16;   /* symbol by slot: uint8 (lut16 0) or int16 (1), tables x 2^PROB_BITS */
    const uint32_t *fcum;         /* freq << 16 | cumulative frequency, tables x alpha */
    const uint16_t *words;
    const int32_t *esc;
} model_t;

/* The decoder's steady part of a group of 8 (steady8) or 16 (steady16) rows: column steps s = xs0 .. x_last, lane j
 * at x = s - 3 j of row y0 + j; every lane in its row and the pixels before it decoded. Returns 0 when a lane ran past
 * its words or escapes. */
typedef int (*steady_fn)(i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
                         const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last);
/* The rANS pass's symbols k = lo - 1 .. 0 of 8 (rans8) or 16 (rans16) lanes side by side (see _simd_driver.c).
 * Symbol i's table entry is tab[i] alpha + idx[i]; ent holds them all where the path asks the driver for that array
 * (rans_encode_with's with_ent), else NULL */
typedef void (*rans_fn)(const int32_t *idx, const int32_t *tab, i64 alpha, const int32_t *ent, const u64 *fc,
                        const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs, i64 *nws, i64 *ci, i64 *ce,
                        i64 *cq, const i64 *o);

/* A plane's dither made and its DN put out a row group at a time by the decoder (decode_plane_dn): the path's
 * dither_fixed and inverse_dn kernels, two buffers of a group's rows (w each: the dither, the symbols), the plane's
 * dither keys and pixel indices (start + i row_step + j col_step), the transform (prepare.inverse_args) and the DN out
 * (a CFA plane of the frame, strides in elements) */
typedef struct {
    void (*dither)(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step, int32_t *out);
    void (*inverse)(const int32_t *sym, i64 rows, i64 cols, u64 k1, u64 k2, i64 start, i64 row_step, i64 col_step,
                    double half_step, double k, double offset, uint16_t *out, i64 out_row_stride, i64 out_col_stride);
    int32_t *u, *sym;
    u64 k1, k2;
    i64 start, row_step, col_step;
    double half_step, k, offset;
    uint16_t *out;
    i64 out_row_stride, out_col_stride;
} dn_t;

/* A path's metraw_decode_plane_dn_<path>: decode_plane with the plane's dither made and its DN put out a row group at a
 * time (dn_t; u and sym: a group's rows), by the path's steady8 / steady16 and its dither and inverse kernels */
#define DECODE_PLANE_DN(name, dither_fn, inverse_fn) \
    int name(i64 *p, i64 h, i64 w, int32_t *u, int32_t *sym, const i64 *thr7, const i64 *coef8x13, i64 tab0, \
             i64 pshift, const void *lut, int lut16, const uint32_t *fcum, i64 alpha, i64 amax, \
             const uint16_t *words, u64 *xs, i64 *pos, const i64 *pmin, const int32_t *esc, i64 *epos, \
             const i64 *eend, i64 nl, int two_vectors, u64 k1, u64 k2, i64 start, i64 row_step, i64 col_step, \
             double half_step, double k, double offset, uint16_t *out, i64 out_row_stride, i64 out_col_stride) \
    { \
        const dn_t dn = {dither_fn, inverse_fn, u, sym, k1, k2, start, row_step, col_step, half_step, k, offset, out, \
                         out_row_stride, out_col_stride}; \
        return decode_plane_with(steady8, steady16, p, h, w, NULL, NULL, thr7, coef8x13, tab0, pshift, lut, lut16, \
                                 fcum, alpha, amax, words, xs, pos, pmin, esc, epos, eend, nl, two_vectors, &dn); \
    }

/* _simd_driver.c: the decoder's plane and the encoder's rANS pass with a path's kernels; the per-table counts */
int decode_plane_with(steady_fn steady8, steady_fn steady16, i64 *p, i64 h, i64 w, const int32_t *u, int32_t *sym,
                      const i64 *thr7, const i64 *coef8x13, i64 tab0, i64 pshift, const void *lut, int lut16,
                      const uint32_t *fcum, i64 alpha, i64 amax, const uint16_t *words, u64 *xs, i64 *pos,
                      const i64 *pmin, const int32_t *esc, i64 *epos, const i64 *eend, i64 nl, int two_vectors,
                      const dn_t *dn);
void rans_encode_with(rans_fn rans8, rans_fn rans16, int with_ent, const int32_t *idx, const int32_t *tab, i64 n,
                      i64 ntab, i64 alpha, const i64 *freq, const i64 *cum, const double *rcp, const i64 *rs,
                      const i64 *rl, const i64 *lr, const i64 *ls, i64 nl, uint16_t *out, u64 *xs, i64 *nws);
void index_counts(const int32_t *t, const int32_t *idx, i64 n, i64 alpha, i64 nt, i64 *counts);

#endif
