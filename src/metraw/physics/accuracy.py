"""One place for every accuracy knob of the optics and emulation (in the spirit of GalSim's GSParams).

All thresholds are dimensionless fractions unless the name carries a unit suffix (``_px`` = pixels of
the grid the quantity is used on). Every emulation reports the `Accuracy` it ran with, the effects it
skipped as negligible under it, and the error bound it claims.

Defaults (and why):

- ``kernel_flux_loss = 1e-3``: a kernel (PSF, smear, jitter) may be truncated to a finite array only
  if the flux outside the array is <= this fraction of its total. For the diffraction PSF this sets
  the kernel radius through the asymptotic encircled energy of the annulus (`kernel_radius_px`).
- ``folding_threshold = 1e-3``: largest fraction of a kernel's total flux that periodic (FFT)
  wrap-around may fold back into the array (FFT grid sizes are chosen from it).
- ``psf_quadrature_error = 1e-6``: largest error of the pixel integration / Fourier evaluation of a
  PSF, as a fraction of its peak pixel (cheap to keep tiny).
- ``band_sampling_error = 1e-4``: largest error, as a fraction of the peak pixel, of a polychromatic
  PSF due to sampling the band with a finite number of wavelengths (sets ``n_wavelengths``).
- ``negligible_smear_px = 0.05``: motion smear shorter than this many target pixels is skipped.
- ``negligible_psf_px = 0.05``: a PSF whose FWHM is below this many target pixels is skipped (the
  pixel box dominates; the skipped blur changes a pixel's expected value by <~ (FWHM/pixel)^2 / 12
  of the local second difference).
- ``max_prebin_fraction_of_psf = 0.1``: the source may be pre-binned exactly (sum of same-colour
  counts, still Poisson) into blocks no wider than this fraction of the PSF FWHM on the ground;
  photon positions inside a block are then approximated, a blur of variance (block^2 / 12) that is
  bounded by this fraction.
- ``poisson_shortcut_max_p = 1e-3``: when the thinning probability p is below this, the expected
  value chain followed by one Poisson draw per target pixel is allowed instead of photon shooting;
  its excess variance over the photon-exact chain is of relative order p.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from metraw.errors import MetrawError

__all__ = ["Accuracy", "kernel_radius_px", "airy_flux_outside", "DEFAULT_ACCURACY"]


@dataclass(frozen=True)
class Accuracy:
    """Accuracy parameters of optics and emulation (see module docstring for each default)."""

    kernel_flux_loss: float = 1e-3
    folding_threshold: float = 1e-3
    psf_quadrature_error: float = 1e-6
    band_sampling_error: float = 1e-4
    negligible_smear_px: float = 0.05
    negligible_psf_px: float = 0.05
    max_prebin_fraction_of_psf: float = 0.1
    poisson_shortcut_max_p: float = 1e-3

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise MetrawError(f"Accuracy.{f.name} must be a finite number >= 0, got {v!r}")
        for name in ("kernel_flux_loss", "folding_threshold", "poisson_shortcut_max_p"):
            if not 0 < getattr(self, name) < 1:
                raise MetrawError(f"Accuracy.{name} must lie in (0, 1), got {getattr(self, name)!r}")
        for name in ("psf_quadrature_error", "band_sampling_error"):
            if not getattr(self, name) > 0:
                raise MetrawError(f"Accuracy.{name} must be > 0, got {getattr(self, name)!r}")

    def to_dict(self) -> dict[str, float]:
        """Plain dict (JSON-ready), e.g. for provenance records."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Accuracy":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise MetrawError(f"unknown Accuracy field(s): {', '.join(sorted(unknown))}")
        return cls(**{k: float(v) for k, v in d.items()})

    def with_(self, **changes: float) -> "Accuracy":
        """A copy with some fields changed."""
        return replace(self, **changes)


DEFAULT_ACCURACY = Accuracy()


def airy_flux_outside(radius_lambda_over_d: float, obscuration: float = 0.0) -> float:
    """Asymptotic fraction of an annular-aperture PSF's flux outside a circle, 1 - EE(r).

    radius in units of lambda/D. For large r (more than a few lambda/D, ring-averaged):
    1 - EE(r) ~= 2 / (pi^2 * r * (1 - obscuration)); for the clear aperture this is the classical
    J0^2 + J1^2 ~ 2 / (pi v) with v = pi r. The annulus's tail is brighter by 1/(1 - eps) because
    its central obscuration moves energy into the rings. Also valid, ring-averaged, for a
    polychromatic PSF (use the shortest wavelength of the band for a bound).
    """
    if radius_lambda_over_d <= 0:
        return 1.0
    if not 0 <= obscuration < 1:
        raise MetrawError(f"obscuration must lie in [0, 1), got {obscuration!r}")
    return min(1.0, 2.0 / (math.pi**2 * radius_lambda_over_d * (1.0 - obscuration)))


def kernel_radius_px(
    wavelength_m: float,
    diameter_m: float,
    pixel_scale_rad: float,
    obscuration: float = 0.0,
    flux_loss: float | None = None,
    accuracy: Accuracy | None = None,
) -> int:
    """Kernel half-width [pixels] so that the diffraction PSF's flux outside the array <= flux_loss.

    Uses the asymptotic annulus encircled energy (`airy_flux_outside`) on the inscribed circle of
    the square array, so it is a bound (the square's corners hold extra flux). ``flux_loss``
    defaults to ``accuracy.kernel_flux_loss``. The array then has shape (2 r + 1, 2 r + 1).
    """
    acc = accuracy or DEFAULT_ACCURACY
    eps = acc.kernel_flux_loss if flux_loss is None else float(flux_loss)
    if not 0 < eps < 1:
        raise MetrawError(f"flux_loss must lie in (0, 1), got {eps!r}")
    if wavelength_m <= 0 or diameter_m <= 0 or pixel_scale_rad <= 0:
        raise MetrawError("wavelength_m, diameter_m and pixel_scale_rad must be > 0")
    if not 0 <= obscuration < 1:
        raise MetrawError(f"obscuration must lie in [0, 1), got {obscuration!r}")
    r_lod = 2.0 / (math.pi**2 * eps * (1.0 - obscuration))
    lod_px = wavelength_m / diameter_m / pixel_scale_rad
    return max(1, int(math.ceil(r_lod * lod_px)))
