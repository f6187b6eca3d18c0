"""How a profile says "this number is not known" (gain, read noise, black level of some files).

A ``CalibrationProfile`` needs finite numbers, but many files (DNG, MicaSense TIFF, GeoTIFF) do
not state the system gain K or the read noise. metraw does not invent them: it stores a
*convention* value and marks the field unknown with ``uncertainty[field] = inf`` and a note in
``RawImage.meta["unknown"]``. ``metraw calibrate`` (``metraw.calibrate``) replaces them with a fit
and a finite uncertainty. The conventions are:

- ``gain_dn_per_e = 1.0``: photoelectrons are read as "DN above black" until calibrated;
- ``read_noise_e = 0.0``;
- for unknown black level (processed products): ``black_level_dn = 0``.

No camera table is shipped: no published gain / read-noise values could be verified for the
cameras in data/real (Canon 550D via Magic Lantern without ISO, MicaSense RedEdge,
WorldView pan products), so they are all reported as unknown.
"""

from __future__ import annotations

import math

from metraw.raw.profile import CalibrationProfile

UNKNOWN_GAIN_DN_PER_E = 1.0
UNKNOWN_READ_NOISE_E = 0.0
UNKNOWN_BLACK_LEVEL_DN = 0.0


def unknown_fields(profile: CalibrationProfile) -> list[str]:
    """Fields of ``profile`` whose value is a convention, not a measurement (uncertainty = inf)."""
    return sorted(k for k, v in profile.uncertainty.items() if not math.isfinite(v))


def noise_model_known(profile: CalibrationProfile) -> bool:
    """True when gain, read noise and black level all carry a finite (or no) uncertainty."""
    return not {"gain_dn_per_e", "read_noise_e", "black_level_dn"} & set(unknown_fields(profile))


def unknown_uncertainty(*fields: str) -> dict[str, float]:
    return {f: math.inf for f in fields}
