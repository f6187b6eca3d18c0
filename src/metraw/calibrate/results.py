"""What a calibration returns (``CalibrationResult``, ``ChannelCalibration``) and what both estimators share:
the frames' radiometry (black/white level, unused low bits), weighted means, the read noise and the profile
built from the per-channel fits (``metraw.calibrate``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from metraw.errors import MetrawError
from metraw.io.dn import unused_low_bits
from metraw.raw.cfa import validate_pattern
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

#: Default fraction of the saturation signal used for the photon-transfer fit (EMVA 1288).
FIT_FRACTION = 0.7


# ------------------------------------------------------------------------------ results
@dataclass
class ChannelCalibration:
    """Fitted noise model of one colour channel (DN in native units, see ``unused_low_bits``).

    ``gain_dn_per_e``, ``read_noise_e``, ``black_level_dn`` with their 1-sigma ``*_u``;
    ``saturation_dn`` the mean at the variance peak (None when not reached);
    ``prnu`` the relative gain non-uniformity sqrt(c) of the single-frame fit (None for series);
    ``n_points`` levels (series) or blocks (image) used; ``signal_range_dn`` the fitted span of
    mu - black; ``chi2_red`` the reduced chi-square of the fit.
    """

    channel: str
    gain_dn_per_e: float
    gain_dn_per_e_u: float
    read_noise_e: float
    read_noise_e_u: float
    black_level_dn: float
    black_level_dn_u: float
    n_points: int
    signal_range_dn: tuple[float, float]
    chi2_red: float
    saturation_dn: float | None = None
    prnu: float | None = None
    prnu_u: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass
class CalibrationResult:
    """Outcome of a calibration: the profile (with ``uncertainty``) and per-channel numbers."""

    profile: CalibrationProfile
    method: str
    channels: dict[str, ChannelCalibration]
    unused_low_bits: int = 0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "unused_low_bits": self.unused_low_bits,
            "notes": list(self.notes),
            "channels": {k: v.to_dict() for k, v in self.channels.items()},
            "profile": self.profile.to_dict(),
        }


# ------------------------------------------------------------------------------ input helpers
def detect_unused_low_bits(arrays: Sequence[np.ndarray], min_distinct: int = 16) -> int:
    """Number of low bits that are zero in every pixel of every array (0..8).

    Only trusted when the data hold at least ``min_distinct`` distinct values after the
    shift (a nearly constant frame would otherwise fake unused bits).
    """
    per_array = [np.bitwise_or.reduce(np.asarray(a, dtype=np.uint16), axis=None) for a in arrays]
    s = unused_low_bits(np.array(per_array, dtype=np.uint16), max_shift=8)
    if s == 0:
        return 0
    distinct = np.unique(np.asarray(arrays[0]).ravel()[:1_000_000] >> s).size
    return s if distinct >= min_distinct else 0


def _frame_array(frame: Any) -> np.ndarray:
    data = frame.data if isinstance(frame, RawImage) else np.asarray(frame)
    if data.ndim != 2 or data.size == 0:
        raise MetrawError(f"a calibration frame must be a non-empty 2-D array, got shape {data.shape}")
    if data.dtype.kind == "f":
        if not np.all(np.isfinite(data)):
            raise MetrawError("a calibration frame contains NaN or infinite values")
        if np.any(data != np.rint(data)) or data.min() < 0 or data.max() > 65535:
            raise MetrawError("a calibration frame must hold integer DN in 0..65535")
        data = data.astype(np.uint16)
    elif data.dtype.kind in "iu":
        if data.min() < 0 or data.max() > 65535:
            raise MetrawError("a calibration frame must hold integer DN in 0..65535")
        data = data.astype(np.uint16, copy=False)
    else:
        raise MetrawError(f"a calibration frame must hold integer DN, got dtype {data.dtype}")
    return data


def _first_profile(frames: Sequence[Any]) -> CalibrationProfile | None:
    for f in frames:
        if isinstance(f, RawImage):
            return f.profile
    return None


@dataclass
class _Radiometry:
    cfa_pattern: str
    black_dn: float | None
    white_dn: float
    adc_bits: int
    shift: int

    @property
    def scale(self) -> int:
        return 1 << self.shift


def _radiometry(arrays: Sequence[np.ndarray], base: CalibrationProfile | None, cfa_pattern: str | None,
                black_level_dn: float | None, white_level_dn: float | None, adc_bits: int | None,
                ) -> _Radiometry:
    """Settle pattern, black, white, ADC bits and unused low bits; returned in native units."""
    pattern = cfa_pattern or (base.cfa_pattern if base else None)
    if pattern is None:
        raise MetrawError("the CFA pattern is unknown: pass cfa_pattern (e.g. 'RGGB' or 'mono')")
    validate_pattern(pattern)
    black = black_level_dn if black_level_dn is not None else (base.black_level_dn if base else None)
    white = white_level_dn if white_level_dn is not None else (base.white_level_dn if base else None)
    shift = detect_unused_low_bits(arrays)
    scale = 1 << shift
    if white is None:
        peak = max(int(a.max()) for a in arrays) >> shift
        bits = max(8, int(peak).bit_length())
        white = float(((1 << bits) - 1) * scale)
    bits = adc_bits if adc_bits is not None else (base.adc_bits if base else None)
    if bits is None:
        bits = max(1, int(math.floor(white / scale)).bit_length())
    elif shift:
        bits = min(int(bits), max(1, int(white / scale).bit_length()))
    return _Radiometry(pattern, None if black is None else float(black) / scale, float(white) / scale,
                       int(bits), shift)


def _native(data: np.ndarray, shift: int) -> np.ndarray:
    return (data >> shift).astype(np.float64) if shift else data.astype(np.float64)


def _weighted_mean(values: np.ndarray, sigmas: np.ndarray) -> tuple[float, float, float]:
    """Inverse-variance weighted mean, its uncertainty (Birge-inflated) and reduced chi-square."""
    values, sigmas = np.asarray(values, float), np.asarray(sigmas, float)
    ok = np.isfinite(values) & np.isfinite(sigmas) & (sigmas > 0)
    if not np.any(ok):
        return float(np.mean(values)), float("inf"), float("nan")
    w = 1.0 / sigmas[ok] ** 2
    mean = float(np.sum(w * values[ok]) / np.sum(w))
    u = math.sqrt(1.0 / np.sum(w))
    n = int(ok.sum())
    chi2 = float(np.sum(w * (values[ok] - mean) ** 2) / (n - 1)) if n > 1 else 1.0
    return mean, u * math.sqrt(max(1.0, chi2)), chi2


def _read_noise(var0: float, var0_u: float, gain: float, gain_u: float) -> tuple[float, float]:
    """sigma_d = sqrt(var0 - 1/12) / K with first-order uncertainty (one-sided when var0 <= 1/12)."""
    excess = var0 - 1.0 / 12.0
    if excess <= 0:
        # Quantisation-limited: read noise not resolved; report 0 with the 1-sigma upper scale.
        return 0.0, math.sqrt(max(var0_u, 0.0)) / gain
    sd = math.sqrt(excess) / gain
    u = math.sqrt((var0_u / (2.0 * math.sqrt(excess) * gain)) ** 2 + (sd * gain_u / gain) ** 2)
    return sd, u


def _build_profile(base: CalibrationProfile | None, rad: _Radiometry, channels: dict[str, ChannelCalibration],
                   full_well_e: float | None) -> CalibrationProfile:
    names = list(channels)
    k, k_u, _ = _weighted_mean([channels[c].gain_dn_per_e for c in names], [channels[c].gain_dn_per_e_u for c in names])
    rn, rn_u, _ = _weighted_mean([channels[c].read_noise_e for c in names], [channels[c].read_noise_e_u for c in names])
    if rad.black_dn is None:
        bl, bl_u, _ = _weighted_mean([channels[c].black_level_dn for c in names],
                                     [channels[c].black_level_dn_u for c in names])
    else:
        bl, bl_u = rad.black_dn, max(ch.black_level_dn_u for ch in channels.values())
    if not k > 0:
        raise MetrawError(f"fitted gain is not positive (K = {k:.4g} DN/e-): the data do not follow the noise model")
    uncertainty = {"gain_dn_per_e": k_u, "read_noise_e": rn_u, "black_level_dn": bl_u}
    fields = dict(gain_dn_per_e=k, read_noise_e=rn, black_level_dn=bl, white_level_dn=rad.white_dn,
                  adc_bits=rad.adc_bits, cfa_pattern=rad.cfa_pattern, full_well_e=full_well_e,
                  uncertainty=uncertainty)
    if base is None:
        return CalibrationProfile(**fields)
    unc = dict(base.uncertainty)
    unc.update(uncertainty)
    fields["uncertainty"] = unc
    if full_well_e is None:
        fields["full_well_e"] = base.full_well_e
    return base.replace(**fields)
