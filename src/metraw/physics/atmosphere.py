"""The atmosphere between the ground and a payload: transmission of the scene and path radiance.

One-way nadir path (docs/noise-model.md, docs/emulation.md):

- **Transmission** ``T`` (0..1) multiplies the scene's radiance. For photons it is binomial thinning
  with probability ``T`` (exact); the emulator folds it into its thinning ratio alpha.
- **Path radiance**: sunlight scattered into the line of sight by air molecules and aerosol. It adds
  to every pixel whatever the scene, and it is independent light, so it adds independent Poisson
  counts (exact). Its spectral radiance is a power law around 550 nm,

      L_path(lambda) = L_550 (lambda / 550 nm)^(-a)     [W m^-2 sr^-1 m^-1],

  and it is collected through the same optics as the scene. Per pixel and channel c:

      e-_c = A Omega t tau QE_c integral_band_c L_path(lambda) lambda / (h c) d lambda.

  Here A Omega is the pixel etendue: aperture area times the pixel's solid angle (pitch / f)^2. So
  path radiance scales with exposure, aperture area and pixel area (through Omega) exactly as the
  scene's signal does. Only the transmission ``T`` separates the two.

Physical ranges (nadir view, sea level, sun elevation 30-60 degrees). The path reflectance is
rho_path = pi L_path / (E0 cos theta_sun), with E0(550 nm) ~ 1.86e9 W m^-2 m^-1:

- clear air (aerosol optical depth 0.1 at 550 nm): rho_path ~ 0.04-0.05 (Rayleigh ~0.03, aerosol
  ~0.01-0.02), so L_550 ~ 1.5-2.5e7 W m^-2 sr^-1 m^-1 (15-25 W m^-2 sr^-1 um^-1); one-way
  T(550 nm) = exp(-(0.097 + 0.1)) ~ 0.82;
- haze (optical depth 0.5-1): rho_path ~ 0.1-0.15, so L_550 ~ 5-8e7; T ~ 0.55-0.33;
- very clean, high sun: L_550 ~ 0.5-1e7, T ~ 0.88.

The spectral slope ``a`` follows the relative scattering models of Chavez (1988, Remote Sens.
Environ. 24, 459): very clear 4 (Rayleigh), clear 2, moderately clear 1, hazy 0.7, very hazy 0.5.
"""

from __future__ import annotations

import math

from metraw.errors import MetrawError
from metraw.physics.daylight import C_LIGHT_M_PER_S, H_PLANCK_J_S
from metraw.raw.profile import CalibrationProfile

#: Reference wavelength of the path radiance's power law [m].
PATH_RADIANCE_REF_M = 550e-9


def pixel_etendue_m2_sr(camera: CalibrationProfile) -> float:
    """A_aperture * Omega_pixel [m^2 sr] of one pixel (needs pitch, focal length, aperture)."""
    if None in (camera.pixel_pitch_m, camera.focal_length_m, camera.aperture_diameter_m):
        raise MetrawError("the camera profile needs pixel_pitch_m, focal_length_m and aperture_diameter_m")
    from metraw.physics.optics import pupil_area_m2  # pi D^2 / 4 (1 - eps^2): bit for bit the same floats

    area = pupil_area_m2(camera.aperture_diameter_m, camera.obscuration_ratio)
    return area * (camera.pixel_pitch_m / camera.focal_length_m) ** 2


def band_photon_radiance(radiance_550_w_m2_sr_m: float, exponent: float, band_m: tuple[float, float]) -> float:
    """Photon radiance [photons s^-1 m^-2 sr^-1] of the power-law path radiance within ``band_m``.

    Closed form of integral L_550 (lambda / lambda_0)^-a lambda / (h c) d lambda over the band."""
    lo, hi = (float(v) for v in band_m)
    if not 0 < lo < hi:
        raise MetrawError(f"band edges must satisfy 0 < lo < hi, got {band_m!r}")
    if not (math.isfinite(radiance_550_w_m2_sr_m) and radiance_550_w_m2_sr_m >= 0):
        raise MetrawError(f"path radiance must be a finite number >= 0, got {radiance_550_w_m2_sr_m!r}")
    if not math.isfinite(exponent):
        raise MetrawError(f"path radiance exponent must be finite, got {exponent!r}")
    # integral of (lambda/lambda0)^-a lambda d lambda = lambda0^2 integral of u^(1-a) du, u = lambda / lambda0
    l0 = PATH_RADIANCE_REF_M
    u0, u1 = lo / l0, hi / l0
    power = 2.0 - exponent
    integral = math.log(u1 / u0) if abs(power) < 1e-12 else (u1**power - u0**power) / power
    return radiance_550_w_m2_sr_m * l0**2 * integral / (H_PLANCK_J_S * C_LIGHT_M_PER_S)


def path_radiance_electrons(camera: CalibrationProfile, radiance_550_w_m2_sr_m: float,
                            exponent: float) -> dict[str, float]:
    """Mean path-radiance photoelectrons per pixel and exposure, per channel of ``camera``.

    Uses the profile's pitch, focal length, aperture, exposure, optics transmission, QE and bands."""
    if radiance_550_w_m2_sr_m == 0:
        return {c: 0.0 for c in camera.channels}
    if camera.exposure_s is None:
        raise MetrawError("the camera profile needs exposure_s to collect path radiance")
    scale = pixel_etendue_m2_sr(camera) * camera.exposure_s * camera.optical_transmission
    return {c: scale * camera.qe_per_channel.get(c, 1.0)
            * band_photon_radiance(radiance_550_w_m2_sr_m, exponent, camera.band_edges_m[c])
            for c in camera.channels}
