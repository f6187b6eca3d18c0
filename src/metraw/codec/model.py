"""The encoder's predictor model of a plane group (``metraw.codec.predictive``): activity contexts and per-context
least-squares predictors, fitted on the causal buffer. Encoder only: the stream stores the thresholds, coefficients
and biases, so none of this has to be reproduced by a decoder bit for bit.

Activity of a pixel: |W-NW| + |N-NW| + |N-NE| + |W-WW| + |N-NN| of its decoded neighbours (16.16 fixed point);
``n_activity_contexts`` contexts with thresholds at the activity's quantiles (``thresholds``, multiples of 256), each
with its own least-squares predictor x ~ W + sum_i c_i (n_i - W) + b over 12 causal neighbours (``normal_equations``
on a sheared sampling lattice, ``fit``). ``model_of_front`` is the whole model of one plane's buffer.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from metraw.codec.decoder import COEF_BITS, FRAC, MAX_NACT, NTAP

MIN_FIT = 64                   # fewer samples in a context: use the default predictor


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
def activity(p, y, x):
    w_ = p[y, x - 1]
    n_ = p[y - 1, x]
    nw = p[y - 1, x - 1]
    return abs(w_ - nw) + abs(n_ - nw) + abs(n_ - p[y - 1, x + 1]) + abs(w_ - p[y, x - 2]) + abs(n_ - p[y - 2, x])


@nb.njit(cache=True, nogil=True, inline="always")
def context_of(act, thr):
    c = 0
    for i in range(thr.size):  # thresholds ascending: a branch-free count
        c += act > thr[i]
    return c


@nb.njit(cache=True, nogil=True)
def activity_samples(p, stride):
    """Activities on the sampling lattice (rows every ``stride``, sheared columns)."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    out = np.empty(((h + stride - 1) // stride) * ((w + stride - 1) // stride + 1), np.int64)
    n = 0
    for y in range(0, h, stride):
        for x0 in range((y // stride) % stride, w, stride):  # sheared lattice: no column aliasing
            out[n] = activity(p, y + 2, x0 + 2)
            n += 1
    return out[:n]


#: Least-squares samples per group (sampling lattice of the encoder's fit; encoder only). 16384 samples
#: for 12 x 8 unknowns cost < 0.002 bit/pixel against 65536 and a quarter of the fitting time.
LS_SAMPLES = 16384
LS_BLOCK = 512                  # samples buffered per activity context before they are added to X^T X


@nb.njit(cache=True, nogil=True, fastmath=True)
def _gram_add(buf, n, ata_c, atb_c):
    """Add X^T X (lower triangle) and X^T t of ``n`` buffered samples (rows of ``buf``: 12 regressors,
    then the target). Encoder only (the fitted coefficients are stored in the stream), so the
    summation order is free: vectorised dot products."""
    for i in range(12):
        di = buf[i]
        for j in range(i + 1):
            dj = buf[j]
            acc = 0.0
            for m in range(n):
                acc += di[m] * dj[m]
            ata_c[i, j] += acc
        dt = buf[12]
        acc = 0.0
        for m in range(n):
            acc += di[m] * dt[m]
        atb_c[i] += acc


@nb.njit(cache=True, nogil=True)
def normal_equations(p, thr, stride, ata, atb):
    """Accumulate per-context X^T X (lower triangle) and X^T t of t = x - W on (n_i - W, 1) over
    the sampling lattice (rows every ``stride``, sheared columns: no column aliasing). Samples are
    buffered per context (``LS_BLOCK``, cache resident) and added in vectorised blocks. Unsigned
    indices into flat views of ``p`` and the buffer: numba checks no index for wrap-around (0.78 ->
    0.69 ms a canon_dng plane, the same sums)."""
    h = p.shape[0] - 2
    w = p.shape[1] - 4
    nact = thr.size + 1
    buf = np.empty((nact, 13, LS_BLOCK + 24))  # padded rows: no 4 KiB cache-set aliasing
    fill = np.zeros(nact, np.uint64)
    sc = 1.0 / 65536.0
    pf = p.reshape(-1)
    bf = buf.reshape(-1)
    one, two = np.uint64(1), np.uint64(2)
    row = np.uint64(LS_BLOCK + 24)        # a buffer row
    ws = np.uint64(p.shape[1])            # a row of p
    for y in range(0, h, stride):
        for x0 in range((y // stride) % stride, w, stride):
            b = np.uint64((y + 2) * p.shape[1] + x0 + 2)   # the pixel; its neighbours at b - 1, b - ws, ...
            ref = pf[b - one]                               # W
            n_, nw = pf[b - ws], pf[b - ws - one]
            act = (abs(ref - nw) + abs(n_ - nw) + abs(n_ - pf[b - ws + one]) + abs(ref - pf[b - two])
                   + abs(n_ - pf[b - two * ws]))          # ``activity``
            c = context_of(act, thr)
            k = fill[c]
            o = np.uint64(c) * np.uint64(13) * row + k      # buf[c, 0, k]
            bf[o] = (n_ - ref) * sc
            bf[o + row] = (nw - ref) * sc
            bf[o + np.uint64(2) * row] = (pf[b - ws + one] - ref) * sc
            bf[o + np.uint64(3) * row] = (pf[b - two] - ref) * sc
            bf[o + np.uint64(4) * row] = (pf[b - two * ws] - ref) * sc
            bf[o + np.uint64(5) * row] = (pf[b - ws - two] - ref) * sc
            bf[o + np.uint64(6) * row] = (pf[b - two * ws - one] - ref) * sc
            bf[o + np.uint64(7) * row] = (pf[b - two * ws + one] - ref) * sc
            bf[o + np.uint64(8) * row] = (pf[b - ws + two] - ref) * sc
            bf[o + np.uint64(9) * row] = (pf[b - two * ws - two] - ref) * sc
            bf[o + np.uint64(10) * row] = (pf[b - two * ws + two] - ref) * sc
            bf[o + np.uint64(11) * row] = 1.0
            bf[o + np.uint64(12) * row] = (pf[b] - ref) * sc
            k += one
            if k == LS_BLOCK:
                _gram_add(buf[c], LS_BLOCK, ata[c], atb[c])
                k = np.uint64(0)
            fill[c] = k
    for c in range(nact):
        if fill[c]:
            _gram_add(buf[c], np.int64(fill[c]), ata[c], atb[c])


#: Bins of ``order_statistics_shifted``'s histogram (values sample >> 8 at or past it are selected exactly apart)
HIST_BINS = 1 << 16


@nb.njit(cache=True, nogil=True)
def order_statistics_shifted(sample, kth):
    """The order statistics at ranks ``kth`` (ascending) of v = ``sample`` >> 8 (``sample`` >= 0): what
    sorted(sample)[kth] >> 8 is, as >> 8 keeps the order. By a histogram of v (``HIST_BINS`` bins; ranks that
    fall past them by ``np.partition`` of those values): ~5x faster than partitioning ``sample``."""
    hist = np.zeros(HIST_BINS + 1, np.int64)
    for i in range(sample.size):
        hist[min(sample[i] >> 8, HIST_BINS)] += 1
    out = np.empty(kth.size, np.int64)
    below = 0  # values in the bins before b
    b = 0
    for j in range(kth.size):
        while b < HIST_BINS and below + hist[b] <= kth[j]:
            below += hist[b]
            b += 1
        out[j] = b
    if b == HIST_BINS:  # ranks among the largest values: exactly, by partitioning them
        big = np.empty(hist[HIST_BINS], np.int64)
        m = 0
        for i in range(sample.size):
            if sample[i] >> 8 >= HIST_BINS:
                big[m] = sample[i] >> 8
                m += 1
        for j in range(kth.size):
            if out[j] == HIST_BINS:
                out[j] = np.partition(big, kth[j] - below)[kth[j] - below]
    return out


@nb.njit(cache=True, nogil=True)
def thresholds(sample, nact):
    """nact - 1 activity thresholds (multiples of 256 at the 'lower' sample quantiles k / nact of
    ``sample``, duplicates removed), padded with 0xFFFFFFFF 2^8."""
    thr = np.full(nact - 1, np.int64(0xFFFFFFFF) << 8)
    n = sample.size
    if nact == 1 or n == 0:
        return thr
    kth = np.empty(nact - 1, np.int64)
    for k in range(1, nact):
        kth[k - 1] = ((n - 1) * k) // nact
    q = order_statistics_shifted(sample, kth)
    for k in range(nact - 1):
        q[k] = min(q[k], np.int64(0xFFFFFFFE))
    uq = np.unique(q)
    thr[:uq.size] = uq << 8
    return thr


@nb.njit(cache=True, nogil=True)
def fit(ata, atb):
    """Per-context least-squares coefficients (``COEF_BITS`` fixed point, nact x 11 flat) and bias
    (``FRAC`` bits) from the lower triangles of X^T X and X^T t (``normal_equations``).

    A context with fewer than ``MIN_FIT`` samples, or a solution that is not finite or has a
    coefficient of magnitude >= 7.9, gets the default predictor (W + N) / 2."""
    nact = ata.shape[0]
    coef = np.zeros(nact * (NTAP - 1), np.int64)
    bias = np.zeros(nact, np.int64)
    reg = np.empty((NTAP, NTAP))
    for c in range(nact):
        for i in range(NTAP):
            for j in range(i + 1):
                reg[i, j] = ata[c, i, j]
                reg[j, i] = ata[c, i, j]
            reg[i, i] += 1e-6
        try:
            sol = np.linalg.solve(reg, atb[c].copy())
        except Exception:  # singular (cannot happen for a Gram matrix + 1e-6 I, but never fail the encode)
            sol = np.full(NTAP, np.nan)
        ok = ata[c, NTAP - 1, NTAP - 1] >= MIN_FIT
        for i in range(NTAP):
            ok &= np.isfinite(sol[i])
        for i in range(NTAP - 1):
            ok &= abs(sol[i]) < 7.9
        if ok:
            for i in range(NTAP - 1):
                coef[c * (NTAP - 1) + i] = np.int64(np.rint(sol[i] * (1 << COEF_BITS)))
            bias[c] = np.int64(np.rint(min(max(sol[NTAP - 1], -16000.0), 16000.0) * (1 << FRAC)))
        else:
            coef[c * (NTAP - 1)] = 1 << (COEF_BITS - 1)  # (W + N) / 2 when a context has too few samples
    return coef, bias


@nb.njit(cache=True, nogil=True)
def model_of_front(front, nact, stride):
    """The model of a plane's causal buffer, one compiled call without the GIL: (thr, coef, bias). ``stride``: the
    least-squares sampling lattice (activities on twice that)."""
    thr = thresholds(activity_samples(front, 2 * stride), nact)
    ata = np.zeros((nact, NTAP, NTAP))
    atb = np.zeros((nact, NTAP))
    normal_equations(front, thr, stride, ata, atb)
    coef, bias = fit(ata, atb)
    return thr, coef, bias


def ls_stride(npix: int) -> int:
    """Least-squares sampling stride for a group of ``npix`` pixels: ~``LS_SAMPLES`` samples for
    12 x nact unknowns. Odd, so that even and odd rows are sampled (sensors with row-pair offsets,
    e.g. MicaSense, bias a fit on even rows only)."""
    return 2 * int(np.sqrt(npix / LS_SAMPLES) / 2) + 1
