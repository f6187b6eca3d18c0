"""Preparation: variance-stabilising transform, subtractive dither, escapes, unbiased inverse.

Per pixel (DN ``y``, profile gain K, black b, read variance s^2 incl. ADC rounding, see
``metraw.raw.vst``), with c = 3/8 + s^2 and x = (y - b) / K photoelectrons:

    z = 2 sqrt(x + c)                     generalised Anscombe (unit noise sigma)
    k = round(z / q + u)                  u ~ U[-1/2, 1/2) from a counter-based hash of
                                          (seed, pixel index): nothing stored per pixel
    z_hat = (k - u) q = z + e             subtractive dither: e ~ U[-q/2, q/2], independent
                                          of z and of every other pixel's e
    y_hat = K ((z_hat / 2)^2 - c) + b - K q^2 / 48

Because the inverse is exactly quadratic, E[y_hat | y] = y + K E[z e / 2 + e^2 / 4] - K q^2/48
= y exactly (E e = 0, E e^2 = q^2 / 12): the curvature bias is a constant, removed exactly.
The error in DN is K (z e / 2 + (e^2 - q^2/12) / 4), so in units of the transform's noise scale
sigma_T(y) = K z / 2 = sqrt(sigma_y^2 + 3 K^2 / 8) it is e + (e^2 - q^2/12) / (2 z):
uniform of variance q^2/12 plus a curvature term that vanishes for bright pixels.
Bound: |y_hat - y| <= q sigma_T / 2 + K q^2 / 24 before the final rounding to integer DN,
which adds at most 0.5 DN (see ``error_bound_dn``).

Escapes (stored losslessly): pixels at or above the white level (saturated) and pixels so far
below black that the transform is undefined (x + c <= 0).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from metraw.codec import native
from metraw.raw.profile import CalibrationProfile
from metraw.raw.vst import effective_read_variance_e2



def _splitmix64(value: int) -> int:
    mask = (1 << 64) - 1
    z = (value + 0x9E3779B97F4A7C15) & mask
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
    return z ^ (z >> 31)


@nb.njit(cache=True, nogil=True, inline="always")
def _dither_value(index, k1, k2):
    """The dither of flat pixel ``index`` (lowbias32 keyed by k1, k2), in [-1/2, 1/2)."""
    m = np.uint64(0xFFFFFFFF)
    x = (np.uint64(index) * np.uint64(0x9E3779B9) + np.uint64(k1)) & m
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & m
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & m
    x ^= np.uint64(k2)
    x ^= x >> np.uint64(16)
    return np.float64(x >> np.uint64(8)) * (1.0 / 16777216.0) - 0.5


@nb.njit(cache=True, nogil=True)
def _dither_kernel(k1, k2, start, count):
    out = np.empty(count, np.float64)
    for i in range(count):
        out[i] = _dither_value(start + i, k1, k2)
    return out


@nb.njit(cache=True, nogil=True)
def _dither_grid_kernel(k1, k2, start, rows, cols, row_step, col_step):
    out = np.empty((rows, cols), np.float64)
    for i in range(rows):
        base = start + i * row_step
        for j in range(cols):
            out[i, j] = _dither_value(base + j * col_step, k1, k2)
    return out


def dither_keys(seed: int) -> tuple[int, int]:
    """The dither hash's two 32-bit keys (k1, k2) for ``seed`` (``dither``)."""
    key = _splitmix64(int(seed))
    return key & 0xFFFFFFFF, (key >> 32) & 0xFFFFFFFF


def dither(seed: int, start: int, count: int) -> np.ndarray:
    """Uniform dither in [-1/2, 1/2) for flat pixel indices ``start .. start+count-1`` (float64).

    Counter-based: each value is a hash (lowbias32, C. Wellons) of the 32-bit pixel index keyed
    by ``splitmix64(seed)``, so any tile regenerates its own dither without the rest of the
    frame. The 24-bit output is exact in float32/float64. Compiled (numba), releases the GIL.
    """
    return _dither_kernel(*dither_keys(seed), int(start), int(count))


def dither_grid(seed: int, start: int, rows: int, cols: int, row_step: int, col_step: int) -> np.ndarray:
    """``dither`` of the pixels start + i row_step + j col_step (i < rows, j < cols) as a contiguous
    (rows, cols) array: a CFA plane's dither without the rest of the frame's."""
    args = (*dither_keys(seed), int(start), int(rows), int(cols), int(row_step), int(col_step))
    if native.LIB is not None:
        return native.dither_grid(*args)
    return _dither_grid_kernel(*args)


def offset_e(profile: CalibrationProfile) -> float:
    """c = 3/8 + s^2 [e-]: the transform's offset (``metraw.raw.vst.anscombe``)."""
    return 0.375 + effective_read_variance_e2(profile)


@nb.njit(cache=True, nogil=True)
def _escape_kernel(data, white, low, out):
    for i in range(data.size):
        v = np.float64(data[i])
        out[i] = (v >= white) | (v <= low)


def _domain_low_dn(profile: CalibrationProfile) -> float:
    """The DN at or below which the transform is undefined (x + c <= 0): escaped."""
    return profile.black_level_dn - profile.gain_dn_per_e * offset_e(profile)


def escape_mask(data: np.ndarray, profile: CalibrationProfile) -> np.ndarray:
    """Pixels stored losslessly: saturated (>= white) or below the transform's domain."""
    low = _domain_low_dn(profile)
    data = np.asarray(data)
    if data.dtype == np.uint16 and data.flags.c_contiguous:  # one compiled pass, no temporaries
        out = np.empty(data.shape, np.bool_)
        _escape_kernel(data.reshape(-1), float(profile.white_level_dn), float(low), out.reshape(-1))
        return out
    return (data >= profile.white_level_dn) | (data <= low)


def escape_index(data: np.ndarray, profile: CalibrationProfile, offset: int = 0) -> np.ndarray:
    """``np.flatnonzero(escape_mask(data, profile)) + offset`` (int64): in one compiled pass where
    ``metraw.codec.native`` is built and ``data`` is C-contiguous uint16 (the bounds as integers: the same pixels)."""
    data = np.asarray(data)
    if native.LIB is None or data.dtype != np.uint16 or not data.flags.c_contiguous:
        return np.flatnonzero(escape_mask(data, profile)) + offset
    return native.escape_index(data, math.ceil(min(profile.white_level_dn, 65536.0)),
                               math.floor(max(_domain_low_dn(profile), -1.0)), offset)


@nb.njit(cache=True, nogil=True)
def _forward_kernel(data, black, inv_k, c, xmax, inv_step, u):
    h, w = data.shape
    out = np.empty((h, w), np.int32)
    row = np.empty(w, np.float64)
    for i in range(h):
        # the row first gathered into a contiguous buffer: ``data`` may be a strided view (a CFA plane of
        # the tile), and the arithmetic below vectorises (sqrt included) only on contiguous rows
        for j in range(w):
            row[j] = data[i, j]
        ui = u[i]
        oi = out[i]
        for j in range(w):
            x = (row[j] - black) * inv_k + c
            x = min(max(x, 0.0), xmax)
            z = 2.0 * np.sqrt(x)
            z *= inv_step
            z += ui[j]
            oi[j] = np.int32(np.rint(z))
    return out


def forward_args(profile: CalibrationProfile, step: float) -> tuple[float, float, float, float, float]:
    """The forward transform's constants (black [DN], 1 / K [e-/DN], c [e-], xmax [e-], 1 / q) for the compiled
    kernels: z = 2 sqrt(min(max((y - black) / K + c, 0), xmax)) (see ``forward``)."""
    k = profile.gain_dn_per_e
    c = offset_e(profile)
    xmax = (profile.white_level_dn - profile.black_level_dn) / k + c
    return float(profile.black_level_dn), 1.0 / k, c, xmax, 1.0 / step


def forward(data: np.ndarray, profile: CalibrationProfile, step: float, u: np.ndarray) -> np.ndarray:
    """Symbols k = round(z / q + u) (int32) for DN ``data`` with dither ``u`` (same shape).

    Escaped pixels get the symbol of the nearest valid value so prediction stays smooth.
    """
    data = np.asarray(data)
    if data.ndim != 2:
        return forward(data.reshape(1, -1), profile, step, np.asarray(u).reshape(1, -1)).reshape(data.shape)
    args = forward_args(profile, step)
    if native.LIB is not None and data.dtype == np.uint16 and all(st > 0 for st in data.strides):
        return native.forward(data, *args, np.ascontiguousarray(u, dtype=np.float64))
    return _forward_kernel(data, *args, np.asarray(u, dtype=np.float64))


def inverse(symbols: np.ndarray, profile: CalibrationProfile, step: float, u: np.ndarray) -> np.ndarray:
    """Bias-corrected reconstruction in DN (float64, before rounding): see module docstring."""
    k = profile.gain_dn_per_e
    zh = (symbols - u) * (0.5 * step)
    return k * (zh * zh) + (profile.black_level_dn - k * offset_e(profile) - k * step * step / 48.0)


@nb.njit(cache=True, nogil=True)
def _inverse_dn_kernel(sym, u, half_step, k, offset, out):
    h, w = sym.shape
    row = np.empty(w, np.uint16)
    for i in range(h):
        # computed into a contiguous row (vectorises), then stored: ``out`` may be a strided view
        si = sym[i]
        ui = u[i]
        for j in range(w):
            zh = (np.float64(si[j]) - ui[j]) * half_step
            v = np.rint(k * (zh * zh) + offset)
            row[j] = np.uint16(min(max(v, 0.0), 65535.0))
        for j in range(w):
            out[i, j] = row[j]


def inverse_dn(symbols: np.ndarray, profile: CalibrationProfile, step: float, u: np.ndarray,
               out: np.ndarray | None = None) -> np.ndarray:
    """``to_dn(inverse(...))`` in one compiled pass (same float64 arithmetic), uint16 into ``out``."""
    if out is None:
        out = np.empty(symbols.shape, np.uint16)
    _inverse_dn_kernel(symbols, np.asarray(u, np.float64), *inverse_args(profile, step), out)
    return out


def inverse_args(profile: CalibrationProfile, step: float) -> tuple[float, float, float]:
    """The inverse transform's constants (q / 2, K [DN/e-], offset [DN]) for the compiled kernels:
    y = K ((s - u) q / 2)^2 + offset with offset = black - K c - K q^2 / 48 (see ``inverse``)."""
    k = profile.gain_dn_per_e
    return 0.5 * step, k, profile.black_level_dn - k * offset_e(profile) - k * step * step / 48.0


def to_dn(values: np.ndarray) -> np.ndarray:
    """Final rounding to integer DN, clipped to the uint16 range."""
    return np.clip(np.rint(values), 0, 65535).astype(np.uint16)


def sigma_t_dn(data: np.ndarray, profile: CalibrationProfile) -> np.ndarray:
    """The transform's local noise scale sigma_T = K sqrt(x + c) [DN] (the codec's 'sigma')."""
    k = profile.gain_dn_per_e
    x = (np.asarray(data, dtype=np.float64) - profile.black_level_dn) / k + offset_e(profile)
    return k * np.sqrt(np.maximum(x, 0.0))


def error_bound_dn(data: np.ndarray, profile: CalibrationProfile, step: float) -> np.ndarray:
    """Per-pixel bound on |decoded - original| [DN]: q sigma_T / 2 + K q^2 / 24 + 0.5 (0 if escaped)."""
    bound = 0.5 * step * sigma_t_dn(data, profile) + profile.gain_dn_per_e * step * step / 24.0 + 0.5
    return np.where(escape_mask(np.asarray(data), profile), 0.0, bound)
