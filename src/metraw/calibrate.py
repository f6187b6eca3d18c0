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

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import stats

from metraw.cfa import channel_names, plane_offsets, split_planes, validate_pattern
from metraw.errors import MetrawError
from metraw.image import RawImage
from metraw.io._dn import unused_low_bits
from metraw.profile import CalibrationProfile

#: Default fraction of the saturation signal used for the photon-transfer fit (EMVA 1288).
FIT_FRACTION = 0.7
#: Side of a from_image block in 2 x 2 cells of one CFA plane (8 -> 16 x 16 plane pixels).
BLOCK_CELLS = 8
#: Fewest accepted blocks per channel for a single-frame fit.
MIN_BLOCKS = 40
#: Fewest blocks in one signal bin of a single-frame fit: MIN_PER_BIN for frames with few blocks
#: (so that there are >= 8 bins), up to BIN_BLOCKS for large frames; at least half of a bin's blocks
#: must pass the smoothness selection.
MIN_PER_BIN = 8
BIN_BLOCKS = 16
#: Fraction of the smoothest blocks of a signal bin from which the bin's noise scale is read
#: (``_smooth_blocks``).
SMOOTH_QUANTILE = 0.25
#: The frame is cut into TILES x TILES tiles for the spatial jackknife of a single-frame fit.
TILES = 4
#: Largest relative standard uncertainty of K that from_image still reports as a fit.
MAX_RELATIVE_GAIN_UNCERTAINTY = 0.5


# ------------------------------------------------------------------------------ results
@dataclass
class ChannelCalibration:
    """Fitted noise model of one colour channel (DN in native units, see ``unused_low_bits``).

    ``gain_dn_per_e``, ``read_noise_e``, ``black_level_dn`` with their 1-sigma ``*_u``;
    ``saturation_dn`` the mean at the variance peak (None when not reached);
    ``prnu`` the relative gain non-uniformity sqrt(c) of the single-frame fit (None for series);
    ``n_points`` levels (series) or blocks (image) used; ``signal_range_dn`` the fitted span of
    mu - black; ``chi2_red`` the reduced chi-square of the fit.
    """

    channel: str
    gain_dn_per_e: float
    gain_dn_per_e_u: float
    read_noise_e: float
    read_noise_e_u: float
    black_level_dn: float
    black_level_dn_u: float
    n_points: int
    signal_range_dn: tuple[float, float]
    chi2_red: float
    saturation_dn: float | None = None
    prnu: float | None = None
    prnu_u: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass
class CalibrationResult:
    """Outcome of a calibration: the profile (with ``uncertainty``) and per-channel numbers."""

    profile: CalibrationProfile
    method: str
    channels: dict[str, ChannelCalibration]
    unused_low_bits: int = 0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "unused_low_bits": self.unused_low_bits,
            "notes": list(self.notes),
            "channels": {k: v.to_dict() for k, v in self.channels.items()},
            "profile": self.profile.to_dict(),
        }


# ------------------------------------------------------------------------------ input helpers
def detect_unused_low_bits(arrays: Sequence[np.ndarray], min_distinct: int = 16) -> int:
    """Number of low bits that are zero in every pixel of every array (0..8).

    Only trusted when the data hold at least ``min_distinct`` distinct values after the
    shift (a nearly constant frame would otherwise fake unused bits).
    """
    per_array = [np.bitwise_or.reduce(np.asarray(a, dtype=np.uint16), axis=None) for a in arrays]
    s = unused_low_bits(np.array(per_array, dtype=np.uint16), max_shift=8)
    if s == 0:
        return 0
    distinct = np.unique(np.asarray(arrays[0]).ravel()[:1_000_000] >> s).size
    return s if distinct >= min_distinct else 0


def _frame_array(frame: Any) -> np.ndarray:
    data = frame.data if isinstance(frame, RawImage) else np.asarray(frame)
    if data.ndim != 2 or data.size == 0:
        raise MetrawError(f"a calibration frame must be a non-empty 2-D array, got shape {data.shape}")
    if data.dtype.kind == "f":
        if not np.all(np.isfinite(data)):
            raise MetrawError("a calibration frame contains NaN or infinite values")
        if np.any(data != np.rint(data)) or data.min() < 0 or data.max() > 65535:
            raise MetrawError("a calibration frame must hold integer DN in 0..65535")
        data = data.astype(np.uint16)
    elif data.dtype.kind in "iu":
        if data.min() < 0 or data.max() > 65535:
            raise MetrawError("a calibration frame must hold integer DN in 0..65535")
        data = data.astype(np.uint16, copy=False)
    else:
        raise MetrawError(f"a calibration frame must hold integer DN, got dtype {data.dtype}")
    return data


def _first_profile(frames: Sequence[Any]) -> CalibrationProfile | None:
    for f in frames:
        if isinstance(f, RawImage):
            return f.profile
    return None


@dataclass
class _Radiometry:
    cfa_pattern: str
    black_dn: float | None
    white_dn: float
    adc_bits: int
    shift: int

    @property
    def scale(self) -> int:
        return 1 << self.shift


def _radiometry(arrays: Sequence[np.ndarray], base: CalibrationProfile | None, cfa_pattern: str | None,
                black_level_dn: float | None, white_level_dn: float | None, adc_bits: int | None,
                ) -> _Radiometry:
    """Settle pattern, black, white, ADC bits and unused low bits; returned in native units."""
    pattern = cfa_pattern or (base.cfa_pattern if base else None)
    if pattern is None:
        raise MetrawError("the CFA pattern is unknown: pass cfa_pattern (e.g. 'RGGB' or 'mono')")
    validate_pattern(pattern)
    black = black_level_dn if black_level_dn is not None else (base.black_level_dn if base else None)
    white = white_level_dn if white_level_dn is not None else (base.white_level_dn if base else None)
    shift = detect_unused_low_bits(arrays)
    scale = 1 << shift
    if white is None:
        peak = max(int(a.max()) for a in arrays) >> shift
        bits = max(8, int(peak).bit_length())
        white = float(((1 << bits) - 1) * scale)
    bits = adc_bits if adc_bits is not None else (base.adc_bits if base else None)
    if bits is None:
        bits = max(1, int(math.floor(white / scale)).bit_length())
    elif shift:
        bits = min(int(bits), max(1, int(white / scale).bit_length()))
    return _Radiometry(pattern, None if black is None else float(black) / scale, float(white) / scale,
                       int(bits), shift)


def _native(data: np.ndarray, shift: int) -> np.ndarray:
    return (data >> shift).astype(np.float64) if shift else data.astype(np.float64)


def _weighted_mean(values: np.ndarray, sigmas: np.ndarray) -> tuple[float, float, float]:
    """Inverse-variance weighted mean, its uncertainty (Birge-inflated) and reduced chi-square."""
    values, sigmas = np.asarray(values, float), np.asarray(sigmas, float)
    ok = np.isfinite(values) & np.isfinite(sigmas) & (sigmas > 0)
    if not np.any(ok):
        return float(np.mean(values)), float("inf"), float("nan")
    w = 1.0 / sigmas[ok] ** 2
    mean = float(np.sum(w * values[ok]) / np.sum(w))
    u = math.sqrt(1.0 / np.sum(w))
    n = int(ok.sum())
    chi2 = float(np.sum(w * (values[ok] - mean) ** 2) / (n - 1)) if n > 1 else 1.0
    return mean, u * math.sqrt(max(1.0, chi2)), chi2


def _read_noise(var0: float, var0_u: float, gain: float, gain_u: float) -> tuple[float, float]:
    """sigma_d = sqrt(var0 - 1/12) / K with first-order uncertainty (one-sided when var0 <= 1/12)."""
    excess = var0 - 1.0 / 12.0
    if excess <= 0:
        # Quantisation-limited: read noise not resolved; report 0 with the 1-sigma upper scale.
        return 0.0, math.sqrt(max(var0_u, 0.0)) / gain
    sd = math.sqrt(excess) / gain
    u = math.sqrt((var0_u / (2.0 * math.sqrt(excess) * gain)) ** 2 + (sd * gain_u / gain) ** 2)
    return sd, u


def _build_profile(base: CalibrationProfile | None, rad: _Radiometry, channels: dict[str, ChannelCalibration],
                   full_well_e: float | None) -> CalibrationProfile:
    names = list(channels)
    k, k_u, _ = _weighted_mean([channels[c].gain_dn_per_e for c in names], [channels[c].gain_dn_per_e_u for c in names])
    rn, rn_u, _ = _weighted_mean([channels[c].read_noise_e for c in names], [channels[c].read_noise_e_u for c in names])
    if rad.black_dn is None:
        bl, bl_u, _ = _weighted_mean([channels[c].black_level_dn for c in names],
                                     [channels[c].black_level_dn_u for c in names])
    else:
        bl, bl_u = rad.black_dn, max(ch.black_level_dn_u for ch in channels.values())
    if not k > 0:
        raise MetrawError(f"fitted gain is not positive (K = {k:.4g} DN/e-): the data do not follow the noise model")
    uncertainty = {"gain_dn_per_e": k_u, "read_noise_e": rn_u, "black_level_dn": bl_u}
    fields = dict(gain_dn_per_e=k, read_noise_e=rn, black_level_dn=bl, white_level_dn=rad.white_dn,
                  adc_bits=rad.adc_bits, cfa_pattern=rad.cfa_pattern, full_well_e=full_well_e,
                  uncertainty=uncertainty)
    if base is None:
        return CalibrationProfile(**fields)
    unc = dict(base.uncertainty)
    unc.update(uncertainty)
    fields["uncertainty"] = unc
    if full_well_e is None:
        fields["full_well_e"] = base.full_well_e
    return base.replace(**fields)


# ------------------------------------------------------------------------------ photon transfer
def _channel_stats(stack: np.ndarray, pattern: str) -> dict[str, tuple[float, float, float, float, int]]:
    """Per channel: (mean, temporal variance, its degrees of freedom, spatial sd of the pixel means, pixels).

    ``stack``: (n_frames, H, W) float64 native DN. The variance is the two-way ANOVA
    interaction mean square (pixel fixed pattern and per-frame offsets removed).
    """
    n = stack.shape[0]
    acc: dict[str, list[float]] = {}
    for (colour, _, _), plane in zip(plane_offsets(pattern), split_planes(stack, pattern)):
        pix_mean = plane.mean(axis=0)
        frame_mean = plane.mean(axis=(1, 2))
        grand = float(frame_mean.mean())
        resid = plane - pix_mean[None] - (frame_mean - grand)[:, None, None]
        ss = float(np.einsum("ijk,ijk->", resid, resid))
        p = pix_mean.size
        a = acc.setdefault(colour, [0.0, 0.0, 0.0, 0.0, 0.0])
        a[0] += grand * p
        a[1] += ss
        a[2] += (p - 1) * (n - 1)
        a[3] += p
        a[4] += float(np.sum((pix_mean - pix_mean.mean()) ** 2)) + p * (pix_mean.mean()) ** 2
    out = {}
    for colour, (s_mu, ss, dof, p, s2) in acc.items():
        mu = s_mu / p
        spatial_var = max(s2 / p - mu * mu, 0.0)
        out[colour] = (mu, ss / dof, dof, math.sqrt(spatial_var), int(p))
    return out


def _stack(frames: Sequence[Any], shift: int) -> np.ndarray:
    arrays = [_frame_array(f) for f in frames]
    shape = arrays[0].shape
    if any(a.shape != shape for a in arrays):
        raise MetrawError("all calibration frames must have the same shape")
    return np.stack([_native(a, shift) for a in arrays])


def from_series(flats: Sequence[Sequence[Any]], darks: Sequence[Any], *, profile: CalibrationProfile | None = None,
                cfa_pattern: str | None = None, white_level_dn: float | None = None, adc_bits: int | None = None,
                fit_fraction: float = FIT_FRACTION) -> CalibrationResult:
    """EMVA 1288 photon transfer from flat-field levels and dark frames.

    ``flats``: one entry per illumination level, each a sequence of >= 2 frames (uint16
    arrays or ``RawImage``) taken under the same light. ``darks``: >= 2 dark frames with
    the flats' exposure time. Pattern, white level and ADC bits come from the arguments,
    else from ``profile`` or the first ``RawImage``, else the pattern is required and the
    white level is inferred from the data's bit depth. The black level is *measured* (mean
    of the darks). Returns a ``CalibrationResult``; ``profile`` fields other than the
    radiometry are kept. Saturation (variance peak) sets ``full_well_e`` when reached.
    """
    if len(darks) < 2:
        raise MetrawError(f"from_series needs >= 2 dark frames, got {len(darks)}")
    if len(flats) < 2:
        raise MetrawError(f"from_series needs >= 2 illumination levels, got {len(flats)}")
    for i, level in enumerate(flats):
        if isinstance(level, (np.ndarray, RawImage)) or len(level) < 2:
            raise MetrawError(f"flat level {i} must be a sequence of >= 2 frames under the same light")
    if not 0 < fit_fraction <= 1:
        raise MetrawError(f"fit_fraction must be in (0, 1], got {fit_fraction}")
    all_frames = list(darks) + [f for level in flats for f in level]
    base = profile or _first_profile(all_frames)
    arrays = [_frame_array(f) for f in all_frames]
    rad = _radiometry(arrays, base, cfa_pattern, None, white_level_dn, adc_bits)
    rad.black_dn = None  # measured from the darks
    dark = _channel_stats(_stack(darks, rad.shift), rad.cfa_pattern)
    levels = []
    for level in flats:
        st = _stack(level, rad.shift)
        clipped = bool(np.any(st >= rad.white_dn))
        levels.append((_channel_stats(st, rad.cfa_pattern), clipped))
    notes: list[str] = []
    channels: dict[str, ChannelCalibration] = {}
    full_wells = []
    for c in channel_names(rad.cfa_pattern):
        mu_d, var_d, dof_d, sd_d, npix_d = dark[c]
        mu = np.array([lv[0][c][0] for lv in levels])
        var = np.array([lv[0][c][1] for lv in levels])
        dof = np.array([lv[0][c][2] for lv in levels])
        clipped = np.array([lv[1] for lv in levels])
        order = np.argsort(mu)
        mu, var, dof, clipped = mu[order], var[order], dof[order], clipped[order]
        peak = int(np.argmax(var))
        reached = peak < len(mu) - 1 or bool(clipped[peak])
        x_all = mu - mu_d
        if reached:
            sat_dn = float(mu[peak])
            use = (x_all <= fit_fraction * (sat_dn - mu_d)) & ~clipped
        else:
            sat_dn = None
            use = ~clipped
        use &= x_all > 0
        if use.sum() < 2:
            raise MetrawError(f"channel {c}: fewer than 2 unclipped flat levels below {fit_fraction:.0%} of saturation")
        x, y = x_all[use], var[use] - var_d
        sy2 = 2.0 * var[use] ** 2 / dof[use]
        w = 1.0 / sy2
        sxx = float(np.sum(w * x * x))
        gain = float(np.sum(w * x * y) / sxx)
        m = int(use.sum())
        chi2 = float(np.sum(w * (y - gain * x) ** 2) / (m - 1)) if m > 1 else 1.0
        u_stat = math.sqrt(1.0 / sxx) * math.sqrt(max(1.0, chi2))
        var_d_u = math.sqrt(2.0 * var_d ** 2 / dof_d)
        u_dark = abs(float(np.sum(w * x)) / sxx) * var_d_u  # var_d enters every point
        gain_u = math.hypot(u_stat, u_dark)
        rn, rn_u = _read_noise(var_d, var_d_u, gain, gain_u)
        if var_d - 1.0 / 12.0 <= 0:
            notes.append(f"channel {c}: dark noise is below quantisation; read noise not resolved")
        black_u = sd_d / math.sqrt(npix_d)  # spatial scatter of the per-pixel dark means (DSNU + temporal)
        channels[c] = ChannelCalibration(c, gain, gain_u, rn, rn_u, float(mu_d), black_u, m,
                                         (float(x.min()), float(x.max())), chi2, saturation_dn=sat_dn)
        if sat_dn is not None:
            full_wells.append((sat_dn - mu_d) / gain)
        if m < 5:
            notes.append(f"channel {c}: only {m} levels in the fit range (EMVA 1288 asks for many more)")
    if rad.shift:
        notes.append(f"data have {rad.shift} unused low bits: profile in native DN (stored DN >> {rad.shift})")
    full_well = float(min(full_wells)) if full_wells else None
    prof = _build_profile(base, rad, channels, full_well)
    return CalibrationResult(prof, "photon_transfer", channels, rad.shift, notes)


# ------------------------------------------------------------------------------ single frame
def _block_stats(plane: np.ndarray, white: float, cells: int) -> dict[str, np.ndarray]:
    """Per block of ``cells`` x ``cells`` 2 x 2 cells (n = cells^2 cells) of one CFA plane:

    ``mu`` the mean; ``v`` the mean square of the diagonal Haar detail HH (noise alone:
    sigma^2 chi2_n / n); ``s`` the smoothness statistic, the mean square of the horizontal and
    vertical details LH, HL about their block means (noise alone: sigma^2 chi2_{2n-2} / (2n-2));
    ``ok`` False for clipped blocks; ``row``, ``col`` the block centre as a fraction of the plane.
    For white Gaussian noise the four Haar sub-bands of a 2 x 2 cell are orthogonal projections,
    so ``s`` is independent of ``v``: choosing blocks by ``s`` leaves the distribution of their
    ``v`` untouched (no selection bias to correct). Texture, edges and curvature raise ``s`` (LH/HL
    pass lower spatial frequencies than HH and respond to edges of any orientation).
    """
    b = cells
    h, w = plane.shape
    nby, nbx = h // (2 * b), w // (2 * b)
    if nby == 0 or nbx == 0:
        empty = np.empty(0)
        return {"mu": empty, "v": empty, "s": empty, "ok": np.empty(0, bool), "row": empty, "col": empty}
    p = plane[: nby * 2 * b, : nbx * 2 * b]
    y00, y01, y10, y11 = p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]

    def blocks(a: np.ndarray) -> np.ndarray:
        return a.reshape(nby, b, nbx, b).transpose(0, 2, 1, 3)

    hh = blocks(0.5 * (y00 - y01 - y10 + y11))
    lh = blocks(0.5 * (y00 + y01 - y10 - y11))
    hl = blocks(0.5 * (y00 - y01 + y10 - y11))
    v = np.mean(hh ** 2, axis=(2, 3))
    s = (np.sum((lh - lh.mean(axis=(2, 3), keepdims=True)) ** 2, axis=(2, 3))
         + np.sum((hl - hl.mean(axis=(2, 3), keepdims=True)) ** 2, axis=(2, 3))) / _smooth_dof(b)
    mu = np.mean(blocks(0.25 * (y00 + y01 + y10 + y11)), axis=(2, 3))
    pb = p.reshape(nby, 2 * b, nbx, 2 * b)
    hi = pb.max(axis=(1, 3))
    lo = pb.min(axis=(1, 3))
    ok = (hi < white) & (lo > 0) & (mu + 6.0 * np.sqrt(v) < white) & (v > 0) & (s > 0)
    row, col = np.meshgrid((np.arange(nby) + 0.5) / nby, (np.arange(nbx) + 0.5) / nbx, indexing="ij")
    return {"mu": mu.ravel(), "v": v.ravel(), "s": s.ravel(), "ok": ok.ravel(), "row": row.ravel(),
            "col": col.ravel()}


def _smooth_dof(cells: int) -> int:
    """Degrees of freedom of the smoothness statistic ``s`` of ``_block_stats`` (LH and HL about their means)."""
    return max(2 * cells * cells - 2, 1)


def _smooth_blocks(s: np.ndarray, dof: int, texture_p: float, quantile: float = SMOOTH_QUANTILE) -> np.ndarray:
    """Indices of the blocks of one signal bin whose smoothness ``s`` is consistent with noise alone.

    The bin's noise scale is read off its smoothest ``quantile`` (that order statistic matched to
    the same quantile of chi2_dof / dof); blocks above the ``1 - texture_p`` quantile of that scaled
    distribution are textured. In a noise-only bin a fraction ~``texture_p`` is dropped; in a bin
    mixing materials the smoothest population is kept. Assumption: the smoothest quarter of a bin
    is nearly noise only; texture it still holds biases the bin upwards (``_fit_channel`` catches
    the curve shapes this produces, ``_fit_channel_jackknife`` measures what it does to K).
    """
    m = s.size
    k = max(int(round(quantile * m)), 1)
    ref = float(np.partition(s, k - 1)[k - 1])
    scale = ref * dof / stats.chi2.ppf(k / (m + 1.0), dof)
    return np.flatnonzero(s <= scale * stats.chi2.ppf(1.0 - texture_p, dof) / dof)


def _signal_bins(x: np.ndarray, per_bin: int, nbins: int = 48) -> list[np.ndarray]:
    """Index arrays of the signal bins: at most ``nbins`` (fewer for few blocks) equal steps of
    sqrt(x), i.e. about equal steps of noise level, each holding >= ``per_bin`` blocks. Sparse
    bins above the last full one (the bright tail: it carries the gain's lever arm, e.g. next to
    clipped highlights) are merged in order until they hold ``per_bin``; sparse bins below it are
    dropped (rare dark levels come from a few deep shadows, mostly along shadow edges, which would
    anchor the intercept). Measured on the embedded scenes: merging the dark tail as well lowers
    the share of honest fits (|z| <= 2) from ~95 % to ~84 %."""
    nb = int(np.clip(x.size // per_bin, 1, nbins))
    r = np.sqrt(np.maximum(x, 0.0))
    lo, hi = (float(r.min()), float(r.max())) if r.size else (0.0, 0.0)
    idx = np.minimum(((r - lo) / max(hi - lo, 1e-12) * nb).astype(int), nb - 1)
    bins = [np.flatnonzero(idx == i) for i in range(nb)]
    full = [i for i, b in enumerate(bins) if b.size >= per_bin]
    if not full:
        return []
    out = [bins[i] for i in range(full[0], full[-1] + 1) if bins[i].size >= per_bin]
    tail = np.empty(0, int)
    for b in bins[full[-1] + 1:]:
        tail = np.concatenate([tail, b])
        if tail.size >= per_bin:
            out.append(tail)
            tail = np.empty(0, int)
    return out


def _fit_ptc(x: np.ndarray, y: np.ndarray, sy: np.ndarray, quadratic: bool = True
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least squares y = a x + b (+ c x^2): parameters [a, b, c], covariance, chi2_red."""
    cols = [x, np.ones_like(x)] + ([x * x] if quadratic else [])
    design = np.stack(cols, axis=1)
    w = 1.0 / sy ** 2
    scale = np.sqrt(np.sum(design ** 2 * w[:, None], axis=0))  # column scaling for conditioning
    ds = design / scale
    normal = ds.T @ (ds * w[:, None])
    try:
        cov_s = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        cov_s = np.full(normal.shape, np.inf)
    beta_s = cov_s @ (ds.T @ (w * y))
    beta = beta_s / scale
    cov = cov_s / np.outer(scale, scale)
    dof = x.size - design.shape[1]
    chi2 = float(np.sum(w * (y - design @ beta) ** 2) / dof) if dof > 0 else float("nan")
    if dof > 0 and chi2 > 1:
        cov = cov * chi2
    if not quadratic:
        beta, cov2 = np.append(beta, 0.0), np.zeros((3, 3))
        cov2[:2, :2] = cov
        cov = cov2
    return beta, cov, chi2


def _admissible_fit(x: np.ndarray, y: np.ndarray, sy: np.ndarray) -> tuple[float, float, float] | None:
    """Weighted least squares of y = a x + b + c x^2 under the physical constraints b >= q^2/12
    (b = K^2 sigma_d^2 + q^2/12) and c >= 0 (PRNU^2, multiplicative texture): the best of the
    fits with c = 0, with b = 1/12, and with both (active sets; ``_fit_channel`` calls it when the
    free fit breaks a constraint). Returns (a, b, c), or None when no such fit is admissible."""
    best = None
    w = 1.0 / sy ** 2
    for fix_b, fix_c in ((False, True), (True, False), (True, True)):
        cols = [x] + ([] if fix_b else [np.ones_like(x)]) + ([] if fix_c else [x * x])
        design = np.stack(cols, axis=1)
        target = y - (1.0 / 12.0 if fix_b else 0.0)
        scale = np.sqrt(np.sum(design ** 2 * w[:, None], axis=0))
        ds = design / scale
        try:
            beta = np.linalg.solve(ds.T @ (ds * w[:, None]), ds.T @ (w * target)) / scale
        except np.linalg.LinAlgError:
            continue
        a = float(beta[0])
        b = 1.0 / 12.0 if fix_b else float(beta[1])
        c = 0.0 if fix_c else float(beta[-1])
        if b < 1.0 / 12.0 or c < 0.0:
            continue
        chi2 = float(np.sum(w * (target - design @ beta) ** 2))
        if best is None or chi2 < best[0]:
            best = (chi2, a, b, c)
    return None if best is None else best[1:]


def _read_noise_fit(a: float, b: float, cov: np.ndarray, black_u: float) -> tuple[float, float]:
    """sigma_d = sqrt(b - 1/12) / a from a single-frame fit, with first-order uncertainty from the
    full covariance of (a, b) (their errors are anti-correlated, which adds up in sigma_d) and the black
    level's uncertainty (b shifts by a * delta_black); one-sided when b <= 1/12 (as ``_read_noise``)."""
    var_a, var_b, cov_ab = float(cov[0, 0]), float(cov[1, 1]) + (a * black_u) ** 2, float(cov[0, 1])
    excess = b - 1.0 / 12.0
    if not (np.isfinite(var_a) and np.isfinite(var_b) and np.isfinite(cov_ab)):
        return (math.sqrt(max(excess, 0.0)) / a if a > 0 else float("nan")), float("inf")
    if excess <= 0:
        return 0.0, math.sqrt(math.sqrt(max(var_b, 0.0))) / a
    sd = math.sqrt(excess) / a
    da, db = -sd / a, 1.0 / (2.0 * a * math.sqrt(excess))
    return sd, math.sqrt(max(da * da * var_a + db * db * var_b + 2.0 * da * db * cov_ab, 0.0))


def _fit_channel(mu: np.ndarray, v: np.ndarray, s: np.ndarray, black: float, n_per_block: int, channel: str,
                 notes: list[str], black_u: float = 0.0, texture_p: float = 1e-3) -> ChannelCalibration:
    """Bin blocks by mean, keep the smooth ones (``_smooth_blocks``), fit the photon-transfer curve.

    Per bin the variance is the mean of the kept blocks' HH variances: unbiased for noise-only
    blocks (the selection looks at ``s`` alone), with n k y / sigma^2 ~ chi2_{n k} for k kept
    blocks, hence the standard uncertainty y sqrt(2 / (n k)). ``black_u`` (the black level's
    uncertainty) enters the intercept: b shifts by K * delta_black.

    Fit var = a x + b + c x^2 (x = mu - black), weighted, Birge-inflated (``_fit_ptc``). Physics
    demands b >= q^2/12 (b = K^2 sigma_d^2 + q^2/12) and c >= 0 (PRNU^2, multiplicative
    texture). Texture the frame cannot tell from noise (white at the plane scale, heavier on dark
    materials than on bright ones) bends the free fit exactly across those limits - intercept under
    q^2/12, negative curvature - and then inflates K. Such a fit is replaced by the constrained one
    (``_admissible_fit``) and the distance K moved is added in quadrature to its uncertainty (a
    noise-only frame moves by about its own sampling error; a textured one by its texture bias).
    Raises MetrawError when too few smooth levels remain or K is not constrained (relative
    uncertainty >= MAX_RELATIVE_GAIN_UNCERTAINTY).
    """
    nblk = mu.size
    if nblk < MIN_BLOCKS:
        raise MetrawError(f"channel {channel}: only {nblk} unclipped blocks "
                          f"(need >= {MIN_BLOCKS}); the frame is too small or too textured for a single-frame fit")
    per_bin = int(np.clip(nblk // 8, MIN_PER_BIN, BIN_BLOCKS))  # >= 8 bins where blocks are few
    dof_s = _smooth_dof(int(round(math.sqrt(n_per_block))))
    xs, ys, sys_, counts = [], [], [], []
    for sel in _signal_bins(mu - black, per_bin):
        keep = sel[_smooth_blocks(s[sel], dof_s, texture_p)]
        if keep.size < per_bin // 2:
            continue
        est = float(np.mean(v[keep]))
        xs.append(float(np.mean(mu[keep])) - black)
        ys.append(est)
        sys_.append(est * math.sqrt(2.0 / (keep.size * n_per_block)))
        counts.append(keep.size)
    x, y, sy = np.array(xs), np.array(ys), np.array(sys_)
    if x.size < 4:
        raise MetrawError(f"channel {channel}: smooth blocks cover too few signal levels for a single-frame fit "
                          f"(mean {mu.min():.1f}..{mu.max():.1f} DN); the frame is too flat, small or textured")
    # Outlier bins (texture-dominated): iterative rejection on robustly scaled residuals.
    keep = np.ones(x.size, bool)
    for _ in range(5):
        beta, _, _ = _fit_ptc(x[keep], y[keep], sy[keep], quadratic=keep.sum() >= 6)
        res = (y - (beta[0] * x + beta[1] + beta[2] * x * x)) / sy
        scale = max(1.0, 1.4826 * float(np.median(np.abs(res[keep]))))
        new_keep = np.abs(res) <= 4.0 * scale
        if np.array_equal(new_keep, keep) or new_keep.sum() < 4:
            break
        keep = new_keep
    if (~keep).sum():
        notes.append(f"channel {channel}: {(~keep).sum()} of {x.size} signal bins rejected as outliers (texture)")
    x, y, sy = x[keep], y[keep], sy[keep]
    counts = [k for k, ok in zip(counts, keep) if ok]
    # Photon-transfer peak inside the data (full well before the ADC clips): fit below 70 % of it.
    smooth = np.array([np.median(y[max(0, i - 2):i + 3]) for i in range(y.size)])
    peak = int(np.argmax(smooth))
    tail = y[peak + 1:]
    if tail.size >= 3 and np.median(tail) < smooth[peak] - 3 * sy[peak]:
        cut = x <= FIT_FRACTION * x[peak]
        notes.append(f"channel {channel}: variance peaks at {x[peak] + black:.1f} DN; fit below {FIT_FRACTION:.0%} of it")
        x, y, sy = x[cut], y[cut], sy[cut]
        counts = [k for k, ok in zip(counts, cut) if ok]
    if x.size < 4:
        raise MetrawError(f"channel {channel}: too few signal levels for a single-frame fit")
    beta, cov, chi2 = _fit_ptc(x, y, sy, quadratic=True)
    a, b, c = (float(t) for t in beta)
    ua = math.sqrt(cov[0, 0]) if np.isfinite(cov[0, 0]) else float("inf")
    uc = math.sqrt(cov[2, 2]) if np.isfinite(cov[2, 2]) else float("inf")
    span = (float(x.min()), float(x.max()))
    rn, rn_u = _read_noise_fit(a, b, cov, black_u)
    if b < 1.0 / 12.0 or c < 0.0:
        # Not physical: report the constrained fit, its uncertainty widened by the move it took.
        adm = _admissible_fit(x, y, sy)
        if adm is not None:
            a_free, rn_free = a, rn
            a, b, c = adm
            ua = math.hypot(ua, a - a_free)
            cov = cov.copy()
            cov[0, 0] = ua * ua
            rn, rn_u = _read_noise_fit(a, b, cov, black_u)
            rn_u = math.hypot(rn_u, rn - rn_free)
            notes.append(f"channel {channel}: free fit not physical (intercept below q^2/12 or negative curvature): "
                         f"constrained fit, K moved by {a - a_free:+.3g} DN/e- (in its uncertainty)")
    if not (a > 0 and ua < MAX_RELATIVE_GAIN_UNCERTAINTY * a):
        raise MetrawError(f"channel {channel}: the frame does not constrain the gain (K = {a:.3g} +- {ua:.2g} DN/e-, "
                          f"signal range {span[0]:.1f}..{span[1]:.1f} DN above black): too flat or too textured; it "
                          f"needs smooth regions over a wide range of brightness, or use a flat/dark series")
    if b - 1.0 / 12.0 <= 0:
        notes.append(f"channel {channel}: read noise not resolved above quantisation")
    prnu = math.sqrt(c) if c > 0 else 0.0
    prnu_u = uc / (2 * prnu) if prnu > 0 else math.sqrt(uc)
    return ChannelCalibration(channel, a, ua, rn, rn_u, black, black_u, int(sum(counts)), span, chi2,
                              prnu=prnu, prnu_u=prnu_u)


def _fit_channel_jackknife(mu: np.ndarray, v: np.ndarray, s: np.ndarray, tile: np.ndarray, black: float,
                           n_per_block: int, channel: str, notes: list[str], black_u: float = 0.0,
                           texture_p: float = 1e-3) -> ChannelCalibration:
    """``_fit_channel`` with a delete-one-tile jackknife over the TILES x TILES tiles of the frame.

    The fit's own uncertainty treats the bins' scatter as noise; texture makes K depend on which
    objects the frame happens to show. Refitting with each tile left out (g refits) gives the
    jackknife standard error sqrt((g-1)/g sum (K_i - mean K)^2) (and the same for read noise), which
    holds that dependence; the reported uncertainty is the larger of the two. A channel whose refits
    fail for more than half of the tiles is unstable and refused; so is one whose K is no longer
    constrained (MAX_RELATIVE_GAIN_UNCERTAINTY) with the jackknife error. Texture that biases every
    tile alike is not seen here: that is left to the physical constraints of ``_fit_channel``.
    """
    ch = _fit_channel(mu, v, s, black, n_per_block, channel, notes, black_u, texture_p)
    reps, fails = [], 0
    groups = np.unique(tile)
    for t in groups:
        m = tile != t
        try:
            r = _fit_channel(mu[m], v[m], s[m], black, n_per_block, channel, [], black_u, texture_p)
            reps.append((r.gain_dn_per_e, r.read_noise_e))
        except MetrawError:
            fails += 1
    if len(reps) < 2 or fails > groups.size // 2:
        raise MetrawError(f"channel {channel}: the fit is unstable: it fails for {fails} of {groups.size} refits "
                          f"that each leave one tile of the frame out; the frame is too small or too textured")
    arr = np.array(reps)
    g = len(reps)
    u_jk = np.sqrt((g - 1) / g * np.sum((arr - arr.mean(axis=0)) ** 2, axis=0))
    if u_jk[0] > ch.gain_dn_per_e_u or u_jk[1] > ch.read_noise_e_u:
        notes.append(f"channel {channel}: uncertainty from the tile jackknife ({g} refits)")
    ch.gain_dn_per_e_u = max(ch.gain_dn_per_e_u, float(u_jk[0]))
    ch.read_noise_e_u = max(ch.read_noise_e_u, float(u_jk[1]))
    if not ch.gain_dn_per_e_u < MAX_RELATIVE_GAIN_UNCERTAINTY * ch.gain_dn_per_e:
        raise MetrawError(f"channel {channel}: the frame does not constrain the gain (K = {ch.gain_dn_per_e:.3g} +- "
                          f"{ch.gain_dn_per_e_u:.2g} DN/e-, jackknife over {g} tiles): the fit depends on which "
                          f"parts of the frame it sees")
    return ch


def _refused_channel(channel: str, black: float, black_u: float) -> ChannelCalibration:
    """Placeholder of a channel the frame cannot calibrate: NaN values and infinite uncertainties, so it
    has weight 0 wherever channels or images are combined by inverse variance (``_weighted_mean``)."""
    nan, inf = float("nan"), float("inf")
    return ChannelCalibration(channel, nan, inf, nan, inf, black, black_u, 0, (nan, nan), nan)


def from_image(image: RawImage | np.ndarray, *, black_level_dn: float | None = None,
               cfa_pattern: str | None = None, white_level_dn: float | None = None, adc_bits: int | None = None,
               profile: CalibrationProfile | None = None, block_cells: int = BLOCK_CELLS,
               texture_p: float = 1e-3) -> CalibrationResult:
    """Single-frame Poisson-Gaussian noise fit (see the module docstring).

    ``image``: a ``RawImage`` (pattern, black and white from its profile) or a 2-D uint16
    array with ``black_level_dn`` and ``cfa_pattern`` given (in the array's stored units).
    ``block_cells``: block side in 2 x 2 cells of one CFA plane; ``texture_p``: probability
    that the smoothness test drops a noise-only block. A channel that cannot be fitted
    (unconstrained, not physical or unstable: ``_fit_channel``, ``_fit_channel_jackknife``) is
    kept as NaN +- inf in ``channels`` with the reason in ``notes``, and has no weight in the
    profile; raises ``MetrawError`` when no channel can be fitted (tiny, flat, clipped or
    textured frames).
    """
    if not 0 < texture_p < 1:
        raise MetrawError(f"texture_p must be in (0, 1), got {texture_p}")
    if block_cells < 2:
        raise MetrawError(f"block_cells must be >= 2, got {block_cells}")
    base = profile if profile is not None else (image.profile if isinstance(image, RawImage) else None)
    data = _frame_array(image)
    rad = _radiometry([data], base, cfa_pattern, black_level_dn, white_level_dn, adc_bits)
    if rad.black_dn is None:
        raise MetrawError("from_image needs the black level (black_level_dn): a single frame cannot separate it "
                          "from the read noise")
    black_u = 0.0
    if black_level_dn is None and base is not None:
        black_u = float(base.uncertainty.get("black_level_dn", 0.0)) / rad.scale
    native = _native(data, rad.shift)
    n = block_cells * block_cells
    keys = ("mu", "v", "s", "tile")
    per_channel: dict[str, dict[str, list[np.ndarray]]] = {}
    total = rejected_clip = 0
    for (colour, _, _), plane in zip(plane_offsets(rad.cfa_pattern), split_planes(native, rad.cfa_pattern)):
        st = _block_stats(plane, rad.white_dn, block_cells)
        st["tile"] = (np.floor(st["row"] * TILES) * TILES + np.floor(st["col"] * TILES)).astype(int)
        good = st["ok"]
        total += good.size
        rejected_clip += int((~good).sum())
        acc = per_channel.setdefault(colour, {k: [] for k in keys})
        for k in keys:
            acc[k].append(st[k][good])
    notes = []
    if rad.shift:
        notes.append(f"data have {rad.shift} unused low bits: profile in native DN (stored DN >> {rad.shift})")
    if total:
        notes.append(f"blocks: {total} in all, {rejected_clip} clipped or dark-clipped")
    channels, refused = {}, {}
    for colour in channel_names(rad.cfa_pattern):
        acc = per_channel.get(colour, {k: [] for k in keys})
        mu, v, s, tile = (np.concatenate(acc[k]) if acc[k] else np.empty(0) for k in keys)
        try:
            channels[colour] = _fit_channel_jackknife(mu, v, s, tile.astype(int), rad.black_dn, n, colour, notes,
                                                      black_u, texture_p)
        except MetrawError as exc:
            refused[colour] = str(exc)
            channels[colour] = _refused_channel(colour, rad.black_dn, black_u)
    if len(refused) == len(channels):
        raise MetrawError("; ".join(refused.values()))
    notes += [f"channel {c} not fitted: {why}" for c, why in refused.items()]
    prof = _build_profile(base, rad, channels, None)
    return CalibrationResult(prof, "single_frame_poisson_gaussian", channels, rad.shift, notes)


# ------------------------------------------------------------------------------ several single frames


def combine_images(results: Sequence[CalibrationResult]) -> CalibrationResult:
    """Single-frame fits of several images of one camera -> one result: per channel and for the profile, the
    inverse-variance weighted mean of gain, read noise and black level, its uncertainty inflated by the Birge
    ratio when the images scatter more than their stated uncertainties (``_weighted_mean``). The first result's
    profile carries the geometry."""
    if not results:
        raise MetrawError("combine_images needs at least one single-frame result")
    if len(results) == 1:
        return results[0]
    channels = {}
    for c in results[0].channels:
        per = [r.channels[c] for r in results]
        k, k_u, chi2 = _weighted_mean([p.gain_dn_per_e for p in per], [p.gain_dn_per_e_u for p in per])
        rn, rn_u, _ = _weighted_mean([p.read_noise_e for p in per], [p.read_noise_e_u for p in per])
        bl, bl_u, _ = _weighted_mean([p.black_level_dn for p in per], [max(p.black_level_dn_u, 1e-12) for p in per])
        span = (min(p.signal_range_dn[0] for p in per), max(p.signal_range_dn[1] for p in per))
        channels[c] = ChannelCalibration(c, k, k_u, rn, rn_u, bl, bl_u, sum(p.n_points for p in per), span, chi2)
    names = list(channels)
    k, k_u, _ = _weighted_mean([channels[c].gain_dn_per_e for c in names], [channels[c].gain_dn_per_e_u for c in names])
    rn, rn_u, _ = _weighted_mean([channels[c].read_noise_e for c in names], [channels[c].read_noise_e_u for c in names])
    first = results[0].profile
    unc = {**first.uncertainty, "gain_dn_per_e": k_u, "read_noise_e": rn_u}
    profile = first.replace(gain_dn_per_e=k, read_noise_e=rn, uncertainty=unc)
    notes = [f"{len(results)} images fitted one by one, combined by inverse-variance weights (Birge-inflated)"]
    notes += sorted({n for r in results for n in r.notes if "unused low bits" in n})
    return CalibrationResult(profile, "single_frame_poisson_gaussian", channels, results[0].unused_low_bits, notes)
