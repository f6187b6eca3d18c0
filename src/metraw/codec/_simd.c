/* metraw.codec._simd: the decoder's per-pixel loop (metraw.codec.decoder.decode_plane) in C, with the steady
 * part of 8- and 16-lane row groups in AVX-512 (lane j of a group in element j of a 512-bit register).
 *
 * Called through ctypes (metraw.codec.native): no Python API, so no Python headers are needed. The arithmetic is
 * the encoder's and numba decoder's to the bit (int64 two's complement; built with -fwrapv), and the tests compare
 * the two decoders on every frame they code.
 *
 * Why lanes in registers: each lane is one dependency chain (neighbours -> activity context -> prediction ->
 * rANS table -> value -> next pixel), so a scalar decoder is bound by that chain's latency. Within one column step
 * the lanes of a group are independent (lane j runs 3 pixels behind lane j - 1), so one vector instruction
 * advances 8 chains. A lane's causal neighbours are the last 8 values of itself and of the two lanes above it: they
 * are kept as histories in registers (H[k]: the value k steps back) and shifted across lanes (valignq), so the
 * steady loop reads no pixel it or its neighbours wrote; the rows above lane 0 (the previous group's last two rows)
 * enter as two more histories (G). Per step: 4 gathers (dither, symbol table, frequency table, rANS word; a fifth, the
 * escape's, only in a step with one) and one scatter of the 8 values. The edges of each group (the first 3 (L - 1) + 1
 * and the last column steps) take the scalar path; 16-lane groups run two vectors side by side (two chains: the
 * gathers' latency overlaps) with 8-lane edges (decode_group16). The encoder's passes follow the decoder (residuals,
 * rANS, causal buffer, alphabet indices); _simd_prepare.c holds the dither and transforms. */
#include "_simd.h"
#if METRAW_X86


/* the causal neighbours of 8 pixels (names as in decoder._pixel: N = the row above, NN two above, ...) */
typedef struct { __m512i W, WW, N, NW, NE, NE2, NW2, NN, NNW, NNE, NNW2, NNE2; } vnbr_t;

/* activity context (to *Cp) and prediction W + ((sum_i k_i n_i - W sum_i k_i) >> 12) + bias of 8 pixels; T: the 7
 * thresholds, CT[k]: tap k's coefficient of each of the 8 contexts (vpermq picks a pixel's) */
INLINE SIMD_FN __m512i vpredict(const __m512i *T, const __m512i *CT, const vnbr_t *n, __m512i *Cp)
{
#define ABSDIF(a, b) _mm512_abs_epi64(_mm512_sub_epi64(a, b))
    __m512i act = _mm512_add_epi64(_mm512_add_epi64(ABSDIF(n->W, n->NW), ABSDIF(n->N, n->NW)),
                                   _mm512_add_epi64(_mm512_add_epi64(ABSDIF(n->N, n->NE), ABSDIF(n->W, n->WW)),
                                                    ABSDIF(n->N, n->NN)));
#undef ABSDIF
    /* context: count of thresholds below act (masks as 0 / -1 vectors, summed in a tree) */
#define GT(k) _mm512_movm_epi64(_mm512_cmpgt_epi64_mask(act, T[k]))
    __m512i c0123 = _mm512_add_epi64(_mm512_add_epi64(GT(0), GT(1)), _mm512_add_epi64(GT(2), GT(3)));
    __m512i c456 = _mm512_add_epi64(_mm512_add_epi64(GT(4), GT(5)), GT(6));
#undef GT
    __m512i C = _mm512_sub_epi64(_mm512_setzero_si512(), _mm512_add_epi64(c0123, c456));
    *Cp = C;
#define KN(k, v) _mm512_mullo_epi64(_mm512_permutexvar_epi64(C, CT[k]), v)
    __m512i a = _mm512_add_epi64(_mm512_add_epi64(_mm512_add_epi64(KN(0, n->N), KN(1, n->NW)),
                                                  _mm512_add_epi64(KN(2, n->NE), KN(3, n->WW))),
                                 _mm512_add_epi64(_mm512_add_epi64(KN(4, n->NN), KN(5, n->NW2)),
                                                  _mm512_add_epi64(KN(6, n->NNW), KN(7, n->NNE))));
    a = _mm512_add_epi64(a, _mm512_add_epi64(_mm512_add_epi64(KN(8, n->NE2), KN(9, n->NNW2)),
                                             _mm512_sub_epi64(KN(10, n->NNE2), KN(11, n->W))));
#undef KN
    return _mm512_add_epi64(_mm512_add_epi64(n->W, _mm512_srai_epi64(a, 12)), _mm512_permutexvar_epi64(C, CT[12]));
}

typedef struct {
    __m512i T[7], CT[13], tab0, escsym, amaxv, alpha, pmask, one, m16, halfv, three;
    i64 cshift, pshift;
    const void *lut; int lut16;
    const uint32_t *fcum; const uint16_t *words; const int32_t *esc;
} vmodel_t;

/* one step of 8 lanes: neighbours and dither given; updates X, POS, EPOS; returns the buffer values */
INLINE SIMD_FN __m512i vstep(const vmodel_t *m, const vnbr_t *n, __m512i UV, __m512i *Xp, __m512i *POSp,
                             __m512i *EPOSp)
{
    const __m512i one = m->one, m16 = m->m16;
    __m512i C;
    __m512i mh = _mm512_add_epi64(vpredict(m->T, m->CT, n, &C), _mm512_add_epi64(UV, m->halfv));
    __m512i sh = _mm512_srai_epi64(mh, 16);
    __m512i fr = _mm512_and_si512(mh, m16);
    __m512i f = _mm512_sub_epi64(one, _mm512_srli_epi64(fr, 15));
    __m512i nf = _mm512_sub_epi64(_mm512_setzero_si512(), f);
    __m512i fold = _mm512_xor_si512(fr, _mm512_and_si512(nf, m16));
    __m512i ph = _mm512_srl_epi64(_mm512_and_si512(_mm512_srli_epi64(fold, 13), m->three),
                                  _mm_cvtsi64_si128(m->pshift));
    __m512i t = _mm512_add_epi64(_mm512_add_epi64(m->tab0, _mm512_sll_epi64(C, _mm_cvtsi64_si128(m->cshift))), ph);
    __m512i X = *Xp;
    __m512i slot = _mm512_and_si512(X, m->pmask);
    __m512i li = _mm512_add_epi64(_mm512_slli_epi64(t, PROB_BITS), slot);
    __m512i s;
    if (m->lut16)
        s = _mm512_srai_epi64(_mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_i64gather_epi32(li, m->lut, 2)), 48), 48);
    else
        s = _mm512_and_si512(_mm512_cvtepu32_epi64(_mm512_i64gather_epi32(li, m->lut, 1)), _mm512_set1_epi64(0xFF));
    __m512i fi = _mm512_add_epi64(_mm512_mul_epu32(t, m->alpha), s);
    __m512i fc = _mm512_cvtepu32_epi64(_mm512_i64gather_epi32(fi, m->fcum, 4));
    X = _mm512_add_epi64(_mm512_mul_epu32(_mm512_srli_epi64(fc, 16), _mm512_srli_epi64(X, PROB_BITS)),
                         _mm512_sub_epi64(slot, _mm512_and_si512(fc, m16)));
    __mmask8 need = _mm512_cmplt_epu64_mask(X, _mm512_set1_epi64(RANS_L));
    __m512i wd = _mm512_and_si512(_mm512_cvtepu32_epi64(_mm512_i64gather_epi32(*POSp, m->words, 2)), m16);
    *Xp = _mm512_mask_mov_epi64(X, need, _mm512_or_si512(_mm512_slli_epi64(X, 16), wd));
    *POSp = _mm512_mask_sub_epi64(*POSp, need, *POSp, one);
    __mmask8 isesc = _mm512_cmpeq_epi64_mask(s, m->escsym);
    __m512i r = _mm512_sub_epi64(s, m->amaxv);
    if (isesc) {   /* escapes are rare: their gather only in the steps that have one */
        __m512i ev = _mm512_cvtepi32_epi64(_mm512_i64gather_epi32(*EPOSp, m->esc, 4));
        r = _mm512_mask_mov_epi64(r, isesc, ev);
        *EPOSp = _mm512_mask_add_epi64(*EPOSp, isesc, *EPOSp, one);
    }
    __m512i v = _mm512_add_epi64(sh, _mm512_add_epi64(_mm512_xor_si512(r, nf), f));
    return _mm512_sub_epi64(_mm512_slli_epi64(v, 16), UV);
}

SIMD_FN static void vmodel_init(vmodel_t *vm, const model_t *m)
{
    for (int k = 0; k < 7; k++) vm->T[k] = _mm512_set1_epi64(m->thr[k]);
    for (int k = 0; k < 13; k++) {
        i64 tmp[8] = {0};
        for (int c = 0; c < 8; c++) tmp[c] = m->coef[c * 13 + k];   /* caller pads coef to 8 contexts */
        vm->CT[k] = _mm512_loadu_si512(tmp);
    }
    vm->tab0 = _mm512_set1_epi64(m->tab0);
    vm->escsym = _mm512_set1_epi64(2 * m->amax + 1);
    vm->amaxv = _mm512_set1_epi64(m->amax);
    vm->alpha = _mm512_set1_epi64(m->alpha);
    vm->pmask = _mm512_set1_epi64((1 << PROB_BITS) - 1);
    vm->one = _mm512_set1_epi64(1);
    vm->m16 = _mm512_set1_epi64(0xFFFF);
    vm->halfv = _mm512_set1_epi64(1 << 15);
    vm->three = _mm512_set1_epi64(3);
    vm->pshift = m->pshift;
    vm->cshift = 2 - m->pshift;   /* c * (4 >> pshift), pshift 0 or 2 */
    vm->lut = m->lut; vm->lut16 = m->lut16; vm->fcum = m->fcum; vm->words = m->words; vm->esc = m->esc;
}

/* steady part of a group of NV x 8 rows: column steps s = xs0 .. x_last, lane j at x = s - 3 j of row y0 + j; every
 * lane in its row (xs0 >= 3 (8 NV - 1) + 1, x_last <= w - 2) and the pixels before it decoded */
INLINE SIMD_FN int steady(const int NV, i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
              const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{
    const i64 ws = w + 4;
    const i64 b0 = (y0 + 2) * ws + 2;
    const __m512i lane = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
    const __m512i vidx = _mm512_mullo_epi64(lane, _mm512_set1_epi64(ws - 3));   /* buffer offset of lane j */
    const __m512i uidx = _mm512_mullo_epi64(lane, _mm512_set1_epi64(w - 3));    /* dither offset of lane j */
    vmodel_t vm;
    vmodel_init(&vm, m);
    __m512i X[2], POS[2], EPOS[2], H[2][9], G[9];
    for (int v = 0; v < NV; v++) {
        X[v] = _mm512_loadu_si512(xs + 8 * v);
        POS[v] = _mm512_loadu_si512(pos + 8 * v);
        EPOS[v] = _mm512_loadu_si512(epos + 8 * v);
        const i64 *base = pf + b0 + 8 * v * (ws - 3) + xs0;
        for (int k = 1; k <= 8; k++) H[v][k] = _mm512_i64gather_epi64(vidx, base - k, 8);
    }
    const i64 *R0 = pf + y0 * ws + 2;         /* two rows above lane 0 (image row y0 - 2) */
    const i64 *R1 = pf + (y0 + 1) * ws + 2;   /* row above lane 0 (image row y0 - 1) */
    /* G[k]: lane 6 = R0[x + 6 - k], lane 7 = R1[x + 3 - k] (the rows above lane 0 as two more lanes' histories) */
#define GV(x) _mm512_mask_mov_epi64(_mm512_set1_epi64(R0[(x) + 6]), 0x80, _mm512_set1_epi64(R1[(x) + 3]))
    for (int k = 1; k <= 8; k++) G[k] = GV(xs0 - k);
    for (i64 x0 = xs0; x0 <= x_last; x0++) {
        __m512i pv[2];
        for (int v = 0; v < NV; v++) {
            const __m512i *A = v ? H[v - 1] : G;    /* the history of the lanes above this vector's lane 0 */
            const __m512i *B = H[v];
            vnbr_t n = {
                .W = B[1], .WW = B[2],
                .N = _mm512_alignr_epi64(B[3], A[3], 7), .NW = _mm512_alignr_epi64(B[4], A[4], 7),
                .NE = _mm512_alignr_epi64(B[2], A[2], 7), .NE2 = _mm512_alignr_epi64(B[1], A[1], 7),
                .NW2 = _mm512_alignr_epi64(B[5], A[5], 7),
                .NN = _mm512_alignr_epi64(B[6], A[6], 6), .NNW = _mm512_alignr_epi64(B[7], A[7], 6),
                .NNE = _mm512_alignr_epi64(B[5], A[5], 6), .NNW2 = _mm512_alignr_epi64(B[8], A[8], 6),
                .NNE2 = _mm512_alignr_epi64(B[4], A[4], 6)};
            __m512i UV = _mm512_cvtepi32_epi64(_mm512_i64gather_epi32(uidx, u + (y0 + 8 * v) * w + x0 - 24 * v, 4));
            pv[v] = vstep(&vm, &n, UV, &X[v], &POS[v], &EPOS[v]);
        }
        for (int v = 0; v < NV; v++) {
            _mm512_i64scatter_epi64(pf + b0 + 8 * v * (ws - 3) + x0, vidx, pv[v], 8);
            for (int k = 8; k > 1; k--) H[v][k] = H[v][k - 1];
            H[v][1] = pv[v];
        }
        for (int k = 8; k > 1; k--) G[k] = G[k - 1];
        G[1] = GV(x0 + 1 - 1);
    }
#undef GV
    for (int v = 0; v < NV; v++) {
        i64 q[8], e[8];
        _mm512_storeu_si512(q, POS[v]);
        _mm512_storeu_si512(e, EPOS[v]);
        for (int j = 0; j < 8; j++)
            if (q[j] < pmin[8 * v + j] || e[j] > eend[8 * v + j]) return 0;
    }
    for (int v = 0; v < NV; v++) {
        _mm512_storeu_si512(xs + 8 * v, X[v]);
        _mm512_storeu_si512(pos + 8 * v, POS[v]);
        _mm512_storeu_si512(epos + 8 * v, EPOS[v]);
    }
    return 1;
}

SIMD_FN static int steady8(i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
                           const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{ return steady(1, pf, y0, w, u, m, xs, pos, pmin, epos, eend, xs0, x_last); }
SIMD_FN static int steady16(i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
                            const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{ return steady(2, pf, y0, w, u, m, xs, pos, pmin, epos, eend, xs0, x_last); }



/* The encoder's residual pass (metraw.codec.predictive._residuals) for one plane, 8 pixels of a row per vector: every
 * neighbour is known to the encoder, so rows run without a sequential dependence. pf: the padded buffer (h + 2) x
 * (w + 4); thr: nthr activity thresholds (nthr <= 7); coef13: per context the 11 coefficients, their sum, the bias
 * (8 contexts, unused ones zero); residuals and table indices (int32) to r_out / t_out at [off, off + h w).
 * Returns max |r|. */
SIMD_FN static i64 residuals_avx512(const i64 *pf, i64 h, i64 w, const i64 *thr, i64 nthr, const i64 *coef13, i64 tab0,
                                    i64 pshift, int32_t *r_out, int32_t *t_out)
{
    const i64 ws = w + 4;
    __m512i T[7], CT[13];
    for (int k = 0; k < 7; k++) T[k] = _mm512_set1_epi64(k < nthr ? thr[k] : INT64_MAX);
    for (int k = 0; k < 13; k++) {
        i64 tmp[8];
        for (int c = 0; c < 8; c++) tmp[c] = coef13[c * 13 + k];
        CT[k] = _mm512_loadu_si512(tmp);
    }
    const __m512i one = _mm512_set1_epi64(1), m16 = _mm512_set1_epi64(0xFFFF), half = _mm512_set1_epi64(1 << 15);
    const __m512i tab0v = _mm512_set1_epi64(tab0), three = _mm512_set1_epi64(3), r32767 = _mm512_set1_epi64(32767);
    const __m128i psh = _mm_cvtsi64_si128(pshift), csh = _mm_cvtsi64_si128(2 - pshift);
    __m512i rmax = _mm512_setzero_si512();
    for (i64 y = 0; y < h; y++) {
        const i64 *row = pf + (y + 2) * ws + 2;
        for (i64 x = 0; x < w; x += 8) {
            const __mmask8 mk = w - x >= 8 ? 0xFF : (__mmask8)((1u << (w - x)) - 1);
            const i64 *b = row + x;
#define LD(o) _mm512_maskz_loadu_epi64(mk, b + (o))
            vnbr_t n = {.W = LD(-1), .WW = LD(-2), .N = LD(-ws), .NW = LD(-ws - 1), .NE = LD(-ws + 1),
                        .NE2 = LD(-ws + 2), .NW2 = LD(-ws - 2), .NN = LD(-2 * ws), .NNW = LD(-2 * ws - 1),
                        .NNE = LD(-2 * ws + 1), .NNW2 = LD(-2 * ws - 2), .NNE2 = LD(-2 * ws + 2)};
            __m512i P = LD(0);
#undef LD
            __m512i C;
            __m512i acc = vpredict(T, CT, &n, &C);
            __m512i sv = _mm512_srai_epi64(_mm512_add_epi64(P, r32767), 16);
            __m512i mh = _mm512_add_epi64(_mm512_add_epi64(acc, _mm512_sub_epi64(_mm512_slli_epi64(sv, 16), P)), half);
            __m512i r = _mm512_sub_epi64(sv, _mm512_srai_epi64(mh, 16));
            __m512i fr = _mm512_and_si512(mh, m16);
            __m512i f = _mm512_sub_epi64(one, _mm512_srli_epi64(fr, 15));
            __m512i nf = _mm512_sub_epi64(_mm512_setzero_si512(), f);
            fr = _mm512_xor_si512(fr, _mm512_and_si512(nf, m16));
            r = _mm512_add_epi64(_mm512_xor_si512(r, nf), f);
            __m512i t = _mm512_add_epi64(_mm512_add_epi64(tab0v, _mm512_sll_epi64(C, csh)),
                                         _mm512_srl_epi64(_mm512_and_si512(_mm512_srli_epi64(fr, 13), three), psh));
            _mm512_mask_cvtepi64_storeu_epi32(r_out + y * w + x, mk, r);
            _mm512_mask_cvtepi64_storeu_epi32(t_out + y * w + x, mk, t);
            rmax = _mm512_mask_max_epi64(rmax, mk, rmax, _mm512_abs_epi64(r));
        }
    }
    return _mm512_reduce_max_epi64(rmax);
}


/* The encoder's rANS pass (rans_encode_with in _simd_driver.c), AVX-512 part: symbols k = lo - 1 .. 0 of lanes g ..
 * g + 8 NV - 1 (every lane has them), the lanes side by side. Each symbol's table entry tab alpha + idx from two
 * gathers (< 2^31: the tables' size), not from an array of the entries made first (the rANS pass 0.68-0.73x,
 * 2026-11-29, Xeon); fc: each entry's freq | cum << 32; x / freq by the reciprocal 1 / freq, computed here (an IEEE
 * division: the table's value) */
INLINE SIMD_FN void rans_lanes(const int NV, const int32_t *idx, const int32_t *tab, i64 alpha, const u64 *fc,
                               const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs, i64 *nws, i64 *ci,
                               i64 *ce, i64 *cq, const i64 *o)
{
    __m512i X[2], NW[2], I[2], E[2], Q[2], O[2];
    for (int v = 0; v < NV; v++) {
        X[v] = _mm512_loadu_si512(xs + 8 * v); NW[v] = _mm512_loadu_si512(nws + 8 * v);
        I[v] = _mm512_loadu_si512(ci + 8 * v); E[v] = _mm512_loadu_si512(ce + 8 * v);
        Q[v] = _mm512_loadu_si512(cq + 8 * v); O[v] = _mm512_loadu_si512(o + 8 * v);
    }
    const __m512i one = _mm512_set1_epi64(1), m16 = _mm512_set1_epi64(0xFFFF), m32 = _mm512_set1_epi64(0xFFFFFFFF);
    const __m512i A = _mm512_set1_epi64(alpha);
    const __m512d eps = _mm512_set1_pd(1.52587890625e-05), oned = _mm512_set1_pd(1.0);
    for (i64 k = lo - 1; k >= 0; k--) {
        for (int v = 0; v < NV; v++) {
            const __m512i T = _mm512_cvtepi32_epi64(_mm512_i64gather_epi32(I[v], tab, 4));
            const __m512i J = _mm512_add_epi64(_mm512_mul_epu32(T, A),
                                               _mm512_cvtepi32_epi64(_mm512_i64gather_epi32(I[v], idx, 4)));
            const __m512i FC = _mm512_i64gather_epi64(J, (const long long *)fc, 8);
            const __m512i F = _mm512_and_si512(FC, m32), C = _mm512_srli_epi64(FC, 32);
            const __m512d R = _mm512_div_pd(oned, _mm512_cvtepu64_pd(F));
            __mmask8 emit = _mm512_cmpge_epu64_mask(X[v], _mm512_slli_epi64(F, 32 - PROB_BITS));
            /* as the scalar coder, every lane writes its low word at its next slot whether it emits or not (no
             * branch); a 32-bit scatter also writes the slot after it, which the lane has not reached: after k of its n
             * symbols a lane holds <= 12 k / 16 + 2 words (<= 12 bits a symbol, 16 a word), so the slot after next is
             * inside its own region for n >= 16, and the caller's array has one word past the last lane's */
            _mm512_i64scatter_epi32(out, _mm512_add_epi64(O[v], NW[v]),
                                    _mm512_cvtepi64_epi32(_mm512_and_si512(X[v], m16)), 2);
            NW[v] = _mm512_mask_add_epi64(NW[v], emit, NW[v], one);
            const __m512i Xs = _mm512_mask_srli_epi64(X[v], emit, X[v], 16);
            /* the rounding mode as a constant expression: clang takes no variable there, not even a const one */
#define RN (_MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC)
            __m512d prod = _mm512_mul_round_pd(_mm512_cvtepu64_pd(Xs), R, RN);
            __m512i q = _mm512_cvttpd_epu64(_mm512_add_round_pd(prod, eps, RN));
#undef RN
            __m512i rem = _mm512_sub_epi64(Xs, _mm512_mul_epu32(q, F));
            X[v] = _mm512_add_epi64(_mm512_add_epi64(_mm512_slli_epi64(q, PROB_BITS), rem), C);
            if (k > 0) {
                __mmask8 inrow = _mm512_cmpgt_epi64_mask(I[v], E[v]);
                __mmask8 next = (__mmask8)~inrow;
                I[v] = _mm512_mask_sub_epi64(I[v], inrow, I[v], one);
                if (next) {
                    __m512i r = _mm512_sub_epi64(Q[v], one);
                    __m512i st = _mm512_mask_i64gather_epi64(E[v], next, r, rs, 8);
                    __m512i ln = _mm512_mask_i64gather_epi64(one, next, r, rl, 8);
                    I[v] = _mm512_mask_mov_epi64(I[v], next, _mm512_sub_epi64(_mm512_add_epi64(st, ln), one));
                    E[v] = _mm512_mask_mov_epi64(E[v], next, st);
                    Q[v] = _mm512_mask_mov_epi64(Q[v], next, r);
                }
            }
        }
    }
    for (int v = 0; v < NV; v++) {
        _mm512_storeu_si512(xs + 8 * v, X[v]);
        _mm512_storeu_si512(nws + 8 * v, NW[v]);
    }
}

#define RANS_LANES_FN(NAME, NV)                                                                                        \
    SIMD_FN static void NAME(const int32_t *idx, const int32_t *tab, i64 alpha, const int32_t *ent, const u64 *fc,   \
                             const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs, i64 *nws, i64 *ci,        \
                             i64 *ce, i64 *cq, const i64 *o)                                                           \
    { (void)ent; rans_lanes(NV, idx, tab, alpha, fc, rs, rl, out, lo, xs, nws, ci, ce, cq, o); }
RANS_LANES_FN(rans_lanes8, 1)
RANS_LANES_FN(rans_lanes16, 2)
#undef RANS_LANES_FN

/* The encoder's causal buffer (metraw.codec.predictive._front): p (h + 2) x (w + 4) of s 2^16 - floor(u 2^16), the
 * two rows above at c0s (= c0 2^16), the two columns left of row y at row y - 1's first value (c0s for row 0), the
 * two right at row y's last. s int32 and u float64 (h x w) C-contiguous; u 2^16 and its floor are exact. */
SIMD_FN static void front_avx512(const int32_t *s, const double *u, i64 h, i64 w, i64 c0s, i64 *p)
{
    const i64 ws = w + 4;
    const __m512d scale = _mm512_set1_pd(65536.0);
    for (i64 k = 0; k < 2 * ws; k++) p[k] = c0s;
    for (i64 y = 0; y < h; y++) {
        i64 *row = p + (y + 2) * ws;
        const int32_t *sy = s + y * w;
        const double *uy = u + y * w;
        for (i64 x = 0; x < w; x += 8) {
            const __mmask8 mk = w - x >= 8 ? 0xFF : (__mmask8)((1u << (w - x)) - 1);
            __m512i sv = _mm512_cvtepi32_epi64(_mm512_castsi512_si256(_mm512_maskz_loadu_epi32((__mmask16)mk, sy + x)));
            __m512d fu = _mm512_roundscale_pd(_mm512_mul_pd(_mm512_maskz_loadu_pd(mk, uy + x), scale),
                                              _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
            __m512i v = _mm512_sub_epi64(_mm512_slli_epi64(sv, 16), _mm512_cvtpd_epi64(fu));
            _mm512_mask_storeu_epi64(row + 2 + x, mk, v);
        }
        row[0] = row[1] = y > 0 ? p[(y + 1) * ws + 2] : c0s;
        row[w + 2] = row[w + 3] = row[w + 1];
    }
}

/* The encoder's alphabet indices (metraw.codec.predictive._index): idx = r + amax, or the escape 2 amax + 1 where
 * |r| > amax (16 a vector), then the per-table counts (ntab x (2 amax + 2), zeroed by the caller) in a scalar pass. */
SIMD_FN static void index_avx512(const int32_t *r, const int32_t *t, i64 n, i64 amax, i64 nt, int32_t *idx,
                                 i64 *counts)
{
    const i64 alpha = 2 * amax + 2;
    const __m512i A = _mm512_set1_epi32((int)amax), NA = _mm512_set1_epi32((int)-amax);
    const __m512i E = _mm512_set1_epi32((int)(alpha - 1));
    for (i64 i = 0; i < n; i += 16) {
        const __mmask16 mk = n - i >= 16 ? 0xFFFF : (__mmask16)((1u << (n - i)) - 1);
        __m512i v = _mm512_maskz_loadu_epi32(mk, r + i);
        __mmask16 out = _mm512_cmpgt_epi32_mask(v, A) | _mm512_cmplt_epi32_mask(v, NA);
        _mm512_mask_storeu_epi32(idx + i, mk, _mm512_mask_mov_epi32(_mm512_add_epi32(v, A), out, E));
    }
    index_counts(t, idx, n, alpha, nt, counts);
}

/* the AVX-512 path's functions (metraw.codec.native binds them where metraw_simd_paths() has PATH_AVX512) */
int metraw_decode_plane_avx512(i64 *p, i64 h, i64 w, const int32_t *u, int32_t *sym, const i64 *thr7,
                               const i64 *coef8x13, i64 tab0, i64 pshift, const void *lut, int lut16,
                               const uint32_t *fcum, i64 alpha, i64 amax, const uint16_t *words, u64 *xs, i64 *pos,
                               const i64 *pmin, const int32_t *esc, i64 *epos, const i64 *eend, i64 nl,
                               int two_vectors)
{
    return decode_plane_with(steady8, steady16, p, h, w, u, sym, thr7, coef8x13, tab0, pshift, lut, lut16, fcum,
                             alpha, amax, words, xs, pos, pmin, esc, epos, eend, nl, two_vectors, NULL);
}

/* _simd_prepare.c's kernels of this path */
void metraw_dither_fixed_avx512(u64 k1, u64 k2, i64 start, i64 rows, i64 cols, i64 row_step, i64 col_step,
                                int32_t *out);
void metraw_inverse_dn_avx512(const int32_t *sym, i64 rows, i64 cols, u64 k1, u64 k2, i64 start, i64 row_step,
                              i64 col_step, double half_step, double k, double offset, uint16_t *out,
                              i64 out_row_stride, i64 out_col_stride);

DECODE_PLANE_DN(metraw_decode_plane_dn_avx512, metraw_dither_fixed_avx512, metraw_inverse_dn_avx512)

i64 metraw_residuals_avx512(const i64 *pf, i64 h, i64 w, const i64 *thr, i64 nthr, const i64 *coef13, i64 tab0,
                            i64 pshift, int32_t *r_out, int32_t *t_out)
{ return residuals_avx512(pf, h, w, thr, nthr, coef13, tab0, pshift, r_out, t_out); }

void metraw_rans_encode_avx512(const int32_t *idx, const int32_t *tab, i64 n, i64 ntab, i64 alpha, const i64 *freq,
                               const i64 *cum, const double *rcp, const i64 *rs, const i64 *rl, const i64 *lr,
                               const i64 *ls, i64 nl, uint16_t *out, u64 *xs, i64 *nws)
{
    rans_encode_with(rans_lanes8, rans_lanes16, 0, idx, tab, n, ntab, alpha, freq, cum, rcp, rs, rl, lr, ls, nl, out,
                     xs, nws);
}

void metraw_front_avx512(const int32_t *s, const double *u, i64 h, i64 w, i64 c0s, i64 *p)
{ front_avx512(s, u, h, w, c0s, p); }

void metraw_index_avx512(const int32_t *r, const int32_t *t, i64 n, i64 amax, i64 ntab, int32_t *idx, i64 *counts)
{ index_avx512(r, t, n, amax, ntab, idx, counts); }
#endif
