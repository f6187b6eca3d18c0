"""RawImage: uint16 DN pixels with their calibration profile, label mask and provenance."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import color_index, split_planes
from metraw.raw.profile import CalibrationProfile

#: Bits of ``RawImage.flags``.
FLAG_SATURATED = 1  #: the pixel (or a source pixel feeding it) reached saturation
FLAG_DEFECT = 2  #: known defective pixel
FLAG_BELOW_BLACK = 4  #: the value is below the black level (read noise on a dark pixel)


@dataclass
class RawImage:
    """A calibrated raw image.

    ``data``: (H, W) uint16 digital numbers as the sensor's ADC produced them.
    ``profile``: the camera model and geometry that give every pixel its noise model.
    ``mask``: optional (H, W) float32 label, the fraction of each pixel's area covered by
    the target class (cars); exact 0/1 at source resolution, fractional after resampling.
    ``flags``: optional (H, W) uint8 bit mask (``FLAG_*``).
    ``provenance``: the raw functions applied so far, each ``{"function": name, "params": {...}}``.
    ``meta``: free-form descriptive metadata (scene type, source file, ...).
    """

    data: np.ndarray
    profile: CalibrationProfile
    mask: np.ndarray | None = None
    flags: np.ndarray | None = None
    provenance: list[dict[str, Any]] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.dtype != np.uint16:
            raise MetrawError(f"raw pixel data must be uint16 DN, got {data.dtype}")
        if data.ndim != 2 or data.size == 0:
            raise MetrawError(f"raw pixel data must be a non-empty 2-D array, got shape {data.shape}")
        self.data = data
        if not isinstance(self.profile, CalibrationProfile):
            raise MetrawError("RawImage needs a CalibrationProfile")
        if self.mask is not None:
            mask = np.asarray(self.mask, dtype=np.float32)
            if mask.shape != data.shape:
                raise MetrawError(f"mask shape {mask.shape} differs from image shape {data.shape}")
            if not np.all(np.isfinite(mask)) or mask.min(initial=0) < 0 or mask.max(initial=0) > 1:
                raise MetrawError("mask values must be finite fractions in [0, 1]")
            self.mask = mask
        if self.flags is not None:
            flags = np.asarray(self.flags)
            if flags.shape != data.shape or flags.dtype != np.uint8:
                raise MetrawError("flags must be a uint8 array of the image's shape")

    # ----------------------------------------------------------------- views
    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape  # type: ignore[return-value]

    @property
    def cfa_pattern(self) -> str:
        return self.profile.cfa_pattern

    def color_index(self) -> np.ndarray:
        """Per-pixel index into ``profile.channels``."""
        return color_index(self.cfa_pattern, self.shape)

    def planes(self) -> list[np.ndarray]:
        """Views of the CFA sub-lattices (see ``metraw.raw.cfa.plane_offsets``)."""
        return split_planes(self.data, self.cfa_pattern)

    def electrons(self) -> np.ndarray:
        """Estimated photoelectrons per pixel, (DN - black) / K, float64 (may be negative)."""
        return (self.data.astype(np.float64) - self.profile.black_level_dn) / self.profile.gain_dn_per_e

    def saturated(self) -> np.ndarray:
        """Boolean map of pixels at or above the white level, or flagged saturated."""
        sat = self.data >= self.profile.white_level_dn
        if self.flags is not None:
            sat |= (self.flags & FLAG_SATURATED) != 0
        return sat

    def variance_dn2(self) -> np.ndarray:
        """Per-pixel noise variance [DN^2] from the profile, evaluated at the observed value."""
        return self.profile.variance_dn2(self.data)

    # ----------------------------------------------------------------- derivation
    def derive(self, data: np.ndarray, profile: CalibrationProfile | None = None, *,
               function: str, params: dict[str, Any], mask: np.ndarray | None | str = "keep",
               flags: np.ndarray | None | str = "keep") -> "RawImage":
        """A new image produced by a raw function: new pixels, profile, provenance entry appended."""
        return RawImage(
            data=data,
            profile=profile if profile is not None else self.profile,
            mask=self.mask if isinstance(mask, str) else mask,
            flags=self.flags if isinstance(flags, str) else flags,
            provenance=self.provenance + [{"function": function, "params": _jsonable(params)}],
            meta=copy.deepcopy(self.meta),
        )

    def summary(self) -> dict[str, Any]:
        p = self.profile
        return {
            "shape": list(self.shape),
            "cfa_pattern": p.cfa_pattern,
            "black_level_dn": p.black_level_dn,
            "white_level_dn": p.white_level_dn,
            "adc_bits": p.adc_bits,
            "gain_dn_per_e": p.gain_dn_per_e,
            "read_noise_e": p.read_noise_e,
            "approximate": p.approximate,
            "min_dn": int(self.data.min()),
            "max_dn": int(self.data.max()),
            "mask": self.mask is not None,
            "provenance": [step["function"] for step in self.provenance],
        }


def _jsonable(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples inside params to plain JSON types."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value
