"""Decoder of the sections ``metraw.codec.predictive`` writes, and the format's constants.

``decode_planes`` parses a section (plane header, predictors, frequency tables, lane words and
escapes, all in compiled code where it loops) and runs the per-pixel loop (compiled, ``nogil``).

Lane j of a section holds rows j, j + L, ... of a plane (L = 16 lanes for large tiles since 2026-11-28, 8 earlier
that day, 4 before; the header says which) and runs 3 pixels behind lane j - 1, so its causal neighbours are ready
and the dependency chains overlap. The arithmetic is the encoder's (``predictive._residuals``) to the bit. Streams of
8 or 16 lanes decode in the compiled C loop where it is built and the CPU has AVX-512 (``metraw.codec.native``: 8
lanes of a row group side by side in one vector register, 16 in two), else, and for other lane counts, in
``decode_plane`` here (numba, groups of 4 rows).

Speed: every array access uses an unsigned index (a cast of the signed one: free) so numba emits
no negative-index wrap-around (a compare and a select per index, ~30 indexings per pixel); the
padded buffer, tables and lookup are read through flat 1-D views with precomputed offsets. In the
per-pixel step no array is sliced and no branch touches an array (numba would count references
there, an atomic operation per pixel).
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numba as nb
import numpy as np
from numba.core import types
from numba.extending import overload

from metraw.codec import native
from metraw.codec.container import get_varint
from metraw.errors import MetrawError

PROB_BITS = 12                 # rANS probability resolution
PROB_SCALE = 1 << PROB_BITS
RANS_L = 1 << 16
FRAC = 16                      # fixed-point bits of reconstructed values
COEF_BITS = 12                 # fractional bits of the predictor coefficients (int16 storage)
NPH = 4                        # folded dither-phase bins per activity context
MAX_NACT = 8                   # activity contexts per group, at most
NTAP = 12                      # W + 11 differences (n_i - W); the 12th LS unknown is the bias
MAX_RESID = 1023
_HEAD = struct.Struct("<BBBBBBH")  # nplanes, nact, phase shift, shared, lanes, table bits, amax
# then per lane: u32 final state, varint words, varint escapes; then per plane zigzag-varint c0


@nb.njit(cache=True, nogil=True, inline="always")
def _u(i):
    return np.uint64(i)


#: Largest activity-context table (entries): thresholds up to CTAB_MAX - 2 (x 2^8) use it, larger ones compares.
CTAB_MAX = 1 << 15


def predictor_table(coef, bias) -> np.ndarray:
    """Per activity context the 11 coefficients, their sum and the bias ((nact, 13) int64): the predictor as the
    per-pixel loops read it (sum_i k_i (n_i - W) = sum_i k_i n_i - W sum_i k_i)."""
    c11 = np.asarray(coef, np.int64).reshape(-1, NTAP - 1)
    return np.concatenate([c11, c11.sum(1, keepdims=True), np.asarray(bias, np.int64).reshape(-1, 1)], 1)


def context_table(thr: np.ndarray) -> np.ndarray | None:
    """Table of the activity context c = #{i: act > thr_i} (thresholds multiples of 2^8, as stored)
    by k = min(((act - 1) >> 8) + 1, size - 1): act > 2^8 T <=> (act - 1) >> 8 >= T for act >= 0, so
    entry k counts the T_i <= k - 1, exact up to the largest threshold. None when that table would
    exceed ``CTAB_MAX`` entries (the decoder then compares)."""
    t = np.sort(np.asarray(thr, np.int64) >> 8)
    n = int(t[-1]) + 2 if t.size else 1
    if n > CTAB_MAX:
        return None
    return np.searchsorted(t, np.arange(n, dtype=np.int64) - 1, side="right").astype(np.uint8)


def _context(act, thr, ctab):
    """Activity context (compiled only: see the overload)."""
    raise NotImplementedError


@overload(_context, inline="always")
def _context_impl(act, thr, ctab):
    if isinstance(ctab, types.NoneType):
        def compare(act, thr, ctab):
            return ((act > thr[0]) + (act > thr[1]) + (act > thr[2]) + (act > thr[3]) + (act > thr[4])
                    + (act > thr[5]) + (act > thr[6]))
        return compare

    def lookup(act, thr, ctab):
        # unsigned min: a negative key (act wrapped around on a corrupt stream's huge values) also
        # lands on the last entry, so no stream can index outside the table
        return np.int64(ctab[min(np.uint64(((act - 1) >> 8) + 1), np.uint64(ctab.size - 1))])
    return lookup


@nb.njit(cache=True, nogil=True, inline="always")
def _pixel(pf, b, ws, w_, ww, uv, thr, ctab, coef, tab0, pshift, lut, fcum, alpha, amax, words, x, pos, esc, epos):
    """Decode the pixel at flat index ``b`` of the padded buffer ``pf`` (row stride ``ws``; its left
    neighbours ``w_`` = pf[b - 1] and ``ww`` = pf[b - 2] passed in: a lane keeps them in registers, off
    the store-to-load path) from one lane, without checking the lane's word and escape positions;
    returns (its buffer value pf[b], x, pos, epos). ``coef``: per context the 11 coefficients, their sum
    and the bias."""
    half = np.int64(1 << 15)
    n_ = pf[_u(b - ws)]
    nw = pf[_u(b - ws - 1)]
    ne = pf[_u(b - ws + 1)]
    nn = pf[_u(b - 2 * ws)]
    act = abs(w_ - nw) + abs(n_ - nw) + abs(n_ - ne) + abs(w_ - ww) + abs(n_ - nn)
    c = _context(act, thr, ctab)
    o = c * 13
    # sum_i k_i (n_i - W) = sum_i k_i n_i - W sum_i k_i (exact integers: the encoder's value)
    acc = (coef[_u(o)] * n_ + coef[_u(o + 1)] * nw + coef[_u(o + 2)] * ne + coef[_u(o + 3)] * ww
           + coef[_u(o + 4)] * nn + coef[_u(o + 5)] * pf[_u(b - ws - 2)] + coef[_u(o + 6)] * pf[_u(b - 2 * ws - 1)]
           + coef[_u(o + 7)] * pf[_u(b - 2 * ws + 1)] + coef[_u(o + 8)] * pf[_u(b - ws + 2)]
           + coef[_u(o + 9)] * pf[_u(b - 2 * ws - 2)] + coef[_u(o + 10)] * pf[_u(b - 2 * ws + 2)]
           - coef[_u(o + 11)] * w_)
    mh = w_ + (acc >> 12) + coef[_u(o + 12)] + uv + half
    sh = mh >> 16
    fr = mh & 0xFFFF
    f = 1 - (fr >> 15)
    t = tab0 + c * (4 >> pshift) + ((((fr ^ (-f & 0xFFFF)) >> 13) & 3) >> pshift)
    slot = np.int64(x & np.uint64(PROB_SCALE - 1))
    s = np.int64(lut[_u((t << PROB_BITS) + slot)])
    fc = np.int64(fcum[_u(t * alpha + s)])
    x = np.uint64(fc >> 16) * (x >> np.uint64(PROB_BITS)) + np.uint64(slot - (fc & 0xFFFF))
    # renormalise without a data-dependent branch: words[pos] is the next word (or a pad)
    need = np.uint64(x < np.uint64(RANS_L))
    x = (x << (need << np.uint64(4))) | (np.uint64(words[_u(pos)]) * need)
    pos -= np.int64(need)
    # escape: the residual is the lane's next escape value, branch-free: esc[epos] is always readable
    is_esc = s == 2 * amax + 1
    ev = np.int64(esc[_u(epos)])
    r = ev if is_esc else s - amax
    epos += np.int64(is_esc)
    v = sh + ((r ^ -f) + f)
    pv = (v << 16) - uv
    pf[_u(b)] = pv
    return pv, x, pos, epos


@nb.njit(cache=True, nogil=True, inline="always")
def decode_pixel(pf, b, ws, uv, thr, ctab, coef, tab0, pshift, lut, fcum, alpha, amax, words, x, pos, pmin, esc,
                 epos, eend):
    """``_pixel`` with the lane's limits checked: returns (x, pos, epos, ok), ok false once the lane has
    used a word below ``pmin`` (its pad) or an escape at or past ``eend``."""
    _, x, pos, epos = _pixel(pf, b, ws, pf[_u(b - 1)], pf[_u(b - 2)], uv, thr, ctab, coef, tab0, pshift, lut, fcum,
                                alpha, amax, words, x, pos, esc, epos)
    return x, pos, epos, (pos >= pmin) & (epos <= eend)


@nb.njit(cache=True, nogil=True, inline="always")
def _u16(u, y, x):
    """floor(u 2^16) of the dither at (y, x), from the plane's ``fixed_dither``."""
    return np.int64(u[_u(y), _u(x)])


@nb.njit(cache=True, nogil=True, inline="always")
def fixed_point(u):
    """floor(u 2^16) of a dither value u in [-1/2, 1/2): the fixed-point dither of the stream's integer
    prediction (encoder and decoder)."""
    return np.int64(np.floor(u * 65536.0))


@nb.njit(cache=True, nogil=True)
def fixed_dither(u):
    """``fixed_point`` of a dither plane (int32)."""
    out = np.empty(u.shape, np.int32)
    uf = u.reshape(-1)
    of = out.reshape(-1)
    for i in range(uf.size):
        of[i] = np.int32(fixed_point(uf[i]))
    return out


@nb.njit(cache=True, nogil=True)
def decode_plane(p, u, sym, thr, ctab, coef, tab0, pshift, lut, fcum, amax, words, xs, pos, pmin, esc, epos, eend):
    """Decode one plane into the padded buffer ``p`` (h + 2, w + 4) and the symbols ``sym`` (the
    plane's view of the tile, filled from the buffer after the per-pixel loop); ``u`` is the plane's dither
    in fixed point (``fixed_dither``: an integer load per pixel instead of float arithmetic); ``thr`` the 7 activity thresholds (padded)
    and ``ctab`` their ``context_table`` or None (compiled separately: compares instead of a lookup); ``coef``
    per context the 11 coefficients, their sum and the bias (one array: one base register less in the
    steady loop); ``lut`` (tables x 2^PROB_BITS) and
    ``fcum`` (tables x alphabet) C-contiguous. Updates the per-lane state ``xs``, word positions
    ``pos`` (lower limits ``pmin``) and escape positions ``epos`` (limits ``eend``) in place;
    returns ok. ``words`` must hold at least w readable pad words below each lane's ``pmin`` and
    ``esc`` at least w + 1 pad values after the last lane's escapes (the steady part checks the
    limits once per group of rows).

    Rows run in groups of 4 (of min(L, 4) where L = 1, 2, 3): with L = 8 or 16 lanes, a group of L rows is
    decoded as L / 4 groups of 4, one below the other (the lanes are in different rows, so any order that decodes
    every pixel after its causal neighbours gives the same values). Groups of 4 full rows run their steady part
    (every lane inside the row, no padding to write) with the lane states in local variables; edges and other
    groups take the general path."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    ws = np.int64(w + 4)
    pf = p.reshape(-1)
    lutf = lut.reshape(-1)
    fcf = fcum.reshape(-1)
    alpha = np.int64(fcum.shape[1])
    nl = xs.size
    sub = 4 if nl % 4 == 0 else nl
    for y0 in range(0, h, sub):
        l0 = y0 % nl  # the lane of row y0
        nr = min(sub, h - y0)
        fast = nr == 4 and w >= 12
        for xsw in range(w + 3 * (nr - 1)):
            if fast and xsw == 10:
                # steady part: xsw = 10 .. w - 2, lanes at x = xsw, xsw - 3, xsw - 6, xsw - 9
                a0, a1, a2, a3 = xs[l0], xs[l0 + 1], xs[l0 + 2], xs[l0 + 3]
                q0, q1, q2, q3 = pos[l0], pos[l0 + 1], pos[l0 + 2], pos[l0 + 3]
                e0, e1, e2, e3 = epos[l0], epos[l0 + 1], epos[l0 + 2], epos[l0 + 3]
                b0 = (y0 + 2) * ws + 2
                # each lane's two left neighbours, carried in registers along the row
                b = b0 + 10
                w0, ww0 = pf[_u(b - 1)], pf[_u(b - 2)]
                w1, ww1 = pf[_u(b + ws - 4)], pf[_u(b + ws - 5)]
                w2, ww2 = pf[_u(b + 2 * ws - 7)], pf[_u(b + 2 * ws - 8)]
                w3, ww3 = pf[_u(b + 3 * ws - 10)], pf[_u(b + 3 * ws - 11)]
                for xs_ in range(10, w - 1):
                    b = b0 + xs_
                    pv, a0, q0, e0 = _pixel(pf, b, ws, w0, ww0, _u16(u, y0, xs_), thr, ctab, coef, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a0, q0, esc, e0)
                    ww0 = w0
                    w0 = pv
                    pv, a1, q1, e1 = _pixel(pf, b + ws - 3, ws, w1, ww1, _u16(u, y0 + 1, xs_ - 3), thr, ctab, coef, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a1, q1, esc, e1)
                    ww1 = w1
                    w1 = pv
                    pv, a2, q2, e2 = _pixel(pf, b + 2 * ws - 6, ws, w2, ww2, _u16(u, y0 + 2, xs_ - 6), thr, ctab, coef, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a2, q2, esc, e2)
                    ww2 = w2
                    w2 = pv
                    pv, a3, q3, e3 = _pixel(pf, b + 3 * ws - 9, ws, w3, ww3, _u16(u, y0 + 3, xs_ - 9), thr, ctab, coef, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a3, q3, esc, e3)
                    ww3 = w3
                    w3 = pv
                # limits checked once per group: a lane uses at most one word and one escape per pixel, and
                # the caller pads the words before each lane and the escapes after the last (``decode_plane``)
                if not ((q0 >= pmin[l0]) & (q1 >= pmin[l0 + 1]) & (q2 >= pmin[l0 + 2]) & (q3 >= pmin[l0 + 3])
                        & (e0 <= eend[l0]) & (e1 <= eend[l0 + 1]) & (e2 <= eend[l0 + 2]) & (e3 <= eend[l0 + 3])):
                    return False
                xs[l0], xs[l0 + 1], xs[l0 + 2], xs[l0 + 3] = a0, a1, a2, a3
                pos[l0], pos[l0 + 1], pos[l0 + 2], pos[l0 + 3] = q0, q1, q2, q3
                epos[l0], epos[l0 + 1], epos[l0 + 2], epos[l0 + 3] = e0, e1, e2, e3
            if fast and 10 <= xsw <= w - 2:
                continue
            for j in range(nr):
                x0 = xsw - 3 * j
                if x0 < 0 or x0 >= w:
                    continue
                y = y0 + j
                yy = y + 2
                if x0 == 0 and y > 0:
                    p[yy, 0] = p[yy - 1, 2]
                    p[yy, 1] = p[yy - 1, 2]
                lj = l0 + j
                x, ps, ep, ok = decode_pixel(pf, yy * ws + x0 + 2, ws, _u16(u, y, x0), thr, ctab, coef, tab0, pshift,
                                                lutf, fcf, alpha, amax, words, xs[lj], pos[lj], pmin[lj], esc, epos[lj],
                                                eend[lj])
                if not ok:
                    return False
                xs[lj] = x
                pos[lj] = ps
                epos[lj] = ep
                if x0 == w - 1:
                    p[yy, w + 2] = p[yy, w + 1]
                    p[yy, w + 3] = p[yy, w + 1]
    # the symbols from the buffer, in a pass that vectorises: pf = s 2^16 - u16 with u16 in [-2^15, 2^15)
    for y in range(h):
        row = p[y + 2, 2:w + 2]
        uy = u[y]
        sy = sym[y]
        for x in range(w):
            sy[x] = (row[x] + uy[x]) >> 16
    return True


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
def _parse_tables(b, off, ntab, alpha, bytes8):
    """The section's ``ntab`` frequency tables from its bytes ``b`` at ``off``: per table u16 first,
    u16 span, then span frequencies (u8, ``_normalise``d again, or u16 little endian); span 0 is an
    unused table (escape only). Returns (freq, new offset, error: 0 ok, 1 truncated, 2 overrun,
    3 bad sum)."""
    freq = np.zeros((ntab, alpha), np.int64)
    q8 = np.zeros((1, alpha), np.int64)
    width = 1 if bytes8 else 2
    for t in range(ntab):
        if off + 4 > b.size:
            return freq, off, 1
        first = np.int64(b[off]) | (np.int64(b[off + 1]) << 8)
        span = np.int64(b[off + 2]) | (np.int64(b[off + 3]) << 8)
        off += 4
        if span == 0:
            freq[t, alpha - 1] = PROB_SCALE
            continue
        if first + span > alpha:
            return freq, off, 2
        if off + width * span > b.size:
            return freq, off, 1
        if bytes8:
            q8[0, :] = 0
            for j in range(span):
                q8[0, first + j] = b[off + j]
            f = _normalise(q8)
            for j in range(alpha):
                freq[t, j] = f[0, j]
        else:
            for j in range(span):
                freq[t, first + j] = np.int64(b[off + 2 * j]) | (np.int64(b[off + 2 * j + 1]) << 8)
        off += width * span
        tot = np.int64(0)
        for j in range(alpha):
            tot += freq[t, j]
        if tot != PROB_SCALE:
            return freq, off, 3
    return freq, off, 0


@nb.njit(cache=True, nogil=True)
def _decoding_tables(freq, sym_type):
    """The decoder's lookup tables: symbol by slot (tables x 2^PROB_BITS, ``sym_type``) and
    freq << 16 | cumulative frequency (tables x alphabet). A symbol's slots filled as one slice (a memset:
    canon_dng's 128 tables in 0.03 ms, not 0.25 filled slot by slot)."""
    ntab, alpha = freq.shape
    # one row more than the tables: the AVX-512 decoder's 32-bit gathers may read a few bytes past the last entry
    lut = np.empty((ntab + 1, PROB_SCALE), sym_type)
    lut[ntab, :] = 0
    fcum = np.empty((ntab, alpha), np.uint32)  # f <= 2^12, cum < 2^12: 32 bits (half the cache of int64)
    for t in range(ntab):
        c = 0
        for j in range(alpha):
            f = freq[t, j]
            fcum[t, j] = np.uint32((f << 16) | c)
            end = min(c + f, PROB_SCALE)
            if end > c:   # not a slice per unused symbol (most of an alphabet): 0.074 against 0.12 ms, 128 tables
                lut[t, c:end] = j
            c += f
        if c < PROB_SCALE:   # frequencies short of the scale (not from _parse_tables, which checks the sum)
            lut[t, c:] = 0
    return lut[:ntab], fcum


@nb.njit(cache=True, nogil=True)
def _init_front(p, c0):
    """The part of a plane's padded buffer (``_front``) the decoder reads before it writes it: the two
    rows above the plane and the left padding of its first row, all ``c0``."""
    p[0, :] = c0
    p[1, :] = c0
    p[2, 0] = c0
    p[2, 1] = c0


def decode_planes(blob, dithers: list[np.ndarray], outs: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Inverse of ``encode_planes``; ``dithers`` are the planes' dither arrays (same shapes): float in [-1/2, 1/2), or
    their fixed-point values floor(u 2^16) as int32 (``fixed_dither``). The symbols (int32) go to ``outs`` (arrays
    or views of the planes' shapes) if given."""
    try:
        return _decode(memoryview(blob), [u.shape for u in dithers], dithers, outs)
    except (struct.error, ValueError, IndexError) as exc:
        raise MetrawError(f"codec stream is corrupt: {exc}") from None


class PlaneDN(NamedTuple):
    """Where a plane's DN go and how (``decode_planes_dn``): dither keys (``prepare.dither_keys``), the plane's pixel
    indices start + i row_step + j col_step, the inverse transform (``prepare.inverse_args``), the DN out (uint16, the
    plane's shape: a CFA plane of the frame)."""

    keys: tuple[int, int]
    start: int
    row_step: int
    col_step: int
    inv: tuple[float, float, float]
    out: np.ndarray


def decode_planes_dn(blob, planes: list[PlaneDN]) -> None:
    """``decode_planes`` then the inverse transform into each plane's ``out``, the fixed-point dither made from its keys
    (``native.dither_fixed``'s values; the compiled path needed): in the compiled loop a row group at a time, so
    neither the dither nor the symbols of a whole plane are made. The same DN as those three steps."""
    try:
        _decode(memoryview(blob), [pl.out.shape for pl in planes], dn=planes)
    except (struct.error, ValueError, IndexError) as exc:
        raise MetrawError(f"codec stream is corrupt: {exc}") from None


def _decode(mv: memoryview, shapes: list[tuple[int, int]], dithers: list[np.ndarray] | None = None, outs=None,
            dn: list[PlaneDN] | None = None) -> list[np.ndarray] | None:
    """The planes (of ``shapes``) of a section: ``decode_planes`` (``dithers`` given), or ``decode_planes_dn``
    (``dn`` given)."""
    npl, nact, pshift, shared, nl, tabbits, amax = _HEAD.unpack_from(mv, 0)
    off = _HEAD.size
    if (npl != len(shapes) or not 1 <= nact <= MAX_NACT or shared > 1 or amax > MAX_RESID or not 1 <= nl <= 16
            or pshift not in (0, 2) or tabbits not in (8, 16)):
        raise ValueError("plane header does not match the frame")
    lanes = []
    for _ in range(nl):
        (st,) = struct.unpack_from("<I", mv, off)
        nwd, off = get_varint(mv, off + 4)
        nes, off = get_varint(mv, off)
        lanes.append((st, nwd, nes))
    c0s = []
    for _ in range(npl):
        z, off = get_varint(mv, off)
        c0s.append(z >> 1 if not z & 1 else -((z + 1) >> 1))
    if any(abs(c) >= 2**31 for c in c0s) or sum(ln[1] for ln in lanes) > len(mv) or sum(ln[2] for ln in lanes) > len(mv):
        raise ValueError("plane header is out of range")
    ngroup = 1 if shared else npl
    heads = []
    for _ in range(ngroup):
        thr = np.frombuffer(mv, "<u4", nact - 1, off).astype(np.int64) << 8
        off += 4 * (nact - 1)
        coef = np.frombuffer(mv, "<i2", nact * (NTAP - 1), off).astype(np.int64)
        off += 2 * nact * (NTAP - 1)
        bias = np.frombuffer(mv, "<i4", nact, off).astype(np.int64)
        off += 4 * nact
        heads.append((thr, coef, bias))
    alpha = 2 * amax + 2
    nph = NPH >> pshift
    ntab = ngroup * nact * nph
    freq, off, err = _parse_tables(np.frombuffer(mv, np.uint8), off, ntab, alpha, tabbits == 8)
    if err:
        raise ValueError(("frequency tables are truncated", "frequency table overruns the alphabet",
                          "frequency table does not sum to the probability scale")[err - 1])
    lut, fcum = _decoding_tables(freq, np.uint8 if alpha <= 256 else np.int16)
    nwords = [ln[1] for ln in lanes]
    # words of lane j at [pmin_j + 1, pmin_j + n_j], after ``pad`` zero words (words[pmin_j] the last of
    # them: branch-free renormalisation); escapes followed by ``pad`` zeros. The decoder's steady part
    # checks a lane's limits once per group of rows and reads at most a row's width past them.
    pad = max([w for _, w in shapes] + [0]) + 16
    pmin = (np.cumsum(np.array(nwords, np.int64) + pad) - np.array(nwords, np.int64) - 1).astype(np.int64)
    # + 2 words: the AVX-512 decoder's 32-bit gathers read one word past the last
    words = np.zeros(int(sum(nwords)) + nl * pad + 2, np.uint16)
    for j, n in enumerate(nwords):
        words[pmin[j] + 1:pmin[j] + 1 + n] = np.frombuffer(mv, "<u2", n, off)
        off += 2 * n
    nesc = [ln[2] for ln in lanes]
    esc = np.zeros(int(sum(nesc)) + pad, np.int32)
    esc[:int(sum(nesc))] = np.frombuffer(mv, "<i4", int(sum(nesc)), off)
    epos = np.concatenate([[0], np.cumsum(nesc)[:-1]]).astype(np.int64)
    eend = epos + np.array(nesc, np.int64)
    xs = np.array([ln[0] for ln in lanes], np.uint64)
    pos = pmin + np.array(nwords, np.int64)
    if outs is None and dn is None:
        outs = [np.empty(shape, np.int32) for shape in shapes]
    # one padded buffer for the planes in turn (``_init_front`` sets what the decoder reads before writing); the
    # compiled loop needs only a row group's rows and the two above them (it moves them up after each group)
    compiled = native.LIB is not None and nl in native.LANE_COUNTS

    def buffer_rows(h):
        return (min(h, nl) if compiled else h) + 2

    buf = np.empty(max(buffer_rows(h) * (w + 4) for h, w in shapes), np.int64)
    if dn is not None and compiled:   # a row group's dither and symbols
        group_u, group_sym = (np.empty(max(min(h, nl) * w for h, w in shapes), np.int32) for _ in range(2))
    for k in range(npl):
        g = 0 if shared else k
        thr, coef, bias = heads[g]
        thr7 = np.concatenate([thr, np.full(MAX_NACT - 1 - thr.size, np.iinfo(np.int64).max, np.int64)])
        coef13 = predictor_table(coef, bias).reshape(-1)
        h, w = shapes[k]
        p = buf[:buffer_rows(h) * (w + 4)].reshape(buffer_rows(h), w + 4)
        _init_front(p, np.int64(c0s[k]) << 16)
        pl = dn[k] if dn is not None else None
        if pl is not None and compiled:
            r = min(h, nl)
            ok = native.decode_plane_dn(p, group_u[:r * w].reshape(r, w), group_sym[:r * w].reshape(r, w), thr7,
                                        coef13, g * nact * nph, pshift, lut, fcum, amax, words, xs, pos, pmin, esc,
                                        epos, eend, pl.keys, pl.start, pl.row_step, pl.col_step, pl.inv, pl.out)
        else:
            if pl is not None:   # a shared model's few lanes: the numba loop below, then the compiled inverse
                u16 = native.dither_fixed(*pl.keys, pl.start, h, w, pl.row_step, pl.col_step)
                out = np.empty((h, w), np.int32)
            else:
                u = dithers[k]
                u16 = (np.ascontiguousarray(u) if u.dtype == np.int32
                       else fixed_dither(np.ascontiguousarray(u, np.float64)))
                out = outs[k]
            if compiled:
                sym = out if out.flags.c_contiguous and out.dtype == np.int32 else np.empty((h, w), np.int32)
                ok = native.decode_plane(p, u16, sym, thr7, coef13, g * nact * nph, pshift, lut, fcum, amax, words,
                                         xs, pos, pmin, esc, epos, eend)
                if sym is not out:
                    out[...] = sym
            else:
                ok = decode_plane(p, u16, out, thr7, context_table(thr), coef13, g * nact * nph, pshift, lut, fcum,
                                  amax, words, xs, pos, pmin, esc, epos, eend)
            if ok and pl is not None:
                native.inverse_dn(out, pl.keys, pl.start, pl.row_step, pl.col_step, *pl.inv, pl.out)
        if not ok:
            raise ValueError("coded data ran out")
    if np.any(pos != pmin) or np.any(xs != RANS_L) or np.any(epos != eend):
        raise ValueError("rANS did not end in its initial state")
    return outs
