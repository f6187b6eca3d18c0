"""Processed 8-bit RGB images (PNG, JPEG, RGB TIFF) -> *approximate* raw images.

A processed photo has been demosaiced, white-balanced, tone-mapped and (often) compressed; its
noise is no longer the sensor's. It can still feed the raw workflow as an approximation:

1. invert the sRGB transfer curve (IEC 61966-2-1) -> linear relative intensity in [0, 1];
2. remosaic: keep, at each pixel, the colour the stated CFA has there;
3. undo the white balance and scale to the photoelectrons of a stated camera: the photo shows a neutral
   (grey) surface as R = G = B, while the camera's raw records it in the ratios of daylight seen through
   the camera's bands and QE (``metraw.physics.daylight.neutral_response``, sun at ``sun_elevation_deg``); so
   linear 1.0 of channel c -> ``white_fraction * saturation_e * neutral_c`` (the largest channel reaches
   ``white_fraction`` of saturation). For the default camera at 45 degrees B/G = 0.51, where the QE ratio
   alone (0.73) would leave raws too blue compared with rendered daylight scenes;
4. apply the camera's sensor model (``metraw.raw.sensor.expose``: Poisson shot noise, dark current,
   read noise, gain, black level, ADC) with a seeded generator.

The result is a valid raw image with a noise model for the *added* noise; the photo's own
(processed, correlated) noise and its tone mapping remain, hence ``approximate=True``.
"""

from __future__ import annotations

import zlib
from pathlib import Path
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.io.labels import attach_labels
from metraw.io.pictures import decode_image
from metraw.physics.daylight import neutral_response
from metraw.raw.cfa import color_index
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose

PROCESSED_SUFFIXES = {".png", ".jpg", ".jpeg"}

APPROXIMATE_REASON = ("made from a processed 8-bit RGB image: sRGB curve inverted, remosaicked and re-exposed "
                      "with the stated camera model; the photo's own demosaicing, tone mapping, compression "
                      "and noise are not undone")


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """Inverse sRGB transfer function (IEC 61966-2-1) on values in [0, 1] -> linear [0, 1]."""
    v = np.asarray(values, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def seed_for(path: Path, seed: int) -> np.random.Generator:
    """A generator that depends on ``seed`` and the file *name* (not the order of ingestion)."""
    ss = np.random.SeedSequence([int(seed), zlib.crc32(path.name.encode("utf-8"))])
    return np.random.Generator(np.random.PCG64(ss))


def approximate_raw(rgb8: np.ndarray, camera: CalibrationProfile, rng: np.random.Generator, *,
                    white_fraction: float = 1.0, gsd_m: float | None = None, source: str = "",
                    sun_elevation_deg: float = 45.0) -> RawImage:
    """Approximate raw image from an 8-bit sRGB array (H, W, 3) using ``camera``'s sensor model.

    ``white_fraction``: fraction of the camera's saturation (photoelectrons) that sRGB white maps to
    for the channel with the largest daylight response. ``sun_elevation_deg``: the sun of the daylight the
    photo's white balance is undone for (5-90 degrees; the channel ratios change by < 5 % over 20-70). ``gsd_m``: ground sample distance of the photo [m]; the
    profile's altitude is set so that ``profile.gsd_m == gsd_m`` (unknown geometry when None).
    """
    a = np.asarray(rgb8)
    if a.dtype != np.uint8:
        raise MetrawError(f"{source}: processed image must be 8-bit, got {a.dtype}")
    if a.ndim == 3 and a.shape[-1] == 4:
        a = a[..., :3]
    if a.ndim != 3 or a.shape[-1] != 3:
        raise MetrawError(f"{source}: processed image must be RGB (H, W, 3), got shape {a.shape}")
    if not 0 < white_fraction <= 1:
        raise MetrawError(f"white_fraction must be in (0, 1], got {white_fraction}")
    pattern = camera.cfa_pattern
    channels = ["R", "G", "B"]
    if pattern == "mono":
        raise MetrawError("approximate raw needs a colour camera (CFA pattern), got mono")
    h, w = a.shape[:2]
    idx = color_index(pattern, (h, w))  # index into ("R", "G", "B")
    mosaic8 = np.take_along_axis(a, idx[..., None].astype(np.intp), axis=2)[..., 0]
    lut = srgb_to_linear(np.arange(256) / 255.0)
    neutral = neutral_response(camera, sun_elevation_deg)
    scale_e = white_fraction * camera.saturation_e * np.array([neutral[c] for c in channels])
    mean_e = lut[mosaic8] * scale_e[idx]
    data = expose(mean_e, camera, rng)
    changes: dict[str, Any] = {"approximate": True, "approximate_reason": APPROXIMATE_REASON}
    if gsd_m is not None:
        if not (gsd_m > 0 and camera.pixel_pitch_m and camera.focal_length_m):
            raise MetrawError("gsd_m needs a positive value and a camera with pixel_pitch_m and focal_length_m")
        changes["altitude_m"] = gsd_m * camera.focal_length_m / camera.pixel_pitch_m
    else:
        changes["altitude_m"] = None
    profile = camera.replace(**changes)
    params = {"source": source, "transfer": "sRGB (IEC 61966-2-1) inverted", "cfa_pattern": pattern,
              "white_fraction": white_fraction, "white_balance": f"daylight, sun at {sun_elevation_deg} deg",
              "electrons_at_white": dict(zip(channels, scale_e.tolist())),
              "camera": camera.camera, "gsd_m": gsd_m}
    return RawImage(data=data, profile=profile, provenance=[{"function": "io.approximate_raw", "params": params}],
                    meta={"source_file": source, "format": "processed 8-bit RGB -> approximate raw",
                          "gsd_m": gsd_m})


def read_processed(path: Path, camera: CalibrationProfile, *, labels: str = "auto", seed: int = 0,
                   white_fraction: float = 1.0, gsd_m: float | None = None,
                   class_names: list[str] | None = None, car_classes=None) -> RawImage:
    """Read a processed RGB image (+ labels) as an approximate raw (see module docstring)."""
    rgb = decode_image(path)
    image = approximate_raw(rgb, camera, seed_for(path, seed), white_fraction=white_fraction, gsd_m=gsd_m,
                            source=str(path))
    image.provenance[0]["params"]["seed"] = int(seed)
    return attach_labels(image, path, labels, class_names=class_names, car_classes=car_classes)
