"""Forward camera model (EMVA 1288 linear): photoelectrons -> uint16 DN.

    charge = min(Poisson(mean_e) + Poisson(dark_current * t), full_well)
    DN     = clip(round(K * (charge + N(0, sigma_d^2)) + black), 0, white)

``readout`` takes photoelectron *counts* (already Poisson, e.g. from photon shooting) so
raw functions can keep Poisson statistics exact upstream and add only the sensor's own terms.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from metraw.raw.profile import CalibrationProfile


def rng_from_seed(seed: int | np.random.Generator) -> np.random.Generator:
    """A PCG64 generator; the same seed gives the same stream on every platform."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.Generator(np.random.PCG64(seed))


def readout(counts_e: np.ndarray, profile: CalibrationProfile, rng: np.random.Generator,
            exposure_s: float | None = None) -> np.ndarray:
    """Digitise photoelectron counts: dark current, full well, read noise, gain, black, ADC.

    ``counts_e``: non-negative photoelectron counts (integers or floats). Dark current
    ``profile.dark_current_e_per_s * exposure_s`` is added as an independent Poisson term
    (``exposure_s`` defaults to ``profile.exposure_s``; no dark term when both are unknown).
    Returns uint16 DN clipped to [0, white_level_dn].
    """
    charge = np.asarray(counts_e, dtype=np.float64)
    shape = charge.shape
    t = profile.exposure_s if exposure_s is None else exposure_s
    dark = _NONE_INT
    if profile.dark_current_e_per_s > 0 and t:
        dark = np.asarray(rng.poisson(profile.dark_current_e_per_s * t, size=shape), np.int64).reshape(-1)
    noise = _NONE_FLOAT
    if profile.read_noise_e > 0:
        noise = np.asarray(rng.normal(0.0, profile.read_noise_e, size=shape), np.float64).reshape(-1)
    full_well = np.inf if profile.full_well_e is None else float(profile.full_well_e)
    out = np.empty(shape, np.uint16)
    _digitise(np.ascontiguousarray(charge).reshape(-1), dark, noise, full_well, float(profile.gain_dn_per_e),
              float(profile.black_level_dn), float(profile.white_level_dn), out.reshape(-1))
    return out


_NONE_INT = np.zeros(0, np.int64)
_NONE_FLOAT = np.zeros(0, np.float64)


@nb.njit(cache=True, nogil=True)
def _digitise(charge, dark, noise, full_well, gain, black, white, out):
    """out = clip(rint(gain (min(charge + dark, full_well) + noise) + black), 0, white) per element, in float64
    and in the order of the former numpy expressions (bit-identical); an empty ``dark`` or ``noise`` is none."""
    for i in range(charge.size):
        q = charge[i]
        if dark.size:
            q = q + np.float64(dark[i])
        q = min(q, full_well)
        if noise.size:
            q = q + noise[i]
        dn = np.rint(gain * q + black)
        out[i] = np.uint16(min(max(dn, 0.0), white))


def expose(mean_e: np.ndarray, profile: CalibrationProfile, rng: np.random.Generator,
           exposure_s: float | None = None) -> np.ndarray:
    """Shot noise (Poisson of the expected photoelectrons ``mean_e``) followed by ``readout``."""
    mean = np.asarray(mean_e, dtype=np.float64)
    if np.any(~np.isfinite(mean)) or np.any(mean < 0):
        raise ValueError("expected photoelectrons must be finite and >= 0")
    return readout(rng.poisson(mean), profile, rng, exposure_s=exposure_s)
