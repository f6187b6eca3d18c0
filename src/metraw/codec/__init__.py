"""Noise-preserving raw codec (docs/codec.md).

``encode(image, step, seed) -> bytes`` and ``decode(blob) -> RawImage``. Preparation
(``metraw.codec.prepare``): generalised Anscombe transform from the image's profile,
quantisation with step ``step`` in units of the noise sigma using subtractive dither from a
counter-based generator keyed by (seed, pixel index), exact removal of the inverse transform's
curvature bias, lossless escapes for saturated and below-domain pixels, final rounding to
integer DN. Coding (``metraw.codec.predictive``): per CFA plane, dither-aware causal linear
prediction in the reconstructed domain, rANS with static tables per (activity, dither-phase)
context, compiled with numba; frames of 256 rows or more are cut into row tiles (2, or more
of at most ``TILE_PIXELS`` each beyond 5 MP; the tiling depends on the frame only) coded in
parallel threads (the kernels release the GIL), each tile's CFA planes as contiguous arrays and
with 16 interleaved rANS lanes; small tiles share one model across their planes. Escape lists
use ``metraw.codec.entropy``. The blob has a compact binary header with an optional embedded
profile and a CRC-32C (``metraw.codec.container``). The per-pixel loops run in C (AVX-512, AVX2
or portable C, chosen at import) where ``metraw.codec.native`` is built, else in numba: the same
bytes and values. The compiled decoder makes a plane's dither and puts out its DN a row group at
a time, with no plane-size intermediate arrays.

Only the pixel array is coded; ``mask`` and ``flags`` are not part of the blob.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

from metraw.codec import container, decoder, entropy, native, predictive, prepare
from metraw.errors import MetrawError
from metraw.raw.cfa import plane_offsets, cell_size
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

__all__ = ["encode", "decode", "round_trip", "ProfileMismatchWarning", "measured_noise_sigma", "THREADS", "threads"]

#: Threads for tile-parallel coding, the calling thread included (the numba kernels release the GIL).
THREADS = 2
#: Row tiles of frames with >= 256 rows, at least (the tiling depends on the frame's size only, never on
#: THREADS, so the bytes do not depend on the thread count).
TILES = 2
#: Pixels of a row tile, at most, on large frames (more tiles than ``TILES`` beyond 2 x TILE_PIXELS): a
#: tile's working set (~40 bytes per pixel) then stays small; on a 20 MP frame 4 tiles instead of 2 code
#: ~1.5x faster on one core at +0.1 % bits (each tile starts its prediction afresh), and 8 instead of 4
#: (2.5 MP, since 2026-11-27) encode 1.33x faster on one core (416 -> 314 ms CPU; 2 threads 204 -> 179 ms wall,
#: medians of 5 interleaved rounds) at +0.28 / +0.14 % bits (steps 1 / 2), decode alike (358 / 362 ms; the
#: decoded pixels do not depend on the tiling). 16 tiles (1.25 MP): no faster, +3.5 % bits. Frames up to 5 MP
#: (the shared real frames, the workflow's scenes) keep their 2 tiles: their bytes do not change.
TILE_PIXELS = 2_500_000
#: Relative difference between measured and claimed noise that triggers a warning.
MISMATCH_TOLERANCE = 0.2


@contextlib.contextmanager
def threads(n: int):
    """``THREADS`` = ``n`` inside the block (worker processes forked inside it inherit it: processes that fill
    the cores each code on one thread); restored after it. The bytes do not depend on it."""
    global THREADS
    if n < 1:
        raise ValueError(f"codec threads must be >= 1, got {n}")
    before, THREADS = THREADS, int(n)
    try:
        yield
    finally:
        THREADS = before


_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The module's helper threads (``THREADS`` - 1 of them), started once per thread count and reused:
    starting a pool per call costs ~0.3 ms of CPU, a few per cent of a small frame's coding time, and
    fresh threads run their first tiles slower. Forgotten after a fork (the child has no threads)."""
    with _POOL_LOCK:
        pool = _POOLS.get(THREADS)
        if pool is None:
            pool = _POOLS[THREADS] = ThreadPoolExecutor(THREADS - 1, thread_name_prefix=f"metraw-codec{THREADS}")
        return pool


def _map_tiles(fn, items: list) -> list:
    """[fn(item) for item in items], on ``THREADS`` threads: the calling thread and the pool's helpers
    take the next item in turn until none is left (the calling thread works too: one thread less to
    wake than handing every item to the pool, and on a small frame the wake-up of an idle core is a
    sizeable part of the run). Results in the order of ``items``, whichever thread made them."""
    if THREADS <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    results = [None] * len(items)
    order = iter(range(len(items)))
    lock = threading.Lock()

    def run():
        while True:
            with lock:
                i = next(order, None)
            if i is None:
                return
            results[i] = fn(items[i])

    helpers = [_pool().submit(run) for _ in range(min(THREADS, len(items)) - 1)]
    try:
        run()
    finally:
        for f in helpers:
            f.result()
    return results


def _forget_pool_after_fork() -> None:
    global _POOL_LOCK
    _POOLS.clear()
    _POOL_LOCK = threading.Lock()


os.register_at_fork(after_in_child=_forget_pool_after_fork)


class ProfileMismatchWarning(UserWarning):
    """The profile's noise model contradicts the noise measured in the pixels."""


def _tiles(h: int, w: int, cell: int) -> list[tuple[int, int]]:
    """Row tiles (start, stop), starting on a CFA cell boundary: 1 below 256 rows, else ``TILES`` or
    more so that a tile has at most ~``TILE_PIXELS`` pixels (and at least 128 rows)."""
    n = 1 if h < 256 else max(TILES, min(-(-h * w // TILE_PIXELS), h // 128))
    size = -(-h // n)
    size += size % cell
    return [(r, min(h, r + size)) for r in range(0, h, size)]


def _planes(a: np.ndarray, pattern: str) -> list[np.ndarray]:
    step = cell_size(pattern)
    return [a[dy::step, dx::step] for _, dy, dx in plane_offsets(pattern) if a[dy::step, dx::step].size]


def _plane_colours(shape: tuple[int, int], pattern: str) -> list[str]:
    """Colours of the non-empty planes of ``_planes`` for an array of ``shape``."""
    step = cell_size(pattern)
    return [c for c, dy, dx in plane_offsets(pattern) if shape[0] > dy and shape[1] > dx]


def _plane_grid(r0: int, r1: int, w: int, pattern: str) -> list[tuple[int, int, int, int]]:
    """(dy, dx, rows, columns) of each non-empty CFA plane of the tile of rows r0 .. r1 - 1 (the
    planes of ``_planes``, in their order)."""
    cell = cell_size(pattern)
    grid = [(dy, dx, len(range(dy, r1 - r0, cell)), len(range(dx, w, cell))) for _, dy, dx in plane_offsets(pattern)]
    return [g for g in grid if g[2] and g[3]]


def _plane_dithers(seed: int, r0: int, r1: int, w: int, pattern: str) -> list[np.ndarray]:
    """Each CFA plane's dither of a tile as its own contiguous array (the coder's kernels run faster on
    contiguous planes than on strided views of the tile)."""
    cell = cell_size(pattern)
    return [prepare.dither_grid(seed, (r0 + dy) * w + dx, ph, pw, cell * w, cell)
            for dy, dx, ph, pw in _plane_grid(r0, r1, w, pattern)]


@nb.njit(cache=True, nogil=True)
def _hh_values(plane, vals, n, add=0, shift=0):
    """Append the finest diagonal Haar (S-transform HH) coefficients of the central 256 x 256 crop of the symbols
    (``plane`` + ``add``) >> ``shift`` to ``vals`` from index ``n``; returns the new count (``plane``: symbols, or
    with add 32767 and shift 16 a causal buffer's interior, s 2^16 - floor(u 2^16) with floor(u 2^16) in
    [-2^15, 2^15)). Compiled: no GIL, no copies."""
    ph, pw = plane.shape
    y0, x0 = max(0, ph // 2 - 128), max(0, pw // 2 - 128)
    h, w = min(256, ph - y0) // 2 * 2, min(256, pw - x0) // 2 * 2
    if h < 2 or w < 2:
        return n
    for i in range(y0, y0 + h, 2):
        a, b = plane[i], plane[i + 1]
        for j in range(x0, x0 + w, 2):
            top = np.float64((a[j] + add) >> shift) - ((a[j + 1] + add) >> shift)
            vals[n] = top - (np.float64((b[j] + add) >> shift) - ((b[j + 1] + add) >> shift))
            n += 1
    return n


@nb.njit(cache=True, nogil=True)
def _mean_abs_dev(v):
    """Mean absolute deviation of ``v`` from its median. Integer values in a range of < 2^16 (the HH band of
    integer symbols) by a histogram: the same number as the sort (the median (a + b) / 2 of the two middle values as
    ``np.median``, and sums of multiples of 1/2 below 2^53: exact in any order), ~15x faster."""
    n = v.size
    lo, hi, integral = v[0], v[0], True   # one pass (v.min() and v.max() took twice its time); a NaN: not integral
    for i in range(n):
        x = v[i]
        lo, hi = min(lo, x), max(hi, x)
        integral &= x == np.floor(x)
    integral &= hi - lo < 65536.0
    if not integral:
        med = np.median(v)
        return np.mean(np.abs(v - med))
    hist = np.zeros(np.int64(hi - lo) + 1, np.int64)
    for i in range(n):
        hist[np.int64(v[i] - lo)] += 1
    ranks = ((n - 1) // 2, n // 2)   # the middle value(s): equal for odd n
    mid = np.empty(2)
    below = 0
    b = 0
    for j in range(2):
        while below + hist[b] <= ranks[j]:
            below += hist[b]
            b += 1
        mid[j] = lo + b
    med = (mid[0] + mid[1]) / 2 if n % 2 == 0 else mid[1]
    total = 0.0
    for k in range(hist.size):
        total += hist[k] * abs(lo + k - med)
    return total / n


def _noise_sigma_of_planes(planes: list[np.ndarray], step: float) -> float | None:
    """``measured_noise_sigma`` from the CFA planes' symbols."""
    vals = np.empty(len(planes) * 128 * 128, np.float64)
    n = 0
    for plane in planes:
        n = _hh_values(plane, vals, n)
    return _noise_sigma_of_hh(vals[:n], step)


def _noise_sigma_of_hh(vals: np.ndarray, step: float) -> float | None:
    """``measured_noise_sigma`` from the planes' HH band values (``_hh_values``)."""
    if vals.size < 256:
        return None
    var_hh = (_mean_abs_dev(vals) * math.sqrt(math.pi / 2)) ** 2
    var_pix = var_hh / 4.0 - 1.0 / 6.0
    return math.sqrt(max(var_pix, 0.0)) * step


def measured_noise_sigma(symbols: np.ndarray, pattern: str, step: float) -> float | None:
    """Noise sigma measured in the pixels, in units of the profile's sigma (1 = agreement).

    Robust estimate from the finest diagonal Haar band of each CFA plane (central 256 x 256 crop:
    plenty for a 20 % consistency check): for white noise of sigma s in transform units, symbols
    carry variance s^2 / q^2 + 1/6 (dither + rounding, non-subtractive view) and the S-transform HH
    band has four times the pixel variance. The band's scale is its mean absolute deviation from
    the median times sqrt(pi / 2) (Gaussian; the MAD itself is too coarse on integer data).
    Returns None when too few pixels.
    """
    return _noise_sigma_of_planes(_planes(symbols, pattern), step)


def _tile_symbols(data: np.ndarray, r0: int, r1: int, profile: CalibrationProfile, step: float,
                  seed: int) -> list[tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]]:
    """Per CFA plane of the row tile r0 .. r1 - 1 of ``data``: (its ``_plane_grid`` entry, dither, symbols), each a
    contiguous array (the coder's kernels are faster on them): what ``encode`` codes and ``round_trip`` reconstructs."""
    w = data.shape[1]
    pattern = profile.cfa_pattern
    cell = cell_size(pattern)
    return [(g, u, prepare.forward(data[r0 + g[0]:r1:cell, g[1]::cell], profile, step, u))
            for g, u in zip(_plane_grid(r0, r1, w, pattern), _plane_dithers(seed, r0, r1, w, pattern))]


def _tile_buffers(data: np.ndarray, r0: int, r1: int, profile: CalibrationProfile, step: float,
                  seed: int) -> list[tuple[np.ndarray, int]]:
    """Per CFA plane of the row tile r0 .. r1 - 1 of ``data``: its causal buffer (front, c0) as
    ``predictive.encode_planes`` makes it from ``_tile_symbols``, made straight from the DN in one compiled pass per
    plane where ``metraw.codec.native`` is built (no dither or symbol arrays: less memory traffic; as a
    ``predictive.LazyBuffer``) and ``data``'s strides are positive, else from ``_tile_symbols``."""
    if native.LIB is None or min(data.strides) <= 0:
        return [predictive._causal_buffer(s, u) for _, u, s in _tile_symbols(data, r0, r1, profile, step, seed)]
    w = data.shape[1]
    cell = cell_size(profile.cfa_pattern)
    keys, args = prepare.dither_keys(seed), prepare.forward_args(profile, step)
    # made when the coder reaches the plane (predictive.LazyBuffer): one plane's buffer in cache at a time
    return [predictive.LazyBuffer((ph, pw), functools.partial(native.plane_buffer, data[r0 + dy:r1:cell, dx::cell], keys,
                                                              (r0 + dy) * w + dx, cell * w, cell, args))
            for dy, dx, ph, pw in _plane_grid(r0, r1, w, profile.cfa_pattern)]


def _check_encode_args(image, step, seed, caller: str) -> tuple[float, int]:
    """(step, seed) as float and int after checking them and ``image`` (one clear error each)."""
    if not isinstance(image, RawImage):
        raise MetrawError(f"{caller} needs a RawImage (uint16 DN with a calibration profile)")
    if image.data.dtype != np.uint16:
        raise MetrawError(f"{caller} needs uint16 DN, got {image.data.dtype}")
    step = float(step)
    if not (math.isfinite(step) and step > 0):
        raise MetrawError(f"quantisation step must be a positive number of sigmas, got {step}")
    seed = int(seed)
    if not 0 <= seed < 2**63:
        raise MetrawError(f"seed must be in [0, 2^63), got {seed}")
    return step, seed


def round_trip(image: RawImage, step: float = 1.0, seed: int = 0) -> np.ndarray:
    """The uint16 DN that ``decode(encode(image, step, seed))`` returns, without coding them.

    The entropy coder is lossless: a decoded pixel is the reconstruction of its quantised symbol
    (``prepare.forward`` then ``prepare.inverse_dn``, with the same dither), or the original DN where
    it was escaped (saturated or below the transform's domain). So the round trip needs neither the
    predictor nor rANS; it is what training draws use, where only the pixels matter, not the bits
    (tests/test_codec.py: equal to the coded path for each CFA pattern, shape, tiling and step).
    """
    step, seed = _check_encode_args(image, step, seed, "codec.round_trip")
    data = image.data
    cell = cell_size(image.profile.cfa_pattern)
    out = np.empty(data.shape, np.uint16)
    for (dy, dx, _, _), u, sym in _tile_symbols(data, 0, data.shape[0], image.profile, step, seed):
        prepare.inverse_dn(sym, image.profile, step, u, out[dy::cell, dx::cell])
    esc = prepare.escape_mask(data, image.profile)
    out[esc] = data[esc]
    return out


def encode(image: RawImage, step: float = 1.0, seed: int = 0, check_profile: bool = True,
           embed_profile: bool = True, account: dict | None = None) -> bytes:
    """Compress ``image``: quantisation step ``step`` in noise sigmas, dither seed ``seed``.

    ``embed_profile=False`` leaves the profile, provenance and meta out of the blob (the zarr
    codec keeps the profile in the array metadata); ``decode`` then needs ``profile=``.

    Warns (``ProfileMismatchWarning``) when the noise measured in the pixels differs from the
    profile's by more than ``MISMATCH_TOLERANCE`` (relative).

    ``account``: if a dict, it receives ``bits`` and ``pixels`` per CFA colour (``{"R": ...}``),
    the bits summing to 8 len(blob): each colour plane's code length under the tables the coder
    used plus its share of the side information (``predictive.encode_planes``), the lossless
    escapes split by escaped pixels of each colour, the container header by pixels.
    """
    step, seed = _check_encode_args(image, step, seed, "codec.encode")
    h, w = image.shape
    if h * w >= 2**32:
        raise MetrawError("images of 2^32 pixels or more are not supported by the codec")
    data = image.data
    prof = image.profile
    pattern = prof.cfa_pattern
    tiles = _tiles(h, w, cell_size(pattern))

    def work(tile):
        r0, r1 = tile
        buffers = _tile_buffers(data, r0, r1, prof, step, seed)
        # the profile check looks at the first row tile only (half the frame at most: plenty), on the causal buffers'
        # interiors ((h + 2) x (w + 4) less the pads: no symbol arrays made) as the coder makes them
        on_buffer = None
        if check_profile and r0 == 0:
            hh = [np.empty(len(buffers) * 128 * 128, np.float64), 0]   # the HH values, their count

            def on_buffer(front):
                hh[1] = _hh_values(front[2:, 2:-2], hh[0], hh[1], 32767, 16)
        acc = [] if account is not None else None
        # the tile's escapes (saturated or below the transform's domain) here, in the tile's thread, not in one pass
        # over the frame after the tiles (canon_dng: 1.2 ms that ran on one core)
        esc = prepare.escape_index(data[r0:r1], prof, r0 * w)
        section = predictive.encode_buffers(buffers, acc, on_buffer)
        measured = _noise_sigma_of_hh(hh[0][:hh[1]], step) if on_buffer is not None else None
        return section, acc, measured, (r1 - r0) * w, esc

    results = _map_tiles(work, tiles)
    idx = np.concatenate([r[4] for r in results])
    if idx.size:
        esc_idx = np.diff(idx, prepend=0).astype(np.int32)
        esc_blob = entropy.encode_streams([esc_idx, data.reshape(-1)[idx].astype(np.int32)])
    else:
        esc_blob = b""
    if check_profile:
        _check_profile(results[0][2], results[0][4].size, results[0][3])   # the first tile's noise and escapes
    meta = ({"profile": prof.to_dict(), "provenance": image.provenance, "meta": image.meta}
            if embed_profile else None)
    header = container.Header((h, w), step, seed, tiles, meta)
    blob = container.pack(header, [r[0] for r in results] + [esc_blob])
    if account is not None:
        esc = np.zeros(h * w, np.bool_)
        esc[idx] = True
        _account(account, blob, results, tiles, esc.reshape(h, w), esc_blob, pattern, w)
    return blob


def _account(account: dict, blob: bytes, results, tiles, esc: np.ndarray, esc_blob: bytes, pattern: str,
             w: int) -> None:
    """Fill ``account`` (see ``encode``): bits and pixels per CFA colour, bits summing to 8 len(blob)."""
    colours = list(dict.fromkeys(c for c, _, _ in plane_offsets(pattern)))
    bits = dict.fromkeys(colours, 0.0)
    pix = dict.fromkeys(colours, 0)
    nesc = dict.fromkeys(colours, 0)
    step_c = cell_size(pattern)
    for c, dy, dx in plane_offsets(pattern):
        pix[c] += int(esc[dy::step_c, dx::step_c].size)
        nesc[c] += int(esc[dy::step_c, dx::step_c].sum())
    for (r0, r1), (sec, acc, *_) in zip(tiles, results):
        for c, b in zip(_plane_colours((r1 - r0, w), pattern), acc):
            bits[c] += b
    total_esc = sum(nesc.values())
    for c in colours:
        if total_esc:
            bits[c] += 8.0 * len(esc_blob) * nesc[c] / total_esc
    rest = 8.0 * len(blob) - sum(bits.values())  # container header, section lengths, CRC
    npix = sum(pix.values())
    for c in colours:
        bits[c] += rest * pix[c] / npix
    account["bits"] = bits
    account["pixels"] = pix


def _check_profile(measured: float | None, escaped: int, pixels: int) -> None:
    """Warn when the noise ``measured`` in a tile (``measured_noise_sigma``) contradicts the profile,
    unless most of the tile's ``pixels`` are escapes (``escaped`` of them: saturated or below black)."""
    if 2 * escaped > pixels:
        return
    if measured is not None and abs(measured - 1.0) > MISMATCH_TOLERANCE:
        warnings.warn(
            f"profile contradicts the pixels: measured noise {measured:.3f} sigma vs claimed 1.000 sigma "
            f"(transform units); the codec's error budget is relative to the claimed noise",
            ProfileMismatchWarning, stacklevel=3)


def _decode_escapes(section, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The escape section's flat pixel indices (int64) and DN (uint16), checked against a frame of ``n`` pixels."""
    esc_idx, esc_val = entropy.decode_streams(section)
    if esc_idx.size != esc_val.size:
        raise MetrawError("metraw raw-codec escape list is corrupt")
    idx = np.cumsum(esc_idx.astype(np.int64))
    if idx.size and (idx[-1] >= n or np.any(esc_val < 0) or np.any(esc_val > 65535)):
        raise MetrawError("metraw raw-codec escape list is corrupt")
    return idx, esc_val.astype(np.uint16)


def read_header(blob: bytes) -> container.Header:
    """The header of a blob (shape, step, seed, tiles, embedded metadata) after checking its CRC."""
    return container.unpack(blob)[0]


def decode(blob: bytes | memoryview, profile: CalibrationProfile | None = None) -> RawImage:
    """Decompress a blob from ``encode``: uint16 DN with the embedded profile (or ``profile`` for
    blobs encoded with ``embed_profile=False``; an explicit ``profile`` must then be the encoder's)."""
    header, sections = container.unpack(blob)
    h, w = header.shape
    step, seed, tiles = header.step, header.seed, header.tiles
    meta = header.meta or {}
    try:
        if "profile" in meta:
            prof = CalibrationProfile.from_dict(meta["profile"])
        elif profile is not None:
            prof = profile
        else:
            raise MetrawError("metraw raw-codec blob has no embedded profile: pass the profile it was encoded with")
    except (KeyError, TypeError, ValueError) as exc:
        raise MetrawError(f"metraw raw-codec header is incomplete: {exc}") from None
    if not (math.isfinite(step) and step > 0) or len(sections) != len(tiles) + 1:
        raise MetrawError("metraw raw-codec blob is malformed (step or section count)")
    out = np.empty((h, w), np.uint16)
    pattern = prof.cfa_pattern

    cell = cell_size(pattern)

    def work(args):
        if args is None:
            return _decode_escapes(sections[-1], h * w)
        (r0, r1), sec = args
        if native.LIB is None:
            us = _plane_dithers(seed, r0, r1, w, pattern)
            syms = predictive.decode_planes(sec, us)
            for (dy, dx, _, _), sym, u in zip(_plane_grid(r0, r1, w, pattern), syms, us):
                prepare.inverse_dn(sym, prof, step, u, out[r0 + dy:r1:cell, dx::cell])
            return
        # compiled: the fixed-point dither for the decoder and the inverse (making its float dither on the way) a row
        # group at a time inside the decoding loop (no plane-size dither or symbol arrays); the same values
        keys, inv = prepare.dither_keys(seed), prepare.inverse_args(prof, step)
        decoder.decode_planes_dn(sec, [
            decoder.PlaneDN(keys, (r0 + dy) * w + dx, cell * w, cell, inv, out[r0 + dy:r1:cell, dx::cell])
            for dy, dx, _, _ in _plane_grid(r0, r1, w, pattern)])

    # the escape list, if any, as one more item: decoded by whichever thread is free first after its tile (canon_dng:
    # 0.3 ms that ran on one core after the tiles), its DN put in after every tile
    items = list(zip(tiles, sections[:-1])) + ([None] if len(sections[-1]) else [])
    results = _map_tiles(work, items)
    if len(sections[-1]):
        esc_idx, esc_val = results[-1]
        out.reshape(-1)[esc_idx] = esc_val
    provenance = list(meta.get("provenance", [])) + [
        {"function": "metraw.codec", "params": {"step": step, "seed": seed}}]
    return RawImage(data=out, profile=prof, provenance=provenance, meta=dict(meta.get("meta", {})))
