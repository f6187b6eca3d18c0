/* metraw.codec._simd, vector-extension kernels (included by _simd_vec.h): the decoder's steady part and the encoder's
 * rANS lanes, as steady and rans_lanes of _simd.c (see there: lane j of a group in element j, histories shifted
 * across lanes), with 8-lane vectors of whatever width the target has. */

typedef struct {
    vi T[7];
    i64 ct[13 * 8];
    i64 tab0, alpha, amax, pshift, cshift;
    const void *lut; int lut16;
    const uint32_t *fcum; const uint16_t *words; const int32_t *esc;
} vmodel_t;

/* one step of 8 lanes (vstep of _simd.c); reads are kept inside the arrays in corrupt streams (positions clamped:
 * such a lane is rejected at the end of the steady part all the same) */
INLINE vi vstep(const vmodel_t *m, const vnbr_t *n, vi UV, vi *Xp, vi *POSp, vi *EPOSp, vi EEND)
{
    vi C;
    const vi mh = vpredict(m->T, m->ct, n, &C) + (UV + (1 << 15));
    const vi sh = vsra(mh, 16);
    const vi fr = mh & 0xFFFF;
    const vi f = 1 - (vi)((vu)fr >> 15);
    const vi nf = -f;
    const vi fold = fr ^ (nf & 0xFFFF);
    const vi t = m->tab0 + (C << m->cshift) + (vi)((((vu)fold >> 13) & 3) >> m->pshift);
    vi X = *Xp;
    const vi slot = X & ((1 << PROB_BITS) - 1);
    const vi li = (t << PROB_BITS) + slot;
    vi s;
    if (m->lut16)
        for (int j = 0; j < 8; j++) s[j] = ((const int16_t *)m->lut)[li[j]];
    else
        for (int j = 0; j < 8; j++) s[j] = ((const uint8_t *)m->lut)[li[j]];
    const vi fi = vmulu32(t, vset(m->alpha)) + s;
    vi fc;
    for (int j = 0; j < 8; j++) fc[j] = m->fcum[fi[j]];
    X = vmulu32((vi)((vu)fc >> 16), (vi)((vu)X >> PROB_BITS)) + (slot - (fc & 0xFFFF));
    const vi need = (vi)((vu)X < (vu){0} + RANS_L);
    const vi pos = *POSp & ~(*POSp < 0);   /* >= 0 */
    vi wd;
    for (int j = 0; j < 8; j++) wd[j] = m->words[pos[j]];
    *Xp = vsel(need, (X << 16) | wd, X);
    *POSp += need;
    const vi isesc = s == 2 * m->amax + 1;
    const vi ep = vsel(*EPOSp > EEND, EEND, *EPOSp);
    vi ev;
    for (int j = 0; j < 8; j++) ev[j] = m->esc[ep[j]];
    const vi r = vsel(isesc, ev, s - m->amax);
    *EPOSp -= isesc;
    const vi v = sh + ((r ^ nf) + f);
    return (v << 16) - UV;
}

INLINE int steady(const int NV, i64 *pf, i64 y0, i64 w, const int32_t *u, const model_t *m, u64 *xs, i64 *pos,
                  const i64 *pmin, i64 *epos, const i64 *eend, i64 xs0, i64 x_last)
{
    const i64 ws = w + 4;
    const i64 b0 = (y0 + 2) * ws + 2;
    vmodel_t vm;
    model_tables(m->thr, 7, m->coef, vm.T, vm.ct);
    vm.tab0 = m->tab0; vm.alpha = m->alpha; vm.amax = m->amax; vm.pshift = m->pshift; vm.cshift = 2 - m->pshift;
    vm.lut = m->lut; vm.lut16 = m->lut16; vm.fcum = m->fcum; vm.words = m->words; vm.esc = m->esc;
    vi X[2], POS[2], EPOS[2], EEND[2], H[2][9], G[9];
    for (int v = 0; v < NV; v++) {
        memcpy(&X[v], xs + 8 * v, sizeof(vi));
        memcpy(&POS[v], pos + 8 * v, sizeof(vi));
        memcpy(&EPOS[v], epos + 8 * v, sizeof(vi));
        memcpy(&EEND[v], eend + 8 * v, sizeof(vi));
        const i64 *base = pf + b0 + 8 * v * (ws - 3) + xs0;
        for (int k = 1; k <= 8; k++)
            for (int j = 0; j < 8; j++) H[v][k][j] = base[j * (ws - 3) - k];
    }
    const i64 *R0 = pf + y0 * ws + 2;         /* two rows above lane 0 (image row y0 - 2) */
    const i64 *R1 = pf + (y0 + 1) * ws + 2;   /* row above lane 0 (image row y0 - 1) */
    /* G[k]: lane 6 = R0[x + 6 - k], lane 7 = R1[x + 3 - k] (the rows above lane 0 as two more lanes' histories) */
#define GV(x) ((vi){0, 0, 0, 0, 0, 0, R0[(x) + 6], R1[(x) + 3]})
    for (int k = 1; k <= 8; k++) G[k] = GV(xs0 - k);
    for (i64 x0 = xs0; x0 <= x_last; x0++) {
        vi pv[2];
        for (int v = 0; v < NV; v++) {
            const vi *A = v ? H[v - 1] : G;    /* the history of the lanes above this vector's lane 0 */
            const vi *B = H[v];
            const vnbr_t n = {
                .W = B[1], .WW = B[2], .N = UP1(B[3], A[3]), .NW = UP1(B[4], A[4]), .NE = UP1(B[2], A[2]),
                .NE2 = UP1(B[1], A[1]), .NW2 = UP1(B[5], A[5]), .NN = UP2(B[6], A[6]), .NNW = UP2(B[7], A[7]),
                .NNE = UP2(B[5], A[5]), .NNW2 = UP2(B[8], A[8]), .NNE2 = UP2(B[4], A[4])};
            const int32_t *ub = u + (y0 + 8 * v) * w + x0 - 24 * v;
            vi UV;
            for (int j = 0; j < 8; j++) UV[j] = ub[j * (w - 3)];
            pv[v] = vstep(&vm, &n, UV, &X[v], &POS[v], &EPOS[v], EEND[v]);
        }
        for (int v = 0; v < NV; v++) {
            i64 *o = pf + b0 + 8 * v * (ws - 3) + x0;
            for (int j = 0; j < 8; j++) o[j * (ws - 3)] = pv[v][j];
            for (int k = 8; k > 1; k--) H[v][k] = H[v][k - 1];
            H[v][1] = pv[v];
        }
        for (int k = 8; k > 1; k--) G[k] = G[k - 1];
        G[1] = GV(x0);
    }
#undef GV
    for (int v = 0; v < NV; v++)
        for (int j = 0; j < 8; j++)
            if (POS[v][j] < pmin[8 * v + j] || EPOS[v][j] > eend[8 * v + j]) return 0;
    for (int v = 0; v < NV; v++) {
        memcpy(xs + 8 * v, &X[v], sizeof(vi));
        memcpy(pos + 8 * v, &POS[v], sizeof(vi));
        memcpy(epos + 8 * v, &EPOS[v], sizeof(vi));
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
                             alpha, amax, words, xs, pos, pmin, esc, epos, eend, nl, two_vectors);
}

/* u64 < 2^52 to double, exactly; trunc of 0 <= v < 2^52 as u64 */
INLINE vd vu2d(vu a) { return (vd)(a | 0x4330000000000000ULL) - 0x1p52; }
INLINE vu vtrunc(vd v)
{
    const vd t = v + 0x1p52;
    return (vu)((vi)((vu)t - 0x4330000000000000ULL) + (vi)(t - 0x1p52 > v));
}

/* rans_lanes of _simd.c: symbols k = lo - 1 .. 0 of 8 NV lanes side by side */
INLINE void rans_lanes(const int NV, const int32_t *ent, const u64 *fc, const i64 *rs, const i64 *rl, uint16_t *out,
                       i64 lo, u64 *xs, i64 *nws, i64 *ci, i64 *ce, i64 *cq, const i64 *o)
{
    vu X[2];
    vi NW[2], I[2], E[2], Q[2], O[2];
    for (int v = 0; v < NV; v++) {
        memcpy(&X[v], xs + 8 * v, sizeof(vi)); memcpy(&NW[v], nws + 8 * v, sizeof(vi));
        memcpy(&I[v], ci + 8 * v, sizeof(vi)); memcpy(&E[v], ce + 8 * v, sizeof(vi));
        memcpy(&Q[v], cq + 8 * v, sizeof(vi)); memcpy(&O[v], o + 8 * v, sizeof(vi));
    }
    for (i64 k = lo - 1; k >= 0; k--) {
        for (int v = 0; v < NV; v++) {
            vu FC;
            for (int j = 0; j < 8; j++) FC[j] = fc[ent[I[v][j]]];
            const vu F = FC & 0xFFFFFFFFULL, C = FC >> 32;
            const vd R = 1.0 / vu2d(F);
            const vi emit = (vi)(X[v] >= F << (32 - PROB_BITS));
            /* every lane writes its low word at its next slot whether it emits or not, as the scalar coder */
            for (int j = 0; j < 8; j++) out[O[v][j] + NW[v][j]] = (uint16_t)X[v][j];
            NW[v] -= emit;
            const vu Xs = (vu)vsel(emit, (vi)(X[v] >> 16), (vi)X[v]);
            const vu q = vtrunc(vu2d(Xs) * R + 1.52587890625e-05);
            const vu rem = Xs - (vu)vmulu32((vi)q, (vi)F);
            X[v] = (q << PROB_BITS) + rem + C;
            if (k > 0) {
                const vi inrow = I[v] > E[v];
                I[v] += inrow;
                for (int j = 0; j < 8; j++)
                    if (!inrow[j]) {
                        const i64 r = Q[v][j] - 1;
                        I[v][j] = rs[r] + rl[r] - 1;
                        E[v][j] = rs[r];
                        Q[v][j] = r;
                    }
            }
        }
    }
    for (int v = 0; v < NV; v++) {
        memcpy(xs + 8 * v, &X[v], sizeof(vi));
        memcpy(nws + 8 * v, &NW[v], sizeof(vi));
    }
}

static void rans8(const int32_t *ent, const u64 *fc, const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs,
                  i64 *nws, i64 *ci, i64 *ce, i64 *cq, const i64 *o)
{ rans_lanes(1, ent, fc, rs, rl, out, lo, xs, nws, ci, ce, cq, o); }
static void rans16(const int32_t *ent, const u64 *fc, const i64 *rs, const i64 *rl, uint16_t *out, i64 lo, u64 *xs,
                   i64 *nws, i64 *ci, i64 *ce, i64 *cq, const i64 *o)
{ rans_lanes(2, ent, fc, rs, rl, out, lo, xs, nws, ci, ce, cq, o); }

void VN(metraw_rans_encode)(const int32_t *idx, const int32_t *tab, i64 n, i64 ntab, i64 alpha, const i64 *freq,
                            const i64 *cum, const double *rcp, const i64 *rs, const i64 *rl, const i64 *lr,
                            const i64 *ls, i64 nl, uint16_t *out, u64 *xs, i64 *nws)
{
    rans_encode_with(rans8, rans16, idx, tab, n, ntab, alpha, freq, cum, rcp, rs, rl, lr, ls, nl, out, xs, nws);
}
