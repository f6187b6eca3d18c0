"""End-to-end emulation: the raw image a target system would record of a source raw's scene.

docs/emulation.md. Per source colour c the light is thinned with p_c = alpha_c / phi_c,

    alpha_c = [A_t / h_t^2 * t_t * tau_t * eta_t,c * T_atm] / [A_s / h_s^2 * t_s * tau_s * eta_s,c]

(A aperture area, h altitude, t exposure, tau optical transmission, eta QE, phi_c the fraction of
source pixels of colour c): a source pixel stands for the c-light of its whole CFA cell, so its
photons are placed uniformly in that cell. Each photon is displaced by the target's system
kernel (polychromatic diffraction PSF of the annular aperture, uniform motion smear of length
v t along the track, Gaussian jitter), mapped to the target frame (GSD = pitch h / f, any
offset, rotation and non-integer GSD ratio) and detected only on a target pixel of its colour
(every pixel for a mono target). Then haze path radiance (Poisson), dark current, read noise,
gain, black, rounding, full well and ADC (`metraw.raw.sensor.readout`).

Two chains of one continuous model, each the other's test:

- photon (reference): counts (stochastically rounded, optionally pre-binned exactly into blocks
  no wider than ``max_prebin_fraction_of_psf`` of the PSF FWHM), binomial thinning, then every
  kept photon gets a continuous position: uniform in its cell (block), plus a PSF displacement
  drawn exactly (wavelength uniform in the band, radius by inverse CDF of the annulus encircled
  energy, its r^-2 tail beyond the table drawn from the asymptote), plus smear and jitter, in one
  compiled loop that draws its own random numbers (`metraw.physics.photon_landing`).
  Cost: O(kept photons): 35 ns a kept photon on one core, thinning included (93 ns with numpy's uniforms; 2026-11-27).
- expected (FFT): the same model in expectation, evaluated in the Fourier domain where it is exact:
  cell counts are spread onto an oversampled ground grid (Gaussian gridding, separable banded
  operators: `metraw.physics.gridding`), multiplied by the transfer functions (cell box, annulus OTF averaged over the band,
  smear, jitter, target pixel box) and evaluated at the target pixel centres (type-2 gridding).
  The OTF vanishes beyond D / lambda, so a grid at twice that band limit loses nothing; the
  gridding error is ~1e-5 of the signal. Then one Poisson draw per target pixel: its excess
  variance over the photon chain is of relative order p (reported), negligible for drone to
  satellite (p ~ 1e-4).
- ``mode="auto"``: "expected" when every p_c <= ``poisson_shortcut_max_p``, else "photon".

Edge policy (light that would come from ground outside the source frame):
``"reflect"`` (default): the scene is mirror-extended beyond the source footprint (exact for a flat
field; in the photon chain photons leaving the footprint are reflected back, the same for kernels
symmetric about the frame axes; for oblique smear the mirrored kernel is used, reported);
``"zero"``: no light from outside (edge pixels are darker); ``"valid"``: the target frame keeps
only pixels whose one-sided kernel tail beyond the footprint is <= ``kernel_flux_loss`` (a
kernel larger than the frame is an error saying so). The label mask follows the same geometry,
without blur: the car-area fraction of each target pixel (source cells assigned by centre).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from metraw.physics.accuracy import DEFAULT_ACCURACY, Accuracy
from metraw.raw.cfa import channel_names, color_index, fill_factor, plane_offsets
from metraw.errors import MetrawError
from metraw.physics.gridding import GaussianWindow
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.physics.photon_landing import land_photons
from metraw.physics.rawfunc import stochastic_round, thin_counts
from metraw.raw.sensor import readout, rng_from_seed
from metraw.emulate.target import TargetSystem

__all__ = ["emulate", "expected_electrons", "photon_electrons", "plan_emulation", "EmulationPlan",
           "thinning_ratios", "EDGE_POLICIES"]

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
    a_s = math.pi / 4 * g["aperture_diameter_m"] ** 2 * (1 - source_profile.obscuration_ratio**2)
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


# ----------------------------------------------------------------------------- source cells
def _cell_planes(source: RawImage, plan: EmulationPlan) -> dict[str, np.ndarray]:
    """Photoelectrons per source cell and colour, float64 (DN - black) / K summed over same-colour sites."""
    prof = source.profile
    step = 1 if prof.is_mono else 2
    hc, wc = plan.cells_shape
    data = source.data[: hc * step, : wc * step]
    out: dict[str, np.ndarray] = {}
    count: dict[str, int] = {}
    for ch, dy, dx in plane_offsets(prof.cfa_pattern):
        plane = data[dy::step, dx::step]
        if ch in out:
            out[ch] += plane
        else:
            out[ch] = plane.astype(np.float64)
        count[ch] = count.get(ch, 0) + 1
    for ch in out:
        out[ch] -= count[ch] * prof.black_level_dn
        out[ch] /= prof.gain_dn_per_e
    return out


def _saturated_cells(source: RawImage, plan: EmulationPlan) -> np.ndarray | None:
    sat = source.saturated()
    if not sat.any():
        return None
    step = 1 if source.profile.is_mono else 2
    hc, wc = plan.cells_shape
    s = sat[: hc * step, : wc * step]
    return s.reshape(hc, step, wc, step).any(axis=(1, 3)) if step == 2 else s


# ----------------------------------------------------------------------------- gridding
class _Fourier:
    """Type-1 gridding of cell values, transfer in Fourier space, type-2 evaluation at target pixel centres."""

    def __init__(self, plan: EmulationPlan):
        self.plan = plan
        hy, hx = plan.grid_h_m
        oy0, ox0 = plan.grid_origin
        Ny, Nx = plan.grid_shape
        hc, wc = plan.cells_shape
        cell = plan.cell_m
        self.periodic = per = plan.edge == "reflect"
        g = plan.gridding
        self.Sy = GaussianWindow((np.arange(hc) + 0.5) * cell / hy + oy0, Ny, per, *g)
        self.Sx = GaussianWindow((np.arange(wc) + 0.5) * cell / hx + ox0, Nx, per, *g)
        ht, wt = plan.frame_shape
        gt = plan.target_gsd_m
        c, s = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
        u = (np.arange(wt) + 0.5 - wt / 2) * gt
        v = (np.arange(ht) + 0.5 - ht / 2) * gt
        if s == 0.0:
            self.separable = True
            self.Ty = GaussianWindow((c * v + plan.centre_m[1]) / hy + oy0, Ny, per, *g)
            self.Tx = GaussianWindow((c * u + plan.centre_m[0]) / hx + ox0, Nx, per, *g)
        else:
            self.separable = False
            X = plan.centre_m[0] + c * u[None, :] - s * v[:, None]
            Y = plan.centre_m[1] + s * u[None, :] + c * v[:, None]
            self.px = (X / hx + ox0).ravel()
            self.py = (Y / hy + oy0).ravel()

    def grid(self, cells: np.ndarray) -> np.ndarray:
        # Sy @ cells @ Sx^T; the column scatter (scattered writes) costs ~4x the row scatter (whole rows) per element,
        # so it goes on the side with fewer rows: after the row scatter when the grid has fewer rows than the cells
        if self.Sy.n_grid < self.Sy.n_points:
            g = self.Sx.scatter_cols(self.Sy.scatter_rows(cells))
        else:
            g = self.Sy.scatter_rows(self.Sx.scatter_cols(cells))
        if self.periodic:  # even extension about ground 0 (and so about the far edge): g(k) += g(-k mod N)
            g = g + np.roll(g[::-1], 1, axis=0)
            g = g + np.roll(g[:, ::-1], 1, axis=1)
        return g

    def filtered(self, grid: np.ndarray, channel: str) -> np.ndarray:
        """The gridded cells times ``channel``'s transfer functions, back on the ground grid.

        The FFTs take scipy's workers (1 unless a caller sets ``scipy.fft.set_workers``; the values do not depend
        on it): the emulation and the training's field processes each fill a core, and a second FFT thread there
        cost ~70 % more CPU per transform (a 384 x 384 grid: 1.5 against 0.9 ms) and waited for a core (8.8 ms).
        """
        G = sfft.rfft2(grid) * self.plan.transfer[channel]
        return sfft.irfft2(G, self.plan.grid_shape)

    def evaluate(self, grid: np.ndarray, channel: str) -> np.ndarray:
        plan = self.plan
        g = self.filtered(grid, channel)
        if self.separable:
            return self.Tx.gather_cols(self.Ty.gather_rows(g))
        plan_m, plan_s = plan.gridding
        offs = np.arange(-plan_m, plan_m + 1)
        ky = np.rint(self.py).astype(np.int64)[:, None] + offs
        kx = np.rint(self.px).astype(np.int64)[:, None] + offs
        wy = np.exp(-0.5 * ((ky - self.py[:, None]) / plan_s) ** 2)
        wx = np.exp(-0.5 * ((kx - self.px[:, None]) / plan_s) ** 2)
        ky %= plan.grid_shape[0]
        kx %= plan.grid_shape[1]
        out = np.zeros(len(self.px))
        for a in range(offs.size):
            out += wy[:, a] * np.einsum("ij,ij->i", g[ky[:, a][:, None], kx], wx)
        return out.reshape(plan.frame_shape)

    def arrivals(self, cells: np.ndarray, channel: str) -> np.ndarray:
        """Expected photons of ``channel`` arriving in each target pixel from ``cells`` (already thinned)."""
        return self.evaluate(self.grid(cells), channel)


def _detect(target: TargetSystem, channel: str, shape) -> np.ndarray | None:
    if target.cfa_pattern == "mono":
        return None
    return color_index(target.cfa_pattern, shape) == target.channels.index(channel)


# ----------------------------------------------------------------------------- chains
def expected_electrons(source: RawImage, target: TargetSystem, accuracy: Accuracy | None = None,
                       edge: str = "reflect") -> tuple[np.ndarray, EmulationPlan]:
    """Expected detected photoelectrons per target pixel (signal only, before haze and dark), float64.

    Negative expectations (dark areas where the source's read noise dominates) are clipped at 0.
    """
    plan = plan_emulation(source.profile, source.shape, target, accuracy, edge)
    return _expected(_cell_planes(source, plan), plan, target, _Fourier(plan)), plan


def _expected(cells: dict[str, np.ndarray], plan, target, fourier) -> np.ndarray:
    out = np.zeros(plan.frame_shape)
    for c, e in cells.items():
        arrive = fourier.arrivals(plan.p[c] * e, c)
        det = _detect(target, c, plan.frame_shape)
        out += arrive if det is None else np.where(det, arrive, 0.0)
    return np.maximum(out, 0.0)


def photon_electrons(source: RawImage, target: TargetSystem, accuracy: Accuracy | None = None,
                     edge: str = "reflect", seed: int | np.random.Generator = 0) -> tuple[np.ndarray, EmulationPlan]:
    """One photon-exact draw of the detected photoelectrons per target pixel (int64), and the plan."""
    plan = plan_emulation(source.profile, source.shape, target, accuracy, edge)
    return _photons(_cell_planes(source, plan), plan, target, rng_from_seed(seed)), plan


def _photons(cells: dict[str, np.ndarray], plan: EmulationPlan, target, rng) -> np.ndarray:
    ht, wt = plan.frame_shape
    out = np.zeros(ht * wt, dtype=np.int64)
    B = plan.prebin
    block = B * plan.cell_m
    hc, wc = plan.cells_shape
    Hm, Wm = hc * plan.cell_m, wc * plan.cell_m
    c_r, s_r = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
    gt = plan.target_gsd_m
    table = plan.psf_table
    for c, e in cells.items():
        e = np.maximum(e, 0.0)
        if B > 1:
            hb, wb = -(-hc // B), -(-wc // B)
            pad = np.zeros((hb * B, wb * B))
            pad[:hc, :wc] = e
            e = pad.reshape(hb, B, wb, B).sum(axis=(1, 3))
        kept = thin_counts(stochastic_round(e, rng), plan.p[c], rng).ravel()
        det = _detect(target, c, plan.frame_shape)
        det_flat = np.ones(ht * wt, np.int8) if det is None else det.ravel().astype(np.int8)
        lo, hi = plan.bands[c]
        key = np.uint64(rng.integers(0, 2**64, dtype=np.uint64))  # this colour's photon stream
        land_photons(kept, e.shape[1], block, Wm * (1 - 1e-12) if B > 1 else 0.0, Hm * (1 - 1e-12) if B > 1 else 0.0,
                     key, lo, hi, plan.altitude_m / (math.pi * plan.diameter_m), table["ee"], table["v"],
                     table["guide"], table["v_max"], table["tail"], plan.smear_m * math.cos(plan.smear_angle_rad),
                     plan.smear_m * math.sin(plan.smear_angle_rad), plan.jitter_m, plan.edge == "reflect", Wm, Hm,
                     plan.centre_m[0], plan.centre_m[1], c_r, s_r, gt, wt, ht, det_flat, out)
    return out.reshape(ht, wt)


def _cell_mask(source: RawImage, plan: EmulationPlan) -> np.ndarray:
    """Car-area fraction of every source CFA cell (float64): the mean of its pixels' fractions."""
    step = 1 if source.profile.is_mono else 2
    hc, wc = plan.cells_shape
    m = source.mask[: hc * step, : wc * step]
    if step == 2:  # mean over the cell's four pixels (float32 sums of four fractions, then float64)
        return (m[0::2, 0::2] + m[0::2, 1::2] + m[1::2, 0::2] + m[1::2, 1::2]).astype(np.float64) / 4.0
    return m.astype(np.float64)


def _mask_fraction(source: RawImage, plan: EmulationPlan) -> np.ndarray:
    """Car-area fraction per target pixel: source cells assigned to the pixel holding their centre."""
    hc, wc = plan.cells_shape
    m = _cell_mask(source, plan)
    ht, wt = plan.frame_shape
    gt = plan.target_gsd_m
    c_r, s_r = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
    x = (np.arange(wc) + 0.5) * plan.cell_m - plan.centre_m[0]
    y = (np.arange(hc) + 0.5) * plan.cell_m - plan.centre_m[1]
    if s_r == 0.0:  # axis-aligned frame: separable 0/1 assignment matrices
        col = np.floor(c_r * x / gt + wt / 2).astype(np.int64)
        row = np.floor(c_r * y / gt + ht / 2).astype(np.int64)
        okc, okr = (col >= 0) & (col < wt), (row >= 0) & (row < ht)
        ax = sp.csr_matrix((np.ones(okc.sum()), (col[okc], np.flatnonzero(okc))), shape=(wt, wc))
        ay = sp.csr_matrix((np.ones(okr.sum()), (row[okr], np.flatnonzero(okr))), shape=(ht, hc))
        total = np.asarray(ay @ (ax @ m.T).T)
        count = np.outer(np.asarray(ay.sum(axis=1)).ravel(), np.asarray(ax.sum(axis=1)).ravel())
        frac = np.where(count > 0, total / np.maximum(count, 1), 0.0)
        return np.clip(frac, 0.0, 1.0).astype(np.float32)
    col = np.floor((c_r * x[None, :] + s_r * y[:, None]) / gt + wt / 2).astype(np.int64)
    row = np.floor((-s_r * x[None, :] + c_r * y[:, None]) / gt + ht / 2).astype(np.int64)
    ok = (col >= 0) & (col < wt) & (row >= 0) & (row < ht)
    pix = (row * wt + col)[ok]
    total = np.bincount(pix, weights=m[ok], minlength=ht * wt)
    count = np.bincount(pix, minlength=ht * wt)
    frac = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return np.clip(frac, 0.0, 1.0).reshape(ht, wt).astype(np.float32)


def emulate(source: RawImage, target: TargetSystem, mode: str = "auto", seed: int | np.random.Generator = 0,
            accuracy: Accuracy | None = None, edge: str = "reflect") -> RawImage:
    """The raw image ``target`` would record of ``source``'s scene (see module docstring).

    ``mode``: "photon" | "expected" | "auto". The result carries the target's profile, the label
    mask (car-area fraction per target pixel), flags (FLAG_SATURATED where the target pixel
    saturates or where light from saturated source pixels exceeds ``kernel_flux_loss`` of its
    expected signal: their true value is unknown, only a lower bound) and a provenance entry
    with the effects modelled and skipped and the error bounds claimed.
    """
    if mode not in ("photon", "expected", "auto"):
        raise MetrawError(f"emulation mode must be photon, expected or auto, got {mode!r}")
    acc = accuracy or DEFAULT_ACCURACY
    rng = rng_from_seed(seed)
    plan = plan_emulation(source.profile, source.shape, target, acc, edge)
    pmax = max(plan.p.values())
    chain = mode if mode != "auto" else ("expected" if pmax <= acc.poisson_shortcut_max_p else "photon")
    cells = _cell_planes(source, plan)
    fourier = None
    mean_signal = None
    if chain == "photon":
        counts = _photons(cells, plan, target, rng).astype(np.float64)
    else:
        fourier = _Fourier(plan)
        mean_signal = _expected(cells, plan, target, fourier)
        counts = rng.poisson(mean_signal).astype(np.float64)
    tshape = plan.frame_shape
    haze = np.take(np.array([target.haze_for(c) for c in target.channels]), color_index(target.cfa_pattern, tshape))
    if np.any(haze > 0):
        counts += rng.poisson(haze)
    profile = target.profile()
    if source.profile.approximate:  # a raw rebuilt from a processed photo stays flagged through the emulation
        profile = profile.replace(approximate=True, approximate_reason="emulated from an approximate source: "
                                  + (source.profile.approximate_reason or "source profile marked approximate"))
    data = readout(counts, profile, rng)
    flags = np.zeros(tshape, np.uint8)
    sat_t = data >= profile.white_level_dn
    if profile.full_well_e is not None:
        sat_t |= counts >= profile.full_well_e
    flags[sat_t] |= FLAG_SATURATED
    sat_cells = _saturated_cells(source, plan)
    n_fed = 0
    if sat_cells is not None:
        fourier = fourier or _Fourier(plan)
        total = mean_signal if mean_signal is not None else _expected(cells, plan, target, fourier)
        sat_light = _expected({c: np.where(sat_cells, e, 0.0) for c, e in cells.items()}, plan, target, fourier)
        fed = sat_light > acc.kernel_flux_loss * np.maximum(total, 1e-300)
        n_fed = int(fed.sum())
        flags[fed] |= FLAG_SATURATED
    mask = _mask_fraction(source, plan) if source.mask is not None else None
    bounds = dict(plan.bounds)
    read_s2 = source.profile.read_noise_e**2 + 0.25
    clipped = {c: float(-np.minimum(e, 0).sum()) for c, e in cells.items()}
    mean_cell = max(1.0, float(np.mean([(e.sum() + clipped[c]) / e.size for c, e in cells.items()])))
    if chain == "expected":
        bounds["poisson_shortcut_excess_variance_rel"] = pmax * (1.0 + read_s2 / mean_cell)
    bounds["source_noise_excess_variance_rel"] = pmax * read_s2 / mean_cell
    mean_signal_e = float(counts.mean() - haze.mean())
    params = {
        "target": target.to_dict(), "mode": mode, "chain": chain, "seed": seed if isinstance(seed, int) else None,
        "accuracy": acc.to_dict(), **plan.summary(), "error_bounds": bounds, "clipped_negative_source_e": clipped,
        "saturated_source_cells": 0 if sat_cells is None else int(sat_cells.sum()),
        "target_pixels_fed_by_saturated": n_fed, "mean_signal_e": mean_signal_e,
        "haze_e": {c: target.haze_for(c) for c in target.channels},
        "deviation": ("source read noise and rounding are thinned with the signal (relative excess variance "
                      f"<= {bounds['source_noise_excess_variance_rel']:.2g})"
                      + ("; expected chain + one Poisson draw per pixel (relative excess variance "
                         f"<= {bounds['poisson_shortcut_excess_variance_rel']:.2g})" if chain == "expected" else "")),
    }
    out = source.derive(data, profile, function="emulate", params=params, mask=mask, flags=flags)
    out.meta["emulation"] = {"chain": chain, "gsd_ratio": plan.target_gsd_m / plan.source_gsd_m, "p": plan.p,
                             "mean_signal_e": mean_signal_e, "modelled": plan.modelled, "skipped": plan.skipped,
                             "error_bounds": bounds}
    return out
