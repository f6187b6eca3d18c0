"""Photon transfer (EMVA 1288) from flat-field levels and dark frames: ``from_series`` (``metraw.calibrate``)."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from metraw.calibrate.results import (FIT_FRACTION, CalibrationResult, ChannelCalibration, _build_profile,
                                     _first_profile, _frame_array, _native, _radiometry, _read_noise)
from metraw.errors import MetrawError
from metraw.raw.cfa import channel_names, plane_offsets, split_planes
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile


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
