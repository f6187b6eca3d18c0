/* metraw.codec._simd, the parts every path shares: the decoder's general (scalar) path and its schedule of row groups
 * around a path's steady part, the encoder's rANS pass around a path's lanes, the alphabet counts, the paths this CPU
 * can run (metraw_simd_paths) and the interface version. The arithmetic is the encoder's and numba decoder's to the
 * bit (int64 two's complement; built with -fwrapv). */
#include "_simd.h"

/* one pixel of one lane (the general path: edges, short rows); lut16 a compile-time constant where inlined */
INLINE void pixel(i64 *restrict pf, i64 b, i64 ws, i64 uv, const i64 *restrict t7,
    const i64 *restrict coef, i64 tab0, i64 pshift, const void *restrict lut, const int lut16,
    const uint32_t *restrict fcum, i64 alpha, i64 amax, const uint16_t *restrict words, const int32_t *restrict esc,
    u64 *restrict xp, i64 *restrict posp, i64 *restrict eposp)
{
    const i64 half = 1 << 15;
    i64 w_ = pf[b - 1], ww = pf[b - 2];
    i64 n_ = pf[b - ws], nw = pf[b - ws - 1], ne = pf[b - ws + 1], nn = pf[b - 2 * ws];
    i64 act = iabs64(w_ - nw) + iabs64(n_ - nw) + iabs64(n_ - ne) + iabs64(w_ - ww) + iabs64(n_ - nn);
    i64 c = (act > t7[0]) + (act > t7[1]) + (act > t7[2]) + (act > t7[3]) + (act > t7[4]) + (act > t7[5])
          + (act > t7[6]);
    const i64 *k = coef + c * 13;
    i64 acc = k[0] * n_ + k[1] * nw + k[2] * ne + k[3] * ww + k[4] * nn + k[5] * pf[b - ws - 2]
            + k[6] * pf[b - 2 * ws - 1] + k[7] * pf[b - 2 * ws + 1] + k[8] * pf[b - ws + 2]
            + k[9] * pf[b - 2 * ws - 2] + k[10] * pf[b - 2 * ws + 2]
            - k[11] * w_;
    i64 mh = w_ + (acc >> 12) + k[12] + uv + half;
    i64 sh = mh >> 16, fr = mh & 0xFFFF, f = 1 - (fr >> 15);
    i64 t = tab0 + c * (4 >> pshift) + ((((fr ^ (-f & 0xFFFF)) >> 13) & 3) >> pshift);
    u64 x = *xp;
    i64 slot = (i64)(x & ((1u << PROB_BITS) - 1));
    i64 li = (t << PROB_BITS) + slot;
    i64 s = lut16 ? (i64)((const int16_t *)lut)[li] : (i64)((const uint8_t *)lut)[li];
    i64 fc = (i64)fcum[t * alpha + s];
    x = (u64)(fc >> 16) * (x >> PROB_BITS) + (u64)(slot - (fc & 0xFFFF));
    u64 need = x < RANS_L;
    x = (x << (need << 4)) | ((u64)words[*posp] * need);
    *posp -= (i64)need;
    int is_esc = s == 2 * amax + 1;
    i64 ev = esc[*eposp];
    i64 r = is_esc ? ev : s - amax;
    *eposp += is_esc;
    i64 v = sh + ((r ^ -f) + f);
    pf[b] = (v << 16) - uv;
    *xp = x;
}

/* the general path of a row group's column step xsw (lanes outside the steady part) */
INLINE int general_step(const int lut16, i64 *restrict pf, i64 xsw, i64 y0, i64 nr,
    i64 w, const int32_t *restrict u, const model_t *m, u64 *restrict xs, i64 *restrict pos, const i64 *restrict pmin,
    i64 *restrict epos, const i64 *restrict eend)
{
    const i64 ws = w + 4;
    for (i64 j = 0; j < nr; j++) {
        i64 x0 = xsw - 3 * j;
        if (x0 < 0 || x0 >= w) continue;
        i64 y = y0 + j, yy = y + 2;
        if (x0 == 0 && y > 0) {
            pf[yy * ws] = pf[(yy - 1) * ws + 2];
            pf[yy * ws + 1] = pf[(yy - 1) * ws + 2];
        }
        u64 x = xs[j]; i64 ps = pos[j], ep = epos[j];
        pixel(pf, yy * ws + x0 + 2, ws, (i64)u[y * w + x0], m->thr, m->coef, m->tab0, m->pshift, m->lut, lut16,
              m->fcum, m->alpha, m->amax, m->words, m->esc, &x, &ps, &ep);
        if (!(ps >= pmin[j] && ep <= eend[j])) return 0;
        xs[j] = x; pos[j] = ps; epos[j] = ep;
        if (x0 == w - 1) {
            pf[yy * ws + w + 2] = pf[yy * ws + w + 1];
            pf[yy * ws + w + 3] = pf[yy * ws + w + 1];
        }
    }
    return 1;
}

/* general_step over column steps [from, to) of the lanes of rows y0 .. y0 + nr - 1 (lanes xs .. eend: theirs) */
static int general_steps(i64 *pf, i64 from, i64 to, i64 y0, i64 nr, i64 w, const int32_t *u, const model_t *m,
                         u64 *xs, i64 *pos, const i64 *pmin, i64 *epos, const i64 *eend)
{
    for (i64 xsw = from; xsw < to; xsw++)
        if (!(m->lut16 ? general_step(1, pf, xsw, y0, nr, w, u, m, xs, pos, pmin, epos, eend)
                       : general_step(0, pf, xsw, y0, nr, w, u, m, xs, pos, pmin, epos, eend))) return 0;
    return 1;
}

/* a full 16-lane group with its two vectors side by side (w >= 48): A = lanes 0-7, B = lanes 8-15 (B's column step s
 * is A's s + 24). The ramps of 16 staggered lanes would take the scalar path for 46 column steps at each end; here
 * only 8-lane ramps do: A's start ramp, A alone in its steady part while B starts, both vectors, then B alone while A
 * ends, B's end. Each lane decodes its pixels in order and after the pixels above it (A runs ahead of B), so the
 * values are those of any other schedule. */
static int decode_group16(steady_fn steady8, steady_fn steady16, i64 *pf, i64 y0, i64 w, const int32_t *u,
                          const model_t *m, u64 *xs, i64 *pos, const i64 *pmin, i64 *epos, const i64 *eend)
{
    /* S8, S16: the first steady column step of 8 and 16 staggered lanes; LAG: B's column step behind A's */
    const i64 S8 = 3 * 7 + 1, S16 = 3 * 15 + 1, LAG = 3 * 8, yb = y0 + 8;
    return general_steps(pf, 0, S8, y0, 8, w, u, m, xs, pos, pmin, epos, eend)
        && steady8(pf, y0, w, u, m, xs, pos, pmin, epos, eend, S8, S16 - 1)
        && general_steps(pf, 0, S16 - LAG, yb, 8, w, u, m, xs + 8, pos + 8, pmin + 8, epos + 8, eend + 8)
        && steady16(pf, y0, w, u, m, xs, pos, pmin, epos, eend, S16, w - 2)
        && general_steps(pf, w - 1, w - 1 + S8, y0, 8, w, u, m, xs, pos, pmin, epos, eend)
        && steady8(pf, yb, w, u, m, xs + 8, pos + 8, pmin + 8, epos + 8, eend + 8, w - 1 - LAG, w - 2)
        && general_steps(pf, w - 1, w - 1 + S8, yb, 8, w, u, m, xs + 8, pos + 8, pmin + 8, epos + 8, eend + 8);
}

/* one row group: rows y0 .. y0 + nr - 1 in lanes 0 .. nr - 1 of a group of nl lanes (xs .. eend: those lanes'); the
 * steady parts by the path's kernels (none: every pixel by the general path) */
static int decode_group(steady_fn steady8, steady_fn steady16, i64 *pf, i64 y0, i64 nr, i64 nl, i64 w,
                        const int32_t *u, const model_t *m, u64 *xs, i64 *pos, const i64 *pmin, i64 *epos,
                        const i64 *eend)
{
    const i64 XS0 = 3 * (nl - 1) + 1;
    if (steady8 && steady16 && nl == 16 && nr == 16 && w >= XS0 + 2)
        return decode_group16(steady8, steady16, pf, y0, w, u, m, xs, pos, pmin, epos, eend);
    if (steady8 && nl == 8 && nr == 8 && w >= XS0 + 2)
        return general_steps(pf, 0, XS0, y0, nr, w, u, m, xs, pos, pmin, epos, eend)
            && steady8(pf, y0, w, u, m, xs, pos, pmin, epos, eend, XS0, w - 2)
            && general_steps(pf, w - 1, w + 3 * (nr - 1), y0, nr, w, u, m, xs, pos, pmin, epos, eend);
    return general_steps(pf, 0, w + 3 * (nr - 1), y0, nr, w, u, m, xs, pos, pmin, epos, eend);
}

/* metraw.codec.decoder.decode_plane: p the padded buffer's first rows (w + 4 values each: the two rows above the
 * plane and its first row's left pads as decoder._init_front sets them, then room for one row group: nl + 2 rows at
 * least), u the fixed-point dither (h x w), sym the symbols out (h x w); lut and words readable 4 bytes past their ends
 * (the AVX-512 gathers read 32 bits); groups of 8 or 16 lanes run the path's steady part: 16 lanes as two vectors
 * side by side where two_vectors is 1, else as two groups of 8 rows one after the other (lane j's rows in the same
 * order, so the same values). A group's rows are decoded into rows 2 .. of p (the kernels index it by plane row: a
 * base pointer y0 rows before p), its symbols taken out, its last two rows moved up to rows 0 and 1 as the next
 * group's rows above: p stays in cache, not a buffer of the plane's size. With dn (u and sym then unused), each
 * group's dither is made into dn->u before it and its symbols into dn->sym, then their DN put out: no plane-size
 * array at all. Returns 1, or 0 when a lane ran past its words or escapes (corrupt stream). */
int decode_plane_with(steady_fn steady8, steady_fn steady16, i64 *p, i64 h, i64 w, const int32_t *u, int32_t *sym,
                      const i64 *thr7, const i64 *coef8x13, i64 tab0, i64 pshift, const void *lut, int lut16,
                      const uint32_t *fcum, i64 alpha, i64 amax, const uint16_t *words, u64 *xs, i64 *pos,
                      const i64 *pmin, const int32_t *esc, i64 *epos, const i64 *eend, i64 nl, int two_vectors,
                      const dn_t *dn)
{
    model_t m = {thr7, coef8x13, tab0, pshift, alpha, amax, lut, lut16, fcum, words, esc};
    const i64 ws = w + 4;
    const i64 sub = nl == 16 && !two_vectors ? 8 : nl;
    for (i64 y0 = 0; y0 < h; y0 += nl) {
        const i64 rows = nl < h - y0 ? nl : h - y0;
        /* plane row y at p[(y - y0 + 2) ws]: the kernels' pf[(y + 2) ws], pf = p - y0 ws (as an address: p's rows
         * are the only ones read or written); with dn, the dither's row y at dn->u[(y - y0) w] likewise */
        i64 *pf = (i64 *)(uintptr_t)((uintptr_t)p - (uintptr_t)(y0 * ws) * sizeof(i64));
        const int32_t *ug = u;
        int32_t *sg = dn ? dn->sym : sym + y0 * w;
        if (dn) {
            dn->dither(dn->k1, dn->k2, dn->start + y0 * dn->row_step, rows, w, dn->row_step, dn->col_step, dn->u);
            ug = (const int32_t *)(uintptr_t)((uintptr_t)dn->u - (uintptr_t)(y0 * w) * sizeof(int32_t));
        }
        for (i64 s0 = 0; s0 < nl && y0 + s0 < h; s0 += sub) {
            const i64 nr = sub < h - y0 - s0 ? sub : h - y0 - s0;
            if (!decode_group(steady8, steady16, pf, y0 + s0, nr, sub, w, ug, &m, xs + s0, pos + s0, pmin + s0,
                              epos + s0, eend + s0))
                return 0;
        }
        for (i64 y = 0; y < rows; y++) {
            const i64 *row = p + (y + 2) * ws + 2;
            const int32_t *uy = ug + (y0 + y) * w;
            int32_t *sy = sg + y * w;
            for (i64 x = 0; x < w; x++) sy[x] = (int32_t)((row[x] + uy[x]) >> 16);
        }
        if (dn)
            dn->inverse(dn->sym, rows, w, dn->k1, dn->k2, dn->start + y0 * dn->row_step, dn->row_step, dn->col_step,
                        dn->half_step, dn->k, dn->offset, dn->out + y0 * dn->out_row_stride, dn->out_row_stride,
                        dn->out_col_stride);
        if (rows == nl) memcpy(p, p + nl * ws, 2 * ws * sizeof(i64));   /* the next group's two rows above */
    }
    return 1;
}

/* The encoder's rANS pass (metraw.codec.predictive._rans_encode): lane j codes the symbols of rows lr[j] ..
 * lr[j + 1] - 1 (row starts rs, lengths rl) backwards into its own stream, words to out[ls[j]:]. Symbol i pushes
 * table entry j = tab[i] alpha + idx[i] (freq, cum, rcp = 1 / freq flat); x / f by the float64 reciprocal, exact for
 * x < 2^32 (see the numba function; no fused multiply-add: built with -ffp-contract=off and explicit rounding). The
 * lanes' streams are independent, so their order does not change the bytes: the symbols past the shortest lane's
 * length go one lane at a time (scalar), the rest 16 lanes at a time in AVX-512 (two vectors of 8 side by side: their
 * dependency chains overlap; 8 for a last group of 8; 2026-11-28 on Zen 5: 5.5 -> 4.0 ms a 2 MP frame). The lanes
 * read each symbol's entry from tab and idx, or with_ent from an array of the entries made here first (the portable
 * path: its element gathers read one array faster than two). States to xs_out, word counts to nws_out (nl each). */
INLINE void enc_symbol(const int32_t *idx, const int32_t *tab, i64 alpha, const i64 *freq, const i64 *cum,
                       const double *rcp, uint16_t *out, i64 o, i64 *nw, u64 *xp, i64 i)
{
    u64 x = *xp;
    i64 j = (i64)tab[i] * alpha + idx[i];
    u64 f = (u64)freq[j];
    u64 emit = x >= (f << (32 - PROB_BITS));
    out[o + *nw] = (uint16_t)(x & 0xFFFF);
    *nw += (i64)emit;
    x >>= emit << 4;
    double prod = (double)x * rcp[j];   /* -ffp-contract=off: no fused multiply-add */
    u64 q = (u64)(prod + 1.52587890625e-05);
    *xp = (q << PROB_BITS) + (x - q * f) + (u64)cum[j];
}

INLINE void enc_cursor(i64 *i, i64 *e, i64 *q, const i64 *rs, const i64 *rl, int more)
{
    if (*i > *e) { *i -= 1; return; }
    if (more) { i64 r = *q - 1; *i = rs[r] + rl[r] - 1; *e = rs[r]; *q = r; }
}

void rans_encode_with(rans_fn rans8, rans_fn rans16, int with_ent, const int32_t *idx, const int32_t *tab, i64 n,
                      i64 ntab, i64 alpha, const i64 *freq, const i64 *cum, const double *rcp, const i64 *rs,
                      const i64 *rl, const i64 *lr, const i64 *ls, i64 nl, uint16_t *out, u64 *xs, i64 *nws)
{
    i64 ci[16], ce[16], cq[16];
    i64 longest = 0, shortest = -1;
    for (i64 j = 0; j < nl; j++) {
        xs[j] = RANS_L;
        nws[j] = 0;
        i64 m = ls[j + 1] - ls[j];
        longest = m > longest ? m : longest;
        shortest = shortest < 0 || m < shortest ? m : shortest;
        i64 q = lr[j + 1] - 1;
        cq[j] = q;
        ci[j] = ce[j] = 0;
        if (q >= lr[j]) { ci[j] = rs[q] + rl[q] - 1; ce[j] = rs[q]; }
    }
    i64 lo = 0;
    int32_t *ent = NULL;
    u64 *fc = NULL;
    if (rans8 && nl % 8 == 0 && shortest >= 16) {   /* >= 16 symbols: the scatter stays in the lane */
        /* in the lanes' loop each symbol's table entry (tab alpha + idx, or ent's) and then one read of the entry's
         * frequency and cumulative frequency (fc), instead of five (symbol, table, frequency, cumulative frequency,
         * reciprocal); without the memory for them, the scalar coder codes every symbol */
        if (with_ent) ent = (int32_t *)malloc((size_t)(n > 0 ? n : 1) * sizeof(int32_t));
        fc = (u64 *)malloc((size_t)(ntab * alpha > 0 ? ntab * alpha : 1) * sizeof(u64));
        if ((ent || !with_ent) && fc) lo = shortest;
    }
    for (i64 k = longest - 1; k >= lo; k--) {
        for (i64 j = 0; j < nl; j++) {
            if (k >= ls[j + 1] - ls[j]) continue;
            enc_symbol(idx, tab, alpha, freq, cum, rcp, out, ls[j], &nws[j], &xs[j], ci[j]);
            enc_cursor(&ci[j], &ce[j], &cq[j], rs, rl, k > 0);
        }
    }
    if (lo > 0) {
        const uint32_t a32 = (uint32_t)alpha;   /* tab alpha + idx mod 2^32, as int32 */
        if (ent)
            for (i64 i = 0; i < n; i++) ent[i] = (int32_t)((uint32_t)tab[i] * a32 + (uint32_t)idx[i]);
        for (i64 e = 0; e < ntab * alpha; e++) fc[e] = (u64)freq[e] | ((u64)cum[e] << 32);
        for (i64 g = 0; g < nl; g += 16)
            (g + 16 <= nl ? rans16 : rans8)(idx, tab, alpha, ent, fc, rs, rl, out, lo, xs + g, nws + g, ci + g, ce + g,
                                            cq + g, ls + g);
    }
    free(ent);
    free(fc);
}

/* The alphabet indices' per-table counts (ntab x alpha, zeroed by the caller): runs of one bin in a row (smooth
 * areas) would chain each increment on the last; two sub-histograms (even and odd pixels) halve that chain */
void index_counts(const int32_t *t, const int32_t *idx, i64 n, i64 alpha, i64 nt, i64 *counts)
{
    int32_t *odd = (int32_t *)calloc((size_t)(nt * alpha), sizeof(int32_t));
    if (!odd) {
        for (i64 i = 0; i < n; i++) counts[(i64)t[i] * alpha + idx[i]] += 1;
        return;
    }
    i64 i = 0;
    for (; i + 1 < n; i += 2) {
        counts[(i64)t[i] * alpha + idx[i]] += 1;
        odd[(i64)t[i + 1] * alpha + idx[i + 1]] += 1;
    }
    for (; i < n; i++) counts[(i64)t[i] * alpha + idx[i]] += 1;
    for (i64 k = 0; k < nt * alpha; k++) counts[k] += odd[k];
    free(odd);
}

/* The escaped DN of n (prepare.escape_mask: >= white or <= low; white and low integers): their indices + offset into
 * out, in order, the first cap of them; returns their count. Each block of 256 DN is first tested whole (an OR of
 * compares, which the compiler vectorises): escapes are rare. */
i64 metraw_escape_index(const uint16_t *d, i64 n, i64 white, i64 low, i64 offset, i64 *out, i64 cap)
{
    const int32_t wt = (int32_t)(white < 0 ? 0 : white > 65536 ? 65536 : white);
    const int32_t lw = (int32_t)(low < -1 ? -1 : low > 65535 ? 65535 : low);
    i64 k = 0;
    for (i64 b = 0; b < n; b += 256) {
        const i64 e = b + 256 < n ? b + 256 : n;
        int any = 0;
        for (i64 i = b; i < e; i++) any |= ((int32_t)d[i] >= wt) | ((int32_t)d[i] <= lw);
        if (!any) continue;
        for (i64 i = b; i < e; i++)
            if ((int32_t)d[i] >= wt || (int32_t)d[i] <= lw) {
                if (k < cap) out[k] = i + offset;
                k++;
            }
    }
    return k;
}

/* The functions' signatures and meaning, version: metraw.codec.native.ABI must match it, so a library built from an
 * older source (an editable install is not rebuilt by a pull) is left unused rather than called wrongly. 4: the
 * functions per path (metraw_<name>_<path>) and metraw_simd_paths; 5: decode_plane_dn, metraw_escape_index. */
int metraw_simd_abi(void) { return 5; }

/* 1 where the steady part of 16-lane groups should run its two vectors side by side (AMD: their overlap hid the
 * AVX-512 gathers' latency, 2026-11-28 on Zen 5: 15 % faster than 8 lanes; the AVX2 path, without gathers since
 * 2026-11-29, not yet timed on AMD), 0 where as two groups of 8 (Intel: measured 2026-11-28 on Emerald Rapids with
 * two vectors, 10-25 % slower than 8 lanes, a noisy host) */
int metraw_two_vector_steady(void)
{
#if METRAW_X86
    __builtin_cpu_init();
    return __builtin_cpu_is("amd");
#else
    return 0;
#endif
}

/* The paths this build has and this CPU runs (PATH_* bits): portable always; AVX2 (with FMA and BMI2) and AVX-512
 * (F and DQ) on x86-64 CPUs that report them */
int metraw_simd_paths(void)
{
    int paths = PATH_PORTABLE;
#if METRAW_X86
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2"))
        paths |= PATH_AVX2;
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq")) paths |= PATH_AVX512;
#endif
    return paths;
}
