"""Dither-aware predictive coding of a symbol plane: causal linear prediction + context rANS.

Symbols are s = round(z / q + u) with the dither u known to both sides (``prepare``). The
coder predicts in the *reconstructed* domain, where every decoded neighbour is
x = s - u = z / q + e (e uniform, independent): the prediction p of z / q is mapped to the
predicted symbol round(p + u) and only r = s - round(p + u) is coded, so the dither adds no
variance to the residual (only the residual of z / q itself and the reconstruction noise of
the neighbours).

All prediction arithmetic is integer (fixed point, ``FRAC`` bits): u is a 24-bit value, so
x = s * 2^16 - u16 exactly, coefficients are integers with ``COEF_BITS`` fractional bits, and
encoder and decoder share one compiled function: the bitstream is platform independent.

Per plane: the context is the quantised local activity |W-NW| + |N-NW| + |N-NE| + |W-WW| +
|N-NN| of decoded neighbours (thresholds at quantiles, stored); each context has its own
least-squares predictor x ~ W + sum_i c_i (n_i - W) + b over 12 causal neighbours (fitted by
the encoder, stored) and its own static rANS table. Decoding is a sequential compiled loop
(numba, ``nogil``) so tiles decode in parallel threads.
"""

from __future__ import annotations

import struct

import numba as nb
import numpy as np

from metraw.errors import MetrawError

FRAC = 16                      # fixed-point bits of reconstructed values
COEF_BITS = 14                 # fractional bits of the predictor coefficients
PROB_BITS = 12                 # rANS probability resolution
PROB_SCALE = 1 << PROB_BITS
RANS_L = 1 << 16
NCTX = 8                       # activity contexts per plane
MIN_FIT = 64                   # fewer samples in a context: use the default predictor
#: causal neighbours (dy, dx); index 0 is W, the reference of the differences
OFFSETS = np.array([(0, -1), (-1, 0), (-1, -1), (-1, 1), (0, -2), (-2, 0), (-1, -2), (-2, -1), (-2, 1), (-1, 2),
                    (-2, -2), (-2, 2)], dtype=np.int64)
NTAP = len(OFFSETS)
MAX_RESID = 1023


def fixed_dither(u: np.ndarray) -> np.ndarray:
    """u in [-1/2, 1/2) with 24-bit resolution -> u * 2^16 floored to int64 (exact, deterministic)."""
    return np.floor(u * (1 << FRAC)).astype(np.int64)


def padded(xfp: np.ndarray, c0: int) -> np.ndarray:
    """Causally padded buffer (h + 2, w + 4) of fixed-point reconstructions (see ``_decode_plane``)."""
    h, w = xfp.shape
    p = np.full((h + 2, w + 4), c0, np.int64)
    p[2:, 2:w + 2] = xfp
    if h > 1:
        p[3:, 0:2] = xfp[:-1, 0:1]
    p[2:, w + 2:] = xfp[:, w - 1:w]
    return p


@nb.njit(cache=True, nogil=True, inline="always")
def _activity(p, y, x):
    w_ = p[y, x - 1]
    n_ = p[y - 1, x]
    nw = p[y - 1, x - 1]
    return abs(w_ - nw) + abs(n_ - nw) + abs(n_ - p[y - 1, x + 1]) + abs(w_ - p[y, x - 2]) + abs(n_ - p[y - 2, x])


@nb.njit(cache=True, nogil=True, inline="always")
def _ctx_of(act, thr):
    c = 0
    while c < thr.size and act > thr[c]:
        c += 1
    return c


@nb.njit(cache=True, nogil=True, inline="always")
def _predict(p, y, x, coef, bias, c):
    ref = p[y, x - 1]
    k = coef[c]
    acc = (k[1] * (p[y - 1, x] - ref) + k[2] * (p[y - 1, x - 1] - ref) + k[3] * (p[y - 1, x + 1] - ref)
           + k[4] * (p[y, x - 2] - ref) + k[5] * (p[y - 2, x] - ref) + k[6] * (p[y - 1, x - 2] - ref)
           + k[7] * (p[y - 2, x - 1] - ref) + k[8] * (p[y - 2, x + 1] - ref) + k[9] * (p[y - 1, x + 2] - ref)
           + k[10] * (p[y - 2, x - 2] - ref) + k[11] * (p[y - 2, x + 2] - ref))
    return ref + (acc >> 14) + bias[c]


@nb.njit(cache=True, nogil=True)
def _normal_equations(p, ctx, nctx, stride):
    """Per-context X^T X and X^T t of the regression t = x - W on (n_i - W, 1), every ``stride``-th pixel."""
    h, w = ctx.shape
    ata = np.zeros((nctx, 12, 12))
    atb = np.zeros((nctx, 12))
    d = np.empty(12)
    sc = 1.0 / 65536.0
    for y in range(0, h, stride):
        yy = y + 2
        for x0 in range(0, w, stride):
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
            c = ctx[y, x0]
            for i in range(12):
                di = d[i]
                atb[c, i] += di * tv
                for j in range(i + 1):
                    ata[c, i, j] += di * d[j]
    for c in range(nctx):
        for i in range(12):
            for j in range(i + 1, 12):
                ata[c, i, j] = ata[c, j, i]
    return ata, atb


@nb.njit(cache=True, nogil=True)
def _prepare_plane(s, u, c0_from_mean):
    """Fixed-point dither u16, padded buffer of reconstructions and activities of one plane."""
    h, w = s.shape
    u16 = np.empty((h, w), np.int64)
    tot = 0.0
    for y in range(h):
        for x in range(w):
            v = np.int64(np.floor(u[y, x] * 65536.0))
            u16[y, x] = v
            tot += (np.int64(s[y, x]) << 16) - v
    c0 = np.int64(np.rint(tot / max(h * w, 1))) if c0_from_mean else np.int64(0)
    p = np.full((h + 2, w + 4), c0, np.int64)
    for y in range(h):
        for x in range(w):
            p[y + 2, x + 2] = (np.int64(s[y, x]) << 16) - u16[y, x]
        if y > 0:
            p[y + 2, 0] = p[y + 1, 2]
            p[y + 2, 1] = p[y + 1, 2]
        p[y + 2, w + 2] = p[y + 2, w + 1]
        p[y + 2, w + 3] = p[y + 2, w + 1]
    act = _activities(p)
    return u16, p, act, c0


@nb.njit(cache=True, nogil=True)
def _context_map(act, thr):
    h, w = act.shape
    ctx = np.empty((h, w), np.int64)
    for y in range(h):
        for x in range(w):
            ctx[y, x] = _ctx_of(act[y, x], thr)
    return ctx


@nb.njit(cache=True, nogil=True)
def _activities(p):
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    act = np.empty((h, w), np.int64)
    for y in range(h):
        for x in range(w):
            act[y, x] = _activity(p, y + 2, x + 2)
    return act


@nb.njit(cache=True, nogil=True)
def _predicted_symbols(p, ctx, u16, coef, bias):
    h, w = ctx.shape
    out = np.empty((h, w), np.int64)
    half = np.int64(1 << 15)
    for y in range(h):
        for x in range(w):
            pr = _predict(p, y + 2, x + 2, coef, bias, ctx[y, x])
            out[y, x] = (pr + u16[y, x] + half) >> 16
    return out


@nb.njit(cache=True, nogil=True)
def _rans_encode(idx, tab, freq, cum, out):
    """Encode alphabet indices ``idx`` with table row ``tab`` (reverse order); words into ``out``.

    Returns (final state, number of 16-bit words)."""
    x = np.uint64(RANS_L)
    nw = 0
    for k in range(idx.size - 1, -1, -1):
        t = tab[k]
        s = idx[k]
        f = np.uint64(freq[t, s])
        if x >= (f << np.uint64(32 - PROB_BITS)):
            out[nw] = np.uint16(x & np.uint64(0xFFFF))
            nw += 1
            x >>= np.uint64(16)
        x = ((x // f) << np.uint64(PROB_BITS)) + (x % f) + np.uint64(cum[t, s])
    return x, nw


@nb.njit(cache=True, nogil=True)
def _decode_plane(p, u16, thr, coef, bias, tab0, lut, freq, cum, amax, words, state, pos, esc, epos):
    """Sequentially decode one plane into the padded buffer ``p``; returns (symbols, state, pos, epos).

    Error codes: pos = -1 when the word stream runs out, epos = -1 when the escape list does."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    sym = np.empty((h, w), np.int64)
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
            pr = _predict(p, yy, xx, coef, bias, c)
            sh = (pr + u16[y, xx0] + half) >> 16
            t = tab0 + c
            slot = x & mask
            s = lut[t, slot]
            x = np.uint64(freq[t, s]) * (x >> np.uint64(PROB_BITS)) + slot - np.uint64(cum[t, s])
            if x < np.uint64(RANS_L):
                if pos <= 0:
                    return sym, x, -1, epos
                pos -= 1
                x = (x << np.uint64(16)) | np.uint64(words[pos])
            if s == esc_idx:
                if epos >= esc.size:
                    return sym, x, pos, -1
                r = np.int64(esc[epos])
                epos += 1
            else:
                r = np.int64(s) - amax
            v = sh + r
            sym[y, xx0] = v
            p[yy, xx] = (v << 16) - u16[y, xx0]
        p[yy, w + 2] = p[yy, w + 1]
        p[yy, w + 3] = p[yy, w + 1]
    return sym, x, pos, epos


def _normalise(counts: np.ndarray) -> np.ndarray:
    """Integer frequencies summing to PROB_SCALE, >= 1 wherever counts > 0 (all-zero: escape only)."""
    total = counts.sum()
    if total == 0:
        freq = np.zeros(counts.size, np.int64)
        freq[-1] = PROB_SCALE
        return freq
    freq = np.floor(counts * (PROB_SCALE / total)).astype(np.int64)
    freq[(counts > 0) & (freq == 0)] = 1
    diff = PROB_SCALE - int(freq.sum())
    order = np.argsort(-freq, kind="stable")
    i = 0
    while diff != 0:
        j = order[i % order.size]
        if diff > 0:
            freq[j] += diff
            diff = 0
        elif freq[j] > 1:
            take = min(-diff, int(freq[j]) - 1)
            freq[j] -= take
            diff += take
        i += 1
    return freq


def _fit(p: np.ndarray, ctx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-context least-squares coefficients (integer, COEF_BITS) and bias (fixed point)."""
    stride = 4 if ctx.size > 1 << 20 else 3 if ctx.size > 1 << 18 else 2 if ctx.size > 1 << 16 else 1
    ata, atb = _normal_equations(p, ctx, NCTX, stride)
    coef = np.zeros((NCTX, NTAP), np.int64)
    bias = np.zeros(NCTX, np.int64)
    for c in range(NCTX):
        sol = np.zeros(NTAP)
        sol[1] = 0.5  # (W + N) / 2 when a context has too few samples
        b = 0.0
        if ata[c, -1, -1] >= MIN_FIT:
            try:
                full = np.linalg.solve(ata[c] + 1e-6 * np.eye(NTAP), atb[c])
                if np.all(np.isfinite(full)) and np.all(np.abs(full[:-1]) < 4):
                    sol[1:] = full[:-1]
                    b = float(np.clip(full[-1], -1000, 1000))
            except np.linalg.LinAlgError:
                pass
        coef[c] = np.rint(sol * (1 << COEF_BITS)).astype(np.int64)
        coef[c, 0] = 0
        bias[c] = int(round(b * (1 << FRAC)))
    return coef, bias


def encode_planes(planes: list[tuple[np.ndarray, np.ndarray]]) -> bytes:
    """Code planes given as (symbols int32, dither float in [-1/2, 1/2)) pairs into one section."""
    heads, idxs, tabs, escs, tables = [], [], [], [], []
    resid = []
    for k, (s, u) in enumerate(planes):
        h, w = s.shape
        u16, p, act, c0 = _prepare_plane(s, u, True)
        c0 = int(c0)
        sample = act.reshape(-1)[::4] if act.size > 1 << 16 else act.reshape(-1)
        thr = np.unique(np.quantile(sample, np.linspace(0, 1, NCTX + 1)[1:-1], method="lower").astype(np.int64))
        thr = np.concatenate([thr, np.full(NCTX - 1 - thr.size, np.iinfo(np.int64).max, np.int64)])
        ctx = _context_map(act, thr)
        coef, bias = _fit(p, ctx)
        sh = _predicted_symbols(p, ctx, u16, coef, bias)
        r = s.astype(np.int64) - sh
        resid.append((r.reshape(-1), ctx.reshape(-1) + k * NCTX))
        heads.append(struct.pack("<IIq", h, w, c0) + thr.astype("<i8").tobytes() + coef[:, 1:].astype("<i4").tobytes()
                     + bias.astype("<i8").tobytes())
    r_all = np.concatenate([r for r, _ in resid]) if resid else np.empty(0, np.int64)
    t_all = np.concatenate([t for _, t in resid]) if resid else np.empty(0, np.int64)
    if r_all.size:
        amax = int(min(MAX_RESID, max(1, np.abs(r_all).max())))
    else:
        amax = 1
    esc_i = 2 * amax + 1
    idx = r_all + amax
    esc = (idx < 0) | (idx >= esc_i)
    esc_vals = r_all[esc].astype("<i4")
    idx[esc] = esc_i
    ntab = max(1, NCTX * len(planes))
    counts = np.bincount(t_all * (esc_i + 1) + idx, minlength=ntab * (esc_i + 1)).reshape(ntab, esc_i + 1)
    freq = np.stack([_normalise(c.astype(np.float64)) for c in counts])
    cum = np.concatenate([np.zeros((ntab, 1), np.int64), np.cumsum(freq, 1)[:, :-1]], 1)
    out = np.empty(idx.size + 2, np.uint16)
    state, nw = _rans_encode(idx, t_all, freq, cum, out)
    for f in freq:
        nz = np.flatnonzero(f)
        first, last = int(nz[0]), int(nz[-1])
        tables.append(struct.pack("<HH", first, last - first + 1) + f[first:last + 1].astype("<u2").tobytes())
    parts = [struct.pack("<IIIQII", len(planes), NCTX, amax, int(state), nw, esc_vals.size)]
    parts += heads + tables
    parts.append(out[:nw].astype("<u2").tobytes())
    parts.append(esc_vals.tobytes())
    return b"".join(parts)


def decode_planes(blob, dithers: list[np.ndarray]) -> list[np.ndarray]:
    """Inverse of ``encode_planes``; ``dithers`` are the planes' dither arrays (same shapes)."""
    try:
        return _decode(memoryview(blob), dithers)
    except (struct.error, ValueError, IndexError) as exc:
        raise MetrawError(f"codec stream is corrupt: {exc}") from None


def _decode(mv: memoryview, dithers: list[np.ndarray]) -> list[np.ndarray]:
    nplanes, nctx, amax, state, nw, nesc = struct.unpack_from("<IIIQII", mv, 0)
    off = struct.calcsize("<IIIQII")
    if nplanes != len(dithers) or nctx != NCTX or amax > MAX_RESID:
        raise ValueError("plane header does not match the frame")
    heads = []
    for u in dithers:
        h, w, c0 = struct.unpack_from("<IIq", mv, off)
        off += 16
        if (h, w) != u.shape:
            raise ValueError("plane shape does not match the frame")
        thr = np.frombuffer(mv, "<i8", NCTX - 1, off).astype(np.int64)
        off += 8 * (NCTX - 1)
        coef = np.zeros((NCTX, NTAP), np.int64)
        coef[:, 1:] = np.frombuffer(mv, "<i4", NCTX * (NTAP - 1), off).reshape(NCTX, NTAP - 1)
        off += 4 * NCTX * (NTAP - 1)
        bias = np.frombuffer(mv, "<i8", NCTX, off).astype(np.int64)
        off += 8 * NCTX
        heads.append((c0, thr, coef, bias))
    alpha = 2 * amax + 2
    ntab = max(1, NCTX * nplanes)
    freq = np.zeros((ntab, alpha), np.int64)
    for t in range(ntab):
        first, span = struct.unpack_from("<HH", mv, off)
        off += 4
        if first + span > alpha:
            raise ValueError("frequency table overruns the alphabet")
        freq[t, first:first + span] = np.frombuffer(mv, "<u2", span, off)
        off += 2 * span
        if freq[t].sum() != PROB_SCALE:
            raise ValueError("frequency table does not sum to the probability scale")
    cum = np.concatenate([np.zeros((ntab, 1), np.int64), np.cumsum(freq, 1)[:, :-1]], 1)
    lut = np.stack([np.repeat(np.arange(alpha, dtype=np.int32), f) for f in freq])
    words = np.frombuffer(mv, "<u2", nw, off).astype(np.uint16)
    off += 2 * nw
    esc = np.frombuffer(mv, "<i4", nesc, off).astype(np.int32)
    pos, epos = nw, 0
    x = np.uint64(state)
    out = []
    for k, (u, (c0, thr, coef, bias)) in enumerate(zip(dithers, heads)):
        u16 = fixed_dither(u)
        h, w = u.shape
        p = np.full((h + 2, w + 4), np.int64(c0), np.int64)
        sym, x, pos, epos = _decode_plane(p, u16, thr, coef, bias, k * NCTX, lut, freq, cum, amax, words, x, pos,
                                          esc, epos)
        if pos < 0 or epos < 0:
            raise ValueError("coded data ran out")
        out.append(sym.astype(np.int32))
    if pos != 0 or int(x) != RANS_L or epos != esc.size:
        raise ValueError("rANS did not end in its initial state")
    return out
