"""Noise calibration: measure gain K [DN/e-] and read noise sigma_d [e-] per CFA channel.

Two estimators of the EMVA 1288 linear model ``var_y = K^2 sigma_d^2 + K (mu_y - black) + q^2/12``:

``from_series(flats, darks)``
    Photon transfer (EMVA 1288). Each illumination level holds >= 2 frames; the temporal
    variance comes from the frame-to-frame residuals (a two-way ANOVA interaction mean
    square: per-pixel fixed pattern and frame-to-frame illumination drift both cancel).
    K is the weighted least-squares slope through the origin of (var - var_dark) against
    (mu - mu_dark), on levels up to ``fit_fraction`` (70 %) of saturation; saturation is
    the mean at the variance peak; sigma_d = sqrt(var_dark - q^2/12) / K.

``from_image(image)``
    Single-frame Poisson-Gaussian fit (after Foi et al. 2008). On each CFA plane the Haar
    details of non-overlapping 2 x 2 cells are computed; the diagonal one d = (y00 - y01 -
    y10 + y11) / 2 has variance exactly sigma^2 for independent noise and cancels constant and
    bilinear signal, axis-aligned edges and row/column offsets (banding). Blocks of cells give
    a local mean and HH variance (chi2_n / n for n cells). Blocks are binned by mean; in each
    bin the smooth blocks are chosen by the horizontal/vertical details (LH, HL), which are
    independent of HH for white noise, so the chosen blocks' HH variances stay unbiased with
    exact chi-square statistics (``_smooth_blocks``); clipped blocks are dropped. A weighted fit
    ``var = a x + b + c x^2`` with ``x = mu - black`` gives K = a, sigma_d^2 = (b - q^2/12) / K^2;
    ``c`` absorbs pixel-to-pixel gain non-uniformity (PRNU) and multiplicative texture. A free fit
    that breaks b >= q^2/12 or c >= 0 (the signature of texture that is heavier on dark surfaces)
    is replaced by the constrained fit, the move added to its uncertainty. Uncertainties are the
    fit covariance, inflated by the reduced chi-square (Birge ratio), and at least the spread of a
    delete-one-tile jackknife over 4 x 4 tiles of the frame (texture makes K depend on which
    objects the frame shows). A channel that cannot be fitted (too little signal range, too
    few smooth blocks, K not constrained, unstable under the jackknife) is left out (NaN +- inf);
    a frame with no fittable channel raises ``MetrawError``.
    Single-frame read noise includes dark fixed-pattern noise (DSNU) that a series removes.
    Limits, measured with ``benchmarks/noise_fit.py`` on the embedded synthetic drone scenes
    (texture several times the noise variance nearly everywhere, 12-bit, K = 0.25 DN/e-): about
    a third of the 1024 px scenes and a few per cent of the 512 px ones are fitted, >= 90 % of
    them within 2 stated sigma; a single frame cannot separate white, uniformly rough texture from
    shot noise, so larger frames (2048 px), whose statistical uncertainty is smaller, are not
    covered as well. A flat/dark series (``from_series``) has none of these limits.

Data stored with unused low bits (e.g. 12-bit samples stored x16) are detected from the
bits that are zero in every pixel; the fit is then done in native units (DN >> s) and the
returned profile describes the data shifted right by ``unused_low_bits`` (as ingest stores
it), which the result states.

All numbers are per colour channel (R, G, B; or L for mono); the profile's scalar gain and
read noise are the inverse-variance weighted means over channels (Birge-inflated when
channels disagree). Standard uncertainties (1 sigma) go in ``profile.uncertainty``.
"""

from metraw.calibrate.photon_transfer import from_series
from metraw.calibrate.results import FIT_FRACTION, CalibrationResult, ChannelCalibration, detect_unused_low_bits
from metraw.calibrate.single_frame import (BIN_BLOCKS, BLOCK_CELLS, MAX_RELATIVE_GAIN_UNCERTAINTY, MIN_BLOCKS,
                                           MIN_PER_BIN, SMOOTH_QUANTILE, TILES, combine_images, from_image)

__all__ = ["BIN_BLOCKS", "BLOCK_CELLS", "FIT_FRACTION", "MAX_RELATIVE_GAIN_UNCERTAINTY", "MIN_BLOCKS", "MIN_PER_BIN",
           "SMOOTH_QUANTILE", "TILES", "CalibrationResult", "ChannelCalibration", "combine_images",
           "detect_unused_low_bits", "from_image", "from_series"]
