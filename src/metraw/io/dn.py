"""Validation of decoded pixel arrays as integer digital numbers (DN), and unused-low-bit detection."""

from __future__ import annotations

import numpy as np

from metraw.errors import MetrawError


def as_dn(array: np.ndarray, what: str) -> np.ndarray:
    """Return ``array`` as a 2-D uint16 DN array, or raise ``MetrawError`` saying why it is not one.

    Accepts unsigned/signed integers and floats whose values are finite, integral and in
    [0, 65535]; anything else (NaN, negative or fractional values, complex, > 16 bits) is refused:
    a raw pixel is an ADC count, and silently rounding or clipping it would bias it.
    """
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.ndim != 2 or a.size == 0:
        raise MetrawError(f"{what}: expected one 2-D band of raw pixels, got shape {a.shape}")
    kind = a.dtype.kind
    if kind == "b" or kind not in "uif":
        raise MetrawError(f"{what}: unsupported pixel dtype {a.dtype} (raw DN must be integers 0..65535)")
    if a.dtype == np.uint16:
        return a
    if kind == "f":
        n_bad = int(np.count_nonzero(~np.isfinite(a)))
        if n_bad:
            raise MetrawError(f"{what}: float data contains {n_bad} NaN/inf values; raw DN must be finite")
        if np.any(a != np.floor(a)):
            raise MetrawError(f"{what}: float data has fractional values; raw DN must be integer counts "
                              "(this looks like processed, not raw, data)")
    lo, hi = a.min(), a.max()
    if lo < 0:
        raise MetrawError(f"{what}: {int(np.count_nonzero(a < 0))} negative values (min {lo}); raw DN are "
                          "counts >= 0 (signed or offset-corrected data is not raw)")
    if hi > 65535:
        raise MetrawError(f"{what}: values {lo}..{hi} do not fit unsigned 16-bit DN (wrong dtype for raw data?)")
    return a.astype(np.uint16)


def unused_low_bits(data: np.ndarray, max_shift: int = 8) -> int:
    """Number of low bits that are zero in *every* pixel (e.g. 4 for 12-bit data stored x16).

    Returns 0 for an all-zero image. Capped at ``max_shift``.
    """
    acc = int(np.bitwise_or.reduce(np.asarray(data, dtype=np.uint16).ravel()))
    if acc == 0:
        return 0
    shift = (acc & -acc).bit_length() - 1
    return min(shift, max_shift)


def bits_needed(value: float) -> int:
    """Smallest ADC bit depth whose range 0..2^b-1 holds ``value``."""
    return max(1, int(np.ceil(np.log2(float(value) + 1.0))))
