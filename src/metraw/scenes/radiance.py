"""Conversion of daylight (``metraw.physics.daylight``) to expected photoelectrons per pixel of a camera.

Lambertian surfaces: radiance L = rho * E / pi. The 250 m air path between ground and drone is
neglected (transmission > 0.99 at these wavelengths).

Camera (pinhole geometry, small angles): a pixel sees the solid angle Omega = (pitch / f)^2,
the aperture has area A = pi D^2 / 4 (1 - obscuration^2); over an exposure t with optics
transmission tau and band quantum efficiency QE_c (flat inside the band edges of the profile)

    e-_c = rho_c * integral_band  E(lambda) / pi * A * Omega * t * tau * QE_c * lambda / (h c)  d lambda.

(A * Omega is the etendue of one pixel; it does not depend on altitude: GSD grows with
altitude exactly as the solid angle of the aperture seen from the ground shrinks.)
"""

from __future__ import annotations

import math

import numpy as np

from metraw.physics.atmosphere import pixel_etendue_m2_sr
from metraw.physics.daylight import C_LIGHT_M_PER_S, H_PLANCK_J_S, ground_irradiance_w_m2_m
from metraw.raw.profile import CalibrationProfile


def electrons_per_reflectance(camera: CalibrationProfile, sun_elevation_deg: float, exposure_s: float,
                              aerosol_depth_550: float = 0.12, samples_per_band: int = 61) -> dict[str, tuple[float, float]]:
    """Per CFA colour: (e- per unit reflectance under the direct beam at normal incidence,
    e- per unit reflectance from the diffuse sky on a horizontal surface) for one pixel.

    Multiply the first by n . s (the cosine of the sun's incidence angle on the surface).
    """
    etendue = pixel_etendue_m2_sr(camera)
    out = {}
    for c in camera.channels:
        lo, hi = camera.band_edges_m[c]
        lam = np.linspace(lo, hi, samples_per_band)
        direct, diffuse = ground_irradiance_w_m2_m(lam, sun_elevation_deg, aerosol_depth_550)
        photons_per_j = lam / (H_PLANCK_J_S * C_LIGHT_M_PER_S)
        scale = etendue * exposure_s * camera.optical_transmission * camera.qe_per_channel.get(c, 1.0) / math.pi
        out[c] = (float(np.trapezoid(direct * photons_per_j, lam) * scale),
                  float(np.trapezoid(diffuse * photons_per_j, lam) * scale))
    return out
