"""Preparation: variance-stabilising transform, subtractive dither, escapes, unbiased inverse.

Per pixel (DN ``y``, profile gain K, black b, read variance s^2 incl. ADC rounding, see
``metraw.vst``), with c = 3/8 + s^2 and x = (y - b) / K photoelectrons:

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

import numpy as np

from metraw.profile import CalibrationProfile
from metraw.vst import effective_read_variance_e2

_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)
_GOLDEN = np.uint32(0x9E3779B9)


def _splitmix64(value: int) -> int:
    mask = (1 << 64) - 1
    z = (value + 0x9E3779B97F4A7C15) & mask
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
    return z ^ (z >> 31)


def dither(seed: int, start: int, count: int) -> np.ndarray:
    """Uniform dither in [-1/2, 1/2) for flat pixel indices ``start .. start+count-1`` (float64).

    Counter-based: each value is a hash (lowbias32, C. Wellons) of the pixel index keyed by
    ``splitmix64(seed)``, so any tile regenerates its own dither without the rest of the frame.
    The 24-bit output is exact in float32/float64.
    """
    key = _splitmix64(int(seed))
    k1 = np.uint32(key & 0xFFFFFFFF)
    k2 = np.uint32((key >> 32) & 0xFFFFFFFF)
    with np.errstate(over="ignore"):
        x = np.arange(start, start + count, dtype=np.uint32)
        x = x * _GOLDEN + k1
        x ^= x >> np.uint32(16)
        x *= _M1
        x ^= x >> np.uint32(15)
        x *= _M2
        x ^= k2
        x ^= x >> np.uint32(16)
    return (x >> np.uint32(8)).astype(np.float64) * (1.0 / 16777216.0) - 0.5


def offset_e(profile: CalibrationProfile) -> float:
    """c = 3/8 + s^2 [e-]: the transform's offset (``metraw.vst.anscombe``)."""
    return 0.375 + effective_read_variance_e2(profile)


def escape_mask(data: np.ndarray, profile: CalibrationProfile) -> np.ndarray:
    """Pixels stored losslessly: saturated (>= white) or below the transform's domain."""
    low = profile.black_level_dn - profile.gain_dn_per_e * offset_e(profile)
    return (data >= profile.white_level_dn) | (data <= low)


def forward(data: np.ndarray, profile: CalibrationProfile, step: float, u: np.ndarray) -> np.ndarray:
    """Symbols k = round(z / q + u) (int32) for DN ``data`` with dither ``u`` (same shape).

    Escaped pixels get the symbol of the nearest valid value so prediction stays smooth.
    """
    k = profile.gain_dn_per_e
    c = offset_e(profile)
    x = (data.astype(np.float64) - profile.black_level_dn) * (1.0 / k) + c
    x = np.minimum(np.maximum(x, 0.0), (profile.white_level_dn - profile.black_level_dn) / k + c)
    z = 2.0 * np.sqrt(x)
    z *= 1.0 / step
    z += u
    return np.rint(z).astype(np.int32)


def inverse(symbols: np.ndarray, profile: CalibrationProfile, step: float, u: np.ndarray) -> np.ndarray:
    """Bias-corrected reconstruction in DN (float64, before rounding): see module docstring."""
    k = profile.gain_dn_per_e
    zh = (symbols - u) * (0.5 * step)
    return k * (zh * zh) + (profile.black_level_dn - k * offset_e(profile) - k * step * step / 48.0)


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
