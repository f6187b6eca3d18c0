"""Lossless coding of integer streams with interleaved static rANS: the codec's escape section (the gaps between
the escaped pixels of ``prepare.escape_mask`` and their DN values).

Entropy coder: range-ANS (Duda 2013) with a static frequency table per context (one context
per stream), 2^14 probability scale, 32-bit states and 16-bit renormalisation. ``lanes``
independent states advance in lock step, so every step is one vectorised numpy operation
over all lanes (encode and decode cost O(n / lanes) Python steps). Values outside a
context's alphabet are coded as an escape symbol and stored verbatim.
"""

from __future__ import annotations

import struct

import numpy as np

from metraw.errors import MetrawError

PROB_BITS = 14
PROB_SCALE = 1 << PROB_BITS
RANS_L = 1 << 16
MAX_ALPHABET = 4096


# ----------------------------------------------------------------------------- frequency tables
def _normalise(counts: np.ndarray) -> np.ndarray:
    """Integer frequencies summing to PROB_SCALE, >= 1 wherever counts > 0."""
    total = counts.sum()
    freq = np.floor(counts * (PROB_SCALE / total)).astype(np.int64)
    freq[(counts > 0) & (freq == 0)] = 1
    diff = PROB_SCALE - freq.sum()
    # give or take the difference from the largest entries (keeps >= 1)
    order = np.argsort(-freq)
    i = 0
    while diff != 0:
        j = order[i % len(order)]
        if diff > 0:
            freq[j] += diff
            diff = 0
        elif freq[j] > 1:
            take = min(-diff, freq[j] - 1)
            freq[j] -= take
            diff += take
        i += 1
    return freq


def _model(values: np.ndarray) -> tuple[int, np.ndarray]:
    """(lo, freq) for one context: alphabet lo .. lo+len(freq)-2 plus an escape symbol last."""
    if values.size == 0:
        return 0, np.array([PROB_SCALE], dtype=np.int64)
    vmin, vmax = int(values.min()), int(values.max())
    if vmax - vmin + 1 > MAX_ALPHABET - 1:
        med = int(np.median(values))
        vmin = max(vmin, med - (MAX_ALPHABET - 1) // 2)
        vmax = vmin + MAX_ALPHABET - 2
    sym = np.clip(values - vmin, -1, vmax - vmin + 1)
    sym[sym < 0] = vmax - vmin + 1
    counts = np.bincount(sym, minlength=vmax - vmin + 2).astype(np.float64)
    return vmin, _normalise(counts)


# ----------------------------------------------------------------------------- rANS
def _rans_encode(freq: np.ndarray, cum: np.ndarray, lanes: int) -> tuple[np.ndarray, np.ndarray]:
    """Encode symbols given by their (freq, cum) arrays; returns (final states, words).

    States are uint32; x // f is computed as floor(x * (1/f) + 2^-16) in float64, which is
    exact for x < 2^32 and f <= 2^14 (the rounding error is below 2^-19 < 1/f).
    """
    n = freq.size
    steps = -(-n // lanes)
    pad = steps * lanes - n
    f = np.concatenate([freq.astype(np.uint32), np.ones(pad, np.uint32)]).reshape(steps, lanes)
    c = np.concatenate([cum.astype(np.uint32), np.zeros(pad, np.uint32)]).reshape(steps, lanes)
    inv = 1.0 / f.astype(np.float64)
    xmax = f.astype(np.uint64) << np.uint64(32 - PROB_BITS)  # 2^32 when f = 2^P: keep 64 bits
    fill = PROB_SCALE - f
    valid_last = np.arange(lanes) < lanes - pad
    x = np.full(lanes, RANS_L, dtype=np.uint32)
    chunks = []
    pb = np.uint32(PROB_BITS)
    s16 = np.uint32(16)
    for t in range(steps - 1, -1, -1):
        emit = x >= xmax[t]
        if t == steps - 1 and pad:
            emit &= valid_last
        if emit.any():
            chunks.append(x[emit].astype(np.uint16))
            x[emit] >>= s16
        q = (x * inv[t] + 2.0 ** -16).astype(np.uint32)
        # (q << P) + (x - q f) + c  ==  x + q (2^P - f) + c
        xn = x + q * fill[t] + c[t]
        if t == steps - 1 and pad:
            xn = np.where(valid_last, xn, x)
        x = xn
    words = np.concatenate(chunks) if chunks else np.empty(0, np.uint16)
    return x, words


def _rans_decode(states: np.ndarray, words: np.ndarray, n: int, ctx_of: np.ndarray,
                 lut_sym: np.ndarray, lut_freq: np.ndarray, lut_cum: np.ndarray, lanes: int) -> np.ndarray:
    """Decode ``n`` symbols; ``ctx_of`` gives each symbol's context row in the lookup tables."""
    steps = -(-n // lanes)
    pad = steps * lanes - n
    amax = lut_freq.shape[1]
    ctx = np.concatenate([ctx_of.astype(np.int64), np.zeros(pad, np.int64)]).reshape(steps, lanes)
    base_sym = ctx * PROB_SCALE
    base_f = ctx * amax
    flat_sym = lut_sym.reshape(-1)
    fc = (lut_freq.astype(np.uint32).reshape(-1), lut_cum.astype(np.uint32).reshape(-1))
    out = np.empty((steps, lanes), dtype=np.int32)
    x = states.astype(np.uint32)
    pos = words.size
    w32 = words.astype(np.uint32)
    mask = np.uint32(PROB_SCALE - 1)
    pb = np.uint32(PROB_BITS)
    s16 = np.uint32(16)
    valid_last = np.arange(lanes) < lanes - pad
    for t in range(steps):
        slot = x & mask
        s = flat_sym[base_sym[t] + slot]
        out[t] = s
        j = base_f[t] + s
        xn = fc[0][j] * (x >> pb) + slot - fc[1][j]
        if t == steps - 1 and pad:
            xn = np.where(valid_last, xn, x)
        need = xn < np.uint32(RANS_L)
        if t == steps - 1 and pad:
            need &= valid_last
        k = int(np.count_nonzero(need))
        if k:
            if k > pos:
                raise MetrawError("codec stream is truncated or corrupt (rANS ran out of data)")
            xn[need] = (xn[need] << s16) | w32[pos - k:pos]
            pos -= k
        x = xn
    if pos != 0 or np.any(x != RANS_L):
        raise MetrawError("codec stream is corrupt (rANS did not end in its initial state)")
    return out.reshape(-1)[:n]


# ----------------------------------------------------------------------------- public API
def _lanes(n: int) -> int:
    """Lane count: a power of two with >= ~512 symbols per lane (each lane's final state costs ~17 bits)."""
    return int(min(16384, max(16, 1 << int(np.floor(np.log2(max(n, 1) / 512 + 1))))))


def encode_streams(streams: list[np.ndarray]) -> bytes:
    """Code a list of 1-D int32 arrays (one context each) into one byte string."""
    models = [_model(s) for s in streams]
    sizes = [s.size for s in streams]
    n = int(sum(sizes))
    parts = [struct.pack("<II", len(streams), n)]
    escapes = []
    freqs, cums = [], []
    for s, (lo, freq) in zip(streams, models):
        alpha = freq.size - 1
        sym = s.astype(np.int64) - lo
        esc = (sym < 0) | (sym >= alpha)
        escapes.append(s[esc])
        sym[esc] = alpha
        cumtab = np.concatenate([[0], np.cumsum(freq)[:-1]])
        freqs.append(freq[sym].astype(np.uint64))
        cums.append(cumtab[sym].astype(np.uint64))
        nz = np.flatnonzero(freq)
        first, last = int(nz[0]), int(nz[-1])
        parts.append(struct.pack("<IiIII", s.size, lo, freq.size, first, last - first + 1))
        parts.append(freq[first:last + 1].astype("<u2").tobytes())
    lanes = _lanes(n)
    if n:
        states, words = _rans_encode(np.concatenate(freqs), np.concatenate(cums), lanes)
    else:
        states, words = np.empty(0, np.uint32), np.empty(0, np.uint16)
    esc_all = np.concatenate(escapes).astype("<i4") if escapes else np.empty(0, "<i4")
    parts.append(struct.pack("<III", lanes, words.size, esc_all.size))
    parts.append(states.astype("<u4").tobytes())
    parts.append(words.astype("<u2").tobytes())
    parts.append(esc_all.tobytes())
    return b"".join(parts)


def decode_streams(blob: bytes) -> list[np.ndarray]:
    """Inverse of ``encode_streams``."""
    try:
        return _decode_streams(memoryview(blob))
    except (struct.error, ValueError, IndexError) as exc:
        raise MetrawError(f"codec stream is corrupt: {exc}") from None


def _decode_streams(mv: memoryview) -> list[np.ndarray]:
    nstreams, n = struct.unpack_from("<II", mv, 0)
    off = 8
    los, freqs, sizes = [], [], []
    for _ in range(nstreams):
        size, lo, alen, first, span = struct.unpack_from("<IiIII", mv, off)
        off += 20
        freq = np.zeros(alen, np.int64)
        freq[first:first + span] = np.frombuffer(mv, "<u2", span, off)
        off += 2 * span
        if freq.sum() != PROB_SCALE:
            raise ValueError("frequency table does not sum to the probability scale")
        los.append(lo)
        freqs.append(freq)
        sizes.append(size)
    lanes, nwords, nesc = struct.unpack_from("<III", mv, off)
    off += 12
    nstates = lanes if n else 0
    states = np.frombuffer(mv, "<u4", nstates, off)
    off += 4 * nstates
    words = np.frombuffer(mv, "<u2", nwords, off)
    off += 2 * nwords
    esc_all = np.frombuffer(mv, "<i4", nesc, off).astype(np.int32)
    amax = max(f.size for f in freqs) if freqs else 1
    lut_sym = np.zeros((max(nstreams, 1), PROB_SCALE), np.int32)
    lut_freq = np.ones((max(nstreams, 1), amax), np.uint64)
    lut_cum = np.zeros((max(nstreams, 1), amax), np.uint64)
    for i, freq in enumerate(freqs):
        lut_sym[i] = np.repeat(np.arange(freq.size, dtype=np.int32), freq)
        lut_freq[i, :freq.size] = freq
        lut_cum[i, :freq.size] = np.concatenate([[0], np.cumsum(freq)[:-1]])
    ctx_of = np.repeat(np.arange(nstreams, dtype=np.int32), sizes)
    sym = _rans_decode(states, words, n, ctx_of, lut_sym, lut_freq, lut_cum, lanes) if n else np.empty(0, np.int32)
    out = []
    start = 0
    epos = 0
    for lo, freq, size in zip(los, freqs, sizes):
        s = sym[start:start + size] + np.int32(lo)
        esc = sym[start:start + size] == freq.size - 1
        k = int(esc.sum())
        if k:
            if epos + k > esc_all.size:
                raise ValueError("escape list is short")
            s[esc] = esc_all[epos:epos + k]
            epos += k
        out.append(s)
        start += size
    return out
