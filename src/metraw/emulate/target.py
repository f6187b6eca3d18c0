"""TargetSystem: the imaging system (satellite payload) an emulation produces raws for.

All fields are SI with the unit in the name. Ground geometry is nadir: GSD = pitch * altitude /
focal length. The target frame is placed on the source's ground footprint: centred on the source
frame's centre, shifted by ``frame_offset_m`` (x along source columns, y along source rows) and
rotated by ``frame_rotation_rad`` (counter-clockwise from the source's column axis to the
target's column axis). ``frame_shape_px`` (rows, cols) fixes the target frame size; ``None``
takes the largest frame that fits in the source footprint under the emulation's edge policy.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError
from metraw.physics.atmosphere import path_radiance_electrons
from metraw.raw.cfa import channel_names, validate_pattern
from metraw.raw.profile import DEFAULT_BANDS_M, CalibrationProfile


@dataclass(frozen=True)
class TargetSystem:
    """A target imaging system (see module docstring for the frame geometry).

    Optics: ``diameter_m`` (primary mirror), ``obscuration_ratio`` (central obscuration diameter /
    diameter), ``focal_length_m``, ``optical_transmission``, ``jitter_rms_rad`` (line-of-sight
    jitter, 1-sigma per axis). Orbit: ``altitude_m``, ``ground_speed_m_per_s`` and
    ``track_angle_rad`` (direction of ground motion, from the source's column axis).
    Atmosphere (`metraw.physics.atmosphere`): ``atmospheric_transmission`` (one way, ground to payload, on the
    scene's light); ``path_radiance_w_m2_sr_m`` (spectral path radiance at 550 nm) with its spectral
    slope ``path_radiance_exponent`` (L ~ lambda^-a), collected through the target's own optics,
    exposure and pixel; ``haze_e``: further path-radiance photoelectrons per pixel given directly (a
    number for every channel, or a mapping per channel; 0 when the radiance is used). Detector: ``pixel_pitch_m``, ``cfa_pattern``,
    ``exposure_s``, ``qe_per_channel``, ``read_noise_e``, ``gain_dn_per_e``, ``black_level_dn``,
    ``adc_bits``, ``full_well_e``, ``dark_current_e_per_s``, ``band_edges_m`` (pass band per
    channel; default `metraw.raw.profile.DEFAULT_BANDS_M`).
    """

    altitude_m: float
    diameter_m: float
    focal_length_m: float
    pixel_pitch_m: float
    exposure_s: float
    cfa_pattern: str = "RGGB"
    obscuration_ratio: float = 0.0
    ground_speed_m_per_s: float = 0.0
    track_angle_rad: float = 0.0
    optical_transmission: float = 1.0
    atmospheric_transmission: float = 1.0
    qe_per_channel: dict[str, float] = field(default_factory=dict)
    band_edges_m: dict[str, tuple[float, float]] = field(default_factory=dict)
    read_noise_e: float = 0.0
    gain_dn_per_e: float = 1.0
    black_level_dn: float = 0.0
    adc_bits: int = 12
    full_well_e: float | None = None
    dark_current_e_per_s: float = 0.0
    haze_e: float | dict[str, float] = 0.0
    path_radiance_w_m2_sr_m: float = 0.0
    path_radiance_exponent: float = 2.0
    jitter_rms_rad: float = 0.0
    frame_offset_m: tuple[float, float] = (0.0, 0.0)
    frame_rotation_rad: float = 0.0
    frame_shape_px: tuple[int, int] | None = None
    name: str = "target"

    def __post_init__(self) -> None:
        # one typed object: every float field holds a float, however it was given (64 or 64.0 in a parameter file, a
        # value parsed from a command line), so a target states itself the same way on every route
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", "float | None") and isinstance(v, (int, float)) and not isinstance(v, bool):
                object.__setattr__(self, f.name, float(v))
        validate_pattern(self.cfa_pattern)
        for name in ("altitude_m", "diameter_m", "focal_length_m", "pixel_pitch_m", "gain_dn_per_e"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise MetrawError(f"target {name} must be a finite number > 0, got {getattr(self, name)!r}")
        for name in ("exposure_s", "ground_speed_m_per_s", "read_noise_e", "black_level_dn",
                     "dark_current_e_per_s", "jitter_rms_rad", "path_radiance_w_m2_sr_m"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0):
                raise MetrawError(f"target {name} must be a finite number >= 0, got {getattr(self, name)!r}")
        for name in ("optical_transmission", "atmospheric_transmission"):
            v = float(getattr(self, name))
            if not 0 <= v <= 1:
                raise MetrawError(f"target {name} must lie in [0, 1], got {v!r}")
        if not 0 <= self.obscuration_ratio < 1:
            raise MetrawError(f"target obscuration_ratio must lie in [0, 1), got {self.obscuration_ratio!r}")
        if not 1 <= int(self.adc_bits) <= 16:
            raise MetrawError(f"target adc_bits must be in 1..16, got {self.adc_bits!r}")
        if self.black_level_dn >= 2 ** int(self.adc_bits) - 1:
            raise MetrawError(f"target black_level_dn {self.black_level_dn} leaves no range in {self.adc_bits} bits")
        if not (math.isfinite(float(self.path_radiance_exponent)) and 0 <= self.path_radiance_exponent <= 6):
            raise MetrawError(f"target path_radiance_exponent must lie in [0, 6], got {self.path_radiance_exponent!r}")
        for c in self.channels:
            if self.qe_per_channel and c not in self.qe_per_channel:
                raise MetrawError(f"target qe_per_channel has no value for channel {c}")
        for c in self.channels:
            h = self._direct_haze(c)
            if not (math.isfinite(h) and h >= 0):
                raise MetrawError(f"target haze_e must be >= 0, got {h!r} for channel {c}")
        if self.frame_shape_px is not None:
            shape = tuple(int(v) for v in self.frame_shape_px)
            if len(shape) != 2 or min(shape) < 1:
                raise MetrawError(f"target frame_shape_px must be (rows, cols) >= 1, got {self.frame_shape_px!r}")
            object.__setattr__(self, "frame_shape_px", shape)
        object.__setattr__(self, "frame_offset_m", tuple(float(v) for v in self.frame_offset_m))
        object.__setattr__(self, "adc_bits", int(self.adc_bits))
        path = (path_radiance_electrons(self.profile(), float(self.path_radiance_w_m2_sr_m),
                                        float(self.path_radiance_exponent))
                if self.path_radiance_w_m2_sr_m else {c: 0.0 for c in self.channels})
        object.__setattr__(self, "_path_e", path)

    # ----------------------------------------------------------------- derived values
    @property
    def channels(self) -> tuple[str, ...]:
        return channel_names(self.cfa_pattern)

    @property
    def gsd_m(self) -> float:
        """Ground sample distance [m] = pitch * altitude / focal length."""
        return self.pixel_pitch_m * self.altitude_m / self.focal_length_m

    @property
    def aperture_area_m2(self) -> float:
        """Collecting area of the annular aperture [m^2]."""
        from metraw.physics.optics import pupil_area_m2

        return pupil_area_m2(self.diameter_m, self.obscuration_ratio)

    @property
    def smear_m(self) -> float:
        """Ground distance travelled during the exposure [m]."""
        return self.ground_speed_m_per_s * self.exposure_s

    def qe(self, channel: str) -> float:
        return float(self.qe_per_channel.get(channel, 1.0)) if self.qe_per_channel else 1.0

    def haze_for(self, channel: str) -> float:
        """Mean path-radiance photoelectrons per pixel of ``channel`` in one exposure: the radiance
        collected through the target's optics (`metraw.physics.atmosphere.path_radiance_electrons`) plus ``haze_e``."""
        return self._direct_haze(channel) + self._path_e[channel]

    def path_radiance_electrons(self) -> dict[str, float]:
        """Path radiance's mean photoelectrons per pixel and exposure, per channel (without ``haze_e``)."""
        return dict(self._path_e)

    def _direct_haze(self, channel: str) -> float:
        return float(self.haze_e.get(channel, 0.0)) if isinstance(self.haze_e, dict) else float(self.haze_e)

    def band(self, channel: str) -> tuple[float, float]:
        """Pass band [m] of ``channel``. A mono target's default is the span of the R, G, B bands
        (420-680 nm): emulated from a colour source it detects exactly the light that source recorded."""
        if channel in self.band_edges_m:
            lo, hi = self.band_edges_m[channel]
        elif channel == "L":
            lo, hi = min(DEFAULT_BANDS_M[c][0] for c in "RGB"), max(DEFAULT_BANDS_M[c][1] for c in "RGB")
        else:
            lo, hi = DEFAULT_BANDS_M[channel]
        return float(lo), float(hi)

    def profile(self) -> CalibrationProfile:
        """The calibration profile of the target's raw images."""
        white = float(2**self.adc_bits - 1)
        return CalibrationProfile(
            gain_dn_per_e=float(self.gain_dn_per_e), black_level_dn=float(self.black_level_dn),
            read_noise_e=float(self.read_noise_e), white_level_dn=white, adc_bits=self.adc_bits,
            cfa_pattern=self.cfa_pattern, full_well_e=None if self.full_well_e is None else float(self.full_well_e),
            dark_current_e_per_s=float(self.dark_current_e_per_s),
            qe_per_channel={c: self.qe(c) for c in self.channels},
            band_edges_m={c: self.band(c) for c in self.channels},
            pixel_pitch_m=float(self.pixel_pitch_m), focal_length_m=float(self.focal_length_m),
            aperture_diameter_m=float(self.diameter_m), obscuration_ratio=float(self.obscuration_ratio),
            altitude_m=float(self.altitude_m), exposure_s=float(self.exposure_s),
            ground_speed_m_per_s=float(self.ground_speed_m_per_s),
            optical_transmission=float(self.optical_transmission), camera=self.name,
        )

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["band_edges_m"] = {k: list(v) for k, v in self.band_edges_m.items()}
        out["frame_offset_m"] = list(self.frame_offset_m)
        out["frame_shape_px"] = None if self.frame_shape_px is None else list(self.frame_shape_px)
        return out

    def replace(self, **changes: Any) -> "TargetSystem":
        return dataclasses.replace(self, **changes)

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "TargetSystem":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise MetrawError(f"unknown target field(s): {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        values = dict(values)
        for name in ("frame_offset_m", "frame_shape_px"):
            if values.get(name) is not None:
                values[name] = tuple(values[name])
        if "band_edges_m" in values and values["band_edges_m"]:
            values["band_edges_m"] = {k: tuple(v) for k, v in values["band_edges_m"].items()}
        try:
            return cls(**values)
        except TypeError as exc:
            raise MetrawError(f"target is incomplete: {exc}") from None

    @classmethod
    def from_params(cls, params: dict[str, Any] | str | Path | None = None,
                    overrides: dict[str, Any] | None = None) -> "TargetSystem":
        """``target.nominal`` of params.yaml (a dict already loaded, or a path), updated by ``overrides``."""
        if params is None or isinstance(params, (str, Path)):
            from metraw.study.points import load_params

            params = load_params(params or "params.yaml")
        try:
            nominal = dict(params["target"]["nominal"])
        except (KeyError, TypeError):
            raise MetrawError("parameters have no target.nominal section") from None
        nominal.update(overrides or {})
        return cls.from_dict(nominal)


def parse_point(text: str) -> dict[str, Any]:
    """Parse ``"name=value,name=value"`` (CLI ``--point``) into target overrides.

    Values are numbers, or words for text fields (``cfa_pattern=mono``); tuples use ``:``
    (``frame_offset_m=10:-5``).
    """
    out: dict[str, Any] = {}
    if not text:
        return out
    known = {f.name for f in dataclasses.fields(TargetSystem)}
    for item in text.split(","):
        if "=" not in item:
            raise MetrawError(f"--point item {item!r} is not name=value")
        name, value = (s.strip() for s in item.split("=", 1))
        if name not in known:
            raise MetrawError(f"--point: unknown target field {name!r}; known: {', '.join(sorted(known))}")
        if ":" in value:
            out[name] = tuple(_parse_number(v, name) for v in value.split(":"))
        elif name in ("cfa_pattern", "name"):
            out[name] = value
        else:
            out[name] = _parse_number(value, name)
    return out


def _parse_number(text: str, name: str) -> float | int:
    try:
        v = float(text)
    except ValueError:
        raise MetrawError(f"--point: {name}={text!r} is not a number") from None
    return int(v) if name in ("adc_bits",) or (name == "frame_shape_px") else v
