"""The decoder's per-pixel loop of ``metraw.codec.predictive`` (compiled, ``nogil``).

Lane j of a section holds rows j, j + L, ... of a plane (L = 4 lanes for large tiles) and runs
3 pixels behind lane j - 1, so its causal neighbours are ready and the L dependency chains
overlap. The arithmetic is the encoder's (``predictive._residuals``) to the bit.

Speed: every array access uses an unsigned index (a cast of the signed one: free) so numba emits
no negative-index wrap-around (a compare and a select per index, ~30 indexings per pixel); the
padded buffer, tables and lookup are read through flat 1-D views with precomputed offsets. In the
per-pixel step no array is sliced and no branch touches an array (numba would count references
there, an atomic operation per pixel).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numba.core import types
from numba.extending import overload

PROB_BITS = 12                 # rANS probability resolution
PROB_SCALE = 1 << PROB_BITS
RANS_L = 1 << 16


@nb.njit(cache=True, nogil=True, inline="always")
def _u(i):
    return np.uint64(i)


#: Largest activity-context table (entries): thresholds up to CTAB_MAX - 2 (x 2^8) use it, larger ones compares.
CTAB_MAX = 1 << 15


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
        return np.int64(ctab[np.uint64(min(((act - 1) >> 8) + 1, ctab.size - 1))])
    return lookup


@nb.njit(cache=True, nogil=True, inline="always")
def _pixel(pf, b, ws, w_, ww, uv, thr, ctab, coef, bias, tab0, pshift, lut, fcum, alpha, amax, words, x, pos, esc,
           epos):
    """Decode the pixel at flat index ``b`` of the padded buffer ``pf`` (row stride ``ws``; its left
    neighbours ``w_`` = pf[b - 1] and ``ww`` = pf[b - 2] passed in: a lane keeps them in registers, off
    the store-to-load path) from one lane, without checking the lane's word and escape positions;
    returns (symbol, its buffer value pf[b], x, pos, epos)."""
    half = np.int64(1 << 15)
    n_ = pf[_u(b - ws)]
    nw = pf[_u(b - ws - 1)]
    ne = pf[_u(b - ws + 1)]
    nn = pf[_u(b - 2 * ws)]
    act = abs(w_ - nw) + abs(n_ - nw) + abs(n_ - ne) + abs(w_ - ww) + abs(n_ - nn)
    c = _context(act, thr, ctab)
    o = c * 12
    # sum_i k_i (n_i - W) = sum_i k_i n_i - W sum_i k_i (exact integers: the encoder's value)
    acc = (coef[_u(o)] * n_ + coef[_u(o + 1)] * nw + coef[_u(o + 2)] * ne + coef[_u(o + 3)] * ww
           + coef[_u(o + 4)] * nn + coef[_u(o + 5)] * pf[_u(b - ws - 2)] + coef[_u(o + 6)] * pf[_u(b - 2 * ws - 1)]
           + coef[_u(o + 7)] * pf[_u(b - 2 * ws + 1)] + coef[_u(o + 8)] * pf[_u(b - ws + 2)]
           + coef[_u(o + 9)] * pf[_u(b - 2 * ws - 2)] + coef[_u(o + 10)] * pf[_u(b - 2 * ws + 2)]
           - coef[_u(o + 11)] * w_)
    mh = w_ + (acc >> 12) + bias[_u(c)] + uv + half
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
    return v, pv, x, pos, epos


@nb.njit(cache=True, nogil=True, inline="always")
def decode_pixel(pf, b, ws, uv, thr, ctab, coef, bias, tab0, pshift, lut, fcum, alpha, amax, words, x, pos, pmin,
                 esc, epos, eend):
    """``_pixel`` with the lane's limits checked: returns (symbol, x, pos, epos, ok), ok false once the
    lane has used a word below ``pmin`` (its pad) or an escape at or past ``eend``."""
    v, _, x, pos, epos = _pixel(pf, b, ws, pf[_u(b - 1)], pf[_u(b - 2)], uv, thr, ctab, coef, bias, tab0, pshift, lut,
                                fcum, alpha, amax, words, x, pos, esc, epos)
    return v, x, pos, epos, (pos >= pmin) & (epos <= eend)


@nb.njit(cache=True, nogil=True, inline="always")
def _u16(u, y, x):
    """floor(u 2^16) of the dither at (y, x)."""
    return np.int64(np.floor(u[_u(y), _u(x)] * 65536.0))


@nb.njit(cache=True, nogil=True)
def decode_plane(p, u, sym, thr, ctab, coef, bias, tab0, pshift, lut, fcum, amax, words, xs, pos, pmin, esc, epos, eend):
    """Decode one plane into the padded buffer ``p`` (h + 2, w + 4) and the symbols ``sym`` (the
    plane's view of the tile); ``u`` is the plane's dither; ``thr`` the 7 activity thresholds (padded)
    and ``ctab`` their ``context_table`` or None (compiled separately: compares instead of a lookup); ``lut`` (tables x 2^PROB_BITS) and
    ``fcum`` (tables x alphabet) C-contiguous. Updates the per-lane state ``xs``, word positions
    ``pos`` (lower limits ``pmin``) and escape positions ``epos`` (limits ``eend``) in place;
    returns ok. ``words`` must hold at least w readable pad words below each lane's ``pmin`` and
    ``esc`` at least w + 1 pad values after the last lane's escapes (the steady part checks the
    limits once per group of rows).

    Groups of 4 full rows run their steady part (every lane inside the row, no padding to write)
    with the lane states in local variables; edges and other groups take the general path."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    ws = np.int64(w + 4)
    pf = p.reshape(-1)
    lutf = lut.reshape(-1)
    fcf = fcum.reshape(-1)
    alpha = np.int64(fcum.shape[1])
    nl = xs.size
    for y0 in range(0, h, nl):
        nr = min(nl, h - y0)
        fast = nr == 4 and w >= 12
        for xsw in range(w + 3 * (nr - 1)):
            if fast and xsw == 10:
                # steady part: xsw = 10 .. w - 2, lanes at x = xsw, xsw - 3, xsw - 6, xsw - 9
                a0, a1, a2, a3 = xs[0], xs[1], xs[2], xs[3]
                q0, q1, q2, q3 = pos[0], pos[1], pos[2], pos[3]
                e0, e1, e2, e3 = epos[0], epos[1], epos[2], epos[3]
                b0 = (y0 + 2) * ws + 2
                # each lane's two left neighbours, carried in registers along the row
                b = b0 + 10
                w0, ww0 = pf[_u(b - 1)], pf[_u(b - 2)]
                w1, ww1 = pf[_u(b + ws - 4)], pf[_u(b + ws - 5)]
                w2, ww2 = pf[_u(b + 2 * ws - 7)], pf[_u(b + 2 * ws - 8)]
                w3, ww3 = pf[_u(b + 3 * ws - 10)], pf[_u(b + 3 * ws - 11)]
                for xs_ in range(10, w - 1):
                    b = b0 + xs_
                    v, pv, a0, q0, e0 = _pixel(pf, b, ws, w0, ww0, _u16(u, y0, xs_), thr, ctab, coef, bias, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a0, q0, esc, e0)
                    sym[_u(y0), _u(xs_)] = v
                    ww0 = w0
                    w0 = pv
                    v, pv, a1, q1, e1 = _pixel(pf, b + ws - 3, ws, w1, ww1, _u16(u, y0 + 1, xs_ - 3), thr, ctab, coef, bias, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a1, q1, esc, e1)
                    sym[_u(y0 + 1), _u(xs_ - 3)] = v
                    ww1 = w1
                    w1 = pv
                    v, pv, a2, q2, e2 = _pixel(pf, b + 2 * ws - 6, ws, w2, ww2, _u16(u, y0 + 2, xs_ - 6), thr, ctab, coef, bias, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a2, q2, esc, e2)
                    sym[_u(y0 + 2), _u(xs_ - 6)] = v
                    ww2 = w2
                    w2 = pv
                    v, pv, a3, q3, e3 = _pixel(pf, b + 3 * ws - 9, ws, w3, ww3, _u16(u, y0 + 3, xs_ - 9), thr, ctab, coef, bias, tab0, pshift, lutf, fcf,
                                              alpha, amax, words, a3, q3, esc, e3)
                    sym[_u(y0 + 3), _u(xs_ - 9)] = v
                    ww3 = w3
                    w3 = pv
                # limits checked once per group: a lane uses at most one word and one escape per pixel, and
                # the caller pads the words before each lane and the escapes after the last (``decode_plane``)
                if not ((q0 >= pmin[0]) & (q1 >= pmin[1]) & (q2 >= pmin[2]) & (q3 >= pmin[3]) & (e0 <= eend[0])
                        & (e1 <= eend[1]) & (e2 <= eend[2]) & (e3 <= eend[3])):
                    return False
                xs[0], xs[1], xs[2], xs[3] = a0, a1, a2, a3
                pos[0], pos[1], pos[2], pos[3] = q0, q1, q2, q3
                epos[0], epos[1], epos[2], epos[3] = e0, e1, e2, e3
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
                v, x, ps, ep, ok = decode_pixel(pf, yy * ws + x0 + 2, ws, _u16(u, y, x0), thr, ctab, coef, bias, tab0, pshift,
                                                lutf, fcf, alpha, amax, words, xs[j], pos[j], pmin[j], esc, epos[j],
                                                eend[j])
                if not ok:
                    return False
                xs[j] = x
                pos[j] = ps
                epos[j] = ep
                sym[y, x0] = v
                if x0 == w - 1:
                    p[yy, w + 2] = p[yy, w + 1]
                    p[yy, w + 3] = p[yy, w + 1]
    return True
