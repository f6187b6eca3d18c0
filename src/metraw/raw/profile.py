"""Calibration profile: the EMVA 1288 linear camera model plus the imaging geometry.

A profile travels with every raw image. It states how a pixel value in DN relates to
photoelectrons and what noise it carries:

    y_DN = clip(round(K * clip(n_e + n_dark + N(0, sigma_d^2), 0, full_well) + black), 0, white)
    var(y) = K^2 sigma_d^2 + K (mu_y - black) + 1/12            [DN^2]

All quantities are SI with the unit in the name (``gain_dn_per_e``, ``exposure_s``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError
from metraw.raw.cfa import channel_names, validate_pattern

SCHEMA_VERSION = 1

#: Default pass bands per channel [m], a generic RGB Bayer filter set and a broad mono band.
DEFAULT_BANDS_M: dict[str, tuple[float, float]] = {
    "R": (590e-9, 680e-9),
    "G": (500e-9, 590e-9),
    "B": (420e-9, 500e-9),
    "L": (450e-9, 800e-9),
}


@dataclass
class CalibrationProfile:
    """Linear camera model (EMVA 1288) and geometry of one raw image.

    Radiometry: ``gain_dn_per_e`` (system gain K), ``black_level_dn``, ``read_noise_e``
    (sigma_d), ``dark_current_e_per_s``, ``white_level_dn`` (largest valid DN),
    ``full_well_e``, ``adc_bits``, ``cfa_pattern`` ("RGGB", ..., or "mono"),
    ``qe_per_channel`` (quantum efficiency per CFA colour, dimensionless) and
    ``band_edges_m`` (pass band per colour).

    Geometry: ``pixel_pitch_m``, ``focal_length_m``, ``aperture_diameter_m``,
    ``obscuration_ratio`` (central obscuration diameter / aperture diameter),
    ``altitude_m``, ``exposure_s``, ``ground_speed_m_per_s``, ``optical_transmission``.
    Unknown geometry is ``None``.

    ``uncertainty`` maps a field name to its 1-sigma standard uncertainty (same unit).
    ``approximate`` marks a profile that is not a measurement of a real raw sensor
    (e.g. a raw reconstructed from an 8-bit processed image); ``approximate_reason`` says why.
    """

    gain_dn_per_e: float
    black_level_dn: float
    read_noise_e: float
    white_level_dn: float
    adc_bits: int
    cfa_pattern: str = "RGGB"
    full_well_e: float | None = None
    dark_current_e_per_s: float = 0.0
    qe_per_channel: dict[str, float] = field(default_factory=dict)
    band_edges_m: dict[str, tuple[float, float]] = field(default_factory=dict)
    pixel_pitch_m: float | None = None
    focal_length_m: float | None = None
    aperture_diameter_m: float | None = None
    obscuration_ratio: float = 0.0
    altitude_m: float | None = None
    exposure_s: float | None = None
    ground_speed_m_per_s: float = 0.0
    optical_transmission: float = 1.0
    camera: str = "unknown"
    uncertainty: dict[str, float] = field(default_factory=dict)
    approximate: bool = False
    approximate_reason: str = ""

    def __post_init__(self) -> None:
        validate_pattern(self.cfa_pattern)
        self.adc_bits = int(_number("adc_bits", self.adc_bits))
        for name in ("gain_dn_per_e", "black_level_dn", "read_noise_e", "white_level_dn"):
            value = _number(name, getattr(self, name))
            if not math.isfinite(value):
                raise MetrawError(f"profile field {name} must be finite, got {value}")
            setattr(self, name, value)
        for name in ("qe_per_channel", "band_edges_m", "uncertainty"):
            if not isinstance(getattr(self, name), dict):
                raise MetrawError(f"profile field {name} must be an object (name -> value), got "
                                  f"{type(getattr(self, name)).__name__}")
        if self.gain_dn_per_e <= 0:
            raise MetrawError(f"profile gain_dn_per_e must be > 0, got {self.gain_dn_per_e}")
        if self.read_noise_e < 0:
            raise MetrawError(f"profile read_noise_e must be >= 0, got {self.read_noise_e}")
        if not 1 <= self.adc_bits <= 16:
            raise MetrawError(f"profile adc_bits must be in 1..16, got {self.adc_bits}")
        if not self.black_level_dn < self.white_level_dn <= 65535:
            raise MetrawError(
                f"profile needs black_level_dn < white_level_dn <= 65535, got "
                f"{self.black_level_dn} and {self.white_level_dn}"
            )
        if not 0.0 <= self.obscuration_ratio < 1.0:
            raise MetrawError(f"profile obscuration_ratio must be in [0, 1), got {self.obscuration_ratio}")
        if not self.qe_per_channel:
            self.qe_per_channel = {c: 1.0 for c in self.channels}
        if not self.band_edges_m:
            self.band_edges_m = {c: DEFAULT_BANDS_M[c] for c in self.channels}
        try:
            self.band_edges_m = {k: (float(v[0]), float(v[1])) for k, v in self.band_edges_m.items()}
        except (TypeError, ValueError, IndexError, KeyError):
            raise MetrawError(f"profile field band_edges_m must map each colour to [low, high] in m, "
                              f"got {self.band_edges_m!r}") from None

    # ----------------------------------------------------------------- derived values
    @property
    def channels(self) -> tuple[str, ...]:
        """Distinct colour names of the CFA ("R", "G", "B") or ("L",) for mono."""
        return channel_names(self.cfa_pattern)

    @property
    def is_mono(self) -> bool:
        return self.cfa_pattern == "mono"

    @property
    def gsd_m(self) -> float | None:
        """Ground sample distance [m] = pitch * altitude / focal length (nadir)."""
        if None in (self.pixel_pitch_m, self.altitude_m, self.focal_length_m):
            return None
        return self.pixel_pitch_m * self.altitude_m / self.focal_length_m

    @property
    def saturation_e(self) -> float:
        """Largest photoelectron count that reads as a valid (unclipped) value."""
        adc_limit = (self.white_level_dn - self.black_level_dn) / self.gain_dn_per_e
        return adc_limit if self.full_well_e is None else min(adc_limit, self.full_well_e)

    def variance_dn2(self, mean_dn):
        """Temporal noise variance [DN^2] of a pixel whose expected value is ``mean_dn``.

        EMVA 1288: K^2 sigma_d^2 + K (mu_y - black) + 1/12 (quantisation). Works on arrays.
        Means below black are treated as black (no negative shot noise).
        """
        import numpy as np

        signal = np.maximum(np.asarray(mean_dn, dtype=np.float64) - self.black_level_dn, 0.0)
        k = self.gain_dn_per_e
        return k * k * self.read_noise_e**2 + k * signal + 1.0 / 12.0

    # ----------------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["band_edges_m"] = {k: list(v) for k, v in self.band_edges_m.items()}
        out["schema_version"] = SCHEMA_VERSION
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "CalibrationProfile":
        if not isinstance(data, dict):
            raise MetrawError(f"profile must be an object of fields, got {type(data).__name__}")
        data = dict(data)
        version = data.pop("schema_version", SCHEMA_VERSION)  # a hand-written profile: the current schema
        if version != SCHEMA_VERSION:
            raise MetrawError(f"profile schema_version {version} is not supported (this metraw reads {SCHEMA_VERSION})")
        fields = dataclasses.fields(cls)
        unknown = sorted(set(data) - {f.name for f in fields})
        if unknown:
            raise MetrawError(f"profile has unknown fields: {', '.join(unknown)}")
        missing = [f.name for f in fields if f.name not in data
                   and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
        if missing:
            raise MetrawError(f"profile lacks required field(s): {', '.join(missing)}")
        try:
            return cls(**data)
        except (TypeError, ValueError) as exc:
            raise MetrawError(f"profile has a field of the wrong type: {exc}") from None

    def to_json(self, indent: int | None = 2) -> str:
        return json.dumps(self.to_dict(), indent=indent, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "CalibrationProfile":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise MetrawError(f"profile is not valid JSON: {exc}") from None
        if not isinstance(data, dict):
            raise MetrawError("profile JSON must be an object")
        return cls.from_dict(data)

    def replace(self, **changes: Any) -> "CalibrationProfile":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def _number(name: str, value: Any) -> float:
    """``value`` as a float, or a ``MetrawError`` naming the field (a string or null is not a number)."""
    if isinstance(value, bool):
        raise MetrawError(f"profile field {name} must be a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise MetrawError(f"profile field {name} must be a number, got {value!r}") from None


#: Geometry and sensor fields that, when stated, must be finite and > 0.
_POSITIVE_WHEN_GIVEN = ("pixel_pitch_m", "focal_length_m", "aperture_diameter_m", "altitude_m", "exposure_s",
                        "full_well_e")


def check_claims(profile: CalibrationProfile) -> CalibrationProfile:
    """Refuse what no real camera states, for profiles the user supplies (``--profile``, ``--camera``,
    ``source.camera``); profiles metraw wrote itself (stores, TIFF and codec headers) are not held to this.

    Geometry and full well, when given, must be finite and > 0; dark current, ground speed >= 0;
    transmission and QE in [0, 1]; a read noise of exactly 0 e- only with an uncertainty saying what it
    is (finite: measured and not resolved; ``Infinity``: unknown) -- a bare 0 is not a sensor's read noise.
    """
    for name in _POSITIVE_WHEN_GIVEN:
        value = getattr(profile, name)
        if value is not None and not 0 < _number(name, value) < math.inf:
            raise MetrawError(f"profile {name} must be > 0 when given, got {value}")
    for name in ("dark_current_e_per_s", "ground_speed_m_per_s"):
        value = _number(name, getattr(profile, name))
        if not 0 <= value < math.inf:
            raise MetrawError(f"profile {name} must be >= 0, got {value}")
    fractions = {"optical_transmission": profile.optical_transmission,
                 **{f"qe_per_channel.{c}": v for c, v in profile.qe_per_channel.items()}}
    for name, value in fractions.items():
        if not 0 <= _number(name, value) <= 1:
            raise MetrawError(f"profile {name} must lie in [0, 1], got {value}")
    if profile.read_noise_e == 0 and "read_noise_e" not in profile.uncertainty:
        raise MetrawError("profile read_noise_e is 0 e-, which no sensor has: give the measured read noise, or "
                          "state its uncertainty (Infinity marks it unknown)")
    return profile


def load_profile(path: str | Path, base: CalibrationProfile | None = None) -> CalibrationProfile:
    """A calibration profile the user supplies in a JSON file, checked with `check_claims`.

    The file holds a full profile (``CalibrationProfile.to_json``, or written by hand from docs/noise-model.md's
    fields: a missing ``schema_version`` means the current one) or, when
    ``base`` is given, an object of fields replacing base's (e.g. ``{"gain_dn_per_e": 0.5}``): a field
    stated there loses base's "unknown" mark (infinite uncertainty) unless the file gives its own
    ``uncertainty``. Every problem is one ``MetrawError`` naming the file.
    """
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise MetrawError(f"cannot read profile {path}: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MetrawError(f"profile {path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise MetrawError(f"profile {path} must hold a JSON object, got {type(data).__name__}")
    try:
        if base is None or "schema_version" in data:
            return check_claims(CalibrationProfile.from_dict(data))
        unknown = sorted(set(data) - {f.name for f in dataclasses.fields(CalibrationProfile)})
        if unknown:
            raise MetrawError(f"profile has unknown fields: {', '.join(unknown)}")
        try:
            unc = {k: v for k, v in base.uncertainty.items() if k not in data}
            unc.update(data.pop("uncertainty", None) or {})
            return check_claims(base.replace(**data, uncertainty=unc))
        except (TypeError, ValueError) as exc:
            raise MetrawError(f"profile has a field of the wrong type: {exc}") from None
    except MetrawError as exc:
        raise MetrawError(f"{path}: {exc}") from None
