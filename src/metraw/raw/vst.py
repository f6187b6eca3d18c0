"""Variance-stabilising transform for Poisson-Gaussian raw data (generalised Anscombe).

In photoelectrons x = (DN - black) / K, a pixel is Poisson(lambda) + N(0, s^2) with
s^2 = sigma_d^2 + 1/(12 K^2) (read noise plus ADC rounding). The generalised Anscombe
transform  f(x) = 2 sqrt(max(x + 3/8 + s^2, 0))  makes the noise approximately unit-variance
for lambda >~ 1 (Starck, Murtagh & Bijaoui 1998; Makitalo & Foi 2013).
"""

from __future__ import annotations

import numpy as np

from metraw.raw.profile import CalibrationProfile


def effective_read_variance_e2(profile: CalibrationProfile) -> float:
    """s^2 [e-^2]: read noise plus the ADC rounding variance referred to electrons."""
    k = profile.gain_dn_per_e
    return profile.read_noise_e**2 + 1.0 / (12.0 * k * k)


def anscombe(dn: np.ndarray, profile: CalibrationProfile) -> np.ndarray:
    """Generalised Anscombe transform of DN values to (approximately) unit-variance units."""
    x = (np.asarray(dn, dtype=np.float64) - profile.black_level_dn) / profile.gain_dn_per_e
    return 2.0 * np.sqrt(np.maximum(x + 0.375 + effective_read_variance_e2(profile), 0.0))


def inverse_anscombe_algebraic(z: np.ndarray, profile: CalibrationProfile) -> np.ndarray:
    """Algebraic inverse of ``anscombe`` back to DN (biased as an estimator of the mean)."""
    x = (np.asarray(z, dtype=np.float64) / 2.0) ** 2 - 0.375 - effective_read_variance_e2(profile)
    return x * profile.gain_dn_per_e + profile.black_level_dn
