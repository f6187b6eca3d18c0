"""Planning an emulation (`metraw.emulate.emulator`): the thinning ratios of the light, the target frame's
geometry, the transfer functions and gridding of the expected chain and the photon chain's tables, per
(source profile, source shape, target, accuracy, edge policy), cached."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.physics.accuracy import DEFAULT_ACCURACY, Accuracy
from metraw.raw.cfa import channel_names, fill_factor
from metraw.raw.sensor import readout

__all__ = ["plan_emulation", "EmulationPlan", "thinning_ratios", "EDGE_POLICIES"]

EDGE_POLICIES = ("reflect", "zero", "valid")
_OVERSAMPLE = 2.0  # grid Nyquist / optical band limit


def _gridding(error: float) -> tuple[int, float]:
    """Gaussian gridding half-width M [grid points] and window sigma for a relative error ~``error``.

    At oversampling 2 the aliasing error is exp(-pi^2 s^2) and the window truncation exp(-M^2/(2 s^2));
    balancing them gives s^2 = M / (pi sqrt 2) and an error ~exp(-pi M / sqrt 2) (M = 6: 1.6e-6).
    """
    m = max(2, math.ceil(-math.log(error) * math.sqrt(2.0) / math.pi))
    return m, math.sqrt(m / (math.pi * math.sqrt(2.0)))


_PLAN_CACHE: dict[str, "EmulationPlan"] = {}


# ----------------------------------------------------------------------------- radiometry
def _source_geometry(profile) -> dict[str, float]:
    need = ("pixel_pitch_m", "focal_length_m", "aperture_diameter_m", "altitude_m", "exposure_s")
    missing = [n for n in need if getattr(profile, n) is None]
    if missing:
        raise MetrawError(f"source profile lacks geometry needed for emulation: {', '.join(missing)}")
    g = {n: float(getattr(profile, n)) for n in need}
    if g["exposure_s"] <= 0:
        raise MetrawError(f"source exposure_s must be > 0, got {g['exposure_s']}")
    return g


def thinning_ratios(source_profile, target: TargetSystem) -> tuple[dict[str, float], dict[str, float]]:
    """(alpha_c, p_c) per source colour (module docstring). Raises when any p_c > 1."""
    g = _source_geometry(source_profile)
    if target.exposure_s <= 0:
        raise MetrawError("target exposure_s must be > 0: a zero exposure records no light "
                          "(use metraw.raw.sensor.readout on zeros for a dark frame)")
    if source_profile.is_mono and target.cfa_pattern != "mono":
        raise MetrawError("a mono source has no colour information for a colour (CFA) target")
    from metraw.physics.optics import pupil_area_m2

    a_s = pupil_area_m2(g["aperture_diameter_m"], source_profile.obscuration_ratio)
    src = a_s / g["altitude_m"] ** 2 * g["exposure_s"] * source_profile.optical_transmission
    tgt = (target.aperture_area_m2 / target.altitude_m**2 * target.exposure_s * target.optical_transmission
           * target.atmospheric_transmission)
    alpha, p = {}, {}
    for c in channel_names(source_profile.cfa_pattern):
        eta_s = float(source_profile.qe_per_channel.get(c, 1.0))
        eta_t = target.qe("L" if target.cfa_pattern == "mono" else c)
        phi = fill_factor(source_profile.cfa_pattern, c)
        alpha[c] = tgt * eta_t / (src * eta_s)
        p[c] = alpha[c] / phi
        if p[c] > 1:
            raise MetrawError(
                f"target needs {p[c]:.3g} times more light than the source recorded in band {c} "
                f"(alpha_{c} = {alpha[c]:.3g}, fill factor {phi:g}, thinning probability p = alpha/phi "
                f"= {p[c]:.3g} > 1): light cannot be created, the source is not good enough for this target")
    return alpha, p


def _tail_lod(threshold: float, obscuration: float) -> float:
    """Distance [lambda/D] beyond which the one-sided marginal PSF tail is <= threshold.

    Marginal of the asymptotic wing density 1 / (pi^3 (1 - eps) r^3): tail(x) = 2 / (pi^3 (1 - eps) x).
    """
    return 2.0 / (math.pi**3 * (1.0 - obscuration) * threshold)


# ----------------------------------------------------------------------------- planning
@dataclass
class EmulationPlan:
    """Geometry, transfer functions and bounds of one (source geometry, target, accuracy, edge)."""

    channels: tuple[str, ...]
    source_gsd_m: float
    cell_m: float
    cells_shape: tuple[int, int]
    target_gsd_m: float
    frame_shape: tuple[int, int]
    rotation_rad: float
    centre_m: tuple[float, float]
    alpha: dict[str, float]
    p: dict[str, float]
    bands: dict[str, tuple[float, float]]
    edge: str
    grid_h_m: tuple[float, float]  # (hy, hx)
    grid_shape: tuple[int, int]
    grid_origin: tuple[int, int]  # grid index of ground (0, 0)
    n_inside: tuple[int, int]  # grid steps across the footprint (y, x)
    transfer: dict[str, np.ndarray]
    gridding: tuple[int, float]
    prebin: int
    psf_table: dict[str, Any]
    margin_m: float
    modelled: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    bounds: dict[str, float] = field(default_factory=dict)
    smear_m: float = 0.0
    smear_angle_rad: float = 0.0
    jitter_m: float = 0.0
    diameter_m: float = 1.0
    altitude_m: float = 1.0

    def summary(self) -> dict[str, Any]:
        return {
            "source_gsd_m": self.source_gsd_m, "target_gsd_m": self.target_gsd_m,
            "gsd_ratio": self.target_gsd_m / self.source_gsd_m, "frame_shape": list(self.frame_shape),
            "rotation_rad": self.rotation_rad, "frame_centre_m": list(self.centre_m), "alpha": self.alpha,
            "p": self.p, "edge": self.edge, "margin_m": self.margin_m, "grid_spacing_m": list(self.grid_h_m),
            "grid_shape": list(self.grid_shape), "prebin_cells": self.prebin, "bands_m": self.bands,
            "modelled": self.modelled, "skipped": self.skipped, "error_bounds": self.bounds,
        }


@lru_cache(maxsize=32)
def _poly_otf_table(band, diameter, obscuration, altitude, n_lambda, f_max):
    """Radial table (f [cycles/m], OTF) of the band-averaged annulus OTF on the ground. Cached (read-only arrays),
    as the plan arrays below: the pretraining makes a plan per box point, and most points share the optics."""
    from metraw.physics.optics import annulus_otf, band_wavelengths

    lam, w = band_wavelengths(band, n_lambda)
    f = np.linspace(0.0, f_max, 8193)
    otf = np.zeros_like(f)
    for lk, wk in zip(lam, w):
        otf += wk * annulus_otf(f * altitude * lk / diameter, obscuration)
    return _read_only(f), _read_only(otf)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@lru_cache(maxsize=8)
def _grid_arrays(ny: int, nx: int, hy: float, hx: float, plan_s: float):
    """(fy (ny, 1), fx (1, nx // 2 + 1), |f|, hx hy win^2) of a plan's real-FFT grid, win the Gaussian gridding
    window's transform; read-only, cached per grid."""
    fy = sfft.fftfreq(ny, hy)[:, None]
    fx = sfft.rfftfreq(nx, hx)[None, :]
    win = (math.sqrt(2 * math.pi) * plan_s) ** 2 * np.exp(
        -2 * math.pi**2 * plan_s**2 * ((fx * hx) ** 2 + (fy * hy) ** 2))
    return _read_only(fy), _read_only(fx), _read_only(np.hypot(fy, fx)), _read_only(hx * hy * win**2)


@lru_cache(maxsize=32)
def _grid_otf(grid: tuple, band, diameter, obscuration, altitude, n_lambda):
    """The band-averaged OTF (``_poly_otf_table``) at every frequency of ``_grid_arrays(*grid)``; read-only, cached."""
    f_tab, otf_tab = _poly_otf_table(band, diameter, obscuration, altitude, n_lambda, diameter / (band[0] * altitude))
    return _read_only(np.interp(_grid_arrays(*grid)[2], f_tab, otf_tab, right=0.0))


def _sinc_along(fx: np.ndarray, fy: np.ndarray, c: float, s: float, scale: float) -> np.ndarray:
    """np.sinc(scale (fx c + fy s)) on the grid, as a vector along one axis where the other's factor is exactly 0
    (fx c + fy s is then exactly fx c or fy s: a signed zero added changes no other value, and sinc(+-0) = 1),
    so an axis-aligned frame and track cost one vector, not a grid, of sines; bit-identical to the full form."""
    if s == 0.0:
        return np.sinc(scale * (fx * c))
    if c == 0.0:
        return np.sinc(scale * (fy * s))
    return np.sinc(scale * (fx * c + fy * s))


_GUIDE_BINS = 1 << 16  # guide table of the inverse encircled energy (photon chain): O(1) start of a lookup


@lru_cache(maxsize=16)
def _ee_table(obscuration: float, v_max: float):
    """Encircled-energy table of the annulus PSF in v = pi D theta / lambda (trapezoid, fine grid).

    Cached (read-only arrays): it depends on the target optics only, while plans are per source
    profile (each scene has its own exposure), and it is the costliest part of a plan (~0.3 s).
    """
    from metraw.physics.optics import annulus_intensity

    v = np.linspace(0.0, v_max, int(v_max / 0.005) + 1)
    integrand = 0.5 * (1 - obscuration**2) * annulus_intensity(v, obscuration) * v
    ee = np.concatenate(([0.0], np.cumsum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(v))))
    tail = 2.0 / (math.pi * v_max * (1.0 - obscuration))  # asymptotic 1 - EE(v_max)
    ee *= (1.0 - tail) / ee[-1]
    # guide[k] = last node j with ee[j] <= k / _GUIDE_BINS: each inverse lookup bisects a short range
    guide = np.clip(np.searchsorted(ee, np.arange(_GUIDE_BINS + 1) / _GUIDE_BINS, side="right") - 1, 0, ee.size - 2)
    for a in (v, ee, guide):
        a.flags.writeable = False
    return {"v": v, "ee": ee, "tail": tail, "v_max": v_max, "guide": guide}


def _plan_key(profile, shape, target, acc, edge) -> str:
    # the source's exposure sets only the thinning ratios (alpha, p): scenes of one camera that differ in exposure
    # alone (auto exposure) share the rest of the plan, its costly part (Fourier grid, transfer functions)
    prof = profile.to_dict()
    prof.pop("exposure_s", None)
    return json.dumps([prof, list(shape), target.to_dict(), acc.to_dict(), edge], sort_keys=True, default=str)


def plan_emulation(source_profile, source_shape: tuple[int, int], target: TargetSystem,
                   accuracy: Accuracy | None = None, edge: str = "reflect") -> EmulationPlan:
    """Everything decided before touching pixels; cached per (geometry, target, accuracy, edge), with the
    thinning ratios of ``source_profile``'s own exposure."""
    acc = accuracy or DEFAULT_ACCURACY
    key = _plan_key(source_profile, source_shape, target, acc, edge)
    plan = _PLAN_CACHE.get(key)
    if plan is None:  # made from this profile: its thinning ratios are this exposure's
        if len(_PLAN_CACHE) > 8:
            _PLAN_CACHE.pop(next(iter(_PLAN_CACHE)))
        plan = _PLAN_CACHE[key] = _make_plan(source_profile, tuple(source_shape), target, acc, edge)
        return plan
    alpha, p = thinning_ratios(source_profile, target)
    if alpha != plan.alpha or p != plan.p:
        plan = replace(plan, alpha=alpha, p=p)
    return plan


def _make_plan(source_profile, source_shape, target: TargetSystem, acc: Accuracy, edge: str) -> EmulationPlan:
    from metraw.physics.optics import n_band_wavelengths

    if edge not in EDGE_POLICIES:
        raise MetrawError(f"edge policy must be one of {', '.join(EDGE_POLICIES)}, got {edge!r}")
    alpha, p = thinning_ratios(source_profile, target)
    g = _source_geometry(source_profile)
    gs = g["pixel_pitch_m"] * g["altitude_m"] / g["focal_length_m"]
    gt = target.gsd_m
    mono = source_profile.is_mono
    cell = gs * (1 if mono else 2)
    if gt < cell:
        raise MetrawError(f"target GSD {gt:.4g} m is finer than the source's CFA cell {cell:.4g} m: "
                          "emulation cannot create resolution")
    H, W = source_shape
    step = 1 if mono else 2
    hc, wc = H // step, W // step
    if hc < 1 or wc < 1:
        raise MetrawError(f"source image {source_shape} holds no whole CFA cell")
    Hm, Wm = hc * cell, wc * cell
    channels = channel_names(source_profile.cfa_pattern)
    bands = {c: (target.band(c) if c in target.channels else tuple(source_profile.band_edges_m[c])) for c in channels}
    d, h_alt, eps = target.diameter_m, target.altitude_m, target.obscuration_ratio
    lam_min = min(b[0] for b in bands.values())
    lam_max = max(b[1] for b in bands.values())
    f_c = d / (lam_min * h_alt)  # optical band limit on the ground [cycles/m]
    fwhm_min = 1.029 * lam_min / d * h_alt
    smear = target.smear_m
    theta = float(target.frame_rotation_rad)
    smear_on = smear >= acc.negligible_smear_px * gt
    jitter = target.jitter_rms_rad * h_alt
    jitter_on = 2.3548 * jitter >= acc.negligible_psf_px * gt
    modelled = ["binomial thinning", "uniform position in the source CFA cell", "diffraction psf (annulus, band-averaged)",
                "target pixel box", "colour filter", "haze (Poisson)", "dark current", "read noise", "gain/black/ADC"]
    skipped = []
    (modelled if smear_on else skipped).append(f"motion smear ({smear:.3g} m)")
    (modelled if jitter_on else skipped).append(f"jitter ({jitter:.3g} m rms)")
    if fwhm_min < acc.negligible_psf_px * gt:
        modelled.append("note: psf below negligible_psf_px, modelled anyway at no cost in the Fourier chain")

    # ---- margin (edge pixels) and pad (FFT period) on the ground
    tail_m = _tail_lod(acc.kernel_flux_loss, eps) * lam_max / d * h_alt
    extra = (smear / 2 if smear_on else 0.0) + (4 * jitter if jitter_on else 0.0)
    margin = tail_m + extra + gt * math.sqrt(2) / 2 if edge == "valid" else 0.0
    pad_m = _tail_lod(acc.folding_threshold, eps) * lam_max / d * h_alt + extra

    # ---- target frame on the footprint
    ox, oy = target.frame_offset_m
    cx, cy = Wm / 2 + ox, Hm / 2 + oy
    cth, sth = abs(math.cos(theta)), abs(math.sin(theta))
    if target.frame_shape_px is not None:
        ht, wt = target.frame_shape_px
    else:
        a_in, b_in = Wm / 2 - abs(ox) - margin, Hm / 2 - abs(oy) - margin
        if a_in <= 0 or b_in <= 0:
            ht = wt = 0
        else:
            k = min(a_in / (a_in * cth + b_in * sth), b_in / (a_in * sth + b_in * cth))
            wt, ht = int(2 * k * a_in / gt + 1e-9), int(2 * k * b_in / gt + 1e-9)
    if ht < 1 or wt < 1:
        raise MetrawError(
            f"the kernel (PSF wings, smear) needs a margin of {margin:.3g} m inside each edge but the source frame "
            f"covers only {Wm:.3g} x {Hm:.3g} m (offset {ox:g}, {oy:g} m): no target pixel would get all its light "
            "under edge policy 'valid'; use a larger source frame, a looser kernel_flux_loss, or edge='reflect'")
    half_w, half_h = wt * gt / 2, ht * gt / 2
    ext_x, ext_y = half_w * cth + half_h * sth, half_w * sth + half_h * cth
    tol = 1e-9 * max(Wm, Hm)
    if (cx - ext_x < margin - tol or cx + ext_x > Wm - margin + tol or cy - ext_y < margin - tol
            or cy + ext_y > Hm - margin + tol):
        raise MetrawError(f"target frame {ht} x {wt} px ({2 * half_h:.4g} x {2 * half_w:.4g} m, rotation {theta:g} rad) "
                          f"does not fit in the source footprint {Hm:.4g} x {Wm:.4g} m with margin {margin:.3g} m")

    # ---- Fourier grid (ground axes = source axes)
    plan_m, plan_s = _gridding(acc.psf_quadrature_error)
    h_max = 1.0 / (2 * _OVERSAMPLE * f_c)
    h_floor = cell / 2
    bounds: dict[str, float] = {}
    if h_max < h_floor:
        h_max = h_floor
        bounds["band_truncation"] = float("nan")  # set below from the OTF beyond the grid band
    if edge == "reflect":
        # even extension: the period is exactly twice the footprint, so the periodic FFT sees the scene
        # mirrored again and again (no wrap-around error at all)
        ny_in = sfft.next_fast_len(max(plan_m + 1, math.ceil(Hm / h_max)), real=True)
        nx_in = sfft.next_fast_len(max(plan_m + 1, math.ceil(Wm / h_max)), real=True)
        oy0 = ox0 = 0
        Ny, Nx = 2 * ny_in, 2 * nx_in
    else:
        ny_in, nx_in = max(1, math.ceil(Hm / h_max)), max(1, math.ceil(Wm / h_max))
        oy0 = math.ceil(pad_m / (Hm / ny_in)) + plan_m + 2
        ox0 = math.ceil(pad_m / (Wm / nx_in)) + plan_m + 2
        Ny = sfft.next_fast_len(ny_in + 2 * oy0 + 1, real=True)
        Nx = sfft.next_fast_len(nx_in + 2 * ox0 + 1, real=True)
    hy, hx = Hm / ny_in, Wm / nx_in
    grid = (Ny, Nx, hy, hx, plan_s)
    fy, fx, fr, denom = _grid_arrays(*grid)
    base = (np.sinc(cell * fx) * np.sinc(cell * fy)  # uniform in the source cell
            * _sinc_along(fx, fy, math.cos(theta), math.sin(theta), gt)  # target pixel box (rotated)
            * _sinc_along(fx, fy, -math.sin(theta), math.cos(theta), gt))
    if smear_on:
        a = target.track_angle_rad
        base = base * _sinc_along(fx, fy, math.cos(a), math.sin(a), smear)
    if jitter_on:
        base = base * np.exp(-2 * math.pi**2 * jitter**2 * fr**2)
    transfer, tables = {}, {}
    n_lams = {}
    beyond = fr > 1 / (2 * max(hx, hy)) if "band_truncation" in bounds else None  # outside the grid's band
    truncation = 0.0  # the largest over the channels (the bluest band reaches farthest)
    for c in channels:
        pix_rad = min(hy, hx) / h_alt
        n_lam = n_band_wavelengths(bands[c], d, pix_rad, (65, 65), eps, acc)
        n_lams[c] = n_lam
        otf = _grid_otf(grid, tuple(bands[c]), d, eps, h_alt, n_lam)
        # target pixel box as a mean (sinc) times its area gives photons per target pixel
        transfer[c] = otf * base * (gt * gt) / denom
        if beyond is not None:
            truncation = max(truncation, float(np.abs(otf * base)[beyond].max(initial=0.0)))
    if beyond is not None:
        bounds["band_truncation"] = truncation
    # photon chain: PSF radial table out to where the outside flux <= kernel_flux_loss / 10 (asymptote beyond)
    v_max = max(50.0, math.pi * 2.0 / (math.pi**2 * (acc.kernel_flux_loss / 10) * (1 - eps)))
    tables = _ee_table(eps, v_max)
    prebin = max(1, int(acc.max_prebin_fraction_of_psf * fwhm_min // cell))
    bounds.update({
        "gridding_relative": math.exp(-math.pi * plan_m / math.sqrt(2.0)),  # measured ~10x below
        "band_sampling_peak_relative": acc.band_sampling_error,
        "fft_wrap_flux": acc.folding_threshold,
        "edge_missing_flux": acc.kernel_flux_loss if edge == "valid" else (0.0 if edge == "reflect" else 0.5),
        "prebin_blur_rms_m": prebin * cell / math.sqrt(12) if prebin > 1 else 0.0,
    })
    if edge == "reflect":
        bounds["edge_light_from_mirrored_scene"] = 1.0
    return EmulationPlan(
        channels=channels, source_gsd_m=gs, cell_m=cell, cells_shape=(hc, wc), target_gsd_m=gt,
        frame_shape=(int(ht), int(wt)), rotation_rad=theta, centre_m=(cx, cy), alpha=alpha, p=p, bands=bands,
        edge=edge, grid_h_m=(hy, hx), grid_shape=(Ny, Nx), grid_origin=(oy0, ox0), n_inside=(ny_in, nx_in),
        transfer=transfer, gridding=(plan_m, plan_s), prebin=prebin, psf_table=tables, margin_m=margin,
        modelled=modelled, skipped=skipped,
        bounds=bounds, smear_m=smear if smear_on else 0.0, smear_angle_rad=target.track_angle_rad,
        jitter_m=jitter if jitter_on else 0.0, diameter_m=d, altitude_m=h_alt)
