"""Dither-aware predictive coding of symbol planes: causal linear prediction + context rANS.

Symbols are s = round(z / q + u) with the dither u known to both sides (``prepare``). The
coder predicts in the *reconstructed* domain, where every decoded neighbour is
x = s - u = z / q + e (e uniform, independent): the prediction p of z / q is mapped to the
predicted symbol round(p + u) and only r = s - round(p + u) is coded, so the dither adds no
variance to the residual.

Dither phase context: with m = p + u and t = m - round(m) in [-1/2, 1/2) (known to the decoder),
r = round(t + d) where d = z / q - p is the prediction error. At coarse steps (d of ~0.5
symbol) the distribution of r depends strongly on t: P(r = 1) is large for t near +1/2 and
small for t near -1/2. Coding r conditioned on t saves ~0.14 bit/pixel at step 2 (H(r | t)
vs H(r) for Gaussian d). The distribution is mirror symmetric (r, t) -> (-r, -t), so t < 0 is
folded onto t > 0 by coding -r, and |t| is quantised into ``NPH`` bins.

All prediction arithmetic is integer (fixed point, ``FRAC`` bits): u is floored to 16 bits,
so x = s * 2^16 - u16 exactly, coefficients are integers with ``COEF_BITS`` fractional bits,
and encoder and decoder share one compiled function: the bitstream is platform independent.

Per group of planes (each CFA plane its own group, or all planes together for small tiles):
the activity context is the quantised local activity |W-NW| + |N-NW| + |N-NE| + |W-WW| +
|N-NN| of decoded neighbours (``nact`` contexts, thresholds at quantiles, stored); each
activity context has its own least-squares predictor x ~ W + sum_i c_i (n_i - W) + b over 12
causal neighbours (fitted by the encoder, stored) and each (activity, phase) context its own
static rANS table. The number of activity contexts shrinks with the plane size so that side
information stays a small fraction of the rate (small images: one context, tables shared by
the planes). Decoding is a sequential compiled loop (numba, ``nogil``), so tiles decode in
parallel threads.
"""

from __future__ import annotations

import struct

import numba as nb
import numpy as np

from metraw.errors import MetrawError

FRAC = 16                      # fixed-point bits of reconstructed values
COEF_BITS = 12                 # fractional bits of the predictor coefficients (int16 storage)
PROB_BITS = 12                 # rANS probability resolution
PROB_SCALE = 1 << PROB_BITS
RANS_L = 1 << 16
NPH = 4                        # folded dither-phase bins per activity context
MAX_NACT = 8                   # activity contexts per group, at most
MIN_FIT = 64                   # fewer samples in a context: use the default predictor
NTAP = 12                      # W + 11 differences (n_i - W); the 12th LS unknown is the bias
MAX_RESID = 1023
SHARED_BELOW = 1 << 16         # tiles with fewer pixels share one model across their planes
_HEAD = struct.Struct("<BBBHIIQ")  # nplanes, nact, shared, amax, words, escapes, final state


def n_activity_contexts(pixels_per_group: int) -> int:
    """Activity contexts for a group of ``pixels_per_group`` pixels (side info vs gain)."""
    if pixels_per_group < 4096:
        return 1
    if pixels_per_group < 16384:
        return 2
    if pixels_per_group < 65536:
        return 4
    return MAX_NACT


@nb.njit(cache=True, nogil=True, inline="always")
def _activity(p, y, x):
    w_ = p[y, x - 1]
    n_ = p[y - 1, x]
    nw = p[y - 1, x - 1]
    return abs(w_ - nw) + abs(n_ - nw) + abs(n_ - p[y - 1, x + 1]) + abs(w_ - p[y, x - 2]) + abs(n_ - p[y - 2, x])


@nb.njit(cache=True, nogil=True, inline="always")
def _ctx_of(act, thr):
    c = 0
    for i in range(thr.size):  # thresholds ascending: a branch-free count
        c += act > thr[i]
    return c


@nb.njit(cache=True, nogil=True, inline="always")
def _predict(p, y, x, k, o, b):
    """W + sum_i k[o + i] (n_i - W) / 2^COEF_BITS + b (fixed point)."""
    ref = p[y, x - 1]
    acc = (k[o] * (p[y - 1, x] - ref) + k[o + 1] * (p[y - 1, x - 1] - ref) + k[o + 2] * (p[y - 1, x + 1] - ref)
           + k[o + 3] * (p[y, x - 2] - ref) + k[o + 4] * (p[y - 2, x] - ref) + k[o + 5] * (p[y - 1, x - 2] - ref)
           + k[o + 6] * (p[y - 2, x - 1] - ref) + k[o + 7] * (p[y - 2, x + 1] - ref)
           + k[o + 8] * (p[y - 1, x + 2] - ref) + k[o + 9] * (p[y - 2, x - 2] - ref)
           + k[o + 10] * (p[y - 2, x + 2] - ref))
    return ref + (acc >> 12) + b


@nb.njit(cache=True, nogil=True)
def _front(s, u, c0):
    """Fixed-point dither u16, causally padded buffer of reconstructions (h+2, w+4) and activities.

    Padding: rows above the plane hold ``c0``; the two columns left of row y repeat the first
    pixel of row y-1, the two right of it the last pixel of row y (the decoder builds the same)."""
    h, w = s.shape
    u16 = np.empty((h, w), np.int64)
    p = np.full((h + 2, w + 4), c0, np.int64)
    for y in range(h):
        for x in range(w):
            v = np.int64(np.floor(u[y, x] * 65536.0))
            u16[y, x] = v
            p[y + 2, x + 2] = (np.int64(s[y, x]) << 16) - v
        if y > 0:
            p[y + 2, 0] = p[y + 1, 2]
            p[y + 2, 1] = p[y + 1, 2]
        p[y + 2, w + 2] = p[y + 2, w + 1]
        p[y + 2, w + 3] = p[y + 2, w + 1]
    act = np.empty((h, w), np.int64)
    for y in range(h):
        for x in range(w):
            act[y, x] = _activity(p, y + 2, x + 2)
    return u16, p, act


@nb.njit(cache=True, nogil=True)
def _normal_equations(p, act, thr, nact, stride, ata, atb):
    """Accumulate per-context X^T X and X^T t of t = x - W on (n_i - W, 1), every ``stride``-th pixel."""
    h, w = act.shape
    d = np.empty(12)
    sc = 1.0 / 65536.0
    for y in range(0, h, stride):
        yy = y + 2
        for x0 in range((y // stride) % stride, w, stride):  # sheared lattice: no column aliasing
            xx = x0 + 2
            ref = p[yy, xx - 1]
            d[0] = (p[yy - 1, xx] - ref) * sc
            d[1] = (p[yy - 1, xx - 1] - ref) * sc
            d[2] = (p[yy - 1, xx + 1] - ref) * sc
            d[3] = (p[yy, xx - 2] - ref) * sc
            d[4] = (p[yy - 2, xx] - ref) * sc
            d[5] = (p[yy - 1, xx - 2] - ref) * sc
            d[6] = (p[yy - 2, xx - 1] - ref) * sc
            d[7] = (p[yy - 2, xx + 1] - ref) * sc
            d[8] = (p[yy - 1, xx + 2] - ref) * sc
            d[9] = (p[yy - 2, xx - 2] - ref) * sc
            d[10] = (p[yy - 2, xx + 2] - ref) * sc
            d[11] = 1.0
            tv = (p[yy, xx] - ref) * sc
            c = _ctx_of(act[y, x0], thr)
            for i in range(12):
                di = d[i]
                atb[c, i] += di * tv
                for j in range(i + 1):
                    ata[c, i, j] += di * d[j]


@nb.njit(cache=True, nogil=True)
def _residuals(s, p, act, u16, thr, coef, bias, tab0, r_out, t_out, off):
    """Residuals r (phase folded) and table indices of one plane into flat outputs at ``off``.

    Returns max |r|."""
    h, w = act.shape
    half = np.int64(1 << 15)
    rmax = np.int64(0)
    k = off
    for y in range(h):
        for x in range(w):
            c = _ctx_of(act[y, x], thr)
            mh = _predict(p, y + 2, x + 2, coef, c * 11, bias[c]) + u16[y, x] + half
            r = np.int64(s[y, x]) - (mh >> 16)
            fr = mh & 0xFFFF
            f = 1 - (fr >> 15)              # 1 when t < 0: fold (r, t) -> (-r, -t)
            fr ^= -f & 0xFFFF
            r = (r ^ -f) + f
            r_out[k] = r
            t_out[k] = tab0 + c * 4 + ((fr >> 13) & 3)
            rmax = max(rmax, abs(r))
            k += 1
    return rmax


@nb.njit(cache=True, nogil=True)
def _index(r, t, amax, ntab):
    """Alphabet indices (escape = 2 amax + 1), per-table counts and escaped residuals."""
    alpha = 2 * amax + 2
    esc_i = alpha - 1
    idx = np.empty(r.size, np.int64)
    counts = np.zeros((ntab, alpha), np.int64)
    esc = np.empty(r.size, np.int32)
    ne = 0
    for i in range(r.size):
        v = r[i]
        if v < -amax or v > amax:
            esc[ne] = np.int32(v)
            ne += 1
            j = esc_i
        else:
            j = v + amax
        idx[i] = j
        counts[t[i], j] += 1
    return idx, counts, esc[:ne]


@nb.njit(cache=True, nogil=True)
def _normalise(counts):
    """Per row: integer frequencies summing to PROB_SCALE, >= 1 wherever counts > 0 (all-zero rows
    stay zero: unused tables)."""
    ntab, alpha = counts.shape
    freq = np.zeros((ntab, alpha), np.int64)
    for t in range(ntab):
        tot = 0
        for j in range(alpha):
            tot += counts[t, j]
        if tot == 0:
            continue
        s = 0
        best = 0
        for j in range(alpha):
            c = counts[t, j]
            if c > 0:
                f = (c * PROB_SCALE) // tot
                if f < 1:
                    f = 1
                freq[t, j] = f
                s += f
                if f > freq[t, best]:
                    best = j
        diff = PROB_SCALE - s
        if diff >= 0:
            freq[t, best] += diff
        else:
            while diff < 0:  # take from the largest entries, keeping >= 1
                best = 0
                for j in range(alpha):
                    if freq[t, j] > freq[t, best]:
                        best = j
                take = min(-diff, freq[t, best] - 1)
                freq[t, best] -= take
                diff += take
    return freq


@nb.njit(cache=True, nogil=True)
def _rans_encode(idx, tab, freq, cum, out):
    """Encode alphabet indices ``idx`` with table rows ``tab`` (reverse order); 16-bit words into ``out``.

    x // f via a float64 reciprocal: exact for x < 2^32 and f <= 2^12 (rounding error < 2^-19,
    fraction of x / f is 0 or >= 2^-12). Returns (final state, number of words)."""
    x = np.uint64(RANS_L)
    nw = 0
    for k in range(idx.size - 1, -1, -1):
        t = tab[k]
        s = idx[k]
        fi = freq[t, s]
        f = np.uint64(fi)
        emit = np.uint64(x >= (f << np.uint64(32 - PROB_BITS)))
        out[nw] = np.uint16(x & np.uint64(0xFFFF))
        nw += np.int64(emit)
        x >>= emit << np.uint64(4)
        q = np.uint64(np.float64(x) * (1.0 / fi) + 1.52587890625e-05)
        x = (q << np.uint64(PROB_BITS)) + (x - q * f) + np.uint64(cum[t, s])
    return x, nw


@nb.njit(cache=True, nogil=True)
def _decode_plane(p, u16, thr, coef, bias, tab0, lut, fcum, amax, words, state, pos, esc, epos):
    """Sequentially decode one plane into the padded buffer ``p``; returns (symbols, state, pos, epos).

    Error codes: pos = -1 when the word stream runs out, epos = -1 when the escape list does."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    sym = np.empty((h, w), np.int32)
    x = np.uint64(state)
    half = np.int64(1 << 15)
    mask = np.uint64(PROB_SCALE - 1)
    esc_idx = 2 * amax + 1
    for y in range(h):
        yy = y + 2
        if y > 0:
            p[yy, 0] = p[yy - 1, 2]
            p[yy, 1] = p[yy - 1, 2]
        for xx0 in range(w):
            xx = xx0 + 2
            c = _ctx_of(_activity(p, yy, xx), thr)
            mh = _predict(p, yy, xx, coef, c * 11, bias[c]) + u16[y, xx0] + half
            sh = mh >> 16
            fr = mh & 0xFFFF
            f = 1 - (fr >> 15)
            t = tab0 + c * 4 + (((fr ^ (-f & 0xFFFF)) >> 13) & 3)
            slot = x & mask
            s = np.int64(lut[t, slot])
            fc = fcum[t, s]
            x = np.uint64(fc >> 16) * (x >> np.uint64(PROB_BITS)) + slot - np.uint64(fc & 0xFFFF)
            # renormalise without a data-dependent branch: words[pos] with pos = words left (words[0] is a pad)
            need = np.uint64(x < np.uint64(RANS_L))
            x = (x << (need << np.uint64(4))) | (np.uint64(words[pos]) * need)
            pos -= np.int64(need)
            if pos < 0:
                return sym, x, -1, epos
            if s == esc_idx:
                if epos >= esc.size:
                    return sym, x, pos, -1
                r = np.int64(esc[epos])
                epos += 1
            else:
                r = s - amax
            v = sh + ((r ^ -f) + f)
            sym[y, xx0] = v
            p[yy, xx] = (v << 16) - u16[y, xx0]
        p[yy, w + 2] = p[yy, w + 1]
        p[yy, w + 3] = p[yy, w + 1]
    return sym, x, pos, epos


def _thresholds(acts: list[np.ndarray], nact: int) -> np.ndarray:
    """nact - 1 activity thresholds (multiples of 256, at quantiles of a subsample), padded with +inf."""
    if nact == 1:
        return np.empty(0, np.int64)
    sample = np.concatenate([a.reshape(-1)[::max(1, a.size // 32768)] for a in acts])
    q = np.quantile(sample, np.linspace(0, 1, nact + 1)[1:-1], method="lower").astype(np.int64)
    q = np.minimum(q >> 8, 0xFFFFFFFE)
    thr = np.unique(q) << 8
    return np.concatenate([thr, np.full(nact - 1 - thr.size, 0xFFFFFFFF << 8, np.int64)])


def _fit(ata: np.ndarray, atb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-context least-squares coefficients (int16, COEF_BITS) and bias (int32, FRAC bits)."""
    nact = ata.shape[0]
    coef = np.zeros((nact, NTAP - 1), np.int64)
    bias = np.zeros(nact, np.int64)
    for c in range(nact):
        sol = np.zeros(NTAP - 1)
        sol[0] = 0.5  # (W + N) / 2 when a context has too few samples
        b = 0.0
        if ata[c, -1, -1] >= MIN_FIT:
            try:
                full = np.linalg.solve(ata[c] + 1e-6 * np.eye(NTAP), atb[c])
                if np.all(np.isfinite(full)) and np.all(np.abs(full[:-1]) < 7.9):
                    sol = full[:-1]
                    b = float(np.clip(full[-1], -16000, 16000))
            except np.linalg.LinAlgError:
                pass
        coef[c] = np.rint(sol * (1 << COEF_BITS)).astype(np.int64)
        bias[c] = int(round(b * (1 << FRAC)))
    return coef, bias


def encode_planes(planes: list[tuple[np.ndarray, np.ndarray]]) -> bytes:
    """Code planes given as (symbols int32, dither float in [-1/2, 1/2)) pairs into one section."""
    npl = len(planes)
    total = sum(s.size for s, _ in planes)
    shared = total < SHARED_BELOW
    groups = [list(range(npl))] if shared else [[k] for k in range(npl)]
    nact = n_activity_contexts(min((sum(planes[k][0].size for k in g) for g in groups), default=0))
    fronts, c0s = [], []
    for s, u in planes:
        c0 = int(np.rint(s.mean())) if s.size else 0
        c0s.append(c0)
        fronts.append(_front(s, np.asarray(u, np.float64), np.int64(c0) << 16))
    ngroup = len(groups)
    ntab = ngroup * nact * NPH
    r_all = np.empty(total, np.int64)
    t_all = np.empty(total, np.int64)
    group_heads = []
    off = 0
    rmax = 0
    for gi, g in enumerate(groups):
        thr = _thresholds([fronts[k][2] for k in g], nact)
        ata = np.zeros((nact, NTAP, NTAP))
        atb = np.zeros((nact, NTAP))
        npix = sum(planes[k][0].size for k in g)
        stride = max(1, int(np.sqrt(npix / 65536)))  # ~65536 samples for 12 x nact unknowns
        for k in g:
            u16, p, act = fronts[k]
            _normal_equations(p, act, thr, nact, stride, ata, atb)
        for c in range(nact):  # symmetric fill
            ata[c] = np.tril(ata[c]) + np.tril(ata[c], -1).T
        coef, bias = _fit(ata, atb)
        for k in g:
            u16, p, act = fronts[k]
            rmax = max(rmax, int(_residuals(planes[k][0], p, act, u16, thr, coef.reshape(-1), bias, gi * nact * NPH,
                                            r_all, t_all, off)))
            off += planes[k][0].size
        group_heads.append((thr >> 8).astype("<u4").tobytes() + coef.astype("<i2").tobytes()
                           + np.clip(bias, -2**31, 2**31 - 1).astype("<i4").tobytes())
    amax = int(min(MAX_RESID, max(1, rmax)))
    idx, counts, esc_vals = _index(r_all, t_all, amax, max(ntab, 1))
    freq = _normalise(counts)
    cum = np.concatenate([np.zeros((freq.shape[0], 1), np.int64), np.cumsum(freq, 1)[:, :-1]], 1)
    out = np.empty(idx.size + 2, np.uint16)
    state, nw = _rans_encode(idx, t_all, freq, cum, out)
    tables = []
    for f in freq:
        nz = np.flatnonzero(f)
        if nz.size == 0:
            tables.append(struct.pack("<HH", 0, 0))
            continue
        first, last = int(nz[0]), int(nz[-1])
        tables.append(struct.pack("<HH", first, last - first + 1) + f[first:last + 1].astype("<u2").tobytes())
    parts = [_HEAD.pack(npl, nact, int(shared), amax, nw, esc_vals.size, int(state)),
             np.array(c0s, "<i4").tobytes()]
    parts += group_heads + tables
    parts.append(out[:nw].astype("<u2").tobytes())
    parts.append(esc_vals.astype("<i4").tobytes())
    return b"".join(parts)


def decode_planes(blob, dithers: list[np.ndarray]) -> list[np.ndarray]:
    """Inverse of ``encode_planes``; ``dithers`` are the planes' dither arrays (same shapes)."""
    try:
        return _decode(memoryview(blob), dithers)
    except (struct.error, ValueError, IndexError) as exc:
        raise MetrawError(f"codec stream is corrupt: {exc}") from None


def _decode(mv: memoryview, dithers: list[np.ndarray]) -> list[np.ndarray]:
    npl, nact, shared, amax, nw, nesc, state = _HEAD.unpack_from(mv, 0)
    off = _HEAD.size
    if npl != len(dithers) or not 1 <= nact <= MAX_NACT or shared > 1 or amax > MAX_RESID:
        raise ValueError("plane header does not match the frame")
    c0s = np.frombuffer(mv, "<i4", npl, off).astype(np.int64)
    off += 4 * npl
    ngroup = 1 if shared else npl
    heads = []
    for _ in range(ngroup):
        thr = np.frombuffer(mv, "<u4", nact - 1, off).astype(np.int64) << 8
        off += 4 * (nact - 1)
        coef = np.frombuffer(mv, "<i2", nact * (NTAP - 1), off).astype(np.int64).reshape(nact, NTAP - 1)
        off += 2 * nact * (NTAP - 1)
        bias = np.frombuffer(mv, "<i4", nact, off).astype(np.int64)
        off += 4 * nact
        heads.append((thr, coef, bias))
    alpha = 2 * amax + 2
    ntab = ngroup * nact * NPH
    freq = np.zeros((ntab, alpha), np.int64)
    for t in range(ntab):
        first, span = struct.unpack_from("<HH", mv, off)
        off += 4
        if span == 0:
            freq[t, -1] = PROB_SCALE  # unused table: escape only
            continue
        if first + span > alpha:
            raise ValueError("frequency table overruns the alphabet")
        freq[t, first:first + span] = np.frombuffer(mv, "<u2", span, off)
        off += 2 * span
        if freq[t].sum() != PROB_SCALE:
            raise ValueError("frequency table does not sum to the probability scale")
    cum = np.concatenate([np.zeros((ntab, 1), np.int64), np.cumsum(freq, 1)[:, :-1]], 1)
    lut = np.stack([np.repeat(np.arange(alpha, dtype=np.int16), f) for f in freq])
    fcum = (freq << 16) | cum
    words = np.zeros(nw + 1, np.uint16)  # words[0]: pad read by the branch-free renormalisation
    words[1:] = np.frombuffer(mv, "<u2", nw, off)
    off += 2 * nw
    esc = np.frombuffer(mv, "<i4", nesc, off).astype(np.int32)
    pos, epos = nw, 0
    x = np.uint64(state)
    out = []
    for k, u in enumerate(dithers):
        g = 0 if shared else k
        thr, coef, bias = heads[g]
        u16 = np.floor(np.asarray(u, np.float64) * (1 << FRAC)).astype(np.int64)
        h, w = u.shape
        p = np.full((h + 2, w + 4), np.int64(c0s[k]) << 16, np.int64)
        sym, x, pos, epos = _decode_plane(p, u16, thr, coef.reshape(-1), bias, g * nact * NPH, lut, fcum, amax,
                                          words, x, pos, esc, epos)
        if pos < 0 or epos < 0:
            raise ValueError("coded data ran out")
        out.append(sym)
    if pos != 0 or int(x) != RANS_L or epos != esc.size:
        raise ValueError("rANS did not end in its initial state")
    return out
