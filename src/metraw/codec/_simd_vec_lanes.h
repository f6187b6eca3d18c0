/* metraw.codec._simd, vector-extension kernels (included by _simd_vec.h): the decoder's steady part and the encoder's
 * rANS lanes, as steady and rans_lanes of _simd.c (see there), with lanes of a group VL to a vector (8 or 16 lanes:
 * 8 / VL or 16 / VL vectors). */

typedef struct {
    vtab_t tb;
    i64 tab0, alpha, amax, pshift, cshift;
    const void *lut; int lut16;
    const uint32_t *fcum; const uint16_t *words; const int32_t *esc;
} vmodel_t;

/* whether any lane of a mask (-1 / 0 lanes) is set */
INLINE int vany(vi m)
{
#if defined(VEC_AVX2)
    return _mm256_movemask_pd((__m256d)m) != 0;
#else
    for (int j = 0; j < VL; j++)
        if (m[j]) return 1;
    return 0;
#endif
}

/* one step of VL lanes (vstep of _simd.c); reads are kept inside the arrays in corrupt streams (positions clamped:
 * such a lane is rejected at the end of the steady part all the same) */
INLINE vi vstep(const vmodel_t *m, const vnbr_t *n, vi UV, vi *Xp, vi *POSp, vi *EPOSp, vi EEND, const int n32)
{
    vi C;
    const vi mh = vpredict_(&m->tb, n, &C, n32) + (UV + (1 << 15));
    const vi sh = vsra(mh, 16);
    const vi fr = mh & 0xFFFF;
    const vi f = 1 - (vi)((vu)fr >> 15);
    const vi nf = -f;
    const vi fold = fr ^ (nf & 0xFFFF);
    const vi t = m->tab0 + (C << m->cshift) + (vi)((((vu)fold >> 13) & 3) >> m->pshift);
    vi X = *Xp;
    const vi slot = X & ((1 << PROB_BITS) - 1);
    const vi li = (t << PROB_BITS) + slot;
    const vi s = m->lut16 ? gather_s16((const int16_t *)m->lut, li) : gather_u8((const uint8_t *)m->lut, li);
    const vi fi = vmulu32(t, vset(m->alpha)) + s;
    const vi fc = gather_u32(m->fcum, fi);
    X = vmulu32((vi)((vu)fc >> 16), (vi)((vu)X >> PROB_BITS)) + (slot - (fc & 0xFFFF));
    const vi need = (vi)((vu)X < (vu){0} + RANS_L);
    const vi pos = *POSp & ~(*POSp < 0);   /* >= 0 */
    const vi wd = gather_u16(m->words, pos);
    *Xp = vsel(need, (X << 16) | wd, X);
    *POSp += need;
    const vi isesc = s == 2 * m->amax + 1;
    vi r = s - m->amax;
    if (vany(isesc)) {   /* escapes are rare: their gather only in the steps that have one */
        const vi ep = vsel(*EPOSp > EEND, EEND, *EPOSp);
        r = vsel(isesc, gather_s32(m->esc, ep), r);
        *EPOSp -= isesc;
    }
    const vi v = sh + ((r ^ nf) + f);
    return (v << 16) - UV;
}

/* Ring of the lanes' last values: slot x & 15 holds column step x's, lane l of the group at column VL + l, the rows
 * above lane 0 (the previous group's last two rows) as lanes -2 and -1 at columns VL - 2 and VL - 1. A lane's
 * neighbours k steps back in itself and the one or two lanes above it: two aligned loads (a vector and the one above
 * it), one shuffle (unaligned loads across two recent vector stores would stall store forwarding) */
/* lanes shifted up by one (two) across a pair: [a_{VL-1}, b_0 .. b_{VL-2}] ([a_{VL-2}, a_{VL-1}, b_0 ..]) */
#if VL == 4
#define UP1(b, a) SHUF(a, b, 3, 4, 5, 6)
#define UP2(b, a) SHUF(a, b, 2, 3, 4, 5)
#else
#define UP1(b, a) SHUF(a, b, 1, 2)
#define UP2(b, a) (a)
#endif
#define RING 16

INLINE int steady(const int NV, i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
                  const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{
    const int NL = 8 * NV, NVV = NL / VL;
    const i64 ws = w + 4;
    const i64 b0 = (y0 + 2) * ws + 2;
    vmodel_t vm;
    model_tables(m->thr, 7, m->coef, &vm.tb);
    vm.tab0 = m->tab0; vm.alpha = m->alpha; vm.amax = m->amax; vm.pshift = m->pshift; vm.cshift = 2 - m->pshift;
    vm.lut = m->lut; vm.lut16 = m->lut16; vm.fcum = m->fcum; vm.words = m->words; vm.esc = m->esc;
    vi X[16 / VL], POS[16 / VL], EPOS[16 / VL], EEND[16 / VL];
    i64 ring[RING][VL + 16] __attribute__((aligned(64)));
    memset(ring, 0, sizeof ring);
    for (int v = 0; v < NVV; v++) {
        memcpy(&X[v], xs + VL * v, sizeof(vi));
        memcpy(&POS[v], pos + VL * v, sizeof(vi));
        memcpy(&EPOS[v], epos + VL * v, sizeof(vi));
        memcpy(&EEND[v], eend + VL * v, sizeof(vi));
    }
    const i64 *R0 = pf + y0 * ws + 2;         /* two rows above lane 0 (image row y0 - 2) */
    const i64 *R1 = pf + (y0 + 1) * ws + 2;   /* row above lane 0 (image row y0 - 1) */
    for (int k = 1; k <= 8; k++) {
        i64 *r = ring[(xs0 - k) & (RING - 1)];
        r[VL - 2] = R0[xs0 - k + 6];
        r[VL - 1] = R1[xs0 - k + 3];
        for (int l = 0; l < NL; l++) r[VL + l] = pf[b0 + l * (ws - 3) + xs0 - k];
    }
    const vi uidx = (vi)IOTA * (w - 3);   /* dither offset of lane j of a vector */
    /* one column step; n32: every value in the ring in [-2^30, 2^30) (FITS30: one 32-bit multiply a tap and 32-bit
     * absolute differences, vpredict_); returns whether the values it adds to the ring are (checked only where n32) */
#define STEP(n32) ({ \
        i64 *out = ring[x0 & (RING - 1)]; \
        vu big_ = {0}; \
        for (int v = 0; v < NVV; v++) { \
            const int c = VL + VL * v;   /* this vector's lane 0 */ \
            const vnbr_t n = {.W = RW(1, 0), .WW = RW(2, 0), .N = RW(3, 1), .NW = RW(4, 1), .NE = RW(2, 1), \
                              .NE2 = RW(1, 1), .NW2 = RW(5, 1), .NN = RW(6, 2), .NNW = RW(7, 2), .NNE = RW(5, 2), \
                              .NNW2 = RW(8, 2), .NNE2 = RW(4, 2)}; \
            const vi UV = gather_s32(u + (y0 + VL * v) * w + x0 - 3 * VL * v, uidx); \
            const vi pv = vstep(&vm, &n, UV, &X[v], &POS[v], &EPOS[v], EEND[v], n32); \
            memcpy(&out[c], &pv, sizeof pv); \
            if (n32) big_ |= (vu)pv + 0x40000000ULL; \
        } \
        const i64 r0_ = R0[x0 + 6], r1_ = R1[x0 + 3]; \
        out[VL - 2] = r0_; \
        out[VL - 1] = r1_; \
        for (int l = 0; l < NL; l++) pf[b0 + l * (ws - 3) + x0] = out[VL + l]; \
        u64 b_ = ((u64)r0_ + 0x40000000ULL) | ((u64)r1_ + 0x40000000ULL); \
        for (int j = 0; j < VL; j++) b_ |= big_[j]; \
        b_ >> 31 == 0; })
#define RB(k) LOADV(vi, &ring[(x0 - (k)) & (RING - 1)][c])
#define RA(k) LOADV(vi, &ring[(x0 - (k)) & (RING - 1)][c - VL])
#define RW(k, sh) ((sh) == 0 ? RB(k) : (sh) == 1 ? UP1(RB(k), RA(k)) : UP2(RB(k), RA(k)))
    i64 x0 = xs0;
#if defined(VEC_AVX2)
    /* the 32-bit products while every value in the ring is in [-2^30, 2^30) (the same sums), then the exact 64-bit
     * ones */
    int fits = vm.tb.k32;
    for (int k = 1; k <= 8; k++) {
        const i64 *r = ring[(xs0 - k) & (RING - 1)];
        fits &= FITS30(r[VL - 2]) && FITS30(r[VL - 1]);
        /* lane l's pixel at column xs0 - k - 3 l, a neighbour where >= -2 (else before its row: not read) */
        for (int l = 0; l < NL && xs0 - k - 3 * l >= -2; l++) fits &= FITS30(r[VL + l]);
    }
    for (; fits && x0 <= x_last; x0++) fits = STEP(1);
#endif
    for (; x0 <= x_last; x0++) (void)STEP(0);
#undef RW
#undef RA
#undef RB
#undef STEP
    for (int v = 0; v < NVV; v++)
        for (int j = 0; j < VL; j++)
            if (POS[v][j] < pmin[VL * v + j] || EPOS[v][j] > eend[VL * v + j]) return 0;
    for (int v = 0; v < NVV; v++) {
        memcpy(xs + VL * v, &X[v], sizeof(vi));
        memcpy(pos + VL * v, &POS[v], sizeof(vi));
        memcpy(epos + VL * v, &EPOS[v], sizeof(vi));
    }
    return 1;
}

static int steady8(i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos, const i64 *pmin,
                   i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{ return steady(1, pf, y0, w, u, m, xs, pos, pmin, epos, eend, xs0, x_last); }
static int steady16(i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos, const i64 *pmin,
                    i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{ return steady(2, pf, y0, w, u, m, xs, pos, pmin, epos, eend, xs0, x_last); }

int VN(metraw_decode_plane)(i64 *p, i64 h, i64 w, const int32_t *u, int32_t *sym, const i64 *thr7,
                            const i64 *coef8x13, i64 tab0, i64 pshift, const void *lut, int lut16,
                            const uint32_t *fcum, i64 alpha, i64 amax, const uint16_t *words, u64 *xs, i64 *pos,
                            const i64 *pmin, const int32_t *esc, i64 *epos, const i64 *eend, i64 nl, int two_vectors)
{
    return decode_plane_with(steady8, steady16, p, h, w, u, sym, thr7, coef8x13, tab0, pshift, lut, lut16, fcum,
                             alpha, amax, words, xs, pos, pmin, esc, epos, eend, nl, two_vectors, NULL);
}

DECODE_PLANE_DN(VN(metraw_decode_plane_dn), VN(metraw_dither_fixed), VN(metraw_inverse_dn))

/* whether every lane of a mask (-1 / 0 lanes) is set */
INLINE int vall(vi m)
{
    for (int j = 0; j < VL; j++)
        if (!m[j]) return 0;
    return 1;
}

/* u64 < 2^52 to double, exactly; trunc of 0 <= v < 2^52 as u64 */
INLINE vd vu2d(vu a) { return (vd)(a | 0x4330000000000000ULL) - 0x1p52; }
INLINE vu vtrunc(vd v)
{
    const vd t = v + 0x1p52;
    return (vu)((vi)((vu)t - 0x4330000000000000ULL) + (vi)(t - 0x1p52 > v));
}

/* rans_lanes of _simd.c: symbols k = lo - 1 .. 0 of 8 NV lanes side by side, VL to a vector, in blocks of RANS_BLOCK
 * steps. Each step's slots and low words go to a buffer (vector stores), and after the block to out lane by lane:
 * stores to out at slots that the lanes' states decide, among the loop's loads, made those loads wait for the states
 * (canon_dng 1-thread, forced AVX2 on an AVX-512 Xeon, 17.4 -> 8.4-9.1 ms, 2026-11-28). On AVX2 each block first
 * reads each lane's table entries (freq | cum << 32) in step order, by scalar loads as the lane's cursor walks its
 * rows (no state decides them), and the steps load them in place of two chained gathers (symbol's entry, then the
 * entry's frequencies): the rANS pass 0.82-0.85x the time (2026-11-29, same CPU). The walk reads the entry as
 * tab alpha + idx, not from an array of the entries that the driver would make first: 0.86-0.93x more. The portable
 * build keeps the gathers (element loops there), 1.36x slower with the block's reads first, and the driver's array
 * of the entries (1.33x slower with two gathers in its place). */
#define RANS_BLOCK 32
#if defined(VEC_AVX2)
#define RANS_ENTRIES_FIRST 1
#else
#define RANS_ENTRIES_FIRST 0
#endif
INLINE void rans_lanes(const int NV, const int32_t *idx, const int32_t *tab, i64 alpha, const int32_t *ent,
                       const u64 *fc, const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs, i64 *nws, i64 *ci,
                       i64 *ce, i64 *cq, const i64 *o)
{
    const int NVV = 8 * NV / VL;
    vu X[16 / VL];
    vi NW[16 / VL], O[16 / VL];
    vi bat[RANS_BLOCK][16 / VL];
    vu bx[RANS_BLOCK][16 / VL];
#if RANS_ENTRIES_FIRST
    const int NL = 8 * NV;
    u64 fcb[RANS_BLOCK][16] __attribute__((aligned(32)));
    i64 I[16], E[16], Q[16];
    for (int j = 0; j < NL; j++) { I[j] = ci[j]; E[j] = ce[j]; Q[j] = cq[j]; }
#else
    vi I[16 / VL], E[16 / VL], Q[16 / VL];
    for (int v = 0; v < NVV; v++) {
        memcpy(&I[v], ci + VL * v, sizeof(vi)); memcpy(&E[v], ce + VL * v, sizeof(vi));
        memcpy(&Q[v], cq + VL * v, sizeof(vi));
    }
#endif
    for (int v = 0; v < NVV; v++) {
        memcpy(&X[v], xs + VL * v, sizeof(vi)); memcpy(&NW[v], nws + VL * v, sizeof(vi));
        memcpy(&O[v], o + VL * v, sizeof(vi));
    }
    for (i64 k0 = lo - 1; k0 >= 0; k0 -= RANS_BLOCK) {
        const int nb = k0 + 1 < RANS_BLOCK ? (int)(k0 + 1) : RANS_BLOCK;
#if RANS_ENTRIES_FIRST
        for (int j = 0; j < NL; j++) {   /* enc_cursor's walk, lane by lane (written out: calling enc_cursor of
                                             * _simd_driver.c here measured 4-10 % slower, 2026-11-29) */
            i64 i = I[j], e = E[j], q = Q[j];
            for (int b = 0; b < nb; b++) {
                fcb[b][j] = fc[(uint32_t)tab[i] * (uint32_t)alpha + (uint32_t)idx[i]];
                if (i > e) i -= 1;
                else if (k0 - b > 0) { q -= 1; i = rs[q] + rl[q] - 1; e = rs[q]; }
            }
            I[j] = i; E[j] = e; Q[j] = q;
        }
#endif
        for (int b = 0; b < nb; b++) {
            for (int v = 0; v < NVV; v++) {
#if RANS_ENTRIES_FIRST
                const vu FC = LOADV(vu, &fcb[b][VL * v]);
#else
                const vu FC = (vu)gather_64(fc, gather_s32(ent, I[v]));
#endif
                const vu F = FC & 0xFFFFFFFFULL, C = FC >> 32;
                const vd R = 1.0 / vu2d(F);
                const vi emit = (vi)(X[v] >= F << (32 - PROB_BITS));
                /* every lane writes its low word at its next slot whether it emits or not, as the scalar coder */
                bat[b][v] = O[v] + NW[v];
                bx[b][v] = X[v];
                NW[v] -= emit;
                const vu Xs = (vu)vsel(emit, (vi)(X[v] >> 16), (vi)X[v]);
                const vu q = vtrunc(vu2d(Xs) * R + 1.52587890625e-05);
                const vu rem = Xs - (vu)vmulu32((vi)q, (vi)F);
                X[v] = (q << PROB_BITS) + rem + C;
#if !RANS_ENTRIES_FIRST
                if (k0 - b > 0) {   /* enc_cursor */
                    const vi inrow = I[v] > E[v];
                    I[v] += inrow;
                    if (!vall(inrow))
                        for (int j = 0; j < VL; j++)
                            if (!inrow[j]) {
                                const i64 r = Q[v][j] - 1;
                                I[v][j] = rs[r] + rl[r] - 1;
                                E[v][j] = rs[r];
                                Q[v][j] = r;
                            }
                }
#endif
            }
        }
        for (int b = 0; b < nb; b++)   /* in order: a lane's slot holds its last word */
            for (int v = 0; v < NVV; v++)
                for (int j = 0; j < VL; j++) out[bat[b][v][j]] = (uint16_t)bx[b][v][j];
    }
    for (int v = 0; v < NVV; v++) {
        memcpy(xs + VL * v, &X[v], sizeof(vi));
        memcpy(nws + VL * v, &NW[v], sizeof(vi));
    }
}

#define RANS_LANES_FN(NAME, NV)                                                                                        \
    static void NAME(const int32_t *idx, const int32_t *tab, i64 alpha, const int32_t *ent, const u64 *fc,           \
                     const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs, i64 *nws, i64 *ci, i64 *ce,       \
                     i64 *cq, const i64 *o)                                                                            \
    { rans_lanes(NV, idx, tab, alpha, ent, fc, rs, rl, out, lo, xs, nws, ci, ce, cq, o); }
RANS_LANES_FN(rans8, 1)
RANS_LANES_FN(rans16, 2)
#undef RANS_LANES_FN

void VN(metraw_rans_encode)(const int32_t *idx, const int32_t *tab, i64 n, i64 ntab, i64 alpha, const i64 *freq,
                            const i64 *cum, const double *rcp, const i64 *rs, const i64 *rl, const i64 *lr,
                            const i64 *ls, i64 nl, uint16_t *out, u64 *xs, i64 *nws)
{
    rans_encode_with(rans8, rans16, !RANS_ENTRIES_FIRST, idx, tab, n, ntab, alpha, freq, cum, rcp, rs, rl, lr, ls, nl,
                     out, xs, nws);
}
#undef RANS_ENTRIES_FIRST
#undef RANS_BLOCK
