"""Daylight: solar spectrum above the atmosphere, clear-sky direct and diffuse irradiance at the ground,
and the relative response of a camera's colour channels to a neutral (grey) surface lit by it.

Model (documented approximations, all scalar, float64):

- Sun above the atmosphere: a 5778 K black body scaled by (R_sun / 1 AU)^2, so the total is
  about 1361 W m^-2 (the solar constant).
- Atmosphere (sea level): Rayleigh optical depth tau_R = 0.0088 * lambda_um^-4.05 and an
  aerosol depth tau_a = 0.12 * (lambda / 550 nm)^-1.3 (clear, moderately clean continental
  air); air mass m = 1 / sin(elevation) (fine above ~15 degrees).
- Direct beam on a surface with normal n: E0 * exp(-(tau_R + tau_a) m) * max(0, n . s).
- Diffuse sky on a horizontal surface (single-scattering partition in the spirit of
  Bird & Riordan 1986): E0 sin(e) [0.5 (1 - T_R) T_a + 0.75 T_R (1 - T_a) + 0.6 (1 - T_R)(1 - T_a)].

Used by ``metraw.scenes.radiance`` (absolute photoelectrons of rendered scenes) and by
``metraw.io.processed`` (a white-balanced photo's white is a neutral surface in daylight).
"""

from __future__ import annotations

import math

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.profile import CalibrationProfile

H_PLANCK_J_S = 6.62607015e-34
C_LIGHT_M_PER_S = 299792458.0
K_BOLTZMANN_J_PER_K = 1.380649e-23
T_SUN_K = 5778.0
R_SUN_M = 6.957e8
AU_M = 1.495978707e11


def solar_toa_irradiance_w_m2_m(wavelength_m: np.ndarray) -> np.ndarray:
    """Spectral solar irradiance above the atmosphere [W m^-2 m^-1] (black body 5778 K)."""
    lam = np.asarray(wavelength_m, dtype=np.float64)
    planck = 2 * H_PLANCK_J_S * C_LIGHT_M_PER_S**2 / lam**5 / np.expm1(
        H_PLANCK_J_S * C_LIGHT_M_PER_S / (lam * K_BOLTZMANN_J_PER_K * T_SUN_K))
    return math.pi * planck * (R_SUN_M / AU_M) ** 2


def optical_depths(wavelength_m: np.ndarray, aerosol_depth_550: float = 0.12) -> tuple[np.ndarray, np.ndarray]:
    """(Rayleigh, aerosol) vertical optical depths at sea level (dimensionless)."""
    lam_um = np.asarray(wavelength_m, dtype=np.float64) * 1e6
    return 0.0088 * lam_um ** -4.05, aerosol_depth_550 * (lam_um / 0.55) ** -1.3


def ground_irradiance_w_m2_m(wavelength_m: np.ndarray, sun_elevation_deg: float,
                             aerosol_depth_550: float = 0.12) -> tuple[np.ndarray, np.ndarray]:
    """(direct normal, diffuse horizontal) spectral irradiance at the ground [W m^-2 m^-1]."""
    if not 5.0 <= sun_elevation_deg <= 90.0:
        raise MetrawError(f"sun elevation must be in [5, 90] degrees, got {sun_elevation_deg}")
    e0 = solar_toa_irradiance_w_m2_m(wavelength_m)
    sin_e = math.sin(math.radians(sun_elevation_deg))
    airmass = 1.0 / sin_e
    tau_r, tau_a = optical_depths(wavelength_m, aerosol_depth_550)
    t_r, t_a = np.exp(-tau_r * airmass), np.exp(-tau_a * airmass)
    direct_normal = e0 * t_r * t_a
    diffuse = e0 * sin_e * (0.5 * (1 - t_r) * t_a + 0.75 * t_r * (1 - t_a) + 0.6 * (1 - t_r) * (1 - t_a))
    return direct_normal, diffuse


def neutral_response(camera: CalibrationProfile, sun_elevation_deg: float = 45.0, aerosol_depth_550: float = 0.12,
                     samples_per_band: int = 61) -> dict[str, float]:
    """Relative photoelectron rate of each CFA colour for a horizontal neutral (grey) Lambertian surface in
    sun and sky, normalised so the largest channel is 1 (dimensionless).

    Integral over the channel's band of (direct * sin(elevation) + diffuse) * QE_c * lambda / (h c): what a
    camera's raw records from a surface that a white-balanced photo shows as grey.
    """
    rates = {}
    sin_e = math.sin(math.radians(sun_elevation_deg))
    for c in camera.channels:
        lo, hi = camera.band_edges_m[c]
        lam = np.linspace(lo, hi, samples_per_band)
        direct, diffuse = ground_irradiance_w_m2_m(lam, sun_elevation_deg, aerosol_depth_550)
        photons = (direct * sin_e + diffuse) * lam / (H_PLANCK_J_S * C_LIGHT_M_PER_S)
        rates[c] = float(np.trapezoid(photons, lam)) * camera.qe_per_channel.get(c, 1.0)
    top = max(rates.values())
    return {c: v / top for c, v in rates.items()}


def lambertian_photon_radiance(band_m: tuple[float, float], reflectance: float, sun_elevation_deg: float = 45.0,
                               aerosol_depth_550: float = 0.12, samples: int = 61) -> float:
    """Photon radiance [photons s^-1 m^-2 sr^-1] within ``band_m`` of a horizontal grey Lambertian surface of
    ``reflectance`` lit by sun and sky: integral of reflectance (direct sin(e) + diffuse) / pi lambda / (h c)."""
    lo, hi = (float(v) for v in band_m)
    if not 0 < lo < hi:
        raise MetrawError(f"band edges must satisfy 0 < lo < hi, got {band_m!r}")
    lam = np.linspace(lo, hi, samples)
    direct, diffuse = ground_irradiance_w_m2_m(lam, sun_elevation_deg, aerosol_depth_550)
    radiance = reflectance * (direct * math.sin(math.radians(sun_elevation_deg)) + diffuse) / math.pi
    return float(np.trapezoid(radiance * lam / (H_PLANCK_J_S * C_LIGHT_M_PER_S), lam))
