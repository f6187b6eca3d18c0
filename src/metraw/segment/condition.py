"""Payload conditioning of the segmenter: the few numbers of an image's calibration profile that set what the
network sees, so that one network trained across a tolerance box can adapt to each payload (issue #15, item 3).

The features come from the payload alone (optics, sensor geometry, exposure, orbit), never from the atmosphere or
the scene: at deployment a satellite image carries its payload's profile, not the day's haze. Each is a base-2
logarithm (or a ratio) of a physical quantity of the image, so that a change of the payload by a factor moves it by
the same amount anywhere in the box:

- ``log2_packed_gsd``: log2 of the packed ground sample distance [m per packed pixel] (CFA cell side x GSD);
- ``log2_psf_fwhm_px``: log2 of the diffraction FWHM, 1.029 lambda / D at ``REFERENCE_WAVELENGTH_M``, on the ground
  in packed pixels (the optics' blur against the sampling);
- ``log2_etendue_exposure``: log2 of (pi D^2 / 4) (pitch / f)^2 t / ``REFERENCE_ETENDUE_EXPOSURE_M2_SR_S``: light
  collected per pixel and unit scene radiance [m^2 sr s] (with the QE, the signal in electrons);
- ``smear_px``: along-track motion during the exposure in packed pixels, v t / packed GSD.

The network (``metraw.segment.model``) turns them into a per-channel scale and shift of every block's features
(FiLM, Perez et al. 2018), zero at initialisation: a conditioned network starts as the plain one.
"""

from __future__ import annotations

import math

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import PACKED_CELL_PX

#: Names of the conditioning features, in the order of ``payload_condition``'s vector.
CONDITION_FEATURES = ("log2_packed_gsd", "log2_psf_fwhm_px", "log2_etendue_exposure", "smear_px")
#: Wavelength of the diffraction feature [m] (the middle of the visible band).
REFERENCE_WAVELENGTH_M = 550e-9
#: Unit of the light-collection feature [m^2 sr s]: the order of a 0.2 m aperture, 1.5 urad pixels and 180 us.
REFERENCE_ETENDUE_EXPOSURE_M2_SR_S = 1e-17

_NEEDED = ("pixel_pitch_m", "focal_length_m", "aperture_diameter_m", "altitude_m", "exposure_s")


def payload_condition(profile) -> np.ndarray | None:
    """The conditioning vector (float32, ``CONDITION_FEATURES``) of a calibration profile, or None when the profile
    lacks its payload geometry (pitch, focal length, aperture, altitude, exposure)."""
    if any(getattr(profile, name, None) in (None, 0) for name in _NEEDED):
        return None
    pitch, focal, diameter = profile.pixel_pitch_m, profile.focal_length_m, profile.aperture_diameter_m
    packed_gsd_m = profile.gsd_m * PACKED_CELL_PX
    fwhm_m = 1.029 * REFERENCE_WAVELENGTH_M / diameter * profile.altitude_m
    etendue_exposure = math.pi * diameter**2 / 4 * (pitch / focal) ** 2 * profile.exposure_s
    smear_m = (profile.ground_speed_m_per_s or 0.0) * profile.exposure_s
    return np.array([math.log2(packed_gsd_m), math.log2(fwhm_m / packed_gsd_m),
                     math.log2(etendue_exposure / REFERENCE_ETENDUE_EXPOSURE_M2_SR_S), smear_m / packed_gsd_m],
                    np.float32)


def require_condition(condition: np.ndarray | None, where: str) -> np.ndarray:
    """``condition``, or one clear error when a conditioned model meets an image without its payload geometry."""
    if condition is None:
        raise MetrawError(f"{where}: the model is conditioned on the payload ({', '.join(CONDITION_FEATURES)}) but the "
                          f"image's profile lacks its geometry ({', '.join(_NEEDED)})")
    return condition
