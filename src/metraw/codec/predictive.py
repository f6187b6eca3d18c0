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
causal neighbours (fitted by the encoder, ``metraw.codec.model``; stored) and each (activity, phase) context its own
static rANS table. The number of activity contexts shrinks with the plane size so that side
information stays a small fraction of the rate (small images: one context, tables shared by
the planes). Large tiles code their rows in 16 interleaved rANS lanes (row classes, each with
its own state; the decoder runs lane j three pixels behind lane j - 1, so the dependency chains
overlap, and the compiled C decoder runs 8 lanes side by side in one AVX-512 register, 16 in two:
4 lanes before 2026-11-28, then 8, then 16: +0.01-0.05 % bits for 8, +0.01-0.15 % more for 16).
Decoding is a sequential compiled loop (C or numba, without the GIL), so tiles decode in parallel
threads.

Speed without changing the stream: the encoder computes activities, contexts and predictions row
by row in passes without a sequential dependence; the least squares accumulate X^T X from
per-context sample buffers in vectorised blocks (encoder only: the coefficients are stored);
the causal buffer (with the dither and the forward transform, from the DN), the residual pass (8
pixels at a time), the alphabet indices and the rANS pass (16 lanes at a time) run in C with AVX-512
where ``metraw.codec.native`` is built, else in numba, to the same bytes; the activity thresholds
come from a histogram; the numba decoder runs the steady part of each 4-row group with the lane states in
registers; both evaluate sum_i k_i (n_i - W) as sum_i k_i n_i - W sum_i k_i (exact integers, the
same value).
The encoder's work is a few compiled calls per section (``model.model_of_front``, the residual pass,
``_code_section``), each releasing the GIL, so that row tiles in parallel threads rarely wait on
each other for the interpreter; a tile's per-pixel arrays (residuals, table and alphabet indices,
rANS words) are the thread's ``scratch`` arrays, reused from call to call (no fresh pages to fault
in). The decoder is ``metraw.codec.decoder`` (unsigned indices into flat views, context by table
lookup, lane limits checked once per group of rows); its set-up (tables, buffers) is compiled too.
Planes arrive contiguous (``metraw.codec`` makes each CFA plane's dither and symbols as its own
array): the vectorised passes need that.
"""

from __future__ import annotations

import struct
from typing import Callable, NamedTuple

import numba as nb
import numpy as np

from metraw.codec import model, native, scratch
from metraw.codec.container import put_varint
from metraw.codec.decoder import (  # noqa: F401  (the format's constants; decode_planes re-exported)
    _HEAD, COEF_BITS, FRAC, MAX_NACT, MAX_RESID, NPH, NTAP, PROB_BITS, PROB_SCALE, RANS_L, _normalise, decode_planes,
    predictor_table,
    fixed_point)

SHARED_BELOW = 1 << 16         # tiles with fewer pixels share one model across their planes
LANES = 16                     # rANS lanes (row classes) for tiles of >= SHARED_BELOW pixels (see the module docstring)


@nb.njit(cache=True, nogil=True)
def _sum(s):
    """Exact sum of an integer plane (int64)."""
    t = np.int64(0)
    h, w = s.shape
    for y in range(h):
        for x in range(w):
            t += s[y, x]
    return t


@nb.njit(cache=True, nogil=True)
def _front(s, u, c0):
    """Causally padded buffer (h+2, w+4) of fixed-point reconstructions s 2^16 - floor(u 2^16).

    Padding: rows above the plane hold ``c0``; the two columns left of row y repeat the first
    pixel of row y-1, the two right of it the last pixel of row y (the decoder builds the same)."""
    h, w = s.shape
    p = np.full((h + 2, w + 4), c0, np.int64)
    for y in range(h):
        for x in range(w):
            p[y + 2, x + 2] = (np.int64(s[y, x]) << 16) - fixed_point(u[y, x])
        if y > 0:
            p[y + 2, 0] = p[y + 1, 2]
            p[y + 2, 1] = p[y + 1, 2]
        p[y + 2, w + 2] = p[y + 2, w + 1]
        p[y + 2, w + 3] = p[y + 2, w + 1]
    return p


@nb.njit(cache=True, nogil=True)
def _mean_symbol(s):
    """c0 = round(mean symbol) of a plane (0 for an empty one): the value of the rows above it."""
    return np.int64(np.rint(_sum(s) / s.size)) if s.size else np.int64(0)


@nb.njit(cache=True, nogil=True)
def _front_c0(s, u):
    """The plane's padded buffer (``_front``) with rows above it at c0 = round(mean symbol); returns
    (front, c0). c0 is stored in the stream: the decoder pads with the same value."""
    c0 = _mean_symbol(s)
    return _front(s, u, c0 << 16), c0


@nb.njit(cache=True, nogil=True)
def _residuals(p, thr, coef, bias, tab0, pshift, r_out, t_out, off):
    """Residuals r (phase folded) and table indices of one plane (its padded buffer ``p``, which holds
    the symbols) into flat outputs at ``off``.

    Row by row in passes without a sequential dependence (every neighbour is known to the
    encoder), so they vectorise; the integer arithmetic is that of ``decoder.decode_pixel``.
    Returns max |r|."""
    h, w = p.shape[0] - 2, p.shape[1] - 4
    half = np.int64(1 << 15)
    rmax = np.int64(0)
    nthr = thr.size
    act = np.empty(w, np.int64)
    ctx = np.empty(w, np.int64)
    acc = np.empty(w, np.int64)
    nact = nthr + 1
    coef12 = np.empty(nact * 13, np.int64)  # per context: the 11 coefficients, their sum, the bias
    for c in range(nact):
        tot = np.int64(0)
        for i in range(11):
            coef12[c * 13 + i] = coef[c * 11 + i]
            tot += coef[c * 11 + i]
        coef12[c * 13 + 11] = tot
        coef12[c * 13 + 12] = bias[c]
    ws = np.int64(w + 4)
    pf = p.reshape(-1)
    U = np.uint64
    for y in range(h):
        b0 = (y + 2) * ws + 2  # flat index of the row's first pixel; unsigned indices: no wrap-around code
        for x in range(w):
            b = b0 + x
            w_ = pf[U(b - 1)]
            n_ = pf[U(b - ws)]
            nw = pf[U(b - ws - 1)]
            act[U(x)] = (abs(w_ - nw) + abs(n_ - nw) + abs(n_ - pf[U(b - ws + 1)]) + abs(w_ - pf[U(b - 2)])
                         + abs(n_ - pf[U(b - 2 * ws)]))
            ctx[U(x)] = 0
        for i in range(nthr):
            ti = thr[i]
            for x in range(w):
                ctx[U(x)] += act[U(x)] > ti
        for x in range(w):
            b = b0 + x
            o = ctx[U(x)] * 13
            # sum_i k_i (n_i - W) = sum_i k_i n_i - W sum_i k_i (exact integers, as in ``decoder.decode_pixel``)
            a = (coef12[U(o)] * pf[U(b - ws)] + coef12[U(o + 1)] * pf[U(b - ws - 1)]
                 + coef12[U(o + 2)] * pf[U(b - ws + 1)] + coef12[U(o + 3)] * pf[U(b - 2)]
                 + coef12[U(o + 4)] * pf[U(b - 2 * ws)] + coef12[U(o + 5)] * pf[U(b - ws - 2)]
                 + coef12[U(o + 6)] * pf[U(b - 2 * ws - 1)] + coef12[U(o + 7)] * pf[U(b - 2 * ws + 1)]
                 + coef12[U(o + 8)] * pf[U(b - ws + 2)] + coef12[U(o + 9)] * pf[U(b - 2 * ws - 2)]
                 + coef12[U(o + 10)] * pf[U(b - 2 * ws + 2)] - coef12[U(o + 11)] * pf[U(b - 1)])
            acc[U(x)] = pf[U(b - 1)] + (a >> 12) + coef12[U(o + 12)]
        k = off + y * w
        for x in range(w):
            c = ctx[U(x)]
            pv = pf[U(b0 + x)]
            # p = s 2^16 - floor(u 2^16) with floor(u 2^16) in [-2^15, 2^15): the symbol and the dither term
            sv = (pv + 32767) >> 16
            mh = acc[U(x)] + ((sv << 16) - pv) + half
            r = sv - (mh >> 16)
            fr = mh & 0xFFFF
            f = 1 - (fr >> 15)              # 1 when t < 0: fold (r, t) -> (-r, -t)
            fr ^= -f & 0xFFFF
            r = (r ^ -f) + f
            r_out[U(k + x)] = r
            t_out[U(k + x)] = tab0 + c * (4 >> pshift) + (((fr >> 13) & 3) >> pshift)
            rmax = max(rmax, abs(r))
    return rmax


@nb.njit(cache=True, nogil=True)
def _index(r, t, amax, ntab):
    """Alphabet indices (escape = 2 amax + 1) and per-table counts."""
    alpha = 2 * amax + 2
    esc_i = alpha - 1
    idx = np.empty(r.size, np.int32)
    counts = np.zeros((ntab, alpha), np.int64)
    for i in range(r.size):
        v = r[i]
        j = esc_i if (v < -amax or v > amax) else v + amax
        idx[i] = j
        counts[t[i], j] += 1
    return idx, counts


@nb.njit(cache=True, nogil=True)
def _lane_rows(hs, ws, nl):
    """Rows of each lane (lane j = rows j, j + nl, ... of every plane in turn, planes concatenated
    row-major): flat start and length of every row, lane by lane; returns (row_start, row_len,
    lane_row_starts, lane_symbol_starts)."""
    nrows = 0
    for k in range(hs.size):
        nrows += hs[k]
    rs = np.empty(nrows, np.int64)
    rl = np.empty(nrows, np.int64)
    lr = np.zeros(nl + 1, np.int64)
    ls = np.zeros(nl + 1, np.int64)
    m = 0
    n = 0
    for j in range(nl):
        off = 0
        for k in range(hs.size):
            for y in range(j, hs[k], nl):
                rs[m] = off + y * ws[k]
                rl[m] = ws[k]
                n += ws[k]
                m += 1
            off += hs[k] * ws[k]
        lr[j + 1] = m
        ls[j + 1] = n
    return rs, rl, lr, ls


@nb.njit(cache=True, nogil=True)
def _lane_escapes(r, idx, rs, rl, lr, esc_i):
    """Escaped residuals in decoding order, lane by lane; returns (values, count per lane)."""
    nl = lr.size - 1
    m = 0
    for i in range(idx.size):
        m += idx[i] == esc_i
    out = np.empty(m, np.int32)
    cnt = np.zeros(nl, np.int64)
    if m == 0:
        return out, cnt
    m = 0
    for j in range(nl):
        for q in range(lr[j], lr[j + 1]):
            for i in range(rs[q], rs[q] + rl[q]):
                if idx[i] == esc_i:
                    out[m] = np.int32(r[i])
                    m += 1
                    cnt[j] += 1
    return out, cnt


@nb.njit(cache=True, nogil=True, inline="always")
def _enc_symbol(idx, tab, alpha, freq, cum, rcp, out, o, nw, x, i):
    """Push symbol ``i`` onto a lane's rANS state ``x`` (words at ``out[o:]``, ``nw`` so far). ``freq``,
    ``cum``, ``rcp``: flat (table, symbol) arrays, ``alpha`` symbols per table; unsigned indices (no
    wrap-around code)."""
    U = np.uint64
    j = U(np.int64(tab[U(i)]) * alpha + idx[U(i)])
    f = U(freq[j])
    emit = U(x >= (f << U(32 - PROB_BITS)))
    out[U(o + nw)] = np.uint16(x & U(0xFFFF))
    nw += np.int64(emit)
    x >>= emit << U(4)
    q = U(np.float64(x) * rcp[j] + 1.52587890625e-05)
    return (q << U(PROB_BITS)) + (x - q * f) + U(cum[j]), nw


@nb.njit(cache=True, nogil=True, inline="always")
def _enc_cursor(i, e, q, rs, rl, more):
    """A lane's previous symbol: (flat index, first index of its row, row) walking backwards."""
    if i > e:
        return i - 1, e, q
    if more:
        r = q - 1
        return rs[r] + rl[r] - 1, rs[r], r
    return i, e, q


@nb.njit(cache=True, nogil=True)
def _rans_encode(idx, tab, freq, cum, rcp, rs, rl, lr, ls, out):
    """Encode lane j = the symbols of rows lr[j] .. lr[j + 1] - 1 (``_lane_rows``; tables ``tab``) into
    its own rANS stream, in reverse; lanes advance in lock step (independent dependency chains).
    Lane j's words go to ``out[ls[j]:]`` (room for one word per symbol). Returns (final states,
    word counts).

    x // f via the float64 reciprocal ``rcp`` = 1 / freq: exact for x < 2^32 and f <= 2^12
    (rounding error < 2^-19, the fraction of x / f is 0 or >= 2^-12)."""
    nl = lr.size - 1
    alpha = np.int64(freq.shape[1])
    freqf, cumf, rcpf = freq.reshape(-1), cum.reshape(-1), rcp.reshape(-1)
    xs = np.full(nl, RANS_L, np.uint64)
    nws = np.zeros(nl, np.int64)
    cq = np.empty(nl, np.int64)   # current row of each lane (walking backwards)
    ci = np.empty(nl, np.int64)   # current flat index
    ce = np.empty(nl, np.int64)   # first flat index of the current row
    longest = 0
    for j in range(nl):
        longest = max(longest, ls[j + 1] - ls[j])
        q = lr[j + 1] - 1
        cq[j] = q
        if q >= lr[j]:
            ci[j] = rs[q] + rl[q] - 1
            ce[j] = rs[q]
    shortest = longest
    for j in range(nl):
        shortest = min(shortest, ls[j + 1] - ls[j])
    lo = shortest if nl % 4 == 0 else 0
    for k in range(longest - 1, lo - 1, -1):
        for j in range(nl):
            if k >= ls[j + 1] - ls[j]:
                continue
            i = ci[j]
            x, nw = _enc_symbol(idx, tab, alpha, freqf, cumf, rcpf, out, ls[j], nws[j], xs[j], i)
            xs[j] = x
            nws[j] = nw
            ci[j], ce[j], cq[j] = _enc_cursor(i, ce[j], cq[j], rs, rl, k > 0)
    for g in range(0, nl if lo > 0 else 0, 4):
        # every lane active: 4 lanes at a time (the lanes' streams are independent), their states in registers
        x0, x1, x2, x3 = xs[g], xs[g + 1], xs[g + 2], xs[g + 3]
        n0, n1, n2, n3 = nws[g], nws[g + 1], nws[g + 2], nws[g + 3]
        i0, i1, i2, i3 = ci[g], ci[g + 1], ci[g + 2], ci[g + 3]
        e0, e1, e2, e3 = ce[g], ce[g + 1], ce[g + 2], ce[g + 3]
        q0, q1, q2, q3 = cq[g], cq[g + 1], cq[g + 2], cq[g + 3]
        o0, o1, o2, o3 = ls[g], ls[g + 1], ls[g + 2], ls[g + 3]
        for k in range(lo - 1, -1, -1):
            more = k > 0
            x0, n0 = _enc_symbol(idx, tab, alpha, freqf, cumf, rcpf, out, o0, n0, x0, i0)
            x1, n1 = _enc_symbol(idx, tab, alpha, freqf, cumf, rcpf, out, o1, n1, x1, i1)
            x2, n2 = _enc_symbol(idx, tab, alpha, freqf, cumf, rcpf, out, o2, n2, x2, i2)
            x3, n3 = _enc_symbol(idx, tab, alpha, freqf, cumf, rcpf, out, o3, n3, x3, i3)
            i0, e0, q0 = _enc_cursor(i0, e0, q0, rs, rl, more)
            i1, e1, q1 = _enc_cursor(i1, e1, q1, rs, rl, more)
            i2, e2, q2 = _enc_cursor(i2, e2, q2, rs, rl, more)
            i3, e3, q3 = _enc_cursor(i3, e3, q3, rs, rl, more)
        xs[g], xs[g + 1], xs[g + 2], xs[g + 3] = x0, x1, x2, x3
        nws[g], nws[g + 1], nws[g + 2], nws[g + 3] = n0, n1, n2, n3
    return xs, nws


@nb.njit(cache=True, nogil=True)
def _plane_symbol_bits(idx, tab, freq, bounds, esc_i):
    """Ideal code length [bits] of each plane's symbols under the coding tables: sum of
    -log2(freq / 2^PROB_BITS) (what rANS achieves to within its final state) plus 32 bits per
    escaped residual (stored as int32). Plane k holds flat symbols ``bounds[k]:bounds[k + 1]``."""
    n = bounds.size - 1
    out = np.zeros(n)
    for k in range(n):
        acc = 0.0
        for i in range(bounds[k], bounds[k + 1]):
            sy = idx[i]
            acc += PROB_BITS - np.log2(np.float64(freq[tab[i], sy]))
            if sy == esc_i:
                acc += 32.0
        out[k] = acc
    return out


class LazyBuffer(NamedTuple):
    """A plane's causal buffer made only when the coder reaches the plane: its (rows, columns) and a function giving
    (front, c0). With per-plane models, each plane is then made, fitted and passed over before the next one is made
    (one buffer in cache at a time instead of a tile's)."""

    shape: tuple[int, int]
    make: Callable[[], tuple[np.ndarray, int]]


def _plane_shape(buffer) -> tuple[int, int]:
    return buffer.shape if isinstance(buffer, LazyBuffer) else buffer_shape(buffer[0])


def _made(buffer, on_buffer) -> tuple[np.ndarray, int]:
    """(front, c0) of a buffer or a ``LazyBuffer``, shown to ``on_buffer`` (if given) once made."""
    front, c0 = buffer.make() if isinstance(buffer, LazyBuffer) else buffer
    if on_buffer is not None:
        on_buffer(front)
    return front, c0


def buffer_shape(front: np.ndarray) -> tuple[int, int]:
    """The plane's (rows, columns) of its causal buffer ``front`` ((h + 2) x (w + 4): two rows above, two columns each
    side)."""
    return front.shape[0] - 2, front.shape[1] - 4


def _causal_buffer(s, u):
    """(front, c0) of ``_front_c0``: the buffer in C where ``metraw.codec.native`` is built and the plane is
    contiguous int32 symbols with a float64 dither, else in numba."""
    if native.LIB is not None and s.dtype == np.int32 and s.flags.c_contiguous and u.dtype == np.float64 \
            and u.flags.c_contiguous:
        c0 = _mean_symbol(s)
        return native.front(s, u, c0), c0
    return _front_c0(s, u)


def _code_section(r, t, amax, ntab, shared, hs, ws, nl):
    """Entropy-code the residuals ``r`` with table indices ``t`` (planes concatenated row-major,
    shapes ``hs`` x ``ws``) in ``nl`` rANS lanes, in four compiled calls (each without the GIL): the
    alphabet indices and counts and the rANS pass (C where ``metraw.codec.native`` is built, the rANS
    pass where nl is a multiple of 8; else numba; the same values), the tables, the escapes and stored
    tables. Shared sections code with 8-bit tables
    (frequencies / 16, ``_normalise``d again; both sides use the same integers).

    Returns (idx, coding freq, table bytes, bytes per table, lane states, lane word counts, words,
    word starts per lane, escape values, escapes per lane); idx (where compiled) and words are the thread's
    ``scratch`` arrays, valid until its next section."""
    if native.LIB is not None:
        idx, counts = native.index(r, t, amax, ntab, scratch.empty("idx", r.size, np.int32))
    else:
        idx, counts = _index(r, t, amax, ntab)
    freq, stored, cum, rcp, rs, rl, lr, starts = _section_tables(counts, shared, hs, ws, nl)
    # one word per symbol, and one the compiled pass may write past the last
    out = scratch.empty("words", r.size + 1, np.uint16)
    if native.LIB is not None and nl % 8 == 0:
        states, nws = native.rans_encode(idx, t, freq, cum, rcp, rs, rl, lr, starts, out)
    else:
        states, nws = _rans_encode(idx, t, freq, cum, rcp, rs, rl, lr, starts, out)
    esc_vals, esc_cnt, tab_bytes, tab_len = _section_escapes_and_tables(r, idx, stored, rs, rl, lr, amax, shared)
    return idx, freq, tab_bytes, tab_len, states, nws, out, starts, esc_vals, esc_cnt


@nb.njit(cache=True, nogil=True)
def _section_tables(counts, shared, hs, ws, nl):
    """``_code_section``'s tables from the symbol counts (``_index``): coding and stored frequencies,
    cumulative frequencies and reciprocals (the rANS tables), and the lanes' rows (``_lane_rows``)."""
    freq = _normalise(counts)
    stored = freq
    if shared:
        stored = np.zeros_like(freq)
        for i in range(freq.shape[0]):
            for j in range(freq.shape[1]):
                if freq[i, j] > 0:
                    stored[i, j] = min(max((freq[i, j] + 8) >> 4, 1), 255)
        freq = _normalise(stored)
    ntab_, alpha = freq.shape
    cum = np.zeros((ntab_, alpha), np.int64)
    rcp = np.empty((ntab_, alpha))
    for i in range(ntab_):
        acc = np.int64(0)
        for j in range(alpha):
            cum[i, j] = acc
            acc += freq[i, j]
            rcp[i, j] = 1.0 / max(freq[i, j], 1)
    rs, rl, lr, starts = _lane_rows(hs, ws, nl)
    return freq, stored, cum, rcp, rs, rl, lr, starts


@nb.njit(cache=True, nogil=True)
def _section_escapes_and_tables(r, idx, stored, rs, rl, lr, amax, shared):
    """``_code_section``'s last part: the escaped residuals lane by lane, and the stored tables' bytes
    (8-bit entries where the section shares one model)."""
    esc_vals, esc_cnt = _lane_escapes(r, idx, rs, rl, lr, 2 * amax + 1)
    ntab_, alpha = stored.shape
    # tables: u16 first, u16 span, then the used range (u8 or u16 little endian); unused: span 0
    width = 1 if shared else 2
    tab_bytes = np.zeros(ntab_ * (4 + width * alpha), np.uint8)
    tab_len = np.zeros(ntab_, np.int64)
    n = 0
    for i in range(ntab_):
        first = 0
        while first < alpha and stored[i, first] == 0:
            first += 1
        last = alpha - 1
        while last >= first and stored[i, last] == 0:
            last -= 1
        span = last - first + 1 if first < alpha else 0
        start = n
        if span == 0:
            first = 0
        tab_bytes[n] = first & 0xFF
        tab_bytes[n + 1] = first >> 8
        tab_bytes[n + 2] = span & 0xFF
        tab_bytes[n + 3] = span >> 8
        n += 4
        for j in range(first, first + span):
            v = stored[i, j]
            tab_bytes[n] = v & 0xFF
            if width == 2:
                tab_bytes[n + 1] = v >> 8
            n += width
        tab_len[i] = n - start
    return esc_vals, esc_cnt, tab_bytes[:n], tab_len


def encode_planes(planes: list[tuple[np.ndarray, np.ndarray]], account: list | None = None) -> bytes:
    """Code planes given as (symbols int32, dither float in [-1/2, 1/2)) pairs into one section: ``encode_buffers``
    of their causal buffers (``_causal_buffer``)."""
    return encode_buffers([_causal_buffer(s, u) for s, u in planes], account)


def encode_buffers(buffers: list, account: list | None = None, on_buffer=None) -> bytes:
    """Code planes given by their causal buffers, (front, c0) pairs (``_causal_buffer``, or straight from the DN by
    ``native.plane_buffer``; front (h + 2) x (w + 4) int64) or ``LazyBuffer``s, into one section. ``on_buffer(front)``
    (if given) sees each plane's front once made.

    Tiles of >= ``SHARED_BELOW`` pixels: per-plane models, ``model.n_activity_contexts`` contexts x
    ``NPH`` phase bins, 12-bit tables, ``LANES`` rANS lanes. Smaller tiles: one model for all planes,
    8-bit tables, and the smallest of (1, 1), (1, NPH), (2, NPH) (activity contexts, phase bins).

    ``account``: if a list, it receives each plane's share of the section [bits], summing to
    8 len(section): the plane's ideal code length (``_plane_symbol_bits``), plus its group's side
    information (predictor, thresholds, tables; split by pixels where planes share a model), plus
    a share of the common overhead (plane header, rANS flush) proportional to its code length."""
    sizes = [h * w for h, w in map(_plane_shape, buffers)]
    if sum(sizes) >= SHARED_BELOW:
        return _encode_planes(buffers, False, model.n_activity_contexts(min(sizes)), 0, account, on_buffer=on_buffer)
    buffers = [_made(b, on_buffer) for b in buffers]   # one model for all planes: every plane at once
    best, best_acc = None, None
    memo = {}  # the candidates share buffers, activities and (same nact) the whole model
    for nact, pshift in ((1, 2), (1, 0), (2, 0)):
        if nact > 1 and sum(sizes) < 2048:
            continue
        acc = [] if account is not None else None
        blob = _encode_planes(buffers, True, nact, pshift, acc, memo)
        if best is None or len(blob) < len(best):
            best, best_acc = blob, acc
    if account is not None:
        account[:] = best_acc
    return best


def _shared_model(buffers, nact: int, memo: dict):
    """One model for all planes (small tiles; ``buffers`` their (front, c0)): (c0 per plane, [(front, thr, coef, bias,
    tab0)] per plane). ``memo`` keeps the activity samples and each nact's model for the other candidate layouts of
    the same planes (``encode_buffers`` tries several)."""
    fronts = [f for f, _ in buffers]
    c0s = [int(c0) for _, c0 in buffers]
    if "acts" not in memo:
        stride = model.ls_stride(sum(h * w for h, w in map(buffer_shape, fronts)))
        memo["acts"] = stride, np.concatenate([model.activity_samples(f, 2 * stride) for f in fronts])
    stride, acts = memo["acts"]
    if nact not in memo:
        thr = model.thresholds(acts, nact)
        ata = np.zeros((nact, NTAP, NTAP))
        atb = np.zeros((nact, NTAP))
        for f in fronts:
            model.normal_equations(f, thr, stride, ata, atb)
        coef, bias = model.fit(ata, atb)
        memo[nact] = [(f, thr, coef, bias, 0) for f in fronts]
    return c0s, memo[nact]


def _encode_planes(buffers, shared: bool, nact: int, pshift: int, account: list | None = None,
                   memo: dict | None = None, on_buffer=None) -> bytes:
    """One section of the planes of causal ``buffers`` with the given model layout (``memo``: see ``_shared_model``;
    ``buffers`` made already where ``shared``, else possibly ``LazyBuffer``s, made plane by plane, ``on_buffer``: see
    ``encode_buffers``). The numerical work runs in a few compiled calls that release the GIL (per plane
    ``model.model_of_front`` and the residual pass, then ``_code_section``), so row tiles coded in parallel threads
    seldom wait for each other."""
    npl = len(buffers)
    shapes = [_plane_shape(b) for b in buffers]
    sizes = [h * w for h, w in shapes]
    total = sum(sizes)
    nph = NPH >> pshift
    ntab = (1 if shared else npl) * nact * nph
    r_all = scratch.empty("residuals", total, np.int32)
    t_all = scratch.empty("tables", total, np.int32)
    c0s, heads = [], []   # heads: each model group's (thr, coef, bias)
    rmax = 0

    def residual_pass(front, thr, coef, bias, tab0, off) -> int:
        if native.LIB is not None:
            return native.residuals(front, thr, predictor_table(coef, bias), tab0, pshift, r_all, t_all, off)
        return int(_residuals(front, thr, coef, bias, tab0, pshift, r_all, t_all, off))

    offsets = [0, *np.cumsum(sizes[:-1]).tolist()]   # each plane's first residual
    if shared:  # one model for all planes: activities and normal equations pooled over the planes
        c0s, models = _shared_model(buffers, nact, {} if memo is None else memo)
        heads.append(models[0][1:4])
        for off, (front, thr, coef, bias, tab0) in zip(offsets, models):
            rmax = max(rmax, residual_pass(front, thr, coef, bias, tab0, off))
    else:   # plane by plane: its buffer made, its model fitted and its residuals taken while the buffer is in cache
        for k, (b, n, off) in enumerate(zip(buffers, sizes, offsets)):
            front, c0 = _made(b, on_buffer)
            c0s.append(int(c0))
            thr, coef, bias = model.model_of_front(front, nact, model.ls_stride(n))
            heads.append((thr, coef, bias))
            rmax = max(rmax, residual_pass(front, thr, coef, bias, k * nact * nph, off))
            del front   # not kept: the next plane's buffer is made without it
    group_heads = [(thr >> 8).astype("<u4").tobytes() + coef.astype("<i2").tobytes()
                   + np.clip(bias, -2**31, 2**31 - 1).astype("<i4").tobytes() for thr, coef, bias in heads]
    amax = int(min(MAX_RESID, max(1, rmax)))
    nl = 1 if shared else LANES
    (idx, freq, tab_bytes, tab_len, states, nws, out, starts, esc_vals,
     esc_cnt) = _code_section(r_all, t_all, amax, max(ntab, 1), shared,
                              np.array([h for h, _ in shapes], np.int64),
                              np.array([w for _, w in shapes], np.int64), nl)
    parts = [_HEAD.pack(npl, nact, pshift, int(shared), nl, 8 if shared else 16, amax)]
    for j in range(nl):
        parts.append(struct.pack("<I", int(states[j])))
        put_varint(parts, int(nws[j]))
        put_varint(parts, int(esc_cnt[j]))
    for c0 in c0s:
        put_varint(parts, 2 * c0 if c0 >= 0 else -2 * c0 - 1)
    parts += group_heads
    parts.append(tab_bytes.tobytes())
    parts += [out[starts[j]:starts[j] + nws[j]].astype("<u2").tobytes() for j in range(nl)]
    parts.append(esc_vals.astype("<i4").tobytes())
    blob = b"".join(parts)
    if account is not None:
        groups = [list(range(npl))] if shared else [[k] for k in range(npl)]
        account[:] = _account(sizes, groups, idx, t_all, freq, 2 * amax + 1, group_heads, tab_len.tolist(),
                              nact * nph, len(blob))
    return blob


def _account(sizes, groups, idx, t_all, freq, esc_i, group_heads, tables, tabs_per_group, nbytes) -> list[float]:
    """Per-plane bits of a section (see ``encode_buffers``; ``sizes`` the planes' pixel counts); they sum to 8
    ``nbytes``. ``tables``: bytes of each coding table as stored."""
    sizes = np.array(sizes, np.int64)
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    bits = _plane_symbol_bits(idx, t_all, freq, bounds, esc_i)
    side = np.zeros(sizes.size)
    for gi, g in enumerate(groups):
        gbits = 8.0 * (len(group_heads[gi]) + sum(tables[gi * tabs_per_group:(gi + 1) * tabs_per_group]))
        gpix = sizes[g].sum()
        for k in g:
            side[k] += gbits * (sizes[k] / gpix if gpix else 1.0 / len(g))
    rest = 8.0 * nbytes - bits.sum() - side.sum()
    w = bits / bits.sum() if bits.sum() > 0 else np.full(sizes.size, 1.0 / sizes.size)
    return list(bits + side + rest * w)
