/* metraw.codec._simd, the per-pixel preparation (metraw.codec.prepare) in AVX-512: the dither, the forward transform,
 * the encoder's plane buffer (dither, transform and causal buffer in one pass), and the decoder's fixed-point dither
 * and inverse transform. Same values as the numba kernels (tests/test_codec_native.py compares them). */
#include "_simd.h"

/* The dither and the forward transform (metraw.codec.prepare: _dither_grid_kernel, _forward_kernel), same values.
 * Dither of pixel index i: lowbias32 (mod 2^32, so 32-bit lanes give numba's uint64-masked values) keyed by k1, k2,
 * 24 bits -> [-1/2, 1/2). Forward: k = rint(2 sqrt(min(max((y - black) / K + c, 0), xmax)) / q + u), one IEEE
 * operation at a time as numba does (no fused multiply-add: -ffp-contract=off and separate intrinsics). */
#if METRAW_X86
/* the dither hash's keys and the index offsets of 16 pixels col_step apart */
typedef struct { __m512i K1, K2, lane; } dither_t;

SIMD_FN INLINE dither_t dither_consts(u64 k1, u64 k2, i64 col_step)
{
    dither_t d = {_mm512_set1_epi32((int)(uint32_t)k1), _mm512_set1_epi32((int)(uint32_t)k2),
                  _mm512_mullo_epi32(_mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0),
                                     _mm512_set1_epi32((int)col_step))};
    return d;
}

/* the 24-bit dither hash (lowbias32 keyed by k1, k2) of the 16 pixels index, index + col_step, ... (mod 2^32) */
SIMD_FN INLINE __m512i dither24(const dither_t *d, i64 index)
{
    __m512i x = _mm512_add_epi32(_mm512_set1_epi32((int)(uint32_t)index), d->lane);
    x = _mm512_add_epi32(_mm512_mullo_epi32(x, _mm512_set1_epi32((int)0x9E3779B9u)), d->K1);
    x = _mm512_xor_si512(x, _mm512_srli_epi32(x, 16));
    x = _mm512_mullo_epi32(x, _mm512_set1_epi32(0x7FEB352D));
    x = _mm512_xor_si512(x, _mm512_srli_epi32(x, 15));
    x = _mm512_mullo_epi32(x, _mm512_set1_epi32((int)0x846CA68Bu));
    x = _mm512_xor_si512(x, d->K2);
    x = _mm512_xor_si512(x, _mm512_srli_epi32(x, 16));
    return _mm512_srli_epi32(x, 8);   /* 24 bits: exact as int32 and as double */
}

/* half hlf (0: pixels 0-7, 1: 8-15) of 16 int32 */
SIMD_FN INLINE __m256i half8(__m512i v, int hlf)
{
    return hlf ? _mm512_extracti64x4_epi64(v, 1) : _mm512_castsi512_si256(v);
}

/* the dither u = x 2^-24 - 1/2 in [-1/2, 1/2) of half hlf of 16 hashes x (exact in float64) */
SIMD_FN INLINE __m512d dither_value8(__m512i x, int hlf)
{
    return _mm512_sub_pd(_mm512_mul_pd(_mm512_cvtepi32_pd(half8(x, hlf)), _mm512_set1_pd(1.0 / 16777216.0)),
                         _mm512_set1_pd(0.5));
}

/* the forward transform's constants: black, 1 / K, c, xmax, 1 / q */
typedef struct { __m512d black, inv_k, c, xmax, inv_step; } fwd_t;

SIMD_FN INLINE fwd_t fwd_consts(double black, double inv_k, double c, double xmax, double inv_step)
{
    fwd_t f = {_mm512_set1_pd(black), _mm512_set1_pd(inv_k), _mm512_set1_pd(c), _mm512_set1_pd(xmax),
               _mm512_set1_pd(inv_step)};
    return f;
}

/* symbols rint(2 sqrt(min(max((y - black) / K + c, 0), xmax)) / q + u) of 8 DN y (as doubles), one IEEE operation at a
 * time as numba's _forward_kernel */
SIMD_FN INLINE __m512i forward8(__m512d y, __m512d u, const fwd_t *f)
{
    __m512d x = _mm512_add_pd(_mm512_mul_pd(_mm512_sub_pd(y, f->black), f->inv_k), f->c);
    x = _mm512_min_pd(_mm512_max_pd(x, _mm512_setzero_pd()), f->xmax);
    __m512d z = _mm512_mul_pd(_mm512_set1_pd(2.0), _mm512_sqrt_pd(x));
    z = _mm512_add_pd(_mm512_mul_pd(z, f->inv_step), u);
    return _mm512_cvtpd_epi64(_mm512_roundscale_pd(z, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
}

SIMD_FN static void dither_grid_avx512(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step,
                                       double *out)
{
    const dither_t dh = dither_consts(k1, k2, col_step);
    for (i64 i = 0; i < rows; i++) {
        const i64 base = start + i * row_step;
        double *o = out + i * cols;
        for (i64 j = 0; j < cols; j += 16) {
            const __mmask16 mk = cols - j >= 16 ? 0xFFFF : (__mmask16)((1u << (cols - j)) - 1);
            const __m512i x = dither24(&dh, base + j * col_step);
            _mm512_mask_storeu_pd(o + j, (__mmask8)(mk & 0xFF), dither_value8(x, 0));
            _mm512_mask_storeu_pd(o + j + 8, (__mmask8)(mk >> 8), dither_value8(x, 1));
        }
    }
}

SIMD_FN static void forward_avx512(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride,
                                   double black, double inv_k, double c, double xmax, double inv_step,
                                   const double *u, int32_t *out)
{
    const fwd_t f = fwd_consts(black, inv_k, c, xmax, inv_step);
    const __m512i lane = _mm512_mullo_epi64(_mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0), _mm512_set1_epi64(col_stride));
    for (i64 i = 0; i < rows; i++) {
        const uint16_t *d = data + i * row_stride;
        for (i64 j = 0; j < cols; j += 8) {
            const __mmask8 mk = cols - j >= 8 ? 0xFF : (__mmask8)((1u << (cols - j)) - 1);
            __m512i v;
            if (col_stride == 1 && mk == 0xFF) {
                v = _mm512_cvtepu16_epi64(_mm_loadu_si128((const __m128i *)(d + j)));
            } else if (i + 1 < rows) {
                /* a CFA plane of the tile: every col_stride-th value by 32-bit gathers (low 16 bits kept); the
                 * 2 bytes read past an element are in the rows below it, inside the array */
                v = _mm512_and_si512(_mm512_cvtepu32_epi64(_mm512_mask_i64gather_epi32(
                        _mm256_setzero_si256(), mk, lane, d + j * col_stride, 2)), _mm512_set1_epi64(0xFFFF));
            } else {   /* the last row: element by element, nothing read past the array */
                i64 tmp[8] = {0};
                for (i64 k = 0; k < 8 && j + k < cols; k++) tmp[k] = d[(j + k) * col_stride];
                v = _mm512_loadu_si512(tmp);
            }
            _mm512_mask_cvtepi64_storeu_epi32(out + i * cols + j, mk,
                forward8(_mm512_cvtepi64_pd(v), _mm512_maskz_loadu_pd(mk, u + i * cols + j), &f));
        }
    }
}
/* Dither, forward transform and causal buffer of one CFA plane in one pass (the encoder's planes: prepare.dither_grid,
 * prepare.forward, then predictive._front, without the dither and symbol arrays in memory; the same values). data:
 * uint16 rows x cols at the strides given (elements); the dither of pixel (i, j) is that of flat index start +
 * i row_step + j col_step. p: (rows + 2) x (cols + 4) int64; this writes rows 2 .. of it, all but the two left pads of
 * its row 2 (they and rows 0, 1 hold c0 2^16, known only from the returned sum of the symbols). 16 pixels a step. */
SIMD_FN static i64 plane_buffer_avx512(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride,
                                       u64 k1, u64 k2, i64 start, i64 row_step, i64 col_step, double black,
                                       double inv_k, double c, double xmax, double inv_step, i64 *p)
{
    const fwd_t f = fwd_consts(black, inv_k, c, xmax, inv_step);
    const dither_t dh = dither_consts(k1, k2, col_step);
    const __m512d fix = _mm512_set1_pd(65536.0);
    const i64 ws = cols + 4;
    __m512i sum = _mm512_setzero_si512();
    for (i64 i = 0; i < rows; i++) {
        const uint16_t *d = data + i * row_stride;
        const i64 base = start + i * row_step;
        i64 *row = p + (i + 2) * ws;
        for (i64 j = 0; j < cols; j += 16) {
            const i64 n = cols - j < 16 ? cols - j : 16;
            const __mmask16 mk = (__mmask16)((1u << n) - 1);
            __m512i v;   /* 16 DN as int32 */
            if (col_stride == 1 && n == 16) {
                v = _mm512_cvtepu16_epi32(_mm256_loadu_si256((const __m256i *)(d + j)));
            } else if (col_stride == 2 && i + 1 < rows) {
                /* each 32-bit word holds a pixel of this plane in its low half; the high half of the last one is the
                 * next column, or the row below: inside the array but for the last row */
                v = _mm512_and_si512(_mm512_maskz_loadu_epi32(mk, d + 2 * j), _mm512_set1_epi32(0xFFFF));
            } else {
                int32_t tmp[16] = {0};
                for (i64 k = 0; k < n; k++) tmp[k] = d[(j + k) * col_stride];
                v = _mm512_loadu_si512(tmp);
            }
            const __m512i x = dither24(&dh, base + j * col_step);
            for (int hlf = 0; hlf < 2; hlf++) {
                const __mmask8 m8 = (__mmask8)(mk >> (8 * hlf));
                if (!m8) break;
                const __m512d u = dither_value8(x, hlf);
                const __m512i s = forward8(_mm512_cvtepi32_pd(half8(v, hlf)), u, &f);
                const __m512i s32 = _mm512_cvtepi32_epi64(_mm512_cvtepi64_epi32(s));   /* int32 symbols, as stored */
                sum = _mm512_mask_add_epi64(sum, m8, sum, s32);
                const __m512i fu = _mm512_cvtpd_epi64(_mm512_roundscale_pd(_mm512_mul_pd(u, fix),
                                                                          _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC));
                _mm512_mask_storeu_epi64(row + 2 + j + 8 * hlf, m8, _mm512_sub_epi64(_mm512_slli_epi64(s32, 16), fu));
            }
        }
        if (i > 0) row[0] = row[1] = p[(i + 1) * ws + 2];
        row[cols + 2] = row[cols + 3] = row[cols + 1];
    }
    return _mm512_reduce_add_epi64(sum);
}
/* The decoder's fixed-point dither floor(u 2^16) (decoder.fixed_dither of prepare.dither_grid's values) of a plane,
 * int32 rows x cols: with u = x 2^-24 - 1/2 (x the 24-bit hash), floor(u 2^16) = (x >> 8) - 2^15 exactly. */
SIMD_FN static void dither_fixed_avx512(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step,
                                        int32_t *out)
{
    const dither_t dh = dither_consts(k1, k2, col_step);
    const __m512i half = _mm512_set1_epi32(1 << 15);
    for (i64 i = 0; i < rows; i++) {
        const i64 base = start + i * row_step;
        for (i64 j = 0; j < cols; j += 16) {
            const __mmask16 mk = cols - j >= 16 ? 0xFFFF : (__mmask16)((1u << (cols - j)) - 1);
            const __m512i x = dither24(&dh, base + j * col_step);
            _mm512_mask_storeu_epi32(out + i * cols + j, mk, _mm512_sub_epi32(_mm512_srli_epi32(x, 8), half));
        }
    }
}

/* The inverse transform to DN (prepare._inverse_dn_kernel: rint(K ((s - u) q / 2)^2 + offset), clipped to 0 .. 65535),
 * the dither made on the way (prepare.dither_grid's values): symbols int32 rows x cols (C-contiguous), DN out at
 * the strides given (elements; a CFA plane of the frame). Rows of 1-pixel cells are stored 8 values at a time, of
 * 2-pixel cells by merging into the 32-bit words (the other half: a pixel of this thread's tile, not the next row's),
 * others value by value. */
SIMD_FN static void inverse_dn_avx512(const int32_t *sym, i64 rows, i64 cols, u64 k1, u64 k2, i64 start, i64 row_step,
                                      i64 col_step, double half_step, double k, double offset, uint16_t *out,
                                      i64 out_row_stride, i64 out_col_stride)
{
    const dither_t dh = dither_consts(k1, k2, col_step);
    const __m512d HS = _mm512_set1_pd(half_step), K = _mm512_set1_pd(k), OFF = _mm512_set1_pd(offset);
    const __m512d lo = _mm512_setzero_pd(), hi = _mm512_set1_pd(65535.0);
    for (i64 i = 0; i < rows; i++) {
        const i64 base = start + i * row_step;
        const int32_t *si = sym + i * cols;
        uint16_t *o = out + i * out_row_stride;
        for (i64 j = 0; j < cols; j += 16) {
            const i64 n = cols - j < 16 ? cols - j : 16;
            const __mmask16 mk = (__mmask16)((1u << n) - 1);
            const __m512i x = dither24(&dh, base + j * col_step);
            const __m512i s = _mm512_maskz_loadu_epi32(mk, si + j);
            __m512i dn[2];
            for (int hlf = 0; hlf < 2; hlf++) {
                const __m512d u = dither_value8(x, hlf);
                const __m512d zh = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(half8(s, hlf)), u), HS);
                __m512d v = _mm512_add_pd(_mm512_mul_pd(K, _mm512_mul_pd(zh, zh)), OFF);
                v = _mm512_roundscale_pd(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
                dn[hlf] = _mm512_cvtpd_epi64(_mm512_min_pd(_mm512_max_pd(v, lo), hi));
            }
            /* 16 DN as the low halves of 16 32-bit words */
            const __m512i d32 = _mm512_inserti64x4(_mm512_castsi256_si512(_mm512_cvtepi64_epi32(dn[0])),
                                                   _mm512_cvtepi64_epi32(dn[1]), 1);
            if (out_col_stride == 1) {
                _mm512_mask_cvtepi32_storeu_epi16(o + j, mk, d32);
            } else if (out_col_stride == 2 && n == 16 && j + 16 < cols) {
                /* the 16 words hold this plane's pixels j .. j + 15 and the next plane's beside them, all in this
                 * row */
                uint32_t *w32 = (uint32_t *)(o + 2 * j);
                const __m512i old = _mm512_loadu_si512(w32);
                const __m512i keep = _mm512_and_si512(old, _mm512_set1_epi32((int)0xFFFF0000u));
                _mm512_storeu_si512(w32, _mm512_or_si512(keep, d32));
            } else {
                int32_t tmp[16];
                _mm512_storeu_si512(tmp, d32);
                for (i64 q = 0; q < n; q++) o[(j + q) * out_col_stride] = (uint16_t)tmp[q];
            }
        }
    }
}

/* the AVX-512 path's functions (metraw.codec.native binds them where metraw_simd_paths() has PATH_AVX512) */
void metraw_dither_grid_avx512(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step, double *out)
{ dither_grid_avx512(k1, k2, start, rows, cols, row_step, col_step, out); }

void metraw_forward_avx512(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride, double black,
                           double inv_k, double c, double xmax, double inv_step, const double *u, int32_t *out)
{ forward_avx512(data, rows, cols, row_stride, col_stride, black, inv_k, c, xmax, inv_step, u, out); }

i64 metraw_plane_buffer_avx512(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride, u64 k1,
                               u64 k2, i64 start, i64 row_step, i64 col_step, double black, double inv_k, double c,
                               double xmax, double inv_step, i64 *p)
{
    return plane_buffer_avx512(data, rows, cols, row_stride, col_stride, k1, k2, start, row_step, col_step, black,
                               inv_k, c, xmax, inv_step, p);
}

void metraw_dither_fixed_avx512(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step,
                                int32_t *out)
{ dither_fixed_avx512(k1, k2, start, rows, cols, row_step, col_step, out); }

void metraw_inverse_dn_avx512(const int32_t *sym, i64 rows, i64 cols, u64 k1, u64 k2, i64 start, i64 row_step,
                              i64 col_step, double half_step, double k, double offset, uint16_t *out,
                              i64 out_row_stride, i64 out_col_stride)
{
    inverse_dn_avx512(sym, rows, cols, k1, k2, start, row_step, col_step, half_step, k, offset, out, out_row_stride,
                      out_col_stride);
}
#endif
