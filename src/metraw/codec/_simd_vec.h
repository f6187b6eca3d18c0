/* metraw.codec._simd, the kernels of _simd.c and _simd_prepare.c once more in GCC / Clang vector extensions: vectors
 * of one register (VL lanes of 64 bits: the decoder's lanes, the encoder's pixels; or of 32: the dither hash),
 * written once and compiled per target by the file that includes this one: _simd_avx2.c (AVX2, FMA, BMI2: VL = 4, a
 * 256-bit register, with vpermd lookups) and _simd_portable.c (any CPU; VL = 2: SSE2 on x86-64, NEON on ARM, or
 * scalar code). The includer defines VEC_PATH (the functions' suffix) and, for AVX2, VEC_AVX2. Same values as the
 * AVX-512 kernels and the numba loops, to the bit: integer arithmetic wraps (-fwrapv), float64 one IEEE operation at
 * a time (-ffp-contract=off: no fused multiply-add), and rounding to integers by adding 1.5 2^52 (round to nearest
 * even, exact for |z| < 2^51: symbols, DN and rANS quotients are far below it). Scatters and gathers are element
 * loops. On AVX2, predictions whose coefficients are int32s and neighbours in [-2^30, 2^30) (real frames:
 * symbols below 2^14) take one signed 32 x 32 -> 64-bit multiply a tap (pmuldq) and 32-bit absolute differences, the
 * same values as the exact 64-bit arithmetic, which the others take. */
#include "_simd.h"

#define VCAT2(a, b) a##_##b
#define VCAT(a, b) VCAT2(a, b)
#define VN(name) VCAT(name, VEC_PATH)

/* VL lanes of 64 bits a vector, the width of one register of the target (AVX2: 4 in a 256-bit register; otherwise 2,
 * 128 bits: SSE2, NEON): a wider generic vector has no machine mode there, so GCC keeps it in memory and takes much
 * of it apart lane by lane (2.5-4x slower than the numba loops, measured 2026-11-28). 8 pixels or lanes of the AVX-512
 * kernels are 8 / VL vectors here. */
#if defined(VEC_AVX2)
#define VL 4
#else
#define VL 2
#endif
typedef i64 vi __attribute__((vector_size(8 * VL)));
typedef u64 vu __attribute__((vector_size(8 * VL)));
typedef double vd __attribute__((vector_size(8 * VL)));
typedef int32_t vs32 __attribute__((vector_size(4 * VL)));
typedef uint32_t vu32 __attribute__((vector_size(4 * VL)));

#if defined(__clang__) || (defined(__GNUC__) && __GNUC__ >= 12)
#define SHUF(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#else
#define SHUF(a, b, ...) __builtin_shuffle(a, b, (vi){__VA_ARGS__})
#endif
#if VL == 4
#define IOTA {0, 1, 2, 3}
#else
#define IOTA {0, 1}
#endif

#define MAGIC 0x1.8p52                  /* 1.5 2^52: its units are integers */
#define MAGIC_BITS 0x4338000000000000LL

INLINE vi vset(i64 a) { return (vi){0} + a; }
/* a >> k (arithmetic) from logical shifts and a compare: targets without a 64-bit arithmetic shift (SSE2, AVX2) would
 * otherwise take each lane apart */
INLINE vi vsra(vi a, int k) { const vi s = a < 0; return (vi)((vu)(a ^ s) >> k) ^ s; }
INLINE vi vabs(vi a) { const vi s = a < 0; return (a ^ s) - s; }
/* products mod 2^64 from 32 x 32 -> 64-bit multiplies (pmuludq), which SSE2 and AVX2 have, unlike 64-bit ones:
 * vmulu32 of the low 32 bits of each factor, vmul of any */
#if defined(VEC_AVX2)
INLINE vi vmulu32(vi a, vi b) { return (vi)_mm256_mul_epu32((__m256i)a, (__m256i)b); }
INLINE vi vsel(vi m, vi a, vi b) { return (vi)_mm256_blendv_epi8((__m256i)b, (__m256i)a, (__m256i)m); }
#elif METRAW_X86
INLINE vi vmulu32(vi a, vi b) { return (vi)_mm_mul_epu32((__m128i)a, (__m128i)b); }
INLINE vi vsel(vi m, vi a, vi b) { return (a & m) | (b & ~m); }   /* m: -1 (a) or 0 (b) per lane */
#else
INLINE vi vmulu32(vi a, vi b) { return (vi)(((vu)a & 0xFFFFFFFFULL) * ((vu)b & 0xFFFFFFFFULL)); }
INLINE vi vsel(vi m, vi a, vi b) { return (a & m) | (b & ~m); }
#endif
INLINE vi vmul(vi a, vi b)
{
#if METRAW_X86
    const vi ah = (vi)((vu)a >> 32), bh = (vi)((vu)b >> 32);
    return vmulu32(a, b) + ((vmulu32(ah, b) + vmulu32(a, bh)) << 32);
#else
    return a * b;
#endif
}
INLINE vd vseld(vi m, vd a, vd b) { return (vd)vsel(m, (vi)a, (vi)b); }
INLINE vi vmax(vi a, vi b) { return vsel(a > b, a, b); }
/* int64 |a| < 2^51 to double, exactly */
INLINE vd vi2d(vi a) { return (vd)(a + MAGIC_BITS) - MAGIC; }
/* rint(z) (nearest, ties to even) as int64, |z| < 2^51 */
INLINE vi vrint(vd z) { return (vi)(z + MAGIC) - MAGIC_BITS; }
/* floor(z) as int64, |z| < 2^51 */
INLINE vi vfloor(vd z) { const vi r = vrint(z); return r + (vi)(vi2d(r) > z); }
/* a < b ? a : b and a > b ? a : b: what minpd / maxpd return (b where either is NaN) */
#if defined(VEC_AVX2)
INLINE vd vmind(vd a, vd b) { return (vd)_mm256_min_pd((__m256d)a, (__m256d)b); }
INLINE vd vmaxd(vd a, vd b) { return (vd)_mm256_max_pd((__m256d)a, (__m256d)b); }
/* int32 to double (one vcvtdq2pd) */
INLINE vd vs32_to_d(vs32 a) { return (vd)_mm256_cvtepi32_pd((__m128i)a); }
#else
INLINE vd vmind(vd a, vd b) { return vseld((vi)(a < b), a, b); }
INLINE vd vmaxd(vd a, vd b) { return vseld((vi)(a > b), a, b); }
INLINE vd vs32_to_d(vs32 a) { return __builtin_convertvector(a, vd); }
#endif
INLINE vd vsqrt(vd x)
{
#if defined(VEC_AVX2)
    return (vd)_mm256_sqrt_pd((__m256d)x);
#elif METRAW_X86
    return (vd)_mm_sqrt_pd((__m128d)x);
#else
    for (int j = 0; j < VL; j++) x[j] = __builtin_sqrt(x[j]);
    return x;
#endif
}

/* gathers: base[idx[j]] of 32-bit (sign- or zero-extended), 16-bit, 8-bit and 64-bit elements, by element loads on
 * every path, AVX2 included: its gather instructions are microcoded on AMD Zen 2 to 4 (VPGATHERDD ymm 39 uops on Zen
 * 3, per uops.info) and slowed by the GDS (Downfall) microcode mitigation on Intel Skylake to Tiger Lake, while the
 * element loads decode as fast as they did on an Emerald Rapids Xeon (2026-11-29: 0.99-1.015x, canon_dng, micasense,
 * spacenet_pan, both 16-lane modes) */
#define GATHER_LOOP(T) { vi r; for (int j = 0; j < VL; j++) r[j] = (i64)(T)b[idx[j]]; return r; }
INLINE vi gather_s32(const int32_t *b, vi idx) GATHER_LOOP(int32_t)
INLINE vi gather_u32(const uint32_t *b, vi idx) GATHER_LOOP(uint32_t)
INLINE vi gather_u16(const uint16_t *b, vi idx) GATHER_LOOP(uint16_t)
INLINE vi gather_s16(const int16_t *b, vi idx) GATHER_LOOP(int16_t)
INLINE vi gather_u8(const uint8_t *b, vi idx) GATHER_LOOP(uint8_t)
INLINE vi gather_64(const u64 *b, vi idx) GATHER_LOOP(u64)

/* n <= VL values from p (zeros past n) and to p (n = VL: one load or store, not a memcpy call) */
#define LOADN(T, V, p, n) ({ V v_ = {0}; if ((n) == VL) { memcpy(&v_, (p), sizeof v_); } \
                             else { memcpy(&v_, (p), (size_t)(n) * sizeof(T)); } v_; })
#define STOREN(T, p, v, n) do { __typeof__(v) s_ = (v); if ((n) == VL) { memcpy((p), &s_, VL * sizeof(T)); } \
                                 else { memcpy((p), &s_, (size_t)(n) * sizeof(T)); } } while (0)
#define LOADV(V, p) ({ V v_; memcpy(&v_, (p), sizeof v_); v_; })

/* ---- the dither and the transforms (_simd_prepare.c): VL pixels a step ---- */

/* the 24-bit dither hash (lowbias32 keyed by k1, k2, mod 2^32) of pixels index, index + col_step, ... */
INLINE vu32 dither24(u64 k1, u64 k2, i64 index, i64 col_step)
{
    const vu32 lane = IOTA;
    vu32 x = (uint32_t)index + lane * (uint32_t)col_step;
    x = x * 0x9E3779B9u + (uint32_t)k1;
    x ^= x >> 16;
    x *= 0x7FEB352Du;
    x ^= x >> 15;
    x *= 0x846CA68Bu;
    x ^= (uint32_t)k2;
    x ^= x >> 16;
    return x >> 8;
}

#if defined(VEC_AVX2)
/* dither24 of 8 pixels in one register */
INLINE __m256i dither24x8(u64 k1, u64 k2, i64 index, i64 col_step)
{
    const __m256i lane8 = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    __m256i x = _mm256_add_epi32(_mm256_set1_epi32((int)(uint32_t)index),
                                 _mm256_mullo_epi32(lane8, _mm256_set1_epi32((int)(uint32_t)col_step)));
    x = _mm256_add_epi32(_mm256_mullo_epi32(x, _mm256_set1_epi32((int)0x9E3779B9u)), _mm256_set1_epi32((int)(uint32_t)k1));
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x7FEB352D));
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 15));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0x846CA68Bu));
    x = _mm256_xor_si256(x, _mm256_set1_epi32((int)(uint32_t)k2));
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
    return _mm256_srli_epi32(x, 8);
}
#endif

/* u = x 2^-24 - 1/2 (exact) */
INLINE vd dither_value(vu32 x) { return vs32_to_d((vs32)x) * (1.0 / 16777216.0) - 0.5; }

typedef struct { double black, inv_k, c, xmax, inv_step; } fwd_t;

/* rint(2 sqrt(min(max((y - black) / K + c, 0), xmax)) / q + u), one IEEE operation at a time */
INLINE vi forward8(vd y, vd u, const fwd_t *f)
{
    vd x = (y - f->black) * f->inv_k + f->c;
    x = vmind(vmaxd(x, (vd){0}), (vd){0} + f->xmax);
    vd z = 2.0 * vsqrt(x);
    z = z * f->inv_step + u;
    return vrint(z);
}

/* n <= VL DN at stride cs as int32 */
INLINE vs32 load_dn(const uint16_t *d, i64 cs, i64 n, int more)
{
    /* contiguous or every other (a CFA plane): one load (the latter reads d[2 VL - 1], inside the row where more DN
     * follow); else lane by lane (through the stack: a store-forwarding stall a vector) */
    typedef uint16_t vu16 __attribute__((vector_size(2 * VL)));
    typedef uint16_t vu16x2 __attribute__((vector_size(4 * VL)));
    if (n == VL && cs == 1) return __builtin_convertvector(LOADV(vu16, d), vs32);
#if VL == 4
    if (n == VL && cs == 2 && more) {
        const vu16x2 t = LOADV(vu16x2, d);
        return __builtin_convertvector(__builtin_shufflevector(t, t, 0, 2, 4, 6), vs32);
    }
#else
    if (n == VL && cs == 2 && more) {
        const vu16x2 t = LOADV(vu16x2, d);
        return __builtin_convertvector(__builtin_shufflevector(t, t, 0, 2), vs32);
    }
#endif
    vs32 v = {0};
    for (i64 k = 0; k < n; k++) v[k] = d[k * cs];
    return v;
}

void VN(metraw_dither_grid)(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step, double *out)
{
    for (i64 i = 0; i < rows; i++)
        for (i64 j = 0; j < cols; j += VL) {
            const vd u = dither_value(dither24(k1, k2, start + i * row_step + j * col_step, col_step));
            STOREN(double, out + i * cols + j, u, cols - j < VL ? cols - j : VL);
        }
}

void VN(metraw_forward)(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride, double black,
                        double inv_k, double c, double xmax, double inv_step, const double *u, int32_t *out)
{
    const fwd_t f = {black, inv_k, c, xmax, inv_step};
    for (i64 i = 0; i < rows; i++)
        for (i64 j = 0; j < cols; j += VL) {
            const i64 n = cols - j < VL ? cols - j : VL;
            const vd y = __builtin_convertvector(load_dn(data + i * row_stride + j * col_stride, col_stride, n, j + VL < cols), vd);
            const vi s = forward8(y, LOADN(double, vd, u + i * cols + j, n), &f);
            STOREN(int32_t, out + i * cols + j, __builtin_convertvector(s, vs32), n);
        }
}

/* the encoder's plane buffer in one pass (plane_buffer_avx512): floor(u 2^16) = (x >> 8) - 2^15 exactly */
i64 VN(metraw_plane_buffer)(const uint16_t *data, i64 rows, i64 cols, i64 row_stride, i64 col_stride, u64 k1, u64 k2,
                            i64 start, i64 row_step, i64 col_step, double black, double inv_k, double c, double xmax,
                            double inv_step, i64 *p)
{
    const fwd_t f = {black, inv_k, c, xmax, inv_step};
    const vi lane = IOTA;
    const i64 ws = cols + 4;
    vi sum = {0};
    for (i64 i = 0; i < rows; i++) {
        i64 *row = p + (i + 2) * ws;
        i64 j = 0;
#if defined(VEC_AVX2)
        /* 8 pixels a step: one 8-lane dither hash, the rest as two vectors of 4 */
        for (; j + 8 < cols || (j + 8 == cols && col_stride == 1); j += 8) {
            const __m256i x = dither24x8(k1, k2, start + i * row_step + j * col_step, col_step);
            const uint16_t *d = data + i * row_stride + j * col_stride;
            for (int h = 0; h < 2; h++) {
                const __m128i xh = h ? _mm256_extracti128_si256(x, 1) : _mm256_castsi256_si128(x);
                const vd u = vs32_to_d((vs32)xh) * (1.0 / 16777216.0) - 0.5;
                const vd y = vs32_to_d(load_dn(d + 4 * h * col_stride, col_stride, 4, 1));
                const vi s = forward8(y, u, &f);
                /* as stored (int32): the low dwords sign-extended */
                const __m256i lo2 = _mm256_shuffle_epi32((__m256i)s, _MM_SHUFFLE(2, 2, 0, 0));
                const vi s32 = (vi)_mm256_blend_epi32((__m256i)s, _mm256_srai_epi32(lo2, 31), 0xAA);
                sum += s32;
                const vi fu = (vi)_mm256_cvtepi32_epi64(_mm_srli_epi32(xh, 8)) - (1 << 15);   /* floor(u 2^16) */
                const vi pv = (s32 << 16) - fu;
                memcpy(row + 2 + j + 4 * h, &pv, sizeof pv);
            }
        }
#endif
        for (; j < cols; j += VL) {
            const i64 n = cols - j < VL ? cols - j : VL;
            const vd y = __builtin_convertvector(load_dn(data + i * row_stride + j * col_stride, col_stride, n, j + VL < cols), vd);
            const vu32 x = dither24(k1, k2, start + i * row_step + j * col_step, col_step);
            const vi s = forward8(y, dither_value(x), &f);
            const vi s32 = __builtin_convertvector(__builtin_convertvector(s, vs32), vi);   /* as stored */
            sum += s32 & (lane < n);
            const vi fu = __builtin_convertvector((vs32)(x >> 8), vi) - (1 << 15);
            STOREN(i64, row + 2 + j, (s32 << 16) - fu, n);
        }
        if (i > 0) row[0] = row[1] = p[(i + 1) * ws + 2];
        row[cols + 2] = row[cols + 3] = row[cols + 1];
    }
    i64 total = 0;
    for (int j = 0; j < VL; j++) total += sum[j];
    return total;
}

void VN(metraw_dither_fixed)(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step, int32_t *out)
{
    for (i64 i = 0; i < rows; i++) {
        i64 j = 0;
#if defined(VEC_AVX2)
        for (; j + 8 <= cols; j += 8) {
            const __m256i x = dither24x8(k1, k2, start + i * row_step + j * col_step, col_step);
            _mm256_storeu_si256((__m256i *)(void *)(out + i * cols + j),
                                _mm256_sub_epi32(_mm256_srli_epi32(x, 8), _mm256_set1_epi32(1 << 15)));
        }
#endif
        for (; j < cols; j += VL) {
            const vu32 x = dither24(k1, k2, start + i * row_step + j * col_step, col_step);
            STOREN(int32_t, out + i * cols + j, (vs32)(x >> 8) - (1 << 15), cols - j < VL ? cols - j : VL);
        }
    }
}

/* rint(K ((s - u) q / 2)^2 + offset) clipped to 0 .. 65535 (clipping before rounding: the same, the bounds being
 * integers) */
void VN(metraw_inverse_dn)(const int32_t *sym, i64 rows, i64 cols, u64 k1, u64 k2, i64 start, i64 row_step,
                           i64 col_step, double half_step, double k, double offset, uint16_t *out, i64 out_row_stride,
                           i64 out_col_stride)
{
    for (i64 i = 0; i < rows; i++) {
        uint16_t *o = out + i * out_row_stride;
        i64 j = 0;
#if defined(VEC_AVX2)
        /* 8 pixels a step: one 8-lane dither hash, two vectors of 4, the DN packed to 16 bits in one register */
        for (; j + 8 <= cols; j += 8) {
            const __m256i x = dither24x8(k1, k2, start + i * row_step + j * col_step, col_step);
            __m256i dn2[2];
            for (int h = 0; h < 2; h++) {
                const __m128i xh = h ? _mm256_extracti128_si256(x, 1) : _mm256_castsi256_si128(x);
                const vd u = vs32_to_d((vs32)xh) * (1.0 / 16777216.0) - 0.5;
                const vd s = vs32_to_d(LOADV(vs32, sym + i * cols + j + 4 * h));
                const vd zh = (s - u) * half_step;
                const vd v = vmind(vmaxd(k * (zh * zh) + offset, (vd){0}), (vd){0} + 65535.0);
                dn2[h] = (__m256i)vrint(v);   /* 0 .. 65535 */
            }
            /* the 8 DN's low words: dwords 0, 2 of each 128-bit half hold them */
            const __m256i d32 = _mm256_permute4x64_epi64(_mm256_castps_si256(_mm256_shuffle_ps(
                _mm256_castsi256_ps(dn2[0]), _mm256_castsi256_ps(dn2[1]), _MM_SHUFFLE(2, 0, 2, 0))), _MM_SHUFFLE(3, 1, 2, 0));
            if (out_col_stride == 1) {
                _mm_storeu_si128((__m128i *)(void *)(o + j),
                                 _mm_packus_epi32(_mm256_castsi256_si128(d32), _mm256_extracti128_si256(d32, 1)));
            } else if (out_col_stride == 2 && j + 8 < cols) {
                /* as inverse_dn_avx512: the 8 DN into the low halves of 8 32-bit words, whose high halves (the next
                 * plane's pixels, in this row and this thread's tile) are kept */
                __m256i *w32 = (__m256i *)(void *)(o + 2 * j);
                const __m256i keep = _mm256_and_si256(_mm256_loadu_si256(w32), _mm256_set1_epi32((int)0xFFFF0000u));
                _mm256_storeu_si256(w32, _mm256_or_si256(keep, d32));
            } else {
                const __m128i d16 = _mm_packus_epi32(_mm256_castsi256_si128(d32), _mm256_extracti128_si256(d32, 1));
                uint16_t *oj = o + j * out_col_stride;
                oj[0] = (uint16_t)_mm_extract_epi16(d16, 0); oj[out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 1);
                oj[2 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 2);
                oj[3 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 3);
                oj[4 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 4);
                oj[5 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 5);
                oj[6 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 6);
                oj[7 * out_col_stride] = (uint16_t)_mm_extract_epi16(d16, 7);
            }
        }
#endif
        for (; j < cols; j += VL) {
            const i64 n = cols - j < VL ? cols - j : VL;
            const vd u = dither_value(dither24(k1, k2, start + i * row_step + j * col_step, col_step));
            const vd s = __builtin_convertvector(LOADN(int32_t, vs32, sym + i * cols + j, n), vd);
            const vd zh = (s - u) * half_step;
            const vd v = vmind(vmaxd(k * (zh * zh) + offset, (vd){0}), (vd){0} + 65535.0);
            const vi dn = vrint(v);
            if (out_col_stride == 1 && n == VL) {
                typedef uint16_t vu16 __attribute__((vector_size(2 * VL)));
                const vu16 o16 = __builtin_convertvector(dn, vu16);
                memcpy(o + j, &o16, sizeof o16);
            } else if (out_col_stride == 1) {
                for (i64 q = 0; q < n; q++) o[j + q] = (uint16_t)dn[q];
            } else {
                for (i64 q = 0; q < n; q++) o[(j + q) * out_col_stride] = (uint16_t)dn[q];
            }
        }
    }
}

/* ---- the coder's loops (_simd.c) ---- */

/* predictive._front: s 2^16 - floor(u 2^16), the pads as front_avx512 */
void VN(metraw_front)(const int32_t *s, const double *u, i64 h, i64 w, i64 c0s, i64 *p)
{
    const i64 ws = w + 4;
    for (i64 k = 0; k < 2 * ws; k++) p[k] = c0s;
    for (i64 y = 0; y < h; y++) {
        i64 *row = p + (y + 2) * ws;
        for (i64 x = 0; x < w; x += VL) {
            const i64 n = w - x < VL ? w - x : VL;
            const vi sv = __builtin_convertvector(LOADN(int32_t, vs32, s + y * w + x, n), vi);
            const vi fu = vfloor(LOADN(double, vd, u + y * w + x, n) * 65536.0);
            STOREN(i64, row + 2 + x, (sv << 16) - fu, n);
        }
        row[0] = row[1] = y > 0 ? p[(y + 1) * ws + 2] : c0s;
        row[w + 2] = row[w + 3] = row[w + 1];
    }
}

/* predictive._index: idx = r + amax, or the escape 2 amax + 1 where |r| > amax; then the counts */
void VN(metraw_index)(const int32_t *r, const int32_t *t, i64 n, i64 amax, i64 nt, int32_t *idx, i64 *counts)
{
    const i64 alpha = 2 * amax + 2;
    const int32_t a = (int32_t)amax, e = (int32_t)(alpha - 1);
    for (i64 i = 0; i < n; i += VL) {
        const i64 m = n - i < VL ? n - i : VL;
        const vs32 v = LOADN(int32_t, vs32, r + i, m);
        const vs32 out = (v > a) | (v < -a);
        STOREN(int32_t, idx + i, ((v + a) & ~out) | (((vs32){0} + e) & out), m);
    }
    index_counts(t, idx, n, alpha, nt, counts);
}

/* the causal neighbours of VL pixels (names as in decoder._pixel) */
typedef struct { vi W, WW, N, NW, NE, NE2, NW2, NN, NNW, NNE, NNW2, NNE2; } vnbr_t;

/* the model's tables: T the 7 activity thresholds (padded with INT64_MAX); ct[8 k + c] tap k's coefficient of context
 * c (taps 0-11, then 12: the bias; 8 contexts, unused ones zero); AVX2: lo[k], hi[k] the low and high 32 bits of tap
 * k's 8 coefficients as 8 dwords, of which vpermd picks each lane's by its context */
typedef struct {
    vi T[7];
    i64 ct[13 * 8];
#if defined(VEC_AVX2)
    __m256i lo[13], hi[13];
    int k32;   /* every coefficient (taps 0-11) and bias is an int32 */
#endif
} vtab_t;

INLINE void model_tables(const i64 *thr, i64 nthr, const i64 *coef13, vtab_t *vt)
{
    for (int k = 0; k < 7; k++) vt->T[k] = vset(k < nthr ? thr[k] : INT64_MAX);
    for (int k = 0; k < 13; k++)
        for (int c = 0; c < 8; c++) vt->ct[8 * k + c] = coef13[c * 13 + k];
#if defined(VEC_AVX2)
    for (int k = 0; k < 13; k++) {
        int32_t lo[8], hi[8];
        for (int c = 0; c < 8; c++) {
            lo[c] = (int32_t)(uint32_t)vt->ct[8 * k + c];
            hi[c] = (int32_t)(uint32_t)((u64)vt->ct[8 * k + c] >> 32);
        }
        vt->lo[k] = _mm256_loadu_si256((const __m256i *)lo);
        vt->hi[k] = _mm256_loadu_si256((const __m256i *)hi);
    }
    vt->k32 = 1;   /* taps 0-11 and the bias */
    for (int k = 0; k < 13 * 8; k++) vt->k32 &= vt->ct[k] == (i64)(int32_t)vt->ct[k];
#endif
}

#if !defined(VEC_AVX2)
/* a coefficient of each lane's context: tab8[C[j]] */
INLINE vi lookup8(const i64 *tab8, vi C)
{
    vi r;
    for (int j = 0; j < VL; j++) r[j] = tab8[C[j]];
    return r;
}
#endif

/* activity context (to *Cp) and prediction W + ((sum_i k_i n_i - W sum_i k_i) >> 12) + bias (vpredict of _simd.c),
 * mod 2^64 */
INLINE vi vpredict_(const vtab_t *m, const vnbr_t *n, vi *Cp, const int n32)
{
    const vi *T = m->T;
#if defined(VEC_AVX2)
    /* n32: every neighbour in [-2^30, 2^30), so a difference is an int32 and its low dword's vpabsd its |.| */
#define VABS(d) (n32 ? (vi)_mm256_and_si256(_mm256_abs_epi32((__m256i)(d)), _mm256_set1_epi64x(0xFFFFFFFF)) : vabs(d))
#else
#define VABS(d) vabs(d)
#endif
    const vi act = VABS(n->W - n->NW) + VABS(n->N - n->NW) + VABS(n->N - n->NE) + VABS(n->W - n->WW)
                 + VABS(n->N - n->NN);
#undef VABS
    const vi C = -((act > T[0]) + (act > T[1]) + (act > T[2]) + (act > T[3]) + (act > T[4]) + (act > T[5])
                   + (act > T[6]));
    *Cp = C;
#if defined(VEC_AVX2)
    /* sum k n = sum lo(k) lo(n) + 2^32 sum (lo(k) hi(n) + hi(k) lo(n)) mod 2^64: 3 pmuludq a tap, one shift in all.
     * C's high dword is 0: vpermd puts context C's dword in each lane's low half (pmuludq reads only that) */
    const __m256i ci = (__m256i)C;
#define LO(k) ((vi)_mm256_permutevar8x32_epi32(m->lo[k], ci))
#define HI(k) ((vi)_mm256_permutevar8x32_epi32(m->hi[k], ci))
    vi a;
    if (n32) {
        /* every neighbour and coefficient an int32: each product exact from one signed 32 x 32 -> 64-bit multiply
         * (pmuldq), so the sum is the same mod 2^64 */
        vi s = {0};
#define TAP(k, v, op) s op (vi)_mm256_mul_epi32((__m256i)(v), (__m256i)LO(k))
        TAP(0, n->N, +=); TAP(1, n->NW, +=); TAP(2, n->NE, +=); TAP(3, n->WW, +=); TAP(4, n->NN, +=);
        TAP(5, n->NW2, +=); TAP(6, n->NNW, +=); TAP(7, n->NNE, +=); TAP(8, n->NE2, +=); TAP(9, n->NNW2, +=);
        TAP(10, n->NNE2, +=); TAP(11, n->W, -=);
#undef TAP
        a = s;
    } else {
        vi lo = {0}, cr = {0};
#define TAP(k, v, op) do { const vi x_ = (v), kl_ = LO(k); lo op vmulu32(x_, kl_); \
                           cr op vmulu32((vi)((vu)x_ >> 32), kl_) + vmulu32(x_, HI(k)); } while (0)
        TAP(0, n->N, +=); TAP(1, n->NW, +=); TAP(2, n->NE, +=); TAP(3, n->WW, +=); TAP(4, n->NN, +=);
        TAP(5, n->NW2, +=); TAP(6, n->NNW, +=); TAP(7, n->NNE, +=); TAP(8, n->NE2, +=); TAP(9, n->NNW2, +=);
        TAP(10, n->NNE2, +=); TAP(11, n->W, -=);
#undef TAP
        a = lo + (cr << 32);
    }
    /* the bias: an int32 (n32) sign-extended by a signed multiply by 1, else from its two halves */
    const vi bias = n32 ? (vi)_mm256_mul_epi32((__m256i)LO(12), _mm256_set1_epi64x(1))
                        : (vi)((vu)LO(12) & 0xFFFFFFFFULL) | (HI(12) << 32);
#undef LO
#undef HI
#else
    const i64 *ct = m->ct;
#define KN(k, v) vmul(lookup8(ct + 8 * (k), C), v)
    const vi a = KN(0, n->N) + KN(1, n->NW) + KN(2, n->NE) + KN(3, n->WW) + KN(4, n->NN) + KN(5, n->NW2)
               + KN(6, n->NNW) + KN(7, n->NNE) + KN(8, n->NE2) + KN(9, n->NNW2) + KN(10, n->NNE2) - KN(11, n->W);
#undef KN
    const vi bias = lookup8(ct + 8 * 12, C);
#endif
    return n->W + vsra(a, 12) + bias;
}
INLINE vi vpredict(const vtab_t *m, const vnbr_t *n, vi *Cp) { return vpredict_(m, n, Cp, 0); }

/* VL pixels of a row (m <= VL of them): residuals and table indices out, |r| of the m into *rmax; n32: every
 * neighbour in [-2^30, 2^30) (vpredict_) */
INLINE void residual_step(const vtab_t *vt, const i64 *b, i64 ws, i64 m, i64 tab0, int psh, int csh, int32_t *ro,
                          int32_t *to, vi *rmax, const int n32)
{
#define LD(o) LOADN(i64, vi, b + (o), m)
    const vnbr_t n = {.W = LD(-1), .WW = LD(-2), .N = LD(-ws), .NW = LD(-ws - 1), .NE = LD(-ws + 1),
                      .NE2 = LD(-ws + 2), .NW2 = LD(-ws - 2), .NN = LD(-2 * ws), .NNW = LD(-2 * ws - 1),
                      .NNE = LD(-2 * ws + 1), .NNW2 = LD(-2 * ws - 2), .NNE2 = LD(-2 * ws + 2)};
    const vi P = LD(0);
#undef LD
    vi C;
    const vi acc = vpredict_(vt, &n, &C, n32);
    const vi sv = vsra(P + 32767, 16);
    const vi mh = acc + ((sv << 16) - P) + (1 << 15);
    vi r = sv - vsra(mh, 16);
    vi fr = mh & 0xFFFF;
    const vi f = 1 - (vi)((vu)fr >> 15);
    const vi nf = -f;
    fr ^= nf & 0xFFFF;
    r = (r ^ nf) + f;
    const vi t = tab0 + (C << csh) + (vi)((((vu)fr >> 13) & 3) >> psh);
#if defined(VEC_AVX2)
    if (m == VL) {   /* the low dwords by one vpermd */
        const __m256i lo = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
        _mm_storeu_si128((__m128i *)(void *)ro, _mm256_castsi256_si128(_mm256_permutevar8x32_epi32((__m256i)r, lo)));
        _mm_storeu_si128((__m128i *)(void *)to, _mm256_castsi256_si128(_mm256_permutevar8x32_epi32((__m256i)t, lo)));
    } else
#endif
    {
        STOREN(int32_t, ro, __builtin_convertvector(r, vs32), m);
        STOREN(int32_t, to, __builtin_convertvector(t, vs32), m);
    }
    const vi lane = IOTA;
    *rmax = vmax(*rmax, vabs(r) & (lane < m));
}

/* whether every value of a padded row (n of them) is in [-2^30, 2^30) (FITS30: int32 products and differences):
 * the OR of the values + 2^30 is below 2^31 */
#define FITS30(v) (((u64)(v) + 0x40000000ULL) >> 31 == 0)
INLINE int row_fits32(const i64 *row, i64 n)
{
    vu acc = {0};
    i64 k = 0;
    for (; k + VL <= n; k += VL) acc |= (vu)LOADV(vi, row + k) + 0x40000000ULL;
    u64 a = 0;
    for (; k < n; k++) a |= (u64)row[k] + 0x40000000ULL;
    for (int j = 0; j < VL; j++) a |= acc[j];
    return a >> 31 == 0;
}

i64 VN(metraw_residuals)(const i64 *pf, i64 h, i64 w, const i64 *thr, i64 nthr, const i64 *coef13, i64 tab0,
                         i64 pshift, int32_t *r_out, int32_t *t_out)
{
    const i64 ws = w + 4;
    vtab_t vt;
    model_tables(thr, nthr, coef13, &vt);
    const int psh = (int)pshift, csh = (int)(2 - pshift);
    vi rmax = {0};
#if defined(VEC_AVX2)
    /* rows of the padded buffer (y + 2 the image's row y) whose values are all in [-2^30, 2^30); a pixel whose three
     * rows are takes one signed 32-bit multiply a tap where the coefficients are int32s (the same sums) */
    int fit[3] = {row_fits32(pf, ws), row_fits32(pf + ws, ws), 0};
#endif
    for (i64 y = 0; y < h; y++) {
        const i64 *row = pf + (y + 2) * ws + 2;
        int32_t *ro = r_out + y * w, *to = t_out + y * w;
        i64 x = 0;
#if defined(VEC_AVX2)
        fit[2] = row_fits32(row - 2, ws);
        if (vt.k32 && fit[0] && fit[1] && fit[2])
            for (; x + VL <= w; x += VL) residual_step(&vt, row + x, ws, VL, tab0, psh, csh, ro + x, to + x, &rmax, 1);
        fit[0] = fit[1];
        fit[1] = fit[2];
#endif
        for (; x + VL <= w; x += VL) residual_step(&vt, row + x, ws, VL, tab0, psh, csh, ro + x, to + x, &rmax, 0);
        if (x < w) residual_step(&vt, row + x, ws, w - x, tab0, psh, csh, ro + x, to + x, &rmax, 0);
    }
    i64 out = 0;
    for (int j = 0; j < VL; j++) out = rmax[j] > out ? rmax[j] : out;
    return out;
}

#include "_simd_vec_lanes.h"
