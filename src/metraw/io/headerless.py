"""Headerless raw dumps (``.raw``, ``.bin``): pixels only, every property stated by the caller.

Required metadata: ``width``, ``height``, ``dtype`` (numpy name with byte order, e.g. ``<u2``,
``uint16``, ``uint8``, ``>u2``, ``float32``), ``cfa_pattern`` and ``black_level_dn``, plus
``adc_bits`` or ``white_level_dn``. Optional: ``offset_bytes`` (header to skip), ``gain_dn_per_e``
and ``read_noise_e`` (unknown -- see ``metraw.io._unknown`` -- when absent), ``stored_shift``
(low bits to shift out, e.g. 4 for 12-bit data stored x16). The file size must match exactly.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.io._unknown import UNKNOWN_GAIN_DN_PER_E, UNKNOWN_READ_NOISE_E
from metraw.io.dn import as_dn, bits_needed
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

HEADERLESS_SUFFIXES = {".raw", ".bin"}
REQUIRED = ("width", "height", "dtype", "cfa_pattern", "black_level_dn")
ALLOWED_DTYPES = ("u1", "u2", "i2", "f4", "f8")


def read_headerless(path: Path, **metadata: Any) -> RawImage:
    missing = [k for k in REQUIRED if metadata.get(k) is None]
    if metadata.get("adc_bits") is None and metadata.get("white_level_dn") is None:
        missing.append("adc_bits or white_level_dn")
    if missing:
        raise MetrawError(f"{path}: headerless raw needs metadata: {', '.join(missing)} missing "
                          "(e.g. --meta width=640 --meta height=480 --meta dtype=uint16 ...)")
    try:
        width, height = int(metadata["width"]), int(metadata["height"])
        offset = int(metadata.get("offset_bytes", 0))
    except (TypeError, ValueError):
        raise MetrawError(f"{path}: width, height and offset_bytes must be integers") from None
    if width <= 0 or height <= 0 or offset < 0:
        raise MetrawError(f"{path}: width and height must be > 0 and offset_bytes >= 0")
    try:
        dtype = np.dtype(metadata["dtype"])
    except TypeError:
        raise MetrawError(f"{path}: unknown dtype {metadata['dtype']!r}") from None
    if f"{dtype.kind}{dtype.itemsize}" not in ALLOWED_DTYPES:
        raise MetrawError(f"{path}: dtype {dtype} is not a raw pixel type (use uint8, uint16, int16, float32, float64)")
    expected = offset + width * height * dtype.itemsize
    size = path.stat().st_size
    if size != expected:
        raise MetrawError(f"{path}: file has {size} bytes but {width} x {height} {dtype} pixels + {offset} header "
                          f"bytes need {expected} ({'truncated' if size < expected else 'size mismatch'})")
    array = np.fromfile(path, dtype=dtype, offset=offset).reshape(height, width)
    data = as_dn(array, str(path))
    provenance = [{"function": "io.read_headerless", "params": {"path": str(path), "dtype": dtype.str,
                                                                "offset_bytes": offset}}]
    try:
        shift = int(metadata.get("stored_shift", 0))
    except (TypeError, ValueError):
        raise MetrawError(f"{path}: stored_shift must be an integer, got {metadata['stored_shift']!r}") from None
    if not 0 <= shift < 16:
        raise MetrawError(f"{path}: stored_shift must lie in 0..15, got {shift}")
    if shift:
        if np.any(data & np.uint16(2**shift - 1)):
            raise MetrawError(f"{path}: stored_shift={shift} but some pixels use those low bits")
        data = data >> np.uint16(shift)
        provenance.append({"function": "io.shift_unused_low_bits", "params": {"shift": shift}})
    try:
        black = float(metadata["black_level_dn"])
        if metadata.get("white_level_dn") is not None:
            white = float(metadata["white_level_dn"])
            bits = int(metadata.get("adc_bits") or bits_needed(white))
        else:
            bits = int(metadata["adc_bits"])
            white = float(2**bits - 1)
        uncertainty = {}
        gain, rn = metadata.get("gain_dn_per_e"), metadata.get("read_noise_e")
        if gain is None:
            uncertainty["gain_dn_per_e"] = math.inf
        if rn is None:
            uncertainty["read_noise_e"] = math.inf
        profile = CalibrationProfile(
            gain_dn_per_e=float(gain) if gain is not None else UNKNOWN_GAIN_DN_PER_E, black_level_dn=black,
            read_noise_e=float(rn) if rn is not None else UNKNOWN_READ_NOISE_E, white_level_dn=white,
            adc_bits=bits, cfa_pattern=str(metadata["cfa_pattern"]), camera=str(metadata.get("camera", "unknown")),
            uncertainty=uncertainty)
    except (TypeError, ValueError) as exc:
        raise MetrawError(f"{path}: bad headerless metadata ({exc})") from None
    except MetrawError as exc:
        raise MetrawError(f"{path}: headerless metadata: {exc}") from None
    if int(data.max()) > white:
        raise MetrawError(f"{path}: pixel values up to {int(data.max())} exceed the white level {white:g} "
                          "(wrong dtype, byte order or bit depth?)")
    meta = {"source_file": str(path), "format": "headerless raw"}
    if uncertainty:
        meta["unknown"] = {k: "not given in the metadata" for k in uncertainty}
    return RawImage(data=data, profile=profile, provenance=provenance, meta=meta)
